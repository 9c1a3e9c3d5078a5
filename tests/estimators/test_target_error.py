"""Accuracy on demand (target_error), the best held-out prefix, and diagnostics that report against the target."""

import warnings

import numpy as np
import pytest

from sympredict import KernelSearch, SymplecticKernelPredictor
from sympredict.data import FlowMapData
from sympredict.exceptions import AccuracyWarning
from sympredict.interpolation.greedy.loop import checkpoint_schedule
from sympredict.interpolation.greedy.trainers import ActiveSetGreedy, ExactGreedy
from sympredict.kernels import IMQ
from sympredict.systems.pendulum import Pendulum


def _data(n, seed, steps=20, dt=0.1):
    rng = np.random.default_rng(seed)
    mu = rng.uniform(0.7, 0.8, n)
    x0 = np.column_stack([rng.uniform(-1.5, 1.5, n), rng.uniform(-1.0, 1.0, n)])
    traj = Pendulum().trajectory(x0, mu, dt=dt, n_steps=steps)
    return FlowMapData(
        traj[:, :-1].reshape(-1, 2), traj[:, 1:].reshape(-1, 2), np.repeat(mu, steps), np.full(n * steps, dt)
    )


def _median_step_error(model, data):
    pred = model.step(data.x0, mu=data.mu, dt=data.dt)
    return float(np.median(np.linalg.norm(pred - data.x1, axis=1) / np.linalg.norm(data.x1 - data.x0, axis=1)))


@pytest.fixture(scope="module")
def data():
    return _data(40, 0), _data(40, 1), _data(20, 2)  # train, validation, fresh


def test_checkpoint_schedule():
    s = checkpoint_schedule(4000)
    assert s[0] == 16 and s[-1] == 4000 and len(s) <= 26 and all(b > a for a, b in zip(s, s[1:]))
    assert checkpoint_schedule(10) == [10]


@pytest.mark.parametrize("target", [1e-2, 1e-3])
def test_target_gives_the_smallest_model_that_meets_it(data, target):
    train, val, fresh = data
    kw = dict(mu_kernel=IMQ(2.0), max_centers=400)
    model = SymplecticKernelPredictor(IMQ(0.5), trainer=ExactGreedy(target_error=target), **kw).fit(
        train, validation=val
    )
    d = model.diagnostics_
    assert d.target_error == target and d.target_met and d.holdout_step_error <= target
    assert model.history_.stop_reason == "target" and model.n_centers_ < 400
    # on fresh samples the target holds within 1.5x
    assert _median_step_error(model, fresh) <= 1.5 * target
    # smallest: one centre fewer misses it on the held-out samples (the bisection's crossing)
    assert model.prefix_errors_[model.n_centers_] <= target
    assert model.prefix_errors_.get(model.n_centers_ - 1, np.inf) > target
    # the same as growing the full model and cutting it: the greedy's prefix
    full = SymplecticKernelPredictor(IMQ(0.5), **kw).fit(train, validation=val)
    small = full.truncated(model.n_centers_)
    np.testing.assert_allclose(model.surrogate_.coef, small.surrogate_.coef, rtol=1e-8, atol=1e-12)
    assert "target 1.00e-0" in d.summary() and "NOT" not in d.summary() and "met" in d.summary() and not d.advice


def test_unreachable_target_warns_once_naming_the_limit_and_keeps_the_best(data):
    train, val, _ = data
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        model = SymplecticKernelPredictor(
            IMQ(0.5), mu_kernel=IMQ(2.0), max_centers=30, trainer=ExactGreedy(target_error=1e-12)
        ).fit(train, validation=val)
    acc = [w for w in caught if issubclass(w.category, AccuracyWarning)]
    assert len(acc) == 1 and "max_centers=30" in str(acc[0].message) and "not met" in str(acc[0].message)
    d = model.diagnostics_
    assert d.target_met is False and "NOT met" in d.summary()
    assert model.n_centers_ == min(model.prefix_errors_, key=lambda k: (model.prefix_errors_[k], k))


