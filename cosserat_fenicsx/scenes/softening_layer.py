"""Softening shear layer: the one-dimensional localisation test of Cosserat plasticity.

An infinitely long layer of height L (the classical localisation benchmark, de Borst 1993,
Comput. Methods Appl. Mech. Eng. 103, 347-362, section "infinitely long shear layer") is
consolidated isotropically to the confining pressure p and then sheared: the top moves
horizontally by U(t) while it carries the normal traction -p; the bottom is fixed; the
rotation is free at both faces (zero couple traction). Everything depends on y only, so
the micropolar balances (3.4), (3.5) reduce to

    sigma12' = 0,   sigma22' = 0,   m32' + sigma12 - sigma21 = 0,

with the strain of eq 2.49, eps12 = u1' + phi, eps21 = -phi, eps22 = u2', kappa32 = phi'
(eps11 = kappa31 = 0). A weakened zone of thickness `weak_size` at mid-height (beta0,
beta* x down to `weak_beta_factor` at the centre, a tent profile) triggers the band.

Why it is here: it isolates the regularisation question of issue 3 item 6 from the
biaxial geometry and is cheap enough to resolve h << l_c. The discretisation is the one of
the FE solver (P2 displacement, P1 rotation, 3 Gauss points per element, consistent
tangent, Newton with cut-back) written directly in numpy/scipy: no dolfinx, so it is also
an independent check of the assembly. The band thickness is H of the section 4.4 fit
(`shear_band.fit_band`, standard deviation of the bell) to the norm of the total strain.

Units: SI (m, Pa, N/m). Shear stress tau = sigma12 (constant through the layer) is the
top reaction per unit length.
"""
from __future__ import annotations

from dataclasses import dataclass, field
import math

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from types import SimpleNamespace

from ..constitutive import ConstitutiveError
from ..materials.ehlers import EhlersMaterial
from ..shear_band import fit_band, strain_norm
from ..stepping import LoadStepper
from ..validation import COUNT, FRACTION, NON_NEGATIVE, POSITIVE, STEPS, check_settings, setting

# 3-point Gauss-Legendre on [-1, 1]: exact for the P2 x P2 stiffness (and as the 2D forms)
_XI = np.array([-math.sqrt(0.6), 0.0, math.sqrt(0.6)])
_W = np.array([5.0, 8.0, 5.0]) / 9.0


@dataclass
class LayerSettings:
    """The layer, its loading and the solver's limits; each field declares its range
    (validation.setting)."""
    height: float = setting(0.1, POSITIVE)          # L [m]
    cell_size: float = setting(1.0e-3, POSITIVE)    # h [m]
    confining: float = setting(100e3, POSITIVE)     # p [Pa]
    shear: float = setting(0.1, POSITIVE)           # U_end / L [-]
    steps: int = setting(100, STEPS)                # nominal steps of the shear phase
    micropolar: bool = setting(True)
    weak_size: float = setting(4.0e-3, NON_NEGATIVE)    # base of the tent-shaped weakening at mid-height [m]
    weak_beta_factor: float = setting(0.9, FRACTION)    # beta0, beta* factor at the centre of the tent
    eta: float = setting(0.1, POSITIVE)             # Perzyna time [s]; one nominal step is 1 s
    material: dict = field(default_factory=dict)   # EhlersMaterial keyword overrides
    max_iterations: int = setting(25, COUNT)
    tolerance: float = setting(1e-8, POSITIVE)      # residual relative to the first one of the step (floor 1e-9 p sqrt(ndof))
    min_step: float = setting(2.0 ** -12, FRACTION)  # smallest step after cut-backs, in nominal steps

    def check(self):
        check_settings(self, "softening layer")
        if self.cell_size > self.height / 4:
            raise ValueError("softening layer: cell_size must be <= height / 4")
        if not self.weak_size < self.height:
            raise ValueError(f"softening layer: weak_size must be in [0, height), got {self.weak_size!r}")


