"""``quasistatic.solve_cell`` on a GPU: one block per cell, one kernel launch for a batch.

The kernel ``solve_rows`` runs, for each cell it is given, what DemCell.solve does without a
servo: the polar path to the target in sub-steps of at most max_increment, the lattice
reduction of a sheared cell, then the ramp and relaxation of each sub-step
(relaxation.advance). The bookkeeping between sub-steps is one thread's (thread 0 of the
block, the CPU's operations); the relaxation is the block's. Progress lives in the work
arrays of quasistatic.py (same slots), so that a cell whose pair slots filled up stops with
NEED_CAPACITY, and continues where it stopped once the host has enlarged them.
"""
import os

from numba import config, cuda, float64, int64

from ..slots import (C_ALPHA, C_DT, C_DTMAX, C_GAIN, C_KAP, C_KAP_END, C_KAP_START, C_MAXRATE, C_METHOD, C_PHI,
                     C_PHI_END, C_PHI_START, C_SKIN, C_STOL, C_TIME, C_TOL, FCUR, H, HB, HREF, IW_INRUN, IW_IPAR,
                     IW_K, IW_NSUB, IW_REMAIN, IW_STAGE, I_CHECK, I_CRIT, I_FCUR, I_KRAMP, I_MAXSTEPS, I_NPAIRS,
                     I_NRAMP, KAP, NPAIRS, N_CTRL, N_IPAR, N_OUT, N_SC, N_SI, O_BONDLOST, O_EKIN, O_EPOT, O_MAXOVL,
                     O_REBUILDS, O_STEPS, O_UNBAL, PHI, Q_CAP, Q_CHECK, Q_CRIT, Q_DAMP, Q_FIREDT, Q_GAIN, Q_LIMIT,
                     Q_MAXINC, Q_METHOD, Q_RATE, Q_SKIN, Q_STOL, Q_TOL, Q_TOTAL, ROTATIONS, R_BUDGET, R_CAPPED,
                     R_CONVERGED, R_EKIN, R_EPOT, R_FAILED_STATUS, R_FAILED_STEPS, R_FAILED_SUB, R_MAXOVL,
                     R_NOCONTACT, R_REBUILDS, R_STEPS, R_SUBSTEPS, R_UNBAL, TIME, T_F, T_KAP, T_PHI, W_CTRL, W_FEND,
                     W_FSTART, W_GEO, W_KAP0, W_OUT, W_PHI0, W_TOTAL)
from ..lanes import LANES
from ..relaxation import CELL_TOO_SMALL, CONVERGED, MAX_STEPS, NEED_CAPACITY, NO_CONTACTS, NONFINITE
from .block import MAX_THREADS
from .kinematics import deformation_gradient, path_point, path_setup, reduce_lattice, substep_count
from .relaxation import advance

#: code of a cell after a launch: waiting, solved, waiting for larger pair slots
PENDING, SOLVED, FULL = 0, 1, 2
#: registers per thread of the solve kernel: 168 (three 128-thread blocks per multiprocessor,
#: a few spilled values) ran 18 % faster than the compiler's 182 on an H200 (docs/results/gpu.md);
#: DEMCELL_GPU_MAX_REGISTERS=0 leaves the choice to the compiler
MAX_REGISTERS = int(os.environ.get("DEMCELL_GPU_MAX_REGISTERS", "168"))
KERNEL_OPTIONS = {} if config.ENABLE_CUDASIM or not MAX_REGISTERS else {"max_registers": MAX_REGISTERS}


@cuda.jit(device=True)
def rotation_increment(phi_a, kap_a0, kap_a1, phi_b, kap_b0, kap_b1, cf, c):
    """quasistatic._rotation_increment: max(|dphi|, max_k |dkappa . Y_k|)."""
    dk0 = kap_b0 - kap_a0
    dk1 = kap_b1 - kap_a1
    j0 = abs(dk0 * cf[c, HREF] + dk1 * cf[c, HREF + 2])
    j1 = abs(dk0 * cf[c, HREF + 1] + dk1 * cf[c, HREF + 3])
    return max(abs(phi_b - phi_a), max(j0, j1))


