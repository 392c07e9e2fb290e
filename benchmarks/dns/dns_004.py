"""The particle biaxial test of 004 chapter 7 and its parameter study (section 7.4.4).

Runs demos/dem_specimen.py (the thesis specimen: Table 7.1 law, membrane and pressure arcs,
platens at 0.03 m/s each) for the base case and the five parameter runs of 004 section 7.4.4
(E_t = 50, 100, 125 N/m at mu = 0.8; mu = 0.4, 0.8, 1.0 at E_t = 100 N/m; the base case is
shared), then reads each run's summary and per-disc fields and checks what the thesis states
in words (dns-spec Part C):

* D1: localisation visible by 90 s, one band dominating by 120 s (the fitted bell's
  amplitude grows and the band is found), a lateral "nose" at 340 s (the largest lateral
  displacement of the free sides at the band's height against the sides' mean);
* D2: at 120 s the in-band mean (|d| < H) of |eps|, |kappa|, |M| and |T21 - T12| against the
  out-of-band mean (|d| > 3H), each at least 3x (dns-spec's threshold);
* D3: the moment balance 7.47, the Pearson correlation of div M with -(T21 - T12);
* D5: the band thickness H at 120 s and 340 s: its relative range over E_t against the range
  over mu (the thesis: E_t has "a distinct influence", mu "no influence").

The thesis gives none of these as numbers (only in figures, which did not survive), so this
is a comparison of trends, reported with the measured numbers.

    /usr/bin/python3 benchmarks/dns/dns_004.py --out results/benchmarks/dns_004             # 29,982 discs
    /usr/bin/python3 benchmarks/dns/dns_004.py --nx 40 --ny 92 --out DIR                    # 3,680 discs
    /usr/bin/python3 benchmarks/dns/dns_004.py --cases base --out DIR                        # the base case only
    /usr/bin/python3 benchmarks/dns/dns_004.py --report-only --out DIR

Outputs in --out: one folder per case (the demo's outputs), dns_004.json (everything) and
dns_004.md (the tables). The times of 004 (90, 120, 340 s) refer to its specimen height,
which the text does not give (dns-spec A1); a smaller --ny reaches the same strains earlier,
so --scale-times (default: on when --ny differs from 263) scales the snapshot times by the
height ratio.
"""
import argparse
import json
import math
import os
import subprocess
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
DEMO = os.path.join(ROOT, "demos", "dem_specimen.py")

#: 004 section 7.4.4: name -> (E_t [N/m], mu)
CASES = {"base": (100.0, 0.8), "Et50": (50.0, 0.8), "Et125": (125.0, 0.8), "mu04": (100.0, 0.4),
         "mu10": (100.0, 1.0)}
THESIS_TIMES = (0.0, 90.0, 120.0, 340.0)
THESIS_ROWS = 263


def run_case(name, args, out):
    ks, mu = CASES[name]
    scale = args.ny / THESIS_ROWS if args.scale_times else 1.0
    times = [t * scale for t in THESIS_TIMES]
    cmd = [sys.executable, DEMO, "--nx", str(args.nx), "--ny", str(args.ny), "--ks", repr(ks), "--friction", repr(mu),
           "--duration", repr(times[-1]), "--snapshots", ",".join(repr(t) for t in times),
           "--output-every", repr(max(0.1, round(times[-1] / 340.0, 1))), "--out", out]
    if args.threads:
        cmd += ["--threads", str(args.threads)]
    if args.perturbation:
        cmd += ["--perturbation", repr(args.perturbation)]
    print(f"[dns_004] {name}: {' '.join(cmd[1:])}", flush=True)
    t0 = time.time()
    c0 = os.times()
    with open(os.path.join(out, "run.log"), "w") as log:
        proc = subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT, cwd=ROOT)
    c1 = os.times()
    return {"command": " ".join(cmd), "returncode": proc.returncode, "wall_s": time.time() - t0,
            "cpu_s": (c1.children_user - c0.children_user) + (c1.children_system - c0.children_system),
            "load_average": list(os.getloadavg()), "snapshot_times": times}


