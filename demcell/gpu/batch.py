"""``DeviceCellBatch``: the cells of one rank resident on a GPU, behind CellBatch's methods.

The states (current and committed) are created on the device once and stay there for the run:
commit and rollback are copies on the device, a solve launches one block per cell
(solve.solve_rows), the homogenised sums and the Kruyt operators are taken on the device.
What crosses to the host per Newton pass is small: the targets (F, phi, kappa), the result
rows of the solve, the per-cell matrices h, h_ref and the rotations (a host mirror, from
which F = h h_ref^-1 is taken with demcell's own arithmetic), the homogenised sums. A cell's
whole state comes to the host only when asked for (``state``, ``view``, ``committed_states``:
checkpoints, moves between ranks, the tangents that are not on the device: pstlo's sparse
solve, cto, the micropolar cell's operators).

The results are CellBatch's bits in Numba's CUDA simulator (tests/test_demcell_gpu.py) and
within round-off on a GPU, whose compiler fuses multiplies and adds. Pair slots that fill up
grow on the device (doubled, as CellBatch grows them) and the cell continues its solve.
"""
import numpy as np
from numba import cuda

from ..batch import CellStore, gradients_of, homogenized_outputs
from ..errors import InputError
from ..interface import DemCell
from . import cells as kernels
from . import simulator
from .block import MAX_THREADS
from .layout import bins_per_cell, from_columns, to_columns
from ..slots import H, HREF, KAP, NCF, NPF, NPI, NQF, NQN, NQS, NQT, PHI
from .solve import FULL, solve_rows
from .. import slots

#: threads per cell (one block); 128 was fastest for 228- and 400-disc cells on an H200
#: (../shared/spec/gpu-cells.md: 256 no faster, 64 half as fast)
DEFAULT_THREADS = 128
#: threads per block of the one-thread-per-cell kernels
PER_CELL_BLOCK = 128
STORE = ("pf", "qf", "qi", "qb", "cf", "ci")


def _host_store(states, p_off, q_off):
    """Host arrays of the device store for `states`, cell k at p_off[k], q_off[k] (pair slots
    past a state's capacity zero)."""
    n = len(states)
    store = {"pf": np.zeros((NPF, p_off[-1])), "qf": np.zeros((NQF, q_off[-1])),
             "qi": np.zeros((2, q_off[-1]), dtype=np.int64), "qb": np.zeros((2, q_off[-1]), dtype=np.uint8),
             "cf": np.zeros((n, NCF)), "ci": np.zeros((n, 2), dtype=np.int64)}
    for k, st in enumerate(states):
        pf, qf, qi, qb, cf, ci = to_columns(st)
        if qf.shape[1] > q_off[k + 1] - q_off[k]:
            raise InputError(f"cell {k}: {qf.shape[1]} pair slots for a capacity of {q_off[k + 1] - q_off[k]}")
        store["pf"][:, p_off[k]:p_off[k + 1]] = pf
        m = qf.shape[1]
        store["qf"][:, q_off[k]:q_off[k] + m] = qf
        store["qi"][:, q_off[k]:q_off[k] + m] = qi
        store["qb"][:, q_off[k]:q_off[k] + m] = qb
        store["cf"][k], store["ci"][k] = cf, ci
    return store


