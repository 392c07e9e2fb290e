"""Checkpoint and restart of a load-stepped run, as batch queues need (docs/reference/restart.md).

After a converged step (every `every` steps, and at `stop_after`) a run writes DIR/checkpoint/:

    meta.json         format, label, step, pseudo-time, next increment, cut-backs, ranks,
                      dolfinx version, the run's options
    fields.npz        the FE solution per component (u1, u2, phi) at its dof coordinates
    points.npz        the committed Gauss-point arrays (QuadratureMap.committed_arrays) and the
                      scene's own per-point arrays, at the Gauss-point coordinates
    resident_R.npz    the material's resident state of rank R's points
                      (Constitutive.export_points: every DEM cell) with their coordinates
    run.json          the scene's history rows, Newton records and other run state, as strict
                      JSON (state_codec: data only, never code)
    run_arrays.npz    the numpy arrays in that run state (only when it holds any)

Everything is keyed by coordinates, not by the partition, so a checkpoint written on n ranks
restarts on m: each rank finds its dofs and Gauss points by nearest coordinates within a
tolerance of 1e-8 of the specimen's size (a point without a match stops the restart with a
message). The directory is written as checkpoint.tmp and renamed when complete, so a run
killed while writing keeps its previous checkpoint. On the same number of ranks the continued
run repeats the uninterrupted one bit for bit (same partition, same arrays, same order of
operations); on another number of ranks it differs by what the partition changes anyway
(the order of the assembly sums).

Nothing in a checkpoint is code: every file is JSON or an array file read without pickle, so
a checkpoint received from someone else cannot run anything when read. Format 1 kept the run
state as a pickle (run.pkl) and is refused rather than read.

A scene that checkpoints provides `problem` (a CosseratProblem with a Gauss-point material:
its `gauss_points` store holds the per-point arrays and their coordinates),
`checkpoint_state()` -> (per-point arrays, run-state dict) and
`restore_state(per_point, run_state)`.
"""
import json
import os
import shutil
import time
import zipfile

import numpy as np

from . import state_codec
from .stepping import StepperPosition

FORMAT = 2
DIRECTORY = "checkpoint"
#: a saved dof or point matches a current one within this fraction of the mesh's extent
MATCH_TOLERANCE = 1e-8
RUN_STATE = "run.json"
RUN_ARRAYS = "run_arrays.npz"


class CheckpointError(RuntimeError):
    """A checkpoint cannot be read or does not fit the run; the message says why."""


def checkpoint_path(directory):
    return os.path.join(directory, DIRECTORY)


def read_meta(directory, label=None):
    """meta.json of the checkpoint in `directory` (a run's output directory); with `label`,
    one written by another demo is refused."""
    path = os.path.join(checkpoint_path(directory), "meta.json")
    if not os.path.isfile(path):
        raise CheckpointError(f"no checkpoint in {directory} ({path} is missing): a run writes one with "
                              "--checkpoint-every N or --stop-after K")
    try:
        with open(path) as f:
            meta = json.load(f)
    except (OSError, ValueError, RecursionError) as error:   # RecursionError: nested too deeply
        raise CheckpointError(f"cannot read {path}: {error}") from None
    if not isinstance(meta, dict):
        raise CheckpointError(f"cannot read {path}: a JSON {type(meta).__name__}, not an object")
    if meta.get("format") == 1:      # its run state is a pickle: reading it could run any code
        raise CheckpointError(f"{path}: checkpoint format 1 (run state pickled in run.pkl) cannot be read safely: "
                              f"unpickling can run code; this version reads format {FORMAT} only")
    if meta.get("format") != FORMAT:
        raise CheckpointError(f"{path}: checkpoint format {meta.get('format')!r}, this version reads {FORMAT}")
    for key, kind, ok in _META_FIELDS:
        value = meta.get(key)
        if not isinstance(value, kind) or isinstance(value, bool) or not ok(value):
            raise CheckpointError(f"{path}: {key!r} is {'missing' if key not in meta else repr(value)[:60]}, "
                                  "not what a checkpoint writes")
    if label is not None and meta.get("label") != label:
        raise CheckpointError(f"the checkpoint in {directory} is of {meta.get('label')!r}, not {label!r}")
    try:     # strict JSON on disk: an infinite option (e.g. rolling friction) is tagged there
        meta["options"] = state_codec.decode(meta["options"], {})
    except state_codec.StateCodecError as error:
        raise CheckpointError(f"{path}: options: {error}") from None
    if not isinstance(meta["options"], dict):
        raise CheckpointError(f"{path}: 'options' is not an object of option values")
    return meta


