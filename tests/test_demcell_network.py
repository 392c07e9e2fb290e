"""Exact solution of the frozen micropolar contact network (demcell/network.py).

References independent of the module: a plain-numpy nonlinear residual of the frozen network
(finite differences), Hill-Mandel / Clapeyron energy identities, closed-form lattice sums of the
hexagonal lattice, and the DEM micropolar cell itself (relaxation in the sticking regime).
The spec's rules are written again here (not imported): constraint weights = the normal force
each disc carries (commit a16d43b); a contact crossing the cell's side is counted at the copy whose contact
point lies in the cell (contact_weights_spec, contact_geometry)."""
import math

import numpy as np
import pytest

import demcell as dc
from demcell.network import (affine_operator, micropolar_network_operator, network_response,
                             network_system)

KN, KS, KR = 1.0e4, 2.0e3, 1.0e-2


# ---------------------------------------------------------------- states
def lattice_state(nx, ny, kn=KN, overlap=1e-4, radius=0.01):
    """Hexagonal lattice with its contacts found by brute force (independent of the DEM
    neighbour search) and fn = kn ovl: an exact equilibrium by symmetry."""
    st = dc.hexagonal_lattice(nx, ny, radius=radius, overlap=overlap)
    a = st.s[None, :, :] - st.s[:, None, :]
    a -= np.floor(a + 0.5)
    d = a @ st.h.T
    dist = np.linalg.norm(d, axis=2)
    R = st.radius
    ii, jj = np.nonzero(np.triu(dist < (R[:, None] + R[None, :]), 1))
    m = ii.size
    if st.pair_i.shape[0] < m:
        st.grow_pairs(m + 16)
    st.pair_i[:m], st.pair_j[:m] = ii, jj
    st.touching[:m] = 1
    st.fn[:m] = kn * (R[ii] + R[jj] - dist[ii, jj])
    st.n_pairs = m
    return st


@pytest.fixture(scope="module")
def packing():
    """A disordered 100-disc reference cell (equilibrium under 10 N/m, DEM relaxation)."""
    law = dc.ContactLaw()
    st, _ = dc.generate_packing(100, pressure=10.0, law=law, seed=0)
    return dc.reference_cell(st, law, dc.RelaxationOptions(), 10.0).state


def law_array(kn=KN, ks=KS, kr=KR, friction=0.5):
    return dc.ContactLaw(kn=kn, ks=ks, friction=friction, rolling_stiffness=kr).as_array()


# ---------------------------------------------------------------- independent numpy model
def contact_weights_spec(st):
    """Weights of the held mean rotation (commit a16d43b, superseding the spec's contact counts):
    w_p = sum of |fn| over the touching contacts of disc p [N] (rattlers: 0, unconstrained)."""
    k = np.nonzero(st.touching[:st.n_pairs])[0]
    w = np.zeros(st.n_particles)
    np.add.at(w, st.pair_i[k], np.abs(st.fn[k]))
    np.add.at(w, st.pair_j[k], np.abs(st.fn[k]))
    return w


def contact_geometry(st):
    """Per touching contact k: discs i, j, image shift n_k = -round(s_j - s_i), branch d (current)
    and D (reference), and the reference lever position X_i of the COUNTED copy (spec COPY RULE):
    the copy whose contact point lies in the cell, shifted by -m, m = floor(s_i + a_i/|d| (s_j -
    s_i + n_k)); its image of j sits at X_i + D = h_ref (s_j + n_k - m - c). Also the contact
    frame: length l, normal n, tangent t = (-n_y, n_x), lever arms a_i, a_j."""
    k = np.nonzero(st.touching[:st.n_pairs])[0]
    i, j = st.pair_i[k], st.pair_j[k]
    a = st.s[j] - st.s[i]
    shift = -np.floor(a + 0.5)                  # n_k
    a = a + shift                               # s_j - s_i + n_k
    d = a @ st.h.T
    l = np.linalg.norm(d, axis=1)
    R = st.radius
    ai = R[i] - 0.5 * (R[i] + R[j] - l)
    m = np.floor(st.s[i] + (ai / l)[:, None] * a)
    n = d / l[:, None]
    return dict(k=k, i=i, j=j, d=d, D=a @ st.h_ref.T, shift=shift, copy=m,
                Xi=(st.s[i] - m - 0.5) @ st.h_ref.T, l=l, n=n, t=np.column_stack((-n[:, 1], n[:, 0])),
                ai=ai, aj=R[j] - 0.5 * (R[i] + R[j] - l))


