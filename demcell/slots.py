"""Which slot of which kernel array holds what: the one table of demcell's array layouts.

The Numba and CUDA kernels take their parameters, controls and results in plain arrays; the
integer constants below name the slots. Every module that reads or writes one of these arrays
imports its slots from here. Units: SI, 2D quantities per unit thickness (forces [N/m] in a
stress, [N] at a contact of a unit-thick disc), F and kappa h_ref dimensionless.

law (float64, N_LAW): the contact law as the kernels read it (``ContactLaw.as_array``,
``DemCell.law_array``)
    KN        normal stiffness kn [N/m]
    KS        tangential stiffness ks [N/m]
    MU        Coulomb friction coefficient [-] (inf: no sliding)
    KR        rolling stiffness kr [N m/rad]
    ETA_R     rolling friction eta_r [-] (limit eta_r R_eff fn; inf: no limit)
    XI_N      normal damping ratio [-]
    XI_T      tangential damping ratio [-]
    COH_N     bond tensile strength [N] (inf: unbreakable)
    COH_T     bond shear strength [N]
    ROTATIONS rotation mode code: ROT_LOCKED, ROT_FREE, ROT_MICROPOLAR
    FROZEN    1: contacts frozen (bilateral, no new ones; DEMQO), else 0

ipar (int64, N_IPAR): integer controls of relaxation.advance, kept between resumed calls
    I_NPAIRS    listed pairs n_pairs
    I_FCUR      1: the forces are those of the current positions
    I_NRAMP     steps of the loading ramp
    I_KRAMP     ramp steps done
    I_MAXSTEPS  steps allowed in this call
    I_CHECK     steps between convergence tests
    I_CRIT      convergence criterion code: ENERGY_RATIO, UNBALANCED_FORCE, NO_CHECK

ctrl (float64, N_CTRL): float controls of relaxation.advance
    C_DT        time step [s]
    C_ALPHA     local non-viscous damping alpha = beta [-]
    C_TOL       tolerance of the criterion [-]
    C_STOL      relative tolerance on the stress targets [-]
    C_GAIN      servo gain [-] (dF per step = -gain (sigma - target) / kn)
    C_MAXRATE   largest |dF| per step of the servo [-]
    C_SKIN      neighbour-list skin [m]
    C_TIME      time of the cell [s]
    C_MASK      4 slots: 1 where the component (11, 12, 21, 22) of F is stress-controlled
    C_TARGET    4 slots: the Cauchy stress targets of those components [N/m]
    C_METHOD    relaxation method code: LOCAL_DAMPING, FIRE
    C_DTMAX     FIRE's largest time step / dt [-]
    C_PHI_START, C_PHI_END, C_PHI   micro-rotation phi at the ramp's start, end, now [rad]
    C_KAP_START, C_KAP_END, C_KAP   2 slots each: curvature kappa31, kappa32 [1/m]
    C_G         2 slots: the last step's curvature increment on the reference lattice,
                dkappa^T h_ref [rad]

out (float64, N_OUT): what relaxation.advance reports
    O_STEPS     steps taken
    O_EKIN      kinetic energy at the last test [J/m] (rattlers left out)
    O_EPOT      elastic energy of the contacts [J/m] (000 eq. 32)
    O_NCONT     contacts
    O_NSLIDE    sliding contacts
    O_UNBAL     largest unbalanced force / mean contact force [-]
    O_S11, O_S12, O_S21, O_S22   Cauchy stress [N/m], tension positive (001 eq. 8)
    O_REBUILDS  neighbour-list rebuilds
    O_MAXOVL    largest overlap / smaller radius [-]
    O_BONDLOST  bonds broken
    O_FMEAN     mean |fn| of the contacts [N]
    O_REACTION  micropolar cell: the held mean rotation's couple per newton of contact force [m]

opts (float64, N_OPTS): options of quasistatic.solve_cell (``quasistatic.solve_options``)
    Q_MAXINC    largest |dF| of a sub-step [-]
    Q_RATE      largest |dF| per step of a ramp [-]
    Q_TOL       tolerance of the criterion [-]
    Q_CHECK     steps between convergence tests
    Q_DAMP      local non-viscous damping [-]
    Q_SKIN      neighbour-list skin [m]
    Q_METHOD    relaxation method code
    Q_FIREDT    FIRE's largest time step / dt [-]
    Q_CRIT      criterion code
    Q_LIMIT     steps of a sub-step after its ramp
    Q_STOL      relative tolerance on stress targets [-]
    Q_GAIN      servo gain [-]
    Q_TOTAL     steps of the whole solve, ramps included
    Q_FIXED     DEM steps of a solve that does not relax (RelaxationOptions.fixed_steps; 0: relax)
    Q_CAP       DEM steps after which a sub-step's relaxation stops and counts as converged
                (RelaxationOptions.relax_cap; 0: none)

target (float64, N_TARGET): where quasistatic.solve_cell takes the cell
    T_F         4 slots: F (11, 12, 21, 22) [-]
    T_PHI       micro-rotation phi [rad]
    T_KAP       2 slots: curvature kappa31, kappa32 [1/m]

result (float64, N_RESULT): what quasistatic.solve_cell reports
    R_STEPS     DEM steps of the solve
    R_SUBSTEPS  sub-steps
    R_CONVERGED 1 when every sub-step converged
    R_NOCONTACT 1 when a sub-step ended without contacts
    R_MAXOVL    largest overlap / smaller radius [-]
    R_FAILED_SUB, R_FAILED_STATUS, R_FAILED_STEPS   the failed sub-step (-1: none), its
                relaxation status code, its steps
    R_EKIN, R_EPOT, R_UNBAL   of the failed sub-step [J/m, J/m, -]
    R_REBUILDS  neighbour-list rebuilds
    R_BUDGET    the solve's step budget when it ran out, else 0
    R_CAPPED    sub-steps stopped by relax_cap before they settled

work (float64, N_WORK) and iwork (int64, N_IWORK): progress of quasistatic.solve_cell, so
that a call stopped for larger pair arrays resumes
    W_GEO       10 slots: the F path (periodic_cell.path_setup)
    W_PHI0, W_KAP0   phi [rad] and kappa (2 slots) [1/m] at the start of the solve
    W_FSTART, W_FEND   4 slots each: F at the start and end of the current sub-step's ramp
    W_CTRL, W_OUT, W_TOTAL   the ctrl, out and summed out arrays of the current relaxation
    IW_STAGE    0 not started, 1 running, 2 done
    IW_NSUB, IW_K   sub-steps, sub-steps done
    IW_INRUN    1 while a relaxation runs
    IW_REMAIN   steps left to the current relaxation
    IW_IPAR     7 slots: its ipar
(per-cell scalars: cellf = (time [s], phi [rad], kappa31, kappa32 [1/m]) and celli =
(n_pairs, forces_current), in this order)

The device store (gpu/, one field per row so that the threads of a block read consecutive
addresses; cell c holds discs p_off[c]:p_off[c+1] and pair slots q_off[c]:q_off[c+1]):
    pf  float64 (NPF, P)   per disc: RADIUS [m], MASS [kg/m], INERTIA [kg m], SX, SY
                           (fractional), VX, VY [m/s], THETA [rad], OMEGA [rad/s], DTHETA
                           [rad], FX, FY [N], MOMENT [N m], SBX, SBY (s at the last build)
    qf  float64 (NQF, Q)   per pair slot: FN, FS [N], MR [N m], DPX, DPY (last branch vector [m])
    qi  int64   (2, Q)     per pair slot: PI, PJ (indices within the cell, i < j)
    qb  uint8   (2, Q)     per pair slot: BONDED, TOUCHING
    cf  float64 (n, NCF)   per cell: H, HB (h_build), HREF (row-major 2x2 each, 4 columns)
                           [m], TIME [s], PHI [rad], KAP (2) [1/m]
    ci  int64   (n, 2)     per cell: NPAIRS, FCUR (forces current)
scratch of the device relaxation:
    qs  float64 (NQS, Q)   per pair: DX, DY, DIST [m], FJX, FJY (force on j) [N], MI, MJ
                           (moments on i and j) [N m], ENERGY (spring energy) [J/m]
    qn  int64   (NQN, Q)   per pair: NEW_I, NEW_J (the list of a rebuild), JLIST (pair slots
                           of each disc as the second disc, indexed by JSTART)
    qt  float64 (NQT, Q)   per pair: history carried over by a rebuild: T_FS, T_MR, T_FN [N,
                           N m, N], T_DPX, T_DPY [m]
    pis int64   (NPI, P)   per disc: ISTART, ICOUNT (its pairs as first disc), JSTART,
                           JCOUNT, JFILL (as second disc), BIN_OF, BIN_ITEM (binning of a
                           rebuild), NCOUNT, NSTART (its new pairs)
    bins int64  (2, B)     per bin: BCOUNT, BSTART of its members
    sc  float64 (N_SC)     one cell's values in shared memory: S_H, S_HB, S_HREF, S_HINV,
                           S_FSTART, S_FEND, S_U0, S_U1 (4 slots each: matrices [m] or [-]),
                           S_ANG0, S_DANG (polar ramp angles [rad]), S_DT, S_DT0, S_DTMAX [s],
                           S_ALPHA [-], S_SKIN, S_RCUT [m], S_TOL [-], S_TIME [s], S_PHI [rad],
                           S_SPIN [rad], S_DAMP [-], S_DISP [m], S_FIRE_A, S_CV, S_CW (FIRE's
                           mixing), S_KEEP, S_INV_S2, S_REACTION [m], S_DPHI, S_PHI_START,
                           S_PHI_END [rad], S_KAP, S_G, S_GK, S_KAP_START, S_KAP_END (2 each)
    si  int64   (N_SI)     X_STEPS, X_REBUILDS, X_LOST (bonds), X_COMPUTED, X_NPOS (FIRE's
                           positive steps), X_MIX (MIX_NONE, MIX_FORCES, MIX_STOP)
"""

