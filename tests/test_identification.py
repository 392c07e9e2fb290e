"""Identification: error analysis against SciPy and statistics, data checks,
the objective's bookkeeping, and bad input refused before any model run."""
import json
import os

import numpy as np
import pytest

from cosserat_fenicsx.identification import data as D
from cosserat_fenicsx.identification.error_analysis import analyse
from cosserat_fenicsx.identification.objective import Objective, _interp_matrix
from cosserat_fenicsx.identification.parameter_set import PLASTIC_HOMOGENEOUS, ParameterSet
from cosserat_fenicsx.identification.virtual_tests import VirtualTest
from cosserat_fenicsx.materials.ehlers.parameters import EhlersParameters
from cosserat_fenicsx.validation import InputError

pytestmark = pytest.mark.serial          # material point only: the serial pass


# ---------------------------------------------------------------- error analysis (4.27)-(4.31)
def _exp_model(x, a, b, c):
    return a * np.exp(-b * x) + c


def test_covariance_equals_scipy_curve_fit():
    """K of (4.28) with s0 of (4.27) is the covariance SciPy's curve_fit estimates
    (absolute_sigma=False), for a nonlinear model with unequal weights."""
    from scipy.optimize import curve_fit
    rng = np.random.default_rng(3)
    x = np.linspace(0, 4, 40)
    sig = 0.05 * (1 + x)
    y = _exp_model(x, 2.0, 1.3, 0.5) + rng.normal(0, sig)
    p, pcov = curve_fit(_exp_model, x, y, p0=(1, 1, 0), sigma=sig, absolute_sigma=False)
    a, b, c = p
    J = np.column_stack([np.exp(-b * x), -a * x * np.exp(-b * x), np.ones_like(x)])
    ea = analyse(["a", "b", "c"], p, J, _exp_model(x, *p) - y, weights=1 / sig ** 2)
    # curve_fit's Jacobian is a finite-difference one (MINPACK), good to ~1e-5
    assert np.allclose(ea.covariance, pcov, rtol=2e-4, atol=0)
    corr = pcov / np.sqrt(np.outer(np.diag(pcov), np.diag(pcov)))
    assert np.allclose(ea.correlation, corr, atol=1e-4)
    # known scatter: s0 ~ 1 when the scatter is right, and K = s0^2 (J^T W J)^-1
    eb = analyse(["a", "b", "c"], p, J, _exp_model(x, *p) - y, sigma=sig)
    assert 0.6 < eb.s0 < 1.4
    p2, pcov2 = curve_fit(_exp_model, x, y, p0=(1, 1, 0), sigma=sig, absolute_sigma=True)
    assert np.allclose(eb.covariance / eb.s0 ** 2, pcov2, rtol=2e-4)


def test_intervals_have_their_nominal_coverage():
    """Over repeated noise draws of a linear model, the marginal t intervals hold the true
    parameter at 95 %, and the joint region of (4.30) holds the true vector at 95 %."""
    rng = np.random.default_rng(11)
    x = np.linspace(0, 1, 12)
    J = np.column_stack([np.ones_like(x), x, x ** 2])
    truth = np.array([1.0, -2.0, 0.5])
    n, marginal, joint = 3000, 0, 0
    for _ in range(n):
        y = J @ truth + rng.normal(0, 0.1, x.size)
        s = np.linalg.lstsq(J, y, rcond=None)[0]
        ea = analyse(["a", "b", "c"], s, J, J @ s - y)
        lo, hi = ea.intervals(joint=False)
        marginal += int(lo[1] <= truth[1] <= hi[1])
        joint += int(ea.inside_joint_region(truth))
    # binomial standard error at 3000 draws: 0.4 %
    assert abs(marginal / n - 0.95) < 0.015
    assert abs(joint / n - 0.95) < 0.015


def test_correlated_parameters_are_flagged():
    """Two parameters entering only as a product (like mu_c l_c^2 of the couple stress):
    correlation -1 up to round-off, or a rank-deficient Fisher matrix."""
    x = np.linspace(0.1, 1, 20)
    a, b = 2.0, 3.0
    J = np.column_stack([b * x, a * x])       # d(a b x)/da, d(a b x)/db
    ea = analyse(["a", "b"], [a, b], J + 1e-9 * np.random.default_rng(0).normal(size=J.shape),
                 np.random.default_rng(1).normal(0, 0.01, x.size))
    assert ea.rank_deficient or abs(ea.correlation[0, 1]) > 0.999


# -------------------------------------------------------------------- data and objective
def _write(path, header, rows):
    with open(path, "w") as f:
        f.write(",".join(header) + "\n")
        for r in rows:
            f.write(",".join(str(v) for v in r) + "\n")
    return str(path)


