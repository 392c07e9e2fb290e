"""Identification you can trust: the model follows the data's load steps (no bias from its
own discretisation), a failed model run is seen by the optimiser and a fit that did not get
anywhere says so, the error analysis survives parameters at bounds and extreme data, and
the identified set runs in the FE demos."""
import dataclasses
import json

import numpy as np
import pytest

from cosserat_fenicsx.identification.error_analysis import analyse
from cosserat_fenicsx.identification.virtual_tests import VirtualTest
from cosserat_fenicsx.materials.ehlers.material_point import LoadPath
from cosserat_fenicsx.materials.ehlers.parameters import EhlersParameters, write_parameter_file
from cosserat_fenicsx.validation import InputError

pytestmark = pytest.mark.serial          # material point only: the serial pass

#: the set that makes the data: Hostun with four plastic parameters moved
HIDDEN = dict(psi1=1.06, psi2=0.93, beta_star=1.11, gamma_star=0.91)
FOUR = ("psi1", "psi2", "beta_star", "gamma_star")
TESTS = (("triaxial", "100e3"), ("triaxial", "300e3"), ("biaxial", "100e3"))


def _hidden_set(path):
    hostun = EhlersParameters()
    write_parameter_file(str(path), EhlersParameters(**dict(hostun.as_dict(), **{
        n: getattr(hostun, n) * f for n, f in HIDDEN.items()})))
    return hostun


def _demo_data(tmp_path, steps, tests=TESTS):
    """history.csv of the material-point demo for each test, made from the hidden set."""
    from conftest import run_demo
    hostun = _hidden_set(tmp_path / "hidden.json")
    args = []
    for kind, p in tests:
        out = tmp_path / f"{kind}_{p}"
        extra = ["--steps", str(steps)] if steps else []
        run_demo("material_point", "--parameters", tmp_path / "hidden.json", "--test", kind, "--confining", p,
                 *extra, "--out", out)
        args += ["--data", f"{kind}:{p}:{out / 'history.csv'}"]
    return hostun, args


def _read(path):
    with open(path) as f:
        return json.load(f)


# ------------------------------------------------------------------ following the data's steps
def test_data_of_the_material_point_demo_are_met_exactly(tmp_path):
    """Noise-free data of the material-point demo (100 steps, its time column) re-identified
    from Hostun: the model follows the data's abscissae and times, so the hidden values come
    back within 1e-4 and f ends below 1e-10 of its start (measured: 1e-9 relative, f 1e-20).
    The same data with the model at 150 equal steps per test (1e-3 axial strain, the old
    default) leave a bias above 1e-3 on psi1: the test fails if the model stops following
    the data."""
    from conftest import run_demo
    hostun, data = _demo_data(tmp_path, 100)
    truth = {n: getattr(hostun, n) * f for n, f in HIDDEN.items()}
    out = tmp_path / "id"
    run_demo("identify", *data, "--params", ",".join(FOUR), "--min-model-steps", "100", "--out", out)
    result = _read(out / "identified_parameters.json")
    assert result["identification"]["converged"] is True
    assert sorted(result["identification"]["identified"]) == sorted(FOUR)
    for n in FOUR:
        assert abs(result["parameters"][n] / truth[n] - 1) < 1e-4, (n, result["parameters"][n], truth[n])
    stage = _read(out / "summary.json")["stages"][0]
    assert stage["f"] < 1e-10 * stage["f_start"]
    # the model's own discretisation error at 100 steps is reported (about 3 % of phi_0)
    largest = max(v for t in stage["discretisation_error"]["largest"].values() for v in t.values())
    assert 0.003 < largest < 0.05
    # the old default: equal steps, 1e-3 axial strain each
    out = tmp_path / "equal"
    run_demo("identify", *data, "--params", ",".join(FOUR), "--n-steps-per-test", "150", "--out", out, check=False)
    psi1 = _read(out / "identified_parameters.json")["parameters"]["psi1"]
    assert abs(psi1 / truth["psi1"] - 1) > 1e-3


