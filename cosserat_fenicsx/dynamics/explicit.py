"""Explicit dynamics of the Cosserat continuum, linear elastic or of a Gauss-point material:
velocity Verlet with mass-proportional damping (003 eqs 31-34, spec section 4), lumped mass
(mass.py).

Semi-discrete equations (2D, per unit depth), d = (u1, u2, phi) nodal values:

    M a + c_m M v + K d = f_c + f_g                             (003 eq 33 before discretisation)

    K d  from  int chi [sigma(eps) : eps(v, w) + m . grad(w)] dA,  sigma = 2 mu sym(eps)
         + lambda tr(eps) I + 2 mu_c skw(eps),  m = 2 mu_c l_c^2 kappa   (elasticity.py,
         kinematics.py; 003 eqs 19-20 with mu = G, mu_c = G_c)
    M    lumped translational mass rho and rotary inertia rho j (mass.py)
    chi  DG0 indicator: 0 on the inactive cells (the DEM region: no Cosserat stiffness, no
         continuum mass; their coarse mass comes from the particles through add_mass)
    f_c  the coupling force (projected particle forces, 003 eq 33), owned entries complete
    f_g  the continuum's weight M_0 g (optional gravity g): its own lumped translational mass
         M_0 (before add_mass) times g, fixed; particles whose mass is added carry their
         weight themselves (the coupler passes it in f_c). The energies reported here leave
         out the potential of gravity

One step t_n -> t_n+1 = t_n + dt:

    d^{n+1} = d^n + dt v^n + dt^2/2 a^n                                         (31)  predict
    v~^{n+1} = v^n + dt a^n                                                      (32)  predict
    a^{n+1} = [M^-1 (f_c - K d^{n+1}) - c_m v^n - c_m dt a^n / 2] / (1 + c_m dt/2)  (33)  correct
    v^{n+1} = v^n + dt/2 (a^n + a^{n+1})                                         (34)  correct

(33) is a = M^-1 F - c_m v with the trapezoidal velocity (34) substituted. Undamped, the scheme
is the central difference: second order, energy conserving to O(dt^2) (no drift), stable for
dt <= 2 / omega_max (stable_step.py). Damped, a free mode decays as exp(-c_m t / 2).

Dirichlet dofs hold their prescribed value (set in (31)), with zero velocity and acceleration.
Massless dofs (inside the inactive region, before add_mass) are held as well. The stiffness K
is assembled once, as a PETSc Mat over the mixed space (u, phi), and never reassembled. With a
Gauss-point material (`material=`) the internal force is instead assembled at every force
evaluation from the material's stress at the 2 x 2 Gauss points (quadrature.QuadratureMap),
the store committed after every step; K (the material's elastic law) then serves the stable
step only.
"""
import math
import numbers

import dolfinx.fem
import dolfinx.fem.petsc
import dolfinx.mesh
import numpy as np
import ufl
from petsc4py import PETSc

from .. import compat
from ..elasticity import MicropolarElasticity
from ..lattice_elasticity import SquareLatticeElasticity
from ..kinematics import curvature, strain
from ..validation import NON_NEGATIVE, POSITIVE, InputError, check
from .mass import lumped_mass, mass_dot
from .stable_step import power_step, rotational_step, start_vector, translational_step

ELEMENTS = {"Q1/Q1": ("quadrilateral", 1, 1), "P2/P1": ("triangle", 2, 1)}
COMPONENTS = ("u1", "u2", "phi")
#: a displacement or rotation above this is taken as a blow-up, before it overflows to inf [m, rad]
BLOW_UP = 1e100
STATE_KEYS = ("displacement", "velocity", "acceleration", "mass")
#: the elastic laws of the continuum: stress(eps), couple_stress(kappa), mu_c, p_wave_modulus
ELASTIC_LAWS = (MicropolarElasticity, SquareLatticeElasticity)


class DynamicsError(RuntimeError):
    """The explicit integration stopped: the message names the cause."""


