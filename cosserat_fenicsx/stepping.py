"""Load stepping over pseudo-time with automatic cut-back.

Loads are scaled by the problem's time functions; a step that SNES cannot converge (or
whose Gauss points fail) is rolled back (fields and history) and retried with half the
increment, until dt_min, where the run stops with a message naming the cause. After an
easy step the increment grows again. Rank 0 prints one line per step.
"""
from dataclasses import dataclass
import time

from .output import print0


class LoadSteppingError(RuntimeError):
    """The increment fell below dt_min; the message names the last cause."""


@dataclass
class StepRecord:
    step: int
    time: float
    dt: float
    iterations: int
    residual: float
    cuts: int
    wall_time: float


class LoadStepper:
    """Drive `problem` with `solver` from t = 0 to t_end.

    dt       first increment of pseudo-time;  dt_min  smallest allowed after cut-backs
    dt_max   largest increment (default dt);   grow    factor after an easy step
    on_step  callable(StepRecord) after every converged step (output, history)
    after_step  callable(StepperPosition) after on_step, with where the stepping stands
             (what a checkpoint saves, checkpoint.py)
    start    a StepperPosition to continue from (a restart); default t = 0, step 0
    stop_after  stop cleanly after this many converged steps in all (as a batch queue's
             time limit would; `stopped_early` says it did)
    """

    def __init__(self, problem, solver, t_end=1.0, dt=0.1, dt_min=None, dt_max=None,
                 grow=1.5, easy_iterations=4, on_step=None, verbose=True, after_step=None,
                 start=None, stop_after=None):
        if not (t_end > 0 and dt > 0):
            raise ValueError(f"t_end and dt must be positive (t_end={t_end}, dt={dt})")
        self.problem, self.solver = problem, solver
        self.t_end, self.dt = float(t_end), float(dt)
        self.dt_min = float(dt_min) if dt_min is not None else self.dt / 2 ** 10
        self.dt_max = float(dt_max) if dt_max is not None else self.dt
        self.grow, self.easy_iterations = grow, easy_iterations
        self.on_step = on_step
        self.after_step = after_step
        self.start = start
        self.stop_after = stop_after
        self.stopped_early = False
        self.verbose = verbose
        self.records = []
        #: cut-backs so far, those of a step that failed down to dt_min included (the records
        #: carry the count at each converged step only)
        self.cuts = start.cuts if start is not None else 0

    def log(self, text):
        if self.verbose:
            print0(self.problem.mesh.comm, text)

    def run(self):
        problem = self.problem
        t, dt, step, cuts = 0.0, self.dt, 0, 0
        if self.start is not None:
            t, dt, step, cuts = self.start.time, self.start.dt, self.start.step, self.start.cuts
        start = time.perf_counter()
        self.log(f"{'step':>5} {'time':>10} {'dt':>10} {'newton':>6} {'residual':>10} {'wall[s]':>8}")
        while t < self.t_end * (1 - 1e-12):
            if self.stop_after is not None and step >= self.stop_after:
                self.stopped_early = True
                break
            dt = min(dt, self.t_end - t)
            problem.set_time(t + dt)
            problem.set_time_step(dt)
            info = self.solver.solve()
            if not info.converged:
                problem.rollback()
                cause = info.failure or f"SNES {info.reason} after {info.iterations} iterations"
                if info.flags and not info.failure:
                    cause += f"; {info.flags}"
                cuts += 1
                self.cuts = cuts
                self.log(f"  cut-back at t={t + dt:.6g} (dt={dt:.3g}): {cause}")
                dt *= 0.5
                if dt < self.dt_min:
                    problem.set_time(t)
                    raise LoadSteppingError(
                        f"load step at t={t:.6g} did not converge down to dt_min={self.dt_min:.3g}: {cause}")
                continue
            problem.commit(dt)
            t += dt
            step += 1
            record = StepRecord(step, t, dt, info.iterations, info.residual, cuts,
                                time.perf_counter() - start)
            self.records.append(record)
            self.log(f"{step:5d} {t:10.4g} {dt:10.3g} {info.iterations:6d} {info.residual:10.3e} "
                     f"{record.wall_time:8.2f}")
            if self.on_step is not None:
                self.on_step(record)
            if info.iterations <= self.easy_iterations:
                dt = min(dt * self.grow, self.dt_max)
            if self.after_step is not None:
                self.after_step(StepperPosition(t, dt, step, cuts))
        return self.records


@dataclass
class StepperPosition:
    """Where a load stepping stands after a converged step: pseudo-time, the increment the
    next step will try, converged steps and cut-backs so far (all a restart needs)."""
    time: float
    dt: float
    step: int
    cuts: int
