"""The arrays of a bounded disc specimen and the options of its engine.

``SpecimenState`` holds everything that evolves (discs, contacts with their history, walls,
time); ``SpecimenOptions`` the numerical and boundary settings of a run. 2D, per unit
out-of-plane depth: forces [N], stresses and stiffnesses [N/m], masses [kg/m], inertias
[kg m^2/m]. x horizontal, y vertical, tension positive.

Contact convention (that of demcell/relaxation.py ``compute_forces``): for a listed pair
i < j, n = (x_j - x_i)/|x_j - x_i|, t = (-n_y, n_x), overlap = r_i + r_j - |x_j - x_i|;
the force on j is fn n + fs t (fn > 0 repulsive), on i its opposite; the contact point lies
a_i = r_i - overlap/2 from i along n; moments: -a_i fs on i, -a_j fs on j, -mr on i, +mr on j.

Walls: index 0 bottom (a horizontal line y = wall_position[0], normal +y into the specimen),
1 top (normal -y), 2 left (x, normal +x), 3 right (normal -x). ``wall_active`` is 0 for a
free (membrane) or periodic side.
"""
from dataclasses import dataclass, field, fields

import numpy as np

from .. import checks
from ..checks import NON_NEGATIVE, POSITIVE, Range
from ..errors import InputError

LATERAL_KINDS = ("walls", "membrane", "periodic", "none")
BOTTOM, TOP, LEFT, RIGHT = range(4)
#: unit normal of each wall pointing into the specimen
WALL_NORMAL = np.array([[0.0, 1.0], [0.0, -1.0], [1.0, 0.0], [-1.0, 0.0]])

_DISC_FLOATS = ("position", "velocity", "rotation", "spin", "radius", "mass", "inertia",
                "reference_position", "reference_rotation", "external_force")
_PAIR_ARRAYS = ("pair_i", "pair_j", "touching", "sliding", "fn", "fs", "mr")


