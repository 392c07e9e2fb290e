#!/usr/bin/env python3
"""The FEM x DEM defaults chosen by measurement: accuracy and cost of the cell configurations.

    /usr/bin/python3 benchmarks/femdem/femdem_defaults.py --out results/benchmarks/femdem_defaults

Runs the biaxial test (demos/femdem_biaxial.py's scene, femdem_cases.run_case) through its peak
and past it, on a small specimen (--mesh 1x2: 12 Gauss points, a uniform specimen, --particles
100: that packing peaks at 1 % axial strain), in each coupling mode (--modes), once per cell
configuration of CASES: the relaxation (local non-viscous damping against FIRE, their tolerance,
time step and loading ramp), the Newton operator (--tangent) and batched cells or not. Every case
spells out its settings, so the table does not move when the defaults do; the case that is the
current default of CellOptions / FemDemSettings is marked.

Accuracy: the largest difference of the mean stress ratio |s11 - s22| / |s11 + s22| from the
case `reference` (local damping relaxed to an unbalanced-force ratio of 1e-4 after a loading
ramp 4x slower than the default: the quasi-static answer as well as we know it; `fire
reference`, the same with FIRE, says how well) over the steps both reached, before the reference's peak and over all
steps; beside it the scatter of the cell: the standard deviation over --seeds packing seeds of
the stand-alone cell's stress ratio on the homogeneous path (femdem_cases.homogeneous_path, the
path of every Gauss point of this uniform specimen), at the same strains. A configuration is as
accurate as the reference when its difference is below the scatter at every step ("diff /
scatter", the largest ratio, <= 1: verdict "ok"). Cost: wall and CPU seconds per load step (without the
cells' preparation), Newton passes (iterations) and DEM steps (all cells, all passes).

One rank (the machine is shared: CPU seconds are the cleaner measure; the load average before
and after each case is in the table). Writes femdem_defaults.txt, .json and .png in --out; each
case's record as soon as it ends (a rerun reuses them: delete a record to run it again).
"""
import argparse
import json
import os
import time

import numpy as np
from mpi4py import MPI

from benchmarks.femdem.femdem_cases import (homogeneous_path, parse_mesh, run_case, settings, stress_ratio, table,
                                            write_report)

