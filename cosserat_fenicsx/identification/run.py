"""A stepwise identification run and its outputs (thesis 4.3, 6.1; used by demos/identify.py).

Each stage identifies its parameters with those of the earlier stages fixed at their
identified values; the error analysis (4.5) is made for every stage that reached an optimum,
and the model's discretisation error is estimated there (steps halved) and reported beside
the objective with the shift it causes in the parameters; where that shift is not small
against the parameters' standard deviations every model step is halved and the stage
fitted again.  The iterations go to iterations.csv as they happen; the best parameter set
to identified_parameters.json after every stage (with what was identified and whether the
fit converged); the figures and summary.json at the end.
"""

from __future__ import annotations

import csv
import dataclasses
import os

import numpy as np

from ..materials.ehlers.parameters import EhlersParameters, write_parameter_file
from .error_analysis import analyse, plot_correlation
from .objective import Objective
from .parameter_set import MICROPOLAR, ParameterSet
from .sqp import identify


@dataclasses.dataclass(frozen=True)
class Stage:
    """One step of the stepwise identification (4.3): the parameters (names or groups) and
    the kinds of test whose data it fits (None: all), e.g. the elastic step 1(a) on the
    unloading branches only."""

    params: tuple
    kinds: tuple = None

    def select(self, data):
        return [d for d in data if self.kinds is None or d.test.kind in self.kinds]

    def describe(self):
        return dict(params=list(self.params), kinds=list(self.kinds) if self.kinds else "all")


@dataclasses.dataclass
class StageResult:
    names: tuple
    identification: object      # IdentificationResult
    analysis: object            # ErrorAnalysis or None (rank-deficient / too few data)
    objective: Objective
    start_evaluation: object
    at_bound: list
    discretisation: dict = None   # Objective.discretisation_error at the best point
    parameter_set: ParameterSet = None
    refinements: int = 0          # times every model step was halved after the first fit


def polar_form(parameters: EhlersParameters) -> EhlersParameters:
    """The micropolar form of a set: itself, or for a non-polar set (mu_c = k_sigma = k_mu =
    0 there) the class defaults of those (mu_c = mu, Hostun's k_sigma and k_mu)."""
    if parameters.micropolar:
        return parameters
    defaults = EhlersParameters()
    return EhlersParameters(**dict(parameters.as_dict(), micropolar=True, mu_c=None, k_sigma=defaults.k_sigma,
                                   k_mu=defaults.k_mu))


def result_parameters(identified: EhlersParameters, polar: EhlersParameters) -> EhlersParameters:
    """The set to write: the identified values, with the micropolar parameters that no
    homogeneous test sees (mu_c, k_sigma, k_mu are 0 in the non-polar model that ran them)
    taken from `polar`, the start set in its micropolar form, so that a finite-element demo
    can run the file."""
    values = identified.as_dict()
    values.update({n: getattr(polar, n) for n in MICROPOLAR})
    values.update(micropolar=True)
    return EhlersParameters(**values)


def _write_result(out, current, polar, stages, k, n_stages):
    identified = [n for st in stages for n in st.names]
    converged = all(st.identification.converged for st in stages)
    note = (f"demos/identify.py, after stage {k} of {n_stages}; {', '.join(MICROPOLAR)} are the start's "
            "(homogeneous tests do not see them)")
    write_parameter_file(os.path.join(out, "identified_parameters.json"), result_parameters(current, polar),
                         note=note, identification=dict(
                             identified=identified, converged=converged, stages_completed=k, stages=n_stages,
                             reasons=[st.identification.message for st in stages if not st.identification.converged],
                             not_identified_micropolar=[n for n in MICROPOLAR if n not in identified]))


