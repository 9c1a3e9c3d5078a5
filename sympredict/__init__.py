"""sympredict: symplectic large-step prediction of parameter-dependent Hamiltonian dynamics.

The main entry point is :class:`SymplecticKernelPredictor`.
"""

import importlib as _importlib
import importlib.abc as _importlib_abc
import importlib.util as _importlib_util
import sys as _sys
import warnings as _warnings


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


#: Modules that moved into the role subpackages: old dotted name -> new one.  Importing an old name
#: (``import sympredict.predictor``, a pickle naming ``sympredict.greedy.loop``, ...) gives the new module
#: itself (same object: ``isinstance`` and monkeypatching see one module) with one DeprecationWarning.
#: A package's submodules follow it (``sympredict.experiments.pendulum`` -> ``sympredict.paper.pendulum``).
_MOVED_MODULES = {
    "sympredict.functionals": "sympredict.interpolation.functionals",
    "sympredict.surrogate": "sympredict.interpolation.surrogate",
    "sympredict.greedy": "sympredict.interpolation.greedy",
    "sympredict.newton": "sympredict.symplectic.newton",
    "sympredict.integrators": "sympredict.symplectic.integrators",
    "sympredict.integrators_compiled": "sympredict.symplectic.integrators_compiled",
    "sympredict.metrics": "sympredict.symplectic.metrics",
    "sympredict.flowmaps": "sympredict.systems.flowmaps",
    "sympredict.linear_flow": "sympredict.systems.linear_flow",
    "sympredict.predictor": "sympredict.estimators.predictor",
    "sympredict.selection": "sympredict.estimators.selection",
    "sympredict.scaling": "sympredict.flowmap.scaling",
    "sympredict.splitting": "sympredict.flowmap.splitting",
    "sympredict.reduction": "sympredict.mor.basis",
    "sympredict.nonlinear_mor": "sympredict.mor.nonlinear",
    "sympredict.experiments": "sympredict.paper",
    "sympredict.report": "sympredict.paper.report",
    "sympredict.plotting": "sympredict.paper.plotting",
}


def _moved_to(fullname: str):
    """The new dotted name of an old module name, or ``None``."""
    for old, new in _MOVED_MODULES.items():
        if fullname == old or fullname.startswith(old + "."):
            return new + fullname[len(old):]
    return None


def _importer_stacklevel() -> int:
    """``stacklevel`` of the line that imported, counted as ``warnings`` counts (import-system frames skipped)."""
    frame, level = _sys._getframe(2), 1
    while frame is not None:
        name = frame.f_code.co_filename
        if not ("importlib" in name and "_bootstrap" in name):
            level += 1
            if name not in (__file__, _importlib.__file__):
                return level
        frame = frame.f_back
    return 1


class _MovedModuleFinder(_importlib_abc.MetaPathFinder, _importlib_abc.Loader):
    """Finds the old names of moved modules (first on ``sys.meta_path``) and loads them as the new modules."""

    def find_spec(self, fullname, path=None, target=None):
        new = _moved_to(fullname) if fullname.startswith("sympredict.") else None
        try:
            if new is None or _importlib_util.find_spec(new) is None:
                return None
        except ImportError:
            return None
        return _importlib_util.spec_from_loader(fullname, self)

    def create_module(self, spec):
        new = _moved_to(spec.name)
        module = _importlib.import_module(new)
        _warnings.warn(f"{spec.name} moved to {new}; import {new} (the old name is deprecated and will be removed)",
                       DeprecationWarning, stacklevel=_importer_stacklevel())
        spec.loader_state = module.__spec__  # the import system sets module.__spec__ to this alias's spec next
        return module

    def exec_module(self, module):
        module.__spec__ = module.__spec__.loader_state  # the module keeps its own spec; nothing runs again


def __getattr__(name: str):
    """``sympredict.predictor`` and the other old submodule attributes: the moved module, with the warning."""
    if f"sympredict.{name}" in _MOVED_MODULES:
        return _importlib.import_module(f"sympredict.{name}")
    raise AttributeError(f"module 'sympredict' has no attribute {name!r}")


_sys.meta_path[:] = [f for f in _sys.meta_path if type(f).__name__ != "_MovedModuleFinder"]
_sys.meta_path.insert(0, _MovedModuleFinder())
