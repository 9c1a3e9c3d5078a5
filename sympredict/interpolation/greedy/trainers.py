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

import inspect
import warnings
from typing import Optional

import numpy as np

from pymor.core.logger import getLogger

from sympredict.base import Setting
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


class Trainer(Setting):
    """A training strategy: owns the greedy's settings and builds the store the greedy loop runs on.

    Every strategy has ``tol`` (stop when the max training residual is at or
    below it; the estimator makes it relative to the data's scale for data in
    small units) and ``power_tol`` (the breakdown guard, relative to the Gramian
    diagonal); strategies that can, also ``criterion`` (``'f'``: f-greedy,
    ``'p'``: P-greedy), ``memory_limit`` (bytes for the Newton basis) and
    ``regularization`` (the ridge term ``lambda``).  A strategy lacks a setting it
    cannot run, so a combination it cannot run cannot be written.
    """

    tol: float = 1e-10
    power_tol: float = 1e-12
    criterion: str = "f"
    memory_limit: Optional[float] = None
    regularization: float = 0.0

    def check(self) -> "Trainer":
        """``ValueError`` naming the setting that is malformed; returns ``self``."""
        for name in ("tol", "power_tol", "regularization"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)) \
                    or not (np.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be a finite non-negative float, got {value!r}")
        if not self.power_tol < 1:
            raise ValueError(f"power_tol must be below 1 (relative to the Gramian diagonal), got {self.power_tol!r}")
        if self.criterion not in ("f", "p"):
            raise ValueError(f"criterion must be 'f' (f-greedy) or 'p' (P-greedy), got {self.criterion!r}")
        limit = self.memory_limit
        if limit is not None and (isinstance(limit, bool) or not isinstance(limit, (int, float, np.number))
                                  or not (np.isfinite(limit) and limit > 0)):
            raise ValueError(f"memory_limit must be None or a positive number of bytes, got {limit!r}")
        return self

    def store(self, functionals, targets, *, tol: float, validation: Optional[tuple]):
        """The :class:`~sympredict.interpolation.greedy.loop.NewtonBasisStore` for these candidates (this strategy's settings)."""
        raise NotImplementedError

    def run(self, functionals, targets, *, max_centers: int, validation: Optional[tuple] = None,
            tol_scale: float = 1.0, divergence_factor: float = 100.0, log_every: int = 100,
            callback=None) -> GreedyResult:
        """Greedy selection over ``functionals`` with this strategy's store (:func:`run_greedy`).

        ``tol_scale`` multiplies ``tol`` (the estimator's rule for data in small units).
        """
        self.check()
        tol = float(self.tol) * float(tol_scale)
        if "criterion" in inspect.signature(self.store).parameters:  # a strategy written for sympredict 0.1
            warnings.warn(f"{type(self).__name__}.store(functionals, targets, *, criterion, power_tol, tol, validation, "
                          "memory_limit) is the signature of sympredict 0.1: define store(functionals, targets, *, tol, "
                          "validation) and read the settings from self", FutureWarning, stacklevel=3)
            if self.regularization:
                raise ValueError(f"the training strategy {type(self).__name__} does not support regularization > 0")
            store = self.store(functionals, targets, criterion=self.criterion, power_tol=self.power_tol, tol=tol,
                               validation=validation, memory_limit=self.memory_limit)
        else:
            store = self.store(functionals, targets, tol=tol, validation=validation)
        with logger.block(f"{store.label} over {functionals.n_functionals} functionals"):
            return run_greedy(store, max_centers=max_centers, tol=tol, criterion=self.criterion,
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
    tol
        Stop when the max training residual is at or below ``tol`` (the
        estimator scales it down for data in small units, see its ``fit``).
    criterion
        ``'f'`` (f-greedy, default) or ``'p'`` (P-greedy).
    power_tol
        Breakdown guard, relative to the Gramian diagonal.
    memory_limit
        Bytes the Newton basis may use (default: 90% of the available memory).
    regularization
        Ridge term ``lambda >= 0`` for noisy data: the Newton basis of
        ``G + lambda I``, so the coefficients solve ``(G_sel + lambda I) c = y_sel``
        on the selected centres instead of interpolating them.  ``0`` (default):
        exact interpolation.  Choose it on validation data
        (:func:`sympredict.estimators.selection.select_regularization`).
    """

    def __init__(self, basis_dtype: str = "float64", *, tol: float = 1e-10, criterion: str = "f",
                 power_tol: float = 1e-12, memory_limit: Optional[float] = None, regularization: float = 0.0):
        self.tol = tol
        self.criterion = criterion
        self.power_tol = power_tol
        self.memory_limit = memory_limit
        self.regularization = regularization
        self.basis_dtype = basis_dtype

    def store(self, functionals, targets, *, tol, validation):
        return DenseStore(functionals, targets, criterion=self.criterion, power_tol=self.power_tol, validation=validation,
                          memory_limit=self.memory_limit, basis_dtype=self.basis_dtype,
                          regularization=float(self.regularization))


@register_trainer
class ActiveSetGreedy(Trainer):
    """f-greedy on an active subset of the samples, refreshed against the full residual.

    (:class:`~sympredict.interpolation.greedy.active_set.ActiveSetStore`, whose docstring
    describes the parameters; ``tol``, ``power_tol`` and ``memory_limit`` as for
    :class:`ExactGreedy`.  An f-greedy without regularization: it has neither
    ``criterion`` nor ``regularization``.)  The run stops when the max residual over *all*
    functionals reaches ``tol`` (or at ``max_centers``); memory ``O(m N_active)``
    instead of ``O(m N)``.  Scenario A (688,464 functionals, ``tol=1e-5``)
    trains in a fraction of the exact greedy's time (``docs/explanation/performance.md``).
    """

    def __init__(self, initial_points: int = 8192, refresh_every: int = 200, max_new_points: int = 4096,
                 margin: float = 0.7, refresh_fraction: float = 0.25, seed: int = 0, *, tol: float = 1e-10,
                 power_tol: float = 1e-12, memory_limit: Optional[float] = None):
        self.tol = tol
        self.power_tol = power_tol
        self.memory_limit = memory_limit
        self.initial_points = initial_points
        self.refresh_every = refresh_every
        self.max_new_points = max_new_points
        self.margin = margin
        self.refresh_fraction = refresh_fraction
        self.seed = seed

    def store(self, functionals, targets, *, tol, validation):
        if not isinstance(functionals, HBFunctionals):
            raise ValueError("ActiveSetGreedy needs state-derivative functionals (the symplectic predictor): "
                             "use ExactGreedy() or ShardedGreedy() for the direct model")
        own = {k: v for k, v in self.get_params(deep=False).items() if k not in ("tol", "power_tol", "memory_limit")}
        return ActiveSetStore(functionals, targets, tol=tol, power_tol=self.power_tol, validation=validation,
                              memory_limit=self.memory_limit, **own)


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
    ``tol``, ``criterion``, ``power_tol``, ``regularization``: as for
    :class:`ExactGreedy`; there is no ``memory_limit`` (each worker checks
    ``memory_limit_per_rank``).  The last run's pool timings are in the
    result's store statistics (``model.greedy_result_.stats``).
    """

    def __init__(self, pool=None, n_shards: Optional[int] = None, memory_limit_per_rank: Optional[float] = None,
                 timeout: Optional[float] = 60.0, *, tol: float = 1e-10, criterion: str = "f",
                 power_tol: float = 1e-12, regularization: float = 0.0):
        self.pool = pool
        self.tol = tol
        self.criterion = criterion
        self.power_tol = power_tol
        self.regularization = regularization
        self.n_shards = n_shards
        self.memory_limit_per_rank = memory_limit_per_rank
        self.timeout = timeout

    def check(self) -> "ShardedGreedy":
        """As :meth:`Trainer.check`, and ``pool`` must be a pyMOR worker pool (or ``None``)."""
        super().check()
        if self.pool is not None and not all(callable(getattr(self.pool, a, None)) for a in ("apply", "map", "push")):
            raise ValueError(f"pool must be a pyMOR WorkerPool (e.g. pymor.parallel.mpi.MPIPool() under mpiexec) or "
                             f"None (the in-process dummy pool), got {self.pool!r}")
        return self

    def __sklearn_clone__(self):
        params = self.get_params(deep=False)
        return type(self)(**params)  # the same pool object: a pool is a connection, not a setting

    def store(self, functionals, targets, *, tol, validation):
        return ShardedStore(functionals, targets, criterion=self.criterion, power_tol=self.power_tol,
                            validation=validation, pool=self.pool, n_shards=self.n_shards,
                            memory_limit_per_rank=self.memory_limit_per_rank, timeout=self.timeout,
                            regularization=float(self.regularization))

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
