"""The couple stress of the grains across the band, and the DNS's own internal length.

Thesis 004 (section 7.4.3, Figs 7.13-7.14) shows the couple stress and the curvature of its
particle model concentrated in the shear band. This benchmark measures them across the band
of the tiled-cell DNS (benchmarks/dns/dns_band.py's dns-2x4 runs: the per-disc REV fields of
004 eqs 7.38-7.42 that demos/dem_specimen.py writes with every snapshot) and across the bands
of the micropolar continua of benchmarks/dns/continuum_bands.py (micropolar and hybrid FEM x
DEM, Ehlers at k_sigma = 0), along the same cut: the distance d to the band axis of each
run's own fitted band (thesis eq. 4.22), in d50.

**The profiles.** |m| = |(m31, m32)| and |kappa| = |(kappa31, kappa32)| at the discs (DNS)
or the Gauss points (continua), binned by d / d50 (bins of one d50), the median of each bin;
|m| is shown as |m| / (G d50) and |kappa| as |kappa| d50, G the shear modulus of each model
(the cell's initial shear modulus G = d sigma12 / d gamma for the DNS and FEM x DEM, the
calibrated mu for Ehlers), so that the three can share an axis.

**The DNS's own l_c.** Where the couple stress is elastic, m = 2 G l_c^2 kappa (the hybrid and
Ehlers law with mu_c = G; 004 eq. 2.74). Inside the band (|d| <= H) the estimate is

    l_c = sqrt(median |m| / (2 G median |kappa|)),

in d50. On the hybrid and Ehlers runs it returns the imposed l_c (both laws are elastic in
the couple stress: k_mu = 0), the check of the estimator; on the DNS it is what the issue
asks: the length a continuum with the same G would need to carry the grains' couple stress
at the grains' curvature.

The DNS band is the fit of dns_band.py's last window with a single band (6-8 % or 4-6 %);
the fields are those of the window's end. A seed without a band is listed and left out.

    python3 benchmarks/dns/band_couple_stress.py --dns results/dns_band --continua results/continuum_bands \\
        --out results/band_couple_stress

Outputs in --out: band_couple_stress.md (the l_c table) and band_couple_stress.png (the
profiles).
"""
import argparse
import json
import math
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))

from benchmarks.dns import continuum_bands as cb  # noqa: E402
from benchmarks.dns import dns_band  # noqa: E402
from benchmarks.dns.dns_band import fmt  # noqa: E402
from benchmarks.dns.dns_004 import band_distance  # noqa: E402

#: models of continuum_bands.py that carry a rotation field
MICROPOLAR_MODELS = ("micropolar", "hybrid", "ehlers")
BIN = 1.0          # bin width of the profiles [d50]
REACH = 15.0       # the profiles span |d| <= REACH d50


def cell_shear_modulus(seed, particles):
    """The initial shear modulus [N/m] of the seed's reference cell (the hybrid mode's mu_c)."""
    from cosserat_fenicsx.materials.dem import CellOptions, initial_shear_modulus, reference_cells
    cells, _ = reference_cells(CellOptions(particles=particles, seed=seed), [0.4])
    return initial_shear_modulus(cells[0])


def profile(d, m, kappa, G, d50):
    """Bin centres [d50] and the medians of |m| / (G d50) and |kappa| d50 per bin."""
    edges = np.arange(-REACH, REACH + BIN, BIN)
    x = d / d50
    centres, mm, kk = [], [], []
    for lo, hi in zip(edges[:-1], edges[1:]):
        inside = (x >= lo) & (x < hi)
        if inside.sum() >= 3:
            centres.append(0.5 * (lo + hi))
            mm.append(float(np.median(m[inside])) / (G * d50))
            kk.append(float(np.median(kappa[inside])) * d50)
    return {"d_over_d50": centres, "m_over_G_d50": mm, "kappa_d50": kk}


def concentration(d, m, kappa, H):
    """In-band (|d| <= H) over out-of-band (|d| > 3 H) medians of |m| and |kappa|, and the
    Pearson correlation of |m| with |kappa| in the band (1 for an elastic couple-stress law)."""
    inside, outside = np.abs(d) <= H, np.abs(d) > 3.0 * H
    if inside.sum() < 3 or outside.sum() < 3:
        return {"m_ratio": None, "kappa_ratio": None, "pearson_in_band": None}
    r = np.corrcoef(m[inside], kappa[inside])[0, 1] if np.ptp(m[inside]) > 0 and np.ptp(kappa[inside]) > 0 else None
    return {"m_ratio": float(np.median(m[inside]) / np.median(m[outside])),
            "kappa_ratio": float(np.median(kappa[inside]) / np.median(kappa[outside])),
            "pearson_in_band": None if r is None else float(r)}


