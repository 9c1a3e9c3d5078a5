"""Canonical coordinates for models with a mass matrix (finite elements): ``M = L L^T``.

A finite-element wave (or elasticity) model ``M q'' = -K(mu) q`` with momenta
``p = M q'`` has the Hamiltonian ``H = 1/2 p^T M^-1 p + 1/2 q^T K(mu) q``, which is
*not* of the form ``1/2 x^T H x`` with an identity mass block, and its
symplectic basis and the kernel ROM live in canonical coordinates.  With the
Cholesky factor ``M = L L^T`` (or the lumped, diagonal mass matrix),

    q~ = L^T q,    p~ = L^-1 p,

is a symplectic change of coordinates (``T = diag(L^T, L^-1)``, ``T^T J T = J``)
in which ``H = 1/2 |p~|^2 + 1/2 q~^T L^-1 K(mu) L^-T q~``: the identity mass
block of :class:`~pymor.models.symplectic.QuadraticHamiltonianModel` and the
Euclidean norm of ``q~`` is the energy norm of ``M``.  Build the FOM, the basis
and the ROM in ``(q~, p~)``; map results back with :meth:`MassMatrixCoordinates.from_canonical`.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg
import scipy.sparse

from sympredict._checks import as_flag, as_real_array

__all__ = ["MassMatrixCoordinates"]

#: Largest ratio of the largest to the smallest mass (squared diagonal of ``L``) accepted.
MAX_MASS_RATIO = 1e12
#: Largest dense mass matrix factored (entries); larger models use a lumped (diagonal) mass matrix.
_MAX_DENSE = 20_000_000


def _as_square(A, name: str) -> np.ndarray:
    """A real, finite, symmetric square matrix (sparse or dense) as a dense array; ``ValueError`` naming ``name``."""
    shape = getattr(A, "shape", None)
    if shape is None or len(shape) != 2 or shape[0] != shape[1] or shape[0] == 0:
        raise ValueError(f"{name} must be a square (N, N) matrix (numpy or scipy.sparse), got shape {shape}")
    if shape[0] * shape[1] > _MAX_DENSE:
        raise ValueError(
            f"{name} is {shape[0]} x {shape[1]}: too large to factor densely (> {_MAX_DENSE} entries); "
            f"use lumped=True (a diagonal mass matrix)"
        )
    dense = A.toarray() if scipy.sparse.issparse(A) else np.asarray(A)
    if dense.dtype.kind not in "iuf":
        raise ValueError(f"{name} must be a real matrix, got dtype {dense.dtype}")
    dense = as_real_array(dense, name)
    scale = max(np.abs(dense).max(), np.finfo(float).tiny)
    if np.abs(dense - dense.T).max() > 1e-12 * scale:
        raise ValueError(f"{name} is not symmetric (max |A - A^T| = {np.abs(dense - dense.T).max():.3e})")
    return dense


class MassMatrixCoordinates:
    """The symplectic map ``(q, p) -> (q~, p~) = (L^T q, L^-1 p)`` of a mass matrix ``M = L L^T``.

    Parameters
    ----------
    mass : ndarray or scipy.sparse matrix of shape (N, N)
        Symmetric positive definite mass matrix.
    lumped : bool
        ``True``: use the lumped (row-sum, diagonal) mass matrix, ``L = diag(sqrt(sum_j M_ij))``; the
        model then is the lumped-mass one (a different, commonly used discretisation).  ``False``: the
        Cholesky factor of ``M`` itself (dense, ``O(N^3)``).

    Attributes
    ----------
    L : ndarray of shape (N, N)
        Lower-triangular factor with ``L L^T = M`` (diagonal when lumped).

    Raises
    ------
    ValueError
        If ``mass`` is not square, symmetric, finite and positive definite (also when lumped), or its masses span
        a ratio above :data:`MAX_MASS_RATIO` (the message says which).
    """

    def __init__(self, mass, lumped: bool = False):
        as_flag(lumped, "lumped")
        M = _as_square(mass, "mass")
        self.N = M.shape[0]
        self.lumped = bool(lumped)
        if lumped:
            d = M.sum(axis=1)
            if not np.all(d > 0):
                raise ValueError(
                    f"the lumped mass matrix has non-positive entries (row sums, min {d.min():.3e}): "
                    f"mass must be positive definite"
                )
            bad = np.flatnonzero(np.diag(M) <= 0)
            if bad.size:  # a mass matrix has positive masses on its diagonal; row sums alone do not show it
                raise ValueError(
                    f"mass has non-positive diagonal entries (entry {int(bad[0])}: {M[bad[0], bad[0]]:.3e}): "
                    "it is not positive definite, so it is no mass matrix; check the assembly"
                )
            try:
                np.linalg.cholesky(M)
            except np.linalg.LinAlgError:
                raise ValueError(
                    "mass is not positive definite (Cholesky failed), although its row sums are "
                    "positive: lumping would hide that; check the assembly"
                ) from None
            self.L = np.diag(np.sqrt(d))
        else:
            try:
                self.L = np.linalg.cholesky(M)
            except np.linalg.LinAlgError:
                raise ValueError(
                    "mass is not positive definite (Cholesky failed): check boundary conditions "
                    "(constrained nodes removed) and the assembly"
                ) from None
        masses = np.diag(self.L) ** 2  # a lower bound of the condition number (exact when diagonal)
        if masses.max() > MAX_MASS_RATIO * masses.min():
            raise ValueError(
                f"mass is ill-conditioned: its (lumped or pivot) masses span {masses.min():.3e} .. "
                f"{masses.max():.3e}, a ratio above {MAX_MASS_RATIO:.0e}; the canonical coordinates "
                "(q~, p~) would lose all digits. Check the units and the assembly (tiny or huge masses)"
            )

    def _solve_L(self, b, trans: bool = False) -> np.ndarray:
        return scipy.linalg.solve_triangular(self.L, b, lower=True, trans="T" if trans else "N")

    def canonical_stiffness(self, stiffness) -> np.ndarray:
        """``L^-1 K L^-T`` (N, N), symmetric: the position block of the Hamiltonian in canonical coordinates."""
        K = _as_square(stiffness, "stiffness")
        if K.shape[0] != self.N:
            raise ValueError(f"stiffness is {K.shape[0]} x {K.shape[0]}, the mass matrix {self.N} x {self.N}")
        A = self._solve_L(self._solve_L(K).T).T  # L^-1 K L^-T
        return 0.5 * (A + A.T)

    def _check(self, a, name):
        a = np.asarray(a, dtype=float)
        if a.shape[-1:] != (self.N,):
            raise ValueError(f"{name} must have N = {self.N} entries in its last axis, got shape {a.shape}")
        return a

    def to_canonical(self, q, p):
        """``(L^T q, L^-1 p)`` for arrays of shape (..., N); returns two arrays of the same shapes."""
        q, p = self._check(q, "q"), self._check(p, "p")
        qt = q @ self.L  # rows: (L^T q)^T = q^T L
        pt = self._solve_L(p.reshape(-1, self.N).T).T.reshape(p.shape)
        return qt, pt

    def from_canonical(self, q_tilde, p_tilde):
        """``(L^-T q~, L p~)``: physical positions and momenta (``p = M q'``) for arrays of shape (..., N)."""
        qt, pt = self._check(q_tilde, "q_tilde"), self._check(p_tilde, "p_tilde")
        q = self._solve_L(qt.reshape(-1, self.N).T, trans=True).T.reshape(qt.shape)
        return q, pt @ self.L.T

    def velocity(self, p_tilde) -> np.ndarray:
        """``q' = M^-1 p = L^-T p~`` for arrays of shape (..., N)."""
        pt = self._check(p_tilde, "p_tilde")
        return self._solve_L(pt.reshape(-1, self.N).T, trans=True).T.reshape(pt.shape)

    def matrix(self) -> np.ndarray:
        """``T = diag(L^T, L^-1)`` (2N, 2N): ``x~ = T x`` for states ``x = (q, p)``; ``T^T J T = J``."""
        T = np.zeros((2 * self.N, 2 * self.N))
        T[: self.N, : self.N] = self.L.T
        T[self.N :, self.N :] = self._solve_L(np.eye(self.N))
        return T
