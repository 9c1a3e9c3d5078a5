"""The blocked-greedy study's noise floor: two runs' JSON compared trainer by trainer, as its users run it."""

import json
from pathlib import Path

import numpy as np
import pytest

from _studies import run_study  # tests/ (on sys.path under pytest)


def _run(seed_train, exact, blocked, n_test=3):
    """A study record with one size: the exact and blocked fits' errors (per test trajectory too)."""

    def fit(errors, held_out):
        errors = np.asarray(errors, dtype=float)
        return {
            "held_out_error": held_out,
            "traj_errors": errors.tolist(),
            "traj_error_median": float(np.median(errors)),
            "traj_error_max": float(errors.max()),
        }

    return {
        "system": "coupled_pendulums",
        "n_test": n_test,
        "test_steps": 200,
        "seeds": {"train": seed_train, "held_out": 2, "test": 3},
        "rows": [{"max_centers": 100, "exact": fit(*exact), "blocked": fit(*blocked)}],
    }


def test_the_noise_floor_compares_the_exact_fits_of_two_training_draws(tmp_path):
    a = _run(1, ([1.0, 2.0, 4.0], 0.5), ([1.0, 3.0, 4.0], 0.6))
    b = _run(4, ([2.0, 2.0, 2.0], 1.0), ([1.0, 1.0, 4.0], 0.5))
    (tmp_path / "a.json").write_text(json.dumps(a))
    (tmp_path / "b.json").write_text(json.dumps(b))
    out, stdout = run_study(
        "blocked_greedy.py",
        tmp_path / "noise.json",
        "--noise-floor",
        str(tmp_path / "a.json"),
        str(tmp_path / "b.json"),
    )
    (row,) = out["rows"]
    exact = row["exact_b_over_a"]
    assert exact["held_out_error"] == pytest.approx(2.0)
    assert exact["traj_error_median"] == pytest.approx(1.0)  # median 2 / median 2
    assert exact["traj_error_max"] == pytest.approx(0.5)  # max 2 / max 4
    assert exact["per_traj_median"] == pytest.approx(1.0)  # ratios 2, 1, 0.5
    assert exact["per_traj_max"] == pytest.approx(2.0)
    assert row["blocked_over_exact_a"]["per_traj_max"] == pytest.approx(1.5)
    assert row["blocked_over_exact_b"]["traj_error_max"] == pytest.approx(2.0)
    assert out["seeds"]["b"]["train"] == 4 and "protocol" in out


def test_the_noise_floor_refuses_runs_that_are_not_comparable(tmp_path):
    a = _run(1, ([1.0, 2.0, 4.0], 0.5), ([1.0, 3.0, 4.0], 0.6))
    (tmp_path / "a.json").write_text(json.dumps(a))
    (tmp_path / "same_seed.json").write_text(json.dumps(_run(1, ([1.0, 2.0, 4.0], 0.5), ([1.0, 3.0, 4.0], 0.6))))
    (tmp_path / "other_tests.json").write_text(json.dumps(_run(4, ([1.0] * 4, 0.5), ([1.0] * 4, 0.6), n_test=4)))
    for other, message in (("same_seed.json", "differ in the training seed"), ("other_tests.json", "'n_test'")):
        with pytest.raises(AssertionError, match=message):
            run_study(
                "blocked_greedy.py",
                tmp_path / "x.json",
                "--noise-floor",
                str(tmp_path / "a.json"),
                str(tmp_path / other),
            )


def test_the_published_ratios_are_those_of_the_runs_per_trajectory_errors():
    """The scaling page's ratios, recomputed from the committed runs' per-trajectory errors by separate code."""
    data = Path(__file__).resolve().parents[2] / "docs" / "data"
    first, second, noise = (
        json.loads((data / name).read_text())
        for name in ("blocked_greedy.json", "blocked_greedy_seed4.json", "blocked_greedy_noise.json")
    )
    for row in first["rows"]:
        exact, blocked = (np.asarray(row[k]["traj_errors"]) for k in ("exact", "blocked"))
        assert len(exact) == first["n_test"] == 100
        assert row["ratios"]["traj_error_max"] == pytest.approx(blocked.max() / exact.max(), rel=1e-12)
        assert row["ratios"]["traj_error_median"] == pytest.approx(np.median(blocked) / np.median(exact), rel=1e-12)
        assert row["ratios"]["per_traj_median"] == pytest.approx(np.median(blocked / exact), rel=1e-12)
    (published,) = noise["rows"]
    a = next(r for r in first["rows"] if r["max_centers"] == published["max_centers"])
    (b,) = second["rows"]
    ea, eb = np.asarray(a["exact"]["traj_errors"]), np.asarray(b["exact"]["traj_errors"])
    assert second["seeds"]["train"] != first["seeds"]["train"] and second["seeds"]["test"] == first["seeds"]["test"]
    assert published["exact_b_over_a"]["traj_error_max"] == pytest.approx(eb.max() / ea.max(), rel=1e-12)
    assert published["exact_b_over_a"]["per_traj_median"] == pytest.approx(np.median(eb / ea), rel=1e-12)
    assert published["exact_b_over_a"]["held_out_error"] == pytest.approx(
        b["exact"]["held_out_error"] / a["exact"]["held_out_error"], rel=1e-12
    )
    bb = np.asarray(b["blocked"]["traj_errors"])
    assert published["blocked_over_exact_b"]["traj_error_max"] == pytest.approx(bb.max() / eb.max(), rel=1e-12)
