"""Newton solvers of the implicit steps (symplectic Euler, midpoint): the NumPy references and the compiled rollout.

Per instance, ``F(p1) = p1 - p0 + dT d_q s(q0, p1) = 0`` with Jacobian
``I + dT d_p d_q s``; then ``q1 = q0 + dT d_p s(q0, p1)``.  Both solvers start
from the explicit guess ``p1 ~ p0 - dT d_q s(q0, p0)`` and stop each instance
by the one stopping rule of :mod:`sympredict.newton_rule`.  A failed solve
raises :class:`~sympredict.exceptions.NewtonConvergenceError` naming the
instances of the first failing macro step and, within it, of the first
failing Newton iteration (non-finite residual before a singular Jacobian
before no convergence): the same report from both backends.
"""

from __future__ import annotations

import os
import time
from typing import Callable, Optional

import numpy as np

from sympredict import _fastkernels
from sympredict.exceptions import NewtonConvergenceError, RolloutMemoryError
from sympredict.symplectic.metrics import j_times
from sympredict.newton_rule import EPS, converged, residual_floor
from sympredict.interpolation.surrogate import HBSurrogate

__all__ = ["solve_step_numpy", "solve_midpoint_numpy", "midpoint_jacobian", "rollout_numpy", "rollout_compiled",
           "rollout_in_chunks", "ordered_weights", "available_memory", "FAILURE_REASONS", "MIDPOINT_FAILURE_REASONS"]

#: Failure codes of the compiled solver and the reason each names.
FAILURE_REASONS = {
    1: "produced a non-finite iterate",
    2: "hit a singular Jacobian I + dT d_p d_q s",
    3: "did not converge in {max_iter} iterations",
}

#: The same codes for the midpoint update (its Jacobian is ``I - dT/2 J Hess s``).
MIDPOINT_FAILURE_REASONS = {**FAILURE_REASONS, 2: "hit a singular Jacobian I - dT/2 J Hess s"}


_j_times = j_times  # ``J v`` on the last axis (sympredict.symplectic.metrics)


def _newton_update(active, F, jac, f_floor, scale, last_update, reasons):
    """One batched Newton update of both NumPy solvers: residual check, solve, stopping rule.

    ``F`` (B_active, k) and ``jac`` (B_active, k, k) at the active instances
    ``active``; raises :class:`NewtonConvergenceError` for a non-finite residual
    or a singular Jacobian (``reasons[1]``, ``reasons[2]``), naming the
    instances.  Returns the update ``delta``, its norm, which instances are
    done (:func:`~sympredict.newton_rule.converged`) and ``|F|_inf``.
    """
    f_norm = np.abs(F).max(axis=1)
    bad = ~np.isfinite(f_norm)
    if np.any(bad):
        raise NewtonConvergenceError(active[bad], f_norm[bad], reason=reasons[1])
    try:
        delta = np.linalg.solve(jac, F[:, :, None])[:, :, 0]
    except np.linalg.LinAlgError:
        singular = np.abs(np.linalg.det(jac)) <= EPS
        raise NewtonConvergenceError(active[singular], f_norm[singular], reason=reasons[2]) from None
    d_norm = np.abs(delta).max(axis=1)
    return delta, d_norm, converged(f_norm, f_floor, d_norm, last_update[active], scale), f_norm


