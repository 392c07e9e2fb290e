"""SQP solution of the identification problem (thesis section 4.2) with SciPy.

min f(s) subject to bounds and g(s) >= 0 (4.1), (4.2), f the objective of (4.18).

Method: SciPy's SLSQP by default.  It is the method of section 4.2 itself: sequential
quadratic programming on the Lagrangian (4.3), an active-set strategy for the inequality
constraints (4.2.2), a BFGS approximation of the Hessian (4.14) and a line search (4.10),
in Kraft's implementation; it takes the bounds and constraints directly and needs only f
and its gradient (5.1) per iteration.  "trust-constr" is available as an alternative and is
given the Gauss-Newton Hessian 2 J^T J of (4.13) (the sensitivities make it free), which
the least-squares structure suggests; measured in docs/identification.md.

The optimiser sees the scaled variables z = s / scale.  Each model evaluation computes f
and the sensitivities together (the gradient costs one sensitivity evaluation); results
are cached by z so that SciPy's separate calls for f and grad f run the model once.  The
best point seen is kept: an identification that stops without converging still returns
(and the demo writes) it, with the reason.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from .objective import Objective

#: largest relative parameter change of the first SQP step (see identify)
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


def identify(objective: Objective, method="SLSQP", max_iterations=50, ftol=1e-10, gtol=1e-6,
             progress=None):
    """Minimise `objective` from its parameter set's start.  progress(IterationRecord): called
    once per SQP iteration (the demo prints one line).  Returns an IdentificationResult."""
    from scipy import optimize
    pset = objective.parameter_set
    z0 = pset.to_scaled(pset.start)
    lo = pset.to_scaled(pset.lower)
    hi = pset.to_scaled(pset.upper)
    cache = {}
    best = {"e": None}
    t0, c0 = time.perf_counter(), time.process_time()

    def evaluate(z):
        key = np.asarray(z, dtype=float).tobytes()
        if key not in cache:
            s = pset.from_scaled(np.clip(z, lo, hi))
            e = objective.evaluate(s, jacobian=True)
            cache.clear()  # only the latest point is re-requested (f, then grad f)
            cache[key] = e
            if best["e"] is None or e.f < best["e"].f:
                best["e"] = e
        return cache[key]

    first = evaluate(z0)
    f_start = first.f
    # SLSQP's first step is steepest descent with a unit Hessian: -grad f in z.  f is scaled
    # so that this step changes the parameters by at most FIRST_STEP (10 %) of their scale;
    # unscaled, a gradient of a few units sent the first trial to the bounds, where the model
    # fails (beta* = 0) and the failed runs cost 100 evaluations' time.  BFGS learns the
    # curvature from there.
    g0 = np.linalg.norm(first.gradient * pset.scale)
    fscale = min(1.0, FIRST_STEP / g0) if g0 > 0 else 1.0

    def fun(z):
        e = evaluate(z)
        return fscale * e.f, fscale * e.gradient * pset.scale   # df/dz = df/ds * scale
    history = []

    def record(z, k):
        e = evaluate(z)
        g = e.gradient * pset.scale
        rec = IterationRecord(iteration=k, f=e.f, projected_gradient=_projected_gradient(z, g, lo, hi),
                              values=pset.values(pset.from_scaled(z)), wall_time=time.perf_counter() - t0)
        history.append(rec)
        if progress is not None:
            progress(rec)

    record(z0, 0)
    bounds = optimize.Bounds(lo, hi)
    cons = []
    if pset.constraint_values(pset.start):
        def g_of(z):
            return np.array(list(pset.constraint_values(pset.from_scaled(z)).values()))
        cons = [dict(type="ineq", fun=g_of)]
    counter = {"k": 0}

    def callback(z, *args):
        counter["k"] += 1
        record(np.asarray(z, dtype=float), counter["k"])

    if method == "SLSQP":
        res = optimize.minimize(fun, z0, jac=True, method="SLSQP", bounds=bounds, constraints=cons,
                                callback=callback, options=dict(maxiter=max_iterations, ftol=ftol * fscale))
    elif method == "trust-constr":
        def hess(z):
            e = evaluate(z)
            Jz = e.jacobian * pset.scale
            return fscale * 2.0 * Jz.T @ Jz        # Gauss-Newton (4.13)
        nlc = []
        if cons:
            nlc = [optimize.NonlinearConstraint(cons[0]["fun"], 0.0, np.inf)]
        res = optimize.minimize(fun, z0, jac=True, hess=hess, method="trust-constr", bounds=bounds,
                                constraints=nlc, callback=lambda z, state: callback(z),
                                options=dict(maxiter=max_iterations, gtol=gtol, xtol=1e-10))
    else:
        raise ValueError(f"identification method must be 'SLSQP' or 'trust-constr', got {method!r}")
    e = best["e"]
    g = e.gradient * pset.scale
    converged = bool(res.success)
    message = str(res.message)
    if not converged and _projected_gradient(pset.to_scaled(e.s), g, lo, hi) <= gtol * max(1.0, e.f):
        converged, message = True, message + " (projected gradient below gtol at the best point)"
    return IdentificationResult(names=pset.names, values=e.s.copy(), start=pset.start, f=e.f, f_start=f_start,
                                converged=converged, message=message, iterations=counter["k"],
                                evaluations=objective.n_evaluations, history=history, best=e,
                                wall_time=time.perf_counter() - t0, cpu_time=time.process_time() - c0)
