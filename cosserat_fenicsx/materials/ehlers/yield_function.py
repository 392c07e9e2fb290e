"""Single-surface yield function (2.76)/(2.77) and plastic potential (2.78).

Micropolar extension of Ehlers' surface (Scholz 2007, section 2.4.4)::

    F   = sqrt(Phi_F) + beta I + I^2/epsilon - kappa                       (2.76)
    Phi_F = Gamma II^D + k_sigma II_skw + k_mu m.m + alpha/2 I^2 + I^4/delta^2
    Gamma = (1 + gamma theta)^m,  theta = III^D / (II^D)^(3/2),  m = 2/9 + sqrt(3)/(3 gamma)  (2.77)
    G   = sqrt(Phi_G) + psi2 beta I + I^2/epsilon                           (2.78)
    Phi_G = psi1 II^D + k_sigma II_skw + k_mu m.m + alpha/2 I^2 + I^4/delta^2

Invariants (spec 4.1): I = tr sigma, S = dev sym sigma, II^D = 1/2 S.S >= 0,
III^D = det S, II_skw = 1/2 sigma_skw.sigma_skw = 1/4 (sig12 - sig21)^2 >= 0.
m uses the *current* gamma (spec 4.2 [REC]).  Generalised vector order as in
elasticity.py; stresses in MPa, couple stresses in MPa m.

Derivatives w.r.t. the generalised vector: the entries for sig12 and sig21 of
d(II^D)/dsigma are both S_12 (= (sig12 + sig21)/2) and those of d(II_skw)/dsigma
are +-(sig12 - sig21)/2, which is the tensor derivative restricted to plane
components (spec 4.3).
"""

import math

from numba import njit

from .parameters import P_ALPHA, P_K_MU, P_K_SIGMA, P_KAPPA, P_PSI1, P_PSI2

#: max |theta| = 2/(3 sqrt 3) (triaxial compression/extension)
THETA_MAX = 2.0 / (3.0 * math.sqrt(3.0))
SQRT3_3 = math.sqrt(3.0) / 3.0


@njit(cache=True, error_model="numpy")
def invariants(S):
    """Return (I, s11, s22, s33, s12, a12, II_D, III_D, II_skw, m.m) of generalised stress S."""
    I = S[0] + S[1] + S[2]
    mean = I / 3.0
    s0 = S[0] - mean
    s1 = S[1] - mean
    s2 = S[2] - mean
    s3 = 0.5 * (S[3] + S[4])
    a = 0.5 * (S[3] - S[4])
    II = 0.5 * (s0 * s0 + s1 * s1 + s2 * s2) + s3 * s3
    III = s2 * (s0 * s1 - s3 * s3)
    return I, s0, s1, s2, s3, a, II, III, a * a, S[5] * S[5] + S[6] * S[6]


@njit(cache=True, error_model="numpy")
def lode_factor(II, III, gamma):
    """Gamma = (1 + gamma theta)^m and theta, m, with the II^D -> 0 guard (spec 5, hazards).

    theta is 0/0 on the hydrostatic axis; Gamma II^D -> 0 continuously there, so
    theta := 0 when II^D is negligible.  theta is clipped to its admissible range
    against round-off.
    """
    m = 2.0 / 9.0 + SQRT3_3 / gamma
    if II > 1e-28:
        theta = III / (II * math.sqrt(II))
        if theta > THETA_MAX:
            theta = THETA_MAX
        elif theta < -THETA_MAX:
            theta = -THETA_MAX
    else:
        theta = 0.0
    base = 1.0 + gamma * theta
    return base ** m, theta, m, base


@njit(cache=True, error_model="numpy")
def yield_function(S, beta, delta, eps, gamma, params):
    """F of (2.76) [MPa] at generalised stress S and hardening state (beta, delta, eps, gamma)."""
    I, s0, s1, s2, s3, a, II, III, IIskw, mm = invariants(S)
    Gam, theta, m, base = lode_factor(II, III, gamma)
    phi = (Gam * II + params[P_K_SIGMA] * IIskw + params[P_K_MU] * mm
           + 0.5 * params[P_ALPHA] * I * I + I ** 4 / (delta * delta))
    if phi < 0.0:
        phi = 0.0
    return math.sqrt(phi) + beta * I + I * I / eps - params[P_KAPPA]


