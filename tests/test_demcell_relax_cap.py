"""Relaxations stopped after N DEM steps (RelaxationOptions.relax_cap = N): a cell that settles
within N steps is the relaxed cell bit for bit; one that does not stops N steps after its ramp,
counts as converged with its grains still moving, and goes on from there at the next solve;
alone and batched give the same bits; the solve's own budget still fails a solve; a bad N is
refused in one line before any work."""
import dataclasses

import numpy as np
import pytest

import demcell as dc
from demcell import slots
from demcell.batch import CellBatch
from demcell.periodic_cell import substep_count
from small_cells import biaxial, cell40, with_options

pytestmark = pytest.mark.serial


@pytest.fixture(scope="module")
def reference():
    return cell40()


def capped(cell, n):
    return with_options(cell, relax_cap=n)


def solve_at(cell, e):
    cell.rollback()
    cell.set_deformation(biaxial(e))
    return cell.solve()


def kinetic_energy(cell):
    st = cell.state
    return 0.5 * float(np.sum(st.mass * np.sum(st.v ** 2, axis=1)) + np.sum(st.inertia * st.omega ** 2))


def test_a_cap_the_solve_does_not_reach_changes_no_bit(reference):
    relaxed = reference.copy()
    full = solve_at(relaxed, 2e-3)
    cell = capped(reference, full.steps + 10)
    result = solve_at(cell, 2e-3)
    assert result.converged and result.capped == 0 and result.steps == full.steps
    assert cell.state.n_pairs == relaxed.state.n_pairs
    m = cell.state.n_pairs
    for name in ("s", "v", "omega"):
        assert np.array_equal(getattr(cell.state, name), getattr(relaxed.state, name)), name
    for name in ("fn", "fs"):
        assert np.array_equal(getattr(cell.state, name)[:m], getattr(relaxed.state, name)[:m]), name


def test_a_capped_solve_stops_after_its_ramp_and_n_steps_and_goes_on_next_time(reference):
    relaxed = reference.copy()
    full = solve_at(relaxed, 2e-3)
    n_ramp = substep_count(2e-3 / reference.options.strain_rate)      # the ramp (001 eq. 7), about
    n = (full.steps - n_ramp) // 4
    assert n > 0
    shorter = solve_at(capped(reference, n // 2), 2e-3)
    cell = capped(reference, n)
    result = solve_at(cell, 2e-3)
    assert result.converged and result.capped == 1 and result.steps - shorter.steps == n - n // 2, result
    assert abs(result.steps - n - n_ramp) <= 1
    assert np.allclose(cell.state.F, biaxial(2e-3), rtol=0, atol=1e-14)
    # not settled: the grains move, the stress is not the relaxed one
    assert kinetic_energy(cell) > 2 * kinetic_energy(relaxed)
    assert not np.allclose(cell.cauchy_stress(), relaxed.cauchy_stress(), rtol=1e-3, atol=0)
    # committed, the next solve goes on from the moving state and settles there (a small increment)
    cell.commit()
    cell.options = dataclasses.replace(cell.options, relax_cap=None)
    cell.set_deformation(biaxial(2e-3 + 1e-6))
    again = cell.solve()
    assert again.converged and again.capped == 0
    assert np.allclose(cell.cauchy_stress(), relaxed.cauchy_stress(), rtol=0.05, atol=0)


def test_capped_batched_equal_the_cells(reference):
    steps = solve_at(reference.copy(), 3e-3).steps
    cells = [capped(reference, max(1, (steps - 300) // 3)) for _ in range(3)]
    batch = CellBatch(cells)
    rows = np.arange(3)
    F = np.array([biaxial(1e-3 * (k + 1)) for k in rows])     # the first may settle, the last not
    batch.set_targets(rows, F)
    res = batch.solve(rows)
    assert res[-1, slots.R_CAPPED] == 1
    for k, cell in enumerate(cells):
        cell.set_deformation(F[k])
        alone = cell.solve()
        assert int(res[k, slots.R_STEPS]) == alone.steps and int(res[k, slots.R_CAPPED]) == alone.capped
        assert batch.outcome(k, res[k])[0]
        m = cell.state.n_pairs
        assert np.array_equal(batch.state(k).s, cell.state.s)
        assert np.array_equal(batch.state(k).fn[:m], cell.state.fn[:m])


def test_the_solves_own_budget_still_fails_the_solve(reference):
    cell = capped(reference, 100)
    cell.rollback()
    cell.set_deformation(biaxial(2e-3))
    result = cell.solve(max_steps=250)           # ramp 201 + 49: spent before the cap
    assert not result.converged and result.capped == 0 and "step budget" in result.message


def test_a_stress_controlled_solve_still_relaxes(reference):
    cell = capped(reference, 5)
    F = cell.state.F.copy()
    F[1, 1] -= 1e-3
    cell.set_deformation(F)
    result = cell.solve(stress_mask=np.array([[True, False], [False, False]]), stress_target=-10.0 * np.eye(2))
    assert result.converged and result.capped == 0
    assert cell.cauchy_stress()[0, 0] == pytest.approx(-10.0, rel=2e-3)


@pytest.mark.parametrize("options, words", [
    (dict(relax_cap=0), "relax_cap must be an integer"),
    (dict(relax_cap=2.5), "relax_cap must be an integer"),
    (dict(relax_cap="ten"), "relax_cap must be an integer"),
    (dict(relax_cap=100, fixed_steps=100), "exclude each other"),
    (dict(relax_cap=5000, max_steps=1000), "exceeds max_steps"),
])
def test_a_bad_cap_is_refused_in_one_line(options, words):
    with pytest.raises(dc.InputError) as error:
        dc.RelaxationOptions(**options)
    text = str(error.value)
    assert "\n" not in text and words in text
