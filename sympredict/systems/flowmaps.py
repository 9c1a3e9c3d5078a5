"""Model-agnostic flow-map data: systems, reference flows, samplers, parameters, existence check.

A *system* is anything with ``flow(x0, mu, t) -> x1`` for batches ``x0 (B, 2n)``,
``mu (B, d_mu)``, ``t (B,)``; three kinds are provided:

* :class:`HamiltonianSystem`: ``H`` and ``grad H`` as NumPy callables; its
  reference flow is the classical Runge–Kutta method of order 4 with step
  halving until two successive results agree to ``rtol`` (Richardson estimate
  ``|x_h - x_{h/2}| / 15``), so the reference is accurate, not merely symplectic;
* :class:`LinearHamiltonianSystem`: ``H(x; mu) = 1/2 x^T H(mu) x + x^T h(mu)``
  with an assembled ``H(mu)`` per parameter; exact flow ``expm``
  (:func:`sympredict.systems.linear_flow.exact_propagators`, as for every quadratic Hamiltonian);
  :func:`linear_system_from_pymor` builds one from a (reduced) pyMOR
  ``QuadraticHamiltonianModel``, assembling ``H_op`` per ``mu`` (no affine
  decomposition needed);
* :class:`FlowFunctionSystem`: a black-box ``flow`` (e.g. a solver you cannot open).

Parameters.  A pyMOR ``Mu`` becomes the predictor's parameter vector by
:func:`mu_to_vector`: the values of ``parameters`` (pyMOR ``Parameters``,
sorted by name, as ``Mu.to_numpy`` orders them) each flattened and concatenated,
so ``{'b': [1, 2], 'a': 3}`` gives ``[3, 1, 2]``.  This order is stable: it is
what pyMOR's own ``DataDrivenReductor`` feeds its regressor.
Validation parameters are drawn in the range (:func:`random_parameters`), not
taken from the training ones: validation on the training parameters only
measures interpolation in the states and picked kernels 3–9x worse on the wave.

Samplers: energy-bounded states (:func:`sample_energy_ellipsoid` exact for a
quadratic ``H``, :func:`sample_energy_box` by rejection for any ``H``) and
:func:`sample_trajectory_neighbourhood` (states near given trajectories, the
region a ROM started from a known initial condition visits).

Existence of the generating function (:func:`check_generating_function`): the
symplectic predictor learns the type-II form ``s(q0, p1)``, which exists only
while ``p1`` determines ``p0``, i.e. ``dp1/dp0`` is invertible along the data.
For a linear mode of frequency ``omega`` the flow is a rotation by ``omega dT``
and ``dp1/dp0 = cos(omega dT)``: the form breaks at ``omega dT = pi/2``.
The symmetric (midpoint) update's ``s((x0 + x1) / 2)`` exists while the
midpoint determines ``x0``, i.e. ``(I + D Phi) / 2`` is invertible: ``|cos(omega dT / 2)|``
for a linear mode, so it breaks at half a turn (``update="midpoint"``).
"""

from __future__ import annotations

import warnings
from typing import Callable, Optional

import numpy as np
from pymor.algorithms.to_matrix import to_matrix
from pymor.core.logger import getLogger
from pymor.models.symplectic import BaseQuadraticHamiltonianModel
from pymor.parameters.base import Mu, Parameters

from sympredict._checks import as_choice, as_even_dimension, as_parameter, as_positive_int, as_real, as_states, as_steps
from sympredict.data import FlowMapData
from sympredict.exceptions import GeneratingFunctionWarning
from sympredict.systems.linear_flow import exact_propagators, generator_propagators
from sympredict.symplectic.metrics import canonical_J, j_times

__all__ = [
    "mu_to_vector",
    "mus_to_matrix",
    "parse_mu",
    "random_parameters",
    "parameter_box",
    "HamiltonianSystem",
    "LinearHamiltonianSystem",
    "FlowFunctionSystem",
    "linear_system_from_pymor",
    "rk4_flow",
    "sample_energy_ellipsoid",
    "sample_energy_box",
    "sample_trajectory_neighbourhood",
    "flow_map_data",
    "sampled_flow_map_data",
    "trajectory_pairs",
    "type2_sigma_min",
    "midpoint_sigma_min",
    "check_generating_function",
    "first_singular_step",
]

logger = getLogger("sympredict.systems.flowmaps")


# ---------------------------------------------------------------- parameters
def parse_mu(mu, parameters):
    """``mu`` as a pyMOR ``Mu`` compatible with ``parameters`` (``ValueError`` otherwise).

    Accepts a ``Mu``, a dict, a number or array (pyMOR's ``Parameters.parse``),
    and ``None`` for a parameter-free model.
    """
    if mu is None and not parameters:
        return Mu()
    if not isinstance(mu, Mu):
        try:
            mu = parameters.parse(mu)
        except Exception as exc:  # pyMOR raises AssertionError / ValueError
            raise ValueError(f"cannot read {mu!r} as parameter values for {dict(parameters)}: {exc}") from None
    if mu.has_time_dependent_values:
        raise ValueError(f"time-dependent parameter values are not supported, got {mu}")
    if set(mu.keys()) != set(parameters.keys()) or not parameters.is_compatible(mu):
        raise ValueError(
            f"mu = {mu} does not match the model's parameters {dict(parameters)} "
            "(names and dimensions must agree exactly)"
        )
    return mu


