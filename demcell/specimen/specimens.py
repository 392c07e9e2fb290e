"""The grains of a bounded specimen: where the discs are before any loading.

Three sources, each returning a ``Discs`` (positions, radii, masses, inertias and the box the
walls start from):

* ``thesis_lattice``: the specimen of 004 chapter 7 (section 7.4.1, Table 7.1): monodisperse
  discs on a regular triangular grid, rows horizontal, centres exactly 2 r apart (no initial
  overlap; the confining stage makes the overlaps). The text gives 30,000 discs but neither
  the aspect nor the orientation; ``../shared/spec/dns-spec.md`` A1 proposes 114 discs per row
  and 263 rows (29,982 discs, H / W = 1.99), the default here.
* ``tiled_cell``: paper 000's DNS A and B (section 4.2): a periodic FEM x DEM reference cell
  copied nx times across and ny times up, so that the DNS and the FEM x DEM runs share the
  grains and the contact law exactly (dns-spec B3, option T). Discs are kept whole: every disc
  whose centre lies in the tiled rectangle, once.
* ``read_discs``: any packing file: a demcell periodic packing (.npz from ``save_packing``,
  tiled 1 x 1) or a table of discs (.npz with ``position`` and ``radius``, or a text file with
  columns x y r).

2D, per unit out-of-plane depth: masses in kg per metre of depth (density [kg/m^2] times
pi r^2, as 004 Table 7.1 with its 1 m depth), inertias m r^2 / 2 [kg m^2 per m].
"""
import math
import os
import warnings
from dataclasses import dataclass, field

import numpy as np

from .. import checks
from ..checks import POSITIVE, Range
from ..errors import InputError

#: discs a specimen may hold: the engine's arrays for 10^7 discs fill some 10 GB
DISCS = Range(1, 10 ** 7, integer=True)
#: copies of the cell per direction
TILES = Range(1, 1000, integer=True)
#: relative radius noise that breaks the lattice's symmetry (004's bands pick a side)
PERTURBATION = Range(0.0, 0.5, high_open=True)
#: a periodic cell must be this close to a rectangle to be tiled into one (|h01|, |h10| over
#: the widths): the isotropic stage holds F21 and servo-controls F12 to a zero shear stress,
#: which leaves a cell sheared by round-off-level amounts
MAX_CELL_SHEAR = 1.0e-2


@dataclass
class Discs:
    """Discs of a specimen before loading (SI units, per unit depth).

    position (n, 2) [m]; radius, mass [kg/m], inertia [kg m^2/m] (n,);
    box (x_min, x_max, y_min, y_max) [m]: the rectangle the walls start on (a wall sits
    on each face, touching the outermost disc); periodic_width [m]: 0, or the period of
    an x-periodic specimen (its box spans one period); info: where the discs came from."""
    position: np.ndarray
    radius: np.ndarray
    mass: np.ndarray
    inertia: np.ndarray
    box: tuple
    periodic_width: float = 0.0
    info: dict = field(default_factory=dict)

    @property
    def n_discs(self):
        return self.radius.size

    @property
    def width(self):
        return self.box[1] - self.box[0]

    @property
    def height(self):
        return self.box[3] - self.box[2]

    def solid_fraction(self):
        """Area of the discs over the box area [-]."""
        return float(np.pi * np.sum(self.radius ** 2) / (self.width * self.height))


def discs_from(position, radius, density=None, box=None, periodic_width=0.0, info=None, mass=None):
    """A checked ``Discs`` from centres [m], radii [m] and either a density [kg/m^2] (mass =
    density pi r^2 per unit depth) or the masses [kg/m]. box None: the bounding box of the
    discs (walls touching the outermost discs); with periodic_width the box spans
    [box[0], box[0] + periodic_width]."""
    position = checks.array("position", position, (None, 2))
    n = position.shape[0]
    checks.number("number of discs", n, DISCS)
    radius = checks.array("radius", radius, (n,), POSITIVE)
    periodic_width = checks.number("periodic_width", periodic_width, Range(0.0))
    if mass is None:
        mass = checks.number("density", density, POSITIVE) * np.pi * radius ** 2
    else:
        mass = checks.array("mass", mass, (n,), POSITIVE)
    if box is None:
        box = (float(np.min(position[:, 0] - radius)), float(np.max(position[:, 0] + radius)),
               float(np.min(position[:, 1] - radius)), float(np.max(position[:, 1] + radius)))
    box = tuple(float(b) for b in checks.array("box", box, (4,)))
    if not (box[1] > box[0] and box[3] > box[2]):
        raise InputError(f"box must be (x_min, x_max, y_min, y_max) with x_max > x_min and y_max > y_min, got {box}")
    if periodic_width > 0.0:
        if periodic_width < 4.0 * float(np.max(radius)):
            raise InputError(f"periodic_width must be at least 4 disc radii (the minimum image of a contact), "
                             f"got {periodic_width:g} m for radii up to {np.max(radius):g} m")
        box = (box[0], box[0] + periodic_width, box[2], box[3])
    return Discs(position=position.copy(), radius=radius.copy(), mass=mass, inertia=0.5 * mass * radius ** 2,
                 box=box, periodic_width=periodic_width, info=dict(info or {}))


