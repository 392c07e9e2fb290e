"""How the six gradients of a Gauss point drive a cell, and how the cell's answer becomes the
six fluxes and the 6x6 tangent of a Gauss point (`kinematics.GRADIENT_NAMES`, `FLUX_NAMES`).

The macro balance is geometrically linear (as for the Ehlers scenes): the strain is
eps = Grad u + e phi (2.49) and the cell is driven by F = I + sym(eps) (001 eq. 7 with the
symmetric part of Grad u; on a Cauchy scene eps is sym Grad u already). The rotation part is
left out on purpose: with linear kinematics, I + Grad u with a skew part W is not a rotation
but a rotation plus a stretch by sqrt(1 + w^2), which in a shear band (w ~ 0.1-0.3) would
dilate the cell by w^2 / 2 (0.5-5 %) for nothing; at small strain a rigid rotation must not
change the stress.

Cell tensors use demcell's order (11, 12, 21, 22) (001 eq. 11): C[r, c] = d sigma_r / d F_c.
In the Gauss-point order sigma11 -> 0, sigma22 -> 1, sigma12 -> 2, sigma21 -> 3, and the same
for eps (F_kl - delta_kl -> eps_kl).

Three modes, one object each, all with the same methods (`deformation`, `increment`,
`drive`, `fluxes`, `tangent`), so the material never needs to know which one it holds:

* `ClassicalMode`: a Cauchy scene (000, 001). sigma = the cell's Cauchy stress (001 eq. 8),
  no couple stress.
* `HybridMode`: the cell gives the symmetric stress; the skew stress 2 mu_c skw(eps) and the
  couple stress m = 2 mu_c l_c^2 kappa (eq. 2.74) are elastic.
* `MicropolarMode`: every flux from a cell that carries rotation and curvature itself
  (driven by F = I + eps, rotation 0, curvature kappa: at small strain the same as
  F = I + Grad u with the rotation phi, rotated by -phi). It needs a cell with
  `micropolar = True` (demcell rotation_mode='micropolar') answering
  `set_deformation(F, rotation=, curvature=)`, a non-symmetric Cauchy stress, a couple
  stress and `tangent(kind, measure="micropolar")` (6x6 in the Gauss-point order); curvature
  and couple stress are converted between the cell's length unit and the specimen's.
"""
import numpy as np

#: position of demcell's components (11, 12, 21, 22) in the Gauss-point flux / gradient order
CELL_TO_CALLBACK = np.array([0, 2, 3, 1])
#: symmetric part of a tensor in demcell's order: P @ t = sym(t)
SYMMETRISER = np.array([[1.0, 0.0, 0.0, 0.0],
                        [0.0, 0.5, 0.5, 0.0],
                        [0.0, 0.5, 0.5, 0.0],
                        [0.0, 0.0, 0.0, 1.0]])


def deformation_gradient(gradients, symmetric=True):
    """F = I + (sym) eps from one row [eps11, eps22, eps12, eps21, ...]."""
    e11, e22, e12, e21 = gradients[0], gradients[1], gradients[2], gradients[3]
    if symmetric:
        e12 = e21 = 0.5 * (e12 + e21)
    return np.array([[1.0 + e11, e12], [e21, 1.0 + e22]])


def deformation_gradients(gradients, symmetric=True):
    """deformation_gradient of many rows at once, (n, 2, 2) (the same arithmetic)."""
    g = np.asarray(gradients, dtype=float)
    e12, e21 = g[:, 2], g[:, 3]
    if symmetric:
        e12 = e21 = 0.5 * (e12 + e21)
    F = np.empty((len(g), 2, 2))
    F[:, 0, 0], F[:, 0, 1], F[:, 1, 0], F[:, 1, 1] = 1.0 + g[:, 0], e12, e21, 1.0 + g[:, 1]
    return F


def place_cell_tangent(C, out):
    """Write a 4x4 demcell tangent into the 6x6 Gauss-point block (zeros elsewhere)."""
    out[:] = 0.0
    out[np.ix_(CELL_TO_CALLBACK, CELL_TO_CALLBACK)] = C


