"""Load balancing of Gauss points between ranks (cosserat_fenicsx/balancing/).

The assignment algorithm on its own (serial): the imbalance falls below the threshold with
few moves and every point has exactly one worker. On 2 ranks (the MPI pass; skipped on
one): the FEM x DEM biaxial with a weak corner gives bit-identical results with and without
balancing while cells move (the greedy at a threshold of 1, and a forced exchange of half
the points every step; the same balanced between Newton passes, where a pass moves points
only when no trial state would be lost), and a cell that fails on the rank it was moved to
still cuts the step with a message naming its point, on every rank (the test finishing
shows no rank was left waiting).

The linear solver of these runs is PETSc's redundant LU: MUMPS on 2 processes is not
bit-reproducible from run to run (test_femdem measured 6e-4 in a stress ratio between two
identical 2-rank runs), which would hide what is compared here.
"""
import dataclasses

import numpy as np
import pytest
from mpi4py import MPI

from cosserat_fenicsx import balancing
from cosserat_fenicsx.balancing import assign, imbalance
from cosserat_fenicsx.constitutive import Constitutive, PointReport

COMM = MPI.COMM_WORLD
two_ranks = pytest.mark.skipif(COMM.size != 2, reason="needs 2 ranks (the MPI pass)")


# --- the assignment (serial) -------------------------------------------------------------

def band_costs(n_ranks, per_rank, heavy, seed=0):
    """Per-point costs of a partition whose first rank holds a band: its points cost
    `heavy` times the others' (with a +-30 % spread), point p starts on rank p // per_rank."""
    rng = np.random.default_rng(seed)
    cost = rng.uniform(0.7, 1.3, n_ranks * per_rank)
    cost[:per_rank] *= heavy
    return cost, np.repeat(np.arange(n_ranks), per_rank)


@pytest.mark.serial
@pytest.mark.parametrize("n_ranks, per_rank, heavy", [(2, 24, 5.0), (4, 30, 3.0), (3, 12, 10.0), (8, 50, 2.0)])
def test_assignment_balances_with_few_moves(n_ranks, per_rank, heavy):
    cost, worker = band_costs(n_ranks, per_rank, heavy)
    before = imbalance(np.bincount(worker, weights=cost, minlength=n_ranks))
    new = assign(cost, worker, n_ranks, threshold=1.10)
    after = imbalance(np.bincount(new, weights=cost, minlength=n_ranks))
    assert before > 1.3 and after <= 1.10, (before, after)
    assert new.shape == worker.shape and set(np.unique(new)) <= set(range(n_ranks))   # one worker each
    moves = np.count_nonzero(new != worker)
    # the fewest moves any assignment needs: the overloaded rank sheds its excess over
    # threshold x mean with its heaviest points first
    loads = np.bincount(worker, weights=cost, minlength=n_ranks)
    excess = loads - 1.10 * loads.mean()
    needed = sum(int(np.searchsorted(np.cumsum(np.sort(cost[worker == r])[::-1]), e) + 1)
                 for r, e in enumerate(excess) if e > 0)
    assert moves <= 3 * needed, (moves, needed)
    assert np.all(worker[new != worker] == 0) or n_ranks > 2   # 2 ranks: only the band's rank gives


@pytest.mark.serial
def test_assignment_leaves_a_balanced_partition_alone_and_ends():
    cost, worker = band_costs(4, 20, 1.0)
    cost = np.ones_like(cost)
    assert np.array_equal(assign(cost, worker, 4), worker)
    # one point carries all the work: nothing can help, the greedy stops without moving it
    cost = np.zeros(8)
    cost[3] = 5.0
    worker = np.repeat(np.arange(2), 4)
    assert np.array_equal(assign(cost, worker, 2, threshold=1.0), worker)
    # zero work everywhere (a step that updated nothing) is balanced
    assert imbalance(np.zeros(3)) == 1.0


@pytest.mark.serial
def test_bad_settings_are_refused():
    with pytest.raises(ValueError, match="threshold"):
        balancing.BalancedMaterial(MPI.COMM_SELF, lambda: None, threshold=0.9)
    with pytest.raises(ValueError, match="every"):
        balancing.BalancedMaterial(MPI.COMM_SELF, lambda: None, every=0)
    with pytest.raises(ValueError, match="cost"):
        balancing.BalancedMaterial(MPI.COMM_SELF, lambda: None, cost="seconds")