def thesis_lattice(nx=114, ny=263, radius=1.0, density=1.0, perturbation=0.0, seed=0):
    """The 004 chapter 7 specimen: ny horizontal rows of nx equal discs on a triangular grid.

    Row j at y = r + j sqrt(3) r; even rows at x = r + 2 r k, odd rows at x = 2 r + 2 r k
    (k = 0..nx-1): neighbours exactly 2 r apart (dns-spec A1). Width (2 nx + 1) r, height
    2 r + (ny - 1) sqrt(3) r; both lateral faces zig-zag by r. Defaults: Table 7.1 (r = 1 m,
    rho = 1 kg/m^3 with 1 m depth, so m = pi kg) and 114 x 263 = 29,982 discs.

    perturbation eps > 0 scales each radius by (1 - eps u), u uniform in [0, 1) from ``seed``
    (never an overlap), to break the lattice's symmetry; 0 (default) keeps it perfect."""
    nx = checks.number("nx", nx, Range(2, 10 ** 5, integer=True))
    ny = checks.number("ny", ny, Range(2, 10 ** 5, integer=True))
    checks.number("nx * ny", nx * ny, DISCS)
    radius = checks.number("radius", radius, POSITIVE)
    density = checks.number("density", density, POSITIVE)
    perturbation = checks.number("perturbation", perturbation, PERTURBATION)
    seed = checks.number("seed", seed, checks.SEED)
    k = np.arange(nx, dtype=float)
    rows = []
    for j in range(ny):
        x = radius * (1.0 + 2.0 * k + (j % 2))
        rows.append(np.column_stack([x, np.full(nx, radius * (1.0 + j * math.sqrt(3.0)))]))
    position = np.concatenate(rows)
    radii = np.full(nx * ny, radius)
    if perturbation > 0.0:
        radii *= 1.0 - perturbation * np.random.default_rng(seed).random(nx * ny)
    box = (0.0, (2 * nx + 1) * radius, 0.0, radius * (2.0 + (ny - 1) * math.sqrt(3.0)))
    info = {"source": "004 chapter 7 triangular lattice", "nx": nx, "ny": ny, "radius": radius,
            "density": density, "perturbation": perturbation, "seed": seed}
    return discs_from(position, radii, density, box=box, info=info)


def _cell_arrays(cell_state):
    """(h, s in [0, 1), radius, mass, inertia) of a demcell CellState, refused in one line if
    the cell is too sheared to tile into a rectangle."""
    from ..state import CellState
    checks.instance("cell_state", cell_state, CellState)
    h = np.asarray(cell_state.h, dtype=float)
    shear = max(abs(h[0, 1]) / abs(h[0, 0]), abs(h[1, 0]) / abs(h[1, 1]))
    if not shear <= MAX_CELL_SHEAR:
        raise InputError(f"the cell is sheared by {shear:.3g} (|h01|/h00 or |h10|/h11); a cell tiles into a "
                         f"rectangular specimen only when this is <= {MAX_CELL_SHEAR:g}")
    return h, np.mod(cell_state.s, 1.0), cell_state.radius, cell_state.mass, cell_state.inertia


