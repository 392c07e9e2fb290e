"""FEM x DEM: a periodic DEM cell (demcell) at every Gauss point, behind the Gauss-point interface.

One `demcell.DemCell` per Gauss point of the cells this rank owns, created once (copies of
the zone's reference cell) and resident on the rank for the whole run, in a cell store
(stores.py: one DemCell per point, or all of them in a demcell cell store, batched=True).

Which state a cell starts from (docs/reference/femdem.md): every update of a point within a load step
starts its cell from the committed state of the last converged step and loads it to the
current iterate's F (001 eq. 7 with F_i the committed F): the step's answer depends on the
committed state and the target only, not on the Newton path or the line search, as for a
return mapping. The tangent is the chosen operator of the cell at the current iterate
(perturbation: 001 eq. 6, four more solves from the committed state; demqo: eq. 20, four frozen-
contact relaxations from the current equilibrium; kruyt: eq. 13; pstlo: appendix B). Points
whose gradients did not change are not solved again (`rate_independent`), tangents are
computed when the Jacobian is assembled (`tangent_on_demand`), commit / rollback reach the
cells.

Per point the history array holds the committed outputs of the cell (coordination number,
fabric anisotropy, sliding fraction, stress ratio, contacts, DEM steps of the last solve,
status). Status: 0 ok; 1 (flagged, the run goes on): the cell lost every contact, its
stress is zero; < 0 (failed, the step is cut): -1 the cell did not relax within its step
budget, -2 inadmissible F (det F <= 0), -3 the micro solve broke down (non-finite values,
cell squeezed below the minimum-image size); a target F further than
`max_strain_increment` from the committed F is refused as -2 before the cell is touched
(micropolar mode: also a curvature change whose rotation jump across the cell |dkappa . Y|
exceeds it, modes.MicropolarMode.increment).
"""
import time

import numpy as np

from ...constitutive import Constitutive, PointReport
from .cells import check_tangent
from .stores import (STATUS_BAD_F, STATUS_BROKEN, STATUS_NO_CONTACTS, STATUS_NOT_RELAXED,  # noqa: F401
                     BatchedCells, CellList, cell_outputs)


