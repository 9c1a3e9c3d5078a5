"""The blocked f-/P-greedy's store: the exact greedy's Newton basis, grown a block of centres at a time.

The exact greedy (:mod:`~sympredict.interpolation.greedy.dense`) adds one centre
per step with a matrix-vector pass over the whole ``m x N`` basis: ``2 m N``
flops that stream ``8 m N`` bytes, so it runs at memory bandwidth.  This store
adds up to ``b`` centres per pass with matrix-matrix products (the same flops at
the arithmetic rate):

1. **Pool.**  The ``c b`` selectable candidates with the largest criterion
   (``|r_i|``, max over outputs, for the f-greedy; ``P2_i`` for the P-greedy;
   ``P2_i > power_tol max G_ii`` as in the exact greedy), ``c = pool_factor``;
   ``tau``: the largest criterion outside the pool.
2. **Block, chosen as the exact greedy would inside the pool.**  The pool's
   residual Gramian ``C = G(P, P) - V(:, P)^T V(:, P)`` (``(c b)^2`` kernel
   entries, one product) and an in-pool greedy on it: a pivoted Cholesky whose
   pivot is the current argmax of the criterion over the pool (residuals and
   power function of the pool updated after every pivot), stopped after ``b``
   pivots, at a pivot whose power function is at the breakdown guard (the
   dependent candidates are dropped), or as soon as the pool's leader falls
   below ``tau`` (then a candidate outside the pool may lead: the next block
   starts from the full criterion).  The first pivot is the exact greedy's
   choice; with ``b = 1`` the selection is the exact greedy's.
3. **Newton basis of the block in one pass.**  ``W^T = G(B, :) - V(:, B)^T V``
   (the block's Gramian rows in one call, then one ``b x m x N`` product),
   ``L_B`` the Cholesky factor of ``W^T(:, B)`` and the new rows
   ``V_B = L_B^{-1} W^T`` (one triangular solve with ``b`` right-hand sides of
   length ``N``).  The same for the validation set.
4. **Per centre, a weak greedy.**  The loop (:func:`~sympredict.interpolation.greedy.loop.run_greedy`)
   then takes the block's centres one by one: ``r -= beta v``, ``P2 -= v^2``
   (``O(N q)`` each), so the history (training and validation residual per
   centre) and the Newton coefficients are those of a one-at-a-time run.
   Before each centre the full criterion is checked: the block's next
   candidate is taken only while its criterion is at least ``1 - slack``
   times the maximum over all candidates (a weak greedy with factor
   ``1 - slack``, whose selections keep the greedy's convergence rates up to
   that factor); otherwise the rest of the block is dropped and a new block
   starts from the current leader, at most twice as large as the part of the
   last block that was kept (at least 8).  ``slack = 0`` accepts only the exact
   greedy's choice (blocks then break at the first candidate outside the pool
   that overtakes and much of the block work is discarded); ``slack = 0.5``
   (the trainer's default) keeps most blocks whole.

Cost: ``2 m N`` flops per centre as the exact greedy, but in products of ``b``
columns (bound by arithmetic, not bandwidth), plus ``2 b N`` for the triangular
solve and ``O(N q)`` per centre.  Kernel evaluations: ``N`` per centre (the
block's rows) plus ``(c b)^2 / b`` for the pool.
Memory (bytes): ``8 (m_max + b) (N + N_val)`` for the basis and the block's
rows, plus ``8 (c b)^2`` for the pool's Gramian and ``~8 b 2n 1024`` for the
Gramian rows' temporaries (:func:`blocked_memory`).
"""

from __future__ import annotations

from typing import Optional

import numpy as np
from scipy.linalg import blas

from sympredict import _numba
from sympredict.interpolation.greedy import _compiled
from sympredict.interpolation.functionals import HBFunctionals, ValueFunctionals
from sympredict.interpolation.greedy.dense import abs_residual
from sympredict.interpolation.greedy.loop import BaseStore, Expansion, check_memory

__all__ = ["BlockedStore", "gram_rows", "pool_gramian", "blocked_memory"]


def blocked_memory(max_centers: int, n_train: int, n_val: int, block_size: int, pool_factor: int) -> int:
    """Peak bytes of :class:`BlockedStore`'s arrays: ``8 ((m_max + b) (N + N_val) + (c b)^2)``."""
    return 8 * ((max_centers + block_size) * (n_train + n_val) + (pool_factor * block_size) ** 2)


