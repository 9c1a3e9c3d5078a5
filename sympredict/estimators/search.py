"""The one search over estimator settings on held-out data: candidate grids, coordinate refinement of
shapes, held-out scores, and the record (table) of every candidate fitted.

Every search of the package runs here: the public selections of :mod:`sympredict.estimators.selection`
(:func:`~sympredict.estimators.selection.select_kernels`, ``refine_kernel_shapes``, ``select_regularization``,
``select_by_score``) and the estimator's own :class:`~sympredict.estimators.auto.KernelSearch`.  The pieces:

* **candidates**: kernels ``family(eps)`` on logarithmic grids of shapes (:func:`log_grid`, :func:`kernel_grid`),
  because useful values span decades (reduced wave coordinates are of size ~20, so state shapes ~5e-3 fit there,
  pendulum states are of size ~5); every candidate is ``clone(estimator).set_params(...)``
  (:func:`fit_candidate`), so no estimator class is needed here;
* **grid search** (:func:`grid_search`): every tuple ``(k_xi, k_mu, k_dT)`` trained by f-greedy to ``m_star``
  centres and ranked by its validation residual ``E_val(m_star)``, a winner on a grid's edge widened beyond it;
* **successive halving** (:func:`halving_survivors`, ``grid_search(..., rungs=...)``): candidates compared first at a
  fraction of the centres, only the best third (at least :data:`HALVING_KEEP`) going on to the next rung, so that
  clearly losing candidates cost a small fraction of a full fit (a greedy fit costs ``O(m^2 N)``);
* **coordinate refinement** (:func:`coordinate_search`): each coordinate of a candidate (a shape, or any value a
  caller can scale) times the given factors, one at a time, while a sweep improves the score
  (:func:`refine_shapes` at a larger ``m_star``; the kernel search's second stage);
* **held-out scores**: ``E_val(m_star)`` (the greedy's validation residual), the mean relative one-step error
  (:func:`one_step_score`), the relative error of rollouts of held-out trajectories
  (:func:`final_size_score`, :func:`relative_rollout_error`), or a score the caller computes on the fitted model
  (:func:`score_search`, :func:`ridge_search`);
* **the record**: one ``dict`` row per candidate fitted (settings, score, centres, fit time, ``error`` where the fit
  failed), kept in the result (:class:`SelectionResult`, ``table``).
"""

from __future__ import annotations

import contextlib
import contextvars
import itertools
import logging
import time
import warnings
from dataclasses import dataclass, field
from typing import Callable, Optional, Sequence

import numpy as np
from pymor.core.logger import getLogger

from sympredict.base import clone
from sympredict.data import FlowMapData
from sympredict.exceptions import NewtonConvergenceError, NonFinitePredictionError
from sympredict.kernels import KERNEL_FAMILIES, RadialKernel
from sympredict.kernels.transforms import KernelTransform

__all__ = [
    "log_grid",
    "kernel_grid",
    "WIDEN_LIMITS",
    "SelectionResult",
    "ScoredSelectionResult",
    "fit_candidate",
    "grid_search",
    "halving_survivors",
    "coordinate_search",
    "refine_shapes",
    "one_step_score",
    "final_size_score",
    "HeldOutScore",
    "EarlyStop",
    "relative_step_errors",
    "EARLY_STOP",
    "EARLY_STOP_MARGINS",
    "REVERSAL_MARGINS",
    "E_VAL_STOP_MARGINS",
    "CANDIDATE_STOP",
    "relative_rollout_error",
    "pair_factors",
    "column_std",
    "state_weights",
    "score_search",
    "ridge_search",
]

#: The searches' logger: the name users configure for the selections' progress.
SEARCH_LOGGER = "sympredict.estimators.selection"
logger = getLogger(SEARCH_LOGGER)

#: The loggers of a candidate's fit, quieted to one line per candidate.
FIT_LOGGERS = ("sympredict.interpolation.greedy", "sympredict.estimators.predictor")


#: ``True`` inside :func:`fit_candidate`: the fit is a search candidate, scored by the search itself, so its
#: ``diagnostics_`` skip the held-out Newton steps (:func:`~sympredict.estimators.auto.diagnose`).
CANDIDATE_FIT = contextvars.ContextVar("sympredict_candidate_fit", default=False)


@contextlib.contextmanager
def quiet_logs(*names, level: int = logging.WARNING):
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


# ------------------------------------------------------------------ candidates
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


def fit_candidate(
    model,
    data: FlowMapData,
    validation: Optional[FlowMapData] = None,
    *,
    uses_mu: bool = True,
    dt=None,
    quiet: bool = True,
):
    """Fit one candidate, ``model`` (an unfitted, configured clone), on ``data``; returns ``model``.

    Parameters
    ----------
    model : estimator
        ``clone(estimator).set_params(...)`` of the candidate.
    data : FlowMapData
        Training samples.
    validation : FlowMapData, optional
        Held-out samples of the greedy's ``E_val(m)`` (the fit's ``validation``).
    uses_mu : bool, default=True
        Pass the parameters (of ``data`` and ``validation``, where they have any); ``False`` for a candidate
        without a parameter kernel.
    dt : float or ndarray, optional
        The steps passed (default ``data.dt``).
    quiet : bool, default=True
        The fit's own log lines (greedy, estimator) at ``WARNING`` only: a search logs one line per candidate.

    Notes
    -----
    Without a target, the candidate's ``diagnostics_`` leave out the held-out one-step error (``nan``;
    :data:`CANDIDATE_FIT`): the
    search scores the candidate itself, and those Newton steps would cost a fit to a few dozen centres.
    """
    mu = data.mu if uses_mu and data.mu.shape[1] else None
    val = (
        None
        if validation is None
        else (
            validation.x0,
            validation.x1,
            validation.mu if uses_mu and validation.mu.shape[1] else None,
            validation.dt,
        )
    )
    token = CANDIDATE_FIT.set(True)
    try:
        with quiet_logs(*FIT_LOGGERS) if quiet else contextlib.nullcontext():
            return model.fit(data.x0, data.x1, mu=mu, dt=data.dt if dt is None else dt, validation=val)
    finally:
        CANDIDATE_FIT.reset(token)


