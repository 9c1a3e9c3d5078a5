"""The fitted flow map of a kernel estimator: one frozen object that predicts.

:class:`FittedSymplecticFlowMap` (what :meth:`SymplecticKernelPredictor.fit
<sympredict.estimators.predictor.SymplecticKernelPredictor.fit>` sets as ``model_``) holds the surrogate, the
kernel, the update rule, the state kernel's transforms flattened, the Newton solver, the training box and the
greedy's history; it offers :meth:`~FittedSymplecticFlowMap.step`, :meth:`~FittedSymplecticFlowMap.rollout`
(with the wrappers' hook ``around``), :meth:`~FittedSymplecticFlowMap.step_jacobian`, the error estimate, the
extrapolation warnings and the prefixes :meth:`~FittedSymplecticFlowMap.truncated` /
:meth:`~FittedSymplecticFlowMap.smallest`.  :class:`FittedDirectFlowMap` is the direct (explicit, not symplectic)
baseline's.  Both are built by their public constructors, by the estimators' ``fit`` and by model files alike
(:mod:`sympredict.estimators.model_files`), and are frozen: ``with_solver`` and ``truncated`` return new ones.
"""

from __future__ import annotations

import copy
import warnings
from typing import Optional

import numpy as np

from sympredict._checks import Constraint, as_even_dimension, as_model_parameter, as_positive_int, as_states, as_steps
from sympredict.data import FlowMapData
from sympredict.exceptions import (
    ExtrapolationWarning,
    ModelFileError,
    NewtonConvergenceError,
    NonFinitePredictionError,
    SolvabilityError,
)
from sympredict.exceptions import NotFittedError
from sympredict.estimators.error_estimate import (
    LOCAL_NEIGHBOURS,
    RESIDUAL_NEIGHBOURS,
    SHARE_DISTANCE_QUANTILE,
    kth_distance,
    local_covariance,
    local_error_units,
    local_log_ratio,
    local_points,
    nearest,
    posterior_share,
    ResidualNeighbours,
    rollout_error_units,
)
from sympredict.interpolation.greedy import GreedyHistory
from sympredict.interpolation.greedy.trainers import ExactGreedy
from sympredict.interpolation.surrogate import HBSurrogate, ValueSurrogate
from sympredict.kernels.transforms import StateKernelParts
from sympredict.symplectic.newton import (
    WARM_HISTORY,
    implicit_rollout,
    ordered_weights,
    rollout_in_chunks,
    rollout_numpy,
)
from sympredict.symplectic.solvers import NewtonSolver
from sympredict.symplectic.updates import as_update

__all__ = [
    "FittedFlowMap",
    "FittedSymplecticFlowMap",
    "FittedDirectFlowMap",
    "NUMPY_ONLY",
    "numpy_only_reason",
    "EXTRAPOLATION_TOLERANCE",
    "check_finite",
    "check_is_fitted",
    "model_coordinates",
    "trainer_regularization",
    "training_box",
]

#: Model features that only the NumPy solver runs: ``(test of the flattened state kernel and the update rule,
#: reason)``.  The one place that says which combination runs on which backend: ``NewtonSolver(backend='numba')``
#: is refused for them at fit (naming the fix), ``'auto'`` uses NumPy and the fitted model says so (``numpy_only_``).
#: Every transform (:class:`~sympredict.kernels.transforms.Scaled`, ``Periodic``, ``Symmetric``) and both updates
#: run compiled; what remains is an update rule added from outside whose compiled kernel does not exist
#: (:attr:`~sympredict.symplectic.updates.UpdateRule.compiled` false): the compiled solver dispatches on the
#: package's rules only.
NUMPY_ONLY = ((lambda parts, rule: not rule.compiled, "this update rule has no compiled solver yet"),)


def numpy_only_reason(parts, rule) -> Optional[str]:
    """Why a model of these state-kernel ``parts`` and update ``rule`` has no compiled solver (the features of
    :data:`NUMPY_ONLY` it has, joined), or ``None``."""
    reasons = [reason for applies, reason in NUMPY_ONLY if applies(parts, rule)]
    return "; ".join(reasons) if reasons else None


#: How far (a fraction of the training box's width, per state coordinate) a state may lie outside the box of the
#: training states before :class:`~sympredict.exceptions.ExtrapolationWarning` calls it an extrapolation: test
#: orbits drawn like the training trajectories overshoot the box by a little (a longer orbit, a phase the data
#: did not reach); 5 % is where the kernel's data still surround the state.
EXTRAPOLATION_TOLERANCE = 0.05

#: The ``solver`` setting's row of the estimator's table of settings, read here too when a prediction swaps the
#: solver (one rule, one message).
SOLVER_SETTING = Constraint(
    NewtonSolver,
    check=lambda solver, name: solver.check(),
    expected="a NewtonSolver (e.g. NewtonSolver(backend='numba')) or None",
)

#: The keys of a training box (``domain``).
DOMAIN_KEYS = ("x_min", "x_max", "mu_min", "mu_max", "dt_min", "dt_max")


#: The numpydoc entries of the states, parameters and steps that the predictions other than ``step`` take as it does.
_QUERY_PARAMETERS = """x : array_like of shape (B, 2n) or (2n,)
            States ``(q, p)``, one per row (or a single state).
        mu, dt : float or array_like, default=None
            Parameters and macro steps, as in :meth:`step`."""


def _query_documented(method):
    """Put :data:`_QUERY_PARAMETERS` where ``method``'s docstring says ``{query}`` (one text for every such method)."""
    method.__doc__ = method.__doc__.replace("{query}", _QUERY_PARAMETERS)
    return method


def _fmt(v) -> str:
    """A short component-wise rendering of a parameter vector."""
    v = np.atleast_1d(v)
    return f"{v[0]:.6g}" if v.size == 1 else "(" + ", ".join(f"{a:.6g}" for a in v) + ")"


def check_finite(out: np.ndarray, what: str) -> np.ndarray:
    """``out`` (B, ...) if finite; :class:`NonFinitePredictionError` naming the instances and ``what`` otherwise."""
    finite = np.isfinite(out)
    if not finite.all():
        bad = np.flatnonzero(~finite.reshape(len(out), -1).all(axis=1))
        raise NonFinitePredictionError(bad, what)
    return out


def check_is_fitted(estimator) -> None:
    """:class:`~sympredict.exceptions.NotFittedError` unless ``estimator`` holds a fitted flow map (``model_``)."""
    if "model_" not in vars(estimator):
        raise NotFittedError(f"this {type(estimator).__name__} is not fitted yet: call fit() or load() first")


def trainer_regularization(trainer) -> float:
    """The ridge term of a training strategy (``None``: the default ``ExactGreedy()``'s): the error estimate's."""
    trainer = ExactGreedy() if trainer is None else trainer
    return float(getattr(trainer, "regularization", 0.0) or 0.0)


def model_coordinates(parts: StateKernelParts, update, dim: int):
    """``(scale, periodic, symmetry)`` of a flattened state kernel for states of dimension ``dim``: the scaling
    vector (2n,), the model's periodic coordinates and state symmetry; ``ValueError`` naming a setting that does
    not fit ``dim`` (one check for fits and model files)."""
    as_even_dimension(dim)
    return parts.scale_vector(dim), parts.model_periodic(dim), parts.model_symmetry(dim, as_update(update))


def training_box(data: FlowMapData) -> dict:
    """The training box of flow-map samples: bounds of the states ``x0`` and ``x1``, of ``mu`` and of ``dt``."""
    states = np.concatenate([data.x0, data.x1])
    return {
        "x_min": states.min(axis=0),
        "x_max": states.max(axis=0),
        "mu_min": data.mu.min(axis=0),
        "mu_max": data.mu.max(axis=0),
        "dt_min": np.array(data.dt.min()),
        "dt_max": np.array(data.dt.max()),
    }


