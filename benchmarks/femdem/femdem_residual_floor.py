#!/usr/bin/env python3
"""Where the residual floor of a post-peak step comes from, measured on that step.

Past the peak a step's FNORM/RNORM stops falling at a floor: below force_rtol (1e-2) the step
converges, between force_rtol and accept_rtol (3e-2) it ends at its best iterate (accepted),
above it the step fails and is cut. The free-rotation 1x2 biaxial of docs/reference/femdem.md
("Past the peak"; 228-disc cells, seed 4, 8 % in 100 steps, no damped retry) runs to load
step --step (default 100, 7.92 %: the step with the highest floor of the --jacobian-lag 1
run, accepted at 0.029), or to its first step that fails with both operators if that comes
first. On that step, from the same committed state and at the same load, the Newton is run
again for its full 25 iterations (no stagnation test) with every iterate's cells recorded:

1. the floor against the cells' relaxation tolerance: the step solved with pstlo and with kruyt,
   the cells relaxed to an unbalanced-force ratio of 1e-3 (the default), 1e-4 and 1e-5 (their
   option row changed in place, the step budget ten times larger). A floor set by the cells'
   relaxation error falls with the tolerance; a floor set by the cells' own discontinuities
   does not;
2. the contacts that open and close between consecutive Newton iterates, per Gauss point (the
   touching pairs of each cell after each residual evaluation);
3. the same step solved on kruyt with damped updates x += alpha dx (the scene's damped retry,
   --dampings).

With --accept-rtol 0.01 the run has no band between force_rtol and accept_rtol: its first step
whose floor lies above 1e-2 fails with both operators and is the one looked at.

Writes OUT/residual_floor.json, OUT/residual_floor.md and OUT/residual_floor.png; a few
minutes on 2 ranks.

    mpirun -n 2 python3 benchmarks/femdem/femdem_residual_floor.py --jacobian-lag 1 --out DIR
    mpirun -n 2 python3 benchmarks/femdem/femdem_residual_floor.py --accept-rtol 0.01 --dampings 0.1 0.3 0.6 --out DIR
"""
import argparse
import json
import os
import time

import numpy as np
from mpi4py import MPI

from cosserat_fenicsx.materials.dem import CellOptions
from cosserat_fenicsx.scenes.femdem_biaxial import FemDemBiaxial, FemDemSettings

COMM = MPI.COMM_WORLD


class Found(Exception):
    """The load step to look at was solved (or failed)."""


class Probe:
    """The scene's solver, stopping the run after the solve of load step `step` or at the first
    solve that fails (fallback included)."""

    def __init__(self, solver, test, step):
        self.solver, self.test, self.step = solver, test, step
        self.failed = None

    def solve(self):
        info = self.solver.solve()
        if not info.converged or len(self.test.history) + 1 >= self.step:
            self.failed = info
            raise Found()
        return info


class ContactTracker:
    """The touching pairs of every local cell after each residual evaluation of a solve."""

    def __init__(self, test):
        self.test, self.sets, self.on = test, [], False
        problem = test.problem
        inner = problem.before_residual

        def before_residual():
            inner()
            if self.on:
                self.sets.append(self.snapshot())
        problem.before_residual = before_residual

    def snapshot(self):
        out = []
        for cell in self.test.material.cells:
            s = cell.state
            n = s.n_pairs
            touching = s.touching[:n].astype(bool)
            out.append(set(zip(s.pair_i[:n][touching].tolist(), s.pair_j[:n][touching].tolist())))
        return out

    def changes(self):
        """Per pair of consecutive iterates: (opened, closed, points with a change) summed over
        the ranks; the first evaluation (the committed state at the new load) starts the list."""
        rows = []
        for before, after in zip(self.sets[:-1], self.sets[1:]):
            opened = sum(len(b - a) for b, a in zip(before, after))
            closed = sum(len(a - b) for b, a in zip(before, after))
            points = sum(1 for b, a in zip(before, after) if a != b)
            rows.append([COMM.allreduce(opened), COMM.allreduce(closed), COMM.allreduce(points)])
        return rows


def set_cell_tolerance(test, tol, budget_factor):
    from demcell import slots
    batch = test.material.store.batch
    if batch is None:
        return
    if not hasattr(test, "_opts0"):
        test._opts0 = batch.opts.copy()
    batch.opts[:] = test._opts0
    batch.opts[:, slots.Q_TOL] = tol
    batch.opts[:, slots.Q_LIMIT] *= budget_factor
    batch.opts[:, slots.Q_TOTAL] *= budget_factor