# ------------------------------------------------------------------ grid search by E_val(m_star)
@dataclass
class SelectionResult:
    """Outcome of :func:`grid_search` (:func:`~sympredict.estimators.selection.select_kernels`).

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


def grid_search(
    data: FlowMapData,
    validation: FlowMapData,
    state_kernels: Sequence[RadialKernel],
    mu_kernels: Sequence[Optional[RadialKernel]] = (None,),
    dt_kernels: Sequence[Optional[RadialKernel]] = (None,),
    m_star: int = 300,
    prefer_complete: bool = False,
    estimator=None,
    widen: int = 2,
    rungs: Sequence[int] = (),
    early_stop: bool = False,
    bound: float = np.inf,
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
    rungs
        Successive halving (:func:`halving_survivors`): centre counts below ``m_star``, increasing; every
        candidate is first trained to ``rungs[0]`` centres and ranked by ``E_val(rungs[0])``, the best third (at
        least :data:`HALVING_KEEP` of them) go on to the next rung, and those left after the last rung are trained
        to ``m_star`` and ranked as without rungs.  Empty (the default): every candidate is trained to ``m_star``.
        Rung fits are recorded in the table with ``rung`` (their centre count) and are never the result.
        Widening candidates are trained to ``m_star`` directly (comparing them at a rung changed the choice on
        one acceptance system).
    early_stop
        Stop a candidate's fit where it is clearly losing (:class:`EarlyStop` by ``'E_val'``, margins
        :data:`E_VAL_STOP_MARGINS`): at a quarter, half and three quarters of ``m_star`` where its validation
        residual exceeds 2000, 200 and 40 times the score to beat, the smallest ``E_val(m_star)`` so far (of this
        grid, and ``bound``).  The residual is the greedy's own (no extra cost); every candidate trained to ``m_star``
        records its ``E_val_quarter``, ``E_val_half`` and ``E_val_three_quarters`` there, with or without the early
        stop.  A stopped candidate is recorded with ``abandoned`` (its centres) and ``E_val = inf``, never the result.
        From a quarter (half, three quarters) of ``m_star`` to all of it the validation residuals of the kernel
        search's first-stage candidates on the six systems of ``sympredict_paper/studies/search_cost.py`` fell at most
        613 (62, 12) times, so such a candidate would not have beaten the score to beat.  Not with ``rungs`` or
        ``prefer_complete``.
    bound
        With ``early_stop``: a score to beat from outside this grid (the smallest ``E_val(m_star)`` of the grids
        searched before it on the same training and validation samples, as the kernel search's first stage passes
        across families and updates); ``inf`` (default): only this grid's own candidates.  Where it stops every
        candidate, the ``ValueError`` of "no candidate" carries the table (``table`` attribute).

    Returns
    -------
    SelectionResult

    Notes
    -----
    Cost: one greedy to ``m_star`` per candidate, ``O(m_star^2 (N + N_val))`` each; with ``rungs``, for ``c``
    candidates about ``c (r_1 / m_star)^2 + c/3 (r_2 / m_star)^2 + ... + max(2, c / 3^k)`` such greedies (for 15
    candidates and rungs ``m_star / 4, m_star / 2``: 4.2 instead of 15).
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
        raise ValueError(
            "grid_search of sympredict.estimators.search needs the estimator whose settings the "
            "candidates share (sympredict.estimators.selection.select_kernels defaults to one)"
        )
    if not float(bound) >= 0:
        raise ValueError(f"grid_search: bound must be a non-negative float or inf, got {bound!r}")
    base = estimator
    dt_fixed = np.ptp(data.dt) == 0
    table = []
    use = early_stop and not rungs and not prefer_complete
    early = EarlyStop(criterion="E_val", margins=E_VAL_STOP_MARGINS) if use else None
    unresolved = []  # per fitted candidate: is its validation residual at m_star still above half its start?

    def score(tup, widened=False, rung=None) -> SelectionResult:
        state, mu_k, dt_k = tup
        size = m_star if rung is None else rung
        inside = base.state_kernel.with_radial(state) if isinstance(base.state_kernel, KernelTransform) else state
        model = clone(base).set_params(
            state_kernel=inside, mu_kernel=mu_k, dt_kernel=dt_k, max_centers=size, trainer__tol=0.0
        )
        label = " x ".join(repr(k) for k in tup if k is not None)
        row = {
            "state": _spec(state),
            "mu": _spec(mu_k),
            "dt": _spec(dt_k),
            "kernels": label,
            "widened": widened,
            **({} if rung is None else {"rung": rung}),
        }
        t0 = time.perf_counter()
        token = None
        if early is not None and rung is None:  # to beat: the smallest E_val(m_star) so far, here or before the grid
            finite = [r["E_val"] for r in table if "rung" not in r and np.isfinite(r["E_val"])]
            token = CANDIDATE_STOP.set(early.start(min(finite + [float(bound)])))
        try:
            fit_candidate(model, data, validation, uses_mu=mu_k is not None)
        except (ValueError, ArithmeticError) as exc:  # LinAlgError is a ValueError
            # a candidate that cannot be trained (coefficients overflow, memory, ...) is scored and skipped
            row.update(
                E_val=np.inf,
                E_train=np.inf,
                n_centers=0,
                complete=False,
                error=str(exc),
                fit_s=time.perf_counter() - t0,
            )
            table.append(row)
            logger.warning(f"{label}: fit failed, candidate skipped ({exc})")
            return SelectionResult(state, mu_k, dt_k, np.inf, False)
        finally:
            if token is not None:
                CANDIDATE_STOP.reset(token)
        val = model.history_.val_max_residual
        if token is not None and early.abandoned is not None:  # clearly losing: never the result
            row.update(
                E_val=np.inf,
                E_train=float(model.history_.train_max_residual[-1]),
                n_centers=model.n_centers_,
                complete=False,
                abandoned=early.abandoned,
                abandoned_E_val=float(val[-1]),
                fit_s=time.perf_counter() - t0,
            )
            table.append(row)
            unresolved.append(float(val[-1]) > 0.5 * float(val[0]))
            logger.info(f"{label}: E_val({model.n_centers_}) = {float(val[-1]):.3e}, clearly losing: stopped")
            return SelectionResult(state, mu_k, dt_k, np.inf, False)
        value = float(val[-1])
        complete = model.n_centers_ >= size or model.history_.stop_reason == "tol"
        if np.isfinite(value) and rung is None:
            unresolved.append(value > 0.5 * float(val[0]))
        half = size // 2  # the early stop's checkpoints: what their margins are measured on
        row.update(
            E_val=value,
            **({"E_val_quarter": float(val[size // 4])} if rung is None and len(val) > size // 4 else {}),
            **({"E_val_half": float(val[half])} if rung is None and len(val) > half else {}),
            **(
                {"E_val_three_quarters": float(val[3 * size // 4])} if rung is None and len(val) > 3 * size // 4 else {}
            ),
            E_train=float(model.history_.train_max_residual[-1]),
            n_centers=model.n_centers_,
            complete=complete,
            fit_s=time.perf_counter() - t0,
        )
        table.append(row)
        logger.info(
            f"{label}: E_val({model.n_centers_}) = {value:.3e}"
            + ("" if rung is None else " (rung)")
            + ("" if complete else f" (stopped early: {model.history_.stop_reason})")
        )
        return SelectionResult(state, mu_k, dt_k, value, complete)

    def better(a, b) -> bool:
        return np.isfinite(a.score) and (b is None or a.rank(prefer_complete) < b.rank(prefer_complete))

    tuples = list(itertools.product(state_kernels, mu_kernels, dt_kernels))
    if any(tup[2] is None for tup in tuples) and not dt_fixed:
        raise ValueError("dt_kernels must not contain None when the data have several macro steps")
    for rung in sorted({int(r) for r in rungs if 0 < int(r) < m_star}):
        ranked = [score(tup, rung=rung) for tup in tuples]
        tuples = halving_survivors(tuples, [r.rank(prefer_complete) for r in ranked])
    best = None
    for tup in tuples:
        candidate = score(tup)
        if better(candidate, best):
            best = candidate
    if best is None:
        if early is not None and np.isfinite(bound) and any("abandoned" in r for r in table):
            exc = ValueError(
                f"every candidate is clearly losing against E_val = {float(bound):.3e} of the grids before this one "
                "(or failed): no finalist from this grid"
            )
        else:
            exc = ValueError(
                "no candidate produced a finite validation residual: every fit failed or broke down "
                "(see the table of the log); try other kernel families or shapes"
            )
        exc.table = table
        raise exc
    # a winner on the edge of its shape grid: extend the grid beyond that edge, one step at a time
    grids = [
        sorted({k.eps for k in opts if k is not None and type(k) is type(chosen)}) if chosen is not None else []
        for opts, chosen in ((state_kernels, best.state), (mu_kernels, best.mu), (dt_kernels, best.dt))
    ]
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
            logger.info(
                f"the chosen {('state', 'mu', 'dt')[i]} kernel {chosen!r} lies on the edge of its shape grid: "
                f"trying {tup[i]!r}"
            )
            candidate = score(tuple(tup), widened=True)
            if better(candidate, best):
                best, moved = candidate, True
        if not moved:
            break
    best.table = table
    for name, chosen, grid in zip(("state", "mu", "dt"), (best.state, best.mu, best.dt), grids):
        if chosen is not None and len(grid) > 1 and chosen.eps in (grid[0], grid[-1]):
            logger.warning(
                f"the chosen {name} kernel {chosen!r} lies on the edge of its shape grid"
                + (f" after widening it {widen} time(s)" if widen else "")
                + ": widen the grid"
            )
    if unresolved and all(unresolved):
        logger.warning(
            f"m_star={m_star} is below what every candidate needs: no candidate has halved its validation "
            "residual at m_star, so the ranking says little about the final size; raise m_star"
        )
    return best


#: Successive halving keeps at least this many candidates per rung.
HALVING_KEEP = 2


def halving_survivors(candidates: Sequence, keys: Sequence, keep: float = 1 / 3) -> list:
    """The candidates that go on from a rung of successive halving: the best ``max(HALVING_KEEP, ceil(keep c))``
    of the ``c`` candidates by ``keys`` (smaller is better; ties by the candidates' order, so the rule is
    deterministic), in their given order.  Candidates whose key is not finite never go on unless fewer than
    :data:`HALVING_KEEP` are finite."""
    n = len(candidates)
    k = min(n, max(HALVING_KEEP, int(np.ceil(keep * n))))
    order = sorted(range(n), key=lambda i: (keys[i], i))
    return [candidates[i] for i in sorted(order[:k])]


# ------------------------------------------------------------------ coordinate refinement
def coordinate_search(
    start: tuple,
    key: Callable,
    active: Sequence[int],
    move: Callable,
    factors: Sequence[float] = (0.5, 2.0),
    sweeps: int = 2,
    from_best: bool = True,
    on_sweep: Optional[Callable] = None,
    shrink: Optional[float] = None,
) -> tuple:
    """Coordinate search: each active coordinate of the best candidate moved by each factor, one at a time.

    Parameters
    ----------
    start : tuple
        The first candidate (hashable coordinates; ``None`` coordinates are never moved).
    key : callable
        ``key(candidate)``: its rank, smaller is better.  Called on every candidate tried, after ``key(start)``;
        cache it where a candidate may recur (equal tuples are equal candidates).
    active : sequence of int
        The coordinates searched, in this order.
    move : callable
        ``move(value, index, factor)``: coordinate ``index`` of value ``value`` moved by ``factor`` (a shape
        ``k.set_params(eps=k.eps * factor)``, a float ``value * factor``).
    factors : sequence of float, default=(0.5, 2.0)
        The moves tried per coordinate, in this order.
    sweeps : int, default=2
        At most this many sweeps over the active coordinates; the search stops after a sweep without improvement.
    from_best : bool, default=True
        Each move from the best candidate so far (``True``), or every factor of a coordinate from the candidate
        that was best when that coordinate's turn began (``False``: both neighbours of it are tried).
    on_sweep : callable, optional
        ``on_sweep(sweep, best)`` after each sweep (e.g. a log line).
    shrink : float, optional
        In ``(0, 1)``: a sweep without improvement does not end the search; the following sweeps move by
        ``exp(shrink**k log f)`` for each factor ``f`` after ``k`` such sweeps (``0.5``: ``2 -> sqrt 2 -> 2^(1/4)``),
        and all ``sweeps`` sweeps run.  ``None`` (default): the search stops after a sweep without improvement.

    Returns
    -------
    tuple
        The best candidate.

    Notes
    -----
    Cost: at most ``1 + len(factors) len(active) sweeps`` calls of ``key``.
    """
    if shrink is not None and not 0 < shrink < 1:
        raise ValueError(f"shrink must lie in (0, 1) or be None, got {shrink!r}")
    logs, scale, moves = np.log(factors), 1.0, tuple(factors)
    best = start
    key(best)
    for sweep in range(sweeps):
        improved = False
        for i in active:
            anchor = best
            if anchor[i] is None:
                continue
            for f in moves:
                origin = best if from_best else anchor
                cand = origin[:i] + (move(origin[i], i, f),) + origin[i + 1 :]
                if key(cand) < key(best):
                    best, improved = cand, True
        if on_sweep is not None:
            on_sweep(sweep, best)
        if not improved:
            if shrink is None:
                break
            scale *= shrink
            moves = tuple(float(m) for m in np.exp(logs * scale))
    return best


def refine_shapes(
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
    or after ``max_sweeps`` sweeps (:func:`coordinate_search`, both neighbours of each shape tried).

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
            scored[tup] = grid_search(
                data,
                validation,
                [tup[0]],
                [tup[1]],
                [tup[2]],
                m_star=m_star,
                prefer_complete=prefer_complete,
                estimator=estimator,
                widen=0,
            )
        return scored[tup]

    def on_sweep(sweep, tup):
        best = scored[tup]
        logger.info(
            f"shape refinement sweep {sweep + 1}: {best.state!r}, {best.mu!r}, {best.dt!r}: "
            f"E_val({m_star}) = {best.score:.3e}"
        )

    chosen = coordinate_search(
        (start.state, start.mu, start.dt),
        lambda t: score(t).rank(prefer_complete),
        [i for i in range(3) if refine[i]],
        lambda k, i, f: k.set_params(eps=k.eps * f),
        factors=(1 / factor, factor),
        sweeps=max_sweeps,
        from_best=False,
        on_sweep=on_sweep,
    )
    best = scored[chosen]
    table = [row for r in scored.values() for row in r.table]
    return SelectionResult(best.state, best.mu, best.dt, best.score, best.complete, table)


# ------------------------------------------------------------------ held-out scores of final-size candidates
def relative_rollout_error(predicted: np.ndarray, states: np.ndarray) -> float:
    """The rollout score: the mean over trajectories of ``max_k |x_k - X_k| / rms_k |X_k|``, the worst relative
    error along each rollout; ``inf`` where it is not finite.

    Parameters
    ----------
    predicted, states : ndarray of shape (P, K + 1, 2n)
        Rolled-out and true states of ``P`` trajectories.

    Returns
    -------
    float
    """
    size = np.sqrt(np.mean(np.sum(states * states, axis=2), axis=1))
    with np.errstate(all="ignore"):
        err = np.linalg.norm(predicted - states, axis=2).max(axis=1) / np.where(size > 0, size, 1.0)
        value = float(np.mean(err))
    return value if np.isfinite(value) else float("inf")


def column_std(x: np.ndarray) -> np.ndarray:
    """Column standard deviations (n,) of ``x`` (N, n) without overflow or underflow (each column scaled by its
    largest magnitude first); ``O(N n)``."""
    big = np.abs(x).max(axis=0)
    big = np.where(big > 0, big, 1.0)
    return (x / big).std(axis=0) * big


def pair_factors(data: FlowMapData) -> np.ndarray:
    """``a_i = sqrt(std(p_i) / std(q_i))`` over the states ``x0`` and ``x1``: the symplectic scaling
    ``(a_i q_i, p_i / a_i)`` that gives each conjugate pair equal spreads (``1`` where a spread is zero).

    Returns
    -------
    ndarray of shape (n,)
    """
    x = np.concatenate([data.x0, data.x1])
    n = x.shape[1] // 2
    # a spread far below the other is round-off: the ratio of two stds each scaled to their maximum (no underflow)
    sq, sp = column_std(x[:, :n]), column_std(x[:, n:])
    a = np.ones(n)
    ok = (sq > 0) & (sp > 0)
    a[ok] = np.sqrt(sp[ok] / sq[ok])
    return np.clip(a, 1e-6, 1e6)


def state_weights(data: FlowMapData) -> np.ndarray:
    """The weights ``(a_1, ..., a_n, 1 / a_1, ..., 1 / a_n)`` (:func:`pair_factors`) of the states' coordinates under
    which the search measures errors: the data's symplectic normalisation ``(a_i q_i, p_i / a_i)``, so that a score
    does not depend on the units of the states (a position error in metres and a velocity error in m/s count alike
    once each is scaled to its spread; an overall factor cancels in a relative error).

    Returns
    -------
    ndarray of shape (2n,)
    """
    a = pair_factors(data)
    return np.concatenate([a, 1.0 / a])


class HeldOutScore(float):
    """A mean held-out error (a ``float``, compared and printed as one) that carries its ``standard_error``: the
    standard deviation of the per-sample errors over ``sqrt`` of their number, the score's own noise from the finite
    held-out sample.  Arithmetic on it gives plain floats; a score without one (a plain ``float``) has none
    (:func:`standard_error` gives 0)."""

    standard_error: float

    def __new__(cls, value: float, standard_error: float = 0.0):
        out = super().__new__(cls, value)
        out.standard_error = float(standard_error) if np.isfinite(standard_error) else 0.0
        return out

    def __reduce__(self):
        return (HeldOutScore, (float(self), self.standard_error))


def standard_error(score) -> float:
    """The ``standard_error`` of a :class:`HeldOutScore`; ``0.0`` for any other score."""
    return float(getattr(score, "standard_error", 0.0))


def relative_step_errors(predicted: np.ndarray, x0: np.ndarray, x1: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Per sample, ``|w (predicted - x1)| / |w (x1 - x0)|``: the relative one-step errors the search scores.

    ``predicted``, ``x0``, ``x1`` have shape (S, 2n) and ``weights`` (2n,) (:func:`state_weights`: the normalised
    coordinates).  Samples that do not move (``x1 == x0``) are left out; where none moves, the absolute errors
    ``|w (predicted - x1)|`` are returned.  Shape (S',).
    """
    inc = np.linalg.norm((x1 - x0) * weights, axis=1)
    rows = inc > 0
    miss = np.linalg.norm((predicted - x1) * weights, axis=1)
    return miss[rows] / inc[rows] if rows.any() else miss


