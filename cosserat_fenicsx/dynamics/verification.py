"""Scenes with closed-form solutions for the explicit Cosserat dynamics, and the measurement of a
period from a time series (used by tests/test_dynamics.py and
benchmarks/verification/explicit_dynamics.py).

- rotation_mode: u held at zero everywhere, phi uniform: the optical mode
      rho j phi_ddot = -4 mu_c phi,  omega_r^2 = 4 mu_c / (rho j)   (stable_step.py derives it)
  Uniform phi has no curvature, and row-sum lumping is exact on a uniform field, so the discrete
  mode is the continuum one; velocity Verlet turns omega into omega_dt with
  sin(omega_dt dt / 2) = omega dt / 2 (the central difference's exact phase).
- p_wave: a strip [0, L] x [0, H], u2 held at zero everywhere, u1 = 0 at x = 0 and x = L, free
  top and bottom: u1 = A sin(pi x / L) cos(omega t), omega = c_p pi / L, c_p = sqrt((lambda +
  2 mu)/rho). This field has no skew strain (u1,2 = u2,1 = phi = 0), so it does not excite the
  rotation whatever mu_c and l_c: the Cauchy P wave, exactly. On Q1 with a uniform mesh the
  field is y-independent and the scheme reduces to the 1D lumped linear element:
      omega_h = (2 c_p / h) sin(k h / 2),  k = pi / L   (relative error -(k h)^2 / 24).
"""
import math

import dolfinx.fem
import numpy as np

from ..elasticity import MicropolarElasticity
from .. import meshes
from .explicit import ExplicitCosserat

CELL_TYPES = {"Q1/Q1": "quadrilateral", "P2/P1": "triangle"}


def verlet_frequency(omega, dt):
    """Angular frequency of the undamped central difference for a mode omega [rad/s]."""
    return 2.0 / dt * math.asin(omega * dt / 2.0)


def spatial_frequency(omega_measured, dt):
    """The semi-discrete (FE) frequency behind a measured Verlet one: inverts verlet_frequency."""
    return 2.0 / dt * math.sin(omega_measured * dt / 2.0)


def zero_crossing_period(times, signal):
    """Mean period [s] from the upward and downward zero crossings (linear interpolation between
    samples), over whole half periods from the first crossing to the last."""
    s = np.asarray(signal, dtype=float)
    t = np.asarray(times, dtype=float)
    sign_change = np.nonzero(s[:-1] * s[1:] < 0.0)[0]
    if len(sign_change) < 3:
        raise ValueError(f"need at least 3 zero crossings to measure a period, found {len(sign_change)}")
    crossings = t[sign_change] - s[sign_change] * (t[sign_change + 1] - t[sign_change]) / (
        s[sign_change + 1] - s[sign_change])
    return 2.0 * (crossings[-1] - crossings[0]) / (len(crossings) - 1)


def decay_rate(times, signal):
    """Exponential decay rate [1/s] of an oscillation: least-squares slope of log|peak| against
    the peak times (local maxima of |signal|, refined by a parabola through three samples)."""
    s = np.abs(np.asarray(signal, dtype=float))
    t = np.asarray(times, dtype=float)
    i = np.nonzero((s[1:-1] > s[:-2]) & (s[1:-1] >= s[2:]))[0] + 1
    if len(i) < 3:
        raise ValueError(f"need at least 3 peaks to measure a decay, found {len(i)}")
    y0, y1, y2 = np.log(s[i - 1]), np.log(s[i]), np.log(s[i + 1])
    denom = y0 - 2.0 * y1 + y2
    shift = np.where(denom != 0.0, 0.5 * (y0 - y2) / np.where(denom != 0.0, denom, 1.0), 0.0)
    dt = t[1] - t[0]
    peak_t = t[i] + shift * dt
    peak_y = y1 - 0.25 * (y0 - y2) * shift
    return -np.polyfit(peak_t, peak_y, 1)[0]


def _all_dofs(model, name):
    return model.subspace(name)[1]


