"""Multi-criterion least-squares objective of the identification (thesis 4.15-4.18, 6.3).

For every test t and measured quantity q with N_tq data points (x_i, phi~_i):

    f(s) = sum_t sum_q  1 / (phi_0,tq^2 N_tq)  sum_i [phi_tq(x_i; s) - phi~_i]^2      (4.17), (4.18)

which is (6.3) term by term: one term per triaxial test and quantity (axial stress,
volumetric strain), the hydrostatic volumetric strain and the biaxial axial stress.  (6.3)
prints the normalisation as 1/sigma_0, (4.17) as 1/phi_0^2; the squared form is used here,
the one that makes f dimensionless.  The model value phi(x_i) is the material-point history
interpolated linearly at the data abscissa x_i, which is prescribed in every test (axial
strain, or pressure), so the interpolation weights do not depend on s and the sensitivity
of phi(x_i) is the same interpolation of the record sensitivities.

The objective works on the weighted residual vector r_n = sqrt(w_n) (phi_n - phi~_n) and its
Jacobian (f = r.r, grad f = 2 J^T r, Gauss-Newton Hessian 2 J^T J, eq. 4.13).  sqrt(w_n) =
1 / (phi_0 sqrt(N_tq)) is formed directly, so any finite data give finite weights.  A test
the model cannot run to its end adds one more residual, sqrt(FAILURE_PENALTY), so that a
least-squares solver sees the failure as a worse point and steps back.  Tests are
independent: with processes > 1 they are evaluated in parallel worker processes.
"""

from __future__ import annotations

import dataclasses
import os
import time

import numpy as np

from ..validation import InputError
from .parameter_set import MICROPOLAR, ParameterSet


@dataclasses.dataclass
class Evaluation:
    """One objective evaluation at s (the identified parameters in SI units)."""

    s: np.ndarray
    f: float
    residual: np.ndarray          # weighted, r_n = sqrt(w_n) (phi_n - phi~_n), then one per test: its penalty
    jacobian: np.ndarray | None   # weighted, dr_n / ds_k (zero rows for the penalties)
    raw_residual: np.ndarray      # phi_n - phi~_n
    raw_jacobian: np.ndarray | None   # d phi_n / d s_k
    curves: dict                  # label -> {"x": model abscissa, q: model values}
    stopped: dict                 # label -> why the model could not run the test ("" if it did)
    wall_time: float
    cpu_time: float

    @property
    def gradient(self):
        return 2.0 * self.jacobian.T @ self.residual

    @property
    def failures(self):
        """{test: why the model stopped} of the tests it could not run to their end."""
        return {label: why for label, why in self.stopped.items() if why}


def _interp_matrix(x_model, x_data):
    """Matrix P (n_data, n_model) with P @ y_model = linear interpolation at x_data (x_model
    monotonic, increasing or decreasing); outside the model's range the end value (a model
    run that stopped early gives a constant, hence large, residual there)."""
    xm = np.asarray(x_model, dtype=float)
    flip = xm.size > 1 and xm[-1] < xm[0]
    if flip:
        xm = xm[::-1]
    n = xm.size
    P = np.zeros((len(x_data), n))
    for i, x in enumerate(x_data):
        if n == 1 or x <= xm[0]:
            P[i, 0] = 1.0
        elif x >= xm[-1]:
            P[i, -1] = 1.0
        else:
            j = int(np.searchsorted(xm, x)) - 1
            j = min(max(j, 0), n - 2)
            t = (x - xm[j]) / (xm[j + 1] - xm[j])
            P[i, j] = 1.0 - t
            P[i, j + 1] = t
    return P[:, ::-1] if flip else P


def _with_origin(test, h, dh, quantities):
    """Model abscissa and values with the unloaded origin prepended for isotropic tests (their
    records start after the first pressure step; at p = 0 the volumetric strain is 0)."""
    x = np.asarray(h[test.abscissa], dtype=float)
    ys = {q: np.asarray(h[q], dtype=float) for q in quantities}
    ds = {q: (None if dh is None else np.asarray(dh[q], dtype=float)) for q in quantities}
    if not test.counts_from_first_record:
        x = np.concatenate([[0.0], x])
        for q in quantities:
            ys[q] = np.concatenate([[0.0], ys[q]])
            if ds[q] is not None:
                ds[q] = np.vstack([np.zeros((1, ds[q].shape[1])), ds[q]])
    return x, ys, ds


