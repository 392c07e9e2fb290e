#!/usr/bin/python3
"""Identification of Ehlers parameters from homogeneous tests (thesis chapters 4-6).

What is solved
--------------
min over the named parameters s of the multi-criterion least-squares objective (4.18),
(6.3): one term per test and measured quantity, each normalised by phi_0^2 N (4.17, Table
6.2), the model being the material-point driver (one Gauss point, no mesh) running each
test.  SQP with SciPy's SLSQP (section 4.2; --method trust-constr with the Gauss-Newton
Hessian as the alternative), gradients from the sensitivities of chapter 5
(--sensitivity numerical | semi-analytical), bounds and the model's constraints (4.2).
Then the error analysis of section 4.5: s0 (4.27), covariance (4.28), standard deviations
(4.29), confidence intervals (4.30) and the correlation matrix (4.31).

Data: one CSV per test in the material-point driver's format (its history.csv):
``axial_strain, axial_stress, volumetric_strain`` for triaxial/biaxial tests,
``pressure`` (or ``mean_stress``) and ``volumetric_strain`` for hydrostatic ones; SI,
tension positive; optional ``<quantity>_std`` columns (scatter, eq. 4.26).  Give each as
``--data KIND:CONFINING:FILE`` (KIND hydrostatic, isotropic_plane_strain, triaxial,
biaxial; CONFINING in Pa, empty for hydrostatic: the file's largest pressure), or all of
them in a JSON --config (see docs/results/identification.md).  Without data the demo runs the
re-identification of section 6.2.3: virtual data from the Hostun set (the five tests of
6.1), the named parameters disturbed by --disturb, then recovered.

Stepwise identification (4.3): --params may be given several times; each stage
identifies its parameters with those of the earlier stages fixed at their identified
values, on the tests of the kinds after a colon (default all), e.g. ``--params
elastic:triaxial_unloading --params plastic:hydrostatic,triaxial,biaxial``; ``--stepwise``
is that sequence (with virtual data it adds unloading branches of the three triaxial
tests, the thesis' data for step 1(a)).  Groups: elastic (4.19), plastic (the 14 of 6.2),
initial, or parameter names separated by commas.

Outputs in --out: identified_parameters.json (loadable: ``demos/material_point.py
--parameters`` and ``demos/biaxial.py --parameters``), summary.json (values, start,
objective, iterations, cost, error analysis), iterations.csv (one row per SQP iteration,
written as it goes), fit.png (every test, data and model at start and end), objective.png
(f against iterations), correlation.png (heat map of 4.31).  One progress line per
iteration.

Examples:
  python3 demos/identify.py --params psi1,psi2,beta_star --out out/identify
  python3 demos/identify.py --data triaxial:100e3:tri100.csv --data hydrostatic::hyd.csv \\
      --params plastic --out out/identify_lab
"""
import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
from cosserat_fenicsx.identification.virtual_tests import MIN_STEPS  # noqa: E402
from cosserat_fenicsx.validation import NON_NEGATIVE, POSITIVE, STEPS, InputError, Parser, Range, number  # noqa: E402

