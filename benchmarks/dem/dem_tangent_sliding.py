#!/usr/bin/python3
"""How far the network tangents are from the cell's real response where contacts slide.

The macro Newton of FEM x DEM re-solves every cell from its committed state at each iterate,
so the derivative of what it solves for is the consistent tangent, CTO (001 eq. 6: the cell
rolled back and re-solved at F + eps L^mn). PSTLO (001 appendix B) linearises the network
with every contact sticking; pstlo_sliding lets the contacts at or near their Coulomb limit
(|fs| >= r mu fn) slide on (demcell/tangent.py). This measures both against CTO on the FEM x
DEM reference cell (CellOptions: 10 N/m, kn 1e4, ks 2e3, mu 0.4, unbalanced-force ratio 1e-3)
committed at a biaxial pre-strain e (F = diag(1 + e/2, 1 - e)) and then solved one Newton-sized
increment de further (a load step's first iterate), for slip ratios r = 0 (PSTLO) and --ratios:

* full: |C - C_cto| / |C_cto| (Frobenius);
* loading: |C D - s| / |s|, D the loading direction (dF11, dF22) = (1/2, -1) and s the secant
  (sigma(F + 1e-4 D) - sigma(F)) / 1e-4 of two solves from the committed state at the
  perturbation's tight tolerance: what a Newton correction along the load sees; CTO's own
  error on it is printed as the yardstick.

    /usr/bin/python3 benchmarks/dem/dem_tangent_sliding.py --out results/benchmarks/dem_tangent_sliding

A few minutes for 228 and 400 discs (five CTOs per size and increment). Writes
dem_tangent_sliding.json and .txt in --out.
"""
import argparse
import json
import os
import time

import numpy as np

import demcell as dc
from demcell.tangent import perturbation_options, perturbation_tangent, pstlo_operator

LOADING = np.array([0.5, 0.0, 0.0, -1.0])     # 001 order 11, 12, 21, 22
SECANT = 1e-4


def biaxial(e):
    return np.array([[1 + 0.5 * e, 0.0], [0.0, 1 - e]])


def secant(cell, F):
    """(sigma(F + SECANT D) - sigma(F)) / SECANT, both solved from the committed state with
    the tolerance of a perturbation of this size."""
    opts = perturbation_options(cell, SECANT)
    out = []
    for dF in (0.0, SECANT):
        c = cell.copy()
        c.rollback()
        c.options = opts
        c.set_deformation(F + dF * LOADING.reshape(2, 2))
        c.solve()
        out.append(c.cauchy_stress().reshape(4).copy())
    return (out[1] - out[0]) / SECANT


def main(argv=None):
    from cosserat_fenicsx.materials.dem import CellOptions
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sizes", type=int, nargs="+", default=[228, 400])
    p.add_argument("--ratios", type=float, nargs="+", default=[0.95, 0.9, 0.85, 0.8])
    p.add_argument("--pre-strains", type=float, nargs="+", default=[0.004, 0.01, 0.016, 0.024, 0.032])
    p.add_argument("--increments", type=float, nargs="+", default=[1e-3, 2e-3])
    p.add_argument("--out", default="results/benchmarks/dem_tangent_sliding")
    a = p.parse_args(argv)
    if any(not 0 < r <= 1 for r in a.ratios):
        p.error("--ratios must be in (0, 1]")
    os.makedirs(a.out, exist_ok=True)
    ratios = [0.0] + a.ratios
    rows, lines = [], []
    start = time.process_time()
    for n in a.sizes:
        options = CellOptions(particles=n)
        state, _ = options.packing_state()
        ref = dc.reference_cell(state, options.law(), options.relaxation(), options.pressure)
        for e in a.pre_strains:
            committed = ref.copy()
            committed.set_deformation(biaxial(e))
            committed.solve()
            committed.commit()
            for de in a.increments:
                cell = committed.copy()
                F = biaxial(e + de)
                cell.set_deformation(F)
                cell.solve()
                st = cell.state
                touching = st.touching[:st.n_pairs] == 1
                mu = cell.law.friction
                fn, fs = st.fn[:st.n_pairs][touching], np.abs(st.fs[:st.n_pairs][touching])
                C_cto, _ = perturbation_tangent(cell, eps=1e-5)
                s = secant(cell, F)
                row = dict(particles=n, pre_strain=e, increment=de, contacts=int(touching.sum()),
                           near_limit={str(r): int(np.sum((fn > 0) & (fs >= r * mu * fn))) for r in ratios[1:]},
                           cto_loading_error=float(np.linalg.norm(C_cto @ LOADING - s) / np.linalg.norm(s)), errors={})
                for r in ratios:
                    C = pstlo_operator(st, cell.law_array, slip_ratio=r)
                    row["errors"][str(r)] = dict(
                        full=float(np.linalg.norm(C - C_cto) / np.linalg.norm(C_cto)),
                        loading=float(np.linalg.norm(C @ LOADING - s) / np.linalg.norm(s)))
                rows.append(row)
                line = (f"{n:5d} {100 * e:5.1f} {100 * de:5.2f} {row['contacts']:5d} {row['cto_loading_error']:6.3f} | "
                        + " | ".join(f"{row['errors'][str(r)]['full']:.2f} {row['errors'][str(r)]['loading']:.2f}"
                                     for r in ratios))
                lines.append(line)
                print(line, flush=True)
                with open(os.path.join(a.out, "dem_tangent_sliding.json"), "w") as f:
                    json.dump(dict(ratios=ratios, rows=rows), f, indent=1)
    head = ("discs  e[%] de[%] cont. CTO(load) | " + " | ".join(
        "PSTLO full load" if r == 0 else f"r={r:g} full load" for r in ratios))
    summary = ["", "range over the states (full / loading):"]
    for r in ratios:
        full = [row["errors"][str(r)]["full"] for row in rows]
        load = [row["errors"][str(r)]["loading"] for row in rows]
        summary.append(f"  {'PSTLO' if r == 0 else f'r = {r:g}'}: {min(full):.2f}-{max(full):.2f} / "
                       f"{min(load):.2f}-{max(load):.2f}")
    cto = [row["cto_loading_error"] for row in rows]
    summary.append(f"  CTO on the loading secant: {min(cto):.3f}-{max(cto):.3f}")
    summary.append(f"CPU {time.process_time() - start:.0f} s, load average {os.getloadavg()[0]:.2f}")
    text = "\n".join([head] + lines + summary)
    print("\n".join(summary))
    with open(os.path.join(a.out, "dem_tangent_sliding.txt"), "w") as f:
        f.write(text + "\n")


if __name__ == "__main__":
    main()