def mu_to_vector(mu, parameters) -> np.ndarray:
    """The parameter vector of ``mu``: values of ``parameters`` sorted by name, each flattened.

    Returns
    -------
    ndarray of shape (parameters.dim,)
    """
    mu = parse_mu(mu, parameters)
    return np.concatenate([np.ravel(mu[k]).astype(float) for k in sorted(parameters)]) if parameters else np.zeros(0)


def mus_to_matrix(mus, parameters) -> np.ndarray:
    """Parameter vectors of several ``Mu`` (:func:`mu_to_vector`), shape (len(mus), parameters.dim)."""
    mus = list(mus)
    if not mus:
        raise ValueError("no parameter values given")
    return np.stack([mu_to_vector(m, parameters) for m in mus]).reshape(len(mus), parameters.dim)


def parameter_box(mus, parameters, space=None):
    """Lower and upper bounds (d,) of the parameters: ``space.ranges`` if given, else the box of ``mus``."""
    if space is not None:
        lo = (
            np.concatenate([np.full(parameters[k], float(space.ranges[k][0])) for k in sorted(parameters)])
            if parameters
            else np.zeros(0)
        )
        hi = (
            np.concatenate([np.full(parameters[k], float(space.ranges[k][1])) for k in sorted(parameters)])
            if parameters
            else np.zeros(0)
        )
        return lo, hi
    mat = mus_to_matrix(mus, parameters)
    return mat.min(axis=0), mat.max(axis=0)


def random_parameters(parameters, lo, hi, n: int, seed: int = 0) -> list:
    """``n`` parameter values uniform in the box ``[lo, hi]`` (seeded; pyMOR's sampler uses a global RNG).

    Returns
    -------
    list of pyMOR Mu
    """
    n = as_positive_int(n, "n")
    rng = np.random.default_rng(seed)
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    values = lo + (hi - lo) * rng.uniform(size=(n, len(lo)))
    out = []
    for v in values:
        d, i = {}, 0
        for k in sorted(parameters):
            d[k] = v[i : i + parameters[k]]
            i += parameters[k]
        out.append(Mu(d))
    return out


# ---------------------------------------------------------------- systems
def rk4_flow(
    gradient: Callable,
    x0: np.ndarray,
    mu: np.ndarray,
    t: np.ndarray,
    rtol: float = 1e-11,
    min_steps: int = 8,
    max_steps: int = 2**16,
) -> np.ndarray:
    """Flow of ``x' = J grad H(x, mu)`` over times ``t`` by RK4 with step halving.

    Starts with ``min_steps`` steps per instance and doubles them until
    ``max |x_h - x_{h/2}| / 15 <= rtol * (1 + |x|)`` for every instance (the
    Richardson estimate of the order-4 error of the finer result), which is returned.

    Parameters
    ----------
    gradient : callable ``(x (B, 2n), mu (B, d)) -> (B, 2n)``
    x0 : ndarray of shape (B, 2n)
    mu : ndarray of shape (B, d)
    t : ndarray of shape (B,)

    Returns
    -------
    ndarray of shape (B, 2n)

    Notes
    -----
    Cost ``O(B * 4 * steps)`` gradient evaluations, batched over ``B``.
    """

    def rhs(x):
        return j_times(gradient(x, mu))

    def integrate(steps):
        h = (t / steps)[:, None]
        x = x0.copy()
        for _ in range(steps):
            k1 = rhs(x)
            k2 = rhs(x + 0.5 * h * k1)
            k3 = rhs(x + 0.5 * h * k2)
            k4 = rhs(x + h * k3)
            x = x + (h / 6.0) * (k1 + 2 * k2 + 2 * k3 + k4)
        return x

    steps = int(min_steps)
    coarse = integrate(steps)
    while True:
        fine = integrate(2 * steps)
        err = np.abs(fine - coarse).max(axis=1) / 15.0
        if not np.all(np.isfinite(fine)):
            raise ValueError("the reference flow diverged (non-finite states): check H, grad H and the step")
        if np.all(err <= rtol * (1.0 + np.abs(fine).max(axis=1))):
            return fine
        steps *= 2
        if steps > max_steps:
            raise ValueError(
                f"the RK4 reference flow did not reach rtol = {rtol:.0e} with {max_steps} steps "
                f"(estimated error {err.max():.1e}): is grad H consistent with H?"
            )
        coarse = fine