#: meta.json's fields: name, type, check
_META_FIELDS = (("label", str, lambda v: True),
                ("step", int, lambda v: v >= 0),
                ("time", (int, float), lambda v: np.isfinite(v)),
                ("dt", (int, float), lambda v: np.isfinite(v) and v > 0),
                ("cuts", int, lambda v: v >= 0),
                ("ranks", int, lambda v: v >= 1),
                ("n_points", int, lambda v: v >= 0),
                ("options", (dict, list), lambda v: True))


def stepper_keywords(checkpoint):
    """LoadStepper keywords of a Checkpointer (none without one): write as due, stop at its
    stop_after, continue from the position it restored."""
    if checkpoint is None:
        return {}
    return {"after_step": checkpoint.after_step if checkpoint.enabled else None,
            "start": checkpoint.resumed, "stop_after": checkpoint.stop_after}


class Checkpointer:
    """Writes the checkpoints of one run and restores a run from one.

    comm        the run's communicator
    directory   the run's output directory (the checkpoint goes to directory/checkpoint)
    label       the demo's name (a checkpoint of another demo is refused)
    options     the run's options (saved; a restart runs with them)
    every       write after every `every`-th converged step (None: only at stop_after)
    stop_after  the run stops after this step (a checkpoint is written there)
    changes     the solver options a restart changed: name -> [saved, new] (reported)
    """

    def __init__(self, comm, directory, label, options, every=None, stop_after=None, restart=False,
                 changes=None):
        self.comm, self.directory, self.label = comm, directory, label
        self.options = dict(options)
        self.changes = dict(changes or {})
        self.every, self.stop_after = every, stop_after
        self.restart = restart
        self.saved_ranks = None
        self.saved_fields = None     # the XDMF series the checkpointed run was writing
        self.fields_file = None      # the one this run writes (fields_path)
        self.scene = None
        self.extra = None
        self.resumed = None          # StepperPosition of the checkpoint a restart continued from
        self.written = []            # steps written by this run
        self.write_seconds = []      # wall time of each write
        self.size_bytes = None       # size of the last checkpoint (rank 0)

    @property
    def enabled(self):
        return self.every is not None or self.stop_after is not None

    def attach(self, scene, extra=None):
        """The scene to save; `extra()` -> a dict of the demo's own run state (e.g. what its
        plot collects; data that state_codec stores), handed back by restore as
        `self.restored_extra`."""
        self.scene, self.extra = scene, extra

    # --- what a demo asks --------------------------------------------------------------------
    def start(self, scene, guard=None, extra=None):
        """Attach the scene and, for a restart, restore it (a failure refuses the restart
        through `guard`, a run_guard.RunGuard: one line, exit 2, the earlier outputs as they
        were -- the guard of a restart is made with write_now=False). Returns the StepperPosition the
        run continues from, None for a fresh run."""
        if not self.restart:
            self.attach(scene, extra)
            return None
        try:
            position = self.restore(scene, extra)
        except CheckpointError as error:
            if guard is None:
                raise
            guard.refuse(f"restart: {error}")
        if guard is not None:
            guard.steps = position.step
        if self.comm.rank == 0:
            print(f"{self.label}: continuing from the checkpoint of step {position.step} (t = {position.time:.6g}) "
                  f"written on {self.saved_ranks} rank(s)", flush=True)
            for name, (old, new) in self.changes.items():
                print(f"{self.label}: --{name.replace('_', '-')} {old} -> {new} from this step on (the continued "
                      "history is no longer the uninterrupted run's)", flush=True)
        return position

    @property
    def resume_time(self):
        """Pseudo-time of the checkpoint a restart continued from (None: a fresh run)."""
        return self.resumed.time if self.resumed else None

    @property
    def resume_step(self):
        return self.resumed.step if self.resumed else None

    def fields_path(self, name):
        """Where the XDMF series goes: `name` in the output directory, continued by a
        restart on the same number of ranks; a restart on another number starts a new
        series `<name>_from_step<K>.xdmf` (the XDMF mesh holds the nodes in the order of the
        partition that wrote it, so the old file cannot take the new partition's data)."""
        if self.resumed is not None and self.saved_ranks == self.comm.size and self.saved_fields:
            name = self.saved_fields                 # the series the checkpointed run wrote
        elif self.resumed is not None:
            stem, ext = os.path.splitext(name)
            name = f"{stem}_from_step{self.resumed.step}{ext}"
        self.fields_file = name
        return os.path.join(self.directory, name)

    def stop_note(self, stepper):
        """'' or the reason a run stopped at --stop-after (with how to continue)."""
        if not stepper.stopped_early:
            return ""
        note = (f"stopped after step {self.stop_after} as asked (--stop-after); the checkpoint is in "
                f"{checkpoint_path(self.directory)}; continue with --restart {self.directory}")
        if self.comm.rank == 0:
            print(f"{self.label}: {note}", flush=True)
        return note

    def summary_entries(self):
        """What summary.json says about checkpoints and restarts."""
        return {"checkpoint_steps_written": list(self.written),
                "checkpoint_write_seconds": list(self.write_seconds),
                "checkpoint_bytes": self.comm.bcast(self.size_bytes, root=0),
                "restarted_from_step": self.resumed.step if self.resumed else None,
                "restarted_from_ranks": self.saved_ranks if self.resumed else None,
                "changed_at_restart": dict(self.changes),
                "stopped_after_step": self.stop_after}

    # --- writing -----------------------------------------------------------------------------
    def after_step(self, position):
        """LoadStepper.after_step: write when this step is due."""
        due = (self.every is not None and position.step % self.every == 0) or \
              (self.stop_after is not None and position.step >= self.stop_after)
        if due:
            self.write(position)

    def write(self, position):
        """Write the checkpoint of the current (committed) state. Collective; a failure to
        write (disk full, permissions) raises CheckpointError on every rank."""
        start = time.perf_counter()
        comm, scene = self.comm, self.scene
        problem = scene.problem
        cb = problem.gauss_points
        final = checkpoint_path(self.directory)
        tmp = final + ".tmp"
        per_point, run_state = scene.checkpoint_state()
        if self.extra is not None:
            run_state = dict(run_state, extra=self.extra())
        arrays = dict(cb.committed_arrays(), **{"scene_" + k: v for k, v in per_point.items()})
        points = np.asarray(cb.coordinates, dtype=np.float64)
        resident = problem.material.export_points(np.arange(cb.n_points))
        fields = _gather_fields(comm, problem)
        gathered = comm.gather((points, arrays), root=0)
        error, encoded = _open_directory(comm, tmp, run_state)
        if not error:
            try:     # the resident state stays per rank (the big part: a DEM cell per point)
                np.savez(os.path.join(tmp, f"resident_{comm.rank}.npz"), coordinates=points, **resident)
                if comm.rank == 0:
                    self._write_rank0(tmp, position, fields, gathered, encoded)
            except (OSError, ValueError) as e:
                error = f"cannot write the checkpoint in {tmp}: {e}"
        errors = [e for e in comm.allgather(error) if e]
        if errors:
            raise CheckpointError(errors[0])
        if comm.rank == 0:
            shutil.rmtree(final, ignore_errors=True)
            os.replace(tmp, final)
        comm.barrier()
        self.written.append(position.step)
        self.write_seconds.append(time.perf_counter() - start)
        if comm.rank == 0:
            self.size_bytes = sum(os.path.getsize(os.path.join(final, f)) for f in os.listdir(final))

    def _write_rank0(self, tmp, position, fields, gathered, encoded):
        import dolfinx
        np.savez(os.path.join(tmp, "fields.npz"), **fields)
        pts = np.concatenate([g[0] for g in gathered])
        np.savez(os.path.join(tmp, "points.npz"), coordinates=pts,
                 **{k: np.concatenate([g[1][k] for g in gathered]) for k in gathered[0][1]})
        write_encoded_run_state(tmp, encoded)
        meta = {"format": FORMAT, "label": self.label, "step": position.step, "time": position.time,
                "dt": position.dt, "cuts": position.cuts, "ranks": self.comm.size, "n_points": len(pts),
                "dolfinx": dolfinx.__version__, "fields_file": self.fields_file,
                "options": state_codec.encode(self.options)[0]}
        with open(os.path.join(tmp, "meta.json"), "w") as f:     # last: a complete directory has it
            json.dump(meta, f, indent=1, allow_nan=False)

    # --- reading -----------------------------------------------------------------------------
    def restore(self, scene, extra=None):
        """Bring `scene` (built with the checkpoint's options) to the checkpoint's state;
        returns the StepperPosition to continue from. Collective."""
        self.attach(scene, extra)
        meta = read_meta(self.directory, self.label)
        path = checkpoint_path(self.directory)
        problem = scene.problem
        cb = problem.gauss_points
        mine = np.asarray(cb.coordinates, dtype=np.float64)
        n_points = self.comm.allreduce(len(mine))
        if n_points != meta["n_points"]:
            raise CheckpointError(f"the checkpoint holds {meta['n_points']} Gauss points, this run has {n_points}: "
                                  "not the same mesh or quadrature")
        scale = _extent(self.comm, mine)
        # read and match everything first, then make a failure collective, then apply: a rank
        # that raised alone would leave the others in a collective call (import_points may be one)
        error, plan = "", None
        try:
            plan = self._read(path, meta, problem, mine, scale)
            _check_like(plan[3], self._run_state(scene), os.path.join(path, RUN_STATE))
        except CheckpointError as e:
            error = str(e)
        except (OSError, KeyError, ValueError, TypeError, AttributeError, EOFError, zipfile.BadZipFile) as e:
            error = f"cannot restore from {path}: {type(e).__name__}: {e}"
        errors = [e for e in self.comm.allgather(error) if e]
        if errors:
            raise CheckpointError(errors[0])
        fields, resident, arrays, run_state = plan
        for dofs, values in fields:
            problem.w.x.array[dofs] = values
        problem.w.x.scatter_forward()
        problem.w_committed.x.array[:] = problem.w.x.array
        for rows, points, saved in resident:      # before restore_committed, which rolls back to it
            problem.material.import_points(points, saved, rows)
        cb.restore_committed(arrays)
        self.restored_extra = run_state.pop("extra", None)
        scene.restore_state({k[len("scene_"):]: v for k, v in arrays.items() if k.startswith("scene_")}, run_state)
        self.saved_ranks = meta["ranks"]
        self.saved_fields = meta.get("fields_file")
        self.resumed = StepperPosition(meta["time"], meta["dt"], meta["step"], meta["cuts"])
        return self.resumed

    def _run_state(self, scene):
        """The run state this run would write now (the shape a restored one must have)."""
        state = dict(scene.checkpoint_state()[1])
        if self.extra is not None:
            state["extra"] = self.extra()
        return state

    def _read(self, path, meta, problem, mine, scale):
        """Everything this rank needs from the checkpoint, matched to its dofs and points
        (local: no MPI). Returns (fields, resident, per-point arrays, run state)."""
        with np.load(os.path.join(path, "fields.npz"), allow_pickle=False) as z:
            saved = dict(z)
        fields = []
        for c in _components(problem):
            if f"{c}_values" not in saved:
                raise CheckpointError(f"the checkpoint has no {c} field (micropolar and Cauchy scenes do not mix)")
            x, dofs = _owned_component_dofs(problem, c)
            rows = _nearest_rows(saved[f"{c}_coordinates"], x, scale, what=f"{c} dof")
            fields.append((dofs, saved[f"{c}_values"][rows]))
        found = np.zeros(len(mine), dtype=np.int64)
        resident = []
        for rank in range(meta["ranks"]):      # every rank reads every file: any partition fits
            with np.load(os.path.join(path, f"resident_{rank}.npz"), allow_pickle=False) as z:
                saved = dict(z)
            rows, points = _saved_among(saved.pop("coordinates"), mine, scale)
            try:
                problem.material.check_exported(saved, rows)
            except ValueError as error:
                raise CheckpointError(f"{os.path.join(path, f'resident_{rank}.npz')}: {error}") from None
            resident.append((rows, points, saved))
            np.add.at(found, points, 1)
        if (found != 1).any():
            raise CheckpointError(f"{int(np.count_nonzero(found != 1))} Gauss point(s) have no (or two) saved "
                                  "material states")
        with np.load(os.path.join(path, "points.npz"), allow_pickle=False) as z:
            saved = dict(z)
        rows = _nearest_rows(saved.pop("coordinates"), mine, scale)
        arrays = {k: v[rows] for k, v in saved.items()}
        run_state = read_run_state(path)
        return fields, resident, arrays, run_state


