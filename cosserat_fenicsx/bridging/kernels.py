"""Compiled loops of the bridging-scale coarse step, pure functions over arrays.

The products with the shape-function matrix N (CSR, one row per particle component) give the
same sums in the same order as scipy's CSR products they replace (row by row, entries in
index order, from zero), so a run is the same bit for bit; what they save is the Python and
temporary arrays of a coarse step that runs thousands of times.
"""
import math

from numba import njit


@njit(cache=True)
def rows_times(indptr, indices, data, rows, x, out):
    """out[r] = sum_k N[rows[r], k] x[k] for the listed rows of the CSR matrix N (indptr,
    indices, data)."""
    for r in range(rows.size):
        i = rows[r]
        s = 0.0
        for jj in range(indptr[i], indptr[i + 1]):
            s += data[jj] * x[indices[jj]]
        out[r] = s


@njit(cache=True)
def rows_times3(indptr, indices, data, x0, x1, x2, out):
    """out[i, f] = sum_k N[i, k] x_f[k] for three fields at once (out (rows, 3))."""
    for i in range(indptr.size - 1):
        s0 = 0.0
        s1 = 0.0
        s2 = 0.0
        for jj in range(indptr[i], indptr[i + 1]):
            a = data[jj]
            k = indices[jj]
            s0 += a * x0[k]
            s1 += a * x1[k]
            s2 += a * x2[k]
        out[i, 0] = s0
        out[i, 1] = s1
        out[i, 2] = s2


@njit(cache=True)
def transpose_times(indptr, indices, data, f, out):
    """out[k] = sum_i N[i, k] f[i] (out zeroed first), the rows i taken in increasing order:
    the order of a CSR product with N^T whose rows list their entries by increasing i."""
    out[:] = 0.0
    for i in range(indptr.size - 1):
        fi = f[i]
        for jj in range(indptr[i], indptr[i + 1]):
            out[indices[jj]] += data[jj] * fi


@njit(cache=True)
def set_path_rows(rows, values, offset, start, velocity, acceleration):
    """The virtual grains' path from the interpolated fields: values (3 n_v, 3) holds, per
    grain component row 3 p + c, the (d, v, a) of the continuum at the grain; start[rows[p]] =
    offset[p] + d (offset: the reference position (x, y), 0 for the rotation), velocity and
    acceleration likewise (003 eqs 17, 25-26)."""
    for p in range(rows.size):
        r = rows[p]
        for c in range(3):
            start[r, c] = values[3 * p + c, 0] + offset[p, c] if c < 2 else values[3 * p + c, 0]
            velocity[r, c] = values[3 * p + c, 1]
            acceleration[r, c] = values[3 * p + c, 2]


@njit(cache=True)
def any_outside(position, rows, x0, x1, y0, y1):
    """True if a centre position[rows[k]] lies outside the box [x0, x1] x [y0, y1] (or is not
    finite)."""
    for k in range(rows.size):
        x = position[rows[k], 0]
        y = position[rows[k], 1]
        if not (x >= x0 and x <= x1 and y >= y0 and y <= y1):
            return True
    return False


@njit(cache=True)
def all_finite(a):
    """True if every value of the C-contiguous array a is finite."""
    x = a.ravel()
    for i in range(x.size):
        if not (abs(x[i]) < math.inf):
            return False
    return True