def band_distance(position, band):
    """Signed distance of each point to the band axis [m] (004 eq. 4.22's d, x1 vertical)."""
    alpha = math.radians(band["inclination_deg"])
    return (position[:, 1] - band["x10"]) * math.cos(alpha) - position[:, 0] * math.sin(alpha)


def concentration(fields, band):
    """D2: in-band (|d| < H) over out-of-band (|d| > 3H) means of the REV fields."""
    d = band_distance(fields["position"], band["band_fit"])
    H = band["band_thickness"]
    ok = fields["valid"]
    inside, outside = ok & (np.abs(d) < H), ok & (np.abs(d) > 3 * H)
    out = {}
    for name, values in (("eps_norm", fields["eps_norm"]), ("kappa_norm", fields["kappa_norm"]),
                         ("m_norm", fields["m_norm"]), ("abs_skew", np.abs(fields["skew"]))):
        a, b = np.nanmean(values[inside]), np.nanmean(values[outside])
        out[name] = {"in_band": float(a), "out_of_band": float(b), "ratio": float(a / b) if b > 0 else None}
    out["discs_in_band"] = int(inside.sum())
    out["discs_out_of_band"] = int(outside.sum())
    return out


def nose(fields):
    """The lateral bulge at 340 s: max over the free-side discs of |u_x| against their mean
    |u_x| (the 'nose-like deformation figure' of 004 Fig. 7.9), and its height [m]."""
    side = fields["excluded"] & np.isfinite(fields["displacement"][:, 0])
    ux = np.abs(fields["displacement"][side, 0])
    if ux.size == 0:
        return None
    k = int(np.argmax(ux))
    return {"max_lateral_displacement": float(ux[k]), "mean_lateral_displacement": float(ux.mean()),
            "height_of_max": float(fields["position"][side][k, 1])}


def analyse(name, out, record):
    path = os.path.join(out, "summary.json")
    if not os.path.isfile(path):
        return dict(record, completed=False)
    s = json.load(open(path))
    rec = dict(record, completed=s.get("completed"), reason=s.get("reason"), n_discs=s.get("n_discs"),
               peak_stress_ratio=s.get("peak_stress_ratio"), axial_strain_at_peak=s.get("axial_strain_at_peak"),
               cpu_seconds_loop=s.get("cpu_seconds"), contact_updates_per_cpu_second=s.get("contact_updates_per_cpu_second"),
               dem_steps=s.get("dem_steps"), isotropic=s.get("isotropic"))
    rec["bands"] = [{k: b.get(k) for k in ("time", "axial_strain", "band", "band_thickness", "band_inclination_deg",
                                           "thickness_over_diameter", "no_band_reason", "invalid_rev_fraction")}
                    | {"amplitude": (b.get("band_fit") or {}).get("amplitude"),
                       "offset": (b.get("band_fit") or {}).get("offset")}
                    for b in s.get("bands", [])]
    rec["balance"] = s.get("balance", [])
    bands = s.get("bands", [])
    if len(bands) >= 3 and bands[2].get("band"):
        fields = dict(np.load(os.path.join(out, "particles", "fields_0002.npz")))
        rec["concentration_120"] = concentration(fields, bands[2])
    if len(bands) >= 4:
        fields = dict(np.load(os.path.join(out, "particles", "fields_0003.npz")))
        rec["nose_340"] = nose(fields)
    return rec