def build_parser():
    p = Parser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter, allow_abbrev=False)
    p.add_argument("--data", action="append", default=[], metavar="KIND:CONFINING:FILE",
                   help="a test's data file (repeatable); none: re-identification from virtual data")
    p.add_argument("--config", default=None, help="JSON file with tests, params, start, bounds (see docs)")
    p.add_argument("--params", action="append", default=[],
                   help="parameters to identify: names or groups, comma separated, optionally :KIND,KIND (the "
                        "tests this stage fits); repeat for stages "
                        "(default: psi1,psi2,beta_star,gamma_star)")
    p.add_argument("--stepwise", action="store_true",
                   help="the stepwise identification of 4.3/6.1: elastic (4.19) on unloading branches, then the "
                        "14 plastic parameters (6.2) on the other tests")
    p.add_argument("--start", default=None, help="JSON parameter file with the start values (default Hostun)")
    p.add_argument("--bounds", default=None, help='JSON {"name": [lower, upper]} overriding the default bounds')
    p.add_argument("--method", choices=("auto", "trf", "SLSQP", "trust-constr"), default="auto",
                   help="auto: trf (Gauss-Newton trust region) unless a nonlinear constraint applies, then SLSQP")
    p.add_argument("--sensitivity", choices=("semi-analytical", "numerical"), default="semi-analytical",
                   help="semi-analytical (section 5.2, default: 24x cheaper than differences) or numerical (5.1)")
    p.add_argument("--max-iterations", type=number(STEPS), default=60, help="SQP iterations per stage")
    p.add_argument("--processes", type=number(Range(1, 64, integer=True)), default=1,
                   help="worker processes evaluating the tests in parallel (default %(default)s)")
    p.add_argument("--confidence", type=number(Range(0.5, 1.0, high_open=True)), default=0.95,
                   help="confidence level of the intervals (4.30) (default %(default)g)")
    p.add_argument("--serial-correlation", action="store_true",
                   help="errors of neighbouring points of a curve correlated (e.g. DEM curves): covariance from "
                        "the Newey-West sandwich instead of (4.28)")
    p.add_argument("--out", default="out/identify", help="output directory (default %(default)s)")
    v = p.add_argument_group("virtual data (no --data: re-identification, section 6.2.3)")
    v.add_argument("--disturb", type=number(Range(-0.5, 0.5)), default=0.1,
                   help="relative disturbance of the start from the reference (default %(default)g)")
    v.add_argument("--noise", type=number(NON_NEGATIVE), default=0.0,
                   help="Gaussian noise on the virtual data, as a fraction of Table 6.2's phi_0 (default 0)")
    v.add_argument("--seed", type=number(Range(0, 2**31, integer=True)), default=0, help="noise seed")
    v.add_argument("--every", type=number(Range(1, 1000, integer=True)), default=3,
                   help="keep every n-th model record as a data point (default %(default)s)")
    v.add_argument("--steps", type=number(STEPS), default=75, help="load steps of each virtual test")
    m = p.add_argument_group("model")
    m.add_argument("--eta", type=number(NON_NEGATIVE), default=1e-4, help="Perzyna time [s] (2.81)")
    m.add_argument("--micropolar", action="store_true",
                   help="keep the micropolar terms (homogeneous tests do not see them, 6.1.1)")
    m.add_argument("--min-model-steps", type=number(STEPS), default=MIN_STEPS,
                   help="the model runs each test along its data, a step ending at every data point, intervals "
                        "split so that a test has at least this many steps over its range (default %(default)s, "
                        "the material-point demo's)")
    m.add_argument("--model-refinements", type=number(Range(0, 6, integer=True)), default=3,
                   help="times every model step may be halved after a fit whose parameters the model's "
                        "discretisation moves by more than --max-discretisation-shift (default %(default)s; 0 "
                        "with virtual data, which the model made with its own steps)")
    m.add_argument("--max-discretisation-shift", type=number(POSITIVE), default=0.25,
                   help="largest shift of a parameter by the model's discretisation error, in standard "
                        "deviations, accepted without halving the steps (default %(default)g)")
    m.add_argument("--n-steps-per-test", type=number(STEPS), default=None, dest="model_steps",
                   help="equal model load steps per test instead (the data's abscissae not followed)")
    return p


