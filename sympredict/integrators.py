"""Classical symplectic integrators, batched over instances: references and baselines.

A *system* is any object with

* ``gradient(x, mu) -> (B, 2n)``: ``grad_x H``,
* ``hessian(x, mu) -> (B, 2n, 2n)``: ``grad_x^2 H`` (implicit methods only),

for states ``x`` of shape ``(B, 2n)`` ordered ``(q, p)`` and parameters ``mu``
of shape ``(B, d_mu)``.  The equations of motion are ``x' = J grad H`` with
``J = [[0, I], [-I, 0]]``.  Every scheme has the same signature
``step(system, x, mu, h) -> x_next`` with ``h`` a float or ``(B,)``.
"""

from __future__ import annotations

import numpy as np

from sympredict._checks import as_real
from sympredict.exceptions import NewtonConvergenceError
from sympredict.metrics import canonical_J

__all__ = ["micro_steps", "apply_J", "implicit_midpoint_step", "symplectic_euler_step", "stormer_verlet_step", "integrate"]

_EPS = np.finfo(float).eps


def micro_steps(t, h_max: float) -> np.ndarray:
    """Number of micro steps of size at most ``h_max`` covering ``t`` exactly (``ceil(t / h_max)``).

    ``t / h_max`` is rounded to 9 digits first so that ``0.05 / 1e-3`` gives 50, not 51.

    Raises
    ------
    ValueError
        If ``h_max`` is not a finite positive number, ``t`` is negative or not
        finite, or more than ``1e12`` micro steps would be needed.
    """
    h_max = as_real(h_max, "h_max", positive=True)
    t = np.asarray(t, dtype=float)
    if not np.all(np.isfinite(t)) or np.any(t < 0):
        raise ValueError(f"times must be finite and >= 0, got {t.min() if t.size else t!r}..{t.max() if t.size else t!r}")
    ratio = np.round(t / h_max, 9)
    if np.any(ratio > 1e12):
        raise ValueError(f"t / h_max = {float(ratio.max()):.3g} micro steps: too many (h_max = {h_max!r} too small for t)")
    return np.maximum(1, np.ceil(ratio).astype(np.int64))


def apply_J(v: np.ndarray) -> np.ndarray:
    """``J v`` for ``v = (v_q, v_p)`` along the last axis: ``(v_p, -v_q)``."""
    n = v.shape[-1] // 2
    return np.concatenate([v[..., n:], -v[..., :n]], axis=-1)


def _as_h(h, b):
    h = np.asarray(h, dtype=float)
    return np.broadcast_to(h.reshape(-1), (b,))[:, None] if h.ndim else np.full((b, 1), float(h))


def implicit_midpoint_step(system, x, mu, h, *, max_iter: int = 50) -> np.ndarray:
    """Implicit midpoint ``x1 = x0 + h J grad H((x0 + x1) / 2)``, solved by Newton to round-off.

    Newton on ``G(x1) = x1 - x0 - h J grad H(m)``, ``m = (x0 + x1)/2``, with
    Jacobian ``I - (h/2) J hess H(m)``; an instance stops when the update is at
    round-off (``<= 4 eps |x1|``) or stops contracting.  Second order,
    symplectic, conserves quadratic invariants.

    Parameters
    ----------
    system
        Provides ``gradient`` and ``hessian`` (see module docstring).
    x : ndarray of shape (B, 2n)
    mu : ndarray of shape (B, d_mu)
    h : float or ndarray of shape (B,)

    Returns
    -------
    ndarray of shape (B, 2n)

    Raises
    ------
    NewtonConvergenceError
        If Newton fails for some instances (e.g. ``h`` too large).
    """
    x = np.asarray(x, dtype=float)
    b, dim = x.shape
    hh = _as_h(h, b)
    x1 = x + hh * apply_J(system.gradient(x, mu))
    eye = np.eye(dim)
    J = canonical_J(dim)
    active = np.arange(b)
    last = np.full(b, np.inf)
    for _ in range(max_iter):
        xa, x1a, ha, mua = x[active], x1[active], hh[active], mu[active]
        mid = 0.5 * (xa + x1a)
        G = x1a - xa - ha * apply_J(system.gradient(mid, mua))
        jac = eye - 0.5 * ha[:, :, None] * (J @ system.hessian(mid, mua))
        delta = np.linalg.solve(jac, G[:, :, None])[:, :, 0]
        d_norm = np.abs(delta).max(axis=1)
        if not np.all(np.isfinite(d_norm)):
            bad = ~np.isfinite(d_norm)
            raise NewtonConvergenceError(active[bad], d_norm[bad], reason="(implicit midpoint) produced a non-finite iterate")
        x1[active] = x1a - delta
        scale = np.abs(x1[active]).max(axis=1) + 1.0
        done = (d_norm <= 4 * _EPS * scale) | ((d_norm >= 0.5 * last[active]) & (d_norm <= 1e3 * _EPS * scale))
        last[active] = d_norm
        active = active[~done]
        if active.size == 0:
            return x1
    raise NewtonConvergenceError(active, last[active], reason=f"(implicit midpoint) did not converge in {max_iter} iterations")


