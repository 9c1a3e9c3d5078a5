"""Generic plumbing for pyMOR worker pools (dummy, MPI, ipyparallel).

* :mod:`~sympredict.parallel.workers`: failures returned from workers and
  re-raised on the driver (:class:`WorkerError`), worker identities, BLAS threads;
* :mod:`~sympredict.parallel.watchdog`: dead or silent MPI ranks end the job
  instead of hanging it;
* :mod:`~sympredict.parallel.pool`: batches of independent instances (reference
  flows, trajectories) evaluated in chunks over a pool, equal to the serial call.

Nothing here knows a system or the greedy: data generation over a pool lives
with each system (``pool=`` arguments in :mod:`sympredict.systems` and the
experiments), the sharded f-greedy with the greedy
(:class:`sympredict.interpolation.greedy.ShardedGreedy`).
"""

from sympredict.parallel.pool import pool_flow, pool_map_instances
from sympredict.parallel.watchdog import ABORT_CODE, Watchdog
from sympredict.parallel.workers import WorkerError, checked, guarded, set_blas_threads, whoami, worker_info

__all__ = [
    "WorkerError",
    "worker_info",
    "set_blas_threads",
    "pool_flow",
    "pool_map_instances",
    "Watchdog",
    "ABORT_CODE",
    "guarded",
    "checked",
    "whoami",
]
