"""Paper 000's DNS against FEM x DEM on the same grains (000 section 4.2, Figs 4-5) and their cost.

Every case is one run of an existing demo in its own process:

* ``dns-NXxNY``: ``demos/dem_specimen.py --specimen tiled --tiles NXxNY`` (NX copies across,
  NY up): the FEM x DEM reference cell of the seed tiled, servo side walls at -p0 (constant
  lateral pressure), smooth platens, local damping 0.7, platens at an inertial number of 1e-4.
  000's DNS A (height x width = 2L x L) is ``dns-1x2``, DNS B (4L x 2L) ``dns-2x4``; the
  larger tilings of the same aspect are ``dns-3x6``, ``dns-4x8``.
* ``classical-NXxNY`` / ``hybrid-NXxNY``: ``demos/femdem_biaxial.py --mode M --mesh NXxNY``
  (10 mm x 20 mm, no weak zone; lateral traction p0, smooth platens) under ``mpirun -n
  --ranks``, one cell of the same seed at every Gauss point.
* ``cell-1x1``: ``demos/dem_cell.py`` loaded as a homogeneous FEM x DEM Gauss point is
  (vertical axis e2 shortened in --step increments, each a straight path in F with the
  lateral stress held at -p0 by an outer iteration; FIRE to the force ratio 1e-3 as the
  FEM x DEM cells): the stand-alone cell, without the Newton of the FE side, which stalls on
  the loose cells of the anisotropic packings.
* a suffix ``-aA0`` (e.g. ``dns-2x4-a0.05``, ``cell-1x1-a0.05``): the cell packing made with
  the initial fabric anisotropy A0 (000 section 4.3.3; ``--anisotropy`` of the demos,
  demcell.generate_packing's deviatoric pre-compaction); ``-locked``: rotations locked.

Both take the demos' defaults for the law and the cell (228 discs, kn = 1e4, ks = 2e3 N/m,
mu = 0.4, p0 = 10 N/m): the same grains (``--seed``: the DNS tiles are copies of the cell
packing ``demcell.generate_packing`` makes for that seed), the same law, the same pressure.
In 2D with linear springs the stress ratio against strain does not depend on the length unit,
so the FEM x DEM specimen (mm) and the DNS (cell units) compare by strain.

Each case writes its demo outputs to ``OUT/LABEL/`` and, when the demo ends, its record
``OUT/LABEL.json`` (the curves, the peak, wall and CPU seconds of the process tree, load
average before and after). A case whose record exists is skipped: the benchmark resumes
where it stopped (a FEM x DEM run stopped part-way continues from its checkpoint). Delete a
record to run its case again.

    /usr/bin/python3 benchmarks/dns/dns_vs_femdem.py --out results/dns_vs_femdem            # about 20 min
    /usr/bin/python3 benchmarks/dns/dns_vs_femdem.py --cases dns-1x2,dns-2x4 --seeds 0,1,2 --strain 0.05 --out DIR
    /usr/bin/python3 benchmarks/dns/dns_vs_femdem.py --cases classical-1x1,classical-1x2,hybrid-2x4 --out DIR
    /usr/bin/python3 benchmarks/dns/dns_vs_femdem.py --report-only --out DIR

Outputs in --out: the records, ``dns_vs_femdem.md`` and ``.csv`` (one row per case and per
study: case, mean over seeds, the DNS scatter; the agreement ranges; the cost table)
and ``dns_vs_femdem.png`` (stress ratio, volumetric strain and coordination against axial
strain; each DNS tiling as its mean +- one standard deviation over the seeds).

The agreement: on a grid of axial strain, a FEM x DEM study (the mean over its seeds) agrees
with a DNS tiling where |FEM - DNS mean| <= the DNS's standard deviation over its seeds (its
own scatter); the strain ranges where that holds are listed.

The cost: CPU seconds per percent of axial strain, for the DNS per disc (its steps to a
strain do not depend on the size at a fixed inertial number, so its cost grows with the
discs: docs/results/dns.md measures the rate flat from 1e3 to 1e5 discs) and for FEM x DEM per
Gauss point (the cells take 99.6 % of the time: docs/results/femdem.md). Unmeasured meshes and
tilings are extrapolated with those two scalings, and marked so.
"""
import argparse
import csv
import json
import math
import os
import re
import resource
import subprocess
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
DNS_DEMO = os.path.join(ROOT, "demos", "dem_specimen.py")
FEMDEM_DEMO = os.path.join(ROOT, "demos", "femdem_biaxial.py")

DEFAULT_CASES = "dns-1x2,dns-2x4,dns-4x8,classical-1x1,classical-1x2"
#: packing seeds whose cell tiles (the cells of seeds 2, 4 and 5 are sheared by more than 1 %)
DEFAULT_SEEDS = "0,1,3"
KINDS = ("dns", "classical", "hybrid", "cell")
CELL_DEMO = os.path.join(ROOT, "demos", "dem_cell.py")
#: Gauss points per rectangle of femdem_biaxial's default mesh (two P2 triangles, 3 points each)
GAUSS_POINTS_PER_RECTANGLE = 6
#: discs of the demos' default cell (000 Table 3)
CELL_DISCS = 228
#: the meshes and tilings of 000 Fig. 4 (and two larger tilings), for the cost table
COST_MESHES = ((1, 1), (1, 2), (2, 4), (4, 8))
COST_TILINGS = ((1, 2), (2, 4), (3, 6), (4, 8))
MPI_ENV = {"OMPI_ALLOW_RUN_AS_ROOT": "1", "OMPI_ALLOW_RUN_AS_ROOT_CONFIRM": "1",
           "OMPI_MCA_rmaps_base_oversubscribe": "1"}


