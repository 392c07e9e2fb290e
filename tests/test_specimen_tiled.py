"""000's DNS built from the FEM x DEM cell: a column of tiles with periodic sides is the
stand-alone periodic cell plus the platens' boundary layers.

The cell is compressed along y with F_11 held (the periodic side of the DNS keeps its width);
the DNS of 1 x ny tiles with periodic x between smooth platens gets the same kinematics. The
platens soften the specimen by a layer of fixed compliance, so the axial compliance of the
DNS is c(ny) = c_cell + c_layer / ny: from ny = 2 and 4 the extrapolation ny -> infinity is
the cell's own compliance (measured: 1.48e-4 against 1.55e-4 1/(N/m), 5 %). A single tile
(ny = 1, some 15 rows) does not follow the law yet: its two platen layers overlap, and the
extrapolation from ny = 1 and 2 misses the cell by 30 %."""
import numpy as np
import pytest

import demcell as dc
from demcell.specimen import SpecimenOptions
from demcell.specimen.biaxial import BiaxialTest
from demcell.specimen.specimens import tiled_cell

# DEM only: nothing here uses MPI, so it runs in the serial pass alone
pytestmark = pytest.mark.serial

LAW = dc.ContactLaw(kn=1e4, ks=2e3, friction=0.4)
P0 = 10.0
STRAIN = 2e-3        # small: the contact network barely changes, the compliances are elastic


@pytest.fixture(scope="module")
def reference_cell():
    state, _ = dc.generate_packing(228, pressure=P0, law=LAW, seed=0)
    return dc.reference_cell(state, LAW, dc.RelaxationOptions(tol=1e-4, damping=0.7, criterion="force"), P0)


def cell_compliance(cell):
    cell = dc.DemCell(cell.state.copy(), LAW, dc.RelaxationOptions(tol=1e-4, damping=0.7, criterion="force"))
    F = cell.deformation_gradient()
    F[1, 1] *= 1.0 - STRAIN
    cell.set_deformation(F)
    assert cell.solve().converged
    return STRAIN / (-cell.homogenized().cauchy[1, 1] - P0)


def dns_compliance(cell, ny):
    discs = tiled_cell(cell.state, 1, ny, periodic_sides=True)
    rho = float(discs.mass.sum() / np.sum(np.pi * discs.radius ** 2))
    rate = 1e-4 * np.sqrt(P0 / rho) / (2 * discs.radius.mean())           # inertial number 1e-4
    options = SpecimenOptions(dt=0.1 * np.sqrt(discs.mass.min() / LAW.kn), lateral="periodic", pressure=P0,
                              local_damping=0.7, threads=1)
    test = BiaxialTest(discs, LAW, options, 0.5 * rate * discs.height)
    test.isotropic_stage(max_time=400.0)
    rows = []
    test.compress(until_strain=STRAIN, on_row=rows.append)
    strain = -np.array([r["axial_strain"] for r in rows])
    stress = -np.array([r["axial_stress"] for r in rows])
    late = strain > 0.25 * STRAIN          # the loading ramp of the first steps left out
    return 1.0 / np.polyfit(strain[late], stress[late], 1)[0]


def test_tiled_columns_converge_to_the_periodic_cell(reference_cell):
    c_cell = cell_compliance(reference_cell)
    c2 = dns_compliance(reference_cell, 2)
    c4 = dns_compliance(reference_cell, 4)
    assert c2 > c4 > c_cell                    # the platen layers soften, less so in a taller column
    layer = (c2 - c4) * 4.0                    # c(ny) = c_inf + layer / ny from ny = 2 and 4
    c_inf = c4 - layer / 4.0
    assert c_inf == pytest.approx(c_cell, rel=0.10), (c2, c4, c_inf, c_cell)
