"""Small numeric helpers written once for NumPy-level Python and for numba-compiled code.

:func:`compilable` marks a plain function as callable from compiled code
(numba's ``register_jitable``) while it stays an ordinary Python function;
without numba it is the identity.  The kernel families' formula helpers,
Newton's stopping rule, the dense solves of the compiled Newton
iterations and the marking of a failed instance's trajectory use it.

The canonical ``J`` is defined here, once (:func:`canonical_J`, and
:func:`j_times` to apply it without forming it), so that every layer may use
it; :mod:`sympredict.symplectic.metrics` re-exports both.
"""

from __future__ import annotations

import math
import os
import sys

import numpy as np

try:  # numba is optional: without it nothing is compiled and these stay plain functions
    from numba.extending import register_jitable as compilable
except ImportError:  # pragma: no cover

    def compilable(function):
        return function


__all__ = ["compilable", "lu_solve_inplace", "fill_nan_after", "canonical_J", "j_times", "parallel_safe"]


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


# --------------------------------------------------------------------------- fork safety of numba's parallel loops
#: Set in a process forked after numba's threading layer started (GNU OpenMP cannot run a parallel region in
#: such a child: numba terminates it).  Such a child runs the parallel loops serially (:func:`parallel_safe`).
_FORKED_AFTER_THREADS = False
_FORK_WARNED = False


def _threads_started() -> bool:
    """Whether numba's threading layer has started in this process (its worker threads exist)."""
    try:
        from numba.np.ufunc import parallel as _parallel

        return bool(getattr(_parallel, "_is_initialized", True))
    except Exception:  # noqa: BLE001 - an unknown numba layout: assume started (the safe side)
        return True


def _after_fork_in_child() -> None:
    global _FORKED_AFTER_THREADS, _FORK_WARNED
    if _FORKED_AFTER_THREADS or ("numba" in sys.modules and _threads_started()):
        _FORKED_AFTER_THREADS = True
        _FORK_WARNED = False


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_after_fork_in_child)


def parallel_safe() -> bool:
    """Whether numba's parallel loops may run in this process: not in a child forked after they ran.

    In such a child (``os.fork``, ``multiprocessing`` with the fork start method) every compiled kernel runs
    its loops on one thread (the same code compiled without ``parallel``), and one :class:`RuntimeWarning`
    says so; the results are those of the serial kernels.
    """
    global _FORK_WARNED
    if not _FORKED_AFTER_THREADS:
        return True
    if not _FORK_WARNED:
        _FORK_WARNED = True
        import warnings

        warnings.warn("this process was forked after numba's parallel loops ran (GNU OpenMP cannot run them in a "
                      "forked child): the compiled kernels run on one thread here; use multiprocessing's 'spawn' or "
                      "'forkserver' start method for parallel loops in the workers", RuntimeWarning, stacklevel=3)
    return False
