"""Long-run drift of the coupled patch (issue: "no drift over 10^5 steps"): the hexagonal
patch of benchmarks/bsm/patch_test.py (r = 0.1 m, exact moduli) under isotropic confinement
(1e-4) is relaxed with mass damping (c_m = 600 /s, `--relax` coarse steps), then run UNDAMPED
for `--steps` more coarse steps. Reported every `--every` steps: the continuum's and the
grains' largest displacement change since the end of the relaxation (over the confinement
displacement), the nodal kinetic energy, the total energy of the coupled system (T4:
benchmarks/bsm/wave.energy, nodal kinetic + FE strain + grains' fine kinetic + contact
springs; the boundary is fixed after the relaxation, so no work enters), the coupling
mismatch. Energy that the coupling
created would show as growing motion.

    PYTHONPATH=. python3 benchmarks/bsm/patch_drift.py --steps 100000
"""
import argparse
import json
import os
import time

import numpy as np
from mpi4py import MPI

from benchmarks.bsm.patch_test import build
from benchmarks.bsm.wave import energy


def potential_system_energy(continuum, coupler):
    """Energy of the coupled system derived from one potential (coupler.py's docstring) [J/m]:
    the T4 energy (benchmarks/bsm/wave.energy) with the nodal kinetic energy of the projected
    region nodes and the grains' fine kinetic energy replaced by the grains' whole kinetic
    energy 1/2 qdot^T M_p qdot (leapfrog half-step velocities). Conserved by the
    coarse_force="interface" couplings; for eq 16 ("grains") it counts the region's coarse
    kinetic energy twice and is not the conserved quantity of anything."""
    projected = coupler.projected_dofs
    v = continuum.velocity.array[:projected.size]
    nodes = 0.5 * float(np.sum(continuum.mass.array[projected] * v[projected] ** 2))
    nodes = MPI.COMM_WORLD.allreduce(nodes)
    coarse = 0.0
    if coupler.is_root:
        from cosserat_fenicsx.bridging.coupler import in_original_order
        st, region = coupler.fine.state, coupler.region
        qdot = np.column_stack([in_original_order(coupler.fine.order, st.velocity),
                                in_original_order(coupler.fine.order, st.spin)])[region.real]
        coarse = coupler.projection.kinetic_energy(qdot)[1]
    return energy(continuum, coupler) - nodes + MPI.COMM_WORLD.bcast(coarse, root=0)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--radius", type=float, default=0.1)
    parser.add_argument("--relax", type=int, default=500)
    parser.add_argument("--steps", type=int, default=100000)
    parser.add_argument("--every", type=int, default=10000)
    parser.add_argument("--substeps", type=int, default=2, help="DEM sub-steps per coarse step m")
    parser.add_argument("--force-time", choices=("end", "lagged"), default="end")
    parser.add_argument("--coarse-force", choices=("grains", "interface"), default=None,
                        help="BridgingCoupler(coarse_force=...): 003 eq 16, or the virtual grains' reactions "
                             "only (default: grains, interface with --region-nodes projected)")
    parser.add_argument("--region-nodes", choices=("integrated", "projected"), default="integrated",
                        help="BridgingCoupler(region_nodes=...): the region's own nodes integrated, or set to d_hat(q)")
    parser.add_argument("--out", default="results/bsm_patch_drift")
    args = parser.parse_args()
    size, strain = 4.0, 1e-4
    delta = strain * size
    bcs = [("u1", lambda x: np.isclose(x[0], 0.0), 0.0), ("u1", lambda x: np.isclose(x[0], size), -delta),
           ("u2", lambda x: np.isclose(x[1], 0.0), 0.0), ("u2", lambda x: np.isclose(x[1], size), -delta)]
    continuum, region, engine, coupler, _ = build(args.radius, mass_damping=600.0, dirichlet=bcs,
                                                  substeps=args.substeps, force_time=args.force_time,
                                                  coarse_force=args.coarse_force, region_nodes=args.region_nodes)
    coupler.run(args.relax)
    # undamped from here on, both scales
    continuum.mass_damping = 0.0
    if engine is not None:
        engine.options = engine.options.with_(mass_damping=0.0)
    d0 = continuum.displacement.array.copy()
    q0 = coupler.grain_motion() if engine is not None else None
    e0 = energy(continuum, coupler)
    h0 = potential_system_energy(continuum, coupler)
    rows = []
    w0 = time.perf_counter()
    done = 0
    while done < args.steps:
        k = min(args.every, args.steps - done)
        coupler.run(k)
        done += k
        coupler.step(diagnose=True)
        done += 1
        change_fe = MPI.COMM_WORLD.allreduce(float(np.abs(continuum.displacement.array - d0).max()), op=MPI.MAX)
        change_grains = float(np.abs(coupler.grain_motion()[:, :2] - q0[:, :2]).max()) if engine is not None else 0.0
        row = {"steps": done, "substeps": coupler.substeps, "force_time": args.force_time,
               "coarse_force": coupler.coarse_force, "region_nodes": args.region_nodes, "time_s": continuum.time, "fe_change_over_delta": change_fe / delta,
               "grain_change_over_delta": MPI.COMM_WORLD.bcast(change_grains) / delta,
               "fe_kinetic_J_per_m": continuum.kinetic_energy(),
               "energy_J_per_m": energy(continuum, coupler), "energy_at_start_J_per_m": e0,
               "potential_system_energy_J_per_m": potential_system_energy(continuum, coupler),
               "potential_system_energy_at_start_J_per_m": h0,
               "mismatch_over_rmin": MPI.COMM_WORLD.bcast(coupler.last_mismatch),
               "wall_s": time.perf_counter() - w0, "load_average": os.getloadavg()[0]}
        rows.append(row)
        if MPI.COMM_WORLD.rank == 0:
            print(json.dumps(row), flush=True)
    if MPI.COMM_WORLD.rank == 0:
        os.makedirs(args.out, exist_ok=True)
        with open(os.path.join(args.out, "patch_drift.json"), "w") as f:
            json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
