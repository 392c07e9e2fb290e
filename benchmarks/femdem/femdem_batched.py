#!/usr/bin/env python3
"""Batched cells against per-cell DemCells, and ranks x threads.

    /usr/bin/python3 benchmarks/femdem/femdem_batched.py --out results/benchmarks/femdem_batched

Two parts, in one run of this script (ratios from one state of the machine; the load
average is recorded before and after each case):

  cells   --cells cells of --particles discs (the FEM x DEM reference cell of CellOptions,
          committed at different biaxial pre-strains, 1-4 %, so that their costs differ as
          in a band), each asked a biaxial increment of --increment from its committed state,
          --rounds times: (a) per cell, as DemMaterial does (rollback, set_deformation,
          solve, homogenize, Kruyt tangent, one Python call each); (b) the same through one
          CellBatch with 1 Numba thread; (c) with 2 threads. Wall and CPU seconds (the CPU of
          all threads), DEM steps, and a check that the three give the same bits.
  fe      demos/femdem_biaxial.py on --mesh (the biaxial with a weak corner, --steps load
          steps of --axial-strain / --steps), as a user runs it: 1 rank per cell; 1 rank
          batched with 1 and 2 threads; 2 ranks per cell; 2 ranks batched (PETSc's redundant
          LU in all five). Wall time, CPU (of all processes), the cell-solve time of the
          slowest rank, DEM steps, and whether every output equals the per-cell run of the
          same rank count.

Writes femdem_batched.json as it goes.
"""
import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from benchmarks import ROOT


def make_cells(n_cells, particles, seed=0):
    import demcell as dc
    from cosserat_fenicsx.materials.dem import CellOptions
    options = CellOptions(particles=particles, seed=seed)
    state, _ = options.packing_state()
    ref = dc.reference_cell(state, options.law(), options.relaxation(), options.pressure)
    cells = []
    for k in range(n_cells):
        cell = ref.copy()
        e = 0.01 + 0.03 * k / max(1, n_cells - 1)
        cell.set_deformation(np.array([[1.0 + 0.5 * e, 0.0], [0.0, 1.0 - e]]))
        cell.solve()
        cell.commit()
        cells.append(cell)
    return cells


def targets(cells, increment, round_):
    out = []
    for k, cell in enumerate(cells):
        F = cell.committed_state.F.copy()
        de = increment * (1.0 + 0.5 * np.sin(k + round_))
        F[1, 1] -= de
        F[0, 0] += 0.5 * de
        out.append(F)
    return np.array(out)


def cells_part(a, log):
    import numba
    from demcell.batch import CellBatch
    from demcell.tangent import kruyt_operator
    t0 = time.perf_counter()
    cells = make_cells(a.cells, a.particles)
    log(f"cells: {a.cells} cells of {a.particles} discs prepared in {time.perf_counter() - t0:.0f} s")
    record = {"cells": a.cells, "particles": a.particles, "increment": a.increment, "rounds": a.rounds, "cases": {}}
    rows = np.arange(len(cells))
    batches = {1: CellBatch(cells), 2: CellBatch(cells)}
    for b in batches.values():            # compile outside the timing
        b.set_targets(rows[:1], targets(cells, a.increment, -1)[:1])
        b.solve(rows[:1])
        b.homogenize(rows[:1])
        b.kruyt(rows[:1])
        b.rollback(rows)
    stresses = {}
    for r in range(a.rounds):
        F = targets(cells, a.increment, r)
        for case in ("per_cell", "batch_1_thread", "batch_2_threads"):
            load = os.getloadavg()[0]
            w, c = time.perf_counter(), time.process_time()
            if case == "per_cell":
                steps, sig = 0, []
                for k, cell in enumerate(cells):
                    cell.rollback()
                    cell.set_deformation(F[k])
                    steps += cell.solve().steps
                    sig.append(cell.homogenized().cauchy)
                    kruyt_operator(cell.state, cell.law_array)
                sig = np.array(sig)
            else:
                threads = 1 if case == "batch_1_thread" else min(2, numba.config.NUMBA_NUM_THREADS)
                numba.set_num_threads(threads)
                b = batches[1 if threads == 1 else 2]
                b.rollback(rows)
                b.set_targets(rows, F)
                res = b.solve(rows)
                sig = b.homogenize(rows)["cauchy"]
                b.kruyt(rows)
                steps = int(res[:, 0].sum())
                numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
            wall, cpu = time.perf_counter() - w, time.process_time() - c
            rec = record["cases"].setdefault(case, {"wall": [], "cpu": [], "steps": [], "load": []})
            rec["wall"].append(wall)
            rec["cpu"].append(cpu)
            rec["steps"].append(steps)
            rec["load"].append(load)
            stresses.setdefault(r, {})[case] = sig
            log(f"cells round {r}: {case:16s} wall {wall:7.2f} s  cpu {cpu:7.2f} s  DEM steps {steps}  load {load:.2f}")
    record["identical"] = all(np.array_equal(s["per_cell"], s[c]) for s in stresses.values()
                              for c in ("batch_1_thread", "batch_2_threads"))
    base = np.median(record["cases"]["per_cell"]["wall"])
    for case, rec in record["cases"].items():
        rec["wall_median"] = float(np.median(rec["wall"]))
        rec["cpu_median"] = float(np.median(rec["cpu"]))
        rec["speedup_wall"] = float(base / rec["wall_median"])
        rec["us_per_dem_step_cpu"] = float(1e6 * np.sum(rec["cpu"]) / np.sum(rec["steps"]))
    log(f"cells: identical bits {record['identical']}; wall speed-up over per cell: " +
        ", ".join(f"{c} {r['speedup_wall']:.2f}x" for c, r in record["cases"].items()))
    return record


