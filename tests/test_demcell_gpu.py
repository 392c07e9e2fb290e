"""demcell.gpu.DeviceCellBatch against demcell.batch.CellBatch, in Numba's CUDA simulator
(NUMBA_ENABLE_CUDASIM=1, set by conftest.py; no GPU needed): the same cells solved on the
"device" must give every bit of every state array, result row, homogenised output and Kruyt
operator of the CPU batch, for fixed steps, full solves and solves stopped by relax_cap, through sub-steps, neighbour
rebuilds, the growth of full pair slots, lattice reduction, commit and rollback, in the
three rotation modes of FEM x DEM cells (free, locked, micropolar), with FIRE and with the
general contact law (rolling resistance, dashpots, bonds), and for DEMQO's frozen copies.
On a GPU the same kernels agree to round-off only (fused multiply-adds): benchmarks/dem/gpu_cells.py
checks that there."""
import os
import subprocess
import sys

import numpy as np
import pytest
from numba import config

import demcell as dc
from demcell.batch import CellBatch
from demcell.state import PAIR_FIELDS, PARTICLE_FIELDS
from demcell import slots

pytestmark = [pytest.mark.serial,
              pytest.mark.skipif(not config.ENABLE_CUDASIM, reason="bit for bit in Numba's CUDA simulator only "
                                 "(NUMBA_ENABLE_CUDASIM=1); on a GPU run benchmarks/dem/gpu_cells.py")]

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
THREADS = 4          # threads per cell in the simulator (a GPU runs 128); one test takes 33


@pytest.fixture(scope="module")
def packing():
    state, _ = dc.generate_packing(24, pressure=10.0, law=dc.ContactLaw(kn=1e4, ks=2e3, friction=0.4), seed=5)
    return state


def make_cells(packing, mode="free", n=2, law=None, **options):
    """n cells of one packing, cells 1.. pre-loaded to different committed states. options:
    RelaxationOptions (a fast ramp by default: the simulator runs a few hundred steps a
    second)."""
    law = law or dc.ContactLaw(kn=1e4, ks=2e3, friction=0.4, rotations=mode != "locked")
    kw = dict(tol=1e-3, criterion="force", strain_rate=1e-4, check_every=10)
    kw.update(options)
    opts = dc.RelaxationOptions(**kw)
    st = packing.copy()
    ref = dc.DemCell(st, law, opts, rotation_mode="micropolar" if mode == "micropolar" else None)
    cells = [ref.copy() for _ in range(n)]
    for k, cell in enumerate(cells[1:], start=1):
        e = 1e-3 * k
        cell.set_deformation(np.array([[1 + 0.5 * e, 0.0], [0.0, 1 - e]]))
        cell.solve()
        cell.commit()
    return cells


def both(cells, threads=THREADS):
    from demcell.gpu.batch import DeviceCellBatch
    return CellBatch([c.copy() for c in cells]), DeviceCellBatch([c.copy() for c in cells], threads=threads)


def same_state(a, b, what=""):
    assert a.n_pairs == b.n_pairs and a.forces_current == b.forces_current, what
    assert a.time == b.time and a.phi == b.phi and np.array_equal(a.kappa, b.kappa), what
    for name in PARTICLE_FIELDS + ("h", "h_build", "h_ref"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), f"{what} {name}"
    for name in PAIR_FIELDS:
        assert np.array_equal(getattr(a, name)[:a.n_pairs], getattr(b, name)[:b.n_pairs]), f"{what} {name}"


def same_cells(cpu, gpu, rows):
    """Current and committed states, homogenised outputs and Kruyt operators bit for bit."""
    for k in rows:
        same_state(cpu.state(k), gpu.state(k), f"cell {k} current")
    for k, (a, b) in enumerate(zip(cpu.committed_states(rows), gpu.committed_states(rows))):
        same_state(a, b, f"cell {k} committed")
    h1, h2 = cpu.homogenize(rows), gpu.homogenize(rows)
    for key in h1:
        assert np.array_equal(h1[key], h2[key]), key
    assert np.array_equal(cpu.kruyt(rows), gpu.kruyt(rows))
    assert np.array_equal(cpu.contact_counts(rows), gpu.contact_counts(rows))
    assert np.array_equal(cpu.deformation_gradients(rows), gpu.deformation_gradients(rows))


