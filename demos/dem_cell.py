#!/usr/bin/python3
"""Biaxial, simple shear or curvature test of one periodic DEM cell (demcell), the micro-scale of FEM x DEM.

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

Micropolar loadings (``--test shear`` / ``--test curvature``, docs/reference/demcell.md and
docs/reference/micropolar_cell.md): after the same packing and isotropic stage, the prepared state
(re-referenced: F = I, sigma = -p0 I, as demcell.reference_cell) becomes a micropolar cell
(rotation_mode "micropolar"): its force-weighted mean grain rotation is held at the imposed
micro-rotation phi and a curvature kappa = grad phi turns the periodic images. Its stress is
not symmetric: the skew stress sigma12 - sigma21 is the reaction to phi, and the couple
stress (m31, m32) [N] answers kappa. First the cell's DEMQO micropolar tangent at the
reference state is printed (6x6, rows sigma11, sigma22, sigma12, sigma21, m31, m32; columns
eps11, eps22, eps12, eps21, kappa31, kappa32, eps = Grad u + e phi, e = [[0, 1], [-1, 0]]),
with mu_c = (C[2,2] - C[2,3]) / 2.

4. ``--test shear``: simple shear F = [[1, gamma], [0, 1]] in increments of ``--increment``
   up to ``--shear-strain``, F fully imposed (the lateral stress sigma22 is NOT controlled,
   it follows), phi held: ``--rotation zero`` (phi = 0, skew strain eps12 - eps21 = gamma,
   expect sigma12 - sigma21 = 2 mu_c gamma while the contacts stay elastic) or
   ``--rotation material`` (phi = -gamma/2, the material rotation: eps12 = eps21 = gamma/2,
   the skew stress is then only the anisotropy of the packing). Look at: sigma12 (shear
   stress) and the skew stress vs gamma in ``shear.png``; the summary's
   initial_skew_modulus (first increment) against the tangent's 2 mu_c.
5. ``--test curvature``: F = I, phi = 0, kappa = (k, 0) ramped until the rotation jump
   k |Y1| across the cell (Y1 = first periodicity vector of the reference cell) reaches
   ``--rotation-jump`` [rad], in increments of ``--increment`` [rad]. Look at: m31 vs
   kappa31 in ``curvature.png``; the summary's bending modulus B = dm31/dkappa31 [N m] of
   the first increment and the length l_c = sqrt(B / (2 mu_c)) against the mean grain
   diameter.
Outputs as the biaxial test's, with the columns of each test in ``history.csv`` (shear:
shear_strain, sigma11, sigma22, sigma12, sigma21, skew_stress, m31, m32,
coordination_number, sliding_fraction; curvature: rotation_jump, kappa31, m31, m32,
skew_stress, sliding_fraction), solver counts in ``details.csv``; in the VTK snapshots the
particles' ``rotation`` is then the rotation fluctuation th~ = theta - theta_ref - phi -
kappa . X (X the reference lever position): the pattern of the grains' own rotations.

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
from demcell.strain_path import strain_path_step  # noqa: E402
from cosserat_fenicsx.figures import pyplot  # noqa: E402
from cosserat_fenicsx.validation import AXIAL_STRAIN, DISCS, FRICTION  # noqa: E402


#: options that belong to one test only (None = not given); their defaults are set after the check
TEST_OPTIONS = {"biaxial": dict(axial_strain=0.1, lateral_control="servo", axial_direction=1),
                "shear": dict(shear_strain=0.02, rotation="zero"),
                "curvature": dict(rotation_jump=0.02)}
FRAME_TOL = 1e-3       # --micro-bc frame: servo tolerance (demcell.frame.FrameOptions.eps_a)
SHEAR_STRAIN = dict(low=0.0, high=0.5, low_open=True, high_open=True)   # |gamma| of the simple shear
ROTATION_JUMP = dict(low=0.0, high=1.0, low_open=True)   # [rad]; DemCell refuses a jump > 1 rad


def parse(argv=None):
    from cosserat_fenicsx.validation import (NON_NEGATIVE, NON_NEGATIVE_INTEGER, POSITIVE, UNIT_OPEN, COUNT,
                                             InputError, Parser, number)
    p = Parser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter,
               allow_abbrev=False, epilog="See the module docstring (head of this file) for details.")
    p.add_argument("--test", choices=tuple(TEST_OPTIONS), default="biaxial",
                   help="biaxial (default, 000 section 4), shear (simple shear of a micropolar cell at a held "
                        "micro-rotation) or curvature (a curvature kappa31 imposed on a micropolar cell)")
    p.add_argument("--particles", type=number(DISCS), default=228,
                   help=f"number of discs, {DISCS.describe()} (default 228, 000 Table 3)")
    p.add_argument("--friction", type=number(FRICTION), default=0.4,
                   help="Coulomb friction mu >= 0, inf: no sliding (default 0.4)")
    p.add_argument("--no-rotation", action="store_true",
                   help="lock particle rotations (000 section 4.3.2; biaxial test only)")
    p.add_argument("--seed", type=number(NON_NEGATIVE_INTEGER), default=0, help="packing seed (default 0)")
    p.add_argument("--axial-strain", type=number(AXIAL_STRAIN), default=None,
                   help="biaxial: final axial shortening |F_11 - 1|, in (0, 0.5) (default 0.1, 000 Table 3)")
    p.add_argument("--shear-strain", type=number(**SHEAR_STRAIN), default=None,
                   help="shear: final gamma = F_12, in (0, 0.5) (default 0.02)")
    p.add_argument("--rotation", choices=("zero", "material"), default=None,
                   help="shear: the held micro-rotation phi = 0 (default; skew strain eps12 - eps21 = gamma) or "
                        "phi = -gamma/2, the material rotation (eps12 - eps21 = 0)")
    p.add_argument("--rotation-jump", type=number(**ROTATION_JUMP), default=None,
                   help="curvature: final rotation jump kappa31 |Y1| across the cell [rad], in (0, 1] "
                        "(default 0.02)")
    p.add_argument("--increment", type=number(POSITIVE), default=1e-3,
                   help="size of one increment of the test's loading (axial strain, shear strain or rotation "
                        "jump [rad]), at most its final value (default 1e-3)")
    p.add_argument("--lateral-control", choices=("servo", "strain"), default=None,
                   help="biaxial: servo (default): the stress servo holds sigma_lat during the relaxation; "
                        "strain: each increment is a straight path in F from the committed state with F_lat "
                        "found by an outer secant iteration, as a FEM x DEM Gauss point is loaded")
    p.add_argument("--axial-direction", type=int, choices=(1, 2), default=None,
                   help="biaxial: axis shortened: 1 (e1, default) or 2 (e2, the vertical of "
                        "demos/femdem_biaxial.py); the other is held at sigma = -p0 by the servo")
    p.add_argument("--pressure", type=number(POSITIVE), default=10.0,
                   help=f"confining pressure p0 [N/m], with p0/kn in [{PRESSURE_RATIO_RANGE[0]:g}, "
                        f"{PRESSURE_RATIO_RANGE[1]:g}] (default 10)")
    p.add_argument("--kn", type=number(POSITIVE), default=1e4, help="normal stiffness [N/m] (default 1e4)")
    p.add_argument("--ks", type=number(NON_NEGATIVE), default=2e3, help="tangential stiffness [N/m] (default 2e3)")
    p.add_argument("--snapshot-every", type=number(COUNT), default=10, help="increments between VTK snapshots")
    p.add_argument("--anisotropy", type=number(low=0.0, high=1.0, high_open=True), default=None,
                   help="target initial fabric anisotropy A0 in [0, 1) (000 section 4.3.3: 0.02, 0.05, 0.08)")
    p.add_argument("--relaxation-tol", type=number(UNIT_OPEN), default=None,
                   help="relaxation tolerance in (0, 1) (default 1e-3, 000 Table 3; 1e-4 for shear and curvature)")
    p.add_argument("--criterion", choices=("energy", "force"), default=None,
                   help="convergence test: E_kin/E_pot (000 eq. 31, default of the biaxial test) or "
                        "unbalanced-force ratio (001, default of shear and curvature: the energy ratio is "
                        "dominated by the pre-stress and stops before a small rotation increment has relaxed)")
    p.add_argument("--relaxation", choices=["local", "fire"], default="local",
                   help="dynamic relaxation: local damping 0.7 (000, default) or FIRE")
    p.add_argument("--micro-bc", choices=("periodic", "frame"), default="periodic",
                   help="biaxial: the cell's boundary: periodic (default, images) or frame (paper 000's frame "
                        "of boundary particles held by a servo, demcell.frame, made from the prepared periodic "
                        "cell; needs --lateral-control strain, its default then)")
    p.add_argument("--frame-thickness", type=number(POSITIVE), default=None,
                   help="frame: width of the frame in mean diameters (default: one particle layer, the discs "
                        "the cut crosses)")
    p.add_argument("--frame-tol", type=number(POSITIVE), default=None,
                   help="frame: servo tolerance eps_a on the frame's residual in mean contact forces "
                        f"(default {FRAME_TOL:g}, with --relaxation-tol 1e-4 and --criterion force)")
    p.add_argument("--packing", default=None, help="start from a packing file (.npz from a previous run)")
    p.add_argument("--out", default="results/dem_cell", help="output directory")
    a = p.parse_args(argv)
    try:
        # an option of another test would be silently ignored: refuse it (one line, before any work)
        for test, own in TEST_OPTIONS.items():
            for name in own:
                if test != a.test and getattr(a, name) is not None:
                    raise InputError(f"--{name.replace('_', '-')} is an option of --test {test}, not of --test "
                                     f"{a.test}" + (" (F is imposed: the lateral stress is not controlled)"
                                                    if name == "lateral_control" else ""))
        if a.no_rotation and a.test != "biaxial":
            raise InputError(f"--no-rotation cannot be used with --test {a.test}: locked rotations cannot carry "
                             "a micro-rotation or a curvature")
        frame = a.micro_bc == "frame"
        if not frame and (a.frame_thickness is not None or a.frame_tol is not None):
            raise InputError("--frame-thickness and --frame-tol are options of --micro-bc frame")
        if frame and a.test != "biaxial":
            raise InputError(f"--micro-bc frame is for --test biaxial: --test {a.test} loads a micropolar cell, "
                             "which is periodic (its curvature turns the periodic images)")
        if frame and a.lateral_control == "servo":
            raise InputError("--micro-bc frame takes --lateral-control strain (the stress servo is the periodic "
                             "cell's: it deforms the cell during the relaxation)")
        if frame and a.relaxation == "fire":
            raise InputError("--micro-bc frame relaxes with local damping (000 section 3.2.1), not --relaxation fire")
        if frame:
            a.lateral_control = "strain"
        micropolar = a.test != "biaxial"
        for name, default in dict(TEST_OPTIONS[a.test], criterion="force" if micropolar or frame else "energy",
                                  relaxation_tol=1e-4 if micropolar or frame else 1e-3).items():
            if getattr(a, name) is None:
                setattr(a, name, default)
        total_name, total = {"biaxial": ("axial-strain", a.axial_strain), "shear": ("shear-strain", a.shear_strain),
                             "curvature": ("rotation-jump", a.rotation_jump)}[a.test]
        if not total / 1e6 <= a.increment <= total:
            raise InputError(f"--increment must be in [--{total_name} / 1e6, --{total_name}] = "
                             f"[{total / 1e6:g}, {total:g}] (at most a million increments), "
                             f"got {a.increment:g}")
        check_pressure_ratio(a.pressure, a.kn)
        dc.ContactLaw(kn=a.kn, ks=a.ks, friction=a.friction, rotations=not a.no_rotation)
        if a.packing is not None:
            ignored = sorted(p.given_options(argv) & {"particles", "seed", "anisotropy"})
            if ignored:       # the file sets the discs: these would be silently without effect
                raise InputError(f"--packing gives the discs: {', '.join('--' + o for o in ignored)} would have no "
                                 f"effect (leave {'it' if len(ignored) == 1 else 'them'} out)")
            dc.load_packing(a.packing)        # missing, truncated or inconsistent: refused now
    except ValueError as error:
        p.refuse(error)
    return a


def echoed_options(a):
    """The options of this run for summary.json (those of the other tests left out)."""
    other = {name for test, own in TEST_OPTIONS.items() if test != a.test for name in own}
    return {k: v for k, v in vars(a).items() if k not in other}


def plot(history, path):
    plt = pyplot()
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


# ----- micropolar loadings (--test shear / curvature), docs/reference/demcell.md and docs/reference/micropolar_cell.md
SHEAR_COLUMNS = ["shear_strain", "sigma11", "sigma22", "sigma12", "sigma21", "skew_stress", "m31", "m32",
                 "coordination_number", "sliding_fraction"]
CURVATURE_COLUMNS = ["rotation_jump", "kappa31", "m31", "m32", "skew_stress", "sliding_fraction"]
DETAIL_COLUMNS = ["load", "micro_rotation", "kappa31", "kappa32", "sigma11", "sigma22", "sigma12", "sigma21",
                  "m31", "m32", "coordination_number", "n_contacts", "mean_rotation_fluctuation",
                  "max_rotation_fluctuation", "converged", "steps"]


def frame_cell(cell, law, opts, a):
    """The prepared periodic cell (after the isotropic stage) cut open into paper 000's frame
    cell (demcell.frame), re-referenced there: F = I, sigma = -p0 I."""
    from demcell.frame import FrameCell, FrameOptions
    prepared = cell.state.copy()
    prepared.v[:] = 0.0
    prepared.omega[:] = 0.0
    frame = dict(thickness=a.frame_thickness) if a.frame_thickness is not None else {}
    # the lateral stress of each increment is found to 1e-4 by a secant iteration
    # (strain_path_step): the servo must bring the stress closer than that
    frame["eps_a"] = a.frame_tol if a.frame_tol is not None else FRAME_TOL
    return FrameCell(prepared, law, FrameOptions(relaxation=opts, max_iterations=300, **frame))


def micropolar_cell(state, law, opts, pressure):
    """The prepared cell of a micropolar test: the isotropic stage at ``pressure`` with free
    rotations, re-referenced there (F = I, sigma = -p0 I; demcell.reference_cell), then the same
    state as a micropolar cell (phi = 0, kappa = 0 at the reference)."""
    ref = dc.reference_cell(state, law, opts, pressure)
    ref.state.phi, ref.state.kappa = 0.0, np.zeros(2)
    return dc.DemCell(ref.state, law, opts, reset_reference=False, rotation_mode="micropolar")


def rotation_fluctuation(state, theta_ref):
    """th~_p = theta_p - theta_p(reference) - phi - kappa . X_p, X_p = h_ref (s_p - c): the part of
    each grain's rotation that the imposed micro-rotation and curvature do not explain [rad]."""
    X = (state.s - 0.5) @ state.h_ref.T
    return state.theta - theta_ref - state.phi - X @ state.kappa


