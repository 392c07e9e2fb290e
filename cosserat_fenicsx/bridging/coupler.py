"""The coupled time loop of the bridging-scale method (003 eqs 25-34, spec sections 3-4).

One coarse step t_n -> t_n+1 = t_n + dt with m DEM sub-steps dt_m = dt / m:

    1. interface data at t_n: u_V = N_V d^n, v_V = N_V v^n, a_V = N_V a^n at the virtual
       grains' reference centres (the coarse motion they follow);
    2. continuum predictor (eqs 31-32): d^{n+1}, v~^{n+1};
    3. m DEM sub-steps (eqs 27-30, the specimen's leapfrog with mass damping c_m) in ONE
       engine call: after sub-step j the virtual grains sit on
           u_V^[j] = u_V + t v_V + t^2/2 a_V,   t = j dt_m                (eqs 25-26)
       (constant coarse acceleration; translations and the Cosserat rotation, eq 17), their
       half-step velocity the chord of that parabola, set after the step's forces;
    4. coarse forces f_c = N_R^T F_R + N_V^T F_V (eq 16): F_R the net contact and plate forces
       on the real grains, F_V the reactions of the real grains on the virtual ones (their
       mutual contacts are not computed: the continuum carries that stiffness), both at
       q^{n+1}, the configuration after the last sub-step (spec decision 2: forces at q, not
       at N d + Q q; the engine evaluates them without committing the contact history);
    5. continuum corrector (eqs 33-34) with f_c.

Gravity (the continuum's `gravity`, which must be the engine's): the engine moves the grains
under their weight, the continuum carries its own (ExplicitCosserat's f_g), and F_R in the
coarse forces includes the real grains' weight m_p g (eq 16's external force), so that the
nodes of the region carry the weight of the grains they represent.

The coarse mass of the DEM-region nodes is the grains' row-sum lumped N_R^T m, N_R^T J (eq 5
lumped; HRZ for P2, whose row sums can be negative), added once; the elements of the region carry no Cosserat stiffness or mass
(ExplicitCosserat(inactive_cells=region_cells(...))). Diagnostic each step:
max |N_R d - P q| / r_min = max |N_R (d - d_hat(q))| / r_min (how far the coarse nodes are
from the projection of the grains), every `diagnose_every` steps (or on request).

Energy, and the region's nodes (region_nodes). Let C be the dofs that carry continuum mass
(the elements outside the region) or drive a virtual grain (N_V != 0), and S the region's
other nodes (inside Omega_D, seen by real grains only). The undamped system with the energy

    H = 1/2 ddot_C^T M_C ddot_C + 1/2 d^T K d + 1/2 qdot^T M_p qdot + W(q_R, N_V d)

(K the Cosserat stiffness outside the region, M_C any fixed positive mass of C, W the contact
energy of the real grains among themselves and with the virtual ones, q_V = N_V d, eq 17)
has the Lagrange equations

    M_p q_R'' = F_R = -dW/dq_R                                  (eq 15: what the engine integrates)
    M_C d_C'' = -(K d)_C + (N_V^T F_V)_C,  F_V = -dW/dq_V       (coarse_force="interface")

and d_S enters H nowhere (no mass, stiffness or virtual grain): it is free, and
region_nodes="projected" sets it to eq 3's d_hat(q) = M^-1 N^T M_p q (consistent M, eq 5)
after every step, with velocity d_hat(qdot) and acceleration M^-1 N^T F_R. M_C keeps the
grains' lumped share on the nodes of Gamma_I (the stable step is unchanged; it only changes
H's kinetic term). Eq 16 instead drives all of the region's nodes by N_R^T F_R,
(M_FE + M_D) d'' = -K d + N_R^T F_R + N_V^T F_V with M_D = N_R^T M_p N_R (lumped here). The
energy that counts the grains' kinetic energy once, E = 1/2 d'^T M_FE d' + 1/2 q'^T M_p q' +
1/2 d^T K d + W, then changes at the rate (eq 15 for F_R)

    dE/dt = d'^T (M_FE d'' + K d - N_V^T F_V) = (N_R d')^T M_p (q_R'' - N_R d''),

which vanishes exactly when d = d_hat(q) on every node of the region with the consistent M_D
(N_R^T M_p Q = 0, eq 12). That constraint cannot hold at the nodes of Gamma_I, which also
carry M_FE and K: substituting it into eq 16 leaves there M_D (d - d_hat)'' = r with
r = -(M_FE d'' + K d - N_V^T F_V) != 0, and M_D^-1 spreads r to every node of the region. It
would hold only if the grains received the constraint's reaction M_p N_R M_D^-1 r in eq 15
(the continuum's inertia and stiffness at Gamma_I acting on the grains, Wagner and Liu's
full bridging scale); the engine integrates eq 15 without it. So with eq 16 the nodes drift
from d_hat(q) and E has a source term of no sign (the slow growth of the undamped patch,
docs/results/bsm.md), whether M_D is lumped or consistent. Time integration: at m = 1 the
loop is velocity Verlet of H (the grains' leapfrog is Verlet for positions; F_R and F_V are
evaluated at (q^{n+1}, N_V d^{n+1})), symplectic, so H's error stays bounded while the
contact law is elastic (no sliding); at m > 1 the virtual grains follow the predictor's
parabola inside the step (eqs 25-26), a multiple-time-step scheme with no such proof
(measured: docs/results/bsm.md).

MPI: the DEM lives on rank `root` (0); the continuum is distributed. Grain forces are
broadcast, interpolated values reduced to the root (shape_map.py).

The DEM engine is used through the `FineScale` interface (demcell.specimen.Specimen with the
bridging extensions: follow_held_path, forces_now, disc_forces, set_skip_held_pairs, load_kernels); its state is read through
`state.position`, `state.rotation` and `order` (original index of each engine disc), its
gravity through `options.gravity`.
"""
import abc
import math
import time
from dataclasses import dataclass, field

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from cosserat_fenicsx.bridging.kernels import all_finite, any_outside, set_path_rows
from cosserat_fenicsx.bridging.projection import ScaleProjection
from cosserat_fenicsx.bridging.shape_map import CosseratShapeMap, sum_over_ranks
from cosserat_fenicsx.dynamics.explicit import STATE_KEYS
from cosserat_fenicsx.validation import InputError

