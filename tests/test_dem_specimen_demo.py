"""demos/dem_specimen.py as a user runs it: outputs, restart bit for bit, signals, bad input."""
import json
import os
import shutil
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from conftest import ROOT, run_demo

pytestmark = pytest.mark.serial

SMALL = ["--nx", 10, "--ny", 20, "--duration", 4, "--output-every", 0.5, "--snapshots", "0,2,4", "--threads", 1]


def _history(path):
    return np.genfromtxt(path, delimiter=",", names=True)


def test_small_thesis_specimen_writes_every_output(tmp_path):
    proc = run_demo("dem_specimen", *SMALL, "--out", tmp_path)
    summary = json.load(open(tmp_path / "summary.json"))
    assert summary["completed"] is True and summary["n_discs"] == 200
    assert summary["isotropic"]["wall_stress"][0] == pytest.approx(-50.0, rel=2e-3)
    h = _history(tmp_path / "history.csv")
    assert h["time"][0] == 0.0 and h["time"][-1] == pytest.approx(4.0)
    assert np.all(np.diff(h["axial_strain"]) < 0)          # the platens close
    # 0.06 m/s closing over 4 s of a 35.6 m high specimen
    assert h["axial_strain"][-1] == pytest.approx(-0.24 / summary["isotropic"]["height"], rel=1e-6)
    assert np.all(h["lateral_stress"] == -50.0) and np.all(np.isfinite(h["stress_ratio"]))
    assert len(summary["bands"]) == 3 and len(summary["balance"]) == 3
    for k in range(3):
        assert (tmp_path / "particles" / f"particles_{k:04d}.vtk").is_file()
        assert (tmp_path / f"band_{k:04d}.png").is_file()
    assert (tmp_path / "curve.png").is_file()
    assert "snapshot 2 at t = 4 s" in proc.stdout
    if shutil.which("pvbatch") and shutil.which("xvfb-run"):      # what a user opens in ParaView
        from test_paraview import pvbatch_json
        grid = pvbatch_json(os.path.join(ROOT, "tests", "paraview_check.py"), tmp_path / "grains.xdmf",
                            tmp_path / "grid.png", "eps_norm")
        assert grid["times"] == pytest.approx([0.0, 2.0, 4.0]) and "skew" in grid["arrays"]
        discs = pvbatch_json(os.path.join(ROOT, "tests", "paraview_vtk_check.py"),
                             tmp_path / "particles" / "particles_0002.vtk")
        assert discs["points"] == 200 and {"eps_norm", "displacement", "rotation"} <= set(discs["arrays"])


def test_stop_and_restart_give_the_straight_run_bit_for_bit(tmp_path):
    straight, split = tmp_path / "straight", tmp_path / "split"
    run_demo("dem_specimen", *SMALL, "--out", straight)
    run_demo("dem_specimen", *SMALL, "--stop-after", 1.5, "--out", split)
    stopped = json.load(open(split / "summary.json"))
    assert stopped["completed"] is False and stopped["reason"] == "--stop-after"
    run_demo("dem_specimen", *SMALL, "--restart", split / "checkpoint.npz", "--out", split)
    a, b = (open(p / "history.csv").read() for p in (straight, split))
    assert a == b
    sa, sb = (json.load(open(p / "summary.json")) for p in (straight, split))
    assert sb["completed"] is True and sa["bands"] == sb["bands"] and sa["peak_stress_ratio"] == sb["peak_stress_ratio"]
    # the fields written after the restart lie on the same grid, with the same values
    assert (straight / "grains.xdmf").read_text() == (split / "grains.xdmf").read_text()
    assert (straight / "grains_0002.bin").read_bytes() == (split / "grains_0002.bin").read_bytes()


@pytest.mark.parametrize("content", [b"", b"PK\x03\x04 not a zip", None])
def test_a_damaged_checkpoint_is_refused_in_one_line(tmp_path, content):
    checkpoint = tmp_path / "checkpoint.npz"
    if content is None:          # a real .npz of something else, without the demo's .json
        np.savez(checkpoint, a=np.ones(3))
    else:
        checkpoint.write_bytes(content)
    proc = run_demo("dem_specimen", *SMALL, "--restart", checkpoint, "--out", tmp_path / "out", check=False)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "not a checkpoint of this demo" in lines[0]


def test_sigint_leaves_readable_outputs(tmp_path):
    cmd = [sys.executable, os.path.join(ROOT, "demos", "dem_specimen.py"), "--nx", 10, "--ny", 20, "--duration",
           200, "--output-every", 0.5, "--threads", 1, "--out", tmp_path]
    proc = subprocess.Popen([str(c) for c in cmd], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            cwd=ROOT)
    deadline = time.time() + 240
    while time.time() < deadline:
        if (tmp_path / "history.csv").is_file() and len(open(tmp_path / "history.csv").readlines()) > 4:
            break
        time.sleep(0.5)
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 128 + signal.SIGINT, err
    summary = json.load(open(tmp_path / "summary.json"))
    assert summary["completed"] is False and "interrupted by SIGINT" in summary["reason"]
    h = _history(tmp_path / "history.csv")
    assert h.size >= 4 and np.all(np.isfinite(h["axial_strain"]))


@pytest.mark.parametrize("args, words", [
    (["--nx", 1], "--nx"),
    (["--tiles", "0x2", "--specimen", "tiled"], "--tiles"),
    (["--anisotropy", "1.5", "--specimen", "tiled"], "--anisotropy"),
    (["--anisotropy", "0.05"], "--specimen tiled"),
    (["--pressure", "-1"], "--pressure"),
    (["--dt", "nan"], "--dt"),
    (["--dt", 10], "stability limit"),
    (["--duration", 10, "--axial-strain", 0.01], "not both"),
    (["--specimen", "file"], "--packing"),
    (["--specimen", "file", "--packing", "/nonexistent.npz"], "not found"),
    (["--snapshots", "1,x"], "--snapshots"),
    (["--restart", "/nonexistent.npz"], "--restart"),
])
def test_bad_input_is_refused_in_one_line(tmp_path, args, words):
    proc = run_demo("dem_specimen", *args, "--out", tmp_path, check=False, timeout=120)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and words in lines[0]
    assert not (tmp_path / "summary.json").exists()


def test_the_last_snapshot_is_taken_at_the_end_of_the_run(tmp_path):
    """The default snapshots (5 over the run) include the end: the run stops on a whole step,
    up to one time step short of the duration, and that row is the last snapshot."""
    run_demo("dem_specimen", "--specimen", "tiled", "--tiles", "1x2", "--axial-strain", 0.003, "--threads", 1,
             "--out", tmp_path)
    summary = json.load(open(tmp_path / "summary.json"))
    assert [f"fields_{k:04d}.npz" for k in range(5)] == sorted(
        f for f in os.listdir(tmp_path / "particles") if f.startswith("fields_"))
    assert summary["snapshots_done"][-1] == pytest.approx(summary["final_time"])
