"""The grid and coordinate searches of kernel shapes on validation data (the algorithm of
:mod:`sympredict.estimators.selection`, which adds the default estimator).

Every candidate tuple ``(k_xi, k_mu, k_dT)`` is trained by f-greedy to ``m_star``
centres; the tuple with the smallest validation residual ``E_val(m_star)``
wins.  Shape parameters are searched on logarithmic grids (:func:`log_grid`)
because useful values span decades (reduced wave coordinates are of size ~20,
so state shapes ~5e-3 fit there, pendulum states are of size ~5).
This module needs no estimator class: the candidates are clones of the estimator passed in, so
the estimator's own kernel search (:mod:`sympredict.estimators.auto`) runs it too.
"""

from __future__ import annotations

import contextlib
import itertools
import logging
import time
from dataclasses import dataclass, field
from typing import Optional, Sequence

import numpy as np
from pymor.core.logger import getLogger

from sympredict.base import clone
from sympredict.data import FlowMapData
from sympredict.kernels import KERNEL_FAMILIES, RadialKernel
from sympredict.kernels.transforms import KernelTransform

__all__ = ["log_grid", "kernel_grid", "SelectionResult", "select_kernels", "refine_kernel_shapes", "WIDEN_LIMITS"]

logger = getLogger("sympredict.estimators.selection")
@contextlib.contextmanager
def _quiet(*names, level: int = logging.WARNING):
    """Raise the given loggers to ``level`` for the duration (candidate fits are logged as one line each)."""
    loggers = [logging.getLogger(n) for n in names]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(max(lg.getEffectiveLevel(), level))
    try:
        yield
    finally:
        for lg, level in zip(loggers, levels):
            lg.setLevel(level)


#: Shape parameters the automatic widening of a grid may reach.
WIDEN_LIMITS = (1e-6, 1e6)


def _spec(kernel: Optional[RadialKernel]) -> Optional[dict]:
    return None if kernel is None else kernel.spec


def log_grid(lo: float, hi: float, per_decade: int = 2) -> np.ndarray:
    """Logarithmically spaced values from ``lo`` to ``hi`` with ``per_decade`` points per decade."""
    if not (0 < lo <= hi):
        raise ValueError(f"log_grid needs 0 < lo <= hi, got {lo!r}, {hi!r}")
    n = max(1, int(round(np.log10(hi / lo) * per_decade)) + 1)
    return np.geomspace(lo, hi, n)


def kernel_grid(families: Sequence[str], eps_values) -> list[Optional[RadialKernel]]:
    """All kernels ``family(eps)``; ``families=()`` or ``eps_values=None`` gives ``[None]`` (factor dropped)."""
    if eps_values is None or not families:
        return [None]
    unknown = [f for f in families if f not in KERNEL_FAMILIES]
    if unknown:
        raise ValueError(f"unknown kernel families {unknown}; choose from {sorted(KERNEL_FAMILIES)}")
    return [KERNEL_FAMILIES[f](float(e)) for f in families for e in eps_values]


@dataclass
class SelectionResult:
    """Outcome of :func:`select_kernels`.

    Attributes
    ----------
    state, mu, dt
        The chosen kernels (``None`` where the factor is dropped).
    score : float
        Its ``E_val(m_star)``.
    complete : bool
        Whether its greedy reached ``m_star`` centres (or the residual tolerance).
    table : list of dict
        Every candidate: its kernels' specs (``state``, ``mu``, ``dt``: ``{'family', 'eps'}``
        or ``None``), a readable ``kernels`` label, ``E_val(m_star)``,
        ``E_train(m_star)``, centres, ``complete``, fit time, and ``error`` for
        a candidate whose fit failed (scored ``inf``, skipped).
    """

    state: RadialKernel
    mu: Optional[RadialKernel]
    dt: Optional[RadialKernel]
    score: float
    complete: bool = True
    table: list = field(default_factory=list)

    def rank(self, prefer_complete: bool = False) -> tuple:
        """Sort key, smaller is better: by ``E_val``, non-finite scores last; with ``prefer_complete``,
        candidates that reached ``m_star`` before those that stopped early."""
        finite = bool(np.isfinite(self.score))
        return (not finite, prefer_complete and not self.complete, self.score if finite else np.inf)