def internal_length(d, m, kappa, G, H):
    """sqrt(median|m| / (2 G median|kappa|)) over the points with |d| <= H [length unit of d]."""
    inside = np.abs(d) <= H
    if inside.sum() < 3:
        return None
    km = float(np.median(kappa[inside]))
    return math.sqrt(float(np.median(m[inside])) / (2.0 * G * km)) if km > 0 else None


def dns_runs(directory, G):
    """One entry per dns-2x4 run of dns_band.py's --out: its band and its l_c."""
    with open(os.path.join(directory, "dns_band.json")) as f:
        results = json.load(f)
    out = []
    for label, r in sorted(results.items()):
        if r["study"] != "dns-2x4":
            continue
        banded = [w for w in r["windows"] if w["band"]]
        entry = {"label": label, "seed": r["seed"], "band": bool(banded)}
        if banded:
            w = banded[-1]
            fields = dict(np.load(os.path.join(directory, label, "particles", w["window"][1])))
            ok = np.asarray(fields["valid"], bool) & ~np.asarray(fields["excluded"], bool)
            ok &= np.isfinite(fields["m3x"]) & np.isfinite(fields["k3x"])
            d = band_distance(fields["position"][ok], w["fit"])
            m = np.hypot(fields["m3x"][ok], fields["m3y"][ok])
            kappa = np.hypot(fields["k3x"][ok], fields["k3y"][ok])
            d50 = w["d50"]
            H = dns_band.corrected(w["thickness_over_d50"], dns_band.PATCH_RADIUS) * d50
            l_c = internal_length(d, m, kappa, G, H)
            entry.update(window=f"{abs(100 * w['axial_strain'][0]):.0f}-{abs(100 * w['axial_strain'][1]):.0f} %",
                         H_over_d50=H / d50, l_c_over_d50=None if l_c is None else l_c / d50,
                         profile=profile(d, m, kappa, G, d50), **concentration(d, m, kappa, H))
        out.append(entry)
    return out


def continuum_runs(directory, d50, G_cell):
    """One entry per record of continuum_bands.py with a rotation field and a fitted band."""
    out = []
    for name in sorted(os.listdir(directory)):
        if not name.endswith(".json"):
            continue
        with open(os.path.join(directory, name)) as f:
            rec = json.load(f)
        model = rec.get("model") or rec.get("mode")
        if model not in MICROPOLAR_MODELS or not rec.get("couple_stress") or not rec.get("window_strain_increment"):
            continue
        nx, _ = rec["mesh"]
        band = cb.measure(rec["points"], rec["window_strain_increment"], cb.WIDTH / nx, d50)
        entry = {"label": rec["label"], "model": model, "mesh": "x".join(map(str, rec["mesh"])),
                 "band": band["band"], "why": band["why"],
                 "imposed_l_c_over_d50": rec["l_c"] / d50 if model in ("hybrid", "ehlers") and rec.get("l_c") else None}
        if band.get("fit") is not None and band["fit"]["converged"] and band["thickness_over_d50"] < REACH:
            # also where the verdict refuses the band (too thin for the mesh, too wide for
            # the specimen): the fields across the fitted axis are still the model's
            G = rec["mu_c"] if model == "ehlers" else G_cell
            d = band_distance(np.asarray(rec["points"]), band["fit"])
            m = np.linalg.norm(np.asarray(rec["couple_stress"]), axis=1)
            kappa = np.linalg.norm(np.asarray(rec["curvature"]), axis=1)
            H = band["thickness_over_d50"] * d50
            l_c = internal_length(d, m, kappa, G, H)
            entry.update(H_over_d50=band["thickness_over_d50"], l_c_over_d50=None if l_c is None else l_c / d50,
                         profile=profile(d, m, kappa, G, d50), **concentration(d, m, kappa, H))
        out.append(entry)
    return out