# --- law --------------------------------------------------------------------------------------
KN, KS, MU, KR, ETA_R, XI_N, XI_T, COH_N, COH_T, ROTATIONS, FROZEN = range(11)
N_LAW = 11
ROT_LOCKED, ROT_FREE, ROT_MICROPOLAR = 0, 1, 2     # values of law[ROTATIONS]

# --- relaxation.advance: ipar, ctrl, out --------------------------------------------------------
I_NPAIRS, I_FCUR, I_NRAMP, I_KRAMP, I_MAXSTEPS, I_CHECK, I_CRIT = range(7)
N_IPAR = 7
ENERGY_RATIO, UNBALANCED_FORCE, NO_CHECK = 0, 1, -1     # values of ipar[I_CRIT]
C_DT, C_ALPHA, C_TOL, C_STOL, C_GAIN, C_MAXRATE, C_SKIN, C_TIME = range(8)
C_MASK, C_TARGET = 8, 12          # 4 + 4 slots, component order 11, 12, 21, 22
C_METHOD, C_DTMAX = 16, 17
C_PHI_START, C_PHI_END, C_PHI = 18, 19, 20
C_KAP_START, C_KAP_END, C_KAP, C_G = 21, 23, 25, 27   # 2 slots each
N_CTRL = 29
LOCAL_DAMPING, FIRE = 0, 1                            # values of ctrl[C_METHOD]
(O_STEPS, O_EKIN, O_EPOT, O_NCONT, O_NSLIDE, O_UNBAL, O_S11, O_S12, O_S21, O_S22,
 O_REBUILDS, O_MAXOVL, O_BONDLOST, O_FMEAN, O_REACTION) = range(15)
