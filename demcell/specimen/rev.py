"""Per-particle REV homogenisation of a bounded disc specimen (004 section 7.4.2, eqs. 7.18-7.42).

For every disc c the REV is the polygon through the centres of the discs B in contact with c,
ordered counter-clockwise by the polar angle of x_b - x_c (004 Fig. 7.10; option
``neighbours="distance"``: every disc with |x_b - x_c| <= (r_b + r_c)(1 + tolerance), for a
dilated band where discs keep 2-3 contacts). R = B + {c}. The REVs of neighbouring discs
overlap. Quantities (2D per unit depth; tension positive; x horizontal, y vertical):

* V_R [m^2 per m]: shoelace area of the polygon, current configuration.
* Outside force and moment on each member i (004 eq. 7.18): f^(i) [N], m^(i) [N m] = the
  contact forces and moments on i from discs that are not in R, plus the external load of i
  (pressure arcs, membrane, walls: everything that is not a disc-disc contact). c itself is
  summed too (it carries none unless a pair with a non-member holds a force).
  A contact between two consecutive members lies on the polygon's edge (its branch is the
  edge): by default (``boundary_contacts="shared"``) it counts half in f^(i) and m^(i), as a
  contact on a cell boundary counts half in Love's formula. Then T is the mean stress over the
  polygon: on the hexagonal lattice under pressure p (contact force 2 p r / sqrt(3)) it gives
  T = -p I exactly (dns-spec H5). Read literally (``boundary_contacts="internal"``, those
  contacts are internal to R) 7.18 + 7.31 give T = -4/3 p I there: the 12 contacts of R
  (branch 2r each) are divided by the area of the hexagon 6 sqrt(3) r^2, while Love's formula
  gives them 8 sqrt(3) r^2. Both forms keep the identities of 004 eq. 7.19: sum f = 0 and
  sum (x^(i) x f^(i) + m^(i)) = 0 at static equilibrium, hence V_R (T21 - T12) = -sum m^(i).
* Stress (004 eq. 7.31): T_kl = V_R^-1 sum_i f_k^(i) (x^(i) - x_c)_l [N/m], so t = T n.
  The origin x_c is dns-spec A8's: identical at equilibrium (sum f = 0).
* Couple stress (004 eq. 7.38 with dns-spec A8's origin correction): M_3l = V_R^-1 sum_i
  m^(i) (x^(i) - x_bar)_l [N], x_bar the polygon's centroid. With global positions (7.38
  literally) sum m^(i) = -V_R (T21 - T12) adds -(T21 - T12) x_c, which is meaningless.
* Displacement and rotation gradients (004 eqs. 7.39-7.40): grad u = V^-1 sum_i u^(i) (x)
  n^(i), grad phi = V^-1 sum_i phi^(i) n^(i), with the length-weighted vertex normal
  n^(i) = 1/2 R_-90 (x_{i+1} - x_{i-1}) (dns-spec A8 / Part D 12). Then sum n = 0 and
  sum x (x) n = V I exactly, so affine fields are reproduced exactly (dns-spec H1, H2).
  Current configuration by default (004 remark after 7.42); ``configuration="reference"``
  takes the polygon of the same discs at x - u (a Lagrangian Grad u).
* Mean rotation (004 eq. 7.41): phi_bar = sum_i v^(i) phi^(i) / sum_i v^(i), v^(i) the
  area of disc i inside the polygon (pi r_c^2 for c, alpha_i r_i^2 / 2 for a member, alpha_i
  the polygon's interior angle at i). dns-spec A8 / Part D 13 normalise by sum v (a rigid
  rotation then gives phi_bar = omega); ``rotation_normalisation="literal"`` divides by V_R
  as printed, which on the hexagonal lattice gives 0.9069 omega (a skew strain error of
  0.093 omega under a rigid rotation).
* Cosserat strain and curvature (004 eq. 7.42): eps_bar = grad u + E^3 phi_bar, i.e.
  eps_12 = u_1,2 + phi, eps_21 = u_2,1 - phi; kappa_3l = phi_,l [1/m].
* Scalars: |eps| = sqrt(eps:eps) (4 components), |kappa|, |M|, skew = T21 - T12 = (I x T)_3
  [N/m], equivalent strain |sym grad u| (Frobenius, the measure of 000 Fig. 7 used by the FE
  scenes), local solid fraction sum v / V_R and void ratio V_R / sum v - 1.

A REV is invalid (NaN, counted) when c has fewer than 3 members, when x_c is not strictly
inside the polygon (a gap of pi or more between consecutive members), or when c is
``excluded`` (a free-boundary or wall disc: an external load acts inside its REV)
(dns-spec A8, Part D 10).

Contact arrays follow demcell's convention: n = (x_j - x_i)/|x_j - x_i|, t = (-n_y, n_x);
the force ON j is fn n + fs t (on i its opposite); the contact point lies at
a_i = r_i - overlap/2 from i along n; the moment on i is -a_i fs - mr, on j -a_j fs + mr.
An x-periodic specimen takes ``periodic_width`` (minimum image in x); its displacements must
be unwrapped (position - reference position of the same, unwrapped, disc).
"""
import math
from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from .. import checks
from ..checks import NON_NEGATIVE, POSITIVE, Range
from ..errors import InputError
from .contacts import contact_geometry

