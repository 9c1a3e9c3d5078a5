"""Symplectic kernel reductor: ``fom -> reductor.reduce() -> rom -> reductor.reconstruct()`` on pyMOR.

The flow-map sibling of pyMOR's ``DataDrivenReductor``: instead of a regressor
``mu -> trajectory`` it learns the reduced flow map ``x_red(t) -> x_red(t + dt)``
with a :class:`~sympredict.SymplecticKernelPredictor` (every step symplectic),
so the ROM runs past the training horizon and for any initial reduced state.

::

    reductor = SymplecticKernelReductor(fom, RB, dt, GalerkinSamples(training_parameters),
                                        SymplecticKernelPredictor(max_centers=500))
    rom = reductor.reduce()           # a pyMOR Model, rom.parameters == fom.parameters
    U_red = rom.solve(mu)             # reduced states at t_k = k dt, k = 0..round(fom.T / dt)
    U = reductor.reconstruct(U_red)   # VectorArray in fom.solution_space

The reductor composes parts, each with one job:

* the samples (:mod:`sympredict.mor.samples`): :class:`~sympredict.mor.samples.GalerkinSamples` (intrusive,
  the exact flow of the symplectic Galerkin ROM), :class:`~sympredict.mor.samples.ProjectedTrajectories`
  (non-intrusive, ``fom.solve`` only), :class:`~sympredict.mor.samples.GivenTrajectories` and
  :class:`~sympredict.mor.samples.GivenSamples` (the caller's data);
* the existence check (:mod:`sympredict.mor.existence`): before training, in the coordinates the estimator is
  trained in, that the generating function exists at ``dt`` (type II, or the midpoint form for an estimator with
  ``update="midpoint"``; fails with the largest admissible ``dt``);
* the estimator: every setting of the learned step (kernels or its own ``search``, budget, update, trainer);
  :class:`~sympredict.mor.selection.ValidationSelection` chooses kernels and ridge term on the validation data
  instead;
* the split (:class:`~sympredict.mor.parts.QuadraticSplit`): the exact linear flow ``L_h`` of the quadratic part
  ``A(mu)`` over half a step split off, the step ``L_h o S o L_h``
  (:class:`~sympredict.flowmap.splitting.SplitKernelPredictor`), only ``S`` learned;
* the training coordinates (:class:`~sympredict.mor.parts.TrainingScaling`, :mod:`sympredict.flowmap.scaling`):
  parameters mapped to ``[0, 1]^d``, ``dt`` to 1, states by a conformally symplectic diagonal map, so the ROM's
  step stays symplectic.

Parameter vectors: :func:`~sympredict.systems.flowmaps.mu_to_vector` (values sorted by
parameter name, each flattened: ``Mu.to_numpy``'s order).
"""

from __future__ import annotations

import time
import warnings
from typing import Optional

import numpy as np
from pymor.algorithms.projection import project
from pymor.algorithms.symplectic import SymplecticBasis
from pymor.core.base import BasicObject
from pymor.operators.symplectic import CanonicalSymplecticFormOperator
from pymor.models.interface import Model
from pymor.vectorarrays.numpy import NumpyVectorSpace

from sympredict._checks import as_flag, as_parameter, as_real
from sympredict.base import clone
from sympredict.data import FlowMapData, TrajectoryData
from sympredict.exceptions import ExtrapolationWarning, NewtonConvergenceError
from sympredict.systems.linear_flow import QuadraticPart
from sympredict.systems.flowmaps import linear_system_from_pymor, mu_to_vector, mus_to_matrix, parameter_box, parse_mu
from sympredict.symplectic.metrics import canonical_J
from sympredict.estimators.predictor import SymplecticKernelPredictor
from sympredict.mor.basis import SymplecticROM
from sympredict.mor.existence import check_existence, split_pairs
from sympredict.mor.parts import QuadraticSplit, TrainingScaling
from sympredict.mor.samples import GalerkinSamples, GivenSamples, GivenTrajectories
from sympredict.mor.selection import DefaultEstimator, ValidationSelection
from sympredict.flowmap.scaling import BoxScaling, NormalizedFlowMap, SymplecticScaling, scaled_quadratic_part
from sympredict.flowmap.splitting import SplitKernelPredictor

__all__ = ["SymplecticKernelReductor", "SymplecticKernelModel", "check_symplectic_basis", "basis_matrix"]

_SYMPLECTIC_TOL = 1e-8


def basis_matrix(RB) -> np.ndarray:
    """The basis ``V = [E, F]`` of a pyMOR ``SymplecticBasis`` as a dense C-ordered (2N, 2n) array, rows ``(q, p)``.

    pyMOR's ``to_numpy()`` is the transpose of a C array (Fortran order); fitted state keeps one layout.
    """
    return np.ascontiguousarray(_to_columns(RB.to_array()), dtype=float)


def _to_columns(U) -> np.ndarray:
    """A VectorArray of length K in a (blocked) phase space as a (dim, K) array (blocks stacked)."""
    if hasattr(U, "blocks"):
        return np.vstack([b.to_numpy() for b in U.blocks])
    return U.to_numpy()


