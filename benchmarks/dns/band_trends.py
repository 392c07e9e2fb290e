"""Thesis 004 section 7.4.4 through the multiscale path: how the shear band's thickness changes
with the contact's tangential stiffness and friction, in the DNS and in FEM x DEM.

The thesis varies its particle model's tangential stiffness E_t over 50, 100 and 125 N/m at
mu = 0.8, and mu over 0.4, 0.8 and 1.0 at E_t = 100 N/m, and finds that E_t has "a distinct
influence" on the band and mu "no influence" (docs/results/dns.md repeats that study on the
thesis' own specimen). Here the same relative changes, x 0.5, x 1 and x 1.25 of each, act on
the law of the FEM x DEM cell (kn = 1e4 N/m, ks = 2e3 N/m, mu = 0.4), so that one law feeds
both paths:

* ``base``: ks = 2e3 N/m, mu = 0.4 (the thesis' E_t = 100, mu = 0.8);
* ``ks0.5``, ``ks1.25``: ks = 1e3, 2.5e3 N/m (E_t = 50, 125);
* ``mu0.5``, ``mu1.25``: mu = 0.2, 0.5 (mu = 0.4, 1.0).

Each law runs

* **the DNS** (``--models dns``): the tiled-cell DNS 2x4 of benchmarks/dns/dns_band.py (the
  cell of the seed, with this law, tiled 2 across and 4 up; servo side walls, smooth platens)
  to 8 % axial strain for each seed, its band measured from the grains exactly as dns_band.py
  does (the patch-corrected H of the bell of eq. 4.22 fitted to the incremental shear strain of
  the windows 4-6 % and 6-8 %, single bands only); serial processes, one Numba thread each;
* **FEM x DEM** (``--models hybrid,micropolar``, under ``mpirun``): the weak-corner biaxial
  test of benchmarks/dns/continuum_bands.py on the same 10 x 20 mm specimen (the DNS 2x4 in
  grain diameters) with the cells of seed --femdem-seed and this law (the weak cells at half
  its friction), measured as there (gamma of the symmetric increment from --window-from to the
  end, at the Gauss points outside the weak corner; a run that stopped before the window from
  its peak). The hybrid runs take l_c = --l-c-d50 x d50; its default, 0.04 d50, is the DNS's
  own internal length (benchmarks/dns/band_couple_stress.py, docs/results/dns_vs_femdem.md).

The report gives, per law and path, the band H / d50 (the DNS as its mean +- standard
deviation over the seeds with a single band), and the thesis' test (dns-spec D5): the relative
range of H over the three stiffnesses and over the three frictions, (max - min) / the base
law's H, for each path. A path reproduces the DNS's trend where its ranges order as the
DNS's do and each change of H has the DNS's sign where the DNS's change exceeds its scatter.

Every run is a record in --out (resumable: a case with a record is not run again; the DNS
runs are those of dns_vs_femdem.py, the FEM x DEM ones those of femdem_cases.run_case):

    python3 benchmarks/dns/band_trends.py --models dns --out results/band_trends                 # 15 runs, ~30 CPU min
    mpirun -n 2 python3 benchmarks/dns/band_trends.py --models hybrid,micropolar --out results/band_trends
    python3 benchmarks/dns/band_trends.py --report-only --out results/band_trends

Outputs in --out: the records, band_trends.json (every measure), band_trends.md (the tables)
and band_trends.png (H / d50 against the change of ks and of mu, per path).
"""
import argparse
import json
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))

from benchmarks.dns import continuum_bands as cb  # noqa: E402
from benchmarks.dns import dns_band  # noqa: E402
from benchmarks.dns import dns_vs_femdem as dvf  # noqa: E402
from benchmarks.dns.dns_band import fmt  # noqa: E402
from benchmarks.femdem.femdem_cases import parse_mesh, settings  # noqa: E402

