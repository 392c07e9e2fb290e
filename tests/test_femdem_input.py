"""FEM x DEM bad input (issue item 10): refused with a clear error before any cell exists.

As a user runs it: demos/femdem_biaxial.py with one bad option must exit with code 2 (the
argparse convention), print one `error: ...` line on stderr naming the option (no
traceback), and do so quickly, before the cells are prepared and a step is computed: no
history.csv (it is opened once the cells exist) and no "cells prepared" line. The default
options (228 discs, a 2x4 mesh: 48 Gauss points) are kept in the runs that must be refused,
so that a check that stopped working would show up as a slow run that writes history.csv.

The Python API: FemDemSettings(...).check() raises ValueError naming the setting (these
tests do no MPI work, so they also run in the MPI pass).
"""
import re
import time

import numpy as np
import pytest

from cosserat_fenicsx.materials.dem import CellOptions
from cosserat_fenicsx.scenes.femdem_biaxial import FemDemSettings, parse_mesh

MAX_WALL = 20.0     # s; a refused run takes ~1.5 s (imports), preparing cells + a step much longer


def packing_file(tmp_path, name="packing.npz", particles=20, **changes):
    """A real demcell packing (optionally with entries replaced or removed)."""
    import demcell as dc
    state, info = dc.generate_packing(particles, pressure=10.0, seed=0)
    path = tmp_path / name
    dc.save_packing(str(path), state, info)
    if changes:
        data = dict(np.load(path))
        for key, value in changes.items():
            if value is None:
                data.pop(key)
            else:
                data[key] = value(data[key]) if callable(value) else value
        np.savez(path, **data)
    return path


def refused(demo, tmp_path, *args):
    """Run the demo with `args`; check the clean refusal; return the error line."""
    out = tmp_path / "out"
    start = time.perf_counter()
    proc = demo("femdem_biaxial", *args, "--out", out, check=False, timeout=60)
    wall = time.perf_counter() - start
    report = f"args {args}: exit {proc.returncode}\nstdout:\n{proc.stdout[-1500:]}\nstderr:\n{proc.stderr[-2500:]}"
    assert "Traceback" not in proc.stderr, report
    assert proc.returncode == 2, report
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    errors = [line for line in lines if "error:" in line]
    assert len(errors) == 1 and lines[-1] == errors[0], report        # one line, the last one
    assert re.match(r"^\S*femdem_biaxial\.py: error: \S", errors[0]), report
    assert "cells prepared" not in proc.stdout, report
    assert not (out / "history.csv").exists(), report
    assert wall < MAX_WALL, f"refusal took {wall:.1f} s\n{report}"
    return errors[0]


def text_as_npz(tmp_path):
    path = tmp_path / "notes.npz"
    path.write_text("these are my notes, not a packing\n")
    return path


def foreign_npz(tmp_path):
    path = tmp_path / "other.npz"
    np.savez(path, x=np.arange(5.0), y=np.ones((2, 2)))
    return path


