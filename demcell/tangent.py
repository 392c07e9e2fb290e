"""Tangent operators of a cell for the macroscopic Newton iteration (paper 001, sections 3-5).

All operators are returned as 4x4 matrices in the notation of 001 eq. 11: rows are
(sigma_11, sigma_12, sigma_21, sigma_22), columns (dF_11, dF_12, dF_21, dF_22), i.e.
d sigma_ij = C_ijkl dF_kl. Since F = I + Grad u with (Grad u)_kl = du_k/dX_l, this is
also d sigma / d Grad u. ``dsigma_to_dpk1`` converts to dP/dF (same ordering), the operator a
total-Lagrangian FE code needs.

* ``kruyt`` (UKO, 001 eq. 13): affine contact displacements, contact springs only; no
  rotations, no pre-stress, no sliding. Written for the current configuration:
  C_ijkm = 1/|Y| sum_c (kn n_i n_k + kt t_i t_k) l_j (F^-1 l)_m, which is eq. 13 when F = I.
* ``perturbation`` (CTO, 001 eq. 6): C_ijmn = (S_ij(F + eps L^mn) - S_ij(F)) / eps, each
  column a full solve from the last committed state (four extra solves).
* ``demqo`` (001 eq. 20): from the current equilibrium, contacts frozen (no loss, no
  creation, bilateral), friction infinite; four small relaxations.
"""
import math

import numpy as np

from .contact_law import KN, KS, MU
from .periodic_cell import branch_vector

COMPONENTS = ((0, 0), (0, 1), (1, 0), (1, 1))   # order 11, 12, 21, 22 (001 eq. 11)


def to_tensor4(C):
    """4x4 (001 eq. 11 order) -> C[i, j, k, l]."""
    T = np.zeros((2, 2, 2, 2))
    for r, (i, j) in enumerate(COMPONENTS):
        for c, (k, l) in enumerate(COMPONENTS):
            T[i, j, k, l] = C[r, c]
    return T


def from_tensor4(T):
    """C[i, j, k, l] -> 4x4 (001 eq. 11 order)."""
    return np.array([[T[i, j, k, l] for (k, l) in COMPONENTS] for (i, j) in COMPONENTS])


def dsigma_to_dpk1(C_sigma, F, sigma):
    """dP/dF from dsigma/dF, with P = J sigma F^-T:
    dP = J tr(F^-1 dF) sigma F^-T + J dsigma F^-T - J sigma F^-T dF^T F^-T."""
    J = np.linalg.det(F)
    Fi = np.linalg.inv(F)
    out = np.zeros((4, 4))
    for c, (k, l) in enumerate(COMPONENTS):
        dF = np.zeros((2, 2))
        dF[k, l] = 1.0
        dsig = C_sigma[:, c].reshape(2, 2)
        dP = (J * np.trace(Fi @ dF) * sigma @ Fi.T + J * dsig @ Fi.T
              - J * sigma @ Fi.T @ dF.T @ Fi.T)
        out[:, c] = dP.reshape(4)
    return out


def kruyt_operator(state, law):
    """Upper-bound Kruyt operator (UKO, 001 eq. 13) of the current contacts [N/m]."""
    h, s = state.h, state.s
    area = abs(np.linalg.det(h))
    Fi = np.linalg.inv(state.F)
    kt = law[KS] if law[MU] > 0.0 else 0.0
    T = np.zeros((2, 2, 2, 2))
    for k in range(state.n_pairs):
        if not state.touching[k]:
            continue
        dx, dy = branch_vector(h, s, int(state.pair_i[k]), int(state.pair_j[k]))
        lvec = np.array([dx, dy])
        n = lvec / math.hypot(dx, dy)
        t = np.array([-n[1], n[0]])
        K = law[KN] * np.outer(n, n) + kt * np.outer(t, t)        # K_ik
        T += np.einsum("ik,j,m->ijkm", K, lvec, Fi @ lvec)
    return from_tensor4(T / area)


def perturbation_tangent(cell, eps=1e-5):
    """Consistent tangent by perturbation (CTO, 001 eq. 6) of any cell implementing the
    ``MicroCell`` interface: for each component, a copy of the cell is rolled back to its
    last committed state and solved to F + eps L^mn. ``cell`` must hold a solved state at F.
    Returns (C 4x4 d sigma/dF, list of solve results)."""
    F = cell.deformation_gradient()
    sig0 = cell.cauchy_stress()
    C = np.zeros((4, 4))
    results = []
    for c, (m, n) in enumerate(COMPONENTS):
        trial = cell.copy()
        trial.rollback()
        Fp = F.copy()
        Fp[m, n] += eps
        trial.set_deformation(Fp)
        results.append(trial.solve())
        C[:, c] = ((trial.cauchy_stress() - sig0) / eps).reshape(4)
    return C, results


def demqo_tangent(cell, eps=1e-6):
    """DEM-based quasi-static operator (DEMQO, 001 eq. 20): four perturbations eps L^mn from
    the current equilibrium with frozen, non-sliding contacts. ``cell`` must be a DemCell."""
    F = cell.deformation_gradient()
    sig0 = cell.cauchy_stress()
    C = np.zeros((4, 4))
    results = []
    for c, (m, n) in enumerate(COMPONENTS):
        trial = cell.copy()
        trial.freeze_contacts()
        Fp = F.copy()
        Fp[m, n] += eps
        trial.set_deformation(Fp)
        results.append(trial.solve())
        C[:, c] = ((trial.cauchy_stress() - sig0) / eps).reshape(4)
    return C, results
