#!/usr/bin/env python3
"""Homogeneous material-point tests of the micropolar Ehlers model (one Gauss point, no mesh).

Tests of the thesis (Scholz 2007, A.1, A.2, section 6.1.2), Hostun sand by default
(Tables 6.1, 6.4 under reading H1, see docs/reference/ehlers.md):

  hydrostatic  sig11 = sig22 = sig33 = -P, P increased to --confining
  triaxial     isotropic consolidation to -P, then axial strain eps11 decreased at
               sig22 = sig33 = -P  (thesis: P = 100, 300, 600 kN/m^2)
  biaxial      plane strain (eps33 = 0): consolidation sig11 = sig22 = -P, then eps11
               decreased at sig22 = -P (thesis: P = 100 kN/m^2)
  all          the five thesis tests, and a comparison with the reference values of
               the spec (section 4.6, reading H1) in h1_comparison.json
  readings     evidence for the Table 3.1 / Table 6.4 reading: hydrostatic loading in
               5 kPa steps to 1 MN/m^2 under four readings (readings.json)

Writes to --out: history.csv (axial_strain, axial_stress, volumetric_strain, then
further columns, the last the time [s] from the start of the recorded phase; SI, tension
positive; strains counted from the start of the deviatoric phase), summary.json, and material_point.png (axial stress and volumetric
strain against axial strain).  No dolfinx needed.

Example:  python3 demos/material_point.py --test triaxial --confining 300e3 --out out/tri300
"""
import argparse
import csv
import json
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
from cosserat_fenicsx.identification.data import TABLE_6_2  # noqa: E402  (no Numba, no dolfinx)
from cosserat_fenicsx.figures import pyplot  # noqa: E402
from cosserat_fenicsx.run_guard import strict_json  # noqa: E402

#: reference values of the spec, section 4.6 (reading H1; a reconstruction, not thesis data)
SPEC_H1 = {
    "triaxial_100kPa": dict(peak_axial_stress=-0.536e6, axial_strain_at_peak=-0.071, final_volumetric_strain=0.098),
    "triaxial_300kPa": dict(peak_axial_stress=-1.415e6, axial_strain_at_peak=-0.077, final_volumetric_strain=0.067),
    "triaxial_600kPa": dict(peak_axial_stress=-2.488e6, axial_strain_at_peak=-0.102, final_volumetric_strain=0.038),
    "biaxial_100kPa": dict(peak_axial_stress=-0.692e6, axial_strain_at_peak=-0.046, final_axial_stress=-0.523e6),
    "hydrostatic": {"volumetric_strain_at_0.1MPa": -0.0011, "volumetric_strain_at_0.3MPa": -0.0049,
                    "volumetric_strain_at_0.6MPa": -0.0100, "volumetric_strain_at_1.0MPa": -0.0166},
}


def build_parser():
    from cosserat_fenicsx.validation import AXIAL_STRAIN, NON_NEGATIVE, POSITIVE, STEPS, Parser, number
    p = Parser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter, allow_abbrev=False)
    p.add_argument("--test", choices=("hydrostatic", "isotropic_plane_strain", "triaxial", "biaxial", "all", "readings"),
                   default="triaxial")
    p.add_argument("--confining", type=number(POSITIVE), default=100e3,
                   help="confining pressure P > 0 [Pa] (hydrostatic: final pressure) (default %(default)g)")
    p.add_argument("--out", default="out/material_point", help="output directory (default %(default)s)")
    g = p.add_argument_group("material (SI units; Hostun defaults, Tables 6.1/6.4)")
    g.add_argument("--parameters", metavar="FILE", default=None,
                   help="JSON parameter file (e.g. identified_parameters.json of demos/identify.py); material "
                        "options given explicitly on the command line override its values")
    g.add_argument("--mu", type=number(POSITIVE), default=91.0e6, help="shear modulus [Pa] (default %(default)g)")
    g.add_argument("--lmbda", type=number(), default=49.4e6, help="Lame constant lambda [Pa] (default %(default)g)")
    g.add_argument("--mu-c", type=number(NON_NEGATIVE), default=None, help="Cosserat modulus [Pa] (default mu_c = mu)")
    g.add_argument("--l-c", type=number(NON_NEGATIVE), default=3e-3, help="internal length [m] (default %(default)g)")
    g.add_argument("--hardening-rows", choices=("uniform", "table3.1"), default="uniform",
                   help="uniform (2.82), reading H1 (default), or the delta/epsilon signs of Table 3.1")
    n = p.add_argument_group("numerics")
    n.add_argument("--steps", type=number(STEPS), default=600, help="load steps of the deviatoric phase (default %(default)s)")
    n.add_argument("--consolidation-steps", type=number(STEPS), default=40, help="steps of the isotropic phase (default %(default)s)")
    n.add_argument("--axial-strain", type=number(AXIAL_STRAIN), default=0.15,
                   help="axial compression strain, in (0, 0.5) (default %(default)g)")
    n.add_argument("--eta", type=number(NON_NEGATIVE), default=1e-4, help="Perzyna relaxation time [s] (2.81) (default %(default)g)")
    n.add_argument("--dt", type=number(POSITIVE), default=1.0, help="time per load step [s] (default %(default)g)")
    return p


