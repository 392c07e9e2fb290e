"""The Gauss-point material interface (constitutive.py, quadrature.py, snes.py):
rate-independent materials are asked only for the points whose gradients changed,
tangents on demand come from the Jacobian path only, commit / rollback reach the material
when the LoadStepper commits / cuts a step, per-point status and cost (PointReport), flags
and failures made collective over the ranks, and the FNORM/RNORM stopping test.

Every material here is linear elastic (its fluxes are bit-identical to those of
LinearElasticMaterial), instrumented: it keeps its own record of what it was asked (which
points, at which gradients, from which state) and the checks compare that record with what
the interface promises. Assertions that depend on rank-local data are made collective
(`assert_everywhere`) so that a failure on one rank fails the test on all ranks instead
of leaving the others waiting in the next test's collective calls."""
import re
import sys

import numpy as np
import pytest
from mpi4py import MPI

from cosserat_fenicsx import (CosseratProblem, ConstitutiveError, LinearElasticMaterial, LoadStepper,
                              LoadSteppingError, MicropolarElasticity, NewtonSolver, meshes)
from cosserat_fenicsx.constitutive import PointReport

COMM = MPI.COMM_WORLD
LAST_RANK = COMM.size - 1
ELASTIC = MicropolarElasticity(mu=1.0e8, lmbda=1.2e8, mu_c=0.4e8, l_c=0.02)


# --- scene ---------------------------------------------------------------------------------
def plate():
    return meshes.rectangle(COMM, 0.2, 0.1, 0.0125, "triangle")


def scene(material, mesh_data, loads=True, scale=None):
    """The plate of tests/test_quadrature_map.py: pulled and sheared, mixed Dirichlet / traction /
    couple conditions (loads=False: driven by the Dirichlet value on top only), every load
    scaled by scale(t) (default t)."""
    mesh, tags, names = mesh_data
    problem = CosseratProblem(mesh, tags, names, material=material)
    problem.add_dirichlet("bottom", "u1", 0.0)
    problem.add_dirichlet("bottom", "u2", 0.0)
    problem.add_dirichlet("bottom", "phi", 0.0)
    problem.add_dirichlet("top", "u1", lambda x: 1e-4 * np.sin(10 * x[0]), scale=scale)
    if loads:
        problem.add_traction("right", (2.0e5, -1.0e5), scale=scale)
        problem.set_body_force((0.0, -2.0e4), scale=scale)
        problem.add_surface_couple("left", 50.0, scale=scale)
        problem.set_body_couple(1.0e3, scale=scale)
    return problem


def reference(mesh_data, dt=0.25):
    """The plain LinearElasticMaterial solved on the same mesh object (same partition)."""
    problem = scene(LinearElasticMaterial(ELASTIC), mesh_data)
    LoadStepper(problem, NewtonSolver(problem), dt=dt, verbose=False).run()
    return problem


def relative_difference(a, b):
    scale = COMM.allreduce(float(np.abs(a).max(initial=0.0)), op=MPI.MAX)
    diff = COMM.allreduce(float(np.abs(a - b).max(initial=0.0)), op=MPI.MAX)
    assert scale > 1e-6
    return diff / scale


def assert_everywhere(ok, what):
    """Collective assertion: every rank fails together (no rank left waiting)."""
    oks = COMM.allgather(bool(ok))
    assert all(oks), f"{what} (per rank: {oks})"


def max_strain(problem, local=False):
    """Largest strain component of the converged fields (on this rank if local)."""
    value = float(np.abs(problem.gauss_points.gradients[:, :4]).max(initial=0.0))
    return value if local else COMM.allreduce(value, op=MPI.MAX)


