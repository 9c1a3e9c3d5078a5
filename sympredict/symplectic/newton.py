"""Newton solvers of the implicit steps (symplectic Euler, midpoint): the NumPy reference and the compiled rollout.

**The algorithm** (one, written here; :func:`implicit_rollout` runs it in
NumPy, batched over the instances, or in compiled code, one instance at a
time, :mod:`sympredict.symplectic._compiled_newton`).  Per instance and
macro step, with ``x0 = (q0, p0)`` the step's input:

* *Unknowns, residual, Jacobian.*  Symplectic Euler: ``u = p1`` (``n``
  unknowns), ``F(u) = u - p0 + dT d_q s(q0, u)``, Jacobian ``I + dT d_p d_q s``
  (the Hessian block only); then ``q1 = q0 + dT d_p s(q0, p1)``.  Midpoint:
  ``u = z = (x0 + x1) / 2`` (``2n`` unknowns), ``F(u) = u - x0 - dT/2 J grad s(u)``,
  Jacobian ``I - dT/2 J Hess s(u)``; then ``x1 = x0 + dT J grad s(z)``.
* *Start guess* ``u_0``.  The explicit guess, one gradient pass at ``x0``:
  ``p0 - dT d_q s(q0, p0)`` (midpoint: ``x0 + dT/2 J grad s(x0)``).  With
  ``warm_start``, from the second state of a rollout on, an extrapolation of
  the previous states instead (no pass): ``3 x_k - 3 x_k-1 + x_k-2`` of the
  unknowns' components (``2 x_k - x_k-1`` when only one previous state
  exists; midpoint: the midpoint of ``x_k`` and that extrapolation of
  ``x_k+1``).  The previous states are the rollout's own, carried across the
  chunks of a long rollout (:func:`rollout_in_chunks` ``history``), so where
  a rollout is cut into chunks does not change a result.
* *Iteration* ``j = 0, 1, ..., max_iter - 1``, each one pass over the centres
  at ``u_j`` (gradient, the Hessian part of the Jacobian, the gradient's
  round-off floor):

  1. ``F_j`` and ``|F_j|_inf`` (NaN if any component is NaN).  A non-finite
     residual fails the instance (reason 1);
  2. ``scale = max(|u_j|_inf, |x_ref|_inf)`` (``x_ref = p0``, midpoint
     ``x0``) and the floor :func:`~sympredict.newton_rule.residual_floor`
     ``(scale, floor, |dT|)`` (midpoint ``|dT|/2``);
  3. the update ``delta_j`` from the Jacobian by Gaussian elimination with
     partial pivoting; an exact zero pivot fails the instance (reason 2:
     :func:`sympredict._numeric.lu_solve_inplace` decides on both paths);
  4. if :func:`~sympredict.newton_rule.converged` ``(|F_j|, floor, |delta_j|_inf,
     |delta_j-1|_inf, scale)`` (``|delta_-1| = inf``), the instance is done and
     ``x1`` is formed from the gradient at ``u_j``;
  5. else ``u_j+1 = u_j - delta_j``.

  An instance still iterating after ``max_iter`` iterations fails (reason 3).
* *Failure report.*  A rollout fails at the first macro step at which an
  instance fails; of that step's failed instances it names those that
  failed at the earliest iteration, and of these the ones with the first
  reason in the order 1, 2, 3 (:data:`FAILURE_REASONS`): one
  :class:`~sympredict.exceptions.NewtonConvergenceError` naming the
  instances, their residuals ``|F|_inf``, the reason and the macro step, and
  for each the contraction estimate ``dT L_S`` at its start guess
  (:func:`contraction_estimate`, evaluated after the failure, so successful
  steps never pay for it).  The NumPy reference stops at the end of the
  iteration at which an instance fails; the compiled rollout lets the other
  instances go on; the report is the same.

The two paths differ only in rounding: the compiled pass sums over the
centres in another order, and its eliminations run in its own code.  Where an
iteration converges this moves the result within the stopping rule
(``tests/_tolerances.py``).  Where it wanders (a step far larger than the
training steps, an iterate far outside the data), whether and when it lands
in a root's basin is decided by those rounding differences, and the two paths
(like two CPUs, or two batch compositions on the NumPy path) may then report
different instances or steps.

**Why the contraction estimate refuses nothing before iterating.**  ``dT L_S < 1``
(``L_S = ||d_p d_q s||_2``; midpoint ``dT/2 ||Hess s||_2``) makes the
fixed-point iteration contract; Newton needs less and often converges far
beyond it.  Measured at the start guess of every step the test suite and the
experiments solve: converged steps reach ``dT L_S = 3.0`` (midpoint, an
oscillator turning by 2.5 rad per step, where the midpoint form is meant to
work) and 5.8 (symplectic Euler, a randomly corrupted model file); on
pendulum steps 16-100 times the training steps, the steps that fail have
``dT L_S`` from 0.00 to 6.5 at their start guess (the explicit guess often lands
where ``s`` is flat, the iteration then moves into its curvature), while
steps that converge in the same rollouts reach 64.  No threshold separates
them, so the estimate is reported with a failure, not used to refuse.
:meth:`SymplecticKernelPredictor.rollout` ``(check_solvability=True)`` is the
strict, sufficient check before a rollout.
"""

