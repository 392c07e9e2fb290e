"""Periodic cell kinematics (001 eq. 7 and appendix A.1; 000 eqs. 6, 12).

The cell is spanned by the periodicity vectors Y1, Y2 = columns of ``h`` and follows the
macroscopic deformation gradient: Y_i = F Y_i^R, i.e. ``h = F h_ref``. Periodicity of
positions (000 eq. 12) holds by construction because particles are stored in fractional
coordinates; rotations are periodic because each particle exists once.

Index conventions used throughout demcell: (Grad u)_ij = du_i/dX_j, F = I + Grad u,
traction t_i = sigma_ij n_j.
"""
import math

import numpy as np
from numba import njit


@njit(cache=True)
def fractional_branch(s, i, j):
    """Minimum-image branch from centre i to centre j in fractional coordinates:
    s_j - s_i - round(s_j - s_i); the rounding picks the nearest periodic image, shifted by
    n = -round(s_j - s_i) lattice vectors."""
    a = s[j, 0] - s[i, 0]
    b = s[j, 1] - s[i, 1]
    a -= math.floor(a + 0.5)
    b -= math.floor(b + 0.5)
    return a, b


@njit(cache=True)
def branch_vector(h, s, i, j):
    """Minimum-image branch vector from centre i to centre j [m] (001 eq. A.1):
    d = h (s_j - s_i - round(s_j - s_i)) (``fractional_branch``)."""
    a, b = fractional_branch(s, i, j)
    return h[0, 0] * a + h[0, 1] * b, h[1, 0] * a + h[1, 1] * b


@njit(cache=True)
def contact_copy(s, i, a, b, lever):
    """Which periodic copy of a contact a micropolar cell counts (docs/reference/micropolar_cell.md):
    the two copies of a contact crossing the cell's side differ in rotation by kappa . Y, and
    the one counted is the copy whose contact point s_i + lever (a, b) lies in the cell
    (lever = a_i / |d|, (a, b) the fractional branch): both its discs are shifted by -m lattice
    vectors. Returns m = floor(contact point), a rule independent of how the pair is labelled."""
    return np.floor(s[i, 0] + lever * a), np.floor(s[i, 1] + lever * b)


@njit(cache=True)
def contact_frame(bx, by, ri, rj):
    """Geometry of a contact with branch vector (bx, by) between discs of radii ri, rj:
    (length l, normal n = b / l, tangent t = (-n_y, n_x), lever arms a_i = ri - ovl/2,
    a_j = rj - ovl/2 to the middle of the overlap ovl = ri + rj - l (001 eqs. A.5-A.6))."""
    l = math.sqrt(bx * bx + by * by)
    nx = bx / l
    ny = by / l
    ovl = ri + rj - l
    return l, nx, ny, -ny, nx, ri - 0.5 * ovl, rj - 0.5 * ovl


@njit(cache=True)
def cell_widths(h):
    """Perpendicular widths of the cell across Y2 and across Y1 [m]: area/|Y2|, area/|Y1|."""
    area = abs(h[0, 0] * h[1, 1] - h[0, 1] * h[1, 0])
    l1 = math.sqrt(h[0, 0] ** 2 + h[1, 0] ** 2)
    l2 = math.sqrt(h[0, 1] ** 2 + h[1, 1] ** 2)
    return area / l2, area / l1


