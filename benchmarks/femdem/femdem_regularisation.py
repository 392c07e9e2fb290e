#!/usr/bin/env python3
"""Does the micropolar macro scale regularise the FEM x DEM shear band?

The classical FEM x DEM continuum (000, 001) and the hybrid mode (the cell's symmetric
stress, elastic skew stress 2 mu_c skw(eps) and couple stress 2 mu_c l_c^2 kappa) on the same
biaxial test with a weak corner (a square of --weak-size whose cells have --weak-friction x
the friction) on --meshes: post-peak curves and the band thickness H (the section 4.4 bell
fitted to the equivalent strain at the Gauss points outside the weak corner; `band_verdict` refuses a fit that is no band: too little
contrast, thinner than half an element, or wider than the specimen). The classical band
should follow the mesh (000 Fig. 4); the hybrid one should converge, with a width that grows
with l_c (--lc-factors x l_c on --lc-mesh).

Cost with the defaults: about 5 CPU hours on one core (the 6x12 runs most of it;
docs/results/femdem.md has the cost of every run). Writes --out/regularisation.txt (table with the cost of every run), regularisation.png
(curves, H against h and l_c, band profiles) and one JSON record per run (reruns resume).

    mpirun -n 2 python3 benchmarks/femdem/femdem_regularisation.py --out results/femdem_regularisation
"""
import argparse
import math
import os

import numpy as np
from mpi4py import MPI

from benchmarks.femdem.femdem_cases import TIME_COLUMNS, parse_mesh, run_case, settings, stored_record, table, write_report

from cosserat_fenicsx.shear_band import band_verdict, fit_band


def outside_weak_corner(record, weak_size):
    """Points and equivalent strains of a record outside the weak corner (the meshes put
    whole elements in it, so these are the points of the unweakened cells, which the
    scene's band() fits: the weak cells strain more whether or not a band forms)."""
    pts, e = np.array(record["points"]), np.array(record["equivalent_strain"])
    keep = ~((pts[:, 0] < weak_size) & (pts[:, 1] < weak_size))
    return pts[keep], e[keep]


def band_outside_weak_corner(record, weak_size, width=0.01, height=0.02):
    """(fit, verdict) of the bell over the unweakened cells (refitted from the record)."""
    if not record["points"]:
        return None, "no step"
    pts, e = outside_weak_corner(record, weak_size)
    try:
        fit = fit_band(pts, e)
    except ValueError as error:
        return None, str(error)
    ok, why = band_verdict(fit, min(width / record["mesh"][0], height / record["mesh"][1]), width)
    return fit, "band" if ok else why


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", default="results/femdem_regularisation")
    p.add_argument("--meshes", nargs="*", default=["2x4", "4x8", "6x12"],
                   help="h = 5, 2.5, 1.67 mm: each puts whole elements in the 5 mm weak corner")
    p.add_argument("--particles", type=int, default=100,
                   help="discs per cell (100: peak at 1 %% strain, so the post-peak range is affordable; docs/results/femdem.md)")
    p.add_argument("--l-c", type=float, default=5e-4, help="internal length of the hybrid runs [m] (docs/results/femdem.md: why 0.5 mm)")
    p.add_argument("--lc-factors", type=float, nargs="*", default=[0.5, 2.0])
    p.add_argument("--lc-mesh", default="4x8")
    p.add_argument("--axial-strain", type=float, default=0.026,
                   help="1.6 %% past the 100-disc peak (docs/results/femdem.md; 0.04 --steps 20 goes further at twice the cost)")
    p.add_argument("--steps", type=int, default=13)
    p.add_argument("--weak-size", type=float, default=5e-3)
    p.add_argument("--weak-friction", type=float, default=0.5)
    p.add_argument("--modes", nargs="+", default=["classical", "hybrid"])
    p.add_argument("--report-only", action="store_true", help="tabulate the runs that have records, run nothing")
    a = p.parse_args()
    comm = MPI.COMM_WORLD
    log = lambda t: comm.rank == 0 and print(t, flush=True)  # noqa: E731
    common = dict(particles=a.particles, axial_strain=a.axial_strain, steps=a.steps, weak_size=a.weak_size,
                  weak_friction_factor=a.weak_friction)
    cases = []
    for mesh in a.meshes:
        nx, ny = parse_mesh(mesh)
        for mode in a.modes:
            extra = {"l_c": a.l_c} if mode == "hybrid" else {}
            cases.append((f"{mode}_{mesh}", dict(common, mesh=(nx, ny), mode=mode, **extra)))
    nx, ny = parse_mesh(a.lc_mesh)
    for factor in a.lc_factors:
        cases.append((f"hybrid_{a.lc_mesh}_lc{factor:g}",
                      dict(common, mesh=(nx, ny), mode="hybrid", l_c=a.l_c * factor)))
    if a.report_only:
        records = [r for r in (stored_record(a.out, label, settings(**kw)) for label, kw in cases) if r is not None]
        log(f"report only: {len(records)} of {len(cases)} runs have records")
    else:
        records = [run_case(comm, a.out, label, settings(**kw), log=log) for label, kw in cases]
    if comm.rank != 0:
        return
    for r in records:
        r["h_mm"] = 10.0 / r["mesh"][0]
        r["lc_mm"] = r["l_c"] * 1e3 if r["l_c"] else None
        fit, r["band_verdict"] = band_outside_weak_corner(r, a.weak_size)
        r["band_fit"] = fit = fit.as_dict() if fit is not None else None
        r["H_mm"] = fit["thickness"] * 1e3 if r["band_verdict"] == "band" else None
        # the fitted bell where the fit converged to something inside the specimen (a fit with
        # no band to find can drift anywhere): shown beside the verdict
        r["H_fit_mm"] = (fit["thickness"] * 1e3 if fit and fit["converged"] and fit["thickness"] < 0.02 else None)
        r["contrast"] = r["band_fit"]["amplitude"] / max(r["band_fit"]["offset"], 1e-300) if r["band_fit"] else None
        r["final"] = r["stress_ratio"][-1]
        r["reached"] = -100.0 * r["axial_strain"][-1] if r["axial_strain"] else None
        r["dem"] = float(sum(r["dem_steps"]))
        r["it"] = int(sum(r["newton_iterations"]))
    text = table(records, [("run", "label", "s"), ("h [mm]", "h_mm", ".3f"), ("l_c [mm]", "lc_mm", ".3f"),
                           ("points", "n_gauss_points", "d"), ("peak", "peak_stress_ratio", ".4f"),
                           ("at strain", "axial_strain_at_peak", ".4f"), ("reached [%]", "reached", ".2f"),
                           ("final", "final", ".4f"),
                           ("H [mm]", "H_mm", ".3f"), ("fit H [mm]", "H_fit_mm", ".3f"), ("A/e0", "contrast", ".2f"),
                           ("Newton", "it", "d"), ("cuts", "cuts", "d"), ("DEM steps", "dem", ".3g"),
                           ("wall [s]", "wall_time", ".0f"), ("CPU [s]", "cpu_time", ".0f"),
                           ("load", "load_average_before", ".1f")] + TIME_COLUMNS)
    verdicts = "\n".join(f"  {r['label']}: {r['band_verdict']}" + (f"; stopped: {r['stopped']}" if r["stopped"] else "")
                         for r in records)
    head = (f"FEM x DEM biaxial 10 x 20 mm, weak corner {a.weak_size * 1e3:g} mm (friction x {a.weak_friction:g}), "
            f"{a.particles} discs per cell, to {a.axial_strain:g} in {a.steps} steps, {comm.size} ranks\n")
    write_report(a.out, "regularisation.txt", head + text + "\nband verdicts:\n" + verdicts)
    plot(records, a, os.path.join(a.out, "regularisation.png"))


