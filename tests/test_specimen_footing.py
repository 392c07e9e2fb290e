"""The rigid plate, 003's footing packings and a tiny full-DEM strip footing (003 section 3)."""
import math

import numpy as np
import pytest

from demcell.errors import InputError
from demcell.specimen import Specimen, SpecimenOptions, SpecimenState
from demcell.specimen.footing import DENSITY, KN, KS, footing_packing, run_footing, table1_law
from demcell.specimen.plate import Plate, plate_contact
from demcell.specimen.specimens import rotated_square_lattice

pytestmark = pytest.mark.serial

R = 0.05
LAW = table1_law(R)


def one_disc(y, lateral="none", x=0.0):
    pos = np.array([[x, y]])
    r = np.array([R])
    m = DENSITY * math.pi * r ** 2
    box = (-1.0, 1.0, -1.0, 1.0)
    state = SpecimenState.from_discs(pos, r, m, 0.5 * m * r ** 2, box, lateral=lateral)
    return Specimen(state, LAW, SpecimenOptions(dt=1e-6, lateral=lateral, normal_dashpot=0.0,
                                                tangential_dashpot=0.0))


@pytest.mark.parametrize("lateral", ["none", "walls"])
def test_plate_on_one_disc_is_kn_overlap(lateral):
    """A disc under the flat face, overlap h: the plate pushes it with kn h (and nothing
    sideways); a disc beside the plate's end meets the corner along the corner-centre line."""
    h = 1e-4
    spec = one_disc(0.0, lateral)
    spec.hold(np.ones(1))                      # keep it still: the force of exactly this overlap
    spec.set_plate(Plate(-0.5, 0.5, R - h))
    spec.advance(1)
    np.testing.assert_allclose(spec.plate_reaction(), [0.0, -KN * h], rtol=1e-9, atol=1e-6)
    np.testing.assert_allclose(spec.disc_forces()[0], [0.0, -KN * h, 0.0], rtol=1e-9, atol=1e-6)
    # corner: the disc's centre 0.03 m left of the plate's end, 0.03 m below its face
    spec = one_disc(0.0, lateral, x=-0.53)
    spec.hold(np.ones(1))
    spec.set_plate(Plate(-0.5, 0.5, 0.03))
    spec.advance(1)
    d = math.hypot(0.03, 0.03)
    f = KN * (R - d)
    np.testing.assert_allclose(spec.plate_reaction(), [-f / math.sqrt(2), -f / math.sqrt(2)], rtol=1e-9)


def test_plate_contact_geometry():
    plate = Plate(0.0, 1.0, 2.0).vector(0.0)
    assert plate_contact(0.5, 1.97, 0.05, plate) == pytest.approx((0.02, 0.0, -1.0))
    h, nx, ny = plate_contact(1.03, 1.96, 0.05, plate)          # corner (1, 2)
    assert h == pytest.approx(0.0) and (nx, ny) == pytest.approx((0.6, -0.8))
    assert plate_contact(-0.04, 2.5, 0.05, plate) == pytest.approx((0.01, -1.0, 0.0))   # side
    assert plate_contact(0.5, 2.1, 0.05, plate) == pytest.approx((0.15, 0.0, -1.0))     # inside
    with pytest.raises(InputError, match="x1 > x0"):
        Plate(1.0, 0.0, 2.0)


def test_rough_plate_friction_limit():
    """A rough plate sliding sideways over a pressed, held disc: the tangential force reaches
    the Coulomb limit mu kn h and opposes the slip."""
    h = 1e-4
    spec = one_disc(0.0)
    spec.hold(np.ones(1))
    spec.set_plate(Plate(-0.5, 0.5, R - h, velocity=(0.1, 0.0), rough=True))
    spec.advance(20)          # elastic: ks times the slip 20 v dt (100 N), below mu kn h = 12.5 kN
    fx, fy = spec.plate_reaction()
    assert fy == pytest.approx(-KN * h, rel=1e-9)
    assert fx == pytest.approx(KS * 20 * 0.1 * 1e-6, rel=1e-6)
    spec.advance(4000)
    assert spec.plate_reaction()[0] == pytest.approx(0.5 * KN * h, rel=1e-9)