from __future__ import annotations

import os
import time
from typing import Callable, Optional

import numpy as np

from sympredict.symplectic import _compiled_newton
from sympredict._checks import as_choice
from sympredict._numeric import lu_solve_inplace
from sympredict.exceptions import NewtonConvergenceError, RolloutMemoryError
from sympredict.symplectic.metrics import j_times
from sympredict.newton_rule import WATCHDOG, accepted, converged, residual_floor
from sympredict.interpolation.surrogate import HBSurrogate

__all__ = [
    "solve_step_numpy",
    "solve_midpoint_numpy",
    "midpoint_jacobian",
    "implicit_rollout",
    "rollout_numpy",
    "rollout_in_chunks",
    "ordered_weights",
    "available_memory",
    "contraction_estimate",
    "start_guess",
    "failure_error",
    "FAILURE_REASONS",
    "MIDPOINT_FAILURE_REASONS",
    "UPDATES",
    "WARM_HISTORY",
]

#: Failure codes of both solvers and the reason each names (the order of the failure report's preference).
FAILURE_REASONS = {
    1: "produced a non-finite iterate",
    2: "hit a singular Jacobian I + dT d_p d_q s",
    3: "did not converge in {max_iter} iterations",
}

#: The same codes for the midpoint update (its Jacobian is ``I - dT/2 J Hess s``).
MIDPOINT_FAILURE_REASONS = {**FAILURE_REASONS, 2: "hit a singular Jacobian I - dT/2 J Hess s"}

#: The implicit updates the solvers know.
UPDATES = _compiled_newton.UPDATES

#: Previous states a warm start extrapolates from (and a chunked rollout carries to its next chunk).
WARM_HISTORY = _compiled_newton.WARM_HISTORY


_j_times = j_times  # ``J v`` on the last axis (sympredict.symplectic.metrics)


def _check_update(update: str) -> bool:
    """Whether ``update`` is the midpoint update (``ValueError`` for an unknown one)."""
    return as_choice(update, "update", UPDATES) == "midpoint"


# --------------------------------------------------------------------------- the algorithm's pieces, in NumPy
def start_guess(
    sur: HBSurrogate, states: np.ndarray, weights: np.ndarray, dt: np.ndarray, midpoint: bool, warm: bool
) -> np.ndarray:
    """Newton's start guess ``u_0`` (B, k) for the step from ``states[:, -1]`` (module docstring).

    ``states`` (B, j+1, 2n): the rollout's states up to the step's input, oldest first (``j <= 2`` used).
    ``warm`` and ``j >= 1``: the extrapolation (no pass over the centres, the same operations as the
    compiled rollout's); else the explicit guess (one gradient pass at the input).
    """
    x = states[:, -1]
    n = x.shape[1] // 2
    if warm and states.shape[1] >= 2:
        u = x if midpoint else x[:, n:]
        u1 = states[:, -2] if midpoint else states[:, -2, n:]
        if states.shape[1] >= 3:  # x_k+1 ~ 3 x_k - 3 x_k-1 + x_k-2 (error O(dT^3))
            nxt = 3.0 * (u - u1) + (states[:, -3] if midpoint else states[:, -3, n:])
        else:  # x_k+1 ~ 2 x_k - x_k-1 (error O(dT^2))
            nxt = 2.0 * u - u1
        return 0.5 * (u + nxt) if midpoint else nxt  # midpoint: z = (x_k + x_k+1) / 2
    g = sur.gradient(x, weights)
    if midpoint:  # z ~ x0 + dT/2 J grad s(x0)
        return x + (0.5 * dt)[:, None] * _j_times(g)
    return x[:, n:] - dt[:, None] * g[:, :n]  # p1 ~ p0 - dT d_q s(q0, p0)


