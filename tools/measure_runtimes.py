"""Time what the README and the docs ask a reader to run; write docs/data/runtimes.json.

    .venv/bin/python tools/measure_runtimes.py                  # all but the test suite (20 min or more on 2 cores)
    .venv/bin/python tools/measure_runtimes.py --only demo pages # a part; the other entries are kept

What is timed (wall seconds, each in a fresh process, BLAS threads = the machine's cores):

* ``demo``: ``sympredict demo`` (the README's first command after installing), cold (a fresh, empty
  ``NUMBA_CACHE_DIR``: the first run on a new machine, compiling the Newton kernels) and warm (the
  same cache again); ``compile_s`` is their difference.
* ``quick``: ``sympredict-paper run pendulum --quick``, ``... run wave --quick`` and ``... run henon-heiles --quick``
  (keys ``pendulum``, ``wave``, ``henon_heiles``).
* ``pages``: every README/docs page with Python blocks: the blocks run in order in one process, as
  ``tests/docs/test_docs_examples.py`` runs them (warm compilation cache).
* ``basis``: the pyMOR tutorial's basis from every 10th snapshot against all 5,010 (time of
  ``psd_complex_svd``, projection error of all snapshots, principal angles between the two spans).
* ``tests``: the default test suite (``python -m pytest -q -x``), only with ``--only tests``.

The page numbers are rendered with the ``{json}`` role (``runtimes.json:pages.tutorials_pymor_rom.s`` for ``docs/tutorials/pymor_rom.md``).  Set
``--machine`` to say where it ran (a shared machine inflates every number).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "data" / "runtimes.json"
SYMPREDICT = [sys.executable, "-m", "sympredict.cli"]
PAPER = [sys.executable, "-m", "sympredict_paper"]
SKIP = re.compile(r"<!--\s*skip-example:")
FENCE = re.compile(r"^(`{3,})\s*([\w{}-]*)")


THREADS = os.cpu_count() or 1


def _env(cache: str | None = None) -> dict:
    cores = str(THREADS)
    env = {
        **os.environ,
        "OPENBLAS_NUM_THREADS": cores,
        "OMP_NUM_THREADS": cores,
        "MKL_NUM_THREADS": cores,
        "NUMBA_NUM_THREADS": cores,
        "MPLBACKEND": "agg",
    }
    if cache is not None:
        env["NUMBA_CACHE_DIR"] = cache
    return env


#: With --cpu-time: the seconds reported are the child's CPU time (user + system) instead of its wall time.
#: On a machine shared with other jobs the wall time is inflated by waiting for a core; with one BLAS
#: thread the CPU time is what the wall time is on an idle machine.
CPU_TIME = False
WALL = {}


def _timed(cmd, cwd, env, timeout=3600) -> float:
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(map(str, cmd))} failed ({proc.returncode}):\n{proc.stderr[-3000:]}")
    WALL[" ".join(map(str, cmd))] = {"wall_s": round(wall, 1), "cpu_s": round(cpu, 1)}
    return round(cpu if CPU_TIME else wall, 1)


def measure_demo(work: Path) -> dict:
    cache = tempfile.mkdtemp(prefix="numba-cache-")
    try:
        cold = _timed([*SYMPREDICT, "demo", "--out", "demo-cold"], work, _env(cache))
        warm = _timed([*SYMPREDICT, "demo", "--out", "demo-warm"], work, _env(cache))
    finally:
        shutil.rmtree(cache, ignore_errors=True)
    return {"command": "sympredict demo", "cold_s": cold, "warm_s": warm, "compile_s": round(max(0.0, cold - warm), 1)}


def measure_quick(work: Path) -> dict:
    out = {}
    for system in ("pendulum", "wave", "henon-heiles"):
        out[system.replace("-", "_")] = {
            "command": f"sympredict-paper run {system} --quick --out DIR",
            "s": _timed([*PAPER, "run", system, "--quick", "--out", f"run-{system}"], work, _env()),
        }
    return out


def page_blocks(page: Path) -> list[str]:
    """The page's runnable ```python blocks in order (those after a skip-example marker left out)."""
    lines, blocks, i, last = page.read_text(encoding="utf-8").split("\n"), [], 0, ""
    while i < len(lines):
        m = FENCE.match(lines[i])
        if not m:
            last = lines[i].strip() or last
            i += 1
            continue
        end = next(j for j in range(i + 1, len(lines)) if lines[j].startswith(m.group(1)))
        if m.group(2) == "python" and not SKIP.search(last):
            blocks.append("\n".join(lines[i + 1 : end]))
        last, i = "", end + 1
    return blocks


def page_key(page: Path) -> str:
    """``docs/tutorials/pymor_rom.md`` -> ``tutorials_pymor_rom`` (a key the ``{json}`` role can name)."""
    rel = page.relative_to(ROOT / "docs") if page.is_relative_to(ROOT / "docs") else Path(page.name.lower())
    return rel.with_suffix("").as_posix().replace("/", "_")