@cuda.jit(device=True)
def start_solve(c, micropolar, cf, target, max_inc, wk, iw, res):
    """solve_cell's first stage (one thread): the path from the current F to the target."""
    F0 = cuda.local.array(4, float64)
    Fe = cuda.local.array(4, float64)
    F0[0], F0[1], F0[2], F0[3] = deformation_gradient(cf, c, H)
    for m in range(4):
        Fe[m] = target[c, T_F + m]
    geo = wk[W_GEO:W_GEO + 10]
    n = path_setup(F0, Fe, max_inc, 1, geo)
    if micropolar:
        n_rot = substep_count(rotation_increment(cf[c, PHI], cf[c, KAP], cf[c, KAP + 1], target[c, T_PHI],
                                                 target[c, T_KAP], target[c, T_KAP + 1], cf, c) / max_inc)
        if n_rot > n:
            n = path_setup(F0, Fe, max_inc, n_rot, geo)
    wk[W_PHI0] = cf[c, PHI]
    wk[W_KAP0] = cf[c, KAP]
    wk[W_KAP0 + 1] = cf[c, KAP + 1]
    iw[IW_NSUB] = n
    iw[IW_K] = 0
    iw[IW_INRUN] = 0
    iw[IW_STAGE] = 1
    for m in range(res.shape[0]):
        res[m] = 0.0
    res[R_SUBSTEPS] = n
    res[R_CONVERGED] = 1.0
    res[R_FAILED_SUB] = -1.0


@cuda.jit(device=True)
def start_substep(c, micropolar, k, n, pf, p0, n_particles, cf, ci, target, dt, opts, wk, iw, res):
    """solve_cell's start of sub-step k of n (one thread): its target, the lattice reduction,
    relaxation.run's set-up of the ramp."""
    Fk = cuda.local.array(4, float64)
    if k == n - 1:
        for m in range(4):
            Fk[m] = target[c, T_F + m]
    else:
        path_point(wk[W_GEO:W_GEO + 10], (k + 1) / n, Fk)
    if micropolar:
        tau = (k + 1) / n
        if k == n - 1:
            phi_k = target[c, T_PHI]
            kap_k0 = target[c, T_KAP]
            kap_k1 = target[c, T_KAP + 1]
        else:
            phi_k = wk[W_PHI0] + tau * (target[c, T_PHI] - wk[W_PHI0])
            kap_k0 = wk[W_KAP0] + tau * (target[c, T_KAP] - wk[W_KAP0])
            kap_k1 = wk[W_KAP0 + 1] + tau * (target[c, T_KAP + 1] - wk[W_KAP0 + 1])
    else:
        reduce_lattice(cf, c, pf, p0, n_particles)
        phi_k = cf[c, PHI]
        kap_k0 = cf[c, KAP]
        kap_k1 = cf[c, KAP + 1]
    f00, f01, f10, f11 = deformation_gradient(cf, c, H)
    size = 0.0
    size = max(size, abs(Fk[0] - f00))
    size = max(size, abs(Fk[1] - f01))
    size = max(size, abs(Fk[2] - f10))
    size = max(size, abs(Fk[3] - f11))
    if micropolar:
        size = max(size, rotation_increment(cf[c, PHI], cf[c, KAP], cf[c, KAP + 1], phi_k, kap_k0, kap_k1,
                                            cf, c))
    n_ramp = substep_count(size / opts[c, Q_RATE])
    ctrl = wk[W_CTRL:W_CTRL + N_CTRL]
    for m in range(N_CTRL):
        ctrl[m] = 0.0
    ctrl[C_DT] = dt[c]
    ctrl[C_ALPHA] = opts[c, Q_DAMP]
    ctrl[C_TOL] = opts[c, Q_TOL]
    ctrl[C_STOL] = opts[c, Q_STOL]
    ctrl[C_GAIN] = opts[c, Q_GAIN]
    ctrl[C_MAXRATE] = max(opts[c, Q_RATE], 1e-12)
    ctrl[C_SKIN] = opts[c, Q_SKIN]
    ctrl[C_TIME] = cf[c, TIME]
    ctrl[C_METHOD] = opts[c, Q_METHOD]
    ctrl[C_DTMAX] = opts[c, Q_FIREDT]
    ctrl[C_PHI_START] = cf[c, PHI]
    ctrl[C_PHI] = cf[c, PHI]
    ctrl[C_PHI_END] = phi_k
    ctrl[C_KAP_START] = cf[c, KAP]
    ctrl[C_KAP_START + 1] = cf[c, KAP + 1]
    ctrl[C_KAP] = cf[c, KAP]
    ctrl[C_KAP + 1] = cf[c, KAP + 1]
    ctrl[C_KAP_END] = kap_k0
    ctrl[C_KAP_END + 1] = kap_k1
    ipar = iw[IW_IPAR:IW_IPAR + N_IPAR]
    for m in range(7):
        ipar[m] = 0
    ipar[I_NPAIRS] = ci[c, NPAIRS]
    ipar[I_FCUR] = ci[c, FCUR]
    ipar[I_NRAMP] = n_ramp
    ipar[I_CHECK] = int(opts[c, Q_CHECK])
    ipar[I_CRIT] = int(opts[c, Q_CRIT])
    wk[W_FSTART] = f00
    wk[W_FSTART + 1] = f01
    wk[W_FSTART + 2] = f10
    wk[W_FSTART + 3] = f11
    for m in range(4):
        wk[W_FEND + m] = Fk[m]
    for m in range(N_OUT):
        wk[W_OUT + m] = 0.0
        wk[W_TOTAL + m] = 0.0
    # this sub-step's steps: its ramp and its relaxation budget, no more than the solve has left
    remain = n_ramp + int(relaxation_budget(opts[c, Q_CAP], opts[c, Q_LIMIT]))
    left = opts[c, Q_TOTAL] - res[R_STEPS]
    if left < remain:
        remain = max(0, int(left))
    iw[IW_REMAIN] = remain
    if ci[c, NPAIRS] == 0 and ci[c, FCUR] == 0:
        # fresh state: make the rebuild test fire (h_build far from h)
        for m in range(4):
            cf[c, HB + m] = cf[c, H + m] * 1e3
    iw[IW_INRUN] = 1


