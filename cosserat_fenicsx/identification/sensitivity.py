"""Sensitivities of the virtual tests with respect to the Ehlers parameters (thesis chapter 5).

d q / d s_k, record by record, for the measured quantities q of a :class:`VirtualTest`
(axial_stress, volumetric_strain, pressure; also the abscissa axial_strain, which is
prescribed in a deviatoric test and so has zero sensitivity), two ways:

``semi-analytical``  (default, the faster) one run whose material point carries the
                     sensitivities along (section 5.2): per committed step, implicit
                     differentiation of the local system of Table 3.1
                     (materials/ehlers/sensitivity.py, Numba) and of the mixed control of the
                     driver (dS/ds = 0 on the stress-controlled components);
``numerical``        central differences (5.5) (or forward, 5.3) of whole test runs with the step
                     h_k = rel_k max(|s_k|, typical_k) (rel_k: DEFAULT_REL_STEP, from the step
                     study :func:`step_study`, benchmarks/identification/identification_sensitivity.py), the
                     perturbed runs checked to take the same discrete path.

Units SI: d q / d s_k per SI unit of s_k (e.g. Pa/Pa for d axial_stress / d mu).
No dolfinx.
"""

from __future__ import annotations

import numpy as np

from ..materials.ehlers.errors import MaterialPointError
from ..materials.ehlers.material import EhlersMaterial
from ..materials.ehlers.local_solver import S_SUBSTEPS
from ..materials.ehlers.material_point import MaterialPoint
from ..materials.ehlers.sensitivity import SENS_MESSAGES, step_sensitivity
from ..materials.ehlers.parameters import (P_BETA_STAR, P_C_BETA_D, P_C_BETA_V, P_C_DELTA_D,
                                           P_C_DELTA_V, P_C_EPS_D, P_C_EPS_V, P_C_GAMMA_D,
                                           P_C_GAMMA_V, P_DELTA_STAR, P_EPS_STAR, P_GAMMA_STAR,
                                           P_LMBDA, P_MU, P_N0, P_NMAX, P_PSI1, P_PSI2, STRESS_UNIT,
                                           EhlersParameters)
from ..validation import InputError

#: name -> (index in the kernel parameter array or -1 for an initial value, stress-like?,
#: typical scale [SI] for the difference step of a parameter that is 0 or tiny)
PARAMETERS = {
    "mu": (P_MU, True, 1e7), "lmbda": (P_LMBDA, True, 1e7),
    "n0": (P_N0, False, 0.1), "n_max": (P_NMAX, False, 0.1),
    "psi1": (P_PSI1, False, 0.1), "psi2": (P_PSI2, False, 0.1),
    "beta_star": (P_BETA_STAR, False, 0.01), "C_beta_V": (P_C_BETA_V, False, 1.0),
    "C_beta_D": (P_C_BETA_D, False, 1.0),
    "delta_star": (P_DELTA_STAR, True, 1e5), "C_delta_V": (P_C_DELTA_V, False, 1.0),
    "C_delta_D": (P_C_DELTA_D, False, 1.0),
    "epsilon_star": (P_EPS_STAR, True, 1e5), "C_epsilon_V": (P_C_EPS_V, False, 1.0),
    "C_epsilon_D": (P_C_EPS_D, False, 1.0),
    "gamma_star": (P_GAMMA_STAR, False, 0.1), "C_gamma_V": (P_C_GAMMA_V, False, 1.0),
    "C_gamma_D": (P_C_GAMMA_D, False, 1.0),
    "beta0": (-1, False, 0.01), "delta0": (-1, True, 1e5), "epsilon0": (-1, True, 1e5),
    "gamma0": (-1, False, 0.1),
}
#: the initial values: row of p = (beta, delta, epsilon, gamma) they seed
INITIAL = {"beta0": 0, "delta0": 1, "epsilon0": 2, "gamma0": 3}
#: the 14 parameters of the non-polar plasticity, thesis eq. (6.2)
PLASTICITY_14 = ("C_beta_D", "C_beta_V", "beta_star", "C_delta_D", "C_delta_V", "delta_star",
                 "C_epsilon_D", "C_epsilon_V", "epsilon_star", "C_gamma_D", "C_gamma_V",
                 "gamma_star", "psi1", "psi2")
