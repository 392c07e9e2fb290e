"""demos/footing_bsm.py stopped and continued as a batch queue runs it (docs/reference/restart.md):
--stop-after K then --restart DIR gives the straight run's history.csv, summary numbers, XDMF
datasets and grain files bit for bit, on 1 and on 2 ranks; SIGTERM ends the run after its
coarse step with a checkpoint that continues it; a damaged, foreign or other-rank-count
checkpoint is refused in one line before any work."""
import json
import os
import shutil
import signal
import subprocess
import sys
import time

import h5py
import numpy as np
import pytest

from conftest import ROOT, read_summary

pytestmark = pytest.mark.serial

TINY = ("--packing", "A", "--depth", 0.004, "--record-every", 4, "--output-every", 2)
NUMBERS = ("final_settlement_mm", "final_load_kN_per_m", "peak_load_kN_per_m", "peak_settlement_mm",
           "max_mismatch_over_rmin", "coarse_steps", "steps_completed", "completed")


def h5_datasets(path):
    out = {}
    with h5py.File(path, "r") as f:
        f.visititems(lambda name, obj: out.__setitem__(name, obj[()]) if isinstance(obj, h5py.Dataset) else None)
    return out


def history(path):
    lines = (path / "history.csv").read_text().splitlines()
    return lines[0], np.array([[float(v) for v in line.split(",")] for line in lines[1:]])


def assert_same_run(a, b):
    """Every written digit: history.csv, the summary's numbers, the XDMF datasets, the grain
    files and their series."""
    assert (a / "history.csv").read_bytes() == (b / "history.csv").read_bytes()
    sa, sb = read_summary(a), read_summary(b)
    assert {k: sa[k] for k in NUMBERS} == {k: sb[k] for k in NUMBERS}
    da, db = h5_datasets(a / "continuum.h5"), h5_datasets(b / "continuum.h5")
    assert sorted(da) == sorted(db) and len(da) > 3
    for name in da:
        assert np.array_equal(da[name], db[name]), name
    assert (a / "grains.vtk.series").read_bytes() == (b / "grains.vtk.series").read_bytes()
    series = json.loads((a / "grains.vtk.series").read_text())["files"]
    assert len(series) >= 3
    for entry in series:
        assert (a / entry["name"]).read_bytes() == (b / entry["name"]).read_bytes(), entry["name"]


def assert_close_run(a, b, rtol=1e-9):
    """The same run with the continuum's sums in another order (another partition)."""
    (ha, va), (hb, vb) = history(a), history(b)
    assert ha == hb and va.shape == vb.shape
    assert np.allclose(va, vb, rtol=rtol, atol=1e-12)
    sa, sb = read_summary(a), read_summary(b)
    for k in NUMBERS:
        assert np.isclose(sa[k], sb[k], rtol=rtol), k


@pytest.fixture(scope="module")
def straight(tmp_path_factory):
    """The tiny footing run straight through on one rank (the reference of every test)."""
    from conftest import run_demo
    out = tmp_path_factory.mktemp("straight")
    run_demo("footing_bsm", *TINY, "--out", out)
    return out


def refused(demo, out, *extra, match):
    proc = demo("footing_bsm", "--restart", out, *extra, check=False)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and match in lines[0], proc.stderr
    assert "continuing" not in proc.stdout


