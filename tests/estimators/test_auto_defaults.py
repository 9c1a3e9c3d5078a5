"""The default estimator on a user's data: what it chooses, that it learns, and what it reports.

``SymplecticKernelPredictor()`` with no kernels normalises the states symplectically, chooses kernel
family, shapes and update on held-out samples (:class:`sympredict.KernelSearch`), learns a parameter or
several steps without being given their kernels, and reports the fit (``diagnostics_``).
"""

import logging
import warnings

import numpy as np
import pytest

from sympredict.kernels.transforms import lower_state_kernel
from sympredict import KernelSearch, ModelFileError, SymplecticKernelPredictor, TrajectoryData
from sympredict.base import clone
from sympredict.container import read_container, write_container
from sympredict.estimators.auto import FitDiagnostics, pair_factors
from sympredict.estimators.model_files import MODEL_FORMAT
from sympredict.interpolation.greedy import ExactGreedy
from sympredict.kernels import IMQ
from sympredict.data import FlowMapData
from sympredict.symplectic.metrics import symplecticity_defect

from _tolerances import assert_same_predictions

SMALL = KernelSearch(m_star=40, max_samples=400, refine_sweeps=1)


def _pendulum_samples(pendulum, n, seed, dt=0.1, mu_range=(0.6, 1.0)):
    rng = np.random.default_rng(seed)
    x0 = np.column_stack([rng.uniform(-1.5, 1.5, n), rng.uniform(-2.0, 2.0, n)])
    mu = rng.uniform(*mu_range, n)
    dt = np.broadcast_to(np.asarray(dt, dtype=float), (n,)) if np.ndim(dt) == 0 else np.asarray(dt)
    x1 = (
        np.vstack([pendulum.flow(x0[i : i + 1], mu[i], dt[i]) for i in range(n)])
        if np.ptp(dt) > 0 or np.ptp(mu) > 0
        else pendulum.flow(x0, mu[0], dt[0])
    )
    return x0, x1, mu, dt


@pytest.fixture(scope="module")
def param_data(pendulum):
    return _pendulum_samples(pendulum, 500, 0)


@pytest.fixture(scope="module")
def auto_model(param_data):
    x0, x1, mu, dt = param_data
    return SymplecticKernelPredictor(max_centers=120, search=SMALL).fit(x0, x1, mu=mu, dt=0.1)


def _step_error(model, pendulum, seed, mu_range=(0.65, 0.95), scale=1.0):
    """Median one-step error relative to the step's increment on fresh states inside the training box."""
    x0, x1, mu, _ = _pendulum_samples(pendulum, 60, seed, mu_range=mu_range)
    pred = model.step(x0 * scale, mu=mu[:, None], dt=0.1) / scale
    return float(np.median(np.linalg.norm(pred - x1, axis=1) / np.linalg.norm(x1 - x0, axis=1)))


def test_a_parameter_without_a_mu_kernel_is_learned(auto_model, pendulum):
    m = auto_model
    assert m.mu_kernel is None and m.state_kernel is None and m.update is None  # the caller's settings stay
    assert m.n_mu_ == 1 and m.kernel_.mu == m.choice_["mu_kernel"] is not None
    assert m.choice_["update"] in ("symplectic_euler", "midpoint") and m.update_ == m.choice_["update"]
    # learned: the parameter dependence matters (mu 0.6 vs 1.0 moves the states differently) and is reproduced
    assert _step_error(m, pendulum, 7) < 2e-2
    x = np.array([[1.0, 0.5]])
    far_apart = np.abs(m.step(x, mu=0.65, dt=0.1) - m.step(x, mu=0.95, dt=0.1)).max()
    exact = np.abs(pendulum.flow(x, 0.65, 0.1) - pendulum.flow(x, 0.95, 0.1)).max()
    assert far_apart == pytest.approx(exact, rel=0.1)


def test_the_default_step_is_symplectic(auto_model):
    x = np.array([[0.4, -0.3], [-1.0, 1.2]])
    jac = auto_model.step_jacobian(x, mu=np.array([[0.7], [0.9]]), dt=0.1)
    assert np.max(symplecticity_defect(jac)) < 1e-9


