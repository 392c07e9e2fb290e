"""demcell stiff and extreme cases and bad input (errors before any work)."""
import math

import numpy as np
import pytest

import demcell as dc
from demcell.interface import RelaxationOptions

pytestmark = pytest.mark.serial


@pytest.fixture(scope="module")
def packing60():
    st, _ = dc.generate_packing(60, pressure=10.0, seed=5)
    return st


def test_stiff_contacts_time_step_follows(packing60):
    soft = dc.DemCell(packing60.copy(), dc.ContactLaw(kn=1e4, ks=2e3))
    stiff = dc.DemCell(packing60.copy(), dc.ContactLaw(kn=1e10, ks=2e9))
    assert stiff.dt == pytest.approx(soft.dt * 1e-3, rel=1e-12)      # dt ~ 1/sqrt(k)
    # same geometry, springs 1e6 times stiffer: the stress scales by 1e6 and stays finite
    s_soft = soft.cauchy_stress()
    F = np.array([[0.99999, 0.0], [0.0, 1.0]])
    for c in (soft, stiff):
        c.set_deformation(F)
        res = c.solve()
        assert res.converged, res.message
    s1, s2 = soft.cauchy_stress(), stiff.cauchy_stress()
    assert np.all(np.isfinite(s2))
    assert np.abs(s2 / 1e6 - s1).max() < 1e-2 * np.abs(s_soft).max()


def test_zero_friction(packing60):
    cell = dc.DemCell(packing60.copy(), dc.ContactLaw(friction=0.0))
    cell.set_deformation(np.diag([0.99, 1.0]))
    res = cell.solve()
    assert res.converged
    assert np.all(cell.state.fs[:cell.state.n_pairs] == 0.0)
    assert np.all(np.isfinite(cell.cauchy_stress()))


def test_infinite_friction_never_slides(packing60):
    cell = dc.DemCell(packing60.copy(), dc.ContactLaw(friction=math.inf))
    cell.set_deformation(np.diag([0.98, 1.0]))
    assert cell.solve().converged
    h = cell.homogenized()
    assert h.sliding_fraction == 0.0 and np.all(np.isfinite(h.cauchy))


def test_pulled_apart_gives_zero_stress_and_flag(packing60):
    cell = dc.DemCell(packing60.copy(), dc.ContactLaw())
    cell.set_deformation(np.diag([1.05, 1.05]))
    res = cell.solve()
    assert res.no_contacts and "no contact" in res.message
    h = cell.homogenized()
    assert h.no_contacts and h.n_contacts == 0
    assert np.all(h.cauchy == 0.0) and np.all(h.pk1 == 0.0)
    assert np.all(np.isfinite(cell.tangent("kruyt")))


def test_huge_increment_is_substepped(packing60):
    cell = dc.DemCell(packing60.copy(), dc.ContactLaw(), RelaxationOptions(max_increment=0.01))
    cell.set_deformation(np.diag([0.9, 1.0]))           # 10 % in one call
    res = cell.solve(stress_mask=np.array([[False, False], [False, True]]),
                     stress_target=np.diag([0.0, -10.0]))
    assert res.substeps == 10 and res.converged, res.message
    s = cell.cauchy_stress()
    assert np.all(np.isfinite(s)) and abs(s[1, 1] + 10.0) < 0.02 and s[0, 0] < s[1, 1]


def test_too_large_time_step_is_refused(packing60):
    auto = dc.DemCell(packing60.copy())
    with pytest.raises(dc.InputError, match="stability estimate"):
        dc.DemCell(packing60.copy(), dc.ContactLaw(), RelaxationOptions(dt=auto.dt * 30))
    with pytest.raises(dc.InputError, match="stability estimate"):      # stiffer law, same dt
        dc.DemCell(packing60.copy(), dc.ContactLaw(), RelaxationOptions(dt=auto.dt * 2)).set_law(
            dc.ContactLaw(kn=1e6, ks=2e5))


def test_soft_contacts_are_flagged(packing60):
    cell = dc.DemCell(packing60.copy(), dc.ContactLaw(kn=50.0, ks=10.0))   # p / kn = 0.2
    res = cell.solve(stress_mask=[[True, True], [False, True]], stress_target=-10.0 * np.eye(2))
    assert res.max_overlap_ratio > 0.1 and "too soft" in res.message


def test_bad_input_is_rejected_before_work(tmp_path, packing60):
    with pytest.raises(dc.InputError, match="kn"):
        dc.ContactLaw(kn=-1.0)
    with pytest.raises(dc.InputError, match=">= 0"):
        dc.ContactLaw(ks=-5.0)
    with pytest.raises(dc.InputError, match="twisting"):
        dc.ContactLaw(twisting_stiffness=1.0)
    with pytest.raises(dc.InputError, match="unknown ContactLaw option"):
        dc.ContactLaw().with_(frcition=0.3)
    with pytest.raises(dc.InputError, match="unknown relaxation option"):
        RelaxationOptions.from_kwargs(tolerance=1e-3)
    with pytest.raises(dc.InputError, match="criterion"):
        RelaxationOptions(criterion="magic")
    with pytest.raises(dc.InputError, match="not found"):
        dc.load_packing(str(tmp_path / "missing.npz"))
    bogus = tmp_path / "bogus.npz"
    np.savez(bogus, a=np.zeros(3))
    with pytest.raises(dc.InputError, match="not a demcell packing"):
        dc.load_packing(str(bogus))
    cell = dc.DemCell(packing60.copy())
    with pytest.raises(dc.InputError, match="det F"):
        cell.set_deformation(np.diag([1.0, -1.0]))
    with pytest.raises(dc.InputError, match="unknown tangent kind"):
        cell.tangent("secant")


