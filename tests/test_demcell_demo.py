"""demos/dem_cell.py end to end (tiny run by default, the full default run is slow), its
micropolar loadings (--test shear / curvature) and the initial-fabric control of the packing
generator."""
import csv
import json
import os
import subprocess
import sys

import numpy as np
import pytest

import demcell as dc

pytestmark = pytest.mark.serial
DEMO = os.path.join(os.path.dirname(__file__), "..", "demos", "dem_cell.py")
COLUMNS = ["axial_strain", "stress_ratio", "volumetric_strain", "coordination_number", "anisotropy"]


def run_demo(out, *args, stdout=False):
    proc = subprocess.run([sys.executable, DEMO, "--out", str(out), *args], check=True,
                          capture_output=True, text=True, timeout=900)
    with open(os.path.join(out, "history.csv")) as f:
        rows = list(csv.reader(f))
    summary = json.load(open(os.path.join(out, "summary.json")))
    return (rows, summary, proc.stdout) if stdout else (rows, summary)


def test_demo_small_run(tmp_path):
    rows, summary = run_demo(tmp_path, "--particles", "40", "--axial-strain", "0.004",
                             "--increment", "0.001", "--snapshot-every", "2", "--no-rotation")
    assert rows[0] == COLUMNS and len(rows) == 1 + 1 + 4
    data = np.array(rows[1:], dtype=float)
    assert np.all(np.isfinite(data)) and data[-1, 0] == pytest.approx(-0.004)
    assert summary["peak_stress_ratio"] == pytest.approx(data[:, 1].max())
    assert os.path.exists(tmp_path / "biaxial.png")
    snaps = sorted(os.listdir(tmp_path / "snapshots"))
    assert "particles_0004.vtk" in snaps and "contacts_0004.vtk" in snaps


def test_demo_rejects_bad_options(tmp_path):
    p = subprocess.run([sys.executable, DEMO, "--out", str(tmp_path), "--axial-strain", "-1"],
                       capture_output=True, text=True)
    assert p.returncode != 0 and "axial-strain" in p.stderr
    p = subprocess.run([sys.executable, DEMO, "--frobnicate"], capture_output=True, text=True)
    assert p.returncode != 0 and "unrecognized" in p.stderr


@pytest.mark.slow
def test_demo_default_run(tmp_path):
    """000 Table 3 parameters: the stress ratio peaks then softens, the sample dilates."""
    rows, summary = run_demo(tmp_path)
    data = np.array(rows[1:], dtype=float)
    assert 0.25 < summary["peak_stress_ratio"] < 0.6
    assert data[-1, 1] < summary["peak_stress_ratio"]
    assert data[-1, 2] > 0.0 and summary["increments_not_converged"] == 0


# ----- micropolar loadings (docs/reference/demcell.md "Micropolar loadings of demos/dem_cell.py")
SHEAR_COLUMNS = ["shear_strain", "sigma11", "sigma22", "sigma12", "sigma21", "skew_stress", "m31", "m32",
                 "coordination_number", "sliding_fraction"]
CURVATURE_COLUMNS = ["rotation_jump", "kappa31", "m31", "m32", "skew_stress", "sliding_fraction"]
# 60 discs at p0/kn = 1e-3 and increments of 1e-4 (a tenth of p0/kn, the overlap per radius): no
# contact opens or slides in the first increment, so the response is the one of the frozen
# network that the DEMQO tangent linearizes (001 eq. 20)
SMALL = ["--particles", "60", "--increment", "1e-4", "--snapshot-every", "1"]


def printed_tangent(stdout):
    """The 6x6 micropolar DEMQO tangent as the demo prints it (the six lines after its header)."""
    lines = stdout.splitlines()
    start = next(i for i, line in enumerate(lines) if "micropolar DEMQO tangent" in line) + 1
    C = np.array([[float(v) for v in line.split("]", 1)[1].split()] for line in lines[start:start + 6]])
    assert C.shape == (6, 6) and np.all(np.isfinite(C))
    return C


def check_outputs(out, rows, columns, plot, n_inc):
    assert rows[0] == columns and len(rows) == 1 + 1 + n_inc
    data = np.array(rows[1:], dtype=float)
    assert np.all(np.isfinite(data))
    assert os.path.exists(out / plot)
    snaps = sorted(os.listdir(out / "snapshots"))
    assert f"particles_{n_inc:04d}.vtk" in snaps and f"contacts_{n_inc:04d}.vtk" in snaps
    return data


def snapshot_rotation(path):
    """The particles' ``rotation`` point data of a legacy VTK snapshot."""
    lines = open(path).read().split("\n")
    start = lines.index("SCALARS rotation double 1") + 2
    end = next(i for i in range(start, len(lines)) if lines[i].startswith("VECTORS"))
    return np.array(lines[start:end], dtype=float)


