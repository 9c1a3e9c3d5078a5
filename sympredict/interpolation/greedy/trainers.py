"""Training strategies: how an estimator runs the greedy (one loop, different stores).

An estimator takes a strategy as its ``trainer`` parameter
(``SymplecticKernelPredictor(..., trainer=ActiveSetGreedy(refresh_every=100))``);
its ``fit`` builds the candidate functionals and calls :meth:`Trainer.run`,
which builds a store and runs :func:`~sympredict.interpolation.greedy.loop.run_greedy`.

=========================  ======================================  ======================================
strategy                   store                                   use it for
=========================  ======================================  ======================================
:class:`ExactGreedy`       all candidates in memory (float64 or    the exact f-/P-greedy (default)
                           float32 basis)
:class:`ActiveSetGreedy`   an active subset, refreshed against     large data, a residual target ``tol``
                           the full residual                       (f-greedy, HB functionals)
:class:`ShardedGreedy`     shards on a pyMOR worker pool (MPI)     data whose basis exceeds one node
=========================  ======================================  ======================================

A strategy that cannot combine with a setting (a P-greedy on the active set,
a float32 basis on shards) raises ``ValueError`` when the run starts.  A new
strategy is a :class:`Trainer` subclass with a ``store`` method; register it
with :func:`register_trainer` so that model files can name it.
"""

from __future__ import annotations

from typing import Optional

from pymor.core.logger import getLogger

from sympredict.base import Parametrized
from sympredict.interpolation.functionals import HBFunctionals
from sympredict.interpolation.greedy.active_set import ActiveSetStore
from sympredict.interpolation.greedy.dense import DenseStore
from sympredict.interpolation.greedy.loop import GreedyResult, run_greedy
from sympredict.interpolation.greedy.sharded import ShardedStore

__all__ = ["Trainer", "ExactGreedy", "ActiveSetGreedy", "ShardedGreedy", "TRAINERS", "register_trainer", "trainer_from_spec"]

logger = getLogger("sympredict.interpolation.greedy")

#: The training strategies by class name (as written in model files).
TRAINERS: dict = {}


def register_trainer(cls):
    """Class decorator: make a :class:`Trainer` subclass known to model files by its class name."""
    TRAINERS[cls.__name__] = cls
    return cls


class Trainer(Parametrized):
    """A training strategy: builds the store the greedy loop runs on."""

    def store(self, functionals, targets, *, criterion: str, power_tol: float, tol: float,
              validation: Optional[tuple], memory_limit: Optional[float], regularization: float = 0.0):
        """The :class:`~sympredict.interpolation.greedy.loop.NewtonBasisStore` for these candidates and settings.

        ``regularization`` is the ridge term ``lambda`` (the Newton basis of
        ``G + lambda I``, :class:`~sympredict.interpolation.greedy.dense.DenseStore`); a
        strategy that has no regularized store raises ``ValueError`` for
        ``lambda > 0``; :meth:`run` passes the keyword only when ``lambda > 0``.
        """
        raise NotImplementedError

    def run(self, functionals, targets, *, max_centers: int, tol: float = 1e-10, criterion: str = "f",
            power_tol: float = 1e-12, validation: Optional[tuple] = None, memory_limit: Optional[float] = None,
            divergence_factor: float = 100.0, log_every: int = 100, callback=None,
            regularization: float = 0.0) -> GreedyResult:
        """Greedy selection over ``functionals`` with this strategy's store (:func:`run_greedy`)."""
        # passed only when set: strategies written before the option (store without the keyword) keep working
        extra = {"regularization": regularization} if regularization else {}
        try:
            store = self.store(functionals, targets, criterion=criterion, power_tol=power_tol, tol=tol,
                               validation=validation, memory_limit=memory_limit, **extra)
        except TypeError as exc:
            if extra and "regularization" in str(exc):
                raise ValueError(f"the training strategy {type(self).__name__} does not support regularization > 0") from None
            raise
        with logger.block(f"{store.label} over {functionals.n_functionals} functionals"):
            return run_greedy(store, max_centers=max_centers, tol=tol, criterion=criterion,
                              divergence_factor=divergence_factor, log_every=log_every, callback=callback)

    @property
    def spec(self) -> dict:
        """``{'name': class name, 'params': {...}}`` for model files (see :func:`trainer_from_spec`)."""
        return {"name": type(self).__name__, "params": self.get_params(deep=False)}


