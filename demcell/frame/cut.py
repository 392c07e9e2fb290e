"""The periodic cell cut open along its sides: paper 000's frame of boundary particles.

``cut_frame(state, thickness)`` turns a periodic CellState into the discs of a bounded
assembly (000 section 2.2, Fig. 2a; dns-spec B2 and B3 option F):

* the cut lines are the sides of the cell moved so that one disc's centre is a corner of
  the cell (the periodic cell has no preferred origin): that disc's four copies are 000's
  four corner particles, at the corners of the cell, x_c = F X_c (eq. 35);
* a disc in the band of a cut line (its centre closer to the line than its radius: the discs
  the cut crosses, 000's one-particle frame; or, with `thickness` t, closer than
  max(radius, t d_mean / 2): a frame t mean diameters wide) becomes two frame particles, a
  "-" copy by the line and a "+" copy by the opposite side, one period away: an edge pair of
  000 eq. 33; a disc in the bands of both lines becomes four (a corner group);
* every other disc is an inner particle, once.

Each copy keeps the index of its disc (``uid``) and its lattice shift (``shift``: the copy's
fractional position is the disc's base position in [0, 1)^2 plus the shift), so periodicity
(000 eq. 12) is x_k - x_l = F h (shift_k - shift_l) for two copies k, l of one disc.

A contact the cut duplicates (two frame discs touching each other by both sides of the cell)
is one periodic contact seen twice (four times at a corner): on tiling, the copies merge and
the contact is shared by the cells. It therefore counts 1/multiplicity in the frame's
reactions and in the homogenised sums (``contact_weights``); without this the servo's fixed
point would not be periodic equilibrium. Two discs touch through one periodic image at most
(the minimum-image size of the cell), so a contact's identity is the pair of its discs.
"""
from dataclasses import dataclass

import numpy as np

from .. import checks
from ..errors import InputError
from ..state import CellState


@dataclass(frozen=True)
class Frame:
    """The cut: per copy k (n_copies of them, inner discs first by disc index, then the frame
    copies) its reference position X (n, 2) [m] in the frame cell's frame (corner disc at the
    origin), radius, mass, inertia, disc index uid, lattice shift (n, 2) int, held flag and
    frame group (the index of its disc among the frame discs, -1 inner).

    h_ref (2, 2) [m]: the cell (columns Y1, Y2) of the reference configuration, F = I;
    origin (2,): fractional position of the corner disc in the periodic state;
    corner_group: the group of the corner disc (its translation is not corrected: eq. 35);
    groups: list of copy-index arrays, one per frame disc (2 copies: an edge pair, 4: a
    corner group); n_discs: discs of the periodic cell."""
    X: np.ndarray
    radius: np.ndarray
    mass: np.ndarray
    inertia: np.ndarray
    uid: np.ndarray
    shift: np.ndarray
    held: np.ndarray
    group: np.ndarray
    groups: tuple
    corner_group: int
    h_ref: np.ndarray
    origin: np.ndarray
    n_discs: int
    thickness: float

    @property
    def n_copies(self):
        return self.X.shape[0]

    @property
    def inner(self):
        """Copy indices of the inner particles (free during the relaxation)."""
        return np.flatnonzero(~self.held)

    @property
    def base_copy(self):
        """For every disc the copy with shift (0, 0) (its position in [0, 1)^2 of the cell)."""
        base = np.full(self.n_discs, -1, np.int64)
        zero = np.flatnonzero((self.shift == 0).all(axis=1))
        base[self.uid[zero]] = zero
        return base

    def edge_pairs(self):
        """(minus copy, plus copy) index pairs of the two-copy groups: 000's edge pairs."""
        pairs = []
        for g in self.groups:
            if len(g) == 2:
                pairs.append(sorted(g, key=lambda k: self.shift[k].sum()))
        return np.array(pairs, np.int64).reshape(-1, 2)


def cell_widths(h):
    """Widths of the cell across its two sides [m]: det h / |Y2| (across the lines parallel
    to Y2) and det h / |Y1|."""
    det = abs(float(np.linalg.det(h)))
    return np.array([det / np.hypot(*h[:, 1]), det / np.hypot(*h[:, 0])])


