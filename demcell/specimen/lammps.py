"""A bounded disc specimen as a LAMMPS run, and LAMMPS's output read back into arrays.

LAMMPS (Debian ``lammps`` 20220106, GRANULAR package) is the peer engine: the same specimen
and contact law run under MPI on more discs than one machine holds, and its output goes
through demcell's homogenisation (``fields``) like the engine's own.

* ``write_lammps_input``: a data file (atom_style sphere, 2D) and an input script (units si,
  dimension 2, ``pair_style gran/hooke/history``, ``fix nve/sphere disc``, ``fix enforce2d``,
  platens and side walls as ``fix wall/gran/region`` on moving planes, a dump, a wall-force
  history);
  ``lammps_law`` maps a demcell ContactLaw onto it, ``LammpsWalls`` holds the walls,
  ``write_lammps_state`` writes an engine's SpecimenState with its law and options;
* ``read_lammps_dump``, ``read_lammps_walls``, ``read_lammps_log``, ``read_lammps_contacts``:
  the outputs as arrays; ``lammps_contact_forces``: a snapshot's contacts in demcell's pair
  convention (pair_i < pair_j, fn, fs, external_force) for ``rev.rev_fields`` / ``fields``;
* ``run_lammps``: runs ``lmp`` (or ``mpirun -n ranks lmp``) in the directory and reads them.

Units: SI, 2D per unit out-of-plane depth as the rest of demcell (forces N, stiffnesses N/m,
masses kg/m, dashpot coefficients N s/m).

Mass of a disc. LAMMPS reads the per-atom ``density`` of a data file as mass per *volume* of a
sphere even in 2D (20220106: a disc of diameter 2 m and density 1 gets mass 4/3 pi, checked),
so the file holds density = m / (4/3 pi r^3) and LAMMPS's mass equals our mass per unit depth
to round-off (the dump carries it back). Its inertia with ``nve/sphere disc`` is m r^2 / 2 as
ours.

The law, ours -> LAMMPS ``gran/hooke/history kn kt gamma_n gamma_t xmu dampflag``:

* kn [N/m] = ContactLaw.kn (004 eq. 7.4 E_n): LAMMPS's hooke normal force is kn * overlap;
* kt [N/m] = ContactLaw.ks (004 eq. 7.8 E_t). LAMMPS stores the tangential *displacement*
  (shear += v_t dt, then its component along n removed) and the force -kt * shear; ours
  stores the force and adds -ks du_t. In 2D they agree up to the second-order shortening
  of the stored vector when the contact turns (LAMMPS projects, it does not rotate);
* xmu = ContactLaw.friction. LAMMPS's Coulomb limit is xmu |f_n,total| (dashpot included,
  absolute value: 004 eq. 7.11 as written when the force is clipped), ours xmu * kn * overlap
  unless SpecimenOptions.coulomb_on_total_normal;
* gamma_n [1/s]: LAMMPS's normal dashpot force is m_eff gamma_n v_n, m_eff = m_i m_j/(m_i + m_j)
  (m_i against a wall), so gamma_n = D_n / m_eff for a dashpot coefficient D_n [N s/m]
  (004 Table 7.1: 100), and gamma_n = 2 xi_n sqrt(kn / m_eff) for a damping ratio xi_n
  (ContactLaw.normal_damping: c = 2 xi sqrt(m_eff kn)). LAMMPS has one gamma_n for all pairs:
  exact for equal masses, for unequal masses the dashpot of a pair whose m_eff differs from
  the one given is scaled by its m_eff / m_eff(given) (documented approximation);
* gamma_t [1/s] likewise from D_t or xi_t (dampflag 1); LAMMPS puts the tangential dashpot
  inside the Coulomb-limited force, ours adds it only while the contact sticks;
* disc-wall: the same kn and dashpot coefficient D_n as two discs (004 eq. 7.43; from a ratio,
  that of two copies of the disc, as demcell.specimen.walls), so gamma_n,wall = D_n / m_i
  (LAMMPS's m_eff against a wall is m_i); smooth platens (kt = 0, xmu = 0) as 004 unless a
  wall friction is asked for. demcell's frictional wall slips by v.t - r omega with the
  law's ks and no tangential dashpot; LAMMPS's wall/gran the same with its own history;
* clipping: LAMMPS's normal force kn overlap - m_eff gamma_n v_n is NOT clipped by default
  (the dashpot may pull during separation: the unclipped closed form, t_c = 0.04294 s and
  e = 0.2549 for Table 7.1); the ``limit_damping`` keyword clips it at zero (t_c = 0.03172 s,
  e = 0.3643), which is SpecimenOptions.clip_normal = True. Both checked against the closed
  forms in tests/test_specimen_lammps.py.
* moment arms: LAMMPS uses the full radii r_i, r_j for the contact-point velocity and the
  torques, ours a_i = r_i - overlap/2 (a relative difference of overlap / 2r in the moments).

Time integration. LAMMPS's velocity Verlet (v_{n+1/2} = v_n + F_n dt/2m, x_{n+1} = x_n +
v_{n+1/2} dt, F_{n+1} = F(x_{n+1}, v_{n+1/2}), v_{n+1} = v_{n+1/2} + F_{n+1} dt/2m) evaluates
the dashpots with the half-step velocity, so v_{n+3/2} = v_{n+1/2} + F(x_{n+1}, v_{n+1/2}) dt/m:
it is the leapfrog of 004 eqs. 7.15-7.17 (dns-spec A5) step for step, dashpots included; only
the start differs (LAMMPS starts from v_0, the leapfrog from v_{-1/2}: equal when the specimen
starts at rest without forces, else v_0 = v_{-1/2} + F_0 dt / 2m). The dump's velocities and
spins are full-step (v_n); LAMMPS keeps no rotation angle for spheres, so the script averages
omega_z over each dump interval (``fix ave/atom``) and ``read_lammps_dump`` rebuilds the
leapfrog rotation sum_k omega_{k+1/2} dt exactly from it (see ``_rotation_increment``).

Walls: plane regions moving at a constant velocity (``region ... move``) with ``fix
wall/gran/region hooke/history``: the wall velocity enters the dashpot (a disc at rest hit by
a platen at 1 m/s leaves at 1 + e m/s with e the disc-wall restitution 0.3970 of dns-spec A3:
tests/test_specimen_lammps.py).
The force each wall exerts on the discs is the sum of the fix's per-atom contact forces,
written every ``wall_every`` steps. Servo-controlled walls are not built (LAMMPS has no such
fix; a ``fix move`` driven from Python would be one).
"""
import math
import os
import re
import resource
import shutil
import subprocess
import time
from dataclasses import dataclass

