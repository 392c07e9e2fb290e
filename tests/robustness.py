"""Run a demo as a user would with numeric options drawn at random, and judge the end.

Shared by the property tests (tests/test_robustness_properties.py, a few draws per demo) and
the sweep (benchmarks/robustness/robustness_sweep.py, many). The demos declare the range of every
numeric option (cosserat_fenicsx.validation); `describe_options(demo)` reads them.

Every draw must end in one of four ways (anything else raises AssertionError):
  refused      exit 2, one line on stderr naming the option, no output directory; a value
               outside the declared range must end this way
  completed    exit 0, summary.json with completed: true, finite numbers in summary.json
               and history.csv
  stopped      exit 1, summary.json with completed: false and the reason (extreme physics)
  interrupted  still running after `timeout` s (a long but valid case): SIGTERM, then
               exit 143 within `grace` s and summary.json with completed: false
and never a Python traceback, NaN in a result file or an HDF5 file that h5py cannot open.
"""
import csv
import json
import math
import os
import shutil
import signal
import subprocess
import sys

from cosserat_fenicsx.validation import Range

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

#: the cheapest meaningful run of each demo (one option at a time is drawn on top of it)
BASELINES = {
    "shear_layer": ["--cell-size", "0.02", "--steps", "2"],
    "hole_plate": ["--cell-size", "0.05"],
    "material_point": ["--test", "triaxial", "--steps", "20", "--consolidation-steps", "5"],
    "dem_cell": ["--particles", "40", "--axial-strain", "0.002", "--increment", "0.001"],
    "biaxial": ["--cell-size", "0.0125", "--steps", "2", "--consolidation-steps", "1", "--axial-strain", "0.002"],
    "femdem_biaxial": ["--mesh", "1x1", "--particles", "40", "--axial-strain", "0.002", "--steps", "2"],
    "identify": ["--steps", "20", "--every", "2", "--max-iterations", "4"],
}
#: [s] a SIGTERM is heard when the current C call returns (docs/reference/robustness.md); the longest
#: one a valid cheap case can make is a MUMPS factorisation of a mesh near meshes.max_elements()
GRACE = 180.0
SPECIAL_VALUES = (math.nan, math.inf, -math.inf, 0.0, -1.0, 1e300, -1e300, 1e-300, 1e-9, 1e9, 0.5, 2.0, 7.0)

ENV = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
           OMPI_MCA_rmaps_base_oversubscribe="1", OMP_NUM_THREADS="1")


def describe_options(demo):
    """{option: dict(low, high, low_open, high_open, integer, infinite, default)}."""
    env = dict(ENV, COSSERAT_DESCRIBE_OPTIONS="1")
    proc = subprocess.run([sys.executable, os.path.join(ROOT, "demos", demo + ".py")], capture_output=True,
                          text=True, env=env, cwd=ROOT, timeout=120)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


def in_range(spec, value):
    """Whether `value` lies in the range a demo declared (describe_options' spec)."""
    return Range(**{k: v for k, v in spec.items() if k != "default"}).contains(value)


def text(value):
    if isinstance(value, float) and value.is_integer() and abs(value) < 1e15:
        return str(int(value))
    return repr(value)


def run_case(demo, values, out, timeout=60.0, grace=GRACE, ranks=None):
    """Run the demo's baseline with `values` ({option: value}, set after the baseline's own
    options, so they win); returns (outcome, detail)."""
    if os.path.exists(out):
        shutil.rmtree(out)
    drawn = [item for option, value in values.items() for item in (option, text(value))]
    cmd = [sys.executable, os.path.join(ROOT, "demos", demo + ".py"), *BASELINES[demo], *drawn, "--out", out]
    if ranks:
        cmd = ["mpirun", "-n", str(ranks)] + cmd
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV, cwd=ROOT)
    interrupted = False
    try:
        stdout, stderr = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        interrupted = True
        proc.send_signal(signal.SIGTERM)
        try:
            stdout, stderr = proc.communicate(timeout=grace)
        except subprocess.TimeoutExpired:
            proc.kill()
            stdout, stderr = proc.communicate()
            raise AssertionError(f"{' '.join(cmd)}: did not end within {grace} s of SIGTERM")
    return judge(cmd, proc.returncode, stdout, stderr, out, interrupted)


def judge(cmd, code, stdout, stderr, out, interrupted):
    where = f"{' '.join(cmd)} (exit {code})"
    assert "Traceback" not in stderr and "Traceback" not in stdout, f"{where}: traceback\n{stderr[-3000:]}"
    if code == 2 and not interrupted:
        lines = [line for line in stderr.strip().splitlines() if line.strip()]
        assert len(lines) == 1 and "error:" in lines[0], f"{where}: a refusal must be one line:\n{stderr[-2000:]}"
        assert not os.path.exists(out), f"{where}: a refused run left {out} behind"
        return "refused", lines[0]
    summary_path = os.path.join(out, "summary.json")
    assert os.path.exists(summary_path), f"{where}: no summary.json\n{stderr[-2000:]}"
    with open(summary_path) as f:
        summary = json.load(f)
    check_files(out, where)
    if interrupted:
        assert code in (128 + signal.SIGTERM, -signal.SIGTERM), f"{where}: SIGTERM should end with 143\n{stderr[-2000:]}"
        assert summary["completed"] is False and summary["reason"], f"{where}: {summary.get('reason')}"
        return "interrupted", summary["reason"]
    if code == 0 and summary.get("completed", True) is False:
        # stopped as asked (--stop-after K): not complete, but nothing went wrong
        assert summary.get("stopped_after_step") and "--stop-after" in summary["reason"], \
            f"{where}: exit 0 but not completed: {summary.get('reason')}"
        assert_finite(summary, where + " summary.json")
        return "completed", summary["reason"]
    if code == 0:
        assert summary.get("completed", True) is True, f"{where}: exit 0 but not completed"
        assert_finite(summary, where + " summary.json")
        return "completed", ""
    assert code == 1, f"{where}: unexpected exit status\n{stderr[-2000:]}"
    assert summary["completed"] is False and summary["reason"], f"{where}: exit 1 without a reason"
    return "stopped", summary["reason"]


#: summary entries that echo settings, where inf is a valid value (friction: no sliding)
SETTINGS = ("options", "law")


def assert_finite(data, where, path=""):
    """Every number of a result is finite (the entries in SETTINGS excepted)."""
    if isinstance(data, dict):
        for k, v in data.items():
            if k in SETTINGS:
                continue
            assert_finite(v, where, f"{path}.{k}")
    elif isinstance(data, (list, tuple)):
        for i, v in enumerate(data):
            assert_finite(v, where, f"{path}[{i}]")
    elif isinstance(data, float):
        assert math.isfinite(data), f"{where}: {path} = {data}"


def check_files(out, where):
    """history.csv has finite numbers only; every .h5 file opens with h5py."""
    history = os.path.join(out, "history.csv")
    if os.path.exists(history):
        with open(history) as f:
            for row in csv.DictReader(f):
                for k, v in row.items():
                    assert v not in (None, "") and math.isfinite(float(v)), f"{where}: history.csv {k} = {v!r}"
    for name in os.listdir(out):
        if name.endswith(".h5"):
            import h5py
            with h5py.File(os.path.join(out, name), "r") as f:
                f.visit(lambda name: None)
