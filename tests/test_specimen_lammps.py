"""The LAMMPS peer of the bounded specimen: the writer's law mapping against the closed-form
collision of 004 Table 7.1 (dns-spec A3 / Part C K1), and a small specimen written, run and
read back (ids, radii, masses, rotations, wall forces). Skipped when LAMMPS is not installed."""
import math
import shutil

import numpy as np
import pytest

from demcell.contact_law import ContactLaw
from demcell.errors import InputError
from demcell.specimen import lammps as L
from demcell.specimen.specimens import thesis_lattice

pytestmark = [pytest.mark.serial,
              pytest.mark.skipif(shutil.which("lmp") is None,
                                 reason="LAMMPS is not installed (no 'lmp' on PATH; Debian package lammps)")]

#: 004 Table 7.1: r = 1 m, m = pi kg per m depth, E_n = 1e4 N/m, D_n = 100 N s/m
RADIUS, MASS, KN, DN = 1.0, math.pi, 1.0e4, 100.0


def collision_closed_form(clipped):
    """Duration [s] and restitution of a head-on disc-disc collision of the linear
    spring-dashpot (m_eff = m/2), contact ending at zero overlap (unclipped) or at zero force
    (clipped: Schwager and Poeschel 2007)."""
    m_eff = MASS / 2.0
    beta = DN / (2.0 * m_eff)
    omega = math.sqrt(KN / m_eff - beta ** 2)
    if not clipped:
        t_c = math.pi / omega
        return t_c, math.exp(-beta * t_c)
    t_c = (math.pi - math.atan2(2.0 * beta * omega, omega ** 2 - beta ** 2)) / omega
    return t_c, math.exp(-beta * t_c) * ((beta / omega) * math.sin(omega * t_c) - math.cos(omega * t_c))


def two_disc_collision(tmp_path, clipped, dt=1.0e-5):
    """Two Table 7.1 discs meeting head-on at 2 m/s (just touching at t = 0); contact
    duration from the steps with a repulsive force (clipped: the overlap outlives the force,
    the discs part at constant speed once it vanishes; unclipped: the force turns attractive
    before the overlap closes, so the steps with overlap) and restitution from the final
    velocities."""
    law = L.lammps_law(ContactLaw(kn=KN, ks=0.0, friction=0.0), MASS / 2.0, normal_dashpot=DN, clip_normal=clipped)
    walls = L.LammpsWalls(position=(-10.0, 10.0, 0.0, 0.0))
    position = np.array([[-RADIUS, 0.0], [RADIUS, 0.0]])
    n_steps = int(round(0.06 / dt))
    L.write_lammps_input(tmp_path, position, np.full(2, RADIUS), np.full(2, MASS), law, walls, dt, n_steps, 1,
                         velocity=np.array([[1.0, 0.0], [-1.0, 0.0]]), thermo_every=n_steps)
    run = L.run_lammps(tmp_path)
    d = run["dump"]
    gap = d["position"][:, 1, 0] - d["position"][:, 0, 0]
    pushed = d["force"][:, 1, 0] > 0.0 if clipped else gap < 2.0 * RADIUS
    duration = np.count_nonzero(pushed) * dt
    restitution = (d["velocity"][-1, 1, 0] - d["velocity"][-1, 0, 0]) / 2.0
    return duration, restitution, d


