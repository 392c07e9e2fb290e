"""demcell's public calls check their arguments, no call runs unbounded, packing files are checked.

* ``DemCell.solve(max_steps=N)`` bounds the whole solve (every sub-step's ramp and relaxation):
  a deformation of a million in one call returns after N steps, not converged, and says why;
  ``max_substep_steps`` keeps the budget of each sub-step after its ramp.
* Every refusal is an InputError (a ValueError) of one line naming the argument.
* A packing file of a newer format, truncated, with a field deleted, of the wrong dtype or
  shape, or with NaN in its arrays is refused in one line naming the file and the field.
"""
import json
import math
import os
import time

import numpy as np
import pytest
from numba import config

import demcell as dc
from demcell.batch import CellBatch
from demcell.interface import RelaxationOptions
from demcell import slots

pytestmark = pytest.mark.serial


@pytest.fixture(scope="module")
def packing30():
    return dc.generate_packing(30)


def refused(call, *words, error=dc.InputError):
    """`call()` must raise `error` with a one-line message holding each of `words`."""
    with pytest.raises(error) as info:
        call()
    message = str(info.value)
    assert "\n" not in message, message
    for w in words:
        assert w in message, (w, message)
    return message


# ----- the step budget of a solve --------------------------------------------------------------

def test_a_huge_deformation_stops_at_the_step_budget(packing30):
    """F = 1e6 I (1e8 sub-steps of 1000 ramp steps each) with max_steps=5000: before, each
    sub-step had its own budget and the call ran for hours; now it stops after 5000 steps."""
    state, _ = packing30
    warm = dc.DemCell(state.copy())          # (compiled, or loaded from Numba's cache, before the clock runs)
    warm.set_deformation(np.diag([1.001, 1.0]))
    warm.solve(max_steps=10)
    cell = dc.DemCell(state.copy())
    cell.set_deformation(1e6 * np.eye(2))
    start = time.perf_counter()
    res = cell.solve(max_steps=5000)
    wall = time.perf_counter() - start
    assert not res.converged and res.steps == 5000, res
    assert res.substeps > 1e7
    assert "step budget of the solve spent (max_steps = 5000" in res.message and "\n" not in res.message
    assert wall < 5.0, wall                  # measured: 0.03 s
    assert np.all(np.isfinite(cell.state.s)) and np.all(np.isfinite(cell.cauchy_stress()))


def test_the_budget_binds_the_servo_and_the_micropolar_paths(packing30):
    state, _ = packing30
    servo = dc.DemCell(state.copy())
    servo.set_deformation(1e6 * np.eye(2))
    res = servo.solve(stress_mask=[[False, False], [False, True]], stress_target=np.zeros((2, 2)), max_steps=4000)
    assert not res.converged and res.steps == 4000 and "step budget" in res.message, res
    micro = dc.DemCell(state.copy(), rotation_mode="micropolar")
    micro.set_deformation(1e6 * np.eye(2), rotation=0.3)
    res = micro.solve(max_steps=3000)
    assert not res.converged and res.steps == 3000 and "step budget" in res.message, res
    res = micro.solve(stress_mask=[[False, False], [False, True]], stress_target=np.zeros((2, 2)), max_steps=2000)
    assert not res.converged and res.steps == 2000 and "step budget" in res.message, res


def test_the_options_bound_a_solve_without_max_steps(packing30):
    state, _ = packing30
    cell = dc.DemCell(state.copy(), options=RelaxationOptions(max_total_steps=3000))
    cell.set_deformation(1e6 * np.eye(2))
    res = cell.solve()
    assert not res.converged and res.steps == 3000 and "max_steps = 3000" in res.message
    assert RelaxationOptions().solve_budget == 20_000_000
    assert RelaxationOptions(max_steps=10).solve_budget == 10 ** 7


def test_max_substep_steps_keeps_the_budget_of_each_substep(packing30):
    state, _ = packing30
    # (no convergence test within the ramp and the 20 steps after it)
    cell = dc.DemCell(state.copy(), options=RelaxationOptions(strain_rate=1e-4, check_every=1000))
    cell.set_deformation(np.diag([1.0025, 0.995]))
    res = cell.solve(max_substep_steps=20)
    assert not res.converged and 50 + 20 <= res.steps <= 51 + 20, res     # the ramp (5e-3 / 1e-4), then 20
    assert "maximum number of steps" in res.message and "step budget" not in res.message