def _open_directory(comm, tmp, run_state):
    """(error, encoded run state on rank 0) after rank 0 encoded the run state and made the
    empty directory `tmp` (collective: the error, '' when none, is every rank's). Encoded
    first: a run state that cannot be stored leaves no directory."""
    error, encoded = "", None
    if comm.rank == 0:
        try:
            encoded = encode_run_state(run_state)
            shutil.rmtree(tmp, ignore_errors=True)
            os.makedirs(tmp)
        except CheckpointError as e:
            error = str(e)
        except OSError as e:
            error = f"cannot write the checkpoint in {tmp}: {e}"
    return comm.bcast(error, root=0), encoded


# --- the run state: strict JSON and arrays, data only (state_codec) --------------------------
def _run_state_types():
    """The records a run state may hold besides plain data (the Newton solver's SolveInfo)."""
    from .snes import SolveInfo
    return (SolveInfo,)


def encode_run_state(run_state):
    """(JSON document, arrays) of a run state; CheckpointError naming the key of a value that
    cannot be stored (a checkpoint holds data only)."""
    if type(run_state) is not dict:
        raise CheckpointError(f"cannot write the checkpoint: the run state is a {type(run_state).__name__}, not a dict")
    try:
        return state_codec.encode(run_state, _run_state_types())
    except state_codec.StateCodecError as error:
        raise CheckpointError(f"cannot write the checkpoint: {error}") from None