def nonlinear_network(st, kn, ks, kr, x, lam, dF, dphi, dkappa, weights=None):
    """Frozen network after finite increments (plain numpy, from the stored fn, fs, mr):
    x = (w_p x, w_p y, th~_p) per disc, lam the couple density; returns (residual (3N,), flux
    (6,) = sigma 11, 12, 21, 22, m1, m2). Positions x_p + dF F^-1 x_p + w_p, bilateral normal
    spring, one step of the incremental tangential and rolling laws (old t and lever arms),
    no sliding; force and moment resultants with the new directions and lever arms."""
    g = contact_geometry(st)
    i, j, d, D, Xi = g["i"], g["j"], g["d"], g["D"], g["Xi"]
    Xj = Xi + D
    kk = g["k"]
    n = st.n_particles
    w = np.column_stack((x[0::3], x[1::3]))
    th = x[2::3]
    E = np.asarray(dF, float).reshape(2, 2) @ np.linalg.inv(st.F)
    R = st.radius
    l0, t0, ai0, aj0 = g["l"], g["t"], g["ai"], g["aj"]      # the frame before the increment
    d1 = d + d @ E.T + w[j] - w[i]
    l1 = np.linalg.norm(d1, axis=1)
    n1 = d1 / l1[:, None]
    t1 = np.column_stack((-n1[:, 1], n1[:, 0]))
    dthi = dphi + Xi @ dkappa + th[i]
    dthj = dphi + Xj @ dkappa + th[j]
    fn = st.fn[kk] + kn * (l0 - l1)
    fs = st.fs[kk] - ks * (np.sum(t0 * (d1 - d), axis=1) - ai0 * dthi - aj0 * dthj)
    mr = st.mr[kk] - kr * (dthj - dthi)
    ovl1 = R[i] + R[j] - l1
    ai, aj = R[i] - 0.5 * ovl1, R[j] - 0.5 * ovl1
    f = fn[:, None] * n1 + fs[:, None] * t1
    Mi, Mj = -ai * fs - mr, -aj * fs + mr
    res = np.zeros((n, 3))
    np.add.at(res[:, :2], i, -f)
    np.add.at(res[:, :2], j, f)
    np.add.at(res[:, 2], i, Mi)
    np.add.at(res[:, 2], j, Mj)
    A = contact_weights_spec(st) if weights is None else weights
    res[:, 2] += lam * A
    area = abs(np.linalg.det((np.eye(2) + E) @ st.h))
    sig = -np.einsum("ka,kb->ab", f, d1) / area
    m = (fs[:, None] * (ai[:, None] * Xi + aj[:, None] * Xj) - mr[:, None] * D).sum(axis=0) / area
    return res.reshape(-1), np.concatenate((sig.reshape(4), m))


def split_macro(u):
    return u[:4], u[4], u[5:7]


def fd_jacobians(st, kn, ks, kr, h_x=1e-9, h_u=1e-7):
    """Central differences of the nonlinear residual and fluxes w.r.t. (x, macro)."""
    n3 = 3 * st.n_particles
    x0, u0 = np.zeros(n3), np.zeros(7)

    def ev(x, u):
        return nonlinear_network(st, kn, ks, kr, x, 0.0, *split_macro(u))

    Jx, Sx = np.zeros((n3, n3)), np.zeros((6, n3))
    for c in range(n3):
        e = np.zeros(n3)
        e[c] = h_x
        rp, fp = ev(x0 + e, u0)
        rm, fm = ev(x0 - e, u0)
        Jx[:, c], Sx[:, c] = (rp - rm) / (2 * h_x), (fp - fm) / (2 * h_x)
    Ju, Su = np.zeros((n3, 7)), np.zeros((6, 7))
    for c in range(7):
        e = np.zeros(7)
        e[c] = h_u
        rp, fp = ev(x0, u0 + e)
        rm, fm = ev(x0, u0 - e)
        Ju[:, c], Su[:, c] = (rp - rm) / (2 * h_u), (fp - fm) / (2 * h_u)
    return Jx, Ju, Sx, Su


def scrambled(st, seed=1):
    """Copy with random tangential forces and rolling moments (not an equilibrium: the
    linearization does not need one), so that every pre-stress term is exercised."""
    st = st.copy()
    rng = np.random.default_rng(seed)
    k = np.nonzero(st.touching[:st.n_pairs])[0]
    st.fs[k] = 0.3 * st.fn[k] * rng.uniform(-1, 1, k.size)
    st.mr[k] = 0.3 * st.fn[k] * st.radius[st.pair_i[k]] * rng.uniform(-1, 1, k.size)
    return st


def coordination(st):
    z = np.zeros(st.n_particles, int)
    k = np.nonzero(st.touching[:st.n_pairs])[0]
    np.add.at(z, st.pair_i[k], 1)
    np.add.at(z, st.pair_j[k], 1)
    return z


def increments(st, resp, dF, dphi, dkappa):
    """Contact increments of a response (from its w and total theta): dd, n.dd, d_ut,
    d theta_r, at the counted copy (spec COPY RULE): rotations theta_i + dkappa . h_ref (-m),
    theta_j + dkappa . h_ref (n_k - m)."""
    g = contact_geometry(st)
    i, j = g["i"], g["j"]
    shift, copy = g["shift"], g["copy"]
    d, l, n, t, ai, aj = g["d"], g["l"], g["n"], g["t"], g["ai"], g["aj"]
    E = np.asarray(dF, float).reshape(2, 2) @ np.linalg.inv(st.F)
    dd = resp["w"][j] - resp["w"][i] + d @ E.T
    dkappa = np.asarray(dkappa, float)
    thi = resp["theta"][i] - (copy @ st.h_ref.T) @ dkappa
    thj = resp["theta"][j] + ((shift - copy) @ st.h_ref.T) @ dkappa
    dut = np.sum(t * dd, axis=1) - ai * thi - aj * thj
    return dict(g=g, n=n, t=t, l=l, ai=ai, aj=aj, E=E, dd=dd, dn=np.sum(n * dd, axis=1), dut=dut,
                dthr=thj - thi)


