"""The error-estimate study (sympredict_paper/studies/error_estimate.py): its measures against separate code, and the
published JSON (docs/data/error_estimate.json) against itself and the issue's goals it reports."""

import json
from pathlib import Path

import numpy as np
import pytest

from _studies import study_module  # tests/

PUBLISHED = Path(__file__).resolve().parents[2] / "docs" / "data" / "error_estimate.json"


@pytest.fixture(scope="module")
def study():
    with study_module("error_estimate.py") as module:
        yield module


def _spearman(a, b):
    """Spearman's rank correlation written out for data without ties: Pearson's of the ranks."""
    ra, rb = np.argsort(np.argsort(a)).astype(float), np.argsort(np.argsort(b)).astype(float)
    ra -= ra.mean()
    rb -= rb.mean()
    return float(ra @ rb / np.sqrt((ra @ ra) * (rb @ rb)))


def test_the_measures_match_separate_code(study):
    """Median effectivity, the shares under 3x and over 30x over all (trajectory, step) pairs after step 0, and per
    horizon the median effectivity, the share under 3x, Spearman and the medians, recomputed here."""
    rng = np.random.default_rng(7)
    true = np.exp(rng.normal(-8.0, 1.5, (40, 31)))
    est = true * np.exp(rng.normal(0.5, 1.4, true.shape))
    true[:, 0] = est[:, 0] = 0.0
    out = study.effectivity_metrics(est, true, [10, 30])
    ratio = (est[:, 1:] / true[:, 1:]).ravel()
    assert out["all_steps"]["median_effectivity"] == pytest.approx(np.sort(ratio)[[599, 600]].mean(), rel=1e-12)
    assert out["all_steps"]["share_under_3x"] == pytest.approx(sum(r < 1 / 3 for r in ratio) / 1200, abs=0)
    assert out["all_steps"]["share_over_30x"] == pytest.approx(sum(r > 30 for r in ratio) / 1200, abs=0)
    assert out["all_steps"]["pairs"] == 1200
    for k in (10, 30):
        h = out["horizons"][str(k)]
        r = np.sort(est[:, k] / true[:, k])
        assert h["median_effectivity"] == pytest.approx((r[19] + r[20]) / 2, rel=1e-12)
        assert h["share_under_3x"] == pytest.approx(np.count_nonzero(r < 1 / 3) / 40, abs=0)
        assert h["spearman"] == pytest.approx(_spearman(est[:, k], true[:, k]), rel=1e-12)
        assert h["median_true_error"] == pytest.approx(np.sort(true[:, k])[19:21].mean(), rel=1e-12)
        assert h["median_estimate"] == pytest.approx(np.sort(est[:, k])[19:21].mean(), rel=1e-12)


def test_the_bootstrap_interval_brackets_the_correlation_and_is_one_for_a_monotone_estimate(study):
    rng = np.random.default_rng(3)
    true = rng.lognormal(0.0, 1.0, 60)
    est = true * rng.lognormal(0.0, 0.7, 60)
    lo, hi = study.spearman_interval(est, true, n_boot=400)
    assert lo < _spearman(est, true) < hi
    assert study.spearman_interval(true**2, true, n_boot=50) == pytest.approx([1.0, 1.0], rel=1e-12)


def test_the_published_results_agree_with_themselves_and_with_the_goals_they_report():
    """Each system's goal flags follow from its numbers and the stated goals; the last step's rank correlation is
    that of its horizon; the figure's median curves end at the horizon's medians; the fresh trajectories' rank
    correlation lies inside its bootstrap interval; every (trajectory, step) pair after step 0 is counted."""
    data = json.loads(PUBLISHED.read_text())
    goals = data["goals"]
    assert data["systems"]
    for name, s in data["systems"].items():
        steps, last = s["steps"], s["horizons"][str(s["steps"])]
        assert s["all_steps"]["pairs"] == s["n_test"] * steps, name
        assert s["goals_met"] == {
            "share_under_3x": s["all_steps"]["share_under_3x"] <= goals["share_under_3x_max"],
            "median_effectivity": s["all_steps"]["median_effectivity"] <= goals["median_effectivity_max"],
            "rank_correlation_last": s["rank_correlation_last"] >= goals["rank_correlation_last_min"],
        }, name
        assert s["rank_correlation_last"] == last["spearman"], name
        curves = s["curves"]
        i = curves["step"].index(steps)
        assert curves["median_true"][i] == pytest.approx(last["median_true_error"], rel=1e-12), name
        assert curves["median_estimate"][i] == pytest.approx(last["median_estimate"], rel=1e-12), name
        ranking = s["ranking"]
        lo, hi = ranking["spearman_interval_90_n_rank"]
        assert lo <= ranking["spearman_last_n_rank"] <= hi, name