def measure_pages(work: Path) -> dict:
    pages = {}
    for page in [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]:
        blocks = page_blocks(page)
        if not blocks:
            continue
        folder = work / page_key(page)
        folder.mkdir(exist_ok=True)
        (folder / "page.py").write_text("\n\n".join(blocks) + "\n")
        name = page_key(page)
        pages[name] = {
            "page": page.relative_to(ROOT).as_posix(),
            "s": _timed([sys.executable, "page.py"], folder, _env()),
        }
        print(f"  {name}: {pages[name]['s']} s", flush=True)
    return pages


_BASIS_SCRIPT = r"""
import json, sys, time
import numpy as np
from pymor.algorithms.symplectic import psd_complex_svd
from pymor.operators.block import BlockDiagonalOperator
from pymor.operators.constructions import LincombOperator
from pymor.parameters.functionals import ExpressionParameterFunctional
from pymordemos.symplectic_wave_equation import discretize_fom

fom = discretize_fom(T=10)
stiffness, identity = fom.H_op.blocks[0, 0], fom.H_op.blocks[1, 1]
fom = fom.with_(H_op=BlockDiagonalOperator([LincombOperator([stiffness], [ExpressionParameterFunctional("c[0]**2 / 0.1**2", {"c": 1})]), identity]))
U = fom.solution_space.empty()
for mu in fom.parameters.space(0.08, 0.12).sample_uniformly(5):
    U.append(fom.solve(mu))
Un = U.to_numpy()
Un = Un if Un.shape[0] == fom.solution_space.dim else Un.T           # columns: snapshots

def span(RB):
    V = RB.to_array().to_numpy()
    V = V if V.shape[0] == fom.solution_space.dim else V.T
    return np.linalg.qr(V)[0]

out = {}
for name, every in (("all", 1), ("every_10th", 10)):
    t0 = time.process_time()  # CPU seconds: on a shared machine the wall time also counts the waits for a core
    RB = psd_complex_svd(U[::every], 4)
    seconds = time.process_time() - t0
    Q = span(RB)
    err = np.linalg.norm(Un - Q @ (Q.T @ Un), axis=0).max() / np.linalg.norm(Un, axis=0).max()
    out[name] = {"snapshots": len(U[::every]), "psd_complex_svd_s": round(seconds, 2), "projection_error": float(err), "Q": Q}
c = np.linalg.svd(out["all"].pop("Q").T @ out["every_10th"].pop("Q"), compute_uv=False)
out["min_cos_principal_angle"] = float(c.min())
json.dump(out, open(sys.argv[1], "w"))
"""


def measure_basis(work: Path) -> dict:
    """The pyMOR tutorial's basis from every 10th snapshot against all: time, projection error, angles."""
    (work / "basis.py").write_text(_BASIS_SCRIPT)
    _timed([sys.executable, "basis.py", "basis.json"], work, _env())
    r = json.loads((work / "basis.json").read_text())
    r["command"] = "psd_complex_svd(U, 4) against psd_complex_svd(U[::10], 4) on the pyMOR tutorial's 5 trajectories"
    return r


def measure_tests(work: Path) -> dict:
    s = _timed([sys.executable, "-m", "pytest", "-q", "-x", "-p", "no:cacheprovider"], ROOT, _env(), timeout=7200)
    return {"command": ".venv/bin/python -m pytest", "default_suite_s": s, "default_suite_min": round(s / 60, 1)}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument(
        "--only",
        nargs="+",
        choices=["demo", "quick", "pages", "basis", "tests"],
        default=["demo", "quick", "pages", "basis"],
    )
    parser.add_argument(
        "--machine",
        default=f"{os.cpu_count()} cores, {platform.machine()} {platform.system()}",
        help="where it ran (say 'shared' if other jobs ran beside it)",
    )
    parser.add_argument("--out", type=Path, default=OUT)
    parser.add_argument(
        "--threads", type=int, default=os.cpu_count() or 1, help="BLAS/numba threads (default: all cores)"
    )
    parser.add_argument(
        "--cpu-time",
        action="store_true",
        help="report CPU seconds instead of wall seconds (a shared machine; use with --threads 1)",
    )
    args = parser.parse_args(argv)
    global THREADS, CPU_TIME
    THREADS, CPU_TIME = args.threads, args.cpu_time
    data = json.loads(args.out.read_text()) if args.out.is_file() else {}
    data.update(
        {
            "command": "python tools/measure_runtimes.py " + " ".join(f"--only {' '.join(args.only)}".split()),
            "machine": args.machine,
            "threads": args.threads,
            "seconds": "CPU time of the process (user + system)" if args.cpu_time else "wall time",
        }
    )
    work = Path(tempfile.mkdtemp(prefix="sympredict-runtimes-"))
    try:
        for part in args.only:
            print(f"{part} ...", flush=True)
            data[part] = {**data.get(part, {}), **globals()[f"measure_{part}"](work)}
            data["wall_and_cpu"] = {**data.get("wall_and_cpu", {}), **WALL}
            args.out.write_text(json.dumps(data, indent=1) + "\n")
    finally:
        shutil.rmtree(work, ignore_errors=True)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