CASES = [   # (id, args, pattern the error line must match)
    ("tangent-foo", ["--tangent", "foo"], r"--tangent"),
    ("micropolar-pstlo-sliding", ["--mode", "micropolar", "--tangent", "pstlo_sliding"], r"pstlo_sliding.*Cauchy"),
    ("mode-foo", ["--mode", "foo"], r"--mode"),
    ("classical-mu-c", ["--mode", "classical", "--mu-c", 100], r"--mu-c"),
    ("classical-l-c", ["--mode", "classical", "--l-c", 1e-3], r"--l-c"),
    ("kn-zero", ["--kn", 0], r"\bkn\b"),
    ("seed-beside-packing", ["--packing", "p.npz", "--seed", 3], r"--packing gives the discs: --seed"),
    ("anisotropy-1.5", ["--anisotropy", 1.5], r"--anisotropy.*\[0, 1\)"),
    ("anisotropy-beside-packing", ["--packing", "p.npz", "--anisotropy", 0.05], r"--packing gives the discs: --anisotropy"),
    ("kn-negative", ["--kn", -1], r"\bkn\b"),
    ("ks-negative", ["--ks", -1], r"\bks\b"),
    ("friction-negative", ["--friction", -0.1], r"\bfriction\b"),
    ("pressure-zero", ["--pressure", 0], r"\bpressure\b"),
    ("particles-5", ["--particles", 5], r"\bparticles\b"),
    ("mesh-2by4", ["--mesh", "2by4"], r"--mesh.*2by4"),
    ("mesh-0x4", ["--mesh", "0x4"], r"--mesh.*0x4"),
    ("mesh-x", ["--mesh", "x"], r"--mesh"),
    ("axial-strain-zero", ["--axial-strain", 0], r"axial[-_]strain"),
    ("axial-strain-0.7", ["--axial-strain", 0.7], r"axial[-_]strain"),
    ("relaxation-tol-zero", ["--relaxation-tol", 0], r"relaxation[-_]tol"),
    ("weak-friction-zero", ["--weak-friction", 0], r"weak[-_]friction"),
    ("force-rtol-zero", ["--force-rtol", 0], r"force[-_]rtol"),
    ("stagnation-its-negative", ["--stagnation-its", -1], r"stagnation[-_]its"),
    ("cell-threads-without-batched", ["--no-batched", "--cell-threads", 2], r"cell_threads.*--no-batched"),
    ("cell-threads-too-many", ["--batched", "--cell-threads", 100000], r"cell_threads.*NUMBA_NUM_THREADS"),
    ("cell-threads-zero", ["--batched", "--cell-threads", 0], r"cell-threads"),
    ("cell-option-no-equals", ["--cell-option", "fire"], r"--cell-option.*KEY=VALUE"),
    ("cell-option-unknown", ["--cell-option", "speed=2"], r"unknown relaxation option.*speed"),
    ("cell-option-own-setting", ["--cell-option", "tol=1e-4"], r"'tol'.*--relaxation-tol"),
    ("cell-option-method", ["--cell-option", "method=verlet"], r"relaxation method 'verlet'"),
    ("cell-option-dt-safety", ["--cell-option", "dt_safety=1.5"], r"dt_safety must be in \(0, 1\]"),
    ("cell-option-check-every", ["--cell-option", "check_every=0"], r"check_every must be an integer >= 1"),
    ("cell-option-fixed-steps-zero", ["--cell-option", "fixed_steps=0"], r"fixed_steps must be an integer in \[1"),
    ("cell-option-fixed-steps-fraction", ["--cell-option", "fixed_steps=2.5"], r"fixed_steps must be an integer"),
    ("cell-option-relax-cap-zero", ["--cell-option", "relax_cap=0"], r"relax_cap must be an integer in \[1"),
    ("cell-option-relax-cap-and-fixed", ["--cell-option", "relax_cap=100", "--cell-option", "fixed_steps=100"],
     r"relax_cap and fixed_steps exclude each other"),
    ("cell-option-relax-cap-over-budget", ["--cell-option", "relax_cap=5000", "--max-dem-steps", 1000],
     r"relax_cap = 5000 exceeds max_steps = 1000"),
]


