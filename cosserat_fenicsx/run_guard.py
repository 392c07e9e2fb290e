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

Python runs a signal handler in the main thread between bytecodes, so a rank inside one long
call would hear the signal only when the call returns. A watchdog thread, woken by the
C-level handler through signal.set_wakeup_fd, ends the run itself (same summary, same exit)
when the main thread has not within MAIN_GRACE (rank 0) or RANK_GRACE seconds; it can run
while the main thread is in a call that releases the GIL (gmsh, a blocking MPI call through
mpi4py, time.sleep), not in one that holds it (a Numba kernel, most dolfinx and PETSc
calls). A rank held there until mpirun's SIGKILL leaves summary.json as its last step wrote
it (`completed: false`, reason RUNNING); its files are readable all the same (closed after
the last step).

summary.json is strict JSON (strict_json): an infinite or undefined number is written as the
string "inf", "-inf" or "nan".
"""
from contextlib import contextmanager
import json
import math
import os
import signal
import sys
import threading
import time

RUNNING = "running, or killed before it could record why (summary.json is rewritten as the run goes)"
SIGNALS = (signal.SIGINT, signal.SIGTERM)
RANK_GRACE = 0.5   # [s] a rank other than 0 keeps computing this long after the signal
MAIN_GRACE = 0.3   # [s] rank 0's watchdog waits this long for the main thread's handler


def _lor():
    from mpi4py import MPI
    return MPI.LOR


def strict_json(value):
    """`value` made of strict-JSON values, as every summary.json is written: tuples and
    arrays become lists, numpy numbers Python numbers, and a number that JSON cannot hold
    the string "inf", "-inf" or "nan" (e.g. the default rolling friction, infinite), so
    that any JSON reader takes the file.  Anything else: its float, or its str()."""
    if isinstance(value, dict):
        return {str(k): strict_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [strict_json(v) for v in value]
    if value is None or isinstance(value, (bool, str)):
        return value
    if hasattr(value, "tolist") and not isinstance(value, (int, float)):     # numpy arrays and scalars
        return strict_json(value.tolist())
    if isinstance(value, int):
        return int(value)
    try:
        number = float(value)
    except (TypeError, ValueError):
        return str(value)
    if math.isfinite(number):
        return number
    return "nan" if math.isnan(number) else ("inf" if number > 0 else "-inf")


class RunGuard:
    """One run's summary.json and its signal handling.

    comm     an mpi4py communicator (or None: serial); rank 0 alone writes and prints
    path     summary.json
    entries  what the summary says before the first step (settings, ...)
    min_interval  [s] progress() rewrites the file at most this often (0: at every call that
             asks; a run of many cheap steps pays an open, a dump and an os.replace each
             time); the start, finish, stop and an interruption always write
    """

    def __init__(self, comm, path, entries=None, label="", write_now=True, min_interval=0.0):
        self.rank = comm.rank if comm is not None else 0
        self.path, self.label = path, label
        self.min_interval = float(min_interval)
        self._written = -math.inf
        self.entries = dict(entries or {})
        self.steps = 0
        #: appended to the interruption's reason (e.g. where the checkpoint a run wrote on
        #: the signal is and how to continue)
        self.interrupt_note = ""
        self._depth, self._pending = 0, None
        self._wakeup = None
        self._previous = {sig: signal.signal(sig, self._handler) for sig in SIGNALS}
        self._start_watchdog()
        if write_now:      # a restart writes at its first step: a refused one leaves the earlier summary
            self._write(completed=False, reason=RUNNING)

    # --- progress ---------------------------------------------------------------------
    def progress(self, write=True, **entries):
        """After a converged step: count it, merge `entries` (e.g. the last step's strain)
        and, with `write`, rewrite summary.json (still `completed: false`) unless it was
        written less than min_interval seconds ago; a run of many cheap steps writes it on
        the steps it records."""
        self.steps += 1
        self.entries.update(entries)
        if write and (self.min_interval <= 0.0 or time.monotonic() - self._written >= self.min_interval):
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
            if self._depth == 0 and self._pending is not None and self.rank == 0:
                self._interrupt(self._pending)

    def signalled(self, comm=None):
        """Whether SIGINT or SIGTERM has arrived (on any rank of `comm`: collective when given),
        so that a run inside `deferred` can end its step its own way (e.g. write a checkpoint)
        before the block ends and the guard exits."""
        mine = self._pending is not None
        return bool(comm.allreduce(mine, op=_lor())) if comm is not None and comm.size > 1 else mine

    def interrupt_now(self, comm=None):
        """End the run as the signal asks, on every rank of `comm` together (a run that
        handled the signal itself at the end of a step: `signalled`): rank 0 writes
        summary.json with the interruption's reason, then every rank exits with status 128 +
        signal number."""
        signum = self._pending or signal.SIGTERM
        if self.rank == 0:
            self._record_interrupt(signum)
        if comm is not None:
            comm.barrier()
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(128 + signum)

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

    def refuse(self, reason):
        """An input found bad after the guard exists (e.g. a checkpoint that does not fit the
        mesh): one line on rank 0, summary.json left as it was, exit status 2 on every rank."""
        reason = " ".join(str(reason).split())
        if self.rank == 0:     # the form of the parser's refusals (validation.Parser.error)
            print(f"{os.path.basename(sys.argv[0]) or self.label}: error: {reason}", file=sys.stderr, flush=True)
        self.release()
        sys.exit(2)

    def release(self):
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        self._previous = {}
        if self._wakeup:
            signal.set_wakeup_fd(self._previous_wakeup)
            os.close(self._wakeup[1])        # the watchdog reads EOF and ends
            self._wakeup = None

    # --- internals --------------------------------------------------------------------
    def _write(self, **override):
        if self.rank != 0:
            return
        data = dict(self.entries, **override)
        data.setdefault("steps_completed", self.steps)
        tmp = self.path + ".tmp"
        with open(tmp, "w") as f:
            json.dump(strict_json(data), f, indent=2, sort_keys=True, allow_nan=False)
        os.replace(tmp, self.path)
        self._written = time.monotonic()

    def _handler(self, signum, frame):
        """Python's handler: runs in the main thread, between bytecodes."""
        self._pending = self._pending or signum
        if self.rank == 0 and self._depth == 0:
            self._interrupt(signum)
        # other ranks: the watchdog ends them after RANK_GRACE (rank 0 may be waiting for
        # them in a collective call); inside `deferred`: when the block is done

    def _start_watchdog(self):
        """A thread woken by the C-level signal handler (signal.set_wakeup_fd): it ends the
        run when the main thread cannot, because it is inside a long call that released
        the GIL (gmsh, a blocking MPI call through mpi4py)."""
        read_end, write_end = os.pipe()
        os.set_blocking(write_end, False)
        self._wakeup = (read_end, write_end)
        self._previous_wakeup = signal.set_wakeup_fd(write_end, warn_on_full_buffer=False)

        def watch():
            while True:
                try:
                    data = os.read(read_end, 1)
                except OSError:
                    data = b""
                if not data:                 # release() closed the write end
                    os.close(read_end)
                    return
                signum = data[0]
                if signum not in SIGNALS:
                    continue
                deadline = time.monotonic() + (MAIN_GRACE if self.rank == 0 else RANK_GRACE)
                while time.monotonic() < deadline or self._depth > 0:
                    time.sleep(0.02)     # the main thread's handler normally ends the run first
                self._interrupt(signum)

        threading.Thread(target=watch, name="run-guard-watchdog", daemon=True).start()

    def _record_interrupt(self, signum):
        name = signal.Signals(signum).name
        reason = f"interrupted by {name} after step {self.steps}{self.interrupt_note}"
        self._write(completed=False, reason=reason, interrupted_by=name, steps_completed=self.steps)
        if self.rank == 0:
            print(f"{self.label + ': ' if self.label else ''}{reason}; "
                  f"the outputs of the completed steps are kept in {os.path.dirname(self.path) or '.'}",
                  flush=True)

    def _interrupt(self, signum):
        try:
            self._record_interrupt(signum)
        finally:
            sys.stdout.flush()
            sys.stderr.flush()
            # no unwinding: the other ranks may be in a collective call this rank never reaches
            os._exit(128 + signum)
