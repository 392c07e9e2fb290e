"""Contacts of a bounded specimen: cell-list Verlet neighbours and the pair force kernel.

Neighbours (``build_pairs``): the discs are binned on a grid of square cells of side
2 r_max + skin (linked cells in CSR form, a counting sort); every pair i < j closer than
r_i + r_j + skin is listed, sorted by i then j. O(n) per build, parallel over the discs in
two passes (count, then fill), so the list does not depend on the number of threads. A
laterally periodic specimen (period L > 0) uses the minimum image in x. The list is rebuilt
when 2 max_i |x_i - x_i^build| (or max |u_i| + the largest wall motion, for the disc-wall
candidates) exceeds the skin. ``merge_history`` carries the contact history (touching, fs,
mr) over from the old list to the new one; ``spatial_order`` renumbers the discs along a
Morton (Z-order) curve of the bins, so that the discs of one contact lie close in memory
whatever the size of the specimen.

Forces (``pair_forces`` then ``gather_forces``): the law is demcell's
``contact_law.contact_update_params`` (the periodic cell's), with the normal force clipped at
>= 0 and the Coulomb limit on the total normal force when asked (004 eqs. 7.4-7.14, dns-spec
A2). Pass 1 (``branch``) writes the branch vector of every pair, pass 2 (``one_pair``)
evaluates every listed pair independently and writes the force on j and the two moments into
a scratch row; pass 3 sums them per disc through the CSR of its pairs (first
the pairs where it is j, then those where it is i, each in list order). Every sum is taken in
a fixed order, so the forces are bit-identical whatever the number of Numba threads.

Rates (004 eqs. 7.4, 7.6, 7.8, leapfrog of dns-spec A5): the overlap rate and the tangential
slip are taken from the half-step velocities v_{n-1/2}, omega_{n-1/2}:
d_overlap = -(v_j - v_i).n dt, d_ut = ((v_j - v_i).t - a_i omega_i - a_j omega_j) dt, the
relative displacement of j's contact point w.r.t. i's along t (the increments of the
periodic cell, which takes them from positions, are the same to round-off).
"""
import math

import numpy as np
from numba import njit, prange

from ..contact_law import contact_update_params

#: pairs below which the kernels take their serial loop. 0: always the parallel loop, even on
#: one thread: in a parallel=True kernel Numba 0.56 compiled the plain range loop some 1.5x
#: slower per pair (44 ns against 30 ns at 10^5 discs, benchmarks/dns/specimen_throughput.py)
#: than the prange loop, whose launch costs only microseconds per step
PARALLEL_MIN_PAIRS = 0

# law vector slots read by the pair kernel (``law_vector``)
(P_KN, P_KS, P_MU, P_KR, P_ETA, P_XIN, P_XIT, P_MEFF, P_PAIRMASS, P_CLIP, P_TOTAL, P_ROT, P_DT, P_PERIOD,
 P_WALL_DN, P_WALL_RATIO, P_PARALLEL_MIN, N_PAR) = range(18)


