"""Explicit DEM time stepping of a periodic cell and quasi-static dynamic relaxation.

``advance`` runs the loop, each step made of named kernels that any assembly of discs can
call (they take plain arrays):
  1. neighbour list: ``neighbours_stale`` (skin test), ``rebuild_neighbours`` (new list, the
     contact history carried over);
  2. contact forces (``compute_forces``, ``contact_law.contact_update``) and, in a
     micropolar cell, the reaction of the held mean rotation (``constrain_moments``);
  3. after the ramp, the convergence test every ``check_every`` steps (``kinetic_energy``,
     ``convergence_test``): kinetic / potential energy ratio (000 eqs. 31-32; rattlers
     excluded) or maximum unbalanced force over mean contact force (001 section 2), plus the
     stress targets of the stress-controlled components;
  4. the loading ramp F(tau) = F_i + tau/tau_1 (F_f - F_i) (001 eq. 7), with optional stress
     control of some components of F (mixed control, servo): ``ramp_cell``, ``cell_rates``
     (spin and h^-1), ``ramp_rotation`` (a micropolar cell's phi and kappa);
  5. FIRE (Bitzek et al. 2006: velocity mixing towards the force, adaptive time step up to
     ``fire_dt_max`` x dt, stop when the power F.v turns negative; its sums over the discs in
     the order of lanes.py): ``fire_mix``, when it is the relaxation method;
  6. leapfrog integration (kick and drift) of the fluctuating motion with local non-viscous
     damping f_d = -alpha |f| sign(v), m_d = -beta |m| sign(omega) (000 section 3.2.1, eq.
     30): ``leapfrog``, ``leapfrog_micropolar``.
The slots of the arrays they share (law, ipar, ctrl, out) are those of ``slots``.

The Python function ``run`` wraps the kernel with the settings of a RelaxationOptions: it
grows the pair arrays when needed and turns status codes into a ``RunReport``.
"""
import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from .contact_law import contact_update_params
from .slots import (COH_N, COH_T, C_ALPHA, C_DT, C_DTMAX, C_G, C_GAIN, C_KAP, C_KAP_END, C_KAP_START, C_MASK,
                    C_MAXRATE, C_METHOD, C_PHI, C_PHI_END, C_PHI_START, C_SKIN, C_STOL, C_TARGET, C_TIME, C_TOL,
                    ENERGY_RATIO, ETA_R, FROZEN, I_CHECK, I_CRIT, I_FCUR, I_KRAMP, I_MAXSTEPS, I_NPAIRS, I_NRAMP, KN,
                    KR, KS, MU, NO_CHECK, N_CTRL, N_IPAR, N_OUT, O_BONDLOST, O_EKIN, O_EPOT, O_FMEAN, O_MAXOVL,
                    O_NCONT, O_NSLIDE, O_REACTION, O_REBUILDS, O_S11, O_S12, O_S21, O_S22, O_STEPS, O_UNBAL,
                    ROTATIONS, XI_N, XI_T)
from .errors import SolveError
from .lanes import LANES, dot, fire_sums, sum_products
from .neighbours import build_pairs, cell_strain_norm, max_displacement, merge_history
from .periodic_cell import contact_copy, polar

# status codes of the kernel
CONVERGED, MAX_STEPS, NEED_CAPACITY, NO_CONTACTS, NONFINITE, CELL_TOO_SMALL = range(6)
STATUS_TEXT = {
    CONVERGED: "converged",
    MAX_STEPS: "maximum number of steps reached before convergence",
    NEED_CAPACITY: "pair arrays full",
    NO_CONTACTS: "no contact left in the cell (e.g. pulled apart): the stress is zero",
    NONFINITE: "non-finite positions or energies (time step too large for the stiffness?)",
    CELL_TOO_SMALL: "cell too small or too distorted for the minimum-image convention "
                    "(2 R_max + skin exceeds half a cell width)",
}