#: Where a search candidate's fit is checked by its held-out one-step error, ``(fraction, factor)``: at ``fraction``
#: of its centres it stops if its score exceeds ``factor`` times the score it must beat (:class:`EarlyStop`).  The
#: factor bounds how far the score may still fall from there to the full size, with room to spare: on the full-size
#: search candidates of the six systems of ``sympredict_paper/studies/search_cost.py`` (``--decay``,
#: ``docs/data/search_decay.json``) the one-step error fell at most 107 times from half the centres to all of them,
#: and up to 1,700 times from a quarter (so no earlier checkpoint: a sharp kernel far behind at a quarter of its
#: centres can still win).
EARLY_STOP_MARGINS = ((0.5, 300.0),)
#: Where a search candidate's one-step error at ``fraction`` of its centres is compared like with like, with the score
#: at the same checkpoint of a candidate to beat that reached its full size, ``(fraction, factor)``: it stops if its
#: score exceeds ``factor`` times that one (:class:`EarlyStop`'s ``reference``).  The factor bounds rank reversals
#: between half and full size, with room to spare: on the second-stage candidates of the six systems of
#: ``sympredict_paper/studies/search_cost.py`` (``sympredict_paper/studies/search_reversals.py``,
#: ``docs/data/search_reversals.json`` and ``search_reversals_300.json``), a candidate that ended better than another
#: (both at full size) scored at most 3.4 times that one's score at half the centres, and one that went on to beat the
#: candidate the rule compared it with at most 0.83 times; the factor is at least twice the former.
REVERSAL_MARGINS = ((0.5, 8.0),)
#: As :data:`EARLY_STOP_MARGINS`, for the first stage's validation residual ``E_val`` (:func:`grid_search`'s
#: ``early_stop``): on the first-stage candidates of those systems it fell at most 613 times from a quarter of
#: ``m_star`` to all of it, 62 times from half and 12 times from three quarters (``search_cost.py --decay``,
#: ``docs/data/search_decay_stage1.json``); each factor is more than three times that fall.
E_VAL_STOP_MARGINS = ((0.25, 2000.0), (0.5, 200.0), (0.75, 40.0))


