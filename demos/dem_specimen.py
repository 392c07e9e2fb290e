#!/usr/bin/python3
"""Biaxial test of a whole particle specimen (DNS): 004 chapter 7 or paper 000's DNS.

What is solved
--------------
A bounded specimen of 2D discs (demcell.specimen: one contact law, force loop and leapfrog
with the periodic cell of FEM x DEM) between two rigid platens, in two phases:

0. isotropic stage: every wall servo-controlled to the confining stress -p (and the free
   sides under the pressure p) until the specimen is at rest; displacements and rotations
   are measured from there;
1. compression: the platens close at --platen-speed each, the lateral boundary keeps p.

Two specimens (``--specimen``):

* ``thesis`` (default): 004 chapter 7 (Table 7.1): monodisperse discs (r = 1 m, m = pi kg per
  m depth) on a triangular grid, 114 x 263 = 29,982 discs by default (--nx, --ny; the text
  says 30,000); E_n = 1e4 N/m, E_t = 100 N/m, D_n = 100 N s/m, mu = 0.8; the free sides under
  p = 50 N/m through pressure arcs and a membrane (004 eqs. 7.44-7.46, E_m = 100 N/m: not in
  the text); platens at 0.03 m/s each for 340 s; no damping but the dashpots in phase 1
  (phase 0 uses local damping 0.7 to settle: 004 does not say how it settled).
* ``tiled``: paper 000's DNS A / B (section 4.2): the FEM x DEM reference cell of
  demos/femdem_biaxial.py (--particles, --seed, the same law: kn = 1e4, ks = 2e3 N/m,
  mu = 0.4, p0 = 10 N/m) tiled --tiles NXxNY times (1x2 is DNS A, 2x4 DNS B), so the DNS and
  FEM x DEM share grains and law (--anisotropy A0: the cell packing made with an initial fabric
  anisotropy, 000 section 4.3.3, as femdem_biaxial.py --anisotropy makes its cells');
  servo-controlled side walls (or --lateral membrane / periodic), local damping 0.7 (000
  section 3.2.1) throughout, platens at the speed that gives an inertial number of 1e-4, to
  an axial strain of 0.1.
* ``file``: the discs of --packing (a demcell packing .npz, tiled --tiles; or a table x y r).

Outputs in --out, written as the run goes:
  history.csv   one row per --output-every [s]: axial, lateral and volumetric strain, platen
                and lateral stress [N/m], stress ratio |s_a - s_l| / |s_a + s_l| (000 eq. 40),
                platen forces [N], coordination, sliding fraction, E_kin/E_el, inertial number
  particles/particles_NNNN.vtk, contacts_NNNN.vtk   at each --snapshots time: the discs with
                displacement, rotation and their REV fields (004 eqs. 7.18-7.42: Cosserat
                strain norm eps_norm, curvature k3x/k3y, stress, skew stress T21 - T12, couple
                stress m3x/m3y, void ratio, coordination), NaN where a REV is invalid; the same
                arrays in particles/fields_NNNN.npz for numpy
  grains.xdmf   the same fields coarse-grained on a grid (Gaussian kernel of --kernel-width)
  summary.json  settings, the isotropic state, peak stress ratio, and at each snapshot the
                shear band of the per-disc Cosserat strain norm fitted by 004 eq. 4.22
                (thickness H, inclination; the same rules as the FE runs), the moment balance
                7.47 (Pearson of div M against -(T21 - T12)), the run's CPU seconds per step
  curve.png     stress ratio and volumetric strain against axial strain
  band_NNNN.png the per-disc strain norm at each snapshot with the fitted band axis

In ParaView: open particles_..vtk (a time series), Glyph (2D Glyph circle, scale by radius,
factor 2), colour by eps_norm to see the bands, or by rotation; open grains.xdmf ("Xdmf3
Reader T") for the fields on the grid. Sign conventions: tension positive (a compressed
specimen has negative axial strain and stress).

    python3 demos/dem_specimen.py                                   # 004, 30,000 discs, 340 s
    python3 demos/dem_specimen.py --nx 20 --ny 40 --duration 60      # a small one, a minute
    python3 demos/dem_specimen.py --specimen tiled --tiles 2x4       # 000's DNS B
"""
import argparse
import json
import math
import os
import sys
import time
import zipfile

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import demcell as dc  # noqa: E402
from demcell.io import CsvLog  # noqa: E402
from demcell.specimen import LostDiscsError, SpecimenOptions  # noqa: E402
from demcell.specimen.biaxial import COLUMNS, BiaxialTest  # noqa: E402
from demcell.specimen.engine import check_time_step  # noqa: E402
from demcell.specimen.fields import coarse_grain, moment_balance, rev_fields  # noqa: E402
from demcell.specimen.files import GridSeries, write_contacts_vtk, write_particles_vtk  # noqa: E402
from demcell.specimen.specimens import read_discs, thesis_lattice, tiled_cell  # noqa: E402
from cosserat_fenicsx.figures import pyplot  # noqa: E402
from cosserat_fenicsx.run_guard import RunGuard  # noqa: E402
from cosserat_fenicsx.shear_band import assess_band, fit_band  # noqa: E402
from cosserat_fenicsx.validation import (NON_NEGATIVE, NON_NEGATIVE_INTEGER, POSITIVE, InputError,  # noqa: E402
                                         Parser, number)

