"""benchmarks/bsm/footing_bands.py against fields with a known answer on the grains of 003's
packing A (the 6 x 3 m region under the plate): an affine shear (exact strain), a rigid wedge
under the plate sliding down between two bands of known inclination (a V), and a surface block
pushed out along outward bands (no V)."""
import math

import numpy as np
import pytest

from benchmarks.bsm.footing_bands import analyse, equivalent_strain, softening
from demcell.specimen.files import read_particles_vtk, write_particles_vtk
from demcell.specimen.footing import footing_packing

PLATE = (8.0, 10.0)


@pytest.fixture(scope="module")
def grains():
    discs = footing_packing("A", (6.0, 12.0, 6.0, 9.0))
    p, r = discs.position, discs.radius
    under = (p[:, 0] + r > PLATE[0]) & (p[:, 0] - r < PLATE[1])
    return p, float(np.max(p[under, 1] + r[under]))


def smooth_step(d, w=0.06):
    return 0.5 * (1.0 + np.tanh(d / w))


def test_affine_shear_is_exact(grains):
    p, _ = grains
    gamma = 2e-3
    eps, grad = equivalent_strain(p, np.column_stack([gamma * p[:, 1], np.zeros(len(p))]))
    assert np.allclose(grad[:, 0, 1], gamma, atol=1e-12)
    assert np.allclose(eps, gamma / math.sqrt(3.0), rtol=1e-9)      # sqrt(2/3 e:e), e12 = gamma / 2


@pytest.mark.parametrize("theta", [45.0, 60.0, 35.0])
def test_wedge_between_two_bands(grains, theta):
    """Grains inside the wedge under the plate, bounded by lines leaving the plate edges at
    theta [deg] from the horizontal, move down by 10 mm: a V of known inclination."""
    p, top = grains
    t = math.radians(theta)
    # signed distances to the two lines, positive inside the wedge
    d_left = (p[:, 0] - PLATE[0]) * math.sin(t) + (p[:, 1] - top) * math.cos(t)
    d_right = (PLATE[1] - p[:, 0]) * math.sin(t) + (p[:, 1] - top) * math.cos(t)
    du = np.zeros_like(p)
    du[:, 1] = -0.01 * smooth_step(d_left) * smooth_step(d_right)
    res, _, _ = analyse(p, du, PLATE, top)
    b = res["bands"]
    assert b["v_shape"]
    for side in ("left", "right"):
        assert abs(b[side]["inclination_deg"] - theta) <= 3.0, (side, b[side])
        assert abs(b[side]["origin_shift_m"]) <= 0.15
        assert b[side]["contrast"] > 5.0
    fits = res["fit_band"]        # fit_band's sign: a V has the left band falling towards +x
    assert fits["left"]["inclination_deg"] == pytest.approx(-theta, abs=1.5)
    assert fits["right"]["inclination_deg"] == pytest.approx(theta, abs=1.5)


def test_outward_bands_are_not_a_v(grains):
    """A block beside each plate edge, above a line leaving the edge outwards at 40 degrees,
    pushed up and out along that line: bands, but no wedge under the plate."""
    p, top = grains
    theta = math.radians(40.0)
    du = np.zeros_like(p)
    for x_edge, out in ((PLATE[0], -1.0), (PLATE[1], 1.0)):
        along = np.array([out * math.cos(theta), math.sin(theta)])          # up the band, outwards
        d = (p[:, 1] - top) * math.cos(theta) + out * (p[:, 0] - x_edge) * math.sin(theta)   # > 0 above the line
        beside = out * (p[:, 0] - x_edge) > -0.2
        du += 0.01 * (smooth_step(d) * beside)[:, None] * along
    res, _, _ = analyse(p, du, PLATE, top)
    b = res["bands"]
    assert not b["v_shape"]
    for side in ("left", "right"):
        assert not b[side]["inward"]
        assert abs(b[side]["inclination_deg"] - 40.0) <= 3.0, (side, b[side])


def test_softening():
    s = np.linspace(0.0, 60.0, 61)
    f = np.where(s < 38.0, 100.0 * s / 38.0, 100.0 - (s - 38.0))
    res = softening(s, f)
    assert res["peak_at_mm"] == 38.0 and res["peak_kN_per_m"] == pytest.approx(100.0)
    assert res["drop"] == pytest.approx(0.22)


def test_particles_vtk_round_trip(tmp_path):
    rng = np.random.default_rng(1)
    p, d = rng.random((7, 2)), rng.random((7, 2))
    write_particles_vtk(tmp_path / "g.vtk", p, np.full(7, 0.05), {"displacement": d, "virtual": np.arange(7.0)})
    q, data = read_particles_vtk(tmp_path / "g.vtk")
    assert np.array_equal(q, p) and np.array_equal(data["displacement"], d)
    assert np.array_equal(data["virtual"], np.arange(7.0)) and np.all(data["radius"] == 0.05)
