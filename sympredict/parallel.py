"""Scale-out on pyMOR worker pools: distributed data generation and a sharded f-greedy.

Everything here takes a pyMOR |WorkerPool| (``pool=None`` means
:data:`pymor.parallel.dummy.dummy_pool`: one in-process worker, so nothing
changes on one machine) and works with the dummy pool, with
:class:`~pymor.parallel.mpi.MPIPool` under ``mpiexec -n P python -m
pymor.tools.mpi script.py`` and, through the same pool interface, with
ipyparallel.  Results are those of the serial code: the same samples, the same
selected functionals and the same coefficients.

Data generation
    :func:`pendulum_flow_map_data`, :func:`pendulum_random_flow_map_data`,
    :func:`reduced_flow_map_data`, :func:`wave_snapshots` and :func:`build_rom`
    take the arguments of their serial counterparts plus ``pool``.  The serial
    function runs once with a stand-in system whose ``flow`` only records its
    arguments (so sampling, grids and random draws are exactly the serial ones);
    the recorded flows are then cut into chunks of instances and evaluated by
    ``pool.map``.  Every flow is vectorised over independent instances, so the
    chunks reproduce the serial arrays bit for bit (checked in the tests).

Sharded f-greedy (:func:`sharded_greedy`, :func:`fit_predictor`)
    The ``N`` candidate functionals are cut into contiguous shards of points,
    one or more per worker.  A worker keeps, for its shards only, the rows of
    the Newton basis (``m x N_shard``), the residuals and the power function.
    Per greedy step the driver (rank 0 under MPI) makes two pool calls:

    1. ``apply`` (all workers): apply the previous winner's update (its
       representer -- point, component, parameter -- and its Newton-basis row
       ``v_k(lambda_j), k < m``: ``O(m)`` data sent to every worker), then report
       each shard's local best ``(score, global index)``, ``max |r|`` and
       ``max |r_val|``: ``O(1)`` per shard back;
    2. ``apply_only`` (owner of the global best): its representer, Newton-basis
       row (``m`` floats), ``P2_j`` and ``r_j``.

    Communication is ``O(workers + m)`` per step, never ``O(N)``.  Ties are
    broken as the serial ``np.argmax`` breaks them (lowest global index: shards
    are contiguous in the global order and each reports its first local
    maximum).  The local updates are the serial formulas applied to a column
    slice, so the selection, the Newton coefficients and the kernel
    coefficients equal those of :func:`sympredict.greedy.greedy_interpolation`.

Failures
    A worker that raises (e.g. its memory check) never hangs the pool: worker
    functions return the exception, and the driver raises :class:`WorkerError`
    (or ``ValueError`` for the memory check) naming the rank.  A worker that
    *dies* (killed, ``os._exit``, segfault) is found by a watchdog thread on the
    driver (process liveness for ranks on the driver's host, MPI heartbeats for
    all ranks); it logs ``worker rank k ... died`` and aborts the MPI job
    (``MPI_Abort``) instead of waiting forever in a collective.  MPICH's
    launcher itself ends the job when a rank is killed by a signal (its banner
    names the PID; the driver logs the rank of every PID at INFO) and, unless
    started with ``-disable-auto-cleanup``, when a rank exits.  See
    ``docs/parallel.md`` for what each case looks like.
"""

from __future__ import annotations

import functools
import math
import os
import socket
import sys
import threading
import time
import traceback
from typing import Callable, Optional

import numpy as np
from pymor.core.logger import getLogger
from pymor.parallel.dummy import dummy_pool

from sympredict.data import FlowMapData
from sympredict.exceptions import SympredictError
from sympredict.greedy import (
    GreedyHistory,
    GreedyResult,
    _abs_residual,
    _fmt_bytes,
    _kernel_coefficients,
    available_memory,
)

__all__ = [
    "WorkerError",
    "worker_info",
    "set_blas_threads",
    "pool_flow",
    "pendulum_flow_map_data",
    "pendulum_random_flow_map_data",
    "reduced_flow_map_data",
    "wave_snapshots",
    "build_rom",
    "shard_bounds",
    "sharded_greedy",
    "fit_predictor",
]

logger = getLogger("sympredict.parallel")

#: Exit code of an MPI job aborted by the watchdog because a worker died or stopped responding.
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
        super().__init__(f"worker rank {rank} on {host} raised {remote_type}: {message}\n--- remote traceback ---\n{remote_traceback}")


# --------------------------------------------------------------------------- worker plumbing
def _whoami() -> tuple:
    """``(rank, host, pid)`` of the calling process (rank 0 outside MPI)."""
    from pymor.tools import mpi

    return (int(mpi.rank), socket.gethostname(), os.getpid())


class _Failure:
    """An exception captured on a worker (returned instead of raised: a raising worker hangs an MPIPool)."""

    def __init__(self, exc: BaseException):
        self.rank, self.host, self.pid = _whoami()
        self.type = type(exc).__name__
        self.message = str(exc)
        self.is_value_error = isinstance(exc, ValueError)
        self.traceback = traceback.format_exc()