# %% Cases
def parse_case(text):
    """'dns-2x4' -> ('dns', (2, 4), False, None); 'classical-1x1-locked' -> ('classical', (1, 1),
    True, None) (the grains' rotations locked, 000 section 4.3.2); 'dns-2x4-a0.05' -> ('dns',
    (2, 4), False, 0.05) (the cell packing made with the initial fabric anisotropy A0 = 0.05,
    000 section 4.3.3); a one-line ValueError for anything else."""
    m = re.fullmatch(r"(dns|classical|hybrid|cell)-(\d+)x(\d+)(?:-a(\d*\.?\d+))?(-locked)?", text.strip())
    target = float(m.group(4)) if m and m.group(4) is not None else None
    if not m or int(m.group(2)) < 1 or int(m.group(3)) < 1 or (target is not None and not 0.0 <= target < 1.0) \
            or (m.group(1) == "cell" and m.group(2, 3) != ("1", "1")):
        raise ValueError(f"a case is KIND-NXxNY[-aA0][-locked] with KIND one of {', '.join(KINDS)} (cell: 1x1 only) "
                         f"and A0 in [0, 1) (e.g. dns-2x4, classical-1x2, dns-1x2-locked, dns-2x4-a0.05), got {text!r}")
    return m.group(1), (int(m.group(2)), int(m.group(3))), bool(m.group(5)), target


def study_name(kind, size, locked=False, anisotropy=None):
    return f"{kind}-{size[0]}x{size[1]}" + variant(locked, anisotropy)


def variant(locked=False, anisotropy=None):
    """The suffix of a study's name after KIND-NXxNY: '-aA0' and '-locked' where they apply."""
    return ("" if anisotropy is None else f"-a{anisotropy:g}") + ("-locked" if locked else "")


def suffix(study):
    """A study's variant ('-a0.05', '-locked', ''): FEM x DEM and the DNS compare within one."""
    return re.sub(r"^[a-z]+-\d+x\d+", "", study)


def plan(cases, seeds):
    """The runs of a study: one per case and seed, in the order given (list of dicts)."""
    runs = []
    for text in cases:
        kind, size, locked, anisotropy = parse_case(text)
        study = study_name(kind, size, locked, anisotropy)
        for seed in seeds:
            runs.append({"label": f"{study}-s{seed}", "kind": kind, "size": list(size), "seed": int(seed),
                         "locked": locked, "anisotropy": anisotropy, "study": study})
    return runs


def law_flags(run):
    """The contact law of a run where it departs from the demos' defaults: the run's "ks"
    (tangential stiffness [N/m]) and "friction" (Coulomb mu), the same flags in every demo."""
    flags = []
    for key, flag in (("ks", "--ks"), ("friction", "--friction")):
        if run.get(key) is not None:
            flags += [flag, repr(float(run[key]))]
    return flags


def command(run, out, strain, step=0.002, ranks=2, threads=None, python=sys.executable, restart=False):
    """The demo's command line of a run (a list) and its environment additions."""
    directory = os.path.join(out, run["label"])
    nx, ny = run["size"]
    if run["kind"] == "dns":
        cmd = [python, DNS_DEMO, "--specimen", "tiled", "--tiles", f"{nx}x{ny}", "--seed", str(run["seed"]),
               "--axial-strain", repr(strain), "--out", directory]
        if threads:
            cmd += ["--threads", str(threads)]
        if run.get("locked"):
            cmd.append("--no-rotation")
        if run.get("anisotropy") is not None:
            cmd += ["--anisotropy", repr(run["anisotropy"])]
        return cmd + law_flags(run), {}
    if run["kind"] == "cell":
        cmd = [python, CELL_DEMO, "--seed", str(run["seed"]), "--axial-strain", repr(strain), "--increment",
               repr(step), "--axial-direction", "2", "--lateral-control", "strain", "--relaxation", "fire",
               "--criterion", "force", "--relaxation-tol", "1e-3", "--out", directory]
        if run.get("locked"):
            cmd.append("--no-rotation")
        if run.get("anisotropy") is not None:
            cmd += ["--anisotropy", repr(run["anisotropy"])]
        return cmd + law_flags(run), {}
    if restart:
        args = ["--restart", directory, "--checkpoint-every", "5"]
    else:
        steps = max(1, int(round(strain / step)))
        args = ["--mode", run["kind"], "--mesh", f"{nx}x{ny}", "--seed", str(run["seed"]), "--axial-strain",
                repr(strain), "--steps", str(steps), "--checkpoint-every", "5", "--out", directory]
        if run.get("locked"):
            args.append("--no-rotation")
        if run.get("anisotropy") is not None:
            args += ["--anisotropy", repr(run["anisotropy"])]
        args += law_flags(run)
    cmd = [python, FEMDEM_DEMO] + args
    if ranks > 1:
        cmd = ["mpirun", "-n", str(ranks)] + cmd
    env = dict(MPI_ENV, OMP_NUM_THREADS="1")
    return cmd, env


def record_path(out, run):
    return os.path.join(out, run["label"] + ".json")


def pending(runs, out):
    """The runs whose record is not in out yet (the resume rule)."""
    return [r for r in runs if not os.path.isfile(record_path(out, r))]


# %% Reading a run's outputs into its record
def read_history(path):
    with open(path) as f:
        return list(csv.DictReader(f))


def _column(rows, key):
    return [float(r[key]) if r.get(key) not in (None, "", "nan") else float("nan") for r in rows]


