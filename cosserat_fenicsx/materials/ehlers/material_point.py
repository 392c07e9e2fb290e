"""Material-point driver: one Gauss point, no mesh, no dolfinx.

Homogeneous tests of the thesis (A.1, A.2, section 6.1.2) with mixed control.  The
point is driven through the *generalised* 7-component path of the kernel
(EhlersMaterial.update_generalised): [eps11, eps22, eps33, eps12, eps21, kappa31,
kappa32] with the total eps33 free, so that a triaxial test (lateral stress -p on
both the 2 and the 3 direction, eps33 != 0) and a plane-strain biaxial test
(eps33 = 0, sig33 from the model) use the very same kernel as the FE.  Each
component is either strain- or stress-controlled; the unknown strains of the
stress-controlled components are found by a Newton iteration with the consistent
tangent (3.37), so its quadratic convergence is visible in ``newton_residuals``.

Axes as in the thesis: e1 axial/vertical, e2 lateral, e3 out-of-plane (spec 0).
SI units, tension positive: a confining pressure p > 0 means sig22 = -p.
"""

from __future__ import annotations

import numpy as np

from ...validation import AXIAL_STRAIN, NON_NEGATIVE, POSITIVE, STEPS, InputError, check
from .errors import MaterialPointError
from .local_solver import S_EPS_P, S_EPV_OFFSET, S_STRAIN, STATE_SIZE

GENERALISED = ("11", "22", "33", "12", "21", "31", "32")


class MaterialPoint:
    """One Gauss point with committed history, advanced by mixed-control load steps."""

    def __init__(self, material, state=None):
        self.material = material
        self.state = material.initial_state(1) if state is None else np.array(state, dtype=float).reshape(1, STATE_SIZE)
        self.strain = self.state[0, S_STRAIN:S_STRAIN + 7].copy()
        self.stress = np.zeros(7)
        self.tangent = None
        self.newton_residuals = []

    def _evaluate(self, strain, dt):
        f = np.zeros((1, 7))
        t = np.zeros((1, 7, 7))
        s = np.zeros((1, STATE_SIZE))
        self.material.update_generalised(strain.reshape(1, 7), dt, self.state, f, t, s)
        return f[0], t[0], s

    def step(self, stress_controlled, target, dt=1.0, tol=1e-7, max_iter=30):
        """One load step.  stress_controlled: bool (7,); target (7,): stress [Pa] for the
        stress-controlled components, total strain for the others.  Commits on success,
        raises MaterialPointError otherwise (the history is then unchanged)."""
        mask = np.asarray(stress_controlled, dtype=bool)
        target = np.asarray(target, dtype=float)
        E = self.strain.copy()
        E[~mask] = target[~mask]
        if mask.any() and self.tangent is not None:
            # predictor with the last tangent: K_uu dE_u = dsig_target - K_uk dE_k
            K = self.tangent
            rhs = (target[mask] - self.stress[mask]) - K[np.ix_(mask, ~mask)] @ (E[~mask] - self.strain[~mask])
            try:
                E[mask] += np.linalg.solve(K[np.ix_(mask, mask)], rhs)
            except np.linalg.LinAlgError:
                pass
        scale = max(np.abs(target[mask]).max() if mask.any() else 0.0, 1e3)
        history = []
        for _ in range(max_iter):
            S, C, s_new = self._evaluate(E, dt)
            r = S[mask] - target[mask]
            res = float(np.abs(r).max()) if mask.any() else 0.0
            history.append(res)
            if res <= tol * scale:
                self.strain, self.stress, self.tangent, self.state = E, S, C, s_new
                self.newton_residuals.append(history)
                return S
            try:
                E[mask] -= np.linalg.solve(C[np.ix_(mask, mask)], r)
            except np.linalg.LinAlgError:
                raise MaterialPointError("material-point driver: singular tangent of the stress-controlled "
                                         "components (no stiffness left to find their strains)") from None
        raise MaterialPointError(f"material-point driver: mixed-control Newton did not converge "
                                 f"(residuals {history[-3:]} Pa)")

    #: bisections of a load step before advance() gives up (an identification lowers it: a
    #: parameter set the model cannot follow with much smaller steps is a failed evaluation)
    max_cuts = 12

    def advance(self, stress_controlled, target, dt=1.0, max_cuts=None):
        """step() with bisection of the increment (and dt) when the point update fails."""
        max_cuts = self.max_cuts if max_cuts is None else max_cuts
        start_target = np.where(stress_controlled, self.stress, self.strain)
        target = np.asarray(target, dtype=float)
        done, frac = 0.0, 1.0
        cuts = 0
        while done < 1.0 - 1e-12:
            f = min(frac, 1.0 - done)
            try:
                self.step(stress_controlled, start_target + (done + f) * (target - start_target), dt * f)
                done += f
            except MaterialPointError:
                cuts += 1
                if cuts > max_cuts:
                    raise
                frac = f / 2.0
        return self.stress


