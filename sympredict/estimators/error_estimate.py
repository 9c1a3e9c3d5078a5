"""The error estimate of a prediction: the learned gradient's error as a Gaussian process, carried through the steps.

The gradient Hermite–Birkhoff interpolant is the posterior mean of a Gaussian process with the model's kernel as
covariance; its posterior covariance of the gradient at two evaluation points ``z, z'``,

    C(z, z') = K(z, z') - V(z) V(z')^T,    V(z) = k(z)^T L^-T  (2n, m),

(``K_ab(z, z') = lambda_a^(1) lambda_b^(2) k``, ``L`` the centres' Gramian factor, ``V`` the Newton basis at
``z``) says how the errors ``delta g`` of the learned gradient at different points go together; its diagonal is
the power function.  One step maps ``delta g`` at its evaluation point ``z_k`` to ``S_k delta g``
(``S_k = d x1 / d g``, :meth:`~sympredict.symplectic.updates.UpdateRule.linearization`); along a rollout the
linearised error is ``delta_K = sum_k M_K,k delta g(z_k)`` with ``M_K,k = D Phi_K-1 ... D Phi_k+1 S_k``, and its
covariance is ``sum_k,l M_K,k C(z_k, z_l) M_K,l^T``.  The error field of the gradient is one smooth function, so
the local errors of the steps add coherently where the posterior correlates them (a systematic frequency or
phase error grows linearly along a periodic orbit, because the orbit revisits the points where its steps err
alike) and average out where it does not; neither a root-sum-square of local errors nor one error vector shared
by all steps in fixed coordinates (which a rotating Jacobian averages away) does that.

The estimate is ``c sqrt(tr Sigma)`` in the states' units with the scale ``c`` calibrated on held-out one-step
errors (the one-step estimate is the ``K = 1`` case, so one scale serves both).  The posterior says where the data
are sparse, not where the flow map is harder to learn, so each step's gradient error also carries a local scale
``f_k`` (``C(z_k, z_l)`` becomes ``f_k f_l C(z_k, z_l)``): the geometric mean of the held-out ratios true one-step
error / estimate at the ``LOCAL_NEIGHBOURS`` held-out samples nearest to the step's state (:func:`local_log_ratio`),
``O(B K N (2n + d_mu))`` for ``N`` held-out samples, small beside the rest.

Which trajectories err most is this one model's own, and its one-step residual vectors ``r_i = Phi(x0_i) - x1_i``
on the samples the fit did not interpolate (held-out samples and training samples that are not centres) say it
where the posterior cannot.  The residual part carries the ``RESIDUAL_NEIGHBOURS`` residual vectors nearest to each
step's state through the later steps as one draw among them, coherently (:func:`propagated_residuals`), times a
scale calibrated like ``c`` (the one-step case on the samples, each without its own residual); it is added to the
posterior's estimate in quadrature.  Near the data it tells the trajectories that pass where the model errs
systematically from the others; away from them (its residuals small, the posterior large) the posterior's part
dominates.  ``O(B K N' (2n + d_mu))`` for the neighbours among ``N'`` residual vectors plus ``O(B K (2n)^2 k)``
for the propagation; the steps' Jacobians are those the posterior's linearisation computes (handed over block by
block, :func:`rollout_error_units`' ``jacobians``), and the propagation carries ``F`` (B, 2n, k) from one block of
steps to the next (:class:`ResidualNeighbours`): memory ``O(B 2n (k + 2n))`` beyond the block and the output.

Cost along ``B`` rollouts of ``K`` steps with ``m`` centres: the Newton basis at every step, ``O(B K 2n m^2)``
(as the power function).  Up to :data:`EXACT_MAX_STEPS` steps every pair of steps is carried
(:class:`CovariancePropagation`): the prior covariances of all pairs, ``O(B K^2 (2n)^2)`` kernel terms, and the
recursion ``O(B K^2 (2n)^3)``; memory ``O(B K (2n)^2 + B 2n m)``.  Beyond, the posterior along each trajectory is
factorised on at most ``r`` landmark functionals pivoted from its own evaluation points
(:class:`LowRankPropagation`): ``O(B K (2n)^2 r (2n + m))`` for the landmarks' covariances with the steps plus
``O(B N r^2)`` for pivoting ``N`` candidates, linear in ``K``; memory ``O(B 2n (r + m))`` per step of a block of
bounded size.  Where the landmarks span the posterior at the points (a periodic or quasi-periodic orbit does in
a few dozen to a few hundred functionals) the two agree up to the pivoting's tolerance and the round-off of the
posterior, a difference of prior-sized terms (on fitted models of 230 to 500 centres over 2,000 to 4,000 steps:
within 3% in the median over the steps, 2% to 20% at the worst step); what the landmarks miss is kept as each
step's own independent error (the diagonal blocks stay exact).
"""

from __future__ import annotations

import logging

import numpy as np
from scipy.linalg import solve_triangular

from sympredict.interpolation.surrogate import HBSurrogate

_log = logging.getLogger(__name__)

