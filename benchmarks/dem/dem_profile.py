#!/usr/bin/python3
"""Profile of the demcell DEM step: where the time of a step goes.

For each size (default 228, 400, 4000 discs) a packing is made with demcell's own generator
(``generate_packing``, p0 = 10 N/m, kn = 1e4 N/m: p0/kn = 1e-3, cached as
``--out/packing_N.npz``), relaxed under friction 0.4 (the isotropic stage of demos/dem_cell.py),
then timed for a fixed number of steps under a small imposed deformation (a ramp of
e22 = -e11 = 2e-3 in total over the timed steps, local damping 0.7, no convergence test), as
in benchmarks/dem/dem_speed.py (which applies 1e-5 per step). Reported: contact updates per CPU second = steps x touching contacts
per step / CPU s. The breakdown is measured, not guessed, by timing the kernels one at a time
on the same state (Numba wrappers loop inside compiled code, so no Python per call):

* force loop: ``compute_forces`` called K times on the current state (all pairs of the
  Verlet list, contact law, force scatter, stress sum);
* periodic images + gathers: a loop over the listed pairs computing only the minimum-image
  branch vector (``branch_vector``), and the same without the rounding (floor) to the
  nearest image: the difference is the cost of the periodic images;
* neighbour list: ``relaxation.rebuild_neighbours`` (``build_pairs``, ``merge_history`` and the
  copy back) called K times; with the number of
  rebuilds counted in the timed run this gives the rebuild share;
* integration: ``relaxation.leapfrog``, the integration of ``advance``, run K times at fixed forces;
* other: the rest (full step - the above; cell update, loop control, and whatever the kernels
  cost more inside the full step than alone on a fixed state: the forces change from step
  to step there, so the branches of the contact law are predicted less well);
* variant: the same run with a zero skin, which forces a rebuild on (almost) every step.

``--ab DIR`` additionally times, in the same process and alternating, the demcell package
copy in DIR (e.g. a pristine copy /tmp/demcell_orig) against the one of this checkout on the
same states, and checks that both give bit-identical positions, rotations, contact forces and
stress after the timed steps; ``--identity`` adds the deterministic runs of ``identity_runs``
(packing generation, isotropic stage, strain increments, bonds, frozen contacts, dynamics,
tangent) through both packages, compared array by array with np.array_equal.

    /usr/bin/python3 benchmarks/dem/dem_profile.py --out out/dem_profile [--ab /tmp/demcell_orig --identity]

Writes --out/summary.json (figures, CPU and wall seconds, load average) and prints a table.
"""
import argparse
import importlib.util
import inspect
import json
import math
import os
import sys
import time

import numpy as np
from numba import njit

import demcell as dc
from demcell.periodic_cell import branch_vector
from demcell.relaxation import compute_forces, leapfrog, rebuild_neighbours, run
from demcell.slots import N_OUT, NO_CHECK

KN, PRESSURE, FRICTION, DAMPING = 1.0e4, 10.0, 0.4, 0.7
STRAIN = 2.0e-3      # total imposed e22 = -e11 over the timed steps (small: the state stays comparable)


def load_avg():
    return [float(x) for x in open("/proc/loadavg").read().split()[:3]]


def prepared_state(n, out):
    """Packing of n discs (generator of demcell, cached), then the isotropic stage with friction."""
    path = os.path.join(out, f"packing_{n}.npz")
    law = dc.ContactLaw(kn=KN, ks=2e3, friction=FRICTION)
    if os.path.exists(path):
        state, _ = dc.load_packing(path)
    else:
        t0 = time.perf_counter()
        state, info = dc.generate_packing(n, pressure=PRESSURE, law=law, seed=0)
        cell = dc.DemCell(state, law, dc.RelaxationOptions(tol=1e-3, damping=0.7))
        dc.isotropic_stage(cell, PRESSURE)
        state = cell.state
        dc.save_packing(path, state, info)
        print(f"  packing {n}: {time.perf_counter() - t0:.1f} s", flush=True)
    dt = dc.DemCell(state.copy(), law).dt
    return state, law, dt


def deform(state, strain):
    return state.F @ np.diag([math.exp(-strain), math.exp(strain)])


