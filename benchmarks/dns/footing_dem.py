#!/usr/bin/python3
"""Full-DEM strip footing of 003 section 3 (the bridging-scale method's reference solution).

The whole domain (default 18 m x 9 m) filled with 003's packing A, B or C, fixed smooth walls
at the bottom and the sides, a rigid plate 2 m wide at the top centre pushed down at 1 m/s to
60 mm; 003 Table 1 contact law (demcell/specimen/footing.py says what is mapped and what is
missing: Li-Chu's rolling force). Writes, in --out:

* history.csv: time [s], settlement [m], load [N/m] (the plate's vertical reaction per metre);
* summary.json: disc count, time step, steps, the peak load and its settlement, the load at
  the final settlement, wall and CPU seconds of the loading (and of the preparation),
  os.getloadavg() before and after, the options;
* force_settlement.png: load [kN/m] against settlement [mm], 003 Table 2's DEM value
  (1674.19 kN/m at 60 mm, packing not stated) marked;
* with --snapshots S1 S2 ... [mm]: grains_S.npz at the first record at or past each
  settlement S: position, reference_position (n, 2) [m], radius (n,) [m], settlement [m],
  load [N/m], plate_x (2,) [m], plate_y0 [m] (the input of benchmarks/bsm/footing_bands.py).

    /usr/bin/python3 benchmarks/dns/footing_dem.py --packing A --out results/footing_A
    /usr/bin/python3 benchmarks/dns/footing_dem.py --packing A --width 6 --height 3 --out /tmp/f6
    /usr/bin/python3 benchmarks/dns/footing_dem.py --packing A --gravity 9.81 --speed 0.1 --out /tmp/fg

With --gravity g the specimen first settles under its weight (--settle-time, local damping
0.7; footing.settle) and the plate is put on the settled surface.
"""
import argparse
import csv
import json
import os
import time

import numpy as np

from demcell.specimen.footing import footing_packing, run_footing

TABLE_2_DEM = 1674.19e3     # [N/m] at 60 mm, 003 Table 2 (whole-domain DEM)


