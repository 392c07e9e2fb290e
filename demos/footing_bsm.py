"""Strip footing by the bridging-scale method (paper 003, Li and Wan 2010, section 3).

A Cosserat continuum (explicit dynamics, 003 eqs 19-20 and 31-34) covers the whole 18 m x 9 m
foundation on 003's mesh (18 x 9 Q1 elements of 1 m; --element P2/P1 for the project's
triangles). A 6 m x 3 m DEM region under the 2 m plate (x in [6, 12] m, y in [6, 9] m, six by
three whole elements; --region-width, --region-depth for another) holds the grains of packing A, B or C (003 Table 1 contact law). Inside
it the grains' motion is split into a coarse part, interpolated from the nodes, and a fine
part (the mass-weighted projection, eqs 3-8); the nodes of the region take their mass and
forces from the grains (eq 16, including the reactions on the virtual interface grains);
the virtual grains just outside the region follow the continuum (eq 17). The rigid plate acts
on the grains only (003-bsm.md decision 8), pushed down at --speed to --depth. The DEM
sub-cycles m times per coarse step (eqs 25-30). Bottom fixed (003; --bottom smooth: u2 = 0 only,
as the full DEM's smooth wall), sides u1 = 0. No gravity by
default (003 mentions none); with --gravity g the continuum and the grains first settle under
their weight for --settle-time (the grains with local damping, the continuum with the mass
damping that damps its lowest mode critically), then the plate is put on the settled surface
and pushed; the settlement counts from there.

The grains are cut out of the same packing the full-DEM reference would use (the whole
domain filled with discs, demcell.specimen.footing.footing_packing): compare with
`python3 -c "from demcell.specimen.footing import run_footing; ..."` (see README).

MPI: the DEM region lives on rank 0 (it is small); the continuum is distributed.

Outputs in --out, written as the run goes: history.csv (time, settlement, plate load per
metre of depth, the coarse/projection mismatch), summary.json, load_settlement.png,
continuum.xdmf (u, phi of the continuum), grains_NNNN.vtk (every grain with its
displacement, its coarse part N d and fine part Q q, rotation, virtual flag) and
grains.vtk.series (the grain files with the continuum's times, so that ParaView plays both on
one clock) and paraview_footing.py, a ParaView Python state that opens them together:

    paraview --state=OUT/paraview_footing.py      (or File > Load State in ParaView)

shows the continuum coloured by |u| (the DEM region's elements are empty of stiffness, not of
mesh) and the grains on it as "Point Gaussian" discs of their radius coloured by the fine
part |Q q| (by hand: open continuum.xdmf with "Xdmf3 Reader T" and grains.vtk.series).

Checkpoint and restart as the other long demos (docs/reference/restart.md): --checkpoint-every
N coarse steps, --stop-after K, --restart DIR (history.csv, continuum.xdmf and the grain series
continued); SIGINT/SIGTERM end the run after the current coarse step with a checkpoint and
"interrupted by SIGTERM after step k" in summary.json. The continuum's state is keyed by dof
coordinates: a restart on the ranks that wrote the checkpoint repeats the straight run bit for
bit, on another number of ranks it continues with the sums in another order (and its fields
go to continuum_from_stepK.xdmf: an XDMF file keeps the partition that wrote it).

    mpirun -n 2 python3 demos/footing_bsm.py --packing A
"""
# %% imports
import sys, os  # noqa: E401
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
# BLAS/OpenMP threads that spin after each small solve starve the DEM kernel's threads (a
# 10x slow-down measured on 2 cores): one BLAS thread unless the user asks otherwise
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import json
import math
import time

import dolfinx.fem
import dolfinx.io
import dolfinx.mesh
import numpy as np
from mpi4py import MPI

