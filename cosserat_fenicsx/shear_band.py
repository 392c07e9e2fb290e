"""Shear-band thickness and inclination by a Gaussian fit (thesis 004, section 4.4).

The norm of the strain e_i = |eps_i| at the integration points (x1_i, x2_i) is fitted with
a bell-shaped surface that is constant along the band axis (eq 4.22):

    e(x; r) = e0 + A exp(-d^2 / (2 H^2)),   d = (x1 - x10) cos(alpha) - x2 sin(alpha),

r = (e0, A, H, x10, alpha), by least squares (eq 4.23). The thesis solves h = grad f = 0
(4.24) by Newton with the exact Hessian (4.25); here the same objective is minimised by
Levenberg-Marquardt with the exact first derivatives of e (spec section 8 item 3), which
converges to the same minimiser and does not need the Hessian to be positive.

Axes as in the thesis: x1 is the vertical (axial) coordinate and x2 the horizontal one, so
in the (x, y) = (horizontal, vertical) coordinates of the FE mesh x1 = y and x2 = x.
Then alpha is the angle between the band axis and the horizontal, positive when the band
rises towards +x; x10 is the height where the band axis crosses x = 0.

**H is the standard deviation of the bell** (what the thesis calls "the thickness",
footnote in section 4.4). A width containing 95 % of the bell is 4H; the full width at half
maximum is 2 sqrt(2 ln 2) H = 2.355 H. Every report in this project gives H itself.
"""
from dataclasses import dataclass, asdict
import math

import numpy as np


@dataclass
class BandFit:
    thickness: float          # H, standard deviation of the bell [m]
    inclination_deg: float    # alpha to the horizontal, in (-90, 90] [deg]
    offset: float             # e0, background strain norm [-]
    amplitude: float          # A, peak strain norm above the background [-]
    x10: float                # height of the band axis at x = 0 [m]
    rms_residual: float       # sqrt(f / M) of eq 4.23 [-]
    iterations: int
    converged: bool

    def as_dict(self):
        return asdict(self)


def strain_norm(gradients):
    """e = |eps| of the total (non-symmetric) strain, the quantity fitted in section 4.4, from
    the callback gradients [eps11, eps22, eps12, eps21, kappa31, kappa32] (n, 6) [-]."""
    g = np.asarray(gradients)
    return np.sqrt(np.sum(g[:, :4] ** 2, axis=1))


def bell(points, r):
    """e(x; r) of eq 4.22 at points (n, 2) given as (x, y) = (x2, x1)."""
    e0, A, H, x10, alpha = r
    d = (points[:, 1] - x10) * math.cos(alpha) - points[:, 0] * math.sin(alpha)
    return e0 + A * np.exp(-d * d / (2.0 * H * H))


def _jacobian(points, r):
    """de/dr, the derivatives listed in spec section 8 item 3 (thesis 4.24)."""
    e0, A, H, x10, alpha = r
    x1, x2 = points[:, 1], points[:, 0]
    ca, sa = math.cos(alpha), math.sin(alpha)
    d = (x1 - x10) * ca - x2 * sa
    E = np.exp(-d * d / (2.0 * H * H))
    J = np.empty((len(points), 5))
    J[:, 0] = 1.0
    J[:, 1] = E
    J[:, 2] = A * E * d * d / H ** 3
    J[:, 3] = A * E * d * ca / H ** 2
    J[:, 4] = A * E * d * ((x1 - x10) * sa + x2 * ca) / H ** 2
    return J


def initial_guess(points, values):
    """Principal axis of the top-decile points (spec section 8 item 4)."""
    e0 = float(np.median(values))
    A = float(values.max() - e0)
    top = values >= np.quantile(values, 0.9)
    p = points[top]
    w = values[top] - e0
    w = w / w.sum() if w.sum() > 0 else np.full(len(p), 1.0 / len(p))
    centre = w @ p
    q = p - centre
    cov = (q * w[:, None]).T @ q
    evals, evecs = np.linalg.eigh(cov)
    axis = evecs[:, 1]                          # (dx, dy) along the band
    alpha = math.atan2(axis[1], axis[0])        # angle to the horizontal
    normal_spread = math.sqrt(max(evals[0], 0.0))
    extent = float(np.ptp(points, axis=0).max())
    H = max(normal_spread, 1e-3 * extent)
    # axis through the centre: d = 0 at (x, y) = centre
    x10 = centre[1] - centre[0] * math.tan(alpha) if abs(math.cos(alpha)) > 1e-12 else centre[1]
    return np.array([e0, A, H, x10, _wrap(alpha)])


