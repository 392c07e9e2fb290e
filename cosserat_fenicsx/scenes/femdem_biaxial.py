"""The FEM x DEM biaxial test of 000 section 4 with a demcell cell at every Gauss point.

One scene shared by demos/femdem_biaxial.py, the tests and the benchmarks.

Specimen and axes. W x H (000: 10 mm x 20 mm), x horizontal (lateral, cell axis 1), y
vertical (axial, cell axis 2), a structured NX x NY mesh (000 uses 1x1, 1x2, 2x4, 4x8
quadrilaterals; here P2 triangles with 3 Gauss points each by default, or Q1 quadrilaterals
with 4 as in 000). Tension positive: the axial strain and a contracting volume are negative.

Loading (000 section 4.1). The isotropic compression is the preparation of the cell
(demcell.reference_cell: compaction to p0, isotropic stage with friction), after which every
Gauss point is at F = I with sigma = -p0 I; phase 1 (one step) applies the confining
traction p0 to the lateral faces and checks that the specimen is in equilibrium there.
Phase 2 moves the top platen down by axial_strain x H in `steps` equal steps with the
lateral traction kept (dead load: the macro is geometrically linear). Smooth platens:
u2 = 0 at the bottom, u2 uniform at the top, u1 free except at a pin at the bottom centre;
the rotation (micropolar scene) is free everywhere.

Modes (materials/dem/modes.py): classical (Cauchy), hybrid (cell's symmetric stress, elastic
skew and couple stress with mu_c, l_c) and micropolar (every flux and tangent block from a
micropolar cell; the cell's grain diameter is placed at grain_diameter, which converts its
curvature and couple stress; the cell's moduli G, mu_c, B and l_c at the reference state are
reported as `cell_moduli`).

Imperfection: a square of side `weak_size` at the lower left corner whose cells have the
contact friction multiplied by `weak_friction_factor` (a weaker cell) triggers the band; 000
has none (the band there comes from the noise of the cells).

Newton and the cells' tolerance (docs/femdem.md): the macro Newton stops on the force ratio
FNORM/RNORM <= force_rtol (001 section 6), 1e-2 by default, above the floor that cells relaxed
to 1e-3 leave in the residual; near the peak that floor rises, and a step whose iteration
stagnates ends at its best iterate if that reached accept_rtol (3e-2), reported as accepted,
as soon as that best has gained less than 10 % in stagnation_its (4) iterations.
"""
from dataclasses import dataclass, field
import math
import time

import dolfinx.fem
import numpy as np
import ufl
from mpi4py import MPI

from .. import compat, meshes
from ..problem import CosseratProblem
from ..quadrature import gauss_point_coordinates
from ..checkpoint import stepper_keywords
from ..shear_band import fit_band_collective
from ..snes import NewtonSolver
from ..stepping import LoadStepper
from ..validation import check
from .biaxial import RecordingSolver

DEFAULT_SOLVER_OPTIONS = {"snes_linesearch_type": "basic"}   # full Newton steps, as 001 and YADE


#: Gauss points (one cell each) of one NXxNY rectangle: two triangles of 3 points
CELL_POINTS_PER_RECTANGLE = 6
#: memory of a cell per disc (114 kB for 228 discs, docs/femdem.md) and the most the cells of
#: one run may take on this 24 GiB machine
BYTES_PER_DISC = 500
MAX_CELL_BYTES = 16e9


