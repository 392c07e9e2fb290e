#!/usr/bin/python3
"""demcell vs YADE speed, side by side in one run.

For each size (default 228, 400, 4000 requested discs; YADE's makeCloud places slightly
fewer, e.g. 383 and 3801):

1. YADE makes the packing with ``../shared/peer-yade/prep_bench.py`` (cached in --out).
2. ``dem_yade_driver.py`` (run by YADE) forces a constant contact stiffness kn, ks on every
   contact (linear Cundall-Strack law, friction tan(0.5) from the packing), exports the
   packing (radii, positions, masses, cell), times NSTEPS steps under the velocity
   gradient of ``peer-yade/run_bench.py`` (1e-5 strain per step, damping 0.7), then one
   quasi-static solve (1e-4 strain in 10 steps, relaxation until max unbalanced force / mean
   contact force <= tol) from the exported state with zero shear forces, whose final
   stress is compared between the codes (a cross-code check of the physics).
   The time step, the same for both codes, is demcell's stable estimate (``--dt-safety``):
   prep_bench's own O.dt is above the stability limit of this law (ks = 0.8 kn) and neither
   code then reaches a quasi-static state.
3. demcell loads the exported packing (same radii, positions, masses, cell, contact law and
   time step; contacts are re-detected, their tangential history starts from zero) and does
   the same two things.

Rounds of (YADE, demcell) alternate so that load changes on the shared machine hit both;
the median ratio and its range over the rounds are reported.
Reported per size: steps/s and contact updates/s (steps/s x contacts per step) per wall
second and per CPU second (the machine is shared, so the CPU-second figures are the fairer
ones), their ratios demcell / YADE, the quasi-static solve (steps, seconds), and the memory
of one cell (state + committed copy, bytes of the arrays). Results go to --out/dem_speed.json
and are printed as a table. Single thread for both (OMP_NUM_THREADS=1, yade -j1).

    /usr/bin/python3 benchmarks/dem/dem_speed.py --out results/dem_speed
"""
import argparse
import json
import math
import os
import shutil
import subprocess
import time

import numpy as np

import demcell as dc
from benchmarks import ROOT
from demcell.contact_law import ContactLaw
from demcell.relaxation import run, stable_time_step
from demcell.state import CellState

HERE = os.path.dirname(os.path.abspath(__file__))
PEER = os.path.join(ROOT, "..", "shared", "peer-yade")


def sh(cmd, log, timeout):
    env = dict(os.environ, OMP_NUM_THREADS="1")
    with open(log, "w") as f:
        p = subprocess.run(cmd, stdout=f, stderr=subprocess.STDOUT, env=env, timeout=timeout)
    return p.returncode


def yade_side(yade, n, out, nsteps, kn, ks, tol, maxsolve, timeout, dt=0.0):
    pack = os.path.join(out, f"pack_{n}.yade.gz")
    if not os.path.exists(pack):
        rc = sh([yade, "-n", "-x", "-j1", os.path.join(PEER, "prep_bench.py"), str(n), pack],
                os.path.join(out, f"yade_prep_{n}.log"), timeout)
        if rc != 0 or not os.path.exists(pack):
            raise RuntimeError(f"YADE packing failed (rc {rc}), see {out}/yade_prep_{n}.log")
    export = os.path.join(out, f"pack_{n}.json")
    log = os.path.join(out, f"yade_run_{n}.log")
    sh([yade, "-n", "-x", "-j1", os.path.join(HERE, "dem_yade_driver.py"), pack, str(nsteps), export,
        repr(kn), repr(ks), repr(tol), str(maxsolve), repr(dt)], log, timeout)
    if nsteps < 2:
        return None, export
    res = {}
    for line in open(log):
        if line.startswith("YADE_TIMING ") or line.startswith("YADE_RESULT "):
            res.update(json.loads(line.split(" ", 1)[1]))
    if "steps_per_s" not in res:
        raise RuntimeError(f"YADE run produced no result, see {log}")
    return res, export


def demcell_state(export):
    d = json.load(open(export))
    h = np.array(d["h"])
    x = np.column_stack([d["x"], d["y"]])
    st = CellState.new(np.array(d["radius"]), (np.linalg.inv(h) @ x.T).T, h, 1.0)
    st.mass[:] = d["mass"]
    st.inertia[:] = 0.5 * st.mass * st.radius ** 2      # as prep_bench.py sets it
    return st, d