def test_table_7_1_mapping():
    """D_n = 100 N s/m is gamma_n = D_n / m_eff between discs (m_eff = m/2) and D_n / m against
    a wall; a damping ratio xi gives the same dashpot (xi_n = 0.399 of dns-spec A2)."""
    law = ContactLaw(kn=KN, ks=100.0, friction=0.8)
    ll = L.lammps_law(law, MASS / 2.0, normal_dashpot=DN)
    assert ll.gamma_n == pytest.approx(DN / (MASS / 2.0), rel=1e-15)
    assert ll.wall_gamma_n == pytest.approx(DN / MASS, rel=1e-15)
    assert (ll.kn, ll.kt, ll.friction, ll.gamma_t, ll.wall_kt, ll.wall_friction) == (KN, 100.0, 0.8, 0.0, 0.0, 0.0)
    assert ll.limit_damping
    xi = DN / (2.0 * math.sqrt(MASS / 2.0 * KN))
    assert xi == pytest.approx(0.399, abs=1e-3)
    by_ratio = L.lammps_law(law.with_(normal_damping=xi), MASS / 2.0)
    assert by_ratio.gamma_n == pytest.approx(ll.gamma_n, rel=1e-14)
    # the wall's dashpot coefficient is the disc-disc one, also from a ratio (004 eq. 7.43)
    assert by_ratio.wall_gamma_n == pytest.approx(ll.wall_gamma_n, rel=1e-14)


@pytest.mark.parametrize("clipped", [False, True])
def test_collision_matches_closed_form(tmp_path, clipped):
    """LAMMPS's normal force is unclipped by default (the dashpot pulls before the overlap
    closes: 0.04294 s, e = 0.2549) and clipped at zero with limit_damping (0.03172 s, 0.3643)."""
    t_c, e = collision_closed_form(clipped)
    assert (t_c, e) == ((pytest.approx(0.03172, abs=1e-5), pytest.approx(0.3643, abs=1e-4)) if clipped else
                        (pytest.approx(0.04294, abs=1e-5), pytest.approx(0.2549, abs=1e-4)))
    duration, restitution, d = two_disc_collision(tmp_path, clipped)
    assert duration == pytest.approx(t_c, abs=2.0e-5)
    assert restitution == pytest.approx(e, rel=2.0e-3)
    # LAMMPS's 2D mass is our mass per unit depth (the data file's density is per sphere volume)
    np.testing.assert_allclose(d["mass"], MASS, rtol=1e-15)


