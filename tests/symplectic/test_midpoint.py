"""The symmetric (midpoint) generating-function update: symplectic, time-symmetric, exists up to a half turn per step."""

import warnings

import numpy as np
import pytest

from sympredict import SymplecticKernelPredictor
from sympredict.exceptions import ExtrapolationWarning
from sympredict.io import load_model, save_model
from sympredict.kernels import IMQ
from sympredict.symplectic.metrics import canonical_J
from sympredict.symplectic.newton import solve_midpoint_numpy
from sympredict.symplectic.solvers import NewtonSolver
from _tolerances import assert_same_predictions  # tests/
from _surrogate_oracles import check_step_jacobian  # tests/

J = canonical_J(2)


def _rotation(x, theta):
    """Flow of H = (q^2 + p^2) / 2 over the time theta (omega = 1)."""
    c, s = np.cos(theta), np.sin(theta)
    return np.column_stack([c * x[:, 0] + s * x[:, 1], -s * x[:, 0] + c * x[:, 1]])


def _oscillator_model(theta, update, n=300):
    x0 = np.random.default_rng(0).uniform(-1, 1, (n, 2))
    model = SymplecticKernelPredictor(IMQ(0.5), max_centers=2 * n, update=update, solver=NewtonSolver(backend="numpy"))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ExtrapolationWarning)
        return model.fit(x0, _rotation(x0, theta), dt=theta)


def _test_states():
    return 0.5 * np.random.default_rng(1).uniform(-1, 1, (40, 2))


@pytest.mark.parametrize("theta", [0.5, np.pi / 2, 2.5, 3.0])
def test_existence_up_to_a_half_turn_per_step(theta):
    """Midpoint: s exists for omega dT < pi (Cayley: S = 2/dT tan(theta/2) I); accurate at and beyond pi/2."""
    x = _test_states()
    err = np.abs(_oscillator_model(theta, "midpoint").step(x) - _rotation(x, theta)).max()
    assert err < 1e-5


def test_type_ii_form_fails_at_a_quarter_turn():
    """The paper's s(q0, p1) degenerates at omega dT = pi/2 (p1 = -q0: xi does not determine the state)."""
    x = _test_states()
    model = _oscillator_model(np.pi / 2, "symplectic_euler")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ExtrapolationWarning)
        try:
            err = np.abs(model.step(x) - _rotation(x, np.pi / 2)).max()
        except ArithmeticError:  # Newton's failure counts as failing too
            err = np.inf
    assert err > 1e-1


@pytest.fixture(scope="module")
def pendulum_midpoint(small_pendulum_data):
    d = small_pendulum_data
    idx = np.random.default_rng(0).choice(len(d), 1500, replace=False)
    # the NumPy reference solver (the compiled one is checked against it in test_midpoint_compiled.py)
    model = SymplecticKernelPredictor(
        IMQ(0.2), IMQ(1.5), IMQ(3.0), max_centers=400, update="midpoint", solver=NewtonSolver(backend="numpy")
    )
    return model.fit(d.x0[idx], d.x1[idx], mu=d.mu[idx], dt=d.dt[idx]), d


def test_symplectic_jacobian_analytic_and_by_finite_differences(pendulum_midpoint):
    model, d = pendulum_midpoint
    x = np.array([[0.4, 0.3], [1.0, -0.5], [-0.7, 0.9]])
    mu, dt = np.array([0.72, 0.75, 0.78]), np.array([0.045, 0.05, 0.055])
    # h = 1e-4: the Newton tolerance sets the floor of the differences (1.8e-6 at h = 1e-6, 1.2e-8 here)
    jac, fd = check_step_jacobian(model, x, mu, dt, fd_atol=1e-7, h=1e-4)
    np.testing.assert_allclose(np.einsum("bji,jk,bkl->bil", fd, J, fd), np.broadcast_to(J, jac.shape), atol=1e-7)


def test_time_symmetry_the_reverse_step_inverts(pendulum_midpoint):
    """With the same s, the step with -dT from x1 returns to x0 (to Newton's tolerance)."""
    model, _ = pendulum_midpoint
    x = np.random.default_rng(3).uniform([-1.5, -1.5], [1.5, 1.5], (20, 2))
    mu, dt = np.full(20, 0.75), np.full(20, 0.05)
    w = model.surrogate_.weights(mu[:, None], dt)
    x1 = solve_midpoint_numpy(model.surrogate_, x, w, dt, 50)
    np.testing.assert_allclose(model.step(x, mu=mu, dt=dt), x1, rtol=0, atol=0)
    back = solve_midpoint_numpy(model.surrogate_, x1, w, -dt, 50)
    np.testing.assert_allclose(back, x, atol=1e-13)
    assert np.abs(x1 - x).max() > 1e-2


def test_accuracy_on_the_pendulum_and_settings(pendulum_midpoint, pendulum, tmp_path):
    model, d = pendulum_midpoint
    x = np.array([[0.8, 0.0], [0.3, 0.5]])
    mu, dt = np.array([0.75, 0.75]), np.array([0.05, 0.05])
    ref = pendulum.trajectory(x, mu, 0.05, 1)[:, 1]
    assert np.abs(model.step(x, mu=mu, dt=dt) - ref).max() < 1e-4
    traj = model.rollout(x, 100, mu=mu, dt=dt)
    assert np.all(np.isfinite(traj)) and model.solvability(x, mu=mu, dt=dt).max() < 1
    save_model(model, tmp_path / "mid.h5")
    loaded = load_model(tmp_path / "mid.h5")
    assert loaded.update == "midpoint"
    assert_same_predictions(loaded, model, x, 5, mu=mu, dt=dt)
    with pytest.raises(ValueError, match="update must be"):
        SymplecticKernelPredictor(IMQ(0.2), IMQ(1.5), IMQ(3.0), update="leapfrog").fit(
            d.x0[:50], d.x1[:50], mu=d.mu[:50], dt=d.dt[:50]
        )
