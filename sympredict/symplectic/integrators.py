"""Classical symplectic integrators, batched over instances: references and baselines.

A *system* is any object with

* ``gradient(x, mu) -> (B, 2n)``: ``grad_x H``,
* ``hessian(x, mu) -> (B, 2n, 2n)``: ``grad_x^2 H`` (implicit methods only),

for states ``x`` of shape ``(B, 2n)`` ordered ``(q, p)`` and parameters ``mu``
of shape ``(B, d_mu)``.  The equations of motion are ``x' = J grad H`` with
``J = [[0, I], [-I, 0]]``.  Every scheme has the same signature
``step(system, x, mu, h) -> x_next`` with ``h`` a float or ``(B,)``.

The code here is the NumPy reference.  :mod:`sympredict.symplectic.integrators_compiled`
runs the same schemes (:data:`SCHEMES`) as one compiled, batched rollout and
takes its composition coefficients (:data:`COMPOSITIONS`) from this module.
"""

from __future__ import annotations

import numpy as np

from sympredict._checks import as_real
from sympredict.exceptions import NewtonConvergenceError
from sympredict.symplectic.metrics import canonical_J, j_times

__all__ = [
    "micro_steps",
    "apply_J",
    "COMPOSITIONS",
    "SCHEMES",
    "SCHEME_ORDERS",
    "implicit_midpoint_step",
    "symplectic_euler_step",
    "stormer_verlet_step",
    "composition_step",
    "yoshida4_step",
    "kahan_li6_step",
    "integrate",
]

_EPS = np.finfo(float).eps

_CBRT2 = 2.0 ** (1.0 / 3.0)

#: Symmetric compositions ``Phi_h = SV_{g_s h} o ... o SV_{g_1 h}`` of the Störmer–Verlet step:
#: the step fractions ``g_i`` (they sum to 1).  Defined once; the compiled path uses these tuples.
#:
#: * ``"stormer_verlet"``: the base method itself, order 2.
#: * ``"yoshida4"``: Yoshida's triple jump, order 4 (H. Yoshida, Phys. Lett. A 150 (1990) 262-268):
#:   ``g_1 = g_3 = 1 / (2 - 2^(1/3))``, ``g_2 = -2^(1/3) / (2 - 2^(1/3))``.
#: * ``"kahan_li6"``: Kahan and Li's 9-stage method s9odr6a, order 6 (W. Kahan, R.-C. Li,
#:   Math. Comp. 66 (1997) 1089-1099), coefficients as printed in Hairer, Lubich, Wanner,
#:   *Geometric Numerical Integration*, 2nd ed. (2006), section V.3.2.
COMPOSITIONS = {
    "stormer_verlet": (1.0,),
    "yoshida4": (1.0 / (2.0 - _CBRT2), -_CBRT2 / (2.0 - _CBRT2), 1.0 / (2.0 - _CBRT2)),
    "kahan_li6": (
        0.39216144400731413927925056,
        0.33259913678935943859974864,
        -0.70624617255763935980996482,
        0.08221359629355080023149045,
        0.79854399093482996339895035,
        0.08221359629355080023149045,
        -0.70624617255763935980996482,
        0.33259913678935943859974864,
        0.39216144400731413927925056,
    ),
}


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
        raise ValueError(
            f"times must be finite and >= 0, got {t.min() if t.size else t!r}..{t.max() if t.size else t!r}"
        )
    ratio = np.round(t / h_max, 9)
    if np.any(ratio > 1e12):
        raise ValueError(
            f"t / h_max = {float(ratio.max()):.3g} micro steps: too many (h_max = {h_max!r} too small for t)"
        )
    return np.maximum(1, np.ceil(ratio).astype(np.int64))