def test_target_without_validation_holds_samples_out(data):
    train, _, _ = data
    model = SymplecticKernelPredictor(
        IMQ(0.5), mu_kernel=IMQ(2.0), max_centers=300, trainer=ExactGreedy(target_error=1e-3)
    ).fit(train)
    assert model.diagnostics_.n_holdout == len(train) // 10 and model.diagnostics_.target_met


def test_best_prefix_is_kept(data):
    """Growing never returns a worse model than one it passed (held-out one-step error at the checkpoints)."""
    train, val, _ = data
    search = KernelSearch(m_star=30, max_samples=300, refine_sweeps=0)  # the fit chooses its parameter kernel
    model = SymplecticKernelPredictor(IMQ(0.5), max_centers=200, search=search).fit(train, validation=val)
    errs = model.prefix_errors_
    assert model.n_centers_ in errs and errs[model.n_centers_] == min(errs.values())
    assert max(errs) >= model.n_centers_
    # every setting and validation given, no target (the kernel search's candidates): no prefix scoring
    plain = SymplecticKernelPredictor(IMQ(0.5), mu_kernel=IMQ(2.0), max_centers=50).fit(train, validation=val)
    assert plain.prefix_errors_ is None and plain.n_centers_ == 50


@pytest.mark.parametrize("bad", [0.0, -1e-3, float("nan"), "1e-3", True])
def test_target_is_checked(data, bad):
    with pytest.raises(ValueError, match="target_error"):
        SymplecticKernelPredictor(IMQ(0.5), mu_kernel=IMQ(2.0), trainer=ExactGreedy(target_error=bad)).fit(data[0])


def test_readme_like_fit_summary_reports_held_out_error_without_not_converged():
    rng = np.random.default_rng(0)
    mu = rng.uniform(0.7, 0.8, size=40)
    x0 = np.column_stack([rng.uniform(-1.5, 1.5, 40), rng.uniform(-1.0, 1.0, 40)])
    from sympredict import TrajectoryData

    states = Pendulum().trajectory(x0, mu, dt=0.1, n_steps=50)
    model = SymplecticKernelPredictor(max_centers=300).fit(TrajectoryData(states, mu=mu, dt=0.1))
    text = model.diagnostics_.summary()
    assert "not converged" not in text and "held-out samples" in text and "error estimate" in text
    assert not model.diagnostics_.advice


def test_cli_train_target_error_and_predict_error(tmp_path, capsys, data):
    from sympredict import TrajectoryData
    from sympredict.cli import main
    from sympredict.io.trajectories import write_trajectories

    rng = np.random.default_rng(3)
    x0 = np.column_stack([rng.uniform(-1.5, 1.5, 30), rng.uniform(-1.0, 1.0, 30)])
    states = Pendulum().trajectory(x0, 0.75, dt=0.1, n_steps=20)
    write_trajectories(TrajectoryData(states, dt=0.1), tmp_path / "t.npz")
    model_path = str(tmp_path / "m.h5")
    assert (
        main(
            [
                "train",
                str(tmp_path / "t.npz"),
                "--out",
                model_path,
                "--max-centers",
                "300",
                "--target-error",
                "1e-3",
                "--threads",
                "1",
            ]
        )
        == 0
    )
    out = capsys.readouterr().out
    assert "target error 1.00e-03: met" in out
    model = SymplecticKernelPredictor.load(model_path)
    assert model.target_error_ == 1e-3 and model.trainer.target_error == 1e-3 and model.n_centers_ < 300
    for suffix in (".npz", ".csv"):
        path = tmp_path / f"pred{suffix}"
        assert (
            main(["predict", model_path, "--x0", "0.5,0.1", "0.3,0.2", "--steps", "6", "--out", str(path), "--error"])
            == 0
        )
        traj, err = model.rollout(np.array([[0.5, 0.1], [0.3, 0.2]]), 6, dt=0.1, return_error=True)
        if suffix == ".npz":
            got = np.load(path)["error"]
        else:
            lines = path.read_text().splitlines()
            assert lines[0].split(",")[-1] == "error"
            got = np.array([float(r.split(",")[-1]) for r in lines[1:]]).reshape(2, 7)
        np.testing.assert_allclose(got, err, rtol=1e-6)
    assert main(["predict", model_path, "--x0", "0.5,0.1", "--steps", "6", "--error"]) == 0
    assert "estimated error" in capsys.readouterr().out


