"""The neighbour list of one cell on a GPU block: rebuilt as ``neighbours.build_pairs`` builds
it (the same pairs in the same order, i < j sorted by i then j), its history carried over
as ``neighbours.merge_history`` carries it, and each disc's pair slots indexed for the
gather of the forces (contacts.gather_forces).

The CPU builds the list disc after disc; here every thread takes discs (t, t + T, ...):
binning by atomic counts, a count of each disc's neighbours, a prefix sum by thread 0 that
places each disc's pairs, then each disc writes and sorts its own. The order of the atomics
changes nothing: every disc's neighbours are sorted. The history of a surviving pair is found
by binary search in the old list (sorted by the key i n + j) instead of by a merge walk.
"""
import math

from numba import cuda

from .block import first_slot_of, lower_bound
from .kinematics import branch_vector
from ..slots import (BCOUNT, BIN_ITEM, BIN_OF, BONDED, BSTART, DPX, DPY, FN, FS, ICOUNT, ISTART, JCOUNT, JFILL, JLIST,
                     JSTART, MR, NCOUNT, NEW_I, NEW_J, NSTART, PI, PJ, RADIUS, SX, SY, TOUCHING, T_DPX, T_DPY, T_FN,
                     T_FS, T_MR)


@cuda.jit(device=True)
def within(pf, i, j, h00, h01, h10, h11, skin):
    """periodic_cell.branch_vector's distance from disc i to disc j (global indices) below
    R_i + R_j + skin."""
    a, b, dx, dy = branch_vector(pf, i, j, h00, h01, h10, h11)
    lim = pf[RADIUS, i] + pf[RADIUS, j] + skin
    return dx * dx + dy * dy < lim * lim


@cuda.jit(device=True)
def sort_slots(arr, row, lo, hi):
    """arr[row, lo:hi] sorted in place (insertion sort: a disc has a few entries)."""
    for u in range(lo + 1, hi):
        key = arr[row, u]
        v = u - 1
        while v >= lo and arr[row, v] > key:
            arr[row, v + 1] = arr[row, v]
            v -= 1
        arr[row, v + 1] = key


@cuda.jit(device=True)
def index_pairs(p0, n, q0, n_pairs, qi, qn, pis):
    """Each disc's pair slots: as first disc (ISTART, ICOUNT: a block of the list sorted by
    i) and as second disc (JLIST[JSTART:JSTART + JCOUNT], in pair order). Four barriers."""
    t = cuda.threadIdx.x
    T = cuda.blockDim.x
    end = q0 + n_pairs
    for ii in range(t, n, T):
        i = p0 + ii
        lo = first_slot_of(qi, q0, end, ii)
        pis[ISTART, i] = lo
        pis[ICOUNT, i] = first_slot_of(qi, lo, end, ii + 1) - lo
        pis[JCOUNT, i] = 0
        pis[JFILL, i] = 0
    cuda.syncthreads()
    for k in range(q0 + t, end, T):
        cuda.atomic.add(pis, (JCOUNT, p0 + qi[PJ, k]), 1)
    cuda.syncthreads()
    if t == 0:
        total = q0
        for ii in range(n):
            pis[JSTART, p0 + ii] = total
            total += pis[JCOUNT, p0 + ii]
    cuda.syncthreads()
    for k in range(q0 + t, end, T):
        j = p0 + qi[PJ, k]
        slot = cuda.atomic.add(pis, (JFILL, j), 1)
        qn[JLIST, pis[JSTART, j] + slot] = k
    cuda.syncthreads()
    for ii in range(t, n, T):
        i = p0 + ii
        sort_slots(qn, JLIST, pis[JSTART, i], pis[JSTART, i] + pis[JCOUNT, i])
    cuda.syncthreads()