def _record(pt, out, e_ref):
    st = pt.state[0]
    out.append(dict(
        eps11=pt.strain[0], eps22=pt.strain[1], eps33=pt.strain[2],
        sig11=pt.stress[0], sig22=pt.stress[1], sig33=pt.stress[2],
        axial_strain=pt.strain[0] - e_ref[0],
        volumetric_strain=pt.strain[:3].sum() - e_ref[:3].sum(),
        axial_stress=pt.stress[0],
        mean_stress=pt.stress[:3].mean(),
        in_plane_pressure=-0.5 * (pt.stress[0] + pt.stress[1]),
        beta=st[7], delta=st[8], epsilon=st[9], gamma=st[10],
        yield_function=st[13], eps_p_vol=st[S_EPS_P:S_EPS_P + 3].sum(),
        newton_iterations=len(pt.newton_residuals[-1]) if pt.newton_residuals else 0))


def _as_arrays(records, pt=None):
    h = {k: np.array([r[k] for r in records]) for k in records[0]}
    if pt is not None:
        h["newton_residuals"] = pt.newton_residuals  # per step, max |stress residual| [Pa]
    return h


def consolidate(pt, sigma, n_steps=40, plane_strain=False, dt=1.0, records=None, e_ref=None, path=None):
    """Stress-controlled proportional loading from the current state to diagonal ``sigma``
    (sig11, sig22, sig33) [Pa]; with plane_strain the total eps33 stays 0 instead and
    only sig11, sig22 are prescribed (sig33 follows from the model). Returns the records
    of the steps (appended to `records` when given, so a caller keeps them on failure);
    their strains are counted from e_ref (7,) (default: zero).  path: a LoadPath of the
    fractions of the way to ``sigma`` at the step ends and their time steps (default:
    n_steps equal steps of dt)."""
    sigma = np.broadcast_to(np.asarray(sigma, dtype=float), (3,))
    mask = np.array([True, True, not plane_strain, False, False, False, False])
    s0 = pt.stress.copy()
    recs = [] if records is None else records
    for k, dt_k in (_uniform(n_steps, dt) if path is None else path.steps()):
        tgt = np.zeros(7)
        tgt[:3] = s0[:3] + k * (sigma - s0[:3]) if path is not None else s0[:3] + k / n_steps * (sigma - s0[:3])
        if plane_strain:
            tgt[2] = 0.0
        pt.advance(mask, tgt, dt_k)
        _record(pt, recs, np.zeros(7) if e_ref is None else e_ref)
    return recs


def _uniform(n_steps, dt):
    """(k, dt) of n_steps equal steps: the step ends are k / n_steps of the way."""
    return ((k, dt) for k in range(1, n_steps + 1))


class LoadPath:
    """A non-uniform load path of one phase: ``fractions`` (n,) of the way from the phase's
    start to its end at each step end (increasing, the last 1), and ``dts`` (n,) the time
    of each step [s].  A test run along the abscissae of measured data (each data point a
    step end) uses one, so that the model's discretisation follows the data's."""

    def __init__(self, fractions, dts):
        self.fractions = np.asarray(fractions, dtype=float)
        self.dts = np.asarray(dts, dtype=float)
        f, d = self.fractions, self.dts
        if f.ndim != 1 or f.size == 0 or d.shape != f.shape:
            raise InputError(f"load path: fractions {f.shape} and time steps {d.shape} must be equal, non-empty 1D")
        if not (np.all(np.isfinite(f)) and np.all(np.diff(np.concatenate([[0.0], f])) > 0)
                and abs(f[-1] - 1.0) <= 1e-12):
            raise InputError("load path: the fractions must increase from above 0 to 1")
        if not (np.all(np.isfinite(d)) and np.all(d > 0)):
            raise InputError("load path: every time step must be finite and > 0")

    def __len__(self):
        return self.fractions.size

    def steps(self):
        return zip(self.fractions, self.dts)


