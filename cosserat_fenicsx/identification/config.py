"""The identification's JSON inputs checked against their schema before any work: the
`--config` file (tests, stages, base and start values, bounds) and a `--bounds` file.

A shape that is not the documented one (docs/results/identification.md, "Data and configuration")
is refused in one line naming the file and the field -- a list where an object belongs, a
bound that is not a pair of numbers, a confining pressure that is a list, an unknown key
(a typo would otherwise be ignored).  The values themselves (parameter names, ranges, test
kinds, files) are checked where they are used, also before any model run.
"""

from __future__ import annotations

import json
import math

from ..validation import InputError
from .virtual_tests import KINDS

#: what a test entry of the config may hold: key -> (what it is, check)
TEST_KEYS = {
    "file": "a file name", "kind": "a test kind", "confining": "a pressure [Pa]",
    "quantities": "a list of quantity names", "normalisation": "an object {quantity: phi_0}",
    "scatter": "an object {quantity: sigma}", "start_pressure": "a pressure [Pa]",
    "unload_at": "an axial compression",
}
CONFIG_KEYS = ("tests", "stages", "params", "base", "start", "bounds")


def read_json(path, what):
    """A JSON file, strictly (NaN and Infinity are not JSON): InputError in one line naming
    it when it cannot be read."""
    def refuse(name):
        raise ValueError(f"{name} is not a JSON value")
    try:
        with open(path, encoding="utf-8") as f:
            return json.load(f, parse_constant=refuse)
    except UnicodeDecodeError:
        raise InputError(f"{what} {path!r}: not a text (UTF-8 JSON) file") from None
    except RecursionError:
        raise InputError(f"{what} {path!r}: nested too deeply") from None
    except (OSError, ValueError) as error:
        raise InputError(f"{what} {path!r}: {' '.join(str(error).split())}") from None


def _number(value):
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _finite(value):
    return _number(value) and math.isfinite(value)


def _names(value):
    return isinstance(value, list) and all(isinstance(v, str) for v in value)


def _positive_map(value):
    return isinstance(value, dict) and all(isinstance(k, str) and _finite(v) and v > 0 for k, v in value.items())


_TEST_CHECKS = {
    "file": lambda v: isinstance(v, str) and v != "",
    "kind": lambda v: isinstance(v, str),
    "confining": lambda v: v is None or (_finite(v) and v > 0),
    "quantities": _names,
    "normalisation": _positive_map,
    "scatter": _positive_map,
    "start_pressure": lambda v: _finite(v) and v >= 0,
    "unload_at": _finite,
}


def check_bounds(doc, where):
    """{name: [lower, upper]} with numbers (an infinite side allowed); returns {name: (lo, hi)}."""
    if not isinstance(doc, dict):
        raise InputError(f"{where}: expected an object {{parameter: [lower, upper]}}, got a JSON {_kind(doc)}")
    out = {}
    for name, pair in doc.items():
        if not (isinstance(pair, list) and len(pair) == 2 and all(_number(v) and not math.isnan(v) for v in pair)):
            raise InputError(f"{where}: bounds of {name!r} must be [lower, upper] (two numbers), got {pair!r}"[:200])
        out[name] = (float(pair[0]), float(pair[1]))
    return out


def check_values(doc, where):
    """{name: value} of parameter values (numbers, booleans or strings); returns it."""
    if not isinstance(doc, dict):
        raise InputError(f"{where}: expected an object {{parameter: value}}, got a JSON {_kind(doc)}")
    for name, value in doc.items():
        if not (isinstance(value, (bool, str)) or _finite(value)):
            raise InputError(f"{where}: {name!r} must be a finite number (or a flag), got {value!r}"[:200])
    return doc


def check_config(doc, where):
    """The --config document, every field's shape checked; returns it."""
    if not isinstance(doc, dict):
        raise InputError(f"{where}: expected a JSON object with {list(CONFIG_KEYS)}, got a JSON {_kind(doc)}")
    unknown = sorted(set(doc) - set(CONFIG_KEYS))
    if unknown:
        raise InputError(f"{where}: unknown key(s) {unknown} (known: {list(CONFIG_KEYS)})")
    tests = doc.get("tests", [])
    if not isinstance(tests, list):
        raise InputError(f"{where}: 'tests' must be a list of test objects, got a JSON {_kind(tests)}")
    for i, test in enumerate(tests):
        if not isinstance(test, dict):
            raise InputError(f"{where}: tests[{i}] must be an object, got {test!r}"[:200])
        for key in ("file", "kind"):
            if key not in test:
                raise InputError(f"{where}: tests[{i}] needs {key!r} ({TEST_KEYS[key]})")
        for key, value in test.items():
            if key not in TEST_KEYS:
                raise InputError(f"{where}: tests[{i}]: unknown key {key!r} (known: {list(TEST_KEYS)})")
            if not _TEST_CHECKS[key](value):
                raise InputError(f"{where}: tests[{i}].{key} must be {TEST_KEYS[key]}, got {value!r}"[:200])
        if test["kind"] not in KINDS:
            raise InputError(f"{where}: tests[{i}].kind {test['kind']!r} is not one of {sorted(KINDS)}"[:200])
        if KINDS[test["kind"]][0] != "pressure" and test.get("confining") is None:
            raise InputError(f"{where}: tests[{i}] ({test['kind']}) needs 'confining', its cell pressure [Pa]")
    for key in ("stages", "params"):
        stages = doc.get(key, [])
        if not isinstance(stages, list):
            raise InputError(f"{where}: {key!r} must be a list of stages, got a JSON {_kind(stages)}")
        for i, stage in enumerate(stages):
            if isinstance(stage, dict):
                extra = sorted(set(stage) - {"params", "kinds"})
                if extra or not _names(stage.get("params")) or not (stage.get("kinds") is None
                                                                    or _names(stage["kinds"])):
                    raise InputError(f"{where}: {key}[{i}] must be {{\"params\": [names], \"kinds\": [kinds]}}, "
                                     f"got {stage!r}"[:200])
            elif not (isinstance(stage, str) or _names(stage)):
                raise InputError(f"{where}: {key}[{i}] must be names (a list, or a comma-separated string), "
                                 f"got {stage!r}"[:200])
    for key in ("base", "start"):
        if key in doc:
            check_values(doc[key], f"{where}: {key!r}")
    if "bounds" in doc:
        check_bounds(doc["bounds"], f"{where}: 'bounds'")
    return doc


def _kind(value):
    return {dict: "object", list: "array", str: "string", bool: "boolean", type(None): "null"}.get(
        type(value), "number")