class _ScalarParameterSystem:
    """Shared by the closed-form systems of one scalar parameter whose reference flow is one macro step of their
    ``trajectory`` (:class:`~sympredict.systems.henon_heiles.HenonHeiles`,
    :class:`~sympredict.systems.three_body.ThreeBody`): the parameter's check, ``repr`` and ``flow``."""

    dim: int
    n_mu = 1
    #: The parameter as named in messages.
    parameter_name = "mu"
    #: Closed range ``(lo, hi)`` the parameter must lie in, or ``None``.
    parameter_bounds: Optional[tuple] = None

    def __repr__(self) -> str:
        return f"{type(self).__name__}()"

    def _parameter(self, mu, b: int) -> np.ndarray:
        """The parameter of each of ``b`` instances, shape (b,), checked against :attr:`parameter_bounds`."""
        mu = as_parameter(mu, b, 1, name=self.parameter_name)[:, 0]
        if self.parameter_bounds is not None:
            lo, hi = self.parameter_bounds
            if np.any((mu < lo) | (mu > hi)):
                raise ValueError(
                    f"{self.parameter_name} must lie in [{lo}, {hi}], got values in [{mu.min()}, {mu.max()}]"
                )
        return mu

    def _one_step(self, x0, mu, t, **options) -> np.ndarray:
        """``Phi_mu^t(x0)``: :meth:`trajectory` with one macro step ``t`` (and its ``options``), shape of ``x0``."""
        x0, single = as_states(x0, "x0", dim=self.dim)
        out = self.trajectory(x0, mu, t, 1, **options)[:, 1]
        return out[0] if single else out


class _System:
    """Shared: dimension checks and the finite-difference flow Jacobian."""

    dim: int
    n_mu: int

    parameters = Parameters({})

    def _inputs(self, x0, mu, t):
        x0, single = as_states(x0, "x0", dim=self.dim)
        b = len(x0)
        if isinstance(mu, Mu):  # a pyMOR Mu: flattened in Parameters order (mu_to_vector)
            mu = mu_to_vector(mu, self.parameters)
        mu = np.zeros((b, 0)) if mu is None or np.size(mu) == 0 else as_parameter(mu, b, self.n_mu or None)
        if mu.shape[1] != self.n_mu:
            raise ValueError(f"mu must have {self.n_mu} component(s) per instance, got shape {np.shape(mu)}")
        return x0, single, np.ascontiguousarray(mu), as_steps(t, b, name="t")

    def flow_jacobian(self, x0, mu, t, rel_step: float = 1e-5) -> np.ndarray:
        """``D Phi(x0)`` by central differences of :meth:`flow`, shape (B, 2n, 2n).

        Step ``rel_step * (1 + |x0|)`` per instance; error ``O(rel_step^2)``
        plus the flow's own error divided by the step.
        """
        x0, single, mu, t = self._inputs(x0, mu, t)
        b, d = x0.shape
        h = rel_step * (1.0 + np.abs(x0).max(axis=1))
        eye = np.eye(d)
        xp = (x0[:, None, :] + h[:, None, None] * eye[None]).reshape(-1, d)
        xm = (x0[:, None, :] - h[:, None, None] * eye[None]).reshape(-1, d)
        rep = lambda a: np.repeat(a, d, axis=0)
        fp = self.flow(xp, rep(mu), rep(t)).reshape(b, d, d)
        fm = self.flow(xm, rep(mu), rep(t)).reshape(b, d, d)
        jac = np.swapaxes((fp - fm) / (2 * h[:, None, None]), 1, 2)
        return jac[0] if single else jac

    def trajectory(self, x0, mu, dt, n_steps: int) -> np.ndarray:
        """States on the grid ``t_k = k dt``, shape (B, K+1, 2n)."""
        n_steps = as_positive_int(n_steps, "n_steps", minimum=0)
        x0, single, mu, dt = self._inputs(x0, mu, dt)
        traj = np.empty((len(x0), n_steps + 1, self.dim))
        traj[:, 0] = x0
        for k in range(n_steps):
            traj[:, k + 1] = self.flow(traj[:, k], mu, dt)
        return traj[0] if single else traj


class HamiltonianSystem(_System):
    """A Hamiltonian system given by ``H`` and ``grad H`` callables.

    Parameters
    ----------
    H : callable ``(x (B, 2n), mu (B, d)) -> (B,)``
    grad_H : callable ``(x (B, 2n), mu (B, d)) -> (B, 2n)``
        Gradient ordered ``(d_q H, d_p H)``.
    dim : int
        ``2n``.
    parameters : pyMOR ``Parameters`` or dict, optional
        Names and dimensions of the parameters (``mu`` vectors follow :func:`mu_to_vector`).
    rtol : float
        Tolerance of the RK4 reference flow (:func:`rk4_flow`).
    """

    def __init__(self, H: Callable, grad_H: Callable, dim: int, parameters=None, rtol: float = 1e-11):
        self.H = H
        self.grad_H = grad_H
        self.dim = as_even_dimension(as_positive_int(dim, "dim", minimum=2), "dim")
        self.parameters = Parameters(parameters or {})
        self.n_mu = self.parameters.dim
        self.rtol = float(rtol)

    def hamiltonian(self, x, mu=None) -> np.ndarray:
        x, _, mu, _ = self._inputs(x, mu, 1.0)
        return np.asarray(self.H(x, mu), dtype=float).reshape(len(x))

    def gradient(self, x, mu=None) -> np.ndarray:
        x, _, mu, _ = self._inputs(x, mu, 1.0)
        return np.asarray(self.grad_H(x, mu), dtype=float).reshape(x.shape)

    def flow(self, x0, mu=None, t=None) -> np.ndarray:
        """Reference flow (RK4, step halving to ``rtol``), shape of ``x0``."""
        x0, single, mu, t = self._inputs(x0, mu, t)
        out = rk4_flow(lambda x, m: np.asarray(self.grad_H(x, m), dtype=float), x0, mu, t, self.rtol)
        return out[0] if single else out