from cosserat_fenicsx import cli
from cosserat_fenicsx.checkpoint import CheckpointError, StateCheckpointer, checkpoint_path
from cosserat_fenicsx.bridging.coupler import BridgingCoupler, BridgingStopped
from cosserat_fenicsx.bridging.region import build_region, region_cells
from cosserat_fenicsx.dynamics.explicit import DynamicsError, ExplicitCosserat
from cosserat_fenicsx.elasticity import MicropolarElasticity
from cosserat_fenicsx.lattice_elasticity import SquareLatticeElasticity
from cosserat_fenicsx.figures import pyplot
from cosserat_fenicsx.output import CsvLog, print0, truncate_xdmf
from cosserat_fenicsx.run_guard import RunGuard
from cosserat_fenicsx.validation import NON_NEGATIVE, POSITIVE, Range, number

# %% options
parser = cli.make_parser(__doc__)
parser.add_argument("--packing", choices=("A", "B", "C"), default="A",
                    help="003 packing: A (lattice, r = 0.05 m), B (lattice, r = 0.03 m), C (random, 0.02-0.05 m)")
parser.add_argument("--element", choices=("Q1/Q1", "P2/P1"), default="Q1/Q1")
parser.add_argument("--speed", type=number(POSITIVE), default=1.0, help="plate speed [m/s] (default %(default)g)")
parser.add_argument("--depth", type=number(Range(0.0, 0.5, low_open=True)), default=0.06,
                    help="final settlement [m] (default %(default)g)")
parser.add_argument("--mass-damping", type=number(NON_NEGATIVE), default=10.0,
                    help="c_m [1/s] on both scales (003 gives none; default %(default)g)")
parser.add_argument("--substeps", type=number(Range(1, 1000, integer=True)), default=None,
                    help="DEM sub-steps per coarse step m (default: the largest the coarse stable step allows)")
parser.add_argument("--domain-width", type=number(Range(6.0, 200.0)), default=18.0,
                    help="width of the foundation [m] (003: 18); the DEM region stays centred under the plate")
parser.add_argument("--region-width", type=number(Range(2.0, 200.0)), default=6.0,
                    help="width of the DEM region [m], centred (003: 6; whole elements of 1 m)")
parser.add_argument("--region-depth", type=number(Range(1.0, 9.0)), default=3.0,
                    help="depth of the DEM region below the surface [m] (003: 3; whole elements of 1 m)")
parser.add_argument("--continuum", choices=("003", "lattice", "lattice-cubic", "lattice-coulomb"), default="003",
                    help="continuum moduli: 003's (E = 500 MPa, nu = 0.2, G_c = 70 MPa) or, for packings A/B, the "
                         "orientation average of the rotated square lattice's affine moduli (lattice: G = (kN + kS)/4, "
                         "lambda = (kN - kS)/4, mu_c = kS/2) or the lattice's own cubic law (lattice-cubic: "
                         "cosserat_fenicsx.lattice_elasticity) or that law with its contacts sliding at the "
                         "friction limit and opening in tension (lattice-coulomb: "
                         "cosserat_fenicsx.materials.lattice_coulomb)")
parser.add_argument("--rough", action="store_true", help="rough plate (Coulomb friction mu_s; default smooth)")
parser.add_argument("--bottom", choices=("fixed", "smooth"), default="fixed",
                    help="the continuum's base: fixed (003) or smooth, u2 = 0 only (the full DEM's smooth wall)")
parser.add_argument("--gravity", type=number(NON_NEGATIVE), default=0.0,
                    help="g [m/s^2] downwards on the grains and the continuum (default 0, as 003)")
parser.add_argument("--settle-time", type=number(POSITIVE), default=0.3,
                    help="settling under gravity before the plate moves [s] (default %(default)g)")
parser.add_argument("--record-every", type=number(Range(1, integer=True)), default=5,
                    help="coarse steps between two history rows (default %(default)s)")
parser.add_argument("--output-every", type=number(Range(1, integer=True)), default=10,
                    help="history rows between two XDMF/VTK outputs (default %(default)s)")
