"""The search engine's own pieces, on scores known in closed form (no fits): the coordinate search, the ridge
choice, successive halving's survivors, and the refusals; and the grid search with rungs on a small fitted case.  The fitted searches that run on it are tested in test_direct_and_selection.py,
test_select_by_score.py and test_auto_defaults.py."""

import numpy as np
import pytest

from sympredict.data import FlowMapData
from sympredict.estimators.search import HALVING_KEEP, coordinate_search, grid_search, halving_survivors, ridge_search
from sympredict import KernelSearch
from sympredict.base import clone
from sympredict.kernels import IMQ


def _counted(f):
    calls = []

    def key(cand):
        calls.append(cand)
        return f(cand)

    return key, calls


def _scale(value, index, factor):
    return value * factor


def test_coordinate_search_walks_to_the_lattice_minimum_of_a_separable_score():
    """Minimum of (log2 a - 3)^2 + (log2 b + 2)^2 on the lattice 2^k: reached from (1, 1) in factor-2 moves."""
    key, calls = _counted(lambda c: (np.log2(c[0]) - 3) ** 2 + (np.log2(c[1]) + 2) ** 2)
    best = coordinate_search((1.0, 1.0), key, [0, 1], _scale, sweeps=10)
    assert best == (8.0, 0.25)
    assert len(calls) <= 1 + 2 * 2 * 10


def test_coordinate_search_keeps_inactive_and_none_coordinates_and_stops_after_a_sweep_without_gain():
    key, calls = _counted(lambda c: abs(np.log2(c[0]) - 1) + (0.0 if c[2] is None else 1.0))
    best = coordinate_search((1.0, 5.0, None), key, [0, 1, 2], lambda v, i, f: v * f if i == 0 else v + f, sweeps=5)
    assert best[0] == 2.0 and best[2] is None
    # coordinate 1 changes nothing in the score: never an improvement, so sweep 2 improves nothing and ends it
    assert best[1] == 5.0
    assert len(calls) == 1 + 2 * (2 * 2 * 2)  # the start; two sweeps of two moves on coordinates 0 and 1, each
    assert len(set(calls)) == 6  # scoring the move and the best (a caller caches: 6 distinct candidates)
    assert all(c[2] is None for c in calls)


def test_from_best_moves_from_the_new_best_and_from_the_anchor_tries_both_neighbours():
    """With the score falling towards small values, the factor 1/2 wins first; from the best, the factor 2 then
    returns to the start (already known); from the coordinate's anchor it tries the other neighbour, 2."""
    key, calls = _counted(lambda c: c[0])
    coordinate_search((1.0,), key, [0], _scale, sweeps=1, from_best=True)
    assert [c[0] for c in calls] == [1.0, 0.5, 1.0, 1.0, 0.5]  # each try: the candidate, then the best
    key, calls = _counted(lambda c: c[0])
    coordinate_search((1.0,), key, [0], _scale, sweeps=1, from_best=False)
    assert [c[0] for c in calls] == [1.0, 0.5, 1.0, 2.0, 0.5]


def test_ridge_search_always_tries_the_exact_fit_and_breaks_ties_towards_the_smaller_term():
    seen = []

    def evaluate(lam):
        seen.append(lam)
        return {0.0: 3.0, 1e-6: 1.0, 1e-4: 1.0, 1e-2: np.nan}[lam], f"model {lam}", {"n_centers": 7}

    best, table, fitted = ridge_search([1e-2, 1e-4, 1e-6, 1e-4], evaluate)
    assert seen == [0.0, 1e-6, 1e-4, 1e-2]
    assert best == (1e-6, 1.0, "model 1e-06")
    assert [row["regularization"] for row in table] == seen and table[0] == {
        "regularization": 0.0,
        "score": 3.0,
        "n_centers": 7,
    }
    assert fitted == {}
    _, _, fitted = ridge_search([1e-6], lambda lam: (1.0, lam, {}), keep=True)
    assert fitted == {0.0: 0.0, 1e-6: 1e-6}


