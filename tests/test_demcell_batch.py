"""demcell.batch.CellBatch against DemCells solved one by one: the same
compiled solve (quasistatic.solve_cell) on slices of one struct of arrays must give every bit
of every state array, with one thread or two, through sub-steps, lattice reduction, a
micropolar cell's rotation and curvature, and the growth of full pair arrays."""
import numpy as np
import numba
import pytest

import demcell as dc
from demcell.batch import CellBatch
from demcell.state import PAIR_FIELDS, PARTICLE_FIELDS
from demcell import slots

pytestmark = pytest.mark.serial


@pytest.fixture(scope="module")
def packing():
    state, _ = dc.generate_packing(60, pressure=10.0, law=dc.ContactLaw(kn=1e4, ks=2e3, friction=0.4), seed=3)
    return state


def make_cells(packing, micropolar=False, n=5):
    law = dc.ContactLaw(kn=1e4, ks=2e3, friction=0.4)
    options = dc.RelaxationOptions(tol=1e-3, criterion="force", max_steps=200_000)
    ref = dc.reference_cell(packing, law, options, 10.0)
    if micropolar:
        st = ref.state.copy()
        st.phi, st.kappa = 0.0, np.zeros(2)
        ref = dc.DemCell(st, law, options, reset_reference=False, rotation_mode="micropolar")
    cells = [ref.copy() for _ in range(n)]
    # different committed states: cells 1.. are pre-loaded by different biaxial strains
    for k, cell in enumerate(cells[1:], start=1):
        e = 1e-3 * k
        cell.set_deformation(np.array([[1 + 0.5 * e, 0.0], [0.0, 1 - e]]))
        cell.solve()
        cell.commit()
    return cells


