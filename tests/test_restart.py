"""Checkpoint and restart as a batch queue uses them (docs/reference/restart.md): a run stopped with
--stop-after K (or killed after its last --checkpoint-every checkpoint) and continued with
--restart DIR writes the history and the fields of the uninterrupted run, bit for bit on one
rank; a checkpoint written on 1 rank continues on 2 and the reverse. Bad restarts are refused
before any work, in one line.

The reference is the same demo run straight through: the restarted run has to reproduce every
written digit of it (history.csv without the wall time, gauss_points.csv, every dataset of
fields.h5), which a restart that lost any part of the state (a cell's contact history, the
committed Gauss-point arrays, the tangents, the stepper's next increment, the flags of which
points changed) would not."""
import json
import os

import h5py
import numpy as np
import pytest

from conftest import read_summary

pytestmark = pytest.mark.serial

BIAXIAL = ("--cell-size", 1e-2, "--steps", 6, "--consolidation-steps", 2, "--write-every", 1)
FEMDEM = ("--mesh", "1x2", "--particles", 40, "--axial-strain", 0.01, "--steps", 5,
          "--weak-size", 2.5e-3, "--weak-friction", 0.8)


def csv_rows(path, drop=("wall_time",)):
    """The rows of a CSV file as strings, without the columns in `drop` (timings)."""
    lines = path.read_text().splitlines()
    header = lines[0].split(",")
    keep = [i for i, name in enumerate(header) if name not in drop]
    return [[row.split(",")[i] for i in keep] for row in lines]


def h5_datasets(path):
    out = {}
    with h5py.File(path, "r") as f:
        f.visititems(lambda name, obj: out.__setitem__(name, obj[()]) if isinstance(obj, h5py.Dataset) else None)
    return out


def assert_same_output(a, b, files=("history.csv",)):
    for name in files:
        assert csv_rows(a / name) == csv_rows(b / name), name
    da, db = h5_datasets(a / "fields.h5"), h5_datasets(b / "fields.h5")
    assert sorted(da) == sorted(db)
    for name in da:
        assert np.array_equal(da[name], db[name]), name


def test_biaxial_stop_and_restart_is_bit_identical(demo, tmp_path):
    """Ehlers biaxial: --stop-after 4 then --restart gives the straight run's outputs."""
    demo("biaxial", *BIAXIAL, "--out", tmp_path / "straight")
    part = tmp_path / "part"
    demo("biaxial", *BIAXIAL, "--out", part, "--stop-after", 4)
    first = read_summary(part)
    assert not first["completed"] and "--restart" in first["reason"] and first["steps"] == 4
    assert first["checkpoint_steps_written"] == [4]
    proc = demo("biaxial", "--restart", part)
    assert "continuing from the checkpoint of step 4" in proc.stdout
    summary = read_summary(part)
    assert summary["completed"] and summary["restarted_from_step"] == 4 and summary["steps"] == 8
    assert_same_output(tmp_path / "straight", part)
    straight = read_summary(tmp_path / "straight")
    assert summary["peak_vertical_stress"] == straight["peak_vertical_stress"]


def test_femdem_restart_after_a_kill_is_bit_identical(demo, tmp_path):
    """FEM x DEM: a run that went on past its last checkpoint (step 4 of 6, as a run killed
    after step 6 would leave it) restarts from step 4: the later rows and XDMF steps are dropped
    and recomputed, every cell continues from its saved contact state."""
    demo("femdem_biaxial", *FEMDEM, "--out", tmp_path / "straight")
    part = tmp_path / "part"
    demo("femdem_biaxial", *FEMDEM, "--out", part, "--checkpoint-every", 4)
    meta = json.loads((part / "checkpoint" / "meta.json").read_text())
    assert meta["step"] == 4 and meta["ranks"] == 1
    demo("femdem_biaxial", "--restart", part)
    assert read_summary(part)["restarted_from_step"] == 4
    assert_same_output(tmp_path / "straight", part, files=("history.csv", "gauss_points.csv"))
    # the comparison sees the cells: the same restart with the cells' tangential contact forces
    # (their friction history) zeroed in the checkpoint does not reproduce the straight run
    tampered = tmp_path / "tampered"
    demo("femdem_biaxial", *FEMDEM, "--out", tampered, "--stop-after", 4)
    path = tampered / "checkpoint" / "resident_0.npz"
    with np.load(path) as z:
        arrays = dict(z)
    arrays["fs"][:] = 0.0
    np.savez(path, **arrays)
    demo("femdem_biaxial", "--restart", tampered)
    assert csv_rows(tampered / "history.csv")[:5] == csv_rows(part / "history.csv")[:5]    # header + 4 steps
    assert csv_rows(tampered / "history.csv")[5:] != csv_rows(part / "history.csv")[5:]