def state_fluxes(st):
    """sigma (2x2) and m (2,) of the stored forces (spec formulas), area, and the resultant
    force (N, 2) and moment (N,) of the contacts on every disc."""
    g = contact_geometry(st)
    i, j, d, D, Xi, k = g["i"], g["j"], g["d"], g["D"], g["Xi"], g["k"]
    n, t, ai, aj = g["n"], g["t"], g["ai"], g["aj"]
    fn, fs, mr = st.fn[k], st.fs[k], st.mr[k]
    f = fn[:, None] * n + fs[:, None] * t
    area = abs(np.linalg.det(st.h))
    sig = -np.einsum("ka,kb->ab", f, d) / area
    m = (fs[:, None] * (ai[:, None] * Xi + aj[:, None] * (Xi + D)) - mr[:, None] * D).sum(axis=0) / area
    Fres = np.zeros((st.n_particles, 2))
    Mres = np.zeros(st.n_particles)
    np.add.at(Fres, i, -f)
    np.add.at(Fres, j, f)
    np.add.at(Mres, i, -ai * fs - mr)
    np.add.at(Mres, j, -aj * fs + mr)
    return sig, m, area, Fres, Mres


E_SKEW = np.array([[0.0, 1.0], [-1.0, 0.0]])
CB_TO_DEMCELL = {0: (0, 0), 1: (1, 1), 2: (0, 1), 3: (1, 0)}   # callback index -> tensor index


def random_macro(rng, scale=1e-4, L=0.1):
    return (scale * rng.standard_normal((2, 2)), scale * rng.standard_normal(),
            scale / L * rng.standard_normal(2))


# ---------------------------------------------------------------- 1. finite differences
@pytest.mark.parametrize("prestress", [True, False])
def test_linearization_equals_finite_differences_of_the_nonlinear_network(packing, prestress):
    st = scrambled(packing)                 # random fs, mr: every pre-stress term is active
    kn, ks, kr = KN, KS, KR
    ref = st.copy()
    if not prestress:                       # a force-free network: its Jacobian is the spring network
        ref.fn[:] = 0.0
        ref.fs[:] = 0.0
        ref.mr[:] = 0.0
    Jx, Ju, Sx, Su = fd_jacobians(ref, kn, ks, kr)
    sysm = network_system(st, law_array(kn, ks, kr), prestress=prestress)
    K = sysm["K"].toarray()
    area = sysm["area"]
    Su_code = sysm["SU"] / area
    if prestress:
        from demcell.network import _area_term
        Su_code = Su_code + _area_term(sysm)
    for name, a, b in (("K", K, Jx), ("G", sysm["G"], Ju), ("Sx", sysm["Sx"] / area, Sx), ("SU", Su_code, Su)):
        err = np.abs(a - b).max() / np.abs(b).max()
        assert err < 1e-6, (name, err)


def test_default_weights_are_the_spec_rule(packing):
    """network.contact_weights (the default of every solve) is the spec's rule, and the same
    as the kernel's (relaxation.contact_weights, which the DEM cell's constraint uses)."""
    from demcell.network import contact_weights
    from demcell import relaxation
    st = packing
    w_kernel = np.zeros(st.n_particles)
    relaxation.contact_weights(w_kernel, 1.0 / st.inertia, st.pair_i, st.pair_j, st.touching, st.fn,
                               st.n_pairs)
    assert np.allclose(contact_weights(st), w_kernel, rtol=1e-14, atol=0.0)
    assert np.allclose(contact_weights(st), contact_weights_spec(st), rtol=1e-14, atol=0.0)


