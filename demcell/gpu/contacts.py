"""Contact forces of one cell on a GPU block: the law per pair, then each disc's resultant.

The arithmetic is ``relaxation.compute_forces``' general loop (the plain frictional loop gives
the same bits): the minimum-image branch vector (001 eq. A.1), the lever arms to the middle
of the overlap (001 eqs. A.5-A.6), ``contact_law.contact_update_params`` (000 eq. 10 with the
optional bond, dashpots and rolling spring), the micropolar cell's image spin. The CPU loop
adds each contact's force to its two discs in pair order; here the threads first compute
every contact (``pair_forces``, one pair per thread), then every disc adds its own contacts in
the same pair order (``gather_forces``: the pairs where it is the second disc, listed in
JLIST in pair order, then its block of pairs as the first disc, which comes after them in a
list sorted by i). Each resultant is thus the same sum in the same order, without atomics.
"""
import math

from numba import cuda

from ..slots import (BONDED, COH_N, COH_T, DIST, DPX, DPY, DTHETA, DX, DY, ENERGY, ETA_R, FJX, FJY, FN, FROZEN, FS,
                     FX, FY, ICOUNT, INERTIA, ISTART, JCOUNT, JLIST, JSTART, KN, KR, KS, MASS, MI, MJ, MOMENT, MR, MU,
                     PI, PJ, RADIUS, ROTATIONS, SX, SY, TOUCHING, XI_N, XI_T)
from ..lanes import LANES
from .block import combine_row


@cuda.jit(device=True)
def contact_update(overlap, d_overlap, d_ut, d_theta_r, fs_old, mr_old, bonded, kn, ks, mu, kr, eta_r,
                   xi_n, xi_t, coh_n, coh_t, m_eff, r_eff, dt):
    """contact_law.contact_update_params, the same operations: (fn, fn_elastic, fs,
    fs_elastic, mr, sliding, bonded)."""
    fn_el = kn * overlap
    if bonded == 1 and fn_el < -coh_n:
        bonded = 0
    if bonded == 0 and overlap <= 0.0:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0, 0
    fn = fn_el
    if xi_n > 0.0:
        fn += 2.0 * xi_n * math.sqrt(m_eff * kn) * d_overlap / dt
    fs = fs_old - ks * d_ut
    limit = mu * fn_el if fn_el > 0.0 else 0.0
    if bonded == 1:
        limit += coh_t
    sliding = 0
    if abs(fs) > limit:
        if bonded == 1:
            bonded = 0
            limit = mu * fn_el if fn_el > 0.0 else 0.0
        if abs(fs) > limit:
            fs = math.copysign(limit, fs)
            sliding = 1
    fs_el = fs
    if xi_t > 0.0 and sliding == 0:
        fs -= 2.0 * xi_t * math.sqrt(m_eff * ks) * d_ut / dt
    mr = 0.0
    if kr > 0.0:
        mr = mr_old - kr * d_theta_r
        mlim = eta_r * r_eff * fn_el if fn_el > 0.0 else 0.0
        if math.isinf(eta_r) and bonded == 1:
            mlim = math.inf
        if abs(mr) > mlim:
            mr = math.copysign(mlim, mr)
    return fn, fn_el, fs, fs_el, mr, sliding, bonded


@cuda.jit(device=True)
def release(k, qf, qb):
    """Pair slot k carries no force: its contact and history are cleared."""
    qb[TOUCHING, k] = 0
    qf[FN, k] = 0.0
    qf[FS, k] = 0.0
    qf[MR, k] = 0.0


