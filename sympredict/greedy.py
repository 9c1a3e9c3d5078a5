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
bandwidth bound: the stream), one Gramian column (``O(N)``, in cache-sized
chunks) and one fused ``O(N)`` pass for the residual, power function, max and
next selection (compiled with numba when installed, bit-identical to the NumPy
passes it replaces).  Memory: ``8 m_max N`` bytes for the basis (plus
``8 m_max N_val`` with a validation set; half with ``basis_dtype='float32'``),
checked before the run starts, with a message saying what fits.

Two faster, non-default paths: ``basis_dtype='float32'`` (half the traffic; the
power function is only accurate to float32 round-off, see
:func:`greedy_interpolation`) and :func:`active_set_greedy` (the basis on an
active subset of the candidates, refreshed against the full residual computed
by :func:`functional_residuals`).
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from typing import Optional, Protocol

import numpy as np
from pymor.core.logger import getLogger
from scipy.linalg import solve_triangular

from sympredict import _fastkernels
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
    "functional_residuals",
    "active_set_greedy",
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
        # compiled column where it is bit-identical to the NumPy one (2n = 2, IMQ factors)
        self._compiled_column = _fastkernels.hb_column_supported(kernel, self.dim, self.mu.shape[1])

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
        if getattr(self, "_compiled_column", False):
            return _fastkernels.hb_column(self.kernel, self.points, self.mu, self.dt, representer, out)
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


    def gram_rows(self, others: "HBFunctionals", indices: np.ndarray, out: np.ndarray) -> np.ndarray:
        """Gramian rows ``lambda_{i_k}^(1) lambda^(2) k`` of functionals of ``others`` against all of this set.

        The same numbers as ``column(others.representer(i_k))`` for every ``k``,
        vectorised over ``k`` (one call instead of ``len(indices)``).

        Parameters
        ----------
        others
            The set the functionals ``i_k`` belong to (same kernel).
        indices : ndarray of shape (K,), int
            Flat indices into ``others``.
        out : ndarray of shape (K, N)

        Notes
        -----
        ``O(K N)`` work, chunked over this set's points (``K x 1024 x 2n`` temporaries).
        """
        pts, comps = np.divmod(np.asarray(indices, dtype=np.int64), self.dim)
        xq, mq, dq = others.points[pts], others.mu[pts], others.dt[pts]
        out3 = out.reshape(len(pts), -1, self.dim)
        rows = np.arange(len(pts))
        step = 1024
        for start in range(0, len(self.points), step):
            sl = slice(start, start + step)
            diff = self.points[None, sl, :] - xq[:, None, :]
            A, B = self.kernel.state.factors(np.sqrt(np.einsum("kpa,kpa->kp", diff, diff)), order=2)
            w = self.kernel.parameter_factor(mq, dq, self.mu[sl], self.dt[sl])
            blk = out3[:, sl]
            np.multiply(diff, (-(w * B) * diff[rows, :, comps])[:, :, None], out=blk)
            blk[rows, :, comps] -= w * A
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
    basis : ndarray of shape (m, N) or None
        The Newton basis itself (``keep_basis=True`` only; benchmarks time the
        matrix-vector product over it).
    """

    selected: np.ndarray
    coef: np.ndarray
    newton_coef: np.ndarray
    history: GreedyHistory = field(repr=False)
    chol: Optional[np.ndarray] = field(default=None, repr=False)
    basis: Optional[np.ndarray] = field(default=None, repr=False)

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


def _finite_coefficients(coef: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """``coef``, or a ``ValueError`` when it overflowed (targets near the float64 limit)."""
    if not np.all(np.isfinite(coef)):
        raise ValueError(
            f"the kernel coefficients overflow (max |target| = {np.abs(targets).max():.3g}): the training targets "
            "are too large for float64; rescale the data (for flow maps, (x1 - x0) / dt with a tiny dt)"
        )
    return coef


def _check_memory(
    max_centers: int, n_train: int, n_val: int, memory_limit: Optional[float], itemsize: int = 8
) -> None:
    """Refuse, before any work, a Newton basis larger than the memory limit, saying what fits.

    The message offers the three ways out: fewer centres, a subset of the
    candidates, or float32 storage of the basis (``basis_dtype='float32'``,
    half the memory; its accuracy is checked against float64 in the tests and
    benchmarks).
    """
    n_all = n_train + n_val
    need = itemsize * max_centers * n_all
    limit = memory_limit if memory_limit is not None else 0.9 * available_memory()
    if need > limit:
        fit_centers = int(limit // (itemsize * n_all))
        fit_candidates = int(limit // (itemsize * max_centers)) - n_val
        offers = [f"use max_centers <= {fit_centers}"]
        if fit_candidates > 0:
            offers.append(f"use at most {fit_candidates} training functionals (a subset of the samples)")
        else:
            offers.append("use fewer training samples")
        if itemsize == 8 and 4 * max_centers * n_all <= limit:
            offers.append(f"store the basis in float32 (basis_dtype='float32': {_fmt_bytes(need / 2)})")
        raise ValueError(
            f"the Newton basis needs {_fmt_bytes(need)} ({max_centers} centres x "
            f"{n_all} functionals x {itemsize} bytes) but the memory limit is {_fmt_bytes(limit)}; "
            + ", ".join(offers) + ", or raise memory_limit"
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
    basis_dtype: str = "float64",
    keep_basis: bool = False,
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
    basis_dtype
        ``'float64'`` (default: the exact f-greedy) or ``'float32'``: the
        Newton basis is stored in single precision (half the memory and half
        the memory traffic of the per-step stream) while the residual, the
        power function and the new basis row are computed in float64 (with the
        compiled kernel the matrix-vector product also accumulates in float64;
        without numba it is a float32 product).  Each stored row carries a
        relative error of ``~6e-8``; check the result's residual against a
        float64 run (``benchmarks/suite.py`` does).
    keep_basis
        Return the Newton basis in :attr:`GreedyResult.basis` (benchmarks).

    Returns
    -------
    GreedyResult

    Notes
    -----
    Per step: one matrix-vector product streaming ``basis[:m]`` (``m N`` reads,
    the bandwidth bound), one Gramian column (``O(N)``, chunked in cache) and
    a few ``O(N)`` vector passes.  Time ``O(m^2 (N + N_val) / 2)`` memory
    traffic in total, memory ``itemsize * m_max (N + N_val)`` bytes (8 or 4).
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
    if basis_dtype not in ("float64", "float32"):
        raise ValueError(f"basis_dtype must be 'float64' or 'float32', got {basis_dtype!r}")
    dtype = np.dtype(basis_dtype)
    _check_memory(max_centers, n, n_val, memory_limit, itemsize=dtype.itemsize)
    single = dtype == np.float32

    res = y.copy()
    res_abs = np.empty(n)
    p2 = functionals.diagonal().astype(float)
    breakdown = power_tol * p2.max()
    basis = np.empty((max_centers, n), dtype=dtype)
    vbasis = np.empty((max_centers, n_val), dtype=dtype) if n_val else None
    row64 = np.empty(n) if single else None
    vrow64 = np.empty(n_val) if single and n_val else None
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
    # With numba, the vector work after the matrix-vector product is one fused
    # pass (sympredict._fastkernels.greedy_update, bit-identical to the NumPy code).
    from sympredict import _fastkernels

    fused = _fastkernels.HAVE_NUMBA and criterion == "f" and y.shape[1] == 1
    zeros = np.zeros(n) if fused else None
    next_sel = None
    t0 = time.perf_counter()
    m = 0
    while m < max_centers:
        if next_sel is None:
            # res_abs holds |r| of the current residual (computed once per step, below)
            score = res_abs if criterion == "f" else p2.copy()
            score[p2 <= breakdown] = -np.inf
            j = int(np.argmax(score))
            best = score[j]
        else:
            j, best = next_sel
        if not np.isfinite(best):
            stop_reason = "power"
            break
        if best <= tol and criterion == "f":
            stop_reason = "tol"
            break
        rep = functionals.representer(j)
        coeffs_j = basis[:m, j].astype(float)
        if fused:
            if single:
                row = functionals.column(rep, out=row64)
                t = _matvec_t(basis, m, coeffs_j) if m else zeros
            else:
                row = functionals.column(rep, out=basis[m])
                t = basis[:m].T @ coeffs_j if m else zeros
            pj = np.sqrt(p2[j])
            b = res[j] / pj
            max_abs, next_j, next_best = _fastkernels.greedy_update(row, t, 1.0 / pj, b[0], res[:, 0], p2, j, breakdown,
                                                                    parallel=_fastkernels.GREEDY_PARALLEL)
            next_sel = (next_j, next_best)
            if single:
                basis[m] = row
            chol[m, :m] = coeffs_j
            chol[m, m] = pj
            beta[m] = b
        elif single:
            row = functionals.column(rep, out=row64)
            if m:
                row -= _matvec_t(basis, m, coeffs_j)
        else:
            row = functionals.column(rep, out=basis[m])
            if m:
                row -= basis[:m].T @ coeffs_j
        if not fused:
            pj = np.sqrt(p2[j])
            row *= 1.0 / pj
            if single:
                basis[m] = row
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
            if single:
                vrow = val_functionals.column(rep, out=vrow64)
                if m:
                    vrow -= _matvec_t(vbasis, m, coeffs_j)
                vrow *= 1.0 / pj
                vbasis[m] = vrow
            else:
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
        if fused:
            train_hist.append(max_abs)
        else:
            _abs_residual(res, out=res_abs)
            train_hist.append(res_abs.max())
        best_train = min(best_train, train_hist[-1])
        # compared by division: divergence_factor * best_train overflows for targets near the float64 limit
        if train_hist[-1] / divergence_factor > best_train:
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
    coef = _finite_coefficients(_kernel_coefficients(chol[:m, :m], beta[:m]), y) if m else np.zeros((0, y.shape[1]))
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
    return GreedyResult(
        selected=selected[:m].copy(), coef=coef, newton_coef=newton, history=history, chol=chol[:m, :m].copy(),
        basis=basis[:m] if keep_basis else None,
    )


def active_set_greedy(
    functionals: HBFunctionals,
    targets: np.ndarray,
    *,
    max_centers: int,
    tol: float = 1e-10,
    power_tol: float = 1e-12,
    divergence_factor: float = 100.0,
    validation: Optional[tuple] = None,
    memory_limit: Optional[float] = None,
    log_every: int = 100,
    initial_points: int = 8192,
    refresh_every: int = 200,
    max_new_points: int = 4096,
    margin: float = 0.7,
    refresh_fraction: float = 0.25,
    seed: int = 0,
) -> GreedyResult:
    """Fast f-greedy: the Newton basis on an active subset of the points, refreshed against the full residual.

    The exact f-greedy streams the ``m x N`` Newton basis once per centre
    (``O(m^2 N)`` memory traffic in total).  Here the basis lives on an
    *active set* of ``N_S << N`` candidates (all ``2n`` components of
    ``initial_points`` random points, seeded); the greedy selects on it as
    usual.  Every ``refresh_every`` centres, and whenever the active set's
    residual reaches ``tol``, the interpolant is evaluated directly at *all*
    ``N`` candidates (:func:`functional_residuals`, ``O(M m 2n)`` flops, no
    basis), and up to ``max_new_points`` points whose residual exceeds the
    active set's maximum join it: their Newton-basis values for the existing
    centres are ``L^{-1} K(selected, new)`` (one triangular solve), their
    residuals and power function follow.  The run stops when the *full*
    residual is at or below ``tol`` or at ``max_centers``.

    The selection differs from the exact f-greedy's (it sees the active set
    only between refreshes); the returned residual is the full one, checked
    by direct evaluation.

    Parameters
    ----------
    functionals, targets, max_centers, tol, power_tol, divergence_factor, validation, memory_limit, log_every
        As in :func:`greedy_interpolation` (f-greedy, one output).
    initial_points
        Points in the first active set.
    refresh_every
        Centres between two refreshes.
    max_new_points
        Points added per refresh at most (the worst ones).
    margin
        The active set is trained down to ``margin * tol`` and points above
        ``max(margin * tol, active maximum)`` join it, so that the last
        refreshes do not each add a handful of points just above ``tol``.
    refresh_fraction
        Intermediate refreshes evaluate a fresh random fraction of the points
        outside the active set (violators cluster, a sample finds their
        regions); whenever that sample is at or below ``tol``, and at the end,
        every candidate is evaluated, so the stopping test is always over all
        ``N`` functionals.  1 evaluates everything every time.
    seed
        Seed of the initial draw and of the refresh samples.

    Returns
    -------
    GreedyResult
        ``history.train_max_residual[k]`` is the active set's maximum after
        ``k`` centres, except the last entry: the full maximum over all ``N``
        candidates.  ``history.stop_reason`` is ``'tol'`` only if that full
        maximum is at or below ``tol``.

    Notes
    -----
    Memory ``8 m_max (2n N_S + N_val)`` bytes for the basis; time
    ``O(m^2 N_S / 2)`` memory traffic plus ``O(M m 2n)`` flops per refresh.
    """
    if not isinstance(functionals, HBFunctionals):
        raise ValueError("active_set_greedy needs HBFunctionals (state-derivative functionals)")
    n = functionals.n_functionals
    dim = functionals.dim
    n_points = len(functionals.points)
    y = np.asarray(targets, dtype=float)
    if y.size != n:
        raise ValueError(f"active_set_greedy interpolates one output: targets must have shape ({n},), got {y.shape}")
    y = y.reshape(n)
    if int(max_centers) < 1:
        raise ValueError(f"max_centers must be a positive integer, got {max_centers!r}")
    max_centers = min(int(max_centers), n)
    n_val = 0
    if validation is not None:
        val_functionals, val_targets = validation
        n_val = val_functionals.n_functionals
        vres = np.array(val_targets, dtype=float).reshape(n_val)
    rng = np.random.default_rng(seed)
    pts = np.sort(rng.choice(n_points, size=min(n_points, int(initial_points)), replace=False))
    cap_points = min(n_points, len(pts) + 4 * int(max_new_points))
    _check_memory(max_centers, cap_points * dim, n_val, memory_limit)

    if not 0 < margin <= 1:
        raise ValueError(f"margin must lie in (0, 1], got {margin!r}")
    inner_tol = margin * tol
    kernel = functionals.kernel
    diag0 = float(functionals.diagonal()[0])
    breakdown = power_tol * diag0
    in_active = np.zeros(n_points, dtype=bool)
    in_active[pts] = True
    cand = (pts[:, None] * dim + np.arange(dim)).reshape(-1)
    sub = HBFunctionals(kernel, functionals.points[pts], functionals.mu[pts], functionals.dt[pts])
    basis = np.empty((max_centers, cap_points * dim))
    vbasis = np.empty((max_centers, n_val)) if n_val else None
    res = y[cand].copy()
    p2 = np.full(len(cand), diag0)
    res_abs = np.abs(res)
    chol = np.zeros((max_centers, max_centers))
    beta = np.zeros(max_centers)
    selected = np.empty(max_centers, dtype=np.int64)
    sel_power = np.empty(max_centers)
    elapsed = np.empty(max_centers)
    train_hist = [np.abs(y).max()]
    val_hist = [np.abs(vres).max()] if n_val else None
    best_train = train_hist[0]
    stop_reason = None
    t0 = time.perf_counter()
    m = 0
    since_refresh = 0
    full_max = train_hist[0]
    while stop_reason is None:
        n_s = len(cand)
        exhausted = False
        while m < max_centers and since_refresh < refresh_every:
            score = np.where(p2 > breakdown, res_abs, -np.inf)
            j = int(np.argmax(score))
            if not np.isfinite(score[j]) or res_abs[j] <= inner_tol:
                exhausted = True
                break
            row = sub.column(sub.representer(j), out=basis[m, :n_s])
            coeffs_j = basis[:m, j].copy()
            if m:
                row -= basis[:m, :n_s].T @ coeffs_j
            pj = np.sqrt(p2[j])
            row *= 1.0 / pj
            chol[m, :m] = coeffs_j
            chol[m, m] = pj
            b = res[j] / pj
            beta[m] = b
            res -= b * row
            res[j] = 0.0
            p2 -= row * row
            p2[j] = 0.0
            np.abs(res, out=res_abs)
            if n_val:
                vrow = val_functionals.column(functionals.representer(cand[j]), out=vbasis[m])
                if m:
                    vrow -= vbasis[:m].T @ coeffs_j
                vrow *= 1.0 / pj
                vres -= b * vrow
                val_hist.append(np.abs(vres).max())
            selected[m] = cand[j]
            sel_power[m] = pj
            m += 1
            since_refresh += 1
            elapsed[m - 1] = time.perf_counter() - t0
            train_hist.append(res_abs.max())
            best_train = min(best_train, train_hist[-1])
            if train_hist[-1] / divergence_factor > best_train:  # no overflow near the float64 limit
                m_best = int(np.argmin(train_hist))
                logger.warning(
                    f"active-set greedy residual blew up at {m} centres ({train_hist[-1]:.2e} vs best {best_train:.2e}); "
                    f"truncating to {m_best} centres (raise power_tol to avoid)"
                )
                m = m_best
                del train_hist[m + 1 :]
                if val_hist is not None:
                    del val_hist[m + 1 :]
                stop_reason = "diverged"
                break
            if log_every and m % log_every == 0:
                logger.info(
                    f"{m} centres: active max {train_hist[-1]:.3e} over {n_s} candidates"
                    + (f", E_val={val_hist[-1]:.3e}" if n_val else "")
                    + f", {elapsed[m - 1]:.1f}s"
                )
        # ---- refresh: residuals by direct evaluation (a sample of the outside points, or all)
        coef = _kernel_coefficients(chol[:m, :m], beta[:m]) if m else np.zeros(0)
        since_refresh = 0
        full = refresh_fraction >= 1 or m >= max_centers or stop_reason is not None or m == 0
        if not full:
            outside = np.flatnonzero(~in_active)
            size = min(outside.size, max(1, int(np.ceil(refresh_fraction * outside.size))))
            pool = np.sort(rng.choice(outside, size=size, replace=False)) if size else outside
            r_eval = functional_residuals(functionals, y, selected[:m], coef, points=pool)
            sample_max = float(np.abs(r_eval).max()) if r_eval.size else 0.0
            logger.info(f"refresh at {m} centres: max residual {sample_max:.3e} on {pool.size} sampled points "
                        f"({len(cand)} active candidates)")
            full = sample_max <= tol
            pool_res = np.abs(r_eval).reshape(-1, dim).max(axis=1) if r_eval.size else np.zeros(0)
        if full:
            r_all = functional_residuals(functionals, y, selected[:m], coef) if m else y.copy()
            full_max = float(np.abs(r_all).max())
            logger.info(f"refresh at {m} centres: full max residual {full_max:.3e} ({len(cand)} active candidates)")
            if stop_reason is not None:
                break
            if full_max <= tol:
                stop_reason = "tol"
                break
            if m >= max_centers:
                stop_reason = "max_centers" if max_centers < n else "exhausted"
                break
            pool = np.flatnonzero(~in_active)
            pool_res = np.abs(r_all).reshape(n_points, dim).max(axis=1)[pool]
        active_max = float(np.where(p2 > breakdown, res_abs, 0.0).max()) if len(cand) else 0.0
        hit = pool_res > max(inner_tol, active_max)
        new, new_res = pool[hit], pool_res[hit]
        if new.size > max_new_points:
            new = new[np.argpartition(new_res, -max_new_points)[-max_new_points:]]
        if new.size == 0:
            if exhausted:
                stop_reason = "power"
                break
            continue
        new = np.sort(new)
        # ---- the new points' Newton-basis values, residuals and power function
        new_sub = HBFunctionals(kernel, functionals.points[new], functionals.mu[new], functionals.dt[new])
        n_new = new.size * dim
        if m:
            kmat = new_sub.gram_rows(functionals, selected[:m], out=np.empty((m, n_new)))
            vals = solve_triangular(chol[:m, :m], kmat, lower=True, overwrite_b=True, check_finite=False)
        else:
            vals = np.zeros((0, n_new))
        new_cand = (new[:, None] * dim + np.arange(dim)).reshape(-1)
        if n_s + n_new > basis.shape[1]:
            grown = np.empty((max_centers, max(n_s + n_new, 2 * basis.shape[1])))
            _check_memory(max_centers, grown.shape[1], n_val, memory_limit)
            grown[:m, :n_s] = basis[:m, :n_s]
            basis = grown
        basis[:m, n_s : n_s + n_new] = vals
        res = np.concatenate([res, y[new_cand] - beta[:m] @ vals])
        p2 = np.concatenate([p2, diag0 - np.einsum("ki,ki->i", vals, vals)])
        res_abs = np.abs(res)
        cand = np.concatenate([cand, new_cand])
        in_active[new] = True
        pts = np.concatenate([pts, new])
        sub = HBFunctionals(kernel, functionals.points[pts], functionals.mu[pts], functionals.dt[pts])
    coef = _finite_coefficients(_kernel_coefficients(chol[:m, :m], beta[:m]), y) if m else np.zeros(0)
    train_hist[-1] = full_max
    history = GreedyHistory(
        train_max_residual=np.array(train_hist),
        val_max_residual=None if val_hist is None else np.array(val_hist),
        selected_power=sel_power[:m].copy(),
        elapsed=elapsed[:m].copy(),
        stop_reason=stop_reason,
    )
    logger.info(
        f"active-set greedy stopped ({stop_reason}) with {m} centres, full max residual {full_max:.3e}, "
        f"{len(cand)} of {n} candidates active"
    )
    return GreedyResult(selected=selected[:m].copy(), coef=coef, newton_coef=beta[:m].copy(), history=history,
                        chol=chol[:m, :m].copy())


def _matvec_t(basis: np.ndarray, m: int, c: np.ndarray) -> np.ndarray:
    """``basis[:m].T @ c`` for a float32 basis, shape (N,), float64.

    Compiled (numba) with float64 accumulation when available, streaming
    ``basis[:m]`` once in column chunks that keep the partial sums in cache;
    else a float32 BLAS product (``m N`` flops either way, ``4 m N`` bytes read).
    """
    from sympredict import _fastkernels

    if _fastkernels.HAVE_NUMBA:
        return _fastkernels.matvec_t(basis, m, c)
    return (basis[:m].T @ c.astype(np.float32)).astype(float)


def functional_residuals(
    functionals: HBFunctionals, targets: np.ndarray, selected: np.ndarray, coef: np.ndarray, points: Optional[np.ndarray] = None
) -> np.ndarray:
    """Residuals ``y_i - lambda_i(s)`` of an HB interpolant at *every* candidate, by direct evaluation.

    Independent of the Newton basis: this is the check of a greedy run's
    claimed residual (float32 basis, active-set training) against the model
    that is actually returned.

    Parameters
    ----------
    functionals
        The ``N = M 2n`` state-derivative functionals (:class:`HBFunctionals`).
    targets : ndarray of shape (N,)
    selected : ndarray of shape (m,), int
        Flat indices of the centres (``point * 2n + component``).
    coef : ndarray of shape (m,)
        Kernel-basis coefficients.
    points : ndarray of shape (P,), int, optional
        Evaluate at these points only (all their ``2n`` functionals).

    Returns
    -------
    ndarray of shape (N,) (or (P * 2n,) with ``points``)

    Notes
    -----
    ``O(M m 2n)`` flops.  Points are grouped by their distinct ``(mu, dT)``
    (15 on the pendulum), so the parameter weights cost ``O(G m)``, not
    ``O(M m)``; compiled and parallel with numba, chunked NumPy otherwise.
    """
    from sympredict import _fastkernels
    from sympredict.surrogate import HBSurrogate

    dim = functionals.dim
    pts, comps = np.divmod(np.asarray(selected, dtype=np.int64), dim)
    sur = HBSurrogate(functionals.kernel, functionals.points[pts], functionals.mu[pts], functionals.dt[pts], comps, coef)
    groups = getattr(functionals, "_parameter_groups", None)
    if groups is None:  # computed once per set (a sort of M rows)
        params = np.column_stack([functionals.mu, functionals.dt])
        uniq, group = np.unique(params, axis=0, return_inverse=True)
        groups = functionals._parameter_groups = (uniq, group.reshape(-1))
    uniq, group = groups
    xi = functionals.points
    y = np.asarray(targets, dtype=float).reshape(len(xi), dim)
    if points is not None:
        points = np.asarray(points, dtype=np.int64)
        xi, group, y = xi[points], group[points], y[points]
    wg = sur.weights(uniq[:, :-1], uniq[:, -1])
    name = functionals.kernel.state.name
    if _fastkernels.HAVE_NUMBA and name in _fastkernels.KERNEL_KINDS:
        grad = _fastkernels.gradients(xi, group, wg, sur.layout(), name, functionals.kernel.state.eps)
    else:
        grad = np.empty_like(xi)
        step = 2048
        for start in range(0, len(grad), step):
            sl = slice(start, start + step)
            grad[sl] = sur.gradient(xi[sl], wg[group[sl]])
    return (y - grad).reshape(-1)


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
