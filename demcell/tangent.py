"""Tangent operators of a cell for the macroscopic Newton iteration (paper 001, sections 3-5).

All operators are returned as 4x4 matrices in the notation of 001 eq. 11: rows are
(sigma_11, sigma_12, sigma_21, sigma_22), columns (dF_11, dF_12, dF_21, dF_22), i.e.
d sigma_ij = C_ijkl dF_kl. Since F = I + Grad u with (Grad u)_kl = du_k/dX_l, this is
also d sigma / d Grad u. ``dsigma_to_dpk1`` converts to dP/dF (same ordering), the operator a
total-Lagrangian FE code needs.

* ``kruyt`` (UKO, 001 eq. 13): affine contact displacements, contact springs only; no
  rotations, no pre-stress, no sliding. Written for the current configuration:
  C_ijkm = 1/|Y| sum_c (kn n_i n_k + kt t_i t_k) l_j (F^-1 l)_m, which is eq. 13 when F = I.
* ``perturbation`` (CTO, 001 eq. 6): C_ijmn = (S_ij(F + eps L^mn) - S_ij(F)) / eps, each
  column a full solve from the last committed state (four extra solves).
* ``demqo`` (001 eq. 20): from the current equilibrium, contacts frozen (no loss, no
  creation, bilateral), friction infinite; four small relaxations.
* ``pstlo`` (001 appendix B): the same frozen-contact problem linearized by hand (pre-stress
  terms included) and solved directly (one sparse LU, scipy); equals DEMQO as eps -> 0.
* ``pstlo_sliding``: PSTLO with the contacts at or near their Coulomb limit (|fs| >=
  SLIP_RATIO mu fn) sliding on under the load (dfs = mu sign(fs) dfn, no tangential spring):
  the consistent tangent of the friction law under continued loading, as a return map's in
  plasticity; its stiffness on symmetric strains floored at STIFFNESS_FLOOR of its largest
  eigenvalue (floor_stiffness), so that a cell at its peak is not a mechanism. Not in 001;
  its elastic operators miss the sliding, which is what makes the macro Newton converge
  linearly where cells slide (docs/reference/femdem.md, "Newton operators").

``TANGENT_KINDS`` declares each kind once (``TangentKind``: what it computes, whether a
micropolar cell has it, whether a cell store batches it, whether its work releases the GIL);
``tangent_kind(name)`` looks one up and refuses any other name in one line.
"""
import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from .slots import KN, KR, KS, MU
from .errors import InputError
from .homogenization import contact_sums
from .periodic_cell import branch_vector, contact_frame, deformation_gradient
from .relaxation import inv2

COMPONENTS = ((0, 0), (0, 1), (1, 0), (1, 1))   # order 11, 12, 21, 22 (001 eq. 11)

#: pstlo_sliding: a contact with |fs| >= SLIP_RATIO mu fn counts as sliding. Not 1: a cell
#: relaxed with damping ends with its sliding contacts a little inside the cone (the last
#: oscillations unload them), and under the next Newton correction they reach it again.
#: Chosen with benchmarks/dem_tangent_sliding.py (the FEM x DEM reference cells of 228 and 400
#: discs at 0.4-3.2 % biaxial strain, 20 states): against the perturbation tangent (CTO, 001
#: eq. 6) PSTLO is off by 35 % (median; Frobenius) and by 42 % along the loading direction;
#: with 0.95, 8 % and 9 % (90th percentiles 14 % and 17 %, worst 46 % and 22 %); 0.9 is as good
#: in the median with a worse outlier (64 % along the load); at 0.85 and 0.8 some cells turn
#: into mechanisms (74-85 %).
SLIP_RATIO = 0.95
#: pstlo_sliding: the smallest eigenvalue of its symmetric part on symmetric strains is kept at
#: or above STIFFNESS_FLOOR times the largest (floor_stiffness). A cell at its peak has a
#: (near-)singular or softening consistent tangent: on the reference cell of 228 discs at 1 %
#: and 3.2 % (friction 0.4 and 0.2) CTO's smallest eigenvalue is -330 and -530 N/m against a
#: largest of 8,900-9,300, and pstlo_sliding's 3 and 35. A macro Newton on such points
#: diverges (strain increments of 5 % to 2,000 at single Gauss points past the peak of the
#: 4x8 biaxial, docs/reference/femdem.md). PSTLO's ratio is 0.28-0.33 on the same states; 0.05 leaves
#: every pre-peak state measured there untouched (0.05-0.21).
STIFFNESS_FLOOR = 0.05



