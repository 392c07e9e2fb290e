"""Fields of a disc specimen from its grains: per-disc REVs, patch derivatives, moment balance
and coarse-grained fields on a grid (004 section 7.4.2; dns-spec A8, Part C H1-H6).

* ``rev_fields`` (from rev.py): per-disc REV stress, couple stress, Cosserat strain and
  curvature (004 eqs. 7.18-7.42, dns-spec A8's corrections).
* ``patch_gradient`` / ``patch_divergence``: the derivative of a per-disc field at each disc
  from a least-squares polynomial on its patch (the disc and its REV members: 7 discs on the
  lattice; 004 section 7.4.2 below eq. 7.47). Complete quadratic a0 + a1 xi + a2 eta + a3 xi^2
  + a4 xi eta + a5 eta^2 in (xi, eta) = x - x_c when the disc and at least 6 members are
  valid; else a linear fit from at least 3 valid points; else NaN (dns-spec A8, Part D 15).
  The derivatives are (a1, a2).
* ``moment_balance``: 0 = (T21 - T12) + div M (004 eq. 7.47) per disc, with the Pearson
  correlation of div M against -(T21 - T12) and against +(T21 - T12): the text first calls
  div M and -I x T "equivalent", then compares div M with I x T (dns-spec A8, Fig. 7.12 note).
* ``coarse_grain``: a Gaussian-kernel average of per-disc values on a regular grid,
  phi(X) = sum_i w_i v_i / sum_i w_i, w_i = exp(-|X - x_i|^2 / (2 w^2)) (weights normalised;
  NaN where no valid value lies within ``cutoff`` = 3 widths). For the XDMF output.
* ``coarse_grained_stress``: the Goldhirsch / Weinhart contact stress
  sigma(X) = -sum_c f_c (x) d_c int_0^1 W(X - x_i - s d_c) ds [N/m], W the 2D Gaussian
  normalised to unit integral, f_c the force on j, d_c = x_j - x_i. The line integral is
  exact (erf), not a midpoint rule. No kinetic part (quasi-static) and no disc-wall branch,
  so near a wall or the free boundary it is not the full stress; in the bulk, its integral
  along a cut equals the force transmitted across it.
"""
import math
from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from .. import checks
from ..checks import POSITIVE, Range
from ..errors import InputError
from .rev import RevFields, contact_geometry, flags, rev_fields  # noqa: F401 (public here)

__all__ = ["RevFields", "rev_fields", "patch_gradient", "patch_divergence", "moment_balance", "MomentBalance",
           "coarse_grain", "coarse_grained_stress"]


@njit(cache=True)
def _solve(a, b):
    """Solve a x = b in place (Gaussian elimination with partial pivoting; a small square
    system). Returns False when a pivot is below 1e-12 of the largest diagonal (rank deficient)."""
    n = b.shape[0]
    scale = 0.0
    for i in range(n):
        scale = max(scale, abs(a[i, i]))
    if scale == 0.0:
        return False
    for col in range(n):
        piv = col
        for r in range(col + 1, n):
            if abs(a[r, col]) > abs(a[piv, col]):
                piv = r
        if abs(a[piv, col]) <= 1e-12 * scale:
            return False
        if piv != col:
            for q in range(n):
                t = a[col, q]
                a[col, q] = a[piv, q]
                a[piv, q] = t
            t = b[col]
            b[col] = b[piv]
            b[piv] = t
        for r in range(col + 1, n):
            f = a[r, col] / a[col, col]
            if f != 0.0:
                for q in range(col, n):
                    a[r, q] -= f * a[col, q]
                b[r] -= f * b[col]
    for r in range(n - 1, -1, -1):
        s = b[r]
        for q in range(r + 1, n):
            s -= a[r, q] * b[q]
        b[r] = s / a[r, r]
    return True