def test_a_budget_that_does_not_bind_changes_no_bit(packing30):
    state, _ = packing30
    F = np.array([[1.002, 0.001], [0.0, 0.997]])
    a, b = dc.DemCell(state.copy()), dc.DemCell(state.copy())
    a.set_deformation(F)
    b.set_deformation(F)
    ra, rb = a.solve(), b.solve(max_steps=10 ** 9)
    assert ra.converged and ra.steps == rb.steps
    k = a.state.n_pairs
    assert np.array_equal(a.state.s, b.state.s) and np.array_equal(a.state.fn[:k], b.state.fn[:k])


@pytest.mark.skipif(not config.ENABLE_CUDASIM, reason="bit for bit in Numba's CUDA simulator only")
def test_the_device_batch_stops_at_the_same_budget(packing30):
    from demcell.gpu.batch import DeviceCellBatch
    state, _ = packing30
    cell = dc.DemCell(state.copy(), options=RelaxationOptions(max_total_steps=120, strain_rate=1e-4,
                                                              check_every=10))
    cpu, gpu = CellBatch([cell.copy()]), DeviceCellBatch([cell.copy()], threads=4)
    rows = np.arange(1)
    F = np.array([[[1.015625, 0.0], [0.0, 0.99]]])      # 2 sub-steps of 79 ramp steps each
    for b in (cpu, gpu):
        b.set_targets(rows, F)
    r1, r2 = cpu.solve(rows), gpu.solve(rows)
    assert np.array_equal(r1, r2)
    assert r1[0, slots.R_STEPS] == 120 and r1[0, slots.R_BUDGET] == 120 and r1[0, slots.R_CONVERGED] == 0.0
    converged, _, message, error = cpu.outcome(0, r1[0])
    assert not converged and error is None and "of 2: step budget of the solve spent" in message, message


# ----- arguments -------------------------------------------------------------------------------

@pytest.mark.parametrize("kwargs, words", [
    (dict(n_particles=30.5), ("n_particles must be an integer", "30.5")),
    (dict(n_particles="30"), ("n_particles must be an integer",)),
    (dict(n_particles=True), ("n_particles must be an integer",)),
    (dict(n_particles=1), ("n_particles must be an integer in [2,",)),
    (dict(pressure=-1.0), ("pressure must be > 0", "-1.0")),
    (dict(pressure=math.nan), ("pressure must be > 0", "nan")),
    (dict(pressure="10"), ("pressure must be > 0",)),
    (dict(r_min=0.0), ("r_min must be > 0",)),
    (dict(radius_ratio=0.5), ("radius_ratio must be >= 1",)),
    (dict(seed=-1), ("seed must be an integer",)),
    (dict(seed=1.5), ("seed must be an integer",)),
    (dict(density=math.inf), ("density must be > 0",)),
    (dict(prep_friction=-0.1), ("prep_friction must be >= 0",)),
    (dict(anisotropy=1.5), ("anisotropy",)),
    (dict(solid_fraction=math.nan), ("solid_fraction",)),
    (dict(law="linear"), ("law must be a ContactLaw", "str")),
    (dict(options=5), ("options must be a RelaxationOptions",)),
])
def test_generate_packing_refuses_bad_arguments(kwargs, words):
    args = dict(n_particles=30)
    args.update(kwargs)
    refused(lambda: dc.generate_packing(**args), *words)


