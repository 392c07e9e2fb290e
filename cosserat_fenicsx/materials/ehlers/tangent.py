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

from numba import literally, njit

NX = 12  # unknowns per point: 7 generalised stresses, plastic increment, 4 hardening variables


@njit(cache=True, error_model="numpy")
def solve_nx(A, B, nrhs):
    """Solve A X = B[:, :nrhs] for A of NX x NX by Gaussian elimination with partial pivoting.

    A and B (NX x >= nrhs) are overwritten (B by the solution). Returns False if a pivot
    vanishes (singular local Jacobian). `nrhs` is made a compile-time literal, so each call
    site (1 for the Newton step, 7 for the tangent) gets a version with constant loop bounds
    (3-15 % faster than runtime bounds, docs/reference/ehlers.md). The row updates run over the full
    width (fixed trip count): columns < k+1 of the rows below the pivot are dead storage,
    never read again, so the solution is that of the triangular loop bit for bit.
    """
    literally(nrhs)
    for k in range(NX):
        p = k
        amax = abs(A[k, k])
        for i in range(k + 1, NX):
            v = abs(A[i, k])
            if v > amax:
                amax = v
                p = i
        if not amax > 1e-300:
            return False
        if p != k:
            for j in range(NX):
                t = A[k, j]
                A[k, j] = A[p, j]
                A[p, j] = t
            for j in range(nrhs):
                t = B[k, j]
                B[k, j] = B[p, j]
                B[p, j] = t
        piv = 1.0 / A[k, k]
        for i in range(k + 1, NX):
            f = A[i, k] * piv
            if f != 0.0:
                for j in range(NX):
                    A[i, j] -= f * A[k, j]
                for j in range(nrhs):
                    B[i, j] -= f * B[k, j]
    for k in range(NX - 1, -1, -1):
        piv = 1.0 / A[k, k]
        for j in range(nrhs):
            s = B[k, j]
            for i in range(k + 1, NX):
                s -= A[k, i] * B[i, j]
            B[k, j] = s * piv
    return True


@njit(cache=True, error_model="numpy")
def consistent_tangent(J, Ce, sc, dc, t, DEp, Dp, scale, with_history, Jlu, Z, C_out, elastic):
    """C_n = dS_n/dE (3.36), (3.37) written into C_out (7x7); Z[:, :7] = dX/dE (12 x 7).

    Plain step (with_history False): C_n = first 7 rows of J^-1 [C_e; 0].
    Substep k of N (with_history True): the substep ends at E_k = E_old + t (E - E_old) and
    starts from a history h = (E_p, p) that itself depends on the final E through
    DEp = dE_p/dE (7x7) and Dp = dp/dE (4x7) of the previous substeps, so (3.36) reads
        J dX/dE = [C_e t - (C_e - sc (x) dc 1_tr) DEp ; 0 ; Dp / scale]
    (G1 depends on E_p through E_e = E - E_p and through eps_crit(tr E_p), the hardening
    rows on p_{n-1}).  J: local Jacobian at the converged state (unchanged); Ce, sc: elastic
    tangent and dS/d eps_crit there; dc = d eps_crit / d eps_p^V there; scale (4) the row
    scaling of the hardening residuals.  elastic: elastic (sub)step, S = S^e(E - E_p), so
    C_n is the right-hand side itself (J is not used).  Returns False if J is singular.
    """
    for i in range(7):
        for j in range(7):
            Z[i, j] = Ce[i, j] * t
    if with_history:
        for i in range(7):
            k1 = 3 if i < 3 else (5 if i < 5 else i + 1)
            k0 = 0 if i < 3 else (3 if i < 5 else i)
            for j in range(7):
                s = 0.0
                for k in range(k0, k1):
                    s += Ce[i, k] * DEp[k, j]
                s -= sc[i] * dc * (DEp[0, j] + DEp[1, j] + DEp[2, j])
                Z[i, j] -= s
    for j in range(7):
        Z[7, j] = 0.0
        for k in range(4):
            Z[8 + k, j] = Dp[k, j] / scale[k] if with_history else 0.0
    if not elastic:
        for i in range(NX):
            for j in range(NX):
                Jlu[i, j] = J[i, j]
        if not solve_nx(Jlu, Z, 7):
            return False
    for i in range(7):
        for j in range(7):
            C_out[i, j] = Z[i, j]
    return True


@njit(cache=True, error_model="numpy")
def propagate_history_sensitivity(Z, n, H, dndp, lam, DEp, Dp):
    """After a plastic substep: E_p,k = E_p,k-1 + dlam n_G(S, beta, delta, epsilon), p_k = X[8:12], so
    dE_p,k/dE = DEp + n (x) d dlam/dE + dlam (H dS/dE + dn/dp dp/dE) and dp_k/dE = Z[8:12]."""
    for i in range(7):
        for j in range(7):
            s = n[i] * Z[7, j]
            h = 0.0
            for k in range(7):
                h += H[i, k] * Z[k, j]
            for m in range(3):
                h += dndp[m, i] * Z[8 + m, j]
            DEp[i, j] += s + lam * h
    for k in range(4):
        for j in range(7):
            Dp[k, j] = Z[8 + k, j]
