"""Candidate linear functionals of generalized kernel interpolation and their Gramian columns.

A greedy (:mod:`sympredict.interpolation.greedy`) selects among ``N`` candidate functionals
``lambda_i``; what it needs of them is the diagonal ``G_ii`` of the generalized
Gramian ``G_ij = lambda_i^(1) lambda_j^(2) k`` and single columns of it.  Two
kinds live on points ``(x_p, mu_p, dT_p)`` of the augmented domain:

* :class:`HBFunctionals`: state derivatives ``d/dxi_a`` at the points
  (gradient Hermite-Birkhoff interpolation: the symplectic predictor);
* :class:`ValueFunctionals`: point evaluations (the direct model).

:func:`functional_residuals` evaluates an HB interpolant at every candidate
(the check of a greedy's claimed residual); :func:`dense_interpolation` is the
dense reference solve for small sets.
"""

from __future__ import annotations

from typing import Optional, Protocol

import numpy as np
from scipy.linalg import cho_factor, cho_solve

from sympredict import _numba
from sympredict.interpolation import _compiled
from sympredict.kernels import ProductKernel

__all__ = ["FunctionalSet", "HBFunctionals", "ValueFunctionals", "functional_residuals", "dense_interpolation"]

#: Points per chunk when a Gramian column is built (keeps the temporaries in cache).
_COLUMN_CHUNK = 8192


class FunctionalSet(Protocol):
    """What the greedy needs of a set of candidate functionals."""

    n_functionals: int

    def diagonal(self) -> np.ndarray:
        """``G_ii`` for all candidates, shape (N,)."""

    def representer(self, i: int):
        """Data identifying functional ``i`` for :meth:`column` of *another* set."""

    def column(self, representer, out: np.ndarray) -> np.ndarray:
        """``lambda_i^(1) lambda^(2) k`` for all candidates ``i`` of this set, into ``out`` (N,)."""


class _AugmentedPoints:
    """Points ``(x_p, mu_p, dT_p)`` of the augmented domain and their parameter factors."""

    def __init__(self, kernel: ProductKernel, points, mu, dt):
        self.kernel = kernel
        self.points = np.ascontiguousarray(points, dtype=float)
        n_points = len(self.points)
        self.mu = np.asarray(mu, dtype=float).reshape(n_points, -1)
        self.dt = np.asarray(dt, dtype=float).reshape(n_points)

    def _chunks(self):
        for start in range(0, len(self.points), _COLUMN_CHUNK):
            yield slice(start, start + _COLUMN_CHUNK)

    def _parameter_factor(self, sl, mu_q, dt_q) -> np.ndarray:
        """``k_mu(mu_p, mu_q) k_dT(dT_p, dT_q)`` for the points in ``sl``, shape (chunk,)."""
        return self.kernel.parameter_factor(self.mu[sl], self.dt[sl], mu_q[None, :], np.atleast_1d(dt_q))[:, 0]


