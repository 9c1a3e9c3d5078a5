"""A process forked after a compiled parallel rollout (os.fork, multiprocessing with fork) keeps working."""

import os
import subprocess
import sys
from pathlib import Path

import pytest


ENV = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")


# --------------------------------------------------------------------------- fork safety
def test_fork_and_pool_after_a_compiled_parallel_rollout():
    """After a parallel compiled rollout, os.fork and multiprocessing.Pool (fork) roll out in the children."""
    pytest.importorskip("numba")
    env = dict(ENV, NUMBA_NUM_THREADS="2")
    proc = subprocess.run(
        [sys.executable, str(Path(__file__).with_name("_fork_check.py"))],
        capture_output=True,
        text=True,
        timeout=400,
        env=env,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "fork child status 0" in proc.stdout and "pool equal True" in proc.stdout
