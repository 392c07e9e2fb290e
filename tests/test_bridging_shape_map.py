"""The particle -> element map of the bridging-scale coupling: shape functions at grain
centres (Q1, P1, P2), exact interpolation of fields the element contains, N^T 1 = particle
count, and the same numbers on 1 and 2 ranks (each particle counted once)."""
import os
import subprocess
import sys

import dolfinx.fem
import dolfinx.mesh
import numpy as np
import pytest
from mpi4py import MPI
from petsc4py import PETSc

from cosserat_fenicsx import compat
from cosserat_fenicsx.bridging.shape_map import CosseratShapeMap, component_spaces

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def cosserat_space(cell, degree_u, degree_phi, comm=MPI.COMM_WORLD):
    kind = dolfinx.mesh.CellType.quadrilateral if cell == "quad" else dolfinx.mesh.CellType.triangle
    mesh = dolfinx.mesh.create_rectangle(comm, [np.array([0.0, 0.0]), np.array([3.0, 2.0])],
                                         [3, 2], kind)
    element = compat.mixed_element([compat.lagrange_element(mesh, degree_u, (2,)),
                                    compat.lagrange_element(mesh, degree_phi)])
    return compat.function_space(mesh, element)


def fill(space, fields):
    """A ghosted Vec over W holding the interpolants of fields {name: f(x)}."""
    w = dolfinx.fem.Function(space)
    vec = compat.petsc_vector(w)
    spaces = component_spaces(space)
    with vec.localForm() as loc:
        for name, f in fields.items():
            collapsed, to_parent = spaces[name]
            coords = collapsed.tabulate_dof_coordinates()
            loc.array[to_parent] = f(coords[:, 0], coords[:, 1])
    return w, vec


def particles(n=60, seed=1):
    rng = np.random.default_rng(seed)
    points = rng.uniform([0, 0], [3, 2], size=(n, 2))
    # some on element edges and nodes, the hard case for 'counted once'
    return np.vstack([points, [[1.0, 1.0], [2.0, 0.5], [1.5, 1.0], [3.0, 2.0], [0.0, 0.0]]])


CASES = {
    "Q1/Q1": ("quad", 1, 1, lambda x, y: 1 + 2 * x - 3 * y + 0.5 * x * y,
              lambda x, y: -0.3 + x * y, lambda x, y: 0.01 - 0.02 * x + 0.03 * y * x),
    "P1/P1": ("tri", 1, 1, lambda x, y: 1 + 2 * x - 3 * y, lambda x, y: 0.2 * x,
              lambda x, y: 0.01 - 0.02 * y),
    "P2/P1": ("tri", 2, 1, lambda x, y: x * x - x * y + 2 * y, lambda x, y: y * y + 0.1,
              lambda x, y: 0.01 - 0.02 * x + y),
}


@pytest.mark.parametrize("case", list(CASES))
def test_interpolation_exact_and_partition_of_unity(case):
    cell, du, dphi, f1, f2, fphi = CASES[case]
    space = cosserat_space(cell, du, dphi)
    points = particles()
    shape = CosseratShapeMap(space, points)
    _, vec = fill(space, {"u1": f1, "u2": f2, "phi": fphi})
    values = shape.interpolate(vec, root=None)
    x, y = points.T
    exact = np.column_stack([f1(x, y), f2(x, y), fphi(x, y)])
    assert np.abs(values - exact).max() < 1e-12
    # N^T 1 over each component sums to the particle count
    w, forces_vec = fill(space, {})
    forces_vec.set(0.0)
    forces_vec.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
    shape.add_transpose(np.ones((len(points), 3)), forces_vec)
    assert forces_vec.sum() == pytest.approx(3 * len(points), rel=1e-12)
    # and N^T F is the adjoint of the interpolation: d . N^T F = (N d) . F
    rng = np.random.default_rng(5)
    forces = rng.normal(size=(len(points), 3))
    forces_vec.set(0.0)
    shape.add_transpose(forces, forces_vec)
    assert vec.dot(forces_vec) == pytest.approx(np.sum(values * forces), rel=1e-12)
    n_u, n_phi = shape.matrices(root=None)
    assert n_u.shape[0] == len(points)
    assert np.allclose(np.asarray(n_u.sum(axis=1)).ravel(), 1.0)
    assert np.allclose(np.asarray(n_phi.sum(axis=1)).ravel(), 1.0)


