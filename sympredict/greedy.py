"""Greedy (f-greedy, P-greedy) generalized kernel interpolation with an incremental Newton basis.

Given ``N`` candidate linear functionals ``lambda_i`` with generalized Gramian
``G_ij = lambda_i^(1) lambda_j^(2) k`` and data ``y_i``, the greedy picks one
functional per step and keeps, for every candidate ``i``,

* the values of the Newton basis ``v_0, ..., v_{m-1}`` (row ``k`` of the
  ``(m, N)`` array ``basis``: one contiguous stream per centre),
* the residual ``r_i = y_i - lambda_i(s_m)``,
* the squared power function ``P2_i = G_ii - sum_k v_k(lambda_i)^2``.

One step with selected functional ``j`` (VKOGA; Santin & Haasdonk 2021):

    v_m      = (G[:, j] - basis[:m].T @ basis[:m, j]) / sqrt(P2_j)
    beta_m   = r_j / sqrt(P2_j)
    r       -= beta_m v_m,     P2 -= v_m^2.

f-greedy picks ``j = argmax |r_i|``, P-greedy ``j = argmax P2_i``.  Candidates
whose ``P2_i`` has fallen to ``power_tol * max_i G_ii`` are linearly dependent
on the selection up to round-off and are never selected: this is what keeps
``sqrt(P2_j)`` away from 0.  With ``L[m, k] = v_k(lambda_{j_m})`` (lower
triangular, the Cholesky factor of the selected Gramian) the kernel-basis
coefficients are ``c = L^{-T} beta``.

Cost per step: one matrix-vector product over ``basis[:m]`` (``m N`` flops,
bandwidth bound), one Gramian column (``O(N)``) and a few ``O(N)`` passes.
Memory: ``8 m_max N`` bytes for the basis (plus ``8 m_max N_val`` with a
validation set), checked before the run starts.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from typing import Optional, Protocol

import numpy as np
from pymor.core.logger import getLogger
from scipy.linalg import solve_triangular

from sympredict.kernels import ProductKernel

__all__ = [
    "FunctionalSet",
    "HBFunctionals",
    "ValueFunctionals",
    "GreedyHistory",
    "GreedyResult",
    "greedy_interpolation",
    "dense_interpolation",
    "available_memory",
]

logger = getLogger("sympredict.greedy")

#: Points per chunk when a Gramian column is built (keeps the temporaries in cache).
_COLUMN_CHUNK = 8192


class FunctionalSet(Protocol):
    """What the greedy needs of a set of candidate functionals."""

    n_functionals: int

    def diagonal(self) -> np.ndarray:
        """``G_ii`` for all candidates, shape (N,)."""

    def representer(self, i: int):
        """Data identifying functional ``i`` for :meth:`column` of *another* set."""

    def column(self, representer, out: np.ndarray) -> np.ndarray:
        """``lambda_i^(1) lambda^(2) k`` for all candidates ``i`` of this set, into ``out`` (N,)."""


class _AugmentedPoints:
    """Points ``(x_p, mu_p, dT_p)`` of the augmented domain and their parameter factors."""

    def __init__(self, kernel: ProductKernel, points, mu, dt):
        self.kernel = kernel
        self.points = np.ascontiguousarray(points, dtype=float)
        n_points = len(self.points)
        self.mu = np.asarray(mu, dtype=float).reshape(n_points, -1)
        self.dt = np.asarray(dt, dtype=float).reshape(n_points)

    def _chunks(self):
        for start in range(0, len(self.points), _COLUMN_CHUNK):
            yield slice(start, start + _COLUMN_CHUNK)

    def _parameter_factor(self, sl, mu_q, dt_q) -> np.ndarray:
        """``k_mu(mu_p, mu_q) k_dT(dT_p, dT_q)`` for the points in ``sl``, shape (chunk,)."""
        return self.kernel.parameter_factor(self.mu[sl], self.dt[sl], mu_q[None, :], np.atleast_1d(dt_q))[:, 0]


class HBFunctionals(_AugmentedPoints):
    """State-derivative functionals ``d/dxi_a`` at augmented points ``(xi_p, mu_p, dT_p)``.

    The flat candidate index is ``i = p * 2n + a`` (point ``p``, component ``a``).

    Parameters
    ----------
    kernel
        Product kernel on ``(xi, mu, dT)``.
    xi : ndarray of shape (M, 2n)
    mu : ndarray of shape (M, d_mu)
    dt : ndarray of shape (M,)
    """

    def __init__(self, kernel: ProductKernel, xi, mu, dt):
        super().__init__(kernel, xi, mu, dt)
        self.dim = self.points.shape[1]
        self.n_functionals = len(self.points) * self.dim

    def diagonal(self) -> np.ndarray:
        # r = 0: d/dx_a d/dy_a k = -A(0); the parameter factors are 1 on the diagonal
        A0, _ = self.kernel.state.factors(np.zeros(1), order=2)
        return np.full(self.n_functionals, -A0[0])

    def representer(self, i: int):
        p, a = divmod(int(i), self.dim)
        return self.points[p], self.mu[p], self.dt[p], a

    def column(self, representer, out: np.ndarray) -> np.ndarray:
        """Gramian column ``w_p (-B d_pa d_pb - A delta_ab)``, ``d_p = xi_p - xi_q``.

        ``out`` has shape (N,) and is filled in chunks of points.
        """
        xi_q, mu_q, dt_q, b = representer
        out2 = out.reshape(-1, self.dim)
        for sl in self._chunks():
            diff = self.points[sl] - xi_q
            A, B = self.kernel.state.factors(np.sqrt(np.einsum("pa,pa->p", diff, diff)), order=2)
            w = self._parameter_factor(sl, mu_q, dt_q)
            blk = out2[sl]
            np.multiply(diff, (-(w * B) * diff[:, b])[:, None], out=blk)
            blk[:, b] -= w * A
        return out


class ValueFunctionals(_AugmentedPoints):
    """Point evaluations ``f -> f(x_p, mu_p, dT_p)`` (the direct model's functionals).

    Gramian entries are plain kernel values ``k_x(x_p, x_q) k_mu k_dT``; the
    diagonal is ``phi(0) = 1``.

    Parameters
    ----------
    kernel
        Product kernel on ``(x, mu, dT)``.
    x : ndarray of shape (M, 2n)
    mu : ndarray of shape (M, d_mu)
    dt : ndarray of shape (M,)
    """

    def __init__(self, kernel: ProductKernel, x, mu, dt):
        super().__init__(kernel, x, mu, dt)
        self.n_functionals = len(self.points)

    def diagonal(self) -> np.ndarray:
        return np.full(self.n_functionals, float(self.kernel.state.phi(np.zeros(1))[0]))

    def representer(self, i: int):
        return self.points[i], self.mu[i], self.dt[i]

    def column(self, representer, out: np.ndarray) -> np.ndarray:
        x_q, mu_q, dt_q = representer
        for sl in self._chunks():
            diff = self.points[sl] - x_q
            out[sl] = self._parameter_factor(sl, mu_q, dt_q) * self.kernel.state.phi(np.sqrt(np.einsum("pa,pa->p", diff, diff)))
        return out


@dataclass
class GreedyHistory:
    """Per-step record of a greedy run (index ``m`` = number of selected centres).

    Attributes
    ----------
    train_max_residual : ndarray of shape (m+1,)
        ``E_train(m) = max_i |r_i|`` over all training functionals, ``m = 0..m_final``.
    val_max_residual : ndarray of shape (m+1,) or None
        ``E_val(m)`` over the validation functionals when a validation set was given.
    selected_power : ndarray of shape (m,)
        ``sqrt(P2_j)`` of the functional selected at each step.
    elapsed : ndarray of shape (m,)
        Wall time in seconds from the start of the run to the end of each step.
    stop_reason : str
        ``'max_centers'``, ``'tol'`` (max residual at or below ``tol``),
        ``'power'`` (every remaining candidate's power function is at round-off),
        ``'diverged'`` (residual blow-up from round-off, truncated to the best
        step) or ``'exhausted'`` (every candidate selected).
    """

    train_max_residual: np.ndarray
    val_max_residual: Optional[np.ndarray]
    selected_power: np.ndarray
    elapsed: np.ndarray
    stop_reason: str

    @property
    def n_centers(self) -> np.ndarray:
        """``0, 1, ..., m_final``, the abscissa of the residual curves."""
        return np.arange(len(self.train_max_residual))


@dataclass
class GreedyResult:
    """Selection and coefficients of a greedy run.

    Attributes
    ----------
    selected : ndarray of shape (m,), int
        Flat indices of the selected functionals, in selection order.
    coef : ndarray of shape (m,) or (m, q)
        Kernel-basis coefficients ``c`` (``s = sum_j c_j lambda_j^(2) k``).
    newton_coef : ndarray of shape (m,) or (m, q)
        Coefficients ``beta`` in the Newton basis.
    history : GreedyHistory
    chol : ndarray of shape (m, m)
        ``L[i, k] = v_k(lambda_{j_i})``: Newton-basis values at the selected
        functionals (the Cholesky factor of their Gramian); what :meth:`coef_prefix` needs.
    """

    selected: np.ndarray
    coef: np.ndarray
    newton_coef: np.ndarray
    history: GreedyHistory = field(repr=False)
    chol: Optional[np.ndarray] = field(default=None, repr=False)

    def coef_prefix(self, m: int) -> np.ndarray:
        """Kernel-basis coefficients of the interpolant on the first ``m`` selected functionals.

        A prefix of a Newton expansion is the greedy's interpolant after ``m``
        steps, so every smaller model comes from one run: ``c = L[:m, :m]^{-T} beta[:m]``,
        ``O(m^2)``.  Equal (to round-off) to a fresh run with ``max_centers=m``.
        """
        if self.chol is None:
            raise ValueError("this result does not carry the Newton basis values at the selected functionals")
        if not 1 <= m <= len(self.selected):
            raise ValueError(f"m must lie in 1..{len(self.selected)}, got {m}")
        return _kernel_coefficients(self.chol[:m, :m], self.newton_coef[:m])


def available_memory() -> int:
    """Bytes of physical memory currently available (``MemAvailable``), or total memory as fallback."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")


def _fmt_bytes(n: float) -> str:
    for unit, size in (("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if n >= size:
            return f"{n / size:.2f} {unit}"
    return f"{n:.0f} B"


def _abs_residual(res: np.ndarray, out: np.ndarray) -> np.ndarray:
    """``max_k |r_ik|`` per candidate into ``out`` (N,), without a temporary for one output."""
    if res.shape[1] == 1:
        return np.abs(res[:, 0], out=out)
    return np.abs(res).max(axis=1, out=out)


def _kernel_coefficients(chol: np.ndarray, beta: np.ndarray) -> np.ndarray:
    """Kernel-basis coefficients ``c = L^{-T} beta`` from the Newton expansion (``O(m^2)``)."""
    return solve_triangular(chol, beta, lower=True, trans="T")


def _check_memory(max_centers: int, n_train: int, n_val: int, memory_limit: Optional[float]) -> None:
    need = 8 * max_centers * (n_train + n_val)
    limit = memory_limit if memory_limit is not None else 0.9 * available_memory()
    if need > limit:
        fit_centers = int(limit // (8 * (n_train + n_val)))
        raise ValueError(
            f"the Newton basis needs {_fmt_bytes(need)} ({max_centers} centres x "
            f"{n_train + n_val} functionals x 8 bytes) but the memory limit is {_fmt_bytes(limit)}; "
            f"use max_centers <= {fit_centers}, fewer training samples, or raise memory_limit"
        )


def greedy_interpolation(
    functionals: HBFunctionals,
    targets: np.ndarray,
    *,
    max_centers: int,
    tol: float = 1e-10,
    criterion: str = "f",
    power_tol: float = 1e-12,
    divergence_factor: float = 100.0,
    validation: Optional[tuple] = None,
    memory_limit: Optional[float] = None,
    log_every: int = 100,
) -> GreedyResult:
    """Sparse generalized interpolation by f-greedy (or P-greedy) selection.

    Parameters
    ----------
    functionals
        The ``N`` candidate functionals (training set).
    targets : ndarray of shape (N,) or (N, q)
        Data ``y_i = lambda_i(f)``; ``q > 1`` interpolates ``q`` outputs with
        shared centres (selection by the max over outputs).
    max_centers
        Upper bound on the number of selected functionals.
    tol
        Stop when ``max_i |r_i| <= tol`` over the selectable candidates.
    criterion
        ``'f'`` (f-greedy, residual-based) or ``'p'`` (P-greedy, power-function based,
        data independent).
    power_tol
        Candidates with ``P2_i <= power_tol * max(G_ii)`` are never selected
        (breakdown guard); when no candidate is left the run stops with
        reason ``'power'``.  The new basis column is computed with a relative
        error of about ``eps_mach sqrt(m) G_ii / P2_j``; below ``1e-12`` the
        basis degrades and the residual can blow up (seen at ``1e-13`` on the
        pendulum).
    divergence_factor
        Safety net for that loss of accuracy: when ``E_train(m)`` exceeds
        ``divergence_factor`` times its minimum so far, the run stops with
        reason ``'diverged'`` and is truncated to the step with the smallest
        ``E_train`` (a prefix of a Newton expansion is again an interpolant).
    validation
        Optional ``(val_functionals, val_targets)``; then ``E_val(m)`` is
        recorded at ``O(N_val m)`` extra work per step.
    memory_limit
        Bytes the Newton basis may use; default 90% of available memory.
        Checked before any work, with a message saying what fits.
    log_every
        Log progress every this many steps.

    Returns
    -------
    GreedyResult

    Notes
    -----
    Time ``O(m^2 (N + N_val) / 2)`` memory traffic in total, memory
    ``8 m_max (N + N_val)`` bytes.
    """
    if criterion not in ("f", "p"):
        raise ValueError(f"criterion must be 'f' (f-greedy) or 'p' (P-greedy), got {criterion!r}")
    n = functionals.n_functionals
    y = np.asarray(targets, dtype=float)
    squeeze = y.ndim == 1
    y = y.reshape(n, -1)
    if n == 0:
        raise ValueError("no candidate functionals: the training set is empty")
    if int(max_centers) < 1:
        raise ValueError(f"max_centers must be a positive integer, got {max_centers!r}")
    max_centers = min(int(max_centers), n)
    n_val = 0
    if validation is not None:
        val_functionals, val_targets = validation
        n_val = val_functionals.n_functionals
        vres = np.array(val_targets, dtype=float).reshape(n_val, -1)
        if vres.shape[1] != y.shape[1]:
            raise ValueError("validation targets must have as many outputs as the training targets")
    _check_memory(max_centers, n, n_val, memory_limit)

    res = y.copy()
    res_abs = np.empty(n)
    p2 = functionals.diagonal().astype(float)
    breakdown = power_tol * p2.max()
    basis = np.empty((max_centers, n))
    vbasis = np.empty((max_centers, n_val)) if n_val else None
    chol = np.zeros((max_centers, max_centers))
    beta = np.zeros((max_centers, y.shape[1]))
    selected = np.empty(max_centers, dtype=np.int64)
    sel_power = np.empty(max_centers)
    elapsed = np.empty(max_centers)
    _abs_residual(res, out=res_abs)
    train_hist = [res_abs.max()]
    val_hist = [np.abs(vres).max()] if n_val else None
    tmp = np.empty(n)
    best_train = train_hist[0]
    stop_reason = "max_centers" if max_centers < n else "exhausted"
    t0 = time.perf_counter()
    m = 0
    while m < max_centers:
        # res_abs holds |r| of the current residual (computed once per step, below)
        score = res_abs if criterion == "f" else p2.copy()
        score[p2 <= breakdown] = -np.inf
        j = int(np.argmax(score))
        if not np.isfinite(score[j]):
            stop_reason = "power"
            break
        if res_abs[j] <= tol and criterion == "f":
            stop_reason = "tol"
            break
        rep = functionals.representer(j)
        row = functionals.column(rep, out=basis[m])
        coeffs_j = basis[:m, j].copy()
        if m:
            row -= basis[:m].T @ coeffs_j
        pj = np.sqrt(p2[j])
        row *= 1.0 / pj
        chol[m, :m] = coeffs_j
        chol[m, m] = pj
        b = res[j] / pj
        beta[m] = b
        if y.shape[1] == 1:
            res[:, 0] -= b[0] * row
        else:
            res -= row[:, None] * b
        res[j] = 0.0
        np.square(row, out=tmp)
        p2 -= tmp
        p2[j] = 0.0
        if n_val:
            vrow = val_functionals.column(rep, out=vbasis[m])
            if m:
                vrow -= vbasis[:m].T @ coeffs_j
            vrow *= 1.0 / pj
            vres -= vrow[:, None] * b
            val_hist.append(np.abs(vres).max())
        selected[m] = j
        sel_power[m] = pj
        m += 1
        elapsed[m - 1] = time.perf_counter() - t0
        _abs_residual(res, out=res_abs)
        train_hist.append(res_abs.max())
        best_train = min(best_train, train_hist[-1])
        if train_hist[-1] > divergence_factor * best_train:
            stop_reason = "diverged"
            m_best = int(np.argmin(train_hist))
            logger.warning(
                f"greedy residual blew up at {m} centres ({train_hist[-1]:.2e} vs best {best_train:.2e}): "
                f"round-off in the Newton basis; truncating to {m_best} centres (raise power_tol to avoid)"
            )
            m = m_best
            del train_hist[m + 1 :]
            if val_hist is not None:
                del val_hist[m + 1 :]
            break
        if log_every and m % log_every == 0:
            logger.info(
                f"{m} centres: E_train={train_hist[-1]:.3e}"
                + (f", E_val={val_hist[-1]:.3e}" if n_val else "")
                + f", P={pj:.2e}, {elapsed[m - 1]:.1f}s"
            )
    coef = _kernel_coefficients(chol[:m, :m], beta[:m]) if m else np.zeros((0, y.shape[1]))
    history = GreedyHistory(
        train_max_residual=np.array(train_hist),
        val_max_residual=None if val_hist is None else np.array(val_hist),
        selected_power=sel_power[:m].copy(),
        elapsed=elapsed[:m].copy(),
        stop_reason=stop_reason,
    )
    logger.info(f"greedy stopped ({stop_reason}) with {m} centres, E_train={train_hist[-1]:.3e}")
    if squeeze:
        coef, newton = coef[:, 0], beta[:m, 0].copy()
    else:
        newton = beta[:m].copy()
    return GreedyResult(selected=selected[:m].copy(), coef=coef, newton_coef=newton, history=history, chol=chol[:m, :m].copy())


def dense_interpolation(functionals: HBFunctionals, targets: np.ndarray) -> np.ndarray:
    """Exact generalized interpolation on all ``N`` functionals by a dense solve (reference).

    Builds the ``N x N`` Gramian column by column and solves ``G c = y`` by
    Cholesky.  ``O(N^2)`` memory and ``O(N^3)`` time: for small data only.

    Parameters
    ----------
    functionals
        The ``N`` functionals.
    targets : ndarray of shape (N,) or (N, q)

    Returns
    -------
    ndarray of shape (N,) or (N, q)
        Kernel-basis coefficients for the functionals in their flat order.

    Raises
    ------
    numpy.linalg.LinAlgError
        If the Gramian is not numerically positive definite (duplicate or
        nearly dependent functionals): use the greedy instead.
    """
    from scipy.linalg import cho_factor, cho_solve

    n = functionals.n_functionals
    gram = np.empty((n, n))
    for j in range(n):
        functionals.column(functionals.representer(j), out=gram[:, j])
    gram = 0.5 * (gram + gram.T)
    return cho_solve(cho_factor(gram, lower=True), np.asarray(targets, dtype=float))
