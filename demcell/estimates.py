"""Closed forms and estimates of the micropolar moduli of a DEM cell (numpy only).

Theory and conventions: docs/reference/micropolar_cell.md. 2D, per unit thickness, tension positive.
Isotropic micropolar law written in the FE callback order (cosserat_fenicsx/kinematics.py:
rows sigma11, sigma22, sigma12, sigma21, m31, m32; columns eps11, eps22, eps12, eps21,
kappa31, kappa32; eps = Grad u + e phi, thesis 004 eq 2.49):

    sigma11 = (lambda + 2G) eps11 + lambda eps22        sigma22 = lambda eps11 + (lambda + 2G) eps22
    sigma12 = (G + mu_c) eps12 + (G - mu_c) eps21       sigma21 = (G - mu_c) eps12 + (G + mu_c) eps21
    m31 = B kappa31                                     m32 = B kappa32

so sigma12 - sigma21 = 2 mu_c (eps12 - eps21) (the shear block of 003 eq 20 with G_c = mu_c).
Units: lambda, G, mu_c [N/m]; B [N m]; kn, ks [N/m]; kr [N m/rad].
"""
import math

import numpy as np

__all__ = ["hexagonal_moduli", "periodic_bending_estimate", "cosserat_moduli_003",
           "isotropic_operator", "uniform_strain_moduli"]

SQRT3 = math.sqrt(3.0)


def hexagonal_moduli(kn, ks, kr, radius, cell=None):
    """Moduli of the regular hexagonal packing of equal discs in contact, affine kinematics.

    Lattice: branch length l = 2R, 3 contacts and area A = 2 sqrt(3) R^2 per disc, contact
    directions n at 0, 60, 120 degrees, t = (-n2, n1).

    Derivation (no pre-stress; F, phi uniform, every disc rotating by phi): the relative
    displacement at a contact is l (eps . n), eps = Grad u + e phi (n . e n = 0 and
    t . e n = -1 turn the spec's d_ut = dd . t - l phi into l t . eps n). With fn = -kn l (n . eps n),
    fs = -ks l (t . eps n) and sigma = -(1/A) sum f (x) d:

        sigma_ij = (l^2 / A) sum_c [kn n_i n_j n_k n_l + ks t_i n_j t_k n_l] eps_kl.

    Over the three directions sum n n n n = (3/8)(d_ij d_kl + d_ik d_jl + d_il d_jk) (the
    hexagonal lattice is isotropic for 4th-order tensors) and t_i t_k = d_ik - n_i n_k, so with
    c = 3 l^2 / A = 2 sqrt(3):

        lambda = c (kn - ks)/8 = sqrt(3)/4 (kn - ks),   G = c (kn + ks)/8 = sqrt(3)/4 (kn + ks),
        G + mu_c = c (kn + 3 ks)/8  ->  mu_c = c ks/4 = sqrt(3)/2 ks.

    Exact for the lattice (Bravais, one disc per primitive cell): the affine state balances the
    forces on every disc by symmetry; the unbalanced contact moments, 3 a ks l (eps12 - eps21),
    the same on every disc, are exactly the uniform reaction couple of the held mean rotation.

    Bending: under kappa the rolling springs give mr = -kr kappa . D, hence
    m = (kr / A) sum_c D (x) D kappa = sqrt(3) kr kappa (sum_c D D = 6 R^2 I). With ks = 0 this
    is exact: the linear rotation field leaves the normal forces unchanged, and the two rolling
    moments of opposite neighbours cancel on every disc. With ks > 0 the linear field also
    slips every contact by l theta(contact point) (theta_i + theta_j^img = 2 theta(midpoint)),
    which adds 4 mu_c <(kappa . X)^2>_contacts / kappa^2: a cell-size-dependent term. This
    function returns B_affine = sqrt(3) kr + mu_c <X (x) X> * 4 (continuum average over the
    cell, <X (x) X> = h_ref h_ref^T / 12, accurate to O(R^2/L^2)) if ``cell`` is given, an UPPER
    BOUND of the relaxed (periodic-fluctuation) modulus; without ``cell`` it returns the rolling
    part sqrt(3) kr only, which is exact for ks = 0 and a lower bound otherwise
    (``bending_exact`` says which). See periodic_bending_estimate for the relaxed value.

    kn, ks [N/m], kr [N m/rad], radius R [m]; cell: None, a width L [m] (square cell) or h_ref
    (2x2, columns the periodicity vectors) [m].
    Returns dict(lambda_, G, mu_c, bending, bending_tensor, bending_exact, bulk);
    bending_tensor is the 2x2 B (m = B kappa), bending the mean of its diagonal.
    """
    kn, ks, kr, radius = float(kn), float(ks), float(kr), float(radius)
    if min(kn, ks, kr) < 0.0 or radius <= 0.0:
        raise ValueError("stiffnesses must be >= 0 and the radius > 0")
    lam = SQRT3 / 4.0 * (kn - ks)
    G = SQRT3 / 4.0 * (kn + ks)
    mu_c = SQRT3 / 2.0 * ks
    B = SQRT3 * kr * np.eye(2)
    exact = ks == 0.0
    if cell is not None:
        h = np.atleast_2d(np.asarray(cell, dtype=float))
        h = h[0, 0] * np.eye(2) if h.shape == (1, 1) else h
        if h.shape != (2, 2):
            raise ValueError("cell must be a width or a 2x2 matrix h_ref")
        B = B + 4.0 * mu_c * (h @ h.T) / 12.0
    return dict(lambda_=lam, G=G, mu_c=mu_c, bulk=lam + G,
                bending=0.5 * float(np.trace(B)), bending_tensor=B, bending_exact=exact)


