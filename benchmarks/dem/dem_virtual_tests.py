#!/usr/bin/python3
"""Virtual laboratory tests on the periodic DEM cell: the data of an Ehlers identification:
an isotropic compression test and plane-strain biaxial tests at three
confining pressures, for several packing seeds, with the seed-to-seed scatter.

What is run (per seed k = --first-seed, ..., --first-seed + --seeds - 1)
-----------------------------------------------------------------------
The cell of ``demos/dem_cell.py`` with its default contact law and pressure (read from
that demo's parser, not repeated here): --discs polydisperse discs (default 228) compacted
without friction to p0 = --pressure (default 10 N/m, p0/kn = 1e-3), then the isotropic
stage with friction on (``demcell.isotropic_stage``, 000 section 4.1).

1. ``isotropic``: the 2D pressure raised from p0 to --isotropic-max x p0 (default 4 p0) in
   --isotropic-steps equal steps, each a servo-controlled relaxation under sigma = -p I
   (``isotropic_stage``). Recorded: pressure p = -(s11 + s22)/2 and the volumetric (area)
   strain eps11 + eps22, counted from the start of the test (the state at p0). A copy of
   the cell is unloaded back to p0 afterwards; its residual volumetric strain (summary.json)
   is the irreversible part of the compaction (measured: below 1e-3 of the total, i.e. this
   branch is elastic). The model side to compare with is the driver's
   isotropic_plane_strain test with p = -(sig11 + sig22)/2 (in plane strain its sig33 is not
   -p, so the 3D mean stress is another abscissa), from its state at p0.
2. ``biaxial_<pc>Pa`` for each confining pressure pc = --confining x p0 (default 1, 2, 4):
   the cell state reached by the isotropic test at pc is the consolidated specimen (the
   consolidation is that isotropic path, so it costs nothing extra); then axis 1 is
   shortened to --axial-strain (default 10 %) in increments of --increment with
   sigma_22 = -pc held by the servo (``--lateral-control servo``, the default of
   demos/dem_cell.py) or by its strain-path iteration (``strain``, as a FEM x DEM Gauss
   point is loaded). Recorded: axial strain eps11, axial stress sigma_11 and volumetric
   strain eps11 + eps22, counted from the start of the deviatoric phase.

Why 4 p0 at most: with linear contacts in 2D the mean overlap is about 2 p/kn radii, so
p/kn = 4e-3 keeps the overlaps below 1 % of a radius (stiffness level kn/p >= 250): the
packing stays granular (its response is set by the contact network, not by the springs'
compliance), as the 10 N/m of demos/dem_cell.py does. Above p/kn = 1e-2 (overlaps of 2 %
of a radius and more) the options are refused.

Increment, tolerance and cost (measured with seeds 0 and 1, 228 discs, these defaults
otherwise, against an increment of 5e-5): coarse increments lower the peak axial stress, the
more so at low pressure, where the increment is a larger part of the elastic strain p/kn:
2e-3 is 4-6 % low at p0, 1 % at 4 p0; 1e-3 2-5 % / 0-1 %; 2.5e-4 0.9-2.4 % / 0 %; at 1e-4
the differences take either sign (-2.2 % to +1.7 %): no bias left that the path noise does
not hide. That noise does not shrink with the increment: past the peak a 228-disc cell goes
through stick-slip events whose order depends on the path, so the curves of one seed at two
fine increments differ by 2-5 % of the peak on average (final volumetric strains by up to
0.01), of the order of the seed scatter, which therefore includes it. A relaxation
tolerance of 1e-4 instead of 1e-3 moves the peaks by < 3.5 % either way (same cost).
Default 1e-4: 5-9 CPU s per biaxial test (fewer at higher pressure), about 22 CPU s per
seed, 67 CPU s for the default 3 seeds (2.5e-4: 12 CPU s per seed).
The ensemble files are on a grid of --grid-step (default 1e-3, 101 points per curve): the
points are not independent measurements (neighbours share the path), which an error analysis
that treats them as independent (thesis 4.27, 4.28) should bear in mind.

Conventions (those of the Ehlers material-point driver, cosserat_fenicsx/materials/ehlers/
material_point.py, that the identification compares with): SI, tension positive, axis 1
axial, compression axial strain negative. Strains are the small-strain measure of the driver,
eps = sym(F F_ref^-1) - I with F_ref the cell at the start of the test (the exact area
change det(F F_ref^-1) - 1 is an extra column). Stresses: the DEM cell's stresses are 2D,
N/m (force per unit out-of-plane length); the discs are read as cylinders of unit thickness
t = 1 m, so sigma [Pa] = sigma_2D [N/m] / 1 m, and the numbers are unchanged.

Outputs in --out (default out/dem_virtual_tests), written as the run goes:
  seed<k>/isotropic.csv        pressure, volumetric_strain, then sigma_11, sigma_22,
                               area_strain, coordination_number, solid_fraction,
                               n_contacts, converged, steps
  seed<k>/biaxial_<pc>Pa.csv   axial_strain, axial_stress, volumetric_strain, then
                               lateral_stress, stress_ratio, area_strain,
                               coordination_number, anisotropy, sliding_fraction,
                               n_contacts, converged, steps
  isotropic.csv, biaxial_<pc>Pa.csv   the ensemble over the seeds done so far (from two
                               seeds on), each seed interpolated linearly onto a common grid
                               (the nominal pressures / the axial strains -k x
                               --grid-step): the means of the same first columns, then
                               axial_stress_std, volumetric_strain_std (sample standard
                               deviation over the seeds, thesis eq. 4.26; an isotropic test
                               has only volumetric_strain_std), then stress_ratio and its std
                               (biaxial) and n_seeds
  summary.json                 settings, per test and seed: peak stress ratio (000 eq. 40),
                               peak axial stress and the strain there, final volumetric
                               strain, increments not converged; cost per test and seed
                               (CPU s, wall s, DEM steps, load average)
  dem_virtual_tests.png        all seeds (thin) and the mean +- std (thick)

    /usr/bin/python3 benchmarks/dem/dem_virtual_tests.py                  # defaults: 3 seeds
    /usr/bin/python3 benchmarks/dem/dem_virtual_tests.py --seeds 5 --increment 5e-4
"""
import argparse
import dataclasses
import importlib.util
import math
import os
import time

