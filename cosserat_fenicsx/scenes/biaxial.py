"""The plane-strain biaxial test of thesis 004 (Appendix A.2, section 6.2; spec 7.2 [REC]).

One scene shared by demos/biaxial.py, the tests and the benchmarks, so that all of them
compute the same boundary-value problem.

Specimen and axes. A rectangle of width W (x, horizontal, the thesis e2 / confining
direction) and height H (y, vertical, the thesis e1 / axial direction); plane strain in
e3 (total eps33 = 0, sig33 from the model, A.4). Tension is positive: the "vertical
stress" is negative in compression (thesis sig11).

Loading (the thesis gives only the confining pressure, 100 kN/m^2, section 6.1.2; the rest
is the [REC] model of spec 7.2):

* Phase 1, consolidation (pseudo-time 0..n1): the fluid pressure p acts as the traction
  -p n on the left and right faces, ramped linearly. The top platen moves to the height at
  which it carries the same vertical traction -p: that displacement is the plane-strain
  consolidation strain of the material point (material_point.consolidate with eps33 = 0,
  the same n1 steps), because consolidation under pressure on all faces is homogeneous.
  (A platen cannot be a traction boundary first and a displacement boundary later in one
  set of forms; `vertical_stress` at the end of phase 1 shows that it carries -p.)
* Phase 2, compression (pseudo-time n1..n1+n2): the top platen moves down by
  axial_strain * H in n2 equal steps, the lateral pressure is kept.
* Platens smooth (no tangential force, as the particle model's walls, section 7.3.1): the
  bottom has u2 = 0, the top a uniform u2, u1 is free on both except at one pin (bottom
  centre) that removes the rigid translation. The rotation is free everywhere (zero
  surface couple), also in phase 1.
* Imperfection: a square of side `weak_size` at the lower left corner has beta0 and
  beta* multiplied by `weak_beta_factor` (less friction: it yields first and triggers the
  band, "a specific position, which is weakened for the simulation", section 6.2.1).

Time and viscosity. One nominal load step is `step_time` of physical time (default 1 s,
cut-backs halve it); only the Perzyna law (2.81) sees physical time, so the scene gives the
material eta / step_time and the solver works in nominal steps. A study of the time step
at a fixed loading rate keeps steps x step_time constant. The Perzyna time (2.81) of this
scene is eta = 0.1 s, not the 1e-4 s of the material-point driver: with 1e-4 s the band forms by a snap (the platen force drops
by several per cent within a platen displacement of 1e-5 H) that displacement control
cannot follow, and the global Newton stalls at dt -> 0 (measured; docs/biaxial.md). With
0.1 s the overstress sigma_ref eta Lambda stays about 1-2 % of the stress in the band and
under 0.3 % before the peak; eta, sigma_ref and r are regularisation devices, not
material data (thesis footnote to 3.32). eta is an option.
"""
from dataclasses import dataclass, field
import math
import time

import dolfinx.fem
import numpy as np
import ufl

from .. import compat, meshes
from ..checkpoint import stepper_keywords
from ..constitutive import Constitutive
from ..output import print0
from ..problem import CosseratProblem
from ..quadrature import gauss_point_coordinates
from ..shear_band import fit_band_collective, strain_norm
from ..snes import NewtonSolver
from ..stepping import LoadStepper
from ..validation import AXIAL_STRAIN, COUNT, FRACTION, NON_NEGATIVE, POSITIVE, InputError, Range, check


