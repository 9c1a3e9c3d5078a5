"""A second opinion on a model's rollouts: a larger companion model fitted to the same data.

A model's own error estimate (``rollout(..., return_error=True)``) knows the size of its local errors better than
their direction, and the directions decide how the errors add up along a trajectory: it ranks trajectories by their
error poorly where they differ by the model's local accuracy rather than by how fast errors grow (the how-to "How
accurate is my prediction?").  A companion fitted the same way with more centres errs differently, and where it is
more accurate its rollout stands in for the exact one: the difference ``x_k - x^c_k`` of the two rollouts estimates
the model's error vector by vector, carried along by the nonlinear maps themselves (the embedded pair of a
Runge-Kutta method's step-size control, with models instead of formulas).

The companion is not exact, and it can err as much as the model (then the difference alone underestimates) or more
over a long rollout (then it overestimates).  :class:`CompanionEstimate` therefore combines three estimates per
trajectory and step::

    error_k = min( hypot(s |x_k - x^c_k|, e^c_k),  e_k )

with ``e^c_k`` the companion's own estimate of its error (added: the difference is only as good as the companion),
``e_k`` the model's own estimate (the cap: it rarely underestimates) and ``s`` the difference's calibration on the
model's held-out samples.  Measured on ten systems (``sympredict_paper/studies/error_estimate_companion.py``,
``docs/data/error_estimate_companion_pair.json``), see the how-to.
"""

from __future__ import annotations

import numbers
from typing import Optional

import numpy as np
from pymor.core.logger import getLogger

from sympredict.base import clone

__all__ = ["CompanionEstimate", "combined_error"]

logger = getLogger("sympredict.estimators.companion")


def combined_error(difference: np.ndarray, companion_error: np.ndarray, own_error: np.ndarray) -> np.ndarray:
    """``min(hypot(difference, companion_error), own_error)``, elementwise (any common shape).

    ``difference`` is the calibrated difference of the two rollouts ``s |x_k - x^c_k|``, ``companion_error`` the
    companion's own estimate of its error and ``own_error`` the model's own estimate, each ``(B, K + 1)``.
    """
    return np.minimum(np.hypot(difference, companion_error), own_error)


