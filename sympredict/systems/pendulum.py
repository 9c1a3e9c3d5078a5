"""The mathematical pendulum with parametric length (paper section 4.2).

``H(q, p; l) = p^2 / (2 m l^2) + m g l (1 - cos q)``, ``m = 1``, ``g = 9.81``,
parameter ``mu = l``.  Reference flows use the implicit midpoint rule with a
micro step of at most ``1e-3`` (as in the paper), solved to round-off.
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np
from pymor.core.logger import getLogger

from sympredict._checks import as_parameter, as_positive_int, as_real, as_states, as_steps
from sympredict.data import FlowMapData
from sympredict.exceptions import NewtonConvergenceError
from sympredict.systems.flowmaps import sample_energy_box
from sympredict.symplectic.integrators import micro_steps
from sympredict.symplectic.integrators_compiled import PointwiseHamiltonian, jit_pointwise
from sympredict.systems.linear_flow import QuadraticPart
from sympredict.parallel import pool_flow

logger = getLogger("sympredict.systems.pendulum")

__all__ = [
    "Pendulum",
    "MU_TRAIN",
    "DT_TRAIN",
    "DT_TEST",
    "energy_bounded_grid",
    "flow_map_data",
    "random_flow_map_data",
]

#: Training lengths and macro steps of scenario A (paper section 4.2).
MU_TRAIN = (0.7, 0.725, 0.75, 0.775, 0.8)
DT_TRAIN = (0.04, 0.05, 0.06)
#: The three test macro steps of the paper's figure.
DT_TEST = (0.0509, 0.04847, 0.05292)

_EPS = np.finfo(float).eps
#: Rounds of ``2 n_samples`` draws :func:`random_flow_map_data` tries before giving up.
MAX_DRAW_ROUNDS = 50


# Per-instance gradients for the compiled integrators (sympredict.symplectic.integrators_compiled):
# mu = (l,), fargs = (m, g); the arithmetic is that of Pendulum.gradient / hessian.
@jit_pointwise
def _grad_V(q, mu, fargs, iargs, out):
    """``dV/dq = m g l sin q``."""
    out[0] = fargs[0] * fargs[1] * mu[0] * math.sin(q[0])


@jit_pointwise
def _grad_T(p, mu, fargs, iargs, out):
    """``dT/dp = p / (m l^2)``."""
    out[0] = p[0] / (fargs[0] * mu[0] * mu[0])


@jit_pointwise
def _grad_H(x, mu, fargs, iargs, out):
    """``grad H = (m g l sin q, p / (m l^2))``."""
    out[0] = fargs[0] * fargs[1] * mu[0] * math.sin(x[0])
    out[1] = x[1] / (fargs[0] * mu[0] * mu[0])


@jit_pointwise
def _hess_H(x, mu, fargs, iargs, out):
    """``diag(m g l cos q, 1 / (m l^2))``."""
    out[0, 0] = fargs[0] * fargs[1] * mu[0] * math.cos(x[0])
    out[0, 1] = 0.0
    out[1, 0] = 0.0
    out[1, 1] = 1.0 / (fargs[0] * mu[0] * mu[0])


class Pendulum:
    """Pendulum ``H(q, p; l) = p^2/(2 m l^2) + m g l (1 - cos q)`` with state ``x = (q, p)`` and ``mu = l``.

    Parameters
    ----------
    g
        Gravitational acceleration.
    mass
        Bob mass ``m``.
    """

    dim = 2
    n_mu = 1

    def __init__(self, g: float = 9.81, mass: float = 1.0):
        self.g = as_real(g, "g", positive=True)
        self.mass = as_real(mass, "mass", positive=True)

    def __repr__(self) -> str:
        return f"Pendulum(g={self.g}, mass={self.mass})"

    def _lengths(self, mu, b):
        length = as_parameter(mu, b, 1, name="mu (pendulum length)")[:, 0]
        if np.any(length <= 0):
            raise ValueError(f"pendulum length mu must be positive, got min {length.min()}")
        return length

    def pointwise(self) -> PointwiseHamiltonian:
        """Per-instance gradients and Hessian for :func:`sympredict.symplectic.integrators_compiled.rollout` (compiled with numba).

        ``H`` is separable (``T = p^2 / (2 m l^2)``, ``V = m g l (1 - cos q)``):
        every scheme applies.
        """
        return PointwiseHamiltonian(
            2,
            1,
            grad_T=_grad_T,
            grad_V=_grad_V,
            grad_H=_grad_H,
            hess_H=_hess_H,
            fargs=(self.mass, self.g),
            check_mu=lambda mu: self._lengths(mu, len(mu)),
            name=repr(self),
        )

    def quadratic_part(self) -> QuadraticPart:
        """The Hessian of ``H`` at the equilibrium ``(0, 0)``: ``A(l) = diag(m g l, 1 / (m l^2))``.

        As monomials in ``l``: ``l^1 diag(m g, 0) + l^-2 diag(0, 1/m)`` (for the
        splitting predictor, :mod:`sympredict.flowmap.splitting`); its flow is the
        linearized pendulum, frequency ``sqrt(g / l)``.
        """
        return QuadraticPart([np.diag([self.mass * self.g, 0.0]), np.diag([0.0, 1.0 / self.mass])], [[1.0], [-2.0]])

    def hamiltonian(self, x, mu) -> np.ndarray:
        """Energy, shape (B,), for states (B, 2) and lengths (B,) or (B, 1)."""
        x = np.atleast_2d(np.asarray(x, dtype=float))
        length = self._lengths(mu, len(x))
        q, p = x[:, 0], x[:, 1]
        return p**2 / (2 * self.mass * length**2) + self.mass * self.g * length * (1 - np.cos(q))

    def gradient(self, x, mu) -> np.ndarray:
        """``grad H = (m g l sin q, p / (m l^2))``, shape (B, 2)."""
        length = self._lengths(mu, len(x))
        return np.column_stack([self.mass * self.g * length * np.sin(x[:, 0]), x[:, 1] / (self.mass * length**2)])

    def hessian(self, x, mu) -> np.ndarray:
        """``diag(m g l cos q, 1 / (m l^2))``, shape (B, 2, 2)."""
        length = self._lengths(mu, len(x))
        hess = np.zeros((len(x), 2, 2))
        hess[:, 0, 0] = self.mass * self.g * length * np.cos(x[:, 0])
        hess[:, 1, 1] = 1.0 / (self.mass * length**2)
        return hess

    def _midpoint_micro_step(self, q, p, length, h):
        """One implicit midpoint step, reduced to a scalar equation for the midpoint angle.

        With ``a = h / (2 m l^2)`` and ``c = h^2 g / (4 l)`` the midpoint angle
        solves ``F(qm) = qm - q - a p + c sin qm = 0`` (Newton, ``F' = 1 + c cos qm``);
        then ``pm = p - (h/2) m g l sin qm``, ``q1 = 2 qm - q``, ``p1 = 2 pm - p``.
        """
        a = h / (2 * self.mass * length**2)
        c = h * h * self.g / (4 * length)
        qm = q + a * p
        for _ in range(30):
            delta = (qm - q - a * p + c * np.sin(qm)) / (1 + c * np.cos(qm))
            qm -= delta
            if np.all(np.abs(delta) <= 2 * _EPS * (np.abs(qm) + 1.0)):
                break
        else:
            bad = np.flatnonzero(np.abs(delta) > 2 * _EPS * (np.abs(qm) + 1.0))
            raise NewtonConvergenceError(bad, np.abs(delta[bad]), reason="(pendulum midpoint) did not converge")
        pm = p - 0.5 * h * self.mass * self.g * length * np.sin(qm)
        return 2 * qm - q, 2 * pm - p

    def flow(self, x0, mu, t, h_max: float = 1e-3) -> np.ndarray:
        """Reference flow ``Phi_mu^t(x0)`` by implicit midpoint with micro step ``t / ceil(t / h_max)``.

        Parameters
        ----------
        x0 : array_like of shape (B, 2)
        mu : float or array_like of shape (B,)
            Lengths.
        t : float or array_like of shape (B,)
            Times (positive).
        h_max
            Largest micro step.

        Returns
        -------
        ndarray of shape (B, 2)

        Notes
        -----
        ``O(B t / h_max)``; instances with fewer micro steps stop early.
        """
        x0, single = as_states(x0, "x0", dim=2)
        b = len(x0)
        length = self._lengths(mu, b)
        t = as_steps(t, b, name="t")
        n_micro = micro_steps(t, h_max)
        h = t / n_micro
        q, p = x0[:, 0].copy(), x0[:, 1].copy()
        if np.all(n_micro == n_micro[0]):
            for _ in range(n_micro[0]):
                q, p = self._midpoint_micro_step(q, p, length, h)
        else:
            for k in range(n_micro.max()):
                act = np.flatnonzero(n_micro > k)
                q[act], p[act] = self._midpoint_micro_step(q[act], p[act], length[act], h[act])
        out = np.column_stack([q, p])
        return out[0] if single else out

    def trajectory(self, x0, mu, dt, n_steps: int, h_max: float = 1e-3) -> np.ndarray:
        """Reference trajectories on the macro grid ``t_k = k dt``, shape (B, K+1, 2)."""
        n_steps = as_positive_int(n_steps, "n_steps", minimum=0)
        x0, single = as_states(x0, "x0", dim=2)
        b = len(x0)
        length = self._lengths(mu, b)
        dt = as_steps(dt, b)
        traj = np.empty((b, n_steps + 1, 2))
        traj[:, 0] = x0
        for k in range(n_steps):
            traj[:, k + 1] = self.flow(traj[:, k], length, dt, h_max)
        return traj[0] if single else traj


def energy_bounded_grid(system: Pendulum, length: float, n_grid: int = 200, energy_max=None) -> np.ndarray:
    """Energy-bounded initial states on a tensor grid (paper's sampling).

    A uniform ``n_grid x n_grid`` grid on ``[-pi, pi] x [-2 sqrt(g), 2 sqrt(g)]``
    (end points included), keeping the points with ``H(q, p; l) < energy_max``
    (default ``2 g``).

    Returns
    -------
    ndarray of shape (M, 2)
    """
    n_grid = as_positive_int(n_grid, "n_grid", minimum=2)
    energy_max = 2 * system.g if energy_max is None else as_real(energy_max, "energy_max", positive=True)
    pmax = 2 * np.sqrt(system.g)
    q, p = np.meshgrid(np.linspace(-np.pi, np.pi, n_grid), np.linspace(-pmax, pmax, n_grid), indexing="ij")
    x = np.column_stack([q.ravel(), p.ravel()])
    return x[system.hamiltonian(x, np.full(len(x), length)) < energy_max]


def flow_map_data(
    system: Pendulum,
    mus=MU_TRAIN,
    dts=DT_TRAIN,
    n_grid: int = 200,
    p_nonpositive: bool = False,
    h_max: float = 1e-3,
    *,
    pool=None,
    chunk_size: Optional[int] = None,
) -> FlowMapData:
    """Flow-map samples over ``mus x dts x energy-bounded grid`` (scenario A; B with ``p_nonpositive``).

    Parameters
    ----------
    system
        The pendulum.
    mus, dts
        Training lengths and macro steps.
    n_grid
        Grid points per axis (paper: 200).
    p_nonpositive
        Keep only initial states with ``p <= 0`` (scenario B).
    h_max
        Micro step of the reference flow.
    pool, chunk_size
        Evaluate the reference flows over a pyMOR worker pool in chunks of
        instances (:func:`sympredict.parallel.pool_flow`: the same samples bit
        for bit); ``None``: in this process.

    Returns
    -------
    FlowMapData
        ``mu`` of shape (M, 1).
    """
    mus, dts = np.atleast_1d(np.asarray(mus, dtype=float)), np.atleast_1d(np.asarray(dts, dtype=float))
    if mus.ndim != 1 or len(mus) == 0:
        raise ValueError(f"mus must be a non-empty sequence of lengths, got shape {mus.shape}")
    if dts.ndim != 1 or len(dts) == 0:
        raise ValueError(f"dts must be a non-empty sequence of macro steps, got shape {dts.shape}")
    x0s, mu_list, dt_list = [], [], []
    for length in mus:
        grid = energy_bounded_grid(system, length, n_grid)
        if p_nonpositive:
            grid = grid[grid[:, 1] <= 0]
        for dt in dts:
            x0s.append(grid)
            mu_list.append(np.full(len(grid), float(length)))
            dt_list.append(np.full(len(grid), float(dt)))
    x0 = np.concatenate(x0s)
    mu = np.concatenate(mu_list)
    dt = np.concatenate(dt_list)
    return FlowMapData(x0, _flows(system, x0, mu, dt, h_max, pool, chunk_size), mu[:, None], dt)


def random_flow_map_data(
    system: Pendulum,
    n_samples: int,
    mu_range=(0.7, 0.8),
    dt_range=(0.04, 0.06),
    seed: int = 0,
    h_max: float = 1e-3,
    mu_values=None,
    dt_values=None,
    *,
    pool=None,
    chunk_size: Optional[int] = None,
) -> FlowMapData:
    """Flow-map samples at random energy-bounded states, lengths and steps (validation data).

    States are drawn uniformly in the sampling box and kept when ``H < 2 g``.
    Lengths and steps are drawn uniformly from ``mu_values`` / ``dt_values``
    when given (e.g. the training grid, as for the paper's validation
    curves), else uniformly in ``mu_range`` / ``dt_range``.  ``pool`` and
    ``chunk_size`` as in :func:`flow_map_data`.

    Raises
    ------
    ValueError
        Bad ranges, or fewer than ``n_samples`` states accepted within
        :data:`MAX_DRAW_ROUNDS` rounds of ``2 n_samples`` draws (acceptance
        below about 1 %: the energy bound excludes nearly the whole box).
    """
    n_samples = as_positive_int(n_samples, "n_samples")
    for name, bounds, values in (("mu_range", mu_range, mu_values), ("dt_range", dt_range, dt_values)):
        if values is None:
            if len(bounds) != 2:
                raise ValueError(f"{name} must be (low, high), got {bounds!r}")
            low, high = (as_real(v, name, positive=True) for v in bounds)
            if low > high:
                raise ValueError(f"{name} must satisfy low <= high, got {bounds!r}")
    rng = np.random.default_rng(seed)

    def draw(values, bounds, size):
        return (
            rng.choice(np.asarray(values, dtype=float), size=size)
            if values is not None
            else rng.uniform(*bounds, size=size)
        )

    pmax = 2 * np.sqrt(system.g)
    try:
        x0, mu = sample_energy_box(
            system,
            n_samples,
            lambda size: draw(mu_values, mu_range, size),
            2 * system.g,
            [-np.pi, -pmax],
            [np.pi, pmax],
            rng,
            max_tries=MAX_DRAW_ROUNDS,
            strict=True,
        )
    except ValueError as exc:
        raise ValueError(
            f"random_flow_map_data: {exc}; the energy bound excludes nearly the whole sampling box "
            f"for {system!r} and these lengths"
        ) from None
    dt = draw(dt_values, dt_range, n_samples)
    return FlowMapData(x0, _flows(system, x0, mu, dt, h_max, pool, chunk_size), mu[:, None], dt)


def _flows(system: Pendulum, x0, mu, dt, h_max, pool, chunk_size) -> np.ndarray:
    """Reference flows of the samples, in this process or over a worker pool (the same arrays)."""
    if pool is None and chunk_size is None:
        return system.flow(x0, mu, dt, h_max)
    with logger.block(
        f"pendulum reference flows: {len(x0)} samples on {len(pool) if pool is not None else 1} worker(s)"
    ):
        return pool_flow(system, x0, mu, dt, h_max, pool=pool, chunk_size=chunk_size)