def curves_from_outputs(kind, directory, pressure=10.0):
    """The curves of a finished (or stopped) run, tension positive, from the demo's history.csv:
    axial_strain, stress_ratio (000 eq. 40 from the platen stress and the lateral stress),
    volumetric_strain, coordination, and for FEM x DEM also the demo's mean over the Gauss
    points (stress_ratio_points) and the anisotropy A (000 eq. 38). Both start at the end of
    the isotropic stage."""
    rows = read_history(os.path.join(directory, "history.csv"))
    if kind == "dns":
        rows = [r for r in rows if int(float(r["phase"])) == 1]
        return {"axial_strain": _column(rows, "axial_strain"), "stress_ratio": _column(rows, "stress_ratio"),
                "volumetric_strain": _column(rows, "volumetric_strain"),
                "coordination": _column(rows, "coordination")}
    if kind == "cell":       # from the end of the isotropic stage
        return {"axial_strain": _column(rows, "axial_strain"), "stress_ratio": _column(rows, "stress_ratio"),
                "volumetric_strain": _column(rows, "volumetric_strain"),
                "coordination": _column(rows, "coordination_number"), "anisotropy": _column(rows, "anisotropy")}
    # the end of the isotropic stage (phase 1, axial strain 0) and the compression (phase 2)
    iso = [r for r in rows if int(float(r["phase"])) == 1]
    rows = iso[-1:] + [r for r in rows if int(float(r["phase"])) == 2]
    sv = np.array(_column(rows, "vertical_stress"))
    sl = -pressure
    ratio = np.abs(sv - sl) / np.abs(sv + sl)
    return {"axial_strain": _column(rows, "axial_strain"), "stress_ratio": ratio.tolist(),
            "stress_ratio_points": _column(rows, "stress_ratio"),
            "volumetric_strain": _column(rows, "volumetric_strain"),
            "coordination": _column(rows, "coordination_number"), "anisotropy": _column(rows, "anisotropy")}


def peak(curves):
    r = np.array(curves["stress_ratio"], dtype=float)
    if r.size == 0 or not np.isfinite(r).any():
        return None, None
    i = int(np.nanargmax(r))
    return float(r[i]), float(curves["axial_strain"][i])


def make_record(run, cmd, returncode, wall, cpu, load_before, load_after, curves, summary):
    ratio_peak, strain_peak = peak(curves)
    final = curves["axial_strain"][-1] if curves["axial_strain"] else 0.0
    nx, ny = run["size"]
    rec = dict(run, command=" ".join(cmd), returncode=returncode, wall_s=wall, cpu_s=cpu,
               load_average_before=load_before, load_average_after=load_after, curves=curves,
               peak_stress_ratio=ratio_peak, axial_strain_at_peak=strain_peak, final_axial_strain=final,
               completed=bool(summary.get("completed", returncode == 0)) if summary else False)
    # the achieved initial fabric anisotropy (000 eq. 38) of the generated cell packing, the same
    # grains in both demos
    packing = ((summary.get("specimen_info") if run["kind"] == "dns" else summary.get("packing")) or {}) \
        if summary else {}
    rec["packing_anisotropy"] = packing.get("packing_anisotropy", packing.get("anisotropy"))
    rec["packing_fabric"] = packing.get("fabric")
    rec["packing_solid_fraction"] = packing.get("packing_solid_fraction", packing.get("solid_fraction"))
    if run["kind"] == "dns":
        rec["discs"] = summary.get("n_discs", CELL_DISCS * nx * ny) if summary else CELL_DISCS * nx * ny
    elif run["kind"] == "cell":
        rec["gauss_points"] = 1
        rec["dem_steps"] = summary.get("dem_steps") if summary else None
        rec["stop_reason"] = summary.get("reason") or None if summary else None
        rec["dem_steps"] = summary.get("dem_steps") if summary else None
    else:
        rec["gauss_points"] = summary.get("n_gauss_points", GAUSS_POINTS_PER_RECTANGLE * nx * ny) if summary \
            else GAUSS_POINTS_PER_RECTANGLE * nx * ny
        rec["newton_iterations"] = summary.get("newton_iterations_total") if summary else None
        rec["stop_reason"] = (summary.get("stopped") or summary.get("reason")) if summary else None
    return rec


def execute(run, out, strain, step, ranks, threads, log=print):
    """Run one case (restarting a FEM x DEM run from its checkpoint when there is one) and
    write its record. CPU seconds are those of the whole process tree (mpirun's ranks
    included); the load average is read before and after."""
    directory = os.path.join(out, run["label"])
    os.makedirs(directory, exist_ok=True)
    restart = run["kind"] not in ("dns", "cell") and os.path.isdir(os.path.join(directory, "checkpoint"))
    cmd, env_add = command(run, out, strain, step, ranks, threads, restart=restart)
    log(f"[dns_vs_femdem] {run['label']}: {' '.join(cmd)}")
    load_before = list(os.getloadavg())
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.time()
    with open(os.path.join(directory, "run.log"), "a") as f:
        proc = subprocess.run(cmd, stdout=f, stderr=subprocess.STDOUT, cwd=ROOT, env=dict(os.environ, **env_add))
    wall = time.time() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    load_after = list(os.getloadavg())
    summary = {}
    path = os.path.join(directory, "summary.json")
    if os.path.isfile(path):
        with open(path) as f:
            summary = json.load(f)
    if not os.path.isfile(os.path.join(directory, "history.csv")):
        with open(os.path.join(directory, "run.log")) as f:
            last = (f.read().strip().splitlines() or [""])[-1]
        log(f"[dns_vs_femdem] {run['label']}: no history.csv (exit {proc.returncode}), no record: {last}")
        return None
    if restart:       # the time of the run before the restart
        earlier = os.path.join(directory, "earlier_cost.json")
        if os.path.isfile(earlier):
            with open(earlier) as f:
                e = json.load(f)
            wall += e["wall_s"]
            cpu += e["cpu_s"]
    rec = make_record(run, cmd, proc.returncode, wall, cpu, load_before, load_after,
                      curves_from_outputs(run["kind"], directory), summary)
    named_stop = summary.get("stopped") or summary.get("reason")
    if named_stop:
        rec["stop_reason"] = named_stop
    if proc.returncode != 0 and run["kind"] not in ("dns", "cell") and os.path.isdir(os.path.join(directory, "checkpoint")) \
            and not rec["completed"] and not named_stop:
        # killed part-way (no stop the demo named): keep its cost and leave no record, so the next call restarts it
        with open(os.path.join(directory, "earlier_cost.json"), "w") as f:
            json.dump({"wall_s": wall, "cpu_s": cpu}, f)
        log(f"[dns_vs_femdem] {run['label']}: stopped at {rec['final_axial_strain']:+.4f} (exit {proc.returncode}); "
            "the next call continues it from its checkpoint")
        return None
    write_json(record_path(out, run), rec)
    log(f"[dns_vs_femdem] {run['label']}: peak {rec['peak_stress_ratio']} at {rec['axial_strain_at_peak']}, "
        f"to {rec['final_axial_strain']:+.4f}, {wall:.0f} s wall, {cpu:.0f} CPU s, load {load_after[0]:.2f}")
    return rec


