"""The shear band of the tiled-cell DNS measured from its grains: thickness and inclination,
mean and scatter over seeds and tilings, in grain diameters.

Runs the DNS cases of benchmarks/dns/dns_vs_femdem.py (``dns-NXxNY``: demos/dem_specimen.py
--specimen tiled, paper 000's DNS with the FEM x DEM cell of the seed tiled; resumable: a
case whose record OUT/LABEL.json exists is skipped) to --strain, then measures the band of
each run from the per-disc snapshots the demo writes (particles/fields_NNNN.npz at 0, 1/4,
1/2, 3/4 and all of the strain):

1. the incremental displacement of every disc over each window of two consecutive snapshots
   (the table shows the last two: 4-6 % and 6-8 % axial strain at --strain 0.08),
   du = u(end) - u(start);
2. its gradient at each disc by the least-squares quadratic patch fit of demcell's
   ``patch_gradient`` over the discs whose centres lie within PATCH_RADIUS = 3 mean
   diameters (a second measure with WIDE_PATCH_RADIUS = 5) in the window's start configuration. The patch
   smooths: a band of the bell's shape is read wider, in quadrature, H_read^2 = H^2 + s^2
   with s = 1.2 d50 at 3 diameters and 2.0 d50 at 5 (measured on known bands on the
   grains, tests/test_dns_band.py); both H_read and H = sqrt(H_read^2 - s^2) are reported;
3. the incremental equivalent (deviatoric) strain per disc, the largest engineering shear
   strain gamma = sqrt((e_xx - e_yy)^2 + (2 e_xy)^2) of the symmetric part (tension
   positive; in simple shear it is the shear strain itself). It is a norm: a far-field
   increment b beside a band's g reads sqrt(g^2 + b^2) - b in the tails, narrower than the
   band (a 4 d50 band on b = A / 10 reads 3.2 d50), so the contrast A / e0 is reported;
4. the bell of thesis 004 eq. 4.22 fitted to gamma at the discs' positions
   (cosserat_fenicsx.shear_band.fit_band): thickness H (the bell's standard deviation) and
   inclination alpha to the horizontal; H / d50, d50 the median disc diameter by number.

A band is reported when ``band_verdict`` accepts the fit (converged, contrast A >= 0.5 e0,
H at least half a diameter, FWHM inside the specimen) and it is a *single* band: at least
SINGLE_BAND_SHARE of the top decile of gamma lies within 2H of the fitted axis (two crossing
bands of equal strength put about half of it outside). Otherwise the table says why, and
no thickness enters the means. The discs on the walls are left out of the fit (their patch
is one-sided).

    /usr/bin/python3 benchmarks/dns/dns_band.py --out results/dns_band            # 9 runs, about 30 CPU min
    /usr/bin/python3 benchmarks/dns/dns_band.py --cases dns-2x4 --seeds 0 --out DIR
    /usr/bin/python3 benchmarks/dns/dns_band.py --report-only --out DIR

Outputs in --out: the dns_vs_femdem records and demo folders, dns_band.json (every window of
every run) and dns_band.md (the table).
"""
import argparse
import json
import math
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))

from benchmarks.dns import dns_vs_femdem as dvf  # noqa: E402
from benchmarks.dns.dns_004 import band_distance  # noqa: E402
from cosserat_fenicsx.shear_band import band_verdict, fit_band  # noqa: E402

DEFAULT_CASES = "dns-2x4,dns-3x6,dns-4x8"
#: the share of the top decile of the strain that must lie within 2H of the axis for one band
SINGLE_BAND_SHARE = 0.6
#: default patch radius for the strain increment [mean disc diameters]: a smaller patch sees
#: mostly the grains' non-affine motion (at 1.5 diameters no run of the 2x4 DNS shows a band)
PATCH_RADIUS = 3.0
#: the patch radius of the second measure, to show how the patch enters H [mean diameters]
WIDE_PATCH_RADIUS = 5.0
#: the patch widens a band in quadrature, H_read^2 = H^2 + s^2: s [d50] at PATCH_RADIUS and at
#: WIDE_PATCH_RADIUS, measured on known bands on the grains of a tiled cell (tests/test_dns_band.py)
PATCH_WIDENING = {PATCH_RADIUS: 1.2, WIDE_PATCH_RADIUS: 2.0}


