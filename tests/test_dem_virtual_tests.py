"""benchmarks/dem/dem_virtual_tests.py: bad options refused before any work, and a tiny run
(40 discs, 2 seeds, 0.6 % axial strain, a few seconds) whose ensemble files are the mean and
sample std (thesis eq. 4.26) of the seed files, in the material-point driver's columns."""
import csv
import json
import os
import subprocess
import sys

import numpy as np
import pytest

pytestmark = pytest.mark.serial          # no MPI content: the serial pass only
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCRIPT = os.path.join(ROOT, "benchmarks", "dem", "dem_virtual_tests.py")
ENV = dict(os.environ, PYTHONPATH=ROOT)      # the repository root on the path, as the Makefile sets it


def run(*args, **kw):
    return subprocess.run([sys.executable, SCRIPT, *map(str, args)], capture_output=True, text=True,
                          timeout=120, env=ENV, **kw)


def read(path):
    with open(path) as f:
        rows = list(csv.reader(f))
    return rows[0], np.array(rows[1:], dtype=float)


@pytest.mark.parametrize("args, message", [
    (["--seeds", "1"], "--seeds"),
    (["--discs", "5"], "--discs"),
    (["--increment", "0.2"], "--increment"),
    (["--grid-step", "1e-5"], "--grid-step"),
    (["--relaxation-tol", "0"], "--relaxation-tol"),
    (["--confining", "8"], "--isotropic-max"),
    (["--confining", "0.5"], "--confining"),
    (["--confining", "2", "2"], "repeated"),
    (["--isotropic-max", "20"], "granular"),
    (["--pressure", "-1"], "--pressure"),
    (["--lateral-control", "stress"], "--lateral-control"),
])
def test_bad_options_refused(tmp_path, args, message):
    out = tmp_path / "out"
    p = run("--out", out, *args)
    assert p.returncode == 2, p.stderr
    assert message in p.stderr and len(p.stderr.strip().splitlines()) == 1
    assert not out.exists()          # refused before any work


def test_tiny_run_ensemble_is_mean_and_std_of_the_seeds(tmp_path):
    p = run("--out", tmp_path, "--discs", 40, "--seeds", 2, "--axial-strain", 0.006, "--increment", 0.002, "--grid-step", 0.002,
            "--confining", 1, 3, "--isotropic-max", 3, "--isotropic-steps", 4)
    assert p.returncode == 0, p.stderr
    summary = json.load(open(tmp_path / "summary.json"))
    assert summary["completed"] and summary["tests"] == ["isotropic", "biaxial_10Pa", "biaxial_30Pa"]
    for name in ("biaxial_10Pa", "biaxial_30Pa"):
        cols, ens = read(tmp_path / f"{name}.csv")
        assert cols[:5] == ["axial_strain", "axial_stress", "volumetric_strain", "axial_stress_std",
                            "volumetric_strain_std"]
        seeds = [read(tmp_path / f"seed{k}" / f"{name}.csv") for k in (0, 1)]
        assert seeds[0][0][:3] == ["axial_strain", "axial_stress", "volumetric_strain"]
        sig = np.array([s[1][:, 1] for s in seeds])
        # the seeds' abscissae are the nominal axial strains, so interpolation is exact here
        np.testing.assert_allclose(seeds[0][1][:, 0], ens[:, 0], atol=1e-12)
        np.testing.assert_allclose(ens[:, 1], sig.mean(axis=0), rtol=1e-8)
        np.testing.assert_allclose(ens[:, 3], np.abs(sig[0] - sig[1]) / np.sqrt(2.0), rtol=1e-6, atol=1e-9)
        pc = float(name.split("_")[1][:-2])
        assert ens[0, 1] == pytest.approx(-pc, rel=2e-3) and ens[-1, 0] == pytest.approx(-0.006)
        assert np.all(sig[:, -1] < -pc)                        # compression raises |sigma_11|
        for k in (0, 1):
            s = summary["per_seed"][name][str(k)]
            assert s["peak_axial_stress"] == pytest.approx(sig[k].min())
    cols, iso = read(tmp_path / "isotropic.csv")
    assert cols[:3] == ["pressure", "volumetric_strain", "volumetric_strain_std"]
    np.testing.assert_allclose(iso[:, 0], [10, 15, 20, 25, 30])
    assert iso[0, 1] == pytest.approx(0.0, abs=1e-6) and np.all(np.diff(iso[:, 1]) < 0)   # compaction
    assert os.path.exists(tmp_path / "dem_virtual_tests.png")
