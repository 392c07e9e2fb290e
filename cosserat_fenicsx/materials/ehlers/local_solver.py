"""Local (Gauss-point) problem of Table 3.1: residual, Jacobian, Newton, substepping.

Unknowns per point (spec section 5, thesis 3.34 in 2D)::

    X = (sig11, sig22, sig33, sig12, sig21, m31, m32, dlam, beta, delta, epsilon, gamma)

with dlam = dt * Lambda, the plastic multiplier increment (Lambda of 2.81 times the
time step), so that Delta eps_p = dlam dG/dsigma and Delta kappa_p = dlam dG/dm (2.79).
Residuals (Table 3.1 with the typos of spec section 5 corrected)::

    G1,G2 = S - S^e(E_n - E_p,n-1 - dlam n_G(S, p);  eps_crit(eps_p,n^V))    (2.73), (2.74), (2.70)
    g3    = sigma_ref (eta dlam / dt)^(1/r) - F(S, p)                          (2.81), r-th root
    g4..7 = [(p - p_n-1) - s_p (p* - p) dlam (C^V tr n_G + C^D |dev n_G|)] / scale_p      (2.82)

g3 is (2.81) solved for F: Lambda = (1/eta) <F/sigma_ref>^r  <=>  F = sigma_ref (eta Lambda)^(1/r)
for F > 0; it is well conditioned as eta -> 0 and eta = 0 gives the rate-independent
consistency condition F = 0 (2.80).  s_p = +1 for the uniform (2.82)/H1 reading,
s_p = -1 on the delta and epsilon rows for the literal Table 3.1 reading.

Solution strategy (spec section 5 [REC]): elastic predictor; if F > 0, Newton from
the predictor with a backtracking line search on the scaled residual that rejects
states beyond the compression point, with negative dlam, or with delta, epsilon,
gamma outside their ranges; if Newton fails, the strain increment (and dt) is bisected
into 2, 4, ... substeps (up to 2**max_substep_levels).  Internal units MPa, m, s.

The consistent tangent is exact also after substepping: the sensitivity of the history
(plastic strain, hardening variables) to the final strain is carried through the substeps
(tangent.consistent_tangent / propagate_history_sensitivity).
"""

import math

import numpy as np
from numba import carray, njit, types
from numba.extending import intrinsic

from .elasticity import compression_point, elastic_stress
from .errors import (STATUS_COMPRESSION_POINT, STATUS_NONFINITE_INPUT, STATUS_NOT_CONVERGED,
                     STATUS_OK, STATUS_SINGULAR, STATUS_TENSILE)
from .parameters import (P_BETA_STAR, P_C_BETA_D, P_C_BETA_V, P_C_DELTA_D, P_C_DELTA_V,
                         P_C_EPS_D, P_C_EPS_V, P_C_GAMMA_D, P_C_GAMMA_V, P_DELTA_STAR,
                         P_EPS_STAR, P_ETA, P_GAMMA_STAR, P_L_C, P_MAX_ITER, P_MAX_LEVELS,
                         P_MICROPOLAR, P_R, P_SIGMA_REF, P_SIGN_DELTA, P_SIGN_EPS, P_TOL,
                         STRESS_UNIT)
from .tangent import NX, consistent_tangent, propagate_history_sensitivity, solve_nx
from .yield_function import plastic_potential_derivatives, yield_function, yield_function_gradient

GAMMA_MAX = 3.0 * math.sqrt(3.0) / 2.0

# ---- layout of the history (state) array, SI units ---------------------------
S_EPS_P = 0        # 0..4: plastic strain eps_p 11, 22, 33, 12, 21 [-]
S_KAPPA_P = 5      # 5, 6: plastic curvature kappa_p 31, 32 [1/m]
S_BETA = 7         # beta [-]
S_DELTA = 8        # delta [Pa] (thesis form, 2.76)
S_EPSILON = 9      # epsilon [Pa]
S_GAMMA = 10       # gamma [-]
S_LAMBDA = 11      # plastic multiplier Lambda [1/s] of the last step (2.81)
S_SIG33 = 12       # out-of-plane stress sig33 [Pa]
S_F = 13           # yield function value F at the end of the step [Pa] (> 0: Perzyna overstress)
S_STRAIN = 14      # 14..20: total generalised strain of this state (eps11,22,33,12,21,kappa31,32)
S_EPS_P_DEV = 21   # accumulated deviatoric plastic strain  sum |Delta eps_p^D| [-]
S_SUBSTEPS = 22    # number of substeps used in the last step (diagnostic)
S_ITERATIONS = 23  # local Newton iterations in the last step (diagnostic)
S_EPV_OFFSET = 24  # plastic volumetric strain accumulated before the FE reference configuration
                   # (prestressed start, EhlersMaterial.initial_stress_state); enters eps_crit only