def test_data_files_are_checked(tmp_path):
    ok = _write(tmp_path / "ok.csv", ["axial_strain", "axial_stress", "volumetric_strain"],
                [(-0.01, -3e5, -0.001), (-0.02, -4e5, 0.0)])
    d = D.read_test(ok, "triaxial", 100e3)
    # phi_0 of (4.17): the data's magnitude (Table 6.2 only for the thesis' virtual tests)
    assert d.test.axial_strain == pytest.approx(0.02) and d.normalisation["axial_stress"] == 4e5
    assert D.default_normalisation("triaxial", 100e3, "axial_stress", [1.0], thesis=True) == 500e3
    cases = {
        "missing column": (["axial_strain", "volumetric_strain"], [(-0.01, 0.0)], dict(quantities=["axial_stress"]),
                           "column 'axial_stress' missing"),
        "nan": (["axial_strain", "axial_stress"], [(-0.01, "nan"), (-0.02, -1e5)], {}, "non-finite"),
        "text": (["axial_strain", "axial_stress"], [(-0.01, "abc")], {}, "is not a number"),
        "tension": (["axial_strain", "axial_stress"], [(0.01, -1e5)], {}, "must be <= 0"),
        "ragged": (["axial_strain", "axial_stress"], [(-0.01,)], {}, "values for 2 columns"),
    }
    for name, (header, rows, kw, message) in cases.items():
        path = _write(tmp_path / f"{name.replace(' ', '_')}.csv", header, rows)
        with pytest.raises(InputError, match=message):
            D.read_test(path, "triaxial", 100e3, **kw)
    with pytest.raises(InputError, match="does not exist"):
        D.read_test(str(tmp_path / "nothere.csv"), "triaxial", 100e3)
    with pytest.raises(InputError, match="not one of"):
        D.read_test(ok, "oedometer", 100e3)
    hyd = _write(tmp_path / "hyd.csv", ["mean_stress", "volumetric_strain"], [(-1e5, -0.001), (-2e5, -0.002)])
    dh = D.read_test(hyd, "hydrostatic", None)
    assert dh.test.confining == pytest.approx(2e5) and np.allclose(dh.x, [1e5, 2e5])


def test_parameter_choice_is_checked():
    base = EhlersParameters(micropolar=False)
    ps = ParameterSet(("plastic",), base)
    assert ps.names == PLASTIC_HOMOGENEOUS and len(ps.names) == 14
    with pytest.raises(InputError, match="not an identifiable"):
        ParameterSet(("psi3",), base)
    with pytest.raises(InputError, match="outside its bounds"):
        ParameterSet(("psi1",), base, {"psi1": (2.0, 3.0)})
    with pytest.raises(InputError, match="empty"):
        ParameterSet(("psi1",), base, {"psi1": (2.0, 1.0)})
    with pytest.raises(InputError, match="not identified"):
        ParameterSet(("psi1",), base, {"psi2": (0.0, 1.0)})
    # the constraints of (4.2): the compression point needs n_max > n0 (2.70) -- a bound when
    # only one of them is identified, a constraint when both are
    one = ParameterSet(("n_max",), base)
    assert one.lower[0] > base.n0 and not one.constraint_values(one.start)
    both = ParameterSet(("n_max", "n0"), base)
    name = "compression point exists: n_max - n0 > 0 (2.70)"
    assert both.constraint_values(both.start)[name] > 0 and both.constraint_values([0.5, 0.6])[name] < 0


def test_interpolation_matrix_is_exact_on_lines():
    xm = np.linspace(0.0, -0.1, 11)          # decreasing, as axial strains are
    xd = np.array([-0.003, -0.05, -0.0999, 0.0])
    P = _interp_matrix(xm, xd)
    assert np.allclose(P @ (3 * xm + 1), 3 * xd + 1)
    assert np.allclose(P.sum(axis=1), 1.0)


def test_objective_terms_and_weights():
    """f = sum of the (6.3) terms, each normalised by phi_0^2 N (4.17): a model that misses
    every data point by exactly phi_0 gives 1 per term; the reference set gives 0."""
    from cosserat_fenicsx.materials.ehlers import EhlersMaterial
    ref = EhlersParameters(micropolar=False)
    test = VirtualTest("triaxial", 300e3, n_steps=30, axial_strain=0.06)
    good = D.from_history(test, test.run(EhlersMaterial(**ref.as_dict())), every=2)
    shifted = D.TestData(test=test, x=good.x, y={q: v + good.normalisation[q] for q, v in good.y.items()},
                         std={}, normalisation=good.normalisation)
    obj = Objective([good, shifted], ParameterSet(("psi1",), ref))
    e = obj.evaluate([ref.psi1], jacobian=False)
    # (both data sets carry the same label, so the terms are checked block by block)
    k = 0
    per = []
    for label, q, n in obj.blocks:
        r = e.residual[k:k + n]
        per.append(float(r @ r))
        k += n
    assert np.allclose(per[:2], 0.0, atol=1e-16) and np.allclose(per[2:], 1.0, rtol=1e-12)
    assert np.isclose(sum(per), e.f)


