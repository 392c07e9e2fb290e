"""The Newton solves of a run as it records them, and the convergence they show.

`RecordingSolver` keeps the SolveInfo (snes.SolveInfo: iterations, residual history, force
ratios) of every solve of a NewtonSolver, converged or cut back; `convergence_orders` reads the
observed order of convergence off one residual history (2 for an exact Newton operator).
"""
import math

import numpy as np


class RecordingSolver:
    """A NewtonSolver that keeps the SolveInfo of every solve (residual histories)."""

    def __init__(self, solver):
        self.solver = solver
        self.infos = []

    def solve(self):
        info = self.solver.solve()
        self.infos.append(info)
        return info

    def infos_converged(self):
        return [info for info in self.infos if info.converged]


def convergence_orders(residuals, floor=None):
    """Observed orders q_k = log(r_k+1 / r_k) / log(r_k / r_k-1) of one Newton solve.

    r_0 is left out: it is the residual of the new load increment at the last converged
    state, the first iteration moves to the new load and says nothing about the rate.
    Residuals below `floor` (default 1e-14 max r: round-off of the assembled residual)
    are left out too."""
    r = np.asarray(residuals, dtype=float)
    if len(r) == 0:
        return []
    floor = 1e-14 * r.max() if floor is None else floor
    r = r[1:]
    r = r[r > floor]
    q = []
    for k in range(1, len(r) - 1):
        if r[k] < r[k - 1] and r[k + 1] < r[k]:
            q.append(math.log(r[k + 1] / r[k]) / math.log(r[k] / r[k - 1]))
    return q