def fe_part(a, log):
    record = {"mesh": a.mesh, "particles": a.fe_particles, "steps": a.steps, "cases": {}}
    common = ["--mesh", a.mesh, "--particles", str(a.fe_particles), "--axial-strain", str(a.axial_strain),
              "--steps", str(a.steps), "--weak-size", "0.005", "--weak-friction", "0.5", "--fields", "displacement",
              # PETSc's redundant LU: MUMPS on 2 processes is not bit-reproducible, and the
              # 2-rank runs are compared digit by digit
              "-pc_type", "redundant"]
    env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
               OMPI_MCA_rmaps_base_oversubscribe="1", OMP_NUM_THREADS="1")
    cases = [("1 rank, per cell", 1, ["--no-batched"]), ("1 rank, batched, 1 thread", 1, ["--batched"]),
             ("1 rank, batched, 2 threads", 1, ["--batched", "--cell-threads", "2"]),
             ("2 ranks, per cell", 2, ["--no-batched"]), ("2 ranks, batched", 2, ["--batched"])]
    for name, ranks, extra in cases:
        out = os.path.join(a.out, "fe_" + name.replace(" ", "").replace(",", "_"))
        cmd = [sys.executable, os.path.join(ROOT, "demos", "femdem_biaxial.py"), *common, *extra, "--out", out]
        if ranks > 1:
            cmd = ["mpirun", "-n", str(ranks)] + cmd
        load = os.getloadavg()[0]
        ru0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        w = time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=ROOT)
        wall = time.perf_counter() - w
        ru1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu = (ru1.ru_utime - ru0.ru_utime) + (ru1.ru_stime - ru0.ru_stime)
        if proc.returncode != 0:
            raise SystemExit(f"{' '.join(cmd)} failed:\n{proc.stdout[-2000:]}\n{proc.stderr[-2000:]}")
        with open(os.path.join(out, "summary.json")) as f:
            summary = json.load(f)
        rec = {"ranks": ranks, "options": extra, "wall_process": wall, "cpu_all_processes": cpu,
               "wall_run": summary["wall_time"], "cell_solves_max_rank": summary["time_max_over_ranks"]["cell_solves"],
               "dem_steps": summary["dem_steps_total"], "load_before": load, "load_after": os.getloadavg()[0],
               "out": out}
        record["cases"][name] = rec
        log(f"fe: {name:28s} wall {summary['wall_time']:7.1f} s  cpu {cpu:7.1f} s  cell solves {rec['cell_solves_max_rank']:7.1f} s"
            f"  load {load:.2f}")
    from tests.test_femdem_batched import same_outputs     # the comparison the tests make
    for name, rec in record["cases"].items():
        ref = record["cases"]["1 rank, per cell" if rec["ranks"] == 1 else "2 ranks, per cell"]["out"]
        try:
            same_outputs(Path(ref), Path(rec["out"]))
            rec["identical_to_per_cell"] = True
        except AssertionError as error:
            rec["identical_to_per_cell"] = f"no: {str(error)[:200]}"
    base = record["cases"]["1 rank, per cell"]["wall_run"]
    for name, rec in record["cases"].items():
        rec["speedup_wall"] = base / rec["wall_run"]
        log(f"fe: {name:28s} speed-up {rec['speedup_wall']:.2f}x, identical to per cell: {rec['identical_to_per_cell']}")
    return record


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", default="results/benchmarks/femdem_batched")
    p.add_argument("--cells", type=int, default=64)
    p.add_argument("--particles", type=int, default=400)
    p.add_argument("--increment", type=float, default=1e-3)
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--mesh", default="4x8")
    p.add_argument("--fe-particles", type=int, default=228)
    p.add_argument("--axial-strain", type=float, default=0.006)
    p.add_argument("--steps", type=int, default=3)
    p.add_argument("--parts", default="cells,fe")
    a = p.parse_args()
    os.makedirs(a.out, exist_ok=True)
    path = os.path.join(a.out, "femdem_batched.json")
    result = {"load_start": list(os.getloadavg()), "cpus": os.cpu_count()}

    def log(text):
        print(text, flush=True)

    def save():
        with open(path, "w") as f:
            json.dump(result, f, indent=1)
    if "cells" in a.parts:
        result["cells"] = cells_part(a, log)
        save()
    if "fe" in a.parts:
        result["fe"] = fe_part(a, log)
    result["load_end"] = list(os.getloadavg())
    save()
    log(f"written {path}")


if __name__ == "__main__":
    main()