@register_trainer
class ExactGreedy(Trainer):
    """The exact f-greedy (or P-greedy) over all candidates (:class:`~sympredict.interpolation.greedy.dense.DenseStore`).

    Parameters
    ----------
    basis_dtype
        ``'float64'`` (default: the exact greedy) or ``'float32'``: half the
        memory and memory traffic; each stored row carries a relative error of
        ``~6e-8`` (on the pendulum with IMQ 0.15 the float32 basis loses the
        power function after ~300 centres and the run stops as ``'diverged'``).
    """

    def __init__(self, basis_dtype: str = "float64"):
        self.basis_dtype = basis_dtype

    def store(self, functionals, targets, *, criterion, power_tol, tol, validation, memory_limit, regularization=0.0):
        return DenseStore(functionals, targets, criterion=criterion, power_tol=power_tol, validation=validation,
                          memory_limit=memory_limit, basis_dtype=self.basis_dtype, regularization=regularization)


@register_trainer
class ActiveSetGreedy(Trainer):
    """f-greedy on an active subset of the samples, refreshed against the full residual.

    (:class:`~sympredict.interpolation.greedy.active_set.ActiveSetStore`, whose docstring
    describes the parameters.)  The run stops when the max residual over *all*
    functionals reaches ``tol`` (or at ``max_centers``); memory ``O(m N_active)``
    instead of ``O(m N)``.  Scenario A (688,464 functionals, ``tol=1e-5``)
    trains in a fraction of the exact greedy's time (``docs/performance.md``).
    """

    def __init__(self, initial_points: int = 8192, refresh_every: int = 200, max_new_points: int = 4096,
                 margin: float = 0.7, refresh_fraction: float = 0.25, seed: int = 0):
        self.initial_points = initial_points
        self.refresh_every = refresh_every
        self.max_new_points = max_new_points
        self.margin = margin
        self.refresh_fraction = refresh_fraction
        self.seed = seed

    def store(self, functionals, targets, *, criterion, power_tol, tol, validation, memory_limit, regularization=0.0):
        if regularization:
            raise ValueError("ActiveSetGreedy has no regularized store: use ExactGreedy() or ShardedGreedy() "
                             "with regularization > 0")
        if criterion != "f":
            raise ValueError(f"ActiveSetGreedy is an f-greedy: use criterion='f' (got {criterion!r}) or ExactGreedy()")
        if not isinstance(functionals, HBFunctionals):
            raise ValueError("ActiveSetGreedy needs state-derivative functionals (the symplectic predictor): "
                             "use ExactGreedy() or ShardedGreedy() for the direct model")
        return ActiveSetStore(functionals, targets, tol=tol, power_tol=power_tol, validation=validation,
                              memory_limit=memory_limit, **self.get_params(deep=False))


@register_trainer
class ShardedGreedy(Trainer):
    """The exact greedy with the candidates sharded over a pyMOR worker pool (:class:`~sympredict.interpolation.greedy.sharded.ShardedStore`).

    Selects exactly the serial greedy's centres (same coefficients bit for
    bit); ``O(m N / P)`` work and memory per worker.

    Parameters
    ----------
    pool
        pyMOR |WorkerPool| (``MPIPool`` under ``mpiexec``); ``None``: the dummy pool.
        :func:`~sympredict.base.clone` keeps the pool (it is shared, never copied);
        model files store ``None``.
    n_shards, memory_limit_per_rank, timeout
        See :class:`~sympredict.interpolation.greedy.sharded.ShardedStore`.

    Notes
    -----
    The estimator's ``memory_limit`` does not apply (each worker checks
    ``memory_limit_per_rank``).  The last run's pool timings are in the
    result's store statistics (``model.greedy_result_.stats``).
    """

    def __init__(self, pool=None, n_shards: Optional[int] = None, memory_limit_per_rank: Optional[float] = None,
                 timeout: Optional[float] = 60.0):
        self.pool = pool
        self.n_shards = n_shards
        self.memory_limit_per_rank = memory_limit_per_rank
        self.timeout = timeout

    def __sklearn_clone__(self):
        params = self.get_params(deep=False)
        return type(self)(**params)  # the same pool object: a pool is a connection, not a setting

    def store(self, functionals, targets, *, criterion, power_tol, tol, validation, memory_limit, regularization=0.0):
        return ShardedStore(functionals, targets, criterion=criterion, power_tol=power_tol, validation=validation,
                            pool=self.pool, n_shards=self.n_shards, memory_limit_per_rank=self.memory_limit_per_rank,
                            timeout=self.timeout, regularization=regularization)

    @property
    def spec(self) -> dict:
        params = self.get_params(deep=False)
        params["pool"] = None
        return {"name": type(self).__name__, "params": params}


def trainer_from_spec(spec: Optional[dict]) -> Trainer:
    """Rebuild a strategy from :attr:`Trainer.spec` (``None``: the default :class:`ExactGreedy`)."""
    if spec is None:
        return ExactGreedy()
    try:
        cls = TRAINERS[spec["name"]]
        return cls(**spec["params"])
    except (KeyError, TypeError) as exc:
        raise ValueError(f"unknown or invalid training strategy {spec!r}; known: {sorted(TRAINERS)} ({exc})") from None
