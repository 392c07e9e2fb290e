"""The shear band of the continua against the band of the grains, in grain diameters.

The DNS band (benchmarks/dns/dns_band.py: the tiled-cell DNS of the FEM x DEM cell, its band
measured from the grains) against the bands of four continua on the same specimen, each on
several meshes:

* ``classical``: FEM x DEM, classical continuum, a periodic cell at every Gauss point;
* ``hybrid``: FEM x DEM, the cells' symmetric stress with an elastic Cosserat part (mu_c the
  cell's initial shear modulus, internal length --l-c-d50 x d50);
* ``micropolar``: FEM x DEM, every flux from the cells (their own skew and couple moduli; the
  cell's grains placed at the mapped mean diameter, docs/reference/micropolar_cell.md);
* ``ehlers``: the micropolar Ehlers model (thesis 004, A.2) with the parameters that
  benchmarks/dem/dem_calibration.py identified from the same cell (--parameters), k_sigma = 0
  (the skew stress stays elastic: the setting with a band that converges in h,
  docs/results/regularisation.md), mu_c = the identified mu, l_c = --l-c-d50 x d50.

**The same specimen in grain diameters.** The continua's specimen is 10 mm x 20 mm, the
DNS 2x4 tiling of the seed's cell (two cells across, four up: 000's DNS B). One cell width
L of that tiling is 5 mm, so a length in the cell's units maps to mm by 5 mm / L, and d50
(the median disc diameter by number, as dns_band.py uses) is d50_cell x 5 mm / L, about
0.35 mm for the 228-disc cells (the specimen is about 29 x 58 d50, as the DNS 2x4 is).

**The same measure.** The DNS band is the section 4.4 bell (thesis 004 eq. 4.22) fitted to
the incremental largest engineering shear strain gamma = sqrt((e_xx - e_yy)^2 + (2 e_xy)^2)
of a window of axial strain past the peak. Each continuum run keeps the symmetric strain
increment at its Gauss points from --window-from to its end, and the same gamma and the same
fit are taken there, at the Gauss points outside the weak corner (the weak material strains
more whether or not a band leaves it). The continua need an imperfection to choose where
the band forms: a 5 mm weak square at the lower left corner (FEM x DEM: contact friction x
0.5; Ehlers: beta0 and beta* x 0.8, the weakening that matches it in the stand-alone cell,
benchmarks/femdem/femdem_vs_ehlers.py); the DNS band forms without one. ``band_verdict``
decides whether a fit is a band (contrast >= 0.5, H >= h / 2, FWHM <= W). The DNS's H is the
patch-corrected H of dns_band.py; the continua's H needs no patch (the FE field is the
gradient itself), but it is as coarse as the Gauss points.

Every run is a record ``OUT/LABEL.json`` (the FEM x DEM runs through
benchmarks/femdem/femdem_cases.run_case, shared with the other FEM x DEM studies; the Ehlers
runs in this process); a case with a record is not run again (resumable). A FEM x DEM case
that runs past --case-minutes is ended at its next step, and its record keeps what it
reached.

    mpirun -n 2 python3 benchmarks/dns/continuum_bands.py --dns results/dns_band --out results/continuum_bands
    mpirun -n 2 python3 benchmarks/dns/continuum_bands.py --models ehlers --ehlers-meshes 2x4,4x8 --out DIR
    python3 benchmarks/dns/continuum_bands.py --report-only --dns results/dns_band --out DIR

Run benchmarks/dem/dem_virtual_tests.py and benchmarks/dem/dem_calibration.py first for the
Ehlers parameters, and benchmarks/dns/dns_band.py --cases dns-2x4 for the DNS band (the table
shows "no DNS record" without it). Outputs in --out: the records, continuum_bands.md (the
table) and continuum_bands.png (H / d50 against h / d50 per model, the DNS band as its mean
+- one standard deviation).
"""
import argparse
import json
import os
import signal
import sys
import threading
import time

import numpy as np
from mpi4py import MPI

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))

