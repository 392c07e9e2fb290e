"""Per-disc REV homogenisation, patch derivatives, moment balance and coarse-grained fields of a
disc specimen against closed forms (dns-spec Part C H1-H6; 004 eqs. 7.18-7.42, 7.47)."""
import math

import numpy as np
import pytest

from demcell.errors import InputError
from demcell.specimen.fields import (coarse_grain, coarse_grained_stress, moment_balance, patch_divergence,
                                     patch_gradient, rev_fields)

# DEM only: nothing here uses MPI, so it runs in the serial pass alone
pytestmark = pytest.mark.serial

R = 1.0
P = 50.0
FN_LATTICE = 2.0 * P * R / math.sqrt(3.0)    # contact force of the hexagonal lattice under p


def hex_lattice(nx, ny, r=R):
    """Centres of a hexagonal lattice with horizontal rows (spacing 2r, rows sqrt(3) r apart,
    odd rows shifted by r)."""
    j, i = np.mgrid[0:ny, 0:nx]
    x = 2.0 * r * i + r * (j % 2)
    y = math.sqrt(3.0) * r * j
    return np.stack([x.ravel(), y.ravel()], -1).astype(float)


def neighbour_pairs(x, reach, width=None):
    """Pairs i < j with |x_j - x_i| <= reach (minimum image in x with width)."""
    d = x[None, :, :] - x[:, None, :]
    if width:
        d[..., 0] -= width * np.floor(d[..., 0] / width + 0.5)
    dist = np.hypot(d[..., 0], d[..., 1])
    i, j = np.nonzero((dist <= reach) & np.triu(np.ones(dist.shape, bool), 1))
    return i.astype(np.int64), j.astype(np.int64)


def lattice_under_pressure(nx=10, ny=10):
    """Hexagonal lattice, every contact at 2 p r / sqrt(3) (overlap 1e-6 r), the resultant of
    each disc's contacts balanced by an external force (the boundary discs' load), the
    perimeter discs excluded."""
    x = hex_lattice(nx, ny)
    radius = np.full(len(x), R * (1.0 + 1e-6))
    i, j = neighbour_pairs(x, 2.0 * R * 1.001)
    fn = np.full(i.size, FN_LATTICE)
    fs = np.zeros(i.size)
    ext = -resultants(x, radius, i, j, fn, fs)[0]
    row, col = np.divmod(np.arange(len(x)), nx)
    perimeter = (row == 0) | (row == ny - 1) | (col == 0) | (col == nx - 1)
    return x, radius, i, j, fn, fs, ext, perimeter


def resultants(x, radius, i, j, fn, fs, mr=None, width=None):
    """Force (n,2) and moment (n,) of the contacts on each disc (demcell's convention)."""
    d = x[j] - x[i]
    if width:
        d[:, 0] -= width * np.floor(d[:, 0] / width + 0.5)
    dist = np.hypot(d[:, 0], d[:, 1])
    n = d / dist[:, None]
    t = np.stack([-n[:, 1], n[:, 0]], -1)
    fj = fn[:, None] * n + fs[:, None] * t
    overlap = radius[i] + radius[j] - dist
    mr = np.zeros(i.size) if mr is None else mr
    force = np.zeros_like(x)
    moment = np.zeros(len(x))
    np.add.at(force, j, fj)
    np.add.at(force, i, -fj)
    np.add.at(moment, i, -(radius[i] - 0.5 * overlap) * fs - mr)
    np.add.at(moment, j, -(radius[j] - 0.5 * overlap) * fs + mr)
    return force, moment


def disordered(seed=1, nx=12, ny=12):
    """A disordered set: a hexagonal lattice jittered by up to 0.2 r with radii in [0.85, 1.15] r;
    the lattice neighbours are the contacts (touching given explicitly)."""
    rng = np.random.default_rng(seed)
    x0 = hex_lattice(nx, ny)
    i, j = neighbour_pairs(x0, 2.0 * R * 1.001)
    x = x0 + rng.uniform(-0.2, 0.2, x0.shape) * R
    radius = rng.uniform(0.85, 1.15, len(x)) * R
    return x, radius, i, j, rng


