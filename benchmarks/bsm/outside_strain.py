"""How much the grains around the DEM region deform, against the continuum that replaces them
in the bridging-scale footing: per 1 m element outside the region, the incremental
equivalent strain over a settlement window of the full DEM (the mean of the grains' patch
gradients in the element, footing_bands.equivalent_strain) and of the BSM's continuum (the
Q1 gradient at the element's centre, from continuum.xdmf), and their ratio of means.

    PYTHONPATH=. python3 benchmarks/bsm/outside_strain.py DEM_RUN BSM_RUN --window 5 20

DEM_RUN: benchmarks/dns/footing_dem.py with --snapshots S1 S2; BSM_RUN: demos/footing_bsm.py
on the default Q1 mesh of 1 m elements (a frame's settlement from history.csv). The region is
read from the BSM run's summary.json.
"""
import argparse
import json
import os

import h5py
import numpy as np

from benchmarks.bsm.footing_bands import bsm_settlements_at, equivalent_of_gradient, equivalent_strain, read_window


def continuum_increment(run, s1, s2):
    """(node coordinates (n, 2), displacement increment (n, 2), (s1, s2) of the frames [mm])."""
    with h5py.File(os.path.join(run, "continuum.h5"), "r") as f:
        x = f["Mesh/mesh/geometry"][:, :2]
        keys = list(f["Function/u"].keys())
        times = np.array([float(k.replace("_", ".")) for k in keys])
        s = bsm_settlements_at(run, times)
        k1, k2 = int(np.argmin(abs(s - s1))), int(np.argmin(abs(s - s2)))
        du = f["Function/u"][keys[k2]][:, :2] - f["Function/u"][keys[k1]][:, :2]
    return x, du, (float(s[k1]), float(s[k2]))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dem_run")
    ap.add_argument("bsm_run")
    ap.add_argument("--window", type=float, nargs=2, default=[5.0, 20.0], metavar=("S1", "S2"))
    args = ap.parse_args()
    with open(os.path.join(args.bsm_run, "summary.json")) as f:
        box = json.load(f)["region"]["box"]
    x, du, frames = continuum_increment(args.bsm_run, *args.window)
    p, d, _, _, dem_window, _ = read_window(args.dem_run, *args.window)
    gradient = np.nan_to_num(equivalent_strain(p, d)[1])

    def node(xx, yy):
        return int(np.argmin(np.hypot(x[:, 0] - xx, x[:, 1] - yy)))

    width, height = int(round(x[:, 0].max())), int(round(x[:, 1].max()))
    rows = []
    for i in range(width):
        for j in range(height):
            if box[0] <= i < box[1] and box[2] <= j < box[3]:
                continue
            a, b, c, e = node(i, j), node(i + 1, j), node(i + 1, j + 1), node(i, j + 1)
            centre = np.column_stack([0.5 * ((du[b] - du[a]) + (du[c] - du[e])),
                                      0.5 * ((du[e] - du[a]) + (du[c] - du[b]))])
            grains = (p[:, 0] >= i) & (p[:, 0] < i + 1) & (p[:, 1] >= j) & (p[:, 1] < j + 1)
            if grains.any():
                rows.append((i, j, equivalent_of_gradient(gradient[grains].mean(axis=0)[None])[0],
                             equivalent_of_gradient(centre[None])[0]))
    rows = np.array(rows)
    ring = ((rows[:, 0] >= box[0] - 2) & (rows[:, 0] < box[1] + 2) & (rows[:, 1] >= box[2] - 2))
    print(f"window: full DEM {dem_window[0]:.1f}-{dem_window[1]:.1f} mm, BSM frames {frames[0]:.1f}-{frames[1]:.1f} mm")
    for name, sel in (("elements within 2 m of the region", ring), ("every element outside the region", slice(None))):
        r = rows[sel]
        print(f"{name}: {len(r)}, mean eps_eq full DEM {r[:, 2].mean():.3g}, continuum {r[:, 3].mean():.3g}, "
              f"ratio {r[:, 2].mean() / r[:, 3].mean():.2f}")


if __name__ == "__main__":
    main()
