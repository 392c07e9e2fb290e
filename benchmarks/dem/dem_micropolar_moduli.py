#!/usr/bin/python3
"""Micropolar moduli of isotropic disordered packings: cell size and paper 003.

For each cell size N (discs) and seed: a packing at 10 N/m (000 Table 3 law: kn 1e4 N/m,
ks 2e3 N/m; compacted frictionless), its reference cell with friction 0.4 (isotropic stage,
force criterion 1e-5), then, for each rolling stiffness kr, a micropolar cell on that same
state and two 6x6 operators in the FE callback order (rows sigma11, sigma22, sigma12,
sigma21, m31, m32; columns eps11, eps22, eps12, eps21, kappa31, kappa32):

* 'pstlo' (network): the frozen contact network solved exactly (demcell/network.py), with
  periodic displacement and rotation fluctuations and the mean rotation held (weights: the
  normal force each disc carries, demcell.network.contact_weights);
* 'kruyt' (affine): the uniform-field operator (no fluctuation, no pre-stress), the
  assumption of 003 eqs 21-24.

Isotropic moduli (lambda, G, mu_c [N/m], B [N m]) are read off both with
estimates.uniform_strain_moduli (least squares, with its anisotropy residual) and compared
with paper 003 eqs 21-24 (estimates.cosserat_moduli_003: N = touching contacts, r = mean
radius, V = cell area, L = half the cell width, k_omega = kr), with the 2D isotropic
uniform-strain averages of the measured fabric (docs/reference/micropolar_cell.md, "Origin of the
factors", with <|D|^2> for l^2) and, for B, with the continuum cell estimate
estimates.periodic_bending_estimate(B0, mu_c, G, L) (B0 = (kr/|Y|) sum |D|^2 / 2, the rolling
part). The B-vs-L slope (log-log least squares over all cells) answers the RVE question:
the theory note predicts B ~ L for ks > 0 (a property of the cell, not of the material).
A DEMQO cross-check (6 frozen-contact relaxations) of the network operator is run on the
first cell.

    nice /usr/bin/python3 benchmarks/dem/dem_micropolar_moduli.py --out out/dem_micropolar_moduli

Outputs in --out: results.csv (one row per cell and kr), summary.json, table.md,
B_vs_L.png, moduli_vs_L.png. Units: stresses and lambda, G, mu_c [N/m] (2D), couple stress
[N], kappa [1/m], B [N m]; lengths [m]; l_c = sqrt(B / (2 mu_c)) in mean grain diameters.
"""
import argparse
import csv
import json
import math
import os
import time

import numpy as np

import demcell as dc
from demcell import estimates as est
from demcell.network import contact_weights

KN, KS, MU, PRESSURE = 1.0e4, 2.0e3, 0.4, 10.0
R_MEAN_NOMINAL = 0.0125      # mean of the radii, uniform in [0.01, 0.015] m (generate_packing defaults)
KR_DEFAULT = 0.1 * KN * R_MEAN_NOMINAL ** 2     # 0.156 N m/rad = 0.1 kn <R>^2


def branch_vectors(state):
    """Reference branch vectors D_k = h_ref (s_j - s_i + n_k) of the touching contacts (n, 2) [m]."""
    k = np.flatnonzero(state.touching[:state.n_pairs] == 1)
    ds = state.s[state.pair_j[k]] - state.s[state.pair_i[k]]
    ds -= np.round(ds)
    return ds @ state.h_ref.T


def fit_slope(L, B):
    """Least-squares slope and its standard error of log B against log L."""
    x, y = np.log(np.asarray(L)), np.log(np.asarray(B))
    A = np.column_stack((x, np.ones_like(x)))
    coef, res, *_ = np.linalg.lstsq(A, y, rcond=None)
    dof = max(len(x) - 2, 1)
    s2 = float(np.sum((y - A @ coef) ** 2)) / dof
    cov = s2 * np.linalg.inv(A.T @ A)
    return float(coef[0]), float(math.sqrt(cov[0, 0])), float(coef[1])


