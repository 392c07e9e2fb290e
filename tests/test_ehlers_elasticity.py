"""Elastic law (2.70)-(2.75) through the full Gauss-point update (spec 10 items 1, 2)."""
import numpy as np
import pytest

from cosserat_fenicsx.materials.ehlers import EhlersMaterial
from cosserat_fenicsx.materials.ehlers.elasticity import volumetric_energy

pytestmark = pytest.mark.serial

MU, LMBDA, L_C = 91.0e6, 49.4e6, 3e-3
N0, NMAX = 0.604, 0.635
C0 = 1.0 - NMAX / N0  # eps_crit at eps_p^V = 0, (2.70): -0.0513


def linear_micropolar(g, mu, lmbda, mu_c, l_c):
    """sig = 2 mu eps_sym + lambda tr(eps) I + 2 mu_c eps_skw, m = 2 mu_c l_c^2 kappa (plane strain)."""
    e11, e22, e12, e21, k31, k32 = g
    tr = e11 + e22
    sym, skw = 0.5 * (e12 + e21), 0.5 * (e12 - e21)
    return np.array([2 * mu * e11 + lmbda * tr, 2 * mu * e22 + lmbda * tr,
                     2 * mu * sym + 2 * mu_c * skw, 2 * mu * sym - 2 * mu_c * skw,
                     2 * mu_c * l_c ** 2 * k31, 2 * mu_c * l_c ** 2 * k32])


def run(mat, g, state=None, dt=1.0):
    g = np.atleast_2d(np.asarray(g, dtype=float))
    n = g.shape[0]
    st = mat.initial_state(n) if state is None else state
    f, t, s = np.zeros((n, 6)), np.zeros((n, 6, 6)), np.zeros((n, mat.state_size))
    mat.update(g, dt, st, f, t, s)
    return f, t, s


def run7(mat, E, state=None, dt=1.0):
    """Generalised 7-component path [eps11, eps22, eps33, eps12, eps21, kappa31, kappa32]."""
    E = np.atleast_2d(np.asarray(E, dtype=float))
    st = mat.initial_state(1) if state is None else state
    f, t, s = np.zeros((1, 7)), np.zeros((1, 7, 7)), np.zeros((1, mat.state_size))
    mat.update_generalised(E, dt, st, f, t, s)
    return f[0], t[0], s[0]


def unloaded_point(mat, p_max=100e3, p_unload=70e3):
    """Consolidated to p_max (on the yield surface), then unloaded to p_unload: strictly inside."""
    from cosserat_fenicsx.materials.ehlers.material_point import MaterialPoint, consolidate
    pt = MaterialPoint(mat)
    consolidate(pt, -p_max, n_steps=10)
    consolidate(pt, -p_unload, n_steps=2)
    assert pt.state[0, 13] < 0.0
    return pt


@pytest.mark.parametrize("mu_c", [MU, 0.3 * MU])
def test_small_strain_limit_is_linear_micropolar_elasticity(mu_c):
    """Small, nearly isotropic compression of the virgin point (inside the initial surface,
    |I| < 0.24 MN/m^2): elastic, and (2.73) -> Hooke as x -> 0 with a relative deviation
    ~ |x / eps_crit|; the exact (2.73)/(2.74) values to round-off; tangent = C_e."""
    mat = EhlersMaterial.hostun(mu_c=mu_c)
    a = 1e-5
    E = np.array([-a, -1.05 * a, -0.95 * a, 0.02 * a, -0.01 * a, 0.3, -0.2])  # kappa in 1/m
    f, t, s = run7(mat, E)
    assert s[11] == 0.0 and s[13] < 0.0, "expected an elastic step (Lambda = 0, F < 0)"
    x = E[:3].sum()
    e_sym, e_skw = 0.5 * (E[3] + E[4]), 0.5 * (E[3] - E[4])
    lin = np.array([2 * MU * E[0] + LMBDA * x, 2 * MU * E[1] + LMBDA * x, 2 * MU * E[2] + LMBDA * x,
                    2 * MU * e_sym + 2 * mu_c * e_skw, 2 * MU * e_sym - 2 * mu_c * e_skw,
                    2 * mu_c * L_C ** 2 * E[5], 2 * mu_c * L_C ** 2 * E[6]])
    dev = np.abs(f - lin).max() / np.abs(lin).max()
    assert dev < 3 * abs(x / C0)  # first-order deviation of lambda c/(c - x)
    exact = lin.copy()
    exact[:3] += LMBDA * x * (C0 / (C0 - x) - 1.0)
    np.testing.assert_allclose(f, exact, rtol=1e-12, atol=1e-12)
    kb = LMBDA * C0 ** 2 / (C0 - x) ** 2
    np.testing.assert_allclose(t[:3, :3], 2 * MU * np.eye(3) + kb, rtol=1e-12)
    np.testing.assert_allclose(t[3:5, 3:5], [[MU + mu_c, MU - mu_c], [MU - mu_c, MU + mu_c]], rtol=1e-12)
    np.testing.assert_allclose(np.diag(t)[5:], 2 * mu_c * L_C ** 2, rtol=1e-12)
    assert np.abs(t[:5, 5:]).max() == 0.0 and np.abs(t[5:, :5]).max() == 0.0


