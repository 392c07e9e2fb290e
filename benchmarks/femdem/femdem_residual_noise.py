#!/usr/bin/env python3
"""How far the FEM x DEM residual is a function of the displacement: its noise, step by step.

A Newton iteration can bring FNORM/RNORM (the residual at the free dofs over the reactions)
only as low as the residual is a function of the iterate. Every residual evaluation solves
each cell from its committed state to the iterate's strain; where a cell's relaxation from
that state is chaotic (a force chain that buckles, a packing at its jamming point), strains
a round-off apart can end in different equilibria, and the residual jumps by what those
cells carry. This script measures that jump on the runs whose Newton stops on a floor past
the peak (docs/reference/femdem.md, "Past the peak").

It runs the hybrid biaxial of `demos/femdem_biaxial.py` (by default the 4x8 mesh to 5 % in 50
steps, the demo's defaults otherwise) and, at every solve from --from-step on, at its
last iterate x (the converged one, before the stepping commits it, or the last of a solve that
failed, before the step is cut):

1. evaluates the residual again at x (a point whose strain did not change since its last
   update keeps its cell as the solve left it): after a converged solve it gives the step's
   last FNORM/RNORM bit for bit;
2. evaluates it at x (1 + delta xi) for each --deltas, xi uniform in [-1, 1] per dof (a fixed
   seed), and reports the noise |r(x (1 + delta xi)) - r(x)| / RNORM (the residual at the free
   dofs). For a smooth residual it scales with delta (about 1e-12 x the stiffness ratio at
   delta 1e-12); a residual that is not a function of x at the level of its floor shows the
   same noise at every delta, down to round-off;
3. evaluates it at x once more, every perturbed cell now solved again from its committed
   state: bit for bit the first (column `deterministic`: the residual is a function of x),
   and the cells are left in x's state for the commit.

The run itself is unchanged by the probes: the same history as without them.

Writes OUT/residual_noise.json, OUT/residual_noise.md and OUT/residual_noise.png as it goes.

    mpirun -n 2 python3 benchmarks/femdem/femdem_residual_noise.py --out DIR
    mpirun -n 2 python3 benchmarks/femdem/femdem_residual_noise.py --cell-option relax_cap=none --out DIR

The defaults' cells stop a relaxation 500 DEM steps after its ramp (relax_cap); the second
command measures cells relaxed to the criterion, whose residual stalls the run at 4.54 %.
"""
import argparse
import json
import os
import time

import numpy as np
from mpi4py import MPI

from cosserat_fenicsx.cli import key_value
from cosserat_fenicsx.scenes.femdem_biaxial import FemDemBiaxial, FemDemSettings, parse_mesh
from cosserat_fenicsx.stepping import LoadSteppingError

COMM = MPI.COMM_WORLD


def norm(values):
    return float(np.sqrt(COMM.allreduce(float(np.sum(values ** 2)))))


