#!/usr/bin/python3
"""FEM x DEM biaxial test: a periodic DEM cell (demcell) at every Gauss point.

What is solved
--------------
The biaxial test of paper 000 section 4 on a W x H = 10 mm x 20 mm specimen meshed with
NX x NY rectangles (--mesh; 000 uses 1x1, 1x2, 2x4, 4x8), every Gauss point carrying its own
periodic disc cell: the cell is deformed by F = I + sym(eps) (001 eq. 7), relaxes to
equilibrium (000 section 3.2.1) and its homogenized Cauchy stress (001 eq. 8) is the stress of
the point. The cell is the one of demos/dem_cell.py (000 Table 3: 228 discs, mu = 0.4,
kn = 1e4 N/m, ks = 2e3 N/m, tolerance 1e-3; p0 = 10 N/m, see the note on the pressure there),
prepared by the same isotropic stage; the same --particles N --seed S give the same packing
(the cells relax by FIRE to the unbalanced-force ratio 1e-3 of 001 by default, or for at most 500
DEM steps after their loading ramp, see --criterion and --cell-option; batched, see --no-batched:
docs/results/femdem.md, "Default cells"; docs/reference/femdem.md, "Past the peak: a cap on the
cells' relaxation").

1. Isotropic compression: the preparation of the cell, so every Gauss point starts at F = I
   with sigma = -p0 I; one macro step applies p0 to the lateral faces and checks equilibrium.
2. Vertical compression: the top platen moves down to --axial-strain of the height in
   --steps steps, the lateral stress p0 is kept; smooth platens.

Coupling modes (--mode): `classical` (a Cauchy continuum, as 000 and 001), `hybrid` (default:
a micropolar continuum whose symmetric stress comes from the cell, with elastic skew stress
2 mu_c skw(eps) and couple stress m = 2 mu_c l_c^2 kappa, eq. 2.74; --mu-c defaults to the
cell's initial shear modulus, --l-c to the mean grain diameter --grain-diameter), and
`micropolar` (every flux and tangent block from a micropolar cell: the grains carry the
rotation and the curvature of the point, demcell rotation_mode='micropolar'; the cell is
scaled so that its mean grain diameter is --grain-diameter, which converts its curvature and
couple stress; its Cosserat moduli G, mu_c, B = dm/dkappa and l_c = sqrt(B / 2 mu_c) at the
reference state are printed and go to summary.json as cell_moduli). The macro
Newton uses the cell operator --tangent (perturbation: 001 eq. 6, demqo: eq. 20, kruyt: eq. 13,
pstlo: appendix B; pstlo_sliding: the same with the contacts on their Coulomb limit sliding)
and stops at FNORM/RNORM <= --force-rtol (001 section 6). A weak zone
(--weak-size, --weak-friction: a square at the lower left corner whose cells have less
friction) triggers a band.

Outputs in --out, written as the run goes: history.csv (axial_strain, stress_ratio = mean
over the Gauss points of |s11 - s22| / |s11 + s22| (000 eq. 40, Fig. 4), volumetric_strain,
coordination_number, anisotropy (000 Fig. 5), vertical_reaction [N/m], Newton iterations,
DEM steps, capped_solves: the cell solves that relax_cap stopped before they settled),
gauss_points.csv (the stress ratio of every Gauss point per step, 000 Fig. 6),
fields.xdmf (displacement, rotation, stress, couple_stress and per cell coordination_number,
anisotropy, sliding_fraction, stress_ratio, equivalent_strain and
incremental_equivalent_strain (000 Fig. 7), dem_steps); at the end snapshots/ (particles and
contact forces of the Gauss points with the highest and lowest stress ratio, 000 Fig. 6
insets), summary.json (peak_stress_ratio, axial_strain_at_peak, n_gauss_points,
band_thickness and band_inclination_deg from the section 4.4 fit outside the weak corner, Newton iterations, DEM
steps, where the time went) and femdem_biaxial.png (the curves of 000 Figs 4-5).
Tension positive: the axial strain and a contracting volume are negative.

In ParaView: open fields.xdmf (Xdmf3 Reader T), colour by incremental_equivalent_strain to see
the band, by stress_ratio or coordination_number for the micro-structure; open
snapshots/*/particles_0000.vtk with a Glyph (circle, scale by radius, factor 2) and
contacts_0000.vtk coloured by normal_force.

    python3 demos/femdem_biaxial.py --mesh 1x1 --axial-strain 0.02 --steps 20
    mpirun -n 2 python3 demos/femdem_biaxial.py --mesh 2x4 --out results/femdem_biaxial
    mpirun -n 2 python3 demos/femdem_biaxial.py --mode classical --mesh 4x8 --weak-size 2.5e-3 --weak-friction 0.8

Load balancing (docs/results/balancing.md): with --balance the cells move between ranks after a step
whose cell work was uneven (a band: its cells relax far longer), results unchanged; with
--balance --balance-passes at the start of every Newton pass, by the pass before.

Batch queues (docs/reference/restart.md): --checkpoint-every N writes OUT/checkpoint (every cell's
contact state included) every N steps, --stop-after K stops cleanly after step K, --restart OUT
continues from the checkpoint, on the same or another number of ranks:

    mpirun -n 2 python3 demos/femdem_biaxial.py --mesh 2x4 --checkpoint-every 5 --stop-after 50 --out run
    mpirun -n 2 python3 demos/femdem_biaxial.py --restart run

What it costs (docs/reference/femdem.md): the cells take 99.6 % of the time, about 0.06 CPU s per cell
update at 228 discs with local damping and half the DEM steps with the default FIRE cells
(docs/results/femdem.md, "Default cells"); a 2x4 mesh (48 cells) to 3 % in 30 steps without a weak zone is a few
CPU minutes. Past the peak, and from the start in a classical run with a weak zone, the
elastic operators make the Newton converge slowly (up to 25 iterations per step, steps
ending at their best iterate: --accept-rtol), and a step can cost ten times as much.
Where the consistent operator (--tangent pstlo) of the sliding cells turns indefinite past the
peak, a step it cannot solve is solved with --fallback-tangent (kruyt) and so are the
--fallback-hold steps after it (history.csv column fallback; docs/reference/femdem.md, "Past
the peak"); with --retry-damping > 0 a step that fails with both is solved once more on the fallback with
damped Newton updates (history.csv column damped) before it is cut.
"""
import sys, os  # noqa: E401
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import math

