"""The DEM region of the bridging-scale method (003 section 1.3, Fig 1): a rectangle of
whole finite elements, the real grains inside it, and one layer of virtual interface grains
just outside its interface Gamma_I with the continuum.

- Real grains: centre inside the rectangle Omega_D (closed). Their motion is the DEM's.
- Virtual grains (003 eq 17): centre outside Omega_D but inside the domain, within
  `layer_width` of Omega_D, and not beyond an edge of Omega_D that lies on the domain
  boundary (Gamma_A, the free or loaded surface: "no virtual particles are needed there").
  Their motion is interpolated from the continuum and prescribed to the DEM. Two rules:
  layer="touching" (lattices A/B: the next rows and columns, i.e. the outside grains in
  contact with a real one, gap <= `touch_tolerance` r), layer="diameter" (random packings:
  every outside grain whose centre is within one maximum diameter of Omega_D).
- Contacts among virtual grains are left to the continuum (the coupler drops their forces).

`region_cells(mesh, box)` (dolfinx) returns the local cells of Omega_D and refuses a
rectangle that does not coincide with whole elements. Positions in m, masses in kg per m
of depth, rotary inertias in kg m^2 per m.
"""
from dataclasses import dataclass

import numpy as np
import scipy.spatial

from cosserat_fenicsx.validation import InputError

EDGES = ("bottom", "top", "left", "right")


def _box(box, name):
    box = np.asarray(box, dtype=float)
    if box.shape != (4,) or not np.all(np.isfinite(box)) or not (box[1] > box[0] and box[3] > box[2]):
        raise InputError(f"{name} must be (x_min, x_max, y_min, y_max) with x_max > x_min and "
                         f"y_max > y_min, got {tuple(box)}")
    return box


def distance_outside(position, box):
    """Euclidean distance [m] of points (n, 2) from the rectangle box (0 inside)."""
    dx = np.maximum(np.maximum(box[0] - position[:, 0], position[:, 0] - box[1]), 0.0)
    dy = np.maximum(np.maximum(box[2] - position[:, 1], position[:, 1] - box[3]), 0.0)
    return np.hypot(dx, dy)


@dataclass
class DemRegion:
    """Grains of the DEM region, real ones first (indices 0..n_real-1), then the virtual
    layer. box (x_min, x_max, y_min, y_max) [m]; free_edges: the edges of the box on the
    domain boundary (no virtual grains beyond them); layer_width [m]."""
    box: np.ndarray
    position: np.ndarray
    radius: np.ndarray
    mass: np.ndarray
    inertia: np.ndarray
    n_real: int
    free_edges: tuple
    layer_width: float

    @property
    def n_discs(self):
        return self.radius.size

    @property
    def n_virtual(self):
        return self.n_discs - self.n_real

    @property
    def real(self):
        return slice(0, self.n_real)

    @property
    def virtual(self):
        return slice(self.n_real, self.n_discs)

    @property
    def is_virtual(self):
        mask = np.zeros(self.n_discs, dtype=bool)
        mask[self.n_real:] = True
        return mask

    def escaped(self, position, margin=None):
        """Indices of real grains whose centre (current `position` of the real grains,
        (n_real, 2)) is more than `margin` (default one maximum diameter) outside Omega_D:
        grains that have left the region, where the projection no longer holds."""
        margin = self.escape_margin() if margin is None else margin
        position = np.asarray(position)
        x0, x1, y0, y1 = self.safe_box(margin)
        if position.size and (position[:, 0].min() >= x0 and position[:, 0].max() <= x1
                              and position[:, 1].min() >= y0 and position[:, 1].max() <= y1):
            return np.zeros(0, dtype=np.int64)
        return np.flatnonzero(distance_outside(position, self.box) > margin)

    def escape_margin(self):
        """The distance outside Omega_D [m] beyond which a grain has left it: one maximum diameter."""
        return 2.0 * float(self.radius.max())

    def safe_box(self, margin=None):
        """(x0, x1, y0, y1) [m]: Omega_D grown by 0.7 margin (< margin / sqrt(2)) on each side;
        no centre inside it lies more than margin outside Omega_D (the cheap test of a step)."""
        grow = 0.7 * (self.escape_margin() if margin is None else margin)
        box = self.box
        return box[0] - grow, box[1] + grow, box[2] - grow, box[3] + grow

    def summary(self):
        return {"box": [float(v) for v in self.box], "real": int(self.n_real),
                "virtual": int(self.n_virtual), "free_edges": list(self.free_edges),
                "layer_width": float(self.layer_width),
                "solid_fraction": float(np.sum(np.pi * self.radius[:self.n_real] ** 2)
                                        / ((self.box[1] - self.box[0]) * (self.box[3] - self.box[2])))}