# %% The measurement
def neighbours_within(position, radius):
    """(offsets, index): for each point the other points within `radius` [m] (CSR, the
    neighbours argument of demcell's patch_gradient)."""
    from scipy.spatial import cKDTree
    lists = cKDTree(position).query_ball_point(position, radius)
    index = [np.array(sorted(j for j in nb if j != i), dtype=np.int64) for i, nb in enumerate(lists)]
    offsets = np.zeros(len(index) + 1, dtype=np.int64)
    offsets[1:] = np.cumsum([len(a) for a in index])
    return offsets, (np.concatenate(index) if index else np.zeros(0, np.int64))


def strain_increment(position, increment, patch_radius, valid=None):
    """The symmetric strain increment (e_xx, e_yy, e_xy) (n, 3) [-] of the displacement
    increment (n, 2) [m] at each disc, from the patch gradient over the discs within
    patch_radius [m] of position (n, 2) [m]; NaN where no fit."""
    from demcell.specimen.fields import patch_gradient
    n = len(position)
    valid = np.ones(n, bool) if valid is None else np.asarray(valid, bool)
    grad, _ = patch_gradient(position, increment, valid, neighbours_within(position, patch_radius))
    return np.column_stack([grad[:, 0, 0], grad[:, 1, 1], 0.5 * (grad[:, 0, 1] + grad[:, 1, 0])])


def shear_strain(e):
    """The largest engineering shear strain sqrt((e_xx - e_yy)^2 + (2 e_xy)^2) of (n, 3) strains."""
    return np.sqrt((e[:, 0] - e[:, 1]) ** 2 + 4.0 * e[:, 2] ** 2)


def top_decile_share(points, values, fit):
    """The fraction of the discs in the top decile of values within 2H of the fitted axis."""
    top = values >= np.quantile(values, 0.9)
    d = band_distance(points[top], fit.as_dict())
    return float(np.mean(np.abs(d) <= 2.0 * fit.thickness))


def measure_band(points, values, d50, width):
    """Fit and judge one field: a dict with the fit, H / d50, |alpha|, the top-decile share
    and `band` (True) or `no_band_reason`."""
    rec = {"band": False, "no_band_reason": "", "fit": None, "thickness_over_d50": None,
           "inclination_deg": None, "top_decile_share": None}
    try:
        fit = fit_band(points, values)
    except ValueError as error:
        rec["no_band_reason"] = str(error)
        return rec
    ok, why = band_verdict(fit, d50, width)
    share = top_decile_share(points, values, fit) if fit.converged else None
    rec.update(fit=fit.as_dict(), top_decile_share=share, thickness_over_d50=fit.thickness / d50,
               inclination_deg=fit.inclination_deg)
    if ok and share < SINGLE_BAND_SHARE:
        ok, why = False, (f"no single band: {100 * share:.0f} % of the top decile within 2H of the axis "
                          f"(below {100 * SINGLE_BAND_SHARE:.0f} %: crossing bands or diffuse)")
    rec["band"], rec["no_band_reason"] = ok, why
    return rec


def window_band(start, end, patch_radius_d=PATCH_RADIUS):
    """The band of the strain increment gamma between two fields_NNNN.npz snapshots (dicts),
    patch radius in mean diameters: measure_band's dict with d50 [m] and the fitted discs."""
    diameter = 2.0 * np.asarray(start["radius"])
    d50 = float(np.median(diameter))
    position = np.asarray(start["position"])
    increment = np.asarray(end["displacement"]) - np.asarray(start["displacement"])
    ok = np.isfinite(increment).all(axis=1) & np.isfinite(position).all(axis=1)
    e = strain_increment(position, np.where(ok[:, None], increment, 0.0), patch_radius_d * float(np.mean(diameter)),
                         ok)
    inner = ok & np.isfinite(e).all(axis=1) & ~np.asarray(start["excluded"], bool) & \
        ~np.asarray(end["excluded"], bool)
    width = float(np.ptp(position[:, 0]))
    gamma = shear_strain(e[inner])
    rec = measure_band(position[inner], gamma, d50, width)
    rec.update(d50=d50, discs_fitted=int(inner.sum()), mean_gamma=float(np.mean(gamma)),
               max_gamma=float(np.max(gamma)))
    return rec