@dataclass(frozen=True)
class TangentKind:
    """One tangent operator of a DemCell (``DemCell.tangent(name)``): what it computes and what
    a caller may count on.

    name : the kind's one name (``TANGENT_KINDS``)
    computes : what the operator is, in words, with its source
    micropolar : a micropolar cell also has it as the 6x6 d(sigma, m)/d(F, kappa)
        (measure 'micropolar'); False: for Cauchy cells only (``cauchy_only``)
    batched : a cell store (batch.CellBatch, gpu.DeviceCellBatch) computes it for many
        Cauchy cells in one call (``CellStore.kruyt``, ``CellStore.demqo``)
    batched_micropolar : the same for micropolar cells
    releases_gil : its per-cell work (scipy's sparse LU) releases the GIL, so that threads of
        one process can share the cells
    relaxes : it runs DEM relaxations; their steps are ``DemCell.last_tangent_steps``
    default_eps : the perturbation size of a kind that perturbs (relative, of F), else None
    """
    name: str
    computes: str
    micropolar: bool
    batched: bool
    batched_micropolar: bool
    releases_gil: bool
    relaxes: bool
    default_eps: float = None

    @property
    def cauchy_only(self):
        """For Cauchy cells only: no 6x6 micropolar operator."""
        return not self.micropolar


#: every tangent kind, by its name
TANGENT_KINDS = {k.name: k for k in (
    TangentKind("kruyt", "uniform-strain (Kruyt) operator of the contact springs, closed form (001 eq. 13; "
                "micropolar: uniform strain and rotation field, 003 eqs 21-24)",
                micropolar=True, batched=True, batched_micropolar=False, releases_gil=False, relaxes=False),
    TangentKind("demqo", "frozen-contact quasi-static operator: perturbations eps L^mn of the current equilibrium "
                "with bilateral, non-sliding contacts, each relaxed (DEMQO, 001 eq. 20)",
                micropolar=True, batched=True, batched_micropolar=True, releases_gil=False, relaxes=True,
                default_eps=1e-6),
    TangentKind("pstlo", "the frozen-contact problem linearized with its pre-stress and solved by one sparse "
                "LU (PSTLO, 001 appendix B; micropolar: network.py); DEMQO as eps -> 0",
                micropolar=True, batched=False, batched_micropolar=False, releases_gil=True, relaxes=False),
    TangentKind("pstlo_sliding", "PSTLO with the contacts near their Coulomb limit sliding on (SLIP_RATIO), "
                "its stiffness floored (floor_stiffness): the consistent tangent of the friction law",
                micropolar=False, batched=False, batched_micropolar=False, releases_gil=True, relaxes=False),
    TangentKind("perturbation", "consistent tangent by perturbation (CTO, 001 eq. 6): full solves from the last "
                "commit to F + eps L^mn", micropolar=True, batched=False, batched_micropolar=False,
                releases_gil=False, relaxes=True, default_eps=1e-5),
)}


def tangent_kind(name, micropolar=False):
    """The TangentKind called `name`; micropolar: for a micropolar operator. Anything else is
    refused in one line naming the kinds there are."""
    kinds = [k for k in TANGENT_KINDS.values() if k.micropolar or not micropolar]
    if not isinstance(name, str):
        raise InputError(f"tangent kind must be a string (one of {', '.join(k.name for k in kinds)}), got {name!r}")
    kind = TANGENT_KINDS.get(name)
    if kind is None:
        raise InputError(f"unknown tangent kind {name!r}: one of {', '.join(k.name for k in kinds)}")
    if micropolar and kind.cauchy_only:
        raise InputError(f"tangent {name!r} is for Cauchy cells (measure 'dsigma_dF' or 'dP_dF'); a micropolar "
                         f"cell has {', '.join(k.name for k in kinds)}")
    return kind

