"""Exact linear response of the frozen periodic contact network of a micropolar cell.

The micropolar generalization of PSTLO (001 appendix B, ``tangent.pstlo_operator``): the
current equilibrium is linearized with its contacts frozen (every touching contact persists,
bilateral, no sliding, no new contact) and the linear equilibrium is solved once (sparse LU).
Kinematics and fluxes follow the micropolar cell conventions (docs/reference/micropolar_cell.md):

* macro inputs: dF (demcell order 11, 12, 21, 22), micro-rotation dphi [rad], curvature
  dkappa (2,) [1/m];
* unknowns per disc p: periodic fluctuation displacement w_p (2) [m] and rotation fluctuation
  th~_p [rad]; one Lagrange multiplier lambda [m] for sum_p w_p th~_p = 0 (w_p: the normal
  force disc p carries, see below); its reaction is the couple lambda w_p on every disc;
* per contact k (i -> nearest image of j, shift n_k): branch increment
  dd = dw_j - dw_i + dF F^-1 d (001 eq. B.3); rotations dtheta_i = dphi + dkappa . X_i + dth~_i,
  image of j: dtheta_j = dphi + dkappa . (X_i + D_k) + dth~_j = ... + dkappa . (X_j + h_ref n_k),
  with the REFERENCE lever positions X_p = h_ref (s_p - c), D_k = h_ref (s_j - s_i + n_k): X is
  held fixed in the linearization (exact at kappa = 0; at kappa != 0 the term kappa . dX_p of a
  moving disc is not included), so dF does not change the rotation field;
* contact law (contact_law.py, frozen): dfn = -kn n.dd, dfs = -ks (t.dd - a_i dth_i - a_j dth_j),
  dmr = -kr (dth_j - dth_i); pre-stress terms as PSTLO: fn dn, fs dt (dn = t t.dd / l,
  dt = -n t.dd / l, eq. B.4) and lever-arm changes da_i = da_j = n.dd / 2 (eq. B.6);
* fluxes (per current area |Y|): sigma = -(1/|Y|) sum f (x) d (001 eq. 8, not symmetric),
  m_l = (1/|Y|) sum [fs (a_i X_i + a_j (X_i + D))_l - mr D_l] (004 eq. 7.38, reference levers);
  the area change adds -sigma tr(F^-1 dF) and -m tr(F^-1 dF).

``prestress=False`` drops every term proportional to the current forces (pure spring network:
no fn dn, fs dt, fs da, f (x) dd, no area terms). Rigid translation and mechanisms (rattlers,
rolling discs) get a regularization of 1e-10 of the largest diagonal entry, as PSTLO, taken per
block (displacements, rotations).

The constraint weights are the kernel's (``contact_weights``: the normal force a disc carries): a
disc whose rotation costs nothing (a rattler; a disc with one contact and kr = 0) would absorb
an area-weighted constraint alone (lambda -> 0, c_phi -> 0). ``rotation_weights`` lets a caller
weight it differently. Contacts crossing the cell's side are counted at the copy whose contact
point lies in the cell, as in the kernel.
"""

import numpy as np
from numba import njit

from .slots import KN, KR, KS, MU
from .periodic_cell import branch_vector, contact_copy, contact_frame, fractional_branch

# demcell order of the 2x2 tensors (11, 12, 21, 22); internal macro columns:
# (F11, F12, F21, F22, phi, kappa1, kappa2); internal flux rows: (s11, s12, s21, s22, m1, m2)
N_MACRO = 7
N_FLUX = 6
# FE callback order (cosserat_fenicsx/kinematics.py): rows s11, s22, s12, s21, m31, m32;
# columns F11-1, F22-1, F12, F21, kappa1, kappa2
CALLBACK_ROWS = (0, 3, 1, 2, 4, 5)
CALLBACK_COLS = (0, 3, 1, 2, 5, 6)
PHI_COL = 4