@dataclass
class EarlyStop:
    """Stop a search candidate's greedy fit at a checkpoint where it is clearly losing (successive halving over the
    centres of one fit: no refit, the fit that goes on is the same run).

    At each checkpoint, ``c = fraction m`` centres of the ``m`` it is fitted to (:data:`EARLY_STOP_MARGINS`), the
    fit's prefix is scored as :func:`final_size_score` scores the full fit (the mean relative one-step error on the
    held-out samples, in their normalised coordinates); the fit gives up where that error exceeds the margin's
    ``factor`` times ``bound``, the score the candidate must beat (the best candidate's so far), or, where a
    ``reference`` is given (the checkpoint scores of the best candidate so far that reached its full size),
    :data:`REVERSAL_MARGINS`' factor times the reference's score at the same checkpoint (like with like).  The
    greedy's prefixes are its own smaller interpolants, whose held-out errors fall as centres are added; the first
    factors bound how far they fell from a checkpoint to the full size on the search candidates of the acceptance
    systems, the second how far two candidates' ranks reversed between the checkpoint and the full size, each with
    room to spare: a candidate given up would have lost.  A prefix whose Newton solve fails (score
    ``inf``) is not given up (a flat kernel's small prefix can fail where the full fit does not).

    Attributes
    ----------
    bound : float
        The score to beat; ``inf``: nothing to beat yet, the fit runs to its size.
    margins : tuple of (float, float)
        ``(fraction, factor)`` per checkpoint.
    abandoned : int or None
        Centres at which the last fit gave up (set by :meth:`give_up`; ``None``: it did not).
    scores : dict
        ``{centres: score}`` of the checkpoints of the last fit.
    """

    bound: float = np.inf
    margins: tuple = EARLY_STOP_MARGINS
    abandoned: Optional[int] = None
    scores: dict = field(default_factory=dict)
    #: ``(samples, weights)``: the held-out samples (a :class:`~sympredict.data.FlowMapData`) and the weights of
    #: their coordinates (:func:`state_weights`) that score the checkpoints (set by :func:`final_size_score`).
    samples: Optional[tuple] = field(default=None, repr=False)
    #: What a checkpoint compares: ``'one-step'`` (the held-out one-step error of the prefix, by Newton steps on
    #: :attr:`samples`) or ``'E_val'`` (the greedy's own validation residual, at no cost: the first stage's score).
    criterion: str = "one-step"
    #: ``{centres: score}``: the checkpoint scores of a candidate to beat that reached its full size (the
    #: :attr:`scores` of its own fit), compared like with like at each checkpoint by :attr:`reference_margins`;
    #: ``None``: no such comparison.
    reference: Optional[dict] = None
    #: ``(fraction, factor)`` per checkpoint of the comparison with :attr:`reference` (criterion ``'one-step'`` only).
    reference_margins: tuple = REVERSAL_MARGINS

    #: Checkpoints below this many centres are skipped (a prefix that small says little).
    smallest = 20

    def _all_margins(self) -> tuple:
        return tuple(self.margins) + (tuple(self.reference_margins) if self.criterion == "one-step" else ())

    def checkpoints(self, m: int) -> list:
        """The centre counts (increasing) at which a fit to ``m`` centres is scored."""
        return sorted({int(f * m) for f, _ in self._all_margins() if self.smallest <= int(f * m) < m})

    def factor(self, c: int, m: int, margins: Optional[tuple] = None) -> float:
        """The margin at ``c`` of ``m`` centres (that of the largest fraction at most ``c / m``) of ``margins``
        (default :attr:`margins`)."""
        out = np.inf
        for f, k in sorted(self.margins if margins is None else margins):
            if int(f * m) <= c:
                out = k
        return float(out)

    def give_up(self, c: int, m: int, value: float) -> bool:
        """Whether a fit to ``m`` centres whose prefix of ``c`` centres scores ``value`` stops (records it): where
        ``value`` exceeds :attr:`margins`' factor times :attr:`bound` (the full-size score to beat), or
        :attr:`reference_margins`' factor times :attr:`reference`'s score at the same ``c`` (like with like)."""
        self.scores[int(c)] = float(value)
        stop = bool(np.isfinite(value) and np.isfinite(self.bound) and value > self.factor(c, m) * self.bound)
        if self.reference is not None and self.criterion == "one-step" and np.isfinite(value):
            target = self.reference.get(int(c), np.inf)
            stop = stop or bool(np.isfinite(target) and value > self.factor(c, m, self.reference_margins) * target)
        if stop:
            self.abandoned = int(c)
        return stop

    def start(self, bound: float, reference: Optional[dict] = None) -> "EarlyStop":
        """Reset for the next candidate, which must beat ``bound`` (and, where given, the checkpoint scores
        ``reference`` of the candidate that scored it); returns ``self``."""
        self.bound, self.reference, self.abandoned, self.scores = float(bound), reference, None, {}
        return self

    @staticmethod
    def error(predicted: np.ndarray, x0: np.ndarray, x1: np.ndarray, weights: np.ndarray) -> float:
        """The mean of :func:`relative_step_errors`, as :func:`final_size_score` scores; ``inf`` where it is not
        finite."""
        with np.errstate(all="ignore"):
            value = float(np.mean(relative_step_errors(predicted, x0, x1, weights)))
        return value if np.isfinite(value) else float("inf")