#: label -> (CellOptions overrides, tangent, batched[, Newton settings]). `extra` is
#: demcell.RelaxationOptions (--cell-option); the Newton settings are FemDemSettings' jacobian_lag
#: (1 if left out) or jacobian_refresh; every case names its relaxation method and its lag, so
#: the defaults can move
#: FIRE relaxed to the criterion, without the cap of the default cells (relax_cap)
LOCAL, FIRE = {"method": "local"}, {"method": "fire", "relax_cap": None}
#: the quasi-static answer as well as we know it: relaxed 10x further than the default and
#: loaded 4x more slowly (the cells' ramp at the default rate, 1e-5 per step, is a dynamic load
#: whose error is larger than the relaxation's); "fire reference" is the same with FIRE, a check
SLOW = 2.5e-6
CASES = {
    "reference": ({"relaxation_tol": 1e-4, "extra": dict(LOCAL, strain_rate=SLOW)}, "pstlo", False),
    "fire reference": ({"relaxation_tol": 1e-4, "extra": dict(FIRE, strain_rate=SLOW)}, "pstlo", False),
    "local tol 1e-4": ({"relaxation_tol": 1e-4, "extra": LOCAL}, "pstlo", False),
    "local": ({"extra": LOCAL}, "pstlo", False),
    "local dt_safety 0.5": ({"extra": dict(LOCAL, dt_safety=0.5)}, "pstlo", False),
    "fire": ({"extra": FIRE}, "pstlo", False),
    "fire fire_dt_max 4": ({"extra": dict(FIRE, fire_dt_max=4.0)}, "pstlo", False),
    "fire strain_rate 2e-5": ({"extra": dict(FIRE, strain_rate=2e-5)}, "pstlo", False),
    "fire kruyt": ({"extra": FIRE}, "kruyt", False),
    "fire pstlo_sliding": ({"extra": FIRE}, "pstlo_sliding", False),
    "fire batched": ({"extra": FIRE}, "pstlo", True),
    "fire kruyt batched": ({"extra": FIRE}, "kruyt", True),
    "fire batched lag 2": ({"extra": FIRE}, "pstlo", True, {"jacobian_lag": 2}),
    "fire batched lag 3": ({"extra": FIRE}, "pstlo", True, {"jacobian_lag": 3}),
    "fire batched lag 5": ({"extra": FIRE}, "pstlo", True, {"jacobian_lag": 5}),
    "fire kruyt batched lag 3": ({"extra": FIRE}, "kruyt", True, {"jacobian_lag": 3}),
    "fire batched refresh 0.5": ({"extra": FIRE}, "pstlo", True, {"jacobian_refresh": 0.5}),
    "fire batched refresh 0.7": ({"extra": FIRE}, "pstlo", True, {"jacobian_refresh": 0.7}),
    "fire batched refresh 0.9": ({"extra": FIRE}, "pstlo", True, {"jacobian_refresh": 0.9}),
    "fire fire_dt_max 4 batched": ({"extra": dict(FIRE, fire_dt_max=4.0)}, "pstlo", True),
    "fire fire_dt_max 4 kruyt batched": ({"extra": dict(FIRE, fire_dt_max=4.0)}, "kruyt", True),
    # cells that do not relax (YADE's way): N DEM steps per solve, the operator rule of the default
    "fire fixed_steps 300 batched": ({"extra": dict(FIRE, fixed_steps=300)}, "pstlo", True, {"jacobian_refresh": 0.7}),
    "fire fixed_steps 1000 batched": ({"extra": dict(FIRE, fixed_steps=1000)}, "pstlo", True,
                                      {"jacobian_refresh": 0.7}),
    # relaxed cells whose relaxation stops N DEM steps after the ramp, settled or not
    "fire relax_cap 300 batched": ({"extra": dict(FIRE, relax_cap=300)}, "pstlo", True, {"jacobian_refresh": 0.7}),
    "fire relax_cap 500 batched": ({"extra": dict(FIRE, relax_cap=500)}, "pstlo", True, {"jacobian_refresh": 0.7}),
    "fire relax_cap 1000 batched": ({"extra": dict(FIRE, relax_cap=1000)}, "pstlo", True, {"jacobian_refresh": 0.7}),
    # the default cells with the convergence test every 10 DEM steps instead of 50
    "fire relax_cap 500 check_every 10 batched": ({"extra": dict(FIRE, relax_cap=500, check_every=10)}, "pstlo", True,
                                                  {"jacobian_refresh": 0.7}),
}
REFERENCE = "reference"


def case(label):
    """(CellOptions overrides, tangent, batched, Newton settings) of a case."""
    cell, tangent, batched, *newton = CASES[label]
    return cell, tangent, batched, dict(newton[0]) if newton else {"jacobian_lag": 1}


def newton_words(newton):
    """A case's Newton settings in the table: the lag, or the refresh factor."""
    return f"refresh {newton['jacobian_refresh']:g}" if "jacobian_refresh" in newton else f"lag {newton['jacobian_lag']}"


def case_settings(label, mode, a):
    cell, tangent, batched, newton = case(label)
    return settings(mesh=parse_mesh(a.mesh), particles=a.particles, cell=dict(cell), mode=mode, tangent=tangent,
                    batched=batched, axial_strain=a.axial_strain, steps=a.steps, **newton)


def is_default(label, mode, a):
    """Whether a case is what FemDemSettings() / CellOptions() give (the demo's defaults)."""
    from cosserat_fenicsx.scenes.femdem_biaxial import FemDemSettings
    from cosserat_fenicsx.materials.dem import CellOptions
    s = case_settings(label, mode, a)
    d = FemDemSettings()
    return (s.tangent == d.tangent and s.batched == d.batched and s.jacobian_rule() == d.jacobian_rule()
            and s.cell.relaxation() == CellOptions(particles=a.particles).relaxation())