def law_vector(law, options, period):
    """The float64 parameter vector of the pair kernel from a ContactLaw and SpecimenOptions.

    Dashpots: options.normal_dashpot D_n [N s/m] given: every pair gets c_n = D_n (the
    kernel passes m_eff = 1/kn and xi_n = D_n / (2 sqrt(m_eff kn)) to contact_update_params,
    whose c = 2 xi sqrt(m_eff kn) is then D_n to round-off); None: the law's ratio
    c = 2 xi_n sqrt(m_eff kn) with m_eff = m_i m_j / (m_i + m_j) per pair. Same for D_t."""
    p = np.zeros(N_PAR)
    p[P_KN], p[P_KS], p[P_MU] = law.kn, law.ks, law.friction
    p[P_KR], p[P_ETA] = law.rolling_stiffness, law.rolling_friction
    if options.normal_dashpot is not None or options.tangential_dashpot is not None:
        m_eff = 1.0 / law.kn
        p[P_MEFF] = m_eff
        d_n = options.normal_dashpot if options.normal_dashpot is not None else 0.0
        d_t = options.tangential_dashpot if options.tangential_dashpot is not None else 0.0
        p[P_XIN] = d_n / (2.0 * math.sqrt(m_eff * law.kn))
        p[P_XIT] = d_t / (2.0 * math.sqrt(m_eff * law.ks)) if law.ks > 0.0 else 0.0
        p[P_PAIRMASS] = 0.0
        p[P_WALL_DN], p[P_WALL_RATIO] = d_n, 0.0
    else:
        p[P_XIN], p[P_XIT] = law.normal_damping, law.tangential_damping
        p[P_PAIRMASS] = 1.0 if (law.normal_damping > 0.0 or law.tangential_damping > 0.0) else 0.0
        p[P_WALL_DN], p[P_WALL_RATIO] = 0.0, law.normal_damping
    p[P_CLIP] = 1.0 if options.clip_normal else 0.0
    p[P_TOTAL] = 1.0 if options.coulomb_on_total_normal else 0.0
    p[P_ROT] = 1.0 if law.rotations else 0.0
    p[P_DT] = options.dt
    p[P_PERIOD] = period
    p[P_PARALLEL_MIN] = PARALLEL_MIN_PAIRS
    return p


# ------------------------------------------------------------------------------------------
# neighbour search


@njit(cache=True)
def _grid(position, radius, skin, period, x_origin):
    """Bin geometry: (cell side, x0, y0, nbx, nby, rc). Periodic (period > 0): the x range
    is one period from x_origin and nbx = floor(period / side) (>= 1)."""
    n = position.shape[0]
    rmax = 0.0
    xmin = math.inf
    xmax = -math.inf
    ymin = math.inf
    ymax = -math.inf
    for i in range(n):
        rmax = max(rmax, radius[i])
        xmin = min(xmin, position[i, 0])
        xmax = max(xmax, position[i, 0])
        ymin = min(ymin, position[i, 1])
        ymax = max(ymax, position[i, 1])
    rc = 2.0 * rmax + skin
    side = rc
    if period > 0.0:
        xmin = x_origin
        xmax = x_origin + period
    # a cloud spread far beyond its discs (a disc flying away) would need many empty bins:
    # larger bins stay correct
    while True:
        nbx = max(1, int((xmax - xmin) / side) + (0 if period > 0.0 else 1))
        nby = max(1, int((ymax - ymin) / side) + 1)
        if nbx * nby <= 4 * n + 16:
            break
        side *= 2.0
    if period > 0.0:
        side_x = period / nbx
    else:
        side_x = side
    return side_x, side, xmin, ymin, nbx, nby, rc


@njit(cache=True)
def _bin_of(x, y, side_x, side_y, x0, y0, nbx, nby, period):
    if period > 0.0:
        u = x - x0
        u -= period * math.floor(u / period)
        bx = int(u / side_x)
    else:
        bx = int((x - x0) / side_x)
    by = int((y - y0) / side_y)
    bx = min(max(bx, 0), nbx - 1)
    by = min(max(by, 0), nby - 1)
    return bx, by


@njit(cache=True)
def bin_discs(position, radius, skin, period, x_origin):
    """Linked cells as CSR: (bin_start (nb + 1,), bin_disc (n,), bin_x (n,), bin_y (n,),
    grid tuple). Discs within a bin in index order (a counting sort)."""
    n = position.shape[0]
    side_x, side_y, x0, y0, nbx, nby, rc = _grid(position, radius, skin, period, x_origin)
    bx_of = np.empty(n, np.int64)
    by_of = np.empty(n, np.int64)
    count = np.zeros(nbx * nby + 1, np.int64)
    for i in range(n):
        bx, by = _bin_of(position[i, 0], position[i, 1], side_x, side_y, x0, y0, nbx, nby, period)
        bx_of[i] = bx
        by_of[i] = by
        count[by * nbx + bx + 1] += 1
    for b in range(nbx * nby):
        count[b + 1] += count[b]
    fill = count[:-1].copy()
    disc = np.empty(n, np.int64)
    for i in range(n):
        b = by_of[i] * nbx + bx_of[i]
        disc[fill[b]] = i
        fill[b] += 1
    return count, disc, bx_of, by_of, nbx, nby


