"""Meshes with named boundaries: {name: tag} dictionaries travel with the facet tags."""
import math
import os

import dolfinx.mesh
import numpy as np

from . import compat
from .resources import memory_bytes
from .validation import POSITIVE, InputError, Range, check

MESH_DIR = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "meshes")
RECTANGLE_BOUNDARIES = {"left": 1, "right": 2, "bottom": 3, "top": 4}


#: memory of the P2/P1 problem with its direct (MUMPS) factorisation per triangle [bytes]:
#: measured on the shear layer, 4.2e5 triangles (2.5e6 unknowns) took 8.4 GB and 106 s
BYTES_PER_ELEMENT = 2.0e4
#: the share of memory a mesh may plan for: on a 24 GiB machine 1.3e6 triangles were killed
#: by the out-of-memory killer after 9 minutes (the factorisation's peak is above the
#: measured resident size), 4.2e5 ran
MEMORY_SHARE = 0.4


def max_elements():
    """The most elements a direct solve fits in the memory of this machine
    (resources.memory_bytes), about 5e5 on a 24 GiB machine: more are refused before gmsh or
    dolfinx is asked for them. Read when a mesh is checked, so that a malformed
    COSSERAT_MEMORY_BYTES is refused in one line there, not raised by an import."""
    return int(MEMORY_SHARE * memory_bytes() / BYTES_PER_ELEMENT)


def rectangle_divisions(width, height, cell_size):
    """(nx, ny) squares of about `cell_size` in a width x height rectangle; InputError when
    that is more than max_elements() (e.g. a cell size of 1e-300 m)."""
    check("width", width, RECTANGLE_LENGTH)
    check("height", height, RECTANGLE_LENGTH)
    check("cell_size", cell_size, POSITIVE)
    nx, ny = (max(1.0, float(np.ceil(extent / cell_size - 1e-9))) for extent in (width, height))   # floats: inf, not OverflowError
    limit = max_elements()
    if not 2 * nx * ny <= limit:              # counted as triangles, two a square
        raise InputError(f"cell size {cell_size:g} m gives {2 * nx * ny:.3g} triangles in a {width:g} x {height:g} m "
                         f"rectangle; at most {limit:.0e}")
    return int(nx), int(ny)


def check_node_at_centre(nx, degree, what="the pin at the bottom centre"):
    """InputError unless a rectangle of nx elements across carries a node of a degree-`degree`
    Lagrange space at mid-width (nodes sit at multiples of 1 / (nx degree) of the width)."""
    if (nx * degree) % 2:
        raise InputError(f"{what} needs a node at mid-width: {nx} element(s) across with degree {degree} "
                         "have none (use an even number of elements across or degree_u 2)")


def check_element_count(area, cell_size, what="the mesh"):
    """InputError when about area / cell_size^2 elements exceed max_elements()."""
    count = area / (cell_size * cell_size) if cell_size * cell_size > 0 else math.inf   # inf, not OverflowError
    limit = max_elements()
    if not count <= limit:
        raise InputError(f"element size {cell_size:g} m gives about {count:.3g} elements in {what}; "
                         f"at most {limit:.0e}")


#: lengths of a geometry [m] whose areas and Jacobians stay well inside double precision
LENGTH = Range(1e-9, 1e9)
#: sides of a rectangle [m]: dolfinx 0.5 locates points (probes.sample_line) with an
#: absolute tolerance, and a layer 1e-5 m high gave NaN profiles (1e-4 m did not)
RECTANGLE_LENGTH = Range(1e-4, 1e6)
#: the hole plate is meshed at unit size: the hole must stay above the mesher's tolerance
HOLE_RATIO = Range(1e-4, 1.0, high_open=True)


def check_hole_plate(radius, half_side, cell_size, hole_cell_size):
    """InputError unless the hole plate can be meshed: lengths in LENGTH, radius / half side
    in HOLE_RATIO, element sizes no coarser than the plate, at most max_elements() elements."""
    check("radius", radius, LENGTH)
    check("half_side", half_side, LENGTH)
    if not half_side > radius:
        raise InputError(f"half_side must be > radius ({radius:g} m), got {half_side:g} m")
    check("radius / half_side", radius / half_side, HOLE_RATIO)
    check("cell_size", cell_size, Range(0.0, half_side, low_open=True))
    check("hole_cell_size", hole_cell_size, Range(0.0, half_side, low_open=True))
    check_element_count(2 * half_side * half_side, cell_size, "the plate")
    check_element_count(2 * radius * radius, hole_cell_size, "the ring around the hole")


