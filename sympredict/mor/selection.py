"""The reductor's choice of kernels and ridge term on its validation data, and its default estimator.

:class:`ValidationSelection` chooses, on the reductor's validation samples (in the coordinates the estimator is
trained in), the state and parameter kernels among candidates
(:func:`~sympredict.estimators.selection.select_kernels`: each trained to ``m_star`` centres with the
estimator's other settings; the smallest validation residual wins) and the ridge term
(``trainer__regularization``) by the validation score of the trained ROM step.  Without it a given estimator
is trained as given (a :class:`~sympredict.SymplecticKernelPredictor` with kernels left ``None`` chooses them
with its own ``search`` on held-out training samples).  :class:`DefaultEstimator` is the reductor's default
recipe.
"""

from __future__ import annotations

import contextlib
import logging
from typing import Callable, Optional

import numpy as np

from sympredict._checks import as_positive_int, as_real
from sympredict.base import Setting, clone
from sympredict.estimators.predictor import SymplecticKernelPredictor
from sympredict.estimators.search import ridge_search, without_target
from sympredict.estimators.selection import log_grid, select_kernels
from sympredict.interpolation.greedy import ExactGreedy
from sympredict.kernels import IMQ, RadialKernel
from sympredict.kernels.transforms import KernelTransform

__all__ = ["ValidationSelection", "DefaultEstimator"]

logger = logging.getLogger("sympredict.mor.selection")


def _check_kernels(kernels, name: str, allow_none: bool) -> Optional[list]:
    """A non-empty list of radial kernels (``None`` entries where ``allow_none``: the factor dropped), or ``None``."""
    if kernels is None:
        return None
    if isinstance(kernels, RadialKernel) or isinstance(kernels, str):
        raise ValueError(f"{name} must be a sequence of kernels (e.g. [IMQ(0.01), IMQ(0.1)]), got {kernels!r}")
    kernels = list(kernels)
    bad = [k for k in kernels if not (isinstance(k, RadialKernel) or (allow_none and k is None))]
    if not kernels or bad:
        raise ValueError(
            f"{name} must be a non-empty sequence of radial kernels (IMQ, Matern52, Matern32)"
            + (" or None" if allow_none else "")
            + f", got {kernels!r}"
        )
    return kernels


class DefaultEstimator(Setting):
    """The reductor's default estimator (``estimator=None`` is ``DefaultEstimator()``).

    A :class:`~sympredict.SymplecticKernelPredictor` with ``max_centers`` and ``ExactGreedy(tol=1e-12)`` whose IMQ
    kernels on the scaled states and parameters the reductor chooses on its validation data from small log
    grids (states ``0.01..1``, parameters ``0.3..3``; a :class:`ValidationSelection` with kernels replaces a grid),
    and whose update the existence check sets (type II where it exists at ``dt``, else the midpoint form).

    Parameters
    ----------
    max_centers : int, default=1000
        The budget (with ``target_error``: the cap).
    target_error : float or None, default=None
        Accuracy on demand (the trainer's ``ExactGreedy(target_error=...)``): the median relative one-step error
        ``|Phi(x0) - x1| / |x1 - x0|`` on the reductor's validation samples (in the coordinates the estimator is
        trained in) that the learned step must reach.  The greedy stops at the smallest model that meets it
        (fewer centres than ``max_centers`` for a loose target); when the cap, the data or a numerically singular
        kernel matrix stop it first, one :class:`~sympredict.exceptions.AccuracyWarning` names the limit and
        the best model found is kept.  ``None``: the budget is filled.
    """

    def __init__(self, max_centers: int = 1000, target_error: Optional[float] = None):
        self.max_centers = max_centers
        self.target_error = target_error

    def check(self) -> "DefaultEstimator":
        as_positive_int(self.max_centers, "DefaultEstimator max_centers")
        ExactGreedy(target_error=self.target_error).check()  # the trainer's own check and message
        return self

    def estimator(self, update: Optional[str]) -> SymplecticKernelPredictor:
        """The unfitted predictor with ``update`` (kernels still open: the reductor chooses them)."""
        return SymplecticKernelPredictor(
            None,
            None,
            None,
            max_centers=self.max_centers,
            trainer=ExactGreedy(tol=1e-12, target_error=self.target_error),
            update=update,
        )