# %% The options, with the defaults of each specimen (None: the specimen's own)
SPECIMEN_DEFAULTS = {
    "thesis": dict(kn=1e4, ks=100.0, friction=0.8, normal_dashpot=100.0, tangential_dashpot=0.0, pressure=50.0,
                   platen_speed=0.03, dt=2e-3, lateral="membrane", loading_damping=0.0, duration=340.0,
                   snapshots=[0.0, 90.0, 120.0, 340.0], output_every=1.0),
    "tiled": dict(kn=1e4, ks=2e3, friction=0.4, normal_dashpot=0.0, tangential_dashpot=0.0, pressure=10.0,
                  platen_speed=None, dt=None, lateral="walls", loading_damping=0.7, axial_strain=0.1,
                  snapshots=None),
}
SPECIMEN_DEFAULTS["file"] = dict(SPECIMEN_DEFAULTS["tiled"])
#: inertial number of the quasi-static default platen speed (tiled and file specimens)
QUASI_STATIC_INERTIAL_NUMBER = 1e-4
#: time step of the tiled and file specimens: this fraction of sqrt(m_min / kn)
DT_FRACTION = 0.1


def tiles(text):
    try:
        nx, ny = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be NXxNY (e.g. 2x4), got {text!r}") from None
    if not (1 <= nx <= 1000 and 1 <= ny <= 1000):
        raise argparse.ArgumentTypeError(f"each count must be in [1, 1000], got {text!r}")
    return nx, ny


def times(text):
    try:
        values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be times in s separated by commas, got {text!r}") from None
    if not values or not all(math.isfinite(v) and v >= 0 for v in values):
        raise argparse.ArgumentTypeError(f"must be finite times >= 0 [s], got {text!r}")
    return sorted(values)


parser = Parser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter,
                allow_abbrev=False, epilog="See the module docstring (head of this file) for details.")
parser.add_argument("--specimen", choices=("thesis", "tiled", "file"), default="thesis",
                    help="thesis (004 ch. 7, default), tiled (000's DNS: the FEM x DEM cell tiled), file (--packing)")
parser.add_argument("--nx", type=number(low=2, high=10 ** 5, integer=True), default=114,
                    help="thesis: discs per row (default 114)")
parser.add_argument("--ny", type=number(low=2, high=10 ** 5, integer=True), default=263,
                    help="thesis: rows (default 263; 114 x 263 = 29,982 discs)")
parser.add_argument("--perturbation", type=number(low=0.0, high=0.5, high_open=True), default=0.0,
                    help="thesis: relative radius noise that breaks the lattice's symmetry (default 0)")
parser.add_argument("--tiles", type=tiles, default=(2, 4), help="tiled/file: copies across x up (default 2x4, DNS B)")
parser.add_argument("--particles", type=number(low=10, high=10 ** 5, integer=True), default=228,
                    help="tiled: discs of the FEM x DEM cell (default 228)")
parser.add_argument("--seed", type=number(NON_NEGATIVE_INTEGER), default=0, help="tiled: packing seed / "
                    "thesis: perturbation seed (default 0)")