def test_other_packing_builders_refuse_bad_arguments():
    refused(lambda: dc.hexagonal_lattice(3.5, 4), "nx must be an integer")
    refused(lambda: dc.hexagonal_lattice(4, 5), "even ny")
    refused(lambda: dc.hexagonal_lattice(4, 4, radius=-0.01), "radius must be > 0")
    refused(lambda: dc.hexagonal_lattice(4, 4, overlap=1.5), "overlap must be in [0, 1)")
    refused(lambda: dc.loose_state(10, solid_fraction=0.9), "solid_fraction must be in (0, 0.6)")
    refused(lambda: dc.loose_state(10.5), "n_particles must be an integer")
    refused(lambda: dc.CellState.new([0.01, -0.01], np.zeros((2, 2)), np.eye(2), 2e3), "radius[1] must be > 0, got -0.01")
    refused(lambda: dc.CellState.new([0.01, 0.01], np.zeros((3, 2)), np.eye(2), 2e3), "s must be an array",
            "shape (2, 2)", "got shape (3, 2)")
    refused(lambda: dc.CellState.new([0.01, 0.01], np.zeros((2, 2)), [[1.0, math.nan], [0.0, 1.0]], 2e3),
            "h[0][1] must be a finite number, got nan")


def test_contact_law_and_options_refuse_bad_values():
    refused(lambda: dc.ContactLaw(kn="1e4"), "ContactLaw.kn must be > 0", "'1e4'")
    refused(lambda: dc.ContactLaw(friction=math.nan), "ContactLaw.friction must be >= 0")
    refused(lambda: dc.ContactLaw(normal_damping=math.inf), "ContactLaw.normal_damping must be >= 0")
    refused(lambda: dc.ContactLaw(rotations=1), "ContactLaw.rotations must be True or False")
    assert dc.ContactLaw(friction=math.inf, cohesion_normal=math.inf).friction == math.inf
    refused(lambda: RelaxationOptions(max_steps=2.5), "RelaxationOptions.max_steps must be an integer")
    refused(lambda: RelaxationOptions(max_total_steps=0), "RelaxationOptions.max_total_steps must be an integer")
    refused(lambda: RelaxationOptions(damping=1.0), "RelaxationOptions.damping must be in [0, 1)")
    refused(lambda: RelaxationOptions(tol="1e-3"), "RelaxationOptions.tol must be > 0")
    assert RelaxationOptions(max_steps=2e5).max_steps == 200_000 and \
        isinstance(RelaxationOptions(max_steps=2e5).max_steps, int)


def test_demcell_refuses_bad_arguments(packing30):
    state, _ = packing30
    refused(lambda: dc.DemCell(state.copy(), options=5), "options must be a RelaxationOptions")
    refused(lambda: dc.DemCell(state.copy(), reset_reference="yes"), "reset_reference must be a bool")
    bad = state.copy()
    bad.s = bad.s[:, :1].copy()
    refused(lambda: dc.DemCell(bad), "s has shape", "expected")
    bad = state.copy()
    bad.s[3, 0] = math.nan
    refused(lambda: dc.DemCell(bad), "s[3][0] must be finite, got nan")
    bad = state.copy()
    bad.radius = bad.radius.astype(np.float32)
    refused(lambda: dc.DemCell(bad), "radius must be an array of dtype float64")
    refused(lambda: dc.create_cells("pack.npz"), "state must be a CellState")
    refused(lambda: dc.create_cells(state, count=2.5), "count must be an integer >= 1")


@pytest.mark.parametrize("F, words", [
    (np.eye(3), ("F must be an array of numbers of shape (2, 2)", "got shape (3, 3)")),
    ([1.0, 0.0, 0.0, 1.0], ("F must be an array", "got shape (4,)")),
    ([[1.0, math.nan], [0.0, 1.0]], ("F[0][1] must be a finite number, got nan",)),
    ([[1.0, 0.0], [0.0, math.inf]], ("F[1][1] must be a finite number, got inf",)),
    ("identity", ("F must be an array of numbers",)),
    ([[1.0, 0.0], [0.0]], ("F must be an array of numbers", "ragged")),
    (np.diag([1.0, -1.0]), ("det F > 0", "det F = -1")),
    (np.zeros((2, 2)), ("det F > 0", "det F = 0")),
    (1e200 * np.eye(2), ("det F > 0", "det F = inf")),
])
def test_set_deformation_refuses_bad_F(packing30, F, words):
    cell = dc.DemCell(packing30[0].copy())
    refused(lambda: cell.set_deformation(F), *words)
    assert np.array_equal(cell.target[0], np.eye(2))           # the target is unchanged