def test_ridge_search_reports_no_finite_score_and_refuses_bad_terms():
    best, table, _ = ridge_search([1e-3], lambda lam: (np.inf, None, {}))
    assert best is None and len(table) == 2
    with pytest.raises(ValueError, match="lambdas must be finite non-negative"):
        ridge_search([-1.0], lambda lam: (0.0, None, {}), name="lambdas")


def test_grid_search_needs_the_estimator_the_candidates_share():
    x = np.zeros((4, 2))
    data = FlowMapData(x, x, None, np.full(4, 0.1))
    with pytest.raises(ValueError, match="needs the estimator"):
        grid_search(data, data, [IMQ(1.0)])


def test_shrink_goes_on_after_a_sweep_without_gain_with_the_factors_logarithms_scaled():
    """Minimum of (log2 a - 1.5)^2: factor 2 reaches 2 and stalls there; without ``shrink`` the search ends at 2,
    with ``shrink=0.5`` the next sweep moves by sqrt 2 = exp(log(2) / 2) and reaches 2^1.5."""
    score = lambda c: (np.log2(c[0]) - 1.5) ** 2  # noqa: E731
    assert coordinate_search((1.0,), score, [0], _scale, factors=(2.0, 0.5), sweeps=3) == (2.0,)
    key, calls = _counted(score)
    sweeps = []
    best = coordinate_search(
        (1.0,),
        key,
        [0],
        _scale,
        factors=(2.0, 0.5),
        sweeps=3,
        shrink=0.5,
        on_sweep=lambda sweep, b: sweeps.append((sweep, b)),
    )
    root2 = float(np.exp(np.log(2.0) * 0.5))
    assert best == (2.0 * root2,)
    assert sweeps == [(0, (2.0,)), (1, (2.0,)), (2, (2.0 * root2,))]  # all three sweeps run
    assert {c[0] for c in calls} == {1.0, 2.0, 4.0, 2.0 * root2, 2.0 * root2 * float(np.exp(-np.log(2.0) * 0.5))}
    with pytest.raises(ValueError, match="shrink must lie in"):
        coordinate_search((1.0,), score, [0], _scale, shrink=1.0)


def test_halving_keeps_the_best_third_in_order_ties_to_the_earlier_and_at_least_two():
    cands = list("abcdefghi")
    keys = [5.0, 1.0, 7.0, 1.0, 9.0, np.inf, 3.0, 8.0, 2.0]
    assert halving_survivors(cands, keys) == ["b", "d", "i"]  # the three smallest, in the given order
    assert halving_survivors(cands, [1.0] * 9) == ["a", "b", "c"]  # ties: the earlier candidates
    assert halving_survivors(cands[:4], keys[:4]) == ["b", "d"]  # at least HALVING_KEEP of few candidates
    assert HALVING_KEEP == 2 and halving_survivors(["x"], [1.0]) == ["x"]
    # a non-finite key goes on only where too few are finite
    assert halving_survivors(["p", "q", "r"], [np.inf, 2.0, np.inf]) == ["p", "q"]
    assert halving_survivors(cands, [(False, k) for k in keys]) == ["b", "d", "i"]  # rank tuples as keys


@pytest.fixture(scope="module")
def rung_case(pendulum):
    """Pendulum samples at one length: train and validation parts."""
    rng = np.random.default_rng(3)
    x0 = np.column_stack([rng.uniform(-1.5, 1.5, 400), rng.uniform(-2.0, 2.0, 400)])
    x1 = pendulum.flow(x0, 0.8, 0.1)
    data = FlowMapData(x0, x1, None, np.full(400, 0.1))
    return data.subset(np.arange(300)), data.subset(np.arange(300, 400))