def rotation(angle):
    """2D rotation matrix R(angle) (counter-clockwise, rad)."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s], [s, c]])


@njit(cache=True)
def polar(F):
    """Polar decomposition F = R U in 2D; returns (angle of R [rad], U). Also used inside the
    relaxation kernel (the polar ramp of a micropolar cell)."""
    angle = math.atan2(F[1, 0] - F[0, 1], F[0, 0] + F[1, 1])
    c = math.cos(angle)
    s = math.sin(angle)
    U = np.empty((2, 2))
    for b in range(2):
        U[0, b] = c * F[0, b] + s * F[1, b]
        U[1, b] = -s * F[0, b] + c * F[1, b]
    off = 0.5 * (U[0, 1] + U[1, 0])
    U[0, 1] = off
    U[1, 0] = off
    return angle, U


@njit(cache=True)
def deformation_gradient(h, h_ref):
    """F = h h_ref^-1 (001 eq. 7), in scalars: the one formula every path of demcell uses (the
    per-cell solve and the batched kernel get the same bits). Each component is a 2x2 minor
    over det h_ref, so a cell at its reference (h == h_ref) gives the identity exactly."""
    r00, r01, r10, r11 = h_ref[0, 0], h_ref[0, 1], h_ref[1, 0], h_ref[1, 1]
    det = r00 * r11 - r01 * r10
    F = np.empty((2, 2))
    F[0, 0] = (h[0, 0] * r11 - h[0, 1] * r10) / det
    F[0, 1] = (h[0, 1] * r00 - h[0, 0] * r01) / det
    F[1, 0] = (h[1, 0] * r11 - h[1, 1] * r10) / det
    F[1, 1] = (h[1, 1] * r00 - h[1, 0] * r01) / det
    return F


#: largest count of sub-steps or ramp steps: the step budget of a solve ends it long before,
#: and the int64 conversion of a larger (or undefined) quotient has no defined value
MAX_COUNT = 1e15


@njit(cache=True)
def substep_count(x):
    """ceil(x) as an integer, at most MAX_COUNT (also for x = nan or inf)."""
    if not x < MAX_COUNT:
        x = MAX_COUNT
    return int(math.ceil(x))


@njit(cache=True)
def path_setup(F0, F1, max_increment, steps, geo):
    """Number of sub-steps from F0 to F1 with max|dF| <= max_increment (at least ``steps``),
    and in geo (10 slots) what path_point needs: the rotation angle a0 of F0, the turn da to
    F1 (in (-pi, pi]) and the stretches U0, U1 of both polar decompositions."""
    a0, U0 = polar(F0)
    a1, U1 = polar(F1)
    da = a1 - a0
    da -= 2.0 * math.pi * math.floor((da + math.pi) / (2.0 * math.pi))
    dmax = 0.0
    umax = 1.0
    for a in range(2):
        for b in range(2):
            dmax = max(dmax, abs(F1[a, b] - F0[a, b]))
            umax = max(umax, abs(U0[a, b]))
    size = max(dmax, abs(da) * umax)
    geo[0] = a0
    geo[1] = da
    for a in range(2):
        for b in range(2):
            geo[2 + 2 * a + b] = U0[a, b]
            geo[6 + 2 * a + b] = U1[a, b]
    return max(1, substep_count(size / max_increment), steps)


@njit(cache=True)
def path_point(geo, tau, Fk):
    """F at the fraction tau of the path of path_setup: R(a0 + tau da) (U0 + tau (U1 - U0))."""
    c = math.cos(geo[0] + tau * geo[1])
    s = math.sin(geo[0] + tau * geo[1])
    for b in range(2):
        u0b = geo[2 + b] + tau * (geo[6 + b] - geo[2 + b])
        u1b = geo[4 + b] + tau * (geo[8 + b] - geo[4 + b])
        Fk[0, b] = c * u0b - s * u1b
        Fk[1, b] = s * u0b + c * u1b


def deformation_path(F0, F1, max_increment, steps=None):
    """Intermediate deformation gradients from F0 to F1 (F1 included), each sub-step with
    max|dF| <= max_increment (or at least ``steps`` sub-steps). The rotation and the stretch of the polar decompositions are
    interpolated separately, so a rigid rotation stays a rigid rotation on the way (a linear
    path in F would shrink the cell half-way through a large rotation). (path_setup and
    path_point: the arithmetic of the Numba solve, quasistatic.solve_cell.)
    """
    F0 = np.ascontiguousarray(F0, dtype=float)
    F1 = np.ascontiguousarray(F1, dtype=float)
    geo = np.empty(10)
    n = path_setup(F0, F1, float(max_increment), int(steps or 1), geo)
    out = []
    for k in range(1, n + 1):
        Fk = np.empty((2, 2))
        path_point(geo, k / n, Fk)
        out.append(Fk)
    out[-1] = F1.copy()
    return out


def cauchy_to_pk1(sigma, F):
    """First Piola-Kirchhoff stress P = J sigma F^-T (inverse of 000 eq. 16)."""
    return np.linalg.det(F) * sigma @ np.linalg.inv(F).T


@njit(cache=True)
def reduce_lattice(h, h_ref, h_build, s, s_build):
    """Lattice reduction of a sheared cell (Lees-Edwards-like remapping): replace Y2 by
    Y2 - k Y1 (or Y1 by Y1 - k Y2) with integer k while that shortens the vectors. The
    periodic medium, F = h h_ref^-1, every particle and every contact are unchanged; only
    the choice of the base cell changes (h -> h M, h_ref -> h_ref M, s -> M^-1 s with M
    unimodular). Keeps the minimum-image convention valid under large shears. In place;
    returns the number of reductions applied."""
    count = 0
    for _ in range(20):
        d12 = h[0, 0] * h[0, 1] + h[1, 0] * h[1, 1]
        d11 = h[0, 0] * h[0, 0] + h[1, 0] * h[1, 0]
        d22 = h[0, 1] * h[0, 1] + h[1, 1] * h[1, 1]
        k2 = round(d12 / d11)
        k1 = round(d12 / d22)
        if k2 != 0 and d22 > d11:          # Y2 -= k2 Y1; s1 += k2 s2
            for m in (h, h_ref, h_build):
                m[0, 1] -= k2 * m[0, 0]
                m[1, 1] -= k2 * m[1, 0]
            for x in (s, s_build):
                for i in range(x.shape[0]):
                    x[i, 0] = (x[i, 0] + k2 * x[i, 1]) % 1.0
                    x[i, 1] = x[i, 1] % 1.0
        elif k1 != 0 and d11 > d22:        # Y1 -= k1 Y2; s2 += k1 s1
            for m in (h, h_ref, h_build):
                m[0, 0] -= k1 * m[0, 1]
                m[1, 0] -= k1 * m[1, 1]
            for x in (s, s_build):
                for i in range(x.shape[0]):
                    x[i, 1] = (x[i, 1] + k1 * x[i, 0]) % 1.0
                    x[i, 0] = x[i, 0] % 1.0
        else:
            break
        count += 1
    return count


def reduce_cell(state):
    """reduce_lattice on a CellState (see there)."""
    return reduce_lattice(state.h, state.h_ref, state.h_build, state.s, state.s_build)
