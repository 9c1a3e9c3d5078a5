"""The fast f-greedy's store: the Newton basis on an active subset of the points, refreshed against the full residual.

The exact f-greedy streams the ``m x N`` Newton basis once per centre
(``O(m^2 N)`` memory traffic in total).  Here the basis lives on an *active
set* of ``N_S << N`` candidates (all ``2n`` components of ``initial_points``
random points, seeded); the greedy selects on it as usual.  Every
``refresh_every`` centres, and whenever the active set's residual reaches
``margin * tol``, the interpolant is evaluated directly at the candidates
(:func:`~sympredict.interpolation.functionals.functional_residuals`, ``O(M m 2n)`` flops, no
basis), and up to ``max_new_points`` points whose residual exceeds the active
set's maximum join it: their Newton-basis values for the existing centres are
``L^{-1} K(selected, new)`` (one triangular solve), their residuals and power
function follow.  The run stops when the *full* residual is at or below
``tol`` or at ``max_centers``.

The selection differs from the exact f-greedy's (it sees the active set only
between refreshes); the residual it certifies is the full one, by direct
evaluation of the returned model.  Memory ``8 m_max (2n N_S + N_val)`` bytes
for the basis; time ``O(m^2 N_S / 2)`` memory traffic plus ``O(M m 2n)`` flops
per refresh.
"""

from __future__ import annotations

from typing import Optional

import numpy as np
from pymor.core.logger import getLogger
from scipy.linalg import solve_triangular

from sympredict.interpolation.functionals import HBFunctionals, functional_residuals
from sympredict.interpolation.greedy.loop import BaseStore, Expansion, check_memory

__all__ = ["ActiveSetStore"]

logger = getLogger("sympredict.interpolation.greedy")


