"""Users' files, outputs that survive faults, fork safety, scales per coordinate: each case named by what it tests."""

import io
import os
import signal
import struct
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest

from sympredict import cli
from sympredict.container import atomic_output
from sympredict.data import TrajectoryData
from sympredict.io.trajectories import MAX_CSV_LINE, read_states, read_trajectories, write_trajectories

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
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=ENV)
    assert proc.stdout.readline().strip() == "ready"
    deadline = time.time() + 60
    while time.time() < deadline and not any(p.name.endswith(".tmp") and p.stat().st_size > 0 for p in tmp_path.iterdir()):
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


# --------------------------------------------------------------------------- parameter columns by name
def test_read_states_matches_parameter_columns_by_name(tmp_path):
    path = tmp_path / "x0.csv"
    path.write_text("q,p,mu2,mu1\n0.1,0.2,0.0802,0.5144\n0.3,0.4,0.1778,0.5188\n")
    x0, mu = read_states(path, 2)
    np.testing.assert_array_equal(mu, [[0.5144, 0.0802], [0.5188, 0.1778]])
    np.testing.assert_array_equal(x0, [[0.1, 0.2], [0.3, 0.4]])


def test_read_states_state_columns_in_any_order(tmp_path):
    path = tmp_path / "x0.csv"
    path.write_text("mu1,p2,q2,p1,q1\n7,4,2,3,1\n")
    x0, mu = read_states(path, 4)
    np.testing.assert_array_equal(x0, [[1, 2, 3, 4]])
    np.testing.assert_array_equal(mu, [[7]])


@pytest.mark.parametrize("header, match", [("q,p,mu1,mu3", "without gaps"), ("q,p,mu,mu1", "both 'mu'"),
                                           ("q,p,mu2", "without gaps")])
def test_read_states_parameter_header_errors(tmp_path, header, match):
    path = tmp_path / "x0.csv"
    cells = ",".join(["0.5"] * len(header.split(",")))
    path.write_text(f"{header}\n{cells}\n")
    with pytest.raises(ValueError, match=match):
        read_states(path, 2)


def test_trajectory_csv_parameter_columns_by_name(tmp_path):
    path = tmp_path / "t.csv"
    path.write_text("traj,t,q,p,mu2,mu1\n" + "".join(f"a,{k},{k},{-k},20,10\n" for k in range(3)))
    data = read_trajectories(path)
    np.testing.assert_array_equal(data.mu, [[10, 20]])


# --------------------------------------------------------------------------- .npz declared shapes and members
def _npz_with_header(path: Path, shape, data: bytes, key="states", compress=zipfile.ZIP_STORED):
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, {"descr": "<f8", "fortran_order": False, "shape": shape})
    with zipfile.ZipFile(path, "w", compression=compress) as z:
        z.writestr(f"{key}.npy", header.getvalue() + data)
        buf = io.BytesIO()
        np.save(buf, np.float64(0.1))
        z.writestr("dt.npy", buf.getvalue())


@pytest.mark.parametrize("shape, match", [((-1, 2), "negative dimension"), ((0, 2), "holds no numbers"),
                                          ((2**62, 2**62, 4), "exceed max_bytes"), ((3, -5, 2), "negative dimension")])
def test_npz_declared_shapes_are_checked_before_reading(tmp_path, shape, match):
    path = tmp_path / "bad.npz"
    _npz_with_header(path, shape, b"\0" * 8 * 1000, compress=zipfile.ZIP_DEFLATED)
    t0 = time.perf_counter()
    with pytest.raises(ValueError, match=match) as info:
        read_trajectories(path)
    assert str(path) in str(info.value) and "'states'" in str(info.value)
    assert time.perf_counter() - t0 < 5


def test_npz_negative_shape_in_read_states(tmp_path):
    path = tmp_path / "x0.npz"
    _npz_with_header(path, (-1, 2), b"\0" * 64, key="x0")
    with pytest.raises(ValueError, match="negative dimension"):
        read_states(path, 2)


def _patch_method(path: Path, method: int = None, flag: int = None):
    raw = bytearray(path.read_bytes())
    for sig, off_flag, off_method in ((b"PK\x03\x04", 6, 8), (b"PK\x01\x02", 8, 10)):
        i = raw.find(sig)
        while i >= 0:
            if method is not None:
                raw[i + off_method:i + off_method + 2] = struct.pack("<H", method)
            if flag is not None:
                raw[i + off_flag:i + off_flag + 2] = struct.pack("<H", flag)
            i = raw.find(sig, i + 4)
    path.write_bytes(bytes(raw))


