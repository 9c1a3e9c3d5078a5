"""Two revisions of sympredict measured side by side: each revision's own benchmark suite, interleaved.

Usage (from the repository root, with the project's virtual environment)::

    .venv/bin/python benchmarks/compare_revisions.py BEFORE AFTER --sections greedy,rollout,scenario_a --repeats 2

``BEFORE`` and ``AFTER`` are git revisions (``HEAD`` is the working tree's
commit).  Each is checked out into a temporary worktree; its own
``benchmarks/suite.py`` runs there in a child process whose ``PYTHONPATH``
puts that worktree's ``sympredict`` first (the child prints which package it
imported, and the driver checks it).  Runs alternate ``BEFORE, AFTER, BEFORE,
AFTER, ...`` so that a change of machine load hits both; the table gives
each metric's median over the repeats and the ratio AFTER / BEFORE
(``benchmarks/_protocol.py``).  Both suites get the same threads: ``--threads``
numba threads and ``--blas-threads`` BLAS threads (default: as many as
``--threads``, since a suite from before the protocol sets both with
``--threads``; a smaller value needs two revisions whose suites take
``--blas-threads``).

Writes ``<out>/compare.json`` (every run's suite results, and the protocol
record: command line, threads, machine) and ``<out>/compare.md`` (the table),
and prints the table.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _protocol  # noqa: E402  (benchmarks/_protocol.py)

ROOT = Path(__file__).resolve().parents[1]

#: (label, path in suite.json, what it means): the targets of the core reshaping (issue 11).
METRICS = [
    ("greedy: exact f-greedy time (s)", ("greedy", "time_s")),
    ("greedy: time / in-run matvec bound", ("greedy", "bandwidth", "ratio_total")),
    ("rollout: compiled trajectory-steps/s (1500 centres, batch 1000)", ("rollout", "numba", "traj_steps_per_s")),
    ("rollout: NumPy trajectory-steps/s", ("rollout", "numpy", "traj_steps_per_s")),
    ("rollout: compiled ms per step of one trajectory", ("rollout", "numba", "latency_ms_per_step_in_rollout")),
    ("rollout: compiled pass / factor cost", ("rollout", "compute_bound", "ratio")),
    ("scenario A: active-set training (s)", ("scenario_a", "fast", "time_train_s")),
    ("scenario A: active-set max residual (direct)", ("scenario_a", "fast", "E_train_direct")),
    ("scenario A: exact greedy training (s)", ("scenario_a", "exact", "time_train_s")),
    ("scenario A: exact greedy / in-run matvec bound", ("scenario_a", "exact", "bandwidth", "ratio_total")),
    ("scenario A: exact greedy peak memory (GiB)", ("scenario_a", "exact", "peak_rss_bytes")),
]


def _get(d, path):
    for key in path:
        if not isinstance(d, dict) or key not in d:
            return None
        d = d[key]
    return d


def _worktree(rev: str, where: Path) -> Path:
    subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(where), rev], check=True,
                   capture_output=True, text=True)
    return where


def _takes_blas_threads(tree: Path) -> bool:
    """Whether the revision's suite sets BLAS threads apart from numba's (``--blas-threads``, the protocol's)."""
    return "import _protocol" in (tree / "benchmarks" / "suite.py").read_text()


def _run_suite(tree: Path, sections: str, threads: int, blas_threads: int, extra: list, out: Path) -> dict:
    env = dict(os.environ, PYTHONPATH=str(tree))
    check = subprocess.run([sys.executable, "-c", "import sympredict, sys; print(sympredict.__file__)"], env=env,
                           cwd=tree, capture_output=True, text=True, check=True)
    if not check.stdout.strip().startswith(str(tree)):
        raise RuntimeError(f"the child imported {check.stdout.strip()}, not the worktree {tree}")
    cmd = [sys.executable, "benchmarks/suite.py", "--sections", sections, "--threads", str(threads), "--out", str(out),
           "--figure", ""] + extra
    if _takes_blas_threads(tree):
        cmd += ["--blas-threads", str(blas_threads)]
    elif blas_threads != threads:
        raise SystemExit(f"the suite of {tree.name} sets BLAS threads = --threads ({threads}); it cannot run with "
                         f"--blas-threads {blas_threads}: compare with the same count for both")
    subprocess.run(cmd, env=env, cwd=tree, check=True)
    return json.loads((out / "suite.json").read_text())


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("before")
    parser.add_argument("after")
    parser.add_argument("--sections", default="greedy,rollout")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--threads", type=int, default=2, help="numba threads of both suites (default 2)")
    parser.add_argument("--blas-threads", type=int, default=None,
                        help="BLAS threads of both suites (default: --threads, as a suite from before the protocol sets)")
    parser.add_argument("--out", default="benchmarks/results/compare")
    args, extra = parser.parse_known_args(argv)
    blas_threads = args.threads if args.blas_threads is None else args.blas_threads
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    runs = {"before": [], "after": []}
    with tempfile.TemporaryDirectory() as tmp:
        trees = {"before": _worktree(args.before, Path(tmp) / "before"), "after": _worktree(args.after, Path(tmp) / "after")}
        try:
            for rep in range(args.repeats):
                for label in ("before", "after"):
                    print(f"--- {label} ({getattr(args, label)}), repeat {rep + 1}/{args.repeats}", flush=True)
                    res = _run_suite(trees[label], args.sections, args.threads, blas_threads, extra, Path(tmp) / f"{label}{rep}")
                    runs[label].append(res)
        finally:
            for tree in trees.values():
                subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(tree)], capture_output=True)
    lines = [f"| metric | before ({args.before}) | after ({args.after}) | after / before |", "|---|---|---|---|"]
    table = []
    for label, path in METRICS:
        b = [v for v in (_get(r, path) for r in runs["before"]) if v is not None]
        a = [v for v in (_get(r, path) for r in runs["after"]) if v is not None]
        if not a or not b:
            continue
        scale = 2.0**-30 if path[-1] == "peak_rss_bytes" else 1.0
        mb, ma = float(np.median(b)) * scale, float(np.median(a)) * scale
        table.append({"metric": label, "before": mb, "after": ma, "ratio": ma / mb, "n": (len(b), len(a))})
        lines.append(f"| {label} | {mb:.3g} | {ma:.3g} | {ma / mb:.2f} |")
    md = "\n".join(lines) + "\n"
    (out / "compare.md").write_text(md)
    protocol = _protocol.record(blas_threads=blas_threads, numba_threads=args.threads, repeats=args.repeats,
                                statistic="median over the repeats of each metric (runs alternating before/after)")
    _protocol.write_json(out / "compare.json", {"args": vars(args), "extra": extra, "table": table, "runs": runs}, protocol)
    print(md)
    return {"table": table}


if __name__ == "__main__":
    main()