def plot(records, a, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(2, 3, figsize=(16, 9))
    styles = {"classical": "--", "hybrid": "-"}
    for r in records:
        if "_lc" in r["label"]:
            continue
        ax[0, 0].plot(-np.array(r["axial_strain"]) * 100, r["stress_ratio"], styles[r["mode"]],
                      label=f"{r['mode']} {r['mesh'][0]}x{r['mesh'][1]}")
    ax[0, 0].set_xlabel("axial strain [%]"); ax[0, 0].set_ylabel("mean stress ratio (000 eq. 40)"); ax[0, 0].legend()
    for mode in ("classical", "hybrid"):
        rs = [r for r in records if r["mode"] == mode and "_lc" not in r["label"]]
        ax[0, 1].plot([r["h_mm"] for r in rs], [r["H_fit_mm"] for r in rs], "o" + styles[mode], label=f"{mode} (fit)")
        ok = [r for r in rs if r["H_mm"]]
        ax[0, 1].plot([r["h_mm"] for r in ok], [r["H_mm"] for r in ok], "ks", mfc="none")
    ax[0, 1].set_xlabel("element size h [mm]"); ax[0, 1].set_ylabel("band thickness H [mm] (squares: a band)")
    ax[0, 1].legend()
    lc = sorted([r for r in records if r["mode"] == "hybrid" and f"_{a.lc_mesh}" in r["label"]],
                key=lambda r: r["l_c"])
    ax[0, 2].plot([r["lc_mm"] for r in lc], [r["H_fit_mm"] for r in lc], "o-")
    ax[0, 2].set_xlabel("l_c [mm]"); ax[0, 2].set_ylabel(f"H [mm] on {a.lc_mesh}")
    for k, mode in enumerate(("classical", "hybrid")):
        for r in [r for r in records if r["mode"] == mode and "_lc" not in r["label"]]:
            if not r["band_fit"] or r["points"] is None:
                continue
            f = r["band_fit"]
            alpha = math.radians(f["inclination_deg"])
            pts, e = outside_weak_corner(r, a.weak_size)
            d = (pts[:, 1] - f["x10"]) * math.cos(alpha) - pts[:, 0] * math.sin(alpha)
            ax[1, k].plot(d * 1e3, e, ".", ms=2, label=f"{r['mesh'][0]}x{r['mesh'][1]}")
        ax[1, k].set_xlabel("distance from the band axis [mm]")
        ax[1, k].set_ylabel("equivalent strain (outside the weak corner)")
        ax[1, k].set_title(mode); ax[1, k].legend()
    ax[1, 2].bar([r["label"] for r in records], [r["wall_time"] for r in records])
    ax[1, 2].set_ylabel("wall time [s]"); ax[1, 2].tick_params(axis="x", rotation=60)
    fig.suptitle("FEM x DEM shear band: classical vs hybrid (micropolar) macro scale")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    main()
