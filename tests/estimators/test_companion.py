"""The companion estimate: a model's rollout error from a larger companion fitted to the same data.

Oracles: the calibration recomputed from its definition on the model's held-out samples, the combination's closed
form, the estimate against the exact pendulum flow, and the refusals that name the fix.
"""

import warnings

import numpy as np
import pytest

from sympredict import SymplecticKernelPredictor
from sympredict.estimators.companion import CompanionEstimate, combined_error
from sympredict.systems.pendulum import Pendulum
from test_target_error import _data as _pendulum_data  # tests/estimators/: pendulum samples from trajectories


def _test_set(n=12, steps=100):
    rng = np.random.default_rng(7)
    x0 = np.column_stack([rng.uniform(-1.2, 1.2, n), rng.uniform(-0.8, 0.8, n)])
    mu = rng.uniform(0.71, 0.79, n)
    return x0, mu, Pendulum().trajectory(x0, mu, dt=0.1, n_steps=steps)


@pytest.fixture(scope="module")
def fitted():
    data = _pendulum_data(40, 0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = SymplecticKernelPredictor(max_centers=80).fit(data)
        estimate = CompanionEstimate.fit(model, data)
    return data, model, estimate


def test_calibration_follows_its_definition_on_the_held_out_samples(fitted):
    _, model, estimate = fitted
    assert estimate.companion.max_centers == 160
    held_out = model.model_.calibration_samples[0]
    assert model.model_.calibration_samples[1] == "held-out samples"
    own = model.step(held_out.x0, mu=held_out.mu, dt=held_out.dt)
    other = estimate.companion.step(held_out.x0, mu=held_out.mu, dt=held_out.dt)
    own_error = np.linalg.norm(own - held_out.x1, axis=1)
    scale = np.quantile(own_error / np.linalg.norm(other - own, axis=1), 0.9)
    ratio = np.median(np.linalg.norm(other - held_out.x1, axis=1)) / np.median(own_error)
    assert estimate.scale_ == pytest.approx(scale, rel=1e-12)
    assert estimate.accuracy_ratio_ == pytest.approx(ratio, rel=1e-12)
    assert "scale_=" in repr(estimate)


def test_combined_error_is_the_companion_difference_with_its_own_error_capped_by_the_model_estimate():
    difference = np.array([[0.0, 3.0, 3.0, 1.0]])
    companion = np.array([[0.0, 4.0, 4.0, 0.0]])
    own = np.array([[0.0, 10.0, 2.0, 5.0]])
    np.testing.assert_array_equal(combined_error(difference, companion, own), [[0.0, 5.0, 2.0, 1.0]])


def test_rollout_error_combines_the_two_rollouts_and_their_own_estimates(fitted):
    _, model, estimate = fitted
    x0, mu, _ = _test_set()
    states, error = estimate.rollout(x0, 30, mu=mu, dt=0.1)
    own_states, own = model.rollout(x0, 30, mu=mu, dt=0.1, return_error=True)
    other, other_error = estimate.companion.rollout(x0, 30, mu=mu, dt=0.1, return_error=True)
    assert np.array_equal(states, own_states)
    assert error.shape == (12, 31) and np.all(error[:, 0] == 0) and np.all(error <= own)
    expected = np.minimum(np.hypot(estimate.scale_ * np.linalg.norm(states - other, axis=2), other_error), own)
    np.testing.assert_allclose(error, expected, rtol=1e-12, atol=0)
    one_state, one_error = estimate.rollout(x0[0], 30, mu=mu[0], dt=0.1)
    assert one_state.shape == (31, 2) and one_error.shape == (31,) and one_error[0] == 0


def test_estimate_against_the_exact_flow_of_the_pendulum(fitted):
    """Effectivity (estimate over true error) within the goals at steps 1, 10 and 100, and the trajectories with
    the largest errors at step 100 ranked near the top."""
    from scipy.stats import spearmanr

    _, _, estimate = fitted
    x0, mu, exact = _test_set()
    states, error = estimate.rollout(x0, 100, mu=mu, dt=0.1)
    true = np.linalg.norm(states - exact, axis=2)
    for k in (1, 10, 100):
        eff = error[:, k] / true[:, k]
        assert 1 / 3 < np.median(eff) < 30 and np.mean(eff < 1 / 3) <= 0.25, (k, eff)
    assert spearmanr(error[:, 100], true[:, 100]).correlation > 0.6


def test_saved_models_rebuild_the_same_estimate(fitted, tmp_path):
    _, model, estimate = fitted
    model.save(tmp_path / "model.h5")
    estimate.companion.save(tmp_path / "companion.h5")
    loaded = (
        SymplecticKernelPredictor.load(tmp_path / "model.h5"),
        SymplecticKernelPredictor.load(tmp_path / "companion.h5"),
    )
    with pytest.raises(ValueError, match="scale="):  # a loaded model keeps no samples to calibrate on
        CompanionEstimate(*loaded).calibrate()
    with pytest.raises(ValueError, match="scale must be"):
        CompanionEstimate(*loaded, scale=-1.0).rollout(_test_set(n=1)[0], 2, mu=0.75, dt=0.1)
    rebuilt = CompanionEstimate(*loaded, scale=estimate.scale_)
    x0, mu, _ = _test_set(n=3)
    np.testing.assert_allclose(
        rebuilt.rollout(x0, 20, mu=mu, dt=0.1)[1], estimate.rollout(x0, 20, mu=mu, dt=0.1)[1], rtol=1e-9
    )


def test_refusals_name_the_fix(fitted):
    data, model, _ = fitted
    with pytest.raises(ValueError, match="budget must be"):
        CompanionEstimate.fit(model, data, budget=1.0)
    with pytest.raises(ValueError, match="cannot tell the model's error"):
        CompanionEstimate(model, model).calibrate()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        elsewhere = SymplecticKernelPredictor(max_centers=40).fit(_pendulum_data(40, 5))
        given = SymplecticKernelPredictor(
            model.choice_["state_kernel"],
            mu_kernel=model.choice_["mu_kernel"],
            update=model.choice_["update"],
            max_centers=40,
        ).fit(data)
    with pytest.raises(ValueError, match="fit both on the same data"):
        CompanionEstimate(model, elsewhere).calibrate()
    with pytest.raises(ValueError, match="no held-out samples"):
        CompanionEstimate(given, model).calibrate()
