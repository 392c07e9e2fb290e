"""Patch test of the bridging-scale coupling (003-bsm.md section 9, T3): ghost forces.

A regular hexagonal lattice of equal discs fills a square DEM region inside a Cosserat
finite-element domain whose moduli are the lattice's exact affine ones
(demcell.estimates.hexagonal_moduli: lambda = sqrt(3)/4 (kn - ks), G = sqrt(3)/4 (kn + ks),
mu_c = sqrt(3)/2 ks). Under a uniform (affine) strain both descriptions carry the same
stress, so in the affine state every nodal force must balance: f_c - K d = 0 with
f_c = N_R^T F_R + N_V^T F_V (003 eq 16). What remains is the ghost force of the coupling.

Static evaluation (no dynamics, exact): the continuum nodes get the affine field d = H x
(phi = the rigid rotation of H), all grains (real and virtual) are driven to the affine
positions and rotations in `increments` steps (their tangential springs accumulate the
affine slip), and the nodal residual f_c - K d is measured. Reported: the largest residual
against the largest nodal force the grains pass to the continuum (the interface force) and
against the mean contact force, for two radii (the residual should shrink with r / h).

    PYTHONPATH=. /usr/bin/python3 benchmarks/bsm/patch_test.py [--radius 0.05 0.025]
"""
import argparse
import json
import math
import os
import time

import dolfinx.mesh
import numpy as np
from mpi4py import MPI

from cosserat_fenicsx.bridging.coupler import BridgingCoupler
from cosserat_fenicsx.bridging.region import build_region, region_cells
from cosserat_fenicsx.dynamics.explicit import ExplicitCosserat
from cosserat_fenicsx.elasticity import MicropolarElasticity

KN, KS = 2.5e8, 5.0e7          # 003 Table 1 [N/m]
DENSITY = 2600.0               # [kg/m^3], disc of unit depth


def hexagonal_packing(domain, radius):
    """Discs of radius r touching on a triangular lattice (rows horizontal) covering domain."""
    x0, x1, y0, y1 = domain
    rows = np.arange(y0 + 0.5 * radius, y1, math.sqrt(3.0) * radius)
    points = []
    for k, y in enumerate(rows):
        xs = np.arange(x0 + radius * (1 + (k % 2)) - 0.5 * radius, x1, 2.0 * radius)
        points.append(np.column_stack([xs, np.full(xs.size, y)]))
    return np.vstack(points)


def build(radius, size=4.0, box=(1.0, 3.0, 1.0, 3.0), cells=4, substeps=2, mass_damping=0.0, dirichlet=(),
          comm=MPI.COMM_WORLD, gravity=(0.0, 0.0), **coupler_options):
    """Continuum, region, engine (rank 0) and coupler of the hexagonal patch (coupler_options:
    BridgingCoupler's keywords, e.g. region_nodes; gravity (g_x, g_y) [m/s^2] on both)."""
    from demcell.contact_law import ContactLaw
    from demcell.estimates import hexagonal_moduli
    from demcell.specimen import Specimen, SpecimenOptions, SpecimenState
    domain = (0.0, size, 0.0, size)
    mesh = dolfinx.mesh.create_rectangle(comm, [np.array([0.0, 0.0]), np.array([size, size])], [cells, cells],
                                         dolfinx.mesh.CellType.quadrilateral)
    moduli = hexagonal_moduli(KN, KS, 0.0, radius)
    elasticity = MicropolarElasticity(mu=moduli["G"], lmbda=moduli["lambda_"], mu_c=moduli["mu_c"], l_c=0.0)
    rho_c = DENSITY * math.pi / (2.0 * math.sqrt(3.0))     # disc mass per lattice cell area
    continuum = ExplicitCosserat(mesh, elasticity, rho_c, 0.5 * radius ** 2, mass_damping=mass_damping,
                                 element="Q1/Q1", inactive_cells=region_cells(mesh, box),
                                 dirichlet=dirichlet, gravity=gravity)
    position = hexagonal_packing(domain, radius)
    r = np.full(len(position), radius)
    m = DENSITY * math.pi * r ** 2
    region = build_region(position, r, m, 0.5 * m * r ** 2, box, domain)
    dt_fine = 0.1 * math.sqrt(m.min() / KN)
    engine = None
    law = ContactLaw(kn=KN, ks=KS, friction=math.inf, rolling_stiffness=0.0)
    if comm.rank == 0:
        state = SpecimenState.from_discs(region.position, region.radius, region.mass, region.inertia,
                                         (0.0, size, 0.0, size), lateral="none")
        engine = Specimen(state, law, SpecimenOptions(dt=dt_fine, lateral="none", mass_damping=mass_damping,
                                                      gravity=gravity))
        engine.hold(region.is_virtual)
    dt = min(dt_fine * substeps, 0.9 * continuum.stable_time_step()["power"])
    substeps = max(1, int(round(dt / dt_fine)))
    coupler = BridgingCoupler(continuum, region, engine, dt_fine * substeps, substeps, fine_dt=dt_fine,
                              **coupler_options)
    return continuum, region, engine, coupler, moduli


