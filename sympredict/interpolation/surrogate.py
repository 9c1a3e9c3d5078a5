"""The gradient Hermite–Birkhoff kernel surrogate ``s(xi, mu, dT)``.

A fitted surrogate is a linear combination of Riesz representers of
state-derivative functionals ``lambda_j f = d f / d xi_{l_j} (z_j)`` at the
augmented centres ``z_j = (xi_j, mu_j, dT_j)``:

.. math::

    s(\\xi, \\mu, \\Delta T) = \\sum_j c_j\\, k_\\mu(\\mu,\\mu_j)\\, k_{\\Delta T}(\\Delta T, \\Delta T_j)\\,
        \\partial^{(2)}_{\\xi_{l_j}} k_\\xi(\\xi, \\xi_j).

Since ``(mu, dT)`` enters only through multiplicative factors, the
evaluation routines take the per-query *weights*
``w_bj = c_j k_mu(mu_b, mu_j) k_dT(dT_b, dT_j)`` (see :meth:`HBSurrogate.weights`)
so that a rollout, where ``(mu, dT)`` is fixed per instance, forms them once.
"""

from __future__ import annotations

import numpy as np
from scipy import sparse
from scipy.linalg import cholesky, solve_triangular

from sympredict.interpolation._compiled import CenterLayout
from sympredict.kernels import ProductKernel

__all__ = ["HBSurrogate", "ValueSurrogate"]

#: Target number of float64 entries of the ``(chunk, m, 2n)`` difference array
#: per chunk (about 1 MB, so that the temporaries of an evaluation stay in L2);
#: measured 2.4x faster batched Newton steps than with 32 MB chunks.
_CHUNK_ENTRIES = 1 << 17


def _rows(values, m: int) -> np.ndarray:
    """``values`` as a C-contiguous float array of ``m`` rows (a 2-D array keeps its shape, so ``m = 0`` keeps its columns).

    C order whatever produced ``values`` (a LAPACK solve returns Fortran order): BLAS takes another
    kernel path for each layout, so a fitted and a loaded model would otherwise round differently.
    """
    arr = np.ascontiguousarray(values, dtype=float)
    return arr if arr.ndim == 2 else arr.reshape(m, -1)


