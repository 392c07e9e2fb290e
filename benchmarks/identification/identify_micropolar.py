#!/usr/bin/env python3
"""Re-identification of the micropolar parameters from a biaxial FE run (thesis 004, section
6.2.3).

Forward model phi(s): the FE biaxial test of cosserat_fenicsx.scenes.biaxial (the scene of
demos/biaxial.py, P2/P1, serial, one run at a time) with the micropolar parameters s (any of
l_c [m], mu_c [Pa], k_sigma [-], k_mu [1/m^2]) replaced. It returns

* sigma_11 [Pa], the platen reaction / width, at N_sigma = steps fixed axial strains of phase 2
  (k * axial_strain / steps, k = 1..steps; pre- and post-peak; linear interpolation when the
  stepper cut steps, so that every run is compared at the same strains);
* H [m], the band thickness of section 4.4 (standard deviation of the bell fitted to |eps|,
  eq 4.22) at N_H post-peak axial strains (--h-strains; default 5, 6, 7, 8 %; a single 8 % is
  the N_H = 1 of section 6.2.4). The final one is the fit at the end of the run, the others
  are interpolated in the fits made after every step from half the platen travel on. The raw
  fit is used, also where `band_verdict` would not call it a band, so that f stays continuous.

Objective (6.10): f = 1/(N_sigma sigma_0^2) sum (sigma_11(s) - sigma~)^2
+ 1/(N_H H_0^2) sum (H(s) - H~)^2, with sigma_0 = |peak of the reference curve| and
H_0 = final H of the reference run (the data's own scales, as Table 6.2 normalises).

Sensitivities by finite differences (section 5.1): central at the reference (correlation
analysis, (6.11) / (4.31) via identification.error_analysis), forward inside SLSQP (P + 1 FE
runs per gradient). Steps: 2 % (--fd-step) of l_c and mu_c, 10 % of k_sigma (its effect on H
is weaker); at a value 0 one-sided, k_sigma 0.1 and k_mu 1e-3 / (2 l_c^2) (the response to
plastic curvature is steep: 0.02 / (2 l_c^2) already thins the band by 17 %). With 80 steps
the differences are smooth (l_c -2, 0, +1, +2, +4 %: H = 4.415, 4.475, 4.506, 4.537,
4.597 mm); with 40 steps the cut-backs at the band snap differ between neighbouring runs
and the 1 % differences scatter by 20-30 %.

Reference set, and why not the thesis' Table 6.6 (l_c = 3 mm, k_sigma = 10): in this
project's reading (docs/results/regularisation.md) a band of l_c-controlled thickness forms only for
k_sigma <= ~1; with k_sigma = 10 the band collapses to the mesh, and H would measure the
element size, not l_c. The reference here is the regularised set of the biaxial
regularisation study (25 mm x 50 mm specimen, 5 mm weak corner x 0.8, eta = 0.1 s, 8 % axial
strain in 80 steps) with l_c = 0.2 mm, k_sigma = 0.5 (inside the regularising range, so that
it can move both ways), k_mu = 0, mu_c = mu = 91 MPa, on a fixed mesh h = 2.5 mm (3-13 s per
run). H depends on l_c there: 2.93 / 4.43 / 6.00 / 8.17 mm for l_c = 0.1 / 0.2 / 0.3 /
0.5 mm (40 steps). h <= l_c / 2 = 0.1 mm is out of reach (250 x 500 cells); what resolves
the band is H / h (the band is ~22 l_c wide): H = 4.43 / 4.34 / 4.32 mm at h = 2.5 / 1.67 /
1.25 mm (32-37 s per run on the finer meshes). The thesis' kind of disturbance is kept:
start l_c x 2.5 = 0.5 mm and k_sigma = 0.

Outputs in --out (default out/identify_micropolar): runs.jsonl (every FE run, appended as it
finishes; a rerun with the same settings reuses them: then the cost reported is the one
measured when each run was made), summary.json, identify_micropolar.png (curves reference /
start / final, H history, objective and parameters against iteration) and correlation.png.

    python3 benchmarks/identification/identify_micropolar.py                   # 112 FE runs, 13 min serial
    python3 benchmarks/identification/identify_micropolar.py --h-strains 0.08 --out out/identify_micropolar_nh1
    python3 benchmarks/identification/identify_micropolar.py --cell-size 1.25e-3 --skip-identification \
        --correlate mu_c l_c --out out/identify_micropolar_h125    # 8 runs of 2-3 min
    python3 benchmarks/identification/identify_micropolar.py --probe l_c=5e-4 k_sigma=0   # one forward run

Measured (h = 2.5 mm, load average ~2 on 2 cores): with N_H = 4, (l_c, k_sigma) are
recovered from (0.5 mm, 0) to -0.003 % and -0.06 % in 24 SLSQP iterations (101 FE runs,
11 min); with N_H = 1 SLSQP stops after 19 iterations at +1.6 % and +20 % (the pair is
correlated +0.9992 with N_H = 1, +0.978 with N_H = 4). corr(mu_c, l_c) = -0.994 / -0.999
(Table 6.7: -0.998): the response depends on mu_c l_c^2 only (4 mu_c with l_c / 2 gives the
same curve to 4e-4 sigma_0, l_c / 2 alone changes it by 10 %).
"""
import argparse
import json
import math
import os
import time