def consolidate_state(material, sigma0, n_steps=40):
    """History row of a point consolidated to diagonal sigma0 and re-referenced to zero strain.

    The total strain of the consolidation is subtracted from the plastic strain (so
    E - E_p, hence the stress, is unchanged at E = 0) and the volumetric part of that
    shift is kept in 'eps_p_vol_offset' so that eps_crit(eps_p^V) (2.70) is unchanged.
    """
    pt = MaterialPoint(material)
    consolidate(pt, sigma0, n_steps=n_steps)
    st = pt.state[0].copy()
    E = st[S_STRAIN:S_STRAIN + 7].copy()
    st[S_EPS_P:S_EPS_P + 7] -= E
    st[S_EPV_OFFSET] += E[:3].sum()
    st[S_STRAIN:S_STRAIN + 7] = 0.0
    return st


def compression_point_ratio(pt):
    """eps_e^V / eps_crit of the committed state (both < 0 in compression; 1 at the
    compression point, eqs. 2.67, 2.70)."""
    st = pt.state[0]
    p = pt.material.parameters
    eps_p_vol = st[S_EPS_P:S_EPS_P + 3].sum()
    eps_crit = 1.0 - p.n_max / (p.n0 * (1.0 - eps_p_vol - st[S_EPV_OFFSET]))
    eps_e_vol = st[S_STRAIN:S_STRAIN + 3].sum() - eps_p_vol
    return float(eps_e_vol / eps_crit)


def _check_test(confining, axial_strain, n_steps, n_consolidation, dt):
    """InputError (a ValueError) naming the argument, before any kernel runs."""
    check("confining pressure", confining, POSITIVE)
    check("axial_strain", axial_strain, AXIAL_STRAIN)
    check("n_steps", n_steps, STEPS)
    check("n_consolidation", n_consolidation, STEPS)
    check("dt", dt, POSITIVE)


class _Records(list):
    """The history records of a test; `on_record(record)` (optional) hears each as it
    is appended, so a caller can write the history as the test goes."""

    def __init__(self, on_record=None):
        super().__init__()
        self.on_record = on_record

    def append(self, record):
        super().append(record)
        if self.on_record is not None:
            self.on_record(record)


def _run_test(pt, recs, load, stop_on_failure):
    """Run load() (which appends a record per converged step to recs) and return the
    history arrays with h["stopped"]: "" when every step converged. A MaterialPointError
    is raised, or with stop_on_failure ends the test at the last converged step, its
    message (the cause, e.g. the compression point) in h["stopped"]."""
    stopped = ""
    try:
        load()
    except MaterialPointError as error:
        if not stop_on_failure:
            raise
        ratio = compression_point_ratio(pt)
        near = (f"; its elastic volumetric strain is at {100 * ratio:.1f} % of the compression point "
                f"eps_crit (eq. 2.70), where the elastic law stiffens without bound" if ratio > 0.5 else "")
        stopped = (f"stopped at the last converged state (mean stress {pt.stress[:3].mean() / 1e3:.6g} kPa, "
                   f"axial strain {pt.strain[0]:.6g}){near}: {error}")
    if not recs:                      # failed in the first step: the initial state
        _record(pt, recs, pt.strain.copy())
    h = _as_arrays(recs, pt)
    h["stopped"] = stopped
    return h


def _new_point(material, point):
    """The point a test drives: a fresh MaterialPoint, or `point` (e.g. a subclass that
    carries parameter sensitivities along the path) when given, which must be fresh."""
    if point is None:
        return MaterialPoint(material)
    if point.material is not material or point.newton_residuals:
        raise ValueError("material-point test: `point` must be a fresh point of the same material")
    return point


def _isotropic(pt, recs, p_max, n_steps, plane_strain, dt, p_start, n_consolidation, path):
    """Isotropic compression to p_max; with p_start > 0 the point is first consolidated to
    p_start (not recorded) and the records start there, strains counted from that state.
    path: a LoadPath of the recorded phase (fractions of the way from p_start to p_max)."""
    if p_start > 0.0:
        consolidate(pt, -p_start, n_steps=n_consolidation, plane_strain=plane_strain, dt=dt)
        e_ref = pt.strain.copy()
        _record(pt, recs, e_ref)
        consolidate(pt, -p_max, n_steps=n_steps, plane_strain=plane_strain, dt=dt, records=recs, e_ref=e_ref,
                    path=path)
    else:
        consolidate(pt, -p_max, n_steps=n_steps, plane_strain=plane_strain, dt=dt, records=recs, path=path)