def test_response_solves_the_linearized_nonlinear_network(packing):
    """The response makes the directional derivative of the nonlinear residual vanish, satisfies
    the constraint, and its flux increments are the derivative of the nonlinear fluxes
    (weights given explicitly: the spec's rule)."""
    st = packing
    la = law_array(KN, KS, KR)
    rng = np.random.default_rng(4)
    dF, dphi, dkappa = random_macro(rng)
    r = network_response(st, la, dF, dphi, dkappa, rotation_weights=contact_weights_spec(st))
    x = np.zeros(3 * st.n_particles)
    x[0::3], x[1::3], x[2::3] = r["w"][:, 0], r["w"][:, 1], r["theta_fluct"]
    A = contact_weights_spec(st)
    assert abs(A @ r["theta_fluct"]) <= 1e-12 * (A @ np.abs(r["theta_fluct"]))
    Xlev = (st.s - 0.5) @ st.h_ref.T
    assert np.allclose(r["theta"], dphi + Xlev @ dkappa + r["theta_fluct"], rtol=0, atol=1e-15)
    eps = 1e-3

    def ev(sgn, xs=1.0, us=1.0):
        return nonlinear_network(st, KN, KS, KR, sgn * eps * xs * x, sgn * eps * r["lambda"],
                                 sgn * eps * us * dF, sgn * eps * us * dphi, sgn * eps * us * dkappa,
                                 weights=A)

    rp, fp = ev(1.0)
    rm, fm = ev(-1.0)
    dres = (rp - rm) / (2 * eps)
    scale = (ev(1.0, us=0.0)[0] - ev(-1.0, us=0.0)[0]) / (2 * eps)    # the fluctuation part alone
    force_rel = np.abs(np.delete(dres, np.s_[2::3])).max() / np.abs(np.delete(scale, np.s_[2::3])).max()
    moment_rel = np.abs(dres[2::3]).max() / np.abs(scale[2::3]).max()
    assert force_rel < 1e-8 and moment_rel < 1e-8, (force_rel, moment_rel)
    dflux = (fp - fm) / (2 * eps)
    got = np.concatenate((r["sigma"].reshape(4), r["m"]))
    assert np.abs(got[:4] - dflux[:4]).max() < 1e-7 * np.abs(dflux[:4]).max()
    assert np.abs(got[4:] - dflux[4:]).max() < 1e-7 * np.abs(dflux[4:]).max()


# ---------------------------------------------------------------- 2. Hill-Mandel
def test_hill_mandel_first_order(packing):
    """dW = sum (fn d ovl - fs d ut - mr d thr) = |Y| [sigma : (dF F^-1 + e dphi) + m . dkappa]
    - sum_p (w_p . F_p + th~_p M_p): exact for admissible increments (periodic w, mean-free
    th~); the last sum is the work of the residual forces of the relaxed state."""
    st = packing
    la = law_array(KN, KS, KR)
    sig, m, area, Fres, Mres = state_fluxes(st)
    rng = np.random.default_rng(5)
    for _ in range(3):
        dF, dphi, dkappa = random_macro(rng)
        r = network_response(st, la, dF, dphi, dkappa)
        inc = increments(st, r, dF, dphi, dkappa)
        k = inc["g"]["k"]
        dW = np.sum(-st.fn[k] * inc["dn"] - st.fs[k] * inc["dut"] - st.mr[k] * inc["dthr"])
        macro = area * (np.sum(sig * (inc["E"] + E_SKEW * dphi)) + m @ dkappa)
        residual_work = np.sum(r["w"] * Fres) + r["theta_fluct"] @ Mres
        assert abs(dW - (macro - residual_work)) < 1e-9 * abs(dW)
        assert abs(residual_work) < 1e-3 * abs(dW)      # the reference cell is near equilibrium


def test_clapeyron_of_the_spring_network(packing):
    """prestress=False: 2 W = |Y| [dsigma : dF F^-1 + (dsigma12 - dsigma21) dphi + dm . dkappa]
    with W = 1/2 sum (kn dn^2 + ks dut^2 + kr dthr^2) of the response (energy of a linear
    network at its constrained equilibrium)."""
    st = packing
    la = law_array(KN, KS, KR)
    area = abs(np.linalg.det(st.h))
    rng = np.random.default_rng(6)
    for _ in range(3):
        dF, dphi, dkappa = random_macro(rng)
        r = network_response(st, la, dF, dphi, dkappa, prestress=False)
        inc = increments(st, r, dF, dphi, dkappa)
        W2 = np.sum(KN * inc["dn"] ** 2 + KS * inc["dut"] ** 2 + KR * inc["dthr"] ** 2)
        work = area * (np.sum(r["sigma"] * (inc["E"] + E_SKEW * dphi)) + r["m"] @ dkappa)
        assert abs(W2 - work) < 1e-8 * W2, (W2, work)


def affine_fluxes(st, inc, kn, ks, kr):
    """dsigma (2x2), dm (2,) of the contact springs alone for given contact increments."""
    g = inc["g"]
    area = abs(np.linalg.det(st.h))
    dfs, dmr = -ks * inc["dut"], -kr * inc["dthr"]
    df = -kn * inc["dn"][:, None] * inc["n"] + dfs[:, None] * inc["t"]
    dsig = -np.einsum("ka,kb->ab", df, g["d"]) / area
    lev = inc["ai"][:, None] * g["Xi"] + inc["aj"][:, None] * (g["Xi"] + g["D"])
    dm = (dfs[:, None] * lev - dmr[:, None] * g["D"]).sum(axis=0) / area
    return dsig, dm