parser.add_argument("--summary-interval", type=number(NON_NEGATIVE), default=1.0,
                    help="summary.json is rewritten at most this often [s] (default %(default)g; 0: after every "
                         "recorded step); always at the start, the end and a stop")
parser.add_argument("--seed", type=number(Range(0, integer=True)), default=0, help="packing C's seed")
parser.add_argument("--region-nodes", choices=("integrated", "projected"), default="integrated",
                    help="BridgingCoupler(region_nodes=...): the region's nodes under 003 eq 16 (default), or "
                         "set to the grains' projection d_hat(q) with the interface under N_V^T F_V only")
parser.add_argument("--threads", type=number(Range(1, 256, integer=True)), default=1,
                    help="Numba threads of the DEM kernel (default 1: a region of a few thousand grains gains "
                         "nothing from threads, and loses 10-40x on a loaded machine)")
cli.add_output_options(parser, "results/footing_bsm")
cli.add_checkpoint_options(parser, "footing_bsm")
args = cli.parse(parser)
comm = MPI.COMM_WORLD
ROOT = 0
checkpoint = StateCheckpointer(comm, args.out, args.checkpoint_label, cli.run_options(args),
                               every=args.checkpoint_every, stop_after=args.stop_after,
                               restart=args.restart is not None)
resumed = None
if args.restart is not None:
    try:        # another rank count, a damaged file: one line before any work
        resumed = checkpoint.read()
    except CheckpointError as error:
        parser.refuse(f"--restart {args.restart}: {error}")

# %% 003's foundation: geometry, continuum moduli (section 5; E = 500 MPa, nu = 0.2, G_c = 70
# MPa, l_c = 0.05 m in the G-reading of eq 20: the project's l_c = l_c sqrt(G / (2 G_c)))
WIDTH, HEIGHT, PLATE = args.domain_width, 9.0, 2.0
BOX = (0.5 * (WIDTH - args.region_width), 0.5 * (WIDTH + args.region_width), HEIGHT - args.region_depth, HEIGHT)
if args.region_width >= WIDTH:
    parser.refuse(f"--region-width {args.region_width:g} m must be less than --domain-width {WIDTH:g} m: the "
                  "continuum must surround the DEM region (the full DEM is demcell.specimen.footing)")
E_MOD, NU, G_C, L_C = 500e6, 0.2, 70e6, 0.05
G = E_MOD / (2 * (1 + NU))
LAMBDA = 2 * G * NU / (1 - 2 * NU)
if args.continuum.startswith("lattice"):
    # the +-45 degree square lattice (l = 2 r, area 4 r^2 per disc, two contacts per disc):
    # C1111 = C1212 = (kN + kS)/2, C1122 = C1221 = (kN - kS)/2, C2121 = C1111; cubic, so the
    # isotropic moduli are orientation averages (bulk, mean shear, skew part)
    if args.packing == "C":
        parser.refuse(f"--continuum {args.continuum} is defined for the lattices A and B only")
    from demcell.specimen.footing import KN, KS
    G, LAMBDA, G_C = (KN + KS) / 4.0, (KN - KS) / 4.0, KS / 2.0
elasticity = MicropolarElasticity(mu=G, lmbda=LAMBDA, mu_c=G_C, l_c=L_C * math.sqrt(G / (2 * G_C)))
# the longitudinal modulus of a vertical column (the settling's lowest mode)
column_modulus = LAMBDA + 2 * G
material = None
if args.continuum in ("lattice-cubic", "lattice-coulomb"):
    elasticity = SquareLatticeElasticity(k_n=KN, k_s=KS, l_c=elasticity.l_c)
    column_modulus = elasticity.moduli[0]
if args.continuum == "lattice-coulomb":
    from cosserat_fenicsx.materials.lattice_coulomb import LatticeCoulombMaterial
    from demcell.specimen.footing import MU
    material = LatticeCoulombMaterial(KN, KS, MU, elasticity.bending_modulus)
