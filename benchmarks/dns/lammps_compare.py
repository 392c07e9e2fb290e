"""The bounded specimen in demcell and in LAMMPS: same discs, same law, same platens.

Two comparisons, written as JSON and a markdown table under --out (nothing is committed):

1. **Platen force histories** (``--nx --ny`` lattice, default 20 x 40 = 800 discs of 004
   Table 7.1, r = 1 m, m = pi kg/m), platens closing at --speed m/s, side walls fixed, every
   step, in two laws:
   * ``undamped``: frictionless (ks = 0, mu = 0), no dashpot, radii perturbed by 2 %: the
     forces depend on the positions only, and velocity Verlet (LAMMPS) and the leapfrog
     (demcell) give the same positions step for step, so the histories agree to round-off
     until round-off differences grow (chaotically: an undamped specimen amplifies them).
     The top platen sits far from y = 0: demcell sums its position (y += v dt), LAMMPS
     evaluates y0 + v t, and kn times that round-off (~1e-8 N after 300 steps at y = 35 m)
     is the floor of its comparison;
   * ``table71``: the thesis law (E_n = 1e4 N/m, E_t = 100 N/m, mu = 0.8, D_n = 100 N s/m,
     normal force clipped, Coulomb on the total normal force), monodisperse lattice (LAMMPS
     has one gamma_n = D_n / m_eff, exact for equal masses). Expected differences: the moment
     arms (LAMMPS r_i, demcell r_i - overlap/2) and LAMMPS's projected (not rotated)
     tangential displacement, both of relative size overlap / r.
   Measures, per platen and window of steps [a, b): the largest |F_lammps - F_demcell| over
   the window divided by the largest |F_demcell| in it (``max_rel``), and the RMS difference
   divided by the mean |F_demcell| over the window (``rms_rel``). Windows: the first
   --early steps after the first contact, and the last half of the run.
2. **CPU seconds per step** at --sizes discs (default 1e3, 1e4, 3e4: lattices 25 x 40,
   70 x 143, 114 x 263), Table 7.1 law, lattice pre-compressed to the overlap of 004's
   isotropic state (5.77e-3 m, every lattice contact loaded), platens closing: LAMMPS on 1 and
   2 MPI ranks (the log's loop time x ranks x its CPU %), demcell on 1 and 2 Numba threads
   (process CPU time of ``Specimen.run``, after 50 warm-up steps); wall seconds beside; the
   median of 3 rounds of --timing-steps steps each.

Run from the repository root (the machine is shared: run nothing else meanwhile):

    PYTHONPATH=. /usr/bin/python3 benchmarks/dns/lammps_compare.py --out results/lammps_compare

Needs LAMMPS (``lmp``; Debian lammps) and demcell/specimen/engine.py; when the engine is
missing only the LAMMPS half runs and the report says so.
"""
import argparse
import importlib.util
import json
import math
import os
import sys
import time
import warnings

import numpy as np

# A private Numba cache: demcell.specimen.contacts.build_pairs (cache=True, calling parallel
# kernels) segfaulted here when loaded from the cache and ran when compiled afresh (numba
# 0.56, 2026-12-05); compiling once per run costs some seconds and no timing (warm-up first)
if "LAMMPS_COMPARE_SHARED_CACHE" not in os.environ:
    import atexit
    import shutil
    import tempfile
    os.environ["NUMBA_CACHE_DIR"] = tempfile.mkdtemp(prefix="lammps_compare_numba_")
    atexit.register(shutil.rmtree, os.environ["NUMBA_CACHE_DIR"], True)

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)

from demcell.contact_law import ContactLaw  # noqa: E402
from demcell.specimen import lammps as L  # noqa: E402
from demcell.specimen.specimens import discs_from, thesis_lattice  # noqa: E402

#: 004 Table 7.1
RADIUS, DENSITY, KN, KT, MU, DN = 1.0, 1.0, 1.0e4, 100.0, 0.8, 100.0
#: lattice of each size
LATTICES = {1000: (25, 40), 10000: (70, 143), 30000: (114, 263)}
#: overlap of a lattice contact at 50 N/m (dns-spec A3: 2 p r / sqrt(3) / E_n)
ISOTROPIC_OVERLAP = 2.0 * 50.0 * RADIUS / math.sqrt(3.0) / KN