@njit(cache=True)
def compute_forces(radius, mass, s, dtheta, force, moment, h, pair_i, pair_j, fn, fs, mr,
                   bonded, touching, d_prev, n_pairs, law, dt, out, image_g0=0.0, image_g1=0.0,
                   plain_path=True):
    """Contact forces and resultants at the current positions; the tangential and rolling
    increments are those of the last step (d - d_prev, dtheta). In a micropolar cell
    (law[ROTATIONS] == 2) the image of j shifted by n = -round(s_j - s_i) lattice vectors turned
    by dtheta_j + g . n in the last step, g = (image_g0, image_g1) = dkappa^T h_ref: the rotation
    jump kappa . Y across the periodic images (docs/reference/micropolar_cell.md). The two periodic copies
    of a contact crossing the cell's side differ in rotation by kappa . Y, so the one counted is
    the copy whose contact point lies in the cell (shifted by -floor(s_contact)): a rule that
    does not depend on how the pair is labelled. Also fills the Cauchy
    stress sigma = (1/|Y|) sum_c f^{j->i} (x) (x_j - x_i) (001 eq. 8, tension positive),
    the potential energy (000 eq. 32), contact counts and the largest overlap / radius.

    Speed (benchmarks/dem/dem_profile.py): the cell matrix and the law are read
    into scalars once (the stores into the pair arrays would otherwise make the compiler
    reload them for every pair), pair indices are used as unsigned integers (no negative-index
    wraparound code per array access) and the minimum-image rounding uses np.floor (a float;
    math.floor returns an integer, i.e. two extra conversions). The arithmetic and its order
    are those of ``branch_vector`` and ``contact_update``: results are bit-identical.
    The branch vectors of all pairs are computed first (``_branch_vectors``: short
    iterations the core overlaps; in a probe this alone made the general loop 15-20 %
    faster, benchmarks/dem/README.md). A cell with the plain frictional law (no bond left, no
    dashpot, rolling spring, frozen contacts or image spin) then goes through
    ``_plain_pair_forces``, the same arithmetic in short loops, about 1.7x faster per step;
    ``plain_path=False`` forces the general loop (the tests compare the two bit for bit)."""
    n = radius.shape[0]
    for i in range(n):
        force[i, 0] = 0.0
        force[i, 1] = 0.0
        moment[i] = 0.0
    h00 = h[0, 0]
    h01 = h[0, 1]
    h10 = h[1, 0]
    h11 = h[1, 1]
    area = abs(h00 * h11 - h01 * h10)
    kn = law[KN]
    ks = law[KS]
    mu = law[MU]
    kr = law[KR]
    eta_r = law[ETA_R]
    xi_n = law[XI_N]
    xi_t = law[XI_T]
    coh_n = law[COH_N]
    coh_t = law[COH_T]
    frozen = law[FROZEN] > 0.5
    image_spin = law[ROTATIONS] > 1.5 and (image_g0 != 0.0 or image_g1 != 0.0)
    viscous = xi_n > 0.0
    need_eff = viscous or xi_t > 0.0 or kr > 0.0
    # spring energies f^2 / (2 k) (000 eq. 32); a zero stiffness carries no force
    half_inv_kn = 0.5 / kn
    half_inv_ks = 0.5 / ks if ks > 0.0 else 0.0
    half_inv_kr = 0.5 / kr if kr > 0.0 else 0.0
    # cohesion acts only through bonds: a law with cohesion but no bond left is plain
    if plain_path and not (frozen or image_spin or need_eff or _any_bond(bonded, n_pairs)):
        s11, s12, s21, s22, epot, ncont, nslide, fsum, maxovl = _plain_pair_forces(
            radius, s, dtheta, force, moment, h00, h01, h10, h11, pair_i, pair_j, fn, fs, mr,
            touching, d_prev, n_pairs, kn, ks, mu, half_inv_kn, half_inv_ks)
        _store_sums(out, area, s11, s12, s21, s22, epot, ncont, nslide, fsum, maxovl)
        return
    work = np.empty((n_pairs, 3))     # branch vector and distance of every pair (first pass)
    _branch_vectors(s, h00, h01, h10, h11, pair_i, pair_j, n_pairs, work)
    s11 = 0.0
    s12 = 0.0
    s21 = 0.0
    s22 = 0.0
    epot = 0.0
    ncont = 0
    nslide = 0
    fsum = 0.0
    maxovl = 0.0
    # the resultant on particle i is kept in registers (fix, fiy, mi) while consecutive pairs
    # share i (the list is sorted by i) and written back whenever i changes: the same
    # additions in the same order (exact for any pair order, as j > i never equals the
    # current i), without a store-to-load round trip through memory per pair
    none = np.uint64(n)
    cur = none
    fix = 0.0
    fiy = 0.0
    mi = 0.0
    for k in range(np.uint64(n_pairs)):
        i = np.uint64(pair_i[k])
        j = np.uint64(pair_j[k])
        if i != cur:
            if cur != none:
                force[cur, 0] = fix
                force[cur, 1] = fiy
                moment[cur] = mi
            cur = i
            fix = force[i, 0]
            fiy = force[i, 1]
            mi = moment[i]
        dx = work[k, 0]
        dy = work[k, 1]
        dist = work[k, 2]
        ri = radius[i]
        rj = radius[j]
        overlap = ri + rj - dist
        if frozen:
            if touching[k] == 0:
                continue
            bond = 1
        else:
            bond = bonded[k]
            if overlap <= 0.0 and bond == 0:
                _release(k, touching, fn, fs, mr)
                continue
        inv_dist, nx, ny, ai, aj = _contact_frame(dx, dy, dist, ri, rj, overlap)
        tx = -ny
        ty = nx
        if touching[k] == 1:
            ux = dx - d_prev[k, 0]
            uy = dy - d_prev[k, 1]
            d_ovl = 0.0
            if viscous:       # the overlap rate is only needed by the normal dashpot
                d_ovl = math.sqrt(d_prev[k, 0] ** 2 + d_prev[k, 1] ** 2) - dist
            dth_i = dtheta[i]
            dth_j = dtheta[j]
            if image_spin:
                # the minimum image again, as in _branch_vectors (the same operations)
                a = s[j, 0] - s[i, 0]
                b = s[j, 1] - s[i, 1]
                round_a = np.floor(a + 0.5)
                round_b = np.floor(b + 0.5)
                a -= round_a
                b -= round_b
                # image shift n = -(round_a, round_b); the copy with its contact point in the
                # cell is shifted by -m for both discs
                m_a, m_b = contact_copy(s, i, a, b, ai * inv_dist)
                copy_shift = image_g0 * m_a + image_g1 * m_b
                dth_i -= copy_shift
                dth_j -= image_g0 * round_a + image_g1 * round_b + copy_shift
            d_ut = ux * tx + uy * ty - ai * dth_i - aj * dth_j
            d_thr = dth_j - dth_i
            fs_old = fs[k]
            mr_old = mr[k]
        else:
            d_ovl = 0.0
            d_ut = 0.0
            d_thr = 0.0
            fs_old = 0.0
            mr_old = 0.0
        m_eff = 0.0
        r_eff = 0.0
        if need_eff:          # only the dashpots and the rolling limit use them
            m_eff = mass[i] * mass[j] / (mass[i] + mass[j])
            r_eff = ri * rj / (ri + rj)
        fnt, fne, fst, fse, mrk, sl, bond = contact_update_params(
            overlap, d_ovl, d_ut, d_thr, fs_old, mr_old, bond, kn, ks, mu, kr, eta_r, xi_n, xi_t,
            coh_n, coh_t, m_eff, r_eff, dt)
        if not frozen:
            bonded[k] = bond
            if fne == 0.0 and fst == 0.0 and overlap <= 0.0:
                _release(k, touching, fn, fs, mr)
                continue
        touching[k] = 1
        d_prev[k, 0] = dx
        d_prev[k, 1] = dy
        fn[k] = fnt
        fs[k] = fse
        mr[k] = mrk
        fjx = fnt * nx + fst * tx
        fjy = fnt * ny + fst * ty
        force[j, 0] += fjx
        force[j, 1] += fjy
        fix -= fjx
        fiy -= fjy
        mi += -ai * fst - mrk
        moment[j] += -aj * fst + mrk
        s11 -= fjx * dx
        s12 -= fjx * dy
        s21 -= fjy * dx
        s22 -= fjy * dy
        epot += half_inv_kn * fne * fne + half_inv_ks * fse * fse + half_inv_kr * mrk * mrk
        ncont += 1
        nslide += sl
        fsum += abs(fnt)
        rmin_ij = min(ri, rj)
        if overlap > maxovl * rmin_ij:
            maxovl = overlap / rmin_ij
    if cur != none:
        force[cur, 0] = fix
        force[cur, 1] = fiy
        moment[cur] = mi
    _store_sums(out, area, s11, s12, s21, s22, epot, ncont, nslide, fsum, maxovl)


@njit(cache=True)
def _store_sums(out, area, s11, s12, s21, s22, epot, ncont, nslide, fsum, maxovl):
    """The sums of the force loop into the output slots: stress (001 eq. 8), energy, counts."""
    out[O_S11] = s11 / area
    out[O_S12] = s12 / area
    out[O_S21] = s21 / area
    out[O_S22] = s22 / area
    out[O_EPOT] = epot
    out[O_NCONT] = ncont
    out[O_NSLIDE] = nslide
    out[O_FMEAN] = fsum / ncont if ncont > 0 else 0.0
    out[O_MAXOVL] = maxovl