def dynamics(run_fn, st, la, dt, F1, n_ramp, nsteps, skin):
    """nsteps steps without convergence test of run_fn, relaxation.run of this checkout (a
    RelaxationOptions) or of one from before run took the options (loose arguments)."""
    if "options" not in inspect.signature(run_fn).parameters:
        return run_fn(st, la, dt, F1, n_ramp, nsteps, criterion=NO_CHECK, damping=DAMPING, skin=skin)
    options = dc.RelaxationOptions(damping=DAMPING, skin_ratio=skin / float(st.radius.min()))
    return run_fn(st, la, dt, F1, n_ramp, nsteps, options, check=False)


def timed_run(run_fn, st, la, dt, nsteps, skin):
    """nsteps steps of the deformation ramp on st (modified); returns cpu, wall, rebuilds,
    mean touching contacts (counted before and after)."""
    c_before = int(np.count_nonzero(st.touching[:st.n_pairs]))
    F1 = deform(st, STRAIN)
    c0, t0 = time.process_time(), time.perf_counter()
    rep = dynamics(run_fn, st, la, dt, F1, nsteps, nsteps, skin)
    cpu, wall = time.process_time() - c0, time.perf_counter() - t0
    c_after = int(np.count_nonzero(st.touching[:st.n_pairs]))
    return cpu, wall, rep.rebuilds, 0.5 * (c_before + c_after)


# not cached: they call demcell's kernels, and a cached caller keeps the callee it was compiled
# with (demcell/numba_cache.py): the profile must time this checkout's demcell
@njit
def _forces_k(k, radius, mass, s, dtheta, force, moment, h, pair_i, pair_j, fn, fs, mr, bonded,
              touching, d_prev, n_pairs, law, dt, out):
    for _ in range(k):
        compute_forces(radius, mass, s, dtheta, force, moment, h, pair_i, pair_j, fn, fs, mr,
                       bonded, touching, d_prev, n_pairs, law, dt, out)


@njit
def _images_k(k, h, s, pair_i, pair_j, n_pairs, rounding):
    acc = 0.0
    for _ in range(k):
        for p in range(n_pairs):
            i = pair_i[p]
            j = pair_j[p]
            if rounding:
                dx, dy = branch_vector(h, s, i, j)
            else:
                a = s[j, 0] - s[i, 0]
                b = s[j, 1] - s[i, 1]
                dx = h[0, 0] * a + h[0, 1] * b
                dy = h[1, 0] * a + h[1, 1] * b
            acc += dx * dx + dy * dy
    return acc


@njit
def _rebuild_k(k, h, s, radius, skin, s_build, h_build, pair_i, pair_j, fn, fs, mr, bonded, touching, d_prev,
               n_pairs):
    lost = 0
    for _ in range(k):
        n_pairs, bonds_lost = rebuild_neighbours(h, s, radius, skin, s_build, h_build, pair_i, pair_j, fn, fs, mr,
                                                 bonded, touching, d_prev, n_pairs)
        lost += bonds_lost
    return lost


@njit
def _integrate_k(k, mass, inertia, force, moment, v, s, omega, dtheta, theta, h, dt, damp):
    """``relaxation.leapfrog`` (the integration of ``advance``) run k times at fixed forces:
    the cost of the integration alone."""
    det = h[0, 0] * h[1, 1] - h[0, 1] * h[1, 0]
    hinv00, hinv01, hinv10, hinv11 = h[1, 1] / det, -h[0, 1] / det, -h[1, 0] / det, h[0, 0] / det
    inv_m = 1.0 / mass
    inv_i = 1.0 / inertia
    vmax2 = 0.0
    for _ in range(k):
        vmax2 = leapfrog(force, moment, v, s, omega, dtheta, theta, inv_m, inv_i, hinv00, hinv01, hinv10, hinv11,
                         dt, damp, True, 0.0)
    return vmax2


def cpu_of(fn, *args):
    c0 = time.process_time()
    fn(*args)
    return time.process_time() - c0


