"""Preparation of a cell before a loading program: the isotropic stage of 000 section 4.1.

A packing from ``generate_packing`` is compacted without friction (dense). Before a test,
friction is switched on (the cell's own contact law) and the cell is relaxed again under
sigma = -p I by the stress servo on F_11, F_12 and F_22 (the isotropic stage).
``demos/dem_cell.py`` runs its biaxial test from there, and so does every Gauss point of a
FEM x DEM run, whose cells are re-referenced to that state (F = I, sigma = -p I), so the
macro specimen starts in equilibrium under the confining pressure.
"""
import numpy as np

from . import checks
from .errors import SolveError
from .interface import DemCell
from .state import CellState

ISOTROPIC_MASK = np.array([[True, True], [False, True]])   # F_21 fixed: no rigid spin


def isotropic_stage(cell, pressure):
    """Relax ``cell`` under sigma = -pressure I [N/m] (servo on F_11, F_12, F_22) and
    commit. Returns the SolveResult; raises SolveError naming the cause if it fails."""
    checks.instance("cell", cell, DemCell)
    pressure = checks.number("pressure", pressure, checks.POSITIVE)
    result = cell.solve(stress_mask=ISOTROPIC_MASK, stress_target=-float(pressure) * np.eye(2))
    if not result.converged:
        raise SolveError(f"isotropic stage at p = {pressure:g} N/m did not converge: {result.message}")
    cell.commit()
    return result


def reference_cell(state, law, options, pressure):
    """A DemCell after the isotropic stage at ``pressure``, re-referenced (F = I there) and
    committed: the starting state of a FEM x DEM Gauss point. ``state`` is not modified."""
    checks.instance("state", state, CellState)
    pressure = checks.number("pressure", pressure, checks.POSITIVE)
    cell = DemCell(state.copy(), law, options)
    isotropic_stage(cell, pressure)
    prepared = cell.state.copy()
    prepared.v[:] = 0.0
    prepared.omega[:] = 0.0
    return DemCell(prepared, law, options, reset_reference=True)