from benchmarks.dns import dns_band  # noqa: E402
from benchmarks.dns.dns_band import fmt  # noqa: E402
from benchmarks.femdem.femdem_cases import StrainWindow, cpu_seconds, parse_mesh, run_case, settings  # noqa: E402
from cosserat_fenicsx.shear_band import band_verdict, fit_band  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
MODELS = ("classical", "hybrid", "micropolar", "ehlers")
FEMDEM_MODELS = ("classical", "hybrid", "micropolar")
WIDTH, HEIGHT = 0.01, 0.02          # the continua's specimen [m]: the DNS 2x4 tiling
TILES_ACROSS = 2
WEAK_SIZE = 5e-3                     # [m]: whole elements on every mesh of the study
FEMDEM_WEAK_FRICTION = 0.5
EHLERS_WEAK_FACTOR = 0.8             # matches friction x 0.5 (femdem_vs_ehlers.py)
EHLERS_CONFINING = 1e5               # [Pa]: the calibration's units (kn x 1e4, p0 x 1e4)
EHLERS_ETA = 0.1                     # [s]: the biaxial scene's default viscosity


# %% The grains in the continuum's units
def grain_scale(seed, particles):
    """(d50 [m], mean diameter [m], metres per cell unit) of the seed's cell packing placed in
    the 2x4 specimen: one cell width is WIDTH / TILES_ACROSS."""
    from demcell import generate_packing
    state, _ = generate_packing(particles, seed=seed)
    metres = WIDTH / TILES_ACROSS / float(np.hypot(*state.h[:, 0]))
    diameter = 2.0 * np.asarray(state.radius)
    return float(np.median(diameter)) * metres, float(np.mean(diameter)) * metres, metres


def check_cell_options(mesh, particles, seed, axial_strain, steps, case_minutes):
    """Refuse before any work what the runs of these options would refuse later: a ValueError
    naming the option (the cells' and the FEM x DEM settings' own checks, and the budget)."""
    if not case_minutes > 0:
        raise ValueError(f"--case-minutes must be > 0, got {case_minutes}")
    settings(mesh=mesh, particles=particles, axial_strain=axial_strain, steps=steps, weak_size=WEAK_SIZE,
             cell={"seed": seed}).check()


# %% One band measure for every model
def outside_weak(points):
    return ~((points[:, 0] < WEAK_SIZE) & (points[:, 1] < WEAK_SIZE))


def measure(points, increment, element_size, d50):
    """The bell of eq 4.22 fitted to gamma of the symmetric increments (n, 3) at the points
    outside the weak corner: a dict with H / d50, inclination, contrast and the verdict."""
    points, increment = np.asarray(points), np.asarray(increment)
    keep = outside_weak(points)
    gamma = dns_band.shear_strain(increment[keep])
    rec = {"band": False, "why": "", "thickness_over_d50": None, "inclination_deg": None, "contrast": None}
    try:
        fit = fit_band(points[keep], gamma)
    except ValueError as error:
        rec["why"] = str(error)
        return rec
    ok, why = band_verdict(fit, element_size, WIDTH)
    share = dns_band.top_decile_share(points[keep], gamma, fit) if fit.converged else None
    if ok and share < dns_band.SINGLE_BAND_SHARE:       # the DNS's test of a single band
        ok, why = False, (f"no single band: {100 * share:.0f} % of the top decile within 2H of the axis "
                          f"(below {100 * dns_band.SINGLE_BAND_SHARE:.0f} %)")
    rec.update(band=bool(ok), why="" if ok else why, thickness_over_d50=fit.thickness / d50,
               inclination_deg=fit.inclination_deg, top_decile_share=share,
               contrast=fit.amplitude / fit.offset if fit.offset > 0 else None, fit=fit.as_dict())
    return rec


# %% The Ehlers runs (in this process)
class OverBudget(Exception):
    """An Ehlers run past its wall budget: its record keeps what it reached."""