def write_json(path, data):
    with open(path + ".tmp", "w") as f:
        json.dump(data, f, indent=1)
    os.replace(path + ".tmp", path)


def reread(out, runs):
    """Read the curves of every recorded run again from its demo outputs (after a change of
    how they are read); the costs of the record are kept."""
    for r in runs:
        path = record_path(out, r)
        directory = os.path.join(out, r["label"])
        if not (os.path.isfile(path) and os.path.isfile(os.path.join(directory, "history.csv"))):
            continue
        with open(path) as f:
            rec = json.load(f)
        summary = {}
        if os.path.isfile(os.path.join(directory, "summary.json")):
            with open(os.path.join(directory, "summary.json")) as f:
                summary = json.load(f)
        new = make_record(r, rec["command"].split(), rec["returncode"], rec["wall_s"], rec["cpu_s"],
                          rec["load_average_before"], rec["load_average_after"],
                          curves_from_outputs(r["kind"], directory), summary)
        new["command"] = rec["command"]
        write_json(path, new)


def load_records(out, runs):
    records = []
    for r in runs:
        path = record_path(out, r)
        if os.path.isfile(path):
            with open(path) as f:
                records.append(json.load(f))
    return records


# %% Studies: mean and scatter over seeds, agreement, cost
def on_grid(record, grid, key="stress_ratio"):
    """A record's curve on the axial-strain grid (compressive strain as a positive number),
    NaN beyond the strain the run reached."""
    eps = -np.array(record["curves"]["axial_strain"], dtype=float)
    y = np.array(record["curves"].get(key, []), dtype=float)
    if eps.size < 2 or y.size != eps.size:
        return np.full(len(grid), np.nan)
    order = np.argsort(eps)
    eps, y = eps[order], y[order]
    values = np.interp(grid, eps, y)
    values[(grid > eps[-1] + 1e-12) | (grid < eps[0] - 1e-12)] = np.nan
    return values


def studies(records, grid, key="stress_ratio"):
    """{study: {"kind", "size", "seeds", "mean", "std", "min", "max", "records"}} over the grid
    (std: sample standard deviation over the seeds, NaN with one seed)."""
    out = {}
    for rec in records:
        out.setdefault(rec["study"], []).append(rec)
    result = {}
    for name, recs in out.items():
        Y = np.array([on_grid(r, grid, key) for r in recs])
        n = np.sum(np.isfinite(Y), axis=0)
        with np.errstate(invalid="ignore"):
            mean = np.array([np.mean(c[np.isfinite(c)]) if np.isfinite(c).any() else np.nan for c in Y.T])
            std = np.array([np.std(c[np.isfinite(c)], ddof=1) if np.isfinite(c).sum() > 1 else np.nan for c in Y.T])
        mins = np.array([np.min(c[np.isfinite(c)]) if np.isfinite(c).any() else np.nan for c in Y.T])
        maxs = np.array([np.max(c[np.isfinite(c)]) if np.isfinite(c).any() else np.nan for c in Y.T])
        # a point counts only where every seed reached it (a mean of fewer seeds is another sample)
        full = n == len(recs)
        result[name] = {"kind": recs[0]["kind"], "size": recs[0]["size"], "seeds": sorted(r["seed"] for r in recs),
                        "mean": np.where(full, mean, np.nan), "std": np.where(full, std, np.nan),
                        "min": np.where(full, mins, np.nan), "max": np.where(full, maxs, np.nan), "records": recs}
    return result


def ranges(mask, grid):
    """The intervals of the grid where mask holds, as [(start, end)]."""
    out, start = [], None
    for x, m in zip(grid, mask):
        if m and start is None:
            start = x
        if not m and start is not None:
            out.append((start, prev))
            start = None
        prev = x
    if start is not None:
        out.append((start, prev))
    return out


def agreement(fem, dns, grid):
    """Where the FEM x DEM study's mean is within the DNS tiling's scatter: (ranges, the
    largest |difference| / std, the strains compared)."""
    both = np.isfinite(fem["mean"]) & np.isfinite(dns["mean"]) & np.isfinite(dns["std"])
    diff = np.abs(fem["mean"] - dns["mean"])
    within = both & (diff <= dns["std"])
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.where(both, diff / dns["std"], np.nan)
    compared = (float(grid[both][0]), float(grid[both][-1])) if both.any() else None
    return ranges(within, grid), (float(np.nanmax(ratio)) if both.any() else None), compared


