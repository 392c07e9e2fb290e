"""Hole plate: micropolar closed form of the stress concentration and its Cauchy limit."""
import pytest

from conftest import read_summary

pytestmark = pytest.mark.serial


@pytest.mark.parametrize("radius, mu_c", [(0.01, 1e8), (0.005, 2e7), (0.005, 5e8)])
def test_scf_against_micropolar_closed_form(demo, tmp_path, radius, mu_c):
    """Coupling numbers N^2 = 1/2, 1/6 and 5/6 (mu = 1e8 Pa), a / l_c = 1 and 0.5."""
    demo("hole_plate", "--radius", radius, "--l-c", 0.01, "--mu-c", mu_c, "--fields", "displacement",
         "--out", tmp_path)
    s = read_summary(tmp_path)
    assert 1.8 < s["scf_closed_form"] < 2.7          # well away from Kirsch
    assert s["scf"] == pytest.approx(s["scf_closed_form"], rel=0.005)


def test_cauchy_scene_gives_kirsch(demo, tmp_path):
    demo("hole_plate", "--cauchy", "--radius", 0.01, "--out", tmp_path)
    s = read_summary(tmp_path)
    assert s["scf"] == pytest.approx(3.0, rel=0.015)


def test_vanishing_internal_length_tends_to_cauchy(demo, tmp_path):
    scf = {}
    for flag in ("--cauchy", None):
        args = ["--radius", 0.01, "--l-c", 1e-5, "--out", tmp_path]
        demo("hole_plate", *(args + ([flag] if flag else [])))
        scf[flag] = read_summary(tmp_path)["scf"]
    assert scf[None] == pytest.approx(scf["--cauchy"], rel=2e-3)
