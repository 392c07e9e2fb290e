"""Error against run time for the elastic solver, so a user can choose a resolution.

1. Manufactured solution (cosserat_fenicsx.manufactured, Taylor-Hood P2/P1, triangles):
   mesh size, dofs, L2/H1 errors of u and phi, observed orders, wall time of one solve
   (mesh, forms, assembly, direct solve; JIT already warm).
2. Plate with a hole, a = l_c (demos/hole_plate.py run as a user runs it, on --np ranks):
   element size on the hole (a/k; the far-field size shrinks with it), dofs, SCF, its
   difference from the closed form of the
   infinite plate (which includes the effect of the finite plate, L = 20 a) and
   from the finest mesh, and the wall time of meshing + solving (the demo's 'wall_time',
   Python start-up and JIT excluded; JIT warm from the first run); the finest mesh is repeated
   on a plate twice as large to show how much the plate size moves the SCF.

    python3 benchmarks/verification/convergence.py --out results/benchmarks [--np 2] [--quick]
Writes convergence_mms.csv, convergence_hole.csv, convergence.png and convergence.json.
"""
import argparse
import json
import os
import subprocess
import sys

import numpy as np
from mpi4py import MPI

from benchmarks import ROOT
from cosserat_fenicsx import analytic, manufactured

parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
parser.add_argument("--out", default="results/benchmarks")
parser.add_argument("--np", type=int, default=2, help="ranks for the hole-plate runs")
parser.add_argument("--quick", action="store_true", help="fewer meshes (smoke run)")
args = parser.parse_args()
os.makedirs(args.out, exist_ok=True)
import logging  # noqa: E402
logging.getLogger().setLevel(logging.WARNING)


def table(rows, columns, formats):
    head = " ".join(f"{c:>12}" for c in columns)
    lines = [head, "-" * len(head)]
    for r in rows:
        lines.append(" ".join(format(r[c], f).rjust(12) for c, f in zip(columns, formats)))
    return "\n".join(lines)


# --- 1. manufactured solution -------------------------------------------------------------
sizes = (4, 8, 16, 32) if args.quick else (4, 8, 16, 32, 64, 128)
manufactured.solve(MPI.COMM_WORLD, 4, manufactured.DEFAULT_ELASTICITY)  # warm the JIT
mms = [manufactured.solve(MPI.COMM_WORLD, n, manufactured.DEFAULT_ELASTICITY) for n in sizes]
for key in ("u_L2", "u_H1", "phi_L2", "phi_H1"):
    for row, rate in zip(mms[1:], manufactured.rates(mms, key)):
        row[key + "_order"] = rate
    mms[0][key + "_order"] = float("nan")
cols = ["h", "dofs", "u_L2", "u_L2_order", "u_H1", "u_H1_order", "phi_L2", "phi_L2_order",
        "phi_H1", "phi_H1_order", "wall_time"]
fmts = [".4g", "d", ".3e", ".2f", ".3e", ".2f", ".3e", ".2f", ".3e", ".2f", ".3f"]
text_mms = table(mms, cols, fmts)
print("Manufactured solution, P2/P1 triangles, unit square, l_c = 0.01 (wall time in s)\n" + text_mms)
np.savetxt(os.path.join(args.out, "convergence_mms.csv"), [[r[c] for c in cols] for r in mms],
           delimiter=",", header=",".join(cols), comments="")

# --- 2. hole plate ----------------------------------------------------------------------
radius = l_c = 0.01
mu = lmbda = 1.0e8
exact = analytic.micropolar_hole_scf(radius, mu, lmbda, mu, l_c)
env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1", OMP_NUM_THREADS="1")


def run_hole(k, half_side, far_size):
    out = os.path.join(args.out, f"hole_{k}_{half_side:g}")
    cmd = ["mpirun", "-n", str(args.np), sys.executable, os.path.join(ROOT, "demos", "hole_plate.py"),
           "--radius", str(radius), "--l-c", str(l_c), "--hole-cell-size", str(radius / k),
           "--half-side", str(half_side), "--cell-size", str(far_size),
           "--fields", "displacement", "--out", out]
    subprocess.run(cmd, check=True, capture_output=True, env=env)
    with open(os.path.join(out, "summary.json")) as f:
        s = json.load(f)
    return {"h_hole": radius / k, "half_side": half_side, "dofs": s["dofs"], "scf": s["scf"],
            "error_closed_form": abs(s["scf"] - exact) / exact, "wall_time": s["wall_time"]}


divisions = (4, 8, 16) if args.quick else (4, 8, 16, 32, 64)
# refine everywhere: hole element size a/k, far-field size (L/12)(4/k)
hole = [run_hole(k, 20 * radius, 20 * radius / 12 * 4 / k) for k in divisions]
# the finite plate adds to the SCF: the same finest mesh sizes on a plate twice as large
larger = run_hole(divisions[-1], 40 * radius, 20 * radius / 12 * 4 / divisions[-1])
for r in hole:
    r["error_finest"] = abs(r["scf"] - hole[-1]["scf"]) / hole[-1]["scf"]
cols_h = ["h_hole", "dofs", "scf", "error_closed_form", "error_finest", "wall_time"]
text_hole = table(hole, cols_h, [".4g", "d", ".5f", ".2e", ".2e", ".2f"])
print(f"\nHole plate a = l_c = {l_c} m, L = 20 a, closed-form SCF {exact:.5f} "
      f"(wall time of meshing + solving on {args.np} ranks, s)\n" + text_hole)
print(f"same finest mesh, L = 40 a: SCF {larger['scf']:.5f}, error vs closed form "
      f"{larger['error_closed_form']:.2e} (plate size alone moves the SCF by "
      f"{abs(larger['scf'] - hole[-1]['scf']) / larger['scf']:.1%})")
np.savetxt(os.path.join(args.out, "convergence_hole.csv"), [[r[c] for c in cols_h] for r in hole],
           delimiter=",", header=",".join(cols_h), comments="")
with open(os.path.join(args.out, "convergence.json"), "w") as f:
    json.dump({"manufactured": mms, "hole_plate": hole, "hole_plate_40a": larger,
               "scf_closed_form": exact}, f, indent=2)

import matplotlib  # noqa: E402
matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
fig, ax = plt.subplots(1, 2, figsize=(11, 4.2))
t = [r["wall_time"] for r in mms]
for key, style in (("u_L2", "o-"), ("u_H1", "s-"), ("phi_L2", "^-"), ("phi_H1", "v-")):
    ax[0].loglog(t, [r[key] for r in mms], style, label=key)
ax[0].set_xlabel("wall time of one solve [s]"); ax[0].set_ylabel("error"); ax[0].legend()
ax[0].set_title("manufactured solution, P2/P1")
ax[1].loglog([r["wall_time"] for r in hole], [r["error_closed_form"] for r in hole], "o-",
             label="vs closed form (infinite plate)")
ax[1].loglog([r["wall_time"] for r in hole[:-1]], [r["error_finest"] for r in hole[:-1]], "s-",
             label="vs finest mesh")
ax[1].set_xlabel(f"wall time of meshing + solving on {args.np} ranks [s]"); ax[1].set_ylabel("relative SCF error")
ax[1].set_title("plate with a hole, a = l_c"); ax[1].legend()
fig.tight_layout(); fig.savefig(os.path.join(args.out, "convergence.png"), dpi=120)
print(f"\nwritten: {args.out}/convergence_mms.csv, convergence_hole.csv, convergence.png")
