"""Particle -> element map of the bridging-scale method: the shape functions N of the
Cosserat fields at the grain centres (003 eq 3), distributed as the continuum is.

Every rank receives the same particle positions (the DEM region lives on rank 0, which
broadcasts them). Each rank locates the particles inside its OWNED cells; a particle on a
cell boundary shared by several ranks is counted by the lowest of them only, so every
particle appears in exactly one rank's rows. From there:

- `interpolate`: values N d of a field at the particles, summed over ranks to rank 0 (or to all);
  `local_values` this rank's part of them (compiled products, kernels.py);
- `add_transpose`: N^T F added into a ghosted PETSc Vec (ADD of the ghost contributions to
  their owners, then the ghosts refreshed);
- `matrix`: the sparse N (particles x global dofs) gathered on rank 0, for the projection.

Shape-function values are basix tabulations at the reference point pulled back from the
particle's position (Lagrange of degree 1 or 2: Q1, P1, P2).
"""
import contextlib

import numpy as np
import scipy.sparse
from mpi4py import MPI
from petsc4py import PETSc

from cosserat_fenicsx import compat
from cosserat_fenicsx.bridging.kernels import rows_times, rows_times3, transpose_times
from cosserat_fenicsx.validation import InputError


def _as_points3(points):
    points = np.asarray(points, dtype=float)
    if points.ndim != 2 or points.shape[1] not in (2, 3):
        raise InputError(f"shape map: points must be (n, 2) or (n, 3), got {points.shape}")
    if not np.all(np.isfinite(points)):
        raise InputError("shape map: a particle position is not finite")
    out = np.zeros((len(points), 3))
    out[:, :points.shape[1]] = points
    return out


def sum_over_ranks(comm, local, root):
    """The array `local` summed over the ranks of comm: on `root` (None elsewhere), or on all
    ranks (root None); on one rank, local itself."""
    if comm.size == 1:
        return local
    out = np.zeros_like(local)
    if root is None:
        comm.Allreduce(local, out, op=MPI.SUM)
        return out
    comm.Reduce(local, out, op=MPI.SUM, root=root)
    return out if comm.rank == root else None


class ScalarShapeMap:
    """The scalar shape functions of a collapsed Lagrange space V at the particles.

    space: scalar Lagrange space (degree 1 or 2), the collapse of one component of W.
    points: (n, 2) particle positions [m], the same on every rank.
    to_parent: (n_local_dofs_V,) the local W dof of each local V dof (collapse's map), or
        None for V itself.
    Attributes of this rank's counted particles: `particles` (indices into points), `cells`
    (local cells), `dofs` (local V dofs, (k, n_dofs_cell)), `values` (basis values, same shape).
    """

    def __init__(self, space, points, to_parent=None):
        mesh = space.mesh
        self.comm = mesh.comm
        self.space = space
        points3 = _as_points3(points)
        self.n_particles = len(points3)
        degree = compat.lagrange_degree(space)
        if degree not in (1, 2):
            raise InputError(f"shape map: Lagrange degree {degree} not supported (1 or 2)")
        n_owned = compat.num_owned_cells(mesh)
        colliding = compat.colliding_cells(mesh, points3)
        first_cell = np.full(self.n_particles, -1, dtype=np.int64)
        for i in range(self.n_particles):
            links = colliding.links(i)
            owned = links[links < n_owned]
            if owned.size:
                first_cell[i] = owned.min()
        # the lowest rank that owns a containing cell counts the particle
        rank = self.comm.rank
        mine = np.where(first_cell >= 0, rank, self.comm.size).astype(np.int32)
        counting = np.empty_like(mine)
        self.comm.Allreduce(mine, counting, op=MPI.MIN)
        outside = np.flatnonzero(counting == self.comm.size)
        if outside.size:
            p = points3[outside[0], :2]
            raise InputError(f"shape map: {outside.size} particle(s) outside the mesh, the "
                             f"first at ({p[0]:g}, {p[1]:g})")
        self.particles = np.flatnonzero(counting == rank)
        self.cells = first_cell[self.particles].astype(np.int32)
        element = compat.basix_lagrange(mesh, degree)
        dofs_per_cell = element.dim
        gdim = mesh.geometry.dim
        self.dofs = np.empty((self.particles.size, dofs_per_cell), dtype=np.int32)
        self.values = np.empty((self.particles.size, dofs_per_cell))
        for k, (p, cell) in enumerate(zip(self.particles, self.cells)):
            reference = compat.pull_back(mesh, points3[p:p + 1, :gdim],
                                         compat.cell_geometry(mesh, cell))
            self.values[k] = element.tabulate(0, reference)[0, 0, :, 0]
            self.dofs[k] = space.dofmap.cell_dofs(cell)
        self.parent_dofs = self.dofs if to_parent is None else np.asarray(to_parent)[self.dofs]
        index_map = space.dofmap.index_map
        self.n_global_dofs = index_map.size_global * space.dofmap.index_map_bs
        local_to_global = np.asarray(index_map.local_to_global(
            np.arange(index_map.size_local + index_map.num_ghosts, dtype=np.int32)))
        self.global_dofs = local_to_global[self.dofs]

    def interpolate_local(self, parent_values):
        """N d for this rank's counted particles, from the local (owned + ghost) array of
        the parent (W, or V if to_parent was None): (k,)."""
        return np.einsum("kd,kd->k", self.values, parent_values[self.parent_dofs])

    def interpolate(self, parent_values, root=0):
        """N d at all particles (n,), on `root` (None elsewhere) or on all ranks (root=None)."""
        local = np.zeros(self.n_particles)
        local[self.particles] = self.interpolate_local(parent_values)
        return sum_over_ranks(self.comm, local, root)

    def add_transpose_local(self, forces, parent_values):
        """parent_values[local dofs] += N^T F over this rank's counted particles;
        forces: (n,) for all particles (only this rank's rows are read)."""
        np.add.at(parent_values, self.parent_dofs.ravel(),
                  (self.values * np.asarray(forces)[self.particles, None]).ravel())

    def matrix(self, root=0):
        """Sparse N (n_particles, n_global_dofs of V), global dof columns, on `root`."""
        rows = np.repeat(self.particles, self.dofs.shape[1])
        triplets = (rows, self.global_dofs.ravel(), self.values.ravel())
        gathered = (self.comm.allgather(triplets) if root is None
                    else self.comm.gather(triplets, root=root))
        if gathered is None:
            return None
        rows, cols, vals = (np.concatenate([g[i] for g in gathered]) for i in range(3))
        return scipy.sparse.csr_matrix((vals, (rows, cols)),
                                       shape=(self.n_particles, self.n_global_dofs))


