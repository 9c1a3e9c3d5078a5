"""select_by_score: settings and budget of the final model chosen by a caller's validation score."""

import numpy as np
import pytest

from sympredict import SymplecticKernelPredictor
from sympredict.kernels import IMQ
from sympredict.estimators.selection import select_by_score
from sympredict.interpolation.greedy import ExactGreedy
from sympredict.symplectic.solvers import NewtonSolver


@pytest.fixture(scope="module")
def split(small_pendulum_data):
    return small_pendulum_data.split(0.2, seed=3)


def step_error(val):
    """Independent score: the RMS error of one predicted step on the validation samples."""

    def score(model):
        return float(np.sqrt(np.mean((model.step(val.x0, mu=val.mu, dt=val.dt) - val.x1) ** 2)))

    return score


def test_chosen_model_is_the_best_scored_prefix_and_equals_a_refit(split):
    data, val = split
    seen = []

    def score(model):
        seen.append(model.n_centers_)
        return step_error(val)(model)

    base = SymplecticKernelPredictor(
        mu_kernel=IMQ(2.0), dt_kernel=IMQ(5.0), trainer=ExactGreedy(tol=0.0), solver=NewtonSolver(backend="numpy")
    )
    cands = [
        {"state_kernel": IMQ(0.15)},
        {"state_kernel": IMQ(0.6)},
        {"state_kernel": IMQ(0.3), "trainer__tol": 3.0},
    ]  # the last stops early (tolerance)
    res = select_by_score(data, val, cands, [20, 60, 40], score, estimator=base)
    rows = [r for r in res.table if r["budget"] is not None]
    # each full candidate scored at every budget (ascending), the early stop once, at its own size
    assert seen[:6] == [20, 40, 60, 20, 40, 60] and len(seen) == 7 and 0 < seen[6] < 20
    assert seen == [r["n_centers"] for r in rows]
    assert rows[-1]["stop_reason"] == "tol" and rows[-1]["budget"] == 20
    best = min(rows, key=lambda r: r["score"])
    assert res.score == best["score"] and res.n_centers == best["n_centers"] == res.model.n_centers_
    assert res.params == cands[best["candidate"]]
    assert all(r["E_val"] is not None and np.isfinite(r["E_val"]) for r in rows)
    # the prefix equals a fit with that budget (round-off)
    refit = base.set_params(**res.params, max_centers=res.n_centers).fit(data.x0, data.x1, mu=data.mu, dt=data.dt)
    np.testing.assert_allclose(
        res.model.step(val.x0, mu=val.mu, dt=val.dt), refit.step(val.x0, mu=val.mu, dt=val.dt), rtol=0, atol=1e-9
    )
    assert res.score == pytest.approx(step_error(val)(refit), rel=1e-6)


def test_failed_fits_and_non_finite_scores_never_win(split):
    data, val = split
    base = SymplecticKernelPredictor(
        mu_kernel=IMQ(2.0), dt_kernel=IMQ(5.0), trainer=ExactGreedy(tol=0.0), solver=NewtonSolver(backend="numpy")
    )
    cands = [
        {"state_kernel": IMQ(0.15), "update": "no such update"},
        {"state_kernel": IMQ(0.15)},
        {"state_kernel": IMQ(0.3)},
    ]

    def score(model):  # a diverged rollout, say, for the first fitted candidate
        return np.nan if model.state_kernel == IMQ(0.15) else step_error(val)(model)

    res = select_by_score(data, val, cands, [30], score, estimator=base)
    assert "error" in res.table[0] and res.table[0]["score"] == np.inf
    assert res.params == cands[2] and np.isfinite(res.score)
    with pytest.raises(ValueError, match="no candidate produced a finite score"):
        select_by_score(data, val, cands[:2], [30], score, estimator=base)
    with pytest.raises(ValueError, match="at least one candidate"):
        select_by_score(data, val, [], [30], score, estimator=base)