class FittedFlowMap:
    """What the fitted kernel flow maps share: the query checks, the training box and its warnings, the history.

    Parameters
    ----------
    kernel : ProductKernel
        The kernel the surrogate was trained with.
    surrogate : HBSurrogate or ValueSurrogate
        Centres and coefficients.
    domain : dict
        The training box (:data:`DOMAIN_KEYS`): ``x_min``, ``x_max`` of shape (2n,), ``mu_min``, ``mu_max`` of
        shape (d_mu,), ``dt_min``, ``dt_max`` scalars.  The state and parameter dimensions are its lengths.
    history : GreedyHistory
        The greedy's residual curves and stop reason.
    dt_fixed : float or None
        The one training step of a fixed-step model (no step kernel), else ``None``.
    greedy_result : GreedyResult or None
        The greedy's selection and Newton data (``None`` for a model read from a file: it cannot be truncated).

    Frozen: its attributes are set by the constructor only.
    """

    name = "model"

    def __init__(self, kernel, surrogate, *, domain: dict, history: GreedyHistory, dt_fixed=None, greedy_result=None):
        self._set(
            kernel=kernel,
            surrogate=surrogate,
            domain=dict(domain),
            history=history,
            dt_fixed=None if dt_fixed is None else float(dt_fixed),
            greedy_result=greedy_result,
            dim=int(len(domain["x_min"])),
            n_mu=int(len(domain["mu_min"])),
        )

    def _set(self, **values) -> None:
        for name, value in values.items():
            object.__setattr__(self, name, value)

    def __setattr__(self, name, value):
        raise AttributeError(
            f"a {type(self).__name__} is frozen: {name!r} is set by its constructor (fit the "
            "estimator again, or use with_solver / truncated for a changed copy)"
        )

    def _replace(self, **values):
        new = copy.copy(self)
        new._set(**values)
        return new

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.n_centers} centres, dim={self.dim}, n_mu={self.n_mu})"

    @property
    def n_centers(self) -> int:
        return self.surrogate.n_centers

    def _what(self) -> str:
        return f"this {self.name}"

    # -------------------------------------------------------------- queries
    def _query(self, x, mu, dt, name: str = "x"):
        """Validate a query; returns states (B, 2n), single flag, mu (B, d_mu), dt (B,)."""
        x, single = as_states(x, name, dim=self.dim)
        b = len(x)
        mu_arr = as_model_parameter(mu, b, self.n_mu)
        if self.dt_fixed is not None:
            if dt is None:
                dt = self.dt_fixed
            dt_arr = as_steps(dt, b)
            if np.any(dt_arr != self.dt_fixed):
                raise ValueError(
                    f"this model was trained for the fixed step dt={self.dt_fixed!r} (dt_kernel=None); "
                    f"got dt={[float(v) for v in np.unique(dt_arr)[:5]]}"
                )
        else:
            dt_arr = as_steps(dt, b)
        self._warn_outside(mu_arr, dt_arr, x)
        return x, single, mu_arr, dt_arr

    def original_periods(self):
        """``(coordinates, periods)`` of angle coordinates in the original state coordinates (none here)."""
        return (), ()

    def _excess(self, x: np.ndarray) -> np.ndarray:
        """How far each state lies outside the box of the training states ``x0`` and ``x1``, per coordinate, in
        units of the box's width there (0 inside; an angle of ``Periodic`` is inside when one of its
        representatives is).  ``x`` of shape (..., 2n); returns the same shape.  A coordinate the data do not
        vary has width 0: there the unit is ``1 + |x_min|`` (any change is news)."""
        lo, hi = self.domain["x_min"], self.domain["x_max"]
        coords, periods = self.original_periods()
        x = np.array(x, dtype=float)
        for i, period in zip(coords, periods):
            x[..., i] = lo[i] + np.mod(x[..., i] - lo[i], period)
        width = hi - lo
        unit = np.where(width > 0, width, 1.0 + np.abs(lo))
        with np.errstate(invalid="ignore"):
            return np.maximum(np.maximum(lo - x, x - hi), 0.0) / unit

    def outside_states(self, x: np.ndarray) -> np.ndarray:
        """Which states lie outside the training box by more than :data:`EXTRAPOLATION_TOLERANCE` of its width in
        some coordinate.  ``x`` of shape (..., 2n); returns a bool array of shape (...)."""
        with np.errstate(invalid="ignore"):
            return np.any(self._excess(x) > EXTRAPOLATION_TOLERANCE, axis=-1)

    def _leaving_message(self, x: np.ndarray) -> str:
        """``coordinate i by v (f % of the box's width)`` for the coordinate that left the box farthest among ``x``
        (..., 2n), the training box's bounds there, and which instance."""
        excess = np.nan_to_num(self._excess(x), nan=0.0).reshape(-1, x.shape[-1])
        row, col = np.unravel_index(int(np.argmax(excess)), excess.shape)
        lo, hi = self.domain["x_min"][col], self.domain["x_max"][col]
        value = x.reshape(-1, x.shape[-1])[row, col]
        beyond = value - hi if value > hi else lo - value
        n = x.shape[-1] // 2
        name = f"q{col + 1}" if col < n else f"p{col - n + 1}"
        return (
            f"state coordinate {col} ({name}) left the box [{lo:.6g}, {hi:.6g}] by {beyond:.3g} "
            f"({100 * excess[row, col]:.1f} % of its width)"
        )

    def _warn_if_trajectory_leaves(self, traj: np.ndarray, stride: int = 1) -> None:
        """Warn when a rollout that starts inside the training states leaves them (it extrapolates from there on).

        Inside means within :data:`EXTRAPOLATION_TOLERANCE` of the box's width per coordinate: a trajectory
        drawn like the training ones may overshoot the box by a little without leaving what the model learned.
        The message names the instances, the first step outside, and the coordinate that left farthest and by
        how much.  One pass of comparisons over ``traj`` (B, K/stride+1, 2n), the states kept every ``stride``
        steps: ``O(B K 2n / stride)``, small next to the rollout.
        """
        outside = self.outside_states(traj)
        left = outside[:, 1:].any(axis=1) & ~outside[:, 0]
        if np.any(left):
            first = (np.argmax(outside[left, 1:], axis=1) + 1) * stride
            warnings.warn(
                f"extrapolation: {int(left.sum())} of {len(traj)} trajectories leave the training states "
                f"{_fmt(self.domain['x_min'])}..{_fmt(self.domain['x_max'])} by more than "
                f"{100 * EXTRAPOLATION_TOLERANCE:g} % of the box's width (instances {np.flatnonzero(left)[:5].tolist()}"
                f"{'...' if left.sum() > 5 else ''}, first at step {int(first.min())}; "
                f"{self._leaving_message(traj[left])}); the prediction from there on "
                "is an extrapolation",
                ExtrapolationWarning,
                stacklevel=4,
            )

    def _warn_outside(self, mu, dt, x):
        d = self.domain
        outside = []
        lo, hi = d["x_min"], d["x_max"]
        if np.any(self.outside_states(x)):
            outside.append(
                f"query states span {_fmt(x.min(axis=0))}..{_fmt(x.max(axis=0))}, "
                f"training states {_fmt(lo)}..{_fmt(hi)} ({self._leaving_message(x)})"
            )
        if mu.shape[1] and (np.any(mu < d["mu_min"]) or np.any(mu > d["mu_max"])):
            outside.append(
                f"query mu spans {_fmt(mu.min(axis=0))}..{_fmt(mu.max(axis=0))}, "
                f"training box {_fmt(d['mu_min'])}..{_fmt(d['mu_max'])}"
            )
        if self.dt_fixed is None and (np.any(dt < d["dt_min"]) or np.any(dt > d["dt_max"])):
            outside.append(
                f"query dt spans {dt.min():.6g}..{dt.max():.6g}, training range {float(d['dt_min']):.6g}..{float(d['dt_max']):.6g}"
            )
        if outside:
            warnings.warn("extrapolation: " + "; ".join(outside), ExtrapolationWarning, stacklevel=5)

    def _history_prefix(self, n_centers: int) -> GreedyHistory:
        h = self.history
        return GreedyHistory(
            train_max_residual=h.train_max_residual[: n_centers + 1],
            val_max_residual=None if h.val_max_residual is None else h.val_max_residual[: n_centers + 1],
            selected_power=h.selected_power[:n_centers],
            elapsed=h.elapsed[:n_centers],
            stop_reason=f"truncated to {n_centers} of {self.n_centers} centres",
        )

    # ----------------------------------------------------------------- files
    #: The surrogate's class (:mod:`sympredict.interpolation.surrogate`), and its arrays as a model file stores them:
    #: ``name -> shape``, in ``m`` (centres), ``dim`` (``2n``) and ``n_mu``, in the order of its constructor.
    surrogate_type, surrogate_layout = None, {}
    #: The centres' parameters and steps (what the weights of a query are computed from), in every surrogate.
    centre_weights_layout = {"centers_mu": ("m", "n_mu"), "centers_dt": ("m",)}

    def surrogate_arrays(self) -> dict:
        """The surrogate's arrays as a model file stores them (:attr:`surrogate_layout`)."""
        return {name: getattr(self.surrogate, name) for name in self.surrogate_layout}

    @classmethod
    def surrogate_from_arrays(cls, kernel, arrays: dict, dim: int, n_mu: int):
        """The surrogate of a model file's arrays (:meth:`surrogate_arrays`), their shapes and values checked."""
        sizes = {"m": len(arrays["coef"]), "dim": dim, "n_mu": n_mu}
        for name, layout in cls.surrogate_layout.items():
            shape = tuple(sizes[size] for size in layout)
            if arrays[name].shape != shape:
                raise ModelFileError(f"the file's {name!r} has shape {arrays[name].shape}, expected {shape}")
        cls._check_surrogate_values(arrays, dim)
        return cls.surrogate_type(kernel, *(arrays[name] for name in cls.surrogate_layout))

    @staticmethod
    def _check_surrogate_values(arrays: dict, dim: int) -> None:
        """``ModelFileError`` for a file's surrogate arrays of the right shapes but unusable values."""