def run_stages(data, stages, start, bounds, args, log=print, out=None, guard=None, polar=None):
    """Run the stages; returns (final EhlersParameters, [StageResult]).  After a stage's fit
    the model's discretisation error is estimated (steps halved) with the shift it causes in
    the parameters; while a shift exceeds args.max_discretisation_shift standard deviations
    every step is halved and the stage fitted again (at most args.model_refinements times),
    unless the halved steps fit the data worse.  guard: a RunGuard
    that counts the iterations (summary.json as the run goes; a signal waits until an
    iteration's row and the best parameters are written).  polar: the start set in its
    micropolar form, whose micropolar values the result file keeps (default: start's)."""
    from contextlib import nullcontext
    current = start
    results = []
    rows = None
    if out is not None:
        f = open(os.path.join(out, "iterations.csv"), "w", newline="")
        rows = csv.writer(f)
        rows.writerow(["stage", "iteration", "objective", "projected_gradient", "wall_time", "values"])
    data = list(data)
    try:
        for k, stage in enumerate(stages, start=1):
            def progress(rec, k=k):
                vals = " ".join(f"{n}={v:.5g}" for n, v in rec.values.items())
                with guard.deferred() if guard is not None else nullcontext():
                    log(f"  it {rec.iteration:3d}  f = {rec.f:.6e}  |proj grad| = {rec.projected_gradient:.3e}  "
                        f"{rec.wall_time:6.1f} s  {vals}")
                    if rows is not None:
                        rows.writerow([k, rec.iteration, f"{rec.f:.10g}", f"{rec.projected_gradient:.6g}",
                                       f"{rec.wall_time:.3f}",
                                       " ".join(f"{n}={v:.10g}" for n, v in rec.values.items())])
                        f.flush()
                    if guard is not None:
                        guard.progress(stage=k, iteration=rec.iteration, objective=rec.f, current=rec.values)

            stage_data = stage.select(data)
            result = _fit(k, stage, stage_data, current, bounds, args, progress, log)
            # refine until the model's steps no longer move the parameters beyond a fraction of
            # their standard deviation -- unless the data agree better with the coarser steps
            # (data made by the model itself with those steps)
            for level in range(1, args.model_refinements + 1):
                ratio, name = _discretisation_shift(result)
                if ratio is None or ratio <= args.max_discretisation_shift:
                    break
                log(f"  the model's discretisation moves {name} by {ratio:.2g} of its standard deviation "
                    f"(above {args.max_discretisation_shift:g}): every step halved, fitted again")
                refined = [dataclasses.replace(d, test=d.test.refined()) for d in stage_data]
                trial = _fit(k, stage, refined, result.parameter_set.parameters(result.identification.values),
                             bounds, args, progress, log, start_evaluation=result.start_evaluation)
                if not (trial.identification.converged and trial.identification.f < result.identification.f):
                    log(f"  halved steps: f {result.identification.f:.4g} -> {trial.identification.f:.4g}; the data "
                        "agree with the coarser steps (made by the model with them?): those kept")
                    break
                first, last = result.identification, trial.identification
                # the stage's record: from its first start, every iteration and evaluation counted
                combined = dataclasses.replace(last, start=first.start, f_start=first.f_start,
                                               iterations=first.iterations + last.iterations,
                                               evaluations=first.evaluations + last.evaluations,
                                               history=first.history + last.history,
                                               wall_time=first.wall_time + last.wall_time,
                                               cpu_time=first.cpu_time + last.cpu_time)
                result = dataclasses.replace(trial, identification=combined, refinements=level)
                swap = {id(old): new for old, new in zip(stage_data, refined)}
                data = [swap.get(id(d), d) for d in data]
                stage_data = refined
            results.append(result)
            current = result.parameter_set.parameters(result.identification.values)
            if out is not None:   # the best point so far, written as soon as it is known
                _write_result(out, current, polar or polar_form(start), results, k, len(stages))
            _log_analysis(result.analysis, args, log)
    finally:
        if rows is not None:
            f.close()
    return current, results



