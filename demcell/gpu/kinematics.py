"""periodic_cell.py's kinematics as CUDA device functions (the same operations): the polar
decomposition, F = h h_ref^-1, the sub-step path, the cell strain since the last build, and
the lattice reduction of a sheared cell. 2x2 matrices are passed as four scalars or as the
row-major columns of the per-cell array cf (layout.H, HB, HREF)."""
import math

from numba import cuda

from ..periodic_cell import MAX_COUNT
from ..slots import H, HB, HREF, SBX, SBY, SX, SY


@cuda.jit(device=True)
def nearest_image(a, b, h00, h01, h10, h11):
    """The nearest periodic image of the fractional vector (a, b) (periodic_cell.fractional_branch):
    (a, b) - round(a, b), and h times it [m]."""
    a -= math.floor(a + 0.5)
    b -= math.floor(b + 0.5)
    return a, b, h00 * a + h01 * b, h10 * a + h11 * b


@cuda.jit(device=True)
def branch_vector(pf, i, j, h00, h01, h10, h11):
    """periodic_cell.branch_vector from disc i to disc j (global indices): the fractional branch
    (a, b) of the nearest image and the branch vector (dx, dy) [m]."""
    return nearest_image(pf[SX, j] - pf[SX, i], pf[SY, j] - pf[SY, i], h00, h01, h10, h11)


@cuda.jit(device=True)
def inv2(a00, a01, a10, a11):
    """relaxation._inv2_scalars: the inverse of a 2x2 matrix."""
    det = a00 * a11 - a01 * a10
    return a11 / det, -a01 / det, -a10 / det, a00 / det


@cuda.jit(device=True)
def polar(f00, f01, f10, f11):
    """periodic_cell.polar: (angle of R [rad], U00, U01, U10, U11) of F = R U."""
    angle = math.atan2(f10 - f01, f00 + f11)
    c = math.cos(angle)
    s = math.sin(angle)
    u00 = c * f00 + s * f10
    u01 = c * f01 + s * f11
    u10 = -s * f00 + c * f10
    u11 = -s * f01 + c * f11
    off = 0.5 * (u01 + u10)
    return angle, u00, off, off, u11


@cuda.jit(device=True)
def deformation_gradient(cf, c, col):
    """periodic_cell.deformation_gradient of the cell matrix at cf[c, col:col + 4] against
    h_ref: (F00, F01, F10, F11)."""
    r00 = cf[c, HREF]
    r01 = cf[c, HREF + 1]
    r10 = cf[c, HREF + 2]
    r11 = cf[c, HREF + 3]
    det = r00 * r11 - r01 * r10
    h00 = cf[c, col]
    h01 = cf[c, col + 1]
    h10 = cf[c, col + 2]
    h11 = cf[c, col + 3]
    return ((h00 * r11 - h01 * r10) / det, (h01 * r00 - h00 * r01) / det,
            (h10 * r11 - h11 * r10) / det, (h11 * r00 - h10 * r01) / det)


@cuda.jit(device=True)
def cell_strain_norm(h00, h01, h10, h11, b00, b01, b10, b11):
    """neighbours.cell_strain_norm: ||h h_build^-1 - I||_F."""
    det = b00 * b11 - b01 * b10
    inv00 = b11 / det
    inv01 = -b01 / det
    inv10 = -b10 / det
    inv11 = b00 / det
    g00 = h00 * inv00 + h01 * inv10 - 1.0
    g01 = h00 * inv01 + h01 * inv11
    g10 = h10 * inv00 + h11 * inv10
    g11 = h10 * inv01 + h11 * inv11 - 1.0
    return math.sqrt(g00 * g00 + g01 * g01 + g10 * g10 + g11 * g11)


