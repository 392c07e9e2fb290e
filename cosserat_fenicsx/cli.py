"""Shared command-line options of the demos, so a user learns them once.

Material: --mu --lmbda --mu-c --l-c (SI units; m = 2 mu_c l_c^2 kappa, eq 2.74),
--cauchy. Mesh: --cell-size H [m], --cell-type, --degree-u, --degree-phi.
Output: --out DIR, --fields. Stepping: --steps. PETSc options (-snes_*, -ksp_*, -pc_*,
-mat_*) pass through to the solver.

Every numeric option declares its range (`validation.number`), so a bad value is refused
while parsing, in one line with exit status 2 (`validation.Parser`); checks that need
several options (`parse(..., check=...)`) run before the output directory is created. A
scene's options are made from its settings dataclass (`add_settings`, `settings_values`):
the range declared on a field (`validation.setting`) is the option's type.
"""
import argparse
import logging
import os

from petsc4py import PETSc

from .elasticity import MicropolarElasticity
from .output import FIELDS
from .validation import (COUNT, DEGREE, NON_NEGATIVE, POSITIVE, STEPS, Parser, declared, field_default, key_value,
                         number, option_dest, option_flag)

PETSC_PREFIXES = ("-snes_", "-ksp_", "-pc_", "-mat_", "-redundant_", "-log_view")


def make_parser(description):
    # the JIT compilers log every C build at INFO level: keep the demos' output readable
    # (setuptools' distutils resets the root logger's level when it compiles, so the handler
    # that ffcx's logging.basicConfig() installed gets the threshold too)
    root = logging.getLogger()
    root.setLevel(logging.WARNING)
    for handler in root.handlers:
        handler.setLevel(logging.WARNING)
    parser = Parser(
        description=description, allow_abbrev=False,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="PETSc options such as -snes_monitor, -snes_rtol 1e-12, -ksp_type gmres, "
               "-pc_type ilu pass through to the Newton solver.")
    return parser


def add_material_options(parser, mu=1.0e8, lmbda=1.0e8, mu_c=None, l_c=1.0e-2):
    parser.material_options = True
    g = parser.add_argument_group("material (linear micropolar elasticity, SI units)")
    g.add_argument("--mu", type=number(POSITIVE), default=mu, help="shear modulus [Pa] (default %(default)g)")
    g.add_argument("--lmbda", type=number(), default=lmbda,
                   help="Lame constant lambda [Pa], lambda + 2 mu / 3 > 0 (default %(default)g)")
    g.add_argument("--mu-c", type=number(NON_NEGATIVE), default=mu_c,
                   help="Cosserat coupling modulus [Pa]; default mu_c = mu (eq 2.75)")
    g.add_argument("--l-c", type=number(NON_NEGATIVE), default=l_c,
                   help="internal length [m]; 0: no couple stress (default %(default)g)")
    g.add_argument("--cauchy", action="store_true", help="classical (Cauchy) continuum: no rotation field")


def add_mesh_options(parser, cell_size=None, with_cell_size=True):
    """--cell-size (default cell_size; left out when with_cell_size is False because the
    scene has its own mesh option), --cell-type, --degree-u, --degree-phi."""
    g = parser.add_argument_group("discretization")
    if with_cell_size:
        g.add_argument("--cell-size", type=number(POSITIVE), default=cell_size,
                       help="target element size [m] (default %(default)s)")
    g.add_argument("--cell-type", choices=("triangle", "quadrilateral"), default="triangle")
    g.add_argument("--degree-u", type=number(DEGREE), default=2, help="displacement degree 1-4 (default 2, Taylor-Hood)")
    g.add_argument("--degree-phi", type=number(DEGREE), default=1, help="rotation degree 1-4 (default 1)")


def add_output_options(parser, out):
    parser.output_options = True
    g = parser.add_argument_group("output")
    g.add_argument("--out", default=out, help="output directory (default %(default)s)")
    g.add_argument("--fields", nargs="+", default=list(FIELDS), choices=FIELDS,
                   help="fields written to XDMF (default: all)")


def add_stepping_options(parser, steps=1):
    g = parser.add_argument_group("load stepping")
    g.add_argument("--steps", type=number(STEPS), default=steps, help="load increments (default %(default)s)")


def add_settings(group, cls, names, defaults=None):
    """The fields `names` of the settings dataclass `cls` (declared with validation.setting)
    as options of the argparse `group`: a number typed with its range, a choice among its
    choices, a bool a flag (--name, and --no-name when the default is True); the default the
    field's, or `defaults[name]` (the demo's own)."""
    fields = declared(cls)
    for name in names:
        f = fields[name]
        meta = f.metadata
        default = (defaults or {}).get(name, field_default(f))
        kwargs = dict(dest=option_dest(f), help=meta["help"])
        if isinstance(field_default(f), bool):
            if default:
                group.add_argument(option_flag(f), action=argparse.BooleanOptionalAction, default=True, **kwargs)
            else:
                group.add_argument(option_flag(f), action="store_true", **kwargs)
            continue
        if default is not None:      # an optional setting's help says what None means
            kwargs["help"] += " (default %(default)s)" if meta["choices"] else " (default %(default)g)"
        if meta["choices"] is not None:
            group.add_argument(option_flag(f), choices=meta["choices"], default=default, **kwargs)
        else:
            group.add_argument(option_flag(f), type=number(meta["allowed"]), default=default, **kwargs)


def settings_values(cls, args, names):
    """{field: value} of the fields `names` of `cls` from the parsed options (add_settings)."""
    fields = declared(cls)
    return {name: getattr(args, option_dest(fields[name])) for name in names}