def measure_cell(ref_state, info, kr, n, seed, options):
    """All moduli of one prepared state under the micropolar law with rolling stiffness kr."""
    law = dc.ContactLaw(kn=KN, ks=KS, friction=MU, rolling_stiffness=kr)
    cell = dc.DemCell(ref_state.copy(), law, options, reset_reference=False, rotation_mode="micropolar")
    st = cell.state
    t0 = time.process_time()
    C_net = cell.tangent("pstlo", measure="micropolar")
    cpu_net = time.process_time() - t0
    C_aff = cell.tangent("kruyt", measure="micropolar")
    net, aff = est.uniform_strain_moduli(C_net), est.uniform_strain_moduli(C_aff)
    area = abs(np.linalg.det(st.h_ref))
    L = math.sqrt(area)
    R = float(st.radius.mean())
    d = 2.0 * R
    D = branch_vectors(st)
    n_c = D.shape[0]
    l2 = float(np.mean(np.sum(D * D, axis=1)))
    # 2D isotropic uniform-strain averages with the measured N <l^2> / V
    c2 = n_c * l2 / area
    iso = dict(lambda_=c2 * (KN - KS) / 8.0, G=c2 * (KN + KS) / 8.0, mu_c=c2 * KS / 4.0)
    B0 = kr * c2 / 2.0          # rolling part (kr/|Y|) sum |D|^2 / 2 (mean of the diagonal)
    m003 = est.cosserat_moduli_003(n_c, R, area, KN, KS, kr=0.0, k_omega=kr, length=L / 2.0)
    B_cont = est.periodic_bending_estimate(B0, net["mu_c"], net["G"], L)
    w = contact_weights(st)
    sig = cell.cauchy_stress()
    row = dict(n=n, seed=seed, kr=kr, L=L, L_over_d=L / d, R_mean=R, contacts=n_c,
               coordination=info["coordination_number"], solid_fraction=info["solid_fraction"],
               rattler_fraction=float(np.mean(w == 0)),      # discs outside the rotation constraint
               ref_pressure=float(-0.5 * np.trace(sig)), ref_skew=float(sig[0, 1] - sig[1, 0]),
               ref_m_norm=float(np.linalg.norm(cell.couple_stress())), cpu_s_pstlo=cpu_net)
    for tag, m in (("net", net), ("aff", aff)):
        for k in ("lambda_", "G", "mu_c", "bending", "residual_stress", "residual_couple", "coupling", "residual"):
            row[f"{tag}_{k.rstrip('_')}"] = m[k]
    for tag, m in (("net", net), ("aff", aff)):
        B = m["bending"]
        row[f"{tag}_B_over_ksR2"] = B / (KS * R * R)
        row[f"{tag}_B_over_mucL2"] = B / (m["mu_c"] * L * L)
        row[f"{tag}_lc_over_d"] = math.sqrt(max(B, 0.0) / (2.0 * m["mu_c"])) / d
        # theory note: relaxed B ~ c mu_eff R L for kr = 0 (hexagonal lattice: c = 0.60-0.67)
        mu_eff = m["mu_c"] * m["G"] / (m["mu_c"] + m["G"])
        row[f"{tag}_B_over_mueffRL"] = B / (mu_eff * R * L)
    row.update(iso_lambda=iso["lambda_"], iso_G=iso["G"], iso_mu_c=iso["mu_c"], B0_rolling=B0,
               B_continuum=B_cont, p003_lambda=m003["lambda_"], p003_G=m003["G"], p003_G_c=m003["G_c"],
               p003_l_c=m003["l_c"], p003_B=m003["bending"])
    if kr > 0.0:
        # ks = 0 check: no contact resists the skew strain, so the theory note expects
        # m = (kr/|Y|) sum D (x) D kappa whatever the cell size (exact for the lattice)
        law0 = dc.ContactLaw(kn=KN, ks=0.0, friction=MU, rolling_stiffness=kr)
        cell0 = dc.DemCell(ref_state.copy(), law0, options, reset_reference=False, rotation_mode="micropolar")
        row["net_B_ks0"] = est.uniform_strain_moduli(cell0.tangent("pstlo", measure="micropolar"))["bending"]
        row["net_B_ks0_over_B0"] = row["net_B_ks0"] / B0
    return row, cell, C_net