BASE_KS, BASE_FRICTION = 2.0e3, 0.4      # the cell's law [N/m], [-] (demos' defaults, 000 Table 3)
#: law name -> (ks [N/m], friction): the thesis' E_t 50 / 100 / 125 and mu 0.4 / 0.8 / 1.0 as
#: changes of the cell's law by the same factors
LAWS = {"base": (BASE_KS, BASE_FRICTION),
        "ks0.5": (0.5 * BASE_KS, BASE_FRICTION), "ks1.25": (1.25 * BASE_KS, BASE_FRICTION),
        "mu0.5": (BASE_KS, 0.5 * BASE_FRICTION), "mu1.25": (BASE_KS, 1.25 * BASE_FRICTION)}
#: the three laws of each parameter, in increasing order
SERIES = {"ks": ("ks0.5", "base", "ks1.25"), "mu": ("mu0.5", "base", "mu1.25")}
PATHS = ("dns", "hybrid", "micropolar")
DNS_TILES = (2, 4)
DNS_STRAIN = 0.08
#: the DNS's windows of the table (axial strain [%]): its peaks are at 2-4 %
DNS_WINDOWS = ("4-6 %", "6-8 %")
#: both windows together: the DNS's H of the trend test (a single band in either window counts;
#: with one window alone a law has too few single bands to compare over seeds)
BOTH_WINDOWS = "4-8 %"
DNS_COLUMNS = DNS_WINDOWS + (BOTH_WINDOWS,)
#: the DNS's own internal length (band_couple_stress.py, seed 0: 0.041 d50) [d50]
GRAINS_L_C_D50 = 0.04


# %% The DNS runs
def dns_runs(seeds, laws):
    return [{"label": f"dns-2x4-{law}-s{seed}", "kind": "dns", "size": list(DNS_TILES), "seed": int(seed),
             "locked": False, "anisotropy": None, "study": f"dns-2x4-{law}", "law": law,
             "ks": LAWS[law][0], "friction": LAWS[law][1]} for law in laws for seed in seeds]


def window_key(w):
    return f"{abs(100 * w['axial_strain'][0]):.0f}-{abs(100 * w['axial_strain'][1]):.0f} %"


def dns_measures(out, runs):
    """{law: {"runs": [...], window: (mean H / d50, std, single bands, runs)}} from the DNS
    records in out (each run's windows measured as dns_band.py measures them)."""
    by_law = {}
    for rec in dvf.load_records(out, runs):
        windows = dns_band.run_bands(os.path.join(out, rec["label"]), dns_band.PATCH_RADIUS)
        entry = by_law.setdefault(rec["law"], {"runs": []})
        entry["runs"].append({
            "label": rec["label"], "seed": rec["seed"], "peak_stress_ratio": rec["peak_stress_ratio"],
            "axial_strain_at_peak": rec["axial_strain_at_peak"], "cpu_s": rec["cpu_s"],
            "windows": [{"window": window_key(w), "band": w["band"], "why": w["no_band_reason"],
                         "H": dns_band.corrected(w["thickness_over_d50"], dns_band.PATCH_RADIUS) if w["band"] else None,
                         "inclination_deg": w["inclination_deg"]} for w in windows]})
    for entry in by_law.values():
        for key, windows in [(w, (w,)) for w in DNS_WINDOWS] + [(BOTH_WINDOWS, DNS_WINDOWS)]:
            hs = [w["H"] for r in entry["runs"] for w in r["windows"] if w["window"] in windows and w["band"]]
            n_runs = sum(1 for r in entry["runs"] for w in r["windows"] if w["window"] in windows)
            mean, sd, n = dns_band.mean_sd(hs)
            entry[key] = (mean, sd, n, n_runs)
    return by_law


# %% The FEM x DEM runs
def femdem_label(model, law, mesh, l_c_d50):
    lc = f"_lc{l_c_d50:g}" if model == "hybrid" else ""
    return f"{model}{lc}_{law}_{mesh[0]}x{mesh[1]}"