import numpy as np

from cosserat_fenicsx.identification.error_analysis import analyse, plot_correlation

MICROPOLAR = ("l_c", "mu_c", "k_sigma", "k_mu")


# --- forward model ----------------------------------------------------------------------
def forward_run(args, params):
    """One FE biaxial run with the micropolar parameters `params` (dict name -> value).

    Returns a dict: stress (N_sigma,) [Pa] at the fixed strains `strain_grid(args)`,
    H [m] (raw fit of eq 4.22, nan when no fit), the band verdict, inclination, run
    statistics (steps, cuts, completed, wall and CPU seconds)."""
    from mpi4py import MPI
    from cosserat_fenicsx.scenes.biaxial import BiaxialSettings, BiaxialTest
    from cosserat_fenicsx.shear_band import band_verdict
    from cosserat_fenicsx.stepping import LoadSteppingError
    s = BiaxialSettings(width=args.width, height=args.height, cell_size=args.cell_size,
                        axial_strain=args.axial_strain, steps=args.steps, weak_size=args.weak_size,
                        weak_beta_factor=args.weak_factor, eta=args.eta, material=dict(params))
    wall, cpu = time.perf_counter(), time.process_time()
    test = BiaxialTest(MPI.COMM_SELF, s, verbose=False)
    band_history = []     # (axial strain, raw H) from half the platen travel on (post-peak)

    def on_step(row):
        if row["phase"] == 2 and -row["axial_strain"] >= 0.5 * args.axial_strain - 1e-12:
            try:
                band_history.append((-row["axial_strain"], test.band().thickness))
            except ValueError:
                band_history.append((-row["axial_strain"], math.nan))

    stopped = ""
    try:
        test.run(on_step)
    except LoadSteppingError as error:
        stopped = str(error)
    rows = [r for r in test.history if r["phase"] >= 1]
    strain = np.array([-r["axial_strain"] for r in rows if r["phase"] == 2])
    stress = np.array([r["vertical_stress"] for r in rows if r["phase"] == 2])
    grid = strain_grid(args)
    # held at the last converged value beyond a stopped run (flagged by `completed`)
    on_grid = np.interp(grid, np.concatenate([[0.0], strain]),
                        np.concatenate([[[r for r in rows if r["phase"] == 1][-1]["vertical_stress"]], stress]))
    try:
        fit = test.band()
        H, incl, verdict = fit.thickness, fit.inclination_deg, band_verdict(fit, args.cell_size, args.width)
    except ValueError as error:
        H, incl, verdict = math.nan, math.nan, (False, str(error))
    return {"params": {k: float(v) for k, v in params.items()}, "stress": on_grid.tolist(), "H": float(H),
            "inclination_deg": float(incl), "band": bool(verdict[0]), "band_reason": verdict[1],
            "H_history": [[float(a), float(b)] for a, b in band_history],
            "plastic_fraction": float(rows[-1]["plastic_fraction"]), "completed": not stopped,
            "stopped": stopped, "steps": len(strain), "cuts": int(rows[-1]["cuts"]),
            "wall": time.perf_counter() - wall, "cpu": time.process_time() - cpu}


