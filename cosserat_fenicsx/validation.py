"""Input validation shared by the demos and the Python APIs (no dolfinx, no PETSc here).

Every number a user gives is checked against a declared `Range` before any form is
compiled or any cell is created; a refusal is an `InputError` whose message is one line
naming the option, the value and the allowed range:

    --height must be > 0, got -1
    biaxial: axial_strain must be in (0, 0.5), got 0.7

A scene's settings (a dataclass) declare each value's range once, on the field
(`setting`): `check_settings` checks an instance against them (the Python API), and
cli.add_settings makes the same fields command-line options whose type carries that range.
The command-line side (`Parser`, `number`) declares the range on the option itself, so
argparse refuses the value while parsing and the property tests can read every numeric
option of a demo and its range from the parser (`Parser.describe_options`; a demo run with
COSSERAT_DESCRIBE_OPTIONS=1 prints them as JSON and exits). `Parser.error` prints
one line (no usage block), on rank 0 only, and exits with status 2 on every rank.
"""
import argparse
from dataclasses import MISSING, dataclass, field, fields
import json
import math
import os
import re
import sys

EXIT_BAD_INPUT = 2


class InputError(ValueError):
    """Bad input, found before any work: one line naming the option, the value and the range."""


@dataclass(frozen=True)
class Range:
    """Allowed values of a number: finite, between `low` and `high` (each bound open or
    closed, None: unbounded), optionally an integer. `infinite` admits +inf (e.g. a
    friction coefficient: no sliding)."""
    low: float = None
    high: float = None
    low_open: bool = False
    high_open: bool = False
    integer: bool = False
    infinite: bool = False

    def describe(self):
        """'> 0', 'in (0, 0.5)', 'an integer >= 1', 'a finite number', ..."""
        if self.low is not None and self.high is not None:
            text = (f"in {'(' if self.low_open else '['}{self.low:g}, "
                    f"{self.high:g}{')' if self.high_open else ']'}")
        elif self.low is not None:
            text = f"{'>' if self.low_open else '>='} {self.low:g}"
        elif self.high is not None:
            text = f"{'<' if self.high_open else '<='} {self.high:g}"
        else:
            text = "a number" if self.infinite else "a finite number"
        if self.integer:
            text = "an integer" if text == "a finite number" else f"an integer {text}"
        return text + (" (inf allowed)" if self.infinite else "")

    def contains(self, value):
        if isinstance(value, bool) or not isinstance(value, (int, float)) and not hasattr(value, "__float__"):
            return False
        v = float(value)
        if math.isnan(v) or (math.isinf(v) and not (self.infinite and v > 0)):
            return False
        if self.integer and (math.isinf(v) or v != int(v)):
            return False
        if self.low is not None and (v < self.low or (self.low_open and v == self.low)):
            return False
        if self.high is not None and (v > self.high or (self.high_open and v == self.high)):
            return False
        return True

    def check(self, name, value):
        """`value` if it lies in the range (as int or float), else InputError naming `name`."""
        if not self.contains(value):
            raise InputError(f"{name} must be {self.describe()}, got {value!r}")
        return int(value) if self.integer else float(value)


ANY = Range()
POSITIVE = Range(low=0.0, low_open=True)
NON_NEGATIVE = Range(low=0.0)
COUNT = Range(low=1, integer=True)
STEPS = Range(1, 1_000_000, integer=True)    # load steps: more than a million is a typo here
NON_NEGATIVE_INTEGER = Range(low=0, integer=True)
UNIT_OPEN = Range(0.0, 1.0, low_open=True, high_open=True)
AXIAL_STRAIN = Range(0.0, 0.5, low_open=True, high_open=True)   # compression of a test, |strain|
FRACTION = Range(0.0, 1.0, low_open=True)    # a factor that weakens: (0, 1]
DISCS = Range(10, 100_000, integer=True)     # discs per periodic DEM cell
FRICTION = Range(0.0, infinite=True)         # Coulomb coefficient; inf: no sliding
DEGREE = Range(1, 4, integer=True)           # polynomial degree of a field


