#!/usr/bin/python3
"""Periodic cell against paper 000's frame cell (demcell.frame) on the same grains.

1. Biaxial path at three cell sizes (--sizes, default 60 120 240 discs, seed 0): the
   prepared reference cell (demcell.reference_cell, p0 = 10 N/m, kn = 1e4 N/m, mu = 0.4) is
   loaded as a periodic DemCell and, cut open, as a FrameCell (one-particle frame, the
   defaults of demcell.frame: stiffness gain beta 0.5 with Anderson mixing, servo tolerance
   --frame-tol in mean contact forces), both by demcell.strain_path_step (axial F imposed,
   the lateral F found by a secant iteration on sigma_lat = -p0: a FEM x DEM Gauss point's
   path, to 1e-3 of p0), --increments of --increment. Per size: the stress-ratio curves and their largest
   difference, the peaks, the volumetric strains, and per increment the frame's servo
   iterations, DEM steps and CPU / wall seconds against the periodic cell's; also the Table
   2 residual r_a (a~ = M R / dt^2) after the first relaxation of every solve, i.e. 000's
   criterion before any servo correction (000 Table 2: eps_a = 1e-4).
2. Grains through the frame (000 section 4.2): a 60-disc cell sheared and compressed in 1 %
   increments to 30 % with a one-particle frame and with a frame 3 mean diameters wide:
   the increment at which a grain is pushed through, if any.
3. Optionally (--femdem MESH) demos/femdem_biaxial.py on that mesh with 100-disc cells,
   periodic against frame (classical mode, --femdem-steps of 0.2 %).

Writes --out/frame_cell.json and prints the tables of docs/results/frame_cell.md.

    python3 benchmarks/dem/frame_cell.py --out results/frame_cell
"""
import argparse
import json
import os
import subprocess
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

import demcell as dc  # noqa: E402
from demcell.frame import FrameCell, FrameOptions, servo  # noqa: E402
from demcell.strain_path import strain_path_step  # noqa: E402

P0 = 10.0
#: the secant iteration's tolerance on the lateral stress (demcell.strain_path_step's default
#: 1e-4 asks a frame cell for several more solves per increment)
LATERAL_RTOL = 1e-3
LAW = dc.ContactLaw(kn=1e4, ks=2e3, friction=0.4)


def reference(n, seed=0):
    state, _ = dc.generate_packing(n, pressure=P0, law=LAW, seed=seed)
    return dc.reference_cell(state, LAW, dc.RelaxationOptions(criterion="force", tol=1e-4), P0)


def table2_first(cell):
    """Table 2's r_a (a~ = M R / dt^2) after the first relaxation of the last solve, before
    any servo correction."""
    first = cell.last_servo.by_measure.get("table2", [])
    return first[0] if first else float("nan")


def biaxial(cell, increments, increment, frame):
    rows = []
    for k in range(1, increments + 1):
        F = cell.deformation_gradient()
        F[1, 1] = 1.0 - k * increment
        c0, w0 = time.process_time(), time.perf_counter()
        iterations, first, capped = [], [], []
        if frame:
            solve = cell.solve

            def counted(max_steps=None):
                result = solve(max_steps)
                iterations.append(cell.last_servo.iterations)
                first.append(table2_first(cell))
                capped.append(not result.converged and cell.last_servo.iterations >= cell.options.max_iterations)
                return result
            cell.solve = counted
        res = strain_path_step(cell, F, 0, -P0, rtol=LATERAL_RTOL)
        if frame:
            del cell.solve
        cell.commit()
        h = cell.homogenized()
        if frame:
            print(f"[frame_cell]   increment {k}: {len(iterations)} solves, servo iterations {iterations}, "
                  f"{int(np.sum(capped))} at the cap, {time.process_time() - c0:.0f} CPU s", flush=True)
        rows.append(dict(axial_strain=-k * increment, stress_ratio=h.stress_ratio,
                         volumetric_strain=float(np.linalg.det(cell.deformation_gradient()) - 1.0),
                         sigma=h.cauchy.tolist(), steps=res.steps, converged=bool(res.converged),
                         cpu=time.process_time() - c0, wall=time.perf_counter() - w0,
                         solves=len(iterations) if frame else None,
                         servo_iterations=int(np.sum(iterations)) if frame else None,
                         servo_iterations_max=int(np.max(iterations)) if frame and iterations else None,
                         capped_solves=int(np.sum(capped)) if frame else None,
                         table2_first=float(np.nanmax(first)) if frame and first else None,
                         load=os.getloadavg()[0]))
    return rows


