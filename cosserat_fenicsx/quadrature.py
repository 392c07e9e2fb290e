"""The Gauss-point data store and evaluator of a material (`QuadratureMap`).

Strain and curvature are evaluated at the quadrature points of the cells this rank owns
(dolfinx 0.5 cannot interpolate an Expression into a quadrature space, so the Expression
is evaluated and the array written), the material updates the points, and stress,
couple stress and tangent are written into quadrature Functions that the residual and
Jacobian forms use. The quadrature degree of these spaces is the degree of the forms'
measure, so the forms read exactly the values the material produced.

Which points are updated when (docs/reference/quadrature_map.md):

* residual: every point, or, for a `rate_independent` material, the points whose
  gradients differ from those of their last update (bitwise);
* Jacobian: a `tangent_on_demand` material computes the tangents of the points updated
  since their last tangent, then the tangent Function is written (so is it before the
  Dirichlet lifting of the first residual of a load step, which reads the tangent; at that
  residual the points are the committed ones and the Jacobian that follows needs exactly
  these tangents); any other material's tangent comes with its update, as before;
* commit (load step converged): trial history -> committed, then `material.commit()`;
  rollback (step cut): committed -> trial, `material.rollback()`, and the fluxes and the
  "last update" gradients go back to the committed ones.
"""
import time

import dolfinx.fem
import numpy as np
import ufl

from . import compat
from .constitutive import ConstitutiveError, STATUS_OK
from .kinematics import stress_tensor, couple_stress_vector


def gauss_point_coordinates(mesh, degree):
    """(x, y) [m] of the quadrature points of degree `degree` of the cells this rank owns,
    in the row order of a QuadratureMap (point p of owned cell c is row c * n_qp + p).
    Needs no store: a scene that places zones by position calls it before the store is
    built."""
    points, _ = compat.quadrature_points(mesh, degree)
    expr = dolfinx.fem.Expression(ufl.SpatialCoordinate(mesh), points)
    cells = np.arange(compat.num_owned_cells(mesh), dtype=np.int32)
    return compat.eval_expression(expr, mesh, cells).reshape(-1, mesh.geometry.dim)[:, :2]


