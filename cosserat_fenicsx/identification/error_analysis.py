"""Error analysis of an identified parameter set (thesis section 4.5, eqs 4.26-4.31).

Nonlinear regression at the optimum s_hat, linearised with the sensitivities
J_nk = d phi_n / d s_k (chapter 5):

* scatter of the data (4.26): sigma_n, the standard deviation of measurement n over
  repeated tests; when it is not known, sigma_n = c / sqrt(w_n) with the objective's
  weights w_n and an unknown common factor c, which the residual analysis estimates;
* residual analysis (4.27): s0^2 = 1/(N - P) sum_n (phi_n - phi~_n)^2 / sigma_n^2
  (s0 ~ 1: the fit is as good as the data; s0 >> 1: the model misses the data);
* covariance (4.28): K = s0^2 (sum_n J_n J_n^T / sigma_n^2)^-1, standard deviations
  sigma_p,i = sqrt(K_ii) (4.29);
* confidence region (4.30): |p_i - p_hat_i| <= l sigma_p,i with l = sqrt(P F_{P,N-P,1-alpha}).
  That l bounds the *joint* ellipsoid (s - s_hat)^T K^-1 (s - s_hat) <= P F (Scheffe), so
  each interval of (4.30) holds its parameter with probability >= 1 - alpha; the marginal
  interval with exactly 1 - alpha is l = t_{N-P, 1-alpha/2}.  Both are reported;
* correlation (4.31): r_ij = K_ij / sqrt(K_ii K_jj) (Table 6.5, 6.7);
* optionally, errors correlated along each curve (serial_blocks): K from the Newey-West
  sandwich instead of (4.28).

Everything works on plain arrays; scipy.stats gives the F and t quantiles.
"""

from __future__ import annotations

import dataclasses

import numpy as np


@dataclasses.dataclass
class ErrorAnalysis:
    """Result of :func:`analyse`; arrays follow `names`."""

    names: list
    values: np.ndarray
    n_data: int
    s0: float
    scatter_known: bool
    covariance: np.ndarray
    std: np.ndarray
    correlation: np.ndarray
    alpha: float
    joint_factor: float        # l of (4.30), sqrt(P F_{P,N-P,1-alpha})
    marginal_factor: float     # t_{N-P,1-alpha/2}
    condition_number: float
    rank_deficient: bool
    serially_correlated: bool = False   # K from the Newey-West sandwich

    def intervals(self, joint=True):
        """(lower, upper) per parameter: (4.30) when joint, else the marginal t interval."""
        f = self.joint_factor if joint else self.marginal_factor
        return self.values - f * self.std, self.values + f * self.std

    def inside_joint_region(self, s):
        """True when s lies in the joint confidence ellipsoid (s - s_hat)^T K^-1 (s - s_hat) <= P F."""
        d = np.asarray(s, dtype=float) - self.values
        q = d @ np.linalg.lstsq(self.covariance, d, rcond=None)[0]
        return bool(q <= self.joint_factor ** 2)

    def to_dict(self):
        lo, hi = self.intervals(joint=True)
        mlo, mhi = self.intervals(joint=False)
        per = {}
        for i, n in enumerate(self.names):
            v = float(self.values[i])
            per[n] = dict(value=v, std=_finite(self.std[i]),
                          relative_std=_finite(self.std[i] / abs(v)) if v != 0 else None,
                          determined=bool(np.isfinite(self.std[i])),
                          interval_joint=[_finite(lo[i]), _finite(hi[i])],
                          interval_marginal=[_finite(mlo[i]), _finite(mhi[i])])
        return dict(method="thesis section 4.5: s0 (4.27), K (4.28), sigma_p (4.29), "
                           "intervals (4.30) joint and t marginal, correlation (4.31)",
                    n_data=self.n_data, n_parameters=len(self.names), s0=self.s0,
                    scatter_known=self.scatter_known, confidence=1.0 - self.alpha,
                    joint_factor=self.joint_factor, marginal_factor=self.marginal_factor,
                    condition_number=self.condition_number if np.isfinite(self.condition_number) else None,
                    rank_deficient=self.rank_deficient, serially_correlated=self.serially_correlated,
                    parameters=per, correlation=[[_finite(c) for c in row] for row in self.correlation],
                    names=list(self.names))