def test_lattice_A_contacts():
    """Packing A: every contact at +-45 degrees, exactly 2 r between centres, 4 contacts per
    interior disc; 003-bsm.md section 8's count for the 6 x 3 m region (1764)."""
    discs = rotated_square_lattice((0.0, 1.2, 0.0, 0.9), R, DENSITY)
    p = discs.position
    d = p[None, :, :] - p[:, None, :]
    dist = np.hypot(d[..., 0], d[..., 1])
    touch = np.abs(dist - 2 * R) < 1e-12
    ang = np.degrees(np.arctan2(d[..., 1], d[..., 0]))[touch]
    assert np.allclose(np.abs(np.abs(ang) - 90.0), 45.0)
    assert not np.any(dist[~np.eye(len(p), dtype=bool)] < 2 * R - 1e-12)
    inner = (p[:, 0] > 2.5 * R) & (p[:, 0] < 1.2 - 2.5 * R) & (p[:, 1] > 2.5 * R) & (p[:, 1] < 0.9 - 2.5 * R)
    assert inner.sum() > 20
    assert np.all(touch[inner].sum(axis=1) == 4)
    assert footing_packing("A", (0.0, 6.0, 0.0, 3.0)).n_discs == 1764
    assert footing_packing("B", (0.0, 6.0, 0.0, 3.0)).n_discs == 4935


def test_plate_reaction_balances_walls():
    """An A lattice in walls under a full-width plate pushed down by s = 1 mm, then stopped
    and let come to rest (mass damping): the plate's force equals minus the sum of the
    walls' (equilibrium), each disc's net force vanishes, and the load is that of the
    springs in series (affine compression, no lateral strain: every contact between two rows
    gives (kn + ks)/2 vertically, the plate and the bottom wall kn per disc they touch). The
    width fits the lattice: the even rows touch both walls (with a gap the unstressed lattice
    is a mechanism, its cells flattening into rhombi at no force)."""
    width, height = 2 * R + 16 * math.sqrt(2) * R, 0.8
    discs = rotated_square_lattice((0.0, width, 0.0, height), R, DENSITY)
    box = (0.0, width, 0.0, 2.0)
    state = SpecimenState.from_discs(discs.position, discs.radius, discs.mass, discs.inertia, box, lateral="walls")
    dt = 0.1 * math.sqrt(discs.mass[0] / KN)
    spec = Specimen(state, LAW, SpecimenOptions(dt=dt, lateral="walls", mass_damping=200.0, normal_dashpot=0.0,
                                                tangential_dashpot=0.0))
    y = discs.position[:, 1]
    top = float(np.max(y + R))
    speed, s = 0.05, 1e-3
    n = int(round(s / (speed * dt)))
    spec.set_plate(Plate(0.0, width, top, velocity=(0.0, -speed)))
    spec.advance(n)
    spec.set_plate_velocity(0.0, 0.0)
    spec.advance(8000)
    plate = spec.plate_reaction()
    walls = spec.state.wall_force.sum(axis=0)
    assert plate[1] < -1e3
    np.testing.assert_allclose(plate + walls, 0.0, atol=1e-6 * abs(plate[1]))
    assert np.abs(spec.disc_forces()[:, :2]).max() < 1e-6 * abs(plate[1])
    rows = np.unique(np.round(y, 9))
    n_top = np.count_nonzero(np.isclose(y, rows[-1]))
    n_bottom = np.count_nonzero(np.isclose(y, rows[0]))
    lower = discs.position[np.isclose(y, rows[0])]
    upper = discs.position[np.isclose(y, rows[1])]
    d = np.hypot(*(upper[None, :, :] - lower[:, None, :]).transpose(2, 0, 1))
    n_gap = np.count_nonzero(np.isclose(d, 2 * R))
    compliance = 1 / (n_top * KN) + (len(rows) - 1) / (n_gap * 0.5 * (KN + KS)) + 1 / (n_bottom * KN)
    settled = top - spec.plate_position()[2]
    # measured 6 % below: the discs end rotated by up to 5e-3 rad (the gear mode of the
    # bipartite lattice is held only by the rolling spring, whose limit eta_r R_eff f_n is
    # reached during the push), so the frictional equilibrium is not the affine one
    assert 0.85 < -plate[1] / (settled / compliance) < 1.0