@dataclass
class BiaxialSettings:
    """Geometry, loading, discretisation and material of one biaxial run (SI units)."""
    width: float = 0.05               # W [m]
    height: float = 0.10              # H [m]
    confining: float = 100e3          # p [Pa], section 6.1.2
    axial_strain: float = 0.08        # platen displacement / H in phase 2 [-]
    consolidation_steps: int = 5      # n1
    steps: int = 80                   # n2
    cell_size: float = 2.0e-3         # [m]
    cell_type: str = "triangle"
    degree_u: int = 2                 # Taylor-Hood P2 / P1 (section 3.2)
    degree_phi: int = 1
    micropolar: bool = True           # False: Cauchy continuum, no rotation field
    weak_size: float = 5.0e-3         # side of the weakened square [m] (0: none)
    weak_beta_factor: float = 0.8     # beta0, beta* of the weakened zone relative to the rest
    eta: float = 0.1                  # Perzyna time [s] (2.81), see the module docstring
    step_time: float = 1.0            # physical time of one nominal step [s]
    material: dict = field(default_factory=dict)   # further EhlersMaterial keyword overrides
    solver_options: dict = field(default_factory=dict)
    dt_min_fraction: float = 2.0 ** -10   # smallest step after cut-backs, in nominal steps

    def check(self):
        """Every setting in range and the material overrides valid (InputError, a
        ValueError, naming the setting), before any mesh, form or kernel exists."""
        for name in ("width", "height", "confining", "cell_size", "step_time"):
            check(f"biaxial: {name}", getattr(self, name), POSITIVE)
        check("biaxial: eta", self.eta, NON_NEGATIVE)      # 0: rate-independent
        check("biaxial: axial_strain", self.axial_strain, AXIAL_STRAIN)
        for name in ("consolidation_steps", "steps"):
            check(f"biaxial: {name}", getattr(self, name), COUNT)
        check("biaxial: weak_size", self.weak_size, Range(0.0, min(self.width, self.height), high_open=True))
        check("biaxial: weak_beta_factor", self.weak_beta_factor, FRACTION)
        check("biaxial: dt_min_fraction", self.dt_min_fraction, FRACTION)
        nx, _ = meshes.rectangle_divisions(self.width, self.height, self.cell_size)
        meshes.check_node_at_centre(nx, self.degree_u)
        from ..materials.ehlers.parameters import hostun   # no Numba: the parameters only
        try:
            used = hostun(**dict(self.material, eta=self.material.get("eta", self.eta) / self.step_time))
        except ValueError as error:
            raise InputError(f"biaxial: {error}") from None
        if self.micropolar and not used.mu_c > 0:
            # no stiffness couples the rotation to the displacement: the Newton matrix is singular
            raise InputError("biaxial: mu_c = 0 leaves the micropolar rotation without stiffness; give mu_c > 0 "
                             "(--mu-c, or in the parameter file: a homogeneous identification cannot see it) or "
                             "run the classical continuum (--classical)")


class ZonedMaterial(Constitutive):
    """Several materials with the same state layout, each on its own set of Gauss points.

    `zone` (n_points,) gives the index of the material of each point; it must be set (by
    set_zones) before the Gauss-point store allocates the history. The update of each zone is the
    update of its material on the zone's rows, so the partition of the work follows the
    mesh partition as for a single material. `kernel_time` accumulates the wall time of
    the material updates (the profile benchmark reads it)."""

    def __init__(self, materials):
        self.materials = list(materials)
        names = {tuple(m.state_names) for m in self.materials}
        if len(names) != 1:
            raise ValueError("ZonedMaterial: all materials must share one state layout")
        self.state_names = self.materials[0].state_names
        self.zone = None
        self.kernel_time = 0.0
        self.kernel_calls = 0

    def set_zones(self, zone):
        zone = np.asarray(zone, dtype=np.int64)
        if zone.size and (zone.min() < 0 or zone.max() >= len(self.materials)):
            raise ValueError("ZonedMaterial: zone index out of range")
        self.zone = zone
        self._rows = [np.flatnonzero(zone == k) for k in range(len(self.materials))]

    def initial_state(self, n_points):
        if self.zone is None or len(self.zone) != n_points:
            raise RuntimeError("ZonedMaterial: set_zones(zone) with one entry per Gauss point first")
        state = np.empty((n_points, len(self.state_names)))
        for material, rows in zip(self.materials, self._rows):
            state[rows] = material.initial_state(len(rows))
        return state

    def update(self, gradients, dt, state_old, flux_out, tangent_out, state_new):
        start = time.perf_counter()
        if len(self.materials) == 1:
            self.materials[0].update(gradients, dt, state_old, flux_out, tangent_out, state_new)
        else:
            for material, rows in zip(self.materials, self._rows):
                if len(rows) == 0:
                    continue
                f, t, s = flux_out[rows], tangent_out[rows], state_new[rows]
                material.update(gradients[rows], dt, state_old[rows], f, t, s)
                flux_out[rows], tangent_out[rows], state_new[rows] = f, t, s
        self.kernel_time += time.perf_counter() - start
        self.kernel_calls += 1


class RecordingSolver:
    """A NewtonSolver that keeps the SolveInfo of every solve (residual histories)."""

    def __init__(self, solver):
        self.solver = solver
        self.infos = []

    def solve(self):
        info = self.solver.solve()
        self.infos.append(info)
        return info

    def infos_converged(self):
        return [info for info in self.infos if info.converged]