@njit(cache=True)
def _contact_frame(dx, dy, dist, ri, rj, overlap):
    """1 / |d|, the unit normal n = d / |d| from i to j (the tangent is t = (-n_y, n_x)) and the
    lever arms of i and j to the contact point in the middle of the overlap (001 eqs.
    A.5-A.6), for both force loops."""
    inv_dist = 1.0 / dist
    return inv_dist, dx * inv_dist, dy * inv_dist, ri - 0.5 * overlap, rj - 0.5 * overlap


@njit(cache=True)
def _release(k, touching, fn, fs, mr):
    """Pair k carries no force: its contact and its history are cleared."""
    touching[k] = 0
    fn[k] = 0.0
    fs[k] = 0.0
    mr[k] = 0.0


@njit(cache=True)
def _any_bond(bonded, n_pairs):
    """True if a cohesive bond holds any listed pair (no early exit: the loop vectorises)."""
    acc = 0
    for k in range(n_pairs):
        acc |= bonded[k]
    return acc != 0


@njit(cache=True)
def _branch_vectors(s, h00, h01, h10, h11, pair_i, pair_j, n_pairs, work):
    """First pass of the force loops: minimum-image branch vector x_j - x_i [m] (``branch_vector``,
    001 eq. A.1) and its length of every listed pair into work[:, 0:3]: short, independent
    iterations without branches, which the core overlaps (see ``_plain_pair_forces``)."""
    for k in range(np.uint64(n_pairs)):
        i = np.uint64(pair_i[k])
        j = np.uint64(pair_j[k])
        a = s[j, 0] - s[i, 0]
        b = s[j, 1] - s[i, 1]
        a -= np.floor(a + 0.5)
        b -= np.floor(b + 0.5)
        dx = h00 * a + h01 * b
        dy = h10 * a + h11 * b
        work[k, 0] = dx
        work[k, 1] = dy
        work[k, 2] = math.sqrt(dx * dx + dy * dy)


@njit(cache=True)
def _plain_pair_forces(radius, s, dtheta, force, moment, h00, h01, h10, h11, pair_i, pair_j,
                       fn, fs, mr, touching, d_prev, n_pairs, kn, ks, mu, half_inv_kn,
                       half_inv_ks):
    """``compute_forces`` for the plain frictional law of 000 (eq. 10: linear springs kn, ks
    [N/m], Coulomb mu; no bond, dashpot, rolling spring, frozen contacts or image spin), the
    law of every FEM x DEM cell. Returns the sums (s11, s12, s21, s22 before the division by
    the area, epot, ncont, nslide, fsum, maxovl); force and moment must be zero on entry.

    Speed (benchmarks/dem/dem_profile.py): the general loop is one long
    dependent chain per pair (image, square root, division, law, scatter: some 250
    instructions), too long for the out-of-order window to start the next pair while one
    finishes (on a Zen 3 core it ran at about 40 ns per pair). Here it is split into three
    loops of short, independent iterations: (1) the minimum-image branch vectors and
    distances (``_branch_vectors``, which the general loop shares), (2) the contact law per
    pair, its force, moments and energy into a scratch row, (3) the scatter to the particles
    and the sums, in the pair order of the general loop. Each contact sees the same
    floating-point operations in the same order, and every sum is taken in the same order:
    the results are bit-identical to the general loop (tests/test_demcell_kernels.py
    compares them)."""
    # the scratch is allocated here, not passed in: the compiler then knows that it aliases
    # none of the arrays the loops store into (passed in, it cost 5-10 % of the step)
    work = np.empty((n_pairs, 8))    # dx, dy, |d|, f_j (2), moment on i, on j, energy
    _branch_vectors(s, h00, h01, h10, h11, pair_i, pair_j, n_pairs, work)
    m = np.uint64(n_pairs)
    ncont = 0
    nslide = 0
    maxovl = 0.0
    for k in range(m):
        i = np.uint64(pair_i[k])
        j = np.uint64(pair_j[k])
        dx = work[k, 0]
        dy = work[k, 1]
        dist = work[k, 2]
        ri = radius[i]
        rj = radius[j]
        overlap = ri + rj - dist
        if overlap <= 0.0:
            _release(k, touching, fn, fs, mr)
            continue
        inv_dist, nx, ny, ai, aj = _contact_frame(dx, dy, dist, ri, rj, overlap)
        tx = -ny
        ty = nx
        # contact_update_params without bond, dashpot or rolling spring: the same operations
        if touching[k] == 1:
            ux = dx - d_prev[k, 0]
            uy = dy - d_prev[k, 1]
            d_ut = ux * tx + uy * ty - ai * dtheta[i] - aj * dtheta[j]
            fst = fs[k] - ks * d_ut
        else:
            fst = 0.0 - ks * 0.0
        fnt = kn * overlap
        limit = mu * fnt if fnt > 0.0 else 0.0
        if abs(fst) > limit:
            fst = math.copysign(limit, fst)
            nslide += 1
        touching[k] = 1
        d_prev[k, 0] = dx
        d_prev[k, 1] = dy
        fn[k] = fnt
        fs[k] = fst
        mr[k] = 0.0
        work[k, 3] = fnt * nx + fst * tx
        work[k, 4] = fnt * ny + fst * ty
        work[k, 5] = -ai * fst - 0.0
        work[k, 6] = -aj * fst + 0.0
        work[k, 7] = half_inv_kn * fnt * fnt + half_inv_ks * fst * fst
        ncont += 1
        rmin_ij = min(ri, rj)
        if overlap > maxovl * rmin_ij:
            maxovl = overlap / rmin_ij
    s11 = 0.0
    s12 = 0.0
    s21 = 0.0
    s22 = 0.0
    epot = 0.0
    fsum = 0.0
    none = np.uint64(radius.shape[0])
    cur = none
    fix = 0.0
    fiy = 0.0
    mi = 0.0
    for k in range(m):
        if touching[k] == 0:
            continue
        i = np.uint64(pair_i[k])
        j = np.uint64(pair_j[k])
        if i != cur:      # resultant of i in registers while the pairs share i (sorted by i)
            if cur != none:
                force[cur, 0] = fix
                force[cur, 1] = fiy
                moment[cur] = mi
            cur = i
            fix = force[i, 0]
            fiy = force[i, 1]
            mi = moment[i]
        fjx = work[k, 3]
        fjy = work[k, 4]
        force[j, 0] += fjx
        force[j, 1] += fjy
        fix -= fjx
        fiy -= fjy
        mi += work[k, 5]
        moment[j] += work[k, 6]
        dx = work[k, 0]
        dy = work[k, 1]
        s11 -= fjx * dx
        s12 -= fjx * dy
        s21 -= fjy * dx
        s22 -= fjy * dy
        epot += work[k, 7]
        fsum += abs(fn[k])
    if cur != none:
        force[cur, 0] = fix
        force[cur, 1] = fiy
        moment[cur] = mi
    return s11, s12, s21, s22, epot, ncont, nslide, fsum, maxovl


