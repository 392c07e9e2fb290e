#!/usr/bin/python3
"""Cost and agreement of the demcell tangent operators (001 sections 3-5).

For each size: a packing at 10 N/m (000 Table 3 law: kn 1e4, ks 2e3, mu 0.4), a biaxial
pre-strain of 0.5 % (lateral stress held), then the four operators of ``DemCell.tangent``
timed (CPU seconds) and compared with PSTLO (max |C - C_pstlo| / max |C_pstlo|). The
perturbation CTO includes sliding, so it differs from the elastic operators by design.

    /usr/bin/python3 benchmarks/dem/dem_tangent.py --out results/dem_tangent
"""
import argparse
import json
import os
import time

import numpy as np

import demcell as dc


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sizes", type=int, nargs="+", default=[228, 400, 4000])
    p.add_argument("--out", default="results/dem_tangent")
    a = p.parse_args(argv)
    os.makedirs(a.out, exist_ok=True)
    rows = []
    law = dc.ContactLaw(kn=1e4, ks=2e3, friction=0.4)
    dc.generate_packing(20, seed=1)                     # JIT warm-up outside the timings
    for n in a.sizes:
        st, info = dc.generate_packing(n, pressure=10.0, law=law, seed=1)
        cell = dc.DemCell(st, law)
        F = cell.deformation_gradient()
        F[0, 0] *= 0.995
        cell.set_deformation(F)
        res = cell.solve(stress_mask=[[False, False], [False, True]], stress_target=np.diag([0.0, -10.0]))
        cell.commit()
        row = dict(n=n, prestrain_converged=res.converged, sliding_fraction=cell.homogenized().sliding_fraction)
        ops = {}
        for kind in ("kruyt", "pstlo", "pstlo_sliding", "demqo", "perturbation"):
            if kind.startswith("pstlo"):
                cell.tangent(kind)                       # compile once
            t0 = time.process_time()
            ops[kind] = cell.tangent(kind)
            row[f"cpu_s_{kind}"] = time.process_time() - t0
        ref = ops["pstlo"]
        for kind, C in ops.items():
            row[f"rel_diff_{kind}_vs_pstlo"] = float(np.abs(C - ref).max() / np.abs(ref).max())
            row[f"C_{kind}"] = C.tolist()
        rows.append(row)
        with open(os.path.join(a.out, "dem_tangent.json"), "w") as f:
            json.dump(rows, f, indent=2)
        print(f"N={n:5d} sliding {row['sliding_fraction']:.3f} | cpu s: " + ", ".join(
            f"{k} {row[f'cpu_s_{k}']:.3f}" for k in ops) + " | rel. diff vs pstlo: " + ", ".join(
            f"{k} {row[f'rel_diff_{k}_vs_pstlo']:.2e}" for k in ops if k != "pstlo"), flush=True)


if __name__ == "__main__":
    main()