class FittedDirectFlowMap(FittedFlowMap):
    """The fitted direct (explicit, non-symplectic) flow map ``x1 = x0 + r(x0, mu, dT)`` of
    :class:`~sympredict.estimators.predictor.DirectKernelPredictor` (parameters as :class:`FittedFlowMap`, with a
    :class:`~sympredict.interpolation.surrogate.ValueSurrogate`)."""

    name = "DirectKernelPredictor"
    surrogate_type = ValueSurrogate
    surrogate_layout = {"centers_x": ("m", "dim"), **FittedFlowMap.centre_weights_layout, "coef": ("m", "dim")}

    def _advance(self, x, weights, dt):
        return x + self.surrogate.value(x, weights)

    def step(self, x, mu=None, dt=None) -> np.ndarray:
        """One explicit predicted step, shape of ``x`` ((B, 2n) or (2n,))."""
        x, single, mu, dt = self._query(x, mu, dt)
        out = check_finite(self._advance(x, self.surrogate.weights(mu, dt), dt), self._what())
        return out[0] if single else out

    def rollout(self, x0, n_steps: int, mu=None, dt=None, *, stride: int = 1, progress=None) -> np.ndarray:
        """Trajectories (B, K // stride + 1, 2n) of ``n_steps`` explicit steps, every ``stride``-th state kept.

        ``stride`` and ``progress`` as in :meth:`FittedSymplecticFlowMap.rollout`; ``O(K B m 2n)``.
        """
        n_steps = as_positive_int(n_steps, "n_steps", minimum=0)
        stride = as_positive_int(stride, "stride")
        x, single, mu, dt = self._query(x0, mu, dt, name="x0")
        weights = self.surrogate.weights(mu, dt)
        traj = rollout_in_chunks(
            lambda state, k: rollout_numpy(lambda s: self._advance(s, weights, dt), state, k),
            x,
            n_steps,
            stride=stride,
            progress=progress,
        )
        traj = check_finite(traj, self._what())
        self._warn_if_trajectory_leaves(traj, stride)
        return traj[0] if single else traj


