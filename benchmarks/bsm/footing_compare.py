"""The strip footing by the bridging-scale method against the full DEM of the same grains
(003-bsm.md T8, and the cost against the grain-count ratio): for each case, demos/footing_bsm.py
is run as a user runs it, then demcell.specimen.footing.run_footing on the whole domain with
the same packing, damping and speed; the plate loads at fixed settlements, the peaks and the
loop times (setup excluded on both sides) are tabulated (docs/results/bsm.md).

    PYTHONPATH=. python3 benchmarks/bsm/footing_compare.py [--cases A:003:10 B:003:10 C:003:10 A:lattice:100] [--repeat 4]

A case is PACKING:CONTINUUM:C_M[:SPEED[:DOMAIN_WIDTH[:REGION_WIDTHxREGION_DEPTH[:BOTTOM]]]] (region 6x3 by
default; BOTTOM fixed, as 003, or smooth, the full DEM's wall: demos/footing_bsm.py --bottom).
--gravity G [m/s^2] settles both under their weight first (demos/footing_bsm.py --gravity,
footing.settle), --depth D [m] the final settlement (default 0.06), --settlements the table's;
--error-range S1 S2 [mm]: the largest |BSM - DEM| over it against the full DEM's peak, and the
change of the mean load (docs/results/bsm.md, error against cost).
"""
import argparse
import csv
import json
import os
import subprocess
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SETTLEMENTS_MM = (5, 10, 15, 20, 30, 40, 50, 60)


def compare(case, out, gravity=0.0, depth=0.06, settlements=SETTLEMENTS_MM, error_range=(2.0, 20.0)):
    fields = case.split(":")
    packing, continuum, c_m = fields[0], fields[1], float(fields[2])
    speed = float(fields[3]) if len(fields) > 3 else 1.0
    width = float(fields[4]) if len(fields) > 4 else 18.0
    region = fields[5].split("x") if len(fields) > 5 else ("6", "3")
    bottom = fields[6] if len(fields) > 6 else "fixed"
    run_dir = os.path.join(out, case.replace(":", "_"))
    env = dict(os.environ, OMP_NUM_THREADS="1", PYTHONPATH=ROOT)
    cmd = [sys.executable, os.path.join(ROOT, "demos", "footing_bsm.py"), "--packing", packing,
           "--continuum", continuum, "--mass-damping", str(c_m), "--speed", str(speed),
           "--domain-width", str(width), "--region-width", region[0], "--region-depth", region[1], "--out", run_dir,
           "--gravity", str(gravity), "--depth", str(depth), "--bottom", bottom]
    subprocess.run(cmd, check=True, env=env, capture_output=True, text=True)
    with open(os.path.join(run_dir, "summary.json")) as f:
        summary = json.load(f)
    with open(os.path.join(run_dir, "history.csv")) as f:
        rows = list(csv.DictReader(f))
    s = np.array([float(r["settlement_mm"]) for r in rows])
    load = np.array([float(r["load_kN_per_m"]) for r in rows])
    from demcell.specimen.footing import run_footing
    w0, c0 = time.perf_counter(), time.process_time()
    full = run_footing(packing, width=width, depth=depth, speed=speed, mass_damping=c_m, record_every=10, threads=1,
                       gravity=gravity)
    total_wall, total_cpu = time.perf_counter() - w0, time.process_time() - c0
    # the loading loop, as the BSM's (setup excluded: packing C's random fill takes seconds)
    full_wall, full_cpu = full.wall_seconds, full.cpu_seconds
    reference = np.interp(s, 1e3 * full.settlement, 1e-3 * full.load)
    result = {"case": case, "bsm": {}, "full_dem": {}, "grains_full": int(full.info["n_discs"]),
              "grains_bsm": summary["grains_real"] + summary["grains_virtual"],
              "grain_ratio": summary["grain_ratio_full_over_bsm"], "bsm_wall_s": summary["wall_s"],
              "full_wall_s": full_wall, "full_cpu_s": full_cpu, "full_total_wall_s": total_wall,
              "full_total_cpu_s": total_cpu, "full_engine_cpu_s": full.specimen.cpu_seconds,
              "bsm_cpu_s": summary["cpu_s"], "speedup": full_wall / summary["wall_s"],
              "split_wall_s": summary["time_split"]["wall_s"], "load_average": os.getloadavg()[0],
              "bsm_peak": [summary["peak_load_kN_per_m"], summary["peak_settlement_mm"]],
              "full_peak": [1e-3 * float(full.load.max()), 1e3 * float(full.settlement[np.argmax(full.load)])]}
    for mm in settlements:
        k = int(np.argmin(np.abs(s - mm)))
        result["bsm"][mm], result["full_dem"][mm] = float(load[k]), float(reference[k])
    grid = np.arange(error_range[0], error_range[1] + 1e-9, 0.1)
    bsm_grid, dem_grid = np.interp(grid, s, load), np.interp(grid, 1e3 * full.settlement, 1e-3 * full.load)
    k = int(np.argmax(np.abs(bsm_grid - dem_grid)))
    result["error"] = {"range_mm": list(error_range), "max_over_dem_peak": float(abs(bsm_grid[k] - dem_grid[k]))
                       / result["full_peak"][0], "at_mm": float(grid[k]),
                       "mean_load_change": float(np.mean(bsm_grid) / np.mean(dem_grid) - 1.0)}
    first = np.argmax(np.abs(load - reference) > 0.01 * np.maximum(np.abs(reference), 100.0))
    result["agree_within_1pc_until_mm"] = float(s[first]) if first > 0 else float(s[-1])
    return result


