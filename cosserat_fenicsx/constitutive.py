"""The constitutive callback interface: what a Gauss-point material implements.

Per Gauss point, with the order of `kinematics.GRADIENT_NAMES` / `FLUX_NAMES`:

    gradients  [eps11, eps22, eps12, eps21, kappa31, kappa32]   (-, 1/m)
    fluxes     [sigma11, sigma22, sigma12, sigma21, m31, m32]   (Pa, N/m)
    tangent    d flux / d gradient, (6, 6)                      (consistent, eqs 3.36-3.38)

A material works on flat arrays over all Gauss points of the cells a rank owns (the MPI
partition splits the work), in the style of fenics-constitutive's interface and
dolfinx_materials' gradients/fluxes/tangent blocks. `update` is pure: it reads the
committed history `state_old` and writes a trial history `state_new`; the caller copies
trial into committed only when a load step has converged, which is what makes a
cut-back a rollback. A Cauchy scene passes eps12 = eps21 = sym part and zero curvature
and uses the first four fluxes only.

A material that cannot produce a stress raises `ConstitutiveError` with a message naming
the cause; the solver turns that into a step cut-back and reports it.
"""
import abc

import numpy as np

GRADIENT_SIZE = 6
FLUX_SIZE = 6


class ConstitutiveError(RuntimeError):
    """A Gauss-point update failed; the message names the cause."""


class Constitutive(abc.ABC):
    """Base class of Gauss-point materials."""

    gradient_size = GRADIENT_SIZE
    flux_size = FLUX_SIZE
    state_names = ()

    @property
    def state_size(self):
        return len(self.state_names)

    def initial_state(self, n_points):
        return np.zeros((n_points, self.state_size))

    @abc.abstractmethod
    def update(self, gradients, dt, state_old, flux_out, tangent_out, state_new):
        """Write flux_out (n, 6), tangent_out (n, 6, 6) and state_new (n, state_size)."""


class LinearElasticMaterial(Constitutive):
    """Linear isotropic micropolar elasticity through the callback: the trivial
    implementation of the interface, used to check the callback plumbing against the
    pure-UFL path. `elasticity` is a `MicropolarElasticity`."""

    def __init__(self, elasticity):
        e = elasticity
        lam, mu, mu_c, bend = e.lmbda, e.mu, e.mu_c, e.bending_modulus
        c = np.zeros((6, 6))
        c[0, 0] = c[1, 1] = lam + 2.0 * mu
        c[0, 1] = c[1, 0] = lam
        c[2, 2] = c[3, 3] = mu + mu_c
        c[2, 3] = c[3, 2] = mu - mu_c
        c[4, 4] = c[5, 5] = bend
        self.stiffness = c

    def update(self, gradients, dt, state_old, flux_out, tangent_out, state_new):
        np.matmul(gradients, self.stiffness.T, out=flux_out)
        tangent_out[:] = self.stiffness
