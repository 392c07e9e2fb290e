"""Stiff and extreme cases at the Gauss-point level, input validation,
purity of the update and the import-lightness of the materials package."""
import math
import subprocess
import sys

import numpy as np
import pytest

from cosserat_fenicsx.materials.ehlers import EhlersMaterial, MaterialPointError
from cosserat_fenicsx.materials.ehlers.material_point import (MaterialPoint, consolidate,
                                                              finite_difference_tangent)

pytestmark = pytest.mark.serial
MU = 91.0e6


def run(mat, g, state, dt=1.0):
    g = np.atleast_2d(np.asarray(g, dtype=float))
    n = g.shape[0]
    f, t, s = np.zeros((n, 6)), np.zeros((n, 6, 6)), np.zeros((n, mat.state_size))
    mat.update(g, dt, state, f, t, s)
    return f, t, s


def finite(*arrays):
    return all(np.all(np.isfinite(a)) for a in arrays)


@pytest.fixture(scope="module")
def prestressed():
    mat = EhlersMaterial.hostun()
    return mat, mat.initial_stress_state(-100e3, 1)


# ----------------------------------------------------------------- extreme states
def test_tensile_state_is_a_clear_error(prestressed):
    mat, st = prestressed
    with pytest.raises(MaterialPointError, match="tensile state") as err:
        run(mat, [[2e-3, 2e-3, 0, 0, 0, 0]], st)
    assert err.value.point == 0
    with pytest.raises(MaterialPointError, match="tensile"):
        run(mat, [[1e-4, 0, 0, 0, 0, 0]], mat.initial_state(1))  # virgin sand pulled


def test_error_names_the_failing_point(prestressed):
    mat, st = prestressed
    g = np.zeros((5, 6))
    g[3] = [2e-3, 2e-3, 0, 0, 0, 0]
    with pytest.raises(MaterialPointError, match="at point 3") as err:
        run(mat, g, np.repeat(st, 5, axis=0))
    assert list(np.flatnonzero(err.value.codes)) == [3]


def test_compression_point(prestressed):
    """Near eps_crit (2.70) the update still converges with finite, very stiff tangent;
    beyond it (total compaction n^S > n_max^S) the message names the compression point."""
    mat, st = prestressed
    f, t, s = run(mat, [[-0.02, -0.02, 0, 0, 0, 0]], st)  # eps^V = -0.04, close to the limit ~ -0.05
    assert finite(f, t, s) and f[0, 0] < -3e6  # 40 x the initial pressure for 4 % compaction
    with pytest.raises(MaterialPointError, match="compression point"):
        run(mat, [[-0.03, -0.03, 0, 0, 0, 0]], st)  # eps^V = -0.06: no admissible state


def test_too_large_increment_is_substepped(prestressed):
    """A large increment that the local Newton cannot take at once is bisected; the result
    equals the same substeps taken as separate steps (substepping is exact time stepping)."""
    mat, st = prestressed
    g = np.array([[-0.02, -0.02, 0, 0, 0, 0]])
    f, t, s = run(mat, g, st, dt=1.0)
    n = int(s[0, 22])
    assert n >= 2, "expected substepping for this increment"
    st_k = st.copy()
    for k in range(1, n + 1):
        fk, tk, sk = run(mat, g * k / n, st_k, dt=1.0 / n)
        st_k = sk
    np.testing.assert_allclose(fk, f, rtol=1e-8)
    np.testing.assert_allclose(sk[0, :11], s[0, :11], rtol=1e-8, atol=1e-14)


