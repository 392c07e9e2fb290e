"""Load balancing of Gauss points whose cost varies (FEM x DEM): points move between ranks.

The mesh partition gives every rank the same number of Gauss points, but in FEM x DEM a
point's work is its cell's relaxation, and the cells in a band relax far longer than those
outside it: a rank holding the band finishes its cells late and the others wait for it at
the next collective (the assembly). `BalancedMaterial` wraps a material and lets another
rank work on a point: the partition's points of a rank are its *home* points (the
Gauss-point store keeps their float history, fluxes and tangents), and each home point has
one *worker* rank whose inner material holds its resident state (the DEM cell) in a *slot*.
Initially every point is worked on at home; the float history never moves, only the
resident state does.

Per call (every rank, every time: `collective = True`, quadrature.QuadratureMap then
calls even a rank with nothing to update):

    update   home -> worker: point index, gradients, committed history row   (Alltoallv)
             worker: the inner material updates its slots, one point per call (timed)
             worker -> home: fluxes, trial history row, [tangent], status, cost (Alltoallv)
    tangent  home -> worker: point index; worker -> home: tangent, status, cost
    messages (the first failure / flag of each home rank's points, named by the worker's
             inner material with the point's coordinates) go back with comm.alltoall

Failures stay local until the exchange is complete: the inner material's ConstitutiveError
becomes a failed status with its message (the store raises it on the home rank after the
material returned, the solver makes it collective), any other exception of the inner
material is carried back as a fatal error and raised (RuntimeError) on the home ranks of
the points of that call, again only after every exchange of the call.

Balancing (after a commit, every `every` commits, when the measured imbalance exceeds
`threshold`; with `passes=True` instead at the start of every Newton pass, by the costs of
the pass before, see below): the cost of a point is the wall time its worker spent in the
inner material's update and tangent for it since the previous commit (`cost='wall'`, the default: the DEM
time steps a cell reports leave out the tangent's work, e.g. pstlo's linear solve, and the
cost of a step grows with the contacts: the seconds per DEM step of the points spread by a
factor 2.5, docs/balancing.md; `cost='work'` uses the reported cost instead). The
per-point costs are gathered on every rank and `assign` (deterministic, the same on every
rank) moves points from the most to the least loaded rank, each time the one whose move
best evens the pair (cost nearest half the gap: the heaviest point that does not overshoot),
until the predicted slowest / mean is below the threshold. The moved points' resident state
goes with `export_points` / `import_points` (comm.alltoall of the struct-of-arrays dicts)
and every rank rebuilds its inner material (`make_material()`) with its new slots, the kept
ones exported and imported too (a restored cell continues bit for bit). The results do not
depend on where a point is worked on (tests/test_balancing.py); the imbalance is recorded
per commit (`balance_report`).

Between Newton passes (`passes=True`): the cells of the band cost more in some passes of a
step than in others, and a balance made after the commit acts one step late. With this
option the wrapper measures the imbalance of every pass (its update and tangent calls) and,
at the start of the next update, moves points by that pass's costs; the commit only
measures. A pass may move points only when every rank re-solves all its points in that
update, or none was solved since the last commit or rollback: every update of a point
starts its cell from the committed state (DemMaterial, 001 eq. 7), so the committed state
is all that has to move, but a point left out of the update keeps a trial state that a move
would lose.

On one rank the wrapper is a pass-through (no exchange, no balancing).

export_points / import_points of the wrapper are collective (the home rank asks the
worker); the exported dict of the inner material must be a struct of arrays whose per-key
concatenation along axis 0 is the export of the concatenated points (true of
DemMaterial's pack_states + zone).
"""
import math
import time

import numpy as np
from mpi4py import MPI

from .constitutive import Constitutive, ConstitutiveError, PointReport

#: rebalance when the slowest rank's cell work exceeds the mean by more than 10 %
DEFAULT_THRESHOLD = 1.10
COSTS = ("wall", "work")
STATUS_FAILED = -1


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


def _offsets(counts):
    return np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)


def _alltoallv(comm, rows, send_counts, recv_counts, width):
    """Rows (float64, `width` columns) grouped by destination rank -> rows grouped by source."""
    send = np.ascontiguousarray(rows, dtype=np.float64).reshape(-1)
    recv = np.empty(int(np.sum(recv_counts)) * width, dtype=np.float64)
    sc, rc = np.asarray(send_counts) * width, np.asarray(recv_counts) * width
    comm.Alltoallv([send, (sc.tolist(), _offsets(sc).tolist()), MPI.DOUBLE],
                   [recv, (rc.tolist(), _offsets(rc).tolist()), MPI.DOUBLE])
    return recv.reshape(-1, width)