@njit(cache=True)
def inv2(a):
    """The inverse of a 2x2 matrix (its adjugate over its determinant)."""
    det = a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0]
    r = np.empty((2, 2))
    r[0, 0] = a[1, 1] / det
    r[0, 1] = -a[0, 1] / det
    r[1, 0] = -a[1, 0] / det
    r[1, 1] = a[0, 0] / det
    return r


@njit(cache=True)
def _inv2_scalars(a00, a01, a10, a11):
    """Entries (00, 01, 10, 11) of the inverse of a 2x2 matrix, as inv2 computes them."""
    det = a00 * a11 - a01 * a10
    return a11 / det, -a01 / det, -a10 / det, a00 / det


@njit(cache=True, nogil=True)
def _kick(force, v, inv_m, i, dt, damp):
    """Velocity of particle i from its force with local non-viscous damping (000 section 3.2.1);
    returns (|v|^2, the displacement v dt)."""
    for c in range(2):
        f = force[i, c]
        if damp > 0.0 and v[i, c] != 0.0:
            f -= damp * abs(f) * math.copysign(1.0, v[i, c])
        v[i, c] += dt * inv_m[i] * f
    return v[i, 0] * v[i, 0] + v[i, 1] * v[i, 1], v[i, 0] * dt, v[i, 1] * dt


@njit(cache=True, nogil=True)
def leapfrog(force, moment, v, s, omega, dtheta, theta, inv_m, inv_i, hinv00, hinv01, hinv10, hinv11,
             dt, damp, rot, spin):
    """One leapfrog step with local non-viscous damping (000 section 3.2.1): velocities from
    the forces, scaled positions s advanced with h^-1 (entries hinv..) and wrapped into [0, 1),
    rotations from the moments (rot False: locked) plus the macroscopic spin increment.
    Returns max |v|^2 (the bound on the displacement since the last neighbour build)."""
    vmax2 = 0.0
    for i in range(s.shape[0]):
        v2, dxs, dys = _kick(force, v, inv_m, i, dt, damp)
        if v2 > vmax2:
            vmax2 = v2
        s[i, 0] += hinv00 * dxs + hinv01 * dys
        s[i, 1] += hinv10 * dxs + hinv11 * dys
        if s[i, 0] >= 1.0 or s[i, 0] < 0.0:
            s[i, 0] -= math.floor(s[i, 0])
        if s[i, 1] >= 1.0 or s[i, 1] < 0.0:
            s[i, 1] -= math.floor(s[i, 1])
        if rot:
            mo = moment[i]
            if damp > 0.0 and omega[i] != 0.0:
                mo -= damp * abs(mo) * math.copysign(1.0, omega[i])
            omega[i] += dt * inv_i[i] * mo
            dtheta[i] = omega[i] * dt + spin
        else:
            omega[i] = 0.0
            dtheta[i] = 0.0
        theta[i] += dtheta[i]
    return vmax2


@njit(cache=True)
def constrain_moments(moment, weight, inv_i, pair_i, pair_j, touching, fn, n_pairs):
    """Micropolar cell: the reaction of the held mean rotation. The constraint is
    sum_p w_p dtheta~_p = 0 with w_p the sum of the normal forces on disc p
    (``contact_weights``): the rotation fluctuation of the discs, averaged with the forces they
    carry, (1/2 sum_c |fn_c|) sum_c |fn_c| (dth~_i + dth~_j), stays zero
    (docs/reference/micropolar_cell.md). Its reaction is a couple lambda w_p on disc p,
    lambda = -sum(w_p M_p / I_p) / sum(w_p^2 / I_p), added to the contact moments, so that
    ``moment`` then holds the net moments. Fills ``weight``; returns (lambda [m], the couple per
    newton of contact force, 1 / sum(w_p^2 / I_p), 0 when no disc carries a force). The sums
    over the discs are taken in the order of lanes.py (the GPU cells take the same)."""
    inv_s2 = contact_weights(weight, inv_i, pair_i, pair_j, touching, fn, n_pairs)
    acc = sum_products(weight, moment, inv_i, np.empty(LANES))
    lam = -acc * inv_s2
    for i in range(moment.shape[0]):
        moment[i] += lam * weight[i]
    return lam, inv_s2


@njit(cache=True)
def contact_weights(weight, inv_i, pair_i, pair_j, touching, fn, n_pairs):
    """Weights of the held mean rotation (``constrain_moments``): weight[p] = sum of |fn| over
    the touching contacts of disc p [N]. Why forces: a disc whose rotation costs (almost)
    nothing -- a rattler, a disc with one contact, a disc held by weak sliding contacts --
    cannot resist the reaction couple, so held in the mean it is spun up and takes the mean with
    it (measured: with equal or contact-count weights, one disc with three sliding contacts of
    1 % of the mean force turned by 2e-2 rad and most of the packing followed the material
    rotation instead of phi). With force weights the reaction on a disc, lambda w_p, and the
    friction it can mobilise, mu sum |fn| a, scale alike, and a contact that opens leaves the
    weights continuously (fn -> 0). Returns 1 / sum(w_p^2 / I_p) (0 when no force)."""
    for i in range(weight.shape[0]):
        weight[i] = 0.0
    for k in range(n_pairs):
        if touching[k] == 1:
            f = abs(fn[k])
            weight[pair_i[k]] += f
            weight[pair_j[k]] += f
    s2 = sum_products(weight, weight, inv_i, np.empty(LANES))
    return 1.0 / s2 if s2 > 0.0 else 0.0


