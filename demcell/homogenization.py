"""Homogenized (macroscopic) quantities of a periodic cell.

Sign convention: tension positive (as on the FE side). Index conventions: traction
t_i = sigma_ij n_j; couple stress mu_3j with couple traction m_3 = mu_3j n_j.

* Cauchy stress (001 eq. 8): sigma = 1/|Y| sum_c f^{j->i} (x) (x_j - x_i), f^{j->i} the force
  that particle j applies on particle i, |Y| = det h the cell area.
* First Piola-Kirchhoff stress P = J sigma F^-T (000 eq. 16 read backwards; equals 000 eq. 14
  for a periodic cell at equilibrium).
* Couple stress (004 chapter 7, eq. 7.38; ``../spec/ehlers-micropolar.md`` section 9):
  mu_3l = 1/|Y| sum_boundary m^(i) x_l^(i). Written as a sum over contacts exactly as the
  Cauchy stress is (the internal sum over particles vanishes at equilibrium):
  mu_3l = -1/|Y| sum_c [ M_i^c x_i,l + M_j^c (x_i + d^c)_l ], with M^c the moment of contact c
  about each centre (tangential force times lever arm, plus the rolling moment) and x_i
  measured from the cell centre. At equilibrium it is independent of that origin. For a
  cell under a homogeneous F (no imposed curvature) it is a fluctuation around zero.
  In a micropolar cell (docs/reference/micropolar_cell.md) the positions are the reference lever
  positions X = h_ref (s - c) and branch vectors D = h_ref (s_j - s_i + n), of the copy of
  each contact whose contact point lies in the cell: the couple stress
  is then the work conjugate of the imposed curvature, m = (1/|Y|) dW/dkappa (Hill-Mandel),
  and the Cauchy stress is not symmetric: |Y| (sigma12 - sigma21) = sum_c fs_c |d_c|, the
  reaction of the held mean rotation.
* Fabric tensor (000 eq. 39): Phi = 1/(2C) sum_p sum_c n_pc (x) n_pc = 1/C sum_c n_c (x) n_c;
  anisotropy (000 eq. 38): A = Phi_1 / Phi_2 - 1 with Phi_1 >= Phi_2 the eigenvalues.
* Coordination number n = 2C / N (000 section 4.1) and the mechanical coordination number
  excluding rattlers (particles with fewer than 2 contacts).
"""
import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from . import checks
from .checks import Range
from .contact_law import ContactLaw
from .slots import KN, KR, KS, MU, N_LAW
from .periodic_cell import branch_vector, cauchy_to_pk1, contact_copy, fractional_branch


@njit(cache=True)
def contact_sums(h, s, radius, pair_i, pair_j, fn, fs, mr, touching, n_pairs, mu, h_ref, micropolar):
    """Per-cell sums over the touching pairs. Returns (sigma (2,2) [N/m], couple (2,) [N],
    fabric (2,2) [-], n_contacts, n_sliding, contacts per particle (N,)). The couple stress
    takes its lever positions from h (s - c), or for a micropolar cell from h_ref (s - c) of the
    copy of the contact whose contact point lies in the cell (relaxation.compute_forces)."""
    area = abs(h[0, 0] * h[1, 1] - h[0, 1] * h[1, 0])
    sigma = np.zeros((2, 2))
    couple = np.zeros(2)
    fabric = np.zeros((2, 2))
    z = np.zeros(radius.shape[0], np.int64)
    nc = 0
    nsl = 0
    for k in range(n_pairs):
        if touching[k] == 0:
            continue
        i = pair_i[k]
        j = pair_j[k]
        dx, dy = branch_vector(h, s, i, j)
        dist = math.sqrt(dx * dx + dy * dy)
        nx = dx / dist
        ny = dy / dist
        tx = -ny
        ty = nx
        fjx = fn[k] * nx + fs[k] * tx
        fjy = fn[k] * ny + fs[k] * ty
        sigma[0, 0] -= fjx * dx
        sigma[0, 1] -= fjx * dy
        sigma[1, 0] -= fjy * dx
        sigma[1, 1] -= fjy * dy
        overlap = radius[i] + radius[j] - dist
        mi = -(radius[i] - 0.5 * overlap) * fs[k] - mr[k]
        mj = -(radius[j] - 0.5 * overlap) * fs[k] + mr[k]
        if micropolar:
            a, b = fractional_branch(s, i, j)
            m_a, m_b = contact_copy(s, i, a, b, (radius[i] - 0.5 * overlap) / dist)
            si0 = s[i, 0] - m_a - 0.5
            si1 = s[i, 1] - m_b - 0.5
            xi0 = h_ref[0, 0] * si0 + h_ref[0, 1] * si1
            xi1 = h_ref[1, 0] * si0 + h_ref[1, 1] * si1
            lx = h_ref[0, 0] * a + h_ref[0, 1] * b
            ly = h_ref[1, 0] * a + h_ref[1, 1] * b
        else:
            xi0 = h[0, 0] * (s[i, 0] - 0.5) + h[0, 1] * (s[i, 1] - 0.5)
            xi1 = h[1, 0] * (s[i, 0] - 0.5) + h[1, 1] * (s[i, 1] - 0.5)
            lx = dx
            ly = dy
        couple[0] -= mi * xi0 + mj * (xi0 + lx)
        couple[1] -= mi * xi1 + mj * (xi1 + ly)
        fabric[0, 0] += nx * nx
        fabric[0, 1] += nx * ny
        fabric[1, 1] += ny * ny
        nc += 1
        z[i] += 1
        z[j] += 1
        if fn[k] > 0.0 and abs(fs[k]) >= (1.0 - 1e-9) * mu * fn[k]:
            nsl += 1
    fabric[1, 0] = fabric[0, 1]
    if nc > 0:
        fabric /= nc
    return sigma / area, couple / area, fabric, nc, nsl, z


