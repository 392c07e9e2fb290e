"""Data-only encoding of a run's state (history rows, Newton records, a demo's own lists) as
strict JSON plus numpy arrays, for checkpoints (checkpoint.py, docs/reference/restart.md).

Why not pickle: reading a pickle runs whatever code its author put in it, so a checkpoint
directory received from someone else could run anything on restart. What this module reads
is data only: JSON values, arrays loaded without pickle, and instances of the few dataclasses
the caller names (built from their fields by their own constructor; no name in a file is ever
imported). A value this module cannot represent is refused when written, naming where it is
in the state, never turned into a string.

encode(value, types) -> (document, arrays): `document` is made of JSON values only (dump it
with json.dump(..., allow_nan=False)); `arrays` maps the keys the document refers to to the
numpy arrays (save them with np.savez, load them with np.load(..., allow_pickle=False)).
decode(document, arrays, types) gives back a value equal to the one encoded. The tags:

    {"__array__": key}             a numpy array, arrays[key]
    {"__tuple__": [...]}           a tuple
    {"__float__": "inf"}           a float that JSON cannot hold: "inf", "-inf", "nan"
    {"__scalar__": [dtype, x]}     a numpy float16 / float32 scalar (kept: arithmetic with it
                                   differs from float64's)
    {"__dict__": [[key, value], ...]}   a dict with a key that is not a string (or is a tag)
    {"__dataclass__": [name, {field: value}]}   an instance of one of `types`

Other numpy scalars become the Python number of the same value (float64 -> float, integers
-> int, bool_ -> bool). Lists and dicts with string keys are JSON arrays and objects.
Pure Python and numpy: testable without MPI or dolfinx.
"""
import dataclasses
import math

import numpy as np

TAGS = ("__array__", "__tuple__", "__float__", "__scalar__", "__dict__", "__dataclass__")
_NONFINITE = {"inf": math.inf, "-inf": -math.inf, "nan": math.nan}
#: numpy scalars kept with their dtype (a float of the same value would compute differently)
_KEPT_SCALARS = {"float16": np.float16, "float32": np.float32}


class StateCodecError(ValueError):
    """A value cannot be encoded, or a document is not one this module writes; the message
    says where."""


def type_name(cls):
    """The name a dataclass is stored under (looked up among `types`, never imported)."""
    return f"{cls.__module__}.{cls.__qualname__}"


def _where(path):
    """`path` (keys and indices from the top) as text, e.g. ['infos'][3].residual_history."""
    out = ""
    for part in path:
        out += f".{part[1:]}" if isinstance(part, str) and part.startswith(".") else f"[{part!r}]"
    return out or "the top level"


def _registry(types):
    registry = {}
    for cls in types or ():
        if not (isinstance(cls, type) and dataclasses.is_dataclass(cls)):
            raise TypeError(f"types must be dataclasses, got {cls!r}")
        registry[type_name(cls)] = cls
    return registry


# --- encoding --------------------------------------------------------------------------------
def encode(value, types=()):
    """(JSON document, {key: array}) of `value`; StateCodecError naming the place of the
    first value that cannot be stored."""
    encoder = _Encoder(_registry(types))
    return encoder.encode(value, ()), encoder.arrays


class _Encoder:
    def __init__(self, registry):
        self.classes = {cls: name for name, cls in registry.items()}
        self.arrays = {}
        self.open = set()          # ids of the containers being encoded (a cycle is refused)

    def fail(self, path, what):
        raise StateCodecError(f"the run state at {_where(path)} is {what}, which a checkpoint cannot hold "
                              "(data only: None, bool, int, float, str, list, tuple, dict, numpy arrays and "
                              "scalars, and the registered records)")

    def encode(self, value, path):
        kind = type(value)
        if value is None or kind in (bool, int, str):
            return value
        if kind is float:
            if math.isfinite(value):
                return value
            return {"__float__": "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf")}
        if isinstance(value, np.generic):
            return self.scalar(value, path)
        if kind is np.ndarray:
            if value.dtype.hasobject:
                self.fail(path, f"an array of dtype {value.dtype} (Python objects)")
            key = f"a{len(self.arrays)}"
            self.arrays[key] = value
            return {"__array__": key}
        if kind in (list, tuple, dict) or kind in self.classes:
            if id(value) in self.open:
                self.fail(path, "a container that contains itself")
            self.open.add(id(value))
            try:
                return self.container(value, kind, path)
            finally:
                self.open.discard(id(value))
        name = kind.__name__ if kind.__module__ == "builtins" else f"{kind.__module__}.{kind.__qualname__}"
        self.fail(path, f"{'an' if name[0] in 'aeiou' else 'a'} {name}")

    def scalar(self, value, path):
        if isinstance(value, np.bool_):
            return bool(value)
        if isinstance(value, np.integer):
            return int(value)
        if isinstance(value, np.floating):
            if value.dtype.name in _KEPT_SCALARS:
                return {"__scalar__": [value.dtype.name, self.encode(float(value), path)]}
            if value.dtype == np.float64:
                return self.encode(float(value), path)
        if isinstance(value, np.str_):
            return str(value)
        self.fail(path, f"a numpy {value.dtype} scalar")

    def container(self, value, kind, path):
        if kind is list:
            return [self.encode(v, path + (i,)) for i, v in enumerate(value)]
        if kind is tuple:
            return {"__tuple__": [self.encode(v, path + (i,)) for i, v in enumerate(value)]}
        if kind is dict:
            if all(type(k) is str and k not in TAGS for k in value):
                return {k: self.encode(v, path + (k,)) for k, v in value.items()}
            return {"__dict__": [[self.encode(k, path + (f".<key {k!r}>",)), self.encode(v, path + (k,))]
                                 for k, v in value.items()]}
        if not all(f.init for f in dataclasses.fields(value)):     # its constructor could not take them back
            self.fail(path, f"a {self.classes[kind]} with fields outside its constructor")
        fields = {f.name: self.encode(getattr(value, f.name), path + (f".{f.name}",))
                  for f in dataclasses.fields(value)}
        return {"__dataclass__": [self.classes[kind], fields]}