guard = RunGuard(comm, os.path.join(args.out, "summary.json"), label="footing_bsm",
                 entries={"packing": args.packing, "element": args.element, "speed": args.speed,
                          "depth": args.depth, "mass_damping": args.mass_damping, "ranks": comm.size},
                 write_now=resumed is None, min_interval=args.summary_interval)

# %% the mesh, and the region checked against it before any work (whole elements)
cell = dolfinx.mesh.CellType.quadrilateral if args.element == "Q1/Q1" else dolfinx.mesh.CellType.triangle
mesh = dolfinx.mesh.create_rectangle(comm, [np.array([0.0, 0.0]), np.array([WIDTH, HEIGHT])],
                                     [int(round(WIDTH)), int(round(HEIGHT))], cell)
try:
    inactive = region_cells(mesh, BOX)
except ValueError as error:
    guard.refuse(error)

# %% the grains: the full-domain packing (the same grains a full-DEM run uses), cut to the
# region and its virtual layer (rank 0 builds, every rank gets the arrays)
t_setup = time.perf_counter()
packing = None
if comm.rank == ROOT:
    from demcell.specimen.footing import DENSITY, footing_packing
    discs = footing_packing(args.packing, (0.0, WIDTH, 0.0, HEIGHT), seed=args.seed)
    packing = (discs.position, discs.radius, discs.mass, discs.inertia, discs.solid_fraction(), DENSITY)
position, radius, mass, inertia, solid_fraction, density = comm.bcast(packing, root=ROOT)
region = build_region(position, radius, mass, inertia, BOX, (0.0, WIDTH, 0.0, HEIGHT),
                      layer="touching" if args.packing in ("A", "B") else "diameter")
n_full = len(radius)
print0(comm, f"packing {args.packing}: {region.n_real} grains in the DEM region + {region.n_virtual} virtual "
             f"(full domain: {n_full} grains)")

# %% the continuum: mass rho_s * solid fraction, micro-inertia <r^2>/2 (003-bsm.md section 5 [R])
rho_c = density * solid_fraction
j = 0.5 * float(np.mean(radius ** 2))
dirichlet = [("u2", lambda x: np.isclose(x[1], 0.0), 0.0),
             ("u1", lambda x: np.isclose(x[0], 0.0) | np.isclose(x[0], WIDTH), 0.0)]
if args.bottom == "fixed":
    dirichlet.append(("u1", lambda x: np.isclose(x[1], 0.0), 0.0))
continuum = ExplicitCosserat(mesh, elasticity, rho_c, j, mass_damping=args.mass_damping, element=args.element,
                             inactive_cells=inactive, dirichlet=dirichlet, gravity=(0.0, -args.gravity),
                             material=material)

# %% the DEM region on rank 0: Table 1 law, the plate on the grains under it, virtual grains held
engine, engine_info = None, None
if comm.rank == ROOT:
    from demcell.specimen.footing import footing_specimen
    from demcell.specimen.specimens import discs_from
    region_discs = discs_from(region.position, region.radius, mass=region.mass)
    engine, engine_info = footing_specimen(args.packing, WIDTH, HEIGHT, PLATE, rough=args.rough,
                                           mass_damping=args.mass_damping, discs=region_discs, lateral="none",
                                           threads=args.threads, gravity=args.gravity)
    engine.hold(region.is_virtual)
dt_fine = comm.bcast(engine.options.dt if engine is not None else None, root=ROOT)
stable = continuum.stable_time_step()  # without the grains' mass: the coupler checks again with it
substeps = args.substeps or max(1, int(0.9 * stable["power"] / dt_fine))
try:
    coupler = BridgingCoupler(continuum, region, engine, dt_fine * substeps, substeps, fine_dt=dt_fine,
                              region_nodes=args.region_nodes)
