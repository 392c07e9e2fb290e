"""The DNS band measurement (benchmarks/dns/dns_band.py) on displacement increments with a
known answer, on the real grain positions of a tiled cell (2 x 4 copies of the seed-0 cell)."""
import math

import numpy as np
import pytest
from scipy.special import erf

import demcell as dc
from demcell.specimen.specimens import tiled_cell
from benchmarks.dns.dns_band import (PATCH_RADIUS, PATCH_WIDENING, SINGLE_BAND_SHARE, WIDE_PATCH_RADIUS, corrected,
                                     window_band)


@pytest.fixture(scope="module")
def grains():
    law = dc.ContactLaw(kn=1e4, ks=2e3, friction=0.4)
    state, _ = dc.generate_packing(228, pressure=10.0, law=law, seed=0)
    discs = tiled_cell(state, 2, 4)
    x = discs.position
    excluded = ((x[:, 0] < x[:, 0].min() + discs.radius.max()) | (x[:, 0] > x[:, 0].max() - discs.radius.max())
                | (x[:, 1] < x[:, 1].min() + discs.radius.max()) | (x[:, 1] > x[:, 1].max() - discs.radius.max()))
    return x, discs.radius, excluded


def shear_band(x, centre, alpha_deg, H, amplitude):
    """Displacement increment of simple shear across a band: along the band axis
    t = (cos a, sin a) by g(d), g' = amplitude exp(-d^2 / 2H^2), d the distance of
    shear_band.bell; its largest engineering shear strain is g'(d) exactly."""
    a = math.radians(alpha_deg)
    t = np.array([math.cos(a), math.sin(a)])
    d = (x[:, 1] - centre[1]) * math.cos(a) - (x[:, 0] - centre[0]) * math.sin(a)
    g = amplitude * H * math.sqrt(math.pi / 2.0) * erf(d / (math.sqrt(2.0) * H))
    return g[:, None] * t[None, :]


def snapshots(x, radius, excluded, increment):
    start = {"position": x, "radius": radius, "displacement": np.zeros_like(x), "excluded": excluded}
    end = dict(start, displacement=increment)
    return start, end


@pytest.mark.parametrize("alpha_deg,H_d50", [(55.0, 3.0), (-60.0, 4.0)])
def test_known_band_is_recovered(grains, alpha_deg, H_d50):
    x, radius, excluded = grains
    d50 = float(np.median(2 * radius))
    centre = x.mean(axis=0)
    background = np.column_stack([0.0 * x[:, 0], -1e-4 * (x[:, 1] - centre[1])])   # uniaxial, gamma 1e-4
    increment = shear_band(x, centre, alpha_deg, H_d50 * d50, 0.02) + background
    rec = window_band(*snapshots(x, radius, excluded, increment))
    assert rec["band"], rec["no_band_reason"]
    assert rec["d50"] == pytest.approx(d50)
    assert corrected(rec["thickness_over_d50"], PATCH_RADIUS) == pytest.approx(H_d50, rel=0.03)
    assert rec["thickness_over_d50"] < 1.1 * H_d50
    assert rec["inclination_deg"] == pytest.approx(alpha_deg, abs=0.5)
    assert rec["top_decile_share"] > 0.95


@pytest.mark.parametrize("patch", [PATCH_RADIUS, WIDE_PATCH_RADIUS])
def test_patch_widening_in_quadrature(grains, patch):
    """The resolution the benchmark corrects for: H_read^2 - H^2 = s^2 of PATCH_WIDENING
    (within 0.25 d50) for bands 2-6 d50 thick; a band of one diameter reads wider than H."""
    x, radius, excluded = grains
    d50 = float(np.median(2 * radius))
    for H in (2.0, 4.0, 6.0):
        rec = window_band(*snapshots(x, radius, excluded, shear_band(x, x.mean(axis=0), 55.0, H * d50, 0.02)),
                          patch)
        assert rec["band"], rec["no_band_reason"]
        assert math.sqrt(rec["thickness_over_d50"] ** 2 - H ** 2) == pytest.approx(PATCH_WIDENING[patch], abs=0.25)
    rec = window_band(*snapshots(x, radius, excluded, shear_band(x, x.mean(axis=0), 55.0, d50, 0.02)), patch)
    assert rec["thickness_over_d50"] > 1.4


def test_norm_of_a_background_narrows_the_bell(grains):
    """gamma is a norm: on a homogeneous increment of a tenth of the band's peak the tails
    read sqrt(g'^2 + b^2) - b, so H comes out below the band's own (the benchmark reports
    the contrast A / e0 beside H for this reason)."""
    x, radius, excluded = grains
    d50 = float(np.median(2 * radius))
    centre = x.mean(axis=0)
    increment = shear_band(x, centre, 55.0, 4.0 * d50, 0.02) + np.column_stack(
        [0.0 * x[:, 0], -0.002 * (x[:, 1] - centre[1])])
    rec = window_band(*snapshots(x, radius, excluded, increment))
    assert rec["band"], rec["no_band_reason"]
    assert 0.6 * 4.0 < corrected(rec["thickness_over_d50"], PATCH_RADIUS) < 0.9 * 4.0


def test_homogeneous_increment_has_no_band(grains):
    x, radius, excluded = grains
    rng = np.random.default_rng(1)
    increment = np.column_stack([0.001 * x[:, 0], -0.002 * x[:, 1]]) + 1e-6 * rng.standard_normal(x.shape)
    rec = window_band(*snapshots(x, radius, excluded, increment))
    assert not rec["band"]


def test_crossing_bands_are_not_one_band(grains):
    x, radius, excluded = grains
    d50 = float(np.median(2 * radius))
    centre = x.mean(axis=0)
    increment = shear_band(x, centre, 55.0, 1.5 * d50, 0.02) + shear_band(x, centre, -55.0, 1.5 * d50, 0.02)
    rec = window_band(*snapshots(x, radius, excluded, increment))
    assert not rec["band"]
    assert rec["top_decile_share"] < SINGLE_BAND_SHARE
    assert "no single band" in rec["no_band_reason"]