def run_femdem(comm, a, model, law, mesh, scale, log):
    """One weak-corner FEM x DEM run of continuum_bands with the law's cells: its record."""
    d50, d_mean, _ = scale
    ks, friction = LAWS[law]
    extra = {"l_c": a.l_c_d50 * d50} if model == "hybrid" else {}
    s = settings(mesh=mesh, particles=a.particles, mode=model, axial_strain=a.axial_strain, steps=a.steps,
                 weak_size=cb.WEAK_SIZE, weak_friction_factor=cb.FEMDEM_WEAK_FRICTION, grain_diameter=d_mean,
                 cell={"seed": a.femdem_seed, "ks": ks, "friction": friction}, **extra)
    label = femdem_label(model, law, mesh, a.l_c_d50)
    record = cb.run_with_budget(comm, a.out, label, s, a.case_minutes, a.window_from, log)
    return dict(record, model=model, law=law)


def femdem_measure(record, d50):
    """continuum_bands' band of a FEM x DEM record, with the peak and how far it ran."""
    row = cb.row(record, d50)
    return {"label": record["label"], "mesh": row["mesh"], "h_over_d50": row["h_over_d50"], "band": row["band"],
            "reached": row["reached"], "window_from": row["window_from"], "stopped": row["stopped"],
            "peak_stress_ratio": record.get("peak_stress_ratio"), "wall_s": row["wall"], "cpu_s": row["cpu"]}


# %% The trend test
def relative_ranges(h):
    """{parameter: (max - min) / H(base)} of {law: H} over each SERIES, None where a law has no H."""
    out = {}
    for name, laws in SERIES.items():
        values = [h.get(law) for law in laws]
        out[name] = (None if any(v is None for v in values) or not values[1]
                     else (max(values) - min(values)) / values[1])
    return out


def changes(h):
    """{parameter: (H(low) - H(base), H(high) - H(base))} of {law: H}, None where missing."""
    out = {}
    for name, (low, base, high) in SERIES.items():
        out[name] = tuple(None if h.get(x) is None or h.get(base) is None else h[x] - h[base] for x in (low, high))
    return out


def change_scatter(sd, law):
    """The scatter of H(law) - H(base) from {law: standard deviation}: the root sum of squares
    of the two laws' deviations; None where `law` has none (a single band)."""
    return None if sd.get(law) is None else float(np.hypot(sd[law], sd["base"] or 0.0))


def sign_agreement(path_change, dns_change, dns_sd):
    """'same', 'opposite' or 'DNS within its scatter' for one change of H."""
    if path_change is None or dns_change is None:
        return "-"
    if dns_sd is None or abs(dns_change) <= dns_sd:
        return "DNS within its scatter"
    return "same" if np.sign(path_change) == np.sign(dns_change) else "opposite"


