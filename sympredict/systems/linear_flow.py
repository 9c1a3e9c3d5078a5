"""Exact flows of parameter-dependent quadratic Hamiltonians ``H0(x; mu) = 1/2 x^T A(mu) x``.

``A(mu) = sum_k theta_k(mu) A_k`` with symmetric ``A_k`` (2n, 2n) and the
monomial coefficients ``theta_k(mu) = prod_i mu_i^{p_ki}``: storable without
code (two arrays, no ``eval``), and enough for the usual parameter laws, e.g.
the pendulum's ``A(l) = l diag(m g, 0) + l^-2 diag(0, 1/m)`` (powers ``1`` and
``-2``) or a wave's ``A(c) = A0 + c^2 A2`` (powers ``0`` and ``2``).

The flow of ``x' = J grad H0 = J A(mu) x`` over a time ``t`` is the linear map
``L = expm(t J A(mu))``, symplectic for every ``t`` and ``mu``
(``L^T J L = J``, since ``J A`` is Hamiltonian), with the inverse
``L^-1 = expm(-t J A) = -J L^T J``.  :class:`QuadraticPart` evaluates ``A(mu)``
and these propagators for batches of ``(mu, t)``; it is the package's one class
for a parametrised quadratic Hamiltonian, and :func:`exact_propagators` its one
matrix exponential: :class:`sympredict.systems.quadratic.QuadraticHamiltonian`
(``H0 + mu H1``) holds a ``QuadraticPart``, and
:class:`sympredict.systems.flowmaps.LinearHamiltonianSystem` (``H(mu)`` from a callable,
plus a linear term) steps through :func:`exact_propagators` too.  The splitting predictor
(:mod:`sympredict.flowmap.splitting`) composes them with a learned map, and systems
provide their quadratic part at the equilibrium
(:meth:`sympredict.systems.pendulum.Pendulum.quadratic_part`).

Conventions: states ``x = (q, p)``, ``J = [[0, I], [-I, 0]]``.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import expm

from sympredict._checks import as_parameter, as_real_array
from sympredict.base import Parametrized
from sympredict.symplectic.metrics import j_times

__all__ = ["QuadraticPart", "exact_propagators", "generator_propagators", "inverse_symplectic_matrices"]


def inverse_symplectic_matrices(L: np.ndarray) -> np.ndarray:
    """``L^-1 = -J L^T J`` of square symplectic matrices ``L`` (..., 2n, 2n): exact, no solve (``O((2n)^2)`` each).

    (The same formula as :func:`sympredict.mor.basis.symplectic_inverse` of a basis ``V`` (2N, 2n); this one
    is for stacks of square maps.)
    """
    n = L.shape[-1] // 2
    # -J L^T J in blocks: L = [[a, b], [c, d]] -> [[d^T, -b^T], [-c^T, a^T]]
    Lt = np.swapaxes(L, -1, -2)
    out = np.empty_like(L)
    out[..., :n, :n] = Lt[..., n:, n:]
    out[..., :n, n:] = -Lt[..., n:, :n]
    out[..., n:, :n] = -Lt[..., :n, n:]
    out[..., n:, n:] = Lt[..., :n, :n]
    return out


def generator_propagators(generators: np.ndarray, t=1.0) -> np.ndarray:
    """``expm(t A)`` of linear generators ``A`` (..., m, m), ``t`` a scalar or of shape ``A.shape[:-2]``.

    The package's one call of ``scipy.linalg.expm`` (scaling and squaring with a
    Pade approximant, one stacked call: each matrix of the stack goes through
    the same algorithm as a single one, so batching does not change results).
    ``O(m^3 (13 + log2 ||t A||))`` flops per matrix.
    """
    t = np.asarray(t, dtype=float)
    return expm(generators * t[..., None, None])


def exact_propagators(H: np.ndarray, t=1.0, linear=None) -> np.ndarray:
    """Exact flow of ``H(x) = 1/2 x^T H x (+ x^T h)`` over ``t``: ``expm(t J H)`` for a stack of assembled Hessians.

    Parameters
    ----------
    H : ndarray of shape (..., 2n, 2n)
        Symmetric Hessians (not checked here: :meth:`QuadraticPart.checked` does).
    t : float or ndarray of shape ``H.shape[:-2]``
        Times (any sign: ``t < 0`` gives the inverse flow).
    linear : ndarray of shape (..., 2n), optional
        A linear term ``h``: the flow is then affine, ``x -> L x + c``, returned as
        the ``(2n+1, 2n+1)`` matrices ``expm(t [[J H, J h], [0, 0]])`` (last row ``e``).

    Returns
    -------
    ndarray of shape (..., 2n, 2n), or (..., 2n+1, 2n+1) with ``linear``

    Notes
    -----
    ``J H`` is formed by :func:`~sympredict.symplectic.metrics.j_times` (a row permutation
    with signs, exact), then :func:`generator_propagators`.
    """
    gen = j_times(H, axis=-2)
    if linear is not None:
        m = H.shape[-1]
        aug = np.zeros(H.shape[:-2] + (m + 1, m + 1))
        aug[..., :m, :m] = gen
        aug[..., :m, m] = j_times(np.asarray(linear, dtype=float))
        gen = aug
    return generator_propagators(gen, t)


class QuadraticPart(Parametrized):
    """``H0(x; mu) = 1/2 x^T A(mu) x`` with ``A(mu) = sum_k (prod_i mu_i^{p_ki}) A_k``.

    Parameters
    ----------
    matrices : array_like of shape (K, 2n, 2n)
        Symmetric ``A_k`` (checked to a relative ``1e-12``; the symmetric part is used).
    powers : array_like of shape (K, d_mu), optional
        Real exponents ``p_ki``; ``None`` (or ``d_mu = 0``) for a parameter-free
        ``A = sum_k A_k``.  Zero exponents make a term independent of ``mu_i``;
        a non-integer exponent needs ``mu_i > 0``, a negative one ``mu_i != 0``.

    Notes
    -----
    ``__init__`` stores its arguments (the estimator contract,
    :mod:`sympredict.base`); :meth:`checked` validates them and every method
    calls it.
    """

    def __init__(self, matrices, powers=None):
        self.matrices = matrices
        self.powers = powers

    def checked(self, dim=None, n_mu=None) -> tuple:
        """The validated ``(matrices (K, 2n, 2n), powers (K, d_mu))`` as float arrays.

        Parameters
        ----------
        dim, n_mu : int, optional
            Expected state dimension ``2n`` and parameter dimension.

        Raises
        ------
        ValueError
            Naming the problem: wrong shapes, an odd or mismatched dimension, a
            non-symmetric or non-finite matrix, non-finite powers, a parameter
            dimension that is not the expected one.
        """
        try:
            mats = np.array(self.matrices, dtype=float)
        except (TypeError, ValueError):
            raise ValueError(
                f"QuadraticPart: matrices must be an array of shape (K, 2n, 2n), got {self.matrices!r}"
            ) from None
        if mats.ndim == 2:
            raise ValueError(
                f"QuadraticPart: matrices must have shape (K, 2n, 2n) (a list of matrices), got {mats.shape}; "
                "wrap a single matrix as [A]"
            )
        if (
            mats.ndim != 3
            or mats.shape[0] == 0
            or mats.shape[1] != mats.shape[2]
            or mats.shape[1] == 0
            or mats.shape[1] % 2
        ):
            raise ValueError(
                f"QuadraticPart: matrices must have shape (K, 2n, 2n) with K >= 1 and an even 2n, got {mats.shape}"
            )
        as_real_array(mats, "QuadraticPart: matrices")
        asym = np.abs(mats - np.swapaxes(mats, 1, 2)).max(axis=(1, 2))
        scale = np.abs(mats).max(axis=(1, 2))
        bad = np.flatnonzero(asym > 1e-12 * np.maximum(scale, np.finfo(float).tiny))
        if bad.size:
            raise ValueError(
                f"QuadraticPart: matrix {int(bad[0])} is not symmetric (max |A - A^T| = {asym[bad[0]]:.3e}); "
                "H0 = 1/2 x^T A x needs symmetric A_k"
            )
        mats = 0.5 * (mats + np.swapaxes(mats, 1, 2))
        k = mats.shape[0]
        if self.powers is None:
            pw = np.zeros((k, 0))
        else:
            try:
                pw = np.array(self.powers, dtype=float)
            except (TypeError, ValueError):
                raise ValueError(
                    f"QuadraticPart: powers must be an array of shape (K, d_mu), got {self.powers!r}"
                ) from None
            if pw.ndim == 1 and len(pw) == k:  # one parameter component
                pw = pw[:, None]
            if pw.ndim != 2 or pw.shape[0] != k:
                raise ValueError(
                    f"QuadraticPart: powers must have shape (K, d_mu) = ({k}, d_mu), one row per matrix, got {pw.shape}"
                )
            as_real_array(pw, "QuadraticPart: powers")
        if dim is not None and mats.shape[1] != dim:
            raise ValueError(
                f"QuadraticPart: the matrices are {mats.shape[1]} x {mats.shape[1]}, "
                f"the states have 2n = {dim} components"
            )
        if n_mu is not None and pw.shape[1] not in (0, n_mu):
            raise ValueError(
                f"QuadraticPart: the powers have {pw.shape[1]} parameter component(s), the parameter has {n_mu}"
            )
        return mats, pw

    @property
    def dim(self) -> int:
        """State dimension ``2n``."""
        return self.checked()[0].shape[1]

    @property
    def n_mu(self) -> int:
        """Parameter components the coefficients use (0: parameter-free)."""
        return self.checked()[1].shape[1]

    def _batch(self, mu, n, d: int) -> int:
        """The batch size: ``n`` if given, else from ``mu`` (rows, or length with one component), else 1."""
        if n is not None:
            return int(n)
        arr = None if mu is None else np.asarray(mu)
        if arr is None or arr.ndim == 0 or (arr.ndim == 1 and d != 1):
            return 1
        return arr.shape[0]

    def coefficients(self, mu=None, n=None) -> np.ndarray:
        """``theta_k(mu)`` of shape (B, K).

        ``mu``: scalar, (B,) (one component), (d_mu,), (B, d_mu) or (1, d_mu)
        (:func:`~sympredict._checks.as_parameter`); ignored when the powers
        use no parameter.  ``n``: the batch size ``B`` (default: from ``mu``).
        """
        _, pw = self.checked()
        k, d = pw.shape
        b = self._batch(mu, n, d)
        if d == 0:
            return np.ones((b, k))
        if mu is None:
            raise ValueError(f"QuadraticPart: mu is required, A(mu) depends on {d} parameter component(s)")
        base = as_parameter(mu, b, d)[:, None, :]  # (B, 1, d)
        bad = ((base < 0) & (pw[None] != np.round(pw[None]))) | ((base == 0) & (pw[None] < 0))
        if np.any(bad):
            raise ValueError(
                "QuadraticPart: theta_k(mu) = prod_i mu_i^p_ki is undefined here (a non-integer power of a "
                "negative mu_i or a negative power of mu_i = 0)"
            )
        with np.errstate(over="ignore"):
            theta = np.prod(np.where(pw[None] == 0, 1.0, base ** pw[None]), axis=2)
        if not np.all(np.isfinite(theta)):
            raise ValueError("QuadraticPart: theta_k(mu) overflows for the given mu")
        return theta

    def hessian(self, mu=None, n=None) -> np.ndarray:
        """``A(mu)`` of shape (B, 2n, 2n); ``O(B K (2n)^2)``."""
        mats, _ = self.checked()
        return np.einsum("bk,kij->bij", self.coefficients(mu, n), mats)

    def energy(self, x, mu=None) -> np.ndarray:
        """``H0 = 1/2 x^T A(mu) x`` of states (B, 2n), shape (B,)."""
        x = np.atleast_2d(np.asarray(x, dtype=float))
        if x.ndim != 2 or x.shape[1] != self.dim:
            raise ValueError(f"x must have shape (B, {self.dim}), got {x.shape}")
        return 0.5 * np.einsum("bi,bij,bj->b", x, self.hessian(mu, len(x)), x)

    def propagator(self, mu=None, t=1.0, n=None) -> np.ndarray:
        """``L = expm(t J A(mu))`` of shape (B, 2n, 2n) for a batch of ``(mu, t)``.

        Parameters
        ----------
        mu : array_like, optional
            As in :meth:`coefficients`.
        t : float or array_like of shape (B,)
            Times (any sign: ``t < 0`` gives the inverse flow).
        n : int, optional
            Batch size ``B`` (default: from ``t`` when it is an array, else from ``mu``).

        Notes
        -----
        One stacked call of ``scipy.linalg.expm`` (:func:`exact_propagators`):
        ``O(B (2n)^3 (13 + log2 ||t J A||))`` flops, no Python loop over the batch.  Exact up to round-off for any ``t``
        (no step-size restriction): symplectic to ``~1e-15``.
        """
        t = as_real_array(t, "t")
        if t.ndim > 1:
            raise ValueError(f"t must be a scalar or have shape (B,), got {t.shape}")
        if n is None and t.ndim == 1 and len(t) > 1:
            n = len(t)
        A = self.hessian(mu, n)
        if t.ndim == 1 and len(t) not in (1, len(A)):
            raise ValueError(f"t must be a scalar or have length {len(A)} (one per instance), got {len(t)}")
        return exact_propagators(A, np.broadcast_to(t.reshape(-1), (len(A),)))