def kinematic_fields(x, radius, i, j, u, phi, **options):
    zeros = np.zeros(i.size)
    return rev_fields(x, radius, u, phi, i, j, zeros, zeros, touching=np.ones(i.size, bool), **options)


def test_h1_polygon_identities_sum_n_zero_and_sum_x_n_equals_v_identity():
    """H1: grad of a constant is sum n / V = 0 and grad of u = x is sum x (x) n / V = I, to 1e-12,
    on a disordered set (every REV polygon irregular)."""
    x, radius, i, j, _ = disordered()
    const = kinematic_fields(x, radius, i, j, np.full_like(x, 3.7), np.full(len(x), 0.3))
    ident = kinematic_fields(x, radius, i, j, x.copy(), np.zeros(len(x)))
    ok = const.valid
    assert ok.sum() > 80 and np.array_equal(ok, ident.valid)
    for name in ("dux_dx", "dux_dy", "duy_dx", "duy_dy", "k3x", "k3y"):
        assert np.max(np.abs(getattr(const, name)[ok])) < 1e-12 * 3.7 * 20
    assert np.allclose(ident.dux_dx[ok], 1.0, rtol=0, atol=1e-12)
    assert np.allclose(ident.duy_dy[ok], 1.0, rtol=0, atol=1e-12)
    assert np.max(np.abs(ident.dux_dy[ok])) < 1e-12 and np.max(np.abs(ident.duy_dx[ok])) < 1e-12
    # the polygon area is the shoelace area of the members' centres: the hexagon on the lattice
    lat = kinematic_fields(hex_lattice(6, 6), np.ones(36), *neighbour_pairs(hex_lattice(6, 6), 2.001),
                           np.zeros((36, 2)), np.zeros(36))
    hexagon = lat.valid & (lat.n_members == 6)
    assert hexagon.sum() == 16
    assert np.allclose(lat.area[hexagon], 6.0 * math.sqrt(3.0), rtol=1e-13)
    assert np.allclose(lat.solid_area[hexagon], 3.0 * math.pi, rtol=1e-13)
    assert np.allclose(lat.solid_fraction[hexagon], math.pi / (2.0 * math.sqrt(3.0)), rtol=1e-13)


@pytest.mark.parametrize("lattice", [True, False], ids=["hexagonal", "disordered"])
def test_h2_affine_fields_reproduced_exactly(lattice):
    """H2: u = G x + c and phi = g . x + phi0 give grad u = G, grad phi = g (the curvature) to
    1e-12; a constant phi gives zero curvature."""
    if lattice:
        x = hex_lattice(9, 9)
        radius = np.ones(len(x))
        i, j = neighbour_pairs(x, 2.001)
    else:
        x, radius, i, j, _ = disordered(seed=7)
    G = np.array([[0.013, -0.021], [0.034, -0.008]])
    g = np.array([0.0042, -0.0031])
    u = x @ G.T + np.array([0.5, -0.2])
    phi = x @ g + 0.17
    f = kinematic_fields(x, radius, i, j, u, phi)
    ok = f.valid
    assert ok.sum() >= (49 if lattice else 80)
    grad = np.stack([np.stack([f.dux_dx, f.dux_dy], -1), np.stack([f.duy_dx, f.duy_dy], -1)], -2)[ok]
    assert np.max(np.abs(grad - G)) < 1e-12
    assert np.max(np.abs(f.k3x[ok] - g[0])) < 1e-12 and np.max(np.abs(f.k3y[ok] - g[1])) < 1e-12
    assert np.allclose(f.kappa_norm[ok], np.hypot(*g), rtol=1e-10)
    flat = kinematic_fields(x, radius, i, j, u, np.full(len(x), 0.17))
    assert np.max(np.abs(flat.kappa_norm[ok])) < 1e-12
    assert np.allclose(flat.phi[ok], 0.17, rtol=0, atol=1e-14)
    # Cosserat strain (004 eq. 7.42): eps_12 = u_1,2 + phi, eps_21 = u_2,1 - phi
    assert np.allclose(flat.exy[ok], G[0, 1] + 0.17, atol=1e-12)
    assert np.allclose(flat.eyx[ok], G[1, 0] - 0.17, atol=1e-12)
    # reference configuration: the same discs at X = x - u, grad taken with respect to X
    X = x
    xc = X + u
    ref = kinematic_fields(xc, radius, i, j, u, phi, configuration="reference")
    gref = np.stack([np.stack([ref.dux_dx, ref.dux_dy], -1), np.stack([ref.duy_dx, ref.duy_dy], -1)], -2)
    okr = ref.valid
    assert okr.sum() >= ok.sum() - 5
    assert np.max(np.abs(gref[okr] - G)) < 1e-12


