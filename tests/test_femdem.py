"""FEM x DEM (a demcell cell at every Gauss point): checks against the stand-alone cell,
finite differences of the macro residual, the classical limit of the hybrid mode, and the
rank count."""
import numpy as np
import pytest
from mpi4py import MPI

from conftest import read_summary

COMM = MPI.COMM_WORLD


def history(out):
    return np.genfromtxt(out / "history.csv", delimiter=",", names=True)


@pytest.mark.serial
@pytest.mark.parametrize("mode", ["classical", "hybrid"])
def test_homogeneous_specimen_equals_the_stand_alone_cell(demo, tmp_path, mode):
    """A 1x1 specimen with smooth platens and no imperfection deforms homogeneously: every
    Gauss point is the stand-alone cell of demos/dem_cell.py (same packing) loaded along the
    same path (straight in F from the committed state, lateral stress p0). Through the peak
    (at about 0.5 % for 100 discs) the curves agree to the relaxation tolerance; the servo
    control of dem_cell.py, a different loading path of the same frictional packing, differs
    by several times more."""
    cell = ("--particles", 100, "--seed", 0)
    demo("dem_cell", *cell, "--axial-direction", 2, "--axial-strain", 0.006, "--increment", 1e-3,
         "--lateral-control", "strain", "--out", tmp_path / "strain")
    demo("dem_cell", *cell, "--axial-direction", 2, "--axial-strain", 0.006, "--increment", 1e-3,
         "--out", tmp_path / "servo")
    demo("femdem_biaxial", *cell, "--mode", mode, "--mesh", "1x1", "--axial-strain", 0.006, "--steps", 6,
         "--out", tmp_path / "fe")
    strain, servo, fe = history(tmp_path / "strain")[1:], history(tmp_path / "servo")[1:], history(tmp_path / "fe")
    fe = fe[fe["phase"] == 2]
    assert np.allclose(fe["axial_strain"], strain["axial_strain"], atol=1e-12)
    peak = int(np.argmax(strain["stress_ratio"]))
    assert 2 <= peak            # the peak is inside the compared range
    error = np.abs(fe["stress_ratio"] / strain["stress_ratio"] - 1.0)
    assert error.max() < 4e-3, error
    assert np.abs(fe["volumetric_strain"] - strain["volumetric_strain"]).max() < 5e-5
    assert np.abs(fe["coordination_number"] - strain["coordination_number"])[:peak + 1].max() < 0.05
    path_effect = np.abs(servo["stress_ratio"] / strain["stress_ratio"] - 1.0).max()
    assert path_effect > 5 * error.max()
    summary = read_summary(tmp_path / "fe")
    assert summary["n_gauss_points"] == 6 and summary["completed"]
    assert summary["band_thickness"] is None     # homogeneous: no band is claimed