def inside_seeds(fem, dns, grid):
    """Where the FEM x DEM study's mean lies between the lowest and the highest DNS seed."""
    both = np.isfinite(fem["mean"]) & np.isfinite(dns["min"]) & (np.array([len(dns["seeds"])] * len(grid)) > 1)
    return ranges(both & (fem["mean"] >= dns["min"]) & (fem["mean"] <= dns["max"]), grid)


def cost_rows(records, strain):
    """The cost: per measured case CPU and wall seconds per percent of axial strain, per disc
    (DNS) or per Gauss point (FEM x DEM); then per mesh the FEM x DEM cost to `strain`
    against each DNS tiling's, measured where there are records, otherwise extrapolated
    (DNS: CPU per percent per disc x discs; FEM x DEM: per Gauss point x points)."""
    per = {}
    for rec in records:
        if rec.get("locked") or rec.get("anisotropy") is not None or rec["kind"] == "cell":
            continue         # the cost of the reference cases, DNS against FEM x DEM
        pct = -100.0 * rec["final_axial_strain"]
        if pct <= 0:
            continue
        units = rec["discs"] if rec["kind"] == "dns" else rec["gauss_points"]
        per.setdefault(rec["study"], []).append({"cpu": rec["cpu_s"] / pct, "wall": rec["wall_s"] / pct,
                                                  "units": units, "kind": rec["kind"], "size": rec["size"],
                                                  "load": rec["load_average_after"][0]})
    measured = {}
    for name, rows in per.items():
        measured[name] = {"kind": rows[0]["kind"], "size": rows[0]["size"], "units": rows[0]["units"], "runs": len(rows),
                          "cpu_per_pct": float(np.mean([r["cpu"] for r in rows])),
                          "wall_per_pct": float(np.mean([r["wall"] for r in rows])),
                          "load": float(np.mean([r["load"] for r in rows]))}
    dns = [m for m in measured.values() if m["kind"] == "dns"]
    # the largest measured tiling and mesh set the per-disc and per-point costs (the least
    # start-up: Numba compilation, the packing, phase 0, the reference cells)
    big = max(dns, key=lambda m: m["units"]) if dns else None
    dns_unit = big["cpu_per_pct"] / big["units"] if dns else None
    fem_unit = {}
    for mode in ("classical", "hybrid"):
        fem = [m for m in measured.values() if m["kind"] == mode]
        if fem:
            big = max(fem, key=lambda m: m["units"])
            fem_unit[mode] = big["cpu_per_pct"] / big["units"]
    pct = 100.0 * strain
    table = []
    for mode, unit in fem_unit.items():
        for mesh in COST_MESHES:
            name = f"{mode}-{mesh[0]}x{mesh[1]}"
            points = GAUSS_POINTS_PER_RECTANGLE * mesh[0] * mesh[1]
            fem_cpu = measured[name]["cpu_per_pct"] * pct if name in measured else unit * points * pct
            row = {"mode": mode, "mesh": f"{mesh[0]}x{mesh[1]}", "gauss_points": points, "fem_cpu": fem_cpu,
                   "fem_measured": name in measured, "dns": []}
            for tiling in COST_TILINGS:
                dname = f"dns-{tiling[0]}x{tiling[1]}"
                discs = CELL_DISCS * tiling[0] * tiling[1]
                if dname in measured:
                    dcpu, known = measured[dname]["cpu_per_pct"] * pct, True
                elif dns_unit is not None:
                    dcpu, known = dns_unit * discs * pct, False
                else:
                    continue
                row["dns"].append({"tiling": f"{tiling[0]}x{tiling[1]}", "discs": discs, "dns_cpu": dcpu,
                                   "measured": known, "ratio": fem_cpu / dcpu})
            # the specimen size (discs) above which the DNS costs more than this mesh
            row["break_even_discs"] = fem_cpu / (dns_unit * pct) if dns_unit else None
            table.append(row)
    return measured, dns_unit, fem_unit, table


# %% Tables and figure
def fmt(x, spec=".3f"):
    return "-" if x is None or (isinstance(x, float) and not math.isfinite(x)) else format(x, spec)


