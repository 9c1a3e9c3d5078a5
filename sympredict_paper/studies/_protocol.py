"""The benchmarks' one timing protocol: threads, warm-up, repeats, statistics, side-by-side ratios, machine, JSON.

Every study in ``sympredict_paper/studies/`` measures the same way (``docs/explanation/performance.md``):

* **threads** set deliberately, for the whole measurement: BLAS and OpenMP
  through ``threadpoolctl`` (``--blas-threads``, default :data:`DEFAULT_BLAS_THREADS`
  = 1: on a 2-core machine a second OpenBLAS thread competes with numba's and
  with other processes, and dense eigen/SVD work runs 2-20x slower), numba's
  parallel loops through ``numba.set_num_threads`` (the script's ``--threads``);
  both are stated in the JSON, with what the thread pools report;
* **warm-up excluded**: each timed callable runs ``warmup`` times (compilation,
  caches, first-touch memory) before the ``repeats`` timed calls;
* **statistics**: the median (the reported number unless a script says
  otherwise), minimum, maximum and mean of the repeats, and the samples;
* **side by side**: methods compared in a ratio are measured in the same
  process, interleaved repeat by repeat (:func:`side_by_side`), so that a change
  of machine load hits all of them;
* **the record**: the exact command line, the working directory, the git
  revision, the thread settings and the machine (CPU model, core count, the
  OpenBLAS core type, NumPy / SciPy / numba versions, numba's CPU name and
  threading layer) are written into the JSON under ``"protocol"``
  (:func:`write_json`), next to the script's own keys (unchanged).

The module depends on NumPy, threadpoolctl and (optionally) numba only, not on
sympredict: it also serves scripts that load other revisions of the package.
Command-line options come from :func:`add_arguments`.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shlex
import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Dict, Optional

import numpy as np
from threadpoolctl import threadpool_info, threadpool_limits

__all__ = [
    "DEFAULT_BLAS_THREADS",
    "add_arguments",
    "limits",
    "measure",
    "side_by_side",
    "summary",
    "machine_info",
    "record",
    "record_options",
    "write_json",
]

#: BLAS/OpenMP threads unless ``--blas-threads`` says otherwise.
DEFAULT_BLAS_THREADS = 1


# --------------------------------------------------------------------------- command line
def add_arguments(
    parser,
    *,
    threads: Optional[int] = None,
    threads_help: str = "numba threads of the compiled code",
    repeats: Optional[int] = None,
    repeats_help: str = "timed calls after the warm-up; their median is reported",
    json_option: bool = True,
    blas_alias: Optional[str] = None,
    json_default: Optional[str] = None,
) -> None:
    """The protocol's options: ``--blas-threads``, and where asked ``--threads``, ``--repeats``, ``--json``.

    ``threads`` / ``repeats``: the script's defaults (``None``: the script has no such option); ``threads_help`` /
    ``repeats_help``: what they count in this script.
    ``blas_alias``: an older name of ``--blas-threads`` that command lines in the docs use (e.g. ``"--threads"``).
    ``json_default``: where ``--json`` writes when not given (``None``: nothing is written then).
    """
    parser.add_argument(
        "--blas-threads",
        type=int,
        default=DEFAULT_BLAS_THREADS,
        help=f"BLAS/OpenMP threads via threadpoolctl (default {DEFAULT_BLAS_THREADS})",
    )
    if blas_alias:
        parser.add_argument(
            blas_alias,
            dest="blas_threads",
            type=int,
            default=argparse.SUPPRESS,
            help="the same as --blas-threads (this script's older name)",
        )
    if threads is not None:
        parser.add_argument("--threads", type=int, default=threads, help=f"{threads_help} (default {threads})")
    if repeats is not None:
        parser.add_argument(
            "--repeats",
            type=int,
            default=repeats,
            help=f"{repeats_help} (default {repeats})",
        )
    if json_option:
        written = "" if json_default is None else f" (default {json_default})"
        parser.add_argument(
            "--json", default=json_default, help=f"also write the results as JSON (with the protocol record){written}"
        )


# --------------------------------------------------------------------------- threads
def _numba():
    try:
        import numba
    except ImportError:  # pragma: no cover
        return None
    return numba


@contextmanager
def limits(blas_threads: int = DEFAULT_BLAS_THREADS, numba_threads: Optional[int] = None):
    """BLAS/OpenMP threads (threadpoolctl) and, if given, numba's threads for the ``with`` block; restored after.

    ``numba_threads`` is capped at numba's pool size (``NUMBA_NUM_THREADS``).
    """
    numba = _numba() if numba_threads is not None else None
    before = numba.get_num_threads() if numba is not None else None
    with threadpool_limits(limits=int(blas_threads)):
        if numba is not None:
            numba.set_num_threads(max(1, min(int(numba_threads), numba.config.NUMBA_NUM_THREADS)))
        try:
            yield
        finally:
            if numba is not None:
                numba.set_num_threads(before)


# --------------------------------------------------------------------------- timing
def summary(samples) -> dict:
    """``median_s``, ``min_s``, ``max_s``, ``mean_s``, ``repeats`` and the ``samples_s`` of timed calls."""
    s = np.asarray(samples, dtype=float)
    return {
        "median_s": float(np.median(s)),
        "min_s": float(s.min()),
        "max_s": float(s.max()),
        "mean_s": float(s.mean()),
        "repeats": int(s.size),
        "samples_s": [float(v) for v in s],
    }


def _timed(fn: Callable) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def measure(fn: Callable, repeats: int = 5, warmup: int = 1) -> dict:
    """``warmup`` untimed calls of ``fn``, then ``repeats`` timed ones: :func:`summary` plus ``warmup``."""
    for _ in range(warmup):
        fn()
    out = summary([_timed(fn) for _ in range(max(1, int(repeats)))])
    out["warmup"] = int(warmup)
    return out


def side_by_side(
    methods: Dict[str, Callable],
    repeats: int = 5,
    warmup: int = 1,
    baseline: Optional[str] = None,
    statistic: str = "median_s",
) -> dict:
    """Several methods measured in this process, interleaved: repeat ``r`` times every method once, in turn.

    Returns ``{"methods": {label: summary}, "ratios": {label: stat(label) / stat(baseline)}, "baseline",
    "statistic", "interleaved": True}``; ``baseline`` defaults to the first method, ``statistic`` to the median.
    """
    labels = list(methods)
    baseline = labels[0] if baseline is None else baseline
    for _ in range(warmup):
        for fn in methods.values():
            fn()
    samples = {label: [] for label in labels}
    for _ in range(max(1, int(repeats))):
        for label, fn in methods.items():
            samples[label].append(_timed(fn))
    stats = {label: dict(summary(s), warmup=int(warmup)) for label, s in samples.items()}
    base = stats[baseline][statistic]
    return {
        "methods": stats,
        "ratios": {label: stats[label][statistic] / base for label in labels},
        "baseline": baseline,
        "statistic": statistic,
        "interleaved": True,
    }


# --------------------------------------------------------------------------- the record
def _cpu_model() -> Optional[str]:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or None


def _git(root: Path) -> Optional[dict]:
    try:
        rev = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True, timeout=10)
        dirty = subprocess.run(
            ["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            timeout=10,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    if rev.returncode != 0:
        return None
    return {"commit": rev.stdout.strip(), "dirty": bool(dirty.stdout.strip())}


def machine_info() -> dict:
    """CPU model and count, platform, Python / NumPy / SciPy / numba versions, thread pools and the BLAS core type."""
    pools = [
        {k: d.get(k) for k in ("user_api", "internal_api", "num_threads", "version", "threading_layer", "architecture")}
        for d in threadpool_info()
    ]
    info = {
        "cpu_model": _cpu_model(),
        "cpus": os.cpu_count(),
        "platform": platform.platform(),
        "machine": platform.machine(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "threadpools": pools,
        "openblas_core_types": sorted(
            {p["architecture"] for p in pools if p.get("internal_api") == "openblas" and p.get("architecture")}
        ),
        "environment": {
            k: os.environ[k]
            for k in (
                "OPENBLAS_CORETYPE",
                "OPENBLAS_NUM_THREADS",
                "OMP_NUM_THREADS",
                "MKL_NUM_THREADS",
                "NUMBA_NUM_THREADS",
                "NUMBA_CPU_NAME",
                "NUMBA_THREADING_LAYER",
            )
            if k in os.environ
        },
        "numba": None,
    }
    try:
        import scipy

        info["scipy"] = scipy.__version__
    except ImportError:  # pragma: no cover
        info["scipy"] = None
    numba = _numba()
    if numba is not None:
        nb = {
            "version": numba.__version__,
            "threads": numba.get_num_threads(),
            "pool_size": numba.config.NUMBA_NUM_THREADS,
            "threading_layer": None,
            "cpu_name": None,
        }
        try:
            nb["threading_layer"] = numba.threading_layer()
        except ValueError:
            pass  # no parallel region has run yet
        try:
            import llvmlite.binding as llvm

            nb["cpu_name"] = numba.config.CPU_NAME or llvm.get_host_cpu_name()
        except Exception:  # pragma: no cover - informative only
            pass
        info["numba"] = nb
    return info


def record(
    *,
    blas_threads: int,
    numba_threads: Optional[int] = None,
    repeats: Optional[int] = None,
    warmup: Optional[int] = None,
    statistic: str = "median",
    notes: Optional[str] = None,
) -> dict:
    """The protocol record of a run: command line, revision, threads, timing settings, machine (:func:`machine_info`).

    Call it inside :func:`limits` (the thread pools then report the limited counts).
    """
    argv = list(getattr(sys, "orig_argv", [sys.executable, *sys.argv]))
    out = {
        "command": shlex.join(argv),
        "cwd": os.getcwd(),
        "time_utc": time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime()),
        "git": _git(Path(__file__).resolve().parents[2]),
        "threads": {"blas": int(blas_threads), "numba": None if numba_threads is None else int(numba_threads)},
        "timing": {
            "warmup": warmup,
            "repeats": repeats,
            "statistic": statistic,
            "clock": "time.perf_counter",
            "ratios": "measured side by side in one process",
        },
        "machine": machine_info(),
    }
    if notes:
        out["notes"] = notes
    return out


def record_options(args: argparse.Namespace, **timing) -> dict:
    """:func:`record` of a run whose threads come from the options of :func:`add_arguments`.

    ``args.blas_threads`` and, where the script has ``--threads``, ``args.threads``; ``timing``: the other
    keywords of :func:`record` (``repeats``, ``warmup``, ``statistic``, ``notes``; ``numba_threads`` where the
    script fixes them).
    """
    return record(**{"blas_threads": args.blas_threads, "numba_threads": getattr(args, "threads", None), **timing})


def _jsonable(value):
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (np.floating,)):
        return float(value)
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    return str(value)


def write_json(path, result, protocol: dict, indent: int = 1) -> None:
    """Write ``result`` (a dict: its keys unchanged, ``"protocol"`` added; any other value under ``"results"``) to ``path``
    (its folder created where missing); ``path`` ``None`` (a run without ``--json``) writes nothing."""
    if path is None:
        return
    data = dict(result) if isinstance(result, dict) else {"results": result}
    data["protocol"] = protocol
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    from sympredict.container import atomic_output  # a report survives a full disk or Ctrl-C whole or not at all

    with atomic_output(path) as fh:
        fh.write(json.dumps(data, indent=indent, default=_jsonable).encode())