def test_the_state_normalisation_is_the_documented_symplectic_scaling(auto_model, param_data):
    x0, x1, _, _ = param_data
    chosen = lower_state_kernel(auto_model.choice_["state_kernel"])  # a symmetry the search found may wrap it
    x = np.vstack([x0, x1])
    # independent oracle: a = sqrt(std(p) / std(q)) over the states trained on (all but the held-out tenth)
    assert chosen.scaling[0] == pytest.approx(np.sqrt(x[:, 1].std() / x[:, 0].std()), rel=0.05)
    assert chosen.radial == auto_model.kernel_.state
    data = FlowMapData(x0, x1, None, np.full(len(x0), 0.1))
    a = pair_factors(data)
    assert a[0] == pytest.approx(np.sqrt(x[:, 1].std() / x[:, 0].std()), rel=1e-12)


def test_physical_units_learn_as_well_as_units_of_order_one(pendulum, param_data):
    """States in small units (x 1e-4, a conformal scaling: the flow stays Hamiltonian) and a shifted parameter: the
    defaults learn as well as in units of order one, where a fixed default kernel would not fit the data's scale."""
    x0, x1, mu, _ = param_data
    s = 1e-4
    ref = SymplecticKernelPredictor(max_centers=120, search=SMALL).fit(x0, x1, mu=mu, dt=0.1)
    small = SymplecticKernelPredictor(max_centers=120, search=SMALL).fit(x0 * s, x1 * s, mu=mu, dt=0.1)
    e_ref, e_small = _step_error(ref, pendulum, 11), _step_error(small, pendulum, 11, scale=s)
    assert e_small < 2e-2 and e_small < 3 * e_ref
    # the shapes follow the units: the chosen state shape of the small-unit model is 1/s times larger
    ratio = small.kernel_.state.eps / ref.kernel_.state.eps
    assert 0.2 / s < ratio < 5 / s


def test_several_steps_without_a_dt_kernel_choose_one(pendulum):
    x0, x1, mu, dt = _pendulum_samples(
        pendulum, 400, 3, dt=np.random.default_rng(3).choice([0.05, 0.1], 400), mu_range=(0.8, 0.8)
    )
    m = SymplecticKernelPredictor(max_centers=100, search=SMALL).fit(x0, x1, dt=dt)
    assert m.dt_fixed_ is None and m.kernel_.dt is not None and m.kernel_.dt == m.choice_["dt_kernel"]
    assert "mu_kernel" not in m.choice_ and m.n_mu_ == 0
    x = np.array([[0.5, 0.5]])
    for step in (0.05, 0.1):
        assert np.abs(m.step(x, dt=step) - pendulum.flow(x, 0.8, step)).max() < 0.02 * step


def test_given_kernels_are_kept_and_no_search_runs(param_data):
    x0, x1, mu, _ = param_data
    explicit = SymplecticKernelPredictor(IMQ(0.3), mu_kernel=IMQ(1.0), max_centers=60, update="symplectic_euler")
    default_update = SymplecticKernelPredictor(IMQ(0.3), mu_kernel=IMQ(1.0), max_centers=60)
    explicit.fit(x0, x1, mu=mu, dt=0.1)
    default_update.fit(x0, x1, mu=mu, dt=0.1)
    assert default_update.search_ is None and default_update.choice_ == {"update": "symplectic_euler"}
    assert explicit.choice_ == {} and explicit.search_ is None
    # the same code path on the same arrays: the same model
    np.testing.assert_array_equal(explicit.surrogate_.coef, default_update.surrogate_.coef)


def test_only_the_open_factors_are_searched(param_data):
    x0, x1, mu, _ = param_data
    m = SymplecticKernelPredictor(IMQ(0.3), max_centers=60, update="midpoint", search=SMALL).fit(x0, x1, mu=mu, dt=0.1)
    assert set(m.choice_) == {"mu_kernel"} and m.kernel_.state == IMQ(0.3) and m.update_ == "midpoint"
    assert {row["state"]["eps"] for row in m.search_.table if row["stage"] == 1} == {0.3}
    assert all(row["kernels"].startswith("IMQ(0.3) x") for row in m.search_.table if row["stage"] == 2)
    assert {row["update"] for row in m.search_.table} == {"midpoint"}