def test_large_simple_shear_remaps_the_cell(packing60):
    """gamma = 3: without remapping the sheared cell would become too thin for the
    minimum-image convention; the base cell is reduced on the way (F unchanged). The shear
    strength is the mean over gamma = 2 to 3: one state of a 60-disc cell in steady shear is
    chaotic (measured: s12 / p0 at gamma = 3 between -0.02 and 0.32 when the load is changed by
    1e-15), the mean is not."""
    cell = dc.DemCell(packing60.copy(), dc.ContactLaw(friction=0.4),
                      RelaxationOptions(max_increment=0.05, strain_rate=1e-4))
    ratios = []
    for gamma in (2.0, 2.25, 2.5, 2.75, 3.0):
        F = np.array([[1.0, gamma], [0.0, 1.0]])
        cell.set_deformation(F)
        res = cell.solve(stress_mask=[[False, False], [False, True]], stress_target=np.diag([0.0, -10.0]))
        assert res.converged, res.message
        s = cell.cauchy_stress()
        assert np.all(np.isfinite(s))
        ratios.append(s[0, 1] / 10.0)
    assert np.allclose(cell.deformation_gradient()[0], F[0])
    h = cell.state.h
    assert abs(h[0, 1]) <= 0.5 * abs(h[0, 0]) + 1e-12           # compact base cell
    assert 0.05 < np.mean(ratios) < 0.6, ratios                 # steady shear strength


def test_fire_relaxation_reaches_the_same_equilibrium(packing60):
    """Frictionless (no path dependence through the tangential springs): both relaxation
    methods must find the same equilibrium."""
    law = dc.ContactLaw(friction=0.0)
    F = np.array([[0.998, 0.0005], [0.0, 1.001]])
    sig = []
    for method in ("local", "fire"):
        cell = dc.DemCell(packing60.copy(), law, RelaxationOptions(method=method, tol=1e-9, check_every=20))
        cell.set_deformation(F)
        assert cell.solve().converged
        sig.append(cell.cauchy_stress())
    assert np.abs(sig[0] - sig[1]).max() < 1e-3 * np.abs(sig[0]).max()
    with pytest.raises(dc.InputError, match="relaxation method"):
        RelaxationOptions(method="verlet")


@pytest.mark.parametrize("ratio", [1e-8, 1e-6, 1e-1])
def test_compaction_across_the_pressure_ratio_range(ratio):
    """p0/kn from 1e-8 to 1e-1: the packing reaches p0 (below 1e-4 in stages; in one stage
    the servo moves a cell without contacts at gain p0/kn per step and runs out of steps)."""
    law = dc.ContactLaw(kn=1e4, ks=2e3)
    state, info = dc.generate_packing(60, pressure=ratio * 1e4, law=law, seed=3)
    cell = dc.DemCell(state, law)
    pressure = cell.homogenized().pressure
    assert abs(pressure / (ratio * 1e4) - 1.0) < 2e-2            # the servo's stress tolerance, 1e-2
    assert info["coordination_number"] > 3.0                       # jammed, not a gas


@pytest.mark.parametrize("ratio", [1e-9, 0.2])
def test_pressure_ratio_outside_the_range_is_refused(ratio):
    with pytest.raises(dc.InputError, match=r"pressure / kn must be in \[1e-08, 0.1\]"):
        dc.generate_packing(60, pressure=ratio * 1e4, law=dc.ContactLaw(kn=1e4, ks=2e3))


@pytest.mark.parametrize("kwargs, message", [
    (dict(stress_mask=[[1, 0], [0, 1]], stress_target=np.eye(2)), "2x2 array of booleans"),
    (dict(stress_mask=[[True, False]], stress_target=np.eye(2)), "2x2 array of booleans"),
    (dict(stress_mask=[[False, False], [False, True]], stress_target=np.diag([0.0, np.nan])), "finite where"),
    (dict(stress_mask=[[False, False], [False, True]], stress_target=np.zeros(3)), "finite where"),
    (dict(max_steps=0), "max_steps must be an integer >= 1"),
    (dict(max_steps=1.5), "max_steps must be an integer >= 1"),
])
def test_solve_refuses_bad_targets_and_masks(packing60, kwargs, message):
    cell = dc.DemCell(packing60.copy())
    before = cell.state.s.copy()
    with pytest.raises(dc.InputError, match=message):
        cell.solve(**kwargs)
    assert np.array_equal(before, cell.state.s)          # refused before any work


@pytest.mark.parametrize("count", [0, -1, 2.5, True, "2"])
def test_create_cells_refuses_a_bad_count(packing60, count):
    with pytest.raises(dc.InputError, match="count must be an integer >= 1"):
        dc.create_cells(packing60, count=count)
