"""The lattice's contacts sliding and opening as a Gauss-point material
(cosserat_fenicsx.materials.lattice_coulomb) against closed forms: below the friction limit
it is the cubic law of lattice_elasticity.py; a lattice-frame shear under compression
saturates at mu k_N |eps'_11| and unloads with k_S; tension opens a family; the consistent
tangent equals finite differences of the update while sticking, sliding and open."""
import math

import numpy as np
import pytest

from cosserat_fenicsx.materials.lattice_coulomb import LatticeCoulombMaterial, lattice_frame_maps

KN, KS, MU, BEND = 2.5e8, 5.0e7, 0.5, 12.0


def update(material, gradients, old=None):
    n = len(gradients)
    flux, tangent, new = np.zeros((n, 6)), np.zeros((n, 6, 6)), np.zeros((n, 4))
    material.update(np.asarray(gradients, float), 0.0, np.zeros((n, 4)) if old is None else old, flux, tangent, new)
    return flux, tangent, new


def from_lattice(strain_lattice):
    """x-y gradient vector (eps11, eps22, eps12, eps21, 0, 0) of a lattice-frame strain (11, 22, 12, 21)."""
    into, _ = lattice_frame_maps(math.pi / 4)
    g = np.zeros(6)
    g[:4] = np.linalg.solve(into, strain_lattice)
    return g


def test_below_the_limit_it_is_the_cubic_law():
    m = LatticeCoulombMaterial(KN, KS, MU, BEND)
    g = np.array([-1e-3, -2e-3, 1e-4, -5e-5, 0.3, -0.2])
    flux, _, _ = update(m, [g])
    c11, c12, c66, mu_c = (KN + KS) / 2, (KN - KS) / 2, KN / 2, KS / 2
    sym, skw = 0.5 * (g[2] + g[3]), 0.5 * (g[2] - g[3])
    expected = [c11 * g[0] + c12 * g[1], c12 * g[0] + c11 * g[1], 2 * c66 * sym + 2 * mu_c * skw,
                2 * c66 * sym - 2 * mu_c * skw, BEND * g[4], BEND * g[5]]
    np.testing.assert_allclose(flux[0], expected, rtol=1e-12, atol=1e-6)


def test_shear_saturates_at_the_friction_limit_and_unloads_elastically():
    """Family 1 compressed by eps'_11 = -1e-3, sheared by eps'_21 in steps: t_1 = k_S eps'_21
    until mu k_N 1e-3, then held there; back by one step: k_S less."""
    m = LatticeCoulombMaterial(KN, KS, MU)
    _, back = lattice_frame_maps(math.pi / 4)
    state = np.zeros((1, 4))
    limit = MU * KN * 1e-3
    shear = np.linspace(0.0, 6e-3, 61)
    for k, gamma in enumerate(shear):
        flux, _, state = update(m, [from_lattice([-1e-3, -1e-3, 0.0, gamma])], state)
        t1 = state[0, 0]
        assert t1 == pytest.approx(min(KS * gamma, limit), rel=1e-9, abs=1e-6)
        lattice = np.linalg.solve(back, flux[0, :4])
        assert lattice[3] == pytest.approx(t1, rel=1e-9, abs=1e-6)          # sigma'_21 = t_1
    flux, _, state = update(m, [from_lattice([-1e-3, -1e-3, 0.0, shear[-2]])], state)
    assert state[0, 0] == pytest.approx(limit - KS * (shear[-1] - shear[-2]), rel=1e-9)


def test_tension_opens_a_family():
    m = LatticeCoulombMaterial(KN, KS, MU)
    _, back = lattice_frame_maps(math.pi / 4)
    flux, tangent, state = update(m, [from_lattice([2e-4, -1e-3, 3e-4, 1e-4])])
    lattice = np.linalg.solve(back, flux[0, :4])
    assert abs(lattice[0]) < 1e-6 and abs(lattice[3]) < 1e-6 and state[0, 0] == 0.0      # family 1 open
    assert lattice[1] == pytest.approx(-KN * 1e-3) and lattice[2] == pytest.approx(KS * 3e-4)


@pytest.mark.parametrize("lattice_strain, regime", [
    ([-1e-3, -2e-3, 1e-4, -5e-5], "stick"),
    ([-1e-3, -1.2e-3, 9e-3, -8e-3], "slide"),
    ([1e-3, -2e-3, 1e-4, 0.0], "open"),
])
def test_tangent_is_the_derivative_of_the_update(lattice_strain, regime):
    m = LatticeCoulombMaterial(KN, KS, MU, BEND)
    g = from_lattice(lattice_strain)
    g[4:] = (0.1, 0.2)
    _, tangent, state = update(m, [g])
    t1, limit1 = state[0, 0], MU * KN * abs(min(lattice_strain[0], 0.0))
    assert {"stick": abs(t1) < limit1, "slide": abs(t1) == pytest.approx(limit1), "open": t1 == 0.0}[regime]
    h = 1e-9
    fd = np.zeros((6, 6))
    for j in range(6):
        step = np.zeros(6)
        step[j] = h
        fd[:, j] = (update(m, [g + step])[0][0] - update(m, [g - step])[0][0]) / (2 * h)
    assert np.abs(fd - tangent[0]).max() < 1e-6 * np.abs(tangent[0]).max()


def test_refusals():
    for args in ((0.0, KS, MU), (KN, -1.0, MU), (KN, KS, -0.1), (KN, KS, float("nan")), (KN, KS, MU, -1.0)):
        with pytest.raises(ValueError):
            LatticeCoulombMaterial(*args)
