"""The DEM region of the bridging-scale coupling: real grains, the virtual interface layer
(none on the free surface), and the whole-element check of the rectangle."""
import dolfinx.mesh
import numpy as np
import pytest
from mpi4py import MPI

from cosserat_fenicsx.bridging.region import build_region, region_cells
from cosserat_fenicsx.validation import InputError


def square_lattice(box, r):
    """Discs of radius r touching on a square lattice of spacing 2r covering box."""
    xs = np.arange(box[0] + r, box[1], 2 * r)
    ys = np.arange(box[2] + r, box[3], 2 * r)
    x, y = np.meshgrid(xs, ys)
    return np.column_stack([x.ravel(), y.ravel()])


def test_lattice_layer_is_the_next_rows_and_none_on_the_free_top():
    r = 0.05
    domain = (0.0, 3.0, 0.0, 2.0)
    position = square_lattice(domain, r)
    n = len(position)
    ones = np.ones(n)
    box = (1.0, 2.0, 1.0, 2.0)            # top edge on the domain's top: free surface
    region = build_region(position, r * ones, ones, ones, box, domain)
    assert region.free_edges == ("top",)
    real = region.position[region.real]
    virtual = region.position[region.virtual]
    assert region.n_real == 10 * 10
    # one column left, one right, one row below (corners touch diagonally? no: gap > 0)
    assert region.n_virtual == 10 + 10 + 10
    assert np.all(virtual[:, 1] < 2.0)
    assert np.all((virtual[:, 0] < 1.0) | (virtual[:, 0] > 2.0) | (virtual[:, 1] < 1.0))
    assert np.isclose(region.layer_width, r)
    assert real.min() > 1.0 and real[:, 1].max() < 2.0
    # the 'diameter' rule takes every grain within 2 r_max: also the diagonal corners
    wide = build_region(position, r * ones, ones, ones, box, domain, layer="diameter")
    assert wide.n_virtual == 10 + 10 + 10 + 2


def test_escaped_grains_are_named():
    r = 0.05
    domain = (0.0, 3.0, 0.0, 2.0)
    position = square_lattice(domain, r)
    ones = np.ones(len(position))
    region = build_region(position, r * ones, ones, ones, (1.0, 2.0, 1.0, 2.0), domain)
    moved = region.position[region.real].copy()
    assert region.escaped(moved).size == 0
    moved[7, 1] += 1.5
    assert region.escaped(moved).tolist() == [7]
    # the safe box: a centre on its edge is within one margin (a diameter) of Omega_D, and
    # one just beyond its corner is not yet counted (the full test decides there)
    margin = region.escape_margin()
    assert margin == 2 * r
    x0, x1, y0, y1 = region.safe_box()
    moved[7] = (x1, y1)
    assert np.hypot(x1 - 2.0, y1 - 2.0) < margin and region.escaped(moved).size == 0
    moved[7] = (x1 + 0.31 * margin, 1.5)
    assert region.escaped(moved).tolist() == [7]


def test_region_must_be_whole_elements():
    mesh = dolfinx.mesh.create_rectangle(MPI.COMM_WORLD, [np.array([0.0, 0.0]), np.array([6.0, 3.0])],
                                         [6, 3], dolfinx.mesh.CellType.quadrilateral)
    cells = region_cells(mesh, (2.0, 4.0, 1.0, 3.0))
    assert MPI.COMM_WORLD.allreduce(len(cells)) == 4
    with pytest.raises(InputError, match="whole elements"):
        region_cells(mesh, (2.5, 4.0, 1.0, 3.0))
    with pytest.raises(InputError, match="cuts an element"):
        region_cells(mesh, (2.0, 4.6, 1.0, 3.0))
    with pytest.raises(InputError, match="must be"):
        region_cells(mesh, (4.0, 2.0, 1.0, 3.0))


def test_region_outside_domain_refused():
    ones = np.ones(3)
    with pytest.raises(InputError, match="not inside the domain"):
        build_region(np.zeros((3, 2)) + 0.5, ones * 0.1, ones, ones, (0.0, 4.0, 0.0, 1.0), (0, 3, 0, 2))
