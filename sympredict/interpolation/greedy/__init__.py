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
    tol: float = 1e-10,
    criterion: str = "f",
    power_tol: float = 1e-12,
    divergence_factor: float = 100.0,
    validation: Optional[tuple] = None,
    memory_limit: Optional[float] = None,
    log_every: int = 100,
    basis_dtype: str = "float64",
    keep_basis: bool = False,
    regularization: float = 0.0,
) -> GreedyResult:
    """Sparse generalized interpolation by f-greedy (or P-greedy) selection, all candidates in memory.

    Parameters
    ----------
    functionals
        The ``N`` candidate functionals (:mod:`sympredict.interpolation.functionals`).
    targets : ndarray of shape (N,) or (N, q)
        Data ``y_i = lambda_i(f)``; ``q > 1`` interpolates ``q`` outputs with
        shared centres (selection by the max over outputs).
    max_centers
        Upper bound on the number of selected functionals.
    tol
        f-greedy stops when ``max |r| <= tol`` over the selectable candidates.
    criterion
        ``'f'`` (residual) or ``'p'`` (power function).
    divergence_factor
        Blow-up factor of the residual that stops and truncates the run
        (:func:`~sympredict.interpolation.greedy.loop.run_greedy`).
    log_every
        Log progress every this many steps.
    power_tol
        Candidates with ``P2_i <= power_tol * max(G_ii)`` are never selected
        (breakdown guard); when no candidate is left the run stops with
        reason ``'power'``.  The new basis column is computed with a relative
        error of about ``eps_mach sqrt(m) G_ii / P2_j``; below ``1e-12`` the
        basis degrades and the residual can blow up (seen at ``1e-13`` on the
        pendulum), which the divergence rule catches.
    validation
        Optional ``(val_functionals, val_targets)``; then ``E_val(m)`` is recorded.
    memory_limit
        Bytes the Newton basis may use; default 90% of available memory.
        Checked before any work, with a message saying what fits.
    basis_dtype
        ``'float64'`` (the exact greedy) or ``'float32'`` (:class:`DenseStore`).
    keep_basis
        Return the Newton basis in :attr:`GreedyResult.basis` (benchmarks).
    regularization
        Ridge term ``lambda >= 0``: the Newton basis of ``G + lambda I`` (noisy
        data, :class:`DenseStore`); ``0`` is the exact interpolation.

    Returns
    -------
    GreedyResult

    Notes
    -----
    Time ``O(m^2 (N + N_val) / 2)`` memory traffic, memory ``itemsize m_max (N + N_val)``
    bytes (:mod:`sympredict.interpolation.greedy.dense`).
    """
    trainer = ExactGreedy(
        basis_dtype,
        tol=tol,
        criterion=criterion,
        power_tol=power_tol,
        memory_limit=memory_limit,
        regularization=regularization,
    )
    return trainer.run(
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
    tol: float = 1e-10,
    power_tol: float = 1e-12,
    divergence_factor: float = 100.0,
    validation: Optional[tuple] = None,
    memory_limit: Optional[float] = None,
    log_every: int = 100,
    initial_points: int = 8192,
    refresh_every: int = 200,
    max_new_points: int = 4096,
    margin: float = 0.7,
    refresh_fraction: float = 0.25,
    seed: int = 0,
) -> GreedyResult:
    """Fast f-greedy on an active subset of the points, refreshed against the full residual (:class:`ActiveSetStore`).

    Arguments as in :func:`greedy_interpolation` (f-greedy, one output) and
    :class:`~sympredict.interpolation.greedy.active_set.ActiveSetStore`.  ``history.train_max_residual[k]`` is the active
    set's maximum after ``k`` centres, except the last entry: the full maximum
    over all ``N`` candidates; ``'tol'`` only if that full maximum is at or below ``tol``.
    """
    trainer = ActiveSetGreedy(
        initial_points,
        refresh_every,
        max_new_points,
        margin,
        refresh_fraction,
        seed,
        tol=tol,
        power_tol=power_tol,
        memory_limit=memory_limit,
    )
    return trainer.run(
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
    tol: float = 1e-10,
    criterion: str = "f",
    power_tol: float = 1e-12,
    divergence_factor: float = 100.0,
    validation: Optional[tuple] = None,
    pool=None,
    n_shards: Optional[int] = None,
    memory_limit_per_rank: Optional[float] = None,
    timeout: Optional[float] = 60.0,
    log_every: int = 100,
    callback: Optional[Callable[[int, float], None]] = None,
    stats: Optional[dict] = None,
    regularization: float = 0.0,
) -> GreedyResult:
    """f-greedy (or P-greedy) with the candidates sharded over a pyMOR worker pool (:class:`~sympredict.interpolation.greedy.sharded.ShardedStore`).

    Same arguments and result as :func:`greedy_interpolation` (same selection
    and coefficients), plus the store's ``pool``, ``n_shards``,
    ``memory_limit_per_rank``, ``timeout`` and ``regularization``; ``callback(m, E_train(m))``
    after each step; ``stats``, a dict filled with the pool timings
    (the store's ``stats``).

    Raises
    ------
    ValueError
        Bad arguments, or a worker's basis over its memory limit (names the rank).
    sympredict.parallel.WorkerError
        Any other exception on a worker (names the rank, carries the remote traceback).
    """
    trainer = ShardedGreedy(
        pool,
        n_shards,
        memory_limit_per_rank,
        timeout,
        tol=tol,
        criterion=criterion,
        power_tol=power_tol,
        regularization=regularization,
    )
    result = trainer.run(
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