@njit(cache=True)
def _scan_disc(i, position, radius, skin, period, bin_start, bin_disc, bx_of, by_of, nbx, nby, out, store):
    """Neighbours j > i of disc i within r_i + r_j + skin: their count; stored in out[:count]
    (sorted) when `store`."""
    xi = position[i, 0]
    yi = position[i, 1]
    ri = radius[i]
    bx = bx_of[i]
    by = by_of[i]
    m = 0
    # distinct bin columns around bx (all of them when a periodic strip has < 3)
    if period > 0.0 and nbx < 3:
        c_lo = 0
        c_hi = nbx - 1
        wrap = False
    elif period > 0.0:
        c_lo = bx - 1
        c_hi = bx + 1
        wrap = True
    else:
        c_lo = max(bx - 1, 0)
        c_hi = min(bx + 1, nbx - 1)
        wrap = False
    for cy in range(max(by - 1, 0), min(by + 1, nby - 1) + 1):
        for cc in range(c_lo, c_hi + 1):
            cx = cc
            if wrap:
                cx = cc % nbx
            b = cy * nbx + cx
            for q in range(bin_start[b], bin_start[b + 1]):
                j = bin_disc[q]
                if j <= i:
                    continue
                dx = position[j, 0] - xi
                if period > 0.0:
                    dx -= period * np.floor(dx / period + 0.5)
                dy = position[j, 1] - yi
                lim = ri + radius[j] + skin
                if dx * dx + dy * dy < lim * lim:
                    if store:
                        out[m] = j
                    m += 1
    if store and m > 1:
        out[:m].sort()
    return m


@njit(cache=True, parallel=True)
def build_pairs(position, radius, skin, period, x_origin):
    """All pairs i < j closer than r_i + r_j + skin [m] (x minimum image when period > 0),
    sorted by i then j: (pair_i, pair_j, row) with row (n + 1,) the CSR start of each i.
    Two parallel passes over the discs (count, fill): the list does not depend on the threads.
    (Numba's parallel loops sit in the kernel called from Python: a cached kernel that calls
    another parallel kernel crashed when loaded from the cache, Numba 0.56.)"""
    n = position.shape[0]
    bin_start, bin_disc, bx_of, by_of, nbx, nby = bin_discs(position, radius, skin, period, x_origin)
    row = np.zeros(n + 1, np.int64)
    dummy = np.empty(0, np.int64)
    for i in prange(n):
        row[i + 1] = _scan_disc(i, position, radius, skin, period, bin_start, bin_disc, bx_of, by_of,
                                nbx, nby, dummy, False)
    for i in range(n):
        row[i + 1] += row[i]
    m = row[n]
    pair_i = np.empty(m, np.int64)
    pair_j = np.empty(m, np.int64)
    for i in prange(n):
        a = row[i]
        c = _scan_disc(i, position, radius, skin, period, bin_start, bin_disc, bx_of, by_of, nbx, nby,
                       pair_j[a:row[i + 1]], True)
        for k in range(a, a + c):
            pair_i[k] = i
    return pair_i, pair_j, row


@njit(cache=True)
def pairs_of_j(n, pair_j):
    """CSR of the pairs by their second disc: (start (n + 1,), pair index (m,)), pair indices
    of each j in list order (a stable counting sort)."""
    m = pair_j.shape[0]
    start = np.zeros(n + 1, np.int64)
    for k in range(m):
        start[pair_j[k] + 1] += 1
    for p in range(n):
        start[p + 1] += start[p]
    fill = start[:-1].copy()
    col = np.empty(m, np.int64)
    for k in range(m):
        j = pair_j[k]
        col[fill[j]] = k
        fill[j] += 1
    return start, col