__all__ = [
    "CovariancePropagation",
    "LowRankPropagation",
    "EXACT_MAX_STEPS",
    "pivoted_cholesky",
    "posterior_covariance",
    "mixed_covariance",
    "prior_covariance",
    "newton_rows",
    "local_covariance",
    "local_error_units",
    "rollout_error_units",
    "LOCAL_NEIGHBOURS",
    "local_points",
    "local_log_ratio",
    "nearest",
    "RESIDUAL_NEIGHBOURS",
    "propagated_residuals",
    "ResidualPropagation",
    "ResidualNeighbours",
    "SHARE_DISTANCE_QUANTILE",
    "kth_distance",
    "posterior_share",
]

#: Held-out samples whose ratios (true one-step error / estimate) set the local scale of the estimate at a point.
LOCAL_NEIGHBOURS = 20

#: Target number of float64 entries of a block of prior covariances (about 32 MB).
_BLOCK_ENTRIES = 1 << 22


def _probes(sur, z: np.ndarray, mu: np.ndarray, dt: np.ndarray) -> HBSurrogate:
    """A surrogate whose "centres" are the gradient functionals ``lambda_a`` at the points ``z`` (C, 2n), every
    component ``a``, with parameters ``mu`` (C, d_mu) and steps ``dt`` (C,) (coefficients 0: only its rows are used)."""
    n, dim = z.shape
    return HBSurrogate(
        sur.kernel,
        np.repeat(z, dim, axis=0),
        np.repeat(np.reshape(mu, (n, -1)), dim, axis=0),
        np.repeat(np.asarray(dt, dtype=float), dim),
        np.tile(np.arange(dim), n),
        np.zeros(n * dim),
    )


def prior_covariance(sur, z_rows: np.ndarray, z_cols: np.ndarray, mu: np.ndarray, dt: float) -> np.ndarray:
    """Prior covariances ``K_ab(z_i, z'_j)`` of the gradient components at two sets of points of one instance.

    The rows of :meth:`~sympredict.interpolation.surrogate.HBSurrogate.gradient_kernel_rows` against the
    gradient functionals at ``z_cols`` (the same code that builds the Gramian, transforms of the state kernel
    included); the parameter factors are 1 since ``(mu, dT)`` is the same for both points.

    Parameters
    ----------
    sur : HBSurrogate
    z_rows : ndarray of shape (R, 2n)
    z_cols : ndarray of shape (C, 2n)
    mu : ndarray of shape (d_mu,)
    dt : float

    Returns
    -------
    ndarray of shape (R, 2n, C, 2n)
    """
    n_cols, dim = z_cols.shape
    probes = _probes(sur, z_cols, np.repeat(np.reshape(mu, (1, -1)), n_cols, axis=0), np.full(n_cols, float(dt)))
    rows = probes.gradient_kernel_rows(z_rows, np.ones((len(z_rows), n_cols * dim)))
    return rows.reshape(len(z_rows), dim, n_cols, dim)


def local_points(x: np.ndarray, mu: np.ndarray, dt: np.ndarray, domain: dict) -> np.ndarray:
    """The coordinates in which the local scale's neighbours are found: state, parameter and step, each
    coordinate divided by the width of the training box (``domain``; a coordinate of zero width is dropped),
    so that every one counts alike whatever its units.  ``x`` (N, 2n), ``mu`` (N, d_mu), ``dt`` (N,) ->
    (N, 2n + d_mu + 1)."""
    lo = np.concatenate([domain["x_min"], domain["mu_min"], np.atleast_1d(domain["dt_min"])]).astype(float)
    hi = np.concatenate([domain["x_max"], domain["mu_max"], np.atleast_1d(domain["dt_max"])]).astype(float)
    width = hi - lo
    keep = width > 0
    pts = np.concatenate([x, np.reshape(mu, (len(x), -1)), np.reshape(dt, (len(x), 1))], axis=1)
    return (pts[:, keep] - lo[keep]) / width[keep]