#: the quantities differentiated (records of the driver's history)
QUANTITIES = ("axial_stress", "volumetric_strain", "pressure", "axial_strain")
METHODS = ("numerical", "semi-analytical")
#: the faster of the two (benchmarks/identification/identification_sensitivity.py: ~20x for a triaxial test
#: with 150 steps and 14 parameters; it costs ~1.5 runs against 2 m + 1)
DEFAULT_METHOD = "semi-analytical"
#: relative step of the central differences per parameter, chosen from the step study
#: (benchmarks/identification/identification_sensitivity.py): 1e-4 on the plateau between truncation and the
#: solver noise; n_max (the compression point, eq. 2.70, makes the elastic law strongly
#: nonlinear in it) needs 1e-5
DEFAULT_REL_STEP = dict({name: 1e-4 for name in PARAMETERS}, n_max=1e-5)
#: relative step of the residual differences inside the semi-analytical method
RESIDUAL_REL_STEP = 1e-5


def check_names(names):
    """The names as a tuple, or InputError naming the valid ones (before any run)."""
    if isinstance(names, str):
        names = (names,)
    names = tuple(names)
    bad = [n for n in names if n not in PARAMETERS]
    if bad or not names:
        raise InputError(f"sensitivity parameter(s) {bad or '(none given)'} not supported; valid names: "
                         f"{', '.join(PARAMETERS)}")
    if len(set(names)) != len(names):
        raise InputError(f"sensitivity parameter names repeated: {list(names)}")
    return names


def _material(parameters, **changes):
    return EhlersMaterial(**dict(parameters.as_dict(), **changes))


def _step(parameters, name, rel):
    _, _, typical = PARAMETERS[name]
    return rel * max(abs(float(getattr(parameters, name))), typical)


def _run(test, material, name=None, point=None, on_record=None):
    try:
        return test.run(material, point=point, on_record=on_record)
    except (MaterialPointError, ValueError) as error:
        what = f" with {name} perturbed" if name else ""
        raise MaterialPointError(f"sensitivity of the {test.label} test: the run{what} failed: {error}") from error


def _quantities(h):
    return {q: np.asarray(h[q], dtype=float) for q in QUANTITIES}


class _PathPoint(MaterialPoint):
    """A MaterialPoint that notes its discrete path (the kernel's substep count of every
    committed step; their number counts the driver's bisections) and whose mixed-control
    Newton stops at `tol` relative to the stress scale (None: the driver's 1e-7).  A tighter
    tol keeps the residual a step happened to stop at (up to 1e-7 |S|, ~1e-5 of a column after
    differencing, see the step study) out of the differences."""

    def __init__(self, material, tol=None):
        super().__init__(material)
        self.tol = tol
        self.path = []

    def step(self, stress_controlled, target, dt=1.0, tol=1e-7, max_iter=30):
        S = super().step(stress_controlled, target, dt, tol if self.tol is None else self.tol, max_iter)
        self.path.append(int(self.state[0, S_SUBSTEPS]))
        return S


def _rel_step(rel_step, name):
    if isinstance(rel_step, dict):
        return float(rel_step.get(name, DEFAULT_REL_STEP.get(name, 1e-4)))
    return float(rel_step)


#: how often the step of a parameter is divided by 4 when a perturbed run takes another path
PATH_RETRIES = 3