@cuda.jit(device=True)
def pair_forces(c, p0, q0, n_pairs, pf, qf, qi, qb, qs, law, h00, h01, h10, h11, g0, g1, dt):
    """The law on the pairs q0 .. q0 + n_pairs - 1 of cell c, pair t, t + T, ... by thread t:
    updates the pair history and writes each contact's branch vector, force on j, moments on
    i and j and spring energy into qs (a pair that does not touch is left with touching 0).
    (g0, g1) = dkappa^T h_ref of a micropolar cell's last step (the image spin)."""
    kn = law[c, KN]
    ks = law[c, KS]
    mu = law[c, MU]
    kr = law[c, KR]
    eta_r = law[c, ETA_R]
    xi_n = law[c, XI_N]
    xi_t = law[c, XI_T]
    coh_n = law[c, COH_N]
    coh_t = law[c, COH_T]
    frozen = law[c, FROZEN] > 0.5
    image_spin = law[c, ROTATIONS] > 1.5 and (g0 != 0.0 or g1 != 0.0)
    viscous = xi_n > 0.0
    need_eff = viscous or xi_t > 0.0 or kr > 0.0
    half_inv_kn = 0.5 / kn
    half_inv_ks = 0.5 / ks if ks > 0.0 else 0.0
    half_inv_kr = 0.5 / kr if kr > 0.0 else 0.0
    for kk in range(cuda.threadIdx.x, n_pairs, cuda.blockDim.x):
        k = q0 + kk
        i = p0 + qi[PI, k]
        j = p0 + qi[PJ, k]
        a = pf[SX, j] - pf[SX, i]
        b = pf[SY, j] - pf[SY, i]
        round_a = math.floor(a + 0.5)
        round_b = math.floor(b + 0.5)
        a -= round_a
        b -= round_b
        dx = h00 * a + h01 * b
        dy = h10 * a + h11 * b
        dist = math.sqrt(dx * dx + dy * dy)
        qs[DX, k] = dx
        qs[DY, k] = dy
        qs[DIST, k] = dist
        ri = pf[RADIUS, i]
        rj = pf[RADIUS, j]
        overlap = ri + rj - dist
        if frozen:
            if qb[TOUCHING, k] == 0:
                continue
            bond = 1
        else:
            bond = int(qb[BONDED, k])
            if overlap <= 0.0 and bond == 0:
                release(k, qf, qb)
                continue
        inv_dist = 1.0 / dist
        nx = dx * inv_dist
        ny = dy * inv_dist
        ai = ri - 0.5 * overlap
        aj = rj - 0.5 * overlap
        tx = -ny
        ty = nx
        if qb[TOUCHING, k] == 1:
            ux = dx - qf[DPX, k]
            uy = dy - qf[DPY, k]
            d_ovl = 0.0
            if viscous:
                d_ovl = math.sqrt(qf[DPX, k] * qf[DPX, k] + qf[DPY, k] * qf[DPY, k]) - dist
            dth_i = pf[DTHETA, i]
            dth_j = pf[DTHETA, j]
            if image_spin:
                # the copy of the contact whose contact point lies in the cell (contact_copy)
                lever = ai * inv_dist
                m_a = math.floor(pf[SX, i] + lever * a)
                m_b = math.floor(pf[SY, i] + lever * b)
                copy_shift = g0 * m_a + g1 * m_b
                dth_i -= copy_shift
                dth_j -= g0 * round_a + g1 * round_b + copy_shift
            d_ut = ux * tx + uy * ty - ai * dth_i - aj * dth_j
            d_thr = dth_j - dth_i
            fs_old = qf[FS, k]
            mr_old = qf[MR, k]
        else:
            d_ovl = 0.0
            d_ut = 0.0
            d_thr = 0.0
            fs_old = 0.0
            mr_old = 0.0
        m_eff = 0.0
        r_eff = 0.0
        if need_eff:
            m_eff = pf[MASS, i] * pf[MASS, j] / (pf[MASS, i] + pf[MASS, j])
            r_eff = ri * rj / (ri + rj)
        fnt, fne, fst, fse, mrk, sl, bond = contact_update(overlap, d_ovl, d_ut, d_thr, fs_old, mr_old, bond,
                                                           kn, ks, mu, kr, eta_r, xi_n, xi_t, coh_n, coh_t,
                                                           m_eff, r_eff, dt)
        if not frozen:
            qb[BONDED, k] = bond
            if fne == 0.0 and fst == 0.0 and overlap <= 0.0:
                release(k, qf, qb)
                continue
        qb[TOUCHING, k] = 1
        qf[DPX, k] = dx
        qf[DPY, k] = dy
        qf[FN, k] = fnt
        qf[FS, k] = fse
        qf[MR, k] = mrk
        qs[FJX, k] = fnt * nx + fst * tx
        qs[FJY, k] = fnt * ny + fst * ty
        qs[MI, k] = -ai * fst - mrk
        qs[MJ, k] = -aj * fst + mrk
        qs[ENERGY, k] = half_inv_kn * fne * fne + half_inv_ks * fse * fse + half_inv_kr * mrk * mrk


