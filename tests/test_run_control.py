"""Running a demo as a user does: PETSc options pass through, and Ctrl-C keeps what was
computed (history rows and XDMF steps are written as each step converges)."""
import os
import signal
import subprocess
import sys
import time

import pytest

from conftest import ROOT

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
