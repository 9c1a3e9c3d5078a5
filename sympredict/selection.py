"""Kernel family and shape parameters chosen on validation data (paper section 4).

Every candidate tuple ``(k_xi, k_mu, k_dT)`` is trained by f-greedy to ``m_star``
centres; the tuple with the smallest validation residual ``E_val(m_star)``
wins.  Shape parameters are searched on logarithmic grids (:func:`log_grid`)
because useful values span decades (reduced wave coordinates are of size ~20,
so state shapes ~5e-3 fit there, pendulum states are of size ~5).
"""

from __future__ import annotations

import contextlib
import itertools
import logging
import time
from dataclasses import dataclass, field
from typing import Optional, Sequence

import numpy as np
from pymor.core.logger import getLogger

from sympredict.data import FlowMapData
from sympredict.kernels import KERNEL_FAMILIES, RadialKernel
from sympredict.predictor import SymplecticKernelPredictor

__all__ = ["log_grid", "kernel_grid", "SelectionResult", "select_kernels"]

logger = getLogger("sympredict.selection")


@contextlib.contextmanager
def _quiet(*names):
    """Raise the given loggers to WARNING for the duration (candidate fits are logged as one line each)."""
    loggers = [logging.getLogger(n) for n in names]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(max(lg.getEffectiveLevel(), logging.WARNING))
    try:
        yield
    finally:
        for lg, level in zip(loggers, levels):
            lg.setLevel(level)


def log_grid(lo: float, hi: float, per_decade: int = 2) -> np.ndarray:
    """Logarithmically spaced values from ``lo`` to ``hi`` with ``per_decade`` points per decade."""
    if not (0 < lo <= hi):
        raise ValueError(f"log_grid needs 0 < lo <= hi, got {lo!r}, {hi!r}")
    n = max(1, int(round(np.log10(hi / lo) * per_decade)) + 1)
    return np.geomspace(lo, hi, n)


def kernel_grid(families: Sequence[str], eps_values) -> list[Optional[RadialKernel]]:
    """All kernels ``family(eps)``; ``families=()`` or ``eps_values=None`` gives ``[None]`` (factor dropped)."""
    if eps_values is None or not families:
        return [None]
    unknown = [f for f in families if f not in KERNEL_FAMILIES]
    if unknown:
        raise ValueError(f"unknown kernel families {unknown}; choose from {sorted(KERNEL_FAMILIES)}")
    return [KERNEL_FAMILIES[f](float(e)) for f in families for e in eps_values]


@dataclass
class SelectionResult:
    """Outcome of :func:`select_kernels`.

    Attributes
    ----------
    state, mu, dt
        The chosen kernels (``None`` where the factor is dropped).
    score : float
        Its ``E_val(m_star)``.
    table : list of dict
        Every candidate with its ``E_val(m_star)``, ``E_train(m_star)``, centres and fit time.
    """

    state: RadialKernel
    mu: Optional[RadialKernel]
    dt: Optional[RadialKernel]
    score: float
    table: list = field(default_factory=list)


def select_kernels(
    data: FlowMapData,
    validation: FlowMapData,
    state_kernels: Sequence[RadialKernel],
    mu_kernels: Sequence[Optional[RadialKernel]] = (None,),
    dt_kernels: Sequence[Optional[RadialKernel]] = (None,),
    m_star: int = 300,
) -> SelectionResult:
    """Grid search over kernel tuples by validation residual at ``m_star`` centres.

    Parameters
    ----------
    data, validation
        Training and validation flow-map data.
    state_kernels, mu_kernels, dt_kernels
        Candidates per factor (``None`` drops a factor).
    m_star
        Number of greedy centres at which candidates are compared.

    Returns
    -------
    SelectionResult

    Notes
    -----
    Cost: one greedy to ``m_star`` per candidate, ``O(m_star^2 (N + N_val))`` each.
    A candidate whose greedy stops early (power breakdown) is scored at its
    last step; non-finite scores never win.
    """
    mu = None if data.mu.shape[1] == 0 else data.mu
    vmu = None if validation.mu.shape[1] == 0 else validation.mu
    dt_fixed = np.ptp(data.dt) == 0
    table = []
    best = None
    for state, mu_k, dt_k in itertools.product(state_kernels, mu_kernels, dt_kernels):
        if dt_k is None and not dt_fixed:
            raise ValueError("dt_kernels must not contain None when the data have several macro steps")
        model = SymplecticKernelPredictor(state, mu_k, dt_k, max_centers=m_star, tol=0.0)
        t0 = time.perf_counter()
        with _quiet("sympredict.greedy", "sympredict.predictor"):
            model.fit(data.x0, data.x1, mu=mu if mu_k is not None else None, dt=data.dt,
                      validation=(validation.x0, validation.x1, vmu if mu_k is not None else None, validation.dt))
        score = float(model.history_.val_max_residual[-1])
        row = {
            "state": repr(state),
            "mu": repr(mu_k),
            "dt": repr(dt_k),
            "E_val": score,
            "E_train": float(model.history_.train_max_residual[-1]),
            "n_centers": model.n_centers_,
            "fit_s": time.perf_counter() - t0,
        }
        table.append(row)
        logger.info(f"{row['state']}, {row['mu']}, {row['dt']}: E_val({model.n_centers_}) = {score:.3e}")
        if np.isfinite(score) and (best is None or score < best.score):
            best = SelectionResult(state, mu_k, dt_k, score)
    if best is None:
        raise ValueError("no candidate produced a finite validation residual")
    best.table = table
    for name, chosen, options in (("state", best.state, state_kernels), ("mu", best.mu, mu_kernels), ("dt", best.dt, dt_kernels)):
        if chosen is None:
            continue
        same_family = sorted(k.eps for k in options if k is not None and type(k) is type(chosen))
        if len(same_family) > 1 and chosen.eps in (same_family[0], same_family[-1]):
            logger.warning(f"the chosen {name} kernel {chosen!r} lies on the edge of its shape grid: widen the grid")
    return best
