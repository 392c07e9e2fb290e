"""Interrupt real runs at random moments and count how they end (docs/reference/robustness.md).

Each trial starts `demos/biaxial.py` (serial or under mpirun), sends SIGINT (to mpirun: what
Ctrl-C in a terminal does) or SIGTERM after a random delay, then reads back what a user
would: summary.json (completed, reason, steps_completed), history.csv and the HDF5 file
(h5py). A trial is clean when the reason says which signal ended it and history.csv, the
HDF5 time steps and steps_completed agree. Prints one line a trial and the tally.

    python3 benchmarks/robustness/interrupt_runs.py --trials 12 --ranks 2 --signal INT
"""
import argparse
import csv
import json
import os
import random
import signal
import subprocess
import sys
import time

import h5py

from benchmarks import ROOT

CASE = ["--cell-size", "0.00625", "--steps", "200", "--consolidation-steps", "2", "--axial-strain", "0.02",
        "--write-every", "1"]


def trial(out, ranks, sig, delay):
    cmd = [sys.executable, os.path.join(ROOT, "demos", "biaxial.py"), *CASE, "--out", out]
    if ranks > 1:
        cmd = ["mpirun", "-n", str(ranks)] + cmd
    env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
               OMPI_MCA_rmaps_base_oversubscribe="1", OMP_NUM_THREADS="1")
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env, cwd=ROOT)
    time.sleep(delay)
    if proc.poll() is not None:
        return dict(outcome="finished before the signal")
    proc.send_signal(sig)
    _, stderr = proc.communicate(timeout=120)
    summary = json.load(open(os.path.join(out, "summary.json")))
    with open(os.path.join(out, "history.csv")) as f:
        rows = len(list(csv.reader(f))) - 1
    try:
        with h5py.File(os.path.join(out, "fields.h5"), "r") as f:
            h5_steps = sorted({len(g) for g in f["Function"].values()}) if "Function" in f else [0]
    except OSError as error:
        h5_steps = [f"unreadable: {error}"]
    if summary["completed"]:
        # the signal came after the final summary (plot and prints left): the results are whole
        return dict(outcome="finished before the signal", code=proc.returncode, steps_completed=rows)
    clean = (summary["reason"].startswith("interrupted by") and summary["steps_completed"] == rows
             and h5_steps in ([rows], [0]) and "Traceback" not in stderr)
    return dict(outcome="clean" if clean else "NOT CLEAN", code=proc.returncode, reason=summary["reason"],
                steps_completed=summary.get("steps_completed"), history_rows=rows, h5_steps=h5_steps)


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--trials", type=int, default=12)
    p.add_argument("--ranks", type=int, default=2)
    p.add_argument("--signal", choices=("INT", "TERM"), default="INT")
    p.add_argument("--max-delay", type=float, default=10.0, help="[s] delays drawn in [1, this]")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default="results/interrupt_runs")
    args = p.parse_args()
    rng = random.Random(args.seed)
    tally = {}
    for k in range(args.trials):
        delay = rng.uniform(1.0, args.max_delay)
        result = trial(os.path.join(args.out, f"trial_{k}"), args.ranks, getattr(signal, "SIG" + args.signal), delay)
        tally[result["outcome"]] = tally.get(result["outcome"], 0) + 1
        print(f"trial {k:2d}  SIG{args.signal} after {delay:5.2f} s  {json.dumps(result)}", flush=True)
    print(f"{args.trials} trials, {args.ranks} rank(s), SIG{args.signal}: {tally}; load average {os.getloadavg()}")
    return 0 if set(tally) <= {"clean", "finished before the signal"} else 1


if __name__ == "__main__":
    sys.exit(main())
