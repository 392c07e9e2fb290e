"""FEM x DEM with the cells of a rank in one struct of arrays (demcell.batch.CellBatch), or
resident on a GPU (demcell.gpu.DeviceCellBatch, the same methods: device='gpu').

The same material as `material.DemMaterial` (same statuses, messages, history and the same
bits: tests/test_femdem_batched.py), but an update is one call for all the points asked:
targets from the gradients (vectorised), one Numba solve over the cells in a prange (the
threads of the rank: NUMBA_NUM_THREADS or `--cell-threads`), one batched homogenisation,
fluxes and history (vectorised). Kruyt tangents of the classical and hybrid modes are batched
too, and DEMQO (all perturbed copies of all cells in one solve call, CellBatch.demqo); pstlo
(a scipy sparse solve), cto (perturbations from the committed state) and the micropolar
Kruyt operator are computed per point on a view of the cell in the store, pstlo on the rank's
threads (its sparse LU releases the GIL).
"""
import time

import numpy as np

from ...constitutive import PointReport
from .cells import GIL_FREE_TANGENTS
from .material import STATUS_BAD_F, STATUS_BROKEN, STATUS_NO_CONTACTS, STATUS_NOT_RELAXED, DemMaterial


class BatchedDemMaterial(DemMaterial):
    """DemMaterial with a store of cells behind it (see module doc): device 'cpu' (a CellBatch
    on the rank's Numba threads) or 'gpu' (a DeviceCellBatch on the rank's CUDA device)."""

    DEVICES = ("cpu", "gpu")

    def __init__(self, reference_cells, mode, tangent="pstlo", max_strain_increment=0.05, device="cpu"):
        if device not in self.DEVICES:
            raise ValueError(f"unknown cell device {device!r}: one of {', '.join(self.DEVICES)}")
        self.batch = None
        super().__init__(reference_cells, mode, tangent, max_strain_increment)
        self.device = device
        self._pool, self._pool_threads = None, 0

    def initial_state(self, n_points):
        state = super().initial_state(n_points)      # the cells, as copies of the zones' reference cells
        if not n_points:
            self.batch = None
        elif self.device == "gpu":
            from demcell.gpu import DeviceCellBatch
            self.batch = DeviceCellBatch(self.cells)
        else:
            from demcell.batch import CellBatch
            self.batch = CellBatch(self.cells)
        self._cells_list = None
        return state

    @property
    def cells(self):
        """Views of the cells in the store (read them; the batch solves)."""
        if self.batch is None:
            return self._cells_list or []
        return [self.batch.view(k) for k in range(self.batch.n_cells)]

    @cells.setter
    def cells(self, value):
        self._cells_list = value

    # --- the callback --------------------------------------------------------------------
    def update(self, gradients, dt, state_old, flux_out, tangent_out, state_new, points=None):
        import demcell.quasistatic as qs
        n_cells = self.batch.n_cells if self.batch is not None else 0
        points = np.arange(n_cells) if points is None else np.asarray(points, dtype=np.int64)
        status = np.zeros(len(points), dtype=np.int32)
        cost = np.zeros(len(points))
        if not len(points):
            return PointReport(status=status, cost=cost, message="", cost_unit=self.cost_unit)
        start = time.perf_counter()
        batch = self.batch
        self._touched.update(int(p) for p in points)
        batch.rollback(points)
        G = np.asarray(gradients)[points]
        F, phi, kappa = self.mode.targets(G)
        texts = {}
        # --- refused before the cell is touched (DemMaterial._solve): a jump too far from the
        # committed state, a non-finite or inverted F, a curvature tearing the cell
        Fc = batch.deformation_gradients(points, committed=True)
        jump = np.abs(F - Fc).max(axis=(1, 2))
        h_ref = batch.lattices(points, committed=True)
        if kappa is not None:
            phi_c, kappa_c = batch.rotations(points, committed=True)
            turn = np.abs(np.einsum("pa,pab->pb", kappa - kappa_c, h_ref)).max(axis=1)
            jump = np.maximum(jump, np.maximum(np.abs(phi - phi_c), turn))
        too_far = ~(jump <= self.max_strain_increment)
        for k in np.flatnonzero(too_far):
            status[k] = STATUS_BAD_F
            texts[k] = (f"strain increment {jump[k]:.6g} from the committed state exceeds max_strain_increment = "
                        f"{self.max_strain_increment:g} (load step too large, or the Newton iteration is diverging)")
        det = F[:, 0, 0] * F[:, 1, 1] - F[:, 0, 1] * F[:, 1, 0]
        bad = ~too_far & ~(np.isfinite(F).all(axis=(1, 2)) & (det > 0.0))
        if kappa is not None:
            tear = np.abs(np.einsum("pa,pab->pb", kappa, h_ref)).max(axis=1)
            bad |= ~too_far & ~(tear <= 1.0)
        for k in np.flatnonzero(bad):
            status[k] = STATUS_BAD_F
            texts[k] = ("inadmissible deformation (det F <= 0, non-finite F, or a curvature turning the periodic "
                        "images by more than 1 rad across the cell): the load step is too large")
        ok = np.flatnonzero(~too_far & ~bad)
        rows = points[ok]
        batch.set_targets(rows, F[ok], None if phi is None else phi[ok], None if kappa is None else kappa[ok])
        result = batch.solve(rows)
        self.timers["solve"] += time.perf_counter() - start
        start = time.perf_counter()
        steps = result[:, qs.R_STEPS].astype(int)
        cost[ok] = steps
        hom = batch.homogenize(rows)
        # only cells that did not simply converge need words (a Python call each)
        unclean = ~((result[:, qs.R_CONVERGED] > 0.5) & (result[:, qs.R_NOCONTACT] < 0.5))
        for j in np.flatnonzero(unclean):
            k = ok[j]
            converged, no_contacts, message, error = batch.outcome(int(rows[j]), result[j])
            if error is not None:
                status[k], texts[k] = STATUS_BROKEN, f"micro solve failed: {error}"
            elif no_contacts and hom["n_contacts"][j] == 0:
                status[k], texts[k] = STATUS_NO_CONTACTS, "the cell lost every contact (zero stress)"
            elif not converged:
                status[k] = STATUS_NOT_RELAXED
                texts[k] = ("the cell did not relax within its step budget "
                            f"(max_steps = {int(batch.max_steps[rows[j]])}): {message}")
        good = status[ok] >= 0
        sel, out_rows = ok[good], rows[good]
        fluxes = np.zeros((len(sel), 6))
        self.mode.fluxes_many(hom["cauchy"][good], hom["couple_stress"][good], G[sel], fluxes)
        flux_out[out_rows] = fluxes
        state_new[out_rows] = np.column_stack([hom["coordination_number"][good], hom["anisotropy"][good],
                                               hom["sliding_fraction"][good], hom["stress_ratio"][good],
                                               hom["n_contacts"][good], steps[good], status[sel]])
        self.timers["homogenize"] += time.perf_counter() - start
        failed = np.flatnonzero(status < 0)
        flagged = np.flatnonzero(status > 0)
        first = failed[0] if len(failed) else (flagged[0] if len(flagged) else None)
        message = "" if first is None else f"{self.where(points[first])}: {texts[first]}"
        return PointReport(status=status, cost=cost, message=message, cost_unit=self.cost_unit)

    def tangent(self, points, tangent_out):
        points = np.asarray(points, dtype=np.int64)
        cost = np.zeros(len(points))
        start = time.perf_counter()
        batch = self.batch
        counts = batch.contact_counts(points)
        live = points[counts > 0]
        if self._kind == "kruyt" and self.mode.name != "micropolar":
            for p, C in zip(live, batch.kruyt(live)):
                self.mode.place(C, tangent_out[p])
        elif self._kind == "demqo":
            tangents, steps = batch.demqo(live)
            for p, C in zip(live, tangents):
                self.mode.place(C, tangent_out[p])
            cost[counts > 0] = steps
        else:
            live_rows = np.flatnonzero(counts > 0)
            cells = dict(zip(live_rows, batch.views(points[live_rows])))    # one download from a GPU

            def one(k):
                cell = cells[k]
                self.mode.tangent(cell, None, self._kind, tangent_out[int(points[k])])
                cost[k] = cell.last_tangent_steps
            pool = self._tangent_pool()
            if pool is None:
                for k in live_rows:
                    one(k)
            else:
                list(pool.map(one, live_rows))
        for p in points[counts == 0]:
            tangent_out[p] = self._floor_tangent(int(self.zone[p]))
        self.timers["tangent"] += time.perf_counter() - start
        return PointReport(status=np.zeros(len(points), dtype=np.int32), cost=cost, cost_unit=self.cost_unit)

    def _tangent_pool(self):
        """Threads for the per-point pstlo tangents, as many as the rank's Numba threads
        (--cell-threads): scipy's sparse LU factorisation, most of a pstlo tangent, releases
        the GIL. None with one thread, or for a kind that would hold the GIL (cto and the
        micropolar Kruyt operator are Python and Numba code without nogil)."""
        import numba
        threads = numba.get_num_threads()
        if threads < 2 or self.tangent_name not in GIL_FREE_TANGENTS:
            return None
        if self._pool is None or self._pool_threads != threads:
            from concurrent.futures import ThreadPoolExecutor
            self._pool, self._pool_threads = ThreadPoolExecutor(threads), threads
        return self._pool

    def commit(self):
        start = time.perf_counter()
        if self._touched:
            self.batch.commit(np.array(sorted(self._touched), dtype=np.int64))
        self._touched.clear()
        self.timers["commit"] += time.perf_counter() - start

    def rollback(self):
        if self._touched:
            self.batch.rollback(np.array(sorted(self._touched), dtype=np.int64))
        self._touched.clear()

    def describe(self):
        return dict(super().describe(), cell_device=self.device)

    # --- resident state ------------------------------------------------------------------
    def export_points(self, points):
        from demcell.state import pack_states
        points = np.asarray(points, dtype=np.int64)
        return dict(pack_states(self.batch.committed_states(points)), zone=self.zone[points].copy())

    def import_points(self, points, arrays, rows=None):
        for p, z, st in self._imported(points, arrays, rows):
            self.batch.set_cell(int(p), self.reference_cells[z], st)

    def memory_bytes(self):
        return self.batch.nbytes() if self.batch is not None else 0
