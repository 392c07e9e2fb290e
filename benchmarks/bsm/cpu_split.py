"""Where the CPU time of demos/footing_bsm.py's loop goes (the CPU counterpart of the wall
split in summary.json, docs/results/bsm.md "Cost"): the demo is run in this process with
process-time counters around the DEM engine's calls (Specimen.advance, Specimen.forces_now:
the m contact passes and leapfrogs of a coarse step), the rest of BridgingCoupler.step
(predictor, corrector, interface, projection, Python) and the rest of the loop (records,
outputs, summary.json, signals); the DEM's CPU time per grain and sub-step is printed beside
that of the full DEM when --full is given (run_footing on the whole domain, threads 1).

    OMP_NUM_THREADS=1 NUMBA_NUM_THREADS=1 PYTHONPATH=. python3 benchmarks/bsm/cpu_split.py --packing A [--full]

The counters cost a few microseconds a call (3 calls a coarse step): the loop's CPU time is
that much above an uncounted run.
"""
import argparse
import os
import runpy
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def counted(cls, name, totals):
    """Wrap cls.name so that its process time is added to totals[name]."""
    original = getattr(cls, name)

    def wrapper(*args, **kwargs):
        c0 = time.process_time()
        try:
            return original(*args, **kwargs)
        finally:
            totals[name] += time.process_time() - c0
    setattr(cls, name, wrapper)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--packing", choices=("A", "B", "C"), default="A")
    parser.add_argument("--domain-width", default="18")
    parser.add_argument("--full", action="store_true", help="also the full DEM's CPU time per grain and step")
    parser.add_argument("--out", default="results/bsm_cpu_split")
    args = parser.parse_args()
    sys.path.insert(0, ROOT)
    from demcell.specimen.engine import Specimen
    from cosserat_fenicsx.bridging.coupler import BridgingCoupler
    totals = {"advance": 0.0, "forces_now": 0.0, "step": 0.0}
    counted(Specimen, "advance", totals)
    counted(Specimen, "forces_now", totals)
    counted(BridgingCoupler, "step", totals)
    sys.argv = [os.path.join(ROOT, "demos", "footing_bsm.py"), "--packing", args.packing,
                "--domain-width", args.domain_width, "--out", args.out]
    run = runpy.run_path(sys.argv[0], run_name="__main__")
    summary, engine = run["summary"], run["engine"]
    steps_done = totals["step"] > 0.0
    dem = totals["advance"] + totals["forces_now"]
    loop = summary["cpu_s"]
    n, fine_steps = engine.state.n_discs, engine.state.step
    per_grain = 1e6 * dem / (n * fine_steps)
    print(f"packing {args.packing}, domain {args.domain_width} m: {n} grains, {fine_steps} DEM steps, "
          f"{summary['coarse_steps']} coarse steps, {engine.rebuilds} neighbour builds")
    print(f"loop CPU {loop:.3f} s: DEM {dem:.3f} s ({100 * dem / loop:.0f} %), rest of the coupled step "
          f"{totals['step'] - dem:.3f} s, rest of the loop {loop - totals['step']:.3f} s"
          if steps_done else f"loop CPU {loop:.3f} s")
    print(f"DEM per grain and step: {per_grain:.4f} us CPU")
    if args.full:
        from demcell.specimen.footing import run_footing
        full = run_footing(args.packing, width=float(args.domain_width), depth=0.06, speed=1.0, mass_damping=10.0,
                           record_every=10, threads=1)
        spec = full.specimen
        full_per_grain = 1e6 * spec.cpu_seconds / (spec.state.n_discs * spec.state.step)
        print(f"full DEM: {spec.state.n_discs} grains, {spec.state.step} steps, {spec.rebuilds} neighbour builds, "
              f"engine CPU {spec.cpu_seconds:.3f} s, per grain and step {full_per_grain:.4f} us; "
              f"the BSM's DEM at that rate: {1e-6 * full_per_grain * n * fine_steps:.3f} s")
    print(f"load average {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
