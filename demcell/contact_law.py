"""Contact law between two discs (2D, per unit out-of-plane thickness).

Linear normal spring ``kn`` and tangential spring ``ks`` with Coulomb sliding
(paper 000, eq. 10: ``f_n = kn du_n``, ``|f_s| <= mu |f_n|``), optional cohesive
bonds (paper 001, "frictional-cohesive contacts"), optional rolling resistance
with its own stiffness ``kr`` and limit (paper 003, Table 1), optional viscous
normal/tangential dashpots.

Internal sign convention of this module: ``fn > 0`` is a *repulsive*
(compressive) normal force; the homogenized stresses are reported with tension
positive (see ``homogenization.py``).

Units (2D, forces per unit thickness): kn, ks in N/m/m = N/m per metre of
thickness, i.e. the "N/m" of paper 000 Table 3; forces in N (per unit
thickness); rolling stiffness kr in N m/rad; cohesion in N.

Twisting resistance (rotation about the contact normal) has no meaning for 2D
discs: their only rotation axis is e3, perpendicular to every contact normal.
``ContactLaw(twisting_stiffness=...)`` therefore only accepts 0.
"""
import math
from dataclasses import dataclass, fields

import numpy as np
from numba import njit

from .checks import NON_NEGATIVE, Range
from .errors import InputError
from .slots import COH_N, COH_T, ETA_R, FROZEN, KN, KR, KS, MU, N_LAW, ROTATIONS, XI_N, XI_T



@dataclass(frozen=True)
class ContactLaw:
    """Parameters of the disc-disc contact law.

    kn : normal stiffness [N/m] (000 Table 3: 1e4)
    ks : tangential stiffness [N/m] (000 Table 3: 2e3)
    friction : Coulomb coefficient mu [-]; 0 = frictionless, ``math.inf`` = no sliding
    rolling_stiffness : kr [N m/rad], 0 = no rolling resistance (003 Table 1 k_omega)
    rolling_friction : eta_r [-]; rolling moment limit |M_r| <= eta_r * R_eff * f_n with
        R_eff = R_i R_j / (R_i + R_j). (003 Table 1 gives the limit as a length
        mu_omega = eta_r * R_eff.)  ``math.inf`` = elastic rolling spring without limit.
    normal_damping, tangential_damping : viscous damping ratios xi [-] of the dashpots,
        c = 2 xi sqrt(m_eff k) with m_eff = m_i m_j / (m_i + m_j). The viscous normal force is
        not clipped at zero (linear spring-dashpot).
    cohesion_normal : tensile strength of a bond [N]; cohesion_shear : shear strength
        of a bond [N] added to the Coulomb limit. Bonds exist only on contacts marked with
        ``DemCell.bond_contacts()`` and break for good when either strength is exceeded.
    rotations : False locks all particle rotations (000 section 4.3.2).
    twisting_stiffness : must be 0 in 2D (see module docstring).
    """

    kn: float = 1.0e4
    ks: float = 2.0e3
    friction: float = 0.4
    rolling_stiffness: float = 0.0
    rolling_friction: float = math.inf
    normal_damping: float = 0.0
    tangential_damping: float = 0.0
    cohesion_normal: float = 0.0
    cohesion_shear: float = 0.0
    rotations: bool = True
    twisting_stiffness: float = 0.0

    #: what each parameter may be: stiffnesses and damping ratios finite, the Coulomb and
    #: rolling limits and the bond strengths may be inf (no sliding, no limit, unbreakable)
    RANGES = {"kn": Range(0.0, low_open=True), "ks": NON_NEGATIVE, "friction": Range(0.0, infinite=True),
              "rolling_stiffness": NON_NEGATIVE, "rolling_friction": Range(0.0, infinite=True),
              "normal_damping": NON_NEGATIVE, "tangential_damping": NON_NEGATIVE,
              "cohesion_normal": Range(0.0, infinite=True), "cohesion_shear": Range(0.0, infinite=True),
              "twisting_stiffness": NON_NEGATIVE}

    def __post_init__(self):
        if not isinstance(self.rotations, (bool, np.bool_)):
            raise InputError(f"ContactLaw.rotations must be True or False, got {self.rotations!r}")
        for name, allowed in self.RANGES.items():
            # frozen: the checked float replaces the given number
            object.__setattr__(self, name, allowed.check(f"ContactLaw.{name}", getattr(self, name)))
        object.__setattr__(self, "rotations", bool(self.rotations))
        if self.twisting_stiffness != 0.0:
            raise InputError("twisting resistance does not exist for 2D discs (their only rotation "
                             "axis e3 is perpendicular to every contact normal); use twisting_stiffness=0")

    def with_(self, **changes):
        """Copy with some fields changed (validated again)."""
        d = {f.name: getattr(self, f.name) for f in fields(self)}
        unknown = set(changes) - set(d)
        if unknown:
            raise InputError(f"unknown ContactLaw option(s): {sorted(unknown)}")
        d.update(changes)
        return ContactLaw(**d)

    def as_array(self, frozen=False):
        """Float64 parameter vector read by the Numba kernels (indices KN..FROZEN)."""
        a = np.zeros(N_LAW)
        a[KN], a[KS], a[MU] = self.kn, self.ks, self.friction
        a[KR], a[ETA_R] = self.rolling_stiffness, self.rolling_friction
        a[XI_N], a[XI_T] = self.normal_damping, self.tangential_damping
        a[COH_N], a[COH_T] = self.cohesion_normal, self.cohesion_shear
        a[ROTATIONS] = 1.0 if self.rotations else 0.0
        a[FROZEN] = 1.0 if frozen else 0.0
        return a

    def to_dict(self):
        return {f.name: (getattr(self, f.name) if f.name == "rotations" else float(getattr(self, f.name)))
                for f in fields(self)}