def held_mean_fluctuation(state, theta_ref):
    """The mean of th~ that the micropolar cell holds at zero, sum_p w_p th~_p / sum_p w_p, with
    the cell's own weights w_p (demcell.network.contact_weights: the normal force disc p
    carries) [rad], and the largest |th~_p|. The constraint acts on the rates with the current
    weights, so this shows whether the held rotation is still phi after the forces changed."""
    from demcell.network import contact_weights
    th = rotation_fluctuation(state, theta_ref)
    weight = contact_weights(state)
    mean = float(weight @ th / weight.sum()) if weight.sum() > 0.0 else 0.0
    return mean, float(np.abs(th).max(initial=0.0))


def write_fluctuation_snapshot(directory, index, cell, theta_ref):
    """VTK snapshot whose particle ``rotation`` is the rotation fluctuation (rotation_fluctuation)."""
    st = cell.state.copy()
    st.theta = rotation_fluctuation(st, theta_ref)
    dc.write_vtk_snapshot(directory, index, st)


def skew_stress_increment(C, dF, dphi):
    """Linear prediction of d(sigma12 - sigma21) [N/m] from the micropolar tangent C (6x6, FE
    callback order) for an increment dF (2x2) and dphi [rad]. The tangent is taken at fixed phi;
    the phi column follows from eps = Grad u + e phi: a rigid rotation F = R(a) with phi = a
    leaves the (isotropic) reference stress unchanged, so d sigma/d phi = C[:, eps12] - C[:, eps21]."""
    deps = np.array([dF[0, 0], dF[1, 1], dF[0, 1], dF[1, 0]])
    skew_row = C[2, :4] - C[3, :4]
    return float(skew_row @ deps + (skew_row[2] - skew_row[3]) * dphi)


