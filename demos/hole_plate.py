"""Plate with a circular hole under uniaxial tension: the micropolar size effect.

A square plate (side 2L) with a central hole of radius a is pulled by the traction T in
x2 on its top and bottom edges (plane strain). A quarter is meshed with gmsh
(meshes/hole_plate.geo): symmetry on x1 = 0 (u1 = 0, phi = 0) and x2 = 0 (u2 = 0,
phi = 0), the hole and the right edge are free. The stress concentration factor
SCF = sigma22(a, 0) / T is 3 in a classical solid (Kirsch) and drops when the hole is not
large compared with the internal length; the published closed form for the infinite
micropolar plate (analytic.micropolar_hole_scf) is plotted against the computed values.

Outputs in --out: summary.json ('scf' for --radius, closed form, Kirsch, 'wall_time' of
meshing + solving + output), scf.csv,
scf.png (SCF against a / l_c), fields.xdmf. In ParaView: open fields.xdmf (reader
"Xdmf3 Reader T"), colour by 'stress' component YY (sigma22; the 2x2 tensor is padded to
3x3) to see the concentration at (a, 0), and by 'rotation', largest at the hole where the
couple stress relieves the concentration.

    mpirun -n 2 python3 demos/hole_plate.py --radius 0.01 --l-c 0.01
    mpirun -n 2 python3 demos/hole_plate.py --sweep       # several a / l_c
"""
import sys, os  # noqa: E401
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import time

import numpy as np
from mpi4py import MPI

from cosserat_fenicsx import CosseratProblem, NewtonSolver, LoadStepper, LoadSteppingError, analytic, cli, meshes
from cosserat_fenicsx.figures import pyplot
from cosserat_fenicsx.output import FieldWriter, CsvLog, print0
from cosserat_fenicsx.run_guard import RunGuard
from cosserat_fenicsx.probes import stress_component_at
from cosserat_fenicsx.validation import POSITIVE, InputError, number

parser = cli.make_parser(__doc__)
cli.add_material_options(parser, mu=1.0e8, lmbda=1.0e8, l_c=1.0e-2)
cli.add_mesh_options(parser, cell_size=None)
cli.add_output_options(parser, "results/hole_plate")
parser.add_argument("--radius", type=number(POSITIVE), default=1.0e-2, help="hole radius a [m] (default %(default)g)")
parser.add_argument("--half-side", type=number(POSITIVE), default=None,
                    help="half side L > a of the plate [m] (default 20 a)")
parser.add_argument("--traction", type=number(), default=1.0e6,
                    help="remote tension T [Pa], |T| in [1e-6, 1e12] (default %(default)g)")
parser.add_argument("--hole-cell-size", type=number(POSITIVE), default=None,
                    help="element size on the hole [m] (default a/16, or --cell-size/4)")
parser.add_argument("--sweep", action="store_true",
                    help="also solve for a = l_c x (0.25, 0.5, 1, 2, 4, 8) and plot them all")


def sweep_radii(args):
    radii = [args.radius]
    if args.sweep:
        radii += [f * args.l_c for f in (0.25, 0.5, 1.0, 2.0, 4.0, 8.0)]
    return radii


def plate_sizes(args, radius):
    """(half side, element size, element size on the hole) [m] of the plate around `radius`."""
    half_side = args.half_side or 20.0 * radius
    h_hole = args.hole_cell_size or (args.cell_size / 4 if args.cell_size else radius / 16)
    return half_side, args.cell_size or half_side / 12, h_hole


def check(args):
    if not 1e-6 <= abs(args.traction) <= 1e12:
        # the stress concentration factor sigma_max / T does not depend on T; a zero load
        # defines none, and far from 1 MPa the solve's absolute tolerances under/overflow
        raise InputError(f"--traction must have a magnitude in [1e-6, 1e12] Pa, got {args.traction:g}")
    if args.sweep and args.l_c == 0:
        raise InputError("--sweep varies a/l_c: it needs --l-c > 0, got 0")
    for radius in sweep_radii(args):
        half_side, h, h_hole = plate_sizes(args, radius)
        meshes.check_hole_plate(radius, half_side, h, h_hole)


args = cli.parse(parser, check=check)
comm = MPI.COMM_WORLD
guard = RunGuard(comm, os.path.join(args.out, "summary.json"), label="hole_plate")
e = args.elasticity
micropolar = not args.cauchy


