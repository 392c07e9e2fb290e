"""Manufactured solution of the micropolar elastic problem (verification).

On the unit square, smooth fields

    u1 = a sin(pi x) cos(pi y),  u2 = a cos(2 pi x) sin(pi y) / 2 + a x y,
    phi = a cos(pi x) sin(2 pi y)

are imposed on the whole boundary, and the body force f = -div sigma and body couple
c = (sigma12 - sigma21) - div m that make them exact are derived symbolically by UFL
from the constitutive law. Errors in L2 and the H1 seminorm then converge at rates
k+1 and k for Lagrange degree k (3 / 2 for P2 displacement, 2 / 1 for P1 rotation), with
one exception that is mathematics, not a bug: when l_c is comparable with the domain,
the energy error of Taylor-Hood is O(h) through l_c |phi - phi_h|_H1 and the L2 error of
u drops to O(h^2) (equal orders P2/P2 restore O(h^3)); the tests pin both cases.
"""
import time

import dolfinx.fem
import numpy as np
import ufl
from mpi4py import MPI

from . import compat, meshes
from .elasticity import MicropolarElasticity
from .problem import CosseratProblem
from .snes import NewtonSolver
from .stepping import LoadStepper

AMPLITUDE = 1.0e-3


def exact_fields(x, module=ufl):
    """(u1, u2, phi) as UFL expressions (module=ufl) or numpy arrays (module=np)."""
    a, pi = AMPLITUDE, np.pi
    sin, cos = module.sin, module.cos
    u1 = a * sin(pi * x[0]) * cos(pi * x[1])
    u2 = 0.5 * a * cos(2 * pi * x[0]) * sin(pi * x[1]) + a * x[0] * x[1]
    phi = a * cos(pi * x[0]) * sin(2 * pi * x[1])
    return u1, u2, phi


def solve(comm, n, elasticity, cell_type="triangle", degree_u=2, degree_phi=1, micropolar=True):
    """Solve on an n x n mesh; returns a dict of errors, dofs, h and wall time."""
    start = time.perf_counter()
    mesh, facet_tags, boundaries = meshes.rectangle(comm, 1.0, 1.0, 1.0 / n, cell_type)
    problem = CosseratProblem(mesh, facet_tags, boundaries, elasticity=elasticity,
                              micropolar=micropolar, degree_u=degree_u, degree_phi=degree_phi)
    x = ufl.SpatialCoordinate(mesh)
    u1, u2, phi = exact_fields(x)
    u_exact = ufl.as_vector([u1, u2])
    from .kinematics import strain, curvature
    sigma = elasticity.stress(strain(u_exact, phi if micropolar else None))
    problem.set_body_force(-ufl.div(sigma), scale=lambda t: 1.0)
    if micropolar:
        m = elasticity.couple_stress(curvature(phi))
        problem.set_body_couple(sigma[0, 1] - sigma[1, 0] - ufl.div(m), scale=lambda t: 1.0)
    numpy_exact = [lambda p, i=i: exact_fields(p, np)[i] for i in range(3)]
    for side in boundaries:
        problem.add_dirichlet(side, "u1", numpy_exact[0], scale=lambda t: 1.0)
        problem.add_dirichlet(side, "u2", numpy_exact[1], scale=lambda t: 1.0)
        if micropolar:
            problem.add_dirichlet(side, "phi", numpy_exact[2], scale=lambda t: 1.0)
    solver = NewtonSolver(problem)
    LoadStepper(problem, solver, dt=1.0, verbose=False).run()
    solve_time = time.perf_counter() - start

    u_h, phi_h = problem.split(problem.w)
    dx = ufl.dx(domain=mesh, metadata={"quadrature_degree": 2 * degree_u + 4})

    def norm(expr):
        value = dolfinx.fem.assemble_scalar(dolfinx.fem.form(expr * dx))
        return float(np.sqrt(mesh.comm.allreduce(value, op=MPI.SUM)))

    e_u = u_h - u_exact
    errors = {"u_L2": norm(ufl.inner(e_u, e_u)), "u_H1": norm(ufl.inner(ufl.grad(e_u), ufl.grad(e_u)))}
    if micropolar:
        e_phi = phi_h - phi
        errors.update(phi_L2=norm(e_phi * e_phi), phi_H1=norm(ufl.inner(ufl.grad(e_phi), ufl.grad(e_phi))))
    dofs = problem.W.dofmap.index_map.size_global * problem.W.dofmap.index_map_bs
    solver.destroy()
    return {"n": n, "h": 1.0 / n, "dofs": dofs, "wall_time": solve_time, **errors}


def rates(results, key):
    """Observed orders log(e_i/e_{i+1}) / log(h_i/h_{i+1})."""
    return [float(np.log(a[key] / b[key]) / np.log(a["h"] / b["h"])) for a, b in zip(results, results[1:])]


# l_c small against the domain: the P1 rotation's gradient error, weighted by l_c in the
# energy, does not pollute the displacement, and Taylor-Hood shows 3/2 and 2/1.
DEFAULT_ELASTICITY = MicropolarElasticity(mu=1.0e8, lmbda=1.5e8, mu_c=0.7e8, l_c=0.01)
# l_c comparable with the domain: the energy error is O(h) through l_c |phi - phi_h|_H1,
# so the duality argument gives only O(h^2) for u in L2 with a P1 rotation.
LARGE_LENGTH_ELASTICITY = MicropolarElasticity(mu=1.0e8, lmbda=1.5e8, mu_c=0.7e8, l_c=0.3)
