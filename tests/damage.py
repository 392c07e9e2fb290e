"""Damage the files the project reads and judge how each reader takes them.

Shared by the property tests (tests/test_damaged_inputs.py, a few derandomized draws per
kind) and the sweep (benchmarks/robustness/damaged_inputs.py, hundreds, with the counts).

The kinds of file (`valid_files` makes a good one of each in a work directory):

  parameters      an Ehlers parameter file (JSON; what identify writes, --parameters reads)
  config          an identification config (JSON; demos/identify.py --config)
  bounds          an identification bounds file (JSON; --bounds)
  test_data       a test-data CSV (identify --data)
  packing         a demcell packing (.npz; --packing)
  checkpoint      the checkpoint directory of a biaxial run (--restart)
  checkpoint_dem  the checkpoint directory of a FEM x DEM run (cells in it)

`damage(kind, path, rng)` damages one file (for a checkpoint: one file in it) by a
structure-aware mutation drawn from rng: truncation at a random byte, random bytes, an
empty file, a file of another kind, a deleted or retyped key, a list where an object is
expected, NaN and inf injected into arrays or values, a future format version, a repeated
or missing CSV column, an object (pickled) array in an .npz.  `judge(kind, path)` runs the
kind's reader in this process and says how it ended:

  refused    the project's refusal (InputError/ValueError/CheckpointError/DemCellError) in
             one line that names the file
  accepted   read, and what it read is usable (finite numbers, a parameter set that builds)
  traceback  any other exception, or a refusal that does not name the file or spans lines
  hang       still reading after `timeout` seconds
  executed   a pickled payload ran (a file appeared): never acceptable

Every reader refuses before any work, so this judges what a demo would do with the file
before it starts; tests/test_damaged_inputs.py also runs a few damaged checkpoints through
a restart under mpirun (1 and 2 ranks) to see the earlier outputs stay as they were.
"""
import csv
import io
import json
import os
import shutil
import signal
import subprocess
import sys

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ENV = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
           OMPI_MCA_rmaps_base_oversubscribe="1", OMP_NUM_THREADS="1")
KINDS = ("parameters", "config", "bounds", "test_data", "packing", "checkpoint", "checkpoint_dem")
OUTCOMES = ("refused", "accepted", "traceback", "hang", "executed")
#: the checkpoints' demo runs (the cheapest that write one)
CHECKPOINT_RUNS = {
    "checkpoint": ("biaxial", ["--cell-size", "0.0125", "--steps", "3", "--consolidation-steps", "1",
                               "--axial-strain", "0.002", "--stop-after", "1"]),
    "checkpoint_dem": ("femdem_biaxial", ["--mesh", "1x1", "--particles", "30", "--axial-strain", "0.003",
                                          "--steps", "3", "--stop-after", "1"]),
}
RETYPES = (None, "text", 1.5, -1, 0, [], {}, [1, 2], True, 1e308, "__NaN__", "__Infinity__")


class Payload:
    """A pickle that creates `marker` when unpickled: reading it must never run it."""

    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        return (open, (self.marker, "w"))


# --- good files ---------------------------------------------------------------------------
def valid_files(work):
    """{kind: path} of a good file of every kind, made in `work` (once; reused if there)."""
    os.makedirs(work, exist_ok=True)
    out = {}
    from cosserat_fenicsx.identification.data import from_history, write_test
    from cosserat_fenicsx.identification.virtual_tests import VirtualTest
    from cosserat_fenicsx.materials.ehlers import EhlersMaterial
    from cosserat_fenicsx.materials.ehlers.parameters import EhlersParameters, write_parameter_file
    out["parameters"] = os.path.join(work, "parameters.json")
    write_parameter_file(out["parameters"], EhlersParameters())
    out["test_data"] = os.path.join(work, "triaxial.csv")
    if not os.path.exists(out["test_data"]):
        test = VirtualTest("triaxial", 100e3, axial_strain=0.02, n_steps=20)
        write_test(from_history(test, test.run(EhlersMaterial(micropolar=False)), every=2), out["test_data"])
    out["config"] = os.path.join(work, "config.json")
    with open(out["config"], "w") as f:
        json.dump({"tests": [{"file": "triaxial.csv", "kind": "triaxial", "confining": 100e3,
                              "normalisation": {"axial_stress": 5e5}}],
                   "stages": [["psi1", "psi2"]], "base": {"n0": 0.604}, "start": {"psi1": 1.8},
                   "bounds": {"psi1": [1.0, 3.0]}}, f)
    out["bounds"] = os.path.join(work, "bounds.json")
    with open(out["bounds"], "w") as f:
        json.dump({"psi1": [1.0, 3.0], "psi2": [0.1, 2.0]}, f)
    out["packing"] = os.path.join(work, "packing.npz")
    if not os.path.exists(out["packing"]):
        import demcell as dc
        state, info = dc.generate_packing(30, seed=1)
        dc.save_packing(out["packing"], state, info)
    for kind, (demo, args) in CHECKPOINT_RUNS.items():
        run = os.path.join(work, kind)
        if not os.path.isdir(os.path.join(run, "checkpoint")):
            proc = subprocess.run([sys.executable, os.path.join(ROOT, "demos", demo + ".py"), *args, "--out", run],
                                  capture_output=True, text=True, env=ENV, cwd=ROOT, timeout=600)
            assert proc.returncode == 0, proc.stderr[-2000:]
        out[kind] = run
    return out