#: The :class:`EarlyStop` that :func:`final_size_score` applies to its candidates' fits (set by the kernel search
#: around the candidates it compares with the best so far), or ``None``: every fit runs to its size.
EARLY_STOP = contextvars.ContextVar("sympredict_early_stop", default=None)
#: During :func:`final_size_score`'s fit of one candidate only: its :class:`EarlyStop`, whose ``samples`` (the
#: held-out samples and their weights) score the fit's checkpoints; read by the estimator's fit.
CANDIDATE_STOP = contextvars.ContextVar("sympredict_candidate_stop", default=None)


def final_size_score(
    estimator,
    params: dict,
    m_final: int,
    train: FlowMapData,
    val: FlowMapData,
    largest: int = 500,
    rollouts: Optional[tuple] = None,
) -> tuple:
    """``(score, centres, seconds, error, rollout, rollout_seconds)`` of one candidate: :func:`one_step_score`'s
    four (``score`` a :class:`HeldOutScore`, which carries its standard error over the held-out samples), ``rollout``, the :func:`relative_rollout_error` of the fitted candidate's rollouts of held-out trajectories
    from their first states (``None`` without ``rollouts``; ``inf`` where the fit or a rollout fails), and the
    rollouts' share of ``seconds``.  Both errors are taken in ``val``'s normalised coordinates (:func:`state_weights`).

    ``rollouts`` is ``(states, mu, dt)``: ``states`` of shape ``(P, K + 1, 2n)``, ``mu`` of shape ``(P, p)`` or
    ``None``, ``dt`` a float.  Cost: one greedy fit to ``m_final`` centres, ``largest`` implicit steps and ``P K``
    more (``K`` steps of a batch of ``P``), on the candidate's own solver (compiled where it is).
    """
    t0 = time.perf_counter()
    model = without_target(clone(estimator).set_params(**params, max_centers=m_final))
    sub = val.subset(np.arange(min(len(val), largest)))
    w = state_weights(val)  # errors in the normalised coordinates: the score does not depend on the units
    uses_mu = params["mu_kernel"] is not None
    early = EARLY_STOP.get()
    if early is not None:
        early.start(early.bound, early.reference)
        early.samples = (sub, w)
    token = None if early is None else CANDIDATE_STOP.set(early)
    try:
        with warnings.catch_warnings():  # a candidate may underfit or extrapolate: its score says so
            warnings.simplefilter("ignore")
            try:
                fit_candidate(model, train, uses_mu=uses_mu, quiet=False)
            finally:
                if token is not None:
                    CANDIDATE_STOP.reset(token)
            if early is not None and early.abandoned is not None:  # clearly losing: no score at full size
                return (
                    np.inf,
                    model.n_centers_,
                    time.perf_counter() - t0,
                    None,
                    None if rollouts is None else np.inf,
                    0.0,
                )
            pred = model.step(
                sub.x0, mu=sub.mu if uses_mu else None, dt=sub.dt if params["dt_kernel"] is not None else None
            )
        each = relative_step_errors(pred, sub.x0, sub.x1, w)
        value = float(np.mean(each))
        spread = float(np.std(each, ddof=1) / np.sqrt(each.size)) if each.size > 1 else 0.0
    except (ValueError, ArithmeticError, NewtonConvergenceError, NonFinitePredictionError) as exc:
        failed = f"{type(exc).__name__}: {exc}"
        return np.inf, 0, time.perf_counter() - t0, failed, None if rollouts is None else np.inf, 0.0
    rollout, t1 = None, time.perf_counter()
    if rollouts is not None:
        states, mu, dt = rollouts
        try:
            with warnings.catch_warnings(), np.errstate(all="ignore"):
                warnings.simplefilter("ignore")  # a candidate may leave the box: its score says so
                predicted = model.rollout(
                    states[:, 0],
                    states.shape[1] - 1,
                    mu=mu if uses_mu else None,
                    dt=dt if params["dt_kernel"] is not None else None,
                )
            rollout = relative_rollout_error(predicted * w, states * w)
        except (ValueError, ArithmeticError, NewtonConvergenceError, NonFinitePredictionError, np.linalg.LinAlgError):
            rollout = np.inf
    t2 = time.perf_counter()
    score = HeldOutScore(value, spread) if np.isfinite(value) else np.inf
    return score, model.n_centers_, t2 - t0, None, rollout, t2 - t1