class LinearHamiltonianSystem(_System):
    """``H(x; mu) = 1/2 x^T H(mu) x + x^T h(mu)``, assembled per parameter; exact flows.

    Parameters
    ----------
    matrix : callable ``mu (d,) -> ndarray (2n, 2n)``
        Symmetric ``H(mu)``; evaluated once per distinct ``mu`` (cached).
    dim : int
    n_mu : int
    linear_term : callable ``mu (d,) -> ndarray (2n,)``, optional
        ``h(mu)``.
    parameters : pyMOR ``Parameters`` or dict, optional
        Names and dimensions, so that methods also take a pyMOR ``Mu`` for ``mu``.
    """

    def __init__(
        self, matrix: Callable, dim: int, n_mu: int = 0, linear_term: Optional[Callable] = None, parameters=None
    ):
        self._matrix_fn = matrix
        if parameters is not None:
            self.parameters = Parameters(parameters)
            if self.parameters.dim != n_mu:
                raise ValueError(
                    f"parameters {dict(self.parameters)} have dimension {self.parameters.dim}, n_mu = {n_mu}"
                )
        self._h_fn = linear_term
        self.dim = as_positive_int(dim, "dim", minimum=2)
        self.n_mu = int(n_mu)
        self.J = canonical_J(self.dim)
        self._cache: dict = {}

    def matrix(self, mu) -> np.ndarray:
        """``H(mu)``, shape (2n, 2n)."""
        mu = np.asarray(mu, dtype=float).reshape(self.n_mu)
        key = ("H", mu.tobytes())
        if key not in self._cache:
            M = np.asarray(self._matrix_fn(mu), dtype=float)
            if M.shape != (self.dim, self.dim):
                raise ValueError(f"H(mu) must have shape {(self.dim, self.dim)}, got {M.shape}")
            self._cache[key] = 0.5 * (M + M.T)
        return self._cache[key]

    def linear_term(self, mu) -> np.ndarray:
        if self._h_fn is None:
            return np.zeros(self.dim)
        mu = np.asarray(mu, dtype=float).reshape(self.n_mu)
        key = ("h", mu.tobytes())
        if key not in self._cache:
            self._cache[key] = np.asarray(self._h_fn(mu), dtype=float).reshape(self.dim)
        return self._cache[key]

    def hamiltonian(self, x, mu=None) -> np.ndarray:
        x, _, mu, _ = self._inputs(x, mu, 1.0)
        return self._grouped(
            x, mu, lambda m, xs: 0.5 * np.einsum("bi,ij,bj->b", xs, self.matrix(m), xs) + xs @ self.linear_term(m)
        )

    def gradient(self, x, mu=None) -> np.ndarray:
        x, _, mu, _ = self._inputs(x, mu, 1.0)
        return self._grouped(x, mu, lambda m, xs: xs @ self.matrix(m) + self.linear_term(m), width=self.dim)

    def hessian(self, x, mu=None) -> np.ndarray:
        x, _, mu, _ = self._inputs(x, mu, 1.0)
        return np.stack([self.matrix(m) for m in mu])

    @staticmethod
    def _grouped(x, mu, fn, width=None):
        out = np.empty((len(x),) if width is None else (len(x), width))
        uniq, inv = np.unique(mu, axis=0, return_inverse=True)
        for i, m in enumerate(uniq):
            sel = inv.ravel() == i
            out[sel] = fn(m, x[sel])
        return out

    def propagator(self, mu, t: float) -> np.ndarray:
        """Affine flow as a ``(2n+1, 2n+1)`` matrix ``expm(t [[J H, J h], [0, 0]])`` (last row ``e``)."""
        key = ("P", np.asarray(mu, float).tobytes(), float(t))
        if key not in self._cache:
            self._cache[key] = exact_propagators(self.matrix(mu), float(t), linear=self.linear_term(mu))
        return self._cache[key]

    def flow(self, x0, mu=None, t=None) -> np.ndarray:
        """Exact flow, one matrix exponential per distinct ``(mu, t)``; shape of ``x0``."""
        x0, single, mu, t = self._inputs(x0, mu, t)
        out = np.empty_like(x0)
        uniq, inv = np.unique(np.column_stack([mu, t]), axis=0, return_inverse=True)
        for i, key in enumerate(uniq):
            sel = inv.ravel() == i
            P = self.propagator(key[:-1], key[-1])
            out[sel] = x0[sel] @ P[: self.dim, : self.dim].T + P[: self.dim, self.dim]
        return out[0] if single else out

    def flow_jacobian(self, x0, mu=None, t=None, rel_step=None) -> np.ndarray:
        """Exact ``D Phi = expm(t J H(mu))`` per instance, shape (B, 2n, 2n)."""
        x0, single, mu, t = self._inputs(x0, mu, t)
        jac = np.stack([self.propagator(m, tt)[: self.dim, : self.dim] for m, tt in zip(mu, t)])
        return jac[0] if single else jac

    def frequencies(self, mu) -> np.ndarray:
        """``|Im|`` of the eigenvalues of ``J H(mu)`` (the modal frequencies for an SPD ``H``)."""
        return np.abs(np.linalg.eigvals(self.J @ self.matrix(mu)).imag)


