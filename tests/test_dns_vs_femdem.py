"""The DNS-against-FEM x DEM benchmark's planning, resume rule, statistics and tables on fake
records (no physics run: those are benchmarks/dns/dns_vs_femdem.py itself)."""
import json
import os

import numpy as np
import pytest

from benchmarks.dns import dns_vs_femdem as b


def fake_record(kind, size, seed, peak, strain_peak=0.02, end=0.05, cpu=100.0, wall=60.0, n=51, case=None):
    eps = -np.linspace(0.0, end, n)
    ratio = peak * np.minimum(1.0, -eps / strain_peak) - 0.5 * np.maximum(0.0, -eps - strain_peak)
    run = b.plan([case or f"{kind}-{size[0]}x{size[1]}"], [seed])[0]
    curves = {"axial_strain": eps.tolist(), "stress_ratio": ratio.tolist(), "volumetric_strain": (0.1 * eps).tolist(),
              "coordination": np.linspace(3.3, 3.0, n).tolist()}
    if kind != "dns":
        curves["anisotropy"] = np.linspace(0.0, 0.3, n).tolist()
    summary = {"completed": True, "n_discs": 228 * size[0] * size[1], "n_gauss_points": 6 * size[0] * size[1]}
    return b.make_record(run, ["demo"], 0, wall, cpu, [1.0, 1.0, 1.0], [1.5, 1.0, 1.0], curves, summary)


def test_plan_labels_and_refusals():
    runs = b.plan(["dns-2x4", "classical-1x2"], [0, 3])
    assert [r["label"] for r in runs] == ["dns-2x4-s0", "dns-2x4-s3", "classical-1x2-s0", "classical-1x2-s3"]
    assert runs[2]["study"] == "classical-1x2" and runs[2]["size"] == [1, 2]
    locked = b.plan(["dns-1x2-locked"], [1])[0]
    assert locked["label"] == "dns-1x2-locked-s1" and locked["locked"] and locked["study"] == "dns-1x2-locked"
    for bad in ("dns-2x", "micro-1x1", "dns-0x2", "dns 2x4", "dns-1x2-free"):
        with pytest.raises(ValueError, match="KIND-NXxNY"):
            b.plan([bad], [0])


def test_commands_use_the_demos_with_the_same_seed_and_strain(tmp_path):
    dns, fem = b.plan(["dns-1x2", "hybrid-2x4"], [5])
    cmd, env = b.command(dns, str(tmp_path), 0.04)
    assert cmd[1].endswith("dem_specimen.py") and cmd[cmd.index("--tiles") + 1] == "1x2"
    assert cmd[cmd.index("--seed") + 1] == "5" and cmd[cmd.index("--axial-strain") + 1] == "0.04" and env == {}
    cmd, env = b.command(fem, str(tmp_path), 0.04, step=0.002, ranks=2)
    assert cmd[:3] == ["mpirun", "-n", "2"] and cmd[4].endswith("femdem_biaxial.py")
    assert cmd[cmd.index("--mode") + 1] == "hybrid" and cmd[cmd.index("--mesh") + 1] == "2x4"
    assert cmd[cmd.index("--steps") + 1] == "20" and cmd[cmd.index("--seed") + 1] == "5"
    assert env["OMPI_ALLOW_RUN_AS_ROOT"] == "1"
    assert "--no-rotation" not in cmd
    for run in b.plan(["dns-1x2-locked", "classical-1x1-locked"], [0]):
        assert "--no-rotation" in b.command(run, str(tmp_path), 0.04)[0]
    cmd, _ = b.command(fem, str(tmp_path), 0.04, restart=True)
    assert "--restart" in cmd and "--mode" not in cmd


def test_resume_skips_cases_with_records(tmp_path):
    runs = b.plan(["dns-1x2", "classical-1x1"], [0, 1])
    b.write_json(b.record_path(str(tmp_path), runs[1]), fake_record("dns", (1, 2), 1, 0.35))
    assert [r["label"] for r in b.pending(runs, str(tmp_path))] == ["dns-1x2-s0", "classical-1x1-s0",
                                                                   "classical-1x1-s1"]
    assert [r["label"] for r in b.load_records(str(tmp_path), runs)] == ["dns-1x2-s1"]


