"""Slip bands and softening of the strip footing (003 section 3, Figs 3, 6, 7): from the grains
of a run at two settlements, the per-grain incremental equivalent strain, the band leaving
each plate edge and its inclination, whether the two make a V (a wedge under the plate), and
the peak and post-peak drop of the plate load.

003 describes, at 60 mm: packings A and B soften (A's peak at 38 mm) and show narrow
"V-shaped slip bands at +-45 degrees" in the nominal strain; C hardens and has no clear band.

Method (all lengths in m):

* incremental displacement du = x(s2) - x(s1) of every real grain over the settlement window
  [s1, s2]; its gradient at each grain from the least-squares quadratic on the grain and its
  8 nearest neighbours at s1 (demcell.specimen.fields.patch_gradient);
* equivalent (von Mises) strain of the symmetric part in plane strain,
  eps_eq = sqrt(2/3 e:e), e the deviator of the 3x3 strain with eps33 = 0 (003-bsm.md [R]
  for 003's undefined "effective strain");
* ray scan from each plate edge E = (x_edge, y_surface) (moved along the surface by up to
  1 m, the best origin kept per angle): for angles phi in [10, 170] deg, the
  mean eps_eq of the grains near the ray E + t (cos phi, -sin phi) (x
  pointing towards the plate centre), t in [t_min, t_max], Gaussian-weighted by the distance
  from the ray (ray_scan), the grains of the top 0.1 m left out (edge_bands). phi < 90: the ray runs under the
  plate (inward, a wedge); phi > 90: away from it (outward, Prandtl's fan side). The band is
  the phi of the largest mean, its inclination from the horizontal min(phi, 180 - phi)
  (within 3 degrees on synthetic wedges of 30-70 degrees on lattice A's grains; fit_band within
  0.7 degrees); the
  contrast is that mean over the mean eps_eq of the window;
* cross-check: cosserat_fenicsx.shear_band.fit_band (thesis 004 eq 4.22, a Gaussian bell
  along a straight band) on each half of the window;
* softening: peak load, its settlement, the load at the end and the drop (peak - end) / peak.

    PYTHONPATH=. python3 benchmarks/bsm/footing_bands.py RUN_DIR [RUN_DIR ...] --window 40 60 --out DIR

RUN_DIR: a benchmarks/dns/footing_dem.py run with --snapshots (grains_S.npz; --window 0 S:
from the reference positions) or a demos/footing_bsm.py run (grains.vtk.series, the frames
nearest to the window's ends).
Writes DIR/bands.json and one strain map DIR/<run>_bands.png per run.
"""
import argparse
import csv
import json
import math
import os

import numpy as np
from scipy.spatial import cKDTree

from cosserat_fenicsx.shear_band import fit_band
from demcell.specimen.fields import patch_gradient

#: neighbours of a grain in its patch (the rotated square lattice's first two shells)
NEIGHBOURS = 8
#: the footing's plate width [m] (demos/footing_bsm.py)
PLATE_WIDTH = 2.0


def equivalent_strain(position, displacement, neighbours=NEIGHBOURS):
    """eps_eq (n,) [-] of the displacement field (n, 2) [m] given at the grains (n, 2) [m]:
    patch-gradient strain, sqrt(2/3 e:e) of its plane-strain deviator (module docstring).
    Also returns the gradient (n, 2, 2), du_i/dx_j (NaN where no fit)."""
    position = np.asarray(position, float)
    tree = cKDTree(position)
    _, idx = tree.query(position, k=neighbours + 1)
    members = idx[:, 1:]
    offsets = np.arange(0, neighbours * len(position) + 1, neighbours, dtype=np.int64)
    grad, _ = patch_gradient(position, np.asarray(displacement, float), np.ones(len(position), bool),
                             (offsets, members.reshape(-1).astype(np.int64)))
    return equivalent_of_gradient(grad), grad


def equivalent_of_gradient(grad):
    """eps_eq (n,) [-] of displacement gradients (n, 2, 2): sqrt(2/3 e:e) of the plane-strain
    deviator of their symmetric part (module docstring)."""
    exx, eyy = grad[:, 0, 0], grad[:, 1, 1]
    exy = 0.5 * (grad[:, 0, 1] + grad[:, 1, 0])
    mean = (exx + eyy) / 3.0
    ee = (exx - mean) ** 2 + (eyy - mean) ** 2 + mean ** 2 + 2.0 * exy ** 2
    return np.sqrt(2.0 / 3.0 * ee)