def to_tensor4(C):
    """4x4 (001 eq. 11 order) -> C[i, j, k, l]."""
    T = np.zeros((2, 2, 2, 2))
    for r, (i, j) in enumerate(COMPONENTS):
        for c, (k, l) in enumerate(COMPONENTS):
            T[i, j, k, l] = C[r, c]
    return T


def from_tensor4(T):
    """C[i, j, k, l] -> 4x4 (001 eq. 11 order)."""
    return np.array([[T[i, j, k, l] for (k, l) in COMPONENTS] for (i, j) in COMPONENTS])


def dsigma_to_dpk1(C_sigma, F, sigma):
    """dP/dF from dsigma/dF, with P = J sigma F^-T:
    dP = J tr(F^-1 dF) sigma F^-T + J dsigma F^-T - J sigma F^-T dF^T F^-T."""
    J = np.linalg.det(F)
    Fi = np.linalg.inv(F)
    out = np.zeros((4, 4))
    for c, (k, l) in enumerate(COMPONENTS):
        dF = np.zeros((2, 2))
        dF[k, l] = 1.0
        dsig = C_sigma[:, c].reshape(2, 2)
        dP = (J * np.trace(Fi @ dF) * sigma @ Fi.T + J * dsig @ Fi.T
              - J * sigma @ Fi.T @ dF.T @ Fi.T)
        out[:, c] = dP.reshape(4)
    return out


@njit(cache=True)
def _kruyt_sum(h, s, pair_i, pair_j, touching, n_pairs, kn, kt, Fi):
    """sum_c K_ik l_j (F^-1 l)_m over the touching contacts, K = kn n n + kt t t."""
    T = np.zeros((2, 2, 2, 2))
    K = np.empty((2, 2))
    for k in range(n_pairs):
        if touching[k] == 0:
            continue
        dx, dy = branch_vector(h, s, pair_i[k], pair_j[k])
        length = math.sqrt(dx * dx + dy * dy)
        nx, ny = dx / length, dy / length
        K[0, 0] = kn * nx * nx + kt * ny * ny
        K[0, 1] = K[1, 0] = (kn - kt) * nx * ny
        K[1, 1] = kn * ny * ny + kt * nx * nx
        lv = (dx, dy)
        gl = (Fi[0, 0] * dx + Fi[0, 1] * dy, Fi[1, 0] * dx + Fi[1, 1] * dy)
        for i in range(2):
            for j in range(2):
                for kk in range(2):
                    for m in range(2):
                        T[i, j, kk, m] += K[i, kk] * lv[j] * gl[m]
    return T


@njit(cache=True)
def kruyt_tensor(h, h_ref, s, pair_i, pair_j, touching, n_pairs, kn, kt):
    """The Kruyt sum divided by the cell area, T[i, j, k, m] [N/m], with F^-1 from the scalar
    F of periodic_cell.deformation_gradient (one formula for a DemCell and a batch)."""
    Fi = inv2(deformation_gradient(h, h_ref))
    area = abs(h[0, 0] * h[1, 1] - h[0, 1] * h[1, 0])
    return _kruyt_sum(h, s, pair_i, pair_j, touching, n_pairs, kn, kt, Fi) / area


def kruyt_operator(state, law):
    """Upper-bound Kruyt operator (UKO, 001 eq. 13) of the current contacts [N/m]."""
    kt = law[KS] if law[MU] > 0.0 else 0.0
    T = kruyt_tensor(state.h, state.h_ref, state.s, state.pair_i, state.pair_j, state.touching, state.n_pairs,
                     float(law[KN]), float(kt))
    return T.reshape(4, 4).copy()


