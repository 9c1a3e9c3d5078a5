"""Launch the MPI checks of ``run_sharded_greedy.py`` with ``mpiexec -n 2`` and judge them.

    .venv/bin/python tests/mpi/launch.py          # exit code 0 iff all four runs behave

Runs (each under a time limit, so a hang is a failure, never a stuck CI job):

1. ``compare``: sharded vs serial selection, pool data, memory limit, worker
   exceptions; must print ``MPI CHECK OK`` and exit 0.
2. ``--exit 1`` (with ``-disable-auto-cleanup``, else MPICH ends the job
   silently with code 0): rank 1 calls ``os._exit(0)`` mid-run; the job must
   exit 75 with ``worker rank 1 ... died``.
3. ``--freeze 1`` (plain ``mpiexec``): rank 1 is SIGSTOPped mid-run; the
   heartbeat timeout must end the job with exit code 75 and
   ``worker rank 1 ... no heartbeat``.
4. ``--kill 1`` (plain ``mpiexec``): rank 1 is SIGKILLed mid-run; MPICH's
   launcher then kills the driver within milliseconds, so the job must end
   (no hang) with a non-zero code and a report naming rank 1: ours
   (``worker rank 1``) or the launcher's ``BAD TERMINATION ... PID <pid of rank 1>``.

Used by ``tests/parallel/test_parallel.py`` and runnable on its own (CI step).
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = Path(__file__).resolve().parent / "run_sharded_greedy.py"


def mpiexec() -> str | None:
    """The ``mpiexec`` next to this Python (the ``mpich`` wheel), else on PATH; None if absent."""
    here = Path(sys.executable).parent / "mpiexec"
    return str(here) if here.exists() else shutil.which("mpiexec")


def have_mpi() -> bool:
    try:
        import mpi4py  # noqa: F401
    except ImportError:
        return False
    return mpiexec() is not None


def run(mode: list, *, cleanup: bool = True, limit: float = 180.0) -> tuple[int, str]:
    """``mpiexec -n 2 python -m pymor.tools.mpi run_sharded_greedy.py MODE``; (exit code, output)."""
    cmd = (
        [mpiexec()]
        + ([] if cleanup else ["-disable-auto-cleanup"])
        + ["-n", "2", sys.executable, "-m", "pymor.tools.mpi", str(SCRIPT), *mode]
    )
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
    try:
        proc = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=limit)
    except subprocess.TimeoutExpired as err:
        out = (err.stdout or b"").decode() if isinstance(err.stdout, bytes) else (err.stdout or "")
        return -999, f"HUNG: no exit within {limit} s\n{out}"
    return proc.returncode, proc.stdout + proc.stderr


def judge_compare() -> tuple[bool, str]:
    rc, out = run([])
    return rc == 0 and "MPI CHECK OK" in out, out


def judge_exit() -> tuple[bool, str]:
    rc, out = run(["--exit", "1"], cleanup=False)
    return rc == 75 and re.search(r"worker rank 1 \(pid \d+ on .*\) died", out) is not None, f"rc={rc}\n{out}"


def judge_freeze() -> tuple[bool, str]:
    rc, out = run(["--freeze", "1"])
    return rc == 75 and "worker rank 1" in out and "no heartbeat" in out, f"rc={rc}\n{out}"


def judge_kill() -> tuple[bool, str]:
    rc, out = run(["--kill", "1"])
    pid = re.search(r"sending SIGKILL to rank 1 \(pid (\d+)\)", out)
    named = "worker rank 1 " in out or (pid is not None and f"PID {pid.group(1)} " in out)
    return rc not in (0, -999) and named, f"rc={rc}\n{out}"


CHECKS = {"compare": judge_compare, "exit": judge_exit, "freeze": judge_freeze, "kill": judge_kill}


def main() -> int:
    if not have_mpi():
        print("mpi4py or mpiexec missing: pip install -e '.[mpi]'", file=sys.stderr)
        return 2
    failed = []
    for name, check in CHECKS.items():
        ok, out = check()
        print(f"{'ok  ' if ok else 'FAIL'} mpi {name}", flush=True)
        if not ok:
            failed.append(name)
            print(out, flush=True)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