# --- instrumented materials ------------------------------------------------------------------
class ProbeElastic(LinearElasticMaterial):
    """Linear elastic as a Gauss-point material, instrumented.

    History (float state): the gradients of the committed step. Resident state (what a DEM
    cell would hold, outside the float arrays): `at`, the gradients of each point's last
    update, and `base`, the committed gradients; commit() / rollback() move them like cells.
    `status_rule(material, points, gradients, state_old) -> (status, message)` and
    `tangent_rule(material, points) -> message` ("" = fine) inject flags and failures.
    Cost per point: 1 + (row % 5) per update, 0.5 per tangent."""
    state_names = ("eps11", "eps22", "eps12", "eps21", "kappa31", "kappa32")
    cost_unit = "test units"
    tangent_factor = 1.0      # tangent = factor * stiffness (1: Newton, else quasi-Newton)

    def __init__(self, elasticity, status_rule=None, tangent_rule=None):
        super().__init__(elasticity)
        self.status_rule, self.tangent_rule = status_rule, tangent_rule
        self.events = []       # shared with Recorder: ordered log of the calls
        self.gauss_points = None   # set by Recorder: lets commit/rollback look at the float history
        self.dt = None

    def initial_state(self, n_points):
        n = n_points
        self.at = np.full((n, 6), np.nan)
        self.at_committed = self.at.copy()
        self.base = np.zeros((n, 6))
        self.stale = np.zeros(n, dtype=bool)       # updated since its last tangent
        self.cost_acc, self.step_cost = np.zeros(n), np.zeros(n)
        self.last_status = np.zeros(n, dtype=np.int32)
        self.update_points = []                    # number of points per update call
        self.redundant = self.missed = self.history_mismatch = self.signature_errors = 0
        self.tangent_points = []
        self.tangent_not_stale = self.tangent_missed = 0
        self.commits = self.rollbacks = 0
        self.commit_after_history, self.rollback_after_history = [], []
        return np.zeros((n, self.state_size))

    # the update -----------------------------------------------------------------------------
    def update(self, gradients, dt, state_old, flux_out, tangent_out, state_new, points=None):
        n = len(gradients)
        if (points is not None) != self.rate_independent:
            self.signature_errors += 1
        given = np.arange(n) if points is None else np.asarray(points)
        asked = np.zeros(n, dtype=bool)
        asked[given] = True
        changed = (gradients != self.at).any(axis=1)     # NaN (never updated): changed
        self.redundant += int(np.count_nonzero(asked & ~changed))
        self.missed += int(np.count_nonzero(changed & ~asked))
        self.history_mismatch += int(np.count_nonzero((state_old[given] != self.base[given]).any(axis=1)))
        g = gradients[given]
        flux_out[given] = g @ self.stiffness.T           # only the rows asked for
        if not self.tangent_on_demand:
            tangent_out[given] = self.tangent_factor * self.stiffness
        state_new[given] = g
        self.at[given] = g
        self.stale[given] = True
        self.dt = dt
        status, message = np.zeros(len(given), dtype=np.int32), ""
        if self.status_rule is not None:
            status, message = self.status_rule(self, given, gradients, state_old)
        cost = 1.0 + (given % 5)
        self.cost_acc[given] += cost
        self.last_status[given] = status
        self.update_points.append(len(given))
        self.events.append(("update", len(given)))
        return PointReport(status=np.asarray(status, dtype=np.int32), cost=cost, message=message,
                           cost_unit=self.cost_unit)

    def tangent(self, points, tangent_out):
        points = np.asarray(points)
        self.events.append(("tangent", len(points)))
        asked = np.zeros(len(self.stale), dtype=bool)
        asked[points] = True
        self.tangent_not_stale += int(np.count_nonzero(~self.stale[points]))
        self.tangent_missed += int(np.count_nonzero(self.stale & ~asked))
        if self.tangent_rule is not None:
            message = self.tangent_rule(self, points)
            if message:
                raise ConstitutiveError(message)
        tangent_out[points] = self.tangent_factor * self.stiffness
        self.stale[points] = False
        cost = np.full(len(points), 0.5)
        self.cost_acc[points] += cost
        self.tangent_points.append(len(points))
        return PointReport(status=np.zeros(len(points), dtype=np.int32), cost=cost, cost_unit=self.cost_unit)

    def commit(self):
        self.events.append(("commit",))
        self.commits += 1
        if self.gauss_points is not None:   # called after the float history was committed
            self.commit_after_history.append(np.array_equal(self.gauss_points.state_old, self.gauss_points.state_new))
        self.at_committed = self.at.copy()
        self.base = np.where(np.isnan(self.at), self.base, self.at)
        self.step_cost = self.cost_acc.copy()
        self.cost_acc[:] = 0.0

    def rollback(self):
        self.events.append(("rollback",))
        self.rollbacks += 1
        if self.gauss_points is not None:   # called after the float history was restored
            self.rollback_after_history.append(np.array_equal(self.gauss_points.state_new, self.gauss_points.state_old))
        self.at = self.at_committed.copy()
        self.stale[:] = True   # the cells are back at the committed state: tangents must follow
        # work done stays counted until the next commit (QuadratureMap.cost)


class RateIndependent(ProbeElastic):
    rate_independent = True


class OnDemand(ProbeElastic):
    tangent_on_demand = True


class RateIndependentOnDemand(ProbeElastic):    # what DemMaterial declares
    rate_independent = True
    tangent_on_demand = True


class Plain(ProbeElastic):
    """The instrumented material with neither capability (the hooks only)."""


RI_ONLY = RateIndependent


class Recorder:
    """Logs, in the material's event list, the solver's solves and the problem's material
    hooks, and keeps the SolveInfos; `check_solve_start` / `check_solve_end` /
    `check_commit` are optional hooks for test-specific checks."""

    def __init__(self, problem, solver, material):
        self.problem, self.material = problem, material
        self.gauss_points = problem.gauss_points
        material.gauss_points = problem.gauss_points
        self.events = material.events
        self.infos = []
        self.committed_flux = self.gauss_points.flux_values.copy()
        self.check_solve_start = self.check_solve_end = self.check_commit = None
        residual, jacobian = problem.before_residual, problem.before_jacobian
        commit, solve = problem.commit, solver.solve

        def before_residual():
            self.events.append(("residual",))
            residual()

        def before_jacobian():
            self.events.append(("jacobian",))
            jacobian()

        def on_commit(dt):
            commit(dt)
            self.committed_flux = self.gauss_points.flux_values.copy()
            if self.check_commit:
                self.check_commit()

        def on_solve():
            if self.check_solve_start:
                self.check_solve_start()
            self.events.append(("solve",))
            info = solve()
            self.infos.append(info)
            self.events.append(("solved", info.converged))
            if self.check_solve_end:
                self.check_solve_end(info)
            return info

        problem.before_residual, problem.before_jacobian = before_residual, before_jacobian
        problem.commit, solver.solve = on_commit, on_solve

    def residual_updates(self):
        """Per solve, the number of points updated at each residual evaluation."""
        solves = []
        for event in self.events:
            if event[0] == "solve":
                solves.append([])
            elif event[0] == "residual":
                solves[-1].append(0)
            elif event[0] == "update":
                solves[-1][-1] += event[1]
        return solves

    def hooks_after_solves(self):
        """The material hook (commit / rollback) that followed each solve, in order."""
        out, pending = [], None
        for event in self.events:
            if event[0] == "solved":
                if pending is not None:
                    out.append((pending, None))
                pending = event[1]
            elif event[0] in ("commit", "rollback"):
                out.append((pending, event[0]))
                pending = None
        if pending is not None:
            out.append((pending, None))
        return out


def run(problem, material, solver=None, **stepper_args):
    solver = solver or NewtonSolver(problem)
    recorder = Recorder(problem, solver, material)
    stepper_args.setdefault("dt", 0.25)
    stepper = LoadStepper(problem, solver, verbose=False, **stepper_args)
    return stepper, recorder