def test_every_strategy_takes_the_target_and_the_search_drops_it(data):
    train, val, _ = data
    model = SymplecticKernelPredictor(
        IMQ(0.5), mu_kernel=IMQ(2.0), max_centers=300, trainer=ActiveSetGreedy(target_error=1e-2)
    ).fit(train, validation=val)
    assert model.history_.stop_reason == "target" and model.diagnostics_.target_met
    from sympredict.estimators.search import without_target as _without_target

    est = SymplecticKernelPredictor(trainer=ExactGreedy(target_error=1e-3))
    assert _without_target(est).trainer.target_error is None


def test_the_blocked_greedy_meets_a_target_too(data):
    from sympredict.interpolation.greedy import BlockedGreedy

    train, val, fresh = data
    model = SymplecticKernelPredictor(
        IMQ(0.5), mu_kernel=IMQ(2.0), max_centers=400, trainer=BlockedGreedy(block_size=16, target_error=1e-3)
    ).fit(train, validation=val)
    d = model.diagnostics_
    assert d.target_met and model.history_.stop_reason == "target" and model.n_centers_ < 400
    assert model.prefix_errors_[model.n_centers_] <= 1e-3 < model.prefix_errors_.get(model.n_centers_ - 1, np.inf)
    assert _median_step_error(model, fresh) <= 1.5e-3


# ------------------------------------------------------------------ held-out trajectories score the prefixes' rollouts
def _trajectories(n, seed, steps=20, dt=0.1):
    from sympredict import TrajectoryData

    rng = np.random.default_rng(seed)
    mu = rng.uniform(0.7, 0.8, n)
    x0 = np.column_stack([rng.uniform(-1.5, 1.5, n), rng.uniform(-1.0, 1.0, n)])
    return TrajectoryData(Pendulum().trajectory(x0, mu, dt=dt, n_steps=steps), mu, dt=dt)


def _rollout_score(model, traj):
    """The documented score, from the fitted model's own rollouts: the mean over trajectories of
    ``max_k |x_k - X_k| / rms_k |X_k|``."""
    from sympredict.exceptions import ExtrapolationWarning

    states = traj.states
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ExtrapolationWarning)  # held-out parameters may lie beyond the training box
        pred = model.rollout(states[:, 0], states.shape[1] - 1, mu=traj.mu, dt=traj.dt)
    size = np.sqrt(np.mean(np.sum(states**2, axis=2), axis=1))
    return float(np.mean(np.linalg.norm(pred - states, axis=2).max(axis=1) / size))


def test_validation_trajectories_score_the_prefixes_by_their_rollouts():
    train, val = _trajectories(40, 0), _trajectories(10, 1)
    model = SymplecticKernelPredictor(IMQ(0.5), mu_kernel=IMQ(2.0), max_centers=200).fit(train, validation=val)
    roll = model.prefix_rollout_errors_
    assert set(roll) == set(model.prefix_errors_) and max(roll) == 200  # every checkpoint, the full run too
    # the kept prefix has the smallest rollout score (the smaller on a tie)
    assert model.n_centers_ == min(roll, key=lambda k: (roll[k], k))
    # the score is the documented one: the kept model's own rollouts over the validation trajectories
    np.testing.assert_allclose(roll[model.n_centers_], _rollout_score(model, val), rtol=1e-6)
    assert roll[model.n_centers_] < roll[16]
    # the same data as samples: every setting given, no target: the plain greedy, as before
    plain = SymplecticKernelPredictor(IMQ(0.5), mu_kernel=IMQ(2.0), max_centers=200).fit(
        train.pairs(), validation=val.pairs()
    )
    assert plain.prefix_errors_ is None and plain.prefix_rollout_errors_ is None and plain.n_centers_ == 200


