"""demos/biaxial.py run as a user runs it (small meshes): outputs, the band measured by
the section 4.4 fit, the classical switch, and the same load-displacement curve on 1 and
2 MPI ranks (issue 3 items 5, 10). Launches processes (mpirun too): serial pass only."""
import json

import numpy as np
import pytest

from conftest import read_summary

pytestmark = pytest.mark.serial
SMALL = ["--cell-size", 0.005, "--width", 0.025, "--height", 0.05]


def history(out):
    return np.genfromtxt(out / "history.csv", delimiter=",", names=True)


def test_demo_outputs_and_band(demo, tmp_path):
    demo("biaxial", *SMALL, "--axial-strain", 0.065, "--steps", 30, "--out", tmp_path)
    s = read_summary(tmp_path)
    for key in ("peak_vertical_stress", "band_thickness", "band_inclination_deg"):
        assert np.isfinite(s[key])
    # peak near the homogeneous plane-strain value -0.69 MN/m^2 (docs/reference/ehlers.md), lowered by
    # the imperfection; a post-peak drop from the band
    assert -0.72e6 < s["peak_vertical_stress"] < -0.6e6
    assert s["final_vertical_stress"] > 0.9 * s["peak_vertical_stress"]
    assert s["completed"] and s["steps"] > 30
    # band: a few mm wide (H is the standard deviation), inclined 45-70 deg to the horizontal
    assert 0.3e-3 < s["band_thickness"] < 5e-3
    assert 45.0 < s["band_inclination_deg"] < 70.0
    h = history(tmp_path)
    assert {"axial_strain", "vertical_stress", "volumetric_strain", "plastic_fraction"} <= set(h.dtype.names)
    assert len(h) == s["steps"]
    # phase 1 ends with the platen carrying the confining pressure (weak zone: within 1 %)
    consolidated = h["vertical_stress"][h["phase"] == 1][-1]
    assert consolidated == pytest.approx(-100e3, rel=0.01)
    # outside the band the wedges unload: part of the Gauss points stops flowing
    assert h["plastic_fraction"][-1] < 0.8
    assert (tmp_path / "biaxial.png").exists() and (tmp_path / "fields.h5").exists()
    xdmf = (tmp_path / "fields.xdmf").read_text()
    for name in ("rotation", "couple_stress", "plastic_strain", "yield_function", "plastic"):
        assert f'Name="{name}"' in xdmf
    residuals = s["newton_residuals_longest_plastic_step"]
    assert residuals[-1] < 1e-8 * residuals[0]


def test_classical_switch(demo, tmp_path):
    demo("biaxial", *SMALL, "--classical", "--axial-strain", 0.05, "--steps", 20, "--out", tmp_path)
    s = read_summary(tmp_path)
    assert s["classical"] and s["mu_c"] == 0.0
    assert -0.72e6 < s["peak_vertical_stress"] < -0.6e6
    xdmf = (tmp_path / "fields.xdmf").read_text()
    assert 'Name="rotation"' not in xdmf and 'Name="couple_stress"' not in xdmf


def test_bad_option_is_named(demo, tmp_path):
    proc = demo("biaxial", "--weak-factor", 1.5, "--out", tmp_path, check=False)
    assert proc.returncode == 2 and "--weak-factor" in proc.stderr


def test_one_and_two_ranks_give_the_same_curve(demo, tmp_path):
    """The Gauss-point work follows the mesh partition; the load-displacement curve is the
    same on 1 and 2 ranks to the solver tolerance (SNES rtol 1e-10), through the peak and
    the formation of the band (the stress drops, most points unload) with its cut-backs."""
    curves = []
    for ranks in (1, 2):
        out = tmp_path / f"n{ranks}"
        demo("biaxial", *SMALL, "--axial-strain", 0.065, "--steps", 30, "--out", out, ranks=ranks)
        curves.append(history(out))
        assert read_summary(out)["ranks"] == ranks
    a, b = curves
    assert a["plastic_fraction"][-1] < 0.8 and a["vertical_stress"][-1] > 0.9 * a["vertical_stress"].min()
    assert len(a) == len(b) and np.array_equal(a["time"], b["time"])
    scale = np.abs(a["vertical_stress"]).max()
    assert np.abs(a["vertical_stress"] - b["vertical_stress"]).max() < 1e-7 * scale
    assert np.abs(a["volumetric_strain"] - b["volumetric_strain"]).max() < 1e-9
