#!/usr/bin/env python3
"""FEM x DEM biaxial test in micropolar mode against hybrid mode.

micropolar: every flux and tangent block from a micropolar cell (the grains carry the point's
rotation and curvature; skew stress and couple stress are the cell's). hybrid: the cell's
symmetric stress with elastic skew and couple stress, mu_c = the cell's G and
l_c = --grain-diameter (the scene's defaults). Same packing, same weak corner (a square of
--weak-size at the lower left, its cells at --weak-friction x the friction), same tangent
(--tangent), on --meshes.

Per run (table femdem_micropolar.md, records <label>.json, figure femdem_micropolar.png):
peak stress ratio (000 eq. 40) and peak platen stress with their axial strains, the stress
ratio and platen stress at the end (post-peak), the band (shear_band.assess_band on the
equivalent strain since the start of the axial stage at the Gauss points outside the weak
corner, as the scene's band()), the Cosserat moduli of the cell at the reference state
(G, mu_c, B = dm/dkappa, l_c = sqrt(B / 2 mu_c), against the grain diameter; for hybrid the
moduli it imposes), wall and CPU seconds, Newton iterations and DEM steps.

Budget: each case gets --case-minutes of wall time (by mesh); at the end of it the case is
sent SIGTERM, ends after its current step and its record keeps what it reached
(femdem_cases.Interrupted). Reruns resume from the records (delete one to rerun it).
The defaults (60-disc cells, grain diameter 0.5 mm, 2 % in 10 steps, pstlo) are chosen to
finish in about 20 minutes on 2 processes of the 2-core machine (18 min measured, docs/results/femdem.md).

    mpirun -n 2 python3 benchmarks/femdem/femdem_micropolar.py --out results/femdem_micropolar
"""
import argparse
import json
import os
import signal
import threading

import numpy as np
from mpi4py import MPI

from benchmarks.femdem.femdem_cases import parse_mesh, run_case, settings, stored_record

from cosserat_fenicsx.shear_band import assess_band, fit_band

WIDTH, HEIGHT = 0.01, 0.02


def cell_moduli(a, comm):
    """Moduli of the reference cell (same packing as the runs): the micropolar cell's own
    (both pstlo and demqo) and the ones the hybrid mode imposes (mu_c = G of the free cell,
    l_c = grain diameter, B = 2 mu_c l_c^2)."""
    from cosserat_fenicsx.materials.dem import CellOptions, initial_shear_modulus, make_mode, mean_grain_diameter
    from cosserat_fenicsx.materials.dem.cells import reference_cells
    from cosserat_fenicsx.scenes.femdem_biaxial import reference_moduli
    opts = CellOptions(particles=a.particles)
    (free,), _ = reference_cells(opts, [opts.friction], comm)
    (mp,), _ = reference_cells(opts, [opts.friction], comm, micropolar=True)
    mode = make_mode("micropolar", length_scale=a.grain_diameter / mean_grain_diameter(mp))
    micropolar = reference_moduli(mode, mp, a.tangent, a.grain_diameter)
    G = initial_shear_modulus(free, "pstlo")
    l_c = a.grain_diameter
    hybrid = {"G": G, "mu_c": G, "bending_modulus": 2 * G * l_c ** 2, "l_c": l_c,
              "l_c_over_grain_diameter": 1.0, "moduli_from": "imposed (hybrid defaults)"}
    return {"micropolar": micropolar, "hybrid": hybrid}


def band_entries(record, weak_size):
    """shear_band.assess_band on the record's final equivalent strain outside the weak corner."""
    if not record.get("points"):
        return None, {"no_band_reason": "no step"}
    pts, e = np.array(record["points"]), np.array(record["equivalent_strain"])
    keep = ~((pts[:, 0] < weak_size) & (pts[:, 1] < weak_size))
    nx, ny = record["mesh"]
    return assess_band(lambda: fit_band(pts[keep], e[keep]), min(WIDTH / nx, HEIGHT / ny), WIDTH, HEIGHT)


class CaseTimer:
    """SIGTERM to this process after `seconds` (every rank has its own timer; run_case checks
    the flag on all ranks together after a converged step, so they stop at the same step)."""

    def __init__(self, seconds):
        self.timer = threading.Timer(seconds, lambda: os.kill(os.getpid(), signal.SIGTERM))
        self.timer.daemon = True

    def __enter__(self):
        self.timer.start()
        return self

    def __exit__(self, *exc):
        self.timer.cancel()