import numpy as np
from mpi4py import MPI

from cosserat_fenicsx import cli
from cosserat_fenicsx.demo_run import DemoRun
from cosserat_fenicsx.figures import pyplot
from cosserat_fenicsx.materials.dem import CellOptions
from cosserat_fenicsx.output import print0
from cosserat_fenicsx.scenes.femdem_biaxial import (DEFAULT_RETRY_DAMPING, FemDemBiaxial, FemDemSettings, max_over_ranks,
                                                    parse_mesh)
from cosserat_fenicsx.shear_band import assess_band, no_band
from cosserat_fenicsx.validation import COUNT, NON_NEGATIVE, NON_NEGATIVE_INTEGER, Number, Range, number

#: the scene's settings given as options (their ranges and help: scenes/femdem_biaxial.py)
DISCRETISATION = ["cell_type", "degree_u", "degree_phi"]
#: the cells' settings given as options after --particles, --seed, --packing (their ranges and help:
#: materials/dem/cells.py CellOptions)
CELL = ("friction", "pressure", "kn", "ks", "rotation", "relaxation_tol", "criterion", "max_steps", "micro_bc",
        "frame_thickness", "frame_tol")
SPECIMEN = ["width", "height", "axial_strain", "steps", "weak_size", "weak_friction_factor"]
COUPLING = ["mode", "mu_c", "l_c", "grain_diameter", "tangent", "jacobian_lag", "jacobian_refresh", "fallback_tangent",
            "fallback_hold", "force_rtol"]
