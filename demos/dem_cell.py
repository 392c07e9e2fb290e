#!/usr/bin/python3
"""Biaxial test of one periodic DEM cell (demcell), the micro-scale of FEM x DEM.

What is solved
--------------
A 2D periodic assembly of polydisperse discs (radii uniform in [R_min, 1.5 R_min], paper 000
section 4.1) with the contact law of paper 000 eq. 10 (linear normal / tangential springs,
Coulomb friction) and the micro parameters of 000 Table 3 by default: 228 particles,
mu = 0.4, kn = 1e4 N/m, ks = 2e3 N/m, density 2e3 kg/m^2, local damping alpha = beta = 0.7,
energy tolerance E_kin/E_pot <= 1e-3 (000 eq. 31).

1. Packing: random gas compacted without friction to the isotropic pressure p0 (seeded, saved
   as ``packing.npz``; ``--packing`` reuses one, ``--anisotropy`` asks for an initial fabric
   anisotropy A0 through a frictional deviatoric pre-compaction).
2. Isotropic compression stage: friction switched on, the cell relaxed under
   sigma = -p0 I (stress control on F_11, F_22 and F_12).
3. Biaxial stage: axial direction e1 shortened in increments of the axial strain
   (F_11 imposed), lateral stress sigma_22 = -p0 kept by the servo on F_22, F_12 = F_21 = 0
   (``--axial-direction 2`` exchanges the axes: the FE specimen's vertical is e2;
   ``--lateral-control strain`` loads each increment along a straight path in F from the
   committed state, the lateral strain found by an outer iteration on sigma_lat, which is
   how a FEM x DEM Gauss point is loaded: a frictional packing is path dependent, and the
   two controls differ by about 1-2 % in the stress ratio before the peak).
   Each increment is a quasi-static solve (loading ramp, 001 eq. 7, then dynamic relaxation).

Sign conventions (as on the FE side): tension positive, so the axial strain F_11 - 1 and a
contracting volumetric strain det F - 1 are negative; the stress ratio
|s11 - s22| / |s11 + s22| (000 eq. 40) is positive. Stresses are 2D (N/m).

Pressure: 000 Table 3 lists sigma_0 = 0.15 MN/m together with kn = 1e4 N/m; in 2D the
overlap/radius is about 2 sigma_0/kn, i.e. 30 radii for those numbers, which is not a
granular state. The default p0 = 10 N/m gives p0/kn = 1e-3 (overlaps of ~0.1 % of a radius);
choose another with ``--pressure``.

Outputs in ``--out`` (written as the run goes): ``history.csv`` (axial_strain,
stress_ratio, volumetric_strain, coordination_number, anisotropy), ``details.csv`` (stresses,
sliding fraction, solver steps), ``summary.json`` (peak_stress_ratio, ...), ``biaxial.png``
(the four curves) and ``snapshots/particles_NNNN.vtk`` + ``contacts_NNNN.vtk``.

In ParaView: open ``particles_..vtk`` (a time series), apply *Glyph* (type 2D Glyph circle or
Sphere, scale by ``radius``, factor 2 for diameter, no orientation); colour by ``rotation``.
Open ``contacts_..vtk``, colour the lines by ``normal_force`` (compression > 0) and use
*Tube* with radius scaled by ``normal_force`` to see the force chains align with e1 as the
peak is approached, and the shear bands of rotation after it.
"""
import argparse
import math
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

import demcell as dc  # noqa: E402
from demcell.interface import RelaxationOptions  # noqa: E402
from demcell.io import CsvLog  # noqa: E402
from demcell.packing import PRESSURE_RATIO_RANGE, check_pressure_ratio  # noqa: E402
from cosserat_fenicsx.validation import AXIAL_STRAIN, DISCS, FRICTION  # noqa: E402


