"""The sign convention of strain and coupling (kinematics.py), pinned."""
import dolfinx.fem
import dolfinx.fem.petsc
import numpy as np
import pytest
import ufl
from mpi4py import MPI

from cosserat_fenicsx import CosseratProblem, MicropolarElasticity, NewtonSolver, LoadStepper, meshes
from petsc4py import PETSc

ELASTIC = MicropolarElasticity(mu=1.0e8, lmbda=2.0e8, mu_c=0.5e8, l_c=0.05)
OMEGA = 1.0e-3


def solve_with_boundary_rotation(phi_sign):
    mesh, tags, names = meshes.rectangle(MPI.COMM_WORLD, 1.0, 0.5, 0.125)
    problem = CosseratProblem(mesh, tags, names, elasticity=ELASTIC)
    for side in names:
        problem.add_dirichlet(side, "u1", lambda x: -OMEGA * x[1])
        problem.add_dirichlet(side, "u2", lambda x: OMEGA * x[0])
        problem.add_dirichlet(side, "phi", phi_sign * OMEGA)
    LoadStepper(problem, NewtonSolver(problem), dt=1.0, verbose=False).run()
    sigma = problem.stress()
    energy = dolfinx.fem.assemble_scalar(dolfinx.fem.form(ufl.inner(sigma, sigma) * ufl.dx))
    return np.sqrt(mesh.comm.allreduce(energy)) / (ELASTIC.mu * OMEGA), problem


def test_rigid_rotation_is_stress_free():
    """u = (-omega x2, omega x1), phi = omega: zero strain, zero stress, and the solver
    reproduces the rigid rotation inside the body."""
    relative_stress, problem = solve_with_boundary_rotation(+1.0)
    assert relative_stress < 1e-10
    _, rotation_dofs = problem.W.sub(1).collapse()
    assert np.allclose(problem.w.x.array[rotation_dofs], OMEGA, rtol=1e-9)


def test_opposite_rotation_is_not_stress_free():
    """The test above can fail: with phi = -omega the coupling stresses the body."""
    relative_stress, _ = solve_with_boundary_rotation(-1.0)
    assert relative_stress > 0.1


def test_coupling_term_sign():
    """u = 0, phi = const: sigma12 = -sigma21 = 2 mu_c phi, and the moment residual is
    +4 mu_c phi per unit area (the coupling restores the rotation)."""
    mesh, tags, names = meshes.rectangle(MPI.COMM_WORLD, 1.0, 1.0, 0.5)
    problem = CosseratProblem(mesh, tags, names, elasticity=ELASTIC)
    problem.add_dirichlet("left", "u1", 0.0)
    problem.w.sub(1).interpolate(lambda x: np.full(x.shape[1], OMEGA))
    sigma = problem.stress()
    area = mesh.comm.allreduce(dolfinx.fem.assemble_scalar(dolfinx.fem.form(1.0 * ufl.dx(domain=mesh))))

    def mean(expr):
        return mesh.comm.allreduce(dolfinx.fem.assemble_scalar(dolfinx.fem.form(expr * ufl.dx))) / area

    assert mean(sigma[0, 1]) == pytest.approx(2 * ELASTIC.mu_c * OMEGA, rel=1e-12)
    assert mean(sigma[1, 0]) == pytest.approx(-2 * ELASTIC.mu_c * OMEGA, rel=1e-12)
    # the moment rows of the assembled residual, summed (the P1 basis sums to w = 1):
    # int (sigma12 - sigma21) dA = +4 mu_c phi A
    vec = dolfinx.fem.petsc.assemble_vector(dolfinx.fem.form(problem.residual_ufl()))
    vec.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
    _, rotation_dofs = problem.W.sub(1).collapse()
    n_owned = problem.W.dofmap.index_map.size_local * problem.W.dofmap.index_map_bs
    dofs = np.asarray(rotation_dofs)
    moment = mesh.comm.allreduce(float(vec.array_r[dofs[dofs < n_owned]].sum()))
    assert moment == pytest.approx(4 * ELASTIC.mu_c * OMEGA * area, rel=1e-10)