#: ``J v`` for ``v = (v_q, v_p)`` along the last axis: ``(v_p, -v_q)`` (:func:`sympredict.symplectic.metrics.j_times`).
apply_J = j_times


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
        The states ``x1`` after one step.

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
            raise NewtonConvergenceError(
                active[bad], d_norm[bad], reason="(implicit midpoint) produced a non-finite iterate"
            )
        x1[active] = x1a - delta
        scale = np.abs(x1[active]).max(axis=1) + 1.0
        done = (d_norm <= 4 * _EPS * scale) | ((d_norm >= 0.5 * last[active]) & (d_norm <= 1e3 * _EPS * scale))
        last[active] = d_norm
        active = active[~done]
        if active.size == 0:
            return x1
    raise NewtonConvergenceError(
        active, last[active], reason=f"(implicit midpoint) did not converge in {max_iter} iterations"
    )


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


def composition_step(system, x, mu, h, *, fractions) -> np.ndarray:
    """The composition ``SV_{g_s h} o ... o SV_{g_1 h}`` of Störmer–Verlet steps (separable ``H`` only).

    Parameters
    ----------
    system, x, mu, h
        As for :func:`stormer_verlet_step`.
    fractions : sequence of float
        Step fractions ``g_i`` (e.g. ``COMPOSITIONS["yoshida4"]``).

    Returns
    -------
    ndarray of shape (B, 2n)

    Notes
    -----
    ``3 s`` gradient evaluations of shape (B, 2n) for ``s`` stages (the
    reference recomputes what the compiled path reuses).
    """
    x = np.asarray(x, dtype=float)
    hh = _as_h(h, len(x))[:, 0]
    for g in fractions:
        x = stormer_verlet_step(system, x, mu, g * hh)
    return x


def yoshida4_step(system, x, mu, h) -> np.ndarray:
    """Yoshida's 4th-order triple jump of Störmer–Verlet (``COMPOSITIONS["yoshida4"]``); separable ``H``."""
    return composition_step(system, x, mu, h, fractions=COMPOSITIONS["yoshida4"])


def kahan_li6_step(system, x, mu, h) -> np.ndarray:
    """Kahan–Li's 6th-order 9-stage composition of Störmer–Verlet (``COMPOSITIONS["kahan_li6"]``); separable ``H``."""
    return composition_step(system, x, mu, h, fractions=COMPOSITIONS["kahan_li6"])


#: Scheme name -> NumPy reference step ``step(system, x, mu, h)``.
SCHEMES = {
    "stormer_verlet": stormer_verlet_step,
    "yoshida4": yoshida4_step,
    "kahan_li6": kahan_li6_step,
    "implicit_midpoint": implicit_midpoint_step,
}

#: Scheme name -> classical order.
SCHEME_ORDERS = {"stormer_verlet": 2, "yoshida4": 4, "kahan_li6": 6, "implicit_midpoint": 2}


def integrate(step, system, x0, mu, h, n_steps: int, substeps: int = 1) -> np.ndarray:
    """Trajectories ``(B, K+1, 2n)`` of ``n_steps`` macro steps, each ``substeps`` applications of ``step``.

    Parameters
    ----------
    step
        ``step(system, x, mu, h)``, e.g. :func:`stormer_verlet_step`.
    system
        See the module docstring.
    x0 : ndarray of shape (B, 2n)
    mu : ndarray of shape (B, d_mu)
    h : float or ndarray of shape (B,)
        The step of ``step`` (the macro step is ``substeps * h``).
    n_steps : int
        Macro steps ``K`` (output rows after the initial state).
    substeps : int
        Steps per macro step.

    Returns
    -------
    ndarray of shape (B, K+1, 2n)
        States at ``t_k = k * substeps * h``.
    """
    x = np.asarray(x0, dtype=float)
    traj = np.empty((len(x), n_steps + 1, x.shape[1]))
    traj[:, 0] = x
    for k in range(n_steps):
        try:
            for _ in range(substeps):
                x = step(system, x, mu, h)
        except NewtonConvergenceError as err:
            raise err.at_step(k) from None
        traj[:, k + 1] = x
    return traj