@njit(cache=True)
def mechanical_contacts(pair_i, pair_j, touching, n_pairs, z):
    """Contacts between two particles that each have at least 2 contacts (z: contacts per
    particle), the C' of the mechanical coordination number (rattlers excluded)."""
    count = 0
    for k in range(n_pairs):
        if touching[k] and z[pair_i[k]] >= 2 and z[pair_j[k]] >= 2:
            count += 1
    return count


@dataclass
class Homogenized:
    """Macroscopic response of one cell (tension positive, 2D per unit thickness).

    cauchy [N/m] (2,2); pk1 [N/m] (2,2); couple_stress [N] (mu_31, mu_32);
    fabric [-] (2,2); anisotropy [-] (000 eq. 38); coordination_number 2C/N;
    mechanical_coordination_number 2C'/N' without rattlers; sliding_fraction [-];
    n_contacts; kinetic_energy, potential_energy [J per m]; solid_fraction [-];
    area [m^2 per m]; F (2,2); no_contacts: True when the cell has lost every contact.
    """
    cauchy: np.ndarray
    pk1: np.ndarray
    couple_stress: np.ndarray
    fabric: np.ndarray
    anisotropy: float
    coordination_number: float
    mechanical_coordination_number: float
    sliding_fraction: float
    n_contacts: int
    kinetic_energy: float
    potential_energy: float
    solid_fraction: float
    area: float
    F: np.ndarray
    no_contacts: bool

    @property
    def pressure(self):
        """p = -tr(sigma)/2 [N/m] (compression positive, for reading convenience)."""
        return -0.5 * float(np.trace(self.cauchy))

    @property
    def stress_ratio(self):
        """|s11 - s22| / |s11 + s22| (000 eq. 40); 0 for a stress-free cell."""
        s = self.cauchy
        den = abs(s[0, 0] + s[1, 1])
        return abs(s[0, 0] - s[1, 1]) / den if den > 0.0 else 0.0


def anisotropy(fabric):
    """A = Phi_1 / Phi_2 - 1 (000 eq. 38); 0 when the fabric is empty."""
    w = np.linalg.eigvalsh(fabric)
    return float(w[1] / w[0] - 1.0) if w[0] > 0.0 else 0.0


def homogenize(state, law, micropolar=False):
    """All homogenized outputs of ``state`` (its forces must be current); ``micropolar``: the
    couple stress of a micropolar cell (reference lever positions). ``law``: a ContactLaw
    or its kernel array (DemCell.law_array)."""
    from .state import CellState
    checks.instance("state", state, CellState)
    if isinstance(law, ContactLaw):
        law = law.as_array()
    law = checks.array("law", law, (N_LAW,), Range(0.0, infinite=True))
    sig, couple, fab, nc, nsl, z = contact_sums(state.h, state.s, state.radius, state.pair_i,
                                                state.pair_j, state.fn, state.fs, state.mr,
                                                state.touching, state.n_pairs, float(law[MU]),
                                                state.h_ref, micropolar)
    F = state.F
    area = abs(np.linalg.det(state.h))
    active = z >= 2
    c_mech = mechanical_contacts(state.pair_i, state.pair_j, state.touching, state.n_pairs, z) if nc else 0
    ekin = 0.5 * float(np.sum(state.mass * np.sum(state.v ** 2, axis=1))
                       + np.sum(state.inertia * state.omega ** 2))
    epot = 0.0
    if nc:
        sel = state.touching[:state.n_pairs] == 1
        fnk = state.fn[:state.n_pairs][sel]
        epot = 0.5 * float(np.sum(fnk ** 2)) / law[KN]
        if law[KS] > 0:
            epot += 0.5 * float(np.sum(state.fs[:state.n_pairs][sel] ** 2)) / law[KS]
        if law[KR] > 0:
            epot += 0.5 * float(np.sum(state.mr[:state.n_pairs][sel] ** 2)) / law[KR]
    return Homogenized(cauchy=sig, pk1=cauchy_to_pk1(sig, F), couple_stress=couple, fabric=fab,
                       anisotropy=anisotropy(fab), coordination_number=2.0 * nc / state.n_particles,
                       mechanical_coordination_number=(2.0 * c_mech / max(1, int(active.sum()))),
                       sliding_fraction=nsl / nc if nc else 0.0, n_contacts=int(nc),
                       kinetic_energy=ekin, potential_energy=epot,
                       solid_fraction=float(np.sum(np.pi * state.radius ** 2)) / area, area=area,
                       F=F, no_contacts=(nc == 0))
