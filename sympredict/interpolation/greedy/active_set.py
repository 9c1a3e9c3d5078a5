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
per refresh.  The active set grows while points join, so its memory is known
only as a bound (every refresh adding ``max_new_points``).

:class:`BoundedActiveSetStore` fixes the size instead: the blocked greedy on a
fixed number of slots, sized to a memory budget, whose points are swapped at
each refresh; its whole peak is :func:`bounded_memory`.
"""

from __future__ import annotations

import time
from typing import Optional

import numpy as np
from pymor.core.logger import getLogger
from scipy.linalg import blas, solve_triangular

from sympredict import _numba
from sympredict.interpolation.functionals import HBFunctionals, functional_residuals
from sympredict.interpolation.greedy.blocked import BlockedStore, gram_rows
from sympredict.interpolation.greedy.dense import abs_residual
from sympredict.interpolation.greedy.loop import BaseStore, Expansion, available_memory, check_memory, format_bytes

__all__ = ["ActiveSetStore", "BoundedActiveSetStore", "bounded_memory", "bounded_capacity", "refresh_chunk"]

logger = getLogger("sympredict.interpolation.greedy")


class ActiveSetStore(BaseStore):
    """Newton basis on an active subset of the points (f-greedy, one output, HB functionals).

    Built by :class:`~sympredict.interpolation.greedy.trainers.ActiveSetGreedy`, which declares the defaults of the
    active set's settings (``initial_points`` to ``seed``); here they are required.

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

    def __init__(
        self,
        functionals,
        targets,
        *,
        tol: float,
        power_tol: float = 1e-12,
        validation: Optional[tuple] = None,
        memory_limit: Optional[float] = None,
        initial_points: int,
        refresh_every: int,
        max_new_points: int,
        margin: float,
        refresh_fraction: float,
        seed: int,
    ):
        if not isinstance(functionals, HBFunctionals):
            raise ValueError("the active-set greedy needs HBFunctionals (state-derivative functionals)")
        n = functionals.n_functionals
        if np.size(targets) != n:
            raise ValueError(
                f"the active-set greedy interpolates one output: targets must have shape ({n},), "
                f"got {np.shape(targets)}"
            )
        if not 0 < margin <= 1:
            raise ValueError(f"margin must lie in (0, 1], got {margin!r}")
        if not 0 < refresh_fraction <= 1:
            raise ValueError(f"refresh_fraction must lie in (0, 1], got {refresh_fraction!r}")
        for name, value in (
            ("initial_points", initial_points),
            ("refresh_every", refresh_every),
            ("max_new_points", max_new_points),
        ):
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
                new = new[np.argpartition(new_res, -self.max_new_points)[-self.max_new_points :]]
            if new.size == 0:
                if exhausted:
                    return -1, -np.inf, np.inf
                continue
            self._add_points(m, np.sort(new))

    def winner(self, j: int, m: int):
        return int(self.cand[j]), self.sub.representer(j), self.basis[:m, j].copy(), self.p2[j], self.res[j : j + 1]

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
        r_all = (
            functional_residuals(self.functionals, self.targets, e.selected[:m], e.coef(m))
            if m
            else self.targets.copy()
        )
        self.full_max = float(np.abs(r_all).max())
        self.full_at = m
        logger.info(
            f"refresh at {m} centres: full max residual {self.full_max:.3e} ({len(self.cand)} active candidates)"
        )
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
            logger.info(
                f"refresh at {m} centres: max residual {sample_max:.3e} on {pool.size} sampled points "
                f"({len(self.cand)} active candidates)"
            )
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


# ---------------------------------------------------------------------------------------------------------------------
# The bounded active set: the blocked greedy on a fixed number of slots, refreshed against every candidate in chunks


#: Bytes of the Gramian-rows buffer a refresh evaluates the candidates through (one chunk of points at a time).
REFRESH_CHUNK_BYTES = 1 << 25