def solve_case(test, tracker, operator, tol, damping):
    """The failing step solved again from the committed state: FNORM/RNORM per iterate and the
    contact changes between iterates."""
    problem, newton, material = test.problem, test.newton, test.material
    set_cell_tolerance(test, tol, 1 if tol >= 1e-3 else 10)
    problem.rollback()
    if material.use_fallback_operator(operator != test.s.tangent):
        problem.gauss_points.invalidate_tangents()
    newton.set_step_damping(damping)
    stagnation, newton.stagnation_its = newton.stagnation_its, None     # the whole 25 iterations
    tracker.sets, tracker.on = [], True
    cpu, start = time.process_time(), time.perf_counter()
    try:
        info = newton.solve()
    finally:
        tracker.on = False
        newton.stagnation_its = stagnation
        newton.set_step_damping(None)
        if material.use_fallback_operator(False):
            problem.gauss_points.invalidate_tangents()
    ratios = [float(r) for r in info.force_ratios]
    changes = tracker.changes()
    finite = [r for r in ratios[1:] if np.isfinite(r)]
    factors = [b / a for a, b in zip(finite[:-1], finite[1:]) if a > 0]
    return {"operator": operator, "cell_tol": tol, "damping": damping, "converged": bool(info.converged),
            "accepted": bool(info.accepted), "iterations": int(info.iterations), "reason": info.reason,
            "failure": info.failure[:200], "force_ratios": ratios,
            "floor": float(min(finite)) if finite else None,
            "median_contraction": float(np.median(factors)) if factors else None,
            "contact_changes": changes,
            "wall_s": time.perf_counter() - start, "cpu_s": COMM.allreduce(time.process_time() - cpu)}


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", required=True)
    p.add_argument("--no-rotation", action="store_true", help="locked rotations (default: free)")
    p.add_argument("--jacobian-lag", type=int, default=None,
                   help="the Newton operator rule of the run (default: the demo's, --jacobian-refresh 0.7)")
    p.add_argument("--step", type=int, default=100, help="the load step to look at (default %(default)s)")
    p.add_argument("--tols", type=float, nargs="+", default=[1e-3, 1e-4, 1e-5])
    p.add_argument("--dampings", type=float, nargs="+", default=[0.3],
                   help="the step solved on the fallback operator with these dampings (default %(default)s)")
    p.add_argument("--accept-rtol", type=float, default=3e-2,
                   help="the run's accept_rtol (default %(default)s; 0.01 = force_rtol: a step ends below it or fails)")
    a = p.parse_args()
    os.makedirs(a.out, exist_ok=True)
    load = [os.getloadavg()]
    cpu0, wall0 = time.process_time(), time.perf_counter()
    settings = FemDemSettings(nx=1, ny=2, axial_strain=0.08, steps=100, retry_damping=0.0, accept_rtol=a.accept_rtol,
                              jacobian_lag=a.jacobian_lag,
                              cell=CellOptions(particles=228, seed=4, rotation=not a.no_rotation))
    test = FemDemBiaxial(COMM, settings, verbose=False)
    probe = Probe(test.solver.solver, test, a.step)
    test.solver.solver = probe
    tracker = ContactTracker(test)
    try:
        test.run()
    except Found:
        pass
    run_wall, run_cpu = time.perf_counter() - wall0, COMM.allreduce(time.process_time() - cpu0)
    result = {"command": "mpirun -n 2 python3 benchmarks/femdem/femdem_residual_floor.py "
                         + (f"--jacobian-lag {a.jacobian_lag} " if a.jacobian_lag else "")
                         + ("--no-rotation " if a.no_rotation else "") + f"--step {a.step} "
                         + (f"--accept-rtol {a.accept_rtol:g} " if a.accept_rtol != 3e-2 else "")
                         + f"--dampings {' '.join(f'{d:g}' for d in a.dampings)} --out DIR",
              "rotation": not a.no_rotation, "operator_rule": list(settings.jacobian_rule()),
              "ranks": COMM.size, "run_to_failure_wall_s": run_wall, "run_to_failure_cpu_s": run_cpu}
    if probe.failed is None:
        result["failing_step"] = None
        result["reached"] = -test.history[-1]["axial_strain"]
    else:
        last = test.history[-1]
        info = probe.failed
        target = -test.platen_displacement(test.problem.time) / settings.height
        result["failing_step"] = {"committed_axial_strain": -last["axial_strain"], "target_axial_strain": target,
                                  "step": last["step"] + 1, "converged": bool(info.converged),
                                  "accepted": bool(info.accepted), "iterations": int(info.iterations),
                                  "failure": info.failure or info.reason,
                                  "fallback_cause": info.fallback[:200], "best_force_ratio":
                                      float(min([r for r in info.force_ratios[1:] if np.isfinite(r)], default=np.nan)),
                                  "flags": info.flags[:300]}
        cases = []
        for tol in a.tols:
            for operator in (settings.tangent, settings.fallback_tangent):
                cases.append(solve_case(test, tracker, operator, tol, None))
                if COMM.rank == 0:
                    c = cases[-1]
                    print(f"{operator} tol {tol:g}: floor {c['floor']:.4g}, {c['iterations']} its, "
                          f"{'converged' if c['converged'] else 'failed'}", flush=True)
        for damping in a.dampings:
            cases.append(solve_case(test, tracker, settings.fallback_tangent, a.tols[0], damping))
        result["cases"] = cases
    result["total_wall_s"] = time.perf_counter() - wall0
    result["total_cpu_s"] = COMM.allreduce(time.process_time() - cpu0)
    load.append(os.getloadavg())
    result["load_average_1min"] = [load[0][0], load[-1][0]]
    if COMM.rank == 0:
        with open(os.path.join(a.out, "residual_floor.json"), "w") as f:
            json.dump(result, f, indent=1)
        write_report(a.out, result)


