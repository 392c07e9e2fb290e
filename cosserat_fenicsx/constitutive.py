"""The Gauss-point material interface: what a material implements (docs/reference/quadrature_map.md).

Per Gauss point, with the order of `kinematics.GRADIENT_NAMES` / `FLUX_NAMES`:

    gradients  [eps11, eps22, eps12, eps21, kappa31, kappa32]   (-, 1/m)
    fluxes     [sigma11, sigma22, sigma12, sigma21, m31, m32]   (Pa, N/m)
    tangent    d flux / d gradient, (6, 6)                      (consistent, eqs 3.36-3.38)

A material works on flat arrays over all Gauss points of the cells a rank owns (the MPI
partition splits the work), in the style of fenics-constitutive's interface and
dolfinx_materials' gradients/fluxes/tangent blocks; the store of these arrays is
quadrature.QuadratureMap. `update` is pure in the float history: it reads the committed
history `state_old` and writes a trial history `state_new`; the store copies trial into
committed only when a load step has converged, which is what makes a cut-back a rollback.
A Cauchy scene passes eps12 = eps21 = sym part and zero curvature and uses the first four
fluxes only.

Every hook below is declared on `Constitutive` with a default that keeps the simple
materials (linear elasticity, Ehlers) as they are; a material overrides what it needs:

* `update(..., points=None)`: `points` None updates every row; a `rate_independent`
  material (fluxes depend on its committed state and its gradients only, not on dt) is
  given the indices of the rows to update instead: the store leaves out the points whose
  gradients equal those of their last update, bitwise (the first residual of a load step,
  whose fields are the committed ones, and any repeated evaluation at the same iterate).
  Rows not in `points` must be left untouched. A material that is not rate_independent is
  always given None.
* `commit()` / `rollback()` are called when a load step converged / was cut, after the
  float history was committed / restored, so resident state (cells) follows the same
  rule (dolfinx_materials' update / revert).
* `tangent_on_demand = True`: `update` need not fill `tangent_out`; the store calls
  `tangent(points, tangent_out)` when the Jacobian is assembled, for the points updated
  since their last tangent only.
* `collective = True`: update and tangent exchange data between ranks; the store calls
  them on every rank every time, with an empty `points` where nothing changed.
* set-up, before the store is built: `set_zones(zone)` (which variant of the material
  each point is), `set_point_coordinates(xy)` (to name a point in messages, `where`);
  then the store reads `initial_state(n)` and `initial_fluxes(n)`.
* resident state (what is not in the float history, e.g. a DEM cell per point):
  `export_points`, `import_points`, `check_exported` (checkpoints, points moved between
  ranks).
* `use_fallback_operator(on)`: a `tangent_on_demand` material with a second operator that
  stays positive definite where its own does not (a DEM cell's contact stiffness past a
  peak, where the consistent operator of a sliding network turns singular) switches to it;
  fallback.FallbackSolver tries a failed load step with it before the step is cut.
* diagnostics: `cost_unit`, `timers`, `memory_bytes()`, `describe()`.

`update` (and `tangent`) may return a `PointReport`: per updated point a status (0 ok,
> 0 usable but flagged, e.g. a cell that lost every contact; < 0 failed) and a cost
(the work done, in the material's `cost_unit`, e.g. DEM time steps). A material that cannot
produce a stress raises `ConstitutiveError` (or reports a negative status) with a message
naming the cause; the solver makes the failure collective over the ranks before any MPI
call, turns it into a step cut-back and reports it.
"""
import abc
from dataclasses import dataclass
from types import MappingProxyType

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
    """Base class of Gauss-point materials (see the module docstring for every hook)."""

    gradient_size = GRADIENT_SIZE
    flux_size = FLUX_SIZE
    state_names = ()
    tangent_on_demand = False
    rate_independent = False
    #: update / tangent do collective exchanges (balancing.BalancedMaterial): the store
    #: calls them on every rank every time, with an empty `points` where nothing changed
    collective = False
    #: unit of PointReport.cost, e.g. "DEM time steps" ("" : no cost reported)
    cost_unit = ""
    #: (n, 2) x, y [m] of the points, given by set_point_coordinates (None: not given)
    coordinates = None
    #: wall seconds [s] spent per part of the work, e.g. {"solve": ..., "tangent": ...}
    timers = MappingProxyType({})

    @property
    def state_size(self):
        return len(self.state_names)

    @property
    def state_index(self):
        """Column of each history variable: state[:, material.state_index[name]]."""
        return {name: i for i, name in enumerate(self.state_names)}

    # --- set-up, before the store is built ------------------------------------------------
    def set_zones(self, zone):
        """zone[p]: which variant of the material point p is (e.g. a weakened one). A
        material with one variant takes zeros only."""
        zone = np.asarray(zone)
        if zone.size and np.any(zone != 0):
            raise ValueError(f"{type(self).__name__} has one zone: zone indices must be 0")

    def set_point_coordinates(self, xy):
        """(x, y) [m] of the points (quadrature.gauss_point_coordinates), used by `where`."""
        self.coordinates = np.asarray(xy, dtype=float)

    def where(self, p):
        """Point p in words, for messages: its position when the coordinates were given."""
        if self.coordinates is not None and p < len(self.coordinates):
            x, y = self.coordinates[p]
            return f"Gauss point at ({x:.4g}, {y:.4g})"
        return f"local Gauss point {p}"

    def initial_state(self, n_points):
        """(n_points, state_size) committed history before the first step."""
        return np.zeros((n_points, self.state_size))

    def initial_fluxes(self, n_points):
        """(n_points, flux_size) fluxes before the first step (a pre-stressed reference
        state has its stress here), zero by default."""
        return np.zeros((n_points, self.flux_size))

    # --- the update ------------------------------------------------------------------------
    @abc.abstractmethod
    def update(self, gradients, dt, state_old, flux_out, tangent_out, state_new, points=None):
        """Write flux_out (n, 6), tangent_out (n, 6, 6) and state_new (n, state_size) for
        the rows `points` (None: every row; see the module docstring); dt [pseudo-time].
        May return a PointReport with one entry per updated row."""

    def tangent(self, points, tangent_out):
        """Write tangent_out[points] (a `tangent_on_demand` material only)."""
        raise NotImplementedError(f"{type(self).__name__} computes its tangent in update()")

    def use_fallback_operator(self, on):
        """Compute the tangents from now on with the material's fallback operator (on=True)
        or its own (on=False); True if that changed the operator. Default: no fallback."""
        return False

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

    # --- diagnostics -----------------------------------------------------------------------
    def memory_bytes(self):
        """Bytes of resident state held on this rank (0 for a material without any)."""
        return 0

    def describe(self):
        """What the run's summary records about the material (a dict of plain values)."""
        return {}

    @property
    def counters(self):
        """Counts of the material's own events on this rank so far ({name: int}; none by
        default)."""
        return {}


class LinearElasticMaterial(Constitutive):
    """Linear isotropic micropolar elasticity as a Gauss-point material: the trivial
    implementation of the interface, used to check the Gauss-point store against the
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

    def update(self, gradients, dt, state_old, flux_out, tangent_out, state_new, points=None):
        if points is None:
            np.matmul(gradients, self.stiffness.T, out=flux_out)
            tangent_out[:] = self.stiffness
        else:
            flux_out[points] = gradients[points] @ self.stiffness.T
            tangent_out[points] = self.stiffness
