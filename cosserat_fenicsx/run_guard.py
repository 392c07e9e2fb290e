"""summary.json as the run goes, and a clean end on SIGINT and SIGTERM (what a user's
Ctrl-C and a batch queue's time limit send), serial and under mpirun.

A run keeps summary.json current: written at the start and after every step with
`completed: false`, so a run killed outright (SIGKILL, power) still leaves one that says it
did not finish and how far it got. On SIGINT or SIGTERM every rank stops without unwinding
through collective MPI or HDF5 calls that the other ranks may not reach: rank 0 writes
summary.json with `completed: false` and `reason: "interrupted by SIGTERM after step k"`,
prints one line and exits with status 128 + signal number; the other ranks keep computing
for RANK_GRACE seconds first (rank 0 may be waiting for them in a collective call), then
exit the same way. The files
stay readable because nothing is left open between steps: history.csv is flushed row by
row and the XDMF/HDF5 file is closed after each step (output.FieldWriter); while a step is
being written (`deferred`, `protect`) the signal waits until the step is complete.

A signal that arrives while a rank is inside one long C call (a linear solve, a Numba
kernel, a blocking MPI collective) is handled when the call returns; mpirun sends SIGKILL
one second after SIGTERM by default, so such a rank may be killed first: its files are
still readable (closed after the last step) and summary.json then holds the last step's
`completed: false` with the reason RUNNING.
"""
from contextlib import contextmanager
import json
import os
import signal
import sys
import threading

RUNNING = "running, or killed before it could record why (summary.json is rewritten after every step)"
SIGNALS = (signal.SIGINT, signal.SIGTERM)
RANK_GRACE = 0.5   # [s] a rank other than 0 keeps computing this long after the signal


def _json_default(value):
    try:
        return float(value)
    except (TypeError, ValueError):
        return str(value)


class RunGuard:
    """One run's summary.json and its signal handling.

    comm     an mpi4py communicator (or None: serial); rank 0 alone writes and prints
    path     summary.json
    entries  what the summary says before the first step (settings, ...)
    """

    def __init__(self, comm, path, entries=None, label=""):
        self.rank = comm.rank if comm is not None else 0
        self.path, self.label = path, label
        self.entries = dict(entries or {})
        self.steps = 0
        self._depth, self._pending = 0, None
        self._previous = {sig: signal.signal(sig, self._handler) for sig in SIGNALS}
        self._write(completed=False, reason=RUNNING)

    # --- progress ---------------------------------------------------------------------
    def progress(self, **entries):
        """After a converged step: count it, merge `entries` (e.g. the last step's strain)
        and rewrite summary.json (still `completed: false`)."""
        self.steps += 1
        self.entries.update(entries)
        self._write(completed=False, reason=RUNNING)

    @contextmanager
    def deferred(self):
        """A signal that arrives inside waits until the block is done (a step's outputs
        are written whole or not at all)."""
        self._depth += 1
        try:
            yield
        finally:
            self._depth -= 1
            if self._depth == 0 and self._pending is not None:
                self._interrupt(self._pending)

    def protect(self, on_step, progress=None):
        """`on_step` wrapped: runs deferred, then counts the step; `progress(arg)` (optional)
        returns summary entries for it."""
        def wrapped(arg):
            with self.deferred():
                on_step(arg)
                self.progress(**(progress(arg) if progress else {}))
        return wrapped

    # --- the end ----------------------------------------------------------------------
    def finish(self, summary):
        """The final summary.json (its `completed` as given, default True; `reason` ''
        when completed) and the previous signal handlers back."""
        summary = dict(summary)
        summary.setdefault("completed", True)
        summary.setdefault("reason", "" if summary["completed"] else "stopped")
        self.entries = summary
        self._write()
        self.release()

    def stop(self, reason, **entries):
        """A run that cannot go on (e.g. a load step that does not converge down to dt_min):
        rank 0 prints the reason, summary.json says completed: false with it (and the
        entries recorded so far), and every rank exits with status 1."""
        reason = " ".join(str(reason).split())
        if self.rank == 0:
            print(f"{self.label + ': ' if self.label else ''}stopped: {reason}", file=sys.stderr, flush=True)
        self.finish(dict(self.entries, **entries, completed=False, reason=reason))
        sys.exit(1)

    def release(self):
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        self._previous = {}

    # --- internals --------------------------------------------------------------------
    def _write(self, **override):
        if self.rank != 0:
            return
        data = dict(self.entries, **override)
        data.setdefault("steps_completed", self.steps)
        tmp = self.path + ".tmp"
        with open(tmp, "w") as f:
            json.dump(data, f, indent=2, sort_keys=True, default=_json_default)
        os.replace(tmp, self.path)

    def _handler(self, signum, frame):
        if self.rank != 0:
            # rank 0 may be waiting for this one in a collective call: carry on for a
            # moment so that it can return to Python and record the interruption
            if self._pending is None:
                self._pending = signum
                self._exit_later(signum, RANK_GRACE)
            return
        if self._depth > 0:
            self._pending = signum
            return
        self._interrupt(signum)

    def _exit_later(self, signum, delay):
        def fire():
            if self._depth > 0:          # inside a collective write: finish it first
                self._exit_later(signum, 0.05)
            else:
                self._interrupt(signum)
        timer = threading.Timer(delay, fire)
        timer.daemon = True
        timer.start()

    def _interrupt(self, signum):
        name = signal.Signals(signum).name
        reason = f"interrupted by {name} after step {self.steps}"
        try:
            self._write(completed=False, reason=reason, interrupted_by=name, steps_completed=self.steps)
            if self.rank == 0:
                print(f"{self.label + ': ' if self.label else ''}{reason}; "
                      f"the outputs of the completed steps are kept in {os.path.dirname(self.path) or '.'}",
                      flush=True)
        finally:
            sys.stdout.flush()
            sys.stderr.flush()
            # no unwinding: the other ranks may be in a collective call this rank never reaches
            os._exit(128 + signum)
