"""Leapfrog integration of the discs of a bounded specimen (004 eqs. 7.15-7.17).

The thesis prints position Verlet, x(t + dt) = f(t) dt^2 / m + 2 x(t) - x(t - dt), with the
dashpot velocities updated by f(t) dt / m. Started from rest this is the leapfrog scheme with
the dashpot forces evaluated at the lagged half-step velocity (dns-spec A5):

    v_{n+1/2} = v_{n-1/2} + F(x_n, v_{n-1/2}) dt / m,    x_{n+1} = x_n + v_{n+1/2} dt,

and the same for the rotation with the inertia. The state's ``velocity`` and ``spin`` are the
half-step values. A held disc (``held[p]`` = 1: a frame particle of demcell.frame, whose
motion is prescribed) ignores its forces: it drifts with the velocity and spin set for it. Optional local non-viscous damping (000 section 3.2.1, eq. 30):
F_c <- F_c - alpha |F_c| sign(v_c) per component, for quasi-static preparation only.
Optional mass damping c_m [1/s] (003 eqs. 9, 29): a force -c_m m v (moment -c_m I omega) with
the velocity taken trapezoidally, v = (v_{n-1/2} + v_{n+1/2}) / 2, so that

    v_{n+1/2} = [(1 - c_m dt/2) v_{n-1/2} + F dt / m] / (1 + c_m dt/2).

This is 003's velocity Verlet with eqs. 27-30 written for the half-step velocity
u_{n+1/2} = v_n + dt a_n / 2: substituting eq. 29 into u_{n+3/2} = u_{n+1/2} + dt a_{n+1}
gives the line above, so the positions are those of eqs. 27-30 exactly. A free disc's speed
decays by (1 - c_m dt/2) / (1 + c_m dt/2) per step, exp(-c_m t) to O((c_m dt)^3) per step.
Rotations locked (ContactLaw.rotations False): spin and rotation stay zero.

One pass over the discs does the gather of the contact forces (contacts.gather_disc), adds
the external force and gravity, and advances the disc, in blocks of discs so that the largest
displacement since the last neighbour build (the staleness test) is reduced in a fixed order.
"""
import math

import numpy as np
from numba import njit

from .contacts import gather_disc

#: discs per block of the integration pass
BLOCK = 512


@njit(cache=True)
def leapfrog_disc(p, fx, fy, mo, position, velocity, rotation, spin, mass, inertia, external_force,
                  external_moment, gx, gy, damp, cm, dt, rot, build_position, held, path, path_t):
    """Advance disc p by one step from its contact resultant (fx, fy [N], mo [N m]), or, if
    held[p], by its prescribed velocity and spin (path_t < 0) or onto its path at the time
    path_t (``follow_path``); cm: mass damping c_m [1/s]; returns |x_p - x_p^build|^2 [m^2]
    (inf if not finite)."""
    if held[p] != 0:
        if path_t >= 0.0:
            return follow_path(p, position, velocity, rotation, spin, dt, rot, build_position, path, path_t)
        return drift_held(p, position, velocity, rotation, spin, dt, rot, build_position)
    fx += external_force[p, 0] + mass[p] * gx
    fy += external_force[p, 1] + mass[p] * gy
    if damp > 0.0:
        if velocity[p, 0] != 0.0:
            fx -= damp * abs(fx) * math.copysign(1.0, velocity[p, 0])
        if velocity[p, 1] != 0.0:
            fy -= damp * abs(fy) * math.copysign(1.0, velocity[p, 1])
    inv_m = 1.0 / mass[p]
    # with cm = 0, keep = 1 and gain = dt exactly: the undamped update bit for bit
    keep = (1.0 - 0.5 * cm * dt) / (1.0 + 0.5 * cm * dt)
    gain = dt / (1.0 + 0.5 * cm * dt)
    velocity[p, 0] = keep * velocity[p, 0] + fx * gain * inv_m
    velocity[p, 1] = keep * velocity[p, 1] + fy * gain * inv_m
    position[p, 0] += velocity[p, 0] * dt
    position[p, 1] += velocity[p, 1] * dt
    if rot:
        mo += external_moment[p]
        if damp > 0.0 and spin[p] != 0.0:
            mo -= damp * abs(mo) * math.copysign(1.0, spin[p])
        spin[p] = keep * spin[p] + mo * gain / inertia[p]
        rotation[p] += spin[p] * dt
    else:
        spin[p] = 0.0
    return displacement2(p, position, build_position)