CELLS = ["balance", "balance_threshold", "balance_cost", "balance_passes", "batched", "cell_threads", "cell_device"]


class RetryDamping(Number):
    """--retry-damping: a number in [0, 1], or none (= 0, no damped retry); a Number, so that the
    option's range is declared like every numeric option's."""

    def __init__(self):
        super().__init__(Range(0.0, 1.0))

    def __call__(self, text):
        return 0.0 if str(text).strip().lower() == "none" else super().__call__(text)


parser = cli.make_parser(__doc__)
cli.add_settings(parser.add_argument_group("discretization"), FemDemSettings, DISCRETISATION)
cli.add_output_options(parser, "results/femdem_biaxial")
cli.add_checkpoint_options(parser, "femdem_biaxial",
                           solver_options=("tangent", "jacobian_lag", "jacobian_refresh", "fallback_tangent", "fallback_hold", "retry_damping", "force_rtol", "accept_rtol", "stagnation_its", "batched",
                                           "cell_threads", "cell_device"))
g = parser.add_argument_group("specimen and loading (000 section 4.1)")
g.add_argument("--mesh", default="2x4", help="NXxNY rectangles (000: 1x1, 1x2, 2x4, 4x8; default %(default)s)")
cli.add_settings(g, FemDemSettings, SPECIMEN)
g = parser.add_argument_group("the cell (as demos/dem_cell.py)")
cli.add_settings(g, CellOptions, ("particles", "seed", "anisotropy"))
g.add_argument("--packing", default=None, help="packing file (.npz from demos/dem_cell.py) instead of generating one")
cli.add_settings(g, CellOptions, CELL)
g.add_argument("--cell-option", type=cli.key_value, action="append", default=[], metavar="KEY=VALUE",
               help="a further demcell.RelaxationOptions of the cells, e.g. method=local (local damping instead "
                    "of the default FIRE), dt_safety=0.5, fixed_steps=100 (YADE's way: N DEM steps per solve, no "
                    "relaxation), relax_cap=none (FIRE relaxations not stopped after the default 500 steps) "
                    "(repeat for more; docs/reference/femdem.md, 'The cells' relaxation')")
g = parser.add_argument_group("coupling")
cli.add_settings(g, FemDemSettings, COUPLING)
g.add_argument("--retry-damping", type=RetryDamping(), default=DEFAULT_RETRY_DAMPING,
               help="a step that failed with --tangent and --fallback-tangent is solved once more from the "
                    "committed state on the fallback with Newton updates x += this * dx before it is cut "
                    "(history.csv column damped; default %(default)g = none: cut at once; measured not to rescue a step so far; "
                    "docs/reference/femdem.md, 'Past the peak')")
g.add_argument("--accept-rtol", type=number(NON_NEGATIVE), default=3e-2,
               help="a step whose Newton stagnates ends at its best iterate if FNORM/RNORM <= this, reported as "
                    "accepted (default %(default)g; 0: never)")
g.add_argument("--stagnation-its", type=number(NON_NEGATIVE_INTEGER), default=4,
               help="... and ends it as soon as its best FNORM/RNORM gained less than 10 %% in this many "
                    "iterations (default %(default)s; 0: only at -snes_max_it)")
g.add_argument("--write-every", type=number(COUNT), default=1, help="XDMF every N steps and at the end (default %(default)s)")
cli.add_settings(parser.add_argument_group("the cells' ranks and devices"), FemDemSettings, CELLS)


