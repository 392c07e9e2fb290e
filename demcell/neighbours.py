"""Verlet neighbour list of a periodic cell (contact detection).

A pair (i, j), i < j, is listed when the minimum-image distance is below
R_i + R_j + skin. The list is rebuilt when the particles or the cell moved enough that
an unlisted pair could touch (criterion in ``needs_rebuild``). The contact history
(tangential force, rolling moment, bond flag, last branch vector) is carried over from
the old list to the new one by a merge on the sorted pair keys i * N + j.
"""
import math

import numpy as np
from numba import njit

from .periodic_cell import branch_vector, cell_widths


@njit(cache=True)
def cell_strain_norm(h, h_build):
    """||h h_build^-1 - I||_F: how much the cell deformed since the last build [-]."""
    det = h_build[0, 0] * h_build[1, 1] - h_build[0, 1] * h_build[1, 0]
    inv00 = h_build[1, 1] / det
    inv01 = -h_build[0, 1] / det
    inv10 = -h_build[1, 0] / det
    inv11 = h_build[0, 0] / det
    g00 = h[0, 0] * inv00 + h[0, 1] * inv10 - 1.0
    g01 = h[0, 0] * inv01 + h[0, 1] * inv11
    g10 = h[1, 0] * inv00 + h[1, 1] * inv10
    g11 = h[1, 0] * inv01 + h[1, 1] * inv11 - 1.0
    return math.sqrt(g00 * g00 + g01 * g01 + g10 * g10 + g11 * g11)


@njit(cache=True)
def max_displacement(h, s, s_build):
    """max_i |h (s_i - s_i^build)| [m]: largest fluctuating displacement since the last build."""
    umax2 = 0.0
    for i in range(s.shape[0]):
        a = s[i, 0] - s_build[i, 0]
        b = s[i, 1] - s_build[i, 1]
        a -= math.floor(a + 0.5)
        b -= math.floor(b + 0.5)
        ux = h[0, 0] * a + h[0, 1] * b
        uy = h[1, 0] * a + h[1, 1] * b
        u2 = ux * ux + uy * uy
        if u2 > umax2:
            umax2 = u2
    return math.sqrt(umax2)


def needs_rebuild(h, h_build, s, s_build, skin, r_cut):
    """True if some pair farther apart than R_i + R_j + skin at the last build may now
    overlap: 2 max_i |u_i| + ||h h_build^-1 - I||_F r_cut > skin, with r_cut = 2 R_max + skin.
    (The kernel evaluates the same bound with an incrementally updated max |u_i|.)"""
    return 2.0 * max_displacement(h, s, s_build) + cell_strain_norm(h, h_build) * r_cut > skin


@njit(cache=True)
def build_pairs(h, s, radius, skin, new_i, new_j):
    """Fill new_i/new_j with all pairs i < j closer than R_i + R_j + skin (sorted by i then j).
    Returns the number of pairs, -1 if the capacity of new_i is too small, -2 if the cell is
    too small or too distorted for the minimum-image convention (r_cut > half a width)."""
    n = radius.shape[0]
    rmax = 0.0
    for i in range(n):
        rmax = max(rmax, radius[i])
    rc = 2.0 * rmax + skin
    w1, w2 = cell_widths(h)
    if rc > 0.5 * min(w1, w2):
        return -2
    cap = new_i.shape[0]
    nb1 = int(w1 / rc)
    nb2 = int(w2 / rc)
    # a cell stretched far beyond its particles (a diverging macro iterate) would need
    # (w / rc)^2 bins: cap them at about 4 per particle (larger bins stay correct)
    while nb1 * nb2 > 4 * n + 9 and max(nb1, nb2) > 3:
        if nb1 >= nb2:
            nb1 = max(3, nb1 // 2)
        else:
            nb2 = max(3, nb2 // 2)
    count = 0
    if nb1 < 3 or nb2 < 3:
        for i in range(n):
            for j in range(i + 1, n):
                dx, dy = branch_vector(h, s, i, j)
                lim = radius[i] + radius[j] + skin
                if dx * dx + dy * dy < lim * lim:
                    if count >= cap:
                        return -1
                    new_i[count] = i
                    new_j[count] = j
                    count += 1
        return count
    # linked cells on the fractional coordinates
    head = -np.ones(nb1 * nb2, np.int64)
    nxt = -np.ones(n, np.int64)
    bin_of = np.empty(n, np.int64)
    for i in range(n):
        b1 = int(s[i, 0] * nb1) % nb1
        b2 = int(s[i, 1] * nb2) % nb2
        b = b1 * nb2 + b2
        bin_of[i] = b
        nxt[i] = head[b]
        head[b] = i
    buf = np.empty(n, np.int64)
    for i in range(n):
        b1 = bin_of[i] // nb2
        b2 = bin_of[i] % nb2
        m = 0
        for o1 in range(-1, 2):
            c1 = (b1 + o1) % nb1
            for o2 in range(-1, 2):
                c2 = (b2 + o2) % nb2
                j = head[c1 * nb2 + c2]
                while j >= 0:
                    if j > i:
                        dx, dy = branch_vector(h, s, i, j)
                        lim = radius[i] + radius[j] + skin
                        if dx * dx + dy * dy < lim * lim:
                            buf[m] = j
                            m += 1
                    j = nxt[j]
        if m > 1:
            buf[:m].sort()
        if count + m > cap:
            return -1
        for k in range(m):
            new_i[count] = i
            new_j[count] = buf[k]
            count += 1
    return count


@njit(cache=True)
def merge_history(n_particles, old_n, old_i, old_j, new_n, new_i, new_j,
                  fs, mr, bonded, touching, d_prev, fn,
                  t_fs, t_mr, t_bonded, t_touching, t_d_prev, t_fn):
    """Copy the per-pair history from the old list (sorted) into the new list (sorted),
    using scratch arrays t_* of the new capacity. Pairs that left the list lose their
    history (they are farther apart than the skin, hence not touching, unless a bond was
    stretched beyond the skin, in which case the bond is counted as broken).
    Returns the number of bonded pairs lost that way."""
    a = 0
    lost = 0
    for k in range(new_n):
        key = new_i[k] * n_particles + new_j[k]
        while a < old_n and old_i[a] * n_particles + old_j[a] < key:
            if bonded[a] == 1:
                lost += 1
            a += 1
        if a < old_n and old_i[a] * n_particles + old_j[a] == key:
            t_fs[k] = fs[a]
            t_mr[k] = mr[a]
            t_bonded[k] = bonded[a]
            t_touching[k] = touching[a]
            t_d_prev[k, 0] = d_prev[a, 0]
            t_d_prev[k, 1] = d_prev[a, 1]
            t_fn[k] = fn[a]
            a += 1
        else:
            t_fs[k] = 0.0
            t_mr[k] = 0.0
            t_bonded[k] = 0
            t_touching[k] = 0
            t_d_prev[k, 0] = 0.0
            t_d_prev[k, 1] = 0.0
            t_fn[k] = 0.0
    while a < old_n:
        if bonded[a] == 1:
            lost += 1
        a += 1
    return lost