def numerical_sensitivities(parameters, test, names, rel_step=None, scheme="central", driver_tol=None,
                            kernel_tol=None, same_path="retry", base=None, diagnostics=None):
    """(h, dh) by differences of whole runs, thesis (5.3)/(5.5), step h_k = rel_k max(|s_k|,
    typical_k) (PARAMETERS).  rel_step: None (DEFAULT_REL_STEP per parameter), a float, or
    {name: float}; scheme "central" (2 runs per parameter) or "forward" (1).
    driver_tol: tolerance of the driver's mixed-control Newton in the perturbed runs (None: the
    driver's own 1e-7); kernel_tol: EhlersParameters.tol (local Newton, Table 3.1) of the
    perturbed runs (None: that of `parameters`).  With driver_tol=1e-9, kernel_tol=1e-12 the
    differences are free of the residuals the two Newton iterations stop at (which otherwise
    limit the agreement with the semi-analytical values to ~1e-5 of a column, and to ~1e-2
    of the noise floor in the hydrostatic test; see the step study).
    same_path: a difference is only a derivative when the perturbed runs take the discrete
    path of the unperturbed one (same driver bisections, same kernel substeps; a bisection
    moves the curve by far more than the step does).  "retry": divide the step by 4, up to
    PATH_RETRIES times, then MaterialPointError naming the parameter; "raise": at once;
    "ignore": difference whatever the path (step_study).
    base: the history at `parameters` if already computed (the h returned).  diagnostics
    (dict, optional): gets the relative step used per parameter ("rel_steps")."""
    names = check_names(names)
    if scheme not in ("central", "forward"):
        raise InputError(f"finite-difference scheme must be 'central' or 'forward', got {scheme!r}")
    if same_path not in ("retry", "raise", "ignore"):
        raise InputError(f"same_path must be 'retry', 'raise' or 'ignore', got {same_path!r}")
    rel_step = DEFAULT_REL_STEP if rel_step is None else rel_step
    for name in names:
        if not _rel_step(rel_step, name) > 0.0:
            raise InputError(f"relative finite-difference step of {name} must be > 0, "
                             f"got {_rel_step(rel_step, name)!r}")
    tight = {} if kernel_tol is None else dict(tol=float(kernel_tol))
    tol = None if driver_tol is None else float(driver_tol)

    def run(name=None, **change):
        material = _material(parameters, **change, **tight)
        pt = _PathPoint(material, tol)
        return _quantities(_run(test, material, name, point=pt)), pt.path

    if base is None or same_path != "ignore":
        material = _material(parameters)
        pt = _PathPoint(material)
        h0 = _run(test, material, point=pt)
        h = h0 if base is None else base
        path0 = pt.path
    else:
        h, path0 = base, None
    q0 = _quantities(h)
    if (tight or tol is not None) and (scheme == "forward" or same_path != "ignore"):
        q0, path0 = run()   # the reference path and values under the tolerances of the differences
    n = len(q0["axial_stress"])
    dh = {q: np.zeros((n, len(names))) for q in QUANTITIES}
    used = {}
    for k, name in enumerate(names):
        rel = _rel_step(rel_step, name)
        s = float(getattr(parameters, name))
        for attempt in range(PATH_RETRIES + 1 if same_path == "retry" else 1):
            step = _step(parameters, name, rel)
            runs, paths = [], []
            for sign in ((1.0, -1.0) if scheme == "central" else (1.0,)):
                try:
                    qk, path = run(name, **{name: s + sign * step})
                except ValueError as error:   # EhlersParameters refuses the value
                    raise MaterialPointError(f"sensitivity w.r.t. {name}: the perturbed value {s + sign * step!r} "
                                             f"is not admissible ({error}); choose a smaller step") from error
                if len(qk["axial_stress"]) != n:
                    raise MaterialPointError(f"sensitivity w.r.t. {name}: the perturbed {test.label} run has "
                                             f"{len(qk['axial_stress'])} records, the unperturbed one {n}")
                runs.append(qk)
                paths.append(path)
            if same_path == "ignore" or all(p == path0 for p in paths):
                break
            if same_path == "raise" or attempt == PATH_RETRIES:
                raise MaterialPointError(
                    f"sensitivity w.r.t. {name}: the perturbed {test.label} runs take another discrete path "
                    f"(driver bisections or kernel substeps: {[len(p) for p in paths]} steps against "
                    f"{len(path0)}) down to the relative step {rel:.3g}; the semi-analytical method does not "
                    f"need that")
            rel /= 4.0
        used[name] = rel
        for q in QUANTITIES:
            if scheme == "central":
                dh[q][:, k] = (runs[0][q] - runs[1][q]) / (2.0 * step)
            else:
                dh[q][:, k] = (runs[0][q] - q0[q]) / step
    if diagnostics is not None:
        diagnostics["rel_steps"] = used
    return h, dh


class _SensitivityFailure(RuntimeError):
    """Raised inside SensitivityPoint.step: not a MaterialPointError, so the driver's
    bisection (MaterialPoint.advance) does not take it for a failed load step."""