def femdem_settings(args):
    """The scene's settings from the options."""
    nx, ny = parse_mesh(args.mesh)
    return FemDemSettings(
        nx=nx, ny=ny, **cli.settings_values(FemDemSettings, args, DISCRETISATION + SPECIMEN + COUPLING + CELLS),
        accept_rtol=args.accept_rtol if args.accept_rtol != 0 else None,
        retry_damping=args.retry_damping,
        stagnation_its=args.stagnation_its if args.stagnation_its != 0 else None,
        cell=CellOptions(**dict(cli.settings_values(CellOptions, args, ("particles", "seed", "anisotropy") + CELL),
                                packing=args.packing, extra=dict(args.cell_option),
                                # a checkpoint's options may hold the older flag no_rotation instead
                                rotation=args.rotation and not getattr(args, "no_rotation", False))))


def check(args):
    if args.mode == "classical" and (args.mu_c is not None or args.l_c is not None):
        raise ValueError("--mu-c and --l-c are micropolar options: a classical (Cauchy) scene has no rotation field")
    if args.mode == "micropolar" and (args.mu_c is not None or args.l_c is not None):
        raise ValueError("--mu-c and --l-c are hybrid-mode options: in mode micropolar the skew and couple "
                         "stresses come from the cells")
    if args.packing is not None and args.restart is None:
        ignored = sorted(parser.given_options() & {"particles", "seed", "anisotropy"})
        if ignored:           # the file sets the discs: these would be silently without effect
            raise ValueError(f"--packing gives the discs: {', '.join('--' + o for o in ignored)} would have no "
                             f"effect (leave {'it' if len(ignored) == 1 else 'them'} out)")
    if args.micro_bc == "frame" and (args.checkpoint_every or args.restart is not None):
        raise ValueError("--micro-bc frame: checkpoints and restarts save periodic cell states (a frame cell "
                         "is not restored from one)")
    if args.micro_bc != "frame" and args.frame_thickness is not None:
        raise ValueError("--frame-thickness is an option of --micro-bc frame")
    femdem_settings(args).check()             # every option, before any cell exists


args = cli.parse(parser, check=check)
comm = MPI.COMM_WORLD
settings = femdem_settings(args)
nx, ny = settings.nx, settings.ny
run = DemoRun(comm, args, "femdem", {"options": {k: v for k, v in vars(args).items() if k != "elasticity"}})
# e.g. a packing that cannot be compacted (demcell errors)
test = run.build(lambda: FemDemBiaxial(comm, settings), "preparing the cells", errors=(ValueError, RuntimeError))
n_points = comm.allreduce(len(test.points))
print0(comm, f"femdem: {args.mode} mode, {args.tangent} tangent, mesh {nx}x{ny}, {n_points} Gauss points "
             f"({test.n_weak_cells} weak elements), {test.packing_info['n_particles']} discs per cell, "
             f"{comm.size} rank(s), cells on {test.cell_device}; cells prepared in {test.preparation_time:.1f} s"
             + (f"; mu_c = {test.mu_c:.4g} N/m, l_c = {test.l_c:.4g} m" if test.mu_c else "")
             + (f" (the cells' moduli, {test.cell_moduli['moduli_from']}: G = {test.cell_moduli['G']:.4g} N/m, "
                f"B = {test.cell_moduli['bending_modulus']:.4g} N m, l_c / d = "
                f"{test.cell_moduli['l_c_over_grain_diameter']:.3g})" if test.cell_moduli else ""))

# (axial_strain, stress ratios in the rank-independent order) per step, on rank 0; kept in the
# checkpoints (--checkpoint-every, --stop-after) and continued by --restart
per_point = run.start(test, {"per_point": []})["per_point"]

# --- outputs written as the run goes ---------------------------------------------------
run.fields(test.cell_fields())
history = run.log("history.csv", ["step", "time", "phase", "axial_strain", "stress_ratio", "volumetric_strain",
                                  "coordination_number", "anisotropy", "sliding_fraction", "vertical_reaction",
                                  "vertical_stress", "mean_sigma11", "mean_sigma22", "newton_iterations",
                                  "force_ratio", "accepted", "fallback", "damped", "dem_steps", "capped_solves",
                                  "points_without_contacts", "cuts",
                                  "wall_time"])