def test_curves_from_the_demos_histories(tmp_path):
    (tmp_path / "d").mkdir()
    (tmp_path / "d" / "history.csv").write_text(
        "time,step,phase,axial_strain,lateral_strain,volumetric_strain,stress_ratio,coordination\n"
        "0,0,0,0,0,0,0,3.3\n0,0,1,0,0,0,0.01,3.3\n1,10,1,-0.01,0.005,-0.005,0.3,3.2\n")
    c = b.curves_from_outputs("dns", str(tmp_path / "d"))
    assert c["axial_strain"] == [0.0, -0.01] and c["stress_ratio"] == [0.01, 0.3]
    (tmp_path / "f").mkdir()
    # the platen stress -30 N/m against p0 = 10 N/m: ratio 20 / 40
    (tmp_path / "f" / "history.csv").write_text(
        "step,phase,axial_strain,stress_ratio,volumetric_strain,coordination_number,anisotropy,vertical_stress\n"
        "0,1,0,0,0,3.3,0,-10\n1,2,-0.002,0.48,-0.001,3.2,0.1,-30\n")
    c = b.curves_from_outputs("classical", str(tmp_path / "f"), pressure=10.0)
    assert c["axial_strain"] == [0.0, -0.002] and c["stress_ratio"] == [pytest.approx(0.0), pytest.approx(0.5)]
    assert c["stress_ratio_points"] == [0.0, 0.48] and c["anisotropy"] == [0.0, 0.1]


def test_scatter_agreement_and_ranges():
    grid = np.round(np.arange(0.0, 0.05 + 1e-9, 0.001), 6)
    recs = [fake_record("dns", (1, 2), s, p) for s, p in ((0, 0.30), (1, 0.34), (2, 0.38))]
    recs.append(fake_record("classical", (1, 1), 0, 0.34))       # the DNS mean: within everywhere
    recs.append(fake_record("hybrid", (1, 1), 0, 0.50))          # far off past the first steps
    st = b.studies(recs, grid)
    d = st["dns-1x2"]
    i = int(np.argmin(np.abs(grid - 0.02)))
    assert d["mean"][i] == pytest.approx(0.34) and d["std"][i] == pytest.approx(0.04)
    assert d["min"][i] == pytest.approx(0.30) and d["max"][i] == pytest.approx(0.38)
    rng, worst, compared = b.agreement(st["classical-1x1"], d, grid)
    assert worst == pytest.approx(0.0, abs=1e-9)
    assert rng[0][1] == pytest.approx(0.05)
    rng, worst, _ = b.agreement(st["hybrid-1x1"], d, grid)
    assert worst > 1 and all(b_ < 0.01 for a, b_ in rng)     # within only at the very start
    span = b.inside_seeds(st["hybrid-1x1"], d, grid)
    assert all(b_ < 0.01 for a, b_ in span)
    assert b.inside_seeds(st["classical-1x1"], d, grid)[0][1] == pytest.approx(0.05)
    assert b.ranges([False, True, True, False, True], [0, 1, 2, 3, 4]) == [(1, 2), (4, 4)]


def test_a_seed_that_stopped_early_leaves_the_mean_undefined_there():
    grid = np.round(np.arange(0.0, 0.05 + 1e-9, 0.001), 6)
    recs = [fake_record("dns", (1, 2), 0, 0.3), fake_record("dns", (1, 2), 1, 0.3, end=0.03, n=31)]
    d = b.studies(recs, grid)["dns-1x2"]
    assert np.isfinite(d["mean"][30]) and np.isnan(d["mean"][40])


def test_cost_table_measured_and_extrapolated():
    recs = [fake_record("dns", (1, 2), 0, 0.3, cpu=50.0), fake_record("dns", (2, 4), 0, 0.3, cpu=200.0),
            fake_record("classical", (1, 1), 0, 0.3, cpu=300.0), fake_record("classical", (1, 2), 0, 0.3, cpu=600.0)]
    measured, dns_unit, fem_unit, table = b.cost_rows(recs, 0.05)
    assert measured["dns-2x4"]["cpu_per_pct"] == pytest.approx(40.0)          # 200 CPU s over 5 %
    assert dns_unit == pytest.approx(40.0 / 1824)                             # the largest tiling: 40 per % / 1824 discs
    assert fem_unit["classical"] == pytest.approx(120.0 / 12)                 # the 1x2 mesh: 120 per % / 12 points
    rows = {r["mesh"]: r for r in table}
    assert rows["1x2"]["fem_measured"] and rows["1x2"]["fem_cpu"] == pytest.approx(600.0)
    assert not rows["4x8"]["fem_measured"] and rows["4x8"]["fem_cpu"] == pytest.approx(10.0 * 192 * 5)
    by = {d["tiling"]: d for d in rows["1x2"]["dns"]}
    assert by["2x4"]["measured"] and by["2x4"]["ratio"] == pytest.approx(3.0)
    assert not by["4x8"]["measured"] and by["4x8"]["dns_cpu"] == pytest.approx(dns_unit * 228 * 32 * 5)
    assert rows["1x2"]["break_even_discs"] == pytest.approx(600.0 / (dns_unit * 5))


