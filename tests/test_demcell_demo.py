"""demos/dem_cell.py end to end (tiny run by default, the full default run is slow) and the
initial-fabric control of the packing generator."""
import csv
import json
import os
import subprocess
import sys

import numpy as np
import pytest

import demcell as dc

pytestmark = pytest.mark.serial
DEMO = os.path.join(os.path.dirname(__file__), "..", "demos", "dem_cell.py")
COLUMNS = ["axial_strain", "stress_ratio", "volumetric_strain", "coordination_number", "anisotropy"]


def run_demo(out, *args):
    subprocess.run([sys.executable, DEMO, "--out", str(out), *args], check=True,
                   capture_output=True, text=True, timeout=900)
    with open(os.path.join(out, "history.csv")) as f:
        rows = list(csv.reader(f))
    summary = json.load(open(os.path.join(out, "summary.json")))
    return rows, summary


def test_demo_small_run(tmp_path):
    rows, summary = run_demo(tmp_path, "--particles", "40", "--axial-strain", "0.004",
                             "--increment", "0.001", "--snapshot-every", "2", "--no-rotation")
    assert rows[0] == COLUMNS and len(rows) == 1 + 1 + 4
    data = np.array(rows[1:], dtype=float)
    assert np.all(np.isfinite(data)) and data[-1, 0] == pytest.approx(-0.004)
    assert summary["peak_stress_ratio"] == pytest.approx(data[:, 1].max())
    assert os.path.exists(tmp_path / "biaxial.png")
    snaps = sorted(os.listdir(tmp_path / "snapshots"))
    assert "particles_0004.vtk" in snaps and "contacts_0004.vtk" in snaps


def test_demo_rejects_bad_options(tmp_path):
    p = subprocess.run([sys.executable, DEMO, "--out", str(tmp_path), "--axial-strain", "-1"],
                       capture_output=True, text=True)
    assert p.returncode != 0 and "axial-strain" in p.stderr
    p = subprocess.run([sys.executable, DEMO, "--frobnicate"], capture_output=True, text=True)
    assert p.returncode != 0 and "unrecognized" in p.stderr


@pytest.mark.slow
def test_demo_default_run(tmp_path):
    """000 Table 3 parameters: the stress ratio peaks then softens, the sample dilates."""
    rows, summary = run_demo(tmp_path)
    data = np.array(rows[1:], dtype=float)
    assert 0.25 < summary["peak_stress_ratio"] < 0.6
    assert data[-1, 1] < summary["peak_stress_ratio"]
    assert data[-1, 2] > 0.0 and summary["increments_not_converged"] == 0


def test_fabric_anisotropy_control():
    st, info = dc.generate_packing(100, pressure=10.0, seed=2, anisotropy=0.05)
    a = dc.DemCell(st).homogenized().anisotropy
    assert a == pytest.approx(info["anisotropy"])
    errors = [abs(t[1] - 0.05) for t in info["anisotropy_trials"]]
    assert abs(a - 0.05) == pytest.approx(min(errors))