# ---------------------------------------------------------------------------- the demo
def test_identify_demo_refuses_bad_input(tmp_path):
    from conftest import run_demo
    good = _write(tmp_path / "t.csv", ["axial_strain", "axial_stress", "volumetric_strain"],
                  [(-0.01, -3e5, -0.001), (-0.02, -4e5, 0.0)])
    nan = _write(tmp_path / "nan.csv", ["axial_strain", "axial_stress"], [(-0.01, "nan")])
    start = tmp_path / "start.json"
    start.write_text(json.dumps({"parameters": {"n_max": 0.5}}))
    cases = [
        (["--data", f"triaxial:100e3:{nan}"], "non-finite"),
        (["--data", f"triaxial:100e3:{good}", "--params", "psi7"], "not an identifiable"),
        (["--data", f"triaxial:100e3:{good}", "--params", "l_c,psi1"], "no effect in homogeneous tests"),
        (["--data", f"triaxial:100e3:{good}", "--params", "psi1", "--bounds", str(tmp_path / "b.json")], "bounds"),
        (["--data", f"triaxial::{good}"], "needs its confining pressure"),
        (["--data", f"triaxial:100e3:{good}", "--start", str(start)], "n0"),
    ]
    (tmp_path / "b.json").write_text(json.dumps({"psi1": [3.0, 4.0]}))
    for argv, message in cases:
        out = tmp_path / "out"
        proc = run_demo("identify", *argv, "--out", out, check=False)
        assert proc.returncode == 2, (argv, proc.stdout, proc.stderr)
        assert message in proc.stderr, (argv, proc.stderr)
        assert not os.path.exists(out), "refused before any work: no output directory"


# ---------------------------------------------------------------- re-identification (6.2.3)
def test_reidentification_of_the_14_plastic_parameters():
    """Virtual data of the five tests of 6.1 from the Hostun set; all 14 parameters of (6.2)
    disturbed by +10 % are recovered to 1e-6 (measured: 6e-9 in 9 iterations)."""
    from cosserat_fenicsx.identification.sqp import identify
    ref = EhlersParameters(micropolar=False)
    data = D.thesis_virtual_data(ref, n_steps=60)
    values = ref.as_dict()
    for n in PLASTIC_HOMOGENEOUS:
        values[n] *= 1.1
    pset = ParameterSet(("plastic",), EhlersParameters(**values))
    res = identify(Objective(data, pset), max_iterations=40)
    truth = np.array([getattr(ref, n) for n in pset.names])
    assert res.converged and res.method == "trf"
    assert res.f < 1e-14 * res.f_start
    assert np.max(np.abs(res.values / truth - 1)) < 1e-6


@pytest.mark.slow
def test_confidence_intervals_cover_the_reference_over_noise_draws():
    """The error analysis (4.27-4.30) of the identification itself: over 60 noise draws (1 %
    of phi_0) the joint region and the marginal intervals hold the reference at about 95 %
    (measured over 100 draws: 0.96 and 0.959; s0 = 1.000)."""
    from cosserat_fenicsx.identification.sqp import identify
    ref = EhlersParameters(micropolar=False)
    truth = None
    joint, marginal, n = 0, 0.0, 60
    for k in range(n):
        data = D.thesis_virtual_data(ref, n_steps=60, noise=0.01, rng=np.random.default_rng(100 + k))
        pset = ParameterSet(("plastic",), ref)
        obj = Objective(data, pset)
        res = identify(obj, max_iterations=40)
        truth = np.array([getattr(ref, m) for m in pset.names])
        ea = analyse(pset.names, res.values, res.best.raw_jacobian, res.best.raw_residual, sigma=obj.scatter)
        lo, hi = ea.intervals(joint=False)
        joint += ea.inside_joint_region(truth)
        marginal += np.mean((lo <= truth) & (truth <= hi))
    # binomial standard error at 60 draws: 2.8 %; 3 of them either side
    assert abs(joint / n - 0.95) < 0.085 and abs(marginal / n - 0.95) < 0.05


