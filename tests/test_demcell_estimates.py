"""demcell.estimates against independent computations (fast, numpy only)."""
import math

import numpy as np
import pytest

from demcell.estimates import (cosserat_moduli_003, hexagonal_moduli, isotropic_operator,
                               periodic_bending_estimate, uniform_strain_moduli)


def hexagonal_cell(nx, ny, R):
    """Equal discs in contact on a triangular lattice in a periodic rectangle (ny even).
    Returns reference lever positions X (from the cell centre), contacts (i, j, D), h_ref."""
    L = np.array([2 * R * nx, math.sqrt(3) * R * ny])
    h = np.diag(L)
    pos = np.array([[2 * R * (i + 0.5 * (j % 2)) + 0.3 * R, math.sqrt(3) * R * j + 0.2 * R]
                    for j in range(ny) for i in range(nx)])
    s = pos / L
    contacts = []
    for i in range(len(s)):
        for j in range(i + 1, len(s)):
            n = -np.round(s[j] - s[i])
            D = h @ (s[j] - s[i] + n)
            if abs(np.linalg.norm(D) - 2 * R) < 1e-9 * R:
                contacts.append((i, j, D, n))
    X = (s - 0.5) @ h.T
    return X, contacts, h


def affine_operator(X, contacts, h, kn, ks, kr, R, copy="midpoint"):
    """6x6 d(sigma, m)/d(eps, kappa) at phi = 0 (FE callback order) of the affine state, from
    the spec's contact law and flux formulas, one unit input at a time (no pre-stress).

    copy: which periodic copy of a boundary-crossing contact is used. "labels" = the spec as
    written (disc i in the cell, j's nearest image, i < j); "midpoint" = the copy whose
    contact point lies in the reference cell (disc i shifted by -m, j by n - m,
    m = floor(s_mid)). The rotation field is not periodic, so the copies are not equivalent."""
    area = abs(np.linalg.det(h))
    hinv = np.linalg.inv(h)
    C = np.zeros((6, 6))
    for col in range(6):
        g = np.zeros((2, 2))
        kappa = np.zeros(2)
        if col < 4:
            g[[(0, 0), (1, 1), (0, 1), (1, 0)][col]] = 1.0
        else:
            kappa[col - 4] = 1.0
        theta = X @ kappa                               # theta_p = phi + kappa . X_p, phi = 0
        sigma = np.zeros((2, 2))
        m = np.zeros(2)
        for i, j, D, n in contacts:
            nrm = D / np.linalg.norm(D)
            t = np.array([-nrm[1], nrm[0]])
            a = R                                       # a_i = a_j = R (no overlap)
            shift = np.zeros(2)
            if copy == "midpoint":
                shift = np.floor(hinv @ (X[i] + 0.5 * D) + 0.5)
            Xi = X[i] - h @ shift                       # lever positions of the copy used
            Xj = Xi + D
            dd = g @ D
            th_i = theta[i] - kappa @ (h @ shift)       # rotation jump across the images
            th_j = theta[j] + kappa @ (h @ (n - shift))
            dut = dd @ t - a * th_i - a * th_j
            fn = -kn * (dd @ nrm)                       # overlap decreases when d lengthens
            fs = -ks * dut
            mr = -kr * (th_j - th_i)
            f = fn * nrm + fs * t
            sigma -= np.outer(f, D) / area
            m += (fs * (a * Xi + a * Xj) - mr * D) / area
        C[:, col] = [sigma[0, 0], sigma[1, 1], sigma[0, 1], sigma[1, 0], m[0], m[1]]
    return C


