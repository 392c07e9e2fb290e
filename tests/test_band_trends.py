"""The trend test of benchmarks/dns/band_trends.py on values with a known answer, and the law
flags every demo of dns_vs_femdem receives."""
import math

import pytest

from benchmarks.dns import band_trends as bt
from benchmarks.dns import dns_vs_femdem as dvf


def test_laws_are_the_thesis_factors():
    # 004 section 7.4.4: E_t 50 / 100 / 125 N/m and mu 0.4 / 0.8 / 1.0 as factors of the base law
    ks = [bt.LAWS[x][0] / bt.BASE_KS for x in bt.SERIES["ks"]]
    mu = [bt.LAWS[x][1] / bt.BASE_FRICTION for x in bt.SERIES["mu"]]
    assert ks == pytest.approx([50 / 100, 1.0, 125 / 100])
    assert mu == pytest.approx([0.4 / 0.8, 1.0, 1.0 / 0.8])
    assert all(bt.LAWS[x][1] == bt.BASE_FRICTION for x in bt.SERIES["ks"])
    assert all(bt.LAWS[x][0] == bt.BASE_KS for x in bt.SERIES["mu"])


def test_relative_ranges_and_changes():
    h = {"base": 4.0, "ks0.5": 6.0, "ks1.25": 3.0, "mu0.5": 4.2, "mu1.25": 3.8}
    rr = bt.relative_ranges(h)
    assert rr["ks"] == pytest.approx(3.0 / 4.0)
    assert rr["mu"] == pytest.approx(0.4 / 4.0)
    ch = bt.changes(h)
    assert ch["ks"] == pytest.approx((2.0, -1.0))
    assert ch["mu"] == pytest.approx((0.2, -0.2))
    missing = {k: v for k, v in h.items() if k != "mu1.25"}
    assert bt.relative_ranges(missing)["mu"] is None
    assert bt.changes(missing)["mu"][1] is None


def test_sign_agreement():
    assert bt.sign_agreement(1.0, 2.0, 0.5) == "same"
    assert bt.sign_agreement(-1.0, 2.0, 0.5) == "opposite"
    assert bt.sign_agreement(-1.0, 0.4, 0.5) == "DNS within its scatter"
    assert bt.sign_agreement(-1.0, 0.4, None) == "DNS within its scatter"
    assert bt.sign_agreement(None, 2.0, 0.5) == "-"


def test_law_flags_are_on_every_demo_command_line(tmp_path):
    run = {"label": "x", "kind": "dns", "size": [2, 4], "seed": 0, "ks": 1000.0, "friction": 0.2}
    for kind in ("dns", "cell", "hybrid"):
        cmd, _ = dvf.command(dict(run, kind=kind, size=[1, 1]), str(tmp_path), 0.04)
        i, j = cmd.index("--ks"), cmd.index("--friction")
        assert float(cmd[i + 1]) == 1000.0 and math.isclose(float(cmd[j + 1]), 0.2)
    cmd, _ = dvf.command({"label": "y", "kind": "dns", "size": [2, 4], "seed": 0}, str(tmp_path), 0.04)
    assert "--ks" not in cmd and "--friction" not in cmd


def test_dns_runs_carry_their_law():
    runs = bt.dns_runs([0, 1], ["base", "mu0.5"])
    assert [r["label"] for r in runs] == ["dns-2x4-base-s0", "dns-2x4-base-s1", "dns-2x4-mu0.5-s0", "dns-2x4-mu0.5-s1"]
    assert runs[2]["friction"] == 0.2 and runs[2]["ks"] == bt.BASE_KS


def test_change_scatter_is_the_root_sum_of_squares():
    sd = {"base": 1.2, "ks0.5": 0.5, "ks1.25": None}
    assert bt.change_scatter(sd, "ks0.5") == pytest.approx(1.3)
    assert bt.change_scatter(sd, "ks1.25") is None
    assert bt.change_scatter({"base": None, "mu0.5": 0.7}, "mu0.5") == pytest.approx(0.7)


@pytest.mark.parametrize("argv, words", [
    (["--particles", "3"], "particles must be an integer >= 10"),
    (["--femdem-seed", "-2"], "seed must be an integer >= 0"),
    (["--steps", "0"], "steps must be an integer"),
    (["--case-minutes", "0"], "--case-minutes must be > 0"),
    (["--mesh", "3x8"], "whole elements in the 5 mm weak corner"),
])
def test_bad_options_are_refused_in_one_line_before_any_work(argv, words, tmp_path, capsys):
    with pytest.raises(SystemExit) as stop:
        bt.main(argv + ["--models", "hybrid", "--out", str(tmp_path / "out")])
    assert stop.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert words in err[-1] and not (tmp_path / "out").exists()
