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
  surface couple), also in phase 1 (scenes.platen_test, shared with the FEM x DEM test).
* Imperfection: a square of side `weak_size` at the lower left corner has beta0 and
  beta* multiplied by `weak_beta_factor` (less friction: it yields first and triggers the
  band, "a specific position, which is weakened for the simulation", section 6.2.1).

Time and viscosity. One nominal load step is `step_time` of physical time (default 1 s,
cut-backs halve it); only the Perzyna law (2.81) sees physical time, so the scene gives the
material eta / step_time and the solver works in nominal steps. A study of the time step
at a fixed loading rate keeps steps x step_time constant. The Perzyna time (2.81) of this
scene is eta = 0.1 s, not the 1e-4 s of the material-point driver: with 1e-4 s the band forms by a snap (the platen force drops
by several per cent within a platen displacement of 1e-5 H) that displacement control
cannot follow, and the global Newton stalls at dt -> 0 (measured; docs/results/ehlers_biaxial.md). With
0.1 s the overstress sigma_ref eta Lambda stays about 1-2 % of the stress in the band and
under 0.3 % before the peak; eta, sigma_ref and r are regularisation devices, not
material data (thesis footnote to 3.32). eta is an option.
"""
from dataclasses import dataclass, field

import numpy as np
from mpi4py import MPI

from .. import meshes
from ..materials.zoned import ZonedMaterial
from ..newton_history import convergence_orders
from ..shear_band import fit_band_collective, strain_norm
from ..snes import NewtonSolver
from ..validation import (AXIAL_STRAIN, DEGREE, FRACTION, NON_NEGATIVE, POSITIVE, STEPS, InputError, Range, check,
                          check_settings, setting)
from .platen_test import CELL_TYPES, PlatenTest


@dataclass
class BiaxialSettings:
    """Geometry, loading, discretisation and material of one biaxial run (SI units). Each
    field declares its range (validation.setting); the demo's options are made from them."""
    width: float = setting(0.05, POSITIVE, "specimen width W [m]")
    height: float = setting(0.10, POSITIVE, "specimen height H [m]")
    confining: float = setting(100e3, POSITIVE, "confining pressure p [Pa] (section 6.1.2)")
    axial_strain: float = setting(0.08, AXIAL_STRAIN, "platen displacement / H in phase 2, in (0, 0.5)")
    consolidation_steps: int = setting(5, STEPS, "load steps of phase 1 (n1)")
    steps: int = setting(80, STEPS, "load steps of phase 2 (n2)")
    cell_size: float = setting(2.0e-3, POSITIVE, "target element size [m]")
    cell_type: str = setting("triangle", choices=CELL_TYPES, help="element shape")
    degree_u: int = setting(2, DEGREE, "displacement degree 1-4 (2: Taylor-Hood P2 / P1, section 3.2)")
    degree_phi: int = setting(1, DEGREE, "rotation degree 1-4")
    micropolar: bool = setting(True)  # False: Cauchy continuum, no rotation field
    weak_size: float = setting(5.0e-3, NON_NEGATIVE,
                               "side of the weakened square at the lower left corner [m], 0: none")
    weak_beta_factor: float = setting(0.8, FRACTION, "beta0 and beta* of the weakened square relative to the "
                                                     "rest, in (0, 1]", flag="--weak-factor")
    eta: float = setting(0.1, NON_NEGATIVE, "Perzyna time eta [s] (2.81), 1 s per step; 0: rate-independent")
    step_time: float = setting(1.0, POSITIVE)     # physical time of one nominal step [s]
    material: dict = field(default_factory=dict)   # further EhlersMaterial keyword overrides
    solver_options: dict = field(default_factory=dict)
    dt_min_fraction: float = setting(2.0 ** -10, FRACTION)   # smallest step after cut-backs, in nominal steps

    def check(self):
        """Every setting in range and the material overrides valid (InputError, a
        ValueError, naming the setting), before any mesh, form or kernel exists."""
        check_settings(self, "biaxial")
        check("biaxial: weak_size", self.weak_size, Range(0.0, min(self.width, self.height), high_open=True))
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


class BiaxialTest(PlatenTest):
    """Build and run one biaxial test; see the module docstring for the set-up."""

    def __init__(self, comm, settings=None, verbose=True):
        from ..materials.ehlers import EhlersMaterial
        from ..materials.ehlers.material_point import MaterialPoint, consolidate
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
        self._volumetric_phase1 = None     # tr(eps) at the end of phase 1: phase 2 counts from it

        self.build_specimen(comm, meshes.rectangle(comm, s.width, s.height, s.cell_size, s.cell_type),
                            self.zoned, s.micropolar, weakened=len(materials) > 1)
        n1 = s.consolidation_steps
        self.load_platens(s.confining, lambda t: min(t / n1, 1.0))
        self.use_solver(NewtonSolver(self.problem, options=s.solver_options), t_end=n1 + s.steps)

    # --- loading --------------------------------------------------------------------
    def platen_displacement(self, t):
        """Vertical displacement of the top platen at pseudo-time t [m]."""
        s = self.s
        n1 = s.consolidation_steps
        if t <= n1:
            return s.height * float(np.interp(t, np.arange(n1 + 1), self.consolidation_strain))
        return s.height * (self.consolidation_strain[-1] - s.axial_strain * (t - n1) / s.steps)

    # --- measurements -----------------------------------------------------------------
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
                "max_yield_function": comm.allreduce(float(F.max()) if len(F) else -np.inf, op=MPI.MAX),
                "newton_iterations": record.iterations, "residual": record.residual,
                "newton_orders_min": min(convergence_orders(info.residual_history)[-1:] or [np.nan]),
                "cuts": record.cuts, "wall_time": record.wall_time}

    # --- checkpoint and restart (checkpoint.py) ------------------------------------------
    def checkpoint_state(self):
        per_point, run_state = super().checkpoint_state()
        return per_point, dict(run_state, volumetric_phase1=self._volumetric_phase1)

    def restore_state(self, per_point, run_state):
        super().restore_state(per_point, run_state)
        self._volumetric_phase1 = run_state["volumetric_phase1"]
