#!/usr/bin/python3
"""FEM x DEM side by side with YADE's FEMxDEM example biaxialSmooth.py, in one run (docs/results/femdem_yade.md).

The problem is YADE's example (Guo & Zhao, /usr/share/doc/yade/examples/FEMxDEM): a
50 mm x 100 mm specimen, 8x16 quadrilaterals with 4 Gauss points each (512 periodic cells of
400 discs made by its prepareRVE.py), lateral pressure 1e5 Pa, smooth platens (u2 = 0 at the
bottom, u2 prescribed at the top, one pin at the bottom centre), the top platen moved down by
1e-4 m = 1e-3 of the height per increment.

1. Debian packages: yade and python3-escript (installed with apt-get when missing and root).
2. YADE: prepareRVE.py makes 0.yade.gz (cached in --out/yade), then biaxialSmooth.py runs for
   --increments increments on a pool of --np worker processes, through femdem_yade_driver.py
   (the example's code unchanged except `file` -> `open`, the pool size, the number of
   increments and no final dump of the 512 packings; timing and counting wrap its MultiScale
   methods from outside).
3. The RVE (0.yade.gz) is exported and converted to a demcell packing (.npz), per unit
   out-of-plane thickness: YADE's cell is a layer of spheres of thickness t = hSize[2,2]
   = 0.1 m confined to the plane, its stress is Pa = force x length / (area x t). A 2D cell
   per unit thickness carrying forces f / t has stress (1/area) sum (f/t) x l, numerically the
   same number, in N/m per metre of thickness: so kn_2D = kn / t, ks_2D = ks / t,
   mass_2D = mass / t (density 2650 kg/m^3 x 1 m), p0 = 1e5 N/m per m, and the platen force
   per unit specimen thickness [N/m] of both codes is compared directly.
   Contact law: YADE's Ip2_FrictMat_FrictMat_FrictPhys gives every contact its own
   kn = 2 E Ra Rb / (Ra + Rb) (E = 6e8 Pa, radii 3-7 mm: 1.9e6-4.2e6 N/m) and ks = 0.8 kn;
   demcell's ContactLaw has one kn for all contacts: ours uses the mean over the RVE's
   contacts (3.01e6 N/m / t) and ks = 0.8 kn; friction tan(0.5) as setContactFriction(0.5).
4. Ours: mpirun -n --np demos/femdem_biaxial.py --mode classical (YADE's continuum is
   Cauchy), Q1 quadrilaterals (--degree-u 1: 2x2 Gauss points, 512 cells on 8x16; YADE uses
   8-node quads with the same 2x2 rule), the same size, pressure and platen increments,
   the packing of 3 (re-equilibrated once at p0 under the constant-kn law), tangent kruyt
   (the uniform-strain contact-stiffness operator, as YADE's getStressAndTangent) and, with
   --tangents kruyt pstlo, pstlo as well; the cells are the demo's defaults (FIRE, batched:
   docs/reference/femdem.md). With --cell-option KEY=VALUE (repeatable; the cells'
   demcell.RelaxationOptions, e.g. method=local) every tangent runs a second time with those
   cells, in the same run, against the same YADE part. With --like-yade ours runs once more
   as YADE's cells run: the kruyt operator and cells that take YADE's mean number of DEM
   steps per cell per Newton pass in this run and do not relax (--cell-option fixed_steps=N):
   the like-for-like ratio of the same work.
   The scatter of the cell: the single-cell response of YADE RVEs from prepareRVE.py with
   makeCloud seeds 1..--scatter-seeds (cell_scatter), the yardstick of the curves' agreement.
   Newton tolerance: YADE stops when |du| / |u| < 1e-2 (L2 norms of the displacement
   correction and of the increment's displacement). With a tangent K, du = K^-1 r and
   u ~ K^-1 dR (dR: the reactions' change over the increment), so that test is about
   |r| / |dR| < 1e-2. Ours stops at FNORM/RNORM <= force_rtol with RNORM the norm of the
   whole reactions R: the equivalent is force_rtol = 1e-2 x mean |dF_top| / |F_top| over the
   increments of YADE's own curve in this run (1.38e-3 over the first 5 increments);
   --force-rtol overrides it.
5. Results in --out: femdem_yade.json (everything), femdem_yade.md (the table: wall and
   CPU seconds per increment, Newton passes, DEM steps, memory, ratios, load averages at the
   start and end of each code's part) and femdem_yade.png (platen force per unit thickness
   against axial strain for both, and wall time per increment).

Memory is the peak of the summed resident set size of each code's process tree (sampled
every 0.2 s): YADE's master and its pool workers, ours mpirun and its ranks.

    /usr/bin/python3 benchmarks/femdem/femdem_yade.py --out results/benchmarks/femdem_yade
    /usr/bin/python3 benchmarks/femdem/femdem_yade.py --increments 10 --tangents kruyt pstlo
    /usr/bin/python3 benchmarks/femdem/femdem_yade.py --tangents pstlo kruyt --like-yade
    /usr/bin/python3 benchmarks/femdem/femdem_yade.py --reuse-yade --tangents kruyt --cell-option method=local

About 15 minutes for the default 5 increments on a 2-core machine at load 1.5-5 (YADE 9 min,
50-160 s per increment; ours 3-4 min per tangent; the scatter estimate 20 s). Measured figures
and what they mean: docs/results/femdem_yade.md.
"""
import argparse
import csv
import json
import os
import resource
import shutil
import subprocess
import sys
import threading
import time