parser.add_argument("--anisotropy", type=number(low=0.0, high=1.0, high_open=True), default=None,
                    help="tiled: target initial fabric anisotropy A0 in [0, 1) of the cell packing (000 section "
                         "4.3.3: 0.02, 0.05, 0.08; demcell.generate_packing's deviatoric pre-compaction)")
parser.add_argument("--packing", default=None, help="file: the packing (.npz of demcell, or text x y r)")
parser.add_argument("--density", type=number(POSITIVE), default=None,
                    help="file: grain density [kg/m^2] for a table without masses")
parser.add_argument("--kn", type=number(POSITIVE), default=None, help="normal stiffness E_n [N/m]")
parser.add_argument("--ks", type=number(NON_NEGATIVE), default=None, help="tangential stiffness E_t [N/m]")
parser.add_argument("--friction", type=number(low=0.0, infinite=True), default=None, help="Coulomb mu")
parser.add_argument("--normal-dashpot", type=number(NON_NEGATIVE), default=None, help="D_n [N s/m]")
parser.add_argument("--tangential-dashpot", type=number(NON_NEGATIVE), default=None, help="D_t [N s/m]")
parser.add_argument("--no-rotation", action="store_true", help="lock the grains' rotations")
parser.add_argument("--pressure", type=number(POSITIVE), default=None, help="confining pressure p [N/m]")
parser.add_argument("--lateral", choices=("membrane", "walls", "periodic"), default=None,
                    help="free sides with pressure and membrane, servo side walls, or periodic in x")
parser.add_argument("--membrane-stiffness", type=number(NON_NEGATIVE), default=100.0,
                    help="E_m [N/m] (004 eq. 7.45; not in the text, default 100)")
parser.add_argument("--platen-speed", type=number(POSITIVE), default=None, help="each platen's speed [m/s]")
parser.add_argument("--duration", type=number(POSITIVE), default=None, help="phase 1 length [s]")
parser.add_argument("--axial-strain", type=number(low=0.0, high=0.5, low_open=True), default=None,
                    help="end phase 1 at this axial shortening instead of --duration")
parser.add_argument("--dt", type=number(POSITIVE), default=None, help="time step [s]")
parser.add_argument("--preparation-damping", type=number(low=0.0, high=1.0, high_open=True), default=0.7,
                    help="local damping of phase 0 (default 0.7)")
parser.add_argument("--loading-damping", type=number(low=0.0, high=1.0, high_open=True), default=None,
                    help="local damping of phase 1 (thesis 0, tiled 0.7)")
parser.add_argument("--settle-time", type=number(POSITIVE), default=120.0,
                    help="longest phase 0 [s of simulated time] (default 120)")
parser.add_argument("--threads", type=number(low=1, high=1024, integer=True), default=None,
                    help="Numba threads (default: all cores)")
parser.add_argument("--output-every", type=number(POSITIVE), default=None,
                    help="history row and progress line every this many s (default phase 1 / 200)")
parser.add_argument("--snapshots", type=times, default=None,
                    help="phase 1 times [s] of the particle and field snapshots, comma separated, each taken "
                         "at the first history row at or after it (thesis: 0,90,120,340; otherwise 5 over "
                         "the run)")
parser.add_argument("--kernel-width", type=number(POSITIVE), default=2.0,
                    help="coarse-graining kernel width in mean disc radii (default 2)")
parser.add_argument("--grid-spacing", type=number(POSITIVE), default=2.0,
                    help="grid spacing of grains.xdmf in mean disc radii (default 2)")
parser.add_argument("--checkpoint-every", type=number(POSITIVE), default=None, help="checkpoint every [s] of phase 1")
parser.add_argument("--stop-after", type=number(POSITIVE), default=None,
                    help="stop (with a checkpoint) after this many s of phase 1 (the run continues by --restart)")
parser.add_argument("--restart", default=None, help="the checkpoint.npz of an earlier run with the same options")
parser.add_argument("--out", default="results/dem_specimen", help="output directory")
args = parser.parse_args()
for name, value in SPECIMEN_DEFAULTS[args.specimen].items():
    if getattr(args, name, None) is None:
        setattr(args, name, value)
if args.axial_strain is not None and "--duration" in sys.argv[1:]:
    parser.refuse("give --duration or --axial-strain, not both")
if args.anisotropy is not None and args.specimen != "tiled":
    parser.refuse("--anisotropy is an option of --specimen tiled (the generated cell packing)")