import numpy as np

from .. import checks
from ..checks import NON_NEGATIVE, POSITIVE, Range
from ..errors import DemCellError, InputError

#: file names inside a run directory
DATA_FILE = "specimen.data"
INPUT_FILE = "in.specimen"
DUMP_FILE = "specimen.dump"
WALL_FILE = "walls.txt"
LOG_FILE = "log.lammps"
CONTACT_FILE = "contacts.dump"

WALL_NAMES = ("bottom", "top", "left", "right")
LATERAL = ("walls", "periodic")
#: the dump's per-atom columns, in order
DUMP_COLUMNS = ("id", "xu", "yu", "vx", "vy", "omegaz", "fx", "fy", "tqz", "radius", "mass", "f_spin_mean")


class LammpsError(DemCellError, RuntimeError):
    """LAMMPS is missing, or a LAMMPS run failed (the message names LAMMPS's own error)."""


@dataclass(frozen=True)
class LammpsLaw:
    """Parameters of ``pair_style gran/hooke/history`` and of the walls' ``wall/gran/region``.

    kn, kt [N/m]: normal and tangential springs; friction [-]: xmu (Coulomb on the total normal
    force); gamma_n, gamma_t [1/s]: dashpots as rates (force = m_eff gamma v);
    wall_kt [N/m], wall_friction [-], wall_gamma_n, wall_gamma_t [1/s]: the disc-wall contact
    (same kn as the discs); limit_damping: clip the total normal force at >= 0."""
    kn: float
    kt: float = 0.0
    friction: float = 0.0
    gamma_n: float = 0.0
    gamma_t: float = 0.0
    wall_kt: float = 0.0
    wall_friction: float = 0.0
    wall_gamma_n: float = 0.0
    wall_gamma_t: float = 0.0
    limit_damping: bool = True

    def __post_init__(self):
        object.__setattr__(self, "kn", checks.number("LammpsLaw.kn", self.kn, POSITIVE))
        for name in ("kt", "gamma_n", "gamma_t", "wall_kt", "wall_gamma_n", "wall_gamma_t"):
            object.__setattr__(self, name, checks.number(f"LammpsLaw.{name}", getattr(self, name), NON_NEGATIVE))
        # LAMMPS refuses xmu > 1e4: a larger friction is "no sliding" anyway
        for name in ("friction", "wall_friction"):
            value = checks.number(f"LammpsLaw.{name}", getattr(self, name), Range(0.0, infinite=True))
            object.__setattr__(self, name, min(value, 1.0e4))
        if not isinstance(self.limit_damping, (bool, np.bool_)):
            raise InputError(f"LammpsLaw.limit_damping must be True or False, got {self.limit_damping!r}")


def lammps_law(law, mass_eff, normal_dashpot=None, tangential_dashpot=None, clip_normal=True,
               wall_friction=0.0, wall_mass=None):
    """The ``LammpsLaw`` of a demcell ``ContactLaw`` (see the module docstring).

    mass_eff [kg/m]: the m_eff of a disc-disc pair (m/2 for equal discs); wall_mass [kg/m]:
    the m_eff of a disc-wall pair (the disc's mass; None: 2 mass_eff); the wall dashpot
    coefficient is the disc-disc one, c = D_n or 2 xi_n sqrt(mass_eff kn);
    normal_dashpot, tangential_dashpot [N s/m]: D_n, D_t of 004 eqs. 7.4 and 7.8 (the thesis'
    coefficients; None: from the law's damping ratios xi_n, xi_t); the walls get the same
    coefficients (004 eq. 7.43); clip_normal: LAMMPS ``limit_damping``;
    wall_friction [-]: 0 for smooth platens (004), else the walls get ks and this friction."""
    mass_eff = checks.number("mass_eff", mass_eff, POSITIVE)
    wall_mass = 2.0 * mass_eff if wall_mass is None else checks.number("wall_mass", wall_mass, POSITIVE)
    normal_dashpot = checks.optional("normal_dashpot", normal_dashpot, NON_NEGATIVE)
    tangential_dashpot = checks.optional("tangential_dashpot", tangential_dashpot, NON_NEGATIVE)
    wall_friction = checks.number("wall_friction", wall_friction, Range(0.0, infinite=True))
    if law.rolling_stiffness > 0.0 or law.cohesion_normal > 0.0 or law.cohesion_shear > 0.0:
        raise InputError("gran/hooke/history has no rolling resistance and no cohesive bonds: "
                         "use rolling_stiffness = 0 and no cohesion for a LAMMPS run")
    if not law.rotations:
        raise InputError("a LAMMPS run integrates the rotations (fix nve/sphere): use ContactLaw(rotations=True)")
    # dashpot coefficients [N s/m]; a wall has the disc-disc coefficient (004 eq. 7.43), as
    # demcell.specimen.walls (from a ratio: that of two copies of the disc, m_eff = m/2)
    if normal_dashpot is None:
        c_n = 2.0 * law.normal_damping * math.sqrt(mass_eff * law.kn)
    else:
        c_n = normal_dashpot
    if tangential_dashpot is None:
        c_t = 2.0 * law.tangential_damping * math.sqrt(mass_eff * law.ks)
    else:
        c_t = tangential_dashpot
    smooth = wall_friction == 0.0
    return LammpsLaw(kn=law.kn, kt=law.ks, friction=law.friction, gamma_n=c_n / mass_eff, gamma_t=c_t / mass_eff,
                     wall_kt=0.0 if smooth else law.ks, wall_friction=wall_friction,
                     wall_gamma_n=c_n / wall_mass, wall_gamma_t=0.0 if smooth else c_t / wall_mass,
                     limit_damping=bool(clip_normal))


