"""Shared runner of the FEM x DEM benchmarks: one case = one FemDemBiaxial run.

`run_case(comm, out, label, settings)` runs the case (unless `out/label.json` exists: long
studies resume where they stopped; or a run of the same settings is in the shared store
`cases_dir(out)`, by default `femdem_cases/` beside `out`: the benchmarks share their runs,
e.g. the hybrid meshes of the regularisation are the mesh family of the convergence study;
results do not depend on the number of ranks) and writes, as soon as it ends, a JSON record with the
history, the peak, the band fit and its verdict, the Newton iterations, the DEM steps, wall
and CPU seconds (CPU summed over the ranks), where the time went (slowest rank), the memory
of the cells and the load average before and after (the machine may be shared: compare
times within one run of a study only).
"""
import hashlib
import json
import os
import resource
import signal
import time

import numpy as np
from mpi4py import MPI

from cosserat_fenicsx.materials.dem import CellOptions
from cosserat_fenicsx.scenes.femdem_biaxial import FemDemBiaxial, FemDemSettings, max_over_ranks, parse_mesh  # noqa: F401
from cosserat_fenicsx.shear_band import band_verdict
from cosserat_fenicsx.stepping import LoadSteppingError


def settings(mesh=(2, 4), particles=228, cell=None, **kw):
    """FemDemSettings with the cell options in one place (`cell`: CellOptions overrides)."""
    nx, ny = mesh
    return FemDemSettings(nx=nx, ny=ny, cell=CellOptions(particles=particles, **(cell or {})), **kw)


def cpu_seconds():
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


class Interrupted(Exception):
    """SIGTERM during a run: the step under way ends, and the record is written with what the
    run reached (a study that must end by a deadline keeps its partial curves). The signal is
    looked at after a converged step, on every rank together (a rank that got it tells the
    others), so no rank waits in a collective. Delete the record to run the case again."""


class _SigtermFlag:
    def __init__(self):
        self.raised = False

    def __call__(self, signum, frame):
        self.raised = True


def cases_dir(out):
    return os.environ.get("FEMDEM_CASES", os.path.join(os.path.dirname(os.path.abspath(out)), "femdem_cases"))


def settings_key(s):
    """A digest of every setting of a run (the dataclass repr lists them all)."""
    return hashlib.sha1(repr(s).encode()).hexdigest()[:16]


def record_paths(out, label, s):
    """Where a case's record lives: the study's own `out/label.json` and the shared store."""
    return os.path.join(out, f"{label}.json"), os.path.join(cases_dir(out), f"{settings_key(s)}.json")


def stored_record(out, label, s):
    """The record of a case if it was run (in `out` or the shared store), else None."""
    for known in record_paths(out, label, s):
        if os.path.isfile(known):
            with open(known) as f:
                record = json.load(f)
            record["label"] = label
            return record
    return None


