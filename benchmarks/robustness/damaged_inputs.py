#!/usr/bin/python3
"""Damaged input files: how every reader of the project takes them (tests/damage.py).

For each kind of file (Ehlers parameter file, identification config and bounds, test-data
CSV, demcell packing, the checkpoint directories of a biaxial and of a FEM x DEM run),
--per-kind damaged copies of a good file (structure-aware mutations: truncation, random
bytes, an empty or foreign file, a deleted or retyped key, a list for an object, NaN and inf
injected, a future format version, a repeated or missing column, a pickled object array)
are read as the demos read them before they start.  Counted per kind: refused (one line
naming the file), accepted (read whole, usable), traceback, hang, executed (a pickle ran).
Then --restarts damaged checkpoints go through a real `--restart` under mpirun (1 and 2
ranks alternately): each must exit 2 with one line and leave the earlier outputs as they
were (or complete, if the damage left the checkpoint valid).

    python3 benchmarks/robustness/damaged_inputs.py [--per-kind 80] [--restarts 20] [--seed 0]

Prints the table and the cases that were neither refused nor accepted; writes
out/damaged_inputs/summary.json.  Aim: 0 tracebacks, 0 hangs, 0 executed.
"""
import argparse
import collections
import json
import os
import subprocess
import sys
import time

import numpy as np

from benchmarks import ROOT
from cosserat_fenicsx.validation import Parser, Range, number
from tests import damage


def restart(path, ranks, demo):
    """A real restart from the damaged checkpoint at `path`: its outcome."""
    before = {n: open(os.path.join(path, n), "rb").read() for n in ("summary.json", "history.csv")
              if os.path.exists(os.path.join(path, n))}
    cmd = ["mpirun", "-n", str(ranks), sys.executable, os.path.join(ROOT, "demos", demo + ".py"), "--restart", path]
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, env=damage.ENV, cwd=ROOT, timeout=600)
    except subprocess.TimeoutExpired:
        return "hang", "still running after 600 s"
    ours = [line for line in proc.stderr.splitlines() if f"{demo}.py: error:" in line]
    unchanged = before == {n: open(os.path.join(path, n), "rb").read() for n in before}
    if "Traceback" in proc.stderr:
        return "traceback", proc.stderr[-400:]
    if proc.returncode == 2 and len(ours) == 1 and unchanged:
        return "refused", ours[0][:300]
    if proc.returncode == 0:
        return "completed", ""
    return "traceback", f"exit {proc.returncode}, {len(ours)} error lines, outputs unchanged: {unchanged}: " \
                        f"{proc.stderr[-300:]}"


def main():
    p = Parser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter, allow_abbrev=False)
    p.add_argument("--per-kind", type=number(Range(1, 100000, integer=True)), default=80)
    p.add_argument("--restarts", type=number(Range(0, 10000, integer=True)), default=20)
    p.add_argument("--seed", type=number(Range(0, 2 ** 32 - 1, integer=True)), default=0)
    p.add_argument("--out", default="out/damaged_inputs")
    args = p.parse_args()
    os.makedirs(args.out, exist_ok=True)
    load = os.getloadavg()
    t0, c0 = time.perf_counter(), time.process_time()
    good = damage.valid_files(os.path.join(args.out, "good"))
    rng = np.random.default_rng(int(args.seed))
    counts = collections.defaultdict(collections.Counter)
    bad = []
    for kind in damage.KINDS:
        for _ in range(int(args.per_kind)):
            path, what = damage.damaged_copy(kind, good[kind], os.path.join(args.out, "work", kind), rng,
                                             foreign_of=good)
            verdict = damage.judge(kind, path)
            counts[kind][verdict["outcome"]] += 1
            if verdict["outcome"] not in ("refused", "accepted"):
                bad.append(dict(kind=kind, damage=what, **verdict))
    restarts = collections.Counter()
    demo = damage.CHECKPOINT_RUNS["checkpoint"][0]
    for k in range(int(args.restarts)):
        path, what = damage.damaged_copy("checkpoint", good["checkpoint"], os.path.join(args.out, "work", "restart"),
                                         rng)
        outcome, message = restart(path, 1 + k % 2, demo)
        restarts[outcome] += 1
        if outcome not in ("refused", "completed"):
            bad.append(dict(kind="restart", damage=what, outcome=outcome, message=message))
    total = collections.Counter()
    print(f"{'kind':16s} " + " ".join(f"{o:>9s}" for o in damage.OUTCOMES))
    for kind in damage.KINDS:
        total.update(counts[kind])
        print(f"{kind:16s} " + " ".join(f"{counts[kind][o]:9d}" for o in damage.OUTCOMES))
    print(f"{'all files':16s} " + " ".join(f"{total[o]:9d}" for o in damage.OUTCOMES))
    print(f"restarts under mpirun ({args.restarts}, 1 and 2 ranks): " +
          ", ".join(f"{o} {n}" for o, n in sorted(restarts.items())))
    for case in bad:
        print(f"  {case['kind']}: {case['damage']} -> {case['outcome']}: {case['message']}")
    summary = dict(per_kind={k: dict(v) for k, v in counts.items()}, total=dict(total), restarts=dict(restarts),
                   files=sum(total.values()), not_refused_nor_accepted=bad, settings=vars(args),
                   wall_time_s=time.perf_counter() - t0, cpu_time_s_main_process=time.process_time() - c0,
                   load_average_start=load, load_average_end=os.getloadavg())
    with open(os.path.join(args.out, "summary.json"), "w") as f:
        json.dump(summary, f, indent=1, allow_nan=False)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
