"""The command line on the user's own files: train on .npz/.h5/.csv trajectories, predict from --x0/--x0-file,
data --system for the shipped systems, --force."""

import numpy as np
import pytest

from sympredict import SymplecticKernelPredictor, read_trajectories
from sympredict.cli import main
from sympredict.data import TrajectoryData
from sympredict.io.trajectories import write_trajectories

from _tolerances import assert_same_predictions, rollout_bound


def oscillator(n_traj=3, n_steps=8, dt=0.1):
    """Harmonic-oscillator trajectories (exact flow), no parameter."""
    x0 = np.random.default_rng(0).uniform(-1, 1, (n_traj, 2))
    t = np.arange(n_steps + 1) * dt
    c, s = np.cos(t)[None, :], np.sin(t)[None, :]
    q, p = x0[:, :1], x0[:, 1:]
    return TrajectoryData(np.stack([q * c + p * s, -q * s + p * c], axis=-1), dt=dt)


@pytest.mark.parametrize("suffix", [".npz", ".h5", ".csv"])
def test_train_on_user_trajectories_then_predict(tmp_path, capsys, suffix):
    data = oscillator()
    write_trajectories(data, tmp_path / f"traj{suffix}")
    model = str(tmp_path / "m.h5")
    assert (
        main(["train", str(tmp_path / f"traj{suffix}"), "--out", model, "--max-centers", "12", "--threads", "1"]) == 0
    )
    out = capsys.readouterr().out
    assert "3 trajectories of 9 states (2n = 2, 0 parameter(s), dt = 0.1), 24 pairs" in out and "saved to" in out
    fitted = SymplecticKernelPredictor.load(model)
    reference = SymplecticKernelPredictor(max_centers=12).fit(read_trajectories(tmp_path / f"traj{suffix}"))
    probe = np.array([[0.3, -0.2], [0.0, 0.4]])
    assert fitted.n_centers_ == reference.n_centers_
    assert_same_predictions(fitted, reference, probe, 3, dt=0.1)
    # predict from --x0 and from a file; the written trajectories read back as data
    traj = str(tmp_path / "pred.npz")
    assert main(["predict", model, "--x0", "0.5,0.1", "--steps", "4", "--out", traj]) == 0
    back = read_trajectories(traj)
    # the command's rollout may take another solver path (progress, backend 'auto'): equal to Newton's stopping rule
    _same_rollout(fitted, back.states[0], np.array([0.5, 0.1]))
    np.testing.assert_allclose(back.times[0], np.arange(5) * 0.1, rtol=0, atol=1e-15)
    (tmp_path / "x0.csv").write_text("q,p\n0.5,0.1\n-0.2,0.3\n")
    assert (
        main(["predict", model, "--x0-file", str(tmp_path / "x0.csv"), "--steps", "4", "--out", traj, "--force"]) == 0
    )
    both = read_trajectories(traj)
    _same_rollout(fitted, both.states[0], np.array([0.5, 0.1]))
    _same_rollout(fitted, both.states[1], np.array([-0.2, 0.3]))


def _same_rollout(model, got, x0, dt=0.1):
    """``got`` (K+1, 2n) is ``model``'s rollout from ``x0`` to the bound of two converged Newton paths
    (``tests/_tolerances.rollout_bound``, in the surrogate's scaled coordinates)."""
    expected = model.rollout(x0, len(got) - 1, dt=dt)
    scale = model._scale_vector(model.dim_)
    sur, steps = model.surrogate_, np.array([dt])
    bound = rollout_bound(sur, expected[None] * scale, sur.weights(np.zeros((1, 0)), steps), steps)
    np.testing.assert_allclose(got * scale, expected * scale, rtol=0, atol=bound)


def test_nothing_is_overwritten_without_force(tmp_path, capsys):
    write_trajectories(oscillator(), tmp_path / "t.npz")
    (tmp_path / "m.h5").write_text("keep me")
    assert main(["train", str(tmp_path / "t.npz"), "--out", str(tmp_path / "m.h5")]) == 1
    assert main(["data", "--system", "henon-heiles", "--out", str(tmp_path / "m.h5")]) == 1
    err = capsys.readouterr().err
    assert err.count("exists: pass --force to replace it") == 2
    assert (tmp_path / "m.h5").read_text() == "keep me"


def test_predict_errors_name_the_option_and_shape(tmp_path, capsys):
    write_trajectories(oscillator(), tmp_path / "t.npz")
    model = str(tmp_path / "m.h5")
    assert main(["train", str(tmp_path / "t.npz"), "--out", model, "--max-centers", "5", "--threads", "1"]) == 0
    capsys.readouterr()  # what training printed and logged
    (tmp_path / "bad.csv").write_text("q1,q2,p1,p2\n1,2,3,4\n")
    (tmp_path / "cell.csv").write_text("q,p\n1,x\n")
    cases = [
        (["--x0", "1,0,3"], "--x0 has 3 numbers per state; the model's states have 2n = 2"),
        (["--x0", "1,a"], "entry 2 of '1,a' is 'a'"),
        (["--x0-file", str(tmp_path / "bad.csv")], r"unexpected column(s) ['q2', 'p2']"),
        (["--x0-file", str(tmp_path / "cell.csv")], "row 2, column 'p': 'x' is not a number"),
        (["--x0", "1,0", "--out", str(tmp_path / "x.txt")], "written as .npz or .csv"),
    ]
    for extra, message in cases:
        assert main(["predict", model, "--steps", "2", *extra]) == 1
        err = capsys.readouterr().err
        assert message in err and err.startswith("sympredict: error:"), (extra, err)


@pytest.mark.parametrize("system, dim", [("henon-heiles", 4), ("wave", 8), ("sine-gordon", 8)])
def test_data_for_every_shipped_system_is_read_by_train(tmp_path, capsys, system, dim):
    out = tmp_path / f"{system}.npz"
    assert (
        main(["data", "--system", system, "--trajectories", "3", "--steps", "4", "--n-points", "4", "--out", str(out)])
        == 0
    )
    assert f"wrote 3 {system} trajectories of 4 steps" in capsys.readouterr().out
    data = read_trajectories(out)
    assert data.states.shape == (3, 5, dim) and data.mu.shape == (3, 1) and data.dt == 0.1
    # the file is what train reads, with the estimator's defaults (kernels and update chosen, mu learned)
    assert main(["train", str(out), "--out", str(tmp_path / "m.h5"), "--max-centers", "5", "--threads", "1"]) == 0
    assert f"3 trajectories of 5 states (2n = {dim}, 1 parameter(s)" in capsys.readouterr().out
    assert SymplecticKernelPredictor.load(tmp_path / "m.h5").kernel_.mu is not None


def test_data_keeps_the_pendulum_default(tmp_path, capsys):
    assert main(["data", "--n-grid", "4", "--out", str(tmp_path / "d.h5")]) == 0
    assert "pendulum flow-map samples" in capsys.readouterr().out
    assert main(["data", "--n-grid", "4", "--out", str(tmp_path / "d.npz")]) == 1
    assert "the pendulum data set is an HDF5 file" in capsys.readouterr().err
