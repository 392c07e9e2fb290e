"""Parameters of the micropolar Ehlers model: defaults, validation, units.

No Numba import here.  All user-facing values are SI (Pa, m, s).  The Numba
kernels work in *internal units* (stress in MPa = MN/m^2, length in m, time in
s) because the Hostun data of the thesis are of order 1 MN/m^2 and this keeps
the local Jacobian (Table 3.1) well scaled; :meth:`EhlersParameters.to_array`
does the conversion.

Hostun sand defaults (Scholz 2007, Tables 6.1 and 6.4, spec section 6)
-----------------------------------------------------------------------
Reading **H1** of the spec (section 4.6), settled in ``docs/reference/ehlers.md``:

* Table 6.4 prints delta and epsilon in m^2/MN, the units of Ehlers' *original*
  parameters (delta_orig^2 I^4, epsilon_orig I^2 have stress units), whereas the
  thesis yield function (2.76) uses their reciprocals (text after 2.76).  So the
  thesis parameters are ``delta = 1/delta_T6.4`` and ``epsilon = 1/epsilon_T6.4``
  (in MN/m^2):  delta0 = 100, delta* = 0.629, epsilon0 = 2.058,
  epsilon* = 86.96 MN/m^2.
* All four hardening parameters p = (beta, delta, epsilon, gamma) evolve with
  the uniform law (2.82), p_dot = (p* - p)(C^V eps_p^V_dot + C^D |eps_p^D_dot|),
  with the C constants of Table 6.4 unchanged.  Table 3.1 writes the delta and
  epsilon rows as (p - p*)(...); that reading is available as
  ``hardening_rows="table3.1"`` for the evidence runs but it cannot consolidate
  the Hostun sand beyond ~0.1-0.15 MN/m^2 (see docs/reference/ehlers.md).

Micropolar defaults (spec section 6, re-identification reference set, T6.6):
l_c = 3 mm, mu_c = mu, k_sigma = 10, k_mu = 0.

Viscoplastic regularisation (2.81), not material data (footnote to 3.32):
eta = 1e-4 s, sigma_ref (thesis sigma_0) = 1 MN/m^2, r = 1.
"""

from __future__ import annotations

import dataclasses
import math
import warnings

import numpy as np

#: internal stress unit of the kernels [Pa]
STRESS_UNIT = 1.0e6

# ---- layout of the float64 parameter array handed to the kernels ------------
P_MU, P_LMBDA, P_MU_C, P_L_C, P_N0, P_NMAX, P_PSI1, P_PSI2 = range(8)
P_K_SIGMA, P_K_MU, P_ALPHA, P_KAPPA = range(8, 12)
P_BETA0, P_BETA_STAR, P_C_BETA_V, P_C_BETA_D = range(12, 16)
P_DELTA0, P_DELTA_STAR, P_C_DELTA_V, P_C_DELTA_D = range(16, 20)
P_EPS0, P_EPS_STAR, P_C_EPS_V, P_C_EPS_D = range(20, 24)
P_GAMMA0, P_GAMMA_STAR, P_C_GAMMA_V, P_C_GAMMA_D = range(24, 28)
P_ETA, P_SIGMA_REF, P_R = range(28, 31)
P_SIGN_DELTA, P_SIGN_EPS = range(31, 33)
P_TOL, P_MAX_ITER, P_MAX_LEVELS, P_MICROPOLAR = range(33, 37)
N_PARAMS = 37

#: hard limit for real Gamma = (1 + gamma*theta)^m, theta >= -2/(3 sqrt 3)  (spec 4.2)
GAMMA_HARD_LIMIT = 3.0 * math.sqrt(3.0) / 2.0
#: yield-surface convexity with m(gamma) of (2.77) holds up to about this value (spec 10.5)
GAMMA_CONVEX_LIMIT = 1.75

_STRESS_LIKE = ("mu", "lmbda", "mu_c", "kappa", "delta0", "delta_star",
                "epsilon0", "epsilon_star", "sigma_ref")


