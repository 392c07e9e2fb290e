"""Point evaluation of finite-element fields (profiles along lines), MPI-safe."""
import numpy as np
from mpi4py import MPI

from . import compat


def _colliding_cells(mesh, points):
    """AdjacencyList: local cells containing each point."""
    return compat.colliding_cells(mesh, points)


def sample_line(function, points):
    """Values of a scalar (sub-)Function at points (n, 3), the same array on every rank.
    Points outside the mesh give NaN."""
    mesh = function.function_space.mesh
    colliding = _colliding_cells(mesh, points)
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
    """Finite-element value of stress component `index` (i, j) at one point [Pa],
    averaged over every cell that contains the point (a mesh vertex on a boundary, such
    as the edge of a hole, belongs to several cells whose stresses differ).

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
    x = np.asarray(point, dtype=float).reshape(1, 3)
    n_owned = compat.num_owned_cells(mesh)
    total, count = 0.0, 0
    for cell in _colliding_cells(mesh, x).links(0):
        if cell < n_owned:
            total += float(f.eval(x[0], np.array([cell], dtype=np.int32))[0])
            count += 1
    total, count = mesh.comm.allreduce(total), mesh.comm.allreduce(count)
    if count == 0:
        raise ValueError(f"point {point} is outside the mesh")
    return total / count
