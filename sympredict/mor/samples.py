"""Where a :class:`~sympredict.mor.reductor.SymplecticKernelReductor` gets its flow-map samples: one part each.

Each source holds its settings and produces the training and validation samples in reduced coordinates
(:class:`~sympredict.data.FlowMapData`, ``x1 = Phi(x0)`` over the reductor's ``dt``, parameter vectors of the
flow parameters in :func:`~sympredict.systems.flowmaps.mu_to_vector` order):

* :class:`GalerkinSamples` (intrusive): the symplectic Galerkin ROM of a pyMOR
  ``QuadraticHamiltonianModel`` gives the exact reduced flow; samples lie in a neighbourhood (relative radius
  ``radius``) of the reduced trajectories from the FOM's initial data, plus the trajectory points;
* :class:`ProjectedTrajectories` (non-intrusive, any time-dependent pyMOR model, linear or not): only
  ``fom.solve`` is called; FOM trajectories are projected with the symplectic inverse
  ``V+ = J_2n^T V^T J_2N`` and consecutive states ``dt`` apart become the samples (``dt`` a multiple of the
  FOM's output step);
* :class:`GivenTrajectories`: as :class:`ProjectedTrajectories`, from FOM trajectories the caller already has
  (no FOM solve);
* :class:`GivenSamples`: flow-map pairs in reduced coordinates the caller already has (its own sampling
  design, its own solver, augmented pairs).

Validation data of the sampling sources come from parameters drawn at random in the parameter box
(``parameter_space`` or the box of the training parameters), never from the training parameters.

A source is a part: ``__init__`` stores its settings; the reductor calls ``check(reductor)`` once (before any
FOM solve; ``ValueError`` naming the argument, the value and the fix) and ``sample(reductor)`` in
:meth:`~sympredict.mor.reductor.SymplecticKernelReductor.training_data`.
"""

from __future__ import annotations

from typing import Optional, Sequence

import numpy as np
from pymor.models.interface import Model
from pymor.models.symplectic import QuadraticHamiltonianModel

from sympredict._checks import as_positive_int, as_real
from sympredict.base import Parametrized
from sympredict.data import FlowMapData, TrajectoryData
from sympredict.systems.flowmaps import (
    parse_mu,
    random_parameters,
    sample_trajectory_neighbourhood,
    trajectory_pairs,
)

__all__ = ["GalerkinSamples", "ProjectedTrajectories", "GivenTrajectories", "GivenSamples"]


def _check_fom(fom, needed: tuple, what: str) -> None:
    """``ValueError`` unless ``fom`` is a pyMOR Model with the attributes ``needed``."""
    missing = [a for a in needed if not hasattr(fom, a)]
    if not isinstance(fom, Model) or missing:
        raise ValueError(
            f"{what} needs a time-dependent pyMOR Model (e.g. an InstationaryModel) with "
            f"{', '.join(needed[:-1])} and {needed[-1]}; {type(fom).__name__} "
            + (f"lacks {', '.join(missing)}" if missing else "is not a pyMOR Model")
        )


def _check_parameter_space(parameter_space, fom) -> None:
    if parameter_space is None:
        return
    from pymor.parameters.base import ParameterSpace

    if not isinstance(parameter_space, ParameterSpace):
        raise ValueError(
            f"parameter_space must be a pyMOR ParameterSpace (e.g. fom.parameters.space(lo, hi)) or None, "
            f"got {type(parameter_space).__name__}"
        )
    if dict(parameter_space.parameters) != dict(fom.parameters):
        raise ValueError(
            f"parameter_space has the parameters {dict(parameter_space.parameters)}, the FOM has "
            f"{dict(fom.parameters)}: names and dimensions must agree"
        )


def _parsed(training_parameters, fom, what: str) -> Optional[list]:
    """The training parameters as pyMOR ``Mu`` (``[None]`` for a parameter-free FOM)."""
    if not fom.parameters:
        return [None]
    if training_parameters is None or len(training_parameters) == 0:
        raise ValueError(
            f"the FOM has parameters {dict(fom.parameters)}: give {what} its training parameters "
            f"(pyMOR Mu, e.g. fom.parameters.space(lo, hi).sample_uniformly(5))"
        )
    return [parse_mu(m, fom.parameters) for m in training_parameters]


def _concat(parts: Sequence[FlowMapData]) -> FlowMapData:
    out = parts[0]
    for p in parts[1:]:
        out = out.concatenate(p)
    return out


