"""FEM x DEM stiff and extreme cases end cleanly.

Every case either converges, cuts the step, or stops with a LoadSteppingError whose message
names the cause; no NaN reaches the outputs (fluxes, history rows, fields); and under MPI a
failure stops every rank together (a test that finishes under `mpirun -n 2` shows that no
rank was left waiting). Tiny problems: 1x1 meshes (6 Gauss points), 100-disc cells, 1-2
steps. The tests not marked serial run in the MPI pass too: every rank runs the same code,
and the asserted values are reduced or gathered over the ranks first.

Last, the demo's output opens in ParaView (serial, skipped without pvbatch / xvfb-run).
"""
import dataclasses
import json
import math
import shutil
import subprocess

import numpy as np
import pytest
from mpi4py import MPI

from cosserat_fenicsx import meshes
from cosserat_fenicsx.materials.dem import CellOptions, DemMaterial, make_mode, reference_cells
from cosserat_fenicsx.materials.dem.material import STATUS_BAD_F, STATUS_NO_CONTACTS
from cosserat_fenicsx.problem import CosseratProblem
from cosserat_fenicsx.quadrature import gauss_point_coordinates
from cosserat_fenicsx.newton_history import RecordingSolver
from cosserat_fenicsx.scenes.femdem_biaxial import FemDemBiaxial, FemDemSettings
from cosserat_fenicsx.snes import NewtonSolver
from cosserat_fenicsx.stepping import LoadStepper, LoadSteppingError

COMM = MPI.COMM_WORLD
W, H = 0.01, 0.02


# --- helpers (collective) ---------------------------------------------------------------

def everywhere(flag):
    """True when `flag` holds on every rank."""
    return COMM.allreduce(bool(flag), op=MPI.LAND)


def total(n):
    return COMM.allreduce(int(n))


def same_everywhere(value):
    """The value of rank 0, after checking every rank has the same."""
    values = COMM.allgather(value)
    assert all(v == values[0] for v in values), values
    return values[0]


def history_is_finite(history):
    return all(math.isfinite(float(v)) for row in history for v in row.values())


def assert_finite(test):
    """No NaN / inf in the fluxes, the committed history, the fields or the history rows."""
    cb = test.gauss_points
    assert everywhere(np.isfinite(cb.flux_values).all() and np.isfinite(cb.state_old).all()
                      and np.isfinite(test.problem.w.x.array).all()), "non-finite flux, state or field"
    assert everywhere(history_is_finite(test.history)), test.history


def run(settings, on_step=None):
    """Build and run one scene; returns (test, message of the LoadSteppingError or '')."""
    test = FemDemBiaxial(COMM, settings, verbose=False)
    message = ""
    try:
        test.run(on_step)
    except LoadSteppingError as error:
        message = str(error)
    return test, same_everywhere(message)


def small_run(steps=2, axial_strain=0.002, batched=True, **cell):
    return FemDemSettings(nx=1, ny=1, steps=steps, axial_strain=axial_strain, dt_min_fraction=2.0 ** -3,
                          batched=batched, cell=CellOptions(particles=100, **cell))


@pytest.fixture(scope="module")
def reference():
    """The prepared 100-disc reference cell (friction 0.4), built on rank 0, broadcast."""
    cells, _ = reference_cells(CellOptions(particles=100), [0.4], COMM)
    return cells


# --- a Gauss point whose cell loses every contact -------------------------------------

def one_point(reference, **kw):
    material = DemMaterial(reference, make_mode("classical"), **kw)
    state = material.initial_state(1)
    return material, state


def update(material, state, eps11, eps22):
    gradients = np.array([[eps11, eps22, 0.0, 0.0, 0.0, 0.0]])
    flux, tangent, state_new = np.full((1, 6), 7.0), np.zeros((1, 6, 6)), np.zeros_like(state)
    report = material.update(gradients, 0.0, state, flux, tangent, state_new)
    return report, flux, state_new


