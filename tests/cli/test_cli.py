"""The command line and the example run end to end (smallest sizes)."""

import subprocess
import sys
from pathlib import Path

import numpy as np

from sympredict.cli import main

ROOT = Path(__file__).resolve().parents[2]


def test_run_all_smoke_writes_everything(smoke_run):
    tmp_path, results, out = smoke_run
    pendulum = results["results"]["pendulum"]
    # the greedy used its whole budget exactly when it says so
    assert pendulum["n_centers"] <= pendulum["preset"]["max_centers"] and len(pendulum["per_dt"]) == len(
        pendulum["preset"]["dt_test"]
    )
    assert (pendulum["n_centers"] == pendulum["preset"]["max_centers"]) == (pendulum["stop_reason"] == "max_centers")
    wave = results["results"]["wave"]
    assert wave["basis"]["symplecticity"] < 1e-13 and len(wave["per_dt"][0]["cases"]) == 2
    for name in results["figures"]:
        assert (tmp_path / name).stat().st_size > 1000
    assert len(results["figures"]) == 2 * (
        6 + 5 + 4
    )  # pendulum A 4 + speed/accuracy + stability, B 5, wave 3 + speed/accuracy; png + pdf
    st = pendulum["stability"]
    assert set(st["long"]) == {"kernel predictor", "direct kernel", "implicit midpoint"}
    assert len(st["dt_sweep"]) == 12 and len(st["mu_sweep"]) == 8
    # failures are reported as the documented strings, never raised
    allowed = ("refused: dT*L_S >= 1", "unstable (state grew)")
    for row in st["dt_sweep"]:
        for method in ("kernel", "implicit midpoint", "Stormer-Verlet"):
            assert isinstance(row[method], float) or row[method] in allowed or row[method].startswith("Newton failed")
    # far beyond its stability limit the explicit method is useless
    sv_small, sv_large = st["dt_sweep"][0]["Stormer-Verlet"], st["dt_sweep"][-1]["Stormer-Verlet"]
    assert isinstance(sv_large, str) or sv_large > 100 * sv_small
    rows = pendulum["speed_accuracy"]["rows"]
    methods = {r["method"] for r in rows}
    assert {
        "kernel predictor",
        "implicit midpoint (compiled)",
        "Stormer-Verlet (compiled)",
        "Yoshida-4 (compiled)",
        "Kahan-Li-6 (compiled)",
    } <= methods
    # smallest models for the validation targets: measured, or listed as unreached (smoke is tiny)
    smallest = [m for m in methods if m.startswith("smallest kernel")]
    assert len(smallest) + len(pendulum["speed_accuracy"]["unreached"]) == 2
    assert all(r["time_per_trajectory_s"] > 0 and r["median_err"] > 0 for r in rows)
    # finer steps are more accurate: the chart shows real convergence, not noise
    for method in (
        "implicit midpoint (compiled)",
        "Stormer-Verlet (compiled)",
        "Yoshida-4 (compiled)",
        "Kahan-Li-6 (compiled)",
    ):
        errs = [r["median_err"] for r in rows if r["method"] == method]
        assert len(errs) >= 3 and all(a > b for a, b in zip(errs, errs[1:])), (method, errs)
    b = pendulum["scenario_b"]
    assert b["mu"] == 0.825 and len(b["per_dt"]) == 3 and b["n_centers_direct"] > 0
    text = (tmp_path / "summary.md").read_text()
    assert "## Pendulum scenario A" in text and "## Wave equation" in text and "pendulum_phase_portrait.png" in text
    assert (tmp_path / "pendulum_model.h5").exists() and (tmp_path / "wave_model_dt0.1.h5").exists()
    assert "kernel median error" in out and "wave dT=0.1" in out
    # the paper's claims are stated with their numbers, in the summary and in results.json
    assert len(results["claims"]) == 3 and all(
        isinstance(c["holds"], bool) and c["evidence"] for c in results["claims"]
    )
    assert text.count("- HOLDS: ") + text.count("- DOES NOT HOLD: ") == 3
    assert ("DOES NOT HOLD" in text) == (not all(c["holds"] for c in results["claims"]))
    # kernel selection by validation ran by default and its winner is the model's kernel
    sel = pendulum["selection"]
    assert sel["chosen"] == pendulum["kernel"] and set(sel["best_per_family"]) == {"imq", "matern32", "matern52"}
    assert sel["chosen_E_val"] <= min(row["E_val"] for row in sel["refine_table"])
    # no bigger model than needed: the wave sizing met its target on validation data with a prefix of the model
    z = wave["smallest"]
    assert z["reached"] and z["validation_error"] <= z["target"] and z["n_centers"] <= z["of_centers"]
    assert all(e > z["rom_share"] * z["target"] for n, e in z["rom_errors"].items() if int(n) < z["n_reduced"])
    assert all(e > z["target"] for m, e in z["center_errors"].items() if int(m) < z["n_centers"])


