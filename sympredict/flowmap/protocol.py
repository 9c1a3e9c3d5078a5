"""The flow-map protocol: what every predictor, wrapper and reduced model's flow map offers.

A *flow map* advances batches of states by macro steps for given parameters::

    x1 = fm.step(x0, mu=mu, dt=dt)                 # (B, 2n) -> (B, 2n)
    traj = fm.rollout(x0, n_steps, mu=mu, dt=dt)   # (B, 2n) -> (B, n_steps + 1, 2n)

with ``fm.dim_`` the state dimension ``2n`` and ``fm.n_mu_`` the parameter
dimension (0 for a fixed parameter).  A *symplectic* flow map also gives the
step's Jacobian, ``fm.step_jacobian(x, mu=mu, dt=dt)`` of shape (B, 2n, 2n),
with ``DPhi^T J DPhi = J`` (what :func:`sympredict.testing.assert_symplectic_step`
checks).

Implemented by :class:`~sympredict.SymplecticKernelPredictor` (symplectic),
:class:`~sympredict.DirectKernelPredictor` (a flow map, not symplectic),
:class:`~sympredict.flowmap.splitting.SplitKernelPredictor` and
:class:`~sympredict.flowmap.scaling.NormalizedFlowMap` (symplectic), and the
flow map of a reduced model (``rom.flow_map``, :mod:`sympredict.mor`).
Wrappers compose through the public hook ``rollout(..., around=(pre, post))``
of :class:`~sympredict.SymplecticKernelPredictor`, which keeps a wrapped
rollout on the compiled solver.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

__all__ = ["FlowMap", "SymplecticFlowMap"]


@runtime_checkable
class FlowMap(Protocol):
    """States in, states one (or ``n_steps``) macro steps later out."""

    dim_: int
    n_mu_: int

    def step(self, x, mu=None, dt=None) -> np.ndarray:
        """One macro step of states (B, 2n) or (2n,)."""

    def rollout(self, x0, n_steps: int, mu=None, dt=None) -> np.ndarray:
        """``n_steps`` macro steps: (B, n_steps + 1, 2n) (or (n_steps + 1, 2n) for one state)."""


@runtime_checkable
class SymplecticFlowMap(FlowMap, Protocol):
    """A flow map whose step is symplectic, with its Jacobian."""

    def step_jacobian(self, x, mu=None, dt=None) -> np.ndarray:
        """``D Phi`` of the step, (B, 2n, 2n) (or (2n, 2n)); ``DPhi^T J DPhi = J``."""