@njit(cache=True, nogil=True)
def leapfrog_micropolar(force, moment, v, s, omega, dtheta, theta, inv_m, inv_i, weight, inv_s2,
                        hinv00, hinv01, hinv10, hinv11, dt, damp, dphi, gk0, gk1, gd0, gd1):
    """``leapfrog`` for a micropolar cell (docs/reference/micropolar_cell.md): the net moments (contact
    + constraint reaction, ``constrain_moments``) drive the rotation fluctuation, whose rates are
    projected back onto sum_p w_p omega_p = 0 (the local damping is not linear, so the
    constrained accelerations alone would let the mean drift); the total rotation increment of
    disc p is omega_p dt + dphi + the increment of the linear field kappa . X_p at its reference
    lever position X_p = h_ref (s_p - c), taken before wrapping (a continuous path). theta_p is
    the total rotation of the disc held in the base cell: when the disc leaves through a side,
    the image that enters is turned by kappa . h_ref n. No macroscopic spin is added.
    (gk0, gk1) = kappa^T h_ref with the new kappa and (gd0, gd1) = dkappa^T h_ref: the rotation
    per unit of fractional coordinate of the linear field and of its change in this step."""
    vmax2 = 0.0
    n = s.shape[0]
    for i in range(n):
        v2, dxs, dys = _kick(force, v, inv_m, i, dt, damp)
        if v2 > vmax2:
            vmax2 = v2
        ds0 = hinv00 * dxs + hinv01 * dys
        ds1 = hinv10 * dxs + hinv11 * dys
        # increment of kappa . X_p along the step (old kappa at the old place -> new at the new)
        dtheta[i] = dphi + gd0 * (s[i, 0] - 0.5) + gd1 * (s[i, 1] - 0.5) + gk0 * ds0 + gk1 * ds1
        s[i, 0] += ds0
        s[i, 1] += ds1
        if s[i, 0] >= 1.0 or s[i, 0] < 0.0:
            w = math.floor(s[i, 0])
            s[i, 0] -= w
            theta[i] -= gk0 * w
        if s[i, 1] >= 1.0 or s[i, 1] < 0.0:
            w = math.floor(s[i, 1])
            s[i, 1] -= w
            theta[i] -= gk1 * w
        mo = moment[i]
        if damp > 0.0 and omega[i] != 0.0:
            mo -= damp * abs(mo) * math.copysign(1.0, omega[i])
        omega[i] += dt * inv_i[i] * mo
    corr = dot(weight, omega, np.empty(LANES)) * inv_s2
    for i in range(n):
        omega[i] -= weight[i] * inv_i[i] * corr
        dtheta[i] += omega[i] * dt
        theta[i] += dtheta[i]
    return vmax2


#: a convergence test that found no reason to stop
GO_ON = -1


@njit(cache=True)
def neighbours_stale(disp, h, h_build, r_cut, skin):
    """True when the neighbour list may miss a contact: the fluctuating displacement since the
    last build (bound ``disp`` [m], counted twice: both discs of a pair move) plus the cell's
    deformation since then, acting over the cut-off r_cut [m], exceed the skin [m]."""
    return 2.1 * disp + cell_strain_norm(h, h_build) * r_cut > skin


@njit(cache=True)
def rebuild_neighbours(h, s, radius, skin, s_build, h_build, pair_i, pair_j, fn, fs, mr, bonded, touching,
                       d_prev, n_pairs):
    """A new neighbour list (every pair closer than R_i + R_j + skin) in place of the old one,
    the contact history carried over (neighbours.merge_history); s_build and h_build become the
    current s and h. Returns (pairs listed, bonds lost), or (-1, 0) when the pair arrays are
    full (nothing changed), (-2, 0) when the cell is too small for the minimum image."""
    n = radius.shape[0]
    cap = pair_i.shape[0]
    new_i = np.empty(cap, np.int64)
    new_j = np.empty(cap, np.int64)
    m = build_pairs(h, s, radius, skin, new_i, new_j)
    if m < 0:
        return m, 0
    t_fs = np.empty(cap)
    t_mr = np.empty(cap)
    t_bd = np.empty(cap, np.uint8)
    t_to = np.empty(cap, np.uint8)
    t_dp = np.empty((cap, 2))
    t_fn = np.empty(cap)
    lost = merge_history(n, n_pairs, pair_i, pair_j, m, new_i, new_j, fs, mr, bonded, touching, d_prev, fn,
                         t_fs, t_mr, t_bd, t_to, t_dp, t_fn)
    pair_i[:] = new_i
    pair_j[:] = new_j
    fs[:] = t_fs
    mr[:] = t_mr
    bonded[:] = t_bd
    touching[:] = t_to
    d_prev[:] = t_dp
    fn[:] = t_fn
    s_build[:] = s
    h_build[:] = h
    return m, lost


@njit(cache=True)
def kinetic_energy(mass, inertia, v, omega, force, moment):
    """(kinetic energy [J/m] of the discs that carry a force, resp. a moment; the largest
    squared resultant force [N^2]). A disc without any contact force (a rattler) or without a
    moment (frictionless) keeps its velocity forever under local damping and carries no
    stress: its kinetic energy is left out of the convergence test (000 eq. 31)."""
    ekin = 0.0
    fmax2 = 0.0
    for i in range(mass.shape[0]):
        f2 = force[i, 0] ** 2 + force[i, 1] ** 2
        if f2 > 0.0:
            ekin += 0.5 * mass[i] * (v[i, 0] ** 2 + v[i, 1] ** 2)
        if moment[i] != 0.0:
            ekin += 0.5 * inertia[i] * omega[i] ** 2
        if f2 > fmax2:
            fmax2 = f2
    return ekin, fmax2


@njit(cache=True)
def convergence_test(ekin, fmax2, crit, ctrl, stress_controlled, smax_t, out):
    """The convergence test of the relaxation: energy ratio E_kin/E_pot <= tol (000 eqs.
    31-32) or largest unbalanced force / mean contact force <= tol (001 section 2), and the
    stress-controlled components (stress_controlled) within ctrl[C_STOL] x smax_t [N/m] of
    their targets. Writes O_EKIN and O_UNBAL; returns CONVERGED, NONFINITE, NO_CONTACTS (no
    contact left and nothing stress-controlled), or GO_ON."""
    out[O_EKIN] = ekin
    unbal = math.sqrt(fmax2) / out[O_FMEAN] if out[O_FMEAN] > 0.0 else math.inf
    out[O_UNBAL] = unbal
    if not (math.isfinite(ekin) and math.isfinite(out[O_EPOT]) and math.isfinite(out[O_S11])):
        return NONFINITE
    if out[O_NCONT] == 0 and not stress_controlled:
        return NO_CONTACTS
    if crit == ENERGY_RATIO:
        ok = ekin <= ctrl[C_TOL] * out[O_EPOT]
    else:
        ok = unbal <= ctrl[C_TOL]
    if ok and stress_controlled:
        for c in range(4):
            if ctrl[C_MASK + c] > 0.5:
                if abs(out[O_S11 + c] - ctrl[C_TARGET + c]) > ctrl[C_STOL] * max(smax_t, 1e-300):
                    ok = False
    return CONVERGED if ok else GO_ON