class CompanionEstimate:
    """Error estimate of a model's rollouts from a companion model with more centres.

    Parameters
    ----------
    model : SymplecticKernelPredictor
        The fitted model whose rollouts are estimated.
    companion : SymplecticKernelPredictor
        A fitted companion, fitted on the same data as ``model`` (so that it left out the same held-out samples;
        :meth:`fit` fits one).
    scale : float, optional
        ``scale_`` of an earlier calibration of the same two models (models loaded from files keep no samples to
        calibrate on); default: calibrated on first use (:meth:`calibrate`).

    Attributes
    ----------
    scale_ : float
        ``s``: the model's ``ERROR_QUANTILE`` (0.9) quantile, over its held-out calibration samples, of
        ``|Phi(x0) - x1| / |Phi_c(x0) - Phi(x0)|`` (the model's one-step error over the two models' one-step
        difference), so that ``s |Phi_c(x0) - Phi(x0)|`` underestimates the model's one-step error on a tenth of them.
    accuracy_ratio_ : float
        The companion's median one-step error ``|Phi_c(x0) - x1|`` over the model's, on the same samples (a
        diagnostic: below 1 the companion is the more accurate one).

    Notes
    -----
    Cost of :meth:`fit`: the companion's fit, with ``budget`` times the model's ``max_centers`` and its own kernel
    search (on the study's ten systems 1.6 to 4.7 times the model's fit).  Cost of :meth:`rollout`: both models'
    rollouts with their own estimates, 1.9 to 4.9 times the model's own estimate there (the companion's estimate
    costs ``O(B K 2n m_c^2)`` for its ``m_c`` centres).  Memory: both rollouts' states and estimates,
    ``O(B K 2n)``.  To keep it, save both models (:meth:`~sympredict.estimators.predictor.SymplecticKernelPredictor.save`)
    and its :attr:`scale_`, and rebuild it with ``CompanionEstimate(model, companion, scale=scale)``.
    """

    def __init__(self, model, companion, scale: Optional[float] = None):
        self.model = model
        self.companion = companion
        self.scale = scale

    @classmethod
    def fit(cls, model, x0, x1=None, mu=None, dt=None, *, validation=None, budget: float = 2.0) -> "CompanionEstimate":
        """Fit a companion to ``model`` on the same data and calibrate it.

        Parameters
        ----------
        model : SymplecticKernelPredictor
            The fitted model.
        x0, x1, mu, dt, validation
            The data ``model`` was fitted on, as its ``fit`` took them.
        budget : float, default=2.0
            The companion's ``max_centers`` over the model's (above 1).

        Returns
        -------
        CompanionEstimate
            Calibrated (:meth:`calibrate`).
        """
        if not (
            isinstance(budget, numbers.Real) and not isinstance(budget, bool) and np.isfinite(budget) and budget > 1
        ):
            raise ValueError(
                f"budget must be a finite number above 1 (the companion's max_centers over the model's), got {budget!r}"
            )
        companion = clone(model).set_params(max_centers=int(round(budget * model.max_centers)))
        companion.fit(x0, x1, mu=mu, dt=dt, validation=validation)
        return cls(model, companion).calibrate()

    def _calibration_samples(self):
        """The model's held-out calibration samples, which the companion must have left out too."""
        own = getattr(self.model.model_, "calibration_samples", None)
        other = getattr(self.companion.model_, "calibration_samples", None)
        if own is None or own[1] != "held-out samples":
            raise ValueError(
                "the model has no held-out samples to calibrate the companion on (a fit with every kernel given "
                "trains on every sample; a model loaded from a file keeps none): leave a kernel to the search or fit "
                "the model with validation=... (and pass the same validation to CompanionEstimate.fit), pass "
                "held-out samples to calibrate(samples=...), or the scale_ of an earlier calibration as scale=..."
            )
        if other is None or not (np.array_equal(own[0].x0, other[0].x0) and np.array_equal(own[0].x1, other[0].x1)):
            raise ValueError(
                "the companion did not leave out the model's held-out samples: fit both on the same data "
                "(CompanionEstimate.fit(model, <the data the model was fitted on>))"
            )
        return own[0]

    @staticmethod
    def _step(estimator, data) -> np.ndarray:
        return estimator.step(data.x0, mu=data.mu if estimator.n_mu_ else None, dt=data.dt)

    def calibrate(self, samples=None) -> "CompanionEstimate":
        """Compute :attr:`scale_` and :attr:`accuracy_ratio_` on held-out samples (one implicit step of each model
        per sample); returns ``self``.

        Parameters
        ----------
        samples : FlowMapData, optional
            Samples neither model was trained on.  Default: the model's held-out samples, checked to be the
            companion's too (both fitted on the same data).
        """
        data = self._calibration_samples() if samples is None else samples
        own = self._step(self.model, data)
        other = self._step(self.companion, data)
        own_error = np.linalg.norm(own - data.x1, axis=1)
        difference = np.linalg.norm(other - own, axis=1)
        ok = difference > 0
        if not ok.any():
            raise ValueError(
                "the companion predicts every held-out sample as the model does: it cannot tell the model's error; "
                "fit it with a larger budget"
            )
        self.scale_ = float(np.quantile(own_error[ok] / difference[ok], self.model.model_.ERROR_QUANTILE))
        self.accuracy_ratio_ = float(np.median(np.linalg.norm(other - data.x1, axis=1)) / np.median(own_error))
        logger.info(
            f"companion estimate: {self.companion.n_centers_} centres against the model's {self.model.n_centers_}; "
            f"its one-step error is {self.accuracy_ratio_:.2f} times the model's on {len(data)} held-out samples; "
            f"the difference of the rollouts is scaled by {self.scale_:.3g}"
        )
        return self

    def rollout(self, x0, n_steps: int, mu=None, dt=None) -> tuple:
        """The model's rollout and the estimate of its error.

        Parameters
        ----------
        x0, n_steps, mu, dt
            As the model's ``rollout``.

        Returns
        -------
        states : ndarray of shape (B, K + 1, 2n) (or (K + 1, 2n) for a single state)
            The model's rollout, as ``model.rollout`` gives it.
        error : ndarray of shape (B, K + 1) (or (K + 1,))
            The estimate of ``|x_k - x_exact,k|_2`` in the states' units (0 at step 0):
            ``min(hypot(scale_ |x_k - x^c_k|, e^c_k), e_k)`` (module docstring).

        Raises
        ------
        NewtonConvergenceError
            Where the model's or the companion's implicit step cannot be solved.
        """
        if not hasattr(self, "scale_"):
            if self.scale is None:
                self.calibrate()
            elif (
                isinstance(self.scale, numbers.Real)
                and not isinstance(self.scale, bool)
                and np.isfinite(self.scale)
                and self.scale > 0
            ):
                self.scale_ = float(self.scale)
            else:
                raise ValueError(f"scale must be a positive finite number (an earlier scale_), got {self.scale!r}")
        states, own = self.model.rollout(x0, n_steps, mu=mu, dt=dt, return_error=True)
        other, other_error = self.companion.rollout(x0, n_steps, mu=mu, dt=dt, return_error=True)
        return states, combined_error(self.scale_ * np.linalg.norm(states - other, axis=-1), other_error, own)

    def __repr__(self) -> str:
        calibrated = f", scale_={self.scale_:.3g}" if hasattr(self, "scale_") else ""
        return (
            f"CompanionEstimate(model with {self.model.n_centers_} centres, companion with "
            f"{self.companion.n_centers_}{calibrated})"
        )