import numpy as np

from benchmarks import ROOT

HERE = os.path.dirname(os.path.abspath(__file__))

EXAMPLE = "/usr/share/doc/yade/examples/FEMxDEM"
YADE_PY = "/usr/lib/x86_64-linux-gnu/yade-double/py/yade/FEMxDEM"
ESCRIPT = "/usr/lib/python3-escript"
PACKAGES = ("yade", "python3-escript")
#: YADE's example: specimen [m], lateral pressure [Pa], platen displacement per increment [m],
#: Newton tolerance on |du| / |u|
WIDTH, HEIGHT, PRESSURE, PLATEN_STEP, YADE_RTOL = 0.05, 0.1, 1e5, 1e-4, 1e-2
MESH = "8x16"
CELLS = 512              # 8 x 16 quadrilaterals x 4 Gauss points


def installed(package):
    r = subprocess.run(["dpkg-query", "-W", "-f=${Status}", package], capture_output=True, text=True)
    return "ok installed" in r.stdout


def ensure_packages():
    missing = [p for p in PACKAGES if not installed(p)]
    if not missing:
        return
    if os.geteuid() != 0:
        raise SystemExit(f"missing Debian packages {missing}: sudo apt-get install -y --no-install-recommends "
                         + " ".join(missing))
    print(f"installing {missing}", flush=True)
    env = dict(os.environ, DEBIAN_FRONTEND="noninteractive")
    subprocess.run(["apt-get", "update", "-q"], check=True, env=env)
    subprocess.run(["apt-get", "install", "-y", "-q", "--no-install-recommends", *missing], check=True, env=env)


class TreeMonitor:
    """Samples a process and its descendants every `every` s in a thread: the peak of their
    summed VmRSS [bytes], and their CPU time (utime + stime of the live processes) each time
    the file `watch` gains a line (ours: a converged step in history.csv)."""

    def __init__(self, pid, every=0.2, watch=None):
        self.pid, self.every, self.watch = pid, every, watch
        self.peak, self.peak_processes = 0, 0
        self.marks = []                   # (lines of watch, time, tree CPU [s]) when it changed
        self._tick = os.sysconf("SC_CLK_TCK")
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _tree(self):
        children = {}
        for p in os.listdir("/proc"):
            if p.isdigit():
                try:
                    ppid = int(open(f"/proc/{p}/stat").read().rsplit(")", 1)[1].split()[1])
                except (OSError, IndexError, ValueError):
                    continue
                children.setdefault(ppid, []).append(int(p))
        out, todo = [], [self.pid]
        while todo:
            p = todo.pop()
            out.append(p)
            todo.extend(children.get(p, []))
        return out

    def _sample(self):
        rss, cpu, n = 0, 0.0, 0
        for p in self._tree():
            try:
                fields = open(f"/proc/{p}/stat").read().rsplit(")", 1)[1].split()
                cpu += (int(fields[11]) + int(fields[12])) / self._tick
                for line in open(f"/proc/{p}/status"):
                    if line.startswith("VmRSS:"):
                        rss += int(line.split()[1]) * 1024
                        n += 1
            except (OSError, IndexError, ValueError):
                pass
        return rss, cpu, n

    def _run(self):
        lines = 0
        while not self._stop.is_set():
            rss, cpu, n = self._sample()
            if rss > self.peak:
                self.peak, self.peak_processes = rss, n
            if self.watch is not None and os.path.exists(self.watch):
                with open(self.watch) as f:
                    now = sum(1 for _ in f)
                if now != lines:
                    lines = now
                    self.marks.append((now, time.time(), cpu))
            self._stop.wait(self.every)

    def stop(self):
        self._stop.set()
        self._thread.join()


def run_measured(cmd, log, env, cwd=None, timeout=None, watch=None):
    """Run cmd (its output to log); returns (returncode, wall [s], CPU of waited-for children [s],
    peak tree RSS [bytes], processes at the peak, load average before and after)."""
    load0 = list(os.getloadavg())
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    with open(log, "w") as f:
        p = subprocess.Popen(cmd, stdout=f, stderr=subprocess.STDOUT, env=env, cwd=cwd)
        mem = TreeMonitor(p.pid, watch=watch)
        try:
            rc = p.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            p.kill()
            rc = p.wait()
        mem.stop()
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    return dict(returncode=rc, wall=wall, cpu_waited_children=cpu, peak_rss_bytes=mem.peak,
                processes_at_peak=mem.peak_processes, load_start=load0, load_end=list(os.getloadavg()), cpu_marks=mem.marks)


# --- YADE ----------------------------------------------------------------------------------
def yade_env(workdir, extra=None):
    env = dict(os.environ, OMP_NUM_THREADS="1",
               PYTHONPATH=":".join([ESCRIPT, YADE_PY, workdir]),
               LD_LIBRARY_PATH=os.path.join(ESCRIPT, "lib"))
    env.update(extra or {})
    return env