# --- damage -------------------------------------------------------------------------------
def _json_paths(node, path=()):
    yield path
    if isinstance(node, dict):
        for k, v in node.items():
            yield from _json_paths(v, path + (k,))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from _json_paths(v, path + (i,))


def _get(node, path):
    for p in path:
        node = node[p]
    return node


def _set(node, path, value):
    if not path:
        return value
    _get(node, path[:-1])[path[-1]] = value
    return node


def _dump_json(doc):
    text = json.dumps(doc)
    return text.replace('"__NaN__"', "NaN").replace('"__Infinity__"', "Infinity")


def _bytes_damage(data, rng, how):
    if how == "truncate":
        return data[:int(rng.integers(0, max(len(data), 1)))]
    if how == "flip":
        b = bytearray(data)
        for _ in range(int(rng.integers(1, 8))):
            if b:
                b[int(rng.integers(len(b)))] = int(rng.integers(256))
        return bytes(b)
    if how == "random":
        return bytes(rng.integers(0, 256, size=int(rng.integers(1, 2000)), dtype=np.uint8))
    return b""


def _json_damage(text, rng, name):
    doc = json.loads(text)
    paths = list(_json_paths(doc))
    how = ["delete", "retype", "retype", "list_top", "nan", "future_format", "deep"][int(rng.integers(7))]
    if how == "delete" and len(paths) > 1:
        path = paths[int(rng.integers(1, len(paths)))]
        parent = _get(doc, path[:-1])
        del parent[path[-1]]
        return _dump_json(doc), f"{name}: deleted {list(path)}"
    if how == "list_top":
        return _dump_json([doc]), f"{name}: a list at the top"
    if how == "nan":
        numbers = [p for p in paths if isinstance(_get(doc, p), (int, float)) and not isinstance(_get(doc, p), bool)]
        if numbers:
            path = numbers[int(rng.integers(len(numbers)))]
            value = ["__NaN__", "__Infinity__", -1e308][int(rng.integers(3))]
            return _dump_json(_set(doc, path, value)), f"{name}: {value} at {list(path)}"
    if how == "future_format" and isinstance(doc, dict) and "format" in doc:
        doc["format"] = doc["format"] + 1
        return _dump_json(doc), f"{name}: format {doc['format']}"
    if how == "deep":
        return "[" * 100000 + "]" * 100000, f"{name}: nested 100000 deep"
    path = paths[int(rng.integers(len(paths)))]
    value = RETYPES[int(rng.integers(len(RETYPES)))]
    return _dump_json(_set(doc, path, value)), f"{name}: {list(path)} = {value!r}"


def _csv_damage(text, rng, name):
    rows = list(csv.reader(io.StringIO(text)))
    header, body = rows[0], rows[1:]
    how = ["drop_column", "repeat_column", "cell", "cell", "ragged", "header_only", "transpose"][int(rng.integers(7))]
    j = int(rng.integers(len(header)))
    if how == "drop_column":
        rows = [r[:j] + r[j + 1:] for r in rows]
        what = f"column {header[j]!r} deleted"
    elif how == "repeat_column":
        rows = [r + [r[j]] for r in rows]
        what = f"column {header[j]!r} repeated"
    elif how == "cell":
        i = int(rng.integers(1, len(rows)))
        value = ["nan", "inf", "-inf", "abc", "", "1e999", "0x10", "1,5"][int(rng.integers(8))]
        rows[i][j] = value
        what = f"row {i} {header[j]!r} = {value!r}"
    elif how == "ragged":
        i = int(rng.integers(1, len(rows)))
        rows[i] = rows[i][:-1]
        what = f"row {i} one value short"
    elif how == "header_only":
        rows = rows[:1]
        what = "no data rows"
    else:
        rows = [list(c) for c in zip(*rows)]
        what = "transposed"
    buf = io.StringIO()
    csv.writer(buf).writerows(rows)
    return buf.getvalue(), f"{name}: {what}"