def breakdown(state, law, dt, nsteps, skin):
    la = law.as_array()
    st = state.copy()
    dynamics(run, st, la, dt, st.F, 0, 50, skin)   # JIT, first list
    base = st.copy()
    cpu, wall, rebuilds, contacts = timed_run(run, st, la, dt, nsteps, skin)
    # forced rebuilds: zero skin (rebuild test fires on every step with motion)
    st0 = base.copy()
    cpu_r, _, rebuilds_r, _ = timed_run(run, st0, la, dt, nsteps, 0.0)
    # kernels alone on the state after the run
    k = nsteps
    out = np.zeros(N_OUT)
    w = st.copy()
    args = (w.radius, w.mass, w.s, w.dtheta, w.force, w.moment, w.h, w.pair_i, w.pair_j, w.fn, w.fs,
            w.mr, w.bonded, w.touching, w.d_prev, w.n_pairs, la, dt, out)
    _forces_k(1, *args)
    t_force = cpu_of(_forces_k, k, *args) / k
    _images_k(1, st.h, st.s, st.pair_i, st.pair_j, st.n_pairs, True)
    t_img = cpu_of(_images_k, k, st.h, st.s, st.pair_i, st.pair_j, st.n_pairs, True) / k
    t_noimg = cpu_of(_images_k, k, st.h, st.s, st.pair_i, st.pair_j, st.n_pairs, False) / k
    w = st.copy()
    iargs = (w.mass, w.inertia, w.force * 1e-3, w.moment * 1e-3, w.v, w.s, w.omega, w.dtheta, w.theta, w.h,
             dt, DAMPING)
    _integrate_k(1, *iargs)
    t_integ = cpu_of(_integrate_k, k, *iargs) / k
    kr = max(20, nsteps // 20)
    w = st.copy()
    rargs = (w.h, w.s, w.radius, skin, w.s_build, w.h_build, w.pair_i, w.pair_j, w.fn, w.fs, w.mr,
             w.bonded, w.touching, w.d_prev, w.n_pairs)
    _rebuild_k(1, *rargs)
    t_rebuild = cpu_of(_rebuild_k, kr, *rargs) / kr
    step = cpu / nsteps
    rebuild_share = rebuilds * t_rebuild / cpu
    force_share = t_force / step
    return dict(n=int(st.n_particles), steps=nsteps, cpu=cpu, wall=wall, contacts_per_step=contacts,
                listed_pairs=int(st.n_pairs), rebuilds=int(rebuilds), steps_per_rebuild=nsteps / max(rebuilds, 1),
                contact_updates_per_cpu_s=nsteps * contacts / cpu, step_us=1e6 * step,
                force_us=1e6 * t_force, force_share=force_share,
                images_gather_us=1e6 * t_img, images_rounding_us=1e6 * (t_img - t_noimg),
                rebuild_us=1e6 * t_rebuild, rebuild_share=rebuild_share,
                integration_us=1e6 * t_integ, integration_share=t_integ / step,
                other_share=1.0 - force_share - rebuild_share - t_integ / step,
                forced_rebuild_cpu=cpu_r, forced_rebuilds=int(rebuilds_r),
                forced_rebuild_slowdown=cpu_r / cpu)


def load_package(path, name="demcell_ab"):
    spec = importlib.util.spec_from_file_location(name, os.path.join(path, "__init__.py"),
                                                  submodule_search_locations=[path])
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod


def ab(state, law, dt, nsteps, skin, other, rounds):
    """Alternate the package in `other` (A) and this checkout's (B) on the same start state."""
    la = law.as_array()
    run_a = sys.modules[other.__name__ + ".relaxation"].run
    st = state.copy()
    dynamics(run, st, la, dt, st.F, 0, 50, skin)
    start = st.copy()
    sa = start.copy()
    dynamics(run_a, sa, la, dt, sa.F, 0, 2, skin)   # JIT of A
    res = {"A": [], "B": []}
    finals = {}
    for _ in range(rounds):
        for tag, fn in (("A", run_a), ("B", run)):
            w = start.copy()
            cpu, wall, _, contacts = timed_run(fn, w, la, dt, nsteps, skin)
            res[tag].append(cpu)
            finals[tag] = w
    a, b = finals["A"], finals["B"]
    same = a.n_pairs == b.n_pairs and all(np.array_equal(getattr(a, f), getattr(b, f)) for f in
                                          ("s", "theta", "v", "omega", "force", "moment", "h"))
    m = a.n_pairs      # pair slots beyond n_pairs are scratch (uninitialised after a rebuild)
    same = same and all(np.array_equal(getattr(a, f)[:m], getattr(b, f)[:m]) for f in
                        ("pair_i", "pair_j", "fn", "fs", "mr", "bonded", "touching", "d_prev"))
    same = same and np.array_equal(dc.homogenize(a, la).cauchy, dc.homogenize(b, la).cauchy)
    ma, mb = float(np.median(res["A"])), float(np.median(res["B"]))
    return dict(cpu_A=res["A"], cpu_B=res["B"], median_cpu_A=ma, median_cpu_B=mb, speedup=ma / mb,
                speedup_min=min(res["A"]) / min(res["B"]),
                contact_updates_per_cpu_s_A=nsteps * contacts / ma,
                contact_updates_per_cpu_s_B=nsteps * contacts / mb, bit_identical=bool(same))


def identity_runs(pkg):
    """Deterministic runs through the public API of the demcell package ``pkg`` (a packing
    generation, the isotropic stage and 5 servo-controlled axial increments of 2e-3 as in
    demos/dem_cell.py, for 228 and 400 discs and for a law with rolling resistance and
    dashpots; from the first: bonded contacts under shear, frozen contacts, 300 steps of
    undamped dynamics, the Kruyt tangent). Returns a dict of final arrays."""
    res = {}
    cases = [("plain", dict(friction=0.4), 228, 0), ("plain400", dict(friction=0.4), 400, 1),
             ("rolling_visc", dict(friction=0.5, rolling_stiffness=1.0, rolling_friction=0.1,
                                   normal_damping=0.05, tangential_damping=0.05), 228, 2)]
    pair_fields = ("pair_i", "pair_j", "fn", "fs", "mr", "bonded", "touching", "d_prev")

    def grab(tag, st, fields):
        for f in fields:      # pair slots beyond n_pairs are scratch
            res[f"{tag}_{f}"] = getattr(st, f)[:st.n_pairs] if f in pair_fields else getattr(st, f).copy()

    for name, kw, n, seed in cases:
        law = pkg.ContactLaw(kn=KN, ks=2e3, **kw)
        state, _ = pkg.generate_packing(n, pressure=PRESSURE, law=pkg.ContactLaw(kn=KN, ks=2e3), seed=seed)
        cell = pkg.DemCell(state, law, pkg.RelaxationOptions(tol=1e-3, damping=0.7))
        pkg.isotropic_stage(cell, PRESSURE)
        F_iso = cell.deformation_gradient()
        mask = np.zeros((2, 2), bool)
        mask[1, 1] = True
        target = np.zeros((2, 2))
        target[1, 1] = -PRESSURE
        steps = []
        for k in range(1, 6):
            F = cell.deformation_gradient()
            F[0, 0] = F_iso[0, 0] * (1 - k * 2e-3)
            cell.set_deformation(F)
            steps.append(cell.solve(stress_mask=mask, stress_target=target).steps)
            cell.commit()
        if name == "plain":
            c2 = cell.copy()
            c2.bond_contacts()
            c2.set_law(law.with_(cohesion_normal=0.5, cohesion_shear=0.5))
            F = c2.deformation_gradient()
            F[0, 1] += 1e-3
            c2.set_deformation(F)
            c2.solve()
            grab(f"{name}_bond", c2.state, ("s", "theta", "fn", "fs", "bonded", "touching"))
            c4 = cell.copy()
            c4.freeze_contacts()
            F = c4.deformation_gradient()
            F[1, 1] -= 1e-3
            c4.set_deformation(F)
            c4.solve()
            grab(f"{name}_frozen", c4.state, ("s", "theta", "fn", "fs", "force", "moment"))
            res[f"{name}_frozen_cauchy"] = c4.cauchy_stress()
            c3 = cell.copy()
            c3.run_dynamics(300, damping=0.0)
            res[f"{name}_dyn_s"] = c3.state.s.copy()
            res[f"{name}_tangent"] = cell.tangent("kruyt")
        grab(name, cell.state, ("s", "v", "theta", "omega", "force", "moment", "h") + pair_fields)
        res[f"{name}_cauchy"] = cell.cauchy_stress()
        res[f"{name}_couple"] = np.asarray(cell.couple_stress())
        res[f"{name}_steps"] = np.array(steps)
    return res


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sizes", type=int, nargs="+", default=[228, 400, 4000])
    p.add_argument("--steps", type=int, default=20000, help="timed steps at 400 discs (scaled ~1/N)")
    p.add_argument("--ab", default=None, help="directory of another demcell package to compare with")
    p.add_argument("--rounds", type=int, default=3, help="alternating A/B rounds (median)")
    p.add_argument("--identity", action="store_true",
                   help="with --ab: also compare the final arrays of identity_runs() bit for bit")
    p.add_argument("--out", default="out/dem_profile")
    a = p.parse_args(argv)
    os.makedirs(a.out, exist_ok=True)
    other = load_package(os.path.abspath(a.ab)) if a.ab else None
    identity = None
    if a.identity:
        if other is None:
            raise SystemExit("--identity needs --ab DIR (the package to compare with)")
        ra, rb = identity_runs(other), identity_runs(dc)
        bad = sorted(k for k in ra if not np.array_equal(ra[k], rb[k]))
        identity = dict(arrays=len(ra), differing=bad, bit_identical=not bad and sorted(ra) == sorted(rb))
        print(f"identity runs: {len(ra)} arrays compared, "
              + ("all bit-identical" if identity["bit_identical"] else f"DIFFERENT: {bad}"), flush=True)
    c_start, w_start, load_start = time.process_time(), time.perf_counter(), load_avg()
    rows = []
    for n in a.sizes:
        state, law, dt = prepared_state(n, a.out)
        skin = 0.1 * float(state.radius.min())          # demcell's default (skin_ratio 0.1)
        nsteps = max(400, int(a.steps * 400 / n))
        row = breakdown(state, law, dt, nsteps, skin)
        row["load_avg"] = load_avg()
        if other is not None:
            row["ab"] = ab(state, law, dt, nsteps, skin, other, a.rounds)
        rows.append(row)
    summary = dict(command=" ".join(sys.argv), rows=rows, identity=identity, cpu_s=time.process_time() - c_start,
                   wall_s=time.perf_counter() - w_start, load_avg_start=load_start, load_avg_end=load_avg())
    with open(os.path.join(a.out, "summary.json"), "w") as f:
        json.dump(summary, f, indent=2)
    print(f"{'N':>5} {'steps':>6} {'contacts':>8} {'pairs':>6} {'cu/cpu-s':>9} {'step us':>8} {'force us':>8} "
          f"{'force%':>6} {'img us':>7} {'round us':>8} {'rebuilds':>8} {'build us':>8} {'build%':>6} "
          f"{'integ%':>6} {'other%':>6} {'skin0 x':>7}")
    for r in rows:
        print(f"{r['n']:5d} {r['steps']:6d} {r['contacts_per_step']:8.0f} {r['listed_pairs']:6d} "
              f"{r['contact_updates_per_cpu_s']:9.2e} {r['step_us']:8.1f} {r['force_us']:8.1f} "
              f"{100 * r['force_share']:6.1f} {r['images_gather_us']:7.1f} {r['images_rounding_us']:8.1f} "
              f"{r['rebuilds']:8d} {r['rebuild_us']:8.1f} {100 * r['rebuild_share']:6.1f} "
              f"{100 * r['integration_share']:6.1f} {100 * r['other_share']:6.1f} {r['forced_rebuild_slowdown']:7.2f}")
        if "ab" in r:
            x = r["ab"]
            print(f"      A/B: cpu A {x['median_cpu_A']:.3f} s, B {x['median_cpu_B']:.3f} s, speed-up "
                  f"{x['speedup']:.3f} (of the minima {x['speedup_min']:.3f}), cu/cpu-s A {x['contact_updates_per_cpu_s_A']:.2e} "
                  f"B {x['contact_updates_per_cpu_s_B']:.2e}, bit-identical {x['bit_identical']}")
    print(f"cpu {summary['cpu_s']:.1f} s, wall {summary['wall_s']:.1f} s, load avg start {load_start} "
          f"end {summary['load_avg_end']}; {os.path.join(a.out, 'summary.json')}")


if __name__ == "__main__":
    main()
