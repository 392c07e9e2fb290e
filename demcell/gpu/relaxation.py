"""``relaxation.advance`` on a GPU block: the loading ramp and the relaxation of one cell.

The loop of the CPU kernel, step by step, with the work of a step shared by the threads of
the block: the neighbour rebuild (neighbours.py), the contact law per pair and the resultant
per disc (contacts.py), the leapfrog per disc. The cell's own values (h, h_build, the ramp,
FIRE's time step and mixing factor, the counters) are kept in every thread's registers, each
thread computing them alike from the same values, and written back by thread 0 when the call
returns, so that a resumed call (after the pair slots grew) continues as the CPU's does.

Reductions: the FIRE sums and the micropolar cell's constraint sums in lanes.py's order (as
the CPU kernel takes them); the largest velocity and displacement as maxima (exact); the sums
of the convergence test (kinetic energy, potential energy, mean contact force, stress) one
after the other by thread 0 in the CPU's order, every `check_every` steps only. The stress
servo of stress-controlled components (DemCell.solve with a stress target) is not here: a
batch solves to deformation targets.
"""
import math

from numba import cuda

from ..slots import (C_ALPHA, C_DT, C_DTMAX, C_G, C_KAP, C_KAP_END, C_KAP_START, C_METHOD, C_PHI, C_PHI_END,
                     C_PHI_START, C_SKIN, C_TIME, C_TOL, DIST, DTHETA, DX, DY, ENERGY, ENERGY_RATIO, FJX, FJY, FN, FX,
                     FY, H, HB, HREF, INERTIA, I_CHECK, I_CRIT, I_FCUR, I_KRAMP, I_MAXSTEPS, I_NPAIRS, I_NRAMP, MASS,
                     MIX_FORCES, MIX_NONE, MIX_STOP, MOMENT, NO_CHECK, OMEGA, O_BONDLOST, O_EKIN, O_EPOT, O_FMEAN,
                     O_MAXOVL, O_NCONT, O_REACTION, O_REBUILDS, O_S11, O_S12, O_S21, O_S22, O_STEPS, O_UNBAL, RADIUS,
                     ROTATIONS, SBX, SBY, SX, SY, S_ALPHA, S_ANG0, S_CV, S_CW, S_DAMP, S_DANG, S_DPHI, S_DT, S_DT0,
                     S_DTMAX, S_FEND, S_FIRE_A, S_FSTART, S_G, S_GK, S_H, S_HB, S_HINV, S_HREF, S_INV_S2, S_KAP,
                     S_KAP_END, S_KAP_START, S_KEEP, S_PHI, S_PHI_END, S_PHI_START, S_RCUT, S_REACTION, S_SKIN,
                     S_SPIN, S_TIME, S_TOL, S_U0, S_U1, THETA, TOUCHING, VX, VY, X_COMPUTED, X_LOST, X_MIX, X_NPOS,
                     X_REBUILDS, X_STEPS)
from ..lanes import LANES
from ..relaxation import CELL_TOO_SMALL, CONVERGED, MAX_STEPS, NEED_CAPACITY, NO_CONTACTS, NONFINITE
from .block import block_max, combine_row
from .contacts import gather_forces, gather_weights, hold_mean_rotation, pair_forces, weight_sums
from .kinematics import cell_strain_norm, inv2, nearest_image, polar
from .neighbours import build_pairs, index_pairs, merge_history

#: a check that found nothing to stop for
GO_ON = -1


