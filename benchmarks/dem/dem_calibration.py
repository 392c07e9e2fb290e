#!/usr/bin/python3
"""A continuum calibrated from the grains: Ehlers parameters of a disc packing.

1. Data: the virtual tests of benchmarks/dem/dem_virtual_tests.py on the periodic DEM cell
   (228 discs, 000 Table 3 contact law, several seeds): a plane-strain isotropic
   compression from p0 to 4 p0 and biaxial tests at p0, 2 p0, 4 p0; ensemble means and the
   scatter between seeds (eq. 4.26).  Run first if out/dem_virtual_tests is missing.
2. Units: linear contacts have no stress scale but kn, so the quasi-static response at a
   given p/kn, friction and ks/kn is the same with every stress multiplied by c and kn by c.
   The cell's 2D stresses (N/m, read as Pa over a 1 m thickness) are multiplied by
   --stress-scale (default 1e4: kn = 1e8 N/m, p0 = 100 kPa, the pressures of the thesis'
   tests), so that the Ehlers parameters come out in the range of the Hostun set and the
   kernel's tolerances (scaled to MPa) apply unchanged.  Stress-like parameters (mu, lmbda,
   delta, epsilon) of the original packing are those divided by c.
3. Identification with demos/identify.py (run as a user would, through a --config file),
   error analysis with the per-test mean scatter (as Table 6.3).  n0 is the packing's solid
   fraction; n_max = 0.99 keeps the compression point (2.70) out of the way (a disc packing
   has no measured compression point in this range: its isotropic test is linear and
   reversible).
4. The identified model against the DEM curves: peak stress, its strain, dilatancy, post-peak,
   per pressure (calibration.png, summary.json).

    python3 benchmarks/dem/dem_calibration.py [--params ...] [--out out/dem_calibration]
"""
import argparse
import csv
import json
import os
import subprocess
import sys
import time

import numpy as np

from benchmarks import ROOT
from cosserat_fenicsx.validation import POSITIVE, Parser, number

#: the parameters identified by default: elasticity, the strength cone (beta, gamma), its
#: hardening, the dilatancy of the potential (psi1, psi2) and the softening (delta)
DEFAULT_PARAMS = "mu,lmbda,beta0,beta_star,C_beta_D,gamma_star,C_gamma_D,psi1,psi2,delta_star,C_delta_D"
STRESS_COLUMNS = ("axial_stress", "pressure")


def read_csv(path):
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    return rows[0], np.array([[float(v) for v in r] for r in rows[1:]])


