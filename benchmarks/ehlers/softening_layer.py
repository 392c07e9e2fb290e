#!/usr/bin/env python3
"""Regularisation in the softening shear layer (the one-dimensional check).

The infinitely long layer of cosserat_fenicsx.scenes.softening_layer (de Borst's
localisation benchmark) with the Ehlers model, sheared under the confining pressure. Three
models on the same meshes:

* micropolar, k_sigma = 0: skew strain and curvature elastic, plastic flow only in the
  symmetric strain -> the band thickness H should converge under refinement;
* micropolar, k_sigma = 10 (the spec's reference set): plastic skew strain relaxes the
  coupling of phi to the displacement -> H is expected to follow h (docs/results/ehlers_biaxial.md);
* classical (micropolar terms off): H follows h.

The layer is cheap enough to refine to h = l_c / 2 and below, which the biaxial specimen
is not. Writes --out/softening_layer.csv (a row per run, appended as runs finish),
softening_layer.json (curves and strain profiles) and softening_layer.png.

    python3 benchmarks/ehlers/softening_layer.py --out results/softening_layer
    python3 benchmarks/ehlers/softening_layer.py --models k_sigma_0 --cell-sizes 4e-4 2e-4 1e-4 5e-5
"""
import argparse
import csv
import json
import os
import time

import numpy as np

from cosserat_fenicsx.scenes.softening_layer import LayerSettings, SofteningLayer
from cosserat_fenicsx.stepping import LoadSteppingError

MODELS = {"k_sigma_0": dict(micropolar=True, k_sigma=0.0),
          "k_sigma_10": dict(micropolar=True, k_sigma=10.0),
          "classical": dict(micropolar=False),
          "micropolar": dict(micropolar=True)}    # k_sigma, k_mu given per run (sweeps)
COLUMNS = ["model", "l_c", "eta", "k_sigma", "k_mu", "cell_size", "h_over_l_c", "peak_tau", "shear_at_peak", "final_tau", "final_shear",
           "band_thickness", "band_amplitude", "plastic_fraction_final", "completed", "steps", "wall_time"]


def run_case(args, model, h, l_c=None, eta=None, k_sigma=None, k_mu=None):
    m = MODELS[model]
    l_c = args.l_c if l_c is None else l_c
    eta = args.eta if eta is None else eta
    k_sigma = m.get("k_sigma", 0.0) if k_sigma is None else k_sigma
    k_mu = args.k_mu if k_mu is None else k_mu
    material = dict(l_c=l_c, k_sigma=k_sigma, k_mu=k_mu) if m["micropolar"] else {}
    s = LayerSettings(height=args.height, cell_size=h, shear=args.shear, steps=args.steps,
                      micropolar=m["micropolar"], weak_size=args.weak_size,
                      weak_beta_factor=args.weak_factor, eta=eta, material=material)
    start = time.perf_counter()
    layer = SofteningLayer(s)
    completed = True
    try:
        layer.run()
    except LoadSteppingError as error:
        completed = False
        print(f"  stopped: {error}", flush=True)
    tau = np.array([r["tau"] for r in layer.history])
    shear = np.array([r["shear"] for r in layer.history])
    i = int(np.argmax(tau))
    band = layer.band()
    lam = layer.state[:, layer.materials[0].state_index["Lambda"]] > 0
    return {"model": model, "l_c": l_c if m["micropolar"] else 0.0, "eta": eta,
            "k_sigma": k_sigma if m["micropolar"] else 0.0, "k_mu": k_mu if m["micropolar"] else 0.0,
            "cell_size": h,
            "h_over_l_c": h / l_c, "peak_tau": tau[i], "shear_at_peak": shear[i], "final_tau": tau[-1], "final_shear": shear[-1],
            "band_thickness": band.thickness, "band_amplitude": band.amplitude,
            "plastic_fraction_final": float(lam.mean()), "completed": completed, "steps": len(tau),
            "wall_time": time.perf_counter() - start,
            "curve": np.column_stack([shear, tau]).tolist(),
            "profile": np.column_stack([layer.y, layer.strain_norm()]).tolist()}