# --- 1. rate-independent: fewer updates, same answer ----------------------------------------------
@pytest.mark.parametrize("kind", [RI_ONLY, RateIndependentOnDemand])
def test_rate_independent_skips_unchanged_points(kind):
    """Four load steps: the plain material's answer (1e-9), with fewer point updates: the
    first residual of steps 2-4 updates no point, no point is updated at unchanged
    gradients, no changed point is left out; the store's counters agree."""
    mesh_data = plate()
    ref = scene(LinearElasticMaterial(ELASTIC), mesh_data)
    ref_solver = NewtonSolver(ref)
    ref_residuals = []
    ref_before = ref.before_residual
    ref.before_residual = lambda: (ref_residuals.append(1), ref_before())
    LoadStepper(ref, ref_solver, dt=0.25, verbose=False).run()

    material = kind(ELASTIC)
    problem = scene(material, mesh_data)
    stepper, rec = run(problem, material, dt=0.25)
    stepper.run()
    n = problem.gauss_points.n_points
    assert len(stepper.records) == 4 and stepper.records[-1].cuts == 0

    assert relative_difference(ref.w.x.array, problem.w.x.array) <= 1e-9
    assert_everywhere(material.signature_errors == 0, "rate_independent material not given points=")
    solves = rec.residual_updates()
    assert len(solves) == 4
    # step 1: the points were never updated, all of them are; afterwards the first residual
    # of a step is at the committed fields: no point is updated
    assert_everywhere(solves[0][0] == n, f"first residual of step 1 updated {solves[0][0]} of {n} points")
    assert_everywhere(all(s[0] == 0 for s in solves[1:]),
                      f"first residual of steps 2.. updated {[s[0] for s in solves[1:]]} points")
    # no point asked twice at the same gradients, none that changed left out
    assert_everywhere(material.redundant == 0, f"{material.redundant} point updates at unchanged gradients")
    assert_everywhere(material.missed == 0, f"{material.missed} changed points not updated")
    total = sum(material.update_points)
    plain_total = n * len(ref_residuals)
    assert_everywhere(total < plain_total, f"{total} point updates, plain material {plain_total}")
    assert_everywhere(total <= plain_total - 3 * n, "the first residuals of steps 2-4 were not skipped")
    counters = problem.gauss_points.counters
    residuals = sum(len(s) for s in solves)
    assert_everywhere(counters["point_updates"] == total, f"counters {counters} vs material {total}")
    assert_everywhere(counters["points_unchanged"] == residuals * n - total, f"counters {counters}")


def test_rate_independent_points_are_the_changed_ones():
    """Driven by hand through the problem's hook: a uniform rotation changes eps12 and eps21
    only (u = 0: eps11 = eps22 = 0 exactly) -> every point; then a rotation on the nodes
    with x < 0.05 only -> the points of the cells touching them, and none else."""
    material = RateIndependentOnDemand(ELASTIC)
    problem = scene(material, plate())
    NewtonSolver(problem)      # builds the forms and the Gauss-point store
    cb = problem.gauss_points
    n = cb.n_points
    problem.before_residual()                      # never updated: every point
    phi_space, phi_map = problem.W.sub(1).collapse()
    phi_dofs = np.asarray(phi_map)
    problem.w.x.array[phi_dofs] += 1e-3
    problem.w.x.scatter_forward()
    problem.before_residual()
    assert_everywhere(not cb.gradients[:, :2].any() and cb.gradients[:, 2:4].all(), "eps12, eps21 only")
    assert_everywhere(material.update_points == [n, n], f"points per update {material.update_points}")
    before = cb.gradients.copy()
    x = phi_space.tabulate_dof_coordinates()
    problem.w.x.array[phi_dofs[x[:, 0] < 0.05]] += 1e-3
    problem.w.x.scatter_forward()
    problem.before_residual()
    changed = int(np.count_nonzero((cb.gradients != before).any(axis=1)))
    assert_everywhere(material.update_points[2:] == ([changed] if changed else []),
                      f"{material.update_points[2:]} updated, {changed} changed")
    assert 0 < COMM.allreduce(changed) < COMM.allreduce(n)
    assert_everywhere(material.redundant == 0 and material.missed == 0,
                      f"{material.redundant} redundant, {material.missed} missed")


@pytest.mark.parametrize("kind", [RI_ONLY, RateIndependentOnDemand])
def test_rate_independent_same_fields_update_nothing(kind):
    """The minimal case of the first residual of a load step: the fields did not change
    since the last update, so no point is updated (and nothing breaks)."""
    material = kind(ELASTIC)
    problem = scene(material, plate())
    NewtonSolver(problem)
    problem.before_residual()
    problem.before_residual()
    problem.before_jacobian()
    assert_everywhere(material.update_points == [problem.gauss_points.n_points], f"{material.update_points}")
    assert_everywhere(problem.gauss_points.counters["points_unchanged"] == problem.gauss_points.n_points,
                      f"counters {problem.gauss_points.counters}")


# --- 2. tangents on demand --------------------------------------------------------------------
@pytest.mark.parametrize("kind", [OnDemand, RateIndependentOnDemand])
def test_tangent_on_demand_from_jacobian_path_only(kind):
    """update() never writes a tangent: tangent() is called inside before_jacobian only, for
    exactly the points updated since their last tangent, and the answer is the plain one."""
    mesh_data = plate()
    ref = reference(mesh_data)
    material = kind(ELASTIC)          # update() never writes tangent_out
    problem = scene(material, mesh_data)
    stepper, rec = run(problem, material, dt=0.25)
    stepper.run()
    assert len(stepper.records) == 4

    assert relative_difference(ref.w.x.array, problem.w.x.array) <= 1e-9
    # every tangent call happens inside before_jacobian: the last hook entered before it is
    # the Jacobian one (not a residual, not an update)
    last, outside, tangent_calls, jacobians = None, 0, 0, 0
    for event in rec.events:
        if event[0] in ("residual", "jacobian", "update"):
            last = event[0]
            jacobians += event[0] == "jacobian"
        elif event[0] == "tangent":
            tangent_calls += 1
            outside += last != "jacobian"
            last = "tangent"      # two tangent calls in one Jacobian would also count
    assert_everywhere(tangent_calls >= len(stepper.records), f"only {tangent_calls} tangent calls")
    assert_everywhere(outside == 0, f"{outside} tangent calls outside the Jacobian path")
    assert_everywhere(tangent_calls <= jacobians, f"{tangent_calls} tangent calls, {jacobians} Jacobians")
    # exactly the points updated since their last tangent
    assert_everywhere(material.tangent_not_stale == 0,
                      f"{material.tangent_not_stale} tangents of points not updated since their last one")
    assert_everywhere(material.tangent_missed == 0,
                      f"{material.tangent_missed} points updated but left out of the tangent call")
    counted = problem.gauss_points.counters["point_tangents"]
    assert_everywhere(counted == sum(material.tangent_points), f"point_tangents {counted}")


