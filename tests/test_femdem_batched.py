"""FEM x DEM with batched cells (the default, --batched: materials/dem/stores.BatchedCells over
demcell.batch) against the per-cell material (--no-batched): every written number of the run is the same bit for bit (history but
its wall times, Gauss-point table, every XDMF dataset), with one or two Numba threads, in the
three modes, with the batched Kruyt tangent, through failing cells, and on 2 ranks balanced."""
import csv
import json

import h5py
import numpy as np
import pytest

pytestmark = pytest.mark.serial

CELL = ("--particles", 60, "--criterion", "force")


def same_outputs(a, b):
    """Every output of two runs equal (wall and CPU times excepted); returns the rows compared."""
    rows = 0
    for name in ("history.csv", "gauss_points.csv"):
        ra, rb = list(csv.DictReader(open(a / name))), list(csv.DictReader(open(b / name)))
        assert len(ra) == len(rb), name
        for x, y in zip(ra, rb):
            for key in x:
                if "wall" not in key and "cpu" not in key:
                    assert x[key] == y[key], (name, key, x[key], y[key])
        rows += len(ra)
    with h5py.File(a / "fields.h5") as fa, h5py.File(b / "fields.h5") as fb:
        names = []
        fa.visititems(lambda n, o: names.append(n) if isinstance(o, h5py.Dataset) else None)
        assert names
        for n in names:
            assert np.array_equal(fa[n][()], fb[n][()]), n
    return rows


# the hybrid/pstlo, micropolar and DEMQO cases are slow (17 s, 21 s and 55 s): their batch paths
# are checked cell by cell in test_demcell_batch.py (test_batch_equals_cells' pstlo tangent,
# test_batch_micropolar_and_capacity, test_batch_demqo_equals_the_cells); make test keeps the
# classical/Kruyt run
@pytest.mark.parametrize("mode, tangent", [pytest.param("hybrid", "pstlo", marks=pytest.mark.slow),
                                           ("classical", "kruyt"),
                                           pytest.param("micropolar", "pstlo", marks=pytest.mark.slow),
                                           pytest.param("hybrid", "demqo", marks=pytest.mark.slow)])
def test_batched_run_is_the_per_cell_run(demo, tmp_path, mode, tangent):
    args = (*CELL, "--mode", mode, "--tangent", tangent, "--mesh", "2x2", "--axial-strain", 0.006, "--steps", 3,
            "--weak-size", 0.005, "--weak-friction", 0.5)
    demo("femdem_biaxial", *args, "--no-batched", "--out", tmp_path / "cells")
    demo("femdem_biaxial", *args, "--batched", "--out", tmp_path / "batched")
    assert same_outputs(tmp_path / "cells", tmp_path / "batched") > 10
    if mode == "hybrid":
        demo("femdem_biaxial", *args, "--batched", "--cell-threads", 2, "--out", tmp_path / "threads")
        same_outputs(tmp_path / "cells", tmp_path / "threads")


def test_batched_failures_cut_the_step_as_per_cell(demo, tmp_path):
    """Cells out of their step budget: the same statuses, message, cuts and end of run."""
    args = (*CELL, "--mesh", "1x2", "--axial-strain", 0.02, "--steps", 2, "--max-dem-steps", 300)
    a = demo("femdem_biaxial", *args, "--no-batched", "--out", tmp_path / "cells", check=False)
    b = demo("femdem_biaxial", *args, "--batched", "--out", tmp_path / "batched", check=False)
    assert a.returncode == b.returncode
    text = a.stdout + a.stderr
    assert "did not relax within its step budget" in text
    same_lines = [line for line in text.splitlines() if "step budget" in line]
    assert same_lines and all(line in b.stdout + b.stderr for line in same_lines)
    same_outputs(tmp_path / "cells", tmp_path / "batched")


def test_batched_and_balanced_on_two_ranks(demo, tmp_path):
    """2 ranks, the balancer moving batched cells (export/import through the store): the
    per-cell unbalanced run's bits (redundant LU: MUMPS on 2 processes is not reproducible)."""
    args = (*CELL, "--mesh", "2x2", "--axial-strain", 0.006, "--steps", 3, "--weak-size", 0.005,
            "--weak-friction", 0.5, "-pc_type", "redundant")
    demo("femdem_biaxial", *args, "--no-batched", "--out", tmp_path / "cells", ranks=2)
    demo("femdem_biaxial", *args, "--batched", "--balance", "--balance-threshold", 1.0, "--balance-cost", "work",
         "--out", tmp_path / "balanced", ranks=2)
    same_outputs(tmp_path / "cells", tmp_path / "balanced")
    assert json.loads((tmp_path / "balanced" / "summary.json").read_text())["balance"]["moves_total"] > 0


def test_cell_options_reach_both_paths(demo, tmp_path):
    """--cell-option (demcell.RelaxationOptions of the cells) reaches the per-cell and the
    batched solve alike: local damping (not the default FIRE) with a larger time step gives the
    same bits in both, and other numbers than the default relaxation (so the option was not
    dropped on the way)."""
    args = (*CELL, "--mesh", "2x2", "--axial-strain", 0.004, "--steps", 2)
    local = ("--cell-option", "method=local", "--cell-option", "dt_safety=0.5")
    demo("femdem_biaxial", *args, *local, "--no-batched", "--out", tmp_path / "cells")
    demo("femdem_biaxial", *args, *local, "--batched", "--out", tmp_path / "batched")
    same_outputs(tmp_path / "cells", tmp_path / "batched")
    demo("femdem_biaxial", *args, "--batched", "--out", tmp_path / "default")
    with pytest.raises(AssertionError):
        same_outputs(tmp_path / "cells", tmp_path / "default")
