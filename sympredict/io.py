"""HDF5 files of trained models and data sets.

The container (layout, checksum, atomic save, checked load) is
:mod:`sympredict.container`; this module names the two formats,
``'sympredict-model'`` and ``'sympredict-dataset'``, and maps them to objects.
"""

from __future__ import annotations

from sympredict.container import SCHEMA_VERSION, read_container, write_container
from sympredict.data import FlowMapData
from sympredict.exceptions import ModelFileError
from sympredict.predictor import MODEL_FORMAT, DirectKernelPredictor, SymplecticKernelPredictor

__all__ = ["SCHEMA_VERSION", "save_model", "load_model", "save_dataset", "load_dataset"]

_DATA_FORMAT = "sympredict-dataset"
_ESTIMATORS = {cls.__name__: cls for cls in (SymplecticKernelPredictor, DirectKernelPredictor)}


def save_model(model, path) -> None:
    """Save a fitted :class:`~sympredict.SymplecticKernelPredictor` or :class:`~sympredict.DirectKernelPredictor` (atomic)."""
    model.save(path)


def load_model(path):
    """Load a model written by :func:`save_model`, whichever estimator it holds; :class:`ModelFileError` if unusable."""
    settings, arrays = read_container(path, MODEL_FORMAT)
    name = settings.get("class", "SymplecticKernelPredictor") if isinstance(settings, dict) else None
    cls = _ESTIMATORS.get(name)
    if cls is None:
        raise ModelFileError(f"{str(path)!r} holds an unknown estimator {name!r}; known: {sorted(_ESTIMATORS)}")
    return cls._from_container(settings, arrays, path)


def save_dataset(data, path, **metadata) -> None:
    """Save a :class:`~sympredict.data.FlowMapData` (atomic); ``metadata`` must be JSON-serializable."""
    arrays = {"x0": data.x0, "x1": data.x1, "mu": data.mu, "dt": data.dt}
    write_container(path, _DATA_FORMAT, {"metadata": metadata}, arrays)


def load_dataset(path):
    """Load a data set written by :func:`save_dataset`; returns ``(FlowMapData, metadata)``."""
    settings, arrays = read_container(path, _DATA_FORMAT)
    try:
        data = FlowMapData(arrays["x0"], arrays["x1"], arrays["mu"], arrays["dt"])
    except (KeyError, ValueError) as exc:
        raise ModelFileError(f"{str(path)!r} is an incomplete or invalid sympredict data set: {exc}") from None
    return data, settings.get("metadata", {})
