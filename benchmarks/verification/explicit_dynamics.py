"""Period error of the explicit Cosserat dynamics against run time (cosserat_fenicsx.dynamics,
003 eqs 31-34), so a user can choose a mesh and a step.

The standing P wave of a strip 1 x 0.25 m (dynamics.verification.p_wave: the closed form
omega = c_p pi / L, c_p = 1 m/s, no skew strain, so exact for any mu_c and l_c) on three
meshes of square cells, Q1/Q1 and P2/P1, each stepped with dt = --courant x the power-
iteration stable step for --periods periods. For each: the stable steps (power, h/c_p, 2/omega_r),
the measured period's error against the continuum closed form (FE dispersion and Verlet's time
error together), the FE error alone (Verlet's inverted), the step count, the wall and CPU time
of the stepping (the model build and power iteration apart), the load average beside them.
Ratios between successive meshes are printed: the error ratio (4 for second order) and the
time ratio (8 expected: 4 x the dofs, 2 x the steps).

    PYTHONPATH=. python3 benchmarks/verification/explicit_dynamics.py --out results/benchmarks/explicit_dynamics
    PYTHONPATH=. mpirun -n 2 python3 benchmarks/verification/explicit_dynamics.py --meshes 8 --periods 1.6 --out ...
Writes summary.json (the rows and, with --series, the signal time series) and explicit_dynamics.png.
"""
import argparse
import json
import math
import os
import time

import numpy as np
from mpi4py import MPI

from cosserat_fenicsx.dynamics import verification as ver

parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
parser.add_argument("--out", default="results/benchmarks/explicit_dynamics")
parser.add_argument("--meshes", default="16,32,64", help="elements along the strip (4 per 1 across)")
parser.add_argument("--elements", default="Q1/Q1,P2/P1")
parser.add_argument("--courant", type=float, default=0.5, help="dt / power stable step")
parser.add_argument("--periods", type=float, default=5.0)
parser.add_argument("--series", action="store_true", help="store the signal series in summary.json")
args = parser.parse_args()
import logging  # noqa: E402
logging.getLogger().setLevel(logging.WARNING)
comm = MPI.COMM_WORLD
if comm.rank == 0:
    os.makedirs(args.out, exist_ok=True)
meshes = [int(n) for n in args.meshes.split(",")]

rows = []
for element in args.elements.split(","):
    ver.p_wave(comm, element, nx=4)                     # forms compiled before any timing
    for nx in meshes:
        model, signal, omega = ver.p_wave(comm, element, nx=nx, ny=max(1, nx // 4))
        stable = model.stable_time_step()
        dt = args.courant * stable["power"]
        steps = int(math.ceil(args.periods * 2 * math.pi / omega / dt))
        comm.Barrier()
        wall, cpu = time.perf_counter(), time.process_time()
        t, s = ver.run(model, signal, dt, steps)
        wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
        period = ver.zero_crossing_period(t, s)
        omega_measured = 2 * math.pi / period
        row = {"element": element, "nx": nx, "ny": max(1, nx // 4), "h": 1.0 / nx,
               "dofs": model.displacement.getSize(), "dt": dt, "steps": steps,
               "dt_power": stable["power"], "dt_translational": stable["translational"],
               "dt_rotational": stable["rotational"],
               "period_error": period / (2 * math.pi / omega) - 1,
               "fe_error": ver.spatial_frequency(omega_measured, dt) / omega - 1,
               "wall_s": comm.allreduce(wall, op=MPI.MAX), "cpu_s": comm.allreduce(cpu),
               "load_average": os.getloadavg()[0], "ranks": comm.size}
        if args.series:
            row["series"] = s.tolist()
        rows.append(row)

if comm.rank == 0:
    head = (f"{'element':>7} {'nx':>4} {'dofs':>6} {'steps':>6} {'power/(h/c)':>11} {'period err':>11} "
            f"{'FE err':>10} {'err ratio':>9} {'wall s':>7} {'cpu s':>7} {'time ratio':>10} {'load':>5}")
    print(head)
    for i, r in enumerate(rows):
        previous = rows[i - 1] if i and rows[i - 1]["element"] == r["element"] else None
        err_ratio = previous["period_error"] / r["period_error"] if previous else float("nan")
        time_ratio = r["wall_s"] / previous["wall_s"] if previous else float("nan")
        print(f"{r['element']:>7} {r['nx']:>4} {r['dofs']:>6} {r['steps']:>6} "
              f"{r['dt_power'] / r['dt_translational']:>11.3f} {r['period_error']:>11.3e} {r['fe_error']:>10.3e} "
              f"{err_ratio:>9.2f} {r['wall_s']:>7.2f} {r['cpu_s']:>7.2f} {time_ratio:>10.2f} {r['load_average']:>5.2f}")
    with open(os.path.join(args.out, "summary.json"), "w") as f:
        json.dump({"courant": args.courant, "periods": args.periods, "rows": rows}, f, indent=1)
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(5, 4))
    for element in args.elements.split(","):
        sel = [r for r in rows if r["element"] == element]
        ax.loglog([r["wall_s"] for r in sel], [abs(r["period_error"]) for r in sel], "o-", label=element)
        for r in sel:
            ax.annotate(f"{r['nx']}x{r['ny']}", (r["wall_s"], abs(r["period_error"])), fontsize=7)
    ax.set_xlabel("wall time of the stepping [s]")
    ax.set_ylabel("|period error| (standing P wave)")
    ax.set_title(f"dt = {args.courant} x power stable step, {args.periods} periods", fontsize=9)
    ax.legend()
    fig.tight_layout()
    fig.savefig(os.path.join(args.out, "explicit_dynamics.png"), dpi=120)