if args.specimen == "file" and args.packing is None:
    parser.refuse("--specimen file needs --packing")
if args.restart is not None and not os.path.isfile(args.restart):
    parser.refuse(f"--restart: no checkpoint at {args.restart}")

# %% The discs (a one-line refusal for an impossible specimen, before any work)
try:
    law = dc.ContactLaw(kn=args.kn, ks=args.ks, friction=args.friction, rotations=not args.no_rotation)
    if args.specimen == "thesis":
        discs = thesis_lattice(args.nx, args.ny, perturbation=args.perturbation, seed=args.seed)
    elif args.specimen == "tiled":
        print(f"[dem_specimen] the FEM x DEM cell: {args.particles} discs, seed {args.seed}, isotropic stage at "
              f"{args.pressure:g} N/m", flush=True)
        state, packing = dc.generate_packing(args.particles, pressure=args.pressure, law=law, seed=args.seed,
                                             anisotropy=args.anisotropy)
        cell = dc.reference_cell(state, law, dc.RelaxationOptions(tol=1e-3, damping=0.7, criterion="force"),
                                 args.pressure)
        discs = tiled_cell(cell.state, *args.tiles, periodic_sides=args.lateral == "periodic")
        # the achieved initial fabric (000 eqs. 38-39) of the packing and of the tiled reference cell
        reference = cell.homogenized()
        discs.info.update(packing_anisotropy=packing["anisotropy"], cell_anisotropy=reference.anisotropy,
                          fabric=packing["fabric"], cell_fabric=reference.fabric.tolist(),
                          packing_solid_fraction=packing["solid_fraction"], prep_friction=packing["prep_friction"])
        if args.anisotropy is not None:
            print(f"[dem_specimen] initial fabric anisotropy A0: target {args.anisotropy:g}, packing "
                  f"{packing['anisotropy']:.4f}, reference cell {reference.anisotropy:.4f}", flush=True)
    else:
        discs = read_discs(args.packing, density=args.density, tiles=args.tiles,
                           periodic_sides=args.lateral == "periodic")
    if args.dt is None:
        args.dt = DT_FRACTION * math.sqrt(float(np.min(discs.mass)) / args.kn)
    check_time_step(args.dt, discs.mass, args.kn)
    r_mean = float(np.mean(discs.radius))
    if args.platen_speed is None:       # inertial number I = rate d / sqrt(p / rho)
        rho = float(np.sum(discs.mass) / np.sum(np.pi * discs.radius ** 2))
        rate = QUASI_STATIC_INERTIAL_NUMBER * math.sqrt(args.pressure / rho) / (2.0 * r_mean)
        args.platen_speed = 0.5 * rate * discs.height
    if args.duration is None:
        args.duration = args.axial_strain * discs.height / (2.0 * args.platen_speed)
    options = SpecimenOptions(dt=args.dt, normal_dashpot=args.normal_dashpot,
                              tangential_dashpot=args.tangential_dashpot, lateral=args.lateral,
                              pressure=args.pressure, membrane_stiffness=args.membrane_stiffness,
                              local_damping=args.preparation_damping, threads=args.threads)
except (InputError, ValueError) as error:       # demcell's InputError is a ValueError
    parser.refuse(error)
if args.snapshots is None:
    args.snapshots = list(np.linspace(0.0, args.duration, 5))
if args.output_every is None:
    args.output_every = args.duration / 200.0

os.makedirs(os.path.join(args.out, "particles"), exist_ok=True)
settings = {k: (list(v) if isinstance(v, tuple) else v) for k, v in vars(args).items()}
guard = RunGuard(None, os.path.join(args.out, "summary.json"),
                 dict(options=settings, n_discs=discs.n_discs, specimen_info=discs.info), label="dem_specimen",
                 write_now=args.restart is None)
t_start = time.time()