def _distances_1d(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``|a_i - b_j|`` for one-component parameters as ``sqrt((a_i - b_j)^2)``, shape (Na, Nb).

    The same operations as :func:`sympredict.kernels.pairwise_distances` for one
    component (bit for bit), without its general-case overhead (the weights of a
    single query are on the latency path of :meth:`SymplecticKernelPredictor.step`).
    """
    d = a.reshape(-1, 1) - b.reshape(1, -1)
    # parameters near the float64 limit give inf distances, which the radial profiles map to
    # their limit, as pairwise_distances' einsum does without a warning
    with np.errstate(over="ignore"):
        np.square(d, out=d)
    return np.sqrt(d, out=d)


def _parameter_factor(kernel: ProductKernel, mu, dt, centers_mu, centers_dt) -> np.ndarray:
    """``kernel.parameter_factor`` (bit-identical), with a short path for one-component parameters."""
    mu = np.asarray(mu, dtype=float)
    dt = np.asarray(dt, dtype=float).reshape(-1)
    if kernel.mu is not None and (mu.ndim != 2 or mu.shape[1] != 1 or centers_mu.shape[1] != 1):
        return kernel.parameter_factor(mu, dt, centers_mu, centers_dt)
    out = None
    if kernel.mu is not None:
        out = kernel.mu.phi(_distances_1d(mu[:, 0], centers_mu[:, 0]))
    if kernel.dt is not None:
        kd = kernel.dt.phi(_distances_1d(dt, centers_dt))
        out = kd if out is None else out * kd
    if out is None:
        out = np.ones((len(dt), len(centers_dt)))
    return out


class HBSurrogate:
    """Fitted gradient-HB surrogate: centres, derivative components, coefficients.

    Parameters
    ----------
    kernel
        The product kernel.
    centers_xi : ndarray of shape (m, 2n)
        Mixed-variable parts ``xi_j = (q0_j, p1_j)`` of the centres.
    centers_mu : ndarray of shape (m, d_mu)
        Parameter parts (``d_mu`` may be 0 when the parameter factor is dropped).
    centers_dt : ndarray of shape (m,)
        Macro-step parts.
    components : ndarray of shape (m,), int
        State component ``l_j`` differentiated at centre ``j``.
    coef : ndarray of shape (m,)
        Kernel-basis coefficients ``c_j``.

    Notes
    -----
    Every evaluation costs ``O(B m 2n)`` (value, gradient) or
    ``O(B m (2n)^2)`` (Hessian) flops for ``B`` queries and is chunked over
    the queries so that temporaries stay near 1 MB (in cache).  With a state
    symmetry (``kernel.symmetry``, :class:`~sympredict.kernels.StateSymmetry`)
    the evaluation runs the same code over the ``K`` plain functionals of
    :meth:`~sympredict.kernels.StateSymmetry.expand` (``K = |G| m`` for signed
    permutations): ``|G|`` times the cost; the centres, components and
    coefficients stay those of the ``m`` centres.
    """

    def __init__(self, kernel: ProductKernel, centers_xi, centers_mu, centers_dt, components, coef):
        self.kernel = kernel
        self.centers_xi = np.ascontiguousarray(centers_xi, dtype=float)
        m, dim = self.centers_xi.shape
        self.centers_mu = _rows(centers_mu, m)
        self.centers_dt = np.ascontiguousarray(centers_dt, dtype=float).reshape(m)
        self.components = np.ascontiguousarray(components, dtype=np.int64).reshape(m)
        self.coef = np.ascontiguousarray(coef, dtype=float).reshape(m)
        # the plain functionals the evaluation sums over: the centres themselves, or with a state
        # symmetry their images g xi_j in the directions g e_{l_j} (StateSymmetry.expand), each
        # weighted by its g_{c l_j} and owned by its centre
        symmetry = kernel.symmetry
        if symmetry is None:
            self._owner, self._xi_eval, self._comp_eval, self._coef_eval = (
                None,
                self.centers_xi,
                self.components,
                self.coef,
            )
            self._image_weight = None
        else:
            symmetry.check_dim(dim)
            self._owner, self._xi_eval, self._comp_eval, self._image_weight = symmetry.expand(
                self.centers_xi, self.components
            )
            self._coef_eval = self._image_weight * self.coef[self._owner]
        k = len(self._xi_eval)
        # one-hot (K, 2n) matrix of the differentiated components: turns the
        # ``delta_{a l_j}`` terms into a small matrix product
        self._onehot = np.zeros((k, dim))
        self._onehot[np.arange(k), self._comp_eval] = 1.0
        self._flat_components = np.arange(k) * dim + self._comp_eval
        self._layout = None  # the compiled kernels' arrangement, made on first use

    @property
    def n_centers(self) -> int:
        return len(self.coef)

    @property
    def dim(self) -> int:
        """State dimension ``2n``."""
        return self.centers_xi.shape[1]

    def weights(self, mu: np.ndarray, dt: np.ndarray) -> np.ndarray:
        """Per-query centre weights ``w_bj = c_j k_mu(mu_b, mu_j) k_dT(dT_b, dT_j)``.

        With a state symmetry, one column per plain functional of the
        group-averaged kernel (:meth:`sympredict.kernels.StateSymmetry.expand`):
        ``c_j g_{c l_j} k_mu k_dT`` of its owning centre ``j``.

        Parameters
        ----------
        mu : ndarray of shape (B, d_mu)
        dt : ndarray of shape (B,)

        Returns
        -------
        ndarray of shape (B, m), or (B, K) with a symmetry (``K = |G| m`` for signed permutations)
        """
        factor = _parameter_factor(self.kernel, mu, dt, self.centers_mu, self.centers_dt)
        if self._owner is not None:
            factor = factor[:, self._owner]
        factor *= self._coef_eval
        return factor

    def _chunks(self, n_queries: int):
        step = max(1, _CHUNK_ENTRIES // max(1, len(self._xi_eval) * self.dim))
        for start in range(0, n_queries, step):
            yield slice(start, min(n_queries, start + step))

    def _differences(self, xi, order: int = 1):
        """Differences, distances and, with periodic coordinates, their derivative terms.

        Returns ``(diff, r, g)`` and, for ``order >= 2``, ``G1`` and the gather
        ``g1 = G1[..., l_j]`` (``order == 3``: also ``g2 = G2[..., l_j]``).
        ``diff`` (chunk, m, 2n) is ``x - x_j``, or ``G = g(x - x_j)`` with
        periodic coordinates (:meth:`sympredict.kernels.PeriodicCoordinates.terms`);
        ``G1``, ``g1``, ``g2`` are ``None`` without periodic coordinates (``g' = 1``,
        ``g'' = 0``: the plain formulas).
        """
        diff = xi[:, None, :] - self._xi_eval[None, :, :]
        periodic = self.kernel.periodic
        G1 = g1 = g2 = None
        if periodic is None:
            r = np.sqrt(np.einsum("bma,bma->bm", diff, diff))
        elif order == 1:
            r, diff = periodic.terms(diff, order=1)
        else:
            terms = periodic.terms(diff, order=order)
            r, diff, G1 = terms[:3]
            g1 = np.take(G1.reshape(len(xi), -1), self._flat_components, axis=1)
            if order == 3:
                g2 = np.take(terms[3].reshape(len(xi), -1), self._flat_components, axis=1)
        # g_bj = d_{b j l_j}: the difference in the centre's differentiated component
        # (one flat gather: faster than fancy indexing with two index arrays)
        g = np.take(diff.reshape(len(xi), -1), self._flat_components, axis=1)
        if order == 1:
            return diff, r, g
        return diff, r, g, G1, g1, g2

    @staticmethod
    def _abs_max_last(diff):
        """``max_a |diff[..., a]|`` by ``2n`` elementwise passes (a reduction over a short last axis is slow)."""
        out = np.abs(diff[..., 0])
        for a in range(1, diff.shape[-1]):
            np.maximum(out, np.abs(diff[..., a]), out=out)
        return out

    def layout(self):
        """The centres arranged for the compiled kernels (:class:`sympredict.interpolation._compiled.CenterLayout`), cached.

        The plain functionals the evaluation sums over: with a state symmetry the images ``g xi_j`` and
        their components (weights then have one column per image, :meth:`weights`), with periodic
        coordinates their periods.  The compiled pass then runs the formulas of the NumPy evaluation.
        """
        if self._layout is None:
            self._layout = CenterLayout(self._xi_eval, self._comp_eval, self.kernel.periodic)
        return self._layout

    def value(self, xi: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """Surrogate values ``s`` (``d/dy_l k = -A d_l``).

        Parameters
        ----------
        xi : ndarray of shape (B, 2n)
        weights : ndarray of shape (B, m)
            From :meth:`weights`.

        Returns
        -------
        ndarray of shape (B,)
        """
        out = np.empty(len(xi))
        for sl in self._chunks(len(xi)):
            diff, r, g = self._differences(xi[sl])
            A, _ = self.kernel.state.factors(r, order=2)
            out[sl] = -np.einsum("bm,bm->b", weights[sl], A * g)
        return out

    def gradient(self, xi: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """State gradient ``d s / d xi`` (``sum_j w_j (-B_j g_j d_j - A_j e_{l_j})``).

        Parameters
        ----------
        xi : ndarray of shape (B, 2n)
        weights : ndarray of shape (B, m)

        Returns
        -------
        ndarray of shape (B, 2n)
        """
        out = np.empty(xi.shape)
        for sl in self._chunks(len(xi)):
            diff, r, g, _, g1, _ = self._differences(xi[sl], order=2)
            A, B = self.kernel.state.factors(r, order=2)
            w = weights[sl]
            wA = w * A if g1 is None else w * A * g1  # periodic: -A g'_l delta_al
            out[sl] = -np.matmul((w * B * g)[:, None, :], diff)[:, 0, :] - wA @ self._onehot
        return out

    def gradient_hessian(self, xi: np.ndarray, weights: np.ndarray, with_floor: bool = False):
        """State gradient and Hessian of ``s`` in one pass over the centres.

        The Hessian uses the third kernel derivatives
        ``d_c d_a d^(2)_b k = -C d_a d_b d_c - B (delta_ac d_b + delta_bc d_a + delta_ab d_c)``
        with ``b = l_j``; summed over the centres this is

        ``H_ac = -sum_j w_j C_j g_j d_ja d_jc - delta_ac sum_j w_j B_j g_j - M_ac - M_ca``,
        ``M_ac = sum_j w_j B_j d_ja [l_j = c]``.

        With periodic coordinates (:class:`~sympredict.kernels.PeriodicCoordinates`)
        ``d`` becomes ``G = g(d)``, ``w_j B_j`` in ``M`` becomes ``w_j B_j g'_{j l_j}``,
        the ``delta_ac`` term becomes ``delta_ac sum_j w_j B_j g_j g'_ja``, and
        ``-delta_ac sum_j w_j A_j g''_{j l_j} [l_j = a]`` is added.

        Parameters
        ----------
        xi : ndarray of shape (B, 2n)
        weights : ndarray of shape (B, m)
        with_floor
            Also return a round-off bound of the gradient: ``eps_mach`` times the
            sum of the absolute values of its terms.  With coefficients of
            ``1e7`` the gradient cannot be evaluated more accurately than this,
            which is what Newton's stopping rule compares against.

        Returns
        -------
        grad : ndarray of shape (B, 2n)
        hess : ndarray of shape (B, 2n, 2n)
        floor : ndarray of shape (B,)
            Only if ``with_floor``.
        """
        n_q, dim = xi.shape
        grad = np.empty((n_q, dim))
        hess = np.empty((n_q, dim, dim))
        floor = np.empty(n_q) if with_floor else None
        eye = np.eye(dim)
        for sl in self._chunks(n_q):
            diff, r, g, G1, g1, g2 = self._differences(xi[sl], order=3)
            w = weights[sl]
            grad[sl], A, wA, wB, wBg, wCg = self._gradient_chunk(diff, r, g, g1, w)
            wCg_diff = diff * wCg[:, :, None]
            h = -np.matmul(wCg_diff.transpose(0, 2, 1), diff)
            if G1 is None:
                h -= wBg.sum(axis=1)[:, None, None] * eye
            else:
                diag = np.matmul(wBg[:, None, :], G1)[:, 0, :] + (w * A * g2) @ self._onehot
                h -= diag[:, :, None] * eye
            M = np.matmul((diff * wB[:, :, None]).transpose(0, 2, 1), self._onehot)
            h -= M
            h -= M.transpose(0, 2, 1)
            hess[sl] = h
            if with_floor:
                floor[sl] = self._gradient_floor(diff, wA, wBg)
        if with_floor:
            return grad, hess, floor
        return grad, hess

    def newton_terms(self, xi: np.ndarray, weights: np.ndarray):
        """What one Newton iteration of the implicit step needs, in one pass over the centres.

        The gradient, the block ``d_p d_q s`` of the Hessian (rows ``q``, columns
        ``p``) and the gradient's round-off floor (see :meth:`gradient_hessian`).
        Off the diagonal blocks ``delta_ac = 0``, so with ``g_j = d_{j l_j}``

        ``H_ac = -sum_j w_j C_j g_j d_ja d_jc - M_ac - M_ca``,  ``a < n <= c``,
        ``M_ac = sum_j w_j B_j d_ja [l_j = c]`` (periodic coordinates as in
        :meth:`gradient_hessian`: no ``delta_ac`` terms here).

        Parameters
        ----------
        xi : ndarray of shape (B, 2n)
            The Newton iterate's mixed variables ``(q0, p1)``.
        weights : ndarray of shape (B, m)

        Returns
        -------
        grad : ndarray of shape (B, 2n)
        hess_qp : ndarray of shape (B, n, n)
        floor : ndarray of shape (B,)

        Notes
        -----
        ``O(B m (2n + n^2))`` flops; temporaries ``O(chunk m 2n)`` (no
        ``(B, m, (2n)^2)`` arrays), chunked over the queries.
        """
        n_q, dim = xi.shape
        n = dim // 2
        grad = np.empty((n_q, dim))
        hqp = np.empty((n_q, n, n))
        floor = np.empty(n_q)
        onehot_p = self._onehot[:, n:]
        onehot_q = self._onehot[:, :n]
        for sl in self._chunks(n_q):
            diff, r, g, _, g1, _ = self._differences(xi[sl], order=2)
            grad[sl], _, wA, wB, wBg, wCg = self._gradient_chunk(diff, r, g, g1, weights[sl])
            dq = diff[:, :, :n]
            dp = diff[:, :, n:]
            h = -np.matmul((dq * wCg[:, :, None]).transpose(0, 2, 1), dp)
            # M_ac for a in q, c in p and M_ca (c in p, a in q): both (chunk, n, n)
            wBdq = (dq * wB[:, :, None]).transpose(0, 2, 1)
            h -= np.matmul(wBdq, onehot_p)
            h -= np.matmul((dp * wB[:, :, None]).transpose(0, 2, 1), onehot_q).transpose(0, 2, 1)
            hqp[sl] = h
            floor[sl] = self._gradient_floor(diff, wA, wBg)
        return grad, hqp, floor

    def _gradient_chunk(self, diff, r, g, g1, w):
        """A chunk's gradient rows and the weighted factors the Hessians reuse (:meth:`gradient_hessian`, :meth:`newton_terms`).

        Returns ``grad`` (chunk, 2n), ``A``, ``wA = w A`` and ``wB = w B`` (both times ``g'``
        for periodic coordinates: the identity terms carry it), ``wBg = w B g`` and ``wCg = w C g``.
        """
        A, B, C = self.kernel.state.factors(r, order=3)
        wA = w * A
        wB = w * B
        wBg = wB * g
        if g1 is not None:  # periodic: the identity terms carry g' (and g'')
            wA = wA * g1
            wB = wB * g1
        grad = -np.matmul(wBg[:, None, :], diff)[:, 0, :] - wA @ self._onehot
        return grad, A, wA, wB, wBg, w * C * g

    def _gradient_floor(self, diff, wA, wBg) -> np.ndarray:
        """``eps_mach`` times the sum of the absolute values of a chunk's gradient terms, shape (chunk,)."""
        return np.finfo(float).eps * (
            np.einsum("bm,bm->b", np.abs(wBg), self._abs_max_last(diff)) + np.abs(wA).sum(axis=1)
        )

    # ------------------------------------------------ power function (error estimate)
    def gradient_kernel_rows(self, xi: np.ndarray, factor: np.ndarray) -> np.ndarray:
        """Gramian rows ``K_a(xi)_j = lambda_a^(1) lambda_j^(2) k`` of the gradient components at queries.

        ``lambda_a`` is ``d/dxi_a`` at the query ``(xi_b, mu_b, dT_b)``, ``lambda_j`` the centre
        functionals: ``K_a(xi)_j = f_bj (-B_bj d_ba g_bj - A_bj delta_{a l_j})`` with ``d = xi - xi_j``,
        ``g = d_{l_j}`` (the terms :meth:`gradient` sums with the weights ``c_j f_bj``).  With a state
        symmetry the sum over the plain functionals of each centre (its images, weighted as in
        :meth:`weights`), with periodic coordinates the periodic differences and ``g'`` (as in
        :meth:`gradient`): ``sum_j c_j K_a(xi)_j`` is the gradient.

        Parameters
        ----------
        xi : ndarray of shape (B, 2n)
        factor : ndarray of shape (B, m)
            Parameter factors ``f_bj = k_mu(mu_b, mu_j) k_dT(dT_b, dT_j)`` (:meth:`parameter_factor`).

        Returns
        -------
        ndarray of shape (B, 2n, m)
        """
        out = np.empty((len(xi), self.dim, self.n_centers))
        if self._owner is not None:  # sums the images' rows into their centres' columns: (K, m) 0/1 matrix
            gather = sparse.csr_matrix(
                (np.ones(len(self._owner)), (np.arange(len(self._owner)), self._owner)),
                shape=(len(self._owner), self.n_centers),
            )
        for sl in self._chunks(len(xi)):
            diff, r, g, _, g1, _ = self._differences(xi[sl], order=2)
            A, B = self.kernel.state.factors(r, order=2)
            f = factor[sl] if self._owner is None else factor[sl][:, self._owner] * self._image_weight
            fA = f * A if g1 is None else f * A * g1  # periodic: -A g'_l delta_al, as in gradient
            rows = -(f * B * g)[:, None, :] * diff.transpose(0, 2, 1)
            rows -= fA[:, None, :] * self._onehot.T[None, :, :]
            if self._owner is None:
                out[sl] = rows
            else:
                out[sl] = (gather.T @ rows.reshape(-1, rows.shape[-1]).T).T.reshape(len(rows), self.dim, -1)
        return out

    def diagonal(self, xi: np.ndarray) -> np.ndarray:
        """``K_aa(z, z) = lambda_a^(1) lambda_a^(2) k`` at the queries (the parameter factors are 1 there), (B, 2n).

        ``-A(0)`` for a plain kernel; with a state symmetry it depends on the point (the images ``g z``), and
        periodic coordinates enter through ``g'`` (:meth:`HBFunctionals.diagonal`).  ``O(B 2n |G|)``.
        """
        xi = np.asarray(xi, dtype=float)
        if self.kernel.symmetry is None:
            a0, _ = self.kernel.state.factors(np.zeros(1), order=2)
            return np.full(xi.shape, -float(a0[0]))
        dim = self.dim
        return self.kernel.symmetry.hb_diagonal(
            self.kernel.state, np.repeat(xi, dim, axis=0), np.tile(np.arange(dim), len(xi)), self.kernel.periodic
        ).reshape(len(xi), dim)

    def parameter_factor(self, mu: np.ndarray, dt: np.ndarray) -> np.ndarray:
        """``k_mu(mu_b, mu_j) k_dT(dT_b, dT_j)`` (B, m): :meth:`weights` without the coefficients."""
        return _parameter_factor(self.kernel, mu, dt, self.centers_mu, self.centers_dt)

    def gram_factor(self, regularization: float = 0.0) -> np.ndarray:
        """Lower Cholesky factor ``L`` of the centres' Gramian ``G + lambda I``, shape (m, m), cached.

        ``G_ij = lambda_i^(1) lambda_j^(2) k`` of the selected functionals: the matrix whose factor the greedy
        built column by column (its Newton basis values at the centres); recomputed here from the centres so
        that a fitted and a loaded model use the same numbers.  ``O(m^2 2n)`` kernel terms and ``m^3 / 3``
        flops, ``8 m^2`` bytes.  A Gramian that round-off made indefinite gets a diagonal shift of
        ``1e-13 m G_ii`` (logged nowhere: it is far below the greedy's breakdown guard ``power_tol``).
        """
        key = float(regularization)
        cached = getattr(self, "_gram_cache", None)
        if cached is not None and cached[0] == key:
            return cached[1]
        m = self.n_centers
        gram = np.empty((m, m))
        step = max(1, _CHUNK_ENTRIES // max(1, m * self.dim))
        for start in range(0, m, step):
            sl = slice(start, min(m, start + step))
            rows = self.gradient_kernel_rows(
                self.centers_xi[sl], self.parameter_factor(self.centers_mu[sl], self.centers_dt[sl])
            )
            gram[sl] = rows[np.arange(sl.stop - sl.start), self.components[sl]]
        gram = 0.5 * (gram + gram.T)
        gram[np.diag_indices(m)] += key
        diag0 = float(gram[0, 0]) if m else 1.0
        try:
            chol = cholesky(gram, lower=True, check_finite=False)
        except np.linalg.LinAlgError:
            gram[np.diag_indices(m)] += 1e-13 * m * diag0
            chol = cholesky(gram, lower=True, check_finite=False)
        chol = np.ascontiguousarray(chol)
        self._gram_cache = (key, chol)
        return chol

    def power_function(self, xi: np.ndarray, mu: np.ndarray, dt: np.ndarray, chol: np.ndarray) -> np.ndarray:
        """Power function ``P_a`` of each gradient component at queries (the GP posterior standard deviation).

        ``P_a(z)^2 = K_aa(z, z) - k_a(z)^T G^-1 k_a(z)`` with ``k_a`` from :meth:`gradient_kernel_rows` and
        ``G = L L^T`` (:meth:`gram_factor`): ``|d_a s(z) - d_a s_m(z)| <= P_a(z) ||s - s_m||_H`` for every
        ``s`` of the native space.  Round-off can make ``P^2`` slightly negative: clipped at 0.

        Parameters
        ----------
        xi : ndarray of shape (B, 2n)
        mu : ndarray of shape (B, d_mu)
        dt : ndarray of shape (B,)
        chol : ndarray of shape (m, m)

        Returns
        -------
        ndarray of shape (B, 2n)

        Notes
        -----
        ``O(B 2n m^2)`` flops (a triangular solve with ``2n B`` right-hand sides, in chunks): for
        ``m = 1000`` centres and ``2n = 4`` about ``8e6`` flops per query, far more than a Newton step.
        """
        b, dim, m = len(xi), self.dim, self.n_centers
        k_diag = self.diagonal(xi)  # K_aa(z, z): the parameter factors are 1 at equal arguments
        if m == 0:
            return np.sqrt(k_diag)
        out = np.empty((b, dim))
        step = max(1, (1 << 19) // (m * dim))
        for start in range(0, b, step):
            sl = slice(start, min(b, start + step))
            rows = self.gradient_kernel_rows(xi[sl], self.parameter_factor(mu[sl], dt[sl]))
            v = solve_triangular(chol, rows.reshape(-1, m).T, lower=True, check_finite=False)
            p2 = k_diag[sl].reshape(-1) - np.einsum("ij,ij->j", v, v)
            out[sl] = np.sqrt(np.maximum(p2, 0.0)).reshape(-1, dim)
        return out


class ValueSurrogate:
    """Vector-valued kernel interpolant ``r(x, mu, dT) = sum_j c_j k((x, mu, dT), z_j)``, ``c_j in R^q``.

    The direct (non-symplectic) baseline's model of the step increment.

    Parameters
    ----------
    kernel
        The product kernel.
    centers_x : ndarray of shape (m, 2n)
        State parts of the centres (the direct model's points are the initial states ``x0``).
    centers_mu : ndarray of shape (m, d_mu)
    centers_dt : ndarray of shape (m,)
    coef : ndarray of shape (m, q)

    Notes
    -----
    Evaluation ``O(B m (2n + q))``, chunked over the queries.
    """

    def __init__(self, kernel: ProductKernel, centers_x, centers_mu, centers_dt, coef):
        self.kernel = kernel
        self.centers_x = np.ascontiguousarray(centers_x, dtype=float)
        m = len(self.centers_x)
        self.centers_mu = _rows(centers_mu, m)
        self.centers_dt = np.ascontiguousarray(centers_dt, dtype=float).reshape(m)
        self.coef = _rows(coef, m)

    @property
    def n_centers(self) -> int:
        return len(self.coef)

    def weights(self, mu: np.ndarray, dt: np.ndarray) -> np.ndarray:
        """Parameter factors ``k_mu(mu_b, mu_j) k_dT(dT_b, dT_j)``, shape (B, m)."""
        return self.kernel.parameter_factor(mu, dt, self.centers_mu, self.centers_dt)

    def value(self, x: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """``r(x)`` for queries (B, 2n) with weights (B, m); shape (B, q)."""
        out = np.empty((len(x), self.coef.shape[1]))
        step = max(1, _CHUNK_ENTRIES // max(1, self.n_centers * x.shape[1]))
        for start in range(0, len(x), step):
            sl = slice(start, start + step)
            diff = x[sl, None, :] - self.centers_x[None, :, :]
            periodic = self.kernel.periodic
            r = np.sqrt(np.einsum("bma,bma->bm", diff, diff)) if periodic is None else periodic.distances(diff)
            k = self.kernel.state.phi(r)
            out[sl] = (k * weights[sl]) @ self.coef
        return out