STATE_SIZE = 25

STATE_NAMES = (
    "eps_p11", "eps_p22", "eps_p33", "eps_p12", "eps_p21", "kappa_p31", "kappa_p32",
    "beta", "delta", "epsilon", "gamma", "Lambda", "sig33", "yield_function",
    "eps11", "eps22", "eps33", "eps12", "eps21", "kappa31", "kappa32",
    "eps_p_dev_accumulated", "substeps", "local_iterations", "eps_p_vol_offset",
)

# Work arrays of the batch kernel, made once per call of update_batch and passed down as
# separate arguments.  (Slicing rows out of one big work array creates array views, and
# every view costs an atomic reference-count increment and decrement in Numba: that was
# about a third of the residual/Jacobian time.)  They are unreferenced views (no meminfo)
# of one buffer owned by update_batch: Numba still emits a reference-count increment and
# decrement per array and call of local_step, but for an array without meminfo that is a
# null test instead of an atomic operation.
WS_NAMES = ("X", "Xt", "R", "Rt", "J", "Jt", "Jlu", "Z", "n", "H", "dndp", "dF", "Ee", "Se",
            "Ce", "sc", "Str", "Ep", "p", "Esub", "Ep0", "p0", "DEp", "Dp", "scale", "V")
WS_SHAPES = ((NX,), (NX,), (NX,), (NX,), (NX, NX), (NX, NX), (NX, NX), (NX, NX),
             (7,), (7, 7), (3, 7), (7,), (7,), (7,), (7, 7), (7,), (7,),
             (7,), (4,), (7,), (7,), (4,), (7, 7), (4, 7), (5,), (4, 7))
WS_SIZE = sum(int(np.prod(sh)) for sh in WS_SHAPES)


@intrinsic
def _f8_pointer(typingctx, address):
    """float64 pointer at the integer address (for unreferenced views of a work buffer)."""
    if not isinstance(address, types.Integer):
        return None
    sig = types.CPointer(types.float64)(address)

    def codegen(context, builder, signature, args):
        return builder.inttoptr(args[0], context.get_value_type(signature.return_type))
    return sig, codegen


@njit(cache=True, error_model="numpy")
def _view1(base, off, n):
    """Unreferenced 1D view buf[off:off + n] of the float64 buffer at address base."""
    return carray(_f8_pointer(base + 8 * off), n)


@njit(cache=True, error_model="numpy")
def _view2(base, off, n, m):
    """Unreferenced 2D view buf[off:off + n m].reshape(n, m) of the buffer at address base."""
    return carray(_f8_pointer(base + 8 * off), (n, m))


@njit(cache=True, error_model="numpy")
def make_workspace(buf):
    """Work arrays for one thread of the batch kernel, in the order of WS_NAMES.

    Views without reference counting of buf (float64, size >= WS_SIZE, C-contiguous), which
    the caller must keep alive while they are used.  Zero-initialised if buf is.
    X, Xt, R, Rt (12): iterate, line-search trial and their residuals; J, Jt, Jlu, Z (12x12):
    Jacobians, LU copy, right-hand sides; n (7), H (7x7), dndp (3x7): flow direction and its
    derivatives; dF (7); Ee, Se, Ce (7x7), sc: elastic strain, stress, tangent, dS/d eps_crit;
    Str: trial stress; Ep, p, Esub, Ep0, p0: history and substep strain; DEp (7x7), Dp (4x7):
    history sensitivity; scale (5): hardening row scales and the eps_p^V offset (index 4);
    V (4x7): gradients of tr n and |dev n|.
    """
    b = np.int64(buf.ctypes.data)
    return (_view1(b, 0, NX), _view1(b, 12, NX), _view1(b, 24, NX), _view1(b, 36, NX),
            _view2(b, 48, NX, NX), _view2(b, 192, NX, NX), _view2(b, 336, NX, NX),
            _view2(b, 480, NX, NX),
            _view1(b, 624, 7), _view2(b, 631, 7, 7), _view2(b, 680, 3, 7), _view1(b, 701, 7),
            _view1(b, 708, 7), _view1(b, 715, 7), _view2(b, 722, 7, 7), _view1(b, 771, 7),
            _view1(b, 778, 7),
            _view1(b, 785, 7), _view1(b, 792, 4), _view1(b, 796, 7), _view1(b, 803, 7),
            _view1(b, 810, 4),
            _view2(b, 814, 7, 7), _view2(b, 863, 4, 7), _view1(b, 891, 5), _view2(b, 896, 4, 7))


