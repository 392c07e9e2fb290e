"""The options of a frame cell (``FrameOptions``): the relaxation of its inner particles (a
demcell RelaxationOptions) and the frame's servo (000 section 3.2.2, Tables 2-3)."""
from dataclasses import dataclass, field, fields, replace

from .. import checks
from ..checks import POSITIVE, Range
from ..errors import InputError
from ..options import RelaxationOptions
from .servo import ACCELERATIONS, GAINS, RAMPS, RESIDUALS


@dataclass(frozen=True)
class FrameOptions:
    """Options of a FrameCell.

    relaxation : RelaxationOptions of the dynamic relaxation of the inner particles (000
        section 3.2.1): criterion 'energy' (E_kin/E_pot <= tol, eqs 31-32, 000 Table 3: 1e-3)
        or 'force', tol, damping alpha = beta (0.7), max_steps per relaxation, check_every,
        strain_rate (largest change of F per step of a loading ramp), dt, dt_safety; method
        must be 'local'. Its solve_budget bounds the DEM steps of a whole solve.
    thickness : None: the frame is the discs the cut crosses (one particle layer, 000); t > 0:
        the discs within max(radius, t d_mean / 2) of a cut line (a band t mean diameters
        wide). 000 section 4.2 saw grains pushed through a one-particle frame.
    gain : 'stiffness' (default: g = beta / sum of the contact stiffnesses of the pair,
        Newton-like, dns-spec B1) or 'table3' (000 Table 3 literally, with the cell's time step)
    beta : factor of the stiffness gain (0.5)
    residual : 'force' (default: Table 2's r_a with the forces in units of the mean contact
        force and the moments in units of that force times the radius) or 'table2' (a~ = M R /
        dt^2, m~ = M R^2 / dt^2 with the cell's time step, Table 2 literally)
    eps_a : tolerance on the residual (eq. 37; 000 Table 2: 1e-4 in its units, met at once at
        this project's p0/kn, docs/reference/frame_cell.md). The residual cannot fall below
        the relaxation's own unbalanced forces: keep eps_a at least 10 x relaxation.tol with
        the force criterion (default 1e-2 in mean contact forces)
    max_iterations : servo iterations allowed per solve (each one a relaxation)
    acceleration : 'anderson' (default: the corrections mixed with those of the last `memory`
        iterations, servo.Anderson; not in 000) or 'none' (000's fixed-gain iteration)
    memory : iterations remembered by the Anderson mixing
    ramp : how a new F reaches the discs: 'frame' (000 Table 2 step 1: the frame copies move
        homogeneously, the inner discs are pushed by them) or 'affine' (every disc on the
        affine map during the ramp, then the inner discs are released: the periodic cell's
        loading path)
    """
    relaxation: RelaxationOptions = field(default_factory=RelaxationOptions)
    thickness: float = None
    gain: str = "stiffness"
    beta: float = 0.5
    residual: str = "force"
    eps_a: float = 1e-2
    max_iterations: int = 100
    acceleration: str = "anderson"
    memory: int = 5
    ramp: str = "frame"

    def __post_init__(self):
        if isinstance(self.relaxation, dict):
            object.__setattr__(self, "relaxation", RelaxationOptions.from_kwargs(**self.relaxation))
        checks.instance("FrameOptions.relaxation", self.relaxation, RelaxationOptions)
        if self.relaxation.method != "local":
            raise InputError("a frame cell relaxes with local damping (000 section 3.2.1): method='local', "
                             f"not {self.relaxation.method!r}")
        if self.thickness is not None:
            object.__setattr__(self, "thickness", checks.number("FrameOptions.thickness", self.thickness, POSITIVE))
        checks.choice("FrameOptions.gain", self.gain, GAINS)
        checks.choice("FrameOptions.residual", self.residual, RESIDUALS)
        checks.choice("FrameOptions.acceleration", self.acceleration, ACCELERATIONS)
        checks.choice("FrameOptions.ramp", self.ramp, RAMPS)
        object.__setattr__(self, "memory", checks.number("FrameOptions.memory", self.memory,
                                                         Range(1, 100, integer=True)))
        object.__setattr__(self, "beta", checks.number("FrameOptions.beta", self.beta,
                                                       Range(0.0, 2.0, low_open=True, high_open=True)))
        object.__setattr__(self, "eps_a", checks.number("FrameOptions.eps_a", self.eps_a, POSITIVE))
        object.__setattr__(self, "max_iterations", checks.number("FrameOptions.max_iterations",
                                                                 self.max_iterations, Range(1, 10 ** 6, integer=True)))

    @property
    def max_steps(self):
        """DEM steps allowed per relaxation (the relaxation options')."""
        return self.relaxation.max_steps

    def with_(self, **changes):
        """Copy with some options changed (validated again); relaxation options by name too."""
        own = {f.name for f in fields(self)}
        relax = {k: v for k, v in changes.items() if k not in own}
        if relax:
            try:
                changes = dict({k: v for k, v in changes.items() if k in own},
                               relaxation=replace(changes.get("relaxation", self.relaxation), **relax))
            except TypeError:
                raise InputError(f"unknown frame option(s) {sorted(relax)}") from None
        return replace(self, **changes)