def targets(n, size):
    out = []
    for k in range(n):
        e = size * (1 + 0.3 * k)
        out.append(np.array([[1 + 0.5 * e, 0.2 * e], [0.1 * e, 1 - e]]))
    return np.array(out)


def micro_targets(cells, size):
    """(phi, kappa) of micropolar targets: a turn and a curvature per cell."""
    n = len(cells)
    scale = float(np.abs(cells[0].state.h_ref).max())
    phi = size * np.linspace(0.5, -0.5, n)
    kappa = size * np.column_stack([np.linspace(1.0, -2.0, n), np.linspace(-1.0, 1.5, n)]) / scale
    return phi, kappa


def solve_both(cpu, gpu, rows, F, phi=None, kappa=None, max_steps=None):
    for b in (cpu, gpu):
        b.rollback(rows)
        b.set_targets(rows, F, phi, kappa)
    r1, r2 = cpu.solve(rows, max_steps=max_steps), gpu.solve(rows, max_steps=max_steps)
    assert np.array_equal(r1, r2)
    return r1


@pytest.mark.parametrize("mode", ["free", "locked", "micropolar"])
def test_fixed_steps_in_each_rotation_mode(packing, mode):
    """A step budget that stops every cell before it relaxes: the ramp, the force loop and
    the leapfrog of each rotation mode, step for step."""
    cells = make_cells(packing, mode)
    cpu, gpu = both(cells)
    rows = np.arange(len(cells))
    phi, kappa = micro_targets(cells, 2e-3) if mode == "micropolar" else (None, None)
    res = solve_both(cpu, gpu, rows, targets(len(cells), 2e-3), phi, kappa, max_steps=15)
    assert (res[:, slots.R_CONVERGED] == 0).all()
    same_cells(cpu, gpu, rows)
    for k in rows:
        assert cpu.outcome(k, res[k]) == gpu.outcome(k, res[k])


def test_relax_cap_through_substeps(packing):
    """Relaxations stopped by relax_cap count as converged and the next sub-step follows, on
    the device as on the CPU (R_CAPPED included)."""
    cells = make_cells(packing, "free", method="fire", relax_cap=20)
    cpu, gpu = both(cells)
    rows = np.arange(len(cells))
    res = solve_both(cpu, gpu, rows, targets(len(cells), 1.2e-2))        # two sub-steps (max_increment 0.01)
    assert (res[:, slots.R_CONVERGED] == 1).all() and (res[:, slots.R_SUBSTEPS] >= 2).all()
    assert (res[:, slots.R_CAPPED] >= 1).all()
    same_cells(cpu, gpu, rows)


def test_full_solves_substeps_growth_commit_rollback(packing):
    """FIRE cells through two sub-steps, neighbour rebuilds, pair slots cut to their content (the first
    rebuild overflows them: the device grows them and the cells go on), then commit of
    one cell, a second solve and a rollback."""
    cells = make_cells(packing, "free", n=2, method="fire")
    for cell in cells:
        st = cell.committed_state
        for name in PAIR_FIELDS:
            setattr(st, name, getattr(st, name)[:st.n_pairs].copy())
        cell.rollback()
    cpu, gpu = both(cells)
    cap0 = gpu.capacity.copy()
    rows = np.arange(2)
    res = solve_both(cpu, gpu, rows, targets(2, 1.2e-2))         # max_increment 0.01
    assert (res[:, slots.R_SUBSTEPS] >= 2).all() and (res[:, slots.R_CONVERGED] == 1).all()
    assert (res[:, slots.R_REBUILDS] > 0).all() and (gpu.capacity > cap0).any()
    assert np.array_equal(gpu.capacity, cpu.capacity)
    same_cells(cpu, gpu, rows)
    for b in (cpu, gpu):
        b.commit(rows[:1])
    solve_both(cpu, gpu, rows, targets(2, 3e-3))
    same_cells(cpu, gpu, rows)
    for b in (cpu, gpu):
        b.rollback(rows)
    same_cells(cpu, gpu, rows)


