"""``FrameCell``: paper 000's micro boundary conditions, a frame of boundary particles driven by
a servo, behind the same interface as the periodic DemCell (interface.MicroCell).

A periodic cell cut open (cut.py) is a bounded assembly of discs run by the specimen engine
(demcell.specimen: the same contact law, cell-list contacts, force loop and leapfrog with
local damping), whose frame copies are held (Specimen.hold: prescribed motion). A solve to a
target F follows 000 Table 2:

1. the frame moves homogeneously with the new F, x_q <- x_q + (F - F_old) X_q, in a loading
   ramp (the frame copies move at constant velocity; at most strain_rate change of F per
   step, as the periodic cell's ramp, 001 eq. 7); their fluctuations and rotations of the
   previous converged increment are kept ("this correction is added to the displacement
   and rotation calculated at the previously converged increment", 000 section 3.2.2; Table
   2 step 1 prints x_q = F X_q, theta_q = 0);
2. dynamic relaxation of the inner discs with local damping while the frame is held, until
   E_kin / E_pot <= tol (000 eqs 31-32; rattlers without contact left out) or the
   unbalanced-force ratio (001) per the relaxation options;
3. the frame's reactions a_q, m_q (eq. 9), the residuals of the edge pairs and corners (eqs 33,
   36) and r_a (Table 2 step 5, servo.residual); r_a <= eps_a: done (eq. 37);
4. corrections Delta u = -g_a Delta a, Delta theta = -g_m Delta m to each pair's two copies
   alike (eq. 34 with the sign that relaxes, servo.py), the corner group's rotation (eq. 35),
   applied in a short ramp; back to 2.

Periodicity (eq. 12) holds at every step (a pair's copies get the same motion); the servo
drives the anti-periodicity of the reactions (eq. 13). The stress is 000's boundary sum
P = V^-1 sum_q a_q (x) X_q (eq. 14) over the frame copies, sigma = P F^T / det F (eq. 16); the
other homogenised outputs (fabric, coordination, sliding fraction, energies) are those of the
cell's periodic view (``periodic_view``: the discs once, each contact once), read by
demcell.homogenization as for a periodic cell. At convergence the frame cell's state IS a
periodic equilibrium, so the periodic view's contact-sum stress equals eq. 14.

An inner disc whose centre leaves the frame polygon (the parallelogram of the corner discs'
centres, F times the reference cell) has been pushed through the frame (000 section 4.2):
the solve stops, not converged, and its message names the discs.
"""
import dataclasses
import math

import numpy as np

from .. import checks
from ..checks import COUNT, MAX_BUDGET, Range
from ..contact_law import ContactLaw
from ..errors import InputError
from ..homogenization import homogenize
from ..interface import MicroCell, SolveResult
from ..periodic_cell import polar, substep_count
from ..relaxation import inv2, stable_time_step
from ..specimen.contacts import build_pairs
from ..specimen.engine import Specimen
from ..specimen.state import SpecimenOptions, SpecimenState
from ..state import CellState
from ..tangent import (SLIP_RATIO, TANGENT_KINDS, dsigma_to_dpk1, floor_stiffness, kruyt_operator,
                       perturbation_tangent, pstlo_operator, tangent_kind)
from . import servo
from .cut import contact_weights, cut_frame
from .options import FrameOptions

#: tangents of a frame cell: the closed forms on its periodic view, and the perturbation
#: (finite differences of its own solve). DEMQO's frozen-contact relaxations are not built.
FRAME_TANGENTS = ("kruyt", "pstlo", "pstlo_sliding", "perturbation")
#: listed pairs from which the engine's loops run in parallel (a cell stays below)
SERIAL_PAIRS = 10 ** 5


@dataclasses.dataclass
class ServoRecord:
    """What the servo did in the last solve: residual r_a after each relaxation (iteration 0:
    after the loading ramp), DEM steps of each relaxation, the steps of the ramps, the final
    residuals in both measures (servo.RESIDUALS), the largest |a+ + a-| / mean contact force,
    and by_measure: the residual after each relaxation in each measure."""
    residuals: list
    relaxation_steps: list
    ramp_steps: int
    residual_force: float = math.nan
    residual_table2: float = math.nan
    anti_periodicity: float = math.nan
    by_measure: dict = dataclasses.field(default_factory=dict)

    @property
    def iterations(self):
        """Servo corrections applied (relaxations after the first one)."""
        return max(0, len(self.residuals) - 1)