def test_npz_deflate64_member_is_a_clear_error(tmp_path):
    path = tmp_path / "d64.npz"
    np.savez(path, states=np.ones((2, 3, 2)), dt=0.1)
    _patch_method(path, method=9)
    with pytest.raises(ValueError, match="Deflate64.*numpy.savez"):
        read_trajectories(path)


def test_npz_encrypted_member_is_a_clear_error(tmp_path):
    path = tmp_path / "enc.npz"
    np.savez(path, states=np.ones((2, 3, 2)), dt=0.1)
    _patch_method(path, flag=1)
    with pytest.raises(ValueError, match="encrypted"):
        read_trajectories(path)


# --------------------------------------------------------------------------- CSV bounded by what it parses
def test_csv_budget_counts_parsed_numbers_not_file_size(tmp_path):
    """Short cells take 2 bytes in the file and 8 parsed: a budget above the file size still refuses the file."""
    path = tmp_path / "t.csv"
    rows = "".join(f"{i % 7},{k % 10},1,2\n" for i in range(7) for k in range(100))
    path.write_text("traj,t,q,p\n" + rows.replace(",1,2", ",1,2"))
    size = path.stat().st_size
    with pytest.raises(ValueError, match="more than max_bytes"):
        read_trajectories(path, max_bytes=2 * size)


def test_csv_huge_cell_is_a_valueerror_naming_the_row(tmp_path):
    path = tmp_path / "t.csv"
    path.write_text("traj,t,q,p\na,0,1,2\na,1," + "1" * 200_000 + ",2\n")
    with pytest.raises(ValueError, match=r"row 3: not a valid CSV row \(field larger"):
        read_trajectories(path)


def test_csv_nul_byte_in_a_label_is_read_as_a_label(tmp_path):
    """A NUL byte in a trajectory label (a raw KeyError once: NumPy strings drop trailing NULs) is just a label."""
    path = tmp_path / "t.csv"
    path.write_text("traj,t,q,p\na\0,0,1,2\na,0,5,6\na\0,1,3,4\na,1,7,8\n")
    data = read_trajectories(path)
    np.testing.assert_array_equal(data.states, [[[1, 2], [3, 4]], [[5, 6], [7, 8]]])


def test_csv_line_longer_than_the_limit_is_refused_before_splitting(tmp_path):
    path = tmp_path / "t.csv"
    path.write_text("traj,t,q,p\n" + "," * (MAX_CSV_LINE + 10) + "\n")
    with pytest.raises(ValueError, match="longer than"):
        read_trajectories(path)


def test_cli_train_on_a_csv_with_a_huge_cell_is_one_line(tmp_path, capsys):
    path = tmp_path / "t.csv"
    path.write_text("traj,t,q,p\na,0,1,2\na,1,\"" + "1" * 200_000 + "\",2\n")
    code = cli.main(["train", str(path), "--out", str(tmp_path / "m.h5")])
    err = capsys.readouterr().err
    assert code == 1 and len(err.strip().splitlines()) == 1 and "row 3" in err and "Traceback" not in err


def test_csv_rows_in_any_order_keep_their_row_numbers(tmp_path):
    path = tmp_path / "t.csv"
    path.write_text("traj,t,q,p\nb,0,5,6\na,0,1,2\n\nb,1,7,8\na,0.5,3,4\na,0.2,3,4\nb,2,0,0\n")
    with pytest.raises(ValueError, match="row 7 has t = 0.2 after t = 0.5"):
        read_trajectories(path)


# --------------------------------------------------------------------------- fork safety
def test_fork_and_pool_after_a_compiled_parallel_rollout():
    """After a parallel compiled rollout, os.fork and multiprocessing.Pool (fork) roll out in the children."""
    pytest.importorskip("numba")
    env = dict(ENV, NUMBA_NUM_THREADS="2")
    proc = subprocess.run([sys.executable, str(Path(__file__).with_name("_fork_check.py"))], capture_output=True,
                          text=True, timeout=400, env=env)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "fork child status 0" in proc.stdout and "pool equal True" in proc.stdout


# --------------------------------------------------------------------------- scales per coordinate and component
def _two_oscillators(amp2: float, p=30, k=10, dt=0.1, seed=0):
    rng = np.random.default_rng(seed)
    w, amp = np.array([1.0, 1.3]), np.array([1.0, amp2])
    ph, r = rng.uniform(0, 2 * np.pi, (p, 2)), rng.uniform(0.5, 1.0, (p, 2)) * amp
    t = np.arange(k + 1) * dt
    q = r[:, None, :] * np.cos(w * t[:, None] + ph[:, None, :])
    pp = -r[:, None, :] * w * np.sin(w * t[:, None] + ph[:, None, :])
    return TrajectoryData(np.concatenate([q, pp], axis=2), None, dt)