@pytest.mark.parametrize("ks", [0.0, 0.3, 1.0])
def test_hexagonal_moduli_against_lattice_sum(ks):
    kn, kr, R = 2.0, 0.05, 0.5
    X, contacts, h = hexagonal_cell(8, 8, R)
    assert len(contacts) == 3 * 64
    C = affine_operator(X, contacts, h, kn, ks, kr, R)
    est = hexagonal_moduli(kn, ks, kr, R, cell=h)
    iso = isotropic_operator(est["lambda_"], est["G"], est["mu_c"], 0.0)
    scale = np.abs(C[:4, :4]).max()
    assert np.abs(C[:4, :4] - iso[:4, :4]).max() < 1e-12 * scale
    # skew stress: sigma12 - sigma21 = 2 mu_c (eps12 - eps21)
    assert abs((C[2, 2] - C[3, 2]) - 2 * est["mu_c"]) < 1e-12 * scale
    assert est["lambda_"] == pytest.approx(math.sqrt(3) / 4 * (kn - ks), rel=1e-14)
    if ks == 0.0:   # a linear rotation field is exact: B = sqrt(3) kr, no cell-size term
        assert np.abs(C[4:, 4:] - math.sqrt(3) * kr * np.eye(2)).max() < 1e-12 * kr
        assert hexagonal_moduli(kn, ks, kr, R)["bending"] == pytest.approx(math.sqrt(3) * kr, rel=1e-14)
        assert est["bending_exact"]
    else:           # affine bound: discrete contact-midpoint sum vs continuum h h^T / 12
        Bt = est["bending_tensor"]
        assert np.abs(C[4:, 4:] - Bt).max() < 0.01 * Bt.max()
        assert not est["bending_exact"]
        # the spec's label-based copy moves the seam of the rotation jump: another B
        Cl = affine_operator(X, contacts, h, kn, ks, kr, R, copy="labels")
        assert np.abs(Cl[4:, 4:] - Bt).max() > 0.03 * Bt.max()
        # the size term is the energy of the slips l theta(midpoint): grows like L^2
        big = affine_operator(*hexagonal_cell(16, 16, R), kn, ks, kr, R)
        ratio = (big[4, 4] - math.sqrt(3) * kr) / (C[4, 4] - math.sqrt(3) * kr)
        assert ratio == pytest.approx(4.0, rel=0.01)


def test_uniform_strain_moduli_recovers_isotropic_operator():
    lam, G, mu_c, B = 3.0e6, 7.0e6, 2.0e6, 1.5e-2
    C = np.zeros((6, 6))
    # written out by hand from sigma = lambda tr(eps) I + 2 G sym(eps) + 2 mu_c skw(eps), m = B kappa
    C[0, :2] = [lam + 2 * G, lam]
    C[1, :2] = [lam, lam + 2 * G]
    C[2, 2:4] = [G + mu_c, G - mu_c]
    C[3, 2:4] = [G - mu_c, G + mu_c]
    C[4, 4] = C[5, 5] = B
    r = uniform_strain_moduli(C)
    assert r["lambda_"] == pytest.approx(lam, rel=1e-12)
    assert r["G"] == pytest.approx(G, rel=1e-12)
    assert r["mu_c"] == pytest.approx(mu_c, rel=1e-12)
    assert r["bending"] == pytest.approx(B, rel=1e-12)
    assert r["residual"] < 1e-12
    # an anisotropic perturbation shows in the residual, a coupling block in `coupling`
    C2 = C.copy()
    C2[0, 0] *= 1.1
    assert uniform_strain_moduli(C2)["residual_stress"] > 0.01
    C3 = C.copy()
    C3[2, 4] = 0.1 * math.sqrt(np.linalg.norm(C[:4, :4]) * np.linalg.norm(C[4:, 4:]))
    assert uniform_strain_moduli(C3)["coupling"] == pytest.approx(0.1, rel=1e-12)
    # the lattice operator of the hexagonal packing reads back as its closed forms
    X, contacts, h = hexagonal_cell(4, 4, 1.0)
    r = uniform_strain_moduli(affine_operator(X, contacts, h, 1.0, 0.0, 0.2, 1.0))
    assert r["G"] == pytest.approx(math.sqrt(3) / 4, rel=1e-12)
    assert r["bending"] == pytest.approx(math.sqrt(3) * 0.2, rel=1e-12)


def test_cosserat_moduli_003_hand_case():
    # N = 12 contacts, r = 0.05 m, V = 0.06 m^2, kN = 2.5e8, ks = 5e7 N/m (003 Table 1),
    # k_r = 1e6 N/m, k_omega = 700 N m/rad, L = 0.3 m. By hand: N r^2 / (2V) = 0.25,
    # G = 0.25 (5e8 + 1.5e8) = 1.625e8, lambda = 0.25 * 2e8 = 5e7,
    # G_c = 2 * 12 * 0.0025 / 0.18 * 5e7 = 1/3 * 5e7,
    # l_c^2 = 4 (2 * 0.09 * 5e7 + 0.0025 * 1e6 + 700) / (3 * 3e8) = 4 * 9003200 / 9e8.
    r = cosserat_moduli_003(12, 0.05, 0.06, 2.5e8, 5e7, kr=1e6, k_omega=700.0, length=0.3)
    assert r["G"] == pytest.approx(1.625e8, rel=1e-14)
    assert r["lambda_"] == pytest.approx(5e7, rel=1e-14)
    assert r["G_c"] == pytest.approx(5e7 / 3, rel=1e-14)
    assert r["l_c"] == pytest.approx(math.sqrt(4 * 9003200 / 9e8), rel=1e-14)
    with pytest.raises(ValueError):
        cosserat_moduli_003(12, 0.05, 0.06, 2.5e8, 5e7)          # l_c needs L when ks > 0


