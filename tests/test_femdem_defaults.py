"""The FEM x DEM defaults are the documented ones (docs/reference/femdem.md, "The cells'
relaxation"; chosen by benchmarks/femdem/femdem_defaults.py, docs/results/femdem.md "Default
cells"): the demo run as a user runs it gets FIRE cells relaxed to an unbalanced-force ratio of
1e-3, batched, with the pstlo operator, and the settings before them stay reachable by options."""
import json

import pytest

pytestmark = pytest.mark.serial

#: what docs/reference/femdem.md states
DOCUMENTED = {"method": "fire", "criterion": "force", "tol": 1e-3, "dt_safety": 0.25, "fire_dt_max": 2.0,
              "strain_rate": 1e-5, "damping": 0.7, "fixed_steps": None}
SMALL = ("--mesh", "1x1", "--particles", 20, "--axial-strain", 0.001, "--steps", 1)


def ran_with(out):
    mode = json.loads((out / "summary.json").read_text())["mode"]
    return mode["relaxation"], mode["tangent"], mode["batched"]


def test_the_settings_default_to_the_documented_cells():
    from cosserat_fenicsx.materials.dem import CellOptions
    from cosserat_fenicsx.scenes.femdem_biaxial import FemDemSettings
    relaxation = CellOptions().relaxation()
    assert {k: getattr(relaxation, k) for k in DOCUMENTED} == DOCUMENTED
    s = FemDemSettings()
    assert s.tangent == "pstlo" and s.batched is True


def test_the_demo_runs_the_documented_cells_and_the_old_ones_on_request(demo, tmp_path):
    demo("femdem_biaxial", *SMALL, "--out", tmp_path / "default")
    relaxation, tangent, batched = ran_with(tmp_path / "default")
    assert {k: relaxation[k] for k in DOCUMENTED} == DOCUMENTED
    assert tangent == "pstlo" and batched is True
    # the defaults before: local damping, one cell at a time
    demo("femdem_biaxial", *SMALL, "--cell-option", "method=local", "--no-batched", "--out", tmp_path / "old")
    relaxation, tangent, batched = ran_with(tmp_path / "old")
    assert relaxation["method"] == "local" and batched is False
    assert {k: relaxation[k] for k in DOCUMENTED if k != "method"} == {k: v for k, v in DOCUMENTED.items()
                                                                       if k != "method"}
