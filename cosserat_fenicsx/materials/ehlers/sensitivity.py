"""Semi-analytical parameter sensitivities of one material-point step (thesis section 5.2).

The local system of Table 3.1, G(X; E, h_{n-1}, s) = 0 with X = (S, dlam, beta, delta,
epsilon, gamma), is differentiated implicitly with respect to the material parameters s,
reusing the Jacobian J = dG/dX of the consistent tangent (3.36):

    J dX/ds = -[dG/ds + dG/dh_{n-1} dh_{n-1}/ds + dG/dE dE/ds]                 (5.22), (5.23)
    E_p,n = E_p,n-1 + dlam n_G(X; s)  ->  dE_p,n/ds by the chain rule             (5.30)-(5.32)
    p_n = X[8:12]                     ->  dp_n/ds = dX[8:12]/ds                   (5.29)

Forward mode: the derivatives are carried as columns, seven for the final strain E_n
(their stress rows are the consistent tangent C_n, eq. 3.37, which the kernel also
returns: a check) and one per parameter at fixed E_n.  When the kernel bisected the step
into 2^k substeps, the substeps are replayed with local_solver.local_step and differentiated
one after the other (the substep strain E_old + t (E_n - E_old) depends on E_n and on the
previous step's strain, both carried); the replay must reproduce the committed state bit for
bit, else the step is refused.

The mixed control of the material-point driver closes the step (section 5.2.3 at one point):
stress-controlled components m have prescribed stress, so dS_m/ds = 0 gives
C_mm dE_m/ds = -(dS/ds|_{E_m})_m; strain-controlled components keep the sensitivity of the
previous step (their prescribed increment does not depend on s).

The partial derivatives dG/ds ("sensitivity load term", 5.14) are analytic for the hardening
constants p*, C^V, C^D (rows of 2.82, linear in them); for every other parameter (Lame
constants, n0, n_max, psi1, psi2, ...) they are central differences of the residual function
at fixed X (and of n_G for dE_p/ds), with a relative step of 1e-5: the residual is a smooth
closed-form function, so this costs two residual evaluations per parameter and substep and is
accurate to ~1e-10; the derivative of the *solution* stays implicit (semi-analytical in the
sense of Kleiber et al., thesis section 5.2).  Initial values beta0 .. gamma0 have no explicit
dependence (pidx = -1): they enter through the seed of dp/ds at the initial state.

Internal units as the kernels (MPa, m, s): stresses in MPa, p = (beta, delta/MPa,
epsilon/MPa, gamma), parameter columns per internal unit of the parameter.
"""

import math

import numpy as np
from numba import njit

from .elasticity import compression_point, elastic_stress
from .errors import STATUS_OK
from .local_solver import (S_BETA, S_DELTA, S_EPS_P, S_EPSILON, S_EPV_OFFSET, S_GAMMA, S_STRAIN,
                           S_SUBSTEPS, WS_SIZE, local_step, make_workspace, residual_jacobian)
from .parameters import (P_BETA_STAR, P_C_BETA_D, P_C_BETA_V, P_C_DELTA_D, P_C_DELTA_V, P_C_EPS_D,
                         P_C_EPS_V, P_C_GAMMA_D, P_C_GAMMA_V, P_DELTA_STAR, P_EPS_STAR, P_GAMMA_STAR,
                         P_MICROPOLAR, P_SIGN_DELTA, P_SIGN_EPS, STRESS_UNIT)
from .tangent import NX
from .yield_function import plastic_potential_derivatives, yield_function

#: status codes of step_sensitivity
SENS_OK = 0
SENS_REPLAY_FAILED = 1      # the replayed local step failed (should not happen: it converged before)
SENS_REPLAY_MISMATCH = 2    # the replay does not reproduce the committed state
SENS_SINGULAR = 3           # singular local Jacobian or C_mm
SENS_INVALID = 4            # a residual evaluation for a parameter difference left the model's domain

SENS_MESSAGES = {
    SENS_REPLAY_FAILED: "the replayed local step failed",
    SENS_REPLAY_MISMATCH: "the replayed local step does not reproduce the committed state",
    SENS_SINGULAR: "singular local Jacobian or stress-controlled tangent block",
    SENS_INVALID: "a parameter difference of the residual left the domain of the model",
}

