"""Explicit Cosserat dynamics (cosserat_fenicsx.dynamics, 003 eqs 31-34) against closed forms:
the optical rotation mode, the standing P wave, energy conservation, mass damping, the stable
step, inactive (DEM) cells, bad input. Global quantities only: the file also runs under mpirun."""
import math

import numpy as np
import pytest
from mpi4py import MPI

from cosserat_fenicsx import meshes
from cosserat_fenicsx.dynamics import DynamicsError, ExplicitCosserat
from cosserat_fenicsx.dynamics import verification as ver
from cosserat_fenicsx.elasticity import MicropolarElasticity
from cosserat_fenicsx.validation import InputError

COMM = MPI.COMM_WORLD
ELEMENTS = ["Q1/Q1", "P2/P1"]


@pytest.mark.parametrize("element", ELEMENTS)
def test_rotation_mode_period(element):
    """u held at zero, phi uniform: omega^2 = 4 mu_c / (rho j) (stable_step.py); the measured
    period within 1 % of the closed form, and the series is exactly the central difference's
    phi0 cos(omega_dt t)."""
    model, signal, omega = ver.rotation_mode(COMM, element, divisions=(3, 3))
    assert omega == pytest.approx(math.sqrt(4 * 0.5 / (2.0 * 0.01)))
    dt = 0.1 * model.stable_time_step()["rotational"]
    t, s = ver.run(model, signal, dt, 160)
    period = ver.zero_crossing_period(t, s)
    assert abs(period / (2 * math.pi / omega) - 1) < 0.01
    assert abs(period / (2 * math.pi / omega) - 1) > 1e-4           # the time error is there, O(dt^2)
    omega_dt = ver.verlet_frequency(omega, dt)
    assert np.abs(s - 1e-3 * np.cos(omega_dt * t)).max() < 1e-9 * 1e-3


