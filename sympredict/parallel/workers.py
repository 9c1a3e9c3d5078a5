"""Worker plumbing on pyMOR worker pools: failures returned, not raised; who runs where.

pyMOR's MPI event loop catches a worker's exception, prints it and skips the
``gather`` the driver waits in: the run would hang.  Every worker function of
sympredict is therefore wrapped by :func:`guarded`: it returns a
:class:`Failure` instead of raising, and the driver re-raises it with
:func:`checked` (``ValueError`` stays ``ValueError``, anything else becomes
:class:`WorkerError` naming the rank and carrying the remote traceback).
"""

from __future__ import annotations

import functools
import os
import socket
import traceback

from pymor.parallel.dummy import dummy_pool
from pymor.tools import mpi
from threadpoolctl import threadpool_limits

from sympredict.exceptions import SympredictError

__all__ = ["WorkerError", "Failure", "guarded", "checked", "whoami", "worker_info", "set_blas_threads", "is_mpi_pool"]

ABORT_CODE = 75


class WorkerError(SympredictError, RuntimeError):
    """An exception raised on a pool worker, re-raised on the driver.

    Attributes
    ----------
    rank : int
        MPI rank (worker index) where it happened.
    host : str
    remote_type : str
        Class name of the remote exception.
    remote_traceback : str
    """

    def __init__(self, rank: int, host: str, remote_type: str, message: str, remote_traceback: str):
        self.rank = rank
        self.host = host
        self.remote_type = remote_type
        self.remote_traceback = remote_traceback
        super().__init__(
            f"worker rank {rank} on {host} raised {remote_type}: {message}\n--- remote traceback ---\n{remote_traceback}"
        )


def whoami() -> tuple:
    """``(rank, host, pid)`` of the calling process (rank 0 outside MPI)."""
    return (int(mpi.rank), socket.gethostname(), os.getpid())


class Failure:
    """An exception captured on a worker (returned instead of raised: a raising worker hangs an MPIPool)."""

    def __init__(self, exc: BaseException):
        self.rank, self.host, self.pid = whoami()
        self.type = type(exc).__name__
        self.message = str(exc)
        self.is_value_error = isinstance(exc, ValueError)
        self.traceback = traceback.format_exc()


def guarded(function):
    """Worker-side wrapper: return a :class:`Failure` instead of raising.

    pyMOR's MPI event loop catches a worker's exception (``SystemExit``
    included), prints it and skips the ``gather`` that the driver is waiting
    in: the run would hang.  Every worker function of sympredict is wrapped.
    """

    @functools.wraps(function)
    def wrapper(*args, **kwargs):
        try:
            return function(*args, **kwargs)
        except BaseException as exc:  # noqa: BLE001 -- everything, SystemExit included, goes back to the driver
            return Failure(exc)

    return wrapper


def checked(results):
    """``results`` (a list, or one result), or the first captured worker failure in it, raised."""
    items = results if isinstance(results, list) else [results]
    for r in items:
        if isinstance(r, Failure):
            if r.is_value_error:
                raise ValueError(f"worker rank {r.rank} on {r.host}: {r.message}")
            raise WorkerError(r.rank, r.host, r.type, r.message, r.traceback)
    return results


@guarded
def _w_info():
    return whoami()


def worker_info(pool=None) -> list:
    """``[(rank, host, pid), ...]`` of the pool's workers, in worker order."""
    pool = dummy_pool if pool is None else pool
    return checked(pool.apply(_w_info))


@guarded
def _w_blas_threads(n):
    threadpool_limits(limits=int(n))
    return whoami()


def set_blas_threads(pool, n_threads: int) -> None:
    """Limit BLAS/OpenMP threads to ``n_threads`` on every worker (threadpoolctl; persists)."""
    pool = dummy_pool if pool is None else pool
    checked(pool.apply(_w_blas_threads, int(n_threads)))


def is_mpi_pool(pool) -> bool:
    try:
        from pymor.parallel.mpi import MPIPool
    except ImportError:  # pragma: no cover
        return False
    return isinstance(pool, MPIPool) and len(pool) > 1