# %% Phase 0: the isotropic stage (or the checkpoint of an earlier run)
kept = {"snapshots_done": [], "bands": [], "balance": [], "isotropic": {}, "series": []}
if args.restart is None:
    test = BiaxialTest(discs, law, options, args.platen_speed)
    print(f"[dem_specimen] {discs.n_discs} discs ({args.specimen}), dt = {args.dt:.3g} s, lateral {args.lateral}; "
          f"phase 0: servo to -{args.pressure:g} N/m", flush=True)
    try:
        m0 = test.isotropic_stage(max_time=args.settle_time)
    except (dc.DemCellError, LostDiscsError) as error:
        guard.stop(f"isotropic stage: {error}")
    kept["isotropic"] = {"time_s": m0.time, "wall_stress": [None if math.isnan(s) else s for s in m0.wall_stress],
                         "coordination": m0.coordination, "height": m0.height, "width": test.width()}
    print(f"[dem_specimen] settled at t = {m0.time:.3g} s: platen stresses {m0.wall_stress[0]:.4g}, "
          f"{m0.wall_stress[1]:.4g} N/m, coordination {m0.coordination:.3f}", flush=True)
else:
    try:        # a damaged or foreign checkpoint: one line, nothing written
        with np.load(args.restart, allow_pickle=False) as checkpoint:
            test = BiaxialTest.restored(checkpoint, law, options, args.platen_speed)
        with open(os.path.splitext(args.restart)[0] + ".json") as f:
            kept = json.load(f)
        missing = {"snapshots_done", "bands", "balance", "isotropic", "series"} - set(kept)
        if missing:
            raise ValueError(f"its .json lacks {sorted(missing)}")
    except (OSError, EOFError, ValueError, KeyError, zipfile.BadZipFile) as error:   # numpy 2: EOFError for an empty file
        guard.refuse(f"--restart {args.restart}: not a checkpoint of this demo ({error})")
    print(f"[dem_specimen] restarted at t = {test.state.time - test.reference['time']:.4g} s of phase 1", flush=True)
test.set_local_damping(args.loading_damping)

# %% Outputs as the run goes
resume_step = test.state.step if args.restart else -1
history_path = os.path.join(args.out, "history.csv")
kept_rows = []
if args.restart and os.path.isfile(history_path):      # the rows up to the checkpoint's step
    with open(history_path) as f:
        lines = f.read().splitlines()[1:]
    kept_rows = [line.split(",") for line in lines if line]      # as written: the same bytes again
    kept_rows = [r for r in kept_rows if float(r[COLUMNS.index("step")]) <= resume_step]
history = CsvLog(history_path, COLUMNS, kept_rows)
rows = [dict(zip(COLUMNS, map(float, r))) for r in kept_rows]
grid_step = args.grid_spacing * r_mean
# the grid covers the specimen at the end of phase 0 with room for the lateral bulge; it is
# made from the reference configuration, so a restarted run writes on the same grid
reference = test.state.reference_position
x_left = float(np.min(reference[:, 0])) - r_mean
nx_grid = max(2, int(math.ceil(1.3 * test.reference["width"] / grid_step)))
ny_grid = max(2, int(math.ceil(test.reference["height"] / grid_step)))
origin = (x_left + 0.5 * test.reference["width"] - 0.5 * nx_grid * grid_step, float(np.min(reference[:, 1])) - r_mean)
series = GridSeries(os.path.join(args.out, "grains.xdmf"), origin, (grid_step, grid_step), (nx_grid, ny_grid),
                    times=[tuple(s) for s in kept["series"]])
grid_x = origin[0] + grid_step * (np.arange(nx_grid) + 0.5)
grid_y = origin[1] + grid_step * (np.arange(ny_grid) + 0.5)

GRID_FIELDS = ("eps_norm", "kappa_norm", "m_norm", "skew", "txx", "tyy", "txy", "phi", "void_ratio", "equivalent_strain")