def ray_scan(position, strain, edge, inward, half_width, t_min, t_max, angles_deg):
    """Weighted mean strain along rays from `edge` (2,) [m], one per angle phi [deg] (module
    docstring; `inward` = +1 or -1, the x direction of the plate centre seen from the edge):
    the grains with t in [t_min, t_max] [m] along the ray, weighted by exp(-d^2 / (2 h^2)),
    d their distance from it, h = half_width [m], cut at 3 h (a smooth score: a sharp strip
    holds the same few lattice grains over several degrees). Returns (means (k,), grains
    within h (k,))."""
    rel = np.asarray(position, float) - np.asarray(edge, float)
    finite = np.isfinite(strain)
    means, counts = np.full(len(angles_deg), np.nan), np.zeros(len(angles_deg), int)
    for k, phi in enumerate(np.radians(angles_deg)):
        dx, dy = inward * math.cos(phi), -math.sin(phi)
        t = rel[:, 0] * dx + rel[:, 1] * dy
        d = np.abs(rel[:, 0] * dy - rel[:, 1] * dx)
        sel = (t >= t_min) & (t <= t_max) & (d <= 3.0 * half_width) & finite
        counts[k] = int(np.sum(sel & (d <= half_width)))
        if counts[k]:
            w = np.exp(-0.5 * (d[sel] / half_width) ** 2)
            means[k] = float(np.sum(w * strain[sel]) / np.sum(w))
    return means, counts


def edge_bands(position, strain, plate_x, surface_y, half_width=0.05, t_min=0.2, t_max=1.2, step_deg=1.0,
               shift=1.0, shift_step=0.05, skin=0.1, min_deg=10.0):
    """The band from each plate edge: {"left"/"right": {"phi_deg", "inclination_deg",
    "inward", "origin_shift_m", "contrast", "best_inward_deg", "best_outward_deg",
    "inward_over_outward"}} and "v_shape": both bands inward (a wedge under the plate).
    plate_x (x0, x1) [m]; surface_y [m]: the surface the edges sit on. The rays start at
    the edge moved by up to `shift` [m] along the surface (origin_shift_m > 0: under the
    plate), since a band need not leave the plate's corner exactly. The grains within
    `skin` [m] of the surface are left out of the scan and the angles kept within
    [min_deg, 180 - min_deg]: the patch fits of the free surface's grains are one-sided and
    their strain is large wherever the surface heaves; a ray along it is not a band. The
    background of the contrast is the mean over the whole window."""
    background = float(np.nanmean(strain))
    angles = np.arange(min_deg, 180.0 - min_deg + 0.5 * step_deg, step_deg)
    deep = position[:, 1] <= surface_y - skin
    position, strain = position[deep], strain[deep]
    shifts = np.arange(-shift, shift + 0.5 * shift_step, shift_step)
    out = {}
    for side, x_edge, inward in (("left", plate_x[0], 1.0), ("right", plate_x[1], -1.0)):
        means = np.array([ray_scan(position, strain, (x_edge + inward * o, surface_y), inward, half_width, t_min,
                                   t_max, angles)[0] for o in shifts])       # (shifts, angles)
        means = np.where(np.isfinite(means), means, -np.inf)
        best = means.max(axis=0)                                             # best origin per angle
        k = int(np.argmax(best))
        inner, outer = angles < 90.0, angles > 90.0
        ki = int(np.argmax(np.where(inner, best, -np.inf)))
        ko = int(np.argmax(np.where(outer, best, -np.inf)))
        phi = float(angles[k])
        out[side] = {"phi_deg": phi, "inclination_deg": min(phi, 180.0 - phi), "inward": bool(phi < 90.0),
                     "origin_shift_m": float(shifts[int(np.argmax(means[:, k]))]),
                     "contrast": float(best[k] / background) if background > 0 else math.inf,
                     "best_inward_deg": float(angles[ki]), "best_outward_deg": float(180.0 - angles[ko]),
                     "inward_over_outward": float(best[ki] / best[ko])}
    out["v_shape"] = bool(out["left"]["inward"] and out["right"]["inward"])
    return out


def half_fits(position, strain, centre_x):
    """fit_band on each half of the window: {"left"/"right": inclination [deg] (positive when
    the band rises towards +x; a V under the plate: left < 0 < right), thickness H [m]}."""
    res = {}
    for side, sel in (("left", position[:, 0] < centre_x), ("right", position[:, 0] > centre_x)):
        ok = sel & np.isfinite(strain)
        try:
            fit = fit_band(position[ok], strain[ok])
            res[side] = {"inclination_deg": fit.inclination_deg, "thickness_m": fit.thickness,
                         "converged": fit.converged}
        except ValueError as error:
            res[side] = {"error": str(error)}
    return res


