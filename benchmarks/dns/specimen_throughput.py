#!/usr/bin/python3
"""Throughput of the bounded specimen engine (demcell.specimen) from 10^3 to 10^6 discs.

For each size a hexagonal lattice of about N discs (004 Table 7.1: r = 1 m, m = pi kg,
E_n = 1e4 N/m, E_t = 100 N/m, D_n = 100 N s/m, mu = 0.8) is compressed to the isotropic strain
of p = 50 N/m between four walls, given small random velocities (so contacts open, close and
slide as in a run) and stepped at dt = 2e-3 s: first a warm-up (compilation, first neighbour
build), then timed steps. With --shuffle the discs are numbered at random first, so that the
engine's spatial (Morton) renumbering has work to do.

Reported per size and thread count: contact updates per CPU second and per wall second (a
contact update = one listed pair evaluated in one step; touching contacts per step beside
it), steps per second, nanoseconds per pair, the neighbour rebuilds, the memory of the
engine's arrays per disc, and os.getloadavg() before and after (2 cores shared: the CPU-second
figures are the fairer ones when others are running). The flatness figure is
max / min - 1 of the per-CPU-second rate over the sizes, per thread count.

    /usr/bin/python3 benchmarks/dns/specimen_throughput.py --out results/specimen_throughput.json
    /usr/bin/python3 benchmarks/dns/specimen_throughput.py --large --out ...   (adds 10^6 discs)
"""
import argparse
import json
import math
import os
import time

import numba
import numpy as np

from demcell import ContactLaw
from demcell.specimen import Specimen, SpecimenOptions, SpecimenState


def lattice_specimen(n_target, seed=0, shuffle=False, threads=1):
    """A square-ish compressed hexagonal lattice of about n_target discs between 4 walls."""
    r, p = 1.0, 50.0
    nx = max(4, int(round(math.sqrt(n_target * math.sqrt(3.0) / 2.0))))
    ny = max(4, int(round(n_target / nx)))
    j, k = np.meshgrid(np.arange(ny), np.arange(nx), indexing="ij")
    strain = 2.0 * p * r / math.sqrt(3.0) / 1e4 / (2.0 * r)
    x = (r + 2.0 * r * k + r * (j % 2)).ravel() * (1.0 - strain)
    y = (r + math.sqrt(3.0) * r * j).ravel() * (1.0 - strain)
    pos = np.column_stack([x, y])
    rng = np.random.default_rng(seed)
    if shuffle:
        pos = pos[rng.permutation(len(pos))]
    n = len(pos)
    rad = np.full(n, r)
    m = np.pi * rad ** 2
    box = (0.0, (2 * nx + 1) * r * (1.0 - strain), 0.0, (2.0 * r + (ny - 1) * math.sqrt(3.0) * r) * (1.0 - strain))
    state = SpecimenState.from_discs(pos, rad, m, 0.5 * m * rad ** 2, box=box, lateral="walls")
    state.velocity[:] = rng.normal(0.0, 0.05, (n, 2))
    law = ContactLaw(kn=1e4, ks=100.0, friction=0.8)
    options = SpecimenOptions(dt=2e-3, normal_dashpot=100.0, tangential_dashpot=0.0, threads=threads,
                              boundary_interval=50)
    return Specimen(state, law, options)


def memory_per_disc(spec):
    st = spec.state
    total = sum(v.nbytes for v in st.to_dict().values() if isinstance(v, np.ndarray))
    for name in ("work", "geo", "row", "jstart", "jcol", "build_position", "external_moment", "cand_disc", "cand_wall",
                 "cand_fs", "block_max", "order"):
        total += getattr(spec, name).nbytes
    return total / st.n_discs


def measure(n_target, threads, updates, shuffle):
    spec = lattice_specimen(n_target, shuffle=shuffle, threads=threads)
    spec.run(n_steps=100)                       # compile, first rebuilds
    pairs = spec.state.n_pairs
    steps = max(100, int(updates / max(pairs, 1)))
    steps = 50 * max(1, steps // 50)
    spec.cpu_seconds = spec.wall_seconds = 0.0
    spec.pair_updates = 0
    rebuilds = spec.rebuilds
    c0, w0 = time.process_time(), time.perf_counter()
    spec.run(n_steps=steps)
    cpu, wall = time.process_time() - c0, time.perf_counter() - w0
    loop_cpu, loop_wall = spec.throughput()
    contacts = int(np.count_nonzero(spec.state.touching))
    return {
        "discs": spec.state.n_discs, "threads": threads, "steps": steps, "pairs_listed": pairs,
        "contacts_touching": contacts, "cpu_s": cpu, "wall_s": wall,
        "updates_per_cpu_s": spec.pair_updates / cpu, "updates_per_wall_s": spec.pair_updates / wall,
        "loop_updates_per_cpu_s": loop_cpu, "loop_updates_per_wall_s": loop_wall,
        "ns_per_pair_wall": 1e9 * wall / spec.pair_updates, "steps_per_wall_s": steps / wall,
        "rebuilds": spec.rebuilds - rebuilds, "memory_bytes_per_disc": memory_per_disc(spec),
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default="specimen_throughput.json", help="JSON file written")
    ap.add_argument("--sizes", default="1000,10000,100000", help="comma-separated disc counts")
    ap.add_argument("--large", action="store_true", help="add 10^6 discs")
    ap.add_argument("--threads", default="1,2", help="comma-separated Numba thread counts")
    ap.add_argument("--updates", type=float, default=3e7, help="contact updates timed per case")
    ap.add_argument("--shuffle", action="store_true", help="number the discs at random first")
    args = ap.parse_args()
    sizes = [int(float(s)) for s in args.sizes.split(",")] + ([1000000] if args.large else [])
    threads = [min(int(t), numba.config.NUMBA_NUM_THREADS) for t in args.threads.split(",")]
    load_before = os.getloadavg()
    rows = []
    for n in sizes:
        for t in threads:
            row = measure(n, t, args.updates, args.shuffle)
            rows.append(row)
            print(f"{row['discs']:>8d} discs {t} thr: {row['updates_per_cpu_s']:.3g} upd/CPU s, "
                  f"{row['updates_per_wall_s']:.3g} upd/wall s, {row['ns_per_pair_wall']:.1f} ns/pair, "
                  f"{row['pairs_listed']} pairs ({row['contacts_touching']} touching), "
                  f"{row['memory_bytes_per_disc']:.0f} B/disc, {row['rebuilds']} rebuilds", flush=True)
    flat = {}
    for t in threads:
        rates = [r["updates_per_cpu_s"] for r in rows if r["threads"] == t]
        flat[str(t)] = max(rates) / min(rates) - 1.0
    result = {"rows": rows, "flatness_cpu": flat, "loadavg_before": load_before, "loadavg_after": os.getloadavg(),
              "numba_threading_layer": numba.threading_layer(), "shuffle": args.shuffle,
              "target_updates_per_cpu_s": 5e7}
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    with open(args.out, "w") as f:
        json.dump(result, f, indent=1)
    print("flatness (max/min - 1 of updates per CPU s):", {k: round(v, 3) for k, v in flat.items()},
          "loadavg", load_before, "->", result["loadavg_after"])


if __name__ == "__main__":
    main()
