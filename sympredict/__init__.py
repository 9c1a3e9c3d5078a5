"""sympredict: symplectic large-step prediction of parameter-dependent Hamiltonian dynamics.

The main entry point is :class:`SymplecticKernelPredictor`.
"""

from sympredict import _numba  # noqa: F401, I001 - first: starts numba once (or hides it, with one warning)

from sympredict.exceptions import (
    ExtrapolationWarning,
    ModelFileError,
    NewtonConvergenceError,
    NotFittedError,
    SolvabilityError,
    SympredictError,
)  # noqa: E402
from sympredict.estimators.predictor import DirectKernelPredictor, SymplecticKernelPredictor
from sympredict.estimators.auto import KernelSearch
from sympredict.data import FlowMapData, TrajectoryData
from sympredict.io import read_trajectories

from sympredict._version import __version__

__all__ = [
    "SymplecticKernelPredictor",
    "DirectKernelPredictor",
    "KernelSearch",
    "SympredictError",
    "NewtonConvergenceError",
    "SolvabilityError",
    "ModelFileError",
    "NotFittedError",
    "ExtrapolationWarning",
    "FlowMapData",
    "TrajectoryData",
    "read_trajectories",
    "__version__",
]