def test_grid_search_with_rungs_keeps_the_best_candidate_at_a_fraction_of_the_fits(rung_case):
    """Successive halving on a grid whose shapes span two decades: the same winner and score as training every
    candidate to m_star, with only the rungs' survivors trained to m_star."""
    from sympredict import SymplecticKernelPredictor

    train, val = rung_case
    grid = [IMQ(e) for e in (0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0)]
    est = SymplecticKernelPredictor(update="midpoint")
    plain = grid_search(train, val, grid, m_star=100, estimator=est, widen=0)
    halved = grid_search(train, val, grid, m_star=100, estimator=est, widen=0, rungs=(25, 50))
    assert halved.state == plain.state and halved.score == plain.score  # same fit of the same arrays
    rows = {m: [r for r in halved.table if r.get("rung") == m] for m in (25, 50, None)}
    assert len(rows[25]) == 7 and len(rows[50]) == 3 and len(rows[None]) == 2
    # each rung passed on its best third by E_val at that rung
    best25 = sorted(rows[25], key=lambda r: r["E_val"])[:3]
    assert {r["kernels"] for r in rows[50]} == {r["kernels"] for r in best25}
    again = grid_search(train, val, grid, m_star=100, estimator=est, widen=0, rungs=(25, 50))
    assert [(r["kernels"], r.get("rung"), r["E_val"]) for r in again.table] == [
        (r["kernels"], r.get("rung"), r["E_val"]) for r in halved.table
    ]


def test_grid_search_early_stop_keeps_the_winner_and_stops_only_candidates_clearly_losing_at_a_checkpoint(rung_case):
    """With ``early_stop`` a candidate whose ``E_val`` at a checkpoint (a quarter, half of ``m_star``) exceeds its
    margin (2000, 200) times the smallest ``E_val(m_star)`` so far stops at the first such checkpoint: the same
    winner and score as training every candidate to ``m_star`` (the same fits of the same arrays), and every stopped
    candidate was that far behind."""
    from sympredict import SymplecticKernelPredictor
    from sympredict.estimators.search import E_VAL_STOP_MARGINS, fit_candidate

    margins = sorted(E_VAL_STOP_MARGINS)
    train, val = rung_case
    grid = [IMQ(e) for e in (0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 20.0, 50.0)]
    est = SymplecticKernelPredictor(update="midpoint")
    plain = grid_search(train, val, grid, m_star=100, estimator=est, widen=0)
    early = grid_search(train, val, grid, m_star=100, estimator=est, widen=0, early_stop=True)
    assert early.state == plain.state and early.score == plain.score
    stopped = [r for r in early.table if "abandoned" in r]
    assert stopped and all(r["n_centers"] == r["abandoned"] in {int(f * 100) for f, _ in margins} for r in stopped)
    full = {r["kernels"]: r["E_val"] for r in plain.table}
    curves = {}  # each candidate's own E_val curve, from its full run's history
    for k in grid:
        model = clone(est).set_params(state_kernel=k, max_centers=100, trainer__tol=0.0)
        curves[repr(k)] = fit_candidate(model, train, val).history_.val_max_residual
    for i, r in enumerate(early.table):
        before = [q["E_val"] for q in early.table[:i] if np.isfinite(q["E_val"])]
        curve = curves[r["kernels"]]
        stop = next(
            (
                int(f * 100)
                for f, k in margins
                if before and len(curve) > f * 100 and curve[int(f * 100)] > k * min(before)
            ),
            None,
        )
        assert r.get("abandoned") == stop, r["kernels"]
        if "abandoned" in r:
            assert r["E_val"] == np.inf and r["abandoned_E_val"] == curve[stop]
            assert full[r["kernels"]] > plain.score  # it would have lost
        else:
            assert r["E_val"] == full[r["kernels"]]