def demqo_check(cell, C_net):
    """DEMQO (frozen contacts, 6 relaxations) against the network operator on one cell."""
    t0 = time.process_time()
    C_q = cell.tangent("demqo", measure="micropolar")
    cpu = time.process_time() - t0
    mq, mn = est.uniform_strain_moduli(C_q), est.uniform_strain_moduli(C_net)
    return dict(rel_diff_max=float(np.abs(C_q - C_net).max() / np.abs(C_net).max()),
                rel_diff_stress_block=float(np.abs(C_q[:4, :4] - C_net[:4, :4]).max() / np.abs(C_net[:4, :4]).max()),
                rel_diff_couple_block=float(np.abs(C_q[4:, 4:] - C_net[4:, 4:]).max() / np.abs(C_net[4:, 4:]).max()),
                rel_diff_B=float(abs(mq["bending"] - mn["bending"]) / abs(mn["bending"])),
                B_demqo=mq["bending"], B_pstlo=mn["bending"], cpu_s_demqo=cpu,
                steps=int(cell.last_tangent_steps))


def mean_std(rows, key):
    v = np.array([r[key] for r in rows], dtype=float)
    return float(v.mean()), float(v.std(ddof=1)) if len(v) > 1 else 0.0


def table(rows, sizes, krs, slopes):
    """Markdown table: mean (std over seeds) per size and kr."""
    head = ("| kr [N m] | N | seeds | L/d | lambda | G | mu_c | B net [N m] | B affine | B 003 | B contin. "
            "| B/(ks R^2) | B/(mu_c L^2) | B/(mu_eff R L) | l_c/d | resid. net |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for kr in krs:
        for n in sizes:
            rs = [r for r in rows if r["n"] == n and r["kr"] == kr]
            if not rs:
                continue

            def f(key, fmt="{:.3g}"):
                m, s = mean_std(rs, key)
                return (fmt.format(m) + (" (" + fmt.format(s) + ")" if len(rs) > 1 else ""))
            lines.append(f"| {kr:.3g} | {n} | {len(rs)} | {f('L_over_d', '{:.1f}')} | {f('net_lambda', '{:.0f}')} | "
                         f"{f('net_G', '{:.0f}')} | {f('net_mu_c', '{:.0f}')} | {f('net_bending')} | "
                         f"{f('aff_bending')} | {f('p003_B')} | {f('B_continuum')} | {f('net_B_over_ksR2')} | "
                         f"{f('net_B_over_mucL2')} | {f('net_B_over_mueffRL')} | "
                         f"{f('net_lc_over_d', '{:.2f}')} | {f('net_residual', '{:.2f}')} |")
    aff = [r for r in rows if r["kr"] == krs[0]]     # the affine lambda, G, mu_c do not depend on kr
    lines.append("")
    lines.append("Affine (uniform-field) moduli, all cells: lambda %.0f (%.0f), G %.0f (%.0f), mu_c %.0f (%.0f) N/m; "
                 "003 eqs 21-23: lambda %.0f, G %.0f, G_c %.0f N/m; 2D isotropic average of the fabric: lambda %.0f, "
                 "G %.0f, mu_c %.0f N/m." % (
                     *mean_std(aff, "aff_lambda"), *mean_std(aff, "aff_G"), *mean_std(aff, "aff_mu_c"),
                     mean_std(aff, "p003_lambda")[0], mean_std(aff, "p003_G")[0], mean_std(aff, "p003_G_c")[0],
                     mean_std(aff, "iso_lambda")[0], mean_std(aff, "iso_G")[0], mean_std(aff, "iso_mu_c")[0]))
    for kr in krs:
        if kr > 0.0:
            lines.append("")
            lines.append(f"ks = 0 check (kr = {kr:.3g}): network B / B0 with B0 = (kr/|Y|) sum |D|^2 / 2: " + ", ".join(
                "N = %d: %.3f (%.3f), B0 %.3g N m" % (n, *mean_std([r for r in rows if r["n"] == n and r["kr"] == kr],
                                                               "net_B_ks0_over_B0"),
                                                   mean_std([r for r in rows if r["n"] == n and r["kr"] == kr],
                                                            "B0_rolling")[0])
                for n in sizes if any(r["n"] == n and r["kr"] == kr for r in rows)))
    lines.append("")
    lines.append("log-log slope of B against L (all cells, +- standard error): " + "; ".join(
        f"kr = {kr:.3g}: network {slopes[kr]['net'][0]:.2f} +- {slopes[kr]['net'][1]:.2f}, "
        f"affine {slopes[kr]['aff'][0]:.2f} +- {slopes[kr]['aff'][1]:.2f}" for kr in krs))
    return "\n".join(lines)


def figures(rows, krs, slopes, out):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6.4, 4.8))
    colours = ["C0", "C3", "C2", "C4"]
    for c, kr in zip(colours, krs):
        rs = [r for r in rows if r["kr"] == kr]
        L = np.array([r["L"] for r in rs])
        Ls = np.linspace(L.min(), L.max(), 50)
        for tag, mk, name in (("net", "o", "network"), ("aff", "s", "affine")):
            B = np.array([r[f"{tag}_bending"] for r in rs])
            sl, se, b = slopes[kr][tag]
            ax.loglog(L, B, mk, color=c, mfc="none" if tag == "aff" else c, ms=5,
                      label=f"{name}, kr={kr:.3g}: slope {sl:.2f}")
            ax.loglog(Ls, np.exp(b) * Ls ** sl, "-" if tag == "net" else ":", color=c, lw=1)
        B003 = np.array([r["p003_B"] for r in rs])
        o = np.argsort(L)
        ax.loglog(L[o], B003[o], "--", color=c, lw=1, alpha=0.7, label=f"003 G l_c^2, kr={kr:.3g}")
    ax.set_xlabel("cell width L [m]")
    ax.set_ylabel("B = dm/dkappa [N m]")
    ax.set_title("Couple-stress modulus vs cell size (kn 1e4, ks 2e3 N/m)")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(os.path.join(out, "B_vs_L.png"), dpi=130)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(6.4, 4.8))
    rs = [r for r in rows if r["kr"] == krs[0]]
    L = np.array([r["L"] for r in rs])
    for c, key, k003 in (("C0", "lambda", "p003_lambda"), ("C1", "G", "p003_G"), ("C2", "mu_c", "p003_G_c")):
        ax.plot(L, [r[f"net_{key}"] for r in rs], "o", color=c, label=f"{key} network")
        ax.plot(L, [r[f"aff_{key}"] for r in rs], "s", mfc="none", color=c, label=f"{key} affine")
        ax.axhline(float(np.mean([r[k003] for r in rs])), color=c, ls="--", lw=1,
                   label=f"003 {'G_c' if key == 'mu_c' else key}")
    ax.set_xscale("log")
    ax.set_xlabel("cell width L [m]")
    ax.set_ylabel("modulus [N/m]")
    ax.set_title(f"lambda, G, mu_c vs cell size (kr = {krs[0]:.3g})")
    ax.legend(fontsize=7, ncol=3)
    fig.tight_layout()
    fig.savefig(os.path.join(out, "moduli_vs_L.png"), dpi=130)
    plt.close(fig)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sizes", type=int, nargs="+", default=[100, 228, 400, 1000, 2000, 4000])
    p.add_argument("--seeds", type=int, default=5, help="seeds 1..S per size")
    p.add_argument("--seeds-large", type=int, default=3, help="seeds for sizes above 1000")
    p.add_argument("--kr", type=float, nargs="+", default=[0.0, KR_DEFAULT],
                   help="rolling stiffnesses [N m/rad] (default 0 and 0.1 kn (12.5 mm)^2)")
    p.add_argument("--no-demqo", action="store_true", help="skip the DEMQO cross-check")
    p.add_argument("--out", default="out/dem_micropolar_moduli")
    a = p.parse_args(argv)
    os.makedirs(a.out, exist_ok=True)
    load_start = os.getloadavg()
    wall0, cpu0 = time.time(), time.process_time()
    prep_law = dc.ContactLaw(kn=KN, ks=KS)
    ref_law = dc.ContactLaw(kn=KN, ks=KS, friction=MU)
    options = dc.RelaxationOptions(criterion="force", tol=1e-5)
    rows, demqo = [], {}
    for n in a.sizes:
        for seed in range(1, (a.seeds if n <= 1000 else a.seeds_large) + 1):
            t0 = time.time()
            st, info = dc.generate_packing(n, pressure=PRESSURE, law=prep_law, seed=seed)
            ref = dc.reference_cell(st, ref_law, options, PRESSURE)
            t_prep = time.time() - t0
            for kr in a.kr:
                row, cell, C_net = measure_cell(ref.state, info, kr, n, seed, options)
                row["wall_s_prep"] = t_prep
                rows.append(row)
                if not a.no_demqo and n == a.sizes[0] and seed == 1:
                    demqo[f"kr={kr:g}"] = dict(n=n, seed=seed, **demqo_check(cell, C_net))
                print(f"N={n:5d} seed {seed} kr {kr:.3g}: L/d {row['L_over_d']:.1f} z {row['coordination']:.2f} | "
                      f"net lambda {row['net_lambda']:.0f} G {row['net_G']:.0f} mu_c {row['net_mu_c']:.0f} "
                      f"B {row['net_bending']:.4g} (resid {row['net_residual']:.2f}) | affine B {row['aff_bending']:.4g}"
                      f" | 003 B {row['p003_B']:.4g} | prep {t_prep:.1f} s", flush=True)
    slopes = {}
    for kr in a.kr:
        rs = [r for r in rows if r["kr"] == kr]
        slopes[kr] = {tag: fit_slope([r["L"] for r in rs], [r[f"{tag}_bending"] for r in rs])
                      for tag in ("net", "aff")}
    md = table(rows, a.sizes, a.kr, slopes)
    if demqo:
        md += "\n\nDEMQO vs network (N = %d, seed 1): " % a.sizes[0] + "; ".join(
            f"{k}: max |dC|/max|C| {v['rel_diff_max']:.2e} (stress block {v['rel_diff_stress_block']:.2e}, "
            f"couple block {v['rel_diff_couple_block']:.2e}), B {v['rel_diff_B']:.2e}, {v['cpu_s_demqo']:.1f} CPU s"
            for k, v in demqo.items())
    figures(rows, a.kr, slopes, a.out)
    with open(os.path.join(a.out, "results.csv"), "w", newline="") as f:
        keys = list(dict.fromkeys(k for r in rows for k in r))
        wr = csv.DictWriter(f, fieldnames=keys, restval="")
        wr.writeheader()
        wr.writerows(rows)
    summary = dict(
        law=dict(kn=KN, ks=KS, friction=MU, pressure=PRESSURE, kr=a.kr),
        sizes=a.sizes, seeds=a.seeds, seeds_large=a.seeds_large,
        slopes={f"kr={kr:g}": {tag: dict(slope=v[0], stderr=v[1]) for tag, v in s.items()}
                for kr, s in slopes.items()},
        per_size={f"kr={kr:g}": {str(n): {k: mean_std([r for r in rows if r["n"] == n and r["kr"] == kr], k)
                                         for k in ("L", "L_over_d", "net_lambda", "net_G", "net_mu_c",
                                                   "net_bending", "aff_bending", "p003_B", "B_continuum",
                                                   "net_B_over_ksR2", "net_B_over_mucL2", "net_B_over_mueffRL",
                                                   "net_lc_over_d",
                                                   "net_residual", "aff_residual")}
                                 for n in a.sizes if any(r["n"] == n for r in rows)} for kr in a.kr},
        demqo_check=demqo,
        wall_s=time.time() - wall0, cpu_s=time.process_time() - cpu0,
        loadavg_start=load_start, loadavg_end=os.getloadavg())
    with open(os.path.join(a.out, "summary.json"), "w") as f:
        json.dump(summary, f, indent=2)
    md += (f"\n\nwall {summary['wall_s']:.0f} s, CPU {summary['cpu_s']:.0f} s, load average "
           f"{load_start[0]:.2f} at start, {summary['loadavg_end'][0]:.2f} at end")
    with open(os.path.join(a.out, "table.md"), "w") as f:
        f.write(md + "\n")
    print(md)


if __name__ == "__main__":
    main()
