"""Past the peak: a load step that fails with the cells' consistent operator is solved with the
Kruyt operator (fallback.FallbackSolver, docs/reference/femdem.md "Past the peak").

The run that needs it: a 1x1 locked-rotation specimen of 100-disc cells (seed 4), whose PSTLO
Newton past the peak (1.8 %) produces strain increments the cells refuse, down to dt_min, at
3.2 %; with the fallback the same run goes through its softening branch with no cut-back and
follows the stand-alone cell (the two runs are the same before the first fallback step, bit
for bit). The logic (the hold, the switch back, the restart state) on a stand-in solver.
"""
import dataclasses

import numpy as np
import pytest

from cosserat_fenicsx.fallback import FallbackSolver
from cosserat_fenicsx.snes import SolveInfo


# --- the logic, on stand-ins ---------------------------------------------------------------

class Material:
    """Converges with the fallback operator only (or with both, `own_converges`)."""

    def __init__(self, has_fallback=True):
        self.has_fallback, self.on, self.switches = has_fallback, False, []

    def use_fallback_operator(self, on):
        changed = self.has_fallback and bool(on) != self.on
        self.on = bool(on) and self.has_fallback
        self.switches.append(bool(on))
        return changed


class Problem:
    def __init__(self):
        self.rollbacks, self.invalidated = 0, 0
        self.gauss_points = self

    def rollback(self):
        self.rollbacks += 1

    def invalidate_tangents(self):
        self.invalidated += 1


class Newton:
    def __init__(self, material, own_converges):
        self.material, self.own_converges, self.operators = material, list(own_converges), []

    def solve(self):
        self.operators.append("fallback" if self.material.on else "own")
        ok = self.material.on or self.own_converges.pop(0)
        return SolveInfo(converged=ok, iterations=3 if ok else 25, residual=0.0, reason="R",
                         failure="" if ok else "strain increment 7e2 exceeds max_strain_increment")


def test_a_failed_step_is_retried_with_the_fallback_then_held():
    material, problem = Material(), Problem()
    newton = Newton(material, own_converges=[True, False, True, True])
    solver = FallbackSolver(newton, problem, material, hold=2)
    infos = [solver.solve() for _ in range(6)]
    assert newton.operators == ["own", "own", "fallback", "fallback", "fallback", "own", "own"]
    assert [bool(i.fallback) for i in infos] == [False, True, True, True, False, False]
    assert all(i.converged for i in infos)
    assert "max_strain_increment" in infos[1].fallback and "held" in infos[2].fallback
    assert infos[1].iterations == 25 + 3                  # the failed try's iterations are counted
    assert problem.rollbacks == 1 and solver.failures == 1 and not material.on
    assert problem.invalidated == 2 * 3                   # each switch recomputes the tangents


def test_without_a_fallback_operator_the_failure_goes_to_the_stepping():
    material, problem = Material(has_fallback=False), Problem()
    solver = FallbackSolver(Newton(material, own_converges=[False]), problem, material)
    info = solver.solve()
    assert not info.converged and not info.fallback and problem.rollbacks == 0 and solver.failures == 0


def test_hold_is_checked():
    with pytest.raises(ValueError, match="hold"):
        FallbackSolver(None, None, None, hold=-1)


# --- the run that needs it ------------------------------------------------------------------

@pytest.mark.serial
def test_locked_specimen_goes_through_its_softening_with_the_fallback():
    from cosserat_fenicsx.materials.dem import CellOptions
    from cosserat_fenicsx.scenes.femdem_biaxial import FemDemBiaxial, FemDemSettings
    from cosserat_fenicsx.stepping import LoadSteppingError
    from mpi4py import MPI

    def settings(**kw):
        return FemDemSettings(nx=1, ny=1, mode="classical", axial_strain=0.036, steps=36,
                              cell=CellOptions(particles=100, seed=4, rotation=False), **kw)

    without = FemDemBiaxial(MPI.COMM_WORLD, settings(fallback_tangent="none"), verbose=False)
    with pytest.raises(LoadSteppingError, match="max_strain_increment"):
        without.run()
    test = FemDemBiaxial(MPI.COMM_WORLD, settings(), verbose=False)
    test.run()
    rows = test.history
    assert rows[-1]["axial_strain"] == pytest.approx(-0.036) and test.stepper.cuts == 0
    used = [r["fallback"] for r in rows]
    first = used.index(1)
    assert sum(used) >= 3 and test.fallback.failures >= 1
    # the same run up to the first step that needed the fallback, bit for bit
    for a, b in zip(rows[:first], without.history[:first]):
        assert a["stress_ratio"] == b["stress_ratio"]
    # a softening branch: the ratio falls by more than 0.03 after its peak, and the steps
    # end at the standard tolerance (none accepted above force_rtol)
    ratio = np.array([r["stress_ratio"] for r in rows])
    peak = int(np.argmax(ratio))
    assert peak < len(rows) - 5 and ratio[peak] - ratio[peak:].min() > 0.03
    assert all(r["force_ratio"] <= test.s.accept_rtol for r in rows)
    assert dataclasses.asdict(test.s)["fallback_tangent"] == "kruyt"
