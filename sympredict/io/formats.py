"""HDF5 files of trained models and data sets.

The container (layout, checksum, atomic save, checked load) is
:mod:`sympredict.container`; this module names the two formats,
``'sympredict-model'`` and ``'sympredict-dataset'``, and maps them to objects.
"""

from __future__ import annotations

import numpy as np

from sympredict._checks import as_real_array, as_steps
from sympredict.container import SCHEMA_VERSION, read_container, write_container
from sympredict.data import FlowMapData
from sympredict.exceptions import ModelFileError
from sympredict.estimators.predictor import MODEL_FORMAT, DirectKernelPredictor, SymplecticKernelPredictor
from sympredict.flowmap.splitting import SplitKernelPredictor

__all__ = ["SCHEMA_VERSION", "save_model", "load_model", "check_model_file", "save_dataset", "load_dataset"]

_DATA_FORMAT = "sympredict-dataset"
_ESTIMATORS = {cls.__name__: cls for cls in (SymplecticKernelPredictor, DirectKernelPredictor, SplitKernelPredictor)}


def _file_rule(where: str, rule, *args):
    """``rule(*args)`` (a :mod:`sympredict._checks` function: each rule written once), its ``ValueError`` a
    :class:`ModelFileError` naming the file."""
    try:
        return rule(*args)
    except ValueError as exc:
        raise ModelFileError(f"{where}: {exc}") from None


def save_model(model, path, *, overwrite: bool = True) -> None:
    """Save a fitted :class:`~sympredict.SymplecticKernelPredictor`, :class:`~sympredict.DirectKernelPredictor` or
    :class:`~sympredict.flowmap.splitting.SplitKernelPredictor` (atomic; ``overwrite=False`` refuses an existing file)."""
    model.save(path, overwrite=overwrite)


#: What a model file is, for the errors on other files.
MODEL_FILES = (
    "a model is an HDF5 file (.h5 or .hdf5) written by model.save(path), save_model or 'sympredict train'; "
    "trajectories (.npz, .csv, .h5) and data sets of 'sympredict data' are training data: give them to "
    "'sympredict train'"
)
_HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"


def check_model_file(path) -> None:
    """Refuse a file that cannot be a model before reading it: not HDF5 (by its signature), or a data set.

    A :class:`ModelFileError` that says what was given and which files are models (:data:`MODEL_FILES`).
    Reads 8 bytes (and the root attributes of an HDF5 file); a missing file is left to the reader.
    """
    import os

    if not os.path.isfile(path):
        return
    try:
        with open(path, "rb") as fh:
            head = fh.read(8)
    except OSError:
        return
    if head != _HDF5_SIGNATURE:
        kind = (
            "a NumPy .npz archive"
            if head.startswith(b"PK")
            else f"a {os.path.splitext(str(path))[1] or 'suffix-less'} file, not HDF5"
        )
        raise ModelFileError(f"{str(path)!r} is not a sympredict model: it is {kind}; {MODEL_FILES}")
    import h5py

    try:
        with h5py.File(path, "r") as f:
            found = f.attrs.get("format")
    except Exception:  # damaged: the container's reader says what is wrong
        return
    if isinstance(found, bytes):
        found = found.decode("utf-8", "replace")
    if found is None:
        raise ModelFileError(
            f"{str(path)!r} is an HDF5 file but not a sympredict model (no 'format' attribute: "
            f"trajectories?); {MODEL_FILES}"
        )
    if found == _DATA_FORMAT:
        raise ModelFileError(f"{str(path)!r} is not a sympredict model but a data set; {MODEL_FILES}")


def load_model(path):
    """Load a model written by :func:`save_model`, whichever estimator it holds; :class:`ModelFileError` if unusable.

    A file that is not a model (not HDF5, or a data set) is refused naming the files that are (:func:`check_model_file`).

    Parameters
    ----------
    path : str or path-like
        A model file written by :func:`save_model` (or an estimator's ``save``).

    Returns
    -------
    SymplecticKernelPredictor, DirectKernelPredictor or SplitKernelPredictor
        The fitted estimator the file holds.

    Raises
    ------
    ModelFileError
        For a file that is not a model or is unusable (naming what is wrong).
    """
    check_model_file(path)
    settings, arrays = read_container(path, MODEL_FORMAT)
    name = settings.get("class", "SymplecticKernelPredictor") if isinstance(settings, dict) else None
    cls = _ESTIMATORS.get(name) if isinstance(name, str) else None
    if cls is None:
        raise ModelFileError(f"{str(path)!r} holds an unknown estimator {name!r}; known: {sorted(_ESTIMATORS)}")
    return cls.from_container(settings, arrays, path)


def save_dataset(data, path, *, overwrite: bool = True, **metadata) -> None:
    """Save a :class:`~sympredict.data.FlowMapData` (atomic; ``overwrite=False`` refuses an existing file);
    ``metadata`` must be JSON-serializable."""
    arrays = {"x0": data.x0, "x1": data.x1, "mu": data.mu, "dt": data.dt}
    write_container(path, _DATA_FORMAT, {"metadata": metadata}, arrays, overwrite=overwrite)


def load_dataset(path):
    """Load a data set written by :func:`save_dataset`; returns ``(FlowMapData, metadata)``.

    Besides the container's checks, the arrays must be consistent: ``x0`` and
    ``x1`` of one shape ``(M, 2n)``, ``mu`` of shape ``(M, d_mu)``, ``dt`` of
    shape ``(M,)`` and positive, all finite; anything else raises
    :class:`ModelFileError` naming the problem.
    """
    settings, arrays = read_container(path, _DATA_FORMAT)
    where = f"{str(path)!r} is not a valid sympredict data set"
    expected = {"x0", "x1", "mu", "dt"}
    if set(arrays) != expected:
        missing, extra = sorted(expected - set(arrays)), sorted(set(arrays) - expected)
        raise ModelFileError(f"{where}: " + (f"missing arrays {missing}" if missing else f"unexpected arrays {extra}"))
    x0, x1, mu, dt = (np.asarray(arrays[k]) for k in ("x0", "x1", "mu", "dt"))
    for name, arr in (("x0", x0), ("x1", x1), ("mu", mu), ("dt", dt)):
        if arr.dtype.kind not in "fiu":
            raise ModelFileError(f"{where}: {name} has dtype {arr.dtype}, expected floats")
        _file_rule(where, as_real_array, arr, name)
    if x0.ndim != 2 or x0.shape[0] == 0 or x0.shape[1] == 0 or x0.shape[1] % 2:
        raise ModelFileError(f"{where}: x0 must have shape (M, 2n) with M >= 1, got {x0.shape}")
    m = x0.shape[0]
    if x1.shape != x0.shape:
        raise ModelFileError(f"{where}: x1 has shape {x1.shape}, x0 has {x0.shape}")
    if mu.ndim != 2 or mu.shape[0] != m:
        raise ModelFileError(f"{where}: mu must have shape ({m}, d_mu), got {mu.shape}")
    if dt.shape != (m,):
        raise ModelFileError(f"{where}: dt must have shape ({m},), got {dt.shape}")
    _file_rule(where, as_steps, dt, m)
    metadata = settings.get("metadata", {})
    if set(settings) != {"metadata"} or not isinstance(metadata, dict):
        raise ModelFileError(f"{where}: its settings must be {{'metadata': {{...}}}}")
    try:
        data = FlowMapData(x0, x1, mu, dt)
    except ValueError as exc:
        raise ModelFileError(f"{where}: {exc}") from None
    return data, metadata
