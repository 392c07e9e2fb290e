#!/usr/bin/env python3
"""A large FEM x DEM run: at least 10,000 Gauss points with 228-disc cells.

    /usr/bin/python3 benchmarks/femdem/femdem_large.py --out results/benchmarks/femdem_large [--stop-after K]
    /usr/bin/python3 benchmarks/femdem/femdem_large.py --out results/benchmarks/femdem_large --restart

runs demos/femdem_biaxial.py under mpirun (--np ranks, --cell-threads threads each) on the
biaxial with a weak corner, mesh --mesh (default 29x58 rectangles: 10,092 Gauss points), to
3 % axial strain in 15 steps (the peak is at 1.4 %), the demo's cells and Newton rule, cells
batched and balanced between the ranks, a checkpoint after every load step. A queue's time
limit is --stop-after K load steps; --restart continues from the last checkpoint (bit for bit,
docs/reference/restart.md), so the run can be carried through the peak in pieces. After each piece it
writes femdem_large.json: Gauss points, wall and CPU seconds, wall seconds and DEM steps per
load step (from history.csv; a step's own seconds, the pieces' clocks joined), the cell memory (summary.json: per cell x points) and the peak
resident memory of a rank, the imbalance before and after each balancing (slowest rank / mean
of the measured cell work), the stress ratio reached and whether the peak was passed.
--cell-option KEY=VALUE is passed on to the demo (the cells' relaxation, e.g. method=fire:
benchmarks/femdem/femdem_cell_relaxation.py measures what it saves and changes).
"""
import argparse
import csv
import json
import os
import resource
import subprocess
import sys
import time

