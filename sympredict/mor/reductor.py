"""Symplectic kernel reductor: ``fom -> reductor.reduce() -> rom -> reductor.reconstruct()`` on pyMOR.

The flow-map sibling of pyMOR's ``DataDrivenReductor``: instead of a regressor
``mu -> trajectory`` it learns the reduced flow map ``x_red(t) -> x_red(t + dt)``
with a :class:`~sympredict.SymplecticKernelPredictor` (every step symplectic),
so the ROM runs past the training horizon and for any initial reduced state.

::

    reductor = SymplecticKernelReductor(fom, RB, training_parameters, dt, data="reduced",
                                        estimator=SymplecticKernelPredictor(max_centers=500))
    rom = reductor.reduce()           # a pyMOR Model, rom.parameters == fom.parameters
    U_red = rom.solve(mu)             # reduced states at t_k = k dt, k = 0..round(fom.T / dt)
    U = reductor.reconstruct(U_red)   # VectorArray in fom.solution_space

Data (:mod:`sympredict.systems.flowmaps`):

* ``data="reduced"`` (intrusive): the symplectic Galerkin ROM (pyMOR's
  ``QuadraticHamiltonianRBReductor``; ``H_op`` assembled per ``mu``, so it need
  not be affine) gives the exact reduced flow; samples lie in a neighbourhood
  (relative radius ``radius``) of the reduced trajectories from the FOM's
  initial data, plus the trajectory points;
* ``data="projected"`` (non-intrusive, any time-dependent pyMOR model, linear
  or not, e.g. an ``InstationaryModel`` with a nonlinear operator): only ``fom.solve`` is called; FOM
  trajectories are projected with the symplectic inverse ``V+ = J_2n^T V^T J_2N``
  and consecutive states ``dt`` apart become the samples (``dt`` a multiple of
  the FOM's output step);
* ``trajectories=(U, mus)`` (the caller's FOM trajectories): as ``data="projected"``,
  without solving the FOM;
* ``data=FlowMapData(...)`` (the caller's samples): flow-map pairs in reduced
  coordinates that the caller already has (its own sampling design, projected
  trajectories of its own solver, augmented pairs); ``validation_data`` gives
  the validation samples, or validation trajectories on the macro grid.

Validation data come from parameters drawn at random in the parameter box
(``parameter_space`` or the box of the training parameters), never from the
training parameters.  On them the reductor can choose the state and parameter
kernels (``state_kernels``, ``mu_kernels``; always for the default estimator)
and the ridge term (``regularizations``).  With ``split`` (the quadratic part
``A(mu)`` of the reduced Hamiltonian) the learned step is
``L_h o S o L_h`` (:class:`~sympredict.flowmap.splitting.SplitKernelPredictor`),
``L_h`` the exact flow of ``A`` over half a step, and only ``S`` is learned.  Before training, :func:`~sympredict.systems.flowmaps.check_generating_function`
checks, in the coordinates the estimator is trained in, that its generating function exists at ``dt``
(type II, or the midpoint form for an estimator with ``update="midpoint"``; fails with the
largest admissible ``dt``).  The estimator is trained in scaled coordinates
(:mod:`sympredict.flowmap.scaling`): parameters mapped to ``[0, 1]^d``, ``dt`` to 1,
states by a conformally symplectic diagonal map, so the ROM's step stays symplectic
(``state_scaling``, ``parameter_scaling``, ``time_scaling``; ``"none"`` trains in the
caller's units, where kernel shapes chosen in those units apply unchanged).

Parameter vectors: :func:`~sympredict.systems.flowmaps.mu_to_vector` (values sorted by
parameter name, each flattened: ``Mu.to_numpy``'s order).
"""

from __future__ import annotations

import time
import warnings
from typing import Optional, Sequence

import numpy as np
from scipy.linalg import logm
from pymor.algorithms.projection import project
from pymor.algorithms.symplectic import SymplecticBasis
from pymor.core.base import BasicObject
from pymor.models.symplectic import QuadraticHamiltonianModel
from pymor.operators.symplectic import CanonicalSymplecticFormOperator
from pymor.models.interface import Model
from pymor.vectorarrays.numpy import NumpyVectorSpace

from sympredict._checks import as_parameter, as_positive_int, as_real
from sympredict.base import clone
from sympredict.data import FlowMapData, TrajectoryData
from sympredict.exceptions import ExtrapolationWarning, NewtonConvergenceError
from sympredict.systems.linear_flow import QuadraticPart, inverse_symplectic_matrices
from sympredict.systems.flowmaps import (
    LinearHamiltonianSystem,
    _report_existence,
    first_singular_step,
    check_generating_function,
    linear_system_from_pymor,
    midpoint_sigma_min,
    mu_to_vector,
    mus_to_matrix,
    parameter_box,
    parse_mu,
    random_parameters,
    sample_trajectory_neighbourhood,
    trajectory_pairs,
    type2_sigma_min,
)
from sympredict.kernels import IMQ, RadialKernel
from sympredict.kernels.transforms import KernelTransform
from sympredict.symplectic.metrics import canonical_J
from sympredict.estimators.predictor import SymplecticKernelPredictor
from sympredict.mor.basis import SymplecticROM
from sympredict.flowmap.scaling import BoxScaling, NormalizedFlowMap, SymplecticScaling, scaled_quadratic_part
from sympredict.flowmap.splitting import SplitKernelPredictor
from sympredict.estimators.selection import log_grid, select_kernels
from sympredict.interpolation.greedy import ExactGreedy

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
        raise ValueError(f"RB must be a pyMOR SymplecticBasis (e.g. sympredict.mor.basis.complex_svd_basis(...).to_pymor(...)), "
                         f"got {type(RB).__name__}")
    if phase_space is not None and RB.phase_space != phase_space:
        raise ValueError(f"RB lives in {RB.phase_space}, but the FOM's solution space is {phase_space}: mismatched spaces")
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
        self.logger.error(f"Newton failed at macro step {k + 1} of {self.n_steps} (mu = {mu}): the exception carries "
                          f"the reduced trajectory of the {k} completed steps (exc.trajectory; "
                          f"reductor.reconstruct(exc.trajectory) for full states)")

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


def _check_fom(fom, data: str) -> None:
    """``data='reduced'`` needs the Galerkin ROM of a quadratic Hamiltonian model; ``'projected'`` any time-dependent
    model; the caller's data (``'given'``) a model with a solution space, initial data and ``T`` (for the ROM)."""
    if data == "reduced":
        if not isinstance(fom, QuadraticHamiltonianModel):
            raise ValueError(f"data='reduced' needs the exact reduced flow of a pyMOR QuadraticHamiltonianModel, got "
                             f"{type(fom).__name__}: for any other pyMOR model use data='projected' (only fom.solve "
                             f"is called)")
        return
    needed = ("solve", "solution_space", "initial_data", "T", "parameters") if data == "projected" else \
        ("solution_space", "initial_data", "T", "parameters")
    missing = [a for a in needed if not hasattr(fom, a)]
    if not isinstance(fom, Model) or missing:
        raise ValueError(f"fom must be a time-dependent pyMOR Model (e.g. an InstationaryModel) with "
                         f"{', '.join(needed[:-1])} and {needed[-1]}; {type(fom).__name__} "
                         + (f"lacks {', '.join(missing)}" if missing else "is not a pyMOR Model"))


_STATE_SCALINGS = ("diag", "uniform", "williamson", "none")
_PARAMETER_SCALINGS = ("box", "none")
_TIME_SCALINGS = ("step", "none")