def _guarded(function):
    """Worker-side wrapper: return a :class:`_Failure` instead of raising.

    pyMOR's MPI event loop catches a worker's exception (``SystemExit``
    included), prints it and skips the ``gather`` that the driver is waiting
    in: the run would hang.  Every worker function of this module is wrapped.
    """

    @functools.wraps(function)
    def wrapper(*args, **kwargs):
        try:
            return function(*args, **kwargs)
        except BaseException as exc:  # noqa: BLE001 -- everything, SystemExit included, goes back to the driver
            return _Failure(exc)

    return wrapper


def _raise_failures(results):
    """Raise the first captured worker failure in ``results`` (a list, or one result)."""
    items = results if isinstance(results, list) else [results]
    for r in items:
        if isinstance(r, _Failure):
            if r.is_value_error:
                raise ValueError(f"worker rank {r.rank} on {r.host}: {r.message}")
            raise WorkerError(r.rank, r.host, r.type, r.message, r.traceback)
    return results


def _checked(results):
    return _raise_failures(results)


@_guarded
def _w_info():
    return _whoami()


def worker_info(pool=None) -> list:
    """``[(rank, host, pid), ...]`` of the pool's workers, in worker order."""
    pool = dummy_pool if pool is None else pool
    return _checked(pool.apply(_w_info))


@_guarded
def _w_blas_threads(n):
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=int(n))
    return _whoami()


def set_blas_threads(pool, n_threads: int) -> None:
    """Limit BLAS/OpenMP threads to ``n_threads`` on every worker (threadpoolctl; persists)."""
    pool = dummy_pool if pool is None else pool
    _checked(pool.apply(_w_blas_threads, int(n_threads)))


def _is_mpi_pool(pool) -> bool:
    try:
        from pymor.parallel.mpi import MPIPool
    except ImportError:  # pragma: no cover
        return False
    return isinstance(pool, MPIPool) and len(pool) > 1