def write_report(out, r):
    lines = ["# The residual floor of a stagnating post-peak step", "",
             f"Run: `{r['command']}` · {r['ranks']} ranks · load {r['load_average_1min'][0]:.1f}-"
             f"{r['load_average_1min'][1]:.1f} · {r['total_wall_s']:.0f} s wall, {r['total_cpu_s']:.0f} CPU s", ""]
    f = r.get("failing_step")
    if f is None:
        lines.append(f"No step failed: the run reached {100 * r['reached']:.2f} %.")
    else:
        outcome = ("converged" if not f["accepted"] else "accepted at its best iterate") if f["converged"] else "failed"
        lines += [f"Load step {f['step']}, {100 * f['committed_axial_strain']:.2f} % -> "
                  f"{100 * f['target_axial_strain']:.2f} %: in the run {outcome} after {f['iterations']} iterations "
                  f"(best FNORM/RNORM {f['best_force_ratio']:.4g}; {f['failure']}). The same step again, 25 "
                  "iterations each:", "",
                  "| operator | cell tol | damping | converged | iterations | floor (best FNORM/RNORM) | "
                  "median contraction per iteration | contacts opened / closed per iteration (median) | "
                  "Gauss points with a change per iteration (median of 12) | wall s |", "|---|---|---|---|---|---|---|---|---|---|"]
        for c in r["cases"]:
            ch = np.array(c["contact_changes"][1:]) if len(c["contact_changes"]) > 1 else np.zeros((1, 3))
            lines.append(f"| {c['operator']} | {c['cell_tol']:g} | {c['damping'] or '-'} | "
                         f"{'yes' if c['converged'] else 'no'}{' (accepted)' if c['accepted'] else ''} | "
                         f"{c['iterations']} | {c['floor']:.4g} | {c['median_contraction']:.3g} | "
                         f"{np.median(ch[:, 0]):.0f} / {np.median(ch[:, 1]):.0f} | {np.median(ch[:, 2]):.0f} | "
                         f"{c['wall_s']:.0f} |")
        lines += ["", "(Contact changes from the second iterate on: the first compares the committed state at "
                      "the new load with the first Newton iterate.)"]
    with open(os.path.join(out, "residual_floor.md"), "w") as fh:
        fh.write("\n".join(lines) + "\n")
    if f is not None:
        from cosserat_fenicsx.figures import pyplot
        plt = pyplot()
        fig, ax = plt.subplots(1, 2, figsize=(12, 4.5))
        for c in r["cases"]:
            label = f"{c['operator']}, tol {c['cell_tol']:g}" + (f", damped {c['damping']}" if c["damping"] else "")
            ax[0].semilogy(range(1, len(c["force_ratios"])), c["force_ratios"][1:], ".-", label=label)
            ch = np.array(c["contact_changes"])
            if len(ch) and c["cell_tol"] == r["cases"][0]["cell_tol"]:
                ax[1].plot(range(1, len(ch) + 1), ch[:, 0] + ch[:, 1], ".-", label=label)
        ax[0].axhline(1e-2, color="k", lw=0.8, ls="--")
        ax[0].axhline(3e-2, color="k", lw=0.8, ls=":")
        ax[0].set_xlabel("residual evaluation"); ax[0].set_ylabel("FNORM/RNORM"); ax[0].legend(fontsize=7)
        ax[1].set_xlabel("between evaluations k-1 and k"); ax[1].set_ylabel("contacts opened + closed (12 cells)")
        ax[1].legend(fontsize=7)
        fig.suptitle(f"step {f['step']} ({100 * f['committed_axial_strain']:.2f} -> "
                     f"{100 * f['target_axial_strain']:.2f} %), free 1x2, 228 discs")
        fig.tight_layout(); fig.savefig(os.path.join(out, "residual_floor.png"), dpi=110)


if __name__ == "__main__":
    main()
