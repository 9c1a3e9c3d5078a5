"""benchmarks/reduced_wave_large_step.py --quick: its results file, and the midpoint form at 50x the FOM step."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pymordemos.symplectic_wave_equation")

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "reduced_wave_large_step.py"


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    out = tmp_path_factory.mktemp("large_step") / "quick.json"
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", NUMBA_NUM_THREADS="1")
    proc = subprocess.run([sys.executable, str(SCRIPT), "--quick", "--json", str(out)], capture_output=True, text=True,
                          env=env, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(out.read_text()), proc.stdout


def test_results_file_structure(quick):
    res, stdout = quick
    setup = res["setup"]
    assert setup["dim"] == 6 and setup["quick"]
    assert not set(setup["test"]) & set(setup["train"])
    assert [e["factor"] for e in res["factors"]] == [10, 50]
    for entry in res["factors"]:
        assert entry["steps"] == round(setup["T"] / entry["dT"])
        assert entry["dT"] == pytest.approx(entry["factor"] * setup["h"])
        assert len(entry["tests"]) == setup["n_test"]
        for t in entry["tests"]:
            assert np.isfinite(t["implicit_midpoint"]["error"]) and t["implicit_midpoint"]["error"] > 0
            assert np.isfinite(t["reduction_error"])
            assert 0 <= t["midpoint_sigma"] <= 1
        assert set(entry["kernels"]) == {"symplectic_euler", "midpoint"}
        for update, rec in entry["kernels"].items():
            assert rec["update"] == update
            assert {"check_symplectic_euler", "check_midpoint"} <= set(rec)
            assert not set(rec["validation_speeds"]) & set(setup["test"])  # kernels chosen off the test speeds
            if "per_test" in rec:  # trained: one row per test speed, an error or a named Newton failure
                assert len(rec["per_test"]) == setup["n_test"]
                assert all((r["error"] is None) == ("newton_failure" in r) for r in rec["per_test"])
            else:
                assert rec["status"].startswith("not trained") and not rec[f"check_{update}"]["ok"]
        assert f"### {entry['factor']}x the FOM step" in stdout


def test_midpoint_form_exists_at_50x_where_type_two_does_not(quick):
    """2n = 6: every reduced mode turns by less than half a turn per step at 50x the FOM step (1.65 rad at most),
    more than a quarter turn for the fastest: the paper's update is refused, the symmetric one trains and steps."""
    res, _ = quick
    entry = next(e for e in res["factors"] if e["factor"] == 50)
    assert np.pi / 2 < entry["max_turn_per_step"] < np.pi
    assert entry["midpoint_sigma_scan_min"] > 0.1
    euler, mid = entry["kernels"]["symplectic_euler"], entry["kernels"]["midpoint"]
    assert not euler["check_symplectic_euler"]["ok"] and "per_test" not in euler
    assert mid["check_midpoint"]["ok"]
    assert all(r["error"] is not None for r in mid["per_test"])  # no Newton failure
    # a learned step, not the identity: its error is far below the size of the motion
    assert all(r["error"] < 0.1 for r in mid["per_test"])