def test_the_other_methods_refuse_bad_arguments(packing30):
    cell = dc.DemCell(packing30[0].copy())
    refused(lambda: cell.set_displacement_gradient(np.zeros(3)), "grad_u must be an array", "(2, 2)")
    refused(lambda: cell.solve(max_steps=0), "max_steps must be an integer >= 1")
    refused(lambda: cell.solve(max_steps=2.5), "max_steps must be an integer >= 1")
    refused(lambda: cell.solve(max_substep_steps=-3), "max_substep_steps must be an integer >= 1")
    refused(lambda: cell.solve(stress_mask=np.eye(2, dtype=int), stress_target=np.eye(2)),
            "stress_mask must be a 2x2 array of booleans")
    refused(lambda: cell.solve(stress_mask=np.eye(2, dtype=bool), stress_target="zero"),
            "stress_target must be a 2x2 array")
    refused(lambda: cell.run_dynamics(-1), "n_steps must be an integer")
    refused(lambda: cell.run_dynamics(2.5), "n_steps must be an integer")
    refused(lambda: cell.run_dynamics(10, damping=1.5), "damping must be in [0, 1)")
    refused(lambda: cell.tangent("demqo", eps=-1e-6), "eps must be in (0, 0.1]")
    refused(lambda: cell.tangent("demqo", eps=math.nan), "eps must be in (0, 0.1]")
    refused(lambda: cell.tangent(3), "tangent kind must be a string")
    refused(lambda: cell.set_law("frictionless"), "law must be a ContactLaw")
    micro = dc.DemCell(packing30[0].copy(), rotation_mode="micropolar")
    refused(lambda: micro.set_deformation(np.eye(2), rotation="0.3"), "rotation must be a number [rad], got '0.3'")
    refused(lambda: micro.set_deformation(np.eye(2), rotation=True), "rotation must be a number [rad]")
    refused(lambda: micro.set_deformation(np.eye(2), curvature="ab"), "curvature must be two finite numbers")
    refused(lambda: micro.set_deformation(np.eye(2), curvature=[[0.0, 1.0], [2.0]]), "curvature must be two finite")
    refused(lambda: cell.restore("state"), "restore needs a CellState")
    refused(lambda: dc.isotropic_stage(cell, -10.0), "pressure must be > 0", "-10.0")
    refused(lambda: dc.isotropic_stage(cell, math.nan), "pressure must be > 0", "nan")
    refused(lambda: dc.isotropic_stage("cell", 10.0), "cell must be a DemCell")
    refused(lambda: dc.reference_cell(packing30[0], dc.ContactLaw(), None, math.inf), "pressure must be > 0")
    refused(lambda: dc.homogenize(cell.state, "law"), "law must be an array of numbers of shape (11,)")
    refused(lambda: dc.homogenize("state", cell.law_array), "state must be a CellState")
    assert dc.homogenize(cell.state, cell.law).n_contacts == cell.homogenized().n_contacts


def test_the_batch_refuses_bad_arguments(packing30):
    batch = CellBatch([dc.DemCell(packing30[0].copy()) for _ in range(2)])
    rows = np.arange(2)
    refused(lambda: batch.set_targets(rows, np.eye(2)), "F must be an array", "shape (2, 2, 2)")
    refused(lambda: batch.set_targets(rows, np.array([np.eye(2), np.diag([1.0, -1.0])])), "det F[1] = -1")
    refused(lambda: batch.set_targets([0, 2], np.array([np.eye(2)] * 2)), "rows must be a 1D array of cell indices")
    refused(lambda: batch.set_targets([0.0, 1.0], np.array([np.eye(2)] * 2)), "rows must be")
    refused(lambda: batch.solve(rows, max_steps=0), "max_steps must be an integer >= 1")


# ----- io ----------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def packing_file(tmp_path_factory, packing30):
    path = str(tmp_path_factory.mktemp("packing") / "pack.npz")
    dc.save_packing(path, *packing30)
    return path


def rewrite(src, dst, change):
    """A copy of the packing file `src` at `dst` with its arrays changed by `change(dict)`."""
    with np.load(src, allow_pickle=False) as z:
        d = {k: z[k] for k in z.files}
    change(d)
    np.savez(dst, **d)
    return str(dst)


