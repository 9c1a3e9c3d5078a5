"""The sharded f-greedy's store: contiguous shards of the candidates on a pyMOR worker pool.

The ``N`` candidate functionals are cut into contiguous shards of points, one
or more per worker.  Each shard is a :class:`~sympredict.interpolation.greedy.dense.DenseStore`
of its candidates (the Newton-basis rows ``m x N_shard``, residuals, power
function), so a shard's update is the serial update applied to a column slice.
Per greedy step the driver (rank 0 under MPI) makes two pool calls:

1. ``apply_only`` (owner of the global best): its representer, Newton-basis
   row (``m`` floats), ``P2_j`` and ``r_j``;
2. ``apply`` (all workers): add the new basis function to every shard
   (``O(m)`` data sent), then report each shard's ``max |r|``, ``max |r_val|``
   and local best ``(score, global index)``: ``O(1)`` per shard back.

Communication is ``O(workers + m)`` per step, never ``O(N)``.  Ties are broken
as the serial ``np.argmax`` breaks them (lowest global index: shards are
contiguous in the global order and each reports its first local maximum).
Shard boundaries are aligned (:data:`SHARD_ALIGN`) so that BLAS treats every
candidate as in the full array: the selection, the Newton coefficients and the
kernel coefficients equal the serial greedy's bit for bit.

A worker that raises (e.g. its memory check) never hangs the pool: worker
functions return the exception (:func:`sympredict.parallel.guarded`), and the
driver raises ``ValueError`` (memory check) or
:class:`~sympredict.parallel.WorkerError` naming the rank.  A worker that
*dies* is found by :class:`~sympredict.parallel.Watchdog`, which aborts the MPI
job.  Memory ``8 m_max (N + N_val) / P`` bytes per worker, checked on each
worker before it allocates.
"""

from __future__ import annotations

import contextlib
import math
import time
from typing import Optional

import numpy as np
from pymor.core.logger import getLogger
from pymor.parallel.dummy import dummy_pool

from sympredict.interpolation.greedy.dense import DenseStore
from sympredict.interpolation.greedy.loop import BaseStore, Expansion, available_memory, format_bytes
from sympredict.parallel import Watchdog, checked, guarded, whoami, worker_info

__all__ = ["SHARD_ALIGN", "shard_bounds", "ShardedStore"]

logger = getLogger("sympredict.interpolation.greedy")


#: Shard boundaries fall on multiples of this many functionals: BLAS then treats every
#: candidate of a shard as it treats it in the full array (same SIMD lanes and tail
#: handling), so the sharded Newton basis equals the serial one bit for bit.
SHARD_ALIGN = 32