class FlowFunctionSystem(_System):
    """A black-box flow ``flow(x0 (B, 2n), mu (B, d), t (B,)) -> (B, 2n)``; ``H`` optional (for samplers)."""

    def __init__(self, flow: Callable, dim: int, n_mu: int = 0, H: Optional[Callable] = None):
        self._flow = flow
        self.dim = as_positive_int(dim, "dim", minimum=2)
        self.n_mu = int(n_mu)
        self.H = H

    def flow(self, x0, mu=None, t=None) -> np.ndarray:
        x0, single, mu, t = self._inputs(x0, mu, t)
        out = np.asarray(self._flow(x0, mu, t), dtype=float).reshape(x0.shape)
        return out[0] if single else out

    def hamiltonian(self, x, mu=None) -> np.ndarray:
        if self.H is None:
            raise ValueError("this FlowFunctionSystem has no H: pass H=... to use energy-based samplers")
        x, _, mu, _ = self._inputs(x, mu, 1.0)
        return np.asarray(self.H(x, mu), dtype=float).reshape(len(x))


def linear_system_from_pymor(model) -> LinearHamiltonianSystem:
    """The (reduced) quadratic Hamiltonian of a pyMOR model as a :class:`LinearHamiltonianSystem`.

    ``H_op`` (and the linear term ``h``) are assembled densely per parameter
    value with ``to_matrix``, so any parameter dependence works; meant for
    reduced models (``2n`` small).  ``mu`` vectors follow :func:`mu_to_vector`.
    """
    if not isinstance(model, BaseQuadraticHamiltonianModel):
        raise ValueError(f"expected a pyMOR (reduced) QuadraticHamiltonianModel, got {type(model).__name__}")
    params = model.parameters

    def as_mu(v):
        d, i = {}, 0
        for k in sorted(params):
            d[k] = v[i : i + params[k]]
            i += params[k]
        return Mu(d)

    def matrix(v):
        return np.asarray(to_matrix(model.H_op, mu=as_mu(v), format="dense"))

    def linear_term(v):
        h = model.h.as_range_array(as_mu(v))
        return h.to_numpy().ravel() if hasattr(h, "to_numpy") else np.hstack([b.to_numpy().ravel() for b in h.blocks])

    dim = model.H_op.source.dim
    return LinearHamiltonianSystem(matrix, dim, params.dim, linear_term, parameters=params)


# ---------------------------------------------------------------- samplers
def _unit_ball(rng, n, d):
    z = rng.normal(size=(n, d))
    return z * rng.uniform(size=(n, 1)) ** (1.0 / d) / np.linalg.norm(z, axis=1, keepdims=True)


def sample_energy_ellipsoid(system: LinearHamiltonianSystem, n: int, mu, energy: float, rng) -> np.ndarray:
    """States uniform in ``{x : 1/2 x^T H(mu) x <= energy}`` (``H(mu)`` SPD), shape (n, 2n).

    ``x = sqrt(2 energy) L^{-T} z``, ``H = L L^T``, ``z`` uniform in the unit ball: exact, rejection-free.
    ``system``: anything with ``matrix(mu)`` and ``dim`` (:class:`LinearHamiltonianSystem`,
    :class:`~sympredict.systems.quadratic.QuadraticHamiltonian`).
    """
    n = as_positive_int(n, "n")
    energy = as_real(energy, "energy", positive=True)
    try:
        L = np.linalg.cholesky(system.matrix(mu))
    except np.linalg.LinAlgError:
        raise ValueError(f"H(mu={mu}) is not positive definite: its energy sub-level set is unbounded") from None
    return np.sqrt(2.0 * energy) * np.linalg.solve(L.T, _unit_ball(rng, n, system.dim).T).T


