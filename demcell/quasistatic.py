"""The quasi-static solve of one cell as one Numba function.

``solve_cell`` is what ``DemCell.solve`` does without a servo: split the way from the
current F (and, in a micropolar cell, phi and kappa) to the target into sub-steps of at most
``max_increment`` (polar path, periodic_cell.path_setup), and for each sub-step reduce the
lattice of a sheared cell, ramp the cell to the sub-step's target (001 eq. 7) and relax it
(relaxation.advance, 000 section 3.2.1). It works on plain arrays, so that one DemCell
(``interface.DemCell.solve``) and many cells of a struct of arrays (``batch.CellBatch``, a
prange over cells) run the same compiled arithmetic: the two give the same bits.

With ``RelaxationOptions.fixed_steps`` = N the solve runs the cells as YADE's FEMxDEM example
does: the ramps of its sub-steps take N DEM steps together (``ramp_steps``) and nothing
relaxes after them (no convergence test, no relaxation budget); the solve counts as converged
once its ramps are done.

With ``RelaxationOptions.relax_cap`` = N a sub-step relaxes as usual but stops N DEM steps
after its ramp if it has not settled by then, and counts as converged (``R_CAPPED`` counts
such sub-steps): cells that settle are the relaxed cells, bit for bit; a cell falling
towards another state past the peak goes on falling at the next solve.

When a cell's pair arrays are full, ``solve_cell`` returns ``NEED_CAPACITY`` with its
progress in ``work`` / ``iwork``; the caller enlarges the pair arrays and calls it again, and
it resumes where it stopped (as relaxation.run does for one ramp).

Per-cell scalars live in small arrays: ``cellf`` = (time [s], phi [rad], kappa31, kappa32
[1/m]), ``celli`` = (n_pairs, forces_current).
"""
import numpy as np
from numba import njit

from .relaxation import CELL_TOO_SMALL, CONVERGED, MAX_STEPS, NEED_CAPACITY, NO_CONTACTS, NONFINITE, advance
from .slots import (C_ALPHA, C_DT, C_DTMAX, C_GAIN, C_KAP, C_KAP_END, C_KAP_START, C_MAXRATE, C_METHOD, C_PHI,
                    C_PHI_END, C_PHI_START, C_SKIN, C_STOL, C_TIME, C_TOL, IW_INRUN, IW_IPAR, IW_K, IW_NSUB,
                    IW_REMAIN, IW_STAGE, I_CHECK, I_CRIT, I_FCUR, I_KRAMP, I_MAXSTEPS, I_NPAIRS, I_NRAMP, NO_CHECK,
                    N_CTRL, N_IPAR, N_OPTS, N_OUT, O_BONDLOST, O_EKIN, O_EPOT, O_MAXOVL, O_REBUILDS, O_STEPS,
                    O_UNBAL, Q_CAP, Q_CHECK, Q_CRIT, Q_DAMP, Q_FIREDT, Q_FIXED, Q_GAIN, Q_LIMIT, Q_MAXINC, Q_METHOD,
                    Q_RATE, Q_SKIN, Q_STOL, Q_TOL, Q_TOTAL, ROTATIONS, R_BUDGET, R_CAPPED, R_CONVERGED, R_EKIN,
                    R_EPOT, R_FAILED_STATUS, R_FAILED_STEPS, R_FAILED_SUB, R_MAXOVL, R_NOCONTACT, R_REBUILDS,
                    R_STEPS, R_SUBSTEPS, R_UNBAL, T_F, T_KAP, T_PHI, W_CTRL, W_FEND, W_FSTART, W_GEO, W_KAP0, W_OUT,
                    W_PHI0, W_TOTAL)
from .periodic_cell import deformation_gradient, path_point, path_setup, reduce_lattice, substep_count

# the solve's own codes next to relaxation's (CONVERGED .. CELL_TOO_SMALL)
DONE = 100


@njit(cache=True)
def _rotation_increment(phi_a, kap_a0, kap_a1, phi_b, kap_b0, kap_b1, h_ref):
    """max(|dphi|, max_k |dkappa . Y_k|) (DemCell.rotation_increment)."""
    dk0 = kap_b0 - kap_a0
    dk1 = kap_b1 - kap_a1
    j0 = abs(dk0 * h_ref[0, 0] + dk1 * h_ref[1, 0])
    j1 = abs(dk0 * h_ref[0, 1] + dk1 * h_ref[1, 1])
    return max(abs(phi_b - phi_a), max(j0, j1))