def parse_stages(params, config_stages, stepwise):
    """Stages from --params NAMES[:KIND,KIND] (repeatable), the config's "stages" (lists of
    names, or {"params": [...], "kinds": [...]}), or --stepwise (4.3: elastic on the unloading
    branches, then the 14 plastic parameters on the five tests)."""
    from cosserat_fenicsx.identification.run import Stage
    from cosserat_fenicsx.identification.virtual_tests import KINDS, UNLOADING

    def split(text):
        return tuple(x.strip() for x in text.split(",") if x.strip())

    stages = []
    if stepwise:
        if params or config_stages:
            raise InputError("--stepwise sets the stages itself: give no --params or config stages with it")
        return [Stage(("elastic",), UNLOADING), Stage(("plastic",), tuple(k for k in KINDS if k not in UNLOADING))]
    for arg in params:
        names, _, kinds = arg.partition(":")
        stages.append(Stage(split(names), split(kinds) or None))
    for st in ([] if params else config_stages):
        if isinstance(st, dict):
            stages.append(Stage(tuple(st.get("params", ())), tuple(st["kinds"]) if st.get("kinds") else None))
        else:
            stages.append(Stage(split(st) if isinstance(st, str) else tuple(st)))
    for st in stages:
        if not st.params:
            raise InputError("a stage names no parameters")
        bad = [k for k in st.kinds or () if k not in KINDS]
        if bad:
            raise InputError(f"stage {','.join(st.params)}: test kind(s) {bad} not among {sorted(KINDS)}")
    return stages or [Stage(("psi1", "psi2", "beta_star", "gamma_star"))]


def virtual_kinds(stages):
    """The kinds of the virtual data: the five tests of 6.1, and the unloading branches when a
    stage asks for them."""
    from cosserat_fenicsx.identification.data import THESIS_TESTS, THESIS_UNLOADING
    asked = {k for st in stages for k in st.kinds or ()}
    return {k for k, _ in THESIS_TESTS} | ({k for k, _ in THESIS_UNLOADING} & asked)


def load_data(args, config):
    """TestData list from --data or the config, or None (virtual data)."""
    from cosserat_fenicsx.identification.data import read_test
    entries = []
    for spec in args.data:
        parts = spec.split(":", 2)
        if len(parts) != 3:
            raise InputError(f"--data {spec!r}: expected KIND:CONFINING:FILE (CONFINING may be empty)")
        kind, conf, path = parts
        try:
            conf = float(conf) if conf.strip() else None
        except ValueError:
            raise InputError(f"--data {spec!r}: confining pressure {conf!r} is not a number") from None
        entries.append(dict(kind=kind, confining=conf, file=path))
    base = os.path.dirname(os.path.abspath(args.config)) if args.config else os.getcwd()
    for t in config.get("tests", []):
        if not isinstance(t, dict) or "file" not in t or "kind" not in t:
            raise InputError(f"config: every test needs 'kind' and 'file', got {t!r}")
        entries.append(dict(t, file=os.path.join(base, t["file"])))
    if not entries:
        return None
    out = []
    for e in entries:
        out.append(read_test(e["file"], e["kind"], e.get("confining"), quantities=e.get("quantities"),
                             normalisation=e.get("normalisation"), scatter=e.get("scatter"),
                             n_steps=args.model_steps and int(args.model_steps),
                             start_pressure=e.get("start_pressure", 0.0), unload_at=e.get("unload_at"),
                             min_steps=int(args.min_model_steps)))
    return out