def test_h3_rigid_rotation_strain_free_and_literal_normalisation_error():
    """H3: u = omega e3 x x, phi = omega: eps_bar = 0 to 1e-12 and phi_bar = omega with the sum v
    normalisation; the literal V_R normalisation (7.41 as printed) gives phi_bar = pi/(2 sqrt 3)
    omega = 0.9069 omega on the lattice, a skew strain of -/+ 0.0931 omega."""
    x = hex_lattice(9, 9)
    radius = np.ones(len(x))
    i, j = neighbour_pairs(x, 2.001)
    omega = 0.013
    u = omega * np.stack([-x[:, 1], x[:, 0]], -1)
    phi = np.full(len(x), omega)
    f = kinematic_fields(x, radius, i, j, u, phi)
    ok = f.valid & (f.n_members == 6)
    assert ok.sum() == 49
    assert np.max(f.eps_norm[f.valid]) < 1e-12 * omega * 100
    assert np.allclose(f.phi[ok], omega, rtol=1e-13)
    assert np.max(f.equivalent_strain[ok]) < 1e-14
    lit = kinematic_fields(x, radius, i, j, u, phi, rotation_normalisation="literal")
    error = 1.0 - math.pi / (2.0 * math.sqrt(3.0))
    assert abs(error - 0.0931) < 1e-4
    assert np.allclose(lit.phi[ok], (1.0 - error) * omega, rtol=1e-12)
    assert np.allclose(lit.exy[ok], -error * omega, rtol=1e-10)
    assert np.allclose(lit.eyx[ok], error * omega, rtol=1e-10)
    # disordered set: still exactly strain-free with sum v
    xd, rd, i, j, _ = disordered(seed=3)
    d = kinematic_fields(xd, rd, i, j, omega * np.stack([-xd[:, 1], xd[:, 0]], -1), np.full(len(xd), omega))
    assert np.max(d.eps_norm[d.valid]) < 1e-12 * omega * 100


def test_h5_isotropic_lattice_stress_minus_p_and_no_couple_stress():
    """H4/H5: the hexagonal lattice with every contact at 2 p r / sqrt(3) gives T = -p I in every
    valid REV (the contacts on the polygon's edges shared half), skew 0 and M = 0; 7.18 read
    literally (those contacts internal) gives -4/3 p I; perimeter discs are excluded."""
    x, radius, i, j, fn, fs, ext, perimeter = lattice_under_pressure()
    f = rev_fields(x, radius, np.zeros_like(x), np.zeros(len(x)), i, j, fn, fs, external_force=ext,
                   excluded=perimeter)
    ok = f.valid
    assert ok.sum() == 64 and f.n_excluded == 36 and f.n_invalid == 36
    assert np.allclose(f.txx[ok], -P, rtol=1e-10) and np.allclose(f.tyy[ok], -P, rtol=1e-10)
    assert np.max(np.abs(f.txy[ok])) < 1e-10 * P and np.max(np.abs(f.skew[ok])) < 1e-10 * P
    assert np.max(f.m_norm[ok]) < 1e-10 * P * R
    assert np.max(f.force_residual[ok]) < 1e-12
    assert np.all(np.isnan(f.txx[~ok]))
    assert np.all(f.coordination[ok] == 6)
    lit = rev_fields(x, radius, np.zeros_like(x), np.zeros(len(x)), i, j, fn, fs, external_force=ext,
                     excluded=perimeter, boundary_contacts="internal")
    assert np.allclose(lit.txx[ok], -4.0 / 3.0 * P, rtol=1e-10)
    # the distance neighbours give the same REVs without any contact flag
    dist = rev_fields(x, radius * (1.0 - 1e-3), np.zeros_like(x), np.zeros(len(x)), i, j, fn, fs,
                      external_force=ext, excluded=perimeter, neighbours="distance")
    assert dist.n_too_few == 0 and np.array_equal(dist.valid, ok)
    assert np.allclose(dist.tyy[ok], -P, rtol=1e-6)


