"""The frame cell (demcell.frame): paper 000's frame of boundary particles held by a servo
(eqs 33-37), against the periodic DemCell of the same discs (which imposes the same
periodicity exactly) and against finite differences."""
import numpy as np
import pytest

import demcell as dc
from demcell.frame import FrameCell, FrameOptions, cut_frame

LAW = dc.ContactLaw(kn=1e4, ks=2e3, friction=0.4)
TIGHT = dc.RelaxationOptions(criterion="force", tol=1e-9, max_steps=10 ** 6)


def lattice_cell(law=LAW):
    """A 6 x 6 hexagonal lattice relaxed in the periodic cell (an exact equilibrium)."""
    cell = dc.DemCell(dc.hexagonal_lattice(6, 6, overlap=1e-3), law, TIGHT)
    assert cell.solve().converged
    return cell


def displaced_frame_state(cell, shift=1e-5):
    """The lattice with one frame disc (an edge pair once cut) moved by `shift` [m] in x: the
    frame cell made from it starts with that pair displaced, by half a contact overlap."""
    state = cell.state.copy()
    frame = cut_frame(state)
    pair = next(g for g in frame.groups if len(g) == 2)
    disc = frame.uid[pair[0]]
    state.s[disc] += np.linalg.solve(state.h, [shift, 0.3 * shift])
    return state


def test_servo_residual_falls_monotonically_to_eps_a_from_a_displaced_pair():
    """000's fixed-gain servo (no acceleration, beta 0.5): with the sign Delta u = -g Delta a
    (dns-spec B2) every iteration lowers r_a until eps_a (1.6 -> 0.02 in about 50
    iterations: the smooth modes of the frame go slowly); with the sign as printed the first
    correction would double the residual."""
    cell = lattice_cell()
    frame = FrameCell(displaced_frame_state(cell), LAW,
                      FrameOptions(relaxation=TIGHT, acceleration="none", eps_a=2e-2, max_iterations=100))
    result = frame.solve()
    r = np.array(frame.last_servo.residuals)
    assert result.converged, result.message
    assert r[0] > 1.0 and r[-1] <= 2e-2
    assert len(r) > 3 and np.all(np.diff(r) < 0.0), r


def test_lattice_frame_forces_are_antiperiodic_and_the_stress_is_the_periodic_cells():
    """A displaced pair of the lattice relaxed back by the servo: the reactions of every edge
    pair cancel (eq. 13) and the stress (eq. 14, 16) is that of the periodic lattice to 1e-6,
    at F = I under pressure and after a small imposed strain."""
    cell = lattice_cell()
    frame = FrameCell(displaced_frame_state(cell), LAW, FrameOptions(relaxation=TIGHT, eps_a=1e-8, max_iterations=300))
    assert frame.solve().converged
    assert frame.last_servo.anti_periodicity < 1e-7
    sigma = cell.cauchy_stress()
    assert np.abs(frame.cauchy_stress() - sigma).max() <= 1e-6 * np.abs(sigma).max()
    F = np.array([[1.0 - 2e-4, 1e-4], [1e-4, 1.0 + 0.5e-4]])
    cell.set_deformation(F)
    assert cell.solve().converged
    frame.set_deformation(F)
    assert frame.solve().converged
    sigma = cell.cauchy_stress()
    assert np.abs(frame.cauchy_stress() - sigma).max() <= 1e-6 * np.abs(sigma).max()
    # the other outputs come from the periodic view: the same contacts, fabric, coordination
    hf, hp = frame.homogenized(), cell.homogenized()
    assert hf.n_contacts == hp.n_contacts and hf.coordination_number == pytest.approx(hp.coordination_number)
    assert np.allclose(hf.fabric, hp.fabric, atol=1e-12)


@pytest.fixture(scope="module")
def random_reference():
    state, _ = dc.generate_packing(80, pressure=10.0, law=LAW, seed=3)
    return dc.reference_cell(state, LAW, dc.RelaxationOptions(criterion="force", tol=1e-6), 10.0)


def test_random_packing_frame_and_periodic_agree(random_reference):
    """80 discs, two biaxial increments of 0.1 %: the frame cell's stress is the periodic
    cell's within 2 % of |sigma| (measured 0.1-0.8 %: the two loading paths differ, the
    boundary-driven one of the frame against the affine one of the periodic cell, and
    contacts open and close on the way; at 1e-6 strain with no sliding the increments agree
    to 1e-5, docs/results/frame_cell.md)."""
    per = random_reference.copy()
    frame = FrameCell(per.state.copy(), LAW, FrameOptions(relaxation=dc.RelaxationOptions(criterion="force",
                                                                                          tol=1e-4), eps_a=1e-3))
    assert np.abs(frame.cauchy_stress() - per.cauchy_stress()).max() < 1e-3 * 10.0
    for k in (1, 2):
        F = np.diag([1.0 - 1e-3 * k, 1.0 + 3e-4 * k])
        per.set_deformation(F)
        per.solve()
        per.commit()
        frame.set_deformation(F)
        result = frame.solve()
        frame.commit()
        assert result.converged, result.message
        sigma = per.cauchy_stress()
        assert np.abs(frame.cauchy_stress() - sigma).max() < 2e-2 * np.abs(sigma).max()
        # eq. 14 from the frame's reactions and the contact sum of the periodic view agree
        view = dc.homogenize(frame.periodic_view(), LAW).cauchy
        assert np.abs(view - frame.cauchy_stress()).max() < 2e-3 * np.abs(sigma).max()