@pytest.mark.parametrize("E", [[-0.023, -0.023, 0, 0, 0, 0, 0], [-0.015, -0.015, -0.01, 1e-3, -2e-4, 0.5, 0.2]])
def test_tangent_is_exact_under_substepping(E):
    """The history sensitivity is carried through the substeps: FD of the full (substepped)
    update matches the returned tangent."""
    mat = EhlersMaterial.hostun(k_mu=1e4)
    st = mat.initial_stress_state(-100e3, 1)
    f, t, s = np.zeros((1, 7)), np.zeros((1, 7, 7)), np.zeros((1, mat.state_size))
    mat.update_generalised(np.array([E]), 1.0, st, f, t, s)
    assert s[0, 22] >= 2, "expected substepping"
    C, C_fd = finite_difference_tangent(mat, np.array(E), st[0], h=1e-8)
    err = np.abs(C - C_fd).max() / np.abs(C_fd).max()
    print(f"{int(s[0, 22])} substeps: relative tangent error {err:.2e}")
    assert err < 1e-6


@pytest.mark.parametrize("l_c", [1e-9, 10.0])
def test_tiny_and_huge_internal_length(l_c):
    mat = EhlersMaterial.hostun(l_c=l_c, k_mu=1.0 / max(l_c, 1e-3) ** 2)
    st = mat.initial_stress_state(-100e3, 1)
    g = np.array([[-2e-4, 0.5e-4, 3e-5, 0, 1e-3, -2e-3]])
    f, t, s = run(mat, g, st)
    assert finite(f, t, s) and s[0, 11] > 0
    assert abs(f[0, 5]) <= 2 * MU * l_c ** 2 * 2e-3 * (1 + 1e-9)  # |m| <= elastic trial
    E = np.array([g[0, 0], g[0, 1], 0.0, g[0, 2], g[0, 3], g[0, 4], g[0, 5]])
    C, C_fd = finite_difference_tangent(mat, E, st[0])
    assert np.abs(C - C_fd).max() <= 1e-5 * np.abs(C_fd).max()


@pytest.mark.parametrize("mu_c", [0.0, 1e-6 * MU])
def test_vanishing_cosserat_modulus(mu_c):
    """mu_c -> 0: the skew stress vanishes (sig12 = sig21), no singular local Jacobian."""
    mat = EhlersMaterial.hostun(mu_c=mu_c)
    st = mat.initial_stress_state(-100e3, 1)
    f, t, s = run(mat, [[-1e-3, 0, 4e-4, -2e-4, 0.1, 0]], st)
    assert finite(f, t, s) and s[0, 11] > 0
    assert abs(f[0, 2] - f[0, 3]) <= 1e-6 * abs(f[0, 0]) + 4 * mu_c * 6e-4


def test_tiny_eta_relative_to_loading_time(prestressed):
    """eta = 1e-12 s with a step of 1e3 s: the stiff viscoplastic limit; F ~ 0 after the update."""
    mat = EhlersMaterial.hostun(eta=1e-12)
    st = mat.initial_stress_state(-100e3, 1)
    f, t, s = run(mat, [[-5e-3, 1e-3, 0, 0, 0, 0]], st, dt=1e3)
    assert finite(f, t, s) and s[0, 11] > 0
    assert 0.0 <= s[0, 13] < 1e-6  # F [Pa]
    f2, _, _ = run(EhlersMaterial.hostun(eta=0.0), [[-5e-3, 1e-3, 0, 0, 0, 0]], st, dt=1e3)
    np.testing.assert_allclose(f, f2, rtol=1e-9)


def test_non_finite_input_is_an_error(prestressed):
    mat, st = prestressed
    with pytest.raises(MaterialPointError, match="non-finite"):
        run(mat, [[np.nan, 0, 0, 0, 0, 0]], st)
    bad = st.copy()
    bad[0, 7] = np.inf
    with pytest.raises(MaterialPointError, match="non-finite"):
        run(mat, [[0, 0, 0, 0, 0, 0]], bad)


# ------------------------------------------------------------------- the callback contract
def test_update_is_pure_and_does_not_touch_state_old(prestressed):
    mat, st = prestressed
    st2 = np.repeat(st, 3, axis=0)
    keep = st2.copy()
    g = np.array([[-3e-3, 1e-3, 2e-4, 1e-4, 0.1, 0.0]] * 3)
    a = run(mat, g, st2)
    b = run(mat, g, st2)
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)
    np.testing.assert_array_equal(st2, keep)