def _fit(k, stage, data, current, bounds, args, progress, log, start_evaluation=None):
    """One fit of a stage's parameters from `current`, its verdict, the discretisation
    estimate and the error analysis (4.5) at the best point: a StageResult."""
    pset = ParameterSet.for_stage(stage.params, current, bounds)
    objective = Objective(data, pset, sensitivity=args.sensitivity, processes=args.processes)
    log(f"stage {k}: {len(pset.names)} parameters {', '.join(pset.names)} "
        f"({args.method}, {args.sensitivity} sensitivities, {objective.n_data} data points of "
        f"{'all tests' if stage.kinds is None else ', '.join(stage.kinds)}; model steps "
        + ", ".join(str(d.test.n_steps) for d in data) + ")")
    try:
        if start_evaluation is None:
            start_evaluation = objective.evaluate(pset.start, jacobian=False)
        res = identify(objective, method=args.method, max_iterations=args.max_iterations, progress=progress)
        best = res.best
        # a parameter at an active bound is held fixed in the error analysis: the linearised
        # statistics of 4.5 assume an interior optimum
        tol = 1e-3 * pset.scale   # closer than 0.1 % of the parameter's scale
        at_bound = [n for n, v, lo, hi, t in zip(pset.names, res.values, pset.lower, pset.upper, tol)
                    if v - lo <= t or hi - v <= t]
        free = [i for i, n in enumerate(pset.names) if n not in at_bound]
        if at_bound:
            log(f"  at a bound (held fixed in the error analysis): {', '.join(at_bound)}")
        log(f"stage {k}: {'converged' if res.converged else 'NOT converged'} ({res.message}); "
            f"f {res.f_start:.4g} -> {res.f:.4g} in {res.iterations} iterations, {res.evaluations} "
            f"evaluations, {res.wall_time:.1f} s")
        discretisation = analysis = None
        if not best.failures:
            discretisation = objective.discretisation_error(
                best.s, jacobian=best.raw_jacobian[:, free] if res.converged and free else None,
                names=[pset.names[i] for i in free])
            log("  " + describe_discretisation(discretisation, res.f))
        if not res.converged:
            log("  no error analysis: the statistics of 4.5 hold at an optimum only")
        elif not free:
            log("  no error analysis: every parameter is at a bound")
        else:
            try:
                blocks = [n for _, _, n in objective.blocks] if args.serial_correlation else None
                analysis = analyse([pset.names[i] for i in free], res.values[free], best.raw_jacobian[:, free],
                                   best.raw_residual, sigma=objective.scatter,
                                   sqrt_weights=objective.sqrt_weights, alpha=1.0 - args.confidence,
                                   serial_blocks=blocks)
            except ValueError as error:
                log(f"  no {error}")
    finally:
        objective.close()
    return StageResult(pset.names, res, analysis, objective, start_evaluation, at_bound, discretisation, pset)


def _discretisation_shift(result):
    """The largest shift of a parameter by the model's discretisation, in units of its
    standard deviation, and its name; (None, None) without an error analysis."""
    est, analysis = result.discretisation, result.analysis
    if analysis is None or est is None or "parameter_shift" not in est:
        return None, None
    ratios = {n: abs(est["parameter_shift"][n]) / sd for n, sd in zip(analysis.names, analysis.std)
              if np.isfinite(sd) and n in est["parameter_shift"]}
    ratios = {n: (r if np.isfinite(r) else np.inf) for n, r in ratios.items()}
    if not ratios:
        return None, None
    name = max(ratios, key=ratios.get)
    return ratios[name], name


def _log_analysis(analysis, args, log):
    if analysis is None:
        return
    log(f"  s0 = {analysis.s0:.3g} (4.27), condition number {analysis.condition_number:.3g}")
    lo, hi = analysis.intervals(joint=True)
    for i, n in enumerate(analysis.names):
        v = analysis.values[i]
        if not np.isfinite(analysis.std[i]):
            log(f"  {n:14s} {v:+.6g}  not determined by the data (rank-deficient sensitivities)")
            continue
        log(f"  {n:14s} {v:+.6g}  std {analysis.std[i]:.3g} "
            f"({100 * analysis.std[i] / max(abs(v), 1e-300):.2g} %)  "
            f"{100 * args.confidence:g} % (4.30) [{lo[i]:+.5g}, {hi[i]:+.5g}]")


def describe_discretisation(estimate, f):
    """One line: the model's discretisation error beside the objective f."""
    if estimate is None:
        return "model discretisation error: not estimated (the model fails with the steps halved)"
    label, q, size = max(((t, q, v) for t, qs in estimate["largest"].items() for q, v in qs.items()),
                         key=lambda item: item[2])
    line = (f"model discretisation error (steps halved, Richardson): alone it would make f = {estimate['f']:.3g} "
            f"(the fit's f = {f:.3g}); largest {100 * size:.2g} % of phi_0 ({label}, {q})")
    if "rms_over_scatter" in estimate:
        line += f"; RMS {estimate['rms_over_scatter']:.2g} of the data's scatter"
        if estimate["rms_over_scatter"] > 0.3:
            line += ": NOT negligible, raise --min-model-steps"
    return line