def solve(radius, write_fields):
    start = time.perf_counter()
    half_side, h, h_hole = plate_sizes(args, radius)
    mesh, facet_tags, boundaries = meshes.hole_plate(comm, radius, half_side, h, h_hole)
    problem = CosseratProblem(mesh, facet_tags, boundaries, elasticity=e, micropolar=micropolar,
                              degree_u=args.degree_u, degree_phi=args.degree_phi)
    problem.add_dirichlet("left", "u1", 0.0)
    problem.add_dirichlet("bottom", "u2", 0.0)
    if micropolar:
        problem.add_dirichlet("left", "phi", 0.0)
        problem.add_dirichlet("bottom", "phi", 0.0)
    problem.add_traction("top", (0.0, args.traction))
    with guard.deferred():             # a signal waits until the new file is closed
        writer = FieldWriter(problem, os.path.join(args.out, "fields.xdmf"), args.fields) if write_fields else None

    def write_step(record):
        with guard.deferred():
            writer.write(record.time)

    solver = NewtonSolver(problem)
    LoadStepper(problem, solver, dt=1.0, verbose=write_fields,
                on_step=write_step if writer else None).run()
    if writer:
        writer.close()
    sigma22 = stress_component_at(problem, (1, 1), np.array([radius, 0.0, 0.0]))
    dofs = problem.W.dofmap.index_map.size_global * problem.W.dofmap.index_map_bs
    return sigma22 / args.traction, dofs, time.perf_counter() - start


radii = sweep_radii(args)
log = CsvLog(comm, os.path.join(args.out, "scf.csv"), ["radius", "radius_over_l_c", "scf", "scf_closed_form", "dofs", "wall_time"])
results = []
for i, radius in enumerate(radii):
    try:
        scf, dofs, wall = solve(radius, write_fields=(i == 0))
    except LoadSteppingError as error:
        guard.stop(f"a = {radius:g} m: {error}")
    exact = analytic.micropolar_hole_scf(radius, e.mu, e.lmbda, e.mu_c, e.l_c) if micropolar else 3.0
    row = {"radius": radius, "radius_over_l_c": radius / e.l_c if e.l_c > 0 else np.inf,
           "scf": scf, "scf_closed_form": exact, "dofs": dofs, "wall_time": wall}
    with guard.deferred():
        log.write(row)
        results.append(row)
        guard.progress(radii_solved=len(results))
    print0(comm, f"a = {radius:.4g} m, a/l_c = {row['radius_over_l_c']:.3g}: SCF = {scf:.4f} "
                 f"(closed form {exact:.4f}, Kirsch 3), {dofs} dofs")
log.close()

first = results[0]
guard.finish({
    "scf": first["scf"], "scf_closed_form": first["scf_closed_form"], "scf_kirsch": 3.0,
    "relative_error": abs(first["scf"] - first["scf_closed_form"]) / first["scf_closed_form"],
    "radius": args.radius, "l_c": e.l_c, "mu": e.mu, "lmbda": e.lmbda, "mu_c": e.mu_c,
    "micropolar": micropolar, "dofs": first["dofs"], "ranks": comm.size,
    "wall_time": first["wall_time"],
    "sweep": results[1:]})

if comm.rank == 0:
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6, 4))
    ratio = np.logspace(-1.5, 2, 200)
    if micropolar and e.l_c > 0:
        ax.semilogx(ratio, [analytic.micropolar_hole_scf(r * e.l_c, e.mu, e.lmbda, e.mu_c, e.l_c) for r in ratio],
                    "k-", label="micropolar closed form (infinite plate)")
    ax.axhline(3.0, color="gray", ls="--", label="classical (Kirsch) 3")
    ax.semilogx([r["radius_over_l_c"] for r in results], [r["scf"] for r in results], "o", mfc="none",
                label="finite elements")
    ax.set_xlabel("hole radius / l_c"); ax.set_ylabel("stress concentration factor")
    ax.set_title(f"mu_c/mu = {e.mu_c / e.mu:g}, nu = {e.poisson_ratio:.3g}")
    ax.legend(loc="lower right"); fig.tight_layout(); fig.savefig(os.path.join(args.out, "scf.png"), dpi=120)
