"""Which Ehlers parameters an identification varies: names, bounds, scales, constraints.

Parameters are chosen by their EhlersParameters field names (SI units: Pa, m); the others
keep the values of a base set.  Groups of the stepwise identification (thesis 4.3, 6.1):

* ELASTIC (4.19): mu, lmbda, n_max (n0 is measured, not identified);
* PLASTIC_HOMOGENEOUS (6.2): the 14 parameters of the non-polar plasticity;
* INITIAL: beta0, delta0, epsilon0, gamma0 (Table 6.4 marks beta0 "assumed");
* MICROPOLAR (4.21): l_c, mu_c, k_sigma, k_mu (identified from inhomogeneous tests only).

Constraints g(s) >= 0 of (4.2) besides the bounds: the compression point exists (2.70:
n_max > n0, else eps_crit >= 0), a positive bulk modulus (lmbda + 2 mu / 3 > 0) and the
convexity limit gamma <= 1.75 of the deviatoric section (2.77, spec 10.5).  The optimiser
works on s_k / scale_k (scale = |start| or the parameter's typical size), so that all
variables are of order one.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..materials.ehlers.parameters import GAMMA_CONVEX_LIMIT, EhlersParameters
from ..validation import InputError

ELASTIC = ("mu", "lmbda", "n_max")
PLASTIC_HOMOGENEOUS = ("C_beta_D", "C_beta_V", "beta_star", "C_delta_D", "C_delta_V", "delta_star",
                       "C_epsilon_D", "C_epsilon_V", "epsilon_star", "C_gamma_D", "C_gamma_V", "gamma_star",
                       "psi1", "psi2")
INITIAL = ("beta0", "delta0", "epsilon0", "gamma0")
MICROPOLAR = ("l_c", "mu_c", "k_sigma", "k_mu")
GROUPS = {"elastic": ELASTIC, "plastic": PLASTIC_HOMOGENEOUS, "initial": INITIAL, "micropolar": MICROPOLAR}

#: default bounds (SI) and typical sizes (scales when the start value is 0)
_C = (-1000.0, 1000.0)
DEFAULT_BOUNDS = {
    "mu": (1e5, 1e11), "lmbda": (0.0, 1e11), "n_max": (1e-3, 0.999), "n0": (1e-3, 0.999),   # lmbda >= 0: nu >= 0
    "C_beta_D": _C, "C_beta_V": _C, "C_delta_D": _C, "C_delta_V": _C, "C_epsilon_D": _C, "C_epsilon_V": _C,
    "C_gamma_D": _C, "C_gamma_V": _C,
    "beta_star": (0.0, 3.0), "beta0": (0.0, 3.0),
    "delta_star": (1e3, 1e10), "delta0": (1e3, 1e10), "epsilon_star": (1e3, 1e10), "epsilon0": (1e3, 1e10),
    "gamma_star": (1e-2, GAMMA_CONVEX_LIMIT), "gamma0": (1e-2, GAMMA_CONVEX_LIMIT),
    "psi1": (1e-3, 50.0), "psi2": (0.0, 10.0),
    "l_c": (0.0, 1.0), "mu_c": (0.0, 1e11), "k_sigma": (0.0, 1e3), "k_mu": (0.0, 1e9),
}
TYPICAL = {"mu": 1e8, "lmbda": 1e8, "l_c": 1e-3, "mu_c": 1e8, "k_sigma": 1.0, "k_mu": 1e3, "psi2": 1.0,
           "beta0": 0.1, "beta_star": 0.1}


def _constraints(values):
    """Named constraints g >= 0 (4.2) on a dict of all parameter values."""
    return {
        "compression point exists: n_max - n0 > 0 (2.70)": values["n_max"] - values["n0"] - 1e-6,
        "bulk modulus lmbda + 2 mu/3 > 0": (values["lmbda"] + 2.0 * values["mu"] / 3.0) / 1e6,
    }


_CONSTRAINT_NAMES = {"compression point exists: n_max - n0 > 0 (2.70)": ("n_max", "n0"),
                     "bulk modulus lmbda + 2 mu/3 > 0": ("mu", "lmbda")}


def expand(names):
    """The parameter names with the groups (GROUPS) expanded, in order, without repeats."""
    out = []
    for n in names:
        for m in GROUPS.get(n, (n,)):
            if m not in out:
                out.append(m)
    return tuple(out)


@dataclasses.dataclass
class ParameterSet:
    """names: identified parameters; base: EhlersParameters with the values of all others and
    the start of the identified ones; bounds: {name: (lo, hi)} overriding DEFAULT_BOUNDS."""

    names: tuple
    base: EhlersParameters
    bounds: dict = dataclasses.field(default_factory=dict)

    def __post_init__(self):
        fields = {f.name: f for f in dataclasses.fields(EhlersParameters)}
        numeric = sorted(n for n in DEFAULT_BOUNDS)
        self.names = expand(self.names)
        if not self.names:
            raise InputError("identification: no parameters named")
        for n in self.names:
            if n not in fields or n not in DEFAULT_BOUNDS:
                raise InputError(f"identification: {n!r} is not an identifiable Ehlers parameter; "
                                 f"valid: {numeric} or a group {sorted(GROUPS)}")
        for n in self.bounds:
            if n not in self.names:
                raise InputError(f"identification: bounds given for {n!r}, which is not identified "
                                 f"(identified: {list(self.names)})")
        self.lower = np.array([self._bound(n)[0] for n in self.names])
        self.upper = np.array([self._bound(n)[1] for n in self.names])
        self._constraints_as_bounds()
        start = self.start
        for n, lo, hi, v in zip(self.names, self.lower, self.upper, start):
            if not lo < hi:
                raise InputError(f"identification: bounds of {n!r} are empty: [{lo:g}, {hi:g}]")
            if not lo <= v <= hi:
                raise InputError(f"identification: the start value {n} = {v:g} lies outside its bounds "
                                 f"[{lo:g}, {hi:g}]")
        for cname, g in self.constraint_values(start).items():
            if not g >= 0:
                raise InputError(f"identification: the start violates the constraint '{cname}' "
                                 f"(value {g:g})")
        self.scale = np.array([abs(v) if v != 0 else TYPICAL.get(n, 1.0) for n, v in zip(self.names, start)])

    @classmethod
    def for_stage(cls, names, base, bounds):
        """The set of one stage of a stepwise identification: of `bounds` (given for all
        stages) it takes those of its own parameters."""
        own = expand(names)
        return cls(own, base, {n: b for n, b in bounds.items() if n in own})

    def _constraints_as_bounds(self):
        """A constraint with one identified parameter is a bound on it (so that a bounds-only
        solver can run); only those with several identified parameters stay constraints."""
        b = self.base
        one = {"n_max": ("n0", lambda: (b.n0 + 1e-6, None)), "n0": ("n_max", lambda: (None, b.n_max - 1e-6)),
               "lmbda": ("mu", lambda: (-2.0 * b.mu / 3.0 + 1e3, None)),
               "mu": ("lmbda", lambda: (-1.5 * b.lmbda + 1e3, None))}
        for k, n in enumerate(self.names):
            if n in one and one[n][0] not in self.names:
                lo, hi = one[n][1]()
                if lo is not None:
                    self.lower[k] = max(self.lower[k], lo)
                if hi is not None:
                    self.upper[k] = min(self.upper[k], hi)

    def _bound(self, n):
        lo, hi = self.bounds.get(n, DEFAULT_BOUNDS[n])
        lo = -math.inf if lo is None else float(lo)
        hi = math.inf if hi is None else float(hi)
        return lo, hi

    @property
    def start(self):
        return np.array([float(getattr(self.base, n)) for n in self.names])

    def parameters(self, s):
        """EhlersParameters with the identified values s (SI) and the base's other values.
        Out-of-range sets raise ValueError from EhlersParameters (the optimiser keeps to the
        bounds, so this names a bound that is too wide)."""
        values = self.base.as_dict()   # mu_c is a number here: varying mu does not move it
        for n, v in zip(self.names, s):
            values[n] = float(v)
        return EhlersParameters(**values)

    def values(self, s):
        return {n: float(v) for n, v in zip(self.names, s)}

    def constraint_values(self, s):
        """The constraints between identified parameters at s (those on one identified
        parameter are bounds, see _constraints_as_bounds)."""
        values = self.base.as_dict()
        values.update(self.values(s))
        out = {}
        for cname, g in _constraints(values).items():
            if all(n in self.names for n in _CONSTRAINT_NAMES[cname]) and not self._implied(cname):
                out[cname] = float(g)
        return out

    def _implied(self, cname):
        """True when the bounds already enforce the constraint (then a bounds-only solver runs)."""
        lo = dict(zip(self.names, self.lower))
        hi = dict(zip(self.names, self.upper))
        if cname.startswith("bulk"):
            return lo["lmbda"] >= 0.0 and lo["mu"] > 0.0
        return lo["n_max"] > hi["n0"]

    def to_scaled(self, s):
        return np.asarray(s, dtype=float) / self.scale

    def from_scaled(self, z):
        return np.asarray(z, dtype=float) * self.scale