# ------------------------------------------------------------------- the companion-model designs
def _companion_run(name):
    import json
    from pathlib import Path

    path = Path(__file__).resolve().parents[2] / "docs" / "data" / name
    return json.loads(path.read_text())["systems"]


def _meets_goals(row) -> bool:
    return row["under3"] <= 0.10 and row["med_eff"] <= 30


def test_the_companion_designs_that_failed_failed_as_the_study_and_the_how_to_say():
    """``error_estimate_companion_final.json``: ``twice_roll`` broke the underestimate goal on the three-body problem
    (39% of the pairs under 3x); ``..._guarded.json``: the difference alone overestimated 41 times in the median on the
    cubic oscillator, and ``guarded`` broke a goal there too."""
    final = _companion_run("error_estimate_companion_final.json")
    three_body = final["three_body"]["effectivity"]["candidates"]["twice_roll"]
    assert three_body["under3"] > 0.3 and not _meets_goals(three_body)
    guarded = _companion_run("error_estimate_companion_guarded.json")
    cubic = guarded["cubic"]["dev"]["candidates"]
    assert cubic["twice_roll"]["med_eff"] > 30 and not _meets_goals(cubic["guarded"])
    assert guarded["cubic"]["companions"]["twice"]["accuracy_ratio"] <= 0.5  # the guard let it through


def test_the_pair_design_qualified_by_its_rule_and_the_how_to_claims_follow():
    """``error_estimate_companion_pair.json``: the goals held on all ten systems; the rank correlation at step 200 was
    at least the own estimate's on nine (below only on the pendulum) and on none below the lower end of the own
    estimate's 90% interval; at least 0.6 on all but the double well; the median effectivity lower on all ten; the
    largest share underestimated on the three-body problem; the companion's fit
    1.6 to 4.7 times the model's and the estimate 1.9 to 4.9 times the own estimate's time (CHANGELOG, docstring)."""
    runs = _companion_run("error_estimate_companion_pair.json")
    assert len(runs) == 10 and "coupled_quartic" in runs
    own = {name: run["dev"]["candidates"]["current"] for name, run in runs.items()}
    pair = {name: run["dev"]["candidates"]["twice_pair"] for name, run in runs.items()}
    assert all(_meets_goals(row) for row in pair.values())
    at_least = [n for n in runs if pair[n]["spearman_last"] >= own[n]["spearman_last"]]
    below_interval = [n for n in runs if pair[n]["spearman_last"] < own[n]["ci90_last"][0]]
    under_06 = [n for n in runs if pair[n]["spearman_last"] < 0.6]
    lower_eff = [n for n in runs if pair[n]["med_eff"] < own[n]["med_eff"]]
    assert len(at_least) == 9 and set(runs) - set(at_least) == {"pendulum"}
    assert below_interval == [] and under_06 == ["double_well"]
    assert len(lower_eff) == 10
    worst = max(runs, key=lambda n: pair[n]["under3"])
    assert worst == "three_body"
    fit = [r["companions"]["twice"]["fit_s"] / r["fit_s"] for r in runs.values()]
    estimate = [(r["dev"]["current_s"] + r["dev"]["twice_estimate_s"]) / r["dev"]["current_s"] for r in runs.values()]
    assert round(min(fit), 1) == 1.6 and round(max(fit), 1) == 4.7
    assert round(min(estimate), 1) == 1.9 and round(max(estimate), 1) == 4.9
