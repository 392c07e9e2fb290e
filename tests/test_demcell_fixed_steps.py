"""Cells run as YADE's FEMxDEM runs them (RelaxationOptions.fixed_steps = N): every solve takes
exactly N DEM steps, the increment of F applied over them and no relaxation after, alone and
batched (the same bits); a bad N is refused in one line before any work."""
import numpy as np
import pytest

import demcell as dc
from demcell import slots
from demcell.batch import CellBatch
from small_cells import biaxial, cell40, with_options

pytestmark = pytest.mark.serial


@pytest.fixture(scope="module")
def reference():
    return cell40()


def fixed(cell, n):
    return with_options(cell, fixed_steps=n)


@pytest.mark.parametrize("n", [1, 37, 100])
def test_a_fixed_step_solve_takes_exactly_n_steps_and_reaches_the_target(reference, n):
    cell = fixed(reference, n)
    relaxed = reference.copy()
    for e in (1e-4, 1e-3, 2e-3):         # ramps of 10, 100, 200 steps at the default strain rate
        for c in (cell, relaxed):
            c.rollback()
            c.set_deformation(biaxial(e))
        result = cell.solve()
        assert result.converged and result.steps == n and result.substeps == 1, result
        assert np.allclose(cell.state.F, biaxial(e), rtol=0, atol=1e-14)
        # not relaxed: its stress is not the quasi-static one (which takes far more steps)
        full = relaxed.solve()
        assert full.steps > n
        assert not np.array_equal(cell.cauchy_stress(), relaxed.cauchy_stress())
    # sub-steps (an increment above max_increment) share the N steps out
    cell.rollback()
    cell.set_deformation(biaxial(2.5e-2))
    result = cell.solve()
    assert result.substeps == 3 and result.steps == max(n, 3) and result.converged


def test_fixed_steps_batched_equal_the_cells(reference):
    cells = [fixed(reference, 50) for _ in range(3)]
    batch = CellBatch(cells)
    rows = np.arange(3)
    F = np.array([biaxial(1e-3 * (k + 1)) for k in rows])
    batch.set_targets(rows, F)
    res = batch.solve(rows)
    for k, cell in enumerate(cells):
        cell.set_deformation(F[k])
        alone = cell.solve()
        assert int(res[k, slots.R_STEPS]) == alone.steps == 50
        assert batch.outcome(k, res[k])[0]
        assert np.array_equal(batch.state(k).s, cell.state.s) and np.array_equal(batch.state(k).fn, cell.state.fn)


def test_a_stress_controlled_solve_still_relaxes(reference):
    """The servo needs equilibrium to find its strain: fixed_steps leaves it alone (the
    isotropic stage of a FEM x DEM run's preparation is such a solve)."""
    cell = fixed(reference, 10)
    F = cell.state.F.copy()
    F[1, 1] -= 1e-3
    cell.set_deformation(F)
    result = cell.solve(stress_mask=np.array([[True, False], [False, False]]), stress_target=-10.0 * np.eye(2))
    assert result.converged and result.steps > 10
    assert cell.cauchy_stress()[0, 0] == pytest.approx(-10.0, rel=2e-3)


@pytest.mark.parametrize("bad", [0, -5, 2.5, float("nan"), "ten"])
def test_a_bad_number_of_steps_is_refused_in_one_line(bad):
    with pytest.raises(dc.InputError) as error:
        dc.RelaxationOptions(fixed_steps=bad)
    text = str(error.value)
    assert "\n" not in text and "fixed_steps must be an integer" in text
