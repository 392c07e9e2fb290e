"""Results do not depend on the number of ranks (demos run with mpirun -n 1 and -n 2)."""
import numpy as np
import pytest

from conftest import read_summary

pytestmark = pytest.mark.serial


@pytest.mark.parametrize("ranks", [2])
def test_shear_layer_same_on_1_and_2_ranks(demo, tmp_path, ranks):
    profiles = {}
    for n in (1, ranks):
        out = tmp_path / f"np{n}"
        demo("shear_layer", "--l-c", 0.01, "--top-rotation", "free", "--steps", 2, "--out", out, ranks=n)
        profiles[n] = np.genfromtxt(out / "profile.csv", delimiter=",", names=True)
        history = np.genfromtxt(out / "history.csv", delimiter=",", names=True)
        profiles[n, "reaction"] = history["reaction_x_top"]
    for key in ("u1", "phi"):
        a, b = profiles[1][key], profiles[ranks][key]
        assert np.abs(a - b).max() <= 1e-9 * np.abs(a).max()
    assert np.allclose(profiles[1, "reaction"], profiles[ranks, "reaction"], rtol=1e-9)


def test_hole_plate_same_on_1_and_2_ranks(demo, tmp_path):
    scf = []
    for n in (1, 2):
        demo("hole_plate", "--radius", 0.01, "--out", tmp_path / f"np{n}", ranks=n)
        scf.append(read_summary(tmp_path / f"np{n}")["scf"])
    assert scf[0] == pytest.approx(scf[1], rel=1e-9)


def test_explicit_dynamics_same_on_1_and_2_ranks(tmp_path):
    """The standing P wave of benchmarks/verification/explicit_dynamics.py (Q1 and P2, power-
    iteration step, 1.6 periods) gives the same series on 1 and 2 ranks to round-off."""
    import json
    import os
    import subprocess
    import sys
    from conftest import ROOT
    series = {}
    for n in (1, 2):
        out = tmp_path / f"np{n}"
        cmd = ["mpirun", "-n", str(n), sys.executable, os.path.join(ROOT, "benchmarks", "verification",
               "explicit_dynamics.py"), "--meshes", "8", "--periods", "1.6", "--series", "--out", str(out)]
        env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
                   OMPI_MCA_rmaps_base_oversubscribe="1", OMP_NUM_THREADS="1",
                   PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300, env=env, cwd=ROOT)
        assert proc.returncode == 0, proc.stderr[-3000:]
        with open(out / "summary.json") as f:
            series[n] = {r["element"]: r for r in json.load(f)["rows"]}
    for element, one in series[1].items():
        two = series[2][element]
        assert two["ranks"] == 2 and one["dofs"] == two["dofs"] and one["steps"] == two["steps"]
        assert two["dt_power"] == pytest.approx(one["dt_power"], rel=1e-12)
        a, b = np.array(one["series"]), np.array(two["series"])
        assert np.abs(a - b).max() <= 1e-10 * np.abs(a).max()
