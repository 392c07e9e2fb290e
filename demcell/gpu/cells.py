"""Per-cell kernels of the device store: what a Newton pass reads from the cells (the
homogenised sums of homogenization.contact_sums, the Kruyt operator of tangent._kruyt_sum,
the touching contacts) and the copies of cells between stores (commit, rollback, the growth
of pair slots, subsets, uploads and downloads).

The sums run one thread per cell, pair after pair in the CPU's order: they are taken once per
pass, not once per DEM step, and so give the CPU's bits at no cost worth a block.
"""
import math

from numba import cuda, float64

from ..slots import FN, FS, H, HREF, KN, KS, MR, MU, NCF, NPF, NQF, PI, PJ, RADIUS, SX, SY, TOUCHING
from .kinematics import branch_vector, inv2


@cuda.jit(cache=True)
def contact_sums(rows, micropolar, p_off, q_off, pf, qf, qi, qb, cf, ci, law, out, counts):
    """homogenization.contact_sums of the cells rows, one thread each: out[r] = sigma (4,
    row-major) [N/m], couple stress (2) [N], fabric (4); counts[r] = (contacts, sliding)."""
    r = cuda.grid(1)
    if r >= rows.shape[0]:
        return
    c = rows[r]
    p0 = p_off[c]
    q0 = q_off[c]
    mu = law[c, MU]
    h00 = cf[c, H]
    h01 = cf[c, H + 1]
    h10 = cf[c, H + 2]
    h11 = cf[c, H + 3]
    area = abs(h00 * h11 - h01 * h10)
    s00 = 0.0
    s01 = 0.0
    s10 = 0.0
    s11 = 0.0
    m0 = 0.0
    m1 = 0.0
    f00 = 0.0
    f01 = 0.0
    f11 = 0.0
    nc = 0
    nsl = 0
    for k in range(q0, q0 + ci[c, 0]):
        if qb[TOUCHING, k] == 0:
            continue
        i = p0 + qi[PI, k]
        j = p0 + qi[PJ, k]
        a, b, dx, dy = branch_vector(pf, i, j, h00, h01, h10, h11)
        dist = math.sqrt(dx * dx + dy * dy)
        nx = dx / dist
        ny = dy / dist
        tx = -ny
        ty = nx
        fn = qf[FN, k]
        fs = qf[FS, k]
        mr = qf[MR, k]
        fjx = fn * nx + fs * tx
        fjy = fn * ny + fs * ty
        s00 -= fjx * dx
        s01 -= fjx * dy
        s10 -= fjy * dx
        s11 -= fjy * dy
        overlap = pf[RADIUS, i] + pf[RADIUS, j] - dist
        mi = -(pf[RADIUS, i] - 0.5 * overlap) * fs - mr
        mj = -(pf[RADIUS, j] - 0.5 * overlap) * fs + mr
        if micropolar[r]:
            # the copy of the contact whose contact point lies in the cell (contact_copy)
            lever = (pf[RADIUS, i] - 0.5 * overlap) / dist
            m_a = math.floor(pf[SX, i] + lever * a)
            m_b = math.floor(pf[SY, i] + lever * b)
            si0 = pf[SX, i] - m_a - 0.5
            si1 = pf[SY, i] - m_b - 0.5
            xi0 = cf[c, HREF] * si0 + cf[c, HREF + 1] * si1
            xi1 = cf[c, HREF + 2] * si0 + cf[c, HREF + 3] * si1
            lx = cf[c, HREF] * a + cf[c, HREF + 1] * b
            ly = cf[c, HREF + 2] * a + cf[c, HREF + 3] * b
        else:
            xi0 = h00 * (pf[SX, i] - 0.5) + h01 * (pf[SY, i] - 0.5)
            xi1 = h10 * (pf[SX, i] - 0.5) + h11 * (pf[SY, i] - 0.5)
            lx = dx
            ly = dy
        m0 -= mi * xi0 + mj * (xi0 + lx)
        m1 -= mi * xi1 + mj * (xi1 + ly)
        f00 += nx * nx
        f01 += nx * ny
        f11 += ny * ny
        nc += 1
        if fn > 0.0 and abs(fs) >= (1.0 - 1e-9) * mu * fn:
            nsl += 1
    if nc > 0:
        f00 /= nc
        f01 /= nc
        f11 /= nc
    out[r, 0] = s00 / area
    out[r, 1] = s01 / area
    out[r, 2] = s10 / area
    out[r, 3] = s11 / area
    out[r, 4] = m0 / area
    out[r, 5] = m1 / area
    out[r, 6] = f00
    out[r, 7] = f01
    out[r, 8] = f01
    out[r, 9] = f11
    counts[r, 0] = nc
    counts[r, 1] = nsl