class NoiseProbe:
    """The scene's step solver, with the residual probed at the last iterate of every solve
    from load step `from_step` on; `on_row(row)` gets each probe's record."""

    def __init__(self, solver, test, from_step, deltas, seed, on_row):
        self.solver, self.test, self.from_step = solver, test, from_step
        self.deltas, self.on_row = deltas, on_row
        self.rng = np.random.default_rng([seed, COMM.rank])

    def solve(self):
        step = len(self.test.history) + 1
        start = time.perf_counter()
        info = self.solver.solve()
        wall = time.perf_counter() - start
        if step >= self.from_step:
            self.probe(step, info, wall)
        return info

    def probe(self, step, info, wall):
        newton = self.test.newton
        x = newton.x.copy()
        start = time.perf_counter()
        r, ratio, reactions = newton.probe_residual(x)
        noise = []
        for delta in self.deltas:
            xp = x.copy()
            with xp.localForm() as local:
                local.array[:] *= 1.0 + delta * self.rng.uniform(-1.0, 1.0, local.array.shape)
            rp = newton.probe_residual(xp)[0]
            noise.append(norm(rp - r) / reactions)
            xp.destroy()
        # the fields and the cells back in x's state for the commit
        r_again, ratio_again, _ = newton.probe_residual(x)
        x.destroy()
        row = {"step": step, "time": float(self.test.problem.time), "converged": bool(info.converged),
               "axial_strain": float(self.test.platen_displacement(self.test.problem.time) / self.test.s.height),
               "newton_iterations": int(info.iterations), "accepted": bool(info.accepted),
               "step_force_ratio": float(info.force_ratios[-1]),
               "reevaluated_ratio": ratio, "reevaluated_again_ratio": ratio_again,
               "deterministic": bool(COMM.allreduce(int(np.array_equal(r, r_again)), op=MPI.MIN)),
               "noise": dict(zip((f"{d:g}" for d in self.deltas), noise)),
               "force_ratios": [float(f) for f in info.force_ratios], "step_wall_s": wall,
               "probe_wall_s": time.perf_counter() - start}
        self.on_row(row)


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", required=True)
    p.add_argument("--mesh", default="4x8")
    p.add_argument("--axial-strain", type=float, default=0.05)
    p.add_argument("--steps", type=int, default=50)
    p.add_argument("--particles", type=int, default=228)
    p.add_argument("--from-step", type=int, default=2, help="the first load step probed (default %(default)s)")
    p.add_argument("--deltas", type=float, nargs="+", default=[1e-12, 1e-9, 1e-6],
                   help="relative perturbations of the displacement (default %(default)s)")
    p.add_argument("--seed", type=int, default=0, help="seed of the perturbations")
    p.add_argument("--cell-option", type=key_value, action="append", default=[], metavar="KEY=VALUE",
                   help="a demcell.RelaxationOptions of the cells, as the demo's (e.g. fixed_steps=1000)")
    a = p.parse_args()
    os.makedirs(a.out, exist_ok=True)
    nx, ny = parse_mesh(a.mesh)
    from cosserat_fenicsx.materials.dem import CellOptions
    settings = FemDemSettings(nx=nx, ny=ny, axial_strain=a.axial_strain, steps=a.steps,
                              cell=CellOptions(particles=a.particles, extra=dict(a.cell_option)))
    test = FemDemBiaxial(COMM, settings, verbose=False)
    command = (f"mpirun -n {COMM.size} python3 benchmarks/femdem/femdem_residual_noise.py --mesh {a.mesh} "
               f"--axial-strain {a.axial_strain:g} --steps {a.steps} --particles {a.particles} "
               + "".join(f"--cell-option {k}={v} " for k, v in a.cell_option)
               + f"--from-step {a.from_step} --deltas {' '.join(f'{d:g}' for d in a.deltas)} --out DIR")
    result = {"command": command, "ranks": COMM.size, "rows": [], "load_average_1min": [os.getloadavg()[0]]}
    cpu0, wall0 = time.process_time(), time.perf_counter()

    def on_row(row):
        result["rows"].append(row)
        if COMM.rank == 0:
            print(f"{'step' if row['converged'] else 'FAIL'} {row['step']:3d} strain {-row['axial_strain']:.4f} ratio {row['step_force_ratio']:.2e} "
                  f"re-evaluated {row['reevaluated_ratio']:.2e} "
                  f"noise " + " ".join(f"{k}: {v:.2e}" for k, v in row["noise"].items()), flush=True)
            write(a.out, result)

    test.solver.solver = NoiseProbe(test.solver.solver, test, a.from_step, a.deltas, a.seed, on_row)
    stop = None
    try:
        test.run()
    except LoadSteppingError as error:    # where the stepping gives up is measured too
        stop = str(error)
    result["stopped"] = stop
    result["wall_s"] = time.perf_counter() - wall0
    result["cpu_s"] = COMM.allreduce(time.process_time() - cpu0)
    result["load_average_1min"].append(os.getloadavg()[0])
    if COMM.rank == 0:
        write(a.out, result)
        plot(a.out, result)


def write(out, result):
    with open(os.path.join(out, "residual_noise.json"), "w") as f:
        json.dump(result, f, indent=1)
    deltas = list(result["rows"][0]["noise"]) if result["rows"] else []
    lines = [f"Run: `{result['command']}`", "",
             "| step | axial strain | Newton its | FNORM/RNORM at the last iterate | re-evaluated | "
             + " | ".join(f"noise at {d}" for d in deltas) + " |",
             "|---" * (5 + len(deltas)) + "|"]
    for r in result["rows"]:
        lines.append(f"| {r['step']}{'' if r['converged'] else ' (failed, cut)'} | {-r['axial_strain']:.3%} | {r['newton_iterations']}{' (accepted)' if r['accepted'] else ''} "
                     f"| {r['step_force_ratio']:.2e} | "
                     f"{r['reevaluated_ratio']:.2e}{'' if r['deterministic'] else ' (not bit for bit)'} | "
                     + " | ".join(f"{r['noise'][d]:.2e}" for d in deltas) + " |")
    if result.get("stopped"):
        lines += ["", f"Stopped: {result['stopped']}"]
    with open(os.path.join(out, "residual_noise.md"), "w") as f:
        f.write("\n".join(lines) + "\n")


def plot(out, result):
    from cosserat_fenicsx.figures import pyplot
    plt = pyplot()
    rows = result["rows"]
    if not rows:
        return
    fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
    for ax, converged, title in ((axes[0], True, "converged steps"), (axes[1], False, "last iterates of failed solves")):
        part = [r for r in rows if r["converged"] == converged]
        strain = [-100 * r["axial_strain"] for r in part]
        ax.semilogy(strain, [r["step_force_ratio"] for r in part], "k.", label="FNORM/RNORM at the iterate")
        for d, marker in zip(rows[0]["noise"], "osd"):
            ax.semilogy(strain, [max(r["noise"][d], 1e-16) for r in part], marker, ms=4, mfc="none",
                        label=f"|r(x (1 + {d} xi)) - r(x)| / RNORM")
        ax.axhline(1e-2, color="g", lw=0.8, ls="--", label="force_rtol")
        ax.axhline(3e-2, color="r", lw=0.8, ls="--", label="accept_rtol")
        ax.set_xlabel("axial strain [%]")
        ax.set_title(title, fontsize=9)
    axes[0].set_ylabel("|residual| / |reactions|")
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(os.path.join(out, "residual_noise.png"), dpi=120)


if __name__ == "__main__":
    main()
