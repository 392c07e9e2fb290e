"""Running a demo as a user does: PETSc options pass through, and Ctrl-C keeps what was
computed (history rows and XDMF steps are written as each step converges)."""
import math
import os
import signal
import subprocess
import sys
import time

import pytest

from conftest import ROOT
from cosserat_fenicsx.run_guard import RUNNING

pytestmark = pytest.mark.serial


def test_petsc_options_pass_through(demo, tmp_path):
    proc = demo("shear_layer", "--out", tmp_path, "-snes_monitor", "-ksp_type", "gmres",
                "-pc_type", "ilu", "-ksp_rtol", "1e-12", "-ksp_view")
    assert "SNES Function norm" in proc.stdout
    assert "type: gmres" in proc.stdout and "type: ilu" in proc.stdout


def test_interrupted_run_keeps_finished_steps(tmp_path):
    cmd = [sys.executable, os.path.join(ROOT, "demos", "shear_layer.py"), "--steps", "400",
           "--cell-size", "0.002", "--out", str(tmp_path)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    history = tmp_path / "history.csv"
    deadline = time.time() + 120
    while time.time() < deadline:
        if history.exists() and len(history.read_text().splitlines()) >= 4:
            break
        time.sleep(0.2)
    proc.send_signal(signal.SIGINT)
    proc.communicate(timeout=60)
    assert proc.returncode != 0                       # it was interrupted, not finished
    rows = history.read_text().splitlines()
    assert len(rows) >= 4 and len(rows) < 401
    import h5py
    with h5py.File(tmp_path / "fields.h5", "r") as f:   # the HDF5 file is closed and readable
        steps = list(f["Function"]["displacement"].keys())
    assert len(steps) >= len(rows) - 1


# long enough that it cannot finish in the second mpirun waits between its SIGCONT and the
# SIGTERM it sends its ranks on Ctrl-C (the tests interrupt it after a few steps)
BIAXIAL = ["--cell-size", "0.0125", "--steps", "2000", "--consolidation-steps", "2", "--axial-strain", "0.05",
           "--write-every", "1"]


def interrupt(tmp_path, sig, rows, ranks=None, demo="biaxial", args=BIAXIAL):
    """Start a real run, send `sig` once history.csv has `rows` data rows (0: as soon as
    summary.json exists, i.e. during the set-up), and return (returncode, out)."""
    out = tmp_path / "out"
    cmd = [sys.executable, os.path.join(ROOT, "demos", demo + ".py"), *args, "--out", str(out)]
    if ranks:
        cmd = ["mpirun", "-n", str(ranks)] + cmd
    env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
               OMPI_MCA_rmaps_base_oversubscribe="1", OMP_NUM_THREADS="1")
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT, env=env)
    history, summary = out / "history.csv", out / "summary.json"
    deadline = time.time() + 300
    while time.time() < deadline and proc.poll() is None:
        if summary.exists() and (rows == 0 or (history.exists() and len(history.read_text().splitlines()) > rows)):
            break
        time.sleep(0.05)
    assert proc.poll() is None, f"the run ended before the signal:\n{proc.communicate()[1][-2000:]}"
    proc.send_signal(sig)
    _, stderr = proc.communicate(timeout=120)
    assert "Traceback" not in stderr, stderr[-3000:]
    return proc.returncode, out


def check_interrupted(out, sig, ranks):
    import json
    import h5py
    summary = json.loads((out / "summary.json").read_text())
    assert summary["completed"] is False, "the run finished before the signal: make it longer"
    rows = (out / "history.csv").read_text().splitlines()[1:] if (out / "history.csv").exists() else []
    if summary["reason"].startswith("interrupted by"):
        # mpirun turns Ctrl-C into SIGTERM for its ranks
        assert summary["reason"].startswith(f"interrupted by {sig.name}" if not ranks else "interrupted by SIG")
        assert summary["steps_completed"] == len(rows)
    else:
        # a rank killed inside a C call before it could record why (run_guard's docstring)
        assert ranks and summary["reason"] == RUNNING, summary["reason"]
    for row in rows:
        assert all(math.isfinite(float(v)) for v in row.split(","))
    if (out / "fields.h5").exists():
        with h5py.File(out / "fields.h5", "r") as f:       # closed after every step: readable
            counts = {name: len(group) for name, group in f["Function"].items()} if "Function" in f else {}
        assert set(counts.values()) <= {len(rows)}, (counts, len(rows))
    return summary, rows


