"""PETSc SNES Newton (with line search) on a CosseratProblem, through petsc4py.

Defaults: newtonls with backtracking line search, a direct LU solve (MUMPS). Anything
given on the command line as -snes_*, -ksp_*, -pc_*, -mat_* overrides them (see
cli.forward_petsc_options). A Gauss-point failure (ConstitutiveError) on any rank turns
the residual into NaN on every rank (the decision is reduced over the ranks before the
collective assembly steps, so nobody waits forever): SNES stops with DIVERGED_FNORM_NAN
on all ranks together and the cause is reported. A failure while the material computes its
tangents (before the Jacobian assembly) is made collective the same way: the matrix is
replaced by the identity and the next residual is NaN, so SNES stops at once.

Stopping test. The default is PETSc's (snes_rtol, snes_atol on the residual norm). With
`force_rtol` the test is the one FEM x DEM uses (001 section 6, Fig. 6: FNORM/RNORM):
the norm of the residual at the free dofs over the norm of the reactions (internal forces
at the Dirichlet dofs), checked from the first Newton update on (when the Dirichlet rows
hold their new values). A material whose stress carries a relaxation error (a DEM cell
relaxed to a tolerance) cannot bring the residual below that error: this test stops at
a level the material can deliver. `SolveInfo.force_ratios` is its history. With
`accept_rtol` (>= force_rtol) as well, a solve that does not reach force_rtol within
snes_max_it but whose best iterate reached FNORM/RNORM <= accept_rtol ends at that iterate
(re-evaluated, so the material's state is the one of that iterate) and is reported as
accepted (`SolveInfo.accepted`, reason ACCEPTED_AT_STAGNATION): the residual of a DEM-backed
material stagnates near the peak at a floor set by the cells' slips, and a step there is as
converged as the cells allow. With `stagnation_its` = k as well, such a solve does not wait for
snes_max_it: it ends as soon as its best FNORM/RNORM is <= accept_rtol and has improved by less
than 10 % over the last k iterations (past the peak a DEM-backed step otherwise spends most of
its cap wandering at its floor: docs/reference/femdem.md, "Past the peak").

Reusing the Jacobian. With `jacobian_refresh` = c (in (0, 1), needs force_rtol) the Jacobian of
the first iteration of a solve is kept (a modified Newton: the callback leaves the assembled
matrix, and with it the factorisation, as it is) until an iteration reduces FNORM/RNORM by less
than the factor c; the next iteration builds it anew and keeps that one by the same rule. The converged state is the same equilibrium (the residual does not
depend on the operator); what changes is the number of operators built, against iterations.
Worth it where an operator costs more than a residual: a DEM cell's PSTLO operator (a sparse
LU per cell) costs one to two cell solves (docs/results/femdem.md, "Newton operators").

Damped updates. `set_step_damping(alpha)` (alpha in (0, 1]; None or 1: full steps) makes every
Newton update of the free dofs alpha times the correction, x += alpha dx; the Dirichlet rows
still take their full value, so the load of the step is applied at the first iteration as
without damping. Used by fallback.FallbackSolver's damped retry of a step that failed with full
updates. With a kept operator (jacobian_refresh = c) the rule that rebuilds it is scaled to the
damped step: an iteration that would contract by c undamped contracts by 1 - alpha (1 - c).
"""
from dataclasses import dataclass, field
import time

import dolfinx.fem.petsc
import numpy as np
from petsc4py import PETSc

from . import compat
from .constitutive import ConstitutiveError
from .validation import FRACTION, check_optional

DEFAULT_OPTIONS = {
    "snes_type": "newtonls",
    "snes_linesearch_type": "bt",
    "snes_rtol": 1e-10,
    "snes_atol": 1e-10,
    "snes_stol": 0.0,
    "snes_max_it": 25,
    "ksp_type": "preonly",
    "pc_type": "lu",
    "pc_factor_mat_solver_type": "mumps",
}