@njit(cache=True)
def merge_history(old_i, old_j, touching, sliding, fn, fs, mr, new_i, new_j):
    """The contact history of the old sorted list carried over to the new sorted list:
    (touching, sliding, fn, fs, mr) of the new list; pairs new to the list start untouched.
    (demcell.neighbours.merge_history does the same for the periodic cell's bond and branch
    vector arrays, which a specimen does not have.)"""
    m = new_i.shape[0]
    t_touch = np.zeros(m, np.int8)
    t_slide = np.zeros(m, np.int8)
    t_fn = np.zeros(m)
    t_fs = np.zeros(m)
    t_mr = np.zeros(m)
    a = 0
    old_n = old_i.shape[0]
    for k in range(m):
        i = new_i[k]
        j = new_j[k]
        while a < old_n and (old_i[a] < i or (old_i[a] == i and old_j[a] < j)):
            a += 1
        if a < old_n and old_i[a] == i and old_j[a] == j:
            t_touch[k] = touching[a]
            t_slide[k] = sliding[a]
            t_fn[k] = fn[a]
            t_fs[k] = fs[a]
            t_mr[k] = mr[a]
            a += 1
    return t_touch, t_slide, t_fn, t_fs, t_mr


def spatial_order(position, radius, skin=0.0):
    """Permutation of the discs along the Morton (Z-order) curve of bins of side
    2 r_max + skin (row-major inside nothing: the bin code alone, ties in index order)."""
    position = np.asarray(position, float)
    side = 2.0 * float(np.max(radius)) + skin
    ix = np.floor((position[:, 0] - position[:, 0].min()) / side).astype(np.uint64)
    iy = np.floor((position[:, 1] - position[:, 1].min()) / side).astype(np.uint64)
    return np.argsort(_interleave(ix) | (_interleave(iy) << np.uint64(1)), kind="stable")


def _interleave(v):
    """Bits of v (< 2^32) spread to the even bit positions."""
    v = v & np.uint64(0xFFFFFFFF)
    for shift, mask in ((16, 0x0000FFFF0000FFFF), (8, 0x00FF00FF00FF00FF), (4, 0x0F0F0F0F0F0F0F0F),
                        (2, 0x3333333333333333), (1, 0x5555555555555555)):
        v = (v | (v << np.uint64(shift))) & np.uint64(mask)
    return v


def brute_force_pairs(position, radius, skin, period=0.0):
    """Reference O(n^2) list (tests): pairs i < j closer than r_i + r_j + skin, sorted."""
    d = position[None, :, :] - position[:, None, :]
    if period > 0.0:
        d[..., 0] -= period * np.floor(d[..., 0] / period + 0.5)
    dist2 = np.sum(d * d, axis=2)
    lim = radius[:, None] + radius[None, :] + skin
    i, j = np.nonzero(np.triu(dist2 < lim * lim, k=1))
    return i.astype(np.int64), j.astype(np.int64)


# ------------------------------------------------------------------------------------------
# pair forces


@njit(cache=True)
def branch(k, position, pair_i, pair_j, period, geo):
    """First pass of the force loop: x_j - x_i of pair k (x minimum image when period > 0) and
    its squared length into geo[k] (short independent iterations that the core overlaps; the
    law pass after it ran 2x faster per pair than one pass doing both, 13 against 29 ns)."""
    i = pair_i[k]
    j = pair_j[k]
    dx = position[j, 0] - position[i, 0]
    if period > 0.0:
        dx -= period * np.floor(dx / period + 0.5)
    dy = position[j, 1] - position[i, 1]
    geo[k, 0] = dx
    geo[k, 1] = dy
    geo[k, 2] = dx * dx + dy * dy


@njit(cache=True)
def clear_pair(k, touching, sliding, fn, fs, mr, work):
    """Pair k out of contact: its history and its force scratch zeroed."""
    touching[k] = 0
    sliding[k] = 0
    fn[k] = 0.0
    fs[k] = 0.0
    mr[k] = 0.0
    work[k, 0] = 0.0
    work[k, 1] = 0.0
    work[k, 2] = 0.0
    work[k, 3] = 0.0


