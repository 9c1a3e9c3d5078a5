"""sympredict: symplectic large-step prediction of parameter-dependent Hamiltonian dynamics.

The main entry point is :class:`SymplecticKernelPredictor`.
"""

import sys as _sys


def _numba_or_numpy() -> None:
    """Start numba once; where it is installed but cannot start (e.g. ``NUMBA_NUM_THREADS=0``), hide it so that
    every module takes its NumPy path, with one warning (numba itself is optional: ``ImportError`` stays quiet)."""
    try:
        import numba  # noqa: F401
    except ImportError:
        return
    except Exception as exc:  # numba's configuration raises ValueError, KeyError, ... at import
        for name in [m for m in _sys.modules if m == "numba" or m.startswith("numba.")]:
            del _sys.modules[name]
        _sys.modules["numba"] = None  # later "import numba" raises ImportError: the NumPy fallbacks
        import warnings

        warnings.warn(f"numba is installed but cannot start ({type(exc).__name__}: {exc}); sympredict runs on its "
                      "NumPy code paths (slower). Check numba's environment variables (NUMBA_NUM_THREADS must be a "
                      "positive integer).", RuntimeWarning, stacklevel=3)


_numba_or_numpy()

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