def test_affine_operator_is_the_uniform_strain_sum_and_an_upper_bound(packing):
    st = packing
    la = law_array(KN, KS, KR, friction=0.5)
    C_aff = affine_operator(st, la)
    zero_w = np.zeros((st.n_particles, 2))
    Xlev = (st.s - 0.5) @ st.h_ref.T
    rng = np.random.default_rng(7)
    for _ in range(4):
        dF, dphi, dkappa = random_macro(rng)
        # the operator is at fixed phi: w = 0, theta_p = dkappa . X_p
        inc0 = increments(st, dict(w=zero_w, theta=Xlev @ dkappa), dF, 0.0, dkappa)
        dsig0, dm0 = affine_fluxes(st, inc0, KN, KS, KR)
        expect = np.array([dsig0[0, 0], dsig0[1, 1], dsig0[0, 1], dsig0[1, 0], dm0[0], dm0[1]])
        u = np.array([dF[0, 0], dF[1, 1], dF[0, 1], dF[1, 0], dkappa[0], dkappa[1]])
        assert np.abs(C_aff @ u - expect).max() < 1e-10 * np.abs(expect).max()
        # Voigt bound: the affine field (w = 0, th~ = 0) is admissible, the network minimizes the energy
        inc = increments(st, dict(w=zero_w, theta=dphi + Xlev @ dkappa), dF, dphi, dkappa)
        W_aff = 0.5 * np.sum(KN * inc["dn"] ** 2 + KS * inc["dut"] ** 2 + KR * inc["dthr"] ** 2)
        r = network_response(st, la, dF, dphi, dkappa, prestress=False)
        ir = increments(st, r, dF, dphi, dkappa)
        W_net = 0.5 * np.sum(KN * ir["dn"] ** 2 + KS * ir["dut"] ** 2 + KR * ir["dthr"] ** 2)
        assert W_net <= W_aff * (1.0 + 1e-10)
    # frictionless contacts carry no tangential spring in the affine estimate
    C0 = affine_operator(st, law_array(KN, KS, KR, friction=0.0))
    C1 = affine_operator(st, law_array(KN, 0.0, KR, friction=0.5))
    assert np.array_equal(C0, C1)


def test_force_block_equals_pstlo_when_the_mean_rotation_is_free(packing):
    """With lambda = 0 (dphi chosen to release the constraint) the micropolar network is the
    classical one with free rotations: the sigma response to dF equals PSTLO's (tangent.py,
    an independent assembly). Rattlers are given zero weight (see the module note)."""
    from demcell.tangent import pstlo_operator
    st = packing
    law = dc.ContactLaw(kn=KN, ks=KS, friction=0.5)
    la = law.as_array()
    weights = np.where(coordination(st) >= 2, math.pi * st.radius ** 2, 0.0)
    C_pst = pstlo_operator(st, la)
    r_phi = network_response(st, la, np.zeros((2, 2)), 1.0, np.zeros(2), rotation_weights=weights)
    for c, (a, b) in enumerate(((0, 0), (0, 1), (1, 0), (1, 1))):
        dF = np.zeros((2, 2))
        dF[a, b] = 1.0
        r = network_response(st, la, dF, 0.0, np.zeros(2), rotation_weights=weights)
        released = r["sigma"] - r["lambda"] / r_phi["lambda"] * r_phi["sigma"]
        err = np.abs(released.reshape(4) - C_pst[:, c]).max() / np.abs(C_pst).max()
        # PSTLO shifts the whole diagonal by 1e-10 of its largest (force) entry, ~1e-6 of the
        # rotational stiffness ks R^2: that bias, not this module, limits the agreement
        assert err < 1e-5, (c, err)


def test_contact_weights_resist_phi_where_area_weights_let_rattlers_absorb_it(packing):
    """Default weights (the kernel's, the normal force each disc carries): the cell resists the
    micro-rotation, d(sigma12 - sigma21)/dphi is a sizeable fraction (measured 0.64; 0.86 with
    contact-count weights) of its affine value
    ks sum_k |d_k|^2 / |Y| (w = 0, th~ = 0: d_ut = -|d| dphi). Documented contrast: the spec's
    former area weights pi R^2 put weight on the rattlers, which turn for free and absorb the
    whole constraint (lambda ~ 0): the cell does not resist phi and its dF block is PSTLO's."""
    from demcell.tangent import pstlo_operator
    st = packing
    if not (coordination(st) == 0).any():
        pytest.skip("no rattler in this packing")
    la = dc.ContactLaw(kn=KN, ks=KS, friction=0.5).as_array()
    inc = increments(st, dict(w=np.zeros((st.n_particles, 2)), theta=np.ones(st.n_particles)),
                     np.zeros((2, 2)), 1.0, np.zeros(2))
    dsig_aff, _ = affine_fluxes(st, inc, KN, KS, KR)
    skew_aff = dsig_aff[0, 1] - dsig_aff[1, 0]
    assert np.isclose(skew_aff, KS * np.sum(inc["l"] ** 2) / abs(np.linalg.det(st.h)), rtol=1e-12)
    _, c_phi = micropolar_network_operator(st, la)
    skew = c_phi[2] - c_phi[3]
    assert skew > 0.3 * skew_aff, (skew, skew_aff)
    C, c_phi_area = micropolar_network_operator(st, la, rotation_weights=math.pi * st.radius ** 2)
    C_pst = pstlo_operator(st, la)
    cb = CALLBACK_ORDER_4
    assert np.abs(C[:4, :4][np.ix_(cb, cb)] - C_pst).max() < 1e-4 * np.abs(C_pst).max()
    assert np.abs(c_phi_area[:4]).max() < 1e-4 * skew_aff


