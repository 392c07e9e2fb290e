"""Yield function (2.76)/(2.77), potential (2.78) and their invariants (spec 4.1-4.3, 10 items 4-6).

Reference values are computed here independently with numpy 3x3 tensors (deviator,
determinant, eigen-free), not with the kernel's component formulas.
"""
import math

import numpy as np
import pytest

from cosserat_fenicsx.materials.ehlers import EhlersMaterial
from cosserat_fenicsx.materials.ehlers.yield_function import (invariants, lode_factor,
                                                              plastic_potential_derivatives,
                                                              yield_function, yield_function_gradient)

pytestmark = pytest.mark.serial
RNG = np.random.default_rng(3)
THETA_MIN = -2.0 / (3.0 * math.sqrt(3.0))


def tensor(S):
    """3x3 stress tensor of a generalised plane vector (sig11, sig22, sig33, sig12, sig21, ...)."""
    return np.array([[S[0], S[3], 0.0], [S[4], S[1], 0.0], [0.0, 0.0, S[2]]])


def reference_nonpolar_ehlers(S, beta, delta_hat, eps_hat, gamma, alpha=0.0, kappa=0.0):
    """Ehlers' original non-polar surface, F = sqrt(Gamma II + alpha/2 I^2 + delta_hat^2 I^4)
    + beta I + eps_hat I^2 - kappa (delta_hat = 1/delta, eps_hat = 1/epsilon of 2.76)."""
    T = tensor(S)
    sym = 0.5 * (T + T.T)
    I = np.trace(T)
    D = sym - I / 3 * np.eye(3)
    II = 0.5 * np.sum(D * D)
    III = np.linalg.det(D)
    m = 2 / 9 + math.sqrt(3) / (3 * gamma)
    Gam = (1 + gamma * III / II ** 1.5) ** m
    return math.sqrt(Gam * II + 0.5 * alpha * I ** 2 + delta_hat ** 2 * I ** 4) + beta * I + eps_hat * I ** 2 - kappa


def random_stress(scale=0.3):
    S = RNG.normal(size=7) * scale
    S[:3] -= 1.0  # confined (MPa)
    return S


def params(**kw):
    return EhlersMaterial.hostun(**kw).params_array


def test_invariants_non_negative_and_rotation_invariant():
    for _ in range(50):
        S = random_stress()
        I, s0, s1, s2, s3, a, II, III, IIskw, mm = invariants(S)
        assert II >= 0.0 and IIskw >= 0.0
        T = tensor(S)
        sym = 0.5 * (T + T.T)
        D = sym - np.trace(T) / 3 * np.eye(3)
        np.testing.assert_allclose(II, 0.5 * np.sum(D * D), rtol=1e-12)
        np.testing.assert_allclose(III, np.linalg.det(D), rtol=1e-10, atol=1e-14)
        np.testing.assert_allclose(IIskw, 0.25 * (S[3] - S[4]) ** 2, rtol=1e-12)
        # rotation about e3 of the symmetric part
        t = RNG.uniform(0, 2 * np.pi)
        Q = np.array([[np.cos(t), -np.sin(t), 0], [np.sin(t), np.cos(t), 0], [0, 0, 1]])
        Tr = Q @ sym @ Q.T
        Sr = np.array([Tr[0, 0], Tr[1, 1], Tr[2, 2], Tr[0, 1], Tr[1, 0], 0.0, 0.0])
        r = invariants(Sr)
        np.testing.assert_allclose(r[6], II, rtol=1e-10)
        np.testing.assert_allclose(r[7], III, rtol=1e-8, atol=1e-14)


def test_lode_ratio_triaxial_compression():
    S = np.array([-3.0, -1.0, -1.0, 0, 0, 0, 0])  # axial more compressive (tension positive)
    I, s0, s1, s2, s3, a, II, III, IIskw, mm = invariants(S)
    Gam, theta, m, base = lode_factor(II, III, 1.2)
    np.testing.assert_allclose(theta, THETA_MIN, rtol=1e-12)
    assert Gam < 1.0  # stronger in compression than in extension


def test_reduces_to_nonpolar_ehlers_and_ignores_skew_and_couple_stress():
    P = params(k_sigma=0.0, k_mu=0.0)
    beta, delta, eps, gamma = 0.2, 3.0, 40.0, 1.3
    for _ in range(30):
        S = random_stress()
        F = yield_function(S, beta, delta, eps, gamma, P)
        np.testing.assert_allclose(F, reference_nonpolar_ehlers(S, beta, 1 / delta, 1 / eps, gamma), rtol=1e-11)
        S2 = S.copy()
        S2[3], S2[4] = 0.5 * (S[3] + S[4]) + 0.7, 0.5 * (S[3] + S[4]) - 0.7  # other skew part
        S2[5:] = RNG.normal(size=2)
        assert yield_function(S2, beta, delta, eps, gamma, P) == pytest.approx(F, rel=1e-12)
    # with k_sigma, k_mu > 0 the skew stress and couple stress enlarge Phi_F (II_skw >= 0, spec 4.1)
    P2 = params(k_sigma=10.0, k_mu=1e4)
    S = random_stress()
    S[3] = S[4] = 0.5 * (S[3] + S[4])  # symmetric, no couple stress
    S[5:] = 0.0
    S2 = S.copy()
    S2[3] += 0.1
    S2[4] -= 0.1
    assert yield_function(S2, beta, delta, eps, gamma, P2) > yield_function(S, beta, delta, eps, gamma, P2)
    S2[5] = 0.01
    assert yield_function(S2, beta, delta, eps, gamma, P2) > yield_function(S, beta, delta, eps, gamma, P2)


