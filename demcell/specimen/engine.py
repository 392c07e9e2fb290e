"""The time loop of a bounded disc specimen: ``Specimen(state, law, options).run(...)``.

Each step (inside Numba, in chunks of ``options.boundary_interval`` steps):
  1. the law on every listed pair (contacts.pair_forces, 004 eqs. 7.3-7.14);
  2. the walls (walls.wall_forces, 004 eq. 7.43) and, for a membrane specimen, the confining
     pressure on the outside arcs of the free-side discs and the membrane between them
     (boundary.pressure_forces / membrane_forces, 004 eqs. 7.44-7.46) into external_force;
  3. gather and leapfrog (integrate.step_discs, 004 eqs. 7.15-7.17);
  2b. the rigid plate, if any (plate.plate_forces: a finite footing, 003 section 3);
  4. the walls and the plate move (prescribed velocity or stress servo, walls.move_walls);
  5. the neighbour list is stale when 2 max |u| > skin (or max |u| + the wall motion > skin):
     the chunk returns and Python rebuilds it (contacts.build_pairs, history merged).
Between chunks Python finds the free-side chains again (boundary.boundary_loop and
side_chains, dns-spec A6), measures the specimen (``Measurement``) and checks it: a non-finite
value or a disc outside the walls or pushed through the membrane stops the run with a
``LostDiscsError`` naming the discs; an inertial number above 1e-3 is warned about once.
"""
import math
import time as _time
import warnings
from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from .. import checks
from ..checks import NON_NEGATIVE, POSITIVE, Range
from ..contact_law import ContactLaw
from ..errors import InputError, SolveError
from .boundary import boundary_loop, escaped_discs, membrane_forces, pressure_forces, side_chains
from .contacts import (P_PARALLEL_MIN, P_WALL_DN, P_WALL_RATIO, branch, build_pairs, clear_pair, contact_geometry,
                       elastic_energy, gather_disc, law_scalars, law_vector, merge_history, one_pair, pairs_of_j,
                       spatial_order)
from .integrate import block, n_blocks, set_held_path
from .kept_pass import KeptPass
from .plate import PL_ACTIVE, PL_VX, PL_VY, PL_X0, PL_Y, Plate, move_plate, no_plate, plate_candidates, plate_forces
from .state import SpecimenOptions, SpecimenState
from .walls import WALL_AXIS, WALL_SIGN, WallControl, move_walls, programme_arrays, wall_candidates, wall_forces

DONE, REBUILD, NONFINITE = range(3)
#: inertial number above which a run is no longer quasi-static (warned once)
INERTIAL_LIMIT = 1.0e-3
# slots of the control vector of the chunk kernel
(C_GX, C_GY, C_DAMP, C_SKIN, C_PRESSURE, C_EM, C_WIDTH, C_LATERAL, C_WALL_MU, C_MASS_DAMP, C_PATH_STEP, C_SKIP_HELD,
 C_FORCES_READY, N_CTRL) = range(14)


def check_time_step(dt, mass, kn):
    """InputError (one line) when dt [s] is above 2 sqrt(m_min / kn), the stability limit of
    the leapfrog for the lightest disc [kg/m] on its stiffest single spring (a disc against a
    wall, kn [N/m]): such a run can only blow up. Below it the step may still be too coarse
    for accuracy (004's 2e-3 s is 0.11 of sqrt(m / kn))."""
    limit = 2.0 * math.sqrt(float(np.min(mass)) / kn)
    if not dt < limit:
        raise InputError(f"time step dt = {dt:g} s is above the stability limit 2 sqrt(m_min / kn) = {limit:.3g} s "
                         f"of the lightest disc on a spring kn = {kn:g} N/m")


class LostDiscsError(SolveError):
    """Discs left the specimen (through a wall or the membrane) or their state is not finite."""


@njit(cache=True)
def lateral_forces(position, radius, chain, chain_start, pressure, stiffness, out):
    """Pressure arcs and membrane of the free sides ADDED into out (n, 2) (boundary.py's
    kernels, 004 eqs. 7.44-7.46)."""
    if chain.shape[0] > 0:
        pressure_forces(position, radius, chain, chain_start, pressure, out)
        if stiffness > 0.0:
            membrane_forces(position, radius, chain, chain_start, stiffness, out)


@njit(cache=True)
def external_loads(cand_disc, cand_wall, cand_fs, chain, chain_start, plate_cand, position, velocity, spin, radius,
                   mass, wall_position, wall_velocity, wall_force, on_wall, plate, plate_fs, plate_force,
                   external_force, external_moment, kn, ks, wall_dn, wall_ratio, clip, wall_mu, dt, membrane,
                   pressure, stiffness):
    """Step 2 of the module docstring: the walls, the plate and the free sides' pressure and
    membrane into external_force, external_moment (only the discs that may carry a load are
    reset), wall_force, plate_force."""
    for c in range(cand_disc.shape[0]):
        p = cand_disc[c]
        external_force[p, 0] = 0.0
        external_force[p, 1] = 0.0
        external_moment[p] = 0.0
        on_wall[p] = 0
    for c in range(chain.shape[0]):
        external_force[chain[c], 0] = 0.0
        external_force[chain[c], 1] = 0.0
    for c in range(plate_cand.shape[0]):
        p = plate_cand[c]
        external_force[p, 0] = 0.0
        external_force[p, 1] = 0.0
        external_moment[p] = 0.0
    wall_forces(cand_disc, cand_wall, cand_fs, position, velocity, spin, radius, mass, wall_position,
                wall_velocity, kn, ks, wall_dn, wall_ratio, clip, wall_mu, dt, external_force, external_moment,
                wall_force, on_wall)
    if plate_cand.shape[0] > 0:
        plate_forces(plate_cand, position, velocity, spin, radius, mass, plate, plate_fs, kn, ks, wall_dn,
                     wall_ratio, clip, dt, external_force, external_moment, plate_force)
    else:
        plate_force[0] = 0.0
        plate_force[1] = 0.0
    if membrane:
        lateral_forces(position, radius, chain, chain_start, pressure, stiffness, external_force)


@njit(cache=True)
def pair_law(k, skip_held, held, geo, velocity, spin, radius, mass, pair_i, pair_j, touching, sliding, fn, fs, mr,
             work, kn, ks, mu, kr, eta_r, xi_n, xi_t, meff, pair_mass, clip, total, rot, dt):
    """The contact law of pair k (contacts.one_pair), or, with skip_held and both discs held,
    no contact at all (history and force cleared: two held discs move nothing, and a caller
    that does not want their mutual force need not subtract it)."""
    if skip_held and held[pair_i[k]] != 0 and held[pair_j[k]] != 0:
        clear_pair(k, touching, sliding, fn, fs, mr, work)
    else:
        one_pair(k, geo, velocity, spin, radius, mass, pair_i, pair_j, touching, sliding, fn, fs, mr, work, kn, ks,
                 mu, kr, eta_r, xi_n, xi_t, meff, pair_mass, clip, total, rot, dt)


