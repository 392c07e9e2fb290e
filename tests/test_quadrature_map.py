"""A material through the Gauss-point store (QuadratureMap): same answer as pure UFL; history commit/rollback; step
cut-back on material failure; clear stop (no hang under MPI) when nothing converges."""
import numpy as np
import pytest
from mpi4py import MPI

from cosserat_fenicsx import (CosseratProblem, ConstitutiveError, LinearElasticMaterial, LoadStepper,
                              LoadSteppingError, MicropolarElasticity, NewtonSolver, meshes)

ELASTIC = MicropolarElasticity(mu=1.0e8, lmbda=1.2e8, mu_c=0.4e8, l_c=0.02)


def plate(cell_type="triangle"):
    return meshes.rectangle(MPI.COMM_WORLD, 0.2, 0.1, 0.0125, cell_type)


def scene(micropolar=True, elasticity=None, material=None, mesh_data=None):
    """A plate pulled and sheared: mixed Dirichlet / traction / couple conditions.
    Compared solutions share `mesh_data`: two meshes may be partitioned differently."""
    mesh, tags, names = mesh_data or plate()
    problem = CosseratProblem(mesh, tags, names, elasticity=elasticity, material=material,
                              micropolar=micropolar)
    problem.add_dirichlet("bottom", "u1", 0.0)
    problem.add_dirichlet("bottom", "u2", 0.0)
    problem.add_dirichlet("top", "u1", lambda x: 1e-4 * np.sin(10 * x[0]))
    problem.add_traction("right", (2.0e5, -1.0e5))
    problem.set_body_force((0.0, -2.0e4))
    if micropolar:
        problem.add_dirichlet("bottom", "phi", 0.0)
        problem.add_surface_couple("left", 50.0)
        problem.set_body_couple(1.0e3)
    return problem


def solve(problem, dt=1.0, **kwargs):
    stepper = LoadStepper(problem, NewtonSolver(problem), dt=dt, verbose=False, **kwargs)
    stepper.run()
    return stepper


@pytest.mark.parametrize("micropolar", [True, False])
@pytest.mark.parametrize("cell_type", ["triangle", "quadrilateral"])
def test_gauss_point_material_equals_pure_ufl(micropolar, cell_type):
    mesh_data = plate(cell_type)
    ufl_path = scene(micropolar, elasticity=ELASTIC, mesh_data=mesh_data)
    solve(ufl_path)
    store_path = scene(micropolar, material=LinearElasticMaterial(ELASTIC), mesh_data=mesh_data)
    solve(store_path)
    a, b = ufl_path.w.x.array, store_path.w.x.array
    scale = MPI.COMM_WORLD.allreduce(np.abs(a).max(), op=MPI.MAX)
    diff = MPI.COMM_WORLD.allreduce(np.abs(a - b).max(), op=MPI.MAX)
    assert scale > 1e-6
    assert diff < 1e-9 * scale
    for boundary, component in (("bottom", "u1"), ("bottom", "u2")):
        assert store_path.reaction(boundary, component) == pytest.approx(
            ufl_path.reaction(boundary, component), rel=1e-8)


class IncrementLimitedElastic(LinearElasticMaterial):
    """Elastic, but refuses strain increments above `limit` (like a plastic return
    mapping that needs sub-steps). History: the committed gradients."""
    state_names = ("eps11", "eps22", "eps12", "eps21", "kappa31", "kappa32")

    def __init__(self, elasticity, limit):
        super().__init__(elasticity)
        self.limit = limit

    def update(self, gradients, dt, state_old, flux_out, tangent_out, state_new, points=None):
        increment = np.abs(gradients[:, :4] - state_old[:, :4]).max(initial=0.0)
        if increment > self.limit:
            raise ConstitutiveError(f"strain increment {increment:.2e} above {self.limit:.2e}")
        super().update(gradients, dt, state_old, flux_out, tangent_out, state_new, points)
        state_new[:] = gradients


def test_cut_back_recovers_and_commits_history():
    mesh_data = plate()
    reference = scene(elasticity=ELASTIC, mesh_data=mesh_data)
    solve(reference)
    material = IncrementLimitedElastic(ELASTIC, limit=1.2e-3)
    problem = scene(material=material, mesh_data=mesh_data)
    stepper = solve(problem, dt=1.0, dt_max=1.0)
    assert sum(1 for r in stepper.records) > 1                     # the step was cut
    assert stepper.records[-1].time == pytest.approx(1.0)
    assert np.allclose(problem.w.x.array, reference.w.x.array, rtol=1e-7, atol=1e-12)
    # the committed history is the converged state, not a failed trial
    assert np.allclose(problem.gauss_points.state_old, problem.gauss_points.gradients)


class FailsOnRankZero(LinearElasticMaterial):
    def update(self, gradients, dt, state_old, flux_out, tangent_out, state_new, points=None):
        super().update(gradients, dt, state_old, flux_out, tangent_out, state_new, points)
        if MPI.COMM_WORLD.rank == 0 and abs(gradients).max() > 0:
            raise ConstitutiveError("local Newton did not converge at Gauss point 3")


class ReturnsNaN(LinearElasticMaterial):
    def update(self, gradients, dt, state_old, flux_out, tangent_out, state_new, points=None):
        super().update(gradients, dt, state_old, flux_out, tangent_out, state_new, points)
        flux_out[0, 0] = np.nan


@pytest.mark.parametrize("material, cause", [
    (FailsOnRankZero(ELASTIC), "local Newton did not converge at Gauss point 3"),
    (ReturnsNaN(ELASTIC), "non-finite stress"),
])
def test_failure_stops_with_named_cause(material, cause):
    """Failure on one rank only must not hang the others, and the message names it."""
    problem = scene(material=material)
    with pytest.raises(LoadSteppingError, match=cause):
        solve(problem, dt=0.5, dt_min=0.1)
    assert np.isfinite(problem.w.x.array).all()  # rolled back to the last converged state


def test_nonconvergent_newton_cut_back_message():
    """SNES limited to 0 iterations cannot converge: the stop names the SNES reason."""
    problem = scene(elasticity=ELASTIC)
    stepper = LoadStepper(problem, NewtonSolver(problem, options={"snes_max_it": 0}), dt=1.0,
                          dt_min=0.3, verbose=False)
    with pytest.raises(LoadSteppingError, match="SNES DIVERGED"):
        stepper.run()
