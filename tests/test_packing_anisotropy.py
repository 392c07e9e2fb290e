"""The anisotropic packings of 000 section 4.3.3 as the demos make them: demcell.generate_packing's
deviatoric pre-compaction reaches the target A0 (000 eq. 38) of the demos' cell closely, with the
fabric's major axis along x (the axis more loaded in the pre-compaction), and femdem_biaxial's
cells (CellOptions.anisotropy) get the very grains dem_specimen's tiled DNS tiles."""
import numpy as np
import pytest

import demcell as dc
from cosserat_fenicsx.materials.dem.cells import CellOptions

#: the demos' law (000 Table 3) and confining pressure
LAW = dict(kn=1.0e4, ks=2.0e3, friction=0.4)
#: how close the scan of 10 deviators gets for 228 discs: it stops within 0.005, but A0(deviator)
#: is noisy and the closest trial can be further (seed 0 at 0.02: 0.010; seed 3 at 0.05: 0.042)
TOLERANCE = 0.01


@pytest.mark.parametrize("seed, target", [(1, 0.05), (1, 0.08), (3, 0.08)])
def test_target_reached_with_the_major_axis_along_x(seed, target):
    state, info = dc.generate_packing(228, pressure=10.0, law=dc.ContactLaw(**LAW), seed=seed, anisotropy=target)
    fabric = dc.DemCell(state, dc.ContactLaw(**LAW)).homogenized().fabric
    w = np.linalg.eigvalsh(fabric)
    assert w[1] / w[0] - 1.0 == pytest.approx(info["anisotropy"], abs=1e-12)       # 000 eqs. 38-39
    assert abs(info["anisotropy"] - target) <= TOLERANCE, info["anisotropy_trials"]
    assert fabric[0, 0] > fabric[1, 1] and np.allclose(info["fabric"], fabric)
    assert len(info["anisotropy_trials"]) > 1          # raised by a deviator, not the isotropic compaction's


def test_the_isotropic_compaction_is_not_isotropic_and_a_target_of_zero_lowers_it():
    """The seed-0 cell: its isotropic compaction gives A = 0.064 along y; a target 0 scans the
    deviators (x more loaded) and keeps the one closest to an isotropic fabric."""
    law = dc.ContactLaw(**LAW)
    _, free = dc.generate_packing(228, pressure=10.0, law=law, seed=0)
    _, zero = dc.generate_packing(228, pressure=10.0, law=law, seed=0, anisotropy=0.0)
    assert free["fabric"][1][1] > free["fabric"][0][0] and free["anisotropy"] > 0.05
    assert zero["anisotropy"] < 0.5 * free["anisotropy"]



def test_a_series_of_targets_shares_its_preparation():
    """Every trial of a target, the deviator 0 included, is compacted with friction 0.3: seed 0
    at 0.08 keeps the deviator 0 (its frictional compaction gives 0.078 along x), and is as
    loose as the others of the series, not as dense as the frictionless plain packing."""
    law = dc.ContactLaw(**LAW)
    _, plain = dc.generate_packing(228, pressure=10.0, law=law, seed=0)
    _, high = dc.generate_packing(228, pressure=10.0, law=law, seed=0, anisotropy=0.08)
    _, low = dc.generate_packing(228, pressure=10.0, law=law, seed=0, anisotropy=0.02)
    assert plain["prep_friction"] == 0.0 and high["prep_friction"] == low["prep_friction"] == 0.3
    assert high["anisotropy_trials"][0][0] == 0.0 and high["anisotropy"] == high["anisotropy_trials"][0][1]
    assert abs(high["solid_fraction"] - low["solid_fraction"]) < 0.01 < plain["solid_fraction"] - high["solid_fraction"]


def test_femdem_cells_and_the_tiled_dns_share_the_grains():
    """CellOptions (femdem_biaxial --anisotropy) and dem_specimen --specimen tiled --anisotropy
    both call generate_packing with the demos' law: the same discs, bit for bit."""
    options = CellOptions(seed=1, anisotropy=0.05)
    options.check()
    cell_state, cell_info = options.packing_state()
    dns_state, dns_info = dc.generate_packing(228, pressure=10.0, law=dc.ContactLaw(**LAW), seed=1, anisotropy=0.05)
    assert np.array_equal(cell_state.s, dns_state.s) and np.array_equal(cell_state.h, dns_state.h)
    assert cell_info["anisotropy"] == dns_info["anisotropy"]


@pytest.mark.parametrize("value", [1.0, -0.01, float("nan"), "0.05"])
def test_bad_targets_are_refused(value):
    with pytest.raises(ValueError, match="anisotropy"):
        CellOptions(anisotropy=value).check()
