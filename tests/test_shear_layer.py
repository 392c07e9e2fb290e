"""Shear layer against its closed form (analytic.shear_layer) at several l_c, mu_c and
both top conditions; run as a user runs the demo."""
import math

import numpy as np
import pytest

from conftest import read_summary

pytestmark = pytest.mark.serial
MU = 1.0e8
HEIGHT = 0.1


@pytest.mark.parametrize("l_c, mu_c_ratio, top", [
    (0.01, 1.0, "fixed"), (0.01, 1.0, "free"), (0.005, 0.1, "fixed"),
    (0.02, 10.0, "free"), (0.05, 1.0, "fixed")])
def test_against_closed_form(demo, tmp_path, l_c, mu_c_ratio, top):
    ell = l_c * math.sqrt((1 + mu_c_ratio) / 2)
    h = min(ell / 4, HEIGHT / 40)
    demo("shear_layer", "--l-c", l_c, "--mu", MU, "--mu-c", mu_c_ratio * MU, "--top-rotation", top,
         "--cell-size", h, "--width", 4 * h, "--height", HEIGHT, "--out", tmp_path)
    s = read_summary(tmp_path)
    assert s["max_error_u1_relative"] < 2e-3
    assert s["max_error_phi_relative"] < 2e-2
    assert s["shear_stress_fe"] == pytest.approx(s["shear_stress_exact"], rel=2e-3)
    profile = np.genfromtxt(tmp_path / "profile.csv", delimiter=",", names=True)
    assert set(profile.dtype.names) >= {"x2", "u1", "phi"}
    assert (tmp_path / "profile.png").exists() and (tmp_path / "fields.h5").exists()


def test_error_decreases_with_refinement(demo, tmp_path):
    errors = []
    for h in (0.01, 0.005, 0.0025):
        demo("shear_layer", "--cell-size", h, "--width", 4 * h, "--out", tmp_path)
        errors.append(read_summary(tmp_path)["max_error_phi_relative"])
    assert errors[0] > 3 * errors[1] > 9 * errors[2]


def test_small_length_approaches_classical_simple_shear(demo, tmp_path):
    """l_c << H: sigma12 -> mu shift / H and, outside the boundary layers, phi equals the
    macro-rotation -u1,2 / 2 (the Cauchy limit). The layers must still be resolved
    (h ~ ell / 4): a fixed rotation on an unresolved layer stiffens the element row."""
    l_c = 1.0e-3
    demo("shear_layer", "--l-c", l_c, "--top-rotation", "free", "--cell-size", l_c / 4,
         "--width", l_c, "--out", tmp_path)
    s = read_summary(tmp_path)
    shift = 1.0e-3
    assert s["shear_stress_fe"] == pytest.approx(s["shear_stress_exact"], rel=2e-3)
    assert s["shear_stress_fe"] == pytest.approx(MU * shift / HEIGHT, rel=2e-2)
    profile = np.genfromtxt(tmp_path / "profile.csv", delimiter=",", names=True)
    inner = (profile["x2"] > 0.02) & (profile["x2"] < 0.08)
    macro_rotation = -0.5 * np.gradient(profile["u1"], profile["x2"])
    assert np.allclose(profile["phi"][inner], macro_rotation[inner], rtol=1e-3)


def test_closed_form_limit():
    """The closed form itself tends to classical simple shear as l_c -> 0."""
    from cosserat_fenicsx.analytic import shear_layer
    u1, phi, tau = shear_layer(np.linspace(0, HEIGHT, 11), HEIGHT, 1e-3, MU, MU, 1e-9, "fixed")
    assert tau == pytest.approx(MU * 1e-3 / HEIGHT, rel=1e-6)
    assert np.allclose(phi[1:-1], -0.5e-3 / HEIGHT, rtol=1e-6)