def yade_prepare(yade, work, copy=True):
    """YADE's RVE: prepareRVE.py -> 0.yade.gz (deterministic: makeCloud seed 1), cached.
    copy: the example's scripts into work (False: a prepareRVE.py is there already)."""
    os.makedirs(work, exist_ok=True)
    for f in ("biaxialSmooth.py", "prepareRVE.py") if copy else ():
        shutil.copy(os.path.join(EXAMPLE, f), work)
    link = os.path.join(work, "yadeimport.py")
    if not os.path.exists(link):
        os.symlink(os.path.realpath(shutil.which(yade)), link)
    rve = os.path.join(work, "0.yade.gz")
    if not os.path.exists(rve):
        with open(os.path.join(work, "prepare.log"), "w") as f:
            subprocess.run([yade, "-n", "-x", "-j1", "prepareRVE.py"], cwd=work, stdout=f, stderr=subprocess.STDOUT,
                           env=dict(os.environ, OMP_NUM_THREADS="1"), timeout=1800)
        if not os.path.exists(rve):
            raise SystemExit(f"prepareRVE.py made no 0.yade.gz, see {work}/prepare.log")
    export = os.path.join(work, "rve.json")
    subprocess.run([yade, "-n", "-x", "-j1", os.path.join(HERE, "femdem_yade_driver.py"), "export", rve, export],
                   cwd=work, stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT, timeout=600)
    if not os.path.exists(export):
        raise SystemExit("exporting the RVE failed: run femdem_yade_driver.py export by hand to see why")
    return json.load(open(export))


def yade_run(yade, work, increments, np_):
    record = os.path.join(work, "record.jsonl")
    for f in (record, os.path.join(work, "result", "biaxial_surf.dat")):
        if os.path.exists(f):
            os.remove(f)
    cmd = ["nice", yade, "-n", "-x", "-j1", os.path.join(HERE, "femdem_yade_driver.py"), "run", "biaxialSmooth.py",
           record]
    m = run_measured(cmd, os.path.join(work, "biaxial.log"), yade_env(work, dict(NP=str(np_), NSTEPS=str(increments))),
                     cwd=work)
    rows = [json.loads(line) for line in open(record)] if os.path.exists(record) else []
    inc = [r for r in rows if r["kind"] == "increment"]
    full = [r for r in rows if r["kind"] == "increment_with_output"]
    for r, f in zip(inc, full):
        r["wall_with_output"] = f["wall"]
    setup = next((r for r in rows if r["kind"] == "setup"), {})
    end = next((r for r in rows if r["kind"] == "end"), {})
    surf = os.path.join(work, "result", "biaxial_surf.dat")
    curve = []
    if os.path.exists(surf):
        for line in open(surf):
            if line.strip() and not line.startswith("#"):
                v = line.split()
                curve.append((float(v[0]), float(v[1])))
    if len(inc) < increments:
        raise SystemExit(f"YADE ran {len(inc)} of {increments} increments (rc {m['returncode']}), "
                         f"see {work}/biaxial.log")
    m.update(increments=inc, setup=setup, cpu_total=end.get("cpu"), wall_in_script=end.get("wall"),
             curve_strain_force=curve)
    return m


# --- ours ----------------------------------------------------------------------------------
def demcell_packing(rve, path):
    """YADE's RVE per unit out-of-plane thickness (module docstring, point 3) -> demcell .npz."""
    import demcell as dc
    from demcell.state import CellState
    t = rve["thickness"]
    h = np.array(rve["h"])
    x = np.column_stack([rve["x"], rve["y"]])
    state = CellState.new(np.array(rve["radius"]), (np.linalg.inv(h) @ x.T).T, h, 1.0)
    state.mass[:] = np.array(rve["mass"]) / t
    state.inertia[:] = np.array(rve["inertia"]) / t
    dc.save_packing(path, state, dict(n_particles=int(state.n_particles), source="YADE prepareRVE.py 0.yade.gz",
                                      thickness=t))
    kn = float(np.mean(rve["contact_kn"])) / t
    ks_over_kn = float(np.mean(np.array(rve["contact_ks"]) / np.array(rve["contact_kn"])))
    return dict(kn=kn, ks=ks_over_kn * kn, friction=float(rve["friction"]),
                kn_yade_range=[float(np.min(rve["contact_kn"])) / t, float(np.max(rve["contact_kn"])) / t])


def label(run):
    """A run's name in the tables: its tangent, and its cell options if any (records written
    before the option existed have no label)."""
    return run.get("label", run["tangent"])


def run_words(tangent, cell_options=(), batched=False, rule=None):
    """The words naming one of ours' runs: its label in the record and the tables (joined by
    spaces) and its folder (by underscores); rule: how often the operator is built, if given."""
    return [tangent, *cell_options] + (["batched"] if batched else []) + ([rule] if rule else [])


