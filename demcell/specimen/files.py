"""Files of a specimen run that ParaView opens: the discs and their contacts as legacy VTK,
the continuum fields of the grains on a grid as an XDMF time series.

* ``write_particles_vtk``: one binary POLYDATA file of disc centres (z = 0) with point data (radius,
  rotation, velocity and whatever the caller adds: displacement, coordination, the REV fields);
  ParaView opens a numbered family ``particles_0000.vtk, ...`` as a time series.
* ``read_particles_vtk``: the inverse, (position (n, 2), {name: (n,) or (n, 2)}) with radius
  among the point data.
* ``write_contacts_vtk``: one line per touching contact, from centre i to centre j (the
  minimum image across an x-periodic side), normal and tangential force as cell data.
* ``GridSeries``: fields on a regular 2D grid (cell-centred values of a 2DCoRectMesh), one raw
  little-endian float64 file per snapshot and one ``.xdmf`` listing them all, rewritten at each
  snapshot, so an interrupted run leaves a readable series of every completed snapshot.

The VTK files are binary (big-endian, as the legacy format wants): ParaView's ASCII reader
cannot parse "nan" and drops every array after the first invalid REV value; binary keeps NaN
and is a third of the size.
"""
import os

import numpy as np

from .. import checks
from ..errors import InputError


def _atomic_text(path, text):
    """Write `text` to `path` through a temporary file, so a reader never sees half a file."""
    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        f.write(text)
    os.replace(tmp, path)


def _binary(f, array, dtype):
    """`array` as big-endian binary (legacy VTK) and the line break after it."""
    f.write(np.ascontiguousarray(array, dtype=dtype).tobytes())
    f.write(b"\n")


def _point_table(f, name, values, n):
    values = np.asarray(values, dtype=float)
    if values.shape == (n,):
        f.write(f"SCALARS {name} double 1\nLOOKUP_TABLE default\n".encode())
        _binary(f, values, ">f8")
    elif values.shape == (n, 2):
        f.write(f"VECTORS {name} double\n".encode())
        _binary(f, np.column_stack([values, np.zeros(n)]), ">f8")
    else:
        raise InputError(f"point data {name!r} must have shape ({n},) or ({n}, 2), got {values.shape}")


def write_particles_vtk(path, position, radius, point_data=None):
    """Disc centres [m] as VTK vertices with ``radius`` [m] and each array of `point_data`
    ({name: (n,) or (n, 2) array}) as point data. NaN values (an invalid REV) are written as
    they are: ParaView shows them as the NaN colour."""
    position = checks.array("position", position, (None, 2))
    n = position.shape[0]
    radius = checks.array("radius", radius, (n,), checks.POSITIVE)
    tmp = str(path) + ".tmp"
    with open(tmp, "wb") as f:
        f.write(f"# vtk DataFile Version 3.0\ndemcell specimen discs\nBINARY\nDATASET POLYDATA\n"
                f"POINTS {n} double\n".encode())
        _binary(f, np.column_stack([position, np.zeros(n)]), ">f8")
        f.write(f"VERTICES {n} {2 * n}\n".encode())
        _binary(f, np.column_stack([np.ones(n, int), np.arange(n)]), ">i4")
        f.write(f"POINT_DATA {n}\n".encode())
        _point_table(f, "radius", radius, n)
        for name, values in (point_data or {}).items():
            _point_table(f, name, values, n)
    os.replace(tmp, path)
    return str(path)


def read_particles_vtk(path):
    """A file of ``write_particles_vtk``: (position (n, 2) [m], {name: (n,) or (n, 2)}), the
    radius among the point data; the z components dropped."""
    with open(path, "rb") as f:
        raw = f.read()

    def line(at):
        end = raw.index(b"\n", at)
        return raw[at:end].decode().split(), end + 1

    at = 0
    for _ in range(4):
        words, at = line(at)
    words, at = line(at)
    if words[:1] != ["POINTS"]:
        raise InputError(f"{path}: not a file of write_particles_vtk (no POINTS line)")
    n = int(words[1])
    position = np.frombuffer(raw, ">f8", 3 * n, at).reshape(n, 3)[:, :2].astype(float)
    at += 24 * n + 1
    words, at = line(at)
    at += 8 * n + 1                          # VERTICES: 2 n big-endian int32
    words, at = line(at)                     # POINT_DATA n
    data = {}
    while at < len(raw):
        words, at = line(at)
        if words[0] == "SCALARS":
            _, at = line(at)                 # LOOKUP_TABLE
            data[words[1]] = np.frombuffer(raw, ">f8", n, at).astype(float)
            at += 8 * n + 1
        elif words[0] == "VECTORS":
            data[words[1]] = np.frombuffer(raw, ">f8", 3 * n, at).reshape(n, 3)[:, :2].astype(float)
            at += 24 * n + 1
        else:
            raise InputError(f"{path}: unexpected section {words[0]!r}")
    return position, data


