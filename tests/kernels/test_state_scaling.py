"""Per-coordinate kernel shapes through a diagonal symplectic scaling of the state (state_scaling)."""

import warnings

import numpy as np
import pytest

from sympredict import SymplecticKernelPredictor
from sympredict.data import mixed_variables
from sympredict.exceptions import ExtrapolationWarning
from sympredict.io import load_model, save_model
from sympredict.kernels import IMQ
from sympredict.estimators.selection import select_kernels
from sympredict.symplectic.solvers import NewtonSolver
from sympredict.kernels.transforms import Scaled
from _surrogate_oracles import check_step_jacobian  # tests/


@pytest.fixture(scope="module")
def data(small_pendulum_data):
    d = small_pendulum_data
    return d.subset(np.random.default_rng(0).choice(len(d), 1200, replace=False))


def _model(update="symplectic_euler", scaling=(2.0,), backend="numpy", max_centers=300):
    return SymplecticKernelPredictor(
        Scaled(IMQ(0.2), factors=scaling),
        IMQ(1.5),
        IMQ(3.0),
        max_centers=max_centers,
        update=update,
        solver=NewtonSolver(backend=backend),
    )


@pytest.mark.parametrize("update", ["symplectic_euler", "midpoint"])
def test_same_as_training_on_scaled_coordinates(data, update):
    """The option is the map (a q, p / a) before the kernel: equal to a plain model on scaled data."""
    s = np.array([2.0, 0.5])
    scaled = _model(update).fit(data.x0, data.x1, mu=data.mu, dt=data.dt)
    plain = _model(update, scaling=None).fit(data.x0 * s, data.x1 * s, mu=data.mu, dt=data.dt)
    assert np.array_equal(scaled.surrogate_.coef, plain.surrogate_.coef)
    x = np.array([[0.4, 0.3], [1.0, -0.5]])
    mu, dt = np.array([0.75, 0.72]), np.array([0.05, 0.045])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ExtrapolationWarning)
        ref_step = plain.step(x * s, mu=mu, dt=dt) / s
        ref_traj = plain.rollout(x * s, 20, mu=mu, dt=dt) / s
    np.testing.assert_allclose(scaled.step(x, mu=mu, dt=dt), ref_step, rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(scaled.rollout(x, 20, mu=mu, dt=dt), ref_traj, rtol=1e-13, atol=1e-14)


@pytest.mark.parametrize(
    "update,backend", [("symplectic_euler", "numpy"), ("symplectic_euler", "auto"), ("midpoint", "numpy")]
)
def test_symplectic_and_derivatives_by_finite_differences(data, update, backend):
    model = _model(update, scaling=(3.0,), backend=backend).fit(data.x0, data.x1, mu=data.mu, dt=data.dt)
    x = np.array([[0.4, 0.3], [1.0, -0.5], [-0.7, 0.9]])
    mu, dt = np.array([0.72, 0.75, 0.78]), np.array([0.045, 0.05, 0.055])
    check_step_jacobian(model, x, mu, dt, fd_atol=1e-6)
    # the gradient in the original coordinates: finite differences of nothing we own, so check it interpolates
    xi, y = (
        mixed_variables(data.x0, data.x1, data.dt)
        if update == "symplectic_euler"
        else (0.5 * (data.x0 + data.x1), mixed_variables(data.x0, data.x1, data.dt)[1])
    )
    pts, comps = np.divmod(model.greedy_result_.selected[:50], 2)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ExtrapolationWarning)
        g = model.surrogate_gradient(xi[pts], mu=data.mu[pts], dt=data.dt[pts])
    np.testing.assert_allclose(g[np.arange(50), comps], y[pts, comps], rtol=1e-6, atol=1e-6)


def test_stored_checked_and_searchable(data, tmp_path, pendulum):
    model = _model(scaling=(1.5,), max_centers=60).fit(data.x0, data.x1, mu=data.mu, dt=data.dt)
    save_model(model, tmp_path / "s.h5")
    back = load_model(tmp_path / "s.h5")
    assert back.state_kernel == Scaled(IMQ(0.2), factors=(1.5,)) and back.state_scaling_ == (1.5,)
    x = data.x0[:4]
    np.testing.assert_array_equal(
        back.step(x, mu=data.mu[:4], dt=data.dt[:4]), model.step(x, mu=data.mu[:4], dt=data.dt[:4])
    )
    for bad in ((0.0,), (1.0, 2.0), "2", (float("inf"),)):
        with pytest.raises(ValueError, match="Scaled.*factors"):
            _model(scaling=bad).fit(data.x0[:40], data.x1[:40], mu=data.mu[:40], dt=data.dt[:40])
    # the validation search takes it through the estimator: scalings compared at the same m*
    train, val = data.subset(np.arange(900)), data.subset(np.arange(900, 1200))
    scores = {}
    for a in (0.5, 1.0, 2.0):
        est = _model(scaling=(a,))
        scores[a] = select_kernels(train, val, [IMQ(0.2)], [IMQ(1.5)], [IMQ(3.0)], m_star=100, estimator=est).score
    assert len(set(scores.values())) == 3 and all(np.isfinite(v) for v in scores.values())
