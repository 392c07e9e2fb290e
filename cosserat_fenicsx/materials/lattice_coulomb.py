"""Coulomb sliding and opening of the 45-degree square disc lattice (003's packings A and B)
as a Gauss-point material: the affine lattice of lattice_elasticity.py whose two contact
families slide at the friction limit and open in tension, as the grains' contacts do.

In the lattice frame (contact normals e1', e2' at +-45 degrees to the horizontal) the force
stress of an affine Cosserat strain eps' = R^T eps R (R = [e1' e2']) is carried by the two
families separately (lattice_elasticity.py; per unit depth):

    family 1 (normal e1'):  normal sigma'_11 = k_N min(eps'_11, 0)       (no tension: open)
                            tangential sigma'_21 = t_1
    family 2 (normal e2'):  normal sigma'_22 = k_N min(eps'_22, 0),  tangential sigma'_12 = t_2

    t_k = clip(t_k,old + k_S (eps'_t - eps'_t,old), -mu |sigma'_kk|, mu |sigma'_kk|)   (closed)
    t_k = 0                                                                             (open)

(eps'_t: eps'_21 for family 1, eps'_12 for family 2), a return to the Coulomb limit of the
contact law (003 Table 1, demcell's contacts) family by family; sigma = R sigma' R^T. The
reference state is the lattice touching without force. The couple stress is elastic,
m = B kappa with B the bending modulus. History per point: t_1, t_2 and the strains
eps'_21, eps'_12 they were last updated at. The tangent is the consistent one of this
return (rows: sticking k_S, sliding mu k_N sign(t), open 0).

What it leaves out: rolling without sliding (the rotation's only resistance is the elastic
skew part and the couple stress), contacts that close again at another place, and every
non-affine motion of the grains (their rearrangement in a band).
"""
import math

import numpy as np

from ..constitutive import Constitutive
from ..validation import NON_NEGATIVE, POSITIVE, check


def lattice_frame_maps(angle):
    """(P, Q) 4x4: eps'_vec = P eps_vec and sigma_vec = Q sigma'_vec, vec order (11, 22, 12, 21)."""
    c, s = math.cos(angle), math.sin(angle)
    rotation = np.array([[c, -s], [s, c]])          # columns e1', e2'
    index = ((0, 0), (1, 1), (0, 1), (1, 0))
    p = np.zeros((4, 4))
    q = np.zeros((4, 4))
    for col, (k, l) in enumerate(index):
        unit = np.zeros((2, 2))
        unit[k, l] = 1.0
        into = rotation.T @ unit @ rotation
        back = rotation @ unit @ rotation.T
        for row, (i, j) in enumerate(index):
            p[row, col] = into[i, j]
            q[row, col] = back[i, j]
    return p, q


class LatticeCoulombMaterial(Constitutive):
    """The module docstring's law. k_n, k_s [N/m per m of depth]; friction mu [-];
    bending_modulus B [N] (m = B kappa); angle of e1' to the horizontal [rad] (pi/4)."""
    state_names = ("t1", "t2", "eps21_lattice", "eps12_lattice")
    rate_independent = True

    def __init__(self, k_n, k_s, friction, bending_modulus=0.0, angle=math.pi / 4):
        self.k_n = check("k_n", k_n, POSITIVE)
        self.k_s = check("k_s", k_s, POSITIVE)
        self.friction = check("friction", friction, NON_NEGATIVE)
        self.bending_modulus = check("bending_modulus", bending_modulus, NON_NEGATIVE)
        self.angle = check("angle", angle)
        self._into, self._back = lattice_frame_maps(self.angle)

    def update(self, gradients, dt, state_old, flux_out, tangent_out, state_new, points=None):
        rows = slice(None) if points is None else points
        g = gradients[rows]
        old = state_old[rows]
        e = g[:, :4] @ self._into.T                       # eps'_11, eps'_22, eps'_12, eps'_21
        kn, ks, mu = self.k_n, self.k_s, self.friction
        closed = e[:, :2] < 0.0                            # families 1, 2
        normal = np.where(closed, kn * e[:, :2], 0.0)      # sigma'_11, sigma'_22
        # tangential: family 1 along eps'_21, family 2 along eps'_12
        strain_t = np.column_stack([e[:, 3], e[:, 2]])
        trial = old[:, :2] + ks * (strain_t - old[:, 2:4])
        limit = mu * np.abs(normal)
        sliding = closed & (np.abs(trial) > limit)
        t = np.where(closed, np.clip(trial, -limit, limit), 0.0)
        stress_lattice = np.column_stack([normal[:, 0], normal[:, 1], t[:, 1], t[:, 0]])
        flux = np.empty((g.shape[0], 6))
        flux[:, :4] = stress_lattice @ self._back.T
        flux[:, 4:6] = self.bending_modulus * g[:, 4:6]
        flux_out[rows] = flux
        state_new[rows] = np.column_stack([t, strain_t])
        # consistent tangent in the lattice frame, rows/cols (11, 22, 12, 21)
        d = np.zeros((g.shape[0], 4, 4))
        d[:, 0, 0] = np.where(closed[:, 0], kn, 0.0)
        d[:, 1, 1] = np.where(closed[:, 1], kn, 0.0)
        stick = closed & ~sliding
        sign = np.sign(t)
        # family 1: t_1 = sigma'_21 (row 3) from eps'_21 (col 3) or, sliding, from eps'_11 (col 0)
        d[:, 3, 3] = np.where(stick[:, 0], ks, 0.0)
        d[:, 3, 0] = np.where(sliding[:, 0], -mu * kn * sign[:, 0], 0.0)
        # family 2: t_2 = sigma'_12 (row 2) from eps'_12 (col 2) or, sliding, from eps'_22 (col 1)
        d[:, 2, 2] = np.where(stick[:, 1], ks, 0.0)
        d[:, 2, 1] = np.where(sliding[:, 1], -mu * kn * sign[:, 1], 0.0)
        tangent = np.zeros((g.shape[0], 6, 6))
        tangent[:, :4, :4] = self._back @ d @ self._into
        tangent[:, 4, 4] = tangent[:, 5, 5] = self.bending_modulus
        tangent_out[rows] = tangent

    def describe(self):
        return {"material": "lattice Coulomb", "k_n": self.k_n, "k_s": self.k_s, "friction": self.friction,
                "bending_modulus": self.bending_modulus, "angle": self.angle}
