"""The measures of benchmarks/dns/continuum_bands.py and band_couple_stress.py on fields with
a known answer: a band of known thickness at Gauss-point-like points of the 10 x 20 mm
specimen, and couple stresses of a known internal length."""
import math

import numpy as np
import pytest

from benchmarks.dns.band_couple_stress import internal_length
from benchmarks.dns.continuum_bands import HEIGHT, WEAK_SIZE, WIDTH, grain_scale, measure, outside_weak


def grid(n=80):
    x, y = np.meshgrid((np.arange(n) + 0.5) * WIDTH / n, (np.arange(2 * n) + 0.5) * HEIGHT / (2 * n))
    return np.column_stack([x.ravel(), y.ravel()])


def band_increment(points, alpha_deg, H, amplitude, offset, x10):
    """The symmetric increment of simple shear along a band through (0, x10) at alpha_deg:
    its largest engineering shear strain is offset + amplitude exp(-d^2 / 2H^2)."""
    a = math.radians(alpha_deg)
    d = (points[:, 1] - x10) * math.cos(a) - points[:, 0] * math.sin(a)
    gamma = offset + amplitude * np.exp(-d ** 2 / (2.0 * H ** 2))
    t, n = np.array([math.cos(a), math.sin(a)]), np.array([-math.sin(a), math.cos(a)])
    e = 0.5 * gamma[:, None, None] * (t[None, :, None] * n[None, None, :] + n[None, :, None] * t[None, None, :])
    return np.column_stack([e[:, 0, 0], e[:, 1, 1], e[:, 0, 1]])


def test_measure_returns_the_band_it_is_given_in_d50():
    points = grid()
    d50 = 3.4e-4
    H = 3.0 * d50
    inc = band_increment(points, 50.0, H, amplitude=0.02, offset=0.002, x10=0.008)
    rec = measure(points, inc, WIDTH / 40, d50)
    assert rec["band"], rec["why"]
    assert rec["thickness_over_d50"] == pytest.approx(3.0, rel=0.02)
    assert abs(rec["inclination_deg"]) == pytest.approx(50.0, abs=0.5)
    assert rec["contrast"] == pytest.approx(10.0, rel=0.05)


def test_measure_leaves_out_the_weak_corner_and_refuses_a_homogeneous_field():
    points = grid()
    keep = outside_weak(points)
    assert not keep[(points[:, 0] < WEAK_SIZE) & (points[:, 1] < WEAK_SIZE)].any()
    assert keep.sum() == len(points) - 40 * 40            # a quarter of the width, an eighth of the height
    # a field that only the weak corner strains more than the rest is no band outside it
    inc = np.tile([1e-3, -1e-3, 0.0], (len(points), 1))
    inc[~keep] *= 5.0
    rec = measure(points, inc, WIDTH / 40, 3.4e-4)
    assert not rec["band"]


def test_internal_length_recovers_an_elastic_couple_stress_law():
    rng = np.random.default_rng(0)
    G, l_c, H = 2.0e3, 1.5e-5, 1e-3
    d = rng.uniform(-5 * H, 5 * H, 4000)
    kappa = np.abs(rng.normal(10.0, 3.0, d.size)) * (1 + 9 * (np.abs(d) <= H))
    m = 2.0 * G * l_c ** 2 * kappa
    assert internal_length(d, m, kappa, G, H) == pytest.approx(l_c, rel=1e-12)
    # outside the band the ratio is another one: only |d| <= H counts
    m_out = np.where(np.abs(d) <= H, m, 100 * m)
    assert internal_length(d, m_out, kappa, G, H) == pytest.approx(l_c, rel=1e-12)
    assert internal_length(d, m, np.zeros_like(kappa), G, H) is None


def test_grain_scale_puts_the_dns_2x4_tiling_in_the_specimen():
    d50, d_mean, metres = grain_scale(0, 228)
    # the DNS 2x4 specimen is 29 x 58 d50 (docs/results/dns_vs_femdem.md)
    assert WIDTH / d50 == pytest.approx(29.2, abs=0.5)
    assert d_mean == pytest.approx(d50, rel=0.1)
    assert metres > 0
