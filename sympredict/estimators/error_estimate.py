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
errors (the one-step estimate is the ``K = 1`` case, so one scale serves both).

Cost along ``B`` rollouts of ``K`` steps with ``m`` centres: the Newton basis at every step, ``O(B K 2n m^2)``
(as the power function), the prior covariances of all pairs of a trajectory's steps, ``O(B K^2 (2n)^2)`` kernel
terms, and the recursion ``O(B K^2 (2n)^3)``; memory ``O(B K (2n)^2 + B 2n m)``.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import solve_triangular

from sympredict.interpolation.surrogate import HBSurrogate

__all__ = [
    "CovariancePropagation",
    "mixed_covariance",
    "prior_covariance",
    "newton_rows",
    "local_covariance",
    "local_error_units",
    "rollout_error_units",
]

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


def rollout_error_units(fitted, traj: np.ndarray, mu: np.ndarray, dt: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Error estimates before calibration (B, K+1) along predicted trajectories ``traj`` (B, K+1, 2n).

    ``sqrt(tr Sigma_k)`` in the states' units, ``Sigma_k`` from :class:`CovariancePropagation`; ``fitted`` is the
    :class:`~sympredict.estimators.fitted.FittedSymplecticFlowMap` (its surrogate, update rule, regularisation
    and scale); ``mu`` (B, d_mu), ``dt`` (B,), ``weights`` (B, m).  Cost: see the module.
    """
    sur, rule, scale = fitted.surrogate, fitted.rule, fitted.scale
    chol = sur.gram_factor(fitted.regularization)
    b, k1, dim = traj.shape
    m = sur.n_centers
    n_steps = max(k1 - 1, 0)
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
        z_all[:, k0:kk] = xi
        # prior covariances of this block's points with every point so far (theirs included): (b, nk, 2n, kk, 2n)
        prior = np.stack([prior_covariance(sur, xi[i], z_all[i, :kk], mu[i], dt[i]) for i in range(b)])
        for i in range(nk):
            k = k0 + i
            sigma = prop.advance(jac[:, i], sens[:, i], v[:, i], prior[:, i, :, : k + 1, :])
            out[:, k + 1] = _norm_units(sigma, scale)
    return out