def test_cell_pulled_apart_is_flagged_with_zero_stress(reference):
    material, state = one_point(reference)
    assert state[0, material.state_index["n_contacts"]] > 0
    report, flux, state_new = update(material, state, 0.02, 0.02)     # 2 % biaxial tension
    assert report.status.tolist() == [STATUS_NO_CONTACTS]
    assert "lost every contact" in report.message
    assert np.all(flux == 0.0)                                           # zero stress, finite
    idx = material.state_index
    assert state_new[0, idx["status"]] == STATUS_NO_CONTACTS and state_new[0, idx["n_contacts"]] == 0
    assert state_new[0, idx["coordination_number"]] == 0 and np.isfinite(state_new).all()
    tangent = np.full((1, 6, 6), np.nan)
    material.tangent(np.array([0]), tangent)                             # no NaN, ...
    reference_tangent = np.full((1, 6, 6), np.nan)
    material.mode.tangent(reference[0], None, "kruyt", reference_tangent[0])
    # ... 1e-6 of the reference stiffness: keeps an element of such points non-singular
    assert np.allclose(tangent, 1e-6 * reference_tangent, rtol=1e-12, atol=0)
    assert np.all(np.diag(tangent[0])[:4] > 0)
    # the trial never reached the committed cell: a small compression from it works again
    report, flux, state_new = update(material, state, 0.0, -1e-3)
    assert report.status.tolist() == [0] and np.isfinite(flux).all()
    assert flux[0, 1] < flux[0, 0] < 0 and state_new[0, idx["n_contacts"]] > 0


def test_strain_increment_guard_and_non_finite_gradients(reference):
    """A far too large or non-finite target is refused (status -2), the flux left as it was."""
    material, state = one_point(reference)
    for eps in (0.06, np.nan, np.inf):
        report, flux, _ = update(material, state, eps, 0.0)
        assert report.status.tolist() == [STATUS_BAD_F], (eps, report)
        assert "max_strain_increment" in report.message
        assert np.all(flux == 7.0)                                       # untouched, no NaN written
    material, state = one_point(reference, max_strain_increment=2.0)    # det F < 0 gets to the cell
    report, flux, _ = update(material, state, -1.5, 0.0)
    assert report.status.tolist() == [STATUS_BAD_F] and "inadmissible deformation" in report.message
    assert np.all(flux == 7.0)


def pulled_apart_scene(reference, steps):
    """1x1 Cauchy specimen of cells, top pulled up by 2 % of H per step (u2 Dirichlet),
    bottom on rollers with a pin, lateral faces free: every cell loses its contacts."""
    material = DemMaterial(reference, make_mode("classical"))
    mesh, tags, names = meshes.rectangle(COMM, W, H, divisions=(1, 1))
    problem = CosseratProblem(mesh, tags, names, material=material, micropolar=False)
    material.set_point_coordinates(gauss_point_coordinates(mesh, problem.quadrature_degree))
    problem.add_dirichlet("bottom", "u2", 0.0)
    problem.add_dirichlet("top", "u2", 1.0, scale=lambda t: 0.02 * H * t)
    problem.add_point_dirichlet((0.5 * W, 0.0), "u1", 0.0)
    solver = RecordingSolver(NewtonSolver(problem, options={"snes_linesearch_type": "basic"}, force_rtol=1e-2))
    cb = problem.gauss_points          # fluxes sigma = -p0 I before any solve (initial_fluxes)
    stepper = LoadStepper(problem, solver, t_end=float(steps), dt=1.0, dt_min=2.0 ** -3, verbose=False)
    message = ""
    try:
        stepper.run()
    except LoadSteppingError as error:
        message = str(error)
    message = same_everywhere(message)
    status = cb.state_old[:, material.state_index["status"]]
    assert everywhere(np.isfinite(cb.flux_values).all() and np.isfinite(problem.w.x.array).all())
    return stepper, solver, message, status, cb


def check_pulled_apart(reference, steps):
    stepper, solver, message, status, cb = pulled_apart_scene(reference, steps)
    if message:      # stopped: the cause is named
        assert "lost every contact" in message, message
    else:            # went on: every point flagged, zero stress
        assert len(stepper.records) == steps
        assert "lost every contact" in solver.infos[-1].flags
        assert total(np.count_nonzero(status == STATUS_NO_CONTACTS)) == total(len(status)) > 0
        assert everywhere(np.all(cb.flux_values == 0.0))


