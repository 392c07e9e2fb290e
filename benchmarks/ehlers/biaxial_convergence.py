#!/usr/bin/env python3
"""Error against wall time for the biaxial test: peak vertical stress
and band thickness H (section 4.4 fit, standard deviation of the bell) across meshes and
numbers of load steps, against the finest run of the set as the reference.

Half-size specimen (25 mm x 50 mm, imperfection 5 mm x 0.8, as benchmarks/ehlers/biaxial_regularisation.py),
the regularising micropolar set of docs/results/regularisation.md (k_sigma = 0, l_c = 0.2 mm,
mu_c = mu), compression to 8 %. (With the spec's k_sigma = 10 the band thickness has no
limit under refinement, so its "error" would only measure the mesh dependence:
`--k-sigma 10 --l-c 3e-3` reproduces that study.) The compression lasts --loading-time
seconds whatever the number of steps: with the Perzyna law the loading rate is physics,
the step size is discretisation. The
reference is the last (h, steps) pair given, which should be the finest in both. The
errors are relative to it, so they measure self-convergence, not the distance to the
exact solution.

Writes --out/convergence.csv (one row per run, appended as runs finish),
convergence.json and convergence.png (error against wall time, one curve per number of
steps, the points along a curve are the meshes).

    python3 benchmarks/ehlers/biaxial_convergence.py --out results/convergence
"""
import argparse
import csv
import json
import os

import numpy as np
from mpi4py import MPI

from benchmarks.ehlers.biaxial_regularisation import add_specimen_arguments, run_case

COLUMNS = ["cell_size", "steps", "peak_vertical_stress", "band_thickness", "band_inclination_deg",
           "completed", "wall_time", "error_peak", "error_thickness"]


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", default="results/convergence")
    p.add_argument("--cell-sizes", type=float, nargs="+", default=[3.33e-3, 2.5e-3, 1.67e-3])
    p.add_argument("--step-counts", type=int, nargs="+", default=[40, 80, 160])
    add_specimen_arguments(p)
    p.add_argument("--loading-time", type=float, default=80.0,
                   help="physical duration of the compression [s], the same for every step count, so that "
                        "the steps change the time discretisation and not the loading rate (default 80 s)")
    p.add_argument("--l-c", type=float, default=0.2e-3, help="internal length [m]")
    args = p.parse_args()
    comm = MPI.COMM_WORLD
    os.makedirs(args.out, exist_ok=True)
    # the reference (finest mesh, most steps) first, so that every later row has its errors
    cases = [(h, n) for n in args.step_counts for h in args.cell_sizes]
    reference = (min(args.cell_sizes), max(args.step_counts))
    cases.remove(reference)
    cases.insert(0, reference)
    results, ref = [], None
    path = os.path.join(args.out, "convergence.csv")
    if comm.rank == 0:
        with open(path, "w", newline="") as f:
            csv.writer(f).writerow(COLUMNS)
    for h, n in cases:
        args.steps = n
        r = run_case(comm, args, True, args.l_c, h, step_time=args.loading_time / n)
        r["steps"] = n
        ref = ref or r
        r["error_peak"] = abs(r["peak_vertical_stress"] - ref["peak_vertical_stress"]) / abs(ref["peak_vertical_stress"])
        r["error_thickness"] = abs(r["band_thickness"] - ref["band_thickness"]) / ref["band_thickness"]
        results.append(r)
        if comm.rank == 0:
            with open(path, "a", newline="") as f:
                csv.writer(f).writerow([r[c] for c in COLUMNS])
            print(" ".join(f"{c}={r[c]:.4g}" if isinstance(r[c], float) else f"{c}={r[c]}" for c in COLUMNS), flush=True)
            with open(os.path.join(args.out, "convergence.json"), "w") as f:
                json.dump([{k: v for k, v in x.items() if k != "curve"} for x in results], f, indent=1, default=float)
            plot(results[1:], args.out)


def plot(results, out):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(1, 2, figsize=(10, 4))
    for n in sorted({r["steps"] for r in results}):
        rs = sorted([r for r in results if r["steps"] == n], key=lambda r: r["wall_time"])
        for a, key in zip(ax, ("error_peak", "error_thickness")):
            a.loglog([r["wall_time"] for r in rs], [max(r[key], 1e-8) for r in rs], "o-", label=f"{n} steps")
            for r in rs:
                a.annotate(f"h={r['cell_size'] * 1e3:.3g}", (r["wall_time"], max(r[key], 1e-8)), fontsize=6)
    ax[0].set_ylabel("relative error of the peak vertical stress")
    ax[1].set_ylabel("relative error of the band thickness H")
    for a in ax:
        a.set_xlabel("wall time [s]"); a.legend(fontsize=7)
    fig.tight_layout(); fig.savefig(os.path.join(out, "convergence.png"), dpi=120)
    plt.close(fig)


if __name__ == "__main__":
    main()