@dataclass(frozen=True)
class LammpsWalls:
    """Rigid walls as in ``SpecimenState``: index 0 bottom (y), 1 top (y), 2 left (x), 3 right
    (x). position (4,) [m], velocity (4,) [m/s] (constant over the run), active (4,) bools:
    an inactive wall is absent (a free side, or the sides of a periodic specimen)."""
    position: tuple
    velocity: tuple = (0.0, 0.0, 0.0, 0.0)
    active: tuple = (True, True, False, False)

    def __post_init__(self):
        for name in ("position", "velocity"):
            values = checks.array(f"walls.{name}", getattr(self, name), (4,))
            object.__setattr__(self, name, tuple(float(v) for v in values))
        active = checks.array("walls.active", self.active, (4,), dtype=bool)
        object.__setattr__(self, "active", tuple(bool(a) for a in active))
        if not (self.active[0] and self.active[1]):
            raise InputError("walls.active: the bottom and top platens must be present, got "
                             f"{self.active[:2]}")
        if self.position[1] <= self.position[0]:
            raise InputError(f"walls.position: the top platen must lie above the bottom one, got {self.position[:2]}")
        if self.active[2] and self.active[3] and self.position[3] <= self.position[2]:
            raise InputError(f"walls.position: the right wall must lie right of the left one, got {self.position[2:]}")

    @classmethod
    def from_state(cls, state):
        """The walls of a ``SpecimenState`` (wall_position, wall_velocity, wall_active)."""
        return cls(position=tuple(state.wall_position), velocity=tuple(state.wall_velocity),
                   active=tuple(bool(a) for a in state.wall_active))


def _g(x):
    """A float written so that LAMMPS reads back the same double."""
    return repr(float(x))