def write_outputs(result, data, args, reference=None):
    """Figures and the summary dict (the caller writes summary.json)."""
    final, stages = result
    out = args.out
    steps = {d.label: d.test.n_steps for st in stages for d in st.objective.data}   # as the last fit ran them
    summary = dict(method=args.method, sensitivity=args.sensitivity, processes=args.processes,
                   tests=[dict(label=d.label, source=d.source, points=len(d.x), quantities=list(d.y),
                               normalisation=d.normalisation, model_steps=steps.get(d.label, d.test.n_steps))
                          for d in data],
                   stages=[])
    for st in stages:
        r = st.identification
        entry = dict(parameters=list(st.names), tests=[d.label for d in st.objective.data],
                     start=dict(zip(st.names, map(float, r.start))),
                     identified=r.values_dict(), f_start=r.f_start, f=r.f, converged=r.converged,
                     message=r.message, iterations=r.iterations, evaluations=r.evaluations,
                     wall_time_s=r.wall_time, terms=st.objective.terms(r.best),
                     model_stopped=r.best.failures, at_bound=st.at_bound,
                     discretisation_error=st.discretisation, model_refinements=st.refinements,
                     error_analysis=st.analysis.to_dict() if st.analysis is not None else None)
        if reference is not None:
            entry["reference"] = {n: float(getattr(reference, n)) for n in st.names}
            entry["relative_error"] = {n: float(v / getattr(reference, n) - 1.0) if getattr(reference, n) else float(v)
                                       for n, v in r.values_dict().items()}
        summary["stages"].append(entry)
    last = stages[-1].identification
    summary.update(converged=all(s.identification.converged for s in stages), f_start=stages[0].identification.f_start,
                   f=last.f, iterations=sum(s.identification.iterations for s in stages),
                   evaluations=sum(s.identification.evaluations for s in stages),
                   identified_parameters_file=os.path.join(out, "identified_parameters.json"))
    _plot_fit(stages, data, os.path.join(out, "fit.png"))
    _plot_objective(stages, os.path.join(out, "objective.png"))
    if stages[-1].analysis is not None:
        plot_correlation(stages[-1].analysis, os.path.join(out, "correlation.png"))
    return summary


def _plot_fit(stages, data, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    panels = [(d, q) for d in data for q in d.y]
    ncol = min(4, len(panels))
    nrow = (len(panels) + ncol - 1) // ncol
    fig, axes = plt.subplots(nrow, ncol, figsize=(3.6 * ncol, 3.0 * nrow), squeeze=False)
    for ax, (d, q) in zip(axes.flat, panels):
        # the start of the first stage that fits this test, the result of the last one
        fits = [st for st in stages if d.label in st.start_evaluation.curves]
        if not fits:
            continue
        first, last = fits[0].start_evaluation, fits[-1].identification.best
        scale = 1e-3 if q.startswith("axial_stress") else 1.0
        xs = 1e-3 if d.test.abscissa == "pressure" else 1.0
        ax.plot(d.x * xs, d.y[q] * scale, "k.", ms=3, label="data")
        for ev, style, lab in ((first, "b--", "start"), (last, "r-", "identified")):
            c = ev.curves[d.label]
            ax.plot(np.asarray(c["x"]) * xs, np.asarray(c[q]) * scale, style, lw=1, label=lab)
        ax.set_title(d.label, fontsize=8)
        ax.set_xlabel("pressure [kPa]" if d.test.abscissa == "pressure" else "axial strain [-]", fontsize=8)
        ax.set_ylabel(q + (" [kPa]" if scale != 1 else " [-]"), fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(True, alpha=0.3)
    for ax in list(axes.flat)[len(panels):]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _plot_objective(stages, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(5, 3.5))
    offset = 0
    for k, st in enumerate(stages, start=1):
        h = st.identification.history
        ax.semilogy([offset + r.iteration for r in h], [r.f for r in h], "o-", ms=3, label=f"stage {k}")
        offset += h[-1].iteration if h else 0
    ax.set_xlabel("SQP iteration")
    ax.set_ylabel("objective f (4.18)")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
