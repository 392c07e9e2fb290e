"""The held discs' path inside the kernel (003 eqs. 25-26: one engine call per coarse step),
the forces at the current configuration without committing the history (003 eq. 33 needs
F_int at q^{n+1}) and the option to drop the contacts between two held discs."""
import numpy as np
import pytest

from demcell import ContactLaw
from demcell.errors import InputError
from demcell.specimen import Specimen, SpecimenOptions, SpecimenState

from tests.test_specimen_coupling import LAW, R, lattice_block

pytestmark = pytest.mark.serial

#: a law whose forces depend on the positions only (no tangential spring, no dashpot, no
#: rolling): the held discs' velocity cannot enter a force
POSITIONAL = ContactLaw(kn=2.5e8, ks=0.0, friction=0.5)
DT = 2e-5


def squeezed(law, reorder=True, mass_damping=0.0):
    pos, r, m, inertia = lattice_block(squeeze=3e-4)
    state = SpecimenState.from_discs(pos, r, m, inertia, box=(-1, 1, -1, 1), lateral="none")
    spec = Specimen(state, law, SpecimenOptions(dt=DT, lateral="none", reorder=reorder, mass_damping=mass_damping))
    held = np.zeros(state.n_discs, bool)
    held[:12] = True                      # the two bottom rows: held-held contacts too
    spec.hold(held)
    return spec, held


def original(spec, array):
    out = np.empty_like(array)
    out[spec.order] = array
    return out


def path_data(spec, rng):
    n = spec.state.n_discs
    start = np.zeros((n, 3))
    start[:, :2] = original(spec, spec.state.position) + 1e-5 * R * rng.standard_normal((n, 2))
    start[:, 2] = original(spec, spec.state.rotation)
    velocity = np.column_stack([0.01 * rng.standard_normal((n, 2)), 0.1 * rng.standard_normal(n)])
    acceleration = np.column_stack([50.0 * rng.standard_normal((n, 2)), 500.0 * rng.standard_normal(n)])
    return start, velocity, acceleration


def on_path(start, velocity, acceleration, t):
    return start + t * velocity + 0.5 * t * t * acceleration