def parse(argv=None):
    from cosserat_fenicsx.validation import (NON_NEGATIVE, NON_NEGATIVE_INTEGER, POSITIVE, UNIT_OPEN, COUNT,
                                             InputError, Parser, number)
    p = Parser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter,
               allow_abbrev=False, epilog="See the module docstring (head of this file) for details.")
    p.add_argument("--particles", type=number(DISCS), default=228,
                   help=f"number of discs, {DISCS.describe()} (default 228, 000 Table 3)")
    p.add_argument("--friction", type=number(FRICTION), default=0.4,
                   help="Coulomb friction mu >= 0, inf: no sliding (default 0.4)")
    p.add_argument("--no-rotation", action="store_true", help="lock particle rotations (000 section 4.3.2)")
    p.add_argument("--seed", type=number(NON_NEGATIVE_INTEGER), default=0, help="packing seed (default 0)")
    p.add_argument("--axial-strain", type=number(AXIAL_STRAIN), default=0.1,
                   help="final axial shortening |F_11 - 1|, in (0, 0.5) (default 0.1, 000 Table 3)")
    p.add_argument("--increment", type=number(POSITIVE), default=1e-3,
                   help="axial strain per increment, at most --axial-strain (default 1e-3)")
    p.add_argument("--lateral-control", choices=("servo", "strain"), default="servo",
                   help="servo (default): the stress servo holds sigma_lat during the relaxation; strain: "
                        "each increment is a straight path in F from the committed state with F_lat found "
                        "by an outer secant iteration, as a FEM x DEM Gauss point is loaded")
    p.add_argument("--axial-direction", type=int, choices=(1, 2), default=1,
                   help="axis shortened: 1 (e1, default) or 2 (e2, the vertical of demos/femdem_biaxial.py); "
                        "the other is held at sigma = -p0 by the servo")
    p.add_argument("--pressure", type=number(POSITIVE), default=10.0,
                   help=f"confining pressure p0 [N/m], with p0/kn in [{PRESSURE_RATIO_RANGE[0]:g}, "
                        f"{PRESSURE_RATIO_RANGE[1]:g}] (default 10)")
    p.add_argument("--kn", type=number(POSITIVE), default=1e4, help="normal stiffness [N/m] (default 1e4)")
    p.add_argument("--ks", type=number(NON_NEGATIVE), default=2e3, help="tangential stiffness [N/m] (default 2e3)")
    p.add_argument("--snapshot-every", type=number(COUNT), default=10, help="increments between VTK snapshots")
    p.add_argument("--anisotropy", type=number(low=0.0, high=1.0, high_open=True), default=None,
                   help="target initial fabric anisotropy A0 in [0, 1) (000 section 4.3.3: 0.02, 0.05, 0.08)")
    p.add_argument("--relaxation-tol", type=number(UNIT_OPEN), default=1e-3,
                   help="relaxation tolerance in (0, 1) (default 1e-3, 000 Table 3)")
    p.add_argument("--criterion", choices=("energy", "force"), default="energy",
                   help="convergence test: E_kin/E_pot (000 eq. 31, default) or unbalanced-force ratio (001)")
    p.add_argument("--relaxation", choices=["local", "fire"], default="local",
                   help="dynamic relaxation: local damping 0.7 (000, default) or FIRE")
    p.add_argument("--packing", default=None, help="start from a packing file (.npz from a previous run)")
    p.add_argument("--out", default="results/dem_cell", help="output directory")
    a = p.parse_args(argv)
    try:
        if not a.axial_strain / 1e6 <= a.increment <= a.axial_strain:
            raise InputError(f"--increment must be in [--axial-strain / 1e6, --axial-strain] = "
                             f"[{a.axial_strain / 1e6:g}, {a.axial_strain:g}] (at most a million increments), "
                             f"got {a.increment:g}")
        check_pressure_ratio(a.pressure, a.kn)
        dc.ContactLaw(kn=a.kn, ks=a.ks, friction=a.friction, rotations=not a.no_rotation)
        if a.packing is not None:
            dc.load_packing(a.packing)        # missing, truncated or inconsistent: refused now
    except ValueError as error:
        p.refuse(error)
    return a


