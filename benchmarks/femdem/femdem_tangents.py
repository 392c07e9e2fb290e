#!/usr/bin/env python3
"""Macro Newton operators of FEM x DEM compared on the biaxial test, as 001 Table 1 and
Figs 6-7: the perturbation CTO (001 eq. 6), DEMQO (eq. 20), Kruyt's upper bound (eq. 13)
and PSTLO (appendix B), each driving the same run to 2 % axial strain; and pstlo_sliding
(PSTLO with the contacts on their Coulomb limit sliding, demcell/tangent.py), not in 001.

Per operator: Newton iterations per step before and after the peak, the convergence
velocity of 001 (the inverse of the number of integrations of the loading path, counting
five per iteration for the CTO and one for the others, normalised by PSTLO's), DEM steps
(the cells' real work, tangent relaxations included), wall and CPU time; and the
convergence of FNORM/RNORM against the iteration for one step before and one after the
peak (001 Fig. 6). Writes --out/tangents.txt, tangents.png and one JSON record per run.

    mpirun -n 2 python3 benchmarks/femdem/femdem_tangents.py --out results/femdem_tangents
    mpirun -n 2 python3 benchmarks/femdem/femdem_tangents.py --mesh 4x8 --steps 8 --mode hybrid --weak-friction 0.5 \
        --batched --tangents pstlo pstlo_sliding --out results/benchmarks/femdem_tangents

(the second is the scene of benchmarks/femdem/femdem_cell_relaxation.py: its default run is shared
through the store of benchmarks/femdem/femdem_cases.py when both write beside each other; add
--cell-option method=fire for the FIRE cells).
"""
import argparse
import os

import numpy as np
from mpi4py import MPI

from benchmarks.femdem.femdem_cases import parse_mesh, run_case, settings, table, write_report
from cosserat_fenicsx.validation import key_value

INTEGRATIONS = {"perturbation": 5, "demqo": 1, "kruyt": 1, "pstlo": 1, "pstlo_sliding": 1}


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", default="results/femdem_tangents")
    p.add_argument("--mesh", default="2x4")
    p.add_argument("--particles", type=int, default=228)
    p.add_argument("--axial-strain", type=float, default=0.02)
    p.add_argument("--steps", type=int, default=20)
    p.add_argument("--tangents", nargs="+", default=["pstlo", "demqo", "kruyt", "perturbation"], choices=list(INTEGRATIONS))
    p.add_argument("--mode", default="classical", choices=("classical", "hybrid"))
    p.add_argument("--batched", action="store_true", help="the cells batched (docs/reference/femdem.md)")
    p.add_argument("--cell-option", type=key_value, action="append", default=[], metavar="KEY=VALUE",
                   help="the cells' demcell.RelaxationOptions (e.g. method=fire)")
    p.add_argument("--weak-size", type=float, default=5e-3, help="weak lower left corner [m] (000 has none)")
    p.add_argument("--weak-friction", type=float, default=0.8)
    a = p.parse_args()
    comm = MPI.COMM_WORLD
    nx, ny = parse_mesh(a.mesh)
    records = []
    for tangent in a.tangents:
        # a weaker corner breaks the symmetry, so that the post-peak response is not homogeneous
        s = settings(mesh=(nx, ny), particles=a.particles, cell={"extra": dict(a.cell_option)}, mode=a.mode,
                     tangent=tangent, axial_strain=a.axial_strain, steps=a.steps, weak_size=a.weak_size,
                     weak_friction_factor=a.weak_friction, batched=a.batched)
        label = "_".join([tangent, a.mode, a.mesh, str(a.particles)] + [f"{k}-{v}" for k, v in a.cell_option])
        records.append(run_case(comm, a.out, label, s,
                                log=lambda t: comm.rank == 0 and print(t, flush=True)))
    if comm.rank != 0:
        return
    ref = next((r for r in records if r["tangent"] == "pstlo"), records[0])

    def split(r):
        i = int(np.argmax(r["stress_ratio"]))
        it = np.array(r["newton_iterations"], dtype=float)
        return it[:i + 1], it[i + 1:]

    def velocity(r, part):
        n = split(r)[part].sum() * INTEGRATIONS[r["tangent"]]
        m = split(ref)[part].sum() * INTEGRATIONS[ref["tangent"]]
        return m / n if n else None

    for r in records:
        pre, post = split(r)
        r["it_pre"], r["it_post"] = float(pre.mean()), float(post.mean()) if len(post) else None
        r["v_i"], r["v_p"] = velocity(r, 0), velocity(r, 1)
        r["dem_total"] = float(sum(r["dem_steps"]))
        r["wall_rel"] = 100.0 * r["wall_time"] / ref["wall_time"]
    text = table(records, [("operator", "tangent", "s"), ("peak", "peak_stress_ratio", ".4f"),
                           ("at strain", "axial_strain_at_peak", ".4f"), ("it/step pre", "it_pre", ".2f"),
                           ("it/step post", "it_post", ".2f"), ("V_i", "v_i", ".2f"), ("V_p", "v_p", ".2f"),
                           ("DEM steps", "dem_total", ".3g"), ("wall [s]", "wall_time", ".0f"),
                           ("CPU [s]", "cpu_time", ".0f"), ("wall %", "wall_rel", ".0f"), ("cuts", "cuts", "d"),
                           ("load", "load_average_before", ".1f")])
    head = (f"FEM x DEM biaxial, {a.mode}, mesh {a.mesh} ({records[0]['n_gauss_points']} Gauss points), "
            f"{a.particles} discs{''.join(f', {k}={v}' for k, v in a.cell_option)}, to {a.axial_strain:g} in {a.steps} steps, "
            f"FNORM/RNORM <= 1e-2, {comm.size} ranks\n"
            "V_i, V_p: 001's convergence velocity before / after the peak (1 / integrations of the loading path, "
            "5 per CTO iteration), relative to pstlo\n")
    write_report(a.out, "tangents.txt", head + text)
    plot(records, os.path.join(a.out, "tangents.png"))


def plot(records, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(1, 4, figsize=(17, 4))
    for r in records:
        i_peak = int(np.argmax(r["stress_ratio"]))
        pre = min(max(1, i_peak // 2), len(r["force_ratios"]) - 1)
        post = min(len(r["force_ratios"]) - 1, i_peak + max(2, (len(r["force_ratios"]) - i_peak) // 2))
        line, = ax[0].semilogy(r["force_ratios"][pre], "o-", label=r["tangent"])
        ax[1].semilogy(r["force_ratios"][post], "o-", color=line.get_color(), label=r["tangent"])
        ax[2].plot(-np.array(r["axial_strain"]) * 100, r["newton_iterations"], ".-", color=line.get_color(),
                   label=r["tangent"])
    for a, title in zip(ax[:2], ("before the peak", "after the peak")):
        a.axhline(1e-2, color="k", lw=0.8, ls="--")
        a.set_xlabel("Newton iteration"); a.set_ylabel("FNORM / RNORM"); a.set_title(title); a.legend()
    ax[2].set_xlabel("axial strain [%]"); ax[2].set_ylabel("Newton iterations per step"); ax[2].legend()
    ref = next((r for r in records if r["tangent"] == "pstlo"), records[0])
    ax[3].bar([r["tangent"] for r in records], [100 * r["wall_time"] / ref["wall_time"] for r in records])
    ax[3].set_ylabel("relative wall time (pstlo = 100)")
    fig.suptitle("FEM x DEM Newton operators (001 Figs 6-7)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    main()