def summarise(samples):
    """The runs of one case: the first run's loads (every run must give the same, the
    same input on one rank) and the median and range of the times over the runs."""
    first = samples[0]
    for other in samples[1:]:
        if other["bsm"] != first["bsm"] or other["full_dem"] != first["full_dem"]:
            raise SystemExit(f"{first['case']}: the loads differ between runs of the same input")
    out = dict(first)
    for key in ("bsm_wall_s", "bsm_cpu_s", "full_wall_s", "full_cpu_s", "full_engine_cpu_s", "load_average"):
        out[key] = float(np.median([r[key] for r in samples]))
    of_limit = [r["full_cpu_s"] / r["bsm_cpu_s"] / r["grain_ratio"] for r in samples]
    out["speedup"] = out["full_wall_s"] / out["bsm_wall_s"]
    out["cpu_speedup_over_limit"] = {"median": out["full_cpu_s"] / out["bsm_cpu_s"] / out["grain_ratio"],
                                     "min": float(min(of_limit)), "max": float(max(of_limit))}
    out["runs"] = samples
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="+", default=["A:003:10", "B:003:10", "C:003:10", "A:lattice:100",
                                                       "A:lattice:100:0.5", "A:003:10:1.0:54"])
    parser.add_argument("--repeat", type=int, default=1,
                        help="runs of each case (times: the median and the range; runs of a second vary by 5-10 %%)")
    parser.add_argument("--gravity", type=float, default=0.0, help="g [m/s^2] on both models (default 0, as 003)")
    parser.add_argument("--depth", type=float, default=0.06, help="final settlement [m] (default 0.06)")
    parser.add_argument("--settlements", type=float, nargs="+", default=list(SETTLEMENTS_MM),
                        help="settlements of the table [mm]")
    parser.add_argument("--error-range", type=float, nargs=2, default=[2.0, 20.0], metavar=("S1", "S2"),
                        help="settlements [mm] of the error summary (default 2 20)")
    parser.add_argument("--out", default="results/bsm_footing_compare")
    args = parser.parse_args()
    if args.repeat < 1:
        parser.error("--repeat must be >= 1")
    os.makedirs(args.out, exist_ok=True)
    results = []
    for case in args.cases:
        r = summarise([compare(case, args.out, args.gravity, args.depth, args.settlements, tuple(args.error_range))
                       for _ in range(args.repeat)])
        results.append(r)
        loads = " | ".join(f"{r['bsm'][mm]:.0f} / {r['full_dem'][mm]:.0f}" for mm in args.settlements)
        limit = r["cpu_speedup_over_limit"]
        spread = f" ({100 * limit['min']:.0f}-{100 * limit['max']:.0f} %)" if args.repeat > 1 else ""
        print(f"| {case} | {loads} | {r['bsm_peak'][0]:.0f} ({r['bsm_peak'][1]:.0f} mm) | "
              f"{r['full_peak'][0]:.0f} ({r['full_peak'][1]:.0f} mm) | agree to 1 % until {r['agree_within_1pc_until_mm']:.1f} mm | "
              f"wall {r['full_wall_s']:.1f} / {r['bsm_wall_s']:.2f} s = {r['speedup']:.1f}x, CPU {r['full_cpu_s']:.1f} / "
              f"{r['bsm_cpu_s']:.2f} s = {r['full_cpu_s'] / r['bsm_cpu_s']:.1f}x (grain ratio "
              f"{r['grain_ratio']:.1f}: {100 * limit['median']:.0f} %{spread}), error over "
              f"{r['error']['range_mm'][0]:g}-{r['error']['range_mm'][1]:g} mm "
              f"{100 * r['error']['max_over_dem_peak']:.1f} % of the DEM peak (at {r['error']['at_mm']:.1f} mm), "
              f"mean load {100 * r['error']['mean_load_change']:+.1f} %, load {r['load_average']:.1f}"
              + (f", median of {args.repeat} runs" if args.repeat > 1 else ""), flush=True)
        with open(os.path.join(args.out, "footing_compare.json"), "w") as f:
            json.dump(results, f, indent=1)


if __name__ == "__main__":
    main()
