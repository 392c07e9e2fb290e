"""SQP solution of the identification problem (thesis section 4.2) with SciPy.

min f(s) = r(s).r(s) subject to bounds and g(s) >= 0 (4.1), (4.2), f of (4.18).

Section 4.2 solves the KKT system (4.8) by a Newton-like iteration (4.10) whose Hessian is
approximated (Table 4.1): gradient method, Gauss-Newton (4.13), Levenberg-Marquardt, or
BFGS (4.14, the thesis' choice).  Three SciPy solvers are offered:

``trf`` (default when the constraints reduce to bounds)
    scipy.optimize.least_squares(method="trf"): a trust-region iteration on the quadratic
    model with the Gauss-Newton Hessian 2 J^T J (4.13), bounds by reflection; the trust
    radius plays the role of the Levenberg-Marquardt damping (Table 4.1, row 3).  For a
    least-squares objective with bound constraints this *is* the SQP iteration of 4.2 with
    the GN Hessian, which the sensitivities make free.
``SLSQP`` (used when a nonlinear constraint (4.2) applies)
    Kraft's SQP: active-set QP subproblems (4.2.2), BFGS Hessian (4.14), line search (4.10);
    the thesis' method.  Measured on the 14-parameter re-identification
    (docs/results/identification.md): f 0.22 -> 6e-7 in 83 iterations with parameters still off by up
    to 11 % (BFGS cannot learn a condition number of 5e3 in 14 dimensions), where trf reaches
    5e-9 in 20 evaluations.
``trust-constr``
    SciPy's trust-region SQP / interior point, given the Gauss-Newton Hessian; slower than
    both here (barrier on the bounds), kept for comparison.

The optimiser sees the scaled variables z = s / scale.  Each model evaluation gives f and
the sensitivities together; results are cached by z so that separate calls for f and its
derivatives run the model once.  The best point seen is kept: an identification that stops
without converging still returns (and the demo writes) it, with the reason.

A solver's own "converged" is not taken on trust: a result is reported as not converged when
the model could not run a test at the best point (its Jacobian is zero there, so the
solver's gradient test proves nothing), or when the fit never left its start although the
start is not a stationary point (every trial step failed or made f worse).
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from .objective import Objective

METHODS = ("auto", "trf", "SLSQP", "trust-constr")
#: largest relative parameter change of SLSQP's first step (see _slsqp)
FIRST_STEP = 0.1


@dataclasses.dataclass
class IterationRecord:
    iteration: int
    f: float
    projected_gradient: float
    values: dict
    wall_time: float


@dataclasses.dataclass
class IdentificationResult:
    names: tuple
    values: np.ndarray          # identified (best) values, SI
    start: np.ndarray
    f: float
    f_start: float
    converged: bool
    message: str
    method: str
    iterations: int
    evaluations: int            # objective evaluations (each with sensitivities)
    history: list
    best: object                # Evaluation at the best point
    wall_time: float
    cpu_time: float

    def values_dict(self):
        return {n: float(v) for n, v in zip(self.names, self.values)}


def _projected_gradient(z, g, lo, hi):
    """Norm of the gradient with the components that push against an active bound removed."""
    pg = g.copy()
    pg[(z <= lo + 1e-12) & (g > 0)] = 0.0
    pg[(z >= hi - 1e-12) & (g < 0)] = 0.0
    return float(np.linalg.norm(pg))


class _Problem:
    """The scaled problem: cached evaluations, the best point, the iteration records."""

    def __init__(self, objective, progress):
        self.objective = objective
        self.pset = objective.parameter_set
        self.lo = self.pset.to_scaled(self.pset.lower)
        self.hi = self.pset.to_scaled(self.pset.upper)
        self.progress = progress
        self.cache = {}
        self.best = None
        self.history = []
        self.t0 = time.perf_counter()
        self.trials = 0
        self.failed_trials = 0
        self.first_failure = ""

    def evaluate(self, z):
        key = np.asarray(z, dtype=float).tobytes()
        if key not in self.cache:
            s = self.pset.from_scaled(np.clip(z, self.lo, self.hi))
            e = self.objective.evaluate(s, jacobian=True)
            self.cache.clear()  # only the latest point is asked for again
            self.cache[key] = e
            self.trials += 1
            if e.failures:
                self.failed_trials += 1
                if not self.first_failure:
                    label, why = next(iter(e.failures.items()))
                    self.first_failure = f"{label}: {why}"
            if self.best is None or e.f < self.best.f:
                self.best = e
        return self.cache[key]

    def gradient(self, z):
        return self.evaluate(z).gradient * self.pset.scale      # df/dz = df/ds * scale

    def record(self, z):
        e = self.evaluate(z)
        rec = IterationRecord(iteration=len(self.history), f=e.f,
                              projected_gradient=_projected_gradient(z, self.gradient(z), self.lo, self.hi),
                              values=self.pset.values(self.pset.from_scaled(z)),
                              wall_time=time.perf_counter() - self.t0)
        self.history.append(rec)
        if self.progress is not None:
            self.progress(rec)


def _trf(p, z0, max_iterations, ftol, gtol):
    from scipy import optimize
    last = {"z": None}

    def jac(z):
        # one Jacobian per accepted trust-region iteration: the progress line goes here
        if last["z"] is None or not np.array_equal(z, last["z"]):
            last["z"] = np.array(z)
            p.record(z)
        return p.evaluate(z).jacobian * p.pset.scale

    res = optimize.least_squares(lambda z: p.evaluate(z).residual, z0, jac=jac, bounds=(p.lo, p.hi),
                                 method="trf", x_scale="jac", ftol=ftol, xtol=1e-12, gtol=gtol,
                                 max_nfev=max_iterations + 1)   # ~ one evaluation per iteration
    return bool(res.status > 0), str(res.message)


def _slsqp(p, z0, max_iterations, ftol, constraints):
    from scipy import optimize
    # SLSQP's first step is steepest descent with a unit Hessian: -grad f in z.  f is scaled
    # so that this step changes the parameters by at most FIRST_STEP of their scale;
    # unscaled, a gradient of a few units sent the first trial to the bounds, where the model
    # fails (beta* = 0) and the failed runs cost 100 evaluations' time.
    g0 = np.linalg.norm(p.gradient(z0))
    fscale = min(1.0, FIRST_STEP / g0) if g0 > 0 else 1.0
    res = optimize.minimize(lambda z: (fscale * p.evaluate(z).f, fscale * p.gradient(z)), z0, jac=True,
                            method="SLSQP", bounds=optimize.Bounds(p.lo, p.hi), constraints=constraints,
                            callback=lambda z: p.record(np.asarray(z, dtype=float)),
                            options=dict(maxiter=max_iterations, ftol=ftol * fscale))
    return bool(res.success), str(res.message)


def _trust_constr(p, z0, max_iterations, gtol, constraints):
    from scipy import optimize

    def hess(z):
        Jz = p.evaluate(z).jacobian * p.pset.scale
        return 2.0 * Jz.T @ Jz        # Gauss-Newton (4.13)

    nlc = [optimize.NonlinearConstraint(c["fun"], 0.0, np.inf) for c in constraints]
    res = optimize.minimize(lambda z: (p.evaluate(z).f, p.gradient(z)), z0, jac=True, hess=hess,
                            method="trust-constr", bounds=optimize.Bounds(p.lo, p.hi), constraints=nlc,
                            callback=lambda z, state: p.record(np.asarray(z, dtype=float)),
                            options=dict(maxiter=max_iterations, gtol=gtol, xtol=1e-12))
    return bool(res.success), str(res.message)


def _stationary(p, z):
    """(stationary, |projected gradient|) at z: stationary within round-off when the
    projected gradient is below 1e-6 of the largest it could be, 2 |J| |r| (0 at an exact fit)."""
    e = p.evaluate(z)
    size = 2.0 * np.linalg.norm(e.jacobian * p.pset.scale) * np.linalg.norm(e.residual)
    pg = _projected_gradient(z, p.gradient(z), p.lo, p.hi)
    return pg <= 1e-6 * size, pg


#: a fit whose objective fell below this fraction of its start meets the data to round-off:
#: a sum of squares has its minimum there, whatever direction the round-off gradient points
EXACT_FIT = 1e-12


def _verdict(p, z0, converged, message, f_start):
    """The solver's (converged, message), checked against what happened (see module doc)."""
    failed = (f"the model failed at {p.failed_trials} of {p.trials} trial points (first: {p.first_failure})"
              if p.failed_trials else "")
    if p.best.failures:
        label, why = next(iter(p.best.failures.items()))
        return False, f"the model cannot run {', '.join(p.best.failures)} at the best point found ({label}: {why})"
    moved = not np.array_equal(p.best.s, p.pset.from_scaled(np.clip(z0, p.lo, p.hi)))
    exact = p.best.f <= EXACT_FIT * f_start
    if not exact and (not moved or p.failed_trials):
        stationary, pg = _stationary(p, p.pset.to_scaled(p.best.s))
        if not stationary and not moved:
            return False, (f"the fit did not move from its start, where the projected gradient is {pg:.3g}, not 0 "
                           f"(solver: {message})" + (f"; {failed}" if failed else ""))
        if not stationary:
            return False, (f"the fit stopped at the edge of the parameters the model can run, its projected "
                           f"gradient {pg:.3g} pointing beyond: {failed} (solver: {message})")
    return converged, message + (f"; {failed}" if failed else "")