def convergence_orders(residuals, floor=None):
    """Observed orders q_k = log(r_k+1 / r_k) / log(r_k / r_k-1) of one Newton solve.

    r_0 is left out: it is the residual of the new load increment at the last converged
    state, the first iteration moves to the new load and says nothing about the rate.
    Residuals below `floor` (default 1e-14 max r: round-off of the assembled residual)
    are left out too."""
    r = np.asarray(residuals, dtype=float)
    if len(r) == 0:
        return []
    floor = 1e-14 * r.max() if floor is None else floor
    r = r[1:]
    r = r[r > floor]
    q = []
    for k in range(1, len(r) - 1):
        if r[k] < r[k - 1] and r[k + 1] < r[k]:
            q.append(math.log(r[k + 1] / r[k]) / math.log(r[k] / r[k - 1]))
    return q


class BiaxialTest:
    """Build and run one biaxial test; see the module docstring for the set-up."""

    def __init__(self, comm, settings=None, verbose=True):
        from ..materials.ehlers import EhlersMaterial
        from ..materials.ehlers.material_point import MaterialPoint, consolidate
        self.comm = comm
        self.s = s = settings or BiaxialSettings()
        s.check()
        self.verbose = verbose
        overrides = dict(s.material)
        overrides.setdefault("micropolar", s.micropolar)
        overrides["eta"] = overrides.get("eta", s.eta) / s.step_time   # material time = nominal steps
        self.material = EhlersMaterial.hostun(**overrides)
        p = self.material.parameters
        materials = [self.material]
        if s.weak_size > 0 and s.weak_beta_factor < 1:
            materials.append(EhlersMaterial.hostun(**dict(
                overrides, beta0=p.beta0 * s.weak_beta_factor, beta_star=p.beta_star * s.weak_beta_factor)))
        self.zoned = ZonedMaterial(materials)

        # phase 1 platen path: homogeneous plane-strain consolidation of the material point
        point = MaterialPoint(self.material)
        records = consolidate(point, -s.confining, n_steps=s.consolidation_steps, plane_strain=True)
        self.consolidation_strain = np.concatenate([[0.0], [r["eps11"] for r in records]])

        self.mesh, facet_tags, boundaries = meshes.rectangle(comm, s.width, s.height, s.cell_size, s.cell_type)
        self.problem = problem = CosseratProblem(self.mesh, facet_tags, boundaries, material=self.zoned,
                                                 micropolar=s.micropolar, degree_u=s.degree_u,
                                                 degree_phi=s.degree_phi)
        self.points = gauss_point_coordinates(self.mesh, problem.quadrature_degree)
        n_qp = len(compat.quadrature_points(self.mesh, problem.quadrature_degree)[1])
        centres = self.points.reshape(-1, n_qp, 2).mean(axis=1)   # whole cells are weakened
        weak = (centres[:, 0] < s.weak_size) & (centres[:, 1] < s.weak_size)
        zone = np.repeat(weak.astype(np.int64), n_qp) if len(materials) > 1 else np.zeros(len(self.points), int)
        self.zoned.set_zones(zone)
        self.n_weak_cells = comm.allreduce(int(weak.sum()) if len(materials) > 1 else 0)

        n1, n2 = s.consolidation_steps, s.steps
        self.t_end = float(n1 + n2)
        lateral = lambda t: min(t / n1, 1.0)  # noqa: E731
        problem.add_traction("left", (s.confining, 0.0), scale=lateral)     # t = sigma n, n = (-1, 0)
        problem.add_traction("right", (-s.confining, 0.0), scale=lateral)
        problem.add_dirichlet("bottom", "u2", 0.0)
        problem.add_dirichlet("top", "u2", 1.0, scale=self.platen_displacement)
        problem.add_point_dirichlet((0.5 * s.width, 0.0), "u1", 0.0)
        self.solver = RecordingSolver(NewtonSolver(problem, options=s.solver_options))
        self._volume_form = dolfinx.fem.form(ufl.div(problem.displacement) * problem.dx)
        self.area = s.width * s.height
        self.history = []
        self.records = []

    # --- loading --------------------------------------------------------------------
    def platen_displacement(self, t):
        """Vertical displacement of the top platen at pseudo-time t [m]."""
        s = self.s
        n1 = s.consolidation_steps
        if t <= n1:
            return s.height * float(np.interp(t, np.arange(n1 + 1), self.consolidation_strain))
        return s.height * (self.consolidation_strain[-1] - s.axial_strain * (t - n1) / s.steps)

    # --- measurements -----------------------------------------------------------------
    @property
    def gauss_points(self):
        return self.problem.gauss_points

    def state(self, name):
        return self.gauss_points.state_old[:, self.material.state_index[name]]

    def vertical_stress(self):
        """Platen reaction / width (section 6.2.3) [Pa], negative in compression."""
        return self.problem.reaction("top", "u2") / self.s.width

    def volumetric_strain(self):
        """Mean of tr(eps) over the specimen (eps33 = 0) [-]."""
        local = dolfinx.fem.assemble_scalar(self._volume_form)
        return self.comm.allreduce(local) / self.area

    def strain_norm(self):
        """|eps| of the total (non-symmetric) strain at every owned Gauss point (section 4.4)."""
        g = self.gauss_points.evaluate_gradients()
        return strain_norm(g)

    def band(self):
        """Gaussian fit of eq 4.22 to the strain norm of all Gauss points (every rank gets it)."""
        return fit_band_collective(self.comm, self.points, self.strain_norm())

    def cell_fields(self):
        """(name, shape, values_fn) of the DG0 fields written next to the FE fields; the
        plastic strain is a 2x2 tensor (row-major eps_p11, eps_p12, eps_p21, eps_p22) like
        the stress, so that XDMF stores it as cell data."""
        cb = lambda: self.gauss_points  # noqa: E731
        idx = self.material.state_index

        def avg(columns):
            return lambda: cb().cell_average(cb().state_old[:, columns])

        plastic = lambda: cb().cell_average((cb().state_old[:, [idx["Lambda"]]] > 0).astype(float))  # noqa: E731
        strain_norm = lambda: cb().cell_average(self.strain_norm()[:, None])  # noqa: E731
        return [("plastic_strain", (2, 2), avg([idx[n] for n in ("eps_p11", "eps_p12", "eps_p21", "eps_p22")])),
                ("accumulated_plastic_strain", (), avg([idx["eps_p_dev_accumulated"]])),
                ("yield_function", (), avg([idx["yield_function"]])),
                ("plastic", (), plastic),
                ("strain_norm", (), strain_norm)]

    def row(self, record):
        """One history row at a converged step."""
        s = self.s
        n1 = s.consolidation_steps
        u_top = self.platen_displacement(record.time)
        u_start = self.platen_displacement(n1)
        F = self.state("yield_function")
        plastic = self.state("Lambda") > 0
        comm = self.comm
        n_points = comm.allreduce(len(F))
        info = self.solver.infos[-1]   # the solve that converged this step
        phase = 1 if record.time <= n1 + 1e-9 else 2
        # strains of phase 2 are counted from its start, as in the material-point driver
        volumetric = self.volumetric_strain()
        if phase == 1:
            self._volumetric_phase1 = volumetric
        return {"step": record.step, "time": record.time, "phase": phase,
                "axial_strain": min(u_top - u_start, 0.0) / s.height if phase == 2 else 0.0,
                "vertical_stress": self.vertical_stress(),
                "volumetric_strain": volumetric - self._volumetric_phase1 if phase == 2 else volumetric,
                "top_displacement": u_top,
                "plastic_fraction": comm.allreduce(int(plastic.sum())) / n_points,
                "max_yield_function": comm.allreduce(float(F.max()) if len(F) else -np.inf, op=_max()),
                "newton_iterations": record.iterations, "residual": record.residual,
                "newton_orders_min": min(convergence_orders(info.residual_history)[-1:] or [np.nan]),
                "cuts": record.cuts, "wall_time": record.wall_time}

    # --- checkpoint and restart (checkpoint.py) ------------------------------------------
    def checkpoint_state(self):
        """(per-point arrays, run state) beyond the fields and the Gauss-point history."""
        return {}, {"history": self.history, "infos": self.solver.infos,
                    "volumetric_phase1": getattr(self, "_volumetric_phase1", None)}

    def restore_state(self, per_point, run_state):
        self.history = list(run_state["history"])
        self.solver.infos = list(run_state["infos"])
        if run_state["volumetric_phase1"] is not None:
            self._volumetric_phase1 = run_state["volumetric_phase1"]

    # --- run --------------------------------------------------------------------------
    def run(self, on_step=None, checkpoint=None):
        """Drive phase 1 and phase 2; `on_step(row)` after every converged step.
        checkpoint: a checkpoint.Checkpointer (writes as it is due, stops at its
        stop_after, continues from the checkpoint it restored). Raises LoadSteppingError
        (message naming the cause) when a step cannot be cut small enough."""

        def record(step):
            row = self.row(step)
            self.history.append(row)
            if on_step is not None:
                on_step(row)

        self.stepper = stepper = LoadStepper(self.problem, self.solver, t_end=self.t_end, dt=1.0,
                                             dt_min=self.s.dt_min_fraction, dt_max=1.0, on_step=record,
                                             easy_iterations=8, verbose=self.verbose,
                                             **stepper_keywords(checkpoint))
        self.records = stepper.run()
        return self.history

    def log(self, text):
        if self.verbose:
            print0(self.comm, text)


def _max():
    from mpi4py import MPI
    return MPI.MAX
