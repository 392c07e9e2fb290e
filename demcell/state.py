"""The complete state of one periodic cell, held in plain NumPy arrays.

Everything the kernels need lives here, so commit / rollback / copy are array copies
(no hidden state anywhere else).

Geometry: the cell is spanned by the periodicity vectors Y1, Y2, the columns of
``h`` (2x2, metres). ``h = F @ h_ref`` where ``F`` is the macroscopic deformation
gradient and ``h_ref`` the cell of the reference configuration (001 eq. 7,
Y_i = F Y_i^R). Particle centres are stored as fractional coordinates ``s`` in
[0, 1)^2, so the current centre is x = h s (the affine part, 000 eq. 6) and the
fluctuation w of 000 eq. 6 is carried by how ``s`` changes.
"""
from dataclasses import dataclass, field, fields

import numpy as np

from . import checks
from .errors import InputError
from .periodic_cell import deformation_gradient

PAIR_FIELDS = ("pair_i", "pair_j", "fn", "fs", "mr", "bonded", "touching", "d_prev")
#: arrays of a state by kind of value (CellState.check); kappa is a float array too
FLOAT_FIELDS = ("radius", "mass", "inertia", "s", "v", "theta", "omega", "dtheta", "force", "moment", "s_build",
                "h", "h_build", "h_ref", "fn", "fs", "mr", "d_prev")
INT_FIELDS = ("pair_i", "pair_j")
FLAG_FIELDS = ("bonded", "touching")
DTYPES = dict({name: np.float64 for name in FLOAT_FIELDS + ("kappa",)}, pair_i=np.int64, pair_j=np.int64,
              bonded=np.uint8, touching=np.uint8)


def _finite(name, a, positive=False):
    """InputError naming `name` and the first bad entry unless every value of `a` is finite
    (and > 0 with `positive`)."""
    ok = np.isfinite(a)
    if positive:
        ok &= a > 0
    if not ok.all():
        where = "".join(f"[{int(i)}]" for i in np.argwhere(~ok)[0])
        raise InputError(f"{name}{where} must be finite{' and > 0' if positive else ''}, got {float(a[~ok][0])!r}")


