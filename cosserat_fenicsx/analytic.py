"""Closed-form solutions used to verify the solver (derivations in docs/reference/verification.md).

Everything here is independent of the finite-element code: plain numpy/scipy.
"""
import math

import numpy as np


def _cosh_ratio(z, big):
    """cosh(z) / cosh(big) without overflow (|z| <= big)."""
    z = np.abs(z)
    return np.exp(z - big) * (1.0 + np.exp(-2.0 * z)) / (1.0 + np.exp(-2.0 * big))


def _sinh_ratio(z, big):
    """sinh(z) / cosh(big) without overflow (|z| <= big)."""
    a = np.abs(z)
    return np.sign(z) * np.exp(a - big) * (1.0 - np.exp(-2.0 * a)) / (1.0 + np.exp(-2.0 * big))


def shear_layer(x2, height, shift, mu, mu_c, l_c, top_rotation="fixed"):
    """Sheared micropolar layer 0 <= x2 <= height, infinite in x1, plane strain.

    Bottom: u = 0, phi = 0. Top: u1 = shift, u2 = 0 and phi = 0 ('fixed') or zero
    surface couple m32 = 0 ('free'). Linear elasticity of eqs 2.73/2.74 (no volume
    change, so lambda plays no role). Returns (u1, phi, tau): displacement [m] and
    rotation [rad] at x2, and the uniform shear stress sigma12 [Pa].

    Derivation: sigma12 = (mu + mu_c) u1' + 2 mu_c phi = tau is constant (momentum), and
    sigma21 - sigma12 = -2 mu_c u1' - 4 mu_c phi, so the moment balance
    sigma21 - sigma12 + m32' = 0 with m32 = 2 mu_c l_c^2 phi' becomes
        phi'' - phi / ell^2 = tau / (l_c^2 (mu + mu_c)),   ell = l_c sqrt((mu + mu_c)/(2 mu)).
    With phi(0) = 0:
        fixed: phi = -tau/(2 mu) [1 - cosh((x2 - h/2)/ell) / cosh(h/(2 ell))]
        free:  phi = -tau/(2 mu) [1 - cosh((h - x2)/ell) / cosh(h/ell)]      (phi'(h) = 0)
    and u1 = (tau x2 - 2 mu_c int_0^x2 phi) / (mu + mu_c); tau follows from u1(h) = shift.
    Far from the faces phi = -tau/(2 mu) equals the macro-rotation -u1'/2: the
    classical simple shear, which is also the l_c -> 0 limit.
    """
    if top_rotation not in ("fixed", "free"):
        raise ValueError("top_rotation must be 'fixed' or 'free'")
    x2 = np.asarray(x2, dtype=float)
    h = float(height)
    if mu_c == 0.0:
        return shift * x2 / h, np.zeros_like(x2), mu * shift / h
    a = 1.0 / (2.0 * mu)
    if l_c == 0.0:
        phi_unit = lambda y: -a * np.ones_like(y)  # noqa: E731
        int_phi_unit = lambda y: -a * y  # noqa: E731
    else:
        ell = l_c * math.sqrt((mu + mu_c) / (2.0 * mu))
        if top_rotation == "fixed":
            half = 0.5 * h / ell
            phi_unit = lambda y: -a * (1.0 - _cosh_ratio((y - 0.5 * h) / ell, half))  # noqa: E731
            int_phi_unit = lambda y: -a * y + a * ell * (  # noqa: E731
                _sinh_ratio((y - 0.5 * h) / ell, half) + math.tanh(half))
        else:
            full = h / ell
            phi_unit = lambda y: -a * (1.0 - _cosh_ratio((h - y) / ell, full))  # noqa: E731
            int_phi_unit = lambda y: -a * y + a * ell * (  # noqa: E731
                math.tanh(full) - _sinh_ratio((h - y) / ell, full))

    def u1_unit(y):
        return (y - 2.0 * mu_c * int_phi_unit(y)) / (mu + mu_c)

    tau = shift / float(u1_unit(np.array(h)))
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