#: REV status codes (``RevFields.status``)
VALID, TOO_FEW, CENTRE_OUTSIDE, EXCLUDED = 0, 1, 2, 3
NEIGHBOURS = ("contacts", "distance")
NORMALISATIONS = ("solid", "literal")
CONFIGURATIONS = ("current", "reference")
BOUNDARY_CONTACTS = ("shared", "internal")


@njit(cache=True)
def _image(dx, width):
    """Minimum image of a horizontal offset (width 0: not periodic)."""
    if width > 0.0:
        dx -= width * math.floor(dx / width + 0.5)
    return dx


@njit(cache=True, parallel=True)
def _visit_cells(position, radius, factor, width, cell, order, start, ncx, ncy, wrap_all, offsets, index, fill):
    """Distance neighbours of every disc from the cell list: counts into offsets[c] (fill
    False) or the indices into index[offsets[c]:] (fill True)."""
    n = position.shape[0]
    for c in prange(n):
        cx = cell[c] % ncx
        cy = cell[c] // ncx
        k = 0
        lo = 0 if wrap_all else cx - 1
        hi = ncx - 1 if wrap_all else cx + 1
        for qy in range(cy - 1, cy + 2):
            if qy < 0 or qy >= ncy:
                continue
            for ox in range(lo, hi + 1):
                qx = ox
                if width > 0.0:
                    qx = ox % ncx
                elif qx < 0 or qx >= ncx:
                    continue
                q = qy * ncx + qx
                for s in range(start[q], start[q + 1]):
                    b = order[s]
                    if b == c:
                        continue
                    dx = _image(position[b, 0] - position[c, 0], width)
                    dy = position[b, 1] - position[c, 1]
                    reach = factor * (radius[b] + radius[c])
                    if dx * dx + dy * dy <= reach * reach:
                        if fill:
                            index[offsets[c] + k] = b
                        k += 1
        if not fill:
            offsets[c] = k


def _distance_neighbours(position, radius, factor, width):
    """Members by distance: for each disc the discs b != c with |x_b - x_c| <= factor (r_b +
    r_c), by a cell list (cells of side factor * 2 r_max). Returns CSR (offsets, index).
    Plain Python around the parallel kernel: a cached kernel that calls a parallel one can
    crash when Numba reloads it from its cache."""
    n = position.shape[0]
    side = 2.0 * factor * float(radius.max())
    ymin = float(position[:, 1].min())
    if width > 0.0:
        ncx = max(1, int(math.floor(width / side)))
        x = position[:, 0] - width * np.floor(position[:, 0] / width)
        side_x = width / ncx
    else:
        x = position[:, 0] - float(position[:, 0].min())
        ncx = int(x.max() / side) + 1
        side_x = side
    ncy = int((float(position[:, 1].max()) - ymin) / side) + 1
    cx = np.minimum((x / side_x).astype(np.int64), ncx - 1)
    cy = np.minimum(((position[:, 1] - ymin) / side).astype(np.int64), ncy - 1)
    cell = cy * ncx + cx
    order = np.argsort(cell, kind="stable").astype(np.int64)
    start = np.zeros(ncx * ncy + 1, np.int64)
    np.cumsum(np.bincount(cell, minlength=ncx * ncy), out=start[1:])
    # x cells to visit: the 3 around (all of them when fewer than 3, so none is visited twice)
    wrap_all = width > 0.0 and ncx < 3
    count = np.zeros(n, np.int64)
    _visit_cells(position, radius, factor, width, cell, order, start, ncx, ncy, wrap_all, count, count, False)
    offsets = np.zeros(n + 1, np.int64)
    np.cumsum(count, out=offsets[1:])
    index = np.empty(offsets[n], np.int64)
    _visit_cells(position, radius, factor, width, cell, order, start, ncx, ncy, wrap_all, offsets, index, True)
    return offsets, index


