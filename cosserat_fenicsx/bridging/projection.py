"""Scale decomposition of the grains' motion: the mass-weighted projection of paper 003.

Li and Wan (2010), eqs 3-8 and 12: the particle displacements q (translations u1, u2 and
the rotation phi of every grain, the total DEM motion) split into a coarse part N d_hat(q),
interpolated from the nodal values of the Cosserat field, and a fine part Q q = q - N d_hat(q),

    d_hat(q) = M^-1 N^T M_p q,   M = N^T M_p N,   P = N M^-1 N^T M_p,   Q = I - P   (eqs 3-7)

with N the finite-element shape functions evaluated at the grains' reference centres. M_p is
diagonal and N does not mix components, so the projection factors into three scalar ones:
the translations weighted by the grain masses m [kg/m] (M_u = N_u^T diag(m) N_u) and the
rotation weighted by the rotary inertias J [kg m] (M_phi = N_phi^T diag(J) N_phi). For
equal-order elements (the paper's Q1) N_u = N_phi; for Taylor-Hood P2/P1 they differ.

The fine part is M_p-orthogonal to the coarse basis, N^T M_p Q = 0 (eq 12), so the kinetic
energy splits exactly: 1/2 qdot^T M_p qdot = 1/2 ddot^T M ddot + 1/2 (Q qdot)^T M_p (Q qdot).

numpy and scipy only: the matrices come from cosserat_fenicsx.bridging.shape_map (or any
other particle -> element map). M is factorised once (Cholesky); an element whose grains
cannot determine its nodal values (too few, or collinear) makes M singular and is refused
by name before any work.
"""
from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.sparse

from cosserat_fenicsx.validation import InputError

# Cholesky pivots below this fraction of the largest diagonal of M are treated as singular:
# far above round-off (1e-16) and far below any well-posed element (a grain-filled element
# has pivots of the order of its own mass share).
_SINGULAR_PIVOT = 1e-10


@dataclass
class CoarseCoefficients:
    """Nodal values d_hat of the coarse field over the projection's own nodes:
    u (n_u_nodes, 2) translations [m] at `nodes_u`, phi (n_phi_nodes,) rotations [rad]
    at `nodes_phi` (column indices of the shape-function matrices)."""
    u: np.ndarray
    phi: np.ndarray


class _ScalarProjection:
    """One weighted least-squares projection onto span(N_s): the nodes are the columns of
    N_s that some particle sees; M = N_s^T W N_s over those, Cholesky-factorised once."""

    def __init__(self, shape, weights, label, element_of_particle):
        shape = scipy.sparse.csr_matrix(shape)
        weights = np.asarray(weights, dtype=float)
        if shape.shape[0] != weights.size:
            raise InputError(f"projection: {weights.size} {label} weights for "
                             f"{shape.shape[0]} particles")
        if not np.all(np.isfinite(weights)) or np.any(weights <= 0.0):
            raise InputError(f"projection: every {label} weight must be finite and > 0")
        used = np.unique(shape.indices[shape.data != 0.0])
        self.nodes = used
        self.shape = shape[:, used].tocsr()
        # N^T once: building the transpose per call cost more than the solve
        self._shape_t = self.shape.T.tocsr()
        self.weights = weights
        if element_of_particle is not None:
            self._refuse_underdetermined_elements(np.asarray(element_of_particle), label)
        mass = (self.shape.T @ scipy.sparse.diags(weights) @ self.shape).toarray()
        self.mass = mass
        self._factor = self._factorise(mass, label)

    def _refuse_underdetermined_elements(self, element_of_particle, label):
        """An element whose grains do not fix its nodal values (fewer grains than nodes,
        or grains on a line) makes M singular or nearly so: refuse it by name."""
        for element in np.unique(element_of_particle):
            rows = np.flatnonzero(element_of_particle == element)
            block = self.shape[rows]
            cols = np.unique(block.indices[block.data != 0.0])
            dense = block[:, cols].toarray()
            rank = np.linalg.matrix_rank(dense, tol=1e-8 * max(1.0, np.abs(dense).max()))
            if rank < cols.size:
                raise InputError(
                    f"projection: element {int(element)} holds {rows.size} grain(s), too few "
                    f"(or collinear) to determine its {cols.size} nodal {label} values: "
                    f"M = N^T M_p N is singular (refine the grains or coarsen the mesh)")

    def _factorise(self, mass, label):
        diag = np.diag(mass)
        if mass.shape[0] == 0:
            raise InputError(f"projection: no particle inside the {label} element nodes")
        try:
            factor = scipy.linalg.cho_factor(mass, lower=True, check_finite=True)
        except np.linalg.LinAlgError:
            factor = None
        pivots = np.abs(np.diag(factor[0])) ** 2 if factor is not None else np.zeros(1)
        if factor is None or pivots.min() < _SINGULAR_PIVOT * diag.max():
            weak = self.nodes[np.argsort(diag)[:4]]
            raise InputError(f"projection: M = N^T M_p N over the {label} nodes is singular "
                             f"(nodes with the least mass: {weak.tolist()}); an element holds "
                             f"too few grains")
        return factor

    def coefficients(self, values):
        """d_hat = M^-1 N^T W q for one scalar component or several columns (n_p, k)."""
        weights = self.weights[:, None] if values.ndim == 2 else self.weights
        return scipy.linalg.cho_solve(self._factor, self._shape_t @ (weights * values))

    def interpolate(self, coefficients):
        return self.shape @ coefficients


