"""A finite rigid plate (003 section 3: the strip footing) acting on the discs of a specimen.

The plate is the rectangle x0 <= x <= x1, y >= y (its bottom face at height y, unbounded
upwards), moving without rotation at a prescribed velocity (v_x, v_y) [m/s]. A disc touches it
where its centre is closer than its radius to the rectangle: the contact point is the point of
the rectangle nearest the centre, so a disc whose centre is under the plate (x0 <= x_p <= x1)
meets the flat face (normal +-y), one beside it below the face meets a corner (normal from the
corner to the centre) and one beside it above the face meets a side (normal +-x, once the plate
has sunk into the packing). A centre inside the rectangle is pushed out through the face.

Law (003 Table 1 has none for the plate [gap]; 003-bsm.md section 6 [R]): the disc-disc k_N
with the same dashpot as a wall (walls.py, 004 eq. 7.43) and, if the plate is rough, a
tangential spring k_s with the Coulomb limit mu f_n (the law's friction), its force history
kept per disc; a smooth plate carries no tangential force. The reaction is recorded as the
force the plate exerts on the discs [N per m of depth]; the load on the footing is its
opposite.
"""
import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from .. import checks
from ..errors import InputError

# slots of the plate vector of the kernels
(PL_X0, PL_X1, PL_Y, PL_VX, PL_VY, PL_MU, PL_ACTIVE, N_PLATE) = range(8)


@dataclass(frozen=True)
class Plate:
    """A rigid plate: bottom face from x0 to x1 [m] at height y [m], velocity (v_x, v_y) [m/s]
    (a footing pushed down has v_y < 0), rough: tangential spring and Coulomb friction with
    the contact law's k_s and mu (False: smooth)."""
    x0: float
    x1: float
    y: float
    velocity: tuple = (0.0, 0.0)
    rough: bool = False

    def __post_init__(self):
        s = object.__setattr__
        for name in ("x0", "x1", "y"):
            s(self, name, checks.number(f"Plate.{name}", getattr(self, name)))
        if not self.x1 > self.x0:
            raise InputError(f"Plate needs x1 > x0, got x0 = {self.x0:g} m, x1 = {self.x1:g} m")
        s(self, "velocity", tuple(float(v) for v in checks.array("Plate.velocity", self.velocity, (2,))))
        if not isinstance(self.rough, (bool, np.bool_)):
            raise InputError(f"Plate.rough must be True or False, got {self.rough!r}")
        s(self, "rough", bool(self.rough))

    @property
    def width(self):
        return self.x1 - self.x0

    def vector(self, friction):
        """The float64 plate vector of the kernels (friction: the law's mu, used if rough)."""
        v = np.zeros(N_PLATE)
        v[PL_X0], v[PL_X1], v[PL_Y] = self.x0, self.x1, self.y
        v[PL_VX], v[PL_VY] = self.velocity
        v[PL_MU] = friction if self.rough else 0.0
        v[PL_ACTIVE] = 1.0
        return v


def no_plate():
    """The plate vector of a specimen without a plate."""
    return np.zeros(N_PLATE)


@njit(cache=True)
def plate_contact(x, y, r, plate):
    """(overlap [m], n_x, n_y): the disc (x, y, r) against the plate rectangle, n the unit
    normal from the plate into the disc; overlap <= 0 when apart."""
    x0 = plate[PL_X0]
    x1 = plate[PL_X1]
    yf = plate[PL_Y]
    cx = min(max(x, x0), x1)
    cy = max(y, yf)
    dx = x - cx
    dy = y - cy
    d2 = dx * dx + dy * dy
    if d2 > 0.0:
        d = math.sqrt(d2)
        return r - d, dx / d, dy / d
    # centre on or inside the rectangle: out through the bottom face
    return r + (y - yf), 0.0, -1.0


@njit(cache=True)
def plate_candidates(position, radius, plate, skin):
    """Discs (c,) whose gap to the plate is below the skin [m] (none without a plate)."""
    n = position.shape[0]
    if plate[PL_ACTIVE] < 0.5:
        return np.zeros(0, np.int64)
    flag = np.zeros(n, np.bool_)
    count = 0
    for p in range(n):
        h, nx, ny = plate_contact(position[p, 0], position[p, 1], radius[p], plate)
        if h > -skin:
            flag[p] = True
            count += 1
    out = np.empty(count, np.int64)
    c = 0
    for p in range(n):
        if flag[p]:
            out[c] = p
            c += 1
    return out


@njit(cache=True)
def plate_forces(cand, position, velocity, spin, radius, mass, plate, plate_fs, kn, ks, dashpot, ratio, clip, dt,
                 external_force, external_moment, plate_force):
    """The plate on its candidate discs: ADDS into external_force (n, 2) and
    external_moment (n,), writes plate_force (2,) (the plate's force on the discs [N]).
    plate_fs (n,): tangential force history per disc (rough plate only). Normal force
    kn overlap + c d(overlap)/dt (c as a wall's: walls.wall_forces), clipped at >= 0 if clip."""
    plate_force[0] = 0.0
    plate_force[1] = 0.0
    mu = plate[PL_MU]
    vpx = plate[PL_VX]
    vpy = plate[PL_VY]
    for c in range(cand.shape[0]):
        p = cand[c]
        h, nx, ny = plate_contact(position[p, 0], position[p, 1], radius[p], plate)
        if h <= 0.0:
            plate_fs[p] = 0.0
            continue
        rvx = velocity[p, 0] - vpx
        rvy = velocity[p, 1] - vpy
        h_rate = -(rvx * nx + rvy * ny)
        coef = dashpot if ratio == 0.0 else 2.0 * ratio * math.sqrt(0.5 * mass[p] * kn)
        f = kn * h + coef * h_rate
        if clip and f < 0.0:
            f = 0.0
        fx = f * nx
        fy = f * ny
        if mu > 0.0:
            # t = (-n_y, n_x); the contact point (centre - r n) slips at (v - v_plate).t - r omega
            tx = -ny
            ty = nx
            slip = (rvx * tx + rvy * ty - radius[p] * spin[p]) * dt
            ft = plate_fs[p] - ks * slip
            lim = mu * f
            if abs(ft) > lim:
                ft = math.copysign(lim, ft)
            plate_fs[p] = ft
            fx += ft * tx
            fy += ft * ty
            external_moment[p] += -radius[p] * ft
        external_force[p, 0] += fx
        external_force[p, 1] += fy
        plate_force[0] += fx
        plate_force[1] += fy


@njit(cache=True)
def move_plate(plate, dt):
    """The plate moves by its velocity over dt [s]."""
    plate[PL_X0] += plate[PL_VX] * dt
    plate[PL_X1] += plate[PL_VX] * dt
    plate[PL_Y] += plate[PL_VY] * dt


__all__ = ["Plate", "no_plate", "plate_contact", "plate_candidates", "plate_forces", "move_plate"]
