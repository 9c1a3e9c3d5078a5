"""Mutation check: apply a fixed list of meaningful faults, one at a time, and run the tests that must catch each.

Usage (from the repository root, with the project's virtual environment)::

    .venv/bin/python tools/mutation_check.py                 # every fault, one at a time
    .venv/bin/python tools/mutation_check.py --only F1 E1    # some faults
    .venv/bin/python tools/mutation_check.py --list          # the list, nothing run
    .venv/bin/python tools/mutation_check.py --jobs 2 --json result.json

Each fault is an exact source snippet and its replacement in one file, with the
test files to run (the list: ``tools/mutation_faults.json``).  The script copies the tree once into a temporary folder
(the working tree is never touched), and for each fault restores the pristine
file, applies the replacement and runs ``pytest -x -q`` on the listed files
with the copy first on ``sys.path``.  Outcomes:

* ``CAUGHT``   -- the tests failed (what we want);
* ``SURVIVED`` -- the tests passed with the fault in place;
* ``TIMEOUT``  -- the tests ran past ``--timeout`` (counted as caught, listed);
* ``ERROR``    -- the snippet occurs zero times or more than once: the code moved or
  changed, and the fault must be re-targeted.  Never skipped silently.

The exit status is 0 only when every fault is caught (``CAUGHT`` or ``TIMEOUT``).
CPU use: one pytest process per fault (``--jobs`` in parallel); the whole list
takes several minutes on 2 cores.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class Fault:
    id: str
    area: str
    file: str
    snippet: str
    replacement: str
    tests: tuple
    what: str


#: The faults, one JSON object a line (id, area, what, file, snippet, replacement, tests): a table of data,
#: kept beside this script; each ``snippet`` stands verbatim, exactly once, in its ``file``.
FAULTS_FILE = ROOT / "tools" / "mutation_faults.json"
FAULTS = [Fault(**{**row, "tests": tuple(row["tests"])}) for row in json.loads(FAULTS_FILE.read_text(encoding="utf-8"))]
_duplicate_ids = sorted({f.id for f in FAULTS if sum(g.id == f.id for g in FAULTS) > 1})
assert not _duplicate_ids, f"fault ids must be unique (--only selects by id): {_duplicate_ids}"


def _copy_tree(dst: Path):
    ignore = shutil.ignore_patterns(
        ".venv", ".git", "_build", "__pycache__", "*.pyc", ".pytest_cache", ".hypothesis", "*.egg-info"
    )
    shutil.copytree(ROOT, dst, ignore=ignore, dirs_exist_ok=True)


def run_fault(fault: Fault, workdir: Path, timeout: float) -> dict:
    """Apply ``fault`` in a private copy ``workdir`` of the tree and run its tests; returns the outcome."""
    target = workdir / fault.file
    pristine = (ROOT / fault.file).read_text()
    count = pristine.count(fault.snippet)
    result = {**asdict(fault), "tests": list(fault.tests), "seconds": 0.0}  # early returns ran nothing
    if count != 1:
        result.update(
            outcome="ERROR", detail=f"snippet found {count} times in {fault.file} (the code moved: re-target the fault)"
        )
        return result
    missing = [t for t in fault.tests if not (workdir / t).exists()]
    if missing:
        result.update(outcome="ERROR", detail=f"test files missing: {missing}")
        return result
    target.write_text(pristine.replace(fault.snippet, fault.replacement))
    env = {
        **os.environ,
        "PYTHONPATH": str(workdir),
        "PYTHONDONTWRITEBYTECODE": "1",
        "OMP_NUM_THREADS": "1",
        "OPENBLAS_NUM_THREADS": "1",
        "MKL_NUM_THREADS": "1",
        "NUMBA_NUM_THREADS": "1",
        # a fresh compiled-code cache per fault: numba checks a cached kernel against its own file's date only,
        # so kernels cached under another fault would hide (or fake) a fault in a formula they inline
        "NUMBA_CACHE_DIR": str(workdir / ".numba_cache" / fault.id),
    }
    cmd = [sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", *fault.tests]
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(cmd, cwd=workdir, env=env, capture_output=True, text=True, timeout=timeout)
        out = proc.stdout + proc.stderr
        if proc.returncode == 0:
            result.update(outcome="SURVIVED", detail=out.strip().splitlines()[-1] if out.strip() else "")
        elif proc.returncode in (1,):
            failed = [line for line in out.splitlines() if line.startswith(("FAILED", "ERROR"))]
            result.update(outcome="CAUGHT", detail=failed[0] if failed else out.strip().splitlines()[-1])
        else:
            result.update(outcome="ERROR", detail=f"pytest exit code {proc.returncode}: {out.strip()[-500:]}")
    except subprocess.TimeoutExpired:
        result.update(outcome="TIMEOUT", detail=f"tests ran past {timeout:.0f} s")
    finally:
        target.write_text(pristine)
    result["seconds"] = round(time.perf_counter() - t0, 1)
    return result


def _check_import_path(workdir: Path):
    """The copy, not the installed checkout, must be what the tests import."""
    env = {**os.environ, "PYTHONPATH": str(workdir)}
    got = subprocess.run(
        [sys.executable, "-c", "import sympredict, os; print(os.path.dirname(sympredict.__file__))"],
        cwd=workdir,
        env=env,
        capture_output=True,
        text=True,
    ).stdout.strip()
    if Path(got).resolve() != (workdir / "sympredict").resolve():
        raise SystemExit(f"mutation_check: the tests would import sympredict from {got}, not from the copy {workdir}")


def summary_by_area(results: list[dict]) -> list[dict]:
    """Per area, in order of first appearance: ``area``, ``faults``, ``caught`` (``CAUGHT`` or ``TIMEOUT``) and the ``ids``."""
    areas: dict = {}
    for r in results:
        a = areas.setdefault(r["area"], {"area": r["area"], "faults": 0, "caught": 0, "ids": []})
        a["faults"] += 1
        a["caught"] += r["outcome"] in ("CAUGHT", "TIMEOUT")
        a["ids"].append(r["id"])
    return list(areas.values())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--only", nargs="+", metavar="ID", help="run these faults only")
    ap.add_argument("--list", action="store_true", help="print the faults and exit")
    ap.add_argument("--jobs", type=int, default=1, help="faults run in parallel (each in its own copy of the tree)")
    ap.add_argument("--timeout", type=float, default=900, help="seconds per fault before it counts as TIMEOUT")
    ap.add_argument("--json", help="write the results here")
    args = ap.parse_args(argv)
    faults = FAULTS
    if args.only:
        unknown = set(args.only) - {f.id for f in FAULTS}
        if unknown:
            ap.error(f"unknown fault ids: {sorted(unknown)}")
        faults = [f for f in FAULTS if f.id in args.only]
    if args.list:
        for f in faults:
            print(f"{f.id:4s} {f.area:12s} {f.file:32s} {f.what}")
        return 0
    with tempfile.TemporaryDirectory(prefix="sympredict-mutants-") as tmp:
        workdirs = [Path(tmp) / f"copy{i}" for i in range(max(1, args.jobs))]
        for w in workdirs:
            _copy_tree(w)
        _check_import_path(workdirs[0])
        t0 = time.perf_counter()
        results = [None] * len(faults)

        def run_chunk(k):
            # copy k runs faults k, k + jobs, ...: faults that share a copy run one after the other
            for i in range(k, len(faults), len(workdirs)):
                results[i] = run_fault(faults[i], workdirs[k], args.timeout)
                r = results[i]
                print(
                    f"{r['id']:4s} {r['outcome']:8s} {r['seconds']:6.1f} s  {r['what']}"
                    + (f"  [{r['detail']}]" if r["outcome"] != "CAUGHT" else ""),
                    flush=True,
                )

        with ThreadPoolExecutor(len(workdirs)) as pool:
            list(pool.map(run_chunk, range(len(workdirs))))
        total = time.perf_counter() - t0
    counts = {k: sum(r["outcome"] == k for r in results) for k in ("CAUGHT", "TIMEOUT", "SURVIVED", "ERROR")}
    print(f"{len(results)} faults in {total:.0f} s: " + ", ".join(f"{v} {k.lower()}" for k, v in counts.items()))
    if args.json:
        # command and machine: the documentation prints them under the tables it renders from this file
        record = {
            "command": shlex.join(getattr(sys, "orig_argv", [sys.executable, *sys.argv])),
            "machine": f"{os.cpu_count()} CPUs, {platform.platform()}",
            "total_seconds": total,
            "counts": counts,
            "areas": summary_by_area(results),
            "results": results,
        }
        Path(args.json).write_text(json.dumps(record, indent=1))
    return 0 if counts["SURVIVED"] == counts["ERROR"] == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