def sample_energy_box(system, n: int, mu, energy: float, lo, hi, rng, max_tries: int = 1000, strict: bool = False):
    """States uniform in ``{x in [lo, hi] : H(x; mu) <= energy}`` by rejection, shape (n, 2n).

    Parameters
    ----------
    mu
        The parameter vector, or a callable ``draw(size) -> (size,) or (size, d_mu)`` giving each
        candidate state its own parameter (drawn after the states of each round); then the
        accepted parameters are returned too.
    strict
        Accept ``H < energy`` instead of ``H <= energy``.
    max_tries
        Rounds of ``2 n`` candidates before giving up.

    Returns
    -------
    ndarray of shape (n, 2n), and with a callable ``mu`` the accepted parameters (n,) or (n, d_mu)

    Raises
    ------
    ValueError
        If fewer than ``n`` states are accepted in ``max_tries`` rounds (the set is tiny in the box);
        the message gives the counts.
    """
    n = as_positive_int(n, "n")
    lo = np.broadcast_to(np.asarray(lo, float), (system.dim,))
    hi = np.broadcast_to(np.asarray(hi, float), (system.dim,))
    per_state = callable(mu)
    if not per_state:
        mu = np.asarray([] if mu is None else mu, dtype=float).reshape(1, -1)
    states, params = [], []
    count = 0
    for _ in range(max_tries):
        cand = rng.uniform(lo, hi, size=(2 * n, system.dim))
        m = mu(len(cand)) if per_state else np.repeat(mu, len(cand), axis=0)
        h = system.hamiltonian(cand, m)
        keep = h < energy if strict else h <= energy
        states.append(cand[keep])
        params.append(m[keep])
        count += int(keep.sum())
        if count >= n:
            x = np.concatenate(states)[:n]
            return (x, np.concatenate(params)[:n]) if per_state else x
    raise ValueError(
        f"only {count} of {n} states accepted (H {'<' if strict else '<='} {energy:g}) in {max_tries * 2 * n} draws"
    )


def sample_trajectory_neighbourhood(trajectories: np.ndarray, n: int, radius: float, rng, scale=None) -> np.ndarray:
    """States near trajectories: a random trajectory point plus a perturbation, shape (n, 2n).

    The perturbation is uniform in a ball of radius ``radius * |x_k|`` in the
    norm ``|x / scale|`` (``scale`` (2n,) per component, default ones), so it
    is relative to the local state size.  ``radius = 0`` returns trajectory points.

    Parameters
    ----------
    trajectories : ndarray of shape (K, 2n) or (B, K, 2n)
    """
    n = as_positive_int(n, "n")
    pts = np.asarray(trajectories, dtype=float)
    pts = pts.reshape(-1, pts.shape[-1])
    scale = np.ones(pts.shape[1]) if scale is None else np.asarray(scale, float)
    # distinct points while there are enough (duplicated samples make contradictory interpolation conditions)
    base = pts[rng.choice(len(pts), size=n, replace=n > len(pts))]
    size = radius * np.linalg.norm(base / scale, axis=1, keepdims=True)
    return base + size * _unit_ball(rng, n, pts.shape[1]) * scale


# ---------------------------------------------------------------- data
def flow_map_data(system, x0, mu, dt) -> FlowMapData:
    """Samples ``x1 = system.flow(x0, mu, dt)``: ``x0 (M, 2n)``, ``mu (M, d)``, ``dt (M,)`` or a float."""
    x0, _ = as_states(x0, "x0", dim=system.dim, allow_single=False)
    mu = np.zeros((len(x0), 0)) if mu is None or np.size(mu) == 0 else as_parameter(mu, len(x0), system.n_mu or None)
    dt = as_steps(dt, len(x0))
    return FlowMapData(x0, system.flow(x0, mu, dt), mu if mu.shape[1] else None, dt)


def sampled_flow_map_data(system, mus: np.ndarray, dts, sampler: Callable, n_per_mu: int, seed: int = 0) -> FlowMapData:
    """Flow-map data over parameters: per ``mu`` row, ``n_per_mu`` states from ``sampler`` and steps from ``dts``.

    Parameters
    ----------
    mus : ndarray of shape (P, d), or a sequence of pyMOR Mu
        Parameter vectors (``d = 0``: one row, parameter-free); ``Mu`` objects are
        flattened by :func:`mu_to_vector` with ``system.parameters``.
    dts : float or sequence of float
        Macro steps; each sample gets one drawn uniformly from this set (or the range
        ``(lo, hi)`` given as a 2-tuple ``("range", lo, hi)``).
    sampler : callable ``(mu (d,), n, rng) -> (n, 2n)``
    """
    rng = np.random.default_rng(seed)
    if system.n_mu and len(mus) and isinstance(mus[0], Mu):
        mus = mus_to_matrix(mus, system.parameters)
    mus = np.asarray(mus, dtype=float).reshape(-1, system.n_mu) if system.n_mu else np.zeros((1, 0))
    x0s, ms, ds = [], [], []
    for m in mus:
        x0 = np.asarray(sampler(m, n_per_mu, rng), dtype=float)
        if isinstance(dts, tuple) and len(dts) == 3 and dts[0] == "range":
            d = rng.uniform(dts[1], dts[2], size=len(x0))
        else:
            d = rng.choice(np.atleast_1d(np.asarray(dts, dtype=float)), size=len(x0))
        x0s.append(x0)
        ms.append(np.repeat(m[None], len(x0), axis=0))
        ds.append(d)
    return flow_map_data(system, np.concatenate(x0s), np.concatenate(ms), np.concatenate(ds))


