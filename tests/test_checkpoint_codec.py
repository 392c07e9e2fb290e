"""The run state of a checkpoint (docs/reference/restart.md) is data only: run.json (strict JSON) and
run_arrays.npz (read without pickle), through cosserat_fenicsx.state_codec. What a restart
hands the scene equals what it saved, types included (a float stays a float, a tuple a tuple,
an array keeps its dtype and bits); a value that cannot be stored is refused at write time
naming its key; a checkpoint of format 1 (a pickled run.pkl) or a pickle put where the run
state belongs is refused without being unpickled; damaged files are refused with one line
naming the file."""
import ast
import dataclasses
import json
import math
import os
import pickle

import numpy as np
import pytest

from cosserat_fenicsx import state_codec
from cosserat_fenicsx.checkpoint import (FORMAT, RUN_ARRAYS, RUN_STATE, CheckpointError, read_meta,
                                         read_run_state, write_run_state)

pytestmark = pytest.mark.serial          # files and one demo start only: the serial pass

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def same(a, b, where="state"):
    """a and b equal with the same types throughout (nan equal to nan, arrays bit for bit)."""
    assert type(a) is type(b), f"{where}: {type(a).__name__} != {type(b).__name__}"
    if isinstance(a, np.ndarray):
        assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes(), where
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), where
        for k, (x, y) in enumerate(zip(a, b)):
            same(x, y, f"{where}[{k}]")
    elif isinstance(a, dict):
        assert list(a) == list(b), where
        for k in a:
            same(a[k], b[k], f"{where}[{k!r}]")
    elif dataclasses.is_dataclass(a):
        same(dataclasses.asdict(a), dataclasses.asdict(b), where)
    elif isinstance(a, float) and math.isnan(a):
        assert math.isnan(b), where
    else:
        assert a == b, where
        if isinstance(a, float):
            assert math.copysign(1.0, a) == math.copysign(1.0, b), where      # -0.0 stays


def python_types(value):
    """What a restore gives for `value`: numpy scalars as the Python numbers of the same
    value (float16/float32 kept), the rest as it is."""
    if isinstance(value, np.generic) and not isinstance(value, (np.float16, np.float32)):
        return value.item()
    if type(value) is list:
        return [python_types(v) for v in value]
    if type(value) is tuple:
        return tuple(python_types(v) for v in value)
    if type(value) is dict:
        return {python_types(k): python_types(v) for k, v in value.items()}
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return type(value)(**{f.name: python_types(getattr(value, f.name)) for f in dataclasses.fields(value)})
    return value


def run_state():
    """A run state like the scenes' and demos' (history rows, SolveInfo records, the demos'
    extra lists of (strain, array) tuples), with the awkward values on top."""
    from cosserat_fenicsx.snes import SolveInfo
    row = {"step": 3, "time": 1.25, "phase": 2, "axial_strain": np.float64(-0.0012), "vertical_stress": -1.0e5,
           "volumetric_strain": -0.0, "plastic_fraction": 0.125, "max_yield_function": -np.inf,
           "newton_orders_min": np.nan, "force_ratio": np.float64(np.nan), "accepted": int(np.bool_(True)),
           "dem_steps": np.float64(1.5e6), "points_without_contacts": np.int64(0), "cuts": 1, "wall_time": 0.5}
    info = SolveInfo(converged=True, iterations=np.int32(4), residual=np.float64(3.2e-11), reason="CONVERGED_FNORM_RELATIVE",
                     residual_history=[np.float64(1.0), np.float64(1e-3), 3.2e-11], failure="", wall_time=0.01,
                     force_ratios=[np.nan, 0.5, np.float64(1e-4)], flags="", accepted=np.bool_(False))
    return {
        "history": [row, dict(row, step=4, max_yield_function=np.float64(np.inf))],
        "infos": [info, SolveInfo(False, 25, np.inf, "DIVERGED_MAX_IT", [1.0, np.nan], "cell without contacts")],
        "volumetric_phase1": np.float64(-2.5e-4),
        "extra": {"per_point": [(0.0, np.array([0.5, np.nan, -np.inf])), (-1e-3, np.arange(4, dtype=np.int32))],
                  "written": [0.0, 1.0, 2.5]},
        "nothing": None, "flags": [True, False, np.bool_(True)], "label": "biaxial", "unicode": "σ₁₁ / p₀",
        "big": 2 ** 70, "tuple": (1, (2.0, "x"), [], ()), "by_step": {1: "a", 2.5: "b", (3, "c"): None, None: 0},
        "tag_like": {"__array__": "not an array", "__tuple__": [1]}, "f32": np.float32(0.1), "f16": np.float16(-2.5),
        "empty": np.zeros((0, 3)), "matrix": np.eye(2, dtype=np.float32), "strings": np.array(["a", "bc"]),
        "scalar_array": np.array(7.0), "text": np.str_("numpy text"), "nested": {"deep": [[{"x": [np.nan]}]]},
    }