def test_quick_search_preset_and_its_overrides():
    """``KernelSearch.quick()``: the default search with smaller comparison sizes and halving; overrides on top,
    checked as any setting is."""
    from sympredict import KernelSearch
    from sympredict.base import clone

    quick = KernelSearch.quick()
    expected = dict(max_samples=1200, m_star=100, final_centers=250, halving=True, refine_sweeps=1)
    assert {k: quick.get_params()[k] for k in expected} == expected
    default = KernelSearch().get_params()
    assert {k: v for k, v in quick.get_params().items() if k not in expected} == {
        k: v for k, v in default.items() if k not in expected
    }
    assert clone(quick) == quick and KernelSearch.quick(seed=3).seed == 3
    assert KernelSearch.quick(final_centers=400).final_centers == 400
    with pytest.raises(ValueError, match="final_centers must be a positive integer"):
        KernelSearch.quick(final_centers=0)
    with pytest.raises(TypeError):
        KernelSearch.quick(no_such_setting=1)


@pytest.fixture(scope="module")
def quick_fit(pendulum):
    """Pendulum samples at five lengths, fitted to 300 centres with the quick search."""
    from sympredict import KernelSearch, SymplecticKernelPredictor

    rng = np.random.default_rng(5)
    n = 1600
    x0 = np.column_stack([rng.uniform(-1.5, 1.5, n), rng.uniform(-1.5, 1.5, n)])
    mu = rng.choice(np.linspace(0.7, 0.8, 5), n)
    x1 = pendulum.flow(x0, mu, 0.1)
    return SymplecticKernelPredictor(max_centers=300, search=KernelSearch.quick()).fit(x0, x1, mu=mu, dt=0.1)


def test_quick_search_scores_its_candidates_below_the_final_size(quick_fit):
    """The quick search compares its candidates at 100 (stage 1) and 250 (stages 2 and 3) centres on at most 1,200
    samples, and fits only the final-size stage's few candidates to ``max_centers``: a search that scored its
    candidates at the final size (as the default does where ``max_centers <= 1000``) fails here."""
    s = quick_fit.search_
    assert s.m_star == 100 and s.m_final == 250 and s.final_size == 300
    assert s.n_train + s.n_validation <= 1200
    by_stage = {k: [r for r in s.table if r["stage"] == k] for k in (1, 2, 3, 4)}
    assert by_stage[1] and by_stage[2] and by_stage[4]
    assert max(r["n_centers"] for r in by_stage[1] if "n_centers" in r) <= 100
    assert all(r["n_centers"] <= 250 for k in (2, 3) for r in by_stage[k])
    # halving: stage 1 at rungs of 25 and 50 centres, stage 2's candidates scored at a rung of 62 first
    assert {r["rung"] for r in by_stage[1] if "rung" in r} == {25, 50}
    assert all(r["rung_centers"] <= 62 for r in by_stage[2])
    # the fits at the size of the model: the final-size stage's one to four per finalist, the best candidates
    # with and without a structure (one finalist of each kind at most)
    symmetric = [r for r in by_stage[4] if r["kernels"].startswith("Symmetric(")]
    plain = [r for r in by_stage[4] if not r["kernels"].startswith("Symmetric(")]
    assert 1 <= len(symmetric) + len(plain) and len(symmetric) <= 4 and len(plain) <= 4
    assert len(s.table) == sum(len(v) for v in by_stage.values())
    assert quick_fit.n_centers_ <= 300 and np.isfinite(s.score)


def test_stage_seconds_split_the_search_time_by_stage(quick_fit):
    """``search_.stage_seconds``: per stage of the table, the sum of its candidates' ``fit_s``, stages in order, within
    the search's wall time (a split that dropped a stage, or counted a candidate twice, fails)."""
    s = quick_fit.search_
    split = s.stage_seconds
    assert list(split) == sorted({r["stage"] for r in s.table}) and {1, 2, 4} <= set(split)
    for stage, seconds in split.items():
        assert seconds == pytest.approx(sum(r.get("fit_s", 0.0) for r in s.table if r["stage"] == stage), rel=1e-12)
        assert seconds > 0
    assert sum(split.values()) <= s.seconds