def write_encoded_run_state(path, encoded):
    """run.json (and run_arrays.npz when there are arrays) in the checkpoint directory `path`."""
    document, arrays = encoded
    with open(os.path.join(path, RUN_STATE), "w") as f:
        json.dump(document, f, allow_nan=False)
    if arrays:
        np.savez(os.path.join(path, RUN_ARRAYS), **arrays)


def write_run_state(path, run_state):
    """Write `run_state` (a dict) to the checkpoint directory `path`."""
    write_encoded_run_state(path, encode_run_state(run_state))


def _refuse_constant(name):
    raise ValueError(f"{name} is not strict JSON")


def read_run_state(path):
    """The run state in the checkpoint directory `path` (run.json and run_arrays.npz); a file
    that is missing, damaged or holds anything the writer does not write is a
    CheckpointError naming it. Nothing read here can run code."""
    name = os.path.join(path, RUN_STATE)
    try:
        with open(name) as f:
            document = json.load(f, parse_constant=_refuse_constant)
    except (OSError, ValueError, RecursionError) as error:       # json.JSONDecodeError and UnicodeDecodeError are ValueErrors
        raise CheckpointError(f"cannot read {name}: {error}") from None
    if type(document) is not dict:
        raise CheckpointError(f"cannot read {name}: a JSON {type(document).__name__}, not an object")
    arrays = {}
    arrays_name = os.path.join(path, RUN_ARRAYS)
    if os.path.exists(arrays_name):
        try:
            with np.load(arrays_name, allow_pickle=False) as z:
                arrays = dict(z)
        except (OSError, ValueError, EOFError, zipfile.BadZipFile) as error:   # an object array is refused here, unread
            raise CheckpointError(f"cannot read {arrays_name}: {error}") from None
    try:
        state = state_codec.decode(document, arrays, _run_state_types(),
                                   arrays_name=RUN_ARRAYS if os.path.exists(arrays_name) else f"{RUN_ARRAYS} (missing)")
    except (state_codec.StateCodecError, TypeError, AttributeError, RecursionError) as error:
        raise CheckpointError(f"cannot read {name}: {error}") from None
    if type(state) is not dict:
        raise CheckpointError(f"cannot read {name}: it holds a {type(state).__name__}, not the run state's dict")
    return state