def _as_trajectories(U, mus, fom, name: str) -> tuple:
    """The caller's FOM trajectories ``(U, mus)`` as ``(list of VectorArrays in fom.solution_space, list of Mu)``.

    ``U``: a sequence of ``P`` VectorArrays (each ``K + 1`` states, as ``fom.solve`` returns) or an array
    ``(P, K + 1, N)`` of full states (``N = fom.solution_space.dim``, blocks stacked as the solution space orders
    them); ``mus``: ``P`` parameter values (pyMOR ``Mu``, dicts, numbers; ``None`` or ``P`` Nones for a parameter-free
    FOM).  Shapes, spaces, lengths and finiteness are checked before anything is copied (``ValueError`` naming
    ``name``).
    """
    space = fom.solution_space
    if isinstance(U, np.ndarray):
        if U.ndim != 3 or U.shape[2] != space.dim or U.shape[0] == 0 or U.shape[1] < 2:
            raise ValueError(
                f"{name}: an array of trajectories must have shape (P, K+1, N) with P >= 1, K + 1 >= 2 and "
                f"N = {space.dim} (the FOM's solution space), got {U.shape}"
            )
        if not np.issubdtype(U.dtype, np.number) or np.iscomplexobj(U) or not np.all(np.isfinite(U)):
            raise ValueError(
                f"{name}: the trajectories must be finite real numbers (NaN, Inf or dtype {U.dtype} found)"
            )
        U = [space.from_numpy(np.array(u, dtype=float).T) for u in U]  # pyMOR: columns are vectors
    else:
        U = list(U) if isinstance(U, (list, tuple)) else [U]
        bad = [i for i, u in enumerate(U) if getattr(u, "space", None) != space]
        if not U or bad:
            raise ValueError(
                f"{name}: U must hold VectorArrays in the FOM's solution space {space}"
                + (
                    f"; entry {bad[0]} is a {type(U[bad[0]]).__name__}"
                    + (f" in {U[bad[0]].space}" if hasattr(U[bad[0]], "space") else "")
                    if bad
                    else ", got none"
                )
            )
        for i, u in enumerate(U):
            if not np.all(np.isfinite(u.norm())):
                raise ValueError(f"{name}: trajectory {i} has NaN or Inf states")
    lengths = sorted({len(u) for u in U})
    if len(lengths) > 1 or lengths[0] < 2:
        raise ValueError(
            f"{name}: every trajectory must have the same number K + 1 >= 2 of states (t_k = k T / K), "
            f"got lengths {lengths}"
        )
    if not fom.parameters and mus is None:
        return U, [None] * len(U)
    if mus is None or isinstance(mus, (str, dict)) or len(mus) != len(U):
        raise ValueError(
            f"{name}: give one parameter value per trajectory ({len(U)}), got {'none' if mus is None else mus!r}"
        )
    return U, [parse_mu(m, fom.parameters) for m in mus]


def _check_stride(reductor, h: float, n_out: Optional[int] = None) -> int:
    """The number of FOM output steps ``h = T / n_out`` in one macro step ``dt``; ``ValueError`` with the exact
    numbers (``T``, ``n_out``, ``h``, ``dt / h`` and the nearest admissible steps) when ``dt`` is not a multiple."""
    dt, T = reductor.dt, reductor.fom.T
    ratio = dt / h
    stride = int(round(ratio))
    if stride < 1 or not np.isclose(stride * h, dt, rtol=1e-9, atol=0):
        n_out = int(round(T / h)) if n_out is None else int(n_out)
        lower, upper = max(1, int(np.floor(ratio))), max(1, int(np.ceil(ratio)))
        near = sorted({lower * h, upper * h})
        raise ValueError(
            f"projected trajectories need dt to be a multiple of the FOM's output step h = T / nt = "
            f"{T!r} / {n_out} = {h!r}; dt = {dt!r} is {ratio:.6g} output steps: use "
            f"dt = k * h, e.g. " + " or ".join(f"{v!r}" for v in near)
        )
    return stride