def write_lammps_input(directory, position, radius, mass, law, walls, dt, n_steps, dump_every, lateral="walls",
                       period=None, velocity=None, spin=None, wall_every=1, skin=None, thermo_every=None,
                       contacts=False):
    """Write a LAMMPS data file and input script of a 2D disc specimen into `directory`.

    position (n, 2) [m], radius (n,) [m], mass (n,) [kg per m depth]: the discs, written with
    ids 1..n in this order; velocity (n, 2) [m/s] and spin (n,) [rad/s]: LAMMPS's full-step
    v_0 and omega_0 (None: at rest); law: a ``LammpsLaw`` (``lammps_law`` maps a ContactLaw);
    walls: a ``LammpsWalls`` (platens always; side walls where active and lateral="walls");
    dt [s]; n_steps: steps to run; dump_every: steps between two dumps (step 0 included);
    lateral: "walls" (x non-periodic, side walls where active, else free) or "periodic"
    (x periodic with period `period` [m] starting at walls.position[2]; None: right - left);
    wall_every: steps between two rows of the wall-force file; skin [m]: neighbour skin (None:
    0.3 times the largest radius); thermo_every: steps between thermo lines (None: dump_every);
    contacts: also dump the touching pairs with their tangential force at every dump
    (``compute pair/local``; ``lammps_contact_forces`` turns them into demcell's pair arrays).

    Returns a dict of the file paths (data, input, dump, walls, log, contacts) and the run
    length."""
    checks.instance("law", law, LammpsLaw)
    checks.instance("walls", walls, LammpsWalls)
    position = checks.array("position", position, (None, 2))
    n = position.shape[0]
    checks.number("number of discs", n, Range(1, 10 ** 8, integer=True))
    radius = checks.array("radius", radius, (n,), POSITIVE)
    mass = checks.array("mass", mass, (n,), POSITIVE)
    velocity = np.zeros((n, 2)) if velocity is None else checks.array("velocity", velocity, (n, 2))
    spin = np.zeros(n) if spin is None else checks.array("spin", spin, (n,))
    dt = checks.number("dt", dt, POSITIVE)
    n_steps = checks.number("n_steps", n_steps, Range(0, 10 ** 12, integer=True))
    dump_every = checks.number("dump_every", dump_every, Range(1, 10 ** 12, integer=True))
    wall_every = checks.number("wall_every", wall_every, Range(1, 10 ** 12, integer=True))
    thermo_every = dump_every if thermo_every is None else checks.number("thermo_every", thermo_every,
                                                                         Range(1, 10 ** 12, integer=True))
    checks.choice("lateral", lateral, LATERAL)
    r_max = float(radius.max())
    skin = 0.3 * r_max if skin is None else checks.number("skin", skin, POSITIVE)
    wp, wv = walls.position, walls.velocity
    duration = n_steps * dt
    if lateral == "periodic":
        period = (wp[3] - wp[2]) if period is None else checks.number("period", period, POSITIVE)
        if not period >= 4.0 * r_max:
            raise InputError(f"period must be at least 4 disc radii, got {period!r} m for radii up to {r_max:g} m")
        x_lo, x_hi = wp[2], wp[2] + period
        side = (False, False)
    else:
        side = (walls.active[2], walls.active[3])
        # shrink-wrapped (m) x bounds follow the discs; these are the least extent
        x_lo = min(float(np.min(position[:, 0] - radius)), wp[2] if side[0] else math.inf) - r_max
        x_hi = max(float(np.max(position[:, 0] + radius)), wp[3] if side[1] else -math.inf) + r_max
    # the box spans the platens over the whole run (they may move apart) plus a margin
    y_lo = min(wp[0], wp[0] + wv[0] * duration, float(np.min(position[:, 1] - radius))) - r_max
    y_hi = max(wp[1], wp[1] + wv[1] * duration, float(np.max(position[:, 1] + radius))) + r_max
    # a disc outside the period is written at its image inside with its image flag, so that
    # LAMMPS's unwrapped xu gives back our x (to round-off of x - k P + k P)
    image = np.zeros(n, np.int64)
    if lateral == "periodic":
        image = np.floor((position[:, 0] - x_lo) / period).astype(np.int64)
        position = position.copy()
        position[:, 0] -= image * period

    os.makedirs(directory, exist_ok=True)
    paths = {key: os.path.join(directory, name) for key, name in
             (("data", DATA_FILE), ("input", INPUT_FILE), ("dump", DUMP_FILE), ("walls", WALL_FILE),
              ("log", LOG_FILE), ("contacts", CONTACT_FILE))}
    # LAMMPS converts the data file's density with the sphere volume, also in 2D
    density = mass / (4.0 / 3.0 * math.pi * radius ** 3)
    ids = np.arange(1, n + 1)
    with open(paths["data"], "w") as f:
        f.write("demcell bounded disc specimen (2D, SI, per unit depth)\n\n")
        f.write(f"{n} atoms\n1 atom types\n\n")
        f.write(f"{_g(x_lo)} {_g(x_hi)} xlo xhi\n{_g(y_lo)} {_g(y_hi)} ylo yhi\n-0.5 0.5 zlo zhi\n\n")
        f.write("Atoms # sphere\n\n")
        table = np.column_stack([ids, np.ones(n), 2.0 * radius, density, position, np.zeros(n), image,
                                 np.zeros(n), np.zeros(n)])
        np.savetxt(f, table, fmt=["%d", "%d", "%.17g", "%.17g", "%.17g", "%.17g", "%d", "%d", "%d", "%d"])
        f.write("\nVelocities\n\n")
        table = np.column_stack([ids, velocity, np.zeros((n, 3)), spin])
        np.savetxt(f, table, fmt=["%d"] + ["%.17g"] * 6)

    lines = [
        "# demcell.specimen.lammps: bounded 2D disc specimen",
        "dimension 2",
        "units si",
        "atom_style sphere",
        f"boundary {'p' if lateral == 'periodic' else 'm'} f p",
        "comm_modify vel yes",
        "newton off",
        f"read_data {DATA_FILE}",
        f"neighbor {_g(skin)} bin",
        "neigh_modify delay 0 every 1 check yes",
        f"pair_style gran/hooke/history {_g(law.kn)} {_g(law.kt)} {_g(law.gamma_n)} {_g(law.gamma_t)} "
        f"{_g(law.friction)} {1 if law.gamma_t > 0.0 else 0}{' limit_damping' if law.limit_damping else ''}",
        "pair_coeff * *",
        f"timestep {_g(dt)}",
        "fix integrate all nve/sphere disc",
        "fix plane all enforce2d",
    ]
    wall_list = [0, 1] + ([2] if side[0] else []) + ([3] if side[1] else [])
    # plane point, normal into the specimen, and the axis a wall moves along
    geometry = {0: ("0 {p} 0 0 1 0", "NULL v_d_{w} NULL"), 1: ("0 {p} 0 0 -1 0", "NULL v_d_{w} NULL"),
                2: ("{p} 0 0 1 0 0", "v_d_{w} NULL NULL"), 3: ("{p} 0 0 -1 0 0", "v_d_{w} NULL NULL")}
    wall_damp = 1 if law.wall_gamma_t > 0.0 else 0
    columns = ["v_t"]
    for w in wall_list:
        name = WALL_NAMES[w]
        plane, move = geometry[w]
        lines += [
            f"variable d_{name} equal {_g(wv[w])}*time",
            f"variable p_{name} equal {_g(wp[w])}+v_d_{name}",
            f"region r_{name} plane {plane.format(p=_g(wp[w]))} side in move {move.format(w=name)} units box",
            f"fix w_{name} all wall/gran/region hooke/history {_g(law.kn)} {_g(law.wall_kt)} "
            f"{_g(law.wall_gamma_n)} {_g(law.wall_gamma_t)} {_g(law.wall_friction)} {wall_damp}"
            f"{' limit_damping' if law.limit_damping else ''} region r_{name} contacts",
            # columns 1-3 of the contact array: contact flag, force on the disc (x, y)
            f"compute f_{name} all reduce sum f_w_{name}[1] f_w_{name}[2] f_w_{name}[3]",
        ]
        columns += [f"c_f_{name}[1]", f"c_f_{name}[2]", f"c_f_{name}[3]", f"v_p_{name}"]
    lines += [
        "variable t equal time",
        f"fix wall_history all ave/time {wall_every} 1 {wall_every} {' '.join(columns)} "
        f"file {WALL_FILE} format ' %.17g'",
        "compute spin_z all property/atom omegaz",
        # mean full-step spin over each dump interval: the reader rebuilds the rotation from it
        f"fix spin_mean all ave/atom 1 {dump_every} {dump_every} c_spin_z",
        f"dump specimen all custom {dump_every} {DUMP_FILE} "
        + " ".join(DUMP_COLUMNS),
        "dump_modify specimen sort id format float %.17g",
    ]
    if contacts:
        lines += [
            # pairs within the cutoff, their ids and the tangential force on patom1 (pair
            # single(): p1 p2 = fs_x, fs_y); the normal force is rebuilt by the reader
            "compute pair_ids all property/local patom1 patom2",
            "compute pair_force all pair/local dist p1 p2",
            f"dump contacts all local {dump_every} {CONTACT_FILE} c_pair_ids[1] c_pair_ids[2] c_pair_force[1] "
            "c_pair_force[2] c_pair_force[3]",
            "dump_modify contacts format float %.17g",
        ]
    lines += [
        # the normal force of each wall: y for the platens, x for the side walls
        "thermo_style custom step time ke cpu " + " ".join(
            f"c_f_{WALL_NAMES[w]}[{3 if w < 2 else 2}]" for w in wall_list),
        "thermo_modify format float %.10g",
        f"thermo {thermo_every}",
        f"run {n_steps}",
    ]
    with open(paths["input"], "w") as f:
        f.write("\n".join(lines) + "\n")
    # the wall order of the history file's columns
    paths["wall_order"] = tuple(wall_list)
    paths["n_steps"] = n_steps
    paths["dt"] = dt
    return paths


