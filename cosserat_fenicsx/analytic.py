"""Closed-form solutions used to verify the solver (derivations in docs/verification.md).

Everything here is independent of the finite-element code: plain numpy/scipy.
"""
import math

import numpy as np


def shear_layer(x2, height, shift, mu, mu_c, l_c, top_rotation="fixed"):
    """Sheared micropolar layer 0 <= x2 <= height, infinite in x1, plane strain.

    Bottom: u = 0, phi = 0. Top: u1 = shift, u2 = 0 and phi = 0 ('fixed') or zero
    surface couple ('free'). Linear elasticity of eqs 2.73/2.74 (no volume change).
    Returns (u1, phi, tau): displacement [m], rotation [rad] at x2, and the uniform shear
    stress sigma12 [Pa].

    Balance: sigma12 = tau is constant; with u1' = (tau - 2 mu_c phi) / (mu + mu_c) the
    moment balance sigma21 - sigma12 + m32' = 0 becomes
        phi'' - phi / ell^2 = tau / (l_c^2 (mu + mu_c)),   ell = l_c sqrt((mu + mu_c) / (2 mu)),
    so phi = -tau/(2 mu) + A cosh(x2/ell) + B sinh(x2/ell), A = tau/(2 mu) from phi(0) = 0,
    B from phi(h) = 0 or phi'(h) = 0, and u1 = (tau x2 - 2 mu_c int_0^x2 phi) / (mu + mu_c);
    tau follows from u1(h) = shift.
    """
    if top_rotation not in ("fixed", "free"):
        raise ValueError("top_rotation must be 'fixed' or 'free'")
    x2 = np.asarray(x2, dtype=float)
    h = float(height)
    if mu_c == 0.0 or l_c == 0.0:
        # no coupling or no length: phi equals the macro-rotation, classical simple shear
        tau = mu * shift / h
        phi = np.full_like(x2, -0.5 * shift / h) if mu_c > 0 else np.zeros_like(x2)
        return shift * x2 / h, phi, tau
    ell = l_c * math.sqrt((mu + mu_c) / (2.0 * mu))
    s = h / ell
    # shape functions for tau = 1; big arguments: use exp-scaled forms through ratios
    a = 1.0 / (2.0 * mu)
    if top_rotation == "fixed":
        b = a * (1.0 - math.cosh(s)) / math.sinh(s) if s < 700 else -a
    else:
        b = -a * math.tanh(s)

    def phi_unit(y):
        return -a + a * np.cosh(y / ell) + b * np.sinh(y / ell)

    def int_phi_unit(y):
        return -a * y + a * ell * np.sinh(y / ell) + b * ell * (np.cosh(y / ell) - 1.0)

    def u1_unit(y):
        return (y - 2.0 * mu_c * int_phi_unit(y)) / (mu + mu_c)

    if s > 600:  # the cosh terms overflow; they only matter within ell of the faces
        raise ValueError("height / ell > 600: use the l_c -> 0 limit instead")
    tau = shift / u1_unit(h)
    return tau * u1_unit(x2), tau * phi_unit(x2), tau


def kirsch_scf():
    """Classical stress concentration at a circular hole under uniaxial tension."""
    return 3.0


def micropolar_hole_scf(radius, mu, lmbda, mu_c, l_c):
    """Stress concentration factor at a circular hole in an infinite plane-strain
    micropolar plate under uniaxial tension (Kaloni & Ariman 1967; Eringen 1968,
    'Theory of micropolar elasticity', Fracture vol. 2; as used by Nakamura, Benedict &
    Lakes 1984):

        SCF = (3 + F) / (1 + F),
        F = 8 (1 - nu) N^2 / (4 + a^2/c^2 + 2 (a/c) K0(a/c) / K1(a/c)),

    with Eringen's constants mu_E = mu - mu_c, kappa = 2 mu_c, gamma = 2 mu_c l_c^2:
    N^2 = kappa / (2 (mu_E + kappa)) = mu_c / (mu + mu_c) (coupling number) and
    c^2 = gamma (mu_E + kappa) / (kappa (2 mu_E + kappa)) = l_c^2 (mu + mu_c) / (2 mu),
    the same length as the rotation decay length of the shear layer.
    """
    from scipy.special import k0e, k1e
    nu = lmbda / (2.0 * (lmbda + mu))
    if mu_c == 0.0 or l_c == 0.0:
        return 3.0
    n2 = mu_c / (mu + mu_c)
    c = l_c * math.sqrt((mu + mu_c) / (2.0 * mu))
    x = radius / c
    F = 8.0 * (1.0 - nu) * n2 / (4.0 + x * x + 2.0 * x * k0e(x) / k1e(x))
    return (3.0 + F) / (1.0 + F)