def run_bands(directory, patch_radius_d=PATCH_RADIUS):
    """Every window of consecutive snapshots of a demo folder: a list of dicts."""
    folder = os.path.join(directory, "particles")
    names = sorted(f for f in os.listdir(folder) if f.startswith("fields_") and f.endswith(".npz"))
    with open(os.path.join(directory, "history.csv")) as f:
        rows = dvf.read_history(os.path.join(directory, "history.csv"))
    times = np.array([float(r["time"]) for r in rows])
    strains = np.array([float(r["axial_strain"]) for r in rows])
    out = []
    for a, b in zip(names[:-1], names[1:]):
        start, end = dict(np.load(os.path.join(folder, a))), dict(np.load(os.path.join(folder, b)))
        eps = [float(np.interp(float(s["time"]), times, strains)) for s in (start, end)]
        rec = window_band(start, end, patch_radius_d)
        rec.update(window=[a, b], axial_strain=eps)
        out.append(rec)
    return out


# %% The table
def mean_sd(values):
    """(mean, sample standard deviation, count) of the values that are not None; None where
    there are too few."""
    v = [x for x in values if x is not None]
    if not v:
        return None, None, 0
    return float(np.mean(v)), (float(np.std(v, ddof=1)) if len(v) > 1 else None), len(v)


def fmt(x, spec=".2f"):
    return "-" if x is None else format(x, spec)


def corrected(h_read, patch_radius_d):
    """The band's own H / d50 from the read one: sqrt(H_read^2 - s^2), None if not above s."""
    s = PATCH_WIDENING[patch_radius_d]
    return math.sqrt(h_read ** 2 - s ** 2) if h_read is not None and h_read > s else None


#: a fitted H / d50 above this is a fit run off the specimen, not a thickness
DIVERGED = 1e3


def _cell(w, patch_radius_d):
    """(verdict text, H_read / d50, H / d50, inclination) of one measure_band dict; a fit that
    is no band in parentheses."""
    h = w["thickness_over_d50"]
    if w["band"]:
        return "yes", fmt(h), fmt(corrected(h, patch_radius_d)), fmt(w["inclination_deg"], "+.1f")
    if h is None or not h < DIVERGED:
        return f"no: {w['no_band_reason'] if h is None else 'the fit diverged (no bell in the field)'}", "-", "-", "-"
    return (f"no: {w['no_band_reason']}", f"({fmt(h)})", f"({fmt(corrected(h, patch_radius_d))})",
            f"({fmt(w['inclination_deg'], '+.1f')})")


def table(results, shown=2):
    """Markdown lines: one row per run and window (the last `shown` windows) and one per tiling
    and window (mean +- std over the seeds with a single band; a fit that is no band is shown in
    parentheses and left out)."""
    r3, r5 = f"{PATCH_RADIUS:g} d", f"{WIDE_PATCH_RADIUS:g} d"
    lines = [f"| tiling | seed | discs | window (axial strain) | band (patch {r3}) | H_read / d50 | H / d50 | "
             f"inclination [deg] | top decile within 2H | contrast A / e0 | band (patch {r5}) | H_read / d50 | "
             "H / d50 | inclination [deg] | peak stress ratio (strain) | CPU s | load after |",
             "|" + "---|" * 17]
    groups = {}
    for label in sorted(results, key=lambda k: (results[k]["discs"], results[k]["seed"])):
        r = results[label]
        for w, v in list(zip(r["windows"], r["windows_wide"]))[-shown:]:
            window = f"{-100 * w['axial_strain'][0]:.0f}-{-100 * w['axial_strain'][1]:.0f} %"
            fit = w["fit"] or {}
            contrast = fit["amplitude"] / fit["offset"] if fit.get("offset", 0) > 0 else None
            contrast = contrast if contrast is not None and abs(contrast) < DIVERGED else None
            lines.append(f"| {r['study']} | {r['seed']} | {r['discs']} | {window} | " +
                         " | ".join(_cell(w, PATCH_RADIUS)) + f" | {fmt(w['top_decile_share'])} | "
                         f"{fmt(contrast)} | " + " | ".join(_cell(v, WIDE_PATCH_RADIUS)) +
                         f" | {fmt(r['peak_stress_ratio'], '.3f')} ({fmt(r['axial_strain_at_peak'], '.1f')} %) | "
                         f"{r['cpu_s']:.0f} | {r['load_after']:.2f} |")
            for key in ((r["study"], window), ("all tilings", window)):
                t = groups.setdefault(key, {"runs": 0, "H": [], "a": [], "H5": [], "a5": []})
                t["runs"] += 1
                for rec, radius, hk, ak in ((w, PATCH_RADIUS, "H", "a"), (v, WIDE_PATCH_RADIUS, "H5", "a5")):
                    if rec["band"]:
                        t[hk].append(corrected(rec["thickness_over_d50"], radius))
                        t[ak].append(abs(rec["inclination_deg"]))
    lines += ["", f"| tiling | window | runs | single bands (patch {r3}) | H / d50 (mean +- std over seeds) | "
              f"abs(inclination) [deg] | single bands (patch {r5}) | H / d50 | abs(inclination) [deg] |",
              "|---|---|---|---|---|---|---|---|---|"]
    for (study, window), t in sorted(groups.items(), key=lambda kv: (kv[0][0] == "all tilings", kv[0])):
        cells = []
        for hk, ak in (("H", "a"), ("H5", "a5")):
            (h, hs, n), (a, as_, _) = mean_sd(t[hk]), mean_sd(t[ak])
            cells.append(f"{n} | {fmt(h)} +- {fmt(hs)} | {fmt(a, '.1f')} +- {fmt(as_, '.1f')}")
        lines.append(f"| {study} | {window} | {t['runs']} | " + " | ".join(cells) + " |")
    return lines


