"""BalancedMaterial: a material whose Gauss points may be worked on by another rank (the
package docstring: home points, workers, slots; the per-call exchange in exchange.py, the
choice of workers in assignment.py, the move of resident state in migration.py)."""
import math
import time

import numpy as np

from ..constitutive import Constitutive, PointReport
from . import exchange
from .assignment import DEFAULT_THRESHOLD, assign, imbalance
from .migration import Slots, migrate

COSTS = ("wall", "work")


class BalancedMaterial(Constitutive):
    """A material whose points may be worked on by another rank (see the module docstring).

    comm           the mesh's communicator
    make_material  callable() -> a fresh inner material of the kind wrapped (same options)
    threshold      rebalance when slowest / mean of the measured cell work exceeds this
                   (>= 1; inf: measure only)
    every          consider rebalancing every this many commits (not used with passes)
    cost           'wall' (seconds per point, default) or 'work' (the inner material's cost)
    passes         balance at the start of every Newton pass by the last pass's costs
                   instead of after the commits (see the module docstring)
    """

    collective = True

    def __init__(self, comm, make_material, threshold=DEFAULT_THRESHOLD, every=1, cost="wall", passes=False):
        if not (isinstance(threshold, (int, float)) and not math.isnan(threshold) and threshold >= 1):
            raise ValueError(f"balancing: threshold must be a number >= 1 (slowest / mean), got {threshold!r}")
        if not (isinstance(every, (int, np.integer)) and every >= 1):
            raise ValueError(f"balancing: every must be an integer >= 1, got {every!r}")
        if cost not in COSTS:
            raise ValueError(f"balancing: cost must be one of {', '.join(COSTS)}, got {cost!r}")
        if not isinstance(passes, bool):
            raise ValueError(f"balancing: passes must be True or False, got {passes!r}")
        self.comm = comm
        self.make_material = make_material
        self.threshold, self.every, self.cost_measure = float(threshold), int(every), cost
        self.passes = passes
        self.inner = make_material()
        self.fallback_on = False        # kept for the inner materials a migration makes
        inner = self.inner
        self.rate_independent = inner.rate_independent
        self.tangent_on_demand = inner.tangent_on_demand
        self.state_names = tuple(inner.state_names)
        self.gradient_size, self.flux_size = inner.gradient_size, inner.flux_size
        self.cost_unit = inner.cost_unit
        self.serial = comm.size == 1
        self.n_home = 0
        self.worker = np.zeros(0, dtype=np.int64)     # worker rank of each home point
        self.zone = None                              # home zones (set_zones), None: none given
        self._timers_done = {}                        # timers of the inner materials replaced
        self._counters_done = {}                      # and their counters
        self._own = {"exchange": 0.0, "migration": 0.0}
        self._commits = 0
        self._moved = False
        self._clean = True              # no point solved since the last commit or rollback
        self._step_done = [0.0, 0.0]    # this step's wall and cost of slots replaced by a pass move
        self._pass = {"imbalance": [], "moves": 0, "seconds": 0.0}   # this step's passes
        self.records = []

    # --- set-up (before the Gauss-point store is built) ----------------------------------
    def set_zones(self, zone):
        self.zone = np.asarray(zone, dtype=np.int64)
        self.inner.set_zones(self.zone)

    def set_point_coordinates(self, xy):
        super().set_point_coordinates(xy)
        self.inner.set_point_coordinates(self.coordinates)

    def initial_state(self, n_points):
        """Every point starts at home: the inner material's slots are the home points.
        Collective (the store is built on every rank)."""
        state = self.inner.initial_state(n_points)
        self.n_home = n_points
        if self.serial:
            return state
        comm = self.comm
        self.worker = np.full(n_points, comm.rank, dtype=np.int64)
        self.n_homes = np.array(comm.allgather(int(n_points)), dtype=np.int64)
        self.home_offset = exchange.offsets(self.n_homes)
        self.slots = Slots(self.home_offset[comm.rank] + np.arange(n_points, dtype=np.int64),
                           self.zone.copy() if self.zone is not None else None,
                           self.coordinates.copy() if self.coordinates is not None else None)
        self._slots_changed()
        return state

    def initial_fluxes(self, n_points):
        if self._moved:
            raise RuntimeError("BalancedMaterial.initial_fluxes: only before any point has moved")
        return self.inner.initial_fluxes(n_points)

    @property
    def slot_global(self):
        """Global point index of each slot this rank works on."""
        return self.slots.global_index

    @property
    def slot_xy(self):
        """x, y [m] of the point in each slot (None when no coordinates were given)."""
        return self.slots.xy

    def _slots_changed(self):
        """Lookup global point -> slot and the slot work arrays, after the slots changed."""
        n = len(self.slot_global)
        self.slot_of = np.full(int(self.n_homes.sum()), -1, dtype=np.int64)
        self.slot_of[self.slot_global] = np.arange(n)
        self._gradients = np.zeros((n, self.gradient_size))
        self._state_old = np.zeros((n, self.state_size))
        self._state_new = np.zeros((n, self.state_size))
        self._flux = np.zeros((n, self.flux_size))
        self._tangent = np.zeros((n, self.flux_size, self.flux_size))
        self.slot_wall = np.zeros(n)        # wall seconds in the inner material since the last commit
        self.slot_work = np.zeros(n)        # its reported cost since the last commit
        self.pass_wall = np.zeros(n)        # the same since the start of the last update (passes=True)
        self.pass_work = np.zeros(n)

    # --- the exchange ---------------------------------------------------------------------
    def _slots(self, received, source):
        """Slots of the received points and an error text (a bookkeeping bug: reported as a
        fatal error after the reply, never raised between the two exchanges)."""
        points = received[:, 0].astype(np.int64)
        slots = self.slot_of[self.home_offset[source] + points]
        if (slots < 0).any():
            return np.zeros(0, dtype=np.int64), "BalancedMaterial: a point was sent to a rank that does not work on it"
        return slots, ""

    def _work(self, per_point, all_points, slots, source):
        """exchange.work on the received slots; their wall time and cost are counted."""
        done = exchange.work(per_point, all_points, slots, source)
        reported = np.where(np.isfinite(done.cost), done.cost, 0.0)
        self.slot_wall[slots] += done.wall
        self.slot_work[slots] += reported
        self.pass_wall[slots] += done.wall
        self.pass_work[slots] += reported
        return done

    def _finish(self, points, order, back):
        """Status and cost in the order of `points`, the message of the report; a fatal error
        of the inner material raises, now that every exchange of the call is done."""
        status = np.empty(len(points), dtype=np.int32)
        cost = np.empty(len(points))
        status[order], cost[order] = back.status, back.cost
        if back.fatal:
            raise RuntimeError(f"material failed on the rank working on the point: {back.fatal}")
        message = back.failure if (status < 0).any() else (back.flag if (status > 0).any() else "")
        return PointReport(status=status, cost=cost, message=message, cost_unit=self.cost_unit)

    # --- the update -----------------------------------------------------------------------
    def update(self, gradients, dt, state_old, flux_out, tangent_out, state_new, points=None):
        """As the inner material's update, each point on its worker (collective)."""
        if self.serial:
            return self.inner.update(gradients, dt, state_old, flux_out, tangent_out, state_new, points=points)
        points = np.arange(self.n_home) if points is None else np.asarray(points, dtype=np.int64)
        if self.passes:
            self._balance_pass(points)
        inner = self.inner          # (rebuilt if points moved)
        self._clean = False
        start = time.perf_counter()
        ng, ns, nf = self.gradient_size, self.state_size, self.flux_size
        sent = exchange.send(self.comm, self.worker, points, np.column_stack([gradients[points], state_old[points]]))
        self._own["exchange"] += time.perf_counter() - start
        received, source = sent.received, sent.source
        slots, error = self._slots(received, source)
        G, SO, SN, F, T = self._gradients, self._state_old, self._state_new, self._flux, self._tangent
        if not error and not self.rate_independent and len(slots) and len(slots) != len(G):
            error = "BalancedMaterial: a rate-dependent material is updated at every point at once"
        width = nf + ns + (0 if self.tangent_on_demand else nf * nf)
        if error:
            done = exchange.fatal(source, error)
            rows = np.full((len(source), width), np.nan)
        else:
            G[slots] = received[:, 1:1 + ng]
            SO[slots] = received[:, 1 + ng:1 + ng + ns]
            if self.rate_independent:
                done = self._work(lambda k: inner.update(G, dt, SO, F, T, SN, points=slots[k:k + 1]), None,
                                  slots, source)
            else:
                done = self._work(None, lambda: inner.update(G, dt, SO, F, T, SN, points=None), slots, source)
            columns = [F[slots], SN[slots]]
            if not self.tangent_on_demand:
                columns.append(T[slots].reshape(len(slots), nf * nf))
            rows = np.column_stack(columns).reshape(len(slots), width)
        start = time.perf_counter()
        back = exchange.reply(self.comm, rows, done, sent)
        self._own["exchange"] += time.perf_counter() - start
        home = points[sent.order]
        flux_out[home] = back.rows[:, :nf]
        state_new[home] = back.rows[:, nf:nf + ns]
        if not self.tangent_on_demand:
            tangent_out[home] = back.rows[:, nf + ns:].reshape(-1, nf, nf)
        return self._finish(points, sent.order, back)

    def tangent(self, points, tangent_out):
        """As the inner material's tangent, each point on its worker (collective)."""
        inner = self.inner
        if self.serial:
            return inner.tangent(points, tangent_out)
        start = time.perf_counter()
        points = np.asarray(points, dtype=np.int64)
        nf = self.flux_size
        sent = exchange.send(self.comm, self.worker, points, np.zeros((len(points), 0)))
        self._own["exchange"] += time.perf_counter() - start
        slots, error = self._slots(sent.received, sent.source)
        T = self._tangent
        if error:
            done = exchange.fatal(sent.source, error)
            rows = np.full((len(sent.source), nf * nf), np.nan)
        else:
            done = self._work(lambda k: inner.tangent(slots[k:k + 1], T), None, slots, sent.source)
            rows = T[slots].reshape(len(slots), nf * nf)
        start = time.perf_counter()
        back = exchange.reply(self.comm, rows, done, sent)
        self._own["exchange"] += time.perf_counter() - start
        tangent_out[points[sent.order]] = back.rows.reshape(-1, nf, nf)
        return self._finish(points, sent.order, back)

    def use_fallback_operator(self, on):
        self.fallback_on = bool(on)
        return self.inner.use_fallback_operator(on)

    def rollback(self):
        self.inner.rollback()
        self._clean = True

    def _balance_pass(self, points):
        """At the start of an update: the imbalance of the pass before (its update and tangent
        calls) and, above the threshold, moves by its per-point costs, if every rank re-solves
        all its points now or none has been solved since the last commit or rollback (module
        docstring). Collective."""
        comm = self.comm
        cost = self.pass_wall if self.cost_measure == "wall" else self.pass_work
        # one collective: every rank's load of the last pass and whether it may move now
        gathered = comm.allgather((float(cost.sum()), bool(self._clean or len(points) == self.n_home)))
        loads = np.array([load for load, _ in gathered])
        safe = all(may for _, may in gathered)
        if loads.sum() > 0:
            self._pass["imbalance"].append(imbalance(loads))
        if safe and loads.sum() > 0 and imbalance(loads) > self.threshold:
            start = time.perf_counter()
            moves, _ = self._rebalance(cost)
            self._pass["moves"] += moves
            seconds = time.perf_counter() - start
            self._pass["seconds"] += seconds
            self._own["migration"] += seconds
        self.pass_wall[:] = 0.0
        self.pass_work[:] = 0.0

    def _rebalance(self, cost):
        """Gather the per-point `cost` of every rank, assign, migrate. Returns (moves, the
        imbalance the assignment predicts). Collective."""
        comm = self.comm
        total = int(self.n_homes.sum())
        g_cost, g_worker = np.zeros(total), np.full(total, -1, dtype=np.int64)
        for rank, (index, c) in enumerate(comm.allgather((self.slot_global, cost))):
            g_cost[index], g_worker[index] = c, rank
        new = assign(g_cost, g_worker, comm.size, self.threshold)
        moves = int(np.count_nonzero(new != g_worker))
        if moves:
            # the slots are rebuilt: keep what this step's slots measured so far (the commit's record)
            self._step_done[0] += float(self.slot_wall.sum())
            self._step_done[1] += float(self.slot_work.sum())
            self._migrate(new)
        return moves, imbalance(np.bincount(new, weights=g_cost, minlength=comm.size))

    def commit(self):
        """Commit the inner material; then, every `every` commits, measure the imbalance and
        move points if it exceeds the threshold (collective: every rank commits together).
        With passes=True the commit only measures (the passes move points)."""
        self.inner.commit()
        self._clean = True
        if self.serial:
            return
        self._commits += 1
        comm = self.comm
        wall = np.array(comm.allgather(float(self.slot_wall.sum()) + self._step_done[0]))
        work = np.array(comm.allgather(float(self.slot_work.sum()) + self._step_done[1]))
        cost = self.slot_wall if self.cost_measure == "wall" else self.slot_work
        loads = wall if self.cost_measure == "wall" else work
        record = {"commit": self._commits, "work_seconds": wall.tolist(), "imbalance": imbalance(wall),
                  "work_cost": work.tolist(), "work_imbalance": imbalance(work), "moves": 0,
                  "predicted_imbalance": imbalance(loads), "migration_seconds": 0.0}
        if self.passes:
            record.update(pass_imbalance=list(self._pass["imbalance"]), pass_moves=self._pass["moves"],
                          pass_migration_seconds=self._pass["seconds"])
        # how well the reported cost stands for the time: seconds per unit of cost over the
        # points (5th, 50th, 95th percentile; spread = their ratio)
        worked = self.slot_work > 0
        ratios = np.concatenate(comm.allgather(self.slot_wall[worked] / self.slot_work[worked]))
        if ratios.size:
            record["seconds_per_cost_percentiles"] = np.percentile(ratios, [5, 50, 95]).tolist()
        if not self.passes and self._commits % self.every == 0 and imbalance(loads) > self.threshold:
            start = time.perf_counter()
            moves, predicted = self._rebalance(cost)
            record.update(moves=moves, migration_seconds=time.perf_counter() - start,
                          predicted_imbalance=predicted)
            self._own["migration"] += time.perf_counter() - start
        record["points_away_from_home"] = comm.allreduce(int(np.count_nonzero(self.worker != comm.rank)))
        self.records.append(record)
        self.slot_wall[:] = 0.0
        self.slot_work[:] = 0.0
        self._step_done = [0.0, 0.0]
        self._pass = {"imbalance": [], "moves": 0, "seconds": 0.0}

    def _migrate(self, new_worker):
        """Move the resident state of the points whose worker changes (new_worker: the worker
        of every global point) and rebuild this rank's inner material with its new slots.
        Called after a commit (the exported states are the committed = current ones) or at
        the start of a pass that re-solves every point from its committed state."""
        comm, old = self.comm, self.inner
        for name, value in old.timers.items():
            self._timers_done[name] = self._timers_done.get(name, 0.0) + value
        for name, value in old.counters.items():
            self._counters_done[name] = self._counters_done.get(name, 0) + value
        self.inner, self.slots = migrate(comm, old, self.make_material, self.slots, new_worker[self.slot_global])
        self.inner.use_fallback_operator(self.fallback_on)
        self._slots_changed()
        self.worker = new_worker[self.home_offset[comm.rank]:self.home_offset[comm.rank] + self.n_home].copy()
        self._moved = True

    # --- resident state (checkpoints; collective) ----------------------------------------
    def export_points(self, points):
        """The committed resident state of home `points`, fetched from their workers: the
        runs of consecutive points on one worker are exported there and concatenated in
        order (see the module docstring). Collective."""
        if self.serial:
            return self.inner.export_points(points)
        comm = self.comm
        points = np.asarray(points, dtype=np.int64)
        runs = exchange.runs(self.worker[points])
        requests = [[] for _ in range(comm.size)]
        for start, stop in runs:
            requests[int(self.worker[points[start]])].append(points[start:stop])
        asked = comm.alltoall(requests)
        answers = [[self.inner.export_points(self.slot_of[self.home_offset[rank] + run]) for run in runs_of]
                   for rank, runs_of in enumerate(asked)]
        got = [list(a) for a in comm.alltoall(answers)]
        parts = [got[int(self.worker[points[start]])].pop(0) for start, _ in runs]
        return exchange.concatenate(parts) if parts else self.inner.export_points(np.zeros(0, dtype=np.int64))

    def import_points(self, points, arrays, rows=None):
        """Make `arrays` (rows `rows`, default all in order) the resident state of home
        `points` on their workers (the arrays go to every worker concerned). Collective."""
        if self.serial:
            return self.inner.import_points(points, arrays, rows)
        comm = self.comm
        points = np.asarray(points, dtype=np.int64)
        rows = np.arange(len(points)) if rows is None else np.asarray(rows, dtype=np.int64)
        dest = self.worker[points]
        sends = [None] * comm.size
        for rank in np.unique(dest):
            mine = dest == rank
            sends[rank] = (points[mine], rows[mine], arrays)
        for rank, got in enumerate(comm.alltoall(sends)):
            if got is not None:
                home, rows_of, arrays_of = got
                self.inner.import_points(self.slot_of[self.home_offset[rank] + home], arrays_of, rows_of)

    # --- diagnostics ----------------------------------------------------------------------
    @property
    def timers(self):
        """The inner materials' timers (summed over those replaced by migrations) and the
        wrapper's own: exchange (in the collectives, waiting included), migration [s]."""
        out = dict(self._timers_done)
        for name, value in self.inner.timers.items():
            out[name] = out.get(name, 0.0) + value
        out.update(self._own)
        return out

    @property
    def counters(self):
        """The inner materials' counters, those of the materials replaced by migrations
        included."""
        out = dict(self._counters_done)
        for name, value in self.inner.counters.items():
            out[name] = out.get(name, 0) + value
        return out

    def memory_bytes(self):
        return self.inner.memory_bytes()

    def describe(self):
        return self.inner.describe()

    def balance_report(self):
        """Per commit: cell-work wall seconds per rank, imbalance = slowest / mean (measured in
        the step), the inner material's cost per rank, moves, the predicted imbalance after
        them, migration seconds, points worked on away from home; and totals. Collective
        values (the same on every rank)."""
        records = self.records
        measured = [r["imbalance"] for r in records]
        return {"threshold": self.threshold, "every": self.every, "cost": self.cost_measure, "passes": self.passes,
                "ranks": self.comm.size,
                "moves_total": int(sum(r["moves"] + r.get("pass_moves", 0) for r in records)),
                "imbalance_mean": float(np.mean(measured)) if measured else None,
                "imbalance_max": float(np.max(measured)) if measured else None,
                "migration_seconds": float(sum(r["migration_seconds"] + r.get("pass_migration_seconds", 0.0)
                                               for r in records)),
                "steps": records}