def _npz_damage(path, rng, name, marker):
    with np.load(path, allow_pickle=False) as z:
        d = {k: z[k] for k in z.files}
    keys = sorted(d)
    how = ["delete", "reshape", "dtype", "nan", "nan", "object", "future_version", "empty_array"][int(rng.integers(8))]
    k = keys[int(rng.integers(len(keys)))]
    floats = [key for key in keys if d[key].dtype.kind == "f" and d[key].size]
    if how == "delete":
        del d[k]
        what = f"{k!r} deleted"
    elif how == "reshape":
        d[k] = d[k].reshape(-1)[: max(d[k].size - 1, 0)] if d[k].size > 1 else np.zeros((3, 3))
        what = f"{k!r} reshaped to {d[k].shape}"
    elif how == "dtype":
        d[k] = d[k].astype(str) if d[k].size else np.array(["x"])
        what = f"{k!r} made text"
    elif how == "nan" and floats:
        k = floats[int(rng.integers(len(floats)))]
        a = d[k].copy()
        a.reshape(-1)[int(rng.integers(a.size))] = [np.nan, np.inf, -np.inf][int(rng.integers(3))]
        d[k] = a
        what = f"non-finite value in {k!r}"
    elif how == "object":
        d[k] = np.array([Payload(marker), 1], dtype=object)
        what = f"{k!r} an object (pickled) array"
    elif how == "future_version" and "demcell_packing_version" in d:
        d["demcell_packing_version"] = np.array(int(d["demcell_packing_version"]) + 1)
        what = "format version + 1"
    else:
        d[k] = np.zeros((0,) + d[k].shape[1:], dtype=d[k].dtype)
        what = f"{k!r} emptied"
    np.savez(path, **d)              # allow_pickle: the object array goes in as a pickle
    return f"{name}: {what}"


def damage(kind, path, rng, foreign=None):
    """Damage the file (or one file of the checkpoint directory) at `path` in place; returns
    a one-line description.  foreign: a path of a file of another kind (copied over)."""
    marker = os.path.join(os.path.dirname(os.path.abspath(path.rstrip("/"))), "EXECUTED")
    if kind.startswith("checkpoint"):
        directory = os.path.join(path, "checkpoint")
        names = sorted(os.listdir(directory))
        target = os.path.join(directory, names[int(rng.integers(len(names)))])
    else:
        target = path
    name = os.path.basename(target)
    generic = ["truncate", "flip", "random", "empty", "foreign"]
    how = generic[int(rng.integers(len(generic)))] if rng.random() < 0.35 else "structure"
    if how == "foreign" and foreign:
        source = foreign if os.path.isfile(foreign) else os.path.join(foreign, "checkpoint", "meta.json")
        shutil.copyfile(source, target)
        return f"{name}: replaced by {os.path.basename(source)}"
    if how in ("truncate", "flip", "random", "empty"):
        with open(target, "rb") as f:
            data = f.read()
        with open(target, "wb") as f:
            f.write(_bytes_damage(data, rng, how))
        return f"{name}: {how}"
    if target.endswith(".npz"):
        return _npz_damage(target, rng, name, marker)
    with open(target) as f:
        text = f.read()
    text, what = (_csv_damage if target.endswith(".csv") else _json_damage)(text, rng, name)
    with open(target, "w") as f:
        f.write(text)
    return what