def perturbation_options(cell, eps, rel=1e-5):
    """Relaxation options for a perturbation of size eps: the unbalanced-force criterion
    (001 section 2) with a tolerance scaled to the force increment the perturbation causes
    (rel x eps x kn x mean branch length / mean contact force, rel = 1e-5). The energy ratio
    of 000 eq. 31 is unfit here: E_pot is dominated by the pre-stress, so it is met long before
    the small perturbation has relaxed."""
    st = cell.state
    npairs = st.n_pairs
    sel = st.touching[:npairs] == 1
    opts = cell.options
    if not sel.any():
        return opts
    fmean = float(np.mean(np.abs(st.fn[:npairs][sel])))
    lmean = 2.0 * float(np.mean(st.radius))
    tol = rel * eps * cell.law.kn * lmean / max(fmean, 1e-300)
    return dataclasses.replace(opts, criterion="force", tol=tol, check_every=10,
                               max_increment=max(opts.max_increment, 2.0 * eps))


def _stress_differences(base, trial_from, F, eps, opts, curvature_eps=None):
    """Relax `base` at F with the tight options `opts`, then for each component m, n solve
    the cell `trial_from(base)` at F + eps L^mn; returns (C 4x4 d sigma/dF, solve results).
    The reference is re-solved with the same options so that the relaxation of its own
    residual does not enter dsigma / eps.
    With ``curvature_eps`` (a micropolar cell) the curvature is perturbed too and the answer
    is the 6x6 d(sigma, m)/d(F, kappa) in demcell's order (rows sigma 11, 12, 21, 22, m1, m2;
    columns F 11, 12, 21, 22, kappa 1, 2), at the cell's target phi and kappa."""
    micropolar = curvature_eps is not None
    base.options = opts
    base.set_deformation(F)
    results = [base.solve()]
    h0 = base.homogenized()
    ref = np.concatenate([h0.cauchy.reshape(4), h0.couple_stress]) if micropolar else h0.cauchy.reshape(4)
    kappa0 = base.state.kappa.copy()
    C = np.zeros((ref.size, ref.size))
    perturbations = [(mn, eps) for mn in COMPONENTS] + ([(k, curvature_eps) for k in (0, 1)] if micropolar else [])
    for c, (what, size) in enumerate(perturbations):
        trial = trial_from(base)
        trial.options = opts
        Fp = F.copy()
        if c < 4:
            Fp[what] += size
            trial.set_deformation(Fp)
        else:
            kp = kappa0.copy()
            kp[what] += size
            trial.set_deformation(Fp, curvature=kp)
        results.append(trial.solve())
        h = trial.homogenized()
        out = np.concatenate([h.cauchy.reshape(4), h.couple_stress]) if micropolar else h.cauchy.reshape(4)
        C[:, c] = (out - ref) / size
    return C, results


def perturbation_tangent(cell, eps=1e-5, options=None):
    """Consistent tangent by perturbation (CTO, 001 eq. 6): for each component, a copy of the
    cell is rolled back to its last committed state and solved to F + eps L^mn. ``cell`` (a
    DemCell, or another cell with copy, rollback, options, set_deformation, solve and
    homogenized) must hold a solved state at F. options: the cell's options for these solves
    (default ``perturbation_options``, a DemCell's). Returns (C 4x4 d sigma/dF, solve results)."""

    def rolled_back_copy(_):
        trial = cell.copy()
        trial.rollback()
        return trial

    opts = perturbation_options(cell, eps) if options is None else options
    return _stress_differences(rolled_back_copy(None), rolled_back_copy, cell.deformation_gradient(), eps, opts)


def demqo_tangent(cell, eps=1e-6):
    """DEM-based quasi-static operator (DEMQO, 001 eq. 20): four perturbations eps L^mn from
    the current equilibrium with frozen, non-sliding contacts. ``cell`` must be a DemCell."""
    base = cell.copy()
    base.freeze_contacts()
    return _stress_differences(base, lambda b: b.copy(), cell.deformation_gradient(), eps,
                               perturbation_options(cell, eps))