@pytest.mark.parametrize("sig, rows, ranks", [
    (signal.SIGINT, 0, None), (signal.SIGTERM, 1, None), (signal.SIGINT, 3, None),
    (signal.SIGTERM, 0, 2), (signal.SIGINT, 1, 2), (signal.SIGTERM, 3, 2)])
def test_interrupted_biaxial_keeps_every_completed_step(tmp_path, sig, rows, ranks):
    code, out = interrupt(tmp_path, sig, rows, ranks)
    assert code != 0
    if not ranks:
        assert code == 128 + sig
    summary, history = check_interrupted(out, sig, ranks)
    assert len(history) >= rows


# the signal sent from inside the creation of fields.h5 (the mesh being written), on every rank
SIGNAL_IN_FILE_CREATION = """
import os, runpy, signal, sys
import dolfinx.io
write_mesh = dolfinx.io.XDMFFile.write_mesh
def signalled_write_mesh(self, mesh):
    os.kill(os.getpid(), signal.SIGTERM)
    write_mesh(self, mesh)
dolfinx.io.XDMFFile.write_mesh = signalled_write_mesh
sys.argv = sys.argv[1:]
runpy.run_path(sys.argv[0], run_name="__main__")
"""


@pytest.mark.parametrize("ranks", [None, 2])
def test_signal_while_the_field_file_is_created_leaves_it_readable(tmp_path, ranks):
    """A signal that arrives while fields.h5 is being created (the set-up of a run, the mesh
    being written) ends the run once the file is closed: readable, with its mesh and no step."""
    import h5py
    out = tmp_path / "out"
    cmd = [sys.executable, "-c", SIGNAL_IN_FILE_CREATION, os.path.join(ROOT, "demos", "biaxial.py"),
           *BIAXIAL, "--out", str(out)]
    if ranks:
        cmd = ["mpirun", "-n", str(ranks)] + cmd
    env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
               OMPI_MCA_rmaps_base_oversubscribe="1", OMP_NUM_THREADS="1")
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, env=env, timeout=300)
    assert "Traceback" not in proc.stderr, proc.stderr[-3000:]
    assert proc.returncode == 128 + signal.SIGTERM if not ranks else proc.returncode != 0
    summary, rows = check_interrupted(out, signal.SIGTERM, ranks)
    assert summary["reason"].startswith("interrupted by SIGTERM after step 0") and rows == []
    with h5py.File(out / "fields.h5", "r") as f:
        assert "Mesh" in f and "Function" not in f


def test_interrupted_output_opens_in_paraview(tmp_path):
    from test_paraview import paraview_read, shutil as _shutil
    if _shutil.which("pvbatch") is None or _shutil.which("xvfb-run") is None:
        pytest.skip("ParaView (python3-paraview) or xvfb-run not installed")
    code, out = interrupt(tmp_path, signal.SIGTERM, 2)
    summary, rows = check_interrupted(out, signal.SIGTERM, None)
    data = paraview_read(out / "fields.xdmf", tmp_path / "render.png", "displacement")
    assert len(data["times"]) == len(rows) and "plastic_strain" in data["arrays"]


def test_interrupted_material_point_keeps_its_history(tmp_path):
    """The material-point driver writes history.csv row by row: Ctrl-C keeps every step."""
    code, out = interrupt(tmp_path, signal.SIGINT, 50, demo="material_point",
                          args=["--test", "triaxial", "--steps", "200000"])
    assert code == 128 + signal.SIGINT
    summary, rows = check_interrupted(out, signal.SIGINT, None)
    assert len(rows) >= 50 and summary["steps_completed"] == len(rows)


def test_summaries_are_strict_json(tmp_path):
    """summary.json takes any JSON reader: infinite and undefined numbers (an infinite rolling
    friction, a NaN estimate) are written as strings, numpy values as numbers, tuples as lists."""
    import json
    import numpy as np
    from cosserat_fenicsx.run_guard import RunGuard, strict_json
    assert strict_json({"a": math.inf, "b": (-math.inf, np.nan), "c": np.float32(0.5), "d": np.int64(3),
                        "e": np.arange(2), 4: None}) == {"a": "inf", "b": ["-inf", "nan"], "c": 0.5, "d": 3,
                                                         "e": [0, 1], "4": None}
    path = tmp_path / "summary.json"
    RunGuard(None, str(path)).finish(dict(rolling_friction=math.inf, estimate=np.float64("nan")))
    text = path.read_text()
    summary = json.loads(text, parse_constant=lambda name: pytest.fail(f"{name} in summary.json"))
    assert summary["rolling_friction"] == "inf" and summary["estimate"] == "nan"
