#!/usr/bin/env python3
"""FEM x DEM load balancing: the biaxial test with a band, balance off and on (docs/results/balancing.md).

The scene of demos/femdem_biaxial.py with a weak corner (a square of --weak-size at the lower
left, its cells at --weak-friction x the friction) so that a band forms from it: the cells of
the band relax far longer than the others, and the rank that owns the corner does more cell
work. The same run twice in one process, balance off (a DemMaterial per rank) and on
(balancing.BalancedMaterial, --threshold), and with `--order off,on,passes` a third time
balanced between the Newton passes (BalancedMaterial(passes=True)); per converged step:

    cell work per rank   wall seconds in the cells' solves, homogenisation, tangents, commits
    imbalance            slowest rank / mean of the cell work of the step
    wall, CPU            seconds of the step (wall: the slowest rank; CPU: summed over the
                         ranks; OpenMPI spins while it waits, so CPU ~ ranks x wall)
    moves                cells moved after the step (balance on), or within it (passes)

with the load average (/proc/loadavg) before and after each run: the machine is shared, and
a busy core makes its rank slow whatever the balance. Writes femdem_balance.json and
femdem_balance.png in --out. The linear solver is PETSc's redundant LU by default (--solver):
MUMPS on 2 processes is not bit-reproducible from run to run, and with it the two runs would
take different Newton paths and do different cell work; with the redundant LU both runs are
bit-identical (checked: identical_histories) and differ only in where the cells are worked
on. Besides the wall seconds, the imbalance in DEM steps (the cells' reported work, which the
machine's load does not change) is recorded.

Defaults (2x4 mesh, 60-disc cells, 2 % in 8 steps, weak corner 5 mm at 0.7 x the friction)
take about a minute on the 2-core machine; the figures of docs/results/balancing.md (4x8 mesh, a
weaker and larger corner, 2.1 % in 7 steps) about 6 minutes per order:

    mpirun -n 2 python3 benchmarks/femdem/femdem_balance.py --out results/femdem_balance
    mpirun -n 2 python3 benchmarks/femdem/femdem_balance.py --mesh 4x8 --axial-strain 0.021 --steps 7 \
        --weak-size 5e-3 --weak-friction 0.5 --order on,off --out results/femdem_balance_4x8
"""
import argparse
import json
import os
import time

import numpy as np
from mpi4py import MPI

from cosserat_fenicsx.balancing import imbalance

CELL_TIMERS = ("solve", "homogenize", "tangent", "commit")
#: redundant: PETSc's LU of the whole (small) system on every rank, bit-reproducible, so both
#: runs take the same Newton path and do the same cell work; mumps: the scene's default
SOLVERS = {"redundant": {"pc_type": "redundant"}, "mumps": {"pc_type": "lu"}}


#: the runs --order may ask for: label -> (balance, between passes)
RUNS = {"off": (False, False), "on": (True, False), "passes": (True, True)}