class QuadratureMap:
    """The Gauss-point data store of one material and its evaluator: the quadrature fields
    the forms read, the committed/trial history, the per-point status and cost arrays.
    Rows: the Gauss points of the cells this rank owns (`coordinates` gives their x, y).

    gradients (n, 6)  gradients of the last evaluation (kinematics.GRADIENT_NAMES)
    flux_values (n, 6), tangent_values (n, 6, 6)  current fluxes and tangents
    state_old, state_new (n, state_size)  committed and trial float history
    status  (n,) int  status of the last update of each point (0 ok, > 0 flagged)
    cost    (n,)      work spent on each point since the last commit (material's unit)
    step_cost (n,)    the same for the last converged step (what a load balancer reads)
    timers  wall seconds in gradient evaluation, material update, material tangent
    counters point updates, points left out as unchanged, point tangents
    """

    def __init__(self, mesh, material, gradient_ufl, degree):
        self.mesh = mesh
        self.material = material
        self.degree = degree
        nf = material.flux_size
        self.flux_space = compat.function_space(mesh, compat.quadrature_element(mesh, degree, nf))
        self.tangent_space = compat.function_space(mesh, compat.quadrature_element(mesh, degree, nf * nf))
        self.flux = dolfinx.fem.Function(self.flux_space, name="flux")
        self.tangent = dolfinx.fem.Function(self.tangent_space, name="tangent")
        points, self.weights = compat.quadrature_points(mesh, degree)
        self.n_qp = points.shape[0]
        self.cells = np.arange(compat.num_owned_cells(mesh), dtype=np.int32)
        self.expression = dolfinx.fem.Expression(gradient_ufl, points)
        # point p of owned cell c -> row of the flat Gauss-point arrays
        self.dofs = compat.cell_dofs(self.flux_space, len(self.cells)).reshape(-1)
        n = self.n_points
        self.gradients = np.zeros((n, material.gradient_size))
        self.tangent_values = np.zeros((n, nf, nf))
        self.state_old = material.initial_state(n)
        self.flux_values = np.array(material.initial_fluxes(n), dtype=np.float64).reshape(n, nf)
        self.state_new = self.state_old.copy()
        self.time_step = 0.0
        self.status = np.zeros(n, dtype=np.int32)
        self.cost = np.zeros(n)
        self.step_cost = np.zeros(n)
        self.cost_unit = ""
        self.flag_message = ""     # the message of a flagged (usable) point of the last update
        self.timers = {"gradients": 0.0, "update": 0.0, "tangent": 0.0}
        self.counters = {"point_updates": 0, "points_unchanged": 0, "point_tangents": 0}
        # gradients each point was last updated with (NaN: never), and their committed copy
        self._updated_at = np.full_like(self.gradients, np.nan)
        self._committed_at = self._updated_at.copy()
        self._flux_committed = self.flux_values.copy()
        self._tangent_committed = self.tangent_values.copy()
        self._tangent_stale = np.ones(n, dtype=bool)
        self._stale_committed = self._tangent_stale.copy()
        self._status_committed = self.status.copy()
        self._coordinates = None
        self.flux.x.array.reshape(-1, nf)[self.dofs] = self.flux_values

    @property
    def n_points(self):
        return len(self.cells) * self.n_qp

    @property
    def coordinates(self):
        """(n_points, 2) x, y [m] of the rows (gauss_point_coordinates), computed once."""
        if self._coordinates is None:
            self._coordinates = gauss_point_coordinates(self.mesh, self.degree)
        return self._coordinates

    # --- UFL views used by the forms -----------------------------------------------
    def stress(self):
        return stress_tensor(self.flux)

    def couple_stress(self):
        return couple_stress_vector(self.flux)

    def tangent_matrix(self):
        n = self.material.flux_size
        return ufl.as_matrix([[self.tangent[n * i + j] for j in range(n)] for i in range(n)])

    # --- the update ------------------------------------------------------------------
    def evaluate_gradients(self):
        start = time.perf_counter()
        values = compat.eval_expression(self.expression, self.mesh, self.cells)
        self.gradients[:] = values.reshape(self.n_points, -1)
        self.timers["gradients"] += time.perf_counter() - start
        return self.gradients

    def update(self):
        """Update the Gauss points from the current fields (see the module docstring).
        Raises ConstitutiveError on this rank only; the caller makes the failure
        collective."""
        self.evaluate_gradients()
        m = self.material
        start = time.perf_counter()
        points = None          # every point
        if m.rate_independent:
            points = np.flatnonzero((self.gradients != self._updated_at).any(axis=1))
            self.counters["points_unchanged"] += self.n_points - len(points)
        report = None
        # a collective material is called on every rank, even one with nothing to update
        if points is None or len(points) or m.collective:
            report = m.update(self.gradients, self.time_step, self.state_old, self.flux_values,
                              self.tangent_values, self.state_new, points=points)
        self.timers["update"] += time.perf_counter() - start
        rows = slice(None) if points is None else points
        self.counters["point_updates"] += self.n_points if points is None else len(points)
        self._record(rows, report)
        flux = self.flux_values[rows]
        finite = np.isfinite(flux).all(axis=1)
        if not m.tangent_on_demand:
            finite &= np.isfinite(self.tangent_values[rows]).all(axis=(1, 2))
        if not finite.all():
            raise ConstitutiveError(f"material returned non-finite stress or tangent at "
                                    f"{int(np.count_nonzero(~finite))} Gauss point(s)")
        self._updated_at[rows] = self.gradients[rows]
        self._tangent_stale[rows] = True
        nf = m.flux_size
        self.flux.x.array.reshape(-1, nf)[self.dofs] = self.flux_values
        if not m.tangent_on_demand:
            self._write_tangent()

    def update_tangent(self):
        """Before a Jacobian assembly (and before the Dirichlet lifting of the first
        residual of a load step): a tangent_on_demand material computes the tangents of the
        points updated since their last one and the tangent Function is written. The
        tangent of any other material came with its update and is written already."""
        m = self.material
        if not m.tangent_on_demand:
            return
        points = np.flatnonzero(self._tangent_stale)
        if len(points) or m.collective:     # a collective material is called on every rank
            start = time.perf_counter()
            report = m.tangent(points, self.tangent_values)
            self.timers["tangent"] += time.perf_counter() - start
            self.counters["point_tangents"] += len(points)
            self._record(points, report, statuses=False)
            if not np.isfinite(self.tangent_values[points]).all():
                raise ConstitutiveError("material returned a non-finite tangent at "
                                        f"{len(points)} Gauss point(s)")
            self._tangent_stale[:] = False
        self._write_tangent()

    def invalidate_tangents(self):
        """Every point's tangent is computed again at the next update_tangent (after the
        material's tangent operator was changed)."""
        self._tangent_stale[:] = True

    def _write_tangent(self):
        nf = self.material.flux_size
        self.tangent.x.array.reshape(-1, nf * nf)[self.dofs] = self.tangent_values.reshape(-1, nf * nf)

    def _record(self, points, report, statuses=True):
        """Keep the per-point status and cost of a report; a failed point raises."""
        if report is None:
            if statuses:
                self.status[points] = STATUS_OK
                self._keep_flag("")
            return
        if report.cost_unit:
            self.cost_unit = report.cost_unit
        self.cost[points] += report.cost
        if statuses:
            self.status[points] = report.status
            self._keep_flag(report.message if (np.asarray(report.status) > 0).any() else "")
        failed = np.flatnonzero(np.asarray(report.status) < 0)
        if failed.size:
            rows = np.arange(self.n_points)[points]
            raise ConstitutiveError(report.message or f"Gauss point update failed at {failed.size} point(s) "
                                    f"(first: local point {int(rows[failed[0]])})")

    def _keep_flag(self, message):
        """flag_message names a flagged point as long as one is flagged (status > 0)."""
        if not (self.status > 0).any():
            self.flag_message = ""
        elif message:
            self.flag_message = message

    def commit(self):
        self.state_old[:] = self.state_new
        self.material.commit()
        self._committed_at[:] = self._updated_at
        self._flux_committed[:] = self.flux_values
        self._tangent_committed[:] = self.tangent_values
        self._stale_committed[:] = self._tangent_stale
        self._status_committed[:] = self.status
        self.step_cost[:] = self.cost
        self.cost[:] = 0.0

    def rollback(self):
        self.state_new[:] = self.state_old
        self.material.rollback()
        self._updated_at[:] = self._committed_at
        self.flux_values[:] = self._flux_committed
        # the tangents computed at the committed state stay valid: the points are there again
        self.tangent_values[:] = self._tangent_committed
        self._tangent_stale[:] = self._stale_committed
        self.status[:] = self._status_committed
        self._keep_flag("")
        nf = self.material.flux_size
        self.flux.x.array.reshape(-1, nf)[self.dofs] = self.flux_values
        self._write_tangent()

    # --- checkpoint / restart (checkpoint.py) ---------------------------------------------
    def committed_arrays(self):
        """The committed per-point arrays (between load steps), each (n_points, k): float
        history, fluxes, tangents, stale-tangent flags, statuses, the gradients of the last
        update (NaN: never) and the work of the last step. With these (and the material's
        resident state) a run continues exactly as it would have."""
        n = self.n_points
        return {"history": self.state_old, "flux": self._flux_committed,
                "tangent": self._tangent_committed.reshape(n, -1),
                "tangent_stale": self._stale_committed.reshape(n, 1).astype(np.float64),
                "status": self._status_committed.reshape(n, 1).astype(np.float64),
                "updated_at": self._committed_at, "step_cost": self.step_cost.reshape(n, 1)}

    def restore_committed(self, arrays):
        """Set the committed per-point arrays (committed_arrays' names and shapes, rows in
        this rank's point order) and return to them as after a cut-back."""
        n = self.n_points
        self.state_old[:] = arrays["history"]
        self._flux_committed[:] = arrays["flux"]
        self._tangent_committed[:] = np.asarray(arrays["tangent"]).reshape(self._tangent_committed.shape)
        self._stale_committed[:] = np.asarray(arrays["tangent_stale"]).reshape(n) != 0
        self._status_committed[:] = np.asarray(arrays["status"]).reshape(n)
        self._committed_at[:] = arrays["updated_at"]
        self.step_cost[:] = np.asarray(arrays["step_cost"]).reshape(n)
        self.cost[:] = 0.0
        self.rollback()

    def cell_average(self, values):
        """Quadrature-weighted average per owned cell of a (n_points, k) array."""
        v = values.reshape(len(self.cells), self.n_qp, -1)
        return np.einsum("cqk,q->ck", v, self.weights) / self.weights.sum()