@dataclass
class FemDemSettings:
    """Geometry, loading, discretisation, coupling mode and cell of one run (SI units for
    lengths, the cell's 2D units (N/m) for stresses)."""
    width: float = 0.01
    height: float = 0.02
    nx: int = 2
    ny: int = 4
    cell_type: str = "triangle"
    degree_u: int = 2
    degree_phi: int = 1
    mode: str = "hybrid"               # classical | hybrid | micropolar
    tangent: str = "pstlo"             # cto | demqo | kruyt | pstlo | pstlo_sliding (not micropolar)
    mu_c: float = None                 # None: the cell's initial shear modulus
    l_c: float = None                  # None: grain_diameter
    grain_diameter: float = 2.5e-4     # mean grain diameter in the specimen's units [m]
    axial_strain: float = 0.10         # platen displacement / H in phase 2
    steps: int = 100
    weak_size: float = 0.0
    weak_friction_factor: float = 1.0
    force_rtol: float = 1e-2
    accept_rtol: float = 3e-2          # a stagnating step ends at its best iterate if below this (None: never)
    stagnation_its: int = 4            # ... as soon as its best gained < 10 % in this many iterations (acts with accept_rtol; None: at the cap)
    dt_min_fraction: float = 2.0 ** -6
    solver_options: dict = field(default_factory=dict)
    cell: object = None                # materials.dem.CellOptions
    balance: bool = False              # move cells between ranks so that they finish together (balancing.py)
    balance_threshold: float = 1.10    # ... when the slowest rank's cell work exceeds the mean by this factor
    balance_cost: str = "wall"         # ... measured as wall seconds per point, or as DEM steps ("work": reproducible)
    balance_passes: bool = False       # ... at the start of every Newton pass by the last pass's costs, not per step
    batched: bool = False              # the rank's cells in one struct of arrays, one Numba solve (materials/dem/batched.py)
    cell_threads: int = 1              # Numba threads per rank over the cells (batched; ranks x threads <= cores)
    cell_device: str = "cpu"           # cpu | gpu: the rank's batched cells on its CUDA device (demcell.gpu)

    def check(self):
        """Raises ValueError naming the setting; called before any cell is created."""
        from ..materials.dem import MODES, CellOptions, check_tangent
        if self.cell is None:
            self.cell = CellOptions()
        for name in ("width", "height"):
            check(f"femdem: {name}", getattr(self, name), meshes.RECTANGLE_LENGTH)
        for name in ("grain_diameter", "force_rtol"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"femdem: {name} must be a positive number, got {v!r}")
        for name in ("nx", "ny", "steps"):
            v = getattr(self, name)
            if not (isinstance(v, (int, np.integer)) and v >= 1):
                raise ValueError(f"femdem: {name} must be an integer >= 1, got {v!r}")
        if not self.grain_diameter < min(self.width, self.height):
            raise ValueError(f"femdem: grain_diameter must be below the specimen's width and height, "
                             f"got {self.grain_diameter!r}")
        if self.l_c is not None and not (math.isfinite(self.l_c) and self.l_c < min(self.width, self.height)):
            raise ValueError(f"femdem: l_c must be below the specimen's width and height, got {self.l_c!r}")
        if not (math.isfinite(self.axial_strain) and 0 < self.axial_strain < 0.5):
            raise ValueError(f"femdem: axial_strain must be in (0, 0.5), got {self.axial_strain!r}")
        if self.mode not in MODES:
            raise ValueError(f"femdem: unknown mode {self.mode!r}: one of {', '.join(MODES)}")
        refusal = check_tangent(self.tangent, self.mode)
        if refusal:
            raise ValueError(f"femdem: {refusal}")
        if self.mode == "classical" and (self.mu_c is not None or self.l_c is not None):
            raise ValueError("femdem: mu_c and l_c are micropolar options; a classical (Cauchy) scene has "
                             "no rotation field (use mode hybrid)")
        if self.mode == "micropolar" and (self.mu_c is not None or self.l_c is not None):
            raise ValueError("femdem: mu_c and l_c are hybrid-mode options; in mode micropolar the skew and "
                             "couple stresses come from the cells (their moduli are reported)")
        if self.mu_c is not None and not (math.isfinite(self.mu_c) and self.mu_c > 0):
            raise ValueError(f"femdem: mu_c must be positive, got {self.mu_c!r}")
        if self.l_c is not None and not (math.isfinite(self.l_c) and self.l_c >= 0):
            raise ValueError(f"femdem: l_c must be >= 0, got {self.l_c!r}")
        if self.accept_rtol is not None and not (math.isfinite(self.accept_rtol) and self.accept_rtol >= self.force_rtol):
            raise ValueError(f"femdem: accept_rtol must be >= force_rtol ({self.force_rtol:g}) or None, "
                             f"got {self.accept_rtol!r}")
        if self.stagnation_its is not None and not (isinstance(self.stagnation_its, (int, np.integer))
                                                    and self.stagnation_its >= 1):
            raise ValueError(f"femdem: stagnation_its must be an integer >= 1 or None, "
                             f"got {self.stagnation_its!r}")
        if not 0 <= self.weak_size < min(self.width, self.height):
            raise ValueError(f"femdem: weak_size must be in [0, min(W, H)), got {self.weak_size!r}")
        if not 0 < self.weak_friction_factor <= 1:
            raise ValueError(f"femdem: weak_friction_factor must be in (0, 1], got {self.weak_friction_factor!r}")
        for name in ("degree_u", "degree_phi"):
            v = getattr(self, name)
            if not (isinstance(v, (int, np.integer)) and v >= 1):
                raise ValueError(f"femdem: {name} must be an integer >= 1, got {v!r}")
        meshes.check_node_at_centre(self.nx, self.degree_u)
        if self.mode == "micropolar" and not self.cell.rotation:
            raise ValueError("femdem: mode micropolar needs grains that rotate (a micropolar cell imposes the "
                             "rotation and curvature on them): drop the locked rotations or use mode hybrid")
        if self.cell_type not in ("triangle", "quadrilateral"):
            raise ValueError(f"femdem: cell_type must be triangle or quadrilateral, got {self.cell_type!r}")
        self.cell.check()
        for name in ("balance", "balance_passes"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"femdem: {name} must be True or False, got {getattr(self, name)!r}")
        if self.balance_passes and not self.balance:
            raise ValueError("femdem: balance_passes (--balance-passes) is a way to balance: it needs balance "
                             "(--balance)")
        if not isinstance(self.batched, bool):
            raise ValueError(f"femdem: batched must be True or False, got {self.batched!r}")
        if not (isinstance(self.cell_threads, (int, np.integer)) and self.cell_threads >= 1):
            raise ValueError(f"femdem: cell_threads must be an integer >= 1, got {self.cell_threads!r}")
        if self.cell_device not in ("cpu", "gpu"):
            raise ValueError(f"femdem: cell_device must be cpu or gpu, got {self.cell_device!r}")
        if self.cell_device == "gpu":
            from demcell.gpu import available
            reason = available()
            if reason:
                raise ValueError(f"femdem: cell_device gpu: {reason}")
            self.batched = True          # a GPU holds the rank's cells as one batch
        if self.cell_threads > 1 and not self.batched:
            raise ValueError("femdem: cell_threads > 1 needs batched cells (--batched)")
        import numba
        if self.cell_threads > numba.config.NUMBA_NUM_THREADS:
            raise ValueError(f"femdem: cell_threads = {self.cell_threads} exceeds NUMBA_NUM_THREADS = "
                             f"{numba.config.NUMBA_NUM_THREADS} (set the environment variable, or use fewer)")
        if not (isinstance(self.balance_threshold, (int, float)) and self.balance_threshold >= 1):
            raise ValueError(f"femdem: balance_threshold must be a number >= 1 (slowest / mean), "
                             f"got {self.balance_threshold!r}")
        from ..balancing import COSTS
        if self.balance_cost not in COSTS:
            raise ValueError(f"femdem: balance_cost must be one of {', '.join(COSTS)}, got {self.balance_cost!r}")
        cells_bytes = CELL_POINTS_PER_RECTANGLE * self.nx * self.ny * BYTES_PER_DISC * self.cell.particles
        if not cells_bytes <= MAX_CELL_BYTES:
            raise ValueError(f"femdem: a {self.nx}x{self.ny} mesh of {self.cell.particles}-disc cells needs about "
                             f"{cells_bytes / 1e9:.3g} GB for its cells; at most {MAX_CELL_BYTES / 1e9:g} GB")