@njit(cache=True, parallel=True)
def _sort_by_angle(position, offsets, index, width):
    """Order each disc's members counter-clockwise by the polar angle of x_b - x_c (in place;
    insertion sort: a few members each)."""
    n = offsets.shape[0] - 1
    for c in prange(n):
        k0 = offsets[c]
        k1 = offsets[c + 1]
        angle = np.empty(k1 - k0)
        for k in range(k0, k1):
            b = index[k]
            angle[k - k0] = math.atan2(position[b, 1] - position[c, 1],
                                       _image(position[b, 0] - position[c, 0], width))
        for k in range(1, k1 - k0):
            a = angle[k]
            b = index[k0 + k]
            q = k - 1
            while q >= 0 and angle[q] > a:
                angle[q + 1] = angle[q]
                index[k0 + q + 1] = index[k0 + q]
                q -= 1
            angle[q + 1] = a
            index[k0 + q + 1] = b


@njit(cache=True)
def _polygon(px, py):
    """Area (shoelace) and centroid of the polygon (px, py) counter-clockwise; strictly
    star-shaped about the origin when every cross(x_k, x_{k+1}) > 0 (returned as `inside`)."""
    nb = px.shape[0]
    area = 0.0
    cx = 0.0
    cy = 0.0
    inside = True
    for k in range(nb):
        q = (k + 1) % nb
        cr = px[k] * py[q] - px[q] * py[k]
        if not cr > 0.0:
            inside = False
        area += 0.5 * cr
        cx += (px[k] + px[q]) * cr
        cy += (py[k] + py[q]) * cr
    if area != 0.0:
        cx /= 6.0 * area
        cy /= 6.0 * area
    return area, cx, cy, inside


@njit(cache=True)
def _interior_angle(px, py, k):
    """Interior angle [rad] at vertex k of the counter-clockwise polygon (px, py)."""
    nb = px.shape[0]
    q = (k + 1) % nb
    p = (k - 1) % nb
    ax = px[q] - px[k]
    ay = py[q] - py[k]
    bx = px[p] - px[k]
    by = py[p] - py[k]
    alpha = math.atan2(ax * by - ay * bx, ax * bx + ay * by)
    if alpha < 0.0:
        alpha += 2.0 * math.pi
    return alpha