class _SymmetricDrive:
    """A cell of force stress only, driven by F = I + sym(eps)."""

    def deformation(self, gradients):
        return deformation_gradient(gradients)

    def drive(self, cell, gradients):
        cell.set_deformation(self.deformation(gradients))

    def targets(self, gradients):
        """(F (n, 2, 2), phi, kappa) of many points (None: a cell without rotation or curvature)."""
        return deformation_gradients(gradients), None, None

    def increment(self, cell, gradients):
        """Largest change of a component of F from the cell's committed state."""
        return float(np.abs(self.deformation(gradients) - cell.deformation_gradient()).max())


class ClassicalMode(_SymmetricDrive):
    """Cauchy continuum: the cell gives the whole stress (000, 001)."""
    name = "classical"
    micropolar_scene = False

    def fluxes(self, homogenized, gradients, out):
        self.fluxes_many(homogenized.cauchy[None], homogenized.couple_stress[None], gradients[None], out[None])

    def fluxes_many(self, cauchy, couple_stress, gradients, out):
        """fluxes of many points: cauchy (n, 2, 2), couple_stress (n, 2), gradients and out (n, 6)."""
        out[:, 0], out[:, 1], out[:, 2], out[:, 3] = cauchy[:, 0, 0], cauchy[:, 1, 1], cauchy[:, 0, 1], cauchy[:, 1, 0]
        out[:, 4:] = 0.0

    def tangent(self, cell, gradients, kind, out):
        self.place(cell.tangent(kind), out)

    def place(self, C, out):
        """The 6x6 block of a cell's 4x4 d sigma / d F."""
        # the Cauchy scene passes eps12 = eps21 (sym Grad u), so the Jacobian's contraction
        # with [.., de12, de12, ..] adds both columns: exactly d sigma(I + sym Grad u)
        place_cell_tangent(C, out)

    def describe(self):
        return {"mode": self.name}


class HybridMode(_SymmetricDrive):
    """The cell gives the symmetric stress; skew and couple stress are elastic (eq. 2.74):

        sigma = sym(sigma_cell(I + sym eps)) + 2 mu_c skw(eps),   m = 2 mu_c l_c^2 kappa

    mu_c [stress unit of the cell] > 0, l_c [m] >= 0 (l_c = 0: no couple stress; the
    rotation then follows the material rotation pointwise)."""
    name = "hybrid"
    micropolar_scene = True

    def __init__(self, mu_c, l_c):
        mu_c, l_c = float(mu_c), float(l_c)
        if not (np.isfinite(mu_c) and mu_c > 0.0):
            raise ValueError(f"hybrid mode: mu_c must be a positive number, got {mu_c!r} "
                             "(mu_c = 0 leaves the rotation undetermined)")
        if not (np.isfinite(l_c) and l_c >= 0.0):
            raise ValueError(f"hybrid mode: l_c must be a number >= 0, got {l_c!r}")
        self.mu_c, self.l_c = mu_c, l_c
        self.bending_modulus = 2.0 * mu_c * l_c ** 2
        skew = np.zeros((4, 4))
        skew[1, 1] = skew[2, 2] = mu_c
        skew[1, 2] = skew[2, 1] = -mu_c
        self._skew = skew

    def fluxes(self, homogenized, gradients, out):
        self.fluxes_many(homogenized.cauchy[None], homogenized.couple_stress[None], gradients[None], out[None])

    def fluxes_many(self, cauchy, couple_stress, gradients, out):
        s = cauchy
        tau = 0.5 * (s[:, 0, 1] + s[:, 1, 0])
        skw = self.mu_c * (gradients[:, 2] - gradients[:, 3])     # 2 mu_c skw(eps)_12
        b = self.bending_modulus
        out[:, 0], out[:, 1], out[:, 2], out[:, 3] = s[:, 0, 0], s[:, 1, 1], tau + skw, tau - skw
        out[:, 4], out[:, 5] = b * gradients[:, 4], b * gradients[:, 5]

    def tangent(self, cell, gradients, kind, out):
        self.place(cell.tangent(kind), out)

    def place(self, C, out):
        """The 6x6 block of a cell's 4x4 d sigma / d F."""
        C = SYMMETRISER @ C @ SYMMETRISER + self._skew
        place_cell_tangent(C, out)
        out[4, 4] = out[5, 5] = self.bending_modulus

    def describe(self):
        return {"mode": self.name, "mu_c": self.mu_c, "l_c": self.l_c,
                "bending_modulus": self.bending_modulus}