def check(name, value, allowed=ANY):
    """Shorthand for allowed.check(name, value)."""
    return allowed.check(name, value)


def check_optional(name, value, allowed=ANY):
    """None passes (the option's default applies); anything else must lie in `allowed`."""
    return None if value is None else allowed.check(name, value)


# --- settings declared with their ranges -----------------------------------------------

def setting(default=None, allowed=None, help=None, *, choices=None, flag=None, optional=False):
    """A dataclass field that declares what it takes: a number in `allowed` (a Range), one
    of `choices`, or a bool (a bool default); a None default, or `optional`, makes None
    pass (a setting that None turns off). `help` (with the unit) and `flag` (default
    --name) are its command-line option (cli.add_settings); a field without `help` is the
    Python API's only."""
    return field(default=default, metadata={"allowed": allowed, "choices": choices, "help": help, "flag": flag,
                                                   "optional": optional or default is None})


def declared(cls):
    """{name: dataclasses.Field} of the fields of `cls` declared with `setting`."""
    return {f.name: f for f in fields(cls) if "allowed" in f.metadata}


def check_settings(settings, label):
    """Every declared field of `settings` in its range: InputError '<label>: <name> must be
    ..., got ...' for the first that is not."""
    for name, f in declared(type(settings)).items():
        value = getattr(settings, name)
        meta = f.metadata
        if value is None and meta["optional"]:
            continue
        if isinstance(f.default, bool):
            if not isinstance(value, bool):
                raise InputError(f"{label}: {name} must be True or False, got {value!r}")
        elif meta["choices"] is not None:
            if not isinstance(value, str) or value not in meta["choices"]:
                raise InputError(f"{label}: {name} must be one of {', '.join(meta['choices'])}, got {value!r}")
        elif meta["allowed"] is not None:
            meta["allowed"].check(f"{label}: {name}", value)


def option_flag(f):
    """The command-line flag of a declared field: its `flag`, else --name."""
    return f.metadata["flag"] or "--" + f.name.replace("_", "-")


def option_dest(f):
    """The argparse dest of a declared field's option (from its flag)."""
    return option_flag(f)[2:].replace("-", "_")


def field_default(f):
    return f.default_factory() if f.default is MISSING else f.default


# --- command line --------------------------------------------------------------------

class Number:
    """argparse `type` of a numeric option with its allowed range; the parser keeps it, so
    `Parser.describe_options()` lists every numeric option with its range."""

    def __init__(self, allowed=ANY):
        self.allowed = allowed
        self.__name__ = "integer" if allowed.integer else "number"   # argparse's "invalid %s value"

    def __call__(self, text):
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
        if self.allowed.integer and math.isfinite(value) and value == int(value):
            value = int(value)
        if not self.allowed.contains(value):
            raise argparse.ArgumentTypeError(f"must be {self.allowed.describe()}, got {text}")
        return value

    def __repr__(self):
        return f"Number({self.allowed.describe()})"


def number(allowed=ANY, **range_kwargs):
    """The argparse type of a number in `allowed` (or in Range(**range_kwargs))."""
    return Number(Range(**range_kwargs) if range_kwargs else allowed)


def key_value(text):
    """argparse `type` of a KEY=VALUE option: (key, value) with the value None (none), an int,
    a float or the string as typed (which option names a key is checked by whoever takes it)."""
    key, sep, raw = text.partition("=")
    if not sep or not key.isidentifier() or not raw:
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE, got {text!r}")
    if raw.lower() == "none":
        return key, None
    for kind in (int, float):
        try:
            return key, kind(raw)
        except ValueError:
            pass
    return key, raw


DESCRIBE_OPTIONS = "COSSERAT_DESCRIBE_OPTIONS"


def _rank():
    """The MPI rank without importing mpi4py (a dolfinx-free demo must stay light)."""
    for key in ("OMPI_COMM_WORLD_RANK", "PMI_RANK", "PMIX_RANK"):
        if key in os.environ:
            return int(os.environ[key])
    return 0


