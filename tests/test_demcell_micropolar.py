"""The micropolar periodic cell (docs/reference/micropolar_cell.md) against references
nobody here wrote.

* regular hexagonal packing, grain rotations prescribed by the held mean rotation (every disc
  is equivalent, so every disc turns by phi): lattice sums over the six contact directions give
  lambda = sqrt(3)/4 (kn - ks), G = sqrt(3)/4 (kn + ks) and the skew response
  sigma12 - sigma21 = 2 mu_c (eps12 - eps21), mu_c = sqrt(3)/2 ks; with ks = 0 a linear rotation
  field equilibrates every disc, so the bending modulus is exactly sqrt(3) kr;
* the principle of virtual power (Hill-Mandel): at every equilibrium state of a loading path with
  sliding, the virtual power of the contact forces for random admissible rates (affine, micro-
  rotation, curvature, periodic fluctuations and rotation fluctuations with zero force-weighted
  mean) equals |Y| [sigma : (L + e phi_dot) + m . kappa_dot], computed here from the contact
  arrays independently of demcell's homogenization;
* rigid-body invariance: F = R(a) with phi = a loads no contact;
* a free-rotation cell is the micropolar cell whose phi is its own mean grain rotation;
* bad input and extremes.
"""
import math

import numpy as np
import pytest

import demcell as dc
from demcell.interface import RelaxationOptions
from demcell.periodic_cell import rotation

pytestmark = pytest.mark.serial

KN, KS = 1.0e4, 2.0e3
SQ3 = math.sqrt(3.0)


@pytest.fixture(scope="module")
def prepared60():
    """A 60-disc packing after the isotropic stage with friction 0.4 (F = I, free rotations)."""
    law = dc.ContactLaw(kn=KN, ks=KS, friction=0.4)
    st, _ = dc.generate_packing(60, pressure=10.0, law=dc.ContactLaw(kn=KN, ks=KS), seed=3)
    opts = RelaxationOptions(criterion="force", tol=1e-5, check_every=20)
    return dc.reference_cell(st, law, opts, 10.0).state, law, opts


def micropolar(prepared, **opts):
    state, law, options = prepared
    if opts:
        options = RelaxationOptions(**dict(dict(criterion="force", tol=1e-5, check_every=20), **opts))
    return dc.DemCell(state.copy(), law, options, reset_reference=False, rotation_mode="micropolar")


def hex_micropolar(law, nx=6, ny=6):
    st = dc.hexagonal_lattice(nx, ny, radius=0.01, overlap=1e-5)
    opts = RelaxationOptions(tol=1e-12, criterion="energy", check_every=20, max_steps=400_000)
    cell = dc.DemCell(st, law, opts, rotation_mode="micropolar")
    assert cell.solve().converged
    cell.commit()
    return cell


def response(cell, F=None, phi=0.0, kappa=(0.0, 0.0)):
    """(sigma, m) after solving from the committed state."""
    cell.rollback()
    cell.set_deformation(np.eye(2) if F is None else F, rotation=phi, curvature=kappa)
    res = cell.solve()
    assert res.converged, res.message
    h = cell.homogenized()
    return h.cauchy, h.couple_stress


@pytest.mark.parametrize("ks", [KS, 0.0])
def test_hexagonal_lattice_moduli_and_skew_modulus_closed_form(ks):
    law = dc.ContactLaw(kn=KN, ks=ks, friction=math.inf)
    cell = hex_micropolar(law)
    s0, _ = response(cell)
    e = 1e-6
    lam, G, mu_c = SQ3 / 4 * (KN - ks), SQ3 / 4 * (KN + ks), SQ3 / 2 * ks
    ds = (response(cell, F=np.diag([1.0 + e, 1.0]))[0] - s0) / e
    assert ds[0, 0] == pytest.approx(lam + 2 * G, rel=2e-3)
    assert ds[1, 1] == pytest.approx(lam, rel=2e-3, abs=2e-3 * KN)
    # F12 alone: eps12 = e, eps21 = 0 -> sigma12 = (G + mu_c) e, sigma21 = (G - mu_c) e
    ds = (response(cell, F=np.array([[1.0, e], [0.0, 1.0]]))[0] - s0) / e
    assert ds[0, 1] == pytest.approx(G + mu_c, rel=2e-3)
    assert ds[1, 0] == pytest.approx(G - mu_c, rel=2e-3, abs=2e-3 * KN)
    # the micro-rotation alone: eps12 - eps21 = 2 phi, so sigma12 - sigma21 = 4 mu_c phi
    ds = response(cell, phi=e)[0] - s0
    assert (ds[0, 1] - ds[1, 0]) / e == pytest.approx(4 * mu_c, rel=2e-3, abs=2e-3 * KN)
    assert ds[0, 1] + ds[1, 0] == pytest.approx(0.0, abs=2e-3 * KN * e)


