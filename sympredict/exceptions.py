"""The package's exceptions: numerical failure and unusable files.

Bad user input raises :class:`ValueError` (with a message naming the argument);
the classes here are for what goes wrong *inside* a correct call.
"""

from __future__ import annotations

import contextlib
import warnings

import numpy as np

__all__ = [
    "SympredictError",
    "NewtonConvergenceError",
    "SolvabilityError",
    "ModelFileError",
    "NotFittedError",
    "RolloutMemoryError",
    "NonFinitePredictionError",
    "ExtrapolationWarning",
    "ScaleWarning",
    "WrappedAngleWarning",
    "GeneratingFunctionWarning",
    "UnderfitWarning",
    "DuplicateSamplesWarning",
    "AccuracyWarning",
    "extrapolation_expected",
]


class SympredictError(Exception):
    """Base class of sympredict's own errors."""


class NotFittedError(SympredictError, ValueError):
    """A model was used before :meth:`fit` (or :meth:`load`)."""


class ModelFileError(SympredictError, ValueError):
    """A file is not a readable sympredict file (foreign, truncated, corrupted or newer schema)."""


class NewtonConvergenceError(SympredictError):
    """Newton's method for an implicit step did not converge for some instances.

    Attributes
    ----------
    instances : ndarray of int
        Indices (into the batch passed by the caller) of the failed instances.
    residuals : ndarray of float
        Their last residual norms (``inf``/``nan`` for non-finite iterates).
    step : int or None
        Index of the macro step within a rollout, if any.
    contraction : ndarray of float or None
        Their contraction estimates ``dT * L_S`` at Newton's start guess
        (:func:`sympredict.symplectic.newton.contraction_estimate`; ``nan`` where the
        Hessian there is not finite), if known.
    """

    def __init__(self, instances, residuals, reason: str = "did not converge", step=None, contraction=None):
        self.instances = np.asarray(instances, dtype=int)
        self.residuals = np.asarray(residuals, dtype=float)
        self.reason = reason
        self.step = step
        self.contraction = None if contraction is None else np.asarray(contraction, dtype=float)
        if self.contraction is None:
            shown = ", ".join(f"{i} (residual {r:.2e})" for i, r in zip(self.instances[:10], self.residuals[:10]))
            causes = "(dT * L_S >= 1)"
        else:
            shown = ", ".join(
                f"{i} (residual {r:.2e}, dT*L_S {c:.3g} at the start guess)"
                for i, r, c in zip(self.instances[:10], self.residuals[:10], self.contraction[:10])
            )
            causes = "(dT*L_S < 1 makes the fixed-point iteration contract; Newton often converges beyond it)"
        more = f" and {len(self.instances) - 10} more" if len(self.instances) > 10 else ""
        where = f" at macro step {step}" if step is not None else ""
        super().__init__(
            f"Newton solve of the implicit step {reason}{where} for {len(self.instances)} instance(s): "
            f"{shown}{more}. A step that is too large for the surrogate {causes} or a state far "
            f"outside the training domain are the usual causes."
        )

    def at_step(self, step: int) -> "NewtonConvergenceError":
        """The same error, annotated with the rollout step."""
        return NewtonConvergenceError(self.instances, self.residuals, self.reason, step, self.contraction)


class RolloutMemoryError(SympredictError, MemoryError):
    """The states a rollout would keep do not fit in the memory available; raised before any work.

    Attributes
    ----------
    needed, available : int
        Bytes the kept states need and bytes the system reports available.
    """

    def __init__(self, needed: int, available: int, shape: tuple):
        self.needed, self.available, self.shape = int(needed), int(available), tuple(shape)
        super().__init__(
            f"keeping the states of this rollout ({shape[0]} trajectories x {shape[1]} kept states x {shape[2]} "
            f"components, float64) needs {needed / 2**30:.3g} GiB, more than the {available / 2**30:.3g} GiB available: "
            "keep every k-th state only (rollout(..., stride=k); the command line's --stride), or roll out fewer steps"
        )


class SolvabilityError(SympredictError):
    """The implicit step is not known to be solvable: ``dT * L_S >= 1`` at some instances.

    Attributes
    ----------
    instances : ndarray of int
        Offending instances.
    margins : ndarray of float
        Their ``dT * L_S`` estimates.
    """

    def __init__(self, instances, margins):
        self.instances = np.asarray(instances, dtype=int)
        self.margins = np.asarray(margins, dtype=float)
        shown = ", ".join(f"{i} (dT*L_S = {v:.2f})" for i, v in zip(self.instances[:10], self.margins[:10]))
        more = f" and {len(self.instances) - 10} more" if len(self.instances) > 10 else ""
        super().__init__(
            f"the implicit step is not guaranteed solvable for {len(self.instances)} instance(s): {shown}{more}. "
            "dT * L_S < 1 is required (paper, Prop. 2); use a smaller dT or stay inside the training domain."
        )


class NonFinitePredictionError(SympredictError, ArithmeticError):
    """A prediction overflowed or turned NaN (never returned silently).

    Attributes
    ----------
    instances : ndarray of int
        Indices (into the batch passed by the caller) of the instances with non-finite values.
    """

    def __init__(self, instances, model: str = "the model", step=None):
        self.instances = np.asarray(instances, dtype=int)
        self.step = step
        shown = ", ".join(str(i) for i in self.instances[:10]) + (" ..." if len(self.instances) > 10 else "")
        where = f" at macro step {step}" if step is not None else ""
        super().__init__(
            f"{model} predicted non-finite states (overflow or NaN){where} for {len(self.instances)} instance(s): "
            f"{shown}. The model's coefficients or the query are far outside what it was trained on: check the "
            f"model file and that the states lie in the training box."
        )


class ExtrapolationWarning(UserWarning):
    """A query lies outside the box spanned by the training data (extrapolation is allowed)."""


class GeneratingFunctionWarning(UserWarning):
    """The type-II generating function ``s(q0, p1)`` is close to not existing on the data
    (``dp1/dp0`` nearly singular): the macro step is close to its largest admissible value."""


class ScaleWarning(UserWarning):
    """Coordinates (conjugate pairs) or parameter components whose spreads differ by orders of magnitude: an
    isotropic kernel hardly sees the small ones, which are then learned badly; the message names them."""


class WrappedAngleWarning(UserWarning):
    """A state coordinate looks like an angle reduced to one period: some samples jump by about a period between
    consecutive states while it otherwise moves little (:func:`sympredict.estimators.structure.wrapped_coordinates`).
    The message names the coordinate and the fix (unwrap the samples, and a ``Periodic`` state kernel)."""


class UnderfitWarning(UserWarning):
    """A fit learned (almost) nothing: no centre selected, or the training residual did not go down,
    although the data move the states; the model is (close to) the identity map."""


class AccuracyWarning(UserWarning):
    """A fit with ``target_error`` did not meet it (the message names the limit: data, centre cap, kernel breakdown)."""


class DuplicateSamplesWarning(UserWarning):
    """Repeated training samples (same ``x0``, ``x1``, ``mu`` and ``dt``) were dropped before a fit;
    overlapping trajectory windows produce them.  The message says how many."""


@contextlib.contextmanager
def extrapolation_expected():
    """Silence :class:`ExtrapolationWarning` inside the block: for code that extrapolates on purpose.

    Experiments use it where leaving the training box is part of the design
    (scenario B, the stability study) or is measured as an error (the small
    truncated models of a size search); the call site says which.
    """
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ExtrapolationWarning)
        yield