def _hessian_part(sur: HBSurrogate, x: np.ndarray, u: np.ndarray, weights: np.ndarray, midpoint: bool):
    """One pass at the iterate: gradient (B, 2n), the Hessian part of the Jacobian, floor (B,)."""
    if midpoint:
        return sur.gradient_hessian(u, weights, with_floor=True)
    n = x.shape[1] // 2
    return sur.newton_terms(np.concatenate([x[:, :n], u], axis=1), weights)


def contraction_estimate(
    sur: HBSurrogate, x: np.ndarray, u: np.ndarray, weights: np.ndarray, dt: np.ndarray, midpoint: bool
) -> np.ndarray:
    """``dT L_S`` at the iterate ``u`` (B, k) of the step from ``x`` (B, 2n), shape (B,).

    Symplectic Euler: ``|dT| ||d_p d_q s(q0, u)||_2``, the Lipschitz constant of the fixed-point map
    ``p -> p0 - dT d_q s(q0, p)`` there; midpoint: ``|dT|/2 ||Hess s(u)||_2``, that of
    ``z -> x0 + dT/2 J grad s(z)``.  Below 1 the fixed-point iteration contracts near ``u`` (paper,
    Prop. 2); Newton often converges beyond it.  Computed from the Hessian part one Newton iteration
    evaluates (one pass); the failure report evaluates it at the start guess.
    """
    _, hess, _ = _hessian_part(sur, x, u, weights, midpoint)
    with np.errstate(invalid="ignore"):
        norm = np.full(len(x), np.nan)
        ok = np.all(np.isfinite(hess), axis=(1, 2))
        if np.any(ok):
            norm[ok] = np.linalg.norm(hess[ok], ord=2, axis=(1, 2))
    return (0.5 if midpoint else 1.0) * np.abs(dt) * norm


def _solve_linear(jac: np.ndarray, F: np.ndarray):
    """Newton updates ``jac^-1 F`` (B, k) and which systems have an exact zero pivot (B,).

    LAPACK's solve when no system is singular; otherwise :func:`lu_solve_inplace`, the compiled
    solver's elimination, decides which are (and solves the others).
    """
    try:
        return np.linalg.solve(jac, F[:, :, None])[:, :, 0], np.zeros(len(F), dtype=bool)
    except np.linalg.LinAlgError:
        delta = np.array(F, dtype=float, copy=True)
        singular = np.array([not lu_solve_inplace(np.array(a, dtype=float), d) for a, d in zip(jac, delta)], dtype=bool)
        return delta, singular