def tiled_cell(cell_state, nx, ny, periodic_sides=False):
    """Paper 000's DNS from a periodic cell: the cell tiled nx across and ny up (000 section
    4.2: DNS A is 1 x 2, DNS B 2 x 4; dns-spec B3 option T).

    Every disc keeps its radius, mass and inertia; disc k of tile (a, b) sits at
    h (s_k + (a, b)), so the contacts across tile borders are exactly the cell's periodic
    contacts. The box is the tiled rectangle of the cell's widths (h00, h11): discs near its
    faces stick out of it by up to a radius, and the walls are put on the outermost discs
    (bounding box) unless periodic_sides, when x is periodic with period nx h00 (the 1 x 1
    tiling with periodic sides is the stand-alone cell bounded by platens)."""
    nx = checks.number("nx", nx, TILES)
    ny = checks.number("ny", ny, TILES)
    h, s, radius, mass, inertia = _cell_arrays(cell_state)
    n_cell = radius.size
    checks.number("discs of the tiling (nx * ny * discs per cell)", nx * ny * n_cell, DISCS)
    tiles = [(a, b) for b in range(ny) for a in range(nx)]
    position = np.concatenate([(s + np.array([a, b], dtype=float)) @ h.T for a, b in tiles])
    radii = np.tile(radius, nx * ny)
    masses = np.tile(mass, nx * ny)
    inertias = np.tile(inertia, nx * ny)
    if periodic_sides:
        period = nx * h[0, 0]
        box = (0.0, period, float(np.min(position[:, 1] - radii)), float(np.max(position[:, 1] + radii)))
    else:
        period = 0.0
        box = (float(np.min(position[:, 0] - radii)), float(np.max(position[:, 0] + radii)),
               float(np.min(position[:, 1] - radii)), float(np.max(position[:, 1] + radii)))
    info = {"source": "tiled periodic cell", "tiles": [nx, ny], "discs_per_cell": int(n_cell),
            "cell_widths": [float(h[0, 0]), float(h[1, 1])], "periodic_sides": bool(periodic_sides)}
    return Discs(position=position, radius=radii.copy(), mass=masses.copy(), inertia=inertias.copy(),
                 box=box, periodic_width=period, info=info)


def read_discs(path, density=None, tiles=(1, 1), periodic_sides=False):
    """Discs from a packing file, refused in one line if it is missing, empty or damaged.

    * a demcell periodic packing (.npz written by ``demcell.save_packing``, e.g. by
      demos/dem_cell.py): tiled ``tiles`` = (nx, ny) times (``tiled_cell``);
    * a table of discs: .npz with arrays ``position`` (n, 2) and ``radius`` (n,) (and ``mass``
      (n,) or a ``density``), or a text file with columns x y r [m] (``#`` comments);
      ``density`` [kg/m^2] is then needed unless the file has masses."""
    from ..io import load_packing
    if isinstance(path, (bool, int)) or not isinstance(path, (str, os.PathLike)):
        raise InputError(f"the packing must be a file path, got {type(path).__name__}")
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise InputError(f"packing file not found: {path}")
    if os.path.getsize(path) == 0:
        raise InputError(f"packing file {path} is empty")
    if path.endswith(".npz"):
        try:
            with np.load(path, allow_pickle=False) as z:
                names = set(z.files)
                table = {k: z[k] for k in ("position", "radius", "mass", "density") if k in names}
        except Exception as error:   # zipfile, zlib, numpy format errors: one line, the cause named
            raise InputError(f"packing file {path} cannot be read: {checks.one_line(error)}") from None
        if "demcell_packing_version" in names:
            state, _info = load_packing(path)
            nx, ny = (checks.number("tiles", t, TILES) for t in tiles)
            discs = tiled_cell(state, nx, ny, periodic_sides=periodic_sides)
            discs.info["file"] = path
            return discs
        if "position" not in table or "radius" not in table:
            raise InputError(f"packing file {path} holds neither a demcell packing nor the arrays 'position' "
                             f"and 'radius' (it has: {', '.join(sorted(names)) or 'nothing'})")
    else:
        try:
            with warnings.catch_warnings():   # an empty table is refused below, in our words
                warnings.simplefilter("ignore", UserWarning)
                rows = np.loadtxt(path, ndmin=2, comments="#")
        except (ValueError, UnicodeDecodeError) as error:
            raise InputError(f"packing file {path} is not a table of x y r: {checks.one_line(error)}") from None
        if rows.size == 0 or rows.shape[1] != 3:
            raise InputError(f"packing file {path} must hold rows of 3 columns x y r, got "
                             f"{'no rows' if rows.size == 0 else f'{rows.shape[1]} columns'}")
        table = {"position": rows[:, :2], "radius": rows[:, 2]}
    info = {"source": "packing file", "file": path}
    if "mass" in table:
        return discs_from(table["position"], table["radius"], mass=table["mass"], info=info)
    if density is None and "density" in table:
        density = float(table["density"])
    if density is None:
        raise InputError(f"packing file {path} has no masses: give the grain density [kg/m^2]")
    return discs_from(table["position"], table["radius"], density, info=info)