@njit(cache=True, error_model="numpy")
def _hardening_constants(params):
    """(p*, C^V, C^D, sign) for p = (beta, delta, epsilon, gamma), eq. (2.82)."""
    pstar = (params[P_BETA_STAR], params[P_DELTA_STAR], params[P_EPS_STAR], params[P_GAMMA_STAR])
    cv = (params[P_C_BETA_V], params[P_C_DELTA_V], params[P_C_EPS_V], params[P_C_GAMMA_V])
    cd = (params[P_C_BETA_D], params[P_C_DELTA_D], params[P_C_EPS_D], params[P_C_GAMMA_D])
    sg = (1.0, params[P_SIGN_DELTA], params[P_SIGN_EPS], 1.0)
    return pstar, cv, cd, sg


@njit(cache=True, error_model="numpy")
def residual_jacobian(X, E, Ep0, p0, dt, params, R, J, n, H, dndp, dF, Ee, Se, Ce, sc, scale, V,
                      want_jac):
    """Residual R (12) of Table 3.1 at X and, if want_jac, its Jacobian J = dR/dX.

    Ep0 (7): plastic strain/curvature at the start of the (sub)step, p0 (4) hardening.
    Leaves in the work arrays: n_G (n), its derivatives (H, dndp), dF, C_e and sc at X.
    scale (5): row scales of the hardening residuals and the eps_p^V offset (index 4).
    Returns (valid, F).  valid is False when X is outside the domain of the model
    (beyond the compression point, then F = inf; at the stress apex, or delta, epsilon,
    gamma out of range, then F = 0); the line search then backtracks.
    """
    beta = X[8]
    delta = X[9]
    eps = X[10]
    gamma = X[11]
    if not (delta > 0.0 and eps > 0.0 and gamma > 0.0 and gamma < GAMMA_MAX and X[7] >= 0.0):
        return False, 0.0
    S = X  # the generalised stress is X[0:7]
    lam = X[7]
    G, phiG = plastic_potential_derivatives(S, beta, delta, eps, params, n, H, dndp)
    if not phiG > 0.0:
        return False, 0.0
    F, dFb, dFd, dFe, dFg, phiF = yield_function_gradient(S, beta, delta, eps, gamma, params, dF)
    if not phiF > 0.0:
        return False, 0.0
    v = n[0] + n[1] + n[2]
    d0 = n[0] - v / 3.0
    d1 = n[1] - v / 3.0
    d2 = n[2] - v / 3.0
    w = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2 + n[3] * n[3] + n[4] * n[4])
    for i in range(7):
        Ee[i] = E[i] - Ep0[i] - lam * n[i]
    epv = Ep0[0] + Ep0[1] + Ep0[2] + scale[4] + lam * v
    if not epv < 0.5:
        return False, 0.0
    c, dc = compression_point(epv, params)
    if not elastic_stress(Ee, c, params, Se, Ce, sc):
        return False, np.inf  # beyond the compression point (inf tags the cause)
    for i in range(7):
        R[i] = S[i] - Se[i]
    eta = params[P_ETA]
    sref = params[P_SIGMA_REF]
    r = params[P_R]
    if eta > 0.0 and lam > 0.0:
        if r == 1.0:
            R[7] = sref * eta * lam / dt - F
        else:
            R[7] = sref * (eta * lam / dt) ** (1.0 / r) - F
    else:
        R[7] = -F
    pstar, cv, cd, sg = _hardening_constants(params)
    for k in range(4):
        pk = X[8 + k]
        A = sg[k] * (pstar[k] - pk)
        B = lam * (cv[k] * v + cd[k] * w)
        R[8 + k] = ((pk - p0[k]) - A * B) / scale[k]
    if not want_jac:
        return True, F
    # ---------------------------------------------------------------- Jacobian
    # gradients of v = tr n and w = |dev n| w.r.t. S and p = (beta, delta, epsilon)
    # V rows: 0 gradient of v, 1 gradient of w, 2 dv/dp, 3 dw/dp
    winv = 1.0 / w if w > 1e-14 else 0.0  # |dev n| has a kink at 0 (hydrostatic flow): subgradient 0
    for j in range(7):
        V[0, j] = H[0, j] + H[1, j] + H[2, j]
        V[1, j] = winv * (d0 * H[0, j] + d1 * H[1, j] + d2 * H[2, j] + n[3] * H[3, j] + n[4] * H[4, j])
    for m in range(3):
        V[2, m] = dndp[m, 0] + dndp[m, 1] + dndp[m, 2]
        vm = V[2, m] / 3.0
        V[3, m] = winv * (d0 * (dndp[m, 0] - vm) + d1 * (dndp[m, 1] - vm) + d2 * (dndp[m, 2] - vm)
                          + n[3] * dndp[m, 3] + n[4] * dndp[m, 4])
    V[2, 3] = 0.0
    V[3, 3] = 0.0
    # G1/G2 rows: R = S - S^e(E - Ep0 - lam n, c(epv0 + lam v)).  C_e is block diagonal
    # (normal 3x3, shear 2x2, couple 2x diagonal): the products below use only its blocks.
    for i in range(7):
        if i < 3:
            k0 = 0
            k1 = 3
        elif i < 5:
            k0 = 3
            k1 = 5
        else:
            k0 = i
            k1 = i + 1
        for j in range(7):
            s = 0.0
            for k in range(k0, k1):
                s += Ce[i, k] * H[k, j]
            J[i, j] = lam * (s - dc * sc[i] * V[0, j])
        J[i, i] += 1.0
        s = 0.0
        for k in range(k0, k1):
            s += Ce[i, k] * n[k]
        J[i, 7] = s - dc * v * sc[i]
        for m in range(3):
            s = 0.0
            for k in range(k0, k1):
                s += Ce[i, k] * dndp[m, k]
            J[i, 8 + m] = lam * (s - dc * sc[i] * V[2, m])
        J[i, 11] = 0.0
    # g3 row
    for j in range(7):
        J[7, j] = -dF[j]
    if eta > 0.0:
        if r == 1.0:
            J[7, 7] = sref * eta / dt
        else:
            J[7, 7] = sref * (eta / dt) ** (1.0 / r) * (1.0 / r) * max(lam, 1e-300) ** (1.0 / r - 1.0)
    else:
        J[7, 7] = 0.0
    J[7, 8] = -dFb
    J[7, 9] = -dFd
    J[7, 10] = -dFe
    J[7, 11] = -dFg
    # hardening rows (2.82), implicit Euler
    for k in range(4):
        pk = X[8 + k]
        A = sg[k] * (pstar[k] - pk)
        B = lam * (cv[k] * v + cd[k] * w)
        inv = 1.0 / scale[k]
        for j in range(7):
            J[8 + k, j] = -A * lam * (cv[k] * V[0, j] + cd[k] * V[1, j]) * inv
        J[8 + k, 7] = -A * (cv[k] * v + cd[k] * w) * inv
        for m in range(4):
            J[8 + k, 8 + m] = -A * lam * (cv[k] * V[2, m] + cd[k] * V[3, m]) * inv
        J[8 + k, 8 + k] += (1.0 + sg[k] * B) * inv
    return True, F