def _newton(
    sur: HBSurrogate, x: np.ndarray, u: np.ndarray, weights: np.ndarray, dt: np.ndarray, max_iter: int, midpoint: bool
):
    """The iteration of the module docstring for a batch, from the start guesses ``u`` (B, k) (overwritten).

    All instances advance together; finished ones leave the active set.  Stops at the end of the
    first iteration at which an instance fails (the failure report names only those).

    Returns
    -------
    x1 : ndarray of shape (B, 2n)
        Rows of instances that did not finish are NaN.
    failure : None or tuple of three ndarray of shape (B,)
        ``None`` when every instance converged, else per instance the failure code (0: converged or
        not finished), the iteration of the failure and ``|F|_inf`` there.
    iterations : ndarray of shape (B,)
        Newton iterations (passes at iterates) made.

    Notes
    -----
    Cost per iteration ``O(B_active m (2n + n^2))`` (:meth:`HBSurrogate.newton_terms`; midpoint
    ``O(B_active m (2n)^2)``, :meth:`HBSurrogate.gradient_hessian`) plus a ``k^3`` solve per instance.
    """
    b, dim = x.shape
    n = dim // 2
    k = u.shape[1]
    h = dt if not midpoint else 0.5 * dt  # the step in the residual
    x_ref = x if midpoint else x[:, n:]
    out = np.full_like(x, np.nan)
    iterations = np.zeros(b, dtype=np.int64)
    codes = np.zeros(b, dtype=np.int64)
    active = np.arange(b)
    last = np.full(b, np.inf)
    # the watchdog (sympredict.newton_rule): the best iterate, its update and |F|_2, passes since, the step fraction
    u_best, d_best = u.copy(), np.zeros_like(u)
    best, since = np.full(b, np.inf), np.zeros(b, dtype=np.int64)
    fraction, f_last = np.ones(b), np.full(b, np.nan)  # fraction below 1: a damped trial from the best iterate
    eye = np.eye(k)
    for it in range(max_iter):
        ua, ha = u[active], h[active]
        g, hess, floor = _hessian_part(sur, x[active], ua, weights[active], midpoint)
        if midpoint:
            jg = _j_times(g)
            F = ua - x[active] - ha[:, None] * jg
        else:
            F = ua - x_ref[active] + ha[:, None] * g[:, :n]
        f_norm = np.abs(F).max(axis=1)
        with np.errstate(over="ignore", invalid="ignore"):
            merit = np.sqrt(np.einsum("ij,ij->i", F, F))
        scale = np.maximum(np.abs(ua).max(axis=1), np.abs(x_ref[active]).max(axis=1))
        f_floor = residual_floor(scale, floor, np.abs(ha))
        f_last[active] = f_norm
        new_best = accepted(merit, best[active], fraction[active], f_norm, f_floor)
        back = None  # no instance goes back (the usual case: every iterate improves)
        if not new_best.all():
            damped = fraction[active] < 1.0
            free_stalled = ~damped & ~new_best
            since[active[free_stalled]] += 1
            restart = free_stalled & ((since[active] >= WATCHDOG) | ~np.isfinite(f_norm))
            back = (damped & ~new_best) | restart
        if back is not None and back.any():  # a damped trial rejected (halve it again), or no progress: back
            # to the best iterate, a line search from it (sympredict.newton_rule.WATCHDOG)
            rest = active[back]
            fraction[rest] = np.where(restart[back], 0.5, 0.5 * fraction[rest])
            u[rest] = u_best[rest] - fraction[rest, None] * d_best[rest]
            ok = ~back
            active, ua, ha, g, hess, F, f_norm, merit, scale, f_floor, new_best = (
                active[ok],
                ua[ok],
                ha[ok],
                g[ok],
                hess[ok],
                F[ok],
                f_norm[ok],
                merit[ok],
                scale[ok],
                f_floor[ok],
                new_best[ok],
            )
            if midpoint:
                jg = jg[ok]
        else:
            rest = active[:0]
        if midpoint:
            jac = eye - ha[:, None, None] * _j_times(hess.transpose(0, 2, 1)).transpose(0, 2, 1)
        else:
            jac = eye + ha[:, None, None] * hess
        finite = np.isfinite(f_norm)
        if finite.all():
            delta, singular = _solve_linear(jac, F)
        else:  # no solve for a non-finite residual (the failure comes first)
            delta = np.zeros_like(F)
            singular = np.zeros(len(active), dtype=bool)
            if finite.any():
                delta[finite], singular[finite] = _solve_linear(jac[finite], F[finite])
        d_norm = np.abs(delta).max(axis=1)
        failed = ~finite | singular
        done = ~failed & converged(f_norm, f_floor, d_norm, last[active], scale)
        idx = active[done]
        iterations[idx] = it + 1
        if midpoint:  # x1 = x0 + dT J grad s(z)
            out[idx] = x[idx] + dt[idx, None] * jg[done]
        else:
            out[idx, :n] = x[idx, :n] + dt[idx, None] * g[done, n:]
            out[idx, n:] = ua[done]
        if failed.any():
            iterations[active[~done]] = it + 1  # the others' outcomes are left open
            iterations[rest] = it + 1
            bad = active[failed]
            codes[bad] = np.where(finite[failed], 2, 1)
            return out, _failure(codes, bad, it, f_norm[failed]), iterations
        keep = ~done
        stepped = active[keep]
        last[stepped] = d_norm[keep]
        better = keep & new_best
        improved = active[better]
        best[improved], since[improved] = merit[better], 0
        u_best[improved], d_best[improved] = ua[better], delta[better]
        fraction[stepped] = 1.0
        u[stepped] = ua[keep] - delta[keep]
        active = np.sort(np.concatenate([stepped, rest]))
        if active.size == 0:
            return out, None, iterations
    codes[active] = 3
    iterations[active] = max_iter
    return out, _failure(codes, active, max_iter, f_last[active]), iterations


def _failure(codes: np.ndarray, bad: np.ndarray, it: int, f_norm: np.ndarray):
    """``(codes, fail_iter, resid)`` (B,) of a batch whose instances ``bad`` failed at iteration ``it``."""
    fail_iter = np.full(len(codes), -1, dtype=np.int64)
    resid = np.zeros(len(codes))
    fail_iter[bad] = it
    resid[bad] = f_norm
    return codes, fail_iter, resid