def summarise(r, moduli, weak_size):
    band, entries = band_entries(r, weak_size)
    eps = -np.array(r["axial_strain"]) if r["axial_strain"] else np.zeros(0)
    q = np.array(r["vertical_stress"]) if r["vertical_stress"] else np.zeros(0)
    i_q = int(np.argmin(q)) if len(q) else None          # compression: most negative
    m = moduli[r["mode"]]
    return {
        "label": r["label"], "mode": r["mode"], "mesh": f"{r['mesh'][0]}x{r['mesh'][1]}",
        "points": r["n_gauss_points"], "reached_pct": 100 * eps[-1] if len(eps) else None,
        "peak_ratio": r["peak_stress_ratio"],
        "peak_ratio_at_pct": -100 * r["axial_strain_at_peak"] if r["axial_strain_at_peak"] is not None else None,
        "peak_stress": -q[i_q] if i_q is not None else None,
        "peak_stress_at_pct": 100 * eps[i_q] if i_q is not None else None,
        "final_ratio": r["stress_ratio"][-1] if r["stress_ratio"] else None,
        "final_stress": -q[-1] if len(q) else None,
        "band": bool(entries.get("band")), "H_mm": 1e3 * band.thickness if band is not None else None,
        "band_fit_H_mm": (1e3 * entries["band_fit"]["thickness"] if entries.get("band_fit") else None),
        "band_note": entries.get("no_band_reason") or entries.get("band_warning") or "",
        "G": m["G"], "mu_c": m["mu_c"], "B": m["bending_modulus"], "l_c_mm": 1e3 * m["l_c"],
        "l_c_over_d": m["l_c_over_grain_diameter"],
        "wall_s": r["wall_time"], "cpu_s": r["cpu_time"], "newton": int(sum(r["newton_iterations"])),
        "dem_steps": float(sum(r["dem_steps"])), "cuts": r["cuts"],
        "stopped": r["stopped"], "load": r["load_average_before"],
    }


COLUMNS = [("run", "label", "s"), ("points", "points", "d"), ("reached [%]", "reached_pct", ".2f"),
           ("peak ratio", "peak_ratio", ".4f"), ("at [%]", "peak_ratio_at_pct", ".2f"),
           ("peak -sigma22 [N/m]", "peak_stress", ".2f"), ("at [%]", "peak_stress_at_pct", ".2f"),
           ("final ratio", "final_ratio", ".4f"), ("final -sigma22 [N/m]", "final_stress", ".2f"),
           ("band H [mm]", "H_mm", ".2f"), ("fit H [mm]", "band_fit_H_mm", ".2f"),
           ("G [N/m]", "G", ".4g"), ("mu_c [N/m]", "mu_c", ".4g"), ("B [N m]", "B", ".3g"),
           ("l_c [mm]", "l_c_mm", ".3f"), ("l_c / d", "l_c_over_d", ".2f"),
           ("Newton", "newton", "d"), ("cuts", "cuts", "d"), ("DEM steps", "dem_steps", ".3g"),
           ("wall [s]", "wall_s", ".0f"), ("CPU [s]", "cpu_s", ".0f"), ("load", "load", ".1f")]