import numpy as np

from benchmarks import ROOT
import demcell as dc
from demcell.interface import RelaxationOptions
from demcell.io import CsvLog
from demcell.packing import check_pressure_ratio
from cosserat_fenicsx.validation import (AXIAL_STRAIN, COUNT, DISCS, NON_NEGATIVE_INTEGER, POSITIVE,
                                         InputError, Parser, Range, UNIT_OPEN, number)

#: largest p/kn of any test: overlaps of about 2 p/kn radii, 2 % of a radius at 1e-2 (see docstring)
GRANULAR_LIMIT = 1e-2
#: two seeds at least: the ensemble files carry a sample standard deviation (thesis eq. 4.26)
SEEDS = Range(2, 1000, integer=True)
#: pressure factors of p0: at least 1 (the tests load from the packing at p0), at most 1000
FACTOR = Range(1.0, 1000.0)
#: the isotropic test must raise the pressure above p0
ISOTROPIC_FACTOR = Range(1.0, 1000.0, low_open=True)

ISOTROPIC_COLUMNS = ["pressure", "volumetric_strain", "sigma_11", "sigma_22", "area_strain",
                     "coordination_number", "solid_fraction", "n_contacts", "converged", "steps"]
BIAXIAL_COLUMNS = ["axial_strain", "axial_stress", "volumetric_strain", "lateral_stress", "stress_ratio",
                   "area_strain", "coordination_number", "anisotropy", "sliding_fraction", "n_contacts",
                   "converged", "steps"]
UNITS = ("SI, tension positive, axis 1 axial; stresses in Pa = the cell's 2D stresses [N/m] over a unit "
         "out-of-plane thickness of 1 m; strains eps = sym(F F_ref^-1) - I counted from the start of each "
         "test (biaxial: of its deviatoric phase), volumetric_strain = eps11 + eps22 (plane strain)")