# --- decoding --------------------------------------------------------------------------------
def decode(document, arrays, types=(), arrays_name="the arrays file"):
    """The value `document` (as json.load gives it) and `arrays` encode; StateCodecError
    naming the place of anything that encode does not write (`arrays_name`: what the
    message calls `arrays`, e.g. their file)."""
    return _Decoder(arrays, _registry(types), arrays_name).decode(document, ())


class _Decoder:
    def __init__(self, arrays, registry, arrays_name):
        self.arrays, self.registry, self.arrays_name = arrays, registry, arrays_name

    def fail(self, path, what):
        raise StateCodecError(f"at {_where(path)}: {what}")

    def decode(self, value, path):
        kind = type(value)
        if value is None or kind in (bool, int, str):
            return value
        if kind is float:
            if not math.isfinite(value):       # json.load with parse_constant refuses these first
                self.fail(path, f"a non-finite number {value!r} outside a __float__ tag")
            return value
        if kind is list:
            return [self.decode(v, path + (i,)) for i, v in enumerate(value)]
        if kind is not dict:
            self.fail(path, f"a {kind.__name__}, not a JSON value")
        tags = [k for k in value if k in TAGS]
        if not tags:
            return {k: self.decode(v, path + (k,)) for k, v in value.items()}
        if len(value) != 1:
            self.fail(path, f"an object with the tag {tags[0]!r} and other keys")
        tag, payload = tags[0], value[tags[0]]
        return getattr(self, "_" + tag.strip("_"))(payload, path)

    def _array(self, key, path):
        if type(key) is not str:
            self.fail(path, f"an __array__ key {key!r} that is not a string")
        if key not in self.arrays:
            self.fail(path, f"the array {key!r}, which {self.arrays_name} does not hold")
        return self.arrays[key]

    def _tuple(self, items, path):
        if type(items) is not list:
            self.fail(path, f"a __tuple__ of {type(items).__name__}, not a list")
        return tuple(self.decode(v, path + (i,)) for i, v in enumerate(items))

    def _float(self, name, path):
        if type(name) is not str or name not in _NONFINITE:
            self.fail(path, f"a __float__ of {name!r} (one of {', '.join(_NONFINITE)})")
        return _NONFINITE[name]

    def _scalar(self, payload, path):
        if type(payload) is not list or len(payload) != 2 or payload[0] not in _KEPT_SCALARS:
            self.fail(path, f"a __scalar__ of {payload!r} (one of {', '.join(_KEPT_SCALARS)} and a number)")
        number = self.decode(payload[1], path)
        if type(number) not in (int, float):
            self.fail(path, f"a __scalar__ value {number!r} that is not a number")
        return _KEPT_SCALARS[payload[0]](number)

    def _dict(self, pairs, path):
        if type(pairs) is not list or not all(type(p) is list and len(p) == 2 for p in pairs):
            self.fail(path, "a __dict__ that is not a list of [key, value] pairs")
        out = {}
        for k, v in pairs:
            key = self.decode(k, path + (f".<key {k!r}>",))
            try:
                hash(key)
            except TypeError:
                self.fail(path, f"a __dict__ key {key!r} that cannot be a key")
            out[key] = self.decode(v, path + (key,))
        return out

    def _dataclass(self, payload, path):
        if type(payload) is not list or len(payload) != 2 or type(payload[1]) is not dict:
            self.fail(path, "a __dataclass__ that is not [name, {field: value}]")
        name, fields = payload
        cls = self.registry.get(name) if type(name) is str else None
        if cls is None:
            self.fail(path, f"a record of type {name!r}, which this reader does not know "
                            f"(it knows {', '.join(sorted(self.registry)) or 'none'})")
        # a field with a default may be absent (a record written before the field existed)
        names = {f.name for f in dataclasses.fields(cls) if f.init}
        required = {f.name for f in dataclasses.fields(cls) if f.init and f.default is dataclasses.MISSING
                    and f.default_factory is dataclasses.MISSING}
        missing, unknown = required - set(fields), set(fields) - names
        if missing or unknown:
            self.fail(path, f"a {name} record " + "; ".join(
                part for part in (f"without {', '.join(sorted(missing))}" if missing else "",
                                  f"with unknown {', '.join(sorted(unknown))}" if unknown else "") if part))
        return cls(**{k: self.decode(v, path + (f".{k}",)) for k, v in fields.items()})
