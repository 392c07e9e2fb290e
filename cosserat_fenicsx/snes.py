"""PETSc SNES Newton (with line search) on a CosseratProblem, through petsc4py.

Defaults: newtonls with backtracking line search, a direct LU solve (MUMPS). Anything
given on the command line as -snes_*, -ksp_*, -pc_*, -mat_* overrides them (see
cli.forward_petsc_options). A Gauss-point failure (ConstitutiveError) on any rank turns
the residual into NaN on every rank (the decision is reduced over the ranks before the
collective assembly steps, so nobody waits forever): SNES stops with DIVERGED_FNORM_NAN
on all ranks together and the cause is reported.
"""
from dataclasses import dataclass, field
import time

import dolfinx.fem.petsc
import numpy as np
from petsc4py import PETSc

from . import compat
from .constitutive import ConstitutiveError

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


class NewtonSolver:
    """Newton solver of `problem` (a CosseratProblem); options override the defaults."""

    _count = 0

    def __init__(self, problem, options=None, prefix="cosserat_"):
        self.problem = problem
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
        self._failure, self._fatal = "", False
        opts = PETSc.Options()
        merged = dict(DEFAULT_OPTIONS)
        merged.update(options or {})
        for key in opts.getAll():
            if key.split("_")[0] in ("snes", "ksp", "pc", "mat"):
                merged[key] = opts[key]
        user = dict(options or {}, **{k: opts[k] for k in opts.getAll()})
        if merged["pc_type"] not in ("lu", "cholesky") and "pc_factor_mat_solver_type" not in user:
            del merged["pc_factor_mat_solver_type"]  # MUMPS is our default for LU only
        for key, value in merged.items():
            opts[prefix + key] = value
        self.snes.setFunction(self._residual, self.b)
        self.snes.setJacobian(self._jacobian, self.A)
        self.snes.setFromOptions()
        self.snes.getKSP().setFromOptions()
        self.snes.setConvergenceHistory(reset=True)   # one history per solve, not cumulative
        for key in merged:
            opts.delValue(prefix + key)

    def _residual(self, snes, x, b):
        x.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
        w = compat.petsc_vector(self.problem.w)
        if x.handle != w.handle:
            x.copy(w)
        self.problem.w.x.scatter_forward()
        failure, fatal = "", 0
        try:
            self.problem.before_residual()
        except ConstitutiveError as error:
            failure = str(error)
        except Exception as error:  # a bug on one rank must not leave the others waiting
            failure, fatal = f"{type(error).__name__}: {error}", 1
        # the decision must be collective: assembly below has collective steps
        comm = self.problem.mesh.comm
        if comm.allreduce(1 if failure else 0) > 0:
            self._fatal = comm.allreduce(fatal) > 0
            self._failure = next(f for f in comm.allgather(failure) if f)
            with b.localForm() as local:
                local.set(np.nan)
            return
        with b.localForm() as local:
            local.set(0.0)
        dolfinx.fem.petsc.assemble_vector(b, self.residual_form)
        compat.apply_lifting(b, self.jacobian_form, self.problem.bcs, x, -1.0)
        b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        compat.set_bc(b, self.problem.bcs, x, -1.0)

    def _jacobian(self, snes, x, A, P):
        A.zeroEntries()
        dolfinx.fem.petsc.assemble_matrix(A, self.jacobian_form, bcs=self.problem.bcs)
        A.assemble()

    def solve(self):
        """One nonlinear solve at the problem's current load. Collective."""
        self._failure, self._fatal = "", False
        start = time.perf_counter()
        self.snes.solve(None, self.x)
        if self._fatal:
            raise RuntimeError(f"material update failed: {self._failure}")
        self.problem.w.x.scatter_forward()
        reason = self.snes.getConvergedReason()
        history = list(self.snes.getConvergenceHistory()[0])
        converged = reason > 0 and not self._failure
        residual = self.snes.getFunctionNorm()
        if converged and not np.isfinite(residual):
            converged = False
        return SolveInfo(converged=converged, iterations=self.snes.getIterationNumber(),
                         residual=residual, reason=REASONS.get(reason, str(reason)),
                         residual_history=history, failure=self._failure,
                         wall_time=time.perf_counter() - start)

    def destroy(self):
        self.snes.destroy()
        self.A.destroy()
        self.b.destroy()