def solve_midpoint_numpy(sur: HBSurrogate, x: np.ndarray, weights: np.ndarray, dt: np.ndarray,
                         max_iter: int) -> np.ndarray:
    """One step of the symmetric (midpoint) generating-function update (NumPy reference).

    ``x1 = x0 + dT J grad s(z)`` with the midpoint ``z = (x0 + x1) / 2``: per
    instance Newton's method on the ``2n`` unknowns ``z``,
    ``F(z) = z - x0 - dT/2 J grad s(z) = 0`` with Jacobian ``I - dT/2 J Hess s(z)``,
    from the explicit guess ``z = x0 + dT/2 J grad s(x0)``; then
    ``x1 = x0 + dT J grad s(z)``.  Stopped by the one rule of
    :mod:`sympredict.newton_rule` with the half step ``dT/2`` in the residual
    floor and ``scale = max(|z|, |x0|)``.  ``dt`` may be negative: with the same
    ``s`` (the same ``weights``) the step with ``-dT`` inverts the step with ``dT``.

    Parameters
    ----------
    sur
        The fitted surrogate (trained on midpoints, see
        :class:`~sympredict.estimators.predictor.SymplecticKernelPredictor` ``update``).
    x : ndarray of shape (B, 2n)
    weights : ndarray of shape (B, m)
    dt : ndarray of shape (B,)
    max_iter
        Newton iterations at most.

    Returns
    -------
    ndarray of shape (B, 2n)

    Raises
    ------
    NewtonConvergenceError
        Naming the instances, as :func:`solve_step_numpy`.

    Notes
    -----
    Cost per iteration ``O(B_active m (2n)^2)`` for the full Hessian
    (:meth:`HBSurrogate.gradient_hessian`) plus a ``(2n)^3`` solve per instance.
    """
    half = 0.5 * dt[:, None]
    z = x + half * _j_times(sur.gradient(x, weights))
    out = np.empty_like(x)
    active = np.arange(len(x))
    last_update = np.full(len(x), np.inf)
    eye = np.eye(x.shape[1])
    for _ in range(max_iter):
        g, hess, floor = sur.gradient_hessian(z[active], weights[active], with_floor=True)
        ha = half[active]
        jg = _j_times(g)
        F = z[active] - x[active] - ha * jg
        scale = np.maximum(np.abs(z[active]).max(axis=1), np.abs(x[active]).max(axis=1))
        f_floor = residual_floor(scale, floor, np.abs(ha[:, 0]))
        jac = eye - ha[:, :, None] * _j_times(hess.transpose(0, 2, 1)).transpose(0, 2, 1)
        delta, d_norm, done, f_norm = _newton_update(active, F, jac, f_floor, scale, last_update, MIDPOINT_FAILURE_REASONS)
        idx = active[done]
        out[idx] = x[idx] + 2.0 * ha[done] * jg[done]
        keep = ~done
        active = active[keep]
        last_update[active] = d_norm[keep]
        z[active] -= delta[keep]
        if active.size == 0:
            return out
    raise NewtonConvergenceError(active, f_norm[keep], reason=MIDPOINT_FAILURE_REASONS[3].format(max_iter=max_iter))


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
    """One implicit symplectic-Euler step for a validated batch (NumPy reference).

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

    Notes
    -----
    All instances advance together; converged instances leave the active
    set.  Cost per iteration ``O(B_active m (2n + n^2))`` (:meth:`HBSurrogate.newton_terms`).
    """
    n = x.shape[1] // 2
    q0, p0 = x[:, :n], x[:, n:]
    h = dt[:, None]
    p = p0 - h * sur.gradient(x, weights)[:, :n]
    out = np.empty_like(x)
    active = np.arange(len(x))
    last_update = np.full(len(x), np.inf)
    eye = np.eye(n)
    for _ in range(max_iter):
        xi = np.concatenate([q0[active], p[active]], axis=1)
        g, hess_qp, floor = sur.newton_terms(xi, weights[active])
        ha = h[active]
        F = p[active] - p0[active] + ha * g[:, :n]
        scale = np.maximum(np.abs(p[active]).max(axis=1), np.abs(p0[active]).max(axis=1))
        f_floor = residual_floor(scale, floor, ha[:, 0])
        jac = eye + ha[:, :, None] * hess_qp
        delta, d_norm, done, f_norm = _newton_update(active, F, jac, f_floor, scale, last_update, FAILURE_REASONS)
        idx = active[done]
        out[idx, :n] = q0[idx] + ha[done] * g[done, n:]
        out[idx, n:] = p[idx]
        keep = ~done
        active = active[keep]
        last_update[active] = d_norm[keep]
        p[active] -= delta[keep]
        if active.size == 0:
            return out
    raise NewtonConvergenceError(active, f_norm[keep], reason=FAILURE_REASONS[3].format(max_iter=max_iter))


def rollout_numpy(advance, x: np.ndarray, n_steps: int) -> np.ndarray:
    """``n_steps`` steps ``x <- advance(x)`` (B, K+1, 2n); a failure names its macro step."""
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


def rollout_in_chunks(run: Callable[[np.ndarray, int], np.ndarray], x: np.ndarray, n_steps: int, *, stride: int = 1,
                      progress: Optional[Callable[[int, int], None]] = None) -> np.ndarray:
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
    rollout within about that time.  Each step depends only on the state before it, so the result
    equals the unchunked rollout bit for bit, except for a Newton warm start, which restarts from the
    explicit guess at each chunk's first step (equal to the solver's stopping rule).
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
    max_chunk = max(1, CHUNK_BYTES // (8 * max(1, b * dim)))
    chunk = min(FIRST_CHUNK_STEPS, max_chunk)
    while done < n_steps:
        k = min(chunk, n_steps - done)
        start = time.perf_counter()
        try:
            traj = run(state, k)
        except NewtonConvergenceError as err:
            raise (err.at_step(done + err.step) if err.step is not None else err) from None
        elapsed = time.perf_counter() - start
        first = -(-(done + 1) // stride) * stride  # the first kept step after `done`
        kept = np.arange(first, done + k + 1, stride)
        if kept.size:
            out[:, kept // stride] = traj[:, kept - done]
        state = np.ascontiguousarray(traj[:, -1])
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


def rollout_compiled(sur: HBSurrogate, x, weights, dt, n_steps: int, max_iter: int, step_index: bool = True,
                     warm_start: bool = False, update: str = "symplectic_euler", around=None,
                     weights_ordered: bool = False):
    """``n_steps`` steps in compiled code (:func:`sympredict._fastkernels.newton_rollout`); failures raise as the NumPy path's.

    ``weights_ordered``: ``weights`` are already in the compiled layout's centre order
    (:func:`ordered_weights`; a chunked rollout orders them once, not per chunk).
    ``warm_start``: Newton starts from the previous step's increment (from the second step on).
    ``update``: ``'symplectic_euler'`` (as :func:`solve_step_numpy`) or ``'midpoint'``
    (as :func:`solve_midpoint_numpy`).
    ``around``: ``None`` or ``(pre, post)`` (B, 2n, 2n): steps ``x_k+1 = post S(pre x_k)``.

    Returns
    -------
    ndarray of shape (B, K+1, 2n)
    """
    traj, codes, fail_step, fail_iter, resid = _fastkernels.newton_rollout(
        x, weights, dt, sur.layout(), sur.kernel.state, max_iter, n_steps, warm_start=warm_start, update=update,
        around=around, weights_ordered=weights_ordered)
    reasons = MIDPOINT_FAILURE_REASONS if update == "midpoint" else FAILURE_REASONS
    failed = codes != 0
    if np.any(failed):
        k = fail_step[failed].min()
        at = failed & (fail_step == k)
        sel = at & (fail_iter == fail_iter[at].min())
        for code in (1, 2, 3):
            hit = sel & (codes == code)
            if np.any(hit):
                err = NewtonConvergenceError(np.flatnonzero(hit), resid[hit], reason=reasons[code].format(max_iter=max_iter))
                raise (err.at_step(int(k)) if step_index else err)
    return traj