def test_identify_demo_writes_its_best_point_when_it_does_not_converge(tmp_path):
    """Too few iterations: exit 1, summary.json says why, and the best point is written and
    loads into the material-point demo (--parameters)."""
    from conftest import run_demo
    out = tmp_path / "id"
    proc = run_demo("identify", "--params", "plastic", "--steps", "30", "--max-iterations", "1", "--out", out,
                    check=False)
    assert proc.returncode == 1, proc.stderr
    with open(out / "summary.json") as f:
        summary = json.load(f)
    assert summary["completed"] is False and "did not converge" in summary["reason"]
    assert summary["stages"][0]["f"] < summary["stages"][0]["f_start"]
    mp = run_demo("material_point", "--test", "triaxial", "--steps", "20", "--parameters",
                  out / "identified_parameters.json", "--out", tmp_path / "mp")
    assert mp.returncode == 0


def test_parameter_file_drives_the_biaxial_demo(tmp_path):
    """A parameter file (what identify writes) sets the FE biaxial test's material; an option
    typed on the command line overrides the file's value."""
    from conftest import read_summary, run_demo
    from cosserat_fenicsx.materials.ehlers.parameters import write_parameter_file
    path = tmp_path / "p.json"
    write_parameter_file(str(path), EhlersParameters(k_sigma=0.5, l_c=4e-3))
    out = tmp_path / "bx"
    run_demo("biaxial", "--parameters", path, "--l-c", "5e-3", "--cell-size", "0.0125", "--steps", "2",
             "--consolidation-steps", "1", "--axial-strain", "0.002", "--out", out)
    s = read_summary(out)
    assert s["k_sigma"] == 0.5 and s["l_c"] == 5e-3 and s["parameters_file"] == str(path)


def test_unloading_branch_is_elastic_and_sees_no_plasticity():
    """The data of step 1(a) (4.3): after the first record the branch stays inside the yield
    surface, and its axial stress change does not depend on a plastic parameter."""
    from cosserat_fenicsx.materials.ehlers import EhlersMaterial
    test = VirtualTest("triaxial_unloading", 300e3, axial_strain=5e-4, n_steps=10)
    h = test.run(EhlersMaterial(micropolar=False))
    assert np.all(h["yield_function"][1:] < 0) and h["axial_stress_change"][0] == 0
    assert np.all(np.diff(h["axial_stress_change"]) > 0)          # unloading: less compression
    other = test.run(EhlersMaterial(micropolar=False, C_gamma_D=40.0))
    assert not np.allclose(other["axial_stress"], h["axial_stress"], rtol=1e-4)   # the level moves
    assert np.allclose(other["axial_stress_change"], h["axial_stress_change"], rtol=2e-2)


def test_stepwise_identification_on_unloading_branches(tmp_path):
    """Thesis 4.3 / 6.1: elastic parameters from unloading branches first (within 2 % of the
    reference although the plastic ones are still 10 % off), the 14 plastic ones next, then a
    joint stage that removes what the first stages could not separate (to 1e-6)."""
    from conftest import run_demo
    out = tmp_path / "sw"
    run_demo("identify", "--params", "elastic:triaxial_unloading", "--params", "plastic:hydrostatic,triaxial,biaxial",
             "--params", "elastic,plastic", "--steps", "40", "--out", out)
    with open(out / "summary.json") as f:
        stages = json.load(f)["stages"]
    assert stages[0]["tests"] and all(t.startswith("triaxial_unloading") for t in stages[0]["tests"])
    assert max(abs(v) for v in stages[0]["relative_error"].values()) < 0.02
    assert max(abs(v) for v in stages[2]["relative_error"].values()) < 1e-6


def test_serially_correlated_errors_need_the_sandwich():
    """Errors correlated along a curve (AR(1), rho = 0.8, as neighbouring points of a DEM curve
    share the loading path): (4.28) holds the slope in half of the draws instead of 95 %; the
    Newey-West sandwich (serial_blocks) in 5 of 6 (HAC estimators are known to stay below
    the nominal rate at this correlation and length); with independent errors the sandwich
    keeps the nominal rate."""
    rng = np.random.default_rng(5)
    x = np.linspace(0, 1, 200)
    J = np.column_stack([np.ones_like(x), x])
    truth = np.array([1.0, 2.0])
    n = 600
    for rho, plain_range, sandwich_range in ((0.8, (0.0, 0.6), (0.8, 1.0)), (0.0, (0.92, 0.98), (0.9, 0.98))):
        plain = sandwich = 0
        for _ in range(n):
            e = np.empty(x.size)
            e[0] = rng.normal()
            for i in range(1, x.size):
                e[i] = rho * e[i - 1] + np.sqrt(1 - rho ** 2) * rng.normal()
            y = J @ truth + 0.05 * e
            s = np.linalg.lstsq(J, y, rcond=None)[0]
            lo, hi = analyse(["a", "b"], s, J, J @ s - y).intervals(joint=False)
            plain += lo[1] <= truth[1] <= hi[1]
            lo, hi = analyse(["a", "b"], s, J, J @ s - y, serial_blocks=[100, 100]).intervals(joint=False)
            sandwich += lo[1] <= truth[1] <= hi[1]
        assert plain_range[0] < plain / n < plain_range[1], (rho, plain / n)
        assert sandwich_range[0] < sandwich / n < sandwich_range[1], (rho, sandwich / n)


