"""Shared command-line options of the demos, so a user learns them once.

Material: --mu --lmbda --mu-c --l-c (SI units; m = 2 mu_c l_c^2 kappa, eq 2.74),
--cauchy. Mesh: --cell-size H [m], --cell-type, --degree-u, --degree-phi.
Output: --out DIR, --fields. Stepping: --steps. PETSc options (-snes_*, -ksp_*, -pc_*,
-mat_*) pass through to the solver.
"""
import argparse
import logging
import os

from petsc4py import PETSc

from .elasticity import MicropolarElasticity
from .output import FIELDS

PETSC_PREFIXES = ("-snes_", "-ksp_", "-pc_", "-mat_", "-log_view")


def make_parser(description):
    # the JIT compilers log every C build at INFO level: keep the demos' output readable
    logging.getLogger().setLevel(logging.WARNING)
    parser = argparse.ArgumentParser(
        description=description, allow_abbrev=False,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="PETSc options such as -snes_monitor, -snes_rtol 1e-12, -ksp_type gmres, "
               "-pc_type ilu pass through to the Newton solver.")
    return parser


def add_material_options(parser, mu=1.0e8, lmbda=1.0e8, mu_c=None, l_c=1.0e-2):
    g = parser.add_argument_group("material (linear micropolar elasticity, SI units)")
    g.add_argument("--mu", type=float, default=mu, help="shear modulus [Pa] (default %(default)g)")
    g.add_argument("--lmbda", type=float, default=lmbda, help="Lame constant lambda [Pa] (default %(default)g)")
    g.add_argument("--mu-c", type=float, default=mu_c,
                   help="Cosserat coupling modulus [Pa]; default mu_c = mu (eq 2.75)")
    g.add_argument("--l-c", type=float, default=l_c, help="internal length [m] (default %(default)g)")
    g.add_argument("--cauchy", action="store_true", help="classical (Cauchy) continuum: no rotation field")


def add_mesh_options(parser, cell_size=None, with_cell_size=True):
    """--cell-size (default cell_size; left out when with_cell_size is False because the
    scene has its own mesh option), --cell-type, --degree-u, --degree-phi."""
    g = parser.add_argument_group("discretization")
    if with_cell_size:
        g.add_argument("--cell-size", type=float, default=cell_size, help="target element size [m] (default %(default)s)")
    g.add_argument("--cell-type", choices=("triangle", "quadrilateral"), default="triangle")
    g.add_argument("--degree-u", type=int, default=2, help="displacement degree (default 2, Taylor-Hood)")
    g.add_argument("--degree-phi", type=int, default=1, help="rotation degree (default 1)")


def add_output_options(parser, out):
    g = parser.add_argument_group("output")
    g.add_argument("--out", default=out, help="output directory (default %(default)s)")
    g.add_argument("--fields", nargs="+", default=list(FIELDS), choices=FIELDS,
                   help="fields written to XDMF (default: all)")


def add_stepping_options(parser, steps=1):
    g = parser.add_argument_group("load stepping")
    g.add_argument("--steps", type=int, default=steps, help="load increments (default %(default)s)")


def parse(parser, argv=None):
    """Parse; forward PETSc options; reject anything else unknown before any work."""
    args, unknown = parser.parse_known_args(argv)
    forward_petsc_options(parser, unknown)
    if getattr(args, "cell_size", None) is not None and not args.cell_size > 0:
        parser.error(f"--cell-size must be positive, got {args.cell_size}")
    if hasattr(args, "steps") and args.steps < 1:
        parser.error(f"--steps must be >= 1, got {args.steps}")
    if hasattr(args, "mu"):
        try:
            args.elasticity = MicropolarElasticity(mu=args.mu, lmbda=args.lmbda, mu_c=args.mu_c, l_c=args.l_c)
            if not args.cauchy:
                args.elasticity.check_micropolar()
        except ValueError as error:
            parser.error(str(error))
    if hasattr(args, "out"):
        os.makedirs(args.out, exist_ok=True)
    return args


def forward_petsc_options(parser, tokens):
    opts = PETSc.Options()
    i = 0
    while i < len(tokens):
        key = tokens[i]
        if not key.startswith(PETSC_PREFIXES):
            parser.error(f"unrecognized argument: {key}")
        value = None
        if i + 1 < len(tokens) and not tokens[i + 1].startswith(PETSC_PREFIXES) \
                and not tokens[i + 1].startswith("--"):
            value = tokens[i + 1]
            i += 1
        opts[key[1:]] = value if value is not None else ""
        i += 1
