"""Training strategies: how an estimator runs the greedy (one loop, different stores).

An estimator takes a strategy as its ``trainer`` parameter
(``SymplecticKernelPredictor(..., trainer=ActiveSetGreedy(refresh_every=100))``);
its ``fit`` builds the candidate functionals and calls :meth:`Trainer.run`,
which builds a store and runs :func:`~sympredict.interpolation.greedy.loop.run_greedy`.

=================================  ======================================  ======================================
strategy                           store                                   use it for
=================================  ======================================  ======================================
:class:`ExactGreedy`               all candidates in memory (float64 or    the exact f-/P-greedy (default)
                                   float32 basis)
:class:`ActiveSetGreedy`           an active subset, refreshed against     large data, a residual target ``tol``
                                   the full residual                       (f-greedy, HB functionals)
:class:`ShardedGreedy`             shards on a pyMOR worker pool (MPI)     data whose basis exceeds one node
:class:`BlockedGreedy`             all candidates in memory, grown by      the f-/P-greedy at the arithmetic rate
                                   blocks of centres (matrix products)     (large ``N`` and ``m``)
:class:`BoundedActiveSetGreedy`    the blocked greedy on slots sized to    a basis larger than the memory
                                   the budget, refreshed against every     (the default there; f-greedy, HB
                                   candidate in chunks                     functionals)
=================================  ======================================  ======================================

Peak memory of the stores (bytes; ``N``, ``N_val``: training and validation
functionals, ``m``: ``max_centers``, ``b``: block size, ``c``: pool factor, ``N_S``:
active functionals, ``P``: shards; :func:`trainer_memory` evaluates them):

* :class:`ExactGreedy`: ``itemsize m (N + N_val)`` (``itemsize`` 8, or 4 for a float32 basis);
* :class:`BlockedGreedy`: ``8 ((m + b) (N + N_val) + (c b)^2)``;
* :class:`ActiveSetGreedy`: ``8 m (N_S + N_val)``, ``N_S <= 2n (initial_points + max_new_points m / refresh_every)``;
* :class:`ShardedGreedy`: ``8 m (N + N_val) / P`` per worker;
* :class:`BoundedActiveSetGreedy`: ``8 [(m + b) (S + N_val) + c b (c b (2n + 1) + m) + m K + 2 m^2 + 4 S + 6 N]``
  for ``S`` slot functionals sized so that this is at most ``memory_limit`` (``K``: the refresh chunk,
  ``8 m K <= 32 MiB``; this formula counts the Cholesky factor and the vectors too).

The others add ``O(m^2)`` for the Cholesky factor and ``O(N)`` vectors.

A strategy that cannot combine with a setting (a P-greedy on the active set,
a float32 basis on shards) raises ``ValueError`` when the run starts.  A new
strategy is a :class:`Trainer` subclass with a ``store`` method; register it
with :func:`register_trainer` so that model files can name it.
"""

from __future__ import annotations

from dataclasses import KW_ONLY, dataclass, fields
from typing import ClassVar, Optional

import numpy as np

from pymor.core.logger import getLogger

from sympredict.base import Setting
from sympredict.interpolation.functionals import HBFunctionals
from sympredict.interpolation.greedy.active_set import (
    ActiveSetStore,
    BoundedActiveSetStore,
    bounded_capacity,
    bounded_memory,
)
from sympredict.interpolation.greedy.blocked import BlockedStore, blocked_memory
from sympredict.interpolation.greedy.dense import DenseStore
from sympredict.interpolation.greedy.loop import GreedyResult, available_memory, format_bytes, run_greedy
from sympredict.interpolation.greedy.sharded import ShardedStore

__all__ = [
    "Trainer",
    "ExactGreedy",
    "ActiveSetGreedy",
    "ShardedGreedy",
    "BlockedGreedy",
    "BoundedActiveSetGreedy",
    "trainer_memory",
    "memory_budget",
    "default_trainer",
    "TRAINERS",
    "register_trainer",
    "trainer_from_spec",
]