class FrameCell(MicroCell):
    """A frame cell (module docstring) made from a periodic CellState (its current
    configuration is the reference, F = I): ``FrameCell(state, law, options)``, options a
    FrameOptions (or a dict of its fields; None: the defaults). Rotations free or locked
    (law.rotations); no micro-rotation or curvature can be imposed."""

    def __init__(self, state, law=None, options=None):
        checks.instance("state", state, CellState, "CellState (e.g. a reference cell's state)")
        state.check()
        law = ContactLaw() if law is None else checks.instance("law", law, ContactLaw)
        if options is None:
            options = FrameOptions()
        elif isinstance(options, dict):
            options = FrameOptions(**options)
        checks.instance("options", options, FrameOptions, "FrameOptions (or a dict of them)")
        if np.any(state.bonded[:state.n_pairs]):
            raise InputError("a frame cell has no cohesive bonds (the specimen engine's contacts do not bond)")
        self.law = law
        self.options = options
        self.frame = cut_frame(state, options.thickness)
        fr = self.frame
        r = options.relaxation
        self.dt = r.dt if r.dt is not None else stable_time_step(fr.radius, fr.mass, fr.inertia, law, r.dt_safety)
        limit = stable_time_step(fr.radius, fr.mass, fr.inertia, law, 1.0)
        if self.dt > limit * (1.0 + 1e-12):
            raise InputError(f"time step dt = {self.dt:.3e} s exceeds the stability estimate {limit:.3e} s")
        self._law_array = law.as_array()
        self._F = np.eye(2)
        self._target = np.eye(2)
        self.last_result = None
        self.last_servo = None
        self.last_tangent_steps = 0
        self.escaped = np.zeros(0, np.int64)
        self._engine = self._new_engine(self._initial_state(state))
        self.commit()

    # ------------------------------------------------------------------ set-up
    def _specimen_options(self):
        r = self.options.relaxation
        # the periodic cell's law: no clipping of the normal force, Coulomb on the elastic part
        return SpecimenOptions(dt=self.dt, clip_normal=False, coulomb_on_total_normal=False, local_damping=r.damping,
                               lateral="none", boundary_interval=r.check_every, reorder=False)

    def _initial_state(self, periodic):
        """The frame's discs at rest at their reference positions, each contact with the
        history (fn, fs, mr) of its periodic contact."""
        fr = self.frame
        lo = fr.X.min(axis=0) - fr.radius.max()
        hi = fr.X.max(axis=0) + fr.radius.max()
        st = SpecimenState.from_discs(fr.X, fr.radius, fr.mass, fr.inertia, (lo[0], hi[0], lo[1], hi[1]),
                                      lateral="none")
        skin = 0.3 * float(fr.radius.max())         # the engine's default skin
        pair_i, pair_j, _ = build_pairs(st.position, st.radius, skin, 0.0, 0.0)
        n_p = periodic.n_pairs
        known = {}
        for k in np.flatnonzero(periodic.touching[:n_p]):
            known[(int(periodic.pair_i[k]), int(periodic.pair_j[k]))] = k
        m = pair_i.shape[0]
        touching = np.zeros(m, np.int8)
        fn, fs, mr = np.zeros(m), np.zeros(m), np.zeros(m)
        for q in range(m):
            a, b = int(fr.uid[pair_i[q]]), int(fr.uid[pair_j[q]])
            k = known.get((min(a, b), max(a, b)))
            if k is None:
                continue
            touching[q] = 1
            fn[q], fs[q] = periodic.fn[k], periodic.fs[k]
            # (fn, fs are the same whichever disc comes first; the rolling moment on j turns sign)
            mr[q] = periodic.mr[k] if a < b else -periodic.mr[k]
        st.pair_i, st.pair_j, st.touching, st.fn, st.fs, st.mr = pair_i, pair_j, touching, fn, fs, mr
        st.sliding = np.zeros(m, np.int8)
        st.rotation = np.asarray(periodic.theta, dtype=float)[fr.uid].copy()
        return st

    def _new_engine(self, spec_state):
        engine = Specimen(spec_state, self.law, self._specimen_options())
        engine.hold(self.frame.held)
        # a cell's few hundred pairs: the serial loops (a parallel region per step costs more
        # than the step, and much more on a loaded machine)
        engine.set_parallel_threshold(SERIAL_PAIRS)
        return engine

    # ------------------------------------------------------------------ MicroCell
    def set_deformation(self, F, rotation=None, curvature=None):
        """Target F (2x2) of the next solve (det F > 0)."""
        if rotation is not None or curvature is not None:
            raise InputError("a frame cell takes no micro-rotation or curvature (its grains rotate freely or are "
                             "locked); a micropolar cell is periodic (demcell.DemCell rotation_mode='micropolar')")
        F = checks.array("F", F, (2, 2))
        with np.errstate(over="ignore"):
            det = float(np.linalg.det(F))
        if not (det > 0.0 and math.isfinite(det)):
            raise InputError(f"F must have a finite det F > 0 (an admissible deformation), got det F = {det:.3g}")
        self._target = F.copy()

    def deformation_gradient(self):
        return self._F.copy()

    @property
    def target(self):
        """The F of the next solve (a copy)."""
        return self._target.copy()

    @property
    def state(self):
        """The periodic view of the current state (a CellState copy, for readers: snapshots,
        grain sizes; see ``periodic_view``)."""
        return self.periodic_view()

    def solve(self, max_steps=None):
        """Bring the cell to the target F (module docstring); -> SolveResult. max_steps: DEM
        steps of the whole solve (default the relaxation options' solve_budget). Its
        substeps are the servo's corrections; ``last_servo`` (ServoRecord) says more."""
        o = self.options
        total = checks.optional("max_steps", max_steps, COUNT)
        total = o.relaxation.solve_budget if total is None else min(total, MAX_BUDGET)
        fr = self.frame
        record = ServoRecord(residuals=[], relaxation_steps=[], ramp_steps=0)
        self.last_servo = record
        self.escaped = np.zeros(0, np.int64)
        steps = 0
        F0, F1 = self._F, self._target
        dF = F1 - F0
        spin = polar(F1)[0] - polar(F0)[0]
        n_ramp = substep_count(float(np.abs(dF).max()) / o.relaxation.strain_rate) if np.any(dF != 0.0) else 0
        held = fr.held
        if o.ramp == "affine":
            # every disc on the affine map x -> F1 F0^-1 x, as the periodic cell's ramp
            moving = np.ones(fr.n_copies, bool)
            move = self._engine.state.position @ (F1 @ inv2(F0) - np.eye(2)).T
        else:
            moving = held
            move = np.zeros((fr.n_copies, 2))
            move[held] = fr.X[held] @ dF.T
        turn = np.where(moving, spin, 0.0)
        steps += self._move_held(move, turn, n_ramp, moving)
        record.ramp_steps += n_ramp
        self._F = F1.copy()
        message, converged, no_contacts = "", False, False
        g_a = g_m = None
        accelerator = servo.Anderson(o.memory) if o.acceleration == "anderson" else None
        applied = np.zeros(3 * len(fr.groups))
        r_mean = float(np.mean(fr.radius))
        for iteration in range(o.max_iterations + 1):
            done, settled = self._relax(max(total - steps, 0))
            steps += done
            record.relaxation_steps.append(done)
            escaped = self._escaped()
            if escaped.size:
                self.escaped = escaped
                message = (f"{escaped.size} grain(s) pushed through the frame (disc(s) {_names(escaped)} of the "
                           f"periodic cell left the frame polygon) at F = {np.round(self._F, 6).tolist()}: a "
                           "thicker frame (FrameOptions.thickness) holds them")
                break
            if self.contact_count() == 0:
                no_contacts, converged = True, True
                message = "no contact left in the cell: zero stress (flag no_contacts)"
                break
            if not settled:
                message = (f"servo iteration {iteration}: the relaxation did not settle within its steps "
                           f"(max_steps = {o.relaxation.max_steps}, {steps} of {total} steps of the solve used)")
                break
            da, dm, weights = self._residuals()
            for kind in servo.RESIDUALS:
                scale_f, scale_m = servo.scales(kind, fr.groups, fr.mass, fr.radius, self.dt, self._mean_force())
                r = servo.residual(da, dm, scale_f, scale_m, fr.corner_group)
                record.by_measure.setdefault(kind, []).append(r)
            r_a = record.by_measure[o.residual][-1]
            record.residuals.append(r_a)
            if r_a <= o.eps_a:
                converged = True
                message = "converged"
                break
            if iteration == o.max_iterations:
                message = (f"the servo did not reach r_a <= {o.eps_a:g} in {o.max_iterations} iterations "
                           f"(r_a = {r_a:.3e})")
                break
            if g_a is None or o.gain == "stiffness":
                g_a, g_m = self._gains()
            du, dth = servo.corrections(da, dm, g_a, g_m, fr.corner_group)
            if accelerator is not None:
                if len(record.residuals) > 1 and r_a > 2.0 * record.residuals[-2]:
                    accelerator.restart()       # a jump (a contact opened, a slip): old differences mislead
                f = np.column_stack([du, dth * r_mean]).ravel()
                step = accelerator.step(applied, f)
                applied += step
                step = step.reshape(-1, 3)
                du, dth = step[:, :2], step[:, 2] / r_mean
            move = np.zeros((fr.n_copies, 2))
            turn = np.zeros(fr.n_copies)
            group = fr.group[held]
            move[held] = du[group]
            turn[held] = dth[group]
            d_mean = 2.0 * float(np.mean(fr.radius))
            size = max(float(np.abs(du).max(initial=0.0)) / d_mean, float(np.abs(dth).max(initial=0.0)))
            n_move = substep_count(size / o.relaxation.strain_rate)
            steps += self._move_held(move, turn, n_move)
            record.ramp_steps += n_move
        self._finish_record(record)
        self.last_result = SolveResult(converged=converged, no_contacts=no_contacts, steps=int(steps),
                                       substeps=record.iterations, message=message,
                                       max_overlap_ratio=self._max_overlap())
        return self.last_result

    # ------------------------------------------------------------------ the steps of a solve
    def _move_held(self, move, turn, n_steps, held=None):
        """Move the held copies (or those of the mask `held`, held for the time) by move (n, 2)
        [m] and turn (n,) [rad] at constant speed in n_steps steps (the free discs follow
        dynamically); their positions end exactly at the targets. Returns the steps run."""
        if n_steps <= 0:
            return 0
        st = self._engine.state
        if held is None:
            held = self.frame.held
        else:
            self._engine.hold(held)
        target_x = st.position[held] + move[held]
        target_r = st.rotation[held] + turn[held]
        st.velocity[held] = move[held] / (n_steps * self.dt)
        st.spin[held] = turn[held] / (n_steps * self.dt) if self.law.rotations else 0.0
        before = st.step
        self._engine.run(n_steps=n_steps)
        self._engine.history.clear()
        st = self._engine.state
        st.position[held] = target_x
        st.rotation[held] = target_r if self.law.rotations else st.rotation[held]
        st.velocity[held] = 0.0
        st.spin[held] = 0.0
        self._engine.hold(self.frame.held)
        return st.step - before

    def _relax(self, budget):
        """Dynamic relaxation with the frame held, at most min(max_steps, budget) steps.
        Returns (steps, settled)."""
        r = self.options.relaxation
        limit = min(r.max_steps, budget)
        if limit <= 0:
            return 0, False
        st = self._engine.state
        before = st.step
        settled = [False]

        def stop(engine, measurement):
            settled[0] = self._settled()
            return settled[0] or self._escaped().size > 0
        self._engine.run(n_steps=limit, stop=stop)
        self._engine.history.clear()
        return self._engine.state.step - before, settled[0]

    def _settled(self):
        """The relaxation's test on the free discs that touch something (000 eq. 31 with eq.
        32, or the unbalanced-force ratio of 001)."""
        r = self.options.relaxation
        st = self._engine.state
        on = np.flatnonzero(st.touching)
        if on.size == 0:
            return True
        free = ~self.frame.held
        loaded = np.zeros(st.n_discs, bool)
        loaded[st.pair_i[on]] = True
        loaded[st.pair_j[on]] = True
        sel = free & loaded
        if r.criterion == "energy":
            e_kin = 0.5 * float(np.sum(st.mass[sel] * np.sum(st.velocity[sel] ** 2, axis=1))
                                + np.sum(st.inertia[sel] * st.spin[sel] ** 2))
            law = self.law
            e_pot = 0.5 * float(np.sum(st.fn[on] ** 2) / law.kn)
            if law.ks > 0.0:
                e_pot += 0.5 * float(np.sum(st.fs[on] ** 2) / law.ks)
            if law.rolling_stiffness > 0.0:
                e_pot += 0.5 * float(np.sum(st.mr[on] ** 2) / law.rolling_stiffness)
            return e_kin <= r.tol * e_pot
        a, _ = servo.reactions(st.position, st.radius, st.pair_i, st.pair_j, st.fn, st.fs, st.mr,
                               st.touching.astype(float))
        unbalanced = float(np.sqrt(np.max(np.sum(a[sel] ** 2, axis=1), initial=0.0)))
        return unbalanced <= r.tol * self._mean_force()

    def _weights(self):
        st = self._engine.state
        return contact_weights(self.frame.uid, st.pair_i, st.pair_j, st.touching)[0]

    def _reactions(self, weights=None):
        """(a (n, 2) [N], m (n,) [N m]) of every copy (eq. 9), duplicated contacts weighted."""
        st = self._engine.state
        w = self._weights() if weights is None else weights
        return servo.reactions(st.position, st.radius, st.pair_i, st.pair_j, st.fn, st.fs, st.mr, w)

    def _residuals(self):
        weights = self._weights()
        a, m = self._reactions(weights)
        da, dm = servo.group_sums(self.frame.groups, a, m)
        return da, dm, weights

    def _gains(self):
        fr, st, o = self.frame, self._engine.state, self.options
        if o.gain == "table3":
            return servo.table3_gains(fr.groups, fr.mass, fr.radius, self.dt)
        return servo.stiffness_gains(fr.groups, st.pair_i, st.pair_j, st.touching, st.radius, self.law.kn,
                                     self.law.ks, o.beta)

    def _mean_force(self):
        st = self._engine.state
        on = st.touching != 0
        return float(np.mean(np.abs(st.fn[on]))) if on.any() else 0.0

    def _escaped(self):
        """Discs of the periodic cell whose inner copy left the frame polygon."""
        st = self._engine.state
        inner = self.frame.inner
        h = self._F @ self.frame.h_ref
        c = st.position[inner] @ inv2(h).T
        out = ~np.all((c >= 0.0) & (c <= 1.0), axis=1)
        return self.frame.uid[inner[out]]

    def _max_overlap(self):
        st = self._engine.state
        on = np.flatnonzero(st.touching)
        if on.size == 0:
            return 0.0
        i, j = st.pair_i[on], st.pair_j[on]
        d = st.position[j] - st.position[i]
        overlap = st.radius[i] + st.radius[j] - np.hypot(d[:, 0], d[:, 1])
        return float(np.max(overlap / np.minimum(st.radius[i], st.radius[j])))

    def _finish_record(self, record):
        if self.contact_count() == 0:
            return
        fr = self.frame
        da, dm, _ = self._residuals()
        for kind in servo.RESIDUALS:
            scale_f, scale_m = servo.scales(kind, fr.groups, fr.mass, fr.radius, self.dt, self._mean_force())
            setattr(record, f"residual_{kind}", servo.residual(da, dm, scale_f, scale_m, fr.corner_group))
        pairs = [g for k, g in enumerate(fr.groups) if k != fr.corner_group]
        worst = max((float(np.hypot(*da[k])) for k, g in enumerate(fr.groups) if k != fr.corner_group),
                    default=0.0) if pairs else 0.0
        record.anti_periodicity = worst / max(self._mean_force(), 1e-300)

    # ------------------------------------------------------------------ outputs
    def frame_stress(self):
        """(P, sigma) [N/m] from the frame's reactions: P = V^-1 sum_q a_q (x) X_q over the
        frame copies (000 eq. 14), sigma = P F^T / det F (eq. 16)."""
        fr = self.frame
        a, _ = self._reactions()
        held = fr.held
        P = np.einsum("ki,kj->ij", a[held], fr.X[held]) / abs(float(np.linalg.det(fr.h_ref)))
        F = self._F
        return P, P @ F.T / float(np.linalg.det(F))

    def homogenized(self):
        """The homogenised outputs (demcell.Homogenized) of the periodic view, with the stress
        of the frame (eqs 14, 16)."""
        view = self.periodic_view()
        out = homogenize(view, self._law_array)
        P, sigma = self.frame_stress()
        return dataclasses.replace(out, cauchy=sigma, pk1=P)

    def cauchy_stress(self):
        return self.frame_stress()[1]

    def pk1_stress(self):
        return self.frame_stress()[0]

    def couple_stress(self):
        """(mu_31, mu_32) [N]: V^-1 sum_q m_q X_q over the frame copies (the moment analogue of
        eq. 14; a fluctuation about zero under a homogeneous F)."""
        fr = self.frame
        _, m = self._reactions()
        held = fr.held
        return m[held] @ fr.X[held] / abs(float(np.linalg.det(fr.h_ref)))

    def contact_count(self):
        """Contacts of the periodic cell (each duplicated one once)."""
        return int(round(float(np.sum(self._weights()))))

    def periodic_view(self):
        """The frame cell as a periodic CellState: every disc once at its copy of shift (0, 0)
        (fractional coordinates in the cell F h_ref), every touching contact once with its
        forces; velocities and rotations of those copies. Exact geometry at any time (eq. 12
        holds throughout); an equilibrium of the periodic cell once the servo has converged."""
        return self._view(self._engine.state, self._F)

    def _view(self, st, F):
        fr = self.frame
        base = fr.base_copy
        h = F @ fr.h_ref
        s = np.mod(st.position[base] @ inv2(h).T, 1.0)
        w, a, b, rev = contact_weights(fr.uid, st.pair_i, st.pair_j, st.touching)
        on = np.flatnonzero(w > 0.0)
        key = a[on] * (fr.n_discs + 1) + b[on]
        _, first = np.unique(key, return_index=True)      # sorted by (a, b)
        pick = on[first]
        m = pick.size
        x = st.position
        d = x[st.pair_j[pick]] - x[st.pair_i[pick]]
        d[rev[pick]] *= -1.0
        n = fr.n_discs
        return CellState(
            radius=fr.radius[base].copy(), mass=fr.mass[base].copy(), inertia=fr.inertia[base].copy(), s=s,
            v=st.velocity[base].copy(), theta=st.rotation[base].copy(), omega=st.spin[base].copy(),
            dtheta=np.zeros(n), force=np.zeros((n, 2)), moment=np.zeros(n), s_build=s.copy(), h=h.copy(),
            h_build=h.copy(), h_ref=fr.h_ref.copy(), pair_i=a[pick].astype(np.int64), pair_j=b[pick].astype(np.int64),
            fn=st.fn[pick].copy(), fs=st.fs[pick].copy(), mr=np.where(rev[pick], -st.mr[pick], st.mr[pick]),
            bonded=np.zeros(m, np.uint8), touching=np.ones(m, np.uint8), d_prev=d, n_pairs=m, forces_current=1,
            time=float(st.time))

    # ------------------------------------------------------------------ tangents
    def tangent(self, kind="kruyt", measure="dsigma_dF", eps=None):
        """4x4 tangent (001 eq. 11 order), kinds FRAME_TANGENTS: 'kruyt' (001 eq. 13), 'pstlo'
        and 'pstlo_sliding' (001 appendix B) of the periodic view's contact network (the frame
        held on F under a uniform strain, resp. the servo's fixed point linearised: the
        periodic equilibrium's), 'perturbation' (001 eq. 6: four solves of this frame cell from
        its last commit to F + eps L^mn, with relaxation and servo tolerances scaled to eps)."""
        if not isinstance(measure, str) or measure not in ("dsigma_dF", "dP_dF"):
            raise InputError(f"unknown tangent measure {measure!r} for a frame cell: 'dsigma_dF' or 'dP_dF'")
        kind = tangent_kind(kind).name
        if kind not in FRAME_TANGENTS:
            raise InputError(f"tangent {kind!r} is not built for a frame cell: one of {', '.join(FRAME_TANGENTS)}")
        eps = checks.optional("eps", eps, Range(0.0, 0.1, low_open=True))
        self.last_tangent_steps = 0
        if kind == "perturbation":
            eps = TANGENT_KINDS[kind].default_eps if eps is None else eps
            C, results = perturbation_tangent(self, eps, options=self.perturbation_options(eps))
            self.last_tangent_steps = sum(r.steps for r in results)
        elif kind == "kruyt":
            C = kruyt_operator(self.periodic_view(), self._law_array)
        elif kind == "pstlo":
            C = pstlo_operator(self.periodic_view(), self._law_array)
        else:
            C = floor_stiffness(pstlo_operator(self.periodic_view(), self._law_array, slip_ratio=SLIP_RATIO))
        if measure == "dP_dF":
            C = dsigma_to_dpk1(C, self._F, self.cauchy_stress())
        return C

    def perturbation_options(self, eps, rel=1e-5, servo_rel=1e-3):
        """Options of the solves of a perturbation of size eps: the unbalanced-force criterion
        at rel x eps x kn x mean diameter / mean contact force (as tangent.perturbation_options)
        and the servo's residual in mean contact forces at servo_rel x the same force ratio."""
        o = self.options
        f = self._mean_force()
        if not f > 0.0:
            return o
        ratio = eps * self.law.kn * 2.0 * float(np.mean(self.frame.radius)) / f
        relax = dataclasses.replace(o.relaxation, criterion="force", tol=rel * ratio, check_every=10)
        return dataclasses.replace(o, relaxation=relax, residual="force", eps_a=servo_rel * ratio,
                                   max_iterations=max(o.max_iterations, 200))

    # ------------------------------------------------------------------ history
    def commit(self):
        self._committed = (self._engine.state.to_dict(), self._F.copy())

    def rollback(self):
        saved, F = self._committed
        self._engine = self._new_engine(SpecimenState.from_dict(saved))
        self._F = F.copy()
        self._target = F.copy()

    @property
    def committed_state(self):
        """The periodic view of the last committed state (a CellState: snapshots)."""
        saved, F = self._committed
        return self._view(SpecimenState.from_dict(saved), F)

    def restore(self, committed):
        raise InputError("a frame cell cannot be restored from a periodic state (checkpoints and moving cells "
                         "between ranks need periodic cells)")

    def copy(self):
        new = FrameCell.__new__(FrameCell)
        new.__dict__.update(self.__dict__)
        new._engine = self._new_engine(SpecimenState.from_dict(self._engine.state.to_dict()))
        new._F, new._target = self._F.copy(), self._target.copy()
        new._committed = ({k: np.copy(v) for k, v in self._committed[0].items()}, self._committed[1].copy())
        new.escaped = self.escaped.copy()
        return new

    def memory_bytes(self):
        """Bytes held by the current and the committed state arrays."""
        st = self._engine.state
        current = sum(np.asarray(v).nbytes for v in st.to_dict().values())
        return current + sum(np.asarray(v).nbytes for v in self._committed[0].values())

    @property
    def law_array(self):
        return self._law_array.copy()


def _names(discs, k=8):
    text = ", ".join(str(int(p)) for p in discs[:k])
    return text + (", ..." if len(discs) > k else "")