def periodic_bending_estimate(B0, mu_c, G, width):
    """Bending modulus of a periodic micropolar cell of width L under uniform curvature.

    Continuum model of the cell (docs/reference/micropolar_cell.md, "Why the couple-stress moduli of a
    periodic cell depend on its size"): kappa along x1, fields depending on x1 only, rotation
    theta = kappa x1 + periodic, displacement fluctuation periodic. Force balance eliminates
    the displacement fluctuation and leaves the skew strain G theta / (G + mu_c), so

        B0 theta'' = 4 mu_eff theta,   mu_eff = mu_c G / (G + mu_c),   ell = sqrt(B0 / (4 mu_eff)),

    with theta(x + L) = theta(x) + kappa L: theta = kappa L sinh(x/ell) / (2 sinh(L / (2 ell)))
    on (-L/2, L/2), flat inside and steep near the cell boundary, and the energy gives

        B(L) = B0 (L / (2 ell)) coth(L / (2 ell))
             ~ B0 + mu_eff L^2 / 3   (L << ell; the affine estimate with mu_c -> mu_eff)
             ~ L sqrt(B0 mu_eff)     (L >> ell; grows linearly with L, no size-independent limit).

    B0 [N m] intrinsic (rolling) bending modulus, mu_c, G [N/m], width L [m]. mu_c = 0 gives
    B0. B0 = 0 with mu_c > 0 gives 0 in the continuum (a jump at no cost); the discrete cell
    then has a layer of about one grain instead (B ~ mu_c R L), outside this model.
    """
    B0, mu_c, G, L = float(B0), float(mu_c), float(G), float(width)
    if mu_c == 0.0 or G == 0.0:
        return B0
    mu_eff = mu_c * G / (G + mu_c)
    if B0 == 0.0:
        return 0.0
    z = L / (2.0 * math.sqrt(B0 / (4.0 * mu_eff)))
    return B0 * (1.0 + z * z / 3.0) if z < 1e-4 else B0 * z / math.tanh(z)


def cosserat_moduli_003(n_contacts, radius, volume, kn, ks, kr=0.0, k_omega=0.0, length=None):
    """Paper 003 (Li & Wan 2010, Chinese J. Theor. Appl. Mech. 42(5):889-900, in Chinese;
    docs/references.md) eqs 21-24, literally.

        G = N r^2 / (2V) (2 k_N + 3 k_s)                     (21)
        lambda = N r^2 / (2V) (k_N - k_s)                    (22)
        G_c = 2 N r^2 / (3V) k_s                             (23)
        l_c = sqrt(4 (2 L^2 k_s + r^2 k_r + k_omega) / (3 (k_N + k_s)))   (24)

    Symbols as read here: N = number of contacts in the RVE (n_contacts), r = particle radius,
    V = RVE volume, in 2D its area [m^2], L = RVE characteristic size [m] (length; required when
    ks > 0 or kr > 0 for l_c), k_N, k_s [N/m] normal and sliding stiffness, k_r [N/m] 003's
    TANGENTIAL ROLLING FORCE stiffness (Li & Chu's model; no counterpart in demcell: 0),
    k_omega [N m/rad] the rolling MOMENT stiffness = demcell's ContactLaw.kr.
    003 cites Eringen (1999) and Bardet & Vardoulakis (2001) for them and assumes a uniform
    strain (no fluctuation) and an isotropic fabric. Their origin (docs/reference/micropolar_cell.md):
    lambda is the 2D isotropic average exactly; G_c = N l^2 k_s / (6V) (l = 2r) is the 3D
    one (2/3 of the 2D N l^2 k_s / (4V)); in G the combination 2 k_N + 3 k_s is the 3D one
    while the prefactor N r^2 / (2V) is the 2D one; the L^2 k_s term of l_c is the affine
    rotation-field (cell-size) term, so l_c grows with L.

    Also returned: ``bending`` = G l_c^2, the couple-stress modulus read from eq 20 (its
    curvature entries are G, which with the usual vectors (.., l_c kappa) and (.., m / l_c)
    means m = G l_c^2 kappa; 003 does not spell the vectors out, so this reading is ours).
    """
    N, r, V = float(n_contacts), float(radius), float(volume)
    kn, ks, kr, kw = float(kn), float(ks), float(kr), float(k_omega)
    if V <= 0.0 or r <= 0.0 or N < 0.0:
        raise ValueError("volume and radius must be > 0, n_contacts >= 0")
    c = N * r * r / (2.0 * V)
    G = c * (2.0 * kn + 3.0 * ks)
    lam = c * (kn - ks)
    G_c = 2.0 * N * r * r / (3.0 * V) * ks
    if length is None:
        if ks != 0.0:
            raise ValueError("length (RVE size L) is needed for l_c when ks > 0")
        length = 0.0
    L = float(length)
    l_c = math.sqrt(4.0 * (2.0 * L * L * ks + r * r * kr + kw) / (3.0 * (kn + ks)))
    return dict(G=G, lambda_=lam, G_c=G_c, l_c=l_c, bending=G * l_c * l_c)