def _check_like(saved, template, name, where=""):
    """The restored run state has the keys and kinds of values that this run writes
    (`template`, its state now): a dict the same keys, a list a list (its dict rows all with
    the keys of the first), a number a number; None matches anything (a value not set yet).
    CheckpointError naming the file and the key."""
    if template is None or saved is None:
        return
    kinds = ((dict,), (list, tuple), (int, float, np.number), (str,), (np.ndarray,))
    kind = next((k for k in kinds if isinstance(template, k) and not isinstance(template, bool)), None)
    if isinstance(template, bool):
        kind = (bool, np.bool_)
    if kind is not None and not isinstance(saved, kind):
        raise CheckpointError(f"{name}: {where or 'the run state'} is a {type(saved).__name__}, "
                              f"not a {type(template).__name__}")
    if isinstance(template, dict):
        if set(saved) != set(template):
            missing, extra = sorted(map(str, set(template) - set(saved))), sorted(map(str, set(saved) - set(template)))
            raise CheckpointError(f"{name}: {where or 'the run state'}: " +
                                  (f"missing {missing}" if missing else f"unknown {extra}"))
        for key in template:
            _check_like(saved[key], template[key], name, f"{where}[{key!r}]")
    elif isinstance(template, (list, tuple)) and saved and isinstance(saved[0], dict):
        for i, row in enumerate(saved):
            _check_like(row, saved[0], name, f"{where}[{i}]")


