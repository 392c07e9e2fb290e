"""A plane-strain specimen compressed between smooth platens: what the biaxial scenes share.

Specimen and axes. A rectangle of width W (x, horizontal, lateral) and height H (y,
vertical, axial); plane strain. Tension is positive: the vertical stress and the axial
strain are negative in compression.

Boundary. The lateral faces carry the confining pressure p as the traction -p n, scaled by
the scene's `lateral_scale(t)`; the platens are smooth (no tangential force): the bottom has
u2 = 0, the top the uniform u2 = platen_displacement(t), u1 is free on both except at one pin
(bottom centre) that removes the rigid translation. The rotation (a micropolar scene) is free
everywhere: zero surface couple.

Imperfection. The cells whose centre lies in the square of side `weak_size` at the lower
left corner are zone 1 of the material (`set_zones`), the others zone 0; the scene's
material makes zone 1 weaker, so that the band starts there.

Run. Nominal load steps of 1 from t = 0 to t_end, cut back to dt_min_fraction (a step that
cannot be cut smaller raises stepping.LoadSteppingError); after every converged step a
history row (the scene's `row(record)`). A checkpoint (checkpoint.Checkpointer) saves and
restores the history and the Newton records with the scene's own state.

A scene derives from PlatenTest, builds its material and calls `build_specimen`,
`load_platens` and `use_solver` in that order; it supplies `platen_displacement(t)`,
`row(record)` and its measurements. Its settings `s` have width, height, degree_u,
degree_phi, weak_size and dt_min_fraction.
"""
import dolfinx.fem
import numpy as np
import ufl

from .. import compat
from ..checkpoint import stepper_keywords
from ..newton_history import RecordingSolver
from ..output import print0
from ..problem import CosseratProblem
from ..quadrature import gauss_point_coordinates
from ..stepping import LoadStepper

CELL_TYPES = ("triangle", "quadrilateral")     # the element shapes of the specimen's mesh


class PlatenTest:
    """The specimen, its platens and its run (see the module docstring)."""

    s = None                  # the scene's settings
    verbose = True

    # --- set-up ---------------------------------------------------------------------
    def build_specimen(self, comm, mesh, material, micropolar, weakened):
        """The problem on `mesh` ((mesh, facet_tags, boundaries) of meshes.rectangle) with
        `material`, its Gauss points (`points`, x y [m]), and the material's zones: the
        weak corner is zone 1 if `weakened`, else every point is zone 0. Returns the
        zone of every owned Gauss point."""
        s = self.s
        self.comm = comm
        self.mesh, facet_tags, boundaries = mesh
        self.problem = problem = CosseratProblem(self.mesh, facet_tags, boundaries, material=material,
                                                 micropolar=micropolar, degree_u=s.degree_u,
                                                 degree_phi=s.degree_phi)
        self.points = gauss_point_coordinates(self.mesh, problem.quadrature_degree)
        n_qp = len(compat.quadrature_points(self.mesh, problem.quadrature_degree)[1])
        centres = self.points.reshape(-1, n_qp, 2).mean(axis=1)   # whole cells are weakened
        weak = (centres[:, 0] < s.weak_size) & (centres[:, 1] < s.weak_size)
        zone = np.repeat(weak.astype(np.int64), n_qp) if weakened else np.zeros(len(self.points), int)
        material.set_zones(zone)
        self.n_weak_cells = comm.allreduce(int(weak.sum()) if weakened else 0)
        self._volume_form = dolfinx.fem.form(ufl.div(problem.displacement) * problem.dx)
        self.history = []
        return zone

    def load_platens(self, confining, lateral_scale):
        """The confining traction [the stress unit] on the lateral faces, scaled by
        lateral_scale(t), and the smooth platens with the pin."""
        s, problem = self.s, self.problem
        problem.add_traction("left", (confining, 0.0), scale=lateral_scale)     # t = sigma n, n = (-1, 0)
        problem.add_traction("right", (-confining, 0.0), scale=lateral_scale)
        problem.add_dirichlet("bottom", "u2", 0.0)
        problem.add_dirichlet("top", "u2", 1.0, scale=self.platen_displacement)
        problem.add_point_dirichlet((0.5 * s.width, 0.0), "u1", 0.0)

    def use_solver(self, newton, t_end):
        """Run with the NewtonSolver `newton` (its solves recorded in `solver.infos`) from
        t = 0 to `t_end` nominal steps."""
        self.solver = RecordingSolver(newton)
        self.t_end = float(t_end)

    # --- what the scene supplies ------------------------------------------------------
    def platen_displacement(self, t):
        """Vertical displacement of the top platen at pseudo-time t [m]."""
        raise NotImplementedError

    def row(self, record):
        """The history row (a dict with step and time) of a converged step (stepping.StepRecord)."""
        raise NotImplementedError

    def after_step(self):
        """Called after every converged step's row is recorded (nothing by default)."""

    # --- measurements ---------------------------------------------------------------
    @property
    def gauss_points(self):
        """The Gauss-point store of the material (quadrature.QuadratureMap)."""
        return self.problem.gauss_points

    def state(self, name):
        """Committed state variable `name` of every owned Gauss point."""
        return self.gauss_points.state_old[:, self.material.state_index[name]]

    def vertical_reaction(self):
        """Force of the top platen per unit thickness, negative in compression."""
        return self.problem.reaction("top", "u2")

    def vertical_stress(self):
        """Platen reaction / width, negative in compression."""
        return self.vertical_reaction() / self.s.width

    def volumetric_strain(self):
        """Mean of tr(eps) over the specimen [-] (small strain)."""
        local = dolfinx.fem.assemble_scalar(self._volume_form)
        return self.comm.allreduce(local) / (self.s.width * self.s.height)

    # --- checkpoint and restart (checkpoint.py) ------------------------------------------
    def checkpoint_state(self):
        """(per-point arrays, run state) beyond the fields and the Gauss-point history."""
        return {}, {"history": self.history, "infos": self.solver.infos}

    def restore_state(self, per_point, run_state):
        self.history = list(run_state["history"])
        self.solver.infos = list(run_state["infos"])

    # --- run --------------------------------------------------------------------------
    def run(self, on_step=None, checkpoint=None):
        """The load steps; `on_step(row)` after every converged step. checkpoint: a
        checkpoint.Checkpointer (writes as due, stops at its stop_after, continues from the
        checkpoint it restored). Raises LoadSteppingError (naming the cause) when a step
        cannot be cut small enough."""

        def record(step):
            row = self.row(step)
            self.history.append(row)
            if on_step is not None:
                on_step(row)
            self.after_step()

        self.stepper = LoadStepper(self.problem, self.solver, t_end=self.t_end, dt=1.0,
                                   dt_min=self.s.dt_min_fraction, dt_max=1.0, on_step=record,
                                   easy_iterations=8, verbose=self.verbose, **stepper_keywords(checkpoint))
        self.records = self.stepper.run()
        return self.history

    def log(self, text):
        if self.verbose:
            print0(self.comm, text)