def failure_error(
    codes, fail_step, fail_iter, resid, max_iter: int, midpoint: bool, contraction: Callable, step_index: bool = True
) -> Optional[NewtonConvergenceError]:
    """The one failure report of both paths (module docstring), or ``None`` when every instance converged.

    ``codes``, ``fail_step``, ``fail_iter``, ``resid`` (B,): per instance as the compiled rollout returns them
    (code 0 and step -1: no failure).  ``contraction(instances, step)`` returns ``dT L_S`` at those instances'
    start guesses of macro step ``step`` (:func:`contraction_estimate`).
    """
    failed = codes != 0
    if not np.any(failed):
        return None
    reasons = MIDPOINT_FAILURE_REASONS if midpoint else FAILURE_REASONS
    k = int(fail_step[failed].min())
    at = failed & (fail_step == k)
    sel = at & (fail_iter == fail_iter[at].min())
    code = min(int(c) for c in codes[sel])
    hit = np.flatnonzero(sel & (codes == code))
    return NewtonConvergenceError(
        hit,
        resid[hit],
        reason=reasons[code].format(max_iter=max_iter),
        step=k if step_index else None,
        contraction=contraction(hit, k),
    )


def _solve_numpy(sur, x, weights, dt, max_iter: int, midpoint: bool) -> np.ndarray:
    """One implicit step (module docstring) for a validated batch, from the explicit guess; raises the report."""
    x = np.asarray(x, dtype=float)
    dt = np.asarray(dt, dtype=float)
    u = start_guess(sur, x[:, None], weights, dt, midpoint, False)
    x1, failure, _ = _newton(sur, x, u, weights, dt, max_iter, midpoint)
    if failure is not None:
        codes, fail_iter, resid = failure
        raise failure_error(
            codes,
            np.where(codes != 0, 0, -1),
            fail_iter,
            resid,
            max_iter,
            midpoint,
            lambda i, k: contraction_estimate(
                sur, x[i], start_guess(sur, x[i, None], weights[i], dt[i], midpoint, False), weights[i], dt[i], midpoint
            ),
            step_index=False,
        )
    return x1


def solve_midpoint_numpy(
    sur: HBSurrogate, x: np.ndarray, weights: np.ndarray, dt: np.ndarray, max_iter: int
) -> np.ndarray:
    """One step of the symmetric (midpoint) generating-function update (NumPy reference).

    ``x1 = x0 + dT J grad s(z)`` with the midpoint ``z = (x0 + x1) / 2``, by the
    algorithm of the module docstring (Newton on the ``2n`` unknowns ``z`` from the
    explicit guess).  ``dt`` may be negative: with the same ``s`` (the same
    ``weights``) the step with ``-dT`` inverts the step with ``dT``.

    Arguments, result and failure report as :func:`solve_step_numpy` (``sur`` trained on
    midpoints, see :class:`~sympredict.estimators.predictor.SymplecticKernelPredictor` ``update``).

    Notes
    -----
    Cost per iteration ``O(B_active m (2n)^2)`` for the full Hessian
    (:meth:`HBSurrogate.gradient_hessian`) plus a ``(2n)^3`` solve per instance.
    """
    return _solve_numpy(sur, x, weights, dt, max_iter, True)


def midpoint_jacobian(hess: np.ndarray, dt: np.ndarray) -> np.ndarray:
    """``D Phi = (I - A)^{-1} (I + A)``, ``A = dT/2 J Hess s(z)``, of the midpoint update (B, 2n, 2n).

    From ``dx1 = dx0 + dT/2 J H (dx0 + dx1)``.  ``J H`` is Hamiltonian, so this
    Cayley transform is symplectic: ``D Phi^T J D Phi = J``.
    """
    eye = np.eye(hess.shape[-1])
    jh = _j_times(hess.transpose(0, 2, 1)).transpose(0, 2, 1)  # J H: J applied to each column
    a = 0.5 * dt[:, None, None] * jh
    return np.linalg.solve(eye - a, eye + a)


def solve_step_numpy(sur: HBSurrogate, x: np.ndarray, weights: np.ndarray, dt: np.ndarray, max_iter: int) -> np.ndarray:
    """One implicit symplectic-Euler step for a validated batch (NumPy reference; the module docstring's algorithm).

    Parameters
    ----------
    sur
        The fitted surrogate.
    x : ndarray of shape (B, 2n)
    weights : ndarray of shape (B, m)
        :meth:`HBSurrogate.weights` of the instances' ``(mu, dT)``.
    dt : ndarray of shape (B,)
    max_iter
        Newton iterations at most.

    Returns
    -------
    ndarray of shape (B, 2n)

    Raises
    ------
    NewtonConvergenceError
        Naming the instances (module docstring).

    Notes
    -----
    All instances advance together; converged instances leave the active
    set.  Cost per iteration ``O(B_active m (2n + n^2))`` (:meth:`HBSurrogate.newton_terms`).
    """
    return _solve_numpy(sur, x, weights, dt, max_iter, False)