def test_h5_periodic_strip_minimum_image():
    """An x-periodic lattice strip: every disc not on the top or bottom row has its 6 members
    across the seam, T = -p I."""
    nx, ny = 8, 6
    x = hex_lattice(nx, ny)
    width = 2.0 * R * nx
    radius = np.full(len(x), R * (1 + 1e-6))
    i, j = neighbour_pairs(x, 2.001, width)
    fn = np.full(i.size, FN_LATTICE)
    ext = -resultants(x, radius, i, j, fn, np.zeros(i.size), width=width)[0]
    row = np.arange(len(x)) // nx
    f = rev_fields(x, radius, np.zeros_like(x), np.zeros(len(x)), i, j, fn, np.zeros(i.size), external_force=ext,
                   excluded=(row == 0) | (row == ny - 1), periodic_width=width)
    assert f.valid.sum() == nx * (ny - 2)
    assert np.allclose(f.tyy[f.valid], -P, rtol=1e-10) and np.allclose(f.txx[f.valid], -P, rtol=1e-10)


@pytest.mark.parametrize("boundary_contacts", ["shared", "internal"])
def test_h4_per_rev_moment_identity_with_tangential_forces(boundary_contacts):
    """H4: with tangential and rolling contact forces and every disc in static equilibrium
    (each disc's resultant balanced by an external force and moment), every REV has sum f = 0
    and (T21 - T12) = -V^-1 sum m^(i) (004 eq. 7.19_2), to 1e-12 relative; at equilibrium T
    does not depend on the origin x_c."""
    x, radius, i, j, rng = disordered(seed=11)
    fn = rng.uniform(10.0, 60.0, i.size)
    fs = rng.uniform(-20.0, 20.0, i.size)
    mr = rng.uniform(-2.0, 2.0, i.size)
    force, moment = resultants(x, radius, i, j, fn, fs, mr)
    f = rev_fields(x, radius, np.zeros_like(x), np.zeros(len(x)), i, j, fn, fs, mr, external_force=-force,
                   external_moment=-moment, touching=np.ones(i.size, bool), boundary_contacts=boundary_contacts)
    ok = f.valid
    assert ok.sum() > 80
    assert np.max(f.force_residual[ok]) < 1e-12
    scale = np.max(np.abs(f.skew[ok]))
    assert scale > 1.0
    assert np.max(np.abs(f.skew[ok] + f.mean_moment[ok])) < 1e-12 * scale
    # the same REVs shifted rigidly by 1e3 r: T and M unchanged (origin independence)
    g = rev_fields(x + 1e3, radius, np.zeros_like(x), np.zeros(len(x)), i, j, fn, fs, mr, external_force=-force,
                   external_moment=-moment, touching=np.ones(i.size, bool), boundary_contacts=boundary_contacts)
    assert np.allclose(g.txy[ok], f.txy[ok], rtol=1e-8, atol=1e-8 * scale)
    assert np.allclose(g.m3x[ok], f.m3x[ok], rtol=1e-8, atol=1e-8 * scale)


def brute_force_rev(c, x, radius, i, j, fn, fs, mr, ext, ext_m, shared):
    """T and M of disc c's REV straight from 7.18, 7.31 and 7.38 (centroid origin), pair by pair."""
    ring = sorted(set(j[i == c]) | set(i[j == c]), key=lambda b: math.atan2(*(x[b] - x[c])[::-1]))
    members = ring + [c]
    poly = x[ring] - x[c]
    cross = poly[:, 0] * np.roll(poly[:, 1], -1) - np.roll(poly[:, 0], -1) * poly[:, 1]
    area = 0.5 * cross.sum()
    centroid = ((poly + np.roll(poly, -1, axis=0)) * cross[:, None]).sum(axis=0) / (6.0 * area)
    T = np.zeros((2, 2))
    M = np.zeros(2)
    for b in members:
        f = ext[b].copy()
        m = ext_m[b]
        for k in np.nonzero((i == b) | (j == b))[0]:
            other = j[k] if i[k] == b else i[k]
            weight = 1.0
            if other in members:
                weight = 0.0
                if shared and b != c and other != c:
                    gap = abs(ring.index(b) - ring.index(other))
                    weight = 0.5 if gap in (1, len(ring) - 1) else 0.0
            d = x[j[k]] - x[i[k]]
            dist = np.hypot(*d)
            n = d / dist
            fj = fn[k] * n + fs[k] * np.array([-n[1], n[0]])
            a = radius[b] - 0.5 * (radius[i[k]] + radius[j[k]] - dist)
            if b == j[k]:
                f += weight * fj
                m += weight * (-a * fs[k] + mr[k])
            else:
                f -= weight * fj
                m += weight * (-a * fs[k] - mr[k])
        T += np.outer(f, x[b] - x[c]) / area
        M += m * (x[b] - x[c] - centroid) / area
    return T, M