def run_case(comm, out, label, s, log=print, window_from=None):
    """Run one case (or read its record); returns the record (every rank).

    window_from: an axial strain (its magnitude) from which the record also keeps the
    symmetric strain increment (e_xx, e_yy, e_xy) of the window to the run's end at every
    Gauss point, `window_strain_increment` (the DNS's band is measured on such an increment:
    benchmarks/dns/dns_band.py). A run that stops before it keeps the window from its peak
    stress ratio instead, if it went past it (`window_from` in the record says where the
    window starts)."""
    path, shared = record_paths(out, label, s)
    record = stored_record(out, label, s)
    if record is not None:
        return record
    load_before = os.getloadavg()
    start, cpu0 = time.perf_counter(), cpu_seconds()
    if comm.rank == 0:
        log(f"{label}: running ({s.mode}, {s.nx}x{s.ny}, {s.cell.particles} discs, {s.tangent})")
    test = FemDemBiaxial(comm, s, verbose=True)    # one line per step: a long study shows progress
    stopped = ""
    flag = _SigtermFlag()
    previous = signal.signal(signal.SIGTERM, flag)

    band_history = []   # the band fit after every step of phase 2: runs stopped at different
                        # strains are compared at a strain they all reached
    window = StrainWindow(window_from) if window_from is not None else None

    def after_step(row):
        if row["phase"] == 2 and window is not None:
            window.after_step(row, row["stress_ratio"], test.gauss_points.gradients)
        if row["phase"] == 2:
            try:
                fit = test.band().as_dict()
            except ValueError:
                fit = None
            band_history.append({"axial_strain": row["axial_strain"], "fit": fit})
        if comm.allreduce(flag.raised, op=MPI.LOR):
            raise Interrupted(f"interrupted by SIGTERM after step {row['step']}")

    try:
        test.run(on_step=after_step)
    except (LoadSteppingError, Interrupted) as error:
        stopped = str(error)
    finally:
        signal.signal(signal.SIGTERM, previous)
    wall = time.perf_counter() - start
    cpu = comm.allreduce(cpu_seconds() - cpu0)
    rows = [r for r in test.history if r["phase"] == 2]
    ratio = np.array([r["stress_ratio"] for r in rows])
    i_peak = int(np.argmax(ratio)) if len(ratio) else 0
    fit, verdict = None, "no step"
    if rows:
        try:
            fit = test.band()
            ok, why = band_verdict(fit, min(s.width / s.nx, s.height / s.ny), s.width)
            verdict = "band" if ok else why
        except ValueError as error:
            verdict = str(error)
    iterations = [r["newton_iterations"] for r in rows]
    points, strain = test.global_order(test.equivalent_strain(test.gradients_start))
    increment = window.increment(comm, test.gauss_points.gradients) if window is not None else None
    window_strain = test.global_order(increment)[1] if increment is not None else None
    couple = curvature = None
    if test.gauss_points.gradients.shape[1] >= 6:     # a rotation field: m3j and kappa3j at the end
        couple = test.global_order(test.gauss_points.flux_values[:, 4:6])[1]
        curvature = test.global_order(test.gauss_points.gradients[:, 4:6])[1]
    record = {
        "label": label, "mode": s.mode, "tangent": s.tangent, "mesh": [s.nx, s.ny],
        "particles": s.cell.particles, "criterion": s.cell.criterion, "relaxation_tol": s.cell.relaxation_tol,
        "l_c": test.l_c, "mu_c": test.mu_c, "n_gauss_points": comm.allreduce(len(test.points)),
        "ranks": comm.size, "completed": not stopped, "stopped": stopped,
        "axial_strain": [r["axial_strain"] for r in rows], "stress_ratio": ratio.tolist(),
        "volumetric_strain": [r["volumetric_strain"] for r in rows],
        "coordination_number": [r["coordination_number"] for r in rows],
        "vertical_stress": [r["vertical_stress"] for r in rows],
        "newton_iterations": iterations, "dem_steps": [r["dem_steps"] for r in rows],
        "cell_tangents_total": comm.allreduce(test.point_tangents()),
        "accepted": [r["accepted"] for r in rows], "final_force_ratio": [r["force_ratio"] for r in rows],
        "force_ratios": [info.force_ratios for info in test.solver.infos_converged()][1:],
        "peak_stress_ratio": float(ratio[i_peak]) if rows else None,
        "axial_strain_at_peak": float(rows[i_peak]["axial_strain"]) if rows else None,
        "band_thickness": fit.thickness if fit is not None and verdict == "band" else None,
        "band_fit": fit.as_dict() if fit is not None else None, "band_verdict": verdict,
        "band_history": band_history,
        "wall_time": wall, "cpu_time": cpu, "preparation_time": test.preparation_time,
        "time_max_over_ranks": {k: max_over_ranks(comm, v) for k, v in test.timing().items()},
        "memory_per_cell_bytes": comm.allreduce(test.material.memory_bytes()) / comm.allreduce(len(test.points)),
        "cuts": int(test.history[-1]["cuts"]) if test.history else 0,
        "load_average_before": load_before[0], "load_average_after": os.getloadavg()[0],
        # the final equivalent strain since the start of phase 2 at every Gauss point (rank 0)
        "points": points.tolist() if points is not None else None,
        "equivalent_strain": strain.tolist() if strain is not None else None,
        "window_from": window.axial_strain if window is not None else None,
        "window_strain_increment": window_strain.tolist() if window_strain is not None else None,
        # the couple stress m31, m32 [N] and curvature kappa31, kappa32 [1/m] at the end (rank 0)
        "couple_stress": couple.tolist() if couple is not None else None,
        "curvature": curvature.tolist() if curvature is not None else None,
    }
    if comm.rank == 0:
        os.makedirs(out, exist_ok=True)
        with open(path + ".tmp", "w") as f:
            json.dump(record, f, indent=1)
        os.replace(path + ".tmp", path)
        os.makedirs(os.path.dirname(shared), exist_ok=True)
        with open(shared + ".tmp", "w") as f:
            json.dump(dict(record, settings=repr(s)), f, indent=1)
        os.replace(shared + ".tmp", shared)
        log(f"{label}: peak {record['peak_stress_ratio']:.4f} at {record['axial_strain_at_peak']:.4f}, "
            f"band {verdict if verdict != 'band' else f'H = {fit.thickness * 1e3:.3f} mm'}, "
            f"{sum(iterations)} Newton iterations, {wall:.0f} s wall, {cpu:.0f} s CPU"
            + (f"; stopped: {stopped}" if stopped else ""))
    return record