# --- the wrapper with a cheap material of known costs (2 ranks) --------------------------------

class Counter(Constitutive):
    """A point's flux is its resident value plus the first gradient; commit keeps it. The
    cost of a point is its zone (known); a negative second gradient fails the point, a
    third gradient of 99 raises a plain exception (a bug)."""
    rate_independent = True
    tangent_on_demand = True
    state_names = ("updates",)

    def __init__(self):
        self.zone, self.xy = None, None

    def set_zones(self, zone):
        self.zone = np.asarray(zone, dtype=float)

    def set_point_coordinates(self, xy):
        self.xy = np.asarray(xy)

    def where(self, p):
        return f"point at ({self.xy[p][0]:.4g}, {self.xy[p][1]:.4g})"

    def initial_state(self, n):
        self.committed, self.trial = np.zeros(n), np.zeros(n)
        return np.zeros((n, 1))

    def update(self, gradients, dt, state_old, flux_out, tangent_out, state_new, points=None):
        status, message = np.zeros(len(points), dtype=np.int32), ""
        for k, p in enumerate(points):
            if gradients[p, 2] == 99:
                raise ZeroDivisionError("a bug")
            if gradients[p, 1] < 0:
                status[k] = -1
                message = message or f"{self.where(p)}: negative"
                continue
            self.trial[p] = self.committed[p] + gradients[p, 0]
            flux_out[p] = self.trial[p]
            state_new[p] = state_old[p] + 1
        return PointReport(status=status, cost=self.zone[points].copy(), message=message)

    def tangent(self, points, tangent_out):
        tangent_out[points] = np.eye(6) * self.committed[points, None, None]
        return PointReport(status=np.zeros(len(points), dtype=np.int32), cost=np.zeros(len(points)))

    def commit(self):
        self.committed[:] = self.trial

    def rollback(self):
        self.trial[:] = self.committed

    def export_points(self, points):
        return {"zone": self.zone[points].copy(), "value": self.committed[points].copy()}

    def import_points(self, points, arrays, rows=None):
        rows = np.arange(len(points)) if rows is None else rows
        self.zone[points] = arrays["zone"][rows]
        self.committed[points] = self.trial[points] = arrays["value"][rows]


def counter_step(material, reference, gradients, state, points=None):
    """One update + tangent + commit of the wrapped material and of a plain one; returns
    both (fluxes, tangents, trial history, report)."""
    out = []
    for m in (material, reference):
        n = len(gradients)
        flux, tangent, new = np.zeros((n, 6)), np.zeros((n, 6, 6)), state.copy()
        pts = np.arange(n) if points is None else points
        report = m.update(gradients, 1.0, state, flux, tangent, new, points=pts)
        # the wrapper's calls are collective: the tangent on every rank or on none (as the
        # solver makes a failure collective first)
        if COMM.allreduce(int((report.status < 0).any())) == 0:
            m.tangent(pts, tangent)
        out.append((flux, tangent, new, report))
    return out


@pytest.mark.serial
def test_one_rank_is_a_pass_through():
    """On one rank the wrapper calls its inner material directly (no exchange, no balancing)."""
    n = 5
    wrapped = balancing.BalancedMaterial(MPI.COMM_SELF, Counter, threshold=1.0, cost="work")
    plain = Counter()
    for m in (wrapped, plain):
        m.set_zones(np.arange(1.0, n + 1))
        m.set_point_coordinates(np.zeros((n, 2)))
    state = wrapped.initial_state(n)
    plain.initial_state(n)
    gradients = np.zeros((n, 6))
    gradients[:, 0] = np.arange(n)
    (fw, tw, sw, rw), (fp, tp, sp, rp) = counter_step(wrapped, plain, gradients, state, np.array([1, 3]))
    assert np.array_equal(fw, fp) and np.array_equal(tw, tp) and np.array_equal(sw, sp)
    wrapped.commit()
    assert wrapped.records == [] and wrapped.inner.committed[3] == 3.0
    assert wrapped.export_points([3])["value"].tolist() == [3.0]