@pytest.mark.parametrize("shared", [True, False], ids=["shared", "internal"])
def test_stress_and_couple_stress_against_pair_by_pair_sums(shared):
    """The kernel's T and M of a disordered set with tangential and rolling forces (out of
    equilibrium, external loads on some discs) equal the pair-by-pair sums of 7.18, 7.31 and
    7.38 with the centroid origin."""
    x, radius, i, j, rng = disordered(seed=5, nx=7, ny=7)
    fn = rng.uniform(10.0, 60.0, i.size)
    fs = rng.uniform(-20.0, 20.0, i.size)
    mr = rng.uniform(-2.0, 2.0, i.size)
    ext = rng.normal(0.0, 5.0, x.shape)
    ext_m = rng.normal(0.0, 1.0, len(x))
    f = rev_fields(x, radius, np.zeros_like(x), np.zeros(len(x)), i, j, fn, fs, mr, external_force=ext,
                   external_moment=ext_m, touching=np.ones(i.size, bool),
                   boundary_contacts="shared" if shared else "internal")
    checked = 0
    for c in np.nonzero(f.valid)[0]:
        T, M = brute_force_rev(c, x, radius, i, j, fn, fs, mr, ext, ext_m, shared)
        assert np.allclose(f.stress()[c], T, rtol=1e-12, atol=1e-12 * np.abs(T).max())
        assert np.allclose([f.m3x[c], f.m3y[c]], M, rtol=1e-12, atol=1e-12 * np.abs(M).max())
        checked += 1
    assert checked >= 20


def test_invalid_revs_counted():
    """< 3 members, centre outside its polygon, excluded disc -> NaN and counted."""
    x = np.array([[0.0, 0.0], [2.0, 0.0], [-1.0, 1.7], [-1.0, -1.7], [4.0, 0.0], [1.0, 1.7], [1.0, -1.7]])
    radius = np.full(7, 1.01)
    # 0: members 1, 2, 3 (centre inside); 1: members 0, 4, 5 (all on one side: gap > pi at 1?)
    pi_, pj = neighbour_pairs(x, 2.03)
    f = rev_fields(x, radius, np.zeros_like(x), np.zeros(7), pi_, pj, np.ones(pi_.size), np.zeros(pi_.size),
                   excluded=np.array([0, 0, 0, 0, 0, 0, 1], bool))
    assert f.status[6] == 3 and f.n_excluded == 1
    assert f.valid[0] and f.n_members[0] == 5
    assert f.n_invalid == int((~f.valid).sum()) == f.n_too_few + f.n_centre_outside + f.n_excluded
    assert f.status[4] == 1                       # one neighbour only
    assert np.isnan(f.txx[~f.valid]).all()
    # three members in a half plane: centre not strictly inside
    y = np.array([[0.0, 0.0], [2.0, 0.0], [1.0, 1.73], [1.0, -1.73]])
    qi, qj = np.array([0, 0, 0]), np.array([1, 2, 3])
    h = rev_fields(y, np.full(4, 1.01), np.zeros_like(y), np.zeros(4), qi, qj, np.ones(3), np.zeros(3))
    assert h.status[0] == 2 and h.n_centre_outside == 1