def test_the_search_scores_on_the_callers_held_out_samples_when_given(param_data):
    """choose(validation=...): the candidates are scored on the caller's samples (every stage-1 E_val is the
    greedy's residual on them, recomputed by hand for the winner) and fitted to a subsample of the data."""
    x0, x1, mu, _ = param_data
    data = FlowMapData(x0[:400], x1[:400], mu[:400], np.full(400, 0.1))
    held = FlowMapData(x0[400:], x1[400:], mu[400:], np.full(100, 0.1))
    est = SymplecticKernelPredictor(IMQ(0.3), max_centers=60, update="midpoint")
    search = KernelSearch(m_star=30, max_samples=300, refine_sweeps=0, structure=False)
    out = search.choose(est, data, {"state": False, "mu": True, "dt": False, "update": False}, validation=held)
    assert (out.n_train, out.n_validation) == (300, 100)
    stage1 = [r for r in out.table if r["stage"] == 1]
    best = min(stage1, key=lambda r: r["E_val"])
    train = data.subset(np.sort(np.random.default_rng(search.seed).permutation(400)[:300]))
    by_hand = clone(est).set_params(mu_kernel=IMQ(best["mu"]["eps"]), max_centers=30, trainer__tol=0.0)
    by_hand.fit(train.x0, train.x1, mu=train.mu, dt=train.dt, validation=(held.x0, held.x1, held.mu, held.dt))
    assert by_hand.history_.val_max_residual[-1] == best["E_val"]  # the same fit on the same arrays
    assert out.score == min(r["score"] for r in out.table if r["stage"] == 2)  # stage 2 on the same samples


def test_the_search_logs_its_choice(param_data, caplog):
    x0, x1, mu, _ = param_data
    with caplog.at_level(logging.INFO, logger="sympredict.estimators"):
        m = SymplecticKernelPredictor(max_centers=60, search=SMALL).fit(x0, x1, mu=mu, dt=0.1)
    text = caplog.text
    assert "kernel search: chose" in text and repr(m.choice_["mu_kernel"]) in text
    assert "held-out samples" in text  # the diagnostics
    assert m.search_.n_train + m.search_.n_validation <= SMALL.max_samples
    assert len([r for r in m.search_.table if r["stage"] == 1]) >= 2 * len(SMALL.shapes)
    stage2 = [r for r in m.search_.table if r["stage"] == 2]
    assert m.search_.m_final == 60 and len(stage2) >= 2 * len(SMALL.families)
    # the winner has the smallest one-step error (of the kernels' candidates, and of the structures that held)
    assert m.search_.score == min(r["score"] for r in m.search_.table if r["stage"] in (2, 3))


def test_diagnostics_report_the_fit_and_advise(param_data):
    x0, x1, mu, _ = param_data
    # without the structure stage: the pendulum's symmetry group makes 15 centres enough, no advice to give
    few = SymplecticKernelPredictor(
        max_centers=15, search=KernelSearch(m_star=15, max_samples=300, refine_sweeps=0, structure=False)
    )
    few.fit(x0, x1, mu=mu, dt=0.1)
    d = few.diagnostics_
    assert isinstance(d, FitDiagnostics)
    assert d.n_train + d.n_holdout == len(x0) and d.n_holdout == 50
    assert d.n_centers == 15 and not d.converged and d.stop_reason == "max_centers"
    assert np.isfinite(d.train_residual) and np.isfinite(d.holdout_residual) and 0 < d.holdout_step_error < 1
    assert any(a.startswith("more centres") for a in d.advice), d.advice
    assert "try: more centres" in d.summary()


def test_a_converged_fit_says_so(param_data):
    x0, x1, mu, _ = param_data
    m = SymplecticKernelPredictor(max_centers=400, trainer=ExactGreedy(tol=1e-2), search=SMALL).fit(
        x0, x1, mu=mu, dt=0.1
    )
    assert m.diagnostics_.converged and m.diagnostics_.stop_reason == "tol" and m.n_centers_ < 400


def test_files_keep_the_settings_and_the_choice(auto_model, tmp_path):
    path = tmp_path / "auto.h5"
    auto_model.save(path)
    back = SymplecticKernelPredictor.load(path)
    assert back.get_params(deep=False).keys() == auto_model.get_params(deep=False).keys()
    assert back.state_kernel is None and back.mu_kernel is None and back.update is None
    assert back.choice_ == auto_model.choice_ and back.update_ == auto_model.update_
    assert back.search == auto_model.search
    x = np.array([[0.3, 0.2], [-0.5, 1.0]])
    assert_same_predictions(back, auto_model, x, 5, mu=0.8, dt=0.1)  # to round-off: BLAS may round with alignment