def _check_reductor_settings(fom, dt, predictor, parameter_space, n_samples, radius, n_validation, horizon,
                             max_centers, check_existence, seed, m_star=300) -> None:
    """The reductor's settings, checked before any FOM solve (``ValueError`` naming the argument and the value given)."""
    as_positive_int(n_samples, "n_samples", minimum=2)  # a fifth on the trajectory, the rest around it: at least 2
    as_positive_int(n_validation, "n_validation")
    as_positive_int(max_centers, "max_centers")
    as_positive_int(m_star, "m_star")
    as_positive_int(seed, "seed", minimum=0)
    as_real(radius, "radius", nonnegative=True)
    if horizon is not None:
        as_real(horizon, "horizon", positive=True)
    if not isinstance(check_existence, (bool, np.bool_)):
        raise ValueError(f"check_existence must be True or False, got {check_existence!r}")
    if predictor is not None:
        missing = [a for a in ("fit", "step", "rollout", "step_jacobian", "get_params")
                   if not callable(getattr(predictor, a, None))]
        if isinstance(predictor, type) or missing:
            raise ValueError(f"estimator must be an estimator instance (e.g. SymplecticKernelPredictor(...)) with fit, step, "
                             f"rollout, step_jacobian and get_params, got {predictor!r}"
                             + (f" (lacks {', '.join(missing)})" if missing and not isinstance(predictor, type) else ""))
    if parameter_space is not None:
        from pymor.parameters.base import ParameterSpace

        if not isinstance(parameter_space, ParameterSpace):
            raise ValueError(f"parameter_space must be a pyMOR ParameterSpace (e.g. fom.parameters.space(lo, hi)) or None, "
                             f"got {type(parameter_space).__name__}")
        if dict(parameter_space.parameters) != dict(fom.parameters):
            raise ValueError(f"parameter_space has the parameters {dict(parameter_space.parameters)}, the FOM has "
                             f"{dict(fom.parameters)}: names and dimensions must agree")


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


def _as_trajectories(given, fom, name: str) -> tuple:
    """The caller's FOM trajectories ``(U, mus)`` as ``(list of VectorArrays in fom.solution_space, list of Mu)``.

    ``U``: a sequence of ``P`` VectorArrays (each ``K + 1`` states, as ``fom.solve`` returns) or an array
    ``(P, K + 1, N)`` of full states (``N = fom.solution_space.dim``, blocks stacked as the solution space orders
    them); ``mus``: ``P`` parameter values (pyMOR ``Mu``, dicts, numbers; ``None`` or ``P`` Nones for a parameter-free
    FOM).  Shapes, spaces, lengths and finiteness are checked before anything is copied (``ValueError`` naming
    ``name``).
    """
    if not isinstance(given, (tuple, list)) or len(given) != 2:
        raise ValueError(f"{name} must be a pair (U, mus): U a list of VectorArrays (or an array (P, K+1, N)) of FOM "
                         f"trajectories, mus their parameter values, got {type(given).__name__}")
    U, mus = given
    space = fom.solution_space
    if isinstance(U, np.ndarray):
        if U.ndim != 3 or U.shape[2] != space.dim or U.shape[0] == 0 or U.shape[1] < 2:
            raise ValueError(f"{name}: an array of trajectories must have shape (P, K+1, N) with P >= 1, K + 1 >= 2 and "
                             f"N = {space.dim} (the FOM's solution space), got {U.shape}")
        if not np.issubdtype(U.dtype, np.number) or np.iscomplexobj(U) or not np.all(np.isfinite(U)):
            raise ValueError(f"{name}: the trajectories must be finite real numbers (NaN, Inf or dtype {U.dtype} found)")
        U = [space.from_numpy(np.array(u, dtype=float).T) for u in U]  # pyMOR: columns are vectors
    else:
        U = list(U) if isinstance(U, (list, tuple)) else [U]
        bad = [i for i, u in enumerate(U) if getattr(u, "space", None) != space]
        if not U or bad:
            raise ValueError(f"{name}: U must hold VectorArrays in the FOM's solution space {space}" +
                             (f"; entry {bad[0]} is a {type(U[bad[0]]).__name__}" + (
                                 f" in {U[bad[0]].space}" if hasattr(U[bad[0]], "space") else "") if bad else
                              ", got none"))
        for i, u in enumerate(U):
            if not np.all(np.isfinite(u.norm())):
                raise ValueError(f"{name}: trajectory {i} has NaN or Inf states")
    lengths = sorted({len(u) for u in U})
    if len(lengths) > 1 or lengths[0] < 2:
        raise ValueError(f"{name}: every trajectory must have the same number K + 1 >= 2 of states (t_k = k T / K), "
                         f"got lengths {lengths}")
    if not fom.parameters and mus is None:
        return U, [None] * len(U)
    if mus is None or isinstance(mus, (str, dict)) or len(mus) != len(U):
        raise ValueError(f"{name}: give one parameter value per trajectory ({len(U)}), got "
                         f"{'none' if mus is None else mus!r}")
    return U, [parse_mu(m, fom.parameters) for m in mus]