# %% The report
def report(dns, femdem, d50, a):
    lines = [f"d50 = {d50 * 1e3:.4f} mm (the FEM x DEM specimen 10 x 20 mm = the DNS 2x4, "
             f"{cb.WIDTH / d50:.1f} x {cb.HEIGHT / d50:.1f} d50); DNS seeds {a.seeds}, to {100 * DNS_STRAIN:g} %; "
             f"FEM x DEM seed {a.femdem_seed}, mesh {a.mesh}, to {100 * a.axial_strain:g} % in {a.steps} steps, "
             f"the window from {100 * a.window_from:g} %; hybrid l_c = {a.l_c_d50:g} d50", ""]
    head = "| law | ks [N/m] | mu | DNS peak stress ratio (seeds) | " + " | ".join(
        f"DNS H / d50, {w} (single bands / windows)" for w in DNS_COLUMNS) + " | " + " | ".join(
        f"{m} H / d50 (verdict) | {m} peak, reached [%]" for m in PATHS[1:]) + " |"
    lines += [head, "|" + "---|" * (4 + len(DNS_COLUMNS) + 2 * (len(PATHS) - 1))]
    for law, (ks, mu) in LAWS.items():
        d = dns.get(law, {})
        peaks = [r["peak_stress_ratio"] for r in d.get("runs", []) if r["peak_stress_ratio"] is not None]
        pm, ps, pn = dns_band.mean_sd(peaks)
        cells = [f"{fmt(pm, '.3f')} +- {fmt(ps, '.3f')} ({pn})"]
        for w in DNS_COLUMNS:
            mean, sd, n, runs = d.get(w, (None, None, 0, 0))
            cells.append(f"{fmt(mean)} +- {fmt(sd)} ({n} / {runs})")
        for model in PATHS[1:]:
            m = femdem.get(model, {}).get(law)
            if m is None:
                cells += ["not run", "-"]
                continue
            b = m["band"]
            h = fmt(b.get("thickness_over_d50"))
            cells.append(f"**{h}**" if b["band"] else f"({h}; {b.get('why', '')[:60]})")
            cells.append(f"{fmt(m['peak_stress_ratio'], '.3f')}, {m['reached']:.2f}")
        lines.append(f"| {law} | {ks:g} | {mu:g} | " + " | ".join(cells) + " |")
    # the trend test per path
    lines += ["", "The thesis' test (dns-spec D5): the relative range of H over the three values of each "
              "parameter, (max - min) / H(base); the changes of H from the base law (low, high) and whether "
              "each has the DNS's sign (a FEM x DEM H counts whatever the verdict, as a reading of its field):", "",
              "| path | range over ks | range over mu | ks: H(x0.5) - H, H(x1.25) - H | mu: H(x0.5) - H, H(x1.25) - H "
              "| signs against the DNS (ks low, ks high, mu low, mu high) |", "|---|---|---|---|---|---|"]
    def dns_column(w, i):     # {law: mean H (i = 0) or its standard deviation (i = 1)} of a DNS column
        return {law: dns.get(law, {}).get(w, (None, None))[i] for law in LAWS}
    paths = {f"DNS {w}": dns_column(w, 0) for w in DNS_COLUMNS}
    paths.update({model: {law: m["band"].get("thickness_over_d50") for law, m in femdem.get(model, {}).items()}
                  for model in PATHS[1:]})
    ref_changes, ref_sd = changes(paths[f"DNS {BOTH_WINDOWS}"]), dns_column(BOTH_WINDOWS, 1)
    for name, h in paths.items():
        rr, ch = relative_ranges(h), changes(h)
        signs = "-"
        if not name.startswith("DNS"):
            signs = ", ".join(sign_agreement(ch[p][i], ref_changes[p][i], change_scatter(ref_sd, SERIES[p][2 * i]))
                              for p in SERIES for i in (0, 1))
        lines.append(f"| {name} | {fmt(rr['ks'])} | {fmt(rr['mu'])} | "
                     f"{', '.join(fmt(v, '+.2f') for v in ch['ks'])} | {', '.join(fmt(v, '+.2f') for v in ch['mu'])} | "
                     f"{signs} |")
    lines += ["", f"(signs against the DNS's H over both windows ({BOTH_WINDOWS}); its change counts as beyond its "
              "scatter where it exceeds the root sum of squares of the two laws' standard deviations over the seeds "
              "and windows; with one single band a law has no deviation, and its change counts as within)"]
    lines += ["", "Every run:", "", "| run | law | window | band | H / d50 | inclination [deg] | peak stress ratio | "
              "CPU s | stopped |", "|---|---|---|---|---|---|---|---|---|"]
    for law in LAWS:
        for r in dns.get(law, {}).get("runs", []):
            for w in r["windows"]:
                if w["window"] in DNS_WINDOWS:
                    verdict = "yes" if w["band"] else "no: " + w["why"][:60]
                    lines.append(f"| {r['label']} | {law} | {w['window']} | {verdict} "
                                 f"| {fmt(w['H'])} | {fmt(w['inclination_deg'], '+.0f')} | "
                                 f"{fmt(r['peak_stress_ratio'], '.3f')} | {r['cpu_s']:.0f} | |")
        for model in PATHS[1:]:
            m = femdem.get(model, {}).get(law)
            if m is None:
                continue
            b = m["band"]
            window = "-" if m["window_from"] is None else f"{m['window_from']:.1f}-{m['reached']:.1f} %"
            verdict = "yes" if b["band"] else "no: " + b.get("why", "")[:60]
            lines.append(f"| {m['label']} | {law} | {window} | {verdict} | "
                         f"{fmt(b.get('thickness_over_d50'))} | {fmt(b.get('inclination_deg'), '+.0f')} | "
                         f"{fmt(m['peak_stress_ratio'], '.3f')} | {m['cpu_s']:.0f} | {m['stopped'][:60]} |")
    return lines