@njit(cache=True)
def _fit_gradient(xi, eta, v, npts, nbasis):
    """Least-squares fit of v on the first nbasis of (1, xi, eta, xi^2, xi eta, eta^2) over
    npts points; (xi, eta) already scaled. Returns (ok, d/dxi, d/deta)."""
    a = np.zeros((nbasis, nbasis))
    b = np.zeros(nbasis)
    phi = np.empty(6)
    for p in range(npts):
        phi[0] = 1.0
        phi[1] = xi[p]
        phi[2] = eta[p]
        phi[3] = xi[p] * xi[p]
        phi[4] = xi[p] * eta[p]
        phi[5] = eta[p] * eta[p]
        for r in range(nbasis):
            b[r] += phi[r] * v[p]
            for q in range(nbasis):
                a[r, q] += phi[r] * phi[q]
    ok = _solve(a, b)
    return ok, b[1], b[2]


@njit(cache=True)
def _patch_fit(xi, eta, v, npts):
    """(d/dxi, d/deta, 1) of the quadratic fit with >= 7 points (the linear one when the
    quadratic is rank deficient or has fewer points, >= 3), (0, 0, 0) when neither fits."""
    g = np.zeros(3)
    if npts >= 7:
        ok, g0, g1 = _fit_gradient(xi, eta, v, npts, 6)
        if ok:
            g[0] = g0
            g[1] = g1
            g[2] = 1.0
            return g
    ok, g0, g1 = _fit_gradient(xi, eta, v, npts, 3)
    if ok:
        g[0] = g0
        g[1] = g1
        g[2] = 1.0
    return g


@njit(cache=True, parallel=True)
def _patch_kernel(position, values, valid, offsets, index, width, out, used):
    """Gradient of each column of values at every valid disc from its patch (see
    patch_gradient); out (n, k, 2), used (n,) points of the fit (0: NaN)."""
    n = position.shape[0]
    ncol = values.shape[1]
    for c in prange(n):
        if not valid[c]:
            continue
        k0 = offsets[c]
        nb = offsets[c + 1] - k0
        xi = np.empty(nb + 1)
        eta = np.empty(nb + 1)
        who = np.empty(nb + 1, np.int64)
        xi[0] = 0.0
        eta[0] = 0.0
        who[0] = c
        npts = 1
        h = 0.0
        for k in range(nb):
            b = index[k0 + k]
            if not valid[b]:
                continue
            dx = position[b, 0] - position[c, 0]
            if width > 0.0:
                dx -= width * math.floor(dx / width + 0.5)
            dy = position[b, 1] - position[c, 1]
            xi[npts] = dx
            eta[npts] = dy
            who[npts] = b
            h = max(h, math.sqrt(dx * dx + dy * dy))
            npts += 1
        if npts < 3 or h == 0.0:
            continue
        # scaled coordinates keep the normal equations well conditioned
        for p in range(npts):
            xi[p] /= h
            eta[p] /= h
        v = np.empty(npts)
        for col in range(ncol):
            for p in range(npts):
                v[p] = values[who[p], col]
            g = _patch_fit(xi, eta, v, npts)
            if g[2] > 0.0:
                out[c, col, 0] = g[0] / h
                out[c, col, 1] = g[1] / h
                used[c] = npts


def _neighbour_csr(neighbours, n):
    """(offsets, index) checked against n discs."""
    if not (isinstance(neighbours, tuple) and len(neighbours) == 2):
        raise InputError("neighbours must be a tuple (offsets, index), e.g. RevFields.members, "
                         f"got {type(neighbours).__name__}")
    offsets = checks.array("neighbours offsets", neighbours[0], (n + 1,), Range(0, integer=True), np.int64)
    if offsets[0] != 0 or np.any(np.diff(offsets) < 0):
        raise InputError("neighbours offsets must start at 0 and never decrease")
    index = checks.array("neighbours index", neighbours[1], (int(offsets[-1]),), Range(0, n - 1, integer=True),
                         np.int64)
    return offsets, index


