"""The f-greedy (and P-greedy) loop, written once, over a small store interface.

Given ``N`` candidate linear functionals ``lambda_i`` with generalized Gramian
``G_ij = lambda_i^(1) lambda_j^(2) k`` and data ``y_i``, the greedy picks one
functional per step (VKOGA; Santin & Haasdonk 2021).  The Newton basis
``v_0, ..., v_{m-1}`` evaluated at the candidates, the residuals
``r_i = y_i - lambda_i(s_m)`` and the squared power function
``P2_i = G_ii - sum_k v_k(lambda_i)^2`` live in a *store*; one step with
selected functional ``j`` is

    v_m      = (G[:, j] - basis[:m].T @ basis[:m, j]) / sqrt(P2_j)
    beta_m   = r_j / sqrt(P2_j)
    r       -= beta_m v_m,     P2 -= v_m^2.

f-greedy picks ``j = argmax |r_i|``, P-greedy ``j = argmax P2_i``, both among
the candidates whose ``P2_i`` is above ``power_tol * max_i G_ii`` (the
breakdown guard: the others are linearly dependent on the selection up to
round-off).  With ``L[m, k] = v_k(lambda_{j_m})`` (lower triangular, the
Cholesky factor of the selected Gramian) the kernel-basis coefficients are
``c = L^{-T} beta``.

:func:`run_greedy` owns what every variant shares: argument checks, the stop
rules (``tol``, ``power``, ``max_centers``, divergence with truncation to the
best step), the Newton coefficients ``L`` and ``beta``, the history, logging
and the final coefficients.  A store (:class:`NewtonBasisStore`) owns where
the basis lives and how a step updates it:

* :class:`~sympredict.interpolation.greedy.dense.DenseStore`: all candidates in memory,
  float64 or float32 (the exact greedy);
* :class:`~sympredict.interpolation.greedy.active_set.ActiveSetStore`: an active subset,
  refreshed against the full residual;
* :class:`~sympredict.interpolation.greedy.sharded.ShardedStore`: contiguous shards over a
  pyMOR worker pool.

The training strategies of the estimators (:mod:`sympredict.interpolation.greedy.trainers`)
build a store and call :func:`run_greedy`.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from typing import Callable, Optional, Protocol

import numpy as np
from pymor.core.logger import getLogger
from scipy.linalg import solve_triangular

__all__ = [
    "GreedyHistory",
    "GreedyResult",
    "NewtonBasisStore",
    "Expansion",
    "run_greedy",
    "available_memory",
    "format_bytes",
    "check_memory",
    "kernel_coefficients",
    "as_targets",
    "BaseStore",
    "Checkpoints",
    "checkpoint_schedule",
]

logger = getLogger("sympredict.interpolation.greedy")


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
        step), ``'exhausted'`` (every candidate selected), ``'target'`` (a checkpoint met the target) or
        ``'abandoned'`` (a checkpoint's ``give_up`` stopped it: a search's candidate clearly losing).
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
    stats : dict
        The store's statistics of the run (the sharded store's pool timings; empty for the others).
    """

    selected: np.ndarray
    coef: np.ndarray
    newton_coef: np.ndarray
    history: GreedyHistory = field(repr=False)
    chol: Optional[np.ndarray] = field(default=None, repr=False)
    basis: Optional[np.ndarray] = field(default=None, repr=False)
    stats: dict = field(default_factory=dict, repr=False)

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
        return kernel_coefficients(self.chol[:m, :m], self.newton_coef[:m])


def available_memory() -> int:
    """Bytes of memory the process may use: ``SYMPREDICT_MEMORY`` if set (bytes, or with a suffix ``K``/``M``/``G``:
    binary units), else ``MemAvailable`` of ``/proc/meminfo`` capped by a cgroup's ``memory.max`` (a container's
    limit), else the total memory."""
    given = os.environ.get("SYMPREDICT_MEMORY", "").strip()
    if given:
        units = {"K": 2**10, "M": 2**20, "G": 2**30, "T": 2**40}
        scale = units.get(given[-1].upper(), 1)
        try:
            value = float(given[:-1] if scale > 1 else given) * scale
        except ValueError:
            value = -1.0
        if not (np.isfinite(value) and value > 0):
            raise ValueError(f"SYMPREDICT_MEMORY must be a positive number of bytes such as 24e9 or 24G, got {given!r}")
        return int(value)
    found = None
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    found = int(line.split()[1]) * 1024
    except OSError:
        pass
    if found is None:
        found = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    try:
        with open("/sys/fs/cgroup/memory.max") as f:
            cap = f.read().strip()
        with open("/sys/fs/cgroup/memory.current") as f:
            used = int(f.read().strip())
        if cap.isdigit():
            found = min(found, max(int(cap) - used, 0))
    except (OSError, ValueError):
        pass
    return int(found)