def evaluate_test(parameters, test, names, jacobian, sensitivity):
    """(h, dh) of one test: the history of the model run and, with `jacobian`, d(record)/ds."""
    if jacobian:
        from .sensitivity import test_sensitivities
        h, dh = test_sensitivities(parameters, test, list(names), method=sensitivity)
        test.derive(h, dh)
        return h, dh
    from ..materials.ehlers import EhlersMaterial
    h = test.run(EhlersMaterial(**parameters.as_dict()), stop_on_failure=True)
    return h, None


#: added to f for every test the model cannot run to its end with a parameter set: f is
#: dimensionless with terms of order (misfit / phi_0)^2, so 1 is "the data missed entirely"
FAILURE_PENALTY = 1.0


def _worker(args):
    """(h, dh, failure) of one test.  A model run that fails (MaterialPointError, e.g. the
    compression point reached, or a perturbed run of the finite differences) is run again
    without sensitivities and stopped at its last converged step: the objective then sees
    the truncated curve plus FAILURE_PENALTY and a zero gradient for that test, so a line
    search steps back from such a parameter set instead of ending the identification."""
    from ..materials.ehlers.errors import MaterialPointError
    parameters, test, names, jacobian, sensitivity = args
    try:
        h, dh = evaluate_test(parameters, test, names, jacobian, sensitivity)
        if not h.get("stopped"):
            return h, dh, ""
        reason = h["stopped"]
    except MaterialPointError as error:
        reason = str(error)
    except Exception as error:  # returned, re-raised in the parent with the test named
        return error
    try:
        h, _ = evaluate_test(parameters, test, names, False, sensitivity)
    except Exception as error:
        return error
    dh = None if not jacobian else {q: np.zeros((len(h[q]), len(names))) for q in test.quantities}
    return h, dh, reason or h.get("stopped", "failed")


def check_homogeneous(names):
    """InputError for parameters the homogeneous tests cannot see: the micropolar ones do not
    act there (sigma symmetric, m = 0, thesis 6.1.1)."""
    polar = [n for n in names if n in MICROPOLAR]
    if polar:
        raise InputError(f"identification: {polar} have no effect in homogeneous tests (thesis 6.1.1: the "
                         "stress stays symmetric, the couple stress zero); identify them from a biaxial FE run "
                         "with a band (benchmarks/identification/identify_micropolar.py)")


def _quiet_worker():
    """A worker leaves Ctrl-C and SIGTERM to its parent (whose RunGuard writes summary.json
    and exits): the forked copy of the parent's handler must not write the summary too.  A
    worker ends itself when its parent is gone (an interrupted run exits without shutting
    the pool down, and the forked siblings keep the task pipe open, so no EOF would come)."""
    import signal
    import threading
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    parent = os.getppid()

    def watch():
        while os.getppid() == parent:
            time.sleep(0.5)
        os._exit(0)

    threading.Thread(target=watch, daemon=True).start()


