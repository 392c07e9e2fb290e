#!/usr/bin/env python3
"""Error against run time of the FEM x DEM biaxial demo: the peak stress ratio
against the wall time, varying one setting at a time from the hybrid runs of
benchmarks/femdem/femdem_regularisation.py (228 discs, PSTLO, l_c = 1 mm, unbalanced-force ratio
1e-3, 5 mm weak corner at friction x 0.5, steps of 0.2 % axial strain) up to 3 %, past the
peak: the cell size (100, 228, 400 discs) and the cells' relaxation tolerance (1e-2 to
3e-4). Both act at the material point, so they are varied on the 1x2 mesh (12 Gauss
points; the 5 mm weak corner holds no element centroid there, so the specimen is uniform),
where a run costs minutes; `--families mesh` adds the macro mesh (1x2,
2x4, 4x8; the regularisation study has the same meshes to 6 %, with the band). The tangent changes the path to the answer, not the
answer: its cost and error are in benchmarks/femdem/femdem_tangents.py.

The error of a family is measured against its most accurate member (finest mesh, tightest
tolerance); the cell size has no converged member (each size is another packing, the
representative volume question), so its row reports values. Writes --out/convergence.txt,
convergence.png (error and value against wall time) and one JSON record per run.

    mpirun -n 2 python3 benchmarks/femdem/femdem_convergence.py --out results/femdem_convergence
"""
import argparse
import os

import numpy as np
from mpi4py import MPI

from benchmarks.femdem.femdem_cases import run_case, settings, table, write_report

# the settings of the hybrid runs of benchmarks/femdem/femdem_regularisation.py, on 1x2, to 3 %
BASE = dict(mesh=(1, 2), particles=228, mode="hybrid", tangent="pstlo", l_c=1e-3, weak_size=5e-3,
            weak_friction_factor=0.5)
FAMILIES = {
    "mesh": [dict(mesh=m) for m in ((1, 2), (2, 4), (4, 8))],
    "cell size": [dict(particles=n) for n in (100, 228, 400)],
    "relaxation": [dict(cell=c) for c in ({"criterion": "force", "relaxation_tol": 1e-2},
                                          {"criterion": "force", "relaxation_tol": 3e-3},
                                          {"criterion": "force", "relaxation_tol": 1e-3},
                                          {"criterion": "force", "relaxation_tol": 3e-4})],
}
REFERENCE = {"mesh": -1, "relaxation": 3}   # most accurate member of each family


def label(kw):
    parts = []
    for k, v in sorted(kw.items()):
        if k == "cell":
            parts.append(f"{v['criterion']}{v['relaxation_tol']:g}")
        elif k == "mesh":
            parts.append(f"{v[0]}x{v[1]}")
        else:
            parts.append(f"{k}{v}")
    return "_".join(parts)


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", default="results/femdem_convergence")
    p.add_argument("--axial-strain", type=float, default=0.03)
    p.add_argument("--steps", type=int, default=15)
    p.add_argument("--families", nargs="+", default=["cell size", "relaxation"], choices=list(FAMILIES))
    a = p.parse_args()
    comm = MPI.COMM_WORLD
    log = lambda t: comm.rank == 0 and print(t, flush=True)  # noqa: E731
    rows = []
    for family in a.families:
        members = []
        for change in FAMILIES[family]:
            kw = dict(BASE, axial_strain=a.axial_strain, steps=a.steps, **change)
            members.append(run_case(comm, a.out, label(dict(BASE, **change)), settings(**kw), log=log))
        ref = members[REFERENCE[family]] if family in REFERENCE else None
        for change, r in zip(FAMILIES[family], members):
            r["family"], r["setting"] = family, label(change)
            if ref is not None and r is not ref:
                r["peak_error"] = abs(r["peak_stress_ratio"] - ref["peak_stress_ratio"]) / ref["peak_stress_ratio"]
            rows.append(r)
    if comm.rank != 0:
        return
    for r in rows:
        r["H_mm"] = r["band_thickness"] * 1e3 if r["band_thickness"] else None    # a band only
        r["it"] = int(sum(r["newton_iterations"]))
        r["dem"] = float(sum(r["dem_steps"]))
        r["cells_s"] = r["time_max_over_ranks"]["cell_solves"] + r["time_max_over_ranks"]["cell_tangents"]
    text = table(rows, [("family", "family", "s"), ("setting", "setting", "s"), ("points", "n_gauss_points", "d"),
                        ("peak", "peak_stress_ratio", ".4f"), ("at strain", "axial_strain_at_peak", ".4f"),
                        ("peak error", "peak_error", ".2e"), ("band H [mm]", "H_mm", ".2f"),
                        ("Newton", "it", "d"), ("cuts", "cuts", "d"), ("DEM steps", "dem", ".3g"),
                        ("cells [s]", "cells_s", ".0f"), ("wall [s]", "wall_time", ".0f"),
                        ("CPU [s]", "cpu_time", ".0f"), ("load", "load_average_before", ".1f")])
    head = (f"FEM x DEM biaxial (hybrid, l_c = 1 mm, 5 mm weak corner), to {a.axial_strain:g} in {a.steps} steps, "
            f"{comm.size} ranks; peak error relative to the most accurate member of the family\n")
    write_report(a.out, "convergence.txt", head + text)
    plot(rows, os.path.join(a.out, "convergence.png"))


def plot(rows, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(1, 2, figsize=(12, 4.5))
    for family in dict.fromkeys(r["family"] for r in rows):
        rs = [r for r in rows if r["family"] == family]
        line, = ax[1].plot([r["wall_time"] for r in rs], [r["peak_stress_ratio"] for r in rs], "o-", label=family)
        for r in rs:
            ax[1].annotate(r["setting"], (r["wall_time"], r["peak_stress_ratio"]), fontsize=7)
        err = [r for r in rs if r.get("peak_error")]
        if err:
            ax[0].loglog([r["wall_time"] for r in err], [r["peak_error"] for r in err], "o-",
                         color=line.get_color(), label=family)
    ax[0].set_xlabel("wall time [s]"); ax[0].set_ylabel("relative error of the peak stress ratio"); ax[0].legend()
    ax[1].set_xscale("log"); ax[1].set_xlabel("wall time [s]"); ax[1].set_ylabel("peak stress ratio"); ax[1].legend()
    fig.suptitle("FEM x DEM biaxial: error against run time")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    main()