class SensitivityPoint(MaterialPoint):
    """A MaterialPoint that carries d(strain, stress, history)/d(parameters) along the path:
    after each committed step the local system and the mixed control are differentiated
    (materials/ehlers/sensitivity.step_sensitivity).  Attributes (internal units, per
    internal parameter unit): dE, dS (7, m), dEp (7, m), dp (4, m); tangent_mismatch: the
    largest relative difference between the replayed consistent tangent and the kernel's."""

    def __init__(self, material, names, analytic=True):
        super().__init__(material)
        self.names = check_names(names)
        m = len(self.names)
        params = material.params_array
        self._params = params
        self._pidx = np.array([PARAMETERS[nm][0] for nm in self.names], dtype=np.int64)
        su = STRESS_UNIT
        self._fd = np.array([RESIDUAL_REL_STEP * max(abs(params[i]) if i >= 0 else 0.0,
                                                    PARAMETERS[nm][2] / (su if PARAMETERS[nm][1] else 1.0))
                             for nm, i in zip(self.names, self._pidx)])
        self._analytic = bool(analytic)
        self.dE = np.zeros((7, m))
        self.dS = np.zeros((7, m))
        self.dEp = np.zeros((7, m))
        self.dp = np.zeros((4, m))
        for k, nm in enumerate(self.names):
            if nm in INITIAL:
                self.dp[INITIAL[nm], k] = 1.0   # p_0 = s (internal units both)
        self.tangent_mismatch = 0.0
        self.substeps_replayed = 0

    def step(self, stress_controlled, target, dt=1.0, tol=1e-7, max_iter=30):
        state_old = self.state[0].copy()
        S = super().step(stress_controlled, target, dt, tol, max_iter)
        C = np.zeros((7, 7))
        code, nsub = step_sensitivity(self.strain, float(dt), state_old, self.state[0], self._params,
                                      np.asarray(stress_controlled, dtype=bool), self._pidx, self._fd,
                                      self._analytic, self.dE, self.dEp, self.dp, self.dS, C)
        if code:
            raise _SensitivityFailure(f"step {len(self.newton_residuals)}: {SENS_MESSAGES[int(code)]}")
        if nsub > 1:
            self.substeps_replayed += 1
        ref = np.abs(self.tangent).max()
        self.tangent_mismatch = max(self.tangent_mismatch,
                                    float(np.abs(C * STRESS_UNIT - self.tangent).max() / ref) if ref > 0 else 0.0)
        return S


def semi_analytical_sensitivities(parameters, test, names, analytic=True, diagnostics=None):
    """(h, dh) from one run of a :class:`SensitivityPoint` (section 5.2).  analytic: the
    hardening rows of the sensitivity load term analytic (else residual differences too).
    diagnostics (dict, optional): filled with tangent_mismatch and substeps_replayed."""
    names = check_names(names)
    material = _material(parameters)
    point = SensitivityPoint(material, names, analytic)
    snaps = []

    def on_record(record):
        snaps.append((point.dS.copy(), point.dE.copy()))

    try:
        h = _run(test, material, point=point, on_record=on_record)
    except _SensitivityFailure as error:
        raise MaterialPointError(f"semi-analytical sensitivity of the {test.label} test failed at {error}") from None
    if len(snaps) != len(h["axial_stress"]):
        raise MaterialPointError(f"semi-analytical sensitivity of the {test.label} test: {len(snaps)} "
                                 f"sensitivity records for {len(h['axial_stress'])} history records")
    su = STRESS_UNIT
    # per SI unit of the parameter: internal stress-like parameters are in MPa
    per_si = np.array([1.0 / su if PARAMETERS[nm][1] else 1.0 for nm in names])
    dS = np.array([s for s, _ in snaps]) * su * per_si        # (n, 7, m) Pa per SI unit
    dE = np.array([e for _, e in snaps]) * per_si             # (n, 7, m)
    # strains counted from the first record (deviatoric phase, or an isotropic start pressure)
    dE_ref = dE[0] if test.counts_from_first_record else np.zeros_like(dE[0])
    in_plane = test.kind == "isotropic_plane_strain"   # VirtualTest.pressure: -(sig11 + sig22)/2
    dh = {"axial_stress": dS[:, 0, :],
          "pressure": -0.5 * (dS[:, 0, :] + dS[:, 1, :]) if in_plane else -dS[:, :3, :].mean(axis=1),
          "volumetric_strain": (dE[:, :3, :] - dE_ref[:3]).sum(axis=1),
          "axial_strain": dE[:, 0, :] - dE_ref[0]}
    if diagnostics is not None:
        diagnostics.update(tangent_mismatch=point.tangent_mismatch, substeps_replayed=point.substeps_replayed)
    return h, dh


