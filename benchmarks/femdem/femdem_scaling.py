#!/usr/bin/env python3
"""FEM x DEM scaling on this machine's ranks and a measured cost model.

    /usr/bin/python3 benchmarks/femdem/femdem_scaling.py --out results/benchmarks/femdem_scaling

launches, one after the other (each under mpirun, in one run of this script, so the ratios
come from one state of the machine; the load average is recorded before and after each):

  strong   the biaxial with a weak corner (a band) on --mesh, 1 rank; 2 ranks; 2 ranks with
           --balance (balancing.BalancedMaterial); 2 ranks with --balance --balance-passes
           (balanced between the Newton passes). Efficiency E = T1 / (2 T2), T the wall
           time of the compression steps; also per DEM step (E x DEM steps of the 2-rank run /
           DEM steps of the 1-rank run), as the partition changes the round-off and with it
           the Newton path and the cells' work.
  weak     cells per rank fixed: --weak-mesh on 1 rank and the mesh twice as tall on 2 ranks
           (both with the weak corner). E_weak = T1 / T2 per step (the two problems differ:
           the taller specimen has twice the cells, and its band crosses more of them).
  shared   the machine's ceiling: a DEM step of the same cell solves in one process alone and
           in two at once (one per core), alternated 3 times; alone / together bounds the
           2-rank efficiency per DEM step whatever the balance (--contention-only: just this).
  cell     the cost of one cell iteration outside the FE: a 400-disc (and a 228-disc) cell of
           the scene's law driven through 10 biaxial increments of 1e-3 (solve from the
           committed state, then the pstlo and kruyt tangents): CPU ms per solve, per 100
           DEM steps, per tangent; memory per cell.

and fits the cost model (per load step, slowest rank)

    T(P) = max_r W_r + A / P + S(P) + X(P)

W_r = the cell work of rank r (t_dem x the DEM steps of its points + t_tan x its tangents; t_dem
and t_tan measured on 1 rank), A = assembly and gradient evaluation (measured on 1 rank;
scales as 1/P), S = linear solve and SNES (measured on 1 and 2 ranks; above 2 ranks taken as
S(2): a direct solve of this 2D problem does not speed up further -- the conservative
reading -- and grows as n^1.5 with the mesh, nested dissection of a 2D problem), X = the balancer's cell migrations (measured on 2 ranks, held constant; the time in its
gradient/flux exchanges is mostly waiting for the slowest rank, which max_r W_r counts, and the
messages themselves are not separated from it: the check against the measured 2-rank runs
shows what the model misses). max_r W_r uses the
measured DEM steps of every Gauss point at every step, split over P ranks (a) by the mesh
partition, emulated as P horizontal strips of equal point count (what a graph partitioner gives
a tall specimen), and (b) by the balancer's greedy assignment (balancing.assign). The model is
checked against the measured 2-rank runs, then evaluated for 1-64 ranks on the measured point
costs replicated onto a grid of --model-points points (nearest measured point): the band
occupies the same fraction of the specimen. Writes femdem_scaling.json and femdem_scaling.png.

Defaults (4x8 mesh = 192 cells of 228 discs, a weak corner of 5 mm at half the friction, 2 % in
8 steps; weak scaling 2x4 / 2x8) took 38 minutes on the 2-core machine otherwise idle
(docs/results/scaling.md), 60 minutes with the strong_2_passes case on a slower day.
"""
import argparse
import json
import os
import subprocess
import sys
import time

from benchmarks import ROOT

# one BLAS thread, as `make benchmark` sets: OpenBLAS threads may spin after a call, and their CPU
# seconds would then count in the cell costs this process measures with process_time
os.environ.setdefault("OMP_NUM_THREADS", "1")
import numpy as np  # noqa: E402