def test_pairs_of_very_different_scales_warn_and_the_diagnostics_name_the_coordinate():
    """Amplitudes 1 and 1e-6: a ScaleWarning names (q2, p2); the per-coordinate hold-out error and the advice too."""
    from sympredict import SymplecticKernelPredictor
    from sympredict.exceptions import ScaleWarning

    with pytest.warns(ScaleWarning, match=r"\(q2, p2\) spread"):
        model = SymplecticKernelPredictor().fit(_two_oscillators(1e-6))
    err = model.diagnostics_.holdout_coordinate_error
    assert err.shape == (4,) and err[1] > 1e3 * err[0] and err[3] > 1e3 * err[2]
    assert any("q2" in a and "p2" in a and "learned badly" in a for a in model.diagnostics_.advice)


def test_pairs_of_similar_scales_do_not_warn():
    import warnings

    from sympredict import SymplecticKernelPredictor
    from sympredict.exceptions import ScaleWarning

    with warnings.catch_warnings():
        warnings.simplefilter("error", ScaleWarning)
        model = SymplecticKernelPredictor().fit(_two_oscillators(0.5))
    assert not any("learned badly" in a for a in model.diagnostics_.advice)
    assert np.all(np.isfinite(model.diagnostics_.holdout_coordinate_error))


def test_parameter_components_of_very_different_widths_warn_naming_the_narrow_one():
    from sympredict.estimators.auto import _warn_unbalanced_parameters
    from sympredict.data import FlowMapData
    from sympredict.exceptions import ScaleWarning

    rng = np.random.default_rng(0)
    mu = np.column_stack([rng.uniform(1, 2, 50), rng.uniform(0, 1e6, 50)])
    data = FlowMapData(rng.normal(size=(50, 2)), rng.normal(size=(50, 2)), mu, 0.1)
    with pytest.warns(ScaleWarning, match=r"mu1 \(width"):
        _warn_unbalanced_parameters(data)


# --------------------------------------------------------------------------- wrapped angles, one warning per fit
def _wrapped_pendulum():
    from sympredict.systems.pendulum import Pendulum

    x0 = np.column_stack([np.zeros(8), np.linspace(4.5, 5.5, 8)])  # rotating
    states = Pendulum().trajectory(x0, np.full(8, 0.75), 0.05, 30)
    states[..., 0] = (states[..., 0] + np.pi) % (2 * np.pi) - np.pi
    return TrajectoryData(states, None, 0.05)


def test_wrapped_angles_name_the_coordinate_and_periodic_once_per_fit():
    import warnings

    from sympredict import SymplecticKernelPredictor
    from sympredict.exceptions import UnderfitWarning, WrappedAngleWarning

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        SymplecticKernelPredictor().fit(_wrapped_pendulum())
    wrapped = [w for w in caught if issubclass(w.category, WrappedAngleWarning)]
    assert len(wrapped) == 1 and "state coordinate 0 (q1)" in str(wrapped[0].message)
    assert "Periodic(None, coordinates=(0,))" in str(wrapped[0].message) and "unwrap" in str(wrapped[0].message)
    assert sum(issubclass(w.category, UnderfitWarning) for w in caught) <= 1  # about the final model only


def test_unwrapped_angles_do_not_warn():
    from sympredict.data import FlowMapData
    from sympredict.estimators.structure import warn_wrapped_angles

    data = _wrapped_pendulum()
    data.states[..., 0] = np.unwrap(data.states[..., 0], axis=1)
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warn_wrapped_angles(data.pairs())
        warn_wrapped_angles(FlowMapData(np.zeros((3, 2)), np.ones((3, 2)), None, 0.1))


def test_candidate_underfits_are_not_warned_only_the_final_model():
    """A search whose candidates underfit: at most one UnderfitWarning, and it is about the final model."""
    import warnings

    from sympredict import SymplecticKernelPredictor
    from sympredict.exceptions import UnderfitWarning

    data = _wrapped_pendulum()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        model = SymplecticKernelPredictor().fit(data)
    under = [w for w in caught if issubclass(w.category, UnderfitWarning)]
    assert len(under) <= 1
    if under:
        assert f"{model.n_centers_} centre" in str(under[0].message) or "no centre" in str(under[0].message)