def _wrap(alpha):
    """Same band line for alpha and alpha +- pi: keep alpha in (-pi/2, pi/2]. In one
    operation, not by repeated subtraction: a fit with no band to find can drift to a huge
    alpha (1e300 - pi == 1e300 loops forever)."""
    if not math.isfinite(alpha):
        return math.nan
    if -math.pi / 2 < alpha <= math.pi / 2:
        return alpha
    wrapped = math.fmod(alpha + math.pi / 2, math.pi)
    wrapped = wrapped + math.pi if wrapped < 0 else wrapped      # in [0, pi)
    wrapped -= math.pi / 2                                        # in [-pi/2, pi/2)
    return math.pi / 2 if wrapped <= -math.pi / 2 else wrapped


#: inclinations [deg] of the restarts of a fit whose first start did not converge
RESTART_INCLINATIONS = (45.0, -45.0, 30.0, -30.0, 60.0, -60.0)


def fit_band(points, values, r0=None, max_iter=200, tol=1e-10):
    """Levenberg-Marquardt fit of eq 4.22 to `values` (n,) at `points` (n, 2) = (x, y),
    from r0 (default: `initial_guess`).

    If that start does not converge (the principal axis of the top decile can point along
    a broad band's normal when the strongest strains sit in a corner, and the fit then
    drifts off the specimen), the fit restarts from bands at RESTART_INCLINATIONS through
    the centroid of the top decile, a tenth of the specimen thick, and returns the converged
    fit with the smallest residual (a fit that converged from its first start is returned
    as it is). Returns a BandFit. Raises ValueError on input that cannot define a band
    (fewer points than parameters, non-finite values, no strain contrast)."""
    points = np.asarray(points, dtype=float)
    values = np.asarray(values, dtype=float)
    if points.ndim != 2 or points.shape[1] != 2 or len(points) != len(values):
        raise ValueError(f"points must be (n, 2) and values (n,), got {points.shape} and {values.shape}")
    if len(values) < 6:
        raise ValueError(f"a band fit needs at least 6 points, got {len(values)}")
    if not (np.isfinite(points).all() and np.isfinite(values).all()):
        raise ValueError("band fit: non-finite coordinates or strain values")
    if not values.max() > values.min():
        raise ValueError("band fit: the strain norm is uniform, there is no band to measure")
    r = np.array(r0, dtype=float) if r0 is not None else initial_guess(points, values)
    first = _fit_from(points, values, r, max_iter, tol)
    if first.converged:
        return first
    e0 = float(np.median(values))
    top = values >= np.quantile(values, 0.9)
    cx, cy = points[top].mean(axis=0)
    length = float(np.ptp(points, axis=0).max())
    fits = []
    for deg in RESTART_INCLINATIONS:
        alpha = math.radians(deg)
        start = np.array([e0, float(values.max()) - e0, 0.1 * length, cy - cx * math.tan(alpha), alpha])
        fits.append(_fit_from(points, values, start, max_iter, tol))
    fits = [f for f in fits if f.converged]
    return min(fits, key=lambda f: f.rms_residual) if fits else first


def _fit_from(points, values, r, max_iter, tol):
    """One Levenberg-Marquardt run from r."""
    r = np.array(r, dtype=float)
    # scale the unknowns so that the damped normal equations are well conditioned
    length = float(np.ptp(points, axis=0).max())
    scale = np.array([max(abs(values).max(), 1e-300)] * 2 + [length, length, 1.0])
    res = bell(points, r) - values
    f = float(res @ res)
    lam, converged, it = 1e-3, False, 0
    for it in range(1, max_iter + 1):
        J = _jacobian(points, r) * scale
        g = J.T @ res
        JTJ = J.T @ J
        improved = False
        for _ in range(30):
            step = -np.linalg.solve(JTJ + lam * np.diag(np.diag(JTJ) + 1e-300), g) * scale
            trial = r + step
            trial[2] = abs(trial[2]) if trial[2] != 0 else r[2] * 0.5   # H enters as H^2
            # a trial far off may overflow (inf or nan): it is refused below like any step
            # that does not descend
            with np.errstate(over="ignore", invalid="ignore"):
                res_t = bell(points, trial) - values
                f_t = float(res_t @ res_t)
            if f_t <= f:
                improved = True
                break
            lam *= 10.0
        if not improved:
            converged = True   # no descent left at any damping: a (local) minimum
            break
        small = np.all(np.abs(step) <= tol * (np.abs(r) + scale * 1e-6))
        r, res, f_old, f = trial, res_t, f, f_t
        lam = max(lam / 10.0, 1e-12)
        if small or (f_old - f) <= tol * max(f_old, 1e-300):
            converged = True
            break
    r[4] = _wrap(r[4])
    r[2] = abs(r[2])
    converged = converged and bool(np.isfinite(r).all())
    return BandFit(thickness=float(r[2]), inclination_deg=math.degrees(r[4]), offset=float(r[0]),
                   amplitude=float(r[1]), x10=float(r[3]), rms_residual=math.sqrt(f / len(values)),
                   iterations=it, converged=converged)