def run_ehlers(comm, out, label, mesh, l_c, a, log):
    """One Ehlers biaxial run (scenes/biaxial.py, what demos/biaxial.py runs) with the calibrated
    parameters; returns its record (every rank), written to OUT/LABEL.json."""
    path = os.path.join(out, f"{label}.json")
    if os.path.isfile(path):
        with open(path) as f:
            return json.load(f)
    from cosserat_fenicsx.materials.ehlers.parameters import read_parameter_file
    from cosserat_fenicsx.scenes.biaxial import BiaxialSettings, BiaxialTest
    from cosserat_fenicsx.stepping import LoadSteppingError
    values = read_parameter_file(a.parameters)
    values.update(k_sigma=0.0, k_mu=0.0, l_c=l_c, mu_c=values["mu"])
    nx, ny = mesh
    s = BiaxialSettings(width=WIDTH, height=HEIGHT, confining=EHLERS_CONFINING, axial_strain=a.axial_strain,
                        steps=a.steps, cell_size=WIDTH / nx, cell_type="triangle", weak_size=WEAK_SIZE,
                        weak_beta_factor=EHLERS_WEAK_FACTOR, micropolar=True, material=values, eta=a.ehlers_eta)
    s.check()
    load_before, start, cpu0 = os.getloadavg()[0], time.perf_counter(), cpu_seconds()
    log(f"{label}: running (Ehlers, {nx}x{ny}, l_c = {l_c * 1e3:.4f} mm)")
    test = BiaxialTest(comm, s)
    window = StrainWindow(a.window_from)
    budget = time.perf_counter() + 60.0 * a.case_minutes

    def on_step(row):
        # the wall budget, decided on rank 0 so that every rank stops after the same step
        if comm.bcast(time.perf_counter() > budget if comm.rank == 0 else None, root=0):
            raise OverBudget(f"stopped after step {row['step']}: past --case-minutes {a.case_minutes:g}")
        if row["phase"] == 2:
            window.after_step(row, -row["vertical_stress"], test.gauss_points.evaluate_gradients())

    stopped = ""
    try:
        test.run(on_step=on_step)
    except (LoadSteppingError, OverBudget) as error:
        stopped = str(error)
    rows = [r for r in test.history if r["phase"] == 2]
    gradients = test.gauss_points.evaluate_gradients()
    increment = window.increment(comm, gradients)
    points = comm.gather(test.points, root=0)
    increments = comm.gather(increment, root=0)
    couple = comm.gather(test.gauss_points.flux_values[:, 4:6], root=0)
    curvature = comm.gather(gradients[:, 4:6], root=0)
    stress = np.array([r["vertical_stress"] for r in rows])
    i_peak = int(np.argmin(stress)) if len(stress) else 0
    record = {
        "label": label, "model": "ehlers", "mesh": [nx, ny], "l_c": l_c, "mu_c": values["mu"], "eta": a.ehlers_eta,
        "completed": not stopped,
        "stopped": stopped, "axial_strain": [r["axial_strain"] for r in rows], "vertical_stress": stress.tolist(),
        "peak_vertical_stress": float(stress[i_peak]) if rows else None,
        "axial_strain_at_peak": float(rows[i_peak]["axial_strain"]) if rows else None,
        "plastic_fraction_final": rows[-1]["plastic_fraction"] if rows else None,
        "window_from": window.axial_strain, "cuts": test.stepper.cuts,
        "wall_time": time.perf_counter() - start, "cpu_time": comm.allreduce(cpu_seconds() - cpu0),
        "load_average_before": load_before, "load_average_after": os.getloadavg()[0], "ranks": comm.size}
    if comm.rank == 0:
        record["points"] = np.concatenate(points).tolist()
        record["window_strain_increment"] = np.concatenate(increments).tolist() if increment is not None else None
        record["couple_stress"] = np.concatenate(couple).tolist()
        record["curvature"] = np.concatenate(curvature).tolist()
        os.makedirs(out, exist_ok=True)
        with open(path + ".tmp", "w") as f:
            json.dump(record, f)
        os.replace(path + ".tmp", path)
        log(f"{label}: {record['wall_time']:.0f} s wall" + (f"; stopped: {stopped}" if stopped else ""))
    return comm.bcast(record if comm.rank == 0 else None, root=0)


# %% The FEM x DEM runs
def run_femdem(comm, out, label, model, mesh, scale, l_c, a, log):
    d50, d_mean, _ = scale
    extra = {"l_c": l_c} if model == "hybrid" else {}
    s = settings(mesh=mesh, particles=a.particles, mode=model, axial_strain=a.axial_strain, steps=a.steps,
                 weak_size=WEAK_SIZE, weak_friction_factor=FEMDEM_WEAK_FRICTION, grain_diameter=d_mean,
                 cell={"seed": a.seed}, **extra)
    return dict(run_with_budget(comm, out, label, s, a.case_minutes, a.window_from, log), model=model)