class ActiveSetStore(BaseStore):
    """Newton basis on an active subset of the points (f-greedy, one output, HB functionals).

    Parameters
    ----------
    functionals
        :class:`~sympredict.interpolation.functionals.HBFunctionals` of ``M`` points (``N = M 2n``).
    targets : ndarray of shape (N,)
    tol
        The full-residual target (the run's ``tol``): the active set is trained down to ``margin * tol``.
    power_tol, validation, memory_limit
        As for :class:`~sympredict.interpolation.greedy.dense.DenseStore`.
    initial_points
        Points in the first active set.
    refresh_every
        Centres between two refreshes.
    max_new_points
        Points added per refresh at most (the worst ones).
    margin
        Points above ``max(margin * tol, active maximum)`` join the active set,
        so that the last refreshes do not each add a handful of points just above ``tol``.
    refresh_fraction
        Intermediate refreshes evaluate a fresh random fraction of the points
        outside the active set (violators cluster, a sample finds their
        regions); whenever that sample is at or below ``tol``, and at the end,
        every candidate is evaluated, so the stopping test is always over all
        ``N`` functionals.  1 evaluates everything every time.
    seed
        Seed of the initial draw and of the refresh samples.
    """

    label = "active-set greedy"

    def __init__(self, functionals, targets, *, tol: float, power_tol: float = 1e-12, validation: Optional[tuple] = None,
                 memory_limit: Optional[float] = None, initial_points: int = 8192, refresh_every: int = 200,
                 max_new_points: int = 4096, margin: float = 0.7, refresh_fraction: float = 0.25, seed: int = 0):
        if not isinstance(functionals, HBFunctionals):
            raise ValueError("the active-set greedy needs HBFunctionals (state-derivative functionals)")
        n = functionals.n_functionals
        if np.size(targets) != n:
            raise ValueError(f"the active-set greedy interpolates one output: targets must have shape ({n},), "
                             f"got {np.shape(targets)}")
        if not 0 < margin <= 1:
            raise ValueError(f"margin must lie in (0, 1], got {margin!r}")
        if not 0 < refresh_fraction <= 1:
            raise ValueError(f"refresh_fraction must lie in (0, 1], got {refresh_fraction!r}")
        for name, value in (("initial_points", initial_points), ("refresh_every", refresh_every),
                            ("max_new_points", max_new_points)):
            if int(value) != value or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        super().__init__(functionals, targets, criterion="f", power_tol=power_tol, validation=validation)
        self.squeeze = True
        self.targets = self.y[:, 0]  # one output: the flat target vector
        self.tol = tol
        self.inner_tol = margin * tol
        self.memory_limit = memory_limit
        self.initial_points = int(initial_points)
        self.refresh_every = int(refresh_every)
        self.max_new_points = int(max_new_points)
        self.refresh_fraction = refresh_fraction
        self.seed = seed

    # ------------------------------------------------------------------ protocol
    def open(self, expansion: Expansion):
        f = self.functionals
        self.expansion = expansion
        self.max_centers = expansion.max_centers
        dim = self.dim = f.dim
        self.n_points = len(f.points)
        self.rng = np.random.default_rng(self.seed)
        pts = np.sort(self.rng.choice(self.n_points, size=min(self.n_points, self.initial_points), replace=False))
        cap_points = min(self.n_points, len(pts) + 4 * self.max_new_points)
        check_memory(self.max_centers, cap_points * dim, self.n_val, self.memory_limit)
        # the Gramian diagonal per functional (constant for a radial kernel, not for a group-averaged one)
        self.diag = f.diagonal()
        self.breakdown = self.power_tol * float(self.diag.max())
        self.in_active = np.zeros(self.n_points, dtype=bool)
        self.in_active[pts] = True
        self.pts = pts
        self.cand = (pts[:, None] * dim + np.arange(dim)).reshape(-1)
        self.sub = HBFunctionals(f.kernel, f.points[pts], f.mu[pts], f.dt[pts])
        self.basis = np.empty((self.max_centers, cap_points * dim))
        self.vbasis = np.empty((self.max_centers, self.n_val)) if self.n_val else None
        self.res = self.targets[self.cand].copy()
        self.p2 = self.diag[self.cand].astype(float)
        self.res_abs = np.abs(self.res)
        self.since_refresh = 0
        self.full_at = -1  # number of centres at the last evaluation of the full residual
        self.full_max = self.targets_max
        return self.full_max, (np.abs(self.vres).max() if self.n_val else None)

    def select(self, m: int):
        while True:
            if self.since_refresh < self.refresh_every:
                score = np.where(self.p2 > self.breakdown, self.res_abs, -np.inf)
                j = int(np.argmax(score))
                if np.isfinite(score[j]) and self.res_abs[j] > self.inner_tol:
                    return j, score[j], np.inf
                exhausted = True
            else:
                exhausted = False
            self.since_refresh = 0
            pool, pool_res, full = self._refresh(m)
            if full and self.full_max <= self.tol:
                return -1, -np.inf, self.full_max
            n_active = len(self.cand)
            active_max = float(np.where(self.p2 > self.breakdown, self.res_abs, 0.0).max()) if n_active else 0.0
            hit = pool_res > max(self.inner_tol, active_max)
            new, new_res = pool[hit], pool_res[hit]
            if new.size > self.max_new_points:
                new = new[np.argpartition(new_res, -self.max_new_points)[-self.max_new_points:]]
            if new.size == 0:
                if exhausted:
                    return -1, -np.inf, np.inf
                continue
            self._add_points(m, np.sort(new))

    def winner(self, j: int, m: int):
        return int(self.cand[j]), self.sub.representer(j), self.basis[:m, j].copy(), self.p2[j], self.res[j:j + 1]

    def add(self, m, rep, coeffs_j, pj, b, j):
        n_s = len(self.cand)
        row = self.sub.column(rep, out=self.basis[m, :n_s])
        if m:
            row -= self.basis[:m, :n_s].T @ coeffs_j
        row *= 1.0 / pj
        b = b[0]
        self.res -= b * row
        self.res[j] = 0.0
        self.p2 -= row * row
        self.p2[j] = 0.0
        np.abs(self.res, out=self.res_abs)
        val_max = None
        if self.n_val:
            vrow = self.val_functionals.column(rep, out=self.vbasis[m])
            if m:
                vrow -= self.vbasis[:m].T @ coeffs_j
            vrow *= 1.0 / pj
            self.vres[:, 0] -= b * vrow
            val_max = np.abs(self.vres).max()
        self.since_refresh += 1
        return self.res_abs.max(), val_max

    def finish(self, m: int):
        """The full maximum residual of the returned model (evaluated here unless it already was at ``m``)."""
        if self.full_at != m:
            self._evaluate_full(m)
        return self.full_max

    # ------------------------------------------------------------------ refreshes
    def _evaluate_full(self, m: int) -> np.ndarray:
        e = self.expansion
        r_all = functional_residuals(self.functionals, self.targets, e.selected[:m], e.coef(m)) if m else self.targets.copy()
        self.full_max = float(np.abs(r_all).max())
        self.full_at = m
        logger.info(f"refresh at {m} centres: full max residual {self.full_max:.3e} ({len(self.cand)} active candidates)")
        return r_all

    def _refresh(self, m: int):
        """Residuals by direct evaluation at a sample of the outside points, or at all: ``(pool, pool_res, full)``."""
        dim = self.dim
        full = self.refresh_fraction >= 1 or m == 0
        if not full:
            e = self.expansion
            outside = np.flatnonzero(~self.in_active)
            size = min(outside.size, max(1, int(np.ceil(self.refresh_fraction * outside.size))))
            pool = np.sort(self.rng.choice(outside, size=size, replace=False)) if size else outside
            r_eval = functional_residuals(self.functionals, self.targets, e.selected[:m], e.coef(m), points=pool)
            sample_max = float(np.abs(r_eval).max()) if r_eval.size else 0.0
            logger.info(f"refresh at {m} centres: max residual {sample_max:.3e} on {pool.size} sampled points "
                        f"({len(self.cand)} active candidates)")
            full = sample_max <= self.tol
            pool_res = np.abs(r_eval).reshape(-1, dim).max(axis=1) if r_eval.size else np.zeros(0)
        if full:
            r_all = self._evaluate_full(m)
            pool = np.flatnonzero(~self.in_active)
            pool_res = np.abs(r_all).reshape(self.n_points, dim).max(axis=1)[pool]
        return pool, pool_res, full

    def _add_points(self, m: int, new: np.ndarray) -> None:
        """The new points' Newton-basis values, residuals and power function; they join the active set."""
        f, e, dim = self.functionals, self.expansion, self.dim
        new_sub = HBFunctionals(f.kernel, f.points[new], f.mu[new], f.dt[new])
        n_new = new.size * dim
        n_s = len(self.cand)
        if m:
            kmat = new_sub.gram_rows(f, e.selected[:m], out=np.empty((m, n_new)))
            vals = solve_triangular(e.chol[:m, :m], kmat, lower=True, overwrite_b=True, check_finite=False)
        else:
            vals = np.zeros((0, n_new))
        new_cand = (new[:, None] * dim + np.arange(dim)).reshape(-1)
        if n_s + n_new > self.basis.shape[1]:
            grown = np.empty((self.max_centers, max(n_s + n_new, 2 * self.basis.shape[1])))
            check_memory(self.max_centers, grown.shape[1], self.n_val, self.memory_limit)
            grown[:m, :n_s] = self.basis[:m, :n_s]
            self.basis = grown
        self.basis[:m, n_s : n_s + n_new] = vals
        self.res = np.concatenate([self.res, self.targets[new_cand] - e.beta[:m, 0] @ vals])
        self.p2 = np.concatenate([self.p2, self.diag[new_cand] - np.einsum("ki,ki->i", vals, vals)])
        self.res_abs = np.abs(self.res)
        self.cand = np.concatenate([self.cand, new_cand])
        self.in_active[new] = True
        self.pts = np.concatenate([self.pts, new])
        self.sub = HBFunctionals(f.kernel, f.points[self.pts], f.mu[self.pts], f.dt[self.pts])
