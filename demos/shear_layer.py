"""Sheared micropolar layer: the boundary layer of the rotation.

A layer of height H (x2 direction) is clamped at the bottom (u = 0, phi = 0) and its top
is shifted by `--shift` in x1 with u2 = 0; the rotation at the top is fixed (phi = 0) or
free (zero surface couple). The sides carry u2 = 0 and zero traction t1 and couple, which
the x1-independent infinite-layer solution satisfies, so the closed form of
`cosserat_fenicsx.analytic.shear_layer` is the exact answer. Boundary layers of width
ell = l_c sqrt((mu + mu_c)/(2 mu)) form where the rotation is fixed.

Outputs in --out: profile.csv (x2, u1, phi along the mid-line, and the closed form),
profile.png, history.csv (shift and reaction of the top per step), summary.json (max
errors, shear stress from the reaction and exact), fields.xdmf. In ParaView: open fields.xdmf (reader "Xdmf3 Reader T"),
colour by 'rotation' to see the boundary layers, by 'stress' component 1 (sigma12) to see
the uniform shear, and 'couple_stress' for m32.

    mpirun -n 2 python3 demos/shear_layer.py --l-c 0.01 --top-rotation free
"""
import sys, os  # noqa: E401
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import numpy as np
from mpi4py import MPI

from cosserat_fenicsx import CosseratProblem, NewtonSolver, LoadStepper, LoadSteppingError, analytic, cli, meshes
from cosserat_fenicsx.figures import pyplot
from cosserat_fenicsx.output import FieldWriter, CsvLog, print0
from cosserat_fenicsx.probes import sample_line
from cosserat_fenicsx.run_guard import RunGuard
from cosserat_fenicsx.validation import POSITIVE, Range, check as check_value, number

SHEAR_STRAIN = Range(1e-12, 1.0)   # |shift| / H: small strains, above the solver's absolute tolerances

parser = cli.make_parser(__doc__)
cli.add_material_options(parser, mu=1.0e8, lmbda=1.0e8, l_c=1.0e-2)
cli.add_mesh_options(parser, cell_size=2.5e-3)
cli.add_output_options(parser, "results/shear_layer")
cli.add_stepping_options(parser, steps=1)
parser.add_argument("--height", type=number(POSITIVE), default=0.1, help="layer height H [m] (default %(default)g)")
parser.add_argument("--width", type=number(POSITIVE), default=None, help="strip width [m] (default H/4)")
parser.add_argument("--shift", type=number(), default=1.0e-3, help="top displacement in x1 [m], |shift| / H in [1e-12, 1] (default %(default)g)")
parser.add_argument("--top-rotation", choices=("fixed", "free"), default="fixed")


def check(args):
    meshes.rectangle_divisions(args.width or args.height / 4, args.height, args.cell_size)
    # small strains: the layer's shear strain shift / H; below 1e-12 the solution drowns
    # in the solver's absolute tolerances
    check_value("--shift / --height (the shear strain)", abs(args.shift / args.height), SHEAR_STRAIN)


args = cli.parse(parser, check=check)
comm = MPI.COMM_WORLD
guard = RunGuard(comm, os.path.join(args.out, "summary.json"), label="shear_layer")
width = args.width or args.height / 4

mesh, facet_tags, boundaries = meshes.rectangle(comm, width, args.height, args.cell_size, args.cell_type)
problem = CosseratProblem(mesh, facet_tags, boundaries, elasticity=args.elasticity,
                          micropolar=not args.cauchy, degree_u=args.degree_u, degree_phi=args.degree_phi)
for side in boundaries:
    problem.add_dirichlet(side, "u2", 0.0)
problem.add_dirichlet("bottom", "u1", 0.0)
problem.add_dirichlet("top", "u1", args.shift)
if not args.cauchy:
    problem.add_dirichlet("bottom", "phi", 0.0)
    if args.top_rotation == "fixed":
        problem.add_dirichlet("top", "phi", 0.0)

with guard.deferred():                 # a signal waits until the new file is closed
    writer = FieldWriter(problem, os.path.join(args.out, "fields.xdmf"), args.fields)
history = CsvLog(comm, os.path.join(args.out, "history.csv"),
                 ["time", "shift", "reaction_x_top", "reaction_y_top", "shear_stress_top"])


def record(step):
    writer.write(step.time)
    rx = problem.reaction("top", "u1")
    history.write({"time": step.time, "shift": step.time * args.shift, "reaction_x_top": rx,
                   "reaction_y_top": problem.reaction("top", "u2"), "shear_stress_top": rx / width})


solver = NewtonSolver(problem)
try:
    LoadStepper(problem, solver, dt=1.0 / args.steps,
                on_step=guard.protect(record, lambda step: {"time": step.time})).run()
except LoadSteppingError as error:
    guard.stop(error)
finally:
    writer.close()
    history.close()

# profile along the vertical mid-line against the closed form
x2 = np.linspace(0.0, args.height, 201)
points = np.column_stack([np.full_like(x2, width / 2), x2, np.zeros_like(x2)])
u1 = sample_line(problem.w.sub(0).sub(0) if problem.micropolar else problem.w.sub(0), points)
phi = sample_line(problem.w.sub(1), points) if problem.micropolar else np.zeros_like(x2)
e = args.elasticity
mu_c = e.mu_c if problem.micropolar else 0.0
u1_ex, phi_ex, tau = analytic.shear_layer(x2, args.height, args.shift, e.mu, mu_c,
                                          e.l_c if problem.micropolar else 0.0, args.top_rotation)
if comm.rank == 0:
    np.savetxt(os.path.join(args.out, "profile.csv"),
               np.column_stack([x2, u1, phi, u1_ex, phi_ex]), delimiter=",",
               header="x2,u1,phi,u1_exact,phi_exact", comments="")
    plt = pyplot()
    fig, ax = plt.subplots(1, 2, figsize=(9, 4), sharey=True)
    ax[0].plot(u1_ex * 1e3, x2, "k-", label="closed form")
    ax[0].plot(u1[::8] * 1e3, x2[::8], "o", mfc="none", label="FE")
    ax[0].set_xlabel("u1 [mm]"); ax[0].set_ylabel("x2 [m]"); ax[0].legend()
    ax[1].plot(phi_ex, x2, "k-", label="closed form")
    ax[1].plot(phi[::8], x2[::8], "o", mfc="none", label="FE")
    ax[1].set_xlabel("phi [rad]")
    fig.suptitle(f"shear layer, l_c={e.l_c:g} m, mu_c={mu_c:g} Pa, top rotation {args.top_rotation}")
    fig.tight_layout(); fig.savefig(os.path.join(args.out, "profile.png"), dpi=120)
scale_u, scale_phi = max(abs(u1_ex).max(), 1e-300), max(abs(phi_ex).max(), 1e-300)
summary = {"shear_stress_exact": tau, "shear_stress_fe": problem.reaction("top", "u1") / width,
           "max_error_u1_relative": float(abs(u1 - u1_ex).max() / scale_u),
           "max_error_phi_relative": float(abs(phi - phi_ex).max() / scale_phi) if problem.micropolar else 0.0,
           "l_c": e.l_c, "mu_c": mu_c, "mu": e.mu, "top_rotation": args.top_rotation,
           "cell_size": args.cell_size, "ranks": comm.size}
guard.finish(summary)
print0(comm, f"max relative error: u1 {summary['max_error_u1_relative']:.2e}, "
             f"phi {summary['max_error_phi_relative']:.2e}")
