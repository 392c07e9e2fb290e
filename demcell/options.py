"""The options of a cell's quasi-static solve (``RelaxationOptions``), read by the Python
drivers of the relaxation (``relaxation.run``, ``DemCell.solve``, ``quasistatic.solve_options``)."""
from dataclasses import dataclass, fields

from .checks import COUNT, MAX_BUDGET, NON_NEGATIVE, POSITIVE, Range
from .errors import InputError
from .slots import ENERGY_RATIO, FIRE, LOCAL_DAMPING, UNBALANCED_FORCE


@dataclass(frozen=True)
class RelaxationOptions:
    """Options of the quasi-static solve.

    criterion : 'energy' (E_kin/E_pot <= tol, 000 eq. 31) or 'force' (max unbalanced force /
        mean contact force <= tol, 001 section 2)
    tol : tolerance of the criterion (000 Table 3: 1e-3)
    damping : local non-viscous damping alpha = beta (000 Table 3: 0.7)
    max_steps : steps allowed per sub-step after its loading ramp before giving up (result
        flagged not converged)
    max_total_steps : steps allowed for a whole solve, every ramp and relaxation of every
        sub-step together (result flagged not converged); None: ``solve_budget``'s default,
        100 x max_steps and at least 1e7
    check_every : steps between convergence tests
    strain_rate : max |dF| per time step during the loading ramp (001 eq. 7 with
        tau_1 = |F_f - F_i| / strain_rate / dt)
    max_increment : largest |dF| of one sub-step; larger increments are split (polar path)
    dt : time step [s]; None = ``stable_time_step`` (follows the stiffness)
    dt_safety : safety factor of the automatic time step
    skin_ratio : neighbour-list skin / R_min
    stress_tol : relative tolerance on stress-controlled components
    servo_gain : dF per step = -gain (sigma - target) / kn on stress-controlled components
    method : 'local' (local non-viscous damping, 000 section 3.2.1) or 'fire' (FIRE, Bitzek
        et al. 2006, adaptive step up to fire_dt_max x dt; see benchmarks/DEM.md for speed)
    fire_dt_max : largest FIRE time step / dt
    fixed_steps : None (relax to the criterion), or N: run the cells as YADE's FEMxDEM cells
        run (Guo & Zhao's simDEM.py): the increment of F applied over exactly N DEM steps per
        solve (shared out over its sub-steps, at least one step each), no relaxation and no
        convergence test after it; the solve counts as converged. Solves without a servo
        only: a stress-controlled solve (``DemCell.solve(stress_mask=...)``, the isotropic
        stage of the preparation) relaxes to ``tol`` as always
    relax_cap : None (relax to the criterion; a sub-step that has not settled after max_steps
        fails), or N <= max_steps: a sub-step that has not settled N DEM steps after its ramp
        stops there and counts as converged, its grains still moving. A cell that settles within
        N steps is a relaxed cell, bit for bit; one that does not (past the peak, a cell whose
        force chains buckle and which falls towards another state) is left where N steps take
        it, as a fixed-step cell is, and goes on from there at the next solve: a rate limit on
        the cells' collapse, not on their loading. Solves without a servo only, as fixed_steps
    """
    criterion: str = "energy"
    tol: float = 1e-3
    damping: float = 0.7
    max_steps: int = 200_000
    max_total_steps: int = None
    check_every: int = 50
    strain_rate: float = 1e-5
    max_increment: float = 0.01
    dt: float = None
    dt_safety: float = 0.25
    skin_ratio: float = 0.1
    stress_tol: float = 1e-3
    servo_gain: float = 0.05
    method: str = "local"
    fire_dt_max: float = 2.0
    fixed_steps: int = None
    relax_cap: int = None

    #: what each numeric option may be (None allowed for dt and max_total_steps: automatic)
    RANGES = {"tol": POSITIVE, "damping": Range(0.0, 1.0, high_open=True),
              "max_steps": Range(1, MAX_BUDGET, integer=True), "max_total_steps": Range(1, MAX_BUDGET, integer=True),
              "check_every": COUNT, "strain_rate": POSITIVE, "max_increment": POSITIVE, "dt": POSITIVE,
              "dt_safety": Range(0.0, 1.0, low_open=True), "skin_ratio": NON_NEGATIVE, "stress_tol": NON_NEGATIVE,
              "servo_gain": NON_NEGATIVE, "fire_dt_max": Range(1.0),
              "fixed_steps": Range(1, MAX_BUDGET, integer=True), "relax_cap": Range(1, MAX_BUDGET, integer=True)}

    def __post_init__(self):
        if self.method not in ("local", "fire"):
            raise InputError(f"unknown relaxation method {self.method!r}: 'local' or 'fire'")
        if self.criterion not in ("energy", "force"):
            raise InputError(f"unknown convergence criterion {self.criterion!r}: use 'energy' "
                             "(000 eq. 31) or 'force' (unbalanced-force ratio, 001)")
        for name, allowed in self.RANGES.items():
            value = getattr(self, name)
            if value is None and name in ("dt", "max_total_steps", "fixed_steps", "relax_cap"):
                continue
            # frozen: the checked value (an int for the step counts) replaces the given one
            object.__setattr__(self, name, allowed.check(f"RelaxationOptions.{name}", value))
        if self.relax_cap is not None and self.fixed_steps is not None:
            raise InputError("relax_cap and fixed_steps exclude each other: a fixed-step cell does not relax")
        if self.relax_cap is not None and self.relax_cap > self.max_steps:
            raise InputError(f"relax_cap = {self.relax_cap} exceeds max_steps = {self.max_steps}: a sub-step "
                             "would fail on max_steps before it reached the cap")

    @property
    def solve_budget(self):
        """DEM steps a whole solve may take (every sub-step's ramp and relaxation):
        max_total_steps, or by default 100 x max_steps and at least 1e7."""
        if self.max_total_steps is not None:
            return self.max_total_steps
        return min(max(100 * self.max_steps, 10 ** 7), MAX_BUDGET)

    @property
    def fixed(self):
        """True when a solve takes exactly ``fixed_steps`` DEM steps and does not relax."""
        return self.fixed_steps is not None

    @property
    def capped(self):
        """True when a sub-step's relaxation stops after ``relax_cap`` DEM steps, settled or not."""
        return self.relax_cap is not None

    @property
    def criterion_code(self):
        """The criterion as the kernels read it (slots.ENERGY_RATIO, slots.UNBALANCED_FORCE)."""
        return ENERGY_RATIO if self.criterion == "energy" else UNBALANCED_FORCE

    @property
    def method_code(self):
        """The relaxation method as the kernels read it (slots.LOCAL_DAMPING, slots.FIRE)."""
        return FIRE if self.method == "fire" else LOCAL_DAMPING

    def skin(self, radius):
        """The neighbour-list skin [m] of discs of radii `radius` [m]: skin_ratio x R_min."""
        return self.skin_ratio * float(radius.min())

    @classmethod
    def from_kwargs(cls, **kw):
        names = {f.name for f in fields(cls)}
        unknown = set(kw) - names
        if unknown:
            raise InputError(f"unknown relaxation option(s) {sorted(unknown)}; known: {sorted(names)}")
        return cls(**kw)