def scaled_copy(src, dst, c, drop_first):
    """The ensemble file with stresses (and their scatter) times c; the start row (axial strain
    0, or the start pressure) dropped: it is the reference state, equal in model and data."""
    header, a = read_csv(src)
    for j, name in enumerate(header):
        if name.split("_std")[0] in STRESS_COLUMNS or name == "axial_stress_std":
            a[:, j] *= c
    if drop_first:
        a = a[1:]
    with open(dst, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        for row in a:
            w.writerow([f"{v:.12g}" for v in row])
    return header, a


def main():
    p = Parser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter, allow_abbrev=False)
    p.add_argument("--dem", default="out/dem_virtual_tests", help="output directory of dem_virtual_tests.py")
    p.add_argument("--stress-scale", type=number(POSITIVE), default=1e4, help="c (default %(default)g)")
    p.add_argument("--params", default=DEFAULT_PARAMS)
    p.add_argument("--out", default="out/dem_calibration")
    args = p.parse_args()
    t0 = time.perf_counter()
    dem = os.path.join(ROOT, args.dem) if not os.path.isabs(args.dem) else args.dem
    if not os.path.isfile(os.path.join(dem, "summary.json")):
        print(f"dem_calibration: running the DEM virtual tests into {dem}")
        subprocess.run([sys.executable, os.path.join(ROOT, "benchmarks", "dem", "dem_virtual_tests.py"), "--out", dem],
                       check=True)
    with open(os.path.join(dem, "summary.json")) as f:
        dsum = json.load(f)
    c = args.stress_scale
    p0 = dsum["options"]["pressure"]
    pressures = [p0 * k for k in dsum["options"]["confining"]]
    out = os.path.abspath(args.out)
    os.makedirs(os.path.join(out, "data"), exist_ok=True)
    tests, curves = [], {}
    header, a = scaled_copy(os.path.join(dem, "isotropic.csv"), os.path.join(out, "data", "isotropic.csv"), c, True)
    iso_std = float(np.mean(a[:, header.index("volumetric_strain_std")]))
    tests.append(dict(file="data/isotropic.csv", kind="isotropic_plane_strain", confining=float(a[:, 0].max()),
                      start_pressure=p0 * c, scatter=dict(volumetric_strain=iso_std)))
    curves["isotropic"] = (header, a)
    for pc in pressures:
        name = f"biaxial_{pc:g}Pa"
        header, a = scaled_copy(os.path.join(dem, name + ".csv"), os.path.join(out, "data", name + ".csv"), c, True)
        scatter = {q: float(np.mean(a[:, header.index(q + "_std")])) for q in ("axial_stress", "volumetric_strain")}
        tests.append(dict(file=f"data/{name}.csv", kind="biaxial", confining=pc * c, scatter=scatter))
        curves[name] = (header, a)
    solid = float(np.mean([s["packing"]["solid_fraction"] for s in dsum["per_seed"]["isotropic"].values()]))
    config = dict(tests=tests, stages=[args.params.split(",")],
                  base=dict(n0=float(solid), n_max=0.99))
    with open(os.path.join(out, "config.json"), "w") as f:
        json.dump(config, f, indent=1)
    # the points of a DEM curve share its loading path: their errors are correlated
    cmd = [sys.executable, os.path.join(ROOT, "demos", "identify.py"), "--config", os.path.join(out, "config.json"),
           "--serial-correlation", "--out", os.path.join(out, "identify")]
    print("dem_calibration:", " ".join(cmd))
    proc = subprocess.run(cmd)
    with open(os.path.join(out, "identify", "summary.json")) as f:
        isum = json.load(f)
    # ---- the identified model against the DEM curves
    from cosserat_fenicsx.identification.virtual_tests import VirtualTest
    from cosserat_fenicsx.materials.ehlers import EhlersMaterial
    from cosserat_fenicsx.materials.ehlers.parameters import read_parameter_file
    values = read_parameter_file(os.path.join(out, "identify", "identified_parameters.json"))
    material = EhlersMaterial(**values, micropolar=False)
    compare = {}
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(1, 3, figsize=(14, 4))
    for k, pc in enumerate(pressures):
        name = f"biaxial_{pc:g}Pa"
        header, a = curves[name]
        ea, sa, va = (a[:, header.index(n)] for n in ("axial_strain", "axial_stress", "volumetric_strain"))
        h = VirtualTest("biaxial", pc * c, axial_strain=float(-ea.min()), n_steps=200).run(material,
                                                                                           stop_on_failure=True)
        im, idd = int(np.argmin(h["axial_stress"])), int(np.argmin(sa))
        compare[name] = dict(
            dem_peak_axial_stress=float(sa[idd] / c), model_peak_axial_stress=float(h["axial_stress"][im] / c),
            dem_axial_strain_at_peak=float(ea[idd]), model_axial_strain_at_peak=float(h["axial_strain"][im]),
            dem_final_axial_stress=float(sa[-1] / c), model_final_axial_stress=float(h["axial_stress"][-1] / c),
            dem_final_volumetric_strain=float(va[-1]), model_final_volumetric_strain=float(h["volumetric_strain"][-1]),
            dem_min_volumetric_strain=float(va.min()), model_min_volumetric_strain=float(np.min(h["volumetric_strain"])),
            model_stopped=h["stopped"])
        col = f"C{k}"
        sd = a[:, header.index("axial_stress_std")]
        ax[0].fill_between(-ea * 100, -(sa - sd) / c, -(sa + sd) / c, color=col, alpha=0.2)
        ax[0].plot(-ea * 100, -sa / c, col, lw=1, label=f"DEM {pc:g} Pa (mean +- std)")
        ax[0].plot(-np.asarray(h["axial_strain"]) * 100, -np.asarray(h["axial_stress"]) / c, col + "--", lw=1.5,
                   label=f"Ehlers {pc:g} Pa")
        ax[1].plot(-ea * 100, va, col, lw=1)
        ax[1].plot(-np.asarray(h["axial_strain"]) * 100, h["volumetric_strain"], col + "--", lw=1.5)
    header, a = curves["isotropic"]
    h = VirtualTest("isotropic_plane_strain", float(a[:, 0].max()), n_steps=50, start_pressure=p0 * c).run(material)
    ax[2].plot(a[:, 0] / c, a[:, 1], "k.", label="DEM")
    ax[2].plot(np.asarray(h["pressure"]) / c, h["volumetric_strain"], "r--", label="Ehlers")
    ax[0].set_xlabel("axial strain [%]"); ax[0].set_ylabel("axial stress [Pa = N/m per m], compression +")
    ax[1].set_xlabel("axial strain [%]"); ax[1].set_ylabel("volumetric (area) strain, dilation +")
    ax[2].set_xlabel("pressure [Pa]"); ax[2].set_ylabel("volumetric strain")
    ax[0].legend(fontsize=7); ax[2].legend(fontsize=7)
    for x in ax:
        x.grid(True, alpha=0.3)
    fig.suptitle("Ehlers parameters identified from the DEM cell (dashed) against the cell (solid)")
    fig.tight_layout()
    fig.savefig(os.path.join(out, "calibration.png"), dpi=110)
    stress_like = ("mu", "lmbda", "mu_c", "delta0", "delta_star", "epsilon0", "epsilon_star", "kappa")
    summary = dict(stress_scale=c, dem_contact_law=dsum.get("contact_law"), pressures_original_Pa=pressures,
                   identified_scaled=values,
                   identified_original_units={k: (v / c if k in stress_like else v) for k, v in values.items()},
                   identification=dict((k, isum.get(k)) for k in ("converged", "f_start", "f", "iterations",
                                                                   "evaluations", "wall_time_s")),
                   error_analysis=isum["stages"][-1]["error_analysis"], comparison=compare,
                   identify_exit_code=proc.returncode, wall_time_s=time.perf_counter() - t0,
                   load_average=os.getloadavg())
    with open(os.path.join(out, "summary.json"), "w") as f:
        json.dump(summary, f, indent=1, default=float)
    print(f"{'test':16s} {'peak DEM':>9s} {'Ehlers':>9s} {'at DEM':>8s} {'Ehlers':>8s} "
          f"{'final DEM':>9s} {'Ehlers':>9s} {'epsV end DEM':>12s} {'Ehlers':>8s}")
    for name, r in compare.items():
        print(f"{name:16s} {r['dem_peak_axial_stress']:9.2f} {r['model_peak_axial_stress']:9.2f} "
              f"{r['dem_axial_strain_at_peak']:8.4f} {r['model_axial_strain_at_peak']:8.4f} "
              f"{r['dem_final_axial_stress']:9.2f} {r['model_final_axial_stress']:9.2f} "
              f"{r['dem_final_volumetric_strain']:12.4f} {r['model_final_volumetric_strain']:8.4f}")
    print(f"dem_calibration: {time.perf_counter() - t0:.1f} s; {out}/summary.json, calibration.png")
    sys.exit(proc.returncode)


if __name__ == "__main__":
    main()
