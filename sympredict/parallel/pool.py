"""Independent instances evaluated over a pyMOR worker pool, in chunks.

:func:`pool_map_instances` calls a method of an object (a system's ``flow``,
a FOM's ``trajectory``) on chunks of a batch of independent instances over a
pool and concatenates the results.  Every such method in sympredict is
vectorised over instances, so the result equals the serial call bit for bit
(checked in the tests).  ``pool=None`` means
:data:`pymor.parallel.dummy.dummy_pool`: one in-process worker.
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np
from pymor.parallel.dummy import dummy_pool

from sympredict.parallel.watchdog import Watchdog
from sympredict.parallel.workers import checked, guarded, worker_info

__all__ = ["pool_map_instances", "pool_flow"]


def _cut(value, sl, n):
    """``value[sl]`` for per-instance arrays of length ``n``; scalars and other shapes unchanged."""
    arr = np.asarray(value)
    if arr.ndim >= 1 and arr.shape[0] == n and n > 1:
        return arr[sl]
    return value


@guarded
def _w_call(method, x0, args, kwargs, obj=None):
    return getattr(obj, method)(x0, *args, **kwargs)


def pool_map_instances(
    obj, method: str, x0, *args, pool=None, chunk_size: Optional[int] = None, timeout: Optional[float] = 60.0, **kwargs
) -> np.ndarray:
    """``getattr(obj, method)(x0, *args, **kwargs)`` evaluated over ``pool`` in chunks of instances.

    Parameters
    ----------
    obj
        Pushed to the workers once (``pool.push``).
    method
        Name of a method vectorised over independent instances along axis 0 of
        ``x0`` and of its output.
    x0 : ndarray of shape (B, ...)
    args, kwargs
        Scalars, or per-instance arrays of length ``B`` (cut with the chunks).
    pool
        pyMOR |WorkerPool| (default: the dummy pool, i.e. one serial call).
    chunk_size
        Instances per task (default ``ceil(B / len(pool))``).
    timeout
        Heartbeat timeout of the MPI watchdog (:class:`~sympredict.parallel.watchdog.Watchdog`).

    Returns
    -------
    ndarray
        Equal to the serial call.  ``O(B)`` data moved; compute as the serial
        method's, divided over the workers.
    """
    pool = dummy_pool if pool is None else pool
    x0 = np.asarray(x0, dtype=float)
    n = len(x0)
    chunk_size = max(1, math.ceil(n / len(pool))) if chunk_size is None else chunk_size
    if int(chunk_size) != chunk_size or chunk_size < 1:
        raise ValueError(f"chunk_size must be a positive integer, got {chunk_size!r}")
    chunk_size = int(chunk_size)
    tasks = [
        (
            x0[s : s + chunk_size],
            tuple(_cut(a, slice(s, s + chunk_size), n) for a in args),
            {k: _cut(v, slice(s, s + chunk_size), n) for k, v in kwargs.items()},
        )
        for s in range(0, n, chunk_size)
    ]
    with Watchdog(pool, worker_info(pool), timeout), pool.push(obj) as remote:
        results = checked(pool.map(_w_call, [method] * len(tasks), *map(list, zip(*tasks)), obj=remote))
    return np.concatenate(results) if len(results) > 1 else results[0]


def pool_flow(system, x0, mu, t, *args, pool=None, chunk_size: Optional[int] = None, **kwargs) -> np.ndarray:
    """``system.flow(x0, mu, t, *args, **kwargs)`` over ``pool`` (:func:`pool_map_instances`).

    Returns
    -------
    ndarray of shape (B, 2n)
        Equal to the serial call.
    """
    return pool_map_instances(system, "flow", x0, mu, t, *args, pool=pool, chunk_size=chunk_size, **kwargs)
