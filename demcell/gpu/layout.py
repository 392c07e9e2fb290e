"""The device store of a batch of cells: which row of which array holds what.

The cells live on the GPU in a few two-dimensional arrays, one field per row, so that the
threads of a block, which take consecutive discs or pairs, read consecutive addresses:

    pf  float64 (NPF, P)   per disc: radius [m], mass [kg/m], inertia [kg m], s (2, fractional),
                           v (2) [m/s], theta, omega, dtheta [rad, rad/s, rad], force (2) [N],
                           moment [N m], s_build (2)
    qf  float64 (NQF, Q)   per pair slot: fn, fs [N], mr [N m], d_prev (2) [m]
    qi  int64   (2, Q)     per pair slot: i, j (indices within the cell, i < j)
    qb  uint8   (2, Q)     per pair slot: bonded, touching
    cf  float64 (n, NCF)   per cell: h, h_build, h_ref (row-major 2x2 each) [m], time [s],
                           phi [rad], kappa (2) [1/m]
    ci  int64   (n, 2)     per cell: n_pairs, forces_current

P and Q are the discs and pair slots of all cells; cell c holds discs p_off[c]:p_off[c+1] and
pair slots q_off[c]:q_off[c+1] (its capacity), as ``batch.CellBatch`` lays them out. These
are the fields of ``state.CellState``; ``to_columns`` and ``from_columns`` convert one cell.
Nothing here imports numba.cuda: the host side packs and unpacks with numpy alone.
"""
import numpy as np

from ..state import CellState

# --- per disc (rows of pf) ---------------------------------------------------------------------
(RADIUS, MASS, INERTIA, SX, SY, VX, VY, THETA, OMEGA, DTHETA, FX, FY, MOMENT, SBX, SBY) = range(15)
NPF = 15
# --- per pair slot (rows of qf, qi, qb) --------------------------------------------------------
FN, FS, MR, DPX, DPY = range(5)
NQF = 5
PI, PJ = 0, 1
BONDED, TOUCHING = 0, 1
# --- per cell (columns of cf, ci) --------------------------------------------------------------
H, HB, HREF = 0, 4, 8             # 4 columns each: 00, 01, 10, 11
TIME, PHI, KAP = 12, 13, 14       # KAP: 2 columns
NCF = 16
NPAIRS, FCUR = 0, 1
# --- scratch of the relaxation kernel ------------------------------------------------------------
# per pair slot, float64 (NQS, Q): the branch vector and its length, the force on j, the
# moments on i and j and the spring energy of each contact in the last force evaluation
DX, DY, DIST, FJX, FJY, MI, MJ, ENERGY = range(8)
NQS = 8
# per pair slot, int64 (NQN, Q): the new list of a rebuild, and the pair slots of each disc as
# the second disc of a pair, in pair order (JLIST, indexed by JSTART)
NEW_I, NEW_J, JLIST = range(3)
NQN = 3
# per pair slot, the history carried over by a rebuild: float64 (NQT, Q), uint8 (2, Q)
T_FS, T_MR, T_FN, T_DPX, T_DPY = range(5)
NQT = 5
# per disc, int64 (NPI, P): its pair slots as the first disc (ISTART, ICOUNT: the pairs are
# sorted by i), as the second (JSTART, JCOUNT into JLIST; JFILL while filling), its bin and
# the bin members of the linked cells of a rebuild, the count and start of its new pairs
ISTART, ICOUNT, JSTART, JCOUNT, JFILL, BIN_OF, BIN_ITEM, NCOUNT, NSTART = range(9)
NPI = 9
# per bin, int64 (2, B): count and start of its members; a cell's bins, at most 4 n + 9
# (neighbours.build_pairs), lie at b_off[c]:b_off[c+1]
BCOUNT, BSTART = range(2)


def bins_per_cell(n_particles):
    """Bin slots reserved for a cell of n_particles discs (build_pairs caps nb1 nb2 at 4 n + 9)."""
    return 4 * int(n_particles) + 10


def to_columns(st):
    """One CellState as (pf block (NPF, n), qf (NQF, m), qi (2, m), qb (2, m), cf row, ci row),
    m its pair capacity."""
    n, m = st.n_particles, st.pair_i.shape[0]
    pf = np.empty((NPF, n))
    pf[RADIUS], pf[MASS], pf[INERTIA] = st.radius, st.mass, st.inertia
    pf[SX], pf[SY] = st.s[:, 0], st.s[:, 1]
    pf[VX], pf[VY] = st.v[:, 0], st.v[:, 1]
    pf[THETA], pf[OMEGA], pf[DTHETA] = st.theta, st.omega, st.dtheta
    pf[FX], pf[FY], pf[MOMENT] = st.force[:, 0], st.force[:, 1], st.moment
    pf[SBX], pf[SBY] = st.s_build[:, 0], st.s_build[:, 1]
    qf = np.empty((NQF, m))
    qf[FN], qf[FS], qf[MR] = st.fn, st.fs, st.mr
    qf[DPX], qf[DPY] = st.d_prev[:, 0], st.d_prev[:, 1]
    qi = np.stack([st.pair_i, st.pair_j]).astype(np.int64)
    qb = np.stack([st.bonded, st.touching]).astype(np.uint8)
    cf = np.empty(NCF)
    cf[H:H + 4], cf[HB:HB + 4], cf[HREF:HREF + 4] = st.h.reshape(4), st.h_build.reshape(4), st.h_ref.reshape(4)
    cf[TIME], cf[PHI], cf[KAP:KAP + 2] = st.time, st.phi, st.kappa
    ci = np.array([st.n_pairs, st.forces_current], dtype=np.int64)
    return pf, qf, qi, qb, cf, ci


def from_columns(pf, qf, qi, qb, cf, ci):
    """The CellState of to_columns' arrays (copies)."""
    return CellState(radius=pf[RADIUS].copy(), mass=pf[MASS].copy(), inertia=pf[INERTIA].copy(),
                     s=np.column_stack([pf[SX], pf[SY]]), v=np.column_stack([pf[VX], pf[VY]]),
                     theta=pf[THETA].copy(), omega=pf[OMEGA].copy(), dtheta=pf[DTHETA].copy(),
                     force=np.column_stack([pf[FX], pf[FY]]), moment=pf[MOMENT].copy(),
                     s_build=np.column_stack([pf[SBX], pf[SBY]]),
                     h=cf[H:H + 4].reshape(2, 2).copy(), h_build=cf[HB:HB + 4].reshape(2, 2).copy(),
                     h_ref=cf[HREF:HREF + 4].reshape(2, 2).copy(),
                     pair_i=qi[PI].copy(), pair_j=qi[PJ].copy(), fn=qf[FN].copy(), fs=qf[FS].copy(),
                     mr=qf[MR].copy(), bonded=qb[BONDED].copy(), touching=qb[TOUCHING].copy(),
                     d_prev=np.column_stack([qf[DPX], qf[DPY]]), n_pairs=int(ci[NPAIRS]),
                     forces_current=int(ci[FCUR]), time=float(cf[TIME]), phi=float(cf[PHI]),
                     kappa=cf[KAP:KAP + 2].copy())
