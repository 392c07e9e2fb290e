"""Specimen.save / Specimen.restored keep what a coupled run needs (the bridging-scale footing
continues from them): a small footing specimen with a rough plate pushed down, mass damping and
held discs, saved mid-run and restored, repeats the straight run bit for bit."""
import numpy as np
import pytest

from demcell.errors import InputError
from demcell.specimen import Specimen
from demcell.specimen.footing import footing_packing, footing_specimen
from demcell.specimen.specimens import discs_from


def _scene():
    packing = footing_packing("A", (0.0, 2.0, 0.0, 1.0))
    discs = discs_from(packing.position, packing.radius, mass=packing.mass)
    spec, _ = footing_specimen("A", 2.0, 1.0, 0.6, rough=True, mass_damping=25.0, discs=discs, lateral="none",
                               threads=1)
    p, r = packing.position, packing.radius
    held = (p[:, 1] - r < 0.12) | (p[:, 0] - r < 0.12) | (p[:, 0] + r > 1.88)
    spec.hold(held)
    spec.set_plate_velocity(0.0, -2.0)
    return spec, held


def _drive(spec, held, reference, k):
    """k steps with the held discs driven along a slow shear from `reference` (original
    order), as the bridging coupler drives its virtual grains."""
    n = spec.state.n_discs
    for _ in range(k):
        t = spec.state.time + spec.options.dt
        position = reference.copy()
        position[held, 0] += 1e-3 * t * reference[held, 1]
        spec.drive_held(position, np.full(n, 1e-4 * t))
        spec.advance(1)


def _reference(spec):
    out = np.empty_like(spec.state.position)
    out[spec.order] = spec.state.position
    return out


def _snapshot(spec):
    return dict(spec.checkpoint_arrays(), forces=spec.disc_forces(), reaction=spec.plate_reaction(),
                plate=np.array(spec.plate_position()))


def test_restored_footing_specimen_repeats_the_straight_run(tmp_path):
    straight, held = _scene()
    reference = _reference(straight)
    _drive(straight, held, reference, 300)
    path = tmp_path / "spec.npz"
    straight.save(path, phase=np.array(1))
    _drive(straight, held, reference, 300)
    fresh, _ = _scene()
    with np.load(path, allow_pickle=False) as data:
        assert int(data["phase"]) == 1
        back = Specimen.restored(data, fresh.law, fresh.options)
    _drive(back, held, reference, 300)
    a, b = _snapshot(straight), _snapshot(back)
    assert a["reaction"][1] < 0.0 and np.count_nonzero(a["engine_plate_fs"]) > 0     # a loaded rough plate
    assert np.count_nonzero(a["engine_held"]) > 0 and a["engine_mass_damping"] == 25.0
    for key in a:
        assert np.array_equal(a[key], b[key]), key


def test_restored_refuses_another_mass_damping(tmp_path):
    spec, _ = _scene()
    path = tmp_path / "spec.npz"
    spec.save(path)
    with np.load(path, allow_pickle=False) as data, pytest.raises(InputError, match="mass damping 25"):
        Specimen.restored(data, spec.law, spec.options.with_(mass_damping=10.0))