def dem_cell_demo():
    """demos/dem_cell.py as a module (its parser's defaults and its strain-path step)."""
    spec = importlib.util.spec_from_file_location("dem_cell_demo", os.path.join(ROOT, "demos", "dem_cell.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def parse(argv=None, demo=None):
    demo = demo or dem_cell_demo()
    d = demo.parse([])                   # the demo's defaults: contact law, p0, increment, relaxation
    p = Parser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter,
               allow_abbrev=False, epilog="See the module docstring (head of this file) for details.")
    p.add_argument("--seeds", type=number(SEEDS), default=3,
                   help=f"number of packing seeds, {SEEDS.describe()} (default 3)")
    p.add_argument("--first-seed", type=number(NON_NEGATIVE_INTEGER), default=0, help="first seed (default 0)")
    p.add_argument("--discs", type=number(DISCS), default=d.particles,
                   help=f"discs per cell, {DISCS.describe()} (default {d.particles})")
    p.add_argument("--pressure", type=number(POSITIVE), default=d.pressure,
                   help=f"packing pressure p0 [N/m = Pa at 1 m thickness] (default {d.pressure:g}, "
                        "as demos/dem_cell.py)")
    p.add_argument("--confining", type=number(FACTOR), nargs="+", default=[1.0, 2.0, 4.0],
                   help="confining pressures of the biaxial tests as multiples of p0, each "
                        f"{FACTOR.describe()} and at most --isotropic-max (default 1 2 4)")
    p.add_argument("--isotropic-max", type=number(ISOTROPIC_FACTOR), default=4.0,
                   help=f"final pressure of the isotropic test / p0, {ISOTROPIC_FACTOR.describe()} (default 4)")
    p.add_argument("--isotropic-steps", type=number(COUNT), default=12,
                   help="equal pressure steps of the isotropic test (default 12)")
    p.add_argument("--axial-strain", type=number(AXIAL_STRAIN), default=0.1,
                   help="final axial shortening |eps11| of the biaxial tests, in (0, 0.5) (default 0.1)")
    p.add_argument("--increment", type=number(POSITIVE), default=1e-4,
                   help="axial strain per increment, at most --axial-strain (default 1e-4: coarser "
                        "increments lower the peak, see the docstring)")
    p.add_argument("--grid-step", type=number(POSITIVE), default=1e-3,
                   help="axial-strain spacing of the ensemble files' common grid, in [--increment, "
                        "--axial-strain] (default 1e-3)")
    p.add_argument("--relaxation-tol", type=number(UNIT_OPEN), default=d.relaxation_tol,
                   help=f"E_kin/E_pot tolerance of each relaxation, in (0, 1) (default {d.relaxation_tol:g}, "
                        "as demos/dem_cell.py)")
    p.add_argument("--lateral-control", choices=("servo", "strain"), default=d.lateral_control,
                   help="as demos/dem_cell.py: servo (default) or strain (straight path in F per increment)")
    p.add_argument("--out", default="out/dem_virtual_tests", help="output directory (default %(default)s)")
    a = p.parse_args(argv)
    try:
        if not a.axial_strain / 1e4 <= a.increment <= a.axial_strain:
            raise InputError(f"--increment must be in [--axial-strain / 1e4, --axial-strain] = "
                             f"[{a.axial_strain / 1e4:g}, {a.axial_strain:g}], got {a.increment:g}")
        if not a.increment <= a.grid_step <= a.axial_strain:
            raise InputError(f"--grid-step must be in [--increment, --axial-strain] = [{a.increment:g}, "
                             f"{a.axial_strain:g}], got {a.grid_step:g}")
        if max(a.confining) > a.isotropic_max:
            raise InputError(f"--confining {max(a.confining):g} exceeds --isotropic-max {a.isotropic_max:g}: the "
                             "isotropic test is the consolidation of the biaxial tests")
        if len(set(a.confining)) != len(a.confining):
            raise InputError(f"--confining has repeated values: {a.confining}")
        check_pressure_ratio(a.pressure, d.kn)
        top = a.isotropic_max * a.pressure / d.kn
        if top > GRANULAR_LIMIT:
            raise InputError(f"--isotropic-max x --pressure / kn = {top:.3g} exceeds {GRANULAR_LIMIT:g}: overlaps of "
                             f"about {200 * top:.1f} % of a radius, no longer a granular state")
    except ValueError as error:
        p.refuse(error)
    a.confining = sorted(a.confining)
    return a, d


def small_strain(F, F_ref):
    """eps = sym(F F_ref^-1) - I (the driver's geometrically linear strain) and the area
    change det(F F_ref^-1) - 1, both from the start of the test."""
    G = F @ np.linalg.inv(F_ref)
    return 0.5 * (G + G.T) - np.eye(2), float(np.linalg.det(G)) - 1.0


def pressure_grid(a):
    """The isotropic test's target pressures [N/m]: equal steps from p0 to --isotropic-max p0,
    with the confining pressures added (each biaxial test starts from one of them)."""
    factors = np.linspace(1.0, a.isotropic_max, a.isotropic_steps + 1)
    factors = np.unique(np.round(np.concatenate([factors, a.confining]), 12))
    return a.pressure * factors


class Cost:
    """CPU s, wall s and load average of one test (time.process_time counts this process only)."""

    def __init__(self):
        self.cpu, self.wall = time.process_time(), time.perf_counter()

    def done(self, steps):
        return dict(cpu_s=round(time.process_time() - self.cpu, 2), wall_s=round(time.perf_counter() - self.wall, 2),
                    dem_steps=int(steps), load_average=[round(x, 2) for x in os.getloadavg()])


def isotropic_test(cell, pressures, path, confining):
    """Raise the pressure of ``cell`` (after the isotropic stage at pressures[0]) through
    ``pressures`` [N/m]; write one row per step to ``path``. Returns (rows, copies of the
    committed cell at each pressure in ``confining``, DEM steps, the residual volumetric
    strain of a copy unloaded to pressures[0])."""
    F_ref = cell.deformation_gradient().copy()
    log = CsvLog(path, ISOTROPIC_COLUMNS)
    rows, starts, steps = [], {}, 0

    def record(n_steps, converged):
        h = cell.homogenized()
        eps, area = small_strain(cell.deformation_gradient(), F_ref)
        row = dict(pressure=h.pressure, volumetric_strain=eps[0, 0] + eps[1, 1], sigma_11=h.cauchy[0, 0],
                   sigma_22=h.cauchy[1, 1], area_strain=area, coordination_number=h.coordination_number,
                   solid_fraction=h.solid_fraction, n_contacts=h.n_contacts, converged=int(converged),
                   steps=n_steps)
        log.write(**row)
        rows.append(row)

    record(0, True)
    for k, p in enumerate(pressures):
        if k > 0:
            res = dc.isotropic_stage(cell, p)       # raises SolveError if it does not relax
            steps += res.steps
            record(res.steps, res.converged)
        for pc in confining:
            if math.isclose(p, pc, rel_tol=1e-9):
                starts[pc] = cell.copy()
    log.close()
    # unloading a copy back to p0: the part of the compaction that is not recovered (the
    # plastic volumetric strain an identification of the compression branch must explain)
    twin = cell.copy()
    res = dc.isotropic_stage(twin, pressures[0])
    eps, _ = small_strain(twin.deformation_gradient(), F_ref)
    unloading = dict(volumetric_strain_after_unloading_to_p0=eps[0, 0] + eps[1, 1], unloading_dem_steps=res.steps)
    return rows, starts, steps + res.steps, unloading


def biaxial_test(cell, confining, a, demo, path):
    """Plane-strain compression of ``cell`` (consolidated at ``confining`` [N/m]): F_11
    shortened by a.increment per increment to a.axial_strain, sigma_22 = -confining held
    (servo, or the strain-path iteration of demos/dem_cell.py). Returns (rows, DEM steps)."""
    F_ref = cell.deformation_gradient().copy()
    log = CsvLog(path, BIAXIAL_COLUMNS)
    rows, steps = [], 0
    mask = np.array([[False, False], [False, True]])
    target = np.diag([0.0, -confining])

    def record(n_steps, converged):
        h = cell.homogenized()
        eps, area = small_strain(cell.deformation_gradient(), F_ref)
        row = dict(axial_strain=eps[0, 0], axial_stress=h.cauchy[0, 0], volumetric_strain=eps[0, 0] + eps[1, 1],
                   lateral_stress=h.cauchy[1, 1], stress_ratio=h.stress_ratio, area_strain=area,
                   coordination_number=h.coordination_number, anisotropy=h.anisotropy,
                   sliding_fraction=h.sliding_fraction, n_contacts=h.n_contacts, converged=int(converged),
                   steps=n_steps)
        log.write(**row)
        rows.append(row)

    record(0, True)
    n_inc = int(round(a.axial_strain / a.increment))
    for k in range(1, n_inc + 1):
        F = cell.deformation_gradient()
        F[0, 0] = F_ref[0, 0] * (1.0 - k * a.axial_strain / n_inc)
        if a.lateral_control == "servo":
            cell.set_deformation(F)
            res = cell.solve(stress_mask=mask, stress_target=target)
        else:
            res = demo.strain_path_step(cell, F, 1, -confining)
        steps += res.steps
        cell.commit()
        record(res.steps, res.converged)
    log.close()
    return rows, steps


def biaxial_name(confining):
    return f"biaxial_{confining:g}Pa"


def seed_summary(kind, rows):
    """Per seed and test: the figures the report and the identification's start need."""
    r = {c: np.array([row[c] for row in rows], dtype=float) for c in rows[0]}
    out = dict(not_converged=int(np.sum(r["converged"] == 0)))
    if kind == "isotropic":
        out.update(final_pressure=float(r["pressure"][-1]), final_volumetric_strain=float(r["volumetric_strain"][-1]))
        return out
    i, j = int(np.argmax(r["stress_ratio"])), int(np.argmin(r["axial_stress"]))
    out.update(peak_stress_ratio=float(r["stress_ratio"][i]), axial_strain_at_peak_ratio=float(r["axial_strain"][i]),
               friction_angle_at_peak_deg=math.degrees(math.asin(min(1.0, r["stress_ratio"][i]))),
               peak_axial_stress=float(r["axial_stress"][j]), axial_strain_at_peak_stress=float(r["axial_strain"][j]),
               final_axial_stress=float(r["axial_stress"][-1]),
               final_volumetric_strain=float(r["volumetric_strain"][-1]),
               min_volumetric_strain=float(r["volumetric_strain"].min()))
    return out


def ensemble(kind, runs, grid):
    """Columns of the ensemble file: each seed's curve interpolated linearly onto ``grid``
    (pressure increasing, or axial strain decreasing), then mean and sample std (ddof 1,
    thesis eq. 4.26) over the seeds."""
    x_name = "pressure" if kind == "isotropic" else "axial_strain"
    quantities = ["volumetric_strain"] if kind == "isotropic" else ["axial_stress", "volumetric_strain",
                                                                     "stress_ratio"]
    sign = 1.0 if kind == "isotropic" else -1.0          # np.interp wants an increasing abscissa
    cols = {x_name: grid}
    values = {}
    for q in quantities:
        v = np.array([np.interp(sign * grid, sign * np.array([r[x_name] for r in rows]),
                                np.array([r[q] for r in rows])) for rows in runs])
        values[q] = v
        cols[q] = v.mean(axis=0)
    for q in quantities:
        cols[q + "_std"] = values[q].std(axis=0, ddof=1)
    if kind != "isotropic":
        cols = {k: cols[k] for k in [x_name, "axial_stress", "volumetric_strain", "axial_stress_std",
                                     "volumetric_strain_std", "stress_ratio", "stress_ratio_std"]}
    cols["n_seeds"] = np.full(grid.size, len(runs))
    return cols


def write_columns(path, cols):
    tmp = path + ".tmp"
    np.savetxt(tmp, np.column_stack(list(cols.values())), delimiter=",", header=",".join(cols), comments="",
               fmt="%.10g")
    os.replace(tmp, path)


def plot(tests, runs, ens, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(2, 2, figsize=(11, 8))
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for name in tests:
        c = colours[tests.index(name) % len(colours)]
        for rows in runs.get(name, []):
            r = {k: np.array([row[k] for row in rows]) for k in rows[0]}
            if name == "isotropic":
                ax[0, 0].plot(-100 * r["volumetric_strain"], r["pressure"], "-", color="grey", lw=0.8)
            else:
                ax[0, 1].plot(-100 * r["axial_strain"], -r["axial_stress"], "-", color=c, lw=0.6, alpha=0.5)
                ax[1, 0].plot(-100 * r["axial_strain"], 100 * r["volumetric_strain"], "-", color=c, lw=0.6, alpha=0.5)
                ax[1, 1].plot(-100 * r["axial_strain"], r["stress_ratio"], "-", color=c, lw=0.6, alpha=0.5)
        e = ens.get(name)
        if e is None:
            continue
        if name == "isotropic":
            ax[0, 0].errorbar(-100 * e["volumetric_strain"], e["pressure"], xerr=100 * e["volumetric_strain_std"],
                              fmt="k-", lw=2, label="mean +- std")
            continue
        x = -100 * e["axial_strain"]
        for axis, q, scale in ((ax[0, 1], "axial_stress", -1.0), (ax[1, 0], "volumetric_strain", 100.0),
                               (ax[1, 1], "stress_ratio", 1.0)):
            m, s = scale * e[q], abs(scale) * e[q + "_std"]
            axis.plot(x, m, "-", color=c, lw=2, label=name)
            axis.fill_between(x, m - s, m + s, color=c, alpha=0.2)
    ax[0, 0].set(xlabel="-volumetric strain -(eps11 + eps22) [%]", ylabel="pressure p [Pa]", title="isotropic")
    ax[0, 1].set(xlabel="axial shortening -eps11 [%]", ylabel="-sigma_11 [Pa]", title="biaxial: axial stress")
    ax[1, 0].set(xlabel="axial shortening -eps11 [%]", ylabel="volumetric strain eps11 + eps22 [%]",
                 title="biaxial: volumetric strain (dilation > 0)")
    ax[1, 1].set(xlabel="axial shortening -eps11 [%]", ylabel="|s11 - s22| / |s11 + s22|",
                 title="biaxial: stress ratio (000 eq. 40)")
    for axis in ax.flat:
        axis.grid(True, alpha=0.3)
        if axis.get_legend_handles_labels()[0]:
            axis.legend(fontsize=8)
    fig.suptitle("demcell virtual tests (thin: seeds, thick: mean, band: +- sample std)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None):
    from cosserat_fenicsx.run_guard import RunGuard
    demo = dem_cell_demo()
    a, d = parse(argv, demo)
    os.makedirs(a.out, exist_ok=True)
    law = dc.ContactLaw(kn=d.kn, ks=d.ks, friction=d.friction, rotations=not d.no_rotation)
    options = RelaxationOptions(tol=a.relaxation_tol, damping=0.7, criterion=d.criterion, method=d.relaxation)
    pressures = pressure_grid(a)
    confining = [a.pressure * f for f in a.confining]
    tests = ["isotropic"] + [biaxial_name(pc) for pc in confining]
    grids = {"isotropic": pressures}
    n_grid = int(round(a.axial_strain / a.grid_step))
    grids.update({biaxial_name(pc): 0.0 - a.axial_strain * np.arange(n_grid + 1) / n_grid for pc in confining})
    settings = dict(options=vars(a), contact_law=law.to_dict(), relaxation=dataclasses.asdict(options), isotropic_pressures=pressures, units=UNITS,
                    tests=tests, granular_limit_p_over_kn=GRANULAR_LIMIT)
    guard = RunGuard(None, os.path.join(a.out, "summary.json"), settings, label="dem_virtual_tests")
    seeds = list(range(a.first_seed, a.first_seed + a.seeds))
    per_seed = {t: {} for t in tests}
    runs = {t: [] for t in tests}
    ens = {}
    t_start, c_start = time.perf_counter(), time.process_time()
    for seed in seeds:
        sdir = os.path.join(a.out, f"seed{seed}")
        os.makedirs(sdir, exist_ok=True)
        cost = Cost()
        try:
            state, info = dc.generate_packing(a.discs, pressure=a.pressure, law=law, seed=seed)
            cell = dc.DemCell(state, law, options)
            prep = dc.isotropic_stage(cell, a.pressure)
        except dc.DemCellError as error:
            guard.stop(f"seed {seed}: packing / isotropic stage: {error}")
        dc.save_packing(os.path.join(sdir, "packing.npz"), cell.state, info)
        packing = dict(solid_fraction=info["solid_fraction"], coordination_number=info["coordination_number"],
                       anisotropy=info["anisotropy"], **{"preparation": cost.done(prep.steps)})
        print(f"[virtual] seed {seed}: {a.discs} discs, solid fraction {info['solid_fraction']:.3f}, "
              f"z {info['coordination_number']:.2f} ({packing['preparation']['cpu_s']:.1f} CPU s)", flush=True)
        cost = Cost()
        try:
            rows, starts, steps, unloading = isotropic_test(cell, pressures, os.path.join(sdir, "isotropic.csv"),
                                                            confining)
        except dc.DemCellError as error:
            guard.stop(f"seed {seed}: isotropic test: {error}")
        per_seed["isotropic"][seed] = dict(seed_summary("isotropic", rows), packing=packing, **unloading,
                                           **cost.done(steps))
        runs["isotropic"].append(rows)
        print(f"[virtual]   isotropic: eps_v {rows[-1]['volumetric_strain']:+.5f} at p {rows[-1]['pressure']:.4g} Pa, "
              f"{unloading['volumetric_strain_after_unloading_to_p0']:+.2e} after unloading to p0 "
              f"({per_seed['isotropic'][seed]['cpu_s']:.1f} CPU s)", flush=True)
        for pc in confining:
            name = biaxial_name(pc)
            cost = Cost()
            try:
                rows, steps = biaxial_test(starts[pc], pc, a, demo, os.path.join(sdir, name + ".csv"))
            except dc.DemCellError as error:
                guard.stop(f"seed {seed}: {name}: {error}")
            per_seed[name][seed] = dict(seed_summary("biaxial", rows), **cost.done(steps))
            runs[name].append(rows)
            s = per_seed[name][seed]
            print(f"[virtual]   {name}: peak ratio {s['peak_stress_ratio']:.3f} at {s['axial_strain_at_peak_ratio']:+.4f}, "
                  f"peak sigma_11 {s['peak_axial_stress']:.4g} Pa, final eps_v {s['final_volumetric_strain']:+.4f}, "
                  f"{s['not_converged']} increments not converged ({s['cpu_s']:.1f} CPU s)", flush=True)
            with guard.deferred():
                guard.progress(per_seed=per_seed)
        with guard.deferred():
            if len(runs["isotropic"]) >= 2:
                for name in tests:
                    kind = "isotropic" if name == "isotropic" else "biaxial"
                    ens[name] = ensemble(kind, runs[name], grids[name])
                    write_columns(os.path.join(a.out, name + ".csv"), ens[name])
            plot(tests, runs, ens, os.path.join(a.out, "dem_virtual_tests.png"))
    stats = {}
    for name in tests:
        for key in ("peak_stress_ratio", "peak_axial_stress", "axial_strain_at_peak_stress", "final_volumetric_strain"):
            v = np.array([per_seed[name][s][key] for s in seeds if key in per_seed[name][s]])
            if v.size:
                stats.setdefault(name, {})[key] = dict(mean=float(v.mean()), std=float(v.std(ddof=1)))
    bad = sum(per_seed[t][s]["not_converged"] for t in tests for s in seeds)
    cost_per_test = {t: {k: round(sum(per_seed[t][s][k] for s in seeds), 2) for k in ("cpu_s", "wall_s", "dem_steps")}
                     for t in tests}
    summary = dict(settings, per_seed=per_seed, ensemble_statistics=stats, increments_not_converged=bad,
                   cost_per_test_all_seeds=cost_per_test,
                   total=dict(cpu_s=round(time.process_time() - c_start, 1),
                              wall_s=round(time.perf_counter() - t_start, 1),
                              dem_steps=int(sum(per_seed[t][s]["dem_steps"] for t in tests for s in seeds)),
                              load_average=[round(x, 2) for x in os.getloadavg()]))
    if bad:
        summary["warning"] = (f"{bad} increments did not relax to the tolerance within the step budget "
                              "(converged = 0 in the seed files): their stresses are not equilibrium values")
        print(f"[virtual] warning: {summary['warning']}")
    guard.finish(summary)
    for name in tests[1:]:
        s = stats[name]
        print(f"[virtual] {name}: peak ratio {s['peak_stress_ratio']['mean']:.3f} +- {s['peak_stress_ratio']['std']:.3f}, "
              f"peak sigma_11 {s['peak_axial_stress']['mean']:.4g} +- {s['peak_axial_stress']['std']:.2g} Pa")
    print(f"[virtual] {summary['total']['cpu_s']} CPU s, {summary['total']['wall_s']} s wall; outputs in {a.out}")
    return summary


if __name__ == "__main__":
    main()