def rectangle(comm, width, height, cell_size=None, cell_type="triangle", origin=(0.0, 0.0), divisions=None):
    """Structured rectangle [x0, x0 + width] x [y0, y0 + height], either of squares of about
    `cell_size` or of `divisions` = (nx, ny) rectangles (each split into two triangles for
    cell_type 'triangle'); returns (mesh, facet_tags, boundaries) with boundaries
    left/right/bottom/top."""
    if (cell_size is None) == (divisions is None):
        raise ValueError("give exactly one of cell_size and divisions")
    if cell_type not in ("triangle", "quadrilateral"):
        raise ValueError(f"cell_type must be 'triangle' or 'quadrilateral', got {cell_type!r}")
    if divisions is not None:
        check("width", width, RECTANGLE_LENGTH)
        check("height", height, RECTANGLE_LENGTH)
        nx, ny = divisions
        if not all(isinstance(n, (int, np.integer)) and n >= 1 for n in (nx, ny)):
            raise ValueError(f"divisions must be two integers >= 1, got {divisions!r}")
    else:
        nx, ny = rectangle_divisions(width, height, cell_size)
    x0, y0 = origin
    mesh = dolfinx.mesh.create_rectangle(
        comm, [np.array([x0, y0]), np.array([x0 + width, y0 + height])], [nx, ny],
        getattr(dolfinx.mesh.CellType, cell_type))
    tol = 1e-10 * max(width, height)
    where = {"left": lambda x: np.isclose(x[0], x0, atol=tol),
             "right": lambda x: np.isclose(x[0], x0 + width, atol=tol),
             "bottom": lambda x: np.isclose(x[1], y0, atol=tol),
             "top": lambda x: np.isclose(x[1], y0 + height, atol=tol)}
    return mesh, tag_facets(mesh, where, RECTANGLE_BOUNDARIES), dict(RECTANGLE_BOUNDARIES)


def tag_facets(mesh, where, tags):
    """Facet MeshTags from {name: marker(x)} and {name: tag}; later names win on corners."""
    fdim = mesh.topology.dim - 1
    mesh.topology.create_connectivity(fdim, mesh.topology.dim)
    values = {}
    for name, marker in where.items():
        for facet in dolfinx.mesh.locate_entities_boundary(mesh, fdim, marker):
            values[int(facet)] = tags[name]
    facets = np.array(sorted(values), dtype=np.int32)
    return dolfinx.mesh.meshtags(mesh, fdim, facets, np.array([values[f] for f in facets], dtype=np.int32))


def from_gmsh_geo(comm, geo_path, parameters, gdim=2):
    """Mesh a gmsh .geo source (ONELAB 'Parameters/NAME' numbers overridden by
    `parameters`) on rank 0 and distribute it. Returns (mesh, facet_tags, boundaries)
    with boundaries named after the physical curves."""
    if not os.path.isfile(geo_path):
        raise FileNotFoundError(f"gmsh source not found: {geo_path}")
    import gmsh
    boundaries = None
    gmsh.initialize()
    gmsh.option.setNumber("General.Terminal", 0)
    try:
        if comm.rank == 0:
            try:
                gmsh.clear()
                for name, value in parameters.items():
                    gmsh.onelab.setNumber(f"Parameters/{name}", [float(value)])
                gmsh.open(geo_path)
                gmsh.model.mesh.generate(gdim)
                boundaries = {gmsh.model.getPhysicalName(gdim - 1, tag): tag
                              for _, tag in gmsh.model.getPhysicalGroups(gdim - 1)}
            except Exception as error:     # told to every rank: the others must not wait in bcast
                boundaries = f"gmsh could not mesh {os.path.basename(geo_path)} with {parameters}: {error}"
        boundaries = comm.bcast(boundaries, root=0)
        if isinstance(boundaries, str):
            raise RuntimeError(boundaries)
        mesh, _, facet_tags = compat.gmsh_model_to_mesh(gmsh.model, comm, 0, gdim)
    finally:
        gmsh.finalize()
    return mesh, facet_tags, boundaries


def hole_plate(comm, radius, half_side, cell_size, hole_cell_size=None,
               geo_path=os.path.join(MESH_DIR, "hole_plate.geo")):
    """Quarter plate [0, L]^2 minus the disc of `radius` (meshes/hole_plate.geo);
    boundaries left, bottom (symmetry), right, top, hole."""
    hole_cell_size = hole_cell_size or cell_size
    check_hole_plate(radius, half_side, cell_size, hole_cell_size)
    # meshed at unit size and scaled: OpenCASCADE's absolute tolerance (1e-7) and the .geo's
    # bounding boxes then see the same numbers at every scale of the plate
    mesh, facet_tags, boundaries = from_gmsh_geo(comm, geo_path, {
        "R": radius / half_side, "L": 1.0, "h": cell_size / half_side, "h_hole": hole_cell_size / half_side})
    mesh.geometry.x[:, :2] *= half_side
    return mesh, facet_tags, boundaries