# --------------------------------------------------------------------------- fit interrupted at the end
def test_ctrl_c_at_the_end_of_fit_leaves_no_previous_diagnostics(monkeypatch):
    from sympredict import SymplecticKernelPredictor
    from sympredict.estimators import predictor as predictor_module

    model = SymplecticKernelPredictor(max_centers=30).fit(_two_oscillators(0.5, p=10))
    assert model.diagnostics_ is not None

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(predictor_module, "diagnose", interrupted)
    with pytest.raises(KeyboardInterrupt):
        model.fit(_two_oscillators(0.5, p=10, seed=1))
    assert "diagnostics_" not in model.__dict__ and "choice_" not in model.__dict__


# --------------------------------------------------------------------------- an old option and its new part both given
def test_old_option_and_new_part_both_given_cannot_silently_disagree():
    """The flat option is not a parameter any more: given beside the part that owns its setting, the call is
    refused (neither silently wins)."""
    from sympredict import SymplecticKernelPredictor
    from sympredict.kernels import IMQ
    from sympredict.kernels.transforms import Periodic
    from sympredict.symplectic.solvers import NewtonSolver

    with pytest.raises(TypeError, match="newton_max_iter"):
        SymplecticKernelPredictor(solver=NewtonSolver(max_iter=100), newton_max_iter=3)
    with pytest.raises(TypeError, match="periodic"):
        SymplecticKernelPredictor(state_kernel=Periodic(IMQ(1.0), coordinates=(0,)), periodic=(1,))
    with pytest.raises(ValueError, match="no parameter 'newton_max_iter'"):
        SymplecticKernelPredictor().set_params(solver=NewtonSolver(max_iter=100), newton_max_iter=3)


# --------------------------------------------------------------------------- mass matrices
@pytest.mark.parametrize("lumped", [True, False])
def test_indefinite_mass_is_refused_also_lumped(lumped):
    from sympredict.mor.mass import MassMatrixCoordinates

    with pytest.raises(ValueError, match="not positive definite|non-positive"):
        MassMatrixCoordinates(np.array([[1.0, 2.0], [2.0, 1.0]]), lumped=lumped)  # row sums 3, eigenvalue -1
    with pytest.raises(ValueError, match="non-positive|not positive definite"):
        MassMatrixCoordinates(np.array([[-1.0, 3.0], [3.0, -1.0]]), lumped=lumped)  # negative masses


@pytest.mark.parametrize("lumped", [True, False])
def test_ill_conditioned_mass_is_refused(lumped):
    from sympredict.mor.mass import MassMatrixCoordinates

    with pytest.raises(ValueError, match="ill-conditioned"):
        MassMatrixCoordinates(np.diag([1.0, 1e-300]), lumped=lumped)
    MassMatrixCoordinates(np.diag([1.0, 1e-6]), lumped=lumped)


# --------------------------------------------------------------------------- rounded times
def _csv_times(path: Path, times):
    rows = "".join(f"{j},{t},{float(np.cos(float(t)))!r},{float(np.sin(float(t)))!r}\n" for j in range(2) for t in times)
    path.write_text("traj,t,q,p\n" + rows)


def test_times_rounded_to_six_decimals_are_uniform(tmp_path):
    h = 0.1 / 3
    _csv_times(tmp_path / "t.csv", [f"{k * h:.6f}" for k in range(30)])
    data = read_trajectories(tmp_path / "t.csv")
    assert data.dt is not None and abs(data.dt - h) <= 1e-6 / 29 + 1e-15


def test_times_jittered_beyond_their_decimals_stay_non_uniform(tmp_path):
    h = 0.1 / 3
    _csv_times(tmp_path / "t.csv", [f"{k * h + 3e-6 * (k % 2):.6f}" for k in range(30)])
    assert read_trajectories(tmp_path / "t.csv").dt is None


def test_unix_second_times_give_the_written_step(tmp_path):
    """Times such as 1700000000.01 parse with round-off of their magnitude: the step is the written 0.01."""
    _csv_times(tmp_path / "t.csv", [f"{1_700_000_000 + k * 0.01:.2f}" for k in range(300)])
    assert read_trajectories(tmp_path / "t.csv").dt == 0.01


# --------------------------------------------------------------------------- reductor inputs
def test_reductor_trajectories_outside_parameter_space_are_refused(small_fe_wave):
    from sympredict.mor import SymplecticKernelReductor

    fom, coords, space, train, RB = small_fe_wave
    far = fom.parameters.space(5.0, 6.0)
    with pytest.raises(ValueError, match="training_parameters: parameter .* lies outside parameter_space"):
        SymplecticKernelReductor(fom, RB, train, 0.01, parameter_space=far)