def _finite(x):
    """A float for JSON, None where it is not finite (an undetermined parameter)."""
    x = float(x)
    return x if np.isfinite(x) else None


def _newey_west(Jw, rw, blocks, lags):
    """B = sum over blocks of sum_{|l| <= L} (1 - |l|/(L + 1)) sum_i g_i g_{i+l}^T, g_i = w_i r_i J_i
    (from the weighted Jw = sqrt(w) J and rw = sqrt(w) r): the variance of the score when the
    errors of neighbouring points of a curve are correlated (Newey & West 1987, Bartlett
    weights), points of different blocks independent."""
    g = rw[:, None] * Jw
    B = np.zeros((Jw.shape[1], Jw.shape[1]))
    rho = _lag1_autocorrelation(rw, blocks)
    start = 0
    for n in blocks:
        gb = g[start:start + n]
        if lags is None:
            # Andrews (1991) bandwidth of the Bartlett kernel for AR(1) errors
            a = 4.0 * rho ** 2 / ((1.0 - rho) ** 2 * (1.0 + rho) ** 2)
            L = int(np.ceil(1.1447 * (a * n) ** (1.0 / 3.0)))
        else:
            L = lags
        B += gb.T @ gb
        for lag in range(1, min(L, n - 1) + 1):
            c = gb[lag:].T @ gb[:-lag]
            B += (1.0 - lag / (L + 1.0)) * (c + c.T)
        start += n
    return B


def _lag1_autocorrelation(e, blocks):
    """Pooled lag-1 autocorrelation of the (weighted) residuals within blocks, in [0, 0.97]."""
    num = den = 0.0
    start = 0
    for n in blocks:
        b = e[start:start + n] - e[start:start + n].mean()
        num += float(b[1:] @ b[:-1])
        den += float(b @ b)
        start += n
    return float(np.clip(num / den, 0.0, 0.97)) if den > 0 else 0.0