@dataclass
class SpecimenState:
    """Discs, contacts, walls and clock of a bounded specimen (see the module docstring).

    position, velocity (n, 2) [m, m/s]: centres and leapfrog half-step velocities v_{n-1/2};
    rotation, spin (n,) [rad, rad/s]; radius, mass, inertia (n,) [m, kg/m, kg m^2/m];
    reference_position (n, 2), reference_rotation (n,): origin of displacement and rotation;
    pair_i, pair_j (m,) int64 (i < j, sorted by i then j); touching, sliding (m,) int8;
    fn, fs (m,) [N], mr (m,) [N m]: the Verlet list with its contact history;
    external_force (n, 2) [N]: every force of the last step that is not a disc-disc contact
    (walls, pressure arcs, membrane); wall_force (4, 2) [N]: force each wall exerts on the
    discs; on_wall, on_boundary (n,) int8; wall_position, wall_velocity (4,) [m, m/s];
    wall_active (4,) int8; period [m]: 0 or the x period of a laterally periodic specimen;
    time [s]; step.
    """
    position: np.ndarray
    velocity: np.ndarray
    rotation: np.ndarray
    spin: np.ndarray
    radius: np.ndarray
    mass: np.ndarray
    inertia: np.ndarray
    reference_position: np.ndarray
    reference_rotation: np.ndarray
    wall_position: np.ndarray
    wall_velocity: np.ndarray
    wall_active: np.ndarray
    pair_i: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    pair_j: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    touching: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int8))
    sliding: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int8))
    fn: np.ndarray = field(default_factory=lambda: np.zeros(0))
    fs: np.ndarray = field(default_factory=lambda: np.zeros(0))
    mr: np.ndarray = field(default_factory=lambda: np.zeros(0))
    external_force: np.ndarray = None
    wall_force: np.ndarray = field(default_factory=lambda: np.zeros((4, 2)))
    on_wall: np.ndarray = None
    on_boundary: np.ndarray = None
    period: float = 0.0
    time: float = 0.0
    step: int = 0

    def __post_init__(self):
        n = self.radius.shape[0] if isinstance(self.radius, np.ndarray) else len(self.radius)
        if self.external_force is None:
            self.external_force = np.zeros((n, 2))
        if self.on_wall is None:
            self.on_wall = np.zeros(n, np.int8)
        if self.on_boundary is None:
            self.on_boundary = np.zeros(n, np.int8)

    @property
    def n_discs(self):
        return self.radius.shape[0]

    @property
    def n_pairs(self):
        return self.pair_i.shape[0]

    @classmethod
    def from_discs(cls, position, radius, mass, inertia, box, lateral="walls", period=0.0):
        """A state at rest from disc arrays and the box (x_min, x_max, y_min, y_max) [m] the
        walls start on. lateral: "walls" (four walls), "membrane" (platens only),
        "periodic" (platens only, x period = `period`, default the box width), "none" (no
        wall: the discs are driven by held discs, Specimen.hold)."""
        checks.choice("lateral", lateral, LATERAL_KINDS)
        position = checks.array("position", position, (None, 2))
        n = position.shape[0]
        if n < 1:
            raise InputError("a specimen needs at least one disc, got 0")
        radius = checks.array("radius", radius, (n,), POSITIVE)
        mass = checks.array("mass", mass, (n,), POSITIVE)
        inertia = checks.array("inertia", inertia, (n,), POSITIVE)
        box = checks.array("box", box, (4,))
        if not (box[1] > box[0] and box[3] > box[2]):
            raise InputError(f"box must be (x_min, x_max, y_min, y_max) with x_max > x_min and y_max > y_min, "
                             f"got {tuple(box)}")
        period = checks.number("period", period, NON_NEGATIVE)
        if lateral == "periodic" and period == 0.0:
            period = float(box[1] - box[0])
        if lateral != "periodic":
            period = 0.0
        platens = 0 if lateral == "none" else 1
        side = 1 if lateral == "walls" else 0
        active = np.array([platens, platens, side, side], np.int8)
        return cls(position=position.copy(), velocity=np.zeros((n, 2)), rotation=np.zeros(n), spin=np.zeros(n),
                   radius=radius.copy(), mass=mass.copy(), inertia=inertia.copy(),
                   reference_position=position.copy(), reference_rotation=np.zeros(n),
                   wall_position=np.array([box[2], box[3], box[0], box[1]], float), wall_velocity=np.zeros(4),
                   wall_active=active, period=float(period))

    @classmethod
    def from_specimen_discs(cls, discs, lateral="walls"):
        """A state at rest from a ``specimens.Discs`` (its box and periodic width)."""
        if lateral == "periodic" and not discs.periodic_width > 0.0:
            raise InputError("lateral='periodic' needs discs with a periodic_width > 0 (tiled with periodic sides)")
        return cls.from_discs(discs.position, discs.radius, discs.mass, discs.inertia, discs.box, lateral,
                              discs.periodic_width)

    def check(self):
        """InputError (one line) unless every array has its shape and dtype, the disc
        properties are finite and > 0 and the kinematic arrays finite; returns self."""
        n = self.n_discs
        if n < 1:
            raise InputError("a specimen needs at least one disc, got 0")
        for name in ("radius", "mass", "inertia"):
            checks.array(name, getattr(self, name), (n,), POSITIVE)
        for name, shape in (("position", (n, 2)), ("velocity", (n, 2)), ("rotation", (n,)), ("spin", (n,)),
                            ("reference_position", (n, 2)), ("reference_rotation", (n,)),
                            ("external_force", (n, 2)), ("wall_force", (4, 2)), ("wall_position", (4,)),
                            ("wall_velocity", (4,))):
            checks.array(name, getattr(self, name), shape)
        m = self.pair_i.shape[0] if isinstance(self.pair_i, np.ndarray) else -1
        for name, dtype in (("pair_i", np.int64), ("pair_j", np.int64), ("touching", np.int8),
                            ("sliding", np.int8), ("fn", np.float64), ("fs", np.float64), ("mr", np.float64)):
            a = getattr(self, name)
            if not isinstance(a, np.ndarray) or a.shape != (m,) or a.dtype != dtype:
                raise InputError(f"{name} must be a {np.dtype(dtype).name} array of shape ({m},), got "
                                 f"{getattr(a, 'dtype', type(a).__name__)} of shape {getattr(a, 'shape', None)}")
        if m and (self.pair_i.min() < 0 or self.pair_j.max() >= n or np.any(self.pair_i >= self.pair_j)):
            raise InputError(f"pair_i, pair_j must satisfy 0 <= i < j < {n}")
        for name in ("on_wall", "on_boundary", "wall_active"):
            a = getattr(self, name)
            size = 4 if name == "wall_active" else n
            if not isinstance(a, np.ndarray) or a.shape != (size,) or a.dtype != np.int8:
                raise InputError(f"{name} must be an int8 array of shape ({size},)")
        checks.number("period", self.period, NON_NEGATIVE)
        checks.number("time", self.time)
        checks.number("step", self.step, Range(0, integer=True))
        return self

    def set_reference(self):
        """The current configuration becomes the origin of displacements and rotations
        (004 section 7.4: u and phi are measured from the end of the isotropic stage)."""
        self.reference_position = self.position.copy()
        self.reference_rotation = self.rotation.copy()

    def kinetic_energy(self):
        """Translational plus rotational kinetic energy of the half-step velocities [J/m]."""
        return float(0.5 * np.sum(self.mass * np.sum(self.velocity ** 2, axis=1))
                     + 0.5 * np.sum(self.inertia * self.spin ** 2))

    def to_dict(self):
        """Plain arrays and numbers (for np.savez); ``from_dict`` reads them back."""
        out = {}
        for f in fields(self):
            v = getattr(self, f.name)
            out[f.name] = np.asarray(v).copy()
        return out

    @classmethod
    def from_dict(cls, data):
        """The state saved by ``to_dict`` (a dict or an open .npz), checked."""
        try:
            kw = {f.name: np.array(data[f.name]) for f in fields(cls)}
        except KeyError as exc:
            raise InputError(f"specimen checkpoint lacks the array {exc.args[0]!r}") from None
        kw["period"] = float(kw["period"])
        kw["time"] = float(kw["time"])
        kw["step"] = int(kw["step"])
        return cls(**kw).check()

    def permuted(self, order):
        """A copy with the discs renumbered: new disc k is old disc order[k] (the contact
        list is dropped; the next neighbour build makes it again, without history)."""
        order = np.asarray(order, np.int64)
        kw = {f.name: getattr(self, f.name) for f in fields(self)}
        for name in _DISC_FLOATS + ("on_wall", "on_boundary"):
            kw[name] = np.ascontiguousarray(getattr(self, name)[order])
        for name in _PAIR_ARRAYS:
            kw[name] = np.zeros(0, getattr(self, name).dtype)
        for name in ("wall_position", "wall_velocity", "wall_active", "wall_force"):
            kw[name] = getattr(self, name).copy()
        return SpecimenState(**kw)