def markdown(rows):
    head = "| " + " | ".join(t for t, _, _ in COLUMNS) + " |"
    lines = [head, "|" + "---|" * len(COLUMNS)]
    for r in rows:
        cells = [format(r[k], f) if r.get(k) is not None else "-" for _, k, f in COLUMNS]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def plot(records, path, title):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(1, 2, figsize=(13, 5))
    styles = {"micropolar": "-", "hybrid": "--"}
    for r in records:
        eps = -100 * np.array(r["axial_strain"])
        label = f"{r['mode']} {r['mesh'][0]}x{r['mesh'][1]}" + (" (stopped)" if r["stopped"] else "")
        ax[0].plot(eps, r["stress_ratio"], styles[r["mode"]], marker=".", label=label)
        ax[1].plot(eps, -np.array(r["vertical_stress"]), styles[r["mode"]], marker=".", label=label)
    ax[0].set_ylabel("mean stress ratio |s11 - s22| / |s11 + s22| (000 eq. 40)")
    ax[1].set_ylabel("platen stress -sigma22 [N/m]")
    for a in ax:
        a.set_xlabel("axial strain -eps22 [%]"); a.grid(alpha=0.3); a.legend()
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", default="results/femdem_micropolar")
    p.add_argument("--meshes", nargs="+", default=["2x4", "4x8"])
    p.add_argument("--modes", nargs="+", default=["micropolar", "hybrid"])
    p.add_argument("--particles", type=int, default=60, help="discs per cell (small: the 4x8 runs must finish)")
    p.add_argument("--grain-diameter", type=float, default=5e-4,
                   help="grain diameter in the specimen [m]: the hybrid l_c, and the micropolar cell's scale "
                        "(0.5 mm: l_c of order the 2.5 mm element / 5, as the regularisation study)")
    p.add_argument("--axial-strain", type=float, default=0.02)
    p.add_argument("--steps", type=int, default=10)
    p.add_argument("--weak-size", type=float, default=5e-3)
    p.add_argument("--weak-friction", type=float, default=0.5)
    p.add_argument("--tangent", default="pstlo",
                   help="cell operator for both modes (pstlo: the frozen network solved exactly; demqo gives the "
                        "same operator at several times the cost; see docs/results/femdem.md)")
    p.add_argument("--case-minutes", default="2x4=7,4x8=22",
                   help="wall budget per case by mesh, e.g. '2x4=5,4x8=14' (then SIGTERM: partial record)")
    p.add_argument("--report-only", action="store_true", help="tabulate the records, run nothing")
    a = p.parse_args()
    comm = MPI.COMM_WORLD
    log = lambda t: comm.rank == 0 and print(t, flush=True)  # noqa: E731
    budget = {k: 60.0 * float(v) for k, v in (item.split("=") for item in a.case_minutes.split(","))}
    os.makedirs(a.out, exist_ok=True)
    moduli = cell_moduli(a, comm)
    if comm.rank == 0:
        with open(os.path.join(a.out, "cell_moduli.json"), "w") as f:
            json.dump(moduli, f, indent=1)
    log(f"cell moduli: micropolar {json.dumps({k: v for k, v in moduli['micropolar'].items() if k != 'moduli_by_tangent'})}")
    common = dict(particles=a.particles, axial_strain=a.axial_strain, steps=a.steps, weak_size=a.weak_size,
                  weak_friction_factor=a.weak_friction, grain_diameter=a.grain_diameter, tangent=a.tangent)
    cases = [(f"{mode}_{mesh}", mesh, settings(mesh=parse_mesh(mesh), mode=mode, **common))
             for mesh in a.meshes for mode in a.modes]
    records = []
    for label, mesh, s in cases:
        if a.report_only:
            r = stored_record(a.out, label, s)
        else:
            with CaseTimer(budget.get(mesh, 600.0)):
                r = run_case(comm, a.out, label, s, log=log)
        if r is not None:
            records.append(r)
        if comm.rank == 0 and records:      # the table and figure after every case: partial results
            rows = [summarise(r, moduli, a.weak_size) for r in records]
            head = (f"FEM x DEM biaxial {WIDTH * 1e3:g} x {HEIGHT * 1e3:g} mm, weak corner {a.weak_size * 1e3:g} mm "
                    f"(friction x {a.weak_friction:g}), {a.particles}-disc cells, grain diameter "
                    f"{a.grain_diameter * 1e3:g} mm, {a.tangent} tangent, to {a.axial_strain:g} in {a.steps} steps, "
                    f"{comm.size} ranks\n\n")
            notes = "\n".join(f"- {r['label']}: band: {r['band_note'] or 'a band'}"
                              + (f"; stopped: {r['stopped']}" if r["stopped"] else "") for r in rows)
            with open(os.path.join(a.out, "femdem_micropolar.md"), "w") as f:
                f.write(head + markdown(rows) + "\n\n" + notes + "\n")
            with open(os.path.join(a.out, "summary.json"), "w") as f:
                json.dump({"rows": rows, "cell_moduli": moduli, "options": vars(a)}, f, indent=1)
            plot(records, os.path.join(a.out, "femdem_micropolar.png"), head.strip())
    log(f"done: {len(records)} of {len(cases)} runs; {a.out}/femdem_micropolar.md")


if __name__ == "__main__":
    main()