@dataclasses.dataclass(frozen=True)
class EhlersParameters:
    """Material and numerical parameters, SI units.

    Elasticity (2.70)-(2.74), Table 6.1
        mu, lmbda [Pa]: Lame constants; mu_c [Pa]: Cosserat shear modulus of the
        skew strain (None -> mu, remark after 2.74); l_c [m]: internal length;
        n0, n_max [-]: initial and maximal solid volume fraction (2.67, 2.70).
    Yield function (2.76)/(2.77) and potential (2.78), Table 6.4
        psi1, psi2 [-]; k_sigma [-]; k_mu [1/m^2]; alpha [-]; kappa [Pa]
        (alpha = kappa = 0 for dry sand, section 2.4.4).
    Hardening (2.82) with p = (beta, delta, epsilon, gamma), thesis form
        beta [-], delta [Pa], epsilon [Pa], gamma [-]: initial value ``*0``,
        limit ``*_star``, volumetric and deviatoric constants ``C_*_V``, ``C_*_D``.
    Viscoplasticity (2.81)
        eta [s] (0 = rate-independent limit, Kuhn-Tucker 2.80), sigma_ref [Pa]
        (thesis sigma_0), r [-] (>= 1).
    Options
        hardening_rows: "uniform" (H1, eq. 2.82) or "table3.1" (delta/epsilon
        rows with the sign printed in Table 3.1).  micropolar: False gives the
        classical (non-polar) model: k_sigma = k_mu = 0, mu_c = 0 and the
        curvature is ignored (couple stress 0).
    Local solver
        tol (scaled residual), max_iter (per Newton solve), max_substep_levels
        (the increment is bisected up to 2**levels substeps).
    """

    mu: float = 91.0e6
    lmbda: float = 49.4e6
    mu_c: float | None = None
    l_c: float = 3.0e-3
    n0: float = 0.604
    n_max: float = 0.635
    psi1: float = 1.85
    psi2: float = 0.669
    k_sigma: float = 10.0
    k_mu: float = 0.0
    alpha: float = 0.0
    kappa: float = 0.0
    beta0: float = 0.120
    beta_star: float = 0.273
    C_beta_V: float = -66.6
    C_beta_D: float = 127.0
    delta0: float = 1.0e6 / 0.01          # H1: 1/(0.01 m^2/MN) = 100 MN/m^2
    delta_star: float = 1.0e6 / 1.59      # 0.629 MN/m^2
    C_delta_V: float = 46.1
    C_delta_D: float = -6.94
    epsilon0: float = 1.0e6 / 0.486       # 2.058 MN/m^2
    epsilon_star: float = 1.0e6 / 0.0115  # 86.96 MN/m^2
    C_epsilon_V: float = -25.3
    C_epsilon_D: float = 34.2
    gamma0: float = 1.00
    gamma_star: float = 1.55
    C_gamma_V: float = -4.52
    C_gamma_D: float = 33.4
    eta: float = 1.0e-4
    sigma_ref: float = 1.0e6
    r: float = 1.0
    hardening_rows: str = "uniform"
    micropolar: bool = True
    tol: float = 1.0e-10
    max_iter: int = 40
    max_substep_levels: int = 8

    def __post_init__(self):
        if self.mu_c is None:
            object.__setattr__(self, "mu_c", self.mu if self.micropolar else 0.0)
        if not self.micropolar:
            # classical continuum: micropolar terms off (spec 10.9)
            object.__setattr__(self, "mu_c", 0.0)
            object.__setattr__(self, "k_sigma", 0.0)
            object.__setattr__(self, "k_mu", 0.0)
        self._validate()

    # ------------------------------------------------------------------ checks
    def _validate(self):
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if f.name in ("hardening_rows", "micropolar"):
                continue
            if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)):
                raise ValueError(f"Ehlers parameter '{f.name}' must be a real number, got {v!r}")
            if not math.isfinite(float(v)):
                raise ValueError(f"Ehlers parameter '{f.name}' must be finite, got {v!r}")

        def positive(name):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"Ehlers parameter '{name}' must be > 0, got {getattr(self, name)!r}")

        def non_negative(name):
            if not getattr(self, name) >= 0.0:
                raise ValueError(f"Ehlers parameter '{name}' must be >= 0, got {getattr(self, name)!r}")

        positive("mu")
        if not self.lmbda + 2.0 * self.mu / 3.0 > 0.0:
            raise ValueError(f"Ehlers parameter 'lmbda' gives a non-positive bulk modulus "
                             f"K = lmbda + 2 mu/3 = {self.lmbda + 2 * self.mu / 3:.6g} Pa")
        for name in ("mu_c", "l_c", "k_sigma", "k_mu", "alpha", "kappa", "psi2", "beta0",
                     "beta_star", "eta"):
            non_negative(name)
        for name in ("psi1", "delta0", "delta_star", "epsilon0", "epsilon_star", "sigma_ref",
                     "tol"):
            positive(name)
        if not 0.0 < self.n0 < 1.0:
            raise ValueError(f"Ehlers parameter 'n0' (initial solid volume fraction) must be in (0, 1), got {self.n0!r}")
        if not 0.0 < self.n_max < 1.0:
            raise ValueError(f"Ehlers parameter 'n_max' must be in (0, 1), got {self.n_max!r}")
        if not self.n0 < self.n_max:
            raise ValueError(f"Ehlers parameter 'n0' = {self.n0} must be < n_max = {self.n_max} "
                             "(eq. 2.70: otherwise eps_crit >= 0 and no compression is possible)")
        for name in ("gamma0", "gamma_star"):
            g = getattr(self, name)
            if not 0.0 < g < GAMMA_HARD_LIMIT:
                raise ValueError(f"Ehlers parameter '{name}' = {g} out of range (0, 3 sqrt(3)/2 = 2.598): "
                                 "Gamma = (1 + gamma theta)^m is not real beyond it (eq. 2.76)")
            if g > GAMMA_CONVEX_LIMIT:
                warnings.warn(f"Ehlers parameter '{name}' = {g} > 1.75: the deviatoric section of "
                              "the yield surface with m(gamma) of (2.77) is not convex (spec 10.5)",
                              stacklevel=3)
        if not self.r >= 1.0:
            raise ValueError(f"Ehlers parameter 'r' (Perzyna exponent, 2.81) must be >= 1, got {self.r!r}")
        if self.hardening_rows not in ("uniform", "table3.1"):
            raise ValueError("Ehlers parameter 'hardening_rows' must be 'uniform' (H1, eq. 2.82) "
                             f"or 'table3.1', got {self.hardening_rows!r}")
        if int(self.max_iter) < 2:
            raise ValueError(f"Ehlers parameter 'max_iter' must be >= 2, got {self.max_iter!r}")
        if not 0 <= int(self.max_substep_levels) <= 20:
            raise ValueError(f"Ehlers parameter 'max_substep_levels' must be in [0, 20], got {self.max_substep_levels!r}")

    # --------------------------------------------------------------- creation
    @classmethod
    def from_kwargs(cls, **params):
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(params) - names)
        if unknown:
            raise ValueError(f"unknown Ehlers parameter(s) {unknown}; valid names: {sorted(names)}")
        return cls(**params)

    def as_dict(self):
        return dataclasses.asdict(self)

    def to_array(self) -> np.ndarray:
        """Float64 parameter vector in internal units (MPa, m, s) for the kernels."""
        su = STRESS_UNIT
        p = np.zeros(N_PARAMS)
        p[P_MU] = self.mu / su
        p[P_LMBDA] = self.lmbda / su
        p[P_MU_C] = self.mu_c / su
        p[P_L_C] = self.l_c if self.micropolar else 0.0
        p[P_N0] = self.n0
        p[P_NMAX] = self.n_max
        p[P_PSI1] = self.psi1
        p[P_PSI2] = self.psi2
        p[P_K_SIGMA] = self.k_sigma
        p[P_K_MU] = self.k_mu  # [1/m^2] in both unit systems: k_mu mu.mu has the units of Phi
        p[P_ALPHA] = self.alpha
        p[P_KAPPA] = self.kappa / su
        p[P_BETA0], p[P_BETA_STAR] = self.beta0, self.beta_star
        p[P_C_BETA_V], p[P_C_BETA_D] = self.C_beta_V, self.C_beta_D
        p[P_DELTA0], p[P_DELTA_STAR] = self.delta0 / su, self.delta_star / su
        p[P_C_DELTA_V], p[P_C_DELTA_D] = self.C_delta_V, self.C_delta_D
        p[P_EPS0], p[P_EPS_STAR] = self.epsilon0 / su, self.epsilon_star / su
        p[P_C_EPS_V], p[P_C_EPS_D] = self.C_epsilon_V, self.C_epsilon_D
        p[P_GAMMA0], p[P_GAMMA_STAR] = self.gamma0, self.gamma_star
        p[P_C_GAMMA_V], p[P_C_GAMMA_D] = self.C_gamma_V, self.C_gamma_D
        p[P_ETA] = self.eta
        p[P_SIGMA_REF] = self.sigma_ref / su
        p[P_R] = self.r
        sign = -1.0 if self.hardening_rows == "table3.1" else 1.0
        p[P_SIGN_DELTA] = sign
        p[P_SIGN_EPS] = sign
        p[P_TOL] = self.tol
        p[P_MAX_ITER] = int(self.max_iter)
        p[P_MAX_LEVELS] = int(self.max_substep_levels)
        p[P_MICROPOLAR] = 1.0 if self.micropolar else 0.0
        return p