def _basis():
    """The four 6x6 matrices d C_iso / d (lambda, G, mu_c, B) in the FE callback order."""
    A = np.zeros((4, 6, 6))
    A[0, :2, :2] = 1.0                                    # lambda
    A[1, 0, 0] = A[1, 1, 1] = 2.0                         # G in the normal block
    A[1, 2:4, 2:4] = 1.0                                  # G (+) mu_c, G (-) mu_c
    A[2, 2, 2] = A[2, 3, 3] = 1.0
    A[2, 2, 3] = A[2, 3, 2] = -1.0                        # mu_c
    A[3, 4, 4] = A[3, 5, 5] = 1.0                         # B
    return A


def isotropic_operator(lambda_, G, mu_c, bending):
    """6x6 isotropic micropolar operator in the FE callback order (module docstring)."""
    return np.tensordot(np.array([lambda_, G, mu_c, bending], dtype=float), _basis(), axes=1)


def uniform_strain_moduli(C6):
    """Isotropic moduli read off a 6x6 operator (e.g. a measured micropolar cell tangent).

    Least squares on the isotropic form, block by block (the stress-strain block, rows/cols
    0-3, gives lambda, G, mu_c; the couple block, rows/cols 4-5, gives B, so the mixed units
    do not weight each other). Returns dict(lambda_, G, mu_c, bending, residual_stress,
    residual_couple, coupling, residual):
    residual_stress = |C_ss - C_iso,ss|_F / |C_ss|_F, residual_couple likewise for the
    2x2 couple block, coupling = |C_sk| + |C_ks| over sqrt(|C_ss| |C_kk|) (the off-diagonal
    blocks, zero for an isotropic 2D operator: there is no isotropic 3rd-order 2D tensor;
    dimensionless since [N/m] [N m] = [N]^2), residual = the largest of the three: the
    relative anisotropy residual.
    """
    C = np.asarray(C6, dtype=float)
    if C.shape != (6, 6) or not np.all(np.isfinite(C)):
        raise ValueError("C6 must be a finite 6x6 array")
    A = _basis()
    ss = A[:3, :4, :4].reshape(3, -1).T
    lam, G, mu_c = np.linalg.lstsq(ss, C[:4, :4].ravel(), rcond=None)[0]
    B = 0.5 * (C[4, 4] + C[5, 5])
    Ciso = isotropic_operator(lam, G, mu_c, B)

    def rel(a, b):
        n = np.linalg.norm(a)
        return float(np.linalg.norm(a - b) / n) if n > 0 else 0.0

    r_s = rel(C[:4, :4], Ciso[:4, :4])
    r_k = rel(C[4:, 4:], Ciso[4:, 4:])
    scale = math.sqrt(np.linalg.norm(C[:4, :4]) * np.linalg.norm(C[4:, 4:]))
    off = np.linalg.norm(C[:4, 4:]) + np.linalg.norm(C[4:, :4])
    coupling = float(off / scale) if scale > 0 else (0.0 if off == 0 else math.inf)
    return dict(lambda_=float(lam), G=float(G), mu_c=float(mu_c), bending=float(B),
                residual_stress=r_s, residual_couple=r_k, coupling=coupling,
                residual=max(r_s, r_k, coupling))