def test_small_specimen_round_trip(tmp_path):
    """240 Table 7.1 discs on the triangular lattice between platens closing at 0.03 m/s, 200
    steps: the dump gives back our ids, radii and masses, finite positions, the platens' forces
    (bottom pushes up, top down, equal in the mean) at their prescribed positions, and the
    rotation rebuilt from 20-step dumps equals the one from every-step dumps."""
    discs = thesis_lattice(nx=12, ny=20, perturbation=0.02, seed=3)
    law = L.lammps_law(ContactLaw(kn=KN, ks=100.0, friction=0.8), MASS / 2.0, normal_dashpot=DN)
    box = discs.box
    walls = L.LammpsWalls(position=(box[2], box[3], box[0], box[1]), velocity=(0.3, -0.3, 0.0, 0.0),
                          active=(True, True, True, True))
    dt, n_steps = 2.0e-3, 200
    runs = {}
    for every in (1, 20):
        directory = tmp_path / f"every{every}"
        paths = L.write_lammps_input(directory, discs.position, discs.radius, discs.mass, law, walls, dt, n_steps,
                                     every, thermo_every=n_steps)
        runs[every] = L.run_lammps(directory, wall_order=paths["wall_order"])
    d, w = runs[20]["dump"], runs[20]["walls"]
    n = discs.n_discs
    assert d["position"].shape == (n_steps // 20 + 1, n, 2)
    assert np.all(np.isfinite(d["position"])) and np.all(np.isfinite(d["rotation"]))
    np.testing.assert_array_equal(d["id"], np.arange(1, n + 1))
    np.testing.assert_array_equal(d["radius"], discs.radius)
    np.testing.assert_allclose(d["mass"], discs.mass, rtol=1e-15)
    np.testing.assert_array_equal(d["position"][0], discs.position)
    # the platens moved as prescribed and pushed the discs
    assert w["timestep"].tolist() == list(range(n_steps + 1))
    moved = np.array(walls.position) + np.array(walls.velocity) * n_steps * dt
    np.testing.assert_allclose(w["wall_position"][-1], moved, rtol=0, atol=1e-12)
    bottom, top = w["wall_force"][:, 0, 1], w["wall_force"][:, 1, 1]
    assert bottom[-1] > 0.0 and top[-1] < 0.0 and w["contacts"][-1, 0] >= 6
    assert np.mean(bottom[-50:]) == pytest.approx(-np.mean(top[-50:]), rel=0.2)
    # the side walls are there, and nothing pushes them along y (smooth)
    np.testing.assert_array_equal(w["wall_force"][:, 2:, 1], 0.0)
    # wall force history: same on both runs (the dump interval changes only the output)
    np.testing.assert_array_equal(runs[1]["walls"]["wall_force"], w["wall_force"])
    every_step = runs[1]["dump"]
    np.testing.assert_array_equal(every_step["position"][::20], d["position"])
    assert np.max(np.abs(d["rotation"][-1])) > 1e-6
    np.testing.assert_allclose(d["rotation"], every_step["rotation"][::20], rtol=0,
                               atol=1e-12 * np.max(np.abs(d["rotation"])) + 1e-15)
    log = runs[20]["log"]
    assert (log["steps"], log["atoms"], log["procs"]) == (n_steps, n, 1)


def test_periodic_specimen_writes_and_runs(tmp_path):
    """lateral="periodic": x periodic over the box width, platens only; discs leaving through
    a side come back through the other, positions are unwrapped."""
    discs = thesis_lattice(nx=10, ny=8)
    law = L.lammps_law(ContactLaw(kn=KN, ks=100.0, friction=0.8), MASS / 2.0, normal_dashpot=DN)
    box = discs.box
    walls = L.LammpsWalls(position=(box[2], box[3], box[0], box[1]), velocity=(0.3, -0.3, 0.0, 0.0))
    paths = L.write_lammps_input(tmp_path, discs.position, discs.radius, discs.mass, law, walls, 2.0e-3, 100, 50,
                                 lateral="periodic", period=2.0 * 10 * RADIUS)
    assert "boundary p f p" in open(paths["input"]).read()
    run = L.run_lammps(tmp_path)
    assert run["dump"]["position"].shape == (3, discs.n_discs, 2)
    # the odd rows' last disc sits on the period's end: written at x = 0 with image flag 1
    np.testing.assert_allclose(run["dump"]["position"][0], discs.position, rtol=0, atol=1e-12)
    assert run["walls"]["wall_force"][-1, 1, 1] < 0.0


def test_bad_input_refused_in_one_line(tmp_path):
    law = L.lammps_law(ContactLaw(kn=KN, ks=0.0, friction=0.0), 1.0)
    walls = L.LammpsWalls(position=(-5.0, 5.0, 0.0, 0.0))
    one = np.zeros((1, 2))
    with pytest.raises(InputError, match=r"radius\[0\] must be > 0"):
        L.write_lammps_input(tmp_path, one, [0.0], [1.0], law, walls, 1e-3, 10, 1)
    with pytest.raises(InputError, match="dt must be > 0"):
        L.write_lammps_input(tmp_path, one, [1.0], [1.0], law, walls, -1.0, 10, 1)
    with pytest.raises(InputError, match="top platen must lie above"):
        L.LammpsWalls(position=(5.0, -5.0, 0.0, 0.0))
    with pytest.raises(InputError, match="rolling resistance"):
        L.lammps_law(ContactLaw(rolling_stiffness=1.0), 1.0)
    with pytest.raises(L.LammpsError, match="LAMMPS is not installed"):
        L.lammps_command(executable="lmp-not-here")
    with pytest.raises(InputError, match="no LAMMPS dump snapshot"):
        (tmp_path / "empty.dump").write_text("")
        L.read_lammps_dump(tmp_path / "empty.dump")


def test_failed_run_names_lammps_error(tmp_path):
    law = L.lammps_law(ContactLaw(kn=KN, ks=0.0, friction=0.0), 1.0)
    walls = L.LammpsWalls(position=(-5.0, 5.0, 0.0, 0.0))
    paths = L.write_lammps_input(tmp_path, np.zeros((1, 2)), [1.0], [1.0], law, walls, 1e-3, 10, 1)
    with open(paths["input"], "a") as f:
        f.write("not_a_lammps_command 1\n")
    with pytest.raises(L.LammpsError, match="ERROR"):
        L.run_lammps(tmp_path)


def test_contact_forces_balance_and_feed_the_rev_fields(tmp_path):
    """The pair dump in demcell's convention (fn rebuilt with the step's half-step velocities,
    fs from LAMMPS's shear history): every disc off the walls is in force balance with its
    contacts (the dump's total force) to round-off, the torques are those of fs with LAMMPS's
    arm r, the remainder of the wall discs sums to the platens' forces; the snapshot goes
    through the REV homogenisation."""
    from demcell.specimen.rev import rev_fields
    discs = thesis_lattice(nx=12, ny=20, perturbation=0.02, seed=3)
    law = L.lammps_law(ContactLaw(kn=KN, ks=100.0, friction=0.8), MASS / 2.0, normal_dashpot=DN)
    b = discs.box
    walls = L.LammpsWalls(position=(b[2], b[3], b[0], b[1]), velocity=(0.3, -0.3, 0.0, 0.0),
                          active=(True, True, True, True))
    dt = 2.0e-3
    L.write_lammps_input(tmp_path, discs.position, discs.radius, discs.mass, law, walls, dt, 400, 20, contacts=True,
                         thermo_every=400)
    run = L.run_lammps(tmp_path)
    d, c, w = run["dump"], run["contacts"], run["walls"]
    r = d["radius"]
    sliding_seen = 0
    for k in range(1, len(d["timestep"])):
        f = L.lammps_contact_forces(d, c, k, law, dt)
        step = int(d["timestep"][k])
        x, wp = d["position"][k], w["wall_position"][step]
        on_wall = ((x[:, 1] - r < wp[0]) | (x[:, 1] + r > wp[1]) | (x[:, 0] - r < wp[2]) | (x[:, 0] + r > wp[3]))
        scale = np.max(np.abs(f["fn"]))
        assert np.all(f["fn"] >= 0.0) and np.all(f["pair_i"] < f["pair_j"])
        assert np.max(np.abs(f["external_force"][~on_wall])) < 1e-11 * scale
        np.testing.assert_allclose(f["external_force"][on_wall].sum(axis=0), w["wall_force"][step].sum(axis=0),
                                   rtol=1e-12, atol=1e-11 * scale)
        torque = np.zeros(r.size)
        np.add.at(torque, f["pair_i"], -r[f["pair_i"]] * f["fs"])
        np.add.at(torque, f["pair_j"], -r[f["pair_j"]] * f["fs"])
        np.testing.assert_allclose(torque, d["torque"][k], rtol=0, atol=1e-11 * scale)
        assert np.all(np.abs(f["fs"]) <= 0.8 * f["fn"] * (1 + 1e-12))
        sliding_seen += int(np.count_nonzero(np.abs(f["fs"]) >= 0.8 * f["fn"] * (1 - 1e-9)))
    assert sliding_seen > 0
    k = len(d["timestep"]) - 1
    f = L.lammps_contact_forces(d, c, k, law, dt)
    fields = rev_fields(d["position"][k], r, d["position"][k] - d["position"][0], d["rotation"][k], f["pair_i"],
                        f["pair_j"], f["fn"], f["fs"], external_force=f["external_force"], excluded=on_wall)
    assert fields.valid.any() and np.all(np.isfinite(fields.txx[fields.valid]))


@pytest.mark.skipif(shutil.which("mpirun") is None, reason="mpirun is not installed (Debian openmpi-bin)")
def test_two_ranks_give_the_serial_run(tmp_path):
    """The same input under mpirun -n 2 (the spatial decomposition changes only the order of
    the sums): the discs come back whole and the platen forces agree with the serial run to
    round-off over 200 steps of the Table 7.1 law."""
    discs = thesis_lattice(nx=12, ny=20)
    law = L.lammps_law(ContactLaw(kn=KN, ks=100.0, friction=0.8), MASS / 2.0, normal_dashpot=DN)
    b = discs.box
    walls = L.LammpsWalls(position=(b[2], b[3], b[0], b[1]), velocity=(0.3, -0.3, 0.0, 0.0),
                          active=(True, True, True, True))
    runs = {}
    for ranks in (1, 2):
        L.write_lammps_input(tmp_path / str(ranks), discs.position, discs.radius, discs.mass, law, walls, 2.0e-3,
                             200, 100, thermo_every=200)
        runs[ranks] = L.run_lammps(tmp_path / str(ranks), ranks=ranks)
    assert runs[2]["log"]["procs"] == 2
    np.testing.assert_array_equal(runs[2]["dump"]["id"], np.arange(1, discs.n_discs + 1))
    f1, f2 = runs[1]["walls"]["wall_force"], runs[2]["walls"]["wall_force"]
    np.testing.assert_allclose(f2, f1, rtol=0, atol=1e-9 * np.max(np.abs(f1)))
    np.testing.assert_allclose(runs[2]["dump"]["position"], runs[1]["dump"]["position"], rtol=0, atol=1e-9)


def test_state_of_the_engine_written_as_is(tmp_path):
    """``write_lammps_state``: a SpecimenState with its law and options (Table 7.1 dashpot,
    clipped) becomes the same LAMMPS run as the explicit call; a membrane specimen, which
    LAMMPS cannot run, is refused in one line."""
    from demcell.specimen.state import SpecimenOptions, SpecimenState
    discs = thesis_lattice(nx=6, ny=6)
    state = SpecimenState.from_specimen_discs(discs, lateral="walls")
    state.wall_velocity[:] = (0.3, -0.3, 0.0, 0.0)
    options = SpecimenOptions(dt=2.0e-3, normal_dashpot=DN, tangential_dashpot=0.0)
    law = ContactLaw(kn=KN, ks=100.0, friction=0.8)
    paths = L.write_lammps_state(tmp_path, state, law, options, 100, 50)
    script = open(paths["input"]).read()
    assert f"gran/hooke/history 10000.0 100.0 {DN / (MASS / 2.0)!r} 0.0 0.8 0 limit_damping" in script
    assert f"wall/gran/region hooke/history 10000.0 0.0 {DN / MASS!r} 0.0 0.0 0 limit_damping" in script
    run = L.run_lammps(tmp_path)
    np.testing.assert_allclose(run["walls"]["wall_position"][-1], state.wall_position + state.wall_velocity * 0.2,
                               rtol=0, atol=1e-12)
    with pytest.raises(InputError, match="no membrane"):
        L.write_lammps_state(tmp_path, state, law, options.with_(lateral="membrane"), 10, 10)


def test_moving_platen_hits_a_disc_with_the_wall_restitution(tmp_path):
    """A disc at rest hit by the bottom platen moving up at 1 m/s (unclipped Table 7.1
    dashpot, m_eff = m against a wall): it leaves at (1 + e) m/s with e = 0.3970 and the
    contact lasts 0.05804 s (dns-spec A3), so the wall's own velocity enters the dashpot."""
    law = L.lammps_law(ContactLaw(kn=KN, ks=0.0, friction=0.0), MASS / 2.0, normal_dashpot=DN, clip_normal=False)
    beta = DN / (2.0 * MASS)
    omega = math.sqrt(KN / MASS - beta ** 2)
    t_c = math.pi / omega
    e = math.exp(-beta * t_c)
    assert (t_c, e) == (pytest.approx(0.05804, abs=1e-5), pytest.approx(0.3970, abs=1e-4))
    dt = 1.0e-5
    walls = L.LammpsWalls(position=(-RADIUS, 10.0, 0.0, 0.0), velocity=(1.0, 0.0, 0.0, 0.0))
    L.write_lammps_input(tmp_path, np.zeros((1, 2)), [RADIUS], [MASS], law, walls, dt, 8000, 1, thermo_every=8000)
    run = L.run_lammps(tmp_path)
    pushed = np.count_nonzero(run["walls"]["contacts"][:, 0]) * dt
    assert pushed == pytest.approx(t_c, abs=2.0e-5)
    assert run["dump"]["velocity"][-1, 0, 1] == pytest.approx(1.0 + e, rel=1e-3)


@pytest.mark.parametrize("case", ["undamped", "table71"])
def test_engine_and_lammps_give_the_same_platen_forces(tmp_path, case):
    """The same 200 discs, law and platens (closing at 0.03 m/s) in demcell's engine and in
    LAMMPS, 300 steps: without dashpots or friction the forces depend on the positions only
    and velocity Verlet and the leapfrog are the same scheme, so the platen forces agree to
    round-off: the bottom platen (at y = 0) to 1e-12 of the force; the top one (at y = 35 m)
    to kn times the round-off of its position, which demcell sums step by step (y += v dt)
    and LAMMPS evaluates as y0 + v t (300 x 1e-16 x 35 m x kn ~ 1e-8 N). With the Table 7.1
    law (friction, clipped dashpot) they differ by the moment arms (LAMMPS r, demcell
    r - overlap/2) and the projected shear: below 1e-6 of the force."""
    import warnings

    from demcell.specimen import Specimen, SpecimenOptions, SpecimenState, WallControl
    if case == "undamped":
        law, opts, perturbation, tol = ContactLaw(kn=KN, ks=0.0, friction=0.0), {}, 0.02, 1e-12
    else:
        law, perturbation, tol = ContactLaw(kn=KN, ks=100.0, friction=0.8), 0.0, 1e-6
        opts = dict(normal_dashpot=DN, tangential_dashpot=0.0)
    discs = thesis_lattice(nx=10, ny=20, perturbation=perturbation, seed=1)
    dt, n_steps, speed = 2.0e-3, 300, 0.03
    options = SpecimenOptions(dt=dt, lateral="walls", boundary_interval=1, **opts)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")      # the inertial number of unloaded platens is infinite
        spec = Specimen(SpecimenState.from_specimen_discs(discs, lateral="walls"), law, options)
        spec.set_walls(bottom=WallControl(velocity=speed), top=WallControl(velocity=-speed))
        forces = []
        spec.run(n_steps=n_steps, on_interval=lambda s, m: forces.append(m.wall_force[:2, 1].copy()))
    f_e = np.array(forces)
    m = float(np.median(discs.mass))
    llaw = L.lammps_law(law, 0.5 * m, opts.get("normal_dashpot"), opts.get("tangential_dashpot"), True, wall_mass=m)
    b = discs.box
    walls = L.LammpsWalls(position=(b[2], b[3], b[0], b[1]), velocity=(speed, -speed, 0.0, 0.0),
                          active=(True, True, True, True))
    L.write_lammps_input(tmp_path, discs.position, discs.radius, discs.mass, llaw, walls, dt, n_steps, n_steps,
                         thermo_every=n_steps)
    run = L.run_lammps(tmp_path)
    f_l = run["walls"]["wall_force"][:n_steps, :2, 1]
    scale = np.max(np.abs(f_e))
    assert scale > 1.0
    wall_roundoff = KN * n_steps * np.finfo(float).eps * abs(b[3])
    np.testing.assert_allclose(f_l[:, 0], f_e[:, 0], rtol=0, atol=tol * scale)
    np.testing.assert_allclose(f_l[:, 1], f_e[:, 1], rtol=0, atol=tol * scale + 10.0 * wall_roundoff)
    x_e = np.empty_like(spec.state.position)
    x_e[spec.order] = spec.state.position
    np.testing.assert_allclose(run["dump"]["position"][-1], x_e, rtol=0, atol=1e3 * tol * RADIUS)