def check_symplectic_basis(RB, phase_space=None, tol: float = _SYMPLECTIC_TOL) -> float:
    """``max |V^T J_2N V - J_2n|`` of a pyMOR ``SymplecticBasis``; ``ValueError`` if not one, or above ``tol``."""

    if not isinstance(RB, SymplecticBasis):
        raise ValueError(
            f"RB must be a pyMOR SymplecticBasis (e.g. sympredict.mor.basis.complex_svd_basis(...).to_pymor(...)), "
            f"got {type(RB).__name__}"
        )
    if phase_space is not None and RB.phase_space != phase_space:
        raise ValueError(
            f"RB lives in {RB.phase_space}, but the FOM's solution space is {phase_space}: mismatched spaces"
        )
    if len(RB) == 0:
        raise ValueError("RB is empty")
    V = RB.to_array()
    J = CanonicalSymplecticFormOperator(RB.phase_space)
    n = len(RB)
    Jn = canonical_J(2 * n)
    defect = float(np.abs(V.inner(J.apply(V)) - Jn).max())
    if not defect <= tol:
        raise ValueError(f"RB is not symplectic: max |V^T J V - J| = {defect:.2e} > {tol:.0e}")
    return defect


class SymplecticKernelModel(Model):
    """A pyMOR model stepping a learned symplectic flow map in reduced coordinates.

    ``solve(mu)`` returns the reduced states at ``t_k = k dt``, ``k = 0..round(T / dt)``;
    ``rom.with_(T=...)`` solves over a longer horizon (a flow map runs past the
    training horizon).  Online cost: one ``(2n,)`` projection of the initial data
    and ``round(T/dt)`` predictor steps, ``O(K m (2n)^2)`` for ``m`` centres.

    Parameters
    ----------
    flow_map : NormalizedFlowMap
        The fitted predictor and its scalings.
    initial_data : pyMOR Operator
        Reduced initial data ``V+ u_0(mu)`` (a vector-like operator).
    T, dt : float
    parameters : pyMOR Parameters
        Those of the FOM.
    flow_parameters : pyMOR Parameters, optional
        Those the flow map takes (default ``parameters``); the others enter the initial data only.
    """

    def __init__(self, flow_map, initial_data, T, dt, parameters, name=None, flow_parameters=None):
        super().__init__(name=name)
        self.__auto_init(locals())
        self.solution_space = NumpyVectorSpace(initial_data.range.dim)
        self.parameters_own = parameters
        self.n_steps = int(round(T / dt))

    def solve(self, mu=None, input=None, return_error_estimate=False):
        """Reduced states at ``t_k = k dt`` (a VectorArray of length ``round(T/dt) + 1``).

        Raises
        ------
        ValueError
            If ``mu`` does not match the FOM's parameters.
        NewtonConvergenceError
            If an implicit step fails; it carries the states computed before the failure:
            ``trajectory`` (a VectorArray in ``solution_space``: reduced coordinates, ``k + 1`` states;
            ``reductor.reconstruct(exc.trajectory)`` gives full states), ``completed_steps`` (``k``) and
            ``trajectory_kind`` (``"reduced"``).
        """
        return super().solve(parse_mu(mu, self.parameters), input, return_error_estimate)

    def _attach_partial_trajectory(self, exc, x0, mu_arg, mu) -> None:
        """Give a Newton failure the reduced trajectory up to the failed step (the rollout is deterministic, so
        rerunning its first ``exc.step`` steps reproduces those states): ``exc.trajectory`` (a VectorArray in
        ``solution_space``, reduced coordinates), ``exc.completed_steps``, ``exc.trajectory_kind = "reduced"``."""
        k = exc.step if exc.step is not None else 0
        partial = x0 if k == 0 else self.flow_map.rollout(x0, int(k), mu=mu_arg, dt=self.dt)[0]
        exc.trajectory = self.solution_space.from_numpy(np.atleast_2d(partial).T)
        exc.completed_steps = int(k)
        exc.trajectory_kind = "reduced"
        self.logger.error(
            f"Newton failed at macro step {k + 1} of {self.n_steps} (mu = {mu}): the exception carries "
            f"the reduced trajectory of the {k} completed steps (exc.trajectory; "
            f"reductor.reconstruct(exc.trajectory) for full states)"
        )

    def _compute(self, quantities, data, mu):
        if "solution" in quantities:
            x0 = self.initial_data.as_range_array(mu).to_numpy().reshape(1, -1)
            vec = mu_to_vector(mu, self.parameters)
            if self.flow_parameters is not None:
                vec = _subvector(vec, self.parameters, self.flow_parameters)
            mu_arg = vec if vec.size else None
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always", ExtrapolationWarning)
                try:
                    traj = self.flow_map.rollout(x0, self.n_steps, mu=mu_arg, dt=self.dt)[0]
                except NewtonConvergenceError as exc:
                    self._attach_partial_trajectory(exc, x0, mu_arg, mu)
                    raise
            for w in caught:  # logged, not raised: a ROM run past T or near the data's edge extrapolates by design
                if issubclass(w.category, ExtrapolationWarning):
                    self.logger.warning(str(w.message))
                else:
                    warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
            data["solution"] = self.solution_space.from_numpy(traj.T)
            quantities.remove("solution")
        super()._compute(quantities, data, mu)


def _subvector(vec: np.ndarray, parameters, sub) -> np.ndarray:
    """The components of a parameter vector of ``parameters`` (:func:`mu_to_vector` order) that belong to ``sub``."""
    return np.asarray(vec, dtype=float)[..., _sub_index(parameters, sub)]