def _check_given_grid(reductor, U) -> None:
    """The caller's trajectories (``K + 1`` states at ``t_k = k T / K``): on the FOM's time grid (``nt`` a
    multiple of ``K`` where the FOM has a time stepper) and ``dt`` a multiple of their step ``T / K``."""
    fom = reductor.fom
    k = len(U) - 1
    nt = getattr(getattr(fom, "time_stepper", None), "nt", None)
    if nt and int(nt) % k:
        raise ValueError(
            f"the given trajectories have {k + 1} states, read as t_k = k T / {k} (T = {fom.T!r}); "
            f"the FOM's time grid has nt = {nt} steps, not a multiple of {k}: give states at every "
            f"output step of fom.solve (nt + 1 = {int(nt) + 1} states) or at every m-th, m dividing nt"
        )
    _check_stride(reductor, fom.T / k, k)


def _projected_pairs(reductor, mus, horizon: float, given=None) -> FlowMapData:
    """Flow-map pairs ``dt`` apart of the projected FOM trajectories at ``mus`` (``fom.solve``, or ``given``:
    VectorArrays of the caller's trajectories at those parameters)."""
    fom = reductor.fom
    trajs, rows = [], reductor._mu_rows(mus)
    h = None
    for i, mu in enumerate(mus):
        U = fom.solve(mu) if given is None else given[i]
        h_mu = fom.T / (len(U) - 1)
        if h is not None and not np.isclose(h, h_mu):
            raise ValueError("the FOM's output grid changes with mu")
        h = h_mu
        trajs.append(reductor.project(U))
    stride = _check_stride(reductor, h)
    k = int(round(horizon / h)) + 1
    # dt exactly: the predictor is a fixed-step model and the ROM queries reductor.dt
    return trajectory_pairs(np.stack([t[:k] for t in trajs]), rows, reductor.dt / stride, stride)


class _Sampled(Parametrized):
    """Common part of the sources that draw validation parameters in the box and sample up to a horizon."""

    exact_flow = False  # the Galerkin ROM's exact reduced flow available (the existence check and "williamson")

    def _check_common(self, reductor) -> None:
        as_positive_int(self.n_validation, "n_validation")
        as_positive_int(self.seed, "seed", minimum=0)
        if self.horizon is not None:
            as_real(self.horizon, "horizon", positive=True)
        _check_parameter_space(self.parameter_space, reductor.fom)

    def _horizon(self, fom) -> float:
        """The time span sampled (``horizon``, default ``fom.T``)."""
        return float(fom.T if self.horizon is None else self.horizon)

    def validation_parameters(self, reductor) -> list:
        """``n_validation`` parameters uniform in the box (seeded), not the training ones."""
        if not reductor.fom.parameters:
            return [None]
        return random_parameters(
            reductor.fom.parameters, reductor.mu_lo, reductor.mu_hi, self.n_validation, seed=self.seed + 7
        )