def select_kernels(
    data: FlowMapData,
    validation: FlowMapData,
    state_kernels: Sequence[RadialKernel],
    mu_kernels: Sequence[Optional[RadialKernel]] = (None,),
    dt_kernels: Sequence[Optional[RadialKernel]] = (None,),
    m_star: int = 300,
    prefer_complete: bool = False,
    estimator=None,
    widen: int = 2,
) -> SelectionResult:
    """Grid search over kernel tuples by validation residual at ``m_star`` centres.

    Parameters
    ----------
    data, validation
        Training and validation flow-map data.
    state_kernels, mu_kernels, dt_kernels
        Candidates per factor (``None`` drops a factor).
    m_star
        Number of greedy centres at which candidates are compared.
    prefer_complete
        Rank candidates whose greedy stopped early (power breakdown) behind
        those that reached ``m_star`` (:meth:`SelectionResult.rank`).  Use it
        when ``m_star`` is close to the final budget.
    estimator
        The (unfitted) estimator whose settings every candidate shares; each
        candidate is ``clone(estimator).set_params(state_kernel=..., mu_kernel=...,
        dt_kernel=..., max_centers=m_star, trainer__tol=0)``; where the estimator's
        state kernel is a transform (``Scaled``, ``Periodic``, ``Symmetric``), the
        candidate state kernels go inside it.  Required here (:func:`sympredict.estimators.selection.select_kernels`
        defaults to ``SymplecticKernelPredictor()``).
    widen
        When the winner's shape lies on the edge of its grid (a family with at
        least two shapes), try one more grid step beyond that edge (the grid's
        ratio there), at most ``widen`` times per factor and within
        :data:`WIDEN_LIMITS`; such candidates are marked ``widened`` in the table.
        A winner still on an edge afterwards is logged as a warning.

    Returns
    -------
    SelectionResult

    Notes
    -----
    Cost: one greedy to ``m_star`` per candidate, ``O(m_star^2 (N + N_val))`` each.
    A candidate whose greedy stops early on a power breakdown (the kernel
    matrix is numerically singular: the kernel cannot use more centres) is
    scored at its last step.  That suits small ``m_star`` and cases where
    every kernel breaks down early anyway (the reduced wave: the best kernel
    stops at 273 centres, the best complete one at 383 with twice its
    error).  Near the final budget, ``prefer_complete`` ranks it behind every
    candidate that reached ``m_star``: on the pendulum such a kernel (IMQ
    eps 0.1, 786 of 1000 centres) had the lowest ``E_val(1000)``, but its
    final model stopped at 791 of 1500 centres with 8x larger trajectory
    errors than the complete runner-up's.  Non-finite scores never win; a
    candidate whose fit fails (``ValueError``, e.g. overflowing coefficients)
    is scored ``inf``, logged and skipped.  When no candidate has halved its
    validation residual at ``m_star``, a warning says that ``m_star`` is below
    what they need (the ranking says little about the final size).
    """
    if estimator is None:
        raise ValueError("select_kernels of sympredict.estimators.grid needs the estimator whose settings the "
                         "candidates share (sympredict.estimators.selection.select_kernels defaults to one)")
    base = estimator
    mu = None if data.mu.shape[1] == 0 else data.mu
    vmu = None if validation.mu.shape[1] == 0 else validation.mu
    dt_fixed = np.ptp(data.dt) == 0
    table = []
    unresolved = []  # per fitted candidate: is its validation residual at m_star still above half its start?

    def score(tup, widened=False) -> SelectionResult:
        state, mu_k, dt_k = tup
        inside = base.state_kernel.with_radial(state) if isinstance(base.state_kernel, KernelTransform) else state
        model = clone(base).set_params(state_kernel=inside, mu_kernel=mu_k, dt_kernel=dt_k, max_centers=m_star,
                                       trainer__tol=0.0)
        label = " x ".join(repr(k) for k in tup if k is not None)
        row = {"state": _spec(state), "mu": _spec(mu_k), "dt": _spec(dt_k), "kernels": label, "widened": widened}
        t0 = time.perf_counter()
        try:
            with _quiet("sympredict.interpolation.greedy", "sympredict.estimators.predictor"):
                model.fit(data.x0, data.x1, mu=mu if mu_k is not None else None, dt=data.dt,
                          validation=(validation.x0, validation.x1, vmu if mu_k is not None else None, validation.dt))
        except (ValueError, ArithmeticError) as exc:  # LinAlgError is a ValueError
            # a candidate that cannot be trained (coefficients overflow, memory, ...) is scored and skipped
            row.update(E_val=np.inf, E_train=np.inf, n_centers=0, complete=False, error=str(exc),
                       fit_s=time.perf_counter() - t0)
            table.append(row)
            logger.warning(f"{label}: fit failed, candidate skipped ({exc})")
            return SelectionResult(state, mu_k, dt_k, np.inf, False)
        val = model.history_.val_max_residual
        value = float(val[-1])
        complete = model.n_centers_ >= m_star or model.history_.stop_reason == "tol"
        if np.isfinite(value):
            unresolved.append(value > 0.5 * float(val[0]))
        row.update(E_val=value, E_train=float(model.history_.train_max_residual[-1]), n_centers=model.n_centers_,
                   complete=complete, fit_s=time.perf_counter() - t0)
        table.append(row)
        logger.info(f"{label}: E_val({model.n_centers_}) = {value:.3e}"
                    + ("" if complete else f" (stopped early: {model.history_.stop_reason})"))
        return SelectionResult(state, mu_k, dt_k, value, complete)

    def better(a, b) -> bool:
        return np.isfinite(a.score) and (b is None or a.rank(prefer_complete) < b.rank(prefer_complete))

    best = None
    for tup in itertools.product(state_kernels, mu_kernels, dt_kernels):
        if tup[2] is None and not dt_fixed:
            raise ValueError("dt_kernels must not contain None when the data have several macro steps")
        candidate = score(tup)
        if better(candidate, best):
            best = candidate
    if best is None:
        raise ValueError("no candidate produced a finite validation residual: every fit failed or broke down "
                         "(see the table of the log); try other kernel families or shapes")
    # a winner on the edge of its shape grid: extend the grid beyond that edge, one step at a time
    grids = [sorted({k.eps for k in opts if k is not None and type(k) is type(chosen)}) if chosen is not None else []
             for opts, chosen in ((state_kernels, best.state), (mu_kernels, best.mu), (dt_kernels, best.dt))]
    for _ in range(widen):
        moved = False
        for i, grid in enumerate(grids):
            tup = [best.state, best.mu, best.dt]
            chosen = tup[i]
            if chosen is None or len(grid) < 2 or chosen.eps not in (grid[0], grid[-1]):
                continue
            ratio = grid[0] / grid[1] if chosen.eps == grid[0] else grid[-1] / grid[-2]
            eps = chosen.eps * ratio
            if not WIDEN_LIMITS[0] <= eps <= WIDEN_LIMITS[1]:
                continue
            grid.insert(0 if ratio < 1 else len(grid), eps)
            tup[i] = chosen.set_params(eps=eps)
            logger.info(f"the chosen {('state', 'mu', 'dt')[i]} kernel {chosen!r} lies on the edge of its shape grid: "
                        f"trying {tup[i]!r}")
            candidate = score(tuple(tup), widened=True)
            if better(candidate, best):
                best, moved = candidate, True
        if not moved:
            break
    best.table = table
    for name, chosen, grid in zip(("state", "mu", "dt"), (best.state, best.mu, best.dt), grids):
        if chosen is not None and len(grid) > 1 and chosen.eps in (grid[0], grid[-1]):
            logger.warning(f"the chosen {name} kernel {chosen!r} lies on the edge of its shape grid"
                           + (f" after widening it {widen} time(s)" if widen else "") + ": widen the grid")
    if unresolved and all(unresolved):
        logger.warning(f"m_star={m_star} is below what every candidate needs: no candidate has halved its validation "
                       "residual at m_star, so the ranking says little about the final size; raise m_star")
    return best