def _load_arrays(name):
    """{key: array} of one .npz of the checkpoint, read without pickle; CheckpointError naming it."""
    try:
        with np.load(name, allow_pickle=False) as z:
            return dict(z)
    except Exception as error:   # noqa: BLE001 -- whatever the zip, zlib and npy layers raise on a damaged file
        raise CheckpointError(f"cannot read {name}: {type(error).__name__}: {' '.join(str(error).split())}") from None


def _check_table(name, arrays, n_rows=None, per_point=True, finite=True):
    """A table keyed by coordinates: 'coordinates' (n, 2) finite, every other array with n
    rows (per_point; a material's resident arrays may be flattened over its points) and no
    NaN (an infinite entry may be a material's own, e.g. a frictionless bound)."""
    coordinates = arrays.get("coordinates")
    if coordinates is None or coordinates.ndim != 2 or coordinates.shape[1] != 2 or \
            not np.issubdtype(coordinates.dtype, np.floating) or not np.all(np.isfinite(coordinates)):
        raise CheckpointError(f"{name}: 'coordinates' must be finite (n, 2) floats")
    n = len(coordinates)
    if n_rows is not None and n != n_rows:
        raise CheckpointError(f"{name}: {n} rows, meta.json says {n_rows}")
    for key, value in arrays.items():
        if per_point and (value.ndim == 0 or len(value) != n):
            raise CheckpointError(f"{name}: {key!r} has shape {value.shape}, not {n} rows")
        if finite and np.issubdtype(value.dtype, np.number) and not np.issubdtype(value.dtype, np.integer) and \
                np.isnan(value).any():
            raise CheckpointError(f"{name}: {key!r} holds NaN: a damaged checkpoint")
    return n


def verify(directory, meta):
    """Every file of the checkpoint in `directory` read and checked (present, readable
    without pickle, the shapes meta.json announces, no NaN, the run state decodable) before
    a restart touches anything; CheckpointError naming the file and the field."""
    path = checkpoint_path(directory)
    if meta.get("layout") == STATE_LAYOUT:
        _verify_state(path, meta)
        return
    fields = _load_arrays(os.path.join(path, "fields.npz"))
    components = sorted({k.rsplit("_", 1)[0] for k in fields})
    if not components:
        raise CheckpointError(f"{os.path.join(path, 'fields.npz')}: no field")
    for c in components:
        table = {"coordinates": fields.get(f"{c}_coordinates"), "values": fields.get(f"{c}_values")}
        if any(v is None for v in table.values()):
            raise CheckpointError(f"{os.path.join(path, 'fields.npz')}: {c!r} needs {c}_coordinates and {c}_values")
        _check_table(os.path.join(path, "fields.npz") + f" ({c})", table)
    _check_table(os.path.join(path, "points.npz"), _load_arrays(os.path.join(path, "points.npz")), meta["n_points"])
    # the resident arrays' meaning is the material's (e.g. the unused pair slots of a DEM cell
    # hold anything): checked by Constitutive.check_exported when the restore reads them
    total = sum(_check_table(os.path.join(path, f"resident_{rank}.npz"),
                             _load_arrays(os.path.join(path, f"resident_{rank}.npz")), per_point=False,
                             finite=False)
                for rank in range(meta["ranks"]))
    if total != meta["n_points"]:
        raise CheckpointError(f"{path}: the resident files hold {total} points, meta.json says {meta['n_points']}")
    read_run_state(path)


# --- FE fields by dof coordinates ----------------------------------------------------------
def _components(problem):
    return ("u1", "u2", "phi") if problem.micropolar else ("u1", "u2")


