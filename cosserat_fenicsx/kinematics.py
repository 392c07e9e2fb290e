"""Plane-strain micropolar kinematics: the one place where signs are fixed.

Convention (thesis 004, eqs 2.49 and 2.52; spec section 1), with (Grad u)_ij = du_i/dx_j
and phi the rotation about e3, positive counter-clockwise:

    strain      eps_ij = u_i,j + e_ij3 phi   ->  eps12 = u1,2 + phi,  eps21 = u2,1 - phi
    curvature   kappa_3j = phi,j             ->  kappa = grad(phi)  [1/m]

The moment-of-momentum coupling term follows from the same tensor: the virtual work of
the stress on a virtual rotation w is  sigma : (e_ij3 w) = (sigma12 - sigma21) w,  i.e. the
term -(I x sigma)_3 w of eq 3.5 with (I x sigma)_3 = sigma21 - sigma12. Writing the weak
form as  sigma : strain(v, w) + m . grad(w)  (eq 5.6) therefore carries the coupling
automatically and no other module repeats these signs.

A rigid rotation u = (-omega x2, omega x1) with phi = omega gives eps = 0 (pinned by
tests/test_kinematics.py).
"""
import ufl

# e_ij3: the 2D alternator, E3 = [[0, 1], [-1, 0]]
ALTERNATOR = ufl.as_matrix([[0.0, 1.0], [-1.0, 0.0]])

# Order of the generalized strain and stress vectors at a Gauss point (constitutive callback).
GRADIENT_NAMES = ("eps11", "eps22", "eps12", "eps21", "kappa31", "kappa32")
FLUX_NAMES = ("sigma11", "sigma22", "sigma12", "sigma21", "m31", "m32")


def strain(u, phi=None):
    """Non-symmetric micropolar strain (eq 2.49); classical sym(grad u) when phi is None."""
    if phi is None:
        return ufl.sym(ufl.grad(u))
    return ufl.grad(u) + phi * ALTERNATOR


def curvature(phi):
    """Curvature vector kappa_3j = phi,j (eq 2.52) [1/m]."""
    return ufl.grad(phi)


def gradient_vector(u, phi=None):
    """[eps11, eps22, eps12, eps21, kappa31, kappa32] as a UFL vector (callback order)."""
    eps = strain(u, phi)
    if phi is None:
        return ufl.as_vector([eps[0, 0], eps[1, 1], eps[0, 1], eps[1, 0], 0.0, 0.0])
    kappa = curvature(phi)
    return ufl.as_vector([eps[0, 0], eps[1, 1], eps[0, 1], eps[1, 0], kappa[0], kappa[1]])


def stress_tensor(flux):
    """2x2 stress from the callback flux vector."""
    return ufl.as_matrix([[flux[0], flux[2]], [flux[3], flux[1]]])


def couple_stress_vector(flux):
    return ufl.as_vector([flux[4], flux[5]])