@njit(cache=True, error_model="numpy")
def yield_function_gradient(S, beta, delta, eps, gamma, params, dF):
    """F (2.76) and its first derivatives (spec 4.3).

    Writes dF/dS into dF (7).  Returns (F, dF/dbeta, dF/ddelta, dF/depsilon,
    dF/dgamma, Phi_F).  Phi_F <= 0 only at the apex S = 0 (alpha = kappa = 0),
    where the derivatives are singular; the caller must treat that case.
    """
    I, s0, s1, s2, s3, a, II, III, IIskw, mm = invariants(S)
    Gam, theta, m, base = lode_factor(II, III, gamma)
    ks = params[P_K_SIGMA]
    kmu = params[P_K_MU]
    alpha = params[P_ALPHA]
    phi = Gam * II + ks * IIskw + kmu * mm + 0.5 * alpha * I * I + I ** 4 / (delta * delta)
    if phi <= 0.0:
        for i in range(7):
            dF[i] = 0.0
        return beta * I + I * I / eps - params[P_KAPPA], I, 0.0, -I * I / (eps * eps), 0.0, 0.0
    rphi = math.sqrt(phi)
    F = rphi + beta * I + I * I / eps - params[P_KAPPA]
    # d(Gamma II)/dS = Gamma S + m gamma base^(m-1) [dIII/dS II^-1/2 - 3/2 theta S]
    # (finite as II -> 0: dIII ~ |S|^2).  dIII/dS = dev(S^2) (Cayley-Hamilton).
    if II > 1e-28:
        k = m * gamma * base ** (m - 1.0)
        rII = math.sqrt(II)
        q0 = s0 * s0 + s3 * s3 - 2.0 * II / 3.0
        q1 = s1 * s1 + s3 * s3 - 2.0 * II / 3.0
        q2 = s2 * s2 - 2.0 * II / 3.0
        q3 = s3 * (s0 + s1)
        g0 = Gam * s0 + k * (q0 / rII - 1.5 * theta * s0)
        g1 = Gam * s1 + k * (q1 / rII - 1.5 * theta * s1)
        g2 = Gam * s2 + k * (q2 / rII - 1.5 * theta * s2)
        g3 = Gam * s3 + k * (q3 / rII - 1.5 * theta * s3)
    else:
        g0 = s0
        g1 = s1
        g2 = s2
        g3 = s3
    vol = alpha * I + 4.0 * I ** 3 / (delta * delta)
    inv2 = 0.5 / rphi
    h = beta + 2.0 * I / eps
    dF[0] = (g0 + vol) * inv2 + h
    dF[1] = (g1 + vol) * inv2 + h
    dF[2] = (g2 + vol) * inv2 + h
    dF[3] = (g3 + ks * a) * inv2
    dF[4] = (g3 - ks * a) * inv2
    dF[5] = 2.0 * kmu * S[5] * inv2
    dF[6] = 2.0 * kmu * S[6] * inv2
    dbeta = I
    ddelta = -I ** 4 / (delta ** 3 * rphi)
    deps = -I * I / (eps * eps)
    # dGamma/dgamma with m = m(gamma): Gamma [m theta/base + ln(base) dm/dgamma]
    dm = -SQRT3_3 / (gamma * gamma)
    dgamma = II * Gam * (m * theta / base + math.log(base) * dm) * inv2
    return F, dbeta, ddelta, deps, dgamma, phi