def test_classical_switch():
    mat = EhlersMaterial.hostun(micropolar=False)
    p = mat.parameters
    assert p.mu_c == 0.0 and p.k_sigma == 0.0 and p.k_mu == 0.0
    st = mat.initial_stress_state(-100e3, 1)
    f, t, s = run(mat, [[-1e-3, 0, 3e-4, 1e-4, 5.0, 2.0]], st)
    assert f[0, 4] == 0.0 and f[0, 5] == 0.0 and np.abs(t[0][4:, :]).max() == 0.0
    assert f[0, 2] == pytest.approx(f[0, 3], rel=1e-12)


def test_shapes_and_dt_validated(prestressed):
    mat, st = prestressed
    with pytest.raises(ValueError, match="gradients"):
        run(mat, np.zeros((1, 5)), st)
    with pytest.raises(ValueError, match="dt"):
        run(mat, np.zeros((1, 6)), st, dt=0.0)
    with pytest.raises(ValueError, match="state_old"):
        run(mat, np.zeros((2, 6)), st)
    f, t = np.zeros((1, 6)), np.zeros((1, 6, 6))
    with pytest.raises(ValueError, match="state_new"):
        mat.update(np.zeros((1, 6)), 1.0, st, f, t, st)


@pytest.mark.parametrize("kw, name", [
    (dict(foo=1.0), "foo"), (dict(mu=-1.0), "mu"), (dict(lmbda=-70e6), "lmbda"), (dict(mu_c=-1.0), "mu_c"),
    (dict(l_c=-1e-3), "l_c"), (dict(n0=0.64), "n0"), (dict(n_max=1.2), "n_max"),
    (dict(gamma0=3.0), "gamma0"), (dict(gamma_star=0.0), "gamma_star"), (dict(eta=-1.0), "eta"),
    (dict(delta0=0.0), "delta0"), (dict(epsilon_star=-1.0), "epsilon_star"), (dict(psi1=0.0), "psi1"),
    (dict(k_sigma=-1.0), "k_sigma"), (dict(k_mu=-1.0), "k_mu"), (dict(r=0.5), "r"),
    (dict(sigma_ref=0.0), "sigma_ref"), (dict(beta0=math.nan), "beta0"), (dict(mu="91e6"), "mu"),
    (dict(hardening_rows="T3.1"), "hardening_rows"),
])
def test_bad_parameters_raise_value_error_naming_them(kw, name):
    with pytest.raises(ValueError, match=name):
        EhlersMaterial(**kw)


def test_gamma_beyond_convexity_warns():
    with pytest.warns(UserWarning, match="convex"):
        EhlersMaterial(gamma_star=2.0)


def test_hostun_defaults_reading_h1():
    p = EhlersMaterial.hostun().parameters
    assert p.mu == 91e6 and p.lmbda == 49.4e6 and p.mu_c == p.mu and p.l_c == 3e-3
    assert p.k_sigma == 10.0 and p.k_mu == 0.0 and p.n0 == 0.604 and p.n_max == 0.635
    # H1: thesis delta, epsilon are the reciprocals of the T6.4 values (m^2/MN)
    assert p.delta0 == pytest.approx(100e6) and p.delta_star == pytest.approx(0.629e6, rel=1e-3)
    assert p.epsilon0 == pytest.approx(2.058e6, rel=1e-3) and p.epsilon_star == pytest.approx(86.96e6, rel=1e-3)
    assert p.hardening_rows == "uniform"
    assert EhlersMaterial.hostun(l_c=1e-2).parameters.l_c == 1e-2


def test_materials_package_import_is_light():
    """Importing cosserat_fenicsx.materials must not import Numba (an elastic scene never needs
    it).  Measured relative to the parent package: on Debian 13, dolfinx 0.9 itself imports
    Numba, which is outside this package's control."""
    code = ("import sys, cosserat_fenicsx; before = set(sys.modules); import cosserat_fenicsx.materials; "
            "new = sorted(m for m in set(sys.modules) - before if m.split('.')[0] == 'numba'); "
            "assert not new, new")
    root = __file__.rsplit("/tests/", 1)[0]
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=root)
    assert r.returncode == 0, r.stderr