except ValueError as error:
    guard.refuse(error)
dt = coupler.dt
n_steps = int(math.ceil(args.depth / (args.speed * dt) - 1e-9))
print0(comm, f"coarse dt = {dt:.3g} s (stable {coupler.stable_dt['power']:.3g} s), m = {substeps} DEM sub-steps "
             f"of {dt_fine:.3g} s, {n_steps} coarse steps")
guard.progress(grains_real=region.n_real, grains_virtual=region.n_virtual, grains_full_domain=n_full,
               dt=dt, substeps=substeps, dt_fine=dt_fine, stable_dt=coupler.stable_dt, region=region.summary())
setup_seconds = time.perf_counter() - t_setup

# %% outputs as the run goes
# a restart: the coupled state (continuum per rank, the region's engine, the coupler's run
# state) and the demo's own (history rows, output index, plate origin) of the checkpoint
y0 = comm.bcast(engine.plate_position()[2] if engine is not None else None, root=ROOT)
settle_steps = 0
settled = {}
rows = []
outputs = {"index": 0, "series": [], "wall_s": 0.0, "cpu_s": 0.0, "xdmf": "continuum.xdmf"}
same_partition = False
if resumed is not None:
    meta, states, run_state = resumed
    try:
        coupler.set_state(states)
        if coupler.steps != meta["step"]:
            raise ValueError(f"the coupler state is at step {coupler.steps}, meta.json says {meta['step']}")
        rows, y0 = list(run_state["rows"]), float(run_state["y0"])
        settle_steps = int(run_state.get("settle_steps", 0))
        outputs.update({k: run_state[k] for k in ("index", "series", "wall_s", "cpu_s", "xdmf")})
        # the XDMF file keeps the nodes in the order of the partition that wrote it: it goes on
        # only where this run's partition is that one (dolfinx's partition of the same mesh on
        # the same ranks is not always the same), otherwise a new series from this step
        same_partition = comm.allreduce(
            len(states) == comm.size and np.array_equal(states[comm.rank]["continuum_dof_coordinates"],
                                                        continuum.dof_keys()[0]), op=MPI.LAND)
        if not same_partition:
            outputs["xdmf"] = f"continuum_from_step{coupler.steps}.xdmf"
    except (ValueError, KeyError, TypeError) as error:        # InputError is a ValueError
        guard.refuse(f"--restart {args.restart}: {checkpoint_path(args.out)} does not fit this run: {error}")
    print0(comm, f"footing_bsm: continuing from the checkpoint of step {coupler.steps} (t = {continuum.time:.6g} s)")

guard.steps = coupler.steps        # the coarse steps done (the setup's progress line is not one)
history = CsvLog(comm, os.path.join(args.out, "history.csv"),
                 ["step", "time", "settlement_mm", "load_kN_per_m", "mismatch_over_rmin", "fe_kinetic_J_per_m"],
                 resume_step=coupler.steps if resumed is not None else None)
xdmf_path = os.path.join(args.out, outputs["xdmf"])
# the file is open only while it is written, and a signal waits until it is closed: an
# interrupted run leaves it readable
with guard.deferred():
    if not same_partition or not os.path.isfile(xdmf_path):
        with dolfinx.io.XDMFFile(comm, xdmf_path, "w") as xdmf:
            xdmf.write_mesh(mesh)
    else:       # the series goes on after the checkpoint's time (later steps of a killed run dropped)
        if comm.rank == ROOT:
            truncate_xdmf(xdmf_path, continuum.time)
        comm.barrier()
u_space, u_map = continuum.subspace("u")
phi_space, phi_map = continuum.subspace("phi")
u_out = dolfinx.fem.Function(u_space, name="u")
phi_out = dolfinx.fem.Function(phi_space, name="phi")