N_OUT = 15

# --- quasistatic.solve_cell: opts, target, result, work, iwork ------------------------------------
(Q_MAXINC, Q_RATE, Q_TOL, Q_CHECK, Q_DAMP, Q_SKIN, Q_METHOD, Q_FIREDT, Q_CRIT, Q_LIMIT,
 Q_STOL, Q_GAIN, Q_TOTAL, Q_FIXED, Q_CAP) = range(15)
N_OPTS = 15
T_F, T_PHI, T_KAP = 0, 4, 5
N_TARGET = 7
(R_STEPS, R_SUBSTEPS, R_CONVERGED, R_NOCONTACT, R_MAXOVL, R_FAILED_SUB, R_FAILED_STATUS,
 R_FAILED_STEPS, R_EKIN, R_EPOT, R_UNBAL, R_REBUILDS, R_BUDGET, R_CAPPED) = range(14)
N_RESULT = 14
W_GEO = 0
W_PHI0, W_KAP0 = 10, 11
W_FSTART, W_FEND = 13, 17
W_CTRL = 21
W_OUT = W_CTRL + N_CTRL
W_TOTAL = W_OUT + N_OUT
N_WORK = W_TOTAL + N_OUT
IW_STAGE, IW_NSUB, IW_K, IW_INRUN, IW_REMAIN, IW_IPAR = 0, 1, 2, 3, 4, 5
N_IWORK = IW_IPAR + N_IPAR

# --- the device store ------------------------------------------------------------------------------
(RADIUS, MASS, INERTIA, SX, SY, VX, VY, THETA, OMEGA, DTHETA, FX, FY, MOMENT, SBX, SBY) = range(15)
NPF = 15
FN, FS, MR, DPX, DPY = range(5)
NQF = 5
PI, PJ = 0, 1
BONDED, TOUCHING = 0, 1
H, HB, HREF = 0, 4, 8
TIME, PHI, KAP = 12, 13, 14
NCF = 16
NPAIRS, FCUR = 0, 1
DX, DY, DIST, FJX, FJY, MI, MJ, ENERGY = range(8)
NQS = 8
NEW_I, NEW_J, JLIST = range(3)
NQN = 3
T_FS, T_MR, T_FN, T_DPX, T_DPY = range(5)
NQT = 5
ISTART, ICOUNT, JSTART, JCOUNT, JFILL, BIN_OF, BIN_ITEM, NCOUNT, NSTART = range(9)
NPI = 9
BCOUNT, BSTART = range(2)
S_H, S_HB, S_HREF, S_HINV, S_FSTART, S_FEND, S_U0, S_U1 = 0, 4, 8, 12, 16, 20, 24, 28
(S_ANG0, S_DANG, S_DT, S_DT0, S_DTMAX, S_ALPHA, S_SKIN, S_TOL, S_RCUT, S_TIME, S_PHI, S_SPIN, S_DAMP,
 S_DISP, S_FIRE_A, S_CV, S_CW, S_KEEP, S_INV_S2, S_REACTION, S_DPHI, S_PHI_START, S_PHI_END) = range(32, 55)
S_KAP, S_G, S_GK, S_KAP_START, S_KAP_END = 55, 57, 59, 61, 63
N_SC = 65
(X_STEPS, X_REBUILDS, X_LOST, X_COMPUTED, X_NPOS, X_MIX) = range(6)
N_SI = 6
MIX_NONE, MIX_FORCES, MIX_STOP = 0, 1, 2              # values of si[X_MIX]