@njit(cache=True, error_model="numpy")
def _hardening_slot(idx):
    """(row k of p = (beta, delta, epsilon, gamma), kind 0: p*, 1: C^V, 2: C^D) of a hardening
    constant's index in the parameter array (2.82), or (-1, -1)."""
    if idx == P_BETA_STAR:
        return 0, 0
    if idx == P_DELTA_STAR:
        return 1, 0
    if idx == P_EPS_STAR:
        return 2, 0
    if idx == P_GAMMA_STAR:
        return 3, 0
    if idx == P_C_BETA_V:
        return 0, 1
    if idx == P_C_DELTA_V:
        return 1, 1
    if idx == P_C_EPS_V:
        return 2, 1
    if idx == P_C_GAMMA_V:
        return 3, 1
    if idx == P_C_BETA_D:
        return 0, 2
    if idx == P_C_DELTA_D:
        return 1, 2
    if idx == P_C_EPS_D:
        return 2, 2
    if idx == P_C_GAMMA_D:
        return 3, 2
    return -1, -1


@njit(cache=True, error_model="numpy")
def _solve(A, B, n):
    """A[:n,:n] Y = B[:n,:] by Gaussian elimination with partial pivoting (runtime number of
    right-hand sides, unlike tangent.solve_nx); A and B are overwritten. False if singular."""
    nrhs = B.shape[1]
    for k in range(n):
        p = k
        amax = abs(A[k, k])
        for i in range(k + 1, n):
            if abs(A[i, k]) > amax:
                amax = abs(A[i, k])
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
                for j in range(k, n):
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
def _elastic_response(Ce, sc, dc, dE, dEp, nc, out):
    """out[:7, :nc] = C_e (dE - dE_p) + sc dc tr(dE_p): the change of the elastic stress
    (2.73, 2.74) with the total and plastic strains, the compression point moving with
    eps_p^V (2.70).  C_e is block diagonal (normal 3x3, shear 2x2, couple diagonal)."""
    for i in range(7):
        k0 = 0 if i < 3 else (3 if i < 5 else i)
        k1 = 3 if i < 3 else (5 if i < 5 else i + 1)
        for j in range(nc):
            s = 0.0
            for kk in range(k0, k1):
                s += Ce[i, kk] * (dE[kk, j] - dEp[kk, j])
            s += sc[i] * dc * (dEp[0, j] + dEp[1, j] + dEp[2, j])
            out[i, j] = s


@njit(cache=True, error_model="numpy")
def _elastic_sensitivity(Ee, epv0, params, pidx, fd_step, dSds):
    """dS^e/ds at fixed elastic strain Ee and eps_p^V (elastic substep), central differences
    of (2.70), (2.73), (2.74) in the parameter (hardening constants and initial values: 0)."""
    m = pidx.shape[0]
    pp = params.copy()
    Sp = np.zeros(7)
    Sm = np.zeros(7)
    Cw = np.zeros((7, 7))
    sw = np.zeros(7)
    for k in range(m):
        for i in range(7):
            dSds[i, k] = 0.0
        idx = pidx[k]
        if idx < 0 or _hardening_slot(idx)[0] >= 0:
            continue
        h = fd_step[k]
        pp[idx] = params[idx] + h
        c, dc = compression_point(epv0, pp)
        ok1 = elastic_stress(Ee, c, pp, Sp, Cw, sw)
        pp[idx] = params[idx] - h
        c, dc = compression_point(epv0, pp)
        ok2 = elastic_stress(Ee, c, pp, Sm, Cw, sw)
        pp[idx] = params[idx]
        if not (ok1 and ok2):
            return False
        for i in range(7):
            dSds[i, k] = (Sp[i] - Sm[i]) / (2.0 * h)
    return True