class FittedSymplecticFlowMap(FittedFlowMap):
    """The fitted symplectic flow map of :class:`~sympredict.estimators.predictor.SymplecticKernelPredictor`.

    Parameters
    ----------
    kernel, surrogate, domain, history, dt_fixed, greedy_result
        As in :class:`FittedFlowMap` (``surrogate`` an :class:`~sympredict.interpolation.surrogate.HBSurrogate`).
    update : str or UpdateRule
        The generating-function update the surrogate was trained for.
    parts : StateKernelParts
        The state kernel's transforms, flattened (scaling factors, periodic coordinates and periods, symmetry).
    solver : NewtonSolver, optional
        The Newton solver of :meth:`step` and :meth:`rollout` (``None``: ``NewtonSolver()``); :meth:`with_solver`
        gives a copy with another.
    regularization : float
        The trainer's ridge term (the error estimate's Gramian).
    error_calibration : dict or None, optional
        The error estimate's calibration (:attr:`error_calibration`); omitted, it is computed on first use
        from ``calibration_samples``.
    calibration_samples : tuple ``(FlowMapData, str)`` or None
        Held-out samples and where they come from, for the calibration computed on first use.
    error_local : dict or None, optional
        The error estimate's local scale (:attr:`error_local`), with ``error_calibration``: ``points``
        (N, 2n + d_mu + 1), the held-out samples' states, parameters and steps, and ``log_ratio`` (N,), the log of
        true one-step error over estimate there (centred); ``None``: one scale everywhere (a model file written
        before the local scale existed).
    residual_samples : FlowMapData or None, optional
        Samples the model's one-step residual vectors are taken on when the calibration is computed (held-out
        samples and training samples that are not centres, :meth:`residual_data`); ``None``: the calibration's
        samples.
    error_residuals : dict or None, optional
        The residual part of the error estimate (:attr:`error_residuals`), with ``error_calibration``: ``points``
        (N, 2n + d_mu + 1) and ``vectors`` (N, 2n); ``None``: none (a model file written before it existed).
    """

    name = "SymplecticKernelPredictor"
    surrogate_type = HBSurrogate
    surrogate_layout = {
        "centers_xi": ("m", "dim"),
        **FittedFlowMap.centre_weights_layout,
        "components": ("m",),
        "coef": ("m",),
    }
    #: Quantile of the held-out ratios (true one-step error / power-function estimate) used as the scale.
    ERROR_QUANTILE = 0.9
    #: Samples the calibration uses at most (``O(n 2n m^2)``).
    ERROR_SAMPLES = 500
    #: Residual vectors kept at most (one predicted step each to compute; the rollout's estimate searches them).
    RESIDUAL_SAMPLES = 4000

    def __init__(
        self,
        kernel,
        surrogate,
        *,
        domain: dict,
        history: GreedyHistory,
        update,
        parts: StateKernelParts = StateKernelParts(),
        dt_fixed=None,
        greedy_result=None,
        solver: Optional[NewtonSolver] = None,
        regularization: float = 0.0,
        error_calibration=...,
        calibration_samples=None,
        error_local=None,
        residual_samples=None,
        error_residuals=None,
    ):
        super().__init__(
            kernel, surrogate, domain=domain, history=history, dt_fixed=dt_fixed, greedy_result=greedy_result
        )
        scale, periodic, symmetry = model_coordinates(parts, update, self.dim)
        cache = (
            {}
            if error_calibration is ...
            else {"calibration": error_calibration, "local": error_local, "residuals": error_residuals}
        )
        self._set(
            update=update,
            rule=as_update(update),
            parts=parts,
            scale=scale,
            model_periodic=periodic,
            model_symmetry=symmetry,
            solver=NewtonSolver() if solver is None else solver,
            _solver_setting=solver,
            regularization=float(regularization or 0.0),
            calibration_samples=calibration_samples,
            residual_samples=residual_samples,
            _cache=cache,
        )

    def with_solver(self, solver: Optional[NewtonSolver]) -> "FittedSymplecticFlowMap":
        """This fitted map with the Newton solver ``solver`` (``None``: the default), checked; the arrays and caches
        are shared.  The setting this map was made with returns the map itself (a prediction's per-call cost; its
        values are checked where they are used, ``max_iter`` by every solve)."""
        if solver is self._solver_setting:
            return self
        checked = SOLVER_SETTING.validate("solver", solver) or NewtonSolver().check()
        return self._replace(solver=checked, _solver_setting=solver)

    def with_error_calibration(self, calibration: Optional[dict]) -> "FittedSymplecticFlowMap":
        """This fitted map with the error calibration ``calibration`` (``None``: no error estimate); the local
        scale (:attr:`error_local`) is kept where ``calibration`` has ``local_neighbours``, the residual part
        (:attr:`error_residuals`) where it has ``residual_neighbours``, each dropped otherwise."""
        has = lambda key: isinstance(calibration, dict) and key in calibration
        local = self.error_local if has("local_neighbours") else None
        residuals = self.error_residuals if has("residual_neighbours") else None
        return self._replace(_cache={"calibration": calibration, "local": local, "residuals": residuals})

    def original_periods(self):
        return self.parts.original_periods(self.dim)

    @property
    def numpy_only(self) -> Optional[str]:
        """Why this model has no compiled solver (:data:`NUMPY_ONLY`), or ``None``."""
        return numpy_only_reason(self.parts, self.rule)

    def backend_for(self, n_instances: int = 1, n_steps: int = 1) -> str:
        """The code :meth:`step` / :meth:`rollout` run for this much work: ``'numpy'`` or ``'numba'``.

        The solver's rule (:meth:`~sympredict.symplectic.solvers.NewtonSolver.backend_for`): ``'numpy'`` or
        ``'numba'`` decide alone; ``'auto'`` uses NumPy without numba, for a model with a NumPy-only
        feature (``numpy_only_``), or when NumPy is estimated at under
        :data:`~sympredict.symplectic.solvers.AUTO_NUMPY_SECONDS` and this process has not loaded the compiled
        rollout yet; compiled code otherwise.  Each call logs its choice at DEBUG level
        (logger ``sympredict.estimators.predictor``).
        """
        return "numba" if self.compiled(int(n_instances), int(n_steps)) else "numpy"

    def compiled(self, n_instances: Optional[int] = None, n_steps: int = 1, *, by_size: bool = False) -> bool:
        """Whether :meth:`step` / :meth:`rollout` use the compiled solver (resolves the solver's ``backend``;
        ``by_size``: :meth:`~sympredict.symplectic.solvers.NewtonSolver.compiled`'s)."""
        return self.solver.compiled(
            n_instances, n_steps, self.surrogate.n_centers, self.dim, self.numpy_only, by_size=by_size
        )

    # ------------------------------------------------------------ stepping
    def _rollout(self, x, weights, dt, n_steps: int, around=None, *, stride: int = 1, progress=None) -> np.ndarray:
        """Kept states (B, K/stride+1, 2n) of a validated batch; ``around = (pre, post)`` (B, 2n, 2n): steps
        ``x_k+1 = post Phi(pre x_k)`` in the original coordinates (the splitting predictor's composition).

        Runs in chunks (:func:`~sympredict.symplectic.newton.rollout_in_chunks`: Ctrl-C and progress between them),
        each chunk one NumPy loop or one compiled call; without ``around`` the chunks work in the model's
        (scaled) coordinates, so chunking does not change the result.
        """
        scale = self.scale
        solver, update = self.solver, self.rule.name
        max_iter = solver.iterations()
        compiled = self.compiled(len(x), n_steps)
        backend = "numba" if compiled else "numpy"
        if compiled:  # the chunks share the weights in the compiled centre order: permuted once
            weights = ordered_weights(self.surrogate, weights)
        if around is not None:  # Phi = D^-1 Phi_scaled D: pre becomes D pre, post becomes post D^-1
            pre, post = around
            pre, post = pre * scale[None, :, None], post / scale[None, None, :]
            # no warm start here (its extrapolation would mix x_k and pre x_k); states in the original coordinates
            options, start, history = {"around": (pre, post)}, x, 0
        else:
            warm = bool(solver.warm_start)
            options, start, history = {"warm_start": warm}, x * scale, WARM_HISTORY if warm else 0

        def run(state, k, previous=None):
            return implicit_rollout(
                self.surrogate,
                state,
                weights,
                dt,
                k,
                max_iter,
                backend=backend,
                update=update,
                weights_ordered=compiled,
                previous=previous,
                **options,
            )

        traj = rollout_in_chunks(run, start, n_steps, stride=stride, progress=progress, history=history)
        return traj if around is not None or self.parts.scaling is None else traj / scale

    def _solve_step(self, x: np.ndarray, weights: np.ndarray, dt: np.ndarray) -> np.ndarray:
        """One implicit step for a validated batch in the original coordinates (``state_scaling`` applied)."""
        if self.parts.scaling is None:
            return self._solve_scaled(x, weights, dt)
        return self._solve_scaled(x * self.scale, weights, dt) / self.scale

    def _solve_scaled(self, x: np.ndarray, weights: np.ndarray, dt: np.ndarray, by_size: bool = False) -> np.ndarray:
        """One implicit step in the model's coordinates, on the configured backend (:mod:`sympredict.symplectic.newton`;
        ``by_size``: chosen by the work's size alone, the same in every process, :meth:`compiled`)."""
        max_iter = self.solver.iterations()
        if self.compiled(len(x), 1, by_size=by_size):
            return implicit_rollout(
                self.surrogate, x, weights, dt, 1, max_iter, backend="numba", step_index=False, update=self.rule.name
            )[:, 1]
        return self.rule.solve(self.surrogate, x, weights, dt, max_iter)

    def step(self, x, mu=None, dt=None, *, return_error: bool = False):
        """One predicted macro step for a batch of states.

        Parameters
        ----------
        x : array_like of shape (B, 2n) or (2n,)
            States ``(q, p)``, one per row (or a single state).
        mu : float or array_like of shape (B,), (d_mu,) or (B, d_mu), default=None
            Parameters (required iff the model has a parameter).
        dt : float or array_like of shape (B,), default=None
            Macro steps; ``None``: the training step of a fixed-step model (required otherwise).
        return_error : bool, default=False
            Also return an estimate of ``|x1_predicted - x1_exact|_2`` per instance (in the states'
            units): the posterior covariance of the learned gradient at the step's evaluation point, mapped
            through the implicit update (``delta x1 = DF^-1 dT J delta g``) and scaled by the fit's
            calibration on held-out samples (``error_calibration_``), and in quadrature the nearest of the model's
            own one-step residual vectors (:attr:`error_residuals`).  Costs ``O(B 2n m^2)`` more.

        Returns
        -------
        ndarray of the shape of ``x``
            (and with ``return_error``, the estimates, shape (B,) or a float for a single state)

        Raises
        ------
        NewtonConvergenceError
            If the implicit equation cannot be solved for some instances
            (the error names them); never returns NaN silently.
        """
        x, single, mu, dt = self._query(x, mu, dt)
        weights = self.surrogate.weights(mu, dt)
        out = check_finite(self._solve_step(x, weights, dt), self._what())
        if not return_error:
            return out[0] if single else out
        c = self._check_error_estimate()
        scale = self.scale
        err = c * self._step_factors(x, mu, dt) * self._local_error_units(x * scale, out * scale, mu, dt, weights)
        err = np.hypot(err, self._residual_part(x[:, None], mu, dt)[:, 1])
        return (out[0], float(err[0])) if single else (out, err)

    def rollout(
        self,
        x0,
        n_steps: int,
        mu=None,
        dt=None,
        *,
        stride: int = 1,
        progress=None,
        check_solvability: bool = False,
        around=None,
        return_error: bool = False,
    ):
        """Trajectories of ``n_steps`` predicted macro steps.

        Parameters
        ----------
        x0 : array_like of shape (B, 2n) or (2n,)
            Initial states ``(q, p)``, one per row (or a single state).
        n_steps : int
            Number of macro steps ``K >= 0``.
        mu : float or array_like of shape (B,), (d_mu,) or (B, d_mu), default=None
            Parameters (required iff the model has a parameter), fixed per instance along the trajectory.
        dt : float or array_like of shape (B,), default=None
            Macro steps, fixed per instance along the trajectory; ``None``: the training step of a
            fixed-step model (required otherwise).
        stride : int, default=1
            Keep the state of every ``stride``-th step only (``traj[:, ::stride]`` of the full
            trajectories, with memory for those alone); ``stride = K`` keeps the first and last states.
        progress : callable, default=None
            ``progress(steps_done, n_steps)``, called between the chunks of a long rollout.
        check_solvability : bool, default=False
            Before stepping, estimate ``dT * L_S`` at the initial states
            (:meth:`solvability`) and raise :class:`SolvabilityError` naming the
            instances where it is ``>= 1``.
        around : tuple ``(pre, post)`` of arrays of shape (B, 2n, 2n) or (2n, 2n), default=None
            The wrappers' hook: step ``x_k+1 = post Phi(pre x_k)`` instead of ``Phi(x_k)``
            (e.g. the exact linear flow ``L_h`` on both sides, :class:`~sympredict.flowmap.splitting.SplitKernelPredictor`),
            on the same solver as a plain rollout (compiled where that is).  The query
            checks and extrapolation warnings are about the model's inputs ``pre x_k``.
        return_error : bool, default=False
            Also return ``error`` (B, K // stride + 1), an estimate of ``|x_predicted - x_exact|_2`` at the
            kept steps, in the states' units (0 at step 0): the covariance of the learned gradient's error at
            every step's evaluation point and between the steps (the Gaussian-process posterior, mixed with one
            error vector fixed in the coordinates), mapped through each step and carried by the later steps'
            Jacobians, with the calibrated scale, and in quadrature the model's own one-step residual vectors
            nearest to each step's state carried coherently by the later steps (:attr:`error_residuals`,
            ``O(B K N (2n + d_mu))`` for ``N`` of them; :mod:`sympredict.estimators.error_estimate`).  It covers the
            model's interpolation error, not noise in the training data nor states far outside the training
            box (see the how-to "How accurate is my prediction?").  The states come from the usual solver
            (compiled where that is); the estimate is computed afterwards in NumPy, ``O(B K 2n m^2)`` (the
            posterior at every step: for ``m = 1000`` centres about 10x to 100x the rollout itself) plus
            ``O(B K^2 (2n)^3)`` for the pairs of steps up to ``EXACT_MAX_STEPS`` (1,000) steps, beyond that
            linear in ``K`` (the posterior factorised on landmarks, logged at INFO), with every step's state
            kept while it runs.  Not with ``around``.

        Returns
        -------
        ndarray of shape (B, K // stride + 1, 2n) (or (K // stride + 1, 2n) for a single state)
            ``traj[:, j]`` is the state at ``t = j stride dT``; with ``return_error``, ``(traj, error)``.

        Raises
        ------
        RolloutMemoryError
            Before any step, when the kept states do not fit in the available memory.

        Notes
        -----
        All instances advance together; the ``(B, m)`` parameter weights are
        formed once.  Cost ``O(K B m (2n)^2 n_newton)``, memory ``O(B (K / stride) 2n)``.
        The steps run in chunks of about 0.2 s, between which Ctrl-C interrupts the rollout
        (:func:`~sympredict.symplectic.newton.rollout_in_chunks`).
        """
        n_steps = as_positive_int(n_steps, "n_steps", minimum=0)
        stride = as_positive_int(stride, "stride")
        if return_error:
            if around is not None:
                raise ValueError(
                    "return_error=True does not apply to a wrapped rollout (around=...): the estimate "
                    "propagates the model's own step; estimate the inner model's rollout instead"
                )
            self._check_error_estimate()
            keep = stride
            stride = 1
        if around is None:
            x, single, mu, dt = self._query(x0, mu, dt, name="x0")
        else:
            x, single = as_states(x0, "x0", dim=self.dim)
            around = self._check_around(around, len(x))
            if self.solver.warm_start:  # said, not silently dropped
                warnings.warn(
                    "the solver's warm_start does not apply to a wrapped rollout (around=...): its "
                    "extrapolation would mix the states x_k and pre x_k; every step starts from the explicit "
                    "guess (pass NewtonSolver(warm_start=False) to the inner model to silence this)",
                    UserWarning,
                    stacklevel=3,
                )
            _, _, mu, dt = self._query(np.einsum("bij,bj->bi", around[0], x), mu, dt, name="pre x0")
        weights = self.surrogate.weights(mu, dt)
        if check_solvability:
            seen = x if around is None else np.einsum("bij,bj->bi", around[0], x)
            margin = self._solvability(seen, weights, dt)
            bad = np.flatnonzero(~(margin < 1.0))
            if bad.size:
                raise SolvabilityError(bad, margin[bad])
        traj = check_finite(
            self._rollout(x, weights, dt, n_steps, around=around, stride=stride, progress=progress), self._what()
        )
        self._warn_if_trajectory_leaves(traj if around is None else np.einsum("bij,bkj->bki", around[0], traj), stride)
        if return_error:
            err = self._rollout_error(traj, mu, dt, weights)[:, ::keep]
            traj = traj[:, ::keep]
            return (traj[0], err[0]) if single else (traj, err)
        return traj[0] if single else traj

    def _check_around(self, around, b: int) -> tuple:
        """``(pre, post)`` as finite C-contiguous float64 arrays (B, 2n, 2n); ``ValueError`` naming the problem."""
        try:
            pre, post = around
        except (TypeError, ValueError):
            raise ValueError("around must be a pair (pre, post) of matrices (B, 2n, 2n) or (2n, 2n)") from None
        out = []
        for name, m in (("pre", pre), ("post", post)):
            m = np.asarray(m, dtype=float)
            if m.ndim == 2:
                m = np.broadcast_to(m, (b, *m.shape))
            if m.shape != (b, self.dim, self.dim) or not np.all(np.isfinite(m)):
                raise ValueError(
                    f"around: {name} must be finite matrices of shape ({b}, {self.dim}, {self.dim}) or "
                    f"({self.dim}, {self.dim}), got shape {m.shape}"
                )
            out.append(np.ascontiguousarray(m))
        return tuple(out)

    def _solvability(self, x, weights, dt):
        return self.rule.contraction(self.surrogate, x * self.scale, weights, dt)

    @_query_documented
    def solvability(self, x, mu=None, dt=None) -> np.ndarray:
        """``dT * L_S`` estimated at the states ``x``: the implicit step is a contraction where it is < 1.

        ``L_S = ||d^2_xi s(q0, p) I_2||_2``: the spectral norm of the Hessian columns
        belonging to ``p`` (paper, Prop. 2 (ii)), evaluated at ``xi = (q0, p0)``.
        It is a local estimate, not the supremum over the domain that the theorem uses.

        Parameters
        ----------
        {query}

        Returns
        -------
        ndarray of shape (B,) (or a float for a single state)
        """
        x, single, mu, dt = self._query(x, mu, dt)
        margin = self._solvability(x, self.surrogate.weights(mu, dt), dt)
        return float(margin[0]) if single else margin

    @_query_documented
    def step_jacobian(self, x, mu=None, dt=None) -> np.ndarray:
        """Jacobian ``D Phi`` of the predicted step, by implicit differentiation.

        (For ``update='midpoint'``: ``(I - A)^{-1} (I + A)``, ``A = dT/2 J Hess s(z)``,
        :func:`~sympredict.symplectic.newton.midpoint_jacobian`.)

        With ``S`` the Hessian of ``s`` at ``(q0, p1)`` and ``M = I + dT S_qp``:
        ``dp1 = M^{-1} (dp0 - dT S_qq dq0)`` and
        ``dq1 = (I + dT S_pq) dq0 + dT S_pp dp1``.
        For every fixed ``(mu, dT)``, ``DPhi^T J DPhi = J`` (symplecticity).

        Parameters
        ----------
        {query}

        Returns
        -------
        ndarray of shape (B, 2n, 2n) (or (2n, 2n) for a single state)
        """
        x, single, mu, dt = self._query(x, mu, dt)
        weights = self.surrogate.weights(mu, dt)
        scale = self.scale
        x = x * scale
        jac = self.rule.jacobian(self.surrogate, x, self._solve_scaled(x, weights, dt), weights, dt)
        if self.parts.scaling is not None:  # D Phi = S^{-1} D Phi_scaled S
            jac = jac * scale[None, None, :] / scale[None, :, None]
        return jac[0] if single else jac

    def surrogate_gradient(self, xi, mu=None, dt=None) -> np.ndarray:
        """``grad_xi s(xi, mu, dT)`` at mixed states ``xi = (q0, p1)`` (midpoints for ``update='midpoint'``), shape (B, 2n)."""
        xi, single, mu, dt = self._query(xi, mu, dt, name="xi")
        # s(xi) = s_model(S xi) with S = diag(scale): grad s = S grad s_model
        g = self.surrogate.gradient(xi * self.scale, self.surrogate.weights(mu, dt)) * self.scale
        return g[0] if single else g

    # ------------------------------------------------------------ prefixes
    def truncated(self, n_centers: int) -> "FittedSymplecticFlowMap":
        """The model made of the first ``n_centers`` centres of this fit (a smaller, cheaper model).

        Uses the greedy's Newton expansion (:meth:`GreedyResult.coef_prefix`): no
        refit, and the result equals a fit with ``max_centers=n_centers`` to
        round-off.  Available on models fitted in this process (the Newton data
        are not saved to files).

        Parameters
        ----------
        n_centers : int
            The number of centres kept, ``1 <= n_centers <=`` the fit's number of centres.

        Returns
        -------
        SymplecticKernelPredictor or FittedSymplecticFlowMap
            A fitted copy (of the estimator, or of its fitted map); its history is cut at ``n_centers``.
        """
        result = self.greedy_result
        if result is None:
            raise ValueError(
                "truncation needs the greedy's Newton data, which are not stored in model files: refit instead"
            )
        n_centers = as_positive_int(n_centers, "n_centers")
        if n_centers > self.n_centers:
            raise ValueError(f"n_centers must be <= {self.n_centers}, got {n_centers}")
        sur = self.surrogate
        small = HBSurrogate(
            sur.kernel,
            sur.centers_xi[:n_centers],
            sur.centers_mu[:n_centers],
            sur.centers_dt[:n_centers],
            sur.components[:n_centers],
            result.coef_prefix(n_centers),
        )
        # keeps the full run's Newton data (it can be truncated further); recalibrated on the same samples when used
        return self._replace(surrogate=small, history=self._history_prefix(n_centers), _cache={})

    def smallest(self, target: float) -> "FittedSymplecticFlowMap":
        """The fewest centres whose validation residual ``E_val(m)`` is at or below ``target``.

        No bigger model than the case needs: ``E_val(m)`` was recorded for every
        ``m`` during the fit, so this is a look-up plus :meth:`truncated`.

        Parameters
        ----------
        target : float
            The largest validation residual ``E_val(m)`` to accept (positive, e.g. ``1e-4``).

        Returns
        -------
        SymplecticKernelPredictor or FittedSymplecticFlowMap
            A fitted copy with the first ``m`` centres (of the estimator, or of its fitted map), as
            :meth:`truncated` gives.

        Raises
        ------
        ValueError
            Without validation data at fit time, or when no ``m`` reaches the
            target (the message gives the best ``E_val`` reached and where).
        """
        val = self.history.val_max_residual
        if val is None:
            raise ValueError("smallest() needs validation data at fit time (fit(..., validation=...))")
        if (
            isinstance(target, bool)
            or not isinstance(target, (int, float, np.integer, np.floating))
            or not (np.isfinite(target) and target > 0)
        ):
            raise ValueError(
                f"target must be a positive float (the largest E_val to accept, e.g. 1e-4), got {target!r}"
            )
        hits = np.flatnonzero(val[1:] <= target)
        if hits.size == 0:
            best = int(np.argmin(val[1:])) + 1
            raise ValueError(
                f"no number of centres reaches E_val <= {target:.2e}: the best is {val[best]:.2e} at {best} centres "
                f"(of {self.n_centers}); train with more centres or more data"
            )
        return self.truncated(int(hits[0]) + 1)

    # ------------------------------------------------------- error estimate
    def _local_error_units(self, xs: np.ndarray, x1s: np.ndarray, mu: np.ndarray, dt: np.ndarray, weights: np.ndarray):
        """One-step error estimates before calibration (B,) of solved steps ``xs -> x1s`` (scaled coordinates):
        the gradient's posterior covariance at the step's evaluation point mapped through ``d x1 / d g``
        (:func:`~sympredict.estimators.error_estimate.local_error_units`).  ``O(B 2n m^2)``."""
        xi, _, sens = self.rule.linearization(self.surrogate, xs, x1s, weights, dt)
        cov = local_covariance(self.surrogate, xi, mu, dt, self.surrogate.gram_factor(self.regularization))
        return local_error_units(sens, cov, self.scale)

    def _check_error_estimate(self) -> float:
        """The calibrated scale of the error estimate; ``ValueError`` naming why there is none."""
        cal = self.error_calibration
        if not cal or not np.isfinite(cal.get("scale", np.nan)):
            raise ValueError(
                "return_error=True needs the error calibration of the fit (error_calibration_), which this "
                "model lacks (a model file written before it existed, or a fit without samples to "
                "calibrate on): refit the model"
            )
        return float(cal["scale"])

    @classmethod
    def calibration_data(cls, train: FlowMapData, holdout: Optional[FlowMapData], selected, dim: int):
        """The samples the error estimate is calibrated on: ``(data, source)`` or ``None``.

        Held-out samples (training samples that are not centres, ``selected // dim``, when there are none), at
        most :attr:`ERROR_SAMPLES` of them.  The calibration itself is computed on first use
        (:attr:`error_calibration`), so fits whose estimate nobody asks for do not pay for it.
        """
        source = "held-out samples"
        data = holdout
        if data is None or not len(data):
            source = "training samples that are not centres (optimistic: pass validation data)"
            used = np.zeros(len(train), dtype=bool)
            used[np.asarray(selected) // dim] = True
            data = train.subset(np.flatnonzero(~used)) if (~used).any() else None
        if data is None or not len(data):
            return None
        if len(data) > cls.ERROR_SAMPLES:
            data = data.subset(np.random.default_rng(0).choice(len(data), cls.ERROR_SAMPLES, replace=False))
        return data, source

    @classmethod
    def residual_data(cls, train: FlowMapData, holdout: Optional[FlowMapData], selected, dim: int):
        """The samples whose one-step residual vectors the error estimate searches near each step: the held-out
        samples and the training samples that are not centres (``selected // dim``), at most
        :attr:`RESIDUAL_SAMPLES` of them (a random subset, seed 0), or ``None``.  Computed on first use with the
        calibration (one predicted step each)."""
        used = np.zeros(len(train), dtype=bool)
        used[np.asarray(selected, dtype=int) // dim] = True
        rest = train.subset(np.flatnonzero(~used)) if (~used).any() else None
        parts = [d for d in (holdout, rest) if d is not None and len(d)]
        if not parts:
            return None
        data = FlowMapData(*(np.concatenate([getattr(d, f) for d in parts]) for f in ("x0", "x1", "mu", "dt")))
        if len(data) > cls.RESIDUAL_SAMPLES:
            data = data.subset(np.sort(np.random.default_rng(0).choice(len(data), cls.RESIDUAL_SAMPLES, replace=False)))
        return data

    @property
    def error_residuals(self) -> Optional[dict]:
        """The residual part of the error estimate: ``points`` (N, 2n + d_mu + 1), the states, parameters and steps
        of held-out samples and training samples that are not centres, and ``vectors`` (N, 2n), the model's one-step
        residuals there, ``Phi(x0_i) - x1_i`` in the states' units; the ``error_calibration["residual_neighbours"]``
        nearest to each step's state, times ``error_calibration["residual_scale"]``, are carried through the later
        steps (:func:`~sympredict.estimators.error_estimate.propagated_residuals`).  ``None``: none."""
        self.error_calibration  # computed with it
        return self._cache.get("residuals")

    def _share(self) -> Optional[tuple]:
        """``(posterior_share, share_distance)`` of ``error_calibration`` (:meth:`_share_factors`); ``None`` without
        :attr:`error_residuals` or in files written before them (the posterior part at its full scale)."""
        if self.error_residuals is None:
            return None
        cal = self.error_calibration
        if "posterior_share" not in cal:
            return None
        return float(cal["posterior_share"]), float(cal["share_distance"])

    def _share_factors(self, x: np.ndarray, mu: np.ndarray, dt: np.ndarray, query=None) -> np.ndarray:
        """The posterior part's factor beside the residual part at states ``x`` (Q, 2n) (user units) with ``mu``
        (Q, d_mu), ``dt`` (Q,): (Q,), :func:`~sympredict.estimators.error_estimate.posterior_share` of the distance
        to the ``residual_neighbours``-th nearest residual sample; ones without it (:meth:`_share`).  ``query``: the
        states' ``local_points`` if already computed.  ``O(Q N (2n + d_mu))`` for ``N`` residual samples."""
        share = self._share()
        if share is None:
            return np.ones(len(x))
        points, _, k = self._residual_arrays()
        d = kth_distance(points, local_points(x, mu, dt, self.domain) if query is None else query, k)
        return posterior_share(d, *share)

    def _residual_neighbours(self, xs: np.ndarray, mu: np.ndarray, dt: np.ndarray):
        """The residual part's propagation (:class:`~sympredict.estimators.error_estimate.ResidualNeighbours`) for
        the steps from the states ``xs`` (B, K, 2n) (user units), ``mu`` (B, d_mu), ``dt`` (B,), fed block by block
        with the steps' Jacobians; ``None`` without :attr:`error_residuals`.  The residual samples' normalised points
        and scaled vectors are computed once per model (:meth:`_residual_arrays`)."""
        arrays = self._residual_arrays()
        if arrays is None:
            return None
        points, vectors, k = arrays
        return ResidualNeighbours(points, vectors, k, xs, mu, dt, self.domain, self.scale)

    def _residual_arrays(self):
        """``(points (N, q), vectors (N, 2n), k)``: :attr:`error_residuals` in
        :func:`~sympredict.estimators.error_estimate.local_points` coordinates and scaled coordinates, and the
        neighbours per step; cached beside the calibration.  ``None`` without :attr:`error_residuals`."""
        res = self.error_residuals
        if res is None:
            return None
        if "residual_arrays" not in self._cache:
            dim, pts = self.dim, res["points"]
            self._cache["residual_arrays"] = (
                local_points(pts[:, :dim], pts[:, dim:-1], pts[:, -1], self.domain),
                res["vectors"] * self.scale,
                int(self.error_calibration["residual_neighbours"]),
            )
        return self._cache["residual_arrays"]

    def _residual_part(self, xs: np.ndarray, mu: np.ndarray, dt: np.ndarray):
        """The residual part of the one-step estimate (B, 2) from the states ``xs`` (B, 1, 2n) (user units): the
        nearest residuals at the step (no Jacobian acts on them); zeros without :attr:`error_residuals`."""
        b, n_steps, dim = xs.shape
        part = self._residual_neighbours(xs, mu, dt)
        if part is None:
            return np.zeros((b, n_steps + 1))
        part(0, np.zeros((b, n_steps, dim, dim)))
        return float(self.error_calibration["residual_scale"]) * part.out

    @property
    def error_calibration(self) -> Optional[dict]:
        """The error estimate's calibration, computed on first use from ``calibration_samples``, then kept:
        ``scale`` (the :attr:`ERROR_QUANTILE` quantile of true one-step error over the estimate with its local
        scale), ``local_neighbours`` (the held-out samples the local scale averages), ``source``, ``n_samples``,
        ``median_effectivity``, ``share_under_3x`` (each sample's local scale left out of its own); ``None``
        without samples."""
        if "calibration" not in self._cache:
            samples = None if self.n_centers == 0 else self.calibration_samples
            cal, local, res = (None, None, None) if samples is None else self._error_calibration(*samples)
            self._cache.update(calibration=cal, local=local, residuals=res)
        return self._cache["calibration"]

    @property
    def error_local(self) -> Optional[dict]:
        """The error estimate's local scale: ``points`` (N, 2n + d_mu + 1), the held-out samples' states,
        parameters and steps, and ``log_ratio`` (N,), the log of true one-step error over estimate at each
        (centred); the estimate at a state is multiplied by ``exp`` of the mean ``log_ratio`` of its
        ``error_calibration["local_neighbours"]`` nearest samples
        (:func:`~sympredict.estimators.error_estimate.local_log_ratio`).  ``None``: one scale everywhere."""
        self.error_calibration  # computed with it
        return self._cache.get("local")

    def _step_factors(self, x: np.ndarray, mu: np.ndarray, dt: np.ndarray) -> np.ndarray:
        """The factors (Q,) on the posterior part of the steps from states ``x`` (Q, 2n) (user units), ``mu``
        (Q, d_mu), ``dt`` (Q,): the local scale (:meth:`_local_factors`) times the share beside the residual part
        (:meth:`_share_factors`), the states normalised once for both."""
        if self.error_local is None and self._share() is None:
            return np.ones(len(x))
        query = local_points(x, mu, dt, self.domain)
        return self._local_factors(x, mu, dt, query) * self._share_factors(x, mu, dt, query)

    def _local_factors(self, x: np.ndarray, mu: np.ndarray, dt: np.ndarray, query=None) -> np.ndarray:
        """The local scale at states ``x`` (Q, 2n) in the user's units with ``mu`` (Q, d_mu), ``dt`` (Q,): (Q,);
        ones without :attr:`error_local`.  ``query``: the states' ``local_points`` if already computed.
        ``O(Q N (2n + d_mu))`` for ``N`` held-out samples."""
        local = self.error_local
        if local is None:
            return np.ones(len(x))
        k = int(self.error_calibration.get("local_neighbours", LOCAL_NEIGHBOURS))
        query = local_points(x, mu, dt, self.domain) if query is None else query
        if "local_points" not in self._cache:  # normalised once per model
            pts = local["points"]
            self._cache["local_points"] = local_points(
                pts[:, : self.dim], pts[:, self.dim : -1], pts[:, -1], self.domain
            )
        return np.exp(local_log_ratio(self._cache["local_points"], local["log_ratio"], query, k))

    def _error_calibration(self, data: FlowMapData, source: str) -> tuple:
        """``(calibration, local, residuals)`` (:attr:`error_calibration`, :attr:`error_local`,
        :attr:`error_residuals`) from held-out ``data`` (and the residual vectors on ``residual_samples``).

        ``ratio_i = |Phi(x0_i) - x1_i| / e_i`` with ``e_i`` the one-step estimate before calibration; the local
        scale ``f_i`` is ``exp`` of the mean centred ``log ratio`` of the ``LOCAL_NEIGHBOURS`` nearest other
        samples; the scale is the :attr:`ERROR_QUANTILE` quantile of ``ratio_i / f_i`` (the one-step estimate
        covers that share of the errors).  ``O(N 2n m^2 + N^2 (2n + d_mu))`` for ``N`` samples."""
        mu = data.mu if self.n_mu else np.zeros((len(data), 0))
        scale = self.scale
        weights = self.surrogate.weights(mu, data.dt)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", ExtrapolationWarning)
                x1s = self._solve_scaled(data.x0 * scale, weights, data.dt, by_size=True)
        except (NewtonConvergenceError, NonFinitePredictionError):
            return None, None, None
        true = np.linalg.norm(x1s / scale - data.x1, axis=1)
        unit = self._local_error_units(data.x0 * scale, x1s, mu, data.dt, weights)
        ok = (unit > 0) & np.isfinite(true)
        if not ok.any():
            return None, None, None
        true, unit = true[ok], unit[ok]
        local, factor = None, np.ones(len(true))
        k = LOCAL_NEIGHBOURS
        if ok.sum() > k and np.all(true > 0):
            # the log ratios, centred; each sample's own ratio left out of its local scale
            log_ratio = np.log(true / unit)
            log_ratio -= log_ratio.mean()
            raw = np.concatenate([data.x0[ok], mu[ok], data.dt[ok, None]], axis=1)
            points = local_points(raw[:, : self.dim], mu[ok], data.dt[ok], self.domain)
            factor = np.exp(local_log_ratio(points, log_ratio, points, k, leave_one_out=True))
            local = {"points": raw, "log_ratio": log_ratio}
        ratio = true / (unit * factor)
        c = float(np.quantile(ratio, self.ERROR_QUANTILE))
        if not c > 0:  # every held-out step exact: fall back to the largest ratio's scale of round-off
            c = float(np.finfo(float).eps)
        est = c * unit * factor
        cal = {
            "scale": c,
            "quantile": self.ERROR_QUANTILE,
            "n_samples": int(ok.sum()),
            "source": source,
            "median_effectivity": float(np.median(est / np.maximum(true, np.finfo(float).tiny))),
            "share_under_3x": float(np.mean(3 * est < true)),
            "median_step_error": float(np.median(true)),
        }
        if local is not None:
            cal["local_neighbours"] = k
        residuals = self._residual_calibration(cal, data, x1s / scale)
        if residuals is not None:
            raw = np.concatenate([data.x0[ok], mu[ok], data.dt[ok, None]], axis=1)
            self._posterior_share(cal, local, residuals, raw, x1s[ok] / scale - data.x1[ok], unit)
        return cal, local, residuals

    def _posterior_share(self, cal: dict, local, residuals: dict, raw: np.ndarray, true: np.ndarray, unit) -> None:
        """``cal``'s ``posterior_share`` and ``share_distance`` (:meth:`_share_factors`).  The share: the posterior
        covers what the residual samples near a state do not tell, so beside them its scale is calibrated on the
        misfit ``|r_i - mean of the k nearest other residual vectors|`` instead of ``|r_i|``: the
        :attr:`ERROR_QUANTILE` quantile of misfit over the one-step estimate before calibration ``unit`` (N,) times
        the local scale the estimate applies at the sample, over ``cal["scale"]``, in ``(0, 1]``.  The distance:
        the :data:`~sympredict.estimators.error_estimate.SHARE_DISTANCE_QUANTILE` quantile of the residual samples'
        distances to their ``k``-th nearest other one (the spacing within which the share was calibrated).
        ``raw`` (N, 2n + d_mu + 1): the calibration samples' states, parameters and steps; ``true`` (N, 2n): their
        residual vectors; a sample that is also a residual sample is left out of its own neighbours.
        ``O((N + N') N' (2n + d_mu))`` for ``N'`` residual samples."""
        pool, vectors = residuals["points"], residuals["vectors"]
        dim, k = self.dim, int(cal["residual_neighbours"])
        pts = local_points(pool[:, :dim], pool[:, dim:-1], pool[:, -1], self.domain)
        near = nearest(pts, local_points(raw[:, :dim], raw[:, dim:-1], raw[:, -1], self.domain), k + 1)
        itself = np.all(pool[near] == raw[:, None, :], axis=2)
        near = np.take_along_axis(near, np.argsort(itself, axis=1, kind="stable")[:, :k], axis=1)
        misfit = np.linalg.norm(true - vectors[near].mean(axis=1), axis=1)
        factor = np.ones(len(raw))
        if local is not None:
            factor = np.exp(
                local_log_ratio(
                    local_points(
                        local["points"][:, :dim], local["points"][:, dim:-1], local["points"][:, -1], self.domain
                    ),
                    local["log_ratio"],
                    local_points(raw[:, :dim], raw[:, dim:-1], raw[:, -1], self.domain),
                    int(cal["local_neighbours"]),
                )
            )
        share = float(np.quantile(misfit / (unit * factor), self.ERROR_QUANTILE)) / cal["scale"]
        distance = float(np.quantile(kth_distance(pts, pts, k, leave_one_out=True), SHARE_DISTANCE_QUANTILE))
        if not (np.isfinite(share) and np.isfinite(distance) and distance > 0):
            return  # no share: the posterior at its full scale
        cal.update(posterior_share=float(min(1.0, max(share, np.finfo(float).eps))), share_distance=distance)

    def _residual_calibration(self, cal: dict, data: FlowMapData, pred: np.ndarray) -> Optional[dict]:
        """The residual vectors of :attr:`error_residuals` on ``residual_samples`` (``data`` itself when there are
        none; ``pred`` its predicted steps), with ``cal``'s ``residual_neighbours`` and ``residual_scale`` (the
        :attr:`ERROR_QUANTILE` quantile over the samples of ``|r_i|`` over the root mean square of its nearest
        other residuals: the one-step case).  ``None`` (and ``cal`` unchanged) with too few samples or a failed
        step.  ``O(N n_newton + N^2 (2n + d_mu))`` for ``N`` samples."""
        pool = self.residual_samples
        if pool is None or not len(pool):
            pool = data
        else:
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", ExtrapolationWarning)
                    weights = self.surrogate.weights(pool.mu if self.n_mu else np.zeros((len(pool), 0)), pool.dt)
                    pred = self._solve_scaled(pool.x0 * self.scale, weights, pool.dt, by_size=True) / self.scale
            except (NewtonConvergenceError, NonFinitePredictionError):
                return None
        k = RESIDUAL_NEIGHBOURS
        vectors = pred - pool.x1
        ok = np.all(np.isfinite(vectors), axis=1)
        if ok.sum() <= k:
            return None
        mu = pool.mu[ok] if self.n_mu else np.zeros((int(ok.sum()), 0))
        vectors, raw = vectors[ok], np.concatenate([pool.x0[ok], mu, pool.dt[ok, None]], axis=1)
        pts = local_points(pool.x0[ok], mu, pool.dt[ok], self.domain)
        near = nearest(pts, pts, k, leave_one_out=True)
        rms = np.sqrt(np.mean(np.sum(vectors[near] ** 2, axis=2), axis=1))
        size = np.linalg.norm(vectors, axis=1)
        good = rms > 0
        if not good.any():
            return None
        cal.update(
            residual_neighbours=k,
            residual_scale=float(max(np.quantile(size[good] / rms[good], self.ERROR_QUANTILE), np.finfo(float).eps)),
            residual_samples=int(ok.sum()),
        )
        return {"points": raw, "vectors": vectors}

    def _rollout_error(self, traj: np.ndarray, mu: np.ndarray, dt: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """Error estimates (B, K+1) along predicted trajectories ``traj`` (B, K+1, 2n) (every step kept): the
        gradient's posterior covariance carried through the steps' Jacobians, with the calibrated scale
        (:func:`~sympredict.estimators.error_estimate.rollout_error_units`), and in quadrature the residual part,
        propagated block by block with the Jacobians of that linearisation (memory ``O(B 2n (k + 2n))`` carried
        between the blocks)."""
        c = self._check_error_estimate()
        b, k1, dim = traj.shape
        local = None
        if (self.error_local is not None or self._share() is not None) and k1 > 1:
            n = k1 - 1
            local = self._step_factors(traj[:, :-1].reshape(-1, dim), np.repeat(mu, n, axis=0), np.repeat(dt, n))
            local = local.reshape(b, n)
        part = self._residual_neighbours(traj[:, :-1], mu, dt) if k1 > 1 else None
        est = c * rollout_error_units(self, traj, mu, dt, weights, local=local, jacobians=part)
        if part is None:
            return est
        return np.hypot(est, float(self.error_calibration["residual_scale"]) * part.out)

    # ----------------------------------------------------------------- files
    @staticmethod
    def _check_surrogate_values(arrays: dict, dim: int) -> None:
        comps = arrays["components"]
        if comps.dtype.kind != "i" or np.any((comps < 0) | (comps >= dim)):
            raise ModelFileError(f"the file's centre components must be integers in 0..{dim - 1}")
