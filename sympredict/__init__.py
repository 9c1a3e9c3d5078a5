"""sympredict: symplectic large-step prediction of parameter-dependent Hamiltonian dynamics.

The main entry point is :class:`SymplecticKernelPredictor`.
"""

from sympredict.exceptions import (
    ExtrapolationWarning,
    ModelFileError,
    NewtonConvergenceError,
    NotFittedError,
    SolvabilityError,
    SympredictError,
)
from sympredict.predictor import DirectKernelPredictor, SymplecticKernelPredictor

from sympredict._version import __version__

__all__ = [
    "SymplecticKernelPredictor",
    "DirectKernelPredictor",
    "SympredictError",
    "NewtonConvergenceError",
    "SolvabilityError",
    "ModelFileError",
    "NotFittedError",
    "ExtrapolationWarning",
    "__version__",
]
