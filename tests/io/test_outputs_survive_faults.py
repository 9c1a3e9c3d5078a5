"""Outputs survive a full disk, a file-size limit and Ctrl-C; concurrent writers cannot both win."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from sympredict import cli
from sympredict.container import atomic_output
from sympredict.data import TrajectoryData
from sympredict.io.trajectories import write_trajectories

ENV = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")


def _data(p=3, k=4, n=1, d=1, seed=0):
    rng = np.random.default_rng(seed)
    return TrajectoryData(rng.normal(size=(p, k + 1, 2 * n)), rng.uniform(0.5, 1.0, (p, d)) if d else None, 0.1)


def _only(folder: Path) -> list:
    return sorted(p.name for p in folder.iterdir())


# --------------------------------------------------------------------------- atomic outputs
@pytest.mark.parametrize("suffix", [".csv", ".npz", ".h5"])
def test_trajectories_over_a_file_size_limit_keep_the_previous_file(tmp_path, suffix):
    """A write that hits RLIMIT_FSIZE (EFBIG, as a full disk) fails with one OSError naming the file; the old file stays."""
    path = tmp_path / f"out{suffix}"
    write_trajectories(_data(), path)
    before = path.read_bytes()
    script = f"""
import resource, signal, sys
import numpy as np
from sympredict.data import TrajectoryData
from sympredict.io.trajectories import write_trajectories
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
resource.setrlimit(resource.RLIMIT_FSIZE, (200000, resource.RLIM_INFINITY))
data = TrajectoryData(np.random.default_rng(1).normal(size=(40, 400, 4)), np.ones(40), 0.1)
try:
    write_trajectories(data, {str(path)!r})
except OSError as exc:
    print(f"error: {{exc}}", file=sys.stderr)
    sys.exit(3)
"""
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120, env=ENV)
    assert proc.returncode == 3, proc.stderr
    assert "could not save" in proc.stderr and str(path) in proc.stderr and "previous file" in proc.stderr
    assert path.read_bytes() == before
    assert _only(tmp_path) == [path.name]


def test_cli_data_force_over_a_file_size_limit_keeps_the_previous_file(tmp_path):
    """``sympredict data --out F --force`` on a full disk: exit 1, one line naming F, F unchanged."""
    path = tmp_path / "hh.csv"
    path.write_text("previous contents\n")
    warm = tmp_path / "warm" / "hh.csv"  # the first run fills numba's cache, which the size limit would also stop
    warm.parent.mkdir()
    script = f"""
import resource, signal, sys
from sympredict.cli import main
args = ["data", "--system", "henon-heiles", "--trajectories", "60", "--steps", "60"]
assert main(args + ["--out", {str(warm)!r}]) == 0
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
resource.setrlimit(resource.RLIMIT_FSIZE, (100000, resource.RLIM_INFINITY))
sys.exit(main(args + ["--out", {str(path)!r}, "--force"]))
"""
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300, env=ENV)
    assert proc.returncode == 1, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "could not save" in lines[0] and str(path) in lines[0], proc.stderr
    assert path.read_text() == "previous contents\n"
    assert _only(tmp_path) == [path.name, "warm"] and warm.stat().st_size > 100000


def test_ctrl_c_while_writing_trajectories_keeps_the_previous_file(tmp_path):
    """SIGINT in the middle of a long CSV write: the previous file is intact, no temporary file, the message names it."""
    path = tmp_path / "big.csv"
    path.write_text("previous\n")
    script = f"""
import sys, time
import numpy as np
from sympredict.data import TrajectoryData
from sympredict.io.trajectories import write_trajectories
data = TrajectoryData(np.random.default_rng(1).normal(size=(400, 2001, 4)), np.ones(400), 0.1)
print("ready", flush=True)
try:
    write_trajectories(data, {str(path)!r})
except KeyboardInterrupt as exc:
    print(f"interrupted: {{exc}}", file=sys.stderr)
    sys.exit(130)
