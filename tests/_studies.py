"""The paper's studies run as their users run them: a script of ``sympredict_paper/studies/`` in a child process."""

import contextlib
import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

#: the folder of the paper's study scripts
STUDIES = Path(__file__).resolve().parents[1] / "sympredict_paper" / "studies"


def run_study(script, json_path, *args, timeout=600):
    """Run ``STUDIES / script`` with ``args`` and ``--json json_path`` (one BLAS, OpenMP and numba thread each).

    Asserts that it exits 0 (the message is the end of its stderr); returns ``(its JSON, its stdout)``.
    """
    env = dict(os.environ, NUMBA_NUM_THREADS="1", OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    proc = subprocess.run(
        [sys.executable, str(STUDIES / script), *args, "--json", str(json_path)],
        capture_output=True,
        text=True,
        env=env,
        timeout=timeout,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(Path(json_path).read_text()), proc.stdout


@contextlib.contextmanager
def study_module(script):
    """Import ``STUDIES / script`` as a module, as the script itself runs: its folder on ``sys.path`` (the studies
    import their shared modules by name) and the module in ``sys.modules`` under its name (a dataclass looks its
    module up), both undone on exit."""
    name = Path(script).stem
    sys.path.insert(0, str(STUDIES))
    try:
        spec = importlib.util.spec_from_file_location(name, STUDIES / script)
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
        yield module
    finally:
        sys.modules.pop(name, None)
        sys.path.remove(str(STUDIES))