def test_interrupted_identification_leaves_its_files_and_no_workers(tmp_path):
    """Ctrl-C during an identification with worker processes: exit 130, summary.json says it
    was interrupted after the iterations it completed, and no worker outlives the run."""
    import signal
    import subprocess
    import sys
    import time
    from conftest import ROOT
    out = tmp_path / "int"
    cmd = [sys.executable, os.path.join(ROOT, "demos", "identify.py"), "--params", "plastic", "--steps", "3000",
           "--every", "1", "--processes", "2", "--out", str(out)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    rows = out / "iterations.csv"
    deadline = time.time() + 120
    while time.time() < deadline and not (rows.exists() and len(rows.read_text().splitlines()) >= 2):
        time.sleep(0.2)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 128 + signal.SIGINT, err
    with open(out / "summary.json") as f:
        summary = json.load(f)
    assert summary["completed"] is False and "interrupted by SIGINT" in summary["reason"]
    time.sleep(2.0)          # a worker notices its parent is gone within 0.5 s
    left = subprocess.run(["pgrep", "-f", str(out)], capture_output=True, text=True).stdout.split()
    assert not left, f"worker processes left behind: {left}"


@pytest.mark.parametrize("doc, named", [
    ([1, 2], "JSON array"), ({"bounds": 3}, "'bounds'"), ({"bounds": {"psi1": 3}}, "'psi1'"),
    ({"bounds": {"psi1": [1, "x"]}}, "'psi1'"), ({"stages": 5}, "'stages'"), ({"stages": [5]}, "stages[0]"),
    ({"stages": [{"params": "psi1", "kinds": 3}]}, "stages[0]"), ({"tests": {"file": "a"}}, "'tests'"),
    ({"tests": [{"file": "a.csv", "kind": "triaxial", "confining": [1]}]}, "tests[0].confining"),
    ({"tests": [{"file": "a.csv", "kind": "triaxial", "normalisation": [1]}]}, "tests[0].normalisation"),
    ({"tests": [{"file": "a.csv"}]}, "'kind'"), ({"tests": [{"file": "a.csv", "kind": "triaxial", "confinig": 1}]},
                                                "'confinig'"),
    ({"base": [1]}, "'base'"), ({"start": {"psi1": None}}, "'psi1'"), ({"bound": {}}, "'bound'")])
def test_config_shapes_are_checked(doc, named):
    """A config of the wrong shape (a list at the top, bounds as a number, a stage that is a
    number, a confining pressure given as a list, an unknown key) is refused in one line
    naming the field, not met later by an AttributeError."""
    from cosserat_fenicsx.identification.config import check_config
    with pytest.raises(InputError) as error:
        check_config(doc, "config c.json")
    assert named in str(error.value) and "c.json" in str(error.value) and "\n" not in str(error.value)


def test_damaged_input_files_are_refused_naming_them(tmp_path):
    """A repeated column, a binary file, NaN in a JSON file: one line each, naming the file."""
    (tmp_path / "dup.csv").write_text("axial_strain,axial_stress,axial_stress\n-0.01,1,2\n")
    with pytest.raises(InputError, match="dup.csv.*more than once"):
        D.read_test(str(tmp_path / "dup.csv"), "triaxial", 1e5)
    (tmp_path / "bin.csv").write_bytes(bytes(range(256)))
    with pytest.raises(InputError, match="bin.csv.*not a text"):
        D.read_test(str(tmp_path / "bin.csv"), "triaxial", 1e5)
    from conftest import run_demo
    (tmp_path / "c.json").write_text('{"start": {"psi1": NaN}}')
    proc = run_demo("identify", "--config", tmp_path / "c.json", "--out", tmp_path / "out", check=False)
    assert proc.returncode == 2 and "c.json" in proc.stderr and "NaN" in proc.stderr
    assert "Traceback" not in proc.stderr and not (tmp_path / "out").exists()