def identify(objective: Objective, method="auto", max_iterations=60, ftol=1e-12, gtol=1e-10, progress=None):
    """Minimise `objective` from its parameter set's start.  method: one of METHODS ("auto":
    trf unless a nonlinear constraint applies, then SLSQP).  progress(IterationRecord):
    called once per iteration (the demo prints one line).  Returns an IdentificationResult."""
    if method not in METHODS:
        raise ValueError(f"identification method must be one of {METHODS}, got {method!r}")
    pset = objective.parameter_set
    constraints = []
    if pset.constraint_values(pset.start):
        constraints = [dict(type="ineq",
                            fun=lambda z: np.array(list(pset.constraint_values(pset.from_scaled(z)).values())))]
    if method == "auto":
        method = "SLSQP" if constraints else "trf"
    if method == "trf" and constraints:
        raise ValueError("identification: trf takes bounds only; the constraints "
                         f"{list(pset.constraint_values(pset.start))} need SLSQP or trust-constr")
    c0 = time.process_time()
    p = _Problem(objective, progress)
    z0 = pset.to_scaled(pset.start)
    f_start = p.evaluate(z0).f
    if method == "trf":
        converged, message = _trf(p, z0, max_iterations, ftol, gtol)
    elif method == "SLSQP":
        p.record(z0)
        converged, message = _slsqp(p, z0, max_iterations, ftol, constraints)
    else:
        p.record(z0)
        converged, message = _trust_constr(p, z0, max_iterations, gtol, constraints)
    converged, message = _verdict(p, z0, converged, message, f_start)
    e = p.best
    return IdentificationResult(names=pset.names, values=e.s.copy(), start=pset.start, f=e.f, f_start=f_start,
                                converged=converged, message=message, method=method,
                                iterations=max(len(p.history) - 1, 0), evaluations=objective.n_evaluations,
                                history=p.history, best=e, wall_time=time.perf_counter() - p.t0,
                                cpu_time=time.process_time() - c0)