@njit(cache=True)
def one_pair(k, geo, velocity, spin, radius, mass, pair_i, pair_j, touching, sliding, fn, fs, mr, work,
              kn, ks, mu, kr, eta_r, xi_n, xi_t, meff_const, pair_mass, clip, total, rot, dt):
    """Contact law of listed pair k (004 eqs. 7.3-7.14 through contact_update_params) from its
    branch vector geo[k] (``branch``): its history updated in place, the force on j
    (work[k, 0:2]) and the moments on i and j (work[k, 2], work[k, 3]) [N, N m]; zeros when
    the discs are apart."""
    i = pair_i[k]
    j = pair_j[k]
    dx = geo[k, 0]
    dy = geo[k, 1]
    ri = radius[i]
    rj = radius[j]
    lim = ri + rj
    d2 = geo[k, 2]
    if d2 >= lim * lim:
        clear_pair(k, touching, sliding, fn, fs, mr, work)
        return
    dist = math.sqrt(d2)
    overlap = lim - dist
    inv = 1.0 / dist
    nx = dx * inv
    ny = dy * inv
    tx = -ny
    ty = nx
    ai = ri - 0.5 * overlap
    aj = rj - 0.5 * overlap
    dvx = velocity[j, 0] - velocity[i, 0]
    dvy = velocity[j, 1] - velocity[i, 1]
    wi = spin[i] if rot else 0.0
    wj = spin[j] if rot else 0.0
    d_ovl = -(dvx * nx + dvy * ny) * dt
    d_ut = (dvx * tx + dvy * ty - ai * wi - aj * wj) * dt
    d_thr = (wj - wi) * dt
    if touching[k] == 1:
        fs_old = fs[k]
        mr_old = mr[k]
    else:
        fs_old = 0.0
        mr_old = 0.0
    m_eff = meff_const
    if pair_mass:
        m_eff = mass[i] * mass[j] / (mass[i] + mass[j])
    r_eff = ri * rj / (ri + rj) if kr > 0.0 else 0.0
    fnt, fne, fst, fse, mrk, sl, bond = contact_update_params(
        overlap, d_ovl, d_ut, d_thr, fs_old, mr_old, 0, kn, ks, mu, kr, eta_r, xi_n, xi_t, 0.0, 0.0,
        m_eff, r_eff, dt, clip, total)
    touching[k] = 1
    sliding[k] = sl
    fn[k] = fnt
    fs[k] = fse
    mr[k] = mrk
    work[k, 0] = fnt * nx + fst * tx
    work[k, 1] = fnt * ny + fst * ty
    work[k, 2] = -ai * fst - mrk
    work[k, 3] = -aj * fst + mrk


@njit(cache=True)
def law_scalars(par):
    """The law vector (``law_vector``) as the scalars the pair kernel takes: (kn, ks, mu, kr,
    eta_r, xi_n, xi_t, m_eff, per-pair mass flag, clip flag, limit-on-total flag, rotations
    flag, dt, period), read once per call rather than once per pair."""
    return (par[P_KN], par[P_KS], par[P_MU], par[P_KR], par[P_ETA], par[P_XIN], par[P_XIT], par[P_MEFF],
            par[P_PAIRMASS] > 0.5, par[P_CLIP] > 0.5, par[P_TOTAL] > 0.5, par[P_ROT] > 0.5, par[P_DT],
            par[P_PERIOD])


@njit(cache=True, parallel=True)
def pair_forces(position, velocity, spin, radius, mass, pair_i, pair_j, touching, sliding, fn, fs, mr, work, par):
    """Pass 1: the law on every listed pair (``one_pair``), parallel over the pairs when
    there are at least par[P_PARALLEL_MIN] of them. work (m, 4) scratch. (The engine's time
    loop has the same loop inline: see build_pairs on calling parallel kernels.)"""
    kn, ks, mu, kr, eta_r, xi_n, xi_t, meff, pair_mass, clip, total, rot, dt, period = law_scalars(par)
    geo = np.empty((pair_i.shape[0], 3))
    if pair_i.shape[0] >= par[P_PARALLEL_MIN]:
        for k in prange(pair_i.shape[0]):
            branch(k, position, pair_i, pair_j, period, geo)
        for k in prange(pair_i.shape[0]):
            one_pair(k, geo, velocity, spin, radius, mass, pair_i, pair_j, touching, sliding, fn, fs, mr,
                      work, kn, ks, mu, kr, eta_r, xi_n, xi_t, meff, pair_mass, clip, total, rot, dt)
    else:
        for k in range(pair_i.shape[0]):
            branch(k, position, pair_i, pair_j, period, geo)
        for k in range(pair_i.shape[0]):
            one_pair(k, geo, velocity, spin, radius, mass, pair_i, pair_j, touching, sliding, fn, fs, mr,
                      work, kn, ks, mu, kr, eta_r, xi_n, xi_t, meff, pair_mass, clip, total, rot, dt)


