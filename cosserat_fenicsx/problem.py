"""The plane-strain micropolar boundary-value problem as UFL forms.

Balance of momentum and of moment of momentum (thesis 004, eqs 2.53, 3.4, 3.5), summed into
one weak form (eq 5.6) with test functions (v, w):

    int sigma : strain(v, w) + m . grad(w) dA = int f.v + c w dA + int t.v + m_n w ds

Taylor-Hood P2 displacement / P1 rotation by default (eq 3.6). The material enters
either as pure UFL (`MicropolarElasticity`) or as a Gauss-point material
(`Constitutive`), in which case stress, couple stress and tangent are quadrature
Functions of its store, `gauss_points` (a quadrature.QuadratureMap). A Cauchy scene (`micropolar=False`) has no rotation field at all.

Loads (Dirichlet values, tractions, surface couples, body force and couple) are given
at full magnitude and scaled by `scale(t)` (default: the load factor t itself) over the
pseudo-time of the load stepping.
"""
import numbers

import dolfinx.fem
import dolfinx.fem.petsc
import dolfinx.mesh
import numpy as np
import ufl
from petsc4py import PETSc

from . import compat
from .constitutive import Constitutive
from .elasticity import MicropolarElasticity
from .kinematics import strain, curvature, gradient_vector
from .validation import check

COMPONENTS = ("u1", "u2", "phi")


def linear_ramp(t):
    return t


def _check_finite(name, value):
    """Numbers in a load (a number or a sequence of them) must be finite: a NaN would
    reach the form compiler as a C literal. UFL expressions pass unchecked."""
    for item in (value if isinstance(value, (list, tuple, np.ndarray)) else (value,)):
        if isinstance(item, numbers.Real):
            check(name, item)


class _Scaled:
    """A dolfinx Constant (or list of them) multiplied by scale(t)."""

    def __init__(self, mesh, value, scale):
        self.scale = scale or linear_ramp
        self.factor = dolfinx.fem.Constant(mesh, PETSc.ScalarType(0.0))
        self.value = value

    def set_time(self, t):
        self.factor.value = self.scale(t)

    def ufl(self):
        return self.factor * self.value


class _Dirichlet:
    def __init__(self, problem, boundary, component, value, scale):
        self.boundary, self.component = boundary, component
        self.scale = scale or linear_ramp
        space, sub_map = problem.component_space(component)
        dofs = dolfinx.fem.locate_dofs_topological(
            (problem.W_component(component), space), problem.mesh.topology.dim - 1,
            problem.facets(boundary))
        self.function = dolfinx.fem.Function(space)
        if isinstance(value, numbers.Real):
            self.base = np.full_like(self.function.x.array, float(value))
        elif callable(value):
            self.function.interpolate(value)
            self.base = self.function.x.array.copy()
        else:
            raise TypeError(f"Dirichlet value for {component} on '{boundary}' must be a number "
                            f"or a callable of x, got {type(value).__name__}")
        if not np.isfinite(self.base).all():
            raise ValueError(f"Dirichlet value for {component} on '{boundary}' is not finite")
        self.bc = dolfinx.fem.dirichletbc(self.function, dofs, problem.W_component(component))
        self.dofs = dofs[0]

    def set_time(self, t):
        self.function.x.array[:] = self.scale(t) * self.base


class _PointDirichlet(_Dirichlet):
    """A Dirichlet value at the nodes of one component that lie at a point (a pin)."""

    def __init__(self, problem, point, component, value, scale):
        self.boundary, self.component = f"point {tuple(point)}", component
        self.scale = scale or linear_ramp
        space, _ = problem.component_space(component)
        x0 = np.array([float(point[0]), float(point[1]), 0.0])
        tol = 1e-10 * max(1.0, float(np.abs(x0).max()))
        dofs = dolfinx.fem.locate_dofs_geometrical(
            (problem.W_component(component), space),
            lambda x: np.linalg.norm(x[:2] - x0[:2, None], axis=0) < tol)
        if problem.mesh.comm.allreduce(len(dofs[0])) == 0:
            raise ValueError(f"no {component} node at the point {tuple(point)}: "
                             "a point condition needs a mesh node there")
        self.function = dolfinx.fem.Function(space)
        self.base = np.full_like(self.function.x.array, float(value))
        self.bc = dolfinx.fem.dirichletbc(self.function, dofs, problem.W_component(component))
        self.dofs = dofs[0]