def gram_rows(functionals, others, indices: np.ndarray, out: np.ndarray, compiled: bool = False) -> np.ndarray:
    """Gramian rows ``lambda_{i_k}^(1) lambda^(2) k`` (``i_k`` in ``others``) against every functional of ``functionals``.

    One call for the HB functionals: compiled (:func:`sympredict.interpolation.greedy._compiled.hb_rows`, a plain kernel) when
    ``compiled``, else :meth:`HBFunctionals.gram_rows`; column by column for sets that have no such method.
    ``out`` has shape (K, N).
    """
    if (
        compiled
        and isinstance(functionals, HBFunctionals)
        and isinstance(others, HBFunctionals)
        and _compiled.hb_rows_supported(functionals.kernel)
    ):
        pts, comps = np.divmod(np.asarray(indices, dtype=np.int64), others.dim)
        return _compiled.hb_rows(
            functionals.kernel,
            functionals.points,
            functionals.mu,
            functionals.dt,
            others.points[pts],
            others.mu[pts],
            others.dt[pts],
            comps,
            out,
        )
    if hasattr(functionals, "gram_rows"):
        return functionals.gram_rows(others, indices, out)
    for k, i in enumerate(indices):
        functionals.column(others.representer(int(i)), out[k])
    return out


def pool_gramian(functionals, pool: np.ndarray, compiled: bool = False) -> np.ndarray:
    """The Gramian ``G(pool, pool)``, shape (K, K), from ``O(K^2)`` kernel entries (not ``K`` full rows).

    For HB functionals the rows are taken against the pool's points (all their
    ``2n`` components) and the pool's components picked out.
    """
    pool = np.asarray(pool, dtype=np.int64)
    if isinstance(functionals, HBFunctionals):
        dim = functionals.dim
        pts, comps = np.divmod(pool, dim)
        uniq, inv = np.unique(pts, return_inverse=True)
        sub = HBFunctionals(functionals.kernel, functionals.points[uniq], functionals.mu[uniq], functionals.dt[uniq])
        rows = gram_rows(sub, functionals, pool, np.empty((len(pool), len(uniq) * dim)), compiled)
        return rows[:, inv * dim + comps]
    if isinstance(functionals, ValueFunctionals):
        sub = ValueFunctionals(functionals.kernel, functionals.points[pool], functionals.mu[pool], functionals.dt[pool])
        out = np.empty((len(pool), len(pool)))
        for k, i in enumerate(pool):
            sub.column(functionals.representer(int(i)), out[k])
        return out
    out = np.empty((len(pool), functionals.n_functionals))
    return gram_rows(functionals, functionals, pool, out, compiled)[:, pool]