@njit(cache=True)
def gather_disc(p, row, jstart, jcol, work):
    """Resultant force and moment of the contacts of disc p from the pair scratch: the pairs
    where p is j (in list order), then those where it is i. Returns (fx, fy, moment)."""
    fx = 0.0
    fy = 0.0
    mo = 0.0
    for q in range(jstart[p], jstart[p + 1]):
        k = jcol[q]
        fx += work[k, 0]
        fy += work[k, 1]
        mo += work[k, 3]
    for k in range(row[p], row[p + 1]):
        fx -= work[k, 0]
        fy -= work[k, 1]
        mo += work[k, 2]
    return fx, fy, mo


@njit(cache=True, parallel=True)
def gather_forces(row, jstart, jcol, work, force, moment, parallel_min):
    """Pass 2: contact resultants per disc into force (n, 2), moment (n,) (overwritten);
    parallel over the discs when there are at least parallel_min pairs."""
    if work.shape[0] >= parallel_min:
        for p in prange(force.shape[0]):
            fx, fy, mo = gather_disc(p, row, jstart, jcol, work)
            force[p, 0] = fx
            force[p, 1] = fy
            moment[p] = mo
    else:
        for p in range(force.shape[0]):
            fx, fy, mo = gather_disc(p, row, jstart, jcol, work)
            force[p, 0] = fx
            force[p, 1] = fy
            moment[p] = mo


@njit(cache=True)
def elastic_energy(position, radius, pair_i, pair_j, touching, fs, mr, kn, ks, kr, period):
    """Energy stored in the contact springs [J/m]: kn h^2/2 + fs^2/(2 ks) + mr^2/(2 kr)."""
    e = 0.0
    for k in range(pair_i.shape[0]):
        if touching[k] == 0:
            continue
        i = pair_i[k]
        j = pair_j[k]
        dx = position[j, 0] - position[i, 0]
        if period > 0.0:
            dx -= period * np.floor(dx / period + 0.5)
        dy = position[j, 1] - position[i, 1]
        h = radius[i] + radius[j] - math.sqrt(dx * dx + dy * dy)
        if h > 0.0:
            e += 0.5 * kn * h * h
        if ks > 0.0:
            e += 0.5 * fs[k] * fs[k] / ks
        if kr > 0.0:
            e += 0.5 * mr[k] * mr[k] / kr
    return e


def contact_geometry(position, radius, pair_i, pair_j, fn, fs, mr=None, periodic_width=None):
    """Per pair: branch d = x_j - x_i (minimum image in x) (m,2) [m], distance (m,) [m],
    overlap (m,) [m], force on j fn n + fs t (m,2) [N], moment on i -a_i fs - mr and on j
    -a_j fs + mr (m,) [N m] (demcell's convention, a = r - overlap/2)."""
    width = float(periodic_width or 0.0)
    d = position[pair_j] - position[pair_i]
    if width > 0.0:
        d[:, 0] -= width * np.floor(d[:, 0] / width + 0.5)
    dist = np.hypot(d[:, 0], d[:, 1])
    safe = np.where(dist > 0.0, dist, 1.0)
    nx = d[:, 0] / safe
    ny = d[:, 1] / safe
    force_j = np.stack([fn * nx - fs * ny, fn * ny + fs * nx], -1)
    overlap = radius[pair_i] + radius[pair_j] - dist
    rolling = 0.0 if mr is None else mr
    moment_i = -(radius[pair_i] - 0.5 * overlap) * fs - rolling
    moment_j = -(radius[pair_j] - 0.5 * overlap) * fs + rolling
    return d, dist, overlap, force_j, moment_i, moment_j