def test_save_and_load_refuse_bad_arguments(tmp_path, packing30):
    state, info = packing30
    refused(lambda: dc.save_packing(3, state), "path must be a file path")
    refused(lambda: dc.save_packing(str(tmp_path / "a.npz"), "state"), "state must be a CellState")
    refused(lambda: dc.save_packing(str(tmp_path / "a.npz"), state, info=[1]), "info must be a dict")
    refused(lambda: dc.save_packing(str(tmp_path / "a.npz"), state, info={"f": object()}),
            "info must be a dict of JSON values")
    refused(lambda: dc.load_packing(None), "path must be a file path")
    refused(lambda: dc.write_vtk_snapshot(str(tmp_path), 1.5, state), "index must be an integer")
    refused(lambda: dc.load_packing(tmp_path / "missing.npz"), "packing file not found", "missing.npz")


def test_a_packing_file_round_trip_still_works(tmp_path, packing_file, packing30):
    st, info = dc.load_packing(packing_file)
    assert np.array_equal(st.s, packing30[0].s) and info["n_particles"] == 30
    st, _ = dc.load_packing(type("P", (os.PathLike,), {"__fspath__": lambda self: packing_file})())
    assert st.n_particles == 30


def test_a_future_version_is_refused(tmp_path, packing_file):
    path = rewrite(packing_file, tmp_path / "future.npz",
                   lambda d: d.update(demcell_packing_version=np.array(dc.io.PACKING_VERSION + 1)))
    refused(lambda: dc.load_packing(path), path, f"format version {dc.io.PACKING_VERSION + 1}",
            f"reads versions 1 to {dc.io.PACKING_VERSION}")
    path = rewrite(packing_file, tmp_path / "zero.npz", lambda d: d.update(demcell_packing_version=np.array(0)))
    refused(lambda: dc.load_packing(path), path, "'demcell_packing_version'", "not a format version")
    path = rewrite(packing_file, tmp_path / "text.npz",
                   lambda d: d.update(demcell_packing_version=np.array("one")))
    refused(lambda: dc.load_packing(path), path, "'demcell_packing_version'")