def operator_rule(word):
    """'lag-N' or 'refresh-C' as the demo's options (--jacobian-lag N, --jacobian-refresh C)."""
    kind, _, value = word.partition("-")
    if kind not in ("lag", "refresh") or not value:
        raise ValueError(f"an operator rule is lag-N or refresh-C, got {word!r}")
    return [f"--jacobian-{kind}", value]


def ours_run(packing, law, increments, np_, tangent, force_rtol, relaxation_tol, out, mpirun, timeout,
             cell_options=(), batched=False, rule=None):
    """One run of the demo on YADE's problem; cell_options: "KEY=VALUE" strings passed on as
    --cell-option (demcell.RelaxationOptions of the cells); batched: the demo's --batched (a
    rank's cells in one struct of arrays, solved and homogenised by one Numba call each); rule:
    how often the operator is built ('lag-N' or 'refresh-C'; None: the demo's default)."""
    os.makedirs(out, exist_ok=True)
    cmd = ["nice", mpirun, "-n", str(np_), sys.executable, os.path.join(ROOT, "demos", "femdem_biaxial.py"),
           "--mesh", MESH, "--cell-type", "quadrilateral", "--degree-u", "1", "--mode", "classical",
           "--width", repr(WIDTH), "--height", repr(HEIGHT), "--packing", packing,
           "--kn", repr(law["kn"]), "--ks", repr(law["ks"]), "--friction", repr(law["friction"]),
           "--pressure", repr(PRESSURE), "--axial-strain", repr(increments * PLATEN_STEP / HEIGHT),
           "--steps", str(increments), "--tangent", tangent, "--force-rtol", repr(force_rtol),
           "--accept-rtol", repr(max(3e-2, force_rtol)), "--fields", "displacement",
           "--write-every", str(increments + 10), "--out", out]
    if relaxation_tol is not None:
        cmd += ["--relaxation-tol", repr(relaxation_tol)]
    for option in cell_options:
        cmd += ["--cell-option", option]
    if batched:
        cmd.append("--batched")
    if rule:
        cmd += operator_rule(rule)
    env = dict(os.environ, OMP_NUM_THREADS="1", OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
               OMPI_MCA_rmaps_base_oversubscribe="1")
    hist = os.path.join(out, "history.csv")
    if os.path.exists(hist):
        os.remove(hist)
    m = run_measured(cmd, os.path.join(out, "run.log"), env, timeout=timeout, watch=hist)
    if not os.path.exists(hist):
        raise SystemExit(f"ours made no history (rc {m['returncode']}), see {out}/run.log")
    rows = list(csv.DictReader(open(hist)))
    summary = json.load(open(os.path.join(out, "summary.json")))
    wall = [float(r["wall_time"]) for r in rows]
    # tree CPU when history.csv had 1 (header) + k lines: the end of step k (0.2 s sampling)
    cpu_at = {lines - 1: cpu for lines, _, cpu in m["cpu_marks"]}
    inc = []
    for k, r in enumerate(rows):
        if r["phase"] != "2":
            continue
        cpu = cpu_at[k + 1] - cpu_at[k] if k in cpu_at and k + 1 in cpu_at else float("nan")
        # a pass = a residual evaluation at a new displacement: every Newton iteration (the
        # evaluation at the last converged state that SNES starts with only checks the cells)
        inc.append(dict(wall=wall[k] - wall[k - 1], cpu=cpu, newton_iterations=int(r["newton_iterations"]),
                        passes=int(r["newton_iterations"]), dem_steps=float(r["dem_steps"]),
                        force_ratio=float(r["force_ratio"]), accepted=int(r["accepted"])))
    curve = [(float(r["axial_strain"]), float(r["vertical_reaction"])) for r in rows]
    m.update(command=" ".join(cmd), increments=inc, curve_strain_force=curve, tangent=tangent,
             label=" ".join(run_words(tangent, cell_options, batched, rule)),
             cell_options=list(cell_options), batched=batched, operator_rule=rule, force_rtol=force_rtol,
             setup_wall=m["wall"] - sum(i["wall"] for i in inc), summary={
                 k: summary.get(k) for k in ("memory_per_cell_bytes", "time_max_over_ranks", "n_gauss_points",
                                             "particles_per_cell", "cell_preparation_time", "wall_time",
                                             "dem_steps_total", "completed", "stopped", "newton_force_ratios")})
    if len(inc) < increments:
        raise SystemExit(f"ours ran {len(inc)} of {increments} increments, see {out}/run.log")
    return m


