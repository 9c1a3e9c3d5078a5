"""No silent numerics in the estimators: rollouts that leave the training states, fits that select nothing."""

import numpy as np
import pytest

from sympredict import DirectKernelPredictor, ExtrapolationWarning, SymplecticKernelPredictor
from sympredict.kernels import IMQ
from sympredict.interpolation.greedy import ExactGreedy
from sympredict.symplectic.solvers import NewtonSolver


def _oscillator(n=60, seed=0, dt=0.3):
    rng = np.random.default_rng(seed)
    x0 = rng.uniform(-1, 1, (n, 2))
    c, s = np.cos(dt), np.sin(dt)
    return x0, x0 @ np.array([[c, -s], [s, c]]), dt


@pytest.mark.parametrize("cls", [SymplecticKernelPredictor, DirectKernelPredictor])
def test_a_rollout_that_leaves_the_training_states_warns(cls):
    """Samples in a square, the flow a rotation: a start near the box's corner circles out of the box."""
    x0, x1, dt = _oscillator()
    model = cls(IMQ(1.0), max_centers=40).fit(x0, x1, dt=dt)
    corner = 0.9 * np.minimum(model.domain_["x_max"], -model.domain_["x_min"])
    assert not model._outside_states(corner[None])[0]  # the start is inside the box ...
    assert np.linalg.norm(corner) > 1.05 * model.domain_["x_max"].max()  # ... on a circle that leaves it
    with pytest.warns(
        ExtrapolationWarning,
        match=r"1 of 2 trajectories leave the training states .*instances \[1\], first at step \d+",
    ):
        model.rollout(np.array([[0.1, 0.2], corner]), int(2 * np.pi / dt) + 1)


def test_a_rollout_inside_does_not_warn():
    x0, x1, dt = _oscillator()
    model = SymplecticKernelPredictor(IMQ(1.0), max_centers=40).fit(x0, x1, dt=dt)
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error", ExtrapolationWarning)
        model.rollout(np.array([[0.3, 0.2], [-0.4, 0.1]]), 50)  # radius < 0.5: the circle stays in the box


@pytest.mark.parametrize("backend", ["numpy", "numba"])
def test_a_fit_that_selects_nothing_is_the_zero_surrogate(backend, tmp_path):
    """Zero increments: the greedy stops at 0 centres ('tol'); the model is the identity map, saved and loaded."""
    x0 = np.random.default_rng(1).uniform(-1, 1, (30, 2))
    model = SymplecticKernelPredictor(IMQ(0.5), trainer=ExactGreedy(tol=0.0), solver=NewtonSolver(backend=backend)).fit(
        x0, x0.copy(), dt=0.1
    )
    assert model.n_centers_ == 0 and model.history_.stop_reason == "tol"
    x = x0[:4] * 0.5
    np.testing.assert_array_equal(model.rollout(x, 5)[:, -1], x)
    np.testing.assert_array_equal(model.step_jacobian(x), np.broadcast_to(np.eye(2), (4, 2, 2)))
    model.save(tmp_path / "zero.h5")
    back = SymplecticKernelPredictor.load(tmp_path / "zero.h5")
    np.testing.assert_array_equal(back.step(x), x)
    direct = DirectKernelPredictor(IMQ(0.5), trainer=ExactGreedy(tol=0.0)).fit(x0, x0.copy(), dt=0.1)
    assert direct.n_centers_ == 0
    np.testing.assert_array_equal(direct.rollout(x, 3)[:, -1], x)
