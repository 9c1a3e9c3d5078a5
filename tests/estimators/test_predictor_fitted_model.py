"""The estimator holds settings; ``fit`` sets one fitted flow map, ``model_``, to which predictions delegate.

The fitted map (:mod:`sympredict.estimators.fitted`) is frozen, built by a public constructor (by ``fit`` and by
model files alike), and predicts on its own: the same arrays through the same code give the estimator's
predictions bit for bit.
"""

import copy

import numpy as np
import pytest

from sympredict import DirectKernelPredictor, SymplecticKernelPredictor
from sympredict.estimators.fitted import (
    FittedDirectFlowMap,
    FittedSymplecticFlowMap,
    check_finite,
    model_coordinates,
    training_box,
)
from sympredict.exceptions import NonFinitePredictionError, NotFittedError
from sympredict.interpolation.greedy import ExactGreedy
from sympredict.kernels import IMQ
from sympredict.kernels.transforms import Periodic, Scaled, StateKernelParts
from sympredict.symplectic.solvers import NewtonSolver

DT = 0.1


def _inner(data, n):
    """``n`` training states well inside the training box (short rollouts from them stay inside)."""
    x = data.x0
    return x[(np.abs(x[:, 0]) < 1.5) & (np.abs(x[:, 1]) < 1.0)][:n]


@pytest.fixture(scope="module")
def scaled_model(coarse_pendulum_data):
    """A model with a symplectic scaling and validation data (E_val recorded), on the NumPy solver."""
    d = coarse_pendulum_data
    return SymplecticKernelPredictor(
        Scaled(IMQ(0.3), factors=(1.3,)), max_centers=30, update="midpoint", solver=NewtonSolver(backend="numpy")
    ).fit(d.x0[::2], d.x1[::2], dt=DT, validation=(d.x0[1::2], d.x1[1::2], None, np.full(len(d.x0[1::2]), DT)))


def test_fit_sets_one_fitted_map_and_the_fitted_attributes_are_views_of_it(scaled_model):
    m = scaled_model.model_
    assert isinstance(m, FittedSymplecticFlowMap)
    assert scaled_model.surrogate_ is m.surrogate and scaled_model.kernel_ is m.kernel
    assert scaled_model.history_ is m.history and scaled_model.greedy_result_ is m.greedy_result
    assert (scaled_model.dim_, scaled_model.n_mu_, scaled_model.dt_fixed_) == (m.dim, m.n_mu, m.dt_fixed) == (2, 0, DT)
    assert scaled_model.update_ == "midpoint" == m.update and scaled_model.state_scaling_ == (1.3,) == m.parts.scaling
    assert scaled_model.n_centers_ == m.n_centers == 30
    assert scaled_model.fitted_params_["update"] == "midpoint"
    np.testing.assert_array_equal(m.scale, [1.3, 1 / 1.3])


def test_the_fitted_map_is_frozen(scaled_model):
    m = scaled_model.model_
    for name in ("surrogate", "solver", "dim", "new_attribute"):
        with pytest.raises(AttributeError, match="frozen"):
            setattr(m, name, None)
    with pytest.raises(AttributeError, match="setter"):  # a fitted attribute of the estimator is a read-only view
        scaled_model.surrogate_ = None


def test_the_estimators_predictions_are_the_fitted_maps(scaled_model, coarse_pendulum_data):
    x = _inner(coarse_pendulum_data, 6)
    m = scaled_model.model_
    np.testing.assert_array_equal(scaled_model.step(x), m.step(x))
    np.testing.assert_array_equal(scaled_model.rollout(x, 7, stride=2), m.rollout(x, 7, stride=2))
    np.testing.assert_array_equal(scaled_model.step_jacobian(x), m.step_jacobian(x))
    np.testing.assert_array_equal(scaled_model.solvability(x), m.solvability(x))
    traj, err = scaled_model.rollout(x, 5, return_error=True)
    traj2, err2 = m.rollout(x, 5, return_error=True)
    np.testing.assert_array_equal(traj, traj2)
    np.testing.assert_array_equal(err, err2)
    L = np.eye(2) * 1.01
    np.testing.assert_array_equal(scaled_model.rollout(x, 3, around=(L, L)), m.rollout(x, 3, around=(L, L)))


def test_the_public_constructor_rebuilds_the_same_map(scaled_model, coarse_pendulum_data):
    """The constructor model files use: the fitted arrays and settings give the same predictions bit for bit."""
    m = scaled_model.model_
    again = FittedSymplecticFlowMap(
        m.kernel,
        FittedSymplecticFlowMap.surrogate_from_arrays(m.kernel, m.surrogate_arrays(), m.dim, m.n_mu),
        domain=m.domain,
        history=m.history,
        dt_fixed=m.dt_fixed,
        update=m.update,
        parts=m.parts,
        solver=m.solver,
        regularization=m.regularization,
        error_calibration=m.error_calibration,
        error_local=m.error_local,
        error_residuals=m.error_residuals,
    )
    x = _inner(coarse_pendulum_data, 5)
    np.testing.assert_array_equal(again.rollout(x, 6), m.rollout(x, 6))
    np.testing.assert_array_equal(again.step(x, return_error=True)[1], m.step(x, return_error=True)[1])
    assert again.error_calibration == m.error_calibration
    with pytest.raises(ValueError, match="Newton data"):  # a map without the greedy's data cannot be truncated
        again.truncated(3)