def test_demo_shear_skew_stress(tmp_path):
    """Simple shear F = [[1, gamma], [0, 1]] at a held micro-rotation. With eps = Grad u + e phi
    the skew strain is eps12 - eps21 = gamma + 2 phi. Hill-Mandel gives
    W_dot = |Y| (sigma12 - sigma21) phi_dot + ..., and the frozen network's energy is a minimum,
    so d(skew stress)/d phi > 0; objectivity (F = R(a), phi = a loads nothing) makes the skew
    stress a function of eps12 - eps21: skew = 2 mu_c (eps12 - eps21) with mu_c > 0. phi = 0:
    positive, about 2 mu_c gamma (mu_c = (C[2,2] - C[2,3]) / 2 of the printed tangent; factor-2
    band: only sliding, which makes it softer, or contact changes could move it, and there are
    none in the first increment, see SMALL). phi = -gamma/2 (the material rotation): no skew
    strain, the skew stress is only the packing's anisotropy, small against the shear stress
    (an isotropic frozen network gives 2 mu_c / (mu + mu_c) ~ 0.6 for phi = 0)."""
    gamma = 2e-4
    rows, summary, stdout = run_demo(tmp_path / "zero", "--test", "shear", "--shear-strain", str(gamma), *SMALL,
                                     stdout=True)
    zero = check_outputs(tmp_path / "zero", rows, SHEAR_COLUMNS, "shear.png", 2)
    C = printed_tangent(stdout)
    mu_c = 0.5 * (C[2, 2] - C[2, 3])
    assert mu_c > 0.0
    d_skew = zero[1, 5] - zero[0, 5]
    assert d_skew > 0.0 and 0.5 < d_skew / (2.0 * mu_c * zero[1, 0]) < 2.0
    assert np.allclose(zero[:, 5], zero[:, 3] - zero[:, 4], rtol=0, atol=1e-12)
    assert summary["initial_skew_modulus"] == pytest.approx(d_skew / zero[1, 0])
    assert summary["peak_shear_stress"] == pytest.approx(zero[:, 3].max())
    assert "not controlled" in summary["lateral_stress"]
    # the snapshots' rotation field is the fluctuation: zero at the reference
    assert np.all(snapshot_rotation(tmp_path / "zero" / "snapshots" / "particles_0000.vtk") == 0.0)

    rows, summary = run_demo(tmp_path / "material", "--test", "shear", "--shear-strain", str(gamma),
                             "--rotation", "material", *SMALL)
    material = check_outputs(tmp_path / "material", rows, SHEAR_COLUMNS, "shear.png", 2)
    d_skew_m = material[1:, 5] - material[0, 5]
    d_shear_m = material[1:, 3] - material[0, 3]
    assert np.all(d_shear_m > 0.0)
    assert np.all(np.abs(d_skew_m) < 0.25 * d_shear_m)
    assert abs(d_skew_m[0]) < 0.25 * d_skew
    assert summary["initial_skew_modulus"] is None


def test_demo_curvature_bending_modulus(tmp_path):
    """kappa = (k, 0) with F = I, phi = 0: Hill-Mandel W_dot = |Y| m . kappa_dot with a stable
    network gives dm31/dkappa31 = B > 0; m31 grows with kappa; the first increment's B is the
    frozen network's, within a factor 2 of the printed tangent's C[4,4] (see SMALL);
    l_c = sqrt(B / (2 mu_c)), and the mean grain diameter is that of the saved packing."""
    rows, summary, stdout = run_demo(tmp_path, "--test", "curvature", "--rotation-jump", "3e-4", *SMALL,
                                     stdout=True)
    data = check_outputs(tmp_path, rows, CURVATURE_COLUMNS, "curvature.png", 3)
    assert data[-1, 0] == pytest.approx(3e-4)
    k_per_jump = data[1:, 1] / data[1:, 0]
    assert np.allclose(k_per_jump, k_per_jump[0], rtol=1e-12) and k_per_jump[0] > 0.0   # k = jump / |Y1|
    assert np.all(np.diff(data[:, 2]) > 0.0)                                             # m31 grows
    C = printed_tangent(stdout)
    B = (data[1, 2] - data[0, 2]) / data[1, 1]
    assert B > 0.0 and summary["bending_modulus_B"] == pytest.approx(B)
    assert 0.5 < B / C[4, 4] < 2.0
    mu_c = 0.5 * (C[2, 2] - C[2, 3])
    assert summary["characteristic_length_l_c"] == pytest.approx(np.sqrt(B / (2.0 * mu_c)), rel=1e-4)
    radius = np.load(tmp_path / "packing.npz")["radius"]
    assert summary["mean_grain_diameter"] == pytest.approx(2.0 * radius.mean())


@pytest.mark.parametrize("args, message", [
    (["--test", "shear", "--lateral-control", "strain"], "--lateral-control is an option of --test biaxial"),
    (["--test", "shear", "--no-rotation"], "locked rotations cannot carry a micro-rotation or a curvature"),
    (["--test", "curvature", "--no-rotation"], "locked rotations cannot carry a micro-rotation or a curvature"),
    (["--test", "curvature", "--shear-strain", "0.01"], "--shear-strain is an option of --test shear"),
    (["--shear-strain", "0.01"], "--shear-strain is an option of --test shear, not of --test biaxial"),
    (["--test", "shear", "--axial-strain", "0.1"], "--axial-strain is an option of --test biaxial"),
    (["--test", "curvature", "--rotation-jump", "0.01", "--increment", "0.02"], "--increment must be in"),
    (["--test", "curvature", "--rotation-jump", "2"], "--rotation-jump"),
    (["--packing", "p.npz", "--particles", "50"], "--packing gives the discs: --particles would have no effect"),
    (["--packing", "p.npz", "--anisotropy", "0.05", "--seed", "1"], "--anisotropy, --seed would have no effect"),
])
def test_demo_refuses_options_of_another_test(tmp_path, args, message):
    out = tmp_path / "out"
    p = subprocess.run([sys.executable, DEMO, "--out", str(out), *args], capture_output=True, text=True)
    lines = p.stderr.strip().splitlines()
    assert p.returncode == 2 and len(lines) == 1 and message in lines[0], p.stderr
    assert not out.exists()


def test_fabric_anisotropy_control():
    st, info = dc.generate_packing(100, pressure=10.0, seed=2, anisotropy=0.05)
    a = dc.DemCell(st).homogenized().anisotropy
    assert a == pytest.approx(info["anisotropy"])
    errors = [abs(t[1] - 0.05) for t in info["anisotropy_trials"]]
    assert abs(a - 0.05) == pytest.approx(min(errors))