def run_with_budget(comm, out, label, s, minutes, window_from, log):
    """femdem_cases.run_case ended after the step under way once `minutes` of wall time have
    passed (its record keeps what the run reached)."""
    # SIGTERM to this process on every rank, which run_case turns into the end of the run
    # after the step under way (all ranks together)
    timer = threading.Timer(60.0 * minutes, os.kill, (os.getpid(), signal.SIGTERM))
    timer.daemon = True
    timer.start()
    try:
        return run_case(comm, out, label, s, log=log, window_from=window_from)
    finally:
        timer.cancel()


# %% The report
def dns_reference(directory):
    """{window text: (mean H / d50, std, bands, runs)} of the DNS 2x4 band (dns_band.py's
    records in `directory`), over the seeds with a single band."""
    path = os.path.join(directory or "", "dns_band.json")
    if not directory or not os.path.isfile(path):
        return {}
    with open(path) as f:
        results = json.load(f)
    groups = {}
    for r in results.values():
        if r["study"] != "dns-2x4":
            continue
        for w in r["windows"]:
            key = f"{abs(100 * w['axial_strain'][0]):.0f}-{abs(100 * w['axial_strain'][1]):.0f} %"
            g = groups.setdefault(key, {"H": [], "runs": 0})
            g["runs"] += 1
            if w["band"]:
                g["H"].append(dns_band.corrected(w["thickness_over_d50"], dns_band.PATCH_RADIUS))
    out = {}
    for key, g in groups.items():
        mean, sd, n = dns_band.mean_sd(g["H"])
        out[key] = (mean, sd, n, g["runs"])
    return out


def row(record, d50):
    nx, ny = record["mesh"]
    h = WIDTH / nx
    band = (measure(record["points"], record["window_strain_increment"], h, d50)
            if record.get("window_strain_increment") else {"band": False, "why": "the run did not reach the window"})
    strains = record["axial_strain"]
    reached = -100 * strains[-1] if strains else 0.0
    model = record["model"] + (f" (eta {record['eta']:g} s)" if record.get("eta", EHLERS_ETA) != EHLERS_ETA else "")
    return {"label": record["label"], "model": model, "mesh": f"{nx}x{ny}", "h_over_d50": h / d50,
            "l_c_over_d50": (record["l_c"] / d50 if record.get("l_c") and record["model"] in ("hybrid", "ehlers")
                             else None),
            "reached": reached, "window_from": (None if record.get("window_from") is None
                                                else -100 * record["window_from"]),
            "band": band, "cpu": record["cpu_time"], "wall": record["wall_time"], "cuts": record.get("cuts"),
            "stopped": record.get("stopped", ""), "load": record["load_average_after"]}


def band_cell(b):
    if b["band"]:
        return f"**{fmt(b['thickness_over_d50'])}**", fmt(b["inclination_deg"], "+.0f"), fmt(b["contrast"], ".1f")
    if b.get("thickness_over_d50") is None:
        return f"no fit ({b['why']})", "-", "-"
    return (f"({fmt(b['thickness_over_d50'])}; {b['why']})", f"({fmt(b['inclination_deg'], '+.0f')})",
            fmt(b["contrast"], ".1f"))