@cuda.jit(device=True)
def relaxation_budget(cap, limit):
    """DEM steps a sub-step may relax after its ramp: the cap (RelaxationOptions.relax_cap)
    where one is set and reachable, else the sub-step budget (quasistatic.solve_cell)."""
    return cap if 0.0 < cap <= limit else limit


@cuda.jit(device=True)
def end_substep(c, k, status, budget, capped, cf, ci, wk, iw, res):
    """solve_cell's bookkeeping after relaxation.advance (one thread); capped: the sub-step's
    relaxation was bounded by relax_cap."""
    ctrl = wk[W_CTRL:W_CTRL + N_CTRL]
    out = wk[W_OUT:W_OUT + N_OUT]
    total = wk[W_TOTAL:W_TOTAL + N_OUT]
    ipar = iw[IW_IPAR:IW_IPAR + N_IPAR]
    total[O_STEPS] += out[O_STEPS]
    total[O_REBUILDS] += out[O_REBUILDS]
    total[O_BONDLOST] += out[O_BONDLOST]
    out[O_REBUILDS] = 0.0
    out[O_BONDLOST] = 0.0
    iw[IW_REMAIN] -= int(out[O_STEPS])
    ci[c, NPAIRS] = ipar[I_NPAIRS]
    ci[c, FCUR] = ipar[I_FCUR]
    if status == NEED_CAPACITY:
        return
    if capped and status == MAX_STEPS and ipar[I_KRAMP] >= ipar[I_NRAMP] and res[R_STEPS] + total[O_STEPS] < budget:
        # the cap, not the solve's budget, stopped the relaxation
        status = CONVERGED
        res[R_CAPPED] += 1.0
    iw[IW_INRUN] = 0
    iw[IW_K] = k + 1
    cf[c, TIME] = ctrl[C_TIME]
    cf[c, PHI] = ctrl[C_PHI]
    cf[c, KAP] = ctrl[C_KAP]
    cf[c, KAP + 1] = ctrl[C_KAP + 1]
    res[R_STEPS] += total[O_STEPS]
    res[R_REBUILDS] += total[O_REBUILDS]
    if status == NONFINITE or status == CELL_TOO_SMALL:
        res[R_CONVERGED] = 0.0
        res[R_FAILED_SUB] = k
        res[R_FAILED_STATUS] = status
        return
    if status == NO_CONTACTS:
        res[R_NOCONTACT] = 1.0
    elif status != CONVERGED:
        res[R_CONVERGED] = 0.0
        res[R_FAILED_SUB] = k
        res[R_FAILED_STATUS] = status
        res[R_FAILED_STEPS] = total[O_STEPS]
        if status == MAX_STEPS and res[R_STEPS] >= budget:
            res[R_BUDGET] = budget
        res[R_EKIN] = out[O_EKIN]
        res[R_EPOT] = out[O_EPOT]
        res[R_UNBAL] = out[O_UNBAL]
        return
    res[R_MAXOVL] = max(res[R_MAXOVL], out[O_MAXOVL])