@pytest.mark.slow
def test_the_14_plastic_parameters_from_the_material_point_demo(tmp_path):
    """The five tests of thesis 6.1 made by the material-point demo at its defaults from the
    hidden set; all 14 plastic parameters of (6.2) identified from Hostun within 1e-4
    (measured: 8e-9 in 14 s)."""
    from conftest import run_demo
    tests = (("hydrostatic", "1e6"),) + TESTS[:2] + (("triaxial", "600e3"), ("biaxial", "100e3"))
    hostun, data = _demo_data(tmp_path, None, tests)
    out = tmp_path / "id"
    run_demo("identify", *data, "--params", "plastic", "--out", out)
    result = _read(out / "identified_parameters.json")
    assert result["identification"]["converged"] is True and len(result["identification"]["identified"]) == 14
    for n in result["identification"]["identified"]:
        truth = getattr(hostun, n) * HIDDEN.get(n, 1.0)
        assert abs(result["parameters"][n] / truth - 1) < 1e-4, (n, result["parameters"][n], truth)
    stage = _read(out / "summary.json")["stages"][0]
    assert stage["f"] < 1e-10 * stage["f_start"]


def test_a_test_following_data_ends_a_step_at_every_point():
    """VirtualTest.following: every data abscissa is a step end, no step is longer than
    1/min_steps of the range (printed data round their abscissae: 0.1 % tolerated), the
    time column sets each step's time; refined() halves every step of both phases."""
    x = np.array([-0.001, -0.0025, -0.01, -0.05])
    test = VirtualTest.following("triaxial", 100e3, x, min_steps=20, axial_strain=0.05)
    path = np.array(test.path)
    assert all(np.isclose(path, v, rtol=0, atol=1e-15).any() for v in x)
    assert np.all(np.diff(-path) > 0) and np.max(np.diff(np.r_[0.0, -path])) <= 0.05 / 20 * (1 + 1e-12)
    # without a time column the material-point demo's rate: 600 s over the range
    assert test.n_steps == len(path) and np.isclose(sum(test.step_times), 600.0)
    timed = VirtualTest.following("triaxial", 100e3, x, times=[1.0, 2.0, 5.0, 9.0], min_steps=20, axial_strain=0.05)
    assert np.isclose(sum(timed.step_times), 9.0)
    fine = timed.refined()
    assert fine.n_steps == 2 * timed.n_steps and fine.n_consolidation == 2 * timed.n_consolidation
    assert np.isclose(sum(fine.step_times), 9.0) and set(timed.path) <= set(fine.path)
    # data short of the range: the model runs on to its end at the data's rate
    short = VirtualTest.following("triaxial", 100e3, x[:2], times=[1.0, 2.0], min_steps=10, axial_strain=0.05)
    assert np.isclose(short.path[-1], -0.05) and np.isclose(sum(short.step_times), 0.05 / 0.0025 * 2.0)
    iso = VirtualTest.following("hydrostatic", 1e6, [2e5, 5e5, 1e6], min_steps=10, start_pressure=1e5)
    assert np.allclose(iso.path[:3], [1.5e5, 2e5, 2.75e5]) and np.isclose(iso.path[-1], 1e6)   # 1e5 split in 2, 3e5 in 4


def test_bad_paths_and_time_columns_are_refused():
    with pytest.raises(InputError, match="time"):
        VirtualTest.following("triaxial", 100e3, [-0.01, -0.02], times=[2.0, 1.0], axial_strain=0.02)
    with pytest.raises(InputError, match="time"):
        VirtualTest.following("triaxial", 100e3, [-0.01, -0.02], times=[1.0, np.nan], axial_strain=0.02)
    for fractions, dts in (([0.5, 0.4, 1.0], [1, 1, 1]), ([0.5, 0.9], [1, 1]), ([0.5, 1.0], [1, 0]),
                           ([0.5, 1.0], [1])):
        with pytest.raises(InputError):
            LoadPath(fractions, dts)


def test_a_uniform_path_is_the_equal_steps():
    """A LoadPath of n equal steps gives the history of n_steps = n, bit for bit."""
    from cosserat_fenicsx.materials.ehlers import EhlersMaterial
    material = EhlersMaterial(micropolar=False)
    plain = VirtualTest("triaxial", 100e3, axial_strain=0.02, n_steps=20).run(material)
    n = 20
    path = VirtualTest("triaxial", 100e3, axial_strain=0.02, path=[-0.02 * k / n for k in range(1, n + 1)],
                       step_times=[1.0] * n).run(material)
    for q in ("axial_stress", "volumetric_strain"):
        assert np.array_equal(np.asarray(plain[q]), np.asarray(path[q])), q


