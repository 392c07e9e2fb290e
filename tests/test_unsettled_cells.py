"""FIRE cells that do not settle are solved again from the committed state with local damping
(materials/dem/stores.py, PointCells.solves_redone; docs/reference/femdem.md, "Past the
peak: cells that FIRE does not settle"). That happens to cells relaxed to the criterion
(relax_cap=none); with the default cap the same cell stops after 500 steps, counted as capped."""
import numpy as np
import pytest

from cosserat_fenicsx.materials.dem import CellOptions
from cosserat_fenicsx.materials.dem.cells import reference_cells
from cosserat_fenicsx.materials.dem.modes import make_mode
from cosserat_fenicsx.materials.dem.stores import BatchedCells, CellList

pytestmark = pytest.mark.serial


def strained(k):
    """F of step k of a dilating biaxial path, 0.1 % axial compression and 0.155 % lateral
    extension a step (written as found: the outcome at step 24 depends on the last bits of F)."""
    a = 1e-3 * k
    return np.diag([1 + 1.55 * a, 1 - a])


@pytest.fixture(scope="module")
def unsettled():
    """A 60-disc cell (seed 1, friction 0.4) committed after 23 steps of the path: FIRE does
    not settle it at step 24 within its 2e5 steps (it cycles at an unbalanced-force ratio of
    about 1.6); local damping settles it in a few thousand."""
    cell = reference_cells(CellOptions(particles=60, seed=1, extra={"relax_cap": None}), [0.4])[0][0]
    assert cell.options.method == "fire" and cell.options.relax_cap is None
    for k in range(1, 24):
        cell.set_deformation(strained(k))
        assert cell.solve().converged
        cell.commit()
    return cell


def test_fire_does_not_settle_the_cell_local_damping_does(unsettled):
    from demcell.batch import CellBatch
    batch = CellBatch([unsettled])
    batch.set_targets([0], strained(24)[None])
    converged, _, message, _ = batch.outcome(0, batch.solve([0])[0])
    assert not converged and "maximum number of steps" in message
    batch.rollback([0])
    batch.set_targets([0], strained(24)[None])
    result = batch.solve([0], method="local")[0]
    converged, no_contacts, _, _ = batch.outcome(0, result)
    assert converged and not no_contacts and result[0] < 20_000
    with pytest.raises(ValueError, match="method"):
        batch.solve([0], method="verlet")


def solve_in_store(store, cell, F):
    """The store's solve of one classical cell to F: (store, status, cost, texts, flux)."""
    cells = store([cell], make_mode("classical"), 0.05)
    gradients = np.zeros((1, 6))
    gradients[0, :2] = F[0, 0] - 1.0, F[1, 1] - 1.0
    flux, state_new = np.zeros((1, 6)), np.zeros((1, 7))
    status, cost, texts = np.zeros(1, dtype=np.int64), np.zeros(1), {}
    timers = {"solve": 0.0, "homogenize": 0.0}
    cells.solve(np.array([0]), gradients, flux, state_new, status, cost, texts, timers)
    return cells, status, cost, texts, flux


@pytest.mark.parametrize("store", [BatchedCells, CellList])
def test_the_store_solves_an_unsettled_cell_again_with_local_damping(unsettled, store):
    F = strained(24)
    cells, status, cost, texts, flux = solve_in_store(store, unsettled.copy(), F)
    assert status[0] == 0 and not texts and cells.solves_redone == 1
    assert cost[0] > 200_000                 # the failed FIRE solve's steps are counted
    # the stress is the local-damping cell's, solved on its own from the committed state
    reference = unsettled.copy()
    reference.options = reference.options.__class__(**{**reference.options.__dict__, "method": "local"})
    reference.rollback()
    reference.set_deformation(F)
    assert reference.solve().converged
    sigma = reference.cauchy_stress()
    np.testing.assert_allclose(flux[0, :3], [sigma[0, 0], sigma[1, 1], sigma[0, 1]], rtol=1e-12, atol=1e-12)
    assert np.all(np.isfinite(flux)) and flux[0, 1] < 0


@pytest.mark.parametrize("store", [BatchedCells, CellList])
def test_with_the_default_cap_the_unsettled_cell_is_capped_not_redone(unsettled, store):
    """The default cells (relax_cap 500): the solve that FIRE cannot settle stops 500 steps
    after its ramp, counts as converged and is counted as capped; nothing is solved again."""
    import dataclasses
    from cosserat_fenicsx.materials.dem.cells import RELAX_CAP
    cell = unsettled.copy()
    cell.options = dataclasses.replace(cell.options, relax_cap=RELAX_CAP)
    cells, status, cost, texts, flux = solve_in_store(store, cell, strained(24))
    assert status[0] == 0 and not texts and cells.solves_redone == 0 and cells.solves_capped == 1
    assert RELAX_CAP < cost[0] < RELAX_CAP + 200      # its ramp (a few steps) and the cap
    assert np.isfinite(flux[0]).all()
