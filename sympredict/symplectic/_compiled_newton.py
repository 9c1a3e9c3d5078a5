"""The compiled (numba) Newton rollout: the prediction hot path.

The implicit symplectic-Euler step solves, per instance,
``F(p) = p - p0 + dT d_q s(q0, p) = 0`` by Newton with Jacobian
``I + dT d_p d_q s``; the symmetric (midpoint) update solves
``F(z) = z - x0 - dT/2 J grad s(z) = 0`` for the midpoint ``z`` with Jacobian
``I - dT/2 J Hess s(z)``.  The NumPy paths (:func:`sympredict.symplectic.newton.solve_step_numpy`,
:func:`sympredict.symplectic.newton.solve_midpoint_numpy`, ``backend='numpy'``) are the
references; the functions here compute the same iterations, instance by
instance, in compiled code (one solver, the update a flag):

* one fused pass over the ``m`` centres per Newton iteration
  (:func:`sympredict.interpolation._compiled._pass`) computes the gradient of
  ``s``, the part of its Hessian the Jacobian needs (the ``n x n`` block
  ``d_p d_q s``, or for the midpoint update the upper triangle of the full
  ``2n x 2n`` Hessian) and the round-off floor of the gradient, in
  ``O((2n + 6) * chunk)`` scratch per thread; results stay bit-reproducible run
  to run, across batch sizes and threads (tested);
* every instance iterates only until it has converged, with the stopping rule
  of the reference (:mod:`sympredict.newton_rule`: the same function);
* a whole rollout of ``K`` steps runs in one call, instances in parallel
  (``numba.prange``) when the batch is large enough, serially for one
  trajectory (latency).

Results agree with the NumPy reference to round-off (summation order differs):
``tests/estimators/test_performance_paths.py`` checks trajectories to ``1e-12`` on a
well-conditioned model and to the gradient's round-off floor on an
ill-conditioned one, where NumPy does not agree with itself across batch sizes
either.

The kernel formulas come from :mod:`sympredict.kernels._compiled`, the numba
policy (flags, the disk cache, threads) from :mod:`sympredict._numba`.

Failure codes returned per instance: 0 converged, 1 non-finite residual,
2 singular Jacobian (exact zero pivot), 3 no convergence in ``max_iter``
iterations.
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np

from sympredict import _numba
from sympredict._numba import JIT, PJIT, call, check_available, compiled, numba, parallel_safe
from sympredict._checks import as_choice
from sympredict._numeric import lu_solve_inplace
from sympredict.interpolation._compiled import CenterLayout, _pass, _scratch, chunk_size
from sympredict.kernels._compiled import family_kernels
from sympredict.newton_rule import WATCHDOG, accepted, converged, residual_floor

__all__ = [
    "rollout_loaded",
    "newton_rollout",
    "newton_solve",
    "check_around",
    "previous_states",
    "UPDATES",
    "WARM_HISTORY",
]

#: Batches below this size are solved on one thread (thread start-up costs more).
PARALLEL_MIN_BATCH = 8


def rollout_loaded() -> bool:
    """Whether this process has the compiled Newton rollout loaded already (compiled or read from the cache)."""
    return _numba.HAVE_NUMBA and bool(_rollout_serial.signatures or _rollout_parallel.signatures)


@compiled(JIT)
def _solve_one(x, w, h, cT, seg, family, eps, per, max_iter, out, sc, grad, hess, jac, delta, u, xi, warm, mid):
    """One implicit step for one instance: ``out <- Phi(x)``.  Returns ``(code, residual, iteration)``.

    The algorithm of :mod:`sympredict.symplectic.newton` (its module docstring; the NumPy
    reference :func:`sympredict.symplectic.newton.implicit_rollout`), for one instance:
    symplectic Euler (``mid`` False): unknowns ``u = p1``,
    ``F = p1 - p0 + dT d_q s(q0, p1)``, Jacobian ``I + dT d_p d_q s``; midpoint
    (``mid`` True): unknowns ``u = z = (x0 + x1) / 2``, ``F = z - x0 - dT/2 J grad s(z)``,
    Jacobian ``I - dT/2 J Hess s(z)``.  ``u`` holds the first guess when ``warm``.
    The iteration count returned is that of the failure (``max_iter`` for code 3)
    or of the converged iterate.
    """
    dim = x.shape[0]
    n = dim // 2
    k = u.shape[0]  # unknowns: n (symplectic Euler) or 2n (midpoint)
    hh = 0.5 * h if mid else h  # the step in the residual
    if not warm:  # explicit guess from the gradient at x0: one pass over the centres
        _pass(x, w, cT, seg, family, eps, 0, per, sc, grad, hess)
        if mid:  # z ~ x0 + dT/2 J grad s(x0)
            for a in range(n):
                u[a] = x[a] + hh * grad[n + a]
                u[n + a] = x[n + a] + hh * -grad[a]
        else:  # p1 ~ p0 - dT d_q s(q0, p0)
            for a in range(n):
                u[a] = x[n + a] - h * grad[a]
    if not mid:
        for a in range(n):
            xi[a] = x[a]
    last = np.inf
    f_norm = np.inf
    # the watchdog (sympredict.newton_rule): the best iterate, its update and |F|_2, passes since, the step fraction
    u_best = np.empty(k)
    d_best = np.zeros(k)
    best = np.inf
    since = 0
    fraction = 1.0  # below 1: a damped trial from the best iterate
    for it in range(max_iter):
        for a in range(k):
            xi[dim - k + a] = u[a]
        floor = _pass(xi, w, cT, seg, family, eps, 2 if mid else 1, per, sc, grad, hess)
        f_norm = 0.0
        merit = 0.0
        scale = 0.0
        finite = True
        for a in range(k):
            if mid:
                jg = grad[n + a] if a < n else -grad[a - n]
                fk = u[a] - x[a] - hh * jg
                x_ref = x[a]
            else:
                fk = u[a] - x[n + a] + h * grad[a]
                x_ref = x[n + a]
            delta[a] = fk
            merit += fk * fk
            if not math.isfinite(fk):
                finite = False
            af = abs(fk)
            if af > f_norm or af != af:  # NaN propagates, as NumPy's max
                f_norm = af
            ap = abs(u[a])
            if ap > scale:
                scale = ap
            ap = abs(x_ref)
            if ap > scale:
                scale = ap
        f_floor = residual_floor(scale, floor, abs(hh))
        merit = math.sqrt(merit)
        new_best = accepted(merit, best, fraction, f_norm, f_floor)
        if fraction < 1.0 and not new_best:  # a damped trial rejected: halve it again
            fraction *= 0.5
            for a in range(k):
                u[a] = u_best[a] - fraction * d_best[a]
            continue
        if fraction == 1.0 and not new_best:
            since += 1
            if since >= WATCHDOG or not finite:  # no progress: back to the best iterate, a line search from it
                fraction = 0.5
                for a in range(k):
                    u[a] = u_best[a] - fraction * d_best[a]
                continue
        if not finite:
            return 1, f_norm, it
        if mid:  # I - dT/2 J H: rows of J H are (H[n + a], -H[a])
            for a in range(n):
                for c in range(dim):
                    jac[a, c] = -(hh * hess[n + a, c])
                    jac[n + a, c] = hh * hess[a, c]
        else:
            for a in range(n):
                for c in range(n):
                    jac[a, c] = h * hess[a, c]
        for a in range(k):
            jac[a, a] += 1.0
        if not lu_solve_inplace(jac, delta):  # the residual becomes the Newton update
            return 2, f_norm, it
        d_norm = 0.0
        for a in range(k):
            v = abs(delta[a])
            if v > d_norm or v != v:
                d_norm = v
        if converged(f_norm, f_floor, d_norm, last, scale):
            if mid:  # x1 = x0 + dT J grad s(z)
                for a in range(n):
                    out[a] = x[a] + h * grad[n + a]
                    out[n + a] = x[n + a] + h * -grad[a]
            else:
                for a in range(n):
                    out[a] = x[a] + h * grad[n + a]
                    out[n + a] = u[a]
            return 0, f_norm, it
        last = d_norm
        if new_best:
            best = merit
            since = 0
            for a in range(k):
                u_best[a] = u[a]
                d_best[a] = delta[a]
        fraction = 1.0
        for a in range(k):
            u[a] -= delta[a]
    return 3, f_norm, max_iter


@compiled(JIT)
def _matvec_into(M, x, out):
    """``out <- M x`` for a small square ``M`` (the split rollout's maps), ``O(dim^2)``."""
    for a in range(M.shape[0]):
        acc = 0.0
        for c in range(M.shape[1]):
            acc += M[a, c] * x[c]
        out[a] = acc


@compiled(JIT)
def _state(traj, prev, i, j, c):
    """Component ``c`` of instance ``i``'s state ``j`` of the rollout; ``j < 0``: the states before it (``prev``)."""
    if j >= 0:
        return traj[i, j, c]
    return prev[i, prev.shape[1] + j, c]


@compiled(JIT)
def _instance_scratch(dim, k_unknown, chunk, periodic):
    """One instance's work arrays: the pass's scratch, ``grad``, ``hess``, ``jac``, ``u``, ``delta``, ``xi`` and the
    split step's input and output ``y_in``, ``y_out``.  Allocated in a call, so that each instance of a parallel loop
    gets its own (numba may hoist an allocation written in the loop body out of the loop)."""
    return (
        _scratch(dim, chunk, periodic),
        np.empty(dim),
        np.empty((dim, dim)),
        np.empty((k_unknown, k_unknown)),
        np.empty(k_unknown),
        np.empty(k_unknown),
        np.empty(dim),
        np.empty(dim),
        np.empty(dim),
    )


def _rollout(
    x0,
    W,
    h,
    cT,
    seg,
    family,
    eps,
    per,
    max_iter,
    chunk,
    traj,
    codes,
    fail_step,
    fail_iter,
    resid,
    passes,
    warm_start,
    mid,
    pre,
    post,
    around,
    prev,
):
    """Every instance's rollout; with ``around``: ``x_k+1 = post[i] S(pre[i] x_k)`` (S the implicit step).

    ``prev`` (B, j, 2n): the rollout's states before ``x0`` (oldest first), which a warm start extrapolates from.
    Compiled twice: ``_rollout_parallel`` runs the instances on numba's threads, ``_rollout_serial`` in a plain
    loop (one trajectory's latency).
    """
    dim = x0.shape[1]
    n = dim // 2
    k_unknown = dim if mid else n
    n_steps = traj.shape[1] - 1
    n_prev = prev.shape[1]
    for i in numba.prange(x0.shape[0]):
        sc, grad, hess, jac, u, delta, xi, y_in, y_out = _instance_scratch(dim, k_unknown, chunk, per.shape[0] > 0)
        for a in range(dim):
            traj[i, 0, a] = x0[i, a]
        codes[i] = 0
        fail_step[i] = -1
        fail_iter[i] = -1
        resid[i] = 0.0
        for k in range(n_steps):
            before = k + n_prev  # states before x_k
            warm = warm_start and before > 0
            if warm:  # extrapolate the previous steps: saves the explicit guess's pass
                off = 0 if mid else n
                for a in range(k_unknown):
                    x_k = traj[i, k, off + a]
                    x_1 = _state(traj, prev, i, k - 1, off + a)
                    if before >= 2:  # x_k+1 ~ 3 x_k - 3 x_k-1 + x_k-2 (error O(dT^3))
                        nxt = 3.0 * (x_k - x_1) + _state(traj, prev, i, k - 2, off + a)
                    else:  # x_k+1 ~ 2 x_k - x_k-1 (error O(dT^2))
                        nxt = 2.0 * x_k - x_1
                    u[a] = 0.5 * (x_k + nxt) if mid else nxt  # midpoint: z = (x_k + x_k+1) / 2
            x_in, x_out = traj[i, k], traj[i, k + 1]
            if around:  # the step maps pre x_k to y_out; x_k+1 = post y_out
                _matvec_into(pre[i], traj[i, k], y_in)
                x_in, x_out = y_in, y_out
            code, r, it = _solve_one(
                x_in,
                W[i],
                h[i],
                cT,
                seg,
                family,
                eps,
                per,
                max_iter,
                x_out,
                sc,
                grad,
                hess,
                jac,
                delta,
                u,
                xi,
                warm,
                mid,
            )
            if around:
                _matvec_into(post[i], y_out, traj[i, k + 1])
            # (the explicit guess's gradient pass and) the Newton passes: it + 1, or max_iter without convergence
            passes[i] += (max_iter if code == 3 else it + 1) + (0 if warm else 1)
            if code != 0:
                codes[i] = code
                fail_step[i] = k
                fail_iter[i] = it
                resid[i] = r
                for kk in range(k + 1, n_steps + 1):
                    for a in range(dim):
                        traj[i, kk, a] = np.nan
                break


_rollout_parallel = compiled(PJIT, "_rollout_parallel")(_rollout)
_rollout_serial = compiled(JIT, "_rollout_serial")(_rollout)


#: The updates the compiled rollout solves (``mid`` flag of the compiled solver).
UPDATES = ("symplectic_euler", "midpoint")

#: Previous states a warm start extrapolates from.
WARM_HISTORY = 2


def check_around(around, b: int, dim: int, warm_start: bool):
    """``(pre, post)`` of a split rollout as C-contiguous float arrays (B, 2n, 2n), or ``None``; checked.

    Shared by the compiled rollout and the NumPy reference (:func:`sympredict.symplectic.newton.implicit_rollout`).
    """
    if around is None:
        return None
    if warm_start:
        raise ValueError("newton_rollout: warm_start cannot be combined with around (pre, post maps)")
    pre, post = (np.ascontiguousarray(a, dtype=np.float64) for a in around)
    if pre.shape != (b, dim, dim) or post.shape != (b, dim, dim):
        raise ValueError(f"around: pre and post must have shape {(b, dim, dim)}, got {pre.shape} and {post.shape}")
    return pre, post


def previous_states(previous, b: int, dim: int) -> np.ndarray:
    """The states before a rollout's first, (B, j, 2n) with ``j <= WARM_HISTORY``, oldest first, C-contiguous
    (``None``: ``j = 0``); shared by both rollouts."""
    if previous is None:
        return np.empty((b, 0, dim))
    previous = np.asarray(previous, dtype=np.float64)
    if previous.ndim != 3 or previous.shape[0] != b or previous.shape[2] != dim:
        raise ValueError(f"previous must have shape (B, j, 2n) = ({b}, j, {dim}), got {previous.shape}")
    return np.ascontiguousarray(previous[:, max(0, previous.shape[1] - WARM_HISTORY) :])


def newton_rollout(
    x0,
    weights,
    dt,
    layout: CenterLayout,
    kernel,
    max_iter: int,
    n_steps: int,
    *,
    weights_ordered: bool = False,
    parallel=None,
    stats: Optional[dict] = None,
    warm_start: bool = False,
    update: str = "symplectic_euler",
    around=None,
    previous=None,
):
    """``n_steps`` implicit steps (symplectic Euler or midpoint) for every instance, in compiled code.

    Parameters
    ----------
    x0 : ndarray of shape (B, 2n)
        Initial states.
    weights : ndarray of shape (B, m)
        Centre weights ``c_j k_mu k_dT`` per instance (:meth:`HBSurrogate.weights`), in the
        surrogate's centre order (or in ``layout.order`` when ``weights_ordered``).
    dt : ndarray of shape (B,)
        Macro steps.
    layout
        The centres (:class:`CenterLayout`).
    kernel
        The state kernel (a :class:`~sympredict.kernels.RadialKernel`; any registered family).
    max_iter
        Newton iterations per step.
    n_steps
        Number of macro steps ``K``.
    parallel
        Run instances on numba's threads; default: when ``B >= 8``.
    stats
        If a dict, ``stats['passes']`` receives the passes over the centres per
        instance (one per gradient or Newton evaluation), shape (B,).
    warm_start
        From the second state of the rollout on (counting ``previous``), start
        Newton from an extrapolation of the previous states instead of the
        explicit guess ``p0 - dT d_q s(q0, p0)``: saves that guess's pass over the
        centres.  ``p_k+1 ~ 3 p_k - 3 p_k-1 + p_k-2`` (error ``O(dT^3)``;
        ``2 p_k - p_k-1`` with one previous state), against the explicit guess's
        ``O(dT^2)``; for ``update='midpoint'`` the midpoint ``z = (x_k + x_k+1) / 2``
        with the same extrapolation of ``x_k+1``.  The converged result satisfies
        the same stopping rule.  Each instance stops iterating on its own
        (converged instances are dropped by construction: one loop per instance).
    previous : ndarray of shape (B, j, 2n), optional
        The rollout's states before ``x0``, oldest first (the last two are used): a
        warm start goes on from them (a chunked rollout's next chunk).
    update
        ``'symplectic_euler'``: ``F(p1) = p1 - p0 + dT d_q s(q0, p1)``, Jacobian
        ``I + dT d_p d_q s`` (``n`` unknowns, the Hessian block only);
        ``'midpoint'``: ``x1 = x0 + dT J grad s((x0 + x1) / 2)``, Newton on the
        midpoint ``z`` (``2n`` unknowns) with Jacobian ``I - dT/2 J Hess s(z)``
        (the full Hessian, its upper triangle computed).  The same pass, solver and
        stopping rule (:func:`sympredict.newton_rule.converged`) for both; they equal
        :func:`sympredict.symplectic.newton.solve_step_numpy` and
        :func:`sympredict.symplectic.newton.solve_midpoint_numpy` to round-off.
    around
        ``None``, or ``(pre, post)``, two arrays (B, 2n, 2n): each macro step is then
        ``x_k+1 = post S(pre x_k)`` with ``S`` the implicit step (the exact-linear-flow
        splitting, :class:`sympredict.flowmap.splitting.SplitKernelPredictor`); ``traj`` holds the
        ``x_k``.  Not combined with ``warm_start`` (its extrapolation would mix the
        coordinates of ``x_k`` and of the step's input).  ``+ O(K B (2n)^2)`` flops.

    Returns
    -------
    traj : ndarray of shape (B, K+1, 2n)
        Rows after an instance's failure are NaN.
    codes : ndarray of shape (B,), int64
        0 converged throughout, else the failure code (module docstring).
    fail_step : ndarray of shape (B,), int64
        Macro step of the failure (-1 if none).
    fail_iter : ndarray of shape (B,), int64
        Newton iteration of the failure (``max_iter`` for code 3, -1 if none).
    residual : ndarray of shape (B,)
        ``|F|_inf`` at the failure.

    Notes
    -----
    ``O(K B m (2n + n^2) (1 + n_newton))`` flops (midpoint: ``O(K B m (2n)^2 / 2 (1 + n_newton))``),
    ``O(B K 2n)`` memory plus ``O((2n + 6) chunk_size(2n))`` scratch per thread; instances in parallel.
    """
    as_choice(update, "update", UPDATES)
    check_available()
    x0 = np.ascontiguousarray(x0, dtype=np.float64)
    weights = np.asarray(weights, dtype=np.float64)
    weights = np.ascontiguousarray(weights if weights_ordered else weights[:, layout.order])
    dt = np.ascontiguousarray(dt, dtype=np.float64)
    b, dim = x0.shape
    traj = np.empty((b, int(n_steps) + 1, dim))
    codes = np.zeros(b, dtype=np.int64)
    fail_step = np.full(b, -1, dtype=np.int64)
    fail_iter = np.full(b, -1, dtype=np.int64)
    resid = np.zeros(b)
    if parallel is None:
        parallel = b >= PARALLEL_MIN_BATCH
    parallel = parallel and parallel_safe()  # a child forked after the parallel loops ran: the cached serial kernel
    maps = check_around(around, b, dim, warm_start)
    pre, post = maps if maps is not None else (np.empty((0, dim, dim)), np.empty((0, dim, dim)))
    prev = previous_states(previous, b, dim)
    ns, (family,) = family_kernels(type(kernel))
    fn = ns._rollout_parallel if parallel else ns._rollout_serial
    passes = np.zeros(b, dtype=np.int64)
    call(
        fn,
        x0,
        weights,
        dt,
        layout.cT,
        layout.seg,
        family,
        float(kernel.eps),
        layout.per,
        int(max_iter),
        chunk_size(dim),
        traj,
        codes,
        fail_step,
        fail_iter,
        resid,
        passes,
        bool(warm_start),
        update == "midpoint",
        pre,
        post,
        around is not None,
        prev,
    )
    if stats is not None:
        stats["passes"] = passes
    return traj, codes, fail_step, fail_iter, resid


def newton_solve(x, weights, dt, layout: CenterLayout, kernel, max_iter: int, **kw):
    """One implicit step for every instance (:func:`newton_rollout` with ``K = 1``).

    Returns
    -------
    x1 : ndarray of shape (B, 2n)
    codes, fail_step, fail_iter, residual : ndarray of shape (B,)
    """
    traj, codes, fail_step, fail_iter, resid = newton_rollout(x, weights, dt, layout, kernel, max_iter, 1, **kw)
    return traj[:, 1], codes, fail_step, fail_iter, resid
