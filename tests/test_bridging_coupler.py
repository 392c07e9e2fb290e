"""The coupled bridging-scale loop (003 eqs 25-34) on a hexagonal patch whose continuum has
the lattice's exact moduli (benchmarks/bsm/patch_test.py): ghost forces of the affine state
shrink with r / h, a uniformly compressed patch relaxes to the affine state with a vanishing
fine part, and bad input or escaping grains stop with their cause named."""
import math

import numpy as np
import pytest

from benchmarks.bsm.patch_test import CASES, build, ghost_forces
from cosserat_fenicsx.bridging.coupler import BridgingCoupler, BridgingStopped
from cosserat_fenicsx.validation import InputError

from mpi4py import MPI

ROOT = MPI.COMM_WORLD.rank == 0


def test_ghost_forces_shrink_with_grain_size():
    coarse = ghost_forces(0.1, CASES["confined"])
    fine = ghost_forces(0.05, CASES["confined"])
    # measured: 18.8 % and 5.9 % of the largest interface nodal force (r / h = 0.1, 0.05)
    assert fine["residual_over_interface"] < 0.08
    assert fine["residual_over_interface"] < 0.75 * coarse["residual_over_interface"]
    # no spurious couple: the affine state has no rotation gradient
    assert fine["max_moment_residual"] < 1e-6 * fine["max_interface_force_N_per_m"]


def test_confined_patch_relaxes_to_the_affine_state():
    size, strain = 4.0, 1e-4
    delta = strain * size
    bcs = [("u1", lambda x: np.isclose(x[0], 0.0), 0.0), ("u1", lambda x: np.isclose(x[0], size), -delta),
           ("u2", lambda x: np.isclose(x[1], 0.0), 0.0), ("u2", lambda x: np.isclose(x[1], size), -delta)]
    continuum, region, engine, coupler, _ = build(0.1, mass_damping=600.0, dirichlet=bcs)
    coupler.run(250)
    parts = coupler.fine_part()
    if ROOT:
        q, nd, fine = parts
        affine = -strain * region.position[region.real]
        # grains near the affine field (the ghost forces bend it near the interface)
        assert np.abs(q[:, :2] - affine).max() < 0.03 * delta
        assert np.abs(fine[:, :2]).max() < 0.01 * delta
        assert coupler.last_mismatch < 1e-3
    for name, comp in (("u1", 0), ("u2", 1)):
        space, dofs = continuum.subspace(name)
        x = space.tabulate_dof_coordinates()[:, :2]
        d = continuum.displacement.array[dofs[dofs < continuum.displacement.getLocalSize()]]
        # measured 4.0 % (r / h = 0.1): the ghost forces of the interface nodes
        assert np.abs(d + strain * x[dofs < continuum.displacement.getLocalSize(), comp]).max() < 0.06 * delta
    timing = coupler.timing_summary()
    assert set(timing["wall_s"]) == {"dem", "projection", "fe", "interface"}


def test_patch_settles_under_gravity_as_the_continuum():
    """Gravity: the grains' weight enters the region's nodes (F_R + m g in eq 16) and the
    patch, relaxed under its own weight (sides u1 = 0, bottom fixed), settles as the pure
    continuum of the same moduli and density does; a DEM region under another g is refused."""
    from cosserat_fenicsx.dynamics import ExplicitCosserat
    size, g = 4.0, (0.0, -9.81)
    bcs = [("u1", lambda x: np.isclose(x[0], 0.0) | np.isclose(x[0], size), 0.0),
           ("u1", lambda x: np.isclose(x[1], 0.0), 0.0), ("u2", lambda x: np.isclose(x[1], 0.0), 0.0)]
    # c_m = 2 omega_1 (omega_1 = pi c_p / (2 size) = 151 rad/s): every mode decays as
    # exp(-omega_1 t) or faster, to e^-20 in 1200 steps
    continuum, region, engine, coupler, _ = build(0.1, mass_damping=300.0, dirichlet=bcs, gravity=g)
    coupler.run(1200)
    reference = ExplicitCosserat(continuum.mesh, continuum.elasticity, continuum.density, continuum.micro_inertia,
                                 mass_damping=300.0, element="Q1/Q1", dirichlet=bcs, gravity=g)
    for _ in range(1200):
        reference.step(coupler.dt)
    space, dofs = continuum.subspace("u2")
    owned = dofs[dofs < continuum.displacement.getLocalSize()]
    comm = continuum.comm
    settled = comm.allreduce(float(np.abs(reference.displacement.array[owned]).max(initial=0.0)), op=MPI.MAX)
    gap = comm.allreduce(float(np.abs(continuum.displacement.array[owned]
                                      - reference.displacement.array[owned]).max(initial=0.0)), op=MPI.MAX)
    # closed form at the top: rho g H^2 / (2 (lambda + 2 mu)); the relaxed continuum is on it
    elastic = continuum.elasticity
    top = continuum.density * 9.81 * size ** 2 / (2 * (elastic.lmbda + 2 * elastic.mu))
    assert settled == pytest.approx(top, rel=0.01)
    # measured 3.5 % (the ghost forces of the interface at r / h = 0.1); without the grains'
    # weight in F_R the nodes are 8 times the settlement off
    assert gap < 0.05 * settled
    from cosserat_fenicsx.bridging.region import region_cells
    weightless = ExplicitCosserat(continuum.mesh, continuum.elasticity, continuum.density, continuum.micro_inertia,
                                  element="Q1/Q1", inactive_cells=region_cells(continuum.mesh, (1.0, 3.0, 1.0, 3.0)),
                                  dirichlet=bcs)
    with pytest.raises(InputError, match="gravity .* is not the continuum's"):
        BridgingCoupler(weightless, region, engine, coupler.dt, coupler.substeps, fine_dt=coupler.dt_fine)


