"""The bridging-scale projection of paper 003 (eqs 3-8, 12): algebra on random grain sets
with bilinear (Q1) shape functions built here independently of dolfinx."""
import numpy as np
import pytest
import scipy.sparse

from cosserat_fenicsx.bridging.projection import ScaleProjection
from cosserat_fenicsx.validation import InputError


def q1_shape(points, nx, ny, h=1.0):
    """Scalar bilinear shape functions of an nx x ny grid of square cells (side h) at points:
    (sparse (n, (nx+1)(ny+1)), element index of each point). Node (i, j) is j*(nx+1)+i."""
    i = np.minimum((points[:, 0] // h).astype(int), nx - 1)
    j = np.minimum((points[:, 1] // h).astype(int), ny - 1)
    xi = points[:, 0] / h - i
    eta = points[:, 1] / h - j
    rows, cols, vals = [], [], []
    for di, dj, w in ((0, 0, (1 - xi) * (1 - eta)), (1, 0, xi * (1 - eta)),
                      (0, 1, (1 - xi) * eta), (1, 1, xi * eta)):
        rows.append(np.arange(len(points)))
        cols.append((j + dj) * (nx + 1) + i + di)
        vals.append(w)
    n = scipy.sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                                shape=(len(points), (nx + 1) * (ny + 1)))
    return n, j * nx + i


@pytest.fixture
def grains():
    rng = np.random.default_rng(3)
    nx, ny = 3, 2
    points = rng.uniform([0, 0], [nx, ny], size=(300, 2))
    radius = rng.uniform(0.02, 0.05, size=300)
    mass = 2600 * np.pi * radius ** 2
    inertia = 0.5 * mass * radius ** 2
    shape, element = q1_shape(points, nx, ny)
    return points, mass, inertia, shape, element, rng


def dense_projector(proj, shape, mass, inertia):
    """P as a dense 3n x 3n matrix (component blocks), built from its definition eq 4."""
    n = len(mass)
    full = np.zeros((3 * n, 3 * n))
    for c, w in enumerate((mass, mass, inertia)):
        ns = shape[:, proj.nodes_u].toarray()
        m = ns.T @ (w[:, None] * ns)
        full[c::3, c::3] = ns @ np.linalg.solve(m, ns.T * w)
    return full


def test_projector_algebra(grains):
    points, mass, inertia, shape, element, rng = grains
    proj = ScaleProjection(shape, mass, inertia, element_of_particle=element)
    q = rng.normal(size=(len(mass), 3))
    pq = proj.coarse(q)
    assert np.array_equal(proj.coarse_translation(q), pq[:, :2])
    # P^2 = P
    assert np.abs(proj.coarse(pq) - pq).max() < 1e-12 * np.abs(pq).max()
    # P N = N: any nodal field is reproduced
    d = proj.project(q)
    d.u = rng.normal(size=d.u.shape)
    d.phi = rng.normal(size=d.phi.shape)
    nd = proj.interpolate(d)
    assert np.abs(proj.coarse(nd) - nd).max() < 1e-12 * np.abs(nd).max()
    # N^T M_p Q = 0 (eq 12), relative to N^T M_p q
    fine = proj.fine(q)
    ns = shape[:, proj.nodes_u]
    for c, w in enumerate((mass, mass, inertia)):
        residual = ns.T @ (w * fine[:, c])
        scale = np.abs(ns.T @ (w * np.abs(q[:, c]))).max()
        assert np.abs(residual).max() < 1e-12 * scale
    # agrees with the dense definition P = N M^-1 N^T M_p (eq 4)
    p = dense_projector(proj, shape, mass, inertia)
    assert np.allclose(p @ q.ravel(), pq.ravel(), atol=1e-12)


def test_kinetic_energy_split(grains):
    points, mass, inertia, shape, element, rng = grains
    proj = ScaleProjection(shape, mass, inertia)
    qdot = rng.normal(size=(len(mass), 3)) * [1.0, 1.0, 30.0]
    total, coarse, fine = proj.kinetic_energy(qdot)
    assert coarse > 0 and fine > 0
    assert abs(total - coarse - fine) < 1e-13 * total


@pytest.mark.parametrize("field", ["translation", "rotation", "affine"])
def test_rigid_and_affine_motions_have_no_fine_part(grains, field):
    points, mass, inertia, shape, element, rng = grains
    proj = ScaleProjection(shape, mass, inertia, element_of_particle=element)
    x, y = points.T
    q = np.zeros((len(mass), 3))
    if field == "translation":
        q[:, 0], q[:, 1] = 0.013, -0.02
    elif field == "rotation":
        theta, centre = 0.004, np.array([1.3, 0.7])
        # small rigid rotation u = theta e_z x (x - c), the grains turning with the body
        q[:, 0] = -theta * (y - centre[1])
        q[:, 1] = theta * (x - centre[0])
        q[:, 2] = theta
    else:
        a = np.array([[0.01, -0.003], [0.004, -0.02]])
        q[:, :2] = points @ a.T + [0.002, -0.001]
        q[:, 2] = 0.001 + 0.002 * x - 0.003 * y
    assert np.abs(proj.fine(q)).max() < 1e-13
    # and the projection recovers the nodal values of the field itself
    assert np.allclose(proj.coarse(q), q, atol=1e-13)


def test_lumped_mass_is_row_sum(grains):
    points, mass, inertia, shape, element, rng = grains
    proj = ScaleProjection(shape, mass, inertia)
    lumped_u, lumped_phi = proj.lumped_mass()
    m_u, m_phi = proj.matrices
    assert np.allclose(lumped_u, m_u.sum(axis=1), rtol=1e-12)
    assert np.allclose(lumped_phi, m_phi.sum(axis=1), rtol=1e-12)
    assert abs(lumped_u.sum() - mass.sum()) < 1e-12 * mass.sum()


def test_element_with_too_few_grains_is_refused_by_name():
    rng = np.random.default_rng(0)
    points = rng.uniform([0, 0], [2, 1], size=(40, 2))
    points = points[(points[:, 0] < 1.0)]
    # element 1 (x in [1, 2]) gets three grains only
    points = np.vstack([points, [[1.2, 0.3], [1.7, 0.5], [1.4, 0.8]]])
    shape, element = q1_shape(points, 2, 1)
    mass = np.ones(len(points))
    with pytest.raises(InputError, match="element 1 holds 3 grain"):
        ScaleProjection(shape, mass, 0.01 * mass, element_of_particle=element)
    # without the element map a singular M is still refused (its nodes named): one grain
    # cannot fix the two nodes that element 1 alone carries
    shape, element = q1_shape(points[:-2], 2, 1)
    with pytest.raises(InputError, match="singular"):
        ScaleProjection(shape, mass[:-2], 0.01 * mass[:-2])


def test_collinear_grains_are_refused():
    points = np.array([[0.1 + 0.2 * k, 0.5] for k in range(5)])
    shape, element = q1_shape(points, 1, 1)
    with pytest.raises(InputError, match="element 0 holds 5 grain"):
        ScaleProjection(shape, np.ones(5), np.ones(5), element_of_particle=element)