# --- 3. commit / rollback reach the material with the LoadStepper -------------------------------------
def increment_limit(limit, rank=None):
    """status -1 (failed) where the strain increment from the committed history exceeds
    `limit` (on `rank` only, or every rank); the fluxes of the trial are written anyway."""
    def rule(material, points, gradients, state_old):
        increment = np.abs(gradients[points, :4] - state_old[points, :4]).max(axis=1, initial=0.0)
        status = np.zeros(len(points), dtype=np.int32)
        if rank is None or COMM.rank == rank:
            status[increment > limit] = -1
        failed = int(np.count_nonzero(status < 0))
        message = f"increment refused at {failed} point(s) on rank {COMM.rank}" if failed else ""
        return status, message
    return rule


@pytest.mark.parametrize("kind", [Plain, OnDemand, RateIndependentOnDemand, RI_ONLY])
def test_commit_and_rollback_follow_the_stepper(kind):
    """A step refused by negative statuses (after the material wrote its trial fluxes) is cut:
    commit() / rollback() follow each solve as the stepper decides, after the float history
    moved; the retry starts from the committed fluxes and state; same answer in the end."""
    mesh_data = plate()
    ref = reference(mesh_data)
    # loads are proportional to t: increments of dt * max_strain; dt = 0.75 is refused,
    # 0.25 and 0.375 are not (steps 0.25, cut 0.75 -> 0.375, then 0.375)
    material = kind(ELASTIC, status_rule=increment_limit(0.5 * max_strain(ref)))
    problem = scene(material, mesh_data)
    stepper, rec = run(problem, material, dt=0.25, dt_max=1.0, grow=4.0)
    cb = problem.gauss_points
    trial_differs, start_ok, function_ok = [], [], []

    def solve_start():
        start_ok.append(np.array_equal(cb.flux_values, rec.committed_flux))
        function_ok.append(np.array_equal(cb.flux.x.array.reshape(-1, 6)[cb.dofs], cb.flux_values))

    def solve_end(info):
        if not info.converged:   # what the rollback has to undo
            trial_differs.append(not np.array_equal(cb.flux_values, rec.committed_flux))

    rec.check_solve_start, rec.check_solve_end = solve_start, solve_end
    stepper.run()

    cuts = stepper.records[-1].cuts
    assert cuts >= 1 and stepper.records[-1].time == pytest.approx(1.0)
    assert relative_difference(ref.w.x.array, problem.w.x.array) <= 1e-8
    # the hooks reach the material exactly once per commit / cut, right after the solve
    hooks = rec.hooks_after_solves()
    expected = [(info.converged, "commit" if info.converged else "rollback") for info in rec.infos]
    assert_everywhere(hooks == expected, f"hooks after solves {hooks}")
    assert_everywhere(material.commits == len(stepper.records) and material.rollbacks == cuts,
                      f"{material.commits} commits, {material.rollbacks} rollbacks")
    assert_everywhere(all(material.commit_after_history) and all(material.rollback_after_history),
                      "material hook called before the float history was committed / restored")
    # after a rollback the fluxes (array and quadrature Function) are the committed ones
    assert COMM.allreduce(sum(trial_differs)) >= 1          # a failed trial had changed them
    assert_everywhere(all(start_ok), f"fluxes at the start of each solve committed: {start_ok}")
    assert_everywhere(all(function_ok), "flux Function differs from flux_values")
    # every update saw the committed history and matched the material's committed state
    assert_everywhere(material.history_mismatch == 0, f"{material.history_mismatch} updates from a stale state")
    if kind.rate_independent:
        # the retried step: its first residual is at the committed fields (nothing to do),
        # the next one updates the changed points again, from the committed state
        solves = rec.residual_updates()
        retried = [i + 1 for i, info in enumerate(rec.infos[:-1]) if not info.converged]
        n = cb.n_points
        after_commit = [i for i in retried if any(info.converged for info in rec.infos[:i])]
        assert after_commit      # a cut of a step after the first (step 1 was never committed)
        assert_everywhere(all(solves[i][0] == 0 for i in after_commit),
                          f"first residual after a rollback: {[solves[i][0] for i in after_commit]}")
        assert_everywhere(all(len(solves[i]) > 1 and solves[i][1] == n for i in retried),
                          f"second residual after a rollback: {[solves[i][:2] for i in retried]}")
        assert_everywhere(material.redundant == 0 and material.missed == 0,
                          f"{material.redundant} redundant, {material.missed} missed point updates")


class NaNTangentAboveLimit:
    """Mixin: the tangent of a point whose increment exceeds `limit` comes back NaN (how a
    local solver that broke down leaves it); the store turns it into a failure."""
    limit = np.inf

    def update(self, gradients, dt, state_old, flux_out, tangent_out, state_new, points=None):
        report = super().update(gradients, dt, state_old, flux_out, tangent_out, state_new, points=points)
        given = np.arange(len(gradients)) if points is None else np.asarray(points)
        increment = np.abs(gradients[given, :4] - state_old[given, :4]).max(axis=1, initial=0.0)
        tangent_out[given[increment > self.limit]] = np.nan
        return report