def shard_bounds(n_points: int, n_shards: int, per_point: int = 1, align: int = SHARD_ALIGN) -> np.ndarray:
    """Boundaries of ``n_shards`` contiguous, balanced point ranges ``[b_s, b_{s+1})``.

    Interior boundaries are multiples of ``align / gcd(align, per_point)`` points
    (``align`` functionals) when every shard can still get points; otherwise
    they are unaligned (equal to the serial result to round-off only).

    Returns
    -------
    ndarray of shape (n_shards + 1,), int
    """
    step = align // math.gcd(align, per_point) if align > 1 else 1
    if n_points < n_shards * step:
        step = 1
    den = n_shards * step
    cuts = [0] + [(n_points * s + den // 2) // den * step for s in range(1, n_shards)] + [n_points]
    return np.array(cuts, dtype=np.int64)


def _subset(functionals, lo: int, hi: int):
    """The functionals of points ``lo:hi`` (same class, same kernel), and functionals per point."""
    points = getattr(functionals, "points", None)
    if points is None or not hasattr(functionals, "kernel"):
        raise TypeError(
            f"sharding needs point-based functionals (HBFunctionals, ValueFunctionals), got {type(functionals).__name__}"
        )
    per_point = functionals.n_functionals // len(points)
    sub = type(functionals)(functionals.kernel, points[lo:hi], functionals.mu[lo:hi], functionals.dt[lo:hi])
    return sub, per_point


class _Shards:
    """Per-worker container of the shards' :class:`DenseStore` objects (pushed empty, filled by :func:`_w_load_shards`)."""

    def __init__(self):
        self.shards = {}


class _Sized:
    """What :meth:`DenseStore.open` reads of the expansion: its capacity."""

    def __init__(self, max_centers: int):
        self.max_centers = max_centers


def _report(sid: int, offset: int, store: DenseStore, m: int, train_max: float, val_max) -> tuple:
    """``(shard, max |r|, max |r_val|, best score, its global index)`` after ``m`` centres."""
    j, score, _ = store.select(m)
    return (
        sid,
        float(train_max),
        -np.inf if val_max is None else float(val_max),
        float(score),
        offset + j if j >= 0 else -1,
    )


@guarded
def _w_load_shards(payload, shards=None):
    """Check the per-rank memory limit, build this worker's shards and report them."""
    specs, settings = payload
    me = whoami()
    need = 8 * settings["max_centers"] * sum(s["n_train"] + s["n_val"] for s in specs)
    limit = settings["memory_limit_per_rank"]
    if limit is None:
        limit = 0.9 * available_memory() / settings["ranks_on_host"].get(me[1], 1)
    if need > limit:
        raise ValueError(
            f"its shards' Newton basis needs {format_bytes(need)} ({settings['max_centers']} centres x "
            f"{sum(s['n_train'] + s['n_val'] for s in specs)} functionals x 8 bytes) but the per-rank memory limit is "
            f"{format_bytes(limit)}; use more ranks (at least {max(1, math.ceil(settings['need_total'] / limit)) if limit > 0 else 'more'}), fewer centres, "
            "or raise memory_limit_per_rank"
        )
    for s in specs:
        val = (s["val_functionals"], s["val_targets"]) if s["n_val"] else None
        store = DenseStore(
            s["functionals"],
            s["targets"],
            criterion=settings["criterion"],
            power_tol=settings["power_tol"],
            validation=val,
            memory_limit=np.inf,
            diagonal_max=settings["diagonal_max"],
            regularization=settings["regularization"],
        )
        shards.shards[s["shard_id"]] = (s["offset"], store, store.open(_Sized(settings["max_centers"])))
    return sorted(shards.shards)


@guarded
def _w_shard_ids(shards=None):
    return sorted(shards.shards)


@guarded
def _w_step(winner, shards=None):
    """Add the winner (``None`` at the start) to every local shard, then report each shard.

    Returns ``(reports, seconds)``: one report per local shard and the compute time spent here.
    """
    t0 = time.perf_counter()
    out = []
    for sid in sorted(shards.shards):
        offset, store, first = shards.shards[sid]
        if winner is None:
            out.append(_report(sid, offset, store, 0, *first))
            continue
        m, rep, coeffs, pj, b, j = winner
        local = j - offset
        train_max, val_max = store.add(m, rep, coeffs, pj, b, local if 0 <= local < store.n_functionals else -1)
        out.append(_report(sid, offset, store, m + 1, train_max, val_max))
    return out, time.perf_counter() - t0


@guarded
def _w_winner(shard_id, j, m, shards=None):
    offset, store, _ = shards.shards[shard_id]
    return store.winner(j - offset, m)[1:]


@guarded
def _w_clear(shards=None):
    shards.shards.clear()


def _combine(reports):
    """Global ``max |r|``, ``max |r_val|`` and best ``(score, index, shard)`` from the workers' shard reports.

    Shards are scanned in global order and a later shard wins only with a
    strictly larger score: the lowest global index among equal maxima, as
    ``np.argmax`` over the whole set.
    """
    flat = sorted((r for worker in reports for r in worker), key=lambda r: r[0])
    train_max = max(r[1] for r in flat)
    val_max = max(r[2] for r in flat)
    best = None
    for sid, _, _, score, j in flat:
        if best is None or score > best[0]:
            best = (score, j, sid)
    return train_max, val_max, best


class ShardedStore(BaseStore):
    """The candidates' Newton basis sharded over a pyMOR worker pool (driver side).

    Parameters
    ----------
    functionals
        ``HBFunctionals`` or ``ValueFunctionals`` with ``M`` points (``N`` functionals).
    targets : ndarray of shape (N,) or (N, q)
    criterion, power_tol, validation
        As for :class:`~sympredict.interpolation.greedy.dense.DenseStore` (the validation set is sharded too).
    pool
        pyMOR |WorkerPool|; default the dummy pool (one in-process worker).
    n_shards
        Number of shards (default ``len(pool)``: one per worker); shards are
        spread evenly over the workers, contiguous in the global order.  More
        shards than workers are allowed (the dummy pool can run ``n_shards=2``).
    memory_limit_per_rank
        Bytes the Newton basis of one worker's shards may use; default 90% of
        the available memory of the worker's host divided by the number of
        workers on that host.
    timeout
        Seconds without a heartbeat after which an MPI worker counts as dead
        (:class:`~sympredict.parallel.Watchdog`); ``None`` disables heartbeats
        (dead local processes are still detected), ``0`` disables the watchdog.
    regularization
        Ridge term ``lambda`` of :class:`~sympredict.interpolation.greedy.dense.DenseStore`
        (each shard adds it at the selected functional's own index when it holds it).

    Attributes
    ----------
    stats : dict
        After a run: per-step wall seconds of the two pool calls on the driver
        (``winner_call``, ``step_call``, shape (m,)), the compute seconds in
        each worker's step (``worker_compute``, (m, workers)), and
        ``n_workers``, ``n_shards``, ``shard_sizes``, ``workers``.
    """

    label = "sharded greedy"

    def __init__(
        self,
        functionals,
        targets,
        *,
        pool=None,
        n_shards: Optional[int] = None,
        memory_limit_per_rank: Optional[float] = None,
        timeout: Optional[float] = 60.0,
        regularization: float = 0.0,
        **base,
    ):
        if not (np.isfinite(regularization) and regularization >= 0):
            raise ValueError(f"regularization must be a finite non-negative float, got {regularization!r}")
        _subset(functionals, 0, 1)  # TypeError for functionals that cannot be sharded
        super().__init__(functionals, targets, **base)  # criterion, power_tol, validation
        self.pool = dummy_pool if pool is None else pool
        self.n_workers = len(self.pool)
        self.n_shards = self.n_workers if n_shards is None else int(n_shards)
        n_points = len(functionals.points)
        if not 1 <= self.n_shards <= max(1, n_points):
            raise ValueError(f"n_shards must lie in 1..{n_points} (the number of points), got {self.n_shards}")
        self.memory_limit_per_rank = memory_limit_per_rank
        self.timeout = timeout
        self.regularization = float(regularization)
        self._stack = None

    def _payloads(self, max_centers: int, workers: list) -> tuple:
        f, y, n_shards = self.functionals, self.y, self.n_shards
        ranks_on_host = {}
        for _, host, _ in workers:
            ranks_on_host[host] = ranks_on_host.get(host, 0) + 1
        per = f.n_functionals // len(f.points)
        bounds = shard_bounds(len(f.points), n_shards, per)
        val_f, vres0, vbounds = None, None, None
        if self.n_val:
            val_f, vres0 = self.val_functionals, self.vres
            vbounds = shard_bounds(len(val_f.points), n_shards, val_f.n_functionals // len(val_f.points))
        specs = []
        for s in range(n_shards):
            sub, per = _subset(f, bounds[s], bounds[s + 1])
            spec = {
                "shard_id": s,
                "offset": int(bounds[s] * per),
                "functionals": sub,
                "n_train": sub.n_functionals,
                "targets": y[bounds[s] * per : bounds[s + 1] * per],
                "val_functionals": None,
                "val_targets": None,
                "n_val": 0,
            }
            if self.n_val and vbounds[s + 1] > vbounds[s]:
                vsub, vper = _subset(val_f, vbounds[s], vbounds[s + 1])
                if vsub.n_functionals:
                    spec.update(
                        val_functionals=vsub,
                        val_targets=vres0[vbounds[s] * vper : vbounds[s + 1] * vper],
                        n_val=vsub.n_functionals,
                    )
            specs.append(spec)
        wb = shard_bounds(n_shards, self.n_workers, align=1)  # shards of worker w: wb[w]..wb[w+1]
        settings = {
            "max_centers": max_centers,
            "criterion": self.criterion,
            "power_tol": self.power_tol,
            "diagonal_max": float(f.diagonal().max()),
            "regularization": self.regularization,
            "memory_limit_per_rank": self.memory_limit_per_rank,
            "ranks_on_host": ranks_on_host,
            "need_total": 8 * max_centers * (self.n_functionals + self.n_val),
        }
        return [(specs[wb[w] : wb[w + 1]], settings) for w in range(self.n_workers)], bounds, per

    # ------------------------------------------------------------------ protocol
    def open(self, expansion: Expansion):
        pool = self.pool
        workers = worker_info(pool)
        payloads, bounds, per = self._payloads(expansion.max_centers, workers)
        logger.info("workers: " + ", ".join(f"rank {r} pid {pid} on {host}" for r, host, pid in workers))
        logger.info(
            f"sharded greedy: {self.n_functionals} functionals{f' (+{self.n_val} validation)' if self.n_val else ''} "
            f"in {self.n_shards} shard(s) on {self.n_workers} worker(s), up to {expansion.max_centers} centres"
        )
        self._stack = contextlib.ExitStack()
        self._stack.enter_context(Watchdog(pool, workers, self.timeout))
        self.remote = self._stack.enter_context(pool.push(_Shards()))
        self._stack.callback(lambda: checked(pool.apply(_w_clear, shards=self.remote)))
        try:
            checked(pool.map(_w_load_shards, payloads, shards=self.remote))
            # where the shards landed, by worker index (apply answers in worker order; map need not place item w on worker w)
            placed = checked(pool.apply(_w_shard_ids, shards=self.remote))
            self.owner = {sid: w for w, sids in enumerate(placed) for sid in sids}
            if sorted(self.owner) != list(range(self.n_shards)):
                raise RuntimeError(f"shards were not placed once each: {placed}")  # pragma: no cover
            train_max, val_max = self._step(None)
        except BaseException:
            self.close()
            raise
        self.timing = []
        self.stats = {
            "n_workers": self.n_workers,
            "n_shards": self.n_shards,
            "shard_sizes": np.diff(bounds) * per,
            "workers": workers,
        }
        return train_max, (val_max if self.n_val else None)

    def _step(self, winner):
        reports = checked(self.pool.apply(_w_step, winner, shards=self.remote))
        self.worker_seconds = tuple(sec for _, sec in reports)
        train_max, val_max, self.best = _combine([r for r, _ in reports])
        return train_max, val_max

    def select(self, m: int):
        score, j, _ = self.best
        if j < 0 or not np.isfinite(score):
            return -1, score, np.inf
        return j, score, (score if self.criterion == "f" else np.inf)

    def winner(self, j: int, m: int):
        t0 = time.perf_counter()
        rep, coeffs_j, p2_j, res_j = checked(
            self.pool.apply_only(_w_winner, self.owner[self.best[2]], self.best[2], j, m, shards=self.remote)
        )
        self._t_winner = time.perf_counter() - t0
        return j, rep, coeffs_j, p2_j, res_j

    def add(self, m, rep, coeffs_j, pj, b, j):
        t0 = time.perf_counter()
        train_max, val_max = self._step((m, rep, coeffs_j, pj, b, j))
        self.timing.append((self._t_winner, time.perf_counter() - t0) + self.worker_seconds)
        return train_max, (val_max if self.n_val else None)

    def finish(self, m: int):
        t = np.array(self.timing).reshape(-1, 2 + self.n_workers)
        self.stats.update(winner_call=t[:, 0], step_call=t[:, 1], worker_compute=t[:, 2:])
        return None

    def close(self) -> None:
        stack, self._stack = self._stack, None
        if stack is not None:
            stack.close()