#: options a restart may give (everything else comes from the checkpoint)
RUN_CONTROL = ("restart", "checkpoint_every", "stop_after")


def add_checkpoint_options(parser, label, solver_options=()):
    """--checkpoint-every N, --stop-after K, --restart DIR (checkpoint.py, docs/reference/restart.md);
    `label` names the demo in its checkpoints. `solver_options` (dests) steer how a step is
    solved, not what is solved (Newton tolerances, the Newton operator): a restart may change
    them, as a run that stalls is continued with another rule; the change is reported."""
    parser.checkpoint_label = label
    parser.restart_solver_options = tuple(solver_options)
    g = parser.add_argument_group("checkpoint and restart (batch queues; docs/reference/restart.md)")
    g.add_argument("--checkpoint-every", type=number(COUNT), default=None, metavar="N",
                   help="write a checkpoint to OUT/checkpoint after every N-th converged step")
    g.add_argument("--stop-after", type=number(COUNT), default=None, metavar="K",
                   help="stop cleanly after K converged steps in all, with a checkpoint (as a queue's time limit "
                        "would); continue with --restart OUT")
    g.add_argument("--restart", metavar="DIR", default=None,
                   help="continue the run whose outputs are in DIR from its last checkpoint, with that run's "
                        f"options (only {_may_change(solver_options)} may be given) and its outputs continued")


def _flag(dest):
    return "--" + dest.replace("_", "-")


def _may_change(solver_options):
    """The options a restart takes, as flags: the run control and the demo's solver options."""
    return ", ".join(["--checkpoint-every", "--stop-after"] + [_flag(d) for d in solver_options])


def restart_arguments(parser, args, argv=None):
    """The options of the run a --restart continues: those saved in its checkpoint, with the
    run-control options and the demo's solver options typed now (args.restart_changes: dest
    -> [saved, new] of the solver options that changed). Any other typed option that differs
    from the saved one, a missing checkpoint or one of another demo is a ValueError naming it."""
    from mpi4py import MPI
    from .checkpoint import CheckpointError, read_meta, verify
    comm = MPI.COMM_WORLD
    error = None
    if comm.rank == 0:         # read once; every rank gets the verdict (a damaged file refused everywhere)
        try:
            verify(args.restart, read_meta(args.restart, parser.checkpoint_label))
        except CheckpointError as e:
            error = str(e)
    error = comm.bcast(error, root=0)
    if error is not None:
        raise ValueError(f"--restart {args.restart}: {error}")
    meta = read_meta(args.restart, parser.checkpoint_label)
    saved = meta["options"]
    parser.check_saved(saved, f"--restart {args.restart}: the checkpoint's options")
    typed = parser.given_options(argv)
    solver = parser.restart_solver_options
    changes = {}
    for dest in sorted(typed - set(RUN_CONTROL)):
        if dest == "out" and os.path.abspath(args.out) == os.path.abspath(args.restart):
            continue
        if dest in solver and dest in saved:
            if saved[dest] != getattr(args, dest):
                changes[dest] = [saved[dest], getattr(args, dest)]
            continue
        if dest not in saved or saved[dest] != getattr(args, dest):
            option = _flag(dest)
            raise ValueError(f"{option} cannot be given with --restart (the run continues with the options it was "
                             f"started with{f': {option} {saved[dest]}' if dest in saved else ''}); only "
                             f"{_may_change(solver)} may change")
    for dest, value in saved.items():
        if dest not in typed:           # --checkpoint-every carries over unless typed again
            setattr(args, dest, value)
    args.restart_changes = changes
    args.out = args.restart
    if args.stop_after is not None and args.stop_after <= meta["step"]:
        raise ValueError(f"--stop-after {args.stop_after}: the checkpoint in {args.restart} is at step {meta['step']} "
                         "already")
    return args


def run_options(args):
    """The options a checkpoint saves (JSON; what a restart runs with)."""
    return {k: v for k, v in vars(args).items()
            if k not in ("elasticity", "checkpoint_label", "restart", "stop_after", "restart_changes")}


def checkpointer(comm, args):
    """The run's Checkpointer (checkpoint.py) from --checkpoint-every, --stop-after, --restart."""
    from .checkpoint import Checkpointer
    return Checkpointer(comm, args.out, args.checkpoint_label, run_options(args),
                        every=args.checkpoint_every, stop_after=args.stop_after, restart=args.restart is not None,
                        changes=args.restart_changes if args.restart is not None else None)


def parse(parser, argv=None, check=None):
    """Parse; forward PETSc options; reject anything else unknown before any work.

    `check(args)` (optional) runs the checks that need several options or the scene's
    settings; a ValueError it raises is refused like a bad option (one line, exit 2).
    With --restart DIR the options are those of the checkpoint in DIR (restart_arguments).
    The output directory is created only when everything passed."""
    args, unknown = parser.parse_known_args(argv)
    forward_petsc_options(parser, unknown)
    try:
        if parser.checkpoint_label is not None:
            args.petsc_options = list(unknown)        # saved in a checkpoint: a restart solves alike
            if args.restart is not None:
                args = restart_arguments(parser, args, argv)
                # the run's PETSc options, then those typed now (they win)
                forward_petsc_options(parser, list(args.petsc_options) + list(unknown))
            args.checkpoint_label = parser.checkpoint_label
        if parser.material_options:
            args.elasticity = MicropolarElasticity(mu=args.mu, lmbda=args.lmbda, mu_c=args.mu_c, l_c=args.l_c)
            if not args.cauchy:
                args.elasticity.check_micropolar()
        if check is not None:
            check(args)
    except ValueError as error:
        parser.refuse(error)
    if parser.output_options:
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