PHASES = ("dem", "projection", "fe", "interface")


class BridgingStopped(RuntimeError):
    """The coupled run stopped; the message names the cause (grains left the region, ...)."""


class FineScale(abc.ABC):
    """What the coupler needs of the DEM region (demcell.specimen.Specimen provides it).
    Disc arrays are in the original order of the region (real grains, then virtual)."""

    @abc.abstractmethod
    def follow_held_path(self, n_steps, start, velocity, acceleration):
        """n DEM steps with the held (virtual) discs on x(t) = start + velocity t +
        acceleration t^2 / 2 (arrays (n, 3): x, y, rotation; only the held rows read), sitting
        on x((s + 1) dt) after step s (003 eqs 25-26)."""

    @abc.abstractmethod
    def forces_now(self, keep=False):
        """(n, 3): net contact (and plate) force [N/m] and moment [N m/m] on every disc at the
        current configuration, held ones included, the contact history not committed; keep:
        the next step may start from this contact pass instead of repeating it (the same
        numbers; the coupler asks for it, since its next call steps on from here)."""

    @abc.abstractmethod
    def disc_forces(self):
        """(n, 3): the same as forces_now, at the start of the last step."""

    @abc.abstractmethod
    def load_kernels(self):
        """Load (compile or read from Numba's cache) the step's kernels now, changing nothing."""

    @abc.abstractmethod
    def set_skip_held_pairs(self, skip):
        """skip True: no contact between two held discs."""

    @abc.abstractmethod
    def checkpoint_arrays(self):
        """{name: array}: everything a continued run needs (restore reads it back)."""

    @abc.abstractmethod
    def restore(self, arrays):
        """Bring the engine, in place, to the state of a checkpoint_arrays() dict."""


@dataclass
class Timings:
    """Wall seconds per phase on this rank. (No per-phase CPU time: process_time() costs
    0.3 ms per call in a process with Numba's and MPI's threads, more than some phases.)"""
    wall: dict = field(default_factory=lambda: {p: 0.0 for p in PHASES})

    def add(self, phase, wall0):
        self.wall[phase] += time.perf_counter() - wall0

    def as_dict(self):
        return {"wall_s": dict(self.wall)}


def in_original_order(order, array):
    """Engine arrays (disc k is original disc order[k]) back in the original order."""
    out = np.empty_like(array)
    out[order] = array
    return out