def test_sliding_fraction_and_void_ratio():
    x, radius, i, j, fn, fs, ext, perimeter = lattice_under_pressure(6, 6)
    sliding = np.zeros(i.size, bool)
    sliding[::3] = True
    f = rev_fields(x, radius, np.zeros_like(x), np.zeros(len(x)), i, j, fn, fs, external_force=ext,
                   excluded=perimeter, sliding=sliding)
    expect = np.bincount(np.concatenate([i[sliding], j[sliding]]), minlength=len(x)) / f.coordination
    assert np.allclose(f.sliding_fraction, expect)
    # the engine's int8 flags are accepted as they are
    g = rev_fields(x, radius, np.zeros_like(x), np.zeros(len(x)), i, j, fn, fs, external_force=ext,
                   excluded=perimeter.astype(np.int8), sliding=sliding.astype(np.int8),
                   touching=np.ones(i.size, np.int8))
    assert np.array_equal(g.valid, f.valid) and np.allclose(g.sliding_fraction, f.sliding_fraction)
    with pytest.raises(InputError, match="excluded"):
        rev_fields(x, radius, np.zeros_like(x), np.zeros(len(x)), i, j, fn, fs, excluded=np.full(len(x), 2))
    assert np.allclose(f.void_ratio[f.valid], 2.0 * math.sqrt(3.0) / math.pi - 1.0, rtol=1e-4)


def quadratic(x, a):
    return a[0] + a[1] * x[:, 0] + a[2] * x[:, 1] + a[3] * x[:, 0] ** 2 + a[4] * x[:, 0] * x[:, 1] + a[5] * x[:, 1] ** 2


def test_h6_patch_fit_exact_for_quadratic_field_and_moment_balance():
    """H6: on the 7-point hexagonal patch the quadratic fit differentiates a quadratic M field
    exactly (1e-10); perimeter discs (3-4 valid points) fall back to the linear fit, exact for a
    linear field; with skew = -div M the balance 7.47 closes and Pearson(div M, -skew) = 1."""
    x = hex_lattice(9, 9) + np.array([3.0, -2.0])
    f = kinematic_fields(x, np.ones(len(x)), *neighbour_pairs(x, 2.001), np.zeros_like(x), np.zeros(len(x)))
    members = f.members
    a = np.array([0.3, -1.2, 0.7, 0.05, -0.11, 0.08])
    b = np.array([-0.4, 0.5, 2.1, -0.07, 0.02, 0.13])
    m3x = quadratic(x, a)
    m3y = quadratic(x, b)
    all_valid = np.ones(len(x), bool)
    exact = (a[1] + 2 * a[3] * x[:, 0] + a[4] * x[:, 1]) + (b[2] + b[4] * x[:, 0] + 2 * b[5] * x[:, 1])
    div = patch_divergence(x, np.stack([m3x, m3y], -1), all_valid, members)
    grad, used = patch_gradient(x, m3x, all_valid, members)
    interior = used == 7
    assert interior.sum() == 49
    assert np.max(np.abs(div[interior] - exact[interior])) < 1e-10
    assert np.max(np.abs(grad[interior, 0] - (a[1] + 2 * a[3] * x[interior, 0] + a[4] * x[interior, 1]))) < 1e-10
    lin = quadratic(x, [0.3, -1.2, 0.7, 0, 0, 0])
    g, used = patch_gradient(x, lin, all_valid, members)
    assert np.all(used >= 3)
    assert np.allclose(g, [-1.2, 0.7], atol=1e-10)
    # an invalid disc neither gets a value nor enters its neighbours' fits
    bad = all_valid.copy()
    bad[40] = False
    g2, used2 = patch_gradient(x, np.where(bad, lin, 1e6), bad, members)
    assert np.isnan(g2[40]).all() and np.allclose(g2[bad], [-1.2, 0.7], atol=1e-10)
    mb = moment_balance(x, -exact, m3x, m3y, all_valid, members)
    assert mb.n_used == len(x)
    assert np.max(np.abs(mb.residual[interior])) < 1e-10
    assert mb.pearson_minus > 0.99 and mb.pearson_plus < -0.99