def test_a_file_whose_choice_is_tampered_with_is_refused(auto_model, tmp_path):
    path = tmp_path / "auto.h5"
    auto_model.save(path)
    settings, arrays = read_container(path, MODEL_FORMAT)
    for bad, match in (
        (dict(settings, choice={"max_centers": 3}), "does not choose"),
        (
            dict(settings, choice={**settings["choice"], "mu_kernel": {"kernel": {"family": "imq", "eps": 9.0}}}),
            "disagrees with its kernel",
        ),
        (dict(settings, choice=[1]), "not a JSON object"),
    ):
        write_container(tmp_path / "bad.h5", MODEL_FORMAT, bad, arrays)
        with pytest.raises(ModelFileError, match=match):
            SymplecticKernelPredictor.load(tmp_path / "bad.h5")


def test_the_estimator_contract_holds(param_data):
    x0, x1, mu, _ = param_data
    m = SymplecticKernelPredictor(max_centers=40, search=SMALL)
    c = clone(m)
    assert c.get_params(deep=False) == m.get_params(deep=False) and c.search is not m.search
    assert m.fit(x0, x1, mu=mu, dt=0.1) is m
    assert not hasattr(c, "choice_") and m.get_params(deep=False)["state_kernel"] is None


@pytest.mark.parametrize(
    "bad, match",
    [
        (dict(families=("rbf",)), "families"),
        (dict(shapes=()), "shapes"),
        (dict(parameter_shapes=(1.0, -2.0)), "parameter_shapes"),
        (dict(updates=("leapfrog",)), "updates"),
        (dict(m_star=0), "m_star"),
        (dict(final_centers=0), "final_centers"),
        (dict(max_samples=5), "max_samples"),
        (dict(validation_fraction=1.0), "validation_fraction"),
        (dict(halving="yes"), "halving"),
        (dict(rollout_finalists="yes"), "rollout_finalists"),
        (dict(final_size="yes"), "final_size"),
    ],
)
def test_bad_search_settings_are_named(bad, match, param_data):
    x0, x1, mu, _ = param_data
    with pytest.raises(ValueError, match=match):
        SymplecticKernelPredictor(search=KernelSearch(**bad)).fit(x0, x1, mu=mu, dt=0.1)
    with pytest.raises(ValueError, match="search must be a KernelSearch"):
        SymplecticKernelPredictor(search="auto").fit(x0, x1, mu=mu, dt=0.1)


def test_too_few_samples_for_a_search_name_the_fix(param_data):
    x0, x1, _, _ = param_data
    with pytest.raises(ValueError, match="pass the kernels"):
        SymplecticKernelPredictor().fit(x0[:6], x1[:6], dt=0.1)


def test_the_second_stage_scores_the_one_step_error_on_held_out_samples(param_data):
    """The stage-2 score is the mean of |Phi(x0) - x1| / |x1 - x0| over the held-out samples, the norms taken in the
    held-out states' normalised coordinates (a q, p / a), a = sqrt(std p / std q) (independent recomputation with the
    same fit), and a Newton failure scores inf instead of stopping the search."""
    from sympredict.estimators.search import one_step_score as _one_step_score
    from sympredict.symplectic.solvers import NewtonSolver

    x0, x1, mu, _ = param_data
    data = FlowMapData(x0, x1, mu, np.full(len(x0), 0.1))
    train, val = data.subset(np.arange(400)), data.subset(np.arange(400, 500))
    params = {"state_kernel": IMQ(0.3), "mu_kernel": IMQ(1.0), "dt_kernel": None, "update": "midpoint"}
    base = SymplecticKernelPredictor()
    value, n, _, err = _one_step_score(base, params, 50, train, val)
    ref = clone(base).set_params(**params, max_centers=50).fit(train.x0, train.x1, mu=train.mu, dt=0.1)
    pred = ref.step(val.x0, mu=val.mu)
    both = np.concatenate([val.x0, val.x1])
    a = np.sqrt(both[:, 1].std() / both[:, 0].std())
    w = np.array([a, 1 / a])
    expected = np.mean(np.linalg.norm((pred - val.x1) * w, axis=1) / np.linalg.norm((val.x1 - val.x0) * w, axis=1))
    assert err is None and n == 50 and value == pytest.approx(expected, rel=1e-12)
    strict = SymplecticKernelPredictor(solver=NewtonSolver(max_iter=1, backend="numpy"))
    value, _, _, err = _one_step_score(strict, params, 50, train, val)
    assert value == np.inf and "NewtonConvergenceError" in err