def two_panels():
    """(pyplot, figure, two axes side by side) for the micropolar tests' plots."""
    plt = pyplot()
    fig, ax = plt.subplots(1, 2, figsize=(10, 4.2), sharex=True)
    return plt, fig, ax


def save_panels(plt, fig, ax, xlabel, title, path):
    for a in ax:
        a.set_xlabel(xlabel)
        a.grid(True, alpha=0.3)
        a.legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_shear(history, path, rotation):
    h = np.atleast_2d(np.array(history))
    x = h[:, 0] * 100.0
    plt, fig, ax = two_panels()
    ax[0].plot(x, h[:, 3], "-", label="sigma12 (shear stress)")
    ax[0].plot(x, h[:, 4], "--", label="sigma21")
    ax[0].plot(x, h[:, 5], "-", label="sigma12 - sigma21 (skew stress)")
    ax[0].set_ylabel("stress [N/m]")
    ax[1].plot(x, h[:, 1], "-", label="sigma11")
    ax[1].plot(x, h[:, 2], "-", label="sigma22 (lateral, not controlled)")
    ax[1].set_ylabel("normal stress [N/m] (tension +)")
    save_panels(plt, fig, ax, "shear strain gamma = F12 [%]", "demcell micropolar simple shear, micro-rotation "
                f"{'phi = 0' if rotation == 'zero' else 'phi = -gamma/2'}", path)