class PlainNaN(NaNTangentAboveLimit, Plain):
    pass


class RateIndependentNaN(NaNTangentAboveLimit, RateIndependent):
    pass


@pytest.mark.parametrize("kind", [PlainNaN, RateIndependentNaN])
def test_cut_back_recovers_from_non_finite_tangent(kind):
    """A failure signalled by a non-finite tangent: after the rollback the smaller step
    must start from the committed state, whether or not the material is rate independent."""
    mesh_data = plate()
    ref = reference(mesh_data)
    material = kind(ELASTIC)
    material.limit = 0.5 * max_strain(ref)
    problem = scene(material, mesh_data)
    stepper, rec = run(problem, material, dt=0.25, dt_max=1.0, grow=4.0, dt_min=1 / 64)
    stepper.run()
    assert stepper.records[-1].time == pytest.approx(1.0)
    assert stepper.records[-1].cuts == 1      # dt 0.75 -> 0.375 once, as for the plain material
    assert "non-finite" in next(info.failure for info in rec.infos if not info.converged)
    assert relative_difference(ref.w.x.array, problem.w.x.array) <= 1e-8


# --- 4. per-point status and cost -----------------------------------------------------------------
FLAG = "point lost every contact (test flag)"


def flag_on_rank_zero(material, points, gradients, state_old):
    status = np.zeros(len(points), dtype=np.int32)
    if COMM.rank == 0:
        status[(points % 7 == 0) & (np.abs(gradients[points]).max(axis=1) > 0)] = 1
    return status, (FLAG if (status > 0).any() else "")


@pytest.mark.parametrize("kind", [Plain, RateIndependentOnDemand])
def test_status_cost_and_collective_flags(kind):
    """Rank 0 flags some points (status 1): the run goes on uncut, every rank's SolveInfo.flags
    names it; status = the last reported status per point; cost = the reported costs
    (updates and tangents) accumulated since the last commit, step_cost = the last step's."""
    mesh_data = plate()
    ref = reference(mesh_data)
    material = kind(ELASTIC, status_rule=flag_on_rank_zero)
    problem = scene(material, mesh_data)
    stepper, rec = run(problem, material, dt=0.25)
    cb = problem.gauss_points
    cost_ok, step_cost_ok, status_ok, flag_local = [], [], [], []

    def solve_end(info):
        cost_ok.append(np.allclose(cb.cost, material.cost_acc, rtol=1e-14, atol=0))
        status_ok.append(np.array_equal(cb.status, material.last_status))
        flag_local.append(cb.flag_message)

    def commit():
        step_cost_ok.append(np.allclose(cb.step_cost, material.step_cost, rtol=1e-14, atol=0)
                            and not cb.cost.any() and (cb.step_cost > 0).all())

    rec.check_solve_end, rec.check_commit = solve_end, commit
    stepper.run()

    # a flag does not stop the run, nor cut a step
    assert len(stepper.records) == 4 and stepper.records[-1].cuts == 0
    assert relative_difference(ref.w.x.array, problem.w.x.array) <= 1e-9
    # the flag is rank 0's only, and every rank's SolveInfo names it
    assert_everywhere(all(info.flags == FLAG for info in rec.infos), f"flags {[i.flags for i in rec.infos]}")
    assert_everywhere(all(f == (FLAG if COMM.rank == 0 else "") for f in flag_local), f"local {flag_local}")
    flagged = COMM.allreduce(int(np.count_nonzero(cb.status > 0)))
    assert flagged == COMM.allreduce(int(np.count_nonzero(material.last_status > 0))) > 0
    # status: the last update's status of each point; cost: accumulated since the last
    # commit (updates and tangents), step_cost: that of the last converged step
    assert_everywhere(all(status_ok), "status differs from the last reported statuses")
    assert_everywhere(all(cost_ok), "cost differs from the accumulated reported costs")
    assert_everywhere(len(step_cost_ok) == 4 and all(step_cost_ok), f"step_cost after commits {step_cost_ok}")
    assert_everywhere(not cb.cost.any(), "cost not reset by the last commit")
    assert cb.cost_unit == ProbeElastic.cost_unit
    # the costs are per point: they vary over the points (1 + row % 5 per update)
    assert_everywhere(cb.step_cost.min() < cb.step_cost.max(), "step_cost uniform")



@pytest.mark.parametrize("kind", [Plain, RateIndependentOnDemand])
def test_flags_reported_in_a_step_without_load_change(kind):
    """Loads scaled by min(2t, 1): the step to t = 1 holds the load of t = 0.5, the fields
    are those of the converged step. The flagged points are still flagged there
    (SolveInfo.flags: a flagged Gauss point at the last iterate)."""
    material = kind(ELASTIC, status_rule=flag_on_rank_zero)
    problem = scene(material, plate(), scale=lambda t: min(2.0 * t, 1.0))
    # snes_atol 1e-10 (the default) is below this scene's round-off floor (~1.2e-10): a step
    # without load change would not converge at all, with any material (see the report)
    solver = NewtonSolver(problem, options={"snes_atol": 1e-6})
    stepper, rec = run(problem, material, solver=solver, dt=0.5)
    stepper.run()
    assert len(rec.infos) == 2 and all(info.converged for info in rec.infos)
    assert rec.infos[1].iterations == 0
    flagged = COMM.allreduce(int(np.count_nonzero(problem.gauss_points.status > 0)))
    assert flagged > 0                              # still flagged at the last iterate
    assert_everywhere(all(info.flags == FLAG for info in rec.infos), f"flags {[i.flags for i in rec.infos]}")