def test_random_increments_converge_or_are_tensile():
    """Robustness: 1000 random FE-layout increments (strain 1e-5..1e-2, curvature up to ~1 1/m)
    from states along a biaxial path (hardening, peak, softening).  Every point converges, or
    fails as a tensile state (no admissible stress); never 'not converged' or 'singular'."""
    from cosserat_fenicsx.materials.ehlers.errors import STATUS_OK, STATUS_TENSILE
    rng = np.random.default_rng(7)
    mat = EhlersMaterial.hostun(k_mu=1e4)
    pt = MaterialPoint(mat)
    consolidate(pt, -100e3, n_steps=10, plane_strain=True)
    bases = [pt.state[0].copy()]
    mask = np.array([False, True, False, False, False, False, False])
    e0 = pt.strain[0]
    for k in range(1, 41):
        tgt = np.zeros(7)
        tgt[0] = e0 - 0.1 * k / 40
        tgt[1] = -100e3
        pt.advance(mask, tgt)
        if k % 8 == 0:
            bases.append(pt.state[0].copy())
    n = 1000
    st = np.array(bases)[rng.integers(0, len(bases), n)]
    st[:, 16] = 0.0  # FE plane strain: committed total eps33 = 0
    d = rng.normal(size=(n, 6))
    d[:, 4:] *= 100.0
    d *= (10 ** rng.uniform(-5, -2, n) / np.linalg.norm(d[:, :4], axis=1))[:, None]
    g = st[:, [14, 15, 17, 18, 19, 20]] + d
    codes = np.zeros(n, dtype=int)
    try:
        run(mat, g, st)
    except MaterialPointError as e:
        codes = e.codes
    assert set(np.unique(codes)) <= {STATUS_OK, STATUS_TENSILE}
    assert np.mean(codes == STATUS_OK) > 0.9


def test_driver_stops_at_the_compression_point_with_the_cause():
    """Hydrostatic compression towards the compression point (eq. 2.70): with stop_on_failure
    the test ends at the last converged state, names the cause, and keeps the history."""
    from cosserat_fenicsx.materials.ehlers import EhlersMaterial
    from cosserat_fenicsx.materials.ehlers import material_point as mp
    with pytest.raises(MaterialPointError):
        mp.hydrostatic_test(EhlersMaterial.hostun(), 2e7, n_steps=100)
    h = mp.hydrostatic_test(EhlersMaterial.hostun(), 2e7, n_steps=100, stop_on_failure=True)
    assert "compression point" in h["stopped"] and "last converged state" in h["stopped"]
    assert 5 < len(h["mean_stress"]) < 100
    assert np.all(np.isfinite(h["mean_stress"])) and np.all(np.diff(h["mean_stress"]) < 0)
    complete = mp.hydrostatic_test(EhlersMaterial.hostun(), 1e6, n_steps=20, stop_on_failure=True)
    assert complete["stopped"] == "" and len(complete["mean_stress"]) == 20


@pytest.mark.parametrize("kwargs, message", [
    (dict(confining=float("nan")), "confining pressure must be > 0"),
    (dict(confining=-1.0), "confining pressure must be > 0"),
    (dict(axial_strain=0.7), "axial_strain must be in \\(0, 0.5\\)"),
    (dict(n_steps=0), "n_steps must be an integer in \\[1"),
    (dict(dt=float("inf")), "dt must be > 0"),
])
def test_driver_refuses_bad_arguments_before_any_kernel(kwargs, message):
    from cosserat_fenicsx.materials.ehlers import EhlersMaterial
    from cosserat_fenicsx.materials.ehlers import material_point as mp
    with pytest.raises(ValueError, match=message):
        mp.triaxial_test(EhlersMaterial.hostun(), **kwargs)