def _declare_specimen():
    """demcell's bounded specimen implements FineScale (it cannot import this module)."""
    from demcell.specimen import Specimen
    FineScale.register(Specimen)


def _rows_at(saved, points, scale, what):
    """(n,) index into `saved` (k, 2) of each of `points` (n, 2) [m]: the saved point at the
    same coordinates within 1e-8 scale; InputError naming the first point without one."""
    from scipy.spatial import cKDTree
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    if len(points) == 0:
        return np.zeros(0, dtype=np.int64)
    if len(saved) == 0:
        dist, found = np.full(len(points), np.inf), np.zeros(len(points), dtype=np.int64)
    else:
        dist, found = cKDTree(saved).query(points)
    bad = np.flatnonzero(~(dist <= 1e-8 * scale))
    if bad.size:
        x, y = points[bad[0]]
        raise InputError(f"no saved {what} at ({x:.6g}, {y:.6g}) (and {bad.size - 1} more): not the same mesh")
    return np.asarray(found, dtype=np.int64)


class BridgingCoupler:
    """Bridging-scale coupling of an ExplicitCosserat continuum with a DEM region.

    continuum: cosserat_fenicsx.dynamics.ExplicitCosserat built with
        inactive_cells=region_cells(mesh, region.box) (all ranks);
    region: bridging.region.DemRegion (all ranks: the reference positions and masses);
    fine: the FineScale engine of the region's discs in the region's order, real grains free
        and virtual ones held (rank `root` only; None elsewhere);
    dt: coarse step [s]; substeps: m (the engine's dt must be dt / m);
    force_time: "end" (grain forces at q^{n+1}) or "lagged" (at the start of the last sub-step);
    coarse_force: "grains" (003 eq 16: N_R^T F_R + N_V^T F_V) or "interface" (N_V^T F_V
        only: the region's nodes are not driven by the real grains, a coupling derived from
        a potential, which conserves energy where "grains" slowly does not; the region's
        nodes then do not follow the grains, so the mismatch diagnostic is meaningless);
        default "grains", or "interface" with region_nodes="projected" (the only one it takes);
    region_nodes: "integrated" (default: every node of the region integrated with eqs 31-34
        under coarse_force) or "projected" (the region's own nodes, those with no continuum
        mass that drive no virtual grain, set to d_hat(q), d_hat(qdot), d_hat(M_p^-1 F_R)
        (eqs 3-5) after each step; the other nodes under N_V^T F_V: the conservative
        coupling of the module docstring, `projected_dofs` marks the set ones).
    """

    def __init__(self, continuum, region, fine, dt, substeps, fine_dt=None, root=0, diagnose_every=10,
                 force_time="end", coarse_force=None, region_nodes="integrated"):
        self.continuum, self.region, self.fine = continuum, region, fine
        self.comm = continuum.comm
        self.root = root
        self.is_root = self.comm.rank == root
        if not (isinstance(substeps, (int, np.integer)) and substeps >= 1):
            raise InputError(f"substeps must be an integer >= 1, got {substeps!r}")
        if not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0.0):
            raise InputError(f"dt must be a finite number > 0 [s], got {dt!r}")
        if self.is_root:
            _declare_specimen()
        if self.is_root and not isinstance(fine, FineScale):
            raise InputError("the DEM region's engine must implement bridging.coupler.FineScale "
                             "(follow_held_path, forces_now, disc_forces, set_skip_held_pairs, load_kernels)")
        if force_time not in ("end", "lagged"):
            raise InputError(f"force_time must be 'end' or 'lagged', got {force_time!r}")
        self.force_time = force_time
        if region_nodes not in ("integrated", "projected"):
            raise InputError(f"region_nodes must be 'integrated' or 'projected', got {region_nodes!r}")
        if coarse_force is None:
            coarse_force = "interface" if region_nodes == "projected" else "grains"
        if coarse_force not in ("grains", "interface"):
            raise InputError(f"coarse_force must be 'grains' or 'interface', got {coarse_force!r}")
        if region_nodes == "projected" and coarse_force != "interface":
            raise InputError("region_nodes='projected' takes coarse_force='interface' only (N_R^T F_R on the "
                             "nodes that drive the virtual grains is the non-conservative term)")
        self.coarse_force = coarse_force
        self.region_nodes = region_nodes
        if self.is_root:
            # the contacts between two virtual grains are the continuum's (decision 1)
            fine.set_skip_held_pairs(True)
        self.dt, self.substeps = float(dt), int(substeps)
        self.dt_fine = self.dt / self.substeps
        if fine_dt is not None and abs(fine_dt - self.dt_fine) > 1e-12 * self.dt_fine:
            raise InputError(f"the DEM step {fine_dt:.6g} s must be dt / substeps = {self.dt_fine:.6g} s")
        self.timings = Timings()
        w0 = time.perf_counter()
        spaces = {name: continuum.subspace(name) for name in ("u1", "u2", "phi")}
        self.shape = CosseratShapeMap(continuum.space, region.position, spaces=spaces)
        # the virtual grains alone: the interface data of every step
        self.shape_virtual = CosseratShapeMap(continuum.space, region.position[region.virtual], spaces=spaces)
        self.diagnose_every = int(diagnose_every)
        n_real = region.n_real
        n_u, n_phi = self.shape.matrices(root)
        elements = self.shape.counted_elements(root)
        self.projection = None
        refusal = None
        if self.is_root:
            try:
                self.projection = ScaleProjection(n_u[:n_real], region.mass[:n_real],
                                                  region.inertia[:n_real], n_phi[:n_real],
                                                  element_of_particle=elements[:n_real])
            except InputError as error:
                refusal = str(error)
        # a refusal on the root reaches every rank (no rank waits in a collective)
        refusal = self.comm.bcast(refusal, root=root)
        if refusal:
            raise InputError(refusal)
        self._weight = self._grain_weight(continuum.gravity)
        # coarse mass of the DEM-region nodes: N_R^T m (u1, u2), N_R^T J (phi), added once
        weights = np.zeros((region.n_discs, 3))
        weights[:n_real] = np.column_stack([region.mass[:n_real], region.mass[:n_real],
                                            region.inertia[:n_real]])
        continuum_mass = continuum.mass.array.copy()
        added = continuum.mass.duplicate()
        added.set(0.0)
        self.shape.add_lumped_mass(weights, added)
        continuum.add_mass(added)
        # the dofs some virtual grain's shape functions see (N_V != 0), assembled over ranks
        added.set(0.0)
        self.shape_virtual.add_lumped_mass(np.ones((region.n_virtual, 3)), added)
        drives_virtual = added.array > 0.0
        added.destroy()
        # S: the region's own dofs (no continuum mass, no virtual grain), set to d_hat(q) when
        # projected; projected_dofs is S then and empty otherwise
        self.own_dofs = continuum.free_dofs & (continuum_mass == 0.0) & ~drives_virtual
        self._own = self._own_maps(spaces, refuse=region_nodes == "projected")
        self.projected_dofs = self.own_dofs if region_nodes == "projected" else np.zeros_like(self.own_dofs)
        self._projected = self._own if region_nodes == "projected" else []
        stable = continuum.stable_time_step()
        self.stable_dt = stable
        if self.dt > stable["power"]:
            raise InputError(f"coarse dt = {self.dt:.6g} s is above the continuum's stable step "
                             f"{stable['power']:.6g} s (power iteration with the grains' mass; "
                             f"rotational 2/omega_r = {stable['rotational']:.3g} s)")
        self.coupling_force = continuum.mass.duplicate()
        self.coupling_force.set(0.0)
        self.r_min = float(region.radius[:n_real].min())
        self.is_virtual = region.is_virtual
        self.steps = 0
        self.max_mismatch = 0.0
        self.last_mismatch = 0.0
        # (engine order, engine rows of the real grains): step()'s escape check
        self._real_rows = None
        # the virtual grains' path of a step (start, velocity, acceleration), filled by step()
        self._path = tuple(np.zeros((region.n_discs, 3)) for _ in range(3))
        self._virtual_rows = np.arange(region.n_real, region.n_discs)
        self._virtual_position = np.zeros((region.n_virtual, 3))
        self._virtual_position[:, :2] = region.position[region.virtual]
        self._safe_box = region.safe_box()
        self._load_kernels()
        # shape maps, projection, mass and stable step: once, apart from the loop's phases
        self.setup_seconds = time.perf_counter() - w0

    def _grain_weight(self, gravity):
        """(n_real, 2) weights m_p g of the real grains [N/m] added to F_R (None without
        gravity); the engine's gravity must be the continuum's (refused on every rank)."""
        refusal = None
        if self.is_root:
            engine = tuple(float(g) for g in self.fine.options.gravity)
            if engine != tuple(gravity):
                refusal = (f"the DEM region's gravity {engine} m/s^2 is not the continuum's {tuple(gravity)}: "
                           "the grains and the continuum must fall under the same g")
        refusal = self.comm.bcast(refusal, root=self.root)
        if refusal:
            raise InputError(refusal)
        if not any(gravity):
            return None
        mass = self.region.mass[:self.region.n_real]
        return np.column_stack([mass * gravity[0], mass * gravity[1]])

    def _load_kernels(self):
        """Every compiled function of a coarse step called once on the current state without
        changing it: Numba loads them from its cache here, in the set-up, rather than in the
        first steps a run times."""
        c = self.continuum
        interface = self.shape_virtual.local_values([c.displacement, c.velocity, c.acceleration])
        self.shape.interpolate_translation(c.displacement, self.root)
        work = self.coupling_force.duplicate()
        self.shape.add_transpose(np.zeros((self.region.n_discs, 3)), work)
        work.destroy()
        if self.is_root:
            self.fine.load_kernels()
            none = np.zeros(0, dtype=np.int64)
            set_path_rows(none, interface, self._virtual_position, *self._path)
            forces = self.fine.forces_now()
            all_finite(forces)
            any_outside(self.fine.state.position, none, *self._safe_box)

    def _own_maps(self, spaces, refuse):
        """Per component (u1, u2, phi): (owned W dofs of own_dofs, their rows in the
        projection's coefficient arrays, column of the coefficients); refuse: a region
        without such dofs is an InputError."""
        nodes = self.comm.bcast((self.projection.nodes_u, self.projection.nodes_phi)
                                if self.is_root else None, root=self.root)
        n_owned = self.own_dofs.size
        maps, found = [], 0
        for c, name in enumerate(("u1", "u2", "phi")):
            space, to_parent = spaces[name]
            index_map = space.dofmap.index_map
            local = np.arange(index_map.size_local, dtype=np.int32)
            parent = np.asarray(to_parent)[local]
            keep = parent < n_owned
            local, parent = local[keep], parent[keep]
            keep = self.own_dofs[parent]
            local, parent = local[keep], parent[keep]
            glob = np.asarray(index_map.local_to_global(local))
            node_list = nodes[0] if c < 2 else nodes[1]
            rows = np.searchsorted(node_list, glob)
            if np.any(rows >= node_list.size) or np.any(node_list[np.minimum(rows, node_list.size - 1)] != glob):
                raise InputError("region_nodes='projected': a massless region dof is not a node of the projection")
            maps.append((parent, rows, c))
            found += parent.size
        if refuse and self.comm.allreduce(found) == 0:
            raise InputError("region_nodes='projected': the region has no node free of continuum mass and "
                             "virtual grains (refine the mesh or enlarge the region)")
        return maps

    def projection_gap(self):
        """(max |d - d_hat(q)| [m] over the translations, the same [rad] over the rotations) at
        the region's own nodes (own_dofs), global (collective): zero to round-off with
        region_nodes="projected", the drift of those nodes from eq 3 under eq 16."""
        coefficients = None
        if self.is_root:
            q = self.grain_motion()[self.region.real]
            coefficients = self.projection.project(q)
            coefficients = (coefficients.u, coefficients.phi)
        u, phi = self.comm.bcast(coefficients, root=self.root)
        gap = np.zeros(2)
        values = self.continuum.displacement.array
        for dofs, rows, comp in self._own:
            if dofs.size:
                exact = u[rows, comp] if comp < 2 else phi[rows]
                gap[comp // 2] = max(gap[comp // 2], float(np.abs(values[dofs] - exact).max()))
        return tuple(self.comm.allreduce(float(g), op=MPI.MAX) for g in gap)

    def _set_projected_nodes(self, q, forces):
        """Projected region nodes: d = d_hat(q), v = d_hat(qdot), a = M^-1 N^T F_R (eqs 3-5,
        the consistent M; the grains' half-step velocities), owned values then ghosts."""
        coefficients = None
        if self.is_root:
            st = self.fine.state
            real = self.region.real
            qdot = np.column_stack([in_original_order(self.fine.order, st.velocity),
                                    in_original_order(self.fine.order, st.spin)])[real]
            weights = np.column_stack([self.region.mass, self.region.mass, self.region.inertia])[real]
            coefficients = [self.projection.project(x) for x in (q[real], qdot, forces[real] / weights)]
            coefficients = [(k.u, k.phi) for k in coefficients]
        if self.comm.size > 1:
            coefficients = self.comm.bcast(coefficients, root=self.root)
        c = self.continuum
        for vec, (u, phi) in zip((c.displacement, c.velocity, c.acceleration), coefficients):
            values = vec.array
            for dofs, rows, comp in self._projected:
                values[dofs] = u[rows, comp] if comp < 2 else phi[rows]
            vec.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)

    # ------------------------------------------------------------------ grain state
    def grain_motion(self):
        """(n, 3) displacements and rotations of all discs from the region's reference, on root."""
        st = self.fine.state
        order = self.fine.order
        q = np.empty((self.region.n_discs, 3))
        q[order, :2] = st.position
        q[:, :2] -= self.region.position
        q[order, 2] = st.rotation
        return q

    def coupling_forces(self):
        """(n, 3) grain forces entering eq 16 (root): all forces on real grains, and on the
        virtual ones only those of real grains (the engine skips virtual-virtual contacts), at
        the current configuration q^{n+1} ("end") or at the start of the last sub-step
        ("lagged": one fine step behind, kept to show the instability it causes). All rows:
        with coarse_force="interface" step() passes only the virtual rows to the nodes."""
        if self.force_time == "end":
            # the first sub-step of the next coarse step needs the same contact pass: kept
            forces = np.array(self.fine.forces_now(keep=True), dtype=float, copy=True)
        else:
            forces = np.array(self.fine.disc_forces(), dtype=float, copy=True)
        return forces

    def _stop(self, message):
        """Collective stop: any rank's cause is raised on all."""
        messages = self.comm.allgather(message) if self.comm.size > 1 else [message]
        causes = [m for m in messages if m]
        if causes:
            raise BridgingStopped(f"bridging-scale run stopped at t = {self.continuum.time:.6g} s "
                                  f"(step {self.steps}): {causes[0]}")

    # ------------------------------------------------------------------ checkpoint
    def state(self):
        """{name: array} of this rank, everything a continued run needs: 'continuum_<k>' the
        continuum's owned values (ExplicitCosserat.state) with their dofs' coordinates and
        components ('continuum_dof_coordinates', 'continuum_dof_component': a restart matches
        them whatever its partition), 'coupler_wall' this rank's per-phase wall seconds, and
        on the root 'fine_<k>' the DEM region's engine (FineScale.checkpoint_arrays: grains,
        contact history, plate, held grains) and 'coupler_<k>' this coupler's run state
        (steps, the mismatch; the grain forces need no saving: they are evaluated from the
        engine's state)."""
        out = {f"continuum_{k}": np.asarray(v) for k, v in self.continuum.state().items()}
        out["continuum_dof_coordinates"], out["continuum_dof_component"] = self.continuum.dof_keys()
        out["coupler_wall"] = np.array([self.timings.wall[p] for p in PHASES])
        if self.is_root:
            out.update({f"fine_{k}": np.asarray(v) for k, v in self.fine.checkpoint_arrays().items()})
            run = {"steps": np.array(self.steps), "max_mismatch": np.array(self.max_mismatch),
                   "last_mismatch": np.array(self.last_mismatch)}
            out.update({f"coupler_{k}": v for k, v in run.items()})
        return out

    def _matched_continuum(self, states):
        """This rank's continuum state from the state() dicts of every rank of a saved run:
        each owned dof takes the saved value of its component at its coordinates (within
        1e-8 of the mesh's extent). InputError when a dof has no saved match."""
        keys = ("dof_coordinates", "dof_component") + STATE_KEYS
        for rank, st in enumerate(states):
            missing = [f"continuum_{k}" for k in keys if f"continuum_{k}" not in st]
            if missing:
                raise InputError(f"the state of rank {rank} lacks {', '.join(missing)}")
        saved = {k: np.concatenate([np.asarray(st[f"continuum_{k}"]) for st in states]) for k in keys}
        coordinates, component = self.continuum.dof_keys()
        scale = float(np.ptp(saved["dof_coordinates"], axis=0).max()) if len(saved["dof_coordinates"]) else 1.0
        rows = np.empty(len(component), dtype=np.int64)
        for k in np.unique(component):
            where = np.flatnonzero(saved["dof_component"] == k)
            mine = np.flatnonzero(component == k)
            if where.size == 0:
                raise InputError(f"the saved state has no dof of component {int(k)}")
            rows[mine] = where[_rows_at(saved["dof_coordinates"][where], coordinates[mine], scale, "dof")]
        out = {k: saved[k][rows] for k in STATE_KEYS}
        out["time"] = states[0]["continuum_time"]
        out["steps"] = states[0].get("continuum_steps", 0)
        store = self.continuum.gauss_points
        if store is not None:
            # the Gauss-point material's committed arrays, point by point at their coordinates
            names = [k for k in states[0] if k.startswith("continuum_gauss_") and k != "continuum_gauss_coordinates"]
            if not names or "continuum_gauss_coordinates" not in states[0]:
                raise InputError("the saved continuum has no Gauss-point state (continuum_gauss_*) for its material")
            points = np.concatenate([np.asarray(st["continuum_gauss_coordinates"]) for st in states])
            found = _rows_at(points, store.coordinates, scale, "Gauss point")
            for name in names:
                saved_values = np.concatenate([np.asarray(st[name]) for st in states])
                out[name[len("continuum_"):]] = saved_values[found]
        return out

    def set_state(self, states):
        """Restore the state() dicts of every rank of a saved run (a list in rank order; the
        same mesh, region and options, any number of ranks: the continuum is matched by dof
        coordinates, the DEM region and the run state are the saved root's). Collective: a
        key missing or a shape that does not fit on any rank raises InputError on every rank
        before anything is changed. On the ranks that saved it the continued run is the
        straight run bit for bit; on others it differs by the order of the sums."""
        error, continuum, root = "", None, None
        try:
            if not (isinstance(states, (list, tuple)) and states and all(isinstance(st, dict) for st in states)):
                raise InputError("set_state needs the list of the saved ranks' state() dicts")
            root = states[self.root] if len(states) > self.root else None
            if root is None or "coupler_steps" not in root:
                raise InputError(f"the saved state has no root rank {self.root} (coupler_steps)")
            continuum = self._matched_continuum(states)
            if self.is_root:
                for key in ("steps", "max_mismatch", "last_mismatch"):
                    if f"coupler_{key}" not in root:
                        raise InputError(f"the coupler state lacks coupler_{key}")
                if not any(k.startswith("fine_") for k in root):
                    raise InputError("the coupler state has no DEM region (fine_*) on the root rank")
        except InputError as e:
            error = str(e)
        errors = [e for e in self.comm.allgather(error) if e]
        if errors:
            raise InputError(errors[0])
        try:
            self.continuum.set_state(continuum)
            if self.is_root:
                self.fine.restore({k[len("fine_"):]: v for k, v in root.items() if k.startswith("fine_")})
        except (InputError, ValueError) as e:
            error = str(e)
        errors = [e for e in self.comm.allgather(error) if e]
        if errors:
            raise InputError(errors[0])
        self.steps = int(root["coupler_steps"])
        self.max_mismatch = float(root["coupler_max_mismatch"])
        self.last_mismatch = float(root["coupler_last_mismatch"])
        # this rank's wall seconds so far when the saved run had it (timing_summary's max)
        wall = states[self.comm.rank].get("coupler_wall") if len(states) == self.comm.size else None
        if wall is not None and np.shape(wall) == (len(PHASES),):
            self.timings.wall = dict(zip(PHASES, (float(v) for v in wall)))

    # ------------------------------------------------------------------ time loop
    def step(self, diagnose=None):
        """One coarse step with m DEM sub-steps (module docstring). diagnose: compute the
        mismatch max |N_R d - P q| / r_min after it (default: every diagnose_every steps)."""
        if diagnose is None:
            diagnose = (self.steps + 1) % self.diagnose_every == 0
        c = self.continuum
        region = self.region
        w0 = time.perf_counter()
        # (d, v, a) at the virtual grains at t_n: row 3 p + c of grain p, component c
        interface = sum_over_ranks(self.comm, self.shape_virtual.local_values(
            [c.displacement, c.velocity, c.acceleration]), self.root)
        self.timings.add("interface", w0)
        w0 = time.perf_counter()
        c.predict(self.dt)
        self.timings.add("fe", w0)
        forces = None
        cause = None
        if self.is_root:
            w0 = time.perf_counter()
            # the virtual grains' path from t_n (full arrays in the region's order; the engine
            # reads the held rows only); the forces at q^{n+1} after the m sub-steps
            start, velocity, acceleration = self._path      # the real grains' rows stay zero
            set_path_rows(self._virtual_rows, interface, self._virtual_position, start, velocity, acceleration)
            try:
                self.fine.follow_held_path(self.substeps, start, velocity, acceleration)
            except (RuntimeError, ValueError, FloatingPointError) as error:
                # the engine's own stop (lost discs, non-finite state) reaches every rank
                cause = f"the DEM region stopped: {error}"
            grain_forces = self.coupling_forces()
            if self._weight is not None:
                grain_forces[:region.n_real, :2] += self._weight
            forces = grain_forces
            if self.coarse_force == "interface":
                forces = grain_forces.copy()
                forces[:region.n_real] = 0.0
            self.timings.add("dem", w0)
            w0 = time.perf_counter()
            if cause is None and not all_finite(forces):
                cause = "a grain force is not finite"
            self.timings.add("interface", w0)
            w0 = time.perf_counter()
            # the real grains where the engine keeps them (no reordering: the escape check
            # needs no order, its message the original index); the full check only when a
            # centre is outside the safe box
            order = self.fine.order
            if self._real_rows is None or self._real_rows[0] is not order:
                self._real_rows = (order, np.flatnonzero(order < region.n_real))
            rows = self._real_rows[1]
            if any_outside(self.fine.state.position, rows, *self._safe_box):
                position = self.fine.state.position[rows]
                escaped = region.escaped(position)
                if escaped.size and cause is None:
                    first = int(np.argmin(order[rows[escaped]]))
                    cause = (f"{escaped.size} grain(s) left the DEM region by more than one diameter "
                             f"(first: grain {int(order[rows[escaped[first]]])} at "
                             f"({position[escaped[first], 0]:.4g}, {position[escaped[first], 1]:.4g}) m)")
            q = self.grain_motion() if diagnose or self._projected else None
            if diagnose:
                self._coarse_q = self.projection.coarse_translation(q[region.real])
            self.timings.add("projection", w0)
        else:
            q = grain_forces = None
        self._stop(cause)
        w0 = time.perf_counter()
        if self.comm.size > 1:
            if not self.is_root:
                forces = np.empty((self.region.n_discs, 3))
            self.comm.Bcast(forces, root=self.root)
        self.coupling_force.set(0.0)
        self.shape.add_transpose(forces, self.coupling_force)
        self.timings.add("interface", w0)
        w0 = time.perf_counter()
        c.correct(self.dt, self.coupling_force)
        self.timings.add("fe", w0)
        if self._projected:
            w0 = time.perf_counter()
            self._set_projected_nodes(q, grain_forces)
            self.timings.add("projection", w0)
        if diagnose:
            w0 = time.perf_counter()
            nd = self.shape.interpolate_translation(c.displacement, self.root)
            if self.is_root:
                mismatch = np.abs(nd[region.real] - self._coarse_q)
                self.last_mismatch = float(np.max(np.hypot(mismatch[:, 0], mismatch[:, 1]))) / self.r_min
                self.max_mismatch = max(self.max_mismatch, self.last_mismatch)
            self.timings.add("projection", w0)
        self.steps += 1

    def run(self, n_steps, on_step=None):
        """n coarse steps; on_step(coupler) after each (all ranks)."""
        for _ in range(int(n_steps)):
            self.step()
            if on_step is not None:
                on_step(self)

    def fine_part(self):
        """(q, coarse N d at the grains, fine part Q q) of all real grains, on root (outputs)."""
        nd = self.shape.interpolate(self.continuum.displacement, self.root)
        if not self.is_root:
            return None
        q = self.grain_motion()[self.region.real]
        return q, nd[self.region.real], self.projection.fine(q)

    def timing_summary(self):
        """Per-phase wall seconds {"wall_s": {phase: s}}, the maximum over ranks."""
        return {"wall_s": {p: self.comm.allreduce(v, op=MPI.MAX) for p, v in self.timings.wall.items()}}