class ScaleProjection:
    """The bridging-scale projection of a grain set (003 eqs 3-8, 12).

    shape_u: scipy sparse (n_particles, n_nodes_u), the scalar shape functions of the
        translation field at the grain centres (rows sum to 1 for particles inside the mesh).
    mass: (n_particles,) grain masses m [kg per m depth] (weights of u1 and u2).
    inertia: (n_particles,) rotary inertias J [kg m^2 per m depth] (weights of phi).
    shape_phi: the scalar shape functions of the rotation field; None = shape_u (equal order).
    element_of_particle: (n_particles,) element index of each grain; when given, an element
        whose grains cannot determine its nodal values is refused by its index.

    Particle arrays q are (n_particles, 3): (u1, u2, phi) per grain, in the order of the rows.
    """

    def __init__(self, shape_u, mass, inertia, shape_phi=None, element_of_particle=None):
        self._u = _ScalarProjection(shape_u, mass, "translation", element_of_particle)
        # equal order: the rotation uses the same shape functions with the inertia weights
        self._phi = _ScalarProjection(shape_u if shape_phi is None else shape_phi, inertia,
                                      "rotation", element_of_particle)
        self.mass = self._u.weights
        self.inertia = self._phi.weights
        self.n_particles = self.mass.size

    @property
    def nodes_u(self):
        """Column indices of shape_u that the projection's translation coefficients refer to."""
        return self._u.nodes

    @property
    def nodes_phi(self):
        return self._phi.nodes

    @property
    def matrices(self):
        """The consistent coarse mass matrices (M_u, M_phi) (eq 5), dense, over nodes_u / nodes_phi."""
        return self._u.mass, self._phi.mass

    def _check(self, q):
        q = np.asarray(q, dtype=float)
        if q.shape != (self.n_particles, 3):
            raise InputError(f"projection: particle field must be ({self.n_particles}, 3), "
                             f"got {q.shape}")
        return q

    def project(self, q):
        """d_hat(q) = M^-1 N^T M_p q (eqs 3-5), as CoarseCoefficients."""
        q = self._check(q)
        return CoarseCoefficients(u=self._u.coefficients(q[:, :2]),
                                  phi=self._phi.coefficients(q[:, 2]))

    def interpolate(self, coefficients):
        """N d: the particle field (n_particles, 3) of nodal values d."""
        out = np.empty((self.n_particles, 3))
        out[:, :2] = self._u.interpolate(coefficients.u)
        out[:, 2] = self._phi.interpolate(coefficients.phi)
        return out

    def coarse(self, q):
        """P q = N d_hat(q) (eq 3)."""
        return self.interpolate(self.project(q))

    def coarse_translation(self, q):
        """(n, 2): the translations of P q (eq 3), coarse(q)[:, :2] without the rotation's
        projection."""
        q = self._check(q)
        return self._u.interpolate(self._u.coefficients(q[:, :2]))

    def fine(self, q):
        """Q q = q - N d_hat(q) (eqs 6-7)."""
        q = self._check(q)
        return q - self.coarse(q)

    def kinetic_energy(self, qdot):
        """(total, coarse, fine) kinetic energies [J per m depth] of the particle velocities
        (eq 12): 1/2 qdot^T M_p qdot, 1/2 ddot^T M ddot with ddot = d_hat(qdot), and
        1/2 (Q qdot)^T M_p (Q qdot). total = coarse + fine up to round-off."""
        qdot = self._check(qdot)
        weights = np.column_stack([self.mass, self.mass, self.inertia])
        total = 0.5 * np.sum(weights * qdot ** 2)
        d = self.project(qdot)
        m_u, m_phi = self.matrices
        coarse = 0.5 * (np.einsum("ik,ij,jk->", d.u, m_u, d.u) + d.phi @ m_phi @ d.phi)
        fine_part = qdot - self.interpolate(d)
        fine = 0.5 * np.sum(weights * fine_part ** 2)
        return total, coarse, fine

    def lumped_mass(self):
        """Row-sum lumped coarse masses (eq 5 lumped): N_u^T m [kg] over nodes_u and
        N_phi^T J [kg m^2] over nodes_phi (the row sums of M when N is a partition of unity)."""
        return (np.asarray(self._u.shape.T @ self.mass).ravel(),
                np.asarray(self._phi.shape.T @ self.inertia).ravel())
