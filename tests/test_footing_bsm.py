"""demos/footing_bsm.py as a user runs it: outputs written, 1 and 2 ranks agree, and until
the first wave comes back from the interface the BSM plate load equals the full-DEM one on
the same grains (the DEM is local: the grains under the plate cannot tell the difference)."""
import csv
import os

import numpy as np
import pytest

from conftest import read_summary

pytestmark = pytest.mark.serial


def history(out):
    with open(os.path.join(out, "history.csv")) as f:
        rows = list(csv.DictReader(f))
    return {k: np.array([float(r[k]) for r in rows]) for k in rows[0]}


def test_footing_bsm_outputs_and_ranks(demo, tmp_path):
    runs = {}
    for n in (1, 2):
        out = tmp_path / f"np{n}"
        demo("footing_bsm", "--packing", "A", "--depth", 0.004, "--record-every", 4, "--out", out, ranks=n)
        runs[n] = history(out)
        summary = read_summary(out)
        assert summary["completed"] and summary["grains_real"] > 1500 and summary["grains_virtual"] > 50
        for name in ("continuum.xdmf", "load_settlement.png", "grains_0000.vtk"):
            assert (out / name).exists()
    assert np.array_equal(runs[1]["settlement_mm"], runs[2]["settlement_mm"])
    assert np.allclose(runs[1]["load_kN_per_m"], runs[2]["load_kN_per_m"], rtol=1e-10)
    assert runs[1]["load_kN_per_m"][-1] > 100.0


def test_early_load_equals_full_dem(demo, tmp_path):
    from demcell.specimen.footing import run_footing
    demo("footing_bsm", "--packing", "A", "--depth", 0.004, "--record-every", 1, "--out", tmp_path)
    bsm = history(tmp_path)
    full = run_footing("A", depth=0.004, mass_damping=10.0, record_every=1, threads=1)
    reference = np.interp(bsm["settlement_mm"], 1e3 * full.settlement, 1e-3 * full.load)
    assert np.allclose(bsm["load_kN_per_m"], reference, rtol=1e-6, atol=1e-6)