def write_series():
    """grains.vtk.series: ParaView's file-series list, each grain file at its time [s]."""
    files = [{"name": name, "time": t} for name, t in outputs["series"]]
    tmp = os.path.join(args.out, "grains.vtk.series.tmp")
    with open(tmp, "w") as f:
        json.dump({"file-series-version": "1.0", "files": files}, f, indent=1)
    os.replace(tmp, os.path.join(args.out, "grains.vtk.series"))


PARAVIEW_STATE = """# ParaView Python state of demos/footing_bsm.py: paraview --state=paraview_footing.py
# (or File > Load State). The continuum and the grains on one clock (the run's time [s]).
import os
from paraview import simple
here = {directory!r}
try:
    here = os.path.dirname(os.path.abspath(__file__)) or here
except NameError:
    pass
continuum = simple.Xdmf3ReaderT(registrationName="continuum", FileName=[os.path.join(here, {xdmf!r})])
grains = simple.OpenDataFile(os.path.join(here, "grains.vtk.series"), registrationName="grains")
view = simple.GetActiveViewOrCreate("RenderView")
shown = simple.Show(continuum, view)
simple.ColorBy(shown, ("POINTS", "u", "Magnitude"))
shown.SetScalarBarVisibility(view, True)
discs = simple.Show(grains, view)
discs.SetRepresentationType("Point Gaussian")
discs.Position = [0.0, 0.0, 0.01]        # in front of the continuum's plane
discs.ScaleByArray = 1
discs.SetScaleArray = ["POINTS", "radius"]
discs.ScaleTransferFunction.Points = [0.0, 0.0, 0.5, 0.0, 1.0, 1.0, 0.5, 0.0]
discs.GaussianRadius = 1.0
discs.ShaderPreset = "Plain circle"
simple.ColorBy(discs, ("POINTS", "fine", "Magnitude"))
discs.SetScalarBarVisibility(view, True)
scene = simple.GetAnimationScene()
scene.UpdateAnimationUsingDataTimeSteps()
scene.AnimationTime = scene.EndTime
shown.RescaleTransferFunctionToDataRange(False, True)
discs.RescaleTransferFunctionToDataRange(False, True)
view.InteractionMode = "2D"
simple.ResetCamera(view)
simple.Render(view)
"""


def write_paraview_state():
    """paraview_footing.py in the output directory (rank 0): the XDMF file this run writes."""
    if comm.rank == ROOT:
        with open(os.path.join(args.out, "paraview_footing.py"), "w") as f:
            f.write(PARAVIEW_STATE.format(directory=os.path.abspath(args.out), xdmf=outputs["xdmf"]))


def write_fields():
    disp = continuum.fields["displacement"].x.array
    u_out.x.array[:] = disp[u_map]
    phi_out.x.array[:] = disp[phi_map]
    with dolfinx.io.XDMFFile(comm, xdmf_path, "a") as xdmf:
        xdmf.write_function(u_out, continuum.time)
        xdmf.write_function(phi_out, continuum.time)
    parts = coupler.fine_part()
    if comm.rank == ROOT:
        from demcell.specimen.files import write_particles_vtk
        q, coarse, fine = parts
        n = region.n_discs
        full_q = coupler.grain_motion()
        data = {"displacement": full_q[:, :2], "rotation": full_q[:, 2],
                "coarse": np.zeros((n, 2)), "fine": np.zeros((n, 2)),
                "virtual": region.is_virtual.astype(float)}
        data["coarse"][region.real] = coarse[:, :2]
        data["fine"][region.real] = fine[:, :2]
        name = f"grains_{outputs['index']:04d}.vtk"
        write_particles_vtk(os.path.join(args.out, name), region.position + full_q[:, :2], region.radius, data)
        outputs["series"].append([name, continuum.time])
        write_series()
    outputs["index"] += 1


