"""Rigid walls (platens) of a bounded specimen: disc-wall forces and the wall programme.

004 eq. 7.43: a disc i overlapping wall w by Delta = <r_i - distance from its centre to the
wall> gets f = (E_n Delta + D_n dDelta/dt) n_w, n_w the wall's normal into the specimen and
dDelta/dt taken with the wall velocity; the same E_n and D_n as between two discs (dns-spec
A4), the total clipped at >= 0 when the law clips. Smooth walls (004: no tangential force, no
moment) unless wall_friction mu_w > 0: then a tangential spring of the law's E_t with the
Coulomb limit mu_w f, kept per disc and wall (its history is lost at a neighbour rebuild only
for a disc that left the wall's candidate list, i.e. moved off the wall).

Walls are kinematic: 0 bottom, 1 top, 2 left, 3 right (state.py). Each follows its
``WallControl``: a prescribed velocity, or a stress servo whose velocity along the inward
normal is gain (sigma_w - target), capped at max_speed, with sigma_w = -(F_w . n_w) / L_w
the normal stress the wall carries (tension positive, so a wall pressing with p gives -p),
F_w the force it exerts on the discs and L_w its loaded length (width for the platens,
height for the side walls) [N/m].
"""
import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from .. import checks
from ..checks import NON_NEGATIVE, POSITIVE
from ..errors import InputError

#: sign of each wall's inward normal along its axis, and the axis (1 = y, 0 = x)
WALL_SIGN = np.array([1.0, -1.0, 1.0, -1.0])
WALL_AXIS = np.array([1, 1, 0, 0], np.int64)
#: component of each wall's tangent t = (-n_y, n_x) along the wall (the other axis)
WALL_TANGENT = np.array([-1.0, 1.0, 1.0, -1.0])
MODES = ("velocity", "stress")


@dataclass(frozen=True)
class WallControl:
    """Motion of one wall. mode "velocity": the wall moves at `velocity` [m/s] along +x or +y
    (the axis of its position: a top platen going down has a negative velocity); "stress":
    servo to the normal stress `stress` [N/m] (tension positive: a confining pressure p is
    stress=-p), velocity along the inward normal gain (sigma - stress) capped at max_speed
    [m/s]; gain [m^2/(N s)] None: max_speed / |stress| (full speed at a 100 % error)."""
    mode: str = "velocity"
    velocity: float = 0.0
    stress: float = 0.0
    gain: float = None
    max_speed: float = None

    def __post_init__(self):
        checks.choice("WallControl.mode", self.mode, MODES)
        object.__setattr__(self, "velocity", checks.number("WallControl.velocity", self.velocity))
        object.__setattr__(self, "stress", checks.number("WallControl.stress", self.stress))
        object.__setattr__(self, "gain", checks.optional("WallControl.gain", self.gain, NON_NEGATIVE))
        object.__setattr__(self, "max_speed", checks.optional("WallControl.max_speed", self.max_speed, POSITIVE))
        if self.mode == "stress" and self.gain is None and self.stress == 0.0:
            raise InputError("WallControl(mode='stress', stress=0) needs an explicit gain [m^2/(N s)]")


def programme_arrays(controls, default_speed):
    """(mode (4,) int64: 0 velocity 1 stress, velocity, target, gain, max_speed (4,)) from 4
    WallControl (None: fixed wall); default_speed [m/s] caps a servo without max_speed."""
    mode = np.zeros(4, np.int64)
    velocity = np.zeros(4)
    target = np.zeros(4)
    gain = np.zeros(4)
    vmax = np.zeros(4)
    for w, c in enumerate(controls):
        if c is None:
            continue
        checks.instance(f"wall control {w}", c, WallControl)
        if c.mode == "velocity":
            velocity[w] = c.velocity
            continue
        mode[w] = 1
        target[w] = c.stress
        vmax[w] = c.max_speed if c.max_speed is not None else default_speed
        gain[w] = c.gain if c.gain is not None else vmax[w] / abs(c.stress)
    return mode, velocity, target, gain, vmax


@njit(cache=True)
def wall_candidates(position, radius, wall_position, wall_active, skin):
    """Disc-wall pairs (disc (c,), wall (c,)) whose gap is below the skin [m]: the only ones a
    wall may touch until the next neighbour build."""
    n = position.shape[0]
    count = 0
    for p in range(n):
        for w in range(4):
            if wall_active[w] and WALL_SIGN[w] * (position[p, WALL_AXIS[w]] - wall_position[w]) < radius[p] + skin:
                count += 1
    disc = np.empty(count, np.int64)
    wall = np.empty(count, np.int64)
    c = 0
    for p in range(n):
        for w in range(4):
            if wall_active[w] and WALL_SIGN[w] * (position[p, WALL_AXIS[w]] - wall_position[w]) < radius[p] + skin:
                disc[c] = p
                wall[c] = w
                c += 1
    return disc, wall