def test_sensitivities(parameters, test, names, method=DEFAULT_METHOD, **options):
    """parameters: EhlersParameters; test: VirtualTest; names: EhlersParameters field names
    (see PARAMETERS); method "semi-analytical" (default, DEFAULT_METHOD) | "numerical".
    Returns (h, dh): h the history
    of test.run(EhlersMaterial(**parameters.as_dict())), dh = {q: (n_records, len(names))} for
    q in QUANTITIES, d q / d s_k per SI unit of s_k.  options: those of
    numerical_sensitivities (rel_step, scheme, driver_tol, kernel_tol, same_path, base,
    diagnostics) or of semi_analytical_sensitivities (analytic, diagnostics).
    InputError for unknown names, method or options (before any run); MaterialPointError
    naming the parameter when a (perturbed) run fails or ends with other records."""
    names = check_names(names)
    if not isinstance(parameters, EhlersParameters):
        raise InputError(f"parameters must be EhlersParameters, got {type(parameters).__name__}")
    if method not in METHODS:
        raise InputError(f"sensitivity method must be one of {METHODS}, got {method!r}")
    allowed = {"numerical": {"rel_step", "scheme", "driver_tol", "kernel_tol", "same_path", "base",
                             "diagnostics"},
               "semi-analytical": {"analytic", "diagnostics"}}[method]
    bad = sorted(set(options) - allowed)
    if bad:
        raise InputError(f"options {bad} not understood by the {method} method (valid: {sorted(allowed)})")
    if method == "numerical":
        return numerical_sensitivities(parameters, test, names, **options)
    return semi_analytical_sensitivities(parameters, test, names, **options)


test_sensitivities.__test__ = False   # not a pytest test despite its name


def step_study(parameters, test, names, rel_steps=tuple(10.0 ** -k for k in range(1, 10)), reference=None,
               driver_tol=None, kernel_tol=None):
    """Error of the central differences against `reference` (default: the semi-analytical
    dh) per relative step and parameter: {rel: {name: error or None}} (None: the perturbed
    value is not admissible or the run failed), error = max over the test's measured
    quantities of |dh_fd - dh_ref|_2 / max(|dh_ref|_2, floor) per column (norm over the
    records; floor = 1e-3 of the largest column of that quantity after scaling each column by
    max(|s_k|, typical_k), so a column that hardly matters is not judged relative to its
    noise).  Shows the plateau between truncation (large steps) and round-off / solver
    tolerance (small steps)."""
    names = check_names(names)
    if reference is None:
        base, reference = semi_analytical_sensitivities(parameters, test, names)
    else:
        base = None
    table = {}
    for rel in rel_steps:
        row = {}
        for k, name in enumerate(names):
            try:
                base, dfd = numerical_sensitivities(parameters, test, (name,), rel_step=float(rel),
                                                    driver_tol=driver_tol, kernel_tol=kernel_tol,
                                                    same_path="ignore", base=base)
            except MaterialPointError:
                row[name] = None
                continue
            row[name] = column_error(parameters, names, {q: dfd[q] for q in test.quantities}, reference,
                                     columns=(k,))
        table[float(rel)] = row
    return table


def parameter_scales(parameters, names):
    """max(|s_k|, typical_k of PARAMETERS) [SI]: the scale of each parameter (its step and error norms)."""
    return np.array([max(abs(float(getattr(parameters, n))), PARAMETERS[n][2]) for n in check_names(names)])


def column_error(parameters, names, dh, reference, columns=None, floor=1e-3):
    """Largest relative error of columns of dh against reference over the quantities in dh:
    |dh_k - ref_k|_2 / max(|ref_k|_2, floor * max_j |ref_j|_2 s_j / s_k), s = parameter_scales
    (dh may hold only the given columns, in their order)."""
    scales = parameter_scales(parameters, names)
    columns = range(len(names)) if columns is None else columns
    worst = 0.0
    for q, d in dh.items():
        ref = reference[q]
        norms = np.linalg.norm(ref, axis=0)
        top = (norms * scales).max()
        for a, k in enumerate(columns):
            col = d[:, a] if d.shape[1] == len(columns) else d[:, k]
            den = max(norms[k], floor * top / scales[k])
            if den > 0:
                worst = max(worst, float(np.linalg.norm(col - ref[:, k]) / den))
    return worst
