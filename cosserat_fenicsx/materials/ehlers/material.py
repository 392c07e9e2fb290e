"""The Ehlers model as a Gauss-point material of the FE side (no dolfinx import).

Contract (constitutive.Constitutive): per Gauss point

* gradients [eps11, eps22, eps12, eps21, kappa31, kappa32]; eps_ij = u_i,j + e_ij3 phi
  (eps12 = u1,2 + phi, eps21 = u2,1 - phi, eq. 2.49), kappa3j = phi_,j [1/m] (2.52);
  plane strain: total eps33 = 0 (A.4);
* flux [sig11, sig22, sig12, sig21, m31, m32] in Pa and N/m, tension positive,
  t_i = sig_ij n_j; sig33 is stored in the state;
* tangent d flux / d gradient: consistent (algorithmic) tangent, eqs (3.36)-(3.38).
"""

from __future__ import annotations

import numpy as np

from ...constitutive import Constitutive
from .errors import STATUS_MESSAGES, MaterialPointError
from .local_solver import (S_BETA, S_DELTA, S_EPSILON, S_GAMMA, STATE_NAMES, STATE_SIZE,
                           update_batch)
from .parameters import EhlersParameters


class EhlersMaterial(Constitutive):
    """Micropolar Ehlers single-surface elasto-viscoplastic model (Scholz 2007, ch. 2-3).

    Elasticity (2.70)-(2.74) with the compression point, yield function (2.76)/(2.77),
    potential (2.78), flow (2.79), Perzyna (2.81), hardening/softening (2.82) under
    reading H1 of the spec (Table 6.4 delta, epsilon are Ehlers' original parameters,
    the thesis uses their reciprocals; uniform sign in 2.82; see docs/reference/ehlers.md),
    solved per point as the system of Table 3.1.

    Parameters are SI keyword arguments, see :class:`EhlersParameters` (defaults:
    Hostun sand, Tables 6.1/6.4, l_c = 3 mm, mu_c = mu, k_sigma = 10, k_mu = 0).
    ``micropolar=False`` switches the micropolar terms off (classical continuum).
    """

    gradient_size = 6
    flux_size = 6
    state_size = STATE_SIZE
    state_names = STATE_NAMES
    #: column of each history variable, e.g. state[:, EhlersMaterial.state_index["yield_function"]]
    state_index = {name: i for i, name in enumerate(STATE_NAMES)}

    def __init__(self, **params):
        self.parameters = EhlersParameters.from_kwargs(**params)
        self._params = self.parameters.to_array()

    @classmethod
    def hostun(cls, **overrides):
        """Hostun sand (Tables 6.1, 6.4 under H1; spec section 6 micropolar defaults)."""
        return cls(**overrides)

    def __repr__(self):
        p = self.parameters
        return (f"EhlersMaterial(mu={p.mu:.4g}, lmbda={p.lmbda:.4g}, mu_c={p.mu_c:.4g}, "
                f"l_c={p.l_c:.4g}, micropolar={p.micropolar}, eta={p.eta:.3g})")

    @property
    def params_array(self):
        """Copy of the float64 parameter vector (internal units) passed to the kernel."""
        return self._params.copy()

    # ------------------------------------------------------------------ state
    def initial_state(self, n_points) -> np.ndarray:
        """Virgin history: no plastic strain, hardening variables at p0 (2.82), zero stress."""
        st = np.zeros((int(n_points), STATE_SIZE))
        p = self.parameters
        st[:, S_BETA] = p.beta0
        st[:, S_DELTA] = p.delta0
        st[:, S_EPSILON] = p.epsilon0
        st[:, S_GAMMA] = p.gamma0
        return st

    def initial_stress_state(self, sigma0, n_points, n_steps=40):
        """History of a point consolidated to the diagonal stress ``sigma0`` at zero strain.

        sigma0: scalar (isotropic, e.g. -100e3 Pa) or (sig11, sig22, sig33) [Pa],
        compression negative.  The consolidation is integrated at one material point
        (stress-controlled, hardening included, see material_point.consolidate) and the
        resulting strain is then moved into the reference configuration: the plastic
        strain is shifted so that the returned state reproduces sigma0 at zero total
        strain (FE displacement u = 0).  Returns (n_points, state_size).
        """
        from .material_point import consolidate_state
        row = consolidate_state(self, sigma0, n_steps=n_steps)
        return np.tile(row, (int(n_points), 1))

    # ----------------------------------------------------------------- update
    def update(self, gradients, dt, state_old, flux_out, tangent_out, state_new, points=None) -> None:
        """Update the rows `points` (None: all points): see module docstring for layouts
        and units.

        Pure: depends only on the arguments (state_old is read-only).  Raises
        MaterialPointError naming the cause and the first failing point (counted among
        the rows updated) when the local problem has no acceptable solution after
        substepping; ValueError on bad input.
        """
        if points is None:
            self._run(gradients, dt, state_old, flux_out, tangent_out, state_new, 6)
            return
        points = np.asarray(points, dtype=np.int64)
        flux, tangent, state = flux_out[points], tangent_out[points], state_new[points]
        self._run(gradients[points], dt, state_old[points], flux, tangent, state, 6)
        flux_out[points], tangent_out[points], state_new[points] = flux, tangent, state

    def update_generalised(self, strain7, dt, state_old, flux_out, tangent_out, state_new):
        """Same as update with 7 components [eps11, eps22, eps33, eps12, eps21, kappa31, kappa32]
        (total eps33 free): used by the material-point driver (triaxial tests)."""
        self._run(strain7, dt, state_old, flux_out, tangent_out, state_new, 7)

    def _run(self, grad, dt, state_old, flux_out, tangent_out, state_new, k):
        dt = float(dt)
        if not np.isfinite(dt) or dt < 0.0 or (dt == 0.0 and self.parameters.eta > 0.0):
            raise ValueError(f"time increment dt must be > 0 (Perzyna 2.81 with eta > 0), got {dt!r}")
        grad = np.ascontiguousarray(grad, dtype=np.float64)
        state_old = np.ascontiguousarray(state_old, dtype=np.float64)
        if grad.ndim != 2 or grad.shape[1] != k:
            raise ValueError(f"gradients must have shape (n, {k}), got {grad.shape}")
        n = grad.shape[0]
        if state_old.shape != (n, STATE_SIZE):
            raise ValueError(f"state_old must have shape ({n}, {STATE_SIZE}), got {state_old.shape}")
        for name, arr, shape in (("flux_out", flux_out, (n, k)), ("tangent_out", tangent_out, (n, k, k)),
                                 ("state_new", state_new, (n, STATE_SIZE))):
            if not isinstance(arr, np.ndarray) or arr.shape != shape or arr.dtype != np.float64:
                raise ValueError(f"{name} must be a float64 array of shape {shape}")
        if state_new is state_old or np.may_share_memory(state_new, state_old):
            raise ValueError("state_new must not share memory with state_old (the update is pure)")
        outs = [flux_out, tangent_out, state_new]
        work = [a if a.flags.c_contiguous else np.empty(a.shape) for a in outs]
        status = np.zeros(n, dtype=np.int32)
        if n:
            update_batch(grad, dt, state_old, self._params, work[0], work[1], work[2], status)
        for a, w in zip(outs, work):
            if a is not w:
                a[...] = w
        bad = np.flatnonzero(status)
        if bad.size:
            i = int(bad[0])
            code = int(status[i])
            msg = STATUS_MESSAGES.get(code, f"status {code}")
            raise MaterialPointError(
                f"Ehlers update failed at point {i}: {msg} ({bad.size} of {n} points failed)",
                codes=status, point=i)