def test_specimen_pulled_apart_goes_on_flagged(reference):
    check_pulled_apart(reference, steps=1)


# --- cuts and stops -----------------------------------------------------------------------

def test_cell_out_of_step_budget_cuts_then_stops_every_rank():
    """After phase 1, the cells of one rank only get a budget of 5 DEM steps per solve (set on
    the resident cells: CellOptions(max_steps=5) already fails in the reference cell's
    preparation, see test_femdem_input.test_tiny_dem_step_budget): phase 2's first step is
    cut and retried down to dt_min, then a LoadSteppingError names the budget on every rank
    (the other rank's cells converge: it must stop with the same message, not wait). The
    budget is set on resident DemCells: one cell at a time (a batch keeps its options in its
    own arrays)."""
    test = FemDemBiaxial(COMM, small_run(batched=False), verbose=False)
    counts = COMM.allgather(len(test.material.cells))
    victim = next(rank for rank, n in enumerate(counts) if n)

    def tighten(row):
        if row["step"] == 1 and COMM.rank == victim:
            for cell in test.material.cells:
                # (no cap: a relaxation stopped by relax_cap counts as converged)
                cell.options = dataclasses.replace(cell.options, max_steps=5, relax_cap=None)

    message = ""
    try:
        test.run(tighten)
    except LoadSteppingError as error:
        message = str(error)
    message = same_everywhere(message)
    assert "did not relax within its step budget" in message and "max_steps = 5" in message, message
    assert "did not converge down to dt_min" in message
    failed = [info for info in test.solver.infos if not info.converged]
    assert len(failed) == 4            # dt = 1, 1/2, 1/4, 1/8, then below dt_min = 1/8
    assert all("did not relax within its step budget" in info.failure for info in failed)
    assert len(test.history) == 1 and test.history[0]["phase"] == 1
    # the failed step's cut-backs are counted (the summary's cut_backs), not only those of
    # the last converged step
    assert test.stepper.cuts == 4 and test.history[-1]["cuts"] == 0
    assert_finite(test)


def test_load_step_far_too_large_is_cut():
    """22 % in one step: the strain-increment guard refuses 22 %, 11 % and 5.5 % (no cell is
    torn), the run stops at dt_min = 1/4 naming the guard (a smaller dt_min goes on to Newton
    solves of 2.75 % and 1.4 % that cost ~30 s of DEM work)."""
    test, message = run(FemDemSettings(nx=1, ny=1, steps=1, axial_strain=0.22, dt_min_fraction=2.0 ** -2,
                                       cell=CellOptions(particles=100)))
    guarded = [info for info in test.solver.infos if "max_strain_increment" in info.failure]
    assert len(guarded) >= 2 and not test.solver.infos[1].converged
    if message:
        assert "did not converge down to dt_min" in message and "max_strain_increment" in message, message
    else:
        assert test.history[-1]["axial_strain"] == pytest.approx(-0.22)
    assert test.history[0]["phase"] == 1
    assert_finite(test)


def test_very_stiff_contacts():
    """kn = 1e7, ks = 2e6 at p0 = 10 N/m (p0/kn = 1e-6): demcell cannot compact the loose
    packing (its servo moves by gain p0/kn per step), and the scene refuses before any step
    with a ValueError naming the compaction; a run that gets through must be finite."""
    settings = small_run(axial_strain=2e-5, kn=1e7, ks=2e6, pressure=10.0)
    try:
        test, message = run(settings)
    except ValueError as error:
        message = same_everywhere(str(error))
        assert "compaction did not converge" in message, message
        return
    if message:
        assert "did not converge" in message, message
    else:
        assert len(test.history) == 3
    assert_finite(test)


