"""What the bridging-scale coupler (003) needs of the specimen engine: mass damping (003 eqs.
9, 29), held discs driven onto prescribed targets (eq. 17), the net force on every disc
(N^T F, N_V^T F_V) and the cheap stepping path."""
import math

import numpy as np
import pytest

from demcell import ContactLaw
from demcell.errors import InputError
from demcell.specimen import Specimen, SpecimenOptions, SpecimenState

pytestmark = pytest.mark.serial

# 003 Table 1 (kn, ks [N/m], mu, k_omega [N m/rad]); r = 0.05 m discs of 2600 kg/m^3
LAW = ContactLaw(kn=2.5e8, ks=5.0e7, friction=0.5, rolling_stiffness=700.0, rolling_friction=0.02)
R, RHO = 0.05, 2600.0


def free_discs(position, radius=R):
    position = np.asarray(position, float)
    r = np.full(position.shape[0], radius)
    m = RHO * np.pi * r ** 2
    return position, r, m, 0.5 * m * r ** 2


def lattice_block(nx=6, ny=5, squeeze=1e-4):
    """A square block of discs slightly overlapping (spacing 2 r (1 - squeeze)), no walls."""
    x, y = np.meshgrid(np.arange(nx), np.arange(ny))
    pos = 2.0 * R * (1.0 - squeeze) * np.column_stack([x.ravel(), y.ravel()]).astype(float)
    pos += 1e-3 * R * np.random.default_rng(3).standard_normal(pos.shape)
    return free_discs(pos)


def test_mass_damping_closed_form():
    """A free disc's velocity and spin decay by (1 - c dt/2)/(1 + c dt/2) per step (the
    trapezoidal eq. 29), which is exp(-c t) to O((c dt)^3) per step."""
    pos, r, m, inertia = free_discs([[0.0, 0.0]])
    state = SpecimenState.from_discs(pos, r, m, inertia, box=(-1, 1, -1, 1), lateral="none")
    state.velocity[0] = [1.0, -2.0]
    state.spin[0] = 3.0
    c, dt, n = 50.0, 1e-4, 400
    spec = Specimen(state, LAW, SpecimenOptions(dt=dt, mass_damping=c, lateral="none", reorder=False))
    spec.advance(n)
    factor = ((1.0 - 0.5 * c * dt) / (1.0 + 0.5 * c * dt)) ** n
    np.testing.assert_allclose(spec.state.velocity[0], [factor, -2.0 * factor], rtol=1e-12)
    assert spec.state.spin[0] == pytest.approx(3.0 * factor, rel=1e-12)
    # against the continuous decay: relative error n (c dt)^3 / 12 = 5e-6 here
    assert factor == pytest.approx(math.exp(-c * n * dt), rel=1e-5)
    # the distance travelled is the sum of the half-step velocities times dt
    travelled = dt * sum(((1.0 - 0.5 * c * dt) / (1.0 + 0.5 * c * dt)) ** k for k in range(1, n + 1))
    assert spec.state.position[0, 0] == pytest.approx(travelled, rel=1e-12)


def test_mass_damping_default_is_off_and_checked():
    assert SpecimenOptions().mass_damping == 0.0
    with pytest.raises(InputError, match="mass_damping"):
        SpecimenOptions(dt=1e-3, mass_damping=2.5e3)
    with pytest.raises(InputError, match="mass_damping"):
        SpecimenOptions(mass_damping=-1.0)