@pytest.mark.serial
@pytest.mark.parametrize("args, pattern", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_bad_option_is_refused(demo, tmp_path, args, pattern):
    line = refused(demo, tmp_path, *args)
    assert re.search(pattern, line, re.IGNORECASE), line


@pytest.mark.serial
def test_missing_packing_file(demo, tmp_path):
    path = tmp_path / "nowhere" / "packing.npz"
    line = refused(demo, tmp_path, "--packing", path)
    assert "packing" in line and str(path) in line and "not found" in line, line


@pytest.mark.serial
@pytest.mark.parametrize("make, pattern", [(text_as_npz, r"cannot read packing file"),
                                           (foreign_npz, r"not a demcell packing")],
                         ids=["text-renamed-npz", "npz-not-a-packing"])
def test_corrupt_packing_file(demo, tmp_path, make, pattern):
    path = make(tmp_path)
    line = refused(demo, tmp_path, "--packing", path)
    assert str(path) in line and re.search(pattern, line), line


# --- corrupt packings, seeds and budgets that once escaped as tracebacks ------------------

@pytest.mark.serial
def test_truncated_packing_file(demo, tmp_path):
    good = packing_file(tmp_path)
    path = tmp_path / "truncated.npz"
    path.write_bytes(good.read_bytes()[:300])
    line = refused(demo, tmp_path, "--packing", path)
    assert str(path) in line, line


@pytest.mark.serial
def test_packing_file_missing_an_array(demo, tmp_path):
    path = packing_file(tmp_path, "incomplete.npz", radius=None)
    line = refused(demo, tmp_path, "--packing", path)
    assert str(path) in line, line


@pytest.mark.serial
def test_packing_file_inconsistent_arrays(demo, tmp_path):
    path = packing_file(tmp_path, "inconsistent.npz", radius=lambda r: r[:5])
    # a small run, so that the outcome where the run gets going costs seconds only
    line = refused(demo, tmp_path, "--packing", path, "--mesh", "1x1", "--steps", 1, "--axial-strain", 0.001)
    assert str(path) in line, line


@pytest.mark.serial
def test_negative_seed(demo, tmp_path):
    line = refused(demo, tmp_path, "--seed", -1)
    assert re.search(r"\bseed\b", line), line


@pytest.mark.serial
def test_tiny_dem_step_budget(demo, tmp_path):
    line = refused(demo, tmp_path, "--max-dem-steps", 5, "--mesh", "1x1", "--particles", 100)
    assert re.search(r"max[-_]dem[-_]steps|max_steps", line), line


# --- the Python API -----------------------------------------------------------------------

API_CASES = [   # (id, settings, pattern of the ValueError)
    ("tangent", dict(tangent="foo"), r"tangent"),
    ("micropolar-pstlo-sliding", dict(mode="micropolar", tangent="pstlo_sliding"), r"pstlo_sliding.*Cauchy"),
    ("mode", dict(mode="foo"), r"mode"),
    ("classical-mu-c", dict(mode="classical", mu_c=100.0), r"mu_c"),
    ("classical-l-c", dict(mode="classical", l_c=1e-3), r"l_c"),
    ("axial-strain-zero", dict(axial_strain=0.0), r"axial_strain"),
    ("axial-strain-0.7", dict(axial_strain=0.7), r"axial_strain"),
    ("axial-strain-nan", dict(axial_strain=float("nan")), r"axial_strain"),
    ("nx-zero", dict(nx=0), r"\bnx\b"),
    ("steps-zero", dict(steps=0), r"\bsteps\b"),
    ("force-rtol-zero", dict(force_rtol=0.0), r"force_rtol"),
    ("stagnation-its-zero", dict(stagnation_its=0), r"stagnation_its"),
    ("stagnation-its-float", dict(stagnation_its=2.5), r"stagnation_its"),
    ("weak-friction-zero", dict(weak_friction_factor=0.0), r"weak_friction_factor"),
    ("kn-zero", dict(cell=CellOptions(kn=0.0)), r"\bkn\b"),
    ("ks-negative", dict(cell=CellOptions(ks=-1.0)), r"\bks\b"),
    ("friction-negative", dict(cell=CellOptions(friction=-0.1)), r"\bfriction\b"),
    ("pressure-zero", dict(cell=CellOptions(pressure=0.0)), r"\bpressure\b"),
    ("particles-5", dict(cell=CellOptions(particles=5)), r"\bparticles\b"),
    ("relaxation-tol-zero", dict(cell=CellOptions(relaxation_tol=0.0)), r"relaxation_tol"),
    ("max-steps-zero", dict(cell=CellOptions(max_steps=0)), r"max_steps"),
    ("missing-packing", dict(cell=CellOptions(packing="/nonexistent/packing.npz")), r"packing file not found"),
    ("cell-threads-float", dict(batched=True, cell_threads=1.5), r"cell_threads"),
    ("batched-string", dict(batched="yes"), r"batched"),
]


@pytest.mark.parametrize("settings, pattern", [c[1:] for c in API_CASES], ids=[c[0] for c in API_CASES])
def test_settings_check_names_the_setting(settings, pattern):
    with pytest.raises(ValueError, match=pattern):
        FemDemSettings(**settings).check()


def test_settings_check_accepts_the_defaults_and_extremes():
    """The check refuses nothing valid: defaults, zero and infinite friction, l_c = 0."""
    FemDemSettings().check()
    FemDemSettings(cell=CellOptions(friction=0.0)).check()
    FemDemSettings(cell=CellOptions(friction=float("inf"), ks=0.0)).check()
    FemDemSettings(l_c=0.0, mu_c=1e3).check()


def test_bad_packing_files_via_the_api(tmp_path):
    for path, pattern in ((text_as_npz(tmp_path), "cannot read packing file"),
                          (foreign_npz(tmp_path), "not a demcell packing")):
        with pytest.raises(ValueError, match=pattern):
            FemDemSettings(cell=CellOptions(packing=str(path))).check()


@pytest.mark.parametrize("name", ["degree_u", "degree_phi"])
def test_settings_check_names_the_degrees(name):
    with pytest.raises(ValueError, match=name):
        FemDemSettings(**{name: 0}).check()


def test_parse_mesh():
    assert parse_mesh("2x4") == (2, 4) and parse_mesh("1X1") == (1, 1)
    for text in ("2by4", "0x4", "x", "2x", "1x2x3", "-1x2", ""):
        with pytest.raises(ValueError, match="--mesh"):
            parse_mesh(text)


def test_bad_settings_refused_before_any_cell():
    """FemDemBiaxial runs the check first: a bad setting costs no cell preparation."""
    from mpi4py import MPI
    from cosserat_fenicsx.scenes.femdem_biaxial import FemDemBiaxial
    start = time.perf_counter()
    with pytest.raises(ValueError, match="kn"):
        FemDemBiaxial(MPI.COMM_WORLD, FemDemSettings(nx=1, ny=1, cell=CellOptions(kn=-1.0)), verbose=False)
    assert time.perf_counter() - start < 1.0