def run(comm, a, label):
    """One run; per-step measurements (the same on every rank)."""
    balance, passes = RUNS[label]
    from cosserat_fenicsx.materials.dem import CellOptions
    from cosserat_fenicsx.scenes.femdem_biaxial import FemDemBiaxial, FemDemSettings, parse_mesh
    nx, ny = parse_mesh(a.mesh)
    s = FemDemSettings(nx=nx, ny=ny, mode=a.mode, tangent=a.tangent, axial_strain=a.axial_strain, steps=a.steps,
                       weak_size=a.weak_size, weak_friction_factor=a.weak_friction, grain_diameter=a.grain_diameter,
                       cell=CellOptions(particles=a.particles), balance=balance, balance_threshold=a.threshold,
                       balance_passes=passes, solver_options=SOLVERS[a.solver])
    load_start = list(os.getloadavg())
    test = FemDemBiaxial(comm, s, verbose=False)
    steps = []
    last = {"wall": time.perf_counter(), "cpu": time.process_time(), "cells": 0.0}

    def on_step(row):
        wall, cpu = time.perf_counter(), time.process_time()
        timers = test.material.timers
        cells = sum(timers.get(k, 0.0) for k in CELL_TIMERS)
        work = comm.allgather(cells - last["cells"])
        report = test.material.balance_report()["steps"][-1] if balance else {}
        # DEM steps per rank (the cells' work in the material's unit, independent of the
        # machine's load): per worker when balanced, per home rank (= worker) when not
        dem = report["work_cost"] if balance else comm.allgather(float(test.gauss_points.step_cost.sum()))
        steps.append({"step": row["step"], "axial_strain": row["axial_strain"], "stress_ratio": row["stress_ratio"],
                      "newton_iterations": row["newton_iterations"], "dem_steps": row["dem_steps"],
                      "cell_work_seconds": work, "imbalance": imbalance(work),
                      "dem_steps_per_rank": dem, "dem_steps_imbalance": imbalance(dem),
                      "wall_seconds": comm.allreduce(wall - last["wall"], op=MPI.MAX),
                      "cpu_seconds": comm.allreduce(cpu - last["cpu"]),
                      "moves": report.get("moves", 0) + report.get("pass_moves", 0),
                      "pass_imbalance": report.get("pass_imbalance"),
                      "predicted_imbalance": report.get("predicted_imbalance"),
                      "points_away_from_home": report.get("points_away_from_home", 0)})
        last.update(wall=time.perf_counter(), cpu=time.process_time(), cells=cells)
        if comm.rank == 0:
            r = steps[-1]
            print(f"  balance {label:6s} step {r['step']:3d}: cell work "
                  f"{' '.join(f'{w:6.2f}' for w in work)} s, imbalance {r['imbalance']:.3f}, "
                  f"DEM steps {r['dem_steps_imbalance']:.3f}, wall {r['wall_seconds']:6.2f} s, moves {r['moves']}",
                  flush=True)

    from cosserat_fenicsx.stepping import LoadSteppingError
    start, cpu_start = time.perf_counter(), time.process_time()
    stopped = ""
    try:
        test.run(on_step)
    except LoadSteppingError as error:   # keep the steps done (the other run stops there too)
        stopped = str(error)
    timers = {k: comm.allgather(v) for k, v in test.material.timers.items()}
    phase2 = [r for r in steps if r["step"] > 1]

    def mean(key):
        return float(np.mean([r[key] for r in phase2])) if phase2 else None

    return {"balance": balance, "passes": passes, "steps": steps, "stopped": stopped, "timers_per_rank": timers,
            "wall_seconds": comm.allreduce(time.perf_counter() - start, op=MPI.MAX),
            "cpu_seconds": comm.allreduce(time.process_time() - cpu_start),
            "imbalance_mean_phase2": mean("imbalance"), "dem_steps_imbalance_mean_phase2": mean("dem_steps_imbalance"),
            "cell_work_max_over_ranks_phase2": float(np.sum([max(r["cell_work_seconds"]) for r in phase2])),
            "cell_work_mean_over_ranks_phase2": float(np.sum([np.mean(r["cell_work_seconds"]) for r in phase2])),
            "wall_seconds_phase2": float(np.sum([r["wall_seconds"] for r in phase2])),
            "moves_total": int(sum(r["moves"] for r in steps)),
            "n_weak_elements": test.n_weak_cells, "n_gauss_points": comm.allreduce(len(test.points)),
            "load_average_start": load_start, "load_average_end": list(os.getloadavg()),
            "balance_report": test.material.balance_report() if balance else None}