@njit(cache=True)
def ramp_steps(opts, size, k, n):
    """DEM steps of the loading ramp of sub-step k of n whose largest |dF| is ``size``:
    size / strain_rate (001 eq. 7), or with fixed_steps N the k-th of n near-equal shares of N
    (at least one step: N steps in all when N >= n)."""
    fixed = int(opts[Q_FIXED])
    if fixed > 0:
        return max(1, (fixed * (k + 1)) // n - (fixed * k) // n)
    return substep_count(size / opts[Q_RATE])


@njit(cache=True, nogil=True)
def solve_cell(radius, mass, inertia, s, v, theta, omega, dtheta, force, moment, s_build, h,
               h_build, h_ref, pair_i, pair_j, fn, fs, mr, bonded, touching, d_prev,
               cellf, celli, law, dt, opts, target, work, iwork, result):
    """Bring one cell from its current state to ``target`` (see module doc). Start with
    iwork[IW_STAGE] = 0; returns DONE (result filled) or NEED_CAPACITY (enlarge the pair
    arrays, call again with the same work arrays)."""
    micropolar = law[ROTATIONS] > 1.5
    Fk = np.empty((2, 2))
    Fe = np.empty((2, 2))
    geo = work[W_GEO:W_GEO + 10]
    ctrl = work[W_CTRL:W_CTRL + N_CTRL]
    out = work[W_OUT:W_OUT + N_OUT]
    total = work[W_TOTAL:W_TOTAL + N_OUT]
    ipar = iwork[IW_IPAR:IW_IPAR + N_IPAR]
    max_inc = opts[Q_MAXINC]
    fixed = opts[Q_FIXED] > 0.0
    # a cap above the sub-step budget would never be reached: the budget fails the sub-step first
    cap = int(opts[Q_CAP]) if 0 < opts[Q_CAP] <= opts[Q_LIMIT] else 0
    if iwork[IW_STAGE] == 0:
        # the path (DemCell.solve; micropolar: refined until phi and kappa also change by at
        # most max_increment per sub-step, DemCell._micropolar_path)
        for a in range(2):
            for b in range(2):
                Fe[a, b] = target[T_F + 2 * a + b]
        F0 = deformation_gradient(h, h_ref)
        n = path_setup(F0, Fe, max_inc, 1, geo)
        if micropolar:
            n_rot = substep_count(_rotation_increment(cellf[1], cellf[2], cellf[3], target[T_PHI],
                                                      target[T_KAP], target[T_KAP + 1], h_ref) / max_inc)
            if n_rot > n:
                n = path_setup(F0, Fe, max_inc, n_rot, geo)
        work[W_PHI0] = cellf[1]
        work[W_KAP0] = cellf[2]
        work[W_KAP0 + 1] = cellf[3]
        iwork[IW_NSUB] = n
        iwork[IW_K] = 0
        iwork[IW_INRUN] = 0
        iwork[IW_STAGE] = 1
        result[:] = 0.0
        result[R_SUBSTEPS] = n
        result[R_CONVERGED] = 1.0
        result[R_FAILED_SUB] = -1.0
    n = iwork[IW_NSUB]
    while iwork[IW_K] < n:
        k = iwork[IW_K]
        if iwork[IW_INRUN] == 0:
            # --- start sub-step k: its target, then relaxation.run's set-up
            if k == n - 1:
                for a in range(2):
                    for b in range(2):
                        Fk[a, b] = target[T_F + 2 * a + b]
            else:
                path_point(geo, (k + 1) / n, Fk)
            if micropolar:
                tau = (k + 1) / n
                if k == n - 1:
                    phi_k = target[T_PHI]
                    kap_k0 = target[T_KAP]
                    kap_k1 = target[T_KAP + 1]
                else:
                    phi_k = work[W_PHI0] + tau * (target[T_PHI] - work[W_PHI0])
                    kap_k0 = work[W_KAP0] + tau * (target[T_KAP] - work[W_KAP0])
                    kap_k1 = work[W_KAP0 + 1] + tau * (target[T_KAP + 1] - work[W_KAP0 + 1])
            else:
                # the curvature's images follow the base cell's lattice: only the other modes
                # reduce a sheared cell to a compact base cell
                reduce_lattice(h, h_ref, h_build, s, s_build)
                phi_k = cellf[1]
                kap_k0 = cellf[2]
                kap_k1 = cellf[3]
            Fcur = deformation_gradient(h, h_ref)
            size = 0.0
            for a in range(2):
                for b in range(2):
                    size = max(size, abs(Fk[a, b] - Fcur[a, b]))
            if micropolar:
                size = max(size, _rotation_increment(cellf[1], cellf[2], cellf[3], phi_k, kap_k0, kap_k1, h_ref))
            n_ramp = ramp_steps(opts, size, k, n)
            ctrl[:] = 0.0
            ctrl[C_DT] = dt
            ctrl[C_ALPHA] = opts[Q_DAMP]
            ctrl[C_TOL] = opts[Q_TOL]
            ctrl[C_STOL] = opts[Q_STOL]
            ctrl[C_GAIN] = opts[Q_GAIN]
            ctrl[C_MAXRATE] = max(opts[Q_RATE], 1e-12)
            ctrl[C_SKIN] = opts[Q_SKIN]
            ctrl[C_TIME] = cellf[0]
            ctrl[C_METHOD] = opts[Q_METHOD]
            ctrl[C_DTMAX] = opts[Q_FIREDT]
            ctrl[C_PHI_START] = cellf[1]
            ctrl[C_PHI] = cellf[1]
            ctrl[C_PHI_END] = phi_k
            ctrl[C_KAP_START] = cellf[2]
            ctrl[C_KAP_START + 1] = cellf[3]
            ctrl[C_KAP] = cellf[2]
            ctrl[C_KAP + 1] = cellf[3]
            ctrl[C_KAP_END] = kap_k0
            ctrl[C_KAP_END + 1] = kap_k1
            ipar[:] = 0
            ipar[I_NPAIRS] = celli[0]
            ipar[I_FCUR] = celli[1]
            ipar[I_NRAMP] = n_ramp
            ipar[I_CHECK] = int(opts[Q_CHECK])
            ipar[I_CRIT] = NO_CHECK if fixed else int(opts[Q_CRIT])
            for a in range(2):
                for b in range(2):
                    work[W_FSTART + 2 * a + b] = Fcur[a, b]
                    work[W_FEND + 2 * a + b] = Fk[a, b]
            out[:] = 0.0
            total[:] = 0.0
            # this sub-step's steps: its ramp and its relaxation budget, no more than the solve has left
            remain = n_ramp + (0 if fixed else (cap if cap > 0 else int(opts[Q_LIMIT])))
            left = opts[Q_TOTAL] - result[R_STEPS]
            if left < remain:
                remain = max(0, int(left))
            iwork[IW_REMAIN] = remain
            if celli[0] == 0 and celli[1] == 0:
                # fresh state: make the rebuild test fire (h_build far from h)
                for a in range(2):
                    for b in range(2):
                        h_build[a, b] = h[a, b] * 1e3
            iwork[IW_INRUN] = 1
        # --- relaxation.run's loop
        for a in range(2):
            for b in range(2):
                Fk[a, b] = work[W_FSTART + 2 * a + b]
                Fe[a, b] = work[W_FEND + 2 * a + b]
        ipar[I_MAXSTEPS] = iwork[IW_REMAIN]
        status = advance(radius, mass, inertia, s, v, theta, omega, dtheta, force, moment, s_build,
                         h, h_build, h_ref, pair_i, pair_j, fn, fs, mr, bonded, touching, d_prev,
                         law, ipar, ctrl, Fk, Fe, out)
        total[O_STEPS] += out[O_STEPS]
        total[O_REBUILDS] += out[O_REBUILDS]
        total[O_BONDLOST] += out[O_BONDLOST]
        out[O_REBUILDS] = 0.0
        out[O_BONDLOST] = 0.0
        iwork[IW_REMAIN] -= int(out[O_STEPS])
        celli[0] = ipar[I_NPAIRS]
        celli[1] = ipar[I_FCUR]
        if status == NEED_CAPACITY:
            return NEED_CAPACITY
        if fixed and status == MAX_STEPS and ipar[I_KRAMP] >= ipar[I_NRAMP]:
            status = CONVERGED      # the ramp is done: a fixed-step solve does not relax
        elif (cap > 0 and status == MAX_STEPS and ipar[I_KRAMP] >= ipar[I_NRAMP]
              and result[R_STEPS] + total[O_STEPS] < opts[Q_TOTAL]):
            # the cap, not the solve's budget, stopped the relaxation
            status = CONVERGED
            result[R_CAPPED] += 1.0
        iwork[IW_INRUN] = 0
        iwork[IW_K] = k + 1
        cellf[0] = ctrl[C_TIME]
        cellf[1] = ctrl[C_PHI]
        cellf[2] = ctrl[C_KAP]
        cellf[3] = ctrl[C_KAP + 1]
        result[R_STEPS] += total[O_STEPS]
        result[R_REBUILDS] += total[O_REBUILDS]
        if status == NONFINITE or status == CELL_TOO_SMALL:
            result[R_CONVERGED] = 0.0
            result[R_FAILED_SUB] = k
            result[R_FAILED_STATUS] = status
            break
        if status == NO_CONTACTS:
            result[R_NOCONTACT] = 1.0
        elif status != CONVERGED:
            result[R_CONVERGED] = 0.0
            result[R_FAILED_SUB] = k
            result[R_FAILED_STATUS] = status
            result[R_FAILED_STEPS] = total[O_STEPS]
            if status == MAX_STEPS and result[R_STEPS] >= opts[Q_TOTAL]:
                result[R_BUDGET] = opts[Q_TOTAL]
            result[R_EKIN] = out[O_EKIN]
            result[R_EPOT] = out[O_EPOT]
            result[R_UNBAL] = out[O_UNBAL]
            break
        result[R_MAXOVL] = max(result[R_MAXOVL], out[O_MAXOVL])
    iwork[IW_STAGE] = 2
    return DONE


def solve_options(options, skin, max_steps, total_steps=None):
    """The option row of solve_cell from a RelaxationOptions, the skin [m], the step
    budget per sub-step (after the ramp) and the step budget of the whole solve (ramps
    included; None: the options' ``solve_budget``)."""
    q = np.zeros(N_OPTS)
    q[Q_MAXINC], q[Q_RATE], q[Q_TOL], q[Q_CHECK] = (options.max_increment, options.strain_rate, options.tol,
                                                    options.check_every)
    q[Q_DAMP], q[Q_SKIN] = options.damping, skin
    q[Q_METHOD] = options.method_code
    q[Q_FIREDT] = options.fire_dt_max
    q[Q_CRIT] = options.criterion_code
    q[Q_LIMIT] = max_steps
    q[Q_STOL], q[Q_GAIN] = options.stress_tol, options.servo_gain
    q[Q_TOTAL] = options.solve_budget if total_steps is None else total_steps
    q[Q_FIXED] = options.fixed_steps if options.fixed else 0
    q[Q_CAP] = options.relax_cap if options.capped else 0
    return q


def outcome(result, dt):
    """(converged, no_contacts, message, error) of a solve_cell result row, in DemCell.solve's
    words; error: the SolveError text when the cell broke down (non-finite values, cell too
    small), else None. no_contacts here means a sub-step ended without contacts (the caller
    checks whether the cell still has none)."""
    from .relaxation import STATUS_TEXT
    status = int(result[R_FAILED_STATUS])
    if result[R_FAILED_SUB] >= 0 and status == NONFINITE:
        return False, False, "", STATUS_TEXT[NONFINITE] + f" (dt = {dt:.3e} s)"
    if result[R_FAILED_SUB] >= 0 and status == CELL_TOO_SMALL:
        return False, False, "", STATUS_TEXT[CELL_TOO_SMALL]
    if result[R_CONVERGED] > 0.5:
        return True, result[R_NOCONTACT] > 0.5, "converged", None
    if result[R_BUDGET] > 0.0:
        message = (f"sub-step {int(result[R_FAILED_SUB]) + 1} of {int(result[R_SUBSTEPS])}: "
                   + budget_words(int(result[R_BUDGET]), int(result[R_FAILED_STEPS])))
        return False, result[R_NOCONTACT] > 0.5, message, None
    ratio = result[R_EKIN] / max(result[R_EPOT], 1e-300)
    hint = (": the kinetic energy exceeds the elastic energy, the cell is not settling "
            "(loading too fast for the damping, or an unstable state)") if ratio > 1.0 else ""
    message = (f"sub-step {int(result[R_FAILED_SUB]) + 1} of {int(result[R_SUBSTEPS])}: {STATUS_TEXT[status]} after "
               f"{int(result[R_FAILED_STEPS])} steps (E_kin/E_pot = {ratio:.2e}, unbalanced ratio "
               f"{result[R_UNBAL]:.2e}){hint}")
    return False, result[R_NOCONTACT] > 0.5, message, None


def budget_words(budget, steps):
    """Why a solve stopped when its step budget ran out (DemCell.solve, CellBatch.outcome)."""
    return (f"step budget of the solve spent (max_steps = {budget} DEM steps over all sub-steps, "
            f"ramps included; {steps} in this sub-step): not converged")


def final_words(converged, no_contacts, contacts, messages, max_overlap):
    """(no_contacts, message) of a finished solve, as DemCell.solve and CellBatch.outcome word
    it: no contacts only if the cell has none left (`contacts`), the failures' messages
    joined (a solve that failed says why first, then that no contact is left), and a warning
    when overlaps passed 10 % of a radius."""
    empty = "no contact left in the cell: zero stress (flag no_contacts)"
    if no_contacts and contacts == 0 and converged:
        message = empty
    elif converged:
        message, no_contacts = "converged", False
    else:
        message = "; ".join(messages)
        if no_contacts and contacts == 0:
            message += "; " + empty
    if max_overlap > 0.1:
        message += (f"; warning: overlaps reach {max_overlap:.2f} of a radius (contacts too soft for this "
                    "stress level, the linear contact law is stretched)")
    return no_contacts, message