def hostun(**overrides) -> EhlersParameters:
    """Hostun sand (Tables 6.1, 6.4 under reading H1) with micropolar defaults of spec 6."""
    return EhlersParameters.from_kwargs(**overrides)


#: fields that are numerics or switches, not material data: a parameter file leaves them out
#: (eta, sigma_ref and r regularise, footnote to 3.32; the demos choose them)
NUMERICAL_FIELDS = ("eta", "sigma_ref", "r", "micropolar", "tol", "max_iter", "max_substep_levels")


def material_values(parameters: EhlersParameters) -> dict:
    """The material data of a parameter set (SI), as a parameter file holds them."""
    return {k: v for k, v in parameters.as_dict().items() if k not in NUMERICAL_FIELDS}


def write_parameter_file(path, parameters: EhlersParameters, note="", identification=None):
    """JSON parameter file (what demos/identify.py writes, and --parameters of the
    material-point and biaxial demos reads): {"parameters": {name: value (SI)}, "note": ...,
    "identification": {...}} (the last: what an identification identified, whether it
    converged; the readers ignore it)."""
    import json
    doc = dict(parameters=material_values(parameters), units="SI (Pa, m)", note=note)
    if identification is not None:
        doc["identification"] = identification
    with open(path, "w") as f:
        json.dump(doc, f, indent=1, allow_nan=False)


