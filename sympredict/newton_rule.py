"""Newton's stopping rule for the implicit step: defined once, used by the NumPy and the compiled solver.

The iteration is Newton's method with a watchdog (:data:`WATCHDOG`, :func:`accepted`): full steps while the
residual ``|F|_2`` improves within :data:`WATCHDOG` passes, else back to the best iterate and a backtracking line
search from it.

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
scalars (:mod:`sympredict.kernels._compiled`).
"""

from __future__ import annotations

import numpy as np

from sympredict._numba import compilable


__all__ = [
    "FLOOR_FACTOR",
    "UPDATE_FACTOR",
    "STALL_RATIO",
    "STALL_FLOOR_FACTOR",
    "DECREASE",
    "MIN_FRACTION",
    "WATCHDOG",
    "residual_floor",
    "converged",
    "accepted",
]

EPS = float(np.finfo(float).eps)
TINY = float(np.finfo(float).tiny)
INF = float("inf")

#: Multiple of the round-off of ``|F|`` (``eps |p| + dT floor_grad``) counted as converged.
FLOOR_FACTOR = 4.0
#: An update below this many ulps of ``|p|`` changes nothing.
UPDATE_FACTOR = 2.0
#: An update at least this fraction of the previous one has stopped contracting ...
STALL_RATIO = 0.5
#: ... which ends the iteration when ``|F|`` is within this factor of its floor.
STALL_FLOOR_FACTOR = 1e3


#: The watchdog (a globalised Newton): Newton's full steps go on while some iterate within WATCHDOG passes improves
#: on the best one so far (:func:`accepted` with fraction 1; Newton's own path may raise the residual for a few
#: iterations on its way into a root's basin, so ordinary steps take exactly the plain Newton iterates).  After
#: WATCHDOG passes without improvement (a cycle, a wandering iterate), or at a non-finite residual, the iteration
#: goes back to the best iterate and halves its Newton step until :func:`accepted` (a backtracking line search on
#: ``|F|_2``); from the iterate so found the full steps go on.  Eight passes: the midpoint update needs a few
#: non-monotone passes to converge at 3 rad per step (an oscillator, ``tests/symplectic/test_midpoint.py``), and
#: an implicit step on data with wrapped angles needs more (``tests/estimators/test_structure.py``: with 3 to 5
#: passes every candidate of the search fails there).
WATCHDOG = 8
#: Sufficient decrease: an iterate reached with step fraction ``lam`` improves on the best one when
#: ``|F|_2 <= (1 - DECREASE lam) |F_best|_2`` ...
DECREASE = 1e-4
#: ... or when its residual is within ``STALL_FLOOR_FACTOR`` of the round-off floor, or when ``lam`` has been halved
#: down to this fraction (the damped iterate is then taken as it is).  Zero: the line search takes no iterate
#: without sufficient decrease; at a local minimum of ``|F|_2`` that is not a root it halves on until ``max_iter``
#: and the instance fails there (taking a damped iterate anyway restarted full Newton steps from near the minimum,
#: where the Jacobian is nearly singular: the iterate was thrown far away, and where it landed depended on round-off).
MIN_FRACTION = 0.0


@compilable
def accepted(merit, merit_best, fraction, f_norm, f_floor):
    """Whether an iterate improves on the best one (the watchdog's test; elementwise, scalars when compiled).

    The merit is ``|F|_2``, for which the Newton direction is a descent direction (``|F|_inf`` need not
    decrease along it).  The first iterate (``merit_best = inf``; a non-finite one then fails at once) and
    iterates at round-off level always count as improvements.

    Parameters
    ----------
    merit
        ``|F|_2`` at the iterate (NaN or ``inf`` for a non-finite residual).
    merit_best
        ``|F|_2`` of the best iterate so far (``inf`` before the first).
    fraction
        The step fraction ``lam`` that reached the iterate: 1 for Newton's full step, below 1 for a damped
        trial from the best iterate.
    f_norm
        ``|F|_inf`` at the iterate.
    f_floor
        :func:`residual_floor` at the iterate.
    """
    return (
        (merit_best == INF)
        | (merit <= (1.0 - DECREASE * fraction) * merit_best)
        | (f_norm <= STALL_FLOOR_FACTOR * f_floor)
        | (fraction <= MIN_FRACTION)
    )


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
