"""Argument checks of demcell's public calls, declared once and used everywhere.

A refusal is an ``InputError`` (a ``ValueError``) raised before any work, one line naming
the argument, what it may be and what it got:

    n_particles must be an integer in [2, 1e+06], got 30.5
    F must be an array of shape (2, 2), got shape (3,)
    radius[3] must be finite and > 0, got nan

``Range`` says what a number may be (the same rules as cosserat_fenicsx/validation.py, which
the FE side uses; demcell does not import it, the plug-in stands alone). ``number``,
``optional``, ``array``, ``instance`` and ``choice`` apply a declaration to an argument.
Integers are refused when they are not whole (30.5 is not cut to 30) and booleans and strings
are not numbers.
"""
import math
import numbers
from dataclasses import dataclass

import numpy as np

from .errors import InputError


def one_line(text):
    """`text` with its line breaks and runs of blanks folded to single spaces (a message
    from numpy or zipfile may span lines)."""
    return " ".join(str(text).split())


def real(value):
    """`value` as a Python number if it is a real number (a numpy scalar or a 0-d numeric
    array included), else None."""
    if isinstance(value, np.ndarray) and value.ndim == 0 and value.dtype.kind in "iuf":
        value = value.item()
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        return None
    return value


@dataclass(frozen=True)
class Range:
    """Allowed values of a number: finite, between ``low`` and ``high`` (each bound open or
    closed, None: unbounded), optionally a whole number; ``infinite`` admits +inf (a friction
    coefficient: no sliding)."""
    low: float = None
    high: float = None
    low_open: bool = False
    high_open: bool = False
    integer: bool = False
    infinite: bool = False

    def describe(self):
        """'> 0', 'in (0, 1]', 'an integer >= 1', 'a finite number', ..."""
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

    def allows(self, a):
        """Elementwise: which values of the float array `a` lie in the range."""
        a = np.asarray(a, dtype=float)
        with np.errstate(invalid="ignore"):
            ok = np.isfinite(a) | ((a == math.inf) & self.infinite)
            if self.integer:
                ok &= np.isfinite(a) & (a == np.round(a))
            if self.low is not None:
                ok &= (a > self.low) if self.low_open else (a >= self.low)
            if self.high is not None:
                ok &= (a < self.high) if self.high_open else (a <= self.high)
        return ok

    def admits(self, v):
        """Scalar form of ``allows`` for a Python int or float, without numpy (the checks of
        calls made once per step stay cheap); an int is compared exactly, not as a float."""
        if type(v) is float:
            if v != v or (v in (math.inf, -math.inf) and not (v > 0 and self.infinite and not self.integer)):
                return False
            if self.integer and v != math.inf and v != math.floor(v):
                return False
        above = self.low is None or (v > self.low if self.low_open else v >= self.low)
        below = self.high is None or (v < self.high if self.high_open else v <= self.high)
        return above and below

    def check(self, name, value):
        """`value` (int when the range is of integers, else float) if it lies in the range,
        else InputError naming `name`."""
        if type(value) in (int, float):
            v, ok = value, self.admits(value)
        else:
            v = real(value)
            ok = v is not None and bool(self.allows(v))
        if not ok:
            raise InputError(f"{name} must be {self.describe()}, got {one_line(repr(value))[:80]}")
        return int(v) if self.integer else float(v)


ANY = Range()
POSITIVE = Range(0.0, low_open=True)
NON_NEGATIVE = Range(0.0)
COUNT = Range(1, integer=True)
#: a step budget above this is no budget (weeks of one cell) and stays clear of int64 overflow
#: in the kernels' counters: larger budgets are cut to it
MAX_BUDGET = 10 ** 15
#: a number of steps to run: none up to the budget
STEP_BUDGET = Range(0, MAX_BUDGET, integer=True)
SEED = Range(0, 2 ** 63 - 1, integer=True)


def number(name, value, allowed=ANY):
    """Shorthand for allowed.check(name, value)."""
    return allowed.check(name, value)


def optional(name, value, allowed=ANY):
    """None passes (the default applies); anything else must lie in `allowed`."""
    return None if value is None else allowed.check(name, value)


def _shape_text(shape):
    return "(" + ", ".join("n" if d is None else str(d) for d in shape) + ("," if len(shape) == 1 else "") + ")"


def array(name, value, shape, allowed=ANY, dtype=np.float64, copy=True):
    """`value` as a new array of `dtype` whose shape is `shape` (None: any length on that
    axis) and whose values lie in `allowed`, else InputError naming `name`, the expected
    shape and the first value out of range. copy=False: `value` itself when it is already
    an array of `dtype` (for a caller that only reads it)."""
    what = "a boolean array" if dtype is bool else "an array of numbers"
    try:
        raw = np.asarray(value)
    except (ValueError, TypeError):
        raise InputError(f"{name} must be {what} of shape {_shape_text(shape)}, got a ragged "
                         f"{type(value).__name__}") from None
    kinds = "b" if dtype is bool else "biuf"
    if raw.dtype.kind not in kinds:
        raise InputError(f"{name} must be {what} of shape {_shape_text(shape)}, got {one_line(repr(value))[:80]}")
    if raw.ndim != len(shape) or any(d is not None and d != s for d, s in zip(shape, raw.shape)):
        raise InputError(f"{name} must be {what} of shape {_shape_text(shape)}, got shape {raw.shape}")
    a = np.array(raw, dtype=dtype, copy=copy or raw.dtype != dtype)
    if dtype is not bool:
        ok = allowed.allows(a)
        if not ok.all():
            bad = tuple(int(i) for i in np.argwhere(~ok)[0])
            where = "".join(f"[{i}]" for i in bad)
            raise InputError(f"{name}{where} must be {allowed.describe()}, got {float(a[bad])!r}")
    return a


def instance(name, value, kind, what=None):
    """`value` if it is a `kind` (a class or a tuple), else InputError naming `name`."""
    if not isinstance(value, kind):
        what = what or (" or ".join(k.__name__ for k in kind) if isinstance(kind, tuple) else kind.__name__)
        raise InputError(f"{name} must be a {what}, got {type(value).__name__}")
    return value


def choice(name, value, choices):
    """`value` if it is one of `choices`, else InputError listing them."""
    if not isinstance(value, str) or value not in choices:
        raise InputError(f"{name} must be one of {', '.join(repr(c) for c in choices)}, got {value!r}")
    return value