#: on more than one rank: every rank factors the whole matrix with sequential MUMPS (PETSc's
#: redundant preconditioner). MUMPS distributed over the ranks picks its slave processes by
#: their load while it factors, so the same system gives other round-off under another
#: machine load, and Newton, the cells and the load steps amplify it into another run
#: (docs/reference/robustness.md, "The same numbers"); redundant LU gives the same bits whatever the
#: load. `-pc_type lu` (on the command line or in the options) restores the distributed
#: factorisation, faster for large meshes on many ranks.
PARALLEL_OPTIONS = {
    "pc_type": "redundant",
    "redundant_pc_type": "lu",
    "redundant_pc_factor_mat_solver_type": "mumps",
}

REASONS = {getattr(PETSc.SNES.ConvergedReason, n): n
           for n in dir(PETSc.SNES.ConvergedReason) if n.isupper()}


@dataclass
class SolveInfo:
    converged: bool
    iterations: int
    residual: float
    reason: str
    residual_history: list = field(default_factory=list)
    failure: str = ""
    wall_time: float = 0.0
    force_ratios: list = field(default_factory=list)
    flags: str = ""     # a flagged Gauss point at the last iterate (e.g. a cell without contacts)
    accepted: bool = False   # ended at its best iterate above force_rtol but below accept_rtol
    fallback: str = ""       # the cause a first try with the material's own operator failed (fallback.py)
    damped: bool = False     # converged only when solved again with damped updates (fallback.py)