def plot_curvature(history, bending_tangent, m31_ref, path):
    h = np.atleast_2d(np.array(history))
    k = h[:, 1]
    plt, fig, ax = two_panels()
    ax[0].plot(k, h[:, 2], "o-", ms=3, label="m31")
    ax[0].plot(k, h[:, 3], "-", label="m32")
    ax[0].plot(k, m31_ref + bending_tangent * k, ":", label="m31(0) + B kappa31 (DEMQO tangent)")
    ax[0].set_ylabel("couple stress [N]")
    ax[1].plot(k, h[:, 4], "-", label="sigma12 - sigma21")
    ax[1].set_ylabel("skew stress [N/m]")
    save_panels(plt, fig, ax, "curvature kappa31 [1/m]", "demcell micropolar curvature test (F = I, phi = 0)", path)


def run_micropolar(a, guard, law, state, info, opts, t0):
    """--test shear or curvature from the packing ``state`` (see the module docstring)."""
    try:
        cell = micropolar_cell(state, law, opts, a.pressure)
    except dc.DemCellError as error:
        guard.stop(f"isotropic stage: {error}")
    hom = cell.homogenized()
    print(f"[demcell] isotropic stage: p = {hom.pressure:.4g} N/m, dt = {cell.dt:.3e} s, "
          f"{cell.contact_count()} contacts; micropolar cell (phi held as the force-weighted mean rotation)")
    C = cell.tangent("demqo", measure="micropolar")      # frozen contact network at the reference
    mu_c = 0.5 * (C[2, 2] - C[2, 3])
    print("[demcell] micropolar DEMQO tangent at the reference (rows sigma11 sigma22 sigma12 sigma21 m31 m32; "
          "columns eps11 eps22 eps12 eps21 kappa31 kappa32):")
    for row in C:
        print("[demcell]   " + " ".join(f"{v:+.5e}" for v in row))
    print(f"[demcell] mu_c = (C[2,2] - C[2,3]) / 2 = {mu_c:.6g} N/m, 2 mu_c = {2 * mu_c:.6g} N/m, "
          f"B = C[4,4] = {C[4, 4]:.6g} N m")
    theta_ref = cell.state.theta.copy()
    snap_dir = os.path.join(a.out, "snapshots")
    shear = a.test == "shear"
    Y1 = float(np.linalg.norm(cell.state.h_ref[:, 0]))      # |Y1| of the reference cell [m]
    total = a.shear_strain if shear else a.rotation_jump
    n_inc = int(round(total / a.increment))
    hist = CsvLog(os.path.join(a.out, "history.csv"), SHEAR_COLUMNS if shear else CURVATURE_COLUMNS)
    det = CsvLog(os.path.join(a.out, "details.csv"), DETAIL_COLUMNS)
    history = []

    def target(load):
        """(F, phi, kappa) at the value ``load`` of the loading parameter (gamma or the jump)."""
        if shear:
            return np.array([[1.0, load], [0.0, 1.0]]), (0.0 if a.rotation == "zero" else -0.5 * load), np.zeros(2)
        return np.eye(2), 0.0, np.array([load / Y1, 0.0])

    def record(load, h, steps, converged):
        s, m = h.cauchy, h.couple_stress
        skew = s[0, 1] - s[1, 0]
        drift, spin = held_mean_fluctuation(cell.state, theta_ref)
        if shear:
            row = [load, s[0, 0], s[1, 1], s[0, 1], s[1, 0], skew, m[0], m[1], h.coordination_number,
                   h.sliding_fraction]
        else:
            row = [load, cell.state.kappa[0], m[0], m[1], skew, h.sliding_fraction]
        with guard.deferred():
            history.append(row)
            hist.write(**dict(zip(hist.columns, row)))
            det.write(load=load, micro_rotation=cell.state.phi, kappa31=cell.state.kappa[0],
                      kappa32=cell.state.kappa[1], sigma11=s[0, 0], sigma22=s[1, 1], sigma12=s[0, 1],
                      sigma21=s[1, 0], m31=m[0], m32=m[1], coordination_number=h.coordination_number,
                      n_contacts=h.n_contacts, mean_rotation_fluctuation=drift, max_rotation_fluctuation=spin,
                      converged=int(converged), steps=steps)
            guard.progress(**{("final_shear_strain" if shear else "final_rotation_jump"): load})

    def draw():
        if shear:
            plot_shear(history, os.path.join(a.out, "shear.png"), a.rotation)
        else:
            plot_curvature(history, C[4, 4], history[0][2], os.path.join(a.out, "curvature.png"))

    record(0.0, hom, 0, True)
    write_fluctuation_snapshot(snap_dir, 0, cell, theta_ref)
    steps_total, n_bad = 0, 0
    for k in range(1, n_inc + 1):
        load = total * k / n_inc
        F, phi, kappa = target(load)
        cell.set_deformation(F, rotation=phi, curvature=kappa)
        try:
            res = cell.solve()
        except dc.DemCellError as error:
            guard.stop(f"increment {k}: {error}")
        steps_total += res.steps
        if not res.converged:
            n_bad += 1
            print(f"[demcell]   increment {k}: NOT converged: {res.message}")
        cell.commit()
        h = cell.homogenized()
        record(load, h, res.steps, res.converged)
        if k % a.snapshot_every == 0 or k == n_inc:
            write_fluctuation_snapshot(snap_dir, k, cell, theta_ref)
            draw()
            r = history[-1]
            if shear:
                print(f"[demcell] gamma = {load:.4f}  sigma12 {r[3]:+.4g}  skew {r[5]:+.4g}  sigma22 {r[2]:+.4g}  "
                      f"z {r[8]:.2f}  sliding {r[9]:.3f}  ({time.time() - t0:.1f} s)")
            else:
                print(f"[demcell] jump = {load:.4f} rad  kappa31 {r[1]:.4g}  m31 {r[2]:+.4g}  skew {r[4]:+.4g}  "
                      f"sliding {r[5]:.3f}  ({time.time() - t0:.1f} s)")
    hist.close()
    det.close()
    hh = np.array(history)
    summary = dict(test=a.test, mu_c=mu_c, tangent_skew_modulus_2mu_c=2 * mu_c, tangent_bending_modulus=C[4, 4],
                   tangent_demqo_micropolar=C.tolist(),
                   tangent_order="rows sigma11 sigma22 sigma12 sigma21 m31 m32; columns eps11 eps22 eps12 eps21 "
                                 "kappa31 kappa32 (eps = Grad u + e phi, e = [[0, 1], [-1, 0]]), at fixed phi")
    F1, phi1, kappa1 = target(hh[1, 0])
    if shear:
        skew_strain = lambda g: g + 2.0 * target(g)[1]     # eps12 - eps21 = gamma + 2 phi
        ipk = int(np.argmax(hh[:, 3]))
        d_skew = hh[1, 5] - hh[0, 5]
        summary.update(
            rotation=a.rotation, micro_rotation="phi = 0" if a.rotation == "zero" else "phi = -gamma/2 (material)",
            lateral_stress="not controlled: F = [[1, gamma], [0, 1]] is imposed, sigma11 and sigma22 follow",
            peak_shear_stress=float(hh[ipk, 3]), shear_strain_at_peak=float(hh[ipk, 0]),
            final_shear_stress=float(hh[-1, 3]), final_skew_stress=float(hh[-1, 5]),
            final_skew_strain=float(skew_strain(hh[-1, 0])),
            final_sigma22_change=float(hh[-1, 2] - hh[0, 2]),
            initial_shear_modulus=float((hh[1, 3] - hh[0, 3]) / hh[1, 0]),
            first_increment_skew_stress_change=float(d_skew),
            first_increment_skew_stress_tangent=skew_stress_increment(C, F1 - np.eye(2), phi1))
        if skew_strain(hh[1, 0]) != 0.0:
            summary["initial_skew_modulus"] = float(d_skew / skew_strain(hh[1, 0]))
        else:
            summary["initial_skew_modulus"] = None
            summary["initial_skew_modulus_note"] = ("the skew strain eps12 - eps21 is held at zero "
                                                    "(--rotation material): no skew modulus to measure")
    else:
        B = float((hh[1, 2] - hh[0, 2]) / hh[1, 1])
        diameter = float(2.0 * cell.state.radius.mean())
        summary.update(
            cell_length_Y1=Y1, final_kappa31=float(hh[-1, 1]), final_m31=float(hh[-1, 2]),
            peak_m31=float(hh[:, 2].max()), final_skew_stress=float(hh[-1, 4]),
            bending_modulus_B=B, mean_grain_diameter=diameter)
        if B > 0.0 and mu_c > 0.0:
            lc = math.sqrt(B / (2.0 * mu_c))
            summary.update(characteristic_length_l_c=lc, l_c_over_mean_diameter=lc / diameter)
        else:
            summary.update(characteristic_length_l_c=None,
                           l_c_note=f"l_c = sqrt(B / (2 mu_c)) needs B > 0 and mu_c > 0 (B = {B:.3g} N m, "
                                    f"mu_c = {mu_c:.3g} N/m)")
    summary.update(increments=n_inc, increments_not_converged=n_bad, dem_steps=int(steps_total),
                   time_step_s=cell.dt, wall_time_s=time.time() - t0, packing=info, micro_bc=a.micro_bc, options=echoed_options(a),
                   sign_convention="tension positive; (Grad u)_ij = du_i/dX_j; phi, kappa ccw positive; "
                                   "skew_stress = sigma12 - sigma21")
    if n_bad:
        summary["warning"] = (f"{n_bad} of {n_inc} increments did not relax to --relaxation-tol within the step "
                              "budget (details.csv: converged = 0): their stresses are not equilibrium values; "
                              "smaller --increment or a larger p0/kn")
        print(f"[demcell] warning: {summary['warning']}")
    guard.finish(summary)
    if shear:
        print(f"[demcell] peak shear stress {summary['peak_shear_stress']:.4g} N/m at gamma "
              f"{summary['shear_strain_at_peak']:.4f}; skew stress at the end {summary['final_skew_stress']:+.4g} N/m; "
              f"first increment: skew {summary['first_increment_skew_stress_change']:+.4g} N/m "
              f"(tangent {summary['first_increment_skew_stress_tangent']:+.4g}); outputs in {a.out}")
    else:
        lc = summary["characteristic_length_l_c"]
        print(f"[demcell] bending modulus B = {summary['bending_modulus_B']:.4g} N m (tangent {C[4, 4]:.4g}), "
              f"l_c = {lc if lc is None else format(lc, '.4g')} m, mean diameter {summary['mean_grain_diameter']:.4g} m; "
              f"outputs in {a.out}")
    return summary