def test_the_fit_logs_and_records_the_search_share(param_data, caplog):
    """The fit's log states how much of it the search took; ``search_.share`` is that ratio."""
    x0, x1, mu, _ = param_data
    with caplog.at_level(logging.INFO, logger="sympredict.estimators"):
        m = SymplecticKernelPredictor(max_centers=60, search=SMALL).fit(x0, x1, mu=mu, dt=0.1)
    s = m.search_
    assert s.fit_seconds is not None and 0 < s.seconds < s.fit_seconds and s.share == s.seconds / s.fit_seconds
    assert s.cpu_seconds is not None and s.cpu_seconds > 0
    line = [r.getMessage() for r in caplog.records if "the kernel search took" in r.getMessage()]
    assert len(line) == 1 and f"({s.share:.0%})" in line[0] and f"{s.fit_seconds:.1f} s" in line[0]


HALVED = KernelSearch(m_star=100, final_centers=100, max_samples=400, refine_sweeps=1, structure=False, halving=True)


@pytest.fixture(scope="module")
def halved_pair(param_data):
    """The same search with and without successive halving (rungs at 25 and 50 centres, stage-2 rung at 25)."""
    x0, x1, mu, _ = param_data
    out = {}
    for halving in (True, False):
        est = SymplecticKernelPredictor(max_centers=100, search=clone(HALVED).set_params(halving=halving))
        out[halving] = est.fit(x0, x1, mu=mu, dt=0.1)
    return out


def test_halving_fits_fewer_candidates_to_full_size_and_keeps_the_choice(halved_pair):
    """On the pendulum, halving chooses what the full search chooses, with fewer fits at full size."""
    from sympredict.estimators.auto import RUNG_MARGIN

    halved, full = halved_pair[True].search_, halved_pair[False].search_
    assert halved_pair[True].choice_ == halved_pair[False].choice_
    assert halved.score == pytest.approx(full.score, rel=1e-9)

    def full_size(table):
        return sum(1 for r in table if "rung" not in r and not r.get("cut"))

    assert full_size(halved.table) < full_size(full.table)
    assert not any("rung" in r or "rung_score" in r for r in full.table)  # the full search has no rungs
    stage1 = [r for r in halved.table if r["stage"] == 1]
    assert {r["rung"] for r in stage1 if "rung" in r} == {25, 50}
    stage2 = [r for r in halved.table if r["stage"] == 2]
    rung_scores = [r["rung_score"] for r in stage2 if np.isfinite(r["rung_score"])]
    for r in stage2:  # every candidate was scored at the rung first; a cut one lost there by more than the margin
        assert r["rung_centers"] <= 25
        if r.get("cut"):
            assert r["score"] == np.inf and r["rung_score"] > RUNG_MARGIN * min(rung_scores)
    assert halved.score == min(r["score"] for r in halved.table if r["stage"] == 2)


def test_halving_is_deterministic(param_data, halved_pair):
    x0, x1, mu, _ = param_data
    again = SymplecticKernelPredictor(max_centers=100, search=clone(HALVED)).fit(x0, x1, mu=mu, dt=0.1)
    first = halved_pair[True].search_.table
    assert [(r["stage"], r["kernels"], r.get("rung"), r.get("cut")) for r in again.search_.table] == [
        (r["stage"], r["kernels"], r.get("rung"), r.get("cut")) for r in first
    ]
    assert again.choice_ == halved_pair[True].choice_
    # the same code path on the same arrays in one process: the same scores, bit for bit
    assert [r.get("score", r.get("E_val")) for r in again.search_.table] == [
        r.get("score", r.get("E_val")) for r in first
    ]


def test_the_second_stage_cuts_candidates_beyond_the_margin_at_the_rung(param_data, monkeypatch):
    """With a margin of 1, every stage-2 candidate whose rung error is above the smallest so far is cut (score inf,
    never chosen); the candidates fitted to full size passed their rung, and the winner is the best of them."""
    import sympredict.estimators.auto as auto

    monkeypatch.setattr(auto, "RUNG_MARGIN", 1.0)
    x0, x1, mu, _ = param_data
    m = SymplecticKernelPredictor(max_centers=100, search=clone(HALVED)).fit(x0, x1, mu=mu, dt=0.1)
    stage2 = [r for r in m.search_.table if r["stage"] == 2]
    cut = [r for r in stage2 if r.get("cut")]
    assert cut and all(r["score"] == np.inf and r["n_centers"] <= 25 for r in cut)
    best_rung = min(r["rung_score"] for r in stage2)
    assert all(r["rung_score"] > best_rung for r in cut)
    fitted = [r for r in stage2 if not r.get("cut")]
    assert fitted and all(np.isfinite(r["score"]) for r in fitted)
    assert m.search_.score == min(r["score"] for r in fitted)


