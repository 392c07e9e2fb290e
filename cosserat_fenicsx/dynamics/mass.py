"""Lumped translational mass and rotary inertia of the Cosserat continuum (003, section 2.3:
a diagonal coarse mass for the explicit steps, eqs 31-34).

Per unit depth (2D): the translational mass of a node is rho times an area [kg/m], its rotary
inertia rho j times an area [kg m] (j the micro-inertia [m^2], e.g. r^2/2 for discs).

Consistent mass (kinetic energy 1/2 int rho |u_dot|^2 + rho j phi_dot^2 dA):

    M_ij = int chi rho N_i . N_j dA  (translation),   J_ij = int chi rho j N_i N_j dA  (rotation)

with chi the DG0 indicator of the active cells (0 in the DEM region, which carries no continuum
mass). Two lumpings:

- row-sum  m_i = sum_j M_ij = int chi rho N_i dA   (degree-1 Lagrange: P1 and Q1; positive)
- HRZ      m_i = M_ii * (element mass / trace of the element matrix)  (Hinton, Rock & Zienkiewicz
  1976) for P2 triangles, whose row sums vanish at the vertices (int N_vertex dA = 0). On a
  straight-sided triangle the element matrix is |T| times the reference one, so the factor
  (element mass / trace) is the same number for every cell (30/19 for P2): it is computed once
  as total mass / total trace of the assembled diagonal. The project's meshes are straight-sided.
  The P2 lumped masses are A/19 at the vertices and 16 A/57 at the edge midpoints.

Both keep the total mass exact: sum of the lumped masses = int chi rho dA.
"""
import dolfinx.fem
import dolfinx.fem.petsc
import numpy as np
import ufl
from petsc4py import PETSc

from .. import compat


def mass_forms(space, indicator, density, micro_inertia, quadrature_degree):
    """UFL (row-sum linear form, consistent bilinear form) of the mixed (u, phi) space."""
    mesh = space.mesh
    dx = ufl.dx(domain=mesh, metadata={"quadrature_degree": quadrature_degree})
    v, w = ufl.split(ufl.TestFunction(space))
    du, dphi = ufl.split(ufl.TrialFunction(space))
    rho = indicator * density
    rowsum = rho * (v[0] + v[1]) * dx + rho * micro_inertia * w * dx
    consistent = rho * ufl.inner(du, v) * dx + rho * micro_inertia * dphi * w * dx
    return rowsum, consistent


def _owned(vec):
    vec.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
    vec.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
    return vec


def lumped_mass(space, indicator, density, micro_inertia, hrz_dofs, quadrature_degree):
    """Lumped mass Vec over `space` (ghosted, ghosts current) [kg/m at u dofs, kg m at phi dofs].

    hrz_dofs: local indices (owned ones used) of the dofs lumped by HRZ (the P2 displacement);
    all others are row sums. Returns (mass Vec, dict of figures: hrz factor, total masses)."""
    rowsum_ufl, consistent_ufl = mass_forms(space, indicator, density, micro_inertia, quadrature_degree)
    mass = _owned(dolfinx.fem.petsc.assemble_vector(dolfinx.fem.form(rowsum_ufl)))
    info = {"hrz_factor": None}
    comm = space.mesh.comm
    n_owned = space.dofmap.index_map.size_local * space.dofmap.index_map_bs
    hrz = np.asarray(hrz_dofs, dtype=np.int64)
    hrz = hrz[hrz < n_owned]
    if comm.allreduce(len(hrz)) > 0:
        matrix = dolfinx.fem.petsc.assemble_matrix(dolfinx.fem.form(consistent_ufl))
        matrix.assemble()
        diagonal = matrix.createVecRight()
        matrix.getDiagonal(diagonal)
        matrix.destroy()
        row_total = comm.allreduce(float(mass.array[hrz].sum()))
        diag_total = comm.allreduce(float(diagonal.array[hrz].sum()))
        factor = row_total / diag_total if diag_total > 0.0 else 0.0
        mass.array[hrz] = factor * diagonal.array[hrz]
        diagonal.destroy()
        mass.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
        info["hrz_factor"] = factor
    return mass, info


def mass_dot(x, mass):
    """x . M x with the lumped mass Vec M (global: every rank gets the same number)."""
    weighted = x.copy()
    weighted.pointwiseMult(weighted, mass)
    value = x.dot(weighted)
    weighted.destroy()
    return value
