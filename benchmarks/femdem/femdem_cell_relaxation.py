#!/usr/bin/env python3
"""Cheaper cells: how the cells' relaxation settings change the cost and the answer of FEM x DEM.

    mpirun -n 2 python3 benchmarks/femdem/femdem_cell_relaxation.py --out results/benchmarks/femdem_cell_relaxation

Almost all of a FEM x DEM run is the cells relaxing to equilibrium (docs/results/scaling.md), and
how many DEM steps that takes is set by the cell's relaxation options, which
demos/femdem_biaxial.py forwards with --cell-option KEY=VALUE. This runs the biaxial test
with a band (the scene of benchmarks/femdem/femdem_scaling.py: --mesh of 228-disc cells, weak
corner, --axial-strain in --steps load steps, through the peak) once per setting:

    default      local non-viscous damping 0.7, time step 0.25 x the stability estimate (the
                 default when this study was made; FIRE is since: docs/results/femdem.md,
                 "Default cells")
    dt_safety    the same with 0.5 x the estimate (half the steps for the same physical time)
    fire         FIRE (Bitzek et al. 2006), time step adapted up to 2 x the default one
    tight        the default relaxed 10x further (--relaxation-tol 1e-4): the reference

and reports, in one run of the machine: wall and CPU seconds, the Newton solves' wall seconds
(slowest rank; their ratio to the default is the speed-up), DEM steps, Newton iterations,
the peak stress ratio and its strain, and the largest difference of the stress ratio from the
reference run (tight, when it is among the cases; else the first) over the steps up to the
reference's peak and over all steps: what the default's own relaxation error is worth, and
what the cheaper settings add to it. The cells' loading ramp is the same number of steps in every case
(strain_rate per step), so a longer time step loads them faster in physical time: the
difference is what that costs. Writes femdem_cell_relaxation.json, .txt and .png in --out
(each case's record as soon as it ends, reused by a rerun; benchmarks/femdem/femdem_cases.py).
"""
import argparse
import os

import numpy as np
from mpi4py import MPI

from benchmarks.femdem.femdem_cases import parse_mesh, run_case, settings, table, write_report

#: label -> CellOptions overrides: `extra` is demcell.RelaxationOptions (--cell-option),
#: relaxation_tol is --relaxation-tol
#: every case names its relaxation method, so that the table does not move with the defaults
#: (FIRE since benchmarks/femdem/femdem_defaults.py; local damping when this study was made)
CASES = {"default": {"extra": {"method": "local"}}, "dt_safety": {"extra": {"method": "local", "dt_safety": 0.5}},
         "fire": {"extra": {"method": "fire"}}, "tight": {"relaxation_tol": 1e-4, "extra": {"method": "local"}}}


def compare(record, reference):
    """Largest |stress ratio - the reference's| over the steps before the reference's peak and
    over all common steps, and the peak's relative change."""
    a, b = np.array(record["stress_ratio"]), np.array(reference["stress_ratio"])
    n = min(len(a), len(b))
    peak = int(np.argmax(b[:n])) + 1 if n else 0
    diff = np.abs(a[:n] - b[:n])
    return {"pre_peak": float(diff[:peak].max()) if peak else None, "all": float(diff.max()) if n else None,
            "peak_change": record["peak_stress_ratio"] / reference["peak_stress_ratio"] - 1.0}


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", default="results/benchmarks/femdem_cell_relaxation")
    p.add_argument("--mesh", default="4x8")
    p.add_argument("--particles", type=int, default=228)
    p.add_argument("--axial-strain", type=float, default=0.02)
    p.add_argument("--steps", type=int, default=8)
    p.add_argument("--cases", default=",".join(CASES), help="comma-separated, of: " + ", ".join(CASES))
    a = p.parse_args()
    comm = MPI.COMM_WORLD
    labels = a.cases.split(",")
    unknown = [c for c in labels if c not in CASES]
    if unknown:
        p.error(f"unknown case(s) {unknown}; known: {', '.join(CASES)}")
    records = []
    for label in labels:
        s = settings(mesh=parse_mesh(a.mesh), particles=a.particles, cell=dict(CASES[label]),
                     axial_strain=a.axial_strain, steps=a.steps, weak_size=5e-3, weak_friction_factor=0.5,
                     batched=True)
        records.append(run_case(comm, a.out, label, s))
    if comm.rank:
        return
    by_label = dict(zip(labels, records))
    ref = by_label.get("tight", records[0])        # the answer, as well as we know it
    base = by_label.get("default", records[0])     # the cost everything is compared with
    for r in records:
        r["options"] = CASES[r["label"]]
        r["dem_steps_total"] = float(np.sum(r["dem_steps"]))
        r["newton_total"] = int(np.sum(r["newton_iterations"]))
        r["difference"] = compare(r, ref)
        r["newton_time"] = r["time_max_over_ranks"]["newton_total"]   # without the cells' preparation
    for r in records:
        r["speed_up"] = base["newton_time"] / r["newton_time"]
    columns = [("case", "label", "s"), ("wall s", "wall_time", ".0f"), ("CPU s", "cpu_time", ".0f"),
               ("Newton s", "newton_time", ".0f"), ("speed-up", "speed_up", ".2f"), ("DEM steps", "dem_steps_total", ".3g"),
               ("Newton its", "newton_total", "d"), ("peak ratio", "peak_stress_ratio", ".4f"),
               ("at strain", "axial_strain_at_peak", ".4f"),
               ("peak change", lambda r: r["difference"]["peak_change"], "+.2%"),
               ("max diff pre-peak", lambda r: r["difference"]["pre_peak"], ".4f"),
               ("max diff all", lambda r: r["difference"]["all"], ".4f"),
               ("load before", "load_average_before", ".2f"), ("load after", "load_average_after", ".2f")]
    text = (f"FEM x DEM biaxial with a band, {a.mesh} mesh ({ref['n_gauss_points']} cells of {a.particles} discs), "
            f"{a.axial_strain:g} axial strain in {a.steps} steps, {comm.size} rank(s), batched cells; "
            f"differences are in the stress ratio (sigma_1 - sigma_3)/(sigma_1 + sigma_3) against {ref['label']}, "
            f"speed-ups against {base['label']}\n"
            + table(records, columns) + "\n")
    write_report(a.out, "femdem_cell_relaxation.txt", text)
    import json
    with open(os.path.join(a.out, "femdem_cell_relaxation.json"), "w") as f:
        json.dump([{k: v for k, v in r.items() if k not in ("points", "equivalent_strain")} for r in records], f,
                  indent=1)
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(10, 4))
    for r in records:
        ax.plot(-np.array(r["axial_strain"]) * 100, r["stress_ratio"], "o-", ms=3,
                label=f"{r['label']} ({r['wall_time']:.0f} s)")
    ax.set_xlabel("axial strain [%]")
    ax.set_ylabel("stress ratio")
    ax.legend()
    ax.set_title("the macroscopic answer")
    bx.bar([r["label"] for r in records], [r["dem_steps_total"] for r in records])
    bx.set_ylabel("DEM steps (all cells, all steps)")
    bx.set_title("the cells' work")
    fig.tight_layout()
    fig.savefig(os.path.join(a.out, "femdem_cell_relaxation.png"), dpi=120)


if __name__ == "__main__":
    main()