def test_a_truncated_file_is_refused(tmp_path, packing_file):
    data = open(packing_file, "rb").read()
    for cut in (len(data) // 2, len(data) - 30, 100, 0):
        path = str(tmp_path / f"cut{cut}.npz")
        with open(path, "wb") as f:
            f.write(data[:cut])
        refused(lambda: dc.load_packing(path), path)
    path = str(tmp_path / "flipped.npz")
    middle = len(data) // 2
    with open(path, "wb") as f:
        f.write(data[:middle] + bytes(b ^ 0xFF for b in data[middle:middle + 64]) + data[middle + 64:])
    refused(lambda: dc.load_packing(path), path)
    path = str(tmp_path / "text.npz")
    with open(path, "w") as f:
        f.write("radius,s\n0.01,0.5\n")
    refused(lambda: dc.load_packing(path), path, "not a readable .npz archive")


@pytest.mark.parametrize("field", ["radius", "s", "h", "h_ref", "pair_i", "n_pairs", "info_json", "time"])
def test_a_deleted_field_is_refused(tmp_path, packing_file, field):
    path = rewrite(packing_file, tmp_path / f"no_{field}.npz", lambda d: d.pop(field))
    refused(lambda: dc.load_packing(path), path, f"lacks the field {field!r}")


def test_an_old_file_without_phi_and_kappa_is_read(tmp_path, packing_file):
    path = rewrite(packing_file, tmp_path / "old.npz", lambda d: [d.pop("phi"), d.pop("kappa")])
    st, _ = dc.load_packing(path)
    assert st.phi == 0.0 and np.all(st.kappa == 0.0)


def _set(name, index, value):
    def change(d):
        a = d[name].copy()
        a[index] = value
        d[name] = a
    return change


@pytest.mark.parametrize("change, words", [
    (_set("radius", 4, math.nan), ("radius[4] must be finite and > 0, got nan",)),
    (_set("radius", 0, -0.01), ("radius[0] must be finite and > 0, got -0.01",)),
    (_set("mass", 2, 0.0), ("mass[2] must be finite and > 0, got 0.0",)),
    (_set("s", (5, 1), math.inf), ("s[5][1] must be finite, got inf",)),
    (_set("v", (0, 0), math.nan), ("v[0][0] must be finite",)),
    (_set("fn", 0, math.nan), ("fn[0] must be finite",)),
    (_set("h", (0, 0), math.nan), ("h[0][0] must be finite",)),
    (lambda d: d.update(h=np.zeros((2, 2))), ("cell matrix h must have a finite det > 0",)),
    (lambda d: d.update(h_ref=np.diag([1.0, -1.0]) * d["h_ref"]), ("cell matrix h_ref", "det > 0")),
    (lambda d: d.update(kappa=np.array([math.nan, 0.0])), ("kappa[0] must be finite",)),
    (lambda d: d.update(time=np.array(math.nan)), ("time must be a finite number",)),
    (_set("pair_j", 0, 10 ** 6), ("pair_j holds particle indices outside [0, 30)",)),
    (_set("touching", 0, 2), ("field 'touching' must hold flags 0 or 1",)),
    (lambda d: d.update(n_pairs=np.array(10 ** 6)), ("field 'n_pairs' = 1000000 outside",)),
    (lambda d: d.update(forces_current=np.array(3)), ("forces_current must be 0 or 1",)),
    (lambda d: d.update(s=d["s"][:, :1]), ("field 's' has shape (30, 1), expected (30, 2)",)),
    (lambda d: d.update(h=np.eye(3)), ("field 'h' has shape (3, 3), expected (2, 2)",)),
    (lambda d: d.update(fn=d["fn"][:-1]), ("field 'fn' has shape",)),
    (lambda d: d.update(radius=d["radius"].astype(str)), ("field 'radius' has dtype <U", "expected floats")),
    (lambda d: d.update(pair_i=d["pair_i"].astype(float)), ("field 'pair_i' has dtype float64",
                                                             "expected integers")),
    (lambda d: d.update(radius=np.zeros(0)), ("field 'radius' has shape (0,)",)),
    (lambda d: d.update(extra=np.zeros(3)), ("unknown field 'extra'",)),
    (lambda d: d.update(info_json=np.array("{not json")), ("field 'info_json' is not JSON",)),
    (lambda d: d.update(info_json=np.array(json.dumps([1, 2]))), ("field 'info_json' is not a JSON object",)),
])
def test_damaged_arrays_are_refused(tmp_path, packing_file, change, words):
    path = rewrite(packing_file, tmp_path / "damaged.npz", change)
    refused(lambda: dc.load_packing(path), f"packing file {path}", *words)


def test_a_float32_file_is_read_as_float64(tmp_path, packing_file):
    path = rewrite(packing_file, tmp_path / "f32.npz", lambda d: d.update(s=d["s"].astype(np.float32)))
    st, _ = dc.load_packing(path)
    assert st.s.dtype == np.float64
    dc.DemCell(st)


def test_a_pickled_field_is_refused_and_never_unpickled(tmp_path, packing_file):
    marker = tmp_path / "unpickled"

    class Bomb:
        def __reduce__(self):
            return (open, (str(marker), "w"))
    path = rewrite(packing_file, tmp_path / "pickle.npz",
                   lambda d: d.update(radius=np.array([Bomb()], dtype=object)))
    refused(lambda: dc.load_packing(path), path, "'radius'")
    assert not marker.exists()


def test_a_header_announcing_more_data_than_the_file_holds_is_refused(tmp_path, packing_file):
    """A forged .npy header (a million pair slots in a file of a few hundred bytes) is refused
    from the header, before an array of that size is allocated."""
    import io
    import zipfile
    with np.load(packing_file, allow_pickle=False) as z:
        d = {k: z[k] for k in z.files}
    path = str(tmp_path / "forged.npz")
    with zipfile.ZipFile(path, "w") as zf:
        for name, a in d.items():
            header = np.lib.format.header_data_from_array_1_0(a)
            if name == "d_prev":
                header["shape"] = (10 ** 6, 2)
            buf = io.BytesIO()
            np.lib.format.write_array_header_1_0(buf, header)
            zf.writestr(name + ".npy", buf.getvalue() + np.ascontiguousarray(a).tobytes())
    refused(lambda: dc.load_packing(path), path, "field 'd_prev' is damaged", "announces 16000000 bytes")