@njit(cache=True, error_model="numpy")
def residual_parameter_derivatives(X, E, Ep0, p0, dt, params, scale, pidx, fd_step, analytic,
                                   dRds, dnds):
    """Sensitivity load term dG/ds (12 x m) of Table 3.1 at fixed X, and dn_G/ds (7 x m).

    Hardening constants with `analytic`: exact derivatives of the rows (2.82),
        G_{8+k} = [(p_k - p_k,n-1) - s_k (p*_k - p_k) dlam (C^V_k tr n + C^D_k |dev n|)] / scale_k;
    other parameters: central differences with steps fd_step (internal units) of
    local_solver.residual_jacobian and yield_function.plastic_potential_derivatives.
    scale (5) as local_step left it (row scales and the eps_p^V offset).  Returns False if
    a perturbed evaluation is outside the model's domain.
    """
    m = pidx.shape[0]
    pp = params.copy()
    Rp = np.zeros(NX)
    Rm = np.zeros(NX)
    Jw = np.zeros((NX, NX))
    nw = np.zeros(7)
    np_ = np.zeros(7)
    Hw = np.zeros((7, 7))
    dw = np.zeros((3, 7))
    dFw = np.zeros(7)
    Eew = np.zeros(7)
    Sew = np.zeros(7)
    Cew = np.zeros((7, 7))
    scw = np.zeros(7)
    Vw = np.zeros((4, 7))
    # flow direction at X (for the analytic hardening rows)
    plastic_potential_derivatives(X, X[8], X[9], X[10], params, nw, Hw, dw)
    v = nw[0] + nw[1] + nw[2]
    d0 = nw[0] - v / 3.0
    d1 = nw[1] - v / 3.0
    d2 = nw[2] - v / 3.0
    w = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2 + nw[3] * nw[3] + nw[4] * nw[4])
    lam = X[7]
    for k in range(m):
        for i in range(NX):
            dRds[i, k] = 0.0
        for i in range(7):
            dnds[i, k] = 0.0
        idx = pidx[k]
        if idx < 0:
            continue
        row, kind = _hardening_slot(idx)
        if row >= 0 and analytic:
            pstar = params[(P_BETA_STAR, P_DELTA_STAR, P_EPS_STAR, P_GAMMA_STAR)[row]]
            cv = params[(P_C_BETA_V, P_C_DELTA_V, P_C_EPS_V, P_C_GAMMA_V)[row]]
            cd = params[(P_C_BETA_D, P_C_DELTA_D, P_C_EPS_D, P_C_GAMMA_D)[row]]
            sg = 1.0
            if row == 1:
                sg = params[P_SIGN_DELTA]
            elif row == 2:
                sg = params[P_SIGN_EPS]
            A = sg * (pstar - X[8 + row])
            if kind == 0:
                dRds[8 + row, k] = -sg * lam * (cv * v + cd * w) / scale[row]
            elif kind == 1:
                dRds[8 + row, k] = -A * lam * v / scale[row]
            else:
                dRds[8 + row, k] = -A * lam * w / scale[row]
            continue
        h = fd_step[k]
        pp[idx] = params[idx] + h
        ok1, F1 = residual_jacobian(X, E, Ep0, p0, dt, pp, Rp, Jw, nw, Hw, dw, dFw, Eew, Sew, Cew, scw,
                                    scale, Vw, False)
        plastic_potential_derivatives(X, X[8], X[9], X[10], pp, np_, Hw, dw)
        pp[idx] = params[idx] - h
        ok2, F2 = residual_jacobian(X, E, Ep0, p0, dt, pp, Rm, Jw, nw, Hw, dw, dFw, Eew, Sew, Cew, scw,
                                    scale, Vw, False)
        plastic_potential_derivatives(X, X[8], X[9], X[10], pp, nw, Hw, dw)
        pp[idx] = params[idx]
        if not (ok1 and ok2):
            return False
        for i in range(NX):
            dRds[i, k] = (Rp[i] - Rm[i]) / (2.0 * h)
        for i in range(7):
            dnds[i, k] = (np_[i] - nw[i]) / (2.0 * h)
    return True