def demcell_side(export, nsteps, kn, ks, tol, maxsolve, repeat=3):
    st0, d = demcell_state(export)
    law = ContactLaw(kn=kn, ks=ks, friction=d["friction"])
    la = law.as_array()
    dt = d["dt"]           # the time step YADE used (the one we passed to it)
    dynamics = dc.RelaxationOptions(damping=0.7)      # skin_ratio 0.1: a skin of 0.1 R_min
    # warm-up (JIT, first neighbour list) then timed run under the same velocity gradient
    st = st0.copy()
    run(st, la, dt, st.F, 0, 200, dynamics, check=False)
    F0 = st.F
    rate = 1e-5

    def ramp(state, k):
        F = F0 @ np.diag([math.exp(rate * k), math.exp(-rate * k)])
        return F

    start = st.copy()
    trials = []
    for _ in range(repeat):          # median of `repeat` runs of the same steps
        st = start.copy()
        counts = [int(np.count_nonzero(st.touching[:st.n_pairs]))]
        t0, c0 = time.perf_counter(), time.process_time()
        done = 0
        half = nsteps // 2
        for chunk in (half, nsteps - half):
            rep = run(st, la, dt, ramp(st, done + chunk), chunk, chunk, dynamics, check=False)
            done += chunk
            counts.append(int(np.count_nonzero(st.touching[:st.n_pairs])))
        trials.append((time.process_time() - c0, time.perf_counter() - t0))
    cpu, wall = sorted(trials)[len(trials) // 2]
    cps = sum(counts) / len(counts)
    res = dict(n=int(st.n_particles), steps=nsteps, repeats=repeat, wall=wall, cpu=cpu, steps_per_s=nsteps / wall,
               steps_per_cpu_s=nsteps / cpu, contacts_per_step=cps, contact_updates_per_s=nsteps / wall * cps,
               contact_updates_per_cpu_s=nsteps / cpu * cps, rebuilds=rep.rebuilds,
               stress_yy=float(dc.homogenize(st, la).cauchy[1, 1]) / 0.1)
    # one quasi-static solve from the exported state (same recipe as the YADE driver)
    st = st0.copy()
    run(st, la, dt, st.F, 0, 1, dynamics, check=False)
    t0, c0 = time.perf_counter(), time.process_time()
    F1 = st.F @ np.diag([math.exp(10 * rate), math.exp(-10 * rate)])
    rep = run(st, la, dt, F1, 10, 10 + maxsolve, dc.RelaxationOptions(criterion="force", tol=tol, check_every=50,
                                                                      damping=0.7))
    res.update(solve_steps=rep.steps, solve_wall=time.perf_counter() - t0, solve_cpu=time.process_time() - c0,
               solve_converged=rep.converged, solve_unbalanced=rep.unbalanced_ratio,
               solve_contacts=rep.n_contacts, solve_stress=dc.homogenize(st, la).cauchy.tolist())
    cell = dc.DemCell(st, law)
    res["memory_per_cell_bytes"] = cell.memory_bytes()
    res["memory_per_cell_bytes_per_particle"] = cell.memory_bytes() / st.n_particles
    return res


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sizes", type=int, nargs="+", default=[228, 400, 4000])
    p.add_argument("--steps", type=int, default=20000, help="timed steps at 400 discs (scaled ~1/N)")
    p.add_argument("--repeat", type=int, default=3, help="demcell timing repeats per round (median)")
    p.add_argument("--rounds", type=int, default=3, help="alternating YADE/demcell rounds (median ratio)")
    p.add_argument("--kn", type=float, default=3e6, help="contact normal stiffness [N/m] for both codes")
    p.add_argument("--ks-ratio", type=float, default=0.8, help="ks / kn (YADE poisson=0.8 of prep_bench)")
    p.add_argument("--tol", type=float, default=1e-3, help="unbalanced-force ratio of the quasi-static solve")
    p.add_argument("--max-solve", type=int, default=100000, help="step limit of the quasi-static solve")
    p.add_argument("--dt-safety", type=float, default=0.5, help="safety factor of the common time step")
    p.add_argument("--yade", default=shutil.which("yade") or "yade")
    p.add_argument("--timeout", type=float, default=1800)
    p.add_argument("--out", default="results/dem_speed")
    a = p.parse_args(argv)
    os.makedirs(a.out, exist_ok=True)
    if not shutil.which(a.yade):
        raise SystemExit(f"YADE executable {a.yade!r} not found: apt-get install yade")
    rows = []
    path = os.path.join(a.out, "dem_speed.json")
    for n in a.sizes:
        nsteps = max(400, int(a.steps * 400 / n))
        ks = a.ks_ratio * a.kn
        # time step: demcell's stable estimate for this packing and law (prep_bench's O.dt is
        # above the stability limit once ks = 0.8 kn is constant), imposed on both codes
        if not os.path.exists(os.path.join(a.out, f"pack_{n}.json")):
            yade_side(a.yade, n, a.out, 1, a.kn, ks, a.tol, 1, a.timeout)   # export only
        st, _ = demcell_state(os.path.join(a.out, f"pack_{n}.json"))
        dt = stable_time_step(st.radius, st.mass, st.inertia, ContactLaw(kn=a.kn, ks=ks), a.dt_safety)
        rounds = []
        for _ in range(a.rounds):      # YADE and demcell alternate: load changes hit both
            y, export = yade_side(a.yade, n, a.out, nsteps, a.kn, ks, a.tol, a.max_solve, a.timeout, dt)
            d = demcell_side(export, nsteps, a.kn, ks, a.tol, a.max_solve, a.repeat)
            rounds.append(dict(yade=y, demcell=d,
                               ratio_cu_cpu=d["contact_updates_per_cpu_s"] / y["contact_updates_per_cpu_s"],
                               ratio_cu_wall=d["contact_updates_per_s"] / y["contact_updates_per_s"],
                               ratio_solve_cpu=y["solve_cpu"] / max(d["solve_cpu"], 1e-9),
                               stress_rel_diff=float(np.abs(np.array(d["solve_stress"]) - np.array(y["solve_stress"])).max()
                                                     / np.abs(np.array(y["solve_stress"])).max()),
                               load1=float(open("/proc/loadavg").read().split()[0])))
        med = lambda key: float(np.median([r[key] for r in rounds]))  # noqa: E731
        row = dict(requested=n, n=d["n"], dt=dt, steps=nsteps, rounds=rounds,
                   median_ratio_contact_updates_cpu=med("ratio_cu_cpu"),
                   median_ratio_contact_updates_wall=med("ratio_cu_wall"),
                   median_ratio_solve_cpu=med("ratio_solve_cpu"),
                   range_ratio_contact_updates_cpu=[min(r["ratio_cu_cpu"] for r in rounds),
                                                    max(r["ratio_cu_cpu"] for r in rounds)],
                   memory_per_cell_bytes=d["memory_per_cell_bytes"])
        rows.append(row)
        with open(path, "w") as f:         # written as the run goes
            json.dump(rows, f, indent=2)
        print(f"N={d['n']:5d} dt={dt:.3e} contacts/step demcell {d['contacts_per_step']:.0f} yade "
              f"{y['contacts_per_step']:.0f} | contact updates/cpu-s demcell "
              + "/".join(f"{r['demcell']['contact_updates_per_cpu_s']:.2e}" for r in rounds)
              + " yade " + "/".join(f"{r['yade']['contact_updates_per_cpu_s']:.2e}" for r in rounds)
              + f" | ratio median {row['median_ratio_contact_updates_cpu']:.2f} range "
              f"{row['range_ratio_contact_updates_cpu'][0]:.2f}-{row['range_ratio_contact_updates_cpu'][1]:.2f}"
              f" (wall {row['median_ratio_contact_updates_wall']:.2f}) | solve: demcell {d['solve_steps']} steps "
              f"{d['solve_cpu']:.3f} cpu-s, yade {y['solve_steps']} steps {y['solve_cpu']:.3f} cpu-s, ratio median "
              f"{row['median_ratio_solve_cpu']:.1f} | stress after the solve: demcell "
              f"{np.array(d['solve_stress']).round(1).tolist()} yade {np.array(y['solve_stress']).round(1).tolist()} "
              f"(max rel. diff {rounds[-1]['stress_rel_diff']:.2e}) | memory/cell {d['memory_per_cell_bytes'] / 1024:.0f} KiB "
              f"({d['memory_per_cell_bytes_per_particle']:.0f} B/particle)", flush=True)
    print(f"results: {path}")


if __name__ == "__main__":
    main()
