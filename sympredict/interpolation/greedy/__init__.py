"""Greedy generalized kernel interpolation: one loop, pluggable stores, training strategies.

* :mod:`~sympredict.interpolation.greedy.loop`: :func:`run_greedy` (selection, stop rules,
  divergence, history: written once) and the store interface;
* stores: :class:`DenseStore` (exact, float64/float32), :class:`ActiveSetStore`
  (active subset, refreshed), :class:`ShardedStore` (pyMOR worker pools), :class:`BlockedStore` (blocks of
  centres), :class:`BoundedActiveSetStore` (blocks on slots sized to a memory budget);
* :mod:`~sympredict.interpolation.greedy.trainers`: the estimators' ``trainer`` strategies
  (:class:`ExactGreedy`, :class:`ActiveSetGreedy`, :class:`ShardedGreedy`).

The functions below run one strategy with explicit arguments (the estimators take the
strategies themselves).
"""

from __future__ import annotations

from typing import Callable, Optional

from sympredict.interpolation.greedy.active_set import BoundedActiveSetStore, ActiveSetStore, bounded_memory
from sympredict.interpolation.greedy.dense import DenseStore
from sympredict.interpolation.greedy.loop import (
    GreedyHistory,
    GreedyResult,
    NewtonBasisStore,
    available_memory,
    check_memory,
    format_bytes,
    kernel_coefficients,
    run_greedy,
)
from sympredict.interpolation.greedy.sharded import SHARD_ALIGN, ShardedStore, shard_bounds
from sympredict.interpolation.greedy.trainers import (
    TRAINERS,
    ActiveSetGreedy,
    BlockedGreedy,
    BoundedActiveSetGreedy,
    ExactGreedy,
    ShardedGreedy,
    Trainer,
    register_trainer,
    trainer_from_spec,
    trainer_memory,
    default_trainer,
    memory_budget,
)
from sympredict.interpolation.greedy.blocked import BlockedStore

__all__ = [
    "GreedyHistory",
    "GreedyResult",
    "NewtonBasisStore",
    "run_greedy",
    "DenseStore",
    "ActiveSetStore",
    "ShardedStore",
    "BlockedStore",
    "BlockedGreedy",
    "trainer_memory",
    "default_trainer",
    "BoundedActiveSetStore",
    "BoundedActiveSetGreedy",
    "bounded_memory",
    "memory_budget",
    "Trainer",
    "ExactGreedy",
    "ActiveSetGreedy",
    "ShardedGreedy",
    "TRAINERS",
    "register_trainer",
    "trainer_from_spec",
    "greedy_interpolation",
    "active_set_greedy",
    "sharded_greedy",
    "shard_bounds",
    "SHARD_ALIGN",
    "available_memory",
    "check_memory",
    "format_bytes",
    "kernel_coefficients",
]


def greedy_interpolation(
    functionals,
    targets,
    *,
    max_centers: int,
    validation: Optional[tuple] = None,
    divergence_factor: float = 100.0,
    log_every: int = 100,
    keep_basis: bool = False,
    **settings,
) -> GreedyResult:
    """Sparse generalized interpolation by f-greedy (or P-greedy) selection, all candidates in memory.

    ``ExactGreedy(**settings).run(...)``: the strategy the estimators take, run once on explicit arguments.

    Parameters
    ----------
    functionals
        The ``N`` candidate functionals (:mod:`sympredict.interpolation.functionals`).
    targets : ndarray of shape (N,) or (N, q)
        Data ``y_i = lambda_i(f)``; ``q > 1`` interpolates ``q`` outputs with
        shared centres (selection by the max over outputs).
    max_centers : int
        Upper bound on the number of selected functionals.
    validation : tuple or None, default=None
        Optional ``(val_functionals, val_targets)``; then ``E_val(m)`` is recorded.
    divergence_factor : float, default=100.0
        Blow-up factor of the residual that stops and truncates the run
        (:func:`~sympredict.interpolation.greedy.loop.run_greedy`).
    log_every : int, default=100
        Log progress every this many steps.
    keep_basis : bool, default=False
        Return the Newton basis in :attr:`GreedyResult.basis` (benchmarks).
    **settings
        The settings of :class:`ExactGreedy`, which checks them: ``tol=1e-10``, ``criterion='f'``,
        ``power_tol=1e-12``, ``memory_limit=None``, ``basis_dtype='float64'``, ``regularization=0.0``.

    Returns
    -------
    GreedyResult

    Notes
    -----
    Time ``O(m^2 (N + N_val) / 2)`` memory traffic, memory ``itemsize m_max (N + N_val)``
    bytes (:mod:`sympredict.interpolation.greedy.dense`).
    """
    return ExactGreedy(**settings).run(
        functionals,
        targets,
        max_centers=max_centers,
        validation=validation,
        divergence_factor=divergence_factor,
        log_every=log_every,
        keep_basis=keep_basis,
    )


def active_set_greedy(
    functionals,
    targets,
    *,
    max_centers: int,
    validation: Optional[tuple] = None,
    divergence_factor: float = 100.0,
    log_every: int = 100,
    **settings,
) -> GreedyResult:
    """Fast f-greedy on an active subset of the points, refreshed against the full residual (:class:`ActiveSetStore`).

    ``ActiveSetGreedy(**settings).run(...)``.  Arguments as in :func:`greedy_interpolation`, with the settings of
    :class:`ActiveSetGreedy` (``initial_points``, ``refresh_every``, ``max_new_points``, ``margin``,
    ``refresh_fraction``, ``seed``, ``tol``, ``power_tol``, ``memory_limit``).  ``history.train_max_residual[k]``
    is the active set's maximum after ``k`` centres, except the last entry: the full maximum over all ``N``
    candidates; ``'tol'`` only if that full maximum is at or below ``tol``.
    """
    return ActiveSetGreedy(**settings).run(
        functionals,
        targets,
        max_centers=max_centers,
        validation=validation,
        divergence_factor=divergence_factor,
        log_every=log_every,
    )


def sharded_greedy(
    functionals,
    targets,
    *,
    max_centers: int,
    validation: Optional[tuple] = None,
    divergence_factor: float = 100.0,
    log_every: int = 100,
    callback: Optional[Callable[[int, float], None]] = None,
    stats: Optional[dict] = None,
    **settings,
) -> GreedyResult:
    """f-greedy (or P-greedy) with the candidates sharded over a pyMOR worker pool (:class:`~sympredict.interpolation.greedy.sharded.ShardedStore`).

    ``ShardedGreedy(**settings).run(...)``: the same arguments and result as :func:`greedy_interpolation` (same
    selection and coefficients), with the settings of :class:`ShardedGreedy` (``pool``, ``n_shards``,
    ``memory_limit_per_rank``, ``timeout``, ``tol``, ``criterion``, ``power_tol``, ``regularization``);
    ``callback(m, E_train(m))`` after each step; ``stats``, a dict filled with the pool timings (the store's
    ``stats``).

    Raises
    ------
    ValueError
        Bad arguments, or a worker's basis over its memory limit (names the rank).
    sympredict.parallel.WorkerError
        Any other exception on a worker (names the rank, carries the remote traceback).
    """
    result = ShardedGreedy(**settings).run(
        functionals,
        targets,
        max_centers=max_centers,
        validation=validation,
        divergence_factor=divergence_factor,
        log_every=log_every,
        callback=callback,
    )
    if stats is not None:
        stats.update(result.stats)
    return result