# --- one FE case (under mpirun) ---------------------------------------------------------------
def run_case(a):
    from benchmarks.femdem.femdem_balance import CELL_TIMERS      # the timers of the cell work
    from mpi4py import MPI
    from cosserat_fenicsx.materials.dem import CellOptions
    from cosserat_fenicsx.scenes.femdem_biaxial import FemDemBiaxial, FemDemSettings, parse_mesh
    comm = MPI.COMM_WORLD
    nx, ny = parse_mesh(a.case_mesh)
    s = FemDemSettings(nx=nx, ny=ny, height=0.02 * ny / 4, axial_strain=a.axial_strain, steps=a.steps,
                       weak_size=a.weak_size, weak_friction_factor=a.weak_friction, cell=CellOptions(particles=a.particles),
                       balance=a.balance, balance_passes=a.balance_passes, solver_options={"pc_type": "redundant"})
    load_before = list(os.getloadavg())
    test = FemDemBiaxial(comm, s, verbose=False)
    steps = []
    last = {"wall": time.perf_counter(), "cpu": time.process_time(), "cells": 0.0, "timing": test.timing(), "migration": 0.0}

    def on_step(row):
        wall, cpu = time.perf_counter(), time.process_time()
        timers = test.material.timers
        cells = sum(timers.get(k, 0.0) for k in CELL_TIMERS)
        migration = timers.get("migration", 0.0)
        timing = test.timing()
        delta = {k: timing[k] - last["timing"][k] for k in timing}
        pts, dem = test.global_order(test.gauss_points.step_cost)
        steps.append({
            "step": row["step"], "phase": row["phase"], "axial_strain": row["axial_strain"],
            "stress_ratio": row["stress_ratio"], "newton_iterations": row["newton_iterations"],
            "wall": comm.allreduce(wall - last["wall"], op=MPI.MAX), "cpu": comm.allreduce(cpu - last["cpu"]),
            "cell_work": comm.allgather(cells - last["cells"]),
            "assembly": comm.allreduce(delta["residual_assembly"] + delta["jacobian_assembly"]
                                       + delta["gradient_evaluation"], op=MPI.MAX),
            "linear": comm.allreduce(max(delta["linear_solve_and_snes"], 0.0), op=MPI.MAX),
            "dem_steps": dem.tolist() if dem is not None else None,
            # the balancer's migrations (its exchanges' time is mostly waiting for the slowest
            # rank, which max_r W_r already counts)
            "migration": comm.allreduce(migration - last["migration"], op=MPI.MAX)})
        last.update(wall=time.perf_counter(), cpu=time.process_time(), cells=cells, timing=timing, migration=migration)

    test.run(on_step=on_step)
    pts, _ = test.global_order(test.gauss_points.step_cost)
    m = test.material.timers
    tangents = comm.allreduce(test.gauss_points.counters["point_tangents"])
    record = {"mesh": [nx, ny], "ranks": comm.size, "balance": a.balance, "balance_passes": a.balance_passes,
              "particles": a.particles,
              "n_points": comm.allreduce(len(test.points)), "points": pts.tolist() if pts is not None else None,
              "steps": steps, "load_before": load_before, "load_after": list(os.getloadavg()),
              "cell_solve_seconds": comm.allreduce(m["solve"] + m["homogenize"]),
              "cell_tangent_seconds": comm.allreduce(m["tangent"]), "point_tangents": tangents,
              "dem_steps_total": float(sum(r["dem_steps"] for r in test.history)),
              "memory_per_cell_bytes": comm.allreduce(test.material.memory_bytes()) / comm.allreduce(len(test.points))}
    if comm.rank == 0:
        with open(a.json, "w") as f:
            json.dump(record, f)


# --- the cost of one cell iteration (serial, no FE) -------------------------------------------
def reference_cell(particles):
    """The scene's prepared cell (committed at F = I), as a FEM x DEM Gauss point starts."""
    import demcell as dc
    from cosserat_fenicsx.materials.dem import CellOptions
    options = CellOptions(particles=particles)
    state, _ = options.packing_state()
    return dc.reference_cell(state, options.law(), options.relaxation(), options.pressure)


def biaxial(e):
    """F of a biaxial increment: axial strain -e, lateral +e/2."""
    return np.array([[1.0 + 0.5 * e, 0.0], [0.0, 1.0 - e]])


