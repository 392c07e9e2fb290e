"""Every difference between the supported dolfinx generations lives here.

Supported: dolfinx 0.5.2 (Debian 12: ufl 2022.2, basix 0.5, legacy UFL elements)
and dolfinx 0.9 (Debian 13: ufl 2024.2, basix.ufl elements, ``functionspace``).
The rest of the package calls these helpers and never tests the version itself.
"""
import basix
import dolfinx
import dolfinx.fem
import numpy as np
import ufl

DOLFINX_VERSION = tuple(int(p) for p in dolfinx.__version__.split(".")[:2])
LEGACY = DOLFINX_VERSION < (0, 7)

if not LEGACY:
    import basix.ufl


def cell_name(mesh):
    """'triangle' or 'quadrilateral'."""
    if LEGACY:
        return mesh.topology.cell_type.name
    return mesh.topology.cell_name()


def basix_cell(mesh):
    return getattr(basix.CellType, cell_name(mesh))


def _element(family, mesh, degree, shape):
    if LEGACY:
        cell = mesh.ufl_cell()
        if shape == ():
            return ufl.FiniteElement(family, cell, degree)
        if len(shape) == 1:
            return ufl.VectorElement(family, cell, degree, dim=shape[0])
        return ufl.TensorElement(family, cell, degree, shape=shape)
    return basix.ufl.element(family, cell_name(mesh), degree, shape=shape or None)


def lagrange_element(mesh, degree, shape=()):
    """Continuous Lagrange element of the given value shape (() scalar, (2,) vector)."""
    return _element("Lagrange", mesh, degree, shape)


def dg_element(mesh, degree, shape=()):
    """Discontinuous Lagrange element (output of quadrature data)."""
    return _element("DG", mesh, degree, shape)


def mixed_element(elements):
    if LEGACY:
        return ufl.MixedElement(elements)
    return basix.ufl.mixed_element(elements)


def quadrature_element(mesh, degree, size):
    """Vector quadrature element holding `size` values per Gauss point."""
    if LEGACY:
        return ufl.VectorElement("Quadrature", mesh.ufl_cell(), degree=degree,
                                 dim=size, quad_scheme="default")
    return basix.ufl.quadrature_element(cell_name(mesh), value_shape=(size,),
                                        scheme="default", degree=degree)


def function_space(mesh, element):
    if LEGACY:
        return dolfinx.fem.FunctionSpace(mesh, element)
    return dolfinx.fem.functionspace(mesh, element)


def quadrature_points(mesh, degree):
    """Reference points and weights of the default rule FFCx uses for `degree`."""
    points, weights = basix.make_quadrature(basix_cell(mesh), degree)
    return np.asarray(points), np.asarray(weights)


def eval_expression(expression, mesh, cells):
    """Evaluate a dolfinx Expression on `cells`: array (n_cells, n_points * value_size)."""
    if LEGACY:
        values = expression.eval(cells)
    else:
        values = expression.eval(mesh, cells)
    return np.asarray(values).reshape(len(cells), -1)


def petsc_vector(function):
    """The PETSc Vec wrapping a Function's values."""
    if LEGACY:
        return function.vector
    return function.x.petsc_vec


def gmsh_model_to_mesh(model, comm, rank, gdim):
    from dolfinx.io import gmshio
    out = gmshio.model_to_mesh(model, comm, rank, gdim=gdim)
    return out[0], out[1], out[2]


def num_owned_cells(mesh):
    return mesh.topology.index_map(mesh.topology.dim).size_local


def cell_dofs(space, n_cells):
    """Dof indices of the first n_cells cells, array (n_cells, dofs_per_cell)."""
    dofmap = space.dofmap.list
    if LEGACY:
        per_cell = space.dofmap.dof_layout.num_dofs
        return dofmap.array.reshape(-1, per_cell)[:n_cells]
    return np.asarray(dofmap)[:n_cells]


def apply_lifting(b, jacobian_form, bcs, x0, scale):
    """b -= scale-weighted lifting of the Dirichlet values relative to x0."""
    import dolfinx.fem.petsc
    if LEGACY:
        dolfinx.fem.petsc.apply_lifting(b, [jacobian_form], bcs=[bcs], x0=[x0], scale=scale)
    else:
        dolfinx.fem.petsc.apply_lifting(b, [jacobian_form], bcs=[bcs], x0=[x0], alpha=scale)


def set_bc(b, bcs, x0, scale):
    import dolfinx.fem.petsc
    if LEGACY:
        dolfinx.fem.petsc.set_bc(b, bcs, x0, scale)
    else:
        dolfinx.fem.petsc.set_bc(b, bcs, x0, alpha=scale)


def cell_geometry_nodes(mesh):
    """Geometry node indices of the local cells, array (n_cells, nodes_per_cell) into
    mesh.geometry.x."""
    dofmap = mesh.geometry.dofmap
    if LEGACY:
        per_cell = len(dofmap.links(0)) if dofmap.num_nodes else 0
        return dofmap.array.reshape(-1, per_cell) if per_cell else np.zeros((0, 0), dtype=np.int32)
    return np.asarray(dofmap)


def colliding_cells(mesh, points):
    """AdjacencyList of the local cells (owned and ghost) containing each point (n, 3)."""
    import dolfinx.geometry
    if LEGACY:
        tree = dolfinx.geometry.BoundingBoxTree(mesh, mesh.topology.dim)
        candidates = dolfinx.geometry.compute_collisions(tree, points)
    else:
        tree = dolfinx.geometry.bb_tree(mesh, mesh.topology.dim)
        candidates = dolfinx.geometry.compute_collisions_points(tree, points)
    return dolfinx.geometry.compute_colliding_cells(mesh, candidates, points)


def cell_geometry(mesh, cell):
    """Physical coordinates (n_nodes, gdim) of one local cell's geometry nodes."""
    return mesh.geometry.x[cell_geometry_nodes(mesh)[cell], :mesh.geometry.dim]


def pull_back(mesh, points, coordinates):
    """Reference coordinates (n, tdim) of physical points (n, gdim) in a cell."""
    cmap = mesh.geometry.cmap
    cmap = cmap() if callable(cmap) else cmap  # a method in some 0.8/0.9 builds
    return np.asarray(cmap.pull_back(np.asarray(points, dtype=float), coordinates))


def lagrange_degree(space):
    """Polynomial degree of a scalar Lagrange space."""
    element = space.ufl_element()
    if LEGACY:
        return element.degree()
    return element.embedded_superdegree


def basix_lagrange(mesh, degree):
    """The basix Lagrange element whose reference dof order dolfinx uses for `degree` <= 2
    (no variant dependence: vertex and edge-midpoint points only)."""
    return basix.create_element(basix.ElementFamily.P, basix_cell(mesh), degree,
                                basix.LagrangeVariant.gll_warped)