@cuda.jit(cache=True)
def kruyt_sums(rows, p_off, q_off, pf, qi, qb, cf, ci, law, out):
    """tangent.kruyt_tensor of the cells rows, one thread each: out[r] = the (2, 2, 2, 2)
    tensor d sigma / d F [N/m] flattened (row i j, column k m), 001 eq. 13."""
    r = cuda.grid(1)
    if r >= rows.shape[0]:
        return
    c = rows[r]
    p0 = p_off[c]
    q0 = q_off[c]
    kn = law[c, KN]
    kt = law[c, KS] if law[c, MU] > 0.0 else 0.0
    h00 = cf[c, H]
    h01 = cf[c, H + 1]
    h10 = cf[c, H + 2]
    h11 = cf[c, H + 3]
    rr00 = cf[c, HREF]
    rr01 = cf[c, HREF + 1]
    rr10 = cf[c, HREF + 2]
    rr11 = cf[c, HREF + 3]
    det = rr00 * rr11 - rr01 * rr10
    F00 = (h00 * rr11 - h01 * rr10) / det
    F01 = (h01 * rr00 - h00 * rr01) / det
    F10 = (h10 * rr11 - h11 * rr10) / det
    F11 = (h11 * rr00 - h10 * rr01) / det
    i00, i01, i10, i11 = inv2(F00, F01, F10, F11)
    area = abs(h00 * h11 - h01 * h10)
    T = cuda.local.array(16, float64)
    K = cuda.local.array(4, float64)
    lv = cuda.local.array(2, float64)
    gl = cuda.local.array(2, float64)
    for m in range(16):
        T[m] = 0.0
    for k in range(q0, q0 + ci[c, 0]):
        if qb[TOUCHING, k] == 0:
            continue
        a, b, dx, dy = branch_vector(pf, p0 + qi[PI, k], p0 + qi[PJ, k], h00, h01, h10, h11)
        length = math.sqrt(dx * dx + dy * dy)
        nx = dx / length
        ny = dy / length
        K[0] = kn * nx * nx + kt * ny * ny
        K[1] = (kn - kt) * nx * ny
        K[2] = K[1]
        K[3] = kn * ny * ny + kt * nx * nx
        lv[0] = dx
        lv[1] = dy
        gl[0] = i00 * dx + i01 * dy
        gl[1] = i10 * dx + i11 * dy
        for ii in range(2):
            for jj in range(2):
                for kk in range(2):
                    for mm in range(2):
                        T[((ii * 2 + jj) * 2 + kk) * 2 + mm] += K[ii * 2 + kk] * lv[jj] * gl[mm]
    for m in range(16):
        out[r, m] = T[m] / area


@cuda.jit(cache=True)
def touching_counts(rows, q_off, qb, ci, counts):
    """The touching contacts of the cells rows, one thread each."""
    r = cuda.grid(1)
    if r >= rows.shape[0]:
        return
    c = rows[r]
    q0 = q_off[c]
    total = 0
    for k in range(q0, q0 + ci[c, 0]):
        total += qb[TOUCHING, k]
    counts[r] = total


@cuda.jit(cache=True)
def copy_cells(src_rows, dst_rows, s_poff, s_qoff, s_pf, s_qf, s_qi, s_qb, s_cf, s_ci,
               d_poff, d_qoff, d_pf, d_qf, d_qi, d_qb, d_cf, d_ci):
    """Cell src_rows[r] of one store into cell dst_rows[r] of another (or the same), one
    block each: its discs, its pair slots (the destination's slots past the source's
    capacity zeroed), its per-cell values. The two cells must have the same discs."""
    r = cuda.blockIdx.x
    cs = src_rows[r]
    cd = dst_rows[r]
    t = cuda.threadIdx.x
    T = cuda.blockDim.x
    ps = s_poff[cs]
    pd = d_poff[cd]
    n = s_poff[cs + 1] - ps
    for u in range(t, NPF * n, T):
        row = u // n
        i = u - row * n
        d_pf[row, pd + i] = s_pf[row, ps + i]
    qs0 = s_qoff[cs]
    qd0 = d_qoff[cd]
    m_src = s_qoff[cs + 1] - qs0
    m_dst = d_qoff[cd + 1] - qd0
    m = min(m_src, m_dst)
    for k in range(t, m_dst, T):
        if k < m:
            for row in range(NQF):
                d_qf[row, qd0 + k] = s_qf[row, qs0 + k]
            d_qi[0, qd0 + k] = s_qi[0, qs0 + k]
            d_qi[1, qd0 + k] = s_qi[1, qs0 + k]
            d_qb[0, qd0 + k] = s_qb[0, qs0 + k]
            d_qb[1, qd0 + k] = s_qb[1, qs0 + k]
        else:
            for row in range(NQF):
                d_qf[row, qd0 + k] = 0.0
            d_qi[0, qd0 + k] = 0
            d_qi[1, qd0 + k] = 0
            d_qb[0, qd0 + k] = 0
            d_qb[1, qd0 + k] = 0
    if t == 0:
        for col in range(NCF):
            d_cf[cd, col] = s_cf[cs, col]
        d_ci[cd, 0] = s_ci[cs, 0]
        d_ci[cd, 1] = s_ci[cs, 1]
