#!/usr/bin/env python3
"""Sensitivities of the Ehlers virtual tests (thesis chapter 5): step study and cost.

1. Step study (section 5.1): error of the central differences (5.5) against the
   semi-analytical sensitivities (section 5.2) for relative steps 1e-1 .. 1e-9, per test kind
   and parameter, error = identification.sensitivity.column_error (relative L2 error of a
   column over the records, worst measured quantity, with a floor of 1e-3 of the largest
   scaled column).  Twice: with the model's solver tolerances (mixed-control Newton of the
   driver 1e-7 |S|, local Newton 1e-10: the runs the objective sees) and with tight ones
   (1e-9, 1e-12: the differences free of the residuals the iterations stop at).  Large
   steps show truncation (error ~ rel^2), small ones round-off and solver noise (~ 1/rel).
2. Cost of one sensitivity evaluation of a triaxial test (150 steps, 300 kPa) w.r.t. the 14
   parameters of eq. (6.2), by each method (after a warm-up, best of --repeat): CPU s, wall s
   and their ratio.

    python3 benchmarks/identification/identification_sensitivity.py [--steps 150] [--study-steps 100] [--repeat 3]

Prints the tables and writes out/identification_sensitivity/summary.json.
"""
import argparse
import os
import time

import numpy as np

from benchmarks import ROOT
from cosserat_fenicsx.identification import sensitivity as sens
from cosserat_fenicsx.identification.virtual_tests import VirtualTest
from cosserat_fenicsx.materials.ehlers.material import EhlersMaterial
from cosserat_fenicsx.materials.ehlers.parameters import EhlersParameters
from cosserat_fenicsx.run_guard import RunGuard

RELS = tuple(10.0 ** -k for k in range(1, 10))
ELASTIC = ("mu", "lmbda", "n_max")
INITIAL = ("beta0", "delta0", "epsilon0", "gamma0")
TESTS = (("hydrostatic", 1e6), ("isotropic_plane_strain", 1e6), ("triaxial", 300e3), ("biaxial", 300e3))


def timed(fn, repeat):
    best = None
    for _ in range(repeat):
        c0, w0 = time.process_time(), time.perf_counter()
        fn()
        c, w = time.process_time() - c0, time.perf_counter() - w0
        best = (c, w) if best is None or w < best[1] else best
    return best


