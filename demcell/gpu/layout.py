"""The device store of a batch of cells: packing one CellState into its columns and back.

The cells live on the GPU in a few two-dimensional arrays, one field per row, so that the
threads of a block, which take consecutive discs or pairs, read consecutive addresses; which
row or column holds what, and in which unit, is the table of ``demcell.slots`` ("The device
store"). Cell c holds discs p_off[c]:p_off[c+1] and pair slots q_off[c]:q_off[c+1] (its
capacity), as ``batch.CellBatch`` lays them out. ``to_columns`` and ``from_columns`` convert
one cell. Nothing here imports numba.cuda: the host side packs and unpacks with numpy alone.
"""
import numpy as np

from ..state import CellState
from ..slots import (BONDED, DPX, DPY, DTHETA, FCUR, FN, FS, FX, FY, H, HB, HREF, INERTIA, KAP, MASS, MOMENT, MR, NCF,
                     NPAIRS, NPF, NQF, OMEGA, PHI, PI, PJ, RADIUS, SBX, SBY, SX, SY, THETA, TIME, TOUCHING, VX, VY)



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