@njit(cache=True)
def contact_update(overlap, d_overlap, d_ut, d_theta_r, fs_old, mr_old, bonded,
                   law, m_eff, r_eff, dt):
    """Advance the force state of one contact by one time step.

    overlap   : current overlap h = R_i + R_j - |d| [m] (001 eq. A.2), may be < 0 for bonds
    d_overlap : increment of overlap during the step [m]
    d_ut      : increment of relative tangential displacement of j w.r.t. i at the
                contact point during the step [m]
    d_theta_r : increment of relative rotation theta_j - theta_i [rad]
    fs_old, mr_old : tangential force on j along t [N] and rolling moment on j [N m]
    bonded    : 1 if a cohesive bond holds the contact
    Returns (fn, fn_elastic, fs, fs_elastic, mr, sliding, bonded); fn > 0 is repulsive on j
    along n, fs is the tangential force on j along t (fs_elastic, without the dashpot, is the
    state to store for the next step).
    Normal: fn = kn h + cn dh/dt; tangential: elastic predictor fs = fs_old - ks d_ut, then
    the Coulomb return |fs| <= mu fn_el (+ bond shear strength) (000 eq. 10).
    """
    return contact_update_params(overlap, d_overlap, d_ut, d_theta_r, fs_old, mr_old, bonded,
                                 law[KN], law[KS], law[MU], law[KR], law[ETA_R], law[XI_N], law[XI_T],
                                 law[COH_N], law[COH_T], m_eff, r_eff, dt)


@njit(cache=True)
def contact_update_params(overlap, d_overlap, d_ut, d_theta_r, fs_old, mr_old, bonded,
                          kn, ks, mu, kr, eta_r, xi_n, xi_t, coh_n, coh_t, m_eff, r_eff, dt,
                          clip_normal=False, limit_on_total=False):
    """``contact_update`` with the law parameters as scalars (kn, ks [N/m], mu [-], kr [N m/rad],
    eta_r [-], xi_n, xi_t [-], cohesions [N]): the force loop reads the law array once per
    call instead of once per contact (the stores into the pair arrays otherwise force the
    compiler to reload it, as it cannot prove that they do not alias). Same arithmetic.

    clip_normal: the total normal force (spring + dashpot) is clipped at >= 0, so that the
    dashpot never pulls two separating discs together (dns-spec A2; the contact then ends
    when the force vanishes, before the overlap does). limit_on_total: the Coulomb and rolling
    limits use that total normal force, as 004 eq. 7.11 reads, instead of the elastic part
    kn h. Both off (the defaults, the periodic cell's law): the same operations as before
    the flags existed."""
    fn_el = kn * overlap
    if bonded == 1 and fn_el < -coh_n:
        bonded = 0
    if bonded == 0 and overlap <= 0.0:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0, 0
    fn = fn_el
    if xi_n > 0.0:
        fn += 2.0 * xi_n * math.sqrt(m_eff * kn) * d_overlap / dt
    if clip_normal and fn < 0.0:
        fn = 0.0
    fn_lim = fn if limit_on_total else fn_el
    # tangential spring, Coulomb limit (000 eq. 10)
    fs = fs_old - ks * d_ut
    # (inf * 0 is avoided: a contact without normal force carries no friction)
    limit = mu * fn_lim if fn_lim > 0.0 else 0.0
    if bonded == 1:
        limit += coh_t
    sliding = 0
    if abs(fs) > limit:
        if bonded == 1:
            bonded = 0
            limit = mu * fn_lim if fn_lim > 0.0 else 0.0
        if abs(fs) > limit:
            fs = math.copysign(limit, fs)
            sliding = 1
    fs_el = fs
    if xi_t > 0.0 and sliding == 0:
        fs -= 2.0 * xi_t * math.sqrt(m_eff * ks) * d_ut / dt
    # rolling resistance (003, Table 1): elastic-perfectly plastic spring on theta_j - theta_i
    mr = 0.0
    if kr > 0.0:
        mr = mr_old - kr * d_theta_r
        mlim = eta_r * r_eff * fn_lim if fn_lim > 0.0 else 0.0
        if math.isinf(eta_r) and bonded == 1:
            mlim = math.inf
        if abs(mr) > mlim:
            mr = math.copysign(mlim, mr)
    return fn, fn_el, fs, fs_el, mr, sliding, bonded