def record():
    plate = None
    if comm.rank == ROOT:
        plate = (y0 - engine.plate_position()[2], -float(engine.plate_reaction()[1]))
    settlement, load = comm.bcast(plate, root=ROOT)
    mismatch = comm.bcast(coupler.last_mismatch, root=ROOT)
    row = {"step": coupler.steps, "time": continuum.time, "settlement_mm": 1e3 * settlement,
           "load_kN_per_m": 1e-3 * load, "mismatch_over_rmin": mismatch,
           "fe_kinetic_J_per_m": continuum.kinetic_energy()}
    history.write(row)
    rows.append(row)
    return row


def save_checkpoint(step):
    """The coupled state and this demo's run state after coarse step `step` (collective)."""
    state = {"rows": rows, "y0": y0, "settle_steps": settle_steps, "index": outputs["index"],
             "series": outputs["series"], "xdmf": outputs["xdmf"],
             "wall_s": outputs["wall_s"] + time.perf_counter() - t0,
             "cpu_s": outputs["cpu_s"] + time.process_time() - c0}
    try:
        checkpoint.write(step, continuum.time, dt, coupler.state(), state)
    except CheckpointError as error:
        history.close()
        guard.stop(error)


write_paraview_state()

# %% gravity: the foundation settles under its weight before the plate moves (the grains
# with local damping, which damps their contacts' vibrations too; the continuum with
# c_m = 2 omega_1, omega_1 = pi c_p / (2 H) its lowest mode), the plate then on the surface
if args.gravity > 0.0 and resumed is None:
    settle_steps = max(1, int(round(args.settle_time / dt)))
    c_settle = math.pi * math.sqrt(column_modulus / rho_c) / HEIGHT
    print0(comm, f"settling under g = {args.gravity:g} m/s^2: {settle_steps} coarse steps, continuum c_m = "
                 f"{c_settle:.3g} 1/s")
    from contextlib import nullcontext
    from demcell.specimen.footing import plate_on_surface, settling
    continuum.set_mass_damping(c_settle)
    try:
        with settling(engine) if comm.rank == ROOT else nullcontext():
            for _ in range(settle_steps):
                coupler.step(diagnose=False)
    except (BridgingStopped, DynamicsError) as error:
        guard.stop(error)
    continuum.set_mass_damping(args.mass_damping)
    top = None
    if comm.rank == ROOT:
        top = plate_on_surface(engine, 0.5 * (WIDTH - PLATE), 0.5 * (WIDTH + PLATE), args.rough)
    top = comm.bcast(top, root=ROOT)
    settled = {"settle_steps": settle_steps, "settle_time": settle_steps * dt, "settle_continuum_c_m": c_settle,
               "surface_drop_mm": 1e3 * (y0 - top), "settle_fe_kinetic_J_per_m": continuum.kinetic_energy()}
    y0 = top
    print0(comm, f"settled: the surface under the plate {settled['surface_drop_mm']:.2f} mm lower, continuum "
                 f"kinetic energy {settled['settle_fe_kinetic_J_per_m']:.3g} J/m")
    guard.progress(**settled)

# %% loading: the plate goes down at --speed; each coarse step = predictor, m DEM sub-steps,
# projected forces, corrector; a checkpoint when due, at --stop-after and on SIGINT/SIGTERM
if resumed is None:
    if comm.rank == ROOT:
        engine.set_plate_velocity(0.0, -args.speed)
    record()
    write_fields()
t0, c0 = time.perf_counter(), time.process_time()
stop_note = ""
try:
    # one deferred block around the loop: a signal waits for the end of the coarse step,
    # where every rank learns of it together and the run ends with a checkpoint
    with guard.deferred():
        last = settle_steps + n_steps
        for step in range(coupler.steps + 1, last + 1):
            recording = (step - settle_steps) % args.record_every == 0 or step == last
            coupler.step(diagnose=recording)
            entries = {}
            if recording:
                row = record()
                entries = {"settlement_mm": row["settlement_mm"], "load_kN_per_m": row["load_kN_per_m"]}
                if (len(rows) - 1) % args.output_every == 0 or step == last:
                    write_fields()
            guard.progress(write=recording, **entries)
            signalled = guard.signalled(comm)
            if checkpoint.due(step) or signalled:
                save_checkpoint(step)
            if signalled:
                history.close()
                guard.interrupt_note = f" (checkpoint written: continue with --restart {args.out})"
                guard.interrupt_now(comm)
            if checkpoint.stops(step) and step < last:
                stop_note = checkpoint.stop_note()
                print0(comm, f"footing_bsm: {stop_note}")
                break
