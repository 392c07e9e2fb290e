#!/usr/bin/python3
"""Re-identification of the Ehlers parameters at the material point.

The check nobody can fake (thesis 6.2.3's method, applied to the homogeneous tests of 6.1):

1. Virtual data: the five tests of 6.1 (hydrostatic to 1 MPa, triaxial at 100 / 300 / 600
   kPa, plane-strain biaxial at 100 kPa) run with the Hostun reference set (Tables 6.1,
   6.4 under H1).
2. Noise-free recovery: the named parameters disturbed by --disturb, identified again by
   SLSQP; the recovered values are compared with the reference (aim: --tolerance).
3. Noise: --draws independent draws of Gaussian noise of --noise x phi_0 (Table 6.2) on
   every data point; each identified from the reference start; the error analysis of
   section 4.5 (known scatter) gives intervals.  Counted: how often the reference lies in
   the joint region of (4.30) and in each parameter's marginal t interval.  At the nominal
   rate (95 %) the error analysis is right; far below it, it is overconfident.

With --model-min-steps the model does not run the steps that made the data: the data come
from --steps equal steps (1 s each; take many, e.g. 4800 with --every 80, for data close to
the time-continuous answer, as measured data are) and the model follows them as it follows
measured data (a step at every data point, at least --model-min-steps over a test).  The
difference is the model's discretisation error, which the noise-free recovery shows as a
bias and the coverage shows as intervals that miss.  --model-steps N runs the model at N
equal steps instead (the old default was 150, 1e-3 axial strain per step).

Prints tables, writes out/reidentification/summary.json and reidentification.png.
Runs in `make benchmark`; about 1 s per objective evaluation with 14 parameters.  Each
identification is demos/identify.py's (run_stages), with its halving of the model's steps.

    python3 benchmarks/identification/reidentification.py [--params plastic] [--draws 40] [--processes 2]
    python3 benchmarks/identification/reidentification.py --steps 4800 --every 80 --model-min-steps 600
"""
import argparse
import dataclasses
import json
import os
import time

import numpy as np

from cosserat_fenicsx.identification.data import thesis_virtual_data
from cosserat_fenicsx.identification.parameter_set import ParameterSet
from cosserat_fenicsx.identification.run import Stage, run_stages
from cosserat_fenicsx.materials.ehlers.parameters import EhlersParameters
from cosserat_fenicsx.validation import NON_NEGATIVE, POSITIVE, STEPS, Parser, Range, number

def run(data, names, start, args):
    """One identification as demos/identify.py makes it (run_stages: one stage, the model's
    steps halved while their error moves a parameter by more than --max-discretisation-shift
    of its standard deviation); returns the stage's result and its CPU seconds."""
    settings = argparse.Namespace(method=args.method, sensitivity=args.sensitivity, processes=args.processes,
                                  max_iterations=args.max_iterations, serial_correlation=False, confidence=0.95,
                                  model_refinements=args.model_refinements,
                                  max_discretisation_shift=args.max_discretisation_shift)
    c0 = time.process_time()
    _, stages = run_stages(data, [Stage(tuple(names))], start, {}, settings, log=lambda *a: None)
    return stages[0], time.process_time() - c0