def same_state(a, b):
    """Every array of two CellStates (pair arrays up to n_pairs) equal bit for bit."""
    assert a.n_pairs == b.n_pairs and a.forces_current == b.forces_current
    assert a.time == b.time and a.phi == b.phi and np.array_equal(a.kappa, b.kappa)
    for name in PARTICLE_FIELDS + ("h", "h_build", "h_ref"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    for name in PAIR_FIELDS:
        assert np.array_equal(getattr(a, name)[:a.n_pairs], getattr(b, name)[:b.n_pairs]), name


def targets(n, size):
    """Biaxial compression with some shear, different per cell."""
    out = []
    for k in range(n):
        e = size * (1 + 0.3 * k)
        out.append(np.array([[1 + 0.5 * e, 0.2 * e], [0.1 * e, 1 - e]]))
    return np.array(out)


def solve_alone(cells, F, phi=None, kappa=None):
    results = []
    for k, cell in enumerate(cells):
        cell.rollback()
        if phi is None:
            cell.set_deformation(F[k])
        else:
            cell.set_deformation(F[k], rotation=phi[k], curvature=kappa[k])
        results.append(cell.solve())
    return results


@pytest.mark.parametrize("size", [2e-3, 2.5e-2])      # one sub-step; three sub-steps
@pytest.mark.parametrize("threads", [1, 2])
def test_batch_equals_cells(packing, size, threads):
    cells = make_cells(packing)
    batch = CellBatch(cells)
    F = targets(len(cells), size)
    alone = solve_alone([c.copy() for c in cells], F)
    rows = np.arange(len(cells))
    batch.rollback(rows)
    batch.set_targets(rows, F)
    old = numba.get_num_threads()
    numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    try:
        res = batch.solve(rows)
    finally:
        numba.set_num_threads(old)
    ref = [c.copy() for c in cells]
    solve_alone(ref, F)
    for k, cell in enumerate(ref):
        same_state(batch.state(k), cell.state)
        converged, _, _, error = batch.outcome(k, res[k])
        assert error is None and converged == alone[k].converged
        assert int(res[k, slots.R_STEPS]) == alone[k].steps and int(res[k, slots.R_SUBSTEPS]) == alone[k].substeps
    # homogenized outputs and the Kruyt operator: the values of the cells
    hom = batch.homogenize(rows)
    C = batch.kruyt(rows)
    for k, cell in enumerate(ref):
        h = cell.homogenized()
        assert np.array_equal(hom["cauchy"][k], h.cauchy) and np.array_equal(hom["fabric"][k], h.fabric)
        assert hom["anisotropy"][k] == h.anisotropy and hom["stress_ratio"][k] == h.stress_ratio
        assert hom["sliding_fraction"][k] == h.sliding_fraction and hom["n_contacts"][k] == h.n_contacts
        assert hom["coordination_number"][k] == h.coordination_number
        assert np.array_equal(C[k], cell.tangent("kruyt"))
    # commit / rollback move whole cells
    batch.commit(rows[:2])
    batch.rollback(rows)
    same_state(batch.state(0), ref[0].state)
    same_state(batch.state(3), cells[3].committed_state)


def test_batch_micropolar_and_capacity(packing):
    cells = make_cells(packing, micropolar=True, n=3)
    for cell in cells:            # pair arrays cut to their content: the first rebuild overflows them
        st = cell.committed_state
        for name in PAIR_FIELDS:
            setattr(st, name, getattr(st, name)[:st.n_pairs].copy())
        cell.rollback()
    batch = CellBatch(cells)
    cap0 = batch.capacity.copy()
    F = targets(3, 2e-2)
    phi = np.array([0.0, 0.0, 0.0])
    kappa = np.array([[2e-3, -1e-3], [0.0, 3e-3], [-4e-3, 1e-3]]) / float(np.abs(cells[0].state.h_ref).max())
    rows = np.arange(3)
    batch.set_targets(rows, F, phi, kappa)
    res = batch.solve(rows)
    assert (batch.capacity > cap0).any()          # the growth path ran
    ref = [c.copy() for c in cells]
    solve_alone(ref, F, phi, kappa)
    hom = batch.homogenize(rows)
    for k, cell in enumerate(ref):
        same_state(batch.state(k), cell.state)
        assert int(res[k, slots.R_STEPS]) == cell.last_result.steps
        assert np.array_equal(hom["couple_stress"][k], cell.couple_stress())
        assert np.array_equal(hom["cauchy"][k], cell.cauchy_stress())
    # a view reads the store: its tangent is the cell's
    assert np.array_equal(batch.view(1).tangent("pstlo"), ref[1].tangent("pstlo"))


def test_batch_large_shear_reduces_lattice(packing):
    cells = make_cells(packing, n=2)
    batch = CellBatch(cells)
    F = np.array([[[1.0, 0.7], [0.0, 1.0]], [[1.0, 0.0], [0.6, 1.0]]])
    rows = np.arange(2)
    batch.set_targets(rows, F)
    batch.solve(rows)
    ref = [c.copy() for c in cells]
    solve_alone(ref, F)
    for k, cell in enumerate(ref):
        assert not np.allclose(cell.state.h_ref, cells[k].state.h_ref)    # reduced
        same_state(batch.state(k), cell.state)


def test_batch_step_budget_and_messages(packing):
    cells = make_cells(packing, n=2)
    batch = CellBatch(cells)
    rows = np.arange(2)
    batch.set_targets(rows, targets(2, 5e-3))
    res = batch.solve(rows, max_steps=20)
    converged, _, message, error = batch.outcome(0, res[0])
    assert not converged and error is None
    assert "maximum number of steps" in message and "sub-step 1 of 1" in message


@pytest.mark.parametrize("micropolar", [False, True])
def test_batch_demqo_equals_the_cells(packing, micropolar):
    """DEMQO of all cells in one call: the 4x4 (6x6 micropolar) operators and DEM steps of
    DemCell.tangent('demqo') on each cell, bit for bit."""
    cells = make_cells(packing, micropolar=micropolar, n=3)
    batch = CellBatch(cells)
    rows = np.arange(3)
    F = targets(3, 2e-3)
    kappa = np.array([[1e-3, 0.0], [0.0, 2e-3], [-1e-3, 1e-3]]) / float(np.abs(cells[0].state.h_ref).max())
    batch.set_targets(rows, F, np.zeros(3) if micropolar else None, kappa if micropolar else None)
    batch.solve(rows)
    tangents, steps = batch.demqo(rows)
    ref = [c.copy() for c in cells]
    solve_alone(ref, F, np.zeros(3) if micropolar else None, kappa if micropolar else None)
    for k, cell in enumerate(ref):
        C = cell.tangent("demqo", measure="micropolar" if micropolar else "dsigma_dF")
        assert C.shape == ((6, 6) if micropolar else (4, 4))
        assert np.array_equal(tangents[k], C)
        assert steps[k] == cell.last_tangent_steps > 0