@dataclass
class CellState:
    """Arrays of one cell. Shapes: N particles, M pair slots (capacity).

    radius [m], mass [kg per m thickness], inertia [kg m^2 per m] : (N,)
    s : fractional positions (N, 2); v : fluctuating velocity [m/s] (N, 2)
    theta : rotation [rad] (N,); omega : fluctuating angular velocity [rad/s] (N,)
    dtheta : rotation increment of the last step [rad] (N,)
    force [N], moment [N m] : resultants of the last force evaluation
    s_build, h_build : positions and cell when the neighbour list was built
    h, h_ref : current and reference cell matrices (columns = periodicity vectors) [m]
    pair_i, pair_j : neighbour pairs (i < j), valid in [0, n_pairs)
    fn [N] (repulsive > 0), fs [N] (on j along t), mr [N m] (rolling moment on j),
    bonded, touching : uint8 flags; d_prev : branch vector of the last step [m] (M, 2)
    n_pairs : number of valid pairs; forces_current : 1 if force/fn/fs match the positions
    time : simulated time [s]
    phi : imposed micro-rotation [rad] and kappa : imposed curvature (2,) [1/m] of a micropolar
        cell (rotation_mode='micropolar', docs/reference/micropolar_cell.md); 0 for the other modes
    """

    radius: np.ndarray
    mass: np.ndarray
    inertia: np.ndarray
    s: np.ndarray
    v: np.ndarray
    theta: np.ndarray
    omega: np.ndarray
    dtheta: np.ndarray
    force: np.ndarray
    moment: np.ndarray
    s_build: np.ndarray
    h: np.ndarray
    h_build: np.ndarray
    h_ref: np.ndarray
    pair_i: np.ndarray
    pair_j: np.ndarray
    fn: np.ndarray
    fs: np.ndarray
    mr: np.ndarray
    bonded: np.ndarray
    touching: np.ndarray
    d_prev: np.ndarray
    n_pairs: int = 0
    forces_current: int = 0
    time: float = 0.0
    phi: float = 0.0
    kappa: np.ndarray = field(default_factory=lambda: np.zeros(2))

    @classmethod
    def new(cls, radius, s, h, density, capacity=None):
        """Fresh state at rest. density [kg/m^2]: disc mass = density * pi R^2 (000 Table 3),
        inertia = m R^2 / 2 (000 section 3.2.1)."""
        radius = checks.array("radius", radius, (None,), checks.POSITIVE)
        n = radius.size
        if n < 1:
            raise InputError("radius must hold at least one disc")
        s = checks.array("s", s, (n, 2)) % 1.0
        h = checks.array("h", h, (2, 2))
        density = checks.number("density", density, checks.POSITIVE)
        capacity = checks.optional("capacity", capacity, checks.COUNT)
        mass = density * np.pi * radius ** 2
        cap = capacity if capacity is not None else max(64, 3 * n)
        return cls(radius=radius, mass=mass, inertia=0.5 * mass * radius ** 2, s=s.copy(),
                   v=np.zeros((n, 2)), theta=np.zeros(n), omega=np.zeros(n), dtheta=np.zeros(n),
                   force=np.zeros((n, 2)), moment=np.zeros(n), s_build=s.copy(),
                   h=h.copy(), h_build=h.copy(), h_ref=h.copy(),
                   pair_i=np.zeros(cap, np.int64), pair_j=np.zeros(cap, np.int64),
                   fn=np.zeros(cap), fs=np.zeros(cap), mr=np.zeros(cap),
                   bonded=np.zeros(cap, np.uint8), touching=np.zeros(cap, np.uint8),
                   d_prev=np.zeros((cap, 2)), n_pairs=0, forces_current=0, time=0.0)

    @property
    def n_particles(self):
        return self.radius.size

    @property
    def F(self):
        """Macroscopic deformation gradient F = h h_ref^-1 (001 eq. 7)."""
        return deformation_gradient(self.h, self.h_ref)

    def positions(self):
        """Current centres x = h s [m], shape (N, 2)."""
        return self.s @ self.h.T

    def copy(self):
        """Deep copy (used for commit / rollback and for perturbations). The pair arrays of the
        copy are trimmed to 1.25 n_pairs + 16 slots (they grow again when needed), which
        keeps committed copies small."""
        cap = min(self.pair_i.shape[0], max(64, int(1.25 * self.n_pairs) + 16))
        kw = {}
        for f in fields(self):
            val = getattr(self, f.name)
            if isinstance(val, np.ndarray):
                val = val[:cap].copy() if f.name in PAIR_FIELDS else val.copy()
            kw[f.name] = val
        return CellState(**kw)

    def grow_pairs(self, capacity):
        """Enlarge the pair arrays to ``capacity`` slots, keeping the content."""
        for name in PAIR_FIELDS:
            old = getattr(self, name)
            new = np.zeros((capacity,) + old.shape[1:], dtype=old.dtype)
            new[:old.shape[0]] = old
            setattr(self, name, new)

    def nbytes(self):
        """Memory held by the arrays of this state [bytes]."""
        return sum(getattr(self, f.name).nbytes for f in fields(self)
                   if isinstance(getattr(self, f.name), np.ndarray))

    def to_dict(self):
        out = {}
        for f in fields(self):
            val = getattr(self, f.name)
            if isinstance(val, np.ndarray) and f.name in PAIR_FIELDS:
                val = val[:self.n_pairs]
            out[f.name] = val
        return out

    def check(self):
        """Types, shapes, dtypes and values consistent (a state given to DemCell, a packing
        read from a file): positive finite radii, masses and inertias, finite positions,
        velocities and forces, cell matrices h and h_ref finite with det > 0, pair indices of
        existing particles. Raises InputError (a ValueError) naming the array; returns self."""
        for name in FLOAT_FIELDS + INT_FIELDS + FLAG_FIELDS + ("kappa",):
            a = getattr(self, name)
            if not isinstance(a, np.ndarray):
                raise InputError(f"{name} must be a numpy array, got {type(a).__name__}")
            if a.dtype != DTYPES[name]:
                # the compiled kernels take these dtypes only
                raise InputError(f"{name} must be an array of dtype {np.dtype(DTYPES[name]).name}, got {a.dtype}")
        n = self.radius.shape[0] if self.radius.ndim == 1 else -1
        if n < 1:
            raise InputError(f"radius must be a non-empty 1D array, got shape {self.radius.shape}")
        per_particle = {"mass": (n,), "inertia": (n,), "s": (n, 2), "v": (n, 2), "theta": (n,), "omega": (n,),
                        "dtheta": (n,), "force": (n, 2), "moment": (n,), "s_build": (n, 2)}
        for name, shape in per_particle.items():
            if getattr(self, name).shape != shape:
                raise InputError(f"{name} has shape {getattr(self, name).shape}, expected {shape} for {n} particles")
        for name in ("h", "h_build", "h_ref"):
            if getattr(self, name).shape != (2, 2):
                raise InputError(f"{name} must be 2x2, got shape {getattr(self, name).shape}")
        m = self.pair_i.shape[0] if self.pair_i.ndim == 1 else -1
        for name in PAIR_FIELDS:
            a = getattr(self, name)
            expected = (m, 2) if name == "d_prev" else (m,)
            if m < 0 or a.shape != expected:
                raise InputError(f"pair array {name} has shape {a.shape}, expected {expected} like pair_i")
        if np.shape(self.kappa) != (2,):
            raise InputError(f"kappa must have shape (2,), got {np.shape(self.kappa)}")
        for name in ("n_pairs", "forces_current"):
            v = getattr(self, name)
            if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)):
                raise InputError(f"{name} must be an integer, got {v!r}")
        if not 0 <= self.n_pairs <= m:
            raise InputError(f"n_pairs = {self.n_pairs} outside [0, {m}] (the pair arrays' length)")
        if self.forces_current not in (0, 1):
            raise InputError(f"forces_current must be 0 or 1, got {self.forces_current!r}")
        for name in ("time", "phi"):
            v = getattr(self, name)
            if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, float, np.integer, np.floating)) \
                    or not np.isfinite(v):
                raise InputError(f"{name} must be a finite number, got {v!r}")
        for name in ("radius", "mass", "inertia"):
            _finite(name, getattr(self, name), positive=True)
        k = self.n_pairs
        for name in FLOAT_FIELDS + ("kappa",):
            if name not in ("radius", "mass", "inertia"):
                # pair slots beyond n_pairs are free: whatever they hold is never read
                _finite(name, getattr(self, name)[:k] if name in PAIR_FIELDS else getattr(self, name))
        for name in ("h", "h_ref"):
            det = float(np.linalg.det(getattr(self, name)))
            if not (det > 0.0 and np.isfinite(det)):
                raise InputError(f"the cell matrix {name} must have a finite det > 0, got det {name} = {det:.3g}")
        for name in ("pair_i", "pair_j"):
            a = getattr(self, name)[:k]
            if k and (a.min() < 0 or a.max() >= n):
                raise InputError(f"{name} holds particle indices outside [0, {n}) (n_pairs = {k})")
        for name in FLAG_FIELDS:
            a = getattr(self, name)[:k]
            if k and not np.isin(a, (0, 1)).all():
                raise InputError(f"{name} must hold flags 0 or 1 (n_pairs = {k})")
        return self

    @classmethod
    def from_dict(cls, d):
        # packings written before the micropolar cell existed have no phi / kappa
        optional = {"phi": 0.0, "kappa": np.zeros(2)}
        kw = {f.name: (d[f.name] if f.name in d or f.name not in optional else optional[f.name])
              for f in fields(cls)}
        for k in ("n_pairs", "forces_current"):
            kw[k] = int(kw[k])
        kw["time"] = float(kw["time"])
        kw["phi"] = float(kw["phi"])
        kw["kappa"] = np.array(kw["kappa"], dtype=np.float64).reshape(-1)
        st = cls(**{k: (np.array(v) if isinstance(v, np.ndarray) else v) for k, v in kw.items()})
        cap = max(64, 3 * st.n_particles, st.n_pairs)
        if st.pair_i.shape[0] < cap:
            st.grow_pairs(cap)
        return st