def test_stop_and_restart_is_the_straight_run(demo, tmp_path, straight):
    """--stop-after 10 --checkpoint-every 4, bad restarts refused on its checkpoint (which is
    left usable), then --restart: every written digit of the straight run."""
    part = tmp_path / "part"
    demo("footing_bsm", *TINY, "--out", part, "--stop-after", 10, "--checkpoint-every", 4)
    first = read_summary(part)
    assert not first["completed"] and "--restart" in first["reason"] and first["steps_completed"] == 10
    assert first["checkpoint_steps_written"] == [4, 8, 10]
    refused(demo, part, "--packing", "B", match="--packing cannot be given with --restart")
    refused(demo, part, "--stop-after", 6, match="is at step 10 already")
    meta_path = part / "checkpoint" / "meta.json"
    meta = meta_path.read_text()
    meta_path.write_text(meta.replace('"footing_bsm"', '"dem_specimen"'))
    refused(demo, part, match="is of 'dem_specimen', not 'footing_bsm'")
    meta_path.write_text(meta)
    state = part / "checkpoint" / "state_0.npz"
    data = state.read_bytes()
    state.write_bytes(data[: len(data) // 2])
    refused(demo, part, match="cannot read")
    state.write_bytes(data)
    proc = demo("footing_bsm", "--restart", part)
    assert "continuing from the checkpoint of step 10" in proc.stdout
    summary = read_summary(part)
    assert summary["completed"] and summary["restarted_from_step"] == 10
    assert summary["checkpoint_steps_written"] == [12, 16, 20, 24, 28]   # --checkpoint-every carried over
    assert_same_run(straight, part)


def test_gravity_settles_then_stops_and_restarts_as_the_straight_run(demo, tmp_path):
    """--gravity: the settling steps come first (0.01 s of coarse steps), the plate is put
    on the settled surface and the history starts there; stopped in the loading and continued,
    every written digit of the straight run (the Coulomb lattice outside the region: its
    Gauss-point history is in the checkpoint)."""
    straight, part = tmp_path / "straight", tmp_path / "part"
    gravity = ("--gravity", 9.81, "--settle-time", 0.01, "--continuum", "lattice-coulomb", "--bottom", "smooth")
    demo("footing_bsm", *TINY, *gravity, "--out", straight)
    summary = read_summary(straight)
    assert summary["bottom"] == "smooth"
    settle = summary["settle_steps"]
    assert settle == round(0.01 / summary["dt"]) and summary["surface_drop_mm"] > 0.0
    assert summary["steps_completed"] == settle + summary["coarse_steps"]
    _, rows = history(straight)
    assert rows[0, 0] == settle and rows[0, 2] == 0.0            # step, settlement of the first row
    demo("footing_bsm", *TINY, *gravity, "--out", part, "--stop-after", settle + 10)
    assert read_summary(part)["steps_completed"] == settle + 10
    demo("footing_bsm", "--restart", part)
    assert_same_run(straight, part)
    # the smooth base (the full DEM's wall): the base slides under the weight (fixed: u1 = 0
    # exactly), u2 stays 0
    state = np.load(part / "checkpoint" / "state_0.npz")
    base = np.isclose(state["continuum_dof_coordinates"][:, 1], 0.0)
    component = state["continuum_dof_component"]
    d = state["continuum_displacement"]
    assert np.count_nonzero(d[base & (component == 0)]) > 0
    assert np.all(d[base & (component == 1)] == 0.0)
    assert read_summary(part)["bottom"] == "smooth"             # carried by the restart


def test_coulomb_lattice_checkpoint_of_two_ranks_continues_on_one(demo, tmp_path):
    """The Gauss-point history of the Coulomb lattice is matched by the points' coordinates:
    a 2-rank checkpoint continues on 1 rank, within round-off of the 1-rank straight run."""
    options = (*TINY, "--gravity", 9.81, "--settle-time", 0.01, "--continuum", "lattice-coulomb")
    straight, two = tmp_path / "straight", tmp_path / "two"
    demo("footing_bsm", *options, "--out", straight)
    demo("footing_bsm", *options, "--out", two, "--stop-after", read_summary(straight)["settle_steps"] + 10,
         ranks=2)
    demo("footing_bsm", "--restart", two)
    assert read_summary(two)["completed"] and read_summary(two)["restarted_from_ranks"] == 2
    assert_close_run(straight, two, rtol=1e-6)


def test_two_ranks_stop_and_continue_on_two_and_on_one(demo, tmp_path, straight):
    """A 2-rank checkpoint continues on 2 ranks and on 1 (the continuum matched by dof
    coordinates): the straight run within round-off (1 and 2 ranks sum in another order, and
    dolfinx's 2-rank partition is not the same in every run), the rows before the checkpoint
    as written."""
    two, one = tmp_path / "two", tmp_path / "one"
    demo("footing_bsm", *TINY, "--out", two, "--stop-after", 12, ranks=2)
    shutil.copytree(two, one)
    demo("footing_bsm", "--restart", two, ranks=2)
    demo("footing_bsm", "--restart", one)
    for out in (two, one):
        summary = read_summary(out)
        assert summary["completed"] and summary["restarted_from_ranks"] == 2
        assert_close_run(straight, out)
    assert (one / "continuum_from_step12.xdmf").exists()
    assert "continuum_from_step12.xdmf" in (one / "paraview_footing.py").read_text()


def test_sigterm_ends_after_the_step_with_a_checkpoint(demo, tmp_path, straight):
    """A SIGTERM in the middle of the run: the step ends, a checkpoint is written, summary.json
    names the signal, and --restart finishes the straight run bit for bit."""
    out = tmp_path / "killed"
    env = dict(os.environ, OMP_NUM_THREADS="1")
    # summary.json after every recorded step, so that the test sees the run's progress
    proc = subprocess.Popen([sys.executable, os.path.join(ROOT, "demos", "footing_bsm.py"), *map(str, TINY),
                             "--summary-interval", "0", "--out", str(out)],
                            cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        try:
            if read_summary(out).get("steps_completed", 0) >= 3:
                break
        except (OSError, ValueError):
            pass
        time.sleep(0.01)
    proc.send_signal(signal.SIGTERM)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 128 + signal.SIGTERM, stdout + stderr
    summary = read_summary(out)
    step = summary["steps_completed"]
    assert 3 <= step < 28
    assert summary["reason"] == (f"interrupted by SIGTERM after step {step} (checkpoint written: continue with "
                                 f"--restart {out})")
    with open(out / "checkpoint" / "meta.json") as f:
        assert json.load(f)["step"] == step
    demo("footing_bsm", "--restart", out)
    assert_same_run(straight, out)