def strain_path_step(cell, F, lat, lateral_stress, rtol=1e-4, max_iterations=30):
    """One increment under full strain control, as a FEM x DEM Gauss point sees it: every trial
    goes straight from the committed state to F (001 eq. 7), and the lateral component
    F[lat, lat] is found by a secant iteration until sigma_lat = lateral_stress (to rtol).
    Returns the last SolveResult with the DEM steps of all trials."""
    def residual(f):
        cell.rollback()
        trial = F.copy()
        trial[lat, lat] = f
        cell.set_deformation(trial)
        result = cell.solve()
        return cell.cauchy_stress()[lat, lat] - lateral_stress, result

    steps = 0
    f0 = cell.deformation_gradient()[lat, lat]
    f1 = f0 + 0.3 * abs(F[1 - lat, 1 - lat] - cell.deformation_gradient()[1 - lat, 1 - lat]) + 1e-12
    (r0, res), (r1, res) = residual(f0), residual(f1)
    steps += res.steps
    for _ in range(max_iterations):
        if abs(r1) <= rtol * abs(lateral_stress) or r1 == r0:
            break
        f0, f1, r0 = f1, f1 - r1 * (f1 - f0) / (r1 - r0), r1
        r1, res = residual(f1)
        steps += res.steps
    res.steps = steps
    return res


