"""The FEM x DEM defaults are the documented ones (docs/reference/femdem.md, "The cells'
relaxation"; chosen by benchmarks/femdem/femdem_defaults.py, docs/results/femdem.md "Default
cells"): the demo run as a user runs it gets FIRE cells relaxed to an unbalanced-force ratio of
1e-3 or for at most 500 DEM steps after their ramp, batched, with the pstlo operator kept while
each Newton iteration gains at least 30 %, and the settings before them stay reachable by
options."""
import json

import pytest

pytestmark = pytest.mark.serial

#: what docs/reference/femdem.md states
DOCUMENTED = {"method": "fire", "criterion": "force", "tol": 1e-3, "dt_safety": 0.25, "fire_dt_max": 2.0,
              "strain_rate": 1e-5, "damping": 0.7, "fixed_steps": None, "relax_cap": 500}
SMALL = ("--mesh", "1x1", "--particles", 20, "--axial-strain", 0.001, "--steps", 1)


def ran_with(out):
    summary = json.loads((out / "summary.json").read_text())
    mode = summary["mode"]
    return mode["relaxation"], mode["tangent"], mode["batched"], summary["operator_rule"]


def test_the_settings_default_to_the_documented_cells():
    from cosserat_fenicsx.materials.dem import CellOptions
    from cosserat_fenicsx.scenes.femdem_biaxial import FemDemSettings
    relaxation = CellOptions().relaxation()
    assert {k: getattr(relaxation, k) for k in DOCUMENTED} == DOCUMENTED
    s = FemDemSettings()
    assert s.tangent == "pstlo" and s.batched is True and s.jacobian_rule() == ("refresh", 0.7)


def test_the_demo_runs_the_documented_cells_and_the_old_ones_on_request(demo, tmp_path):
    demo("femdem_biaxial", *SMALL, "--out", tmp_path / "default")
    relaxation, tangent, batched, lag = ran_with(tmp_path / "default")
    assert {k: relaxation[k] for k in DOCUMENTED} == DOCUMENTED
    assert tangent == "pstlo" and batched is True and lag == ["refresh", 0.7]
    # the capped solves are counted per step and in all (none in this small pre-peak step)
    header = (tmp_path / "default" / "history.csv").read_text().splitlines()[0].split(",")
    summary = json.loads((tmp_path / "default" / "summary.json").read_text())
    assert "capped_solves" in header and summary["cell_solves_capped"] == 0
    # the defaults before: local damping, one cell at a time, an operator at every iteration
    demo("femdem_biaxial", *SMALL, "--cell-option", "method=local", "--no-batched", "--jacobian-lag", 1,
         "--out", tmp_path / "old")
    relaxation, tangent, batched, lag = ran_with(tmp_path / "old")
    assert relaxation["method"] == "local" and batched is False and lag == ["lag", 1]
    assert relaxation["relax_cap"] is None           # the cap belongs to the FIRE default
    assert {k: relaxation[k] for k in DOCUMENTED if k not in ("method", "relax_cap")} == {
        k: v for k, v in DOCUMENTED.items() if k not in ("method", "relax_cap")}


@pytest.mark.parametrize("extra, cap", [({}, 500), ({"method": "fire"}, 500), ({"relax_cap": None}, None),
                                        ({"relax_cap": 2000}, 2000), ({"method": "local"}, None),
                                        ({"fixed_steps": 300}, None), ({"method": "local", "relax_cap": 3000}, 3000)])
def test_the_default_cap_belongs_to_the_fire_relaxation(extra, cap):
    from cosserat_fenicsx.materials.dem import CellOptions
    assert CellOptions(extra=extra).relaxation().relax_cap == cap
    assert CellOptions(extra=extra, micro_bc="frame").relaxation().relax_cap == extra.get("relax_cap")
    # a step budget below the cap leaves the cap out: the budget fails a solve, as asked
    if not extra:
        assert CellOptions(max_steps=300).relaxation().relax_cap is None


@pytest.mark.parametrize("kept", [(), ("--jacobian-lag", 2), ("--jacobian-refresh", 0.9)])
def test_a_kept_operator_is_built_fewer_times_for_the_same_answer(demo, tmp_path, kept):
    """--jacobian-refresh (0.7 the default) keeps the operator of a step's first Newton
    iteration until an iteration gains less than the factor; --jacobian-lag 2 builds it at the
    first iteration and then every second one. Each builds fewer operators than lag 1 for the
    same equilibrium (all stop at FNORM/RNORM <= force_rtol, so the stress ratio agrees to
    the cells' relaxation noise, far below the 1 % asserted)."""
    run = ("--mesh", "1x1", "--particles", 20, "--axial-strain", 0.004, "--steps", 2)
    summaries = {}
    for name, option in (("every", ("--jacobian-lag", 1)), ("kept", kept)):
        demo("femdem_biaxial", *run, *option, "--out", tmp_path / name)
        summaries[name] = json.loads((tmp_path / name / "summary.json").read_text())
    every, kept = summaries["every"], summaries["kept"]
    assert every["cell_tangents_total"] >= every["n_gauss_points"] * every["newton_iterations_total"]
    assert kept["cell_tangents_total"] < every["cell_tangents_total"]
    assert every["cell_solves_redone_with_local_damping"] == 0
    assert abs(kept["peak_stress_ratio"] - every["peak_stress_ratio"]) <= 1e-2 * every["peak_stress_ratio"]


@pytest.mark.parametrize("bad", [("--jacobian-refresh", 0), ("--jacobian-refresh", 1), ("--jacobian-refresh", 1.5),
                                 ("--jacobian-lag", 0), ("--jacobian-lag", 2, "--jacobian-refresh", 0.5)])
def test_a_bad_operator_rule_is_refused_before_any_work(demo, tmp_path, bad):
    proc = demo("femdem_biaxial", *SMALL, *bad, "--out", tmp_path / "bad", check=False)
    assert proc.returncode != 0 and "--jacobian-" in proc.stderr + proc.stdout
    assert not (tmp_path / "bad" / "history.csv").exists()


def test_accept_and_stagnation_take_none_as_never_and_refuse_negatives():
    """--accept-rtol 0 and --stagnation-its 0 reach the settings as None ("never", "only at
    the cap"), which the settings take; a negative value is still refused."""
    from cosserat_fenicsx.scenes.femdem_biaxial import FemDemSettings
    FemDemSettings(accept_rtol=None, stagnation_its=None).check()
    for bad in ({"accept_rtol": -0.1}, {"stagnation_its": -1}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            FemDemSettings(**bad).check()
