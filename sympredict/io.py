"""HDF5 files of trained models and data sets.

The container (layout, checksum, atomic save, checked load) is
:mod:`sympredict.container`; this module names the two formats,
``'sympredict-model'`` and ``'sympredict-dataset'``, and maps them to objects.
"""

from __future__ import annotations

import numpy as np

from sympredict.container import SCHEMA_VERSION, read_container, write_container
from sympredict.exceptions import ModelFileError

__all__ = ["SCHEMA_VERSION", "save_model", "load_model", "save_dataset", "load_dataset"]

_MODEL_FORMAT = "sympredict-model"
_DATA_FORMAT = "sympredict-dataset"


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
    write_container(path, _MODEL_FORMAT, settings, arrays)


def load_model(path):
    """Load a model written by :func:`save_model`; :class:`ModelFileError` if unusable."""
    from sympredict.greedy import GreedyHistory
    from sympredict.kernels import ProductKernel, kernel_from_spec
    from sympredict.predictor import SymplecticKernelPredictor
    from sympredict.surrogate import HBSurrogate

    settings, arrays = read_container(path, _MODEL_FORMAT)
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
    write_container(path, _DATA_FORMAT, {"metadata": metadata}, arrays)


def load_dataset(path):
    """Load a data set written by :func:`save_dataset`; returns ``(FlowMapData, metadata)``.

    Besides the container's checks, the arrays must be consistent: ``x0`` and
    ``x1`` of one shape ``(M, 2n)``, ``mu`` of shape ``(M, d_mu)``, ``dt`` of
    shape ``(M,)`` and positive, all finite; anything else raises
    :class:`ModelFileError` naming the problem.
    """
    from sympredict.data import FlowMapData

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
        if not np.all(np.isfinite(arr)):
            raise ModelFileError(f"{where}: {name} contains NaN or Inf")
    if x0.ndim != 2 or x0.shape[0] == 0 or x0.shape[1] == 0 or x0.shape[1] % 2:
        raise ModelFileError(f"{where}: x0 must have shape (M, 2n) with M >= 1, got {x0.shape}")
    m = x0.shape[0]
    if x1.shape != x0.shape:
        raise ModelFileError(f"{where}: x1 has shape {x1.shape}, x0 has {x0.shape}")
    if mu.ndim != 2 or mu.shape[0] != m:
        raise ModelFileError(f"{where}: mu must have shape ({m}, d_mu), got {mu.shape}")
    if dt.shape != (m,):
        raise ModelFileError(f"{where}: dt must have shape ({m},), got {dt.shape}")
    if np.any(dt <= 0):
        raise ModelFileError(f"{where}: dt must be positive, min is {float(dt.min())!r}")
    metadata = settings.get("metadata", {})
    if set(settings) != {"metadata"} or not isinstance(metadata, dict):
        raise ModelFileError(f"{where}: its settings must be {{'metadata': {{...}}}}")
    try:
        data = FlowMapData(x0, x1, mu, dt)
    except ValueError as exc:
        raise ModelFileError(f"{where}: {exc}") from None
    return data, metadata