def rotation_mode(comm, element="Q1/Q1", divisions=(4, 4), mu=1.0, lmbda=1.0, mu_c=0.5, l_c=0.1,
                  density=2.0, micro_inertia=0.01, mass_damping=0.0, phi0=1e-3, **kwargs):
    """(model, signal, omega_r): the unit square, u held at zero, phi = phi0 uniform at rest;
    signal() is the mass-weighted mean rotation [rad] (global)."""
    mesh, _, _ = meshes.rectangle(comm, 1.0, 1.0, divisions=divisions, cell_type=CELL_TYPES[element])
    elasticity = MicropolarElasticity(mu=mu, lmbda=lmbda, mu_c=mu_c, l_c=l_c)
    probe = ExplicitCosserat(mesh, elasticity, density, micro_inertia, mass_damping, element=element, **kwargs)
    dirichlet = [("u1", _all_dofs(probe, "u1"), 0.0), ("u2", _all_dofs(probe, "u2"), 0.0)]
    model = ExplicitCosserat(mesh, elasticity, density, micro_inertia, mass_damping, element=element,
                             dirichlet=dirichlet, **kwargs)
    phi = _all_dofs(model, "phi")
    weights = model.mass.copy()
    weights.array[:] = 0.0
    owned = phi[phi < len(weights.array)]
    weights.array[owned] = model.mass.array[owned]
    weights.scale(1.0 / weights.sum())
    model.displacement.array[owned] = phi0
    model.update_acceleration()
    omega = math.sqrt(4.0 * mu_c / (density * micro_inertia))
    return model, (lambda: model.displacement.dot(weights)), omega


def p_wave(comm, element="Q1/Q1", nx=8, ny=1, length=1.0, height=0.25, mu=0.3, lmbda=0.4, mu_c=0.03,
           l_c=0.05, density=1.0, micro_inertia=1.0, mass_damping=0.0, amplitude=1e-3, **kwargs):
    """(model, signal, omega): the standing P wave of the strip (module docstring), started
    from u1 = amplitude sin(pi x / L) at rest; signal() is the mass-weighted projection of u1
    on that shape [m] (global). omega = c_p pi / L (continuum) [rad/s]."""
    mesh, _, _ = meshes.rectangle(comm, length, height, divisions=(nx, ny), cell_type=CELL_TYPES[element])
    elasticity = MicropolarElasticity(mu=mu, lmbda=lmbda, mu_c=mu_c, l_c=l_c)
    probe = ExplicitCosserat(mesh, elasticity, density, micro_inertia, mass_damping, element=element, **kwargs)
    ends = lambda x: np.isclose(x[0], 0.0) | np.isclose(x[0], length)   # noqa: E731
    dirichlet = [("u2", _all_dofs(probe, "u2"), 0.0), ("u1", ends, 0.0)]
    model = ExplicitCosserat(mesh, elasticity, density, micro_inertia, mass_damping, element=element,
                             dirichlet=dirichlet, **kwargs)
    space, dofs = model.subspace("u1")
    shape = dolfinx.fem.Function(space)
    shape.interpolate(lambda x: np.sin(math.pi * x[0] / length))
    n = len(model.displacement.array)
    owned = dofs < n
    model.displacement.array[dofs[owned]] = amplitude * shape.x.array[owned]
    model.update_acceleration()
    weights = model.mass.copy()
    weights.array[:] = 0.0
    weights.array[dofs[owned]] = model.mass.array[dofs[owned]] * shape.x.array[owned]
    norm = model.displacement.dot(weights)
    weights.scale(amplitude / norm)
    c_p = math.sqrt((lmbda + 2.0 * mu) / density)
    return model, (lambda: model.displacement.dot(weights)), c_p * math.pi / length


def run(model, signal, dt, steps, energy=False):
    """(times, signal values[, total energies]) over `steps` steps, the start included."""
    times, values, energies = [model.time], [signal()], []
    if energy:
        energies.append(model.kinetic_energy() + model.strain_energy())
    for _ in range(steps):
        model.step(dt)
        times.append(model.time)
        values.append(signal())
        if energy:
            energies.append(model.kinetic_energy() + model.strain_energy())
    if energy:
        return np.array(times), np.array(values), np.array(energies)
    return np.array(times), np.array(values)