@cuda.jit(device=True)
def build_pairs(p0, n, q0, capacity, pf, qn, pis, bins, b0, h00, h01, h10, h11, skin, rmax, shi):
    """neighbours.build_pairs into qn[NEW_I], qn[NEW_J] (from slot q0): the number of pairs,
    -1 if more than `capacity`, -2 if the cell is too small or too distorted for the minimum
    image. Every thread gets the answer."""
    t = cuda.threadIdx.x
    T = cuda.blockDim.x
    rc = 2.0 * rmax + skin
    area = abs(h00 * h11 - h01 * h10)
    l1 = math.sqrt(h00 * h00 + h10 * h10)
    l2 = math.sqrt(h01 * h01 + h11 * h11)
    w1 = area / l2
    w2 = area / l1
    if rc > 0.5 * min(w1, w2):
        return -2
    nb1 = int(w1 / rc)
    nb2 = int(w2 / rc)
    while nb1 * nb2 > 4 * n + 9 and max(nb1, nb2) > 3:
        if nb1 >= nb2:
            nb1 = max(3, nb1 // 2)
        else:
            nb2 = max(3, nb2 // 2)
    linked = nb1 >= 3 and nb2 >= 3
    count = 0
    if linked:
        for bb in range(t, nb1 * nb2, T):
            bins[BCOUNT, b0 + bb] = 0
        cuda.syncthreads()
        for ii in range(t, n, T):
            i = p0 + ii
            bn = (int(pf[SX, i] * nb1) % nb1) * nb2 + int(pf[SY, i] * nb2) % nb2
            pis[BIN_OF, i] = bn
            cuda.atomic.add(bins, (BCOUNT, b0 + bn), 1)
        cuda.syncthreads()
        if t == 0:
            total = 0
            for bb in range(nb1 * nb2):
                bins[BSTART, b0 + bb] = total
                total += bins[BCOUNT, b0 + bb]
                bins[BCOUNT, b0 + bb] = 0          # now the fill counter
        cuda.syncthreads()
        for ii in range(t, n, T):
            bn = pis[BIN_OF, p0 + ii]
            slot = cuda.atomic.add(bins, (BCOUNT, b0 + bn), 1)
            pis[BIN_ITEM, p0 + bins[BSTART, b0 + bn] + slot] = ii
        cuda.syncthreads()
    # each disc counts, then (once placed) writes and sorts its neighbours j > i
    for write in range(2):
        for ii in range(t, n, T):
            i = p0 + ii
            m = 0
            base = pis[NSTART, i]
            if linked:
                bn = pis[BIN_OF, i]
                b1 = bn // nb2
                b2 = bn % nb2
                for o1 in range(3):
                    c1 = (b1 + o1 + nb1 - 1) % nb1
                    for o2 in range(3):
                        cb = b0 + c1 * nb2 + (b2 + o2 + nb2 - 1) % nb2
                        start = bins[BSTART, cb]
                        for u in range(start, start + bins[BCOUNT, cb]):
                            jj = pis[BIN_ITEM, p0 + u]
                            if jj > ii and within(pf, i, p0 + jj, h00, h01, h10, h11, skin):
                                if write == 1:
                                    qn[NEW_I, base + m] = ii
                                    qn[NEW_J, base + m] = jj
                                m += 1
            else:
                for jj in range(ii + 1, n):
                    if within(pf, i, p0 + jj, h00, h01, h10, h11, skin):
                        if write == 1:
                            qn[NEW_I, base + m] = ii
                            qn[NEW_J, base + m] = jj
                        m += 1
            if write == 0:
                pis[NCOUNT, i] = m
            else:
                sort_slots(qn, NEW_J, base, base + m)
        cuda.syncthreads()
        if write == 0:
            if t == 0:
                total = 0
                for ii in range(n):
                    pis[NSTART, p0 + ii] = q0 + total
                    total += pis[NCOUNT, p0 + ii]
                shi[0] = total
            cuda.syncthreads()
            count = shi[0]
            cuda.syncthreads()
            if count > capacity:
                return -1
    return count


@cuda.jit(device=True)
def merge_history(n, q0, old_n, new_n, qf, qi, qb, qn, qt, qtb, shi):
    """neighbours.merge_history, then the new list and its history into the pair slots:
    returns the bonds lost (bonded pairs that left the list). Three barriers."""
    t = cuda.threadIdx.x
    T = cuda.blockDim.x
    old_end = q0 + old_n
    new_end = q0 + new_n
    if t == 0:
        shi[1] = 0
    for u in range(q0 + t, new_end, T):
        key = qn[NEW_I, u] * n + qn[NEW_J, u]
        a = lower_bound(qi, q0, old_end, n, key)
        if a < old_end and qi[PI, a] * n + qi[PJ, a] == key:
            qt[T_FS, u] = qf[FS, a]
            qt[T_MR, u] = qf[MR, a]
            qtb[BONDED, u] = qb[BONDED, a]
            qtb[TOUCHING, u] = qb[TOUCHING, a]
            qt[T_DPX, u] = qf[DPX, a]
            qt[T_DPY, u] = qf[DPY, a]
            qt[T_FN, u] = qf[FN, a]
        else:
            qt[T_FS, u] = 0.0
            qt[T_MR, u] = 0.0
            qtb[BONDED, u] = 0
            qtb[TOUCHING, u] = 0
            qt[T_DPX, u] = 0.0
            qt[T_DPY, u] = 0.0
            qt[T_FN, u] = 0.0
    cuda.syncthreads()
    for a in range(q0 + t, old_end, T):
        if qb[BONDED, a] == 1:
            key = qi[PI, a] * n + qi[PJ, a]
            u = lower_bound(qn, q0, new_end, n, key)
            if not (u < new_end and qn[NEW_I, u] * n + qn[NEW_J, u] == key):
                cuda.atomic.add(shi, 1, 1)
    cuda.syncthreads()
    lost = shi[1]
    for u in range(q0 + t, new_end, T):
        qi[PI, u] = qn[NEW_I, u]
        qi[PJ, u] = qn[NEW_J, u]
        qf[FS, u] = qt[T_FS, u]
        qf[MR, u] = qt[T_MR, u]
        qb[BONDED, u] = qtb[BONDED, u]
        qb[TOUCHING, u] = qtb[TOUCHING, u]
        qf[DPX, u] = qt[T_DPX, u]
        qf[DPY, u] = qt[T_DPY, u]
        qf[FN, u] = qt[T_FN, u]
    cuda.syncthreads()
    return lost
