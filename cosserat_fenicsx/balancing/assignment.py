"""Which rank works on which Gauss point: the imbalance of per-rank loads and the greedy
assignment that evens them (deterministic: every rank computes the same answer from the
same gathered costs)."""
import numpy as np

#: rebalance when the slowest rank's cell work exceeds the mean by more than 10 %
DEFAULT_THRESHOLD = 1.10


def imbalance(loads):
    """Slowest / mean of per-rank loads (1 when there is no load)."""
    loads = np.asarray(loads, dtype=float)
    mean = loads.mean() if loads.size else 0.0
    return float(loads.max() / mean) if mean > 0 else 1.0


def assign(cost, worker, n_ranks, threshold=DEFAULT_THRESHOLD):
    """New workers of points of cost `cost` now worked on by `worker`: greedy moves from the
    most to the least loaded rank, each the point whose move best evens the pair (cost
    nearest half their gap, strictly below the gap so that the pair's maximum drops),
    until the predicted slowest / mean <= threshold or no move helps. Every move lowers
    the sum of squared loads, so it ends. Deterministic (ties: lowest index), so every rank
    computes the same answer from the same gathered costs. Returns a new array."""
    cost = np.asarray(cost, dtype=float)
    worker = np.array(worker, dtype=np.int64)
    loads = np.bincount(worker, weights=cost, minlength=n_ranks).astype(float)
    for _ in range(len(cost)):
        if imbalance(loads) <= threshold:
            break
        hi, lo = int(np.argmax(loads)), int(np.argmin(loads))
        gap = loads[hi] - loads[lo]
        movable = np.flatnonzero((worker == hi) & (cost > 0) & (cost < gap))
        if not movable.size:
            break
        k = movable[np.argmin(np.abs(gap - 2.0 * cost[movable]))]
        worker[k] = lo
        loads[hi] -= cost[k]
        loads[lo] += cost[k]
    return worker
