"""The issue-14 accuracy benchmarks run (``--quick``) and report what they chose on validation data only."""

import numpy as np
import pytest

from _studies import run_study  # tests/


def _run(script, tmp_path, *extra):
    summary, stdout = run_study(script, tmp_path / "out.json", "--quick", *extra)
    assert "chosen" in stdout
    return summary


def _check_choice(summary):
    assert not set(summary["test_seeds"]) & set(summary["val_seeds"])
    scores = [c["score"] for c in summary["candidates"]]
    assert len(scores) >= 3 and all(np.isfinite(scores))
    best = min(summary["candidates"], key=lambda c: c["score"])
    assert best["params"] == summary["chosen"]  # the validation minimum is the chosen candidate


@pytest.mark.parametrize("script", ["pendulum_accuracy.py", "henon_heiles_accuracy.py"])
def test_accuracy_benchmark_quick(script, tmp_path):
    summary = _run(script, tmp_path)
    _check_choice(summary)
    if script.startswith("pendulum"):
        values = [v for d in summary["test_medians"].values() for v in d.values()]
        assert len(values) == 3 * len(summary["test_seeds"])
        if len(summary["test_seeds"]) == 1:  # one draw: pooling over the seeds changes nothing
            (per_seed,) = summary["test_medians"].values()
            assert summary["test_medians_pooled"] == per_seed
        assert summary["met_pooled"] == (max(summary["test_medians_pooled"].values()) <= summary["target"])
    else:
        assert summary["sampling"] == min(summary["candidates"], key=lambda c: c["score"])["sampling"]
        values = [t["median_at_T"] for t in summary["test"].values()]
    assert all(np.isfinite(values))
    assert summary["met"] == (max(values) <= summary["target"])


def test_pendulum_accuracy_quick_with_symmetry(tmp_path):
    """The group-invariant kernel (``--symmetry klein``) through the same protocol."""
    summary = _run("pendulum_accuracy.py", tmp_path, "--symmetry", "klein")
    _check_choice(summary)
    assert summary["symmetry"] == "klein" and summary["update"] == "midpoint"
    values = [v for d in summary["test_medians"].values() for v in d.values()]
    assert len(values) == 3 * len(summary["test_seeds"]) and all(np.isfinite(values))
    assert summary["met"] == (max(values) <= summary["target"])


def test_pendulum_accuracy_quick_with_split(tmp_path):
    """The exact-linear-flow splitting (``--split``, sympredict.flowmap.splitting) through the same protocol."""
    summary = _run("pendulum_accuracy.py", tmp_path, "--split", "--symmetry", "klein")
    _check_choice(summary)
    assert summary["split"] is True and summary["symmetry"] == "klein"
    values = [v for d in summary["test_medians"].values() for v in d.values()]
    assert len(values) == 3 * len(summary["test_seeds"]) and all(np.isfinite(values))
    assert summary["met"] == (max(values) <= summary["target"])