CALLBACK_ORDER_4 = [0, 2, 3, 1]    # demcell index (11, 12, 21, 22) -> callback position


# ---------------------------------------------------------------- 3. hexagonal lattice
def lattice_sum_moduli(kn, ks, l):
    """C_ijkl = 1/A sum over the 3 contact directions of a disc (kn n_i n_k + ks t_i t_k) l^2 n_j n_l,
    A = sqrt(3)/2 l^2 per disc (one disc per primitive cell: w = 0 and, at fixed phi, th~ = 0
    by symmetry, so the affine field is exact)."""
    T = np.zeros((2, 2, 2, 2))
    for ang in (0.0, math.pi / 3, 2 * math.pi / 3):
        n = np.array([math.cos(ang), math.sin(ang)])
        t = np.array([-n[1], n[0]])
        K = kn * np.outer(n, n) + ks * np.outer(t, t)
        T += np.einsum("ik,j,l->ijkl", K, n, n) * l ** 2
    return T / (math.sqrt(3.0) / 2.0 * l ** 2)


@pytest.mark.parametrize("ks", [KS, 0.3 * KN])
def test_hexagonal_lattice_micropolar_moduli(ks):
    st = lattice_state(6, 6)
    C, c_phi = micropolar_network_operator(st, law_array(KN, ks, KR), prestress=False)
    l = 2 * 0.01 * (1 - 1e-4)
    T = lattice_sum_moduli(KN, ks, l)
    lam, G, mu_c = math.sqrt(3) / 4 * (KN - ks), math.sqrt(3) / 4 * (KN + ks), math.sqrt(3) / 2 * ks
    # the lattice sum reproduces the closed forms
    assert np.isclose(T[0, 0, 1, 1], lam, rtol=1e-12) and np.isclose(T[0, 0, 0, 0], lam + 2 * G, rtol=1e-12)
    assert np.isclose(T[0, 1, 0, 1], G + mu_c, rtol=1e-12) and np.isclose(T[0, 1, 1, 0], G - mu_c, rtol=1e-12)
    for r in range(4):
        for c in range(4):
            assert abs(C[r, c] - T[CB_TO_DEMCELL[r] + CB_TO_DEMCELL[c]]) < 1e-9 * KN, (r, c)
    # skew response: sigma12 - sigma21 = 2 mu_c (eps12 - eps21), eps = F - I + e phi
    skew_F = C[2, 2:4] - C[3, 2:4]
    assert np.allclose(skew_F, [2 * mu_c, -2 * mu_c], rtol=1e-9, atol=1e-9 * KN)
    assert np.isclose(c_phi[2] - c_phi[3], 2 * mu_c * 2, rtol=1e-9, atol=1e-9 * KN)
    assert np.abs(c_phi[[0, 1]]).max() < 1e-9 * KN


def test_hexagonal_lattice_bending_modulus_without_tangential_springs():
    st = lattice_state(6, 6)
    kr = 0.05
    C, c_phi = micropolar_network_operator(st, law_array(KN, 0.0, kr), prestress=False)
    assert np.allclose(C[4:, 4:], math.sqrt(3) * kr * np.eye(2), rtol=0, atol=1e-9 * kr)
    assert np.abs(C[4:, :4]).max() < 1e-9 * kr and np.abs(C[:4, 4:]).max() < 1e-9 * KN
    r = network_response(st, law_array(KN, 0.0, kr), np.zeros((2, 2)), 0.0, [3.0, -1.0], prestress=False)
    assert np.abs(r["theta_fluct"]).max() < 1e-12 and np.abs(r["w"]).max() < 1e-15   # linear field exact


def test_hexagonal_lattice_bending_with_tangential_springs_table():
    """Reported, not asserted against a number: dm/dkappa of the hexagonal cell with ks > 0
    grows with the cell (the linear rotation field loads the tangential springs in proportion
    to the distance from the cell centre). Asserted: the Voigt bound."""
    rows = []
    for nx in (4, 8, 16):
        st = lattice_state(nx, nx)
        la = law_array(KN, KS, KR)
        C, _ = micropolar_network_operator(st, la, prestress=False)
        Ca = affine_operator(st, la)
        L = math.sqrt(abs(np.linalg.det(st.h)))
        rows.append((nx, st.n_particles, L, C[4, 4], C[5, 5], Ca[4, 4], Ca[5, 5]))
        assert C[4, 4] <= Ca[4, 4] and C[5, 5] <= Ca[5, 5]
    print("\n nx x ny   N    L [m]    dm1/dk1   dm2/dk2   affine dm1/dk1  affine dm2/dk2")
    for row in rows:
        print(" %2d x %-2d %4d  %.4f  %9.4g %9.4g  %9.4g %9.4g" % (row[0], row[0], *row[1:]))