@pytest.mark.parametrize("case", list(CASES))
def test_compiled_products_equal_scipys_bit_for_bit(case):
    """The compiled N x (three fields at once, one field, the translations only) and N^T F
    (kernels.py) give scipy's CSR products to the last bit (same sums in the same order), so
    a coupled run does not change with them."""
    cell, du, dphi, f1, f2, fphi = CASES[case]
    space = cosserat_space(cell, du, dphi)
    points = particles()
    shape = CosseratShapeMap(space, points)
    rng = np.random.default_rng(11)
    # the Functions are kept: a Vec only wraps its Function's memory
    functions = [fill(space, {}) for _ in range(3)]
    vecs = [vec for _, vec in functions]
    for vec in vecs:
        with vec.localForm() as loc:
            loc.array[:] = rng.normal(size=loc.array.size)
        vec.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
    m = shape.local_matrix
    with vecs[0].localForm() as a, vecs[1].localForm() as b, vecs[2].localForm() as c:
        stacked = np.column_stack([a.array_r, b.array_r, c.array_r])
    expected = m @ stacked
    assert np.array_equal(shape.local_values(vecs), expected)
    assert np.array_equal(shape.local_values(vecs[1:2])[:, 0], m @ stacked[:, 1])
    if MPI.COMM_WORLD.size == 1:
        three = shape.interpolate(vecs[0], root=0)
        assert np.array_equal(shape.interpolate_translation(vecs[0], root=0), three[:, :2])
    forces = rng.normal(size=(len(points), 3))
    target, out = fill(space, {})
    out.set(0.0)
    shape.add_transpose(forces, out)
    if MPI.COMM_WORLD.size == 1:
        assert np.array_equal(out.array, m.T.tocsr() @ forces.ravel())


def test_particle_outside_mesh_is_refused():
    from cosserat_fenicsx.validation import InputError
    space = cosserat_space("quad", 1, 1)
    with pytest.raises(InputError, match="outside the mesh"):
        CosseratShapeMap(space, np.array([[0.5, 0.5], [3.5, 1.0]]))


def report(path):
    """Interpolated values and assembled N^T F (by global dof coordinates) for the Q1/Q1
    case, written by rank 0: the serial/parallel comparison."""
    cell, du, dphi, f1, f2, fphi = CASES["Q1/Q1"]
    space = cosserat_space(cell, du, dphi)
    points = particles()
    shape = CosseratShapeMap(space, points)
    source, vec = fill(space, {"u1": f1, "u2": f2, "phi": lambda x, y: np.sin(x) * np.cos(y)})
    values = shape.interpolate(vec, root=0)
    forces = np.random.default_rng(5).normal(size=(len(points), 3))
    target, out = fill(space, {})
    out.set(0.0)
    shape.add_transpose(forces, out)
    spaces = component_spaces(space)
    table = []
    with out.localForm() as loc:
        for c, name in enumerate(("u1", "u2", "phi")):
            collapsed, to_parent = spaces[name]
            n_owned = collapsed.dofmap.index_map.size_local
            coords = collapsed.tabulate_dof_coordinates()[:n_owned, :2]
            for xy, v in zip(coords, loc.array[to_parent[:n_owned]]):
                table.append((c, round(xy[0], 9), round(xy[1], 9), v))
    table = MPI.COMM_WORLD.gather(table, root=0)
    if MPI.COMM_WORLD.rank == 0:
        table = np.array(sorted(sum(table, [])))
        np.savez(path, values=values, table=table)


@pytest.mark.serial
def test_one_and_two_ranks_agree(tmp_path):
    env = dict(os.environ, PYTHONPATH=ROOT, OMPI_ALLOW_RUN_AS_ROOT="1",
               OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1", OMPI_MCA_rmaps_base_oversubscribe="1",
               OMP_NUM_THREADS="1")
    results = {}
    for n in (1, 2):
        path = tmp_path / f"np{n}.npz"
        cmd = ["mpirun", "-n", str(n), sys.executable, os.path.abspath(__file__), str(path)]
        subprocess.run(cmd, check=True, env=env, timeout=120, capture_output=True)
        results[n] = np.load(path)
    assert np.allclose(results[1]["values"], results[2]["values"], rtol=1e-12, atol=1e-14)
    assert np.array_equal(results[1]["table"][:, :3], results[2]["table"][:, :3])
    assert np.allclose(results[1]["table"][:, 3], results[2]["table"][:, 3], rtol=1e-12, atol=1e-13)


if __name__ == "__main__":
    report(sys.argv[1])


@pytest.mark.parametrize("case", list(CASES))
def test_lumped_mass_positive_and_total(case):
    """The grains' coarse mass: row sums for Q1/P1, HRZ for P2 (whose row sums go negative):
    every dof >= 0, each component's total = the particles' total, weightless particles add 0."""
    cell, du, dphi = CASES[case][:3]
    space = cosserat_space(cell, du, dphi)
    points = particles(200, seed=4)
    shape = CosseratShapeMap(space, points)
    weights = np.random.default_rng(2).uniform(1.0, 2.0, size=(len(points), 3))
    weights[-20:] = 0.0
    _, vec = fill(space, {})
    vec.set(0.0)
    shape.add_lumped_mass(weights, vec)
    assert vec.array.min() >= 0.0 and np.isfinite(vec.array).all()
    spaces = component_spaces(space)
    n_owned = vec.getLocalSize()
    for c, name in enumerate(("u1", "u2", "phi")):
        dofs = spaces[name][1]
        total = MPI.COMM_WORLD.allreduce(float(vec.array[dofs[dofs < n_owned]].sum()))
        assert total == pytest.approx(weights[:, c].sum(), rel=1e-12)