def symplectic_euler_step(system, x, mu, h, *, max_iter: int = 50) -> np.ndarray:
    """Symplectic Euler ``p1 = p0 - h d_q H(q0, p1)``, ``q1 = q0 + h d_p H(q0, p1)``.

    Explicit for separable ``H = T(p) + V(q)`` (one Newton iteration
    converges exactly); Newton on ``p1`` otherwise.  First order.
    """
    x = np.asarray(x, dtype=float)
    b, dim = x.shape
    n = dim // 2
    hh = _as_h(h, b)
    q0, p0 = x[:, :n], x[:, n:]
    p = p0.copy()
    for _ in range(max_iter):
        xi = np.concatenate([q0, p], axis=1)
        g = system.gradient(xi, mu)
        F = p - p0 + hh * g[:, :n]
        jac = np.eye(n) + hh[:, :, None] * system.hessian(xi, mu)[:, :n, n:]
        delta = np.linalg.solve(jac, F[:, :, None])[:, :, 0]
        p = p - delta
        if np.all(np.abs(delta) <= 4 * _EPS * (np.abs(p) + 1.0)):
            break
    else:
        bad = np.flatnonzero(np.abs(delta).max(axis=1) > 4 * _EPS * (np.abs(p).max(axis=1) + 1.0))
        raise NewtonConvergenceError(bad, np.abs(delta).max(axis=1)[bad], reason="(symplectic Euler) did not converge")
    g = system.gradient(np.concatenate([q0, p], axis=1), mu)
    return np.concatenate([q0 + hh * g[:, n:], p], axis=1)


def stormer_verlet_step(system, x, mu, h) -> np.ndarray:
    """Störmer–Verlet (leapfrog) for separable ``H = T(p) + V(q)``; explicit, second order.

    ``p_half = p0 - h/2 V'(q0)``, ``q1 = q0 + h T'(p_half)``, ``p1 = p_half - h/2 V'(q1)``.
    Only valid for separable Hamiltonians (``d_q H`` independent of ``p`` and
    ``d_p H`` independent of ``q``); stable only for ``h`` below ``2 / omega_max``.
    """
    x = np.asarray(x, dtype=float)
    b, dim = x.shape
    n = dim // 2
    hh = _as_h(h, b)
    q, p = x[:, :n], x[:, n:]
    p = p - 0.5 * hh * system.gradient(x, mu)[:, :n]
    q = q + hh * system.gradient(np.concatenate([q, p], axis=1), mu)[:, n:]
    p = p - 0.5 * hh * system.gradient(np.concatenate([q, p], axis=1), mu)[:, :n]
    return np.concatenate([q, p], axis=1)


def integrate(step, system, x0, mu, h, n_steps: int) -> np.ndarray:
    """Trajectories ``(B, K+1, 2n)`` of ``n_steps`` applications of ``step(system, x, mu, h)``."""
    x = np.asarray(x0, dtype=float)
    traj = np.empty((len(x), n_steps + 1, x.shape[1]))
    traj[:, 0] = x
    for k in range(n_steps):
        try:
            traj[:, k + 1] = step(system, traj[:, k], mu, h)
        except NewtonConvergenceError as err:
            raise err.at_step(k) from None
    return traj