def micropolar_tangent(cell, kind, eps=None):
    """6x6 d(sigma, m)/d(F, kappa) of a micropolar cell at fixed phi, in the FE callback's order
    (see DemCell.tangent). 'perturbation' and 'demqo' perturb F by eps and kappa by
    eps / max|Y_k| (a rotation jump of eps across the cell). Returns (C, solve results)."""
    from .network import CALLBACK_ROWS, affine_operator, micropolar_network_operator
    if kind == "pstlo":
        return micropolar_network_operator(cell.state, cell.law_array)[0], []
    if kind == "kruyt":
        return affine_operator(cell.state, cell.law_array), []
    eps = tangent_kind(kind, micropolar=True).default_eps if eps is None else eps
    k_eps = eps / float(np.abs(cell.state.h_ref).sum(axis=0).max())
    F = cell.deformation_gradient()
    if kind == "perturbation":
        _, phi, kappa = cell.target

        def rolled_back_copy(_):
            trial = cell.copy()
            trial.rollback()
            trial.target = (F, phi, kappa)
            return trial
        C, results = _stress_differences(rolled_back_copy(None), rolled_back_copy, F, eps,
                                         perturbation_options(cell, eps), curvature_eps=k_eps)
    else:
        base = cell.copy()
        base.freeze_contacts()
        C, results = _stress_differences(base, lambda b: b.copy(), F, eps, perturbation_options(cell, eps),
                                         curvature_eps=k_eps)
    # demcell's order (11, 12, 21, 22, then kappa / m 1, 2) -> the FE callback order, the same
    # permutation for the rows (fluxes) and the columns (gradients)
    order = list(CALLBACK_ROWS)
    return C[np.ix_(order, order)], results


