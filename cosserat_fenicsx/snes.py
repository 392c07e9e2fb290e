"""PETSc SNES Newton (with line search) on a CosseratProblem, through petsc4py.

Defaults: newtonls with backtracking line search, a direct LU solve (MUMPS). Anything
given on the command line as -snes_*, -ksp_*, -pc_*, -mat_* overrides them (see
cli.forward_petsc_options). A Gauss-point failure (ConstitutiveError) on any rank turns
the residual into NaN on that rank, which makes the norm NaN on every rank: SNES stops
with DIVERGED_FNORM_NAN on all ranks together (no hang) and the cause is reported.
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

    def __init__(self, problem, options=None, prefix="cosserat_"):
        self.problem = problem
        self.residual_form, self.jacobian_form = problem.forms()
        self.x = compat.petsc_vector(problem.w)
        self.b = dolfinx.fem.petsc.create_vector(self.residual_form)
        self.A = dolfinx.fem.petsc.create_matrix(self.jacobian_form)
        self.snes = PETSc.SNES().create(problem.mesh.comm)
        self.snes.setOptionsPrefix(prefix)
        self._failure = ""
        # user (command-line) options win over our defaults and over `options`
        opts = PETSc.Options()
        merged = dict(DEFAULT_OPTIONS)
        merged.update(options or {})
        for key, value in merged.items():
            if not opts.hasName(key) and not opts.hasName(prefix + key):
                opts[prefix + key] = value
        for key in list(opts.getAll()):
            # unprefixed command-line options (-snes_rtol ...) apply to this solver
            if not key.startswith(prefix) and key.split("_")[0] in ("snes", "ksp", "pc", "mat"):
                opts[prefix + key] = opts[key]
        self.snes.setFunction(self._residual, self.b)
        self.snes.setJacobian(self._jacobian, self.A)
        self.snes.setFromOptions()
        self.snes.getKSP().setFromOptions()
        self.snes.setConvergenceHistory()

    def _residual(self, snes, x, b):
        x.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
        w = compat.petsc_vector(self.problem.w)
        if x.handle != w.handle:
            x.copy(w)
        self.problem.w.x.scatter_forward()
        try:
            self.problem.before_residual()
        except ConstitutiveError as error:
            self._failure = str(error)
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
        comm = self.problem.mesh.comm
        self._failure = ""
        start = time.perf_counter()
        self.snes.solve(None, self.x)
        self.problem.w.x.scatter_forward()
        reason = self.snes.getConvergedReason()
        history = list(self.snes.getConvergenceHistory()[0])
        failures = [f for f in comm.allgather(self._failure) if f]
        converged = reason > 0 and not failures
        residual = self.snes.getFunctionNorm()
        if converged and not np.isfinite(residual):
            converged = False
        return SolveInfo(converged=converged, iterations=self.snes.getIterationNumber(),
                         residual=residual, reason=REASONS.get(reason, str(reason)),
                         residual_history=history, failure=failures[0] if failures else "",
                         wall_time=time.perf_counter() - start)

    def destroy(self):
        self.snes.destroy()
        self.A.destroy()
        self.b.destroy()