def main():
    p = Parser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter, allow_abbrev=False)
    p.add_argument("--params", default="plastic", help="names or groups, comma separated (default plastic: 14)")
    p.add_argument("--disturb", type=number(Range(-0.5, 0.5)), default=0.1)
    p.add_argument("--tolerance", type=number(Range(0, 1, low_open=True)), default=1e-3,
                   help="aim for the noise-free recovery, relative (default %(default)g)")
    p.add_argument("--noise", type=number(NON_NEGATIVE), default=0.01, help="noise / phi_0 (default %(default)g)")
    p.add_argument("--draws", type=number(Range(0, 10000, integer=True)), default=40)
    p.add_argument("--steps", type=number(STEPS), default=75)
    p.add_argument("--every", type=number(Range(1, 1000, integer=True)), default=3)
    p.add_argument("--model-min-steps", type=number(STEPS), default=None,
                   help="the model follows the data with at least this many steps per test (default: the data's steps)")
    p.add_argument("--model-steps", type=number(STEPS), default=None,
                   help="the model runs this many equal steps per test instead")
    p.add_argument("--model-refinements", type=number(Range(0, 6, integer=True)), default=3,
                   help="as demos/identify.py (default %(default)s; 0: the model keeps its first steps)")
    p.add_argument("--max-discretisation-shift", type=number(POSITIVE), default=0.25)
    p.add_argument("--sensitivity", choices=("numerical", "semi-analytical"), default="semi-analytical")
    p.add_argument("--method", choices=("auto", "trf", "SLSQP", "trust-constr"), default="auto",
                   help="auto: trf (Gauss-Newton trust region) unless a nonlinear constraint applies, then SLSQP")
    p.add_argument("--processes", type=number(Range(1, 64, integer=True)), default=1)
    p.add_argument("--max-iterations", type=number(STEPS), default=100)
    p.add_argument("--out", default="out/reidentification")
    args = p.parse_args()
    os.makedirs(args.out, exist_ok=True)
    names = tuple(x for x in args.params.split(",") if x)
    reference = EhlersParameters(micropolar=False)
    names = ParameterSet(names, reference).names
    load = os.getloadavg()
    summary = dict(params=list(names), reference={n: getattr(reference, n) for n in names}, settings=vars(args),
                   load_average_start=load)

    def virtual_data(noise, rng):
        data = thesis_virtual_data(reference, args.steps, args.every, noise, rng,
                                   model_min_steps=args.model_min_steps and int(args.model_min_steps))
        if args.model_steps:
            data = [dataclasses.replace(d, test=dataclasses.replace(d.test, n_steps=int(args.model_steps), path=None,
                                                                    step_times=None)) for d in data]
        return data

    def dump():
        with open(os.path.join(args.out, "summary.json"), "w") as f:
            json.dump(summary, f, indent=1, default=float)

    # ---- 2. noise-free recovery from a disturbed start
    data = virtual_data(0.0, np.random.default_rng(0))
    values = reference.as_dict()
    for n in names:
        values[n] *= 1.0 + args.disturb
    start = EhlersParameters(**values)
    t0 = time.perf_counter()
    stage, cpu = run(data, names, start, args)
    pset, res, ea = stage.parameter_set, stage.identification, stage.analysis
    rel = {n: float(v / getattr(reference, n) - 1.0) for n, v in zip(names, res.values)}
    worst = max(abs(v) for v in rel.values())
    print(f"noise-free recovery ({len(names)} parameters, start {100 * args.disturb:+g} %, {args.method}, "
          f"{args.sensitivity}): {res.iterations} iterations, {res.evaluations} evaluations, "
          f"{time.perf_counter() - t0:.1f} s wall, {cpu:.1f} s CPU; f {res.f_start:.3g} -> {res.f:.3g}; "
          f"worst relative error {worst:.2e} (aim {args.tolerance:g}): {'met' if worst <= args.tolerance else 'MISSED'}; "
          f"model steps halved {stage.refinements} time(s)")
    print(f"{'parameter':14s} {'reference':>12s} {'start':>12s} {'identified':>12s} {'rel. error':>10s}")
    for n, v0, v in zip(names, pset.start, res.values):
        print(f"{n:14s} {getattr(reference, n):12.6g} {v0:12.6g} {v:12.6g} {rel[n]:10.2e}")
    summary["noise_free"] = dict(iterations=res.iterations, evaluations=res.evaluations, f_start=res.f_start, f=res.f,
                                 converged=res.converged, message=res.message, relative_error=rel,
                                 worst_relative_error=worst, aim=args.tolerance, aim_met=worst <= args.tolerance,
                                 wall_time_s=res.wall_time, cpu_time_s=cpu, model_refinements=stage.refinements,
                                 model_steps=[d.test.n_steps for d in stage.objective.data],
                                 discretisation_error=stage.discretisation,
                                 condition_number=ea.condition_number if ea else None,
                                 correlation=ea.correlation.tolist() if ea else None)
    dump()
    # ---- 3. noise draws: coverage of the confidence intervals
    rng = np.random.default_rng(2026)
    inside_joint, inside_marginal, s0s, its, recs, levels = 0, np.zeros(len(names)), [], [], [], []
    truth = np.array([getattr(reference, n) for n in names])
    for k in range(args.draws):
        data = virtual_data(args.noise, rng)
        stage, cpu = run(data, names, reference, args)
        res, ea = stage.identification, stage.analysis
        levels.append(stage.refinements)
        if ea is None or list(ea.names) != list(names):      # no intervals (or a parameter at a bound): a miss
            print(f"draw {k + 1:3d}: no error analysis for all parameters ({res.message})")
            j, m, ea = False, np.zeros(len(names), dtype=bool), None
        else:
            j = ea.inside_joint_region(truth)
            lo, hi = ea.intervals(joint=False)
            m = (lo <= truth) & (truth <= hi)
        inside_joint += int(j)
        inside_marginal += m
        s0s.append(ea.s0 if ea else np.nan)
        its.append(res.iterations)
        recs.append(dict(draw=k, converged=res.converged, iterations=res.iterations, s0=ea.s0 if ea else None,
                         inside_joint=j, inside_marginal=m.tolist(), values=res.values.tolist(),
                         std=ea.std.tolist() if ea else None, cpu_s=cpu, model_refinements=stage.refinements))
        n = k + 1
        print(f"draw {n:3d}: s0 = {s0s[-1]:.3f}, {res.iterations} it, steps halved {stage.refinements}x, "
              f"joint {'in ' if j else 'OUT'}, marginal "
              f"{int(m.sum())}/{len(names)} in; coverage so far joint {inside_joint / n:.2f}, marginal "
              f"{inside_marginal.mean() / n:.2f}")
        summary["noise"] = dict(draws=n, noise_over_phi0=args.noise, joint_coverage=inside_joint / n,
                                marginal_coverage=(inside_marginal / n).tolist(),
                                marginal_coverage_mean=float(inside_marginal.mean() / n),
                                binomial_std_at_95=float(np.sqrt(0.95 * 0.05 / n)), nominal=0.95,
                                s0_mean=float(np.nanmean(s0s)), iterations_mean=float(np.mean(its)),
                                model_refinements_mean=float(np.mean(levels)), records=recs)
        dump()
    summary["load_average_end"] = os.getloadavg()
    dump()
    if args.draws:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        cov = summary["noise"]["marginal_coverage"]
        fig, ax = plt.subplots(figsize=(max(5, 0.45 * len(names) + 2), 3.5))
        ax.bar(range(len(names)), cov, color="0.6")
        ax.axhline(0.95, color="r", lw=1, label="nominal 95 %")
        ax.axhline(summary["noise"]["joint_coverage"], color="b", ls="--", lw=1, label="joint region (4.30)")
        ax.set_xticks(range(len(names)))
        ax.set_xticklabels(names, rotation=90, fontsize=8)
        ax.set_ylim(0, 1.05)
        ax.set_ylabel(f"coverage over {args.draws} draws")
        ax.legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(os.path.join(args.out, "reidentification.png"), dpi=110)


if __name__ == "__main__":
    main()