def _pendulum_trajectories(pendulum, n, steps, seed):
    rng = np.random.default_rng(seed)
    mu = rng.uniform(0.6, 1.0, n)
    x0 = np.column_stack([rng.uniform(-1.5, 1.5, n), rng.uniform(-1.0, 1.0, n)])
    return TrajectoryData(pendulum.trajectory(x0, mu, dt=0.1, n_steps=steps), mu=mu, dt=0.1)


ROLLED = KernelSearch(
    families=("imq",), m_star=20, max_samples=200, refine_sweeps=0, structure=False, rollout_finalists=True
)


@pytest.fixture()
def scripted_scores(monkeypatch):
    """The candidates' scores scripted (the fits are real): midpoint wins one step (1e-3 against 2e-3) and loses the
    held-out rollouts (1.0 against 0.1); the held-out trajectories each call received are recorded."""
    import sympredict.estimators.auto as auto

    real, seen = auto.final_size_score, []

    def scripted(estimator, params, m_final, train, val, largest=500, rollouts=None):
        _, n, secs, err, _, ro_s = real(estimator, params, m_final, train, val, largest, rollouts)
        seen.append(rollouts)
        midpoint = params["update"] == "midpoint"
        return (
            (1e-3 if midpoint else 2e-3),
            n,
            secs,
            err,
            None if rollouts is None else (1.0 if midpoint else 0.1),
            ro_s,
        )

    monkeypatch.setattr(auto, "final_size_score", scripted)
    return seen


def test_finalists_are_decided_by_held_out_rollouts_where_one_step_scores_disagree(pendulum, scripted_scores):
    """From trajectories, the search rolls the held-out trajectories out with every full-size candidate and the
    finalist with the smallest rollout error wins, although another wins one step; the log and ``search_`` say
    which score decided.  Without rollout scoring, or from samples, the one-step error decides."""
    traj = _pendulum_trajectories(pendulum, 100, 6, 0)
    m = SymplecticKernelPredictor(max_centers=40, search=ROLLED).fit(traj)
    s = m.search_
    assert m.choice_["update"] == "symplectic_euler"
    assert s.decided_by == "held-out rollouts" and s.rollout_score == 0.1 and s.score == 2e-3
    assert sorted((f["update"], f["score"], f["rollout"]) for f in s.finalists) == [
        ("midpoint", 1e-3, 1.0),
        ("symplectic_euler", 2e-3, 0.1),
    ]
    assert "decided by held-out rollouts" in s.summary()
    assert all(r["rollout"] in (0.1, 1.0) for r in s.table if r["stage"] == 2)
    assert 0 < s.rollout_seconds == sum(r["rollout_s"] for r in s.table if "rollout_s" in r) < s.seconds
    # the rollouts are whole held-out trajectories the fit does not see: 5 of 100, all their 6 steps
    states, mu, dt = scripted_scores[0]
    assert states.shape == (5, 7, 2) and mu.shape == (5, 1) and dt == 0.1
    assert len({tuple(x) for x in states[:, 0]} & {tuple(x) for x in traj.states[:, 0]}) == 5
    assert KernelSearch().rollout_finalists is False  # the default (its Notes: it measured worse on the pendulum)
    off = SymplecticKernelPredictor(max_centers=40, search=clone(ROLLED).set_params(rollout_finalists=False))
    off.fit(traj)
    assert off.choice_["update"] == "midpoint" and off.search_.decided_by == "one-step error"
    assert off.search_.rollout_score is None and off.search_.finalists == []
    x0, x1, mu = traj.states[:, :-1].reshape(-1, 2), traj.states[:, 1:].reshape(-1, 2), np.repeat(traj.mu, 6, axis=0)
    samples = SymplecticKernelPredictor(max_centers=40, search=ROLLED).fit(x0, x1, mu=mu, dt=0.1)
    assert samples.choice_["update"] == "midpoint" and samples.search_.decided_by == "one-step error"
    # two held-out trajectories (of 40) are too few to rank models by: the one-step error decides
    few = SymplecticKernelPredictor(max_centers=40, search=ROLLED).fit(
        TrajectoryData(traj.states[:40], mu=traj.mu[:40], dt=0.1)
    )
    assert few.choice_["update"] == "midpoint" and few.search_.decided_by == "one-step error"
    assert all("rollout" not in r for r in few.search_.table)


