"""The Hénon–Heiles system with a parametric cubic coupling.

``H(q, p; lambda) = 1/2 (p1^2 + p2^2 + q1^2 + q2^2) + lambda (q1^2 q2 - q2^3 / 3)``,
state ``x = (q1, q2, p1, p2)``, parameter ``mu = lambda``.  Separable
(``T = |p|^2 / 2``, ``V(q; lambda)``), so every scheme of
:mod:`sympredict.symplectic.integrators_compiled` applies.

In polar coordinates ``V = r^2 / 2 + lambda (r^3 / 3) sin(3 theta)``; for
``lambda != 0`` the three saddles at ``r = 1 / |lambda|`` have the escape
energy ``1 / (6 lambda^2)`` (``1/6`` for ``lambda = 1``).  Below it the
component of ``{V <= E}`` that contains the origin (the well) is the star-shaped
set ``{|q| <= r_E, V <= E}`` with ``r_E^2 / 2 - |lambda| r_E^3 / 3 = E``: along
every ray ``V >= r^2/2 - |lambda| r^3/3``, which increases up to ``1/|lambda|``,
and ``V`` itself increases along rays there.  Orbits started in the well with
``H <= E`` stay in it.

The reference flow is Kahan–Li's 6th-order composition (compiled) with step
halving: the result with ``2r`` sub-steps is accepted when it differs from the
one with ``r`` sub-steps by at most ``tol`` (the ``2r`` result is then about
``2^6`` times more accurate than that difference).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import brentq

from sympredict._checks import as_positive_int, as_real, as_states, as_steps
from sympredict.exceptions import SympredictError
from sympredict.systems.flowmaps import _ScalarParameterSystem
from sympredict.symplectic.integrators import micro_steps
from sympredict.symplectic.integrators_compiled import PointwiseHamiltonian, jit_pointwise, rollout

__all__ = ["HenonHeiles", "LAMBDA_RANGE", "escape_energy", "energy_bounded_states"]

#: The parameter range of the issue's experiments.
LAMBDA_RANGE = (0.8, 1.0)


# Per-instance gradients for the compiled integrators (sympredict.symplectic.integrators_compiled): mu = (lambda,).
@jit_pointwise
def _grad_V(q, mu, fargs, iargs, out):
    """``dV/dq = (q1 + 2 lambda q1 q2, q2 + lambda (q1^2 - q2^2))``."""
    lam = mu[0]
    out[0] = q[0] + 2.0 * lam * q[0] * q[1]
    out[1] = q[1] + lam * (q[0] * q[0] - q[1] * q[1])


@jit_pointwise
def _grad_T(p, mu, fargs, iargs, out):
    """``dT/dp = p``."""
    out[0] = p[0]
    out[1] = p[1]


@jit_pointwise
def _grad_H(x, mu, fargs, iargs, out):
    """``(dV/dq, p)``."""
    lam = mu[0]
    out[0] = x[0] + 2.0 * lam * x[0] * x[1]
    out[1] = x[1] + lam * (x[0] * x[0] - x[1] * x[1])
    out[2] = x[2]
    out[3] = x[3]


@jit_pointwise
def _hess_H(x, mu, fargs, iargs, out):
    """``diag([[1 + 2 lambda q2, 2 lambda q1], [2 lambda q1, 1 - 2 lambda q2]], I)``."""
    lam = mu[0]
    out[:, :] = 0.0
    out[0, 0] = 1.0 + 2.0 * lam * x[1]
    out[0, 1] = 2.0 * lam * x[0]
    out[1, 0] = 2.0 * lam * x[0]
    out[1, 1] = 1.0 - 2.0 * lam * x[1]
    out[2, 2] = 1.0
    out[3, 3] = 1.0


def escape_energy(lam: float) -> float:
    """Energy ``1 / (6 lambda^2)`` of the saddles (``inf`` for ``lambda = 0``: a harmonic oscillator)."""
    lam = as_real(lam, "lam")
    return np.inf if lam == 0 else 1.0 / (6.0 * lam * lam)


class HenonHeiles(_ScalarParameterSystem):
    """Hénon–Heiles ``H = |p|^2/2 + |q|^2/2 + lambda (q1^2 q2 - q2^3/3)`` with ``x = (q1, q2, p1, p2)``, ``mu = lambda``."""

    dim = 4
    parameter_name = "mu (Hénon–Heiles lambda)"

    def hamiltonian(self, x, mu) -> np.ndarray:
        """Energies (B,) of states (B, 4) for ``lambda`` (B,) or (B, 1)."""
        x, _ = as_states(x, "x", dim=4)
        lam = self._parameter(mu, len(x))
        q1, q2, p1, p2 = x.T
        return 0.5 * (p1 * p1 + p2 * p2 + q1 * q1 + q2 * q2) + lam * (q1 * q1 * q2 - q2 * q2 * q2 / 3.0)

    def gradient(self, x, mu) -> np.ndarray:
        """``grad H = (q1 + 2 lambda q1 q2, q2 + lambda (q1^2 - q2^2), p1, p2)``, shape (B, 4)."""
        x = np.asarray(x, dtype=float)
        lam = self._parameter(mu, len(x))
        q1, q2 = x[:, 0], x[:, 1]
        return np.column_stack([q1 + 2.0 * lam * q1 * q2, q2 + lam * (q1 * q1 - q2 * q2), x[:, 2], x[:, 3]])

    def hessian(self, x, mu) -> np.ndarray:
        """``grad^2 H``, shape (B, 4, 4)."""
        x = np.asarray(x, dtype=float)
        lam = self._parameter(mu, len(x))
        hess = np.zeros((len(x), 4, 4))
        hess[:, 0, 0] = 1.0 + 2.0 * lam * x[:, 1]
        hess[:, 0, 1] = hess[:, 1, 0] = 2.0 * lam * x[:, 0]
        hess[:, 1, 1] = 1.0 - 2.0 * lam * x[:, 1]
        hess[:, 2, 2] = hess[:, 3, 3] = 1.0
        return hess

    def pointwise(self) -> PointwiseHamiltonian:
        """Per-instance gradients and Hessian for :func:`sympredict.symplectic.integrators_compiled.rollout` (compiled with numba)."""
        return PointwiseHamiltonian(
            4, 1, grad_T=_grad_T, grad_V=_grad_V, grad_H=_grad_H, hess_H=_hess_H, name=repr(self)
        )

    def trajectory(
        self, x0, mu, dt, n_steps: int, h_max: float = 0.02, tol: float = 1e-11, max_halvings: int = 6
    ) -> np.ndarray:
        """Reference trajectories on the macro grid ``t_k = k dt``: Kahan–Li-6 with step halving.

        Starting from ``r = max ceil(dt / h_max)`` sub-steps per macro step,
        the rollouts with ``r`` and ``2r`` sub-steps are compared; the ``2r``
        one is returned once ``max |x_r - x_2r| <= tol (1 + max |x|)`` over the
        whole trajectory, else ``r`` is doubled (at most ``max_halvings`` times).

        Parameters
        ----------
        x0 : array_like of shape (B, 4) or (4,)
        mu : float or array_like of shape (B,)
            ``lambda`` per instance.
        dt : float or array_like of shape (B,)
            Macro steps.
        n_steps : int
        h_max : float
            Largest initial sub-step.
        tol : float
            Accepted difference between the two refinements.
        max_halvings : int

        Returns
        -------
        ndarray of shape (B, K+1, 4)
            The finer rollout of the accepted pair (``2r`` sub-steps per macro step).

        Raises
        ------
        SympredictError
            If the check does not pass after ``max_halvings`` halvings (e.g. an
            orbit that has escaped and blows up).

        Notes
        -----
        ``O(B K r)`` gradient evaluations, ``27 B K r`` for the accepted pair.
        """
        x0, single = as_states(x0, "x0", dim=4)
        b = len(x0)
        lam = self._parameter(mu, b)
        dt = as_steps(dt, b)
        n_steps = as_positive_int(n_steps, "n_steps", minimum=0)
        h_max, tol = as_real(h_max, "h_max", positive=True), as_real(tol, "tol", positive=True)
        max_halvings = as_positive_int(max_halvings, "max_halvings", minimum=0)
        r = int(micro_steps(dt, h_max).max())
        coarse = rollout(self, x0, lam, dt, n_steps, scheme="kahan_li6", substeps=r)
        for _ in range(max_halvings + 1):
            fine = rollout(self, x0, lam, dt, n_steps, scheme="kahan_li6", substeps=2 * r)
            diff = np.abs(fine - coarse).max()
            if diff <= tol * (1.0 + np.abs(fine).max()):
                return fine[0] if single else fine
            coarse, r = fine, 2 * r
        raise SympredictError(
            f"Hénon–Heiles reference: step halving did not reach tol = {tol:g} with {r} sub-steps per macro step "
            f"(last difference {diff:.2e}); an orbit may have escaped the well"
        )

    def flow(self, x0, mu, t, h_max: float = 0.02, tol: float = 1e-11) -> np.ndarray:
        """Reference flow ``Phi_lambda^t(x0)`` (:meth:`trajectory` with one macro step ``t``), shape (B, 4)."""
        return self._one_step(x0, mu, t, h_max=h_max, tol=tol)


def _well_radius(lam: float, energy: float) -> float:
    """``r_E`` in ``[0, 1/|lambda|]`` with ``r^2/2 - |lambda| r^3/3 = E`` (``sqrt(2E)`` for ``lambda = 0``)."""
    a = abs(lam)
    if a == 0:
        return float(np.sqrt(2.0 * energy))
    r_max = 1.0 / a
    if energy >= escape_energy(lam):
        return r_max
    return brentq(lambda r: 0.5 * r * r - a * r**3 / 3.0 - energy, 0.0, r_max, xtol=1e-15)


def energy_bounded_states(
    system: HenonHeiles, lam: float, n_samples: int, energy_max=None, seed: int = 0
) -> np.ndarray:
    """States uniform (Lebesgue in phase space) in the well with ``H(x; lambda) <= energy_max``.

    Rejection sampling, vectorised: ``q`` uniform in ``[-r_E, r_E]^2`` (``r_E``
    of the module docstring), ``p`` uniform in ``[-sqrt(2E), sqrt(2E)]^2``,
    kept when ``|q| <= r_E`` and ``H <= E``; about 30 % are kept for small ``E``.

    Parameters
    ----------
    system
        The system.
    lam : float
        ``lambda``.
    n_samples : int
    energy_max : float, optional
        ``E``, at most the escape energy ``1/(6 lambda^2)`` (the default; required for ``lambda = 0``).
    seed : int

    Returns
    -------
    ndarray of shape (n_samples, 4)
    """
    n_samples = as_positive_int(n_samples, "n_samples")
    lam = float(lam)
    e_esc = escape_energy(lam)
    if energy_max is None:
        if not np.isfinite(e_esc):
            raise ValueError("energy_max is required for lam = 0 (no escape energy)")
        energy_max = e_esc
    energy_max = float(energy_max)
    if not (np.isfinite(energy_max) and 0 < energy_max <= e_esc):
        raise ValueError(f"energy_max must lie in (0, {e_esc:.6g}] (the escape energy 1/(6 lam^2)), got {energy_max!r}")
    r_q = _well_radius(lam, energy_max)
    r_p = np.sqrt(2.0 * energy_max)
    rng = np.random.default_rng(seed)
    kept = []
    n_kept = 0
    while n_kept < n_samples:
        m = 4 * (n_samples - n_kept) + 16
        cand = np.hstack([rng.uniform(-r_q, r_q, size=(m, 2)), rng.uniform(-r_p, r_p, size=(m, 2))])
        ok = (np.einsum("ij,ij->i", cand[:, :2], cand[:, :2]) <= r_q * r_q) & (
            system.hamiltonian(cand, np.full(m, lam)) <= energy_max
        )
        kept.append(cand[ok])
        n_kept += int(ok.sum())
    return np.concatenate(kept)[:n_samples]