def _window(traj: np.ndarray, previous: np.ndarray, k: int) -> np.ndarray:
    """The states up to step ``k``'s input, at most ``WARM_HISTORY`` before it (B, j+1, 2n), oldest first."""
    if k >= WARM_HISTORY or previous.shape[1] == 0:
        return traj[:, max(0, k - WARM_HISTORY) : k + 1]
    return np.concatenate([previous, traj[:, : k + 1]], axis=1)[:, -(WARM_HISTORY + 1) :]


#: The implementations :func:`implicit_rollout` runs.
BACKENDS = ("numpy", "numba")


def implicit_rollout(
    sur: HBSurrogate,
    x,
    weights,
    dt,
    n_steps: int,
    max_iter: int,
    *,
    backend: str = "numpy",
    step_index: bool = True,
    warm_start: bool = False,
    update: str = "symplectic_euler",
    around=None,
    weights_ordered: bool = False,
    previous=None,
    stats: Optional[dict] = None,
) -> np.ndarray:
    """``n_steps`` implicit steps of the module docstring's algorithm, in NumPy or in compiled code.

    Parameters
    ----------
    sur : HBSurrogate
        The fitted surrogate.
    x : ndarray of shape (B, 2n)
        Initial states.
    weights : ndarray of shape (B, m)
        :meth:`HBSurrogate.weights` of the instances' ``(mu, dT)``.
    dt : ndarray of shape (B,)
    n_steps : int
        ``K >= 0``.
    max_iter : int
        Newton iterations per step at most.
    backend : {'numpy', 'numba'}, default='numpy'
        ``'numpy'``: the reference, batched over the instances (converged instances leave the active set, cost per
        iteration ``O(B_active m (2n + n^2))``); ``'numba'``: one compiled call
        (:func:`sympredict.symplectic._compiled_newton.newton_rollout`), instance by instance on numba's threads.
        The same algorithm and failure report; results equal to round-off.
    step_index : bool, default=True
        Name the macro step in the error.
    warm_start : bool, default=False
        Start Newton from the extrapolation of the previous states when there are any (module docstring).
    update : {'symplectic_euler', 'midpoint'}, default='symplectic_euler'
        The implicit step (as :func:`solve_step_numpy` or :func:`solve_midpoint_numpy`).
    around : tuple of two ndarray of shape (B, 2n, 2n), default=None
        ``(pre, post)``: steps ``x_k+1 = post S(pre x_k)``; not with ``warm_start``.
    weights_ordered : bool, default=False
        ``weights`` are already in the compiled layout's centre order (:func:`ordered_weights`; a chunked compiled
        rollout orders them once, not per chunk).
    previous : ndarray of shape (B, j, 2n), default=None
        The rollout's states before ``x`` (oldest first; the last ``WARM_HISTORY`` are used): a
        warm start continues from them (:func:`rollout_in_chunks` passes them between chunks).
    stats : dict, default=None
        If a dict, ``stats['passes']`` receives the passes over the centres per instance, shape (B,).

    Returns
    -------
    ndarray of shape (B, K+1, 2n)

    Raises
    ------
    NewtonConvergenceError
        The report of the module docstring, with the macro step (``step_index``).
    """
    midpoint = _check_update(update)
    compiled = as_choice(backend, "backend", BACKENDS) == "numba"
    if weights_ordered and not compiled:  # the reference takes them in the surrogate's centre order
        weights = np.asarray(weights, dtype=np.float64)[:, np.argsort(sur.layout().order)]
    args = (sur, x, weights, dt, int(n_steps), max_iter, midpoint, warm_start, around, previous, stats)
    traj, failure = _compiled_rollout(*args, weights_ordered) if compiled else _numpy_rollout(*args)
    if failure is not None:
        codes, fail_step, fail_iter, resid, contraction = failure
        raise failure_error(codes, fail_step, fail_iter, resid, max_iter, midpoint, contraction, step_index)
    return traj