@two_ranks
def test_wrapper_moves_points_of_known_cost():
    """Rank 0's points cost 5, rank 1's cost 1: after a commit the predicted and the next
    measured imbalance (in reported cost) are below the threshold, each point is worked on
    by exactly one rank, and the results are those of the unwrapped material, whose resident
    state followed the points (three steps, moves in between). A failing point on the rank it
    moved to reports its own message at home; a bug there raises (RuntimeError) on its home
    rank after the exchange, the other rank is not left waiting; export_points returns the
    committed values in the order asked, import_points sets them."""
    n = 12
    rng = np.random.default_rng(COMM.rank)
    xy = np.column_stack([np.arange(n) + 100.0 * COMM.rank, np.zeros(n)])
    wrapped = balancing.BalancedMaterial(COMM, Counter, threshold=1.1, cost="work")
    plain = Counter()
    for m in (wrapped, plain):
        m.set_zones(np.full(n, 5.0 if COMM.rank == 0 else 1.0))
        m.set_point_coordinates(xy)
    state = wrapped.initial_state(n)
    plain.initial_state(n)
    before = None
    for step in range(3):
        gradients = np.zeros((n, 6))
        gradients[:, 0] = rng.normal(size=n)
        points = np.arange(step, n)              # some points unchanged, as the callback does
        (fw, tw, sw, rw), (fp, tp, sp, rp) = counter_step(wrapped, plain, gradients, state, points)
        assert np.array_equal(fw, fp) and np.array_equal(tw, tp) and np.array_equal(sw, sp)
        assert np.array_equal(rw.cost, rp.cost) and np.array_equal(rw.status, rp.status)
        state = sw
        wrapped.commit()
        plain.commit()
        before = before or wrapped.balance_report()["steps"][0]
    steps = wrapped.balance_report()["steps"]
    assert before["work_imbalance"] == pytest.approx(5 * 12 * 2 / (6 * 12))
    assert before["moves"] > 0 and before["predicted_imbalance"] <= 1.1
    assert steps[1]["work_imbalance"] <= 1.1 + 1e-12          # measured in the next step
    owners = np.concatenate(COMM.allgather(wrapped.slot_global))
    assert np.array_equal(np.sort(owners), np.arange(2 * n))   # every point exactly once
    away = np.flatnonzero(wrapped.worker != COMM.rank)
    assert COMM.allreduce(len(away)) == steps[-1]["points_away_from_home"] > 0
    # a failing point worked on away from home: its message, at home
    gradients = np.zeros((n, 6))
    if COMM.rank == 0:
        gradients[away[0], 1] = -1.0
    (_, _, _, rw), (_, _, _, rp) = counter_step(wrapped, plain, gradients, state)
    assert np.array_equal(rw.status, rp.status) and rw.message == rp.message
    if COMM.rank == 0:
        assert rw.message == f"point at ({xy[away[0], 0]:.4g}, 0): negative" and rw.status[away[0]] == -1
    wrapped.rollback()
    plain.rollback()
    # a bug on the worker: RuntimeError on the home rank, after the exchange
    gradients = np.zeros((n, 6))
    if COMM.rank == 0:
        gradients[away[0], 2] = 99
    raised = ""
    try:
        wrapped.update(gradients, 1.0, state, np.zeros((n, 6)), np.zeros((n, 6, 6)), state.copy(), points=np.arange(n))
    except RuntimeError as error:
        raised = str(error)
    # (the worker skips the points after the bug, so the other rank's points there fail too)
    assert "ZeroDivisionError: a bug" in COMM.bcast(raised)
    wrapped.rollback()
    exported = wrapped.export_points(np.arange(n)[::-1])
    assert np.array_equal(exported["value"], plain.committed[::-1])
    assert np.array_equal(exported["zone"], plain.zone[::-1])
    wrapped.import_points(np.arange(n), {"zone": plain.zone, "value": plain.committed + 1.0})
    assert np.array_equal(wrapped.export_points(np.arange(n))["value"], plain.committed + 1.0)