HISTORY_COLUMNS = ["axial_strain", "axial_stress", "volumetric_strain", "sig22", "sig33", "mean_stress",
                   "eps22", "eps33", "eps_p_vol", "beta", "delta", "epsilon", "gamma", "yield_function", "time"]


def run_test(material, test, confining, args, out, guard):
    """One test; history.csv is written row by row as the steps converge (an interrupted
    run keeps them), each row counted by the RunGuard."""
    from cosserat_fenicsx.materials.ehlers import material_point as mp
    with open(os.path.join(out, "history.csv"), "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(HISTORY_COLUMNS)
        # time [s] from the start of the recorded phase: a deviatoric test's first row is that
        # start, an isotropic test's first row the end of its first step
        rows = [0 if test in ("triaxial", "biaxial") else 1]

        def on_record(record):
            with guard.deferred():
                record = dict(record, time=rows[0] * args.dt)
                rows[0] += 1
                writer.writerow([f"{record[c]:.10g}" for c in HISTORY_COLUMNS])
                f.flush()
                guard.progress(final_axial_strain=record["axial_strain"])

        options = dict(dt=args.dt, stop_on_failure=True, on_record=on_record)
        if test == "hydrostatic":
            h = mp.hydrostatic_test(material, confining, n_steps=args.steps, **options)
        elif test == "isotropic_plane_strain":
            h = mp.isotropic_plane_strain_test(material, confining, n_steps=args.steps, **options)
        elif test == "triaxial":
            h = mp.triaxial_test(material, confining, args.axial_strain, args.steps, args.consolidation_steps,
                                 **options)
        else:
            h = mp.biaxial_test(material, confining, args.axial_strain, args.steps, args.consolidation_steps,
                                **options)
    s = mp.summarize(h)
    s.update(test=test, confining_pressure=confining, completed=not h["stopped"], reason=h["stopped"])
    if h["stopped"]:
        print(f"material_point: {test}: {h['stopped']}", file=sys.stderr)
    if test in ("hydrostatic", "isotropic_plane_strain"):
        for p in (0.1e6, 0.3e6, 0.6e6, 1.0e6):
            if -h["mean_stress"].min() >= p * (1 - 1e-9):
                s[f"volumetric_strain_at_{p / 1e6:.1f}MPa"] = float(np.interp(-p, h["mean_stress"][::-1],
                                                                               h["volumetric_strain"][::-1]))
    return h, s


def plot(h, out, title):
    """material_point.png (history.csv is written as the test goes, summary.json by the RunGuard)."""
    plt = pyplot()
    fig, ax = plt.subplots(2, 1, figsize=(6, 7), sharex=True)
    ax[0].plot(h["axial_strain"], h["axial_stress"] / 1e3)
    ax[0].set_ylabel("axial stress sig11 [kPa] (tension +)")
    ax[1].plot(h["axial_strain"], h["volumetric_strain"])
    ax[1].set_ylabel("volumetric strain [-] (dilation +)")
    ax[1].set_xlabel("axial strain eps11 [-] (tension +)")
    ax[0].set_title(title)
    for a in ax:
        a.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(os.path.join(out, "material_point.png"), dpi=120)
    plt.close(fig)


READINGS = {
    "H1: T6.4 delta, epsilon as reciprocals (MN/m^2), uniform (2.82)": dict(),
    "reciprocals, Table 3.1 signs on the delta/epsilon rows": dict(hardening_rows="table3.1"),
    "T6.4 values used directly as thesis delta, epsilon, Table 3.1 signs":
        dict(hardening_rows="table3.1", delta0=0.01e6, delta_star=1.59e6, epsilon0=0.486e6, epsilon_star=0.0115e6),
    "T6.4 values used directly as thesis delta, epsilon, uniform (2.82)":
        dict(delta0=0.01e6, delta_star=1.59e6, epsilon0=0.486e6, epsilon_star=0.0115e6),
}


def run_readings(args):
    """Hydrostatic loading in 5 kPa steps to 1 MN/m^2 under each reading; records how far it gets."""
    from cosserat_fenicsx.materials.ehlers import EhlersMaterial, MaterialPointError
    from cosserat_fenicsx.materials.ehlers.material_point import MaterialPoint, consolidate
    out = {}
    for name, kw in READINGS.items():
        mat = EhlersMaterial.hostun(eta=args.eta, **kw)
        pt = MaterialPoint(mat)
        p_reached, err = 0.0, None
        try:
            for k in range(1, 201):
                consolidate(pt, -5e3 * k, n_steps=1, dt=args.dt)
                p_reached = 5e3 * k
        except MaterialPointError as e:
            err = str(e)
        st = pt.state[0]
        out[name] = dict(max_pressure_Pa=p_reached, volumetric_strain=float(pt.strain[:3].sum()),
                         beta=st[7], delta_Pa=st[8], epsilon_Pa=st[9], failure=err)
        print(f"{name:72s} reached {p_reached / 1e3:7.1f} kPa, eps_V = {pt.strain[:3].sum():+.4f}"
              + (f"  | {err[:60]}" if err else ""))
    os.makedirs(args.out, exist_ok=True)
    with open(os.path.join(args.out, "readings.json"), "w") as f:
        json.dump(strict_json(out), f, indent=2, allow_nan=False)
    return out


def main(argv=None):
    parser = build_parser()
    args = parser.parse_args(argv)
    from cosserat_fenicsx.materials.ehlers.parameters import hostun   # no Numba: the parameters only
    from cosserat_fenicsx.materials.ehlers.parameters import read_parameter_file
    material_options = dict(mu=args.mu, lmbda=args.lmbda, mu_c=args.mu_c, l_c=args.l_c, eta=args.eta,
                            hardening_rows=args.hardening_rows)
    try:
        if args.parameters:
            # the file's values, then the material options given explicitly on the command line
            given = parser.given_options(argv)
            material_options = dict(read_parameter_file(args.parameters), eta=args.eta,
                                    **{k: v for k, v in material_options.items() if k in given})
        hostun(**material_options)
    except ValueError as error:
        parser.refuse(error)
    from cosserat_fenicsx.materials.ehlers import EhlersMaterial
    from cosserat_fenicsx.run_guard import RunGuard
    material = EhlersMaterial.hostun(**material_options)
    t0 = time.perf_counter()
    os.makedirs(args.out, exist_ok=True)
    if args.test == "readings":
        return run_readings(args)
    if args.test != "all":
        guard = RunGuard(None, os.path.join(args.out, "summary.json"), dict(test=args.test), label="material_point")
        h, s = run_test(material, args.test, args.confining, args, args.out, guard)
        s["wall_time_s"] = time.perf_counter() - t0
        plot(h, args.out, f"{args.test}, P = {args.confining / 1e3:g} kPa")
        guard.finish(s)
        print(json.dumps(s, indent=2))
        if not s["completed"]:
            sys.exit(1)
        return s
    table = {}
    completed = True
    for test, p in (("hydrostatic", 1.0e6), ("triaxial", 100e3), ("triaxial", 300e3), ("triaxial", 600e3),
                    ("biaxial", 100e3)):
        key = "hydrostatic" if test == "hydrostatic" else f"{test}_{p / 1e3:.0f}kPa"
        os.makedirs(os.path.join(args.out, key), exist_ok=True)
        guard = RunGuard(None, os.path.join(args.out, key, "summary.json"), dict(test=test), label="material_point")
        h, s = run_test(material, test, p, args, os.path.join(args.out, key), guard)
        plot(h, os.path.join(args.out, key), key)
        guard.finish(s)
        completed &= s["completed"]
        ref = SPEC_H1[key]
        table[key] = {k: dict(model=s[k], spec_H1=v, rel_diff=(s[k] - v) / abs(v)) for k, v in ref.items() if k in s}
        # Table 6.2 normalisation factors (magnitudes of the measured data)
        table[key]["table_6_2"] = TABLE_6_2[(test, None if test == "hydrostatic" else p)]
    table["wall_time_s"] = time.perf_counter() - t0
    with open(os.path.join(args.out, "h1_comparison.json"), "w") as f:
        json.dump(strict_json(table), f, indent=2, allow_nan=False)
    for key, rows in table.items():
        if key == "wall_time_s":
            continue
        for k, r in rows.items():
            if k != "table_6_2":
                print(f"{key:18s} {k:32s} model {r['model']:+.4g}  spec {r['spec_H1']:+.4g}  ({100 * r['rel_diff']:+.1f} %)")
    if not completed:
        sys.exit(1)
    return table


if __name__ == "__main__":
    main()