def test_report_writes_tables_and_figure(tmp_path):
    out = str(tmp_path)
    runs = b.plan(["dns-1x2", "classical-1x1"], [0, 1])
    for r, p in zip(runs, (0.3, 0.34, 0.33, 0.32)):
        kind, size, _, _ = b.parse_case(r["study"])
        b.write_json(b.record_path(out, r), fake_record(kind, size, r["seed"], p))
    text = "\n".join(b.report(out, runs, 0.05, "test"))
    assert "| classical-1x1 | dns-1x2 |" in text and "FEM / DNS 2x4 (1824 discs)" in text
    assert os.path.isfile(os.path.join(out, "dns_vs_femdem.png"))
    with open(os.path.join(out, "dns_vs_femdem.json")) as f:
        assert json.load(f)["agreement"][0]["femdem"] == "classical-1x1"
    assert open(os.path.join(out, "dns_vs_femdem.csv")).read().count("\n") == 5


def test_locked_runs_pair_with_locked_dns_and_give_the_rotation_ratio(tmp_path):
    out = str(tmp_path)
    runs = b.plan(["dns-1x2", "dns-1x2-locked", "classical-1x1", "classical-1x1-locked"], [0, 1])
    peaks = {"dns-1x2": 0.3, "dns-1x2-locked": 0.6, "classical-1x1": 0.4, "classical-1x1-locked": 0.5}
    for r in runs:
        kind, size, _, _ = b.parse_case(r["study"])
        b.write_json(b.record_path(out, r), fake_record(kind, size, r["seed"], peaks[r["study"]] + 0.01 * r["seed"],
                                                        case=r["study"]))
    text = "\n".join(b.report(out, runs, 0.05, "test"))
    assert "| classical-1x1-locked | dns-1x2-locked |" in text and "| classical-1x1 | dns-1x2-locked |" not in text
    with open(os.path.join(out, "dns_vs_femdem.json")) as f:
        found = {r["case"]: r["ratio"] for r in json.load(f)["rotation"]}
    assert found["dns-1x2"] == pytest.approx(0.305 / 0.605) and found["classical-1x1"] == pytest.approx(0.405 / 0.505)
    # the cost table counts the free runs only
    assert "dns-1x2-locked |" not in text.split("## Cost")[1]


def test_reread_refreshes_curves_and_keeps_costs(tmp_path):
    out = str(tmp_path)
    run = b.plan(["classical-1x1"], [0])[0]
    b.write_json(b.record_path(out, run), fake_record("classical", (1, 1), 0, 0.4, cpu=123.0))
    os.makedirs(os.path.join(out, run["label"]))
    with open(os.path.join(out, run["label"], "history.csv"), "w") as f:
        f.write("step,phase,axial_strain,stress_ratio,volumetric_strain,coordination_number,anisotropy,vertical_stress\n"
                "0,1,0,0,0,3.9,0,-10\n1,2,-0.002,0.48,-0.001,3.2,0.1,-30\n")
    b.reread(out, [run])
    rec = b.load_records(out, [run])[0]
    assert rec["cpu_s"] == 123.0 and rec["curves"]["axial_strain"] == [0.0, -0.002]
    assert rec["peak_stress_ratio"] == pytest.approx(0.5)


def _fake_demo(tmp_path, monkeypatch, summary, code):
    """b.command replaced by a process that writes a FEM x DEM run's history (and summary)
    and its checkpoint folder, then exits with `code`; returns the restart flags seen."""
    import sys
    seen = []

    def command(run, out, strain, step=0.002, ranks=2, threads=None, python=sys.executable, restart=False):
        seen.append(restart)
        d = os.path.join(out, run["label"])
        script = (f"import os, json; d = {d!r}; os.makedirs(os.path.join(d, 'checkpoint'), exist_ok=True); "
                  "open(os.path.join(d, 'history.csv'), 'w').write('step,phase,axial_strain,stress_ratio,"
                  "volumetric_strain,coordination_number,anisotropy,vertical_stress\\n0,1,0,0,0,3.9,0,-10\\n"
                  "1,2,-0.002,0.4,0,3.8,0.1,-20\\n'); "
                  f"s = {summary!r}; s is not None and json.dump(s, open(os.path.join(d, 'summary.json'), 'w')); "
                  f"raise SystemExit({code})")
        return [python, "-c", script], {}
    monkeypatch.setattr(b, "command", command)
    return seen