def test_coarse_step_above_the_stable_one_is_refused():
    continuum, region, engine, coupler, _ = build(0.1)
    stable = coupler.stable_dt["power"]
    m = math.ceil(1.5 * stable / coupler.dt_fine)
    with pytest.raises(InputError, match="above the continuum's stable step"):
        BridgingCoupler(continuum, region, engine, coupler.dt_fine * m, m, fine_dt=coupler.dt_fine)


def test_mismatched_dem_step_is_refused():
    continuum, region, engine, coupler, _ = build(0.1)
    with pytest.raises(InputError, match="dt / substeps"):
        BridgingCoupler(continuum, region, engine, coupler.dt, coupler.substeps, fine_dt=0.5 * coupler.dt_fine)


def test_grains_leaving_the_region_stop_the_run():
    continuum, region, engine, coupler, _ = build(0.1)
    if ROOT:
        # throw one real grain out of the region at 2000 m/s (the region lives on rank 0)
        k = int(np.argmin(engine.order != 0))
        engine.state.velocity[k] = (0.0, -2000.0)
    with pytest.raises(BridgingStopped, match="left the DEM region|DEM region stopped"):
        coupler.run(20)


def test_compressive_pulse_crosses_the_interface():
    """T4/T5 (benchmarks/bsm/wave.py): a plane P pulse of wavelength ~ 16 h, 80 r through a
    region with the continuum's exact moduli: small reflection, energy kept."""
    from benchmarks.bsm.wave import run
    t, bsm, c_p = run(1.0)
    energies = run.energies
    _, fe, _ = run(1.0, coupled=False)
    window = t > 4.0 / c_p
    # measured 0.68 % of the step and 0.46 % largest energy deviation
    assert np.max(np.abs(bsm[window] - fe[window])) < 0.015 * 1e-4
    assert np.max(np.abs(energies - energies[0])) < 0.01 * energies[0]


def test_one_engine_call_per_coarse_step_with_the_end_of_step_forces():
    """The m sub-steps are one engine call (the virtual grains' path inside the engine); the
    coarse forces are those at q^{n+1} (forces_now, which the engine's next step reproduces);
    no contact between two virtual grains is computed; a bad option is refused."""
    continuum, region, engine, coupler, _ = build(0.1)
    assert coupler.substeps > 1 and coupler.force_time == "end"
    if ROOT:
        calls = []
        follow = engine.follow_held_path
        engine.follow_held_path = lambda *a: (calls.append(a[0]), follow(*a))
        seen = []
        forces_now = engine.forces_now
        engine.forces_now = lambda **kw: seen.append(forces_now(**kw)) or seen[-1]
    for _ in range(3):
        coupler.step()
    if ROOT:
        assert calls == [coupler.substeps] * 3
        assert len(seen) == 3
        st = engine.state
        virtual = region.is_virtual[engine.order]
        both = virtual[st.pair_i] & virtual[st.pair_j]
        assert both.any() and not np.any(st.touching[both])
        follow(1, np.zeros((region.n_discs, 3)), np.zeros((region.n_discs, 3)), np.zeros((region.n_discs, 3)))
        # (the held discs jump during that step, but the forces are those of its start)
        assert np.array_equal(engine.disc_forces(), seen[-1])
    with pytest.raises(InputError, match="coarse_force"):
        BridgingCoupler(continuum, region, engine, coupler.dt, coupler.substeps, fine_dt=coupler.dt_fine,
                        coarse_force="virtual")


def test_state_restored_on_a_fresh_coupler_repeats_the_run():
    """state() taken mid-run and set_state() on a coupler built anew continue the straight run
    bit for bit (continuum, grains with their contact history, the mismatch)."""
    size, delta = 4.0, 4e-4
    bcs = [("u1", lambda x: np.isclose(x[0], size), -delta), ("u2", lambda x: np.isclose(x[1], 0.0), 0.0)]
    continuum, region, engine, coupler, _ = build(0.1, mass_damping=100.0, dirichlet=bcs)
    coupler.run(20)
    saved = {k: np.array(v, copy=True) for k, v in coupler.state().items()}
    coupler.run(20)
    straight = coupler.state()
    continuum2, _, engine2, fresh, _ = build(0.1, mass_damping=100.0, dirichlet=bcs)
    fresh.set_state(MPI.COMM_WORLD.allgather(saved))   # every saved rank's state, as a checkpoint holds them
    assert fresh.steps == 20
    fresh.run(20)
    again = fresh.state()
    assert sorted(again) == sorted(straight)
    for key in straight:
        if key != "coupler_wall":
            assert np.array_equal(straight[key], again[key]), key
    if ROOT:
        assert np.abs(straight["continuum_displacement"]).max() > 0.0 and straight["coupler_max_mismatch"] > 0.0
    broken = dict(saved)
    broken.pop("continuum_velocity")
    with pytest.raises(InputError, match="lacks continuum_velocity"):
        fresh.set_state(MPI.COMM_WORLD.allgather(broken))
