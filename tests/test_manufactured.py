"""Manufactured solution: observed convergence orders of u and phi in L2 and H1."""
import pytest
from mpi4py import MPI

from cosserat_fenicsx import manufactured

MESHES = (4, 8, 16, 32)


def series(elasticity, cell_type="triangle", degree_u=2, degree_phi=1, micropolar=True, meshes=MESHES):
    return [manufactured.solve(MPI.COMM_WORLD, n, elasticity, cell_type, degree_u, degree_phi, micropolar)
            for n in meshes]


def assert_orders(results, expected):
    for key, order in expected.items():
        observed = manufactured.rates(results, key)[-2:]  # asymptotic range
        assert order - 0.15 < min(observed) and max(observed) < order + 0.5, (key, observed)


@pytest.mark.parametrize("cell_type", ["triangle", "quadrilateral"])
def test_taylor_hood_orders(cell_type):
    """P2 displacement 3 (L2) / 2 (H1), P1 rotation 2 / 1."""
    results = series(manufactured.DEFAULT_ELASTICITY, cell_type)
    assert_orders(results, {"u_L2": 3.0, "u_H1": 2.0, "phi_L2": 2.0, "phi_H1": 1.0})


def test_taylor_hood_large_internal_length():
    """l_c ~ domain: the P1 rotation limits u in L2 to order 2 (see manufactured.py)."""
    results = series(manufactured.LARGE_LENGTH_ELASTICITY)
    assert_orders(results, {"u_L2": 2.0, "u_H1": 2.0, "phi_L2": 2.0, "phi_H1": 1.0})


def test_equal_order_p2_p2():
    """Other degrees are selectable; P2/P2 gives 3/2 for both fields even at large l_c."""
    results = series(manufactured.LARGE_LENGTH_ELASTICITY, degree_phi=2)
    assert_orders(results, {"u_L2": 3.0, "u_H1": 2.0, "phi_L2": 3.0, "phi_H1": 2.0})


def test_cauchy_scene_orders():
    results = series(manufactured.DEFAULT_ELASTICITY, micropolar=False)
    assert_orders(results, {"u_L2": 3.0, "u_H1": 2.0})
    assert "phi_L2" not in results[0]