@dataclass(frozen=True)
class SpecimenOptions:
    """Numerical and boundary settings of a specimen run.

    dt [s]: time step (004 NGT; dns-spec A5 proposes 2e-3 s for Table 7.1);
    normal_dashpot D_n [N s/m] (004 eq. 7.4; Table 7.1: 100) or None: the dashpot of the
        ContactLaw's damping ratio, c = 2 xi_n sqrt(m_eff kn); the same coefficient acts
        between a disc and a wall (004 eq. 7.43);
    tangential_dashpot D_t [N s/m] (004 eq. 7.8; Table 7.1: 0) or None: from xi_t;
    clip_normal: the total normal force (spring + dashpot) is clipped at >= 0 (no cohesion
        while the dashpot pulls; dns-spec D3);
    coulomb_on_total_normal: the Coulomb limit mu fn uses the total (clipped) normal force as
        004 eq. 7.11 reads (True), or the elastic part kn overlap as the periodic cell (False);
    local_damping alpha [-]: non-viscous damping f - alpha |f| sign(v) (000 section 3.2.1),
        for quasi-static preparation; 0 in a dynamic run (004 uses only the dashpots);
    mass_damping c_m [1/s]: velocity-proportional damping -c_m m v and -c_m I omega on the free
        discs, trapezoidal in time (003 eqs. 9, 29; integrate.py); 0: none;
    gravity (g_x, g_y) [m/s^2];
    skin [m]: Verlet skin (None: 0.3 times the largest radius);
    lateral: "walls" | "membrane" | "periodic" | "none" (no wall at all: boundary conditions
        through held discs, ``Specimen.hold``, as demcell.frame's frame cell);
    membrane_stiffness E_m [N/m] (004 eq. 7.45; NGT, dns-spec proposes 100);
    pressure p [N/m]: confining pressure on the free sides (004 eq. 7.44) and the target of
        the servo-controlled side walls;
    boundary_interval: steps between two boundary-line detections (and measurements);
    boundary_gap g_tol [m] (None: half the mean radius): proximity of two boundary discs;
    wall_friction mu_w [-]: 0 = smooth walls (004: no tangential force at the platens);
    threads: Numba threads (None: leave numba's setting);
    reorder: renumber the discs in spatial (Morton) order at construction.
    """
    dt: float = 2.0e-3
    normal_dashpot: float = None
    tangential_dashpot: float = None
    clip_normal: bool = True
    coulomb_on_total_normal: bool = True
    local_damping: float = 0.0
    mass_damping: float = 0.0
    gravity: tuple = (0.0, 0.0)
    skin: float = None
    lateral: str = "walls"
    membrane_stiffness: float = 100.0
    pressure: float = 0.0
    boundary_interval: int = 50
    boundary_gap: float = None
    wall_friction: float = 0.0
    threads: int = None
    reorder: bool = True

    def __post_init__(self):
        s = object.__setattr__
        s(self, "dt", checks.number("SpecimenOptions.dt", self.dt, POSITIVE))
        s(self, "normal_dashpot", checks.optional("SpecimenOptions.normal_dashpot", self.normal_dashpot, NON_NEGATIVE))
        s(self, "tangential_dashpot",
          checks.optional("SpecimenOptions.tangential_dashpot", self.tangential_dashpot, NON_NEGATIVE))
        for name in ("clip_normal", "coulomb_on_total_normal", "reorder"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise InputError(f"SpecimenOptions.{name} must be True or False, got {getattr(self, name)!r}")
            s(self, name, bool(getattr(self, name)))
        s(self, "local_damping", checks.number("SpecimenOptions.local_damping", self.local_damping,
                                               Range(0.0, 1.0, high_open=True)))
        s(self, "mass_damping", checks.number("SpecimenOptions.mass_damping", self.mass_damping, NON_NEGATIVE))
        if self.mass_damping * self.dt >= 2.0:
            raise InputError(f"SpecimenOptions.mass_damping c_m dt = {self.mass_damping * self.dt:g} must be below 2 "
                             f"(above it the trapezoidal damping reverses the velocity every step)")
        s(self, "gravity", tuple(float(g) for g in checks.array("SpecimenOptions.gravity", self.gravity, (2,))))
        s(self, "skin", checks.optional("SpecimenOptions.skin", self.skin, POSITIVE))
        checks.choice("SpecimenOptions.lateral", self.lateral, LATERAL_KINDS)
        s(self, "membrane_stiffness", checks.number("SpecimenOptions.membrane_stiffness", self.membrane_stiffness,
                                                    NON_NEGATIVE))
        s(self, "pressure", checks.number("SpecimenOptions.pressure", self.pressure, NON_NEGATIVE))
        s(self, "boundary_interval", checks.number("SpecimenOptions.boundary_interval", self.boundary_interval,
                                                   Range(1, 10 ** 6, integer=True)))
        s(self, "boundary_gap", checks.optional("SpecimenOptions.boundary_gap", self.boundary_gap, POSITIVE))
        s(self, "wall_friction", checks.number("SpecimenOptions.wall_friction", self.wall_friction,
                                               Range(0.0, infinite=True)))
        s(self, "threads", checks.optional("SpecimenOptions.threads", self.threads, Range(1, 1024, integer=True)))

    def with_(self, **changes):
        """Copy with some options changed (validated again)."""
        d = {f.name: getattr(self, f.name) for f in fields(self)}
        unknown = set(changes) - set(d)
        if unknown:
            raise InputError(f"unknown SpecimenOptions option(s): {sorted(unknown)}")
        d.update(changes)
        return SpecimenOptions(**d)

    def to_dict(self):
        return {f.name: getattr(self, f.name) for f in fields(self)}