def build_region(position, radius, mass, inertia, box, domain, layer="touching",
                 touch_tolerance=1e-6):
    """Split a packing that covers Omega_D and its surroundings into real and virtual grains.

    position (n, 2), radius, mass, inertia (n,): the packing (any extent; grains away from
    Omega_D are dropped); box: Omega_D; domain: the continuum's bounding rectangle (edges of
    Omega_D on it are free: Gamma_A). layer: "touching" or "diameter" (module docstring)."""
    box, domain = _box(box, "DEM region"), _box(domain, "domain")
    position = np.asarray(position, dtype=float)
    radius, mass, inertia = (np.asarray(a, dtype=float) for a in (radius, mass, inertia))
    n = radius.size
    if position.shape != (n, 2) or mass.shape != (n,) or inertia.shape != (n,):
        raise InputError(f"DEM region: position must be (n, 2) and radius, mass, inertia (n,), "
                         f"got {position.shape}, {radius.shape}, {mass.shape}, {inertia.shape}")
    if layer not in ("touching", "diameter"):
        raise InputError(f"DEM region: layer must be 'touching' or 'diameter', got {layer!r}")
    if np.any(box[[0, 2]] < domain[[0, 2]] - 1e-12) or np.any(box[[1, 3]] > domain[[1, 3]] + 1e-12):
        raise InputError(f"DEM region {tuple(box)} is not inside the domain {tuple(domain)}")
    scale = 1e-9 * max(abs(domain).max(), 1.0)
    on_boundary = (abs(box[2] - domain[2]) < scale, abs(box[3] - domain[3]) < scale,
                   abs(box[0] - domain[0]) < scale, abs(box[1] - domain[1]) < scale)
    free_edges = tuple(e for e, b in zip(EDGES, on_boundary) if b)
    inside = distance_outside(position, box) == 0.0
    if not np.any(inside):
        raise InputError(f"DEM region {tuple(box)} holds no grain")
    r_max = float(radius.max())
    width = 2.0 * r_max
    outside = distance_outside(position, box)
    candidate = (~inside) & (outside <= width) & (distance_outside(position, domain) == 0.0)
    # nothing beyond an edge on the domain boundary (the free surface Gamma_A)
    beyond = (position[:, 1] < box[2], position[:, 1] > box[3],
              position[:, 0] < box[0], position[:, 0] > box[1])
    for b, side in zip(on_boundary, beyond):
        if b:
            candidate &= ~side
    candidates = np.flatnonzero(candidate)
    real = np.flatnonzero(inside)
    if layer == "touching" and candidates.size:
        tree = scipy.spatial.cKDTree(position[real])
        near = tree.query_ball_point(position[candidates], r=2.0 * r_max * (1 + touch_tolerance))
        keep = []
        for c, neighbours in zip(candidates, near):
            if neighbours:
                gap = (np.hypot(*(position[real[neighbours]] - position[c]).T)
                       - radius[real[neighbours]] - radius[c])
                if gap.min() <= touch_tolerance * radius[c]:
                    keep.append(c)
        candidates = np.asarray(keep, dtype=int)
        width = float(outside[candidates].max()) if candidates.size else 0.0
    order = np.concatenate([real, candidates])
    return DemRegion(box=box, position=position[order].copy(), radius=radius[order].copy(),
                     mass=mass[order].copy(), inertia=inertia[order].copy(), n_real=real.size,
                     free_edges=free_edges, layer_width=width)


def region_cells(mesh, box):
    """Local indices of this rank's OWNED cells inside Omega_D (ExplicitCosserat's
    inactive_cells).

    Refuses (one line) a rectangle that does not coincide with whole elements: every cell
    whose midpoint is inside must have all its vertices inside, and their areas must add up
    to the rectangle's (summed over the owned cells of all ranks)."""
    import dolfinx.mesh
    from mpi4py import MPI
    from cosserat_fenicsx import compat
    box = _box(box, "DEM region")
    tdim = mesh.topology.dim
    n_cells = mesh.topology.index_map(tdim).size_local + mesh.topology.index_map(tdim).num_ghosts
    n_owned = compat.num_owned_cells(mesh)
    cells = np.arange(n_cells, dtype=np.int32)
    mid = dolfinx.mesh.compute_midpoints(mesh, tdim, cells)[:, :2]
    tol = 1e-9 * max(abs(box).max(), 1.0)
    inside = ((mid[:, 0] > box[0]) & (mid[:, 0] < box[1]) & (mid[:, 1] > box[2]) & (mid[:, 1] < box[3]))
    chosen = cells[inside]
    area = 0.0
    cut = None
    for cell in chosen:
        xy = compat.cell_geometry(mesh, cell)[:, :2]
        if (np.any(xy[:, 0] < box[0] - tol) or np.any(xy[:, 0] > box[1] + tol)
                or np.any(xy[:, 1] < box[2] - tol) or np.any(xy[:, 1] > box[3] + tol)):
            bad = ", ".join(f"({x:g}, {y:g})" for x, y in xy)
            cut = (f"DEM region {tuple(box)} cuts an element (vertices {bad}): "
                   f"it must coincide with whole elements")
            break
        if cell < n_owned:
            area += _polygon_area(xy)
    # every rank learns of a cut found by any (no rank left waiting in a collective)
    cuts = [c for c in mesh.comm.allgather(cut) if c]
    if cuts:
        raise InputError(cuts[0])
    area = mesh.comm.allreduce(area, op=MPI.SUM)
    expected = (box[1] - box[0]) * (box[3] - box[2])
    if abs(area - expected) > 1e-9 * expected:
        raise InputError(f"DEM region {tuple(box)} is not a union of whole elements: the elements "
                         f"inside cover {area:g} m^2 of its {expected:g} m^2")
    return chosen[chosen < n_owned]


def _polygon_area(xy):
    """Area of a cell from its geometry nodes (triangle, or quadrilateral in dolfinx's
    tensor-product order 0, 1, 3, 2)."""
    if len(xy) == 4:
        xy = xy[[0, 1, 3, 2]]
    x, y = xy[:, 0], xy[:, 1]
    return 0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))
