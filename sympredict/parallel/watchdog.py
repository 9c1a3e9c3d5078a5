"""A driver-side guard against dead or silent MPI workers.

A worker that *dies* (killed, ``os._exit``, segfault) is found by a watchdog
thread on the driver (process liveness for ranks on the driver's host, MPI
heartbeats for all ranks); it logs ``worker rank k ... died`` and aborts the
MPI job (``MPI_Abort``) instead of waiting forever in a collective.  See
``docs/howto/mpi.md`` for what each case looks like.
"""

from __future__ import annotations

import os
import socket
import threading
import time
from typing import Optional

from pymor.core.logger import getLogger

from sympredict.parallel.workers import checked, guarded, is_mpi_pool, whoami

__all__ = ["ABORT_CODE", "Watchdog"]

logger = getLogger("sympredict.parallel")

#: Exit code of an MPI job aborted by the watchdog because a worker died or stopped responding.
ABORT_CODE = 75


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


@guarded
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
        return whoami()
    if MPI.Query_thread() < MPI.THREAD_MULTIPLE:
        _hb_state["thread"] = None
        return whoami()
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
                _abort(
                    f"rank {comm.Get_rank()}: no heartbeat from the driver (rank 0 on {driver[1]}) for {timeout:.0f} s"
                )
        comm.send(None, dest=0, tag=_HB_BYE)

    thread = threading.Thread(target=beat, name="sympredict-heartbeat", daemon=True)
    _hb_state.update(thread=thread, stop=stop)
    thread.start()
    return whoami()


@guarded
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


@guarded
def _w_thread_level():
    from mpi4py import MPI

    return MPI.Query_thread() >= MPI.THREAD_MULTIPLE


class Watchdog:
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
        self.active = is_mpi_pool(pool) and (timeout is None or timeout > 0)
        self.pool = pool
        self.workers = workers
        self.timeout = timeout
        self.poll = poll

    def __enter__(self):
        if not self.active:
            return self
        me = whoami()
        self.local = [(r, pid) for r, host, pid in self.workers if host == me[1] and pid != me[2]]
        self.heartbeat = self.timeout is not None and all(checked(self.pool.apply(_w_thread_level)))
        if self.timeout is not None and not self.heartbeat:
            logger.warning("MPI has no THREAD_MULTIPLE support: no heartbeats, only ranks on this host are watched")
        if self.heartbeat:
            interval = max(0.05, min(1.0, self.timeout / 20))
            checked(self.pool.apply(_w_heartbeat_start, interval, self.timeout, me))
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
                        _abort(
                            f"worker rank {r} on {where} sent no heartbeat for {now - t:.1f} s (timeout "
                            f"{self.timeout:.0f} s): dead, hung or unreachable; aborting the MPI job"
                        )
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
            checked(self.pool.apply(_w_heartbeat_stop, n_beating))
        return False
