"""Nonlinear micropolar elasticity with the compression point, eqs (2.67)-(2.75).

Generalised 2D (plane) vectors, index order used by every kernel::

    0: 11   1: 22   2: 33   3: 12   4: 21   5: (3)1   6: (3)2

strain  E = (eps11, eps22, eps33, eps12, eps21, kappa31, kappa32)   [-], [1/m]
stress  S = (sig11, sig22, sig33, sig12, sig21, m31, m32)           [MPa], [MPa m]

(internal units, see parameters.py).  Tension positive; eps_ij = u_i,j + e_ij3 phi
(2.49), kappa_3j = phi_,j (2.52).
"""

import numpy as np
from numba import njit

from .parameters import P_LMBDA, P_L_C, P_MU, P_MU_C, P_N0, P_NMAX


@njit(cache=True, error_model="numpy")
def compression_point(eps_p_vol, params):
    """Critical volumetric elastic strain eps_crit and d eps_crit / d eps_p^V.

    (2.67), (2.70): n_p^S = n0^S (1 - eps_p^V), eps_crit = 1 - n_max^S / n_p^S  (< 0).
    Returns (c, dc/deps_p^V); dc/deps_p^V = -n_max / (n0 (1 - eps_p^V)^2).
    """
    n0 = params[P_N0]
    nmax = params[P_NMAX]
    one_m = 1.0 - eps_p_vol
    c = 1.0 - nmax / (n0 * one_m)
    dc = -nmax / (n0 * one_m * one_m)
    return c, dc


@njit(cache=True, error_model="numpy")
def elastic_stress(Ee, c, params, S, C, sc):
    """Stress, couple stress and their derivatives for elastic strain ``Ee``.

    (2.73): sigma = 2 mu eps_e,sym + lambda c/(c - x) x I + 2 mu_c eps_e,skw, x = tr eps_e
    (2.74): m = 2 mu_c l_c^2 kappa_e
    Writes S (7), the elastic tangent C = dS/dEe (7x7; bulk term lambda c^2/(c-x)^2,
    spec section 3) and sc = dS/dc (volumetric part -lambda x^2/(c-x)^2 I).
    Returns False when x <= c (elastic state beyond the compression point,
    where the law changes sign and is meaningless), True otherwise.
    """
    mu = params[P_MU]
    lam = params[P_LMBDA]
    muc = params[P_MU_C]
    lc = params[P_L_C]
    x = Ee[0] + Ee[1] + Ee[2]
    d = c - x  # < 0 in the admissible range x > c
    ok = d < 0.0
    if not ok:
        d = -1e-150  # keeps d*d representable; the caller rejects this state anyway
    f = lam * c / d
    for i in range(7):
        sc[i] = 0.0
        for j in range(7):
            C[i, j] = 0.0
    vol = f * x
    kb = lam * c * c / (d * d)
    for i in range(3):
        S[i] = 2.0 * mu * Ee[i] + vol
        sc[i] = -lam * x * x / (d * d)
        C[i, i] = 2.0 * mu
        for j in range(3):
            C[i, j] += kb
    S[3] = (mu + muc) * Ee[3] + (mu - muc) * Ee[4]
    S[4] = (mu + muc) * Ee[4] + (mu - muc) * Ee[3]
    C[3, 3] = mu + muc
    C[4, 4] = mu + muc
    C[3, 4] = mu - muc
    C[4, 3] = mu - muc
    kc = 2.0 * muc * lc * lc
    S[5] = kc * Ee[5]
    S[6] = kc * Ee[6]
    C[5, 5] = kc
    C[6, 6] = kc
    return ok


@njit(cache=True, error_model="numpy")
def volumetric_energy(x, c, lmbda):
    """Volumetric part of the free energy consistent with (2.73) [MPa].

    (2.72) as printed, lambda c {x + c[ln(c - x) - ln c]}, differentiates to
    -lambda c x/(c - x), the negative of (2.73) (spec section 3, sign slip), so we
    use psi_vol = -lambda c {x + c ln(1 - x/c)}, d psi_vol/dx = lambda c x/(c - x).
    """
    return -lmbda * c * (x + c * np.log(1.0 - x / c))