def _numpy_rollout(sur, x, weights, dt, n_steps, max_iter, midpoint, warm_start, around, previous, stats):
    """:func:`implicit_rollout` in NumPy: ``(traj, failure)``, ``failure`` ``None`` or the arguments of
    :func:`failure_error` that the instances' state gives (at the first macro step where any fails)."""
    x = np.asarray(x, dtype=np.float64)
    dt = np.asarray(dt, dtype=np.float64)
    b, dim = x.shape
    maps = _compiled_newton.check_around(around, b, dim, warm_start)
    previous = _compiled_newton.previous_states(previous, b, dim)
    traj = np.empty((b, n_steps + 1, dim))
    traj[:, 0] = x
    passes = np.zeros(b, dtype=np.int64)
    for k in range(n_steps):
        if maps is None:
            window = _window(traj, previous, k)
        else:
            window = np.einsum("bij,bj->bi", maps[0], traj[:, k])[:, None]
        warm = warm_start and window.shape[1] >= 2
        u = start_guess(sur, window, weights, dt, midpoint, warm)
        passes += 0 if warm else 1
        y = window[:, -1]
        x1, failure, iterations = _newton(sur, y, u, weights, dt, max_iter, midpoint)
        passes += iterations
        if failure is not None:
            if stats is not None:
                stats["passes"] = passes
            codes, fail_iter, resid = failure

            def contraction(i, kk, y=y, window=window, warm=warm):  # dT L_S at the failed step's start guesses
                guess = start_guess(sur, window[i], weights[i], dt[i], midpoint, warm)
                return contraction_estimate(sur, y[i], guess, weights[i], dt[i], midpoint)

            return traj, (codes, np.where(codes != 0, k, -1), fail_iter, resid, contraction)
        traj[:, k + 1] = x1 if maps is None else np.einsum("bij,bj->bi", maps[1], x1)
    if stats is not None:
        stats["passes"] = passes
    return traj, None


def rollout_numpy(advance, x: np.ndarray, n_steps: int) -> np.ndarray:
    """``n_steps`` steps ``x <- advance(x)`` (B, K+1, 2n); a failure names its macro step (any explicit map)."""
    traj = np.empty((len(x), n_steps + 1, x.shape[1]))
    traj[:, 0] = x
    for k in range(n_steps):
        try:
            traj[:, k + 1] = advance(traj[:, k])
        except NewtonConvergenceError as err:
            raise err.at_step(k) from None
    return traj


#: A chunk of a long rollout aims at this wall time (seconds): between chunks Python runs, so Ctrl-C
#: (KeyboardInterrupt) and progress reports are served at least this often, also on the compiled path.
CHUNK_SECONDS = 0.2
#: ... and its trajectory holds at most this many bytes (the rollout keeps only the strided states).
CHUNK_BYTES = 32 * 2**20
#: The first chunk's steps: short rollouts run in one call, longer ones learn the time per step from it.
FIRST_CHUNK_STEPS = 64
#: A chunk is at most this many times the previous one (the time per step of a short chunk is a noisy estimate).
CHUNK_GROWTH = 8