class DeviceCellBatch(CellStore):
    """The cells of one rank (DemCells: each keeps its law, options and time step) resident on
    the current CUDA device, with the methods of demcell.batch.CellBatch (see module doc).
    threads: threads per cell (one block per cell, at most 256)."""

    def __init__(self, cells, threads=DEFAULT_THREADS, rows=None):
        """cells: DemCells (their current and committed states are uploaded); or a
        DeviceCellBatch whose cells `rows` (rows may repeat) are copied on the device, current
        states only (current = committed), with their laws, options, time steps and targets
        (``subset``)."""
        if rows is not None:
            self._take_rows(cells, np.asarray(rows, dtype=np.int64))
            return
        cells = list(cells)
        if any(c.options.fixed for c in cells):
            raise InputError("fixed_steps (cells that do not relax) runs on CPU cells only, not on a GPU")
        if not (isinstance(threads, (int, np.integer)) and 1 <= threads <= MAX_THREADS):
            raise InputError(f"threads per cell must be an integer in [1, {MAX_THREADS}], got {threads!r}")
        self.threads = int(threads)
        simulator.patch()
        self._settings(cells)
        particles = np.array([c.state.n_particles for c in cells], dtype=np.int64)
        capacity = np.array([max(c.state.pair_i.shape[0], c.committed_state.pair_i.shape[0]) for c in cells],
                            dtype=np.int64)
        self.p_off = np.concatenate([[0], np.cumsum(particles)]).astype(np.int64)
        self.b_off = np.concatenate([[0], np.cumsum([bins_per_cell(m) for m in particles])]).astype(np.int64)
        self._layout(capacity)
        self._stores = {}
        self._mirror = {}
        for name, states in (("current", [c.state for c in cells]), ("committed", [c.committed_state for c in cells])):
            self._upload(name, _host_store(states, self.p_off, self.q_off))
        self._particle_scratch()
        self._pair_scratch()

    def _take_rows(self, source, rows):
        """This batch made of copies of the current states of `source`'s cells rows."""
        self.threads = source.threads
        self.n_cells = len(rows)
        self.templates = [source.templates[k] for k in rows]
        for name in ("micropolar", "law", "dt", "opts", "max_steps", "target", "cost"):
            setattr(self, name, getattr(source, name)[rows].copy())
        particles = np.diff(source.p_off)[rows]
        self.p_off = np.concatenate([[0], np.cumsum(particles)]).astype(np.int64)
        self.b_off = np.concatenate([[0], np.cumsum([bins_per_cell(m) for m in particles])]).astype(np.int64)
        self._layout(source.capacity[rows])
        P, Q = int(self.p_off[-1]), int(self.q_off[-1])
        self._stores, self._mirror = {}, {}
        d_src, d_dst = cuda.to_device(rows), cuda.to_device(np.arange(len(rows), dtype=np.int64))
        for name in ("current", "committed"):
            self._stores[name] = {"pf": cuda.device_array((NPF, P)), "qf": cuda.device_array((NQF, Q)),
                                  "qi": cuda.device_array((2, Q), dtype=np.int64),
                                  "qb": cuda.device_array((2, Q), dtype=np.uint8),
                                  "cf": cuda.device_array((len(rows), NCF)),
                                  "ci": cuda.device_array((len(rows), 2), dtype=np.int64)}
            if len(rows):
                kernels.copy_cells[len(rows), min(source.threads, 128)](d_src, d_dst, *source.store_args("current"),
                                                                        *self.store_args(name))
            self._refresh_mirror(name)
        self._particle_scratch()
        self._pair_scratch()

    # --- layout and device arrays ---------------------------------------------------------------
    def _layout(self, capacity):
        self.capacity = np.asarray(capacity, dtype=np.int64)
        self.q_off = np.concatenate([[0], np.cumsum(self.capacity)]).astype(np.int64)
        self._d_poff = cuda.to_device(self.p_off)
        self._d_qoff = cuda.to_device(self.q_off)
        self._d_boff = cuda.to_device(self.b_off)

    def _upload(self, name, host):
        self._stores[name] = {key: cuda.to_device(np.ascontiguousarray(host[key])) for key in STORE}
        self._mirror[name] = {"cf": host["cf"].copy(), "ci": host["ci"].copy()}

    def _particle_scratch(self):
        P = int(self.p_off[-1])
        self._pis = cuda.device_array((NPI, P), dtype=np.int64)
        self._weight = cuda.device_array(P, dtype=np.float64)
        self._bins = cuda.device_array((2, int(self.b_off[-1])), dtype=np.int64)

    def _pair_scratch(self):
        Q = int(self.q_off[-1])
        self._qs = cuda.device_array((NQS, Q), dtype=np.float64)
        self._qn = cuda.device_array((NQN, Q), dtype=np.int64)
        self._qt = cuda.device_array((NQT, Q), dtype=np.float64)
        self._qtb = cuda.device_array((2, Q), dtype=np.uint8)

    def store_args(self, name, offsets=None):
        """The device arrays of store `name` ('current', 'committed') as the kernels of
        gpu/cells.py take them: offsets (default this batch's), particle, pair and cell arrays."""
        st = self._stores[name]
        p_off, q_off = offsets if offsets is not None else (self._d_poff, self._d_qoff)
        return (p_off, q_off, st["pf"], st["qf"], st["qi"], st["qb"], st["cf"], st["ci"])

    def _copy(self, src_rows, dst_rows, src, dst, dst_offsets=None, dst_store=None):
        """kernels.copy_cells between two stores of this batch (or into dst_store)."""
        src_rows = np.asarray(src_rows, dtype=np.int64)
        if not len(src_rows):
            return
        d_src, d_dst = cuda.to_device(src_rows), cuda.to_device(np.asarray(dst_rows, dtype=np.int64))
        target = self.store_args(dst, dst_offsets) if dst_store is None else dst_store
        kernels.copy_cells[len(src_rows), min(self.threads, 128)](d_src, d_dst, *self.store_args(src), *target)

    def _grow(self, cells, capacity):
        """Pair slots of `cells` enlarged to `capacity` (arrays) in both stores, on the device."""
        new_cap = self.capacity.copy()
        new_cap[np.asarray(cells, dtype=np.int64)] = capacity
        old_q = self._d_qoff
        old = self._stores
        self._layout(new_cap)
        Q = int(self.q_off[-1])
        all_ = np.arange(self.n_cells)
        self._stores = {}
        for name, st in old.items():
            fresh = {"pf": st["pf"], "cf": st["cf"], "ci": st["ci"],
                     "qf": cuda.device_array((NQF, Q), dtype=np.float64),
                     "qi": cuda.device_array((2, Q), dtype=np.int64),
                     "qb": cuda.device_array((2, Q), dtype=np.uint8)}
            kernels.copy_cells[self.n_cells, 128](cuda.to_device(all_), cuda.to_device(all_), self._d_poff, old_q,
                                                  st["pf"], st["qf"], st["qi"], st["qb"], st["cf"], st["ci"],
                                                  self._d_poff, self._d_qoff, fresh["pf"], fresh["qf"], fresh["qi"],
                                                  fresh["qb"], fresh["cf"], fresh["ci"])
            self._stores[name] = fresh
        self._pair_scratch()

    def _refresh_mirror(self, name):
        st = self._stores[name]
        self._mirror[name] = {"cf": st["cf"].copy_to_host(), "ci": st["ci"].copy_to_host()}

    # --- the work -------------------------------------------------------------------------------
    def deformation_gradients(self, rows, committed=False):
        """F = h h_ref^-1 of the cells rows (n, 2, 2), demcell's arithmetic on the host mirror."""
        cf = self._mirror["committed" if committed else "current"]["cf"]
        rows = np.asarray(rows, dtype=np.int64)
        out = np.zeros((len(rows), 2, 2))
        gradients_of(rows, np.ascontiguousarray(cf[:, H:H + 4]).reshape(-1, 2, 2),
                     np.ascontiguousarray(cf[:, HREF:HREF + 4]).reshape(-1, 2, 2), out)
        return out

    def rotations(self, rows, committed=False):
        """(phi (n,) [rad], kappa (n, 2) [1/m]) of the cells rows."""
        cf = self._mirror["committed" if committed else "current"]["cf"][np.asarray(rows, dtype=np.int64)]
        return cf[:, PHI].copy(), cf[:, KAP:KAP + 2].copy()

    def lattices(self, rows, committed=False):
        """h_ref (n, 2, 2) [m] of the cells rows."""
        cf = self._mirror["committed" if committed else "current"]["cf"][np.asarray(rows, dtype=np.int64)]
        return cf[:, HREF:HREF + 4].reshape(-1, 2, 2).copy()

    def _per_cell(self, kernel, rows, *args):
        d_rows = cuda.to_device(np.asarray(rows, dtype=np.int64))
        blocks = (len(rows) + PER_CELL_BLOCK - 1) // PER_CELL_BLOCK
        kernel[blocks, PER_CELL_BLOCK](d_rows, *args)

    def contact_counts(self, rows):
        """Touching contacts of the cells rows (current state)."""
        rows = np.asarray(rows, dtype=np.int64)
        if not len(rows):
            return np.zeros(0, dtype=np.int64)
        st = self._stores["current"]
        out = cuda.device_array(len(rows), dtype=np.int64)
        self._per_cell(kernels.touching_counts, rows, self._d_qoff, st["qb"], st["ci"], out)
        return out.copy_to_host()

    def solve(self, rows, max_steps=None, method=None):
        """Solve the cells rows from their current states to their targets (CellBatch.solve):
        the result rows (len(rows), quasistatic.N_RESULT)."""
        rows = self.rows_of(rows)
        opts = self.solve_options(max_steps, method)
        if not len(rows):
            return np.zeros((0, slots.N_RESULT))
        n = len(rows)
        d_rows = cuda.to_device(rows)
        d_law, d_dt, d_opts, d_target = (cuda.to_device(np.ascontiguousarray(a)) for a in
                                         (self.law, self.dt, opts, self.target))
        work = cuda.to_device(np.zeros((n, slots.N_WORK)))
        iwork = cuda.to_device(np.zeros((n, slots.N_IWORK), dtype=np.int64))
        result = cuda.to_device(np.zeros((n, slots.N_RESULT)))
        code = cuda.to_device(np.zeros(n, dtype=np.int64))
        blocks = np.arange(n, dtype=np.int64)
        while True:
            st = self._stores["current"]
            with simulator.fast_barriers():
                solve_rows[len(blocks), self.threads](cuda.to_device(blocks), d_rows, self._d_poff, self._d_qoff,
                                                      self._d_boff, st["pf"], st["qf"], st["qi"], st["qb"], st["cf"],
                                                      st["ci"], d_law, d_dt, d_opts, d_target, work, iwork,
                                                      result, code, self._qs, self._qn, self._qt, self._qtb,
                                                      self._pis, self._bins, self._weight)
            full = np.flatnonzero(code.copy_to_host() == FULL)
            if not len(full):
                break
            # pair slots full: double them (as CellBatch) and continue those cells
            self._grow(rows[full], 2 * self.capacity[rows[full]])
            blocks = full.astype(np.int64)
        out = result.copy_to_host()
        self._refresh_mirror("current")
        self.cost[rows] = np.maximum(out[:, slots.R_STEPS], 1.0)
        return out

    def homogenize(self, rows):
        """CellBatch.homogenize of the cells rows, the sums taken on the device."""
        rows = np.asarray(rows, dtype=np.int64)
        n = len(rows)
        if not n:
            return homogenized_outputs(np.zeros((0, 2, 2)), np.zeros((0, 2)), np.zeros((0, 2, 2)),
                                       np.zeros((0, 2), dtype=np.int64), np.zeros(0))
        st = self._stores["current"]
        out = cuda.device_array((n, 10), dtype=np.float64)
        counts = cuda.device_array((n, 2), dtype=np.int64)
        self._per_cell(kernels.contact_sums, rows, cuda.to_device(self.micropolar[rows]), self._d_poff,
                       self._d_qoff, st["pf"], st["qf"], st["qi"], st["qb"], st["cf"], st["ci"],
                       cuda.to_device(self.law), out, counts)
        out = out.copy_to_host()
        return homogenized_outputs(out[:, 0:4].reshape(n, 2, 2), out[:, 4:6].copy(), out[:, 6:10].reshape(n, 2, 2),
                                   counts.copy_to_host(), np.diff(self.p_off)[rows])

    def kruyt(self, rows):
        """Kruyt operators (001 eq. 13) of the cells rows, (n, 4, 4) d sigma / d F, on the device."""
        rows = np.asarray(rows, dtype=np.int64)
        if not len(rows):
            return np.zeros((0, 4, 4))
        st = self._stores["current"]
        out = cuda.device_array((len(rows), 16), dtype=np.float64)
        self._per_cell(kernels.kruyt_sums, rows, self._d_poff, self._d_qoff, st["pf"], st["qi"], st["qb"], st["cf"],
                       st["ci"], cuda.to_device(self.law), out)
        return out.copy_to_host().reshape(len(rows), 4, 4)

    def subset(self, rows):
        """A new DeviceCellBatch of copies of the current states of rows (current = committed),
        with their laws, options, time steps and targets; rows may repeat."""
        return DeviceCellBatch(self, self.threads, rows)

    # --- state ------------------------------------------------------------------------------------
    def commit(self, rows):
        """The current states of rows become their committed states."""
        rows = np.asarray(rows, dtype=np.int64)
        self._copy(rows, rows, "current", "committed")
        for key in ("cf", "ci"):
            self._mirror["committed"][key][rows] = self._mirror["current"][key][rows]

    def rollback(self, rows):
        """Cells rows return to their committed states (targets: the committed F, phi, kappa)."""
        rows = np.asarray(rows, dtype=np.int64)
        self._copy(rows, rows, "committed", "current")
        for key in ("cf", "ci"):
            self._mirror["current"][key][rows] = self._mirror["committed"][key][rows]
        if len(rows):
            self.set_targets(rows, self.deformation_gradients(rows))

    def _download(self, name, rows):
        """CellStates (copies) of the cells rows of a store: one gather on the device, one copy
        per array to the host."""
        rows = np.asarray(rows, dtype=np.int64)
        if not len(rows):
            return []
        particles = np.diff(self.p_off)[rows]
        p_off = np.concatenate([[0], np.cumsum(particles)]).astype(np.int64)
        q_off = np.concatenate([[0], np.cumsum(self.capacity[rows])]).astype(np.int64)
        P, Q, n = int(p_off[-1]), int(q_off[-1]), len(rows)
        packed = (cuda.to_device(p_off), cuda.to_device(q_off), cuda.device_array((NPF, P)),
                  cuda.device_array((NQF, Q)), cuda.device_array((2, Q), dtype=np.int64),
                  cuda.device_array((2, Q), dtype=np.uint8), cuda.device_array((n, NCF)),
                  cuda.device_array((n, 2), dtype=np.int64))
        self._copy(rows, np.arange(n), name, None, dst_store=packed)
        pf, qf, qi, qb, cf, ci = (a.copy_to_host() for a in packed[2:])
        return [from_columns(pf[:, p_off[r]:p_off[r + 1]], qf[:, q_off[r]:q_off[r + 1]], qi[:, q_off[r]:q_off[r + 1]],
                             qb[:, q_off[r]:q_off[r + 1]], cf[r], ci[r]) for r in range(n)]

    def committed_states(self, rows):
        """Copies of the committed CellStates of rows (what a checkpoint saves)."""
        return self._download("committed", rows)

    def state(self, k):
        """A copy of the current CellState of cell k."""
        return self._download("current", [k])[0]

    def views(self, rows):
        """view(k) of every k in rows, downloaded together."""
        current, committed = self._download("current", rows), self._download("committed", rows)
        return [DemCell.view(self.templates[int(k)], a, b, self._target_of(k))
                for k, a, b in zip(rows, current, committed)]

    def restore(self, k, state):
        """Cell k continues from `state` (a CellState): committed and current."""
        k = int(k)
        if state.n_particles != self.p_off[k + 1] - self.p_off[k]:
            raise InputError(f"cell {k}: a state of {state.n_particles} particles for "
                             f"{self.p_off[k + 1] - self.p_off[k]}")
        if state.pair_i.shape[0] > self.capacity[k]:
            self._grow([k], [state.pair_i.shape[0]])
        one_p = np.array([0, state.n_particles], dtype=np.int64)
        one_q = np.array([0, self.capacity[k]], dtype=np.int64)
        host = _host_store([state], one_p, one_q)
        src = (cuda.to_device(one_p), cuda.to_device(one_q)) + tuple(cuda.to_device(host[key]) for key in STORE)
        for name in ("committed", "current"):
            kernels.copy_cells[1, 128](cuda.to_device(np.zeros(1, dtype=np.int64)),
                                       cuda.to_device(np.array([k], dtype=np.int64)), *src, *self.store_args(name))
            self._mirror[name]["cf"][k], self._mirror[name]["ci"][k] = host["cf"][0], host["ci"][0]
        self.rollback([k])

    def nbytes(self):
        """Bytes of the device arrays (both stores and the scratch of the kernels)."""
        arrays = [a for st in self._stores.values() for a in st.values()]
        arrays += [self._pis, self._weight, self._bins, self._qs, self._qn, self._qt, self._qtb]
        return int(sum(a.nbytes for a in arrays))

    def bytes_per_cell(self):
        """Device bytes per cell of this batch (nbytes / cells)."""
        return self.nbytes() / max(1, self.n_cells)


def device_summary():
    """The current CUDA device in words: its name and memory, or the simulator."""
    from numba import config
    if config.ENABLE_CUDASIM:
        return "Numba's CUDA simulator"
    name = cuda.get_current_device().name
    free, total = cuda.current_context().get_memory_info()
    return f"{name.decode() if isinstance(name, bytes) else name}, {total / 2**30:.0f} GiB"
