"""Kernel family and shape parameters chosen on validation data (paper section 4).

Every candidate tuple ``(k_xi, k_mu, k_dT)`` is trained by f-greedy to ``m_star``
centres; the tuple with the smallest validation residual ``E_val(m_star)``
wins.  Shape parameters are searched on logarithmic grids (:func:`log_grid`)
because useful values span decades (reduced wave coordinates are of size ~20,
so state shapes ~5e-3 fit there, pendulum states are of size ~5).
Where the ranking at ``m_star`` does not carry over to the final size,
:func:`select_by_score` ranks the final models (every budget a greedy prefix)
by a score the caller computes on validation data, e.g. rollout errors.

These are the public entry points, with ``SymplecticKernelPredictor()`` as the default estimator; the search
itself (grids, coordinate refinement, held-out scores, the record) is :mod:`sympredict.estimators.search`.
"""

from __future__ import annotations

import inspect
import time
import warnings
from dataclasses import dataclass, field
from typing import Callable, Optional, Sequence

import numpy as np
from pymor.core.logger import getLogger

from sympredict.base import clone
from sympredict.data import FlowMapData
from sympredict.estimators import search
from sympredict.estimators.predictor import SymplecticKernelPredictor, update_variables
from sympredict.estimators.search import (
    WIDEN_LIMITS,
    ScoredSelectionResult,
    SelectionResult,
    fit_candidate,
    kernel_grid,
    log_grid,
)
from sympredict.exceptions import ExtrapolationWarning

__all__ = [
    "log_grid",
    "kernel_grid",
    "SelectionResult",
    "select_kernels",
    "refine_kernel_shapes",
    "WIDEN_LIMITS",
    "RegularizationResult",
    "select_regularization",
    "ScoredSelectionResult",
    "select_by_score",
]

logger = getLogger("sympredict.estimators.selection")


def _with_default_estimator(engine, name: str):
    """The public entry point ``name`` of the search's ``engine``: the same function (its signature and docstring),
    with ``SymplecticKernelPredictor()`` as the default ``estimator`` (the search itself has none: it is imported by
    the estimator's module)."""
    signature = inspect.signature(engine)

    def entry(*args, **kwargs):
        bound = signature.bind(*args, **kwargs)
        if bound.arguments.get("estimator") is None:
            bound.arguments["estimator"] = SymplecticKernelPredictor()
        return engine(*bound.args, **bound.kwargs)

    entry.__name__ = entry.__qualname__ = name
    entry.__signature__ = signature
    entry.__doc__ = engine.__doc__.replace(
        "Required here (:func:`sympredict.estimators.selection.select_kernels`\n        defaults to "
        "``SymplecticKernelPredictor()``).",
        "Default ``SymplecticKernelPredictor()``.",
    )
    return entry


select_kernels = _with_default_estimator(search.grid_search, "select_kernels")
refine_kernel_shapes = _with_default_estimator(search.refine_shapes, "refine_kernel_shapes")


@dataclass
class RegularizationResult:
    """Outcome of :func:`select_regularization`.

    Attributes
    ----------
    regularization : float
        The chosen ridge term ``lambda`` (``0.0``: the exact fit won).
    score : float
        Its validation score.
    table : list of dict
        Every candidate: ``regularization``, ``score``, ``E_val`` (max residual), ``rms_val``,
        ``n_centers``, ``stop_reason``, ``fit_s``.
    model : SymplecticKernelPredictor
        The fitted model of the chosen ``lambda``.
    models : dict
        ``lambda -> fitted model`` of every candidate (``keep_models=True``; else empty).
    """

    regularization: float
    score: float
    table: list = field(default_factory=list)
    model: Optional[SymplecticKernelPredictor] = field(default=None, repr=False)
    models: dict = field(default_factory=dict, repr=False)