def test_a_named_stop_is_recorded_and_a_killed_run_restarts(tmp_path, monkeypatch):
    out = str(tmp_path)
    stop, killed = b.plan(["classical-2x4"], [0, 1])
    seen = _fake_demo(tmp_path, monkeypatch, {"completed": False, "stopped": "the cell did not relax"}, 1)
    rec = b.execute(stop, out, 0.05, 0.002, 1, None, log=lambda m: None)
    assert rec["stop_reason"] == "the cell did not relax" and os.path.isfile(b.record_path(out, stop))
    seen = _fake_demo(tmp_path, monkeypatch, None, 1)          # killed: no summary, a checkpoint
    assert b.execute(killed, out, 0.05, 0.002, 1, None, log=lambda m: None) is None
    assert not os.path.isfile(b.record_path(out, killed))
    assert os.path.isfile(os.path.join(out, killed["label"], "earlier_cost.json"))
    seen = _fake_demo(tmp_path, monkeypatch, {"completed": True}, 0)
    rec = b.execute(killed, out, 0.05, 0.002, 1, None, log=lambda m: None)
    assert seen == [True] and rec["completed"] and os.path.isfile(b.record_path(out, killed))


def test_anisotropic_cases_pass_their_target_to_both_demos_and_pair_within_their_target(tmp_path):
    """000 section 4.3.3: 'dns-2x4-a0.05' and 'classical-1x1-a0.05' make the cell packing with
    --anisotropy 0.05; the report lists the achieved A0 with its major axis and the peak per
    target, and compares FEM x DEM with the DNS of the same target only."""
    assert b.parse_case("dns-2x4-a0.05") == ("dns", (2, 4), False, 0.05)
    assert b.parse_case("classical-1x1-a0-locked") == ("classical", (1, 1), True, 0.0)
    cell = b.plan(["cell-1x1-a0.08"], [3])[0]
    cmd = b.command(cell, str(tmp_path), 0.05, step=0.002)[0]
    assert cmd[1].endswith("dem_cell.py") and cmd[cmd.index("--anisotropy") + 1] == "0.08"
    assert cmd[cmd.index("--axial-direction") + 1] == "2" and cmd[cmd.index("--lateral-control") + 1] == "strain"
    assert cmd[cmd.index("--increment") + 1] == "0.002" and cmd[cmd.index("--seed") + 1] == "3"
    for bad in ("dns-2x4-a1.5", "dns-2x4-a", "dns-2x4-locked-a0.05", "dns-2x4-a-0.1", "cell-1x2"):
        with pytest.raises(ValueError, match="KIND-NXxNY"):
            b.plan([bad], [0])
    runs = b.plan(["dns-2x4", "dns-2x4-a0.02", "dns-2x4-a0.05", "classical-1x1", "classical-1x1-a0.02",
                   "classical-1x1-a0.05"], [0, 1])
    assert [r["study"] for r in runs[::2]] == ["dns-2x4", "dns-2x4-a0.02", "dns-2x4-a0.05", "classical-1x1",
                                               "classical-1x1-a0.02", "classical-1x1-a0.05"]
    for r in runs:
        cmd = b.command(r, str(tmp_path), 0.05)[0]
        assert ("--anisotropy" in cmd) == (r["anisotropy"] is not None)
        if r["anisotropy"] is not None:
            assert cmd[cmd.index("--anisotropy") + 1] == repr(r["anisotropy"])
    out = str(tmp_path)
    peaks = {"dns-2x4": 0.4, "dns-2x4-a0.02": 0.35, "dns-2x4-a0.05": 0.3, "classical-1x1": 0.5,
             "classical-1x1-a0.02": 0.48, "classical-1x1-a0.05": 0.45}
    for r in runs:
        kind, size, _, target = b.parse_case(r["study"])
        rec = fake_record(kind, size, r["seed"], peaks[r["study"]] + 0.02 * r["seed"], case=r["study"])
        rec["packing_anisotropy"] = 0.06 if target is None else target + 0.002 * r["seed"]
        rec["packing_solid_fraction"] = 0.84 if target is None else 0.80
        rec["packing_fabric"] = [[0.485, 0.0], [0.0, 0.515]] if target is None else [[0.51, 0.0], [0.0, 0.49]]
        b.write_json(b.record_path(out, r), rec)
    text = "\n".join(b.report(out, runs, 0.05, "test"))
    assert "| classical-1x1-a0.05 | dns-2x4-a0.05 |" in text and "| classical-1x1-a0.05 | dns-2x4 |" not in text
    assert "| dns-2x4 | 0.05 | 0,1 | 0.050x, 0.052x (mean 0.051) | 0.800 | 0.310 +- 0.014 |" in text
    assert "| dns-2x4 | none | 0,1 | 0.060y, 0.060y" in text
    with open(os.path.join(out, "dns_vs_femdem.json")) as f:
        found = {(r["case"], r["target"]): r for r in json.load(f)["anisotropy"]}
    assert found[("classical-1x1", 0.05)]["peak_over_lowest_target"] == pytest.approx(0.46 / 0.49)
    assert found[("classical-1x1", None)]["peak_over_lowest_target"] is None
    assert "dns-2x4-a0.05 |" not in text.split("## Cost")[1]