def scatter(a):
    """Stand-alone cells of seeds 0..a.seeds-1 (the reference's relaxation) on the homogeneous
    path at the run's load steps: {strains, ratios (seeds x steps), std, mean}."""
    from cosserat_fenicsx.materials.dem import reference_cells
    strains = [-a.axial_strain * k / a.steps for k in range(1, a.steps + 1)]
    ratios = []
    for seed in range(a.seeds):
        s = settings(mesh=(1, 1), particles=a.particles, cell=dict(CASES[REFERENCE][0], seed=seed))
        cell = reference_cells(s.cell, [s.cell.friction])[0][0]
        ratios.append([stress_ratio(sigma) for sigma in homogeneous_path(cell, strains, s.cell.pressure)])
    r = np.array(ratios)
    return {"seeds": a.seeds, "strains": strains, "ratios": r.tolist(), "mean": r.mean(0).tolist(),
            "std": r.std(0, ddof=1).tolist()}


def compare(record, reference, strains, spread):
    """Largest |stress ratio - the reference's| at the record's load steps inside the strain range
    the reference reached (the reference interpolated linearly where a cut-back put its steps
    elsewhere), before the reference's peak and over all of them; the largest ratio of that
    difference to the scatter of the cell (`spread` at `strains`) at the same strain, and the
    verdict: as accurate when the difference is below the scatter at every step."""
    e, r = -np.array(record["axial_strain"]), np.array(record["stress_ratio"])
    e_ref, r_ref = -np.array(reference["axial_strain"]), np.array(reference["stress_ratio"])
    inside = e <= e_ref[-1] + 1e-12 if len(e_ref) else np.zeros(len(e), bool)
    if not inside.any():
        return {"pre_peak": None, "all": None, "steps_compared": 0, "over_scatter": None, "verdict": "no"}
    e, r = e[inside], r[inside]
    diff = np.abs(r - np.interp(e, e_ref, r_ref))
    pre = e <= e_ref[int(np.argmax(r_ref))] + 1e-12
    over = float(np.max(diff / np.interp(e, -np.array(strains), spread)))
    return {"pre_peak": float(diff[pre].max()) if pre.any() else None, "all": float(diff.max()),
            "steps_compared": int(len(e)), "over_scatter": over, "verdict": "ok" if over <= 1.0 else "no"}


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", default="results/benchmarks/femdem_defaults")
    p.add_argument("--mesh", default="1x2")
    p.add_argument("--particles", type=int, default=100)
    p.add_argument("--axial-strain", type=float, default=0.024)
    p.add_argument("--steps", type=int, default=12)
    p.add_argument("--modes", nargs="+", default=["classical", "hybrid", "micropolar"],
                   choices=("classical", "hybrid", "micropolar"))
    p.add_argument("--cases", default=",".join(CASES), help="comma-separated, of: " + ", ".join(CASES))
    p.add_argument("--seeds", type=int, default=6, help="packing seeds of the single-cell scatter (default 6)")
    a = p.parse_args()
    comm = MPI.COMM_WORLD
    labels = [c for c in a.cases.split(",") if c]
    unknown = [c for c in labels if c not in CASES]
    if unknown:
        p.error(f"unknown case(s) {unknown}; known: {', '.join(CASES)}")
    if REFERENCE not in labels:
        labels.insert(0, REFERENCE)
    if a.seeds < 2:
        p.error("--seeds must be >= 2 (a standard deviation)")
    start = time.perf_counter()
    load_start = os.getloadavg()
    path = os.path.join(a.out, "scatter.json")
    if os.path.isfile(path):
        with open(path) as f:
            spread = json.load(f)
    else:
        spread = scatter(a)
        if comm.rank == 0:
            os.makedirs(a.out, exist_ok=True)
            with open(path, "w") as f:
                json.dump(spread, f)
    records = []
    for mode in a.modes:
        for label in labels:
            cell, tangent, batched, newton = case(label)
            if mode == "micropolar" and tangent == "pstlo_sliding":
                continue             # Cauchy cells only (materials.dem.cells.check_tangent)
            r = run_case(comm, os.path.join(a.out, mode), label, case_settings(label, mode, a),
                         log=lambda t: comm.rank == 0 and print(t, flush=True))
            r["mode"], r["label"], r["batched"] = mode, label, batched
            r["default"] = is_default(label, mode, a)
            records.append(r)
    if comm.rank:
        return
    std = np.array(spread["std"])
    for r in records:
        ref = next(q for q in records if q["mode"] == r["mode"] and q["label"] == REFERENCE)
        n = len(r["stress_ratio"])
        work = r["time_max_over_ranks"]["newton_total"]
        r["difference"] = compare(r, ref, spread["strains"], std)
        r["wall_per_step"] = work / max(n, 1)
        r["cpu_per_step"] = (r["cpu_time"] - r["preparation_time"]) / max(n, 1)
        r["newton_total"] = int(np.sum(r["newton_iterations"]))
        r["dem_steps_total"] = float(np.sum(r["dem_steps"]))
        r["reached"] = -r["axial_strain"][-1] if n else 0.0
        r["name"] = r["label"] + (" (default)" if r["default"] else "")
    for r in records:
        base = next((q for q in records if q["mode"] == r["mode"] and q["label"] == "local"),
                    next(q for q in records if q["mode"] == r["mode"] and q["label"] == REFERENCE))
        r["speed_up"] = base["cpu_per_step"] / r["cpu_per_step"]
    columns = [("mode", "mode", "s"), ("case", "name", "s"), ("tangent", "tangent", "s"),
               ("operator built", lambda r: newton_words(case(r["label"])[3]), "s"),
               ("operators", lambda r: r.get("cell_tangents_total", float("nan")), ".0f"),
               ("wall s/step", "wall_per_step", ".2f"), ("CPU s/step", "cpu_per_step", ".2f"),
               ("vs local", "speed_up", ".2f"), ("Newton", "newton_total", "d"), ("DEM steps", "dem_steps_total", ".3g"),
               ("reached", "reached", ".4f"), ("peak", "peak_stress_ratio", ".4f"),
               ("at", lambda r: -r["axial_strain_at_peak"], ".4f"),
               ("diff pre-peak", lambda r: r["difference"]["pre_peak"], ".4f"),
               ("diff all", lambda r: r["difference"]["all"], ".4f"),
               ("diff / scatter", lambda r: r["difference"]["over_scatter"], ".2f"),
               ("as accurate", lambda r: r["difference"]["verdict"], "s"),
               ("load", "load_average_before", ".2f")]
    strains = ", ".join(f"{-e * 100:.1f} %: {m:.3f} +- {s:.3f}" for e, m, s in
                        zip(spread["strains"], spread["mean"], spread["std"]))
    text = (f"FEM x DEM biaxial, mesh {a.mesh} ({records[0]['n_gauss_points']} Gauss points, uniform), "
            f"{a.particles} discs, {a.axial_strain:g} axial strain in {a.steps} steps, {comm.size} rank(s); "
            f"differences in the stress ratio against '{REFERENCE}' (same mode); 'vs local': CPU per step of "
            f"'local' / this; wall s/step: the Newton's wall seconds per load step (no preparation)\n"
            f"scatter of the stand-alone cell over {a.seeds} seeds (stress ratio mean +- std): {strains}\n"
            f"load average {load_start[0]:.2f} at the start, {os.getloadavg()[0]:.2f} at the end; "
            f"{time.perf_counter() - start:.0f} s\n" + table(records, columns) + "\n")
    write_report(a.out, "femdem_defaults.txt", text)
    with open(os.path.join(a.out, "femdem_defaults.json"), "w") as f:
        json.dump({"scatter": spread, "records": [{k: v for k, v in r.items()
                                                   if k not in ("points", "equivalent_strain", "band_history")}
                                                  for r in records]}, f, indent=1)
    plot(records, spread, a.modes, os.path.join(a.out, "femdem_defaults.png"))


def plot(records, spread, modes, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, len(modes), figsize=(5 * len(modes), 4), squeeze=False)
    e = -np.array(spread["strains"]) * 100
    for ax, mode in zip(axes[0], modes):
        m, s = np.array(spread["mean"]), np.array(spread["std"])
        ax.fill_between(e, m - s, m + s, color="0.85", label="stand-alone cell, mean +- std over seeds")
        for r in records:
            if r["mode"] == mode:
                ax.plot(-np.array(r["axial_strain"]) * 100, r["stress_ratio"], ".-", ms=3,
                        lw=2 if r["label"] == REFERENCE else 1, label=f"{r['name']} ({r['cpu_per_step']:.2f} CPU s/step)")
        ax.set_xlabel("axial strain [%]")
        ax.set_ylabel("stress ratio")
        ax.set_title(mode)
        ax.legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


if __name__ == "__main__":
    main()