@njit(cache=True, parallel=True)
def advance_steps(n_steps, position, velocity, rotation, spin, radius, mass, inertia, external_force,
                  external_moment, on_wall, held, pair_i, pair_j, touching, sliding, fn, fs, mr, work, geo, row, jstart,
                  jcol, cand_disc, cand_wall, cand_fs, chain, chain_start, build_position, build_wall, wall_position,
                  wall_velocity, wall_active, wall_force, mode, velocity_prog, target, gain, vmax, par, ctrl, block_max,
                  plate, plate_cand, plate_fs, plate_force, build_plate, net, path):
    """Up to n_steps steps (module docstring); returns (steps done, status): DONE, REBUILD
    (the neighbour list is stale) or NONFINITE. net (n, 3): each disc's contact plus
    external force and moment of the last step. path (n, 9): the held discs' path when
    ctrl[C_PATH_STEP] >= 0 (the steps of it done before this call; integrate.follow_path);
    ctrl[C_SKIP_HELD]: no contact between two held discs (``pair_law``).

    The two parallel loops (pairs, then blocks of discs) are written here rather than called
    (contacts.pair_forces, integrate.block are their bodies): a cached Numba kernel calling
    another parallel kernel crashed when loaded from the cache (Numba 0.56). Below
    par[P_PARALLEL_MIN] pairs both run serially (a parallel region costs microseconds);
    either way every sum has the same order, so the result does not depend on the threads."""
    kn, ks, mu, kr, eta_r, xi_n, xi_t, meff, pair_mass, clip, total, rot, dt, period = law_scalars(par)
    wall_dn = par[P_WALL_DN]
    wall_ratio = par[P_WALL_RATIO]
    n_pairs = pair_i.shape[0]
    parallel = n_pairs >= par[P_PARALLEL_MIN]
    nb = block_max.shape[0]
    gx = ctrl[C_GX]
    gy = ctrl[C_GY]
    damp = ctrl[C_DAMP]
    skin = ctrl[C_SKIN]
    pressure = ctrl[C_PRESSURE]
    stiffness = ctrl[C_EM]
    width = ctrl[C_WIDTH]
    membrane = ctrl[C_LATERAL] > 0.5
    wall_mu = ctrl[C_WALL_MU]
    cm = ctrl[C_MASS_DAMP]
    path_step0 = ctrl[C_PATH_STEP]
    skip_held = ctrl[C_SKIP_HELD] > 0.5
    forces_ready = ctrl[C_FORCES_READY] > 0.5
    for s in range(n_steps):
        path_t = (path_step0 + s + 1) * dt if path_step0 >= 0.0 else -1.0
        # 1-2 done already for the first step when ctrl[C_FORCES_READY] (Specimen.forces_now(keep=True))
        if s > 0 or not forces_ready:
            # 1. contact law per pair
            if parallel:
                for k in prange(n_pairs):
                    branch(k, position, pair_i, pair_j, period, geo)
                for k in prange(n_pairs):
                    pair_law(k, skip_held, held, geo, velocity, spin, radius, mass, pair_i, pair_j, touching, sliding,
                             fn, fs, mr, work, kn, ks, mu, kr, eta_r, xi_n, xi_t, meff, pair_mass, clip, total, rot, dt)
            else:
                for k in range(n_pairs):
                    branch(k, position, pair_i, pair_j, period, geo)
                for k in range(n_pairs):
                    pair_law(k, skip_held, held, geo, velocity, spin, radius, mass, pair_i, pair_j, touching, sliding,
                             fn, fs, mr, work, kn, ks, mu, kr, eta_r, xi_n, xi_t, meff, pair_mass, clip, total, rot, dt)
            # 2. external loads: only the discs that may carry one are reset
            external_loads(cand_disc, cand_wall, cand_fs, chain, chain_start, plate_cand, position, velocity, spin,
                           radius, mass, wall_position, wall_velocity, wall_force, on_wall, plate, plate_fs,
                           plate_force, external_force, external_moment, kn, ks, wall_dn, wall_ratio, clip, wall_mu, dt,
                           membrane, pressure, stiffness)
        # 3. gather and leapfrog, the staleness bound reduced over the blocks in order
        if parallel:
            for b in prange(nb):
                block_max[b] = block(b, row, jstart, jcol, work, position, velocity, rotation, spin, mass, inertia,
                                     external_force, external_moment, gx, gy, damp, cm, dt, rot, build_position,
                                     held, net, path, path_t)
        else:
            for b in range(nb):
                block_max[b] = block(b, row, jstart, jcol, work, position, velocity, rotation, spin, mass, inertia,
                                     external_force, external_moment, gx, gy, damp, cm, dt, rot, build_position,
                                     held, net, path, path_t)
        u2 = 0.0
        for b in range(nb):
            if block_max[b] > u2:
                u2 = block_max[b]
        umax = math.sqrt(u2)
        # 4. walls
        move_walls(wall_position, wall_velocity, wall_active, wall_force, mode, velocity_prog, target, gain, vmax,
                   width, dt)
        move_plate(plate, dt)
        if not (umax < math.inf):
            return s + 1, NONFINITE
        wmax = 0.0
        for w in range(4):
            wmax = max(wmax, abs(wall_position[w] - build_wall[w]))
        wmax = max(wmax, math.hypot(plate[PL_X0] - build_plate[0], plate[PL_Y] - build_plate[1]))
        if 2.0 * umax > skin or umax + wmax > skin:
            return s + 1, REBUILD
    return n_steps, DONE


