"""The conservative coupling of the region's nodes (coupler.py's docstring: region_nodes=
"projected"): the region's own nodes are eq 3's projection d_hat(q) of the grains to
round-off (with eq 16 they are not), the undamped patch keeps the energy of the potential
system, and eq 16's force on the nodes that drive the virtual grains is refused with it."""
import numpy as np
import pytest
from mpi4py import MPI

from benchmarks.bsm.patch_drift import potential_system_energy
from benchmarks.bsm.patch_test import build
from cosserat_fenicsx.validation import InputError

ROOT = MPI.COMM_WORLD.rank == 0
SIZE, DELTA = 4.0, 4e-4
BCS = [("u1", lambda x: np.isclose(x[0], 0.0), 0.0), ("u1", lambda x: np.isclose(x[0], SIZE), -DELTA),
       ("u2", lambda x: np.isclose(x[1], 0.0), 0.0), ("u2", lambda x: np.isclose(x[1], SIZE), -DELTA)]


def relaxed_then_free(region_nodes, relax=500, free=1000):
    continuum, region, engine, coupler, _ = build(0.1, mass_damping=600.0, dirichlet=BCS,
                                                  region_nodes=region_nodes)
    coupler.run(relax)
    continuum.mass_damping = 0.0
    if engine is not None:
        engine.options = engine.options.with_(mass_damping=0.0)
    h0 = potential_system_energy(continuum, coupler)
    coupler.run(free)
    return continuum, coupler, h0


def test_projected_region_nodes_are_the_grains_projection_and_keep_the_energy():
    continuum, coupler, h0 = relaxed_then_free("projected")
    # the patch (4 x 4 Q1, region 2 x 2 cells) has one node of its own: the centre (u1, u2, phi)
    assert MPI.COMM_WORLD.allreduce(int(np.count_nonzero(coupler.projected_dofs))) == 3
    gap_u, gap_phi = coupler.projection_gap()
    # round-off of d_hat against the confinement displacement DELTA and rotations of ~1e-6
    assert gap_u < 1e-14 * DELTA and gap_phi < 1e-16
    h = potential_system_energy(continuum, coupler)
    # measured 1.7e-9 relative over 1000 undamped steps (the leapfrog's half-step velocities)
    assert abs(h - h0) < 2e-8 * h0


def test_eq16_region_nodes_are_not_the_projection():
    """The same patch under eq 16 (default): the centre node, driven by N_R^T F_R with the
    lumped mass, is off d_hat(q) (what the projected option removes)."""
    _, coupler, _ = relaxed_then_free("integrated", free=0)
    assert not coupler.projected_dofs.any()
    gap_u, gap_phi = coupler.projection_gap()
    # measured 6.6e-4 DELTA (2.6e-7 m) after the damped relaxation
    assert gap_u > 1e-4 * DELTA


def test_projected_region_nodes_refuse_eq16_forces():
    with pytest.raises(InputError, match="region_nodes='projected' takes coarse_force='interface'"):
        build(0.1, region_nodes="projected", coarse_force="grains")
    with pytest.raises(InputError, match="region_nodes must be"):
        build(0.1, region_nodes="consistent")