class SofteningLayer:
    """P2/P1 finite elements on [0, L] with the Ehlers model at the Gauss points."""

    def __init__(self, settings: LayerSettings):
        s = self.s = settings
        s.check()
        n = self.n_cells = int(round(s.height / s.cell_size))
        h = self.h = s.height / n
        self.nu = 2 * n + 1                       # P2 nodes
        self.nphi = n + 1 if s.micropolar else 0  # P1 nodes
        self.ndof = 2 * self.nu + self.nphi
        # Gauss points, weights and B matrices (6 x 8 per point: dofs u1[3], u2[3], phi[2])
        y0 = np.arange(n) * h
        self.y = (y0[:, None] + 0.5 * h * (1.0 + _XI[None, :])).ravel()
        self.weight = np.tile(_W * 0.5 * h, n)
        dN = np.stack([_XI - 0.5, -2.0 * _XI, _XI + 0.5], axis=1) * (2.0 / h)   # dP2/dy
        L = np.stack([(1 - _XI) / 2, (1 + _XI) / 2], axis=1)                  # P1
        dL = np.array([-1.0, 1.0]) / h
        B = np.zeros((3, 6, 8))
        if s.micropolar:
            B[:, 2, 0:3] = dN            # eps12 = u1' + phi
            B[:, 2, 6:8] = L
            B[:, 3, 6:8] = -L            # eps21 = -phi
            B[:, 5, 6:8] = dL            # kappa32 = phi'
        else:
            B[:, 2, 0:3] = 0.5 * dN      # classical: eps12 = eps21 = u1' / 2
            B[:, 3, 0:3] = 0.5 * dN
        B[:, 1, 3:6] = dN                # eps22 = u2'
        self.B = B
        e = np.arange(n)
        u_nodes = np.stack([2 * e, 2 * e + 1, 2 * e + 2], axis=1)
        cols = [u_nodes, self.nu + u_nodes]
        if s.micropolar:
            cols.append(2 * self.nu + np.stack([e, e + 1], axis=1))
        else:
            cols.append(np.zeros((n, 2), dtype=int))   # unused (B columns are zero)
        self.dofs = np.concatenate(cols, axis=1)        # (n, 8)
        self.top_u1 = 2 * n
        self.top_u2 = self.nu + 2 * n
        self.fixed = np.array([0, self.nu, self.top_u1])   # bottom u1, u2; top u1 (driven)
        self.free = np.setdiff1d(np.arange(self.ndof), self.fixed)
        # materials: beta0, beta* scaled by a tent profile, weakest at mid-height (one
        # material per distinct factor). A tent, not a step: in a classical layer every
        # point of an equally weak zone softens together, so a step imperfection would set
        # the classical band width; with a tent the weakest Gauss points set it.
        base = dict(s.material, eta=s.eta, micropolar=s.micropolar)
        weak = 1.0 - (1.0 - s.weak_beta_factor) * np.clip(
            1.0 - np.abs(self.y - 0.5 * s.height) / (0.5 * s.weak_size + 1e-300), 0.0, 1.0)
        p = EhlersMaterial.hostun(**base).parameters
        self.materials, self.zones = [], []
        for factor in np.unique(np.round(weak, 12))[::-1]:
            idx = np.flatnonzero(np.abs(weak - factor) < 1e-11)
            self.materials.append(EhlersMaterial.hostun(**dict(base, beta0=p.beta0 * factor,
                                                               beta_star=p.beta_star * factor)))
            self.zones.append(idx)
        npts = self.y.size
        self.state = np.empty((npts, EhlersMaterial.state_size))
        for m, idx in zip(self.materials, self.zones):
            self.state[idx] = m.initial_stress_state(-s.confining, idx.size)
        self.x = np.zeros(self.ndof)
        self.flux = np.zeros((npts, 6))
        self.tangent = np.zeros((npts, 6, 6))
        self.state_new = self.state.copy()
        self._last_increment = None
        self._trial = None          # converged x of the current step, until commit
        self._t, self._U, self._dt, self._its = 0.0, 0.0, 1.0, 0
        self.history = []

    # --------------------------------------------------------------------------------
    def gradients(self, x):
        xe = x[self.dofs]                                       # (n, 8)
        g = np.einsum("qij,ej->eqi", self.B, xe).reshape(-1, 6)
        return g

    def _evaluate(self, x, dt):
        g = self.gradients(x)
        for m, idx in zip(self.materials, self.zones):
            f, c, st = np.empty((idx.size, 6)), np.empty((idx.size, 6, 6)), np.empty((idx.size, self.state.shape[1]))
            m.update(g[idx], dt, self.state[idx], f, c, st)
            self.flux[idx], self.tangent[idx], self.state_new[idx] = f, c, st
        n = self.n_cells
        w = self.weight.reshape(n, 3)
        flux = self.flux.reshape(n, 3, 6)
        tan = self.tangent.reshape(n, 3, 6, 6)
        fe = np.einsum("eq,qia,eqi->ea", w, self.B, flux)
        ke = np.einsum("eq,qia,eqij,qjb->eab", w, self.B, tan, self.B)
        r = np.zeros(self.ndof)
        np.add.at(r, self.dofs, fe)
        r[self.top_u2] += self.s.confining          # top traction t2 = -p (external)
        rows = np.repeat(self.dofs, 8, axis=1).ravel()
        cols = np.tile(self.dofs, (1, 8)).ravel()
        K = sp.csr_matrix((ke.ravel(), (rows, cols)), shape=(self.ndof, self.ndof))
        return r, K

    def tau(self):
        """Shear stress sigma12 [Pa] (mean over the points; it is constant to the tolerance)."""
        return float(np.average(self.flux[:, 2], weights=self.weight))

    def predictor(self, U):
        """Start of the Newton iteration for the top displacement U: the last converged
        increment scaled to the new one (the first step: simple shear u1 = U y / L). Moving
        only the top node would put the whole increment into the top element."""
        x = self.x.copy()
        dU = U - x[self.top_u1]
        if self._last_increment is None:
            nodes = np.linspace(0.0, self.s.height, self.nu)
            x[:self.nu] += dU * nodes / self.s.height
        else:
            x += self._last_increment * (dU / self._last_increment[self.top_u1])
        x[self.top_u1] = U
        return x

    def solve_step(self, U, dt):
        x = self.predictor(U)
        r0 = None
        for it in range(self.s.max_iterations + 1):
            r, K = self._evaluate(x, dt)
            norm = float(np.linalg.norm(r[self.free]))
            if not np.isfinite(norm):
                raise ConstitutiveError("non-finite residual")
            if r0 is None:
                r0 = norm
            # absolute floor: a nodal residual is a stress (Pa) for u and ~ stress x h for phi;
            # the local Newton of the kernel leaves ~1e-10 p of noise per entry (measured)
            if norm <= max(self.s.tolerance * r0, 1e-9 * self.s.confining * math.sqrt(self.ndof)):
                return x, it
            if it == self.s.max_iterations:
                break
            Kff = K[self.free][:, self.free].tocsc()
            x[self.free] -= spla.spsolve(Kff, r[self.free])
        raise ConstitutiveError(f"Newton did not converge in {self.s.max_iterations} iterations")

    # the interface LoadStepper drives (stepping.py): time = nominal steps of the shear
    def set_time(self, t):
        self._t = t
        self._U = self.s.shear * self.s.height * t / self.s.steps

    def set_time_step(self, dt):
        self._dt = dt

    def solve(self):
        """One step to the current U with Newton; the record LoadStepper reads."""
        try:
            self._trial, self._its = self.solve_step(self._U, self._dt)
        except ConstitutiveError as error:
            return SimpleNamespace(converged=False, failure=str(error), reason=None, iterations=0, residual=np.nan)
        return SimpleNamespace(converged=True, failure=None, reason=None, iterations=self._its, residual=0.0)

    def rollback(self):
        self._trial = None          # x, state are only replaced at commit

    def commit(self, dt):
        x = self._trial
        self._last_increment = x - self.x
        self.x = x
        self.state, self.state_new = self.state_new.copy(), self.state_new
        self.history.append({"time": self._t, "shear": x[self.top_u1] / self.s.height, "tau": self.tau(),
                             "iterations": self._its})

    def run(self):
        """Shear to U_end = shear * L with the project's LoadStepper (cut-back on a failed point
        update or Newton, growth after <= 6 iterations); returns the history rows. Raises
        LoadSteppingError naming the cause when the step falls below min_step."""
        LoadStepper(self, self, t_end=self.s.steps, dt=1.0, dt_min=self.s.min_step, dt_max=1.0,
                    easy_iterations=6, verbose=False).run()
        return self.history

    def strain_norm(self):
        """|eps| of the total non-symmetric strain at the Gauss points (section 4.4)."""
        g = self.gradients(self.x)
        return strain_norm(g)

    def band(self):
        """Section 4.4 fit to the final strain norm. The layer is a band parallel to x, so the
        points are laid on two columns far apart (x = 0 and x = 10 L), which pins the
        inclination to 0; H is the standard deviation of the bell [m]."""
        e = self.strain_norm()
        L = self.s.height
        pts = np.concatenate([np.column_stack([np.zeros_like(self.y), self.y]),
                              np.column_stack([np.full_like(self.y, 10 * L), self.y])])
        return fit_band(pts, np.concatenate([e, e]))
