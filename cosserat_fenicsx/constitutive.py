"""The constitutive callback interface: what a Gauss-point material implements.

Per Gauss point, with the order of `kinematics.GRADIENT_NAMES` / `FLUX_NAMES`:

    gradients  [eps11, eps22, eps12, eps21, kappa31, kappa32]   (-, 1/m)
    fluxes     [sigma11, sigma22, sigma12, sigma21, m31, m32]   (Pa, N/m)
    tangent    d flux / d gradient, (6, 6)                      (consistent, eqs 3.36-3.38)

A material works on flat arrays over all Gauss points of the cells a rank owns (the MPI
partition splits the work), in the style of fenics-constitutive's interface and
dolfinx_materials' gradients/fluxes/tangent blocks. `update` is pure in the float history:
it reads the committed history `state_old` and writes a trial history `state_new`; the
caller copies trial into committed only when a load step has converged, which is what makes
a cut-back a rollback. A Cauchy scene passes eps12 = eps21 = sym part and zero curvature
and uses the first four fluxes only.

Three optional capabilities serve materials whose points are expensive or whose state is
not a float array (a DEM cell per Gauss point); the defaults keep the simple materials
(linear elasticity, Ehlers) exactly as they were:

* `commit()` / `rollback()` are called when a load step converged / was cut, after the
  float history was committed / restored, so resident state (cells) follows the same
  rule (dolfinx_materials' update / revert).
* `tangent_on_demand = True`: `update` need not fill `tangent_out`; the callback calls
  `tangent(points, tangent_out)` when the Jacobian is assembled, for the points updated
  since their last tangent only.
* `rate_independent = True`: the fluxes of a point depend on its committed state and its
  gradients only (not on dt), so the callback passes `points` (indices of the rows to
  update) and leaves out the points whose gradients equal those of their last update: the
  first residual of a load step (the fields are the committed ones) and any repeated
  evaluation at the same iterate. Rows not in `points` must be left untouched.

`update` (and `tangent`) may return a `PointReport`: per updated point a status (0 ok,
> 0 usable but flagged, e.g. a cell that lost every contact; < 0 failed) and a cost
(the work done, in the material's unit, e.g. DEM time steps). A material that cannot
produce a stress raises `ConstitutiveError` (or reports a negative status) with a message
naming the cause; the solver makes the failure collective over the ranks before any MPI
call, turns it into a step cut-back and reports it.
"""
import abc
from dataclasses import dataclass

import numpy as np

GRADIENT_SIZE = 6
FLUX_SIZE = 6

STATUS_OK = 0          # PointReport.status: converged
# > 0: usable result with a flag (the material documents its codes); < 0: failed


class ConstitutiveError(RuntimeError):
    """A Gauss-point update failed; the message names the cause."""


@dataclass
class PointReport:
    """What an update or tangent call did, one entry per point it was given.

    status  int array: 0 ok, > 0 usable but flagged, < 0 failed
    cost    float array: work per point in `cost_unit` (e.g. DEM time steps)
    message the cause of the first flag or failure, in words (may be empty)
    """
    status: np.ndarray
    cost: np.ndarray
    message: str = ""
    cost_unit: str = ""


class Constitutive(abc.ABC):
    """Base class of Gauss-point materials."""

    gradient_size = GRADIENT_SIZE
    flux_size = FLUX_SIZE
    state_names = ()
    tangent_on_demand = False
    rate_independent = False
    #: update / tangent do collective exchanges (balancing.BalancedMaterial): the callback
    #: calls them on every rank every time, with an empty `points` where nothing changed
    collective = False

    @property
    def state_size(self):
        return len(self.state_names)

    def initial_state(self, n_points):
        return np.zeros((n_points, self.state_size))

    @abc.abstractmethod
    def update(self, gradients, dt, state_old, flux_out, tangent_out, state_new):
        """Write flux_out (n, 6), tangent_out (n, 6, 6) and state_new (n, state_size).
        A `rate_independent` material also takes `points=` (see the module docstring)."""

    def tangent(self, points, tangent_out):
        """Write tangent_out[points] (a `tangent_on_demand` material only)."""
        raise NotImplementedError(f"{type(self).__name__} computes its tangent in update()")

    def commit(self):
        """The load step converged: the trial state becomes the committed one."""

    def rollback(self):
        """The load step was cut: return to the committed state."""

    # --- resident state: checkpoints (checkpoint.py), points moved between ranks ---------
    def export_points(self, points):
        """The committed resident state of `points` (what is not in the float history, e.g.
        a DEM cell per point) as a dict of plain arrays, {} for a material without any.
        Called between load steps (after a commit)."""
        return {}

    def import_points(self, points, arrays, rows=None):
        """Make `arrays` (from export_points, possibly on another rank or another run) the
        committed and current resident state of `points`; `rows`: which of the exported
        points they are (default: all, in order)."""

    def check_exported(self, arrays, rows=None):
        """Raise ValueError naming what is wrong if `arrays` (read back from a file, e.g. a
        checkpoint) are not states that import_points can take: types, shapes, finite values
        where the state has meaning. Called before any import, so that a refusal can be
        made on every rank together."""


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