def engine_available():
    return importlib.util.find_spec("demcell.specimen.engine") is not None


def laws(case):
    """(ContactLaw, SpecimenOptions keywords, perturbation) of a comparison case."""
    if case == "undamped":
        return ContactLaw(kn=KN, ks=0.0, friction=0.0), dict(normal_dashpot=None, clip_normal=True), 0.02
    return (ContactLaw(kn=KN, ks=KT, friction=MU),
            dict(normal_dashpot=DN, tangential_dashpot=0.0, clip_normal=True, coulomb_on_total_normal=True), 0.0)


def lattice(nx, ny, perturbation=0.0, compress=0.0):
    """004 lattice; compress > 0: centres drawn together about the centre so that every
    lattice contact overlaps by `compress` [m], the walls moved in by the same strain."""
    discs = thesis_lattice(nx=nx, ny=ny, radius=RADIUS, density=DENSITY, perturbation=perturbation, seed=1)
    if compress > 0.0:
        s = 1.0 - compress / (2.0 * RADIUS)
        centre = np.array([0.5 * (discs.box[0] + discs.box[1]), 0.5 * (discs.box[2] + discs.box[3])])
        position = centre + s * (discs.position - centre)
        # the walls keep the outer discs' overlap with them at half a contact's
        box = (position[:, 0].min() - RADIUS + 0.5 * compress, position[:, 0].max() + RADIUS - 0.5 * compress,
               position[:, 1].min() - RADIUS + 0.5 * compress, position[:, 1].max() + RADIUS - 0.5 * compress)
        discs = discs_from(position, discs.radius, DENSITY, box=box, info=discs.info)
    return discs


def write_lammps(directory, discs, law, opts, dt, n_steps, speed, dump_every, wall_every):
    m = float(np.median(discs.mass))
    llaw = L.lammps_law(law, 0.5 * m, opts.get("normal_dashpot"), opts.get("tangential_dashpot"),
                        opts.get("clip_normal", True), wall_mass=m)
    b = discs.box
    walls = L.LammpsWalls(position=(b[2], b[3], b[0], b[1]), velocity=(speed, -speed, 0.0, 0.0),
                          active=(True, True, True, True))
    return L.write_lammps_input(directory, discs.position, discs.radius, discs.mass, llaw, walls, dt, n_steps,
                                dump_every, wall_every=wall_every, thermo_every=max(n_steps, 1))


def demcell_specimen(discs, law, opts, dt, speed, threads=None, boundary_interval=50):
    from demcell.specimen import Specimen, SpecimenOptions, SpecimenState, WallControl
    state = SpecimenState.from_specimen_discs(discs, lateral="walls")
    options = SpecimenOptions(dt=dt, lateral="walls", threads=threads, boundary_interval=boundary_interval, **opts)
    # the platens start on discs without load: the engine's inertial number is infinite then,
    # and its warning says nothing about a comparison of engines
    warnings.filterwarnings("ignore", message="inertial number")
    spec = Specimen(state, law, options)
    spec.set_walls(bottom=WallControl(velocity=speed), top=WallControl(velocity=-speed))
    return spec


def window_measures(f_l, f_e, a, b):
    """max_rel and rms_rel of one force history over steps [a, b) (module docstring)."""
    d = f_l[a:b] - f_e[a:b]
    ref_max = float(np.max(np.abs(f_e[a:b])))
    ref_mean = float(np.mean(np.abs(f_e[a:b])))
    std = float(np.std(f_e[a:b]))
    return {"steps": [int(a), int(b)],
            "max_rel": float(np.max(np.abs(d)) / ref_max) if ref_max > 0 else math.nan,
            "rms_rel": float(np.sqrt(np.mean(d ** 2)) / ref_mean) if ref_mean > 0 else math.nan,
            "mean_force_demcell": ref_mean, "mean_force_lammps": float(np.mean(np.abs(f_l[a:b]))),
            "std_force_demcell": std,
            "mean_diff_over_std": float(abs(np.mean(f_l[a:b]) - np.mean(f_e[a:b])) / std) if std > 0 else math.nan}