def set_affine(continuum, gradient):
    """d = H x on the continuum nodes, phi = (H21 - H12) / 2 (the rigid rotation of H)."""
    import dolfinx.fem
    work = dolfinx.fem.Function(continuum.space)
    phi = 0.5 * (gradient[1, 0] - gradient[0, 1])
    for c, name in enumerate(("u1", "u2", "phi")):
        space, dofs = continuum.subspace(name)
        x = space.tabulate_dof_coordinates()[:, :2]
        work.x.array[dofs] = (x @ gradient[c]) if c < 2 else phi
    n_owned = continuum.displacement.getLocalSize()
    continuum.displacement.array[:] = work.x.array[:n_owned]
    continuum._forward(continuum.displacement)


def ghost_forces(radius, gradient, increments=20):
    """Largest nodal residual f_c - K d in the affine state (module docstring)."""
    continuum, region, engine, coupler, moduli = build(radius)
    comm = continuum.comm
    set_affine(continuum, gradient)
    phi = 0.5 * (gradient[1, 0] - gradient[0, 1])
    contact_mean = None
    if comm.rank == 0:
        # every grain driven onto the affine state, every contact's history built on the way
        engine.hold(np.ones(region.n_discs, dtype=bool))
        engine.set_skip_held_pairs(False)
        rotation = np.full(region.n_discs, phi)
        for k in range(1, increments + 2):
            s = min(k, increments) / increments
            engine.drive_held(region.position + s * region.position @ gradient.T, s * rotation)
            engine.advance(1)
        touching = engine.state.touching != 0
        contact_mean = float(np.mean(np.hypot(engine.state.fn[touching], engine.state.fs[touching])))
        # then the coupler's setting: the virtual grains held, their mutual contacts dropped
        engine.hold(region.is_virtual)
        engine.set_skip_held_pairs(True)
    contact_mean = comm.bcast(contact_mean, root=0)
    forces = coupler.coupling_forces() if comm.rank == 0 else None
    forces = comm.bcast(forces, root=0)
    fc = continuum.mass.duplicate()
    fc.set(0.0)
    coupler.shape.add_transpose(forces, fc)
    interface = continuum.mass.duplicate()
    interface.set(0.0)
    virtual_only = forces.copy()
    virtual_only[:region.n_real] = 0.0
    coupler.shape.add_transpose(virtual_only, interface)
    kd = continuum.mass.duplicate()
    continuum.internal_force(continuum.displacement, kd)
    residual = fc.array - kd.array
    out = {}
    size = 4.0
    worst = {}
    for name in ("u1", "u2", "phi"):
        space, dofs = continuum.subspace(name)
        x = space.tabulate_dof_coordinates()[:, :2]
        # the outer boundary carries the affine field's traction: not a ghost force
        interior = ((dofs < len(residual)) & (x.min(axis=1) > 1e-9) & (x.max(axis=1) < size - 1e-9))
        dofs, x = dofs[interior], x[interior]
        if dofs.size:
            k = int(np.argmax(np.abs(residual[dofs])))
            worst[name] = (float(abs(residual[dofs[k]])), x[k].tolist())
        out[name] = (comm.allreduce(float(np.abs(residual[dofs]).max(initial=0.0)), op=MPI.MAX),
                     comm.allreduce(float(np.abs(interface.array[dofs]).max(initial=0.0)), op=MPI.MAX),
                     comm.allreduce(float(np.abs(kd.array[dofs]).max(initial=0.0)), op=MPI.MAX))
    u_res = max(out["u1"][0], out["u2"][0])
    u_int = max(out["u1"][1], out["u2"][1])
    return {"radius": radius, "r_over_h": radius / 1.0, "real": region.n_real, "virtual": region.n_virtual,
            "max_residual_N_per_m": u_res, "max_interface_force_N_per_m": u_int,
            "residual_over_interface": u_res / u_int, "mean_contact_force_N_per_m": contact_mean,
            "residual_over_contact": u_res / contact_mean, "max_moment_residual": out["phi"][0],
            "max_K_d_N_per_m": max(out["u1"][2], out["u2"][2]),
            "worst_node": {k: v for k, v in worst.items()} if comm.size == 1 else None,
            "moduli": {k: float(v) for k, v in moduli.items() if k in ("lambda_", "G", "mu_c")}}


CASES = {
    "confined": np.array([[-1e-4, 0.0], [0.0, -1e-4]]),
    "oedometric+shear": np.array([[-2e-4, 0.5e-4], [0.5e-4, -3e-4]]),
}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--radius", type=float, nargs="+", default=[0.05, 0.025])
    parser.add_argument("--out", default="results/bsm_patch")
    args = parser.parse_args()
    rows = []
    for case, gradient in CASES.items():
        for radius in args.radius:
            w0, c0 = time.perf_counter(), time.process_time()
            row = ghost_forces(radius, gradient)
            row.update(case=case, wall_s=time.perf_counter() - w0, cpu_s=time.process_time() - c0,
                       load_average=os.getloadavg()[0])
            rows.append(row)
            if MPI.COMM_WORLD.rank == 0:
                print(f"{case:18s} r = {radius:.3f} m  grains {row['real']} + {row['virtual']} virtual: "
                      f"max ghost force {row['max_residual_N_per_m']:.4g} N/m = "
                      f"{row['residual_over_interface']:.3%} of the largest interface nodal force, "
                      f"{row['residual_over_contact']:.3g} x the mean contact force "
                      f"({row['wall_s']:.1f} s wall, load {row['load_average']:.2f})", flush=True)
    if MPI.COMM_WORLD.rank == 0:
        os.makedirs(args.out, exist_ok=True)
        with open(os.path.join(args.out, "patch_test.json"), "w") as f:
            json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