gauss_log = run.log("gauss_points.csv", ["step", "axial_strain", "point", "x", "y", "stress_ratio"])


def record(row):
    history.write(row)
    pts, ratios = test.global_order(test.gauss_point_ratios())
    if comm.rank == 0:
        per_point.append((row["axial_strain"], ratios))
        for k, (xy, r) in enumerate(zip(pts, ratios)):
            gauss_log.write({"step": row["step"], "axial_strain": row["axial_strain"], "point": k,
                             "x": xy[0], "y": xy[1], "stress_ratio": r})


run.run(record, lambda row: {"final_axial_strain": row["axial_strain"]}, write_every=args.write_every)

# --- particle snapshots of the Gauss points with the highest and lowest stress ratio ------
ratios = test.gauss_point_ratios()
snapshots = {}
for label, pick in (("highest_stress_ratio", np.argmax), ("lowest_stress_ratio", np.argmin)):
    local = (float(ratios[pick(ratios)]) if len(ratios) else (-np.inf if pick is np.argmax else np.inf),
             comm.rank, int(pick(ratios)) if len(ratios) else -1)
    everyone = comm.allgather(local)
    best = max(everyone) if pick is np.argmax else min(everyone)
    # the committed cell (a balanced run may work on it on another rank: export_points fetches it)
    cell = test.material.export_points([best[2]] if comm.rank == best[1] else [])
    if comm.rank == best[1]:
        import demcell
        from demcell.state import unpack_states
        directory = os.path.join(args.out, "snapshots", label)
        demcell.write_vtk_snapshot(directory, 0, unpack_states(cell)[0])
    xy = comm.bcast(test.points[best[2]].tolist() if comm.rank == best[1] else None, root=best[1])
    snapshots[label] = {"stress_ratio": best[0], "x": xy[0], "y": xy[1],
                        "files": f"snapshots/{label}/particles_0000.vtk, contacts_0000.vtk"}

# --- summary --------------------------------------------------------------------------------
rows = [r for r in test.history if r["phase"] == 2]
band, band_entries = None, no_band("no compression step")
if rows:
    band, band_entries = assess_band(test.band, min(args.width / nx, args.height / ny), args.width, args.height)
for key, text in (("no_band_reason", "no band"), ("band_warning", "band"), ("mesh_warning", "mesh")):
    if band_entries[key]:
        print0(comm, f"femdem: {text}: {band_entries[key]}")