def strain_grid(args):
    """The N_sigma fixed axial strains (magnitudes) of the stress data [-]."""
    return args.axial_strain * np.arange(1, args.steps + 1) / args.steps


class Model:
    """phi(s) with a cache: identical parameter sets run once (also across reruns, through
    runs.jsonl). `used` holds every distinct run this identification needed (computed now
    or read back), so that its cost is reported the same either way."""

    def __init__(self, args, base):
        self.args, self.base = args, dict(base)
        self.path = os.path.join(args.out, "runs.jsonl")
        self.cache, self.used, self.computed = {}, {}, 0
        self.phase = {}     # the runs of one phase (correlation, identification), see cost()
        self.settings = {k: getattr(args, k) for k in
                         ("width", "height", "cell_size", "axial_strain", "steps", "weak_size", "weak_factor", "eta")}
        self.settings["record"] = 2     # records with the post-peak H history
        if os.path.exists(self.path):
            for line in open(self.path):
                rec = json.loads(line)
                if rec.get("settings") == self.settings:
                    self.cache[self.key(rec["params"])] = rec

    @property
    def runs(self):
        return len(self.used)

    @property
    def wall(self):
        return sum(r["wall"] for r in self.used.values())

    @property
    def cpu(self):
        return sum(r["cpu"] for r in self.used.values())

    def cost(self):
        """FE runs of the current phase and their wall / CPU seconds; starts a new phase."""
        out = {"fe_runs": len(self.phase), "fe_wall_s": sum(r["wall"] for r in self.phase.values()),
               "fe_cpu_s": sum(r["cpu"] for r in self.phase.values())}
        self.phase = {}
        return out

    @staticmethod
    def key(params):
        return tuple(sorted((k, float(f"{v:.12g}")) for k, v in params.items()))

    def __call__(self, **changes):
        params = dict(self.base, **changes)
        k = self.key(params)
        if k in self.cache:
            self.used[k] = self.phase[k] = self.cache[k]
            return self.cache[k]
        rec = forward_run(self.args, params)
        rec["settings"] = self.settings
        self.cache[k] = self.used[k] = self.phase[k] = rec
        self.computed += 1
        with open(self.path, "a") as f:
            f.write(json.dumps(rec) + "\n")
        print(f"    FE run {self.runs} (new {self.computed}): " + ", ".join(f"{n}={v:.5g}" for n, v in params.items())
              + f" -> peak {min(rec['stress']) / 1e3:.2f} kPa, H = {rec['H'] * 1e3:.3f} mm"
              + f" (band {'yes' if rec['band'] else 'no: ' + rec['band_reason'][:60]}), {rec['steps']} steps,"
              + f" {rec['cuts']} cuts, {rec['wall']:.0f} s{'' if rec['completed'] else ', STOPPED'}", flush=True)
        return rec


H_STRAINS = None   # axial strains of the N_H thickness data, set in main (--h-strains)


def band_data(rec):
    """H [m] at the N_H strains H_STRAINS: the final fit for the final strain, otherwise
    linear interpolation in the post-peak history (the stepper may have cut steps)."""
    hist = np.array(rec["H_history"]) if rec["H_history"] else np.zeros((0, 2))
    out = []
    for e in H_STRAINS:
        if abs(e - max(H_STRAINS)) < 1e-12 and rec["completed"]:
            out.append(rec["H"])
        else:
            out.append(float(np.interp(e, hist[:, 0], hist[:, 1])) if len(hist) else math.nan)
    return out


def data_vector(rec):
    """phi = (sigma_11 at the N_sigma fixed strains..., H at the N_H strains). A state where
    the band fit failed counts as H = 0, so that f stays finite for SLSQP (flagged in the log
    by the band verdict of the run)."""
    return np.nan_to_num(np.array(rec["stress"] + band_data(rec)), nan=0.0)


def weights(ref):
    """The weights of (6.10): 1/(N_sigma sigma_0^2) per stress point, 1/(N_H H_0^2) per H,
    sigma_0 = |peak| and H_0 = final H of the reference."""
    n, nh = len(ref["stress"]), len(H_STRAINS)
    sigma0 = abs(min(ref["stress"]))
    return np.concatenate([np.full(n, 1.0 / (n * sigma0 ** 2)), np.full(nh, 1.0 / (nh * ref["H"] ** 2))]), sigma0