def one_step_score(
    estimator, params: dict, m_final: int, train: FlowMapData, val: FlowMapData, largest: int = 500
) -> tuple:
    """``(score, centres, seconds, error)`` of one candidate: ``clone(estimator)`` with ``params`` fitted
    to ``m_final`` centres on ``train`` (its trainer's ``target_error`` dropped: candidates compete at their full
    size), scored by the mean relative one-step error ``|Phi(x0) - x1| / |x1 - x0|`` on (up to ``largest``)
    ``val`` samples, the norms taken in ``val``'s normalised coordinates (:func:`state_weights`: no dependence on the
    units); ``inf`` for a failed fit or Newton solve, or a non-finite prediction.

    ``params`` holds ``state_kernel``, ``mu_kernel``, ``dt_kernel``, ``update`` and any other settings.
    Cost: one greedy fit to ``m_final`` centres and ``largest`` implicit steps.
    """
    return final_size_score(estimator, params, m_final, train, val, largest)[:4]


def without_target(model):
    """``model`` with its trainer's ``target_error`` dropped (search candidates compete at their full size)."""
    if getattr(model.trainer, "target_error", None) is not None:
        model.set_params(trainer__target_error=None)
    return model


@dataclass
class ScoredSelectionResult:
    """Outcome of :func:`score_search` (:func:`~sympredict.estimators.selection.select_by_score`).

    Attributes
    ----------
    params : dict
        The chosen candidate's settings (as given in ``candidates``).
    n_centers : int
        The chosen budget: the number of centres of :attr:`model`.
    score : float
        Its score.
    model : estimator
        The chosen candidate fitted (truncated to ``n_centers`` where it was fitted further).
    table : list of dict
        One row per (candidate, budget): ``candidate`` (index), ``params`` (readable),
        ``budget``, ``n_centers``, ``score``, ``E_val`` (the greedy's validation
        residual at ``n_centers``), ``stop_reason`` of the fit, ``fit_s``, ``score_s``;
        a failed fit gives one row with ``error`` and ``score = inf``.
    """

    params: dict
    n_centers: int
    score: float
    model: Optional[object] = field(default=None, repr=False)
    table: list = field(default_factory=list)