def nearest(points: np.ndarray, queries: np.ndarray, k: int, leave_one_out: bool = False) -> np.ndarray:
    """Indices (Q, k') of the ``k' = min(k, N)`` nearest ``points`` (N, q) to each query (Q, q), Euclidean, nearest
    first (equal distances by index); ``leave_one_out``: the queries are the points themselves, each without itself
    (``k' <= N - 1``).  ``O(Q N q)`` time, ``O(chunk N)`` memory.

    The squared distances are summed coordinate by coordinate from the differences, not expanded as
    ``|a|^2 - 2 a.b + |b|^2``: the expansion loses the small distances to cancellation and rounds with the BLAS
    kernel, so two nearly equally near points could swap from one CPU to another; elementwise sums in a fixed
    order round alike everywhere."""
    n = len(points)
    k = max(1, min(int(k), n - 1 if leave_one_out else n))
    out = np.empty((len(queries), k), dtype=np.intp)
    chunk = max(1, (1 << 20) // max(1, n))
    for start in range(0, len(queries), chunk):
        sl = slice(start, min(len(queries), start + chunk))
        d2 = np.zeros((sl.stop - sl.start, n))
        for j in range(points.shape[1]):  # a handful of coordinates: 2n + d_mu + 1
            diff = queries[sl, j][:, None] - points[None, :, j]
            d2 += diff * diff
        if leave_one_out:
            d2[np.arange(sl.stop - sl.start), np.arange(sl.start, sl.stop)] = np.inf
        near = np.argpartition(d2, k - 1, axis=1)[:, :k]
        # nearest first (ties by index): argpartition's order differs between NumPy's builds, and the residual
        # part pairs the i-th nearest of one step with the i-th nearest of the next
        order = np.lexsort((near, np.take_along_axis(d2, near, axis=1)), axis=1)
        out[sl] = np.take_along_axis(near, order, axis=1)
    return out


def local_log_ratio(
    points: np.ndarray, log_ratio: np.ndarray, queries: np.ndarray, k: int, leave_one_out: bool = False
) -> np.ndarray:
    """The local scale of the error estimate at each query: the mean of ``log_ratio`` over the ``k`` nearest
    ``points`` (Euclidean, in :func:`local_points` coordinates), shape (Q,).

    ``log_ratio`` (N,) are the logs of true one-step error over estimate at held-out samples ``points`` (N, q);
    the power function says where data are sparse, not where the flow map is hard to learn, so the estimate is
    rescaled by what the fit's own errors near the query were.  ``leave_one_out``: the queries are the points
    themselves, each without its own ratio (the calibration's).  ``O(Q N q)`` time, ``O(chunk N)`` memory
    (:func:`nearest`).
    """
    return log_ratio[nearest(points, queries, k, leave_one_out)].mean(axis=1)


def _prior_at_points(sur, z: np.ndarray, mu: np.ndarray, dt: np.ndarray, chunk: int = 32) -> np.ndarray:
    """``K(z_i, z_i)`` (B, 2n, 2n), each point against itself, in chunks of ``chunk`` points (``O(B chunk (2n)^2)``
    kernel terms; the off-diagonal blocks of a chunk, computed with parameter factors 1, are discarded)."""
    b, dim = z.shape
    out = np.empty((b, dim, dim))
    for start in range(0, b, chunk):
        sl = slice(start, min(b, start + chunk))
        n = sl.stop - sl.start
        rows = _probes(sur, z[sl], mu[sl], dt[sl]).gradient_kernel_rows(z[sl], np.ones((n, n * dim)))
        out[sl] = rows.reshape(n, dim, n, dim)[np.arange(n), :, np.arange(n), :]
    return out


def newton_rows(sur, xi: np.ndarray, mu: np.ndarray, dt: np.ndarray, chol: np.ndarray) -> np.ndarray:
    """The Newton basis ``V(z) = L^-1 k(z)`` of the gradient components at the points, shape (B, 2n, m).

    ``sum_j V_aj^2 = K_aa - P_a^2`` (:meth:`~sympredict.interpolation.surrogate.HBSurrogate.power_function`).
    ``O(B 2n m^2)``.
    """
    b, dim, m = len(xi), sur.dim, sur.n_centers
    out = np.empty((b, dim, m))
    step = max(1, (1 << 19) // max(1, m * dim))
    for start in range(0, b, step):
        sl = slice(start, min(b, start + step))
        rows = sur.gradient_kernel_rows(xi[sl], sur.parameter_factor(mu[sl], dt[sl]))
        v = solve_triangular(chol, rows.reshape(-1, m).T, lower=True, check_finite=False)
        out[sl] = v.T.reshape(-1, dim, m)
    return out


def local_covariance(sur, xi: np.ndarray, mu: np.ndarray, dt: np.ndarray, chol: np.ndarray) -> np.ndarray:
    """Posterior covariance ``C(z, z) = K(z, z) - V(z) V(z)^T`` of the gradient at each point, (B, 2n, 2n).

    Its diagonal is the squared power function.  ``O(B 2n m^2)``.
    """
    v = newton_rows(sur, xi, mu, dt, chol)
    return mixed_covariance(_prior_at_points(sur, xi, mu, dt) - np.matmul(v, v.transpose(0, 2, 1)))


def mixed_covariance(cov: np.ndarray) -> np.ndarray:
    """The one-step covariance of the estimate's error model, ``(C + diag(P^2)) / 2`` (B, 2n, 2n), from the
    posterior covariance ``C`` at the points: the two halves of :class:`CovariancePropagation` at one step."""
    p2 = np.maximum(np.diagonal(cov, axis1=1, axis2=2), 0.0)
    out = 0.5 * cov
    idx = np.arange(cov.shape[1])
    out[:, idx, idx] += 0.5 * p2
    return out


def _norm_units(cov: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """``sqrt(tr(D^-1 Sigma D^-1))`` of covariances (B, 2n, 2n) in scaled coordinates, in the states' units."""
    var = np.einsum("bii,i->b", cov, 1.0 / scale**2)
    return np.sqrt(np.maximum(var, 0.0))


def local_error_units(sens: np.ndarray, cov: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """One step's error estimate before calibration, ``sqrt(tr(S C S^T))`` in the states' units, (B,).

    ``sens`` (B, 2n, 2n): ``d x1 / d g``; ``cov`` (B, 2n, 2n): :func:`local_covariance`; ``scale`` (2n,).
    """
    return _norm_units(np.matmul(np.matmul(sens, cov), sens.transpose(0, 2, 1)), scale)


class CovariancePropagation:
    """The linearised error's covariance along ``B`` rollouts, one step at a time.

    The recursion over the steps ``k -> k+1`` (``D = D Phi_k``, ``S = S_k = d x1 / d g``,
    ``Y = sum_l<k M_k,l K(z_l, z_k)``):

        Q <- D Q D^T + D Y S^T + S Y^T D^T + S K(z_k, z_k) S^T,   W <- D W + S V(z_k),
        M_k+1,l = D M_k,l,  M_k+1,k = S,                          Sigma = Q - W W^T,

    so that ``Sigma_K = sum_k,l M_K,k C(z_k, z_l) M_K,l^T`` with ``C = K - V V^T``.  The error model is the
    mixture, with equal weights, of this field and one that is constant in the coordinates along the rollout,
    ``delta g(z_k) = diag(P(z_k)) xi`` with one ``xi`` for all steps (``P`` the power function), propagated as
    ``F <- D F + S diag(P(z_k))``: the covariance returned is ``(Sigma_K + F F^T) / 2``.  The kernel's posterior
    correlation carries errors that the flow transports (a phase error along a periodic orbit); the
    fixed-coordinate part keeps the error that persists in one direction while the trajectory moves across
    the posterior's correlation length (slow drifts, the early steps of an exponential growth).  Step ``k``
    costs ``O(B k (2n)^3)``; memory ``O(B K (2n)^2 + B 2n m)`` for ``K`` steps.

    Parameters
    ----------
    b, dim, m : int
        Instances, state dimension, Newton basis size (0: a prior without data).
    n_steps : int
        Steps at most.
    """

    def __init__(self, b: int, dim: int, m: int, n_steps: int):
        self.q = np.zeros((b, dim, dim))
        self.w = np.zeros((b, dim, m))
        self.f = np.zeros((b, dim, dim))
        self.stack = np.zeros((b, n_steps, dim, dim))  # M_k,l for l < k
        self.k = 0

    def advance(self, d: np.ndarray, s: np.ndarray, v: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """One step; returns the covariance ``Sigma`` (B, 2n, 2n) of the error after it.

        ``d``, ``s`` (B, 2n, 2n): the step's Jacobian and sensitivity; ``v`` (B, 2n, m): the Newton basis at its
        evaluation point ``z_k``; ``rows`` (B, 2n, k+1, 2n): the prior covariances ``K(z_k, z_l)``, ``l <= k``.
        """
        k, stack = self.k, self.stack
        y = np.einsum("blic,balc->bia", stack[:, :k], rows[:, :, :k, :])
        dy_s = np.matmul(np.matmul(d, y), s.transpose(0, 2, 1))
        self.q = (
            np.matmul(np.matmul(d, self.q), d.transpose(0, 2, 1))
            + dy_s
            + dy_s.transpose(0, 2, 1)
            + np.matmul(np.matmul(s, rows[:, :, k, :]), s.transpose(0, 2, 1))
        )
        self.w = np.matmul(d, self.w) + np.matmul(s, v)
        power = np.sqrt(
            np.maximum(np.diagonal(rows[:, :, k, :], axis1=1, axis2=2) - np.einsum("bam,bam->ba", v, v), 0.0)
        )
        self.f = np.matmul(d, self.f) + s * power[:, None, :]
        if k:
            stack[:, :k] = np.matmul(d[:, None], stack[:, :k])
        stack[:, k] = s
        self.k = k + 1
        return 0.5 * (self.correlated + self.fixed)

    @property
    def correlated(self) -> np.ndarray:
        """The kernel part ``Sigma_K = Q - W W^T`` (B, 2n, 2n): the errors correlated as the posterior says."""
        return self.q - np.matmul(self.w, self.w.transpose(0, 2, 1))

    @property
    def fixed(self) -> np.ndarray:
        """The fixed-coordinate part ``F F^T`` (B, 2n, 2n): one error vector, scaled by the power function."""
        return np.matmul(self.f, self.f.transpose(0, 2, 1))


#: Steps above which :func:`rollout_error_units` factorises the posterior covariance along each trajectory
#: (``method="auto"``); up to it the exact recursion over all pairs of steps is cheaper than the factorisation.
EXACT_MAX_STEPS = 1000
#: Candidate gradient functionals (points x 2n) from which the landmarks are pivoted, per trajectory.
_CANDIDATES = 2048
#: Landmark functionals at most (the rank of the factorisation).
_RANK_MAX = 512
#: Relative residual variance at which the pivoted Cholesky of the candidates stops.
_RANK_TOL = 1e-8


def posterior_covariance(sur, chol, z_rows, z_cols, mu, dt, v_rows=None, v_cols=None) -> np.ndarray:
    """``C(z_i, z'_j) = K(z_i, z'_j) - V(z_i) V(z'_j)^T`` of one instance, (R, 2n, C, 2n).

    :func:`prior_covariance` minus the Newton basis products (:func:`newton_rows`, computed unless given).
    """

    def basis(z):
        n = len(z)
        return newton_rows(sur, z, np.repeat(np.reshape(mu, (1, -1)), n, axis=0), np.full(n, float(dt)), chol)

    v_rows = basis(z_rows) if v_rows is None else v_rows
    v_cols = basis(z_cols) if v_cols is None else v_cols
    return prior_covariance(sur, z_rows, z_cols, mu, dt) - np.tensordot(v_rows, v_cols, axes=([2], [2]))


def pivoted_cholesky(mat: np.ndarray, rank_max: int, tol: float) -> tuple:
    """Greedy pivoted Cholesky of a positive semidefinite ``mat`` (N, N): ``(pivots (r,), factor (r, r))``.

    Picks the largest residual diagonal until it falls below ``tol`` times the largest diagonal or ``r``
    reaches ``rank_max``; ``mat[p][:, p] = factor factor^T`` (lower).  ``O(N r^2)``.
    """
    n = len(mat)
    diag = np.clip(np.diagonal(mat).copy(), 0.0, None)
    top = float(diag.max()) if n else 0.0
    cols = np.zeros((n, min(rank_max, n)))
    pivots = []
    for j in range(cols.shape[1]):
        p = int(np.argmax(diag))
        if top <= 0.0 or diag[p] <= tol * top:
            break
        col = (mat[:, p] - cols[:, :j] @ cols[p, :j]) / np.sqrt(diag[p])
        cols[:, j] = col
        diag = np.clip(diag - col**2, 0.0, None)
        diag[p] = 0.0
        pivots.append(p)
    pivots = np.asarray(pivots, dtype=int)
    return pivots, cols[pivots][:, : len(pivots)]


class LowRankPropagation:
    """The linearised error's covariance along ``B`` rollouts with the posterior factorised: linear in the steps.

    Along each trajectory the posterior covariance of the gradient is replaced by its landmark (Nystrom)
    factorisation plus the exact remainder of each point's own covariance,

        C(z_k, z_l) ~ A_k^T A_l + [k = l] R_k,   A_k = L_pp^-1 C(p, z_k)  (r, 2n),   R_k = C(z_k, z_k) - A_k^T A_k,

    ``p`` the landmark functionals pivoted from the trajectory's own evaluation points (all of them, or an
    evenly spaced subset on long horizons; :func:`pivoted_cholesky`), ``L_pp`` their factor.  The diagonal
    blocks are exact (the power function is kept), the remainder is positive semidefinite and its
    correlations between steps are dropped (a step's unexplained part adds as an independent error).  Then

        G <- D G + S A_k^T,   Q <- D Q D^T + S R_k S^T,   Sigma_K = G G^T + Q,

    the same sum ``sum_k,l M_K,k C(z_k, z_l) M_K,l^T`` as :class:`CovariancePropagation` with the factorised
    ``C``; with every pair of functionals among the landmarks it is that sum up to round-off.  The fixed-coordinate
    part and the mixture are :class:`CovariancePropagation`'s.  Step costs ``O(B (2n)^2 r)``; memory
    ``O(B 2n r)``.
    """

    def __init__(self, b: int, dim: int, rank: int):
        self.g = np.zeros((b, dim, rank))
        self.q = np.zeros((b, dim, dim))
        self.f = np.zeros((b, dim, dim))

    def advance(self, d, s, a, resid, power) -> np.ndarray:
        """One step; ``d``, ``s`` (B, 2n, 2n), ``a`` (B, r, 2n), ``resid`` (B, 2n, 2n), ``power`` (B, 2n)."""
        st = s.transpose(0, 2, 1)
        self.g = np.matmul(d, self.g) + np.matmul(s, a.transpose(0, 2, 1))
        self.q = np.matmul(np.matmul(d, self.q), d.transpose(0, 2, 1)) + np.matmul(np.matmul(s, resid), st)
        self.f = np.matmul(d, self.f) + s * power[:, None, :]
        corr = np.matmul(self.g, self.g.transpose(0, 2, 1)) + self.q
        return 0.5 * (corr + np.matmul(self.f, self.f.transpose(0, 2, 1)))


def _landmarks(sur, chol, z: np.ndarray, mu: np.ndarray, dt: float) -> tuple:
    """Landmark points (P, 2n), component of each landmark functional and its point (r,), factor (r, r)."""
    n_steps, dim = z.shape
    n_cand = max(1, _CANDIDATES // dim)
    idx = np.unique(np.linspace(0, n_steps - 1, min(n_steps, n_cand)).round().astype(int))
    zc = z[idx]
    vc = newton_rows(sur, zc, np.repeat(np.reshape(mu, (1, -1)), len(zc), axis=0), np.full(len(zc), float(dt)), chol)
    cov = posterior_covariance(sur, chol, zc, zc, mu, dt, vc, vc).reshape(len(zc) * dim, len(zc) * dim)
    pivots, factor = pivoted_cholesky(0.5 * (cov + cov.T), _RANK_MAX, _RANK_TOL)
    points, where = np.unique(pivots // dim, return_inverse=True)
    return zc[points], where, pivots % dim, factor


def rollout_error_units(
    fitted,
    traj: np.ndarray,
    mu: np.ndarray,
    dt: np.ndarray,
    weights: np.ndarray,
    method: str = "auto",
    local: np.ndarray = None,
    jacobians=None,
) -> np.ndarray:
    """Error estimates before calibration (B, K+1) along predicted trajectories ``traj`` (B, K+1, 2n).

    ``sqrt(tr Sigma_k)`` in the states' units; ``fitted`` is the
    :class:`~sympredict.estimators.fitted.FittedSymplecticFlowMap` (its surrogate, update rule, regularisation
    and scale); ``mu`` (B, d_mu), ``dt`` (B,), ``weights`` (B, m).  ``method``: ``"exact"``, every pair of steps
    (:class:`CovariancePropagation`, ``O(B K^2 (2n)^3)``); ``"lowrank"``, the posterior factorised on landmarks
    along each trajectory (:class:`LowRankPropagation`, linear in ``K``); ``"auto"``: exact up to
    :data:`EXACT_MAX_STEPS` steps.  ``local`` (B, K), optional: each step's local scale (a factor on its gradient
    error, so ``C(z_k, z_l)`` becomes ``s_k s_l C(z_k, z_l)``; :func:`local_log_ratio`).  ``jacobians``, optional:
    ``jacobians(k0, jac)`` is called with each block's step Jacobians ``jac`` (B, nk, 2n, 2n) (scaled coordinates,
    steps ``k0 .. k0 + nk - 1``, in order), so that other parts of the estimate reuse them
    (:class:`ResidualNeighbours`) instead of evaluating the Hessians again.  Cost: see the module.
    """
    sur, rule, scale = fitted.surrogate, fitted.rule, fitted.scale
    chol = sur.gram_factor(fitted.regularization)
    b, k1, dim = traj.shape
    m = sur.n_centers
    n_steps = max(k1 - 1, 0)
    if method not in ("auto", "exact", "lowrank"):
        raise ValueError(f"method must be 'auto', 'exact' or 'lowrank', got {method!r}")
    if method == "lowrank" or (method == "auto" and n_steps > EXACT_MAX_STEPS):
        if n_steps > EXACT_MAX_STEPS:
            _log.info(
                "error estimate along %d rollouts of %d steps: posterior factorised on at most %d landmarks "
                "per trajectory (linear in the steps)",
                b,
                n_steps,
                _RANK_MAX,
            )
        return _rollout_error_lowrank(fitted, chol, traj, mu, dt, weights, factors=local, jacobians=jacobians)
    z_all = np.empty((b, n_steps, dim))
    out = np.zeros((b, k1))
    prop = CovariancePropagation(b, dim, m, n_steps)
    block = max(1, min(n_steps, _BLOCK_ENTRIES // max(1, b * dim * dim * k1)))
    for k0 in range(0, n_steps, block):
        kk = min(n_steps, k0 + block)
        nk = kk - k0
        xs = (traj[:, k0:kk] * scale).reshape(-1, dim)
        x1s = (traj[:, k0 + 1 : kk + 1] * scale).reshape(-1, dim)
        rep = lambda a: np.repeat(a, nk, axis=0)
        xi, jac, sens = rule.linearization(sur, xs, x1s, rep(weights), rep(dt))
        v = newton_rows(sur, xi, rep(mu), rep(dt), chol).reshape(b, nk, dim, m)
        xi, jac, sens = xi.reshape(b, nk, dim), jac.reshape(b, nk, dim, dim), sens.reshape(b, nk, dim, dim)
        if jacobians is not None:
            jacobians(k0, jac)
        if local is not None:
            sens = sens * local[:, k0:kk, None, None]
        z_all[:, k0:kk] = xi
        # prior covariances of this block's points with every point so far (theirs included): (b, nk, 2n, kk, 2n)
        prior = np.stack([prior_covariance(sur, xi[i], z_all[i, :kk], mu[i], dt[i]) for i in range(b)])
        for i in range(nk):
            k = k0 + i
            sigma = prop.advance(jac[:, i], sens[:, i], v[:, i], prior[:, i, :, : k + 1, :])
            out[:, k + 1] = _norm_units(sigma, scale)
    return out


def _rollout_error_lowrank(fitted, chol, traj, mu, dt, weights, factors=None, jacobians=None) -> np.ndarray:
    """:func:`rollout_error_units` by :class:`LowRankPropagation`: landmarks per trajectory, then the steps in
    blocks of bounded memory.  ``O(B K 2n m^2)`` (the Newton basis at the steps) ``+ O(B K (2n)^2 r (2n + m))``
    ``+ O(B N r^2)`` (the pivoting over ``N`` candidates); memory ``O(B 2n (r + m) block)``."""
    sur, rule, scale = fitted.surrogate, fitted.rule, fitted.scale
    b, k1, dim = traj.shape
    m = sur.n_centers
    n_steps = k1 - 1
    out = np.zeros((b, k1))
    if n_steps <= 0:
        return out
    x0s = (traj[:, :-1] * scale).reshape(-1, dim)
    x1s = (traj[:, 1:] * scale).reshape(-1, dim)
    z_all = rule.variables(x0s, x1s, np.repeat(dt, n_steps))[0].reshape(b, n_steps, dim)
    marks = [_landmarks(sur, chol, z_all[i], mu[i], dt[i]) for i in range(b)]
    rank = max(1, max(len(mk[3]) for mk in marks))
    v_marks = [
        newton_rows(
            sur, mk[0], np.repeat(np.reshape(mu[i], (1, -1)), len(mk[0]), axis=0), np.full(len(mk[0]), dt[i]), chol
        )
        for i, mk in enumerate(marks)
    ]
    prop = LowRankPropagation(b, dim, rank)
    block = max(1, min(n_steps, _BLOCK_ENTRIES // max(1, b * dim * max(rank, m, dim))))
    for k0 in range(0, n_steps, block):
        kk = min(n_steps, k0 + block)
        nk = kk - k0
        rep = lambda a: np.repeat(a, nk, axis=0)
        xi, jac, sens = rule.linearization(
            sur,
            (traj[:, k0:kk] * scale).reshape(-1, dim),
            (traj[:, k0 + 1 : kk + 1] * scale).reshape(-1, dim),
            rep(weights),
            rep(dt),
        )
        v = newton_rows(sur, xi, rep(mu), rep(dt), chol)
        local = _prior_at_points(sur, xi, rep(mu), rep(dt)) - np.matmul(v, v.transpose(0, 2, 1))
        xi, v = xi.reshape(b, nk, dim), v.reshape(b, nk, dim, m)
        a = np.zeros((b, nk, rank, dim))
        for i, (pts, where, comp, factor) in enumerate(marks):
            if not len(comp):
                continue
            cross = posterior_covariance(sur, chol, pts, xi[i], mu[i], dt[i], v_rows=v_marks[i], v_cols=v[i])
            rows = cross[where, comp].reshape(len(comp), nk * dim)
            a[i, :, : len(comp)] = (
                solve_triangular(factor, rows, lower=True, check_finite=False).reshape(-1, nk, dim).transpose(1, 0, 2)
            )
        local = local.reshape(b, nk, dim, dim)
        resid = local - np.matmul(a.transpose(0, 1, 3, 2), a)
        power = np.sqrt(np.maximum(np.diagonal(local, axis1=2, axis2=3), 0.0))
        jac, sens = jac.reshape(b, nk, dim, dim), sens.reshape(b, nk, dim, dim)
        if jacobians is not None:
            jacobians(k0, jac)
        if factors is not None:
            sens = sens * factors[:, k0:kk, None, None]
        for j in range(nk):
            sigma = prop.advance(jac[:, j], sens[:, j], a[:, j], resid[:, j], power[:, j])
            out[:, k0 + j + 1] = _norm_units(sigma, scale)
    return out


#: Nearest residual vectors whose spread, carried through the later steps, is the residual part of the estimate.
RESIDUAL_NEIGHBOURS = 5


def propagated_residuals(jac: np.ndarray, resid: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """The model's own one-step residuals near each step, carried coherently through the later steps' Jacobians.

    ``resid`` (B, K, k, 2n): at step ``k`` the residual vectors ``Phi(x0_i) - x1_i`` of the ``k`` held-out samples
    nearest to the step's state (scaled coordinates), nearest first (:func:`nearest`: the ``i``-th nearest of one
    step and of the next make one draw); ``U_k = resid_k^T / sqrt(k)`` (2n, k) is their second-moment
    factor (``U_k U_k^T`` the neighbours' mean ``r r^T``).  One draw among the neighbours' residuals errs alike at
    every step (a systematic error near the orbit adds up, as the residuals of one model do along a trajectory),

        F_0 = 0,   F_k+1 = D Phi_k F_k + U_k,   e_k = |D^-1 F_k|_F,

    ``jac`` (B, K, 2n, 2n) the steps' Jacobians, ``scale`` (2n,) the model's scaling (``D``).  Returns (B, K+1),
    0 at step 0, in the states' units.  ``O(B K (2n)^2 k)``; memory ``O(B 2n k)`` besides the inputs
    (:class:`ResidualPropagation`, all steps as one block).
    """
    b, n_steps, k, dim = resid.shape
    prop = ResidualPropagation(b, dim, k, scale, n_steps)
    prop.advance(jac, resid)
    return prop.out


class ResidualPropagation:
    """:func:`propagated_residuals` block by block of steps: ``F_k+1 = D Phi_k F_k + U_k`` with ``F`` (B, 2n, k)
    carried from one block to the next, so that a rollout's Jacobians and neighbours are never all held at once.

    Parameters
    ----------
    b, dim, k : int
        Instances, state dimension, neighbours per step.
    scale : ndarray of shape (2n,)
        The model's scaling ``D`` (the residuals and Jacobians are in scaled coordinates).
    n_steps : int
        Steps of the rollout; :attr:`out` (B, K+1) holds the estimate in the states' units, 0 at step 0.

    Notes
    -----
    A block of ``nk`` steps costs ``O(B nk (2n)^2 k)``; memory ``O(B 2n k)`` for ``F`` plus the block's inputs
    ``O(B nk 2n (2n + k))``, besides :attr:`out`.
    """

    def __init__(self, b: int, dim: int, k: int, scale: np.ndarray, n_steps: int):
        self.f = np.zeros((b, dim, k))
        self.out = np.zeros((b, n_steps + 1))
        self.inv_scale2 = 1.0 / np.asarray(scale, dtype=float) ** 2
        self.step = 0

    def advance(self, jac: np.ndarray, resid: np.ndarray) -> None:
        """The next ``nk`` steps: ``jac`` (B, nk, 2n, 2n) their Jacobians, ``resid`` (B, nk, k, 2n) their
        neighbours' residual vectors (scaled coordinates, nearest first); fills ``out[:, j + 1]`` for them."""
        k = resid.shape[2]
        u = resid.transpose(0, 1, 3, 2) / np.sqrt(max(k, 1))
        f, k0 = self.f, self.step
        for j in range(resid.shape[1]):
            f = np.matmul(jac[:, j], f) + u[:, j]
            self.out[:, k0 + j + 1] = np.sqrt(np.einsum("bik,i->b", f * f, self.inv_scale2))
        self.f, self.step = f, k0 + resid.shape[1]


class ResidualNeighbours:
    """The residual part along ``B`` rollouts, step block by step block: for each block, the ``k`` residual vectors
    nearest to its states (:func:`nearest` in :func:`local_points` coordinates), carried by
    :class:`ResidualPropagation` with the block's Jacobians (the ones the posterior's linearisation computed).

    Parameters
    ----------
    points : ndarray of shape (N, q)
        The residual samples in :func:`local_points` coordinates (normalised once, at the calibration).
    vectors : ndarray of shape (N, 2n)
        Their residual vectors in scaled coordinates.
    k : int
        Neighbours per step.
    states : ndarray of shape (B, K, 2n)
        The steps' initial states in the states' units.
    mu : ndarray of shape (B, d_mu)
    dt : ndarray of shape (B,)
    domain : dict
        The training box (:func:`local_points`).
    scale : ndarray of shape (2n,)

    Notes
    -----
    A block of ``nk`` steps costs ``O(B nk N q)`` for the neighbours plus :class:`ResidualPropagation`'s; memory
    ``O(B nk (k 2n + q) + chunk N)`` for the block, ``O(B 2n k)`` carried, besides :attr:`out` (B, K+1).
    """

    def __init__(self, points, vectors, k, states, mu, dt, domain, scale):
        self.points, self.vectors, self.states = points, vectors, states
        self.mu, self.dt, self.domain = np.reshape(mu, (len(states), -1)), dt, domain
        b, n_steps, dim = states.shape
        self.k = max(1, min(int(k), len(points)))
        self.prop = ResidualPropagation(b, dim, self.k, scale, n_steps)

    @property
    def out(self) -> np.ndarray:
        """(B, K+1): the part so far, 0 at step 0 (before calibration's ``residual_scale``)."""
        return self.prop.out

    def __call__(self, k0: int, jac: np.ndarray) -> None:
        """The steps ``k0 .. k0 + nk - 1`` with their Jacobians ``jac`` (B, nk, 2n, 2n) (scaled coordinates)."""
        b, nk, dim = jac.shape[0], jac.shape[1], jac.shape[2]
        if k0 != self.prop.step:
            raise ValueError(f"the residual part's blocks come in order: expected step {self.prop.step}, got {k0}")
        query = local_points(
            self.states[:, k0 : k0 + nk].reshape(-1, dim),
            np.repeat(self.mu, nk, axis=0),
            np.repeat(self.dt, nk),
            self.domain,
        )
        near = nearest(self.points, query, self.k)
        self.prop.advance(jac, self.vectors[near].reshape(b, nk, near.shape[1], dim))


#: Quantile of the residual samples' own (leave-one-out) distances to their ``k``-th nearest other sample within
#: which the posterior part is cut to its share beside the residual part (:func:`posterior_share`).
SHARE_DISTANCE_QUANTILE = 0.9


def kth_distance(points: np.ndarray, queries: np.ndarray, k: int, leave_one_out: bool = False) -> np.ndarray:
    """Euclidean distance (Q,) of each query (Q, q) to its ``k``-th nearest of ``points`` (N, q) (:func:`nearest`,
    with its ``leave_one_out``).  ``O(Q N q)``."""
    near = nearest(points, queries, k, leave_one_out=leave_one_out)
    return np.sqrt(np.sum((queries - points[near[:, -1]]) ** 2, axis=1))


def posterior_share(distance: np.ndarray, share: float, reference: float) -> np.ndarray:
    """The posterior part's factor beside the residual part at states ``distance`` (any shape) from their ``k``-th
    nearest residual sample: ``share`` (in (0, 1]) within ``reference`` (the residual samples' own spacing, where
    the share was calibrated), rising linearly to 1 at twice it, 1 beyond (far from the residual samples only the
    posterior knows the error),

        g(d) = share + (1 - share) * clip(d / reference - 1, 0, 1).
    """
    return share + (1.0 - share) * np.clip(np.asarray(distance, dtype=float) / reference - 1.0, 0.0, 1.0)