def size_study(sizes, increments, increment, frame_tol, ramp="frame", max_iterations=300, dump=None, seeds=(0,)):
    """Per size and packing seed (keys 'N/seed'); dump(out) after each (a long study keeps what
    it measured)."""
    out = {}
    for n, seed in [(n, seed) for seed in seeds for n in sizes]:
        ref = reference(n, seed)
        relax = dc.RelaxationOptions(criterion="force", tol=1e-4)
        periodic = dc.DemCell(ref.state.copy(), LAW, relax)
        frame = FrameCell(ref.state.copy(), LAW, FrameOptions(relaxation=relax, eps_a=frame_tol,
                                                                      max_iterations=max_iterations, ramp=ramp))
        fr = frame.frame
        print(f"[frame_cell] {n} discs, seed {seed}: frame {len(fr.groups)} / inner {fr.inner.size}", flush=True)
        p_rows = biaxial(periodic, increments, increment, False)
        # the periodic cell's own sensitivity to how tightly each state is relaxed: the floor
        # below which a difference of the frame cell says nothing about its boundary
        tight = biaxial(dc.DemCell(ref.state.copy(), LAW, dc.RelaxationOptions(criterion="force", tol=1e-5)),
                        increments, increment, False)
        f_rows = biaxial(frame, increments, increment, True)
        rp = np.array([r["stress_ratio"] for r in p_rows])
        rf = np.array([r["stress_ratio"] for r in f_rows])
        sp = np.array([r["sigma"] for r in p_rows])
        sf = np.array([r["sigma"] for r in f_rows])
        key = f"{n}/{seed}"
        out[key] = dict(discs=n, seed=seed, frame_discs=len(fr.groups), inner_discs=int(fr.inner.size), periodic=p_rows, frame=f_rows,
                      frame_inner_ratio=len(fr.groups) / int(fr.inner.size),
                      capped_solves=int(sum(r["capped_solves"] for r in f_rows)),
                      solves=int(sum(r["solves"] for r in f_rows)),
                      ratio_difference_max=float(np.abs(rf - rp).max()),
                      ratio_difference_floor=float(np.abs(np.array([r["stress_ratio"] for r in tight]) - rp).max()),
                      stress_difference_max=float((np.abs(sf - sp).max(axis=(1, 2)) / np.abs(sp).max(axis=(1, 2))).max()),
                      peak_periodic=float(rp.max()), peak_frame=float(rf.max()),
                      volumetric_difference_max=float(np.abs(np.array([r["volumetric_strain"] for r in f_rows])
                                                             - np.array([r["volumetric_strain"] for r in p_rows])).max()),
                      cost_ratio_cpu=float(sum(r["cpu"] for r in f_rows) / sum(r["cpu"] for r in p_rows)),
                      cost_ratio_steps=float(sum(r["steps"] for r in f_rows) / sum(r["steps"] for r in p_rows)))
        if dump is not None:
            dump(out)
        print(f"[frame_cell] {key} done: {json.dumps({k: v for k, v in out[key].items() if not isinstance(v, list)})}",
              flush=True)
    return out


def escape_study(n=60, increment=0.01, final=0.3):
    ref = reference(n)
    out = {}
    for thickness in (None, 3.0):
        cell = FrameCell(ref.state.copy(), LAW, FrameOptions(relaxation=dc.RelaxationOptions(criterion="force", tol=1e-3),
                                                          thickness=thickness, eps_a=1e-2, max_iterations=50))
        lost = None
        for k in range(1, int(round(final / increment)) + 1):
            e = k * increment
            cell.set_deformation(np.array([[1.0 - e, 0.5 * e], [0.5 * e, 1.0 + 0.5 * e]]))
            res = cell.solve()
            if cell.escaped.size:
                lost = dict(increment=k, strain=e, discs=cell.escaped.tolist(), message=res.message)
                break
            cell.commit()
        out["one particle" if thickness is None else f"{thickness:g} diameters"] = dict(
            frame_discs=len(cell.frame.groups), inner_discs=int(cell.frame.inner.size), lost=lost,
            reached=e)
        print(f"[frame_cell] escape, thickness {thickness}: {out[list(out)[-1]]}", flush=True)
    return out