@njit(cache=True)
def current_forces(position, velocity, spin, radius, mass, external_force, external_moment, on_wall, held, pair_i,
                   pair_j, touching, sliding, fn, fs, mr, work, geo, row, jstart, jcol, cand_disc, cand_wall, cand_fs,
                   chain, chain_start, wall_position, wall_velocity, wall_force, par, ctrl, plate, plate_cand, plate_fs,
                   plate_force, net):
    """Steps 1-2 of ``advance_steps`` and the gather on the configuration as it is: net (n, 3)
    the contact plus external force and moment of every disc, what the next step will use
    (the same law, the same sums in the same order). The history arguments (touching,
    sliding, fn, fs, mr, cand_fs, plate_fs) and external_force, external_moment, on_wall,
    wall_force, plate_force are modified: pass copies. Serial."""
    kn, ks, mu, kr, eta_r, xi_n, xi_t, meff, pair_mass, clip, total, rot, dt, period = law_scalars(par)
    skip_held = ctrl[C_SKIP_HELD] > 0.5
    for k in range(pair_i.shape[0]):
        branch(k, position, pair_i, pair_j, period, geo)
    for k in range(pair_i.shape[0]):
        pair_law(k, skip_held, held, geo, velocity, spin, radius, mass, pair_i, pair_j, touching, sliding, fn, fs, mr,
                 work, kn, ks, mu, kr, eta_r, xi_n, xi_t, meff, pair_mass, clip, total, rot, dt)
    external_loads(cand_disc, cand_wall, cand_fs, chain, chain_start, plate_cand, position, velocity, spin, radius,
                   mass, wall_position, wall_velocity, wall_force, on_wall, plate, plate_fs, plate_force,
                   external_force, external_moment, kn, ks, par[P_WALL_DN], par[P_WALL_RATIO], clip,
                   ctrl[C_WALL_MU], dt, ctrl[C_LATERAL] > 0.5, ctrl[C_PRESSURE], ctrl[C_EM])
    for p in range(position.shape[0]):
        fx, fy, mo = gather_disc(p, row, jstart, jcol, work)
        net[p, 0] = fx + external_force[p, 0]
        net[p, 1] = fy + external_force[p, 1]
        net[p, 2] = mo + external_moment[p]


@dataclass
class Measurement:
    """The specimen at the end of an interval. Stresses tension positive [N/m]."""
    time: float
    step: int
    wall_position: np.ndarray       # (4,) [m]
    wall_velocity: np.ndarray       # (4,) [m/s]
    wall_force: np.ndarray          # (4, 2) [N] force of each wall on the discs
    wall_stress: np.ndarray         # (4,) [N/m] normal stress each wall carries (nan: no wall)
    kinetic_energy: float           # [J/m]
    elastic_energy: float           # [J/m] contact springs and wall springs
    coordination: float             # 2 N_contacts / N_discs
    sliding_fraction: float         # sliding contacts / contacts
    max_overlap: float              # largest overlap / smaller radius
    n_contacts: int
    inertial_number: float          # |strain rate| d / sqrt(p / rho) of the platens (0 if at rest)
    width: float                    # [m] loaded width of the platens
    height: float                   # [m] platen gap
    rebuilds: int                   # neighbour builds so far

    def as_dict(self):
        return {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in self.__dict__.items()}


