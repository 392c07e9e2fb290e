"""The plug-in interface a finite-element Gauss-point callback calls (no dolfinx here).

``MicroCell`` is the abstract interface any micro-scale engine can implement; ``DemCell``
is the Numba DEM implementation. Conventions (same as the FE side):

* tension positive; (Grad u)_ij = du_i/dX_j; F = I + Grad u; traction t_i = sigma_ij n_j;
* 2D quantities per unit out-of-plane thickness: stresses in N/m;
* tangents are 4x4 matrices, rows (11, 12, 21, 22) of the stress, columns (11, 12, 21, 22)
  of F (001 eq. 11): ``tangent(kind, measure="dsigma_dF")`` gives d sigma_ij / d F_kl
  (= d sigma / d Grad u), ``measure="dP_dF"`` gives d P_ij / d F_kl.

Typical Gauss-point use::

    cells = create_cells(load_packing("pack.npz"), count=n_gauss, law=ContactLaw(...))
    cell.set_deformation(F)              # each Newton iteration
    res = cell.solve()                   # -> SolveResult (converged, flags, message)
    P, C = cell.pk1_stress(), cell.tangent("kruyt", measure="dP_dF")
    cell.commit()                        # once the macro step converged
    cell.rollback()                      # to restart a macro iteration from the last commit
"""
import abc
import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from .contact_law import ContactLaw
from .slots import COH_N, COH_T, ETA_R, MU, ROTATIONS, ROT_MICROPOLAR
from . import checks
from . import quasistatic as qs
from .checks import COUNT, MAX_BUDGET, Range
from .errors import InputError, SolveError
from .homogenization import homogenize
from .options import RelaxationOptions
from .periodic_cell import path_point, path_setup, reduce_cell, substep_count
from .relaxation import MAX_STEPS, NO_CONTACTS, run, stable_time_step
from .state import CellState
from .tangent import (SLIP_RATIO, TANGENT_KINDS, demqo_tangent, dsigma_to_dpk1, floor_stiffness, kruyt_operator,
                      micropolar_tangent, perturbation_tangent, pstlo_operator, tangent_kind)
from . import slots

#: how the grains of a cell rotate: 'free' (rotations follow the contact moments, the macro spin
#: is added: symmetric stress at equilibrium), 'locked' (no grain rotation, 000 section 4.3.2),
#: 'micropolar' (mean rotation held at the imposed phi, curvature kappa as a rotation jump across
#: the periodic images: skew stress and couple stress, docs/reference/micropolar_cell.md)
ROTATION_MODES = ("free", "locked", "micropolar")


@dataclass
class SolveResult:
    """Outcome of ``solve``. converged: every sub-step met the criterion (or the cell has no
    contact left); no_contacts: the cell lost every contact (stress is exactly zero);
    steps: time steps used; substeps: number of sub-steps; message: the cause in words
    (with a warning when overlaps exceed 10 % of a radius); max_overlap_ratio: largest
    overlap / smaller radius met; capped: sub-steps that RelaxationOptions.relax_cap stopped
    before they settled (they count as converged)."""
    converged: bool
    no_contacts: bool
    steps: int
    substeps: int
    message: str
    max_overlap_ratio: float = 0.0
    capped: int = 0


class MicroCell(abc.ABC):
    """What a Gauss point needs from a micro-scale engine (see module docstring)."""

    @abc.abstractmethod
    def set_deformation(self, F): """Target macroscopic deformation gradient (2x2)."""

    def set_displacement_gradient(self, grad_u):
        """Target (Grad u)_ij = du_i/dX_j; F = I + Grad u."""
        self.set_deformation(np.eye(2) + checks.array("grad_u", grad_u, (2, 2)))

    @abc.abstractmethod
    def solve(self): """Bring the cell to quasi-static equilibrium at the target; -> SolveResult."""

    @abc.abstractmethod
    def deformation_gradient(self): """Current F (2x2)."""

    @abc.abstractmethod
    def cauchy_stress(self): """Cauchy stress [N/m] (2x2), tension positive."""

    def pk1_stress(self):
        """First Piola-Kirchhoff stress P = J sigma F^-T (000 eq. 16)."""
        F = self.deformation_gradient()
        return np.linalg.det(F) * self.cauchy_stress() @ np.linalg.inv(F).T

    @abc.abstractmethod
    def couple_stress(self): """(mu_31, mu_32) [N]."""

    @abc.abstractmethod
    def tangent(self, kind="kruyt", measure="dsigma_dF"): """4x4 operator (001 eq. 11 order)."""

    @abc.abstractmethod
    def commit(self): """Remember the current state as the last converged one."""

    @abc.abstractmethod
    def rollback(self): """Return to the last committed state."""

    @abc.abstractmethod
    def copy(self): """Independent deep copy (including the committed state)."""