# --------------------------------------------------------------------------- watchdog
def _alive(pid: int) -> bool:
    """Whether process ``pid`` exists and is not a zombie (Linux ``/proc``; else ``kill(pid, 0)``)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            state = f.read().rsplit(")", 1)[1].split()[0]
        return state not in ("Z", "X", "x")
    except FileNotFoundError:
        return False
    except (OSError, IndexError):
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return False
        except PermissionError:
            return True
        return True


_HB_TAG, _HB_BYE = 7301, 7302
_hb_state: dict = {}


def _abort(message: str) -> None:
    """Report ``message`` and end the whole MPI job (never returns).

    The line goes to file descriptor 2 first, unbuffered: when a worker is
    killed by a signal, MPICH's launcher kills this process a few milliseconds
    later, and the report must be out by then.  Half a second passes before
    ``MPI_Abort`` so that the launcher forwards it.
    """
    try:
        os.write(2, f"sympredict.parallel: ERROR: {message}\n".encode())
        logger.error(message)
        time.sleep(0.5)  # let the launcher forward the report before the abort tears the job down
    finally:
        from mpi4py import MPI

        MPI.COMM_WORLD.Abort(ABORT_CODE)


@_guarded
def _w_heartbeat_start(interval: float, timeout: float, driver: tuple):
    """On every rank: duplicate COMM_WORLD for heartbeats; workers start a beating thread.

    A worker beats to rank 0 every ``interval`` seconds and watches the
    driver's beats (and, on the driver's host, its pid); if the driver is gone
    for ``timeout`` seconds the worker aborts the job (no orphaned ranks).
    """
    from mpi4py import MPI

    comm = MPI.COMM_WORLD.Dup()
    _hb_state.clear()
    _hb_state["comm"] = comm
    if comm.Get_rank() == 0:
        return _whoami()
    if MPI.Query_thread() < MPI.THREAD_MULTIPLE:
        _hb_state["thread"] = None
        return _whoami()
    stop = threading.Event()
    local_driver = driver[1] == socket.gethostname()

    def beat():
        last = time.monotonic()
        while not stop.wait(interval):
            comm.send(None, dest=0, tag=_HB_TAG)
            while comm.iprobe(source=0, tag=_HB_TAG):
                comm.recv(source=0, tag=_HB_TAG)
                last = time.monotonic()
            if local_driver and not _alive(driver[2]):
                _abort(f"rank {comm.Get_rank()}: the driver (rank 0, pid {driver[2]} on {driver[1]}) died")
            if time.monotonic() - last > timeout:
                _abort(f"rank {comm.Get_rank()}: no heartbeat from the driver (rank 0 on {driver[1]}) for {timeout:.0f} s")
        comm.send(None, dest=0, tag=_HB_BYE)

    thread = threading.Thread(target=beat, name="sympredict-heartbeat", daemon=True)
    _hb_state.update(thread=thread, stop=stop)
    thread.start()
    return _whoami()


@_guarded
def _w_heartbeat_stop(n_beating: int):
    """On every rank: stop the beats, drain them on rank 0 (each worker ends with a BYE), free the communicator."""
    from mpi4py import MPI

    comm = _hb_state.get("comm")
    if comm is None:
        return None
    if comm.Get_rank() == 0:
        byes = 0
        status = MPI.Status()
        while byes < n_beating:
            comm.recv(source=MPI.ANY_SOURCE, tag=MPI.ANY_TAG, status=status)
            byes += status.Get_tag() == _HB_BYE
        while comm.iprobe(source=MPI.ANY_SOURCE, tag=_HB_TAG):
            comm.recv(source=MPI.ANY_SOURCE, tag=_HB_TAG)
    else:
        thread = _hb_state.get("thread")
        if thread is not None:
            _hb_state["stop"].set()
            thread.join()
        while comm.iprobe(source=0, tag=_HB_TAG):
            comm.recv(source=0, tag=_HB_TAG)
    comm.Barrier()
    while comm.iprobe(source=MPI.ANY_SOURCE, tag=_HB_TAG):  # beats that were still in flight
        comm.recv(source=MPI.ANY_SOURCE, tag=_HB_TAG)
    comm.Free()
    _hb_state.clear()
    return None


@_guarded
def _w_thread_level():
    from mpi4py import MPI

    return MPI.Query_thread() >= MPI.THREAD_MULTIPLE


class _Watchdog:
    """Driver-side guard against dead or silent MPI workers (a no-op for other pools).

    A daemon thread waits on pidfds of the workers on the driver's host (a
    worker that exits is reported at once) and checks, every ``poll``
    seconds, the MPI heartbeats of all workers (a worker silent for
    ``timeout`` seconds is reported: hung, or dead on another host).  On either it logs an error
    naming the rank and calls ``MPI_Abort`` -- the driver's main thread is
    blocked inside a collective and could not raise.

    Use as a context manager around pool work; cost: two pool calls to set up
    and tear down, one tiny message per worker and ``interval``.
    """

    def __init__(self, pool, workers: list, timeout: Optional[float], poll: float = 0.05):
        self.active = _is_mpi_pool(pool) and (timeout is None or timeout > 0)
        self.pool = pool
        self.workers = workers
        self.timeout = timeout
        self.poll = poll

    def __enter__(self):
        if not self.active:
            return self
        me = _whoami()
        self.local = [(r, pid) for r, host, pid in self.workers if host == me[1] and pid != me[2]]
        self.heartbeat = self.timeout is not None and all(_checked(self.pool.apply(_w_thread_level)))
        if self.timeout is not None and not self.heartbeat:
            logger.warning("MPI has no THREAD_MULTIPLE support: no heartbeats, only ranks on this host are watched")
        if self.heartbeat:
            interval = max(0.05, min(1.0, self.timeout / 20))
            _checked(self.pool.apply(_w_heartbeat_start, interval, self.timeout, me))
            self.comm = _hb_state["comm"]
            self.interval = interval
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, name="sympredict-watchdog", daemon=True)
        self.thread.start()
        return self

    def _run(self):
        import select

        last = {r: time.monotonic() for r, _, _ in self.workers if r != 0}
        next_beat = 0.0
        # pidfds wake this thread the moment a local worker exits (Linux >= 5.3); else /proc polling
        poller, by_fd, polled = select.poll(), {}, []
        for rank, pid in self.local:
            try:
                fd = os.pidfd_open(pid)
            except (AttributeError, OSError):
                polled.append((rank, pid))
                continue
            poller.register(fd, select.POLLIN)
            by_fd[fd] = (rank, pid)
        host = socket.gethostname()
        try:
            while not self.stop.is_set():
                for fd, _ in poller.poll(int(self.poll * 1000)):
                    rank, pid = by_fd[fd]
                    _abort(f"worker rank {rank} (pid {pid} on {host}) died during the run; aborting the MPI job")
                for rank, pid in polled:
                    if not _alive(pid):
                        _abort(f"worker rank {rank} (pid {pid} on {host}) died during the run; aborting the MPI job")
                if not self.heartbeat:
                    continue
                from mpi4py import MPI

                status = MPI.Status()
                while self.comm.iprobe(source=MPI.ANY_SOURCE, tag=_HB_TAG, status=status):
                    self.comm.recv(source=status.Get_source(), tag=_HB_TAG)
                    last[status.Get_source()] = time.monotonic()
                now = time.monotonic()
                if now >= next_beat:
                    for r in last:
                        self.comm.send(None, dest=r, tag=_HB_TAG)
                    next_beat = now + self.interval
                for r, t in last.items():
                    if now - t > self.timeout:
                        where = next(h for rr, h, _ in self.workers if rr == r)
                        _abort(f"worker rank {r} on {where} sent no heartbeat for {now - t:.1f} s (timeout "
                               f"{self.timeout:.0f} s): dead, hung or unreachable; aborting the MPI job")
        finally:
            for fd in by_fd:
                os.close(fd)

    def __exit__(self, exc_type, exc, tb):
        if not self.active:
            return False
        self.stop.set()
        self.thread.join()
        if self.heartbeat:
            n_beating = len(self.workers) - 1
            _checked(self.pool.apply(_w_heartbeat_stop, n_beating))
        return False


# --------------------------------------------------------------------------- data generation
class _FlowRecorder:
    """Stands in for a system: everything is delegated, except ``flow``, which records and returns its input."""

    def __init__(self, system):
        self._system = system
        self.calls = []

    def __getattr__(self, name):
        return getattr(self._system, name)

    def flow(self, x0, mu, t, *args, **kwargs):
        x0 = np.array(x0, dtype=float)
        self.calls.append((x0, mu, t, args, kwargs))
        return x0.copy()


class _RomRecorder:
    """A reduced model whose ``system`` is a :class:`_FlowRecorder`."""

    def __init__(self, rom):
        self._rom = rom
        self.system = _FlowRecorder(rom.system)

    def __getattr__(self, name):
        return getattr(self._rom, name)


def _cut(value, sl, n):
    """``value[sl]`` for per-instance arrays of length ``n``; scalars and other shapes unchanged."""
    arr = np.asarray(value)
    if arr.ndim >= 1 and arr.shape[0] == n and n > 1:
        return arr[sl]
    return value


@_guarded
def _w_flow(x0, mu, t, args, kwargs, system=None):
    return system.flow(x0, mu, t, *args, **kwargs)


def _replay(calls, system, pool, chunk_size: Optional[int], timeout: Optional[float] = 60.0) -> list:
    """Evaluate recorded ``flow`` calls over the pool in chunks of instances; one output per call."""
    total = sum(len(c[0]) for c in calls)
    if chunk_size is None:
        chunk_size = max(1, math.ceil(total / len(pool)))
    chunk_size = int(chunk_size)
    if chunk_size < 1:
        raise ValueError(f"chunk_size must be a positive integer, got {chunk_size!r}")
    tasks, owner = [], []
    for i, (x0, mu, t, args, kwargs) in enumerate(calls):
        n = len(x0)
        for start in range(0, n, chunk_size):
            sl = slice(start, start + chunk_size)
            tasks.append((x0[sl], _cut(mu, sl, n), _cut(t, sl, n), args, kwargs))
            owner.append(i)
    with _Watchdog(pool, worker_info(pool), timeout), pool.push(system) as remote:
        results = _checked(pool.map(_w_flow, *map(list, zip(*tasks)), system=remote))
    outs = [[] for _ in calls]
    for i, r in zip(owner, results):
        outs[i].append(r)
    return [np.concatenate(o) if len(o) > 1 else o[0] for o in outs]


def pool_flow(system, x0, mu, t, *args, pool=None, chunk_size: Optional[int] = None, **kwargs) -> np.ndarray:
    """``system.flow(x0, mu, t, *args, **kwargs)`` evaluated over a pool in chunks of instances.

    Parameters
    ----------
    system
        Anything with a ``flow(x0, mu, t, ...)`` vectorised over independent instances.
    x0 : ndarray of shape (B, 2n)
    mu, t
        Scalars or per-instance arrays of length ``B``.
    pool
        pyMOR |WorkerPool| (default: the dummy pool, i.e. one serial call).
    chunk_size
        Instances per task (default ``ceil(B / len(pool))``).

    Returns
    -------
    ndarray of shape (B, 2n)
        Equal to the serial call.  ``O(B)`` data moved; compute as the serial flow, divided over the workers.
    """
    pool = dummy_pool if pool is None else pool
    x0 = np.array(x0, dtype=float)
    return _replay([(x0, mu, t, args, kwargs)], system, pool, chunk_size)[0]


def _with_flows(data: FlowMapData, recorder: _FlowRecorder, system, pool, chunk_size) -> FlowMapData:
    outs = _replay(recorder.calls, system, pool, chunk_size)
    # the recorded calls must cover data.x1 in order: the stand-in returned copies of the inputs
    assert np.array_equal(np.concatenate([c[0] for c in recorder.calls]), data.x1), "unexpected flow-call structure"
    return FlowMapData(data.x0, np.concatenate(outs), data.mu, data.dt)


def pendulum_flow_map_data(system, mus=None, dts=None, n_grid: int = 200, p_nonpositive: bool = False,
                           h_max: float = 1e-3, *, pool=None, chunk_size: Optional[int] = None) -> FlowMapData:
    """:func:`sympredict.systems.pendulum.flow_map_data` with the reference flows computed over ``pool``.

    Same arguments and result (bit for bit) as the serial function; ``mus`` and
    ``dts`` default to ``MU_TRAIN`` and ``DT_TRAIN``.  Work ``O(M / h_max)``
    divided over the workers; ``O(M)`` data moved.
    """
    from sympredict.systems import pendulum as pend

    pool = dummy_pool if pool is None else pool
    rec = _FlowRecorder(system)
    plan = pend.flow_map_data(rec, pend.MU_TRAIN if mus is None else mus, pend.DT_TRAIN if dts is None else dts,
                              n_grid=n_grid, p_nonpositive=p_nonpositive, h_max=h_max)
    with logger.block(f"pendulum flow-map data: {len(plan)} samples on {len(pool)} worker(s)"):
        return _with_flows(plan, rec, system, pool, chunk_size)


def pendulum_random_flow_map_data(system, n_samples: int, mu_range=(0.7, 0.8), dt_range=(0.04, 0.06), seed: int = 0,
                                  h_max: float = 1e-3, mu_values=None, dt_values=None, *, pool=None,
                                  chunk_size: Optional[int] = None) -> FlowMapData:
    """:func:`sympredict.systems.pendulum.random_flow_map_data` with the flows computed over ``pool`` (same result)."""
    from sympredict.systems import pendulum as pend

    pool = dummy_pool if pool is None else pool
    rec = _FlowRecorder(system)
    plan = pend.random_flow_map_data(rec, n_samples, mu_range=mu_range, dt_range=dt_range, seed=seed, h_max=h_max,
                                     mu_values=mu_values, dt_values=dt_values)
    return _with_flows(plan, rec, system, pool, chunk_size)


def reduced_flow_map_data(rom, speeds, dt: float, n_per_speed: int, energy: float, seed: int, *, pool=None,
                          chunk_size: Optional[int] = None) -> FlowMapData:
    """:func:`sympredict.experiments.wave.reduced_flow_map_data` with the reduced flows computed over ``pool``.

    Same arguments and result; one recorded flow per speed, each cut into
    chunks of ``chunk_size`` states (default ``ceil(M / len(pool))``).
    """
    from sympredict.experiments import wave

    pool = dummy_pool if pool is None else pool
    rec = _RomRecorder(rom)
    plan = wave.reduced_flow_map_data(rec, speeds, dt, n_per_speed, energy, seed)
    return _with_flows(plan, rec.system, rom.system, pool, chunk_size)


@_guarded
def _w_trajectory(x0, mu, dt, n_steps, h_max, fom=None):
    return fom.trajectory(x0, mu, dt, n_steps, h_max=h_max)


def wave_snapshots(fom, x0, mu: float, dt: float, n_steps: int, h_max: float = 1e-3, *, pool=None) -> np.ndarray:
    """FOM reference trajectories ``fom.trajectory(x0, mu, dt, n_steps)`` with the initial states split over ``pool``.

    Returns
    -------
    ndarray of shape (B, n_steps + 1, 2N)
        Equal to the serial call (each worker factors its own sparse LU:
        ``O(N)`` per worker, time ``O(B n_steps n_micro N / workers)``).
    """
    pool = dummy_pool if pool is None else pool
    x0 = np.atleast_2d(np.asarray(x0, dtype=float))
    parts = [p for p in np.array_split(np.arange(len(x0)), min(len(pool), len(x0))) if len(p)]
    with _Watchdog(pool, worker_info(pool), 60.0), pool.push(fom) as remote:
        out = _checked(pool.map(_w_trajectory, [x0[p] for p in parts], [mu] * len(parts), [dt] * len(parts),
                                [n_steps] * len(parts), [h_max] * len(parts), fom=remote))
    return np.concatenate(out)


def build_rom(preset, seed: int = 0, *, pool=None):
    """:func:`sympredict.experiments.wave.build_rom` with the FOM snapshots computed over ``pool``.

    Returns what the serial function returns (``fom, rom, energy, info``), the
    same basis bit for bit (the test compares them).
    """
    from sympredict.experiments.wave import build_rom as serial_build_rom

    return serial_build_rom(preset, seed, pool=dummy_pool if pool is None else pool)


# --------------------------------------------------------------------------- sharded greedy
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


class _Shard:
    """One shard's greedy state: Newton-basis rows, residuals and power function of its candidates.

    ``offset`` is the global flat index of its first functional.  Memory
    ``8 max_centers (N_shard + N_val_shard)`` bytes for the basis rows.
    """

    def __init__(self, shard_id, offset, functionals, targets, val_functionals, val_targets, max_centers, criterion,
                 breakdown):
        self.shard_id = shard_id
        self.offset = int(offset)
        self.f = functionals
        self.n = functionals.n_functionals
        self.res = np.array(targets, dtype=float)
        self.res_abs = np.empty(self.n)
        self.tmp = np.empty(self.n)
        self.p2 = functionals.diagonal().astype(float)
        self.criterion = criterion
        self.breakdown = breakdown
        self.basis = np.empty((max_centers, self.n))
        self.vf = val_functionals
        self.n_val = 0 if val_functionals is None else val_functionals.n_functionals
        if self.n_val:
            self.vres = np.array(val_targets, dtype=float)
            self.vbasis = np.empty((max_centers, self.n_val))

    def update(self, m, rep, coeffs, pj, b, j):
        """Add Newton basis function ``m`` (selected functional ``j``, global) to this shard: ``O(m N_shard)``."""
        row = self.f.column(rep, out=self.basis[m])
        if m:
            row -= self.basis[:m].T @ coeffs
        row *= 1.0 / pj
        if self.res.shape[1] == 1:
            self.res[:, 0] -= b[0] * row
        else:
            self.res -= row[:, None] * b
        local = j - self.offset
        own = 0 <= local < self.n
        if own:
            self.res[local] = 0.0
        np.square(row, out=self.tmp)
        self.p2 -= self.tmp
        if own:
            self.p2[local] = 0.0
        if self.n_val:
            vrow = self.vf.column(rep, out=self.vbasis[m])
            if m:
                vrow -= self.vbasis[:m].T @ coeffs
            vrow *= 1.0 / pj
            self.vres -= vrow[:, None] * b

    def report(self):
        """``(max |r|, max |r_val|, best score, its global index)`` of this shard: ``O(N_shard)``."""
        _abs_residual(self.res, out=self.res_abs)
        train_max = float(self.res_abs.max())
        val_max = float(np.abs(self.vres).max()) if self.n_val else -np.inf
        score = self.res_abs if self.criterion == "f" else self.p2.copy()
        score[self.p2 <= self.breakdown] = -np.inf
        jl = int(np.argmax(score))
        return train_max, val_max, float(score[jl]), self.offset + jl

    def winner(self, j, m):
        """Representer, Newton-basis row ``v_k(lambda_j), k < m``, ``P2_j`` and ``r_j`` of global functional ``j``."""
        local = j - self.offset
        return self.f.representer(local), self.basis[:m, local].copy(), self.p2[local], self.res[local].copy()


class _ShardStore:
    """Per-worker container for the shards (pushed empty, filled by :func:`_w_load_shards`)."""

    def __init__(self):
        self.shards = {}


@_guarded
def _w_load_shards(payload, store=None):
    """Check the per-rank memory limit, then build this worker's shards.  Returns ``(rank, host, shard ids)``."""
    specs, settings = payload
    me = _whoami()
    need = 8 * settings["max_centers"] * sum(s["n_train"] + s["n_val"] for s in specs)
    limit = settings["memory_limit_per_rank"]
    if limit is None:
        limit = 0.9 * available_memory() / settings["ranks_on_host"].get(me[1], 1)
    if need > limit:
        raise ValueError(
            f"its shards' Newton basis needs {_fmt_bytes(need)} ({settings['max_centers']} centres x "
            f"{sum(s['n_train'] + s['n_val'] for s in specs)} functionals x 8 bytes) but the per-rank memory limit is "
            f"{_fmt_bytes(limit)}; use more ranks (at least {max(1, math.ceil(settings['need_total'] / limit)) if limit > 0 else 'more'}), fewer centres, "
            "or raise memory_limit_per_rank"
        )
    for s in specs:
        store.shards[s["shard_id"]] = _Shard(
            s["shard_id"], s["offset"], s["functionals"], s["targets"], s["val_functionals"], s["val_targets"],
            settings["max_centers"], settings["criterion"], settings["breakdown"],
        )
    return me[0], me[1], sorted(store.shards)