def write_lammps_state(directory, state, law, options, n_steps, dump_every, wall_every=1):
    """``write_lammps_input`` of a ``SpecimenState`` with a ``ContactLaw`` and
    ``SpecimenOptions`` (lateral "walls" or "periodic"; a membrane specimen has no LAMMPS
    counterpart). m_eff is that of two discs of the median mass (exact when monodisperse);
    the velocities are the state's half-step velocities taken as LAMMPS's v_0, exact when the
    state is at rest without forces (see the module docstring)."""
    if options.lateral not in LATERAL:
        raise InputError(f"a LAMMPS specimen has lateral 'walls' or 'periodic', got {options.lateral!r} "
                         "(no membrane or confining pressure in LAMMPS)")
    m = float(np.median(state.mass))
    llaw = lammps_law(law, 0.5 * m, options.normal_dashpot, options.tangential_dashpot, options.clip_normal,
                      options.wall_friction, wall_mass=m)
    walls = LammpsWalls.from_state(state)
    return write_lammps_input(directory, state.position, state.radius, state.mass, llaw, walls, options.dt,
                              n_steps, dump_every, lateral=options.lateral,
                              period=state.period if options.lateral == "periodic" else None,
                              velocity=state.velocity, spin=state.spin, wall_every=wall_every, skin=options.skin)


def _rotation_increment(spin_mean, spin_0, spin_1, torque_0, torque_1, inertia, dt, steps):
    """Leapfrog rotation sum_{k=0}^{N-1} omega_{k+1/2} dt over a dump interval of N steps [rad]
    from the full-step values LAMMPS keeps: omega_{k+1/2} = (omega_k + omega_{k+1})/2 +
    (T_k - T_{k+1}) dt / 4I (velocity Verlet's two half kicks), so the sum is
    dt [N mean(omega_1..N) + (omega_0 - omega_N)/2 + (T_0 - T_N) dt / 4I]."""
    return dt * (steps * spin_mean + 0.5 * (spin_0 - spin_1) + (torque_0 - torque_1) * dt / (4.0 * inertia))


def read_lammps_dump(path, dt=None):
    """Snapshots of a dump written by ``write_lammps_input`` as id-sorted arrays.

    Returns a dict: timestep (s,) int64; id (n,) int64; position, velocity, force (s, n, 2)
    [m, m/s, N] (positions unwrapped across a periodic side; full-step velocities v_n);
    spin, torque (s, n) [rad/s, N m]; radius (n,) [m]; mass (n,) [kg/m]; and, when `dt` [s] is
    given, rotation (s, n) [rad]: the leapfrog rotation since the first snapshot, rebuilt
    exactly from the interval-mean spin (``_rotation_increment``)."""
    try:
        with open(path) as f:
            text = f.read()
    except OSError as exc:
        raise InputError(f"cannot read the LAMMPS dump {path}: {checks.one_line(exc)}") from None
    blocks = text.split("ITEM: TIMESTEP\n")[1:]
    if not blocks:
        raise InputError(f"{path} holds no LAMMPS dump snapshot")
    steps, tables, header = [], [], None
    for block in blocks:
        head, _, body = block.partition("ITEM: ATOMS ")
        lines = head.split("\n")
        try:
            step = int(lines[0])
            count = int(lines[lines.index("ITEM: NUMBER OF ATOMS") + 1])
        except (ValueError, IndexError):
            raise InputError(f"{path}: a corrupt dump header near timestep {lines[0][:20]!r}") from None
        names, _, rows = body.partition("\n")
        if header is None:
            header = names.split()
        elif names.split() != header:
            raise InputError(f"{path}: the dump's columns change at timestep {step}")
        values = np.array(rows.split(), dtype=float)
        if values.size != count * len(header):
            # the last snapshot of a run cut short may be partial
            if block is blocks[-1] and len(steps) > 0:
                break
            raise InputError(f"{path}: timestep {step} has {values.size} numbers, expected {count} x {len(header)}")
        steps.append(step)
        tables.append(values.reshape(count, len(header)))
    counts = {t.shape[0] for t in tables}
    if len(counts) != 1:
        raise InputError(f"{path}: the number of discs changes between snapshots ({sorted(counts)}): lost discs?")
    col = {name: k for k, name in enumerate(header)}
    missing = [c for c in DUMP_COLUMNS if c not in col]
    if missing:
        raise InputError(f"{path} lacks the dump columns {missing}")
    data = np.stack(tables)
    order = np.argsort(data[:, :, col["id"]], axis=1, kind="stable")
    data = np.take_along_axis(data, order[:, :, None], axis=1)
    ids = data[0, :, col["id"]].astype(np.int64)
    if np.any(data[:, :, col["id"]].astype(np.int64) != ids):
        raise InputError(f"{path}: the discs' ids differ between snapshots")

    def pair(a, b):
        return np.stack([data[:, :, col[a]], data[:, :, col[b]]], axis=-1)

    out = {"timestep": np.array(steps, np.int64), "id": ids, "position": pair("xu", "yu"),
           "velocity": pair("vx", "vy"), "force": pair("fx", "fy"), "spin": data[:, :, col["omegaz"]].copy(),
           "torque": data[:, :, col["tqz"]].copy(), "radius": data[0, :, col["radius"]].copy(),
           "mass": data[0, :, col["mass"]].copy()}
    if dt is not None:
        dt = checks.number("dt", dt, POSITIVE)
        inertia = 0.5 * out["mass"] * out["radius"] ** 2
        rotation = np.zeros_like(out["spin"])
        mean = data[:, :, col["f_spin_mean"]]
        for s in range(1, len(steps)):
            rotation[s] = rotation[s - 1] + _rotation_increment(
                mean[s], out["spin"][s - 1], out["spin"][s], out["torque"][s - 1], out["torque"][s], inertia, dt,
                steps[s] - steps[s - 1])
        out["rotation"] = rotation
    return out