# ---------------------------------------------------------------- 4. against the DEM cell
# The exact solution of the periodic contact network (a linear solve of equilibrium and the
# contact law alone) against the DEM micropolar cell (demcell/relaxation.py, homogenization.py)
# on the disordered packing, in the sticking regime (friction = inf: nothing slides).
DEM_TOL = 1e-8      # unbalanced-force criterion: max_p |F_p| <= DEM_TOL * mean contact force


@pytest.fixture(scope="module", params=[0.0, KR], ids=["kr0", "kr"])
def sticking_cell(packing, request):
    """The reference packing as a micropolar DEM cell without sliding, relaxed again at F = I,
    phi = 0, kappa = 0 under the tight criterion (the network is linearized about this state)."""
    law = dc.ContactLaw(kn=KN, ks=KS, friction=math.inf, rolling_stiffness=request.param)
    opts = dc.RelaxationOptions(criterion="force", tol=DEM_TOL, check_every=20)
    cell = dc.DemCell(packing.copy(), law, opts, reset_reference=False, rotation_mode="micropolar")
    cell.set_deformation(np.eye(2), rotation=0.0, curvature=np.zeros(2))
    assert cell.solve().converged
    return cell


def error_scales(st, tol):
    """What a relaxation tolerance ``tol`` allows (each relaxed state's residual forces are
    below tol f_mean): stress tol p (the residual relative to the contact forces that carry
    p = -tr(sigma)/2), couple stress tol p R_mean, rotation tol f_mean / (kn R_mean) (the
    displacement a residual force causes on a contact spring, over a lever arm)."""
    sig, _, _, _, _ = state_fluxes(st)
    k = np.nonzero(st.touching[:st.n_pairs])[0]
    p, R, f = -0.5 * np.trace(sig), float(st.radius.mean()), float(np.abs(st.fn[k]).mean())
    return tol * p, tol * p * R, tol * f / (KN * R)


def touching_set(st):
    return {(int(st.pair_i[k]), int(st.pair_j[k])) for k in range(st.n_pairs) if st.touching[k]}


def test_dem_cell_increments_equal_the_network_solution_in_the_sticking_regime(sticking_cell):
    """Issue 10: small increments of F (1e-6 per component), phi (1e-6) and kappa (rotation
    jumps 1e-6, -0.7e-6 across the cell's sides) of the DEM cell vs network_response: stress,
    couple stress and the rotation increments of the discs with >= 2 contacts. Central
    differences (+u, -u) remove the second-order (geometric) term of the DEM; what remains is
    the relaxation error, bounded by error_scales (measured: <= 0.08 of the stress scale, <= 0.2
    of the couple-stress scale, <= 3.6 of the rotation scale, bound 10x; see the report). The network without its
    pre-stress terms misses by 10-250 stress scales (asserted > 5): the comparison sees them.
    Precondition (asserted): no contact loses more than half its overlap, affinely or in the
    network; a contact that opens during the relaxation restarts its tangential force from 0
    (the DEM leaves the frozen network: a random dF with components up to 3.3e-6 opened the
    weakest contact, overlap 7e-8 m, and moved m by 20 %)."""
    cell = sticking_cell
    base = cell.state
    la = cell.law_array
    h0 = cell.homogenized()
    th0 = base.theta.copy()
    s_tol, m_tol, th_tol = error_scales(base, DEM_TOL)
    g = contact_geometry(base)
    ovl = base.radius[g["i"]] + base.radius[g["j"]] - np.linalg.norm(g["d"], axis=1)
    sel = coordination(base) >= 2
    dF = 1e-6 * np.array([[1.0, 0.6], [-0.4, -0.8]])
    dk = np.linalg.solve(base.h_ref.T, [1.0e-6, -0.7e-6])     # dkappa . Y_k = jumps
    zero = np.zeros((2, 2)), 0.0, np.zeros(2)
    cases = dict(F=(dF, 0.0, zero[2]), phi=(zero[0], 1e-6, zero[2]), kappa=(zero[0], 0.0, dk),
                 all=(dF, 1e-6, dk))
    rows = []
    for name, u in cases.items():
        r = network_response(base, la, *u)
        affine = dict(w=np.zeros((base.n_particles, 2)), theta=np.zeros(base.n_particles))
        for inc in (increments(base, r, *u), increments(base, affine, u[0], 0.0, zero[2])):
            assert np.all(np.abs(inc["dn"]) < 0.5 * ovl), name
        out = []
        for sign in (1.0, -1.0):
            trial = cell.copy()
            trial.set_deformation(np.eye(2) + sign * u[0], rotation=sign * u[1], curvature=sign * u[2])
            assert trial.solve().converged
            assert touching_set(trial.state) == touching_set(base), name
            h1 = trial.homogenized()
            out.append((h1.cauchy - h0.cauchy, h1.couple_stress - h0.couple_stress, trial.state.theta - th0))
        dsig, dm, dth = ((a - b) / 2.0 for a, b in zip(*out))
        e_s = np.abs(dsig - r["sigma"]).max()
        e_m = np.abs(dm - r["m"]).max()
        e_t = np.abs(dth - r["theta"])[sel].max()
        bare = network_response(base, la, *u, prestress=False)
        miss = max(np.abs(dsig - bare["sigma"]).max() / s_tol, np.abs(dm - bare["m"]).max() / m_tol)
        rows.append((name, e_s / np.abs(r["sigma"]).max(), e_s / s_tol, e_m / np.abs(r["m"]).max(), e_m / m_tol,
                     e_t / np.abs(r["theta"][sel]).max(), e_t / th_tol, miss))
        assert e_s < s_tol and e_m < m_tol and e_t < 10.0 * th_tol, rows[-1]
        assert miss > 5.0, rows[-1]
    print("\n case   sigma: rel  /scale    m: rel  /scale   theta: rel  /scale   no-prestress miss /scale")
    for row in rows:
        print(" %-6s %9.2e %6.3f  %9.2e %6.3f  %9.2e %6.2f   %9.1f" % row)