except (BridgingStopped, DynamicsError) as error:
    history.close()
    guard.stop(error)
wall = outputs["wall_s"] + time.perf_counter() - t0
cpu = outputs["cpu_s"] + time.process_time() - c0
history.close()

# %% summary and figure
timing = coupler.timing_summary()
loads = np.array([r["load_kN_per_m"] for r in rows])
settlements = np.array([r["settlement_mm"] for r in rows])
peak = int(np.argmax(loads))
summary = {"packing": args.packing, "element": args.element, "speed": args.speed, "depth": args.depth,
           "mass_damping": args.mass_damping, "rough": args.rough, "ranks": comm.size, "continuum": args.continuum,
           "bottom": args.bottom, "gravity": args.gravity, "settle_steps": settle_steps, **settled,
           "moduli": ({"C11": elasticity.moduli[0], "C12": elasticity.moduli[1], "C66": elasticity.moduli[2],
                       "mu_c": elasticity.mu_c} if args.continuum in ("lattice-cubic", "lattice-coulomb")
                      else {"G": G, "lambda": LAMBDA, "G_c": G_C}),
           "grains_real": region.n_real, "grains_virtual": region.n_virtual, "grains_full_domain": n_full,
           "grain_ratio_full_over_bsm": n_full / (region.n_real + region.n_virtual),
           "dt": dt, "substeps": substeps, "dt_fine": dt_fine, "coarse_steps": n_steps,
           "stable_dt": coupler.stable_dt, "final_settlement_mm": float(settlements[-1]),
           "final_load_kN_per_m": float(loads[-1]), "peak_load_kN_per_m": float(loads[peak]),
           "peak_settlement_mm": float(settlements[peak]),
           "max_mismatch_over_rmin": comm.bcast(coupler.max_mismatch, root=ROOT),
           "wall_s": wall, "cpu_s": cpu, "setup_wall_s": setup_seconds,
           "coupler_setup_wall_s": coupler.setup_seconds, "time_split": timing,
           "load_average": os.getloadavg(), "region": region.summary(),
           "l_c_project": elasticity.l_c, "rho_c": rho_c, "micro_inertia": j, "steps_completed": coupler.steps,
           "fields_file": outputs["xdmf"], **checkpoint.summary_entries()}
if stop_note:
    summary.update(completed=False, reason=stop_note)
if comm.rank == ROOT:
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(5.5, 4))
    ax.plot(settlements, loads, "-", label=f"BSM, packing {args.packing}")
    ax.set_xlabel("settlement [mm]")
    ax.set_ylabel("plate load [kN/m]")
    ax.legend()
    ax.set_title(f"strip footing, {args.speed:g} m/s, c_m = {args.mass_damping:g} 1/s")
    fig.tight_layout()
    fig.savefig(os.path.join(args.out, "load_settlement.png"), dpi=120)
guard.finish(summary)
print0(comm, f"load at {settlements[-1]:.1f} mm: {loads[-1]:.1f} kN/m (peak {loads[peak]:.1f} kN/m at "
             f"{settlements[peak]:.1f} mm); {wall:.1f} s wall, DEM {timing['wall_s']['dem']:.1f} s, "
             f"projection {timing['wall_s']['projection']:.1f} s, FE {timing['wall_s']['fe']:.1f} s, "
             f"interface {timing['wall_s']['interface']:.1f} s")