class NewtonSolver:
    """Newton solver of `problem` (a CosseratProblem); options override the defaults."""

    _count = 0

    #: a best FNORM/RNORM still above this fraction of the best of stagnation_its iterations
    #: before (it gained less than 10 %) has stagnated
    STAGNATION_GAIN = 0.9

    def __init__(self, problem, options=None, prefix="cosserat_", force_rtol=None, accept_rtol=None,
                 stagnation_its=None, jacobian_refresh=None):
        if force_rtol is not None and not (np.isfinite(force_rtol) and force_rtol > 0):
            raise ValueError(f"force_rtol must be a positive number, got {force_rtol!r}")
        if accept_rtol is not None and not (force_rtol is not None and np.isfinite(accept_rtol)
                                            and accept_rtol >= force_rtol):
            raise ValueError(f"accept_rtol must be a number >= force_rtol (and needs force_rtol), got {accept_rtol!r}")
        if stagnation_its is not None and not (accept_rtol is not None and isinstance(stagnation_its, (int, np.integer))
                                               and stagnation_its >= 1):
            raise ValueError(f"stagnation_its must be an integer >= 1 (and needs accept_rtol), got {stagnation_its!r}")
        if jacobian_refresh is not None and not (force_rtol is not None and 0 < jacobian_refresh < 1):
            raise ValueError(f"jacobian_refresh must be a number in (0, 1) (and needs force_rtol), "
                             f"got {jacobian_refresh!r}")
        self.problem = problem
        self.jacobian_refresh = jacobian_refresh
        self.stagnation_its = stagnation_its
        self._best_by_it = []
        self.force_rtol = force_rtol
        self.accept_rtol = accept_rtol
        self._best = (np.inf, None)
        self.residual_form, self.jacobian_form = problem.forms()
        self.x = compat.petsc_vector(problem.w)
        self.b = dolfinx.fem.petsc.create_vector(self.residual_form)
        self.A = dolfinx.fem.petsc.create_matrix(self.jacobian_form)
        self.snes = PETSc.SNES().create(problem.mesh.comm)
        # precedence: defaults < `options` < command line (-snes_* etc., stored unprefixed
        # by cli.forward_petsc_options); a unique prefix keeps solvers independent
        NewtonSolver._count += 1
        prefix = f"{prefix}{NewtonSolver._count}_"
        self.snes.setOptionsPrefix(prefix)
        self._failure, self._fatal, self._first_residual = "", False, True
        self._keep_jacobian = False
        self.step_damping = None
        self._precheck_installed = False
        opts = PETSc.Options()
        merged = dict(DEFAULT_OPTIONS)
        if problem.mesh.comm.size > 1:
            merged.update(PARALLEL_OPTIONS)
        merged.update(options or {})
        for key in opts.getAll():
            if key.split("_")[0] in ("snes", "ksp", "pc", "mat", "redundant"):
                merged[key] = opts[key]
        user = dict(options or {}, **{k: opts[k] for k in opts.getAll()})
        if merged["pc_type"] not in ("lu", "cholesky") and "pc_factor_mat_solver_type" not in user:
            del merged["pc_factor_mat_solver_type"]  # MUMPS is our default for LU only
        if merged["pc_type"] != "redundant":
            for key in PARALLEL_OPTIONS:
                if key.startswith("redundant_") and key not in user:
                    merged.pop(key, None)
        for key, value in merged.items():
            opts[prefix + key] = value
        self.snes.setFunction(self.residual, self.b)
        self.snes.setJacobian(self.jacobian, self.A)
        self.snes.setFromOptions()
        self._force_ratios = []
        if force_rtol is not None:
            self._bc_rows = self._owned_dirichlet_rows()
            self._free_rows = np.setdiff1d(np.arange(self.x.getLocalSize()), self._bc_rows)
            self.snes.setConvergenceTest(self._force_ratio_test)
        #: wall seconds: material (Gauss-point update and tangents), residual and Jacobian
        #: assembly, and the rest of the solves (linear solve, SNES, line search)
        self.timers = {"material": 0.0, "residual_assembly": 0.0, "jacobian_assembly": 0.0, "solve_total": 0.0}
        self.snes.getKSP().setFromOptions()
        self.snes.setConvergenceHistory(reset=True)   # one history per solve, not cumulative
        for key in merged:
            opts.delValue(prefix + key)

    def _owned_dirichlet_rows(self):
        n_owned = self.x.getLocalSize()
        rows = [bc.dof_indices()[0] for bc in self.problem.bcs]
        rows = np.unique(np.concatenate(rows)) if rows else np.zeros(0, dtype=np.int32)
        return rows[rows < n_owned]

    def _force_ratio_test(self, snes, it, norms):
        """Converged when |residual at free dofs| <= force_rtol |reactions| (after it 0)."""
        ratio = self._force_ratios[-1] if self._force_ratios else np.nan
        if np.isnan(ratio) or self._failure:
            return PETSc.SNES.ConvergedReason.DIVERGED_FNORM_NAN
        if it >= 1 and ratio <= self.force_rtol:
            return PETSc.SNES.ConvergedReason.CONVERGED_FNORM_RELATIVE
        if self.jacobian_refresh is not None and it >= 2 and ratio > self._refresh_factor() * self._force_ratios[-2]:
            self._keep_jacobian = False     # the kept operator has stopped paying: build the next one
        self._best_by_it.append(self._best[0])
        k = self.stagnation_its
        if k is not None and it > k:
            best, before = self._best_by_it[-1], self._best_by_it[-1 - k]
            if best <= self.accept_rtol and best > self.STAGNATION_GAIN * before:
                return PETSc.SNES.ConvergedReason.DIVERGED_MAX_IT   # solve() ends at the best iterate
        if it >= snes.getTolerances()[3]:
            return PETSc.SNES.ConvergedReason.DIVERGED_MAX_IT
        return PETSc.SNES.ConvergedReason.ITERATING

    def _refresh_factor(self):
        """The contraction below which a kept operator is kept, for the current step damping."""
        c, alpha = self.jacobian_refresh, self.step_damping
        return c if alpha is None else 1.0 - alpha * (1.0 - c)

    def set_step_damping(self, alpha):
        """Newton updates of the free dofs x += alpha dx from the next iteration on (alpha in
        (0, 1]; None: full steps, the default). Collective in effect: give every rank the same."""
        alpha = check_optional("step damping", alpha, FRACTION)
        self.step_damping = None if alpha is None or alpha == 1 else alpha
        if self.step_damping is not None and not self._precheck_installed:
            # the line search's pre-check may change the search direction y (x_new = x - lambda y):
            # with the basic line search (the FEM x DEM scene's) the update is alpha dx exactly
            self._damp_rows = self._free_dofs()
            self.snes.setLineSearchPreCheck(self._damp)
            self._precheck_installed = True

    def _free_dofs(self):
        if self.force_rtol is not None:
            return self._free_rows
        return np.setdiff1d(np.arange(self.x.getLocalSize()), self._owned_dirichlet_rows())

    def _damp(self, x, y):
        """Line-search pre-check: the correction of the free dofs scaled by the step damping."""
        if self.step_damping is None:
            return False
        with y.localForm() as local:
            local.array[self._damp_rows] *= self.step_damping
        return True

    def _force_ratio(self, b):
        """(FNORM / RNORM, RNORM) of the assembled residual b (before the Dirichlet rows are
        set): the norm at the free dofs over the norm of the reactions. Collective."""
        local = b.array_r
        reactions = float(np.sum(local[self._bc_rows] ** 2))
        free = float(np.sum(local[self._free_rows] ** 2))
        comm = self.problem.mesh.comm
        free, reactions = comm.allreduce(free), comm.allreduce(reactions)
        # no reaction yet (a step from rest): nothing to compare with, unless nothing is left
        ratio = np.sqrt(free / reactions) if reactions > 0 else (0.0 if free == 0 else np.inf)
        return (float(ratio) if np.isfinite(free) else np.nan), float(np.sqrt(reactions))

    def _record_force_ratio(self, b):
        """FNORM / RNORM of b appended to the solve's history; the best iterate kept."""
        ratio = self._force_ratio(b)[0]
        self._force_ratios.append(ratio)
        if self.accept_rtol is not None and self._residual_calls > 1 and ratio < self._best[0]:
            self._best = (float(ratio), self._x_now.array_r.copy())

    def probe_residual(self, x):
        """The residual at x without a Newton solve, for measuring it (needs force_rtol):
        the material is brought to x's state from its committed one, as a Newton iterate's
        would be, and left there. Returns (r, FNORM/RNORM, RNORM): r the residual at this
        rank's owned free dofs (a copy), RNORM the norm of the reactions. Collective; a
        material failure is a RuntimeError on every rank."""
        if self.force_rtol is None:
            raise ValueError("probe_residual measures FNORM/RNORM: the solver needs force_rtol")
        self._failure = ""
        self._set_fields(x)
        if self._material_step(self.problem.before_residual):
            raise RuntimeError(f"material update failed: {self._failure}")
        b = self.b.duplicate()
        with b.localForm() as local:
            local.set(0.0)
        dolfinx.fem.petsc.assemble_vector(b, self.residual_form)
        b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        ratio, reactions = self._force_ratio(b)
        free = b.array_r[self._free_rows].copy()
        b.destroy()
        return free, ratio, reactions

    def _set_fields(self, x):
        """The problem's fields set to the values of x (its ghosts refreshed first)."""
        x.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
        w = compat.petsc_vector(self.problem.w)
        if x.handle != w.handle:
            x.copy(w)
        self.problem.w.x.scatter_forward()

    def residual(self, snes, x, b):
        """The SNES function callback: b = F(x), the material updated first."""
        start, material = time.perf_counter(), self.timers["material"]
        try:
            self._assemble_residual(x, b)
        finally:   # the material's share is counted apart
            self.timers["residual_assembly"] += (time.perf_counter() - start
                                                 - (self.timers["material"] - material))

    def _assemble_residual(self, x, b):
        if self._failure:   # a collective failure in the tangents: stop SNES here
            with b.localForm() as local:
                local.set(np.nan)
            self._force_ratios.append(np.nan)
            return
        self._set_fields(x)
        self._x_now = x
        self._residual_calls += 1      # the first one is the committed state: never "best"
        failed = self._material_step(self.problem.before_residual)
        if not failed and self._first_residual:
            # the lifting below applies the Dirichlet increment of the step through the
            # Jacobian form, which reads the material tangent: make it current
            self._first_residual = False
            failed = self._material_step(self.problem.before_jacobian)
        if failed:
            with b.localForm() as local:
                local.set(np.nan)
            self._force_ratios.append(np.nan)
            return
        with b.localForm() as local:
            local.set(0.0)
        dolfinx.fem.petsc.assemble_vector(b, self.residual_form)
        if self.force_rtol is not None:
            b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
            self._record_force_ratio(b)
            with b.localForm() as local:   # undo the reverse scatter: lifting adds again below
                local.array[b.getLocalSize():] = 0.0
        compat.apply_lifting(b, self.jacobian_form, self.problem.bcs, x, -1.0)
        b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        compat.set_bc(b, self.problem.bcs, x, -1.0)

    def _material_step(self, step):
        """Run a material step (update or tangents) with the failure made collective before
        any MPI call: returns True (on every rank) when it failed on any rank."""
        start = time.perf_counter()
        failure, fatal = "", 0
        try:
            step()
        except ConstitutiveError as error:
            failure = str(error)
        except Exception as error:  # a bug on one rank must not leave the others waiting
            failure, fatal = f"{type(error).__name__}: {error}", 1
        self.timers["material"] += time.perf_counter() - start
        comm = self.problem.mesh.comm
        if comm.allreduce(1 if failure else 0) > 0:
            self._fatal = comm.allreduce(fatal) > 0
            self._failure = next(f for f in comm.allgather(failure) if f)
            return True
        return False

    def jacobian(self, snes, x, A, P):
        """The SNES Jacobian callback: A = dF/dx with the material's tangents (or A left as it
        is, so that its factorisation is reused, while jacobian_refresh keeps it)."""
        if self._keep_jacobian:
            return
        self._keep_jacobian = self.jacobian_refresh is not None
        failed = self._material_step(self.problem.before_jacobian)
        start = time.perf_counter()
        A.zeroEntries()
        if failed:   # a harmless matrix; the next residual is NaN and stops SNES
            A.assemble()
            A.shift(1.0)
        else:
            dolfinx.fem.petsc.assemble_matrix(A, self.jacobian_form, bcs=self.problem.bcs)
            A.assemble()
        self.timers["jacobian_assembly"] += time.perf_counter() - start

    def solve(self):
        """One nonlinear solve at the problem's current load. Collective."""
        self._failure, self._fatal = "", False
        self._force_ratios = []
        self._first_residual = True
        self._best = (np.inf, None)
        self._best_by_it = []
        self._residual_calls = 0
        self._keep_jacobian = False     # the first iteration's operator is built (then kept if refreshing)
        start = time.perf_counter()
        try:
            self.snes.solve(None, self.x)
        except PETSc.Error as error:
            # e.g. MUMPS refusing a singular matrix (every Gauss point of an element without
            # stiffness); the factorisation is collective, so every rank gets here
            self._failure = self._failure or f"linear solve failed (PETSc error {error.ierr}: singular Jacobian?)"
        if self._fatal:
            self.timers["solve_total"] += time.perf_counter() - start
            raise RuntimeError(f"material update failed: {self._failure}")
        self.problem.w.x.scatter_forward()
        reason = self.snes.getConvergedReason()
        history = list(self.snes.getConvergenceHistory()[0])
        store = self.problem.gauss_points
        flag = store.flag_message if store is not None else ""
        flags = next((f for f in self.problem.mesh.comm.allgather(flag) if f), "")
        converged = reason > 0 and not self._failure
        accepted = False
        if (not converged and not self._failure and self.accept_rtol is not None
                and self._best[0] <= self.accept_rtol):
            # end at the best iterate: re-evaluate it so that fluxes and material state are its own
            self.x.array[:] = self._best[1]
            self.x.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
            self._first_residual = False
            self.residual(self.snes, self.x, self.b)
            self.problem.w.x.scatter_forward()
            converged = accepted = not self._failure and self._force_ratios[-1] <= self.accept_rtol
            reason = "ACCEPTED_AT_STAGNATION"
        if not converged and not self._failure and self.force_rtol is not None and len(self._force_ratios) > 2:
            best = min(self._force_ratios[1:])
            if np.isfinite(best) and best > self.force_rtol:
                flags = (flags + "; " if flags else "") + (
                    f"FNORM/RNORM did not go below {best:.2g} (force_rtol = {self.force_rtol:g}): the cells' "
                    "response is not smooth at this scale (sliding, rearrangements); tighten the cells' "
                    "relaxation, use larger cells or loosen force_rtol")
        residual = self.snes.getFunctionNorm()
        if converged and not np.isfinite(residual):
            converged = False
        # the re-evaluation of an accepted iterate is part of the solve (its cell solves are in
        # timers["material"], which the split of the time subtracts from this total)
        self.timers["solve_total"] += time.perf_counter() - start
        return SolveInfo(converged=converged, iterations=self.snes.getIterationNumber(),
                         residual=residual, reason=reason if isinstance(reason, str) else REASONS.get(reason, str(reason)),
                         residual_history=history, failure=self._failure,
                         wall_time=time.perf_counter() - start, force_ratios=list(self._force_ratios),
                         flags=flags, accepted=accepted)

    def destroy(self):
        self.snes.destroy()
        self.A.destroy()
        self.b.destroy()
