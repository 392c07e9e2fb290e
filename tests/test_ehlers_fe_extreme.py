"""Stiff and extreme cases of the FE Ehlers model, on small meshes: each
one converges, or stops with a LoadSteppingError whose message names the cause; never a
NaN, never a hang. In-process, so they also run under `mpirun -n 2`, where a failure on
one rank must stop both ranks with the same message."""
import numpy as np
import pytest
from mpi4py import MPI

from cosserat_fenicsx import meshes
from cosserat_fenicsx.problem import CosseratProblem
from cosserat_fenicsx.scenes.biaxial import BiaxialSettings, BiaxialTest
from cosserat_fenicsx.snes import NewtonSolver
from cosserat_fenicsx.stepping import LoadStepper, LoadSteppingError
from cosserat_fenicsx.constitutive import ConstitutiveError
from cosserat_fenicsx.materials.ehlers import EhlersMaterial

COMM = MPI.COMM_WORLD
SMALL = dict(cell_size=0.0125, consolidation_steps=3)


def run(**kwargs):
    s = BiaxialSettings(**dict(SMALL, **kwargs))
    test = BiaxialTest(COMM, s, verbose=False)
    rows = test.run()
    assert all(np.isfinite(r["vertical_stress"]) for r in rows)
    assert np.isfinite(test.problem.w.x.array).all()
    return test, rows


def test_very_small_internal_length():
    """l_c = 1 um: the couple stress modulus 2 mu_c l_c^2 is 1e-10 of mu m^2; the rotation
    is still determined (by mu_c through the skew strain)."""
    test, rows = run(material=dict(l_c=1e-6), axial_strain=0.02, steps=5)
    assert rows[-1]["axial_strain"] == pytest.approx(-0.02)


def test_very_large_internal_length():
    """l_c = 1 m, ten times the specimen: the rotation is forced to be nearly uniform."""
    test, rows = run(material=dict(l_c=1.0), axial_strain=0.02, steps=5)
    assert rows[-1]["axial_strain"] == pytest.approx(-0.02)


def test_vanishing_cosserat_modulus():
    """mu_c = 1e-6 mu: rotation and displacement nearly decouple; the curvature term
    2 mu_c l_c^2 still holds the rotation field."""
    test, rows = run(material=dict(mu_c=91.0), axial_strain=0.02, steps=5)
    assert rows[-1]["axial_strain"] == pytest.approx(-0.02)


def test_tiny_viscosity():
    """eta = 1e-12 s against 1 s steps: the rate-independent limit (2.80); F <= 1e-6 Pa."""
    test, rows = run(eta=1e-12, axial_strain=0.02, steps=5)
    assert rows[-1]["axial_strain"] == pytest.approx(-0.02)
    assert max(r["max_yield_function"] for r in rows) < 1e-3


def test_load_step_far_too_large_is_cut_and_recovers():
    """The whole compression to 3 % in one step: the stepper cuts it back and recovers.
    The end point differs from the 30-step curve by the time-discretisation error of the
    large accepted steps (implicit Euler, up to 1/4 of the range), about 10 %."""
    test, rows = run(axial_strain=0.03, steps=1, weak_size=0.0, eta=1e-4)
    assert rows[-1]["cuts"] > 0
    assert rows[-1]["axial_strain"] == pytest.approx(-0.03)
    ref, ref_rows = run(axial_strain=0.03, steps=30, weak_size=0.0, eta=1e-4)
    assert rows[-1]["vertical_stress"] == pytest.approx(ref_rows[-1]["vertical_stress"], rel=0.15)


def test_near_the_compression_point():
    """Confining pressure 5 MN/m^2: the plane-strain consolidation compacts the sand to
    x = tr eps_e at 3/4 of eps_crit (eq 2.70, the bulk tangent lambda c^2/(c-x)^2 is 16
    lambda there), and the FE still converges. Beyond (8 MN/m^2) the material point of
    the consolidation stops with a ConstitutiveError naming the local failure."""
    test, rows = run(confining=5e6, consolidation_steps=20, axial_strain=0.002, steps=2, weak_size=0.0)
    st, idx = test.gauss_points.state_old, test.material.state_index
    eps_p_vol = st[:, idx["eps_p11"]] + st[:, idx["eps_p22"]] + st[:, idx["eps_p33"]]
    x = st[:, idx["eps11"]] + st[:, idx["eps22"]] - eps_p_vol
    p = test.material.parameters
    c = 1.0 - p.n_max / (p.n0 * (1.0 - eps_p_vol))
    assert COMM.allreduce(float((x / c).min()), op=MPI.MIN) > 0.7
    assert rows[19]["vertical_stress"] == pytest.approx(-5e6, rel=1e-3)
    with pytest.raises(ConstitutiveError, match="did not converge|compression point"):
        run(confining=8e6, consolidation_steps=20, axial_strain=0.002, steps=2)


def test_tensile_state_in_a_frictional_material_is_named():
    """Pulling a stress-free block of sand: no admissible stress (F > 0 for every
    I_sigma > 0, eq 2.76). The stepper cuts back to dt_min and names the cause."""
    mesh, tags, names = meshes.rectangle(COMM, 0.05, 0.1, 0.025)
    problem = CosseratProblem(mesh, tags, names, material=EhlersMaterial.hostun())
    problem.add_dirichlet("bottom", "u2", 0.0)
    problem.add_point_dirichlet((0.025, 0.0), "u1", 0.0)
    problem.add_dirichlet("top", "u2", 1e-4)
    stepper = LoadStepper(problem, NewtonSolver(problem), t_end=1.0, dt=1.0, dt_min=0.25, verbose=False)
    with pytest.raises(LoadSteppingError, match="tensile state"):
        stepper.run()
    assert np.isfinite(problem.w.x.array).all()


@pytest.mark.parametrize("bad", [dict(step_time=0.0), dict(step_time=-1.0), dict(cell_size=-1e-3)])
def test_bad_biaxial_settings_stop_before_any_work(bad):
    with pytest.raises(ValueError, match=next(iter(bad))):
        BiaxialTest(COMM, BiaxialSettings(**dict(SMALL, **bad)), verbose=False)
