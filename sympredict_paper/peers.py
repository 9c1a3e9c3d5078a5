"""Data-driven peers of the kernel predictor, for the comparisons (speed against accuracy, data-driven page).

:class:`VKOGAFlowMap` gives pyMOR's VKOGA (``pymor.algorithms.ml.vkoga.VKOGARegressor``,
Gaussian kernel, f-/fp-greedy with pyMOR's ``weak_greedy``) the same flow-map
samples as the kernel predictor: the inputs ``(x0, mu, dT)`` scaled to the
unit box of the training data, the target the increment ``x1 - x0`` (as the
direct model, :class:`~sympredict.estimators.predictor.DirectKernelPredictor`), and it
steps explicitly ``x_{k+1} = x_k + r(x_k, mu, dT)``: a values-only, not
symplectic flow map that needs only data.

pyMOR's ``DataDrivenReductor`` learns ``mu -> solution trajectory`` for one
fixed initial state: it does not apply to flow maps over varying initial
states, so VKOGA enters here through its regressor, which that reductor uses
by default.
"""

from __future__ import annotations

import time

import numpy as np
from pymor.algorithms.ml.vkoga import GaussianKernel, VKOGARegressor
from pymor.core.logger import getLogger

from sympredict._checks import as_positive_int

__all__ = ["VKOGAFlowMap", "flow_map_inputs", "select_vkoga_length_scale"]

logger = getLogger("sympredict_paper.peers")


def flow_map_inputs(x, mu, dt, with_mu: bool, with_dt: bool) -> np.ndarray:
    """Regression inputs ``[x, mu, dT]`` (the columns a model uses), shape (B, 2n + d_mu + 1)."""
    cols = [np.asarray(x, dtype=float)]
    b = len(cols[0])
    if with_mu:
        m = np.asarray(mu, dtype=float)
        cols.append(np.full((b, 1), float(m)) if m.ndim == 0 else m.reshape(b, -1))
    if with_dt:
        cols.append(np.asarray(dt, dtype=float).reshape(b, 1) if np.ndim(dt) else np.full((b, 1), float(dt)))
    return np.hstack(cols)


class VKOGAFlowMap:
    """pyMOR's VKOGA regressor as an explicit flow map ``x1 = x0 + r(x0, mu, dT)`` (values only, not symplectic).

    Parameters
    ----------
    max_centers : int
        VKOGA's greedy budget.
    length_scale : float
        Gaussian kernel length scale in the scaled inputs (unit box).
    criterion : str
        pyMOR's selection rule (``'f'``, ``'fp'`` or ``'p'``).
    tol, reg
        pyMOR's greedy tolerance and kernel regularisation.

    Attributes
    ----------
    regressor_ : VKOGARegressor
    n_centers_ : int
    fit_time_s_ : float
    """

    def __init__(
        self,
        max_centers: int = 500,
        length_scale: float = 0.3,
        criterion: str = "f",
        tol: float = 1e-10,
        reg: float = 1e-12,
    ):
        self.max_centers = max_centers
        self.length_scale = length_scale
        self.criterion = criterion
        self.tol = tol
        self.reg = reg

    def _inputs(self, x, mu, dt) -> np.ndarray:
        z = flow_map_inputs(x, mu, dt, self.with_mu_, self.with_dt_)
        return (z - self.lo_) / self.span_

    def fit(self, x0, x1, mu=None, dt=None) -> "VKOGAFlowMap":
        """Fit on samples ``x1 = Phi(x0; mu, dT)``: ``x0, x1`` (M, 2n), ``mu`` (M,)/(M, d_mu) or None, ``dt`` (M,) or None.

        A column that is constant over the data (a fixed step) is dropped.
        Cost: pyMOR's greedy, ``O(M m^2 d)`` kernel evaluations for ``m`` centres.
        """
        x0 = np.asarray(x0, dtype=float)
        x1 = np.asarray(x1, dtype=float)
        self.with_mu_ = mu is not None and np.ptp(np.asarray(mu, dtype=float)) > 0
        self.with_dt_ = dt is not None and np.ptp(np.asarray(dt, dtype=float)) > 0
        self.dt_fixed_ = None if dt is None or self.with_dt_ else float(np.asarray(dt).ravel()[0])
        z = flow_map_inputs(x0, mu, dt, self.with_mu_, self.with_dt_)
        self.lo_ = z.min(axis=0)
        self.span_ = np.where(np.ptp(z, axis=0) > 0, np.ptp(z, axis=0), 1.0)
        t0 = time.perf_counter()
        self.regressor_ = VKOGARegressor(
            kernel=GaussianKernel(self.length_scale),
            criterion=self.criterion,
            max_centers=as_positive_int(self.max_centers, "max_centers"),
            tol=self.tol,
            reg=self.reg,
        )
        self.regressor_.fit(self._inputs(x0, mu, dt), x1 - x0)
        self.fit_time_s_ = time.perf_counter() - t0
        self.n_centers_ = len(self.regressor_._surrogate._centers)
        logger.info(f"VKOGA: {self.n_centers_} centres on {len(x0)} samples in {self.fit_time_s_:.1f} s")
        return self

    def step(self, x, mu=None, dt=None) -> np.ndarray:
        """One explicit step for states (B, 2n); ``O(B m d)``."""
        x = np.asarray(x, dtype=float)
        return x + self.regressor_.predict(self._inputs(x, mu, dt))

    def rollout(self, x0, n_steps: int, mu=None, dt=None) -> np.ndarray:
        """Trajectories (B, K+1, 2n); ``O(K B m d)``, a NumPy matrix product per step."""
        n_steps = as_positive_int(n_steps, "n_steps", minimum=0)
        x = np.asarray(x0, dtype=float)
        traj = np.empty((len(x), n_steps + 1, x.shape[1]))
        traj[:, 0] = x
        for k in range(n_steps):  # the steps are sequential; each is batched over instances
            traj[:, k + 1] = self.step(traj[:, k], mu, dt)
        return traj


def select_vkoga_length_scale(data, validation, length_scales=(0.1, 0.3, 1.0, 3.0), m_star: int = 50) -> dict:
    """VKOGA's Gaussian length scale chosen like the kernel predictor's shapes: the smallest validation error at ``m_star`` centres.

    Parameters
    ----------
    data, validation : FlowMapData
        Training and validation samples.
    length_scales : sequence of float
        Candidates (unit-box inputs).
    m_star : int
        Centres at which the candidates are compared.

    Returns
    -------
    dict
        ``length_scale`` (the winner), ``table`` (``length_scale``, ``max_err``: max over the validation
        samples and components of the one-step error) and ``time_s``.
    """
    t0 = time.perf_counter()
    table = []
    for ell in length_scales:
        peer = VKOGAFlowMap(max_centers=m_star, length_scale=ell).fit(data.x0, data.x1, mu=data.mu, dt=data.dt)
        err = float(np.abs(peer.step(validation.x0, validation.mu, validation.dt) - validation.x1).max())
        table.append({"length_scale": float(ell), "max_err": err if np.isfinite(err) else float("inf")})
    best = min(table, key=lambda row: row["max_err"])
    logger.info(
        f"VKOGA length scale {best['length_scale']:g} (validation max error {best['max_err']:.2e} at {m_star} centres)"
    )
    return {"length_scale": best["length_scale"], "table": table, "time_s": time.perf_counter() - t0}
