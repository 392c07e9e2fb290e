"""A compression pulse crossing the bridging-scale interface (003-bsm.md T5): reflection.

A 12 m x 4 m Cosserat strip (Q1, h = 0.25 m; top and bottom u2 = 0, so that the pulse stays
plane) holds a 4 m x 2 m DEM region at its centre: a hexagonal lattice (r = 0.05 m) whose
affine moduli are the continuum's (demcell.estimates.hexagonal_moduli) and whose mass per
area is the continuum's density, so that a perfect coupling reflects nothing. A right-moving
compressive P pulse, u1 = A/2 (1 - erf((x - x0)/w)) (strain -A/(w sqrt(pi)) exp(-((x-x0)/w)^2),
never tensile: the unbonded lattice, touching without overlap, cannot carry tension),
v1 = -c_p du1/dx, starts at x0 = 2 m. A probe at x = 3 m records u1(t); the same run without
the region (pure FE, same mesh) is the reference, and the reflection coefficient is
max |u1_BSM - u1_FE| / A over the time after the incident pulse has passed the probe (a
reflected pulse of coefficient R adds R A to the displacement step; R^2: the reflected
energy fraction).
003 neglects reflection; this measures it at two pulse widths (wavelength ~ 4 w).

    PYTHONPATH=. python3 benchmarks/bsm/wave.py [--widths 0.5 1.0]
"""
import argparse
import json
import math
import os
import time

import dolfinx.fem
import dolfinx.mesh
import numpy as np
from mpi4py import MPI

from benchmarks.bsm.patch_test import DENSITY, KN, KS, hexagonal_packing
from cosserat_fenicsx.bridging.coupler import BridgingCoupler
from cosserat_fenicsx.bridging.region import build_region, region_cells
from cosserat_fenicsx.dynamics.explicit import ExplicitCosserat
from cosserat_fenicsx.elasticity import MicropolarElasticity

LX, LY, H = 12.0, 4.0, 0.25
BOX = (4.0, 8.0, 1.0, 3.0)
RADIUS = 0.05


def run(width, amplitude=1e-4, coupled=True, x0=2.0, probe=(3.0, 2.0), mass_damping=0.0):
    from demcell.contact_law import ContactLaw
    from demcell.estimates import hexagonal_moduli
    from demcell.specimen import Specimen, SpecimenOptions, SpecimenState
    comm = MPI.COMM_WORLD
    mesh = dolfinx.mesh.create_rectangle(comm, [np.array([0.0, 0.0]), np.array([LX, LY])],
                                         [int(LX / H), int(LY / H)], dolfinx.mesh.CellType.quadrilateral)
    moduli = hexagonal_moduli(KN, KS, 0.0, RADIUS)
    elasticity = MicropolarElasticity(mu=moduli["G"], lmbda=moduli["lambda_"], mu_c=moduli["mu_c"], l_c=0.0)
    rho_c = DENSITY * math.pi / (2.0 * math.sqrt(3.0))
    bcs = [("u2", lambda x: np.isclose(x[1], 0.0) | np.isclose(x[1], LY), 0.0)]
    continuum = ExplicitCosserat(mesh, elasticity, rho_c, 0.5 * RADIUS ** 2, mass_damping=mass_damping,
                                 element="Q1/Q1", inactive_cells=region_cells(mesh, BOX) if coupled else None,
                                 dirichlet=bcs)
    c_p = math.sqrt((moduli["lambda_"] + 2 * moduli["G"]) / rho_c)
    # the pulse: u1 = g(x), v1 = -c_p g'(x)
    work_d = dolfinx.fem.Function(continuum.space)
    work_v = dolfinx.fem.Function(continuum.space)
    space, dofs = continuum.subspace("u1")
    x = space.tabulate_dof_coordinates()[:, 0]
    from scipy.special import erf
    work_d.x.array[dofs] = 0.5 * amplitude * (1.0 - erf((x - x0) / width))
    work_v.x.array[dofs] = c_p * amplitude / (width * math.sqrt(math.pi)) * np.exp(-((x - x0) / width) ** 2)
    n_owned = continuum.displacement.getLocalSize()
    continuum.displacement.array[:] = work_d.x.array[:n_owned]
    continuum.velocity.array[:] = work_v.x.array[:n_owned]
    for vec in (continuum.displacement, continuum.velocity):
        continuum._forward(vec)
    coupler = None
    dt_fine = 0.1 * math.sqrt(DENSITY * math.pi * RADIUS ** 2 / KN)
    if coupled:
        position = hexagonal_packing((0.0, LX, 0.0, LY), RADIUS)
        r = np.full(len(position), RADIUS)
        m = DENSITY * math.pi * r ** 2
        region = build_region(position, r, m, 0.5 * m * r ** 2, BOX, (0.0, LX, 0.0, LY))
        engine = None
        if comm.rank == 0:
            state = SpecimenState.from_discs(region.position, region.radius, region.mass, region.inertia,
                                             (0.0, LX, 0.0, LY), lateral="none")
            engine = Specimen(state, ContactLaw(kn=KN, ks=KS, friction=math.inf),
                              SpecimenOptions(dt=dt_fine, lateral="none", mass_damping=mass_damping,
                                              normal_dashpot=0.0, tangential_dashpot=0.0, threads=1))
            engine.hold(region.is_virtual)
        coupler = BridgingCoupler(continuum, region, engine, 2 * dt_fine, 2, fine_dt=dt_fine)
        dt = coupler.dt
    else:
        dt = 2 * dt_fine
    continuum.update_acceleration()
    # probe: the u1 node at `probe`
    xy = space.tabulate_dof_coordinates()[:, :2]
    hit = np.flatnonzero(np.hypot(xy[:, 0] - probe[0], xy[:, 1] - probe[1]) < 1e-9)
    hit = hit[dofs[hit] < n_owned]
    duration = (LX - x0) / c_p
    times, values, energies = [], [], []
    for step in range(int(duration / dt)):
        if coupled:
            coupler.step()
        else:
            continuum.step(dt)
        value = float(continuum.displacement.array[dofs[hit[0]]]) if hit.size else 0.0
        times.append(continuum.time)
        values.append(comm.allreduce(value))
        energies.append(energy(continuum, coupler))
    run.energies = np.array(energies)
    return np.array(times), np.array(values), c_p


