"""demcell plug-in interface: state handling, packing files, mixed control, outputs."""
import math

import numpy as np
import pytest

import demcell as dc
from demcell.interface import RelaxationOptions
from demcell.tangent import COMPONENTS

pytestmark = pytest.mark.serial


@pytest.fixture(scope="module")
def packing():
    return dc.generate_packing(60, pressure=10.0, seed=7)


def test_generation_is_reproducible_and_compacted(packing):
    st, info = packing
    st2, info2 = dc.generate_packing(60, pressure=10.0, seed=7)
    assert np.array_equal(st.s, st2.s) and np.array_equal(st.radius, st2.radius)
    assert st.radius.max() / st.radius.min() <= 1.5
    assert 0.80 < info["solid_fraction"] < 0.88 and info["coordination_number"] > 3.0
    s = dc.DemCell(st.copy()).cauchy_stress()
    assert abs(-0.5 * np.trace(s) - 10.0) < 0.2 and abs(s[0, 1]) < 0.2


def test_packing_file_round_trip(tmp_path, packing):
    st, info = packing
    path = str(tmp_path / "pack.npz")
    dc.save_packing(path, st, info)
    st2, info2 = dc.load_packing(path)
    assert info2["seed"] == 7
    a, b = dc.DemCell(st.copy()), dc.DemCell(st2)
    assert np.allclose(a.cauchy_stress(), b.cauchy_stress(), rtol=0, atol=1e-12)


def test_commit_rollback_copy(packing):
    cell = dc.create_cells(packing[0], count=2)[0]
    cell.set_deformation(np.diag([0.995, 1.0]))
    assert cell.solve().converged
    cell.commit()
    s_commit = cell.cauchy_stress()
    twin = cell.copy()
    cell.set_deformation(np.diag([0.99, 1.0]))
    cell.solve()
    assert not np.allclose(cell.cauchy_stress(), s_commit)
    assert np.allclose(twin.cauchy_stress(), s_commit)      # copies are independent
    cell.rollback()
    assert np.allclose(cell.cauchy_stress(), s_commit)
    assert np.allclose(cell.deformation_gradient(), np.diag([0.995, 1.0]))


def test_mixed_control_biaxial_keeps_lateral_stress(packing):
    cell = dc.DemCell(packing[0].copy(), dc.ContactLaw(friction=0.4))
    cell.set_deformation(np.diag([0.99, 1.0]))
    res = cell.solve(stress_mask=[[False, False], [False, True]], stress_target=np.diag([0.0, -10.0]))
    assert res.converged
    s = cell.cauchy_stress()
    assert abs(s[1, 1] + 10.0) < 1e-3 * 10.0 * 1.01
    assert s[0, 0] < -10.0                                    # axial compression above confinement


def test_pk1_and_dP_dF(packing):
    law = dc.ContactLaw(friction=math.inf)
    cell = dc.DemCell(packing[0].copy(), law, RelaxationOptions(tol=1e-9, check_every=20))
    F = np.array([[0.997, 0.001], [0.0, 1.001]])
    cell.set_deformation(F)
    assert cell.solve().converged
    sig, P = cell.cauchy_stress(), cell.pk1_stress()
    assert np.allclose(P, np.linalg.det(F) * sig @ np.linalg.inv(F).T)
    Cs = cell.tangent("pstlo")
    Cp = cell.tangent("pstlo", measure="dP_dF")
    # dP/dF by central differences of P(F) = J(F) (sigma + C_s dF) F^-T
    eps = 1e-6
    for c, (k, l) in enumerate(COMPONENTS):
        dF = np.zeros((2, 2))
        dF[k, l] = eps
        Pp, Pm = [np.linalg.det(F + q) * (sig + (Cs @ q.reshape(4)).reshape(2, 2)) @ np.linalg.inv(F + q).T
                  for q in (dF, -dF)]
        assert np.allclose((Pp - Pm).reshape(4) / (2 * eps), Cp[:, c], rtol=0, atol=1e-6 * np.abs(Cp).max())