def _sub_index(parameters, sub) -> np.ndarray:
    """Indices of the parameters ``sub`` in the vectors of ``parameters`` (both sorted by name)."""
    offsets, i = {}, 0
    for k in sorted(parameters):
        offsets[k] = i
        i += parameters[k]
    return np.array([offsets[k] + j for k in sorted(sub) for j in range(sub[k])], dtype=int)


def _operator_parameters(fom) -> set:
    """Names of the parameters the FOM's evolution depends on (its operators other than the initial data)."""
    names = set()
    for attr in ("operator", "H_op", "h", "mass", "rhs"):
        op = getattr(fom, attr, None)
        if op is not None and hasattr(op, "parameters"):
            names |= set(op.parameters)
    return names


def _flow_parameters(fom, flow_parameters):
    """``fom.parameters`` restricted to the names ``flow_parameters`` (``None``: all), checked."""
    from pymor.parameters.base import Parameters

    if flow_parameters is None:
        return fom.parameters
    if isinstance(flow_parameters, str) or not all(isinstance(k, str) for k in flow_parameters):
        raise ValueError(
            f"flow_parameters must be a sequence of parameter names (e.g. ('c',)), got {flow_parameters!r}"
        )
    names = set(flow_parameters)
    unknown = names - set(fom.parameters)
    if unknown:
        raise ValueError(f"flow_parameters {sorted(unknown)} are not parameters of the FOM ({dict(fom.parameters)})")
    needed = _operator_parameters(fom) & set(fom.parameters)
    if needed - names:
        raise ValueError(
            f"the FOM's evolution depends on {sorted(needed)}: flow_parameters={sorted(names)} leaves out "
            f"{sorted(needed - names)} (only parameters of the initial data may be left out)"
        )
    return Parameters({k: fom.parameters[k] for k in names})


def _check_estimator(estimator) -> None:
    missing = [
        a
        for a in ("fit", "step", "rollout", "step_jacobian", "get_params")
        if not callable(getattr(estimator, a, None))
    ]
    if isinstance(estimator, type) or missing:
        raise ValueError(
            f"estimator must be an estimator instance (e.g. SymplecticKernelPredictor(...)) with fit, step, "
            f"rollout, step_jacobian and get_params, or None (DefaultEstimator()), got {estimator!r}"
            + (f" (lacks {', '.join(missing)})" if missing and not isinstance(estimator, type) else "")
        )
    if isinstance(estimator, SplitKernelPredictor):
        raise ValueError(
            "estimator=SplitKernelPredictor(...): give the inner SymplecticKernelPredictor as estimator and "
            "split=QuadraticSplit(A): the reductor builds the split in its scaled coordinates"
        )


def _part(value, cls, name: str, example: str):
    """``value`` (an instance of ``cls``) checked, or ``ValueError`` naming the argument, the value and the fix."""
    if not isinstance(value, cls):
        raise ValueError(f"{name} must be a {cls.__name__} (e.g. {name}={example}) or None, got {value!r}")
    return value


