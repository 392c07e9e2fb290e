"""The servo-control of 000 section 3.2.2 (eqs 33-37, Table 2) as plain array functions.

* ``reactions``: a_q, m_q, the force and moment that hold each disc where it is (eq. 9:
  sum_c f_c,q = -a_q), from the contact list, a contact the cut duplicates weighted by
  1/multiplicity (cut.contact_weights);
* ``group_sums``: Delta a_e = a_e+ + a_e- and Delta m_e = m_e+ + m_e- (eq. 33), and for the
  four corners Delta m_c = sum_c m_c (eq. 36), per frame disc (its group of copies);
* ``corrections``: Delta u = -g_a Delta a, Delta theta = -g_m Delta m (eqs 34-35 with the sign
  that relaxes, dns-spec B2 SIGN WARNING: a_q is the force ON the disc, the contacts push the
  pair along -Delta a; as printed, +g_a Delta a, the residual grows). The corner group keeps
  its translation (x_c = F X_c, eq. 35). Gains ``stiffness_gains`` (g = beta / sum of the
  contact stiffnesses of the group: kn per contact for the translation, ks a^2 for the
  rotation) or ``table3_gains`` (000 Table 3: g_a M / dt^2 = 1e2, g_m M R^2 / dt^2 = 2e2);
* ``residual``: r_a of Table 2 step 5, the groups' Delta a, Delta m in units of
  a~ = M R / dt^2, m~ = M R^2 / dt^2 ('table2') or of the mean contact force f and f R
  ('force').

Units: forces [N], moments [N m], lengths [m], 2D per unit depth.
"""
import numpy as np

from ..specimen.contacts import contact_geometry

#: 000 Table 3: g_a M / dt^2 and g_m M R^2 / dt^2
TABLE3_GAIN_FORCE = 1.0e2
TABLE3_GAIN_MOMENT = 2.0e2
GAINS = ("stiffness", "table3")
RESIDUALS = ("force", "table2")
ACCELERATIONS = ("anderson", "none")
RAMPS = ("frame", "affine")


def reactions(position, radius, pair_i, pair_j, fn, fs, mr, weight):
    """(a (n, 2) [N], m (n,) [N m]): minus the weighted contact resultant of each disc."""
    n = position.shape[0]
    a = np.zeros((n, 2))
    m = np.zeros(n)
    on = np.flatnonzero(weight > 0.0)
    if on.size:
        i, j = pair_i[on], pair_j[on]
        _, _, _, force_j, moment_i, moment_j = contact_geometry(position, radius, i, j, fn[on], fs[on], mr[on])
        w = weight[on]
        np.add.at(a, j, -w[:, None] * force_j)
        np.add.at(a, i, w[:, None] * force_j)
        np.add.at(m, i, -w * moment_i)
        np.add.at(m, j, -w * moment_j)
    return a, m


def group_sums(groups, a, m):
    """(Delta a (G, 2), Delta m (G,)): the sums over the copies of each frame disc (eqs 33, 36)."""
    da = np.array([a[g].sum(axis=0) for g in groups]).reshape(-1, 2)
    dm = np.array([m[g].sum() for g in groups])
    return da, dm


def stiffness_gains(groups, pair_i, pair_j, touching, radius, kn, ks, beta):
    """(g_a (G,) [m/N], g_m (G,) [1/(N m)]): beta over the summed stiffness of the contacts of
    each group's copies, kn per contact for a translation and ks a^2 (a the radius) for a
    rotation; 0 for a group without contact (nothing to correct)."""
    n = radius.shape[0]
    count = np.zeros(n)
    on = np.flatnonzero(touching != 0)
    np.add.at(count, pair_i[on], 1.0)
    np.add.at(count, pair_j[on], 1.0)
    k_t = np.array([kn * count[g].sum() for g in groups])
    k_r = np.array([ks * float(np.sum(count[g] * radius[g] ** 2)) for g in groups])
    g_a = np.where(k_t > 0.0, beta / np.where(k_t > 0.0, k_t, 1.0), 0.0)
    g_m = np.where(k_r > 0.0, beta / np.where(k_r > 0.0, k_r, 1.0), 0.0)
    return g_a, g_m


def table3_gains(groups, mass, radius, dt):
    """000 Table 3's gains g_a = 1e2 dt^2 / M, g_m = 2e2 dt^2 / (M R^2) of each group's disc
    (dt [s] the time step)."""
    first = np.array([g[0] for g in groups], np.int64)
    M, R = mass[first], radius[first]
    return TABLE3_GAIN_FORCE * dt ** 2 / M, TABLE3_GAIN_MOMENT * dt ** 2 / (M * R * R)


def corrections(da, dm, g_a, g_m, corner_group):
    """(Delta u (G, 2) [m], Delta theta (G,) [rad]) = (-g_a Delta a, -g_m Delta m); the corner
    group's translation stays (eq. 35)."""
    du = -g_a[:, None] * da
    du[corner_group] = 0.0
    return du, -g_m * dm


def residual(da, dm, force_scale, moment_scale, corner_group):
    """r_a of Table 2 step 5: sqrt(sum over the groups of |Delta a|^2 / a~^2 + (Delta m / m~)^2),
    the corner group by its moment only (its force is the support reaction of the frame)."""
    fa = np.sum(da * da, axis=1) / force_scale ** 2
    fa[corner_group] = 0.0
    return float(np.sqrt(np.sum(fa) + np.sum((dm / moment_scale) ** 2)))


def scales(kind, groups, mass, radius, dt, mean_force):
    """(a~ (G,), m~ (G,)) of ``residual``: 'table2' M R / dt^2 and M R^2 / dt^2 of each
    group's disc; 'force' the mean contact force f [N] and f R."""
    first = np.array([g[0] for g in groups], np.int64)
    M, R = mass[first], radius[first]
    if kind == "table2":
        return M * R / dt ** 2, M * R * R / dt ** 2
    f = max(float(mean_force), 1e-300)
    return np.full(len(groups), f), f * R


class Anderson:
    """Anderson acceleration (type II, Walker & Ni 2011) of the servo's fixed-point iteration
    x <- x + f(x), f = the corrections of ``corrections`` (a Jacobi step preconditioned by the
    gains): the next correction f_k - (dX + dF) gamma with gamma the least-squares fit of the
    last `memory` differences of f to f_k. The plain servo damps the smooth modes of the
    frame slowly (a rate of 1 - beta lambda_min / lambda_max of the frame's Schur complement,
    lambda_min / lambda_max ~ d / L): tens to hundreds of iterations. Not in 000.

    x, f: flat vectors of the groups' (u_x, u_y, theta R_mean) [m]."""

    def __init__(self, memory=5):
        self.memory = memory
        self.xs, self.fs = [], []

    def restart(self):
        self.xs, self.fs = [], []

    def step(self, x, f):
        """The correction to apply at x with the plain correction f."""
        self.xs.append(x.copy())
        self.fs.append(f.copy())
        if len(self.xs) > self.memory + 1:
            self.xs.pop(0)
            self.fs.pop(0)
        if len(self.xs) < 2:
            return f
        dX = np.diff(np.array(self.xs), axis=0).T
        dF = np.diff(np.array(self.fs), axis=0).T
        gamma = np.linalg.lstsq(dF, f, rcond=None)[0]
        return f - (dX + dF) @ gamma
