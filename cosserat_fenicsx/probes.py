"""Point evaluation of finite-element fields (profiles along lines), MPI-safe."""
import dolfinx.geometry
import numpy as np
from mpi4py import MPI

from . import compat


def sample_line(function, points):
    """Values of a scalar (sub-)Function at points (n, 3), the same array on every rank.
    Points outside the mesh give NaN."""
    mesh = function.function_space.mesh
    if compat.LEGACY:
        tree = dolfinx.geometry.BoundingBoxTree(mesh, mesh.topology.dim)
    else:
        tree = dolfinx.geometry.bb_tree(mesh, mesh.topology.dim)
    candidates = dolfinx.geometry.compute_collisions(tree, points) if compat.LEGACY \
        else dolfinx.geometry.compute_collisions_points(tree, points)
    colliding = dolfinx.geometry.compute_colliding_cells(mesh, candidates, points)
    n_owned = compat.num_owned_cells(mesh)
    local = np.full(len(points), np.nan)
    for i in range(len(points)):
        cells = [c for c in colliding.links(i) if c < n_owned]
        if cells:
            local[i] = function.eval(points[i], np.array(cells[:1], dtype=np.int32))[0]
    # each point is owned by at least one rank: take the first finite value
    gathered = mesh.comm.allgather(local)
    values = np.full(len(points), np.nan)
    for arr in gathered:
        mask = np.isnan(values) & np.isfinite(arr)
        values[mask] = arr[mask]
    return values


def stress_component_at(problem, index, point):
    """Finite-element value of stress component `index` (i, j) at one point [Pa].

    The stress of the pure-UFL path is interpolated into discontinuous Lagrange of
    degree max(degree_u - 1, 0); on affine triangles that holds the FE stress exactly."""
    import dolfinx.fem
    mesh = problem.mesh
    degree = max(problem.degree_u - 1, 0)
    V = compat.function_space(mesh, compat.dg_element(mesh, degree))
    f = dolfinx.fem.Function(V)
    points = V.element.interpolation_points
    points = points() if callable(points) else points
    f.interpolate(dolfinx.fem.Expression(problem.stress()[index], points))
    return float(sample_line(f, np.asarray(point, dtype=float).reshape(1, 3))[0])
