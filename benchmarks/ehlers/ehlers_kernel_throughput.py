#!/usr/bin/env python3
"""Throughput of the Ehlers Gauss-point kernel: updates per second per core.

Measures EhlersMaterial.update (the FE callback: one compiled batch kernel over all points,
serial) after a warm-up call, for

  elastic    unloading increments from a consolidated state (elastic predictor only)
  onset      first deviatoric increment after consolidation (flow direction changes)
  hardening  steady biaxial loading increments, contractant hardening
  softening  steady loading increments past the peak (dilatant softening)

(all plastic regimes: local Newton of Table 3.1 + consistent tangent, plane strain,
micropolar terms active).  Figures are wall time on a possibly shared machine; the
best of --repeat runs is the least disturbed one.

and checks the Numba cache: the first call in two fresh processes is timed, and the
dispatcher statistics must show cache hits and no cache misses (no recompilation).

    python3 benchmarks/ehlers/ehlers_kernel_throughput.py [--points 20000] [--repeat 5] [--baseline REV]

--baseline REV also times the kernel of git revision REV (extracted to a temporary directory)
on the same inputs, alternating old and new runs, and prints the CPU-time ratio new/old per
regime (best of --repeat each) and the largest relative difference of flux, tangent and state.
On a shared machine this ratio is more reliable than absolute figures.
"""
import argparse
import json
import os
import importlib
import importlib.util
import shutil
import subprocess
import sys
import tempfile
import time

import numpy as np

from benchmarks import ROOT

FRESH = r"""
import time, numpy as np
t0 = time.perf_counter()
from cosserat_fenicsx.materials.ehlers import EhlersMaterial
from cosserat_fenicsx.materials.ehlers.local_solver import update_batch
t1 = time.perf_counter()
m = EhlersMaterial.hostun()
st = m.initial_state(4)
g = np.zeros((4, 6)); g[:, :2] = -1e-4
f, t, s = np.zeros((4, 6)), np.zeros((4, 6, 6)), np.zeros_like(st)
m.update(g, 1.0, st, f, t, s)
t2 = time.perf_counter()
st = update_batch.stats
print(t1 - t0, t2 - t1, sum(st.cache_hits.values()), sum(st.cache_misses.values()))
"""


def states(material, kind, n, rng, increment=2e-4):
    """Committed states and trial gradients (FE layout, plane strain) for n points.

    elastic:   consolidated to 100 kPa, axial unloading increment
    onset:     consolidated, first deviatoric increment (change of flow direction)
    hardening: after 20 biaxial steps of the same increment (steady contractant hardening)
    softening: past the peak (eps11 = -8 %), steady increments (dilatant softening)
    Trial increments get a +-50 % jitter, a skew strain and a curvature so that the
    micropolar terms are active.
    """
    from cosserat_fenicsx.materials.ehlers.material_point import MaterialPoint, consolidate
    pt = MaterialPoint(material)
    consolidate(pt, -100e3, n_steps=10, plane_strain=True)
    mask = np.array([False, True, False, False, False, False, False])
    e0 = pt.strain[0]
    target = {"elastic": 0.0, "onset": 0.0, "hardening": 20 * increment, "softening": 0.08}[kind]
    nsteps = int(round(target / increment))
    prev = pt.strain.copy()
    for k in range(1, nsteps + 1):
        prev = pt.strain.copy()
        tgt = np.zeros(7)
        tgt[0] = e0 - increment * k
        tgt[1] = -100e3
        pt.advance(mask, tgt)
    st = np.repeat(pt.state, n, axis=0)
    base = pt.strain[[0, 1, 3, 4, 5, 6]]
    d = pt.strain - prev  # last increment of the path
    g = np.repeat(base[None, :], n, axis=0)
    jitter = rng.uniform(0.5, 1.5, size=n)
    if kind == "elastic":
        g[:, 0] += 0.1 * increment * jitter  # axial unloading: inside the yield surface
        g[:, 1] += 0.05 * increment * jitter
    else:
        if not nsteps:
            d[0], d[1] = -increment, 0.3 * increment
        g[:, 0] += d[0] * jitter  # repeat the path's last increment (steady loading)
        g[:, 1] += d[1] * jitter
        g[:, 2] += 0.05 * increment * jitter
        g[:, 3] -= 0.02 * increment * jitter
        g[:, 4] += 0.05 * jitter  # curvature [1/m]
    return g, st


def measure(material, g, st, repeat):
    """Best and median wall-clock throughput, and the CPU-time throughput (process_time: the
    kernel is single-threaded, so this is the rate per core even when the machine is shared)."""
    n = g.shape[0]
    f, t, s = np.zeros((n, 6)), np.zeros((n, 6, 6)), np.zeros_like(st)
    material.update(g, 1.0, st, f, t, s)  # warm-up
    wall, cpu = [], []
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        material.update(g, 1.0, st, f, t, s)
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    plastic = float(np.mean(s[:, 11] > 0))
    iters = float(np.mean(s[:, 23]))
    return n / min(wall), n / np.median(wall), n / min(cpu), plastic, iters