# --- judging --------------------------------------------------------------------------------
def _read(kind, path):
    """Read as the demo would before it starts; returns nothing or raises."""
    if kind == "parameters":
        from cosserat_fenicsx.materials.ehlers.parameters import EhlersParameters, read_parameter_file
        EhlersParameters(**read_parameter_file(path))
    elif kind in ("config", "bounds"):
        from cosserat_fenicsx.identification.config import check_bounds, check_config, read_json
        from cosserat_fenicsx.identification.data import read_test
        if kind == "bounds":
            check_bounds(read_json(path, "bounds"), f"bounds {path!r}")
            return
        config = check_config(read_json(path, "config"), f"config {path!r}")
        for t in config.get("tests", []):     # the files it names are read too (refusals name them)
            read_test(os.path.join(os.path.dirname(path), t["file"]), t["kind"], t.get("confining"),
                      quantities=t.get("quantities"), normalisation=t.get("normalisation"),
                      scatter=t.get("scatter"), start_pressure=t.get("start_pressure", 0.0),
                      unload_at=t.get("unload_at"))
    elif kind == "test_data":
        from cosserat_fenicsx.identification.data import read_test
        d = read_test(path, "triaxial", 100e3)
        assert all(np.all(np.isfinite(v)) for v in [d.x, *d.y.values()]), "non-finite data accepted"
    elif kind == "packing":
        import demcell as dc
        state, _ = dc.load_packing(path)
        for name, value in vars(state).items() if hasattr(state, "__dict__") else ():
            if isinstance(value, np.ndarray) and value.dtype.kind == "f":
                assert np.all(np.isfinite(value)), f"non-finite {name} accepted"
    else:
        from cosserat_fenicsx.checkpoint import CheckpointError, read_meta, verify
        meta = read_meta(path, CHECKPOINT_RUNS[kind][0])
        verify(path, meta)
        if kind == "checkpoint_dem":      # what the restore asks of the material (check_exported)
            from demcell.state import unpack_states
            for rank in range(meta["ranks"]):
                name = os.path.join(path, "checkpoint", f"resident_{rank}.npz")
                with np.load(name, allow_pickle=False) as z:
                    arrays = {k: z[k] for k in z.files}
                try:
                    for state in unpack_states(arrays):
                        state.check()
                except (ValueError, KeyError, IndexError) as error:
                    raise CheckpointError(f"{name}: {type(error).__name__}: {error}") from None


class _Hang(Exception):
    pass


def _alarm(signum, frame):
    raise _Hang()


def judge(kind, path, timeout=30):
    """dict(outcome, message): how the kind's reader takes the file at `path`."""
    from cosserat_fenicsx.checkpoint import CheckpointError
    from cosserat_fenicsx.validation import InputError
    marker = os.path.join(os.path.dirname(os.path.abspath(path.rstrip("/"))), "EXECUTED")
    previous = signal.signal(signal.SIGALRM, _alarm)
    signal.alarm(timeout)
    try:
        _read(kind, path)
        outcome, message = "accepted", ""
    except _Hang:
        outcome, message = "hang", f"still reading after {timeout} s"
    except (InputError, ValueError, CheckpointError) as error:
        message = str(error)
        named = os.path.basename(path.rstrip("/")) in message or path in message
        outcome = "refused" if named and "\n" not in message and message else "traceback"
        if outcome == "traceback":
            message = f"{type(error).__name__} (not naming the file or not one line): {message}"
    except Exception as error:        # noqa: BLE001 -- anything else is what the sweep counts
        if type(error).__module__.startswith("demcell") and type(error).__name__.endswith("Error"):
            message = str(error)
            named = os.path.basename(path) in message or path in message
            outcome = "refused" if named and "\n" not in message else "traceback"
        else:
            outcome, message = "traceback", f"{type(error).__name__}: {error}"[:300]
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
    if os.path.exists(marker):
        outcome, message = "executed", "a pickled payload ran while reading"
        os.remove(marker)
    return dict(outcome=outcome, message=" ".join(message.split())[:300])


def damaged_copy(kind, good, work, rng, foreign_of=None):
    """A damaged copy of the good file of `kind` in `work`; returns (path, description)."""
    os.makedirs(work, exist_ok=True)
    if kind.startswith("checkpoint"):
        target = os.path.join(work, kind)
        shutil.rmtree(target, ignore_errors=True)
        shutil.copytree(good, target)
    else:
        target = os.path.join(work, os.path.basename(good))
        shutil.copyfile(good, target)
        if kind == "config":       # the test file it names, beside it
            shutil.copyfile(os.path.join(os.path.dirname(good), "triaxial.csv"), os.path.join(work, "triaxial.csv"))
    foreign = None
    if foreign_of:
        others = [k for k in foreign_of if k != kind]
        foreign = foreign_of[others[int(rng.integers(len(others)))]]
    return target, damage(kind, target, rng, foreign)