@pytest.mark.parametrize("kind", [Plain, RateIndependentOnDemand])
def test_negative_status_on_one_rank_cuts_every_rank(kind):
    """A negative status on the last rank only: the step is cut on every rank, named, and
    the half step converges to the plain answer."""
    mesh_data = plate()
    ref = reference(mesh_data)
    # the last rank refuses increments above 0.7 x its own largest strain at t = 1: dt = 1
    # is refused there only, dt = 0.5 is not
    limit = 0.7 * max_strain(ref, local=True)
    material = kind(ELASTIC, status_rule=increment_limit(limit, rank=LAST_RANK))
    problem = scene(material, mesh_data)
    stepper, rec = run(problem, material, dt=1.0)
    stepper.run()
    assert stepper.records[-1].time == pytest.approx(1.0)
    assert stepper.records[-1].cuts == 1
    assert relative_difference(ref.w.x.array, problem.w.x.array) <= 1e-8
    rollbacks = COMM.allgather(material.rollbacks)
    assert rollbacks == [1] * COMM.size                      # the cut reached every rank
    failures = [info.failure for info in rec.infos if not info.converged]
    assert len(failures) == 1
    assert re.fullmatch(rf"increment refused at [1-9]\d* point\(s\) on rank {LAST_RANK}", failures[0]), failures


@pytest.mark.parametrize("kind", [Plain, RateIndependentOnDemand])
def test_negative_status_everywhere_stops_with_message(kind):
    """The last rank refuses every loaded state: LoadSteppingError naming the message, every
    rank rolled back every attempt (no hang)."""
    def refuse(material, points, gradients, state_old):
        status = np.zeros(len(points), dtype=np.int32)
        if COMM.rank == LAST_RANK:
            status[np.abs(gradients[points]).max(axis=1) > 0] = -1
        return status, ("cell did not relax (test)" if (status < 0).any() else "")

    material = kind(ELASTIC, status_rule=refuse)
    problem = scene(material, plate())
    stepper, rec = run(problem, material, dt=0.5, dt_min=0.1)
    with pytest.raises(LoadSteppingError, match=r"cell did not relax \(test\)"):
        stepper.run()
    assert COMM.allgather(material.rollbacks) == [len(rec.infos)] * COMM.size
    assert len(rec.infos) >= 3 and not any(info.converged for info in rec.infos)
    assert_everywhere(np.isfinite(problem.w.x.array).all() and not problem.w.x.array.any(),
                      "fields not rolled back to the (zero) committed state")


# --- 5. a ConstitutiveError inside tangent() on rank 0 only ----------------------------------------------
def called_from(name):
    frame = sys._getframe(1)
    while frame is not None:
        if frame.f_code.co_name == name:
            return True
        frame = frame.f_back
    return False


class QuasiNewtonOnDemand(OnDemand):
    """Tangent 1.1 x stiffness: Newton needs several iterations, so tangents are asked
    from the solver's Jacobian callback too, not only before the first residual's lifting."""
    tangent_factor = 1.1


def tangent_failure(path, max_dt=None):
    """Rank 0 raises in tangent() when called through `path` ('jacobian' or
    '_assemble_residual', the first residual's lifting), while the step's dt > max_dt."""
    def rule(material, points):
        via = "jacobian" if called_from("jacobian") else "_assemble_residual" if called_from(
            "_assemble_residual") else "elsewhere"
        material.tangent_paths = getattr(material, "tangent_paths", []) + [via]
        if COMM.rank == 0 and via == path and (max_dt is None or material.dt > max_dt):
            return f"tangent of rank 0 failed (test, via {path})"
        return ""
    return rule


@pytest.mark.parametrize("path", ["jacobian", "_assemble_residual"])
def test_tangent_failure_on_rank_zero_is_collective(path):
    """ConstitutiveError in tangent() on rank 0 only, from the solver's Jacobian callback or
    from the first residual's lifting: every rank's solve fails with that message, every
    attempt is rolled back everywhere, LoadSteppingError names it (no hang)."""
    material = QuasiNewtonOnDemand(ELASTIC, tangent_rule=tangent_failure(path))
    problem = scene(material, plate())
    stepper, rec = run(problem, material, dt=0.5, dt_min=0.1)
    with pytest.raises(LoadSteppingError, match=rf"tangent of rank 0 failed \(test, via {path}\)"):
        stepper.run()
    # every rank saw every failed solve and rolled back as often
    assert COMM.allgather(material.rollbacks) == [len(rec.infos)] * COMM.size
    assert len(rec.infos) >= 3 and not any(info.converged for info in rec.infos)
    assert_everywhere(all(info.failure == f"tangent of rank 0 failed (test, via {path})" for info in rec.infos),
                      f"failures {[info.failure for info in rec.infos]}")
    assert_everywhere("elsewhere" not in material.tangent_paths, f"{set(material.tangent_paths)}")


class QuasiNewtonRateIndependentOnDemand(RateIndependentOnDemand):
    tangent_factor = 1.1


@pytest.mark.parametrize("kind", [QuasiNewtonOnDemand, QuasiNewtonRateIndependentOnDemand])
def test_tangent_failure_cut_recovers(kind):
    """Rank 0's tangent fails in the Jacobian of a later Newton iteration (after a
    successful update at a trial iterate) of every step with dt > 0.3: those steps are cut
    on every rank, the smaller ones converge to the plain material's answer. Step 1
    (dt 0.25) passes, so the cuts roll back to a committed state."""
    mesh_data = plate()
    ref = reference(mesh_data)
    material = kind(ELASTIC, tangent_rule=tangent_failure("jacobian", max_dt=0.3))
    problem = scene(material, mesh_data)
    stepper, rec = run(problem, material, dt=0.25, dt_max=1.0, grow=4.0, easy_iterations=100)
    stepper.run()
    assert stepper.records[-1].time == pytest.approx(1.0)
    cuts = stepper.records[-1].cuts
    assert cuts >= 2 and all(r.dt <= 0.3 for r in stepper.records)
    failures = [info.failure for info in rec.infos if not info.converged]
    assert failures == ["tangent of rank 0 failed (test, via jacobian)"] * cuts
    assert COMM.allgather(material.rollbacks) == [cuts] * COMM.size
    assert all(info.iterations >= 1 for info in rec.infos if not info.converged)   # not the first Jacobian
    assert relative_difference(ref.w.x.array, problem.w.x.array) <= 1e-8
    assert_everywhere("elsewhere" not in material.tangent_paths, f"{set(material.tangent_paths)}")
    assert_everywhere(material.history_mismatch == 0, f"{material.history_mismatch} updates from a stale state")
    if kind.rate_independent:   # after the rollback: nothing at the committed fields, no redundant update
        solves = rec.residual_updates()
        retried = [i + 1 for i, info in enumerate(rec.infos[:-1]) if not info.converged]
        assert_everywhere(all(solves[i][0] == 0 for i in retried), f"{[solves[i][0] for i in retried]}")
        assert_everywhere(material.redundant == 0 and material.missed == 0,
                          f"{material.redundant} redundant, {material.missed} missed point updates")