def cut_frame(state, thickness=None):
    """The Frame of a periodic CellState (module docstring). thickness: None (the discs the
    cut crosses, one particle layer) or t > 0: the discs whose centre lies within
    max(radius, t d_mean / 2) of a cut line [t in mean diameters]. Refused in one line: a
    non-positive thickness, a band wider than half the cell, a cell without inner discs."""
    checks.instance("state", state, CellState)
    if thickness is not None:
        thickness = checks.number("thickness", thickness, checks.POSITIVE)
    radius = state.radius
    n = radius.size
    h = np.array(state.h, dtype=float)
    width = cell_widths(h)
    d_mean = 2.0 * float(np.mean(radius))
    band = radius.copy() if thickness is None else np.maximum(radius, 0.5 * thickness * d_mean)
    if not float(band.max()) < 0.5 * float(width.min()):
        raise InputError(f"frame thickness {thickness} mean diameters: the band ({2 * band.max():.3g}) is at least "
                         f"the cell's width ({width.min():.3g}); a thinner frame or a larger cell")
    # the corner disc: the one nearest the origin of the fractional coordinates
    s = np.mod(np.asarray(state.s, dtype=float), 1.0)
    wrapped = s - (s >= 0.5)
    corner = int(np.argmin(np.sum((wrapped @ h.T) ** 2, axis=1)))
    origin = s[corner].copy()
    u = np.mod(s - origin, 1.0)
    u[corner] = 0.0
    v = u - (u >= 0.5)
    in_band = np.abs(v) * width[None, :] < band[:, None]
    in_band[corner] = True
    inner = ~in_band.any(axis=1)
    if not inner.any():
        raise InputError(f"a cell of {n} discs has no inner disc once its frame (thickness "
                         f"{'one particle' if thickness is None else thickness}) is cut out: too few discs for a "
                         "frame cell")
    coords, uid, shift, group = [], [], [], []
    for p in np.flatnonzero(inner):
        coords.append(u[p])
        uid.append(p)
        shift.append((0, 0))
        group.append(-1)
    groups = []
    # the corner disc first: group 0
    frame_discs = [corner] + [int(p) for p in np.flatnonzero(~inner) if p != corner]
    for g, p in enumerate(frame_discs):
        xs = (v[p, 0], v[p, 0] + 1.0) if in_band[p, 0] else (u[p, 0],)
        ys = (v[p, 1], v[p, 1] + 1.0) if in_band[p, 1] else (u[p, 1],)
        members = []
        for cx in xs:
            for cy in ys:
                members.append(len(coords))
                coords.append((cx, cy))
                uid.append(p)
                shift.append((int(round(cx - u[p, 0])), int(round(cy - u[p, 1]))))
                group.append(g)
        groups.append(np.array(members, np.int64))
    coords = np.array(coords, dtype=float)
    uid = np.array(uid, np.int64)
    held = np.array(group) >= 0
    return Frame(X=coords @ h.T, radius=radius[uid].copy(), mass=state.mass[uid].copy(),
                 inertia=state.inertia[uid].copy(), uid=uid, shift=np.array(shift, np.int64), held=held,
                 group=np.array(group, np.int64), groups=tuple(groups), corner_group=0, h_ref=h.copy(),
                 origin=origin, n_discs=n, thickness=thickness)


def contact_weights(uid, pair_i, pair_j, touching):
    """Per listed pair of the frame's discs: 1 / (number of touching pairs between the same
    two discs of the periodic cell) for a touching pair, 0 otherwise (module docstring).
    Also returns the disc pair (a, b) with a < b of each pair and whether the pair's order
    is reversed with respect to it (uid[i] > uid[j])."""
    a = np.minimum(uid[pair_i], uid[pair_j])
    b = np.maximum(uid[pair_i], uid[pair_j])
    reversed_ = uid[pair_i] > uid[pair_j]
    weight = np.zeros(pair_i.shape[0])
    on = np.flatnonzero(touching != 0)
    if on.size:
        key = a[on] * (int(uid.max()) + 1) + b[on]
        _, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
        weight[on] = 1.0 / counts[inverse]
    return weight, a, b, reversed_