def study_table(rows, names):
    lines = [f"{'rel step':>9} " + " ".join(f"{n[:11]:>11}" for n in names) + f" {'worst':>9}"]
    for rel, row in rows.items():
        vals = [row[n] for n in names]
        worst = max((v for v in vals if v is not None), default=float("nan"))
        lines.append(f"{rel:9.0e} " + " ".join(f"{v:11.1e}" if v is not None else f"{'n/a':>11}" for v in vals)
                     + f" {worst:9.1e}")
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=150, help="deviatoric steps of the timed triaxial test")
    ap.add_argument("--study-steps", type=int, default=100, help="load steps of the tests of the step study")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--out", default=os.path.join(ROOT, "out", "identification_sensitivity"))
    a = ap.parse_args(argv)
    os.makedirs(a.out, exist_ok=True)
    params = EhlersParameters(micropolar=False)
    names = sens.PLASTICITY_14 + ELASTIC + INITIAL
    guard = RunGuard(None, os.path.join(a.out, "summary.json"), dict(options=vars(a), parameters=list(names)),
                     label="identification_sensitivity")
    load = os.getloadavg()
    summary = dict(options=vars(a), load_average_start=load, parameters=list(names), step_study={})
    # warm-up: Numba compilation / cache load
    sens.test_sensitivities(params, VirtualTest("triaxial", 300e3, n_steps=5, n_consolidation=5), names[:2],
                            "semi-analytical")
    for kind, confining in TESTS:
        test = VirtualTest(kind, confining, n_steps=a.study_steps)
        h, ref = sens.test_sensitivities(params, test, names, "semi-analytical")
        summary["step_study"][kind] = {}
        for tol in (None, 1e-9):
            tols = dict(driver_tol=tol, kernel_tol=None if tol is None else 1e-12)
            rows = sens.step_study(params, test, names, RELS, reference=ref, **tols)
            label = ("solver tolerances of the model (driver 1e-7, local 1e-10)" if tol is None
                     else "tight solver tolerances (driver 1e-9, local 1e-12)")
            print(f"\n{test.label}, {a.study_steps} steps, {label}: central-difference error vs relative step")
            print(study_table(rows, names))
            # the default steps of the numerical method, evaluated the same way
            _, dfd = sens.numerical_sensitivities(params, test, names, **tols)
            default = sens.column_error(params, names, {q: dfd[q] for q in test.quantities}, ref)
            print(f"  default steps (DEFAULT_REL_STEP): worst column error {default:.2e}")
            summary["step_study"][kind]["default_tolerances" if tol is None else "tight_tolerances"] = dict(
                table={f"{r:.0e}": row for r, row in rows.items()}, default_steps_error=default)
        summary["step_study"][kind]["prescribed_abscissa_max_abs"] = float(np.abs(ref[test.abscissa]).max()) \
            if kind != "isotropic_plane_strain" else None
        guard.progress()
    # cost of one sensitivity evaluation: triaxial, 150 steps, 14 parameters
    test = VirtualTest("triaxial", 300e3, n_steps=a.steps)
    p14 = sens.PLASTICITY_14
    sens.test_sensitivities(params, test, p14, "semi-analytical")
    c_sa, w_sa = timed(lambda: sens.test_sensitivities(params, test, p14, "semi-analytical"), a.repeat)
    c_fd, w_fd = timed(lambda: sens.test_sensitivities(params, test, p14, "numerical"), a.repeat)
    c_run, w_run = timed(lambda: test.run(EhlersMaterial(**params.as_dict())), a.repeat)
    _, dsa = sens.test_sensitivities(params, test, p14, "semi-analytical")
    _, dfd = sens.test_sensitivities(params, test, p14, "numerical")
    agree = sens.column_error(params, p14, {q: dfd[q] for q in test.quantities}, dsa)
    cost = dict(test=test.label, steps=a.steps, parameters=len(p14), repeat=a.repeat,
                one_run=dict(cpu_s=c_run, wall_s=w_run),
                semi_analytical=dict(cpu_s=c_sa, wall_s=w_sa),
                numerical_central=dict(cpu_s=c_fd, wall_s=w_fd, runs=2 * len(p14) + 1),
                ratio_numerical_over_semi_analytical=dict(cpu=c_fd / c_sa, wall=w_fd / w_sa),
                agreement_default_steps=agree)
    print(f"\ncost of one sensitivity evaluation, {test.label}, {a.steps} steps, {len(p14)} parameters "
          f"(best of {a.repeat}, load average {load[0]:.2f}):")
    print(f"  {'':28s} {'CPU s':>8} {'wall s':>8}")
    print(f"  {'one run (no sensitivities)':28s} {c_run:8.4f} {w_run:8.4f}")
    print(f"  {'semi-analytical':28s} {c_sa:8.4f} {w_sa:8.4f}")
    print(f"  {'numerical (central, 29 runs)':28s} {c_fd:8.4f} {w_fd:8.4f}")
    print(f"  ratio numerical / semi-analytical: CPU {c_fd / c_sa:.1f}, wall {w_fd / w_sa:.1f}")
    print(f"  worst column error numerical (default steps) vs semi-analytical: {agree:.2e}")
    summary.update(cost=cost, load_average_end=os.getloadavg(),
                   faster="semi-analytical" if w_sa < w_fd else "numerical")
    guard.finish(summary)
    print(f"\nwrote {os.path.join(a.out, 'summary.json')}")


if __name__ == "__main__":
    main()