def test_hexagonal_lattice_bending_modulus_without_tangential_springs():
    """ks = 0: rolling springs only; the linear field kappa . X balances every disc (the six
    rolling moments cancel in pairs), so m = sqrt(3) kr kappa for any cell size."""
    kr = 0.5
    for nx, ny in ((6, 6), (10, 12)):
        cell = hex_micropolar(dc.ContactLaw(kn=KN, ks=0.0, friction=math.inf, rolling_stiffness=kr), nx, ny)
        _, m0 = response(cell)
        k = 1e-4 / float(np.abs(cell.state.h_ref).sum(axis=0).max())
        for direction in ((1.0, 0.0), (0.0, 1.0)):
            _, m = response(cell, kappa=k * np.array(direction))
            dm = (m - m0) / k
            assert dm @ np.array(direction) == pytest.approx(SQ3 * kr, rel=1e-3)
            assert abs(dm @ np.array(direction[::-1])) < 1e-3 * SQ3 * kr


def contact_arrays(state):
    """Per touching contact, from the raw arrays: i, j, n, t, |d|, d, D (reference branch),
    image shift, lever arms, forces. Independent of demcell's homogenization."""
    k = np.flatnonzero(state.touching[:state.n_pairs] == 1)
    i, j = state.pair_i[k], state.pair_j[k]
    a = state.s[j] - state.s[i]
    r = np.floor(a + 0.5)
    a = a - r
    d = a @ state.h.T
    D = a @ state.h_ref.T
    length = np.linalg.norm(d, axis=1)
    n = d / length[:, None]
    t = np.column_stack([-n[:, 1], n[:, 0]])
    ovl = state.radius[i] + state.radius[j] - length
    ai = state.radius[i] - ovl / 2
    # the copy of a contact counted is the one whose contact point lies in the cell
    copy = -np.floor(state.s[i] + (ai / length)[:, None] * a)
    return dict(i=i, j=j, n=n, t=t, d=d, D=D, shift=-r, copy=copy, ai=ai,
                aj=state.radius[j] - ovl / 2, fn=state.fn[k], fs=state.fs[k], mr=state.mr[k])


def virtual_power(state, c, L, phi_dot, kappa_dot, w, omega):
    """Power of the contact forces on the relative motion of the contacts:
    sum_c fn ovl_dot - fs ut_dot - mr thr_dot (the rate of the elastic energy for sticking
    contacts) for the virtual rates: velocities L x_p + w_p, rotation rates
    phi_dot + kappa_dot . X_p + omega_p, image of j: + kappa_dot . (h_ref shift), and both discs
    of the copy of the contact in the cell: + kappa_dot . (h_ref copy)."""
    X = (state.s - 0.5) @ state.h_ref.T
    rate = phi_dot + X @ kappa_dot + omega
    copy = (c["copy"] @ state.h_ref.T) @ kappa_dot
    th_i = rate[c["i"]] + copy
    th_j = rate[c["j"]] + (c["shift"] @ state.h_ref.T) @ kappa_dot + copy
    d_dot = c["d"] @ L.T + w[c["j"]] - w[c["i"]]
    ovl_dot = -np.sum(c["n"] * d_dot, axis=1)
    ut_dot = np.sum(c["t"] * d_dot, axis=1) - c["ai"] * th_i - c["aj"] * th_j
    thr_dot = th_j - th_i
    return float(np.sum(c["fn"] * ovl_dot - c["fs"] * ut_dot - c["mr"] * thr_dot))