def select_regularization(
    data: FlowMapData,
    validation: FlowMapData,
    lambdas,
    estimator: SymplecticKernelPredictor,
    metric: str = "rms",
    keep_models: bool = False,
) -> RegularizationResult:
    """The ridge term ``lambda`` of the greedy (noisy data) chosen on validation data.

    Every ``lambda`` in ``lambdas``, and always ``0`` (the exact fit), is
    trained as ``clone(estimator).set_params(trainer__regularization=lambda)`` and
    scored on the validation samples by the residual of the learned gradient,
    ``grad s(xi_v) - y_v`` (the validation targets carry the same noise as the
    training targets).  Since the exact fit is a candidate, the chosen
    ``lambda`` is never worse than it on this score.

    Parameters
    ----------
    data, validation
        Training and validation flow-map data (the kernels are the estimator's).
    lambdas : sequence of float
        Candidate ridge terms ``>= 0`` in the units of the Gramian diagonal
        ``G_ii`` (for an HB functional ``-phi''(0)`` times the parameter factors' ``phi(0)``).
    estimator
        The (unfitted) estimator whose other settings every candidate shares.
    metric
        ``'rms'`` (default: root mean square over all validation functionals,
        the noise-robust score) or ``'max'`` (``E_val``, the maximum).
    keep_models
        Return every candidate's fitted model (:attr:`RegularizationResult.models`).

    Returns
    -------
    RegularizationResult

    Notes
    -----
    Cost: one greedy fit per candidate plus ``O(N_val m 2n)`` for the score.
    Ties go to the smaller ``lambda`` (the exact fit first).
    """
    if metric not in ("rms", "max"):
        raise ValueError(f"metric must be 'rms' or 'max', got {metric!r}")
    for name, given in (("data", data), ("validation", validation)):
        if not isinstance(given, FlowMapData):
            raise ValueError(
                f"{name} must be a FlowMapData (sympredict.data.FlowMapData(x0, x1, mu, dt), or "
                f"TrajectoryData(...).pairs()), got {type(given).__name__}"
            )
    if not isinstance(estimator, SymplecticKernelPredictor):
        raise ValueError(
            f"estimator must be a SymplecticKernelPredictor (the ridge term is its greedy's), got "
            f"{type(estimator).__name__}"
        )
    mu = None if data.mu.shape[1] == 0 else data.mu
    vmu = None if validation.mu.shape[1] == 0 else validation.mu
    vxi, vy = update_variables(
        getattr(estimator, "update", None) or "symplectic_euler", validation.x0, validation.x1, validation.dt
    )
    uses_dt = estimator.dt_kernel is not None

    def evaluate(lam):
        model = clone(estimator).set_params(trainer__regularization=lam)
        t0 = time.perf_counter()
        fit_candidate(model, data, uses_mu=mu is not None, dt=data.dt if uses_dt else data.dt[0])
        with warnings.catch_warnings():  # validation xi = (q0, p1) may leave the box of the training states slightly
            warnings.simplefilter("ignore", ExtrapolationWarning)
            grad = model.surrogate_gradient(vxi, mu=vmu, dt=validation.dt if uses_dt else None)
        res = grad - vy
        rms, emax = float(np.sqrt(np.mean(res**2))), float(np.abs(res).max())
        score = rms if metric == "rms" else emax
        logger.info(f"regularization {lam:.3g}: {metric} validation residual {score:.4e} ({model.n_centers_} centres)")
        return (
            score,
            model,
            {
                "E_val": emax,
                "rms_val": rms,
                "n_centers": model.n_centers_,
                "stop_reason": model.history_.stop_reason,
                "fit_s": time.perf_counter() - t0,
            },
        )

    best, table, models = search.ridge_search(lambdas, evaluate, keep=keep_models, name="lambdas")
    if best is None:
        raise ValueError("no regularization produced a finite validation score")
    return RegularizationResult(best[0], best[1], table, best[2], models)


def select_by_score(
    data: FlowMapData,
    validation: Optional[FlowMapData],
    candidates: Sequence[dict],
    budgets: Sequence[int],
    score: Callable[[SymplecticKernelPredictor], float],
    estimator: Optional[SymplecticKernelPredictor] = None,
) -> ScoredSelectionResult:
    """Settings and number of centres chosen by a caller's validation score of the fitted models.

    :func:`select_kernels` ranks candidates by their greedy residual at a small
    ``m_star``; where that ranking does not carry over to the final size (the
    reduced wave at 2n = 20: the kernel best at 300 centres was 4x worse at
    1,500), this ranks the *final* models by what matters, e.g. the rollout
    error on validation parameters.  Every candidate is fitted once to the
    largest budget; smaller budgets are its greedy prefixes
    (:meth:`~sympredict.estimators.predictor.SymplecticKernelPredictor.truncated`, equal to a
    fit with that budget to round-off), so the budget is chosen at the cost of
    the scores alone.

    Parameters
    ----------
    data : FlowMapData
        Training data (parameters, if any, in ``data.mu``).
    validation : FlowMapData or None
        Validation samples for the greedy's ``E_val(m)`` (recorded in the table, not scored).
    candidates : sequence of dict
        Settings ``clone(estimator).set_params(**candidate)``, e.g.
        ``{"state_kernel": IMQ(0.003), "mu_kernel": IMQ(0.3), "trainer__regularization": 0.0}``.
    budgets : sequence of int
        Numbers of centres compared (the largest is the fit's ``max_centers``).
        A fit that stops early (power breakdown, tolerance) is scored once at its size
        for all budgets beyond it.
    score : callable
        ``score(fitted_model) -> float``, smaller is better; must use validation
        data only (never test data).  Non-finite scores never win.
    estimator
        The unfitted estimator whose other settings all candidates share
        (default ``SymplecticKernelPredictor()``).

    Returns
    -------
    ScoredSelectionResult

    Notes
    -----
    Cost: one greedy to ``max(budgets)`` per candidate, plus one ``score`` per
    (candidate, budget).  Only the best model so far is kept in memory.  Ties go
    to the earlier candidate and the smaller budget.
    """
    return search.score_search(
        data, validation, candidates, budgets, score, SymplecticKernelPredictor() if estimator is None else estimator
    )