def _check_start(p_start, p_max):
    check("p_start", p_start, NON_NEGATIVE)
    if not p_start < p_max:
        raise InputError(f"p_start = {p_start:g} Pa must be below p_max = {p_max:g} Pa")


def hydrostatic_test(material, p_max=1.0e6, n_steps=200, dt=1.0, stop_on_failure=False, on_record=None,
                     point=None, p_start=0.0, n_consolidation=40, path=None):
    """Hydrostatic compression to mean stress -p_max (A.1): sig11 = sig22 = sig33 = -p.
    (stop_on_failure: _run_test; on_record(record): called as each step's record is made;
    point: the MaterialPoint to drive, see _new_point; p_start, path: see _isotropic.)"""
    _check_test(p_max, 0.1, n_steps, n_consolidation, dt)
    _check_start(p_start, p_max)
    pt = _new_point(material, point)
    recs = _Records(on_record)
    return _run_test(pt, recs, lambda: _isotropic(pt, recs, p_max, n_steps, False, dt, p_start, n_consolidation,
                                                  path), stop_on_failure)


def isotropic_plane_strain_test(material, p_max=1.0e6, n_steps=200, dt=1.0, stop_on_failure=False,
                                on_record=None, point=None, p_start=0.0, n_consolidation=40, path=None):
    """Isotropic compression in plane strain: sig11 = sig22 = -p, eps33 = 0 (sig33 from the
    model), p increased to p_max.  The 2D counterpart of the hydrostatic test, as a periodic
    disc cell runs it (its pressure is the in-plane one, -(sig11 + sig22)/2, its 'volumetric'
    strain eps11 + eps22, the area change).  p_start, path: see _isotropic."""
    _check_test(p_max, 0.1, n_steps, n_consolidation, dt)
    _check_start(p_start, p_max)
    pt = _new_point(material, point)
    recs = _Records(on_record)
    return _run_test(pt, recs, lambda: _isotropic(pt, recs, p_max, n_steps, True, dt, p_start, n_consolidation,
                                                  path), stop_on_failure)


def _compression(pt, recs, mask, lateral, confining, axial_strain, n_steps, dt, change=None, path=None):
    """The deviatoric phase of the triaxial and biaxial tests: eps11 decreased by
    axial_strain in n_steps from the current state (or changed by the signed `change`),
    -confining on the `lateral` components; strains counted from the start of the phase.
    recs None: the phase is not recorded.  path: a LoadPath (its fractions of the change
    and time steps) instead of n_steps equal steps of dt."""
    e_ref = pt.strain.copy()
    change = -axial_strain if change is None else change
    if recs is not None:
        _record(pt, recs, e_ref)
    for k, dt_k in (_uniform(n_steps, dt) if path is None else path.steps()):
        tgt = np.zeros(7)
        tgt[0] = e_ref[0] + change * k if path is not None else e_ref[0] + change * k / n_steps
        tgt[lateral] = -confining
        pt.advance(mask, tgt, dt_k)
        if recs is not None:
            _record(pt, recs, e_ref)


def triaxial_test(material, confining=100e3, axial_strain=0.15, n_steps=600, n_consolidation=40, dt=1.0,
                  stop_on_failure=False, on_record=None, point=None, path=None):
    """Triaxial compression (A.1): isotropic consolidation to -p, then eps11 decreased by
    ``axial_strain`` at constant lateral stress sig22 = sig33 = -p (eps22 = eps33 free).
    Axial and volumetric strains are counted from the start of the deviatoric phase.
    path: a LoadPath of the deviatoric phase instead of n_steps equal steps of dt."""
    _check_test(confining, axial_strain, n_steps, n_consolidation, dt)
    pt = _new_point(material, point)
    recs = _Records(on_record)

    def load():
        consolidate(pt, -confining, n_steps=n_consolidation, dt=dt)
        mask = np.array([False, True, True, False, False, False, False])
        _compression(pt, recs, mask, [1, 2], confining, axial_strain, n_steps, dt, path=path)
    return _run_test(pt, recs, load, stop_on_failure)