def trajectory_pairs(trajectories: np.ndarray, mu: np.ndarray, h: float, stride: int) -> FlowMapData:
    """Pairs ``(x(t_k), x(t_k + stride h))`` of trajectories sampled every ``h`` (non-intrusive data).

    Parameters
    ----------
    trajectories : ndarray of shape (B, K+1, 2n)
    mu : ndarray of shape (B, d)
    h : float
        Sampling interval of the trajectories.
    stride : int
        Samples per macro step (``dt = stride * h``).
    """
    traj = np.asarray(trajectories, dtype=float)
    stride = as_positive_int(stride, "stride")
    b, k1, d = traj.shape
    if stride >= k1:
        raise ValueError(f"the trajectories have {k1} samples, too few for a step of {stride} samples")
    x0 = traj[:, :-stride].reshape(-1, d)
    x1 = traj[:, stride:].reshape(-1, d)
    mu = np.asarray(mu, float).reshape(b, -1)
    m = np.repeat(mu, k1 - stride, axis=0)
    return FlowMapData(x0, x1, m if m.shape[1] else None, np.full(len(x0), stride * h))


# ---------------------------------------------------------------- existence check
def type2_sigma_min(jacobians: np.ndarray) -> np.ndarray:
    """Smallest singular value of ``dp1/dp0`` (the lower-right block of ``D Phi``), shape (B,)."""
    jac = np.asarray(jacobians, dtype=float)
    n = jac.shape[-1] // 2
    return np.linalg.svd(jac[..., n:, n:], compute_uv=False)[..., -1]


def midpoint_sigma_min(jacobians: np.ndarray) -> np.ndarray:
    """Smallest singular value of ``(I + D Phi) / 2``, the Jacobian of ``x0 -> (x0 + x1) / 2``, shape (B,).

    The symmetric update's generating function is a function of the midpoint: it
    exists while this is nonzero; ``|cos(theta / 2)|`` for a mode turning by ``theta``.
    """
    jac = np.asarray(jacobians, dtype=float)
    return np.linalg.svd(0.5 * (np.eye(jac.shape[-1]) + jac), compute_uv=False)[..., -1]


_SIGMA = {"symplectic_euler": type2_sigma_min, "midpoint": midpoint_sigma_min}


def check_generating_function(
    system,
    data: FlowMapData,
    fail_below: float = 1e-2,
    warn_below: float = 0.1,
    max_points: int = 200,
    seed: int = 0,
    update: str = "symplectic_euler",
) -> dict:
    """Check that the type-II generating function ``s(q0, p1)`` exists on the data; fail or warn if not.

    With ``update="midpoint"`` the symmetric update's ``s((x0 + x1) / 2)`` is
    checked instead: ``sigma`` is then the smallest singular value of
    ``(I + D Phi) / 2`` (:func:`midpoint_sigma_min`, ``|cos(omega dT / 2)|`` for a
    linear mode: it fails at half a turn per step, ``omega dT = pi``).

    ``s(q0, p1)`` exists while ``p1`` determines ``p0``: ``dp1/dp0`` invertible.
    Its smallest singular value ``sigma`` is computed at (up to ``max_points``
    random) samples from the system's flow Jacobian (exact for a
    :class:`LinearHamiltonianSystem`, central differences of the reference flow
    otherwise).  For a linear mode ``sigma = |cos(omega dT)|``: it vanishes at
    ``omega dT = pi/2``.  A block-diagonal symplectic conjugation ``q -> A q, p -> A^{-T} p``
    (a diagonal state normalization) does not change invertibility, only ``sigma``; one
    that mixes ``q`` and ``p`` (e.g. Williamson coordinates) does, so pass the system and
    the data in the coordinates the predictor is trained in (the Jacobian there is
    ``T D Phi T^-1``; :class:`~sympredict.mor.SymplecticKernelReductor` does).

    Parameters
    ----------
    fail_below, warn_below
        Thresholds on ``min sigma`` (dimensionless: ``dp1/dp0`` maps momenta to momenta).

    Returns
    -------
    dict
        ``sigma_min`` (over the checked points), ``dt_max`` (largest step, at the
        checked points' parameters, with ``sigma >= fail_below``: ``pi / (2 omega_max)``
        for a linear system, a scan of ``dT`` otherwise), ``points`` checked.

    Raises
    ------
    ValueError
        If ``min sigma < fail_below``, or a data step lies at or past ``dt_max``
        (the form broke at a smaller step even if ``dp1/dp0`` is invertible again there).

    Warns
    -----
    GeneratingFunctionWarning
        If ``fail_below <= min sigma < warn_below``.
    """
    as_choice(update, "update", _SIGMA)
    rng = np.random.default_rng(seed)
    idx = np.sort(rng.choice(len(data), size=min(len(data), max_points), replace=False))
    x0, mu, dt = data.x0[idx], data.mu[idx], data.dt[idx]
    sigma = _SIGMA[update](system.flow_jacobian(x0, mu, dt))
    worst = int(np.argmin(sigma))
    dt_max = _largest_admissible_dt(system, x0, mu, dt, fail_below, update)
    if dt.max() >= dt_max:  # past the first singularity, even where dp1/dp0 has recovered
        worst = int(np.argmax(dt))
    info = _report_existence(float(sigma[worst]), mu[worst], float(dt[worst]), dt_max, fail_below, warn_below, update)
    info["points"] = len(idx)
    return info