def _owned_component_dofs(problem, component):
    """(coordinates (n, 2), dofs of w) of the owned dofs of one component."""
    space, parent = problem.component_space(component)
    n_owned = space.dofmap.index_map.size_local
    x = space.tabulate_dof_coordinates()[:n_owned, :2]
    return x, np.asarray(parent)[:n_owned]


def _gather_fields(comm, problem):
    out = {}
    for c in _components(problem):
        x, dofs = _owned_component_dofs(problem, c)
        parts = comm.gather((x, problem.w_committed.x.array[dofs]), root=0)
        if comm.rank == 0:
            out[f"{c}_coordinates"] = np.concatenate([p[0] for p in parts])
            out[f"{c}_values"] = np.concatenate([p[1] for p in parts])
    return out


# --- matching by coordinates ----------------------------------------------------------------
def _extent(comm, points):
    """Largest side of the bounding box of all ranks' points (the matching tolerance's scale)."""
    from mpi4py import MPI
    lo = np.full(2, np.inf) if not len(points) else points.min(axis=0)
    hi = np.full(2, -np.inf) if not len(points) else points.max(axis=0)
    lo, hi = lo.copy(), hi.copy()
    comm.Allreduce(MPI.IN_PLACE, lo, op=MPI.MIN)
    comm.Allreduce(MPI.IN_PLACE, hi, op=MPI.MAX)
    return float(np.max(hi - lo)) or 1.0


def _nearest_rows(saved, wanted, scale, what="Gauss point"):
    """Row of `saved` (k, 2) at each of `wanted` (n, 2), within the tolerance; every wanted
    point must be there (CheckpointError naming the first that is not)."""
    from scipy.spatial import cKDTree
    if not len(wanted):
        return np.zeros(0, dtype=np.int64)
    if not len(saved):
        raise CheckpointError(f"the checkpoint has no {what}s")
    dist, rows = cKDTree(saved).query(wanted)
    bad = np.flatnonzero(dist > MATCH_TOLERANCE * scale)
    if bad.size:
        x, y = wanted[bad[0]]
        raise CheckpointError(f"no saved {what} at ({x:.6g}, {y:.6g}) (and {bad.size - 1} more): not the same mesh")
    return rows


def _saved_among(saved, wanted, scale):
    """(rows of `saved`, indices of `wanted`) of the saved points that are among `wanted`
    within the tolerance (one rank's file of a checkpoint against this rank's points)."""
    from scipy.spatial import cKDTree
    if not len(saved) or not len(wanted):
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    dist, points = cKDTree(wanted).query(saved)
    rows = np.flatnonzero(dist <= MATCH_TOLERANCE * scale)
    return rows, points[rows]


# --- explicit runs: the state as per-rank arrays (StateCheckpointer) ------------------------
#: meta.json's "layout" of a StateCheckpointer's checkpoint (a Checkpointer's has none)
STATE_LAYOUT = "per-rank state"


def _state_file(path, rank):
    return os.path.join(path, f"state_{rank}.npz")


def _verify_state(path, meta):
    """A StateCheckpointer's files: state_R.npz of every rank readable without pickle, no NaN
    in a float array, the run state decodable."""
    for rank in range(meta["ranks"]):
        name = _state_file(path, rank)
        for key, value in _load_arrays(name).items():
            if np.issubdtype(value.dtype, np.floating) and np.isnan(value).any():
                raise CheckpointError(f"{name}: {key!r} holds NaN: a damaged checkpoint")
    read_run_state(path)


