"""Where a DemMaterial's cells live: one protocol, two stores.

`PointCells` is what DemMaterial asks of the cells of a rank's Gauss points (cell p is the
cell of point p; demcell.batch.CellStore is the other level, the protocol of the batches
that `BatchedCells` holds): solve a set of points at their gradients (fluxes, history
rows, statuses, DEM steps), their tangents, commit / rollback, their committed states and a
cell replaced by an imported state. Two stores implement it with the same statuses, messages and bits
(tests/test_femdem_batched.py):

* `CellList`: one demcell.DemCell per point, solved one after the other;
* `BatchedCells`: the cells in one struct of arrays (demcell.batch.CellBatch, device 'cpu':
  one Numba solve over the cells in a prange on the rank's threads, NUMBA_NUM_THREADS or
  `--cell-threads`) or resident on a GPU (demcell.gpu.DeviceCellBatch, device 'gpu'):
  targets from the gradients, solve, homogenisation, fluxes and history vectorised. The
  tangents that demcell batches (demcell.tangent.TANGENT_KINDS: kruyt of Cauchy cells,
  demqo) are one call; the others are computed per point on a view of the cell in the
  store, on the rank's threads where the kind releases the GIL (pstlo's sparse LU).

Statuses (DemMaterial's history and PointReport): 0 ok; 1 (flagged, the run goes on): the
cell lost every contact, its stress is zero; < 0 (failed, the step is cut): -1 the cell did
not relax within its step budget, -2 inadmissible F (det F <= 0, or a target further than
`max_strain_increment` from the committed state), -3 the micro solve broke down.
"""
import abc
from dataclasses import replace
import time

import numpy as np

STATUS_NO_CONTACTS = 1
STATUS_NOT_RELAXED, STATUS_BAD_F, STATUS_BROKEN = -1, -2, -3

TOO_FAR = ("strain increment {jump:.6g} from the committed state exceeds max_strain_increment = {limit:g} "
           "(load step too large, or the Newton iteration is diverging)")
NO_CONTACTS = "the cell lost every contact (zero stress)"


def cell_outputs(h, steps, status):
    """History row of a cell (DemMaterial.state_names) from its homogenized outputs `h`."""
    return (h.coordination_number, h.anisotropy, h.sliding_fraction, h.stress_ratio,
            h.n_contacts, steps, status)


class PointCells(abc.ABC):
    """The cells of a rank's Gauss points (module docstring). `points` are int64 arrays of
    point indices; `status`, `cost` (n_points given,) and `texts` ({position in points:
    words}) are filled in place by solve and tangent."""

    def __init__(self, mode, max_strain_increment):
        self.mode = mode
        self.max_strain_increment = max_strain_increment
        # FIRE cell solves that did not settle and were done again with local damping (see
        # BatchedCells._relax_unjammed)
        self.solves_redone = 0
        # cell solves that RelaxationOptions.relax_cap stopped before they settled
        self.solves_capped = 0

    @property
    @abc.abstractmethod
    def cells(self):
        """The cells as DemCells to read (views of the store's; solve through the store)."""

    @abc.abstractmethod
    def solve(self, points, gradients, flux_out, state_new, status, cost, texts, timers):
        """Each cell of `points` from its committed state to the target of its gradients'
        row; for a point whose status is >= 0, its fluxes and history row written.
        timers["solve"], timers["homogenize"] [s] accumulate."""

    @abc.abstractmethod
    def tangent(self, points, kind, tangent_out, cost, floor):
        """tangent_out[p] = the `kind` (demcell.tangent.TangentKind) operator of the cell of
        each point p (6x6, mode.tangent), floor(p) for a cell without contacts."""

    @abc.abstractmethod
    def commit(self, points):
        """The cells of `points` keep their current state as the committed one."""

    @abc.abstractmethod
    def rollback(self, points):
        """The cells of `points` return to their committed state."""

    @abc.abstractmethod
    def committed_states(self, points):
        """The committed demcell.CellState of each point's cell, in order."""

    @abc.abstractmethod
    def set_cell(self, p, template, state):
        """Point p's cell becomes a cell of `template` (a DemCell: law, options) in `state`,
        committed and current."""

    @abc.abstractmethod
    def nbytes(self):
        """Bytes held by the cells (current and committed states)."""

    def describe(self):
        """What the run's summary records about the store."""
        return {}