def patch_gradient(position, values, valid, neighbours, periodic_width=None):
    """Gradient [value/m] of per-disc values at each disc from the least-squares polynomial on
    its patch (the disc and its neighbours; the 7-point patch of 004 section 7.4.2 on the
    lattice): quadratic when the disc and >= 6 neighbours are valid, else linear from >= 3
    valid points, else NaN (dns-spec A8). NaN at invalid discs.

    position (n,2) [m]; values (n,) or (n,k); valid (n,) bool; neighbours (offsets (n+1,),
    index): e.g. RevFields.members. Returns (n,2) or (n,k,2) and the points used per disc
    (n,) int (0: no fit)."""
    position = checks.array("position", position, (None, 2))
    n = position.shape[0]
    raw = np.asarray(values)
    single = raw.ndim == 1
    values = _values(raw, n, single)
    valid = flags("valid", valid, n) & np.all(np.isfinite(values), axis=1)
    offsets, index = _neighbour_csr(neighbours, n)
    width = checks.optional("periodic_width", periodic_width, POSITIVE) or 0.0
    out = np.full((n, values.shape[1], 2), np.nan)
    used = np.zeros(n, np.int64)
    _patch_kernel(position, values, valid, offsets, index, width, out, used)
    return (out[:, 0, :] if single else out), used


def _values(raw, n, single):
    """Per-disc values as (n, k) float (NaN allowed: invalid REVs)."""
    if raw.dtype.kind not in "biuf" or raw.shape[:1] != (n,) or raw.ndim not in (1, 2):
        raise InputError(f"values must be an array of numbers of shape (n,) or (n, k) with n = {n}, "
                         f"got shape {raw.shape}")
    a = np.array(raw, dtype=np.float64)
    return a[:, None] if single else a


def patch_divergence(position, values, valid, neighbours, periodic_width=None):
    """div of a per-disc vector field, values (n,2) = (v_x, v_y): dv_x/dx + dv_y/dy from the
    patch fit of each component (patch_gradient). For div M: values = (m3x, m3y) [N],
    result [N/m] (004 eq. 7.47). Returns (n,) (NaN where no fit)."""
    raw = np.asarray(values)
    if raw.ndim != 2 or raw.shape[1] != 2:
        raise InputError(f"values must be an array of shape (n, 2), got shape {raw.shape}")
    grad, _ = patch_gradient(position, raw, valid, neighbours, periodic_width)
    return grad[:, 0, 0] + grad[:, 1, 1]


@dataclass
class MomentBalance:
    """Moment balance 0 = (T21 - T12) + div M (004 eq. 7.47), per disc and summarised.

    div_m (n,) [N/m]; residual (n,) = skew + div_m [N/m]; used (n,) bool: both finite;
    n_used; pearson_minus = Pearson(div M, -(T21 - T12)) (the balance); pearson_plus =
    Pearson(div M, +(T21 - T12)) (the text's Fig. 7.12 comparison); rms_div_m, rms_skew,
    rms_residual [N/m] over the used discs. A Pearson is NaN with fewer than 3 discs or a
    constant field."""
    div_m: np.ndarray
    residual: np.ndarray
    used: np.ndarray
    n_used: int
    pearson_minus: float
    pearson_plus: float
    rms_div_m: float
    rms_skew: float
    rms_residual: float


def _pearson(a, b):
    if a.size < 3:
        return math.nan
    a = a - a.mean()
    b = b - b.mean()
    den = math.sqrt(float(np.dot(a, a)) * float(np.dot(b, b)))
    return float(np.dot(a, b)) / den if den > 0.0 else math.nan


def moment_balance(position, skew, m3x, m3y, valid, neighbours, periodic_width=None):
    """(T21 - T12) + div M per disc (004 eq. 7.47; div M from patch_divergence on (m3x, m3y))
    and its summary (MomentBalance). position (n,2) [m]; skew = T21 - T12 [N/m], m3x, m3y [N]
    (n,) (RevFields); valid (n,) bool; neighbours (offsets, index) (RevFields.members)."""
    position = checks.array("position", position, (None, 2))
    n = position.shape[0]
    skew = _values(np.asarray(skew), n, True)[:, 0]
    m = np.stack([_values(np.asarray(m3x), n, True)[:, 0], _values(np.asarray(m3y), n, True)[:, 0]], -1)
    div_m = patch_divergence(position, m, valid, neighbours, periodic_width)
    residual = skew + div_m
    used = np.isfinite(residual)
    d = div_m[used]
    s = skew[used]
    rms = (lambda a: float(np.sqrt(np.mean(a * a))) if a.size else math.nan)
    return MomentBalance(div_m=div_m, residual=residual, used=used, n_used=int(used.sum()),
                         pearson_minus=_pearson(d, -s), pearson_plus=_pearson(d, s), rms_div_m=rms(d),
                         rms_skew=rms(s), rms_residual=rms(residual[used]))