def stiffness_form(space, elasticity, indicator, quadrature_degree=2):
    """Bilinear form of K: int chi [sigma(eps(du, dphi)) : eps(v, w) + m(dphi) . grad(w)] dA.
    Quadrature degree 2 integrates P2/P1 and Q1/Q1 (2 x 2 Gauss, 003 section 5) exactly on
    straight-sided triangles and parallelograms."""
    dx = ufl.dx(domain=space.mesh, metadata={"quadrature_degree": quadrature_degree})
    du, dphi = ufl.split(ufl.TrialFunction(space))
    v, w = ufl.split(ufl.TestFunction(space))
    sigma = elasticity.stress(strain(du, dphi))
    couple = elasticity.couple_stress(curvature(dphi))
    return indicator * (ufl.inner(sigma, strain(v, w)) + ufl.inner(couple, curvature(w))) * dx


class ExplicitCosserat:
    """Explicit (velocity Verlet, 003 eqs 31-34) Cosserat continuum, linear elastic or of a
    Gauss-point material.

    mesh            dolfinx mesh (quadrilaterals for Q1/Q1, triangles for P2/P1) [m]
    elasticity      MicropolarElasticity (mu_c > 0) or SquareLatticeElasticity (003's lattices)
    density         rho [kg/m^3] (> 0)
    micro_inertia   j [m^2] (> 0): rotary inertia rho j per unit area (r^2/2 for discs)
    mass_damping    c_m [1/s] (>= 0): force -c_m M v
    element         "Q1/Q1" (003's bilinear quads) or "P2/P1" (project default, HRZ-lumped)
    inactive_cells  local cell indices without stiffness and mass (the DEM region); each rank
                    lists its owned cells (ghost entries are taken from their owners)
    dirichlet       [(component "u1" | "u2" | "phi", where, value [m | rad])], where either a
                    boundary-facet locator x -> bool array or an array of local dofs of the
                    mixed space (owned dofs listed by their owning rank)
    refuse_unstable True: predict() refuses dt above the power-iteration stable step
    gravity         (g_x, g_y) [m/s^2]: the body force f_g = M_0 g (module docstring)
    material        a Gauss-point material (constitutive.Constitutive, e.g.
                    materials.lattice_coulomb.LatticeCoulombMaterial) whose stress replaces K d
                    in the internal force (updated and committed every step, 2 x 2 Gauss on
                    Q1); `elasticity` is then its elastic law, for the stable step only
    """

    def __init__(self, mesh, elasticity, density, micro_inertia, mass_damping=0.0, element="P2/P1",
                 inactive_cells=None, dirichlet=(), refuse_unstable=True, gravity=(0.0, 0.0), material=None):
        if not isinstance(elasticity, ELASTIC_LAWS):
            raise InputError("elasticity must be a MicropolarElasticity or a SquareLatticeElasticity")
        if elasticity.mu_c <= 0.0:
            raise InputError(f"explicit Cosserat dynamics needs mu_c > 0 (the rotation has no "
                             f"stiffness otherwise), got {elasticity.mu_c!r}")
        self.density = check("density", density, POSITIVE)
        self.micro_inertia = check("micro_inertia", micro_inertia, POSITIVE)
        self.mass_damping = check("mass_damping", mass_damping, NON_NEGATIVE)
        self.gravity = _gravity(gravity)
        if element not in ELEMENTS:
            raise InputError(f"element must be one of {', '.join(ELEMENTS)}, got {element!r}")
        cell, degree_u, degree_phi = ELEMENTS[element]
        if compat.cell_name(mesh) != cell:
            raise InputError(f"element {element} needs a {cell} mesh, got {compat.cell_name(mesh)} cells")
        self.mesh, self.elasticity, self.element = mesh, elasticity, element
        self.refuse_unstable = bool(refuse_unstable)
        self.comm = mesh.comm
        tdim = mesh.topology.dim

        el_u = compat.lagrange_element(mesh, degree_u, (mesh.geometry.dim,))
        el_phi = compat.lagrange_element(mesh, degree_phi)
        self.space = compat.function_space(mesh, compat.mixed_element([el_u, el_phi]))
        index_map = self.space.dofmap.index_map
        self._n_owned = index_map.size_local * self.space.dofmap.index_map_bs
        self._subspaces = {}

        # active-cell indicator chi (DG0)
        self._dg0 = compat.function_space(mesh, compat.dg_element(mesh, 0))
        self.indicator = dolfinx.fem.Function(self._dg0)
        self.indicator.x.array[:] = 1.0
        n_local_cells = mesh.topology.index_map(tdim).size_local + mesh.topology.index_map(tdim).num_ghosts
        if inactive_cells is not None:
            cells = np.asarray(inactive_cells).ravel()
            if cells.size == 0:
                cells = cells.astype(np.int64)      # np.asarray([]) is float
            if cells.size and (cells.dtype.kind not in "iu" or cells.min() < 0 or cells.max() >= n_local_cells):
                raise InputError(f"inactive_cells must be local cell indices in [0, {n_local_cells}), "
                                 f"got {cells.dtype} values in [{cells.min()}, {cells.max()}]")
            cell_dofs = compat.cell_dofs(self._dg0, n_local_cells)[:, 0]
            self.indicator.x.array[cell_dofs[cells]] = 0.0
            self.indicator.x.scatter_forward()   # owners' values win on ghost cells
        self.inactive_cells = None if inactive_cells is None else cells

        # fields: d, v, a as Functions of W and their (ghosted) PETSc Vecs
        self.fields = {name: dolfinx.fem.Function(self.space, name=name)
                       for name in ("displacement", "velocity", "acceleration")}
        self.displacement = compat.petsc_vector(self.fields["displacement"])
        self.velocity = compat.petsc_vector(self.fields["velocity"])
        self.acceleration = compat.petsc_vector(self.fields["acceleration"])
        self.time = 0.0
        self.steps = 0

        # Dirichlet dofs (owned) and their values
        self._bc_dofs, self._bc_values = self._locate_dirichlet(dirichlet)

        # K once; lumped mass
        self._stiffness_form = dolfinx.fem.form(stiffness_form(self.space, elasticity, self.indicator))
        self.stiffness = dolfinx.fem.petsc.assemble_matrix(self._stiffness_form)
        self.stiffness.assemble()
        u_dofs = self.subspace("u")[1] if degree_u == 2 else np.zeros(0, dtype=np.int64)
        self.mass, self.mass_info = lumped_mass(self.space, self.indicator, self.density, self.micro_inertia,
                                                u_dofs, quadrature_degree=2 * degree_u)
        self._force = self.stiffness.createVecLeft()
        self._weight = self._continuum_weight()
        self.gauss_points = None if material is None else self._gauss_point_force(material)
        self._v_tilde = self.velocity.duplicate()
        self._predicted_dt = None
        self._stable = None
        self._update_inverse_mass()
        self._apply_dirichlet(self.displacement)
        self.update_acceleration()

    # --- spaces and dofs -----------------------------------------------------------
    def _sub(self, name):
        if name == "u":
            return self.space.sub(0)
        if name == "phi":
            return self.space.sub(1)
        if name in ("u1", "u2"):
            return self.space.sub(0).sub(int(name[1]) - 1)
        raise InputError(f"unknown component {name!r}, expected one of u, u1, u2, phi")

    def subspace(self, name):
        """(collapsed space V, array of the W dofs of V's local dofs) of 'u', 'u1', 'u2' or 'phi'."""
        if name not in self._subspaces:
            space, dofs = self._sub(name).collapse()
            self._subspaces[name] = (space, np.asarray(dofs, dtype=np.int64))
        return self._subspaces[name]

    def _locate_dirichlet(self, dirichlet):
        fdim = self.mesh.topology.dim - 1
        all_dofs, all_values = [], []
        for entry in dirichlet:
            if len(entry) != 3:
                raise InputError(f"a Dirichlet condition is (component, where, value), got {entry!r}")
            component, where, value = entry
            if component not in COMPONENTS:
                raise InputError(f"Dirichlet component must be one of {', '.join(COMPONENTS)}, got {component!r}")
            if not isinstance(value, numbers.Real) or not math.isfinite(value):
                raise InputError(f"Dirichlet value of {component} must be a finite number, got {value!r}")
            if callable(where):
                self.mesh.topology.create_connectivity(fdim, fdim + 1)
                facets = dolfinx.mesh.locate_entities_boundary(self.mesh, fdim, where)
                space = self.subspace(component)[0]
                dofs = dolfinx.fem.locate_dofs_topological((self._sub(component), space), fdim, facets)[0]
            else:
                dofs = np.asarray(where)
                if dofs.size and (dofs.dtype.kind not in "iu" or dofs.min() < 0
                                  or dofs.max() >= len(self.fields["displacement"].x.array)):
                    raise InputError(f"Dirichlet dofs of {component} must be local dof indices of the mixed space")
                component_dofs = self.subspace(component)[1]
                if not np.isin(dofs, component_dofs).all():
                    raise InputError(f"Dirichlet dofs given for {component} are not all {component} dofs")
            dofs = np.asarray(dofs, dtype=np.int64)
            dofs = dofs[dofs < self._n_owned]
            all_dofs.append(dofs)
            all_values.append(np.full(len(dofs), float(value)))
        if not all_dofs:
            return np.zeros(0, dtype=np.int64), np.zeros(0)
        dofs, values = np.concatenate(all_dofs), np.concatenate(all_values)
        # later conditions win on shared dofs
        _, last = np.unique(dofs[::-1], return_index=True)
        keep = len(dofs) - 1 - last
        return dofs[keep], values[keep]

    def _apply_dirichlet(self, vec, values=True):
        vec.array[self._bc_dofs] = self._bc_values if values else 0.0

    @staticmethod
    def _forward(vec):
        vec.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)

    # --- mass ----------------------------------------------------------------------
    def _update_inverse_mass(self):
        mass = self.mass.array
        if not np.isfinite(mass).all() or (mass < 0.0).any():
            raise InputError("the lumped mass must be finite and >= 0 at every dof")
        self._massless = mass == 0.0
        self._held = self._massless.copy()
        self._held[self._bc_dofs] = True
        self._free = ~self._held
        self._inverse_mass = np.zeros_like(mass)
        self._inverse_mass[self._free] = 1.0 / mass[self._free]
        self._stable = None

    @property
    def free_dofs(self):
        """Boolean mask over the owned dofs: neither Dirichlet nor massless (the dofs that move)."""
        return self._free.copy()

    def add_mass(self, vec):
        """Add a mass Vec over W (the particles' row-sum lumped N^T m, N^T J [kg/m, kg m]),
        owned entries complete (ghost contributions already added). The acceleration is
        recomputed from the new mass at the next correct()."""
        added = vec.array
        if not np.isfinite(added).all() or (added < 0.0).any():
            raise InputError("add_mass: the added mass must be finite and >= 0 at every dof")
        self.mass.array[:] += added
        self._forward(self.mass)
        self._update_inverse_mass()

    @property
    def total_mass(self):
        """(translational mass [kg/m]: the u1 masses summed, rotary inertia [kg m]: the phi ones), global."""
        u1 = self.subspace("u1")[1]
        phi = self.subspace("phi")[1]
        owned_u1, owned_phi = u1[u1 < self._n_owned], phi[phi < self._n_owned]
        return (self.comm.allreduce(float(self.mass.array[owned_u1].sum())),
                self.comm.allreduce(float(self.mass.array[owned_phi].sum())))

    def set_mass_damping(self, mass_damping):
        """c_m [1/s] (>= 0) from the next step on: a run may settle with one and load with
        another."""
        self.mass_damping = check("mass_damping", mass_damping, NON_NEGATIVE)

    def _gauss_point_force(self, material):
        """The store of `material` at the 2 x 2 Gauss points (quadrature.QuadratureMap) and
        the form of its internal force int chi [sigma : eps(v, w) + m . grad w] dA."""
        from ..constitutive import Constitutive
        from ..kinematics import gradient_vector
        from ..quadrature import QuadratureMap
        if not isinstance(material, Constitutive):
            raise InputError("material must be a constitutive.Constitutive (a Gauss-point material)")
        u, phi = ufl.split(self.fields["displacement"])
        store = QuadratureMap(self.mesh, material, gradient_vector(u, phi), 2)
        v, w = ufl.split(ufl.TestFunction(self.space))
        dx = ufl.dx(domain=self.mesh, metadata={"quadrature_degree": 2})
        work = self.indicator * (ufl.inner(store.stress(), strain(v, w))
                                 + ufl.dot(store.couple_stress(), curvature(w))) * dx
        self._internal_form = dolfinx.fem.form(work)
        self._internal_vec = dolfinx.fem.petsc.create_vector(self._internal_form)
        return store

    def _material_force(self):
        """f_int of the Gauss-point material at the current d (trial update, owned entries)."""
        self.gauss_points.update()
        vec = self._internal_vec
        with vec.localForm() as local:
            local.set(0.0)
        dolfinx.fem.petsc.assemble_vector(vec, self._internal_form)
        vec.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        return vec.array

    @property
    def weight(self):
        """f_g = M_0 g over the owned dofs [N/m at u dofs, 0 at phi dofs] (a copy; zeros
        without gravity)."""
        return np.zeros_like(self.mass.array) if self._weight is None else self._weight.copy()

    def _continuum_weight(self):
        """f_g = M_0 g over the owned dofs (None without gravity): the lumped translational
        mass of the active cells times g at the u1 and u2 dofs [N/m]."""
        if not any(self.gravity):
            return None
        weight = np.zeros_like(self.mass.array)
        for name, g in zip(("u1", "u2"), self.gravity):
            dofs = self.subspace(name)[1]
            dofs = dofs[dofs < self._n_owned]
            weight[dofs] = self.mass.array[dofs] * g
        return weight

    # --- forces, energies -----------------------------------------------------------
    def internal_force(self, d, out):
        """out = K d (owned entries) [N/m at u dofs, N at phi dofs]."""
        self.stiffness.mult(d, out)
        return out

    def kinetic_energy(self):
        """1/2 v . M v [J/m] (global)."""
        return 0.5 * mass_dot(self.velocity, self.mass)

    def strain_energy(self):
        """1/2 d . K d [J/m] (global)."""
        self.stiffness.mult(self.displacement, self._force)
        return 0.5 * self.displacement.dot(self._force)

    # --- stable step ----------------------------------------------------------------
    def h_min(self):
        """Shortest cell edge of the active cells [m] (global)."""
        tdim = self.mesh.topology.dim
        n_cells = self.mesh.topology.index_map(tdim).size_local
        nodes = compat.cell_geometry_nodes(self.mesh)[:n_cells]
        active = compat.cell_dofs(self._dg0, n_cells)[:, 0]
        nodes = nodes[self.indicator.x.array[active] > 0.0]
        corners = 4 if compat.cell_name(self.mesh) == "quadrilateral" else 3
        x = self.mesh.geometry.x[:, :2]
        h = math.inf
        for i in range(corners):
            for j in range(i + 1, corners):
                if len(nodes):
                    h = min(h, float(np.linalg.norm(x[nodes[:, i]] - x[nodes[:, j]], axis=1).min()))
        return self.comm.allreduce(h, op=_min_op())

    def stable_time_step(self):
        """{'power', 'translational', 'rotational'} stable steps [s] (stable_step.py); the
        power iteration runs once and is kept until the mass changes."""
        if self._stable is None:
            start = self.displacement.duplicate()
            work = dolfinx.fem.Function(self.space)
            for name in ("u1", "u2", "phi"):
                space, dofs = self.subspace(name)
                f = dolfinx.fem.Function(space)
                f.interpolate(start_vector)
                work.x.array[dofs] = f.x.array
            start.array[:] = work.x.array[:self._n_owned]
            power, lam, iterations = power_step(self.internal_force, self.mass, self._free, start)
            self._stable = {"power": power,
                            "translational": translational_step(self.elasticity, self.density, self.h_min()),
                            "rotational": rotational_step(self.elasticity, self.density, self.micro_inertia),
                            "power_iterations": iterations}
        return {k: v for k, v in self._stable.items() if k != "power_iterations"}

    # --- time stepping --------------------------------------------------------------
    def _check_dt(self, dt):
        dt = check("dt", dt, POSITIVE)
        if self.refuse_unstable:
            if self._stable is None:
                self.stable_time_step()
            stable = self._stable["power"]
            if dt > stable:
                raise InputError(f"dt = {dt:.6g} s is above the stable step {stable:.6g} s "
                                 f"(2/omega_max of M^-1 K by power iteration; rotational 2/omega_r = "
                                 f"{self._stable['rotational']:.3g} s, h/c_p = {self._stable['translational']:.3g} s)")
        return dt

    def update_acceleration(self, coupling_force=None):
        """a = M^-1 (f_c - K d) - c_m v at the current state: the start of a run, or after owned
        entries of d or v were set by hand (their ghosts are refreshed here)."""
        self._forward(self.displacement)
        self._forward(self.velocity)
        force = self._net_force(coupling_force)
        a = self.acceleration.array
        a[:] = self._inverse_mass * force - self.mass_damping * self.velocity.array
        a[self._held] = 0.0
        self._forward(self.acceleration)

    def _net_force(self, coupling_force):
        if self.gauss_points is None:
            self.stiffness.mult(self.displacement, self._force)
            force = -self._force.array
        else:
            force = -self._material_force()
        if self._weight is not None:
            force += self._weight          # force is a fresh array (the negation)
        if coupling_force is not None:
            f = coupling_force.array
            if not np.isfinite(f).all():
                self._stop("the coupling force is not finite")
            loose = int(np.count_nonzero(f[self._massless]))
            if self.comm.size > 1:
                loose = self.comm.allreduce(loose)
            if loose:
                self._stop(f"the coupling force acts on {loose} massless dof(s): add their mass first (add_mass)")
            force = force + f
        return force

    def predict(self, dt):
        """Eqs 31-32: d += dt v + dt^2/2 a (Dirichlet values set), returns v~ = v + dt a (a Vec,
        zero on held dofs). Call correct(dt, ...) with the same dt next."""
        dt = self._check_dt(dt)
        d, v, a = self.displacement.array, self.velocity.array, self.acceleration.array
        d[:] += dt * v + 0.5 * dt * dt * a
        self._apply_dirichlet(self.displacement)
        self._forward(self.displacement)
        self._v_tilde.array[:] = v + dt * a
        self._v_tilde.array[self._held] = 0.0
        self._forward(self._v_tilde)
        self._predicted_dt = dt
        return self._v_tilde

    def correct(self, dt, coupling_force=None):
        """Eqs 33-34: a^{n+1} from the forces at d^{n+1} (K d and the coupling force, a Vec over W
        with ghost contributions added), then v^{n+1}; time += dt."""
        if self._predicted_dt is None or dt != self._predicted_dt:
            raise InputError(f"correct(dt={dt!r}) must follow predict with the same dt "
                             f"(predicted: {self._predicted_dt!r})")
        force = self._net_force(coupling_force)
        c = self.mass_damping
        v, a = self.velocity.array, self.acceleration.array
        a_new = (self._inverse_mass * force - c * v - 0.5 * c * dt * a) / (1.0 + 0.5 * c * dt)
        a_new[self._held] = 0.0
        v[:] += 0.5 * dt * (a + a_new)
        v[self._held] = 0.0
        a[:] = a_new
        self._forward(self.velocity)
        self._forward(self.acceleration)
        if self.gauss_points is not None:
            self.gauss_points.commit()
        self._predicted_dt = None
        self.time += dt
        self.steps += 1
        self._check_blow_up(dt)

    def step(self, dt):
        """One velocity-Verlet step without coupling: predict + correct."""
        self.predict(dt)
        self.correct(dt)

    def _check_blow_up(self, dt):
        size = self.displacement.norm(PETSc.NormType.NORM_INFINITY)
        if math.isfinite(size) and size < BLOW_UP:
            return
        stable = self._stable["power"] if self._stable else None
        if stable is not None and dt > stable:
            cause = f"dt = {dt:.6g} s is above the stable step {stable:.6g} s (power iteration)"
        elif stable is not None:
            cause = (f"dt = {dt:.6g} s is below the continuum's stable step {stable:.6g} s: "
                     "look at the coupling forces and the added mass")
        else:
            cause = "the stable step was not computed (refuse_unstable=False): compare dt with stable_time_step()"
        self._stop(f"the displacement grew to |d|_inf = {size:.3g} at t = {self.time:.6g} s "
                   f"(step {self.steps}); {cause}")

    def _stop(self, message):
        raise DynamicsError("explicit dynamics stopped: " + message)

    # --- checkpoints ----------------------------------------------------------------
    def state(self):
        """Owned values: {'displacement', 'velocity', 'acceleration', 'mass': arrays, 'time':
        0-d array, 'steps': 0-d array}."""
        out = {"displacement": self.displacement.array.copy(), "velocity": self.velocity.array.copy(),
               "acceleration": self.acceleration.array.copy(), "mass": self.mass.array.copy()}
        out["time"] = np.array(self.time)
        out["steps"] = np.array(self.steps)
        if self.gauss_points is not None:
            out.update({f"gauss_{k}": np.array(v, copy=True)
                        for k, v in self.gauss_points.committed_arrays().items()})
            out["gauss_coordinates"] = self.gauss_points.coordinates.copy()
        return out

    def dof_keys(self):
        """(coordinates (n_owned, 2) [m], component (n_owned,) index into COMPONENTS) of the
        owned dofs, in the order of state()'s arrays: what identifies a dof whatever the
        partition (a state saved on other ranks is matched by them)."""
        coordinates = np.full((self._n_owned, 2), np.nan)
        component = np.full(self._n_owned, -1, dtype=np.int64)
        for k, name in enumerate(COMPONENTS):
            space, dofs = self.subspace(name)
            x = space.tabulate_dof_coordinates()[:, :2]
            mine = dofs < self._n_owned
            coordinates[dofs[mine]] = x[mine]
            component[dofs[mine]] = k
        if (component < 0).any():
            raise InputError("dof_keys: an owned dof of no component")
        return coordinates, component

    def set_state(self, state):
        """Restore a state() dict (same mesh, element and ranks)."""
        missing = [k for k in STATE_KEYS + ("time",) if k not in state]
        if missing:
            raise InputError(f"set_state: missing {', '.join(missing)}")
        for key in STATE_KEYS:
            values = np.asarray(state[key], dtype=float)
            if values.shape != (self._n_owned,):
                raise InputError(f"set_state: {key} has shape {values.shape}, expected ({self._n_owned},)")
            if not np.isfinite(values).all():
                raise InputError(f"set_state: {key} is not finite")
        time = float(state["time"])
        if not math.isfinite(time):
            raise InputError(f"set_state: time must be finite, got {time!r}")
        gauss = None
        if self.gauss_points is not None:
            store = self.gauss_points
            gauss = {k[len("gauss_"):]: np.asarray(v) for k, v in state.items()
                     if k.startswith("gauss_") and k != "gauss_coordinates"}
            current = store.committed_arrays()
            if set(gauss) != set(current) or any(np.shape(gauss[k]) != np.shape(v) for k, v in current.items()):
                raise InputError(f"set_state: the Gauss-point arrays do not fit this rank's {store.n_points} points "
                                 f"(a material's state is needed: {', '.join(sorted(current))})")
        vectors = {"displacement": self.displacement, "velocity": self.velocity,
                   "acceleration": self.acceleration, "mass": self.mass}
        for key, vec in vectors.items():
            vec.array[:] = np.asarray(state[key], dtype=float)
            self._forward(vec)
        self._update_inverse_mass()
        if gauss is not None:
            self.gauss_points.restore_committed(gauss)
        self.time = time
        self.steps = int(state.get("steps", 0))
        self._predicted_dt = None


def _gravity(gravity):
    """(g_x, g_y) as two finite floats [m/s^2], or a one-line refusal."""
    try:
        values = tuple(float(g) for g in gravity)
    except (TypeError, ValueError):
        values = ()
    if len(values) != 2 or not all(math.isfinite(g) for g in values):
        raise InputError(f"gravity must be two finite numbers (g_x, g_y) [m/s^2], got {gravity!r}")
    return values


def _min_op():
    from mpi4py import MPI
    return MPI.MIN