def write_contacts_vtk(path, position, pair_i, pair_j, normal_force, tangential_force, periodic_width=0.0):
    """Touching contacts as VTK lines (one per contact given: pass only the touching ones),
    normal and tangential force [N] as cell data. With periodic_width > 0 the line ends at
    the minimum image of j."""
    position = checks.array("position", position, (None, 2))
    pair_i = np.asarray(pair_i, dtype=np.int64)
    pair_j = np.asarray(pair_j, dtype=np.int64)
    m = pair_i.size
    a = position[pair_i]
    d = position[pair_j] - a
    if periodic_width > 0.0:
        d[:, 0] -= periodic_width * np.round(d[:, 0] / periodic_width)
    points = np.zeros((2 * m, 3))
    points[0::2, :2] = a
    points[1::2, :2] = a + d
    tmp = str(path) + ".tmp"
    with open(tmp, "wb") as f:
        f.write(f"# vtk DataFile Version 3.0\ndemcell specimen contacts\nBINARY\nDATASET POLYDATA\n"
                f"POINTS {2 * m} double\n".encode())
        _binary(f, points, ">f8")
        f.write(f"LINES {m} {3 * m}\n".encode())
        _binary(f, np.column_stack([np.full(m, 2), 2 * np.arange(m), 2 * np.arange(m) + 1]), ">i4")
        f.write(f"CELL_DATA {m}\nSCALARS normal_force double 1\nLOOKUP_TABLE default\n".encode())
        _binary(f, np.asarray(normal_force, dtype=float), ">f8")
        f.write(b"SCALARS tangential_force double 1\nLOOKUP_TABLE default\n")
        _binary(f, np.asarray(tangential_force, dtype=float), ">f8")
    os.replace(tmp, path)
    return str(path)


class GridSeries:
    """A time series of cell fields on a regular grid, as XDMF + raw binary (ParaView's
    "XDMF Reader"). Each ``write`` adds a snapshot file ``<stem>_NNNN.bin`` and rewrites
    ``<stem>.xdmf``; a restart that passes the times already written continues the list."""

    def __init__(self, path, origin, spacing, shape, times=()):
        """path: the .xdmf file; origin (x0, y0) [m] of the grid's lower-left corner,
        spacing (dx, dy) [m], shape (nx, ny) cells."""
        self.path = os.fspath(path)
        if not self.path.endswith(".xdmf"):
            raise InputError(f"the grid series must be an .xdmf file, got {self.path}")
        self.origin = checks.array("origin", origin, (2,))
        self.spacing = checks.array("spacing", spacing, (2,), checks.POSITIVE)
        nx, ny = (checks.number("grid cells", s, checks.COUNT) for s in shape)
        self.shape = (nx, ny)
        self.stem = os.path.splitext(os.path.basename(self.path))[0]
        self.snapshots = [(float(t), names) for t, names in times]

    def _data_file(self, index):
        return f"{self.stem}_{index:04d}.bin"

    def write(self, time, fields):
        """Add the snapshot at `time` [s]: fields {name: (ny, nx) array of cell values}."""
        nx, ny = self.shape
        names = list(fields)
        index = len(self.snapshots)
        blob = []
        for name in names:
            values = np.asarray(fields[name], dtype="<f8")
            if values.shape != (ny, nx):
                raise InputError(f"grid field {name!r} must have shape ({ny}, {nx}), got {values.shape}")
            blob.append(np.ascontiguousarray(values))
        directory = os.path.dirname(self.path) or "."
        with open(os.path.join(directory, self._data_file(index)), "wb") as f:
            for values in blob:
                f.write(values.tobytes())
        self.snapshots.append((float(time), names))
        _atomic_text(self.path, self._xml())

    def _xml(self):
        nx, ny = self.shape
        x0, y0 = self.origin
        dx, dy = self.spacing
        grids = []
        for index, (time, names) in enumerate(self.snapshots):
            attributes = []
            for k, name in enumerate(names):
                seek = k * nx * ny * 8
                attributes.append(
                    f'        <Attribute Name="{name}" AttributeType="Scalar" Center="Cell">\n'
                    f'          <DataItem Dimensions="{ny} {nx}" NumberType="Float" Precision="8" Format="Binary" '
                    f'Endian="Little" Seek="{seek}">{self._data_file(index)}</DataItem>\n'
                    f'        </Attribute>\n')
            grids.append(
                f'      <Grid Name="grains" GridType="Uniform">\n'
                f'        <Time Value="{time!r}"/>\n'
                f'        <Topology TopologyType="2DCoRectMesh" Dimensions="{ny + 1} {nx + 1}"/>\n'
                f'        <Geometry GeometryType="ORIGIN_DXDY">\n'
                f'          <DataItem Dimensions="2" NumberType="Float" Format="XML">{y0!r} {x0!r}</DataItem>\n'
                f'          <DataItem Dimensions="2" NumberType="Float" Format="XML">{dy!r} {dx!r}</DataItem>\n'
                f'        </Geometry>\n' + "".join(attributes) + '      </Grid>\n')
        return ('<?xml version="1.0" ?>\n<Xdmf Version="3.0">\n  <Domain>\n'
                '    <Grid Name="series" GridType="Collection" CollectionType="Temporal">\n'
                + "".join(grids) + '    </Grid>\n  </Domain>\n</Xdmf>\n')