@cuda.jit(device=True)
def force_sums(p0, q0, n_pairs, pf, qf, qi, qb, qs, area, out):
    """The sums of compute_forces over the contacts of the last force evaluation, in pair
    order (one thread): stress (001 eq. 8), potential energy, contacts, mean normal force,
    largest overlap / radius, into out."""
    s11 = 0.0
    s12 = 0.0
    s21 = 0.0
    s22 = 0.0
    epot = 0.0
    fsum = 0.0
    ncont = 0
    maxovl = 0.0
    for k in range(q0, q0 + n_pairs):
        if qb[TOUCHING, k] == 0:
            continue
        fjx = qs[FJX, k]
        fjy = qs[FJY, k]
        dx = qs[DX, k]
        dy = qs[DY, k]
        s11 -= fjx * dx
        s12 -= fjx * dy
        s21 -= fjy * dx
        s22 -= fjy * dy
        epot += qs[ENERGY, k]
        fsum += abs(qf[FN, k])
        ncont += 1
        ri = pf[RADIUS, p0 + qi[0, k]]
        rj = pf[RADIUS, p0 + qi[1, k]]
        overlap = ri + rj - qs[DIST, k]
        rmin_ij = min(ri, rj)
        if overlap > maxovl * rmin_ij:
            maxovl = overlap / rmin_ij
    out[O_S11] = s11 / area
    out[O_S12] = s12 / area
    out[O_S21] = s21 / area
    out[O_S22] = s22 / area
    out[O_EPOT] = epot
    out[O_NCONT] = ncont
    out[O_FMEAN] = fsum / ncont if ncont > 0 else 0.0
    out[O_MAXOVL] = maxovl


@cuda.jit(device=True)
def convergence_test(p0, n, q0, n_pairs, pf, qf, qi, qb, qs, area, crit, tol, out):
    """relaxation.advance's test after the ramp (one thread, the CPU's order): the status to
    stop with, or GO_ON."""
    force_sums(p0, q0, n_pairs, pf, qf, qi, qb, qs, area, out)
    ekin = 0.0
    fmax2 = 0.0
    for i in range(p0, p0 + n):
        f2 = pf[FX, i] * pf[FX, i] + pf[FY, i] * pf[FY, i]
        if f2 > 0.0:
            ekin += 0.5 * pf[MASS, i] * (pf[VX, i] * pf[VX, i] + pf[VY, i] * pf[VY, i])
        if pf[MOMENT, i] != 0.0:
            ekin += 0.5 * pf[INERTIA, i] * (pf[OMEGA, i] * pf[OMEGA, i])
        if f2 > fmax2:
            fmax2 = f2
    out[O_EKIN] = ekin
    unbal = math.sqrt(fmax2) / out[O_FMEAN] if out[O_FMEAN] > 0.0 else math.inf
    out[O_UNBAL] = unbal
    if not (math.isfinite(ekin) and math.isfinite(out[O_EPOT]) and math.isfinite(out[O_S11])):
        return NONFINITE
    if out[O_NCONT] == 0:
        return NO_CONTACTS
    if crit == ENERGY_RATIO:
        ok = ekin <= tol * out[O_EPOT]
    else:
        ok = unbal <= tol
    return CONVERGED if ok else GO_ON


@cuda.jit(device=True)
def start(c, cf, ctrl, fse, rmax, sc, si):
    """The cell's values of an advance call into the block's shared arrays (one thread)."""
    for m in range(4):
        sc[S_H + m] = cf[c, H + m]
        sc[S_HB + m] = cf[c, HB + m]
        sc[S_HREF + m] = cf[c, HREF + m]
    for m in range(8):
        sc[S_FSTART + m] = fse[m]
    ang0, sc[S_U0], sc[S_U0 + 1], sc[S_U0 + 2], sc[S_U0 + 3] = polar(fse[0], fse[1], fse[2], fse[3])
    ang1, sc[S_U1], sc[S_U1 + 1], sc[S_U1 + 2], sc[S_U1 + 3] = polar(fse[4], fse[5], fse[6], fse[7])
    dang = ang1 - ang0
    dang -= 2.0 * math.pi * math.floor((dang + math.pi) / (2.0 * math.pi))
    sc[S_ANG0] = ang0
    sc[S_DANG] = dang
    dt = ctrl[C_DT]
    sc[S_DT] = dt
    sc[S_DT0] = dt
    sc[S_TOL] = ctrl[C_TOL]
    sc[S_DTMAX] = dt * max(ctrl[C_DTMAX], 1.0)
    sc[S_ALPHA] = ctrl[C_ALPHA]
    sc[S_SKIN] = ctrl[C_SKIN]
    sc[S_RCUT] = 2.0 * rmax + ctrl[C_SKIN]
    sc[S_TIME] = ctrl[C_TIME]
    sc[S_PHI] = ctrl[C_PHI]
    sc[S_PHI_START] = ctrl[C_PHI_START]
    sc[S_PHI_END] = ctrl[C_PHI_END]
    for m in range(2):
        sc[S_KAP_START + m] = ctrl[C_KAP_START + m]
        sc[S_KAP_END + m] = ctrl[C_KAP_END + m]
    sc[S_KAP] = ctrl[C_KAP]
    sc[S_KAP + 1] = ctrl[C_KAP + 1]
    sc[S_G] = ctrl[C_G]
    sc[S_G + 1] = ctrl[C_G + 1]
    sc[S_FIRE_A] = 0.1
    sc[S_INV_S2] = 0.0
    sc[S_REACTION] = 0.0
    si[X_STEPS] = 0
    si[X_REBUILDS] = 0
    si[X_LOST] = 0
    si[X_COMPUTED] = 0
    si[X_NPOS] = 0