def table(results, args, d5):
    lines = [f"Run: `/usr/bin/python3 benchmarks/dns/dns_004.py --nx {args.nx} --ny {args.ny}` · "
             f"{time.strftime('%Y-%m-%d')} · load average {os.getloadavg()[0]:.1f}", "",
             "| case | E_t [N/m] | mu | discs | completed | H at 90 s | H at 120 s | H at 340 s [m] | inclination at 120 s | "
             "peak stress ratio | wall / CPU s |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for name, r in results.items():
        ks, mu = CASES[name]

        def h(k):
            b = r.get("bands", [])
            return f"{b[k]['band_thickness']:.3g}" if len(b) > k and b[k]["band"] else "no band"
        incl = r.get("bands", [{}] * 3)
        incl = f"{incl[2]['band_inclination_deg']:.1f}" if len(incl) > 2 and incl[2].get("band") else "-"
        peak = f"{r['peak_stress_ratio']:.3f}" if r.get("peak_stress_ratio") is not None else "-"
        lines.append(f"| {name} | {ks:g} | {mu:g} | {r.get('n_discs')} | {r.get('completed')} | {h(1)} | {h(2)} | {h(3)} "
                     f"| {incl} | {peak} | {r['wall_s']:.0f} / {r['cpu_s']:.0f} |")
    if "base" in results and results["base"].get("concentration_120"):
        c = results["base"]["concentration_120"]
        lines += ["", "D2, base case at 120 s: in-band (|d| < H) over out-of-band (|d| > 3H) means (dns-spec: >= 3)", "",
                  "| field | in band | out of band | ratio |", "|---|---|---|---|"]
        for k in ("eps_norm", "kappa_norm", "m_norm", "abs_skew"):
            lines.append(f"| {k} | {c[k]['in_band']:.3g} | {c[k]['out_of_band']:.3g} | "
                         f"{c[k]['ratio']:.2f} |" if c[k]["ratio"] is not None else f"| {k} | - | - | - |")
    if d5:
        lines += ["", f"D5: relative range of H at 120 s over E_t {d5['Et_range_120']}, over mu {d5['mu_range_120']}; "
                  f"at 340 s over E_t {d5['Et_range_340']}, over mu {d5['mu_range_340']}"]
    return "\n".join(lines) + "\n"


def relative_range(values):
    values = [v for v in values if v is not None]
    if len(values) < 2:
        return None
    return round(float((max(values) - min(values)) / np.mean(values)), 3)


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--nx", type=int, default=114)
    p.add_argument("--ny", type=int, default=263)
    p.add_argument("--cases", nargs="+", choices=tuple(CASES), default=list(CASES))
    p.add_argument("--threads", type=int, default=None)
    p.add_argument("--perturbation", type=float, default=0.0)
    p.add_argument("--scale-times", choices=("yes", "no", "auto"), default="auto")
    p.add_argument("--report-only", action="store_true")
    p.add_argument("--out", default="results/benchmarks/dns_004")
    args = p.parse_args()
    args.scale_times = args.scale_times == "yes" or (args.scale_times == "auto" and args.ny != THESIS_ROWS)
    os.makedirs(args.out, exist_ok=True)
    path = os.path.join(args.out, "dns_004.json")
    results = json.load(open(path)) if os.path.isfile(path) else {}
    for name in args.cases:
        out = os.path.join(args.out, name)
        os.makedirs(out, exist_ok=True)
        record = results.get(name, {}) if args.report_only else run_case(name, args, out)
        results[name] = analyse(name, out, {k: record.get(k) for k in ("command", "returncode", "wall_s", "cpu_s",
                                                                        "load_average", "snapshot_times")})
        with open(path, "w") as f:
            json.dump(results, f, indent=2)

    def thickness(name, k):
        b = results.get(name, {}).get("bands", [])
        return b[k]["band_thickness"] if len(b) > k and b[k]["band"] else None
    results["D5"] = {f"{what}_range_{t}": relative_range([thickness(n, k) for n in names])
                     for what, names in (("Et", ("Et50", "base", "Et125")), ("mu", ("mu04", "base", "mu10")))
                     for t, k in (("120", 2), ("340", 3))}
    with open(path, "w") as f:
        json.dump(results, f, indent=2)
    text = table({k: v for k, v in results.items() if k in CASES}, args, results["D5"])
    with open(os.path.join(args.out, "dns_004.md"), "w") as f:
        f.write(text)
    print(text)

if __name__ == "__main__":
    main()
