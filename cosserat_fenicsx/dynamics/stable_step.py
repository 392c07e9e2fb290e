"""Stable time step of the explicit central-difference / velocity-Verlet scheme (003 eqs 31-34).

Velocity Verlet is stable for dt <= 2 / omega_max, omega_max^2 the largest eigenvalue of
M^-1 K (M the lumped mass, K the stiffness, on the free dofs). The mass damping of eq 33 does
not move this limit: the scheme is Newmark beta = 0, gamma = 1/2 with the damping force at
v^{n+1}, whose critical Omega = omega dt is 2 for every damping ratio (Hughes 1987, the
Omega_crit formula at gamma = 1/2).

Three numbers [s]:

- power: 2 / sqrt(lambda_max), lambda_max from the power iteration on M^-1 K restricted to the
  free dofs (Dirichlet and massless dofs removed), with the Rayleigh quotient
  (x.Kx)/(x.Mx) as the estimate. The quotient approaches lambda_max from below, so the step it
  gives is approached from above: the iteration stops when the quotient changes by less than
  `rtol` over `check` iterations, and the result is multiplied by `safety` (default 1 - 1e-3).
- translational: h_min / c_p, c_p = sqrt((lambda + 2 mu)/rho) the P-wave speed, h_min the
  shortest cell edge of the active cells. The textbook CFL estimate: exact for the 1D lumped
  linear element, an estimate (not a bound) for Q1 and P2 in 2D.
- rotational: 2 / omega_r, the optical (homogeneous rotation) mode of the Cosserat continuum.
  With u = 0 and phi uniform, eps = phi E3 (kinematics.strain), so sigma = 2 mu_c skw(eps) =
  2 mu_c phi E3 and the virtual work sigma : (w E3) = 2 mu_c phi w (E3 : E3) = 4 mu_c phi w;
  the curvature does not enter. The kinetic energy 1/2 rho j phi_dot^2 gives
      rho j phi_ddot = -4 mu_c phi,   omega_r^2 = 4 mu_c / (rho j)
  for this project's sigma = 2 mu sym + lambda tr I + 2 mu_c skw (003 section 4 writes the
  same with G_c = mu_c). It is independent of h and is the exact lambda_max of M^-1 K when u is
  held and l_c = 0 (lumped rotary inertia of degree-1 elements: M_L^-1 M has largest
  eigenvalue 1, at the uniform field). Curvature stiffness (l_c > 0) and coupling with u
  raise omega_max above omega_r: the power estimate is the one to use.
"""
import math

import numpy as np

from .mass import mass_dot

POWER_ITERATIONS = 2000


def rotational_step(elasticity, density, micro_inertia):
    """2 / sqrt(4 mu_c / (rho j)) [s]; inf when mu_c = 0."""
    if elasticity.mu_c == 0.0:
        return math.inf
    return 2.0 / math.sqrt(4.0 * elasticity.mu_c / (density * micro_inertia))


def translational_step(elasticity, density, h_min):
    """h_min / c_p [s], c_p = sqrt(M / rho), M the law's largest longitudinal modulus
    (lambda + 2 mu when isotropic)."""
    return h_min / math.sqrt(elasticity.p_wave_modulus / density)


def start_vector(x):
    """A deterministic pseudo-random field of the coordinates (rank-count independent)."""
    return np.sin(43758.5453 * np.sin(12.9898 * x[0] + 78.233 * x[1] + 1.0))


def power_step(apply_stiffness, mass, free, x, rtol=1e-7, check=20, max_iterations=POWER_ITERATIONS,
               safety=1.0 - 1e-3):
    """2 / sqrt(lambda_max(M^-1 K)) on the free dofs [s], by power iteration.

    apply_stiffness(x, y): y = K x (PETSc Vecs); mass: lumped mass Vec; free: boolean array over
    the owned dofs; x: start Vec (consumed: do not use it afterwards). Returns (step, lambda_max, iterations).
    Global reductions only: every rank gets the same numbers."""
    inv_mass = np.zeros_like(mass.array)
    inv_mass[free] = 1.0 / mass.array[free]
    y = x.duplicate()
    x.array[~free] = 0.0
    lam, previous, iterations = 0.0, None, 0
    for iterations in range(1, max_iterations + 1):
        xmx = mass_dot(x, mass)
        if not xmx > 0.0:
            break
        x.scale(1.0 / math.sqrt(xmx))         # x.Mx = 1
        apply_stiffness(x, y)                  # y = K x
        lam = x.dot(y)                         # Rayleigh quotient x.Kx / x.Mx
        y.array[:] *= inv_mass                 # y = M^-1 K x on the free dofs, 0 elsewhere
        x, y = y, x
        if iterations % check == 0:
            if previous is not None and abs(lam - previous) <= rtol * abs(lam):
                break
            previous = lam
    if not lam > 0.0:
        return math.inf, lam, iterations
    return safety * 2.0 / math.sqrt(lam), lam, iterations