def reference_moduli(mode, cell, tangent, grain_diameter):
    """Cosserat moduli of the micropolar reference cell in the specimen's units
    (materials.dem.cells.micropolar_moduli: G, mu_c, B = dm/dkappa, l_c = sqrt(B / (2 mu_c))
    against the grain diameter), read off the network tangent 'pstlo' and the frozen-contact
    relaxations 'demqo' (both at the reference state). The headline values come from the
    run's own tangent if that is one of these two, else from pstlo; if a tangent fails its
    entry holds the error and the other one is used."""
    from ..materials.dem.cells import micropolar_moduli
    per_kind, errors = {}, {}
    for name, kind in (("pstlo", "pstlo"), ("demqo", "demqo")):
        block = np.zeros((6, 6))
        try:
            mode.tangent(cell, None, kind, block)
        except Exception as error:          # the network operator is optional for the run
            errors[name] = f"{type(error).__name__}: {error}"
            continue
        per_kind[name] = micropolar_moduli(block, grain_diameter)
    if not per_kind:
        raise RuntimeError(f"femdem: no micropolar tangent of the reference cell: {errors}")
    source = tangent if tangent in per_kind else ("pstlo" if "pstlo" in per_kind else "demqo")
    out = dict(per_kind[source], moduli_from=source, grain_diameter=grain_diameter,
               moduli_by_tangent=per_kind)
    if errors:
        out["moduli_errors"] = errors
    return out