@cuda.jit(device=True)
def gather_forces(p0, n, pf, qb, qs, qn, pis):
    """Force and moment of every disc of the cell (disc t, t + T, ... by thread t): its
    contacts added in pair order, as the CPU loop adds them."""
    for ii in range(cuda.threadIdx.x, n, cuda.blockDim.x):
        i = p0 + ii
        fx = 0.0
        fy = 0.0
        m = 0.0
        start = pis[JSTART, i]
        for u in range(start, start + pis[JCOUNT, i]):
            k = qn[JLIST, u]
            if qb[TOUCHING, k] == 1:
                fx += qs[FJX, k]
                fy += qs[FJY, k]
                m += qs[MJ, k]
        start = pis[ISTART, i]
        for k in range(start, start + pis[ICOUNT, i]):
            if qb[TOUCHING, k] == 1:
                fx -= qs[FJX, k]
                fy -= qs[FJY, k]
                m += qs[MI, k]
        pf[FX, i] = fx
        pf[FY, i] = fy
        pf[MOMENT, i] = m


@cuda.jit(device=True)
def gather_weights(p0, n, qf, qb, qn, pis, weight):
    """relaxation.contact_weights' weight of every disc: |fn| summed over its touching
    contacts in pair order."""
    for ii in range(cuda.threadIdx.x, n, cuda.blockDim.x):
        i = p0 + ii
        w = 0.0
        start = pis[JSTART, i]
        for u in range(start, start + pis[JCOUNT, i]):
            k = qn[JLIST, u]
            if qb[TOUCHING, k] == 1:
                w += abs(qf[FN, k])
        start = pis[ISTART, i]
        for k in range(start, start + pis[ICOUNT, i]):
            if qb[TOUCHING, k] == 1:
                w += abs(qf[FN, k])
        weight[i] = w


@cuda.jit(device=True)
def weight_sums(p0, n, pf, weight, with_moments, part, shf):
    """relaxation.contact_weights' 1 / sum(w^2 / I) and, with_moments, constrain_moments'
    sum(w M / I), in lanes.py's order; both left in shf[0], shf[1] for every thread.
    Two barriers."""
    t = cuda.threadIdx.x
    for lane in range(t, LANES, cuda.blockDim.x):
        s2 = 0.0
        acc = 0.0
        for ii in range(lane, n, LANES):
            i = p0 + ii
            w = weight[i]
            inv_i = 1.0 / pf[INERTIA, i]
            s2 += w * w * inv_i
            if with_moments:
                acc += w * pf[MOMENT, i] * inv_i
        part[0, lane] = s2
        part[1, lane] = acc
    cuda.syncthreads()
    if t == 0:
        s2 = combine_row(part, 0)
        shf[0] = 1.0 / s2 if s2 > 0.0 else 0.0
        shf[1] = combine_row(part, 1)
    cuda.syncthreads()


@cuda.jit(device=True)
def hold_mean_rotation(p0, n, pf, qf, qb, qn, pis, weight, part, shf):
    """relaxation.constrain_moments: the weights, then the reaction lambda w_p of the held mean
    rotation added to every disc's moment. Returns (lambda, 1 / sum(w^2 / I)); every thread
    gets them. Three barriers."""
    gather_weights(p0, n, qf, qb, qn, pis, weight)
    cuda.syncthreads()
    weight_sums(p0, n, pf, weight, True, part, shf)
    inv_s2 = shf[0]
    lam = -shf[1] * inv_s2
    for ii in range(cuda.threadIdx.x, n, cuda.blockDim.x):
        i = p0 + ii
        pf[MOMENT, i] += lam * weight[i]
    cuda.syncthreads()
    return lam, inv_s2
