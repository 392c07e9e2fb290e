"""demcell.strain_path_step on a stand-in cell whose lateral stress is linear in F[lat, lat]:
the secant iteration lands on the confining stress, and the DEM steps it reports are those
of every trial it solved."""
import numpy as np
import pytest

from demcell.strain_path import strain_path_step

pytestmark = pytest.mark.serial


class Result:
    def __init__(self, steps):
        self.steps = steps


class LinearCell:
    """sigma_lat,lat = k (F[lat, lat] - 1) [N/m]; each solve costs `cost` DEM steps."""

    def __init__(self, k=1.0e3, cost=7):
        self.k, self.cost = k, cost
        self.F = np.eye(2)
        self.solves = 0

    def rollback(self):
        pass

    def set_deformation(self, F):
        self.F = np.array(F, dtype=float)

    def deformation_gradient(self):
        return self.F.copy()

    def solve(self):
        self.solves += 1
        return Result(self.cost)

    def cauchy_stress(self):
        s = np.zeros((2, 2))
        s[0, 0] = self.k * (self.F[0, 0] - 1.0)
        return s


def test_secant_reaches_the_lateral_stress_and_counts_every_trial():
    cell = LinearCell()
    F = np.array([[1.0, 0.0], [0.0, 0.99]])
    res = strain_path_step(cell, F, 0, -2.0, rtol=1e-10)
    assert abs(cell.cauchy_stress()[0, 0] + 2.0) <= 1e-8
    assert cell.solves >= 3                       # two starting trials and at least one secant update
    assert res.steps == cell.cost * cell.solves   # the first trial's steps are counted too


class SaturatingCell(LinearCell):
    """A loose cell that slides: the lateral stress saturates at -1 N/m, flat beyond, so a
    confining stress of -2 N/m is out of reach and a plain secant step runs away across the
    flat stretch (to det F <= 0, which set_deformation refuses, as DemCell does)."""

    def set_deformation(self, F):
        if np.linalg.det(F) <= 0:
            raise ValueError(f"det F = {np.linalg.det(F):.3g}")
        super().set_deformation(F)

    def cauchy_stress(self):
        s = np.zeros((2, 2))
        s[0, 0] = -np.tanh(self.k * (1.0 - self.F[0, 0]))
        return s


def test_secant_stays_bounded_and_keeps_its_best_trial_on_a_flat_response():
    cell = SaturatingCell(k=1.0e3)
    F = np.array([[1.0, 0.0], [0.0, 0.998]])
    strain_path_step(cell, F, 0, -2.0)
    assert 1.0 - 6.0 * 0.002 - 1e-9 <= cell.F[0, 0] < 1.0
    # the best the cell can do: the lateral stress nearest -2 N/m within the bound
    assert cell.cauchy_stress()[0, 0] == pytest.approx(-np.tanh(1.0e3 * 6.0 * 0.002), abs=1e-9)