class MicropolarMode:
    """Every flux from a micropolar cell (rotation and curvature imposed on the grains; demcell
    rotation_mode='micropolar', docs/reference/micropolar_cell.md).

    The cell is driven by F = I + eps (eps = Grad u + e phi, 2.49, not symmetrised), rotation 0
    and curvature kappa: at small strain the cell at (I + Grad u, phi) seen in axes turned by
    -phi, so the skew part of eps (the rotation of the material relative to the grains) is what
    loads the contacts.

    Units. The cell has its own length unit (cells.py): its force stress does not depend on it,
    its curvature and couple stress do. `length_scale` [m per cell length unit] =
    (grain diameter in the specimen [m]) / (mean grain diameter of the cell in its units):
        kappa_cell = length_scale kappa        [1/cell unit] from [1/m]
        m          = length_scale m_cell       [N] from [N/m x cell unit]
    so in the 6x6 tangent d sigma/d kappa and d m/d eps carry one factor length_scale and
    d m/d kappa two."""
    name = "micropolar"
    micropolar_scene = True

    def __init__(self, length_scale=1.0):
        length_scale = float(length_scale)
        if not (np.isfinite(length_scale) and length_scale > 0.0):
            raise ValueError(f"micropolar mode: length_scale must be a positive number, got {length_scale!r}")
        self.length_scale = length_scale
        # rows (sigma11, sigma22, sigma12, sigma21, m31, m32), cols (eps.., kappa31, kappa32)
        scale = np.ones(6)
        scale[4:] = length_scale
        self._scale = np.outer(scale, scale)
        self.moduli = None      # set by describe_cell (cells.micropolar_moduli)

    def deformation(self, gradients):
        return deformation_gradient(gradients, symmetric=False)

    def curvature(self, gradients):
        """kappa of the cell [1/cell unit] from the macro kappa [1/m]."""
        return self.length_scale * np.array([gradients[4], gradients[5]], dtype=float)

    def increment(self, cell, gradients):
        """Size of the jump from the cell's committed state, measured like a strain: the
        largest change of a component of F and the largest change of the rotation jump across
        the cell |dkappa_cell . Y_k| (Y_k the periodicity vectors): that is the relative
        rotation the curvature imposes on the grains at opposite sides of the cell."""
        jump = float(np.abs(self.deformation(gradients) - cell.deformation_gradient()).max())
        return max(jump, cell.rotation_increment(0.0, self.curvature(gradients)))

    def drive(self, cell, gradients):
        cell.set_deformation(self.deformation(gradients), rotation=0.0, curvature=self.curvature(gradients))

    def targets(self, gradients):
        """(F (n, 2, 2), phi (n,), kappa (n, 2) of the cells) of many points."""
        g = np.asarray(gradients, dtype=float)
        return deformation_gradients(g, symmetric=False), np.zeros(len(g)), self.length_scale * g[:, 4:6]

    def fluxes(self, homogenized, gradients, out):
        self.fluxes_many(homogenized.cauchy[None], homogenized.couple_stress[None], gradients[None], out[None])

    def fluxes_many(self, cauchy, couple_stress, gradients, out):
        L = self.length_scale
        out[:, 0], out[:, 1], out[:, 2], out[:, 3] = cauchy[:, 0, 0], cauchy[:, 1, 1], cauchy[:, 0, 1], cauchy[:, 1, 0]
        out[:, 4], out[:, 5] = L * couple_stress[:, 0], L * couple_stress[:, 1]

    def tangent(self, cell, gradients, kind, out):
        self.place(cell.tangent(kind, measure="micropolar"), out)

    def place(self, C, out):
        """The 6x6 block of the cell's micropolar operator (Gauss-point order, cell units)."""
        out[:] = self._scale * C

    def describe(self):
        d = {"mode": self.name, "length_scale": self.length_scale}
        if self.moduli is not None:
            d.update(self.moduli)
        return d


MODES = ("classical", "hybrid", "micropolar")


def make_mode(name, mu_c=None, l_c=None, length_scale=1.0):
    """The mode object of `name`; hybrid needs mu_c and l_c, micropolar the length scale of
    the cell (MicropolarMode)."""
    if name == "classical":
        return ClassicalMode()
    if name == "hybrid":
        return HybridMode(mu_c, l_c)
    if name == "micropolar":
        return MicropolarMode(length_scale)
    raise ValueError(f"unknown FEM x DEM mode {name!r}: one of {', '.join(MODES)}")