@njit(cache=True, error_model="numpy")
def _merit(R, sig_scale, m_scale):
    s = 0.0
    for i in range(5):
        t = R[i] / sig_scale
        s += t * t
    for i in range(5, 7):
        t = R[i] / m_scale
        s += t * t
    t = R[7] / sig_scale
    s += t * t
    for i in range(8, 12):
        s += R[i] * R[i]
    return math.sqrt(s)


@njit(cache=True, error_model="numpy")
def local_step(E, dt, Ep, p, params, S_out, C_out, t, with_history,
               X, Xt, R, Rt, J, Jt, Jlu, Z, n, H, dndp, dF, Ee, Se, Ce, sc, Str, Ep0, p0, DEp, Dp, scale, V):
    """One implicit Euler step of the local system from history (Ep, p) to total strain E.

    On success Ep (7) and p (4) are overwritten with the new history, S_out with the
    stress and C_out with the consistent tangent dS/dE_final.  t: fraction of the full
    increment reached at the end of this substep (E = E_old + t (E_final - E_old));
    with_history: the start history depends on E_final through DEp, Dp (earlier substeps),
    which are then updated for the next substep (exact tangent under substepping).
    The remaining arguments are the work arrays of make_workspace.
    Returns
    (status, dlam, F, iterations).
    """
    for i in range(7):
        Ep0[i] = Ep[i]
    for k in range(4):
        p0[k] = p[k]
    # ----- elastic predictor
    for i in range(7):
        Ee[i] = E[i] - Ep0[i]
    c, dc = compression_point(Ep0[0] + Ep0[1] + Ep0[2] + scale[4], params)
    if not elastic_stress(Ee, c, params, Str, Ce, sc):
        return STATUS_COMPRESSION_POINT, 0.0, 0.0, 0
    Ftr = yield_function(Str, p0[0], p0[1], p0[2], p0[3], params)
    smax = 0.0
    for i in range(5):
        smax = max(smax, abs(Str[i]))
    sig_scale = max(smax, 1e-6)  # >= 1 Pa
    pstar, cv, cd, sg = _hardening_constants(params)
    for k in range(4):
        scale[k] = abs(p0[k]) + abs(pstar[k])
    if Ftr <= 1e-14 * sig_scale:
        for i in range(7):
            S_out[i] = Str[i]
        # elastic (sub)step: dS/dE = C_e t - (C_e - sc (x) dc 1_tr) dE_p/dE, history unchanged
        if not consistent_tangent(J, Ce, sc, dc, t, DEp, Dp, scale, with_history, Jlu, Z, C_out, True):
            return STATUS_SINGULAR, 0.0, Ftr, 0
        return STATUS_OK, 0.0, Ftr, 0
    Itr = Str[0] + Str[1] + Str[2]
    m_scale = sig_scale * max(params[P_L_C], 1e-6)
    # ----- plastic corrector: Newton from the predictor
    tol = params[P_TOL]
    max_iter = int(params[P_MAX_ITER])
    # Newton starts from the elastic predictor (dlam = 0).  (Starting from dlam = Lambda_old dt
    # was tried: it saves < 1 iteration in steady loading, less than its extra evaluation costs.)
    for i in range(7):
        X[i] = Str[i]
    X[7] = 0.0 if params[P_R] == 1.0 else 1e-12
    for k in range(4):
        X[8 + k] = p0[k]
    valid, F = residual_jacobian(X, E, Ep0, p0, dt, params, R, J, n, H, dndp, dF, Ee, Se, Ce, sc,
                                 scale, V, True)
    merit = _merit(R, sig_scale, m_scale) if valid else np.inf
    if not valid:
        return (STATUS_TENSILE if Itr >= 0.0 else STATUS_SINGULAR), 0.0, 0.0, 0
    converged = False
    hit_crit = False  # a Newton trial was rejected beyond the compression point
    it = 0
    while it < max_iter:
        if merit < tol:
            converged = True
            break
        it += 1
        for i in range(NX):
            Z[i, 0] = -R[i]
            for j in range(NX):
                Jlu[i, j] = J[i, j]
        if not solve_nx(Jlu, Z, 1):
            break
        alpha = 1.0
        accepted = False
        for ls in range(30):
            for i in range(NX):
                Xt[i] = X[i] + alpha * Z[i, 0]
            if Xt[7] < 0.0:
                Xt[7] = 0.0
            ok, Ft = residual_jacobian(Xt, E, Ep0, p0, dt, params, Rt, Jt, n, H, dndp, dF, Ee, Se, Ce,
                                       sc, scale, V, True)
            if not ok and Ft == np.inf:
                hit_crit = True
            if ok:
                mt = _merit(Rt, sig_scale, m_scale)
                if mt <= (1.0 - 1e-4 * alpha) * merit or mt < tol:
                    accepted = True
                    break
            alpha *= 0.5
        if not accepted:
            break
        for i in range(NX):
            X[i] = Xt[i]
            R[i] = Rt[i]
            for j in range(NX):
                J[i, j] = Jt[i, j]
        F = Ft
        merit = mt
    if not converged:
        if Itr >= 0.0:
            return STATUS_TENSILE, 0.0, 0.0, it
        return (STATUS_COMPRESSION_POINT if hit_crit else STATUS_NOT_CONVERGED), 0.0, 0.0, it
    # converged: the last residual_jacobian call was at X (predictor or accepted line-search
    # trial), so the work arrays (n_G, C_e) and J belong to the solution
    lam = X[7]
    for i in range(7):
        S_out[i] = X[i]
        Ep[i] = Ep0[i] + lam * n[i]
    for k in range(4):
        p[k] = X[8 + k]
    v = n[0] + n[1] + n[2]
    c, dc = compression_point(Ep0[0] + Ep0[1] + Ep0[2] + scale[4] + lam * v, params)
    if not consistent_tangent(J, Ce, sc, dc, t, DEp, Dp, scale, with_history, Jlu, Z, C_out, False):
        return STATUS_SINGULAR, lam, F, it
    if with_history:
        propagate_history_sensitivity(Z, n, H, dndp, lam, DEp, Dp)
    return STATUS_OK, lam, F, it