class CosseratProblem:
    """Fields, boundary conditions and forms of one scene.

    mesh, facet_tags   dolfinx mesh and facet MeshTags
    boundaries         {name: tag} of the facet tags, e.g. {"bottom": 1, "top": 2}
    elasticity         MicropolarElasticity for the pure-UFL path, or
    material           a Constitutive evaluated at the Gauss points (exactly one)
    micropolar         False: Cauchy continuum, no rotation field
    degree_u, degree_phi   Lagrange degrees (default Taylor-Hood 2 / 1)
    """

    def __init__(self, mesh, facet_tags, boundaries, elasticity=None, material=None,
                 micropolar=True, degree_u=2, degree_phi=1, quadrature_degree=None):
        if (elasticity is None) == (material is None):
            raise ValueError("give exactly one of elasticity= (pure UFL) or material= (Gauss-point material)")
        if elasticity is not None and not isinstance(elasticity, MicropolarElasticity):
            raise TypeError("elasticity must be a MicropolarElasticity")
        if material is not None and not isinstance(material, Constitutive):
            raise TypeError("material must implement cosserat_fenicsx.constitutive.Constitutive")
        if micropolar and elasticity is not None:
            elasticity.check_micropolar()
        for name, degree in (("degree_u", degree_u), ("degree_phi", degree_phi)):
            if not isinstance(degree, int) or degree < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {degree!r}")
        self.mesh, self.facet_tags = mesh, facet_tags
        self.boundaries = dict(boundaries)
        present = set(np.unique(facet_tags.values).tolist()) if facet_tags is not None else set()
        present = set(mesh.comm.allreduce(list(present)))  # tags may live on one rank only
        missing = {n: t for n, t in self.boundaries.items() if t not in present}
        if missing:
            raise ValueError(f"boundary tags not found in the mesh facet tags: {missing}")
        self.elasticity, self.material = elasticity, material
        self.micropolar = micropolar
        self.degree_u, self.degree_phi = degree_u, degree_phi
        simplex = compat.cell_name(mesh) == "triangle"
        if quadrature_degree is None:
            quadrature_degree = 2 * degree_u - 2 if simplex else 2 * degree_u
        self.quadrature_degree = max(quadrature_degree, 1)
        self.dx = ufl.dx(domain=mesh, metadata={"quadrature_degree": self.quadrature_degree})
        self.ds = ufl.ds(domain=mesh, subdomain_data=facet_tags)

        el_u = compat.lagrange_element(mesh, degree_u, (mesh.geometry.dim,))
        if micropolar:
            el_phi = compat.lagrange_element(mesh, degree_phi)
            self.W = compat.function_space(mesh, compat.mixed_element([el_u, el_phi]))
        else:
            self.W = compat.function_space(mesh, el_u)
        self.w = dolfinx.fem.Function(self.W, name="solution")
        self.w_committed = dolfinx.fem.Function(self.W)
        self.v = ufl.TestFunction(self.W)
        self.dw = ufl.TrialFunction(self.W)
        self._dirichlet, self._tractions, self._couples = [], [], []
        self._surface_loads = []
        self._body_force = self._body_couple = None
        self._collapsed = {}
        self._gauss_points = None
        self._compiled = None
        self._internal_form = None
        self.time = 0.0

    # --- fields --------------------------------------------------------------------
    def split(self, w):
        if self.micropolar:
            u, phi = ufl.split(w)
            return u, phi
        return w, None

    @property
    def displacement(self):
        return self.split(self.w)[0]

    @property
    def rotation(self):
        return self.split(self.w)[1]

    def W_component(self, component):
        self._check_component(component)
        if component == "phi":
            return self.W.sub(1)
        i = int(component[1]) - 1
        return self.W.sub(0).sub(i) if self.micropolar else self.W.sub(i)

    def component_space(self, component):
        if component not in self._collapsed:
            self._collapsed[component] = self.W_component(component).collapse()
        return self._collapsed[component]

    def _check_component(self, component):
        if component not in COMPONENTS:
            raise ValueError(f"unknown component '{component}', expected one of {COMPONENTS}")
        if component == "phi" and not self.micropolar:
            raise ValueError("a Cauchy scene has no rotation field: no condition on 'phi'")

    def facets(self, boundary):
        if boundary not in self.boundaries:
            raise ValueError(f"unknown boundary '{boundary}', known: {sorted(self.boundaries)}")
        return self.facet_tags.find(self.boundaries[boundary])

    # --- loads ---------------------------------------------------------------------
    def add_dirichlet(self, boundary, component, value, scale=None):
        """Prescribe u1, u2 or phi on a named boundary (number or callable of x)."""
        self.facets(boundary)
        for other in self._dirichlet:
            if other.boundary == boundary and other.component == component:
                raise ValueError(f"two Dirichlet conditions on {component} of '{boundary}'")
        for kind, name, comps in self._tractions + self._couples:
            if name == boundary and component in comps:
                raise ValueError(f"inconsistent boundary conditions: {component} on '{boundary}' "
                                 f"has both a Dirichlet value and a {kind}")
        self._dirichlet.append(_Dirichlet(self, boundary, component, value, scale))
        self._compiled = None

    def add_point_dirichlet(self, point, component, value=0.0, scale=None):
        """Prescribe u1, u2 or phi (a number) at the node(s) located at `point` (x, y):
        a pin that removes a rigid-body mode without constraining a whole boundary."""
        self._check_component(component)
        _check_finite(f"point value of {component}", value)
        _check_finite(f"point of the {component} pin", point)
        self._dirichlet.append(_PointDirichlet(self, point, component, value, scale))
        self._compiled = None

    def add_traction(self, boundary, traction, scale=None):
        """Traction t_i = sigma_ij n_j [Pa] on a named boundary (pair of numbers or UFL)."""
        _check_finite(f"traction on '{boundary}'", traction)
        self._add_surface_load(boundary, "traction", ("u1", "u2"), ufl.as_vector(traction), scale)

    def add_surface_couple(self, boundary, couple, scale=None):
        """Surface couple m_3j n_j [N/m] on a named boundary."""
        if not self.micropolar:
            raise ValueError("a Cauchy scene has no rotation field: no surface couple")
        _check_finite(f"surface couple on '{boundary}'", couple)
        self._add_surface_load(boundary, "surface couple", ("phi",), couple, scale)

    def _add_surface_load(self, boundary, kind, comps, value, scale):
        self.facets(boundary)
        for bc in self._dirichlet:
            if bc.boundary == boundary and bc.component in comps:
                raise ValueError(f"inconsistent boundary conditions: {bc.component} on '{boundary}' "
                                 f"has both a Dirichlet value and a {kind}")
        (self._tractions if kind == "traction" else self._couples).append((kind, boundary, comps))
        self._surface_loads.append((boundary, comps, _Scaled(self.mesh, value, scale)))
        self._compiled = None

    def set_body_force(self, force, scale=None):
        """Body force per unit volume f [N/m^3] (pair of numbers or UFL)."""
        _check_finite("body force", force)
        self._body_force = _Scaled(self.mesh, ufl.as_vector(force), scale)
        self._compiled = None

    def set_body_couple(self, couple, scale=None):
        """Body couple per unit volume c [N/m^2]."""
        _check_finite("body couple", couple)
        if not self.micropolar:
            raise ValueError("a Cauchy scene has no rotation field: no body couple")
        self._body_couple = _Scaled(self.mesh, couple, scale)
        self._compiled = None

    @property
    def bcs(self):
        return [d.bc for d in self._dirichlet]

    def set_time(self, t):
        self.time = t
        for item in self._dirichlet:
            item.set_time(t)
        for _, _, load in self._surface_loads:
            load.set_time(t)
        for load in (self._body_force, self._body_couple):
            if load is not None:
                load.set_time(t)

    # --- constitutive response --------------------------------------------------------
    def stress(self):
        """Force stress (2x2, non-symmetric) as UFL [Pa]."""
        if self.material is not None:
            return self.gauss_points.stress()
        u, phi = self.split(self.w)
        return self.elasticity.stress(strain(u, phi))

    def couple_stress(self):
        """Couple stress (m31, m32) as UFL [N/m]."""
        if not self.micropolar:
            return None
        if self.material is not None:
            return self.gauss_points.couple_stress()
        return self.elasticity.couple_stress(curvature(self.rotation))

    # --- forms ---------------------------------------------------------------------
    def check(self):
        """Errors that must surface before any assembly."""
        if not self._dirichlet:
            raise ValueError("no Dirichlet condition: the rigid-body motion is undetermined")

    def forms(self):
        """Compiled (residual, jacobian) dolfinx forms."""
        if self._compiled is None:
            self.check()
            self._compiled = (dolfinx.fem.form(self.residual_ufl()),
                              dolfinx.fem.form(self.jacobian_ufl()))
        return self._compiled

    def external_work(self):
        v, w_test = self.split(self.v)
        terms = []
        for boundary, comps, load in self._surface_loads:
            ds = self.ds(self.boundaries[boundary])
            if comps == ("phi",):
                terms.append(load.ufl() * w_test * ds)
            else:
                terms.append(ufl.dot(load.ufl(), v) * ds)
        if self._body_force is not None:
            terms.append(ufl.dot(self._body_force.ufl(), v) * ufl.dx(domain=self.mesh))
        if self._body_couple is not None:
            terms.append(self._body_couple.ufl() * w_test * ufl.dx(domain=self.mesh))
        return sum(terms[1:], terms[0]) if terms else None

    def internal_work(self):
        v, w_test = self.split(self.v)
        if self.material is not None:
            flux = self.gauss_points.flux
            return ufl.dot(flux, gradient_vector(v, w_test)) * self.dx
        work = ufl.inner(self.stress(), strain(v, w_test)) * self.dx
        if self.micropolar:
            work += ufl.dot(self.couple_stress(), curvature(w_test)) * self.dx
        return work

    def residual_ufl(self):
        ext = self.external_work()
        return self.internal_work() - ext if ext is not None else self.internal_work()

    def jacobian_ufl(self):
        if self.material is not None:
            v, w_test = self.split(self.v)
            du, dphi = self.split(self.dw)
            C = self.gauss_points.tangent_matrix()
            return ufl.dot(ufl.dot(C, gradient_vector(du, dphi)), gradient_vector(v, w_test)) * self.dx
        return ufl.derivative(self.residual_ufl(), self.w, self.dw)

    @property
    def gauss_points(self):
        """The material's Gauss-point store (quadrature.QuadratureMap), built on first
        access: the material's history is allocated then, so zones and point coordinates are
        given to the material before. None for a pure-UFL problem."""
        if self._gauss_points is None and self.material is not None:
            from .quadrature import QuadratureMap
            u, phi = self.split(self.w)
            self._gauss_points = QuadratureMap(self.mesh, self.material, gradient_vector(u, phi),
                                               self.quadrature_degree)
        return self._gauss_points

    # --- state management used by the load stepping ------------------------------------
    def before_residual(self):
        """Called by the solver whenever the fields changed (material update)."""
        if self._gauss_points is not None:
            self._gauss_points.update()

    def before_jacobian(self):
        """Called by the solver before the Jacobian is assembled (material tangents)."""
        if self._gauss_points is not None:
            self._gauss_points.update_tangent()

    def commit(self, dt):
        self.w_committed.x.array[:] = self.w.x.array
        if self._gauss_points is not None:
            self._gauss_points.commit()

    def rollback(self):
        self.w.x.array[:] = self.w_committed.x.array
        if self._gauss_points is not None:
            self._gauss_points.rollback()

    def set_time_step(self, dt):
        if self._gauss_points is not None:
            self._gauss_points.time_step = dt

    # --- post-processing ---------------------------------------------------------------
    def reaction(self, boundary, component):
        """Discrete reaction on a Dirichlet boundary: the internal-force residual summed
        over the constrained dofs of `component` [N/m per unit thickness]."""
        facets = self.facets(boundary)
        space = self.W_component(component)
        dofs = dolfinx.fem.locate_dofs_topological(space, self.mesh.topology.dim - 1, facets)
        if self._internal_form is None:
            self._internal_form = dolfinx.fem.form(self.internal_work())
        vec = dolfinx.fem.petsc.assemble_vector(self._internal_form)
        vec.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        n_owned = self.W.dofmap.index_map.size_local * self.W.dofmap.index_map_bs
        local = vec.array_r
        total = float(np.sum(local[dofs[dofs < n_owned]]))
        vec.destroy()
        return self.mesh.comm.allreduce(total)