def main(argv=None):
    from cosserat_fenicsx.run_guard import RunGuard
    a = parse(argv)
    os.makedirs(a.out, exist_ok=True)
    guard = RunGuard(None, os.path.join(a.out, "summary.json"), dict(options=echoed_options(a)), label="demcell")
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
    if a.test != "biaxial":
        return run_micropolar(a, guard, law, state, info, opts, t0)
    cell = dc.DemCell(state, law, opts)
    try:
        dc.isotropic_stage(cell, a.pressure)   # friction on, sigma = -p0 I (000 section 4.1)
    except dc.DemCellError as error:
        guard.stop(f"isotropic stage: {error}")
    servo_iterations = []
    if a.micro_bc == "frame":
        cell = frame_cell(cell, law, opts, a)
        print(f"[demcell] frame cell: {len(cell.frame.groups)} frame discs ({cell.frame.n_copies - cell.frame.inner.size}"
              f" copies: {len(cell.frame.edge_pairs())} edge pairs), {cell.frame.inner.size} inner discs")
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
        if a.micro_bc == "frame":
            servo_iterations.append(cell.last_servo.iterations)
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
                   time_step_s=cell.dt, wall_time_s=time.time() - t0, packing=info, micro_bc=a.micro_bc,
                   options=echoed_options(a), sign_convention="tension positive; axial_strain = F_aa/F_aa_iso - 1 (a = axial direction)")
    if a.micro_bc == "frame":
        summary["frame"] = dict(frame_discs=len(cell.frame.groups), inner_discs=int(cell.frame.inner.size),
                                thickness=a.frame_thickness, servo_iterations_mean=float(np.mean(servo_iterations)),
                                servo_iterations_max=int(max(servo_iterations)), options=str(cell.options))
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