def test_coarse_grained_stress_integrates_to_platen_force():
    """The coarse-grained contact stress of the pressed lattice, integrated along a horizontal cut
    between the rows, equals the vertical force on the top row (the platen force) to 1e-6; both
    components match the closed-form cut integral of every branch (the erf line weight); its
    bulk value is -p I within 2 %."""
    nx, ny = 12, 14
    x, radius, i, j, fn, fs, ext, perimeter = lattice_under_pressure(nx, ny)
    top = np.arange(len(x)) // nx == ny - 1
    platen = ext[top].sum(axis=0)
    assert platen[1] < 0.0
    width = 1.5 * R
    gx = np.arange(-12.0, 2.0 * nx * R + 12.0, 0.1)
    ycut = math.sqrt(3.0) * R * (ny - 1) / 2.0
    sigma = coarse_grained_stress(x, radius, i, j, fn, fs, gx, np.array([ycut]), width)
    step = gx[1] - gx[0]
    force = np.sum(sigma[0, :, :, 1], axis=0) * step
    assert abs(force[1] - platen[1]) < 1e-6 * abs(platen[1])
    # both components against the closed form of the cut integral of each branch's kernel line:
    # int sigma_k2 dx = -sum_c f_k [Phi((Y - y_i)/w) - Phi((Y - y_j)/w)] (f on j, Phi the normal cdf)
    cdf = np.vectorize(lambda z: 0.5 * (1.0 + math.erf(z / math.sqrt(2.0))))
    d = x[j] - x[i]
    n = d / np.hypot(d[:, 0], d[:, 1])[:, None]
    fj = fn[:, None] * n
    weight = cdf((ycut - x[i, 1]) / width) - cdf((ycut - x[j, 1]) / width)
    expect = -(fj * weight[:, None]).sum(axis=0)
    assert np.allclose(force, expect, rtol=1e-6, atol=1e-6 * abs(platen[1]))
    centre = np.argmin(np.abs(gx - nx * R))
    assert np.allclose(sigma[0, centre], -P * np.eye(2), atol=0.02 * P)


def test_coarse_grain_normalised_weights_and_nan_far_away():
    x = hex_lattice(8, 8)
    gx = np.linspace(-10.0, 25.0, 36)
    gy = np.linspace(-10.0, 22.0, 33)
    const = coarse_grain(x, np.full(len(x), 4.2), gx, gy, 1.0)
    near = np.isfinite(const)
    assert near.any() and (~near).any()
    assert np.allclose(const[near], 4.2, rtol=1e-14)
    dist = np.min(np.hypot(gx[None, :, None] - x[:, 0][None, None, :], gy[:, None, None] - x[:, 1][None, None, :]),
                  axis=2)
    assert np.array_equal(near, dist <= 3.0)
    # two columns, invalid values skipped
    vals = np.stack([x[:, 0], np.where(np.arange(len(x)) % 2 == 0, np.nan, 1.0)], -1)
    two = coarse_grain(x, vals, gx, gy, 1.0)
    assert two.shape == (33, 36, 2)
    assert np.allclose(two[near, 1][np.isfinite(two[near, 1])], 1.0)
    # x-periodic: a disc moved by whole periods (unwrapped positions) weighs the same, and a
    # node near x = 0 sees the discs near x = width through the seam
    width = 16.0
    xs = x.copy()
    xs[::3, 0] += 2.0 * width
    gp = np.linspace(0.0, width, 17)
    a = coarse_grain(x, x[:, 1], gp, gy, 1.0, periodic_width=width)
    b = coarse_grain(xs, x[:, 1], gp, gy, 1.0, periodic_width=width)
    assert np.allclose(a, b, equal_nan=True, rtol=1e-13)
    assert np.allclose(a[:, 0], a[:, -1], equal_nan=True, rtol=1e-12)


def test_bad_input_refused_in_one_line():
    x = hex_lattice(3, 3)
    z = np.zeros(2)
    with pytest.raises(InputError, match="radius"):
        rev_fields(x, np.ones(4), np.zeros_like(x), np.zeros(9), [0, 1], [1, 2], z, z)
    with pytest.raises(InputError, match="pair_j"):
        rev_fields(x, np.ones(9), np.zeros_like(x), np.zeros(9), [0, 1], [1, 9], z, z)
    with pytest.raises(InputError, match="neighbours"):
        rev_fields(x, np.ones(9), np.zeros_like(x), np.zeros(9), [0, 1], [1, 2], z, z, neighbours="voronoi")
    with pytest.raises(InputError, match="width"):
        coarse_grain(x, np.ones(9), [0.0, 1.0], [0.0, 1.0], 0.0)