def test_demqo_micropolar_tangent_equals_the_network_tangent(sticking_cell):
    """cell.tangent('demqo', 'micropolar') (6 frozen-contact DEM perturbations, eps on F,
    eps / max|Y_k| on kappa, one-sided) vs 'pstlo' (the network solve). Each of the two states
    of a difference is relaxed to the DEMQO tolerance tol_q (tangent.perturbation_options,
    proportional to eps), so entry (r, c) may be off by 2 tol_q S_r / eps_c (S_r = p for sigma
    rows, p R_mean for m rows, see error_scales): a bound independent of eps, while the
    one-sided O(eps) geometric term is not covered by it and shrinks with eps, hence eps = 1e-7
    (measured at the default eps = 1e-6: <= 0.04 of the bound with contact-count weights, up to
    0.35 with force weights, concentrated in the F12, F21 columns and 20x smaller at 1e-7).
    The network without pre-stress misses the sigma-F block by > 10 bounds."""
    from demcell.tangent import perturbation_options
    cell = sticking_cell
    st = cell.state
    eps = 1e-7
    Cd = cell.tangent("demqo", measure="micropolar", eps=eps)
    Cp = cell.tangent("pstlo", measure="micropolar")
    tol_q = perturbation_options(cell, eps).tol
    k_eps = eps / float(np.abs(st.h_ref).sum(axis=0).max())
    s_tol, m_tol, _ = error_scales(st, tol_q)
    bound = 2.0 * np.array([s_tol] * 4 + [m_tol] * 2)[:, None] / np.array([eps] * 4 + [k_eps] * 2)[None, :]
    ratio = np.abs(Cd - Cp) / bound
    blocks = [np.abs(Cd - Cp)[a:b, c:d].max() / np.abs(Cp[a:b, c:d]).max()
              for a, b in ((0, 4), (4, 6)) for c, d in ((0, 4), (4, 6))]
    print("\n demqo vs pstlo: max |dC| / bound %.3f; relative per block (s-F, s-k, m-F, m-k) %s"
          % (ratio.max(), " ".join("%.1e" % b for b in blocks)))
    assert ratio.max() < 1.0, ratio
    C0, _ = micropolar_network_operator(st, cell.law_array, prestress=False)
    assert (np.abs(Cd - C0) / bound)[:4, :4].max() > 10.0


def test_demqo_equals_the_network_at_a_loaded_state_with_skew_stress(packing):
    """At a loaded state the held mean rotation carries a reaction (skew stress != 0), and its
    force weights change with the normal forces: the network's lambda dw_p terms
    (network._reaction_triplets). DEMQO (the DEM kernel recomputing its weights every step) and
    the network agree to 1e-4 of the largest entry of each row (measured 3e-6); with the weights
    held fixed (no lambda dw_p terms) the network misses by > 1e-3 (measured 1e-2 in the m rows)."""
    from demcell.network import contact_weights
    law = dc.ContactLaw(kn=KN, ks=KS, friction=math.inf)
    opts = dc.RelaxationOptions(criterion="force", tol=1e-8, check_every=20)
    cell = dc.DemCell(packing.copy(), law, opts, reset_reference=False, rotation_mode="micropolar")
    width = float(np.abs(cell.state.h_ref).sum(axis=0).max())
    cell.set_deformation(np.array([[1 - 1e-3, 3e-4], [-2e-4, 1 + 4e-4]]), rotation=0.0,
                         curvature=np.array([2e-3, -1e-3]) / width)
    assert cell.solve().converged
    sigma = cell.cauchy_stress()
    assert abs(sigma[0, 1] - sigma[1, 0]) > 0.05      # a real reaction at this state
    Cd = cell.tangent("demqo", measure="micropolar", eps=1e-7)
    Cp = cell.tangent("pstlo", measure="micropolar")
    scale = np.abs(Cd).max(axis=1, keepdims=True)
    assert (np.abs(Cp - Cd) / scale).max() < 1e-4
    fixed, _ = micropolar_network_operator(cell.state, cell.law_array,
                                           rotation_weights=contact_weights(cell.state))
    assert (np.abs(fixed - Cd) / scale).max() > 1e-3