@two_ranks
def test_passes_move_points_only_where_no_trial_state_is_lost(monkeypatch):
    """passes=True: points move at the start of an update by the last pass's costs, but only
    when every rank re-solves all its points in it, or nothing was solved since the commit: a
    point left out of a pass keeps a trial state on its worker, which a move would lose (its
    committed value would then come out wrong). Here the odd points are forced to change rank
    at every move; the results and the committed values are the unwrapped material's."""
    monkeypatch.setattr(balancing.material, "assign", forced_exchange)
    n = 12
    rng = np.random.default_rng(7 + COMM.rank)
    wrapped = balancing.BalancedMaterial(COMM, Counter, cost="work", passes=True)
    wrapped.threshold = 0.0                      # move at every chance, whatever the costs
    plain = Counter()
    for m in (wrapped, plain):
        m.set_zones(np.full(n, 5.0 if COMM.rank == 0 else 1.0))
        m.set_point_coordinates(np.column_stack([np.arange(n) + 100.0 * COMM.rank, np.zeros(n)]))
    state = wrapped.initial_state(n)
    plain.initial_state(n)

    def one_pass(points):
        gradients = np.zeros((n, 6))
        gradients[:, 0] = rng.normal(size=n)
        (fw, tw, sw, rw), (fp, tp, sp, rp) = counter_step(wrapped, plain, gradients, state, points)
        assert np.array_equal(fw[points], fp[points]) and np.array_equal(tw[points], tp[points])
        assert np.array_equal(sw, sp) and np.array_equal(rw.cost, rp.cost)
        return COMM.allreduce(int(np.count_nonzero(wrapped.worker != COMM.rank)))

    every, even = np.arange(n), np.arange(0, n, 2)
    assert one_pass(every) == 0                  # nothing measured yet
    assert one_pass(even) == 0                   # the odd points hold trial states: no move
    assert one_pass(every) == n                  # all re-solved: the odd points of both ranks move
    assert one_pass(even) == n                   # trial states again: they stay
    wrapped.commit()
    plain.commit()
    assert np.array_equal(wrapped.export_points(every)["value"], plain.committed)
    record = wrapped.balance_report()["steps"][0]
    assert record["moves"] == 0 and record["pass_moves"] == n and len(record["pass_imbalance"]) == 3
    assert one_pass(even) == 0                   # after a commit a partial pass may move: all home again
    wrapped.commit()
    plain.commit()
    assert np.array_equal(wrapped.export_points(every)["value"], plain.committed)
    assert wrapped.balance_report()["moves_total"] == 2 * n


# --- FEM x DEM on 2 ranks --------------------------------------------------------------------

def settings(**kw):
    from cosserat_fenicsx.materials.dem import CellOptions
    from cosserat_fenicsx.scenes.femdem_biaxial import FemDemSettings
    return FemDemSettings(**dict(dict(nx=2, ny=2, axial_strain=0.003, steps=3, weak_size=0.005,
                                      weak_friction_factor=0.7, cell=CellOptions(particles=50),
                                      solver_options={"pc_type": "redundant"}), **kw))


def forced_exchange(cost, worker, n_ranks, threshold):
    """Every point of odd global index moves to the next rank, every time: cells go away and
    come back whatever their cost."""
    new = np.array(worker)
    odd = np.arange(len(new)) % 2 == 1
    new[odd] = (new[odd] + 1) % n_ranks
    return new


def run(balance, on_step=None, every_commit=False, **kw):
    """every_commit: rebalance at every commit whatever the measured wall times (a threshold
    of 1 still depends on them: equal times would not move anything)."""
    from cosserat_fenicsx.scenes.femdem_biaxial import FemDemBiaxial
    test = FemDemBiaxial(COMM, settings(balance=balance, **kw), verbose=False)
    if every_commit:
        test.material.threshold = 0.0
    test.run(on_step)
    cb = test.gauss_points
    out = {name: test.global_order(values)[1] for name, values in
           (("flux", cb.flux_values), ("history", cb.state_old), ("gradients", cb.gradients))}
    rows = [{k: v for k, v in row.items() if k != "wall_time"} for row in test.history]
    return test, rows, out


def assert_identical(a, b):
    (_, rows_a, out_a), (_, rows_b, out_b) = a, b
    assert rows_a == rows_b                                # every history value, bit for bit
    if COMM.rank == 0:
        for key in out_a:
            assert np.array_equal(out_a[key], out_b[key]), key