@njit(cache=True, error_model="numpy")
def step_sensitivity(E_new, dt, state_old, state_new, params, mask, pidx, fd_step, analytic,
                     dE, dEp, dp, dS, C_out):
    """Propagate parameter sensitivities over one committed mixed-control step (5.21)-(5.32).

    E_new (7): committed total generalised strain; dt [s]; state_old, state_new (STATE_SIZE,
    SI): history before and after the step (state_new: only its substep count and, for the
    replay check, the new history are read); params: kernel parameter array; mask (7,) bool:
    stress-controlled components; pidx (m,): parameter-array index per sensitivity column
    (-1: no explicit dependence, e.g. initial values); fd_step (m,): residual-difference
    steps (internal units); analytic: hardening rows analytic.
    In/out (internal units, per internal unit of the parameter): dE (7, m) total strain,
    dEp (7, m) plastic strain/curvature, dp (4, m) hardening variables, dS (7, m) stress;
    on entry those of the previous step, on return those of this one.  C_out (7, 7): the
    consistent tangent dS/dE_n of the replayed step, from the E columns (MPa).
    Returns (status, nsub): SENS_OK or an error code, and the number of substeps replayed.
    """
    su = STRESS_UNIT
    m = pidx.shape[0]
    nc = 7 + m
    buf = np.zeros(WS_SIZE)
    (X, Xt, R, Rt, J, Jt, Jlu, Z, n, H, dndp, dF, Ee, Se, Ce, sc, Str, Ep, p, Esub, Ep0, p0, DEp_w, Dp_w,
     scale, V) = make_workspace(buf)
    S = np.zeros(7)
    Cw = np.zeros((7, 7))
    E = E_new.copy()
    if params[P_MICROPOLAR] == 0.0:
        E[5] = 0.0   # classical model: the kernel ignores the curvature
        E[6] = 0.0
    nsub = int(state_new[S_SUBSTEPS])
    if nsub < 1:
        nsub = 1
    for i in range(7):
        Ep[i] = state_old[S_EPS_P + i]
    p[0] = state_old[S_BETA]
    p[1] = state_old[S_DELTA] / su
    p[2] = state_old[S_EPSILON] / su
    p[3] = state_old[S_GAMMA]
    scale[4] = state_old[S_EPV_OFFSET]
    # derivative columns: 0..6 w.r.t. E_n, 7.. w.r.t. the parameters at fixed E_n
    GEp = np.zeros((7, nc))
    Gp = np.zeros((4, nc))
    GS = np.zeros((7, nc))
    for k in range(m):
        for i in range(7):
            GEp[i, 7 + k] = dEp[i, k]
        for i in range(4):
            Gp[i, 7 + k] = dp[i, k]
    dEsub = np.zeros((7, nc))
    B = np.zeros((NX, nc))
    dRds = np.zeros((NX, m))
    dnds = np.zeros((7, m))
    dSe = np.zeros((7, m))
    Ep0c = np.zeros(7)
    p0c = np.zeros(4)
    dts = dt / nsub
    for ks in range(1, nsub + 1):
        t = ks / nsub
        for i in range(7):
            Esub[i] = state_old[S_STRAIN + i] + t * (E[i] - state_old[S_STRAIN + i])
            for j in range(nc):
                dEsub[i, j] = 0.0
            dEsub[i, i] = t
            for k in range(m):
                dEsub[i, 7 + k] = (1.0 - t) * dE[i, k]
        for i in range(7):
            Ep0c[i] = Ep[i]
        for k in range(4):
            p0c[k] = p[k]
        code, lam, F, it = local_step(Esub, dts, Ep, p, params, S, Cw, t, False,
                                      X, Xt, R, Rt, J, Jt, Jlu, Z, n, H, dndp, dF, Ee, Se, Ce, sc,
                                      Str, Ep0, p0, DEp_w, Dp_w, scale, V)
        if code != STATUS_OK:
            return SENS_REPLAY_FAILED, nsub
        # which branch did local_step take?  the same elastic-predictor test, recomputed
        for i in range(7):
            Ee[i] = Esub[i] - Ep0c[i]
        epv0 = Ep0c[0] + Ep0c[1] + Ep0c[2] + scale[4]
        c0, dc0 = compression_point(epv0, params)
        elastic_stress(Ee, c0, params, Str, Ce, sc)
        Ftr = yield_function(Str, p0c[0], p0c[1], p0c[2], p0c[3], params)
        smax = 0.0
        for i in range(5):
            smax = max(smax, abs(Str[i]))
        if Ftr <= 1e-14 * max(smax, 1e-6):
            # elastic substep: S = S^e(E - E_p, c(eps_p^V)), history unchanged
            if not _elastic_sensitivity(Ee, epv0, params, pidx, fd_step, dSe):
                return SENS_INVALID, nsub
            _elastic_response(Ce, sc, dc0, dEsub, GEp, nc, GS)
            for i in range(7):
                for k in range(m):
                    GS[i, 7 + k] += dSe[i, k]
            continue
        # plastic substep: X converged, J at X; partial derivatives first (they use their
        # own work arrays), then the Jacobian and flow direction at X once more
        if not residual_parameter_derivatives(X, Esub, Ep0c, p0c, dts, params, scale, pidx, fd_step,
                                              analytic, dRds, dnds):
            return SENS_INVALID, nsub
        ok, F = residual_jacobian(X, Esub, Ep0c, p0c, dts, params, R, J, n, H, dndp, dF, Ee, Se, Ce, sc,
                                  scale, V, True)
        if not ok:
            return SENS_REPLAY_FAILED, nsub
        lam = X[7]
        v = n[0] + n[1] + n[2]
        c, dc = compression_point(epv0 + lam * v, params)
        # right-hand side -[dG/dE dE/dc + dG/dE_p0 dE_p0/dc + dG/dp0 dp0/dc + dG/ds]
        _elastic_response(Ce, sc, dc, dEsub, GEp, nc, B)
        for j in range(nc):
            B[7, j] = 0.0
            for k in range(4):
                B[8 + k, j] = Gp[k, j] / scale[k]
        for k in range(m):
            for i in range(NX):
                B[i, 7 + k] -= dRds[i, k]
        for i in range(NX):
            for j in range(NX):
                Jlu[i, j] = J[i, j]
        if not _solve(Jlu, B, NX):
            return SENS_SINGULAR, nsub
        # history: E_p = E_p0 + dlam n_G(S, beta, delta, epsilon; s), p = X[8:12]  (5.30)-(5.32)
        for i in range(7):
            for j in range(nc):
                hsum = 0.0
                for kk in range(7):
                    hsum += H[i, kk] * B[kk, j]
                for mm in range(3):
                    hsum += dndp[mm, i] * B[8 + mm, j]
                if j >= 7:
                    hsum += dnds[i, j - 7]
                GEp[i, j] += n[i] * B[7, j] + lam * hsum
        for k in range(4):
            for j in range(nc):
                Gp[k, j] = B[8 + k, j]
        for i in range(7):
            for j in range(nc):
                GS[i, j] = B[i, j]
    # the replay must be the committed step
    same = True
    for i in range(7):
        same = same and Ep[i] == state_new[S_EPS_P + i]
    same = same and p[0] == state_new[S_BETA] and p[1] * su == state_new[S_DELTA]
    same = same and p[2] * su == state_new[S_EPSILON] and p[3] == state_new[S_GAMMA]
    if not same:
        return SENS_REPLAY_MISMATCH, nsub
    for i in range(7):
        for j in range(7):
            C_out[i, j] = GS[i, j]
    # mixed control: dE_u/ds carried (strain-controlled), C_mm dE_m/ds = -(dS/ds|_E)_m
    nm = 0
    for i in range(7):
        if mask[i]:
            nm += 1
    mi = np.zeros(nm, dtype=np.int64)
    a = 0
    for i in range(7):
        if mask[i]:
            mi[a] = i
            a += 1
    dEn = dE.copy()
    if nm > 0:
        A = np.zeros((nm, nm))
        Bm = np.zeros((nm, m))
        for a in range(nm):
            for b in range(nm):
                A[a, b] = GS[mi[a], mi[b]]
            for k in range(m):
                s = GS[mi[a], 7 + k]
                for j in range(7):
                    if not mask[j]:
                        s += GS[mi[a], j] * dE[j, k]
                Bm[a, k] = -s
        if not _solve(A, Bm, nm):
            return SENS_SINGULAR, nsub
        for a in range(nm):
            for k in range(m):
                dEn[mi[a], k] = Bm[a, k]
    if params[P_MICROPOLAR] == 0.0:
        for k in range(m):
            dEn[5, k] = 0.0
            dEn[6, k] = 0.0
    for k in range(m):
        for i in range(7):
            s = GS[i, 7 + k]
            se = GEp[i, 7 + k]
            for j in range(7):
                s += GS[i, j] * dEn[j, k]
                se += GEp[i, j] * dEn[j, k]
            dS[i, k] = s
            dEp[i, k] = se
            dE[i, k] = dEn[i, k]
        for i in range(4):
            s = Gp[i, 7 + k]
            for j in range(7):
                s += Gp[i, j] * dEn[j, k]
            dp[i, k] = s
    buf[0] = 0.0  # the work views do not own buf: keep it alive until here
    return SENS_OK, nsub