@njit(cache=True, error_model="numpy")
def plastic_potential_derivatives(S, beta, delta, eps, params, n, H, dndp):
    """Flow direction n = dG/dS (2.78, 2.79), its Hessian H and dn/d(beta, delta, epsilon).

    n (7): dG/dsigma (5 plane components) and dG/dm (2 couple components), spec 4.3:
      dG/dsigma = [psi1 S + k_sigma sigma_skw + (alpha I + 4 I^3/delta^2) I]/(2 sqrt Phi_G)
                  + (psi2 beta + 2 I/epsilon) I,     dG/dm = k_mu m / sqrt Phi_G.
    H (7x7) = d n / dS (symmetric); dndp (3x7) rows d n/d beta, d n/d delta, d n/d epsilon
    (G does not depend on gamma).  Returns (G, Phi_G); Phi_G <= 0 (apex) leaves
    n, H undefined and the caller must stop.
    """
    I, s0, s1, s2, s3, a, II, III, IIskw, mm = invariants(S)
    psi1 = params[P_PSI1]
    psi2 = params[P_PSI2]
    ks = params[P_K_SIGMA]
    kmu = params[P_K_MU]
    alpha = params[P_ALPHA]
    d2 = delta * delta
    phi = psi1 * II + ks * IIskw + kmu * mm + 0.5 * alpha * I * I + I ** 4 / d2
    if phi <= 0.0:
        return psi2 * beta * I + I * I / eps, phi
    rphi = math.sqrt(phi)
    # gradient of Phi_G
    vol = alpha * I + 4.0 * I ** 3 / d2
    gp0 = psi1 * s0 + vol
    gp1 = psi1 * s1 + vol
    gp2 = psi1 * s2 + vol
    gp3 = psi1 * s3 + ks * a
    gp4 = psi1 * s3 - ks * a
    gp5 = 2.0 * kmu * S[5]
    gp6 = 2.0 * kmu * S[6]
    inv2 = 0.5 / rphi
    h = psi2 * beta + 2.0 * I / eps
    n[0] = gp0 * inv2 + h
    n[1] = gp1 * inv2 + h
    n[2] = gp2 * inv2 + h
    n[3] = gp3 * inv2
    n[4] = gp4 * inv2
    n[5] = gp5 * inv2
    n[6] = gp6 * inv2
    # Hessian of Phi_G
    for i in range(7):
        for j in range(7):
            H[i, j] = 0.0
    hv = alpha + 12.0 * I * I / d2
    for i in range(3):
        for j in range(3):
            H[i, j] = hv - psi1 / 3.0
        H[i, i] += psi1
    H[3, 3] = 0.5 * (psi1 + ks)
    H[4, 4] = 0.5 * (psi1 + ks)
    H[3, 4] = 0.5 * (psi1 - ks)
    H[4, 3] = 0.5 * (psi1 - ks)
    H[5, 5] = 2.0 * kmu
    H[6, 6] = 2.0 * kmu
    # d n/dS = H_Phi/(2 sqrt Phi) - gPhi gPhi^T/(4 Phi^3/2) + 2/eps 1(x)1
    gp = (gp0, gp1, gp2, gp3, gp4, gp5, gp6)
    c4 = 0.25 / (phi * rphi)
    for i in range(7):
        gi = gp[i]
        for j in range(7):
            H[i, j] = H[i, j] * inv2 - c4 * gi * gp[j]
    for i in range(3):
        for j in range(3):
            H[i, j] += 2.0 / eps
    # d n / d beta
    for j in range(7):
        dndp[0, j] = 0.0
        dndp[2, j] = 0.0
    for j in range(3):
        dndp[0, j] = psi2
        dndp[2, j] = -2.0 * I / (eps * eps)
    # d n / d delta: dPhi/ddelta = -2 I^4/delta^3, d gPhi/ddelta = -8 I^3/delta^3 (normals)
    dphi = -2.0 * I ** 4 / (d2 * delta)
    dgv = -8.0 * I ** 3 / (d2 * delta)
    for j in range(7):
        dndp[1, j] = -gp[j] * dphi * c4
    for j in range(3):
        dndp[1, j] += dgv * inv2
    G = rphi + psi2 * beta * I + I * I / eps
    return G, phi
