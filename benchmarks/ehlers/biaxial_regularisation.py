#!/usr/bin/env python3
"""Regularisation by the micropolar terms: shear-band thickness and the
post-peak curve of the biaxial test on several meshes, micropolar against classical, and
the thickness against l_c.

Runs cosserat_fenicsx.scenes.biaxial (the scene of demos/biaxial.py) on a half-size
specimen (W x H = 25 mm x 50 mm, imperfection 5 mm as in the demo) so that h <= l_c / 2 is affordable;
the band thickness is H of the section 4.4 fit (standard deviation of the bell, eq 4.22)
at the final state. Expected: micropolar H converges under refinement,
classical H follows the element size h; H grows with l_c.

Writes --out/regularisation.csv (one row per run, appended as runs finish, so a partial
run keeps its rows), regularisation.json and regularisation.png (curves, H against h, H
against l_c). Serial or under mpirun.

    python3 benchmarks/ehlers/biaxial_regularisation.py --out results/regularisation
    python3 benchmarks/ehlers/biaxial_regularisation.py --cell-sizes 2.5e-3 1.25e-3 --l-c 3e-3 6e-3
"""
import argparse
import csv
import json
import os
import time

import numpy as np
from mpi4py import MPI

from cosserat_fenicsx.scenes.biaxial import BiaxialSettings, BiaxialTest
from cosserat_fenicsx.stepping import LoadSteppingError

COLUMNS = ["model", "l_c", "cell_size", "peak_vertical_stress", "axial_strain_at_peak", "final_vertical_stress",
           "plastic_fraction_final", "band_thickness", "band_inclination_deg", "band_rms", "completed", "steps", "wall_time"]


def run_case(comm, args, micropolar, l_c, h, step_time=1.0):
    s = BiaxialSettings(width=args.width, height=args.height, cell_size=h, micropolar=micropolar,
                        axial_strain=args.axial_strain, steps=args.steps, weak_size=args.weak_size,
                        weak_beta_factor=args.weak_factor,
                        eta=args.eta, step_time=step_time,
                        material=dict(l_c=l_c, k_sigma=args.k_sigma, k_mu=args.k_mu) if micropolar else {})
    start = time.perf_counter()
    test = BiaxialTest(comm, s, verbose=False)
    completed = True
    try:
        test.run()
    except LoadSteppingError as error:
        completed = False
        if comm.rank == 0:
            print(f"  stopped: {error}", flush=True)
    rows = [r for r in test.history if r["phase"] == 2]
    stress = np.array([r["vertical_stress"] for r in rows])
    i = int(np.argmin(stress))
    try:
        band = test.band()
    except ValueError:
        band = None
    return {"model": "micropolar" if micropolar else "classical", "l_c": l_c if micropolar else 0.0,
            "cell_size": h, "peak_vertical_stress": stress[i], "axial_strain_at_peak": rows[i]["axial_strain"],
            "final_vertical_stress": stress[-1],
            "plastic_fraction_final": rows[-1]["plastic_fraction"], "band_thickness": band.thickness if band else np.nan,
            "band_inclination_deg": band.inclination_deg if band else np.nan,
            "band_rms": band.rms_residual if band else np.nan, "completed": completed, "steps": len(rows),
            "wall_time": time.perf_counter() - start,
            "curve": [[r["axial_strain"], r["vertical_stress"]] for r in rows]}


def add_specimen_arguments(p):
    """Options shared with biaxial_convergence.py: half-size specimen, imperfection, loading,
    viscosity and the regularising micropolar set (docs/results/regularisation.md)."""
    p.add_argument("--width", type=float, default=0.025)
    p.add_argument("--height", type=float, default=0.05)
    p.add_argument("--weak-size", type=float, default=5e-3)
    p.add_argument("--weak-factor", type=float, default=0.8,
                   help="beta0, beta* of the weakened square relative to the rest (default 0.8, as the demo)")
    p.add_argument("--axial-strain", type=float, default=0.08)
    p.add_argument("--eta", type=float, default=0.1, help="Perzyna time [s] (default 0.1, as the demo)")
    p.add_argument("--k-sigma", type=float, default=0.0,
                   help="skew-stress weight in F, G (default 0: the regularising choice, docs/results/regularisation.md; "
                        "the spec's reference set is 10)")
    p.add_argument("--k-mu", type=float, default=0.0, help="couple-stress weight in F, G [1/m^2] (default 0)")


