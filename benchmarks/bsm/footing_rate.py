"""Is the strip footing quasi-static? (003-bsm.md T7; 003 section 3 calls its 1 m/s slow.)
The plate load against settlement of runs of the same footing at successively lower plate
speeds, compared pair by pair: the largest change of the load over the settlement range,
relative to the faster run's peak load, and the change of the peak. The footing is
quasi-static where halving the speed changes the curve by less than 1 %.

    PYTHONPATH=. python3 benchmarks/bsm/footing_rate.py RUN_DIR [RUN_DIR ...] [--from 0.5] [--to 60]

RUN_DIR: benchmarks/dns/footing_dem.py or demos/footing_bsm.py folders (history.csv,
summary.json), sorted here by speed, fastest first. Prints one table row per pair and the
cost of each run (loading CPU and wall seconds, load average); --png FILE: the curves.
"""
import argparse
import json
import os

import numpy as np

from benchmarks.bsm.footing_bands import load_history


def run_info(run):
    """(speed [m/s], CPU s, wall s, load average) of a run folder's summary.json."""
    with open(os.path.join(run, "summary.json")) as f:
        s = json.load(f)
    if "loading_cpu_s" in s:            # footing_dem.py
        return (float(s["options"]["speed"]), s["loading_cpu_s"], s["loading_wall_s"],
                max(s["loadavg_before"][0], s["loadavg_after"][0]))
    # a run that stopped early (footing_bsm: a grain left the region) has no timing
    nan = float("nan")
    return float(s["speed"]), s.get("cpu_s", nan), s.get("wall_s", nan), s.get("load_average", [nan])[0]


def change(fast, slow, grid):
    """Largest |F_slow - F_fast| over the grid [mm] / the fast run's peak, the settlement where
    it is, the relative change of the peak load and of the mean load over the grid (the work
    of the plate: robust to the single-contact spikes of the curves)."""
    f1 = np.interp(grid, *fast)
    f2 = np.interp(grid, *slow)
    k = int(np.argmax(np.abs(f2 - f1)))
    peak1, peak2 = float(np.max(fast[1])), float(np.max(slow[1]))
    return (float(abs(f2[k] - f1[k]) / peak1), float(grid[k]), (peak2 - peak1) / peak1,
            float(np.mean(f2) / np.mean(f1) - 1.0))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("runs", nargs="+")
    ap.add_argument("--from", dest="s0", type=float, default=0.5, help="first settlement compared [mm]")
    ap.add_argument("--to", dest="s1", type=float, default=60.0, help="last settlement compared [mm]")
    ap.add_argument("--png", help="a figure of the load curves, speed by speed")
    args = ap.parse_args()
    runs = sorted(((run_info(r), r) for r in args.runs), key=lambda x: -x[0][0])
    grid = np.arange(args.s0, args.s1 + 1e-9, 0.1)
    for (info, run) in runs:
        s, f = load_history(run)
        k = int(np.argmax(f))
        print(f"{run}: {info[0]:g} m/s, peak {f[k]:.0f} kN/m at {s[k]:.1f} mm, load at {s[-1]:.1f} mm {f[-1]:.0f}; "
              f"CPU {info[1]:.1f} s, wall {info[2]:.1f} s, load average {info[3]:.1f}")
    print("| speeds [m/s] | max |dF| / F_peak | at [mm] | peak change | mean load change |")
    for (i1, r1), (i2, r2) in zip(runs[:-1], runs[1:]):
        c, at, dp, dm = change(load_history(r1), load_history(r2), grid)
        print(f"| {i1[0]:g} -> {i2[0]:g} | {100 * c:.1f} % | {at:.1f} | {100 * dp:+.1f} % | {100 * dm:+.1f} % |")
    if args.png:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        fig, ax = plt.subplots(figsize=(6, 4))
        for info, run in runs:
            ax.plot(*load_history(run), lw=0.8, label=f"{info[0]:g} m/s")
        ax.set_xlabel("settlement [mm]")
        ax.set_ylabel("plate load [kN/m]")
        ax.set_yscale("symlog", linthresh=10.0)
        ax.legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(args.png, dpi=120)


if __name__ == "__main__":
    main()
