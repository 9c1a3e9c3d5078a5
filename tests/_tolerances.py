"""Tolerances for comparing two computations of one quantity by different code paths.

Bit-equality holds only where the same code path runs on the same arrays.  Anything
else (BLAS against compiled code, another OpenBLAS kernel, numba code built for
another CPU with or without FMA, warm against cold Newton starts) agrees only to
round-off or to a solver's stopping rule, and how far apart the two land depends on
the CPU.  The bounds here are derived from those, never tuned to a machine:

* :func:`newton_step_bound`: two Newton solves of the same implicit step that both
  stopped by the rule of :mod:`sympredict.newton_rule` have residuals within
  ``STALL_FLOOR_FACTOR * residual_floor`` (the loosest way the rule lets an instance
  stop), evaluated with the gradient's own round-off bound at that point;
* :func:`rollout_bound`: two rollouts of ``K`` implicit steps whose Newton solves both
  converged to the gradient's round-off floor: per step the solutions differ by about
  ``dT`` times that floor (the same equation, evaluated with other rounding), the factor
  ``ROLLOUT_FACTOR`` covers the solve's conditioning and the carried error of a short
  rollout, plus a few ulps of the state per step (maps applied around the solve);
* :func:`value_rollout_bound`: the same for explicit steps ``x + dT r(x)`` (the direct
  model): the round-off of a sum of ``m`` terms, ``m eps sum |terms|``, per step.
"""

from __future__ import annotations

import numpy as np

from sympredict.newton_rule import EPS, STALL_FLOOR_FACTOR, residual_floor


def newton_step_bound(surrogate, xi, weights, dt) -> np.ndarray:
    """Per instance, how far a converged Newton iterate's residual may be from zero, shape (B,).

    ``xi`` (B, 2n) are the points the surrogate's gradient is evaluated at (in the
    surrogate's coordinates), ``weights`` (B, m) their parameter factors, ``dt`` (B,)
    the steps.  Also covers the oracle's own round-off in re-evaluating the
    gradient (``dt * floor``).
    """
    xi = np.atleast_2d(np.asarray(xi, dtype=float))
    _, _, floor = surrogate.gradient_hessian(xi, np.atleast_2d(weights), with_floor=True)
    dt = np.abs(np.broadcast_to(np.asarray(dt, dtype=float), (len(xi),)))
    scale = np.abs(xi).max(axis=1)
    return STALL_FLOOR_FACTOR * residual_floor(scale, floor, dt) + dt * floor


#: Per-step multiple of ``dT x floor`` two converged solutions may differ by (see the module docstring).
ROLLOUT_FACTOR = 100.0


def rollout_bound(surrogate, states, weights, dt) -> float:
    """A bound on how far two paths' rollouts of ``K`` implicit steps may drift apart.

    ``states`` (B, K+1, 2n) is one of the two trajectories, in the surrogate's
    coordinates (the floor is smooth in the state, so its points stand in for the
    evaluation points of the solves), ``weights`` (B, m) and ``dt`` (B,) as in
    :func:`newton_step_bound`.  Returns
    ``K (ROLLOUT_FACTOR max(dT) max(floor) + 4 eps max|x|)``.
    """
    states = np.asarray(states, dtype=float)
    _, k1, dim = states.shape
    _, _, floor = surrogate.gradient_hessian(
        states.reshape(-1, dim), np.repeat(np.atleast_2d(weights), k1, axis=0), with_floor=True
    )
    return float((k1 - 1) * (ROLLOUT_FACTOR * np.abs(dt).max() * floor.max() + 4 * EPS * np.abs(states).max()))


def value_rollout_bound(coef, states, dt, growth: float = 2.0) -> float:
    """A bound on how far two evaluations of ``K`` explicit steps ``x + dT sum_j c_j k_j w_j`` may drift apart.

    A sum of ``m`` terms computed in another order (another BLAS kernel, alignment, FMA) differs by at most
    ``m eps sum_j |c_j k_j w_j| <= m eps sum_j |c_j|`` (kernels and weights bounded by 1, as the radial
    profiles here are); ``coef`` (m, q), ``states`` (B, K+1, 2n) one of the two trajectories, ``dt`` the steps.
    """
    coef = np.asarray(coef, dtype=float).reshape(len(coef), -1)
    states = np.asarray(states, dtype=float)
    k = states.shape[1] - 1
    per_step = len(coef) * EPS * np.abs(dt).max() * np.abs(coef).sum(axis=0).max() + 4 * EPS * np.abs(states).max()
    return float(growth * k * per_step)


def assert_same_predictions(actual_model, expected_model, x, n_steps, mu=None, dt=None):
    """Two models with the same fitted arrays (a model and its loaded copy, clone or twin) predict alike.

    Rollouts of ``n_steps`` from ``x`` agree to the bound of the expected model's update
    (:func:`rollout_bound` for implicit steps, :func:`value_rollout_bound` for the direct
    model), not bit for bit: the same code on the same values may still round with the
    arrays' memory alignment in AVX-512 BLAS kernels.  Returns the bound used.
    """
    expected = expected_model.rollout(x, n_steps, mu=mu, dt=dt)
    got = actual_model.rollout(x, n_steps, mu=mu, dt=dt)
    inner = getattr(expected_model, "predictor_", expected_model)  # a split model's surrogate is its predictor's
    sur = inner.surrogate_
    traj = expected.reshape(-1, expected.shape[-2], expected.shape[-1])
    b = len(traj)
    steps = np.broadcast_to(np.asarray(inner.dt_fixed_ if dt is None else dt, dtype=float).reshape(-1), (b,))
    if hasattr(sur, "gradient_hessian"):
        n_mu = inner.n_mu_
        given = np.zeros((1, 0)) if mu is None else np.asarray(mu, dtype=float)
        params = np.broadcast_to(given.reshape(-1, n_mu) if given.size > n_mu else given.reshape(1, n_mu), (b, n_mu))
        bound = rollout_bound(sur, traj, sur.weights(params, steps), steps)
    else:
        bound = value_rollout_bound(sur.coef, traj, steps)
    np.testing.assert_allclose(got, expected, rtol=0, atol=bound)
    return bound
