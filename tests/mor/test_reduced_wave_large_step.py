"""sympredict_paper/studies/reduced_wave_large_step.py --quick: its results file, and the midpoint form at 50x the FOM step."""

import numpy as np
import pytest

from _studies import run_study  # tests/

pytest.importorskip("pymordemos.symplectic_wave_equation")


def run_quick(out, *extra):
    return run_study("reduced_wave_large_step.py", out, "--quick", *extra)


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    return run_quick(tmp_path_factory.mktemp("large_step") / "quick.json")


@pytest.fixture(scope="module")
def rollout_runs(tmp_path_factory):
    """The rollout search twice, with disjoint test seeds (one of them two seeds)."""
    tmp = tmp_path_factory.mktemp("large_step_rollout")
    return (
        run_quick(tmp / "a.json", "--search", "rollout", "--test-seeds", "12"),
        run_quick(tmp / "b.json", "--search", "rollout", "--test-seeds", "5", "6"),
    )


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


def _choice(res):
    """Everything the rollout search decided, per step factor and update (timings left out)."""
    out = {}
    for entry in res["factors"]:
        out[entry["factor"]] = {"chosen_update": entry["chosen_update"]}
        for update, rec in entry["kernels"].items():
            if "selection" in rec:
                out[entry["factor"]][update] = (
                    rec["kernel"],
                    rec["validation_speeds"],
                    rec["validation_implicit_midpoint"],
                    [{k: v for k, v in r.items() if not k.endswith("_s")} for r in rec["selection"]],
                )
    return out


def test_rollout_search_never_sees_the_test_speeds(rollout_runs):
    """The chosen shapes, budget and update, and every validation score, are the same whatever the test seeds:
    the search uses the validation speeds only.  The chosen model is the best-scored (candidate, budget)."""
    (a, out_a), (b, out_b) = rollout_runs
    assert a["setup"]["test_seeds"] == [12] and b["setup"]["test_seeds"] == [5, 6]
    assert not set(a["setup"]["test"]) & set(b["setup"]["test"])
    assert b["setup"]["test_seed"] == [5] * b["setup"]["n_test"] + [6] * b["setup"]["n_test"]
    assert _choice(a) == _choice(b)
    for res in (a, b):
        for entry in res["factors"]:
            assert [t["seed"] for t in entry["tests"]] == res["setup"]["test_seed"]
            scores = {}
            for update, rec in entry["kernels"].items():
                if "selection" not in rec:
                    continue
                rows = [r for r in rec["selection"] if r["budget"] is not None]
                best = min(rows, key=lambda r: r["score"])
                assert rec["kernel"]["score"] == best["score"] and rec["centres"] == best["n_centers"]
                assert {r["n_centers"] for r in rows} <= set(res["setup"]["budgets"])
                for r in rows:  # the score is the worst validation speed's ratio to implicit midpoint
                    if r["validation_errors"] is not None:
                        ratio = max(e / i for e, i in zip(r["validation_errors"], rec["validation_implicit_midpoint"]))
                        assert r["score"] == pytest.approx(ratio)
                assert len(rec["per_test"]) == len(res["setup"]["test"])
                scores[update] = rec["kernel"]["score"]
            assert entry["chosen_update"] == min(scores, key=scores.get)
    assert "chosen kernel / implicit midpoint" in out_a and "| 6 |" in out_b
