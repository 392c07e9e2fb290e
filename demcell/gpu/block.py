"""What the threads of one block do together: sums in lanes.py's order, maxima, searches.

One block solves one cell; its threads take the discs (or the pairs) of the cell in turn,
thread t the items t, t + T, t + 2 T, ... (T = blockDim.x). Every reduction whose result
steers the motion is taken in an order fixed independently of T, so that the bits do not
depend on the launch: sums in lanes.py's lanes and tree, maxima (exact in any order),
integer prefix sums (exact) one after the other by thread 0.
"""
from numba import cuda

from ..lanes import LANES

#: the largest block (the shared scratch of a reduction holds one value per thread)
MAX_THREADS = 256


@cuda.jit(device=True)
def combine_row(part, row):
    """lanes.combine on part[row, :] (one thread; shared memory)."""
    off = LANES // 2
    while off > 0:
        for lane in range(off):
            part[row, lane] = part[row, lane] + part[row, lane + off]
        off //= 2
    return part[row, 0]


@cuda.jit(device=True)
def block_max(value, scratch):
    """The largest `value` over the threads of the block, returned to every thread (exact:
    the maximum does not depend on the order). Contains two barriers."""
    t = cuda.threadIdx.x
    scratch[t] = value
    cuda.syncthreads()
    best = scratch[0]
    for u in range(1, cuda.blockDim.x):
        best = max(best, scratch[u])
    cuda.syncthreads()
    return best


@cuda.jit(device=True)
def lower_bound(qi, lo, hi, n, key):
    """First pair slot in [lo, hi) whose key i n + j (qi rows 0, 1) is >= key, for slots
    sorted by that key."""
    while lo < hi:
        mid = (lo + hi) // 2
        if qi[0, mid] * n + qi[1, mid] < key:
            lo = mid + 1
        else:
            hi = mid
    return lo


@cuda.jit(device=True)
def first_slot_of(qi, lo, hi, value):
    """First pair slot in [lo, hi) whose first disc (qi row 0, sorted) is >= value."""
    while lo < hi:
        mid = (lo + hi) // 2
        if qi[0, mid] < value:
            lo = mid + 1
        else:
            hi = mid
    return lo