def femdem(mesh, steps, out, particles=100, increment=2e-3, relaxation_tol=1e-4, frame_tol=1e-3):
    """demos/femdem_biaxial.py periodic then frame (same seed); wall and child CPU seconds,
    the history per step."""
    import resource
    root = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..")
    result = {}
    for bc in ("periodic", "frame"):
        target = os.path.join(out, f"femdem_{bc}")
        cmd = [sys.executable, os.path.join(root, "demos", "femdem_biaxial.py"), "--mesh", mesh, "--particles", str(particles),
               "--mode", "classical", "--axial-strain", str(increment * steps), "--steps", str(steps),
               "--relaxation-tol", str(relaxation_tol), "--micro-bc", bc,
               *(["--frame-tol", str(frame_tol)] if bc == "frame" else []), "--out", target]
        w0 = time.perf_counter()
        r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        load = os.getloadavg()[0]
        subprocess.run(cmd, check=True, capture_output=True, text=True)
        r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        summary = json.load(open(os.path.join(target, "summary.json")))
        history = np.genfromtxt(os.path.join(target, "history.csv"), delimiter=",", names=True)
        result[bc] = dict(wall=time.perf_counter() - w0, cpu=(r1.ru_utime + r1.ru_stime) - (r0.ru_utime + r0.ru_stime),
                          load=[load, os.getloadavg()[0]], peak=summary["peak_stress_ratio"],
                          stress_ratio=history["stress_ratio"].tolist(), dem_steps=summary["dem_steps_total"],
                          newton=summary["newton_iterations_total"],
                          history={k: history[k].tolist() for k in history.dtype.names})
        print(f"[frame_cell] femdem {mesh} {bc}: {json.dumps({k: v for k, v in result[bc].items() if k != 'history'})}",
              flush=True)
    return result


def pre_peak(s, name):
    """Largest difference of the increments up to the periodic cell's peak (before softening)."""
    p, f = s["periodic"], s["frame"]
    rp = np.array([r["stress_ratio"] for r in p])
    last = int(np.argmax(rp)) + 1
    if name == "ratio":
        return float(np.abs(np.array([r["stress_ratio"] for r in f[:last]]) - rp[:last]).max())
    sp = np.array([r["sigma"] for r in p[:last]])
    sf = np.array([r["sigma"] for r in f[:last]])
    return float((np.abs(sf - sp).max(axis=(1, 2)) / np.abs(sp).max(axis=(1, 2))).max())