def test_tangents_against_finite_differences(random_reference):
    """Frozen-friction packing: the frame cell's perturbation tangent (finite differences of
    its own solves) against PSTLO of its periodic view, and Kruyt's operator equal to the
    periodic cell's of the same contacts."""
    law = LAW.with_(friction=np.inf)
    per = dc.DemCell(random_reference.state.copy(), law, TIGHT)
    per.solve()
    frame = FrameCell(per.state.copy(), law, FrameOptions(relaxation=TIGHT, eps_a=1e-6, max_iterations=500))
    assert frame.solve().converged
    frame.commit()
    K_f, K_p = frame.tangent("kruyt"), per.tangent("kruyt")
    assert np.abs(K_f - K_p).max() < 1e-9 * np.abs(K_p).max()
    C_fd = frame.tangent("perturbation", eps=1e-6)
    C_pstlo = frame.tangent("pstlo")
    assert frame.last_tangent_steps == 0
    # (the symmetric part: the antisymmetric columns are a rigid rotation of the held frame)
    sym = np.array([[1, 0, 0, 0], [0, .5, .5, 0], [0, .5, .5, 0], [0, 0, 0, 1]])
    err = np.abs((C_fd - C_pstlo) @ sym).max() / np.abs(C_pstlo @ sym).max()
    assert err < 2e-2, err
    with pytest.raises(dc.InputError, match="not built for a frame cell"):
        frame.tangent("demqo")


def test_bad_input_is_refused_in_one_line():
    cell = lattice_cell()
    for bad in (0.0, -1.0):
        with pytest.raises(dc.InputError, match="thickness"):
            FrameOptions(thickness=bad)
    with pytest.raises(dc.InputError, match="band"):
        FrameCell(cell.state.copy(), LAW, FrameOptions(thickness=6.0))
    small = dc.hexagonal_lattice(3, 4, overlap=1e-3)     # 3 columns: all in a 2.9-diameter frame
    with pytest.raises(dc.InputError, match="no inner disc") as info:
        FrameCell(small, LAW, FrameOptions(thickness=2.9))
    assert "\n" not in str(info.value)
    frame = FrameCell(cell.state.copy(), LAW)
    with pytest.raises(dc.InputError, match="micro-rotation"):
        frame.set_deformation(np.eye(2), rotation=0.1)
    with pytest.raises(dc.InputError, match="det F"):
        frame.set_deformation(np.diag([1.0, -1.0]))


@pytest.mark.serial
def test_dem_cell_demo_runs_with_a_frame(demo, tmp_path):
    """demos/dem_cell.py --micro-bc frame: a tiny biaxial run, micro_bc in summary.json."""
    import json
    demo("dem_cell", "--particles", 50, "--axial-strain", 0.002, "--increment", 0.001, "--micro-bc", "frame",
         "--relaxation-tol", 1e-3, "--frame-tol", 2e-2, "--out", tmp_path)
    summary = json.load(open(tmp_path / "summary.json"))
    assert summary["micro_bc"] == "frame" and summary["frame"]["frame_discs"] > 4
    data = np.genfromtxt(tmp_path / "history.csv", delimiter=",", names=True)
    assert len(data) == 3 and np.all(np.isfinite(data["stress_ratio"])) and data["stress_ratio"][-1] > 0.1
    refused = demo("dem_cell", "--micro-bc", "frame", "--test", "shear", "--out", tmp_path / "x", check=False)
    assert refused.returncode != 0 and "--micro-bc frame is for --test biaxial" in refused.stderr


@pytest.mark.serial
def test_femdem_biaxial_runs_with_frame_cells(demo, tmp_path):
    """demos/femdem_biaxial.py --micro-bc frame: one compression step of a 1x1 mesh of frame
    cells (one at a time: batched cells are the default of periodic cells only); micropolar mode
    and GPU cells are refused in one line."""
    import json
    demo("femdem_biaxial", "--mesh", "1x1", "--particles", 50, "--axial-strain", 0.001, "--steps", 1,
         "--micro-bc", "frame", "--mode", "classical", "--relaxation-tol", 1e-3, "--frame-tol", 2e-2,
         "--out", tmp_path)
    summary = json.load(open(tmp_path / "summary.json"))
    assert summary["micro_bc"] == "frame" and summary["completed"] and summary["peak_stress_ratio"] > 0.05
    for extra, words in ((("--mode", "micropolar"), "mode micropolar"), (("--cell-device", "gpu"), "cell_device gpu")):
        refused = demo("femdem_biaxial", "--micro-bc", "frame", *extra, "--out", tmp_path / "x", check=False)
        assert refused.returncode != 0 and words in refused.stderr + refused.stdout
        assert "micro_bc 'frame' cannot be used" in refused.stderr + refused.stdout