def snapshot(index, t):
    """Particles, contacts, grid fields, the band fit and the moment balance at phase-1 time t."""
    st = test.state
    excluded = (st.on_boundary != 0) | (st.on_wall != 0)
    rev = rev_fields(st.position, st.radius, st.position - st.reference_position, st.rotation - st.reference_rotation,
                     st.pair_i, st.pair_j, st.fn, st.fs, st.mr, st.external_force, excluded,
                     st.period if st.period > 0 else None, touching=st.touching, sliding=st.sliding)
    per_disc = {name: getattr(rev, name) for name in GRID_FIELDS + ("k3x", "k3y", "m3x", "m3y", "coordination")}
    per_disc.update(displacement=st.position - st.reference_position, rotation=st.rotation - st.reference_rotation)
    write_particles_vtk(os.path.join(args.out, "particles", f"particles_{index:04d}.vtk"), st.position, st.radius,
                        per_disc)
    np.savez_compressed(os.path.join(args.out, "particles", f"fields_{index:04d}.npz"), time=t, position=st.position,
                        radius=st.radius, valid=rev.valid, excluded=excluded, **per_disc)
    k = np.flatnonzero(st.touching)
    write_contacts_vtk(os.path.join(args.out, "particles", f"contacts_{index:04d}.vtk"), st.position, st.pair_i[k],
                       st.pair_j[k], st.fn[k], st.fs[k], st.period)
    width_k = args.kernel_width * r_mean
    fields = {name: coarse_grain(st.position, getattr(rev, name), grid_x, grid_y, width_k, valid=rev.valid)
              for name in GRID_FIELDS}
    series.write(t, fields)
    kept["series"] = [list(s) for s in series.snapshots]
    valid = rev.valid & np.isfinite(rev.eps_norm)
    points = st.position[valid]
    band, entries = assess_band(lambda: fit_band(points, rev.eps_norm[valid]), 2.0 * r_mean, test.width(),
                                float(st.wall_position[1] - st.wall_position[0]))
    balance = moment_balance(st.position, rev.skew, rev.m3x, rev.m3y, rev.valid, rev.members,
                             st.period if st.period > 0 else None)
    kept["bands"].append(dict(entries, time=t, axial_strain=rows[-1]["axial_strain"] if rows else 0.0,
                              invalid_rev_fraction=rev.invalid_fraction,
                              thickness_over_diameter=None if band is None else band.thickness / (2.0 * r_mean)))
    kept["balance"].append({"time": t, "pearson_div_m_vs_minus_skew": balance.pearson_minus,
                            "pearson_div_m_vs_skew": balance.pearson_plus, "rms_div_m": balance.rms_div_m,
                            "rms_skew": balance.rms_skew, "rms_residual": balance.rms_residual})
    kept["snapshots_done"].append(t)
    plot_band(index, t, points, rev.eps_norm[valid], band)
    text = (f"band H = {band.thickness:.3g} m ({band.thickness / (2 * r_mean):.2f} d), "
            f"{band.inclination_deg:.1f} deg" if band is not None else f"no band ({entries['no_band_reason']})")
    print(f"[dem_specimen]   snapshot {index} at t = {t:.4g} s: {text}; invalid REVs "
          f"{100 * rev.invalid_fraction:.1f} %", flush=True)


def plot_band(index, t, points, values, band):
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(5, 8))
    sc = ax.scatter(points[:, 0], points[:, 1], c=values, s=4.0, cmap="viridis",
                    vmax=float(np.quantile(values, 0.98)) if values.size else None)
    fig.colorbar(sc, ax=ax, label="Cosserat strain norm |eps| per disc REV")
    if band is not None:
        x = np.array([points[:, 0].min(), points[:, 0].max()])
        ax.plot(x, band.x10 + np.tan(np.radians(band.inclination_deg)) * x, "r--",
                label=f"band axis, H = {band.thickness:.3g} m")
        ax.legend(loc="upper right")
    ax.set_aspect("equal")
    ax.set_title(f"t = {t:.4g} s of phase 1")
    fig.tight_layout()
    fig.savefig(os.path.join(args.out, f"band_{index:04d}.png"), dpi=110)
    plt.close(fig)


def plot_curve():
    if len(rows) < 2:
        return
    plt = pyplot()
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 4))
    e = -np.array([r["axial_strain"] for r in rows])
    a1.plot(e, [r["stress_ratio"] for r in rows])
    a1.set_xlabel("axial shortening -eps_a")
    a1.set_ylabel("stress ratio |s_a - s_l| / |s_a + s_l|")
    a2.plot(e, [r["volumetric_strain"] for r in rows])
    a2.set_xlabel("axial shortening -eps_a")
    a2.set_ylabel("volumetric strain (A - A0) / A0")
    fig.suptitle(f"{args.specimen} specimen, {discs.n_discs} discs")
    fig.tight_layout()
    fig.savefig(os.path.join(args.out, "curve.png"), dpi=110)
    plt.close(fig)