class BlockedStore(BaseStore):
    """Newton basis of all ``N`` candidates, grown by blocks of up to ``block_size`` centres (module docstring).

    Parameters
    ----------
    functionals, targets, criterion, power_tol, validation, memory_limit
        As for :class:`~sympredict.interpolation.greedy.dense.DenseStore`.
    block_size
        ``b``: centres per block at most (``1``: the exact greedy's selection).
    pool_factor
        ``c``: the pool holds the ``c b`` best candidates by the criterion.
    slack
        A block's next candidate is taken while its criterion is at least
        ``1 - slack`` times the maximum over all candidates (step 4 above).
    compiled
        The block's Gramian rows by :func:`sympredict.interpolation.greedy._compiled.hb_rows` (state-derivative
        functionals, a kernel without periodic coordinates or symmetry); default: when numba is
        installed.  NumPy's :meth:`~sympredict.interpolation.functionals.HBFunctionals.gram_rows` otherwise.

    Notes
    -----
    Memory ``8 ((m_max + b) (N + N_val) + (c b)^2)`` bytes (:func:`blocked_memory`),
    checked before the run.  ``stats['blocks']``: the number of blocks;
    ``stats['block_sizes']``: their sizes; ``stats['rejected']``: block candidates dropped by the ``slack`` rule.
    """

    label = "blocked greedy"

    def __init__(
        self,
        functionals,
        targets,
        *,
        memory_limit: Optional[float] = None,
        block_size: int = 64,
        pool_factor: int = 4,
        slack: float = 0.0,
        compiled: Optional[bool] = None,
        **base,
    ):
        if isinstance(slack, bool) or not isinstance(slack, (int, float, np.number)) or not 0 <= slack < 1:
            raise ValueError(f"slack must be a float in [0, 1), got {slack!r}")
        for name, value in (("block_size", block_size), ("pool_factor", pool_factor)):
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        super().__init__(functionals, targets, **base)  # criterion, power_tol, validation
        self.memory_limit = memory_limit
        self.block_size = int(block_size)
        self.pool_factor = int(pool_factor)
        self.slack = float(slack)
        self.compiled = _numba.use_compiled(compiled)
        self.basis = None

    def open(self, expansion: Expansion):
        n, n_val, max_centers = self.n_functionals, self.n_val, expansion.max_centers
        b = min(self.block_size, max_centers)
        # the block's rows live in the basis' own rows m..m+b-1: b spare rows past max_centers
        extra = (self.pool_factor * b) ** 2 // max(n + n_val, 1) + 1
        check_memory(max_centers + b + extra, n, n_val, self.memory_limit)
        self.max_centers = max_centers
        self.res = self.y.copy()
        self.res_abs = np.empty(n)
        self.p2 = self.functionals.diagonal().astype(float)
        self.breakdown = self.power_tol * self.p2.max()
        self.basis = np.empty((max_centers + b, n))
        self.vbasis = np.empty((max_centers + b, n_val)) if n_val else None
        self.queue, self.block_start, self.block_chol, self.position = [], 0, None, 0
        self.next_size = self.block_size
        self.stats = {"blocks": 0, "block_sizes": [], "rejected": 0}
        abs_residual(self.res, out=self.res_abs)
        return self.res_abs.max(), (np.abs(self.vres).max() if n_val else None)

    def _score(self) -> np.ndarray:
        score = self.res_abs.copy() if self.criterion == "f" else self.p2.copy()
        score[self.p2 <= self.breakdown] = -np.inf
        return score

    def select(self, m: int):
        score = self._score()
        best = float(score.max())
        if self.position < len(self.queue):
            j = self.queue[self.position]
            if not score[j] >= (1.0 - self.slack) * best:
                # a candidate outside the block leads now: the rest of the block is not the greedy's choice
                self.stats["rejected"] += len(self.queue) - self.position
                # the next block: twice what this one kept (rows past the cut were computed in vain)
                self.next_size = max(8, 2 * self.position)
                self.queue = []
        if self.position >= len(self.queue):
            self._new_block(m, score)
            if not self.queue:
                return -1, -np.inf, np.inf
        j = self.queue[self.position]
        # the tol rule's certificate: max |r| over the selectable candidates now
        return j, score[j], (best if self.criterion == "f" else np.inf)

    def _new_block(self, m: int, score: np.ndarray) -> None:
        """Choose the next block (pool, in-pool greedy) and compute its Newton basis rows (module docstring)."""
        b = min(self.next_size, self.block_size, self.max_centers - m)
        self.next_size = self.block_size
        self.queue, self.position = [], 0
        while b > 0:
            selectable = int(np.count_nonzero(np.isfinite(score)))
            if selectable == 0:
                return
            pool, order, chol = self._choose(m, score, b)
            if len(order):
                self._block_rows(m, pool[order], chol)
                return
            # the pool's own residual Gramian puts all of it at the breakdown guard (round-off apart from P2):
            # dependent candidates, never selectable again
            self.p2[pool] = 0.0
            score[pool] = -np.inf

    def _choose(self, m: int, score: np.ndarray, b: int):
        """The pool (best first), the in-pool greedy's order and its Cholesky factor."""
        selectable = int(np.count_nonzero(np.isfinite(score)))
        k_pool = min(self.pool_factor * b, selectable)
        if k_pool < len(score):
            # the k_pool largest, the lowest indices among ties at the threshold (np.argmax's rule)
            threshold = score[np.argpartition(-score, k_pool - 1)[k_pool - 1]]
            above = np.flatnonzero(score > threshold)
            pool = np.concatenate([above, np.flatnonzero(score == threshold)[: k_pool - len(above)]])
            outside = np.ones(len(score), dtype=bool)
            outside[pool] = False
            tau = float(score[outside].max())
        else:
            pool, tau = np.arange(len(score)), -np.inf
        # best first, the lowest index first on ties (np.argmax's rule: b = 1 selects as the exact greedy)
        pool = pool[np.lexsort((pool, -score[pool]))]
        order, chol = self._pool_greedy(m, pool, b, tau)
        return pool, order, chol

    def _pool_greedy(self, m: int, pool: np.ndarray, b: int, tau: float):
        """The greedy restricted to the pool, as a pivoted Cholesky of its residual Gramian: ``(order, L)``."""
        gram = pool_gramian(self.functionals, pool, self.compiled)
        if m:
            vp = self.basis[:m, pool]
            gram -= vp.T @ vp
        k_pool = len(pool)
        chol = np.zeros((k_pool, b))
        p2 = np.diag(gram).copy()
        res = self.res[pool].copy()
        available = p2 > self.breakdown
        order = []
        for k in range(b):
            score = np.abs(res).max(axis=1) if self.criterion == "f" else p2.copy()
            score[~available] = -np.inf
            i = int(np.argmax(score))
            if not np.isfinite(score[i]) or (k and score[i] < tau):
                break
            col = gram[:, i] - chol[:, :k] @ chol[i, :k]
            piv = np.sqrt(p2[i])
            v = col / piv
            chol[:, k] = v
            res -= np.outer(v, res[i] / piv)
            p2 -= v * v
            available[i] = False
            available &= p2 > self.breakdown
            order.append(i)
        return np.array(order, dtype=np.int64), chol[order, : len(order)]

    def _block_rows(self, m: int, block: np.ndarray, pool_chol: np.ndarray) -> None:
        """``V_B = L_B^{-1} (G(B, :) - V(:, B)^T V)`` into ``basis[m:m+b]`` (and the validation basis)."""
        kb = len(block)
        rows = self.basis[m : m + kb]
        gram_rows(self.functionals, self.functionals, block, rows, self.compiled)
        vt = self.basis[:m, block]  # (m, kb)
        if m:
            # rows -= vt^T basis[:m], in place: on the Fortran views, W (N, kb) -= basis[:m]^T (N, m) @ vt (m, kb)
            blas.dgemm(-1.0, self.basis[:m].T, vt, beta=1.0, c=rows.T, overwrite_c=1)
        # L_B from the block's own residual Gramian (the numbers the rows are divided by); the pool's
        # factor where round-off makes that block numerically indefinite
        gb = rows[:, block]
        try:
            chol = np.linalg.cholesky(0.5 * (gb + gb.T))
            if not np.all(np.diag(chol) ** 2 > self.breakdown):
                chol = pool_chol
        except np.linalg.LinAlgError:
            chol = pool_chol
        blas.dtrsm(1.0, chol, rows.T, side=1, lower=1, trans_a=1, overwrite_b=1)
        if self.n_val:
            vrows = self.vbasis[m : m + kb]
            gram_rows(self.val_functionals, self.functionals, block, vrows, self.compiled)
            if m:
                blas.dgemm(-1.0, self.vbasis[:m].T, vt, beta=1.0, c=vrows.T, overwrite_c=1)
            blas.dtrsm(1.0, chol, vrows.T, side=1, lower=1, trans_a=1, overwrite_b=1)
        self.queue, self.position = [int(i) for i in block], 0
        self.block_start, self.block_chol = m, chol
        self.stats["blocks"] += 1
        self.stats["block_sizes"].append(kb)

    def winner(self, j: int, m: int):
        k = self.position
        coeffs = self.basis[:m, j].copy()
        coeffs[self.block_start : m] = self.block_chol[k, :k]  # the factor the block's rows were divided by
        return j, None, coeffs, self.block_chol[k, k] ** 2, self.res[j]

    def add(self, m, rep, coeffs_j, pj, b, j):
        row = self.basis[m]
        res = self.res
        if self.n_outputs == 1:
            res[:, 0] -= b[0] * row
        else:
            res -= row[:, None] * b
        self.p2 -= row * row
        res[j] = 0.0
        self.p2[j] = 0.0
        self.position += 1
        val_max = None
        if self.n_val:
            self.vres -= self.vbasis[m][:, None] * b
            val_max = np.abs(self.vres).max()
        abs_residual(res, out=self.res_abs)
        return self.res_abs.max(), val_max
