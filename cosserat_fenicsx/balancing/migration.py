"""Moving points between worker ranks: the resident state of the points whose worker
changes goes with the inner material's export_points / import_points (comm.alltoall of the
struct-of-arrays dicts) and every rank rebuilds its inner material with its new slots, the
kept ones exported and imported too (a restored cell continues bit for bit)."""
from typing import NamedTuple

import numpy as np


class Slots(NamedTuple):
    """The points a rank works on, one slot each, in ascending global point order."""
    global_index: np.ndarray     # global point index of each slot
    zone: np.ndarray             # zone of each slot (None: the material has no zones given)
    xy: np.ndarray               # (x, y) [m] of each slot (None: not given)

    def block(self, rows, arrays):
        """The slots `rows` with their exported resident state, as sent to another rank."""
        return {"global": self.global_index[rows], "arrays": arrays,
                "zone": None if self.zone is None else self.zone[rows],
                "xy": None if self.xy is None else self.xy[rows]}


def migrate(comm, old, make_material, slots, dest):
    """Move the resident state of the slots of `old` (this rank's inner material) to their
    new workers `dest` (rank per slot) and build this rank's new inner material
    (`make_material()`) with the slots it now works on. Returns (new inner material, its
    Slots). Collective; called between load steps (the exported states are the committed =
    current ones) or before a pass that re-solves every point from its committed state."""
    outgoing = []
    for rank in range(comm.size):
        rows = np.flatnonzero(dest == rank) if rank != comm.rank else np.zeros(0, dtype=np.int64)
        outgoing.append(None if not rows.size else slots.block(rows, old.export_points(rows)))
    incoming = comm.alltoall(outgoing)
    kept = np.flatnonzero(dest == comm.rank)
    blocks = [slots.block(kept, old.export_points(kept) if kept.size else {})]
    blocks += [b for b in incoming if b is not None]
    g = np.concatenate([b["global"] for b in blocks])
    order = np.argsort(g, kind="stable")                  # slots in global point order
    position = np.empty_like(order)
    position[order] = np.arange(len(order))
    new = Slots(g[order],
                None if slots.zone is None else np.concatenate([b["zone"] for b in blocks])[order],
                None if slots.xy is None else np.concatenate([b["xy"] for b in blocks])[order])
    inner = make_material()
    if new.zone is not None:
        inner.set_zones(new.zone)
    if new.xy is not None:
        inner.set_point_coordinates(new.xy)
    inner.initial_state(len(new.global_index))
    offset = 0
    for b in blocks:
        n = len(b["global"])
        if n:
            inner.import_points(position[offset:offset + n], b["arrays"])
        offset += n
    return inner, new