@pytest.mark.parametrize("ranks_before,ranks_after", [(1, 2), pytest.param(2, 1, marks=pytest.mark.slow)])
def test_femdem_checkpoint_moves_between_rank_counts(demo, tmp_path, ranks_before, ranks_after):
    """A checkpoint written on 1 rank continues on 2 and the reverse. The partition changes
    the assembly order, which the cells amplify up to their relaxation tolerance: the bound is
    the one of the 1-against-2-ranks test (tests/test_femdem.py): 2 x 1e-3 of the stress ratio and
    of the largest platen stress, before the peak (past it the cells amplify more: measured 2.1e-3
    of the platen stress at 1 % axial strain)."""
    args = FEMDEM[:4] + ("--axial-strain", 0.004) + FEMDEM[6:]     # before the peak, as that test
    demo("femdem_biaxial", *args, "--out", tmp_path / "straight", ranks=ranks_before)
    part = tmp_path / "part"
    demo("femdem_biaxial", *args, "--out", part, "--stop-after", 3, ranks=ranks_before)
    demo("femdem_biaxial", "--restart", part, ranks=ranks_after)
    summary = read_summary(part)
    assert summary["completed"] and summary["ranks"] == ranks_after
    assert summary["restarted_from_ranks"] == ranks_before
    # the XDMF of the first part holds the nodes in the old partition's order: a new series
    assert (part / "fields_from_step3.xdmf").exists()
    a = np.genfromtxt(tmp_path / "straight" / "history.csv", delimiter=",", names=True)
    b = np.genfromtxt(part / "history.csv", delimiter=",", names=True)
    assert len(a) == len(b) == 6
    assert np.array_equal(a["stress_ratio"][:3], b["stress_ratio"][:3])     # the rows before are kept
    assert np.allclose(a["stress_ratio"], b["stress_ratio"], rtol=0, atol=2e-3)
    assert np.allclose(a["vertical_stress"], b["vertical_stress"], rtol=0, atol=2e-3 * np.abs(a["vertical_stress"]).max())


def test_balanced_run_restarts_bit_for_bit_on_two_ranks(demo, tmp_path):
    """With load balancing (cells worked on away from their home rank, cosserat_fenicsx/balancing) a
    checkpoint fetches every cell from its worker and a restart puts it back home: on 2 ranks
    (the Newton solver's redundant LU by default: the same bits whatever the load,
    tests/test_reproducible.py) the stopped and restarted run is the straight one to every
    digit."""
    # DEM steps as the cost: the same moves in every run; the weak cells (friction x 0.1) slide
    # and cost 1.6 times the others' DEM steps at step 2, so cells move whatever the CPU's
    # round-off (with friction x 0.5 the ranks' work differed by less than one cell's on some CPUs)
    args = ("--mesh", "2x2", "--particles", 40, "--axial-strain", 0.0075, "--steps", 5, "--weak-size", 5e-3,
            "--weak-friction", 0.1, "--balance", "--balance-threshold", 1.0, "--balance-cost", "work")
    demo("femdem_biaxial", *args, "--out", tmp_path / "straight", ranks=2)
    part = tmp_path / "part"
    demo("femdem_biaxial", *args, "--out", part, "--stop-after", 4, ranks=2)
    assert read_summary(part)["balance"]["moves_total"] > 0          # cells had moved when it was saved
    demo("femdem_biaxial", "--restart", part, ranks=2)
    assert_same_output(tmp_path / "straight", part, files=("history.csv", "gauss_points.csv"))