def plot(result, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(1, 3, figsize=(15, 4.5))
    for label, style in (("off", "k.-"), ("on", "b.-"), ("passes", "g.-")):
        if label not in result:
            continue
        steps = result[label]["steps"]
        k = [r["step"] for r in steps]
        ax[0].plot(k, [r["imbalance"] for r in steps], style, label=f"balance {label}, wall seconds")
        ax[0].plot(k, [r["dem_steps_imbalance"] for r in steps], style[0] + "--", lw=0.8,
                   label=f"balance {label}, DEM steps")
        ax[1].plot(k, [r["wall_seconds"] for r in steps], style, label=f"balance {label}")
        work = np.array([r["cell_work_seconds"] for r in steps])
        for rank in range(work.shape[1]):
            ax[2].plot(k, work[:, rank], style, alpha=1.0 if rank == 0 else 0.5,
                       label=f"balance {label}, rank {rank}")
    ax[0].axhline(result["threshold"], color="r", lw=0.8, ls="--", label="threshold")
    ax[0].set_ylabel("cell work: slowest rank / mean")
    ax[1].set_ylabel("wall seconds per step")
    ax[2].set_ylabel("cell work per rank [s]")
    for a in ax:
        a.set_xlabel("load step")
        a.grid(alpha=0.3)
        a.legend(fontsize=7)
    fig.suptitle(f"FEM x DEM biaxial with a weak corner, mesh {result['options']['mesh']}, "
                 f"{result['options']['particles']} discs, {result['ranks']} ranks")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", default="results/femdem_balance")
    p.add_argument("--mesh", default="2x4")
    p.add_argument("--particles", type=int, default=60)
    p.add_argument("--mode", default="hybrid")
    p.add_argument("--tangent", default="pstlo")
    p.add_argument("--axial-strain", type=float, default=0.02)
    p.add_argument("--steps", type=int, default=8)
    p.add_argument("--weak-size", type=float, default=5e-3)
    p.add_argument("--weak-friction", type=float, default=0.7)
    p.add_argument("--grain-diameter", type=float, default=5e-4)
    p.add_argument("--threshold", type=float, default=1.10)
    p.add_argument("--order", default="off,on",
                   help="the runs in the order made, from off, on and passes (balanced between the Newton "
                        "passes), comma-separated, off and on included (default off,on; the machine's load "
                        "drifts: run two orders to bracket it)")
    p.add_argument("--solver", choices=tuple(SOLVERS), default="redundant", help="linear solver (default %(default)s)")
    a = p.parse_args()
    order = a.order.split(",")
    if not ({"off", "on"} <= set(order) <= set(RUNS)) or len(set(order)) != len(order):
        p.error(f"--order {a.order}: off and on, and optionally passes, each once, comma-separated")
    comm = MPI.COMM_WORLD
    if comm.size < 2:
        raise SystemExit("femdem_balance: run it on 2 or more ranks (mpirun -n 2 ...)")
    result = {"options": vars(a), "ranks": comm.size, "threshold": a.threshold}
    for label in order:
        result[label] = run(comm, a, label)
    labels = [k for k in RUNS if k in result]          # off, on[, passes]
    runs = [result[k] for k in labels]
    both = {key: [r[key] for r in runs] for key in ("imbalance_mean_phase2", "dem_steps_imbalance_mean_phase2",
                                                    "wall_seconds_phase2", "cell_work_max_over_ranks_phase2",
                                                    "cpu_seconds", "moves_total")}
    # the numerics of the runs step by step (bit-identical with the redundant LU)
    numerics = [[(r["stress_ratio"], r["newton_iterations"], r["dem_steps"]) for r in x["steps"]] for x in runs]
    n = min(map(len, numerics))
    ratios = np.array([[row[0] for row in rows[:n]] for rows in numerics])
    off = result["off"]
    result["comparison"] = dict(
        both, runs=labels,
        wall_ratio_over_off_phase2=[r["wall_seconds_phase2"] / off["wall_seconds_phase2"] for r in runs],
        max_stress_ratio_difference=float(np.abs(ratios - ratios[0]).max()) if n else None,
        identical_histories=all(x == numerics[0] for x in numerics))
    if comm.rank == 0:
        os.makedirs(a.out, exist_ok=True)
        with open(os.path.join(a.out, "femdem_balance.json"), "w") as f:
            json.dump(result, f, indent=1)
        plot(result, os.path.join(a.out, "femdem_balance.png"))
        c = result["comparison"]
        for k, label in enumerate(labels):
            r = result[label]
            print(f"balance {label:6s}: imbalance (phase 2 mean, slowest / mean cell work) "
                  f"{c['imbalance_mean_phase2'][k]:.3f} (DEM steps {c['dem_steps_imbalance_mean_phase2'][k]:.3f}), "
                  f"phase 2 wall {c['wall_seconds_phase2'][k]:.1f} s "
                  f"(/ off: {c['wall_ratio_over_off_phase2'][k]:.3f}), "
                  f"{c['moves_total'][k]} moves, load average {r['load_average_start'][0]:.2f} -> "
                  f"{r['load_average_end'][0]:.2f}", flush=True)
        print(f"identical results: {c['identical_histories']}; outputs in {a.out}", flush=True)


if __name__ == "__main__":
    main()