def softening(settlement_mm, load_kN):
    """Peak load [kN/m], its settlement [mm], the final load and (peak - final) / peak."""
    s, f = np.asarray(settlement_mm, float), np.asarray(load_kN, float)
    k = int(np.argmax(f))
    return {"peak_kN_per_m": float(f[k]), "peak_at_mm": float(s[k]), "final_kN_per_m": float(f[-1]),
            "final_at_mm": float(s[-1]), "drop": float((f[k] - f[-1]) / f[k]) if f[k] > 0 else math.nan}


def window_box(plate_x, surface_y, width=6.0, depth=3.0):
    """(x_min, x_max, y_min, y_max) [m]: 003's 6 x 3 m DEM region under the plate."""
    c = 0.5 * (plate_x[0] + plate_x[1])
    return c - 0.5 * width, c + 0.5 * width, surface_y - depth, surface_y + 1.0


def analyse(position, displacement, plate_x, surface_y, box=None):
    """Strain and bands of one window. position (n, 2) [m] at the window's start, displacement
    (n, 2) [m] over it. Returns (dict, strain (n,), inside (n,) bool)."""
    position = np.asarray(position, float)
    strain, _ = equivalent_strain(position, displacement)
    box = box or window_box(plate_x, surface_y)
    inside = ((position[:, 0] >= box[0]) & (position[:, 0] <= box[1]) & (position[:, 1] >= box[2])
              & (position[:, 1] <= box[3]))
    p, e = position[inside], strain[inside]
    res = {"grains": int(inside.sum()), "median_strain": float(np.nanmedian(e)),
           "p99_strain": float(np.nanpercentile(e, 99)), "bands": edge_bands(p, e, plate_x, surface_y),
           "fit_band": half_fits(p, e, 0.5 * (plate_x[0] + plate_x[1]))}
    return res, strain, inside


# %% reading runs
def load_history(run):
    """(settlement [mm], plate load [kN/m]) of a footing_dem or footing_bsm run folder."""
    with open(os.path.join(run, "history.csv")) as f:
        rows = list(csv.DictReader(f))
    if "settlement_mm" in rows[0]:
        return (np.array([float(r["settlement_mm"]) for r in rows]),
                np.array([float(r["load_kN_per_m"]) for r in rows]))
    return (np.array([1e3 * float(r["settlement_m"]) for r in rows]),
            np.array([1e-3 * float(r["load_N_per_m"]) for r in rows]))


def bsm_settlements_at(run, times):
    """Settlement [mm] of a footing_bsm run at its output times [s], from history.csv (under
    gravity the loading starts after the settling, at the first row's time)."""
    with open(os.path.join(run, "history.csv")) as f:
        rows = list(csv.DictReader(f))
    return np.interp(times, [float(r["time"]) for r in rows], [float(r["settlement_mm"]) for r in rows])


def read_window(run, s1_mm, s2_mm):
    """(position at s1, displacement s1 -> s2, plate_x, surface_y, (s1, s2) actual [mm], kind)
    of a footing_dem run (grains_S.npz) or a footing_bsm run (grains.vtk.series)."""
    with open(os.path.join(run, "summary.json")) as f:
        summary = json.load(f)
    if os.path.exists(os.path.join(run, "grains.vtk.series")):
        from demcell.specimen.files import read_particles_vtk
        with open(os.path.join(run, "grains.vtk.series")) as f:
            files = json.load(f)["files"]
        s = bsm_settlements_at(run, [fr["time"] for fr in files])
        k1, k2 = int(np.argmin(abs(s - s1_mm))), int(np.argmin(abs(s - s2_mm)))
        p0, d0 = read_particles_vtk(os.path.join(run, files[0]["name"]))
        p1, d1 = read_particles_vtk(os.path.join(run, files[k1]["name"]))
        p2, d2 = read_particles_vtk(os.path.join(run, files[k2]["name"]))
        real = d1["virtual"] < 0.5
        ref = p0[real] - d0["displacement"][real]
        r = d0["radius"][real]
        centre = 0.5 * (np.min(ref[:, 0] - r) + np.max(ref[:, 0] + r))    # the region is centred on the plate
        plate_x = (centre - 0.5 * PLATE_WIDTH, centre + 0.5 * PLATE_WIDTH)
        under = (ref[:, 0] + r > plate_x[0]) & (ref[:, 0] - r < plate_x[1])
        # the plate starts on the surface as it was after the settling (surface_drop_mm)
        surface = float(np.max(ref[under, 1] + r[under])) - 1e-3 * float(summary.get("surface_drop_mm", 0.0))
        return p1[real], p2[real] - p1[real], plate_x, surface - s[k1] * 1e-3, (s[k1], s[k2]), "BSM"
    g2 = np.load(os.path.join(run, f"grains_{s2_mm:g}.npz"))
    if s1_mm == 0.0:              # the whole history: from the reference positions
        p1, s1, y1 = g2["reference_position"], 0.0, float(g2["plate_y0"])
    else:
        g1 = np.load(os.path.join(run, f"grains_{s1_mm:g}.npz"))
        p1, s1 = g1["position"], float(g1["settlement"])
        y1 = float(g1["plate_y0"]) - s1
    return p1, g2["position"] - p1, tuple(g2["plate_x"]), y1, (1e3 * s1, 1e3 * float(g2["settlement"])), "DEM"


