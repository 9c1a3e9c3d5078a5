"""HDF5 files of trained models and data sets.

Layout (schema version :data:`SCHEMA_VERSION`)::

    /                      attrs: format, schema_version, package_version, checksum
    /settings              attrs: JSON of the constructor settings and kernel spec
    /arrays/<name>         the arrays (float64 / int64), exactly as in memory

``format`` is ``'sympredict-model'`` or ``'sympredict-dataset'``.  The checksum
is the SHA-256 of the arrays' names, dtypes, shapes and bytes, so a damaged
file is detected on load.  Saving is atomic: the file is written next to the
target under a temporary name and renamed over it, so an interrupted save
never destroys a previous file.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from pathlib import Path

import h5py
import numpy as np

from sympredict.exceptions import ModelFileError

__all__ = ["SCHEMA_VERSION", "save_model", "load_model", "save_dataset", "load_dataset"]

SCHEMA_VERSION = 1
_MODEL_FORMAT = "sympredict-model"
_DATA_FORMAT = "sympredict-dataset"


def _checksum(arrays: dict) -> str:
    digest = hashlib.sha256()
    for name in sorted(arrays):
        arr = np.ascontiguousarray(arrays[name])
        digest.update(f"{name}|{arr.dtype.str}|{arr.shape}|".encode())
        digest.update(arr.tobytes())
    return digest.hexdigest()


def _write(path, fmt: str, settings: dict, arrays: dict) -> None:
    from sympredict import __version__

    path = Path(path)
    if path.is_dir():
        raise ValueError(f"path {str(path)!r} is a directory; give a file name such as model.h5")
    directory = path.parent if str(path.parent) else Path(".")
    if not directory.exists():
        raise ValueError(f"directory {str(directory)!r} does not exist")
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=directory)
    os.close(fd)
    try:
        with h5py.File(tmp, "w") as f:
            f.attrs["format"] = fmt
            f.attrs["schema_version"] = SCHEMA_VERSION
            f.attrs["package_version"] = __version__
            f.attrs["checksum"] = _checksum(arrays)
            f.attrs["settings"] = json.dumps(settings)
            grp = f.create_group("arrays")
            for name, arr in arrays.items():
                grp.create_dataset(name, data=np.asarray(arr))
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise


def _read(path, fmt: str):
    path = Path(path)
    if not path.is_file():
        raise ModelFileError(f"{str(path)!r} does not exist or is not a file")
    try:
        with h5py.File(path, "r") as f:
            found = f.attrs.get("format")
            if found is None:
                raise ModelFileError(f"{str(path)!r} is an HDF5 file but not a sympredict file (no 'format' attribute)")
            if found != fmt:
                raise ModelFileError(f"{str(path)!r} is a {found!r} file, expected {fmt!r}")
            version = int(f.attrs["schema_version"])
            if version > SCHEMA_VERSION:
                raise ModelFileError(
                    f"{str(path)!r} has schema version {version}, written by sympredict "
                    f"{f.attrs.get('package_version')}; this sympredict reads up to version {SCHEMA_VERSION}: upgrade sympredict"
                )
            settings = json.loads(f.attrs["settings"])
            arrays = {name: ds[()] for name, ds in f["arrays"].items()}
            checksum = f.attrs["checksum"]
    except ModelFileError:
        raise
    except (OSError, KeyError, ValueError, TypeError) as exc:
        raise ModelFileError(f"{str(path)!r} cannot be read as a sympredict file (truncated or corrupted?): {exc}") from None
    if _checksum(arrays) != checksum:
        raise ModelFileError(f"{str(path)!r} is corrupted: its arrays do not match the stored checksum")
    return settings, arrays


def save_model(model, path) -> None:
    """Save a fitted :class:`~sympredict.SymplecticKernelPredictor` (atomic)."""
    sur = model.surrogate_
    hist = model.history_
    settings = {
        "kernel": model.kernel_.spec,
        "state_kernel_given": model.state_kernel is not None,
        "max_centers": int(model.max_centers),
        "tol": float(model.tol),
        "criterion": model.criterion,
        "power_tol": float(model.power_tol),
        "newton_max_iter": int(model.newton_max_iter),
        "memory_limit": model.memory_limit,
        "dim": model.dim_,
        "n_mu": model.n_mu_,
        "dt_fixed": model.dt_fixed_,
        "stop_reason": hist.stop_reason,
    }
    arrays = {
        "centers_xi": sur.centers_xi,
        "centers_mu": sur.centers_mu,
        "centers_dt": sur.centers_dt,
        "components": sur.components,
        "coef": sur.coef,
        "train_max_residual": hist.train_max_residual,
        "selected_power": hist.selected_power,
        "elapsed": hist.elapsed,
    }
    if hist.val_max_residual is not None:
        arrays["val_max_residual"] = hist.val_max_residual
    arrays.update({f"domain_{k}": np.asarray(v) for k, v in model.domain_.items()})
    _write(path, _MODEL_FORMAT, settings, arrays)


def load_model(path):
    """Load a model written by :func:`save_model`; :class:`ModelFileError` if unusable."""
    from sympredict.greedy import GreedyHistory
    from sympredict.kernels import ProductKernel, kernel_from_spec
    from sympredict.predictor import SymplecticKernelPredictor
    from sympredict.surrogate import HBSurrogate

    settings, arrays = _read(path, _MODEL_FORMAT)
    try:
        spec = settings["kernel"]
        kernel = ProductKernel(kernel_from_spec(spec["state"]), kernel_from_spec(spec["mu"]), kernel_from_spec(spec["dt"]))
        model = SymplecticKernelPredictor(
            kernel.state if settings["state_kernel_given"] else None,
            kernel.mu,
            kernel.dt,
            max_centers=settings["max_centers"],
            tol=settings["tol"],
            criterion=settings["criterion"],
            power_tol=settings["power_tol"],
            newton_max_iter=settings["newton_max_iter"],
            memory_limit=settings["memory_limit"],
        )
        model.kernel_ = kernel
        model.surrogate_ = HBSurrogate(
            kernel, arrays["centers_xi"], arrays["centers_mu"], arrays["centers_dt"], arrays["components"], arrays["coef"]
        )
        model.history_ = GreedyHistory(
            train_max_residual=arrays["train_max_residual"],
            val_max_residual=arrays.get("val_max_residual"),
            selected_power=arrays["selected_power"],
            elapsed=arrays["elapsed"],
            stop_reason=settings["stop_reason"],
        )
        model._set_shape_info(settings["dim"], settings["n_mu"], settings["dt_fixed"])
        model.domain_ = {k[len("domain_"):]: v for k, v in arrays.items() if k.startswith("domain_")}
    except (KeyError, TypeError, ValueError) as exc:
        raise ModelFileError(f"{str(path)!r} is an incomplete sympredict model file: {exc!r}") from None
    return model


def save_dataset(data, path, **metadata) -> None:
    """Save a :class:`~sympredict.data.FlowMapData` (atomic); ``metadata`` must be JSON-serializable."""
    arrays = {"x0": data.x0, "x1": data.x1, "mu": data.mu, "dt": data.dt}
    _write(path, _DATA_FORMAT, {"metadata": metadata}, arrays)


def load_dataset(path):
    """Load a data set written by :func:`save_dataset`; returns ``(FlowMapData, metadata)``."""
    from sympredict.data import FlowMapData

    settings, arrays = _read(path, _DATA_FORMAT)
    try:
        data = FlowMapData(arrays["x0"], arrays["x1"], arrays["mu"], arrays["dt"])
    except (KeyError, ValueError) as exc:
        raise ModelFileError(f"{str(path)!r} is an incomplete or invalid sympredict data set: {exc}") from None
    return data, settings.get("metadata", {})