def fd_step(name, value, args):
    """Finite-difference step of parameter `name` at `value`: relative, or absolute at 0."""
    if value != 0.0:
        return args.fd_rel[name] * abs(value)
    return args.zero_steps[name]


def jacobian(model, names, point, args, central):
    """d phi / d s_k by central (or forward) differences at `point` (dict). Columns for a
    parameter at 0 are forward (one-sided: the parameter cannot be negative)."""
    base = data_vector(model(**point)) if not central or any(point[n] == 0 for n in names) else None
    cols, steps = [], {}
    for n in names:
        h = fd_step(n, point[n], args)
        steps[n] = h
        plus = data_vector(model(**dict(point, **{n: point[n] + h})))
        if central and point[n] - h > 0:
            minus = data_vector(model(**dict(point, **{n: point[n] - h})))
            cols.append((plus - minus) / (2 * h))
        else:
            cols.append((plus - base) / h)
    return np.array(cols).T, steps


# --- identification ---------------------------------------------------------------------
def parse_assignments(items):
    out = {}
    for item in items or []:
        name, _, value = item.partition("=")
        if name not in MICROPOLAR:
            raise SystemExit(f"unknown micropolar parameter {name!r} (one of {MICROPOLAR})")
        out[name] = float(value)
    return out


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", default="out/identify_micropolar")
    p.add_argument("--width", type=float, default=0.025)
    p.add_argument("--height", type=float, default=0.05)
    p.add_argument("--cell-size", type=float, default=2.5e-3)
    p.add_argument("--axial-strain", type=float, default=0.08)
    p.add_argument("--steps", type=int, default=80,
                   help="load steps of phase 2 = N_sigma (default 80: with 40 the cut-backs at the band snap "
                        "differ between neighbouring parameter sets and make the differences noisy)")
    p.add_argument("--weak-size", type=float, default=5e-3)
    p.add_argument("--weak-factor", type=float, default=0.8)
    p.add_argument("--eta", type=float, default=0.1)
    p.add_argument("--reference", nargs="*", default=["l_c=2e-4", "k_sigma=0.5", "k_mu=0"],
                   help="reference micropolar set, name=value (mu_c defaults to mu)")
    p.add_argument("--start", nargs="*", default=["l_c=5e-4", "k_sigma=0"], help="disturbed start, name=value")
    p.add_argument("--identify", nargs="*", default=["l_c", "k_sigma"])
    p.add_argument("--bounds", nargs="*", default=["l_c=5e-5:8e-4", "k_sigma=0:1"],
                   help="name=low:high of the identified parameters")
    p.add_argument("--correlate", nargs="*", default=["mu_c", "l_c", "k_sigma", "k_mu"])
    p.add_argument("--fd-step", type=float, default=0.02,
                   help="relative finite-difference step of l_c and mu_c (default 0.02); k_sigma gets 5x it")
    p.add_argument("--max-iter", type=int, default=25)
    p.add_argument("--ftol", type=float, default=1e-12,
                   help="SLSQP ftol on f (default 1e-12: f is 0 at the reference, a valley floor of 1e-6 is not the end)")
    p.add_argument("--tolerance", type=float, default=0.02,
                   help="relative tolerance of the recovered values (default 0.02)")
    p.add_argument("--h-strains", type=float, nargs="*", default=[0.05, 0.06, 0.07, 0.08],
                   help="axial strains of the N_H band thicknesses, post-peak, in [axial_strain / 2, axial_strain] "
                        "(default 0.05 0.06 0.07 0.08; one value = the final state only, N_H = 1 as section 6.2.4)")
    p.add_argument("--skip-correlation", action="store_true")
    p.add_argument("--skip-identification", action="store_true")
    p.add_argument("--probe", nargs="*", help="only run the forward model with these name=value and print")
    args = p.parse_args(argv)
    os.makedirs(args.out, exist_ok=True)
    global H_STRAINS
    H_STRAINS = sorted(args.h_strains) if args.h_strains else [args.axial_strain]
    if min(H_STRAINS) < 0.5 * args.axial_strain or max(H_STRAINS) > args.axial_strain:
        raise SystemExit("--h-strains must lie in [axial_strain / 2, axial_strain] (the recorded post-peak part)")

    from cosserat_fenicsx.materials.ehlers.parameters import hostun
    reference = parse_assignments(args.reference)
    reference.setdefault("mu_c", hostun().mu)
    base = dict(reference)
    model = Model(args, base)
    mu_c = reference["mu_c"]
    l_c = reference["l_c"]
    # relative steps: k_sigma moves H weakly (dH/dk_sigma ~ -0.6 mm), so 5x the step of l_c, mu_c.
    # Absolute steps at 0: k_sigma 5 x fd_step; k_mu 1e-3 / (2 l_c^2) -- the response to
    # plastic curvature is steep (measured: k_mu = 0.02 / (2 l_c^2) already thins the band by 17 %)
    args.fd_rel = {"l_c": args.fd_step, "mu_c": args.fd_step, "k_sigma": 5 * args.fd_step, "k_mu": args.fd_step}
    args.zero_steps = {"k_mu": 1e-3 / (2 * l_c ** 2), "k_sigma": 5 * args.fd_step, "l_c": args.fd_step * l_c,
                       "mu_c": args.fd_step * mu_c}

    if args.probe is not None:
        rec = model(**parse_assignments(args.probe))
        print(json.dumps({k: v for k, v in rec.items() if k != "stress"}, indent=1))
        return

    start_wall, start_cpu = time.perf_counter(), time.process_time()
    print(f"reference {reference}; mesh h = {args.cell_size} m, {args.steps} steps to {args.axial_strain}", flush=True)
    ref = model()
    data = data_vector(ref)
    w, sigma0 = weights(ref)
    H0 = ref["H"]
    print(f"reference: peak {min(ref['stress']) / 1e3:.2f} kPa, H = {H0 * 1e3:.3f} mm, band {ref['band']}", flush=True)
    summary = {"method": "thesis 004 section 6.2.3: objective (6.10), FD sensitivities, SLSQP, correlation (6.11)",
               "settings": model.settings, "reference": reference, "sigma_0": sigma0, "H_0": H0,
               "N_sigma": len(ref["stress"]), "N_H": len(H_STRAINS), "H_strains": H_STRAINS, "fd_step_relative": args.fd_rel,
               "fd_step_at_zero": args.zero_steps, "H_data": band_data(ref)}

    def objective_parts(rec):
        r = data_vector(rec) - data
        ns = len(rec["stress"])
        return float(np.sum(w[:ns] * r[:ns] ** 2)), float(np.sum(w[ns:] * r[ns:] ** 2)), r

    # --- correlation analysis at the reference (6.11) ---
    if not args.skip_correlation:
        names = list(args.correlate)
        J, steps = jacobian(model, names, reference, args, central=True)
        vals = [reference[n] for n in names]
        # At the reference the virtual data are met exactly: residual 0, so the factor s0^2
        # of (4.28) would be 0 and K with it. The residual passed is a unit normalised one,
        # r_n = 1/sqrt(w_n) (every term of (6.10) contributes alike, s0^2 = N/(N-P)); K is then
        # the inverse Fisher matrix of (6.10) times that factor, and the correlation (4.31)
        # does not depend on it. (6.11) itself weights without the 1/N: both are reported.
        ea = analyse(names, vals, J, 1.0 / np.sqrt(w), weights=w)
        ns = len(ref["stress"])
        w611 = np.concatenate([np.full(ns, 1.0 / sigma0 ** 2), np.full(len(data) - ns, 1.0 / H0 ** 2)])
        ea611 = analyse(names, vals, J, 1.0 / np.sqrt(w611), weights=w611)
        # cross-check: (6.11) by hand, inverse of sum w J^T J, in log-scaled columns
        D = np.array([v if v != 0 else 1.0 for v in vals])
        Kd = np.linalg.inv((J * D).T @ (w[:, None] * (J * D)))
        corr_direct = Kd / np.sqrt(np.outer(np.diag(Kd), np.diag(Kd)))
        if not np.allclose(corr_direct, ea.correlation, atol=1e-6):
            print("WARNING: error_analysis correlation differs from the direct (6.11) inverse", flush=True)
        # normalised sensitivities (6.9), and the mu_c / l_c column ratio (a constant factor
        # between them = full correlation, section 6.2.2)
        norm = J * np.array(vals)[None, :] / np.where(data == 0, 1, data)[:, None]
        summary["correlation"] = {"names": names, "fd_steps": steps, "weights_6_10": ea.to_dict(),
                                  "correlation_direct_inverse": corr_direct.tolist(),
                                  "jacobian": J.tolist(),
                                  "weights_6_11": ea611.to_dict(),
                                  "normalised_sensitivities_6_9": {n: norm[:, i].tolist() for i, n in enumerate(names)}}
        plot_correlation(ea, os.path.join(args.out, "correlation.png"),
                         title="correlation (4.31), weights (6.10)")
        print("correlation (4.31) with the (6.10) weights:\n" + "\n".join(
            f"  {n:>8s} " + " ".join(f"{c:+.3f}" for c in ea.correlation[i]) for i, n in enumerate(names)), flush=True)
        if "mu_c" in names and "l_c" in names:
            i, j = names.index("mu_c"), names.index("l_c")
            # in log variables a pure dependence on mu_c l_c^2 gives d/dln l_c = 2 d/dln mu_c
            ratio = norm[:, j] @ norm[:, i] / max(norm[:, i] @ norm[:, i], 1e-300)
            summary["correlation"]["dlnphi_dlnl_c_over_dlnphi_dlnmu_c"] = float(ratio)
            print(f"  least-squares ratio of normalised sensitivities l_c / mu_c: {ratio:.3f} "
                  "(2 if only mu_c l_c^2 mattered)", flush=True)
        # What two-parameter identifications can separate: correlation of each pair with the
        # others held fixed (inverse of the 2 x 2 Fisher block), and the singular values of the
        # weighted Jacobian in relative units (s d phi / d s; k_mu, at 0, per 1/(2 l_c^2)):
        # one large and the rest small = the data carry one combination of the parameters.
        Ds = np.array([v if v != 0 else (1.0 / (2 * l_c ** 2) if n == "k_mu" else 1.0) for n, v in zip(names, vals)])
        Jw = np.sqrt(w)[:, None] * J * Ds
        A = Jw.T @ Jw
        pairs = {}
        for a in range(len(names)):
            for b in range(a + 1, len(names)):
                Kp = np.linalg.inv(A[np.ix_([a, b], [a, b])])
                pairs[f"{names[a]}-{names[b]}"] = float(Kp[0, 1] / math.sqrt(Kp[0, 0] * Kp[1, 1]))
        sv = np.linalg.svd(Jw, compute_uv=False)
        summary["correlation"]["pair_correlations_others_fixed"] = pairs
        summary["correlation"]["singular_values_relative"] = sv.tolist()
        summary["correlation"]["singular_value_units"] = {n: float(d) for n, d in zip(names, Ds)}
        # Beyond the linearisation: if only mu_c l_c^2 mattered, (4 mu_c, l_c / 2) and
        # (mu_c / 4, 2 l_c) would reproduce the reference; l_c / 2 alone shows the scale.
        if "mu_c" in names and "l_c" in names:
            scaling = {}
            for label, ch in (("4mu_c,l_c/2", dict(mu_c=4 * mu_c, l_c=l_c / 2)),
                              ("mu_c/4,2l_c", dict(mu_c=mu_c / 4, l_c=2 * l_c)), ("l_c/2", dict(l_c=l_c / 2))):
                rec = model(**ch)
                d = data_vector(rec) - data
                scaling[label] = {"max_stress_difference_over_sigma0": float(np.abs(d[:ns]).max() / sigma0),
                                  "max_H_difference_over_H0": float(np.abs(d[ns:]).max() / H0)}
                print(f"  {label:>12s}: max |d sigma_11| / sigma_0 = {scaling[label]['max_stress_difference_over_sigma0']:.2e},"
                      f" max |d H| / H_0 = {scaling[label]['max_H_difference_over_H0']:.2e}", flush=True)
            summary["correlation"]["mu_c_l_c_squared_scaling"] = scaling
        print("  pair correlations (others fixed): " + ", ".join(f"{k} {v:+.4f}" for k, v in pairs.items()), flush=True)
        print("  singular values of sqrt(w) J diag(s): " + " ".join(f"{v:.3g}" for v in sv), flush=True)
        summary["correlation"]["cost"] = model.cost()
        with open(os.path.join(args.out, "summary.json"), "w") as f:
            json.dump(summary, f, indent=1)
    model.cost()
    if args.skip_identification:
        return
    # --- re-identification by SLSQP ---
    from scipy.optimize import minimize
    names = list(args.identify)
    start = dict(reference, **parse_assignments(args.start))
    bounds = {}
    for item in args.bounds:
        n, _, rng = item.partition("=")
        lo, hi = (float(v) for v in rng.split(":"))
        bounds[n] = (lo, hi)
    scale = np.array([abs(start[n]) if start[n] != 0 else 1.0 for n in names])   # x = s / scale: O(1)

    def point(x):
        return dict(reference, **{n: float(v) for n, v in zip(names, x * scale)})

    history = []
    evals = {"f": 0, "grad": 0}

    def fun(x):
        evals["f"] += 1
        fs, fh, _ = objective_parts(model(**point(x)))
        return fs + fh

    def grad(x):
        evals["grad"] += 1
        pt = point(x)
        J, _ = jacobian(model, names, pt, args, central=False)
        _, _, r = objective_parts(model(**pt))
        return 2.0 * (J.T @ (w * r)) * scale

    def progress(x):
        pt = point(x)
        fs, fh, _ = objective_parts(model(**pt))
        it = len(history)      # history[0] is the start
        history.append({"iteration": it, **{n: pt[n] for n in names}, "f": fs + fh, "f_stress": fs,
                        "f_band": fh, "fe_runs": model.runs, "wall": time.perf_counter() - start_wall})
        print(f"iter {it:3d}: " + " ".join(f"{n} = {pt[n]:.5g}" for n in names)
              + f"  f = {fs + fh:.4e} (stress {fs:.3e}, band {fh:.3e})  FE runs {model.runs}"
              + f"  wall {time.perf_counter() - start_wall:.0f} s", flush=True)

    x0 = np.array([start[n] for n in names]) / scale
    fs0, fh0, _ = objective_parts(model(**start))
    history.append({"iteration": 0, **{n: start[n] for n in names}, "f": fs0 + fh0, "f_stress": fs0, "f_band": fh0,
                    "fe_runs": model.runs, "wall": time.perf_counter() - start_wall})
    print(f"start  : " + " ".join(f"{n} = {start[n]:.5g}" for n in names) + f"  f = {fs0 + fh0:.4e}", flush=True)
    res = minimize(fun, x0, jac=grad, method="SLSQP", callback=progress,
                   bounds=[(bounds[n][0] / s, bounds[n][1] / s) for n, s in zip(names, scale)],
                   options={"maxiter": args.max_iter, "ftol": args.ftol})
    final = point(res.x)
    final_rec = model(**final)
    # SLSQP's last callback point is not always res.x (a failed line search returns the best
    # point): the returned one is recorded as the last entry, flagged "returned"
    fs, fh, _ = objective_parts(final_rec)
    history.append({"iteration": len(history), "returned": True, **{n: final[n] for n in names}, "f": fs + fh,
                    "f_stress": fs, "f_band": fh, "fe_runs": model.runs, "wall": time.perf_counter() - start_wall})
    errors = {n: (final[n] - reference[n]) / reference[n] if reference[n] != 0 else final[n] - reference[n]
              for n in names}
    recovered = all(abs(e) <= args.tolerance for e in errors.values())
    # error analysis (section 4.5) at the identified point, with the last forward-difference Jacobian
    J, _ = jacobian(model, names, final, args, central=False)
    _, _, r = objective_parts(final_rec)
    ea_final = analyse(names, [final[n] for n in names], J, r, weights=w) if np.any(r != 0) else None
    summary["identification"] = {
        "identified": names, "start": {n: start[n] for n in names}, "bounds": bounds,
        "final": {n: final[n] for n in names}, "relative_error": errors, "tolerance": args.tolerance,
        "recovered_within_tolerance": recovered, "slsqp_message": str(res.message), "slsqp_success": bool(res.success),
        "iterations": int(res.nit), "objective_evaluations": evals["f"], "gradient_evaluations": evals["grad"],
        "history": history, "error_analysis_at_final": ea_final.to_dict() if ea_final else None,
        "cost": model.cost()}
    summary["cost"] = {"fe_runs": model.runs, "fe_runs_computed_in_this_invocation": model.computed,
                       "fe_wall_s": model.wall, "fe_cpu_s": model.cpu,
                       "note": "fe_* sum the distinct FE runs this identification used, as measured when "
                               "each was computed (runs.jsonl); total_* are this invocation only",
                       "mean_wall_per_run_s": model.wall / max(model.runs, 1),
                       "total_wall_s": time.perf_counter() - start_wall,
                       "total_cpu_s": time.process_time() - start_cpu,
                       "load_average": os.getloadavg()}
    summary["curves"] = {"axial_strain": strain_grid(args).tolist(), "reference": ref["stress"],
                         "start": model(**start)["stress"], "final": final_rec["stress"],
                         "H": {"reference": H0, "start": model(**start)["H"], "final": final_rec["H"]},
                         "H_history": {"reference": ref["H_history"], "start": model(**start)["H_history"],
                                       "final": final_rec["H_history"]}}
    with open(os.path.join(args.out, "summary.json"), "w") as f:
        json.dump(summary, f, indent=1)
    ic = summary["identification"]["cost"]
    print(f"identification alone: {ic['fe_runs']} FE runs, {ic['fe_wall_s']:.0f} s wall, {ic['fe_cpu_s']:.0f} s CPU",
          flush=True)
    print(f"SLSQP: {res.message} after {res.nit} iterations; " + ", ".join(
        f"{n}: {final[n]:.5g} (reference {reference[n]:.5g}, error {errors[n]:+.2%})" for n in names)
        + f"; within {args.tolerance:.0%}: {recovered}; {model.runs} FE runs, {model.wall:.0f} s wall, "
        f"{model.cpu:.0f} s CPU", flush=True)
    plot(args, summary)


