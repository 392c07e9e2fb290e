"""The grains of bounded specimens: 004's lattice, 000's tiled cell, packing files."""
import math

import numpy as np
import pytest

import demcell as dc
from demcell.errors import InputError
from demcell.specimen.specimens import read_discs, thesis_lattice, tiled_cell

# DEM only: nothing here uses MPI, so it runs in the serial pass alone
pytestmark = pytest.mark.serial


def _overlapping_pairs(position, radius, lattice=None):
    """Brute force: pairs (i < j) closer than r_i + r_j (minimum image of the periodic
    `lattice`, columns the period vectors)."""
    d = position[None, :, :] - position[:, None, :]
    if lattice is not None:
        f = d @ np.linalg.inv(lattice).T
        d = (f - np.round(f)) @ lattice.T
    dist = np.hypot(d[..., 0], d[..., 1])
    i, j = np.nonzero(np.triu(dist < (radius[:, None] + radius[None, :]) * (1 - 1e-12), 1))
    return set(zip(i.tolist(), j.tolist()))


def test_thesis_lattice_default_is_the_spec_geometry():
    discs = thesis_lattice()
    assert discs.n_discs == 114 * 263 == 29982
    assert discs.width == pytest.approx(229.0)
    assert discs.height == pytest.approx(2.0 + 262 * math.sqrt(3.0))
    assert discs.height / discs.width == pytest.approx(1.99, abs=0.005)
    assert discs.mass[0] == pytest.approx(math.pi)            # rho 1 kg/m^3, 1 m depth
    assert discs.inertia[0] == pytest.approx(math.pi / 2.0)


def test_thesis_lattice_neighbours_touch_without_overlap():
    discs = thesis_lattice(nx=6, ny=5)
    d = np.hypot(*(discs.position[None] - discs.position[:, None]).transpose(2, 0, 1))
    np.fill_diagonal(d, np.inf)
    assert d.min() == pytest.approx(2.0, rel=1e-14)
    interior = 6 + 2                                          # row 1, disc 2: six neighbours
    assert np.sum(np.isclose(d[interior], 2.0, rtol=1e-12)) == 6
    # every disc lies in the box, the outermost discs touch it
    assert np.all(discs.position[:, 0] - discs.radius >= discs.box[0] - 1e-12)
    assert np.all(discs.position[:, 1] + discs.radius <= discs.box[3] + 1e-12)
    assert np.min(discs.position[:, 1] - discs.radius) == pytest.approx(discs.box[2])


def test_perturbed_lattice_is_reproducible_and_never_overlaps():
    a = thesis_lattice(nx=8, ny=8, perturbation=0.05, seed=3)
    b = thesis_lattice(nx=8, ny=8, perturbation=0.05, seed=3)
    np.testing.assert_array_equal(a.radius, b.radius)
    assert np.all(a.radius <= 1.0) and np.all(a.radius >= 0.95)
    assert not _overlapping_pairs(a.position, a.radius)


def _cell():
    state, _ = dc.generate_packing(40, pressure=10.0, seed=2)
    return state


def test_tiling_keeps_every_periodic_contact_of_the_cell():
    cell = _cell()
    h = cell.h
    x = np.mod(cell.s, 1.0) @ h.T
    cell_pairs = _overlapping_pairs(x, cell.radius, lattice=h)
    assert len(cell_pairs) > 40
    discs = tiled_cell(cell, 2, 3)
    assert discs.n_discs == 6 * cell.radius.size
    tiled_pairs = _overlapping_pairs(discs.position, discs.radius, lattice=h @ np.diag([2.0, 3.0]))
    assert len(tiled_pairs) == 6 * len(cell_pairs)
    # without the periodic images: the contacts across the outer faces are the only ones lost
    inner = _overlapping_pairs(discs.position, discs.radius)
    assert len(cell_pairs) * 6 > len(inner) > 0


def test_tiling_with_periodic_sides_spans_the_period():
    cell = _cell()
    discs = tiled_cell(cell, 2, 1, periodic_sides=True)
    assert discs.periodic_width == pytest.approx(2 * cell.h[0, 0])
    assert discs.width == pytest.approx(discs.periodic_width)


def test_packing_files_round_trip(tmp_path):
    cell = _cell()
    dc.save_packing(tmp_path / "cell.npz", cell)
    discs = read_discs(tmp_path / "cell.npz", tiles=(2, 2))
    assert discs.n_discs == 4 * cell.radius.size
    table = tmp_path / "discs.txt"
    np.savetxt(table, np.column_stack([discs.position, discs.radius]))
    again = read_discs(table, density=2000.0)
    np.testing.assert_allclose(again.position, discs.position, rtol=1e-15)
    np.testing.assert_allclose(again.mass, 2000.0 * np.pi * discs.radius ** 2)
    np.savez(tmp_path / "discs.npz", position=discs.position, radius=discs.radius, mass=discs.mass)
    np.testing.assert_array_equal(read_discs(tmp_path / "discs.npz").mass, discs.mass)


@pytest.mark.parametrize("call, words", [
    (lambda: thesis_lattice(nx=0), "nx"),
    (lambda: thesis_lattice(nx=10.5), "nx"),
    (lambda: thesis_lattice(radius=float("nan")), "radius"),
    (lambda: thesis_lattice(density=-1.0), "density"),
    (lambda: thesis_lattice(perturbation=0.7), "perturbation"),
    (lambda: thesis_lattice(nx=10 ** 5, ny=10 ** 5), "nx * ny"),
    (lambda: tiled_cell(_cell(), 0, 2), "nx"),
    (lambda: tiled_cell(_cell(), 2, 1001), "ny"),
    (lambda: tiled_cell("cell", 2, 2), "cell_state"),
])
def test_bad_specimens_are_refused_in_one_line(call, words):
    with pytest.raises(InputError) as error:
        call()
    assert words in str(error.value) and "\n" not in str(error.value)


def test_a_sheared_cell_is_refused():
    cell = _cell()
    cell.h[0, 1] = 0.1 * cell.h[0, 0]
    with pytest.raises(InputError, match="sheared"):
        tiled_cell(cell, 2, 2)


@pytest.mark.parametrize("content, words", [
    (b"", "empty"),
    (b"PK\x03\x04 not really a zip", "cannot be read"),
    (b"1 2\n3 4\n", "3 columns"),
    (b"x y r\n", "not a table"),
    (b"# only a comment\n", "no rows"),
])
def test_damaged_packing_files_are_refused_in_one_line(tmp_path, content, words):
    path = tmp_path / ("p.npz" if content.startswith(b"PK") else "p.txt")
    path.write_bytes(content)
    with pytest.raises(InputError) as error:
        read_discs(path, density=1.0)
    assert words in str(error.value) and "\n" not in str(error.value)


def test_missing_density_and_missing_file_are_refused(tmp_path):
    (tmp_path / "p.txt").write_text("0 0 1\n3 0 1\n")
    with pytest.raises(InputError, match="density"):
        read_discs(tmp_path / "p.txt")
    with pytest.raises(InputError, match="not found"):
        read_discs(tmp_path / "nothing.npz")
    np.savez(tmp_path / "other.npz", a=np.ones(3))
    with pytest.raises(InputError, match="neither"):
        read_discs(tmp_path / "other.npz")