@cuda.jit(device=True)
def ramp(sc, kramp, n_ramp, micropolar):
    """The cell of the next step (one thread): the loading ramp (001 eq. 7), straight in F or,
    micropolar, polar; h^-1 and the macroscopic spin increment (the skew part of dF F^-1);
    a micropolar cell's rotation and curvature ramp and the image spin g = dkappa^T h_ref."""
    o00 = sc[S_H]
    o01 = sc[S_H + 1]
    o10 = sc[S_H + 2]
    o11 = sc[S_H + 3]
    tau = kramp / n_ramp if n_ramp > 0 else 1.0
    if micropolar:
        if tau >= 1.0:
            m00 = sc[S_FEND]
            m01 = sc[S_FEND + 1]
            m10 = sc[S_FEND + 2]
            m11 = sc[S_FEND + 3]
        else:
            ca = math.cos(sc[S_ANG0] + tau * sc[S_DANG])
            sa = math.sin(sc[S_ANG0] + tau * sc[S_DANG])
            u0b = sc[S_U0] + tau * (sc[S_U1] - sc[S_U0])
            u1b = sc[S_U0 + 2] + tau * (sc[S_U1 + 2] - sc[S_U0 + 2])
            m00 = ca * u0b - sa * u1b
            m10 = sa * u0b + ca * u1b
            u0b = sc[S_U0 + 1] + tau * (sc[S_U1 + 1] - sc[S_U0 + 1])
            u1b = sc[S_U0 + 3] + tau * (sc[S_U1 + 3] - sc[S_U0 + 3])
            m01 = ca * u0b - sa * u1b
            m11 = sa * u0b + ca * u1b
    else:
        m00 = sc[S_FSTART] + tau * (sc[S_FEND] - sc[S_FSTART])
        m01 = sc[S_FSTART + 1] + tau * (sc[S_FEND + 1] - sc[S_FSTART + 1])
        m10 = sc[S_FSTART + 2] + tau * (sc[S_FEND + 2] - sc[S_FSTART + 2])
        m11 = sc[S_FSTART + 3] + tau * (sc[S_FEND + 3] - sc[S_FSTART + 3])
    r00 = sc[S_HREF]
    r01 = sc[S_HREF + 1]
    r10 = sc[S_HREF + 2]
    r11 = sc[S_HREF + 3]
    h00 = m00 * r00 + m01 * r10
    h01 = m00 * r01 + m01 * r11
    h10 = m10 * r00 + m11 * r10
    h11 = m10 * r01 + m11 * r11
    sc[S_H] = h00
    sc[S_H + 1] = h01
    sc[S_H + 2] = h10
    sc[S_H + 3] = h11
    hi00, hi01, hi10, hi11 = inv2(o00, o01, o10, o11)
    g01 = (h00 - o00) * hi01 + (h01 - o01) * hi11
    g10 = (h10 - o10) * hi00 + (h11 - o11) * hi10
    sc[S_SPIN] = 0.5 * (g10 - g01)
    sc[S_HINV], sc[S_HINV + 1], sc[S_HINV + 2], sc[S_HINV + 3] = inv2(h00, h01, h10, h11)
    if micropolar:
        # micro-rotation and curvature follow the ramp (001 eq. 7 applied to phi, kappa)
        phi_new = sc[S_PHI_START] + tau * (sc[S_PHI_END] - sc[S_PHI_START])
        k0 = sc[S_KAP_START] + tau * (sc[S_KAP_END] - sc[S_KAP_START])
        k1 = sc[S_KAP_START + 1] + tau * (sc[S_KAP_END + 1] - sc[S_KAP_START + 1])
        dk0 = k0 - sc[S_KAP]
        dk1 = k1 - sc[S_KAP + 1]
        sc[S_KAP] = k0
        sc[S_KAP + 1] = k1
        sc[S_G] = dk0 * r00 + dk1 * r10
        sc[S_G + 1] = dk0 * r01 + dk1 * r11
        sc[S_DPHI] = phi_new - sc[S_PHI]
        sc[S_GK] = k0 * r00 + k1 * r10
        sc[S_GK + 1] = k0 * r01 + k1 * r11
        sc[S_PHI] = phi_new