@njit(cache=True, parallel=True)
def _rev_kernel(position, radius, displacement, rotation, offsets, index, inc_off, inc_pair, inc_is_j,
                inc_other, force_j, moment_i, moment_j, external_force, external_moment, excluded, width,
                reference, literal, shared, status, out):
    """Per-disc REV quantities into out (n, N_OUT) (columns: see rev_fields)."""
    n = radius.shape[0]
    for c in prange(n):
        k0 = offsets[c]
        nb = offsets[c + 1] - k0
        if excluded[c]:
            status[c] = EXCLUDED
            continue
        if nb < 3:
            status[c] = TOO_FEW
            continue
        px = np.empty(nb)
        py = np.empty(nb)
        kx = np.empty(nb)
        ky = np.empty(nb)
        for k in range(nb):
            b = index[k0 + k]
            px[k] = _image(position[b, 0] - position[c, 0], width)
            py[k] = position[b, 1] - position[c, 1]
            # reference vertices: the same discs at x - u, relative to c at x_c - u_c
            kx[k] = px[k] - displacement[b, 0] + displacement[c, 0]
            ky[k] = py[k] - displacement[b, 1] + displacement[c, 1]
        area, gx, gy, inside = _polygon(px, py)
        if reference:
            area_k, _, _, inside_k = _polygon(kx, ky)
            inside = inside and inside_k
        else:
            for k in range(nb):
                kx[k] = px[k]
                ky[k] = py[k]
            area_k = area
        if not inside:
            status[c] = CENTRE_OUTSIDE
            continue
        status[c] = VALID
        # outside forces and moments (7.18) of each member of R, c (number nb) included
        t00 = 0.0
        t01 = 0.0
        t10 = 0.0
        t11 = 0.0
        m0 = 0.0
        m1 = 0.0
        sfx = 0.0
        sfy = 0.0
        sfabs = 0.0
        msum = 0.0
        for k in range(nb + 1):
            b = np.int64(c)
            xb = 0.0
            yb = 0.0
            if k < nb:
                b = index[k0 + k]
                xb = px[k]
                yb = py[k]
            fx = external_force[b, 0]
            fy = external_force[b, 1]
            mb = external_moment[b]
            for s in range(inc_off[b], inc_off[b + 1]):
                o = inc_other[s]
                # weight of the contact in f^(b): 1 from outside R, 0 inside R, 1/2 (shared) for
                # a contact between consecutive members: it lies on the polygon's edge
                weight = 1.0
                if o == c:
                    weight = 0.0
                else:
                    for q in range(nb):
                        if index[k0 + q] == o:
                            weight = 0.0
                            if shared and k < nb and (q == (k + 1) % nb or q == (k + nb - 1) % nb):
                                weight = 0.5
                            break
                if weight == 0.0:
                    continue
                p = inc_pair[s]
                if inc_is_j[s]:
                    fx += weight * force_j[p, 0]
                    fy += weight * force_j[p, 1]
                    mb += weight * moment_j[p]
                else:
                    fx -= weight * force_j[p, 0]
                    fy -= weight * force_j[p, 1]
                    mb += weight * moment_i[p]
            t00 += fx * xb
            t01 += fx * yb
            t10 += fy * xb
            t11 += fy * yb
            m0 += mb * (xb - gx)
            m1 += mb * (yb - gy)
            sfx += fx
            sfy += fy
            sfabs += math.sqrt(fx * fx + fy * fy)
            msum += mb
        # gradients with the length-weighted vertex normals (7.39-7.40), mean rotation (7.41)
        g00 = 0.0
        g01 = 0.0
        g10 = 0.0
        g11 = 0.0
        h0 = 0.0
        h1 = 0.0
        rc = radius[c]
        v_sum = math.pi * rc * rc
        phi_sum = v_sum * rotation[c]
        v_cur = v_sum
        for k in range(nb):
            b = index[k0 + k]
            q = (k + 1) % nb
            p = (k - 1) % nb
            nx = 0.5 * (ky[q] - ky[p])
            ny = -0.5 * (kx[q] - kx[p])
            ux = displacement[b, 0]
            uy = displacement[b, 1]
            g00 += ux * nx
            g01 += ux * ny
            g10 += uy * nx
            g11 += uy * ny
            h0 += rotation[b] * nx
            h1 += rotation[b] * ny
            v = 0.5 * _interior_angle(kx, ky, k) * radius[b] * radius[b]
            v_sum += v
            phi_sum += v * rotation[b]
            if reference:
                v_cur += 0.5 * _interior_angle(px, py, k) * radius[b] * radius[b]
        if not reference:
            v_cur = v_sum
        phi = phi_sum / (area_k if literal else v_sum)
        g00 /= area_k
        g01 /= area_k
        g10 /= area_k
        g11 /= area_k
        h0 /= area_k
        h1 /= area_k
        out[c, 0] = nb
        out[c, 1] = area
        out[c, 2] = v_cur
        out[c, 3] = position[c, 0] + gx
        out[c, 4] = position[c, 1] + gy
        out[c, 5] = t00 / area
        out[c, 6] = t01 / area
        out[c, 7] = t10 / area
        out[c, 8] = t11 / area
        out[c, 9] = m0 / area
        out[c, 10] = m1 / area
        out[c, 11] = g00
        out[c, 12] = g01
        out[c, 13] = g10
        out[c, 14] = g11
        out[c, 15] = h0
        out[c, 16] = h1
        out[c, 17] = phi
        out[c, 18] = math.sqrt(sfx * sfx + sfy * sfy) / sfabs if sfabs > 0.0 else 0.0
        out[c, 19] = msum / area