def refine_kernel_shapes(
    data: FlowMapData,
    validation: FlowMapData,
    start: SelectionResult,
    m_star: int,
    factor: float = 2.0,
    max_sweeps: int = 3,
    prefer_complete: bool = False,
    estimator=None,
    refine: Sequence[bool] = (True, True, True),
) -> SelectionResult:
    """Coordinate search of the shape parameters around ``start`` at a larger ``m_star``.

    A grid search at small ``m_star`` is cheap but favours flat kernels (few
    centres resolve little); this refines the winner where the final model
    lives.  Each sweep tries every factor's shape times ``1/factor`` and
    ``factor`` (the family kept), one factor at a time, keeping any candidate
    that ranks better (:meth:`SelectionResult.rank`: lower ``E_val(m_star)``,
    with ``prefer_complete`` complete runs first); it stops after a sweep without improvement
    or after ``max_sweeps`` sweeps.

    refine : (bool, bool, bool)
        Which shapes are searched: state, parameter, step (the others are kept).

    Returns
    -------
    SelectionResult
        The best tuple, scored at ``m_star``; ``table`` lists every candidate
        evaluated here (the start re-scored first).

    Notes
    -----
    Cost: at most ``1 + 6 max_sweeps`` greedy fits to ``m_star`` centres (fewer
    with dropped factors); candidates already scored are not refitted.
    """
    if not (factor > 1):
        raise ValueError(f"factor must be > 1, got {factor!r}")
    scored = {}

    def score(tup):
        if tup not in scored:  # kernels are values: equal family and shape, equal key
            scored[tup] = select_kernels(data, validation, [tup[0]], [tup[1]], [tup[2]], m_star=m_star,
                                         prefer_complete=prefer_complete, estimator=estimator, widen=0)
        return scored[tup]

    best = score((start.state, start.mu, start.dt))
    for sweep in range(max_sweeps):
        improved = False
        for i in range(3):
            current = (best.state, best.mu, best.dt)
            if current[i] is None or not refine[i]:
                continue
            for f in (1 / factor, factor):
                tup = list(current)
                tup[i] = current[i].set_params(eps=current[i].eps * f)
                cand = score(tuple(tup))
                if cand.rank(prefer_complete) < best.rank(prefer_complete):
                    best, improved = cand, True
        logger.info(f"shape refinement sweep {sweep + 1}: {best.state!r}, {best.mu!r}, {best.dt!r}: E_val({m_star}) = {best.score:.3e}")
        if not improved:
            break
    table = [row for r in scored.values() for row in r.table]
    return SelectionResult(best.state, best.mu, best.dt, best.score, best.complete, table)
