#!/usr/bin/python3
"""Cost of the identification's building blocks, ratios in one run.

The five virtual tests of thesis 6.1 (hydrostatic to 1 MPa, triaxial 100/300/600 kPa,
biaxial 100 kPa; --steps load steps each), 14 parameters (6.2):

* one objective evaluation without sensitivities (five material-point runs);
* with semi-analytical sensitivities (section 5.2);
* with numerical ones (central differences, 5.5: 29 runs per test);
* each serial and with the tests spread over --processes worker processes.

Wall and CPU seconds (CPU of this process plus its workers), best of --repeat, and the
load average, since the machine may be shared.

    python3 benchmarks/identification/identification_cost.py [--steps 150] [--processes 2] [--repeat 5]
"""
import argparse
import json
import os
import resource
import time

import numpy as np

from cosserat_fenicsx.identification.data import thesis_virtual_data
from cosserat_fenicsx.identification.objective import Objective
from cosserat_fenicsx.identification.parameter_set import ParameterSet
from cosserat_fenicsx.materials.ehlers.parameters import EhlersParameters
from cosserat_fenicsx.validation import STEPS, Parser, Range, number

def cpu_all():
    """CPU seconds of this process and its (finished) children; workers of a pool are counted
    when the pool is shut down, so the pool is closed inside each timing."""
    s, c = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return s.ru_utime + s.ru_stime + c.ru_utime + c.ru_stime


def main():
    p = Parser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter, allow_abbrev=False)
    p.add_argument("--steps", type=number(STEPS), default=150)
    p.add_argument("--processes", type=number(Range(2, 64, integer=True)), default=2)
    p.add_argument("--repeat", type=number(Range(1, 100, integer=True)), default=5)
    p.add_argument("--out", default="out/identification_cost")
    args = p.parse_args()
    ref = EhlersParameters(micropolar=False)
    data = thesis_virtual_data(ref, n_steps=args.steps)
    pset = ParameterSet(("plastic",), ref)
    load0 = os.getloadavg()
    rows = {}
    for label, sens, jac in (("objective only", "semi-analytical", False),
                             ("with semi-analytical sensitivities", "semi-analytical", True),
                             ("with numerical sensitivities", "numerical", True)):
        for procs in (1, args.processes):
            best_w, best_c = np.inf, np.inf
            for _ in range(args.repeat):
                obj = Objective(data, pset, sensitivity=sens, processes=procs)
                obj.evaluate(pset.start, jacobian=jac)       # warm: compilation, pool start
                c0, w0 = cpu_all(), time.perf_counter()
                obj.evaluate(pset.start, jacobian=jac)
                w = time.perf_counter() - w0
                obj.close()
                c = cpu_all() - c0
                best_w, best_c = min(best_w, w), min(best_c, c)
            rows[f"{label}, {procs} process(es)"] = dict(wall_s=best_w, cpu_s=best_c)
            print(f"{label:38s} {procs} proc: wall {best_w:7.3f} s  CPU {best_c:7.3f} s", flush=True)
    base = rows["objective only, 1 process(es)"]["wall_s"]
    for k, r in rows.items():
        r["wall_over_objective_only"] = r["wall_s"] / base
    summary = dict(settings=vars(args), parameters=len(pset.names), data_points=int(sum(d.n_points for d in data)),
                   rows=rows, load_average_start=load0, load_average_end=os.getloadavg(),
                   note="CPU of the pooled runs includes the worker processes (counted when the pool closes, "
                        "so also their start-up)")
    os.makedirs(args.out, exist_ok=True)
    with open(os.path.join(args.out, "summary.json"), "w") as f:
        json.dump(summary, f, indent=1)
    print(f"load average {load0} -> {os.getloadavg()}; {args.out}/summary.json")


if __name__ == "__main__":
    main()