def case_table(records):
    lines = ["| case | seed | peak stress ratio | at axial strain | reached | volumetric strain at the end | "
             "coordination start / end | anisotropy at peak | wall s | CPU s | load before / after | exit |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    rows_csv = []
    for rec in sorted(records, key=lambda r: (r["study"], r["seed"])):
        c = rec["curves"]
        vol = c["volumetric_strain"][-1] if c["volumetric_strain"] else None
        coord = (c["coordination"][0], c["coordination"][-1]) if c["coordination"] else (None, None)
        aniso = None
        if c.get("anisotropy") and rec["axial_strain_at_peak"] is not None:
            aniso = c["anisotropy"][int(np.nanargmax(np.array(c["stress_ratio"], dtype=float)))]
        lb, la = rec["load_average_before"][0], rec["load_average_after"][0]
        strain_peak = None if rec["axial_strain_at_peak"] is None else -100 * rec["axial_strain_at_peak"]
        lines.append(f"| {rec['study']} | {rec['seed']} | {fmt(rec['peak_stress_ratio'])} | {fmt(strain_peak, '.2f')} % | "
                     f"{fmt(-100 * rec['final_axial_strain'], '.2f')} % | {fmt(None if vol is None else 100 * vol, '+.2f')} % | "
                     f"{fmt(coord[0], '.2f')} / {fmt(coord[1], '.2f')} | {fmt(aniso)} | {rec['wall_s']:.0f} | "
                     f"{rec['cpu_s']:.0f} | {lb:.2f} / {la:.2f} | {rec['returncode']}"
                     f"{' (stopped: ' + rec['stop_reason'][:90] + ')' if rec.get('stop_reason') else ''} |")
        rows_csv.append({"case": rec["study"], "seed": rec["seed"], "peak_stress_ratio": rec["peak_stress_ratio"],
                         "axial_strain_at_peak": rec["axial_strain_at_peak"],
                         "final_axial_strain": rec["final_axial_strain"], "final_volumetric_strain": vol,
                         "coordination_start": coord[0], "coordination_end": coord[1], "anisotropy_at_peak": aniso,
                         "wall_s": rec["wall_s"], "cpu_s": rec["cpu_s"], "load_before": lb, "load_after": la,
                         "returncode": rec["returncode"]})
    return lines, rows_csv


def study_table(st, grid, marks=(0.005, 0.01, 0.02, 0.03, 0.04, 0.05, 0.08, 0.1)):
    marks = [m for m in marks if m <= grid[-1] + 1e-12]
    head = "| study | seeds | peak (mean +- std over seeds) | its strain | " + \
        " | ".join(f"ratio at {100 * m:g} %" for m in marks) + " |"
    lines = [head, "|" + "---|" * (4 + len(marks))]
    for name in sorted(st, key=lambda n: (n.split("-")[0] != "dns", n)):
        s = st[name]
        peaks = [r["peak_stress_ratio"] for r in s["records"] if r["peak_stress_ratio"] is not None]
        strains = [-100 * r["axial_strain_at_peak"] for r in s["records"] if r["axial_strain_at_peak"] is not None]
        sd = lambda v: np.std(v, ddof=1) if len(v) > 1 else float("nan")  # noqa: E731
        cells = []
        for m in marks:
            i = int(np.argmin(np.abs(grid - m)))
            cells.append(f"{fmt(s['mean'][i])} +- {fmt(s['std'][i])}" if np.isfinite(s["std"][i])
                         else fmt(s["mean"][i]))
        lines.append(f"| {name} | {','.join(map(str, s['seeds']))} | {fmt(np.mean(peaks) if peaks else None)} +- "
                     f"{fmt(sd(peaks))} | {fmt(np.mean(strains) if strains else None, '.2f')} +- {fmt(sd(strains), '.2f')} % | "
                     + " | ".join(cells) + " |")
    return lines


def agreement_lines(st, grid):
    lines = ["| FEM x DEM | DNS | strains compared | within the DNS scatter (|FEM - DNS| <= std over seeds) | "
             "between the lowest and highest DNS seed | largest |FEM - DNS| / std |", "|---|---|---|---|---|---|"]
    found = []
    for f in sorted(n for n in st if st[n]["kind"] != "dns"):
        for d in sorted(n for n in st if st[n]["kind"] == "dns" and suffix(n) == suffix(f)):
            rng, worst, compared = agreement(st[f], st[d], grid)
            text = ", ".join(f"{100 * a:.1f}-{100 * b:.1f} %" for a, b in rng) or "nowhere"
            span = inside_seeds(st[f], st[d], grid)
            span_text = ", ".join(f"{100 * a:.1f}-{100 * b:.1f} %" for a, b in span) or "nowhere"
            lines.append(f"| {f} | {d} | {'-' if compared is None else f'{100 * compared[0]:.1f}-{100 * compared[1]:.1f} %'}"
                         f" | {text if compared else '- (one seed: no scatter)'} | {span_text if compared else '-'} | "
                         f"{fmt(worst, '.2f')} |")
            found.append({"femdem": f, "dns": d, "within": rng, "between_seeds": span,
                          "largest_difference_over_std": worst,
                          "compared": compared})
    return lines, found


def rotation_lines(st):
    """000 section 4.3.2: the peak with free rotations over the peak with locked ones, per
    case with both (means over the seeds; 000: 0.39 / 0.48 = 0.81 at 7.3 %)."""
    lines = ["| case | seeds free / locked | peak free (strain) | peak locked (strain) | free / locked |",
             "|---|---|---|---|---|"]
    found = []
    for name in sorted(n for n in st if n.endswith("-locked")):
        free = name[:-len("-locked")]
        if free not in st:
            continue
        def mean_peak(s):
            p = [r["peak_stress_ratio"] for r in s["records"] if r["peak_stress_ratio"] is not None]
            e = [-100 * r["axial_strain_at_peak"] for r in s["records"] if r["axial_strain_at_peak"] is not None]
            return (float(np.mean(p)), float(np.mean(e))) if p else (None, None)
        (pf, ef), (pl, el) = mean_peak(st[free]), mean_peak(st[name])
        ratio = pf / pl if pf and pl else None
        lines.append(f"| {free} | {','.join(map(str, st[free]['seeds']))} / {','.join(map(str, st[name]['seeds']))} | "
                     f"{fmt(pf)} ({fmt(ef, '.2f')} %) | {fmt(pl)} ({fmt(el, '.2f')} %) | {fmt(ratio)} |")
        found.append({"case": free, "peak_free": pf, "peak_locked": pl, "ratio": ratio})
    return lines, found


def _mean_std(values):
    v = [float(x) for x in values if x is not None and np.isfinite(x)]
    if not v:
        return None, None
    return float(np.mean(v)), (float(np.std(v, ddof=1)) if len(v) > 1 else None)


def major_axis(fabric):
    """'x' or 'y': the axis nearer the fabric tensor's major eigenvector (the platens load y);
    '' when unknown."""
    if fabric is None:
        return ""
    w, v = np.linalg.eigh(np.array(fabric, dtype=float))
    return "x" if abs(v[0, -1]) >= abs(v[1, -1]) else "y"


def anisotropy_lines(st):
    """000 section 4.3.3: per case (KIND-NXxNY) and target A0 (none: the isotropic compaction),
    the achieved A0 of the packings (and the axis of the fabric's major eigenvector), their
    solid fraction, the peak stress ratio and its strain, mean +- the sample standard
    deviation over the seeds, and the peak over that of the lowest target (000 Fig. 13: a
    higher A0 gives a lower peak, at a smaller strain). The packings made to a target share
    their preparation (friction 0.3), the plain one (none) is compacted without friction and
    is denser: it is listed, not compared."""
    lines = ["| case | A0 target | seeds | achieved A0 (each seed; x: major axis across the load, y: along) | "
             "solid fraction | peak stress ratio | strain at peak [%] | peak / peak at the lowest target |",
             "|---|---|---|---|---|---|---|---|"]
    found = []
    groups = {}
    for name, s in st.items():
        recs = s["records"]
        base = re.sub(r"-a[0-9.]+", "", name)
        groups.setdefault(base, []).append((recs[0].get("anisotropy"), name, s))
    if not any(t is not None for g in groups.values() for t, _, _ in g):
        return lines, found
    for base in sorted(groups, key=lambda n: (st[groups[n][0][1]]["kind"] != "dns", n)):
        rows = sorted(groups[base], key=lambda g: -1.0 if g[0] is None else g[0])
        targets = [t for t, _, _ in rows if t is not None]
        reference = None
        for target, name, s in rows:
            recs = sorted(s["records"], key=lambda r: r["seed"])
            a0 = [r.get("packing_anisotropy") for r in recs]
            axes = [major_axis(r.get("packing_fabric")) for r in recs]
            pk, pk_sd = _mean_std([r["peak_stress_ratio"] for r in recs])
            ep, ep_sd = _mean_std([None if r["axial_strain_at_peak"] is None else -100 * r["axial_strain_at_peak"]
                                   for r in recs])
            if targets and target == min(targets):
                reference = pk
            ratio = pk / reference if pk and reference and target is not None else None
            phi = [r.get("packing_solid_fraction") for r in recs]
            lines.append(f"| {base} | {'none' if target is None else f'{target:g}'} | "
                         f"{','.join(str(r['seed']) for r in recs)} | "
                         f"{', '.join(fmt(a, '.3f') + x for a, x in zip(a0, axes))} (mean {fmt(_mean_std(a0)[0])}) | "
                         f"{fmt(_mean_std(phi)[0])} | {fmt(pk)} +- {fmt(pk_sd)} | {fmt(ep, '.2f')} +- {fmt(ep_sd, '.2f')} | {fmt(ratio)} |")
            found.append({"case": base, "target": target, "seeds": [r["seed"] for r in recs], "achieved": a0,
                          "major_axis": axes, "solid_fraction": phi,
                          "peak_mean": pk, "peak_std": pk_sd, "strain_at_peak_pct_mean": ep,
                          "strain_at_peak_pct_std": ep_sd, "peak_over_lowest_target": ratio})
    return lines, found


def cost_lines(measured, dns_unit, fem_unit, table, strain):
    lines = ["| case | runs | size | CPU s per % strain | per disc / Gauss point | wall s per % | load (after) |",
             "|---|---|---|---|---|---|---|"]
    for name in sorted(measured, key=lambda n: (measured[n]["kind"] != "dns", n)):
        m = measured[name]
        unit = "discs" if m["kind"] == "dns" else "Gauss points"
        lines.append(f"| {name} | {m['runs']} | {m['units']} {unit} | {m['cpu_per_pct']:.1f} | "
                     f"{m['cpu_per_pct'] / m['units']:.3g} | {m['wall_per_pct']:.1f} | {m['load']:.2f} |")
    lines += ["", f"To {100 * strain:g} % axial strain (CPU s; * extrapolated: DNS {fmt(dns_unit, '.3g')} CPU s per % "
              "per disc, FEM x DEM " + ", ".join(f"{k} {v:.3g}" for k, v in fem_unit.items()) +
              " CPU s per % per Gauss point):", ""]
    tilings = [f"{t[0]}x{t[1]}" for t in COST_TILINGS]
    lines += ["| FEM x DEM mesh | Gauss points | FEM x DEM CPU s | " +
              " | ".join(f"FEM / DNS {t} ({CELL_DISCS * int(t.split('x')[0]) * int(t.split('x')[1])} discs)"
                         for t in tilings) + " | DNS costs more from (discs) |",
              "|" + "---|" * (4 + len(tilings))]
    for row in table:
        by = {d["tiling"]: d for d in row["dns"]}
        cells = [f"{by[t]['ratio']:.3g}{'' if by[t]['measured'] else '*'}" if t in by else "-" for t in tilings]
        lines.append(f"| {row['mode']} {row['mesh']} | {row['gauss_points']} | {row['fem_cpu']:.0f}"
                     f"{'' if row['fem_measured'] else '*'} | " + " | ".join(cells) +
                     f" | {fmt(row['break_even_discs'], ',.0f')} |")
    return lines


def figure(st, grid, path):
    from cosserat_fenicsx.figures import pyplot
    plt = pyplot()
    keys = [("stress_ratio", "stress ratio |s_a - s_l| / |s_a + s_l| (000 eq. 40)"),
            ("volumetric_strain", "volumetric strain (tension +)"), ("coordination", "coordination number")]
    fig, axes = plt.subplots(1, 3, figsize=(16, 6.5))
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for k, name in enumerate(sorted(st, key=lambda n: (st[n]["kind"] != "dns", n))):
        s = st[name]
        c = colours[k % len(colours)]
        anisotropy = s["records"][0].get("anisotropy")
        locked = ("" if anisotropy is None else f", A0 target {anisotropy:g}") + \
            (", rotations locked" if name.endswith("-locked") else "")
        for ax, (key, ylabel) in zip(axes, keys):
            if key == "stress_ratio":
                mean, std = s["mean"], s["std"]
            else:
                sk = studies(s["records"], grid, key)[name]
                mean, std = sk["mean"], sk["std"]
            x = 100 * grid
            if s["kind"] == "dns":
                ax.plot(x, mean, "-", color=c, lw=2, label=f"DNS {s['size'][0]}x{s['size'][1]} tiles{locked} (seeds "
                        f"{','.join(map(str, s['seeds']))}: mean +- std)")
                ax.fill_between(x, mean - std, mean + std, color=c, alpha=0.25)
            else:
                for r in s["records"]:
                    ax.plot(100 * grid, on_grid(r, grid, key), "--", color=c, lw=0.7)
                ax.plot(x, mean, "-", color=c, lw=1.5, marker="o", ms=2.5,
                        label=(f"stand-alone cell{locked} (mean of seeds " if s["kind"] == "cell" else
                               f"FEM x DEM {s['kind']} {s['size'][0]}x{s['size'][1]}{locked} (mean of seeds ") +
                        f"{','.join(map(str, s['seeds']))}; dashed: each)")
            ax.set_xlabel("axial strain [%] (compression)")
            ax.set_ylabel(ylabel)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=3, fontsize=7)
    fig.suptitle("000 Fig. 4-5 with this project's cell: the tiled-cell DNS against FEM x DEM (same grains, law, p0)")
    fig.tight_layout(rect=(0, 0.05 + 0.018 * math.ceil(len(st) / 3), 1, 1))
    fig.savefig(path, dpi=120)
    plt.close(fig)