def test_a_fit_from_trajectories_holds_whole_trajectories_out():
    """A fit that chooses a kernel, given trajectories and no validation, holds a twentieth of the trajectories out
    whole (besides the held-out samples of the others) and scores its prefixes also by their rollouts."""
    from sympredict.estimators.predictor import _hold_out_trajectories

    data = _trajectories(40, 0)
    search = KernelSearch(m_star=30, max_samples=300, refine_sweeps=0)
    model = SymplecticKernelPredictor(IMQ(0.5), max_centers=100, search=search).fit(data)
    d = model.diagnostics_
    assert (d.n_train, d.n_holdout) == (38 * 20 - 76, 76)  # 2 trajectories out, then a tenth of the samples
    roll = model.prefix_rollout_errors_
    assert roll is not None and model.n_centers_ == min(roll, key=lambda k: (roll[k], k))
    _, held = _hold_out_trajectories(data, search.seed)
    np.testing.assert_allclose(roll[model.n_centers_], _rollout_score(model, held), rtol=1e-6)
    # none of the held-out trajectories' states is a centre
    centres = model.surrogate_.centers_xi[:, :1]  # q0 of the centres' samples (the state kernel's coordinates)
    assert not np.isin(held.states[:, :-1, 0], centres).any()
    # the same data given as samples: samples held out, one-step scores only (as before)
    samples = SymplecticKernelPredictor(IMQ(0.5), max_centers=100, search=search).fit(data.pairs())
    assert samples.diagnostics_.n_holdout == len(data.pairs()) // 10 and samples.prefix_rollout_errors_ is None
    # too few trajectories to hold two out of twenty: samples only
    few = _trajectories(19, 0)
    assert _hold_out_trajectories(few, 0) == (few, None)
    assert [len(t) for t in _hold_out_trajectories(_trajectories(300, 0, steps=2), 0)] == [285, 15]


def test_the_rollout_rule_keeps_a_prefix_that_the_one_step_error_would_grow_past():
    """``keep``: with held-out trajectories the best rollout score wins over the best one-step score (more centres
    can fit the samples better and extrapolate worse); a target is still met by the smallest prefix."""
    from sympredict.estimators.predictor import _HeldOutSteps

    rule = _HeldOutSteps.__new__(_HeldOutSteps)
    rule.target, rule.rollouts = None, ("held-out trajectories",)
    rule.scores = {16: 1e-2, 32: 1e-3, 64: 1e-4}
    rule.rollout_scores = {16: 1e-1, 32: 1e-3, 64: 5e-3}
    assert rule.keep(64) == 32 and rule.keep(16) == 16
    rule.rollout_scores[64] = 1e-3
    assert rule.keep(64) == 32  # a tie: the smaller
    rule.target = 5e-3
    assert rule.keep(64) == 32  # the smallest meeting the target (one-step)
    rule.target, rule.rollouts = None, None
    assert rule.keep(64) == 64  # samples only: the best one-step score


def test_with_a_target_and_trajectories_the_smallest_prefix_meeting_it_is_kept():
    train, val = _trajectories(40, 0), _trajectories(10, 1)
    model = SymplecticKernelPredictor(
        IMQ(0.5), mu_kernel=IMQ(2.0), max_centers=400, trainer=ExactGreedy(target_error=1e-2)
    ).fit(train, validation=val)
    steps, roll = model.prefix_errors_, model.prefix_rollout_errors_
    assert model.history_.stop_reason == "target" and model.diagnostics_.target_met
    assert steps[model.n_centers_] <= 1e-2 < steps.get(model.n_centers_ - 1, np.inf)
    # the prefixes that missed the target were rolled out; those that met it are kept by their one-step score
    assert roll and all(steps[k] > 1e-2 for k in roll) and model.n_centers_ not in roll
