"""Small numeric helpers written once for NumPy-level Python and for numba-compiled code.

:func:`compilable` marks a plain function as callable from compiled code
(numba's ``register_jitable``) while it stays an ordinary Python function;
without numba it is the identity.  The kernel families' formula helpers,
Newton's stopping rule, the dense solves of the compiled Newton
iterations and the marking of a failed instance's trajectory use it.
"""

from __future__ import annotations

import math

try:  # numba is optional: without it nothing is compiled and these stay plain functions
    from numba.extending import register_jitable as compilable
except ImportError:  # pragma: no cover

    def compilable(function):
        return function


__all__ = ["compilable", "lu_solve_inplace", "fill_nan_after"]


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