class SymplecticKernelReductor(BasicObject):
    """Learn a symplectic reduced flow map of a pyMOR Hamiltonian model.

    Parameters
    ----------
    fom : pymor.models.interface.Model
        The full-order model: what ``samples`` needs (a ``QuadraticHamiltonianModel`` for
        :class:`~sympredict.mor.samples.GalerkinSamples`; any time-dependent pyMOR model with ``solve``,
        ``solution_space``, ``initial_data`` and ``T`` for :class:`~sympredict.mor.samples.ProjectedTrajectories`;
        a model with ``solution_space``, ``initial_data`` and ``T`` with the caller's data, from whose initial
        data the ROM starts).  Any parameters (names, dimensions) or none.
    RB : pymor.algorithms.symplectic.SymplecticBasis
        Symplectic basis of ``fom.solution_space`` (``V^T J V = J`` checked).
    dt : float
        Macro step of the ROM.
    samples : GalerkinSamples, ProjectedTrajectories, GivenTrajectories or GivenSamples, default=None
        Where the training and validation samples come from (:mod:`sympredict.mor.samples`; its training
        parameters, sizes, seed, parameter box).  ``None``: ``GalerkinSamples()`` (a parameter-free FOM).
    estimator : estimator or None, default=None
        The one place for every setting of the learned step: an unfitted estimator with
        ``fit``/``rollout``/``step``/``step_jacobian`` (cloned, never modified), with all its parts
        (kernels, ``max_centers``, ``update``, ``trainer``, ``solver``, ``search``).  A
        :class:`SymplecticKernelPredictor` with kernels left ``None`` chooses them itself on held-out samples
        (its ``search``); with ``update=None`` the reductor sets the form that exists at ``dt`` (type II or
        midpoint) or, where both do, leaves the choice to it; what it chose is ``choice_["estimator"]``.
        ``None``: :class:`~sympredict.mor.selection.DefaultEstimator` (``DefaultEstimator(max_centers=...)`` for
        another budget).  Accuracy on demand goes through it too: ``DefaultEstimator(target_error=1e-3)``, or a
        given estimator whose trainer has a ``target_error``; the learned step then stops at the smallest
        number of centres whose median relative one-step error on the validation samples (in the trained
        coordinates) meets the target, and warns (:class:`~sympredict.exceptions.AccuracyWarning`, naming the
        limit) where it cannot.  The reduced dimension is ``RB``'s: the reductor does not choose it.
    selection : ValidationSelection or None, default=None
        Kernels and ridge term chosen on the validation data (:mod:`sympredict.mor.selection`); ``None``: the
        estimator is trained as given (the default estimator's kernels on its IMQ grids).
    split : QuadraticSplit or None, default=None
        The quadratic part ``A(mu)`` of the reduced Hamiltonian whose exact linear flow is split off the learned
        step, always or only where the existence check needs it (:class:`~sympredict.mor.parts.QuadraticSplit`).
    scaling : TrainingScaling or None, default=None
        The coordinates the estimator is trained in (:class:`~sympredict.mor.parts.TrainingScaling`; ``None``:
        ``TrainingScaling()``: states ``"diag"``, parameters ``"box"``, time ``"step"``).
    flow_parameters : sequence of str or None, default=None
        The parameters the flow map takes (default: all of the FOM's).  Parameters that enter only the initial
        data (checked: the FOM's other operators must not depend on them) are left out, so the kernel
        interpolates in the others only; samples, parameter box and split use the flow parameters' vectors.
    check_existence : bool, default=True
        Check that the generating function exists at ``dt`` before training
        (:func:`~sympredict.mor.existence.check_existence`, in the trained coordinates); on the caller's data from
        least-squares linear maps per parameter (a check that cannot run is logged as not done).
    """

    def __init__(
        self,
        fom,
        RB,
        dt,
        samples=None,
        estimator=None,
        *,
        selection=None,
        split=None,
        scaling=None,
        flow_parameters=None,
        check_existence: bool = True,
    ):
        samples = GalerkinSamples() if samples is None else samples
        if not all(callable(getattr(samples, a, None)) for a in ("check_model", "check", "sample")):
            raise ValueError(
                f"samples must be GalerkinSamples(...), ProjectedTrajectories(...), "
                f"GivenTrajectories(U, mus) or GivenSamples(data) (sympredict.mor.samples), got {samples!r}"
            )
        if not isinstance(fom, Model):
            raise ValueError(f"fom must be a time-dependent pyMOR Model, got {type(fom).__name__}")
        self.fom, self.samples = fom, samples
        self.estimator = DefaultEstimator() if estimator is None else estimator
        self.selection = (
            None
            if selection is None
            else _part(
                selection, ValidationSelection, "selection", "ValidationSelection(state_kernels=[IMQ(0.1)])"
            ).check()
        )
        self.split = None if split is None else _part(split, QuadraticSplit, "split", "QuadraticSplit(A)")
        self.scaling = (
            TrainingScaling()
            if scaling is None
            else _part(scaling, TrainingScaling, "scaling", "TrainingScaling('diag')")
        ).check()
        self.check_existence = as_flag(check_existence, "check_existence")
        if isinstance(self.estimator, DefaultEstimator):
            self.estimator.check()
        else:
            _check_estimator(self.estimator)
        self.dt = float(as_real(dt, "dt", positive=True))
        samples.check_model(fom)  # before the basis is compared with the model's space
        self.flow_parameters = _flow_parameters(fom, flow_parameters)
        self._flow_index = _sub_index(fom.parameters, self.flow_parameters)
        self._flow_subset = self.flow_parameters != fom.parameters
        check_symplectic_basis(RB, fom.solution_space)
        self.RB = RB
        self.V = basis_matrix(RB)  # (2N, 2n)
        self.V_plus_array = RB.transposed_symplectic_inverse().to_array()
        self.dim = 2 * len(RB)
        if self.split is not None:
            self.split.check(self.dim, self.flow_parameters.dim)
            if self.split.fallback and not self.check_existence:
                raise ValueError(
                    "split=QuadraticSplit(A, fallback=True) is split off where the existence check finds "
                    "no generating function without it; check_existence=False never checks: give "
                    "QuadraticSplit(A) to always split, or check_existence=True"
                )
        if self.scaling.state == "williamson" and not samples.exact_flow:
            raise ValueError(
                f"TrainingScaling(state='williamson') needs the reduced operator of the Galerkin ROM: use "
                f"samples=GalerkinSamples(...) or state='diag' (samples={type(samples).__name__})"
            )
        if isinstance(self.estimator, SymplecticKernelPredictor):
            self.estimator.check_params()  # its settings, before any FOM solve (fit would check them after sampling)
        training_parameters = samples.check(self)
        self.training_parameters = (
            None
            if training_parameters is None or len(training_parameters) == 0
            else [parse_mu(m, fom.parameters) for m in training_parameters]
        )
        parameter_space = samples.parameter_space
        if self.training_parameters is not None or parameter_space is not None:
            # the FOM's parameter box (validation draws), and the flow parameters' part of it (their scaling)
            self.mu_lo, self.mu_hi = parameter_box(self.training_parameters, fom.parameters, parameter_space)
            self.flow_lo, self.flow_hi = self.mu_lo[self._flow_index], self.mu_hi[self._flow_index]
            if parameter_space is not None:
                self._check_inside_space()
        else:  # the caller's samples without training parameters: the box of its samples
            self.mu_lo = self.mu_hi = None
            self.flow_lo, self.flow_hi = samples.data.mu.min(axis=0), samples.data.mu.max(axis=0)
        regularizations = None if self.selection is None else self.selection.regularizations_
        if (
            regularizations is not None
            and isinstance(samples, (GivenSamples, GivenTrajectories))
            and samples.validation is None
        ):
            raise ValueError(
                f"ValidationSelection(regularizations={self.selection.regularizations!r}) scores each "
                f"ridge term on validation data: give {type(samples).__name__}(..., validation=...)"
            )

    def _check_inside_space(self) -> None:
        """``ValueError`` naming the first training parameter (given, of the trajectories, of the samples) outside
        ``parameter_space``: the scaling maps the box onto [0, 1], so data outside it are extrapolation."""
        if self.training_parameters and self.fom.parameters:
            self._refuse_outside("training_parameters", self._mu_rows(self.training_parameters), self.mu_lo, self.mu_hi)
        if isinstance(self.samples, GivenSamples):
            self._refuse_outside("data", self.samples.data.mu, self.flow_lo, self.flow_hi)

    @staticmethod
    def _refuse_outside(what: str, rows: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> None:
        if not len(rows) or rows.shape[1] != len(lo):
            return
        tol = 1e-9 * np.maximum(np.abs(lo), np.abs(hi)) + 1e-300
        out = np.flatnonzero(((rows < lo - tol) | (rows > hi + tol)).any(axis=1))
        if out.size:
            raise ValueError(
                f"{what}: parameter {rows[out[0]].tolist()} (and {out.size - 1} more) lies outside "
                f"parameter_space [{lo.tolist()}, {hi.tolist()}]: give a parameter_space that contains "
                "the training parameters (or leave it out: the box of the training parameters)"
            )

    # ------------------------------------------------------------ projection
    def project(self, U) -> np.ndarray:
        """Reduced coordinates ``V+ U`` of a VectorArray in ``fom.solution_space``, shape (len(U), 2n).

        Parameters
        ----------
        U : VectorArray
            Full states in ``fom.solution_space``.

        Returns
        -------
        ndarray of shape (len(U), 2n)
        """
        if U.space != self.fom.solution_space:
            raise ValueError(f"U must lie in the FOM's solution space {self.fom.solution_space}, got {U.space}")
        return self.V_plus_array.inner(U).T

    def reconstruct(self, U_red):
        """``V U_red``: a VectorArray in ``fom.solution_space``.

        Parameters
        ----------
        U_red : VectorArray or array_like of shape (K, 2n) or (2n,)
            What ``rom.solve`` returns (a VectorArray of dimension ``2n``), or reduced states in rows.

        Returns
        -------
        VectorArray
            ``len(U_red)`` full states in ``fom.solution_space``.
        """
        if isinstance(U_red, np.ndarray) or isinstance(U_red, (list, tuple)):
            arr = np.atleast_2d(np.asarray(U_red, dtype=float))
            if arr.ndim != 2 or arr.shape[1] != self.dim:
                raise ValueError(
                    f"U_red as an array must have shape (K, 2n) = (K, {self.dim}) (reduced states in "
                    f"rows), got {np.shape(U_red)}; or give what rom.solve returns"
                )
            return self.RB.to_array().lincomb(arr.T)  # pyMOR: coefficients (2n, len)
        if not hasattr(U_red, "space"):
            raise ValueError(
                f"U_red must be a VectorArray of the ROM (what rom.solve returns) or an array (K, 2n), "
                f"got {type(U_red).__name__}"
            )
        if U_red.space.dim != self.dim:
            raise ValueError(f"U_red must have dimension 2n = {self.dim}, got {U_red.space.dim}")
        return self.RB.to_array().lincomb(U_red.to_numpy())  # pyMOR: coefficients (2n, len)

    def _reduced_initial_data(self):
        return project(self.fom.initial_data, self.V_plus_array, None)

    def _initial_state(self, mu) -> np.ndarray:
        return self.project(self.fom.initial_data.as_range_array(mu))[0]

    # ------------------------------------------------------------ data
    def _mu_rows(self, mus) -> np.ndarray:
        return mus_to_matrix(mus, self.fom.parameters) if self.fom.parameters else np.zeros((len(mus), 0))

    def validation_parameters(self) -> list:
        """The validation parameters of the samples (drawn in the box, or those of given validation trajectories)."""
        return self.samples.validation_parameters(self)

    def _galerkin(self):
        """The symplectic Galerkin ROM of the FOM (:class:`~sympredict.mor.basis.SymplecticROM`: pyMOR's
        ``QuadraticHamiltonianRBReductor``) and its reduced quadratic Hamiltonian with exact flows, built once:
        ``galerkin`` (the ROM), ``galerkin_rom`` (its pyMOR model), ``reduced_system``."""
        if not hasattr(self, "galerkin_rom"):
            self.galerkin = SymplecticROM(self.fom, self.RB, symplectic_tol=_SYMPLECTIC_TOL)
            self.galerkin_rom = self.galerkin.rom
            self.reduced_system = linear_system_from_pymor(self.galerkin_rom)
        return self.reduced_system

    def _default(self) -> bool:
        return isinstance(self.estimator, DefaultEstimator)

    def _given_update(self) -> Optional[str]:
        """The update the caller fixed (the given estimator's, by name), or ``None`` where the reductor chooses."""
        update = None if self._default() else getattr(self.estimator, "update", None)
        return update if update is None or isinstance(update, str) else getattr(update, "name", update)

    def _update(self) -> Optional[str]:
        """The generating-function update checked and trained: the given estimator's, else the one chosen for
        it (``choice_["update"]``; ``None``: left to the estimator, both forms exist at ``dt``)."""
        given = self._given_update()
        if given is not None:
            return given
        default = "symplectic_euler" if self._default() else None
        return getattr(self, "choice_", {}).get("update", default)

    def _to_flow(self, d: FlowMapData) -> FlowMapData:
        """Samples with the FOM's parameter vectors -> with the flow parameters' vectors."""
        if not self._flow_subset:
            return d
        return FlowMapData(d.x0, d.x1, d.mu[:, self._flow_index] if self.flow_parameters else None, d.dt)

    def split_pairs(self, data: FlowMapData) -> FlowMapData:
        """``S``'s samples ``(L_h x0, L_{-h} x1)``, ``L_h = expm(dt/2 J A(mu))``, of samples ``x1 = Phi(x0)``
        (the identity where no split is in use), in reduced coordinates."""
        return data if self._split is None else split_pairs(data, self._split)

    def training_data(self):
        """Training and validation data in original reduced coordinates, parameter vectors of the flow parameters.

        Returns ``(train, val)``: :class:`~sympredict.data.FlowMapData`, and for the caller's samples its
        validation data as given (``FlowMapData``, :class:`~sympredict.data.TrajectoryData` or ``None``).  Runs the
        existence check (``existence_``, ``choice_``).
        """
        train, val, reference = self.samples.sample(self)
        if not isinstance(self.samples, GivenSamples):
            train, val = self._to_flow(train), None if val is None else self._to_flow(val)
        self._split = None if self.split is None or self.split.fallback else self.split.quadratic
        if self.check_existence:
            self.existence_, self.choice_, self._split = check_existence(
                train,
                self._fit_state_scaling(train),
                self.dt,
                given_update=self._given_update(),
                open_estimator=not self._default(),
                split=self.split,
                reference=reference,
                log=self.logger,
            )
            self.existence_["coordinates"] = f"trained (TrainingScaling state={self.scaling.state!r})"
        return train, val

    def _fit_state_scaling(self, train: FlowMapData) -> SymplecticScaling:
        """The state scaling of the predictor's coordinates (``scaling.state``), fitted on the training states."""
        reference = None
        if self.scaling.state == "williamson":
            centre = 0.5 * (self.mu_lo + self.mu_hi)
            reference = self._galerkin().matrix(centre)
        return SymplecticScaling(self.scaling.state, reference).fit(np.concatenate([train.x0, train.x1]))

    # ------------------------------------------------------------ reduce
    def scaled_training_data(self):
        """Training and validation data in the predictor's coordinates, and the scalings that map to them.

        Samples the data (:meth:`training_data`, kept as ``train_data_`` and ``validation_data_``), fits the state
        scaling and, when the parameters vary, the box scaling of the parameters (``scaling``); the step becomes
        the time unit.  :meth:`reduce` fits its predictor on exactly these data, so a kernel search run on them
        (e.g. :func:`~sympredict.estimators.selection.select_kernels` with another update) chooses for the model
        that :meth:`reduce` trains.

        Returns
        -------
        s_train, s_val : FlowMapData
            Scaled states, parameters in ``[0, 1]^d`` (``None`` when they do not vary), ``dt = 1``
            (each as given where the scaling is ``"none"``); ``s_val`` is ``None`` without validation data,
            the consecutive states of validation trajectories.
        state_scaling : SymplecticScaling
        mu_scaling : BoxScaling or None
        """
        with self.logger.block(f"flow-map data ({type(self.samples).__name__}), 2n = {self.dim}, dt = {self.dt!r}"):
            train, val = self.training_data()
        self.train_data_, self.validation_data_ = train, val
        if isinstance(val, TrajectoryData):  # validation trajectories: their consecutive states for the greedy's E_val
            val = val.pairs()
        vary_mu = train.mu.shape[1] > 0 and bool(np.any(np.ptp(train.mu, axis=0) > 0))
        state_scaling = self._fit_state_scaling(train)
        mu_scaling = None
        if vary_mu:
            d = train.mu.shape[1]
            # "none": the identity map (lo = 0, width = 1), so the predictor sees the parameter vectors unchanged
            mu_scaling = (
                BoxScaling().fit(train.mu, self.flow_lo, self.flow_hi)
                if self.scaling.parameters == "box"
                else BoxScaling().fit(train.mu, np.zeros(d), np.ones(d))
            )
        self.tau_ = self.dt if self.scaling.time == "step" else 1.0

        assert np.allclose(train.dt, self.dt) and (val is None or np.allclose(val.dt, self.dt))

        def scaled(d):
            if d is None:
                return None
            return FlowMapData(
                state_scaling.transform(d.x0),
                state_scaling.transform(d.x1),
                mu_scaling.transform(d.mu) if vary_mu else None,
                np.ones(len(d)) if self.scaling.time == "step" else d.dt,
            )  # time unit dt

        return scaled(train), scaled(val), state_scaling, mu_scaling

    def _fit(self, predictor, s_train, s_val, vary_mu, state_scaling, mu_scaling):
        """Fit ``predictor`` (inside the split, if any) on the scaled data; the flow map in reduced coordinates."""
        model = predictor
        if self._split is not None:
            quad = self._split
            if not vary_mu and quad.checked()[1].shape[1]:  # one training parameter: A at that parameter
                quad = QuadraticPart(quad.hessian(self.train_data_.mu[:1], 1))
            model = SplitKernelPredictor(predictor, scaled_quadratic_part(quad, state_scaling, mu_scaling, self.tau_))
        model.fit(
            s_train.x0,
            s_train.x1,
            mu=s_train.mu if vary_mu else None,
            dt=s_train.dt,
            validation=None if s_val is None else (s_val.x0, s_val.x1, s_val.mu if vary_mu else None, s_val.dt),
        )
        flow_map = NormalizedFlowMap(
            model, state_scaling, mu_scaling if vary_mu else None, self.tau_, parameters=self.flow_parameters
        )
        if not vary_mu and self.flow_parameters:
            # one training parameter: the predictor has no mu input, the ROM accepts only that mu
            flow_map = _FixedMuFlowMap(flow_map, self.train_data_.mu[0], parameters=self.flow_parameters)
        return model, flow_map

    def validation_score(self, flow_map, validation=None) -> float:
        """Mean relative error of ``flow_map`` (reduced coordinates) on validation data (default ``validation_data_``).

        ``TrajectoryData``: rollouts from the first states over all steps, ``mean |x_k - X_k| / |X_k|`` over
        trajectories and ``k >= 1``; ``FlowMapData``: one step from each ``x0`` against ``x1``.  ``inf`` for a failed
        or non-finite prediction.
        """
        val = self.validation_data_ if validation is None else validation
        try:
            with warnings.catch_warnings():  # a candidate may extrapolate or fail: its score says so
                warnings.simplefilter("ignore")
                if isinstance(val, TrajectoryData):
                    ref = val.states[:, 1:]
                    pred = flow_map.rollout(
                        val.states[:, 0], ref.shape[1], mu=val.mu if val.mu.shape[1] else None, dt=self.dt
                    )[:, 1:]
                else:
                    ref = val.x1
                    pred = flow_map.step(val.x0, mu=val.mu if val.mu.shape[1] else None, dt=self.dt)
                score = float(np.mean(np.linalg.norm(pred - ref, axis=-1) / np.linalg.norm(ref, axis=-1)))
        except Exception as exc:  # a Newton failure, a non-finite prediction: this candidate cannot be used
            self.logger.info(f"validation rollout failed: {type(exc).__name__}: {exc}")
            return np.inf
        return score if np.isfinite(score) else np.inf

    def reduce(self, T: Optional[float] = None) -> SymplecticKernelModel:
        """Sample data, fit the predictor, return the ROM (horizon ``T``, default ``fom.T``).

        Sets ``predictor_`` (the fitted predictor, in the scaled coordinates; a
        :class:`~sympredict.flowmap.splitting.SplitKernelPredictor` where a split is in use), ``flow_map_`` (the
        ROM's flow map in reduced coordinates), ``selection_`` (where kernels were chosen on validation data),
        ``regularization_`` and ``regularization_table_`` (with ``ValidationSelection(regularizations=...)``: the
        chosen term and ``[{"regularization", "score"}]``, ``score`` ``None`` where not finite), ``choice_``
        (update, reason, split; ``choice_["estimator"]``: what the estimator's own search chose) and
        ``timings_`` (seconds of ``data``, ``selection`` and ``fit``).

        Parameters
        ----------
        T : float, default=None
            Time horizon of the ROM; ``None``: ``fom.T``.

        Returns
        -------
        SymplecticKernelModel
            The reduced-order model (a pyMOR model).
        """
        if isinstance(self.samples, GivenSamples):
            rows = self.samples.data.mu
        else:
            rows = self._mu_rows(self.training_parameters)[:, self._flow_index]
        chooses_mu = self.selection is not None and self.selection.mu_kernels is not None
        if len(np.unique(rows, axis=0)) > 1 and self._lacks_mu_kernel(self.estimator) and not chooses_mu:
            # before any FOM solve (reduce() would find it after sampling)
            raise ValueError(
                "the parameters vary across the training parameters but the estimator has mu_kernel=None "
                "and does not choose one: give it a mu_kernel, or train at one parameter value"
            )
        t0 = time.perf_counter()
        s_train, s_val, state_scaling, mu_scaling = self.scaled_training_data()
        timings = {"data": time.perf_counter() - t0}
        train = self.train_data_
        vary_mu = mu_scaling is not None
        t0 = time.perf_counter()
        if self._split is None:
            search = (s_train, s_val)
        else:  # the kernels of S, compared on S's samples
            search = tuple(
                None if d is None else self._scaled_split_pairs(d, state_scaling, mu_scaling, vary_mu)
                for d in (s_train, s_val)
            )
        selection = self.selection or ValidationSelection().check()
        if self._default():
            base = self.estimator.estimator(self._update())
            predictor, sel = selection.choose_kernels(base, *search, vary_mu, default=True, log=self.logger)
        else:
            given = clone(self.estimator)
            if self._given_update() is None and self._update() is not None:  # the update the existence check chose
                given = given.set_params(update=self._update())
            predictor, sel = selection.choose_kernels(clone(given), *search, vary_mu, default=False, log=self.logger)
            predictor = predictor or given
            if vary_mu and self._lacks_mu_kernel(predictor):
                raise ValueError(
                    "the parameters vary across the training parameters but the estimator has "
                    "mu_kernel=None and does not choose one: give it a mu_kernel"
                )
        if sel is not None:
            self.selection_ = sel
        timings["selection"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        with self.logger.block(
            f"fitting {type(predictor).__name__} on {len(train)} samples"
            + ("" if self._split is None else " (inside the split)")
        ):
            if selection.regularizations_ is None:
                model, flow_map = self._fit(predictor, s_train, s_val, vary_mu, state_scaling, mu_scaling)
            else:
                model, flow_map, self.regularization_, self.regularization_table_ = selection.choose_regularization(
                    predictor,
                    lambda c: self._fit(c, s_train, s_val, vary_mu, state_scaling, mu_scaling),
                    self.validation_score,
                    log=self.logger,
                )
        timings["fit"] = time.perf_counter() - t0
        self.timings_ = timings
        self.predictor_ = model
        self.flow_map_ = flow_map
        if not hasattr(self, "choice_"):
            self.choice_ = {"update": self._update(), "reason": "no existence check (check_existence=False)"}
        inner = getattr(model, "predictor_", model)  # inside a split: the kernel part
        if getattr(inner, "choice_", None):  # what the estimator's own search chose (KernelSearch)
            self.choice_["estimator"] = dict(inner.choice_)
        self._check_one_step(flow_map)
        name = None if self.fom.name is None else "kernel_" + self.fom.name
        return SymplecticKernelModel(
            flow_map,
            self._reduced_initial_data(),
            self.fom.T if T is None else T,
            self.dt,
            self.fom.parameters,
            name=name,
            flow_parameters=self.flow_parameters if self._flow_subset else None,
        )

    @staticmethod
    def _lacks_mu_kernel(estimator) -> bool:
        """An estimator with ``mu_kernel=None`` that does not choose one itself (a
        :class:`SymplecticKernelPredictor` chooses an open ``mu_kernel`` at fit: ``_chooses_open_factors``)."""
        return getattr(estimator, "mu_kernel", True) is None and not getattr(estimator, "_chooses_open_factors", False)

    def _fitted_update(self):
        """The update of the fitted kernel part (``update_``; inside a split its predictor's), by name."""
        inner = getattr(self.predictor_, "predictor_", self.predictor_)
        update = getattr(inner, "update_", None) or self._update()
        return update if update is None or isinstance(update, str) else getattr(update, "name", update)

    def _check_one_step(self, flow_map) -> None:
        """One step of the fitted flow map from the training data's first states, per training parameter;
        ``ValueError`` with the reason and the settings to change when it fails or is not finite (a ROM that
        cannot take one step is never returned)."""
        train = self.train_data_
        rows, first = np.unique(train.mu, axis=0, return_index=True)
        x = train.x0[first]
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", ExtrapolationWarning)
                y = flow_map.step(x, mu=train.mu[first] if train.mu.shape[1] else None, dt=self.dt)
            reason = None if np.all(np.isfinite(y)) else "the step is not finite"
        except NewtonConvergenceError as exc:
            reason = f"Newton's method failed: {exc}"
        if reason is not None:
            raise ValueError(
                f"the fitted ROM cannot take one step of dt = {self.dt!r} from the training data "
                f"({reason}; update = {self._fitted_update()!r}): "
                f"use update='midpoint' (estimator=SymplecticKernelPredictor(update='midpoint')), a "
                f"smaller dt, or a larger basis or budget (the estimator's max_centers)"
            )

    def _scaled_split_pairs(self, d, state_scaling, mu_scaling, vary_mu):
        """``S``'s samples in the predictor's coordinates (what the kernel search compares candidates on)."""
        quad = self._split
        if not vary_mu and quad.checked()[1].shape[1]:
            quad = QuadraticPart(quad.hessian(self.train_data_.mu[:1], 1))
        quad = scaled_quadratic_part(quad, state_scaling, mu_scaling if vary_mu else None, self.tau_)
        return split_pairs(d, quad)


class _FixedMuFlowMap:
    """A flow map trained at one parameter value: refuses others (no parameter input to learn from)."""

    def __init__(self, flow_map: NormalizedFlowMap, mu: np.ndarray, parameters=None):
        self.flow_map, self.mu = flow_map, np.asarray(mu, float)
        self.parameters = parameters
        self.dim_, self.n_mu_ = flow_map.dim_, self.mu.size  # the flow-map protocol (its one mu is accepted)

    def _check(self, mu):
        if mu is not None:
            mu = as_parameter(mu, 1, self.mu.size, parameters=getattr(self, "parameters", None))
        if mu is not None and not np.allclose(np.ravel(mu), self.mu):
            raise ValueError(
                f"this ROM was trained at the single parameter {self.mu.tolist()}: it cannot predict at {np.ravel(mu).tolist()}"
            )

    def rollout(self, x0, n_steps, mu=None, dt=None):
        self._check(mu)
        return self.flow_map.rollout(x0, n_steps, None, dt)

    def step(self, x, mu=None, dt=None):
        self._check(mu)
        return self.flow_map.step(x, None, dt)

    def step_jacobian(self, x, mu=None, dt=None):
        self._check(mu)
        return self.flow_map.step_jacobian(x, None, dt)
