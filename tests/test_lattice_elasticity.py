"""The cubic law of the 45-degree square lattice (cosserat_fenicsx.lattice_elasticity) against
the lattice itself: the strain energy of an affine Cosserat field (u = H x, a uniform rotation
phi), assembled from the law's UFL stress on a unit square, equals the energy of the two
contact springs per disc that the same field stretches and shears (contact points of two
neighbours at l n moved apart by H l n - phi l t), over the cell area l^2; the isotropic
orientation average of the same moduli does not."""
import math

import dolfinx.fem
import numpy as np
import pytest
import ufl
from mpi4py import MPI

from cosserat_fenicsx import compat, meshes
from cosserat_fenicsx.elasticity import MicropolarElasticity
from cosserat_fenicsx.kinematics import strain
from cosserat_fenicsx.lattice_elasticity import SquareLatticeElasticity

KN, KS = 2.5e8, 5.0e7        # 003 Table 1 [N/m]


def lattice_energy(gradient, phi, radius=0.05):
    """Spring energy per unit area [J/m^2] of the rotated square lattice under u = H x with
    every disc rotated by phi (normals at +-45 degrees, tangents n rotated by +90 degrees)."""
    spacing = 2.0 * radius
    energy = 0.0
    for angle in (math.pi / 4, 3 * math.pi / 4):
        n = np.array([math.cos(angle), math.sin(angle)])
        t = np.array([-n[1], n[0]])
        gap = spacing * (gradient @ n) - phi * spacing * t
        energy += 0.5 * KN * (gap @ n) ** 2 + 0.5 * KS * (gap @ t) ** 2
    return energy / spacing ** 2


def continuum_energy(law, gradient, phi):
    """1/2 int sigma(eps) : eps over the unit square of the affine field [J/m]."""
    mesh, _, _ = meshes.rectangle(MPI.COMM_WORLD, 1.0, 1.0, divisions=(2, 2), cell_type="quadrilateral")
    space = compat.function_space(mesh, compat.lagrange_element(mesh, 1, (2,)))
    u = dolfinx.fem.Function(space)
    u.interpolate(lambda x: np.vstack([gradient[0, 0] * x[0] + gradient[0, 1] * x[1],
                                       gradient[1, 0] * x[0] + gradient[1, 1] * x[1]]))
    eps = strain(u, dolfinx.fem.Constant(mesh, phi))
    form = dolfinx.fem.form(0.5 * ufl.inner(law.stress(eps), eps) * ufl.dx)
    return mesh.comm.allreduce(dolfinx.fem.assemble_scalar(form), op=MPI.SUM)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_affine_energy_is_the_contact_springs(seed):
    rng = np.random.default_rng(seed)
    gradient = 1e-3 * rng.standard_normal((2, 2))
    phi = 1e-3 * rng.standard_normal()
    exact = lattice_energy(gradient, phi)
    law = SquareLatticeElasticity(k_n=KN, k_s=KS, l_c=0.05)
    assert continuum_energy(law, gradient, phi) == pytest.approx(exact, rel=1e-10)
    average = MicropolarElasticity(mu=(KN + KS) / 4, lmbda=(KN - KS) / 4, mu_c=KS / 2)
    assert abs(continuum_energy(average, gradient, phi) / exact - 1.0) > 0.01


def test_moduli_and_rigid_rotation():
    law = SquareLatticeElasticity(k_n=KN, k_s=KS)
    assert law.moduli == (1.5e8, 1.0e8, 1.25e8) and law.mu_c == 2.5e7 and law.p_wave_modulus == KN
    rotation = np.array([[0.0, -1e-3], [1e-3, 0.0]])
    assert lattice_energy(rotation, 1e-3) == pytest.approx(0.0, abs=1e-25)
    assert continuum_energy(law, rotation, 1e-3) == pytest.approx(0.0, abs=1e-20)
    # compression along y: C11 = (kN + kS)/2, the lattice's, not the average's lambda + 2 mu
    squeeze = np.array([[0.0, 0.0], [0.0, -1e-3]])
    assert lattice_energy(squeeze, 0.0) == pytest.approx(0.5 * 1.5e8 * 1e-6, rel=1e-12)
    for bad in ({"k_n": 0.0, "k_s": KS}, {"k_n": KN, "k_s": -1.0}, {"k_n": KN, "k_s": KS, "l_c": -1.0},
                {"k_n": float("nan"), "k_s": KS}):
        with pytest.raises(ValueError):
            SquareLatticeElasticity(**bad)
