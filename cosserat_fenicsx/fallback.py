"""A load step that fails with the material's tangent operator is tried again with its fallback
operator before the step is cut.

Why. Past the peak of a granular specimen the consistent operators of a DEM cell (PSTLO,
DEMQO, perturbation: 001 eq. 6, 20, appendix B) lose their stiffness in the directions the
sliding contacts free: with many cells there at once (a homogeneous specimen, or a band)
the assembled Jacobian turns nearly singular, its Newton correction is orders of magnitude
too large (a Gauss-point strain increment of 7e2 in the locked-rotation 1x2 run of
docs/reference/femdem.md, "Past the peak") and the cells refuse it (max_strain_increment),
at every step size the stepping cuts down to. The contact springs' uniform-strain operator
(Kruyt, 001 eq. 13) stays positive definite while the contact network holds: a Newton on it
converges more slowly (a modified Newton) but to the same equilibrium, since the residual,
not the operator, decides what is converged.

So a solve that fails (a Gauss point refused, or SNES diverged or stagnated) is done again
from the committed state at the same load with `material.use_fallback_operator(True)`. Where
one step needed it the next ones will too (the cells stay past their peak), and a first try
that fails costs a whole Newton solve: the `hold` steps after a fallback step are solved with
the fallback operator directly, then the material's own is tried again. The stepping sees one
solve: converged, or failed (then it cuts the step as before). `SolveInfo.fallback` says why a
step used the fallback (the first try's cause, or that it was held), so the runs report how
many steps needed it. `held` is run state: a checkpoint keeps it (same bits after a restart).

Damped retry (`damping`, e.g. 0.3; None: off). Past the peak a step can also fail with both
operators because its Newton stagnates above accept_rtol: each correction carries cells across
contact events (contacts opening and closing), so the residual jumps by what no operator sees.
Such a step, failed on the fallback operator (its retry or a held step), is solved once more
from the committed state on the fallback operator with damped updates (x += damping dx,
NewtonSolver.set_step_damping) before it goes back to the stepping to be cut, in case shorter
corrections get under the floor. Converged, it is reported with `SolveInfo.damped` and the hold
starts as after a fallback step. A material without a fallback operator (fallback none: cut at
once) gets no damped retry either. Measured so far it has not turned a cut step into a
converged one (docs/reference/femdem.md, "Past the peak: ending a stagnating step"): it costs
one Newton solve more per step that is then cut anyway.
"""
import dataclasses

from .validation import FRACTION, check_optional


class FallbackSolver:
    """`solver` (a NewtonSolver) whose failed solves are tried again with the fallback operator
    of `material` (Constitutive.use_fallback_operator) on `problem` (a CosseratProblem)."""

    #: steps solved with the fallback operator directly after one that needed it
    HOLD = 5

    def __init__(self, solver, problem, material, hold=HOLD, damping=None):
        if not (isinstance(hold, int) and hold >= 0):
            raise ValueError(f"fallback: hold must be an integer >= 0, got {hold!r}")
        damping = check_optional("fallback: damping", damping, FRACTION)
        self.solver, self.problem, self.material = solver, problem, material
        self.hold = hold
        self.damping = damping
        #: steps that converged only in the damped retry
        self.damped_steps = 0
        #: converged steps still to be solved with the fallback operator (run state)
        self.held = 0
        #: first tries with the material's own operator that failed
        self.failures = 0

    def solve(self):
        if self.held > 0 and self._switch(True):
            try:
                info = self.solver.solve()
            finally:
                self._switch(False)
            if info.converged:
                self.held -= 1
            else:
                info = self._damped_retry(info)
            return dataclasses.replace(info, fallback=f"held after a step that needed it ({self.held} more)")
        info = self.solver.solve()
        if info.converged or not self._switch(True):      # converged, or no other operator
            return info
        cause = info.failure or f"SNES {info.reason} after {info.iterations} iterations"
        self.failures += 1
        self.problem.rollback()         # from the committed state, at the same load
        try:
            retry = self.solver.solve()
        finally:
            self._switch(False)
        if retry.converged:
            self.held = self.hold
        else:
            retry = self._damped_retry(retry)
        return dataclasses.replace(retry, fallback=cause, iterations=info.iterations + retry.iterations,
                                   wall_time=info.wall_time + retry.wall_time)

    def _damped_retry(self, failed):
        """The step `failed` on the fallback operator, solved again from the committed state on
        that operator with damped updates; `failed` itself if there is no damping."""
        if self.damping is None or not self._switch(True):      # off, or no fallback operator
            return failed
        self.problem.rollback()
        self.solver.set_step_damping(self.damping)
        try:
            retry = self.solver.solve()
        finally:
            self.solver.set_step_damping(None)
            self._switch(False)
        if retry.converged:
            self.held = self.hold
            self.damped_steps += 1
        return dataclasses.replace(retry, damped=retry.converged, iterations=failed.iterations + retry.iterations,
                                   wall_time=failed.wall_time + retry.wall_time)

    def _switch(self, on):
        """Set the material's operator; the stored tangents are computed again with it."""
        changed = self.material.use_fallback_operator(on)
        if changed:
            self.problem.gauss_points.invalidate_tangents()
        return changed

    def destroy(self):
        self.solver.destroy()