@_guarded
def _w_shard_ids(store=None):
    return sorted(store.shards)


@_guarded
def _w_step(winner, store=None):
    """Apply the previous winner (``None`` at the start) to every local shard, then report each shard.

    Returns ``(reports, seconds)``: one report per local shard and the compute time spent here.
    """
    t0 = time.perf_counter()
    out = []
    for sid in sorted(store.shards):
        shard = store.shards[sid]
        if winner is not None:
            shard.update(*winner)
        out.append((sid,) + shard.report())
    return out, time.perf_counter() - t0


@_guarded
def _w_winner(shard_id, j, m, store=None):
    return store.shards[shard_id].winner(j, m)


@_guarded
def _w_clear(store=None):
    store.shards.clear()


def sharded_greedy(
    functionals,
    targets: np.ndarray,
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
) -> GreedyResult:
    """f-greedy (or P-greedy) with the candidates sharded over a pyMOR worker pool.

    Same arguments and result as :func:`sympredict.greedy.greedy_interpolation`
    (same selection order and stop reason; the coefficients agree to round-off,
    in the tests to 1e-10 relative or better), plus:

    Parameters
    ----------
    functionals
        ``HBFunctionals`` or ``ValueFunctionals`` with ``M`` points (``N`` functionals).
    targets : ndarray of shape (N,) or (N, q)
    validation
        ``(val_functionals, val_targets)``; also sharded over the workers.
    pool
        pyMOR |WorkerPool|; default the dummy pool (one in-process worker).
    n_shards
        Number of shards (default ``len(pool)``: one per worker); shards are
        spread evenly over the workers, contiguous in the global order.  More
        shards than workers are allowed (the dummy pool can run ``n_shards=2``).
    memory_limit_per_rank
        Bytes the Newton basis of one worker's shards may use; default 90% of
        the available memory of the worker's host divided by the number of
        workers on that host.  Every worker checks before allocating; a worker
        over its limit ends the run with ``ValueError`` naming its rank.
    timeout
        Seconds without a heartbeat after which an MPI worker counts as dead
        (see :class:`_Watchdog`); ``None`` disables heartbeats (dead local
        processes are still detected), ``0`` disables the watchdog.
    callback
        Called on the driver after each step with ``(m, E_train(m))``.
    stats
        A dict to fill with per-step timings: ``winner_call`` (m,) and
        ``step_call`` (m,) wall seconds of the two pool calls on the driver,
        ``worker_compute`` (m, workers) seconds spent computing in each
        worker's step (the rest of ``step_call`` is communication and
        waiting), plus ``n_workers``, ``n_shards``, ``shard_sizes``, ``workers``.

    Returns
    -------
    GreedyResult

    Raises
    ------
    ValueError
        Bad arguments, or a worker's basis over its memory limit (names the rank).
    WorkerError
        Any other exception on a worker (names the rank, carries the remote traceback).

    Notes
    -----
    Per step: ``O(m N / P)`` work per worker (``P`` workers), two pool calls,
    ``O(P + m)`` data.  Memory ``8 m_max (N + N_val) / P`` bytes per worker,
    ``O(m_max^2)`` on the driver (the Cholesky factor of the selected Gramian).
    """
    if criterion not in ("f", "p"):
        raise ValueError(f"criterion must be 'f' (f-greedy) or 'p' (P-greedy), got {criterion!r}")
    pool = dummy_pool if pool is None else pool
    _subset(functionals, 0, 1)  # TypeError for functionals that cannot be sharded
    n = functionals.n_functionals
    if n == 0:
        raise ValueError("no candidate functionals: the training set is empty")
    y = np.asarray(targets, dtype=float)
    squeeze = y.ndim == 1
    y = y.reshape(n, -1)
    if int(max_centers) < 1:
        raise ValueError(f"max_centers must be a positive integer, got {max_centers!r}")
    max_centers = min(int(max_centers), n)
    n_workers = len(pool)
    n_shards = n_workers if n_shards is None else int(n_shards)
    n_points = len(functionals.points)
    if not 1 <= n_shards <= n_points:
        raise ValueError(f"n_shards must lie in 1..{n_points} (the number of points), got {n_shards}")
    val_f, vres0, n_val = None, None, 0
    if validation is not None:
        val_f, val_targets = validation
        n_val = val_f.n_functionals
        vres0 = np.array(val_targets, dtype=float).reshape(n_val, -1)
        if vres0.shape[1] != y.shape[1]:
            raise ValueError("validation targets must have as many outputs as the training targets")

    workers = worker_info(pool)
    ranks_on_host = {}
    for _, host, _ in workers:
        ranks_on_host[host] = ranks_on_host.get(host, 0) + 1
    breakdown = power_tol * functionals.diagonal().max()
    per = functionals.n_functionals // n_points
    bounds = shard_bounds(n_points, n_shards, per)
    vbounds = shard_bounds(len(val_f.points), n_shards, val_f.n_functionals // len(val_f.points)) if n_val else None
    specs = []
    for s in range(n_shards):
        sub, per = _subset(functionals, bounds[s], bounds[s + 1])
        spec = {"shard_id": s, "offset": int(bounds[s] * per), "functionals": sub, "n_train": sub.n_functionals,
                "targets": y[bounds[s] * per: bounds[s + 1] * per], "val_functionals": None, "val_targets": None, "n_val": 0}
        if n_val and vbounds[s + 1] > vbounds[s]:
            vsub, vper = _subset(val_f, vbounds[s], vbounds[s + 1])
            if vsub.n_functionals:
                spec.update(val_functionals=vsub, val_targets=vres0[vbounds[s] * vper: vbounds[s + 1] * vper],
                            n_val=vsub.n_functionals)
        specs.append(spec)
    wb = shard_bounds(n_shards, n_workers, align=1)  # shards of worker w: wb[w]..wb[w+1]
    settings = {"max_centers": max_centers, "criterion": criterion, "breakdown": breakdown,
                "memory_limit_per_rank": memory_limit_per_rank, "ranks_on_host": ranks_on_host,
                "need_total": 8 * max_centers * (n + n_val)}
    payloads = [(specs[wb[w]: wb[w + 1]], settings) for w in range(n_workers)]
    del specs

    chol = np.zeros((max_centers, max_centers))
    beta = np.zeros((max_centers, y.shape[1]))
    selected = np.empty(max_centers, dtype=np.int64)
    sel_power = np.empty(max_centers)
    elapsed = np.empty(max_centers)
    stop_reason = "max_centers" if max_centers < n else "exhausted"
    logger.info("workers: " + ", ".join(f"rank {r} pid {pid} on {host}" for r, host, pid in workers))
    logger.info(f"sharded greedy: {n} functionals{f' (+{n_val} validation)' if n_val else ''} in {n_shards} shard(s) "
                f"on {n_workers} worker(s), up to {max_centers} centres")

    with _Watchdog(pool, workers, timeout), pool.push(_ShardStore()) as store:
        try:
            _checked(pool.map(_w_load_shards, payloads, store=store))
            # where the shards landed, by worker index (apply answers in worker order; map need not place item w on worker w)
            placed = _checked(pool.apply(_w_shard_ids, store=store))
            owner = {sid: w for w, sids in enumerate(placed) for sid in sids}
            if sorted(owner) != list(range(n_shards)):
                raise RuntimeError(f"shards were not placed once each: {placed}")  # pragma: no cover
            reports = _checked(pool.apply(_w_step, None, store=store))
            train_max, val_max, best = _combine([r for r, _ in reports])
            train_hist = [train_max]
            val_hist = [val_max] if n_val else None
            best_train = train_hist[0]
            timing = []
            t0 = time.perf_counter()
            m = 0
            while m < max_centers:
                score, j, sid = best
                if not np.isfinite(score):
                    stop_reason = "power"
                    break
                if criterion == "f" and score <= tol:
                    stop_reason = "tol"
                    break
                t_call = time.perf_counter()
                rep, coeffs_j, p2_j, res_j = _checked(pool.apply_only(_w_winner, owner[sid], sid, j, m, store=store))
                t_winner = time.perf_counter() - t_call
                pj = np.sqrt(p2_j)
                chol[m, :m] = coeffs_j
                chol[m, m] = pj
                b = res_j / pj
                beta[m] = b
                selected[m] = j
                sel_power[m] = pj
                t_call = time.perf_counter()
                reports = _checked(pool.apply(_w_step, (m, rep, coeffs_j, pj, b, j), store=store))
                t_step = time.perf_counter() - t_call
                if stats is not None:
                    timing.append((t_winner, t_step) + tuple(sec for _, sec in reports))
                m += 1
                elapsed[m - 1] = time.perf_counter() - t0
                train_max, val_max, best = _combine([r for r, _ in reports])
                train_hist.append(train_max)
                if n_val:
                    val_hist.append(val_max)
                best_train = min(best_train, train_max)
                if callback is not None:
                    callback(m, train_max)
                if train_max / divergence_factor > best_train:  # as the serial greedy (no overflow)
                    stop_reason = "diverged"
                    m_best = int(np.argmin(train_hist))
                    logger.warning(
                        f"greedy residual blew up at {m} centres ({train_max:.2e} vs best {best_train:.2e}): "
                        f"round-off in the Newton basis; truncating to {m_best} centres (raise power_tol to avoid)"
                    )
                    m = m_best
                    del train_hist[m + 1:]
                    if val_hist is not None:
                        del val_hist[m + 1:]
                    break
                if log_every and m % log_every == 0:
                    logger.info(
                        f"{m} centres: E_train={train_hist[-1]:.3e}"
                        + (f", E_val={val_hist[-1]:.3e}" if n_val else "")
                        + f", P={pj:.2e}, {elapsed[m - 1]:.1f}s"
                    )
        finally:
            _raise_failures(pool.apply(_w_clear, store=store))

    if stats is not None:
        t = np.array(timing).reshape(-1, 2 + n_workers)
        stats.update(winner_call=t[:, 0], step_call=t[:, 1], worker_compute=t[:, 2:], n_workers=n_workers,
                     n_shards=n_shards, shard_sizes=np.diff(bounds) * per, workers=workers)
    coef = _kernel_coefficients(chol[:m, :m], beta[:m]) if m else np.zeros((0, y.shape[1]))
    history = GreedyHistory(
        train_max_residual=np.array(train_hist),
        val_max_residual=None if val_hist is None else np.array(val_hist),
        selected_power=sel_power[:m].copy(),
        elapsed=elapsed[:m].copy(),
        stop_reason=stop_reason,
    )
    logger.info(f"sharded greedy stopped ({stop_reason}) with {m} centres, E_train={train_hist[-1]:.3e}")
    if squeeze:
        coef, newton = coef[:, 0], beta[:m, 0].copy()
    else:
        newton = beta[:m].copy()
    return GreedyResult(selected=selected[:m].copy(), coef=coef, newton_coef=newton, history=history, chol=chol[:m, :m].copy())


def _combine(reports):
    """Global ``max |r|``, ``max |r_val|`` and best ``(score, index, shard)`` from the workers' shard reports.

    Shards are scanned in global order and a later shard wins only with a
    strictly larger score: the lowest global index among equal maxima, as
    ``np.argmax`` over the whole set.
    """
    flat = sorted((r for worker in reports for r in worker), key=lambda r: r[0])
    train_max = max(r[1] for r in flat)
    val_max = max(r[2] for r in flat)
    best = (-np.inf, -1, -1)
    for sid, _, _, score, j in flat:
        if best[1] < 0 or score > best[0]:
            best = (score, j, sid)
    return train_max, val_max, best


def fit_predictor(model, x0, x1, mu=None, dt=None, *, validation=None, pool=None, n_shards: Optional[int] = None,
                  memory_limit_per_rank: Optional[float] = None, timeout: Optional[float] = 60.0,
                  stats: Optional[dict] = None):
    """``model.fit(x0, x1, mu, dt, validation=validation)`` with the greedy sharded over ``pool``.

    Runs the model's own ``fit`` (validation, duplicate check, default kernel,
    surrogate and fitted state) with its greedy step replaced by
    :func:`sharded_greedy` using the model's settings (``max_centers``, ``tol``,
    ``criterion``, ``power_tol``); so the fitted model equals ``model.fit(...)``
    (same centres; coefficients to round-off).  Works for
    :class:`~sympredict.predictor.SymplecticKernelPredictor` and
    :class:`~sympredict.predictor.DirectKernelPredictor`.  ``pool``,
    ``n_shards``, ``memory_limit_per_rank``, ``timeout`` and ``stats`` are
    passed to :func:`sharded_greedy`.

    Returns
    -------
    model
        Fitted (as ``fit`` returns ``self``).
    """

    if getattr(model, "basis_dtype", "float64") != "float64":
        raise ValueError(f"the sharded greedy keeps a float64 Newton basis; got basis_dtype={model.basis_dtype!r}")

    def _greedy(functionals, targets, val):
        with logger.block(f"sharded f-greedy over {functionals.n_functionals} functionals"):
            return sharded_greedy(
                functionals, targets, max_centers=model.max_centers, tol=model.tol, criterion=model.criterion,
                power_tol=model.power_tol, validation=val, pool=pool, n_shards=n_shards,
                memory_limit_per_rank=memory_limit_per_rank, timeout=timeout, stats=stats,
            )

    model._greedy = _greedy  # instance attribute shadows the method for this one call
    try:
        return model.fit(x0, x1, mu=mu, dt=dt, validation=validation)
    finally:
        del model._greedy