def plot(args, summary):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    c = summary["curves"]
    e = np.array(c["axial_strain"]) * 100
    fig, ax = plt.subplots(1, 4, figsize=(18, 4))
    for key, style in (("reference", "k-"), ("start", "b--"), ("final", "r:")):
        ax[0].plot(e, -np.array(c[key]) / 1e3, style, label=f"{key}: H = {c['H'][key] * 1e3:.2f} mm")
        hh = np.array(c["H_history"][key])
        ax[3].plot(hh[:, 0] * 100, hh[:, 1] * 1e3, style, label=key)
    ax[0].set_xlabel("axial strain -eps_11 [%]")
    ax[0].set_ylabel("-sigma_11 [kPa]")
    ax[0].legend(fontsize=8)
    ax[3].plot(np.array(summary["H_strains"]) * 100, np.array(summary["H_data"]) * 1e3, "ko", mfc="none",
               label="data (N_H points)")
    ax[3].set_xlabel("axial strain -eps_11 [%]")
    ax[3].set_ylabel("band thickness H (eq 4.22) [mm]")
    ax[3].legend(fontsize=8)
    h = summary["identification"]["history"]
    names = summary["identification"]["identified"]
    ax[1].semilogy([r["iteration"] for r in h], [max(r["f"], 1e-16) for r in h], "ko-", label="f (6.10)")
    ax[1].semilogy([r["iteration"] for r in h], [max(r["f_band"], 1e-16) for r in h], "g.--", label="band term")
    ax[1].semilogy([h[-1]["iteration"]], [max(h[-1]["f"], 1e-16)], "r*", ms=12, label="returned by SLSQP")
    ax[1].set_xlabel("SLSQP iteration (last: the point returned)")
    ax[1].set_ylabel("objective")
    ax[1].legend(fontsize=8)
    ref = summary["reference"]
    for n, style in zip(names, ("r-o", "b-s", "g-^")):
        ax[2].plot([r["iteration"] for r in h], [r[n] / ref[n] if ref[n] else r[n] for r in h], style,
                   label=f"{n} / reference" if ref[n] else f"{n} (reference 0)")
    ax[2].axhline(1.0, color="0.6", lw=0.8)
    ax[2].set_xlabel("SLSQP iteration")
    ax[2].legend(fontsize=8)
    fig.suptitle(f"re-identification of {', '.join(names)} from sigma_11 and H (6.10), h = {args.cell_size * 1e3:g} mm")
    fig.tight_layout()
    fig.savefig(os.path.join(args.out, "identify_micropolar.png"), dpi=120)
    plt.close(fig)


if __name__ == "__main__":
    main()