def rotated_square_lattice(box, radius, density):
    """003's packings A and B (section 3: r = 0.05 m and 0.03 m): equal discs on a square
    lattice rotated by 45 degrees, so that every contact normal lies at +-45 degrees to the
    horizontal and every interior disc has 4 neighbours exactly 2 r away (no overlap).

    Rows are sqrt(2) r apart, the discs of a row 2 sqrt(2) r apart, every other row shifted by
    sqrt(2) r; the first row and the first column touch the lower and left faces of box =
    (x_min, x_max, y_min, y_max) [m], and every disc lies wholly inside it. density [kg/m^2]:
    mass rho pi r^2 per unit depth (003 Table 1: 2600 kg/m^3 with 1 m depth)."""
    box = tuple(float(b) for b in checks.array("box", box, (4,)))
    radius = checks.number("radius", radius, POSITIVE)
    density = checks.number("density", density, POSITIVE)
    x0, x1, y0, y1 = box
    a = math.sqrt(2.0) * radius
    if not (x1 - x0 >= 2.0 * radius + a and y1 - y0 >= 2.0 * radius + a):
        raise InputError(f"box {box} is too small for a rotated square lattice of radius {radius:g} m "
                         f"(at least {2.0 * radius + a:.3g} m each way)")
    ny = int(math.floor((y1 - y0 - 2.0 * radius) / a + 1e-9)) + 1
    rows = []
    for j in range(ny):
        xs = np.arange(x0 + radius + (j % 2) * a, x1 - radius + 1e-9 * radius, 2.0 * a)
        rows.append(np.column_stack([xs, np.full(xs.size, y0 + radius + j * a)]))
    position = np.concatenate(rows)
    checks.number("number of discs", position.shape[0], DISCS)
    info = {"source": "square lattice rotated 45 degrees (003 packings A/B)", "radius": radius, "rows": ny,
            "density": density}
    return discs_from(position, np.full(position.shape[0], radius), density, box=box, info=info)


def random_dense(box, r_min, r_max, density, n_cell=600, seed=0, law=None):
    """003's packing C (section 3: random, r = 0.02-0.05 m): radii uniform in [r_min, r_max]
    [m], filling box = (x_min, x_max, y_min, y_max) [m] densely.

    003 uses Bagi's inward packing (not available here). Instead a periodic cell of n_cell
    discs is compacted isotropically without friction (demcell.packing.generate_packing, to
    1e-4 kn, overlaps of about 2e-4 radii) and tiled over the box (``tiled_cell``); the discs
    lying wholly inside the box are kept. The packing therefore repeats with the cell's
    period (about sqrt(n_cell) mean diameters), and the discs cut at the box's faces leave
    gaps of up to a diameter against the walls. Masses from density [kg/m^2] times pi r^2."""
    from ..contact_law import ContactLaw
    from ..packing import generate_packing
    box = tuple(float(b) for b in checks.array("box", box, (4,)))
    r_min = checks.number("r_min", r_min, POSITIVE)
    r_max = checks.number("r_max", r_max, POSITIVE)
    if not r_max >= r_min:
        raise InputError(f"random_dense needs r_max >= r_min, got {r_min:g}, {r_max:g} m")
    density = checks.number("density", density, POSITIVE)
    law = ContactLaw(kn=2.5e8, ks=5.0e7, friction=0.5) if law is None else law
    cell, cell_info = generate_packing(n_particles=n_cell, pressure=1e-4 * law.kn, law=law, r_min=r_min,
                                       radius_ratio=r_max / r_min, seed=seed, density=density)
    # the cell tiled by its own lattice vectors (exact for a slightly sheared cell too) over a
    # range of copies that covers the box, then cut to the discs wholly inside it
    h = np.asarray(cell.h, dtype=float)
    frac = np.mod(np.asarray(cell.s, dtype=float), 1.0)
    corners = np.array([[box[0], box[2]], [box[1], box[2]], [box[0], box[3]], [box[1], box[3]]])
    span = corners @ np.linalg.inv(h).T
    a0, b0 = np.floor(span.min(axis=0)).astype(int) - 1
    a1, b1 = np.ceil(span.max(axis=0)).astype(int) + 1
    checks.number("discs of the tiling", (a1 - a0) * (b1 - b0) * frac.shape[0], DISCS)
    pos = np.concatenate([(frac + np.array([a, b], dtype=float)) @ h.T
                          for b in range(b0, b1) for a in range(a0, a1)])
    r = np.tile(np.asarray(cell.radius, dtype=float), (a1 - a0) * (b1 - b0))
    inside = ((pos[:, 0] - r >= box[0]) & (pos[:, 0] + r <= box[1]) & (pos[:, 1] - r >= box[2])
              & (pos[:, 1] + r <= box[3]))
    info = {"source": "tiled periodic cell compacted without friction (003 packing C stand-in)",
            "r_min": r_min, "r_max": r_max, "n_cell": int(n_cell), "seed": int(seed), "density": density,
            "cell_solid_fraction": float(cell_info["solid_fraction"]),
            "cell_h": h.tolist()}
    return discs_from(pos[inside], r[inside], density, box=box, info=info)