def available_memory() -> Optional[int]:
    """Bytes of memory the system reports available (Linux ``MemAvailable``; ``None`` where unknown)."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return None


def rollout_in_chunks(
    run: Callable[..., np.ndarray],
    x: np.ndarray,
    n_steps: int,
    *,
    stride: int = 1,
    progress: Optional[Callable[[int, int], None]] = None,
    history: int = 0,
) -> np.ndarray:
    """A rollout of ``n_steps`` in chunks, keeping every ``stride``-th state: ``traj[:, ::stride]`` of the full one.

    Parameters
    ----------
    run
        ``run(state, k)`` returns the trajectory (B, k+1, 2n) of ``k >= 1`` steps from ``state`` (B, 2n)
        (one call of a model's NumPy or compiled rollout).
    x : ndarray of shape (B, 2n)
        Initial states.
    n_steps
        ``K >= 0``.
    stride
        Keep the states at steps ``0, stride, 2 stride, ... <= K``.
    progress
        Called as ``progress(steps_done, n_steps)`` after each chunk.
    history
        ``h > 0``: ``run`` is called as ``run(state, k, previous)`` with the rollout's last ``h`` states
        before ``state`` (B, j, 2n), ``j <= h``, oldest first (``None`` at the first chunk): what a
        Newton warm start extrapolates from (:data:`WARM_HISTORY`), so that it goes on across chunks.

    Returns
    -------
    ndarray of shape (B, K // stride + 1, 2n)

    Raises
    ------
    RolloutMemoryError
        Before any work, when the kept states need more memory than the system has available.
    NewtonConvergenceError
        As the chunk's rollout raises it, with the macro step counted from the rollout's start.

    Notes
    -----
    Memory ``O(B (K / stride + chunk) 2n)``.  Chunks are timed and sized to take about
    :data:`CHUNK_SECONDS` (at most :data:`CHUNK_BYTES` of states), so Ctrl-C interrupts a compiled
    rollout within about that time.  Each step depends only on the states before it (the last one,
    and with ``history`` the ones a warm start extrapolates from), so the result equals the
    unchunked rollout bit for bit.
    """
    b, dim = x.shape
    n_kept = n_steps // stride + 1
    needed = b * n_kept * dim * 8
    available = available_memory() if needed > CHUNK_BYTES else None  # small rollouts skip reading /proc
    if available is not None and needed > available:
        raise RolloutMemoryError(needed, available, (b, n_kept, dim))
    out = np.empty((b, n_kept, dim))
    out[:, 0] = x
    state, done = x, 0
    previous = None
    max_chunk = max(1, CHUNK_BYTES // (8 * max(1, b * dim)))
    chunk = min(FIRST_CHUNK_STEPS, max_chunk)
    while done < n_steps:
        k = min(chunk, n_steps - done)
        start = time.perf_counter()
        try:
            traj = run(state, k, previous) if history > 0 else run(state, k)
        except NewtonConvergenceError as err:
            raise (err.at_step(done + err.step) if err.step is not None else err) from None
        elapsed = time.perf_counter() - start
        first = -(-(done + 1) // stride) * stride  # the first kept step after `done`
        kept = np.arange(first, done + k + 1, stride)
        if kept.size:
            out[:, kept // stride] = traj[:, kept - done]
        state = np.ascontiguousarray(traj[:, -1])
        if history > 0:  # the states before the next chunk's first, oldest first
            before = traj[:, max(0, k - history) : k]
            if previous is not None and before.shape[1] < history:
                before = np.concatenate([previous, before], axis=1)[:, -history:]
            previous = np.ascontiguousarray(before)
        done += k
        if progress is not None:
            progress(done, n_steps)
        # the next chunk: about CHUNK_SECONDS at the speed just measured, at most CHUNK_GROWTH times this one
        per_step = elapsed / k
        grown = CHUNK_GROWTH * k
        chunk = int(min(max_chunk, grown, max(1.0, CHUNK_SECONDS / per_step) if per_step > 0 else grown))
    return out


def ordered_weights(sur: HBSurrogate, weights: np.ndarray) -> np.ndarray:
    """``weights`` (B, m) in the compiled layout's centre order, C-contiguous float64 (one copy, ``O(B m)``)."""
    return np.ascontiguousarray(np.asarray(weights, dtype=np.float64)[:, sur.layout().order])


def _compiled_rollout(
    sur, x, weights, dt, n_steps, max_iter, midpoint, warm_start, around, previous, stats, weights_ordered
):
    """:func:`implicit_rollout` in compiled code (:func:`sympredict.symplectic._compiled_newton.newton_rollout`):
    ``(traj, failure)`` as :func:`_numpy_rollout` returns them."""
    stats = {} if stats is None else stats
    traj, codes, fail_step, fail_iter, resid = _compiled_newton.newton_rollout(
        x,
        weights,
        dt,
        sur.layout(),
        sur.kernel.state,
        max_iter,
        n_steps,
        warm_start=warm_start,
        update="midpoint" if midpoint else "symplectic_euler",
        around=around,
        weights_ordered=weights_ordered,
        previous=previous,
        stats=stats,
    )

    def contraction(i, k):  # dT L_S at the start guesses of step k, from the states the compiled rollout kept
        w = np.asarray(weights, dtype=np.float64)[i]
        if weights_ordered:  # back to the surrogate's centre order
            w = w[:, np.argsort(sur.layout().order)]
        h = np.asarray(dt, dtype=np.float64)[i]
        if around is None:
            before = None if previous is None else np.asarray(previous, dtype=np.float64)[i]
            window = _window(traj[i], _compiled_newton.previous_states(before, len(i), traj.shape[2]), k)
        else:
            window = np.einsum("bij,bj->bi", np.asarray(around[0], dtype=np.float64)[i], traj[i, k])[:, None]
        warm = warm_start and window.shape[1] >= 2
        return contraction_estimate(sur, window[:, -1], start_guess(sur, window, w, h, midpoint, warm), w, h, midpoint)

    return traj, ((codes, fail_step, fail_iter, resid, contraction) if codes.any() else None)