def read_lammps_walls(path, wall_order=(0, 1)):
    """The wall-force history written by ``write_lammps_input`` (``fix ave/time``).

    wall_order: the walls of the file's columns (``write_lammps_input``'s "wall_order").
    Returns a dict: timestep (k,) int64; time (k,) [s]; wall_force (k, 4, 2) [N] the force
    each wall exerts on the discs (zero for an absent wall), as SpecimenState.wall_force;
    wall_position (k, 4) [m] (nan for an absent wall); contacts (k, 4) discs touching it."""
    try:
        rows = np.loadtxt(path, comments="#", ndmin=2)
    except (OSError, ValueError) as exc:
        raise InputError(f"cannot read the LAMMPS wall history {path}: {checks.one_line(exc)}") from None
    expected = 2 + 4 * len(wall_order)
    if rows.shape[1] != expected:
        raise InputError(f"{path} has {rows.shape[1]} columns, expected {expected} for walls {tuple(wall_order)}")
    k = rows.shape[0]
    force = np.zeros((k, 4, 2))
    position = np.full((k, 4), np.nan)
    contacts = np.zeros((k, 4), np.int64)
    for c, w in enumerate(wall_order):
        base = 2 + 4 * c
        contacts[:, w] = np.rint(rows[:, base]).astype(np.int64)
        force[:, w, 0] = rows[:, base + 1]
        force[:, w, 1] = rows[:, base + 2]
        position[:, w] = rows[:, base + 3]
    return {"timestep": rows[:, 0].astype(np.int64), "time": rows[:, 1], "wall_force": force,
            "wall_position": position, "contacts": contacts}


_LOOP = re.compile(r"Loop time of ([0-9.eE+-]+) on (\d+) procs for (\d+) steps with (\d+) atoms")
_CPU = re.compile(r"([0-9.]+)% CPU use with (\d+) MPI tasks x (\d+) OpenMP threads")
_SECTION = re.compile(r"^(Pair|Neigh|Comm|Output|Modify|Other)\s*\|(.*)$")


def read_lammps_log(path):
    """Timings and counters of the last run in a LAMMPS log.

    Returns a dict: loop_seconds [s] (wall time of the run loop), procs, steps, atoms,
    cpu_percent (per MPI task), cpu_seconds (loop_seconds x procs x cpu_percent / 100),
    sections {Pair, Neigh, Comm, Output, Modify, Other: average seconds}, neighbours (pairs in
    the half list, when printed), neighbour_builds, thermo (dict of column -> array of the
    last run's thermo lines)."""
    try:
        with open(path) as f:
            text = f.read()
    except OSError as exc:
        raise InputError(f"cannot read the LAMMPS log {path}: {checks.one_line(exc)}") from None
    loops = _LOOP.findall(text)
    if not loops:
        raise InputError(f"{path} holds no finished LAMMPS run ('Loop time' missing)")
    loop, procs, steps, atoms = loops[-1]
    out = {"loop_seconds": float(loop), "procs": int(procs), "steps": int(steps), "atoms": int(atoms)}
    cpu = _CPU.findall(text)
    out["cpu_percent"] = float(cpu[-1][0]) if cpu else math.nan
    out["cpu_seconds"] = out["loop_seconds"] * out["procs"] * out["cpu_percent"] / 100.0
    last = text[text.rfind("Loop time of"):]
    sections = {}
    for line in last.split("\n"):
        m = _SECTION.match(line)
        if m:
            parts = [p.strip() for p in m.group(2).split("|")]
            try:
                sections[m.group(1)] = float(parts[1]) if parts[1] else float(parts[0])
            except (ValueError, IndexError):
                pass
    out["sections"] = sections
    m = re.findall(r"Total # of neighbors = (\d+)", last)
    out["neighbours"] = int(m[-1]) if m else None
    m = re.findall(r"Neighbor list builds = (\d+)", last)
    out["neighbour_builds"] = int(m[-1]) if m else None
    # thermo block of the last run: from its header line to "Loop time"
    head = text.rfind("\n   Step ") if "\n   Step " in text else text.rfind("\nStep ")
    thermo = {}
    if head >= 0:
        block = text[head + 1:text.rfind("Loop time of")].strip().split("\n")
        names = block[0].split()
        rows = []
        for line in block[1:]:
            parts = line.split()
            if len(parts) != len(names):
                continue
            try:
                rows.append([float(p) for p in parts])
            except ValueError:
                continue
        if rows:
            table = np.array(rows)
            thermo = {name: table[:, k] for k, name in enumerate(names)}
    out["thermo"] = thermo
    return out