def test_the_rollout_score_is_the_mean_worst_relative_error_of_the_held_out_rollouts(pendulum):
    """``final_size_score``'s rollout score against an independent recomputation with the same fit: the mean over
    the trajectories of ``max_k |x_k - X_k| / rms_k |X_k|``, the states weighted as the validation samples'
    normalisation (a q, p / a), a = sqrt(std p / std q); a failed Newton solve scores ``inf``."""
    from sympredict.estimators.search import final_size_score
    from sympredict.symplectic.solvers import NewtonSolver

    traj = _pendulum_trajectories(pendulum, 12, 8, 1)
    data = FlowMapData(
        traj.states[:10, :-1].reshape(-1, 2),
        traj.states[:10, 1:].reshape(-1, 2),
        np.repeat(traj.mu[:10], 8, axis=0),
        np.full(80, 0.1),
    )
    states, mu = traj.states[10:], traj.mu[10:]
    params = {"state_kernel": IMQ(0.3), "mu_kernel": IMQ(1.0), "dt_kernel": None, "update": "midpoint"}
    base = SymplecticKernelPredictor()
    value, n, secs, err, rollout, rollout_s = final_size_score(base, params, 30, data, data, rollouts=(states, mu, 0.1))
    ref = clone(base).set_params(**params, max_centers=30).fit(data.x0, data.x1, mu=data.mu, dt=0.1)
    with warnings.catch_warnings():  # the held-out states may leave the training box: the score measures it
        warnings.simplefilter("ignore")
        pred = ref.rollout(states[:, 0], 8, mu=mu)
    both = np.concatenate([data.x0, data.x1])
    a = np.sqrt(both[:, 1].std() / both[:, 0].std())
    w = np.array([a, 1 / a])
    worst = np.linalg.norm((pred - states) * w, axis=2).max(axis=1)
    expected = np.mean(worst / np.sqrt(np.mean(np.sum((states * w) ** 2, axis=2), axis=1)))
    assert err is None and n == 30 and rollout == pytest.approx(expected, rel=1e-12) and rollout > 0
    assert 0 < rollout_s < secs
    assert final_size_score(base, params, 30, data, data)[4] is None  # no trajectories, no rollout score
    strict = SymplecticKernelPredictor(solver=NewtonSolver(max_iter=1, backend="numpy"))
    assert final_size_score(strict, params, 30, data, data, rollouts=(states, mu, 0.1))[4] == np.inf


def test_the_choice_is_refitted_at_the_final_size_and_narrowed_where_it_stops_early(param_data, monkeypatch):
    """With ``max_centers`` above ``final_centers``, the chosen settings are fitted to ``max_centers`` centres; a
    fit that stops early (scripted: 10 of 60 centres) is followed by the same settings with every open shape
    doubled, then the best candidate of the other kind (with or without a symmetry), and the smallest one-step error
    at the final size wins.  Without the stage the search ends at its second stage's choice."""
    import sympredict.estimators.auto as auto

    real, calls = auto.one_step_score, []

    def scripted(estimator, params, m_final, train, val, largest=500):
        value, n, secs, err = real(estimator, params, m_final, train, val, largest)
        calls.append((params, m_final))
        first = len(calls) == 1
        return (1e-2 if first else 1e-3), (10 if first else m_final), secs, err

    monkeypatch.setattr(auto, "one_step_score", scripted)
    x0, x1, mu, _ = param_data
    search = KernelSearch(families=("imq",), m_star=20, final_centers=30, max_samples=300, refine_sweeps=0)
    off = SymplecticKernelPredictor(max_centers=60, search=clone(search).set_params(final_size=False))
    off.fit(x0, x1, mu=mu, dt=0.1)
    assert not calls and off.search_.final_size == 0 and not [r for r in off.search_.table if r["stage"] == 4]
    m = SymplecticKernelPredictor(max_centers=60, search=search).fit(x0, x1, mu=mu, dt=0.1)
    # the structure stage ran (the pendulum's sign flips hold): the best candidate of the other kind (with or without
    # a symmetry) is fitted to the final size after the chosen one and its narrowing, and loses the tie
    assert [c[1] for c in calls] == [60, 60, 60] and m.search_.final_size == 60
    symmetric = ["Symmetric" in repr(c[0]["state_kernel"]) for c in calls]
    assert symmetric[0] == symmetric[1] != symmetric[2]
    first, second = calls[0][0], calls[1][0]
    assert repr(first["state_kernel"]) == repr(off.choice_["state_kernel"])  # the second stage's choice, refitted
    inner = lower_state_kernel(first["state_kernel"]).radial, lower_state_kernel(second["state_kernel"]).radial
    assert inner[1].eps == pytest.approx(2 * inner[0].eps, rel=1e-15)
    assert second["mu_kernel"].eps == pytest.approx(2 * first["mu_kernel"].eps, rel=1e-15)
    assert repr(m.choice_["state_kernel"]) == repr(second["state_kernel"]) and m.search_.score == 1e-3
    assert [r["n_centers"] for r in m.search_.table if r["stage"] == 4] == [10, 60, 60]
    assert "refitted with 60 centres" in m.search_.summary()
    # no stage where the second stage already ran at the final size
    calls.clear()
    same = SymplecticKernelPredictor(max_centers=30, search=search).fit(x0, x1, mu=mu, dt=0.1)
    assert not calls and same.search_.final_size == 0