def test_the_discretisation_estimate_is_the_error_against_fine_steps():
    """Objective.discretisation_error (Richardson with halved steps, first order) against the
    error itself: the model at n steps minus the model at 16 n, at the data points; within
    20 % for the largest error of each quantity."""
    from cosserat_fenicsx.identification.data import from_history
    from cosserat_fenicsx.identification.objective import Objective
    from cosserat_fenicsx.identification.parameter_set import ParameterSet
    from cosserat_fenicsx.materials.ehlers import EhlersMaterial
    ref = EhlersParameters(micropolar=False)
    fine = VirtualTest("triaxial", 100e3, axial_strain=0.05, n_steps=800, n_consolidation=320)
    d = from_history(fine, fine.run(EhlersMaterial(**ref.as_dict())), every=16)
    coarse = VirtualTest.following("triaxial", 100e3, d.x, min_steps=50, axial_strain=0.05, n_consolidation=20)
    assert coarse.n_steps <= 51            # the data's 50 intervals and the rest of the range
    d = dataclasses.replace(d, test=coarse)
    obj = Objective([d], ParameterSet(("psi1",), ref))
    estimate = obj.discretisation_error(obj.parameter_set.start)["largest"][d.label]
    actual = obj.evaluate(obj.parameter_set.start, jacobian=False).raw_residual      # model(n) - model(16 n)
    k = 0
    for q in d.y:
        m = len(d.y[q])
        err = np.max(np.abs(actual[k:k + m])) / d.normalisation[q]
        k += m
        assert err > 1e-3 and abs(estimate[q] / err - 1) < 0.2, (q, estimate[q], err)


# -------------------------------------------------------------- verdicts, bounds, extreme data
def _triaxial_file(tmp_path, scale=1.0, name="t.csv"):
    """A triaxial curve at 100 kPa made by the material-point driver from Hostun, its axial
    stress multiplied by `scale`."""
    from cosserat_fenicsx.identification.data import from_history, write_test
    from cosserat_fenicsx.materials.ehlers import EhlersMaterial
    test = VirtualTest("triaxial", 100e3, axial_strain=0.05, n_steps=50)
    d = from_history(test, test.run(EhlersMaterial(micropolar=False)), every=2)
    d.y["axial_stress"] = d.y["axial_stress"] * scale
    write_test(d, tmp_path / name)
    return tmp_path / name


def test_a_fit_the_model_cannot_follow_is_not_converged(tmp_path):
    """A curve 50 times stiffer than any the model makes: the optimiser runs into parameters
    the model cannot run and stops there; the demo says NOT converged with the cause, exits
    1, and the result file says so (before: 'converged', exit 0, the start returned)."""
    from conftest import run_demo
    path = _triaxial_file(tmp_path, 50.0)
    out = tmp_path / "stiff"
    proc = run_demo("identify", "--data", f"triaxial:100e3:{path}", "--params", "psi1,psi2,beta_star,gamma_star",
                    "--min-model-steps", "100", "--out", out, check=False)
    assert proc.returncode == 1, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert "NOT converged" in proc.stdout
    result = _read(out / "identified_parameters.json")
    assert result["identification"]["converged"] is False and result["identification"]["reasons"]
    assert _read(out / "summary.json")["completed"] is False


def test_a_model_that_cannot_run_at_all_is_not_converged(tmp_path):
    """A cell pressure of 1e300 Pa: every model run stops at the compression point; NOT
    converged, exit 1, no confidence intervals (before: converged, standard deviations 0)."""
    from conftest import run_demo
    path = _triaxial_file(tmp_path)
    out = tmp_path / "huge"
    proc = run_demo("identify", "--data", f"triaxial:1e300:{path}", "--params", "psi1", "--out", out, check=False)
    assert proc.returncode == 1, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert "NOT converged" in proc.stdout and "cannot run" in proc.stdout
    assert "95 %" not in proc.stdout
    assert _read(out / "identified_parameters.json")["identification"]["converged"] is False