def test_micropolar_full_solve(packing):
    cells = make_cells(packing, "micropolar")
    cpu, gpu = both(cells)
    rows = np.arange(2)
    phi, kappa = micro_targets(cells, 4e-3)
    res = solve_both(cpu, gpu, rows, targets(2, 4e-3), phi, kappa)
    assert (res[:, slots.R_CONVERGED] == 1).all()
    same_cells(cpu, gpu, rows)


def test_fire_and_the_general_contact_law(packing):
    """FIRE (its sums in lanes.py's order, adaptive step) with rolling resistance, both
    dashpots and bonds on one cell: the general force loop."""
    law = dc.ContactLaw(kn=1e4, ks=2e3, friction=0.4, rolling_stiffness=0.05, rolling_friction=0.2,
                        normal_damping=0.1, tangential_damping=0.05, cohesion_normal=0.02, cohesion_shear=0.02)
    cells = make_cells(packing, "free", law=law, method="fire")
    cells[0].bond_contacts()
    cells[0].commit()
    cpu, gpu = both(cells, threads=33)        # more threads than lanes.LANES
    rows = np.arange(2)
    res = solve_both(cpu, gpu, rows, targets(2, 3e-3))
    assert (res[:, slots.R_STEPS] > 0).all()
    same_cells(cpu, gpu, rows)


def test_lattice_reduction(packing):
    cells = make_cells(packing, "free", n=2, max_increment=0.6, strain_rate=1e-2)
    cpu, gpu = both(cells)
    rows = np.arange(2)
    F = np.array([[[1.0, 0.6], [0.0, 1.0]], [[1.0, 0.0], [0.6, 1.0]]])
    solve_both(cpu, gpu, rows, F, max_steps=10)
    for b in (cpu, gpu):
        b.commit(rows)
    # the next sub-step starts from a shear of 0.6: its lattice is reduced first
    solve_both(cpu, gpu, rows, F * 1.05 - 0.05 * np.eye(2), max_steps=10)
    for k in rows:
        assert not np.allclose(gpu.state(k).h_ref, cells[k].state.h_ref)    # reduced
    same_cells(cpu, gpu, rows)


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["free", "micropolar"])
def test_demqo_on_the_device(packing, mode):
    """DEMQO's frozen copies (subset, frozen law, tight options) relaxed on the device."""
    cells = make_cells(packing, mode)
    cpu, gpu = both(cells)
    rows = np.arange(2)
    phi, kappa = micro_targets(cells, 2e-3) if mode == "micropolar" else (None, None)
    solve_both(cpu, gpu, rows, targets(2, 2e-3), phi, kappa)
    t1, s1 = cpu.demqo(rows)
    t2, s2 = gpu.demqo(rows)
    assert np.array_equal(s1, s2) and all(np.array_equal(a, b) for a, b in zip(t1, t2))


def test_states_in_and_out(packing):
    """set_cell / restore upload a state, views and committed_states download it, subset
    copies on the device: each the CPU batch's."""
    cells = make_cells(packing, "free", n=3)
    cpu, gpu = both(cells)
    rows = np.arange(3)
    solve_both(cpu, gpu, rows, targets(3, 1e-3), max_steps=5)
    st = cells[2].committed_state
    for b in (cpu, gpu):
        b.set_cell(0, cells[1], st)
    same_cells(cpu, gpu, rows)
    for a, b in zip(cpu.views(rows), gpu.views(rows)):
        same_state(a.state, b.state)
        assert np.array_equal(a.law_array, b.law_array) and a.dt == b.dt
    sub_c, sub_g = cpu.subset([2, 0, 2]), gpu.subset([2, 0, 2])
    same_cells(sub_c, sub_g, np.arange(3))
    assert gpu.nbytes() > 0