class HBFunctionals(_AugmentedPoints):
    """State-derivative functionals ``d/dxi_a`` at augmented points ``(xi_p, mu_p, dT_p)``.

    The flat candidate index is ``i = p * 2n + a`` (point ``p``, component ``a``).

    Parameters
    ----------
    kernel
        Product kernel on ``(xi, mu, dT)``.
    xi : ndarray of shape (M, 2n)
        The points' state variables: mixed ``(q0, p1)`` or midpoints ``(x0 + x1) / 2`` (the update's).
    mu : ndarray of shape (M, d_mu)
    dt : ndarray of shape (M,)
    """

    def __init__(self, kernel: ProductKernel, xi, mu, dt):
        super().__init__(kernel, xi, mu, dt)
        self.dim = self.points.shape[1]
        self.n_functionals = len(self.points) * self.dim
        self._parameter_groups = None  # distinct (mu, dT) and each point's group, made on first use
        # compiled column where it is bit-identical to the NumPy one (2n = 2, IMQ factors)
        # (the compiled kernels know no periodic coordinates)
        self._compiled_column = kernel.periodic is None and _compiled.hb_column_supported(
            kernel, self.dim, self.mu.shape[1]
        )
        if kernel.periodic is not None:
            kernel.periodic.check_dim(self.dim)
        if kernel.symmetry is not None:
            kernel.symmetry.check_dim(self.dim)

    def diagonal(self) -> np.ndarray:
        symmetry = self.kernel.symmetry
        if symmetry is not None:  # depends on the point: k_G(x, x) sums over the images g x
            pts = np.repeat(self.points, self.dim, axis=0)
            return symmetry.hb_diagonal(
                self.kernel.state, pts, np.tile(np.arange(self.dim), len(self.points)), self.kernel.periodic
            )
        # r = 0: d/dx_a d/dy_a k = -A(0); the parameter factors are 1 on the diagonal
        A0, _ = self.kernel.state.factors(np.zeros(1), order=2)
        return np.full(self.n_functionals, -A0[0])

    def representer(self, i: int):
        p, a = divmod(int(i), self.dim)
        return self.points[p], self.mu[p], self.dt[p], a

    def column(self, representer, out: np.ndarray) -> np.ndarray:
        """Gramian column ``w_p (-B d_pa d_pb - A delta_ab)``, ``d_p = xi_p - xi_q``.

        With periodic coordinates ``w_p (-B g_pa g_pb - A g'_pb delta_ab)``
        (:class:`~sympredict.kernels.PeriodicCoordinates`).
        With a state symmetry (:class:`~sympredict.kernels.StateSymmetry`) the
        weighted sum of these plain columns over its :meth:`~sympredict.kernels.StateSymmetry.terms`.
        ``out`` has shape (N,) and is filled in chunks of points.
        """
        symmetry = self.kernel.symmetry
        if symmetry is None:
            return self._plain_column(representer, out)
        xi_q, mu_q, dt_q, b = representer
        out[:] = 0.0
        tmp = np.empty_like(out)
        for z, c, w in symmetry.terms(np.asarray(xi_q, dtype=float)[None, :], np.array([b])):
            out += w[0] * self._plain_column((z[0], mu_q, dt_q, c), tmp)
        return out

    def _plain_column(self, representer, out: np.ndarray) -> np.ndarray:
        """The column of the plain (not group-averaged) state kernel (see :meth:`column`)."""
        if self._compiled_column:
            return _compiled.hb_column(self.kernel, self.points, self.mu, self.dt, representer, out)
        xi_q, mu_q, dt_q, b = representer
        out2 = out.reshape(-1, self.dim)
        periodic = self.kernel.periodic
        for sl in self._chunks():
            diff = self.points[sl] - xi_q
            if periodic is None:
                r, g1 = np.sqrt(np.einsum("pa,pa->p", diff, diff)), None
            else:
                r, diff, g1 = periodic.terms(diff, order=2)
            A, B = self.kernel.state.factors(r, order=2)
            w = self._parameter_factor(sl, mu_q, dt_q)
            blk = out2[sl]
            np.multiply(diff, (-(w * B) * diff[:, b])[:, None], out=blk)
            blk[:, b] -= w * A if g1 is None else w * A * g1[:, b]
        return out

    def gram_rows(self, others: "HBFunctionals", indices: np.ndarray, out: np.ndarray) -> np.ndarray:
        """Gramian rows ``lambda_{i_k}^(1) lambda^(2) k`` of functionals of ``others`` against all of this set.

        The same numbers as ``column(others.representer(i_k))`` for every ``k``,
        vectorised over ``k`` (one call instead of ``len(indices)``).

        Parameters
        ----------
        others
            The set the functionals ``i_k`` belong to (same kernel).
        indices : ndarray of shape (K,), int
            Flat indices into ``others``.
        out : ndarray of shape (K, N)

        Notes
        -----
        ``O(K N)`` work, chunked over this set's points (``K x 1024 x 2n`` temporaries).
        """
        pts, comps = np.divmod(np.asarray(indices, dtype=np.int64), self.dim)
        xq, mq, dq = others.points[pts], others.mu[pts], others.dt[pts]
        symmetry = self.kernel.symmetry
        if symmetry is None:
            return self._plain_rows(xq, mq, dq, comps, out)
        # group-averaged kernel: the weighted plain rows of the terms (StateSymmetry.terms)
        out[:] = 0.0
        tmp = np.empty_like(out)
        for z, c, w in symmetry.terms(xq, comps):
            self._plain_rows(z, mq, dq, np.full(len(pts), c), tmp)
            tmp *= w[:, None]
            out += tmp
        return out

    def _plain_rows(self, xq, mq, dq, comps, out: np.ndarray) -> np.ndarray:
        """:meth:`gram_rows` of the plain state kernel for query points ``xq`` (K, 2n) and components ``comps`` (K,)."""
        out3 = out.reshape(len(xq), -1, self.dim)
        rows = np.arange(len(xq))
        step = 1024
        for start in range(0, len(self.points), step):
            sl = slice(start, start + step)
            diff = self.points[None, sl, :] - xq[:, None, :]
            if self.kernel.periodic is None:
                r, g1 = np.sqrt(np.einsum("kpa,kpa->kp", diff, diff)), None
            else:
                r, diff, g1 = self.kernel.periodic.terms(diff, order=2)
            A, B = self.kernel.state.factors(r, order=2)
            w = self.kernel.parameter_factor(mq, dq, self.mu[sl], self.dt[sl])
            blk = out3[:, sl]
            np.multiply(diff, (-(w * B) * diff[rows, :, comps])[:, :, None], out=blk)
            blk[rows, :, comps] -= w * A if g1 is None else w * A * g1[rows, :, comps]
        return out