def cell_cost(particles, increments=10):
    cell = reference_cell(particles)
    # one solve and one tangent of each kind, rolled back, before the timing: the first call of
    # a kernel in a process loads it from Numba's cache (about 0.1 s), which over 10 solves of
    # 10 ms doubled the "ms per 100 DEM steps" reported until 2026-12-04
    cell.set_deformation(biaxial(1e-3))
    cell.solve()
    for kind in ("pstlo", "kruyt"):
        cell.tangent(kind)
    cell.rollback()
    out = {"particles": particles, "solve_cpu": [], "solve_steps": [], "pstlo_cpu": [], "kruyt_cpu": []}
    for k in range(1, increments + 1):
        e = 1e-3 * k
        cell.set_deformation(biaxial(e))
        c0 = time.process_time()
        result = cell.solve()
        out["solve_cpu"].append(time.process_time() - c0)
        out["solve_steps"].append(result.steps)
        for kind in ("pstlo", "kruyt"):
            c0 = time.process_time()
            cell.tangent(kind)
            out[f"{kind}_cpu"].append(time.process_time() - c0)
        cell.commit()
    steps = np.sum(out["solve_steps"])
    out.update(ms_per_solve=1e3 * np.mean(out["solve_cpu"]), mean_steps_per_solve=float(np.mean(out["solve_steps"])),
               ms_per_100_steps=1e5 * np.sum(out["solve_cpu"]) / steps,
               ms_pstlo=1e3 * np.mean(out["pstlo_cpu"]), ms_kruyt=1e3 * np.mean(out["kruyt_cpu"]),
               memory_bytes=cell.memory_bytes())
    return out


# --- the machine's ceiling: a DEM step with one core busy and with both -------------------------
def probe(particles, seconds):
    """Cell solves of the scene's cell for `seconds` of wall time, started on a "go" line from
    stdin after the set-up (so that two probes time the same window); prints the CPU and wall
    time per DEM step as JSON."""
    cell = reference_cell(particles)

    def strain(k):      # biaxial increments of 1-5e-3 from the committed state, in turn
        return biaxial(1e-3 * (1 + k % 5))

    cell.set_deformation(strain(0))
    cell.solve()                         # compiled (or loaded from the cache) before the window
    print("ready", flush=True)
    sys.stdin.readline()
    c0, w0, steps, solves = time.process_time(), time.perf_counter(), 0, 0
    while time.perf_counter() - w0 < seconds:
        cell.rollback()
        cell.set_deformation(strain(solves))
        steps += cell.solve().steps
        solves += 1
    cpu, wall = time.process_time() - c0, time.perf_counter() - w0
    print(json.dumps({"cpu_us_per_step": 1e6 * cpu / steps, "wall_us_per_step": 1e6 * wall / steps,
                      "steps": steps, "solves": solves}), flush=True)


def contention(particles, rounds=3, seconds=8.0):
    """The cost of a DEM step of the same cell solves in one process alone and in two at once
    (one per core), alternated `rounds` times: alone / together is what the machine itself
    allows the 2-rank efficiency per DEM step to be (shared cache, memory bandwidth, clock,
    and on a virtual machine the host's other tenants), whatever the balance."""
    env = dict(os.environ, OMP_NUM_THREADS="1")
    cmd = [sys.executable, os.path.abspath(__file__), "--probe", "--particles", str(particles),
           "--probe-seconds", str(seconds)]

    def window(n):
        procs = [subprocess.Popen(cmd, env=env, cwd=ROOT, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                  text=True) for _ in range(n)]
        for q in procs:
            if q.stdout.readline().strip() != "ready":
                for other in procs:      # none left waiting for its "go"
                    other.kill()
                raise SystemExit(f"contention probe failed before its window: {' '.join(cmd)}")
        for q in procs:
            q.stdin.write("go\n")
            q.stdin.flush()
        return [json.loads(q.communicate()[0]) for q in procs]

    alone, together = [], []
    for _ in range(rounds):
        alone += window(1)
        together += window(2)
    a = float(np.median([r["cpu_us_per_step"] for r in alone]))
    b = float(np.median([r["cpu_us_per_step"] for r in together]))
    return {"particles": particles, "rounds": rounds, "seconds": seconds, "alone": alone, "together": together,
            "alone_cpu_us_per_step": a, "together_cpu_us_per_step": b, "ceiling": a / b}


# --- the cost model ------------------------------------------------------------------------------
def strips(points, n_ranks):
    """Rank of every point when the specimen is cut into n_ranks horizontal strips of equal
    point count (an emulation of a graph partition of a tall specimen)."""
    order = np.lexsort((points[:, 0], points[:, 1]))
    rank = np.empty(len(points), dtype=np.int64)
    rank[order] = np.arange(len(points)) * n_ranks // len(points)
    return rank


