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
the rotation (micropolar scene) is free everywhere (scenes.platen_test, shared with the
Ehlers biaxial test).

Modes (materials/dem/modes.py): classical (Cauchy), hybrid (cell's symmetric stress, elastic
skew and couple stress with mu_c, l_c) and micropolar (every flux and tangent block from a
micropolar cell; the cell's grain diameter is placed at grain_diameter, which converts its
curvature and couple stress; the cell's moduli G, mu_c, B and l_c at the reference state are
reported as `cell_moduli`).

Imperfection: a square of side `weak_size` at the lower left corner whose cells have the
contact friction multiplied by `weak_friction_factor` (a weaker cell) triggers the band; 000
has none (the band there comes from the noise of the cells).

Newton and the cells' tolerance (docs/reference/femdem.md): the macro Newton stops on the force ratio
FNORM/RNORM <= force_rtol (001 section 6), 1e-2 by default, above the floor that cells relaxed
to 1e-3 leave in the residual; near the peak that floor rises, and a step whose iteration
stagnates ends at its best iterate if that reached accept_rtol (3e-2), reported as accepted,
as soon as that best has gained less than 10 % in stagnation_its (4) iterations. Past the
peak the consistent operators (pstlo, demqo, perturbation) of cells with sliding contacts turn
indefinite and the Newton corrections explode: a step that fails with `tangent` is solved again
with `fallback_tangent` (kruyt, positive definite while the contact network holds), and the
`fallback_hold` (5) steps after it too (fallback.py); with `retry_damping` > 0 (off by
default: it has not been seen to rescue a step) a step that fails with both is solved once more on
the fallback with damped Newton updates before it is cut.
"""
from dataclasses import dataclass, field
import time

import numpy as np
from mpi4py import MPI

from .. import meshes
from ..balancing import COSTS
from ..materials.dem.cells import TANGENTS
from ..materials.dem.modes import MODES
from ..resources import memory_bytes
from ..shear_band import fit_band_collective
from ..fallback import FallbackSolver
from ..snes import NewtonSolver
from ..validation import (AXIAL_STRAIN, COUNT, DEGREE, FRACTION, NON_NEGATIVE, NON_NEGATIVE_INTEGER, POSITIVE,
                          STEPS, Range, check_settings, setting)
from .platen_test import CELL_TYPES, PlatenTest

DEFAULT_SOLVER_OPTIONS = {"snes_linesearch_type": "basic"}   # full Newton steps, as 001 and YADE
#: the operator is kept while each Newton iteration reduces FNORM/RNORM to 70 % or less (the
#: fastest rule measured in all three modes: docs/results/femdem.md, "How often the operator is built")
DEFAULT_JACOBIAN_REFRESH = 0.7
#: Newton updates of the damped retry of a step that failed with both operators (fallback.py), as a
#: fraction of the full correction (docs/reference/femdem.md, "Past the peak: ending a stagnating step")
DEFAULT_RETRY_DAMPING = 0.0


#: Gauss points (one cell each) of one NXxNY rectangle: two triangles of 3 points
CELL_POINTS_PER_RECTANGLE = 6
#: memory of a cell per disc (114 kB for 228 discs, docs/reference/femdem.md)
BYTES_PER_DISC = 500
#: the share of the machine's memory (resources.memory_bytes) the cells of one run may take;
#: the rest is the FE problem's, MPI's and Python's
CELL_MEMORY_SHARE = 0.6


@dataclass
class FemDemSettings:
    """Geometry, loading, discretisation, coupling mode and cell of one run (SI units for
    lengths, the cell's 2D units (N/m) for stresses). Each field declares its range
    (validation.setting); the demo's options are made from them."""
    width: float = setting(0.01, meshes.RECTANGLE_LENGTH, "specimen width W [m]")
    height: float = setting(0.02, meshes.RECTANGLE_LENGTH, "specimen height H [m]")
    nx: int = setting(2, COUNT)        # rectangles across W (the demo's --mesh NXxNY)
    ny: int = setting(4, COUNT)        # rectangles along H
    cell_type: str = setting("triangle", choices=CELL_TYPES, help="element shape")
    degree_u: int = setting(2, DEGREE, "displacement degree 1-4 (2: Taylor-Hood)")
    degree_phi: int = setting(1, DEGREE, "rotation degree 1-4")
    mode: str = setting("hybrid", choices=MODES,
                        help="classical: Cauchy continuum; hybrid: micropolar, elastic skew and couple stress; "
                             "micropolar: every flux and tangent block from a micropolar cell")
    tangent: str = setting("pstlo", choices=TANGENTS,
                           help="cell operator of the macro Newton (pstlo_sliding: PSTLO with the contacts on their "
                                "Coulomb limit sliding, not for mode micropolar; docs/reference/femdem.md)")
    fallback_tangent: str = setting("kruyt", choices=TANGENTS + ("none",),
                                    help="operator a load step that failed with --tangent is tried again with "
                                         "before it is cut (none: cut at once; docs/reference/femdem.md, "
                                         "'Past the peak')")
    fallback_hold: int = setting(5, NON_NEGATIVE_INTEGER, "steps solved with the fallback tangent directly "
                                                                "after one that needed it")
    # a step that failed with tangent and fallback_tangent is solved once more on the fallback with
    # Newton updates x += retry_damping dx before it is cut (fallback.py; 0: cut at once); the demo's
    # --retry-damping
    retry_damping: float = setting(DEFAULT_RETRY_DAMPING, Range(0.0, 1.0))
    mu_c: float = setting(None, POSITIVE, "Cosserat modulus [N/m] (hybrid; default: the cell's initial shear modulus)")
    l_c: float = setting(None, NON_NEGATIVE, "internal length [m] (hybrid; default: --grain-diameter)")
    grain_diameter: float = setting(2.5e-4, POSITIVE, "mean grain diameter in the specimen's units [m] (W / 40)")
    axial_strain: float = setting(0.10, AXIAL_STRAIN, "platen displacement / H, in (0, 0.5)")
    steps: int = setting(100, STEPS, "load steps of the compression")
    weak_size: float = setting(0.0, NON_NEGATIVE, "side of the weak square at the lower left corner [m], 0: none")
    weak_friction_factor: float = setting(1.0, FRACTION, "contact friction of the weak cells / --friction, in (0, 1]",
                                          flag="--weak-friction")
    force_rtol: float = setting(1e-2, POSITIVE, "Newton stops at FNORM/RNORM <= this")
    jacobian_lag: int = setting(None, COUNT, "the cells' operator is built at the first Newton iteration of a step and "
                                             "then every N-th (PETSc's -snes_lag_jacobian; 1: every iteration; "
                                             "default: the --jacobian-refresh rule)")
    jacobian_refresh: float = setting(None, Range(0.0, 1.0, low_open=True, high_open=True),
                                      "the operator of a step's first Newton iteration is kept until an iteration "
                                      "reduces FNORM/RNORM by less than this factor, then built anew (default "
                                      f"{DEFAULT_JACOBIAN_REFRESH} unless --jacobian-lag is given; snes.py, "
                                      "docs/reference/femdem.md 'How often the operator is built')")
    # a stagnating step ends at its best iterate if below this (None: never), as soon as its
    # best gained < 10 % in stagnation_its iterations (None: at the cap); the demo's
    # --accept-rtol 0 and --stagnation-its 0 are the None
    accept_rtol: float = setting(3e-2, NON_NEGATIVE, optional=True)
    stagnation_its: int = setting(4, COUNT, optional=True)
    dt_min_fraction: float = setting(2.0 ** -6, FRACTION)   # smallest step after cut-backs, in nominal steps
    solver_options: dict = field(default_factory=dict)
    cell: object = None                # materials.dem.CellOptions
    balance: bool = setting(False, help="move cells between ranks so that the ranks finish their cells together "
                                        "(docs/results/balancing.md)")
    balance_threshold: float = setting(1.10, Range(low=1.0, infinite=True),
                                       "... when the slowest rank's cell work / the mean exceeds this (inf: measure "
                                       "the imbalance only)")
    balance_cost: str = setting("wall", choices=COSTS,
                                help="... cell work measured in wall seconds or in DEM steps (work: the same moves "
                                     "in every run, whatever the machine's load)")
    balance_passes: bool = setting(False, help="... at the start of every Newton pass, by the cell work of the pass "
                                               "before, instead of after every step (docs/results/balancing.md)")
    batched: bool = setting(True, help="the rank's cells in one struct of arrays, solved by one Numba call (the "
                                       "same results as one cell at a time, --no-batched; docs/reference/femdem.md)")
    cell_threads: int = setting(1, COUNT, "Numba threads per rank over the cells, with --batched "
                                          "(ranks x threads <= cores)")
    cell_device: str = setting("cpu", choices=("cpu", "gpu"),
                               help="where a rank's cells live: cpu or gpu, its CUDA device (rank r on GPU r mod the "
                                    "GPUs; batched; docs/results/gpu.md); refused without a GPU and Numba's CUDA target")

    def jacobian_rule(self):
        """How often the cells' operator is built: ("lag", N) or ("refresh", factor)."""
        if self.jacobian_lag is not None:
            return "lag", self.jacobian_lag
        return "refresh", self.jacobian_refresh if self.jacobian_refresh is not None else DEFAULT_JACOBIAN_REFRESH

    def check(self):
        """Raises ValueError naming the setting; called before any cell is created."""
        from ..materials.dem import CellOptions, check_tangent
        if self.cell is None:
            self.cell = CellOptions()
        check_settings(self, "femdem")
        if self.jacobian_lag is not None and self.jacobian_refresh is not None:
            raise ValueError("femdem: give --jacobian-lag or --jacobian-refresh, not both (two rules for when the "
                             "operator is built)")
        if not self.grain_diameter < min(self.width, self.height):
            raise ValueError(f"femdem: grain_diameter must be below the specimen's width and height, "
                             f"got {self.grain_diameter!r}")
        if self.l_c is not None and not self.l_c < min(self.width, self.height):
            raise ValueError(f"femdem: l_c must be below the specimen's width and height, got {self.l_c!r}")
        for name in (self.tangent, self.fallback_tangent):
            refusal = None if name == "none" else check_tangent(name, self.mode)
            if refusal:
                raise ValueError(f"femdem: {refusal}")
        if self.mode == "classical" and (self.mu_c is not None or self.l_c is not None):
            raise ValueError("femdem: mu_c and l_c are micropolar options; a classical (Cauchy) scene has "
                             "no rotation field (use mode hybrid)")
        if self.mode == "micropolar" and (self.mu_c is not None or self.l_c is not None):
            raise ValueError("femdem: mu_c and l_c are hybrid-mode options; in mode micropolar the skew and "
                             "couple stresses come from the cells (their moduli are reported)")
        if self.accept_rtol is not None and not self.accept_rtol >= self.force_rtol:
            raise ValueError(f"femdem: accept_rtol must be >= force_rtol ({self.force_rtol:g}) or None, "
                             f"got {self.accept_rtol!r}")
        if not self.weak_size < min(self.width, self.height):
            raise ValueError(f"femdem: weak_size must be in [0, min(W, H)), got {self.weak_size!r}")
        meshes.check_node_at_centre(self.nx, self.degree_u)
        if self.mode == "micropolar" and not self.cell.rotation:
            raise ValueError("femdem: mode micropolar needs grains that rotate (a micropolar cell imposes the "
                             "rotation and curvature on them): drop the locked rotations or use mode hybrid")
        self.cell.check()
        if self.cell.micro_bc == "frame":
            from ..materials.dem.cells import FRAME_TANGENTS
            for name, on, why in (("mode micropolar", self.mode == "micropolar", "a micropolar cell is periodic"),
                                  ("cell_device gpu", self.cell_device == "gpu", "the cell stores batch periodic cells"),
                                  ("balance", self.balance, "cells move between ranks as periodic states"),
                                  (f"tangent {self.tangent}", self.tangent not in FRAME_TANGENTS,
                                   f"a frame cell has {', '.join(FRAME_TANGENTS)}"),
                                  (f"fallback_tangent {self.fallback_tangent}",
                                   self.fallback_tangent not in FRAME_TANGENTS + ("none",),
                                   f"a frame cell has {', '.join(FRAME_TANGENTS)}")):
                if on:
                    raise ValueError(f"femdem: micro_bc 'frame' cannot be used with {name} ({why})")
            self.batched = False         # frame cells are solved one at a time (the stores batch periodic cells)
        if self.balance_passes and not self.balance:
            raise ValueError("femdem: balance_passes (--balance-passes) is a way to balance: it needs balance "
                             "(--balance)")
        if self.cell_device == "gpu":
            from demcell.gpu import available
            reason = available()
            if reason:
                raise ValueError(f"femdem: cell_device gpu: {reason}")
            if self.cell.relaxation().fixed:
                raise ValueError("femdem: cell_device gpu: fixed_steps (cells that do not relax) runs on CPU cells "
                                 "only")
            self.batched = True          # a GPU holds the rank's cells as one batch
        if self.cell_threads > 1 and not self.batched:
            raise ValueError("femdem: cell_threads > 1 needs batched cells (the default: leave out --no-batched)")
        import numba
        if self.cell_threads > numba.config.NUMBA_NUM_THREADS:
            raise ValueError(f"femdem: cell_threads = {self.cell_threads} exceeds NUMBA_NUM_THREADS = "
                             f"{numba.config.NUMBA_NUM_THREADS} (set the environment variable, or use fewer)")
        cells_bytes = CELL_POINTS_PER_RECTANGLE * self.nx * self.ny * BYTES_PER_DISC * self.cell.particles
        memory = memory_bytes()
        max_cell_bytes = CELL_MEMORY_SHARE * memory
        if not cells_bytes <= max_cell_bytes:
            raise ValueError(f"femdem: a {self.nx}x{self.ny} mesh of {self.cell.particles}-disc cells needs about "
                             f"{cells_bytes / 1e9:.3g} GB for its cells; at most {max_cell_bytes / 1e9:.3g} GB "
                             f"({CELL_MEMORY_SHARE:g} of the {memory / 1e9:.3g} GB of memory)")


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


class FemDemBiaxial(PlatenTest):
    """Build and run one FEM x DEM biaxial test (see the module docstring)."""

    def __init__(self, comm, settings=None, verbose=True):
        from ..materials.dem import (DemMaterial, initial_shear_modulus, make_mode, mean_grain_diameter,
                                     reference_cells)
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

        fallback = None if s.fallback_tangent == "none" else s.fallback_tangent

        def make_material():
            return DemMaterial(self.reference_cells, self.mode, s.tangent, fallback_tangent=fallback)
        self.cell_device = "cpu"
        if s.batched:
            import numba
            from ..materials.dem.batched import BatchedDemMaterial
            numba.set_num_threads(s.cell_threads)
            if s.cell_device == "gpu":
                from demcell.gpu import use_device
                self.cell_device = use_device(comm.rank)

            def make_material():
                return BatchedDemMaterial(self.reference_cells, self.mode, s.tangent, device=s.cell_device,
                                          fallback_tangent=fallback)
        self.material = make_material()
        self.balanced = s.balance and comm.size > 1
        if self.balanced:
            from ..balancing import BalancedMaterial
            self.material = BalancedMaterial(comm, make_material,
                                             threshold=s.balance_threshold, cost=s.balance_cost,
                                             passes=s.balance_passes)

        mesh = meshes.rectangle(comm, s.width, s.height, cell_type=s.cell_type, divisions=(s.nx, s.ny))
        zone = self.build_specimen(comm, mesh, self.material, self.mode.micropolar_scene,
                                   weakened=len(frictions) > 1)
        self.in_imperfection = zone.astype(bool)   # per owned Gauss point
        self.material.set_point_coordinates(self.points)
        self.load_platens(s.cell.pressure, lambda t: 1.0)
        rule, value = s.jacobian_rule()
        options = dict(DEFAULT_SOLVER_OPTIONS, snes_lag_jacobian=value if rule == "lag" else 1, **s.solver_options)
        self.newton = NewtonSolver(self.problem, options=options, force_rtol=s.force_rtol,
                                   accept_rtol=s.accept_rtol,
                                   stagnation_its=s.stagnation_its if s.accept_rtol is not None else None,
                                   jacobian_refresh=value if rule == "refresh" else None)
        self.fallback = FallbackSolver(self.newton, self.problem, self.material, hold=s.fallback_hold,
                                       damping=s.retry_damping or None)
        self.use_solver(self.fallback, t_end=1.0 + s.steps)
        cb = self.problem.gauss_points     # fluxes sigma = -p0 I before any solve (initial_fluxes)
        self.gradients_start = np.zeros_like(cb.gradients)       # phase 2 starts at u = 0
        self.gradients_previous = np.zeros_like(cb.gradients)
        self.capped_reported = 0         # cell solves stopped by relax_cap, all ranks, up to the last row

    # --- loading ---------------------------------------------------------------------
    def platen_displacement(self, t):
        """Vertical displacement of the top platen at pseudo-time t [m] (0 in phase 1)."""
        s = self.s
        return -s.height * s.axial_strain * max(t - 1.0, 0.0) / s.steps

    # --- measurements ---------------------------------------------------------------------
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

    def band(self):
        """Gaussian fit of thesis eq 4.22 to the equivalent strain since the start of phase 2,
        over the Gauss points outside the imperfection: the weak cells strain more than the
        rest whether or not a band forms, and a bell fitted through them describes the weak
        corner, not the band that leaves it (docs/reference/femdem.md, regularisation study)."""
        keep = ~self.in_imperfection
        return fit_band_collective(self.comm, self.points[keep], self.equivalent_strain(self.gradients_start)[keep])

    def cell_fields(self):
        """(name, shape, values_fn) of the DG0 fields written next to the FE fields: the
        cells' coordination_number, anisotropy, sliding_fraction and dem_steps, the
        stress_ratio (000 eq. 40), the equivalent_strain since the start of phase 2 and the
        incremental_equivalent_strain of the last step (000 Fig. 7)."""
        cb = self.gauss_points
        idx = self.material.state_index

        def state(name):
            return lambda: cb.cell_average(cb.state_old[:, [idx[name]]])

        return ([(name, (), state(name)) for name in ("coordination_number", "anisotropy", "sliding_fraction",
                                                      "dem_steps")]
                + [("stress_ratio", (), lambda: cb.cell_average(self.gauss_point_ratios()[:, None])),
                   ("equivalent_strain", (),
                    lambda: cb.cell_average(self.equivalent_strain(self.gradients_start)[:, None])),
                   ("incremental_equivalent_strain", (),
                    lambda: cb.cell_average(self.equivalent_strain(self.gradients_previous)[:, None]))])

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
        reaction = self.vertical_reaction()
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
               "accepted": int(info.accepted), "fallback": int(bool(info.fallback)),
               "damped": int(info.damped),
               "dem_steps": comm.allreduce(float(cb.step_cost.sum())),
               "points_without_contacts": comm.allreduce(int(np.count_nonzero(status == 1))),
               "cuts": record.cuts, "wall_time": record.wall_time}
        # the step's cell solves that the cells' relax_cap stopped before they settled (failed
        # attempts of the step included)
        capped = comm.allreduce(self.cell_solves_capped())
        row["capped_solves"] = capped - self.capped_reported
        self.capped_reported = capped
        return row

    # --- checkpoint and restart (checkpoint.py) ------------------------------------------
    def checkpoint_state(self):
        """(per-point arrays, run state) beyond the fields, the Gauss-point arrays and the cells."""
        per_point, run_state = super().checkpoint_state()
        return dict(per_point, gradients_previous=self.gradients_previous), dict(run_state, fallback_held=self.fallback.held)

    def restore_state(self, per_point, run_state):
        super().restore_state(per_point, run_state)
        self.gradients_previous[:] = per_point["gradients_previous"]
        self.fallback.held = int(run_state.get("fallback_held", 0))

    # --- run --------------------------------------------------------------------------
    def after_step(self):
        """The next step's incremental equivalent strain counts from here."""
        self.gradients_previous[:] = self.gauss_points.gradients

    def balance_report(self):
        """What the load balancer did (balancing.BalancedMaterial.balance_report); None when
        the cells do not move between ranks."""
        return self.material.balance_report() if self.balanced else None

    def cell_solves_redone(self):
        """Cell solves on this rank that FIRE did not settle and local damping did again."""
        return self.material.counters.get("cell_solves_redone", 0)

    def cell_solves_capped(self):
        """Cell solves on this rank that the cells' relax_cap stopped before they settled."""
        return self.material.counters.get("cell_solves_capped", 0)

    def point_tangents(self):
        """Cell operators built on this rank so far (one per Gauss point and Jacobian)."""
        return self.gauss_points.counters["point_tangents"]

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


def max_over_ranks(comm, value):
    return comm.allreduce(value, op=MPI.MAX)