def divergence_steps(f_l, f_e, levels=(1e-12, 1e-9, 1e-6, 1e-3, 1e-1)):
    """First step at which |F_lammps - F_demcell| exceeds each level times the largest |F_demcell|
    so far (None: never): how a round-off difference grows."""
    ref = np.maximum.accumulate(np.abs(f_e))
    rel = np.abs(f_l - f_e) / np.where(ref > 0.0, ref, 1.0)
    out = {}
    for level in levels:
        k = np.flatnonzero(rel > level)
        out[f"{level:g}"] = int(k[0]) if k.size else None
    return out


def compare_histories(case, nx, ny, dt, n_steps, speed, early, workdir):
    """Platen forces of both engines every step, the window measures, final positions."""
    law, opts, perturbation = laws(case)
    discs = lattice(nx, ny, perturbation)
    directory = os.path.join(workdir, f"history_{case}")
    paths = write_lammps(directory, discs, law, opts, dt, n_steps, speed, dump_every=n_steps, wall_every=1)
    run = L.run_lammps(directory, wall_order=paths["wall_order"], dt=dt)
    f_l = run["walls"]["wall_force"][:, :2, 1]               # (n_steps + 1, 2): row k = forces at x_k
    spec = demcell_specimen(discs, law, opts, dt, speed, boundary_interval=1)
    forces = []
    # each 1-step interval measures the wall force of that step's positions x_k
    spec.run(n_steps=n_steps, on_interval=lambda s, m: forces.append(m.wall_force[:2, 1].copy()))
    f_e = np.array(forces)                                   # row k = forces at x_k
    f_l = f_l[:f_e.shape[0]]
    touched = np.flatnonzero(np.any(f_e != 0.0, axis=1) | np.any(f_l != 0.0, axis=1))
    first = int(touched[0]) if touched.size else 0
    windows = {"early": (first, min(first + early, n_steps)), "late": (n_steps // 2, n_steps)}
    out = {"case": case, "discs": discs.n_discs, "steps": n_steps, "dt": dt, "platen_speed": speed,
           "first_contact_step": first, "law": law.to_dict(), "options": {k: v for k, v in opts.items()},
           "perturbation": perturbation, "lammps_seconds": run["log"]["loop_seconds"]}
    for w, name in enumerate(("bottom", "top")):
        for key, (a, b) in windows.items():
            out[f"{name}_{key}"] = window_measures(f_l[:, w], f_e[:, w], a, b)
        out[f"{name}_divergence_steps"] = divergence_steps(f_l[:, w], f_e[:, w])
    # final positions (demcell renumbers its discs: .order[k] is the original index of disc k)
    x_e = np.empty_like(spec.state.position)
    x_e[spec.order] = spec.state.position
    x_l = run["dump"]["position"][-1]
    out["final_position_max_diff_over_r"] = float(np.max(np.abs(x_l - x_e)) / RADIUS)
    out["history"] = {"step": list(range(f_e.shape[0])), "lammps_bottom": f_l[:, 0].tolist(),
                      "demcell_bottom": f_e[:, 0].tolist(), "lammps_top": f_l[:, 1].tolist(),
                      "demcell_top": f_e[:, 1].tolist()}
    return out


def time_lammps(discs, law, opts, dt, n_steps, speed, ranks, workdir):
    directory = os.path.join(workdir, f"timing_lammps_{discs.n_discs}_{ranks}")
    write_lammps(directory, discs, law, opts, dt, n_steps, speed, dump_every=n_steps, wall_every=50)
    rounds = []
    for _ in range(3):
        run = L.run_lammps(directory, ranks=ranks, read=False)
        log = run["log"]
        rounds.append((log["cpu_seconds"] / log["steps"], log["loop_seconds"] / log["steps"]))
    cpu, wall = (float(np.median([r[i] for r in rounds])) for i in (0, 1))
    return {"engine": "lammps", "ranks": ranks, "discs": discs.n_discs, "steps": log["steps"],
            "cpu_s_per_step": cpu, "wall_s_per_step": wall, "rounds": rounds,
            "cpu_percent": log["cpu_percent"], "pair_seconds": log["sections"].get("Pair"),
            "listed_pairs": log["neighbours"], "neighbour_builds": log["neighbour_builds"],
            "process_cpu_seconds": run["cpu_seconds"]}


def time_demcell(discs, law, opts, dt, n_steps, speed, threads):
    spec = demcell_specimen(discs, law, opts, dt, speed, threads=threads)
    spec.run(n_steps=50)          # compile and warm up (thread pool included)
    rounds = []
    for _ in range(3):
        c0, w0 = spec.cpu_seconds, spec.wall_seconds
        spec.run(n_steps=n_steps)
        rounds.append(((spec.cpu_seconds - c0) / n_steps, (spec.wall_seconds - w0) / n_steps))
    cpu, wall = (float(np.median([r[i] for r in rounds])) for i in (0, 1))
    return {"engine": "demcell", "threads": threads, "discs": discs.n_discs, "steps": n_steps,
            "cpu_s_per_step": cpu, "wall_s_per_step": wall, "rounds": rounds,
            "listed_pairs": int(spec.state.n_pairs), "contacts": int(np.count_nonzero(spec.state.touching))}


def markdown(report):
    lines = ["# demcell vs LAMMPS on the bounded specimen", ""]
    if report.get("engine_missing"):
        lines += [f"**demcell's engine is missing** ({report['engine_missing']}): LAMMPS only.", ""]
    if report.get("histories"):
        lines += ["## Platen force histories", "",
                  "| case | discs | steps | platen | window (steps) | max rel. diff | RMS diff / mean force | "
                  "mean force demcell / LAMMPS [N] | mean diff / std |", "|---|---|---|---|---|---|---|---|---|"]
        for h in report["histories"]:
            for name in ("bottom", "top"):
                for key in ("early", "late"):
                    m = h[f"{name}_{key}"]
                    lines.append(f"| {h['case']} | {h['discs']} | {h['steps']} | {name} | {key} {m['steps'][0]}-"
                                 f"{m['steps'][1]} | {m['max_rel']:.2e} | {m['rms_rel']:.2e} | "
                                 f"{m['mean_force_demcell']:.4g} / {m['mean_force_lammps']:.4g} | "
                                 f"{m['mean_diff_over_std']:.2e} |")
        lines += ["", "First step where |dF| exceeds a level times max |F| so far (bottom platen):", ""]
        for h in report["histories"]:
            lines.append(f"* {h['case']}: " + ", ".join(f"{k}: {v}" for k, v in h["bottom_divergence_steps"].items()))
        lines += ["", "Final positions, max |x_lammps - x_demcell| / r: " + ", ".join(
            f"{h['case']} {h['final_position_max_diff_over_r']:.2e}" for h in report["histories"]), ""]
    if report.get("timings"):
        lines += ["## CPU seconds per step", "",
                  "| discs | engine | ranks / threads | CPU s / step | wall s / step | listed pairs | load (1 min) |",
                  "|---|---|---|---|---|---|---|"]
        for t in report["timings"]:
            lines.append(f"| {t['discs']} | {t['engine']} | {t.get('ranks') or t.get('threads')} | "
                         f"{t['cpu_s_per_step']:.3e} | {t['wall_s_per_step']:.3e} | {t.get('listed_pairs')} | "
                         f"{t['load_average'][0]:.2f} |")
        lines += ["", "Ratio LAMMPS / demcell of CPU s per step (same size, 1 rank vs 1 thread, 2 vs 2):", ""]
        for r in report.get("ratios", []):
            lines.append(f"* {r['discs']} discs, {r['cores']} core(s): {r['ratio']:.2f}")
    lines += ["", f"Command: `{report['command']}`", ""]
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, help="folder for lammps_compare.json, .md and the LAMMPS runs")
    ap.add_argument("--nx", type=int, default=20)
    ap.add_argument("--ny", type=int, default=40)
    ap.add_argument("--dt", type=float, default=2.0e-3, help="time step [s] (dns-spec A5)")
    ap.add_argument("--steps", type=int, default=4000, help="steps of the force-history comparison")
    ap.add_argument("--early", type=int, default=200, help="steps of the early window after the first contact")
    ap.add_argument("--speed", type=float, default=0.03, help="platen speed [m/s] (004: 0.03)")
    ap.add_argument("--sizes", default="1000,10000,30000", help="disc counts of the timings (of 1000, 10000, 30000)")
    ap.add_argument("--timing-steps", type=int, default=200)
    ap.add_argument("--skip-histories", action="store_true")
    ap.add_argument("--skip-timings", action="store_true")
    args = ap.parse_args(argv)
    os.makedirs(args.out, exist_ok=True)
    report = {"command": "PYTHONPATH=. /usr/bin/python3 benchmarks/dns/lammps_compare.py " + " ".join(
        sys.argv[1:] if argv is None else argv), "date": time.strftime("%Y-%m-%d %H:%M"),
              "load_average": os.getloadavg(), "histories": [], "timings": [], "ratios": []}
    have_engine = engine_available()
    if not have_engine:
        report["engine_missing"] = "demcell/specimen/engine.py not found"
        print("demcell's engine (demcell/specimen/engine.py) is missing: the comparison needs it; "
              "timing LAMMPS only", flush=True)

    def save():
        with open(os.path.join(args.out, "lammps_compare.json"), "w") as f:
            json.dump(report, f, indent=1)
        with open(os.path.join(args.out, "lammps_compare.md"), "w") as f:
            f.write(markdown(report))

    if have_engine and not args.skip_histories:
        for case in ("undamped", "table71"):
            h = compare_histories(case, args.nx, args.ny, args.dt, args.steps, args.speed, args.early, args.out)
            report["histories"].append(h)
            print(f"{case}: {h['discs']} discs, first contact step {h['first_contact_step']}; bottom platen early "
                  f"max rel {h['bottom_early']['max_rel']:.2e}, late RMS/mean {h['bottom_late']['rms_rel']:.2e}, "
                  f"late mean diff/std {h['bottom_late']['mean_diff_over_std']:.2e}; "
                  f"final positions max diff / r {h['final_position_max_diff_over_r']:.2e}", flush=True)
            save()
    if not args.skip_timings:
        report["load_average_before_timings"] = os.getloadavg()
        law, opts, _ = laws("table71")
        for n in (int(s) for s in args.sizes.split(",")):
            if n not in LATTICES:
                raise SystemExit(f"--sizes: {n} is not one of {sorted(LATTICES)}")
            discs = lattice(*LATTICES[n], compress=ISOTROPIC_OVERLAP)
            row = {}
            for ranks in (1, 2):
                t = time_lammps(discs, law, opts, args.dt, args.timing_steps, args.speed, ranks, args.out)
                report["timings"].append(t)
                row[("lammps", ranks)] = t["cpu_s_per_step"]
                t["load_average"] = os.getloadavg()
                print(f"{discs.n_discs} discs LAMMPS {ranks} rank(s): {t['cpu_s_per_step']:.3e} CPU s/step, "
                      f"{t['wall_s_per_step']:.3e} wall s/step", flush=True)
                save()
            if have_engine:
                for threads in (1, 2):
                    t = time_demcell(discs, law, opts, args.dt, args.timing_steps, args.speed, threads)
                    t["load_average"] = os.getloadavg()
                    report["timings"].append(t)
                    row[("demcell", threads)] = t["cpu_s_per_step"]
                    print(f"{discs.n_discs} discs demcell {threads} thread(s): {t['cpu_s_per_step']:.3e} CPU s/step, "
                          f"{t['wall_s_per_step']:.3e} wall s/step", flush=True)
                    save()
                for cores in (1, 2):
                    report["ratios"].append({"discs": discs.n_discs, "cores": cores,
                                             "ratio": row[("lammps", cores)] / row[("demcell", cores)]})
            save()
    save()
    print(f"wrote {os.path.join(args.out, 'lammps_compare.json')} and lammps_compare.md", flush=True)


if __name__ == "__main__":
    main()