def fit_band_collective(comm, points, values):
    """fit_band over the points of all ranks (each rank passes its own); rank 0 fits and
    every rank gets the BandFit, or the same ValueError."""
    points = np.concatenate(comm.allgather(np.asarray(points)))
    values = np.concatenate(comm.allgather(np.asarray(values)))
    result = None
    if comm.rank == 0:
        try:
            result = fit_band(points, values)
        except ValueError as error:
            result = str(error)
    result = comm.bcast(result, root=0)
    if isinstance(result, str):
        raise ValueError(result)
    return result


def band_verdict(fit, element_size, specimen_width, min_contrast=0.5):
    """Whether a fitted bell is a shear band the mesh resolves: (True, "") or (False, why).

    A fit always returns numbers, also on a homogeneous field; a band needs a strain
    contrast (A >= min_contrast e0: the band strains at least 1.5 times the rest), a
    thickness the Gauss points resolve (H >= element_size / 2) and a width that fits in
    the specimen (FWHM = 2.355 H <= specimen_width)."""
    if not fit.converged:
        return False, "the fit did not converge"
    if not fit.amplitude >= min_contrast * max(fit.offset, 0.0):
        if fit.amplitude > 0.0:
            return False, (f"no localisation: strain contrast A/e0 = {fit.amplitude / fit.offset:.2g} "
                           f"below {min_contrast:g}")
        # a profile that does not rise (A <= 0: a trough, or a fit run off to A ~ -1e22) has no
        # contrast to state as a ratio
        return False, (f"no localisation: the fitted bell does not rise above its background "
                       f"(A = {fit.amplitude:.2g}, e0 = {fit.offset:.2g})")
    if fit.thickness < 0.5 * element_size:
        return False, (f"H = {fit.thickness:.3g} m is below half an element ({element_size:.3g} m): "
                       "not resolved by the mesh")
    if 2.355 * fit.thickness > specimen_width:
        return False, f"diffuse: FWHM 2.355 H = {2.355 * fit.thickness:.3g} m exceeds the specimen width"
    return True, ""


def resolution_warning(element_size, specimen_width, specimen_height, min_elements=4):
    """'' or why the mesh cannot resolve a band in the specimen: fewer than `min_elements`
    elements across its narrower side (a band of thickness H needs H >= h / 2 and room on
    both sides of it)."""
    across = min(specimen_width, specimen_height) / element_size
    if across < min_elements:
        return (f"the mesh cannot resolve a band: {across:.3g} element(s) across the specimen "
                f"(element size {element_size:.3g} m; at least {min_elements} needed)")
    return ""


def assess_band(fit, element_size, specimen_width, specimen_height):
    """The band entries of a summary.json: `fit` is a callable returning a BandFit (or
    raising ValueError). A band is reported when band_verdict accepts the fit as a
    localisation (converged, strain contrast A/e0 >= 0.5, FWHM inside the specimen) and the
    bell describes the field (rms residual below the amplitude); otherwise `band` is false,
    the thickness null and `no_band_reason` says why. A band thinner than half an element is
    reported with `band_resolved: false` (its thickness follows the element size: the
    classical-continuum result) and the reason in `band_warning`; `mesh_warning` says when
    fewer than 4 elements span the specimen. Returns (band or None, dict of entries)."""
    warning = resolution_warning(element_size, specimen_width, specimen_height)
    result, band, reason, resolved = None, None, "", True
    try:
        result = fit()
        is_band, reason = band_verdict(result, 0.0, specimen_width)
        if is_band and not result.rms_residual <= result.amplitude:
            is_band, reason = False, (f"the bell does not describe the strain field: rms residual "
                                      f"{result.rms_residual:.3g} above the amplitude {result.amplitude:.3g}")
        band = result if is_band else None
    except ValueError as error:
        reason = str(error)
    if band is not None and warning:
        band, reason = None, warning
    band_warning = ""
    if band is not None and band.thickness < 0.5 * element_size:
        resolved = False
        band_warning = (f"H = {band.thickness:.3g} m is below half an element ({element_size:.3g} m): "
                        "the band is as thin as the mesh allows, its thickness follows the element size")
    if band is None:
        return None, no_band(reason, warning, result)
    return band, {"band": True, "band_resolved": resolved, "band_warning": band_warning,
                  "band_thickness": band.thickness, "band_inclination_deg": band.inclination_deg,
                  "band_fit": result.as_dict(), "no_band_reason": "", "mesh_warning": warning}


def no_band(reason, mesh_warning="", fit=None):
    """The band entries of a summary.json without a band (see assess_band)."""
    return {"band": False, "band_resolved": False, "band_warning": "", "band_thickness": None,
            "band_inclination_deg": None, "band_fit": fit.as_dict() if fit else None,
            "no_band_reason": reason, "mesh_warning": mesh_warning}