# --------------------------------------------------------------------------- noisy data
def test_noisy_data_get_regularization_advice():
    from sympredict import SymplecticKernelPredictor
    from sympredict.systems.pendulum import Pendulum

    rng = np.random.default_rng(0)
    x0 = np.column_stack([rng.uniform(-1, 1, 30), rng.uniform(-1, 1, 30)])
    clean = Pendulum().trajectory(x0, np.full(30, 0.75), 0.05, 20)
    noisy = SymplecticKernelPredictor(max_centers=120).fit(TrajectoryData(clean + 1e-3 * rng.normal(size=clean.shape), None, 0.05))
    assert any("noisy data?" in a and "regularization" in a for a in noisy.diagnostics_.advice)
    exact = SymplecticKernelPredictor(max_centers=120).fit(TrajectoryData(clean, None, 0.05))
    assert not any("noisy data?" in a for a in exact.diagnostics_.advice)


# --------------------------------------------------------------------------- Newton with a watchdog
def test_watchdog_rule_on_synthetic_values():
    from sympredict.newton_rule import MIN_FRACTION, accepted

    inf, nan = float("inf"), float("nan")
    merit = np.array([5.0, 5.0, 4.0, nan, 5.0, 1e-20, nan])
    best = np.array([inf, 4.0, 5.0, 5.0, 4.0, 1e-21, inf])
    fraction = np.array([1.0, 1.0, 1.0, 0.5, MIN_FRACTION, 1.0, 1.0])
    f_norm, f_floor = merit, np.full(7, 1e-18)
    np.testing.assert_array_equal(accepted(merit, best, fraction, f_norm, f_floor),
                                  [True, False, True, False, True, True, True])


@pytest.mark.paths
def test_ordinary_steps_take_the_plain_newton_iterates(small_pendulum_model, monkeypatch):
    """Where every iterate improves (ordinary steps), the watchdog never acts: the rollout is bit-identical to the
    plain Newton iteration (the rule replaced by one that accepts everything), on the NumPy path."""
    import copy

    from sympredict.symplectic import newton

    rng = np.random.default_rng(3)
    x = np.column_stack([rng.uniform(-0.5, 0.5, 16), rng.uniform(-0.3, 0.3, 16)])
    mu = rng.uniform(0.71, 0.79, 16)
    model = copy.copy(small_pendulum_model).set_params(solver__backend="numpy")
    watched = model.rollout(x, 20, mu=mu, dt=0.05)
    monkeypatch.setattr(newton, "accepted", lambda merit, *args: np.ones(np.shape(merit), dtype=bool))
    np.testing.assert_array_equal(model.rollout(x, 20, mu=mu, dt=0.05), watched)


@pytest.mark.paths
def test_a_cycling_newton_is_restarted_alike_on_both_backends(small_pendulum_data):
    """Far steps (dT = 1.0 on a model trained at 0.04..0.06): for most single instances both backends report the
    same outcome (converged, or the same failing step), unchanged under relative perturbations 1e-14 and 1e-11."""
    import copy
    import warnings

    from sympredict import NewtonConvergenceError
    from sympredict.exceptions import ExtrapolationWarning
    from sympredict.interpolation.greedy import ExactGreedy
    from sympredict.kernels import IMQ

    from sympredict import SymplecticKernelPredictor

    d = small_pendulum_data
    model = SymplecticKernelPredictor(IMQ(0.15), mu_kernel=IMQ(2.0), dt_kernel=IMQ(0.2), max_centers=60,
                                      trainer=ExactGreedy(tol=1e-10)).fit(d.x0, d.x1, mu=d.mu, dt=d.dt)
    rng = np.random.default_rng(0)
    x = np.column_stack([rng.uniform(0.0, np.pi / 2, 20), rng.uniform(-0.5, 0.5, 20)])
    mu = rng.uniform(0.71, 0.79, 20)

    def outcome(backend, xs, i):
        m = copy.copy(model).set_params(solver__backend=backend)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", ExtrapolationWarning)
                m.rollout(xs[i:i + 1], 20, mu=mu[i:i + 1], dt=1.0)
            return -1
        except NewtonConvergenceError as exc:
            return exc.step

    stable = 0
    for i in range(6):
        per = {rel: [outcome(b, x * (1 + rel), i) for b in ("numpy", "numba")] for rel in (0.0, 1e-14, 1e-11)}
        stable += len({v for pair in per.values() for v in pair}) == 1  # one outcome, backends and perturbations
    assert stable >= 4
