#!/usr/bin/python3
"""Local damping (000 section 3.2.1) vs FIRE relaxation on the biaxial path of the demo.

For each size: a packing (seed 0, 10 N/m, 000 Table 3 law), isotropic stage, then 30
axial increments of 1e-3 at constant lateral stress, each a quasi-static solve with
E_kin/E_pot <= 1e-3. Reports DEM steps, CPU seconds and the stress ratio path of both
methods (their difference shows how much the relaxation path changes the frictional answer).

    /usr/bin/python3 benchmarks/dem/dem_relaxation.py --out results/dem_relaxation

A second table (dem_relaxation_error.json) is the error of one solve as FEM x DEM asks it:
the FEM x DEM reference cell (CellOptions, unbalanced-force ratio 1e-3) committed at biaxial
pre-strains of 0-4 %, then asked an increment of 1e-4 or 1e-3 (the target F, no servo), with
the default relaxation, dt_safety 0.5, FIRE, and a tolerance of 1e-4: DEM steps and
|sigma - sigma_ref| / |sigma_ref| against the same solve relaxed to 1e-5 (what
`--cell-option` trades in docs/results/femdem.md).
"""
import argparse
import json
import os
import time

import numpy as np

import demcell as dc
from demcell.interface import RelaxationOptions


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


#: the settings of the error table (demcell.RelaxationOptions overrides)
ERROR_SETTINGS = {"default": {}, "tol 1e-4": {"tol": 1e-4}, "dt_safety 0.5": {"dt_safety": 0.5},
                  "fire": {"method": "fire"}}


def solve_error(particles, increments=(1e-4, 1e-3), pre_strains=(0.0, 0.01, 0.02, 0.04)):
    """Rows (increment, pre-strain, setting, DEM steps, relative stress error to a 1e-5 solve)."""
    import dataclasses
    from cosserat_fenicsx.materials.dem import CellOptions
    options = CellOptions(particles=particles)
    state, _ = options.packing_state()
    ref = dc.reference_cell(state, options.law(), options.relaxation(), options.pressure)
    committed = []
    for e in pre_strains:
        cell = ref.copy()
        cell.set_deformation(np.array([[1 + 0.5 * e, 0.0], [0.0, 1 - e]]))
        cell.solve()
        cell.commit()
        committed.append(cell)

    def solve(cell0, increment, **changes):
        cell = cell0.copy()
        cell.options = dataclasses.replace(cell.options, **changes)
        cell.set_law(cell.law)          # the time step follows the new dt_safety
        F = cell.committed_state.F.copy()
        F[0, 0] += 0.5 * increment
        F[1, 1] -= increment
        cell.set_deformation(F)
        result = cell.solve()
        return cell.cauchy_stress().copy(), result.steps

    rows = []
    for increment in increments:
        for e, cell0 in zip(pre_strains, committed):
            exact, _ = solve(cell0, increment, tol=1e-5)
            for label, changes in ERROR_SETTINGS.items():
                sigma, steps = solve(cell0, increment, **changes)
                rows.append(dict(increment=increment, pre_strain=e, setting=label, dem_steps=steps,
                                 stress_error=float(np.linalg.norm(sigma - exact) / np.linalg.norm(exact))))
    return rows


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
    rows = solve_error(a.sizes[0])
    with open(os.path.join(a.out, "dem_relaxation_error.json"), "w") as f:
        json.dump(rows, f, indent=1)
    print(f"one solve of a {a.sizes[0]}-disc FEM x DEM cell against a 1e-5 relaxation:")
    for increment in sorted({r["increment"] for r in rows}):
        for label in ERROR_SETTINGS:
            sel = [r for r in rows if r["increment"] == increment and r["setting"] == label]
            print(f"  increment {increment:.0e}  {label:14s} DEM steps {min(r['dem_steps'] for r in sel):5d}-"
                  f"{max(r['dem_steps'] for r in sel):5d}  stress error {min(r['stress_error'] for r in sel):.1e}-"
                  f"{max(r['stress_error'] for r in sel):.1e}")


if __name__ == "__main__":
    main()