def figure(dns, continua, path):
    from cosserat_fenicsx.figures import pyplot
    plt = pyplot()
    fig, ax = plt.subplots(1, 2, figsize=(11, 4))
    for e in dns:
        if "profile" in e:
            p = e["profile"]
            ax[0].plot(p["d_over_d50"], p["m_over_G_d50"], "k-", lw=1, alpha=0.7, label=f"DNS seed {e['seed']}")
            ax[1].plot(p["d_over_d50"], p["kappa_d50"], "k-", lw=1, alpha=0.7, label=f"DNS seed {e['seed']}")
    finest = {}       # the finest mesh of each model and internal length
    for c in continua:
        key = (c["model"], c["imposed_l_c_over_d50"])
        if "profile" in c and (key not in finest or int(c["mesh"].split("x")[0]) > int(finest[key]["mesh"].split("x")[0])):
            finest[key] = c
    for i, e in enumerate(finest.values()):
        p = e["profile"]
        ax[0].plot(p["d_over_d50"], p["m_over_G_d50"], "o--", ms=3, color=f"C{i}", label=e["label"])
        ax[1].plot(p["d_over_d50"], p["kappa_d50"], "o--", ms=3, color=f"C{i}", label=e["label"])
    ax[0].set_ylabel("|m| / (G d50), median per bin"); ax[1].set_ylabel("|kappa| d50, median per bin")
    for a in ax:
        a.set_xlabel("distance from the band axis d / d50"); a.set_yscale("log"); a.legend(fontsize=6)
    fig.tight_layout(); fig.savefig(path, dpi=120)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], allow_abbrev=False,
                                formatter_class=argparse.RawDescriptionHelpFormatter,
                                epilog=__doc__.split("\n\n", 1)[1])
    p.add_argument("--dns", required=True, help="dns_band.py's --out (with the dns-2x4 runs)")
    p.add_argument("--continua", required=True, help="continuum_bands.py's --out")
    p.add_argument("--seed", type=int, default=0, help="the seed of the continua's cells (continuum_bands.py --seed)")
    p.add_argument("--particles", type=int, default=228)
    p.add_argument("--out", default="results/band_couple_stress")
    a = p.parse_args(argv)
    for path in (os.path.join(a.dns, "dns_band.json"), a.continua):
        if not os.path.exists(path):
            p.error(f"{path} does not exist: run dns_band.py and continuum_bands.py first")
    G = cell_shear_modulus(a.seed, a.particles)
    d50 = cb.grain_scale(a.seed, a.particles)[0]
    dns = dns_runs(a.dns, G)
    continua = continuum_runs(a.continua, d50, G)
    lines = [f"Run: `benchmarks/dns/band_couple_stress.py {' '.join(argv if argv is not None else sys.argv[1:])}` · "
             f"{time.strftime('%Y-%m-%d')}", "",
             f"G of the cell (seed {a.seed}) = {G:.1f} N/m; continua: d50 = {d50 * 1e3:.4f} mm", "",
             "| run | band (window / mesh) | H / d50 | l_c / d50 from the fields | l_c / d50 imposed | "
             "|m| in / out of the band | |kappa| in / out | Pearson r(|m|, |kappa|) in the band |",
             "|---|---|---|---|---|---|---|---|"]

    def tail(e):
        return (f" | {fmt(e.get('m_ratio'))} | {fmt(e.get('kappa_ratio'))} | {fmt(e.get('pearson_in_band'))} |")
    for e in dns:
        lines.append(f"| DNS 2x4 seed {e['seed']} | " + (f"{e['window']} | {fmt(e['H_over_d50'])} | "
                                                      f"**{fmt(e['l_c_over_d50'], '.3f')}** | -" + tail(e)
                                                      if e["band"] else "no single band | - | - | - | - | - | - |"))
    for e in continua:
        where = e["mesh"] if e["band"] else f"{e['mesh']}, not a band: {e['why'][:50]}"
        lines.append(f"| {e['label']} | {where} | {fmt(e.get('H_over_d50'))} | {fmt(e.get('l_c_over_d50'), '.3f')} | "
                     f"{fmt(e['imposed_l_c_over_d50'], '.3f')}" + tail(e))
    estimates = [e["l_c_over_d50"] for e in dns if e.get("l_c_over_d50") is not None]
    if estimates:
        lines += ["", f"DNS l_c / d50 over the seeds with a band: {np.mean(estimates):.3f} "
                      f"(range {min(estimates):.3f}-{max(estimates):.3f}, {len(estimates)} seeds)"]
    os.makedirs(a.out, exist_ok=True)
    with open(os.path.join(a.out, "band_couple_stress.md"), "w") as f:
        f.write("\n".join(lines) + "\n")
    with open(os.path.join(a.out, "band_couple_stress.json"), "w") as f:
        json.dump({"G": G, "d50": d50, "dns": dns, "continua": continua}, f, indent=1)
    print("\n".join(lines))
    figure(dns, continua, os.path.join(a.out, "band_couple_stress.png"))


if __name__ == "__main__":
    main()