class ValidationSelection(Setting):
    """Kernels and ridge term chosen on the reductor's validation data.

    Parameters
    ----------
    state_kernels, mu_kernels : sequence of RadialKernel or None, default=None
        Candidate kernels (in the estimator's coordinates; ``mu_kernels`` may hold ``None``: the factor dropped).
        ``None``: the estimator's own kernel (for :class:`DefaultEstimator`: the IMQ log grid).
    m_star : int, default=300
        Centres at which the kernel candidates are compared (at most the budget).
    regularizations : sequence of float or None, default=None
        Ridge terms (``trainer__regularization``) tried besides ``0`` (the exact fit): each candidate is trained
        and scored on the validation data in reduced coordinates; the smallest score wins, ties to the smaller
        term.  Validation samples score the mean relative error of one step; validation trajectories the mean
        relative error of the rollouts from their first states (a failed or non-finite rollout scores ``inf``).

    Notes
    -----
    Cost: one greedy fit to ``m_star`` centres per kernel pair, one full fit per ridge term.
    """

    def __init__(self, state_kernels=None, mu_kernels=None, m_star: int = 300, regularizations=None):
        self.state_kernels = state_kernels
        self.mu_kernels = mu_kernels
        self.m_star = m_star
        self.regularizations = regularizations

    def check(self) -> "ValidationSelection":
        _check_kernels(self.state_kernels, "ValidationSelection state_kernels", allow_none=False)
        _check_kernels(self.mu_kernels, "ValidationSelection mu_kernels", allow_none=True)
        as_positive_int(self.m_star, "ValidationSelection m_star")
        self.regularizations_ = (
            None
            if self.regularizations is None
            else [
                float(as_real(v, "ValidationSelection regularizations", nonnegative=True))
                for v in np.atleast_1d(np.asarray(self.regularizations, dtype=object))
            ]
        )
        return self

    def choose_kernels(self, base, train, val, vary_mu: bool, default: bool, log=logger):
        """``(clone(base) with the chosen kernels, SelectionResult)``, or ``(None, None)`` with nothing to choose."""
        state_kernels = _check_kernels(self.state_kernels, "state_kernels", False)
        mu_kernels = _check_kernels(self.mu_kernels, "mu_kernels", True)
        if not default and state_kernels is None and mu_kernels is None:
            return None, None
        if val is None:
            raise ValueError(
                "choosing kernels on validation data (ValidationSelection kernels, or the default "
                "estimator) needs validation data: give GivenSamples(data, validation) or "
                "GivenTrajectories(U, mus, validation=...), or an estimator that chooses its kernels "
                "on held-out training samples (estimator=SymplecticKernelPredictor(), no kernels given)"
            )
        inner = base.state_kernel.radial if isinstance(base.state_kernel, KernelTransform) else base.state_kernel
        if state_kernels is not None:
            states = state_kernels
        else:
            states = [IMQ(float(e)) for e in log_grid(0.01, 1.0, 2)] if default else [inner]
        if not vary_mu:
            mus = [None]
        elif mu_kernels is not None:
            mus = mu_kernels
        else:
            mus = [IMQ(float(e)) for e in log_grid(0.3, 3.0, 2)] if default else [base.mu_kernel]
        m_star = min(self.m_star, int(getattr(base, "max_centers", self.m_star)))
        with (
            log.block(f"kernel shapes on validation data ({len(states) * len(mus)} candidates, m* = {m_star})")
            if hasattr(log, "block")
            else contextlib.nullcontext()
        ):
            # the candidates compete at m_star centres: a target_error is the final fit's (as in the estimator's search)
            sel = select_kernels(
                train, val, states, mus, [base.dt_kernel], m_star=m_star, estimator=without_target(clone(base))
            )
        state = (
            base.state_kernel.with_radial(sel.state) if isinstance(base.state_kernel, KernelTransform) else sel.state
        )
        return clone(base).set_params(state_kernel=state, mu_kernel=sel.mu), sel

    def choose_regularization(self, predictor, fit: Callable, score: Callable, log=logger):
        """Every ridge term of ``{0} | regularizations`` fitted (``fit(candidate) -> (model, flow_map)``) and scored
        (``score(flow_map) -> float``); returns ``(model, flow_map, chosen term, table)``."""
        exact = {}

        def evaluate(lam):
            model, flow_map = fit(clone(predictor).set_params(trainer__regularization=lam))
            value = score(flow_map)
            log.info(f"regularization {lam:.3g}: validation score {value:.4e} ({model.n_centers_} centres)")
            if lam == 0.0:
                exact["fit"] = (model, flow_map)
            return value, (model, flow_map), {}

        best, table, _ = ridge_search(self.regularizations_, evaluate, name="ValidationSelection regularizations")
        for row in table:  # the record is JSON: a failed fit's score is None
            row["score"] = row["score"] if np.isfinite(row["score"]) else None
        if best is None:
            log.warning("no regularization gave a finite validation score: the exact fit (0) is kept")
            return (*exact["fit"], 0.0, table)
        lam, _, (model, flow_map) = best
        return model, flow_map, lam, table