def _conjugated_system(system: LinearHamiltonianSystem, M: np.ndarray) -> LinearHamiltonianSystem:
    """``system`` in the coordinates ``x~ = M x`` (``M^T J M = s^2 J``, conformally symplectic): ``H~ = s^2 M^-T H M^-1``
    and ``h~ = s^2 M^-T h``, so that ``J H~ = M J H M^-1`` and the flow Jacobian is ``M D Phi M^-1``."""
    M = np.asarray(M, dtype=float)
    dim = M.shape[0]
    J = canonical_J(dim)
    s2 = float((M.T @ J @ M)[0, dim // 2] / J[0, dim // 2])
    Minv = np.linalg.inv(M)
    return LinearHamiltonianSystem(lambda mu: s2 * Minv.T @ system.matrix(mu) @ Minv, dim, system.n_mu,
                                   lambda mu: s2 * Minv.T @ system.linear_term(mu))


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
        raise ValueError(f"flow_parameters must be a sequence of parameter names (e.g. ('c',)), got {flow_parameters!r}")
    names = set(flow_parameters)
    unknown = names - set(fom.parameters)
    if unknown:
        raise ValueError(f"flow_parameters {sorted(unknown)} are not parameters of the FOM ({dict(fom.parameters)})")
    needed = _operator_parameters(fom) & set(fom.parameters)
    if needed - names:
        raise ValueError(f"the FOM's evolution depends on {sorted(needed)}: flow_parameters={sorted(names)} leaves out "
                         f"{sorted(needed - names)} (only parameters of the initial data may be left out)")
    return Parameters({k: fom.parameters[k] for k in names})


def _check_choice(value, name: str, choices: tuple) -> str:
    if not isinstance(value, str) or value not in choices:
        raise ValueError(f"{name} must be one of {choices}, got {value!r}")
    return value


def _check_kernels(kernels, name: str, allow_none: bool) -> Optional[list]:
    """A non-empty list of radial kernels (``None`` entries where ``allow_none``: the factor dropped), or ``None``."""
    if kernels is None:
        return None
    if isinstance(kernels, RadialKernel) or isinstance(kernels, str):
        raise ValueError(f"{name} must be a sequence of kernels (e.g. [IMQ(0.01), IMQ(0.1)]), got {kernels!r}")
    kernels = list(kernels)
    bad = [k for k in kernels if not (isinstance(k, RadialKernel) or (allow_none and k is None))]
    if not kernels or bad:
        raise ValueError(f"{name} must be a non-empty sequence of radial kernels (IMQ, Matern52, Matern32)"
                         + (" or None" if allow_none else "") + f", got {kernels!r}")
    return kernels



def _check_sizes(name: str, what: str, dim_given: int, dim: int, n_mu_given: int, n_mu: int) -> None:
    """``ValueError`` naming ``name`` when its state or parameter dimension does not fit the reductor's."""
    if dim_given != dim:
        raise ValueError(f"{name} has {what} of dimension {dim_given}, the basis has 2n = {dim}: give reduced "
                         f"coordinates (reductor.project(U) of full states)")
    if n_mu_given != n_mu:
        raise ValueError(f"{name} has parameter vectors of dimension {n_mu_given}, the flow map's parameters have "
                         f"dimension {n_mu} (mu_to_vector order: values sorted by parameter name)")

def _check_given_data(data, validation_data, dim: int, n_mu: int, dt: float) -> None:
    """The caller's training samples and validation samples (or trajectories): reduced states of dimension ``2n``,
    parameter vectors of the flow parameters' dimension, all at the reductor's ``dt``."""
    for name, d in (("data", data), ("validation_data", validation_data)):
        if d is None:
            continue
        if isinstance(d, TrajectoryData) and name == "validation_data":
            _check_sizes(name, "trajectories", d.states.shape[2], dim, d.mu.shape[1], n_mu)
            if d.dt is None:
                raise ValueError("validation_data has non-uniform times; the reductor's validation rollouts take "
                                 f"uniform steps of its dt = {dt!r}")
            if not np.isclose(d.dt, dt, rtol=1e-12, atol=0):
                raise ValueError(f"validation_data has the step {d.dt!r}, the reductor's dt is {dt!r}")
            continue
        if not isinstance(d, FlowMapData):
            raise ValueError(f"{name} must be a sympredict.data.FlowMapData of reduced samples"
                             + (" or a TrajectoryData" if name == "validation_data" else "")
                             + f", got {type(d).__name__}")
        _check_sizes(name, "states", d.x0.shape[1], dim, d.mu.shape[1], n_mu)
        if not np.allclose(d.dt, dt, rtol=1e-12, atol=0):
            raise ValueError(f"{name} has steps {np.unique(d.dt)[:5].tolist()}, the reductor's dt is {dt!r}: a reductor "
                             f"learns one macro step")


class SymplecticKernelReductor(BasicObject):
    """Learn a symplectic reduced flow map of a pyMOR Hamiltonian model.

    Parameters
    ----------
    fom : pymor.models.interface.Model
        ``data="reduced"``: a ``QuadraticHamiltonianModel`` (its Galerkin ROM gives the
        exact reduced flow).  ``data="projected"``: any time-dependent pyMOR model with
        ``solve``, ``solution_space``, ``initial_data`` and ``T`` (e.g. an
        ``InstationaryModel`` with a nonlinear operator); only ``solve`` is called, and the
        FOM's trajectories are assumed Hamiltonian (the ROM's steps are symplectic whatever
        the data).  With the caller's data: any time-dependent model with
        ``solution_space``, ``initial_data`` and ``T`` (the ROM starts from its initial data).
        Any parameters (names, dimensions) or none.
    RB : pymor.algorithms.symplectic.SymplecticBasis
        Symplectic basis of ``fom.solution_space`` (``V^T J V = J`` checked).
    training_parameters : sequence of pyMOR Mu
        E.g. ``fom.parameters.space(...).sample_uniformly(n)``; ``None`` or ``[]``
        for a parameter-free model, or with the caller's ``data`` (then those of its samples).
    dt : float
        Macro step of the ROM.
    estimator : estimator, optional
        The one place for every setting of the learned step: an unfitted estimator with
        ``fit``/``rollout``/``step``/``step_jacobian`` (cloned, never modified), with all its parts
        (kernels, ``max_centers``, ``update``, ``trainer`` with ``tol``/``power_tol``/``regularization``,
        ``solver``, ``search``).  A :class:`SymplecticKernelPredictor` with kernels left ``None`` chooses
        them itself on held-out samples (its ``search=KernelSearch(...)``: families, shapes, ``m_star``);
        with ``update=None`` the reductor sets the form that exists at ``dt`` (type II or midpoint) or, where
        both do, leaves the choice to it; what it chose is ``choice_["estimator"]``.  Default: a
        :class:`SymplecticKernelPredictor` (``max_centers``, ``ExactGreedy(tol=1e-12)``) with IMQ kernels on
        the scaled states and parameters whose shapes are chosen on the validation data from a small log grid
        (``state_kernels``, ``mu_kernels`` replace the grid).
    data : {"reduced", "projected"} or FlowMapData, optional
        Intrusive Galerkin-flow samples (the default), non-intrusive projected FOM trajectories
        (the default with ``trajectories``), or the caller's flow-map samples in reduced coordinates
        (``x1 = Phi(x0)`` over ``dt``; parameter vectors in :func:`~sympredict.systems.flowmaps.mu_to_vector`
        order), e.g. from its own sampling design or its own solver.
    parameter_space : pyMOR ParameterSpace, optional
        Box for the parameter scaling and the validation parameters (default: box of the training ones).
    n_samples : int
        ``data="reduced"``: flow-map samples per training parameter.
    radius : float
        ``data="reduced"``: relative radius of the trajectory neighbourhood.
    n_validation : int
        Number of validation parameters (random in the box).
    horizon : float, optional
        Time span of the trajectories sampled (default ``fom.T``).
    state_scaling : {"diag", "uniform", "williamson", "none"}
        :class:`~sympredict.flowmap.scaling.SymplecticScaling` mode; ``"williamson"``
        (``data="reduced"`` only) uses the Williamson form of ``V^T H(mu) V`` at
        the centre of the parameter box.
    max_centers : int, optional
        Budget of the default estimator (1000); a given estimator has its own (refused here).
    check_existence : bool
        Run :func:`~sympredict.systems.flowmaps.check_generating_function` on the data, for
        the estimator's ``update`` (type II by default; ``"midpoint"``: the
        symmetric form, which holds up to half a turn per step), in the coordinates the estimator
        is trained in (after ``state_scaling``: the Jacobian there is ``T D Phi T^-1``, and a scaling
        that mixes ``q`` and ``p``, such as ``"williamson"``, changes where the type II form exists).
        On the caller's data the check uses a least-squares linear map per parameter, as for
        ``data="projected"``; a check that cannot run (fewer samples per parameter than ``2n``) is
        logged as not done.
    seed : int
    validation_data : FlowMapData, optional
        With the caller's ``data``: its validation samples (needed to choose kernels).
    parameter_scaling : {"box", "none"}
        ``"box"``: parameters mapped from the box onto ``[0, 1]^d``; ``"none"``: the
        predictor sees the parameter vectors as they are.
    time_scaling : {"step", "none"}
        ``"step"``: the macro step becomes the time unit (the predictor sees ``dt = 1``);
        ``"none"``: it sees ``dt``.
    state_kernels, mu_kernels : sequence of RadialKernel, optional
        Candidate kernels chosen on the validation data
        (:func:`~sympredict.estimators.selection.select_kernels`: each trained to ``m_star``
        centres with the predictor's other settings; the smallest validation residual wins),
        in the predictor's coordinates.  Default for the default predictor: IMQ log grids
        (states ``0.01..1``, parameters ``0.3..3``); for a given predictor: its own kernels
        (no search unless one of them is given).
    m_star : int
        Centres at which the kernel candidates are compared (at most the budget).
    regularizations : sequence of float, optional
        Ridge terms (``trainer__regularization``) tried besides ``0`` (the exact fit): each
        candidate is trained on the training data and scored on the validation data, in
        reduced coordinates; the smallest score wins, ties to the smaller term.  Validation
        samples (``FlowMapData``) score the mean relative error of one step; validation
        trajectories (``TrajectoryData``) the mean relative error of the rollouts from their
        first states over all their steps (a failed or non-finite rollout scores ``inf``).
    split : QuadraticPart, optional
        The quadratic part ``A(mu)`` of the reduced Hamiltonian (in reduced coordinates, a
        function of the flow parameters): the learned step becomes ``L_h o S o L_h``
        (:class:`~sympredict.flowmap.splitting.SplitKernelPredictor`, ``L_h = expm(dt/2 J A)``,
        carried into the scaled coordinates by :func:`~sympredict.flowmap.scaling.scaled_quadratic_part`),
        so the linear part of the flow is exact and only ``S`` is learned.  The existence check and
        the kernel search then see ``S``'s pairs ``(L_h x0, L_{-h} x1)``.
    split_fallback : QuadraticPart, optional
        The known quadratic part ``A(mu)`` of the reduced Hamiltonian (as for ``split``), split off only
        where the existence check finds no generating function at ``dt`` without it (after the midpoint
        form, where the update is left open): the kernel then learns the remainder ``S``, whose flow is
        close to the identity.  Logged; ``choice_["split"] = "split_fallback"`` and ``choice_["reason"]``
        say why.  Needs ``check_existence=True``.
    flow_parameters : sequence of str, optional
        The parameters the flow map takes (default: all of the FOM's).  Parameters that enter only
        the initial data (checked: the FOM's other operators must not depend on them) are left out,
        so the kernel interpolates in the others only; data, ``parameter_space`` box and
        ``split`` use the flow parameters' vectors.
    trajectories : tuple (U, mus), optional
        FOM trajectories the caller already has, used instead of ``fom.solve`` (``data="projected"``
        without solving the FOM; ``training_parameters`` are then ``mus``): ``U`` a sequence of ``P``
        VectorArrays in ``fom.solution_space`` (as ``fom.solve`` returns them) or an array
        ``(P, K + 1, N)`` of full states, each trajectory ``K + 1`` states at ``t_k = k T / K``
        (``T = fom.T``; ``K`` divides the FOM's ``nt`` where it has a time stepper, and ``dt`` is a multiple
        of ``T / K``); ``mus`` ``P`` parameter values (pyMOR ``Mu``, dicts or numbers; ``None`` for a
        parameter-free FOM).  Checked before anything is trained.
    validation_trajectories : tuple (U, mus), optional
        With ``trajectories``: the validation trajectories, same form (the validation parameters are their
        ``mus``).  Without them no validation data exist: give an estimator that chooses its kernels on
        held-out training samples, or its kernels.
    """

    def __init__(self, fom, RB, training_parameters, dt, estimator=None, data=None, *, parameter_space=None,
                 n_samples: int = 400, radius: float = 0.05, n_validation: int = 3, horizon: Optional[float] = None,
                 state_scaling: str = "diag", max_centers: Optional[int] = None, check_existence: bool = True,
                 seed: int = 0, validation_data=None, parameter_scaling: str = "box", time_scaling: str = "step",
                 state_kernels=None, mu_kernels=None, m_star: int = 300, regularizations=None,
                 split: Optional[QuadraticPart] = None, split_fallback: Optional[QuadraticPart] = None,
                 flow_parameters=None, trajectories=None,
                 validation_trajectories=None):
        if estimator is not None and max_centers is not None:
            raise ValueError(f"max_centers={max_centers!r} is the budget of the default estimator; the given estimator "
                             f"has its own: set it there (estimator=SymplecticKernelPredictor(max_centers="
                             f"{max_centers!r}, ...)) and leave max_centers out")
        predictor = estimator  # the internal name
        max_centers = 1000 if max_centers is None else max_centers
        if trajectories is None and validation_trajectories is not None:
            raise ValueError("validation_trajectories go with trajectories=(U, mus): give the training trajectories too")
        if trajectories is not None and data not in (None, "projected"):
            raise ValueError(f"trajectories=(U, mus) are the FOM trajectories that data='projected' would compute; "
                             f"data={data!r} does not use them: leave data out (or data='projected')")
        if data is None:
            data = "projected" if trajectories is not None else "reduced"
        if isinstance(data, FlowMapData):
            mode = "given"
        elif isinstance(data, str) and data in ("reduced", "projected"):
            mode = data
        else:
            raise ValueError(f"data must be 'reduced', 'projected' or a FlowMapData of reduced samples, got {data!r}")
        if validation_data is not None and mode != "given":
            raise ValueError(f"validation_data goes with the caller's data (data=FlowMapData(...)); data={data!r} "
                             f"samples its own validation data")
        _check_fom(fom, "given" if trajectories is not None else mode)  # given trajectories: no FOM solve
        check_symplectic_basis(RB, fom.solution_space)
        _check_choice(state_scaling, "state_scaling", _STATE_SCALINGS)
        _check_choice(parameter_scaling, "parameter_scaling", _PARAMETER_SCALINGS)
        _check_choice(time_scaling, "time_scaling", _TIME_SCALINGS)
        if state_scaling == "williamson" and mode != "reduced":
            raise ValueError("state_scaling='williamson' needs the reduced operator: use data='reduced' or 'diag'")
        dt = as_real(dt, "dt", positive=True)
        _check_reductor_settings(fom, dt, predictor, parameter_space, n_samples, radius, n_validation, horizon,
                                 max_centers, check_existence, seed, m_star)
        state_kernels = _check_kernels(state_kernels, "state_kernels", allow_none=False)
        mu_kernels = _check_kernels(mu_kernels, "mu_kernels", allow_none=True)
        flow = _flow_parameters(fom, flow_parameters)
        if regularizations is not None:
            regularizations = [float(as_real(v, "regularizations", nonnegative=True))
                               for v in np.atleast_1d(np.asarray(regularizations, dtype=object))]
        if split is not None and split_fallback is not None:
            raise ValueError("give the quadratic part once: split= (always split off) or split_fallback= (split off "
                             "only where no generating function exists at dt without it), not both")
        for qname, quad in (("split", split), ("split_fallback", split_fallback)):
            if quad is None:
                continue
            if not isinstance(quad, QuadraticPart):
                raise ValueError(f"{qname} must be a sympredict.systems.linear_flow.QuadraticPart (the quadratic part "
                                 f"A(mu) of the reduced Hamiltonian), got {quad!r}")
            quad.checked(dim=2 * len(RB))
            if quad.checked()[1].shape[1] not in (0, flow.dim):
                raise ValueError(f"{qname} depends on {quad.checked()[1].shape[1]} parameter component(s), the flow map "
                                 f"takes {flow.dim}")
            if isinstance(predictor, SplitKernelPredictor):
                raise ValueError("give the inner SymplecticKernelPredictor as estimator and the quadratic part as split: "
                                 "the reductor builds the SplitKernelPredictor in its scaled coordinates")
        if mode == "given":
            _check_given_data(data, validation_data, 2 * len(RB), flow.dim, float(dt))
            if (fom.parameters and flow == fom.parameters
                    and (training_parameters is None or len(training_parameters) == 0)):
                training_parameters = [fom.parameters.parse(row) for row in np.unique(data.mu, axis=0)]
        if trajectories is not None:
            if training_parameters is not None and len(training_parameters) > 0:
                raise ValueError("with trajectories=(U, mus) the training parameters are their mus: leave "
                                 "training_parameters out (None)")
            trajectories = _as_trajectories(trajectories, fom, "trajectories")
            training_parameters = trajectories[1] if fom.parameters else None
        if validation_trajectories is not None:
            validation_trajectories = _as_trajectories(validation_trajectories, fom, "validation_trajectories")
        if not fom.parameters:
            training_parameters = [None]
        elif (training_parameters is None or len(training_parameters) == 0) and mode != "given":
            raise ValueError(f"the FOM has parameters {dict(fom.parameters)}: give training_parameters (pyMOR Mu)")
        self.__auto_init(locals())
        self.estimator = predictor
        self._split = split  # the split in use: split, or split_fallback where the existence check needs it
        self.mode = mode
        self.state_kernels, self.mu_kernels = state_kernels, mu_kernels
        self.regularizations = regularizations
        self.flow_parameters = flow
        self._flow_index = _sub_index(fom.parameters, flow)
        self._flow_subset = flow != fom.parameters
        self.training_parameters = None if training_parameters is None or len(training_parameters) == 0 else \
            [parse_mu(m, fom.parameters) for m in training_parameters]
        if isinstance(predictor, SymplecticKernelPredictor):
            predictor.check_params()  # its settings, before any FOM solve (fit would check them after all samples)
        self.dt = float(dt)
        self.horizon = float(fom.T if horizon is None else horizon)
        self.RB = RB
        self.V = basis_matrix(RB)  # (2N, 2n)
        self.V_plus_array = RB.transposed_symplectic_inverse().to_array()
        self.dim = 2 * len(RB)
        for given in (trajectories, validation_trajectories):
            if given is not None:
                self._check_given_grid(given[0][0])
        if mode == "projected" and trajectories is None and getattr(fom, "num_values", None) is None and getattr(
                getattr(fom, "time_stepper", None), "nt", None):  # an InstationaryModel's output grid, known up front
            self._check_stride(fom.T / fom.time_stepper.nt, fom.time_stepper.nt)
        if mode == "projected" and not self.dt <= self.horizon * (1 + 1e-12):
            raise ValueError(f"dt = {self.dt!r} is longer than the sampled time span (horizon = {self.horizon!r}, "
                             f"fom.T = {fom.T!r}): no flow-map pair fits; use a smaller dt or a longer horizon")
        if mode == "projected" and self.horizon > fom.T * (1 + 1e-12):
            raise ValueError(f"horizon = {self.horizon!r} is past the FOM's final time T = {fom.T!r}: its trajectories "
                             f"end at T (data='projected'); use horizon <= T or fom.with_(T=...)")
        if self.training_parameters is not None or parameter_space is not None:
            # the FOM's parameter box (validation draws), and the flow parameters' part of it (their scaling)
            self.mu_lo, self.mu_hi = parameter_box(self.training_parameters, fom.parameters, parameter_space)
            self.flow_lo, self.flow_hi = self.mu_lo[self._flow_index], self.mu_hi[self._flow_index]
            if parameter_space is not None:
                self._check_inside_space(trajectories, data)
        else:  # the caller's data without training parameters: the box of its samples
            self.mu_lo = self.mu_hi = None
            self.flow_lo, self.flow_hi = data.mu.min(axis=0), data.mu.max(axis=0)

    def _check_inside_space(self, trajectories, data) -> None:
        """``ValueError`` naming the first training parameter (given, of the trajectories, of the samples) outside
        ``parameter_space``: the scaling maps the box onto [0, 1], so data outside it are extrapolation."""
        if self.training_parameters and self.fom.parameters:
            self._refuse_outside("training_parameters", self._mu_rows(self.training_parameters), self.mu_lo, self.mu_hi)
        if trajectories is not None and self.fom.parameters:
            self._refuse_outside("trajectories", self._mu_rows(self._given_mus(trajectories)), self.mu_lo, self.mu_hi)
        if isinstance(data, FlowMapData):
            self._refuse_outside("data", data.mu, self.flow_lo, self.flow_hi)

    @staticmethod
    def _refuse_outside(what: str, rows: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> None:
        if not len(rows) or rows.shape[1] != len(lo):
            return
        tol = 1e-9 * np.maximum(np.abs(lo), np.abs(hi)) + 1e-300
        out = np.flatnonzero(((rows < lo - tol) | (rows > hi + tol)).any(axis=1))
        if out.size:
            raise ValueError(f"{what}: parameter {rows[out[0]].tolist()} (and {out.size - 1} more) lies outside "
                             f"parameter_space [{lo.tolist()}, {hi.tolist()}]: give a parameter_space that contains "
                             "the training parameters (or leave it out: the box of the training parameters)")

    # ------------------------------------------------------------ projection
    def project(self, U) -> np.ndarray:
        """Reduced coordinates ``V+ U`` of a VectorArray in ``fom.solution_space``, shape (len(U), 2n)."""
        if U.space != self.fom.solution_space:
            raise ValueError(f"U must lie in the FOM's solution space {self.fom.solution_space}, got {U.space}")
        return self.V_plus_array.inner(U).T

    def reconstruct(self, U_red):
        """``V U_red``: a VectorArray in ``fom.solution_space``.

        ``U_red``: what ``rom.solve`` returns (a VectorArray of dimension ``2n``), or an array of reduced
        states of shape ``(K, 2n)`` (or ``(2n,)``).
        """
        if isinstance(U_red, np.ndarray) or isinstance(U_red, (list, tuple)):
            arr = np.atleast_2d(np.asarray(U_red, dtype=float))
            if arr.ndim != 2 or arr.shape[1] != self.dim:
                raise ValueError(f"U_red as an array must have shape (K, 2n) = (K, {self.dim}) (reduced states in "
                                 f"rows), got {np.shape(U_red)}; or give what rom.solve returns")
            return self.RB.to_array().lincomb(arr.T)  # pyMOR: coefficients (2n, len)
        if not hasattr(U_red, "space"):
            raise ValueError(f"U_red must be a VectorArray of the ROM (what rom.solve returns) or an array (K, 2n), "
                             f"got {type(U_red).__name__}")
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

    def _given_mus(self, given) -> list:
        return given[1] if self.fom.parameters else [None] * len(given[0])

    def validation_parameters(self) -> list:
        """``n_validation`` parameters uniform in the box (seeded), not the training ones (with
        ``validation_trajectories``: theirs)."""
        if self.validation_trajectories is not None:
            return self._given_mus(self.validation_trajectories)
        if not self.fom.parameters:
            return [None]
        return random_parameters(self.fom.parameters, self.mu_lo, self.mu_hi, self.n_validation, seed=self.seed + 7)

    def _galerkin(self):
        """The symplectic Galerkin ROM of the FOM (:class:`~sympredict.mor.basis.SymplecticROM`: pyMOR's
        ``QuadraticHamiltonianRBReductor``) and its reduced quadratic Hamiltonian with exact flows, built once:
        ``galerkin`` (the ROM), ``galerkin_rom`` (its pyMOR model), ``reduced_system``."""
        if not hasattr(self, "galerkin_rom"):
            self.galerkin = SymplecticROM(self.fom, self.RB, symplectic_tol=_SYMPLECTIC_TOL)
            self.galerkin_rom = self.galerkin.rom
            self.reduced_system = linear_system_from_pymor(self.galerkin_rom)
        return self.reduced_system

    def _reduced_data(self, mus, n_per_mu, seed):
        system = self._galerkin()
        rng = np.random.default_rng(seed)
        rows = self._mu_rows(mus)
        n_fine = int(np.ceil(self.horizon / self.dt)) * 4
        parts = []
        for mu, row in zip(mus, rows):
            x0 = self._initial_state(mu)
            traj = system.trajectory(x0[None], row[None] if row.size else None, self.dt / 4, n_fine)[0]
            n_on = max(1, n_per_mu // 5)  # a fifth on the trajectory itself
            states = np.concatenate([sample_trajectory_neighbourhood(traj, n_per_mu - n_on, self.radius, rng),
                                     sample_trajectory_neighbourhood(traj, n_on, 0.0, rng)])
            mrow = np.repeat(row[None], len(states), axis=0)
            parts.append(FlowMapData(states, system.flow(states, mrow, self.dt), mrow if row.size else None,
                                     np.full(len(states), self.dt)))
        return _concat(parts), system

    def _check_given_grid(self, U) -> None:
        """The caller's trajectories (``K + 1`` states at ``t_k = k T / K``): on the FOM's time grid (``nt`` a
        multiple of ``K`` where the FOM has a time stepper) and ``dt`` a multiple of their step ``T / K``."""
        k = len(U) - 1
        nt = getattr(getattr(self.fom, "time_stepper", None), "nt", None)
        if nt and int(nt) % k:
            raise ValueError(f"the given trajectories have {k + 1} states, read as t_k = k T / {k} (T = {self.fom.T!r}); "
                             f"the FOM's time grid has nt = {nt} steps, not a multiple of {k}: give states at every "
                             f"output step of fom.solve (nt + 1 = {int(nt) + 1} states) or at every m-th, m dividing nt")
        self._check_stride(self.fom.T / k, k)

    def _projected_data(self, mus, given=None):
        """Flow-map pairs ``dt`` apart of the projected FOM trajectories at ``mus`` (``fom.solve``, or ``given``:
        VectorArrays of the caller's trajectories at those parameters)."""
        trajs, rows = [], self._mu_rows(mus)
        h = None
        for i, mu in enumerate(mus):
            U = self.fom.solve(mu) if given is None else given[i]
            h_mu = self.fom.T / (len(U) - 1)
            if h is not None and not np.isclose(h, h_mu):
                raise ValueError("the FOM's output grid changes with mu")
            h = h_mu
            trajs.append(self.project(U))
        stride = self._check_stride(h)
        k = int(round(self.horizon / h)) + 1
        # dt exactly: the predictor is a fixed-step model and the ROM queries self.dt
        return trajectory_pairs(np.stack([t[:k] for t in trajs]), rows, self.dt / stride, stride)

    def _check_stride(self, h: float, n_out: Optional[int] = None) -> int:
        """The number of FOM output steps ``h = T / n_out`` in one macro step ``dt``; ``ValueError`` with the exact
        numbers (``T``, ``n_out``, ``h``, ``dt / h`` and the nearest admissible steps) when ``dt`` is not a multiple."""
        ratio = self.dt / h
        stride = int(round(ratio))
        if stride < 1 or not np.isclose(stride * h, self.dt, rtol=1e-9, atol=0):
            n_out = int(round(self.fom.T / h)) if n_out is None else int(n_out)
            lower, upper = max(1, int(np.floor(ratio))), max(1, int(np.ceil(ratio)))
            near = sorted({lower * h, upper * h})
            raise ValueError(f"data='projected' needs dt to be a multiple of the FOM's output step h = T / nt = "
                             f"{self.fom.T!r} / {n_out} = {h!r}; dt = {self.dt!r} is {ratio:.6g} output steps: use "
                             f"dt = k * h, e.g. " + " or ".join(f"{v!r}" for v in near))
        return stride

    def _given_update(self) -> Optional[str]:
        """The update the caller fixed (the given estimator's, by name), or ``None`` where the reductor chooses."""
        update = getattr(self.estimator, "update", None) if self.estimator is not None else None
        return update if update is None or isinstance(update, str) else getattr(update, "name", update)

    def _update(self) -> Optional[str]:
        """The generating-function update checked and trained: the given estimator's, else the one chosen for
        it (``choice_["update"]``; ``None``: left to the estimator, both forms exist at ``dt``)."""
        given = self._given_update()
        if given is not None:
            return given
        default = "symplectic_euler" if self.estimator is None else None
        return getattr(self, "choice_", {}).get("update", default)

    def _checked_update(self) -> str:
        """:meth:`_update` for the existence check (type II where the choice is left to the estimator)."""
        return self._update() or "symplectic_euler"

    def _checked_existence(self, check):
        """``check()`` (an existence check for :meth:`_checked_update`).  Where the caller left the update open
        (the default estimator, or an estimator with ``update=None``): when the type II generating function does
        not exist at ``dt`` (a mode turns past a quarter turn per step), the midpoint form (up to half a turn) is
        chosen instead, logged and kept in ``choice_``; for an estimator with ``update=None`` the choice stays
        with it (``choice_["update"] = None``) where both forms exist."""
        given = self._given_update()
        if given is not None:
            self.choice_ = {"update": given, "reason": "the given estimator's update"}
        else:
            self.choice_ = {"update": "symplectic_euler", "reason": "type II generating function exists at dt"}
        try:
            out = check()
        except ValueError as exc:
            if given is not None or self._split is not None:
                raise
            first = str(exc)
        else:
            if isinstance(out, dict) and out.get("not_checked"):
                self.choice_["reason"] = "not checked: too few samples per parameter (see the log)"
                return out
            if given is None and self.estimator is not None:  # the estimator chooses, where both forms exist
                self.choice_ = {"update": "midpoint", "reason": "probe"}
                try:
                    with warnings.catch_warnings():  # a probe: its warnings are not the caller's
                        warnings.simplefilter("ignore")
                        check()
                except ValueError as exc:
                    self.choice_ = {"update": "symplectic_euler", "reason": f"the midpoint form does not exist at "
                                    f"dt = {self.dt!r} ({exc}); the type II form does"}
                    self.logger.info(f"update='symplectic_euler' set on the estimator: {self.choice_['reason']}")
                else:
                    self.choice_ = {"update": None, "reason": "both generating functions exist at dt: the "
                                    "estimator's search chooses (update=None)"}
            return out
        self.choice_ = {"update": "midpoint", "reason": f"type II does not exist at dt = {self.dt!r}: {first}"}
        try:
            out = check()
        except ValueError as exc:
            raise ValueError(f"neither generating function exists at dt = {self.dt!r}: midpoint: {exc}; type II: "
                             f"{first}") from None
        self.logger.info(f"update='midpoint' chosen: the type II generating function does not exist at dt = "
                         f"{self.dt!r} ({first}); the midpoint form does")
        return out

    def _check_existence_from_data(self, data):
        """Existence check (type II, or the midpoint form for the predictor's update) from the data alone:
        per parameter a least-squares linear map ``x1 ~ M x0``
        (exact for a linear FOM, the best linear fit of a nonlinear one), its generator ``log(M) / dt``
        for the largest admissible step.  Parameters with fewer than ``2n`` samples (or samples spanning fewer
        dimensions) are skipped, with one log line."""
        worst, generators, skipped = (np.inf, None), [], 0
        for row in np.unique(data.mu, axis=0):
            sel = np.all(data.mu == row, axis=1)
            if sel.sum() < self.dim:
                skipped += 1
                continue
            M, _, rank, _ = np.linalg.lstsq(data.x0[sel], data.x1[sel], rcond=None)
            if rank < self.dim:
                self.logger.info(f"existence check skipped at mu = {row.tolist()}: its samples span only {rank} of "
                                 f"the {self.dim} reduced dimensions (no linear map to fit)")
                continue
            M = M.T
            sigma = float((midpoint_sigma_min if self._checked_update() == "midpoint" else type2_sigma_min)(M[None])[0])
            generators.append(np.real(logm(M)) / self.dt)
            if sigma < worst[0]:
                worst = (sigma, row)
        if skipped:
            self.logger.info(f"existence check: {skipped} parameter value(s) with fewer than 2n = {self.dim} samples "
                             f"skipped")
        if worst[1] is None:
            self.logger.warning(f"existence check not done: no parameter value has samples spanning all 2n = "
                                f"{self.dim} reduced dimensions, so nothing says whether the generating function "
                                f"exists at dt = {self.dt!r} (more samples per parameter, or check_existence=False "
                                f"to say so)")
            return {"not_checked": True}
        update = self._checked_update()
        om = max(float(np.abs(np.linalg.eigvals(A).imag).max()) for A in generators)
        if om * self.dt < 1e-6:  # no rotation to speak of (e.g. the remainder S of a split): no singular step ahead
            dt_max = np.inf
        else:
            try:
                with np.errstate(all="ignore"):
                    dt_max = first_singular_step(generators, update=update)
            except np.linalg.LinAlgError:  # the scan ran into the non-symplectic round-off of the fitted maps
                dt_max = np.inf
        return _report_existence(worst[0], worst[1], self.dt, dt_max, 1e-2, 0.1, update)

    _check_existence_projected = _check_existence_from_data  # the name of earlier versions

    def _to_flow(self, d: FlowMapData) -> FlowMapData:
        """Samples with the FOM's parameter vectors -> with the flow parameters' vectors."""
        if not self._flow_subset:
            return d
        return FlowMapData(d.x0, d.x1, d.mu[:, self._flow_index] if self.flow_parameters else None, d.dt)

    def split_pairs(self, data: FlowMapData) -> FlowMapData:
        """``S``'s samples ``(L_h x0, L_{-h} x1)``, ``L_h = expm(dt/2 J A(mu))``, of samples ``x1 = Phi(x0)``
        (the identity without ``split``), in reduced coordinates."""
        if self._split is None:
            return data
        L = self._split.propagator(data.mu if data.mu.shape[1] else None, 0.5 * data.dt, n=len(data))
        return FlowMapData(np.einsum("bij,bj->bi", L, data.x0),
                           np.einsum("bij,bj->bi", inverse_symplectic_matrices(L), data.x1),
                           data.mu if data.mu.shape[1] else None, data.dt)

    def training_data(self):
        """Training and validation data in original reduced coordinates, parameter vectors of the flow parameters.

        Returns ``(train, val)``: :class:`~sympredict.data.FlowMapData`, and for the caller's data its
        ``validation_data`` as given (``FlowMapData``, :class:`~sympredict.data.TrajectoryData` or ``None``).
        """
        reference = None
        if self.mode == "given":
            train, val = self.data, self.validation_data
        else:
            val_mus = self.validation_parameters()
            if self.mode == "reduced":
                train, system = self._reduced_data(self.training_parameters, self.n_samples, self.seed)
                val, _ = self._reduced_data(val_mus, max(50, self.n_samples // 4), self.seed + 1)
                reference = (system, train)  # the exact Jacobians, with the FOM's parameter vectors
            elif self.trajectories is not None:  # the caller's FOM trajectories: no FOM solve
                train = self._projected_data(self.training_parameters, self.trajectories[0])
                val = None if self.validation_trajectories is None else \
                    self._projected_data(self._given_mus(self.validation_trajectories), self.validation_trajectories[0])
            else:
                train = self._projected_data(self.training_parameters)
                val = self._projected_data(val_mus)
            train, val = self._to_flow(train), None if val is None else self._to_flow(val)
        self._split = self.split
        if self.check_existence:
            self.existence_ = self._existence(train, reference)
        if self.check_existence:
            self.existence_["coordinates"] = f"trained (state_scaling={self.state_scaling!r})"
        return train, val

    def _existence(self, train: FlowMapData, reference) -> dict:
        """The existence check in the trained coordinates (``x~ = T x``, ``D Phi~ = T D Phi T^-1``): exact Jacobians
        of the reduced system (``reference = (system, samples)``, ``data="reduced"`` without a split), else the
        least-squares linear maps of the samples (``S``'s pairs with a split).  With ``split_fallback``, where no
        generating function exists at ``dt`` without it, the exact linear flow of the quadratic part is split off
        (the kernel learns the remainder ``S``), logged and recorded in ``choice_["split"]``."""
        scaling = self._fit_state_scaling(train)

        def check():
            if reference is not None and self._split is None:
                system, full = reference
                return check_generating_function(_conjugated_system(system, scaling.matrix_),
                                                 self._scaled_states(full, scaling), update=self._checked_update())
            return self._check_existence_from_data(self._scaled_states(self.split_pairs(train), scaling))

        try:
            return self._checked_existence(check)
        except ValueError as exc:
            if self.split_fallback is None:
                raise
            first = str(exc)
        self._split = self.split_fallback
        try:
            out = self._checked_existence(check)
        except ValueError as exc:
            self._split = None
            raise ValueError(f"no generating function exists at dt = {self.dt!r}, neither without a split ({first}) "
                             f"nor for the remainder S once the exact linear flow of split_fallback is split off "
                             f"({exc}): use a smaller macro step") from None
        self.choice_["split"] = "split_fallback"
        self.choice_["reason"] = (f"no generating function exists at dt = {self.dt!r} without a split ({first}); with "
                                  f"the exact linear flow of split_fallback split off, the remainder's "
                                  f"({self.choice_['reason']})")
        self.logger.info(f"split_fallback used: the step is L_h o S o L_h with the exact linear flow L_h of the "
                         f"quadratic part; {self.choice_['reason']}")
        return out

    def _fit_state_scaling(self, train: FlowMapData) -> SymplecticScaling:
        """The state scaling of the predictor's coordinates (``state_scaling``), fitted on the training states."""
        reference = None
        if self.state_scaling == "williamson":
            centre = 0.5 * (self.mu_lo + self.mu_hi)
            reference = self._galerkin().matrix(centre)
        return SymplecticScaling(self.state_scaling, reference).fit(np.concatenate([train.x0, train.x1]))

    @staticmethod
    def _scaled_states(d: FlowMapData, scaling: SymplecticScaling) -> FlowMapData:
        """Samples with their states in the scaled coordinates (parameters and steps as given)."""
        return FlowMapData(scaling.transform(d.x0), scaling.transform(d.x1), d.mu if d.mu.shape[1] else None, d.dt)

    # ------------------------------------------------------------ reduce
    def _search_kernels(self, base, train, val, vary_mu):
        """``clone(base)`` with the state and parameter kernels chosen on ``val`` among the candidates
        (:func:`~sympredict.estimators.selection.select_kernels`), or ``None`` when there is nothing to choose."""
        default = self.estimator is None
        if not default and self.state_kernels is None and self.mu_kernels is None:
            return None
        if val is None:
            raise ValueError("choosing kernels (state_kernels, mu_kernels or the default estimator) needs validation "
                             "data: give validation_data with the caller's data, validation_trajectories with "
                             "trajectories, or an estimator that chooses its kernels on held-out training samples "
                             "(estimator=SymplecticKernelPredictor(), no kernels given)")
        inner = base.state_kernel.radial if isinstance(base.state_kernel, KernelTransform) else base.state_kernel
        if self.state_kernels is not None:
            states = self.state_kernels
        else:
            states = [IMQ(float(e)) for e in log_grid(0.01, 1.0, 2)] if default else [inner]
        if not vary_mu:
            mus = [None]
        elif self.mu_kernels is not None:
            mus = self.mu_kernels
        else:
            mus = [IMQ(float(e)) for e in log_grid(0.3, 3.0, 2)] if default else [base.mu_kernel]
        m_star = min(self.m_star, int(getattr(base, "max_centers", self.m_star)))
        with self.logger.block(f"kernel shapes on validation data ({len(states) * len(mus)} candidates, m* = {m_star})"):
            sel = select_kernels(train, val, states, mus, [base.dt_kernel], m_star=m_star, estimator=base)
        self.selection_ = sel
        state = base.state_kernel.with_radial(sel.state) if isinstance(base.state_kernel, KernelTransform) else sel.state
        return clone(base).set_params(state_kernel=state, mu_kernel=sel.mu)

    def _default_predictor(self, train, val, vary_mu):
        base = SymplecticKernelPredictor(None, None, None, max_centers=self.max_centers, trainer=ExactGreedy(tol=1e-12),
                                         update=self._update())
        return self._search_kernels(base, train, val, vary_mu)

    def scaled_training_data(self):
        """Training and validation data in the predictor's coordinates, and the scalings that map to them.

        Samples the data (:meth:`training_data`, kept as ``train_data_`` and
        ``validation_data_``), fits the state scaling (``state_scaling``) and,
        when the parameters vary, the box scaling of the parameters
        (``parameter_scaling``); the step becomes the time unit (``time_scaling``).
        :meth:`reduce` fits its predictor on exactly
        these data, so a kernel search run on them (e.g.
        :func:`~sympredict.estimators.selection.select_kernels` with another update) chooses
        for the model that :meth:`reduce` trains.

        Returns
        -------
        s_train, s_val : FlowMapData
            Scaled states, parameters in ``[0, 1]^d`` (``None`` when they do not vary), ``dt = 1``
            (each as given where the scaling is ``"none"``); ``s_val`` is ``None`` without validation data,
            the consecutive states of validation trajectories.
        state_scaling : SymplecticScaling
        mu_scaling : BoxScaling or None
        """
        with self.logger.block(f"flow-map data ({self.mode}), 2n = {self.dim}, dt = {self.dt!r}"):
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
            mu_scaling = BoxScaling().fit(train.mu, self.flow_lo, self.flow_hi) if self.parameter_scaling == "box" else \
                BoxScaling().fit(train.mu, np.zeros(d), np.ones(d))
        self.tau_ = self.dt if self.time_scaling == "step" else 1.0

        assert np.allclose(train.dt, self.dt) and (val is None or np.allclose(val.dt, self.dt))

        def scaled(d):
            if d is None:
                return None
            return FlowMapData(state_scaling.transform(d.x0), state_scaling.transform(d.x1),
                               mu_scaling.transform(d.mu) if vary_mu else None,
                               np.ones(len(d)) if self.time_scaling == "step" else d.dt)  # time unit dt

        return scaled(train), scaled(val), state_scaling, mu_scaling

    def _fit(self, predictor, s_train, s_val, vary_mu, state_scaling, mu_scaling):
        """Fit ``predictor`` (inside the split, if any) on the scaled data; the flow map in reduced coordinates."""
        model = predictor
        if self._split is not None:
            quad = self._split
            if not vary_mu and quad.checked()[1].shape[1]:  # one training parameter: A at that parameter
                quad = QuadraticPart(quad.hessian(self.train_data_.mu[:1], 1))
            model = SplitKernelPredictor(predictor, scaled_quadratic_part(quad, state_scaling, mu_scaling, self.tau_))
        model.fit(s_train.x0, s_train.x1, mu=s_train.mu if vary_mu else None, dt=s_train.dt,
                  validation=None if s_val is None else (s_val.x0, s_val.x1, s_val.mu if vary_mu else None, s_val.dt))
        flow_map = NormalizedFlowMap(model, state_scaling, mu_scaling if vary_mu else None, self.tau_,
                                     parameters=self.flow_parameters)
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
                    pred = flow_map.rollout(val.states[:, 0], ref.shape[1], mu=val.mu if val.mu.shape[1] else None,
                                            dt=self.dt)[:, 1:]
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
        :class:`~sympredict.flowmap.splitting.SplitKernelPredictor` with ``split``), ``flow_map_`` (the ROM's
        flow map in reduced coordinates), ``selection_`` (where kernels were chosen), ``regularization_`` and
        ``regularization_table_`` (with ``regularizations``: the chosen term and ``[{"regularization", "score"}]``,
        ``score`` ``None`` where not finite) and ``timings_`` (seconds of ``data``, ``selection`` and ``fit``).
        """
        if self.mode == "given":
            rows = self.data.mu
        else:
            rows = self._mu_rows(self.training_parameters)[:, self._flow_index]
        if len(np.unique(rows, axis=0)) > 1 and self._lacks_mu_kernel(self.estimator) and self.mu_kernels is None:
            # before any FOM solve (reduce() would find it after sampling)
            raise ValueError("the parameters vary across training_parameters but the estimator has mu_kernel=None and "
                             "does not choose one: give it a mu_kernel, or train at one parameter value")
        if self.regularizations is not None and self.validation_data is None and self.mode == "given":
            raise ValueError("choosing the regularization needs validation data: give validation_data (samples or "
                             "trajectories) with the caller's data")
        if self.regularizations is not None and self.trajectories is not None and self.validation_trajectories is None:
            raise ValueError("choosing the regularization needs validation data: give validation_trajectories with "
                             "trajectories")
        t0 = time.perf_counter()
        s_train, s_val, state_scaling, mu_scaling = self.scaled_training_data()
        timings = {"data": time.perf_counter() - t0}
        train = self.train_data_
        vary_mu = mu_scaling is not None
        t0 = time.perf_counter()
        if self._split is None:
            search = (s_train, s_val)
        else:  # the kernels of S, compared on S's samples
            search = tuple(None if d is None else self._scaled_split_pairs(d, state_scaling, mu_scaling, vary_mu)
                           for d in (s_train, s_val))
        if self.estimator is None:
            predictor = self._default_predictor(*search, vary_mu)
        else:
            given = clone(self.estimator)
            if self._given_update() is None and self._update() is not None:  # the update the existence check chose
                given = given.set_params(update=self._update())
            predictor = self._search_kernels(clone(given), *search, vary_mu) or given
            if vary_mu and self._lacks_mu_kernel(predictor):
                raise ValueError("the parameters vary across training_parameters but the estimator has mu_kernel=None "
                                 "and does not choose one: give it a mu_kernel")
        timings["selection"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        with self.logger.block(f"fitting {type(predictor).__name__} on {len(train)} samples"
                               + ("" if self._split is None else " (inside the split)")):
            if self.regularizations is None:
                model, flow_map = self._fit(predictor, s_train, s_val, vary_mu, state_scaling, mu_scaling)
            else:
                model, flow_map = self._choose_regularization(predictor, s_train, s_val, vary_mu, state_scaling,
                                                              mu_scaling)
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
        return SymplecticKernelModel(flow_map, self._reduced_initial_data(), self.fom.T if T is None else T, self.dt,
                                     self.fom.parameters, name=name,
                                     flow_parameters=self.flow_parameters if self._flow_subset else None)

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
            raise ValueError(f"the fitted ROM cannot take one step of dt = {self.dt!r} from the training data "
                             f"({reason}; update = {self._fitted_update()!r}): "
                             f"use update='midpoint' (estimator=SymplecticKernelPredictor(update='midpoint')), a "
                             f"smaller dt, or a larger basis or budget (the estimator's max_centers)")

    def _scaled_split_pairs(self, d, state_scaling, mu_scaling, vary_mu):
        """``S``'s samples in the predictor's coordinates (what the kernel search compares candidates on)."""
        quad = self._split
        if not vary_mu and quad.checked()[1].shape[1]:
            quad = QuadraticPart(quad.hessian(self.train_data_.mu[:1], 1))
        quad = scaled_quadratic_part(quad, state_scaling, mu_scaling if vary_mu else None, self.tau_)
        L = quad.propagator(d.mu if d.mu.shape[1] else None, 0.5 * d.dt, n=len(d))
        return FlowMapData(np.einsum("bij,bj->bi", L, d.x0), np.einsum("bij,bj->bi", inverse_symplectic_matrices(L), d.x1),
                           d.mu if d.mu.shape[1] else None, d.dt)

    def _choose_regularization(self, predictor, s_train, s_val, vary_mu, state_scaling, mu_scaling):
        """Every ridge term of ``{0} | regularizations`` fitted and scored by :meth:`validation_score`; the best."""
        table, best = [], None
        for lam in sorted({0.0, *self.regularizations}):
            candidate = clone(predictor).set_params(trainer__regularization=lam)
            model, flow_map = self._fit(candidate, s_train, s_val, vary_mu, state_scaling, mu_scaling)
            score = self.validation_score(flow_map)
            table.append({"regularization": lam, "score": score if np.isfinite(score) else None})
            self.logger.info(f"regularization {lam:.3g}: validation score {score:.4e} ({model.n_centers_} centres)")
            if np.isfinite(score) and (best is None or score < best[0]):  # ties: the smaller term (tried first)
                best = (score, lam, model, flow_map)
            elif best is None and lam == 0.0:
                zero = (np.inf, lam, model, flow_map)
        if best is None:
            self.logger.warning("no regularization gave a finite validation score: the exact fit (0) is kept")
            best = zero
        self.regularization_, self.regularization_table_ = best[1], table
        return best[2], best[3]


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
            raise ValueError(f"this ROM was trained at the single parameter {self.mu.tolist()}: it cannot predict at {np.ravel(mu).tolist()}")

    def rollout(self, x0, n_steps, mu=None, dt=None):
        self._check(mu)
        return self.flow_map.rollout(x0, n_steps, None, dt)

    def step(self, x, mu=None, dt=None):
        self._check(mu)
        return self.flow_map.step(x, None, dt)

    def step_jacobian(self, x, mu=None, dt=None):
        self._check(mu)
        return self.flow_map.step_jacobian(x, None, dt)


def _concat(parts: Sequence[FlowMapData]) -> FlowMapData:
    out = parts[0]
    for p in parts[1:]:
        out = out.concatenate(p)
    return out
