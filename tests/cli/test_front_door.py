"""The paths a newcomer takes first: clear messages for the usual mistakes, a quiet ``train``.

Each wrong input ends in one error that names the argument (or option) and the fix, never a raw
``AttributeError``/``TypeError`` from inside NumPy, h5py or pyMOR.
"""

import subprocess
import sys

import numpy as np
import pytest

from sympredict import DirectKernelPredictor, SymplecticKernelPredictor
from sympredict.cli import main
from sympredict.kernels import IMQ
from sympredict.systems.pendulum import Pendulum, random_flow_map_data


@pytest.fixture(scope="module")
def pendulum_pairs():
    pendulum = Pendulum()
    data = random_flow_map_data(pendulum, 120, seed=0, mu_values=(0.75,), dt_values=(0.05,))
    val = random_flow_map_data(pendulum, 40, seed=1, mu_values=(0.75,), dt_values=(0.05,))
    return data, val


# ---------------------------------------------------------------- the command line
def test_a_file_that_is_no_model_is_refused_naming_what_a_model_is(tmp_path, capsys):
    text = tmp_path / "notes.txt"
    text.write_text("hello\n")
    npz = tmp_path / "traj.npz"
    np.savez(npz, states=np.zeros((2, 3, 2)), dt=0.1)
    dataset = tmp_path / "data.h5"
    assert main(["data", "--random", "20", "--out", str(dataset)]) == 0
    capsys.readouterr()
    for wrong in (text, npz, dataset):
        for argv in (["predict", str(wrong), "--x0", "1,0", "--steps", "1"], ["report", str(wrong)]):
            assert main(argv) == 1
            err = capsys.readouterr().err
            assert "is not a sympredict model" in err and "model.save" in err and "sympredict train" in err, err
            assert "OSError" not in err and "corrupted" not in err


def test_train_kernel_options_are_named_after_the_kernel_and_dt_is_refused(tmp_path, capsys):
    traj = tmp_path / "traj.npz"
    states = Pendulum().trajectory(np.array([[0.5, 0.0], [1.0, 0.0]]), 0.75, dt=0.1, n_steps=10)
    np.savez(traj, states=states, dt=0.1)
    out = str(tmp_path / "m.h5")
    assert main(["train", str(traj), "--dt", "0.1", "--out", out]) == 1
    err = capsys.readouterr().err
    assert "train has no --dt" in err and "--dt-kernel" in err
    assert main(["train", str(traj), "--mu", "imq:1", "--out", out]) == 1
    assert "--mu-kernel" in capsys.readouterr().err
    assert (
        main(
            [
                "train",
                str(traj),
                "--state-kernel",
                "imq:0.5",
                "--mu-kernel",
                "none",
                "--dt-kernel",
                "none",
                "--max-centers",
                "10",
                "--threads",
                "1",
                "--out",
                out,
            ]
        )
        == 0
    )
    assert SymplecticKernelPredictor.load(out).kernel_.state == IMQ(0.5)


def test_trajectories_saved_without_dt_say_how_to_add_it(tmp_path, capsys):
    f = tmp_path / "my_trajectories.npz"
    np.savez(f, states=np.zeros((3, 11, 4)), mu=[0.1, 0.2, 0.3])
    assert main(["train", str(f), "--out", str(tmp_path / "m.h5")]) == 1
    err = capsys.readouterr().err
    assert "found neither" in err and "np.savez('my_trajectories.npz', states=states, mu=mu, dt=0.1)" in err


def test_train_prints_one_result_line_by_default_and_the_log_with_verbose(tmp_path):
    data = tmp_path / "d.h5"
    assert main(["data", "--out", str(data), "--n-grid", "8"]) == 0
    sym = [sys.executable, "-m", "sympredict.cli", "train", str(data), "--centers", "20", "--threads", "1"]
    quiet = subprocess.run([*sym, "--out", str(tmp_path / "a.h5")], capture_output=True, text=True, timeout=300)
    assert quiet.returncode == 0, quiet.stderr
    assert quiet.stderr == "" and len(quiet.stdout.strip().splitlines()) == 1, (quiet.stdout, quiet.stderr)
    assert quiet.stdout.startswith("trained 20 centres") and "saved to" in quiet.stdout
    loud = subprocess.run(
        [*sym, "--out", str(tmp_path / "b.h5"), "--verbose"], capture_output=True, text=True, timeout=300
    )
    assert loud.returncode == 0 and "greedy" in loud.stderr and "read " in loud.stderr
    assert "nan on 0 held-out" not in loud.stderr


