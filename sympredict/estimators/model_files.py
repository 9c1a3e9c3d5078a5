"""Model files of the kernel estimators: settings as JSON, fitted arrays, checked on the way in.

A model file is a :mod:`sympredict.container` of format :data:`MODEL_FORMAT`:
``settings`` (the layout, the class, its parameters encoded by
:func:`encode_param`, the product kernel's spec, the shapes) and the fitted
arrays (centres, coefficients, residual history, training box).  Files are
hostile input: :func:`from_container` checks every setting against the
estimator's own checks (one schema for constructors and files) and every
array against the settings, and raises :class:`~sympredict.exceptions.ModelFileError`
naming what is wrong.  Only files of layout :data:`MODEL_LAYOUT` are read; files of the earlier,
pre-release layouts are refused with the advice to refit.
"""

from __future__ import annotations

import numpy as np

from sympredict.container import read_container, write_container
from sympredict.estimators.auto import KernelSearch
from sympredict.exceptions import ModelFileError
from sympredict.estimators.fitted import (
    DOMAIN_KEYS,
    FittedDirectFlowMap,
    FittedSymplecticFlowMap,
    check_is_fitted,
    model_coordinates,
    trainer_regularization,
)
from sympredict.interpolation.greedy import GreedyHistory, Trainer, trainer_from_spec
from sympredict.kernels import ProductKernel
from sympredict.kernels.transforms import StateKernelParts, decode_value, encode_value, lower_state_kernel
from sympredict.symplectic.solvers import NewtonSolver
from sympredict.symplectic.updates import UpdateRule

__all__ = [
    "MODEL_FORMAT",
    "MODEL_LAYOUT",
    "save",
    "load",
    "to_container",
    "from_container",
    "encode_param",
    "decode_param",
]

#: ``format`` attribute of model files (:mod:`sympredict.container`).
MODEL_FORMAT = "sympredict-model"

#: Layout of a model file's settings: the parameters of the composed estimator (kernels and their
#: transforms, update rule, trainer, solver).  Layouts 1 and 2 were written by pre-release versions and are
#: not read.
MODEL_LAYOUT = 3


def pre_release_layout(path) -> ModelFileError:
    """The error for a model file of a pre-release layout (1 or 2), which this version does not read."""
    return ModelFileError(
        f"{str(path)!r} was written by a pre-release version of sympredict (model layout 1 or 2), "
        f"which this version does not read: fit the model again and save it (layout {MODEL_LAYOUT})"
    )


def save(model, path, *, overwrite: bool = True) -> None:
    """Write ``model`` to ``path`` atomically (:func:`to_container`); ``overwrite=False`` refuses an existing file."""
    write_container(path, MODEL_FORMAT, *to_container(model), overwrite=overwrite)


def load(cls, path):
    """The ``cls`` model in the file ``path`` (:func:`from_container`)."""
    settings, arrays = read_container(path, MODEL_FORMAT)
    return from_container(cls, settings, arrays, path)


def encode_param(value):
    """A parameter value as JSON: the parts by their specs (update rules by name), kernel-valued settings by
    :func:`~sympredict.kernels.transforms.encode_value`."""
    if isinstance(value, UpdateRule):
        return value.name
    if isinstance(value, NewtonSolver):
        return {"solver": value.get_params(deep=False)}
    if isinstance(value, Trainer):
        return {"trainer": value.spec}
    if isinstance(value, KernelSearch):
        return {"search": {k: list(v) if isinstance(v, tuple) else v for k, v in value.get_params(deep=False).items()}}
    try:
        return encode_value(value)
    except ValueError:
        raise ValueError(f"cannot store the parameter value {value!r} in a model file") from None


def decode_param(value):
    """The parameter value :func:`encode_param` wrote."""
    if isinstance(value, dict) and "trainer" in value:
        return trainer_from_spec(value["trainer"])
    if isinstance(value, dict) and set(value) == {"solver"} and isinstance(value["solver"], dict):
        return NewtonSolver(**value["solver"])
    if isinstance(value, dict) and set(value) == {"search"} and isinstance(value["search"], dict):
        unknown = sorted(set(value["search"]) - set(KernelSearch().get_params(deep=False)))
        if unknown:
            raise ValueError(f"unknown KernelSearch setting(s) {unknown}")
        return KernelSearch(**{k: tuple(v) if isinstance(v, list) else v for k, v in value["search"].items()})
    return decode_value(value)


