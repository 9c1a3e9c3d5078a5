"""Newton's stopping rule for the implicit step: defined once, used by the NumPy and the compiled solver.

An instance stops iterating when the residual ``|F|_inf`` reaches its
round-off floor, when the Newton update no longer changes the iterate, or when
the update stagnates within ``STALL_FLOOR_FACTOR`` of the floor:

* ``f_floor = FLOOR_FACTOR (eps |p| + dT floor_grad) + tiny``, where
  ``floor_grad`` is the round-off bound of the surrogate gradient
  (:meth:`sympredict.interpolation.surrogate.HBSurrogate.gradient_hessian`) and ``|p|`` the
  larger of ``|p0|_inf`` and ``|p1|_inf``;
* ``|delta|_inf <= UPDATE_FACTOR eps |p|``;
* ``|delta|_inf >= STALL_RATIO * previous |delta|_inf`` and ``|F| <= STALL_FLOOR_FACTOR f_floor``.

:func:`converged` works elementwise on NumPy arrays and, compiled by numba, on
scalars (:mod:`sympredict._fastkernels`).
"""

from __future__ import annotations

import numpy as np

from sympredict._numeric import compilable



__all__ = ["FLOOR_FACTOR", "UPDATE_FACTOR", "STALL_RATIO", "STALL_FLOOR_FACTOR", "residual_floor", "converged"]

EPS = float(np.finfo(float).eps)
TINY = float(np.finfo(float).tiny)

#: Multiple of the round-off of ``|F|`` (``eps |p| + dT floor_grad``) counted as converged.
FLOOR_FACTOR = 4.0
#: An update below this many ulps of ``|p|`` changes nothing.
UPDATE_FACTOR = 2.0
#: An update at least this fraction of the previous one has stopped contracting ...
STALL_RATIO = 0.5
#: ... which ends the iteration when ``|F|`` is within this factor of its floor.
STALL_FLOOR_FACTOR = 1e3


@compilable
def residual_floor(scale, gradient_floor, h):
    """Round-off floor of ``|F|_inf``: ``4 eps |p| + 4 dT floor_grad + tiny``."""
    return FLOOR_FACTOR * EPS * scale + FLOOR_FACTOR * h * gradient_floor + TINY


@compilable
def converged(f_norm, f_floor, d_norm, last_update, scale):
    """Whether an instance stops iterating (elementwise on arrays; scalars when compiled).

    Parameters
    ----------
    f_norm
        ``|F(p)|_inf`` at the current iterate.
    f_floor
        :func:`residual_floor` there.
    d_norm
        ``|delta|_inf`` of the Newton update just computed.
    last_update
        ``|delta|_inf`` of the previous iteration (``inf`` at the first).
    scale
        ``max(|p|_inf, |p0|_inf)``.
    """
    return (
        (f_norm <= f_floor)
        | (d_norm <= UPDATE_FACTOR * EPS * scale)
        | ((d_norm >= STALL_RATIO * last_update) & (f_norm <= STALL_FLOOR_FACTOR * f_floor))
    )