# ------------------------------------------------------------------ early stop of clearly losing candidates
def test_early_stop_checks_half_the_centres_and_gives_up_only_beyond_its_margin_of_a_finite_bound():
    from sympredict.estimators.search import EARLY_STOP_MARGINS, EarlyStop

    ((fraction, factor),) = EARLY_STOP_MARGINS
    early = EarlyStop()
    assert early.checkpoints(40) == [int(fraction * 40)] and early.checkpoints(30) == []  # none below 20 centres
    assert not early.start(np.inf).give_up(20, 40, 1e9)  # nothing to beat yet
    early.start(1e-3)
    assert not early.give_up(20, 40, 0.99 * factor * 1e-3) and early.abandoned is None
    assert not early.give_up(20, 40, np.inf) and not early.give_up(20, 40, np.nan)  # a failed prefix goes on
    assert early.give_up(20, 40, 1.01 * factor * 1e-3) and early.abandoned == 20
    assert early.start(1.0).abandoned is None and early.scores == {}


@pytest.fixture(scope="module")
def pendulum_split(pendulum):
    rng = np.random.default_rng(3)
    x0 = np.column_stack([rng.uniform(-1.5, 1.5, 160), rng.uniform(-1.5, 1.5, 160)])
    data = FlowMapData(x0, pendulum.flow(x0, 0.8, 0.1), None, np.full(160, 0.1))
    return data.subset(np.arange(120)), data.subset(np.arange(120, 160))


@pytest.mark.paths
def test_a_candidate_given_up_stops_at_its_checkpoint_with_the_full_runs_prefix(pendulum_split):
    """Under :data:`CANDIDATE_STOP` a fit scores its prefix at half its centres (the one-step error of the full fit's
    own truncation, by another Newton solver: within its stopping rule) and stops there where it gives up; its
    selection is the full run's prefix (the same code path), and with nothing to beat it is the full run."""
    from sympredict import SymplecticKernelPredictor
    from sympredict.estimators.search import CANDIDATE_STOP, EarlyStop, fit_candidate, state_weights

    train, val = pendulum_split
    est = SymplecticKernelPredictor(IMQ(0.5), max_centers=60, update="midpoint")
    full = fit_candidate(clone(est), train)
    assert full.n_centers_ == 60
    w = state_weights(val)
    for bound, stops in ((1e-12, True), (np.inf, False)):
        early = EarlyStop(bound=bound, samples=(val, w))
        token = CANDIDATE_STOP.set(early)
        try:
            model = fit_candidate(clone(est), train)
        finally:
            CANDIDATE_STOP.reset(token)
        result, ref = model.model_.greedy_result, full.model_.greedy_result
        if stops:
            assert model.history_.stop_reason == "abandoned" and model.n_centers_ == early.abandoned == 30
            np.testing.assert_array_equal(result.selected, ref.selected[:30])
        else:
            assert model.history_.stop_reason == "max_centers" and early.abandoned is None
            np.testing.assert_array_equal(result.selected, ref.selected)
            np.testing.assert_array_equal(result.coef, ref.coef)
        half = full.truncated(30).step(val.x0, dt=0.1)
        np.testing.assert_allclose(early.scores[30], EarlyStop.error(half, val.x0, val.x1, w), rtol=1e-6)


def test_final_size_score_of_an_abandoned_candidate_is_inf_with_the_checkpoints_centres(pendulum_split):
    from sympredict import SymplecticKernelPredictor
    from sympredict.estimators.search import EARLY_STOP, EarlyStop, final_size_score

    train, val = pendulum_split
    est = SymplecticKernelPredictor(max_centers=60)
    params = {"state_kernel": IMQ(0.5), "mu_kernel": None, "dt_kernel": None, "update": "midpoint"}
    plain = final_size_score(est, params, 60, train, val)
    for bound, expect in ((1e-12, (np.inf, 30)), (np.inf, (float(plain[0]), 60))):
        token = EARLY_STOP.set(EarlyStop(bound=bound))
        try:
            value, n, _, err, _, _ = final_size_score(est, params, 60, train, val)
        finally:
            EARLY_STOP.reset(token)
        assert (float(value), n, err) == (*expect, None)