class CellList(PointCells):
    """One DemCell per point, solved one by one."""

    def __init__(self, cells, mode, max_strain_increment):
        super().__init__(mode, max_strain_increment)
        self._cells = list(cells)

    @property
    def cells(self):
        return self._cells

    def solve(self, points, gradients, flux_out, state_new, status, cost, texts, timers):
        for k, p in enumerate(points):
            cell = self._cells[p]
            start = time.perf_counter()
            code, text, steps = self._solve(cell, gradients[p])
            timers["solve"] += time.perf_counter() - start
            cost[k] = steps
            status[k] = code
            if code:
                texts[k] = text
            if code < 0:
                continue
            start = time.perf_counter()
            h = cell.homogenized()
            self.mode.fluxes(h, gradients[p], flux_out[p])
            state_new[p] = cell_outputs(h, steps, code)
            timers["homogenize"] += time.perf_counter() - start

    def _solve(self, cell, gradients):
        """(status, message, DEM steps) of one solve from the committed state."""
        import demcell as dc
        cell.rollback()
        # |dF| and, in micropolar mode, the change of the rotation jump across the cell
        jump = self.mode.increment(cell, gradients)
        if not jump <= self.max_strain_increment:
            # a cell asked to jump this far is either a load step far too large or a Newton
            # iterate running away: refuse it (the step is cut) instead of tearing the cell
            return STATUS_BAD_F, TOO_FAR.format(jump=jump, limit=self.max_strain_increment), 0
        try:
            self.mode.drive(cell, gradients)
        except dc.InputError as error:
            return STATUS_BAD_F, f"inadmissible deformation ({error}): the load step is too large", 0
        try:
            result = cell.solve()
            if not result.converged and cell.options.method == "fire":
                result = self._relax_unjammed(cell, gradients, result)
            self.solves_capped += result.capped > 0
        except dc.SolveError as error:
            return STATUS_BROKEN, f"micro solve failed: {error}", 0
        if result.no_contacts:
            return STATUS_NO_CONTACTS, NO_CONTACTS, result.steps
        if not result.converged:
            return (STATUS_NOT_RELAXED, "the cell did not relax within its step budget "
                    f"(max_steps = {cell.options.max_steps}; strain increment {jump:.3g} from the committed "
                    f"state): {result.message}", result.steps)
        return 0, "", result.steps

    def _relax_unjammed(self, cell, gradients, first):
        """The FIRE solve that did not settle, again from the committed state with local
        damping (BatchedCells._relax_unjammed says why); its steps include the first's."""
        fire = cell.options
        cell.options = replace(fire, method="local")
        try:
            cell.rollback()
            self.mode.drive(cell, gradients)
            result = cell.solve()
        finally:
            cell.options = fire
        self.solves_redone += 1
        return replace(result, steps=result.steps + first.steps)

    def tangent(self, points, kind, tangent_out, cost, floor):
        for k, p in enumerate(points):
            cell = self._cells[p]
            if cell.contact_count():
                self.mode.tangent(cell, None, kind.name, tangent_out[p])
            else:
                tangent_out[p] = floor(p)
            cost[k] = cell.last_tangent_steps

    def commit(self, points):
        for p in points:
            self._cells[p].commit()

    def rollback(self, points):
        for p in points:
            self._cells[p].rollback()

    def committed_states(self, points):
        return [self._cells[p].committed_state for p in points]

    def set_cell(self, p, template, state):
        cell = template.copy()
        cell.restore(state)
        self._cells[p] = cell

    def nbytes(self):
        return sum(c.memory_bytes() for c in self._cells)