class Objective:
    """f(s) of (4.18) over a list of TestData, for the parameters of `parameter_set`."""

    def __init__(self, data, parameter_set: ParameterSet, sensitivity="semi-analytical", processes=1):
        if not data:
            raise InputError("identification: no test data")
        if sensitivity not in ("numerical", "semi-analytical"):
            raise InputError(f"sensitivity must be 'numerical' or 'semi-analytical', got {sensitivity!r}")
        check_homogeneous(parameter_set.names)
        self.data = list(data)
        self.parameter_set = parameter_set
        self.sensitivity = sensitivity
        self.processes = int(processes)
        self._pool = None
        self.n_evaluations = 0
        self.n_jacobians = 0
        # weights (4.17), data vector and its scatter, in one flat order: test, quantity, point
        sw, y, sig, self.blocks = [], [], [], []
        for d in self.data:
            for q in d.y:
                n = len(d.y[q])
                sw.append(np.full(n, (1.0 / d.normalisation[q]) / np.sqrt(n)))
                y.append(d.y[q])
                sig.append(d.std.get(q, np.full(n, np.nan)))
                self.blocks.append((d.label, q, n))
        #: sqrt(w_n) of (4.17); w_n itself may underflow for data of huge magnitude
        self.sqrt_weights = np.concatenate(sw)
        self.observed = np.concatenate(y)
        scatter = np.concatenate(sig)
        self.scatter = scatter if np.all(np.isfinite(scatter)) else None

    @property
    def n_data(self):
        return self.observed.size

    @property
    def weights(self):
        """w_n of (4.17)."""
        return self.sqrt_weights ** 2

    def close(self):
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None

    def _map(self, tasks):
        if self.processes <= 1 or len(tasks) == 1:
            return [_worker(t) for t in tasks]
        if self._pool is None:
            import concurrent.futures
            import multiprocessing
            self._pool = concurrent.futures.ProcessPoolExecutor(
                max_workers=min(self.processes, len(self.data)), mp_context=multiprocessing.get_context("fork"),
                initializer=_quiet_worker)
        return list(self._pool.map(_worker, tasks))

    def evaluate(self, s, jacobian=True):
        """Evaluation at s (SI values of parameter_set.names)."""
        return self._evaluate(s, jacobian, [d.test for d in self.data])

    def discretisation_error(self, s, factor=2, jacobian=None, names=None):
        """The model's discretisation error at s, estimated by running every test with its
        steps split in `factor` (Richardson for a first-order scheme: the error of the
        model as run is factor/(factor - 1) times the change): a dict with the objective
        that the error alone would make ("f"), its largest size per test and quantity in
        units of phi_0 ("largest"), and, when the data's scatter is known, its RMS in units
        of the scatter ("rms_over_scatter").  jacobian (N, P) at s, of the parameters
        `names`: also the shift of the fitted parameters that the error causes when the
        data follow the time-continuous model ("parameter_shift", the Gauss-Newton step
        -(J^T W J)^-1 J^T W e).  None when the model fails on the finer steps."""
        coarse = self.evaluate(s, jacobian=False)
        fine = self._evaluate(s, False, [d.test.refined(factor) for d in self.data])
        if coarse.failures or fine.failures:
            return None
        error = (coarse.raw_residual - fine.raw_residual) * factor / (factor - 1.0)
        weighted = self.sqrt_weights * error
        largest, k = {}, 0
        for d in self.data:
            for q in d.y:
                m = len(d.y[q])
                largest.setdefault(d.label, {})[q] = float(np.max(np.abs(error[k:k + m])) / d.normalisation[q])
                k += m
        out = dict(f=float(weighted @ weighted), largest=largest, steps_factor=factor,
                   method="Richardson: the tests run again with every step split in steps_factor (first order)")
        if self.scatter is not None:
            out["rms_over_scatter"] = float(np.sqrt(np.mean((error / self.scatter) ** 2)))
        if jacobian is not None:
            shift = -np.linalg.lstsq(self.sqrt_weights[:, None] * np.asarray(jacobian), weighted, rcond=None)[0]
            out["parameter_shift"] = dict(zip(names or self.parameter_set.names, map(float, shift)))
        return out

    def _evaluate(self, s, jacobian, tests):
        t0, c0 = time.perf_counter(), time.process_time()
        params = self.parameter_set.parameters(s)
        names = self.parameter_set.names
        results = self._map([(params, test, names, jacobian, self.sensitivity) for test in tests])
        model, dmodel, curves, stopped = [], [], {}, {}
        for d, test, res in zip(self.data, tests, results):
            if isinstance(res, Exception):
                raise type(res)(f"{d.label}: {res}") from res
            h, dh, failure = res
            stopped[d.label] = failure
            x, ys, ds = _with_origin(test, h, dh, list(d.y))
            P = _interp_matrix(x, d.x)
            curves[d.label] = dict(x=x, **ys)
            for q in d.y:
                model.append(P @ ys[q])
                if jacobian:
                    dmodel.append(P @ ds[q])
        phi = np.concatenate(model)
        raw = phi - self.observed
        sw = self.sqrt_weights
        penalties = np.array([np.sqrt(FAILURE_PENALTY) if stopped[d.label] else 0.0 for d in self.data])
        r = np.concatenate([sw * raw, penalties])
        J = Jw = None
        if jacobian:
            J = np.vstack(dmodel)
            Jw = np.vstack([sw[:, None] * J, np.zeros((penalties.size, J.shape[1]))])
            self.n_jacobians += 1
        self.n_evaluations += 1
        # the parent's CPU time; worker processes add theirs (reported by the caller's totals)
        return Evaluation(s=np.array(s, dtype=float), f=float(r @ r), residual=r, jacobian=Jw, raw_residual=raw,
                          raw_jacobian=J, curves=curves, stopped=stopped,
                          wall_time=time.perf_counter() - t0, cpu_time=time.process_time() - c0)

    def terms(self, evaluation):
        """The terms of (6.3): {test: {quantity: its contribution to f}}."""
        out, k = {}, 0
        for label, q, n in self.blocks:
            r = evaluation.residual[k:k + n]
            out.setdefault(label, {})[q] = float(r @ r)
            k += n
        return out