def plot(results, out, mesh_l_c):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(1, 3, figsize=(15, 4.5))
    for r in results:
        c = np.array(r["curve"])
        style = "-" if r["model"] == "micropolar" else "--"
        label = f"{r['model']} l_c={r['l_c'] * 1e3:g} h={r['cell_size'] * 1e3:.3g} mm"
        ax[0].plot(-c[:, 0] * 100, -c[:, 1] / 1e3, style, label=label)
    ax[0].set_xlabel("axial strain [%]"); ax[0].set_ylabel("vertical stress [kPa]"); ax[0].legend(fontsize=6)
    for model, marker in (("micropolar", "o-"), ("classical", "s--")):
        rs = sorted([r for r in results if r["model"] == model and (model == "classical" or r["l_c"] == mesh_l_c)],
                    key=lambda r: r["cell_size"])
        if rs:
            ax[1].plot([r["cell_size"] * 1e3 for r in rs], [r["band_thickness"] * 1e3 for r in rs], marker, label=model)
    ax[1].set_xlabel("element size h [mm]"); ax[1].set_ylabel("band thickness H [mm]"); ax[1].legend()
    ax[1].set_xlim(left=0); ax[1].set_ylim(bottom=0)
    hmin = min((r["cell_size"] for r in results if r["model"] == "micropolar"), default=None)
    rs = sorted([r for r in results if r["model"] == "micropolar" and r["cell_size"] == hmin], key=lambda r: r["l_c"])
    if rs:
        ax[2].plot([r["l_c"] * 1e3 for r in rs], [r["band_thickness"] * 1e3 for r in rs], "o-")
        ax[2].set_title(f"h = {hmin * 1e3:.3g} mm")
    ax[2].set_xlabel("l_c [mm]"); ax[2].set_ylabel("band thickness H [mm]")
    fig.tight_layout(); fig.savefig(os.path.join(out, "regularisation.png"), dpi=120)
    plt.close(fig)


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", default="results/regularisation")
    p.add_argument("--parts", nargs="+", choices=["mesh", "classical", "l_c"], default=["mesh", "classical", "l_c"],
                   help="mesh: micropolar at --mesh-l-c on every cell size; classical: the Cauchy model on every "
                        "cell size; l_c: micropolar at every --l-c on --l-c-cell-size")
    p.add_argument("--cell-sizes", type=float, nargs="+", default=[2.5e-3, 1.25e-3, 0.625e-3])
    p.add_argument("--mesh-l-c", type=float, default=0.2e-3, help="l_c of the mesh sweep [m] (default 0.2 mm)")
    p.add_argument("--l-c", type=float, nargs="+", default=[0.75e-3, 0.3e-3, 0.1e-3],
                   help="internal lengths of the l_c sweep [m]")
    p.add_argument("--l-c-cell-size", type=float, default=None,
                   help="cell size of the l_c sweep [m] (default: the smallest of --cell-sizes)")
    p.add_argument("--steps", type=int, default=80)
    add_specimen_arguments(p)
    args = p.parse_args()
    comm = MPI.COMM_WORLD
    os.makedirs(args.out, exist_ok=True)
    cases = []
    if "mesh" in args.parts:
        cases += [(True, args.mesh_l_c, h) for h in args.cell_sizes]
    if "classical" in args.parts:
        cases += [(False, 0.0, h) for h in args.cell_sizes]
    if "l_c" in args.parts:
        h_l_c = args.l_c_cell_size or min(args.cell_sizes)
        cases += [(True, l_c, h_l_c) for l_c in args.l_c if (True, l_c, h_l_c) not in cases]
    results = []
    path = os.path.join(args.out, "regularisation.csv")
    if comm.rank == 0:
        with open(path, "w", newline="") as f:
            csv.writer(f).writerow(COLUMNS)
    for micropolar, l_c, h in cases:
        r = run_case(comm, args, micropolar, l_c, h)
        results.append(r)
        if comm.rank == 0:
            with open(path, "a", newline="") as f:
                csv.writer(f).writerow([r[c] for c in COLUMNS])
            print(" ".join(f"{c}={r[c]:.4g}" if isinstance(r[c], float) else f"{c}={r[c]}" for c in COLUMNS), flush=True)
            with open(os.path.join(args.out, "regularisation.json"), "w") as f:
                json.dump({"settings": vars(args), "runs": results}, f, indent=1, default=float)
            plot(results, args.out, args.mesh_l_c)


if __name__ == "__main__":
    main()