class DemCell(MicroCell):
    """A periodic DEM cell (see package docs). Create with ``DemCell(state, law, options)`` or
    ``create_cells``. The reference configuration (F = I) is the state it was created from.
    ``rotation_mode``: one of ROTATION_MODES; None = 'free', or 'locked' for a law with
    rotations=False. A 'micropolar' cell takes ``set_deformation(F, rotation=phi,
    curvature=kappa)`` and answers a non-symmetric ``cauchy_stress()``, ``couple_stress()`` and
    ``tangent(kind, measure="micropolar")`` (6x6)."""

    def __init__(self, state, law=None, options=None, reset_reference=True, rotation_mode=None):
        if not isinstance(state, CellState):
            raise InputError("DemCell needs a CellState (e.g. from load_packing or generate_packing)")
        state.check()
        law = ContactLaw() if law is None else law
        if not isinstance(law, ContactLaw):
            raise InputError("law must be a ContactLaw")
        options = relaxation_options(options)
        checks.instance("reset_reference", reset_reference, (bool, np.bool_), "bool")
        if rotation_mode is None:
            rotation_mode = "free" if law.rotations else "locked"
        if rotation_mode not in ROTATION_MODES:
            raise InputError(f"unknown rotation_mode {rotation_mode!r}: one of {', '.join(ROTATION_MODES)}")
        if law.rotations != (rotation_mode != "locked"):
            raise InputError(f"rotation_mode {rotation_mode!r} contradicts ContactLaw(rotations={law.rotations}): "
                             "locked rotations cannot carry a micro-rotation or a curvature" if rotation_mode ==
                             "micropolar" else f"rotation_mode {rotation_mode!r} contradicts "
                             f"ContactLaw(rotations={law.rotations})")
        self.rotation_mode = rotation_mode
        self.state = state
        if reset_reference:
            self.state.h_ref = state.h.copy()
            if rotation_mode == "micropolar":
                self.state.phi = 0.0
                self.state.kappa = np.zeros(2)
        self.law = law
        self.options = options
        self._frozen = False
        self._law_array = self._law_to_array(law)
        self.dt = options.dt if options.dt is not None else stable_time_step(
            state.radius, state.mass, state.inertia, law, options.dt_safety)
        self._check_dt()
        self._target = state.F
        self._target_phi = state.phi
        self._target_kappa = state.kappa.copy()
        self._committed = state.copy()
        self.last_result = None
        self.last_tangent_steps = 0

    @property
    def micropolar(self):
        """True when the cell carries rotation and curvature itself (FEM x DEM mode 'micropolar')."""
        return self.rotation_mode == "micropolar"

    @property
    def law_array(self):
        """The contact law as the kernels read it (contact_law's slots, with the rotation mode
        and a frozen network): a copy."""
        return self._law_array.copy()

    @property
    def target(self):
        """The target of the next solve: (F (2x2), phi [rad], kappa (2,) [1/m]), copies. A cell
        that is not micropolar keeps phi and kappa at those of its state."""
        return self._target.copy(), self._target_phi, self._target_kappa.copy()

    @target.setter
    def target(self, value):
        """Set (F, phi, kappa) as given, without set_deformation's checks: for a store that
        keeps checked targets of its own (batch.CellStore.set_targets)."""
        F, phi, kappa = value
        self._target = np.array(F, dtype=float).reshape(2, 2)
        self._target_phi = float(phi)
        self._target_kappa = np.array(kappa, dtype=float).reshape(2)

    @classmethod
    def view(cls, cell, state, committed=None, target=None):
        """A DemCell with the law, options, time step and rotation mode of `cell` that holds
        `state` as its current state, not copied (views into a batch's store, say), and
        `committed` (default `state`) as its committed one; its target is `target` = (F, phi,
        kappa), default that of `state`. state None: a template without state arrays, which
        a later view gives one (batch.template_of)."""
        new = cls.__new__(cls)
        new.__dict__.update(cell.__dict__)
        new.__dict__.update(state=state, _committed=state if committed is None else committed,
                            _law_array=cell.law_array)
        if target is None:
            target = (np.eye(2), 0.0, np.zeros(2)) if state is None else (state.F, state.phi, state.kappa)
        new.target = target
        return new

    # ----- configuration
    def _law_to_array(self, law, frozen=False):
        a = law.as_array(frozen=frozen)
        if self.rotation_mode == "micropolar":
            a[ROTATIONS] = ROT_MICROPOLAR
        return a

    def _check_dt(self):
        """A user time step above the stability estimate (safety 1) is refused before work."""
        limit = stable_time_step(self.state.radius, self.state.mass, self.state.inertia, self.law, 1.0)
        if self.dt > limit * (1.0 + 1e-12):
            raise InputError(f"time step dt = {self.dt:.3e} s exceeds the stability estimate "
                             f"{limit:.3e} s of this law and packing (2/omega_max, relaxation.stable_time_step); "
                             "use dt=None (automatic) or a smaller dt")

    def set_law(self, law):
        """Change the contact law (e.g. friction after compaction); the time step follows."""
        if not isinstance(law, ContactLaw):
            raise InputError("law must be a ContactLaw")
        if law.rotations != (self.rotation_mode != "locked"):
            raise InputError(f"a cell with rotation_mode {self.rotation_mode!r} needs "
                             f"ContactLaw(rotations={self.rotation_mode != 'locked'})")
        self.law = law
        self._law_array = self._law_to_array(law, frozen=self._frozen)
        if self._frozen:
            self._set_frozen_array()
        if self.options.dt is None:
            self.dt = stable_time_step(self.state.radius, self.state.mass, self.state.inertia,
                                       law, self.options.dt_safety)
        self._check_dt()

    def freeze_contacts(self):
        """Quasi-elastic mode of DEMQO (001 section 5.1): existing contacts persist (bilateral),
        no new contacts, no sliding."""
        self._frozen = True
        self._set_frozen_array()

    def _set_frozen_array(self):
        a = self._law_to_array(self.law, frozen=True)
        a[MU] = math.inf
        a[COH_N] = math.inf
        a[COH_T] = math.inf
        a[ETA_R] = math.inf
        self._law_array = a

    def bond_contacts(self):
        """Give every current contact a cohesive bond (strengths from the ContactLaw)."""
        np_ = self.state.n_pairs
        self.state.bonded[:np_] = self.state.touching[:np_]

    # ----- MicroCell interface
    def set_deformation(self, F, rotation=None, curvature=None):
        """Target F (2x2); for a micropolar cell also the micro-rotation phi [rad] and the
        curvature kappa = grad phi (2,) [1/length of the cell] (None: keep the current target)."""
        F = checks.array("F", F, (2, 2))
        with np.errstate(over="ignore"):        # (an overflow is refused below as det F = inf)
            det = float(np.linalg.det(F))
        if not (det > 0.0 and math.isfinite(det)):
            raise InputError(f"F must have a finite det F > 0 (an admissible deformation), got det F = {det:.3g}")
        if (rotation is not None or curvature is not None) and not self.micropolar:
            if self.rotation_mode == "locked":
                raise InputError("rotations are locked in this cell: a micro-rotation or a curvature cannot be "
                                 "imposed (use rotation_mode='micropolar' with ContactLaw(rotations=True))")
            raise InputError("rotation and curvature need a cell created with rotation_mode='micropolar' "
                             "(this cell's grains rotate freely and its stress is symmetric)")
        if rotation is not None:
            if checks.real(rotation) is None:       # (a string or a bool is no angle)
                raise InputError(f"rotation must be a number [rad], got {checks.one_line(repr(rotation))[:80]}")
            rotation = float(checks.real(rotation))
            if not math.isfinite(rotation):
                raise InputError(f"rotation must be finite, got {rotation!r}")
        if curvature is not None:
            try:
                kappa = np.array(curvature, dtype=float).reshape(-1)
            except (TypeError, ValueError):
                kappa = np.zeros(0)
            if kappa.shape != (2,) or not np.all(np.isfinite(kappa)):
                raise InputError("curvature must be two finite numbers (kappa31, kappa32), got "
                                 f"{checks.one_line(repr(curvature))[:80]}")
            curvature = kappa
            # a rotation jump kappa . Y across the cell beyond 1 rad is no longer a gradient of a
            # small rotation field: refuse it before the cell is torn
            jump = float(np.abs(curvature @ self.state.h_ref).max())
            if jump > 1.0:
                raise InputError(f"curvature {curvature.tolist()} turns the periodic images by {jump:.3g} rad "
                                 "across the cell (> 1 rad): too large for this cell")
        self._target = F
        if rotation is not None:
            self._target_phi = rotation
        if curvature is not None:
            self._target_kappa = curvature

    def deformation_gradient(self):
        return self.state.F

    def solve(self, stress_mask=None, stress_target=None, max_steps=None, max_substep_steps=None):
        """Move the cell to the target F and relax (000 section 3.2.1, 001 eq. 7).

        Mixed control: ``stress_mask`` (2x2 bool) marks components of F that are not imposed
        but adjusted by a servo until the Cauchy stress component equals ``stress_target``
        (2x2, N/m, tension positive); the other components follow the target F.
        Large increments are split in sub-steps of at most ``max_increment``.

        ``max_steps`` bounds the whole solve: the DEM steps of every sub-step, ramps and
        relaxations together (default: the options' ``solve_budget``). When they are spent the
        solve stops where it is and reports not converged, with the reason in the message.
        ``max_substep_steps`` bounds the relaxation of each sub-step after its ramp (default:
        the options' ``max_steps``).
        """
        o = self.options
        mask = None
        total = checks.optional("max_steps", max_steps, COUNT)
        total = o.solve_budget if total is None else min(total, MAX_BUDGET)
        limit = checks.optional("max_substep_steps", max_substep_steps, COUNT)
        limit = o.max_steps if limit is None else min(limit, MAX_BUDGET)
        if stress_mask is not None:
            mask = np.asarray(stress_mask)
            if mask.shape != (2, 2) or mask.dtype != bool:
                raise InputError("stress_mask must be a 2x2 array of booleans, got "
                                 f"{checks.one_line(repr(stress_mask))[:80]}")
            if stress_target is None:
                raise InputError("stress_mask given without stress_target")
            try:
                target = np.asarray(stress_target, dtype=float)
            except (TypeError, ValueError):
                target = np.zeros(0)
            if target.shape != (2, 2) or not np.all(np.isfinite(target[mask])):
                raise InputError(f"stress_target must be a 2x2 array, finite where stress_mask is set, "
                                 f"got {checks.one_line(repr(stress_target))[:80]}")
            stress_target = target
        capped = 0
        if mask is None:
            converged, no_contacts, message, substeps, steps, max_ovl, capped = self._solve_to_target(limit, total)
            msgs = [] if converged else [message]
        else:
            converged, no_contacts, msgs, substeps, steps, max_ovl = self._servo_solve(mask, stress_target, limit,
                                                                                       total)
        no_contacts, msg = qs.final_words(converged, no_contacts, self.contact_count(), msgs, max_ovl)
        self.last_result = SolveResult(converged=converged, no_contacts=no_contacts, steps=steps,
                                       substeps=substeps, message=msg, max_overlap_ratio=max_ovl, capped=capped)
        return self.last_result

    def _servo_solve(self, mask, stress_target, limit, total):
        """Mixed control (stress_mask): sub-steps of the imposed components, each ramped and
        relaxed by relaxation.run with the servo on the others, within `limit` steps after
        each ramp and `total` steps in all. The sub-step targets are made one at a time: a
        huge increment has many more sub-steps than the step budget ever reaches."""
        o = self.options
        F0 = self.state.F
        dF = self._target - F0
        n = max(1, substep_count(np.abs(dF[~mask]).max(initial=0.0) / o.max_increment))

        def linear(k, n=n):
            return F0 + (k / n) * dF
        point = (lambda k: (linear(k), None, None))
        if self.micropolar:
            n, point = self._micropolar_path(n, linear)
        steps = 0
        max_ovl = 0.0
        msgs = []
        no_contacts = False
        converged = True
        for k in range(1, n + 1):
            Fk, phi_k, kappa_k = point(k)
            if not self.micropolar:          # (the curvature's images follow the base cell's lattice)
                reduce_cell(self.state)      # large shears: keep a compact base cell
            size = np.abs(Fk - self.state.F)[~mask].max(initial=0.0)
            if phi_k is not None:
                size = max(size, self.rotation_increment(phi_k, kappa_k))
            n_ramp = substep_count(size / o.strain_rate)
            budget = min(n_ramp + limit, max(total - steps, 0))
            rep = run(self.state, self._law_array, self.dt, Fk, n_ramp, budget, o, stress_mask=mask,
                      stress_target=stress_target, phi_end=phi_k, kappa_end=kappa_k)
            steps += rep.steps
            if rep.status == NO_CONTACTS:
                no_contacts = True
            elif not rep.converged:
                converged = False
                if rep.status == MAX_STEPS and steps >= total:
                    msgs.append(f"sub-step {k} of {n}: " + qs.budget_words(total, rep.steps))
                    break
                ratio = rep.kinetic_energy / max(rep.potential_energy, 1e-300)
                hint = (": the kinetic energy exceeds the elastic energy, the cell is not settling "
                        "(loading too fast for the damping, or an unstable state)") if ratio > 1.0 else ""
                msgs.append(f"sub-step {k} of {n}: {rep.message} after {rep.steps} steps "
                            f"(E_kin/E_pot = {ratio:.2e}, unbalanced ratio {rep.unbalanced_ratio:.2e}){hint}")
                break
            max_ovl = max(max_ovl, rep.max_overlap_ratio)
        return converged, no_contacts, msgs, n, steps, max_ovl

    def _solve_to_target(self, limit, total):
        """The solve without servo: quasistatic.solve_cell (the same compiled function a
        batch.CellBatch runs for many cells) on this cell's arrays."""
        st = self.state
        cellf = np.array([st.time, st.phi, st.kappa[0], st.kappa[1]])
        celli = np.array([st.n_pairs, st.forces_current], dtype=np.int64)
        target = np.empty(slots.N_TARGET)
        target[slots.T_F:slots.T_F + 4] = self._target.reshape(4)
        target[slots.T_PHI] = self._target_phi if self.micropolar else st.phi
        target[slots.T_KAP:slots.T_KAP + 2] = self._target_kappa if self.micropolar else st.kappa
        opts = qs.solve_options(self.options, self.options.skin(st.radius), limit, total)
        work, iwork, result = np.zeros(slots.N_WORK), np.zeros(slots.N_IWORK, dtype=np.int64), np.zeros(slots.N_RESULT)
        while qs.solve_cell(st.radius, st.mass, st.inertia, st.s, st.v, st.theta, st.omega, st.dtheta, st.force,
                            st.moment, st.s_build, st.h, st.h_build, st.h_ref, st.pair_i, st.pair_j, st.fn,
                            st.fs, st.mr, st.bonded, st.touching, st.d_prev, cellf, celli, self._law_array,
                            self.dt, opts, target, work, iwork, result) == qs.NEED_CAPACITY:
            st.grow_pairs(2 * st.pair_i.shape[0])
        st.time, st.phi, st.kappa = float(cellf[0]), float(cellf[1]), cellf[2:4].copy()
        st.n_pairs, st.forces_current = int(celli[0]), int(celli[1])
        converged, no_contacts, message, error = qs.outcome(result, self.dt)
        if error is not None:
            raise SolveError(error)
        return (converged, no_contacts, message, int(result[slots.R_SUBSTEPS]), int(result[slots.R_STEPS]),
                float(result[slots.R_MAXOVL]), int(result[slots.R_CAPPED]))

    def rotation_increment(self, phi, kappa):
        """Size of a change from the current (phi, kappa) to the given ones, measured like a
        strain: |dphi| (the slip it causes at a contact, per unit lever arm) and the largest
        change of the rotation jump across the cell, |dkappa . Y_k| (Y_k of the reference cell)."""
        dk = np.asarray(kappa) - self.state.kappa
        return max(abs(phi - self.state.phi), float(np.abs(dk @ self.state.h_ref).max()))

    def _micropolar_path(self, n, linear):
        """Sub-steps of a micropolar solve: the F path (`n` sub-steps, F of sub-step k:
        linear(k)), refined until each sub-step also changes (phi, kappa) by at most
        max_increment (then along the polar path, periodic_cell.path_setup), with phi and
        kappa linear along it. Returns (number of sub-steps, k -> (F, phi, kappa) of sub-step
        k = 1..n), one sub-step at a time."""
        max_inc = self.options.max_increment
        n_rot = substep_count(self.rotation_increment(self._target_phi, self._target_kappa) / max_inc)
        F_at = linear
        if n_rot > n:
            F1 = np.array(self._target, dtype=float)
            geo = np.empty(10)
            n = path_setup(np.ascontiguousarray(self.state.F), F1, float(max_inc), int(n_rot), geo)

            def polar_point(k, n=n):
                if k == n:
                    return F1.copy()
                Fk = np.empty((2, 2))
                path_point(geo, k / n, Fk)
                return Fk
            F_at = polar_point
        phi0, kap0 = self.state.phi, self.state.kappa.copy()
        phi1, kap1 = self._target_phi, self._target_kappa.copy()

        def point(k):
            if k == n:
                return F_at(k), phi1, kap1.copy()
            return F_at(k), phi0 + (k / n) * (phi1 - phi0), kap0 + (k / n) * (kap1 - kap0)
        return n, point

    def run_dynamics(self, n_steps, damping=0.0):
        """Plain explicit dynamics for n_steps at fixed F (no convergence test), e.g. for a
        collision or an energy-conservation check. Returns the RunReport."""
        n_steps = checks.number("n_steps", n_steps, Range(0, MAX_BUDGET, integer=True))
        damping = checks.number("damping", damping, Range(0.0, 1.0, high_open=True))
        # plain local damping: the options' method would mix FIRE into the dynamics
        options = dataclasses.replace(self.options, damping=damping, method="local")
        return run(self.state, self._law_array, self.dt, self.state.F, 0, n_steps, options, check=False)

    def homogenized(self):
        """All homogenized outputs (``homogenization.Homogenized``)."""
        return homogenize(self.state, self._law_array, micropolar=self.micropolar)

    def cauchy_stress(self):
        return self.homogenized().cauchy

    def couple_stress(self):
        return self.homogenized().couple_stress

    def contact_count(self):
        n = self.state.n_pairs
        return int(np.count_nonzero(self.state.touching[:n]))

    def tangent(self, kind="kruyt", measure="dsigma_dF", eps=None):
        """Tangent operator, 4x4 in the order of 001 eq. 11.
        kind: a name of tangent.TANGENT_KINDS, whose entries say what each computes and for
        which cells: 'kruyt' (001 eq. 13, closed form), 'demqo' (001 eq. 20, 4 frozen-contact
        relaxations), 'pstlo' (001 appendix B, one sparse solve of the same linearized
        problem), 'pstlo_sliding' (the same with the contacts near their Coulomb limit sliding:
        tangent.SLIP_RATIO; floored: tangent.floor_stiffness), 'perturbation' (CTO, 001 eq. 6,
        4 full solves from the last commit).
        measure: 'dsigma_dF' (d sigma_ij/dF_kl = d sigma/d Grad u) or 'dP_dF'; for a micropolar
        cell also 'micropolar': the 6x6 d(sigma, m)/d(F, kappa) at fixed phi in the FE callback's
        order (rows sigma11, sigma22, sigma12, sigma21, m31, m32; columns eps11, eps22, eps12,
        eps21, kappa31, kappa32), kinds 'perturbation', 'demqo' (6 perturbations), 'pstlo' (the
        frozen network solved exactly, demcell/network.py) and 'kruyt' (uniform strain and
        rotation field: the assumption of 003 eqs 21-24)."""
        if not isinstance(measure, str) or measure not in ("dsigma_dF", "dP_dF", "micropolar"):
            raise InputError(f"unknown tangent measure {measure!r}: 'dsigma_dF', 'dP_dF' or 'micropolar'")
        kind = tangent_kind(kind, micropolar=measure == "micropolar").name
        # a perturbation beyond 0.1 of F is no derivative any more
        eps = checks.optional("eps", eps, Range(0.0, 0.1, low_open=True))
        if measure == "micropolar":
            if not self.micropolar:
                raise InputError("measure='micropolar' needs a cell created with rotation_mode='micropolar'")
            C, results = micropolar_tangent(self, kind, eps)
            self.last_tangent_steps = sum(r.steps for r in results)
            return C
        results = []
        eps = TANGENT_KINDS[kind].default_eps if eps is None else eps
        if kind == "kruyt":
            C = kruyt_operator(self.state, self._law_array)
        elif kind == "demqo":
            C, results = demqo_tangent(self, eps)
        elif kind == "perturbation":
            C, results = perturbation_tangent(self, eps)
        elif kind == "pstlo":
            C = pstlo_operator(self.state, self._law_array)
        else:
            C = floor_stiffness(pstlo_operator(self.state, self._law_array, slip_ratio=SLIP_RATIO))
        self.last_tangent_steps = sum(r.steps for r in results)   # DEM steps of its relaxations
        if measure == "dP_dF":
            C = dsigma_to_dpk1(C, self.state.F, self.cauchy_stress())
        return C

    def commit(self):
        self._committed = self.state.copy()

    def rollback(self):
        self.state = self._committed.copy()
        self.target = (self.state.F, self.state.phi, self.state.kappa)

    @property
    def committed_state(self):
        """The last committed CellState (what a checkpoint saves; do not modify)."""
        return self._committed

    def restore(self, committed):
        """Make `committed` (a CellState, e.g. read back from a checkpoint) the committed
        state and roll back to it: the cell continues as the one it was saved from."""
        if not isinstance(committed, CellState):
            raise InputError("restore needs a CellState")
        if committed.n_particles != self._committed.n_particles:
            raise InputError(f"restore: a state of {committed.n_particles} particles for a cell of "
                             f"{self._committed.n_particles}")
        self._committed = committed
        self.rollback()

    def copy(self):
        return DemCell.view(self, self.state.copy(), self._committed.copy(), self.target)

    def memory_bytes(self):
        """Bytes held by the current and the committed state arrays."""
        return self.state.nbytes() + self._committed.nbytes()


def relaxation_options(options):
    """`options` as RelaxationOptions: None (the defaults), a RelaxationOptions or a dict of
    them; anything else is refused."""
    if options is None:
        return RelaxationOptions()
    if isinstance(options, dict):
        return RelaxationOptions.from_kwargs(**options)
    return checks.instance("options", options, RelaxationOptions, "RelaxationOptions (or a dict of them)")


def create_cells(state, count=1, law=None, options=None):
    """``count`` independent DemCells starting from the same packing state."""
    checks.instance("state", state, CellState, "CellState (e.g. from load_packing or generate_packing)")
    count = checks.number("count", count, COUNT)
    return [DemCell(state.copy(), law, options) for _ in range(count)]