def _grid(name, g):
    g = checks.array(name, g, (None,))
    if g.size < 1 or np.any(np.diff(g) <= 0.0):
        raise InputError(f"{name} must be a non-empty increasing array, got {g.size} values")
    return g


@njit(cache=True)
def _coarse_kernel(points, values, gx, gy, width, reach, period, num, den, near):
    """Accumulate Gaussian weights of each point on the grid nodes within reach (and its
    periodic images in x when period > 0)."""
    inv = 0.5 / (width * width)
    ncol = values.shape[1]
    shifts = np.array([-period, 0.0, period]) if period > 0.0 else np.zeros(1)
    for p in range(points.shape[0]):
        for sx in shifts:
            x = points[p, 0] + sx
            y = points[p, 1]
            i0 = np.searchsorted(gx, x - reach)
            i1 = np.searchsorted(gx, x + reach, side="right")
            j0 = np.searchsorted(gy, y - reach)
            j1 = np.searchsorted(gy, y + reach, side="right")
            for j in range(j0, j1):
                dy = gy[j] - y
                for i in range(i0, i1):
                    dx = gx[i] - x
                    r2 = dx * dx + dy * dy
                    if r2 > reach * reach:
                        continue
                    w = math.exp(-r2 * inv)
                    den[j, i] += w
                    near[j, i] = True
                    for q in range(ncol):
                        num[j, i, q] += w * values[p, q]


def coarse_grain(points, values, grid_x, grid_y, width, valid=None, periodic_width=None, cutoff=3.0):
    """Gaussian-kernel coarse-grained field on the grid (grid_x (nx,), grid_y (ny,)) [m]:
    phi(X) = sum_i w_i v_i / sum_i w_i, w_i = exp(-|X - x_i|^2 / (2 width^2)), over the points
    with valid (default all) and finite values within cutoff * width of X (default 3 widths:
    NaN where none). points (n,2) [m]; values (n,) or (n,k); width [m] the kernel's standard
    deviation (a user option: about one to two disc diameters); periodic_width [m]: x-periodic
    (the grid within [0, periodic_width]). Returns (ny, nx) or (ny, nx, k), the layout of
    files.GridSeries."""
    points = checks.array("points", points, (None, 2))
    n = points.shape[0]
    raw = np.asarray(values)
    single = raw.ndim == 1
    values = _values(raw, n, single)
    width = checks.number("width", width, POSITIVE)
    cutoff = checks.number("cutoff", cutoff, POSITIVE)
    gx = _grid("grid_x", grid_x)
    gy = _grid("grid_y", grid_y)
    keep = np.all(np.isfinite(values), axis=1)
    if valid is not None:
        keep &= flags("valid", valid, n)
    period = checks.optional("periodic_width", periodic_width, POSITIVE) or 0.0
    if period > 0.0:
        # unwrapped positions (a LAMMPS dump's xu) back into [0, period): the kernel adds the
        # images at -period and +period only
        points = points.copy()
        points[:, 0] -= period * np.floor(points[:, 0] / period)
    num = np.zeros((gy.size, gx.size, values.shape[1]))
    den = np.zeros((gy.size, gx.size))
    near = np.zeros((gy.size, gx.size), bool)
    _coarse_kernel(np.ascontiguousarray(points[keep]), np.ascontiguousarray(values[keep]), gx, gy, width,
                   cutoff * width, period, num, den, near)
    with np.errstate(invalid="ignore", divide="ignore"):
        field = num / den[..., None]
    field[~near] = np.nan
    return field[..., 0] if single else field