@cuda.jit(device=True)
def fire_update(sc, si, part):
    """FIRE (Bitzek et al. 2006) after the sums of the step (combined: part[row, 0]; one
    thread): the mixing of
    velocities and forces (MIX_FORCES with 1 - a, cv, cw), or a stop (MIX_STOP), and the new
    time step and mixing factor."""
    power = part[0, 0]
    vn2 = part[1, 0]
    fn2 = part[2, 0]
    wn2 = part[3, 0]
    mn2 = part[4, 0]
    fire_a = sc[S_FIRE_A]
    if power > 0.0:
        sc[S_CV] = fire_a * math.sqrt(vn2 / fn2) if fn2 > 0.0 else 0.0
        sc[S_CW] = fire_a * math.sqrt(wn2 / mn2) if mn2 > 0.0 else 0.0
        sc[S_KEEP] = 1.0 - fire_a
        si[X_MIX] = MIX_FORCES
        si[X_NPOS] += 1
        if si[X_NPOS] > 5:
            sc[S_DT] = min(sc[S_DT] * 1.1, sc[S_DTMAX])
            sc[S_FIRE_A] = fire_a * 0.99
    else:
        sc[S_DT] = max(sc[S_DT] * 0.5, sc[S_DT0] / 64.0)
        sc[S_FIRE_A] = 0.1
        si[X_NPOS] = 0
        si[X_MIX] = MIX_STOP