def unloading_test(material, confining=100e3, unload_at=0.02, axial_strain=5e-4, n_steps=10, n_consolidation=40,
                   dt=1.0, stop_on_failure=False, on_record=None, point=None, n_loading=None, path=None):
    """An unloading branch of a triaxial test, the data of the elastic step 1(a) of the
    thesis' stepwise identification (4.3, eq. 4.19): consolidation to -p, axial compression
    to eps11 = -unload_at at sig22 = sig33 = -p (n_loading steps, 1e-3 each by default, not
    recorded), then eps11 *increased* by axial_strain in n_steps, recorded with the strains
    counted from the start of the unloading (positive axial strains).  Inside the yield
    surface the branch is elastic (2.70-2.74): it sees mu, lmbda and n_max, not the plasticity."""
    _check_test(confining, axial_strain, n_steps, n_consolidation, dt)
    check("unload_at", unload_at, AXIAL_STRAIN)
    n_loading = max(10, int(np.ceil(unload_at / 1e-3))) if n_loading is None else n_loading
    check("n_loading", n_loading, STEPS)
    pt = _new_point(material, point)
    recs = _Records(on_record)

    def load():
        consolidate(pt, -confining, n_steps=n_consolidation, dt=dt)
        mask = np.array([False, True, True, False, False, False, False])
        _compression(pt, None, mask, [1, 2], confining, unload_at, n_loading, dt)
        _compression(pt, recs, mask, [1, 2], confining, 0.0, n_steps, dt, change=axial_strain, path=path)
    return _run_test(pt, recs, load, stop_on_failure)


def biaxial_test(material, confining=100e3, axial_strain=0.15, n_steps=600, n_consolidation=40, dt=1.0,
                 stop_on_failure=False, on_record=None, point=None, path=None):
    """Homogeneous plane-strain biaxial test (A.2): consolidation sig11 = sig22 = -p with
    eps33 = 0, then eps11 decreased at sig22 = -p, eps33 = 0 (sig33 from the model).
    path: as for triaxial_test."""
    _check_test(confining, axial_strain, n_steps, n_consolidation, dt)
    pt = _new_point(material, point)
    recs = _Records(on_record)

    def load():
        consolidate(pt, -confining, n_steps=n_consolidation, plane_strain=True, dt=dt)
        mask = np.array([False, True, False, False, False, False, False])
        _compression(pt, recs, mask, [1], confining, axial_strain, n_steps, dt, path=path)
    return _run_test(pt, recs, load, stop_on_failure)


def summarize(h):
    """Peak (most compressive) axial stress, strain at peak, final volumetric strain, ..."""
    i = int(np.argmin(h["axial_stress"]))
    ev = h["volumetric_strain"]
    j = int(np.argmin(ev))
    extra = {}
    res = h.get("newton_residuals")
    if res:
        # the longest Newton history of a step: shows the convergence rate of the mixed-control
        # Newton that uses the consistent tangent (3.37)
        extra["newton_residuals_longest_step_Pa"] = [float(r) for r in max(res, key=len)]
    return dict(**extra,
        peak_axial_stress=float(h["axial_stress"][i]),
        axial_strain_at_peak=float(h["axial_strain"][i]),
        final_axial_stress=float(h["axial_stress"][-1]),
        final_axial_strain=float(h["axial_strain"][-1]),
        final_volumetric_strain=float(ev[-1]),
        min_volumetric_strain=float(ev[j]),
        axial_strain_at_min_volumetric_strain=float(h["axial_strain"][j]),
        max_yield_function=float(np.max(h["yield_function"])),
        max_newton_iterations=int(np.max(h["newton_iterations"])),
        n_points=int(len(ev)))


def finite_difference_tangent(material, strain7, state, dt=1.0, h=1e-7):
    """Consistent tangent (3.37) of the kernel and its central finite-difference estimate.

    strain7: total generalised strain [eps11, eps22, eps33, eps12, eps21, kappa31, kappa32]
    at t_n; state (state_size,) committed history.  Strain steps are h, curvature steps
    h / max(l_c, 1e-3 m) so that both perturb the stress by similar amounts.
    Returns (C, C_fd), both (7, 7) in SI (Pa, Pa m, Pa m^2).
    """
    E = np.asarray(strain7, dtype=float).reshape(1, 7)
    st = np.asarray(state, dtype=float).reshape(1, STATE_SIZE)

    def run(e):
        f = np.zeros((1, 7))
        t = np.zeros((1, 7, 7))
        s = np.zeros((1, STATE_SIZE))
        material.update_generalised(e, dt, st, f, t, s)
        return f[0], t[0]

    _, C = run(E)
    C_fd = np.zeros((7, 7))
    lc = max(material.parameters.l_c, 1e-3)
    for j in range(7):
        hj = h if j < 5 else h / lc
        ep = E.copy()
        ep[0, j] += hj
        em = E.copy()
        em[0, j] -= hj
        C_fd[:, j] = (run(ep)[0] - run(em)[0]) / (2.0 * hj)
    return C, C_fd