def main(argv=None):
    parser = build_parser()
    args = parser.parse_args(argv)
    t_start, c_start = time.perf_counter(), time.process_time()
    from cosserat_fenicsx.identification.config import check_bounds, check_config, read_json
    from cosserat_fenicsx.identification.objective import check_homogeneous
    from cosserat_fenicsx.identification.parameter_set import ParameterSet
    from cosserat_fenicsx.materials.ehlers.parameters import EhlersParameters, read_parameter_file
    # ---- every input checked before any model run
    try:
        config = check_config(read_json(args.config, "config"), f"config {args.config!r}") if args.config else {}
        stages = parse_stages(args.params, config.get("stages", config.get("params", [])), args.stepwise)
        base = dict(eta=args.eta, micropolar=args.micropolar)
        if config.get("base"):
            base.update(config["base"])
        if args.start:
            base.update(read_parameter_file(args.start))
        base.update(config.get("start", {}))
        bounds = (check_bounds(read_json(args.bounds, "bounds"), f"bounds {args.bounds!r}") if args.bounds
                  else check_bounds(config.get("bounds", {}), "config 'bounds'"))
        try:
            reference = EhlersParameters(**base)
        except (TypeError, ValueError) as error:
            raise InputError(f"start parameters: {error}") from None
        data = load_data(args, config)
        virtual = data is None
        start_values = reference.as_dict()
        if virtual and "model_refinements" not in parser.given_options(argv):
            args.model_refinements = 0     # the model made the data with its own steps: halving cannot help
        if virtual:
            all_names = {n for st in stages for n in ParameterSet(st.params, reference).names}
            for n in all_names:
                start_values[n] = start_values[n] * (1.0 + args.disturb) if start_values[n] != 0 else 0.0
        start = EhlersParameters(**start_values)
        try:   # the micropolar values the result file keeps (homogeneous tests do not see them)
            defaults = EhlersParameters()
            polar = EhlersParameters(**dict(start_values, micropolar=True, mu_c=base.get("mu_c"),
                                            k_sigma=base.get("k_sigma", defaults.k_sigma),
                                            k_mu=base.get("k_mu", defaults.k_mu)))
        except (TypeError, ValueError) as error:
            raise InputError(f"start parameters: {error}") from None
        identified = set()
        for st in stages:   # names, bounds, constraints and data at the start, stage by stage
            names = ParameterSet.for_stage(st.params, start, bounds).names
            check_homogeneous(names)
            identified.update(names)
            kinds = {d.test.kind for d in data} if data is not None else virtual_kinds(stages)
            if st.kinds is not None and not kinds & set(st.kinds):
                raise InputError(f"stage {','.join(st.params)}: no data of the kinds {list(st.kinds)}")
        unused = sorted(set(bounds) - identified)
        if unused:
            raise InputError(f"bounds given for {unused}, which no stage identifies (identified: {sorted(identified)})")
    except (InputError, ValueError) as error:
        parser.refuse(error)
    os.makedirs(args.out, exist_ok=True)
    from cosserat_fenicsx.identification.data import thesis_virtual_data
    from cosserat_fenicsx.identification.run import run_stages, write_outputs
    from cosserat_fenicsx.run_guard import RunGuard
    guard = RunGuard(None, os.path.join(args.out, "summary.json"),
                     dict(stages=[st.describe() for st in stages], method=args.method, sensitivity=args.sensitivity),
                     label="identify")
    if virtual:
        print(f"identify: re-identification from virtual data of the Hostun set, start disturbed by "
              f"{100 * args.disturb:+g} %, noise {args.noise:g} phi_0")
        data = thesis_virtual_data(reference, args.steps, args.every, args.noise, np.random.default_rng(args.seed),
                                   unloading="triaxial_unloading" in virtual_kinds(stages))
    for d in data:
        print(f"  {d.label}: {len(d.x)} points, quantities {list(d.y)}, normalisation "
              + ", ".join(f"{q} {v:.4g}" for q, v in d.normalisation.items()) + f"  ({d.source})")
    result = run_stages(data, stages, start, bounds, args, log=print, out=args.out, guard=guard, polar=polar)
    summary = write_outputs(result, data, args, reference if virtual else None)
    summary["wall_time_s"] = time.perf_counter() - t_start
    summary["cpu_time_s_main_process"] = time.process_time() - c_start
    summary["completed"] = summary["converged"]
    summary["reason"] = "" if summary["converged"] else (
        "the identification did not converge; its best point is in identified_parameters.json: "
        + "; ".join(st["message"] for st in summary["stages"] if not st["converged"]))
    guard.finish(summary)
    print(f"identify: {'converged' if summary['converged'] else 'NOT converged (best point written)'}; "
          f"f {summary['f_start']:.4g} -> {summary['f']:.4g}; {summary['iterations']} iterations, "
          f"{summary['evaluations']} evaluations, {summary['wall_time_s']:.1f} s; results in {args.out}")
    if not summary["converged"]:
        sys.exit(1)
    return summary


if __name__ == "__main__":
    main()