@dataclass
class RevFields:
    """Per-disc REV fields (arrays of length n; NaN where the REV is invalid). Units: 2D per
    unit depth, tension positive; x horizontal, y vertical.

    valid (bool), status (int8: 0 valid, 1 fewer than 3 members, 2 centre not strictly
    inside, 3 excluded disc); n_members; area V_R [m^2]; solid_area sum v [m^2];
    solid_fraction, void_ratio [-]; centroid (n,2) [m];
    stress T_kl (t = T n) [N/m]: txx, txy (T_12: x force, y arm), tyx, tyy; skew = T21 - T12;
    couple stress m3x, m3y (M_3l) [N], m_norm; mean_moment = V_R^-1 sum m^(i) [N/m] (equals
    -(T21 - T12) at static equilibrium, 004 eq. 7.19_2);
    force_residual = |sum f^(i)| / sum |f^(i)| [-] (0 at equilibrium);
    grad u: dux_dx, dux_dy, duy_dx, duy_dy [-]; curvature k3x = dphi/dx, k3y = dphi/dy [1/m];
    phi mean rotation [rad]; Cosserat strain exx, exy (u_x,y + phi), eyx (u_y,x - phi), eyy;
    eps_norm, kappa_norm [1/m], equivalent_strain |sym grad u|;
    coordination (contacts per disc, all discs, int64); sliding_fraction (sliding contacts /
    contacts of the disc; NaN without a sliding flag or without contacts);
    member_offsets (n+1,), member_index: the REV members of each disc counter-clockwise (the
    patch of patch_divergence); n_invalid, n_too_few, n_centre_outside, n_excluded;
    options used: neighbours, rotation_normalisation, configuration, boundary_contacts.
    """
    valid: np.ndarray
    status: np.ndarray
    n_members: np.ndarray
    area: np.ndarray
    solid_area: np.ndarray
    solid_fraction: np.ndarray
    void_ratio: np.ndarray
    centroid: np.ndarray
    txx: np.ndarray
    txy: np.ndarray
    tyx: np.ndarray
    tyy: np.ndarray
    skew: np.ndarray
    m3x: np.ndarray
    m3y: np.ndarray
    m_norm: np.ndarray
    mean_moment: np.ndarray
    force_residual: np.ndarray
    dux_dx: np.ndarray
    dux_dy: np.ndarray
    duy_dx: np.ndarray
    duy_dy: np.ndarray
    k3x: np.ndarray
    k3y: np.ndarray
    phi: np.ndarray
    exx: np.ndarray
    exy: np.ndarray
    eyx: np.ndarray
    eyy: np.ndarray
    eps_norm: np.ndarray
    kappa_norm: np.ndarray
    equivalent_strain: np.ndarray
    coordination: np.ndarray
    sliding_fraction: np.ndarray
    member_offsets: np.ndarray
    member_index: np.ndarray
    n_invalid: int
    n_too_few: int
    n_centre_outside: int
    n_excluded: int
    neighbours: str
    rotation_normalisation: str
    configuration: str
    boundary_contacts: str

    @property
    def invalid_fraction(self):
        """Share of discs whose REV is invalid."""
        return self.n_invalid / max(1, self.valid.shape[0])

    @property
    def members(self):
        """(offsets, index): the neighbours argument of patch_divergence / moment_balance."""
        return self.member_offsets, self.member_index

    def stress(self):
        """T as (n, 2, 2) [N/m]."""
        return np.stack([np.stack([self.txx, self.txy], -1), np.stack([self.tyx, self.tyy], -1)], -2)


def _csr(owner, n):
    """Offsets and order of entries grouped by owner (stable)."""
    order = np.argsort(owner, kind="stable")
    offsets = np.zeros(n + 1, np.int64)
    np.cumsum(np.bincount(owner, minlength=n), out=offsets[1:])
    return offsets, order


def flags(name, value, n):
    """A per-item flag array (bool, or integers 0/1 such as the engine's int8 ``touching``,
    ``on_wall``, ``on_boundary``) as bool of length n, else InputError."""
    raw = np.asarray(value)
    if raw.dtype.kind in "iu" and raw.ndim == 1 and raw.size and not np.isin(raw, (0, 1)).all():
        raise InputError(f"{name} must hold booleans or 0/1, got {raw[~np.isin(raw, (0, 1))][0]!r}")
    if raw.dtype.kind in "iu":
        raw = raw.astype(bool)
    return checks.array(name, raw, (n,), dtype=bool)