class ValueFunctionals(_AugmentedPoints):
    """Point evaluations ``f -> f(x_p, mu_p, dT_p)`` (the direct model's functionals).

    Gramian entries are plain kernel values ``k_x(x_p, x_q) k_mu k_dT``; the
    diagonal is ``phi(0) = 1``.

    Parameters
    ----------
    kernel
        Product kernel on ``(x, mu, dT)``.
    x : ndarray of shape (M, 2n)
    mu : ndarray of shape (M, d_mu)
    dt : ndarray of shape (M,)
    """

    def __init__(self, kernel: ProductKernel, x, mu, dt):
        if kernel.symmetry is not None:
            raise ValueError("point-evaluation functionals (the direct model) do not support a state symmetry")
        super().__init__(kernel, x, mu, dt)
        self.n_functionals = len(self.points)

    def diagonal(self) -> np.ndarray:
        return np.full(self.n_functionals, float(self.kernel.state.phi(np.zeros(1))[0]))

    def representer(self, i: int):
        return self.points[i], self.mu[i], self.dt[i]

    def column(self, representer, out: np.ndarray) -> np.ndarray:
        x_q, mu_q, dt_q = representer
        for sl in self._chunks():
            diff = self.points[sl] - x_q
            periodic = self.kernel.periodic
            r = np.sqrt(np.einsum("pa,pa->p", diff, diff)) if periodic is None else periodic.distances(diff)
            out[sl] = self._parameter_factor(sl, mu_q, dt_q) * self.kernel.state.phi(r)
        return out


