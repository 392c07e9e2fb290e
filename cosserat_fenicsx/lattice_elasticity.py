"""Linear micropolar elasticity of the square disc lattice rotated by 45 degrees (003's
packings A and B): the affine moduli of its contacts, a cubic law.

In the lattice frame (contact normals e1', e2', spacing l = 2 r, one disc and two contacts
per cell of area l^2) an affine Cosserat strain eps = grad u + phi E3 (kinematics.py) moves
the contact points of two neighbours apart by l eps' n, which the springs k_N (along n) and
k_S (across) resist. Per unit depth (l^2 / A = 1), with no Poisson coupling:

    sigma'_11 = k_N eps'_11,  sigma'_22 = k_N eps'_22,  sigma'_12 = k_S eps'_12,  sigma'_21 = k_S eps'_21

Rotated by 45 degrees (contact normals at +-45 degrees to the horizontal), split into the
symmetric part, cubic in the x-y frame, and the skew part:

    sigma_11 = C11 eps_11 + C12 eps_22,  sigma_22 = C12 eps_11 + C11 eps_22,  sym sigma_12 = 2 C66 sym eps_12
    C11 = (k_N + k_S) / 2,  C12 = (k_N - k_S) / 2,  C66 = k_N / 2
    skw sigma = 2 mu_c skw eps,  mu_c = k_S / 2

(003-bsm.md T3: the rotated square lattice is cubic, not isotropic.) The orientation average
of the same moduli, the isotropic MicropolarElasticity(mu = (k_N + k_S) / 4, lmbda =
(k_N - k_S) / 4, mu_c = k_S / 2), is stiffer in vertical compression (lambda + 2 mu =
(3 k_N + k_S) / 4 against C11) and softer in shear (mu against C66). The couple stress is
MicropolarElasticity's m = 2 mu_c l_c^2 kappa. Units: k_N, k_S [N/m per m of depth] give the
moduli in Pa.
"""
from dataclasses import dataclass
import math

import ufl


@dataclass(frozen=True)
class SquareLatticeElasticity:
    """Affine moduli of the 45-degree square lattice (module docstring).

    k_n, k_s  contact stiffnesses [N/m per m of depth] (> 0)
    l_c       internal length of the couple stress [m] (>= 0)
    """
    k_n: float
    k_s: float
    l_c: float = 0.0

    def __post_init__(self):
        for name in ("k_n", "k_s", "l_c"):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ValueError(f"lattice parameter {name} must be a finite number, got {value!r}")
        if self.k_n <= 0.0 or self.k_s <= 0.0:
            raise ValueError(f"contact stiffnesses must be > 0, got k_n = {self.k_n}, k_s = {self.k_s} N/m")
        if self.l_c < 0.0:
            raise ValueError(f"internal length l_c must be >= 0, got {self.l_c} m")

    @property
    def moduli(self):
        """(C11, C12, C66) [Pa] of the symmetric part in the x-y frame."""
        return 0.5 * (self.k_n + self.k_s), 0.5 * (self.k_n - self.k_s), 0.5 * self.k_n

    @property
    def mu_c(self):
        """Cosserat modulus of the skew part, k_s / 2 [Pa]."""
        return 0.5 * self.k_s

    @property
    def p_wave_modulus(self):
        """The largest longitudinal modulus [Pa]: k_n along the contact normals (C11 along x
        and y); the stable step's translational estimate."""
        return self.k_n

    @property
    def bending_modulus(self):
        """2 mu_c l_c^2 [N]."""
        return 2.0 * self.mu_c * self.l_c * self.l_c

    def stress(self, eps):
        """Force stress [Pa] of the strain eps (module docstring)."""
        c11, c12, c66 = self.moduli
        shear = c66 * (eps[0, 1] + eps[1, 0])
        symmetric = ufl.as_matrix([[c11 * eps[0, 0] + c12 * eps[1, 1], shear],
                                   [shear, c12 * eps[0, 0] + c11 * eps[1, 1]]])
        return symmetric + 2.0 * self.mu_c * ufl.skew(eps)

    def couple_stress(self, kappa):
        """Couple stress m_3j = 2 mu_c l_c^2 kappa_3j [N/m]."""
        return self.bending_modulus * kappa