# --- 6. the FNORM/RNORM stopping test ----------------------------------------------------------------
class QuasiNewton(Plain):
    tangent_factor = 2.0      # the error halves per iteration: several iterations


BASIC = {"snes_linesearch_type": "basic"}    # one residual per iteration


def force_ratio(problem, solver):
    """FNORM/RNORM of the current fields, from a fresh assembly of the residual."""
    import dolfinx.fem.petsc
    from petsc4py import PETSc
    b = dolfinx.fem.petsc.assemble_vector(solver.residual_form)
    b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
    local = b.array_r.copy()
    b.destroy()
    rows = np.unique(np.concatenate([bc.dof_indices()[0] for bc in problem.bcs]))
    rows = rows[rows < len(local)]
    reactions = COMM.allreduce(float(np.sum(local[rows] ** 2)))
    free = COMM.allreduce(float(np.sum(local ** 2))) - reactions
    return np.sqrt(free / reactions)


def test_force_rtol_stops_at_the_first_ratio_below():
    """Quasi-Newton (tangent 2 x stiffness, basic line search: one residual per iteration):
    the solve stops at the first iteration >= 1 whose FNORM/RNORM is <= force_rtol; the
    reported ratio is that of the final fields; a looser force_rtol stops earlier on the
    same path."""
    mesh_data = plate()
    ref = scene(LinearElasticMaterial(ELASTIC), mesh_data)
    ref_solver = NewtonSolver(ref)
    ref.set_time(1.0)
    assert ref_solver.solve().converged
    histories = {}
    errors = {}
    for force_rtol in (1e-2, 1e-4):
        problem = scene(QuasiNewton(ELASTIC), mesh_data)
        solver = NewtonSolver(problem, options=BASIC, force_rtol=force_rtol)
        problem.set_time(1.0)
        info = solver.solve()
        ratios = info.force_ratios
        histories[force_rtol] = ratios
        assert info.converged and info.reason == "CONVERGED_FNORM_RELATIVE"
        assert len(ratios) == info.iterations + 1
        assert info.iterations >= 3
        assert ratios[-1] <= force_rtol                          # stopped once below ...
        assert all(r > force_rtol for r in ratios[1:-1])         # ... and not earlier
        assert ratios[-1] == pytest.approx(force_ratio(problem, solver), rel=1e-6)
        errors[force_rtol] = relative_difference(ref.w.x.array, problem.w.x.array)
        assert COMM.allgather(info.iterations) == [info.iterations] * COMM.size
    # the same iteration path: the loose tolerance stops at the first ratio of the tight
    # run below it
    loose, tight = histories[1e-2], histories[1e-4]
    first_below = next(i for i in range(1, len(tight)) if tight[i] <= 1e-2)
    assert len(loose) - 1 == first_below
    assert np.allclose(loose, tight[:len(loose)], rtol=1e-10)
    assert errors[1e-4] < 0.1 * errors[1e-2] < 1e-2     # the tighter test, the closer to Newton's answer


def test_force_rtol_needs_one_iteration():
    """At an equilibrium already (a second solve at the same load) the ratio before any
    iteration is below force_rtol: the solve still makes one Newton update."""
    problem = scene(QuasiNewton(ELASTIC), plate())
    solver = NewtonSolver(problem, options=BASIC, force_rtol=1e-3)
    problem.set_time(1.0)
    first = solver.solve()
    assert first.converged
    problem.commit(1.0)
    second = solver.solve()
    assert second.force_ratios[0] <= 1e-3 and second.force_ratios[0] == pytest.approx(
        first.force_ratios[-1], rel=1e-6)
    assert second.converged and second.iterations == 1
    assert second.force_ratios[-1] <= 1e-3


def test_force_rtol_displacement_driven_from_rest():
    """Driven by the top Dirichlet value only, from rest: at iteration 0 there is neither
    residual nor reaction; the test must wait for the first Newton update."""
    mesh_data = plate()
    problem = scene(LinearElasticMaterial(ELASTIC), mesh_data, loads=False)
    solver = NewtonSolver(problem, force_rtol=1e-6)
    problem.set_time(1.0)
    info = solver.solve()
    assert info.converged, f"{info.reason} after {info.iterations} iterations, ratios {info.force_ratios}"
    assert info.iterations >= 1 and info.force_ratios[-1] <= 1e-6


