"""Linear isotropic micropolar elasticity (thesis 004, eq 2.73 without the compression
point, eq 2.74 for the couple stress; eq 2.75 is the special case mu_c = mu).

    sigma = 2 mu sym(eps) + lambda tr(eps) I + 2 mu_c skw(eps)       [Pa]
    m     = 2 mu_c l_c^2 kappa                                        [N/m = Pa m]

Plane strain: eps33 = 0, so sigma33 = lambda tr(eps) is an output only.
"""
from dataclasses import dataclass
import math

import ufl

from .kinematics import strain, curvature


@dataclass(frozen=True)
class MicropolarElasticity:
    """Elastic constants.

    mu     shear modulus [Pa] (> 0)
    lmbda  Lame's first constant [Pa] (bulk modulus lmbda + 2 mu / 3 > 0)
    mu_c   Cosserat (rotational coupling) modulus [Pa] (>= 0); None means mu_c = mu (eq 2.75)
    l_c    internal length [m] (>= 0)
    """
    mu: float
    lmbda: float
    mu_c: float = None
    l_c: float = 0.0

    def __post_init__(self):
        if self.mu_c is None:
            object.__setattr__(self, "mu_c", self.mu)
        for name in ("mu", "lmbda", "mu_c", "l_c"):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ValueError(f"elastic parameter {name} must be a finite number, got {value!r}")
        if self.mu <= 0.0:
            raise ValueError(f"shear modulus mu must be positive, got {self.mu} Pa")
        if 3.0 * self.lmbda + 2.0 * self.mu <= 0.0:
            raise ValueError(f"bulk modulus lmbda + 2 mu/3 must be positive (lmbda={self.lmbda}, mu={self.mu})")
        if self.mu_c < 0.0:
            raise ValueError(f"Cosserat modulus mu_c must be >= 0, got {self.mu_c} Pa")
        if self.l_c < 0.0:
            raise ValueError(f"internal length l_c must be >= 0, got {self.l_c} m")
        if not math.isfinite(self.bending_modulus):
            raise ValueError(f"the bending modulus 2 mu_c l_c^2 overflows (mu_c = {self.mu_c:g} Pa, "
                             f"l_c = {self.l_c:g} m)")

    @property
    def poisson_ratio(self):
        return self.lmbda / (2.0 * (self.lmbda + self.mu))

    @property
    def p_wave_modulus(self):
        """lambda + 2 mu [Pa], the longitudinal modulus."""
        return self.lmbda + 2.0 * self.mu

    @property
    def bending_modulus(self):
        """2 mu_c l_c^2 [N], the factor of eq 2.74."""
        return 2.0 * self.mu_c * self.l_c * self.l_c   # inf, not OverflowError, when too large

    @property
    def rotation_length(self):
        """Decay length of the free rotation, l_c sqrt((mu + mu_c) / (2 mu)) [m]."""
        return self.l_c * math.sqrt((self.mu + self.mu_c) / (2.0 * self.mu))

    def check_micropolar(self):
        """A micropolar scene with mu_c = 0 has no equation for the rotation."""
        if self.mu_c == 0.0:
            raise ValueError("mu_c = 0 decouples the rotation and, with m = 2 mu_c l_c^2 kappa "
                             "(eq 2.74), leaves it undetermined: use a Cauchy scene (--cauchy) "
                             "or a small positive mu_c")

    def stress(self, eps):
        """Force stress (eq 2.73 with the compression point removed) [Pa]."""
        dim = eps.ufl_shape[0]
        return (2.0 * self.mu * ufl.sym(eps) + self.lmbda * ufl.tr(eps) * ufl.Identity(dim)
                + 2.0 * self.mu_c * ufl.skew(eps))

    def couple_stress(self, kappa):
        """Couple stress m_3j (eq 2.74) [N/m]."""
        return self.bending_modulus * kappa

    def stress_from(self, u, phi=None):
        return self.stress(strain(u, phi))

    def couple_stress_from(self, phi):
        return self.couple_stress(curvature(phi))