def _check_inputs(position, radius, displacement, rotation, pair_i, pair_j, fn, fs, mr, external_force,
                  external_moment, excluded, touching, sliding, periodic_width):
    position = checks.array("position", position, (None, 2))
    n = position.shape[0]
    if n < 1:
        raise InputError("position must hold at least one disc, got 0")
    radius = checks.array("radius", radius, (n,), POSITIVE)
    displacement = checks.array("displacement", displacement, (n, 2))
    rotation = checks.array("rotation", rotation, (n,))
    pair_i = checks.array("pair_i", pair_i, (None,), Range(0, n - 1, integer=True), np.int64)
    m = pair_i.shape[0]
    pair_j = checks.array("pair_j", pair_j, (m,), Range(0, n - 1, integer=True), np.int64)
    if np.any(pair_i == pair_j):
        raise InputError(f"pair_i and pair_j must differ, got a pair ({int(pair_i[pair_i == pair_j][0])}, "
                         f"{int(pair_i[pair_i == pair_j][0])})")
    fn = checks.array("fn", fn, (m,))
    fs = checks.array("fs", fs, (m,))
    mr = None if mr is None else checks.array("mr", mr, (m,))
    external_force = (np.zeros((n, 2)) if external_force is None
                      else checks.array("external_force", external_force, (n, 2)))
    external_moment = (np.zeros(n) if external_moment is None
                       else checks.array("external_moment", external_moment, (n,)))
    excluded = np.zeros(n, bool) if excluded is None else flags("excluded", excluded, n)
    touching = None if touching is None else flags("touching", touching, m)
    sliding = None if sliding is None else flags("sliding", sliding, m)
    width = checks.optional("periodic_width", periodic_width, POSITIVE) or 0.0
    return (position, radius, displacement, rotation, pair_i, pair_j, fn, fs, mr, external_force,
            external_moment, excluded, touching, sliding, width)