def report(rows, dns, d50, a):
    lines = [f"d50 = {d50 * 1e3:.4f} mm (seed {a.seed}, {a.particles} discs; the specimen is "
             f"{WIDTH / d50:.1f} x {HEIGHT / d50:.1f} d50); window from {100 * a.window_from:g} % to the end "
             f"({100 * a.axial_strain:g} %)", ""]
    lines += ["DNS 2x4 (dns_band.py, patch-corrected H, seeds with a single band):", ""]
    if dns:
        lines += ["| window | single bands / runs | H / d50 (mean +- std) |", "|---|---|---|"]
        lines += [f"| {k} | {v[2]} / {v[3]} | {fmt(v[0])} +- {fmt(v[1])} |" for k, v in sorted(dns.items())]
    else:
        lines += ["no DNS record (run benchmarks/dns/dns_band.py --cases dns-2x4 and give its --out as --dns)"]
    lines += ["", "| model | mesh | h / d50 | l_c / d50 | reached [%] | window [%] | H / d50 (verdict) | "
              "inclination [deg] | contrast A / e0 | cut-backs | wall / CPU [s] | load after | stopped |",
              "|" + "---|" * 13]
    for r in rows:
        h, incl, contrast = band_cell(r["band"])
        window = "-" if r["window_from"] is None else f"{r['window_from']:.1f}-{r['reached']:.1f}"
        lines.append(f"| {r['model']} | {r['mesh']} | {r['h_over_d50']:.1f} | {fmt(r['l_c_over_d50'])} | "
                     f"{r['reached']:.2f} | {window} | {h} | {incl} | "
                     f"{contrast} | {fmt(r['cuts'], 'd')} | {r['wall']:.0f} / {r['cpu']:.0f} | {r['load']:.2f} | "
                     f"{r['stopped'][:90]} |")
    lines += ["", "The mesh change of each model and internal length (H / d50 on its finest mesh with a band "
              "over that on its coarsest with a band):", ""]
    for key in dict.fromkeys((r["model"], r["l_c_over_d50"]) for r in rows):
        name = key[0] + ("" if key[1] is None else f", l_c = {key[1]:g} d50")
        with_band = [r for r in rows if (r["model"], r["l_c_over_d50"]) == key and r["band"]["band"]]
        if len(with_band) >= 2:
            coarse = max(with_band, key=lambda r: r["h_over_d50"])
            fine = min(with_band, key=lambda r: r["h_over_d50"])
            lines.append(f"- {name}: {fine['band']['thickness_over_d50'] / coarse['band']['thickness_over_d50']:.2f} "
                         f"({coarse['mesh']} -> {fine['mesh']}, h / d50 {coarse['h_over_d50']:.1f} -> "
                         f"{fine['h_over_d50']:.1f})")
        else:
            lines.append(f"- {name}: {len(with_band)} mesh with a band, no mesh change")
    return lines


def figure(rows, dns, path):
    from cosserat_fenicsx.figures import pyplot
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6, 4.5))
    groups = dict.fromkeys((r["model"], r["l_c_over_d50"]) for r in rows)
    for i, (model, l_c) in enumerate(groups):
        rs = sorted((r for r in rows if (r["model"], r["l_c_over_d50"]) == (model, l_c)
                     and r["band"].get("thickness_over_d50") is not None
                     and r["band"]["thickness_over_d50"] < 100), key=lambda r: r["h_over_d50"])
        if not rs:
            continue
        name = model + ("" if l_c is None else f", l_c {l_c:g} d50")
        marker = "osD^v<>p"[i % 8]
        ax.plot([r["h_over_d50"] for r in rs], [r["band"]["thickness_over_d50"] for r in rs], "-", lw=0.8,
                color=f"C{i}")
        for r in rs:
            ax.plot(r["h_over_d50"], r["band"]["thickness_over_d50"], marker,
                    mfc=None if r["band"]["band"] else "none", color=f"C{i}", label=name if r is rs[0] else None)
    for i, (key, (mean, sd, n, _)) in enumerate(sorted(dns.items())):
        if mean is not None:
            ax.axhspan(mean - (sd or 0), mean + (sd or 0), color="k", alpha=0.08)
            ax.axhline(mean, color="k", ls=("-", "--", ":", "-.")[i % 4], lw=0.8, label=f"DNS 2x4, {key} ({n} bands)")
    ax.set_xlabel("element size h / d50"); ax.set_ylabel("band H / d50 (open: not a band by the verdict)")
    ax.set_xscale("log"); ax.set_yscale("log"); ax.legend(fontsize=7)
    fig.tight_layout(); fig.savefig(path, dpi=120)