@pytest.mark.parametrize(
    "argv, expected",
    [
        (["data", "--random", "0"], "--random: must be >= 1"),
        (["data", "--n-grid", "0"], "--n-grid: must be >= 2"),
        (["predict", "m.h5", "--x0", "1,0", "--steps", "1", "--mu="], "argument --mu"),
    ],
)
def test_data_and_predict_numbers_are_checked_by_option(argv, expected, tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main([*argv, "--out", str(tmp_path / "x.h5")] if argv[0] == "data" else argv)
    assert exc.value.code == 2 and expected in capsys.readouterr().err


def test_data_refuses_a_grid_that_cannot_fit_in_memory_before_allocating(tmp_path, capsys):
    assert main(["data", "--n-grid", "100000", "--out", str(tmp_path / "x.h5")]) == 1
    err = capsys.readouterr().err
    assert "--n-grid 100000" in err and "GiB" in err and "give --n-grid" in err
    assert not (tmp_path / "x.h5").exists()


# ---------------------------------------------------------------- the Python API
def test_select_regularization_names_wrong_validation_and_wrong_estimator(pendulum_pairs):
    from sympredict.estimators.selection import select_regularization

    data, val = pendulum_pairs
    est = SymplecticKernelPredictor(IMQ(0.5), IMQ(1.0), None, max_centers=10)
    with pytest.raises(ValueError, match=r"validation must be a FlowMapData .*got tuple"):
        select_regularization(data, (val.x0, val.x1, val.mu, val.dt), [1e-8], est)
    with pytest.raises(ValueError, match=r"estimator must be a SymplecticKernelPredictor.*DirectKernelPredictor"):
        select_regularization(data, val, [1e-8], DirectKernelPredictor(IMQ(0.5)))


@pytest.mark.parametrize("target", ["abc", None, -1.0, float("nan")])
def test_smallest_refuses_a_target_that_is_no_positive_number(pendulum_pairs, target):
    data, val = pendulum_pairs
    model = SymplecticKernelPredictor(IMQ(0.5), IMQ(1.0), None, max_centers=10)
    model.fit(data.x0, data.x1, mu=data.mu, dt=0.05, validation=(val.x0, val.x1, val.mu, 0.05))
    with pytest.raises(ValueError, match=r"target must be a positive float"):
        model.smallest(target)


def test_sharded_greedy_names_a_pool_that_is_no_worker_pool(pendulum_pairs):
    from sympredict.interpolation.greedy import ShardedGreedy

    data, _ = pendulum_pairs
    model = SymplecticKernelPredictor(IMQ(0.5), IMQ(1.0), None, max_centers=5, trainer=ShardedGreedy(pool="pool"))
    with pytest.raises(ValueError, match=r"pool must be a pyMOR WorkerPool .*got 'pool'"):
        model.fit(data.x0, data.x1, mu=data.mu, dt=0.05)


def test_reductor_empty_kernel_list_and_array_reconstruct(small_fe_wave):
    from sympredict.mor import DefaultEstimator, ProjectedTrajectories, SymplecticKernelReductor, ValidationSelection

    fom, _, _, train, RB = small_fe_wave
    dt = 5 * fom.T / fom.time_stepper.nt
    with pytest.raises(ValueError, match=r"state_kernels must be a non-empty sequence"):
        SymplecticKernelReductor(
            fom, RB, dt, ProjectedTrajectories(train), selection=ValidationSelection(state_kernels=[])
        )
    reductor = SymplecticKernelReductor(fom, RB, dt, ProjectedTrajectories(train), DefaultEstimator(max_centers=10))
    full = reductor.reconstruct(np.zeros((2, reductor.dim)))
    assert len(full) == 2 and full.space == fom.solution_space and full.norm().max() == 0
    x = np.arange(2.0 * reductor.dim).reshape(2, reductor.dim)
    np.testing.assert_allclose(reductor.project(reductor.reconstruct(x)), x, atol=1e-10 * np.abs(x).max())
    with pytest.raises(ValueError, match=r"U_red as an array must have shape \(K, 2n\)"):
        reductor.reconstruct(np.zeros((2, 4)))


def test_the_working_line_shows_on_a_terminal_only_and_is_erased():
    import io

    from sympredict.cli._console import _Working

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    tty, pipe, verbose = Terminal(), io.StringIO(), Terminal()
    for stream, quiet in ((tty, False), (pipe, False), (verbose, True)):
        with _Working("sympredict train: 30 pairs, training", stream=stream, quiet=quiet):
            pass
    assert tty.getvalue() == "sympredict train: 30 pairs, training ...\r\x1b[K"
    assert pipe.getvalue() == "" and verbose.getvalue() == ""


def test_demo_writes_a_model_a_figure_and_one_line(tmp_path, capsys, monkeypatch):
    """``sympredict demo`` end to end, at small sizes (the command's own sizes take a minute)."""
    from sympredict.cli import demo

    monkeypatch.setattr(demo, "N_TRAJECTORIES", 8)
    monkeypatch.setattr(demo, "MAX_CENTERS", 20)
    monkeypatch.setattr(demo, "HORIZON_STEPS", 20)
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), "--threads", "1"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("demo: ") and "max state error" in lines[0]
    assert {"model.h5", "demo.png", "demo.pdf", "demo.json"} <= {p.name for p in out.iterdir()}
    assert SymplecticKernelPredictor.load(out / "model.h5").n_centers_ <= 20
    (out / "notes.txt").write_text("mine")
    assert main(["demo", "--out", str(out)]) == 1
    assert "holds other files than a demo's" in capsys.readouterr().err