# --- the scatter of the cell ---------------------------------------------------------------
def cell_scatter(yade, out, seeds, law, increments, width):
    """The platen force per unit thickness of a homogeneous specimen (one cell: F_22 imposed,
    sigma_11 = -p0 by the servo, F_12 = F_21 = 0) for YADE RVEs from prepareRVE.py with other
    makeCloud seeds (seed 1 is the example's), all under ours' law of the example's RVE:
    its spread is the scatter of a 400-disc cell, the yardstick of the curves' agreement.
    Returns {seed: [force at 0, 1, ..., increments x 1e-3 axial strain]}."""
    from benchmarks.femdem.femdem_cases import homogeneous_path
    from cosserat_fenicsx.materials.dem import CellOptions, reference_cells
    curves = {}
    for seed in seeds:
        work = os.path.abspath(os.path.join(out, f"seed_{seed}"))
        os.makedirs(work, exist_ok=True)
        src = open(os.path.join(EXAMPLE, "prepareRVE.py")).read()
        if "seed=1)" not in src:
            raise SystemExit("prepareRVE.py has changed: no 'seed=1)' to replace")
        open(os.path.join(work, "prepareRVE.py"), "w").write(src.replace("seed=1)", f"seed={seed})"))
        rve = yade_prepare(yade, work, copy=False)
        packing = os.path.join(work, "rve_yade.npz")
        demcell_packing(rve, packing)
        opts = CellOptions(packing=packing, pressure=PRESSURE, kn=law["kn"], ks=law["ks"], friction=law["friction"],
                           criterion="force")
        cell = reference_cells(opts, [law["friction"]])[0][0]
        force = [float(cell.cauchy_stress()[1, 1]) * width]
        try:
            path = homogeneous_path(cell, [-k * PLATEN_STEP / HEIGHT for k in range(1, increments + 1)], PRESSURE)
        except RuntimeError as error:
            raise SystemExit(f"seed {seed}: {error}")
        force += [float(sigma[1, 1]) * width for sigma in path]
        curves[seed] = force
        print(f"cell of seed {seed}: force {np.round(force, 1).tolist()} N/m", flush=True)
    return curves


# --- report --------------------------------------------------------------------------------
def mean(rows, key):
    return float(np.mean([r[key] for r in rows]))


def table(res):
    y = res["yade"]
    lines = ["| increment | YADE wall s | YADE CPU s | YADE passes | YADE DEM steps | "
             + " | ".join(f"ours {label(o)} wall s | CPU s | passes | DEM steps | FNORM/RNORM | wall ratio YADE/ours"
                          for o in res["ours"]) + " |",
             "|" + "---|" * (5 + 6 * len(res["ours"]))]
    for k, yi in enumerate(y["increments"]):
        cells = [str(k + 1), f"{yi['wall']:.1f}", f"{yi['cpu']:.1f}", str(yi["passes"]), f"{yi['dem_steps']:.3g}"]
        for o in res["ours"]:
            oi = o["increments"][k]
            cells += [f"{oi['wall']:.2f}", f"{oi['cpu']:.1f}", str(oi["passes"]), f"{oi['dem_steps']:.3g}", f"{oi['force_ratio']:.2g}",
                      f"{yi['wall'] / oi['wall']:.1f}"]
        lines.append("| " + " | ".join(cells) + " |")
    cells = ["mean", f"{mean(y['increments'], 'wall'):.1f}", f"{mean(y['increments'], 'cpu'):.1f}",
             f"{mean(y['increments'], 'passes'):.2f}", f"{mean(y['increments'], 'dem_steps'):.3g}"]
    for o in res["ours"]:
        cells += [f"{mean(o['increments'], 'wall'):.2f}", f"{mean(o['increments'], 'cpu'):.1f}",
                  f"{mean(o['increments'], 'passes'):.2f}",
                  f"{mean(o['increments'], 'dem_steps'):.3g}", "",
                  f"{mean(y['increments'], 'wall') / mean(o['increments'], 'wall'):.1f}"]
    lines.append("| " + " | ".join(cells) + " |")
    lines.append("")
    lines.append("| run | wall s (all) | CPU s (all) | set-up s | peak RSS of the tree MB | processes | "
                 "load avg start | load avg end |")
    lines.append("|---|---|---|---|---|---|---|---|")
    runs = [("YADE", y, y["cpu_total"], y["setup"].get("wall", float("nan")))] + \
        [(f"ours {label(o)}", o, o["cpu_waited_children"], o["setup_wall"]) for o in res["ours"]]
    for name, r, cpu, setup in runs:
        lines.append(f"| {name} | {r['wall']:.1f} | {cpu:.1f} | {setup:.1f} | {r['peak_rss_bytes'] / 2**20:.0f} | "
                     f"{r['processes_at_peak']} | {r['load_start'][0]:.2f} | {r['load_end'][0]:.2f} |")
    lines.append("")
    lines.append("| one cell pass | wall ms x processes | CPU ms | DEM steps |")
    lines.append("|---|---|---|---|")
    for name, r in [("YADE", y)] + [(f"ours {label(o)}", o) for o in res["ours"]]:
        c = r["per_cell_pass"]
        lines.append(f"| {name} | {c['wall_ms_x_np']:.1f} | {c['cpu_ms']:.1f} | {c['dem_steps']:.0f} |")
    sc = res.get("cell_scatter")
    lines.append("")
    lines.append("| axial strain % | YADE force N/m | " + " | ".join(f"ours {label(o)}" for o in res["ours"])
                 + (" | single cells of seeds 1..N: mean | std | min | max" if sc else "") + " |")
    lines.append("|---|---|" + "---|" * len(res["ours"]) + ("---|---|---|---|" if sc else ""))
    for k, (e, f) in enumerate(y["curve_strain_force"]):
        cells = [f"{abs(100 * e):.1f}", f"{f:.0f}"] + [f"{o['curve_strain_force'][k][1]:.0f}" for o in res["ours"]]
        if sc:
            cells += [f"{sc['mean'][k]:.0f}", f"{sc['std'][k]:.0f}" if sc["std"] else "", f"{sc['min'][k]:.0f}",
                      f"{sc['max'][k]:.0f}"]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