def test_very_stiff_contacts_on_a_soft_packing(tmp_path):
    """The same stiff contacts on a packing compacted with the default contacts: the cell is
    prepared, but the macro Newton stalls (force ratio ~0.1 > 1e-2) even for 1e-5 strain
    steps (bounded here: 10 Newton iterations, one cut); it must end completed or in a named
    stop, finite."""
    import demcell as dc
    state, info = dc.generate_packing(100, pressure=10.0, seed=0)
    path = str(tmp_path / "soft.npz")
    dc.save_packing(path, state, info)
    settings = small_run(axial_strain=2e-5, kn=1e7, ks=2e6, packing=path)
    settings.dt_min_fraction = 0.5
    settings.solver_options = {"snes_max_it": 10}
    test, message = run(settings)
    assert test.history and test.history[0]["phase"] == 1
    if message:
        assert "did not converge down to dt_min" in message and message.split(": ", 1)[1], message
    else:
        assert len(test.history) == 3
    assert_finite(test)


def check_friction_run(friction, **cell):
    test, message = run(small_run(friction=friction, **cell))
    assert message == "" and len(test.history) == 3, message
    assert_finite(test)
    sliding = test.state("sliding_fraction")
    last = test.history[-1]
    if friction == 0.0:     # every contact at its (zero) Coulomb limit, a weak packing
        assert everywhere(np.all(sliding == 1.0)) and last["stress_ratio"] < 0.15
    else:                   # nothing slides
        assert everywhere(np.all(sliding == 0.0)) and last["stress_ratio"] > 0.2


def test_infinite_friction():
    check_friction_run(math.inf)


def test_zero_friction_energy_criterion():
    """Frictionless discs with the cells relaxed to E_kin/E_pot <= 1e-3 (000 eq. 31)."""
    check_friction_run(0.0, criterion="energy")


def test_zero_friction():
    """Frictionless cells with the default criterion (unbalanced-force ratio 1e-3): every
    contact sits at its (zero) Coulomb limit, the packing rearranges at any shear and the
    macro residual does not go below about 0.02-0.05 (measured). Bounded here (8 Newton
    iterations, one cut): the run either completes or stops with a message that says the
    residual stagnated above force_rtol and why, never with NaN."""
    settings = small_run(friction=0.0)
    settings.dt_min_fraction = 0.5
    settings.solver_options = {"snes_max_it": 8}
    test, message = run(settings)
    assert_finite(test)
    assert (message == "" and len(test.history) == 3) or (
        "did not go below" in message and "not smooth" in message), message


# --- the demo's output in ParaView (serial) ------------------------------------------------

VTK_SCRIPT = r'''
import json, sys
from paraview import simple
out = {}
for label, path in (("particles", sys.argv[1]), ("contacts", sys.argv[2])):
    reader = simple.LegacyVTKReader(FileNames=[path])
    reader.UpdatePipeline()
    info = reader.GetDataInformation()
    arrays = {}
    for kind, data in (("point", reader.PointData), ("cell", reader.CellData)):
        for name in data.keys():
            a = data[name]
            arrays[name] = {"kind": kind, "components": a.GetNumberOfComponents(),
                            "range": [list(a.GetRange(i)) for i in range(a.GetNumberOfComponents())]}
    out[label] = {"points": info.GetNumberOfPoints(), "cells": info.GetNumberOfCells(), "arrays": arrays}
print("PARAVIEW_JSON " + json.dumps(out))
'''

FIELDS = ["displacement", "rotation", "stress", "couple_stress", "coordination_number", "anisotropy",
          "sliding_fraction", "stress_ratio", "equivalent_strain", "incremental_equivalent_strain", "dem_steps"]

no_paraview = shutil.which("pvbatch") is None or shutil.which("xvfb-run") is None