def analyse(names, values, jacobian, residual, sigma=None, weights=None, alpha=0.05, serial_blocks=None,
            lags=None, sqrt_weights=None):
    """Error analysis at the optimum.

    jacobian (N, P): d phi_n / d s_k; residual (N,): phi_n(s_hat) - phi~_n;
    sigma (N,): data scatter sigma_n (4.26), or None: then `weights` (N,) (the objective's
    w_n) fix the relative scatter sigma_n ~ 1/sqrt(w_n) and s0 carries the common factor
    (sqrt_weights: sqrt(w_n) instead, for weights whose squares underflow).
    serial_blocks (list of lengths summing to N, the curves in data order): the errors of
    neighbouring points of one curve may be correlated (a DEM curve's points share its loading
    path); (4.28) assumes them independent and then understates K.  K becomes the sandwich
    A^-1 B A^-1 with B of Newey-West over `lags` neighbours (default: Andrews' AR(1) plug-in
    bandwidth from the residuals' lag-1 autocorrelation).
    """
    from scipy import stats
    J = np.asarray(jacobian, dtype=float)
    r = np.asarray(residual, dtype=float)
    N, P = J.shape
    if r.shape != (N,):
        raise ValueError(f"error analysis: residual has shape {r.shape}, the jacobian {J.shape}")
    if N <= P:
        raise ValueError(f"error analysis needs more data points than parameters (N = {N}, P = {P})")
    if sigma is not None:
        sw = 1.0 / np.asarray(sigma, dtype=float)
        known = True
    else:
        sw = (np.ones(N) if weights is None and sqrt_weights is None else
              np.asarray(sqrt_weights, dtype=float) if sqrt_weights is not None else
              np.sqrt(np.asarray(weights, dtype=float)))
        sw = sw / sw.max() if np.all(np.isfinite(sw)) and sw.max() > 0 else sw   # the common factor is s0's
        known = False
    if P == 0:
        raise ValueError("error analysis: no free parameter (all at a bound)")
    if not (np.all(np.isfinite(sw)) and np.all(sw > 0)):
        raise ValueError("error analysis: data scatter (or weights) must be finite and > 0")
    rw = sw * r
    Jw = sw[:, None] * J
    A = Jw.T @ Jw                                                        # Fisher matrix
    # scale columns so that the condition number measures identifiability, not units
    d = np.sqrt(np.diag(A))
    d[d == 0] = 1.0
    An = A / np.outer(d, d)
    ev = np.linalg.eigvalsh(An)
    cond = float(ev[-1] / ev[0]) if ev[0] > 0 else float("inf")
    deficient = not np.isfinite(cond) or cond > 1e14
    Ainv = np.linalg.pinv(An, rcond=1e-14) / np.outer(d, d)
    # parameters the data do not determine: a zero sensitivity, or a part in a null direction
    # of the Fisher matrix; the pseudo-inverse would give them a variance of 0
    vals, vecs = np.linalg.eigh(An)
    null = vecs[:, vals <= max(vals[-1], 0.0) * 1e-14]
    undetermined = (np.diag(A) == 0) | (np.abs(null) > 1e-6).any(axis=1)
    rank = P - null.shape[1]          # what the data determine; the rest spends no degree of freedom
    top = float(np.max(np.abs(rw)))
    s0sq = (top * float(np.linalg.norm(rw / top))) ** 2 / (N - rank) if top > 0 else 0.0   # (4.27), no overflow
    if not np.isfinite(s0sq):
        raise ValueError(f"error analysis: the weighted residuals (up to {top:.3g}) are too large to square")
    if serial_blocks is None:
        K = s0sq * Ainv                                                  # (4.28)
    else:
        if sum(serial_blocks) != N:
            raise ValueError(f"error analysis: serial blocks of {sum(serial_blocks)} points for {N} data")
        # sandwich; (N / (N - P)) is the small-sample factor that makes it equal to (4.28)
        # for independent errors
        K = (N / (N - rank)) * Ainv @ _newey_west(Jw, rw, serial_blocks, lags) @ Ainv
    if not np.all(np.isfinite(K)):
        raise ValueError("error analysis: the covariance (4.28) overflows")
    std = np.sqrt(np.clip(np.diag(K), 0.0, None))                        # (4.29)
    std[undetermined] = np.inf
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = K / np.outer(std, std)                                    # (4.31)
    corr[~np.isfinite(corr)] = 0.0
    corr[undetermined, :] = corr[:, undetermined] = np.nan
    np.fill_diagonal(corr, 1.0)
    joint = float(np.sqrt(rank * stats.f.ppf(1.0 - alpha, rank, N - rank))) if rank else float("inf")  # (4.30)
    marginal = float(stats.t.ppf(1.0 - alpha / 2.0, N - rank))
    return ErrorAnalysis(names=list(names), values=np.asarray(values, dtype=float), n_data=N,
                         s0=float(np.sqrt(s0sq)), scatter_known=known, covariance=K, std=std,
                         correlation=corr, alpha=alpha, joint_factor=joint, marginal_factor=marginal,
                         condition_number=cond, rank_deficient=deficient,
                         serially_correlated=serial_blocks is not None)


def plot_correlation(analysis, path, title="parameter correlation (4.31)"):
    """Heat map of the correlation matrix, as Table 6.5/6.7 in colour."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    n = len(analysis.names)
    fig, ax = plt.subplots(figsize=(1.0 + 0.55 * n, 0.6 + 0.5 * n))
    im = ax.imshow(analysis.correlation, vmin=-1, vmax=1, cmap="RdBu_r")
    ax.set_xticks(range(n))
    ax.set_yticks(range(n))
    ax.set_xticklabels(analysis.names, rotation=90, fontsize=8)
    ax.set_yticklabels(analysis.names, fontsize=8)
    for i in range(n):
        for j in range(n):
            ax.text(j, i, f"{analysis.correlation[i, j]:.2f}", ha="center", va="center", fontsize=6)
    fig.colorbar(im, ax=ax, fraction=0.046)
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