def test_homogenized_outputs(packing):
    cell = dc.DemCell(packing[0].copy(), dc.ContactLaw(rolling_stiffness=0.5, rolling_friction=0.2))
    cell.set_deformation(np.diag([0.99, 1.0]))
    assert cell.solve().converged
    h = cell.homogenized()
    assert h.fabric.shape == (2, 2) and abs(np.trace(h.fabric) - 1.0) < 1e-12
    w = np.linalg.eigvalsh(h.fabric)
    assert h.anisotropy == pytest.approx(w[1] / w[0] - 1.0)
    assert h.coordination_number == pytest.approx(2.0 * h.n_contacts / 60)
    assert 0.0 <= h.sliding_fraction <= 1.0 and h.couple_stress.shape == (2,)
    assert np.all(np.isfinite(h.couple_stress))
    # couple stress is a fluctuation around zero: small compared with sigma * mean radius
    assert np.abs(h.couple_stress).max() < 0.5 * np.abs(h.cauchy).max() * packing[0].radius.mean()


def test_cohesive_bonds_carry_tension_then_break(packing):
    F = np.diag([1.003, 1.003])                 # 0.3 % isotropic pull
    plain = dc.DemCell(packing[0].copy(), dc.ContactLaw())
    plain.set_deformation(F)
    assert plain.solve().no_contacts            # cohesionless: falls apart
    cell = dc.DemCell(packing[0].copy(), dc.ContactLaw(cohesion_normal=0.5, cohesion_shear=0.5))
    cell.bond_contacts()
    n_bonds = int(cell.state.bonded.sum())
    cell.set_deformation(F)
    assert cell.solve().converged
    assert np.trace(cell.cauchy_stress()) > 0.0   # bonds carry tension
    cell.set_deformation(np.diag([1.05, 1.05]))
    assert cell.solve().converged
    assert int(cell.state.bonded[:cell.state.n_pairs].sum()) < n_bonds


def test_rotations_off(packing):
    cell = dc.DemCell(packing[0].copy(), dc.ContactLaw(rotations=False))
    theta0 = cell.state.theta.copy()
    cell.set_deformation(np.diag([0.99, 1.0]))
    assert cell.solve().converged
    assert np.array_equal(cell.state.theta, theta0)


def test_interface_is_abstract():
    with pytest.raises(TypeError):
        dc.MicroCell()


def test_packing_to_target_solid_fraction():
    st, info = dc.generate_packing(60, pressure=10.0, seed=7, solid_fraction=0.85)
    h = dc.DemCell(st).homogenized()
    assert h.solid_fraction == pytest.approx(0.85, abs=1e-9)
    assert info["pressure_achieved"] == pytest.approx(h.pressure) and h.pressure > 10.0
    with pytest.raises(dc.InputError, match="solid fraction"):
        dc.generate_packing(60, solid_fraction=1.2)


def test_tangent_kinds_are_declared_once(packing):
    """Every kind DemCell.tangent answers is an entry of tangent.TANGENT_KINDS, one name per
    operator; a micropolar cell refuses exactly the kinds declared Cauchy-only, and any other
    name is refused in one line that lists the kinds."""
    from demcell.tangent import TANGENT_KINDS, tangent_kind
    assert list(TANGENT_KINDS) == ["kruyt", "demqo", "pstlo", "pstlo_sliding", "perturbation"]
    assert [k for k, v in TANGENT_KINDS.items() if v.cauchy_only] == ["pstlo_sliding"]
    assert [k for k, v in TANGENT_KINDS.items() if v.releases_gil] == ["pstlo", "pstlo_sliding"]
    assert all(v.relaxes == (v.default_eps is not None) for v in TANGENT_KINDS.values())
    for name in ("cto", "CTO", ""):
        with pytest.raises(dc.InputError, match="unknown tangent kind") as err:
            tangent_kind(name)
        assert "\n" not in str(err.value) and all(k in str(err.value) for k in TANGENT_KINDS)
    st = packing[0].copy()
    st.phi, st.kappa = 0.0, np.zeros(2)
    cell = dc.DemCell(st, rotation_mode="micropolar")
    for name, kind in TANGENT_KINDS.items():
        if kind.cauchy_only:
            with pytest.raises(dc.InputError, match="is for Cauchy cells"):
                cell.tangent(name, measure="micropolar")
    for name in ("kruyt", "pstlo"):
        assert cell.tangent(name, measure="micropolar").shape == (6, 6)
        assert dc.DemCell(packing[0].copy()).tangent(name).shape == (4, 4)