def read_parameter_file(path) -> dict:
    """The {name: value} of a parameter file, checked (unknown names, non-numbers, a set that
    EhlersParameters refuses): ValueError naming the file, before any model runs."""
    import json

    def refuse(name):
        raise ValueError(f"{name} is not a JSON value")
    try:
        with open(path, encoding="utf-8") as f:
            doc = json.load(f, parse_constant=refuse)
    except UnicodeDecodeError:
        raise ValueError(f"parameter file {path!r}: not a text (UTF-8 JSON) file") from None
    except RecursionError:
        raise ValueError(f"parameter file {path!r}: nested too deeply") from None
    except (OSError, ValueError) as error:
        raise ValueError(f"parameter file {path!r}: {' '.join(str(error).split())}") from None
    values = doc.get("parameters", doc) if isinstance(doc, dict) else None
    if not isinstance(values, dict):
        raise ValueError(f"parameter file {path!r}: expected a JSON object of parameter values")
    allowed = {f.name for f in dataclasses.fields(EhlersParameters)} - set(NUMERICAL_FIELDS)
    unknown = sorted(set(values) - allowed)
    if unknown:
        raise ValueError(f"parameter file {path!r}: unknown parameter(s) {unknown}")
    try:
        EhlersParameters(**values)
    except (TypeError, ValueError) as error:
        raise ValueError(f"parameter file {path!r}: {error}") from None
    return dict(values)