class Parser(argparse.ArgumentParser):
    """An ArgumentParser whose errors are one line (no usage block), printed by rank 0
    only, with exit status 2 on every rank (collective: every rank parses the same argv).
    Negative numbers in scientific notation (`--lmbda -1e9`, `--shift -inf`) are values,
    not options (argparse's own pattern knows only -12 and -1.5)."""

    #: set by cli.add_material_options, add_output_options, add_checkpoint_options: what
    #: cli.parse makes of the options (the elasticity, the output directory, a restart)
    material_options = False
    output_options = False
    checkpoint_label = None          # the demo's name in its checkpoints; None: no checkpoints
    restart_solver_options = ()      # dests a restart may change (how a step is solved)

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$|^-inf(inity)?$",
                                                   re.IGNORECASE)

    def parse_known_args(self, args=None, namespace=None):
        if os.environ.get(DESCRIBE_OPTIONS):
            # for tools and the property tests: the numeric options and their ranges, no run
            if _rank() == 0:
                print(json.dumps(self.describe_options()))
            sys.exit(0)
        return super().parse_known_args(args, namespace)

    def describe_options(self):
        """{option: {low, high, low_open, high_open, integer, infinite, default}} of every
        numeric option (printed by a demo run with COSSERAT_DESCRIBE_OPTIONS=1)."""
        return {a.option_strings[-1]: dict(vars(a.type.allowed), default=a.default)
                for a in self._actions if isinstance(a.type, Number) and a.option_strings}

    def error(self, message):
        if _rank() == 0:
            sys.stderr.write(f"{self.prog}: error: {message}\n")
            sys.stderr.flush()
        sys.exit(EXIT_BAD_INPUT)

    def refuse(self, error):
        """An InputError or ValueError found after parsing, still before any work."""
        self.error(" ".join(str(error).split()) or type(error).__name__)

    def check_saved(self, values, where):
        """Option values read from a file (a checkpoint's options) checked as if typed: each
        a dest of this parser, a flag a boolean, a choice among its choices, a number in its
        declared range, a list where the option collects several; ValueError naming `where`
        and the option."""
        actions = {a.dest: a for a in self._actions}
        for dest, value in values.items():
            action = actions.get(dest)
            if action is None:
                continue             # the run's own entries (petsc_options, ...), not typed options
            flag = action.option_strings[-1] if action.option_strings else dest
            if action.nargs == 0:                 # a flag (store_true / store_false)
                ok = isinstance(value, bool)
            elif isinstance(action, argparse._AppendAction) or action.nargs in ("*", "+"):
                ok = value is None or isinstance(value, (list, tuple))
            elif value is None:
                ok = action.default is None
            elif action.choices is not None:
                ok = isinstance(value, (str, int, float)) and not isinstance(value, bool) and value in action.choices
            elif isinstance(action.type, Number):
                ok = isinstance(value, (int, float)) and not isinstance(value, bool)
                if ok:
                    try:
                        action.type(repr(float(value)))
                    except argparse.ArgumentTypeError as error:
                        raise ValueError(f"{where}: {flag} {error}") from None
            else:
                ok = isinstance(value, (str, int, float)) and not isinstance(value, bool)
                if ok and action.type is not None and isinstance(value, str):
                    try:
                        action.type(value)
                    except (argparse.ArgumentTypeError, ValueError, TypeError) as error:
                        raise ValueError(f"{where}: {flag} {value!r}: {error}"[:300]) from None
            if not ok:
                raise ValueError(f"{where}: {flag} is {value!r}"[:200] + ", not a value this option takes")

    def given_options(self, argv=None):
        """The dests of the options given explicitly in argv (default sys.argv[1:]), so a
        value read from a file can be overridden only by what the user typed."""
        argv = sys.argv[1:] if argv is None else list(argv)
        typed = {tok.split("=", 1)[0] for tok in argv if tok.startswith("--")}
        return {a.dest for a in self._actions if typed & set(a.option_strings)}