@njit(cache=True)
def wall_forces(cand_disc, cand_wall, cand_fs, position, velocity, spin, radius, mass, wall_position, wall_velocity,
                kn, ks, dashpot, ratio, clip, wall_mu, dt, external_force, external_moment, wall_force, on_wall):
    """004 eq. 7.43 for every candidate disc-wall pair: ADDS the wall force into
    external_force (n, 2) and into wall_force (4, 2) (which it zeroes first), sets on_wall.
    dashpot D_n [N s/m] (used when ratio == 0) or the damping ratio xi_n: c = 2 xi_n
    sqrt(m_i kn / 2), the coefficient between two copies of disc i. wall_mu > 0: tangential
    spring ks with Coulomb limit wall_mu f along t = (-n_y, n_x), its force history in
    cand_fs (c,), its moment -r f_t ADDED into external_moment (n,)."""
    for w in range(4):
        wall_force[w, 0] = 0.0
        wall_force[w, 1] = 0.0
    for c in range(cand_disc.shape[0]):
        p = cand_disc[c]
        w = cand_wall[c]
        a = WALL_AXIS[w]
        s = WALL_SIGN[w]
        delta = radius[p] - s * (position[p, a] - wall_position[w])
        if delta <= 0.0:
            cand_fs[c] = 0.0
            continue
        delta_rate = -s * (velocity[p, a] - wall_velocity[w])
        coef = dashpot if ratio == 0.0 else 2.0 * ratio * math.sqrt(0.5 * mass[p] * kn)
        f = kn * delta + coef * delta_rate
        if clip and f < 0.0:
            f = 0.0
        external_force[p, a] += s * f
        wall_force[w, a] += s * f
        on_wall[p] = 1
        if wall_mu > 0.0:
            # tangent t = (-n_y, n_x) along axis b: slip of the contact point (offset -r n from the
            # centre) on the wall, which moves only along its normal: v.t - r omega
            b = 1 - a
            tb = WALL_TANGENT[w]
            slip = (velocity[p, b] * tb - radius[p] * spin[p]) * dt
            ft = cand_fs[c] - ks * slip
            lim = wall_mu * f
            if abs(ft) > lim:
                ft = math.copysign(lim, ft)
            cand_fs[c] = ft
            external_force[p, b] += ft * tb
            wall_force[w, b] += ft * tb
            external_moment[p] += -radius[p] * ft


@njit(cache=True)
def wall_stress(w, wall_force, length):
    """Normal stress carried by wall w [N/m], tension positive: -(F_w . n_w) / L_w."""
    return -WALL_SIGN[w] * wall_force[w, WALL_AXIS[w]] / length


@njit(cache=True)
def move_walls(wall_position, wall_velocity, wall_active, wall_force, mode, velocity, target, gain, vmax,
               width, dt):
    """Wall velocities from the programme (a servo reads this step's wall force), then the
    positions advanced by v dt. width [m]: loaded length of the platens when there are no
    side walls (membrane: the specimen's width; periodic: the period)."""
    for w in range(4):
        if not wall_active[w]:
            continue
        if mode[w] == 1:
            if w < 2:
                length = wall_position[3] - wall_position[2] if wall_active[2] and wall_active[3] else width
            else:
                length = wall_position[1] - wall_position[0]
            v = WALL_SIGN[w] * gain[w] * (wall_stress(w, wall_force, length) - target[w])
            if v > vmax[w]:
                v = vmax[w]
            elif v < -vmax[w]:
                v = -vmax[w]
            wall_velocity[w] = v
        else:
            wall_velocity[w] = velocity[w]
        wall_position[w] += wall_velocity[w] * dt


def wall_lengths(state, width):
    """Loaded length of each wall [m] (platens: distance between the side walls, or `width`;
    side walls: distance between the platens)."""
    wp = state.wall_position
    sides = bool(state.wall_active[2] and state.wall_active[3])
    platen = wp[3] - wp[2] if sides else width
    return np.array([platen, platen, wp[1] - wp[0], wp[1] - wp[0]])


__all__ = ["WallControl", "programme_arrays", "wall_candidates", "wall_forces", "wall_stress", "move_walls",
           "wall_lengths", "WALL_SIGN", "WALL_AXIS", "WALL_TANGENT"]