def max_work(cost, rank, n_ranks):
    return float(np.bincount(rank, weights=cost, minlength=n_ranks).max())


def balanced_max_work(cost, n_ranks):
    """Slowest rank after the balancer's assignment from the partition's strips."""
    from cosserat_fenicsx.balancing import assign
    worker = assign(cost, np.zeros(len(cost), dtype=np.int64), n_ranks, threshold=1.0)
    return max_work(cost, np.asarray(worker), n_ranks)


def model(one, two_balanced, points_grid=None, ranks=(1, 2, 4, 8, 16, 32, 64)):
    """T(P) per compression step from the 1-rank record (constants) and the 2-rank records
    (S(2), X); per step the point costs in seconds, optionally replicated onto points_grid."""
    steps1 = [s for s in one["steps"] if s["phase"] == 2]
    t_dem = one["cell_solve_seconds"] / max(one["dem_steps_total"], 1.0)       # s per DEM step
    t_tan = one["cell_tangent_seconds"] / max(one["point_tangents"], 1)         # s per tangent
    pts = np.array(one["points"])
    grid = pts if points_grid is None else points_grid
    nearest = np.argmin(((grid[:, None, :] - pts[None, :, :]) ** 2).sum(-1), axis=1) if points_grid is not None \
        else np.arange(len(pts))
    steps2 = [s for s in two_balanced["steps"] if s["phase"] == 2] if two_balanced else []
    S2 = np.mean([s["linear"] for s in steps2]) if steps2 else None
    X = np.mean([s["migration"] for s in steps2]) if steps2 else 0.0
    out = {"t_dem_seconds": t_dem, "t_tangent_seconds": t_tan, "S2": S2, "X": X, "ranks": list(ranks),
           "strips": [], "balanced": []}
    scale = len(grid) / len(pts)
    for P in ranks:
        t_strip = t_bal = 0.0
        for s in steps1:
            # a point's step cost: its DEM steps + the tangents of its Newton iterations (one per
            # iteration at most: the average share of the measured tangents)
            cost = (np.array(s["dem_steps"]) * t_dem + t_tan * one["point_tangents"] / (len(pts) * len(one["steps"])))
            cost = cost[nearest]
            S = s["linear"] if P == 1 else (np.mean([t["linear"] for t in steps2]) if steps2 else s["linear"])
            # assembly grows with the points and splits over the ranks; a sparse direct solve
            # of a 2D problem grows as n^1.5 (nested dissection) and is taken not to split
            common = s["assembly"] * scale / P + S * scale ** 1.5 + (X if P > 1 else 0.0)
            t_strip += max_work(cost, strips(grid, P), P) + common
            t_bal += (balanced_max_work(cost, P) if P > 1 else cost.sum()) + common
        out["strips"].append(t_strip / len(steps1))
        out["balanced"].append(t_bal / len(steps1))
    for key in ("strips", "balanced"):
        t = np.array(out[key])
        out[key + "_efficiency"] = (t[0] / (np.array(ranks) * t)).tolist()
    return out


# --- the launcher --------------------------------------------------------------------------------
def launch(a, label, ranks, mesh, balance=False, passes=False):
    path = os.path.join(a.out, f"{label}.json")
    if not os.path.isfile(path):
        cmd = ["mpirun", "-n", str(ranks), sys.executable, os.path.abspath(__file__), "--case", "--case-mesh", mesh,
               "--json", path, "--particles", str(a.particles), "--steps", str(a.steps),
               "--axial-strain", str(a.axial_strain), "--weak-size", str(a.weak_size),
               "--weak-friction", str(a.weak_friction)] + (["--balance"] if balance else []) \
            + (["--balance-passes"] if passes else [])
        env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
                   OMPI_MCA_rmaps_base_oversubscribe="1", OMP_NUM_THREADS="1")
        print(f"{label}: {' '.join(cmd)}", flush=True)
        subprocess.run(cmd, check=True, env=env, cwd=ROOT)
    with open(path) as f:
        return json.load(f)