def fd_grad(fun, x, h=1e-6):
    g = np.zeros_like(x)
    for i in range(x.size):
        xp, xm = x.copy(), x.copy()
        xp[i] += h
        xm[i] -= h
        g[i] = (fun(xp) - fun(xm)) / (2 * h)
    return g


@pytest.mark.parametrize("kw", [dict(), dict(k_mu=3e3, alpha=0.05, kappa=0.001)])
def test_yield_gradient_and_potential_hessian_by_finite_differences(kw):
    """Spec 4.3 derivatives: dF/dS, dF/d(beta, delta, epsilon, gamma) incl. dm/dgamma of (2.77);
    n = dG/dS, its Hessian and dn/d(beta, delta, epsilon)."""
    P = params(**kw)
    p = np.array([0.2, 3.0, 40.0, 1.3])
    for _ in range(10):
        S = random_stress()
        dF = np.zeros(7)
        F, db, dd, de, dg, phi = yield_function_gradient(S, *p, P, dF)
        np.testing.assert_allclose(dF, fd_grad(lambda s: yield_function(s, *p, P), S), rtol=1e-6, atol=1e-8)
        dp = fd_grad(lambda q: yield_function(S, *q, P), p, h=1e-4)
        np.testing.assert_allclose([db, dd, de, dg], dp, rtol=1e-6, atol=1e-9)
        n, H, dndp = np.zeros(7), np.zeros((7, 7)), np.zeros((3, 7))
        G, phiG = plastic_potential_derivatives(S, p[0], p[1], p[2], P, n, H, dndp)

        def pot(s, q=p):
            return plastic_potential_derivatives(s, q[0], q[1], q[2], P, np.zeros(7), np.zeros((7, 7)),
                                                 np.zeros((3, 7)))[0]

        def flow(s, q=p):
            nn = np.zeros(7)
            plastic_potential_derivatives(s, q[0], q[1], q[2], P, nn, np.zeros((7, 7)), np.zeros((3, 7)))
            return nn

        np.testing.assert_allclose(n, fd_grad(pot, S), rtol=1e-6, atol=1e-8)
        Hfd = np.array([fd_grad(lambda s: flow(s)[i], S) for i in range(7)])
        np.testing.assert_allclose(H, Hfd, rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(H, H.T, atol=1e-12)
        for k in range(3):
            Dfd = np.array([fd_grad(lambda q: flow(S, np.r_[q, p[3]])[i], p[:3])[k] for i in range(7)])
            np.testing.assert_allclose(dndp[k], Dfd, rtol=1e-5, atol=1e-7)


def test_flow_is_volumetric_on_hydrostatic_axis_and_no_nan_at_zero_deviator():
    """Spec 10.4 / 10.6: dG/dsigma purely volumetric on the hydrostatic axis; F and dF/dsigma
    finite and continuous as II^D -> 0 (theta is 0/0 there)."""
    P = params()
    p = (0.2, 3.0, 40.0, 1.3)
    S = np.array([-0.5, -0.5, -0.5, 0, 0, 0, 0])
    n, H, dndp = np.zeros(7), np.zeros((7, 7)), np.zeros((3, 7))
    plastic_potential_derivatives(S, p[0], p[1], p[2], P, n, H, dndp)
    assert np.all(np.isfinite(n)) and np.all(np.isfinite(H))
    np.testing.assert_allclose(n[:3], n[0], rtol=1e-14)
    assert np.abs(n[3:]).max() == 0.0
    dF = np.zeros(7)
    F0 = yield_function_gradient(S, *p, P, dF)[0]
    d0 = dF.copy()
    assert np.all(np.isfinite(dF))
    for t in (1e-4, 1e-8, 1e-12):
        St = S + t * np.array([1.0, -0.4, -0.6, 0.3, 0.3, 0, 0])
        Ft = yield_function_gradient(St, *p, P, dF)[0]
        assert np.all(np.isfinite(dF))
        assert abs(Ft - F0) < 10 * t
        assert np.abs(dF - d0).max() < 10 * math.sqrt(t) + 1e-12


def polar_convexity_margin(gamma, n=2000):
    """min over the Lode angle of r^2 + 2 r'^2 - r r'' for the deviatoric section r = Gamma^(-1/2)
    with theta = (2/(3 sqrt 3)) cos(3 t) and m from (2.77) (spec 10.5); relative to r^2."""
    t = np.linspace(0, 2 * np.pi / 3, n, endpoint=False)
    h = t[1] - t[0]
    m = 2 / 9 + math.sqrt(3) / (3 * gamma)
    r = (1 + gamma * (2 / (3 * math.sqrt(3))) * np.cos(3 * t)) ** (-m / 2)
    rp = (np.roll(r, -1) - np.roll(r, 1)) / (2 * h)
    rpp = (np.roll(r, -1) - 2 * r + np.roll(r, 1)) / h ** 2
    return np.min((r ** 2 + 2 * rp ** 2 - r * rpp) / r ** 2)


def test_deviatoric_section_convex_in_the_used_gamma_range():
    """Spec 10.5: convex for the Hostun range gamma in [1, 1.55] with m(gamma) of (2.77);
    not convex any more at gamma = 2 (why parameters.py warns above 1.75)."""
    for g in (1.0, 1.2, 1.55):
        assert polar_convexity_margin(g) > -1e-4
    assert polar_convexity_margin(2.0) < -1e-2
