"""Specimen files: the grid series and the discs open in ParaView with the values written."""
import os
import shutil

import numpy as np
import pytest

from conftest import ROOT
from demcell.errors import InputError
from demcell.specimen.files import GridSeries, write_contacts_vtk, write_particles_vtk

# DEM only: nothing here uses MPI, so it runs in the serial pass alone
pytestmark = pytest.mark.serial

needs_paraview = pytest.mark.skipif(shutil.which("pvbatch") is None or shutil.which("xvfb-run") is None,
                                    reason="ParaView (python3-paraview) or xvfb-run not installed")


def _grid(tmp_path):
    series = GridSeries(tmp_path / "grains.xdmf", origin=(1.0, 2.0), spacing=(0.5, 0.25), shape=(4, 3))
    ramp = np.arange(12.0).reshape(3, 4)
    series.write(0.0, {"strain_norm": ramp, "skew_stress": -ramp})
    series.write(2.5, {"strain_norm": 2 * ramp, "skew_stress": np.full((3, 4), np.nan)})
    return series


def test_grid_series_files_hold_the_values(tmp_path):
    _grid(tmp_path)
    raw = np.fromfile(tmp_path / "grains_0001.bin", dtype="<f8")
    np.testing.assert_array_equal(raw[:12], 2 * np.arange(12.0))
    assert np.all(np.isnan(raw[12:]))
    text = (tmp_path / "grains.xdmf").read_text()
    assert text.count("<Grid Name=\"grains\"") == 2 and 'Seek="96"' in text


def test_grid_series_refuses_a_wrong_shape(tmp_path):
    series = GridSeries(tmp_path / "g.xdmf", origin=(0, 0), spacing=(1, 1), shape=(4, 3))
    with pytest.raises(InputError, match="shape"):
        series.write(0.0, {"a": np.zeros((4, 3))})
    with pytest.raises(InputError, match="xdmf"):
        GridSeries(tmp_path / "g.h5", origin=(0, 0), spacing=(1, 1), shape=(4, 3))


@needs_paraview
def test_grid_series_and_discs_open_in_paraview(tmp_path):
    from test_paraview import pvbatch_json
    _grid(tmp_path)
    data = pvbatch_json(os.path.join(ROOT, "tests", "paraview_check.py"), tmp_path / "grains.xdmf",
                        tmp_path / "grid.png", "strain_norm")
    assert data["times"] == pytest.approx([0.0, 2.5])
    assert data["cells"] == 12
    assert data["arrays"]["strain_norm"]["range"][0] == pytest.approx([0.0, 22.0])
    position = np.array([[0.0, 0.0], [2.0, 0.0], [1.0, 1.7]])
    write_particles_vtk(tmp_path / "particles_0000.vtk", position, np.ones(3),
                        {"rotation": [0.1, 0.2, 0.3], "displacement": np.ones((3, 2))})
    write_contacts_vtk(tmp_path / "contacts_0000.vtk", position, [0, 1], [1, 2], [5.0, 6.0], [0.5, -0.5])
    discs = pvbatch_json(os.path.join(ROOT, "tests", "paraview_vtk_check.py"), tmp_path / "particles_0000.vtk")
    assert discs["points"] == 3 and discs["arrays"]["rotation"] == pytest.approx([0.1, 0.3])
    contacts = pvbatch_json(os.path.join(ROOT, "tests", "paraview_vtk_check.py"), tmp_path / "contacts_0000.vtk")
    assert contacts["cells"] == 2 and contacts["arrays"]["normal_force"] == pytest.approx([5.0, 6.0])