ratio = np.array([r["stress_ratio"] for r in rows]) if rows else np.zeros(0)
i_peak = int(np.argmax(ratio)) if len(ratio) else None
iterations = [r["newton_iterations"] for r in rows]
timing = {k: max_over_ranks(comm, v) for k, v in test.timing().items()}
memory = comm.allreduce(test.material.memory_bytes())
summary = {
    "peak_stress_ratio": float(ratio[i_peak]) if rows else None,
    "axial_strain_at_peak": float(rows[i_peak]["axial_strain"]) if rows else None,
    "friction_angle_at_peak_deg": float(math.degrees(math.asin(min(1.0, ratio[i_peak])))) if rows else None,
    "final_stress_ratio": float(ratio[-1]) if rows else None,
    "final_axial_strain": float(rows[-1]["axial_strain"]) if rows else None,
    "n_gauss_points": n_points, "particles_per_cell": test.packing_info["n_particles"], "micro_bc": args.micro_bc,
    **band_entries,
    "band_thickness_definition": "H = standard deviation of the bell fitted to the equivalent strain (thesis 4.22); FWHM = 2.355 H",
    "newton_iterations_total": int(sum(iterations)),
    "newton_iterations_mean_before_peak": float(np.mean(iterations[:i_peak + 1])) if rows else None,
    "newton_iterations_mean_after_peak": float(np.mean(iterations[i_peak + 1:])) if rows and i_peak + 1 < len(rows) else None,
    "newton_force_ratios": [info.force_ratios for info in test.solver.infos_converged()],
    "steps_accepted_above_force_rtol": int(sum(r["accepted"] for r in test.history)),
    "steps_with_fallback_tangent": int(sum(r["fallback"] for r in test.history)),
    "steps_with_damped_retry": int(sum(r.get("damped", 0) for r in test.history)),
    "dem_steps_total": float(sum(r["dem_steps"] for r in test.history)),
    "cell_tangents_total": comm.allreduce(test.point_tangents()),
    "cell_solves_redone_with_local_damping": comm.allreduce(test.cell_solves_redone()),
    "cell_solves_capped": comm.allreduce(test.cell_solves_capped()),
    "operator_rule": list(settings.jacobian_rule()),
    "steps": len(test.history), "cut_backs": test.stepper.cuts,
    "cell_preparation_time": test.preparation_time, "ranks": comm.size,
    "cell_device": test.cell_device,
    "time_max_over_ranks": timing,
    "memory_per_cell_bytes": memory / n_points, "snapshots": snapshots,
    "mode": test.material.describe(), "mu_c": test.mu_c, "l_c": test.l_c, "cell_moduli": test.cell_moduli,
    "length_scale": test.length_scale, "packing": test.packing_info,
    "options": {k: v for k, v in vars(args).items() if k != "elasticity"},
    "balance": test.balance_report(),
}
run.finish(summary)

# --- figure: 000 Figs 4-6 -----------------------------------------------------------------------
if comm.rank == 0 and rows:
    plt = pyplot()
    rows_all = test.history
    eps = np.array([-r["axial_strain"] * 100 for r in rows_all])
    fig, ax = plt.subplots(2, 3, figsize=(14, 7.5))
    if per_point:
        curves = np.array([p[1] for p in per_point])
        ax[0, 0].plot(eps, curves, "-", color="0.75", lw=0.5)
    ax[0, 0].plot(eps, [r["stress_ratio"] for r in rows_all], "k-", lw=2, label="mean over Gauss points")
    ax[0, 0].set_ylabel("stress ratio |s11-s22|/|s11+s22| (000 eq. 40)"); ax[0, 0].legend()
    panels = [("volumetric_strain", "volumetric strain (tension +)"), ("coordination_number", "coordination number"),
              ("anisotropy", "fabric anisotropy A (000 eq. 38)"), ("vertical_stress", "platen reaction / W [N/m]")]
    for a, (key, label) in zip([ax[0, 1], ax[0, 2], ax[1, 0], ax[1, 1]], panels):
        a.plot(eps, [r[key] for r in rows_all], "b-")
        a.set_ylabel(label)
    ax[1, 2].plot(eps, [r["newton_iterations"] for r in rows_all], "r.")
    ax[1, 2].set_ylabel("Newton iterations per step")
    for a in ax.flat:
        a.set_xlabel("axial strain -eps_22 [%]"); a.grid(alpha=0.3)
    fig.suptitle(f"FEM x DEM biaxial, {args.mode} mode, mesh {nx}x{ny} ({n_points} cells), "
                 f"{test.packing_info['n_particles']} discs, {args.tangent} tangent"
                 + (f"; band H = {band.thickness * 1e3:.2f} mm, {band.inclination_deg:.0f} deg" if band else ""))
    fig.tight_layout(); fig.savefig(os.path.join(args.out, "femdem_biaxial.png"), dpi=110)
    plt.close(fig)
print0(comm, f"peak stress ratio {summary['peak_stress_ratio']} at axial strain {summary['axial_strain_at_peak']}; "
             f"band H = {summary['band_thickness']}; {run.wall_time:.0f} s; outputs in {args.out}")
run.exit()