def score_search(
    data: FlowMapData,
    validation: Optional[FlowMapData],
    candidates: Sequence[dict],
    budgets: Sequence[int],
    score: Callable,
    estimator,
) -> ScoredSelectionResult:
    """Settings and number of centres chosen by a caller's validation score of the fitted models.

    Every candidate ``clone(estimator).set_params(**candidate, max_centers=max(budgets))`` is fitted once; smaller
    budgets are its greedy prefixes (``truncated``), so the budget is chosen at the cost of the scores alone.
    ``score(fitted_model) -> float``, smaller is better; non-finite scores never win; ties go to the earlier
    candidate and the smaller budget.  A failed fit (``ValueError``, ``ArithmeticError``) is recorded and skipped.
    The parameters of :func:`~sympredict.estimators.selection.select_by_score` (which documents them).

    Cost: one greedy to ``max(budgets)`` per candidate, plus one ``score`` per (candidate, budget).  Only the best
    model so far is kept in memory.
    """
    budgets = sorted({int(b) for b in budgets})
    if not candidates or not budgets or budgets[0] < 1:
        raise ValueError(
            f"need at least one candidate and positive budgets, got {len(candidates)} candidates, budgets {budgets}"
        )
    table, best = [], None
    for i, cand in enumerate(candidates):
        label = ", ".join(f"{k}={v!r}" for k, v in cand.items())
        t0 = time.perf_counter()
        try:  # set_params refuses a malformed setting at once (its table): the candidate failed, as a failed fit
            model = clone(estimator).set_params(**cand, max_centers=budgets[-1])
            fit_candidate(model, data, validation, uses_mu=model.mu_kernel is not None)
        except (ValueError, ArithmeticError) as exc:
            table.append(
                {
                    "candidate": i,
                    "params": label,
                    "budget": None,
                    "n_centers": 0,
                    "score": np.inf,
                    "error": str(exc),
                    "fit_s": time.perf_counter() - t0,
                }
            )
            logger.warning(f"{label}: fit failed, candidate skipped ({exc})")
            continue
        fit_s = time.perf_counter() - t0
        val = model.history_.val_max_residual
        for b in budgets:
            m = min(b, model.n_centers_)
            if table and table[-1]["candidate"] == i and table[-1]["n_centers"] == m:
                continue  # stopped before this budget: already scored at its size
            sized = model if m == model.n_centers_ else model.truncated(m)
            t1 = time.perf_counter()
            value = float(score(sized))
            row = {
                "candidate": i,
                "params": label,
                "budget": b,
                "n_centers": m,
                "score": value,
                "E_val": None if val is None else float(val[m]),
                "stop_reason": model.history_.stop_reason,
                "fit_s": fit_s,
                "score_s": time.perf_counter() - t1,
            }
            table.append(row)
            logger.info(f"{label}, {m} centres: score {value:.4e}")
            if np.isfinite(value) and (best is None or value < best[2]):
                best = (dict(cand), m, value, sized)
    if best is None:
        raise ValueError("no candidate produced a finite score: every fit failed or diverged (see the log)")
    return ScoredSelectionResult(best[0], best[1], best[2], best[3], table)