def test_003_on_hexagonal_lattice_against_closed_forms():
    """N = 3 contacts and V = 2 sqrt(3) R^2 per disc: lambda agrees, G and G_c do not."""
    kn, ks, R = 1.0, 0.25, 1.0
    r = cosserat_moduli_003(3, R, 2 * math.sqrt(3) * R * R, kn, ks, length=10.0)
    hx = hexagonal_moduli(kn, ks, 0.0, R)
    assert r["lambda_"] == pytest.approx(hx["lambda_"], rel=1e-14)
    assert r["G"] / hx["G"] == pytest.approx((2 * kn + 3 * ks) / (kn + ks), rel=1e-14)
    assert r["G_c"] / hx["mu_c"] == pytest.approx(2 / 3, rel=1e-14)


def fd_periodic_bending(B0, mu_c, G, L, n=400):
    """Independent check of periodic_bending_estimate: 1D periodic Cosserat strip (fields of
    x1 only) by finite differences, theta = kappa x + periodic, v = u2 periodic, mean theta
    held at zero; energy density G v'^2/2 + 2 mu_c (theta - v'/2)^2 + B0 theta'^2/2."""
    hx = L / n
    x = -L / 2 + (np.arange(n) + 0.5) * hx
    kappa = 1.0
    # unknowns: theta~ (n), v (n); edge k joins node k and k+1 (the last through the image)
    nu = 2 * n
    Dm = np.zeros((n, n))          # edge difference of a periodic field
    Av = np.zeros((n, n))          # edge average
    for k in range(n):
        Dm[k, k], Dm[k, (k + 1) % n] = -1 / hx, 1 / hx
        Av[k, k], Av[k, (k + 1) % n] = 0.5, 0.5
    th_lin = kappa * x
    th_lin_next = np.roll(th_lin, -1)
    th_lin_next[-1] += kappa * L   # the image of node 0 carries the rotation jump kappa L
    d_lin = (th_lin_next - th_lin) / hx
    a_lin = 0.5 * (th_lin_next + th_lin)
    # energy = sum_edges hx [G/2 (Dm v)^2 + 2 mu_c (Av th + a_lin - (Dm v)/2)^2 + B0/2 (Dm th + d_lin)^2]
    Zt, Zv = np.zeros((n, n)), np.zeros((n, n))
    S = np.hstack([Av, -0.5 * Dm])         # skew strain rows
    Gv = np.hstack([Zt, Dm])
    Bt = np.hstack([Dm, Zv])
    K = hx * (G * Gv.T @ Gv + 4 * mu_c * S.T @ S + B0 * Bt.T @ Bt)
    rhs = -hx * (4 * mu_c * S.T @ a_lin + B0 * Bt.T @ d_lin)
    # constraints: mean theta~ = 0, v[0] = 0 (rigid translation)
    Cn = np.zeros((2, nu))
    Cn[0, :n] = 1.0
    Cn[1, n] = 1.0
    M = np.block([[K, Cn.T], [Cn, np.zeros((2, 2))]])
    sol = np.linalg.solve(M, np.concatenate([rhs, [0.0, 0.0]]))[:nu]
    th, v = sol[:n], sol[n:]
    skew = Av @ th + a_lin - 0.5 * Dm @ v
    W = hx * np.sum(0.5 * G * (Dm @ v) ** 2 + 2 * mu_c * skew ** 2 + 0.5 * B0 * (Dm @ th + d_lin) ** 2)
    return 2 * W / (L * kappa ** 2)


@pytest.mark.parametrize("L_over_ell", [0.3, 2.0, 10.0])
def test_periodic_bending_estimate_against_finite_differences(L_over_ell):
    B0, mu_c, G = 1.0, 3.0, 5.0
    ell = math.sqrt(B0 / (4 * mu_c * G / (G + mu_c)))
    L = L_over_ell * ell
    assert periodic_bending_estimate(B0, mu_c, G, L) == pytest.approx(
        fd_periodic_bending(B0, mu_c, G, L), rel=2e-3)
    # limits quoted in the docstring
    mu_eff = mu_c * G / (G + mu_c)
    assert periodic_bending_estimate(B0, mu_c, G, 1e-3 * ell) == pytest.approx(
        B0 + mu_eff * (1e-3 * ell) ** 2 / 3, rel=1e-12)
    assert periodic_bending_estimate(B0, mu_c, G, 100 * ell) == pytest.approx(
        100 * ell * math.sqrt(B0 * mu_eff), rel=1e-12)