@njit(cache=True, error_model="numpy")
def update_batch(grad, dt, state_old, params, flux, tangent, state_new, status):
    """Batch Gauss-point update: the single compiled entry point used by EhlersMaterial.update.

    grad (n, k) with k = 6, plane strain [eps11, eps22, eps12, eps21, kappa31, kappa32]
    (total eps33 = 0, A.4), or k = 7, generalised order [eps11, eps22, eps33, eps12, eps21,
    kappa31, kappa32] (material-point driver).  flux (n, k) [Pa, N/m], tangent (n, k, k)
    [Pa, Pa m, Pa m^2], state_old/state_new (n, STATE_SIZE) SI, status (n,) int32.
    Failed points get zero flux and tangent, the old state and a non-zero status.
    """
    npts = grad.shape[0]
    k = grad.shape[1]
    su = STRESS_UNIT
    # one buffer for all work arrays, including E, S, C and a copy of params; the views
    # passed down carry no reference count (see make_workspace)
    npar = params.shape[0]
    buf = np.zeros(WS_SIZE + 63 + npar)
    (X, Xt, R, Rt, J, Jt, Jlu, Z, n, H, dndp, dF, Ee, Se, Ce, sc, Str, Ep, p, Esub, Ep0, p0, DEp, Dp,
     scale, V) = make_workspace(buf)
    b = np.int64(buf.ctypes.data)
    E = _view1(b, WS_SIZE, 7)
    S = _view1(b, WS_SIZE + 7, 7)
    C = _view2(b, WS_SIZE + 14, 7, 7)
    par = _view1(b, WS_SIZE + 63, npar)
    for i in range(npar):
        par[i] = params[i]
    idx = np.empty(k, dtype=np.int64)
    if k == 6:
        idx[0] = 0
        idx[1] = 1
        idx[2] = 3
        idx[3] = 4
        idx[4] = 5
        idx[5] = 6
    else:
        for a in range(k):
            idx[a] = a
    polar = params[P_MICROPOLAR] != 0.0
    max_levels = int(params[P_MAX_LEVELS])
    nstate = state_old.shape[1]
    for ip in range(npts):
        for i in range(7):
            E[i] = 0.0
        for a in range(k):
            E[idx[a]] = grad[ip, a]
        if not polar:
            E[5] = 0.0  # classical model: curvature ignored
            E[6] = 0.0
        # ---- Gauss-point update with substepping (internal units inside, SI history).  The
        # per-point code is written out here rather than in a function of its own: a call with
        # the ~30 work arrays as arguments costs an atomic reference-count increment and
        # decrement per array and call, which Numba does not remove in a function this large.
        finite = True
        for i in range(7):
            finite = finite and math.isfinite(E[i])
        for i in range(nstate):
            finite = finite and math.isfinite(state_old[ip, i])
        code = STATUS_OK if finite else STATUS_NONFINITE_INPUT
        total_it = 0
        dlam_sum = 0.0
        dev_acc = 0.0
        F = 0.0
        nsub = 1
        scale[4] = state_old[ip, S_EPV_OFFSET]
        for level in range(max_levels + 1 if finite else 0):
            nsub = 1 << level
            for i in range(7):
                Ep[i] = state_old[ip, S_EPS_P + i]
            p[0] = state_old[ip, S_BETA]
            p[1] = state_old[ip, S_DELTA] / su
            p[2] = state_old[ip, S_EPSILON] / su
            p[3] = state_old[ip, S_GAMMA]
            dlam_sum = 0.0
            dev_acc = 0.0
            total_it = 0
            code = STATUS_OK
            for j in range(7):  # d(history)/dE_final = 0 at the start of the increment
                for i in range(7):
                    DEp[i, j] = 0.0
                for i in range(4):
                    Dp[i, j] = 0.0
            for ks in range(1, nsub + 1):
                t = ks / nsub
                for i in range(7):
                    Esub[i] = state_old[ip, S_STRAIN + i] + t * (E[i] - state_old[ip, S_STRAIN + i])
                # plastic strain before the substep, for the accumulated deviatoric measure
                e0 = Ep[0]
                e1 = Ep[1]
                e2 = Ep[2]
                e3 = Ep[3]
                e4 = Ep[4]
                code, dlam, F, it = local_step(Esub, dt / nsub, Ep, p, par, S, C, t, nsub > 1,
                                               X, Xt, R, Rt, J, Jt, Jlu, Z, n, H, dndp, dF, Ee, Se, Ce, sc,
                                               Str, Ep0, p0, DEp, Dp, scale, V)
                total_it += it
                if code != STATUS_OK:
                    break
                dlam_sum += dlam
                a0 = Ep[0] - e0
                a1 = Ep[1] - e1
                a2 = Ep[2] - e2
                tr = (a0 + a1 + a2) / 3.0
                a3 = Ep[3] - e3
                a4 = Ep[4] - e4
                dev_acc += math.sqrt((a0 - tr) ** 2 + (a1 - tr) ** 2 + (a2 - tr) ** 2 + a3 * a3 + a4 * a4)
            if code == STATUS_OK:
                break
        status[ip] = code
        if code != STATUS_OK:
            for a in range(k):
                flux[ip, a] = 0.0
                for bb in range(k):
                    tangent[ip, a, bb] = 0.0
            for i in range(state_new.shape[1]):
                state_new[ip, i] = state_old[ip, i]
            continue
        for i in range(7):
            state_new[ip, S_EPS_P + i] = Ep[i]
            state_new[ip, S_STRAIN + i] = E[i]
        state_new[ip, S_BETA] = p[0]
        state_new[ip, S_DELTA] = p[1] * su
        state_new[ip, S_EPSILON] = p[2] * su
        state_new[ip, S_GAMMA] = p[3]
        state_new[ip, S_LAMBDA] = dlam_sum / dt if dt > 0.0 else 0.0
        state_new[ip, S_SIG33] = S[2] * su
        state_new[ip, S_F] = F * su
        state_new[ip, S_EPS_P_DEV] = state_old[ip, S_EPS_P_DEV] + dev_acc
        state_new[ip, S_SUBSTEPS] = nsub
        state_new[ip, S_ITERATIONS] = total_it
        for i in range(S_ITERATIONS + 1, nstate):
            state_new[ip, i] = state_old[ip, i]
        for a in range(k):
            flux[ip, a] = S[idx[a]] * su
            for bb in range(k):
                tangent[ip, a, bb] = C[idx[a], idx[bb]] * su
    buf[0] = 0.0  # the work views above do not own buf: keep it alive until here