def ridge_search(regularizations, evaluate: Callable, keep: bool = False, name: str = "regularizations") -> tuple:
    """The ridge term of the greedy chosen by a held-out score: ``0`` (the exact fit) and every given term compete.

    Parameters
    ----------
    regularizations : sequence of float
        Candidate terms ``lambda >= 0``; ``0`` is always added.  Tried in increasing order.
    evaluate : callable
        ``evaluate(lam) -> (score, fitted, row)``: the candidate with ridge term ``lam`` fitted (typically
        ``clone(estimator).set_params(trainer__regularization=lam)``) and scored on held-out data, smaller is
        better, with its ``row`` of the record (a ``dict``; ``regularization`` and ``score`` are added).

    Returns
    -------
    best : tuple or None
        ``(lam, score, fitted)`` of the best finite score (ties: the smaller term), ``None`` when no score is finite.
    table : list of dict
        One row per term.
    fitted : dict
        ``lam -> fitted`` of every term (``keep=True``; else empty).

    Notes
    -----
    Cost: one ``evaluate`` per term.  Since the exact fit competes, the chosen term is never worse than it on the
    score.
    """
    values = sorted({0.0, *(float(v) for v in np.atleast_1d(regularizations))})
    if not all(np.isfinite(v) and v >= 0 for v in values):
        raise ValueError(f"{name} must be finite non-negative floats, got {regularizations!r}")
    table, best, fitted = [], None, {}
    for lam in values:
        value, model, row = evaluate(lam)
        table.append({"regularization": lam, "score": value, **row})
        if keep:
            fitted[lam] = model
        if np.isfinite(value) and (best is None or value < best[1]):
            best = (lam, value, model)
    return best, table, fitted