def strain_map(path, position, strain, inside, plate_x, surface_y, res, title):
    """PNG of eps_eq at the grains of the window, the plate and the two scanned bands."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    p, e = position[inside], strain[inside]
    vmax = float(np.nanpercentile(e, 99)) or 1.0
    fig, ax = plt.subplots(figsize=(8, 4.4))
    sc = ax.scatter(p[:, 0], p[:, 1], c=np.clip(e, 0, vmax), s=2, cmap="viridis", vmin=0, vmax=vmax)
    ax.plot(plate_x, [surface_y, surface_y], "r-", lw=3)
    for side, x_edge, inward in (("left", plate_x[0], 1.0), ("right", plate_x[1], -1.0)):
        band = res["bands"][side]
        phi, x_o = math.radians(band["phi_deg"]), x_edge + inward * band["origin_shift_m"]
        ax.plot([x_o, x_o + 1.2 * inward * math.cos(phi)], [surface_y, surface_y - 1.2 * math.sin(phi)],
                "r--", lw=1)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title, fontsize=8)
    fig.colorbar(sc, ax=ax, label="incremental eps_eq [-]", shrink=0.8)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("runs", nargs="+", help="run folders of footing_dem.py (--snapshots) or footing_bsm.py")
    ap.add_argument("--window", type=float, nargs=2, default=(40.0, 60.0), help="settlements s1 s2 [mm]")
    ap.add_argument("--out", default="footing_bands")
    args = ap.parse_args()
    os.makedirs(args.out, exist_ok=True)
    table = {}
    for run in args.runs:
        name = os.path.basename(os.path.normpath(run))
        position, du, plate_x, surface_y, window, kind = read_window(run, *args.window)
        if window[1] - window[0] < 0.5 * (args.window[1] - args.window[0]):
            print(f"{name}: skipped, its frames cover only {window[0]:.1f}-{window[1]:.1f} mm of the window "
                  f"(a run that stopped early?)")
            continue
        res, strain, inside = analyse(position, du, plate_x, surface_y)
        res.update(kind=kind, window_mm=window, softening=softening(*load_history(run)))
        table[name] = res
        b = res["bands"]
        title = (f"{name} ({kind}): eps_eq {window[0]:.1f}-{window[1]:.1f} mm; left {b['left']['inclination_deg']:.0f} "
                 f"deg {'in' if b['left']['inward'] else 'out'}, right {b['right']['inclination_deg']:.0f} deg "
                 f"{'in' if b['right']['inward'] else 'out'}")
        strain_map(os.path.join(args.out, f"{name}_bands.png"), position, strain, inside, plate_x, surface_y, res,
                   title)
        s = res["softening"]
        print(f"{name:14s} {kind} window {window[0]:.1f}-{window[1]:.1f} mm: left {b['left']['inclination_deg']:.0f} "
              f"({'in' if b['left']['inward'] else 'out'}, x{b['left']['contrast']:.1f}), right "
              f"{b['right']['inclination_deg']:.0f} ({'in' if b['right']['inward'] else 'out'}, "
              f"x{b['right']['contrast']:.1f}), V {b['v_shape']}; fit_band "
              f"{res['fit_band']['left'].get('inclination_deg', float('nan')):.0f} / "
              f"{res['fit_band']['right'].get('inclination_deg', float('nan')):.0f}; peak {s['peak_kN_per_m']:.0f} "
              f"kN/m at {s['peak_at_mm']:.1f} mm, drop {100 * s['drop']:.0f} %", flush=True)
    with open(os.path.join(args.out, "bands.json"), "w") as f:
        json.dump(table, f, indent=1)


if __name__ == "__main__":
    main()