def _p_wave_error(element, nx):
    model, signal, omega = ver.p_wave(COMM, element, nx=nx, ny=max(1, nx // 4))
    stable = model.stable_time_step()
    dt = 0.2 * stable["power"]
    t, s = ver.run(model, signal, dt, int(2.2 * 2 * math.pi / omega / dt))
    omega_h = ver.spatial_frequency(2 * math.pi / ver.zero_crossing_period(t, s), dt)
    return omega_h / omega - 1.0, stable["power"] / stable["translational"]


@pytest.mark.parametrize("element", ELEMENTS)
def test_standing_p_wave_dispersion(element):
    """Standing P wave of the strip (verification.p_wave): the FE frequency (Verlet's time
    error removed) converges at rate 2 on two meshes; on Q1 it is the 1D lumped linear element's
    (2 c/h) sin(k h / 2) exactly, and its stable step is h/c_p (the 1D closed form; the top
    mode of u1 with Dirichlet ends sits just below k = pi/h)."""
    (coarse, ratio_coarse), (fine, ratio_fine) = _p_wave_error(element, 4), _p_wave_error(element, 8)
    assert coarse < 0 and fine < 0                                    # lumped mass: too soft
    rate = math.log2(coarse / fine)
    assert 1.8 < rate < 2.2, (coarse, fine)
    if element == "Q1/Q1":
        assert 1.0 < ratio_fine < ratio_coarse < 1.1
        for nx, error in ((4, coarse), (8, fine)):
            h, k = 1.0 / nx, math.pi
            assert error == pytest.approx(2 / h * math.sin(k * h / 2) / k - 1, rel=1e-3)   # c_p = 1


def test_energy_conserved_to_second_order():
    """Undamped: kinetic + strain energy oscillates by O(dt^2) over many periods, no drift."""
    spread = []
    for fraction in (0.4, 0.2):
        model, signal, omega = ver.p_wave(COMM, "Q1/Q1", nx=6)
        dt = fraction * model.stable_time_step()["power"]
        _, _, energy = ver.run(model, signal, dt, int(10 * 2 * math.pi / omega / dt), energy=True)
        spread.append(np.ptp(energy) / energy[0])
        half = len(energy) // 2        # no drift: the second half spans the same band as the first
        assert abs(energy[half:].mean() / energy[:half].mean() - 1) < 0.1 * spread[-1]
    assert spread[0] < 0.05
    assert 3.5 < spread[0] / spread[1] < 4.5


@pytest.mark.parametrize("element", ELEMENTS)
def test_mass_damping_decay(element):
    """c_m: a free mode decays as exp(-c_m t / 2) (003 eq 33)."""
    omega = math.sqrt(4 * 0.5 / (2.0 * 0.01))
    c_m = 0.1 * omega
    model, signal, _ = ver.rotation_mode(COMM, element, divisions=(2, 2), mass_damping=c_m)
    dt = 0.05 * model.stable_time_step()["rotational"]
    t, s = ver.run(model, signal, dt, 500)
    assert ver.decay_rate(t, s) == pytest.approx(c_m / 2, rel=0.01)
    undamped, signal, _ = ver.rotation_mode(COMM, element, divisions=(2, 2))
    t, s = ver.run(undamped, signal, dt, 500)
    assert abs(ver.decay_rate(t, s)) < 1e-6 * c_m


@pytest.mark.parametrize("element", ELEMENTS)
def test_stable_step_rotational_closed_form_and_blow_up(element):
    """u held, l_c = 0: lambda_max(M^-1 K) is the optical mode exactly, so the power iteration
    gives 2/omega_r; 5 % above it the uniform rotation blows up (stopped, cause named), 5 %
    below it stays bounded; refused before any work when refuse_unstable."""
    model, signal, _ = ver.rotation_mode(COMM, element, divisions=(3, 3), l_c=0.0, refuse_unstable=False)
    steps = model.stable_time_step()
    assert steps["power"] == pytest.approx(steps["rotational"], rel=2e-3)
    assert steps["power"] <= steps["rotational"]
    with pytest.raises(DynamicsError, match="above the stable step"):
        for _ in range(1000):
            model.step(1.05 * steps["power"])
    stable, signal, _ = ver.rotation_mode(COMM, element, divisions=(3, 3), l_c=0.0)
    t, s = ver.run(stable, signal, 0.95 * steps["power"], 1000)
    assert np.abs(s).max() < 5 * 1e-3
    refusing, _, _ = ver.rotation_mode(COMM, element, divisions=(3, 3), l_c=0.0)
    before = refusing.displacement.array.copy()
    with pytest.raises(InputError, match="above the stable step"):
        refusing.step(1.05 * steps["power"])
    assert refusing.time == 0.0 and np.array_equal(refusing.displacement.array, before)


def test_mass_damping_keeps_the_stable_step():
    """Newmark beta = 0, gamma = 1/2 with the damping at v^{n+1} (eq 33): omega dt = 2 stays the
    limit whatever c_m (stable_step.py): heavily damped (c_m = omega_r), 3 % below it decays,
    5 % above it still blows up."""
    omega = math.sqrt(4 * 0.5 / (2.0 * 0.01))
    model, signal, _ = ver.rotation_mode(COMM, "Q1/Q1", divisions=(2, 2), l_c=0.0, mass_damping=omega)
    dt = model.stable_time_step()["power"]
    t, s = ver.run(model, signal, 0.97 * dt, 400)
    assert np.abs(s[-50:]).max() < 1e-3 * np.abs(s).max()
    unstable, _, _ = ver.rotation_mode(COMM, "Q1/Q1", divisions=(2, 2), l_c=0.0, mass_damping=omega,
                                       refuse_unstable=False)
    unstable.stable_time_step()
    with pytest.raises(DynamicsError, match="above the stable step"):
        for _ in range(4000):
            unstable.step(1.05 * dt)


@pytest.mark.serial
@pytest.mark.parametrize("element", ELEMENTS)
def test_power_iteration_against_dense_eigenvalues(element):
    """The power step against 2/sqrt(lambda_max) of the dense generalised problem (free square,
    micropolar, l_c > 0), and beside the closed-form estimates."""
    mesh, _, _ = meshes.rectangle(COMM, 1.0, 1.0, divisions=(3, 3), cell_type=ver.CELL_TYPES[element])
    elasticity = MicropolarElasticity(mu=1.0, lmbda=0.5, mu_c=0.3, l_c=0.2)
    model = ExplicitCosserat(mesh, elasticity, 1.5, 0.05, element=element,
                             dirichlet=[("u2", lambda x: np.isclose(x[1], 0.0), 0.0)])
    stiffness = model.stiffness.convert("dense").getDenseArray()
    free = model.free_dofs
    mass = model.mass.array[free]
    k = stiffness[np.ix_(free, free)] / np.sqrt(np.outer(mass, mass))
    lam = np.linalg.eigvalsh(k).max()
    steps = model.stable_time_step()
    assert steps["power"] == pytest.approx(0.999 * 2 / math.sqrt(lam), rel=1e-4)
    assert 0.1 < steps["power"] / steps["translational"] < 1.5


@pytest.mark.parametrize("element", ELEMENTS)
def test_inactive_cells_carry_no_mass_and_no_stiffness(element):
    """Cells in x < 0.5 inactive: total mass rho A_active and rotary inertia
    rho j A_active exactly; strain energies of a uniform stretch and a uniform rotation are
    those of the active half; no force on or from the dofs inside the inactive half."""
    import dolfinx.mesh
    mesh, _, _ = meshes.rectangle(COMM, 1.0, 1.0, divisions=(4, 2), cell_type=ver.CELL_TYPES[element])
    inactive = dolfinx.mesh.locate_entities(mesh, 2, lambda x: x[0] < 0.5 + 1e-9)   # all vertices
    mu, lmbda, mu_c, rho, j = 1.0, 0.7, 0.4, 3.0, 0.02
    model = ExplicitCosserat(mesh, MicropolarElasticity(mu=mu, lmbda=lmbda, mu_c=mu_c, l_c=0.1), rho, j,
                             element=element, inactive_cells=inactive)
    translational, rotary = model.total_mass
    assert translational == pytest.approx(rho * 0.5, rel=1e-13)
    assert rotary == pytest.approx(rho * j * 0.5, rel=1e-13)

    def set_field(name, values):
        space, dofs = model.subspace(name)
        from dolfinx.fem import Function
        f = Function(space)
        f.interpolate(values)
        owned = dofs < len(model.displacement.array)
        model.displacement.array[dofs[owned]] = f.x.array[owned]

    set_field("u1", lambda x: x[0])
    model.update_acceleration()
    assert model.strain_energy() == pytest.approx(0.5 * (lmbda + 2 * mu) * 0.5, rel=1e-12)
    model.displacement.array[:] = 0.0
    set_field("phi", lambda x: np.ones(x.shape[1]))
    assert model.strain_energy() == pytest.approx(0.5 * 4 * mu_c * 0.5, rel=1e-12)

    massless = model.mass.array == 0.0
    assert COMM.allreduce(int(massless.sum())) > 0
    rng = np.random.default_rng(COMM.rank)
    model.displacement.array[:] = np.where(massless, rng.random(len(massless)), 0.0)
    force = model.stiffness.createVecLeft()
    model.internal_force(model.displacement, force)
    assert force.norm() == 0.0
    assert model.strain_energy() == 0.0

    # the particles' mass makes the dofs active in time stepping
    added = model.mass.copy()
    added.array[:] = np.where(massless, 0.25, 0.0)
    model.add_mass(added)
    assert COMM.allreduce(int((model.mass.array == 0.0).sum())) == 0


@pytest.mark.parametrize("element", ELEMENTS)
def test_gravity_column_settles_to_the_closed_form(element):
    """A column under its own weight (sides u1 = 0, bottom fixed), relaxed with mass damping:
    u2(y) = -rho g (H y - y^2 / 2) / (lambda + 2 mu), the uniaxial-strain closed form. On Q1
    the column is the 1D linear element with the lumped (here consistent) load: nodally
    exact; on P2 the HRZ-lumped load is not the consistent one, so within a few per cent.
    The weight is the continuum's own mass times g, and added mass does not change it."""
    width, height, rho, g = 0.5, 2.0, 2.0, 0.01
    mu, lmbda = 0.3, 0.4
    mesh, _, _ = meshes.rectangle(COMM, width, height, divisions=(1, 8), cell_type=ver.CELL_TYPES[element])
    sides = lambda x: np.isclose(x[0], 0.0) | np.isclose(x[0], width)    # noqa: E731
    bottom = lambda x: np.isclose(x[1], 0.0)                              # noqa: E731
    c_p = math.sqrt((lmbda + 2 * mu) / rho)
    model = ExplicitCosserat(mesh, MicropolarElasticity(mu=mu, lmbda=lmbda, mu_c=0.03, l_c=0.05), rho, 1.0,
                             mass_damping=math.pi * c_p / height, element=element, gravity=(0.0, -g),
                             dirichlet=[("u1", sides, 0.0), ("u1", bottom, 0.0), ("u2", bottom, 0.0)])
    space, dofs = model.subspace("u2")
    owned = dofs < len(model.displacement.array)
    y = space.tabulate_dof_coordinates()[owned, 1]
    weight = COMM.allreduce(float(model.weight[dofs[owned]].sum()))
    assert weight == pytest.approx(-rho * width * height * g, rel=1e-12)
    model.update_acceleration()
    dt = 0.8 * model.stable_time_step()["power"]
    for _ in range(int(40.0 / (0.5 * model.mass_damping) / dt)):       # exp(-c_m t / 2) < 1e-17
        model.step(dt)
    u2 = model.displacement.array[dofs[owned]]
    exact = -rho * g * (height * y - 0.5 * y ** 2) / (lmbda + 2 * mu)
    error = COMM.allreduce(float(np.abs(u2 - exact).max(initial=0.0)), op=MPI.MAX)
    top = rho * g * 0.5 * height ** 2 / (lmbda + 2 * mu)
    if element == "Q1/Q1":
        assert error < 1e-9 * top
        phi_dofs = model.subspace("phi")[1]
        phi = model.displacement.array[phi_dofs[phi_dofs < len(model.displacement.array)]]
        assert COMM.allreduce(float(np.abs(phi).max(initial=0.0)), op=MPI.MAX) < 1e-9 * top / height
    else:
        assert 1e-6 * top < error < 0.05 * top
    added = model.mass.copy()
    added.array[:] = 1.0
    model.add_mass(added)
    assert COMM.allreduce(float(model.weight[dofs[owned]].sum())) == pytest.approx(weight, rel=1e-14)


def test_gravity_refusal_and_no_weight_without_it():
    mesh, _, _ = meshes.rectangle(COMM, 1.0, 1.0, divisions=(2, 2), cell_type="quadrilateral")
    elasticity = MicropolarElasticity(mu=1.0, lmbda=1.0, mu_c=0.5, l_c=0.1)
    for bad in ((0.0,), (0.0, float("inf")), "down", None):
        with pytest.raises(InputError, match="gravity must be two finite numbers"):
            ExplicitCosserat(mesh, elasticity, 1.0, 0.01, element="Q1/Q1", gravity=bad)
    model = ExplicitCosserat(mesh, elasticity, 1.0, 0.01, element="Q1/Q1")
    model.update_acceleration()
    assert model.acceleration.norm() == 0.0 and not model.weight.any()
    with pytest.raises(InputError, match="mass_damping must be >= 0"):
        model.set_mass_damping(-1.0)


def test_gauss_point_material_in_its_elastic_range_is_the_linear_path():
    """ExplicitCosserat(material=...): the lattice's Coulomb material, which sticks under a
    column's weight (k_S < mu k_N), gives the cubic law's K d path to round-off; its state()
    carries the Gauss-point history and set_state() continues the run bit for bit."""
    from cosserat_fenicsx.lattice_elasticity import SquareLatticeElasticity
    from cosserat_fenicsx.materials.lattice_coulomb import LatticeCoulombMaterial
    mesh, _, _ = meshes.rectangle(COMM, 2.0, 4.0, divisions=(2, 4), cell_type="quadrilateral")
    law = SquareLatticeElasticity(2.5e8, 5e7, l_c=0.05)
    sides = lambda x: np.isclose(x[0], 0.0) | np.isclose(x[0], 2.0)      # noqa: E731
    bottom = lambda x: np.isclose(x[1], 0.0)                              # noqa: E731
    bcs = [("u1", sides, 0.0), ("u1", bottom, 0.0), ("u2", bottom, 0.0)]
    options = dict(mass_damping=50.0, element="Q1/Q1", dirichlet=bcs, gravity=(0.0, -9.81))
    linear = ExplicitCosserat(mesh, law, 2042.0, 1e-3, **options)
    plastic = ExplicitCosserat(mesh, law, 2042.0, 1e-3, **options,
                               material=LatticeCoulombMaterial(2.5e8, 5e7, 0.5, law.bending_modulus))
    dt = 0.5 * linear.stable_time_step()["power"]
    for model in (linear, plastic):
        model.update_acceleration()
        for _ in range(200):
            model.step(dt)
    size = COMM.allreduce(float(np.abs(linear.displacement.array).max(initial=0.0)), op=MPI.MAX)
    gap = COMM.allreduce(float(np.abs(linear.displacement.array - plastic.displacement.array).max(initial=0.0)),
                         op=MPI.MAX)
    assert size > 0.0 and gap < 1e-12 * size
    state = plastic.state()
    assert "gauss_history" in state and state["gauss_history"].shape[1] == 4
    plastic.step(dt)
    after = plastic.displacement.array.copy()
    plastic.set_state(state)
    plastic.step(dt)
    assert np.array_equal(plastic.displacement.array, after)
    state.pop("gauss_history")
    with pytest.raises(InputError, match="Gauss-point arrays"):
        plastic.set_state(state)
    assert np.array_equal(plastic.displacement.array, after)          # refused before any change


def test_hrz_lumping_of_p2():
    """Two triangles of area 1/2: HRZ gives rho A/19 at a vertex of one triangle and
    2 x 16 rho A/57 at the midpoint of the shared diagonal (Hinton, Rock & Zienkiewicz 1976)."""
    mesh, _, _ = meshes.rectangle(COMM, 1.0, 1.0, divisions=(1, 1), cell_type="triangle")
    rho = 3.0
    model = ExplicitCosserat(mesh, MicropolarElasticity(mu=1.0, lmbda=1.0, mu_c=0.5), rho, 0.01)
    assert model.mass_info["hrz_factor"] == pytest.approx(30 / 19, rel=1e-12)
    dofs = model.subspace("u1")[1]
    masses = model.mass.array[dofs[dofs < len(model.mass.array)]]
    low = COMM.allreduce(masses.min() if len(masses) else np.inf, op=MPI.MIN)
    high = COMM.allreduce(masses.max() if len(masses) else 0.0, op=MPI.MAX)
    assert low == pytest.approx(rho * 0.5 / 19, rel=1e-12)
    assert high == pytest.approx(2 * 16 * rho * 0.5 / 57, rel=1e-12)


def test_predict_correct_with_coupling_force_is_eq_33():
    """A constant force on free dofs: a = M^-1 f (undamped) after one step from rest."""
    model, _, _ = ver.rotation_mode(COMM, "Q1/Q1", divisions=(2, 2), phi0=0.0)
    force = model.mass.copy()
    free = model.free_dofs
    force.array[:] = np.where(free, 0.3 * model.mass.array, 0.0)
    dt = 0.1 * model.stable_time_step()["power"]
    v_tilde = model.predict(dt)
    assert v_tilde.norm() == 0.0
    model.correct(dt, coupling_force=force)
    assert np.allclose(model.acceleration.array[free], 0.3)       # d is still zero: no K d yet
    assert np.all(model.acceleration.array[~free] == 0.0)
    assert np.allclose(model.velocity.array[free], 0.5 * dt * 0.3)
    state = model.state()
    model.step(dt)
    model.set_state(state)
    assert model.time == pytest.approx(dt) and np.array_equal(model.velocity.array, state["velocity"])


def test_refusals():
    mesh, _, _ = meshes.rectangle(COMM, 1.0, 1.0, divisions=(2, 2), cell_type="quadrilateral")
    elasticity = MicropolarElasticity(mu=1.0, lmbda=1.0, mu_c=0.5, l_c=0.1)
    for kwargs, message in (({"density": -1.0}, "density must be > 0"),
                            ({"micro_inertia": 0.0}, "micro_inertia must be > 0"),
                            ({"mass_damping": -0.1}, "mass_damping must be >= 0"),
                            ({"element": "P2/P1"}, "needs a triangle mesh"),
                            ({"element": "Q2"}, "element must be one of"),
                            ({"dirichlet": [("u3", lambda x: x[0] < 0, 0.0)]}, "component must be one of"),
                            ({"dirichlet": [("u1", lambda x: x[0] < 0, float("nan"))]}, "finite number"),
                            ({"inactive_cells": np.array([-1])}, "local cell indices")):
        args = {"density": 1.0, "micro_inertia": 0.01, "element": "Q1/Q1", **kwargs}
        with pytest.raises(InputError, match=message):
            ExplicitCosserat(mesh, elasticity, **args)
    with pytest.raises(InputError, match="mu_c > 0"):
        ExplicitCosserat(mesh, MicropolarElasticity(mu=1.0, lmbda=1.0, mu_c=0.0), 1.0, 0.01, element="Q1/Q1")
    model = ExplicitCosserat(mesh, elasticity, 1.0, 0.01, element="Q1/Q1", inactive_cells=[])
    assert model.total_mass == pytest.approx((1.0, 0.01))
    with pytest.raises(InputError, match="dt must be > 0"):
        model.step(-1.0)
    with pytest.raises(InputError, match="must follow predict"):
        model.correct(1e-3)
    bad = model.mass.copy()
    bad.array[:] = np.nan
    model.predict(1e-3)
    with pytest.raises(DynamicsError, match="coupling force is not finite"):
        model.correct(1e-3, coupling_force=bad)
    with pytest.raises(InputError, match="added mass"):
        model.add_mass(bad)