def rev_fields(position, radius, displacement, rotation, pair_i, pair_j, fn, fs, mr=None, external_force=None,
               excluded=None, periodic_width=None, *, external_moment=None, touching=None, sliding=None,
               neighbours="contacts", distance_tolerance=0.1, rotation_normalisation="solid",
               configuration="current", boundary_contacts="shared"):
    """Per-particle REV homogenisation of a disc specimen (004 eqs. 7.18-7.42 with dns-spec
    A8's corrections; see the module docstring). Plain arrays, so a LAMMPS dump goes through
    it as well as the engine's state:

    position (n,2) [m]; radius (n,) [m]; displacement (n,2) [m] = position - reference
    position; rotation (n,) [rad] since the reference; pair_i, pair_j (m,) int; fn, fs (m,)
    [N] (force on j = fn n + fs t); mr (m,) [N m] rolling moment on j (None: 0);
    external_force (n,2) [N] everything on a disc that is not a disc-disc contact (None: 0);
    external_moment (n,) [N m] (None: 0); excluded (n,) bool: discs whose REV is invalid
    (free boundary, wall contact); periodic_width [m]: x-periodic specimen (minimum image);
    touching (m,) bool: which pairs are contacts (None: overlap > 0); sliding (m,) bool: the
    sliding contacts (gives sliding_fraction). Flag arrays may be 0/1 integers (the engine's
    int8 ``touching``; ``excluded = on_boundary | on_wall``).

    neighbours: "contacts" (004's REV) or "distance" (all discs within (r_b + r_c)(1 +
    distance_tolerance)); rotation_normalisation: "solid" (sum v, default) or "literal" (V_R,
    7.41 as printed); configuration: "current" (default) or "reference" (polygon at x - u for
    grad u, grad phi and the rotation weights); boundary_contacts: "shared" (a contact
    between consecutive members counts half, default: T = -p I on the pressed lattice) or
    "internal" (7.18 literally: T = -4/3 p I there).

    Returns a RevFields.
    """
    checks.choice("neighbours", neighbours, NEIGHBOURS)
    checks.choice("rotation_normalisation", rotation_normalisation, NORMALISATIONS)
    checks.choice("configuration", configuration, CONFIGURATIONS)
    checks.choice("boundary_contacts", boundary_contacts, BOUNDARY_CONTACTS)
    tolerance = checks.number("distance_tolerance", distance_tolerance, NON_NEGATIVE)
    (position, radius, displacement, rotation, pair_i, pair_j, fn, fs, mr, external_force, external_moment,
     excluded, touching, sliding, width) = _check_inputs(
        position, radius, displacement, rotation, pair_i, pair_j, fn, fs, mr, external_force, external_moment,
        excluded, touching, sliding, periodic_width)
    n = position.shape[0]
    m = pair_i.shape[0]
    _, _, overlap, force_j, moment_i, moment_j = contact_geometry(position, radius, pair_i, pair_j, fn, fs, mr,
                                                                  width)
    contact = overlap > 0.0 if touching is None else touching
    # incidence of every pair on both its discs (forces from non-members)
    ends = np.concatenate([pair_i, pair_j])
    inc_off, order = _csr(ends, n)
    inc_pair = (order % m).astype(np.int64) if m else np.zeros(0, np.int64)
    inc_is_j = order >= m
    inc_other = np.concatenate([pair_j, pair_i])[order]
    ci = pair_i[contact]
    cj = pair_j[contact]
    coordination = np.bincount(np.concatenate([ci, cj]), minlength=n).astype(np.int64)
    if neighbours == "contacts":
        offsets, corder = _csr(np.concatenate([ci, cj]), n)
        index = np.concatenate([cj, ci])[corder].astype(np.int64)
    else:
        offsets, index = _distance_neighbours(position, radius, 1.0 + tolerance, width)
    _sort_by_angle(position, offsets, index, width)
    status = np.zeros(n, np.int8)
    out = np.full((n, 20), np.nan)
    _rev_kernel(position, radius, displacement, rotation, offsets, index, inc_off, inc_pair, inc_is_j, inc_other,
                np.ascontiguousarray(force_j), moment_i, moment_j, external_force, external_moment, excluded, width,
                configuration == "reference", rotation_normalisation == "literal", boundary_contacts == "shared",
                status, out)
    valid = status == VALID
    col = {name: out[:, k] for k, name in enumerate(
        ["n", "area", "solid", "gx", "gy", "txx", "txy", "tyx", "tyy", "m3x", "m3y", "dux_dx", "dux_dy", "duy_dx",
         "duy_dy", "k3x", "k3y", "phi", "fres", "mmean"])}
    phi = col["phi"]
    exx = col["dux_dx"]
    exy = col["dux_dy"] + phi
    eyx = col["duy_dx"] - phi
    eyy = col["duy_dy"]
    sym = 0.5 * (col["dux_dy"] + col["duy_dx"])
    if sliding is None:
        sliding_fraction = np.full(n, np.nan)
    else:
        s = contact & sliding
        count = np.bincount(np.concatenate([pair_i[s], pair_j[s]]), minlength=n)
        with np.errstate(invalid="ignore", divide="ignore"):
            sliding_fraction = np.where(coordination > 0, count / np.maximum(coordination, 1), np.nan)
    n_members = np.diff(offsets)
    return RevFields(
        valid=valid, status=status, n_members=n_members, area=col["area"], solid_area=col["solid"],
        solid_fraction=col["solid"] / col["area"], void_ratio=col["area"] / col["solid"] - 1.0,
        centroid=np.stack([col["gx"], col["gy"]], -1), txx=col["txx"], txy=col["txy"], tyx=col["tyx"],
        tyy=col["tyy"], skew=col["tyx"] - col["txy"], m3x=col["m3x"], m3y=col["m3y"],
        m_norm=np.hypot(col["m3x"], col["m3y"]), mean_moment=col["mmean"], force_residual=col["fres"],
        dux_dx=col["dux_dx"], dux_dy=col["dux_dy"], duy_dx=col["duy_dx"], duy_dy=col["duy_dy"], k3x=col["k3x"],
        k3y=col["k3y"], phi=phi, exx=exx, exy=exy, eyx=eyx, eyy=eyy,
        eps_norm=np.sqrt(exx ** 2 + exy ** 2 + eyx ** 2 + eyy ** 2), kappa_norm=np.hypot(col["k3x"], col["k3y"]),
        equivalent_strain=np.sqrt(exx ** 2 + eyy ** 2 + 2.0 * sym ** 2), coordination=coordination,
        sliding_fraction=sliding_fraction, member_offsets=offsets, member_index=index,
        n_invalid=int(np.count_nonzero(~valid)), n_too_few=int(np.count_nonzero(status == TOO_FEW)),
        n_centre_outside=int(np.count_nonzero(status == CENTRE_OUTSIDE)),
        n_excluded=int(np.count_nonzero(status == EXCLUDED)), neighbours=neighbours,
        rotation_normalisation=rotation_normalisation, configuration=configuration,
        boundary_contacts=boundary_contacts)