def figure(dns, femdem, path):
    from cosserat_fenicsx.figures import pyplot
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.8), sharey=True)
    factors = (0.5, 1.0, 1.25)
    for ax, (name, laws) in zip(axes, SERIES.items()):
        for w, style, alpha in ((BOTH_WINDOWS, "ko-", 1.0), (DNS_WINDOWS[0], "k^:", 0.4), (DNS_WINDOWS[1], "kv:", 0.4)):
            vals = [dns.get(law, {}).get(w, (None, None))[:2] for law in laws]
            xs = [f for f, (m, _) in zip(factors, vals) if m is not None]
            ax.errorbar(xs, [m for m, _ in vals if m is not None], yerr=[s or 0.0 for m, s in vals if m is not None],
                        fmt=style, alpha=alpha, capsize=3, label=f"DNS 2x4, {w}")
        for j, model in enumerate(PATHS[1:]):
            ms = [femdem.get(model, {}).get(law) for law in laws]
            pts = [(f, m) for f, m in zip(factors, ms) if m is not None and m["band"].get("thickness_over_d50")]
            if not pts:
                continue
            ax.plot([f for f, _ in pts], [m["band"]["thickness_over_d50"] for _, m in pts], "-", color=f"C{j}", lw=0.8)
            for f, m in pts:
                ax.plot(f, m["band"]["thickness_over_d50"], "D", color=f"C{j}",
                        mfc=None if m["band"]["band"] else "none",
                        label=(f"FEM x DEM {model}, {m['mesh']} (h = {m['h_over_d50']:.1f} d50)"
                               if (f, m) == pts[0] else None))
        ax.set_xlabel(f"{'ks' if name == 'ks' else 'mu'} / its base value ({'2e3 N/m' if name == 'ks' else '0.4'})")
        ax.set_xticks(factors)
    axes[0].set_ylabel("band H / d50 (open: not a band by the verdict)")
    axes[0].legend(fontsize=7)
    fig.suptitle("004 section 7.4.4 through the multiscale path: the band against the contact law", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


# %% Main
def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], allow_abbrev=False,
                                formatter_class=argparse.RawDescriptionHelpFormatter,
                                epilog=__doc__.split("\n\n", 1)[1])
    p.add_argument("--out", default="results/band_trends")
    p.add_argument("--models", default=",".join(PATHS), help=f"comma list out of {','.join(PATHS)} (dns: serial "
                                                              "processes, run it without mpirun)")
    p.add_argument("--laws", default=",".join(LAWS), help=f"comma list out of {','.join(LAWS)}")
    p.add_argument("--seeds", default=dvf.DEFAULT_SEEDS, help="DNS packing seeds (default: the seeds whose cell tiles)")
    p.add_argument("--femdem-seed", type=int, default=0, help="packing seed of the FEM x DEM cells (default 0)")
    p.add_argument("--particles", type=int, default=dvf.CELL_DISCS)
    p.add_argument("--mesh", default="4x8", help="FEM x DEM mesh NXx2NX, whole elements in the 5 mm weak corner")
    p.add_argument("--l-c-d50", type=float, default=GRAINS_L_C_D50,
                   help=f"internal length of the hybrid runs in d50 (default {GRAINS_L_C_D50:g}: the DNS's own)")
    p.add_argument("--axial-strain", type=float, default=0.04)
    p.add_argument("--steps", type=int, default=20)
    p.add_argument("--window-from", type=float, default=0.02, help="the FEM x DEM window starts at this axial strain")
    p.add_argument("--case-minutes", type=float, default=10.0, help="wall budget of a FEM x DEM case")
    p.add_argument("--report-only", action="store_true")
    a = p.parse_args(argv)
    models = [m for m in a.models.split(",") if m]
    laws = [x for x in a.laws.split(",") if x]
    bad = sorted(set(models) - set(PATHS)) + sorted(set(laws) - set(LAWS))
    if bad:
        p.error(f"unknown models or laws {bad}; models from {','.join(PATHS)}, laws from {','.join(LAWS)}")
    try:
        mesh = parse_mesh(a.mesh)
        seeds = [int(s) for s in a.seeds.split(",") if s.strip()]
    except ValueError as error:
        p.error(str(error))
    weak_elements = cb.WEAK_SIZE * mesh[0] / cb.WIDTH
    if mesh[1] != 2 * mesh[0] or abs(weak_elements - round(weak_elements)) > 1e-9:
        p.error(f"mesh {a.mesh}: NXx2NX with whole elements in the 5 mm weak corner (2x4, 4x8, 6x12, ...)")
    if not a.l_c_d50 > 0:
        p.error("--l-c-d50 must be > 0")
    if not 0.0 < a.window_from < a.axial_strain < 0.5:
        p.error("need 0 < --window-from < --axial-strain < 0.5")
    try:
        cb.check_cell_options(mesh, a.particles, a.femdem_seed, a.axial_strain, a.steps, a.case_minutes)
    except ValueError as error:
        p.error(str(error))
    from mpi4py import MPI
    comm = MPI.COMM_WORLD
    if "dns" in models and not a.report_only and comm.size > 1:
        p.error("the DNS runs are serial processes: run --models dns without mpirun")
    log = lambda t: comm.rank == 0 and print(t, flush=True)  # noqa: E731
    os.makedirs(a.out, exist_ok=True)
    runs = dns_runs(seeds, laws)
    if "dns" in models and not a.report_only:
        for run in dvf.pending(runs, a.out):
            dvf.execute(run, a.out, DNS_STRAIN, 0.002, 1, 1, log=log)
    scale = cb.grain_scale(a.femdem_seed, a.particles)
    d50 = scale[0]
    records = []
    for model in (m for m in PATHS[1:] if m in models):
        for law in laws:
            label = femdem_label(model, law, mesh, a.l_c_d50)
            path = os.path.join(a.out, f"{label}.json")
            if a.report_only:
                if not os.path.isfile(path):
                    continue
                with open(path) as f:
                    records.append(dict(json.load(f), model=model, law=law))
            else:
                records.append(run_femdem(comm, a, model, law, mesh, scale, log))
    if comm.rank != 0:
        return
    femdem = {}
    for record in records:
        femdem.setdefault(record["model"], {})[record["law"]] = femdem_measure(record, d50)
    dns = dns_measures(a.out, runs) if "dns" in models else {}
    dvf.write_json(os.path.join(a.out, "band_trends.json"), {"dns": dns, "femdem": femdem, "d50": d50})
    lines = [f"Run: `benchmarks/dns/band_trends.py {' '.join(argv if argv is not None else sys.argv[1:])}` · "
             f"{time.strftime('%Y-%m-%d')} · load {os.getloadavg()[0]:.2f}", ""] + report(dns, femdem, d50, a)
    with open(os.path.join(a.out, "band_trends.md"), "w") as f:
        f.write("\n".join(lines) + "\n")
    print("\n".join(lines))
    figure(dns, femdem, os.path.join(a.out, "band_trends.png"))


if __name__ == "__main__":
    main()
