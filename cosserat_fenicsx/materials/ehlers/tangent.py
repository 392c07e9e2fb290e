"""Consistent (algorithmic) tangent by implicit differentiation, eqs (3.35)-(3.37).

The local system G_n(E_n, S_n(E_n)) = 0 of Table 3.1 (unknowns S_n = generalised
stress, plastic increment, beta, delta, epsilon, gamma) gives (3.36)

    dG/dS_n . dS_n/dE_n = - dG/dE_n .

Only the elasticity rows G^1, G^2 depend explicitly on E_n, through
-C_e (dS^e/dE_e, including the 2 mu_c l_c^2 couple block), so
dS_n/dE_n = J^-1 [C_e; 0] and the consistent tangent C_n (3.37) is its first
7 rows.  It couples sigma-kappa and m-eps in the plastic range when k_mu != 0
and is unsymmetric (non-associated flow and hardening).
"""

from numba import njit

NX = 12  # unknowns per point: 7 generalised stresses, plastic increment, 4 hardening variables


@njit(cache=True, error_model="numpy")
def solve_inplace(A, B, nrhs):
    """Solve A X = B[:, :nrhs] by Gaussian elimination with partial pivoting.

    A (n x n) and B (n x >= nrhs) are overwritten (B by the solution).
    Returns False if a pivot vanishes (singular local Jacobian).
    """
    n = A.shape[0]
    for k in range(n):
        p = k
        amax = abs(A[k, k])
        for i in range(k + 1, n):
            v = abs(A[i, k])
            if v > amax:
                amax = v
                p = i
        if not amax > 1e-300:
            return False
        if p != k:
            for j in range(n):
                t = A[k, j]
                A[k, j] = A[p, j]
                A[p, j] = t
            for j in range(nrhs):
                t = B[k, j]
                B[k, j] = B[p, j]
                B[p, j] = t
        piv = 1.0 / A[k, k]
        for i in range(k + 1, n):
            f = A[i, k] * piv
            if f != 0.0:
                for j in range(k + 1, n):
                    A[i, j] -= f * A[k, j]
                for j in range(nrhs):
                    B[i, j] -= f * B[k, j]
    for k in range(n - 1, -1, -1):
        piv = 1.0 / A[k, k]
        for j in range(nrhs):
            s = B[k, j]
            for i in range(k + 1, n):
                s -= A[k, i] * B[i, j]
            B[k, j] = s * piv
    return True


@njit(cache=True, error_model="numpy")
def consistent_tangent(J, Ce, Jlu, Z, C_out):
    """C_n = first 7 rows of J^-1 [C_e; 0] (3.36), (3.37), written into C_out (7x7).

    J: local Jacobian dG/dS at the converged state (12x12, unchanged);
    Ce: elastic tangent at the converged elastic strain (7x7).
    Jlu (12x12) and Z (12x7) are work arrays.  Returns False if J is singular.
    """
    for i in range(NX):
        for j in range(NX):
            Jlu[i, j] = J[i, j]
        for j in range(7):
            Z[i, j] = Ce[i, j] if i < 7 else 0.0
    if not solve_inplace(Jlu, Z, 7):
        return False
    for i in range(7):
        for j in range(7):
            C_out[i, j] = Z[i, j]
    return True