logger = getLogger("sympredict.interpolation.greedy")

#: The training strategies by class name (as written in model files).
TRAINERS: dict = {}


def register_trainer(cls):
    """Class decorator: make a :class:`Trainer` subclass known to model files by its class name."""
    TRAINERS[cls.__name__] = cls
    return cls


@dataclass(eq=False, repr=False, kw_only=True)
class Trainer(Setting):
    """A training strategy: owns the greedy's settings and builds the store the greedy loop runs on.

    Every strategy has ``tol`` (stop when the max training residual is at or
    below it; the estimator makes it relative to the data's scale for data in
    small units), ``power_tol`` (the breakdown guard, relative to the Gramian
    diagonal) and ``target_error``, declared here once as keyword-only settings;
    strategies that can, also ``criterion`` (``'f'``: f-greedy, ``'p'``: P-greedy),
    ``memory_limit`` (bytes for the Newton basis) and ``regularization`` (the ridge
    term ``lambda``), declared by each such strategy.  A strategy lacks a setting it
    cannot run, so a combination it cannot run cannot be written.

    The strategies are dataclasses (``eq=False, repr=False``: equality and ``repr`` are
    :class:`~sympredict.base.Setting`'s): the generated ``__init__`` only stores, its arguments are the
    settings (:meth:`~sympredict.base.Parametrized.get_params`), a strategy's own settings positional
    first, the shared ones keyword-only.
    """

    tol: float = 1e-10
    power_tol: float = 1e-12
    #: Accuracy on demand: the median relative one-step error on held-out samples the estimator grows the
    #: model to (``None``: no target, the size is ``max_centers``); read by the estimator's fit.
    target_error: Optional[float] = None
    #: What a strategy without the setting runs with (an f-greedy, its basis unbounded but checked, no ridge).
    criterion: ClassVar[str] = "f"
    memory_limit: ClassVar[Optional[float]] = None
    regularization: ClassVar[float] = 0.0

    def check(self) -> "Trainer":
        """``ValueError`` naming the setting that is malformed; returns ``self``."""
        for name in ("tol", "power_tol", "regularization"):
            value = getattr(self, name)
            if (
                isinstance(value, bool)
                or not isinstance(value, (int, float, np.floating, np.integer))
                or not (np.isfinite(value) and value >= 0)
            ):
                raise ValueError(f"{name} must be a finite non-negative float, got {value!r}")
        if not self.power_tol < 1:
            raise ValueError(f"power_tol must be below 1 (relative to the Gramian diagonal), got {self.power_tol!r}")
        if self.criterion not in ("f", "p"):
            raise ValueError(f"criterion must be 'f' (f-greedy) or 'p' (P-greedy), got {self.criterion!r}")
        target = self.target_error
        if target is not None and (
            isinstance(target, bool)
            or not isinstance(target, (int, float, np.floating))
            or not (np.isfinite(target) and target > 0)
        ):
            raise ValueError(
                f"target_error must be a positive float (a relative one-step error such as 1e-4) or None, "
                f"got {target!r}"
            )
        limit = self.memory_limit
        if limit is not None and (
            isinstance(limit, bool)
            or not isinstance(limit, (int, float, np.number))
            or not (np.isfinite(limit) and limit > 0)
        ):
            raise ValueError(f"memory_limit must be None or a positive number of bytes, got {limit!r}")
        return self

    def store(self, functionals, targets, *, tol: float, validation: Optional[tuple]):
        """The :class:`~sympredict.interpolation.greedy.loop.NewtonBasisStore` for these candidates (this strategy's settings)."""
        raise NotImplementedError

    def store_settings(self, validation: Optional[tuple]) -> dict:
        """The keyword arguments a store takes from its strategy: ``power_tol``, ``validation``; ``criterion``,
        ``memory_limit`` and ``regularization`` where they are among the strategy's settings (an f-greedy-only
        strategy has no ``criterion``, a sharded one a memory limit per rank instead); and the strategy's own
        settings, its positional fields (``basis_dtype``, ``block_size``, ...), which are its store's."""
        params = self.get_params(deep=False)
        shared = {name: params[name] for name in ("criterion", "memory_limit") if name in params}
        if "regularization" in params:
            shared["regularization"] = float(params["regularization"])
        own = {f.name: getattr(self, f.name) for f in fields(self) if not f.kw_only}
        return {"power_tol": self.power_tol, "validation": validation, **shared, **own}

    def run(
        self,
        functionals,
        targets,
        *,
        max_centers: int,
        validation: Optional[tuple] = None,
        tol_scale: float = 1.0,
        divergence_factor: float = 100.0,
        log_every: int = 100,
        callback=None,
        checkpoints=None,
        keep_basis: bool = False,
    ) -> GreedyResult:
        """Greedy selection over ``functionals`` with this strategy's store (:func:`run_greedy`).

        ``tol_scale`` multiplies ``tol`` (the estimator's rule for data in small units); ``checkpoints``
        scores prefixes (held-out errors: the target stop and the best prefix, :func:`run_greedy`);
        ``keep_basis``: the selected centres' Newton basis rows in ``result.basis`` (:class:`ExactGreedy`
        only, whose store holds the basis of every candidate).
        """
        self.check()
        if keep_basis and not isinstance(self, ExactGreedy):
            raise ValueError(
                f"keep_basis needs ExactGreedy (the whole Newton basis in memory), not {type(self).__name__}"
            )
        tol = float(self.tol) * float(tol_scale)
        store = self.store(functionals, targets, tol=tol, validation=validation)
        with logger.block(f"{store.label} over {functionals.n_functionals} functionals"):
            result = run_greedy(
                store,
                max_centers=max_centers,
                tol=tol,
                criterion=self.criterion,
                divergence_factor=divergence_factor,
                log_every=log_every,
                callback=callback,
                checkpoints=checkpoints,
            )
        if keep_basis:
            result.basis = store.basis[: len(result.selected)]
        return result

    @property
    def spec(self) -> dict:
        """``{'name': class name, 'params': {...}}`` for model files (see :func:`trainer_from_spec`)."""
        return {"name": type(self).__name__, "params": self.get_params(deep=False)}