@cuda.jit(device=True)
def path_setup(F0, F1, max_increment, steps, geo):
    """periodic_cell.path_setup (F0, F1 as 4-vectors, row-major): the number of sub-steps,
    and the path in geo (10 slots)."""
    a0, p00, p01, p10, p11 = polar(F0[0], F0[1], F0[2], F0[3])
    a1, q00, q01, q10, q11 = polar(F1[0], F1[1], F1[2], F1[3])
    da = a1 - a0
    da -= 2.0 * math.pi * math.floor((da + math.pi) / (2.0 * math.pi))
    dmax = 0.0
    for m in range(4):
        dmax = max(dmax, abs(F1[m] - F0[m]))
    umax = 1.0
    umax = max(umax, abs(p00))
    umax = max(umax, abs(p01))
    umax = max(umax, abs(p10))
    umax = max(umax, abs(p11))
    size = max(dmax, abs(da) * umax)
    geo[0] = a0
    geo[1] = da
    geo[2] = p00
    geo[3] = p01
    geo[4] = p10
    geo[5] = p11
    geo[6] = q00
    geo[7] = q01
    geo[8] = q10
    geo[9] = q11
    return max(1, substep_count(size / max_increment), steps)


@cuda.jit(device=True)
def substep_count(x):
    """periodic_cell.substep_count: ceil(x) as an integer, at most MAX_COUNT (nan and inf too)."""
    if not x < MAX_COUNT:
        x = MAX_COUNT
    return int(math.ceil(x))


@cuda.jit(device=True)
def path_point(geo, tau, Fk):
    """periodic_cell.path_point into Fk (4-vector, row-major)."""
    c = math.cos(geo[0] + tau * geo[1])
    s = math.sin(geo[0] + tau * geo[1])
    for b in range(2):
        u0b = geo[2 + b] + tau * (geo[6 + b] - geo[2 + b])
        u1b = geo[4 + b] + tau * (geo[8 + b] - geo[4 + b])
        Fk[b] = c * u0b - s * u1b
        Fk[2 + b] = s * u0b + c * u1b


@cuda.jit(device=True)
def reduce_lattice(cf, c, pf, p0, n):
    """periodic_cell.reduce_lattice on cell c (one thread): h, h_ref, h_build and the
    fractional positions s, s_build of its discs, in place."""
    for _ in range(20):
        d12 = cf[c, H] * cf[c, H + 1] + cf[c, H + 2] * cf[c, H + 3]
        d11 = cf[c, H] * cf[c, H] + cf[c, H + 2] * cf[c, H + 2]
        d22 = cf[c, H + 1] * cf[c, H + 1] + cf[c, H + 3] * cf[c, H + 3]
        k2 = round(d12 / d11)
        k1 = round(d12 / d22)
        if k2 != 0 and d22 > d11:          # Y2 -= k2 Y1; s1 += k2 s2
            for col in (H, HREF, HB):
                cf[c, col + 1] -= k2 * cf[c, col]
                cf[c, col + 3] -= k2 * cf[c, col + 2]
            for i in range(p0, p0 + n):
                pf[SX, i] = (pf[SX, i] + k2 * pf[SY, i]) % 1.0
                pf[SY, i] = pf[SY, i] % 1.0
                pf[SBX, i] = (pf[SBX, i] + k2 * pf[SBY, i]) % 1.0
                pf[SBY, i] = pf[SBY, i] % 1.0
        elif k1 != 0 and d11 > d22:        # Y1 -= k1 Y2; s2 += k1 s1
            for col in (H, HREF, HB):
                cf[c, col] -= k1 * cf[c, col + 1]
                cf[c, col + 2] -= k1 * cf[c, col + 3]
            for i in range(p0, p0 + n):
                pf[SY, i] = (pf[SY, i] + k1 * pf[SX, i]) % 1.0
                pf[SX, i] = pf[SX, i] % 1.0
                pf[SBY, i] = (pf[SBY, i] + k1 * pf[SBX, i]) % 1.0
                pf[SBX, i] = pf[SBX, i] % 1.0
        else:
            break
