"""The run of a scene demo: what every stepped demo does around its physics.

A demo parses its options (cli.parse), builds its scene and then hands the run to a
`DemoRun`, which keeps

* summary.json current and the signals handled (run_guard.RunGuard; a --restart writes it
  at its first step, so a refused restart leaves the earlier summary),
* the checkpoints of --checkpoint-every, --stop-after and --restart (cli.checkpointer),
* fields.xdmf (every --write-every steps and the last converged state) and the CSV logs,
  continued by a restart after the checkpoint's step,
* the entries every summary has (completed, stopped, reason, the checkpoint's, wall_time)
  and the exit status: 0 when the run reached its end or --stop-after, 1 when a step could
  not be cut small enough (what was computed until then is kept and summarised).

The scene is any object with `problem`, `history` (a list of row dicts with step and time),
`stepper` (the LoadStepper of its last run) and `run(on_step, checkpoint)`, as
scenes.platen_test.PlatenTest; the demo supplies its rows' columns, its summary and its figures.
"""
import os
import sys
import time

from . import cli
from .output import CsvLog, FieldWriter, print0
from .run_guard import RunGuard
from .stepping import LoadSteppingError


class DemoRun:
    """One run of a scene demo from its parsed options `args` (out, fields, the checkpoint
    options); `label` names it in messages and checkpoints, `entries` are what summary.json
    says before the first step."""

    def __init__(self, comm, args, label, entries=None):
        self.comm, self.args, self.label = comm, args, label
        self.guard = RunGuard(comm, os.path.join(args.out, "summary.json"), entries, label=label,
                              write_now=args.restart is None)
        self.scene = self.checkpoint = self.writer = None
        self.logs = []
        self.written = []          # pseudo-times written to fields.xdmf (a restart continues the list)
        self.kept = {}
        self.stopped = ""
        self.wall_time = 0.0

    def build(self, make, what, errors=(RuntimeError,)):
        """The scene make() returns; one of `errors` raised while building it stops the run
        with `what` and the error as the reason (exit status 1)."""
        try:
            return make()
        except errors as error:
            self.guard.stop(f"{what}: {error}")

    def start(self, scene, kept=None):
        """Checkpoints of `scene` (a --restart restores it here). `kept` ({name: list}): what
        the demo accumulates besides the scene's history, saved in every checkpoint; returns
        it, as restored by a restart."""
        self.scene = scene
        self.kept = dict(kept or {})
        self.checkpoint = cli.checkpointer(self.comm, self.args)
        if self.checkpoint.start(scene, self.guard, extra=lambda: dict(self.kept, written=self.written)):
            restored = self.checkpoint.restored_extra
            self.written = restored["written"]
            self.kept = {name: restored[name] for name in self.kept}
        return self.kept

    def fields(self, cell_fields=()):
        """fields.xdmf of the scene's problem with the extra cell fields (name, shape,
        values_fn), continued by a restart."""
        with self.guard.deferred():        # a signal waits until the new file is closed: readable
            self.writer = FieldWriter(self.scene.problem, self.checkpoint.fields_path("fields.xdmf"),
                                      self.args.fields, resume_time=self.checkpoint.resume_time)
        for name, shape, values in cell_fields:
            self.writer.add_cell_field(name, shape, values)
        return self.writer

    def log(self, name, columns):
        """A CsvLog OUT/name whose first column is the step (a restart keeps its rows up to
        the checkpoint); closed when the run ends."""
        log = CsvLog(self.comm, os.path.join(self.args.out, name), columns, resume_step=self.checkpoint.resume_step)
        self.logs.append(log)
        return log

    def run(self, on_row, progress, write_every=1):
        """Run the scene: after every converged step on_row(row), then the fields every
        `write_every` steps, the step counted in summary.json with progress(row)'s entries.
        A step that cannot be cut small enough ends the run with what was computed (the
        reason in `stopped`); if not one step converged the run stops there (exit 1).
        Writes the last converged state, closes the files; returns `stopped` ('' when the
        run reached its end)."""
        def record(row):
            on_row(row)
            if row["step"] % write_every == 0:
                self.writer.write(row["time"])
                self.written.append(row["time"])

        scene = self.scene
        start = time.perf_counter()
        try:
            scene.run(self.guard.protect(record, progress), checkpoint=self.checkpoint)
            self.stopped = self.checkpoint.stop_note(scene.stepper)
        except LoadSteppingError as error:
            self.stopped = str(error)       # keep what was computed: the demo summarises the part before
            print0(self.comm, f"{self.label}: stopped early: {self.stopped}")
            if not scene.history:
                self.guard.stop(self.stopped)     # not one step converged: nothing to summarise
        if scene.history and scene.history[-1]["time"] not in self.written:
            self.writer.write(scene.history[-1]["time"])   # the last converged state (once)
        self.writer.close()
        for log in self.logs:
            log.close()
        self.wall_time = time.perf_counter() - start
        return self.stopped

    def summary_entries(self):
        """What every summary says about the run: completed, stopped, reason, the
        checkpoint's entries and wall_time [s] of the steps."""
        return {"completed": not self.stopped, "stopped": self.stopped, "reason": self.stopped,
                **self.checkpoint.summary_entries(), "wall_time": self.wall_time}

    def finish(self, summary):
        """The final summary.json: the demo's `summary` with summary_entries()."""
        self.guard.finish(dict(summary, **self.summary_entries()))

    def exit(self):
        """Exit status 1 if the run stopped short of its end for another reason than
        --stop-after (a step that could not be cut small enough)."""
        if self.stopped and not self.scene.stepper.stopped_early:
            sys.exit(1)