def lammps_command(ranks=1, executable="lmp"):
    """The command line that runs LAMMPS on `ranks` MPI ranks ([lmp] or [mpirun, -n, ranks, lmp]);
    LammpsError in one line when the executable (or mpirun) is not installed."""
    ranks = checks.number("ranks", ranks, Range(1, 4096, integer=True))
    lmp = shutil.which(executable)
    if lmp is None:
        raise LammpsError(f"LAMMPS is not installed: no '{executable}' on PATH "
                          "(Debian: apt-get install lammps python3-lammps)")
    if ranks == 1:
        return [lmp]
    mpirun = shutil.which("mpirun")
    if mpirun is None:
        raise LammpsError("mpirun is not installed (Debian: apt-get install openmpi-bin): needed for ranks > 1")
    return [mpirun, "-n", str(ranks), lmp]


def _mpi_environment():
    env = dict(os.environ)
    # containers run as root and may have fewer cores than ranks
    env.update({"OMPI_ALLOW_RUN_AS_ROOT": "1", "OMPI_ALLOW_RUN_AS_ROOT_CONFIRM": "1",
                "OMPI_MCA_rmaps_base_oversubscribe": "1", "OMP_NUM_THREADS": "1"})
    return env


def run_lammps(directory, ranks=1, executable="lmp", read=True, wall_order=None, dt=None, timeout=None):
    """Run the input script written by ``write_lammps_input`` in `directory` and read its outputs.

    ranks: MPI ranks (1: plain ``lmp``; more: ``mpirun -n ranks lmp``); read: parse the dump and
    wall history (False: only the log, for timings); wall_order, dt: as returned by
    ``write_lammps_input`` (None: read from the input script); timeout [s].
    Returns a dict: log (``read_lammps_log``), dump (``read_lammps_dump``, rotations included),
    walls (``read_lammps_walls``), wall_seconds [s] of the whole process, cpu_seconds [s] of the
    child processes (setup and output included; the log's cpu_seconds is the run loop only).
    LammpsError with LAMMPS's own error line when the run fails."""
    command = lammps_command(ranks, executable) + ["-in", INPUT_FILE, "-log", LOG_FILE, "-screen", "none"]
    script = os.path.join(directory, INPUT_FILE)
    if not os.path.isfile(script):
        raise InputError(f"no LAMMPS input script in {directory} (write_lammps_input writes {INPUT_FILE})")
    for name in (LOG_FILE, DUMP_FILE, WALL_FILE, CONTACT_FILE):
        p = os.path.join(directory, name)
        if os.path.exists(p):
            os.remove(p)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    try:
        proc = subprocess.run(command, cwd=directory, env=_mpi_environment(), capture_output=True, text=True,
                              timeout=timeout)
    except subprocess.TimeoutExpired:
        raise LammpsError(f"LAMMPS ran past the timeout of {timeout} s in {directory}") from None
    wall_seconds = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    log_path = os.path.join(directory, LOG_FILE)
    if proc.returncode != 0 or not os.path.isfile(log_path):
        text = proc.stdout + proc.stderr
        if os.path.isfile(log_path):
            with open(log_path) as f:
                text += f.read()
        errors = [line.strip() for line in text.split("\n") if "ERROR" in line]
        reason = errors[-1] if errors else (text.strip().split("\n") or ["no output"])[-1]
        raise LammpsError(f"LAMMPS failed in {directory} (exit {proc.returncode}): {reason[:300]}")
    out = {"log": read_lammps_log(log_path), "wall_seconds": wall_seconds,
           "cpu_seconds": (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)}
    if read:
        script_text = open(script).read()
        if dt is None:
            dt = float(re.search(r"^timestep (\S+)", script_text, re.M).group(1))
        if wall_order is None:
            wall_order = tuple(WALL_NAMES.index(name) for name in re.findall(r"^fix w_(\w+) ", script_text, re.M))
        out["dump"] = read_lammps_dump(os.path.join(directory, DUMP_FILE), dt=dt)
        out["walls"] = read_lammps_walls(os.path.join(directory, WALL_FILE), wall_order)
        if os.path.isfile(os.path.join(directory, CONTACT_FILE)):
            out["contacts"] = read_lammps_contacts(os.path.join(directory, CONTACT_FILE))
    return out


def read_lammps_contacts(path):
    """The pair dump of ``write_lammps_input(contacts=True)``: a list of one dict per snapshot,
    timestep; id1, id2 (k,) int64 the atoms of each pair; fs_on_1 (k, 2) [N] the tangential
    force on atom id1 (LAMMPS's single(): -kt * shear, see ``lammps_contact_forces``)."""
    try:
        with open(path) as f:
            text = f.read()
    except OSError as exc:
        raise InputError(f"cannot read the LAMMPS pair dump {path}: {checks.one_line(exc)}") from None
    out = []
    for block in text.split("ITEM: TIMESTEP\n")[1:]:
        head, _, body = block.partition("ITEM: ENTRIES ")
        lines = head.split("\n")
        try:
            step = int(lines[0])
            count = int(lines[lines.index("ITEM: NUMBER OF ENTRIES") + 1])
        except (ValueError, IndexError):
            raise InputError(f"{path}: a corrupt pair dump header near timestep {lines[0][:20]!r}") from None
        names, _, rows = body.partition("\n")
        values = np.array(rows.split(), dtype=float).reshape(-1, len(names.split())) if count else np.zeros((0, 5))
        if values.shape[0] != count:
            raise InputError(f"{path}: timestep {step} has {values.shape[0]} pairs, expected {count}")
        out.append({"timestep": step, "id1": values[:, 0].astype(np.int64), "id2": values[:, 1].astype(np.int64),
                    "fs_on_1": values[:, 3:5].copy()})
    if not out:
        raise InputError(f"{path} holds no LAMMPS pair dump snapshot")
    return out