def tables(result):
    """The tables of docs/results/frame_cell.md from a result (also --from-json)."""
    sizes = result.get("sizes", {})
    if sizes:
        print("| discs/seed | frame / inner discs | max abs. d stress ratio (to the periodic peak) | periodic tol 1e-5 "
              "against 1e-4 | max d sigma / max abs. sigma (to the peak) | peak periodic / frame | max abs. d eps_v "
              "| servo iterations per increment (solves) | most per solve | solves at the cap "
              "| DEM steps frame / periodic | CPU frame / periodic | Table 2 r_a at iteration 0 (max) |")
        print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for key, s in sizes.items():
        f = s["frame"]
        print(f"| {key} | {s['frame_discs']} / {s['inner_discs']} | {s['ratio_difference_max']:.3f} "
              f"({pre_peak(s, 'ratio'):.3f}) | {s['ratio_difference_floor']:.3f} | {s['stress_difference_max']:.3f} "
              f"({pre_peak(s, 'sigma'):.3f}) | {s['peak_periodic']:.3f} / {s['peak_frame']:.3f} | "
              f"{s['volumetric_difference_max']:.1e} | {np.mean([r['servo_iterations'] for r in f]):.0f} "
              f"({np.mean([r['solves'] for r in f]):.1f}) | {max(r['servo_iterations_max'] for r in f)} | "
              f"{s['capped_solves']} / {s['solves']} | {s['cost_ratio_steps']:.0f} | {s['cost_ratio_cpu']:.0f} | "
              f"{max(r['table2_first'] for r in f):.1e} |")
    by_size = {}
    for s in sizes.values():
        by_size.setdefault(s["discs"], []).append(s)
    if any(len(rows) > 1 for rows in by_size.values()):
        print("\n| discs | seeds | frame / inner (mean) | max abs. d stress ratio: mean (min-max) | to the peak: mean "
              "(min-max) | max d sigma / max abs. sigma: mean (min-max) | to the peak: mean (min-max) "
              "| periodic tol 1e-5 against 1e-4 (max) | solves at the cap |")
        print("|---|---|---|---|---|---|---|---|---|")
        for n, rows in sorted(by_size.items()):
            cols = [[s["ratio_difference_max"] for s in rows], [pre_peak(s, "ratio") for s in rows],
                    [s["stress_difference_max"] for s in rows], [pre_peak(s, "sigma") for s in rows]]
            print(f"| {n} | {len(rows)} | {np.mean([s['frame_inner_ratio'] for s in rows]):.2f} | "
                  + " | ".join(f"{np.mean(c):.3f} ({min(c):.3f}-{max(c):.3f})" for c in cols)
                  + f" | {max(s['ratio_difference_floor'] for s in rows):.3f} | "
                  f"{sum(s['capped_solves'] for s in rows)} / {sum(s['solves'] for s in rows)} |")
    for bc, r in result.get("femdem", {}).items():
        h = r["history"]
        print(f"\nFEM x DEM, {bc}: wall {r['wall']:.0f} s, CPU {r['cpu']:.0f} s, load {r['load']}, Newton {r['newton']}, "
              f"DEM steps {r['dem_steps']:.0f}")
        for k in range(len(h["step"])):
            print(f"  step {h['step'][k]:.0f}: axial {h['axial_strain'][k]:.4f}, ratio {h['stress_ratio'][k]:.4f}, "
                  f"Newton {h['newton_iterations'][k]:.0f}, DEM steps {h['dem_steps'][k]:.0f}, "
                  f"wall {h['wall_time'][k]:.1f} s, cuts {h['cuts'][k]:.0f}")


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sizes", type=int, nargs="*", default=[60, 120, 240], help="disc counts (none: skip the study)")
    p.add_argument("--seeds", type=int, nargs="+", default=[0], help="packing seeds per size")
    p.add_argument("--increments", type=int, default=10)
    p.add_argument("--increment", type=float, default=2e-3)
    p.add_argument("--frame-tol", type=float, default=1e-3)
    p.add_argument("--ramp", choices=("frame", "affine"), default="frame",
                   help="how the frame cell's discs reach a new F (FrameOptions.ramp)")
    p.add_argument("--servo-max-iterations", type=int, default=300, help="FrameOptions.max_iterations")
    p.add_argument("--no-escape", action="store_true")
    p.add_argument("--femdem", default=None, help="mesh NXxNY of the FEM x DEM comparison (default: skipped)")
    p.add_argument("--femdem-steps", type=int, default=5)
    p.add_argument("--femdem-particles", type=int, default=100)
    p.add_argument("--femdem-relaxation-tol", type=float, default=1e-4,
                   help="both kinds of cell (the frame's servo tolerance --frame-tol must stay >= 10 x this)")
    p.add_argument("--out", default="results/frame_cell")
    p.add_argument("--from-json", default=None, help="print the tables of a written frame_cell.json and stop")
    a = p.parse_args()
    if a.from_json:
        tables(json.load(open(a.from_json)))
        return
    os.makedirs(a.out, exist_ok=True)
    t0 = time.perf_counter()
    path = os.path.join(a.out, "frame_cell.json")
    result = dict(options=vars(a))

    def dump(sizes):
        json.dump(dict(result, sizes=sizes), open(path, "w"), indent=1)
    result["sizes"] = size_study(a.sizes, a.increments, a.increment, a.frame_tol, a.ramp, a.servo_max_iterations, dump,
                                    a.seeds) \
        if a.sizes else {}
    if not a.no_escape:
        result["escape"] = escape_study()
    if a.femdem:
        result["femdem"] = femdem(a.femdem, a.femdem_steps, a.out, a.femdem_particles, a.increment,
                                  a.femdem_relaxation_tol, a.frame_tol)
    result["wall_time"] = time.perf_counter() - t0
    json.dump(result, open(os.path.join(a.out, "frame_cell.json"), "w"), indent=1)
    tables(result)
    print(f"[frame_cell] {result['wall_time']:.0f} s; {os.path.join(a.out, 'frame_cell.json')}")


if __name__ == "__main__":
    main()
