"""Gauss-point plumbing of the constitutive callback.

Strain and curvature are evaluated at the quadrature points of the cells this rank owns
(dolfinx 0.5 cannot interpolate an Expression into a quadrature space, so the Expression
is evaluated and the array written), the material updates every point, and stress,
couple stress and tangent are written into quadrature Functions that the residual and
Jacobian forms use. The quadrature degree of these spaces is the degree of the forms'
measure, so the forms read exactly the values the material produced.
"""
import dolfinx.fem
import numpy as np
import ufl

from . import compat
from .constitutive import ConstitutiveError
from .kinematics import stress_tensor, couple_stress_vector


class GaussPointCallback:
    """Owns the quadrature fields and the committed/trial history of one material."""

    def __init__(self, mesh, material, gradient_ufl, degree):
        self.mesh = mesh
        self.material = material
        self.degree = degree
        nf = material.flux_size
        self.flux_space = compat.function_space(mesh, compat.quadrature_element(mesh, degree, nf))
        self.tangent_space = compat.function_space(mesh, compat.quadrature_element(mesh, degree, nf * nf))
        self.flux = dolfinx.fem.Function(self.flux_space, name="flux")
        self.tangent = dolfinx.fem.Function(self.tangent_space, name="tangent")
        points, self.weights = compat.quadrature_points(mesh, degree)
        self.n_qp = points.shape[0]
        self.cells = np.arange(compat.num_owned_cells(mesh), dtype=np.int32)
        self.expression = dolfinx.fem.Expression(gradient_ufl, points)
        # point p of owned cell c -> row of the flat Gauss-point arrays
        self.dofs = compat.cell_dofs(self.flux_space, len(self.cells)).reshape(-1)
        n = self.n_points
        self.gradients = np.zeros((n, material.gradient_size))
        self.flux_values = np.zeros((n, nf))
        self.tangent_values = np.zeros((n, nf, nf))
        self.state_old = material.initial_state(n)
        self.state_new = self.state_old.copy()
        self.time_step = 0.0

    @property
    def n_points(self):
        return len(self.cells) * self.n_qp

    # --- UFL views used by the forms -----------------------------------------------
    def stress(self):
        return stress_tensor(self.flux)

    def couple_stress(self):
        return couple_stress_vector(self.flux)

    def tangent_matrix(self):
        n = self.material.flux_size
        return ufl.as_matrix([[self.tangent[n * i + j] for j in range(n)] for i in range(n)])

    # --- the update ------------------------------------------------------------------
    def evaluate_gradients(self):
        values = compat.eval_expression(self.expression, self.mesh, self.cells)
        self.gradients[:] = values.reshape(self.n_points, -1)
        return self.gradients

    def update(self):
        """Update every owned Gauss point from the current fields. Raises
        ConstitutiveError on this rank only; the caller makes the failure collective."""
        self.evaluate_gradients()
        self.material.update(self.gradients, self.time_step, self.state_old,
                             self.flux_values, self.tangent_values, self.state_new)
        if not (np.isfinite(self.flux_values).all() and np.isfinite(self.tangent_values).all()):
            bad = np.flatnonzero(~np.isfinite(self.flux_values).all(axis=1))
            raise ConstitutiveError(f"material returned non-finite stress or tangent at "
                                    f"{max(len(bad), 1)} Gauss point(s)")
        nf = self.material.flux_size
        self.flux.x.array.reshape(-1, nf)[self.dofs] = self.flux_values
        self.tangent.x.array.reshape(-1, nf * nf)[self.dofs] = self.tangent_values.reshape(-1, nf * nf)

    def commit(self):
        self.state_old[:] = self.state_new

    def rollback(self):
        self.state_new[:] = self.state_old

    def cell_average(self, values):
        """Quadrature-weighted average per owned cell of a (n_points, k) array."""
        v = values.reshape(len(self.cells), self.n_qp, -1)
        return np.einsum("cqk,q->ck", v, self.weights) / self.weights.sum()