#: per-particle fields (first axis N) and per-cell fields of a CellState, for pack_states
PARTICLE_FIELDS = ("radius", "mass", "inertia", "s", "v", "theta", "omega", "dtheta", "force", "moment", "s_build")
CELL_FIELDS = ("h", "h_build", "h_ref", "kappa", "n_pairs", "forces_current", "time", "phi")


def pack_states(states):
    """Many CellStates as one struct of arrays: every per-particle field concatenated over
    the cells (counts in `n_particles`), every pair field over the cells at its full
    capacity (counts in `pair_capacity`; capacities are kept so that a state unpacked runs
    bit for bit as the original), per-cell fields stacked. Plain arrays: np.savez writes
    them, mpi4py sends them. Inverse: unpack_states."""
    states = list(states)
    out = {"n_particles": np.array([st.n_particles for st in states], dtype=np.int64),
           "pair_capacity": np.array([st.pair_i.shape[0] for st in states], dtype=np.int64)}
    for name in PARTICLE_FIELDS + PAIR_FIELDS:
        parts = [getattr(st, name) for st in states]
        out[name] = np.concatenate(parts) if parts else np.zeros(0)
    for name in CELL_FIELDS:
        out[name] = np.array([getattr(st, name) for st in states])
    return out


def unpack_states(arrays, rows=None):
    """The CellStates of a pack_states struct of arrays (copies, in order); rows: the
    indices of the cells wanted (default all)."""
    n_particles = np.asarray(arrays["n_particles"], dtype=np.int64)
    capacity = np.asarray(arrays["pair_capacity"], dtype=np.int64)
    p_off = np.concatenate([[0], np.cumsum(n_particles)])
    c_off = np.concatenate([[0], np.cumsum(capacity)])
    states = []
    for k in (range(len(n_particles)) if rows is None else rows):
        kw = {name: np.array(arrays[name][p_off[k]:p_off[k + 1]]) for name in PARTICLE_FIELDS}
        kw.update({name: np.array(arrays[name][c_off[k]:c_off[k + 1]]) for name in PAIR_FIELDS})
        kw.update(h=np.array(arrays["h"][k]), h_build=np.array(arrays["h_build"][k]),
                  h_ref=np.array(arrays["h_ref"][k]), kappa=np.array(arrays["kappa"][k]),
                  n_pairs=int(arrays["n_pairs"][k]), forces_current=int(arrays["forces_current"][k]),
                  time=float(arrays["time"][k]), phi=float(arrays["phi"][k]))
        states.append(CellState(**kw))
    return states