def test_held_discs_follow_the_path_to_round_off():
    spec, held = squeezed(LAW)
    rng = np.random.default_rng(1)
    for m in (1, 5, 7):
        start, velocity, acceleration = path_data(spec, rng)
        spec.follow_held_path(m, start, velocity, acceleration)
        end = on_path(start, velocity, acceleration, m * DT)
        np.testing.assert_allclose(original(spec, spec.state.position)[held], end[held, :2], rtol=0, atol=1e-15)
        np.testing.assert_allclose(original(spec, spec.state.rotation)[held], end[held, 2], rtol=0, atol=1e-15)
        if m == 1:
            continue          # the first step absorbs the jump to the (perturbed) start
        # the last half-step velocity is the path's at the step's middle, v0 + a (m - 1/2) dt
        mid = velocity + (m - 0.5) * DT * acceleration
        np.testing.assert_allclose(original(spec, spec.state.velocity)[held], mid[held, :2], rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(original(spec, spec.state.spin)[held], mid[held, 2], rtol=1e-9, atol=1e-10)
    assert spec.state.step == 13


def test_one_call_equals_drive_held_and_advance_per_step():
    """With a law that reads positions only, one call of m steps is m calls of drive_held +
    advance(1) to round-off (with a tangential spring they differ by design: the old loop
    showed the contact law the held discs' velocity of the step ahead)."""
    rng = np.random.default_rng(2)
    a, held = squeezed(POSITIONAL)
    b, _ = squeezed(POSITIONAL)
    m = 6
    for _ in range(3):
        start, velocity, acceleration = path_data(a, rng)
        a.follow_held_path(m, start, velocity, acceleration)
        for j in range(1, m + 1):
            x = on_path(start, velocity, acceleration, j * DT)
            b.drive_held(x[:, :2], x[:, 2])
            b.advance(1)
    scale = np.abs(b.state.position).max()
    np.testing.assert_allclose(a.state.position, b.state.position, rtol=0, atol=1e-14 * scale)
    np.testing.assert_allclose(a.state.velocity, b.state.velocity, rtol=0, atol=1e-9 * np.abs(b.state.velocity).max())
    f = np.abs(b.disc_forces()).max()
    assert f > 1e3
    np.testing.assert_allclose(a.disc_forces(), b.disc_forces(), rtol=0, atol=1e-8 * f)


def test_path_survives_neighbour_rebuilds():
    """A path long enough to stale the neighbour list several times (the kernel returns to
    Python mid-call): the held discs still end on it."""
    spec, held = squeezed(LAW)
    n = spec.state.n_discs
    start = np.zeros((n, 3))
    start[:, :2] = original(spec, spec.state.position)
    velocity = np.zeros((n, 3))
    velocity[:, 0] = 3.0
    acceleration = np.zeros((n, 3))
    acceleration[:, 1] = 100.0
    rebuilds = spec.rebuilds
    steps = 500
    spec.follow_held_path(steps, start, velocity, acceleration)
    assert spec.rebuilds > rebuilds + 2
    end = on_path(start, velocity, acceleration, steps * DT)
    np.testing.assert_allclose(original(spec, spec.state.position)[held], end[held, :2], rtol=0, atol=1e-14)


def test_forces_now_are_the_next_steps_forces_and_commit_nothing():
    spec, held = squeezed(LAW, mass_damping=50.0)
    rng = np.random.default_rng(3)
    start, velocity, acceleration = path_data(spec, rng)
    spec.follow_held_path(4, start, velocity, acceleration)
    st = spec.state
    before = {k: getattr(st, k).copy() for k in ("position", "velocity", "touching", "sliding", "fn", "fs", "mr",
                                                   "external_force", "wall_force")}
    net_before = spec.disc_forces()
    now = spec.forces_now()
    for k, v in before.items():
        assert np.array_equal(getattr(st, k), v), k
    assert np.array_equal(spec.disc_forces(), net_before)
    assert not np.array_equal(now, net_before)          # the configuration moved
    spec.follow_held_path(1, start, velocity, acceleration)
    assert np.array_equal(spec.disc_forces(), now)      # bit for bit: the same sums



STATE_ARRAYS = ("position", "velocity", "rotation", "spin", "touching", "sliding", "fn", "fs", "mr",
                "external_force")


def coupled_steps(keep, seed, n_steps, change_at, change):
    """n_steps coarse steps as the coupler takes them (3 held-path steps, then forces_now(keep))
    with change(spec) after the step change_at; returns (state arrays, forces of each step,
    disc_forces, plate reaction, whether each step took a kept pass)."""
    spec, held = squeezed(LAW, mass_damping=50.0)
    rng = np.random.default_rng(seed)
    taken = []
    take = spec._take_pending_forces
    spec._take_pending_forces = lambda: taken.append(take()) or taken[-1]
    forces = []
    for k in range(n_steps):
        start, velocity, acceleration = path_data(spec, rng)
        spec.follow_held_path(3, start, velocity, acceleration)
        forces.append(spec.forces_now(keep=keep))
        if k == change_at:
            change(spec)
    arrays = {k: getattr(spec.state, k).copy() for k in STATE_ARRAYS}
    return arrays, forces, spec.disc_forces(), spec.plate_reaction(), taken


def assert_same_runs(a, b):
    for k in a[0]:
        assert np.array_equal(a[0][k], b[0][k]), k
    assert all(np.array_equal(x, y) for x, y in zip(a[1], b[1]))
    assert np.array_equal(a[2], b[2]) and np.array_equal(a[3], b[3])


def test_forces_now_kept_for_the_next_step_change_nothing():
    """forces_now(keep=True) (the coupler's end-of-step forces): the next call starts from
    that contact pass instead of repeating it, and the run is the same bit for bit as with
    forces_now() (every state array, the forces, the plate); the pass is dropped when the
    engine changed in between (here a held disc's velocity), and the step then evaluates its
    own forces (still the same run as without keep)."""
    def nudge(spec):
        spec.state.velocity[0, 0] += 1e-3
    plain = coupled_steps(False, 5, 6, 3, nudge)
    kept = coupled_steps(True, 5, 6, 3, nudge)
    assert plain[4] == [False] * 6
    assert kept[4] == [False] + [True] * 3 + [False, True]
    assert_same_runs(plain, kept)


def virtual_pair_forces(state, order, is_virtual):
    """(n, 3) forces and moments, original order, that the contacts BETWEEN two virtual discs
    put on them (demcell.specimen.state's pair convention: force fn n + fs t on j, its
    opposite on i; moments -a_i fs - mr on i, -a_j fs + mr on j)."""
    n = order.size
    out = np.zeros((n, 3))
    virtual_engine = is_virtual[order]
    i, j = state.pair_i, state.pair_j
    both = virtual_engine[i] & virtual_engine[j] & (state.touching != 0)
    if not np.any(both):
        return out
    i, j = i[both], j[both]
    fn, fs, mr = state.fn[both], state.fs[both], state.mr[both]
    branch = state.position[j] - state.position[i]
    dist = np.hypot(branch[:, 0], branch[:, 1])
    nrm = branch / dist[:, None]
    tng = np.column_stack([-nrm[:, 1], nrm[:, 0]])
    force = fn[:, None] * nrm + fs[:, None] * tng
    overlap = state.radius[i] + state.radius[j] - dist
    a_i = state.radius[i] - 0.5 * overlap
    a_j = state.radius[j] - 0.5 * overlap
    engine = np.zeros((n, 3))
    np.add.at(engine[:, 0], j, force[:, 0])
    np.add.at(engine[:, 1], j, force[:, 1])
    np.add.at(engine[:, 0], i, -force[:, 0])
    np.add.at(engine[:, 1], i, -force[:, 1])
    np.add.at(engine[:, 2], i, -a_i * fs - mr)
    np.add.at(engine[:, 2], j, -a_j * fs + mr)
    out[order] = engine
    return out


def test_skip_held_pairs_drops_exactly_their_forces():
    """Skipping the held-held contacts changes nothing for the free discs (held discs ignore
    forces) and removes from disc_forces exactly the held-held pair forces."""
    rng = np.random.default_rng(4)
    a, held = squeezed(LAW)
    b, _ = squeezed(LAW)
    b.set_skip_held_pairs(True)
    for _ in range(3):
        start, velocity, acceleration = path_data(a, rng)
        a.follow_held_path(5, start, velocity, acceleration)
        b.follow_held_path(5, start, velocity, acceleration)
    assert np.array_equal(a.state.position, b.state.position)
    pairs = virtual_pair_forces(a.state, a.order, held)
    assert np.abs(pairs).max() > 1e3
    f = np.abs(a.disc_forces()).max()
    # (virtual_pair_forces takes the branch at the end of the step, the forces its start: 1e-5)
    np.testing.assert_allclose(b.disc_forces(), a.disc_forces() - pairs, rtol=0, atol=1e-5 * f)
    assert np.abs(virtual_pair_forces(b.state, b.order, held)).max() == 0.0


def test_bad_path_refused_before_any_step():
    """A path of the wrong shape, or a non-finite value in a held disc's row, is refused naming
    the array (and the disc), before any step; a non-finite value in a free disc's row is not
    read (free discs follow their forces) and runs."""
    spec, held = squeezed(LAW)
    rng = np.random.default_rng(6)
    start, velocity, acceleration = path_data(spec, rng)
    step = spec.state.step
    with pytest.raises(InputError, match=r"velocity must be an array of numbers of shape"):
        spec.follow_held_path(2, start, velocity[:-1], acceleration)
    bad = acceleration.copy()
    disc = int(np.flatnonzero(held)[3])
    bad[disc, 1] = np.nan
    with pytest.raises(InputError, match=rf"acceleration\[{disc}\] \(a held disc\) must be finite"):
        spec.follow_held_path(2, start, velocity, bad)
    assert spec.state.step == step
    free = int(np.flatnonzero(~held)[0])
    bad = start.copy()
    bad[free, 0] = np.inf
    spec.follow_held_path(2, bad, velocity, acceleration)
    assert spec.state.step == step + 2 and np.isfinite(spec.state.position).all()


def test_kept_pass_dropped_after_a_neighbour_rebuild():
    """A neighbour rebuild between forces_now(keep=True) and the next step (here set_plate,
    which rebuilds the list) replaces the pair arrays: the kept pass is dropped, not copied
    into arrays of another length, and the run is the one without keep bit for bit."""
    def rebuild(spec):
        spec.set_plate(None)
    plain = coupled_steps(False, 7, 4, 1, rebuild)
    kept = coupled_steps(True, 7, 4, 1, rebuild)
    assert plain[4] == [False] * 4
    assert kept[4] == [False, True, False, True]
    assert_same_runs(plain, kept)
