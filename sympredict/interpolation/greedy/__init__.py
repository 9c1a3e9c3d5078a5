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

import inspect
from typing import Optional

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


def greedy_interpolation(functionals, targets, *, max_centers: int, **arguments) -> GreedyResult:
    """Sparse generalized interpolation by f-greedy (or P-greedy) selection, all candidates in memory.

    ``ExactGreedy(**settings).run(...)``: the strategy the estimators take, run once on explicit arguments
    (the keyword arguments that are :class:`ExactGreedy`'s settings make the strategy, the others go to
    :meth:`Trainer.run`).

    Parameters
    ----------
    functionals
        The ``N`` candidate functionals (:mod:`sympredict.interpolation.functionals`).
    targets : ndarray of shape (N,) or (N, q)
        Data ``y_i = lambda_i(f)``; ``q > 1`` interpolates ``q`` outputs with
        shared centres (selection by the max over outputs).
    max_centers : int
        Upper bound on the number of selected functionals.
    **arguments
        :meth:`Trainer.run`'s arguments: ``validation=None`` (optional ``(val_functionals, val_targets)``;
        then ``E_val(m)`` is recorded), ``divergence_factor=100.0`` (blow-up factor of the residual that stops
        and truncates the run, :func:`~sympredict.interpolation.greedy.loop.run_greedy`), ``log_every=100``
        (log progress every this many steps), ``keep_basis=False`` (return the Newton basis in
        :attr:`GreedyResult.basis`; benchmarks), ``callback=None``; and the settings of
        :class:`ExactGreedy`, which checks them: ``tol=1e-10``, ``criterion='f'``, ``power_tol=1e-12``,
        ``memory_limit=None``, ``basis_dtype='float64'``, ``regularization=0.0``.

    Returns
    -------
    GreedyResult

    Raises
    ------
    TypeError
        A keyword argument that is neither a setting of the strategy nor an argument of :meth:`Trainer.run`
        (the message lists both).

    Notes
    -----
    Time ``O(m^2 (N + N_val) / 2)`` memory traffic, memory ``itemsize m_max (N + N_val)``
    bytes (:mod:`sympredict.interpolation.greedy.dense`).
    """
    return _run_strategy(ExactGreedy, "greedy_interpolation", functionals, targets, max_centers, arguments)


def active_set_greedy(functionals, targets, *, max_centers: int, **arguments) -> GreedyResult:
    """Fast f-greedy on an active subset of the points, refreshed against the full residual (:class:`ActiveSetStore`).

    ``ActiveSetGreedy(**settings).run(...)``.  Arguments as in :func:`greedy_interpolation`, with the settings of
    :class:`ActiveSetGreedy` (``initial_points``, ``refresh_every``, ``max_new_points``, ``margin``,
    ``refresh_fraction``, ``seed``, ``tol``, ``power_tol``, ``memory_limit``).  ``history.train_max_residual[k]``
    is the active set's maximum after ``k`` centres, except the last entry: the full maximum over all ``N``
    candidates; ``'tol'`` only if that full maximum is at or below ``tol``.
    """
    return _run_strategy(ActiveSetGreedy, "active_set_greedy", functionals, targets, max_centers, arguments)


def sharded_greedy(
    functionals, targets, *, max_centers: int, stats: Optional[dict] = None, **arguments
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
    result = _run_strategy(ShardedGreedy, "sharded_greedy", functionals, targets, max_centers, arguments)
    if stats is not None:
        stats.update(result.stats)
    return result


def _run_strategy(cls: type, caller: str, functionals, targets, max_centers: int, arguments: dict) -> GreedyResult:
    """``cls(**settings).run(functionals, targets, max_centers=max_centers, **rest)``: ``arguments`` split into the
    strategy's settings (its ``__init__`` parameters) and :meth:`Trainer.run`'s arguments; ``TypeError`` naming
    ``caller`` for any other keyword."""
    names = set(cls().get_params(deep=False))  # the strategy's settings (its defaults' names)
    run_names = set(inspect.signature(Trainer.run).parameters) - {"self", "functionals", "targets", "max_centers"}
    unknown = sorted(set(arguments) - names - run_names)
    if unknown:
        raise TypeError(
            f"{caller}() got unexpected keyword arguments {unknown}; {cls.__name__}'s settings are "
            f"{sorted(names)}, the run's arguments {sorted(run_names)}"
        )
    settings = {k: v for k, v in arguments.items() if k in names}
    rest = {k: v for k, v in arguments.items() if k not in names}
    return cls(**settings).run(functionals, targets, max_centers=max_centers, **rest)