def component_spaces(space):
    """(u1, u2, phi) -> (collapsed scalar space, map to W local dofs) of a Cosserat mixed
    space W = (vector u, scalar phi)."""
    out = {}
    for name, sub in (("u1", space.sub(0).sub(0)), ("u2", space.sub(0).sub(1)),
                      ("phi", space.sub(1))):
        collapsed, to_parent = sub.collapse()
        out[name] = (collapsed, np.asarray(to_parent))
    return out


class CosseratShapeMap:
    """Shape functions of (u1, u2, phi) of the mixed Cosserat space W at the particles.

    interpolate(vec) -> (n, 3) fields at the particles; add_transpose(forces (n, 3), vec)
    adds N^T F into a ghosted Vec over W; matrices() -> (N_u, N_phi) on rank 0 for the
    projection (N_u from the u1 space: u1 and u2 share the scalar shape functions)."""

    COMPONENTS = ("u1", "u2", "phi")

    def __init__(self, space, points, spaces=None):
        self.comm = space.mesh.comm
        spaces = spaces or component_spaces(space)
        self.maps = {name: ScalarShapeMap(spaces[name][0], points, spaces[name][1])
                     for name in self.COMPONENTS}
        self.n_particles = self.maps["u1"].n_particles
        # this rank's rows of N as one sparse matrix (3 n, local W dofs incl. ghosts): row
        # 3 p + c holds component c of particle p (zero rows for particles counted elsewhere)
        index_map = space.dofmap.index_map
        n_local = (index_map.size_local + index_map.num_ghosts) * space.dofmap.index_map_bs
        rows, cols, vals = [], [], []
        for c, name in enumerate(self.COMPONENTS):
            m = self.maps[name]
            rows.append(np.repeat(3 * m.particles + c, m.dofs.shape[1]))
            cols.append(m.parent_dofs.ravel())
            vals.append(m.values.ravel())
        self.local_matrix = scipy.sparse.csr_matrix(
            (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
            shape=(3 * self.n_particles, n_local))
        self._translation_rows = np.flatnonzero(np.arange(3 * self.n_particles) % 3 != 2)
        self._work = None

    def _local_arrays(self, vecs, stack):
        """The local (owned + ghost) values of each Vec over W, read-only, valid inside
        `stack`; the ghosts refreshed first (on one rank there are none)."""
        arrays = []
        for v in vecs:
            if self.comm.size > 1:
                v.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
            arrays.append(stack.enter_context(v.localForm()).array_r)
        return arrays

    def local_values(self, vecs):
        """(3 n, len(vecs)): this rank's N x of each Vec over W (row 3 p + c: component c at
        particle p; zero for the particles counted elsewhere), the Vecs' ghosts refreshed
        first. Sum the rows over ranks for the values."""
        m = self.local_matrix
        out = np.empty((m.shape[0], len(vecs)))
        with contextlib.ExitStack() as stack:
            arrays = self._local_arrays(vecs, stack)
            if len(arrays) == 3:
                rows_times3(m.indptr, m.indices, m.data, *arrays, out)
            else:
                every_row = np.arange(m.shape[0])
                for f, x in enumerate(arrays):
                    column = np.empty(m.shape[0])
                    rows_times(m.indptr, m.indices, m.data, every_row, x, column)
                    out[:, f] = column
        return out

    def interpolate(self, vec, root=0):
        """(n, 3) values of (u1, u2, phi) at the particles on root (None elsewhere), from a
        Vec over W whose ghosts are refreshed first. A list of Vecs gives a list of arrays
        (one reduction for all)."""
        vecs = vec if isinstance(vec, (list, tuple)) else [vec]
        local = self.local_values(vecs)
        local = np.ascontiguousarray(local.reshape(self.n_particles, 3, -1).transpose(2, 0, 1))
        out = sum_over_ranks(self.comm, local, root)
        if out is None:
            return None
        return list(out) if isinstance(vec, (list, tuple)) else out[0]

    def interpolate_translation(self, vec, root=0):
        """(n, 2) values of (u1, u2) at the particles on root (None elsewhere): the first two
        columns of interpolate(vec), without the rotation's products."""
        m = self.local_matrix
        local = np.empty(self._translation_rows.size)
        with contextlib.ExitStack() as stack:
            x, = self._local_arrays([vec], stack)
            rows_times(m.indptr, m.indices, m.data, self._translation_rows, x, local)
        return sum_over_ranks(self.comm, local.reshape(self.n_particles, 2), root)

    def add_transpose(self, forces, vec):
        """vec += N^T F (forces (n, 3): f1 [N/m], f2 [N/m], moment [N m/m] per particle,
        the same array on every rank), assembled over ranks (ghost ADD, then ghosts refreshed)."""
        forces = np.ascontiguousarray(forces, dtype=float).reshape(-1)
        if self._work is None or self._work.getSize() != vec.getSize():
            self._work = vec.duplicate()
        work = self._work
        m = self.local_matrix
        with work.localForm() as loc:
            transpose_times(m.indptr, m.indices, m.data, forces, loc.array)
        # this rank's contributions to ghost dofs go to their owners
        work.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        vec.axpy(1.0, work)
        vec.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)

    def add_lumped_mass(self, weights, vec):
        """vec += the particles' lumped coarse mass (003 eq 5 lumped): weights (n, 3) are
        (m, m, J) per particle [kg/m, kg m]. Row-sum N^T w where every shape value is >= 0
        (Q1, P1); otherwise (P2, whose vertex functions are negative inside the element) the
        HRZ diagonal: w N_i^2 summed per cell and scaled to the cell's total particle mass,
        so that no dof gets a negative mass."""
        weights = np.asarray(weights, dtype=float)
        if self._work is None or self._work.getSize() != vec.getSize():
            self._work = vec.duplicate()
        work = self._work
        with work.localForm() as loc:
            loc.array[:] = 0.0
            for c, name in enumerate(self.COMPONENTS):
                m = self.maps[name]
                w = weights[m.particles, c]
                if self.comm.allreduce(bool(np.any(m.values < 0.0)), op=MPI.LOR):
                    square = w[:, None] * m.values ** 2
                    cells, index = np.unique(m.cells, return_inverse=True)
                    total = np.bincount(index, weights=w, minlength=cells.size)
                    diagonal = np.bincount(index, weights=square.sum(axis=1), minlength=cells.size)
                    # cells holding only weightless (virtual) particles add nothing
                    scale = np.divide(total, diagonal, out=np.zeros_like(total), where=diagonal > 0.0)
                    contribution = square * scale[index][:, None]
                else:
                    contribution = w[:, None] * m.values
                np.add.at(loc.array, m.parent_dofs.ravel(), contribution.ravel())
        work.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        vec.axpy(1.0, work)
        vec.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)

    def matrices(self, root=0):
        return self.maps["u1"].matrix(root), self.maps["phi"].matrix(root)

    def counted_elements(self, root=0):
        """(n,) global index of the cell that counts each particle, on root (for the
        projection's refusal message); -1 never remains (every particle is counted)."""
        m = self.maps["u1"]
        index_map = m.space.mesh.topology.index_map(m.space.mesh.topology.dim)
        local = np.full(self.n_particles, -1, dtype=np.int64)
        local[m.particles] = np.asarray(index_map.local_to_global(m.cells))
        out = np.empty_like(local)
        self.comm.Allreduce(local, out, op=MPI.MAX)
        return out if root is None or self.comm.rank == root else None