def phase2(record, key):
    return float(sum(s[key] for s in record["steps"] if s["phase"] == 2))


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", default="results/benchmarks/femdem_scaling")
    p.add_argument("--mesh", default="4x8", help="strong-scaling mesh (default %(default)s)")
    p.add_argument("--weak-mesh", default="2x4", help="weak scaling: this on 1 rank, twice as tall on 2")
    p.add_argument("--particles", type=int, default=228)
    p.add_argument("--steps", type=int, default=8)
    p.add_argument("--axial-strain", type=float, default=0.02)
    p.add_argument("--weak-size", type=float, default=5e-3, help="side of the weak corner [m] (default %(default)g)")
    p.add_argument("--weak-friction", type=float, default=0.5, help="its friction / the friction (default %(default)g)")
    p.add_argument("--model-points", type=int, default=10000, help="points of the model's large mesh")
    p.add_argument("--case", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--case-mesh", help=argparse.SUPPRESS)
    p.add_argument("--json", help=argparse.SUPPRESS)
    p.add_argument("--balance", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--balance-passes", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--probe", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--probe-seconds", type=float, default=8.0, help=argparse.SUPPRESS)
    p.add_argument("--contention-only", action="store_true",
                   help="only the DEM step with one core busy against both (about 1 minute)")
    a = p.parse_args()
    if a.case:
        return run_case(a)
    if a.probe:
        return probe(a.particles, a.probe_seconds)
    os.makedirs(a.out, exist_ok=True)
    start = time.perf_counter()
    shared = contention(a.particles)
    print(f"a DEM step of {a.particles}-disc cell solves: {shared['alone_cpu_us_per_step']:.2f} us of CPU "
          f"alone, {shared['together_cpu_us_per_step']:.2f} us with both cores busy (median of "
          f"{shared['rounds']} alternated rounds): the machine's ceiling on E per DEM step "
          f"{shared['ceiling']:.3f}", flush=True)
    if a.contention_only:
        with open(os.path.join(a.out, "contention.json"), "w") as f:
            json.dump({"contention": shared, "load_after": list(os.getloadavg())}, f, indent=1)
        return
    cells = {n: cell_cost(n) for n in (228, 400)}
    for n, c in cells.items():
        print(f"cell of {n} discs: {c['ms_per_solve']:.1f} ms per solve ({c['mean_steps_per_solve']:.0f} DEM steps), "
              f"{c['ms_per_100_steps']:.2f} ms per 100 DEM steps, pstlo {c['ms_pstlo']:.1f} ms, "
              f"kruyt {c['ms_kruyt']:.1f} ms, {c['memory_bytes'] / 1e3:.0f} kB", flush=True)
    nx, ny = (int(v) for v in a.weak_mesh.split("x"))
    runs = {"strong_1": launch(a, "strong_1", 1, a.mesh), "strong_2": launch(a, "strong_2", 2, a.mesh),
            "strong_2_balanced": launch(a, "strong_2_balanced", 2, a.mesh, balance=True),
            "strong_2_passes": launch(a, "strong_2_passes", 2, a.mesh, balance=True, passes=True),
            "weak_1": launch(a, "weak_1", 1, a.weak_mesh), "weak_2": launch(a, "weak_2", 2, f"{nx}x{2 * ny}")}
    T = {k: phase2(r, "wall") for k, r in runs.items()}
    result = {"contention": shared, "cells": cells,
              "runs": {k: {kk: v for kk, v in r.items() if kk != "steps"} for k, r in runs.items()},
              "wall_phase2": T,
              "cpu_phase2": {k: phase2(r, "cpu") for k, r in runs.items()},
              # the runs may take different Newton paths (cut-backs): per unit of cell work too
              "dem_steps": {k: r["dem_steps_total"] for k, r in runs.items()},
              "strong_efficiency_per_dem_step": {k: (T["strong_1"] / runs["strong_1"]["dem_steps_total"])
                                                 / (2 * T[k] / runs[k]["dem_steps_total"])
                                                 for k in ("strong_2", "strong_2_balanced", "strong_2_passes")},
              "strong_efficiency": T["strong_1"] / (2 * T["strong_2"]),
              "strong_efficiency_balanced": T["strong_1"] / (2 * T["strong_2_balanced"]),
              "strong_efficiency_passes": T["strong_1"] / (2 * T["strong_2_passes"]),
              "weak_efficiency": T["weak_1"] / T["weak_2"],
              "imbalance_2": [max(s["cell_work"]) / np.mean(s["cell_work"]) for s in runs["strong_2"]["steps"]
                              if s["phase"] == 2],
              "imbalance_2_balanced": [max(s["cell_work"]) / np.mean(s["cell_work"])
                                       for s in runs["strong_2_balanced"]["steps"] if s["phase"] == 2],
              "imbalance_2_passes": [max(s["cell_work"]) / np.mean(s["cell_work"])
                                     for s in runs["strong_2_passes"]["steps"] if s["phase"] == 2]}
    # what is left of the per-DEM-step loss once the machine's own share is taken out: the
    # imbalance, the exchanges and the waits, i.e. the part the code can still win back
    result["strong_efficiency_per_dem_step_over_ceiling"] = {
        k: e / shared["ceiling"] for k, e in result["strong_efficiency_per_dem_step"].items()}
    one = runs["strong_1"]
    checked = model(one, runs["strong_2_balanced"], ranks=(1, 2))
    n2 = len([s for s in runs["strong_2"]["steps"] if s["phase"] == 2])
    result["model_check"] = {"predicted_2_strips": checked["strips"][1], "predicted_2_balanced": checked["balanced"][1],
                             "measured_2": T["strong_2"] / n2, "measured_2_balanced": T["strong_2_balanced"] / n2,
                             "measured_1": T["strong_1"] / n2, "predicted_1": checked["strips"][0]}
    side = int(np.sqrt(a.model_points / 2))
    W, H = 0.01, 0.02 * int(a.mesh.split("x")[1]) / 4          # the specimen of run_case
    gx, gy = np.meshgrid((np.arange(side) + 0.5) / side * W, (np.arange(2 * side) + 0.5) / (2 * side) * H)
    grid = np.column_stack([gx.ravel(), gy.ravel()])
    result["model"] = model(one, runs["strong_2_balanced"], points_grid=grid)
    result["model"]["points"] = len(grid)
    result["wall_seconds"] = time.perf_counter() - start
    with open(os.path.join(a.out, "femdem_scaling.json"), "w") as f:
        json.dump(result, f, indent=1)
    print(json.dumps({k: result[k] for k in ("strong_efficiency", "strong_efficiency_balanced",
                                               "strong_efficiency_passes", "strong_efficiency_per_dem_step",
                                               "strong_efficiency_per_dem_step_over_ceiling", "weak_efficiency",
                                               "model_check")}, indent=1))
    m = result["model"]
    for P, ts, tb, es, eb in zip(m["ranks"], m["strips"], m["balanced"], m["strips_efficiency"], m["balanced_efficiency"]):
        print(f"model, {m['points']} points: P = {P:3d}: {ts:9.2f} s/step (strips, E = {es:.2f}), "
              f"{tb:9.2f} s/step (balanced, E = {eb:.2f})")
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(1, 2, figsize=(11, 4))
    ax[0].plot(m["ranks"], m["strips_efficiency"], "o-", label="partition (strips)")
    ax[0].plot(m["ranks"], m["balanced_efficiency"], "s-", label="balanced")
    ax[0].plot([2], [result["strong_efficiency"]], "k^", label="measured, 2 ranks")
    ax[0].plot([2], [result["strong_efficiency_balanced"]], "kv", label="measured, 2 ranks balanced")
    ax[0].plot([2], [result["strong_efficiency_passes"]], "k>", label="measured, 2 ranks balanced between passes")
    ax[0].set_xscale("log", base=2); ax[0].set_xlabel("ranks"); ax[0].set_ylabel("parallel efficiency")
    ax[0].set_title(f"cost model, {m['points']} points of {a.particles} discs"); ax[0].legend(); ax[0].grid(alpha=0.3)
    ax[1].plot(result["imbalance_2"], "o-", label="2 ranks")
    ax[1].plot(result["imbalance_2_balanced"], "s-", label="2 ranks, balanced")
    ax[1].plot(result["imbalance_2_passes"], "^-", label="2 ranks, balanced between passes")
    ax[1].set_xlabel("compression step"); ax[1].set_ylabel("cell work: slowest rank / mean"); ax[1].legend()
    ax[1].grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(os.path.join(a.out, "femdem_scaling.png"), dpi=110)


if __name__ == "__main__":
    main()
