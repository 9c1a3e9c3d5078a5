"""Start-up: a numba that cannot start falls back to NumPy with one warning; a bad MPLBACKEND breaks neither predict nor
plotting."""

import os
import subprocess
import sys
from pathlib import Path


ROOT = Path(__file__).resolve().parents[1]


def _python(code, **env):
    return subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env={**os.environ, **env}, cwd=ROOT
    )


def test_invalid_numba_thread_count_falls_back_to_numpy_with_one_warning():
    code = (
        "import warnings; warnings.simplefilter('always')\n"
        "import numpy as np, sympredict\n"
        "from sympredict import _numba\n"
        "from sympredict.kernels import IMQ\n"
        "assert not _numba.HAVE_NUMBA\n"
        "x0 = np.random.default_rng(0).uniform(-1, 1, (20, 2)); x1 = x0 + 0.05 * x0[:, ::-1]\n"
        "m = sympredict.SymplecticKernelPredictor(IMQ(0.5), max_centers=10).fit(x0, x1, dt=0.1)\n"
        "print(np.isfinite(m.step(x0[:2] * 0.5)).all())\n"
    )
    proc = _python(code, NUMBA_NUM_THREADS="0")
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "True"
    assert proc.stderr.count("RuntimeWarning") == 1 and "NUMBA_NUM_THREADS" in proc.stderr


def test_bad_mplbackend_does_not_break_predict(coarse_pendulum_model_file):
    code = (
        "import sys\nfrom sympredict.cli import main\n"
        f"rc = main(['predict', {str(coarse_pendulum_model_file)!r}, '--x0', '0.5,0.1', '--steps', '2'])\n"
        "assert 'matplotlib' not in sys.modules\nsys.exit(rc)\n"
    )
    proc = _python(code, MPLBACKEND="no-such-backend", NUMBA_NUM_THREADS="1")
    assert proc.returncode == 0, proc.stderr
    assert "instance 0" in proc.stdout


def test_bad_mplbackend_does_not_break_plotting():
    proc = _python(
        "import sympredict_paper.plotting as p, matplotlib, os\n"
        "assert matplotlib.get_backend().lower() == 'agg' and os.environ['MPLBACKEND'] == 'no-such-backend'\n",
        MPLBACKEND="no-such-backend",
        NUMBA_NUM_THREADS="1",
    )
    assert proc.returncode == 0, proc.stderr