@njit(cache=True)
def ramp_cell(h, h_old, h_ref, href_inv, F_start, F_end, tau, ctrl, kn, out, polar_ramp, ang0, dang, U0, U1,
              Fm):
    """The cell matrix h [m] of the next step: F = F_start + tau (F_end - F_start) on the
    imposed components (001 eq. 7; polar_ramp: turned by ang0 + tau dang and stretched
    linearly from U0 to U1 instead, polar.py's path), and on the stress-controlled ones
    (ctrl[C_MASK]) the F of h_old corrected by the servo, dF = -gain (sigma - target) / kn
    (kn [N/m]) capped at ctrl[C_MAXRATE]; then h = F h_ref. Fm: scratch (2x2)."""
    for a in range(2):
        for b in range(2):
            c = 2 * a + b
            if ctrl[C_MASK + c] > 0.5:
                dF = -ctrl[C_GAIN] * (out[O_S11 + c] - ctrl[C_TARGET + c]) / kn
                dF = min(max(dF, -ctrl[C_MAXRATE]), ctrl[C_MAXRATE])
                Fm[a, b] = h_old[a, 0] * href_inv[0, b] + h_old[a, 1] * href_inv[1, b] + dF
            elif not polar_ramp:
                Fm[a, b] = F_start[a, b] + tau * (F_end[a, b] - F_start[a, b])
    if polar_ramp:
        if tau >= 1.0:
            Fm[:] = F_end
        else:
            ca = math.cos(ang0 + tau * dang)
            sa = math.sin(ang0 + tau * dang)
            for b in range(2):
                u0b = U0[0, b] + tau * (U1[0, b] - U0[0, b])
                u1b = U0[1, b] + tau * (U1[1, b] - U0[1, b])
                Fm[0, b] = ca * u0b - sa * u1b
                Fm[1, b] = sa * u0b + ca * u1b
    for a in range(2):
        for b in range(2):
            h[a, b] = Fm[a, 0] * h_ref[0, b] + Fm[a, 1] * h_ref[1, b]


@njit(cache=True)
def cell_rates(h_old, h):
    """(macroscopic spin increment [rad], the skew part of dF F^-1 between h_old and h; the
    entries 00, 01, 10, 11 of h^-1 [1/m]). Scalar inverses: no 2x2 array per step, the
    arithmetic of inv2."""
    hi00, hi01, hi10, hi11 = _inv2_scalars(h_old[0, 0], h_old[0, 1], h_old[1, 0], h_old[1, 1])
    g01 = (h[0, 0] - h_old[0, 0]) * hi01 + (h[0, 1] - h_old[0, 1]) * hi11
    g10 = (h[1, 0] - h_old[1, 0]) * hi00 + (h[1, 1] - h_old[1, 1]) * hi10
    spin = 0.5 * (g10 - g01)
    hinv00, hinv01, hinv10, hinv11 = _inv2_scalars(h[0, 0], h[0, 1], h[1, 0], h[1, 1])
    return spin, hinv00, hinv01, hinv10, hinv11


@njit(cache=True)
def fire_mix(force, v, moment, omega, rot, part, fire_a, fire_npos, dt, dt_max, dt_min):
    """One FIRE update (Bitzek et al., PRL 97, 170201, 2006; N_min 5, f_inc 1.1, f_dec 0.5,
    alpha_start 0.1, f_alpha 0.99): while the power F.v is positive the velocities turn
    towards the forces by fire_a and, after 5 such steps, the time step grows (up to dt_max
    [s]) and fire_a shrinks; otherwise the discs stop, the step halves (down to dt_min) and
    fire_a starts again. Sums over the discs in the order of lanes.py (part: scratch).
    Returns (dt, fire_a, fire_npos)."""
    power, vn2, fn2, wn2, mn2 = fire_sums(force, v, moment, omega, rot, part)
    if power > 0.0:
        cv = fire_a * math.sqrt(vn2 / fn2) if fn2 > 0.0 else 0.0
        cw = fire_a * math.sqrt(wn2 / mn2) if mn2 > 0.0 else 0.0
        for i in range(v.shape[0]):
            v[i, 0] = (1.0 - fire_a) * v[i, 0] + cv * force[i, 0]
            v[i, 1] = (1.0 - fire_a) * v[i, 1] + cv * force[i, 1]
            omega[i] = (1.0 - fire_a) * omega[i] + cw * moment[i]
        fire_npos += 1
        if fire_npos > 5:
            dt = min(dt * 1.1, dt_max)
            fire_a *= 0.99
    else:
        dt = max(dt * 0.5, dt_min)
        fire_a = 0.1
        fire_npos = 0
        v[:] = 0.0
        omega[:] = 0.0
    return dt, fire_a, fire_npos


@njit(cache=True)
def ramp_rotation(ctrl, tau, h_ref):
    """Micropolar cell: the micro-rotation phi [rad] and the curvature kappa [1/m] follow the
    ramp (001 eq. 7 applied to phi and kappa). Stores the new kappa in ctrl[C_KAP] and its
    increment on the reference lattice, dkappa^T h_ref, in ctrl[C_G] (also for the next force
    evaluation); returns (phi, kappa31, kappa32)."""
    phi_new = ctrl[C_PHI_START] + tau * (ctrl[C_PHI_END] - ctrl[C_PHI_START])
    k0 = ctrl[C_KAP_START] + tau * (ctrl[C_KAP_END] - ctrl[C_KAP_START])
    k1 = ctrl[C_KAP_START + 1] + tau * (ctrl[C_KAP_END + 1] - ctrl[C_KAP_START + 1])
    dk0 = k0 - ctrl[C_KAP]
    dk1 = k1 - ctrl[C_KAP + 1]
    ctrl[C_KAP] = k0
    ctrl[C_KAP + 1] = k1
    ctrl[C_G] = dk0 * h_ref[0, 0] + dk1 * h_ref[1, 0]
    ctrl[C_G + 1] = dk0 * h_ref[0, 1] + dk1 * h_ref[1, 1]
    return phi_new, k0, k1