@pytest.fixture()
def scripted_search(monkeypatch):
    """The second stage's scores scripted by the candidate's shapes relative to the start's (the first stage is real):
    the start scores 1e-3 (1e-2 at half its centres); its state shape doubled wins (1e-4) although at half its centres
    it is 50 times the start's full-size score (5 times the start's at half); every other candidate scores 1e-2, and
    1.0 at half its centres.  The checkpoint goes through the search's
    :class:`EarlyStop` as a fit's would.  Returns ``{'seen': [(state eps / start's, bound or None) per call], 'start':
    (eps, factors, mu kernel)}``."""
    import sympredict.estimators.auto as auto
    from sympredict.estimators.search import EARLY_STOP, HeldOutScore

    record = {"seen": [], "start": None}

    def scripted(estimator, params, m_final, train, val, largest=500, rollouts=None):
        state = params["state_kernel"]
        if record["start"] is None:
            record["start"] = (state.kernel.eps, state.factors, params["mu_kernel"])
        eps0, factors0, mu0 = record["start"]
        early = EARLY_STOP.get()
        record["seen"].append((state.kernel.eps / eps0, None if early is None else early.bound))
        same = state.factors == factors0 and params["mu_kernel"] == mu0
        if same and np.isclose(state.kernel.eps, 2 * eps0):
            half, full = 5e-2, 1e-4
        elif same and state.kernel.eps == eps0:
            half, full = 1e-2, 1e-3
        else:
            half, full = 1.0, 1e-2
        if early is not None and early.give_up(m_final // 2, m_final, half):
            return np.inf, m_final // 2, 0.0, None, None, 0.0
        return HeldOutScore(full, 0.0), m_final, 0.0, None, None, 0.0

    monkeypatch.setattr(auto, "final_size_score", scripted)
    return record


def test_the_early_stop_keeps_a_winner_far_behind_at_half_its_centres_and_stops_clear_losers(pendulum, scripted_search):
    """The coordinate search's neighbour that wins at full size was 50 times the best score at half its centres (5
    times the best candidate's own score there): within the margins, it is fitted to full size and chosen; the
    neighbours 1000 times behind stop there (rows with ``abandoned``, never chosen); the start is never stopped (it
    has nothing to beat).  Without the early stop, the same choice."""
    from sympredict import SymplecticKernelPredictor

    rng = np.random.default_rng(0)
    x0 = np.column_stack([rng.uniform(-1.5, 1.5, 300), rng.uniform(-1.5, 1.5, 300)])
    mu = rng.uniform(0.6, 1.0, 300)
    x1 = np.vstack([pendulum.flow(x0[i : i + 1], mu[i], 0.1) for i in range(300)])
    search = KernelSearch(
        families=("imq",), updates=("symplectic_euler",), m_star=20, max_samples=200, refine_sweeps=1, structure=False
    )
    model = SymplecticKernelPredictor(max_centers=40, search=search).fit(x0, x1, mu=mu, dt=0.1)
    seen, eps0 = scripted_search["seen"], scripted_search["start"][0]
    assert seen[0] == (1.0, np.inf)  # the start: nothing to beat, never stopped
    assert model.choice_["state_kernel"].kernel.eps == pytest.approx(2 * eps0)
    assert model.search_.score == pytest.approx(1e-4)
    rows = [r for r in model.search_.table if r.get("stage") == 2]
    stopped = [r for r in rows if "abandoned" in r]
    assert len(rows) == 7 and len(stopped) == 5  # the start, the winner; five neighbours stopped at 20 of 40 centres
    assert all(r["score"] == np.inf and r["n_centers"] == 20 and r["abandoned_score"] == 1.0 for r in stopped)
    scripted_search["seen"].clear()
    scripted_search["start"] = None
    off = SymplecticKernelPredictor(max_centers=40, search=clone(search).set_params(early_stop=False))
    off.fit(x0, x1, mu=mu, dt=0.1)
    assert all(bound is None for _, bound in scripted_search["seen"])
    assert repr(off.choice_) == repr(model.choice_)