@njit(cache=True)
def _pstlo_triplets(h, s, radius, pair_i, pair_j, fn, fs, mr, touching, n_pairs, kn, ks, kr, Finv,
                    mu=0.0, slip_ratio=0.0):
    """Linearized equilibrium of the frozen, non-sliding contact network (001 appendix B).

    Unknowns per particle p: fluctuation displacement w_p (2) and total rotation dtheta_p (1),
    dof numbers 3p, 3p+1, 3p+2. Per contact, db = w_j - w_i + dF F^-1 b (001 eq. B.3) and
      dfn = -kn n.db, dfs = -ks (t.db - a_i dth_i - a_j dth_j), dmr = -kr (dth_j - dth_i),
      dn = (t t^T) db / l, dt = -(n t^T) db / l (eq. B.4), da = (n.db) / 2 (eq. B.6 along n),
    with f_j = fn n + fs t the force on j, M_i = -a_i fs - mr, M_j = -a_j fs + mr.
    Returns COO triplets of K (d residual / d unknowns, residual = resultant force/moment),
    the 3N x 4 coupling G (d residual / d F_kl) and the stress sensitivities
    Sx (4 x 3N, d sigma / d unknowns, times area) and SF (4 x 4, times area; the area change
    term is added by the caller).

    ``slip_ratio`` > 0: a contact at or near its Coulomb limit (|fs| >= slip_ratio mu fn,
    fn > 0; mu is the law's friction) goes on sliding: dfs = mu sign(fs) dfn replaces the
    tangential spring (the consistent tangent of the Coulomb law under continued loading, as
    the return map of plasticity; the network keeps its normal springs and pre-stress)."""
    n = radius.shape[0]
    cap = 0
    for k in range(n_pairs):
        if touching[k] == 1:
            cap += 1
    rows = np.empty(cap * 36, np.int64)
    cols = np.empty(cap * 36, np.int64)
    vals = np.empty(cap * 36)
    G = np.zeros((3 * n, 4))
    Sx = np.zeros((4, 3 * n))
    SF = np.zeros((4, 4))
    m = 0
    # local operator L (rows: f_j x, f_j y, M_i, M_j ; cols: db x, db y, dth_i, dth_j)
    L = np.empty((4, 4))
    for k in range(n_pairs):
        if touching[k] == 0:
            continue
        i = pair_i[k]
        j = pair_j[k]
        bx, by = branch_vector(h, s, i, j)
        l, nx, ny, tx, ty, ai, aj = contact_frame(bx, by, radius[i], radius[j])
        f_n = fn[k]
        f_s = fs[k]
        # on the Coulomb limit: the tangential force follows the normal one (slip_mu), no spring
        slip_mu = 0.0
        on_limit = slip_ratio > 0.0 and f_n > 0.0 and abs(f_s) >= mu * f_n * slip_ratio
        if on_limit:
            slip_mu = math.copysign(mu, f_s)
        for c in range(2):
            e = 1.0 if c == 0 else 0.0
            o = 1.0 - e
            ndb = nx * e + ny * o          # n . db for db = unit vector c
            tdb = tx * e + ty * o
            dfn = -kn * ndb
            dfs = slip_mu * dfn if on_limit else -ks * tdb
            dnx = tx * tdb / l
            dny = ty * tdb / l
            dtx = -nx * tdb / l
            dty = -ny * tdb / l
            L[0, c] = dfn * nx + f_n * dnx + dfs * tx + f_s * dtx
            L[1, c] = dfn * ny + f_n * dny + dfs * ty + f_s * dty
            da = 0.5 * ndb
            L[2, c] = -da * f_s - ai * dfs
            L[3, c] = -da * f_s - aj * dfs
        # rotations: dfs = ks a_i dth_i (+ ks a_j dth_j), rolling dmr = kr dth_i (- kr dth_j)
        for c in range(2):
            a = ai if c == 0 else aj
            dfs = 0.0 if on_limit else ks * a
            dmr = kr if c == 0 else -kr
            L[0, 2 + c] = dfs * tx
            L[1, 2 + c] = dfs * ty
            L[2, 2 + c] = -ai * dfs - dmr
            L[3, 2 + c] = -aj * dfs + dmr
        # chain to the unknowns: db = w_j - w_i (+ affine part), so the columns of w_i get -L and
        # those of w_j +L; residual rows: force on i = -f_j, force on j = +f_j, M_i, M_j
        dof = (3 * i, 3 * i + 1, 3 * j, 3 * j + 1, 3 * i + 2, 3 * j + 2)
        for rr in range(6):
            if rr < 2:
                lrow, sign = rr, -1.0
            elif rr < 4:
                lrow, sign = rr - 2, 1.0
            elif rr == 4:
                lrow, sign = 2, 1.0
            else:
                lrow, sign = 3, 1.0
            for cc in range(6):
                if cc < 2:
                    val = -L[lrow, cc]
                elif cc < 4:
                    val = L[lrow, cc - 2]
                elif cc == 4:
                    val = L[lrow, 2]
                else:
                    val = L[lrow, 3]
                rows[m] = dof[rr]
                cols[m] = dof[cc]
                vals[m] = sign * val
                m += 1
            # affine part: db = dF Finv b -> d db_a / dF_kl = delta_ak (Finv b)_l
            for kl in range(4):
                kk = kl // 2
                ll = kl % 2
                gb = Finv[ll, 0] * bx + Finv[ll, 1] * by
                G[dof[rr], kl] += sign * L[lrow, kk] * gb
        # stress (times area): sigma_ab = -sum f_a b_b -> d = -(df_a b_b + f_a db_b)
        fjx = f_n * nx + f_s * tx
        fjy = f_n * ny + f_s * ty
        fvec = (fjx, fjy)
        bvec = (bx, by)
        for ab in range(4):
            aa = ab // 2
            bb = ab % 2
            # unknowns: db depends on w_i (-), w_j (+); df depends on db and rotations
            for cc in range(2):
                coef = -(L[aa, cc] * bvec[bb] + (fvec[aa] if bb == cc else 0.0))
                Sx[ab, 3 * i + cc] -= coef
                Sx[ab, 3 * j + cc] += coef
            Sx[ab, 3 * i + 2] += -L[aa, 2] * bvec[bb]
            Sx[ab, 3 * j + 2] += -L[aa, 3] * bvec[bb]
            for kl in range(4):
                kk = kl // 2
                ll = kl % 2
                gb = Finv[ll, 0] * bx + Finv[ll, 1] * by
                SF[ab, kl] += -(L[aa, kk] * gb * bvec[bb] + (fvec[aa] * gb if bb == kk else 0.0))
    return rows[:m], cols[:m], vals[:m], G, Sx, SF