def lammps_contact_forces(dump, contacts, snapshot, law, dt, period=0.0):
    """The contacts of dump snapshot `snapshot` in demcell's convention, for ``fields``:
    pair_i < pair_j (indices = LAMMPS id - 1), n = (x_j - x_i)/|x_j - x_i|, t = (-n_y, n_x),
    fn (m,) [N] total normal force on j along n (> 0 repulsive), fs (m,) [N] tangential force
    on j along t, and external_force (n, 2) [N] = the dump's total force minus the contact
    forces (the walls' share).

    dump: ``read_lammps_dump``; contacts: ``read_lammps_contacts`` (same dump interval);
    law: the ``LammpsLaw`` of the run; dt [s]; period [m]: x period (0: none).

    The normal force is rebuilt exactly as LAMMPS computed it at that step: kn overlap -
    m_eff gamma_n (v_i - v_j).(x_i - x_j)/r with the half-step velocities v_n - F_n dt / 2m
    that velocity Verlet used (the dump holds v_n), clipped at zero under limit_damping.
    The tangential force is LAMMPS's single() at the dump time: -kt * shear (the stored,
    already Coulomb-limited displacement; plus m_eff gamma_t v_t at the full-step velocity,
    which differs from the step's when gamma_t > 0). single() limits it again with its own
    normal force (full-step damping); where that cut it, the forces are solved from the
    discs' torques (exact for smooth walls; with frictional walls they are left at the cut).
    Exact to round-off without dashpots, and with the normal dashpot and gamma_t = 0 on
    smooth walls (tests/test_specimen_lammps.py checks the force and torque balance)."""
    checks.instance("law", law, LammpsLaw)
    k = checks.number("snapshot", snapshot, Range(0, len(dump["timestep"]) - 1, integer=True))
    c = contacts[k]
    if c["timestep"] != int(dump["timestep"][k]):
        raise InputError(f"pair dump timestep {c['timestep']} differs from the dump's {int(dump['timestep'][k])}")
    x = dump["position"][k]
    n = x.shape[0]
    m = dump["mass"]
    v_half = dump["velocity"][k] - dump["force"][k] * dt / (2.0 * m[:, None])
    a = np.minimum(c["id1"], c["id2"]) - 1
    b = np.maximum(c["id1"], c["id2"]) - 1
    # under MPI with newton off a pair across two ranks is listed by both
    key = np.unique(a * n + b, return_index=True)[1]
    a, b = a[key], b[key]
    fs_on_1 = c["fs_on_1"][key]
    first_is_i = (np.minimum(c["id1"], c["id2"]) == c["id1"])[key]
    d = x[b] - x[a]
    if period > 0.0:
        d[:, 0] -= period * np.floor(d[:, 0] / period + 0.5)
    dist = np.hypot(d[:, 0], d[:, 1])
    r = dump["radius"]
    overlap = r[a] + r[b] - dist
    touch = overlap > 0.0
    a, b, d, dist, overlap, fs_on_1, first_is_i = (a[touch], b[touch], d[touch], dist[touch], overlap[touch],
                                                  fs_on_1[touch], first_is_i[touch])
    nvec = d / dist[:, None]
    tvec = np.stack([-nvec[:, 1], nvec[:, 0]], -1)
    m_eff = m[a] * m[b] / (m[a] + m[b])
    approach = -np.einsum("ij,ij->i", v_half[b] - v_half[a], nvec)
    fn = law.kn * overlap + m_eff * law.gamma_n * approach
    if law.limit_damping:
        fn = np.maximum(fn, 0.0)
    # tangential force on j: -fs_on_1 when atom 1 is i, +fs_on_1 when atom 1 is j
    on_j = np.where(first_is_i[:, None], -fs_on_1, fs_on_1)
    fs = np.einsum("ij,ij->i", on_j, tvec)
    if law.gamma_n > 0.0 and law.friction < 1.0e4:
        # single()'s own limit, with the full-step velocities of the dump
        v_full = dump["velocity"][k]
        approach_full = -np.einsum("ij,ij->i", v_full[b] - v_full[a], nvec)
        single_fn = law.kn * overlap + m_eff * law.gamma_n * approach_full
        single_limit = law.friction * (np.maximum(single_fn, 0.0) if law.limit_damping else np.abs(single_fn))
        limit = law.friction * fn
        fs = np.where(np.abs(fs) > limit, np.copysign(limit, fs), fs)
        # where single() cut the force to its own smaller limit the stored value lies between
        # that limit and mu fn: those few forces are solved from the discs' torques (LAMMPS's
        # arm is the radius; smooth walls add none), which the dump holds exactly
        cut = (np.abs(fs) >= (1.0 - 1e-9) * single_limit) & (single_limit < limit)
        if cut.any() and law.wall_kt == 0.0:
            torque = dump["torque"][k].copy()
            keep = ~cut
            np.add.at(torque, a[keep], r[a[keep]] * fs[keep])
            np.add.at(torque, b[keep], r[b[keep]] * fs[keep])
            q = np.flatnonzero(cut)
            rows = np.unique(np.concatenate([a[q], b[q]]))
            where = {int(p): e for e, p in enumerate(rows)}
            matrix = np.zeros((rows.size, q.size))
            for col, e in enumerate(q):
                matrix[where[int(a[e])], col] = -r[a[e]]
                matrix[where[int(b[e])], col] = -r[b[e]]
            solved = np.linalg.lstsq(matrix, torque[rows], rcond=None)[0]
            fs[q] = np.clip(solved, -limit[q], limit[q])
    force_j = fn[:, None] * nvec + fs[:, None] * tvec
    contact_force = np.zeros((n, 2))
    np.add.at(contact_force, b, force_j)
    np.add.at(contact_force, a, -force_j)
    return {"pair_i": a.astype(np.int64), "pair_j": b.astype(np.int64), "fn": fn, "fs": fs,
            "external_force": dump["force"][k] - contact_force}
