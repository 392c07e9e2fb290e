"""Consistent tangent (3.36)-(3.38) against central finite differences of the full update.

The finite differences perturb the *whole* Gauss-point update (local Newton of Table 3.1
included), so they check the tangent against the stress actually returned, including
the eps_crit(eps_p^V) chain (2.70), the hardening rows (2.82) and the sigma-kappa /
m-eps coupling that k_mu != 0 brings through the potential (2.78).
"""
import numpy as np
import pytest

from cosserat_fenicsx.materials.ehlers import EhlersMaterial
from cosserat_fenicsx.materials.ehlers.material_point import (MaterialPoint, consolidate,
                                                              finite_difference_tangent)

pytestmark = pytest.mark.serial

TOL = 2e-6  # relative (max-norm) tangent error; FD truncation/round-off is ~1e-8 here


def rel_err(C, C_fd):
    return np.abs(C - C_fd).max() / np.abs(C_fd).max()


def sheared_point(material, confining, axial, n_steps, shear=0.0, curvature=0.0):
    """Triaxial path to an axial strain, then an optional micropolar shear/curvature increment
    so that skew stress and couple stress are non-zero (they are zero in homogeneous tests)."""
    pt = MaterialPoint(material)
    consolidate(pt, -confining, n_steps=20)
    e0 = pt.strain[0]
    mask = np.array([False, True, True, False, False, False, False])
    for k in range(1, n_steps + 1):
        tgt = np.zeros(7)
        tgt[0] = e0 + axial * k / n_steps
        tgt[1] = tgt[2] = -confining
        pt.advance(mask, tgt)
    E = pt.strain.copy()
    E[3] += shear
    E[4] -= 0.3 * shear
    E[5] += curvature
    E[6] -= 0.5 * curvature
    return E, pt.state[0].copy()


CASES = {
    # name: (material overrides, confining, axial strain, steps, shear, curvature, expected regime)
    "elastic_unloading": (dict(), 100e3, -0.02, 20, 0.0, 0.0, "elastic"),
    "hardening_contractant": (dict(), 300e3, -0.01, 10, 2e-4, 0.05, "plastic"),
    "softening_dilatant": (dict(), 100e3, -0.12, 60, 2e-4, 0.05, "plastic"),
    "hardening_k_mu": (dict(k_mu=2e4), 300e3, -0.01, 10, 2e-4, 0.5, "plastic"),
    "softening_k_mu": (dict(k_mu=2e4), 100e3, -0.12, 60, 2e-4, 0.5, "plastic"),
    "rate_independent_eta0": (dict(eta=0.0), 300e3, -0.02, 10, 1e-4, 0.1, "plastic"),
}


@pytest.mark.parametrize("name", list(CASES))
def test_tangent_matches_finite_differences(name):
    over, p, axial, steps, shear, curv, regime = CASES[name]
    mat = EhlersMaterial.hostun(**over)
    E, st = sheared_point(mat, p, axial, steps, shear, curv)
    if regime == "elastic":
        E[0] += 2e-4  # unload axially: inside the yield surface
    else:
        E[0] -= 2e-4  # keep loading
    C, C_fd = finite_difference_tangent(mat, E, st)
    err = rel_err(C, C_fd)
    print(f"{name}: relative tangent error {err:.2e}")
    assert err < TOL, f"{name}: tangent error {err:.3e}\n{C}\n{C_fd}"
    # the regime is the one intended: the elastic tangent is the block-diagonal C_e
    coupling = np.abs(C[:5, 5:]).max() + np.abs(C[5:, :5]).max()
    if regime == "elastic":
        assert coupling == 0.0
    elif over.get("k_mu", 0.0) > 0:
        # sigma-kappa and m-eps coupling through k_mu m.m in Phi_G (spec 5)
        assert np.abs(C[:5, 5:]).max() > 1e-6 * np.abs(C[:5, :5]).max() * mat.parameters.l_c
        assert np.abs(C[5:, :5]).max() > 0.0
    else:
        assert coupling == 0.0


def test_tangent_near_compression_point():
    """Strong compaction: the eps_crit(eps_p^V) chain term (2.70) is large here."""
    mat = EhlersMaterial.hostun()
    pt = MaterialPoint(mat)
    consolidate(pt, [-4.0e6, -3.6e6, -3.6e6], n_steps=40)
    st = pt.state[0].copy()
    epv = st[:3].sum()
    E = pt.strain.copy()
    E[:3] -= 2e-5
    C, C_fd = finite_difference_tangent(mat, E, st, h=1e-8)
    err = rel_err(C, C_fd)
    print(f"near compression point (eps_p^V = {epv:.4f}): relative tangent error {err:.2e}")
    assert err < TOL


def test_plane_strain_fe_layout_tangent():
    """The 6-component FE callback returns the plane-strain (eps33 = 0) sub-block, d flux/d gradient."""
    mat = EhlersMaterial.hostun(k_mu=1e4)
    st = mat.initial_stress_state(-200e3, 1)
    g = np.array([[-3e-3, 1e-3, 4e-4, 1e-4, 0.2, -0.1]])

    def run(gg):
        f = np.zeros((1, 6))
        t = np.zeros((1, 6, 6))
        s = np.zeros((1, mat.state_size))
        mat.update(gg, 1.0, st, f, t, s)
        return f[0], t[0], s[0]

    f, C, s = run(g)
    assert s[11] > 0.0  # plastic
    C_fd = np.zeros((6, 6))
    for j in range(6):
        h = 1e-7 if j < 4 else 1e-7 / mat.parameters.l_c
        gp, gm = g.copy(), g.copy()
        gp[0, j] += h
        gm[0, j] -= h
        C_fd[:, j] = (run(gp)[0] - run(gm)[0]) / (2 * h)
    err = rel_err(C, C_fd)
    print(f"FE layout: relative tangent error {err:.2e}")
    assert err < TOL


def test_local_and_driver_newton_converge_quadratically():
    """Mixed-control Newton of the driver uses the consistent tangent: quadratic convergence
    (e_{k+1} <= K e_k^2 with a moderate K) in a plastic triaxial step."""
    mat = EhlersMaterial.hostun()
    pt = MaterialPoint(mat)
    consolidate(pt, -300e3, n_steps=10)
    mask = np.array([False, True, True, False, False, False, False])
    tgt = np.zeros(7)
    tgt[0] = pt.strain[0] - 5e-3
    tgt[1] = tgt[2] = -300e3
    pt.tangent = None  # no predictor: start the Newton far from the solution
    pt.step(mask, tgt)
    r = np.array(pt.newton_residuals[-1]) / 300e3
    print("driver Newton residuals (relative):", r)
    assert len(r) <= 8
    big = r[:-1] > 1e-9
    rates = np.log(r[1:][big[:len(r) - 1]]) / np.log(r[:-1][big])
    assert rates.size and rates[-1] > 1.7, rates