from benchmarks import ROOT


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", default="results/benchmarks/femdem_large")
    p.add_argument("--np", type=int, default=2)
    p.add_argument("--cell-threads", type=int, default=1)
    p.add_argument("--mesh", default="29x58")
    p.add_argument("--particles", type=int, default=228)
    p.add_argument("--axial-strain", type=float, default=0.03)
    p.add_argument("--steps", type=int, default=15)
    p.add_argument("--tangent", default="pstlo")
    p.add_argument("--cell-option", action="append", default=[], metavar="KEY=VALUE",
                   help="forwarded to the demo (cells' relaxation; benchmarks/femdem/femdem_cell_relaxation.py)")
    p.add_argument("--accept-rtol", type=float, default=None,
                   help="the demo's --accept-rtol; with --restart it changes the rule from the checkpoint on "
                        "(docs/reference/restart.md)")
    p.add_argument("--force-rtol", type=float, default=None, help="the demo's --force-rtol (the same)")
    p.add_argument("--stop-after", type=int, default=None, help="stop after this load step (a queue's limit)")
    p.add_argument("--restart", action="store_true", help="continue the run in --out from its last checkpoint")
    a = p.parse_args()
    run_dir = os.path.join(a.out, "run")
    if a.restart:
        demo_args = ["--restart", run_dir]
    else:
        demo_args = ["--mesh", a.mesh, "--particles", str(a.particles), "--axial-strain", str(a.axial_strain),
                     "--steps", str(a.steps), "--tangent", a.tangent, "--weak-size", "0.005", "--weak-friction",
                     "0.5", "--batched", "--cell-threads", str(a.cell_threads), "--balance",
                     "--checkpoint-every", "1", "--fields", "displacement", "--out", run_dir]
        for option in a.cell_option:
            demo_args += ["--cell-option", option]
    for flag, value in (("--accept-rtol", a.accept_rtol), ("--force-rtol", a.force_rtol)):
        if value is not None:
            demo_args += [flag, str(value)]
    if a.stop_after is not None:
        demo_args += ["--stop-after", str(a.stop_after)]
    cmd = ["mpirun", "-n", str(a.np), sys.executable, os.path.join(ROOT, "demos", "femdem_biaxial.py"), *demo_args]
    env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
               OMPI_MCA_rmaps_base_oversubscribe="1", OMP_NUM_THREADS="1")
    os.makedirs(a.out, exist_ok=True)
    # the first history row of each piece: there the step clock (history.csv's wall_time,
    # which runs from the start of a piece or a phase) starts again
    piece_starts = [0]
    if a.restart:
        record_path = os.path.join(a.out, "femdem_large.json")
        # a piece killed before its end (a queue's hard limit) left no record: its steps are
        # then counted as the first piece's
        if os.path.exists(record_path):
            with open(record_path) as f:
                piece_starts = json.load(f)["piece_starts"]
        with open(os.path.join(run_dir, "checkpoint", "meta.json")) as f:
            piece_starts.append(int(json.load(f)["step"]))     # one history row per step
    load = list(os.getloadavg())
    wall = time.perf_counter()
    ru0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    proc = subprocess.run(cmd, env=env, cwd=ROOT)
    ru1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    wall = time.perf_counter() - wall
    if proc.returncode != 0:
        raise SystemExit(f"the run failed ({proc.returncode}): {' '.join(cmd)}")
    with open(os.path.join(run_dir, "summary.json")) as f:
        summary = json.load(f)
    rows = list(csv.DictReader(open(os.path.join(run_dir, "history.csv"))))
    steps, previous = [], (None, 0.0)
    for r in rows:
        # history.csv's wall_time runs from the start of the phase's stepping (and of a restarted
        # piece): a step's own seconds are the difference, unless the clock started again
        phase, clock = r["phase"], float(r["wall_time"])
        own = clock - previous[1] if phase == previous[0] and len(steps) not in piece_starts else clock
        previous = (phase, clock)
        steps.append({"step": int(r["step"]), "phase": int(phase), "axial_strain": float(r["axial_strain"]),
                      "stress_ratio": float(r["stress_ratio"]), "wall_seconds": own,
                      "dem_steps": float(r["dem_steps"]), "newton_iterations": int(float(r["newton_iterations"]))})
    ratios = [s["stress_ratio"] for s in steps]
    balance = summary.get("balance") or {}
    record = {"command": cmd, "piece_starts": piece_starts, "gauss_points": summary["n_gauss_points"], "ranks": a.np,
              "cell_threads": a.cell_threads, "particles_per_cell": summary["particles_per_cell"],
              "piece_wall_seconds": wall, "piece_cpu_seconds": (ru1.ru_utime - ru0.ru_utime) + (ru1.ru_stime - ru0.ru_stime),
              "load_before": load, "load_after": list(os.getloadavg()),
              "memory_per_cell_bytes": summary["memory_per_cell_bytes"],
              "cell_memory_bytes": summary["memory_per_cell_bytes"] * summary["n_gauss_points"],
              "peak_rss_of_a_rank_bytes": ru1.ru_maxrss * 1024,
              "steps": steps, "time_max_over_ranks": summary["time_max_over_ranks"],
              "imbalance": [{k: r.get(k) for k in ("commit", "imbalance", "work_imbalance", "predicted_imbalance",
                                                   "moves", "migration_seconds")}
                            for r in balance.get("steps", [])] if isinstance(balance, dict) else balance,
              "imbalance_mean": balance.get("imbalance_mean") if isinstance(balance, dict) else None,
              "changed_at_restart": summary.get("changed_at_restart"),
              "completed": summary["completed"], "peak_passed": bool(ratios) and ratios[-1] < max(ratios),
              "peak_stress_ratio": max(ratios) if ratios else None}
    with open(os.path.join(a.out, "femdem_large.json"), "w") as f:
        json.dump(record, f, indent=1)
    for s in steps:
        print(f"step {s['step']:3d}  strain {s['axial_strain']:+.4f}  ratio {s['stress_ratio']:.4f}  "
              f"wall {s['wall_seconds']:8.1f} s  DEM steps {s['dem_steps']:.3g}  Newton {s['newton_iterations']}")
    print(f"{record['gauss_points']} Gauss points on {a.np} ranks: piece {wall:.0f} s wall, "
          f"{record['piece_cpu_seconds']:.0f} s CPU; cells {record['cell_memory_bytes'] / 2**20:.0f} MiB, "
          f"peak RSS of a rank {record['peak_rss_of_a_rank_bytes'] / 2**20:.0f} MiB; peak passed: {record['peak_passed']}")


if __name__ == "__main__":
    main()