class DemMaterial(Constitutive):
    """Gauss-point material backed by demcell cells.

    reference_cells  list of prepared DemCells, one per zone (see cells.reference_cells)
    mode             a mode object of modes.py (classical, hybrid, micropolar)
    tangent          a name of cells.TANGENTS (demcell.tangent.TANGENT_KINDS): 'perturbation',
                     'demqo', 'kruyt', 'pstlo', 'pstlo_sliding' (Cauchy cells)
    batched          the cells in one demcell cell store (stores.BatchedCells) on `device`
                     ('cpu' or 'gpu'), else one DemCell per point (stores.CellList)
    fallback_tangent the operator of a load step that failed with `tangent`
                     (use_fallback_operator; None: none). Default kruyt: the contact springs'
                     uniform-strain stiffness stays positive definite where the consistent
                     operators of a network with sliding contacts turn singular past a peak
                     (fallback.py, docs/reference/femdem.md "Past the peak")
    """

    rate_independent = True
    tangent_on_demand = True
    state_names = ("coordination_number", "anisotropy", "sliding_fraction", "stress_ratio",
                   "n_contacts", "dem_steps", "status")
    state_index = {name: i for i, name in enumerate(state_names)}
    cost_unit = "DEM time steps"

    def __init__(self, reference_cells, mode, tangent="pstlo", max_strain_increment=0.05, batched=False,
                 device="cpu", fallback_tangent="kruyt"):
        for name in (tangent, fallback_tangent):
            refusal = None if name is None else check_tangent(name, mode.name)
            if refusal:
                raise ValueError(refusal)
        if not reference_cells:
            raise ValueError("DemMaterial needs at least one reference cell")
        if mode.name == "micropolar" and not all(c.micropolar for c in reference_cells):
            raise ValueError("mode 'micropolar' needs cells that carry rotation and curvature themselves "
                             "(demcell.DemCell(..., rotation_mode='micropolar'), as "
                             "reference_cells(..., micropolar=True) makes them)")
        if not (np.isfinite(max_strain_increment) and max_strain_increment > 0):
            raise ValueError(f"max_strain_increment must be positive, got {max_strain_increment!r}")
        if batched and device not in BatchedCells.DEVICES:
            raise ValueError(f"unknown cell device {device!r}: one of {', '.join(BatchedCells.DEVICES)}")
        self.max_strain_increment = float(max_strain_increment)
        self.reference_cells = list(reference_cells)
        self.mode = mode
        self.tangent_name = tangent
        self.fallback_tangent = fallback_tangent
        self.fallback_on = False
        self.batched, self.device = batched, device
        self.zone = None
        self.store = CellList([], mode, self.max_strain_increment)
        self._touched = set()
        self._floors = {}
        self.timers = {"solve": 0.0, "homogenize": 0.0, "tangent": 0.0, "commit": 0.0}

    @property
    def tangent_kind(self):
        """The demcell.tangent.TangentKind of the cell operator the Newton uses."""
        from demcell.tangent import tangent_kind
        on = self.fallback_on and self.fallback_tangent is not None
        return tangent_kind(self.fallback_tangent if on else self.tangent_name)

    def use_fallback_operator(self, on):
        before = self.tangent_kind.name
        self.fallback_on = bool(on)
        return self.tangent_kind.name != before

    @property
    def cells(self):
        """The cells, one per point, to read (the store solves them)."""
        return self.store.cells

    # --- set-up ------------------------------------------------------------------------
    def set_zones(self, zone):
        """zone[p]: index of the reference cell of point p (before the store is built)."""
        zone = np.asarray(zone, dtype=np.int64)
        if zone.size and (zone.min() < 0 or zone.max() >= len(self.reference_cells)):
            raise ValueError("DemMaterial: zone index out of range")
        self.zone = zone

    def initial_state(self, n_points):
        """Create the cells (copies of the reference cells) and their initial outputs."""
        if self.zone is None:
            self.zone = np.zeros(n_points, dtype=np.int64)
        if len(self.zone) != n_points:
            raise RuntimeError("DemMaterial: set_zones needs one entry per Gauss point")
        cells = [self.reference_cells[z].copy() for z in self.zone]
        if self.batched:
            self.store = BatchedCells(cells, self.mode, self.max_strain_increment, self.device)
        else:
            self.store = CellList(cells, self.mode, self.max_strain_increment)
        state = np.zeros((n_points, len(self.state_names)))
        for z, ref in enumerate(self.reference_cells):
            state[self.zone == z] = cell_outputs(ref.homogenized(), 0, 0)
        return state

    def initial_fluxes(self, n_points):
        """Fluxes of the reference state (F = I) per point, (n_points, 6) [Pa, N/m]."""
        out = np.zeros((n_points, 6))
        for z, ref in enumerate(self.reference_cells):
            row = np.zeros(6)
            self.mode.fluxes(ref.homogenized(), np.zeros(6), row)
            out[self.zone == z] = row
        return out

    # --- the update --------------------------------------------------------------------
    def update(self, gradients, dt, state_old, flux_out, tangent_out, state_new, points=None):
        points = np.arange(len(self.zone)) if points is None else np.asarray(points, dtype=np.int64)
        status = np.zeros(len(points), dtype=np.int32)
        cost = np.zeros(len(points))
        texts = {}
        if len(points):
            self._touched.update(int(p) for p in points)
            self.store.solve(points, gradients, flux_out, state_new, status, cost, texts, self.timers)
        # the first failure names the cause, else the first flag
        failed, flagged = np.flatnonzero(status < 0), np.flatnonzero(status > 0)
        first = failed[0] if len(failed) else (flagged[0] if len(flagged) else None)
        message = "" if first is None else f"{self.where(points[first])}: {texts[first]}"
        return PointReport(status=status, cost=cost, message=message, cost_unit=self.cost_unit)

    def tangent(self, points, tangent_out):
        points = np.asarray(points, dtype=np.int64)
        cost = np.zeros(len(points))
        start = time.perf_counter()
        if len(points):
            # a cell without contacts has no stiffness (and pstlo's solve would be singular); a
            # whole element of such points would make the Jacobian singular, so it gets 1e-6 of
            # its reference cell's stiffness: the stress stays zero
            self.store.tangent(points, self.tangent_kind, tangent_out, cost,
                               lambda p: self._floor_tangent(int(self.zone[p])))
        self.timers["tangent"] += time.perf_counter() - start
        return PointReport(status=np.zeros(len(points), dtype=np.int32), cost=cost, cost_unit=self.cost_unit)

    def _floor_tangent(self, zone):
        if zone not in self._floors:
            block = np.zeros((6, 6))
            self.mode.tangent(self.reference_cells[zone], None, "kruyt", block)
            self._floors[zone] = 1e-6 * block
        return self._floors[zone]

    def commit(self):
        start = time.perf_counter()
        if self._touched:
            self.store.commit(np.array(sorted(self._touched), dtype=np.int64))
        self._touched.clear()
        self.timers["commit"] += time.perf_counter() - start

    def rollback(self):
        if self._touched:
            self.store.rollback(np.array(sorted(self._touched), dtype=np.int64))
        self._touched.clear()

    # --- resident state (checkpoint.py; a load balancer moves cells with the same pair) --
    def export_points(self, points):
        """zone and committed cell state of `points` (demcell.state.pack_states arrays)."""
        from demcell.state import pack_states
        points = np.asarray(points, dtype=np.int64)
        return dict(pack_states(self.store.committed_states(points)), zone=self.zone[points].copy())

    def import_points(self, points, arrays, rows=None):
        """Cells of `points` continue from exported states (zone included): a copy of the
        zone's reference cell (law, options) restored to the state. rows: which of the
        exported cells (default all)."""
        for p, z, st in self._imported(points, arrays, rows):
            self.store.set_cell(p, self.reference_cells[z], st)

    def check_exported(self, arrays, rows=None):
        """Every exported cell state consistent (demcell's CellState.check: finite positions,
        radii > 0, det h > 0, pair arrays of existing particles) and its zone one of this
        material's."""
        from demcell.state import unpack_states
        if "zone" not in arrays:
            raise ValueError("the cell states have no 'zone'")
        zone = np.asarray(arrays["zone"])
        if rows is not None:
            zone = zone[np.asarray(rows, dtype=np.int64)]
        if zone.size and (not np.issubdtype(zone.dtype, np.integer) or zone.min() < 0
                          or zone.max() >= len(self.reference_cells)):
            raise ValueError("a cell state's zone is not one of this material's")
        for k, state in enumerate(unpack_states(arrays, rows)):
            try:
                state.check()
            except ValueError as error:
                raise ValueError(f"cell state {k}: {error}") from None

    def _imported(self, points, arrays, rows):
        """(point, zone, CellState) of exported cells, checked; the zones are set."""
        from demcell.state import unpack_states
        points = np.asarray(points, dtype=np.int64)
        zone = np.asarray(arrays["zone"], dtype=np.int64)
        if rows is not None:
            zone = zone[np.asarray(rows, dtype=np.int64)]
        states = unpack_states(arrays, rows)
        if len(states) != len(points) or len(zone) != len(points):
            raise ValueError(f"{type(self).__name__}.import_points: {len(states)} cell states for {len(points)} points")
        if zone.size and (zone.min() < 0 or zone.max() >= len(self.reference_cells)):
            raise ValueError(f"{type(self).__name__}.import_points: zone index out of range")
        for p, z in zip(points, zone):
            self.zone[p] = z
            self._touched.discard(int(p))
        return zip(points, zone, states)

    # --- diagnostics ---------------------------------------------------------------------
    @property
    def counters(self):
        """cell_solves_redone: FIRE cell solves of this rank that did not settle and were
        solved again with local damping (stores.PointCells.solves_redone); cell_solves_capped:
        cell solves that the cells' relax_cap stopped before they settled."""
        return {"cell_solves_redone": self.store.solves_redone, "cell_solves_capped": self.store.solves_capped}

    def memory_bytes(self):
        """Bytes held by the cells of this rank (current and committed states)."""
        return self.store.nbytes()

    def describe(self):
        """The mode (micropolar: with the cell moduli of the reference state, see
        cells.micropolar_moduli, once the scene has set them), the tangent, the zones, batched or
        not and the cells' relaxation (demcell.RelaxationOptions, as the cells run it)."""
        import dataclasses
        return dict(self.mode.describe(), tangent=self.tangent_name, n_zones=len(self.reference_cells),
                    batched=self.batched, relaxation=dataclasses.asdict(self.reference_cells[0].options),
                    **self.store.describe())