def _report_existence(
    s_min: float,
    mu_worst,
    dt_worst: float,
    dt_max: float,
    fail_below: float,
    warn_below: float,
    update: str = "symplectic_euler",
) -> dict:
    """Raise / warn / log for the existence check (one message for every data source)."""
    mu_worst = np.ravel(mu_worst)
    where = f"mu = {mu_worst.tolist() if mu_worst.size else '(none)'}, dT = {dt_worst:.4g}"
    if update == "midpoint":
        cause = (
            f"the midpoint generating function s((x0 + x1)/2) needs (I + DPhi)/2 invertible, but its smallest singular "
            f"value is {s_min:.2e} at {where} (a linear mode of frequency omega has |cos(omega dT / 2)|: "
            f"it fails at omega dT = pi, half a turn per step); the largest admissible dT here is about {dt_max:.4g}"
        )
    else:
        cause = (
            f"the type-II generating function s(q0, p1) needs dp1/dp0 invertible, but its smallest singular value "
            f"is {s_min:.2e} at {where} (a linear mode of frequency omega has dp1/dp0 = cos(omega dT): "
            f"it fails at omega dT = pi/2); the largest admissible dT here is about {dt_max:.4g}"
        )
    if dt_worst >= dt_max:
        raise ValueError(
            cause.replace(
                "but its smallest singular value",
                "and dT = %.4g lies past the first step where it is singular (smallest singular value here" % dt_worst,
                1,
            ).replace(" at mu", ") at mu", 1)
            + ": use a smaller macro step"
        )
    if s_min < fail_below:
        raise ValueError(cause + ": use a smaller macro step")
    if s_min < warn_below:
        warnings.warn(
            cause + ": the macro step is close to it, expect a hard interpolation problem",
            GeneratingFunctionWarning,
            stacklevel=3,
        )
    logger.info(
        f"{'midpoint' if update == 'midpoint' else 'type-II'} generating function exists on the data: "
        f"min sigma = {s_min:.3f}, largest admissible dT ~ {dt_max:.4g}"
    )
    return {"sigma_min": s_min, "dt_max": dt_max}


def _broken(jac: np.ndarray, threshold: float, update: str = "symplectic_euler") -> bool:
    """The form's Jacobian (``dp1/dp0``, or ``(I + D Phi)/2`` for the midpoint form) singular or past a singularity:
    ``sigma_min < threshold`` or ``det <= 0`` (it is ``+1`` at ``dT = 0``)."""
    if update == "midpoint":
        block = 0.5 * (np.eye(jac.shape[-1]) + jac)
    else:
        n = jac.shape[-1] // 2
        block = jac[..., n:, n:]
    return bool(np.any(_SIGMA[update](jac) < threshold) or np.any(np.linalg.det(block) <= 0))


def first_singular_step(
    generators, threshold: float = 1e-2, n_grid: int = 800, update: str = "symplectic_euler"
) -> float:
    """First ``t`` where the form's Jacobian of ``expm(t A)`` becomes (nearly) singular, over linear generators ``A = J H``.

    Scans ``(0, 2 pi / omega_max]`` on ``n_grid`` points (``omega_max`` the largest
    ``|Im|`` eigenvalue); returns ``pi / (2 omega_max)`` (``pi / omega_max`` for
    ``update="midpoint"``) if no point breaks, ``inf`` for ``omega_max = 0``.
    Cost ``O(n_grid * len(generators))`` matrix exponentials.
    """
    om = max(float(np.abs(np.linalg.eigvals(A).imag).max()) for A in generators)
    if om == 0:
        return np.inf
    for t in np.linspace(0, 2 * np.pi / om, n_grid + 1)[1:]:
        if any(_broken(generator_propagators(A, t), threshold, update) for A in generators):
            return float(t)
    return float(np.pi / ((1 if update == "midpoint" else 2) * om))


def _largest_admissible_dt(system, x0, mu, dt, threshold: float, update: str = "symplectic_euler") -> float:
    """The first ``dT`` of a scan where ``dp1/dp0`` becomes (nearly) singular at some point (:func:`_broken`).

    Linear systems: exact propagators on a grid of ``(0, 2 pi / omega_max]``
    (800 steps; modes coupled through ``H`` may break before ``pi / (2 omega_max)``);
    otherwise finite-difference Jacobians of the reference flow at up to 10 of the
    points on ``(0, 4 max dT]`` (40 steps).  A sign change of ``det(dp1/dp0)``
    between grid points counts, so a coarse grid cannot step over the singularity
    (the midpoint form's ``det((I + D Phi)/2)`` only touches 0 at a half turn,
    ``cos^2(theta/2)`` per mode: there the scan relies on the threshold, which
    the linear grid resolves, ``|theta - pi| / 2 <= pi / 800`` at the fastest mode).
    """
    if isinstance(system, LinearHamiltonianSystem):
        return first_singular_step(
            [system.J @ system.matrix(m) for m in np.unique(mu, axis=0)], threshold, update=update
        )
    sub = slice(0, min(10, len(x0)))
    grid = np.linspace(0, 4 * float(dt.max()), 41)[1:]
    for t in grid:
        if _broken(system.flow_jacobian(x0[sub], mu[sub], np.full(len(x0[sub]), t)), threshold, update):
            return float(t)
    return float(grid[-1])  # admissible at least up to here