def report(out, runs, strain, args_line):
    records = load_records(out, runs)
    if not records:
        print("[dns_vs_femdem] no records yet")
        return None
    top = max(-r["final_axial_strain"] for r in records)
    grid = np.round(np.arange(0.0, min(strain, top) + 1e-9, 0.001), 6)
    st = studies(records, grid)
    cases, rows_csv = case_table(records)
    summary = study_table(st, grid)
    agree, found = agreement_lines(st, grid)
    rotation, rotation_found = rotation_lines(st)
    fabric, fabric_found = anisotropy_lines(st)
    measured, dns_unit, fem_unit, table = cost_rows(records, strain)
    cost = cost_lines(measured, dns_unit, fem_unit, table, strain)
    figure(st, grid, os.path.join(out, "dns_vs_femdem.png"))
    text = [f"# DNS against FEM x DEM ({args_line})", "", "## Cases", ""] + cases + \
        ["", "## Mean and scatter over seeds", ""] + summary + ["", "## Agreement", ""] + agree + \
        (["", "## Rotations free against locked (000 section 4.3.2)", ""] + rotation if rotation_found else []) + \
        (["", "## Initial fabric anisotropy (000 section 4.3.3)", ""] + fabric if fabric_found else []) + \
        ["", "## Cost", ""] + cost + ["", "Figure: dns_vs_femdem.png"]
    with open(os.path.join(out, "dns_vs_femdem.md"), "w") as f:
        f.write("\n".join(text) + "\n")
    with open(os.path.join(out, "dns_vs_femdem.csv"), "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows_csv[0]))
        w.writeheader()
        w.writerows(rows_csv)
    write_json(os.path.join(out, "dns_vs_femdem.json"),
               {"agreement": found, "rotation": rotation_found, "anisotropy": fabric_found, "cost": table, "cost_measured": measured, "dns_cpu_per_pct_per_disc": dns_unit,
                "femdem_cpu_per_pct_per_point": fem_unit})
    print("\n".join(text))
    return text


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], allow_abbrev=False,
                                formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__.split("\n\n", 1)[1])
    p.add_argument("--cases", default=DEFAULT_CASES, help=f"comma-separated KIND-NXxNY (default {DEFAULT_CASES})")
    p.add_argument("--seeds", default=DEFAULT_SEEDS, help=f"packing seeds, comma separated (default {DEFAULT_SEEDS}: "
                   "seeds whose cell dem_specimen.py can tile)")
    p.add_argument("--strain", type=float, default=0.05, help="axial strain of every run (default 0.05)")
    p.add_argument("--step", type=float, default=0.002, help="FEM x DEM load step in strain (default 0.002)")
    p.add_argument("--ranks", type=int, default=2, help="MPI ranks of the FEM x DEM runs (default 2)")
    p.add_argument("--threads", type=int, default=None, help="Numba threads of the DNS (default: all cores)")
    p.add_argument("--report-only", action="store_true", help="only the tables and figure of the records in --out")
    p.add_argument("--reread", action="store_true", help="read the curves of the recorded runs again from their "
                   "outputs before the report (the costs are kept)")
    p.add_argument("--out", default="results/dns_vs_femdem", help="output directory")
    args = p.parse_args(argv)
    try:
        runs = plan([c for c in args.cases.split(",") if c.strip()], [int(s) for s in args.seeds.split(",") if s.strip()])
    except ValueError as error:
        p.error(str(error))
    if not (0.0 < args.strain < 0.5 and 0.0 < args.step <= args.strain):
        p.error(f"--strain must be in (0, 0.5) and --step in (0, strain], got {args.strain}, {args.step}")
    os.makedirs(args.out, exist_ok=True)
    if not args.report_only:
        todo = pending(runs, args.out)
        print(f"[dns_vs_femdem] {len(runs)} runs, {len(runs) - len(todo)} with records, {len(todo)} to run", flush=True)
        for run in todo:
            execute(run, args.out, args.strain, args.step, args.ranks, args.threads,
                    log=lambda m: print(m, flush=True))
    if args.reread:
        reread(args.out, runs)
    report(args.out, runs, args.strain, f"--cases {args.cases} --seeds {args.seeds} --strain {args.strain}")


if __name__ == "__main__":
    main()