def analyse(out, runs):
    results = {}
    for rec in dvf.load_records(out, runs):
        directory = os.path.join(out, rec["label"])
        results[rec["label"]] = {
            "study": rec["study"], "seed": rec["seed"], "discs": rec.get("discs"), "cpu_s": rec["cpu_s"],
            "wall_s": rec["wall_s"], "load_after": rec["load_average_after"][0],
            "peak_stress_ratio": rec["peak_stress_ratio"],
            "axial_strain_at_peak": None if rec["axial_strain_at_peak"] is None else -100 * rec["axial_strain_at_peak"],
            "windows": run_bands(directory, PATCH_RADIUS), "windows_wide": run_bands(directory, WIDE_PATCH_RADIUS)}
    return results


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], allow_abbrev=False,
                                formatter_class=argparse.RawDescriptionHelpFormatter,
                                epilog=__doc__.split("\n\n", 1)[1])
    p.add_argument("--cases", default=DEFAULT_CASES, help=f"dns-NXxNY cases (default {DEFAULT_CASES})")
    p.add_argument("--seeds", default=dvf.DEFAULT_SEEDS, help="packing seeds (default 0,1,3: the seeds that tile)")
    p.add_argument("--strain", type=float, default=0.08, help="axial strain of every run (default 0.08)")
    p.add_argument("--threads", type=int, default=1, help="Numba threads of each DNS (default 1)")
    p.add_argument("--report-only", action="store_true", help="only measure the bands of the runs in --out")
    p.add_argument("--out", default="results/dns_band", help="output directory")
    args = p.parse_args(argv)
    try:
        runs = dvf.plan([c for c in args.cases.split(",") if c.strip()], [int(s) for s in args.seeds.split(",")])
    except ValueError as error:
        p.error(str(error))
    if any(r["kind"] != "dns" for r in runs):
        p.error("dns_band measures DNS cases only (dns-NXxNY)")
    if not 0.0 < args.strain < 0.5:
        p.error(f"--strain must be in (0, 0.5), got {args.strain}")
    os.makedirs(args.out, exist_ok=True)
    if not args.report_only:
        for run in dvf.pending(runs, args.out):
            dvf.execute(run, args.out, args.strain, 0.002, 1, args.threads, log=lambda m: print(m, flush=True))
    results = analyse(args.out, runs)
    dvf.write_json(os.path.join(args.out, "dns_band.json"), results)
    lines = [f"Run: `benchmarks/dns/dns_band.py --cases {args.cases} --seeds {args.seeds} --strain {args.strain} "
             f"` · {time.strftime('%Y-%m-%d')} · load {os.getloadavg()[0]:.2f}", ""]
    lines += table(results) if results else ["no records yet"]
    with open(os.path.join(args.out, "dns_band.md"), "w") as f:
        f.write("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