def plot(history, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    h = np.atleast_2d(np.array(history))
    x = -h[:, 0] * 100.0
    fig, ax = plt.subplots(2, 2, figsize=(9, 7), sharex=True)
    labels = ["stress ratio |s11-s22|/|s11+s22|", "volumetric strain det F - 1 (tension +)",
              "coordination number 2C/N", "fabric anisotropy A (000 eq. 38)"]
    for k, a in enumerate(ax.flat):
        a.plot(x, h[:, k + 1], "-")
        a.set_ylabel(labels[k])
        a.grid(True, alpha=0.3)
    for a in ax[1]:
        a.set_xlabel("axial shortening -(F11 - 1) [%]")
    fig.suptitle("demcell periodic biaxial test")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv=None):
    from cosserat_fenicsx.run_guard import RunGuard
    a = parse(argv)
    os.makedirs(a.out, exist_ok=True)
    guard = RunGuard(None, os.path.join(a.out, "summary.json"), dict(options=vars(a)), label="demcell")
    t0 = time.time()
    law = dc.ContactLaw(kn=a.kn, ks=a.ks, friction=a.friction, rotations=not a.no_rotation)
    if a.packing:
        print(f"[demcell] packing from {a.packing}")
        state, info = dc.load_packing(a.packing)
    else:
        print(f"[demcell] packing: {a.particles} discs, seed {a.seed}, compaction to {a.pressure} N/m")
        try:
            state, info = dc.generate_packing(a.particles, pressure=a.pressure, law=law, seed=a.seed,
                                              anisotropy=a.anisotropy)
        except dc.DemCellError as error:
            guard.stop(f"packing: {error}")
    dc.save_packing(os.path.join(a.out, "packing.npz"), state, info)
    print(f"[demcell]   solid fraction {info['solid_fraction']:.3f}, coordination {info['coordination_number']:.2f}, "
          f"A0 {info['anisotropy']:.3f}, R_min/L {info['r_min_over_L']:.4f}")
    opts = RelaxationOptions(tol=a.relaxation_tol, damping=0.7, criterion=a.criterion, method=a.relaxation)
    cell = dc.DemCell(state, law, opts)
    try:
        dc.isotropic_stage(cell, a.pressure)   # friction on, sigma = -p0 I (000 section 4.1)
    except dc.DemCellError as error:
        guard.stop(f"isotropic stage: {error}")
    F = cell.deformation_gradient()
    F_iso = F.copy()
    J_iso = np.linalg.det(F_iso)
    hom = cell.homogenized()
    print(f"[demcell] isotropic stage: p = {hom.pressure:.4g} N/m, dt = {cell.dt:.3e} s, "
          f"{cell.contact_count()} contacts")
    snap_dir = os.path.join(a.out, "snapshots")
    history = []
    hist = CsvLog(os.path.join(a.out, "history.csv"),
                  ["axial_strain", "stress_ratio", "volumetric_strain", "coordination_number", "anisotropy"])
    det = CsvLog(os.path.join(a.out, "details.csv"),
                 ["axial_strain", "sigma_11", "sigma_22", "sigma_12", "sigma_21", "couple_31", "couple_32",
                  "sliding_fraction", "n_contacts", "converged", "steps"])

    ax = a.axial_direction - 1          # axial e1 (default) or e2 (the FE specimen's vertical)
    lat = 1 - ax

    def record(h, res_steps, converged):
        with guard.deferred():
            write_row(h, res_steps, converged)
            guard.progress(final_axial_strain=history[-1][0])

    def write_row(h, res_steps, converged):
        eps_a = F[ax, ax] / F_iso[ax, ax] - 1.0
        eps_v = np.linalg.det(cell.deformation_gradient()) / J_iso - 1.0
        row = [eps_a, h.stress_ratio, eps_v, h.coordination_number, h.anisotropy]
        history.append(row)
        hist.write(**dict(zip(hist.columns, row)))
        det.write(axial_strain=eps_a, sigma_11=h.cauchy[0, 0], sigma_22=h.cauchy[1, 1],
                  sigma_12=h.cauchy[0, 1], sigma_21=h.cauchy[1, 0], couple_31=h.couple_stress[0],
                  couple_32=h.couple_stress[1], sliding_fraction=h.sliding_fraction,
                  n_contacts=h.n_contacts, converged=int(converged), steps=res_steps)

    record(hom, 0, True)
    dc.write_vtk_snapshot(snap_dir, 0, cell.state)
    n_inc = int(round(a.axial_strain / a.increment))
    mask = np.zeros((2, 2), dtype=bool)
    mask[lat, lat] = True
    target = np.zeros((2, 2))
    target[lat, lat] = -a.pressure
    steps_total, n_bad = 0, 0
    for k in range(1, n_inc + 1):
        F = cell.deformation_gradient()
        F[ax, ax] = F_iso[ax, ax] * (1.0 - k * a.increment)
        if a.lateral_control == "servo":
            cell.set_deformation(F)
            res = cell.solve(stress_mask=mask, stress_target=target)
        else:
            res = strain_path_step(cell, F, lat, -a.pressure)
        steps_total += res.steps
        if not res.converged:
            n_bad += 1
            print(f"[demcell]   increment {k}: NOT converged: {res.message}")
        cell.commit()
        h = cell.homogenized()
        record(h, res.steps, res.converged)
        if k % a.snapshot_every == 0 or k == n_inc:
            dc.write_vtk_snapshot(snap_dir, k, cell.state)
            plot(history, os.path.join(a.out, "biaxial.png"))
            print(f"[demcell] eps_a = {history[-1][0]:+.4f}  ratio {h.stress_ratio:.3f}  "
                  f"eps_v {history[-1][2]:+.4f}  z {h.coordination_number:.2f}  A {h.anisotropy:.3f}  "
                  f"({time.time() - t0:.1f} s)")
    hist.close()
    det.close()
    hh = np.array(history)
    ipk = int(np.argmax(hh[:, 1]))
    summary = dict(peak_stress_ratio=float(hh[ipk, 1]), axial_strain_at_peak=float(hh[ipk, 0]),
                   final_stress_ratio=float(hh[-1, 1]), final_volumetric_strain=float(hh[-1, 2]),
                   friction_angle_at_peak_deg=float(math.degrees(math.asin(min(1.0, hh[ipk, 1])))),
                   increments=n_inc, increments_not_converged=n_bad, dem_steps=int(steps_total),
                   time_step_s=cell.dt, wall_time_s=time.time() - t0, packing=info,
                   options=vars(a), sign_convention="tension positive; axial_strain = F_aa/F_aa_iso - 1 (a = axial direction)")
    if n_bad:
        summary["warning"] = (f"{n_bad} of {n_inc} increments did not relax to --relaxation-tol within the step "
                              "budget (details.csv: converged = 0): their stresses are not equilibrium values; "
                              "smaller --increment or a larger p0/kn")
        print(f"[demcell] warning: {summary['warning']}")
    guard.finish(summary)
    print(f"[demcell] peak stress ratio {summary['peak_stress_ratio']:.3f} at axial strain "
          f"{summary['axial_strain_at_peak']:+.4f}; outputs in {a.out}")
    return summary


if __name__ == "__main__":
    main()