def test_run_state_round_trip(tmp_path):
    state = run_state()
    write_run_state(str(tmp_path), state)
    assert sorted(os.listdir(tmp_path)) == [RUN_STATE, RUN_ARRAYS]
    with open(tmp_path / RUN_STATE) as f:      # strict JSON: no NaN / Infinity literals
        json.load(f, parse_constant=lambda name: pytest.fail(f"{name} in run.json"))
    back = read_run_state(str(tmp_path))
    same(python_types(state), back)
    # the numbers a continued run computes with are the saved ones bit for bit
    assert back["volumetric_phase1"] == state["volumetric_phase1"]
    assert back["infos"][0].residual_history == state["infos"][0].residual_history
    assert back["f32"].dtype == np.float32 and back["f32"] == state["f32"]


def test_a_state_without_arrays_writes_no_arrays_file(tmp_path):
    state = {"history": [{"step": 1, "time": 1.0}], "infos": [], "volumetric_phase1": None, "extra": {"written": []}}
    write_run_state(str(tmp_path), state)
    assert os.listdir(tmp_path) == [RUN_STATE]
    same(state, read_run_state(str(tmp_path)))


@pytest.mark.parametrize("value,key,what", [
    ({1, 2}, "['extra']['plot']", "a set"),
    (1 + 2j, "['extra']['plot']", "a complex"),
    (b"bytes", "['extra']['plot']", "a bytes"),
    ([1, object()], "['extra']['plot'][1]", "an object"),
    (np.array([None, 1]), "['extra']['plot']", "Python objects"),
    (np.complex128(1j), "['extra']['plot']", "complex128"),
    ({"a": (1, {"f": lambda: 0})}, "['extra']['plot']['a'][1]['f']", "a function"),
])
def test_what_cannot_be_stored_is_refused_at_write_time_naming_the_key(tmp_path, value, key, what):
    with pytest.raises(CheckpointError) as error:
        write_run_state(str(tmp_path), {"history": [], "extra": {"plot": value}})
    message = str(error.value)
    assert key in message and what in message and "\n" not in message
    assert not os.listdir(tmp_path)            # nothing written, not a string in its place


def test_a_record_type_the_reader_does_not_know_is_refused():
    @dataclasses.dataclass
    class Point:
        x: float
        y: float = 0.0

    document, arrays = state_codec.encode([Point(1.0)], types=(Point,))
    assert state_codec.decode(document, arrays, types=(Point,)) == [Point(1.0)]
    with pytest.raises(state_codec.StateCodecError, match="does not know"):
        state_codec.decode(document, arrays)            # never looked up by its name
    with pytest.raises(state_codec.StateCodecError, match=r"\[0\] is a .*Point"):
        state_codec.encode([Point(1.0)])
    del document[0]["__dataclass__"][1]["y"]      # a field with a default may be absent
    assert state_codec.decode(document, arrays, types=(Point,)) == [Point(1.0, 0.0)]
    del document[0]["__dataclass__"][1]["x"]
    with pytest.raises(state_codec.StateCodecError, match="without x"):
        state_codec.decode(document, arrays, types=(Point,))
    document[0]["__dataclass__"][1].update(x=1.0, z=1)
    with pytest.raises(state_codec.StateCodecError, match="with unknown z"):
        state_codec.decode(document, arrays, types=(Point,))


def test_a_container_holding_itself_is_refused():
    loop = []
    loop.append(loop)
    with pytest.raises(state_codec.StateCodecError, match="contains itself"):
        state_codec.encode({"a": loop})


class Payload:
    """Unpickling this creates the file `marker` (as a hostile checkpoint could run anything)."""

    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        return (open, (self.marker, "w"))


def test_the_payload_would_run_if_it_were_unpickled(tmp_path):
    """The control of the tests below: unpickling the payload does create its file."""
    marker = tmp_path / "control"
    loaded = pickle.loads(pickle.dumps({"history": Payload(str(marker))}))
    loaded["history"].close()
    assert marker.exists()


def fake_checkpoint(out, marker, format):
    """out/checkpoint as a format-`format` checkpoint of the biaxial demo whose run.pkl
    creates `marker` when unpickled."""
    path = out / "checkpoint"
    path.mkdir(parents=True)
    meta = {"format": format, "label": "biaxial", "step": 2, "time": 2.0, "dt": 1.0, "cuts": 0, "ranks": 1,
            "n_points": 4, "dolfinx": "0", "fields_file": "fields.xdmf", "options": {}}
    (path / "meta.json").write_text(json.dumps(meta))
    (path / "run.pkl").write_bytes(pickle.dumps({"history": Payload(str(marker))}))
    return path