def _concatenate(parts):
    """Per-key concatenation of exported struct-of-arrays dicts (in order)."""
    parts = [p for p in parts if p]
    if len(parts) == 1:
        return parts[0]
    return {key: np.concatenate([np.asarray(p[key]) for p in parts]) for key in parts[0]} if parts else {}


def _runs(values):
    """(start, stop) of the maximal runs of equal values."""
    if not len(values):
        return []
    cuts = np.flatnonzero(np.diff(values)) + 1
    starts = np.concatenate([[0], cuts])
    stops = np.concatenate([cuts, [len(values)]])
    return list(zip(starts.tolist(), stops.tolist()))


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
        self.home_offset = _offsets(self.n_homes)
        self.slot_global = self.home_offset[comm.rank] + np.arange(n_points, dtype=np.int64)
        self.slot_zone = self.zone.copy() if self.zone is not None else None
        self.slot_xy = self.coordinates.copy() if self.coordinates is not None else None
        self._slots_changed()
        return state

    def initial_fluxes(self, n_points):
        if self._moved:
            raise RuntimeError("BalancedMaterial.initial_fluxes: only before any point has moved")
        return self.inner.initial_fluxes(n_points)

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
    def _send(self, points, rows):
        """Rows of home `points` to their workers. Returns (order, send_counts, received
        rows, source rank of each received row, recv_counts); rows[:, 0] is the point."""
        dest = self.worker[points]
        order = np.argsort(dest, kind="stable")
        send_counts = np.bincount(dest, minlength=self.comm.size).astype(np.int64)
        recv_counts = np.array(self.comm.alltoall(send_counts.tolist()), dtype=np.int64)
        rows = np.column_stack([points[order].astype(np.float64), rows[order]])
        received = _alltoallv(self.comm, rows, send_counts, recv_counts, rows.shape[1])
        source = np.repeat(np.arange(self.comm.size), recv_counts)
        return order, send_counts, received, source, recv_counts

    def _slots(self, received, source):
        """Slots of the received points and an error text (a bookkeeping bug: reported as a
        fatal error after the reply, never raised between the two exchanges)."""
        points = received[:, 0].astype(np.int64)
        slots = self.slot_of[self.home_offset[source] + points]
        if (slots < 0).any():
            return np.zeros(0, dtype=np.int64), "BalancedMaterial: a point was sent to a rank that does not work on it"
        return slots, ""

    def _reply(self, rows, status, cost, messages, source, send_counts, recv_counts):
        """Results back to the home ranks; the messages of each home rank's points (first
        failure, else first flag; a fatal error) with alltoall. Returns (rows, status,
        cost, failure, flag, fatal) on the home rank, rows in the order sent."""
        comm = self.comm
        back = _alltoallv(comm, np.column_stack([rows, status, cost]), recv_counts, send_counts, rows.shape[1] + 2)
        per_source = [["", "", ""] for _ in range(comm.size)]
        for k, text in messages.items():
            entry = per_source[source[k]]
            slot = 2 if status[k] == -np.inf else (0 if status[k] < 0 else 1)
            if not entry[slot]:
                entry[slot] = text
        got = comm.alltoall(per_source)
        failure = next((g[0] for g in got if g[0]), "")
        flag = next((g[1] for g in got if g[1]), "")
        fatal = next((g[2] for g in got if g[2]), "")
        status_back = back[:, -2]
        status_back[np.isinf(status_back)] = STATUS_FAILED
        return back[:, :-2], status_back.astype(np.int32), back[:, -1], failure, flag, fatal

    def _work(self, per_point, all_points, slots, source):
        """Run the inner material on the received slots: `per_point(k)` for each (timed one
        by one: the cost of each point), or, for a material that updates every row at once,
        `all_points()` once (time and cost shared). Returns (status, cost, messages) with
        status -inf for a fatal error; nothing raises before the reply."""
        n = len(slots)
        status, cost, wall, messages = np.zeros(n), np.zeros(n), np.zeros(n), {}

        def call(function):
            try:
                report = function()
            except ConstitutiveError as error:
                return None, STATUS_FAILED, str(error)
            except Exception as error:   # a bug must not leave the other ranks in the exchange
                return None, -np.inf, f"{type(error).__name__}: {error}"
            return report, None, ""

        if per_point is not None:
            for k in range(n):
                start = time.perf_counter()
                report, code, text = call(lambda: per_point(k))
                wall[k] = time.perf_counter() - start
                if report is not None:
                    status[k], cost[k] = report.status[0], report.cost[0]
                    text = report.message if report.status[0] != 0 else ""
                elif code is not None:
                    status[k] = code
                if text:
                    messages[k] = text
                if status[k] == -np.inf:
                    # the same bug would follow: skip the rest, each home rank concerned told why
                    status[k:] = -np.inf
                    for s in np.unique(source[k:]):
                        messages.setdefault(k + int(np.flatnonzero(source[k:] == s)[0]), text)
                    break
        elif n:
            start = time.perf_counter()
            report, code, text = call(all_points)
            wall[:] = (time.perf_counter() - start) / n
            if report is not None:
                status[:], cost[:] = np.asarray(report.status)[slots], np.asarray(report.cost)[slots]
                text = report.message
            elif code is not None:
                status[:] = code
            if text:   # the one message goes to the first point of each home rank it concerns
                for s in np.unique(source):
                    ks = np.flatnonzero((source == s) & (status != 0))
                    if ks.size:
                        messages[int(ks[0])] = text
        self.slot_wall[slots] += wall
        self.slot_work[slots] += np.where(np.isfinite(cost), cost, 0.0)
        self.pass_wall[slots] += wall
        self.pass_work[slots] += np.where(np.isfinite(cost), cost, 0.0)
        return status, cost, messages

    @staticmethod
    def _fatal(source, error):
        """(status, cost, messages) of a call that could not run: every point fatal."""
        n = len(source)
        return np.full(n, -np.inf), np.zeros(n), {int(np.flatnonzero(source == s)[0]): error for s in np.unique(source)}

    def _finish(self, points, order, status_back, cost_back, failure, flag, fatal):
        """Status and cost in the order of `points`, the message of the report; a fatal error
        of the inner material raises, now that every exchange of the call is done."""
        status = np.empty(len(points), dtype=np.int32)
        cost = np.empty(len(points))
        status[order], cost[order] = status_back, cost_back
        if fatal:
            raise RuntimeError(f"material failed on the rank working on the point: {fatal}")
        message = failure if (status < 0).any() else (flag if (status > 0).any() else "")
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
        order, send_counts, received, source, recv_counts = self._send(
            points, np.column_stack([gradients[points], state_old[points]]))
        self._own["exchange"] += time.perf_counter() - start
        slots, error = self._slots(received, source)
        G, SO, SN, F, T = self._gradients, self._state_old, self._state_new, self._flux, self._tangent
        if not error and not self.rate_independent and len(slots) and len(slots) != len(G):
            error = "BalancedMaterial: a rate-dependent material is updated at every point at once"
        width = nf + ns + (0 if self.tangent_on_demand else nf * nf)
        if error:
            status, cost, messages = self._fatal(source, error)
            rows = np.full((len(source), width), np.nan)
        else:
            G[slots] = received[:, 1:1 + ng]
            SO[slots] = received[:, 1 + ng:1 + ng + ns]
            if self.rate_independent:
                status, cost, messages = self._work(
                    lambda k: inner.update(G, dt, SO, F, T, SN, points=slots[k:k + 1]), None, slots, source)
            else:
                status, cost, messages = self._work(None, lambda: inner.update(G, dt, SO, F, T, SN, points=None), slots, source)
            columns = [F[slots], SN[slots]]
            if not self.tangent_on_demand:
                columns.append(T[slots].reshape(len(slots), nf * nf))
            rows = np.column_stack(columns).reshape(len(slots), width)
        start = time.perf_counter()
        back, status_back, cost_back, failure, flag, fatal = self._reply(
            rows, status, cost, messages, source, send_counts, recv_counts)
        self._own["exchange"] += time.perf_counter() - start
        home = points[order]
        flux_out[home] = back[:, :nf]
        state_new[home] = back[:, nf:nf + ns]
        if not self.tangent_on_demand:
            tangent_out[home] = back[:, nf + ns:].reshape(-1, nf, nf)
        return self._finish(points, order, status_back, cost_back, failure, flag, fatal)

    def tangent(self, points, tangent_out):
        """As the inner material's tangent, each point on its worker (collective)."""
        inner = self.inner
        if self.serial:
            return inner.tangent(points, tangent_out)
        start = time.perf_counter()
        points = np.asarray(points, dtype=np.int64)
        nf = self.flux_size
        order, send_counts, received, source, recv_counts = self._send(points, np.zeros((len(points), 0)))
        self._own["exchange"] += time.perf_counter() - start
        slots, error = self._slots(received, source)
        T = self._tangent
        if error:
            status, cost, messages = self._fatal(source, error)
            rows = np.full((len(source), nf * nf), np.nan)
        else:
            status, cost, messages = self._work(lambda k: inner.tangent(slots[k:k + 1], T), None, slots, source)
            rows = T[slots].reshape(len(slots), nf * nf)
        start = time.perf_counter()
        back, status_back, cost_back, failure, flag, fatal = self._reply(
            rows, status, cost, messages, source, send_counts, recv_counts)
        self._own["exchange"] += time.perf_counter() - start
        tangent_out[points[order]] = back.reshape(-1, nf, nf)
        return self._finish(points, order, status_back, cost_back, failure, flag, fatal)

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
        dest = new_worker[self.slot_global]
        outgoing = []
        for rank in range(comm.size):
            slots = np.flatnonzero(dest == rank) if rank != comm.rank else np.zeros(0, dtype=np.int64)
            outgoing.append(None if not slots.size else self._slot_block(slots, old.export_points(slots)))
        incoming = comm.alltoall(outgoing)
        kept = np.flatnonzero(dest == comm.rank)
        blocks = [self._slot_block(kept, old.export_points(kept) if kept.size else {})]
        blocks += [b for b in incoming if b is not None]
        g = np.concatenate([b["global"] for b in blocks])
        order = np.argsort(g, kind="stable")                  # slots in global point order
        position = np.empty_like(order)
        position[order] = np.arange(len(order))
        self.slot_global = g[order]
        if self.slot_zone is not None:
            self.slot_zone = np.concatenate([b["zone"] for b in blocks])[order]
        if self.slot_xy is not None:
            self.slot_xy = np.concatenate([b["xy"] for b in blocks])[order]
        for name, value in old.timers.items():
            self._timers_done[name] = self._timers_done.get(name, 0.0) + value
        inner = self.make_material()
        if self.slot_zone is not None:
            inner.set_zones(self.slot_zone)
        if self.slot_xy is not None:
            inner.set_point_coordinates(self.slot_xy)
        inner.initial_state(len(self.slot_global))
        offset = 0
        for b in blocks:
            n = len(b["global"])
            if n:
                inner.import_points(position[offset:offset + n], b["arrays"])
            offset += n
        self.inner = inner
        self._slots_changed()
        self.worker = new_worker[self.home_offset[comm.rank]:self.home_offset[comm.rank] + self.n_home].copy()
        self._moved = True

    def _slot_block(self, slots, arrays):
        return {"global": self.slot_global[slots], "arrays": arrays,
                "zone": None if self.slot_zone is None else self.slot_zone[slots],
                "xy": None if self.slot_xy is None else self.slot_xy[slots]}

    # --- resident state (checkpoints; collective) ----------------------------------------
    def export_points(self, points):
        """The committed resident state of home `points`, fetched from their workers: the
        runs of consecutive points on one worker are exported there and concatenated in
        order (see the module docstring). Collective."""
        if self.serial:
            return self.inner.export_points(points)
        comm = self.comm
        points = np.asarray(points, dtype=np.int64)
        runs = _runs(self.worker[points])
        requests = [[] for _ in range(comm.size)]
        for start, stop in runs:
            requests[int(self.worker[points[start]])].append(points[start:stop])
        asked = comm.alltoall(requests)
        answers = [[self.inner.export_points(self.slot_of[self.home_offset[rank] + run]) for run in runs_of]
                   for rank, runs_of in enumerate(asked)]
        got = [list(a) for a in comm.alltoall(answers)]
        parts = [got[int(self.worker[points[start]])].pop(0) for start, _ in runs]
        return _concatenate(parts) if parts else self.inner.export_points(np.zeros(0, dtype=np.int64))

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