def refresh_chunk(max_centers: int, dim: int) -> int:
    """Functionals per refresh chunk: ``K = 2n floor(2^25 / (8 m 2n))`` (at least ``2n``), so ``8 m K <= 32 MiB``."""
    return dim * max(1, REFRESH_CHUNK_BYTES // (8 * max(int(max_centers), 1) * dim))


def bounded_memory(
    max_centers: int, n_train: int, n_val: int, slots: int, dim: int, block_size: int = 64, pool_factor: int = 4
) -> int:
    """Peak bytes of a run on :class:`BoundedActiveSetStore` (store, refresh buffers and the greedy loop's factor).

    ``8 [(m + b) (S + N_val) + c b (c b (2n + 1) + m) + m K + 2 m^2 + 4 S + 6 N]`` for ``m`` centres,
    ``S`` slots (functionals), ``N``/``N_val`` training/validation functionals, block size ``b``, pool factor ``c``
    and refresh chunk ``K`` (:func:`refresh_chunk`): the slots' and the validation set's Newton basis with the
    block's rows, the pool's Gramian (rows against the pool's points) and basis columns, the refresh's
    Gramian rows and triangular solve, the Cholesky factor (the loop's and the result's) and ``O(S + N)``
    vectors (residuals, power function, targets, the Gramian diagonal).  With compiled Gramian rows (numba);
    NumPy's rows add ``~4 x 8 m 1024 2n`` temporaries in a refresh.
    """
    m, b, c = int(max_centers), min(int(block_size), int(max_centers)), int(pool_factor)
    k = refresh_chunk(m, dim)
    pool = c * b
    return 8 * ((m + b) * (slots + n_val) + pool * (pool * (dim + 1) + m) + m * k + 2 * m * m + 4 * slots + 6 * n_train)


def bounded_capacity(
    budget: float, max_centers: int, n_train: int, n_val: int, dim: int, block_size: int = 64, pool_factor: int = 4
) -> int:
    """The most points whose ``2n`` functionals fit in the slots within ``budget`` bytes (:func:`bounded_memory`),
    at most ``N / 2n``; ``0`` when not even the fixed part fits."""
    fixed = bounded_memory(max_centers, n_train, n_val, 0, dim, block_size, pool_factor)
    m, b = int(max_centers), min(int(block_size), int(max_centers))
    per_point = 8 * dim * (m + b + 4)
    points = int((float(budget) - fixed) // per_point)
    return max(0, min(points, n_train // dim))


class BoundedActiveSetStore(BlockedStore):
    """The blocked greedy on ``S = 2n P`` slots (``P`` points), refreshed against all ``N`` candidates: bounded memory.

    The Newton basis lives on a fixed number of *slots*, each holding the ``2n`` functionals of one point;
    the blocked greedy (:class:`~sympredict.interpolation.greedy.blocked.BlockedStore`: pool, in-pool
    greedy, block rows by one product and one triangular solve, weak-greedy acceptance) runs over the
    slots.  The slots start with the ``P`` points of the largest ``max |y|``.  At the first block boundary
    after every ``refresh_every`` centres (and whenever no slot's residual exceeds ``tol``) the model is
    evaluated at *every* candidate, in chunks of points (the centres' Gramian rows against a chunk,
    ``8 m K`` bytes, never ``N x m``; or :func:`~sympredict.interpolation.functionals.functional_residuals`'
    compiled evaluation where its parameter weights fit those bytes), and up to ``max_new_points`` points outside the slots whose residual
    exceeds that of a slot's point replace the slots' points of smallest residual (largest against
    smallest): their Newton basis values ``L^{-1} K(selected, new)`` come from one triangular solve per
    chunk, their residuals and power function follow.  A point that leaves loses nothing: its
    selected functionals stay in the expansion, and it can come back.

    The run stops with ``'tol'`` only when the residual evaluated at every candidate is at or below ``tol``;
    at the end the full residual of the returned model is evaluated.  With ``P >= N / 2n`` every point has
    a slot and the run is :class:`BlockedStore`'s (the same selection, bit for bit; no refresh).

    Parameters
    ----------
    functionals
        :class:`~sympredict.interpolation.functionals.HBFunctionals` of ``M`` points (``N = M 2n``).
    targets : ndarray of shape (N,)
    tol, power_tol, validation, memory_limit
        As for :class:`ActiveSetStore` (``memory_limit`` bounds :func:`bounded_memory`).
    max_points
        ``P``: the points the slots hold; ``None`` (default): the most that fit ``memory_limit``
        (:func:`bounded_capacity`).
    block_size, pool_factor, slack, compiled
        As for :class:`~sympredict.interpolation.greedy.blocked.BlockedStore`.
    refresh_every
        Centres between two refreshes (at least).
    max_new_points
        Points swapped into the slots per refresh at most (each costs ``m^2 2n`` flops: at 1,024 a
        refresh's swaps stay below the block products between refreshes for slots of more than
        ``2n 1024 m / (2 refresh_every)`` functionals).

    Notes
    -----
    Memory: :func:`bounded_memory`, checked before the run.  Time: the blocked greedy's ``2 m S`` flops per
    centre (matrix products), plus per refresh ``N m`` Gramian entries (the full evaluation) and ``m^2 2n``
    flops per point swapped in.  ``stats``: the blocked store's, and ``'refreshes'``, ``'swapped'`` (points), ``'refresh_s'`` (seconds in
    refreshes, of which ``'swap_s'`` in swaps), ``'swaps'`` (``[centres, points]`` per swap), ``'evaluated_at'`` (centre counts of the full evaluations), ``'slots'`` (``S``), ``'memory_formula'`` (bytes).
    """

    label = "bounded active-set greedy"

    def __init__(
        self,
        functionals,
        targets,
        *,
        tol: float,
        max_points: Optional[int] = None,
        power_tol: float = 1e-12,
        validation: Optional[tuple] = None,
        memory_limit: Optional[float] = None,
        block_size: int = 64,
        pool_factor: int = 4,
        slack: float = 0.5,
        refresh_every: int = 256,
        max_new_points: int = 1024,
        compiled: Optional[bool] = None,
    ):
        if not isinstance(functionals, HBFunctionals):
            raise ValueError(
                "the bounded active-set greedy needs HBFunctionals (state-derivative functionals): "
                "use BlockedGreedy() for the direct model"
            )
        if np.size(targets) != functionals.n_functionals:
            raise ValueError(
                f"the bounded active-set greedy interpolates one output: targets must have shape "
                f"({functionals.n_functionals},), got {np.shape(targets)}"
            )
        for name, value in (
            ("max_points", max_points),
            ("refresh_every", refresh_every),
            ("max_new_points", max_new_points),
        ):
            if name == "max_points" and value is None:
                continue
            if isinstance(value, bool) or int(value) != value or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        super().__init__(
            functionals,
            targets,
            criterion="f",
            power_tol=power_tol,
            validation=validation,
            memory_limit=memory_limit,
            block_size=block_size,
            pool_factor=pool_factor,
            slack=slack,
            compiled=compiled,
        )
        self.full = functionals
        self.tol = float(tol)
        self.max_points = None if max_points is None else int(max_points)
        self.refresh_every = int(refresh_every)
        self.max_new_points = int(max_new_points)

    def open(self, expansion: Expansion):
        f = self.full
        dim, n_points = f.dim, len(f.points)
        m_max = expansion.max_centers
        b = min(self.block_size, m_max)
        limit = self.memory_limit if self.memory_limit is not None else 0.9 * available_memory()
        if self.max_points is None:  # sized to the memory limit
            cap = bounded_capacity(limit, m_max, self.n_functionals, self.n_val, dim, b, self.pool_factor)
            if cap < 1:
                raise ValueError(
                    f"the bounded active-set greedy cannot hold one point within {format_bytes(limit)} "
                    f"with {m_max} centres (bounded_memory): use fewer centres or raise memory_limit"
                )
            logger.info(f"bounded active set: {cap} of {n_points} points in its slots within {format_bytes(limit)}")
        cap = min(self.max_points or cap, n_points)
        need = bounded_memory(m_max, self.n_functionals, self.n_val, cap * dim, dim, b, self.pool_factor)
        if need > limit:
            fits = bounded_capacity(limit, m_max, self.n_functionals, self.n_val, dim, b, self.pool_factor)
            raise ValueError(
                f"the bounded active-set greedy with {cap} points in its slots needs {format_bytes(need)} "
                f"(bounded_memory) but the memory limit is {format_bytes(limit)}; use max_points <= {fits}"
                + (", fewer centres" if fits == 0 else "")
                + " or raise memory_limit"
            )
        self.expansion, self.max_centers, self.dim, self.n_points = expansion, m_max, dim, n_points
        self.covers_all = cap >= n_points
        self.y_points = self.y[:, 0].reshape(n_points, dim)
        # functional_residuals' compiled evaluation keeps (G, m) parameter weights for G distinct (mu, dT): used
        # where they fit the refresh chunk's bytes, else the centres' Gramian rows in chunks of points
        plain = f.kernel.periodic is None and f.kernel.symmetry is None
        if plain and _numba.HAVE_NUMBA and self.compiled:
            groups = len(np.unique(np.column_stack([f.mu, f.dt]), axis=0))
            self.direct_ok = 8 * groups * m_max <= REFRESH_CHUNK_BYTES
        else:
            self.direct_ok = not plain  # NumPy's evaluation: chunks of about 32 MiB
        self.diag_all = f.diagonal().astype(float)
        self.breakdown = self.power_tol * float(self.diag_all.max())
        if self.covers_all:
            slot_pts = np.arange(n_points)
        else:  # the points of largest |y| (the f-greedy's first choices)
            size = np.abs(self.y_points).max(axis=1)
            slot_pts = np.sort(np.argpartition(-size, cap - 1)[:cap])
        self.slot_pts = slot_pts
        self.in_slots = np.zeros(n_points, dtype=bool)
        self.in_slots[slot_pts] = True
        self._set_slot_functionals()
        cand = (slot_pts[:, None] * dim + np.arange(dim)).reshape(-1)
        self.res = self.y[cand].copy()
        self.res_abs = np.empty(len(cand))
        self.p2 = self.diag_all[cand].copy()
        self.basis = np.empty((m_max + b, len(cand)))
        self.vbasis = np.empty((m_max + b, self.n_val)) if self.n_val else None
        self.queue, self.block_start, self.block_chol, self.position = [], 0, None, 0
        self.next_size = self.block_size
        self.stats = {
            "blocks": 0,
            "block_sizes": [],
            "rejected": 0,
            "refreshes": 0,
            "swapped": 0,
            "refresh_s": 0.0,
            "swap_s": 0.0,
            "swaps": [],
            "evaluated_at": [],
            "slots": int(len(cand)),
            "memory_formula": int(need),
        }
        self.refreshed_at, self.full_at, self.full_max = 0, 0, self.targets_max
        abs_residual(self.res, out=self.res_abs)
        return self.targets_max, (np.abs(self.vres).max() if self.n_val else None)

    def _set_slot_functionals(self) -> None:
        f, pts = self.full, self.slot_pts
        self.functionals = HBFunctionals(f.kernel, f.points[pts], f.mu[pts], f.dt[pts])

    def select(self, m: int):
        if self.covers_all:
            return super().select(m)
        if self.position >= len(self.queue):
            score = self._score()
            slot_best = float(score.max()) if score.size else -np.inf
            due = m - self.refreshed_at >= self.refresh_every
            starved = not slot_best > self.tol and self.full_at != m
            if due or starved:
                self._refresh(m)
                if self.full_max <= self.tol:
                    return -1, -np.inf, self.full_max
        j, score, _ = super().select(m)
        return j, score, (self.full_max if self.full_at == m else np.inf)

    def winner(self, j: int, m: int):
        index, rep, coeffs, p2, res = super().winner(j, m)
        point, comp = divmod(int(j), self.dim)
        return int(self.slot_pts[point]) * self.dim + comp, rep, coeffs, p2, res

    def finish(self, m: int):
        """The full maximum residual of the returned model (evaluated here unless it already was at ``m``)."""
        if self.covers_all:
            return None
        if self.full_at != m:
            self._evaluate_full(m)
        return self.full_max

    def close(self) -> None:
        self.basis = self.vbasis = None  # before the loop copies its factor: the peak stays the formula's

    # ------------------------------------------------------------------ refreshes
    def _centre_rows(self, sub: HBFunctionals, m: int, buf: np.ndarray) -> np.ndarray:
        """The selected centres' Gramian rows against ``sub``'s functionals: (m, 2n P_sub), a view of ``buf``."""
        rows = buf[: m * sub.n_functionals].reshape(m, sub.n_functionals)
        return gram_rows(sub, self.full, self.expansion.selected[:m], rows, self.compiled)

    def _evaluate_full(self, m: int) -> np.ndarray:
        """``max_k |r|`` per point over every candidate (chunks of points; ``8 m K`` bytes of rows)."""
        f, dim = self.full, self.dim
        t0 = time.perf_counter()
        if m == 0:
            point_res = np.abs(self.y_points).max(axis=1)
        elif self.direct_ok:  # the compiled evaluation by parameter groups: (G, m) weights within the chunk's bytes
            e = self.expansion
            r = functional_residuals(f, self.y[:, 0], e.selected[:m], e.coef(m)[:, 0])
            point_res = np.abs(r).reshape(self.n_points, dim).max(axis=1)
        else:
            coef = self.expansion.coef(m)[:, 0]
            chunk = refresh_chunk(self.max_centers, dim) // dim
            buf = np.empty(m * chunk * dim)
            point_res = np.empty(self.n_points)
            for start in range(0, self.n_points, chunk):
                part = slice(start, min(start + chunk, self.n_points))
                sub = HBFunctionals(f.kernel, f.points[part], f.mu[part], f.dt[part])
                rows = self._centre_rows(sub, m, buf)
                r = self.y_points[part] - (coef @ rows).reshape(-1, dim)
                point_res[part] = np.abs(r).max(axis=1)
        self.full_max, self.full_at = float(point_res.max()), m
        self.stats["refresh_s"] += time.perf_counter() - t0
        self.stats["evaluated_at"].append(int(m))
        logger.info(
            f"refresh at {m} centres: full max residual {self.full_max:.3e} over {self.n_functionals} "
            f"functionals ({len(self.res)} in slots)"
        )
        return point_res

    def _refresh(self, m: int) -> None:
        """Evaluate every candidate; swap the worst points outside the slots for the slots' best-fitted ones."""
        point_res = self._evaluate_full(m)
        self.refreshed_at = m
        self.stats["refreshes"] += 1
        outside = np.flatnonzero(~self.in_slots)
        if outside.size == 0 or self.full_max <= self.tol:
            return
        k = min(self.max_new_points, outside.size, len(self.slot_pts))
        top = outside[np.argpartition(-point_res[outside], k - 1)[:k]]
        top = top[np.argsort(-point_res[top], kind="stable")]
        # a slot's worth: its selectable residual (a candidate at the breakdown guard is never selected again)
        slot_res = np.where(self.p2 > self.breakdown, self.res_abs, 0.0).reshape(-1, self.dim).max(axis=1)
        low = np.argsort(slot_res, kind="stable")[:k]
        gain = (point_res[top] > slot_res[low]) & (point_res[top] > self.tol)
        n_swap = int(np.count_nonzero(gain))  # top falls and low rises: the swaps that gain are a prefix
        if n_swap:
            t0 = time.perf_counter()
            self._swap(m, low[:n_swap], top[:n_swap])
            self.stats["swapped"] += n_swap
            self.stats["swaps"].append([int(m), n_swap])
            spent = time.perf_counter() - t0
            self.stats["refresh_s"] += spent
            self.stats["swap_s"] += spent

    def _swap(self, m: int, slots: np.ndarray, new: np.ndarray) -> None:
        """Points ``new`` into ``slots``: Newton basis values ``L^{-1} K(selected, new)``, residuals, power function."""
        f, e, dim = self.full, self.expansion, self.dim
        chunk = refresh_chunk(self.max_centers, dim) // dim
        chol = np.array(e.chol[:m, :m]) if m else None
        buf = np.empty(m * chunk * dim) if m else None
        beta = e.beta[:m, 0]
        for start in range(0, len(new), chunk):
            pts, where = new[start : start + chunk], slots[start : start + chunk]
            cols = (where[:, None] * dim + np.arange(dim)).reshape(-1)
            flat = (pts[:, None] * dim + np.arange(dim)).reshape(-1)
            if m:
                sub = HBFunctionals(f.kernel, f.points[pts], f.mu[pts], f.dt[pts])
                vals = self._centre_rows(sub, m, buf)
                blas.dtrsm(1.0, chol, vals.T, side=1, lower=1, trans_a=1, overwrite_b=1)
                self.basis[:m, cols] = vals
                self.res[cols, 0] = self.y[flat, 0] - beta @ vals
                self.p2[cols] = self.diag_all[flat] - np.einsum("ki,ki->i", vals, vals)
            else:
                self.res[cols, 0] = self.y[flat, 0]
                self.p2[cols] = self.diag_all[flat]
        self.in_slots[self.slot_pts[slots]] = False
        self.in_slots[new] = True
        self.slot_pts[slots] = new
        self._set_slot_functionals()
        abs_residual(self.res, out=self.res_abs)