@njit(cache=True, nogil=True)   # long: lets run_guard's watchdog act on a signal meanwhile
def advance(radius, mass, inertia, s, v, theta, omega, dtheta, force, moment, s_build, h,
            h_build, h_ref, pair_i, pair_j, fn, fs, mr, bonded, touching, d_prev,
            law, ipar, ctrl, F_start, F_end, out):
    """Run up to ipar[I_MAXSTEPS] steps of the loading ramp + relaxation (see module doc).
    All arrays are updated in place; ipar keeps n_pairs, forces_current and the ramp
    progress so that a call interrupted by NEED_CAPACITY can be resumed. Returns a status.
    Each step: neighbour list (rebuilt when stale), forces, convergence test after the ramp,
    next cell of the ramp, FIRE mixing (method FIRE), kick and drift."""
    n = radius.shape[0]
    dt = ctrl[C_DT]
    alpha = ctrl[C_ALPHA]
    skin = ctrl[C_SKIN]
    rot = law[ROTATIONS] > 0.5
    micropolar = law[ROTATIONS] > 1.5
    rmax = 0.0
    for i in range(n):
        rmax = max(rmax, radius[i])
    r_cut = 2.0 * rmax + skin
    href_inv = inv2(h_ref)
    n_ramp = ipar[I_NRAMP]
    check_every = max(1, ipar[I_CHECK])
    crit = ipar[I_CRIT]
    any_mask = False
    for c in range(4):
        if ctrl[C_MASK + c] > 0.5:
            any_mask = True
    smax_t = 0.0
    for c in range(4):
        if ctrl[C_MASK + c] > 0.5:
            smax_t = max(smax_t, abs(ctrl[C_TARGET + c]))
    h_old = np.empty((2, 2))
    Fm = np.empty((2, 2))
    # micropolar cell: the ramp turns and stretches separately (polar path, as between the
    # sub-steps of DemCell.solve): a straight line in F between two rotations would squeeze the
    # cell half-way (by 1 - cos(da/2)), a real strain that moves contacts and, through the
    # force-weighted mean rotation, the rotation the grains are held at
    polar_ramp = micropolar and not any_mask
    ang0, U0 = polar(F_start)
    ang1, U1 = polar(F_end)
    dang = ang1 - ang0
    dang -= 2.0 * math.pi * math.floor((dang + math.pi) / (2.0 * math.pi))
    inv_m = 1.0 / mass
    inv_i = 1.0 / inertia
    weight = np.zeros(n)       # micropolar: normal force per disc, the weights of the mean rotation
    inv_s2 = 0.0
    if micropolar:             # (a resumed call with current forces needs them from its first step)
        inv_s2 = contact_weights(weight, inv_i, pair_i, pair_j, touching, fn, ipar[I_NPAIRS])
    # FIRE: time step between dt/2^k and dt_max = C_DTMAX dt
    fire = ctrl[C_METHOD] > 0.5
    dt_max = dt * max(ctrl[C_DTMAX], 1.0)
    fire_a = 0.1
    fire_npos = 0
    fire_part = np.empty((5, LANES))
    # bound on the fluctuating displacement since the last neighbour build, updated with
    # max |v| dt each step (5 % margin for the change of h during the accumulation)
    disp = max_displacement(h, s, s_build)
    out[O_STEPS] = 0
    status = MAX_STEPS
    for step in range(ipar[I_MAXSTEPS] + 1):
        if ipar[I_FCUR] == 0:
            if neighbours_stale(disp, h, h_build, r_cut, skin):
                m, lost = rebuild_neighbours(h, s, radius, skin, s_build, h_build, pair_i, pair_j, fn, fs, mr,
                                             bonded, touching, d_prev, ipar[I_NPAIRS])
                if m == -1:
                    return NEED_CAPACITY
                if m == -2:
                    return CELL_TOO_SMALL
                out[O_BONDLOST] += lost
                ipar[I_NPAIRS] = m
                disp = 0.0
                out[O_REBUILDS] += 1
            compute_forces(radius, mass, s, dtheta, force, moment, h, pair_i, pair_j, fn, fs, mr,
                           bonded, touching, d_prev, ipar[I_NPAIRS], law, dt, out,
                           ctrl[C_G], ctrl[C_G + 1])
            if micropolar:
                out[O_REACTION], inv_s2 = constrain_moments(moment, weight, inv_i, pair_i, pair_j, touching,
                                                            fn, ipar[I_NPAIRS])
            ipar[I_FCUR] = 1
        # convergence test once the ramp is over
        if crit != NO_CHECK and ipar[I_KRAMP] >= n_ramp and step % check_every == 0 and step > 0:
            ekin, fmax2 = kinetic_energy(mass, inertia, v, omega, force, moment)
            status = convergence_test(ekin, fmax2, crit, ctrl, any_mask, smax_t, out)
            if status != GO_ON:
                break
            status = MAX_STEPS
        if step == ipar[I_MAXSTEPS]:
            break
        # --- new cell: ramp (001 eq. 7) and servo on the stress-controlled components
        h_old[:] = h
        if ipar[I_KRAMP] < n_ramp:
            ipar[I_KRAMP] += 1
        tau = ipar[I_KRAMP] / n_ramp if n_ramp > 0 else 1.0
        ramp_cell(h, h_old, h_ref, href_inv, F_start, F_end, tau, ctrl, law[KN], out, polar_ramp, ang0, dang,
                  U0, U1, Fm)
        spin, hinv00, hinv01, hinv10, hinv11 = cell_rates(h_old, h)
        damp = alpha
        if fire:
            damp = 0.0
            dt, fire_a, fire_npos = fire_mix(force, v, moment, omega, rot, fire_part, fire_a, fire_npos, dt,
                                             dt_max, ctrl[C_DT] / 64.0)
        if micropolar:
            phi_new, k0, k1 = ramp_rotation(ctrl, tau, h_ref)
            vmax2 = leapfrog_micropolar(force, moment, v, s, omega, dtheta, theta, inv_m, inv_i,
                                        weight, inv_s2, hinv00, hinv01, hinv10, hinv11, dt, damp,
                                        phi_new - ctrl[C_PHI], k0 * h_ref[0, 0] + k1 * h_ref[1, 0],
                                        k0 * h_ref[0, 1] + k1 * h_ref[1, 1], ctrl[C_G], ctrl[C_G + 1])
            ctrl[C_PHI] = phi_new
        else:
            vmax2 = leapfrog(force, moment, v, s, omega, dtheta, theta, inv_m, inv_i,
                             hinv00, hinv01, hinv10, hinv11, dt, damp, rot, spin)
        disp += math.sqrt(vmax2) * dt
        ipar[I_FCUR] = 0
        ctrl[C_TIME] += dt
        out[O_STEPS] += 1
    return status