class GalerkinSamples(_Sampled):
    """Samples of the exact reduced flow of the symplectic Galerkin ROM (intrusive).

    pyMOR's ``QuadraticHamiltonianRBReductor`` gives the reduced quadratic Hamiltonian (``H_op`` assembled per
    ``mu``, so it need not be affine); its exact flow over ``dt`` maps states drawn around the reduced
    trajectories from the FOM's initial data (a fifth on the trajectories themselves).

    Parameters
    ----------
    training_parameters : sequence of pyMOR Mu or None, default=None
        E.g. ``fom.parameters.space(...).sample_uniformly(n)``; ``None`` for a parameter-free FOM.
    n_samples : int, default=400
        Flow-map samples per training parameter (at least 2).
    radius : float, default=0.05
        Relative radius of the trajectory neighbourhood.
    n_validation : int, default=3
        Number of validation parameters (random in the box); ``max(50, n_samples // 4)`` samples each.
    parameter_space : pyMOR ParameterSpace or None, default=None
        Box for the parameter scaling and the validation parameters (default: box of the training ones).
    horizon : float or None, default=None
        Time span of the trajectories sampled (default ``fom.T``).
    seed : int, default=0
    """

    exact_flow = True

    @staticmethod
    def check_model(fom) -> None:
        if not isinstance(fom, QuadraticHamiltonianModel):
            raise ValueError(
                f"GalerkinSamples needs the exact reduced flow of a pyMOR QuadraticHamiltonianModel, got "
                f"{type(fom).__name__}: for any other pyMOR model use "
                f"samples=ProjectedTrajectories(...) (only fom.solve is called)"
            )

    def __init__(
        self,
        training_parameters=None,
        n_samples: int = 400,
        radius: float = 0.05,
        n_validation: int = 3,
        parameter_space=None,
        horizon: Optional[float] = None,
        seed: int = 0,
    ):
        self.training_parameters = training_parameters
        self.n_samples = n_samples
        self.radius = radius
        self.n_validation = n_validation
        self.parameter_space = parameter_space
        self.horizon = horizon
        self.seed = seed

    def check(self, reductor) -> list:
        """Settings and FOM checked; returns the training parameters (``Mu``; ``[None]`` without parameters)."""
        self.check_model(reductor.fom)
        as_positive_int(self.n_samples, "n_samples", minimum=2)  # a fifth on the trajectory, the rest around it
        as_real(self.radius, "radius", nonnegative=True)
        self._check_common(reductor)
        return _parsed(self.training_parameters, reductor.fom, "GalerkinSamples")

    def _samples(self, reductor, mus, n_per_mu, seed):
        system = reductor._galerkin()
        dt = reductor.dt
        rng = np.random.default_rng(seed)
        rows = reductor._mu_rows(mus)
        n_fine = int(np.ceil(self._horizon(reductor.fom) / dt)) * 4
        parts = []
        for mu, row in zip(mus, rows):
            x0 = reductor._initial_state(mu)
            traj = system.trajectory(x0[None], row[None] if row.size else None, dt / 4, n_fine)[0]
            n_on = max(1, n_per_mu // 5)  # a fifth on the trajectory itself
            states = np.concatenate(
                [
                    sample_trajectory_neighbourhood(traj, n_per_mu - n_on, self.radius, rng),
                    sample_trajectory_neighbourhood(traj, n_on, 0.0, rng),
                ]
            )
            mrow = np.repeat(row[None], len(states), axis=0)
            parts.append(
                FlowMapData(states, system.flow(states, mrow, dt), mrow if row.size else None, np.full(len(states), dt))
            )
        return _concat(parts), system

    def sample(self, reductor):
        """``(train, val, reference)``: samples with the FOM's parameter vectors and ``(system, train)`` (the exact
        reduced system, for the existence check)."""
        train, system = self._samples(reductor, reductor.training_parameters, self.n_samples, self.seed)
        val, _ = self._samples(
            reductor, self.validation_parameters(reductor), max(50, self.n_samples // 4), self.seed + 1
        )
        return train, val, (system, train)


class ProjectedTrajectories(_Sampled):
    """Consecutive states ``dt`` apart of projected FOM trajectories (non-intrusive: only ``fom.solve``).

    Works for any time-dependent pyMOR model with ``solve``, ``solution_space``, ``initial_data`` and ``T`` (e.g.
    an ``InstationaryModel`` with a nonlinear operator); its trajectories are assumed Hamiltonian (the ROM's
    steps are symplectic whatever the data).  ``dt`` must be a multiple of the FOM's output step.

    Parameters
    ----------
    training_parameters : sequence of pyMOR Mu or None, default=None
        The parameters ``fom.solve`` is called at; ``None`` for a parameter-free FOM.
    n_validation : int, default=3
        Number of validation parameters (random in the box), each one more ``fom.solve``.
    parameter_space : pyMOR ParameterSpace or None, default=None
        Box for the parameter scaling and the validation parameters (default: box of the training ones).
    horizon : float or None, default=None
        Time span of the trajectories used (default and at most ``fom.T``).
    seed : int, default=0
    """

    def __init__(
        self,
        training_parameters=None,
        n_validation: int = 3,
        parameter_space=None,
        horizon: Optional[float] = None,
        seed: int = 0,
    ):
        self.training_parameters = training_parameters
        self.n_validation = n_validation
        self.parameter_space = parameter_space
        self.horizon = horizon
        self.seed = seed

    @staticmethod
    def check_model(fom) -> None:
        _check_fom(fom, ("solve", "solution_space", "initial_data", "T", "parameters"), "ProjectedTrajectories")

    def _check_horizon(self, reductor) -> None:
        fom = reductor.fom
        horizon = self._horizon(fom)
        if not reductor.dt <= horizon * (1 + 1e-12):
            raise ValueError(
                f"dt = {reductor.dt!r} is longer than the sampled time span (horizon = {horizon!r}, "
                f"fom.T = {fom.T!r}): no flow-map pair fits; use a smaller dt or a longer horizon"
            )
        if horizon > fom.T * (1 + 1e-12):
            raise ValueError(
                f"horizon = {horizon!r} is past the FOM's final time T = {fom.T!r}: its trajectories "
                f"end at T; use horizon <= T or fom.with_(T=...)"
            )

    def check(self, reductor) -> list:
        """Settings, FOM and the FOM's output grid checked; returns the training parameters."""
        fom = reductor.fom
        self.check_model(fom)
        self._check_common(reductor)
        mus = _parsed(self.training_parameters, fom, "ProjectedTrajectories")
        if getattr(fom, "num_values", None) is None and getattr(getattr(fom, "time_stepper", None), "nt", None):
            _check_stride(reductor, fom.T / fom.time_stepper.nt, fom.time_stepper.nt)  # the output grid, up front
        self._check_horizon(reductor)
        return mus

    def sample(self, reductor):
        """``(train, val, None)``: pairs of the projected trajectories, with the FOM's parameter vectors."""
        horizon = self._horizon(reductor.fom)
        train = _projected_pairs(reductor, reductor.training_parameters, horizon)
        val = _projected_pairs(reductor, self.validation_parameters(reductor), horizon)
        return train, val, None


class GivenTrajectories(ProjectedTrajectories):
    """Consecutive states ``dt`` apart of projected FOM trajectories the caller already has (no FOM solve).

    All of it is checked (shapes, spaces, lengths, finiteness, the time grid) before anything is trained.

    Parameters
    ----------
    U : sequence of VectorArray or ndarray of shape (P, K + 1, N)
        ``P`` trajectories in ``fom.solution_space`` (as ``fom.solve`` returns them) or full states, each ``K + 1``
        states at ``t_k = k T / K`` (``T = fom.T``; ``K`` divides the FOM's ``nt`` where it has a time stepper,
        and ``dt`` is a multiple of ``T / K``).
    mus : sequence of pyMOR Mu, dicts or numbers, or None, default=None
        The ``P`` parameter values (the training parameters); ``None`` for a parameter-free FOM.
    validation : tuple (U, mus) or None, default=None
        Validation trajectories of the same form.  Without them there are no validation data: give an
        estimator that chooses its kernels on held-out training samples, or its kernels.
    parameter_space : pyMOR ParameterSpace or None, default=None
        Box for the parameter scaling (default: box of ``mus``).
    horizon : float or None, default=None
        Time span of the trajectories used (default and at most ``fom.T``).
    """

    def __init__(self, U, mus=None, validation=None, parameter_space=None, horizon: Optional[float] = None):
        self.U = U
        self.mus = mus
        self.validation = validation
        self.parameter_space = parameter_space
        self.horizon = horizon

    n_validation, seed = 1, 0  # not used: the validation parameters are those of the validation trajectories

    @staticmethod
    def check_model(fom) -> None:
        _check_fom(fom, ("solution_space", "initial_data", "T", "parameters"), "GivenTrajectories")

    def check(self, reductor) -> list:
        fom = reductor.fom
        self.check_model(fom)
        self._check_common(reductor)
        trajectories, validation = self._trajectories(fom)
        for given in (trajectories, validation):
            if given is not None:
                _check_given_grid(reductor, given[0][0])
        self._check_horizon(reductor)
        return trajectories[1] if fom.parameters else [None]

    def _trajectories(self, fom) -> tuple:
        """The training and validation trajectories read and checked (``(VectorArrays, Mus)`` each, or ``None``).

        Read once per ``(fom, U, mus, validation)``: ``check``, ``validation_parameters`` and ``sample`` all need
        them, and an array of full states is copied and scanned for NaN on every read.
        """
        key = (fom, self.U, self.mus, self.validation)
        read = self.__dict__.get("_read")
        if read is not None and all(a is b for a, b in zip(read[0], key)):
            return read[1]
        if self.validation is not None and (
            not isinstance(self.validation, (tuple, list)) or len(self.validation) != 2
        ):
            raise ValueError(
                f"GivenTrajectories: validation must be a pair (U, mus) of validation trajectories "
                f"and their parameter values, got {type(self.validation).__name__}"
            )
        trajectories = (
            _as_trajectories(self.U, self.mus, fom, "GivenTrajectories"),
            None
            if self.validation is None
            else _as_trajectories(*self.validation, fom, "GivenTrajectories validation"),
        )
        self._read = (key, trajectories)
        return trajectories

    @staticmethod
    def _parameters(trajectories, fom) -> list:
        """The parameter values of ``trajectories`` (``(VectorArrays, Mus)``): ``None`` each for a parameter-free FOM."""
        return trajectories[1] if fom.parameters else [None] * len(trajectories[0])

    def validation_parameters(self, reductor) -> list:
        """The parameters of the validation trajectories (``[]`` without them)."""
        if self.validation is None:
            return []
        return self._parameters(self._trajectories(reductor.fom)[1], reductor.fom)

    def sample(self, reductor):
        trajectories, validation = self._trajectories(reductor.fom)
        horizon = self._horizon(reductor.fom)
        train = _projected_pairs(reductor, reductor.training_parameters, horizon, trajectories[0])
        val = (
            None
            if validation is None
            else _projected_pairs(reductor, self._parameters(validation, reductor.fom), horizon, validation[0])
        )
        return train, val, None


def _check_sizes(name: str, what: str, dim_given: int, dim: int, n_mu_given: int, n_mu: int) -> None:
    """``ValueError`` naming ``name`` when its state or parameter dimension does not fit the reductor's."""
    if dim_given != dim:
        raise ValueError(
            f"{name} has {what} of dimension {dim_given}, the basis has 2n = {dim}: give reduced "
            f"coordinates (reductor.project(U) of full states)"
        )
    if n_mu_given != n_mu:
        raise ValueError(
            f"{name} has parameter vectors of dimension {n_mu_given}, the flow map's parameters have "
            f"dimension {n_mu} (mu_to_vector order: values sorted by parameter name)"
        )


class GivenSamples(Parametrized):
    """Flow-map samples in reduced coordinates that the caller already has.

    Parameters
    ----------
    data : FlowMapData
        Training pairs ``x1 = Phi(x0)`` over the reductor's ``dt``, reduced states of dimension ``2n``,
        parameter vectors of the flow parameters (:func:`~sympredict.systems.flowmaps.mu_to_vector` order).
    validation : FlowMapData or TrajectoryData or None, default=None
        Validation samples, or validation trajectories on the macro grid (uniform steps ``dt``).
    parameter_space : pyMOR ParameterSpace or None, default=None
        Box for the parameter scaling (default: box of the samples' parameters).
    """

    exact_flow = False

    def __init__(self, data, validation=None, parameter_space=None):
        self.data = data
        self.validation = validation
        self.parameter_space = parameter_space

    @staticmethod
    def check_model(fom) -> None:
        _check_fom(fom, ("solution_space", "initial_data", "T", "parameters"), "GivenSamples")

    def check(self, reductor) -> Optional[list]:
        """The samples' sizes and steps checked; returns the training parameters (the samples' distinct parameter
        values where the flow takes all of the FOM's parameters, else ``None``)."""
        fom = reductor.fom
        self.check_model(fom)
        _check_parameter_space(self.parameter_space, fom)
        dim, n_mu, dt = reductor.dim, reductor.flow_parameters.dim, reductor.dt
        for name, d in (("data", self.data), ("validation", self.validation)):
            if d is None:
                continue
            if isinstance(d, TrajectoryData) and name == "validation":
                _check_sizes(name, "trajectories", d.states.shape[2], dim, d.mu.shape[1], n_mu)
                if d.dt is None:
                    raise ValueError(
                        "validation has non-uniform times; the reductor's validation rollouts take "
                        f"uniform steps of its dt = {dt!r}"
                    )
                if not np.isclose(d.dt, dt, rtol=1e-12, atol=0):
                    raise ValueError(f"validation has the step {d.dt!r}, the reductor's dt is {dt!r}")
                continue
            if not isinstance(d, FlowMapData):
                raise ValueError(
                    f"GivenSamples: {name} must be a sympredict.data.FlowMapData of reduced samples"
                    + (" or a TrajectoryData" if name == "validation" else "")
                    + f", got {type(d).__name__}"
                )
            _check_sizes(name, "states", d.x0.shape[1], dim, d.mu.shape[1], n_mu)
            if not np.allclose(d.dt, dt, rtol=1e-12, atol=0):
                raise ValueError(
                    f"{name} has steps {np.unique(d.dt)[:5].tolist()}, the reductor's dt is {dt!r}: a "
                    f"reductor learns one macro step"
                )
        if not fom.parameters:
            return [None]
        if reductor.flow_parameters == fom.parameters:
            return [fom.parameters.parse(row) for row in np.unique(self.data.mu, axis=0)]
        return None

    def validation_parameters(self, reductor) -> list:
        return []

    def sample(self, reductor):
        """``(data, validation, None)`` as given (already with the flow parameters' vectors)."""
        return self.data, self.validation, None