@two_ranks
def test_balanced_run_is_bit_identical(monkeypatch):
    """Balance off, balance on with the greedy at threshold 1 (moves whenever any point
    helps), and a forced exchange of half the points at every commit: the same history rows
    (but wall times), fluxes, float history and gradients at every Gauss point, bit for bit;
    cells did move."""
    reference = run(False)
    greedy = run(True, balance_threshold=1.0)
    assert_identical(reference, greedy)
    monkeypatch.setattr(balancing.material, "assign", forced_exchange)
    forced = run(True, every_commit=True)
    assert_identical(reference, forced)
    report = forced[0].material.balance_report()
    assert report["moves_total"] == len(forced[0].history) * (COMM.allreduce(len(forced[0].points)) // 2)
    # on 2 ranks the odd points go away at odd commits and come back at even ones
    assert [r["points_away_from_home"] > 0 for r in report["steps"]] == [c % 2 == 1 for c in range(1, 5)]
    # the measured imbalance and the cell work of every rank are recorded per commit
    steps = greedy[0].material.balance_report()["steps"]
    assert len(steps) == len(greedy[0].history) and all(r["imbalance"] >= 1.0 for r in steps)
    assert all(len(r["work_seconds"]) == 2 for r in steps)
    assert greedy[0].material.balance_report()["moves_total"] >= 0
    # the resident state of every point can be fetched from its worker (checkpoints,
    # snapshots): the same cells as the unbalanced run's
    from demcell.state import CELL_FIELDS, PAIR_FIELDS, PARTICLE_FIELDS, unpack_states
    mine = reference[0].material.export_points(np.arange(len(reference[0].points)))
    theirs = forced[0].material.export_points(np.arange(len(forced[0].points)))
    assert mine.keys() == theirs.keys() and np.array_equal(mine["zone"], theirs["zone"])
    cells = list(zip(unpack_states(mine), unpack_states(theirs)))
    assert len(cells) == len(forced[0].points)
    for a, b in cells:     # the pair slots past n_pairs are scratch (they differ once a cell moved)
        assert all(np.array_equal(getattr(a, k), getattr(b, k)) for k in PARTICLE_FIELDS + CELL_FIELDS)
        assert all(np.array_equal(getattr(a, k)[:a.n_pairs], getattr(b, k)[:b.n_pairs]) for k in PAIR_FIELDS)


@two_ranks
def test_balancing_between_passes_is_bit_identical(monkeypatch):
    """The FEM x DEM biaxial balanced between Newton passes (passes=True), by the greedy at
    threshold 1 and by a forced exchange of half the points at every pass: the same results
    as without balancing, bit for bit; the points moved within the steps, not at commits."""
    reference = run(False)
    greedy = run(True, balance_threshold=1.0, balance_passes=True)
    assert_identical(reference, greedy)
    monkeypatch.setattr(balancing.material, "assign", forced_exchange)
    forced = run(True, every_commit=True, balance_passes=True)
    assert_identical(reference, forced)
    steps = forced[0].material.balance_report()["steps"]
    assert all(r["moves"] == 0 for r in steps)
    assert sum(r["pass_moves"] for r in steps) >= len(steps) * COMM.allreduce(len(forced[0].points)) // 2
    assert all(len(r["pass_imbalance"]) >= 1 for r in steps[1:])


@two_ranks
def test_failing_guest_cell_cuts_the_step_naming_the_point(monkeypatch):
    """Points exchanged at the first commit, then the cells a rank works on for the other
    get a budget of 5 DEM steps: phase 2's first step fails on the guest rank, is cut down to
    dt_min and the run stops on every rank with the message of the worker naming the
    point's coordinates."""
    from cosserat_fenicsx.stepping import LoadSteppingError
    monkeypatch.setattr(balancing.material, "assign", forced_exchange)
    guests = []

    def tighten(row):
        m = test.material
        if row["step"] == 1:
            mine = (m.slot_global >= m.home_offset[COMM.rank]) & (m.slot_global < m.home_offset[COMM.rank] + m.n_home)
            for slot in np.flatnonzero(~mine):
                cell = m.inner.cells[slot]
                cell.options = dataclasses.replace(cell.options, max_steps=5, relax_cap=None)
                guests.append(tuple(m.slot_xy[slot]))
            m.every = 10 ** 6                     # the cells stay where they are now

    from cosserat_fenicsx.scenes.femdem_biaxial import FemDemBiaxial
    # one DemCell per point (not the batched default): the test edits a guest cell's own options
    test = FemDemBiaxial(COMM, settings(balance=True, batched=False, dt_min_fraction=2.0 ** -2), verbose=False)
    test.material.threshold = 0.0      # the forced exchange at the first commit, whatever the wall times
    message = ""
    try:
        test.run(tighten)
    except LoadSteppingError as error:
        message = str(error)
    messages = COMM.allgather(message)
    assert messages[0] == messages[1], messages
    assert "did not relax within its step budget" in message and "max_steps = 5" in message, message
    everyone = [xy for g in COMM.allgather(guests) for xy in g]
    assert everyone and any(f"Gauss point at ({x:.4g}, {y:.4g})" in message for x, y in everyone), message
    assert len(test.history) == 1