def test_every_thread_of_a_block_gets_the_one_shared_array():
    """The simulator creates a shared array when the first thread asks for it, without a
    lock; demcell.gpu.simulator.patch locks it. 16 threads released at once ask 500 times:
    unpatched, about 3 % of the blocks hand one thread a private copy (the garbage-index
    failures this once caused)."""
    import threading
    from numba.cuda.simulator import kernelapi
    from demcell.gpu import simulator
    simulator.patch()
    old = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)
    split = 0
    try:
        for _ in range(500):
            shared = kernelapi.FakeCUDAShared(0)
            got = []
            start = threading.Barrier(16)

            def ask():
                start.wait()
                got.append(id(shared.array(4, np.float64)))
            threads = [threading.Thread(target=ask) for _ in range(16)]
            for th in threads:
                th.start()
            for th in threads:
                th.join()
            split += len(set(got)) > 1
    finally:
        sys.setswitchinterval(old)
    assert split == 0


def test_refused_without_a_device():
    """Without a CUDA device (and without the simulator) the batch is refused in one line."""
    code = ("import demcell.gpu as g; r = g.available(); print(r)\n"
            "import sys; sys.exit(0 if r else 3)")
    env = dict(os.environ, NUMBA_ENABLE_CUDASIM="0", CUDA_VISIBLE_DEVICES="")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=ROOT,
                          timeout=120)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "CUDA" in proc.stdout and len(proc.stdout.strip().splitlines()) == 1


@pytest.mark.slow
def test_femdem_demo_with_gpu_cells(tmp_path):
    """demos/femdem_biaxial.py with --cell-device gpu (the simulator) writes the history and the
    per-point stress ratios of --batched CPU cells, byte for byte (the wall time aside)."""
    from conftest import run_demo
    common = ["--mesh", "1x1", "--particles", "16", "--steps", "2", "--axial-strain", "0.002", "--tangent", "kruyt",
              "--cell-option", "method=fire"]
    outs = {}
    for device in ("cpu", "gpu"):
        out = tmp_path / device
        run_demo("femdem_biaxial", *common, "--batched", "--cell-device", device, "--out", out)
        outs[device] = out
    def table(path, drop):
        with open(path) as f:
            return [",".join(v for k, v in enumerate(line.strip().split(",")) if k not in drop) for line in f]
    assert table(outs["cpu"] / "history.csv", {19}) == table(outs["gpu"] / "history.csv", {19})
    assert table(outs["cpu"] / "gauss_points.csv", set()) == table(outs["gpu"] / "gauss_points.csv", set())
    with open(outs["gpu"] / "summary.json") as f:
        assert "simulator" in f.read()


@pytest.mark.slow
def test_femdem_demo_on_two_ranks_with_restart(tmp_path):
    """On 2 ranks: GPU cells (the simulator) write the --batched CPU cells' outputs, also when the
    run stops after 2 steps with a checkpoint and continues (--restart), and a CPU run's
    checkpoint continued with --cell-device gpu."""
    from conftest import run_demo
    common = ["--mesh", "1x1", "--particles", "16", "--steps", "3", "--axial-strain", "0.003", "--tangent", "kruyt",
              "--cell-option", "method=fire"]
    cpu, gpu, switched = tmp_path / "cpu", tmp_path / "gpu", tmp_path / "switched"
    run_demo("femdem_biaxial", *common, "--batched", "--out", cpu, ranks=2)
    run_demo("femdem_biaxial", *common, "--cell-device", "gpu", "--checkpoint-every", "1", "--stop-after", "2",
             "--out", gpu, ranks=2)
    run_demo("femdem_biaxial", "--restart", gpu, ranks=2)
    run_demo("femdem_biaxial", *common, "--batched", "--checkpoint-every", "1", "--stop-after", "2", "--out", switched,
             ranks=2)
    run_demo("femdem_biaxial", "--restart", switched, "--cell-device", "gpu", ranks=2)

    def table(path, drop):
        with open(path) as f:
            return [",".join(v for k, v in enumerate(line.strip().split(",")) if k not in drop) for line in f]
    for run in (gpu, switched):
        assert table(cpu / "history.csv", {19}) == table(run / "history.csv", {19})
        assert table(cpu / "gauss_points.csv", set()) == table(run / "gauss_points.csv", set())