class BatchedCells(PointCells):
    """The cells in a demcell cell store: device 'cpu' (a CellBatch on the rank's Numba
    threads) or 'gpu' (a DeviceCellBatch on the rank's CUDA device)."""

    DEVICES = ("cpu", "gpu")

    def __init__(self, cells, mode, max_strain_increment, device="cpu"):
        if device not in self.DEVICES:
            raise ValueError(f"unknown cell device {device!r}: one of {', '.join(self.DEVICES)}")
        super().__init__(mode, max_strain_increment)
        self.device = device
        self._pool, self._pool_threads = None, 0
        if not cells:
            self.batch = None
        elif device == "gpu":
            from demcell.gpu import DeviceCellBatch
            self.batch = DeviceCellBatch(cells)
        else:
            from demcell.batch import CellBatch
            self.batch = CellBatch(cells)

    @property
    def cells(self):
        if self.batch is None:
            return []
        return [self.batch.view(k) for k in range(self.batch.n_cells)]

    def solve(self, points, gradients, flux_out, state_new, status, cost, texts, timers):
        from demcell import slots
        start = time.perf_counter()
        batch = self.batch
        batch.rollback(points)
        G = np.asarray(gradients)[points]
        F, phi, kappa = self.mode.targets(G)
        # --- refused before the cell is touched (CellList._solve): a jump too far from the
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
            texts[k] = TOO_FAR.format(jump=jump[k], limit=self.max_strain_increment)
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
        targets = (F[ok], None if phi is None else phi[ok], None if kappa is None else kappa[ok])
        batch.set_targets(rows, *targets)
        result = batch.solve(rows)
        self._relax_unjammed(rows, result, *targets)
        self.solves_capped += int(np.count_nonzero(result[:, slots.R_CAPPED] > 0.5))
        timers["solve"] += time.perf_counter() - start
        start = time.perf_counter()
        steps = result[:, slots.R_STEPS].astype(int)
        cost[ok] = steps
        hom = batch.homogenize(rows)
        # only cells that did not simply converge need words (a Python call each)
        unclean = ~((result[:, slots.R_CONVERGED] > 0.5) & (result[:, slots.R_NOCONTACT] < 0.5))
        for j in np.flatnonzero(unclean):
            k = ok[j]
            converged, no_contacts, message, error = batch.outcome(int(rows[j]), result[j])
            if error is not None:
                status[k], texts[k] = STATUS_BROKEN, f"micro solve failed: {error}"
            elif no_contacts and hom["n_contacts"][j] == 0:
                status[k], texts[k] = STATUS_NO_CONTACTS, NO_CONTACTS
            elif not converged:
                status[k] = STATUS_NOT_RELAXED
                texts[k] = ("the cell did not relax within its step budget "
                            f"(max_steps = {int(batch.max_steps[rows[j]])}; strain increment {jump[k]:.3g} "
                            f"from the committed state): {message}")
        good = status[ok] >= 0
        sel, out_rows = ok[good], rows[good]
        fluxes = np.zeros((len(sel), 6))
        self.mode.fluxes_many(hom["cauchy"][good], hom["couple_stress"][good], G[sel], fluxes)
        flux_out[out_rows] = fluxes
        state_new[out_rows] = np.column_stack([hom["coordination_number"][good], hom["anisotropy"][good],
                                               hom["sliding_fraction"][good], hom["stress_ratio"][good],
                                               hom["n_contacts"][good], steps[good], status[sel]])
        timers["homogenize"] += time.perf_counter() - start

    def _relax_unjammed(self, rows, result, F, phi, kappa):
        """FIRE cells that did not settle are solved again from the committed state with local
        damping; their result rows are replaced, their DEM steps added. Two ways FIRE fails
        to settle a cell that local damping settles, both seen past the peak: a cell strained
        just past its jamming point, whose grains fly apart and keep colliding (FIRE damps
        only against the forces; local damping takes energy out at every collision until no
        contact is left: zero stress), and a cell whose FIRE iteration cycles at an
        unbalanced-force ratio of order 1 with little kinetic energy (docs/reference/femdem.md,
        "Past the peak: cells that FIRE does not settle")."""
        from demcell import slots
        unsettled = ((result[:, slots.R_CONVERGED] < 0.5) & (self.batch.opts[rows, slots.Q_METHOD] == slots.FIRE))
        if not unsettled.any():
            return
        sel = np.flatnonzero(unsettled)
        again = rows[sel]
        self.batch.rollback(again)
        self.batch.set_targets(again, F[sel], None if phi is None else phi[sel], None if kappa is None else kappa[sel])
        retry = self.batch.solve(again, method="local")
        retry[:, slots.R_STEPS] += result[sel, slots.R_STEPS]
        result[sel] = retry
        self.solves_redone += len(sel)

    def tangent(self, points, kind, tangent_out, cost, floor):
        batch = self.batch
        counts = batch.contact_counts(points)
        live = points[counts > 0]
        micropolar = self.mode.name == "micropolar"
        if kind.batched and (kind.batched_micropolar or not micropolar) and kind.name in ("kruyt", "demqo"):
            if kind.name == "kruyt":
                tangents, steps = batch.kruyt(live), None
            else:
                tangents, steps = batch.demqo(live)
            for p, C in zip(live, tangents):
                self.mode.place(C, tangent_out[p])
            if steps is not None:
                cost[counts > 0] = steps
        else:
            live_rows = np.flatnonzero(counts > 0)
            cells = dict(zip(live_rows, batch.views(points[live_rows])))    # one download from a GPU

            def one(k):
                cell = cells[k]
                self.mode.tangent(cell, None, kind.name, tangent_out[int(points[k])])
                cost[k] = cell.last_tangent_steps
            pool = self._tangent_pool(kind)
            if pool is None:
                for k in live_rows:
                    one(k)
            else:
                list(pool.map(one, live_rows))
        for p in points[counts == 0]:
            tangent_out[p] = floor(p)

    def _tangent_pool(self, kind):
        """Threads for the per-point tangents of a kind that releases the GIL (pstlo: scipy's
        sparse LU factorisation, most of its work), as many as the rank's Numba threads
        (--cell-threads). None with one thread, or for a kind that would hold the GIL."""
        import numba
        threads = numba.get_num_threads()
        if threads < 2 or not kind.releases_gil:
            return None
        if self._pool is None or self._pool_threads != threads:
            from concurrent.futures import ThreadPoolExecutor
            self._pool, self._pool_threads = ThreadPoolExecutor(threads), threads
        return self._pool

    def commit(self, points):
        self.batch.commit(points)

    def rollback(self, points):
        self.batch.rollback(points)

    def committed_states(self, points):
        return self.batch.committed_states(points)

    def set_cell(self, p, template, state):
        self.batch.set_cell(int(p), template, state)

    def nbytes(self):
        return self.batch.nbytes() if self.batch is not None else 0

    def describe(self):
        return {"cell_device": self.device}
