#!/usr/bin/python3
"""Local damping (000 section 3.2.1) vs FIRE relaxation on the biaxial path of the demo.

For each size: a packing (seed 0, 10 N/m, 000 Table 3 law), isotropic stage, then 30
axial increments of 1e-3 at constant lateral stress, each a quasi-static solve with
E_kin/E_pot <= 1e-3. Reports DEM steps, CPU seconds and the stress ratio path of both
methods (their difference shows how much the relaxation path changes the frictional answer).

    /usr/bin/python3 benchmarks/dem_relaxation.py --out results/dem_relaxation
"""
import argparse
import json
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

import demcell as dc  # noqa: E402
from demcell.interface import RelaxationOptions  # noqa: E402


def biaxial(state, law, method, increments, p0=10.0):
    cell = dc.DemCell(state.copy(), law, RelaxationOptions(method=method))
    cell.solve(stress_mask=[[True, True], [False, True]], stress_target=-p0 * np.eye(2))
    F = cell.deformation_gradient()
    F0 = F.copy()
    steps, ratios, ok = 0, [], True
    t0 = time.process_time()
    for k in range(1, increments + 1):
        F[0, 0] = F0[0, 0] * (1.0 - 1e-3 * k)
        cell.set_deformation(F)
        r = cell.solve(stress_mask=[[False, False], [False, True]], stress_target=np.diag([0.0, -p0]))
        steps += r.steps
        ok = ok and r.converged
        ratios.append(cell.homogenized().stress_ratio)
    return dict(steps=steps, cpu_s=time.process_time() - t0, converged=ok, stress_ratio=ratios)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sizes", type=int, nargs="+", default=[228, 400])
    p.add_argument("--increments", type=int, default=30)
    p.add_argument("--out", default="results/dem_relaxation")
    a = p.parse_args(argv)
    os.makedirs(a.out, exist_ok=True)
    law = dc.ContactLaw(kn=1e4, ks=2e3, friction=0.4)
    rows = []
    for n in a.sizes:
        st, _ = dc.generate_packing(n, pressure=10.0, law=law, seed=0)
        biaxial(st, law, "fire", 1)          # JIT warm-up of both paths
        row = dict(n=n)
        for method in ("local", "fire"):
            row[method] = biaxial(st, law, method, a.increments)
        row["steps_ratio_local_over_fire"] = row["local"]["steps"] / row["fire"]["steps"]
        row["max_stress_ratio_difference"] = float(np.max(np.abs(np.array(row["local"]["stress_ratio"])
                                                                 - np.array(row["fire"]["stress_ratio"]))))
        rows.append(row)
        with open(os.path.join(a.out, "dem_relaxation.json"), "w") as f:
            json.dump(rows, f, indent=2)
        print(f"N={n}: local {row['local']['steps']} steps {row['local']['cpu_s']:.2f} cpu-s, fire "
              f"{row['fire']['steps']} steps {row['fire']['cpu_s']:.2f} cpu-s (steps ratio "
              f"{row['steps_ratio_local_over_fire']:.2f}); max |stress ratio difference| "
              f"{row['max_stress_ratio_difference']:.3f}", flush=True)


if __name__ == "__main__":
    main()