def load_baseline(rev):
    """update_batch of the Ehlers kernel at git revision rev, as a separate top-level package."""
    tmp = tempfile.mkdtemp(prefix="ehlers_baseline_")
    arch = subprocess.run(["git", "-C", ROOT, "archive", rev, "cosserat_fenicsx/materials/ehlers"],
                          capture_output=True, check=True).stdout
    subprocess.run(["tar", "-x", "-C", tmp], input=arch, check=True)
    pkg = os.path.join(tmp, "ehlers_baseline")
    shutil.move(os.path.join(tmp, "cosserat_fenicsx", "materials", "ehlers"), pkg)
    for name in ("__init__.py", "material.py", "material_point.py"):
        os.remove(os.path.join(pkg, name))
    open(os.path.join(pkg, "__init__.py"), "w").close()
    err = os.path.join(pkg, "errors.py")
    src = open(err).read().replace("from ...constitutive import ConstitutiveError",
                                   "class ConstitutiveError(RuntimeError):\n    pass")
    open(err, "w").write(src)
    # imported from its folder as the package ehlers_baseline, beside the current kernel
    spec = importlib.util.spec_from_file_location("ehlers_baseline", os.path.join(pkg, "__init__.py"),
                                                  submodule_search_locations=[pkg])
    sys.modules["ehlers_baseline"] = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(sys.modules["ehlers_baseline"])
    return importlib.import_module("ehlers_baseline.local_solver").update_batch


def compare(old_kernel, params, g, st, repeat):
    """CPU-time throughput of the baseline and the current kernel, runs alternated; max rel. diff."""
    from cosserat_fenicsx.materials.ehlers.local_solver import update_batch
    n = g.shape[0]
    out = {}
    for lab, fn in (("old", old_kernel), ("new", update_batch)):
        f, t, s, c = np.zeros((n, 6)), np.zeros((n, 6, 6)), np.zeros_like(st), np.zeros(n, np.int32)
        fn(g, 1.0, st, params, f, t, s, c)  # warm-up
        out[lab] = (fn, f, t, s, c)
    best = {"old": np.inf, "new": np.inf}
    for r in range(repeat):
        for lab in (("old", "new") if r % 2 == 0 else ("new", "old")):
            fn, f, t, s, c = out[lab]
            c0 = time.process_time()
            fn(g, 1.0, st, params, f, t, s, c)
            best[lab] = min(best[lab], time.process_time() - c0)
    diff = 0.0
    for a, b in zip(out["old"][1:4], out["new"][1:4]):
        a, b = a.reshape(n, -1), b.reshape(n, -1)
        sc = np.maximum(np.maximum(np.abs(a).max(1), np.abs(b).max(1)), 1e-300)
        diff = max(diff, float((np.abs(a - b).max(1) / sc).max()))
    same = bool(np.array_equal(out["old"][4], out["new"][4]))
    return n / best["old"], n / best["new"], diff, same


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--points", type=int, default=20000)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--json", default=None, help="also write the figures to this JSON file")
    ap.add_argument("--baseline", default=None, help="git revision whose kernel is timed alongside")
    args = ap.parse_args(argv)
    old_kernel = load_baseline(args.baseline) if args.baseline else None
    from cosserat_fenicsx.materials.ehlers import EhlersMaterial
    mat = EhlersMaterial.hostun()
    rng = np.random.default_rng(0)
    rows = {}
    print(f"Ehlers kernel throughput, {args.points} points, 1 thread (best / median of {args.repeat})")
    print(f"{'regime':10s} {'wall best':>12s} {'wall median':>12s} {'CPU-time':>12s} {'plastic':>8s} {'local it':>9s}")
    print(f"{'':10s} {'[upd/s]':>12s} {'[upd/s]':>12s} {'[upd/s/core]':>12s}")
    for kind in ("elastic", "onset", "hardening", "softening"):
        g, st = states(mat, kind, args.points, rng)
        best, med, cpu, plastic, iters = measure(mat, g, st, args.repeat)
        rows[kind] = dict(wall_best_updates_per_s=best, wall_median_updates_per_s=med,
                          cpu_updates_per_s=cpu, plastic_fraction=plastic, mean_local_iterations=iters)
        print(f"{kind:10s} {best:12.3e} {med:12.3e} {cpu:12.3e} {plastic:8.2f} {iters:9.2f}")
        if old_kernel is not None:
            cpu_old, cpu_new, diff, same = compare(old_kernel, mat.params_array, g, st, args.repeat)
            rows[kind].update(baseline_cpu_updates_per_s=cpu_old, alternated_cpu_updates_per_s=cpu_new,
                              max_relative_difference=diff, same_status=same)
            print(f"{'':10s} vs {args.baseline}: CPU-time old {cpu_old:.3e}, new {cpu_new:.3e} upd/s/core, "
                  f"new/old {cpu_new / cpu_old:.3f}, max rel. difference {diff:.1e}, same status {same}")
    print(f"load average during the run: {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")
    print("\nfirst call in a fresh process (import / first update; numba cache hits, misses):")
    fresh = []
    for k in range(2):
        out = subprocess.run([sys.executable, "-c", FRESH], capture_output=True, text=True,
                             check=True).stdout.split()
        imp, first, hits, misses = float(out[0]), float(out[1]), int(out[2]), int(out[3])
        fresh.append(dict(import_s=imp, first_update_s=first, cache_hits=hits, cache_misses=misses))
        print(f"  run {k + 1}: import {imp:.2f} s, first update {first:.3f} s, cache hits {hits}, misses {misses}")
    rows["fresh_process"] = fresh
    if fresh[1]["cache_misses"] or not fresh[1]["cache_hits"]:
        print("WARNING: the kernel was recompiled in a fresh process (numba cache not used)")
    if args.json:
        os.makedirs(os.path.dirname(os.path.abspath(args.json)), exist_ok=True)
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=2)
    return rows


if __name__ == "__main__":
    main()