"""
    proc = subprocess.Popen(
        [sys.executable, "-c", script],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=ENV,
        # as in a terminal: a run started in the background with SIGINT ignored must not pass that on to the child
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    assert proc.stdout.readline().strip() == "ready"
    deadline = time.time() + 60
    while time.time() < deadline and not any(
        p.name.endswith(".tmp") and p.stat().st_size > 0 for p in tmp_path.iterdir()
    ):
        time.sleep(0.01)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert "was not written" in err and str(path) in err
    assert path.read_text() == "previous\n"
    assert _only(tmp_path) == [path.name]


def test_no_overwrite_refuses_an_existing_file(tmp_path):
    path = tmp_path / "t.npz"
    write_trajectories(_data(), path)
    before = path.read_bytes()
    with pytest.raises(FileExistsError, match="exists: not replaced"):
        write_trajectories(_data(seed=1), path, overwrite=False)
    assert path.read_bytes() == before


def test_no_overwrite_loses_to_a_file_created_while_writing(tmp_path):
    """Two writers without --force: the one that publishes second gets FileExistsError, the first one's file stays."""
    path = tmp_path / "m.bin"
    with pytest.raises(FileExistsError, match="created by someone else"):
        with atomic_output(path, overwrite=False) as fh:
            fh.write(b"second writer")
            path.write_bytes(b"first writer")  # the other process publishes meanwhile
    assert path.read_bytes() == b"first writer"
    assert _only(tmp_path) == [path.name]


def test_overwrite_true_replaces_whole_files(tmp_path):
    path = tmp_path / "m.bin"
    with atomic_output(path) as fh:
        fh.write(b"a" * 10)
    with atomic_output(path) as fh:
        fh.write(b"b" * 5)
        assert path.read_bytes() == b"a" * 10  # unchanged until the rename
    assert path.read_bytes() == b"b" * 5


def test_an_exception_inside_the_block_writes_nothing(tmp_path):
    path = tmp_path / "m.bin"
    path.write_bytes(b"old")
    with pytest.raises(RuntimeError):
        with atomic_output(path) as fh:
            fh.write(b"new")
            raise RuntimeError("boom")
    assert path.read_bytes() == b"old" and _only(tmp_path) == ["m.bin"]


def test_concurrent_cli_train_without_force_second_is_refused(tmp_path, small_pendulum_data, monkeypatch, capsys):
    """``train --out same.h5`` twice at once without --force: the second to finish is refused, its model kept aside."""
    from sympredict import SymplecticKernelPredictor
    from sympredict.io import save_dataset

    data = tmp_path / "d.h5"
    save_dataset(small_pendulum_data, data)
    out = tmp_path / "same.h5"
    real_fit = SymplecticKernelPredictor.fit

    def fit_while_another_run_saves(self, *args, **kwargs):
        result = real_fit(self, *args, **kwargs)
        out.write_bytes(b"the other run's model")  # the concurrent run saved first
        return result

    monkeypatch.setattr(SymplecticKernelPredictor, "fit", fit_while_another_run_saves)
    code = cli.main(["train", str(data), "--out", str(out), "--max-centers", "20", "--threads", "1"])
    err = capsys.readouterr().err
    assert code == 1 and "not replaced" in err and "kept in" in err, err
    assert out.read_bytes() == b"the other run's model"


def test_cli_train_user_data_without_max_centers(tmp_path, capsys):
    """``sympredict train data.npz --out m.h5`` without --max-centers trains with the estimator's default."""
    from sympredict.systems.pendulum import Pendulum

    pend = Pendulum()
    x0 = np.column_stack([np.linspace(-0.6, 0.6, 6), np.linspace(0.4, -0.4, 6)])
    states = pend.trajectory(x0, np.full(6, 0.75), 0.1, 8)
    np.savez(tmp_path / "d.npz", states=states, dt=0.1)
    code = cli.main(["train", str(tmp_path / "d.npz"), "--out", str(tmp_path / "m.h5"), "--threads", "1"])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert (tmp_path / "m.h5").is_file() and "must be an integer" not in err