def test_femdem_restart_may_change_the_newton_rule(demo, tmp_path):
    """A run that stalls is continued with another Newton rule (--tangent, --accept-rtol, ...
    the demo's solver options): the restart takes them, the material runs with them, and
    summary.json and the log say what changed; what is solved (--mesh) still cannot change."""
    part = tmp_path / "part"
    demo("femdem_biaxial", *FEMDEM, "--out", part, "--stop-after", 2)
    proc = demo("femdem_biaxial", "--restart", part, "--mesh", "2x4", check=False)
    assert proc.returncode == 2 and "--mesh cannot be given with --restart" in proc.stderr
    assert "--tangent" in proc.stderr                    # the message lists what may change
    proc = demo("femdem_biaxial", "--restart", part, "--tangent", "pstlo_sliding", "--accept-rtol", 0.05,
                "--checkpoint-every", 1)
    assert "--tangent pstlo -> pstlo_sliding" in proc.stdout
    summary = read_summary(part)
    assert summary["completed"] and summary["restarted_from_step"] == 2
    assert summary["changed_at_restart"] == {"accept_rtol": [0.03, 0.05], "tangent": ["pstlo", "pstlo_sliding"]}
    assert summary["mode"]["tangent"] == "pstlo_sliding" and summary["options"]["accept_rtol"] == 0.05
    # and the checkpoint it leaves carries the new rule on
    meta = json.loads((part / "checkpoint" / "meta.json").read_text())
    assert meta["options"]["tangent"] == "pstlo_sliding"


def test_bad_restarts_are_refused_before_any_work(demo, tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    proc = demo("biaxial", "--restart", empty, check=False)
    assert proc.returncode == 2 and "no checkpoint" in proc.stderr and "--checkpoint-every" in proc.stderr
    part = tmp_path / "part"
    demo("biaxial", *BIAXIAL, "--out", part, "--stop-after", 2)
    proc = demo("biaxial", "--restart", part, "--cell-size", 5e-3, check=False)
    assert proc.returncode == 2 and "--cell-size cannot be given with --restart" in proc.stderr
    proc = demo("femdem_biaxial", "--restart", part, check=False)
    assert proc.returncode == 2 and "'biaxial', not 'femdem_biaxial'" in proc.stderr
    proc = demo("biaxial", "--restart", part, "--stop-after", 2, check=False)
    assert proc.returncode == 2 and "at step 2 already" in proc.stderr
    # a damaged checkpoint: refused in one line before any work, the earlier outputs as they were
    before = {name: (part / name).read_bytes() for name in ("summary.json", "history.csv")}
    os.remove(part / "checkpoint" / "points.npz")
    proc = demo("biaxial", "--restart", part, check=False, ranks=2)
    ours = [line for line in proc.stderr.splitlines() if "biaxial.py: error:" in line]    # mpirun adds its own
    assert proc.returncode == 2 and len(ours) == 1 and "points.npz" in ours[0]
    assert "Traceback" not in proc.stderr
    assert before == {name: (part / name).read_bytes() for name in before}


def test_pack_states_round_trip_continues_bit_for_bit():
    """demcell.state.pack_states / unpack_states (the checkpoint's and the load balancer's
    format) keep every array, pair capacities included: a restored cell relaxes to the same
    state and tangent as the original."""
    import demcell as dc
    from demcell.state import pack_states, unpack_states
    law = dc.ContactLaw(kn=1e4, ks=2e3, friction=0.4)
    st, _ = dc.generate_packing(40, pressure=10.0, law=law, seed=1)
    ref = dc.reference_cell(st, law, dc.RelaxationOptions(tol=1e-3), 10.0)
    cells = [ref.copy() for _ in range(3)]
    for k, c in enumerate(cells):
        c.set_deformation(np.array([[1.0 + 1e-3 * k, 2e-3], [0.0, 0.996]]))
        c.solve()
        c.commit()
    packed = pack_states(c.committed_state for c in cells)
    restored = [ref.copy() for _ in range(2)]
    for c, st in zip(restored, unpack_states(packed, rows=[2, 0])):
        c.restore(st)
    for original, copy in ((cells[2], restored[0]), (cells[0], restored[1])):
        for c in (original, copy):
            c.rollback()
            c.set_deformation(np.array([[1.004, 3e-3], [1e-3, 0.99]]))
            c.solve()
        assert np.array_equal(original.state.s, copy.state.s)
        assert np.array_equal(original.cauchy_stress(), copy.cauchy_stress())
        assert np.array_equal(original.tangent("demqo"), copy.tangent("demqo"))
    with pytest.raises(dc.InputError):
        restored[0].restore(dc.generate_packing(20, pressure=10.0, law=law, seed=0)[0])