def test_power_identity_along_a_path_with_sliding(prepared60):
    """Hill-Mandel at every equilibrium state of a shear path with micro-rotation and curvature
    that makes contacts slide; the fluctuation rates (which do no work at equilibrium only
    thanks to the reaction of the held mean rotation) are large on purpose."""
    cell = micropolar(prepared60, tol=1e-7)
    rng = np.random.default_rng(1)
    width = float(np.abs(cell.state.h_ref).sum(axis=0).max())
    e = np.array([[0.0, 1.0], [-1.0, 0.0]])
    sliding = []
    for step in range(1, 7):
        gamma = 4e-3 * step
        cell.set_deformation(np.array([[1.0, gamma], [0.0, 1.0]]), rotation=0.3 * gamma,
                             curvature=(0.2 * gamma / width, -0.1 * gamma / width))
        assert cell.solve().converged
        cell.commit()
        st = cell.state
        h = cell.homogenized()
        sliding.append(h.sliding_fraction)
        area = abs(np.linalg.det(st.h))
        c = contact_arrays(st)
        f = np.abs(c["fn"])      # the constraint weights: the normal force each disc carries
        weight = (np.bincount(c["i"], weights=f, minlength=st.n_particles)
                  + np.bincount(c["j"], weights=f, minlength=st.n_particles))
        scale = area * np.abs(h.cauchy).max()
        for _ in range(3):
            L = rng.standard_normal((2, 2))
            phi_dot = rng.standard_normal()
            kappa_dot = rng.standard_normal(2) / width
            w = rng.standard_normal((st.n_particles, 2)) * width
            omega = rng.standard_normal(st.n_particles)
            omega -= weight * (weight @ omega) / (weight @ weight)      # sum_p w_p omega_p = 0
            macro = area * (np.sum(h.cauchy * (L + e * phi_dot)) + h.couple_stress @ kappa_dot)
            micro = virtual_power(st, c, L, phi_dot, kappa_dot, w, omega)
            assert micro == pytest.approx(macro, abs=2e-3 * scale), (step, micro, macro)
        # without the constraint on omega the fluctuation does work: the reaction is real
        omega = np.where(weight > 0, 1.0, 0.0)
        zero = np.zeros(2)
        spin_power = virtual_power(st, c, np.zeros((2, 2)), 0.0, zero, np.zeros_like(st.s), omega)
        reaction = area * (h.cauchy[0, 1] - h.cauchy[1, 0])
        if abs(reaction) > 0.05 * scale:
            assert abs(spin_power) > 0.05 * scale
    print("sliding fractions along the path", np.round(sliding, 3))
    assert max(sliding) > 0.02, sliding     # the path slides


def contact_forces(state):
    """{(i, j): fn} of the touching contacts (the pair slots are reordered by list rebuilds)."""
    k = np.flatnonzero(state.touching[:state.n_pairs] == 1)
    return {(int(state.pair_i[q]), int(state.pair_j[q])): float(state.fn[q]) for q in k}


def test_rigid_rotation_with_equal_micro_rotation_loads_no_contact(prepared60):
    cell = micropolar(prepared60)
    s0, m0 = cell.cauchy_stress(), cell.couple_stress()
    fn0 = contact_forces(cell.state)
    a = 0.3
    cell.set_deformation(rotation(a), rotation=a)
    assert cell.solve().converged
    R = rotation(a)
    assert np.allclose(cell.cauchy_stress(), R @ s0 @ R.T, atol=1e-4 * np.abs(s0).max())
    # the couple stress is measured at reference lever positions: unchanged
    assert np.allclose(cell.couple_stress(), m0, atol=1e-4 * np.abs(s0).max() * 0.01)
    fn = contact_forces(cell.state)
    assert fn.keys() == fn0.keys()
    assert max(abs(fn[k] - fn0[k]) for k in fn) < 1e-4 * max(fn0.values())
    # a micro-rotation different from the material rotation loads the contacts, and its skew
    # stress does not depend on the rigid rotation it is superposed on
    skews = []
    for angle in (0.0, a):
        cell.rollback()
        cell.set_deformation(rotation(angle), rotation=angle + 1e-4)
        assert cell.solve().converged
        s = cell.cauchy_stress()
        skews.append(s[0, 1] - s[1, 0])
    assert skews[0] > 0.05           # sigma12 - sigma21 = 2 mu_c (eps12 - eps21) > 0 for phi > 0
    assert skews[1] == pytest.approx(skews[0], rel=0.02)


def test_free_cell_is_the_micropolar_cell_at_its_own_mean_rotation(prepared60):
    """A free-rotation cell under a small symmetric strain: its grains turn on average by
    phi_f (force-weighted, as the micropolar constraint measures it); the micropolar cell held
    at phi = phi_f gives the same stress and no skew stress. Held at phi = 0 instead (the
    material rotation of a symmetric F), it does carry a skew stress."""
    state, law, opts = prepared60
    free = dc.DemCell(state.copy(), law, RelaxationOptions(criterion="force", tol=1e-7, check_every=20),
                      reset_reference=False)
    F = np.array([[1.0 - 2e-4, 1e-4], [1e-4, 1.0 + 1e-4]])
    free.set_deformation(F)
    assert free.solve().converged
    c = contact_arrays(free.state)
    f = np.abs(c["fn"])
    weight = (np.bincount(c["i"], weights=f, minlength=len(state.radius))
              + np.bincount(c["j"], weights=f, minlength=len(state.radius)))
    phi_f = float(weight @ (free.state.theta - state.theta) / weight.sum())
    s_free = free.cauchy_stress()
    mp = micropolar(prepared60, tol=1e-7)
    mp.set_deformation(F, rotation=phi_f)
    assert mp.solve().converged
    s_mp = mp.cauchy_stress()
    change = np.abs(s_free - state_stress(prepared60)).max()
    assert np.abs(s_mp - s_free).max() < 0.02 * change
    assert abs(s_mp[0, 1] - s_mp[1, 0]) < 0.02 * change
    mp.rollback()
    mp.set_deformation(F, rotation=0.0)
    assert mp.solve().converged
    s0 = mp.cauchy_stress()
    if abs(phi_f) > 1e-6:
        assert abs(s0[0, 1] - s0[1, 0]) > 0.05 * change