def test_a_pickled_run_state_is_never_loaded(tmp_path):
    marker = tmp_path / "pwned"
    path = fake_checkpoint(tmp_path / "old", marker, format=1)
    with pytest.raises(CheckpointError) as error:
        read_meta(str(tmp_path / "old"), "biaxial")
    message = str(error.value)
    assert "format 1" in message and "cannot be read safely" in message and "\n" not in message
    # a run.pkl beside a current meta.json is not read either: run.json is the run state
    path = fake_checkpoint(tmp_path / "new", marker, format=FORMAT)
    assert read_meta(str(tmp_path / "new"), "biaxial")["format"] == FORMAT == 2
    with pytest.raises(CheckpointError, match=f"cannot read .*{RUN_STATE}"):
        read_run_state(str(path))
    # nor a pickle under the array file's name, or inside it as an object array
    (path / RUN_STATE).write_text(json.dumps({"history": {"__array__": "a0"}}))
    (path / RUN_ARRAYS).write_bytes(pickle.dumps({"a0": Payload(str(marker))}))
    with pytest.raises(CheckpointError, match=f"cannot read .*{RUN_ARRAYS}"):
        read_run_state(str(path))
    np.savez(path / RUN_ARRAYS, a0=np.array([Payload(str(marker))], dtype=object))
    with pytest.raises(CheckpointError, match=f"cannot read .*{RUN_ARRAYS}.*allow_pickle"):
        read_run_state(str(path))
    assert not marker.exists()


def test_a_restart_from_a_format_1_checkpoint_is_refused_without_unpickling(tmp_path, demo):
    """The demo as a user runs it: one line, exit status 2, the pickle never loaded."""
    marker = tmp_path / "pwned"
    fake_checkpoint(tmp_path / "old", marker, format=1)
    proc = demo("biaxial", "--restart", tmp_path / "old", check=False)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert "format 1" in proc.stderr and "cannot be read safely" in proc.stderr and "Traceback" not in proc.stderr
    assert not marker.exists()


DAMAGED = [
    ("not JSON", '{"history": [1, 2', RUN_STATE),
    ("not UTF-8", b"\xff\xfe{", RUN_STATE),
    ("a NaN literal", '{"history": [NaN]}', RUN_STATE),
    ("a list", '[{"history": []}]', RUN_STATE),
    ("a string", '"history"', RUN_STATE),
    ("a wrong tag", '{"history": {"__float__": "1e400"}}', RUN_STATE),
    ("a tag with more keys", '{"history": {"__tuple__": [1], "x": 2}}', RUN_STATE),
    ("a tuple of a number", '{"history": {"__tuple__": 3}}', RUN_STATE),
    ("a missing array", '{"history": {"__array__": "a7"}}', RUN_ARRAYS),
    ("an array key not a string", '{"history": {"__array__": 0}}', RUN_STATE),
    ("an unknown record", '{"infos": [{"__dataclass__": ["os.system", {"command": "true"}]}]}', RUN_STATE),
    ("a record without a field",
     '{"infos": [{"__dataclass__": ["cosserat_fenicsx.snes.SolveInfo", {"converged": true}]}]}', RUN_STATE),
    ("a record of a list", '{"infos": [{"__dataclass__": ["cosserat_fenicsx.snes.SolveInfo", []]}]}', RUN_STATE),
    ("an unhashable key", '{"__dict__": [[[1, 2], 3]]}', RUN_STATE),
    ("pairs that are not pairs", '{"__dict__": [[1, 2, 3]]}', RUN_STATE),
    ("a bad scalar", '{"f": {"__scalar__": ["object", 1]}}', RUN_STATE),
    ("a tagged top level that is not a dict", '{"__tuple__": [1, 2]}', RUN_STATE),
]


@pytest.mark.parametrize("what,text,named", DAMAGED, ids=[d[0] for d in DAMAGED])
def test_a_damaged_run_state_is_refused_naming_the_file(tmp_path, what, text, named):
    (tmp_path / RUN_STATE).write_bytes(text if isinstance(text, bytes) else text.encode())
    with pytest.raises(CheckpointError) as error:
        read_run_state(str(tmp_path))
    message = str(error.value)
    assert "\n" not in message and str(tmp_path / RUN_STATE) in message and named in message, message


def test_a_key_that_only_looks_like_a_tag_is_data(tmp_path):
    (tmp_path / RUN_STATE).write_text('{"history": {"__code__": "print(1)"}}')
    assert read_run_state(str(tmp_path)) == {"history": {"__code__": "print(1)"}}