class Specimen:
    """A bounded 2D disc specimen and its time loop.

    state: SpecimenState (copied: the engine owns its arrays; read them from ``.state``);
    law: demcell ContactLaw (kn = E_n, ks = E_t, friction = mu, rolling, damping ratios);
    options: SpecimenOptions. With options.reorder the discs are renumbered along a
    Morton curve (``.order[k]`` is the original index of disc k).
    """

    def __init__(self, state, law, options=None):
        checks.instance("state", state, SpecimenState)
        checks.instance("law", law, ContactLaw)
        options = SpecimenOptions() if options is None else checks.instance("options", options, SpecimenOptions)
        state.check()
        expected = {"walls": (1, 1, 1, 1), "none": (0, 0, 0, 0)}.get(options.lateral, (1, 1, 0, 0))
        if tuple(int(a) for a in state.wall_active) != expected:
            raise InputError(f"state.wall_active {tuple(int(a) for a in state.wall_active)} does not match "
                             f"lateral={options.lateral!r} (expected {expected})")
        if options.lateral == "periodic" and not state.period > 0.0:
            raise InputError("lateral='periodic' needs state.period > 0 (the x period of the specimen) [m]")
        if options.lateral != "periodic" and state.period > 0.0:
            raise InputError(f"state.period = {state.period:g} m but lateral={options.lateral!r}: set period 0")
        check_time_step(options.dt, state.mass, law.kn)
        rmax = float(np.max(state.radius))
        if state.period > 0.0 and state.period < 2.0 * (2.0 * rmax + (options.skin or 0.3 * rmax)):
            raise InputError(f"period {state.period:g} m must be at least twice 2 r_max + skin (minimum image)")
        self.law = law
        self.options = options
        self.skin = options.skin if options.skin is not None else 0.3 * rmax
        self.gap_tolerance = options.boundary_gap if options.boundary_gap is not None else 0.5 * float(
            np.mean(state.radius))
        if options.lateral == "membrane" and self.skin < self.gap_tolerance:
            self.skin = self.gap_tolerance     # the boundary loop reads its candidate edges from the list
        if options.reorder and state.n_discs > 1:
            self.order = spatial_order(state.position, state.radius, self.skin)
            history = state.n_pairs > 0
            state = state.permuted(self.order)
            if history:
                warnings.warn("Specimen(reorder=True) renumbered the discs: the contact history of the "
                              "state was dropped", stacklevel=2)
        else:
            self.order = np.arange(state.n_discs)
            state = SpecimenState.from_dict(state.to_dict())
        self.state = state
        self.par = law_vector(law, options, state.period)
        self.pressure = options.pressure
        self.controls = [None, None, None, None]
        if options.lateral == "walls" and options.pressure > 0.0:
            self.controls[2] = self.controls[3] = WallControl("stress", stress=-options.pressure)
        self.rebuilds = 0
        self.chain = np.zeros(0, np.int64)
        self.chain_start = np.zeros(3, np.int64)
        self.loop = np.zeros(0, np.int64)
        self.external_moment = np.zeros(state.n_discs)
        self.held = np.zeros(state.n_discs, np.int8)
        self.block_max = np.zeros(n_blocks(state.n_discs))
        self.plate_vector = no_plate()
        self.plate_force = np.zeros(2)
        self.plate_fs = np.zeros(state.n_discs)
        self.plate_cand = np.zeros(0, np.int64)
        self.build_plate = np.zeros(2)
        self.net = np.zeros((state.n_discs, 3))
        self.path = np.zeros((state.n_discs, 9))
        self.skip_held_pairs = False
        self._held_target = None
        self._kept = KeptPass(self.PASS_STATE, self.PASS_ENGINE, self.PASS_SCRATCH, self.PASS_INPUTS_STATE,
                              self.PASS_INPUTS_ENGINE)
        self._warned_inertial = False
        self._warned_sides = False
        self.history = []
        self.cpu_seconds = 0.0
        self.wall_seconds = 0.0
        self.pair_updates = 0
        self._prepared = None
        self._rebuild()

    # ------------------------------------------------------------------ neighbours
    def _check_finite(self):
        st = self.state
        bad = np.flatnonzero(~(np.isfinite(st.position).all(axis=1) & np.isfinite(st.velocity).all(axis=1)
                               & np.isfinite(st.spin)))
        if bad.size:
            raise LostDiscsError(f"non-finite position or velocity of {bad.size} disc(s) at t = {st.time:g} s "
                                 f"(first: {self._names(bad)}): time step too large for the stiffness?")

    def _names(self, idx, k=8):
        """Original indices (before the spatial renumbering) of the first k discs of idx."""
        idx = np.asarray(idx)
        text = ", ".join(str(int(self.order[i])) for i in idx[:k])
        return text + (", ..." if idx.size > k else "")

    def _rebuild(self):
        """New Verlet list (history merged), disc-wall candidates, CSR of the pairs by j."""
        self._check_finite()
        st = self.state
        x0 = float(np.min(st.position[:, 0])) if st.period > 0.0 else 0.0
        new_i, new_j, row = build_pairs(st.position, st.radius, self.skin, st.period, x0)
        touching, sliding, fn, fs, mr = merge_history(st.pair_i, st.pair_j, st.touching, st.sliding, st.fn, st.fs,
                                                      st.mr, new_i, new_j)
        st.pair_i, st.pair_j, st.touching, st.sliding, st.fn, st.fs, st.mr = new_i, new_j, touching, sliding, fn, fs, mr
        self.row = row
        self.jstart, self.jcol = pairs_of_j(st.n_discs, new_j)
        self.work = np.zeros((new_i.shape[0], 4))
        self.geo = np.zeros((new_i.shape[0], 3))
        old = getattr(self, "cand_disc", None)
        old_plate = self.plate_cand
        self.plate_cand = plate_candidates(st.position, st.radius, self.plate_vector, self.skin)
        self.build_plate = self.plate_vector[[PL_X0, PL_Y]].copy()
        gone_plate = np.setdiff1d(old_plate, self.plate_cand)
        self.plate_fs[gone_plate] = 0.0
        disc, wall = wall_candidates(st.position, st.radius, st.wall_position, st.wall_active, self.skin)
        cand_fs = np.zeros(disc.shape[0])
        if old is not None and self.options.wall_friction > 0.0:
            prev = {(int(p), int(w)): f for p, w, f in zip(old, self.cand_wall, self.cand_fs)}
            cand_fs = np.array([prev.get((int(p), int(w)), 0.0) for p, w in zip(disc, wall)])
        self.cand_disc, self.cand_wall, self.cand_fs = disc, wall, cand_fs
        self.build_position = st.position.copy()
        self.build_wall = st.wall_position.copy()
        if old is not None:
            # discs no longer near a wall lose their wall load; the others keep the last step's
            gone = np.setdiff1d(np.union1d(old, old_plate), np.union1d(disc, self.plate_cand))
            gone = gone[~np.isin(gone, self.chain)]
            st.external_force[gone] = 0.0
            self.external_moment[gone] = 0.0
            st.on_wall[gone] = 0
        self.rebuilds += 1

    # ------------------------------------------------------------------ boundary
    def lateral_width(self):
        """Width the platens load [m]: the period, the distance between the side walls, or the
        extent of the discs of a membrane specimen."""
        st = self.state
        if st.period > 0.0:
            return st.period
        if st.wall_active[2] and st.wall_active[3]:
            return float(st.wall_position[3] - st.wall_position[2])
        return float(np.max(st.position[:, 0] + st.radius) - np.min(st.position[:, 0] - st.radius))

    def _update_boundary(self):
        """The free-side chains again (dns-spec A6; every boundary_interval steps)."""
        if self.options.lateral != "membrane" or (self.pressure == 0.0 and self.options.membrane_stiffness == 0.0):
            return
        st = self.state
        loop = boundary_loop(st.position, st.radius, st.pair_i, st.pair_j, self.gap_tolerance)
        try:
            chain, chain_start = side_chains(loop, self._near_platen(), st.position)
        except InputError as exc:
            # no platen contact (a loose cloud): nothing anchors the membrane
            if not self._warned_sides:
                self._warned_sides = True
                warnings.warn(f"t = {st.time:g} s: {exc}; no pressure or membrane acts until a platen touches",
                              stacklevel=3)
            chain, chain_start = np.zeros(0, np.int64), np.zeros(3, np.int64)
        out = escaped_discs(st.position, st.radius, loop)
        if out.size:
            raise LostDiscsError(f"{out.size} disc(s) pushed through the membrane at t = {st.time:g} s "
                                 f"(original indices {self._names(out)})")
        chain = np.ascontiguousarray(chain, np.int64)
        # discs that left the chain lose their load now; the others keep the last step's
        # (the kernel resets the chain's entries at the start of each step)
        st.external_force[np.setdiff1d(self.chain, chain)] = 0.0
        self.loop = loop
        self.chain = np.ascontiguousarray(chain, np.int64)
        self.chain_start = np.ascontiguousarray(chain_start, np.int64)
        st.on_boundary[:] = 0
        st.on_boundary[self.chain] = 1

    def _near_platen(self):
        """Flags (n,) of the discs within the boundary gap tolerance of a platen: the edge
        particles of dns-spec A6 (no pressure; membrane anchors). A tolerance rather than
        overlap > 0: a corner disc whose platen overlap hovers about zero would otherwise
        switch between anchor and loaded disc at every detection, and each switch kicks the
        specimen by p r."""
        st = self.state
        near = np.zeros(st.n_discs, np.int8)
        for w in range(2):
            if st.wall_active[w]:
                a = WALL_AXIS[w]
                gap = WALL_SIGN[w] * (st.position[:, a] - st.wall_position[w]) - st.radius
                near[gap < self.gap_tolerance] = 1
        return near

    # ------------------------------------------------------------------ measurements
    def measure(self):
        """A ``Measurement`` of the current state (and the lost-disc checks)."""
        st = self.state
        self._check_finite()
        self._check_walls()
        width = self.lateral_width()
        height = float(st.wall_position[1] - st.wall_position[0])
        lengths = np.array([width, width, height, height])
        stress = np.full(4, np.nan)
        for w in range(4):
            if st.wall_active[w]:
                stress[w] = -WALL_SIGN[w] * st.wall_force[w, WALL_AXIS[w]] / lengths[w]
        law = self.law
        e_el = elastic_energy(st.position, st.radius, st.pair_i, st.pair_j, st.touching, st.fs, st.mr, law.kn,
                              law.ks, law.rolling_stiffness, st.period)
        for w in range(4):
            if st.wall_active[w]:
                a = WALL_AXIS[w]
                h = st.radius - WALL_SIGN[w] * (st.position[:, a] - st.wall_position[w])
                e_el += 0.5 * law.kn * float(np.sum(h[h > 0.0] ** 2))
        e_kin = float(0.5 * np.dot(st.mass, np.einsum("ij,ij->i", st.velocity, st.velocity))
                      + 0.5 * np.dot(st.inertia, st.spin ** 2))
        nc = int(np.count_nonzero(st.touching))
        nsl = int(np.count_nonzero(st.sliding & st.touching))
        ovl = 0.0
        if nc:
            k = np.flatnonzero(st.touching)
            i, j = st.pair_i[k], st.pair_j[k]
            h = contact_geometry(st.position, st.radius, i, j, st.fn[k], st.fs[k], None, st.period)[2]
            ovl = float(np.max(h / np.minimum(st.radius[i], st.radius[j])))
        m = Measurement(time=st.time, step=st.step, wall_position=st.wall_position.copy(),
                        wall_velocity=st.wall_velocity.copy(), wall_force=st.wall_force.copy(), wall_stress=stress,
                        kinetic_energy=e_kin, elastic_energy=e_el, coordination=2.0 * nc / st.n_discs,
                        sliding_fraction=nsl / nc if nc else 0.0, max_overlap=ovl, n_contacts=nc,
                        inertial_number=self._inertial_number(stress, height), width=width, height=height,
                        rebuilds=self.rebuilds)
        if m.inertial_number > INERTIAL_LIMIT and not self._warned_inertial:
            self._warned_inertial = True
            warnings.warn(f"inertial number {m.inertial_number:.3g} > {INERTIAL_LIMIT:g} at t = {st.time:g} s: "
                          f"the platens move too fast for a quasi-static test", stacklevel=3)
        return m

    def _inertial_number(self, stress, height):
        """I = |strain rate of the platens| d_mean / sqrt(p / rho_s), p the mean platen
        pressure (or the confining pressure), rho_s the grains' density per area."""
        st = self.state
        rate = abs(st.wall_velocity[1] - st.wall_velocity[0]) / height if height > 0 else 0.0
        if rate == 0.0:
            return 0.0
        p = np.nanmean(-stress[:2])
        p = max(p, self.pressure)
        if not p > 0.0:
            return math.nan      # no confinement yet: undefined, not warned about
        rho = float(np.sum(st.mass) / np.sum(np.pi * st.radius ** 2))
        return rate * 2.0 * float(np.mean(st.radius)) / math.sqrt(p / rho)

    def _check_walls(self):
        st = self.state
        for w, name in enumerate(("bottom", "top", "left", "right")):
            if st.wall_active[w]:
                a = WALL_AXIS[w]
                out = np.flatnonzero(WALL_SIGN[w] * (st.position[:, a] - st.wall_position[w]) < 0.0)
                if out.size:
                    raise LostDiscsError(f"{out.size} disc(s) passed through the {name} wall at t = {st.time:g} s "
                                         f"(original indices {self._names(out)})")

    # ------------------------------------------------------------------ running
    def hold(self, mask):
        """Hold the discs of `mask` (n,) bool, in the original disc order: from the next step
        on they ignore their forces and move with the velocity and spin of their state
        (prescribed motion, e.g. demcell.frame's frame particles); the others are free."""
        mask = checks.array("mask", np.asarray(mask, dtype=float), (self.state.n_discs,))
        self.held = np.ascontiguousarray((mask[self.order] != 0.0).astype(np.int8))

    def set_walls(self, bottom=None, top=None, left=None, right=None):
        """Wall programme: a WallControl per wall (None: fixed). Absent walls (membrane or
        periodic sides) must stay None."""
        controls = [bottom, top, left, right]
        for w, c in enumerate(controls):
            if c is not None:
                checks.instance(f"wall {w}", c, WallControl)
                if not self.state.wall_active[w]:
                    raise InputError(f"wall {w} does not exist for lateral={self.options.lateral!r}")
        self.controls = controls

    def _default_speed(self):
        """Cap of a servo without max_speed: the platen speed giving an inertial number of
        1e-4 at the confining pressure (or the law's kn / 1000 as a stress scale)."""
        st = self.state
        p = self.pressure if self.pressure > 0.0 else 1e-3 * self.law.kn
        rho = float(np.sum(st.mass) / np.sum(np.pi * st.radius ** 2))
        height = float(st.wall_position[1] - st.wall_position[0])
        return 1e-4 * height * math.sqrt(p / rho) / (2.0 * float(np.mean(st.radius)))

    def run(self, duration=None, n_steps=None, on_interval=None, every=1, stop=None):
        """Advance by `duration` [s] or `n_steps` steps (one of them). Every `every` intervals
        of options.boundary_interval steps the specimen is measured (``Measurement``, appended
        to ``.history``) and `on_interval(specimen, measurement)` is called; `stop(specimen,
        measurement)` returning True ends the run early. Returns the last measurement."""
        opt = self.options
        if (duration is None) == (n_steps is None):
            raise InputError("run needs exactly one of duration [s] or n_steps")
        if n_steps is None:
            duration = checks.number("duration", duration, NON_NEGATIVE)
            n_steps = int(round(duration / opt.dt))
        n_steps = checks.number("n_steps", n_steps, checks.STEP_BUDGET)
        every = checks.number("every", every, Range(1, integer=True))
        programme, ctrl = self._prepare()
        self._kept.drop()       # run() evaluates its own forces (forces_now(keep=True))
        st = self.state
        interval = opt.boundary_interval
        if opt.lateral == "membrane" and self.chain.size == 0:
            self._update_boundary()
        last = None
        left = n_steps
        intervals = 0
        since = st.step % interval
        while left > 0:
            ctrl[C_WIDTH] = self.lateral_width()
            k = min(left, interval - since)
            done = self._chunk(k, programme, ctrl)
            left -= done
            since = (since + done) % interval
            if since == 0 or left == 0:
                if since == 0:
                    self._update_boundary()
                    intervals += 1
                if intervals % every == 0 or left == 0:
                    last = self.measure()
                    self.history.append(last)
                    if on_interval is not None:
                        on_interval(self, last)
                    if stop is not None and stop(self, last):
                        break
        if last is None:
            last = self.measure()
        return last

    def advance(self, n_steps):
        """n_steps steps and nothing else: no measurement, no history, no boundary-line
        detection (so not for a membrane specimen); the kernel runs from one neighbour
        rebuild to the next without returning to Python. For a caller that steps the
        specimen itself (the bridging-scale coupler's sub-steps, 003 eqs. 25-30). The checks of
        ``measure`` (lost discs) are not made; a non-finite state still raises."""
        n_steps = checks.number("n_steps", n_steps, checks.STEP_BUDGET)
        if self.options.lateral == "membrane":
            raise InputError("Specimen.advance has no free-side update: run a membrane specimen with run()")
        programme, ctrl = self._prepare(reuse=True)
        ctrl[C_WIDTH] = self.lateral_width()
        left = n_steps
        # one clock reading per call, not per chunk (process_time is a system call that costs
        # more with every thread of the process); the neighbour rebuilds are counted in it
        c0, w0 = _time.process_time(), _time.perf_counter()
        ctrl[C_FORCES_READY] = 1.0 if n_steps > 0 and self._take_pending_forces() else 0.0
        try:
            while left > 0:
                left -= self._chunk(left, programme, ctrl, clock=False)
                ctrl[C_FORCES_READY] = 0.0
        finally:
            ctrl[C_FORCES_READY] = 0.0
            self.cpu_seconds += _time.process_time() - c0
            self.wall_seconds += _time.perf_counter() - w0

    def _prepare(self, reuse=False):
        """The wall programme arrays and the control vector of the kernel. reuse: those of the
        last call if the wall controls, the options and the pressure are the same (a caller of
        advance(1) per sub-step pays for them once; the default servo speed cap is then not
        updated to the platen gap, as within one run)."""
        opt = self.options
        if opt.threads is not None:
            import numba
            numba.set_num_threads(min(opt.threads, numba.config.NUMBA_NUM_THREADS))
        key = (tuple(self.controls), opt, self.pressure, bool(self.skip_held_pairs))
        cached = self._prepared
        if reuse and cached is not None and cached[0] == key:
            return cached[1], cached[2]
        programme = programme_arrays(self.controls, self._default_speed())
        ctrl = np.zeros(N_CTRL)
        ctrl[C_GX], ctrl[C_GY] = opt.gravity
        ctrl[C_DAMP] = opt.local_damping
        ctrl[C_SKIN] = self.skin
        ctrl[C_PRESSURE] = self.pressure
        ctrl[C_EM] = opt.membrane_stiffness
        ctrl[C_LATERAL] = 1.0 if opt.lateral == "membrane" else 0.0
        ctrl[C_WALL_MU] = opt.wall_friction
        ctrl[C_MASS_DAMP] = opt.mass_damping
        ctrl[C_PATH_STEP] = -1.0
        ctrl[C_SKIP_HELD] = 1.0 if self.skip_held_pairs else 0.0
        self._prepared = (key, programme, ctrl)
        return programme, ctrl

    def load_kernels(self):
        """The step kernel called for zero steps and the kept pass's comparisons on equal
        arrays (nothing changes): Numba loads them from its cache now. For a caller that times
        its steps (the footing's loop, the bridging coupler): the loading is then part of its
        set-up, not of the first steps."""
        prepared = self._prepared
        self._chunk(0, *self._prepare(), clock=False)
        self._prepared = prepared
        self._kept.load_kernels(self)

    def _chunk(self, k, programme, ctrl, clock=True):
        """At most k steps of the kernel (one step if held targets are pending: the held discs
        are then put exactly on them); the clock, the timers (clock False: the caller times
        itself) and a rebuild after it. Returns the steps done; a non-finite state raises
        LostDiscsError."""
        st = self.state
        opt = self.options
        mode, vel, target, gain, vmax = programme
        if self._held_target is not None:
            k = min(k, 1)
        if clock:
            c0, w0 = _time.process_time(), _time.perf_counter()
        done, status = advance_steps(k, st.position, st.velocity, st.rotation, st.spin, st.radius, st.mass,
                                     st.inertia, st.external_force, self.external_moment, st.on_wall, self.held,
                                     st.pair_i, st.pair_j, st.touching, st.sliding, st.fn, st.fs, st.mr, self.work,
                                     self.geo, self.row, self.jstart, self.jcol, self.cand_disc, self.cand_wall,
                                     self.cand_fs, self.chain, self.chain_start, self.build_position, self.build_wall,
                                     st.wall_position, st.wall_velocity, st.wall_active, st.wall_force, mode, vel,
                                     target, gain, vmax, self.par, ctrl, self.block_max, self.plate_vector,
                                     self.plate_cand, self.plate_fs, self.plate_force, self.build_plate, self.net,
                                     self.path)
        if ctrl[C_PATH_STEP] >= 0.0:
            ctrl[C_PATH_STEP] += done
        if clock:
            self.cpu_seconds += _time.process_time() - c0
            self.wall_seconds += _time.perf_counter() - w0
        self.pair_updates += done * st.n_pairs
        st.step += done
        st.time += done * opt.dt
        if self._held_target is not None and done > 0:
            idx, x, theta = self._held_target
            st.position[idx] = x
            if self.law.rotations:
                st.rotation[idx] = theta
            self._held_target = None
        if status == NONFINITE:
            self._check_finite()
            raise LostDiscsError(f"non-finite state at t = {st.time:g} s (time step too large?)")
        if status == REBUILD:
            self._rebuild()
        return done

    # ------------------------------------------------------------------ coupling interface
    def drive_held(self, position, rotation):
        """Prescribe the held discs' next configuration: position (n, 2) [m] and rotation (n,)
        [rad], in the original disc order (only the held discs' rows are read). Their velocity
        and spin become (target - current) / dt, and after the next step they sit exactly on
        the targets (003 eq. 17: the virtual interface particles follow the continuum)."""
        n = self.state.n_discs
        position = checks.array("position", position, (n, 2))[self.order]
        rotation = checks.array("rotation", rotation, (n,))[self.order]
        idx = np.flatnonzero(self.held)
        if idx.size == 0:
            raise InputError("drive_held: no disc is held (Specimen.hold first)")
        st = self.state
        dt = self.options.dt
        x = position[idx].copy()
        theta = rotation[idx].copy()
        st.velocity[idx] = (x - st.position[idx]) / dt
        st.spin[idx] = (theta - st.rotation[idx]) / dt if self.law.rotations else 0.0
        self._held_target = (idx, x, theta)

    def follow_held_path(self, n_steps, start, velocity, acceleration):
        """n_steps steps (as ``advance``) with the held discs on the constant-acceleration path
        x(t) = start + velocity t + acceleration t^2 / 2, t from the call's start (003 eqs.
        25-26, the sub-steps of one coarse step): after step s they sit on x((s + 1) dt), and
        their half-step velocity is x((s + 1) dt) - x(s dt) over dt (the first step's absorbs
        any jump from where they are to `start`). start, velocity, acceleration: (n, 3)
        [m, m/s, m/s^2 for x, y; rad, rad/s, rad/s^2 for the rotation] in the original disc
        order, only the held rows read. One call = n_steps calls of drive_held + advance(1),
        except that the contact law of a step sees the held discs' velocity of the step
        before (as a free disc's), not that of the step ahead."""
        n = self.state.n_discs
        rows = np.flatnonzero(self.held)
        if rows.size == 0:
            raise InputError("follow_held_path: no disc is held (Specimen.hold first)")
        source = self.order[rows]
        names = ("start", "velocity", "acceleration")
        arrays = [np.asarray(value) for value in (start, velocity, acceleration)]
        for name, value in zip(names, arrays):
            if value.shape != (n, 3) or value.dtype.kind not in "biuf":
                checks.array(name, value, (n, 3))          # the refusal names the shape or type
        bad = set_held_path(self.path, rows, source, *(np.ascontiguousarray(a, dtype=np.float64) for a in arrays))
        if bad >= 0:
            k, a = divmod(bad, 3)
            row = arrays[a][source[k]]
            raise InputError(f"{names[a]}[{int(source[k])}] (a held disc) must be finite, got {row.tolist()}")
        self._held_target = None
        programme, ctrl = self._prepare(reuse=True)
        ctrl[C_PATH_STEP] = 0.0
        try:
            self.advance(n_steps)
        finally:
            ctrl[C_PATH_STEP] = -1.0

    def set_skip_held_pairs(self, skip):
        """skip True: no contact between two held discs from the next step on (their history
        cleared, no force in ``disc_forces``: a coupler that drops those contacts need not
        subtract them). Default False (demcell.frame's held frame copies keep theirs)."""
        self.skip_held_pairs = bool(skip)

    #: the arrays of the contact pass that forces_now(keep=True) keeps for the next step
    PASS_STATE = ("external_force", "on_wall", "touching", "sliding", "fn", "fs", "mr", "wall_force")
    PASS_ENGINE = ("external_moment", "cand_fs", "plate_fs", "plate_force")
    #: the per-pair scratch arrays the pass fills, and the arrays whose values it reads
    PASS_SCRATCH = ("work", "geo")
    PASS_INPUTS_STATE = ("position", "velocity", "rotation", "spin", "wall_position", "wall_velocity")
    PASS_INPUTS_ENGINE = ("plate_vector", "held", "par")

    def forces_now(self, keep=False):
        """(n, 3), original order: the net force and moment on every disc at the current
        configuration (what ``disc_forces`` will report after the next step, the forces at the
        start of that step), the contact history not committed. For a caller that needs the
        forces at the end of its steps (the bridging coupler's corrector, 003 eq. 33).

        keep: the contact pass is also kept (the history as the next step will update it, the
        pair forces, the wall and plate loads), and the next ``advance`` or
        ``follow_held_path`` starts its first step from it instead of evaluating the same
        forces again: one contact pass per call, not two, and the same numbers bit for bit
        (the same kernels on the same arrays). It is used only if the engine is then still
        as forces_now saw it (positions, velocities, rotations, spins, plate, walls, held
        discs, neighbour list, law and options: compared at that step); otherwise it is
        dropped and the step evaluates its forces. Either way the committed state (and
        ``checkpoint_arrays``) is not changed by this call."""
        st = self.state
        programme, ctrl = self._prepare(reuse=True)
        net = np.empty_like(self.net)
        kept = self._kept.prepare(self)
        current_forces(st.position, st.velocity, st.spin, st.radius, st.mass, kept["external_force"],
                       kept["external_moment"], kept["on_wall"], self.held, st.pair_i, st.pair_j, kept["touching"],
                       kept["sliding"], kept["fn"], kept["fs"], kept["mr"], kept["work"], kept["geo"], self.row,
                       self.jstart, self.jcol, self.cand_disc, self.cand_wall, kept["cand_fs"], self.chain,
                       self.chain_start, st.wall_position, st.wall_velocity, kept["wall_force"], self.par, ctrl,
                       self.plate_vector, self.plate_cand, kept["plate_fs"], kept["plate_force"], net)
        if keep and self._held_target is None:
            self._kept.keep(self, self._pass_scalars())
        out = np.empty_like(net)
        out[self.order] = net
        return out

    def _pass_scalars(self):
        """The scalars a kept pass depends on besides its input arrays: the step, the
        neighbour list, the skipped held pairs, no pending held target (a pass is kept only
        then), the prepared programme."""
        st = self.state
        return st.step, self.rebuilds, id(st.pair_i), self.skip_held_pairs, self._held_target is None, self._prepared[0]

    def _take_pending_forces(self):
        """True after copying in the contact pass kept by forces_now(keep=True), if the engine
        is still as it saw it (``KeptPass.take``); the pass is dropped either way."""
        return self._kept.take(self, self._pass_scalars())

    def disc_forces(self):
        """(n, 3) array, original disc order: the net force (f_x, f_y) [N/m] and moment [N m/m]
        of the last step on every disc, held ones included: its contacts plus the walls, the
        plate and the pressure (003 eq. 9: f_int + f_ext at the centroid; no gravity, no
        damping). Zeros before the first step."""
        out = np.empty_like(self.net)
        out[self.order] = self.net
        return out

    # ------------------------------------------------------------------ rigid plate
    def set_plate(self, plate):
        """Put a rigid plate (plate.Plate) on the specimen from the next step on (None: take it
        away). Its position is then advanced by the engine (``plate_position``)."""
        if plate is None:
            self.plate_vector = no_plate()
        else:
            checks.instance("plate", plate, Plate)
            self.plate_vector = plate.vector(self.law.friction)
        self.plate_force[:] = 0.0
        self._rebuild()

    def set_plate_velocity(self, vx, vy):
        """Plate velocity (v_x, v_y) [m/s] from the next step on."""
        if self.plate_vector[PL_ACTIVE] < 0.5:
            raise InputError("the specimen has no plate (set_plate first)")
        self.plate_vector[PL_VX] = checks.number("vx", vx)
        self.plate_vector[PL_VY] = checks.number("vy", vy)

    def plate_position(self):
        """(x0, x1, y) [m] of the plate now (nan without a plate)."""
        if self.plate_vector[PL_ACTIVE] < 0.5:
            return (math.nan, math.nan, math.nan)
        return tuple(float(v) for v in self.plate_vector[:3])

    def plate_reaction(self):
        """(2,) force the plate exerted on the discs in the last step [N per m of depth]; the
        load on a footing pushed down is -plate_reaction()[1]."""
        return self.plate_force.copy()

    def isotropic_stage(self, pressure, stress_tolerance=1e-3, energy_tolerance=1e-6, max_time=30.0,
                        max_speed=None, gain=None):
        """Stress-controlled isotropic stage (dns-spec A7 phase 0): every wall servo-controlled
        to the stress -pressure [N/m] (and the free sides under that confining pressure) until
        |sigma_w + p| < stress_tolerance p on every wall and E_kin / E_el < energy_tolerance,
        at most max_time [s]. The walls then stop; returns (converged, last measurement)."""
        pressure = checks.number("pressure", pressure, POSITIVE)
        stress_tolerance = checks.number("stress_tolerance", stress_tolerance, POSITIVE)
        energy_tolerance = checks.number("energy_tolerance", energy_tolerance, POSITIVE)
        max_time = checks.number("max_time", max_time, POSITIVE)
        self.pressure = pressure
        control = WallControl("stress", stress=-pressure, gain=gain, max_speed=max_speed)
        active = self.state.wall_active
        self.set_walls(*[control if active[w] else None for w in range(4)])

        def converged(spec, m):
            servo = np.array([bool(a) for a in active])
            ok = np.all(np.abs(m.wall_stress[servo] + pressure) < stress_tolerance * pressure)
            return bool(ok and m.elastic_energy > 0.0 and m.kinetic_energy < energy_tolerance * m.elastic_energy)

        last = self.run(duration=max_time, stop=converged)
        done = converged(self, last)
        self.set_walls()
        self.state.wall_velocity[:] = 0.0
        return done, last

    def set_parallel_threshold(self, n_pairs):
        """Run the pair and disc loops in parallel from n_pairs listed pairs on (default
        contacts.PARALLEL_MIN_PAIRS; 0: always, as the thread-independence test does)."""
        self.par[P_PARALLEL_MIN] = checks.number("n_pairs", n_pairs, Range(0, integer=True))

    def throughput(self):
        """Pair updates per CPU second and per wall second of the time loop so far."""
        return (self.pair_updates / self.cpu_seconds if self.cpu_seconds > 0 else 0.0,
                self.pair_updates / self.wall_seconds if self.wall_seconds > 0 else 0.0)

    def set_mass_damping(self, c_m):
        """Mass damping c_m [1/s] from the next step on (003 eqs. 9, 29): a run may settle
        with one and load with another."""
        self.options = self.options.with_(mass_damping=c_m)

    def set_local_damping(self, alpha):
        """Local non-viscous damping alpha in [0, 1) from the next run on (000 section
        3.2.1): a run may settle with it and load without (004) or with it (000's DNS)."""
        self.options = self.options.with_(local_damping=alpha)

    #: engine arrays a checkpoint keeps besides the SpecimenState: the plate (position,
    #: velocity, friction and active flag in its vector; its last reaction; the tangential
    #: springs of the discs on it), the held discs, the last step's net forces (disc_forces),
    #: the moments the walls put on the discs, the mass damping c_m [1/s]
    RUN_ARRAYS = ("plate_vector", "plate_force", "plate_fs", "held", "net", "external_moment")

    def checkpoint_arrays(self):
        """{name: array} of everything a continued run needs (``restored`` reads it back): the
        SpecimenState (contact history included), the original disc order, the engine
        arrays of RUN_ARRAYS under 'engine_<name>' and the mass damping."""
        out = dict(self.state.to_dict(), order=self.order.copy(),
                   engine_mass_damping=np.array(float(self.options.mass_damping)))
        for name in self.RUN_ARRAYS:
            out["engine_" + name] = np.array(getattr(self, name), copy=True)
        return out

    def save(self, path, **extra):
        """Checkpoint of the state (.npz; the original disc order in `order`, the plate, the
        held discs, the mass damping: ``checkpoint_arrays``) and the arrays of `extra` (a
        scene's own: its phase, its reference configuration)."""
        np.savez(path, **extra, **self.checkpoint_arrays())

    @classmethod
    def restored(cls, checkpoint, law, options):
        """The specimen of a checkpoint written by ``save`` (a dict or an open .npz), its discs
        in the saved order (options.reorder is not applied again), with its plate, held discs,
        last forces and mass damping (a checkpoint without them, written before they were
        kept, restores a specimen without plate and without held discs). The mass damping of
        `options` must be the saved one (InputError otherwise). Stepped on from here it
        repeats the saved run bit for bit."""
        keys = set(checkpoint.keys())
        if "engine_mass_damping" in keys:
            saved = float(np.asarray(checkpoint["engine_mass_damping"]))
            if saved != float(options.mass_damping):
                raise InputError(f"the specimen checkpoint has mass damping {saved:g} 1/s, the options "
                                 f"{float(options.mass_damping):g} 1/s")
        specimen = cls(SpecimenState.from_dict(checkpoint), law, options.with_(reorder=False))
        order = np.asarray(checkpoint["order"], np.int64)
        n = specimen.state.n_discs
        if order.shape != (n,) or not np.array_equal(np.sort(order), np.arange(n)):
            raise InputError(f"specimen checkpoint: 'order' is not a permutation of {n} discs")
        specimen.order = order
        present = [name for name in cls.RUN_ARRAYS if "engine_" + name in keys]
        if not present:
            return specimen
        if len(present) != len(cls.RUN_ARRAYS):
            missing = sorted(set(cls.RUN_ARRAYS) - set(present))
            raise InputError(f"specimen checkpoint lacks the array(s) {', '.join('engine_' + m for m in missing)}")
        for name in cls.RUN_ARRAYS:
            current = getattr(specimen, name)
            value = np.asarray(checkpoint["engine_" + name])
            if value.shape != current.shape or not np.all(np.isfinite(value)):
                raise InputError(f"specimen checkpoint: engine_{name} has shape {value.shape} (expected "
                                 f"{current.shape}) or is not finite")
            setattr(specimen, name, np.ascontiguousarray(value.astype(current.dtype)))
        # the plate's candidate discs from the restored plate, then its springs and reaction
        # (set after the rebuild, which forgets the springs of discs no longer near it)
        plate_fs, plate_force = specimen.plate_fs.copy(), specimen.plate_force.copy()
        specimen._rebuild()
        specimen.plate_fs[:] = plate_fs
        specimen.plate_force[:] = plate_force
        return specimen

    def restore(self, checkpoint):
        """Bring this specimen to a checkpoint of ``checkpoint_arrays`` in place (the same
        law and options; ``restored``'s checks): a caller holding this object (a coupler, a
        demo) continues with it. The caller's setting of ``set_skip_held_pairs`` is kept."""
        skip = self.skip_held_pairs
        self.__dict__.update(type(self).restored(checkpoint, self.law, self.options).__dict__)
        self.skip_held_pairs = skip