def test_plane_strain_elastic_step_is_linear_in_the_increment():
    """FE layout, elastic unloading increment from a confined state: the response is the
    elastic law with the tangent at the current x, and the FE tangent is the eps33 = 0 sub-block."""
    mat = EhlersMaterial.hostun(mu_c=0.5 * MU)
    pt = unloaded_point(mat)
    st = pt.state.copy()
    E0 = pt.strain.copy()
    f0, t0, _ = run7(mat, E0, st)
    d = np.array([1e-8, -2e-8, 0.0, 3e-8, -1e-8, 0.5, 0.2])
    f1, _, s1 = run7(mat, E0 + d, st)
    assert s1[11] == 0.0
    np.testing.assert_allclose(f1 - f0, t0 @ d, rtol=1e-5, atol=1e-6)
    # FE plane-strain layout: exactly the rows/columns (11, 22, 12, 21, 31, 32) of the 7x7 tangent
    idx = [0, 1, 3, 4, 5, 6]
    g = E0[idx][None, :]
    st6 = st.copy()
    st6[0, 14 + 2] = 0.0  # the FE path has eps33 = 0; make the committed strain consistent
    E7 = E0.copy()
    E7[2] = 0.0
    f7, t7, _ = run7(mat, E7, st6)
    f, t, s = run(mat, g, st6)
    np.testing.assert_allclose(f[0], f7[idx], rtol=1e-12)
    np.testing.assert_allclose(t[0], t7[np.ix_(idx, idx)], rtol=1e-12)
    np.testing.assert_allclose(s[0, 12], f7[2], rtol=1e-12)


def test_kinematic_signs_uniform_rotation():
    """Spec 10.1 inside the yield surface: phi = const with u = 0 gives eps12 = phi, eps21 = -phi
    and sig12 = -sig21 = 2 mu_c phi (restoring); normal stresses unchanged."""
    mat = EhlersMaterial.hostun()
    pt = unloaded_point(mat)
    f0, _, _ = run7(mat, pt.strain, pt.state)
    phi = 1e-7
    E = pt.strain.copy()
    E[3] += phi
    E[4] -= phi
    f, _, s = run7(mat, E, pt.state)
    assert s[11] == 0.0
    np.testing.assert_allclose(f[3] - f0[3], 2 * MU * phi, rtol=1e-9)
    np.testing.assert_allclose(f[4] - f0[4], -2 * MU * phi, rtol=1e-9)
    np.testing.assert_allclose(f[:3], f0[:3], rtol=1e-12)


def test_bulk_stiffness_and_energy():
    """d sig^V/d eps^V at 0 equals K = lambda + 2 mu/3 = 110.1 MN/m^2; the corrected energy
    psi_vol = -lambda c{x + c ln(1 - x/c)} differentiates to the volumetric stress of (2.73);
    the bulk term lambda c^2/(c - x)^2 blows up at the compression point."""
    lam = LMBDA / 1e6
    c = C0
    for x in (-1e-3, -0.02, -0.05):
        h = 1e-7
        dpsi = (volumetric_energy(x + h, c, lam) - volumetric_energy(x - h, c, lam)) / (2 * h)
        np.testing.assert_allclose(dpsi, lam * c * x / (c - x), rtol=1e-6)
    mat = EhlersMaterial.hostun()
    _, t, _ = run(mat, np.zeros(6))
    K = (t[0][0, 0] + t[0][0, 1] + LMBDA) / 3.0  # 3D bulk: (C1111 + 2 C1122)/3 with C1133 = C1122 = lambda
    np.testing.assert_allclose(K, LMBDA + 2 * MU / 3, rtol=1e-12)
    assert abs(K / 1e6 - 110.07) < 0.01
    x = 0.999 * c
    assert LMBDA * c ** 2 / (c - x) ** 2 > 1e5 * LMBDA


def test_compression_point_is_a_clear_error():
    """An elastic strain beyond eps_crit has no stress (n^S would exceed n_max^S): clear error."""
    from cosserat_fenicsx.materials.ehlers import MaterialPointError
    mat = EhlersMaterial.hostun()
    st = mat.initial_stress_state(-100e3, 1)
    with pytest.raises(MaterialPointError, match="compression point"):
        run(mat, [-0.04, -0.04, 0, 0, 0, 0], st)