def test_parameters_at_their_bounds_and_extreme_data_do_not_crash(tmp_path):
    """Every identified parameter ending at a bound: no error analysis, said in one line,
    exit 0 and the result written (before: IndexError, no file).  Data of magnitude 1e300:
    weights without overflow, finite outputs (before: OverflowError)."""
    from conftest import run_demo
    path = _triaxial_file(tmp_path)
    bounds = tmp_path / "b.json"
    bounds.write_text(json.dumps({"psi1": [2.0, 2.5]}))             # Hostun's 1.85 lies below: the fit ends at 2
    out = tmp_path / "bound"
    proc = run_demo("identify", "--data", f"triaxial:100e3:{path}", "--params", "psi1", "--bounds", bounds,
                    "--start", _start_file(tmp_path, psi1=2.2), "--out", out, check=False)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert "every parameter is at a bound" in proc.stdout
    assert _read(out / "identified_parameters.json")["parameters"]["psi1"] == pytest.approx(2.0)
    big = _triaxial_file(tmp_path, 1e300, "big.csv")
    out = tmp_path / "big"
    proc = run_demo("identify", "--data", f"triaxial:100e3:{big}", "--params", "psi1", "--out", out, check=False)
    assert proc.returncode in (0, 1), proc.stderr[-2000:]
    assert "Traceback" not in proc.stderr
    summary = (out / "summary.json").read_text()
    assert "NaN" not in summary and "Infinity" not in summary


def _start_file(tmp_path, **values):
    path = tmp_path / "start.json"
    write_parameter_file(str(path), EhlersParameters(**dict(EhlersParameters().as_dict(), **values)))
    return path


def test_bounds_of_parameters_no_stage_identifies_are_refused(tmp_path):
    from conftest import run_demo
    path = _triaxial_file(tmp_path)
    bounds = tmp_path / "b.json"
    bounds.write_text(json.dumps({"psi2": [1.0, 2.0]}))
    proc = run_demo("identify", "--data", f"triaxial:100e3:{path}", "--params", "psi1", "--bounds", bounds,
                    "--out", tmp_path / "out", check=False)
    assert proc.returncode == 2 and "no stage identifies" in proc.stderr
    assert len(proc.stderr.strip().splitlines()) <= 2
    assert not (tmp_path / "out").exists()


def test_an_undetermined_parameter_has_an_infinite_interval():
    """A parameter the data do not see (zero column of J): std inf, correlation NaN, the
    others' intervals as without it (it spends no degree of freedom); no crash, no zero width."""
    rng = np.random.default_rng(1)
    x = np.linspace(0, 1, 50)
    J = np.column_stack([np.ones_like(x), x, np.zeros_like(x)])
    r = 0.01 * rng.normal(size=x.size)
    ea = analyse(["a", "b", "c"], [1.0, 2.0, 3.0], J, r)
    ref = analyse(["a", "b"], [1.0, 2.0], J[:, :2], r)
    assert np.isinf(ea.std[2]) and np.all(np.isfinite(ea.std[:2]))
    assert np.allclose(ea.std[:2], ref.std, rtol=1e-12)
    assert np.isnan(ea.correlation[2, 0])
    doc = json.dumps(ea.to_dict(), allow_nan=False)          # strict JSON: None where not finite
    assert "null" in doc


# ------------------------------------------------------------- the identified set drives the FE
def test_identified_set_runs_in_the_biaxial_demo(tmp_path):
    """identify writes the plastic values it found with the start's micropolar values (homogeneous
    tests do not see l_c, mu_c, k_sigma, k_mu); demos/biaxial.py runs that file (before: it
    wrote mu_c = 0 and the FE solve stopped at t = 0 with DIVERGED_LINEAR_SOLVE).  A set with
    mu_c = 0 is refused by the biaxial demo in one line naming mu_c."""
    from conftest import read_summary, run_demo
    path = _triaxial_file(tmp_path)
    out = tmp_path / "id"
    run_demo("identify", "--data", f"triaxial:100e3:{path}", "--params", "psi1", "--out", out)
    result = _read(out / "identified_parameters.json")
    assert result["parameters"]["mu_c"] > 0 and result["parameters"]["l_c"] > 0
    assert "mu_c" in result["identification"]["not_identified_micropolar"]
    bx = tmp_path / "bx"
    run_demo("biaxial", "--parameters", out / "identified_parameters.json", "--cell-size", "0.0125", "--steps", "2",
             "--consolidation-steps", "1", "--axial-strain", "0.002", "--out", bx)
    assert read_summary(bx)["completed"] is True
    bad = tmp_path / "mu0.json"
    write_parameter_file(str(bad), EhlersParameters(micropolar=True, mu_c=0.0))
    proc = run_demo("biaxial", "--parameters", bad, "--out", tmp_path / "bad", check=False)
    assert proc.returncode == 2 and "mu_c" in proc.stderr and len(proc.stderr.strip().splitlines()) <= 2