def dns_window_fields(directory):
    """[(title, positions [d50], gamma)] of the dns-2x4 runs in dns_band.py's --out, each at its
    last window with a single band (dns_band.json), the discs on the walls left out."""
    path = os.path.join(directory or "", "dns_band.json")
    if not directory or not os.path.isfile(path):
        return []
    with open(path) as f:
        results = json.load(f)
    panels = []
    for label, r in sorted(results.items()):
        banded = [w for w in r["windows"] if w["band"]] if r["study"] == "dns-2x4" else []
        if not banded:
            continue
        w = banded[-1]
        folder = os.path.join(directory, label, "particles")
        start, end = (dict(np.load(os.path.join(folder, n))) for n in w["window"])
        position = np.asarray(start["position"])
        d = 2.0 * np.asarray(start["radius"])
        e = dns_band.strain_increment(position, np.asarray(end["displacement"]) - np.asarray(start["displacement"]),
                                      dns_band.PATCH_RADIUS * float(np.mean(d)))
        keep = np.isfinite(e).all(axis=1) & ~np.asarray(start["excluded"], bool)
        window = f"{abs(100 * w['axial_strain'][0]):.0f}-{abs(100 * w['axial_strain'][1]):.0f} %"
        panels.append((f"DNS 2x4 seed {r['seed']}, {window}", (position[keep] - position.min(axis=0)) /
                       float(np.median(d)), dns_band.shear_strain(e[keep])))
    return panels


def fields_figure(records, dns_panels, d50, path):
    """000 Fig. 7 side by side: the incremental shear strain gamma of the window in the DNS
    (at the discs) and in each model's finest mesh (at the Gauss points), in d50."""
    from cosserat_fenicsx.figures import pyplot
    finest = {}
    for r in records:
        if r.get("window_strain_increment") and (r["model"] not in finest or r["mesh"][0] > finest[r["model"]]["mesh"][0]
                                                 or (r["mesh"][0] == finest[r["model"]]["mesh"][0]
                                                     and r.get("l_c", 0) < finest[r["model"]].get("l_c", 0))):
            finest[r["model"]] = r
    panels = dns_panels + [
        (f"{m} {r['mesh'][0]}x{r['mesh'][1]}" + (f", l_c {r['l_c'] / d50:g} d50" if m in ("hybrid", "ehlers") else ""),
         np.asarray(r["points"]) / d50, dns_band.shear_strain(np.asarray(r["window_strain_increment"])))
        for m, r in finest.items()]
    if not panels:
        return
    plt = pyplot()
    fig, ax = plt.subplots(1, len(panels), figsize=(2.4 * len(panels), 4.6), squeeze=False)
    for a, (title, xy, gamma) in zip(ax[0], panels):
        sc = a.scatter(xy[:, 0], xy[:, 1], c=gamma / np.quantile(gamma, 0.98), s=2, cmap="viridis", vmin=0, vmax=1)
        a.set_title(title, fontsize=7); a.set_aspect("equal"); a.set_xlabel("x / d50")
    ax[0][0].set_ylabel("y / d50")
    fig.colorbar(sc, ax=ax[0].tolist(), label="gamma of the window / its 98th percentile")
    fig.savefig(path, dpi=120)


