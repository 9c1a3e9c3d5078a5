"""The command line and the example run end to end (smallest sizes)."""

import json
import subprocess
import sys
from pathlib import Path

from sympredict.cli import main

ROOT = Path(__file__).resolve().parents[1]


def test_run_pendulum_smoke_writes_everything(tmp_path, capsys):
    assert main(["run", "pendulum", "--preset", "smoke", "--out", str(tmp_path), "--threads", "1"]) == 0
    results = json.loads((tmp_path / "results.json").read_text())
    summary = results["pendulum_scenario_a"]
    assert summary["n_centers"] == 150 and len(summary["per_dt"]) == 3
    for name in results["figures"]:
        assert (tmp_path / name).stat().st_size > 1000
    assert len(results["figures"]) == 8  # 4 figures x (png, pdf)
    text = (tmp_path / "summary.md").read_text()
    assert "| dT |" in text and "pendulum_phase_portrait.png" in text
    assert (tmp_path / "pendulum_model.h5").exists()
    assert "kernel median error" in capsys.readouterr().out


def test_cli_rejects_unknown_system(tmp_path):
    proc = subprocess.run(
        [sys.executable, "-m", "sympredict.cli", "run", "nosuchsystem", "--out", str(tmp_path)], capture_output=True, text=True
    )
    assert proc.returncode == 2 and "invalid choice" in proc.stderr


def test_example_runs(tmp_path):
    out = tmp_path / "example.png"
    proc = subprocess.run(
        [sys.executable, str(ROOT / "examples" / "pendulum_phase_portrait.py"), "--n-grid", "12", "--centers", "100",
         "--horizon", "2", "--out", str(out)],
        capture_output=True, text=True, timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    assert out.stat().st_size > 1000 and "kernel predictor" in proc.stdout
