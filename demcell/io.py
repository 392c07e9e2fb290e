"""Files: packings (.npz), particle / contact snapshots for ParaView (legacy VTK, ASCII),
and a CSV writer that flushes every row (results are written as the run goes)."""
import csv
import json
import os
import zipfile

import numpy as np

from .errors import InputError
from .periodic_cell import branch_vector
from .state import CellState

PACKING_VERSION = 1


def save_packing(path, state, info=None):
    """Save a CellState (positions, radii, cell, contact history) and an info dict (.npz)."""
    d = state.to_dict()
    d["demcell_packing_version"] = np.array(PACKING_VERSION)
    d["info_json"] = np.array(json.dumps(info or {}))
    np.savez_compressed(path, **d)


def load_packing(path):
    """Load (state, info) written by ``save_packing``; clear error if missing or not a packing."""
    if not os.path.isfile(path):
        raise InputError(f"packing file not found: {path}")
    try:
        with np.load(path, allow_pickle=False) as z:
            if "demcell_packing_version" not in z.files:
                raise InputError(f"{path} is not a demcell packing file")
            d = {k: z[k] for k in z.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as e:
        raise InputError(f"cannot read packing file {path} (not a readable .npz archive: {e})") from None
    try:
        info = json.loads(str(d.pop("info_json")))
        d.pop("demcell_packing_version")
        state = CellState.from_dict(d).check()
    except KeyError as e:
        raise InputError(f"packing file {path} lacks the array {e}") from None
    except (ValueError, TypeError) as e:
        raise InputError(f"packing file {path} is inconsistent: {e}") from None
    return state, info


def write_vtk_snapshot(directory, index, state):
    """Write ``particles_NNNN.vtk`` (centres with radius, rotation, velocity) and
    ``contacts_NNNN.vtk`` (one line per contact, from centre i to the image of centre j,
    with normal and tangential force as cell data) in ``directory``. Legacy ASCII VTK
    POLYDATA, z = 0; ParaView opens each numbered family as a time series."""
    os.makedirs(directory, exist_ok=True)
    p_path = os.path.join(directory, f"particles_{index:04d}.vtk")
    c_path = os.path.join(directory, f"contacts_{index:04d}.vtk")
    x = state.positions()
    n = state.n_particles
    with open(p_path, "w") as f:
        f.write("# vtk DataFile Version 3.0\ndemcell particles\nASCII\nDATASET POLYDATA\n")
        f.write(f"POINTS {n} double\n")
        np.savetxt(f, np.column_stack([x, np.zeros(n)]), fmt="%.9e")
        f.write(f"VERTICES {n} {2 * n}\n")
        np.savetxt(f, np.column_stack([np.ones(n, int), np.arange(n)]), fmt="%d")
        f.write(f"POINT_DATA {n}\nSCALARS radius double 1\nLOOKUP_TABLE default\n")
        np.savetxt(f, state.radius, fmt="%.9e")
        f.write("SCALARS rotation double 1\nLOOKUP_TABLE default\n")
        np.savetxt(f, state.theta, fmt="%.9e")
        f.write("VECTORS velocity double\n")
        np.savetxt(f, np.column_stack([state.v, np.zeros(n)]), fmt="%.9e")
    idx = [k for k in range(state.n_pairs) if state.touching[k]]
    m = len(idx)
    pts = np.zeros((2 * m, 3))
    for q, k in enumerate(idx):
        i, j = int(state.pair_i[k]), int(state.pair_j[k])
        dx, dy = branch_vector(state.h, state.s, i, j)
        pts[2 * q, :2] = x[i]
        pts[2 * q + 1, :2] = x[i] + (dx, dy)
    with open(c_path, "w") as f:
        f.write("# vtk DataFile Version 3.0\ndemcell contact network\nASCII\nDATASET POLYDATA\n")
        f.write(f"POINTS {2 * m} double\n")
        np.savetxt(f, pts, fmt="%.9e")
        f.write(f"LINES {m} {3 * m}\n")
        np.savetxt(f, np.column_stack([np.full(m, 2), 2 * np.arange(m), 2 * np.arange(m) + 1]), fmt="%d")
        f.write(f"CELL_DATA {m}\nSCALARS normal_force double 1\nLOOKUP_TABLE default\n")
        np.savetxt(f, state.fn[idx], fmt="%.9e")
        f.write("SCALARS tangential_force double 1\nLOOKUP_TABLE default\n")
        np.savetxt(f, state.fs[idx], fmt="%.9e")
    return p_path, c_path


class CsvLog:
    """CSV file written row by row (flushed), so a run that stops leaves its history."""

    def __init__(self, path, columns):
        self.columns = list(columns)
        self._f = open(path, "w", newline="")
        self._w = csv.writer(self._f)
        self._w.writerow(self.columns)
        self._f.flush()

    def write(self, **row):
        self._w.writerow([row[c] for c in self.columns])
        self._f.flush()

    def close(self):
        self._f.close()
