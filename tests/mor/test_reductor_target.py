"""Accuracy on demand in the reductor: a target_error through the estimator part gives the smallest learned step that
meets it, and an unreachable one warns naming the limit."""

import warnings

import numpy as np
import pytest

from sympredict import SymplecticKernelPredictor
from sympredict.exceptions import AccuracyWarning
from sympredict.interpolation.greedy import ExactGreedy
from sympredict.kernels import IMQ
from sympredict.mor import DefaultEstimator, GalerkinSamples, SymplecticKernelReductor


def _fresh_step_error(reductor, fom, RB, dt, train) -> float:
    """Median relative one-step error ``|Phi(x0) - x1| / |x1 - x0|`` of the ROM's flow map (reduced coordinates) on
    samples at parameters it never saw (another seed's validation parameters of the Galerkin flow)."""
    fresh = SymplecticKernelReductor(fom, RB, dt, GalerkinSamples(train, n_validation=3, seed=7)).training_data()[1]
    x1 = reductor.flow_map_.step(fresh.x0, mu=fresh.mu, dt=dt)
    return float(np.median(np.linalg.norm(x1 - fresh.x1, axis=1) / np.linalg.norm(fresh.x1 - fresh.x0, axis=1)))


@pytest.fixture(scope="module")
def default_rom(wave):
    fom, train, RB, dt = wave
    red = SymplecticKernelReductor(fom, RB, dt, GalerkinSamples(train))
    red.reduce()
    return red


def test_a_loose_target_gives_a_smaller_rom_that_meets_it_on_fresh_samples(wave, default_rom):
    fom, train, RB, dt = wave
    target = 1e-2
    with warnings.catch_warnings():
        warnings.simplefilter("error", AccuracyWarning)  # met: no warning
        red = SymplecticKernelReductor(fom, RB, dt, GalerkinSamples(train), DefaultEstimator(target_error=target))
        red.reduce()
    fitted = red.predictor_
    assert fitted.target_error_ == target and fitted.diagnostics_.target_met
    assert fitted.history_.stop_reason == "target"
    # fewer centres than the default budget, and than the default reductor's model
    assert fitted.n_centers_ < DefaultEstimator().max_centers and fitted.n_centers_ < default_rom.predictor_.n_centers_
    # the smallest prefix meeting it: one centre fewer misses it
    assert fitted.prefix_errors_[fitted.n_centers_] <= target < fitted.prefix_errors_.get(fitted.n_centers_ - 1, np.inf)
    # on fresh samples, in the ROM's reduced coordinates, the target holds within 1.5x
    assert _fresh_step_error(red, fom, RB, dt, train) <= 1.5 * target
    # the default reductor fills its budget to breakdown and is more accurate (the target bought a smaller model)
    assert _fresh_step_error(default_rom, fom, RB, dt, train) < target


def test_a_given_estimators_trainer_carries_the_target(wave):
    fom, train, RB, dt = wave
    est = SymplecticKernelPredictor(IMQ(0.3), IMQ(1.0), max_centers=400, trainer=ExactGreedy(target_error=1e-2))
    red = SymplecticKernelReductor(fom, RB, dt, GalerkinSamples(train), est)
    red.reduce()
    assert red.predictor_.history_.stop_reason == "target" and red.predictor_.n_centers_ < 400
    assert est.trainer.target_error == 1e-2 and not est.is_fitted  # the caller's estimator is cloned, never changed


def test_an_unreachable_target_warns_once_naming_the_limit_and_keeps_the_best(wave, default_rom):
    fom, train, RB, dt = wave
    with pytest.warns(AccuracyWarning) as caught:
        red = SymplecticKernelReductor(fom, RB, dt, GalerkinSamples(train), DefaultEstimator(target_error=1e-9))
        red.reduce()
    accuracy = [w for w in caught if issubclass(w.category, AccuracyWarning)]
    assert len(accuracy) == 1  # the final fit's, not the kernel candidates'
    message = str(accuracy[0].message)
    assert "target_error=1e-09 not met" in message and "Limit:" in message
    assert any(limit in message for limit in ("kernel breakdown", "centre cap", "the data"))
    assert not red.predictor_.diagnostics_.target_met
    assert red.predictor_.n_centers_ >= 1 and np.all(
        np.isfinite(red.predictor_.prefix_errors_[red.predictor_.n_centers_])
    )


@pytest.mark.parametrize("bad", [0.0, -1e-3, float("nan"), "1e-3", True])
def test_the_default_estimators_target_is_checked(bad):
    with pytest.raises(ValueError, match="target_error"):
        DefaultEstimator(target_error=bad).check()