def format_bytes(n: float) -> str:
    for unit, size in (("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if n >= size:
            return f"{n / size:.2f} {unit}"
    return f"{n:.0f} B"


def as_targets(targets, n: int) -> tuple:
    """The greedy's data as a float array of shape (N, q), whether it was a vector, and ``max |y|``."""
    y = np.asarray(targets, dtype=float)
    y2 = y.reshape(n, -1)
    return y2, y.ndim == 1, float(np.abs(y2).max()) if n else 0.0


def kernel_coefficients(chol: np.ndarray, beta: np.ndarray) -> np.ndarray:
    """Kernel-basis coefficients ``c = L^{-T} beta`` from the Newton expansion (``O(m^2)``).

    Returned C-contiguous: LAPACK gives Fortran order for a 2-D ``beta``, and fitted state has one
    memory layout whatever produced it (BLAS rounds differently on another layout).
    """
    return np.ascontiguousarray(solve_triangular(chol, beta, lower=True, trans="T"))


def _finite_coefficients(coef: np.ndarray, targets_max: float) -> np.ndarray:
    """``coef``, or a ``ValueError`` when it overflowed (targets near the float64 limit)."""
    if not np.all(np.isfinite(coef)):
        raise ValueError(
            f"the kernel coefficients overflow (max |target| = {targets_max:.3g}): the training targets "
            "are too large for float64; rescale the data (for flow maps, (x1 - x0) / dt with a tiny dt)"
        )
    return coef


def check_memory(max_centers: int, n_train: int, n_val: int, memory_limit: Optional[float], itemsize: int = 8) -> None:
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
        offers = [f"use max_centers <= {fit_centers}"] if fit_centers >= 1 else []
        if fit_candidates > 0:
            offers.append(f"use at most {fit_candidates} training functionals (a subset of the samples)")
        else:
            offers.append("use fewer training samples")
        if itemsize == 8 and 4 * max_centers * n_all <= limit:
            offers.append(f"store the basis in float32 (basis_dtype='float32': {format_bytes(need / 2)})")
        raise ValueError(
            f"the Newton basis needs {format_bytes(need)} ({max_centers} centres x "
            f"{n_all} functionals x {itemsize} bytes) but the memory limit is {format_bytes(limit)}; "
            + ", ".join(offers)
            + ", or raise memory_limit"
        )


class Expansion:
    """The Newton expansion built so far, owned by :func:`run_greedy` and readable by the store.

    Attributes
    ----------
    selected : ndarray of shape (m_max,), int
        Global flat indices of the selected functionals (first ``m`` valid).
    chol : ndarray of shape (m_max, m_max)
        ``L[i, k] = v_k(lambda_{j_i})``.
    beta : ndarray of shape (m_max, q)
        Newton coefficients (``m_max``: the run's ``max_centers``).
    """

    def __init__(self, max_centers: int, n_outputs: int):
        self.max_centers = max_centers
        self.selected = np.empty(max_centers, dtype=np.int64)
        self.chol = np.zeros((max_centers, max_centers))
        self.beta = np.zeros((max_centers, n_outputs))

    def coef(self, m: int) -> np.ndarray:
        """Kernel-basis coefficients ``(m, q)`` of the interpolant on the first ``m`` functionals."""
        if m == 0:
            return np.zeros((0, self.beta.shape[1]))
        return kernel_coefficients(self.chol[:m, :m], self.beta[:m])


def checkpoint_schedule(max_centers: int, first: int = 16, factor: float = 1.25) -> list:
    """Centre counts ``first, first * factor, ...`` (rounded, distinct) and ``max_centers``: where a run is scored.

    Geometric, so scoring costs a bounded share of the run: about ``log(m / first) / log(factor)`` checkpoints
    (25 up to 4,000 centres) whatever ``m``.
    """
    out, m = [], float(max(1, first))
    while int(round(m)) < max_centers:
        out.append(int(round(m)))
        m *= factor
    out.append(int(max_centers))
    return sorted(set(out))


class Checkpoints(Protocol):
    """Scores of prefixes of a run (held-out errors of the interpolant on the first ``m`` centres).

    :func:`run_greedy` calls :meth:`score` after the steps listed in ``at`` (and may call it at other ``m``
    to refine a crossing of the target); :meth:`keep` chooses the prefix the run returns.
    """

    at: list
    target: Optional[float]

    def score(self, m: int, selected: np.ndarray, coef: np.ndarray) -> float:
        """The error of the interpolant on the first ``m`` centres: flat indices ``selected`` (m,) of the
        selected functionals, kernel coefficients ``coef`` (m,) or (m, q)."""

    def keep(self, m: int) -> int:
        """Of a run with ``m`` centres, how many to keep (the best prefix, or the smallest meeting the target)."""

    # optional: ``give_up(m, score, val_max) -> bool`` after the score at a checkpoint of ``at`` (``val_max``: the
    # validation residual ``E_val(m)``, or None without validation): ``True`` stops the run there (reason
    # ``'abandoned'``: a search's candidate clearly losing, :class:`~sympredict.estimators.search.EarlyStop`)


class NewtonBasisStore(Protocol):
    """What :func:`run_greedy` needs of a store of the Newton basis.

    Attributes
    ----------
    n_functionals : int
        ``N``, the number of candidates.
    n_outputs : int
        ``q``, outputs interpolated with shared centres.
    targets_max : float
        ``max |y|`` (for the overflow message).
    squeeze : bool
        Whether the targets were given as a vector (then the result's
        coefficients are vectors too).
    label : str
        How the log names the variant.
    stats : dict
        Statistics of the run for :attr:`GreedyResult.stats` (may stay empty).
    """

    n_functionals: int
    n_outputs: int
    targets_max: float
    squeeze: bool
    label: str
    stats: dict

    def open(self, expansion: Expansion) -> tuple:
        """Allocate (memory checks first) and return ``(E_train(0), E_val(0) or None)``."""

    def select(self, m: int) -> tuple:
        """The next functional: ``(j, score, certified)``.

        ``j`` is the store's own index (``-1`` when no candidate is selectable),
        ``score`` its selection score, ``certified`` an upper bound of ``|r|``
        over every candidate that the ``tol`` rule covers (``inf`` when the store
        cannot vouch for one).
        """

    def winner(self, j: int, m: int) -> tuple:
        """``(global index, representer, v_k(lambda_j) for k < m, P2_j, r_j)`` of the store's functional ``j``."""

    def add(self, m: int, representer, coeffs: np.ndarray, pj: float, beta: np.ndarray, j: int) -> tuple:
        """Add Newton basis function ``m`` (functional ``j``); return ``(E_train(m+1), E_val(m+1) or None)``."""

    def finish(self, m: int) -> Optional[float]:
        """After the last step (``m`` centres kept): the full maximum residual if the store evaluates it, else None."""

    def close(self) -> None:
        """Release what :meth:`open` acquired (called on every exit path)."""


class BaseStore:
    """What every store sets up from its arguments: targets, criterion, breakdown setting, validation set.

    Subclasses call ``super().__init__`` and implement :class:`NewtonBasisStore`'s
    ``open``, ``select``, ``winner`` and ``add``; ``finish`` and ``close`` default
    to nothing.

    Attributes
    ----------
    y : ndarray of shape (N, q)
    vres : ndarray of shape (N_val, q)
        The validation residual (the validation targets at the start).
    """

    label = "greedy"

    def __init__(
        self,
        functionals,
        targets,
        *,
        criterion: str = "f",
        power_tol: float = 1e-12,
        validation: Optional[tuple] = None,
    ):
        self.functionals = functionals
        self.n_functionals = n = functionals.n_functionals
        self.y, self.squeeze, self.targets_max = as_targets(targets, n)
        self.n_outputs = self.y.shape[1]
        self.criterion = criterion
        self.power_tol = power_tol
        self.stats = {}
        self.val_functionals, self.n_val, self.vres = None, 0, None
        if validation is not None:
            self.val_functionals, val_targets = validation
            self.n_val = self.val_functionals.n_functionals
            self.vres = np.array(val_targets, dtype=float).reshape(self.n_val, -1)
            if self.vres.shape[1] != self.n_outputs:
                raise ValueError("validation targets must have as many outputs as the training targets")

    def finish(self, m: int) -> Optional[float]:
        return None

    def close(self) -> None:
        pass


def run_greedy(
    store: NewtonBasisStore,
    *,
    max_centers: int,
    tol: float = 1e-10,
    criterion: str = "f",
    divergence_factor: float = 100.0,
    log_every: int = 100,
    callback: Optional[Callable[[int, float], None]] = None,
    checkpoints: Optional[Checkpoints] = None,
) -> GreedyResult:
    """The greedy loop: selection, stop rules, Newton coefficients, history.

    Parameters
    ----------
    store
        Where the Newton basis lives (:class:`NewtonBasisStore`).
    max_centers
        Upper bound on the number of selected functionals (clamped to ``N``).
    tol
        f-greedy stops with ``'tol'`` once the store certifies ``max |r| <= tol``.
    criterion
        ``'f'`` or ``'p'``; the store selects by it, the loop applies ``tol`` only to ``'f'``.
    divergence_factor
        When ``E_train(m)`` exceeds ``divergence_factor`` times its minimum so far,
        the Newton basis has lost accuracy to round-off: the run stops with
        ``'diverged'`` and is truncated to the step with the smallest ``E_train``
        (a prefix of a Newton expansion is again an interpolant).
    log_every
        Log progress every this many steps.
    callback
        Called after each step with ``(m, E_train(m))``.
    checkpoints
        Scores of prefixes (:class:`Checkpoints`, e.g. held-out one-step errors) at the centre counts
        ``checkpoints.at``.  With a ``target``, the run stops (reason ``'target'``) at the first checkpoint
        whose score meets it, after refining by bisection between it and the previous checkpoint
        (prefixes cost no new selection); in any case the run is cut to ``checkpoints.keep(m)`` centres at
        the end (the best prefix: growing never returns a worse model than one it passed).  Where ``checkpoints``
        has a ``give_up(m, score, val_max)`` method and it returns ``True`` at a checkpoint, the run stops there (reason
        ``'abandoned'``).

    Returns
    -------
    GreedyResult
        ``history.stop_reason``: ``'max_centers'``, ``'exhausted'`` (every
        candidate selected), ``'tol'``, ``'power'`` (no selectable candidate
        left) or ``'diverged'``.  When the store evaluates the full residual
        at the end (:meth:`NewtonBasisStore.finish`), the last entry of
        ``history.train_max_residual`` is that value, and a run stopped at
        ``max_centers`` whose full residual is at or below ``tol`` reports ``'tol'``.

    Notes
    -----
    ``O(m_max^2)`` memory here (the Cholesky factor); the store's cost per step
    is documented with each store.
    """
    if criterion not in ("f", "p"):
        raise ValueError(f"criterion must be 'f' (f-greedy) or 'p' (P-greedy), got {criterion!r}")
    n = store.n_functionals
    if n == 0:
        raise ValueError("no candidate functionals: the training set is empty")
    try:
        max_centers = int(max_centers)
    except (TypeError, ValueError):
        raise ValueError(f"max_centers must be a positive integer, got {max_centers!r}") from None
    if max_centers < 1:
        raise ValueError(f"max_centers must be a positive integer, got {max_centers!r}")
    if not (np.isfinite(tol) and tol >= 0):
        raise ValueError(f"tol must be a finite non-negative float, got {tol!r}")
    if not (divergence_factor > 1):
        raise ValueError(f"divergence_factor must be a float > 1, got {divergence_factor!r}")
    max_centers = min(max_centers, n)
    expansion = Expansion(max_centers, store.n_outputs)
    sel_power = np.empty(max_centers)
    elapsed = np.empty(max_centers)
    stop_reason = "max_centers" if max_centers < n else "exhausted"
    train0, val0 = store.open(expansion)
    try:
        train_hist = [train0]
        val_hist = None if val0 is None else [val0]
        best_train = train0
        t0 = time.perf_counter()
        m = 0
        marks = set(checkpoints.at) if checkpoints is not None else set()
        last_mark = 0
        while m < max_centers:
            j, score, certified = store.select(m)
            if criterion == "f" and certified <= tol:
                stop_reason = "tol"
                break
            if j < 0 or not np.isfinite(score):
                stop_reason = "power"
                break
            index, rep, coeffs_j, p2_j, r_j = store.winner(j, m)
            pj = np.sqrt(p2_j)
            b = r_j / pj
            expansion.chol[m, :m] = coeffs_j
            expansion.chol[m, m] = pj
            expansion.beta[m] = b
            expansion.selected[m] = index
            sel_power[m] = pj
            train_max, val_max = store.add(m, rep, coeffs_j, pj, b, j)
            m += 1
            elapsed[m - 1] = time.perf_counter() - t0
            train_hist.append(train_max)
            if val_hist is not None:
                val_hist.append(val_max)
            best_train = min(best_train, train_max)
            if callback is not None:
                callback(m, train_max)
            # compared by division: divergence_factor * best_train overflows for targets near the float64 limit
            if train_max / divergence_factor > best_train:
                stop_reason = "diverged"
                m_best = int(np.argmin(train_hist))
                logger.warning(_divergence_message(store.label, m, m_best, train_max, best_train))
                m = m_best
                del train_hist[m + 1 :]
                if val_hist is not None:
                    del val_hist[m + 1 :]
                break
            if log_every and m % log_every == 0:
                logger.info(
                    f"{m} centres: E_train={train_max:.3e}"
                    + (f", E_val={val_max:.3e}" if val_hist is not None else "")
                    + f", P={pj:.2e}, {elapsed[m - 1]:.1f}s"
                )
            if m in marks:
                err = checkpoints.score(m, expansion.selected[:m], _squeezed(expansion.coef(m), store.squeeze))
                if checkpoints.target is not None and err <= checkpoints.target:
                    lo, hi = last_mark, m  # the crossing lies in (lo, hi]: bisect on prefixes
                    while hi - lo > 1:
                        mid = (lo + hi) // 2
                        coef_mid = _squeezed(expansion.coef(mid), store.squeeze)
                        if checkpoints.score(mid, expansion.selected[:mid], coef_mid) <= checkpoints.target:
                            hi = mid
                        else:
                            lo = mid
                    stop_reason = "target"
                    break
                give_up = getattr(checkpoints, "give_up", None)
                if give_up is not None and give_up(m, err, None if val_hist is None else val_hist[-1]):
                    stop_reason = "abandoned"
                    break
                last_mark = m
        if checkpoints is not None and m:
            if stop_reason != "target" and m not in marks:  # the final model is a candidate too
                checkpoints.score(m, expansion.selected[:m], _squeezed(expansion.coef(m), store.squeeze))
            keep = int(checkpoints.keep(m))
            if 0 < keep < m:
                why = "the smallest meeting the target" if stop_reason == "target" else "the best held-out prefix"
                logger.info(f"{store.label}: keeping the first {keep} of {m} centres ({why})")
                m = keep
                del train_hist[m + 1 :]
                if val_hist is not None:
                    del val_hist[m + 1 :]
        final = store.finish(m)
    finally:
        store.close()
    if final is not None:
        train_hist[-1] = final
        if criterion == "f" and stop_reason in ("max_centers", "exhausted") and final <= tol:
            stop_reason = "tol"
    coef = _finite_coefficients(expansion.coef(m), store.targets_max) if m else expansion.coef(0)
    history = GreedyHistory(
        train_max_residual=np.array(train_hist),
        val_max_residual=None if val_hist is None else np.array(val_hist),
        selected_power=sel_power[:m].copy(),
        elapsed=elapsed[:m].copy(),
        stop_reason=stop_reason,
    )
    logger.info(f"{store.label} stopped ({stop_reason}) with {m} centres, E_train={train_hist[-1]:.3e}")
    newton = expansion.beta[:m].copy()
    if store.squeeze:
        coef, newton = coef[:, 0], newton[:, 0].copy()
    return GreedyResult(
        selected=expansion.selected[:m].copy(),
        coef=coef,
        newton_coef=newton,
        history=history,
        chol=expansion.chol[:m, :m].copy(),
        stats=dict(store.stats),
    )


def _squeezed(coef: np.ndarray, squeeze: bool) -> np.ndarray:
    """Coefficients ``(m, q)`` as the result gives them: ``(m,)`` for targets given as a vector."""
    return coef[:, 0] if squeeze else coef


def _divergence_message(label: str, m: int, m_best: int, train_max: float, best_train: float) -> str:
    """What the greedy logs when its training residual blows up at ``m`` centres and it keeps the best ``m_best``."""
    if m_best == 0:
        return (
            f"{label} residual grew from {best_train:.2e} (no centres) to {train_max:.2e} with {m} centre(s): no "
            f"centre reduced it, so the fit keeps no centres (the zero correction); the data are inconsistent "
            f"(equal states with different targets: remove duplicate samples) or the kernel shapes do not "
            f"fit the data's scale (choose other shapes)"
        )
    return (
        f"{label} residual blew up at {m} centres ({train_max:.2e} vs best {best_train:.2e} at {m_best} centres): "
        f"round-off in the Newton basis; keeping the first {m_best} centres (a larger power_tol stops before it)"
    )