def functional_residuals(
    functionals: HBFunctionals,
    targets: np.ndarray,
    selected: np.ndarray,
    coef: np.ndarray,
    points: Optional[np.ndarray] = None,
    compiled: Optional[bool] = None,
) -> np.ndarray:
    """Residuals ``y_i - lambda_i(s)`` of an HB interpolant at *every* candidate, by direct evaluation.

    Independent of the Newton basis: this is the check of a greedy run's
    claimed residual (float32 basis, active-set training) against the model
    that is actually returned.

    Parameters
    ----------
    functionals
        The ``N = M 2n`` state-derivative functionals (:class:`HBFunctionals`).
    targets : ndarray of shape (N,)
    selected : ndarray of shape (m,), int
        Flat indices of the centres (``point * 2n + component``).
    coef : ndarray of shape (m,)
        Kernel-basis coefficients.
    points : ndarray of shape (P,), int, optional
        Evaluate at these points only (all their ``2n`` functionals).
    compiled
        Use the compiled evaluation (default: when numba is installed and the kernel has no periodic
        coordinates or state symmetry, which only the NumPy evaluation supports); both agree to round-off.

    Returns
    -------
    ndarray of shape (N,) (or (P * 2n,) with ``points``)

    Notes
    -----
    ``O(M m 2n)`` flops.  Compiled (numba): points are grouped by their
    distinct ``(mu, dT)`` (15 on the pendulum), so the parameter weights cost
    ``O(G m)``, not ``O(M m)``, and the points run in parallel.  NumPy: the
    Gramian rows of the centres (:meth:`HBFunctionals.gram_rows`) times the
    coefficients, in chunks of points (``O(m 2n chunk)`` memory).
    """
    dim = functionals.dim
    selected = np.asarray(selected, dtype=np.int64)
    coef = np.asarray(coef, dtype=float).reshape(-1)
    sel_pts, comps = np.divmod(selected, dim)
    idx = np.arange(len(functionals.points)) if points is None else np.asarray(points, dtype=np.int64)
    y = np.asarray(targets, dtype=float).reshape(len(functionals.points), dim)[idx]
    if len(selected) == 0:
        return y.reshape(-1).copy()
    if compiled and functionals.kernel.periodic is not None:
        raise ValueError(
            "functional_residuals: the compiled evaluation does not support periodic coordinates "
            "(periodic=...): pass compiled=False or None"
        )
    if compiled and functionals.kernel.symmetry is not None:
        raise ValueError(
            "functional_residuals: the compiled evaluation does not support a state symmetry "
            "(symmetry=...): pass compiled=False or None"
        )
    plain = functionals.kernel.periodic is None and functionals.kernel.symmetry is None
    if plain and _numba.use_compiled(compiled):
        groups = functionals._parameter_groups
        if groups is None:  # computed once per set (a sort of M rows)
            uniq, group = np.unique(np.column_stack([functionals.mu, functionals.dt]), axis=0, return_inverse=True)
            groups = functionals._parameter_groups = (uniq, group.reshape(-1))
        uniq, group = groups
        kernel = functionals.kernel
        wg = kernel.parameter_factor(uniq[:, :-1], uniq[:, -1], functionals.mu[sel_pts], functionals.dt[sel_pts]) * coef
        layout = _compiled.CenterLayout(functionals.points[sel_pts], comps)
        grad = _compiled.gradients(functionals.points[idx], group[idx], wg, layout, kernel.state)
        return (y - grad).reshape(-1)
    out = np.empty(y.shape)
    step = max(1, (1 << 22) // (len(selected) * dim))  # (m, chunk 2n) Gramian rows of about 32 MB
    for start in range(0, len(idx), step):
        part = idx[start : start + step]
        sub = HBFunctionals(functionals.kernel, functionals.points[part], functionals.mu[part], functionals.dt[part])
        rows = sub.gram_rows(functionals, selected, out=np.empty((len(selected), sub.n_functionals)))
        out[start : start + step] = y[start : start + step] - (coef @ rows).reshape(-1, dim)
    return out.reshape(-1)


def dense_interpolation(functionals: HBFunctionals, targets: np.ndarray) -> np.ndarray:
    """Exact generalized interpolation on all ``N`` functionals by a dense solve (reference).

    Builds the ``N x N`` Gramian column by column and solves ``G c = y`` by
    Cholesky.  ``O(N^2)`` memory and ``O(N^3)`` time: for small data only.

    Parameters
    ----------
    functionals
        The ``N`` functionals.
    targets : ndarray of shape (N,) or (N, q)

    Returns
    -------
    ndarray of shape (N,) or (N, q)
        Kernel-basis coefficients for the functionals in their flat order.

    Raises
    ------
    numpy.linalg.LinAlgError
        If the Gramian is not numerically positive definite (duplicate or
        nearly dependent functionals): use the greedy instead.
    """
    n = functionals.n_functionals
    gram = np.empty((n, n))
    for j in range(n):
        functionals.column(functionals.representer(j), out=gram[:, j])
    gram = 0.5 * (gram + gram.T)
    return cho_solve(cho_factor(gram, lower=True), np.asarray(targets, dtype=float))