@njit(cache=True)
def _network_triplets(h, h_ref, s, radius, pair_i, pair_j, fn, fs, mr, touching, n_pairs,
                      kn, ks, kr, Finv, prestress):
    """Per-contact linearization of the frozen micropolar network, assembled.

    Returns COO triplets (rows, cols, vals) of K = d residual / d (w, th~) (3N x 3N, dofs
    3p, 3p+1 = w_p, 3p+2 = th~_p; residual = resultant force and moment on each disc), the
    coupling G = d residual / d macro (3N x 7), the flux sensitivities times the area
    Sx = d(|Y| flux) / d(w, th~) (6 x 3N) and SU = d(|Y| flux) / d macro (6 x 7) without the
    area change term, and the current fluxes times the area (6,) (sigma 11, 12, 21, 22, m1, m2).
    """
    n = radius.shape[0]
    ps = 1.0 if prestress else 0.0
    cap = 0
    for k in range(n_pairs):
        if touching[k] == 1:
            cap += 1
    rows = np.empty(cap * 36, np.int64)
    cols = np.empty(cap * 36, np.int64)
    vals = np.empty(cap * 36)
    G = np.zeros((3 * n, N_MACRO))
    Sx = np.zeros((N_FLUX, 3 * n))
    SU = np.zeros((N_FLUX, N_MACRO))
    flux = np.zeros(N_FLUX)
    L = np.empty((4, 4))        # (f_j x, f_j y, M_i, M_j) / (dd x, dd y, dth_i, dth_j)
    O = np.empty((N_FLUX, 4))   # |Y| d flux / (dd x, dd y, dth_i, dth_j)
    Bu = np.zeros((4, N_MACRO))  # (dd x, dd y, dth_i, dth_j) / macro
    R = np.empty((6, 4))        # residual rows (f_i x, f_i y, f_j x, f_j y, M_i, M_j) / local
    dof = np.empty(6, np.int64)
    m = 0
    for k in range(n_pairs):
        if touching[k] == 0:
            continue
        i = pair_i[k]
        j = pair_j[k]
        a0, a1 = fractional_branch(s, i, j)     # nearest image, shift n_k = -round(s_j - s_i)
        bx = h[0, 0] * a0 + h[0, 1] * a1
        by = h[1, 0] * a0 + h[1, 1] * a1
        Dx = h_ref[0, 0] * a0 + h_ref[0, 1] * a1
        Dy = h_ref[1, 0] * a0 + h_ref[1, 1] * a1
        l, nx, ny, tx, ty, ai, aj = contact_frame(bx, by, radius[i], radius[j])
        # the copy of the contact counted (periodic_cell.contact_copy, as the kernel)
        m0, m1 = contact_copy(s, i, a0, a1, ai / l)
        si0 = s[i, 0] - m0 - 0.5
        si1 = s[i, 1] - m1 - 0.5
        Xix = h_ref[0, 0] * si0 + h_ref[0, 1] * si1
        Xiy = h_ref[1, 0] * si0 + h_ref[1, 1] * si1
        Xjx = Xix + Dx           # image of j in that copy
        Xjy = Xiy + Dy
        f_n = fn[k]
        f_s = fs[k]
        m_r = mr[k]
        fjx = f_n * nx + f_s * tx
        fjy = f_n * ny + f_s * ty
        fvec = (fjx, fjy)
        bvec = (bx, by)
        lev = (ai * Xix + aj * Xjx, ai * Xiy + aj * Xjy)    # a_i X_i + a_j X_j^img
        xsum = (Xix + Xjx, Xiy + Xjy)
        Dvec = (Dx, Dy)
        # current fluxes times the area (spec: sigma = -sum f (x) d, m = sum fs lev - mr D)
        for ab in range(4):
            flux[ab] -= fvec[ab // 2] * bvec[ab % 2]
        for q in range(2):
            flux[4 + q] += f_s * lev[q] - m_r * Dvec[q]
        # --- local operator L and flux derivative O (columns dd x, dd y)
        for c in range(2):
            ndb = nx if c == 0 else ny
            tdb = tx if c == 0 else ty
            dfn = -kn * ndb
            dfs = -ks * tdb
            dnx = tx * tdb / l
            dny = ty * tdb / l
            dtx = -nx * tdb / l
            dty = -ny * tdb / l
            da = 0.5 * ndb
            L[0, c] = dfn * nx + dfs * tx + ps * (f_n * dnx + f_s * dtx)
            L[1, c] = dfn * ny + dfs * ty + ps * (f_n * dny + f_s * dty)
            L[2, c] = -ai * dfs - ps * da * f_s
            L[3, c] = -aj * dfs - ps * da * f_s
            for ab in range(4):
                aa = ab // 2
                bb = ab % 2
                O[ab, c] = -L[aa, c] * bvec[bb] - (ps * fvec[aa] if bb == c else 0.0)
            for q in range(2):
                O[4 + q, c] = dfs * lev[q] + ps * f_s * da * xsum[q]
        # columns dth_i, dth_j: dfs = ks a dth, dmr = kr dth_i - kr dth_j
        for c in range(2):
            dfs = ks * (ai if c == 0 else aj)
            dmr = kr if c == 0 else -kr
            L[0, 2 + c] = dfs * tx
            L[1, 2 + c] = dfs * ty
            L[2, 2 + c] = -ai * dfs - dmr
            L[3, 2 + c] = -aj * dfs + dmr
            for ab in range(4):
                O[ab, 2 + c] = -L[ab // 2, 2 + c] * bvec[ab % 2]
            for q in range(2):
                O[4 + q, 2 + c] = dfs * lev[q] - dmr * Dvec[q]
        # --- chain to the macro inputs: dd = dF F^-1 d, dth = dphi + dkappa . X
        for kl in range(4):
            kk = kl // 2
            ll = kl % 2
            gb = Finv[ll, 0] * bx + Finv[ll, 1] * by
            Bu[0, kl] = gb if kk == 0 else 0.0
            Bu[1, kl] = gb if kk == 1 else 0.0
        Bu[2, 4] = 1.0
        Bu[3, 4] = 1.0
        Bu[2, 5] = Xix
        Bu[2, 6] = Xiy
        Bu[3, 5] = Xjx
        Bu[3, 6] = Xjy
        # residual rows: force on i = -f_j, force on j = +f_j, then M_i, M_j
        for c in range(4):
            R[0, c] = -L[0, c]
            R[1, c] = -L[1, c]
            R[2, c] = L[0, c]
            R[3, c] = L[1, c]
            R[4, c] = L[2, c]
            R[5, c] = L[3, c]
        dof[0] = 3 * i
        dof[1] = 3 * i + 1
        dof[2] = 3 * j
        dof[3] = 3 * j + 1
        dof[4] = 3 * i + 2
        dof[5] = 3 * j + 2
        # local unknowns (w_i x, w_i y, w_j x, w_j y, th~_i, th~_j) -> local inputs:
        # dd = w_j - w_i, dth_i = th~_i, dth_j = th~_j
        for rr in range(6):
            for cc in range(6):
                # columns w_i: -R[:, 0:2]; w_j: +R[:, 0:2]; th~_i, th~_j: R[:, 2:4]
                val = -R[rr, cc] if cc < 2 else R[rr, cc - 2]
                rows[m] = dof[rr]
                cols[m] = dof[cc]
                vals[m] = val
                m += 1
            for u in range(N_MACRO):
                acc = 0.0
                for c in range(4):
                    acc += R[rr, c] * Bu[c, u]
                G[dof[rr], u] += acc
        for ab in range(N_FLUX):
            Sx[ab, dof[0]] -= O[ab, 0]
            Sx[ab, dof[1]] -= O[ab, 1]
            Sx[ab, dof[2]] += O[ab, 0]
            Sx[ab, dof[3]] += O[ab, 1]
            Sx[ab, dof[4]] += O[ab, 2]
            Sx[ab, dof[5]] += O[ab, 3]
            for u in range(N_MACRO):
                acc = 0.0
                for c in range(4):
                    acc += O[ab, c] * Bu[c, u]
                SU[ab, u] += acc
    return rows[:m], cols[:m], vals[:m], G, Sx, SU, flux


def _law_values(law_array, affine=False):
    """(kn, ks, kr) [N/m, N/m, N m/rad]. The frozen network keeps ks whatever the friction
    (DEMQO freezes with mu = inf); the affine estimate drops it for frictionless contacts (as
    the Kruyt operator, 001 eq. 13)."""
    kn = float(law_array[KN])
    ks = float(law_array[KS])
    if affine and not law_array[MU] > 0.0:
        ks = 0.0
    return kn, ks, float(law_array[KR])


def network_system(state, law_array, prestress=True, affine=False):
    """The assembled linearization of ``state`` (see ``_network_triplets``): a dict with
    K (scipy CSC 3N x 3N, unregularized), G (3N x 7), Sx (6 x 3N), SU (6 x 7) -- flux rows
    (s11, s12, s21, s22, m1, m2), macro columns (F11, F12, F21, F22, phi, kappa1, kappa2),
    both times |Y| and without the area term -- flux (6,) the current fluxes, area |Y|,
    Finv."""
    import scipy.sparse as sp
    n = state.n_particles
    Finv = np.linalg.inv(state.F)
    kn, ks, kr = _law_values(law_array, affine)
    rows, cols, vals, G, Sx, SU, flux = _network_triplets(
        state.h, state.h_ref, state.s, state.radius, state.pair_i, state.pair_j, state.fn, state.fs,
        state.mr, state.touching, state.n_pairs, kn, ks, kr, Finv, bool(prestress))
    area = abs(np.linalg.det(state.h))
    K = sp.csc_matrix((vals, (rows, cols)), shape=(3 * n, 3 * n))
    return dict(K=K, G=G, Sx=Sx, SU=SU, flux=flux / area, area=area, Finv=Finv, radius=state.radius)


def _area_term(system):
    """-flux (x) tr(F^-1 dF): d ln|Y| / dF_kl = (F^-1)_lk, macro columns 0..3 only."""
    Finv = system["Finv"]
    trace = np.zeros(N_MACRO)
    trace[:4] = [Finv[l, k] for k, l in ((0, 0), (0, 1), (1, 0), (1, 1))]
    return -np.outer(system["flux"], trace)


def _solve(system, rhs_macro, weights, refine=3):
    """Solve [K + reg I, c A; c A^T, 0] [x; lambda/c] = [-G u; 0] for the macro columns
    ``rhs_macro`` (7 x m). Returns (x (3N x m), lambda (m,)) with lambda the couple density."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla
    K = system["K"]
    n3 = K.shape[0]
    diag = np.abs(K.diagonal())
    # 1e-10 of the largest diagonal entry, per block: forces per length and moments per radian
    # differ by ~R^2 kn / ks, and one common shift would disturb the moment balance at 1e-6
    dmax_w = max(diag[0::3].max(initial=0.0), diag[1::3].max(initial=0.0), 1e-300)
    dmax_th = diag[2::3].max(initial=0.0)
    if not dmax_th > 0.0:       # ks = kr = 0: rotations cost nothing
        dmax_th = dmax_w * float(np.mean(system["radius"] ** 2))
    reg = np.full(n3, 1e-10 * dmax_w)
    reg[2::3] = 1e-10 * dmax_th
    Kr = K + sp.diags(reg, format="csc")
    col = np.zeros(n3)
    col[2::3] = weights
    # scale the constraint to the rotational stiffness so the LU sees comparable entries
    scale = max(diag[2::3].max(initial=0.0), 1e-300) / max(float(np.abs(weights).max()), 1e-300)
    c = sp.csc_matrix(scale * col.reshape(-1, 1))
    A_reg = sp.bmat([[Kr, c], [c.T, None]], format="csc")
    A = sp.bmat([[K, c], [c.T, None]], format="csc")
    rhs = np.zeros((n3 + 1, rhs_macro.shape[1]))
    rhs[:n3] = -system["G"] @ rhs_macro
    lu = spla.splu(A_reg)
    X = lu.solve(rhs)
    # iterative refinement against the unregularized system: removes the O(1e-10) bias the
    # shift puts on the mechanisms that the loading does excite (a rattler absorbing the
    # mean-rotation constraint spins; its shifted spin energy would otherwise stay in the
    # solution); the unexcited null modes (rigid translation) stay at zero
    for _ in range(refine):
        X += lu.solve(rhs - A @ X)
    return X[:n3], scale * X[n3]


def contact_weights(state):
    """The kernel's weights of the held mean rotation (relaxation.contact_weights): the sum of
    |fn| over the touching contacts of each disc [N]."""
    k = np.flatnonzero(state.touching[:state.n_pairs] == 1)
    f = np.abs(state.fn[k])
    return (np.bincount(state.pair_i[k], weights=f, minlength=state.n_particles)
            + np.bincount(state.pair_j[k], weights=f, minlength=state.n_particles))


@njit(cache=True)
def _reaction_triplets(h, s, radius, pair_i, pair_j, fn, fs, mr, touching, n_pairs, kn, Finv, weight):
    """The change of the constraint's reaction with the weights. At a loaded equilibrium every
    disc carries the couple lambda w_p (M_p + lambda w_p = 0, lambda = -sum w M / sum w^2), and
    the force weights w_p = sum |fn| change with the normal forces: d(lambda w_p) contains
    lambda dw_p, dw_p = sum_c sign(fn_c) dfn_c, dfn_c = -kn n . dd_c over the contacts of p
    (dd = dw_j - dw_i + dF F^-1 d). Zero at a state without skew stress (lambda = 0).
    Returns (lambda, COO triplets of K, the 3N x 4 coupling to dF)."""
    n = radius.shape[0]
    moment = np.zeros(n)
    for k in range(n_pairs):
        if touching[k] == 0:
            continue
        i = pair_i[k]
        j = pair_j[k]
        bx, by = branch_vector(h, s, i, j)
        l, nx, ny, tx, ty, ai, aj = contact_frame(bx, by, radius[i], radius[j])
        moment[i] += -ai * fs[k] - mr[k]
        moment[j] += -aj * fs[k] + mr[k]
    num = 0.0
    den = 0.0
    for p in range(n):
        num += weight[p] * moment[p]
        den += weight[p] * weight[p]
    lam = -num / den if den > 0.0 else 0.0
    rows = np.empty(8 * n_pairs, np.int64)
    cols = np.empty(8 * n_pairs, np.int64)
    vals = np.empty(8 * n_pairs)
    G = np.zeros((3 * n, 4))
    m = 0
    for k in range(n_pairs):
        if touching[k] == 0 or lam == 0.0:
            continue
        i = pair_i[k]
        j = pair_j[k]
        bx, by = branch_vector(h, s, i, j)
        l, nx, ny, tx, ty, ai, aj = contact_frame(bx, by, radius[i], radius[j])
        c = -lam * kn * (1.0 if fn[k] >= 0.0 else -1.0)     # lambda d|fn| / d(n . dd)
        for p in (i, j):
            for q, sign in ((i, -1.0), (j, 1.0)):
                rows[m] = 3 * p + 2
                cols[m] = 3 * q
                vals[m] = sign * c * nx
                m += 1
                rows[m] = 3 * p + 2
                cols[m] = 3 * q + 1
                vals[m] = sign * c * ny
                m += 1
            for kl in range(4):
                kk = kl // 2
                ll = kl % 2
                gb = Finv[ll, 0] * bx + Finv[ll, 1] * by
                G[3 * p + 2, kl] += c * (nx if kk == 0 else ny) * gb
    return lam, rows[:m], cols[:m], vals[:m], G


def _with_reaction_change(system, state, law_array, weights):
    """``system`` with the lambda dw_p terms of ``_reaction_triplets`` added to K and G."""
    import scipy.sparse as sp
    lam, rows, cols, vals, G = _reaction_triplets(
        state.h, state.s, state.radius, state.pair_i, state.pair_j, state.fn, state.fs, state.mr,
        state.touching, state.n_pairs, float(law_array[KN]), system["Finv"], weights)
    if lam == 0.0:
        return system
    out = dict(system)
    out["K"] = system["K"] + sp.csc_matrix((vals, (rows, cols)), shape=system["K"].shape)
    out["G"] = system["G"].copy()
    out["G"][:, :4] += G
    return out


def _weights(state, rotation_weights):
    if rotation_weights is None:
        return contact_weights(state)
    w = np.asarray(rotation_weights, dtype=float)
    if w.shape != (state.n_particles,) or not np.isfinite(w).all() or not np.abs(w).max() > 0:
        raise ValueError("rotation_weights must be N finite numbers, not all zero")
    return w


def _flux_response(system, X, U, prestress):
    """d flux = (Sx x + SU u) / |Y| (+ area term): (6 x m)."""
    out = (system["Sx"] @ X + system["SU"] @ U) / system["area"]
    if prestress:
        out += _area_term(system) @ U
    return out


def _to_callback(C7):
    """(6 x 7 internal) -> (C 6x6 callback order, c_phi (6,))."""
    rows = list(CALLBACK_ROWS)
    return C7[np.ix_(rows, list(CALLBACK_COLS))], C7[rows, PHI_COL]


def micropolar_network_operator(state, law_array, prestress=True, rotation_weights=None):
    """Micropolar tangent of the frozen contact network ('pstlo', micropolar measure).

    Returns (C, c_phi): C 6x6 = d(sigma, m)/d(F, kappa) at fixed phi, rows (sigma11, sigma22,
    sigma12, sigma21, m31, m32) [N/m, N], columns (F11 - 1, F22 - 1, F12, F21, kappa1, kappa2)
    [-, 1/m]; c_phi (6,) = d(sigma, m)/dphi [per rad], same rows. law_array: ContactLaw.as_array()."""
    system = network_system(state, law_array, prestress)
    weights = _weights(state, rotation_weights)
    if prestress and rotation_weights is None:
        system = _with_reaction_change(system, state, law_array, weights)
    U = np.eye(N_MACRO)
    X, _ = _solve(system, U, weights)
    return _to_callback(_flux_response(system, X, U, prestress))


def network_response(state, law_array, dF, dphi, dkappa, prestress=True, rotation_weights=None):
    """Response of the frozen network to one macro increment dF (2x2), dphi [rad], dkappa (2,)
    [1/m]. Returns a dict: 'sigma' (2x2 increment [N/m]), 'm' (2,) [N], 'w' (N, 2) fluctuation
    displacements with zero mean [m], 'theta' (N,) total rotation increments of the discs
    (dphi + dkappa . X_p + dth~_p) [rad], 'theta_fluct' (N,) dth~_p, 'lambda' the increment of
    the reaction couple density [N m / m^2] (reaction lambda A_p on disc p)."""
    system = network_system(state, law_array, prestress)
    weights = _weights(state, rotation_weights)
    if prestress and rotation_weights is None:
        system = _with_reaction_change(system, state, law_array, weights)
    U = np.zeros((N_MACRO, 1))
    U[:4, 0] = np.asarray(dF, dtype=float).reshape(4)
    U[4, 0] = float(dphi)
    U[5:, 0] = np.asarray(dkappa, dtype=float).reshape(2)
    X, lam = _solve(system, U, weights)
    d = _flux_response(system, X, U, prestress)[:, 0]
    n = state.n_particles
    x = X[:, 0]
    Xlev = (state.s - 0.5) @ state.h_ref.T
    th_f = x[2::3].copy()
    w = np.column_stack((x[0::3], x[1::3])).reshape(n, 2)
    w -= w.mean(axis=0)       # the rigid translation is arbitrary: report a mean-free fluctuation
    return dict(sigma=d[:4].reshape(2, 2), m=d[4:].copy(), w=w,
                theta=U[4, 0] + Xlev @ U[5:, 0] + th_f, theta_fluct=th_f, **{"lambda": float(lam[0])})


def affine_operator(state, law_array):
    """Uniform-strain estimate (micropolar Kruyt, the assumption of 003 eqs. 21-24): every
    disc follows the affine field (w = 0, th~ = 0), contact springs only (kn, ks if friction >
    0, kr), no pre-stress. 6x6 in the callback order (as micropolar_network_operator's C)."""
    system = network_system(state, law_array, prestress=False, affine=True)
    return _to_callback(system["SU"] / system["area"])[0]
