"""Robustness sweep: every numeric option of every demo with extreme and random values.

Each case runs a demo's cheapest baseline (tests/robustness.py BASELINES) with one option
set to a drawn value and judges the end: refused in one line before any work, completed
with finite outputs, stopped with a reason, or interrupted by SIGTERM after --timeout
seconds with its outputs readable (tests/robustness.py says what each requires). Writes
sweep.jsonl (one line a case) and summary.json (counts per demo and outcome, the failures).

    python3 benchmarks/robustness/robustness_sweep.py --out results/robustness_sweep               # specials
    python3 benchmarks/robustness/robustness_sweep.py --random 5 --seed 1 --demos biaxial dem_cell
"""
import argparse
import json
import math
import os
import random
import sys
import time

from tests import robustness


def draws(spec, n_random, rng, specials):
    """The special values, then n_random values drawn inside and around the range."""
    values = list(specials)
    low = spec["low"] if spec["low"] is not None else -1e6
    high = spec["high"] if spec["high"] is not None else max(1e6, 10 * abs(spec["default"] or 1))
    for _ in range(n_random):
        if spec["integer"]:
            values.append(float(rng.randint(int(low) - 2, int(min(high, 10 ** 6)) + 2)))
        elif rng.random() < 0.5 and low > 0:
            values.append(math.exp(rng.uniform(math.log(low * 0.5 if low else 1e-12), math.log(high * 2))))
        else:
            values.append(rng.uniform(low - 0.1 * (high - low), high + 0.1 * (high - low)))
    return values


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--demos", nargs="+", default=list(robustness.BASELINES), choices=list(robustness.BASELINES))
    p.add_argument("--random", type=int, default=0, help="random draws per option besides the specials")
    p.add_argument("--specials", nargs="+", type=float, default=None,
                   help="the special values to try (default: tests/robustness.py SPECIAL_VALUES)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--timeout", type=float, default=60.0, help="[s] before a running case gets SIGTERM")
    p.add_argument("--out", default="results/robustness_sweep")
    args = p.parse_args()
    os.makedirs(args.out, exist_ok=True)
    rng = random.Random(args.seed)
    counts, failures = {}, []
    started = time.perf_counter()
    with open(os.path.join(args.out, "sweep.jsonl"), "w") as log:
        for demo in args.demos:
            for option, spec in robustness.describe_options(demo).items():
                for value in draws(spec, args.random, rng, args.specials or robustness.SPECIAL_VALUES):
                    case_dir = os.path.join(args.out, "case")
                    t0 = time.perf_counter()
                    try:
                        outcome, detail = robustness.run_case(demo, {option: value}, case_dir, timeout=args.timeout)
                    except AssertionError as error:
                        outcome, detail = "FAILED", str(error)[:2000]
                        failures.append(dict(demo=demo, option=option, value=repr(value), detail=detail))
                    row = dict(demo=demo, option=option, value=repr(value),
                               in_range=robustness.in_range(spec, value), outcome=outcome,
                               detail=detail[:300], seconds=round(time.perf_counter() - t0, 2))
                    log.write(json.dumps(row) + "\n")
                    log.flush()
                    counts.setdefault(demo, {}).setdefault(outcome, 0)
                    counts[demo][outcome] += 1
                    print(f"{demo:15s} {option:24s} {row['value']:>12s} {outcome:11s} {row['seconds']:6.1f} s "
                          f"{detail[:90]}", flush=True)
    total = sum(sum(c.values()) for c in counts.values())
    summary = dict(cases=total, counts=counts, failures=failures, seconds=time.perf_counter() - started,
                   load_average=os.getloadavg(), command=" ".join(sys.argv))
    with open(os.path.join(args.out, "summary.json"), "w") as f:
        json.dump(summary, f, indent=2)
    print(f"{total} cases, {len(failures)} failed; counts {json.dumps(counts)}")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