@pytest.mark.serial
@pytest.mark.skipif(no_paraview, reason="ParaView (python3-paraview) or xvfb-run not installed")
def test_femdem_output_in_paraview(demo, tmp_path):
    from test_paraview import paraview_read, pvbatch_json
    from conftest import read_summary
    strain, p0 = 0.002, 10.0
    demo("femdem_biaxial", "--mesh", "1x2", "--particles", 100, "--axial-strain", strain, "--steps", 2,
         "--out", tmp_path)
    summary = read_summary(tmp_path)
    assert summary["completed"] and summary["n_gauss_points"] == 12
    history = np.genfromtxt(tmp_path / "history.csv", delimiter=",", names=True)

    data = paraview_read(tmp_path / "fields.xdmf", tmp_path / "render.png", "stress_ratio")
    arrays = data["arrays"]
    assert set(FIELDS) <= set(arrays), sorted(arrays)
    assert data["times"] == pytest.approx([1.0, 2.0, 3.0])
    for name, a in arrays.items():
        assert np.isfinite(a["range"]).all(), (name, a)
    rng = {name: arrays[name]["range"] for name in FIELDS}
    assert 2.0 <= rng["coordination_number"][0][0] <= rng["coordination_number"][0][1] <= 6.0
    assert 0.0 <= rng["stress_ratio"][0][0] <= rng["stress_ratio"][0][1] <= 1.0
    assert rng["stress_ratio"][0][1] > 0.1                     # 0.2 % compression: ~0.3
    assert rng["stress_ratio"][0][0] - 1e-5 <= history["stress_ratio"][-1] <= rng["stress_ratio"][0][1] + 1e-5
    assert 0.0 <= rng["sliding_fraction"][0][0] <= rng["sliding_fraction"][0][1] <= 1.0
    assert 0.0 <= rng["anisotropy"][0][0] <= rng["anisotropy"][0][1] < 1.0
    assert rng["dem_steps"][0][0] > 0
    eq, inc = rng["equivalent_strain"][0], rng["incremental_equivalent_strain"][0]
    assert 0.5 * strain < eq[0] <= eq[1] < 3.0 * strain and 0.0 < inc[0] <= inc[1] < eq[1]
    s11, s22 = rng["stress"][0], rng["stress"][4]                 # 3x3 tensor, row-major
    assert s11 == pytest.approx([-p0, -p0], rel=0.02)             # the lateral traction
    assert s22[1] < -1.2 * p0                                     # axial compression
    u2 = rng["displacement"][1]
    assert u2[0] == pytest.approx(-strain * 0.02, rel=1e-4) and abs(u2[1]) < 1e-9
    assert arrays["stress"]["kind"] == "cell" and arrays["displacement"]["kind"] == "point"
    # the snapshot points are the extreme ones of the field (cell averages lie between)
    snaps = summary["snapshots"]
    assert snaps["highest_stress_ratio"]["stress_ratio"] >= rng["stress_ratio"][0][1] - 1e-5
    assert snaps["lowest_stress_ratio"]["stress_ratio"] <= rng["stress_ratio"][0][0] + 1e-5

    script = tmp_path / "vtk_check.py"
    script.write_text(VTK_SCRIPT)
    snap = tmp_path / "snapshots" / "highest_stress_ratio"
    vtk = pvbatch_json(script, snap / "particles_0000.vtk", snap / "contacts_0000.vtk")
    particles, contacts = vtk["particles"], vtk["contacts"]
    n = summary["particles_per_cell"]
    assert n == 100 and particles["points"] == n and particles["cells"] == n     # one vertex per disc
    assert {"radius", "rotation", "velocity"} <= set(particles["arrays"])
    r_min, r_max = particles["arrays"]["radius"]["range"][0]
    assert 0.0 < r_min <= r_max <= 1.5 * r_min * (1 + 1e-9)                      # radius ratio 1.5
    m = contacts["cells"]                                                          # one line per contact
    assert m > 0 and contacts["points"] == 2 * m
    assert {"normal_force", "tangential_force"} <= set(contacts["arrays"])
    assert contacts["arrays"]["normal_force"]["kind"] == "cell"
    f_min, f_max = contacts["arrays"]["normal_force"]["range"][0]
    assert f_max > 0.0 and f_min >= 0.0 and np.isfinite([f_min, f_max]).all()     # compressive, no cohesion
    z = 2.0 * m / n                                                                # this point's coordination
    assert rng["coordination_number"][0][0] - 0.2 <= z <= rng["coordination_number"][0][1] + 0.2


# --- a second step after every cell lost its contacts (once a MUMPS error) ---------------

def test_specimen_pulled_apart_then_further(reference):
    check_pulled_apart(reference, steps=2)