def snapshot(out, mm, specimen, settlement, load):
    """grains_MM.npz of the engine's state now (module docstring)."""
    st, plate = specimen.state, specimen.plate_position()
    np.savez(os.path.join(out, f"grains_{mm:g}.npz"), position=st.position,
             reference_position=st.reference_position, radius=st.radius, settlement=settlement, load=load,
             plate_x=np.array(plate[:2]), plate_y0=plate[2] + settlement)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--packing", default="A", choices=("A", "B", "C"))
    ap.add_argument("--width", type=float, default=18.0, help="domain width [m]")
    ap.add_argument("--height", type=float, default=9.0, help="domain height [m]")
    ap.add_argument("--plate-width", type=float, default=2.0, help="footing width [m]")
    ap.add_argument("--speed", type=float, default=1.0, help="plate speed [m/s]")
    ap.add_argument("--depth", type=float, default=0.06, help="final settlement [m]")
    ap.add_argument("--mass-damping", type=float, default=10.0, help="c_m [1/s]")
    ap.add_argument("--dt-fraction", type=float, default=0.1, help="dt / sqrt(m_min / k_N)")
    ap.add_argument("--rough", action="store_true", help="plate friction mu_s (default smooth)")
    ap.add_argument("--record-every", type=int, default=10, help="steps between two records")
    ap.add_argument("--n-cell", type=int, default=600, help="discs of the periodic cell of packing C")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=1,
                    help="Numba threads (1: on a loaded shared machine two threads ran 100x slower)")
    ap.add_argument("--snapshots", type=float, nargs="*", default=[],
                    help="settlements [mm] at which the grains are saved (grains_S.npz)")
    ap.add_argument("--gravity", type=float, default=0.0, help="g [m/s^2] downwards (default 0, as 003)")
    ap.add_argument("--settle-time", type=float, default=0.3, help="settling under gravity [s]")
    ap.add_argument("--out", default="footing_dem", help="output folder")
    args = ap.parse_args()
    os.makedirs(args.out, exist_ok=True)
    load_before = os.getloadavg()
    c0, w0 = time.process_time(), time.perf_counter()
    discs = footing_packing(args.packing, (0.0, args.width, 0.0, args.height), seed=args.seed, n_cell=args.n_cell)
    prep_cpu, prep_wall = time.process_time() - c0, time.perf_counter() - w0
    print(f"packing {args.packing}: {discs.n_discs} discs, solid fraction {discs.solid_fraction():.4f} "
          f"({prep_wall:.1f} s wall)", flush=True)
    pending = sorted(args.snapshots)
    csv_path = os.path.join(args.out, "history.csv")
    with open(csv_path, "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(["time_s", "settlement_m", "load_N_per_m"])

        def record(row):
            writer.writerow([f"{row['time']:.9g}", f"{row['settlement']:.9g}", f"{row['load']:.9g}"])
            if row["step"] % (50 * args.record_every) == 0:
                fh.flush()
                print(f"  s = {1e3 * row['settlement']:6.2f} mm  load = {row['load'] / 1e3:9.2f} kN/m", flush=True)
            while pending and 1e3 * row["settlement"] >= pending[0] - 1e-2:
                snapshot(args.out, pending.pop(0), row["specimen"], row["settlement"], row["load"])

        res = run_footing(args.packing, args.width, args.height, args.plate_width, args.speed, args.depth,
                          args.rough, args.mass_damping, args.dt_fraction, args.record_every, args.seed,
                          discs=discs, threads=args.threads, on_record=record, gravity=args.gravity,
                          settle_time=args.settle_time)
    # the last step can end up to half a step short of --depth: the final state stands for it
    for s in [s for s in pending if s <= 1e3 * args.depth + 1e-9]:
        snapshot(args.out, s, res.specimen, float(res.settlement[-1]), float(res.load[-1]))
    peak, at = res.peak()
    info = dict(res.info)
    info["packing"] = args.packing
    summary = {"packing": args.packing, "n_discs": info["n_discs"], "solid_fraction": info["solid_fraction"],
               "dt": info["dt"], "n_steps": info["n_steps"], "peak_load_N_per_m": peak,
               "peak_settlement_m": at, "final_settlement_m": float(res.settlement[-1]),
               "final_load_N_per_m": float(res.load[-1]),
               "final_mean_load_last_mm_N_per_m": float(np.mean(res.load[res.settlement > res.settlement[-1] - 1e-3])),
               "table2_dem_N_per_m": TABLE_2_DEM, "loading_wall_s": res.wall_seconds,
               "loading_cpu_s": res.cpu_seconds, "preparation_wall_s": prep_wall, "preparation_cpu_s": prep_cpu,
               "loadavg_before": load_before, "loadavg_after": os.getloadavg(), "options": vars(args),
               "info": info}
    with open(os.path.join(args.out, "summary.json"), "w") as fh:
        json.dump(summary, fh, indent=1, default=str)
    print(json.dumps({k: v for k, v in summary.items() if k not in ("info", "options")}, indent=1, default=str))
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib missing: no figure")
        return
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.plot(1e3 * res.settlement, res.load / 1e3, lw=1, label=f"DEM, packing {args.packing} ({info['n_discs']} discs)")
    ax.plot([60.0], [TABLE_2_DEM / 1e3], "k*", label="003 Table 2, DEM (packing not stated)")
    ax.axvline(1e3 * at, color="0.7", lw=0.8, ls="--")
    ax.set_xlabel("settlement [mm]")
    ax.set_ylabel("load [kN/m]")
    ax.set_title(f"strip footing {args.width:g} x {args.height:g} m, c_m = {args.mass_damping:g} 1/s, "
                 f"{'rough' if args.rough else 'smooth'} plate", fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(os.path.join(args.out, "force_settlement.png"), dpi=120)


if __name__ == "__main__":
    main()
