"""Files: packings (.npz), particle / contact snapshots for ParaView (legacy VTK, ASCII),
and a CSV writer that flushes every row (results are written as the run goes)."""
import csv
import json
import os
import zipfile
import zlib

import numpy as np

from . import checks
from .errors import InputError
from .periodic_cell import branch_vector
from .state import DTYPES, FLAG_FIELDS, CellState

#: format of the packing files save_packing writes; load_packing reads versions 1 to this one
PACKING_VERSION = 1
#: the fields of a packing file: kinds of dtype (numpy's dtype.kind letters) and shape, "n"
#: the particles (the length of radius), "m" the pair slots (the length of pair_i)
PACKING_FIELDS = {
    **{name: ("f", ("n",)) for name in ("radius", "mass", "inertia", "theta", "omega", "dtheta", "moment")},
    **{name: ("f", ("n", 2)) for name in ("s", "v", "force", "s_build")},
    **{name: ("f", (2, 2)) for name in ("h", "h_build", "h_ref")},
    "pair_i": ("iu", ("m",)), "pair_j": ("iu", ("m",)), "fn": ("f", ("m",)), "fs": ("f", ("m",)),
    "mr": ("f", ("m",)), "bonded": ("biu", ("m",)), "touching": ("biu", ("m",)), "d_prev": ("f", ("m", 2)),
    "n_pairs": ("iu", ()), "forces_current": ("biu", ()), "time": ("fiu", ()), "phi": ("fiu", ()),
    "kappa": ("f", (2,)), "demcell_packing_version": ("iu", ()), "info_json": ("U", ()),
}
#: fields a packing written before the micropolar cell existed lacks (CellState.from_dict)
OPTIONAL_FIELDS = ("phi", "kappa")
KIND_WORDS = {"f": "floats", "iu": "integers", "biu": "flags", "fiu": "a number", "U": "a text"}
#: pair slots per particle a packing may carry (a few contacts and neighbours each in practice)
MAX_PAIRS_PER_PARTICLE = 100


def _path(path, what="path"):
    """`path` as a str (a str or an os.PathLike), else InputError."""
    if isinstance(path, (bool, int)) or not isinstance(path, (str, os.PathLike)):
        raise InputError(f"{what} must be a file path (str or os.PathLike), got {type(path).__name__}")
    return os.fspath(path)


def save_packing(path, state, info=None):
    """Save a CellState (positions, radii, cell, contact history) and an info dict (.npz)."""
    path = _path(path)
    checks.instance("state", state, CellState)
    state.check()
    if info is not None:
        checks.instance("info", info, dict)
    try:
        info_json = json.dumps(info or {})
    except (TypeError, ValueError) as e:
        raise InputError(f"info must be a dict of JSON values: {checks.one_line(e)}") from None
    d = state.to_dict()
    d["demcell_packing_version"] = np.array(PACKING_VERSION)
    d["info_json"] = np.array(info_json)
    np.savez_compressed(path, **d)


class _Damaged(Exception):
    """A field of a packing file that cannot be used (the message names it)."""


def _header(zf, member):
    """(shape, dtype) of an .npy member of an open zip archive, read from its header only."""
    with zf.open(member) as f:
        version = np.lib.format.read_magic(f)
        if version == (1, 0):
            shape, _, dtype = np.lib.format.read_array_header_1_0(f)
        elif version == (2, 0):
            shape, _, dtype = np.lib.format.read_array_header_2_0(f)
        else:
            raise _Damaged(f"an .npy header of version {version}")
        header_end = f.tell()
    if not dtype.hasobject:
        # a header that announces more data than the member holds would allocate it first
        announced = int(np.prod(shape, dtype=np.float64)) * dtype.itemsize
        held = zf.getinfo(member).file_size - header_end
        if announced > held:
            raise _Damaged(f"its header announces {announced} bytes of data, the archive holds {held}")
    return shape, dtype


def _expected_shape(spec, n, m):
    return tuple(n if d == "n" else m if d == "m" else d for d in spec)