def test_tiny_footing_A():
    """Packing A in a 3 x 1.5 m box, a 1 m plate pushed 3 mm at 0.05 m/s: the load rises with
    the settlement, and the secant stiffness lies between two elastic estimates from the
    lattice's moduli (C22 = (kn + ks)/2, C12 = (kn - ks)/2 per unit depth, the ±45 degree
    square lattice with rotations free): a column under the plate free to bulge,
    (C22 - C12^2/C11) B / H, and the whole width confined, C22 W / H."""
    res = run_footing("A", width=3.0, height=1.5, plate_width=1.0, speed=0.05, depth=3e-3, mass_damping=100.0,
                      record_every=20, threads=1)
    n = res.specimen.state.n_discs
    assert 300 < n < 600
    s, f = res.settlement, res.load
    assert s[-1] == pytest.approx(3e-3, abs=res.info["dt"] * 0.05)
    assert np.all(np.diff(f[len(f) // 4:]) > -0.02 * f[-1])      # rising, up to small oscillations
    c11 = c22 = 0.5 * (KN + KS)
    c12 = 0.5 * (KN - KS)
    low = (c22 - c12 ** 2 / c11) * 1.0 / 1.5
    high = c22 * 3.0 / 1.5
    k = (f[-1] - f[len(f) // 2]) / (s[-1] - s[len(s) // 2])
    assert low < k < high, (low, k, high)
    assert res.wall_seconds > 0.0 and res.cpu_seconds > 0.0


def test_random_dense_packing_C():
    """Packing C: radii within 0.02-0.05 m, every disc inside the box, overlaps only those of
    the compaction (about 2e-4 of a radius at 1e-4 kn), a dense cell (frictionless compaction:
    solid fraction above 0.8)."""
    from demcell.specimen.specimens import random_dense
    box = (0.0, 1.0, 0.0, 0.6)
    d = random_dense(box, 0.02, 0.05, DENSITY, n_cell=30, seed=1)
    p, r = d.position, d.radius
    assert d.n_discs > 50
    assert r.min() >= 0.02 and r.max() <= 0.05
    assert np.all(p[:, 0] - r >= 0.0) and np.all(p[:, 0] + r <= 1.0)
    assert np.all(p[:, 1] - r >= 0.0) and np.all(p[:, 1] + r <= 0.6)
    dist = np.hypot(*(p[None] - p[:, None]).transpose(2, 0, 1))
    np.fill_diagonal(dist, np.inf)
    overlap = (r[None] + r[:, None] - dist) / np.minimum(r[None], r[:, None])
    assert overlap.max() < 5e-3
    assert d.info["cell_solid_fraction"] > 0.8
    np.testing.assert_allclose(d.mass, DENSITY * np.pi * r ** 2)


def test_footing_impact_load_is_wave_impedance():
    """At 1 m/s (003's speed) the first load on packing A is the plane-wave impedance of the
    lattice under the plate, rho_b c_p v B, rho_b = 2600 pi / 4 (square lattice), c_p =
    sqrt(C22 / rho_b), C22 = (kn + ks) / 2, until the wave returns from the bottom (2 H / c_p)."""
    res = run_footing("A", width=3.0, height=1.5, plate_width=1.0, speed=1.0, depth=2e-3, mass_damping=0.0,
                      record_every=1, threads=1)
    rho_b = DENSITY * math.pi / 4.0
    c_p = math.sqrt(0.5 * (KN + KS) / rho_b)
    impedance = rho_b * c_p * 1.0 * 1.0
    window = (res.settlement > 0.5e-3) & (res.settlement < 2e-3)
    assert 2e-3 < 2 * 1.5 / c_p
    assert np.mean(res.load[window]) == pytest.approx(impedance, rel=0.05)      # measured 1.011


def test_footing_settles_under_gravity():
    """Gravity: after footing.settle the bottom wall carries the discs' weight (static
    equilibrium, the side walls smooth), the surface has come down, and run_footing puts the
    plate on it and counts settlement and time from there."""
    from demcell.specimen.footing import footing_specimen, settle
    spec, info = footing_specimen("A", width=3.0, height=1.5, plate_width=1.0, gravity=9.81, threads=1)
    assert spec.options.gravity == (0.0, -9.81)
    settled = settle(spec, 0.3)
    weight = 9.81 * float(spec.state.mass.sum())
    bottom = float(spec.state.wall_force[0, 1])
    assert bottom == pytest.approx(weight, rel=0.01)
    assert settled["settle_kinetic_energy"] < 1e-4 * weight * 1.5
    assert spec.options.local_damping == 0.0 and spec.options.mass_damping == 10.0   # restored
    # the walls against the lattice: the surface comes down level (measured 0.006 mm across
    # 3 m; with the right wall on the domain's face the lattice slumps into the gap: 1 mm)
    p, r = spec.state.position, spec.state.radius
    tops = [np.max((p[:, 1] + r)[(p[:, 0] >= x) & (p[:, 0] < x + 0.5)]) for x in np.arange(0.0, 3.0, 0.5)]
    assert max(tops) - min(tops) < 1e-4
    assert info["walls"][1] < 3.0 and info["plate_y0"] - max(tops) > 0.0
    res = run_footing("A", width=3.0, height=1.5, plate_width=1.0, speed=0.1, depth=1e-3, record_every=50,
                      threads=1, gravity=9.81, settle_time=0.3)
    assert res.info["plate_y0"] < info["plate_y0"] and res.info["settle_steps"] > 0
    assert res.time[0] == 0.0 and res.time[-1] == pytest.approx(1e-3 / 0.1, rel=1e-3)
    assert res.load[-1] > 0.0
    with pytest.raises(InputError, match="gravity"):
        footing_specimen("A", width=3.0, height=1.5, plate_width=1.0, gravity=-1.0)