def plot(results, out):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(1, 4, figsize=(20, 4.5))
    styles = {"k_sigma_0": "-", "k_sigma_10": ":", "classical": "--", "micropolar": "-."}
    for r in results:
        if r["model"] == "micropolar":
            continue     # the k_sigma / k_mu sweeps: table only
        c, p = np.array(r["curve"]), np.array(r["profile"])
        label = f"{r['model']} l_c={r['l_c'] * 1e3:g} eta={r['eta']:g} s h={r['cell_size'] * 1e3:.3g} mm"
        ax[0].plot(c[:, 0] * 100, c[:, 1] / 1e3, styles[r["model"]], label=label)
        ax[1].plot(p[:, 1], p[:, 0] * 1e3, styles[r["model"]], label=label)
    ax[0].set_xlabel("shear U/L [%]"); ax[0].set_ylabel("shear stress tau [kPa]"); ax[0].legend(fontsize=6)
    ax[1].set_xlabel("strain norm |eps| at the end"); ax[1].set_ylabel("y [mm]")
    base = results[0]["eta"] if results else None
    for model, marker in (("k_sigma_0", "o-"), ("k_sigma_10", "^:"), ("classical", "s--")):
        rs = sorted([r for r in results if r["model"] == model and r["eta"] == base
                     and r["l_c"] in (0.0, results[0]["l_c"])], key=lambda r: r["cell_size"])
        if rs:
            ax[2].loglog([r["cell_size"] * 1e3 for r in rs], [r["band_thickness"] * 1e3 for r in rs], marker,
                         label=model)
    ax[2].set_xlabel("element size h [mm]"); ax[2].set_ylabel("band thickness H [mm]"); ax[2].legend()
    rs = sorted({r["l_c"]: r for r in results if r["model"] == "k_sigma_0" and r["eta"] == base}.values(),
                key=lambda r: r["l_c"])
    ax[3].plot([r["l_c"] * 1e3 for r in rs], [r["band_thickness"] * 1e3 for r in rs], "o-")
    ax[3].set_xlabel("l_c [mm]"); ax[3].set_ylabel("band thickness H [mm] (k_sigma = 0, finest h)")
    ax[3].set_xlim(left=0); ax[3].set_ylim(bottom=0)
    fig.tight_layout(); fig.savefig(os.path.join(out, "softening_layer.png"), dpi=120)
    plt.close(fig)


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", default="results/softening_layer")
    p.add_argument("--models", nargs="+", choices=["k_sigma_0", "k_sigma_10", "classical"],
                   default=["k_sigma_0", "k_sigma_10", "classical"])
    p.add_argument("--cell-sizes", type=float, nargs="+", default=[4e-4, 2e-4, 1e-4, 5e-5])
    p.add_argument("--l-c", type=float, default=1e-4, help="internal length [m] (default 0.1 mm)")
    p.add_argument("--k-mu", type=float, default=0.0)
    p.add_argument("--height", type=float, default=0.04, help="layer height L [m] (default 40 mm)")
    p.add_argument("--weak-size", type=float, default=1e-3)
    p.add_argument("--weak-factor", type=float, default=0.9)
    p.add_argument("--shear", type=float, default=0.3, help="U_end / L (default 0.3)")
    p.add_argument("--steps", type=int, default=150)
    p.add_argument("--eta", type=float, default=0.1)
    p.add_argument("--l-c-sweep", type=float, nargs="*", default=[5e-5, 2e-4],
                   help="further l_c [m] for k_sigma = 0 on --sweep-cell-size (H against l_c)")
    p.add_argument("--eta-sweep", type=float, nargs="*", default=[0.01],
                   help="further eta [s] for k_sigma = 0 and classical on --sweep-cell-size")
    p.add_argument("--sweep-cell-size", type=float, default=2.5e-5)
    p.add_argument("--k-sigma-sweep", type=float, nargs="*", default=[0.1, 1.0, 2.0, 3.0],
                   help="further k_sigma, each on --k-sweep-cell-sizes (where the regularisation stops)")
    p.add_argument("--k-mu-sweep", type=float, nargs="*", default=[5e7],
                   help="further k_mu [1/m^2] with k_sigma = 0, each on --k-sweep-cell-sizes (plastic curvature)")
    p.add_argument("--k-sweep-cell-sizes", type=float, nargs="*", default=[2e-4, 1e-4, 5e-5])
    p.add_argument("--replot", action="store_true", help="redraw the figure from --out/softening_layer.json")
    args = p.parse_args()
    if args.replot:
        with open(os.path.join(args.out, "softening_layer.json")) as f:
            plot(json.load(f)["runs"], args.out)
        return
    os.makedirs(args.out, exist_ok=True)
    path = os.path.join(args.out, "softening_layer.csv")
    with open(path, "w", newline="") as f:
        csv.writer(f).writerow(COLUMNS)
    cases = [dict(model=model, h=h) for model in args.models for h in args.cell_sizes]
    cases += [dict(model="k_sigma_0", h=args.sweep_cell_size, l_c=l_c) for l_c in args.l_c_sweep]
    cases += [dict(model=model, h=args.sweep_cell_size, eta=eta) for eta in args.eta_sweep
              for model in ("k_sigma_0", "classical")]
    cases += [dict(model="micropolar", h=h, k_sigma=k) for k in args.k_sigma_sweep for h in args.k_sweep_cell_sizes]
    cases += [dict(model="micropolar", h=h, k_mu=k) for k in args.k_mu_sweep for h in args.k_sweep_cell_sizes]
    results = []
    for case in cases:
        r = run_case(args, **case)
        results.append(r)
        with open(path, "a", newline="") as f:
            csv.writer(f).writerow([r[c] for c in COLUMNS])
        print(" ".join(f"{c}={r[c]:.4g}" if isinstance(r[c], float) else f"{c}={r[c]}" for c in COLUMNS),
              flush=True)
        with open(os.path.join(args.out, "softening_layer.json"), "w") as f:
            json.dump({"settings": vars(args), "runs": results}, f, indent=1, default=float)
        plot(results, args.out)


if __name__ == "__main__":
    main()