def test_drive_held_reaches_targets_and_forces_balance():
    """Held discs land exactly on their targets after the next step (original order, with
    the Morton renumbering on); the net forces of a closed system (no wall, no plate) sum to
    zero, and so do the moments about the origin (action = reaction, 003 eq. 9)."""
    pos, r, m, inertia = lattice_block()
    n = pos.shape[0]
    state = SpecimenState.from_discs(pos, r, m, inertia, box=(-1, 1, -1, 1), lateral="none")
    spec = Specimen(state, LAW, SpecimenOptions(dt=2e-5, lateral="none", reorder=True))
    assert not np.all(spec.order == np.arange(n))
    held = np.zeros(n, bool)
    held[:6] = True                         # the bottom row
    spec.hold(held)
    rng = np.random.default_rng(0)
    for _ in range(5):
        x = spec.state.position[np.argsort(spec.order)].copy()
        theta = spec.state.rotation[np.argsort(spec.order)].copy()
        x[held] += 1e-4 * R * rng.standard_normal((6, 2))
        theta[held] += 1e-3 * rng.standard_normal(6)
        spec.drive_held(x, theta)
        spec.advance(1)
        inv = np.argsort(spec.order)
        np.testing.assert_allclose(spec.state.position[inv][held], x[held], rtol=0, atol=1e-15)
        np.testing.assert_allclose(spec.state.rotation[inv][held], theta[held], rtol=0, atol=1e-15)
    spec.advance(20)
    f = spec.disc_forces()
    inv = np.argsort(spec.order)
    # the forces act at the positions of the step's start
    x = (spec.state.position - spec.options.dt * spec.state.velocity)[inv]
    assert f.shape == (n, 3)
    scale = np.abs(f[:, :2]).max()
    assert scale > 1.0                      # the block is squeezed: real forces
    np.testing.assert_allclose(f[:, :2].sum(axis=0), 0.0, atol=1e-10 * scale * n)
    torque = f[:, 2] + x[:, 0] * f[:, 1] - x[:, 1] * f[:, 0]
    assert abs(torque.sum()) < 1e-10 * scale * R * n
    # the held discs carry forces too (the reactions the coupler needs)
    assert np.abs(f[held, :2]).max() > 0.0


def test_disc_forces_match_pair_sum():
    """disc_forces = the pair forces of the list summed per disc (independent of the
    kernel's gather): force on j is +f, on i -f."""
    pos, r, m, inertia = lattice_block(4, 3)
    state = SpecimenState.from_discs(pos, r, m, inertia, box=(-1, 1, -1, 1), lateral="none")
    spec = Specimen(state, LAW, SpecimenOptions(dt=2e-5, lateral="none", reorder=False))
    spec.advance(1)
    st = spec.state
    f = np.zeros((st.n_discs, 2))
    for k in np.flatnonzero(st.touching):
        i, j = st.pair_i[k], st.pair_j[k]
        d = st.position[j] - st.position[i]
        # the forces are those of the step's start positions: undo the step's motion
        d -= (st.velocity[j] - st.velocity[i]) * spec.options.dt
        nrm = d / np.linalg.norm(d)
        t = np.array([-nrm[1], nrm[0]])
        fk = st.fn[k] * nrm + st.fs[k] * t
        f[j] += fk
        f[i] -= fk
    np.testing.assert_allclose(spec.disc_forces()[:, :2], f, rtol=1e-9, atol=1e-9 * np.abs(f).max())


def test_advance_equals_run():
    """advance(n) and run(n_steps=n) give the same state bit for bit (same kernel)."""
    out = []
    for path in ("run", "advance"):
        pos, r, m, inertia = lattice_block()
        state = SpecimenState.from_discs(pos, r, m, inertia, box=(-1, 1, -1, 1), lateral="none")
        spec = Specimen(state, LAW, SpecimenOptions(dt=2e-5, lateral="none", mass_damping=10.0))
        if path == "run":
            spec.run(n_steps=300)
        else:
            spec.advance(300)
        out.append(spec.state.position.copy())
        assert spec.state.step == 300
    assert np.array_equal(out[0], out[1])


def test_drive_held_needs_held_discs():
    pos, r, m, inertia = free_discs([[0.0, 0.0]])
    state = SpecimenState.from_discs(pos, r, m, inertia, box=(-1, 1, -1, 1), lateral="none")
    spec = Specimen(state, LAW, SpecimenOptions(dt=1e-5, lateral="none"))
    with pytest.raises(InputError, match="held"):
        spec.drive_held(pos, np.zeros(1))