def test_a_model_file_holds_the_same_fitted_map(scaled_model, coarse_pendulum_data, tmp_path):
    scaled_model.save(tmp_path / "m.h5")
    loaded = SymplecticKernelPredictor.load(tmp_path / "m.h5")
    assert isinstance(loaded.model_, FittedSymplecticFlowMap) and loaded.model_.greedy_result is None
    x = _inner(coarse_pendulum_data, 5)
    np.testing.assert_array_equal(loaded.rollout(x, 6), scaled_model.rollout(x, 6))
    assert loaded.model_.parts == scaled_model.model_.parts and loaded.model_.regularization == 0.0


def test_the_solver_is_a_setting_read_when_predicting(scaled_model, coarse_pendulum_data):
    """``set_params(solver=...)`` after the fit changes how, not what, is predicted: the fitted map is shared."""
    other = copy.copy(scaled_model).set_params(solver__max_iter=1)
    assert other.model_ is scaled_model.model_
    assert other._fitted().solver.max_iter == 1 and scaled_model._fitted().solver.max_iter == 50
    assert scaled_model._fitted() is scaled_model.model_  # the solver it was fitted with: no copy per call
    searched = SymplecticKernelPredictor(IMQ(0.3), max_centers=10, solver=NewtonSolver(backend="numpy"))
    searched.fit(coarse_pendulum_data.x0, coarse_pendulum_data.x1, dt=DT)  # update=None: fitted on a resolved clone
    assert searched._fitted() is searched.model_ and searched.model_.solver is searched.solver
    with_one = scaled_model.model_.with_solver(NewtonSolver(max_iter=1, backend="numpy"))
    assert with_one.surrogate is scaled_model.model_.surrogate and with_one.solver.max_iter == 1
    with pytest.raises(ValueError, match="solver must be a NewtonSolver"):
        scaled_model.model_.with_solver("numpy")


def test_truncated_and_smallest_on_the_map_and_the_estimator(scaled_model, coarse_pendulum_data):
    x = _inner(coarse_pendulum_data, 4)
    small = scaled_model.truncated(12)
    assert isinstance(small, SymplecticKernelPredictor) and small.max_centers == 12 == small.n_centers_
    assert small.fitted_params_["max_centers"] == 12 and scaled_model.n_centers_ == 30
    np.testing.assert_array_equal(small.rollout(x, 4), scaled_model.model_.truncated(12).rollout(x, 4))
    assert small.history_.stop_reason == "truncated to 12 of 30 centres"
    target = float(scaled_model.history_.val_max_residual[20])
    smallest = scaled_model.smallest(target)
    assert smallest.n_centers_ == scaled_model.model_.smallest(target).n_centers <= 20


def test_unfitted_estimators_have_no_fitted_attributes():
    est = SymplecticKernelPredictor(IMQ(0.3))
    assert not est.is_fitted and not hasattr(est, "surrogate_") and not hasattr(est, "update_")
    with pytest.raises(NotFittedError, match="not fitted yet"):
        est.step(np.zeros(2))
    with pytest.raises(NotFittedError, match="not fitted yet"):
        est.numpy_only_


def test_a_failed_fit_keeps_the_previous_fitted_map(scaled_model, coarse_pendulum_data):
    m = copy.copy(scaled_model)
    before = m.model_
    with pytest.raises(ValueError):
        m.fit(coarse_pendulum_data.x0, coarse_pendulum_data.x1[:5], dt=DT)
    assert m.model_ is before


def test_the_direct_model_has_its_fitted_map(coarse_pendulum_data, tmp_path):
    d = coarse_pendulum_data
    est = DirectKernelPredictor(IMQ(0.3), max_centers=20).fit(d.x0, d.x1, dt=DT)
    assert isinstance(est.model_, FittedDirectFlowMap) and est.surrogate_ is est.model_.surrogate
    x = _inner(d, 5)
    np.testing.assert_array_equal(est.rollout(x, 4), est.model_.rollout(x, 4))
    est.save(tmp_path / "d.h5")
    np.testing.assert_array_equal(DirectKernelPredictor.load(tmp_path / "d.h5").rollout(x, 4), est.rollout(x, 4))


def test_training_box_and_model_coordinates(coarse_pendulum_data):
    box = training_box(coarse_pendulum_data)
    states = np.concatenate([coarse_pendulum_data.x0, coarse_pendulum_data.x1])
    np.testing.assert_array_equal(box["x_min"], states.min(axis=0))
    assert box["mu_min"].shape == (1,) and float(box["dt_min"]) == DT
    parts = StateKernelParts(scaling=(2.0,), periodic=(0,))
    scale, periodic, symmetry = model_coordinates(parts, "symplectic_euler", 2)
    np.testing.assert_array_equal(scale, [2.0, 0.5])
    assert periodic is not None and symmetry is None
    with pytest.raises(ValueError, match="even dimension"):
        model_coordinates(parts, "symplectic_euler", 3)
    with pytest.raises(ValueError, match="Scaled factors"):
        model_coordinates(StateKernelParts(scaling=(2.0, 3.0)), "midpoint", 2)
    assert Periodic  # the transform the periodic parts come from


def test_check_finite_names_the_instances():
    with pytest.raises(NonFinitePredictionError) as info:
        check_finite(np.array([[0.0, 1.0], [np.nan, 0.0], [np.inf, 1.0]]), "this model")
    assert "1" in str(info.value) and "this model" in str(info.value)


def test_the_estimator_checks_its_settings_publicly():
    """``check_params`` (what fit, model files and the reductor run) names the bad setting; returns the trainer."""
    assert isinstance(SymplecticKernelPredictor(IMQ(0.3)).check_params(), ExactGreedy)
    with pytest.raises(ValueError, match="max_centers"):
        SymplecticKernelPredictor(IMQ(0.3), max_centers=0).check_params()
    with pytest.raises(ValueError, match="solver must be a NewtonSolver"):
        SymplecticKernelPredictor(IMQ(0.3), solver="numba").check_params()