def floor_stiffness(C, fraction=STIFFNESS_FLOOR):
    """C (4x4, order 11, 12, 21, 22) with the eigenvalues of its symmetric part on symmetric
    strains raised to at least `fraction` times the largest: in Mandel form (e11, e22,
    sqrt2 e12) the symmetric part's eigenpairs (lam, v) below the floor f get (f - lam) v v^T
    added, mapped back to the 4x4 so that it acts on the symmetric part of dF and gives a
    symmetric stress. C is returned unchanged (the same array) when no eigenvalue is below
    the floor. Units those of C [N/m in 2D]."""
    r = 1.0 / math.sqrt(2.0)
    # Mandel basis of the symmetric 2x2 tensors in the 11, 12, 21, 22 order
    B = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0], [0.0, r, r, 0.0]])
    M = B @ C @ B.T
    lam, vec = np.linalg.eigh(0.5 * (M + M.T))
    floor = fraction * lam[-1]
    low = lam < floor
    if not low.any():
        return C
    correction = (vec[:, low] * (floor - lam[low])) @ vec[:, low].T
    return C + B.T @ correction @ B


def _solve_structurally_symmetric(K, B, spla):
    """K X = B for the PSTLO stiffness: K is structurally symmetric (not symmetric: the
    pre-stress terms), so a minimum-degree ordering of K + K^T without row pivoting is about
    2.5x faster than SuperLU's default for a few hundred discs; the answer is checked by its
    residual and the pivoting LU is the fall-back."""
    try:
        X = spla.splu(K, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                      options={"SymmetricMode": True}).solve(B)
        scale = max(float(np.abs(B).max()), 1e-300)
        if np.isfinite(X).all() and float(np.abs(K @ X - B).max()) <= 1e-9 * scale:
            return X
    except RuntimeError:     # a zero pivot without pivoting
        pass
    return spla.splu(K).solve(B)


def pstlo_operator(state, law, slip_ratio=0.0):
    """Pre-stressed truss-like operator (PSTLO, 001 appendix B): d sigma / dF of the current
    equilibrium with frozen, non-sliding contacts, by one sparse linear solve of the
    linearized equilibrium (incl. pre-stress terms f_n de, f_t dt and lever-arm changes).
    Rigid translation and mechanisms (rattlers, free spins) are removed by a tiny diagonal
    regularization (1e-10 of the largest diagonal entry). Same ordering as 001 eq. 11."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla
    n = state.n_particles
    F = state.F
    Finv = np.linalg.inv(F)
    area = abs(np.linalg.det(state.h))
    rows, cols, vals, G, Sx, SF = _pstlo_triplets(
        state.h, state.s, state.radius, state.pair_i, state.pair_j, state.fn, state.fs, state.mr,
        state.touching, state.n_pairs, float(law[KN]), float(law[KS]), float(law[KR]), Finv, float(law[MU]),
        slip_ratio)
    K = sp.csc_matrix((vals, (rows, cols)), shape=(3 * n, 3 * n))
    diag = np.abs(K.diagonal())
    reg = 1e-10 * max(diag.max(initial=0.0), 1e-300)
    K = K + sp.identity(3 * n, format="csc") * reg
    X = _solve_structurally_symmetric(K, -G, spla)   # unknowns per unit dF_kl
    C = (Sx @ X + SF) / area
    sigma = contact_sums(state.h, state.s, state.radius, state.pair_i, state.pair_j, state.fn, state.fs,
                         state.mr, state.touching, state.n_pairs, float(law[MU]), state.h_ref, False)[0]
    trace_term = np.array([Finv[l, k] for (k, l) in COMPONENTS])   # d ln J / dF_kl
    C -= np.outer(sigma.reshape(4), trace_term)
    return C