@register_trainer
@dataclass(eq=False, repr=False)
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
        Breakdown guard, relative to the Gramian diagonal: candidates with ``P2_i <= power_tol * max(G_ii)``
        are never selected; when none is left the run stops with reason ``'power'``.  The new basis column
        carries a relative error of about ``eps_mach sqrt(m) G_ii / P2_j``; below ``1e-12`` the basis degrades
        and the residual can blow up (seen at ``1e-13`` on the pendulum), which the divergence rule catches.
    memory_limit
        Bytes the Newton basis may use (default: 90% of the available memory), checked before any work with
        a message saying what fits.
    regularization
        Ridge term ``lambda >= 0`` for noisy data: the Newton basis of
        ``G + lambda I``, so the coefficients solve ``(G_sel + lambda I) c = y_sel``
        on the selected centres instead of interpolating them.  ``0`` (default):
        exact interpolation.  Choose it on validation data
        (:func:`sympredict.estimators.selection.select_regularization`).
    target_error
        Accuracy on demand (read by :class:`~sympredict.SymplecticKernelPredictor`'s fit): grow the model
        until the median relative one-step error ``|Phi(x0) - x1| / |x1 - x0|`` on held-out samples is at
        most this, then stop (the estimator's ``max_centers`` stays the cap).  ``None`` (default): no target.

    Notes
    -----
    Peak memory ``itemsize m (N + N_val)`` bytes (``itemsize`` 8, 4 for float32; :func:`trainer_memory`),
    checked before the run; time ``O(m^2 (N + N_val))`` at memory bandwidth.
    """

    basis_dtype: str = "float64"
    _: KW_ONLY
    criterion: str = "f"
    memory_limit: Optional[float] = None
    regularization: float = 0.0

    def store(self, functionals, targets, *, tol, validation):
        return DenseStore(functionals, targets, **self.store_settings(validation))


@register_trainer
@dataclass(eq=False, repr=False)
class ActiveSetGreedy(Trainer):
    """f-greedy on an active subset of the samples, refreshed against the full residual.

    (:class:`~sympredict.interpolation.greedy.active_set.ActiveSetStore`, whose docstring
    describes the parameters; ``tol``, ``power_tol``, ``memory_limit`` and ``target_error`` as for
    :class:`ExactGreedy`.  An f-greedy without regularization: it has neither
    ``criterion`` nor ``regularization``.)  The run stops when the max residual over *all*
    functionals reaches ``tol`` (or at ``max_centers``); memory ``8 m (N_S + N_val)`` bytes for ``N_S``
    active functionals instead of ``8 m (N + N_val)``: first ``N_S = 2n min(M, initial_points + 4 max_new_points)``,
    grown by doubling while points join (:func:`trainer_memory`).  Scenario A (688,464 functionals, ``tol=1e-5``)
    trains in a fraction of the exact greedy's time (``docs/explanation/performance.md``).
    """

    initial_points: int = 8192
    refresh_every: int = 200
    max_new_points: int = 4096
    margin: float = 0.7
    refresh_fraction: float = 0.25
    seed: int = 0
    _: KW_ONLY
    memory_limit: Optional[float] = None

    def store(self, functionals, targets, *, tol, validation):
        if not isinstance(functionals, HBFunctionals):
            raise ValueError(
                "ActiveSetGreedy needs state-derivative functionals (the symplectic predictor): "
                "use ExactGreedy() or ShardedGreedy() for the direct model"
            )
        return ActiveSetStore(functionals, targets, tol=tol, **self.store_settings(validation))


@register_trainer
@dataclass(eq=False, repr=False)
class ShardedGreedy(Trainer):
    """The exact greedy with the candidates sharded over a pyMOR worker pool (:class:`~sympredict.interpolation.greedy.sharded.ShardedStore`).

    Selects exactly the serial greedy's centres (same coefficients bit for
    bit); ``O(m N / P)`` work and ``8 m (N + N_val) / P`` bytes per worker.

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
    ``tol``, ``criterion``, ``power_tol``, ``regularization``, ``target_error``: as for
    :class:`ExactGreedy`; there is no ``memory_limit`` (each worker checks
    ``memory_limit_per_rank``).  The last run's pool timings are in the
    result's store statistics (``model.greedy_result_.stats``).
    """

    pool: object = None
    n_shards: Optional[int] = None
    memory_limit_per_rank: Optional[float] = None
    timeout: Optional[float] = 60.0
    _: KW_ONLY
    criterion: str = "f"
    regularization: float = 0.0

    def check(self) -> "ShardedGreedy":
        """As :meth:`Trainer.check`, and ``pool`` must be a pyMOR worker pool (or ``None``)."""
        super().check()
        if self.pool is not None and not all(callable(getattr(self.pool, a, None)) for a in ("apply", "map", "push")):
            raise ValueError(
                f"pool must be a pyMOR WorkerPool (e.g. pymor.parallel.mpi.MPIPool() under mpiexec) or "
                f"None (the in-process dummy pool), got {self.pool!r}"
            )
        return self

    def __sklearn_clone__(self):
        params = self.get_params(deep=False)
        return type(self)(**params)  # the same pool object: a pool is a connection, not a setting

    def store(self, functionals, targets, *, tol, validation):
        return ShardedStore(functionals, targets, **self.store_settings(validation))

    @property
    def spec(self) -> dict:
        params = self.get_params(deep=False)
        params["pool"] = None
        return {"name": type(self).__name__, "params": params}


@dataclass(eq=False, repr=False)
class _BlockRule:
    """The block rule's settings, the first positional settings of :class:`BlockedGreedy` and
    :class:`BoundedActiveSetGreedy` (whose store grows :class:`BlockedStore`'s blocks): ``block_size``
    centres per block at most, a pool of ``pool_factor`` blocks, the weak greedy's ``slack``."""

    block_size: int = 64
    pool_factor: int = 4
    slack: float = 0.5


@register_trainer
@dataclass(eq=False, repr=False)
class BlockedGreedy(Trainer, _BlockRule):
    """The f-greedy (or P-greedy) grown by blocks of centres with matrix-matrix products (:class:`~sympredict.interpolation.greedy.blocked.BlockedStore`).

    How a block is chosen: the ``pool_factor * block_size`` candidates with the
    largest criterion form a pool; the greedy runs inside the pool on its
    residual Gramian (a pivoted Cholesky whose pivot is the pool's current
    argmax of ``|r|``, or of ``P2`` for the P-greedy), dropping candidates that
    became dependent, and stops after ``block_size`` centres or when the pool's
    leader falls below the best candidate left outside it.  The block's Newton
    basis rows then come from one Gramian-rows call, one matrix product and one
    triangular solve; the history is recorded per centre as for the exact greedy.
    Each of the block's centres is taken only while its criterion is at least
    ``1 - slack`` times the current maximum over all candidates (a weak greedy);
    otherwise a new block starts.  ``block_size=1`` or ``slack=0`` selects the
    exact greedy's centres (to round-off).

    Parameters
    ----------
    block_size
        Centres per block at most (``b``).
    pool_factor
        The pool's size in blocks (``c``).
    slack
        The weak greedy's slack: ``0`` the exact greedy's selection (slow: blocks
        break early), ``0.5`` (default) a block's centre is taken while its
        criterion is at least half the maximum.
    tol, criterion, power_tol, memory_limit, target_error
        As for :class:`ExactGreedy` (no ``regularization``, no float32 basis).

    Notes
    -----
    Time: the exact greedy's ``2 m N`` flops per centre in ``b``-column products
    (arithmetic-bound instead of bandwidth-bound) plus ``O(N q)`` per centre.
    Memory ``8 ((m + b) (N + N_val) + (c b)^2)`` bytes.
    """

    _: KW_ONLY
    criterion: str = "f"
    memory_limit: Optional[float] = None

    def store(self, functionals, targets, *, tol, validation):
        return BlockedStore(functionals, targets, **self.store_settings(validation))


@register_trainer
@dataclass(eq=False, repr=False)
class BoundedActiveSetGreedy(Trainer, _BlockRule):
    """The blocked f-greedy on an active set of bounded size, refreshed against every candidate (:class:`~sympredict.interpolation.greedy.active_set.BoundedActiveSetStore`).

    For data whose Newton basis ``8 m N`` exceeds the memory: the basis lives on ``S = 2n P`` slots,
    ``P`` the most points that fit the budget (:func:`~sympredict.interpolation.greedy.active_set.bounded_capacity`);
    the blocked greedy (:class:`BlockedGreedy`'s block rule) selects on them, and every ``refresh_every``
    centres the model is evaluated at all ``N`` candidates in chunks and the worst points outside replace the
    best-fitted ones inside.  Where every point fits, the run is :class:`BlockedGreedy`'s.

    Parameters
    ----------
    block_size, pool_factor, slack
        As for :class:`BlockedGreedy`.
    refresh_every
        Centres between two evaluations of every candidate (at least).
    max_new_points
        Points swapped in per refresh at most.
    tol, power_tol, target_error
        As for :class:`ExactGreedy` (an f-greedy without regularization: no ``criterion``, no ``regularization``).
    memory_limit
        The budget in bytes for everything :func:`~sympredict.interpolation.greedy.active_set.bounded_memory`
        counts (default :func:`memory_budget`: half the available memory); the slots are sized to it.

    Notes
    -----
    Peak memory ``8 [(m + b) (S + N_val) + c b (c b (2n + 1) + m) + m K + 2 m^2 + 4 S + 6 N]`` bytes
    (``K``: the refresh chunk, ``8 m K <= 32 MiB``), at most ``memory_limit`` by construction
    (:func:`trainer_memory`); time ``2 m S`` flops per centre in matrix products plus ``N m`` Gramian entries
    per refresh.
    """

    refresh_every: int = 256
    max_new_points: int = 1024
    _: KW_ONLY
    memory_limit: Optional[float] = None

    def budget(self) -> float:
        """The bytes the run may use: ``memory_limit``, or :func:`memory_budget`."""
        return memory_budget() if self.memory_limit is None else float(self.memory_limit)

    def capacity(self, n_train: int, n_val: int, max_centers: int, dim: int) -> int:
        """Points the slots hold within :meth:`budget` (:func:`~sympredict.interpolation.greedy.active_set.bounded_capacity`)."""
        m = min(int(max_centers), n_train)
        return bounded_capacity(
            self.budget(), m, n_train, n_val, dim, min(int(self.block_size), m), int(self.pool_factor)
        )

    def store(self, functionals, targets, *, tol, validation):
        if not isinstance(functionals, HBFunctionals):
            raise ValueError(
                "BoundedActiveSetGreedy needs state-derivative functionals (the symplectic predictor): "
                "use BlockedGreedy() for the direct model"
            )
        return BoundedActiveSetStore(
            functionals,
            targets,
            tol=tol,
            max_points=None,
            **{**self.store_settings(validation), "memory_limit": self.budget()},
        )


def memory_budget(fraction: float = 0.5) -> float:
    """Bytes a trainer sized to the machine may plan for: ``fraction`` of the available memory (``MemAvailable``
    in ``/proc/meminfo``, :func:`~sympredict.interpolation.greedy.loop.available_memory`)."""
    return fraction * available_memory()


def trainer_memory(
    trainer: Trainer, n_train: int, n_val: int, max_centers: int, dim: int = 1, initial: bool = False
) -> float:
    """Peak bytes of ``trainer``'s store for ``n_train`` training and ``n_val`` validation functionals (module docstring).

    ``dim``: functionals per point (``2n`` for the state-derivative functionals; the active set's size).
    For :class:`ActiveSetGreedy` the bound assumes every refresh adds ``max_new_points``; ``initial=True``
    gives its first allocation ``8 m (2n min(M, initial_points + 4 max_new_points) + N_val)`` instead (the
    active set then grows by doubling, up to three times the grown size while it copies).
    """
    m = int(max_centers)
    if isinstance(trainer, BlockedGreedy):
        b = min(int(trainer.block_size), m)
        return float(blocked_memory(m, n_train, n_val, b, int(trainer.pool_factor)))
    if isinstance(trainer, ExactGreedy):
        return float(np.dtype(trainer.basis_dtype).itemsize * m * (n_train + n_val))
    if isinstance(trainer, BoundedActiveSetGreedy):
        points = trainer.capacity(n_train, n_val, m, dim)
        b = min(int(trainer.block_size), m)
        return float(bounded_memory(m, n_train, n_val, points * dim, dim, b, int(trainer.pool_factor)))
    if isinstance(trainer, ActiveSetGreedy):
        if initial:
            active = dim * (trainer.initial_points + 4 * trainer.max_new_points)
        else:
            active = dim * (
                trainer.initial_points + trainer.max_new_points * -(-m // max(int(trainer.refresh_every), 1))
            )
        return float(8 * m * (min(active, n_train) + n_val))
    if isinstance(trainer, ShardedGreedy):
        shards = trainer.n_shards or 1
        return float(8 * m * (n_train + n_val) / shards)
    raise ValueError(f"no memory formula for the training strategy {type(trainer).__name__}")


#: Above this size of the exact greedy's Newton basis (bytes) the default is the blocked greedy: the one-at-a-time
#: greedy streams the whole basis once per centre and runs at memory bandwidth, the blocked one at the arithmetic rate.
BLOCKED_ABOVE_BYTES = 2**30


def default_trainer(functionals, n_val: int, max_centers: int, memory: Optional[float] = None) -> Trainer:
    """The training strategy a fit without ``trainer`` uses: the fastest that fits the memory, logged with the reason.

    Each strategy's peak memory is its formula (:func:`trainer_memory`) checked against ``memory``:

    * :class:`ExactGreedy` where its Newton basis ``8 m (N + N_val)`` fits in ``memory`` and is below
      :data:`BLOCKED_ABOVE_BYTES` (1 GiB);
    * :class:`BlockedGreedy` where the basis is larger and ``8 ((m + b) (N + N_val) + (c b)^2)`` still fits
      (the same selection rule up to the weak greedy's slack, several times faster);
    * :class:`BoundedActiveSetGreedy` (state-derivative functionals) where neither fits: its slots are sized so
      that its whole peak (:func:`~sympredict.interpolation.greedy.active_set.bounded_memory`) is at most half
      of ``memory`` (the slots' size sets its time, ``2 m S`` flops per centre, and the fit keeps room for
      its data);
    * else :class:`ExactGreedy`, whose memory check then says what fits.

    ``memory``: bytes available (default 90 % of the available memory, :func:`available_memory`).
    """
    n, m = functionals.n_functionals, min(int(max_centers), functionals.n_functionals)
    limit = 0.9 * available_memory() if memory is None else float(memory)
    exact, blocked = ExactGreedy(), BlockedGreedy()
    need_exact, need_blocked = trainer_memory(exact, n, n_val, m), trainer_memory(blocked, n, n_val, m)
    if need_exact <= min(limit, BLOCKED_ABOVE_BYTES) or (need_exact <= limit < need_blocked):
        choice, why = exact, f"its Newton basis needs {format_bytes(need_exact)} of {format_bytes(limit)}"
    elif need_blocked <= limit:
        choice, why = (
            blocked,
            (
                f"the Newton basis ({format_bytes(need_blocked)} of {format_bytes(limit)}) exceeds "
                f"{format_bytes(BLOCKED_ABOVE_BYTES)}: blocks of centres with matrix products"
            ),
        )
    elif isinstance(functionals, HBFunctionals):
        bounded = BoundedActiveSetGreedy(memory_limit=0.5 * limit)
        points = bounded.capacity(n, n_val, m, functionals.dim)
        if points >= 1:
            need = trainer_memory(bounded, n, n_val, m, dim=functionals.dim)
            choice, why = (
                bounded,
                (
                    f"the full Newton basis ({format_bytes(need_exact)}) exceeds {format_bytes(limit)}; "
                    f"{points} of {len(functionals.points)} points in the slots, peak "
                    f"{format_bytes(need)} within half of it"
                ),
            )
        else:
            choice, why = exact, "nothing fits: the exact greedy's memory check says what does"
    else:
        choice, why = exact, "nothing fits: the exact greedy's memory check says what does"
    logger.info(f"trainer: {type(choice).__name__} ({why})")
    return choice


def trainer_from_spec(spec: Optional[dict]) -> Trainer:
    """Rebuild a strategy from :attr:`Trainer.spec` (``None``: the default :class:`ExactGreedy`)."""
    if spec is None:
        return ExactGreedy()
    try:
        cls = TRAINERS[spec["name"]]
        return cls(**spec["params"])
    except (KeyError, TypeError) as exc:
        raise ValueError(f"unknown or invalid training strategy {spec!r}; known: {sorted(TRAINERS)} ({exc})") from None
