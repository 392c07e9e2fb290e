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