def load_packing(path):
    """Load (state, info) written by ``save_packing``. A missing file, an archive that cannot
    be read (truncated, not a zip), a file of a newer format, a field missing, unknown, of the
    wrong dtype or shape, or values a packing cannot have (radii <= 0, non-finite positions,
    a cell matrix with det <= 0, ...) are refused in one line naming the file and the field."""
    path = _path(path)
    if not os.path.isfile(path):
        raise InputError(f"packing file not found: {path}")
    field = None
    try:
        with zipfile.ZipFile(path) as zf:
            members = {name[:-4]: name for name in zf.namelist() if name.endswith(".npy")}
            if "demcell_packing_version" not in members:
                raise InputError(f"{path} is not a demcell packing file (no field 'demcell_packing_version')")
            field = "demcell_packing_version"
            shape, dtype = _header(zf, members[field])
            if shape != () or dtype.hasobject or dtype.kind not in "iu":
                raise _Damaged(f"a {dtype} array of shape {shape}, not an integer")
            version = int(_read(zf, members, field))
            if version > PACKING_VERSION:
                raise InputError(f"packing file {path} has format version {version}; this demcell reads versions "
                                 f"1 to {PACKING_VERSION} (a newer demcell wrote it)")
            if version < 1:
                raise _Damaged(f"{version}, not a format version (1 to {PACKING_VERSION})")
            field = None
            for name in members:
                if name not in PACKING_FIELDS:
                    raise InputError(f"packing file {path} has an unknown field {name!r} (format version {version})")
            for name in PACKING_FIELDS:
                if name not in members and name not in OPTIONAL_FIELDS:
                    raise InputError(f"packing file {path} lacks the field {name!r}")
            headers = {}
            for field in members:
                headers[field] = _header(zf, members[field])
            field = None
            n = headers["radius"][0][0] if len(headers["radius"][0]) == 1 else -1
            m = headers["pair_i"][0][0] if len(headers["pair_i"][0]) == 1 else -1
            if not 1 <= n <= 10 ** 6:
                raise InputError(f"packing file {path}: field 'radius' has shape {headers['radius'][0]}, expected "
                                 "(n,) with 1 <= n <= 1e6 particles")
            if not 0 <= m <= MAX_PAIRS_PER_PARTICLE * n + 64:
                raise InputError(f"packing file {path}: field 'pair_i' has shape {headers['pair_i'][0]}, expected "
                                 f"(m,) with m <= {MAX_PAIRS_PER_PARTICLE} n + 64 pair slots")
            for name, (shape, dtype) in headers.items():
                kinds, spec = PACKING_FIELDS[name]
                if dtype.hasobject or dtype.kind not in kinds:
                    raise InputError(f"packing file {path}: field {name!r} has dtype {dtype}, expected "
                                     f"{KIND_WORDS[kinds]}")
                expected = _expected_shape(spec, n, m)
                if tuple(shape) != expected:
                    raise InputError(f"packing file {path}: field {name!r} has shape {tuple(shape)}, expected "
                                     f"{expected}")
            d = {}
            for field in members:
                d[field] = _read(zf, members, field)
            field = None
    except _Damaged as e:
        raise InputError(f"packing file {path}: field {field!r} is damaged: {checks.one_line(e)}") from None
    except (OSError, EOFError, ValueError, zipfile.BadZipFile, zlib.error, KeyError, IndexError, TypeError,
            UnicodeDecodeError, OverflowError, NotImplementedError, RuntimeError) as e:
        # (zipfile: NotImplementedError for an unknown compression or zip version, RuntimeError
        # for an encrypted member)
        if isinstance(e, InputError):
            raise
        where = f" (field {field!r})" if field else ""
        raise InputError(f"cannot read packing file {path}{where}: not a readable .npz archive "
                         f"({type(e).__name__}: {checks.one_line(e)})") from None
    try:
        info = json.loads(str(d.pop("info_json")))
    except ValueError as e:
        raise InputError(f"packing file {path}: field 'info_json' is not JSON ({checks.one_line(e)})") from None
    if not isinstance(info, dict):
        raise InputError(f"packing file {path}: field 'info_json' is not a JSON object")
    d.pop("demcell_packing_version")
    if not 0 <= int(d["n_pairs"]) <= m:
        # (CellState.from_dict would make room for them: n_pairs slots of zeros)
        raise InputError(f"packing file {path}: field 'n_pairs' = {int(d['n_pairs'])} outside [0, {m}] "
                         "(the pair arrays' length)")
    for name, a in d.items():
        kinds = PACKING_FIELDS[name][0]
        if name in FLAG_FIELDS and not np.isin(a, (0, 1)).all():
            # (before the conversion to uint8, which would wrap 256 to 0)
            raise InputError(f"packing file {path}: field {name!r} must hold flags 0 or 1")
        if name in DTYPES:
            d[name] = a.astype(DTYPES[name])      # e.g. float32 from a foreign writer
        elif kinds == "fiu":
            d[name] = a.astype(np.float64)
    try:
        state = CellState.from_dict(d).check()
    except InputError as e:
        raise InputError(f"packing file {path}: {checks.one_line(e)}") from None
    return state, info


def _read(zf, members, field):
    """The array `field` of an open packing archive (no pickles)."""
    with zf.open(members[field]) as f:
        return np.lib.format.read_array(f, allow_pickle=False)


def write_vtk_snapshot(directory, index, state):
    """Write ``particles_NNNN.vtk`` (centres with radius, rotation, velocity) and
    ``contacts_NNNN.vtk`` (one line per contact, from centre i to the image of centre j,
    with normal and tangential force as cell data) in ``directory``. Legacy ASCII VTK
    POLYDATA, z = 0; ParaView opens each numbered family as a time series."""
    directory = _path(directory, "directory")
    index = checks.number("index", index, checks.Range(0, 10 ** 9, integer=True))
    checks.instance("state", state, CellState)
    state.check()
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

    def __init__(self, path, columns, kept_rows=()):
        """kept_rows: rows (lists of values, in the order of `columns`) written after the
        header before any new one: what a restarted run keeps of its earlier file."""
        self.columns = list(columns)
        self._f = open(path, "w", newline="")
        self._w = csv.writer(self._f)
        self._w.writerow(self.columns)
        for row in kept_rows:
            self._w.writerow(row)
        self._f.flush()

    def write(self, **row):
        self._w.writerow([row[c] for c in self.columns])
        self._f.flush()

    def close(self):
        self._f.close()