def test_probe_residual_repeats_the_solve_and_leaves_the_state():
    """The residual probed at the converged displacement gives the solve's last FNORM/RNORM
    bit for bit and the residual of the independent evaluation (force_ratio); probed at a
    perturbed displacement it moves by about the stiffness times the perturbation (a smooth
    material), and probing at x again restores x. Without force_rtol it is refused."""
    problem = scene(QuasiNewton(ELASTIC), plate())
    solver = NewtonSolver(problem, options=BASIC, force_rtol=1e-4)
    problem.set_time(1.0)
    info = solver.solve()
    assert info.converged
    x = solver.x.copy()
    r, ratio, reactions = solver.probe_residual(x)
    assert ratio == info.force_ratios[-1]
    assert ratio == pytest.approx(force_ratio(problem, solver), rel=1e-6)
    assert reactions > 0.0
    changes = []
    for delta in (1e-9, 1e-6):
        xp = x.copy()
        xp.array[:] *= 1.0 + delta * np.linspace(-1.0, 1.0, xp.array.size)
        rp = solver.probe_residual(xp)[0]
        changes.append(np.sqrt(COMM.allreduce(float(np.sum((rp - r) ** 2)))) / reactions)
    assert 0.0 < changes[0] < 1e-6 and changes[1] == pytest.approx(1e3 * changes[0], rel=1e-2)   # linear in delta
    r_again, ratio_again, _ = solver.probe_residual(x)
    assert ratio_again == ratio and np.array_equal(r_again, r)
    assert np.array_equal(solver.x.array, x.array)
    with pytest.raises(ValueError, match="force_rtol"):
        NewtonSolver(problem, options=BASIC).probe_residual(x)


@pytest.mark.parametrize("force_rtol", [0.0, -1e-3, float("nan"), float("inf")])
def test_invalid_force_rtol(force_rtol):
    problem = scene(LinearElasticMaterial(ELASTIC), plate())
    with pytest.raises(ValueError, match="force_rtol"):
        NewtonSolver(problem, force_rtol=force_rtol)


class Overshooting(Plain):
    tangent_factor = 0.45     # |1 - 1/0.45| = 1.2: the iteration diverges after the first update


def test_accept_rtol_ends_a_stagnating_solve_at_its_best_iterate():
    """A diverging iteration (tangent too soft) never reaches force_rtol; with accept_rtol
    above its best FNORM/RNORM the solve ends at that iterate, re-evaluated (the reported
    ratio is the one of the final fields), and says so; below it, the solve fails."""
    mesh_data = plate()
    for accept, expect in ((None, False), (1e-6, False), (10.0, True)):
        problem = scene(Overshooting(ELASTIC), mesh_data)
        solver = NewtonSolver(problem, options=dict(BASIC, snes_max_it=5), force_rtol=1e-9,
                              accept_rtol=accept)
        problem.set_time(1.0)
        info = solver.solve()
        ratios = info.force_ratios
        iterates = ratios[1:6]                    # after iteration 1 .. 5
        best = int(np.argmin(iterates))
        assert min(iterates) > 1e-3 and best < len(iterates) - 1     # never converging, best not last
        assert info.converged == expect and info.accepted == expect
        if expect:
            assert info.reason == "ACCEPTED_AT_STAGNATION" and len(ratios) == 7
            assert ratios[-1] == pytest.approx(iterates[best], rel=1e-9)      # re-evaluated best iterate
            assert ratios[-1] == pytest.approx(force_ratio(problem, solver), rel=1e-6)
    for bad in (1e-10, float("nan")):          # below force_rtol, or not a number
        with pytest.raises(ValueError, match="accept_rtol"):
            NewtonSolver(scene(Overshooting(ELASTIC), mesh_data), force_rtol=1e-9, accept_rtol=bad)
    with pytest.raises(ValueError, match="accept_rtol"):
        NewtonSolver(scene(Overshooting(ELASTIC), mesh_data), accept_rtol=1e-2)   # needs force_rtol


class TooStiff(Plain):
    tangent_factor = 40.0     # |1 - 1/40| = 0.975: converges, 2.5 % a step (a stagnating step)


class Stiffer(Plain):
    tangent_factor = 2.0      # |1 - 1/2| = 0.5: converges at a steady rate


def test_stagnation_its_ends_a_stagnating_solve_early():
    """With stagnation_its = k a solve whose best FNORM/RNORM (<= accept_rtol) gained less
    than 10 % in k iterations ends there at its best iterate, not at snes_max_it; a solve
    that keeps gaining more than that is left to converge."""
    mesh_data = plate()
    options = dict(BASIC, snes_max_it=25)
    # diverging after the first update: the best is iterate 1, nothing is gained after it
    problem = scene(Overshooting(ELASTIC), mesh_data)
    solver = NewtonSolver(problem, options=options, force_rtol=1e-9, accept_rtol=10.0, stagnation_its=2)
    problem.set_time(1.0)
    info = solver.solve()
    assert info.accepted and info.reason == "ACCEPTED_AT_STAGNATION" and info.iterations == 3
    assert info.force_ratios[-1] == pytest.approx(min(info.force_ratios[1:4]), rel=1e-9)
    # 2.5 % gained per iteration: 7 % in 3 iterations is stagnation; without the option the
    # same solve runs to the cap
    ratios = {}
    for k in (3, None):
        problem = scene(TooStiff(ELASTIC), mesh_data)
        solver = NewtonSolver(problem, options=options, force_rtol=1e-9, accept_rtol=10.0, stagnation_its=k)
        problem.set_time(1.0)
        info = solver.solve()
        assert info.accepted
        ratios[k] = info.force_ratios
        assert info.iterations == (25 if k is None else pytest.approx(5, abs=1)), info.force_ratios
    assert ratios[3][-1] > ratios[None][-1]        # it did stop before it had got as far
    # 50 % gained per iteration: never stagnation, converges to force_rtol
    problem = scene(Stiffer(ELASTIC), mesh_data)
    solver = NewtonSolver(problem, options=options, force_rtol=1e-4, accept_rtol=10.0, stagnation_its=1)
    problem.set_time(1.0)
    info = solver.solve()
    assert info.converged and not info.accepted and info.force_ratios[-1] <= 1e-4
    for bad, accept in ((0, 1e-2), (1.5, 1e-2), (3, None)):
        with pytest.raises(ValueError, match="stagnation_its"):
            NewtonSolver(scene(Plain(ELASTIC), mesh_data), force_rtol=1e-3, accept_rtol=accept, stagnation_its=bad)