def state_stress(prepared):
    state, law, opts = prepared
    return dc.DemCell(state.copy(), law, opts, reset_reference=False).cauchy_stress()


def test_commit_rollback_copy_carry_rotation_and_curvature(prepared60):
    cell = micropolar(prepared60)
    cell.set_deformation(np.eye(2), rotation=1e-3, curvature=(0.01, 0.0))
    cell.solve()
    assert cell.state.phi == pytest.approx(1e-3)
    assert np.allclose(cell.state.kappa, (0.01, 0.0))
    cell.commit()
    twin = cell.copy()
    cell.set_deformation(np.eye(2), rotation=2e-3, curvature=(0.02, 0.0))
    cell.solve()
    assert twin.state.phi == pytest.approx(1e-3)
    cell.rollback()
    assert cell.state.phi == pytest.approx(1e-3) and np.allclose(cell.state.kappa, (0.01, 0.0))
    cell.solve()           # the target is the committed state again: nothing moves
    assert cell.state.phi == pytest.approx(1e-3)


def test_packing_file_keeps_rotation_and_curvature(tmp_path, prepared60):
    cell = micropolar(prepared60)
    cell.set_deformation(np.eye(2), rotation=1e-3, curvature=(0.01, -0.02))
    cell.solve()
    dc.save_packing(tmp_path / "p.npz", cell.state)
    st, _ = dc.load_packing(str(tmp_path / "p.npz"))
    assert st.phi == pytest.approx(1e-3) and np.allclose(st.kappa, (0.01, -0.02))
    # a packing written before the micropolar cell existed (no phi / kappa) still loads
    d = dict(np.load(tmp_path / "p.npz"))
    d.pop("phi"), d.pop("kappa")
    np.savez(tmp_path / "old.npz", **d)
    st, _ = dc.load_packing(str(tmp_path / "old.npz"))
    assert st.phi == 0.0 and np.all(st.kappa == 0.0)


@pytest.mark.parametrize("kwargs, match", [
    (dict(rotation=math.nan), "rotation must be finite"),
    (dict(rotation="a"), "rotation must be a number"),
    (dict(curvature=(math.inf, 0.0)), "curvature must be two finite numbers"),
    (dict(curvature=(1.0, 2.0, 3.0)), "curvature must be two finite numbers"),
    (dict(curvature=(1e3, 0.0)), "too large for this cell"),
])
def test_bad_rotation_or_curvature_refused(prepared60, kwargs, match):
    cell = micropolar(prepared60)
    with pytest.raises(dc.InputError, match=match):
        cell.set_deformation(np.eye(2), **kwargs)


def test_rotation_and_curvature_need_a_micropolar_cell(prepared60):
    state, law, opts = prepared60
    free = dc.DemCell(state.copy(), law, opts, reset_reference=False)
    with pytest.raises(dc.InputError, match="rotation_mode='micropolar'"):
        free.set_deformation(np.eye(2), curvature=(0.1, 0.0))
    with pytest.raises(dc.InputError, match="measure='micropolar'"):
        free.tangent("demqo", measure="micropolar")
    locked = law.with_(rotations=False)
    with pytest.raises(dc.InputError, match="locked rotations"):
        dc.DemCell(state.copy(), locked, opts, rotation_mode="micropolar")
    cell = dc.DemCell(state.copy(), locked, opts)
    with pytest.raises(dc.InputError, match="rotations are locked"):
        cell.set_deformation(np.eye(2), rotation=0.1)
    with pytest.raises(dc.InputError, match="unknown rotation_mode"):
        dc.DemCell(state.copy(), law, opts, rotation_mode="cosserat")


def test_large_curvature_stays_finite(prepared60):
    """A rotation jump of 0.5 rad across the cell (half the refused limit): the cell relaxes
    to finite stresses; the couple stress is far outside its linear range."""
    cell = micropolar(prepared60, tol=1e-4)
    width = float(np.abs(cell.state.h_ref).sum(axis=0).max())
    small = micropolar(prepared60, tol=1e-4)
    small.set_deformation(np.eye(2), curvature=(1e-3 / width, 0.0))
    assert small.solve().converged
    cell.set_deformation(np.eye(2), curvature=(0.5 / width, 0.0))
    res = cell.solve()
    h = cell.homogenized()
    assert res.converged, res.message
    assert np.all(np.isfinite(h.cauchy)) and np.all(np.isfinite(h.couple_stress))
    m0 = micropolar(prepared60).couple_stress()[0]
    assert (h.couple_stress[0] - m0) < 0.5 * 500 * (small.couple_stress()[0] - m0)