@njit(cache=True)
def drift_held(p, position, velocity, rotation, spin, dt, rot, build_position):
    """A held disc moves by its prescribed velocity and spin [m/s, rad/s] whatever its forces;
    returns |x_p - x_p^build|^2 [m^2] (inf if not finite)."""
    position[p, 0] += velocity[p, 0] * dt
    position[p, 1] += velocity[p, 1] * dt
    if rot:
        rotation[p] += spin[p] * dt
    else:
        spin[p] = 0.0
    return displacement2(p, position, build_position)


@njit(cache=True)
def follow_path(p, position, velocity, rotation, spin, dt, rot, build_position, path, t):
    """A held disc put on its constant-acceleration path at the end of the step, time t [s]
    since the path's start (003 eqs. 25-26: x = x0 + v0 t + a t^2 / 2, the same for the
    rotation); path[p] = (x0, y0, theta0, vx, vy, omega, ax, ay, alpha). Its half-step
    velocity and spin become (target - current) / dt: on the path, v0 + a (t - dt/2) exactly,
    and after a jump of the path's start the step that absorbs it. Set AFTER the step's
    forces, so the contact law saw the velocity of the step before, as for a free disc.
    Returns |x_p - x_p^build|^2 [m^2] (inf if not finite)."""
    half = 0.5 * t * t
    for c in range(2):
        target = path[p, c] + t * path[p, 3 + c] + half * path[p, 6 + c]
        velocity[p, c] = (target - position[p, c]) / dt
        position[p, c] = target
    if rot:
        target = path[p, 2] + t * path[p, 5] + half * path[p, 8]
        spin[p] = (target - rotation[p]) / dt
        rotation[p] = target
    else:
        spin[p] = 0.0
    return displacement2(p, position, build_position)


@njit(cache=True)
def set_held_path(path, rows, source, start, velocity, acceleration):
    """path[rows[k]] = (start, velocity, acceleration)[source[k]] for every held disc k (the
    engine's row rows[k] of the disc whose original index is source[k]; the (n, 3) arrays in
    the original order, only those rows read). Returns -1, or 3 k' + a of the first
    non-finite value, k' its index in `source` and a the array (0 start, 1 velocity, 2
    acceleration); the rows before it are written."""
    for k in range(rows.shape[0]):
        r = rows[k]
        s = source[k]
        for a in range(3):
            values = start if a == 0 else velocity if a == 1 else acceleration
            for c in range(3):
                v = values[s, c]
                if not (abs(v) < math.inf):
                    return 3 * k + a
                path[r, 3 * a + c] = v
    return -1


@njit(cache=True)
def displacement2(p, position, build_position):
    """|x_p - x_p^build|^2 [m^2], inf if not finite."""
    ux = position[p, 0] - build_position[p, 0]
    uy = position[p, 1] - build_position[p, 1]
    u2 = ux * ux + uy * uy
    if not (u2 <= 1.0e300):
        u2 = math.inf
    return u2


@njit(cache=True)
def block(b, row, jstart, jcol, work, position, velocity, rotation, spin, mass, inertia, external_force,
          external_moment, gx, gy, damp, cm, dt, rot, build_position, held, net, path, path_t):
    """Gather + leapfrog of the discs of block b (BLOCK discs); returns their largest
    |x - x_build|^2. net (n, 3): the contact resultant plus the external force and moment
    (walls, plate, pressure) of every disc, held ones included, written before the step
    [N, N m]. path, path_t: the held discs' path (``follow_path``; path_t < 0: none). The
    engine's time loop runs the blocks in a parallel loop and takes the maximum over the
    blocks in block order."""
    n = position.shape[0]
    umax = 0.0
    for p in range(b * BLOCK, min(n, (b + 1) * BLOCK)):
        fx, fy, mo = gather_disc(p, row, jstart, jcol, work)
        net[p, 0] = fx + external_force[p, 0]
        net[p, 1] = fy + external_force[p, 1]
        net[p, 2] = mo + external_moment[p]
        u2 = leapfrog_disc(p, fx, fy, mo, position, velocity, rotation, spin, mass, inertia, external_force,
                           external_moment, gx, gy, damp, cm, dt, rot, build_position, held, path, path_t)
        if u2 > umax:
            umax = u2
    return umax


def n_blocks(n):
    """Blocks of the integration pass for n discs."""
    return max(1, -(-n // BLOCK))


def kinetic_energy(mass, inertia, velocity, spin):
    """Translational plus rotational kinetic energy of the half-step velocities [J/m]."""
    return float(0.5 * np.dot(mass, np.einsum("ij,ij->i", velocity, velocity)) + 0.5 * np.dot(inertia, spin * spin))