class StateCheckpointer:
    """Checkpoints of a run whose whole state is a dict of arrays per rank and a run-state
    dict (an explicit time loop: the bridging-scale footing, BridgingCoupler.state), in the
    directory layout and with the refusals of Checkpointer: DIR/checkpoint/ holds meta.json
    (its "layout" STATE_LAYOUT), state_R.npz of every rank R and run.json / run_arrays.npz,
    written as checkpoint.tmp and renamed when complete. The arrays are per rank as the
    caller gives them; a restart reads every rank's file and matches what it owns (the
    caller keys its arrays: BridgingCoupler.state by dof coordinates).

    comm, directory, label, options, every, stop_after, restart: as Checkpointer's (steps)."""

    def __init__(self, comm, directory, label, options, every=None, stop_after=None, restart=False):
        self.comm, self.directory, self.label = comm, directory, label
        self.options = dict(options)
        self.every, self.stop_after, self.restart = every, stop_after, restart
        self.resumed_step = None     # the step a restart continued from
        self.saved_ranks = None
        self.written, self.write_seconds = [], []
        self.size_bytes = None

    @property
    def enabled(self):
        return self.every is not None or self.stop_after is not None

    def due(self, step):
        """Whether a checkpoint is written after `step` (every `every`, and at stop_after)."""
        return (self.every is not None and step % self.every == 0) or \
               (self.stop_after is not None and step >= self.stop_after)

    def stops(self, step):
        """Whether the run stops after `step` (--stop-after)."""
        return self.stop_after is not None and step >= self.stop_after

    def write(self, step, time_, dt, arrays, run_state):
        """Write the checkpoint of step `step` at time `time_` [s] (coarse step dt [s]):
        `arrays` this rank's {name: array}, `run_state` (rank 0's is written) data that
        state_codec stores. Collective; a failure raises CheckpointError on every rank."""
        start = time.perf_counter()
        comm = self.comm
        final = checkpoint_path(self.directory)
        tmp = final + ".tmp"
        error, encoded = _open_directory(comm, tmp, run_state)
        if not error:
            try:
                np.savez(_state_file(tmp, comm.rank), **arrays)
            except (OSError, ValueError) as e:
                error = f"cannot write the checkpoint in {tmp}: {e}"
        errors = [e for e in comm.allgather(error) if e]
        if not errors and comm.rank == 0:
            try:
                import dolfinx
                write_encoded_run_state(tmp, encoded)
                meta = {"format": FORMAT, "layout": STATE_LAYOUT, "label": self.label, "step": int(step),
                        "time": float(time_), "dt": float(dt), "cuts": 0, "ranks": comm.size, "n_points": 0,
                        "dolfinx": dolfinx.__version__, "options": state_codec.encode(self.options)[0]}
                with open(os.path.join(tmp, "meta.json"), "w") as f:     # last: a complete directory has it
                    json.dump(meta, f, indent=1, allow_nan=False)
                shutil.rmtree(final, ignore_errors=True)
                os.replace(tmp, final)
                self.size_bytes = sum(os.path.getsize(os.path.join(final, f)) for f in os.listdir(final))
            except (OSError, ValueError) as e:
                errors = [f"cannot write the checkpoint in {tmp}: {e}"]
        errors = [e for e in comm.allgather(errors[0] if errors else "") if e]
        if errors:
            raise CheckpointError(errors[0])
        self.written.append(int(step))
        self.write_seconds.append(time.perf_counter() - start)

    def read(self):
        """(meta, [the arrays of every saved rank, in rank order], run state) of the checkpoint
        in the directory: every rank reads every rank's file, so the caller can match what it
        owns now (BridgingCoupler.set_state matches the continuum by dof coordinates: any
        number of ranks). Collective: a checkpoint of another demo or layout, or a damaged
        file, is a CheckpointError on every rank."""
        error, out = "", None
        try:
            meta = read_meta(self.directory, self.label)
            if meta.get("layout") != STATE_LAYOUT:
                raise CheckpointError(f"the checkpoint in {self.directory} is not a per-rank state checkpoint")
            path = checkpoint_path(self.directory)
            out = (meta, [_load_arrays(_state_file(path, r)) for r in range(meta["ranks"])], read_run_state(path))
        except CheckpointError as e:
            error = str(e)
        errors = [e for e in self.comm.allgather(error) if e]
        if errors:
            raise CheckpointError(errors[0])
        self.resumed_step, self.saved_ranks = out[0]["step"], out[0]["ranks"]
        return out

    def stop_note(self):
        """The reason of a stop at --stop-after, with how to continue."""
        return (f"stopped after step {self.stop_after} as asked (--stop-after); the checkpoint is in "
                f"{checkpoint_path(self.directory)}; continue with --restart {self.directory}")

    def summary_entries(self):
        return {"checkpoint_steps_written": list(self.written),
                "checkpoint_write_seconds": list(self.write_seconds),
                "checkpoint_bytes": self.comm.bcast(self.size_bytes, root=0),
                "restarted_from_step": self.resumed_step, "restarted_from_ranks": self.saved_ranks,
                "stopped_after_step": self.stop_after}