def _run_example(script, *args):
    """Run ``examples/<script>`` with ``args`` in a child process; asserts exit 0 and returns its stdout."""
    proc = subprocess.run(
        [sys.executable, str(ROOT / "examples" / script), *args], capture_output=True, text=True, timeout=300
    )
    assert proc.returncode == 0, proc.stderr
    return proc.stdout


def test_example_runs(tmp_path):
    out = tmp_path / "example.png"
    stdout = _run_example(
        "pendulum_phase_portrait.py", "--n-grid", "12", "--centers", "100", "--horizon", "2", "--out", str(out)
    )
    assert out.stat().st_size > 1000 and "kernel predictor" in stdout


def test_wave_example_runs():
    stdout = _run_example("wave_mor_workflow.py", "--n-points", "80", "--samples", "60", "--centers", "80")
    assert "ROM + kernel predictor" in stdout and "V^T J V - J" in stdout


def test_data_train_predict_report_workflow(tmp_path, capsys):
    data, val, model, csv = (str(tmp_path / n) for n in ("d.h5", "v.h5", "m.h5", "t.csv"))
    assert main(["data", "--n-grid", "12", "--out", data]) == 0
    assert main(["data", "--random", "50", "--out", val]) == 0
    assert main(["train", data, "--validation", val, "--centers", "60", "--out", model, "--threads", "1"]) == 0
    assert (
        main(
            [
                "predict",
                model,
                "--x0",
                "1.0,0.0",
                "0.5,0.2",
                "--mu",
                "0.75",
                "--dt",
                "0.05",
                "--steps",
                "5",
                "--out",
                csv,
            ]
        )
        == 0
    )
    rows = np.loadtxt(csv, delimiter=",", skiprows=1)  # traj, t, q1, p1, mu1
    assert rows.shape == (2 * 6, 5) and np.all(np.isfinite(rows))
    from sympredict import SymplecticKernelPredictor, read_trajectories

    expected = SymplecticKernelPredictor.load(model).rollout(np.array([[1.0, 0.0], [0.5, 0.2]]), 5, mu=0.75, dt=0.05)
    np.testing.assert_array_equal(rows[:, 2:4], expected.reshape(-1, 2))
    back = read_trajectories(csv)  # the written trajectories are data again
    np.testing.assert_array_equal(back.states, expected)
    np.testing.assert_array_equal(back.mu, [[0.75], [0.75]])
    np.testing.assert_allclose(back.times[0], np.arange(6) * 0.05, rtol=0, atol=1e-15)
    assert main(["report", model]) == 0
    out = capsys.readouterr().out
    assert "60 centres" in out and "training box" in out
    # wrong file kinds and bad arguments: one line, exit code 1
    assert main(["predict", data, "--x0", "1,0", "--steps", "2"]) == 1
    assert main(["train", model, "--out", str(tmp_path / "x.h5")]) == 1
    assert main(["train", data, "--state-kernel", "gauss:1", "--out", str(tmp_path / "x.h5")]) == 1
    err = capsys.readouterr().err
    assert err.count("sympredict: error:") == 3 and "Traceback" not in err


def test_version_plain_piped_output_and_one_line_warnings(tmp_path):
    """--version; no ANSI colour codes when stderr is not a terminal (even where TERM has colours) or with
    NO_COLOR; a Python warning is one readable line."""
    from sympredict import __version__

    sym = [sys.executable, "-m", "sympredict.cli"]
    out = subprocess.run([*sym, "--version"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and out.stdout.strip() == f"sympredict {__version__}"
    env = {**__import__("os").environ, "TERM": "xterm-256color", "OPENBLAS_NUM_THREADS": "1"}
    data, model = tmp_path / "d.h5", tmp_path / "m.h5"
    assert (
        subprocess.run(
            [*sym, "data", "--out", str(data), "--n-grid", "8"], capture_output=True, env=env, timeout=120
        ).returncode
        == 0
    )
    train = subprocess.run(
        [*sym, "train", str(data), "--out", str(model), "--centers", "30", "--threads", "1", "--verbose"],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )
    assert train.returncode == 0, train.stderr
    assert "greedy" in train.stderr and "\x1b[" not in train.stderr  # the log is there, without escape codes
    # a start far outside the training states: the extrapolation warning, on one line
    pred = subprocess.run(
        [
            *sym,
            "predict",
            str(model),
            "--x0",
            "40,0",
            "--mu",
            "0.75",
            "--dt",
            "0.05",
            "--steps",
            "2",
            "--backend",
            "numpy",
        ],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )
    warned = [line for line in pred.stderr.splitlines() if "warning" in line]
    assert warned and all(
        line.startswith("sympredict: warning: ExtrapolationWarning: extrapolation") for line in warned
    ), pred.stderr
    assert len(pred.stderr.splitlines()) == len(warned), pred.stderr