class StrainWindow:
    """Where a run's strain window starts: the Gauss-point gradients at the first step of
    phase 2 whose axial strain reaches `window_from` (its magnitude); for a run that stops
    before it, at its peak (the step of phase 2 with the largest `strength`), if the run went
    past it."""

    def __init__(self, window_from):
        self.window_from = window_from
        self.start = self.axial_strain = None
        self._peak = None           # (strength, gradients, axial strain, step) of the peak so far
        self._last_step = None

    def after_step(self, row, strength, gradients):
        """A converged step of phase 2 (its history row), the specimen's `strength` there
        (larger is stronger) and its Gauss-point gradients (copied where kept)."""
        self._last_step = row["step"]
        if self._peak is None or strength > self._peak[0]:
            self._peak = (strength, gradients.copy(), row["axial_strain"], row["step"])
        if self.start is None and abs(row["axial_strain"]) >= self.window_from - 1e-12:
            self.start, self.axial_strain = gradients.copy(), row["axial_strain"]

    def increment(self, comm, gradients):
        """(e_xx, e_yy, e_xy) from the window's start to `gradients` at this rank's points, or
        None on every rank when the run has no window (collective)."""
        if self.start is None and self._peak is not None and self._last_step > self._peak[3]:
            _, self.start, self.axial_strain, _ = self._peak
        if not comm.allreduce(self.start is not None, op=MPI.LAND):
            return None
        return symmetric_increment(gradients, self.start)


def symmetric_increment(gradients, since):
    """(e_xx, e_yy, e_xy) (n, 3) of the symmetric strain from the Gauss-point gradients
    `since` to `gradients` (columns eps11, eps22, eps12, eps21: kinematics.GRADIENT_NAMES;
    the rotation cancels in the symmetric part)."""
    d = np.asarray(gradients)[:, :4] - np.asarray(since)[:, :4]
    return np.column_stack([d[:, 0], d[:, 1], 0.5 * (d[:, 2] + d[:, 3])])


def homogeneous_path(cell, axial_strains, pressure):
    """The stand-alone cell on the homogeneous path of the biaxial test with smooth platens:
    F_22 = 1 + e imposed for each e of `axial_strains` (tension positive: e < 0 compresses),
    F_12 = F_21 = 0, sigma_11 = -pressure [N/m] held by the servo on F_11, committed after each.
    What a uniform specimen's every Gauss point does; over packing seeds, the scatter of the
    cell (the yardstick of a curve's agreement). Returns the 2x2 Cauchy stresses [N/m], one per
    strain; RuntimeError if a solve does not converge."""
    mask = np.array([[True, False], [False, False]])
    stresses = []
    for e in axial_strains:
        F = cell.deformation_gradient().copy()
        F[1, 1] = 1.0 + e
        F[0, 1] = F[1, 0] = 0.0
        cell.set_deformation(F)
        result = cell.solve(stress_mask=mask, stress_target=-pressure * np.eye(2))
        if not result.converged:
            raise RuntimeError(f"the cell did not converge at axial strain {e:g}: {result.message}")
        cell.commit()
        stresses.append(cell.cauchy_stress().copy())
    return stresses


def stress_ratio(sigma):
    """|s11 - s22| / |s11 + s22| of a 2x2 stress (000 eq. 40, the history's stress_ratio)."""
    return abs(sigma[0, 0] - sigma[1, 1]) / abs(sigma[0, 0] + sigma[1, 1])


def time_split(record):
    """Where the Newton time went (slowest rank), in % of it: cell solves (and homogenisation),
    cell tangents, assembly (residual and Jacobian), linear solve and SNES."""
    t = record["time_max_over_ranks"]
    parts = {"solves %": t["cell_solves"] + t.get("cell_homogenisation", 0.0), "tangents %": t["cell_tangents"],
             "assembly %": t["residual_assembly"] + t["jacobian_assembly"],
             # records made before the accepted iterate's re-evaluation was timed inside the
             # solve can come out negative here: that part was cell time, not linear solve
             "linear %": max(t["linear_solve_and_snes"], 0.0)}
    total = max(sum(parts.values()), 1e-300)
    return {k: 100 * v / total for k, v in parts.items()}


TIME_COLUMNS = [(k, (lambda r, k=k: time_split(r)[k]), ".2f") for k in ("solves %", "tangents %", "assembly %", "linear %")]


def write_report(out, name, text):
    """Print a study's report and write it to out/name (rank 0; creates out, which is still
    missing when every record came from the shared store)."""
    print(text)
    os.makedirs(out, exist_ok=True)
    with open(os.path.join(out, name), "w") as f:
        f.write(text.rstrip("\n") + "\n")


def table(records, columns):
    """Fixed-width text table of records (list of dicts) for `columns` [(title, key, fmt)]."""
    head = " ".join(f"{t:>{max(len(t), 10)}}" for t, _, _ in columns)
    lines = [head, "-" * len(head)]
    for r in records:
        cells = []
        for t, key, fmt in columns:
            v = key(r) if callable(key) else r.get(key)
            cells.append(f"{(format(v, fmt) if v is not None else '-'):>{max(len(t), 10)}}")
        lines.append(" ".join(cells))
    return "\n".join(lines)
