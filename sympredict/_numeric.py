"""Small numeric helpers written once for NumPy-level Python and for numba-compiled code.

:func:`sympredict._numba.compilable` marks the dense solves of the compiled
Newton iterations and the marking of a failed instance's trajectory as
callable from compiled code while they stay ordinary Python functions.

The canonical ``J`` is defined here, once (:func:`canonical_J`, and
:func:`j_times` to apply it without forming it), so that every layer may use
it; :mod:`sympredict.symplectic.metrics` re-exports both.
"""

from __future__ import annotations

import math

import numpy as np

from sympredict._numba import compilable


__all__ = ["lu_solve_inplace", "fill_nan_after", "canonical_J", "j_times"]


@compilable
def lu_solve_inplace(a, b) -> bool:
    """Solve ``a x = b`` by Gaussian elimination with partial pivoting; ``b`` becomes ``x``, ``a`` is destroyed.

    Returns False on an exact zero pivot (LAPACK ``getrf``'s singular case).
    ``O(dim^3)`` for ``a`` of shape (dim, dim); meant for the small Newton
    systems of one instance inside compiled loops.
    """
    dim = a.shape[0]
    for c in range(dim):
        piv = c
        best = abs(a[c, c])
        for r in range(c + 1, dim):
            if abs(a[r, c]) > best:
                best = abs(a[r, c])
                piv = r
        if best == 0.0:
            return False
        if piv != c:
            for j in range(dim):
                a[c, j], a[piv, j] = a[piv, j], a[c, j]
            b[c], b[piv] = b[piv], b[c]
        inv = 1.0 / a[c, c]
        for r in range(c + 1, dim):
            f = a[r, c] * inv
            if f != 0.0:
                for j in range(c + 1, dim):
                    a[r, j] -= f * a[c, j]
                b[r] -= f * b[c]
    for r in range(dim - 1, -1, -1):
        s = b[r]
        for j in range(r + 1, dim):
            s -= a[r, j] * b[j]
        b[r] = s / a[r, r]
    return True


@compilable
def fill_nan_after(traj, i, k) -> None:
    """``traj[i, k+1:] = NaN``: the states after a failed step ``k`` of instance ``i`` (traj (B, K+1, 2n))."""
    for kk in range(k + 1, traj.shape[1]):
        for j in range(traj.shape[2]):
            traj[i, kk, j] = math.nan


def canonical_J(dim: int) -> np.ndarray:
    """The Poisson matrix ``J = [[0, I], [-I, 0]]`` of size ``dim = 2n`` (``J^T = -J = J^-1``).

    The one construction of ``J`` in the package; :func:`j_times` applies it
    without forming it (use that for large ``2n`` or batches).
    """
    n = dim // 2
    return np.block([[np.zeros((n, n)), np.eye(n)], [-np.eye(n), np.zeros((n, n))]])


def j_times(v: np.ndarray, axis: int = -1) -> np.ndarray:
    """``J v`` along ``axis`` of ``v`` (even length ``2n`` there): ``(v_q, v_p) -> (v_p, -v_q)``, ``J`` never formed.

    ``O(size of v)``; a dense ``J_2N`` at ``N = 16,000`` would be 8 GB.  Equals
    ``canonical_J(2n) @ v`` for ``axis=0`` of a matrix, ``v @ canonical_J(2n).T``
    for the last axis of a batch of states, and ``J A`` of a stack of matrices
    ``A`` (..., 2n, 2n) for ``axis=-2``.  ``J^T v = -J v``.
    """
    n = v.shape[axis] // 2
    if axis == -1:  # the common case, kept lean (Newton iterations call it)
        return np.concatenate([v[..., n:], -v[..., :n]], axis=-1)
    hi = [slice(None)] * v.ndim
    lo = [slice(None)] * v.ndim
    hi[axis] = slice(n, None)
    lo[axis] = slice(None, n)
    return np.concatenate([v[tuple(hi)], -v[tuple(lo)]], axis=axis)
