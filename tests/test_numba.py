"""The compiled kernels compile once per machine: numba's disk cache across processes, and surviving a bad cache.

Fresh processes share a private cache folder (``NUMBA_CACHE_DIR``); what they
compiled or loaded is read from numba's own counters (``stats.cache_hits`` and
``stats.cache_misses`` of the dispatchers), not from wall-clock time.
"""

import json
import logging
import os
import subprocess
import sys

import numpy as np
import pytest

from sympredict import _numba
from sympredict.kernels import _compiled as compiled_kernels
from sympredict.interpolation import _compiled as compiled_surrogate
from sympredict.kernels import KERNEL_FAMILIES, RadialKernel

pytestmark = pytest.mark.skipif(not _numba.HAVE_NUMBA, reason="the compiled kernels need numba (optional extra)")

#: One serial compiled rollout (IMQ, 2n = 2) in a fresh process; prints what it compiled, loaded and logged.
SCRIPT = r"""
import json, logging, os, shutil, sys
import numpy as np

messages = []


class Keep(logging.Handler):
    def emit(self, record):
        messages.append(record.getMessage())


logging.getLogger("sympredict").addHandler(Keep())
from sympredict import _numba
from sympredict.symplectic import _compiled_newton as fk

from sympredict import _numba
from sympredict.kernels import _compiled as compiled_kernels
from sympredict.interpolation import _compiled as compiled_surrogate
from sympredict.kernels import IMQ, ProductKernel
from sympredict.interpolation.surrogate import HBSurrogate

if sys.argv[1] == "unwritable":  # after import (numba has chosen the folder): a file where the folder was
    cache = os.environ["NUMBA_CACHE_DIR"]
    shutil.rmtree(cache)
    open(cache, "w").close()
rng = np.random.default_rng(0)
m = 40
sur = HBSurrogate(ProductKernel(IMQ(0.6), IMQ(1.0)), rng.normal(size=(m, 2)), rng.normal(size=(m, 1)), np.ones(m),
                  rng.integers(0, 2, m), 1e-3 * rng.normal(size=m))
x = 0.5 * rng.normal(size=(3, 2))
w = sur.weights(rng.normal(size=(3, 1)), np.ones(3))
traj = fk.newton_rollout(x, w, np.full(3, 0.05), sur.layout(), IMQ(0.6), 50, 5, parallel=False)[0]
print(json.dumps({
    "traj": traj.tolist(),
    "entry_hits": sum(fk._rollout_serial.stats.cache_hits.values()),
    "compiled": sorted(d.py_func.__name__ for d in _numba.CACHED if sum(d.stats.cache_misses.values())),
    "messages": messages,
}))
"""


def _run(mode: str, cache_dir) -> dict:
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache_dir), NUMBA_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    proc = subprocess.run([sys.executable, "-c", SCRIPT, mode], env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


@pytest.fixture(scope="module")
def primed(tmp_path_factory):
    """A cache folder after one process compiled into it, and that process's report."""
    cache = tmp_path_factory.mktemp("numba_cache")
    return cache, _run("plain", cache)


def test_a_second_process_loads_the_kernels_from_disk(primed):
    cache, first = primed
    assert "_rollout_serial" in first["compiled"] and "_pass" in first["compiled"]
    second = _run("plain", cache)
    assert second["entry_hits"] >= 1
    assert second["compiled"] == []  # nothing compiled in the second process: the callees came with the entry
    assert second["messages"] == []
    np.testing.assert_array_equal(second["traj"], first["traj"])
    # one index per compiled function, not one per process
    index = sorted(p.name for p in cache.rglob("*.nbi"))
    assert len(index) == len(set(index))
    assert _run("plain", cache)["compiled"] == [] and sorted(p.name for p in cache.rglob("*.nbi")) == index


def test_a_corrupt_cache_costs_compilation_not_an_error(primed, tmp_path):
    cache, first = primed
    bad = tmp_path / "bad_cache"
    bad.mkdir()
    for p in cache.rglob("*"):  # a copy of the primed cache with every file overwritten by garbage
        if p.is_file():
            target = bad / p.relative_to(cache)
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_bytes(b"not a pickle" * 10)
    out = _run("plain", bad)
    np.testing.assert_array_equal(out["traj"], first["traj"])
    assert len(out["messages"]) == 1 and "disk cache" in out["messages"][0]


def test_an_unwritable_cache_costs_compilation_not_an_error(tmp_path, primed):
    out = _run("unwritable", tmp_path / "gone")
    np.testing.assert_array_equal(out["traj"], primed[1]["traj"])
    assert len(out["messages"]) == 1 and "disk cache" in out["messages"][0]


def test_no_cache_folder_at_all_leaves_a_kernel_uncached_with_one_warning(monkeypatch, caplog):
    """``cache=True`` raises when no folder is usable (a read-only install); the kernel then compiles uncached."""
    scope = {}
    exec("def twice(x):\n    return 2.0 * x\n", scope)  # no source file: numba finds no cache folder for it
    monkeypatch.setattr(_numba, "_CACHE_WARNED", False)
    monkeypatch.setattr(_numba, "CACHED", [])
    with caplog.at_level(logging.WARNING, logger="sympredict"):
        twice = _numba.jit_cached(scope["twice"], _numba.JIT)
        _numba.jit_cached(scope["twice"], _numba.JIT)
    assert twice(1.5) == 3.0
    assert len(caplog.records) == 1 and "disk cache" in caplog.records[0].getMessage()


def test_every_family_of_the_package_has_a_code():
    """A family of the package without a code would run on the uncached path (compiled in every process)."""
    own = {f for f in KERNEL_FAMILIES.values() if f.__module__.startswith("sympredict.")}
    assert own == set(compiled_kernels.FAMILY_CODES)
    assert sorted(compiled_kernels.FAMILY_CODES.values()) == list(range(len(own)))


def test_families_from_outside_the_package_stay_out_of_the_disk_cache():
    class Outside(RadialKernel):
        name = "outside"

        @staticmethod
        def profile(e, r):
            return 1.0 / (1.0 + (e * r) ** 2)

    ns, codes = compiled_kernels.family_kernels(Outside, compiled_kernels.IMQ)
    assert codes == (-1, 0)
    from numba.core.caching import NullCache

    for name, _, _, cached in _numba.DEFINITIONS:
        compiled = getattr(ns, name)
        assert compiled is not cached
        assert isinstance(compiled._cache, NullCache)
    assert compiled_kernels.family_kernels(compiled_kernels.IMQ)[0]._pass is compiled_surrogate._pass


def test_numba_is_taken_from_the_policy_module_only():
    """One numba policy: no library module imports numba or sets numba's disk cache on its own (numba's typing
    extension for the family codes stays with the code it types)."""
    import ast
    from pathlib import Path

    package = Path(_numba.__file__).parent
    allowed = {package / "_numba.py", package / "kernels" / "_compiled.py"}
    offenders = []
    for path in sorted(package.rglob("*.py")):
        if path in allowed or "paper" in path.relative_to(package).parts:
            continue
        tree = ast.parse(path.read_text(), str(path))
        for node in ast.walk(tree):
            names = (
                [a.name for a in node.names]
                if isinstance(node, ast.Import)
                else [node.module or ""]
                if isinstance(node, ast.ImportFrom)
                else []
            )
            if any(n == "numba" or n.startswith("numba.") for n in names):
                offenders.append(f"{path.relative_to(package)}:{node.lineno} imports numba")
            if isinstance(node, ast.keyword) and node.arg == "cache":
                offenders.append(f"{path.relative_to(package)}:{node.lineno} sets cache=")
    assert not offenders, offenders
