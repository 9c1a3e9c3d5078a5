"""Flow-map data: samples ``x1 = Phi_mu^dT(x0)`` and their mixed-variable form.

The symplectic predictor is trained on the *mixed* variables and targets

* ``xi = (q0, p1)``,
* ``y = J^T (x1 - x0) / dT = (-(p1 - p0) / dT, (q1 - q0) / dT)``,

with ``J = [[0, I], [-I, 0]]``, so that the implicit symplectic-Euler update
``p1 = p0 - dT d_q s(q0, p1)``, ``q1 = q0 + dT d_p s(q0, p1)`` reproduces the
data exactly where ``grad_xi s(xi_j) = y_j``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sympredict._checks import as_parameter, as_states, as_steps
from sympredict._numeric import j_times

__all__ = ["FlowMapData", "TrajectoryData", "mixed_variables"]


def mixed_variables(x0: np.ndarray, x1: np.ndarray, dt: np.ndarray):
    """Mixed variables and gradient targets of flow-map samples.

    Parameters
    ----------
    x0, x1 : ndarray of shape (M, 2n)
    dt : ndarray of shape (M,)

    Returns
    -------
    xi : ndarray of shape (M, 2n)
        ``(q0, p1)``.
    y : ndarray of shape (M, 2n)
        ``J^T (x1 - x0) / dT``.
    """
    n = x0.shape[1] // 2
    xi = np.concatenate([x0[:, :n], x1[:, n:]], axis=1)
    inc = (x1 - x0) / dt[:, None]
    y = -j_times(inc)  # J^T = -J
    return xi, y


@dataclass
class FlowMapData:
    """A set of flow-map samples over parameters and macro steps.

    Attributes
    ----------
    x0, x1 : ndarray of shape (M, 2n)
        Initial and propagated states, ``x1 = Phi_mu^dt(x0)``.
    mu : ndarray of shape (M, d_mu)
        Parameters (``d_mu = 0`` for a parameter-free system).
    dt : ndarray of shape (M,)
        Macro steps.
    """

    x0: np.ndarray
    x1: np.ndarray
    mu: np.ndarray
    dt: np.ndarray

    def __post_init__(self):
        self.x0, _ = as_states(self.x0, "x0", allow_single=False)
        self.x1, _ = as_states(self.x1, "x1", dim=self.x0.shape[1], allow_single=False)
        m = len(self.x0)
        if len(self.x1) != m:
            raise ValueError(f"x0 and x1 must have the same number of samples, got {m} and {len(self.x1)}")
        if self.mu is None or np.size(self.mu) == 0:
            self.mu = np.zeros((m, 0))
        else:
            self.mu = as_parameter(self.mu, m, None)
        self.dt = as_steps(self.dt, m)

    def __len__(self) -> int:
        return len(self.x0)

    def subset(self, index) -> "FlowMapData":
        """The samples selected by ``index`` (an index array, slice or mask)."""
        return FlowMapData(self.x0[index], self.x1[index], self.mu[index], self.dt[index])

    def split(self, validation_fraction: float, seed: int = 0):
        """Random train/validation split.

        Returns
        -------
        (FlowMapData, FlowMapData)
            Training and validation parts.
        """
        if not 0 < validation_fraction < 1:
            raise ValueError(f"validation_fraction must lie in (0, 1), got {validation_fraction!r}")
        perm = np.random.default_rng(seed).permutation(len(self))
        n_val = max(1, int(round(validation_fraction * len(self))))
        return self.subset(np.sort(perm[n_val:])), self.subset(np.sort(perm[:n_val]))

    def concatenate(self, other: "FlowMapData") -> "FlowMapData":
        """The union of two data sets (same state and parameter dimensions)."""
        return FlowMapData(
            np.concatenate([self.x0, other.x0]),
            np.concatenate([self.x1, other.x1]),
            np.concatenate([self.mu, other.mu]),
            np.concatenate([self.dt, other.dt]),
        )


@dataclass
class TrajectoryData:
    """Trajectories on a uniform macro grid ``t_k = k dt``, one parameter vector each.

    Validation data that score whole rollouts (e.g. the reductor's choice of a ridge term):
    a model is rolled out from ``states[:, 0]`` for ``K`` steps and compared with ``states[:, 1:]``.

    Attributes
    ----------
    states : ndarray of shape (P, K+1, 2n)
    mu : ndarray of shape (P, d_mu)
        Parameters (``d_mu = 0`` for a parameter-free system).
    dt : float
        The macro step between consecutive states.
    """

    states: np.ndarray
    mu: np.ndarray
    dt: float

    def __post_init__(self):
        states = np.asarray(self.states, dtype=float)
        if states.ndim != 3 or states.shape[1] < 2 or states.shape[2] == 0 or states.shape[2] % 2:
            raise ValueError(f"states must have shape (P, K+1, 2n) with K >= 1 and an even 2n, got {states.shape}")
        if not np.all(np.isfinite(states)):
            raise ValueError("states contain NaN or Inf")
        self.states = states
        p = len(states)
        self.mu = np.zeros((p, 0)) if self.mu is None or np.size(self.mu) == 0 else as_parameter(self.mu, p, None)
        self.dt = float(as_steps(self.dt, 1)[0])

    def __len__(self) -> int:
        return len(self.states)

    def pairs(self) -> FlowMapData:
        """Consecutive states as flow-map samples ``(x(t_k), x(t_{k+1}))``, ``P K`` rows (trajectory by trajectory)."""
        p, k1, dim = self.states.shape
        return FlowMapData(self.states[:, :-1].reshape(-1, dim), self.states[:, 1:].reshape(-1, dim),
                           np.repeat(self.mu, k1 - 1, axis=0) if self.mu.shape[1] else None,
                           np.full(p * (k1 - 1), self.dt))