STYLES = ("rs--", "b^:", "g.-", "mv-.", "cD--", "yo:")     # one per run of ours (tangents x cells)


def plot(res, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(1, 3, figsize=(17, 4.8))
    e, f = np.array(res["yade"]["curve_strain_force"]).T
    sc = res.get("cell_scatter")
    if sc:
        ax[0].fill_between(-100 * e, -np.array(sc["min"]) / 1e3, -np.array(sc["max"]) / 1e3, color="0.85",
                           label=f"single cells, YADE RVEs of seeds 1-{len(sc['seeds'])} (ours' law): range")
    ax[0].plot(-100 * e, -f / 1e3, "ko-", label="YADE FEMxDEM biaxialSmooth.py")
    for o, style in zip(res["ours"], STYLES):
        e, f = np.array(o["curve_strain_force"]).T
        ax[0].plot(-100 * e, -f / 1e3, style, label=f"ours, {label(o)}")
    ax[0].set_xlabel("axial strain -eps_22 [%]")
    ax[0].set_ylabel("top platen force per unit thickness [kN/m]")
    ax[0].legend(fontsize=8); ax[0].grid(alpha=0.3)
    # the same curves minus the mean single-cell curve: the agreement on the scale of the scatter
    e, f = np.array(res["yade"]["curve_strain_force"]).T
    ref = np.array(sc["mean"]) if sc else f
    if sc:
        ax[2].fill_between(-100 * e, -(np.array(sc["min"]) - ref), -(np.array(sc["max"]) - ref), color="0.85",
                           label="single cells of the seeds: range")
    ax[2].plot(-100 * e, -(f - ref), "ko-", label="YADE")
    for o, style in zip(res["ours"], STYLES):
        eo, fo = np.array(o["curve_strain_force"]).T
        ax[2].plot(-100 * eo, -(fo - ref[:len(fo)]), style, label=f"ours, {label(o)}")
    ax[2].set_xlabel("axial strain -eps_22 [%]")
    ax[2].set_ylabel("force - " + ("mean single-cell force" if sc else "YADE's") + " [N/m]")
    ax[2].legend(fontsize=8); ax[2].grid(alpha=0.3)
    k = np.arange(1, len(res["yade"]["increments"]) + 1)
    w = 0.8 / (1 + len(res["ours"]))
    ax[1].bar(k - 0.4 + w / 2, [i["wall"] for i in res["yade"]["increments"]], w, color="k", label="YADE")
    for j, (o, style) in enumerate(zip(res["ours"], STYLES)):
        ax[1].bar(k - 0.4 + w * (j + 1.5), [i["wall"] for i in o["increments"]], w, color=style[0],
                  label=f"ours {label(o)}")
    ax[1].set_yscale("log"); ax[1].set_xlabel("increment"); ax[1].set_ylabel("wall time of the Newton solve [s]")
    ax[1].legend(fontsize=8); ax[1].grid(alpha=0.3, which="both")
    fig.suptitle(f"FEM x DEM biaxial, {MESH} quads x 4 Gauss points = 512 cells of 400 discs, both on "
                 f"{res['np']} processes")
    fig.tight_layout(); fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--increments", type=int, default=5, help="load increments of 1e-3 axial strain (default 5)")
    p.add_argument("--np", type=int, default=2, help="YADE pool workers and our MPI ranks (default 2)")
    p.add_argument("--tangents", nargs="+", default=["pstlo"], choices=("kruyt", "pstlo", "demqo", "perturbation"),
                   help="our tangent(s), one run each (default pstlo, the demo's; kruyt is the closest to YADE's)")
    p.add_argument("--force-rtol", type=float, default=None,
                   help="our Newton tolerance FNORM/RNORM (default: the equivalent of YADE's |du|/|u| < 1e-2 "
                        "from YADE's curve in this run, module docstring)")
    p.add_argument("--relaxation-tol", type=float, default=None,
                   help="our cells' relaxation tolerance (default: the demo's, docs/reference/femdem.md; YADE's "
                        "cells do not relax: about 100 steps per call)")
    p.add_argument("--like-yade", action="store_true",
                   help="run ours once more as YADE runs: its operator (kruyt) and cells that do not relax "
                        "(--cell-option fixed_steps=N, N = YADE's mean DEM steps per cell per Newton pass in "
                        "this run): the like-for-like ratio of the same work")
    p.add_argument("--cell-option", action="append", default=[], metavar="KEY=VALUE",
                   help="run every tangent a second time with these cells (demcell.RelaxationOptions, e.g. "
                        "method=fire; repeat for more; passed on to demos/femdem_biaxial.py)")
    p.add_argument("--operator-rules", nargs="+", default=None, metavar="RULE",
                   help="run every tangent once per rule for how often the operator is built: lag-N (the demo's "
                        "--jacobian-lag N) or refresh-C (--jacobian-refresh C); default: the demo's default only")
    p.add_argument("--batched", action="store_true",
                   help="label ours' runs 'batched' and pass --batched (the demo's default since the defaults "
                        "study), so that --reuse-yade keeps older per-cell runs beside them")
    p.add_argument("--scatter-seeds", type=int, default=6,
                   help="YADE RVEs (prepareRVE.py seeds 1..N) whose single-cell response gives the scatter of "
                        "the cell (default 6; 0: skip)")
    p.add_argument("--yade", default="yade")
    p.add_argument("--mpirun", default="mpirun")
    p.add_argument("--timeout", type=float, default=7200, help="limit per run [s]")
    p.add_argument("--out", default="results/benchmarks/femdem_yade")
    p.add_argument("--reuse-yade", action="store_true",
                   help="take YADE's part (its record, the RVE, the tolerance) from --out/femdem_yade.json of an "
                        "earlier run instead of running it again (15 min here); ours' runs are added to that "
                        "record, replacing runs of the same tangent and cell options")
    p.add_argument("--report-only", action="store_true",
                   help="only rewrite the table and the plot from --out/femdem_yade.json (no run)")
    a = p.parse_args(argv)
    if a.report_only:
        res = json.load(open(os.path.join(a.out, "femdem_yade.json")))
        report(res, a.out)
        return
    if a.increments < 1 or a.np < 1:
        raise SystemExit("--increments and --np must be >= 1")
    for rule in a.operator_rules or ():
        try:
            operator_rule(rule)
        except ValueError as error:
            raise SystemExit(f"--operator-rules: {error}")
    if a.force_rtol is not None and not 0 < a.force_rtol < 1:
        raise SystemExit("--force-rtol must be in (0, 1)")
    if a.cell_option:       # refused here, before YADE's 10 minutes, not by the demo after them
        from cosserat_fenicsx.materials.dem import CellOptions
        from cosserat_fenicsx.validation import key_value
        try:
            CellOptions(extra=dict(key_value(o) for o in a.cell_option)).check()
        except (ValueError, TypeError, argparse.ArgumentTypeError) as error:
            raise SystemExit(f"--cell-option: {error}")
    record = os.path.join(a.out, "femdem_yade.json")
    if a.reuse_yade:
        res = reused_record(record, a)
        run_ours(res, a, res["law_ours"], os.path.abspath(os.path.join(a.out, "rve_yade.npz")),
                 a.force_rtol if a.force_rtol is not None else res["force_rtol"])
        return
    ensure_packages()
    for exe in (a.yade, a.mpirun):
        if not shutil.which(exe):
            raise SystemExit(f"{exe} not found")
    os.makedirs(a.out, exist_ok=True)
    work = os.path.abspath(os.path.join(a.out, "yade"))
    rve = yade_prepare(a.yade, work)
    packing = os.path.abspath(os.path.join(a.out, "rve_yade.npz"))
    law = demcell_packing(rve, packing)
    print(f"RVE: {len(rve['radius'])} discs, {len(rve['contact_kn'])} contacts, t = {rve['thickness']} m, YADE dt "
          f"{rve['dt']:.3g} s, damping {rve['damping']}; ours kn = {law['kn']:.4g} N/m per m (YADE's per contact "
          f"{law['kn_yade_range'][0]:.3g}-{law['kn_yade_range'][1]:.3g}), ks = {law['ks']:.4g}, mu = "
          f"{law['friction']:.4f}", flush=True)

    print(f"YADE: {a.increments} increments on {a.np} workers ...", flush=True)
    y = yade_run(a.yade, work, a.increments, a.np)
    print(f"YADE: {y['wall']:.0f} s, mean {mean(y['increments'], 'wall'):.1f} s per increment", flush=True)
    f = np.array(y["curve_strain_force"])[:, 1]
    grow = float(np.mean(np.abs(np.diff(f)) / np.abs(f[1:])))
    rtol = a.force_rtol if a.force_rtol is not None else YADE_RTOL * grow
    res = dict(np=a.np, increments_requested=a.increments, mesh=MESH, width=WIDTH, height=HEIGHT, pressure=PRESSURE,
               platen_step=PLATEN_STEP, yade_rtol=YADE_RTOL, reaction_growth_per_increment=grow,
               force_rtol=rtol, relaxation_tol=a.relaxation_tol, force_rtol_from="option" if a.force_rtol is not None else "YADE rtol x mean |dF|/|F|",
               rve=dict(n=len(rve["radius"]), contacts=len(rve["contact_kn"]), thickness=rve["thickness"],
                        dt=rve["dt"], damping=rve["damping"], stress_pa=rve["stress_pa"]),
               law_ours=law, yade=y, ours=[])
    with open(record, "w") as fh:      # YADE's part kept if ours fails
        json.dump(res, fh, indent=1)
    run_ours(res, a, law, packing, rtol)


def reused_record(record, a):
    """The record of an earlier run whose YADE part ``--reuse-yade`` takes, checked against
    the options before any work."""
    if not os.path.exists(record):
        raise SystemExit(f"--reuse-yade: no {record} of an earlier run")
    with open(record) as fh:
        res = json.load(fh)
    if "yade" not in res or not os.path.exists(os.path.join(a.out, "rve_yade.npz")):
        raise SystemExit(f"--reuse-yade: {record} has no YADE part (or rve_yade.npz is missing)")
    if res["increments_requested"] != a.increments or res["np"] != a.np:
        raise SystemExit(f"--reuse-yade: the earlier run had --increments {res['increments_requested']} "
                         f"--np {res['np']}; give the same")
    if not shutil.which(a.mpirun):
        raise SystemExit(f"{a.mpirun} not found")
    res["yade_reused"] = True
    return res


def yade_steps_per_cell_pass(y):
    """YADE's DEM steps per cell per Newton pass (its ns = int(max(1e5 max|D|, 2)), the mean over
    the cells and passes of its run, rounded): the fixed_steps of ours' like-for-like cells."""
    passes = sum(i["passes"] for i in y["increments"]) * CELLS
    return max(1, int(round(sum(i["dem_steps"] for i in y["increments"]) / passes)))


def run_ours(res, a, law, packing, rtol):
    """Ours' runs (every tangent, then every tangent with --cell-option, then with --like-yade
    the Kruyt operator, YADE's, with cells that take YADE's DEM steps per pass), the scatter of
    the cell and the report, added to ``res`` and written as they go."""
    y = res["yade"]
    record = os.path.join(a.out, "femdem_yade.json")
    rules = a.operator_rules or [None]
    variants = [(t, (), rule) for t in a.tangents for rule in rules]
    if a.cell_option:
        variants += [(t, tuple(a.cell_option), rule) for t in a.tangents for rule in rules]
    if a.like_yade:     # YADE builds its operator at every pass
        res["yade_steps_per_cell_pass"] = yade_steps_per_cell_pass(y)
        variants.append(("kruyt", (f"fixed_steps={res['yade_steps_per_cell_pass']}",), "lag-1"))
    for tangent, cell_options, rule in variants:
        words = run_words(tangent, cell_options, a.batched, rule)
        name = " ".join(words)
        print(f"ours: {name}, force_rtol {rtol:.3g} ...", flush=True)
        o = ours_run(packing, law, a.increments, a.np, tangent, rtol, a.relaxation_tol,
                     os.path.join(a.out, "ours_" + "_".join(words).replace("=", "-")), a.mpirun,
                     a.timeout, cell_options, a.batched, rule)
        print(f"ours {name}: {o['wall']:.0f} s, mean {mean(o['increments'], 'wall'):.2f} s per increment",
              flush=True)
        fy = np.array(y["curve_strain_force"])[:, 1]
        fo = np.array(o["curve_strain_force"])[:, 1]
        n = min(len(fy), len(fo))
        o["force_relative_difference"] = (np.abs(fo[:n] - fy[:n]) / np.abs(fy[:n])).tolist()
        o["wall_ratio_mean"] = mean(y["increments"], "wall") / mean(o["increments"], "wall")
        o["wall_ratio_per_increment"] = [yi["wall"] / oi["wall"] for yi, oi in zip(y["increments"], o["increments"])]
        res["ours"] = [r for r in res["ours"] if label(r) != label(o)] + [o]
        with open(record, "w") as fh:
            json.dump(res, fh, indent=1)
    if a.scatter_seeds > 0 and not (a.reuse_yade and res.get("cell_scatter")):
        curves = cell_scatter(a.yade, os.path.join(a.out, "scatter"), range(1, a.scatter_seeds + 1), law,
                              a.increments, WIDTH)
        f = np.array(list(curves.values()))
        res["cell_scatter"] = dict(seeds=list(curves), force=f.tolist(), mean=f.mean(0).tolist(),
                                   std=f.std(0, ddof=1).tolist() if len(f) > 1 else None,
                                   min=f.min(0).tolist(), max=f.max(0).tolist())
    for o in [res["yade"]] + res["ours"]:       # cost of one cell pass (one cell, one Newton pass)
        inc = o["increments"]
        passes = sum(i["passes"] for i in inc) * CELLS
        o["per_cell_pass"] = dict(wall_ms_x_np=1e3 * a.np * sum(i["wall"] for i in inc) / passes,
                                  cpu_ms=1e3 * sum(i["cpu"] for i in inc) / passes,
                                  dem_steps=sum(i["dem_steps"] for i in inc) / passes)
    with open(record, "w") as fh:
        json.dump(res, fh, indent=1)
    report(res, a.out)


def report(res, out):
    """femdem_yade.md (the tables) and femdem_yade.png from the results; prints the tables."""
    text = table(res)
    with open(os.path.join(out, "femdem_yade.md"), "w") as fh:
        fh.write(text + "\n")
    plot(res, os.path.join(out, "femdem_yade.png"))
    print(text)
    for o in res["ours"]:
        print(f"ours {label(o)}: wall per increment YADE / ours = {o['wall_ratio_mean']:.1f}; platen force "
              f"relative difference per increment {np.round(o['force_relative_difference'], 4).tolist()}")


if __name__ == "__main__":
    main()
