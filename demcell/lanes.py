"""Sums over the discs of a cell taken in an order that a GPU block can take too.

A few sums over the particles feed the motion at every step: FIRE's power and norms
(``relaxation.advance``) and the micropolar cell's held mean rotation
(``relaxation.constrain_moments``, ``relaxation.leapfrog_micropolar``). A GPU block
(``demcell.gpu``) cannot add n numbers one after the other without stalling its threads, so
these sums are taken in an order that both can:

    LANES partial sums, lane l adding the particles l, l + LANES, l + 2 LANES, ... in turn
    (each from 0.0), then the partials combined pairwise in a fixed tree: lane l takes
    lane l + 16, then l + 8, 4, 2, 1.

The CPU kernels and the GPU kernels then do the same floating-point operations in the same
order, and give the same bits (exactly in Numba's CUDA simulator; on a GPU within the fused
multiply-adds its compiler forms). Any order is as accurate as the sequential one for these
sums of a few hundred terms; the one here is merely fixed.
"""
from numba import njit

#: partial sums per reduction (one warp of a GPU block)
LANES = 32


@njit(cache=True)
def combine(part):
    """The tree of the module doc over part (LANES,), in place; returns the total."""
    off = LANES // 2
    while off > 0:
        for lane in range(off):
            part[lane] = part[lane] + part[lane + off]
        off //= 2
    return part[0]


@njit(cache=True)
def fire_sums(force, v, moment, omega, rot, part):
    """FIRE's sums over the discs (Bitzek et al. 2006): the power F . v (with M omega when
    the discs rotate), |v|^2, |F|^2, |omega|^2, |M|^2, in the order of the module doc.
    part: scratch (5, LANES)."""
    n = force.shape[0]
    for lane in range(LANES):
        power = 0.0
        vn2 = 0.0
        fn2 = 0.0
        wn2 = 0.0
        mn2 = 0.0
        for i in range(lane, n, LANES):
            power += force[i, 0] * v[i, 0] + force[i, 1] * v[i, 1]
            vn2 += v[i, 0] * v[i, 0] + v[i, 1] * v[i, 1]
            fn2 += force[i, 0] * force[i, 0] + force[i, 1] * force[i, 1]
            if rot:
                power += moment[i] * omega[i]
                wn2 += omega[i] * omega[i]
                mn2 += moment[i] * moment[i]
        part[0, lane] = power
        part[1, lane] = vn2
        part[2, lane] = fn2
        part[3, lane] = wn2
        part[4, lane] = mn2
    return combine(part[0]), combine(part[1]), combine(part[2]), combine(part[3]), combine(part[4])


@njit(cache=True)
def sum_products(a, b, c, part):
    """sum_i (a_i b_i) c_i in the order of the module doc; part: scratch (LANES,)."""
    n = a.shape[0]
    for lane in range(LANES):
        acc = 0.0
        for i in range(lane, n, LANES):
            acc += a[i] * b[i] * c[i]
        part[lane] = acc
    return combine(part)


@njit(cache=True)
def dot(a, b, part):
    """sum_i a_i b_i in the order of the module doc; part: scratch (LANES,)."""
    n = a.shape[0]
    for lane in range(LANES):
        acc = 0.0
        for i in range(lane, n, LANES):
            acc += a[i] * b[i]
        part[lane] = acc
    return combine(part)