def test_a_missing_or_damaged_arrays_file_is_refused_naming_it(tmp_path):
    write_run_state(str(tmp_path), {"extra": {"per_point": [(0.0, np.arange(3.0))]}})
    (tmp_path / RUN_ARRAYS).write_bytes(b"PK\x03\x04 truncated")
    with pytest.raises(CheckpointError, match=f"cannot read .*{RUN_ARRAYS}"):
        read_run_state(str(tmp_path))
    os.remove(tmp_path / RUN_ARRAYS)
    with pytest.raises(CheckpointError, match=rf"{RUN_ARRAYS} \(missing\)"):
        read_run_state(str(tmp_path))


def test_checkpoint_module_reads_arrays_without_pickle():
    """Every np.load in checkpoint.py says allow_pickle=False, and pickle is not imported."""
    with open(os.path.join(ROOT, "cosserat_fenicsx", "checkpoint.py")) as f:
        tree = ast.parse(f.read())
    loads = [node for node in ast.walk(tree) if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
             and node.func.attr == "load" and getattr(node.func.value, "id", None) == "np"]
    assert len(loads) >= 4
    for call in loads:
        keywords = {k.arg: k.value for k in call.keywords}
        assert isinstance(keywords.get("allow_pickle"), ast.Constant) and keywords["allow_pickle"].value is False, \
            f"np.load on line {call.lineno}"
    imported = {alias.name for node in ast.walk(tree) if isinstance(node, (ast.Import, ast.ImportFrom))
                for alias in node.names}
    assert "pickle" not in imported


@pytest.mark.parametrize("change, named", [
    (dict(step=None), "'step'"), (dict(step=-1), "'step'"), (dict(step="2"), "'step'"), (dict(step=True), "'step'"),
    (dict(time=float("nan")), "'time'"), (dict(dt=0.0), "'dt'"), (dict(ranks=0), "'ranks'"),
    (dict(n_points=1.5), "'n_points'"), (dict(options=3), "'options'"), (dict(options=[1, 2]), "options"),
    (dict(options={"friction": {"__float__": "big"}}), "options"), (dict(label=7), "'label'")])
def test_a_damaged_meta_file_is_refused_naming_the_field(tmp_path, change, named):
    """meta.json checked field by field before anything else is read: one line naming the
    file and the field (a missing 'step' or an 'options' list were a KeyError/AttributeError)."""
    path = fake_checkpoint(tmp_path, tmp_path / "marker", format=FORMAT)
    meta = json.loads((path / "meta.json").read_text())
    meta.update(change)
    for key in [k for k, v in change.items() if v is None]:
        del meta[key]
    (path / "meta.json").write_text(json.dumps(meta))
    with pytest.raises(CheckpointError) as error:
        read_meta(str(tmp_path))
    message = str(error.value)
    assert named in message and "meta.json" in message and "\n" not in message


def test_infinite_options_are_strict_json_in_meta(tmp_path):
    """An infinite option (the default rolling friction) is tagged in meta.json, which stays
    strict JSON, and read back as inf."""
    from cosserat_fenicsx import state_codec
    path = fake_checkpoint(tmp_path, tmp_path / "marker", format=FORMAT)
    meta = json.loads((path / "meta.json").read_text())
    meta["options"] = state_codec.encode({"rolling_friction": float("inf"), "mesh": (2, 4)})[0]
    (path / "meta.json").write_text(json.dumps(meta, allow_nan=False))
    options = read_meta(str(tmp_path))["options"]
    assert options["rolling_friction"] == float("inf") and options["mesh"] == (2, 4)


def test_a_restored_run_state_must_have_the_shape_this_run_writes():
    """The run state read back is compared with the one the fresh scene would write: a
    missing or unknown key, a value of another kind, a history row without a column of the
    others are refused naming the file and the key (a deleted 'written' of the demo's own
    state was a KeyError after the restore)."""
    from cosserat_fenicsx.checkpoint import _check_like
    template = {"history": [], "infos": [], "volumetric_phase1": None, "extra": {"written": []}}
    good = {"history": [{"step": 1, "s": 0.5}, {"step": 2, "s": 0.7}], "infos": [1], "volumetric_phase1": -1e-4,
            "extra": {"written": [0.0]}}
    _check_like(good, template, "run.json")
    for bad, named in ((dict(good, extra={}), "missing ['written']"), (dict(good, extra=[]), "['extra']"),
                       (dict(good, history={"a": 1}), "['history']"), (dict(good, more=1), "unknown ['more']"),
                       (dict(good, history=[{"step": 1, "s": 0.5}, {"step": 2}]), "['history'][1]"),
                       (dict(good, extra={"written": 3}), "['written']")):
        with pytest.raises(CheckpointError) as error:
            _check_like(bad, template, "run.json")
        assert named in str(error.value) and "run.json" in str(error.value), str(error.value)