def parse_mesh(text):
    """'NXxNY' -> (nx, ny); ValueError naming the option otherwise."""
    try:
        nx, ny = (int(v) for v in str(text).lower().split("x"))
    except ValueError:
        raise ValueError(f"--mesh must look like NXxNY (e.g. 2x4), got {text!r}") from None
    if nx < 1 or ny < 1:
        raise ValueError(f"--mesh needs at least one element each way, got {text!r}")
    return nx, ny


class FemDemBiaxial:
    """Build and run one FEM x DEM biaxial test (see the module docstring)."""

    def __init__(self, comm, settings=None, verbose=True):
        from ..materials.dem import (DemMaterial, initial_shear_modulus, make_mode, mean_grain_diameter,
                                     reference_cells)
        self.comm = comm
        self.s = s = settings or FemDemSettings()
        s.check()
        self.verbose = verbose
        start = time.perf_counter()
        frictions = [s.cell.friction]
        if s.weak_size > 0 and s.weak_friction_factor < 1:
            frictions.append(s.cell.friction * s.weak_friction_factor)
        self.reference_cells, self.packing_info = reference_cells(s.cell, frictions, comm,
                                                                  micropolar=s.mode == "micropolar")
        self.preparation_time = time.perf_counter() - start
        ref = self.reference_cells[0]
        # metres per length unit of the cell: places the cell's grains at grain_diameter
        self.length_scale = s.grain_diameter / mean_grain_diameter(ref)
        self.cell_moduli = None
        if s.mode == "classical":
            self.mu_c = self.l_c = None
            self.mode = make_mode(s.mode)
        elif s.mode == "hybrid":
            self.mu_c = s.mu_c if s.mu_c is not None else initial_shear_modulus(ref)
            self.l_c = s.l_c if s.l_c is not None else s.grain_diameter
            self.mode = make_mode(s.mode, self.mu_c, self.l_c)
        else:
            self.mode = make_mode(s.mode, length_scale=self.length_scale)
            self.cell_moduli = self.mode.moduli = reference_moduli(self.mode, ref, s.tangent, s.grain_diameter)
            self.mu_c, self.l_c = self.cell_moduli["mu_c"], self.cell_moduli["l_c"]
        def make_material():
            return DemMaterial(self.reference_cells, self.mode, s.tangent)
        self.cell_device = "cpu"
        if s.batched:
            import numba
            from ..materials.dem.batched import BatchedDemMaterial
            numba.set_num_threads(s.cell_threads)
            if s.cell_device == "gpu":
                from demcell.gpu import use_device
                self.cell_device = use_device(comm.rank)

            def make_material():
                return BatchedDemMaterial(self.reference_cells, self.mode, s.tangent, device=s.cell_device)
        self.material = make_material()
        if s.balance and comm.size > 1:
            from ..balancing import BalancedMaterial
            self.material = BalancedMaterial(comm, make_material,
                                             threshold=s.balance_threshold, cost=s.balance_cost,
                                             passes=s.balance_passes)

        self.mesh, tags, names = meshes.rectangle(comm, s.width, s.height, cell_type=s.cell_type,
                                                  divisions=(s.nx, s.ny))
        self.problem = problem = CosseratProblem(self.mesh, tags, names, material=self.material,
                                                 micropolar=self.mode.micropolar_scene,
                                                 degree_u=s.degree_u, degree_phi=s.degree_phi)
        self.points = gauss_point_coordinates(self.mesh, problem.quadrature_degree)
        n_qp = len(compat.quadrature_points(self.mesh, problem.quadrature_degree)[1])
        centres = self.points.reshape(-1, n_qp, 2).mean(axis=1)   # whole cells are weakened
        weak = (centres[:, 0] < s.weak_size) & (centres[:, 1] < s.weak_size)
        zone = np.repeat(weak.astype(np.int64), n_qp) if len(frictions) > 1 else np.zeros(len(self.points), int)
        self.material.set_zones(zone)
        self.in_imperfection = zone.astype(bool)   # per owned Gauss point
        self.material.set_point_coordinates(self.points)
        self.n_weak_cells = comm.allreduce(int(weak.sum()) if len(frictions) > 1 else 0)

        p0 = s.cell.pressure
        self.t_end = 1.0 + s.steps
        problem.add_traction("left", (p0, 0.0), scale=lambda t: 1.0)     # t = sigma n, n = (-1, 0)
        problem.add_traction("right", (-p0, 0.0), scale=lambda t: 1.0)
        problem.add_dirichlet("bottom", "u2", 0.0)
        problem.add_dirichlet("top", "u2", 1.0, scale=self.platen_displacement)
        problem.add_point_dirichlet((0.5 * s.width, 0.0), "u1", 0.0)
        options = dict(DEFAULT_SOLVER_OPTIONS, **s.solver_options)
        self.newton = NewtonSolver(problem, options=options, force_rtol=s.force_rtol, accept_rtol=s.accept_rtol,
                                   stagnation_its=s.stagnation_its if s.accept_rtol is not None else None)
        self.solver = RecordingSolver(self.newton)
        self._volume_form = dolfinx.fem.form(ufl.div(problem.displacement) * problem.dx)
        cb = problem.gauss_points
        cb.set_initial_fluxes(self.material.initial_fluxes())    # sigma = -p0 I before any solve
        self.gradients_start = np.zeros_like(cb.gradients)       # phase 2 starts at u = 0
        self.gradients_previous = np.zeros_like(cb.gradients)
        self.history = []

    # --- loading ---------------------------------------------------------------------
    def platen_displacement(self, t):
        """Vertical displacement of the top platen at pseudo-time t [m] (0 in phase 1)."""
        s = self.s
        return -s.height * s.axial_strain * max(t - 1.0, 0.0) / s.steps

    @property
    def gauss_points(self):
        return self.problem.gauss_points

    # --- measurements ---------------------------------------------------------------------
    def state(self, name):
        """Committed output `name` of every owned Gauss point (DemMaterial.state_names)."""
        return self.gauss_points.state_old[:, self.material.state_index[name]]

    def mean(self, values):
        """Mean over all Gauss points of all ranks (000 averages over the integration points)."""
        return self.comm.allreduce(float(np.sum(values))) / self.comm.allreduce(len(values))

    def gauss_point_ratios(self):
        """Stress ratio (000 eq. 40) of every owned Gauss point from the committed fluxes."""
        f = self.gauss_points.flux_values
        den = np.abs(f[:, 0] + f[:, 1])
        return np.where(den > 0, np.abs(f[:, 0] - f[:, 1]) / np.where(den > 0, den, 1.0), 0.0)

    def equivalent_strain(self, since):
        """|sym(eps - eps_since)| (Frobenius) per owned Gauss point: 000 Fig. 7's equivalent
        strain since the gradients `since` (the start of phase 2, or the last step)."""
        d = self.gauss_points.gradients[:, :4] - since[:, :4]
        sym = 0.5 * (d[:, 2] + d[:, 3])
        return np.sqrt(d[:, 0] ** 2 + d[:, 1] ** 2 + 2.0 * sym ** 2)

    def volumetric_strain(self):
        """Mean of tr(eps) over the specimen [-] (small-strain J - 1)."""
        return self.comm.allreduce(dolfinx.fem.assemble_scalar(self._volume_form)) / (self.s.width * self.s.height)

    def band(self):
        """Gaussian fit of thesis eq 4.22 to the equivalent strain since the start of phase 2,
        over the Gauss points outside the imperfection: the weak cells strain more than the
        rest whether or not a band forms, and a bell fitted through them describes the weak
        corner, not the band that leaves it (docs/femdem.md, regularisation study)."""
        keep = ~self.in_imperfection
        return fit_band_collective(self.comm, self.points[keep], self.equivalent_strain(self.gradients_start)[keep])

    def global_order(self, values):
        """(points, values) of all ranks on rank 0, sorted by (y, x): rank-independent order."""
        pts = self.comm.gather(self.points, root=0)
        vals = self.comm.gather(np.asarray(values), root=0)
        if self.comm.rank != 0:
            return None, None
        pts, vals = np.concatenate(pts), np.concatenate(vals)
        order = np.lexsort((np.round(pts[:, 0], 12), np.round(pts[:, 1], 12)))
        return pts[order], vals[order]

    def row(self, record):
        """One history row at a converged step."""
        s, comm = self.s, self.comm
        cb = self.gauss_points
        info = self.solver.infos[-1]
        phase = 1 if record.time <= 1.0 + 1e-9 else 2
        reaction = self.problem.reaction("top", "u2")
        status = self.state("status")
        row = {"step": record.step, "time": record.time, "phase": phase,
               "axial_strain": self.platen_displacement(record.time) / s.height,
               "stress_ratio": self.mean(self.gauss_point_ratios()),
               "volumetric_strain": self.volumetric_strain(),
               "coordination_number": self.mean(self.state("coordination_number")),
               "anisotropy": self.mean(self.state("anisotropy")),
               "sliding_fraction": self.mean(self.state("sliding_fraction")),
               "vertical_reaction": reaction, "vertical_stress": reaction / s.width,
               "mean_sigma11": self.mean(cb.flux_values[:, 0]), "mean_sigma22": self.mean(cb.flux_values[:, 1]),
               "newton_iterations": record.iterations, "force_ratio": info.force_ratios[-1] if info.force_ratios else np.nan,
               "accepted": int(info.accepted),
               "dem_steps": comm.allreduce(float(cb.step_cost.sum())),
               "points_without_contacts": comm.allreduce(int(np.count_nonzero(status == 1))),
               "cuts": record.cuts, "wall_time": record.wall_time}
        return row

    # --- checkpoint and restart (checkpoint.py) ------------------------------------------
    def checkpoint_state(self):
        """(per-point arrays, run state) beyond the fields, the Gauss-point arrays and the cells."""
        return {"gradients_previous": self.gradients_previous}, {"history": self.history, "infos": self.solver.infos}

    def restore_state(self, per_point, run_state):
        self.gradients_previous[:] = per_point["gradients_previous"]
        self.history = list(run_state["history"])
        self.solver.infos = list(run_state["infos"])

    # --- run --------------------------------------------------------------------------
    def run(self, on_step=None, checkpoint=None):
        """Phase 1 and phase 2; `on_step(row)` after every converged step. checkpoint: a
        checkpoint.Checkpointer (writes as due, stops at its stop_after, continues from
        the checkpoint it restored). Raises LoadSteppingError (naming the cause) when a
        step cannot be cut small enough."""

        def record(step):
            row = self.row(step)
            self.history.append(row)
            if on_step is not None:
                on_step(row)
            self.gradients_previous[:] = self.gauss_points.gradients

        self.stepper = LoadStepper(self.problem, self.solver, t_end=self.t_end, dt=1.0,
                                   dt_min=self.s.dt_min_fraction, dt_max=1.0, on_step=record,
                                   easy_iterations=8, verbose=self.verbose, **stepper_keywords(checkpoint))
        self.stepper.run()
        return self.history

    def timing(self):
        """Where the time went on this rank [s]: cell solves, cell tangents, assembly,
        the rest of the Newton solves (linear solve, SNES) and everything."""
        t = self.newton.timers
        m = self.material.timers
        cb = self.gauss_points.timers
        other = t["solve_total"] - t["material"] - t["residual_assembly"] - t["jacobian_assembly"]
        return {"cell_solves": m["solve"], "cell_homogenisation": m["homogenize"], "cell_tangents": m["tangent"],
                "cell_commits": m["commit"], "gradient_evaluation": cb["gradients"],
                "residual_assembly": t["residual_assembly"], "jacobian_assembly": t["jacobian_assembly"],
                "linear_solve_and_snes": other, "newton_total": t["solve_total"]}

    def log(self, text):
        if self.verbose and self.comm.rank == 0:
            print(text, flush=True)


def max_over_ranks(comm, value):
    return comm.allreduce(value, op=MPI.MAX)