@dataclass
class RunReport:
    """What one call of ``run`` did. status: one of the codes above; message: plain text."""
    status: int
    message: str
    steps: int
    rebuilds: int
    kinetic_energy: float
    potential_energy: float
    n_contacts: int
    n_sliding: int
    unbalanced_ratio: float
    max_overlap_ratio: float
    bonds_lost: int
    reaction: float = 0.0     # micropolar cell: lambda, the constraint's couple per newton of contact force [m]

    @property
    def converged(self):
        return self.status == CONVERGED


def stable_time_step(radius, mass, inertia, law, safety=0.25):
    """Time step [s] from masses and stiffnesses: dt = safety * 2 / omega_max with
    omega_max^2 = z * max(2 kn/m, 6 ks/m, 2 kr/I)_min over the particles, z = 6 contacts
    (hexagonal packing), i.e. the highest eigen-frequency of a particle held by its
    contact springs (translation 1/m_i + 1/m_j <= 2/m; tangential spring through lever R on
    I = m R^2 / 2 adds 2 R^2 / I = 4/m). A normal dashpot of damping ratio xi reduces the limit
    by (sqrt(1 + xi^2) - xi). Stiffer contacts give a smaller step automatically."""
    m = float(np.min(mass))
    i_min = float(np.min(inertia))
    w2 = max(2.0 * law.kn / m, 6.0 * law.ks / m, 2.0 * law.rolling_stiffness / i_min)
    w = math.sqrt(6.0 * w2)
    xi = max(law.normal_damping, law.tangential_damping)
    return safety * 2.0 / w * (math.sqrt(1.0 + xi * xi) - xi)


def run(state, law_array, dt, F_end, n_ramp, max_steps, options, stress_mask=None, stress_target=None,
        phi_end=None, kappa_end=None, check=True):
    """Ramp the cell from its current F to ``F_end`` in ``n_ramp`` steps, then relax, with the
    relaxation settings of ``options`` (a RelaxationOptions: criterion, tol, check_every,
    damping, skin_ratio, stress_tol, servo_gain, strain_rate as the servo's largest dF per
    step, method, fire_dt_max); ``dt`` [s] the time step, ``law_array`` the kernels' law.
    A micropolar cell (law_array[ROTATIONS] == 2) also ramps its micro-rotation from state.phi
    to ``phi_end`` and its curvature from state.kappa to ``kappa_end`` (None: unchanged).
    Stops at convergence, at ``max_steps`` steps, or on a failure status; check=False: no
    convergence test (plain dynamics for max_steps). ``stress_mask`` (2x2 bool) selects the
    components of F driven by the servo to reach ``stress_target`` (2x2 Cauchy stress [N/m],
    tension positive). Returns a RunReport; raises SolveError on non-finite values (the
    state is then unusable: roll back)."""
    ctrl = np.zeros(N_CTRL)
    ctrl[C_DT], ctrl[C_ALPHA], ctrl[C_TOL], ctrl[C_STOL] = dt, options.damping, options.tol, options.stress_tol
    ctrl[C_GAIN], ctrl[C_MAXRATE] = options.servo_gain, max(options.strain_rate, 1e-12)
    ctrl[C_SKIN], ctrl[C_TIME] = options.skin(state.radius), state.time
    ctrl[C_METHOD], ctrl[C_DTMAX] = options.method_code, options.fire_dt_max
    if stress_mask is not None:
        ctrl[C_MASK:C_MASK + 4] = np.asarray(stress_mask, dtype=float).reshape(4)
        ctrl[C_TARGET:C_TARGET + 4] = np.asarray(stress_target, dtype=float).reshape(4)
    ctrl[C_PHI_START] = ctrl[C_PHI] = state.phi
    ctrl[C_PHI_END] = state.phi if phi_end is None else float(phi_end)
    ctrl[C_KAP_START:C_KAP_START + 2] = state.kappa
    ctrl[C_KAP:C_KAP + 2] = state.kappa
    ctrl[C_KAP_END:C_KAP_END + 2] = state.kappa if kappa_end is None else np.asarray(kappa_end, float)
    ipar = np.zeros(N_IPAR, np.int64)
    ipar[I_NPAIRS], ipar[I_FCUR], ipar[I_NRAMP] = state.n_pairs, state.forces_current, n_ramp
    ipar[I_CHECK], ipar[I_CRIT] = options.check_every, options.criterion_code if check else NO_CHECK
    F_start = state.F
    F_end = np.array(F_end, dtype=np.float64)
    out = np.zeros(N_OUT)
    total = np.zeros(N_OUT)
    remaining = int(max_steps)
    if state.n_pairs == 0 and state.forces_current == 0:
        # fresh state: make the rebuild test fire (h_build far from h) to build the first list
        state.h_build[:] = state.h * 1e3
    while True:
        ipar[I_MAXSTEPS] = remaining
        status = advance(state.radius, state.mass, state.inertia, state.s, state.v, state.theta,
                         state.omega, state.dtheta, state.force, state.moment, state.s_build,
                         state.h, state.h_build, state.h_ref, state.pair_i, state.pair_j,
                         state.fn, state.fs, state.mr, state.bonded, state.touching, state.d_prev,
                         law_array, ipar, ctrl, F_start, F_end, out)
        total[O_STEPS] += out[O_STEPS]
        total[O_REBUILDS] += out[O_REBUILDS]
        total[O_BONDLOST] += out[O_BONDLOST]
        out[O_REBUILDS] = 0
        out[O_BONDLOST] = 0
        remaining -= int(out[O_STEPS])
        state.n_pairs = int(ipar[I_NPAIRS])
        state.forces_current = int(ipar[I_FCUR])
        if status == NEED_CAPACITY:
            state.grow_pairs(2 * state.pair_i.shape[0])
            continue
        break
    state.time = float(ctrl[C_TIME])
    state.phi = float(ctrl[C_PHI])
    state.kappa = ctrl[C_KAP:C_KAP + 2].copy()
    if status == NONFINITE:
        raise SolveError(STATUS_TEXT[NONFINITE] + f" (dt = {dt:.3e} s)")
    if status == CELL_TOO_SMALL:
        raise SolveError(STATUS_TEXT[CELL_TOO_SMALL])
    return RunReport(status=int(status), message=STATUS_TEXT[int(status)], steps=int(total[O_STEPS]),
                     rebuilds=int(total[O_REBUILDS]), kinetic_energy=float(out[O_EKIN]),
                     potential_energy=float(out[O_EPOT]), n_contacts=int(out[O_NCONT]),
                     n_sliding=int(out[O_NSLIDE]), unbalanced_ratio=float(out[O_UNBAL]),
                     max_overlap_ratio=float(out[O_MAXOVL]), bonds_lost=int(total[O_BONDLOST]),
                     reaction=float(out[O_REACTION]))