@cuda.jit(cache=True, **KERNEL_OPTIONS)
def solve_rows(blocks, rows, p_off, q_off, b_off, pf, qf, qi, qb, cf, ci, law, dt, opts, target, work, iwork,
               result, code, qs, qn, qt, qtb, pis, bins, weight):
    """solve_cell for the cell rows[b] of each b in blocks, one block each; work, iwork,
    result and code are indexed by b. code[b]: SOLVED, or FULL (enlarge the cell's pair
    slots, launch again with the same work arrays)."""
    part = cuda.shared.array((5, LANES), float64)
    shr = cuda.shared.array(MAX_THREADS, float64)
    shi = cuda.shared.array(8, int64)
    shf = cuda.shared.array(8, float64)
    sc = cuda.shared.array(N_SC, float64)
    si = cuda.shared.array(N_SI, int64)
    t = cuda.threadIdx.x
    b = blocks[cuda.blockIdx.x]
    c = rows[b]
    p0 = p_off[c]
    n = p_off[c + 1] - p0
    q0 = q_off[c]
    capacity = q_off[c + 1] - q0
    b0 = b_off[c]
    micropolar = law[c, ROTATIONS] > 1.5
    wk = work[b]
    iw = iwork[b]
    res = result[b]
    stage = iw[IW_STAGE]
    cuda.syncthreads()
    if stage == 0:
        if t == 0:
            start_solve(c, micropolar, cf, target, opts[c, Q_MAXINC], wk, iw, res)
        cuda.syncthreads()
    status = CONVERGED
    while True:
        k = iw[IW_K]
        n_sub = iw[IW_NSUB]
        in_run = iw[IW_INRUN]
        cuda.syncthreads()
        if k >= n_sub:
            break
        if t == 0:
            if in_run == 0:
                start_substep(c, micropolar, k, n_sub, pf, p0, n, cf, ci, target, dt, opts, wk, iw, res)
            iw[IW_IPAR + I_MAXSTEPS] = iw[IW_REMAIN]
        cuda.syncthreads()
        status = advance(c, p0, n, q0, capacity, pf, qf, qi, qb, cf, law, qs, qn, qt, qtb, pis, bins, b0, weight,
                         wk[W_CTRL:W_CTRL + N_CTRL], iw[IW_IPAR:IW_IPAR + N_IPAR], wk[W_OUT:W_OUT + N_OUT],
                         wk[W_FSTART:W_FSTART + 8], part, shr, shi, shf, sc, si)
        if t == 0:
            end_substep(c, k, status, opts[c, Q_TOTAL], 0.0 < opts[c, Q_CAP] <= opts[c, Q_LIMIT], cf, ci, wk, iw, res)
        cuda.syncthreads()
        if status == MAX_STEPS and res[R_CONVERGED] > 0.5:
            status = CONVERGED        # stopped by relax_cap (end_substep): the next sub-step follows
        if status == NEED_CAPACITY:
            break
        if status != CONVERGED and status != NO_CONTACTS:
            break
    if t == 0:
        if status == NEED_CAPACITY:
            code[b] = FULL
        else:
            iw[IW_STAGE] = 2
            code[b] = SOLVED