def energy(continuum, coupler):
    """Energy of the coupled system [J/m] (003-bsm.md T4): 1/2 v.Mv of the nodes (the region's
    nodes carry the grains' lumped mass) + 1/2 d.K d of the continuum outside the region + the
    fine kinetic energy 1/2 (Q qdot).M_p(Q qdot) of the real grains + the contact springs
    except those between two virtual grains (left to the continuum). Grain velocities are the
    leapfrog half-step ones."""
    total = continuum.kinetic_energy() + continuum.strain_energy()
    if coupler is None:
        return total
    grains = 0.0
    if coupler.is_root:
        from cosserat_fenicsx.bridging.coupler import in_original_order
        engine, region = coupler.fine, coupler.region
        st = engine.state
        qdot = np.column_stack([in_original_order(engine.order, st.velocity),
                                in_original_order(engine.order, st.spin)])[region.real]
        fine = coupler.projection.fine(qdot)
        weights = np.column_stack([region.mass, region.mass, region.inertia])[region.real]
        grains += 0.5 * float(np.sum(weights * fine ** 2))
        virtual = region.is_virtual[engine.order]
        keep = (st.touching != 0) & ~(virtual[st.pair_i] & virtual[st.pair_j])
        i, j = st.pair_i[keep], st.pair_j[keep]
        gap = np.hypot(*(st.position[j] - st.position[i]).T)
        h = np.maximum(st.radius[i] + st.radius[j] - gap, 0.0)
        grains += float(np.sum(0.5 * KN * h ** 2 + st.fs[keep] ** 2 / (2.0 * KS)))
    return total + MPI.COMM_WORLD.bcast(grains, root=0)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--widths", type=float, nargs="+", default=[0.5, 1.0])
    parser.add_argument("--out", default="results/bsm_wave")
    args = parser.parse_args()
    rows = []
    for width in args.widths:
        w0 = time.perf_counter()
        t, bsm, c_p = run(width)
        e_bsm = run.energies
        _, fe, _ = run(width, coupled=False)
        e_fe = run.energies
        # after the incident pulse has passed the probe (x = 3 m): t > (1 m + 3 w) / c_p
        after = t > (1.0 + 3.0 * width) / c_p
        before_far_end = t < (2 * (LX - 3.0) - 1.0) / c_p     # no echo of the right end yet
        window = after & before_far_end
        reflected = float(np.max(np.abs(bsm[window] - fe[window])))
        incident = 1e-4                                      # the step A
        transmitted_gap = float(np.max(np.abs(bsm - fe)))
        row = {"width_m": width, "wavelength_m": 4 * width, "reflection": reflected / incident,
               "energy_fraction": (reflected / incident) ** 2, "max_difference_over_incident": transmitted_gap / incident,
               "c_p": c_p, "wall_s": time.perf_counter() - w0, "load_average": os.getloadavg()[0],
               "energy_drift_bsm": float(np.max(np.abs(e_bsm - e_bsm[0])) / e_bsm[0]),
               "energy_drift_fe": float(np.max(np.abs(e_fe - e_fe[0])) / e_fe[0]),
               "energy_end_bsm": float(e_bsm[-1] / e_bsm[0])}
        rows.append(row)
        if MPI.COMM_WORLD.rank == 0:
            print(f"pulse width {width:g} m (wavelength ~{4 * width:g} m, {4 * width / RADIUS:.0f} r): reflected "
                  f"amplitude {row['reflection']:.3%} of the incident, energy {row['energy_fraction']:.2e} "
                  f"; energy (undamped) max drift {row['energy_drift_bsm']:.2%} (pure FE "
                  f"{row['energy_drift_fe']:.2%}), end/start {row['energy_end_bsm']:.4f} "
                  f"({row['wall_s']:.1f} s wall, load {row['load_average']:.2f})", flush=True)
            os.makedirs(args.out, exist_ok=True)
            np.savetxt(os.path.join(args.out, f"probe_w{width:g}.csv"), np.column_stack([t, fe, bsm]),
                       delimiter=",", header="t,u1_fe,u1_bsm", comments="")
    if MPI.COMM_WORLD.rank == 0:
        with open(os.path.join(args.out, "wave.json"), "w") as f:
            json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