@njit(cache=True)
def _line_weight(ax, ay, bx, by, width):
    """int_0^1 W(a + s b) ds for the 2D Gaussian W(r) = exp(-|r|^2 / (2 w^2)) / (2 pi w^2)
    (exact: the part along b is an erf, the part across it a factor)."""
    length = math.sqrt(bx * bx + by * by)
    norm = 1.0 / (2.0 * math.pi * width * width)
    if length < 1e-12 * width:
        return norm * math.exp(-(ax * ax + ay * ay) / (2.0 * width * width))
    ex = bx / length
    ey = by / length
    along = ax * ex + ay * ey
    across2 = max(0.0, ax * ax + ay * ay - along * along)
    root2w = math.sqrt(2.0) * width
    part = 0.5 * math.sqrt(math.pi) * root2w / length * (math.erf((along + length) / root2w) - math.erf(along / root2w))
    return norm * math.exp(-across2 / (2.0 * width * width)) * part


@njit(cache=True)
def _stress_kernel(xi, d, force_j, gx, gy, width, reach, period, sigma):
    """Add each contact's -f (x) d times its line weight to the grid nodes within reach of its
    branch (and its periodic images in x)."""
    shifts = np.array([-period, 0.0, period]) if period > 0.0 else np.zeros(1)
    for c in range(xi.shape[0]):
        for sx in shifts:
            x0 = xi[c, 0] + sx
            y0 = xi[c, 1]
            x1 = x0 + d[c, 0]
            y1 = y0 + d[c, 1]
            i0 = np.searchsorted(gx, min(x0, x1) - reach)
            i1 = np.searchsorted(gx, max(x0, x1) + reach, side="right")
            j0 = np.searchsorted(gy, min(y0, y1) - reach)
            j1 = np.searchsorted(gy, max(y0, y1) + reach, side="right")
            f0 = force_j[c, 0]
            f1 = force_j[c, 1]
            for j in range(j0, j1):
                for i in range(i0, i1):
                    w = _line_weight(x0 - gx[i], y0 - gy[j], d[c, 0], d[c, 1], width)
                    sigma[j, i, 0, 0] -= w * f0 * d[c, 0]
                    sigma[j, i, 0, 1] -= w * f0 * d[c, 1]
                    sigma[j, i, 1, 0] -= w * f1 * d[c, 0]
                    sigma[j, i, 1, 1] -= w * f1 * d[c, 1]


def coarse_grained_stress(position, radius, pair_i, pair_j, fn, fs, grid_x, grid_y, width, periodic_width=None,
                          cutoff=6.0):
    """Coarse-grained contact stress on the grid [N/m] (ny, nx, 2, 2), tension positive, t = sigma n:
    sigma(X) = -sum_c f_c (x) d_c int_0^1 W(X - x_i - s d_c) ds (Goldhirsch 2010, Weinhart et al.
    2012; static part), W the unit-integral 2D Gaussian of standard deviation width [m], f_c
    the force on j (fn n + fs t) [N], d_c = x_j - x_i [m] (minimum image in x with
    periodic_width). The branch integral is exact (erf). The kernel is cut at cutoff widths
    (6: a relative error below 1e-7). Pairs with zero force add nothing."""
    position = checks.array("position", position, (None, 2))
    n = position.shape[0]
    radius = checks.array("radius", radius, (n,), POSITIVE)
    pair_i = checks.array("pair_i", pair_i, (None,), Range(0, n - 1, integer=True), np.int64)
    m = pair_i.shape[0]
    pair_j = checks.array("pair_j", pair_j, (m,), Range(0, n - 1, integer=True), np.int64)
    fn = checks.array("fn", fn, (m,))
    fs = checks.array("fs", fs, (m,))
    width = checks.number("width", width, POSITIVE)
    cutoff = checks.number("cutoff", cutoff, POSITIVE)
    gx = _grid("grid_x", grid_x)
    gy = _grid("grid_y", grid_y)
    period = checks.optional("periodic_width", periodic_width, POSITIVE) or 0.0
    d, _, _, force_j, _, _ = contact_geometry(position, radius, pair_i, pair_j, fn, fs, None, period)
    keep = (fn != 0.0) | (fs != 0.0)
    sigma = np.zeros((gy.size, gx.size, 2, 2))
    xi = position[pair_i]
    if period > 0.0:
        xi[:, 0] -= period * np.floor(xi[:, 0] / period)
    _stress_kernel(np.ascontiguousarray(xi[keep]), np.ascontiguousarray(d[keep]),
                   np.ascontiguousarray(force_j[keep]), gx, gy, width, cutoff * width, period, sigma)
    return sigma