@cuda.jit(device=True)
def advance(c, p0, n, q0, capacity, pf, qf, qi, qb, cf, law, qs, qn, qt, qtb, pis, bins, b0, weight,
            ctrl, ipar, out, fse, part, shr, shi, shf, sc, si):
    """Up to ipar[I_MAXSTEPS] steps of the ramp and the relaxation of cell c (relaxation.advance
    without the stress servo); fse: F_start, F_end (8 slots, row-major). The cell's own values
    live in the shared arrays sc, si, written by thread 0 between barriers; the few that steer
    the loop (forces current, the ramp step, the pair count, the displacement bound) every
    thread keeps alike in registers. Every thread returns the status."""
    t = cuda.threadIdx.x
    T = cuda.blockDim.x
    rot = law[c, ROTATIONS] > 0.5
    micropolar = law[c, ROTATIONS] > 1.5
    fire = ctrl[C_METHOD] > 0.5
    n_ramp = ipar[I_NRAMP]
    check_every = max(1, ipar[I_CHECK])
    crit = ipar[I_CRIT]
    max_steps = ipar[I_MAXSTEPS]
    rmax = 0.0
    for ii in range(t, n, T):
        rmax = max(rmax, pf[RADIUS, p0 + ii])
    rmax = block_max(rmax, shr)
    if t == 0:
        start(c, cf, ctrl, fse, rmax, sc, si)
    n_pairs = ipar[I_NPAIRS]
    fcur = ipar[I_FCUR]
    kramp = ipar[I_KRAMP]
    cuda.syncthreads()
    index_pairs(p0, n, q0, n_pairs, qi, qn, pis)
    if micropolar:
        gather_weights(p0, n, qf, qb, qn, pis, weight)
        cuda.syncthreads()
        weight_sums(p0, n, pf, weight, False, part, shf)
        if t == 0:
            sc[S_INV_S2] = shf[0]
    u2max = 0.0
    h00 = sc[S_H]
    h01 = sc[S_H + 1]
    h10 = sc[S_H + 2]
    h11 = sc[S_H + 3]
    for ii in range(t, n, T):          # neighbours.max_displacement
        i = p0 + ii
        _, _, ux, uy = nearest_image(pf[SX, i] - pf[SBX, i], pf[SY, i] - pf[SBY, i], h00, h01, h10, h11)
        u2max = max(u2max, ux * ux + uy * uy)
    disp = math.sqrt(block_max(u2max, shr))
    status = MAX_STEPS
    for step in range(max_steps + 1):
        if fcur == 0:
            if 2.1 * disp + cell_strain_norm(sc[S_H], sc[S_H + 1], sc[S_H + 2], sc[S_H + 3], sc[S_HB],
                                                   sc[S_HB + 1], sc[S_HB + 2], sc[S_HB + 3]) * sc[S_RCUT] > sc[S_SKIN]:
                m = build_pairs(p0, n, q0, capacity, pf, qn, pis, bins, b0, sc[S_H], sc[S_H + 1], sc[S_H + 2],
                                sc[S_H + 3], sc[S_SKIN], rmax, shi)
                if m == -1:
                    status = NEED_CAPACITY
                    break
                if m == -2:
                    status = CELL_TOO_SMALL
                    break
                lost = merge_history(n, q0, n_pairs, m, qf, qi, qb, qn, qt, qtb, shi)
                for ii in range(t, n, T):
                    pf[SBX, p0 + ii] = pf[SX, p0 + ii]
                    pf[SBY, p0 + ii] = pf[SY, p0 + ii]
                n_pairs = m
                disp = 0.0
                if t == 0:
                    si[X_LOST] += lost
                    for mm in range(4):
                        sc[S_HB + mm] = sc[S_H + mm]
                    si[X_REBUILDS] += 1
                cuda.syncthreads()
                index_pairs(p0, n, q0, n_pairs, qi, qn, pis)
            pair_forces(c, p0, q0, n_pairs, pf, qf, qi, qb, qs, law, sc[S_H], sc[S_H + 1], sc[S_H + 2],
                        sc[S_H + 3], sc[S_G], sc[S_G + 1], sc[S_DT])
            cuda.syncthreads()
            gather_forces(p0, n, pf, qb, qs, qn, pis)
            cuda.syncthreads()
            if micropolar:
                reaction, inv_s2 = hold_mean_rotation(p0, n, pf, qf, qb, qn, pis, weight, part, shf)
                if t == 0:
                    sc[S_REACTION] = reaction
                    sc[S_INV_S2] = inv_s2
            fcur = 1
            if t == 0:
                si[X_COMPUTED] = 1
        if crit != NO_CHECK and kramp >= n_ramp and step % check_every == 0 and step > 0:
            if t == 0:
                shi[2] = convergence_test(p0, n, q0, n_pairs, pf, qf, qi, qb, qs,
                                          abs(sc[S_H] * sc[S_H + 3] - sc[S_H + 1] * sc[S_H + 2]), crit, sc[S_TOL],
                                          out)
            cuda.syncthreads()
            verdict = shi[2]
            if verdict != GO_ON:
                status = verdict
                break
        if step == max_steps:
            break
        # --- the next cell (thread 0), FIRE's sums in lanes.py's order first
        if fire:
            for lane in range(t, LANES, T):
                power = 0.0
                vn2 = 0.0
                fn2 = 0.0
                wn2 = 0.0
                mn2 = 0.0
                for ii in range(lane, n, LANES):
                    i = p0 + ii
                    power += pf[FX, i] * pf[VX, i] + pf[FY, i] * pf[VY, i]
                    vn2 += pf[VX, i] * pf[VX, i] + pf[VY, i] * pf[VY, i]
                    fn2 += pf[FX, i] * pf[FX, i] + pf[FY, i] * pf[FY, i]
                    if rot:
                        power += pf[MOMENT, i] * pf[OMEGA, i]
                        wn2 += pf[OMEGA, i] * pf[OMEGA, i]
                        mn2 += pf[MOMENT, i] * pf[MOMENT, i]
                part[0, lane] = power
                part[1, lane] = vn2
                part[2, lane] = fn2
                part[3, lane] = wn2
                part[4, lane] = mn2
            cuda.syncthreads()
            for row in range(t, 5, T):        # the five trees side by side
                combine_row(part, row)
            cuda.syncthreads()
        if kramp < n_ramp:
            kramp += 1
        if t == 0:
            ramp(sc, kramp, n_ramp, micropolar)
            si[X_MIX] = MIX_NONE
            sc[S_DAMP] = sc[S_ALPHA]
            if fire:
                sc[S_DAMP] = 0.0
                fire_update(sc, si, part)
        cuda.syncthreads()
        # --- FIRE's mixing, then the leapfrog (000 section 3.2.1), disc by disc
        mix = si[X_MIX]
        dt = sc[S_DT]
        damp = sc[S_DAMP]
        hinv00 = sc[S_HINV]
        hinv01 = sc[S_HINV + 1]
        hinv10 = sc[S_HINV + 2]
        hinv11 = sc[S_HINV + 3]
        if mix == MIX_FORCES:
            keep = sc[S_KEEP]
            cv = sc[S_CV]
            cw = sc[S_CW]
            for ii in range(t, n, T):
                i = p0 + ii
                pf[VX, i] = keep * pf[VX, i] + cv * pf[FX, i]
                pf[VY, i] = keep * pf[VY, i] + cv * pf[FY, i]
                pf[OMEGA, i] = keep * pf[OMEGA, i] + cw * pf[MOMENT, i]
        elif mix == MIX_STOP:
            for ii in range(t, n, T):
                i = p0 + ii
                pf[VX, i] = 0.0
                pf[VY, i] = 0.0
                pf[OMEGA, i] = 0.0
        vmax2 = 0.0
        if micropolar:
            dphi = sc[S_DPHI]
            gd0 = sc[S_G]
            gd1 = sc[S_G + 1]
            gk0 = sc[S_GK]
            gk1 = sc[S_GK + 1]
            for ii in range(t, n, T):
                i = p0 + ii
                v2, dxs, dys = kick(pf, i, dt, damp)
                vmax2 = max(vmax2, v2)
                ds0 = hinv00 * dxs + hinv01 * dys
                ds1 = hinv10 * dxs + hinv11 * dys
                pf[DTHETA, i] = dphi + gd0 * (pf[SX, i] - 0.5) + gd1 * (pf[SY, i] - 0.5) + gk0 * ds0 + gk1 * ds1
                pf[SX, i] += ds0
                pf[SY, i] += ds1
                if pf[SX, i] >= 1.0 or pf[SX, i] < 0.0:
                    w = math.floor(pf[SX, i])
                    pf[SX, i] -= w
                    pf[THETA, i] -= gk0 * w
                if pf[SY, i] >= 1.0 or pf[SY, i] < 0.0:
                    w = math.floor(pf[SY, i])
                    pf[SY, i] -= w
                    pf[THETA, i] -= gk1 * w
                mo = pf[MOMENT, i]
                if damp > 0.0 and pf[OMEGA, i] != 0.0:
                    mo -= damp * abs(mo) * math.copysign(1.0, pf[OMEGA, i])
                pf[OMEGA, i] += dt * (1.0 / pf[INERTIA, i]) * mo
            # the rates projected back onto sum w omega = 0 (relaxation.leapfrog_micropolar)
            cuda.syncthreads()
            for lane in range(t, LANES, T):
                acc = 0.0
                for ii in range(lane, n, LANES):
                    acc += weight[p0 + ii] * pf[OMEGA, p0 + ii]
                part[0, lane] = acc
            cuda.syncthreads()
            if t == 0:
                shf[2] = combine_row(part, 0)
            cuda.syncthreads()
            corr = shf[2] * sc[S_INV_S2]
            for ii in range(t, n, T):
                i = p0 + ii
                pf[OMEGA, i] -= weight[i] * (1.0 / pf[INERTIA, i]) * corr
                pf[DTHETA, i] += pf[OMEGA, i] * dt
                pf[THETA, i] += pf[DTHETA, i]
        else:
            spin = sc[S_SPIN]
            for ii in range(t, n, T):
                i = p0 + ii
                v2, dxs, dys = kick(pf, i, dt, damp)
                vmax2 = max(vmax2, v2)
                pf[SX, i] += hinv00 * dxs + hinv01 * dys
                pf[SY, i] += hinv10 * dxs + hinv11 * dys
                if pf[SX, i] >= 1.0 or pf[SX, i] < 0.0:
                    pf[SX, i] -= math.floor(pf[SX, i])
                if pf[SY, i] >= 1.0 or pf[SY, i] < 0.0:
                    pf[SY, i] -= math.floor(pf[SY, i])
                if rot:
                    mo = pf[MOMENT, i]
                    if damp > 0.0 and pf[OMEGA, i] != 0.0:
                        mo -= damp * abs(mo) * math.copysign(1.0, pf[OMEGA, i])
                    pf[OMEGA, i] += dt * (1.0 / pf[INERTIA, i]) * mo
                    pf[DTHETA, i] = pf[OMEGA, i] * dt + spin
                else:
                    pf[OMEGA, i] = 0.0
                    pf[DTHETA, i] = 0.0
                pf[THETA, i] += pf[DTHETA, i]
        # --- the bound on the displacement since the last build: the largest velocity (exact in
        # any order), in two levels (a lane per 32 threads, then the lanes); every thread takes
        # it, so that the next step needs no further barrier
        shr[t] = vmax2
        cuda.syncthreads()
        for lane in range(t, min(T, LANES), T):
            best = shr[lane]
            for u in range(lane + LANES, T, LANES):
                best = max(best, shr[u])
            part[0, lane] = best
        cuda.syncthreads()
        for lane in range(min(T, LANES)):
            vmax2 = max(vmax2, part[0, lane])
        disp += math.sqrt(vmax2) * dt
        fcur = 0
        if t == 0:
            sc[S_TIME] += dt
            si[X_STEPS] += 1
    # --- back to the cell's arrays (one thread), as the CPU kernel leaves them
    cuda.syncthreads()
    if t == 0:
        for m in range(4):
            cf[c, H + m] = sc[S_H + m]
            cf[c, HB + m] = sc[S_HB + m]
        ctrl[C_TIME] = sc[S_TIME]
        ctrl[C_PHI] = sc[S_PHI]
        ctrl[C_KAP] = sc[S_KAP]
        ctrl[C_KAP + 1] = sc[S_KAP + 1]
        ctrl[C_G] = sc[S_G]
        ctrl[C_G + 1] = sc[S_G + 1]
        ipar[I_NPAIRS] = n_pairs
        ipar[I_FCUR] = fcur
        ipar[I_KRAMP] = kramp
        out[O_STEPS] = si[X_STEPS]
        out[O_REBUILDS] += si[X_REBUILDS]
        out[O_BONDLOST] += si[X_LOST]
        if si[X_COMPUTED] == 1:
            force_sums(p0, q0, n_pairs, pf, qf, qi, qb, qs,
                       abs(sc[S_H] * sc[S_H + 3] - sc[S_H + 1] * sc[S_H + 2]), out)
            if micropolar:
                out[O_REACTION] = sc[S_REACTION]
    cuda.syncthreads()
    return status


@cuda.jit(device=True)
def kick(pf, i, dt, damp):
    """relaxation._kick: the velocity of disc i from its force with local non-viscous damping
    (000 section 3.2.1); returns (|v|^2, the displacement v dt)."""
    f = pf[FX, i]
    if damp > 0.0 and pf[VX, i] != 0.0:
        f -= damp * abs(f) * math.copysign(1.0, pf[VX, i])
    pf[VX, i] += dt * (1.0 / pf[MASS, i]) * f
    f = pf[FY, i]
    if damp > 0.0 and pf[VY, i] != 0.0:
        f -= damp * abs(f) * math.copysign(1.0, pf[VY, i])
    pf[VY, i] += dt * (1.0 / pf[MASS, i]) * f
    vx = pf[VX, i]
    vy = pf[VY, i]
    return vx * vx + vy * vy, vx * dt, vy * dt
