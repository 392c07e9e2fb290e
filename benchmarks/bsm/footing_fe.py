"""Pure Cosserat FE reference of 003's strip footing (Fig 10; the third column of the
BSM / full-DEM / FE comparison): static linear elastic Cosserat, 003's moduli (E = 500 MPa,
nu = 0.2, G_c = 70 MPa, l_c = 0.05 m in the G-reading: project l_c = l_c sqrt(G / (2 G_c))),
18 m x 9 m, bottom fixed (--bottom smooth: u2 = 0 only), sides u1 = 0, a smooth rigid plate 2 m wide at the top centre as a
prescribed settlement u2 = -depth of the top nodes under it. Linear: the plate load is
proportional to the settlement; reported at 60 mm for 003's 1 m mesh (Q1/Q1) and finer ones.

    PYTHONPATH=. python3 benchmarks/bsm/footing_fe.py [--cells 1 0.5 0.25]
"""
import argparse
import json
import math
import os
import sys
import time

import numpy as np
from mpi4py import MPI

from cosserat_fenicsx import CosseratProblem, LoadStepper, NewtonSolver, meshes
from cosserat_fenicsx.elasticity import MicropolarElasticity

E_MOD, NU, G_C, L_C = 500e6, 0.2, 70e6, 0.05
WIDTH, HEIGHT, PLATE = 18.0, 9.0, 2.0


def plate_load(cell, depth=0.06, degree_u=1, cell_type="quadrilateral", continuum="003", bottom="fixed"):
    G = E_MOD / (2 * (1 + NU))
    lam = 2 * G * NU / (1 - 2 * NU)
    g_c = G_C
    if continuum == "lattice":
        from demcell.specimen.footing import KN, KS
        G, lam, g_c = (KN + KS) / 4.0, (KN - KS) / 4.0, KS / 2.0
    elasticity = MicropolarElasticity(mu=G, lmbda=lam, mu_c=g_c, l_c=L_C * math.sqrt(G / (2 * g_c)))
    divisions = (int(round(WIDTH / cell)), int(round(HEIGHT / cell)))
    mesh, _, boundaries = meshes.rectangle(MPI.COMM_WORLD, WIDTH, HEIGHT, divisions=divisions, cell_type=cell_type)
    tol = 1e-9
    x0, x1 = 0.5 * (WIDTH - PLATE), 0.5 * (WIDTH + PLATE)
    where = {"left": lambda x: np.isclose(x[0], 0.0), "right": lambda x: np.isclose(x[0], WIDTH),
             "bottom": lambda x: np.isclose(x[1], 0.0), "top": lambda x: np.isclose(x[1], HEIGHT),
             "plate": lambda x: np.isclose(x[1], HEIGHT) & (x[0] > x0 - tol) & (x[0] < x1 + tol)}
    tags = dict(boundaries, plate=max(boundaries.values()) + 1)
    facet_tags = meshes.tag_facets(mesh, where, tags)
    problem = CosseratProblem(mesh, facet_tags, tags, elasticity=elasticity, degree_u=degree_u, degree_phi=1)
    if bottom == "fixed":
        problem.add_dirichlet("bottom", "u1", 0.0)
    problem.add_dirichlet("bottom", "u2", 0.0)
    problem.add_dirichlet("left", "u1", 0.0)
    problem.add_dirichlet("right", "u1", 0.0)
    problem.add_dirichlet("plate", "u2", -depth)
    LoadStepper(problem, NewtonSolver(problem), dt=1.0).run()
    return -problem.reaction("plate", "u2")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cells", type=float, nargs="+", default=[1.0, 0.5, 0.25])
    parser.add_argument("--bottom", choices=("fixed", "smooth"), default="fixed",
                        help="the base: fixed (003) or smooth, u2 = 0 only (the full DEM's wall)")
    parser.add_argument("--out", default="results/bsm_footing_fe")
    args = parser.parse_args()
    rows = []
    for continuum in ("003", "lattice"):
        for cell in args.cells:
            w0 = time.perf_counter()
            load = plate_load(cell, continuum=continuum, bottom=args.bottom)
            rows.append({"continuum": continuum, "bottom": args.bottom, "cell": cell, "load_60mm_kN_per_m": 1e-3 * load,
                         "wall_s": time.perf_counter() - w0, "load_average": os.getloadavg()[0]})
            if MPI.COMM_WORLD.rank == 0:
                print(f"{continuum:8s} h = {cell:g} m (Q1/Q1): plate load at 60 mm {1e-3 * load:.1f} kN/m", flush=True)
    if MPI.COMM_WORLD.rank == 0:
        os.makedirs(args.out, exist_ok=True)
        with open(os.path.join(args.out, "footing_fe.json"), "w") as f:
            json.dump(rows, f, indent=1)


if __name__ == "__main__":
    sys.exit(main())
