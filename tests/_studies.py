"""The paper's studies run as their users run them: a script of ``sympredict_paper/studies/`` in a child process."""

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