def _scripted_final_size(monkeypatch, results):
    """``_at_final_size`` run on a chosen candidate whose fits at 60 centres give the scripted ``results``
    ``(score, standard error, centres)`` in order; ``(params, score, state shapes fitted)``."""
    import sympredict.estimators.auto as auto
    from sympredict.estimators.search import HeldOutScore

    fitted = []

    def scripted(estimator, params, m_final, train, val, largest=500):
        value, se, n = results[len(fitted)]
        fitted.append(lower_state_kernel(params["state_kernel"]).radial.eps)
        return HeldOutScore(value, se), n, 0.0, None

    monkeypatch.setattr(auto, "one_step_score", scripted)
    rng = np.random.default_rng(0)
    train = FlowMapData(rng.normal(size=(40, 2)), rng.normal(size=(40, 2)), np.zeros((40, 0)), np.full(40, 0.1))
    chosen = {"state_kernel": IMQ(0.5), "mu_kernel": None, "dt_kernel": None, "update": "midpoint"}
    table, opened = [], {"state": True, "mu": False, "dt": False, "update": True}
    params, score = auto._at_final_size(None, chosen, 1.0, 60, train, train, table, opened)
    assert [r["n_centers"] for r in table] == [r[2] for r in results[: len(fitted)]]
    return params, score, fitted


def test_the_final_size_stage_narrows_only_where_narrowing_measures_better(monkeypatch):
    """A fit that stops early is narrowed (its shape doubled) only while the narrowed one's held-out error is below
    the flatter one's beyond the noise (one standard error of the narrowed one's): a narrowed shape within it, or
    worse, does not replace the flat one and ends the doubling; a clearly better one does, and the doubling goes on."""
    # the narrowed shape is better, but within its standard error: the flat one stays, no third fit
    params, score, fitted = _scripted_final_size(
        monkeypatch, [(1.0e-3, 2e-4, 10), (0.9e-3, 1e-4, 30)] + [(1e-9, 0, 60)]
    )
    assert fitted == [0.5, 1.0] and params["state_kernel"].eps == 0.5 and score == 1.0e-3
    # worse: likewise
    params, score, fitted = _scripted_final_size(monkeypatch, [(1.0e-3, 1e-5, 10), (2e-3, 1e-5, 60), (1e-9, 0, 60)])
    assert fitted == [0.5, 1.0] and params["state_kernel"].eps == 0.5 and score == 1.0e-3
    # clearly better twice, then within the noise: the second narrowing is chosen
    params, score, fitted = _scripted_final_size(
        monkeypatch, [(1.0e-3, 1e-5, 10), (1e-4, 1e-6, 20), (5e-5, 1e-6, 40), (4.95e-5, 1e-6, 60)]
    )
    assert fitted == [0.5, 1.0, 2.0, 4.0] and params["state_kernel"].eps == 2.0 and score == 5e-5


def test_the_final_size_stage_does_not_narrow_a_nearly_full_fit(monkeypatch):
    """A fit that reaches ``NEAR_FULL`` of its centres is not narrowed (the shape that suits 90 % of the centres is
    within 11 % of the full fit's, far below a doubling); one that stops below it is."""
    from sympredict.estimators.auto import NEAR_FULL

    near = int(np.ceil(NEAR_FULL * 60))
    params, score, fitted = _scripted_final_size(monkeypatch, [(1e-3, 1e-5, near), (1e-9, 0, 60)])
    assert fitted == [0.5] and params["state_kernel"].eps == 0.5
    params, score, fitted = _scripted_final_size(monkeypatch, [(1e-3, 1e-5, near - 1), (1e-5, 0, 60)])
    assert fitted == [0.5, 1.0] and params["state_kernel"].eps == 1.0