def _is_int(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _check_file_shape_info(settings: dict, path) -> None:
    """A model file's ``dim``, ``n_mu``, ``dt_fixed`` and ``stop_reason`` settings: types and bounds."""
    dim, n_mu, dt_fixed = settings["dim"], settings["n_mu"], settings["dt_fixed"]
    if not _is_int(dim) or not _is_int(n_mu) or dim < 1 or n_mu < 0:
        raise ModelFileError(
            f"{str(path)!r}: invalid dimensions in its settings: dim={dim!r}, n_mu={n_mu!r} "
            "(integers >= 1 and >= 0 expected)"
        )
    if dt_fixed is not None and (
        isinstance(dt_fixed, bool)
        or not isinstance(dt_fixed, (int, float))
        or not (np.isfinite(dt_fixed) and dt_fixed > 0)
    ):
        raise ModelFileError(f"{str(path)!r}: its setting dt_fixed={dt_fixed!r} must be null or a positive finite step")
    if not isinstance(settings["stop_reason"], str):
        raise ModelFileError(f"{str(path)!r}: its setting stop_reason={settings['stop_reason']!r} must be a string")


def _check_file_history(m: int, h: GreedyHistory, d: dict, path) -> None:
    """A model file's residual history fits its ``m`` centres: ``m + 1`` residuals, ``m`` powers; the training box
    ``d`` is ordered."""
    for name, arr, length in (
        ("train_max_residual", h.train_max_residual, m + 1),
        ("val_max_residual", h.val_max_residual, m + 1),
        ("selected_power", h.selected_power, m),
    ):
        if arr is not None and (arr.ndim != 1 or len(arr) != length or arr.dtype.kind != "f"):
            raise ModelFileError(
                f"{str(path)!r}: its array {name!r} has shape {arr.shape} (dtype {arr.dtype}), "
                f"expected ({length},) floats for {m} centres"
            )
    for lo, hi in (("x_min", "x_max"), ("mu_min", "mu_max"), ("dt_min", "dt_max")):
        if np.any(d[lo] > d[hi]):
            raise ModelFileError(f"{str(path)!r}: its training box has domain_{lo} > domain_{hi}")
    if not d["dt_min"] > 0:
        raise ModelFileError(
            f"{str(path)!r}: its training box has a non-positive step domain_dt_min={float(d['dt_min'])!r}"
        )


def to_container(model) -> tuple:
    """The fitted model as a container's ``(settings, arrays)`` (what :meth:`save` writes): its parameters at fit
    time (with the current solver, a setting read when predicting) and its fitted flow map (``model_``)."""
    check_is_fitted(model)
    fitted = model.model_
    params = dict(model.get_params(deep=False))
    params.update({k: v for k, v in (getattr(model, "fitted_params_", None) or {}).items() if k != "solver"})
    type(model)(**params).check_params()  # the checks load() runs: a file it would refuse is never written
    hist = fitted.history
    settings = {
        "layout": MODEL_LAYOUT,
        "class": type(model).__name__,
        "params": {k: encode_param(v) for k, v in params.items()},
        "kernel": fitted.kernel.spec,
        "dim": fitted.dim,
        "n_mu": fitted.n_mu,
        "dt_fixed": fitted.dt_fixed,
        "stop_reason": hist.stop_reason,
        "choice": {k: encode_param(v) for k, v in _file_choice_of(model, params).items()},
    }
    calibration = getattr(fitted, "error_calibration", None)
    if calibration:  # the error estimate's scale (SymplecticKernelPredictor.rollout(..., return_error=True))
        settings["error_calibration"] = dict(calibration)
    arrays = {"train_max_residual": hist.train_max_residual, "selected_power": hist.selected_power}
    local = getattr(fitted, "error_local", None) if calibration else None
    if local is not None:  # its local scale
        arrays.update(error_local_points=local["points"], error_local_log_ratio=local["log_ratio"])
    residuals = getattr(fitted, "error_residuals", None) if calibration else None
    if residuals is not None:  # its residual part
        arrays.update(error_residual_points=residuals["points"], error_residual_vectors=residuals["vectors"])
    if hist.val_max_residual is not None:
        arrays["val_max_residual"] = hist.val_max_residual
    arrays.update({f"domain_{k}": np.asarray(v) for k, v in fitted.domain.items()})
    arrays.update(fitted.surrogate_arrays())
    return settings, arrays


def from_container(cls, settings, arrays: dict, path):
    """The model of a file's ``(settings, arrays)`` (:func:`~sympredict.container.read_container`)."""
    if isinstance(settings, dict) and settings.get("layout", 1) in (1, 2):
        raise pre_release_layout(path)
    found = settings.get("class") if isinstance(settings, dict) else None
    if found != cls.__name__:
        raise ModelFileError(f"{str(path)!r} holds a {found!r}, not a {cls.__name__}")
    if settings.get("layout") != MODEL_LAYOUT:
        raise ModelFileError(
            f"{str(path)!r} has an unknown model layout {settings.get('layout')!r} "
            f"(this sympredict reads layout {MODEL_LAYOUT})"
        )
    try:
        params = settings["params"]
        if not isinstance(params, dict):
            raise ModelFileError(f"{str(path)!r}: its setting 'params' is not a JSON object")
        decoded = {k: decode_param(v) for k, v in params.items()}
        unknown = sorted(set(decoded) - set(cls().get_params(deep=False)))
        if unknown:
            raise ModelFileError(f"{str(path)!r} has unknown setting(s) {unknown} for a {cls.__name__}")
        model = cls(**decoded)
        try:  # the settings pass the checks of fit (one schema for constructors and files)
            model.check_params()
        except ValueError as exc:
            raise ModelFileError(f"{str(path)!r} has an invalid setting: {exc}") from None
        choice = _file_choice(settings.get("choice", {}), path)
        if choice:
            try:  # the chosen settings pass the same checks
                type(model)(**{**model.get_params(deep=False), **choice}).check_params()
            except ValueError as exc:
                raise ModelFileError(f"{str(path)!r} has an invalid chosen setting: {exc}") from None
        fitted_params = {**model.get_params(deep=False), **choice}
        model.fitted_params_ = dict(model.get_params(deep=False))
        model.choice_, model.search_, model.diagnostics_ = choice, None, None
        kernel = ProductKernel.from_spec(settings["kernel"])
        _check_choice_matches_kernel(choice, kernel, path)
        _check_file_shape_info(settings, path)
        for name, size, key in (("domain_x_min", settings["dim"], "dim"), ("domain_mu_min", settings["n_mu"], "n_mu")):
            box = arrays.get(name)  # before anything is allocated by the file's sizes
            if box is None or box.ndim != 1 or box.shape[0] != size:
                raise ModelFileError(
                    f"{str(path)!r}: its setting {key}={size!r} disagrees with its training box "
                    f"{name!r} of shape {None if box is None else box.shape}"
                )
        dim, n_mu = settings["dim"], settings["n_mu"]
        symplectic = cls.fitted_type is FittedSymplecticFlowMap
        periodic = symmetry = None
        if symplectic:
            parts = lower_state_kernel(fitted_params["state_kernel"])
            parts = StateKernelParts(
                scaling=parts.scaling, periodic=parts.periodic, period=parts.period, symmetry=parts.symmetry
            )
            try:
                _, periodic, symmetry = model_coordinates(parts, fitted_params["update"], dim)
            except ValueError as exc:
                raise ModelFileError(
                    f"{str(path)!r} has an invalid setting for states of dimension {dim}: {exc}"
                ) from None
        if kernel.periodic != periodic:
            raise ModelFileError(
                f"the file's periodic coordinates {kernel.periodic!r} disagree with its setting "
                f"state_kernel={model.state_kernel!r}"
            )
        if kernel.symmetry != symmetry:
            raise ModelFileError(
                f"the file's state symmetry {kernel.symmetry!r} disagrees with its setting "
                f"state_kernel={model.state_kernel!r}"
            )
        check_file_arrays(dim, n_mu, symplectic, kernel, arrays)
        surrogate = cls.fitted_type.surrogate_from_arrays(kernel, arrays, dim, n_mu)
        n = len(arrays["selected_power"])
        history = GreedyHistory(
            train_max_residual=arrays["train_max_residual"],
            val_max_residual=arrays.get("val_max_residual"),
            selected_power=arrays["selected_power"],
            elapsed=np.full(n, np.nan),  # timings are not stored
            stop_reason=settings["stop_reason"],
        )
        calibration = settings.get("error_calibration")
        if calibration is not None and not (
            isinstance(calibration, dict) and isinstance(calibration.get("scale"), float) and calibration["scale"] > 0
        ):
            raise ModelFileError(f"{str(path)!r}: its error_calibration is not a record with a positive 'scale'")
        local = _file_error_local(arrays, calibration, dim + n_mu + 1, path)
        residuals = _file_error_residuals(arrays, calibration, dim, n_mu, path)
        domain = {k: arrays[f"domain_{k}"] for k in DOMAIN_KEYS}
        _check_file_history(surrogate.n_centers, history, domain, path)
        if symplectic:  # the fitted flow map, by its public constructor (as fit builds it)
            model.model_ = FittedSymplecticFlowMap(
                kernel,
                surrogate,
                domain=domain,
                history=history,
                dt_fixed=settings["dt_fixed"],
                update=fitted_params["update"],
                parts=parts,
                solver=model.solver,
                regularization=trainer_regularization(fitted_params["trainer"]),
                error_calibration=calibration,
                error_local=local,
                error_residuals=residuals,
            )
        else:
            model.model_ = FittedDirectFlowMap(
                kernel, surrogate, domain=domain, history=history, dt_fixed=settings["dt_fixed"]
            )
    except ModelFileError:
        raise
    except (KeyError, TypeError, ValueError, AttributeError, IndexError, OverflowError, RecursionError) as exc:
        raise ModelFileError(f"{str(path)!r} is an incomplete or inconsistent sympredict model file: {exc!r}") from None
    return model


def _file_error_local(arrays: dict, calibration, width: int, path):
    """The error estimate's local scale of a model file (``error_local_points`` (N, 2n + d_mu + 1) and
    ``error_local_log_ratio`` (N,), with the calibration's ``local_neighbours`` in 1..N), or ``None`` for a file
    without it (written before it existed, or by a fit without enough held-out samples)."""
    names = ("error_local_points", "error_local_log_ratio")
    present = [name in arrays for name in names]
    k = calibration.get("local_neighbours") if isinstance(calibration, dict) else None
    if not any(present) and k is None:
        return None
    if not all(present) or k is None:
        raise ModelFileError(
            f"{str(path)!r}: its error estimate's local scale is incomplete (it needs the arrays {list(names)} "
            "and the error_calibration's 'local_neighbours')"
        )
    points, log_ratio = arrays["error_local_points"], arrays["error_local_log_ratio"]
    n = len(log_ratio)
    if points.ndim != 2 or points.shape != (n, width) or log_ratio.ndim != 1 or points.dtype.kind != "f":
        raise ModelFileError(
            f"{str(path)!r}: its error_local_points of shape {points.shape} and error_local_log_ratio of shape "
            f"{log_ratio.shape} are not (N, {width}) and (N,) float arrays"
        )
    if type(k) is not int or not 1 <= k <= n:
        raise ModelFileError(
            f"{str(path)!r}: its error_calibration's local_neighbours={k!r} is not an integer in 1..{n}"
        )
    return {"points": points.astype(float), "log_ratio": log_ratio.astype(float)}


def _file_choice_of(model, params: dict) -> dict:
    """What the file keeps as ``choice``: the fit's ``choice_``, and the fitted update where ``update=None`` (a
    fitted state assembled by hand has no ``choice_``)."""
    choice = dict(getattr(model, "choice_", None) or {})
    if "update" in params and params["update"] is None and "update" not in choice:
        choice["update"] = model.update_
    return choice


#: What a fit may choose (:class:`~sympredict.estimators.auto.KernelSearch`), stored as the file's ``choice``.
CHOSEN_SETTINGS = ("state_kernel", "mu_kernel", "dt_kernel", "update")


def _file_choice(raw, path) -> dict:
    """The decoded ``choice`` of a model file: only settings a fit chooses."""
    if not isinstance(raw, dict):
        raise ModelFileError(f"{str(path)!r}: its setting 'choice' is not a JSON object")
    unknown = sorted(set(raw) - set(CHOSEN_SETTINGS))
    if unknown:
        raise ModelFileError(f"{str(path)!r}: its 'choice' holds settings a fit does not choose: {unknown}")
    return {k: decode_param(v) for k, v in raw.items()}


def _check_choice_matches_kernel(choice: dict, kernel: ProductKernel, path) -> None:
    """The chosen kernels are the file's product kernel (the kernel predictions use)."""
    pairs = [
        (
            "state_kernel",
            lower_state_kernel(choice["state_kernel"]).radial if "state_kernel" in choice else None,
            kernel.state,
        ),
        ("mu_kernel", choice.get("mu_kernel"), kernel.mu),
        ("dt_kernel", choice.get("dt_kernel"), kernel.dt),
    ]
    for name, chosen, used in pairs:
        if name in choice and chosen != used:
            raise ModelFileError(f"{str(path)!r}: its chosen {name} {chosen!r} disagrees with its kernel {used!r}")


def check_file_arrays(dim: int, n_mu: int, symplectic: bool, kernel: ProductKernel, arrays: dict) -> None:
    """Consistency of a model file's arrays with its settings (files are hostile input)."""
    if dim < 1 or n_mu < 0 or (symplectic and dim % 2):
        raise ModelFileError(f"invalid dimensions in the file: dim={dim}, n_mu={n_mu}")
    if (kernel.mu is None) != (n_mu == 0):
        raise ModelFileError("the file's mu kernel and parameter dimension disagree")
    for name, shape in (
        ("domain_x_min", (dim,)),
        ("domain_x_max", (dim,)),
        ("domain_mu_min", (n_mu,)),
        ("domain_mu_max", (n_mu,)),
        ("domain_dt_min", ()),
        ("domain_dt_max", ()),
    ):
        arr = arrays.get(name)
        if arr is None or arr.shape != shape or not np.all(np.isfinite(arr)):
            raise ModelFileError(f"the file's training box {name!r} is missing, of the wrong shape or not finite")
    for name, arr in arrays.items():
        if arr.dtype.kind not in "fi" or not np.all(np.isfinite(arr)):
            raise ModelFileError(f"the file's array {name!r} is not a finite numeric array")


def _file_error_residuals(arrays: dict, calibration, dim: int, n_mu: int, path):
    """The error estimate's residual part of a model file (``error_residual_points`` (N, 2n + d_mu + 1) and
    ``error_residual_vectors`` (N, 2n), finite floats, with the calibration's ``residual_neighbours`` in 1..N and a
    positive finite ``residual_scale``), or ``None`` for a file without it (written before it existed, or by a fit
    without enough samples)."""
    names = ("error_residual_points", "error_residual_vectors")
    present = [name in arrays for name in names]
    cal = calibration if isinstance(calibration, dict) else {}
    k, c = cal.get("residual_neighbours"), cal.get("residual_scale")
    if not any(present) and k is None and c is None:
        return None
    if not all(present) or k is None or c is None:
        raise ModelFileError(
            f"{str(path)!r}: its error estimate's residual part is incomplete (it needs the arrays {list(names)} "
            "and the error_calibration's 'residual_neighbours' and 'residual_scale')"
        )
    points, vectors = arrays["error_residual_points"], arrays["error_residual_vectors"]
    n, width = len(vectors), dim + n_mu + 1
    if (
        points.ndim != 2
        or points.shape != (n, width)
        or vectors.shape != (n, dim)
        or points.dtype.kind != "f"
        or vectors.dtype.kind != "f"
    ):
        raise ModelFileError(
            f"{str(path)!r}: its error_residual_points of shape {points.shape} and error_residual_vectors of shape "
            f"{vectors.shape} are not (N, {width}) and (N, {dim}) float arrays"
        )
    if not (np.all(np.isfinite(points)) and np.all(np.isfinite(vectors))):
        raise ModelFileError(f"{str(path)!r}: its error_residual_points or error_residual_vectors are not finite")
    if type(k) is not int or not 1 <= k <= n:
        raise ModelFileError(
            f"{str(path)!r}: its error_calibration's residual_neighbours={k!r} is not an integer in 1..{n}"
        )
    if not isinstance(c, float) or not (np.isfinite(c) and c > 0):
        raise ModelFileError(f"{str(path)!r}: its error_calibration's residual_scale={c!r} is not a positive float")
    # the posterior part's share beside the residual part; files written before it: the posterior at its full scale
    share, distance = cal.get("posterior_share"), cal.get("share_distance")
    if (share is None) != (distance is None):
        raise ModelFileError(
            f"{str(path)!r}: its error_calibration has only one of 'posterior_share' and 'share_distance' (both or none)"
        )
    if share is not None and (not isinstance(share, float) or not (np.isfinite(share) and 0 < share <= 1)):
        raise ModelFileError(
            f"{str(path)!r}: its error_calibration's posterior_share={share!r} is not a float in (0, 1]"
        )
    if distance is not None and (not isinstance(distance, float) or not (np.isfinite(distance) and distance > 0)):
        raise ModelFileError(
            f"{str(path)!r}: its error_calibration's share_distance={distance!r} is not a positive float"
        )
    return {"points": points.astype(float), "vectors": vectors.astype(float)}