# %% Main
def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], allow_abbrev=False,
                                formatter_class=argparse.RawDescriptionHelpFormatter,
                                epilog=__doc__.split("\n\n", 1)[1])
    p.add_argument("--out", default="results/continuum_bands")
    p.add_argument("--dns", default=None, help="dns_band.py's --out with the dns-2x4 runs")
    p.add_argument("--models", default=",".join(MODELS), help=f"comma list out of {','.join(MODELS)}")
    p.add_argument("--femdem-meshes", default="2x4,4x8", help="FEM x DEM meshes (whole elements in the 5 mm weak "
                                                             "corner: 2x4, 4x8, 6x12, ...)")
    p.add_argument("--ehlers-meshes", default="2x4,4x8,8x16,16x32")
    p.add_argument("--seed", type=int, default=0, help="packing seed of the cells (the DNS's seed 0)")
    p.add_argument("--particles", type=int, default=228)
    p.add_argument("--l-c-d50", default="1", help="internal lengths of the hybrid runs in d50 (comma list)")
    p.add_argument("--ehlers-l-c-d50", default="1,0.3,0.1", help="internal lengths of the Ehlers runs in d50")
    p.add_argument("--parameters", default=os.path.join(ROOT, "out", "dem_calibration", "identify",
                                                        "identified_parameters.json"),
                   help="the Ehlers parameters identified from the cell (benchmarks/dem/dem_calibration.py)")
    p.add_argument("--ehlers-eta", type=float, default=EHLERS_ETA,
                   help="Perzyna time of the Ehlers runs [s per 1 s step] (0: rate-independent)")
    p.add_argument("--axial-strain", type=float, default=0.04)
    p.add_argument("--steps", type=int, default=20)
    p.add_argument("--window-from", type=float, default=0.02, help="the band's window starts at this axial strain")
    p.add_argument("--case-minutes", type=float, default=20.0, help="wall budget of a case (it ends after the "
                                                                     "step under way)")
    p.add_argument("--report-only", action="store_true")
    a = p.parse_args(argv)
    models = [m for m in a.models.split(",") if m]
    unknown = sorted(set(models) - set(MODELS))
    if unknown:
        p.error(f"unknown models {unknown}; choose from {','.join(MODELS)}")
    try:
        femdem_meshes = [parse_mesh(m) for m in a.femdem_meshes.split(",") if m]
        ehlers_meshes = [parse_mesh(m) for m in a.ehlers_meshes.split(",") if m]
        a.l_c_d50 = [float(v) for v in a.l_c_d50.split(",") if v]
        a.ehlers_l_c_d50 = [float(v) for v in a.ehlers_l_c_d50.split(",") if v]
    except ValueError as error:
        p.error(str(error))
    if min(a.l_c_d50 + a.ehlers_l_c_d50, default=1.0) <= 0:
        p.error("internal lengths must be > 0")
    for nx, ny in femdem_meshes + ehlers_meshes:
        h = WIDTH / nx
        if ny != 2 * nx or abs(WEAK_SIZE / h - round(WEAK_SIZE / h)) > 1e-9:
            p.error(f"mesh {nx}x{ny}: the meshes are NXx2NX with whole elements in the 5 mm weak corner")
    if not 0.0 < a.window_from < a.axial_strain < 0.5:
        p.error("need 0 < --window-from < --axial-strain < 0.5")
    if "ehlers" in models and not a.report_only and not os.path.isfile(a.parameters):
        p.error(f"no Ehlers parameters at {a.parameters}: run benchmarks/dem/dem_calibration.py first")
    try:
        check_cell_options((femdem_meshes or ehlers_meshes or [(2, 4)])[0], a.particles, a.seed, a.axial_strain,
                           a.steps, a.case_minutes)
    except ValueError as error:
        p.error(str(error))
    comm = MPI.COMM_WORLD
    log = lambda t: comm.rank == 0 and print(t, flush=True)  # noqa: E731
    scale = grain_scale(a.seed, a.particles)
    d50 = scale[0]
    records = []
    lengths = {"hybrid": a.l_c_d50, "ehlers": a.ehlers_l_c_d50}
    for model in models:
        for l_c_d50, mesh in ((v, m) for v in lengths.get(model, [None])
                              for m in (ehlers_meshes if model == "ehlers" else femdem_meshes)):
            lc = "" if l_c_d50 is None else f"_lc{l_c_d50:g}"
            eta = f"_eta{a.ehlers_eta:g}" if model == "ehlers" and a.ehlers_eta != EHLERS_ETA else ""
            label = f"{model}{lc}{eta}_{mesh[0]}x{mesh[1]}"
            l_c = None if l_c_d50 is None else l_c_d50 * d50
            path = os.path.join(a.out, f"{label}.json")
            if a.report_only:
                if os.path.isfile(path):
                    with open(path) as f:
                        records.append(dict(json.load(f), model=model))
                continue
            if model == "ehlers":
                records.append(run_ehlers(comm, a.out, label, mesh, l_c, a, log))
            else:
                records.append(run_femdem(comm, a.out, label, model, mesh, scale, l_c, a, log))
    if comm.rank != 0:
        return
    rows = [row(r, d50) for r in records]
    dns = dns_reference(a.dns)
    lines = [f"Run: `benchmarks/dns/continuum_bands.py {' '.join(argv if argv is not None else sys.argv[1:])}` · "
             f"{time.strftime('%Y-%m-%d')} · load {os.getloadavg()[0]:.2f}", ""] + report(rows, dns, d50, a)
    os.makedirs(a.out, exist_ok=True)
    with open(os.path.join(a.out, "continuum_bands.md"), "w") as f:
        f.write("\n".join(lines) + "\n")
    print("\n".join(lines))
    figure(rows, dns, os.path.join(a.out, "continuum_bands.png"))
    fields_figure(records, dns_window_fields(a.dns), d50, os.path.join(a.out, "continuum_bands_fields.png"))


if __name__ == "__main__":
    main()