def save_checkpoint():
    path = os.path.join(args.out, "checkpoint.npz")
    test.save(path + ".tmp.npz")
    os.replace(path + ".tmp.npz", path)
    with open(path[:-4] + ".json.tmp", "w") as f:
        json.dump(kept, f)
    os.replace(path[:-4] + ".json.tmp", path[:-4] + ".json")


# %% Phase 1: the platens close; a row, a progress line, snapshots and checkpoints as it goes
steps_per_row = max(1, int(round(args.output_every / (args.dt * options.boundary_interval))))
phase1_done = test.state.time - test.reference["time"] if args.restart is not None else -math.inf
pending = [t for t in args.snapshots if phase1_done + 1e-9 < t <= args.duration + 1e-9]
next_checkpoint = [args.checkpoint_every] if args.checkpoint_every else [math.inf]
if args.restart is not None and args.checkpoint_every:
    done = test.state.time - test.reference["time"]
    next_checkpoint[0] = args.checkpoint_every * (math.floor(done / args.checkpoint_every + 1e-9) + 1)


class StopRun(Exception):
    pass


def on_row(row):
    with guard.deferred():
        rows.append(row)
        history.write(**row)
        t = row["time"]
        # the run ends on a whole step, up to one dt short of the last snapshot time
        while pending and t >= pending[0] - max(1e-9 * max(1.0, t), args.dt):
            pending.pop(0)
            snapshot(len(kept["snapshots_done"]), t)
        if len(rows) % 20 == 0:
            plot_curve()
        print(f"[dem_specimen] t = {t:8.3f} s  eps_a {row['axial_strain']:+.4f}  ratio {row['stress_ratio']:.3f}  "
              f"eps_v {row['volumetric_strain']:+.4f}  z {row['coordination']:.2f}  slide "
              f"{row['sliding_fraction']:.3f}  Ekin/Eel {row['kinetic_to_elastic']:.1e}  "
              f"({time.time() - t_start:.0f} s)", flush=True)
        guard.progress(final_time=t, final_axial_strain=row["axial_strain"])
        if t >= next_checkpoint[0] - 1e-9:
            save_checkpoint()
            next_checkpoint[0] += args.checkpoint_every
        if args.stop_after is not None and t >= args.stop_after - 1e-9:
            save_checkpoint()
            raise StopRun


if args.restart is None and 0.0 in pending:
    rows.append(test.row(test.specimen.measure()))
    history.write(**rows[-1])
    pending.pop(0)
    snapshot(0, 0.0)
stopped = False
try:
    remaining = args.duration - (test.state.time - test.reference["time"])
    if remaining > 0.5 * args.dt:
        test.compress(duration=remaining, on_row=on_row, every=steps_per_row)
except StopRun:
    stopped = True
except (dc.DemCellError, LostDiscsError) as error:
    history.close()
    plot_curve()
    guard.stop(f"phase 1: {error}", **kept)
history.close()
plot_curve()

# %% Summary
ratio = np.array([r["stress_ratio"] for r in rows])
peak = int(np.nanargmax(ratio)) if ratio.size else 0
cpu, wall = test.specimen.cpu_seconds, test.specimen.wall_seconds
summary = dict(kept, options=settings, n_discs=discs.n_discs, specimen_info=discs.info, completed=not stopped,
               reason="--stop-after" if stopped else "",
               peak_stress_ratio=float(ratio[peak]) if rows else None,
               axial_strain_at_peak=float(rows[peak]["axial_strain"]) if rows else None,
               final_axial_strain=rows[-1]["axial_strain"] if rows else None,
               final_time=rows[-1]["time"] if rows else None,
               dem_steps=int(test.state.step), cpu_seconds=cpu, loop_wall_seconds=wall,
               contact_updates_per_cpu_second=test.specimen.throughput()[0],
               wall_time_s=time.time() - t_start, load_average=list(os.getloadavg()),
               sign_convention="tension positive; axial_strain = (h - h0) / h0 from the end of phase 0")
guard.finish(summary)
print(f"[dem_specimen] {'stopped after' if stopped else 'done:'} t = {summary['final_time']:.4g} s, peak stress ratio "
      f"{summary['peak_stress_ratio']:.3f} at eps_a {summary['axial_strain_at_peak']:+.4f}; "
      f"{summary['contact_updates_per_cpu_second']:.3g} contact updates per CPU s; outputs in {args.out}")
