"""SymplecticKernelPredictor: symplecticity, exactness, accuracy, API behaviour and errors."""

import copy
import warnings

import h5py
import numpy as np
import pytest

from sympredict import (
    ExtrapolationWarning,
    ModelFileError,
    NewtonConvergenceError,
    NotFittedError,
    DirectKernelPredictor,
    SymplecticKernelPredictor,
)
from sympredict.symplectic.integrators import implicit_midpoint_step, integrate
from sympredict.kernels import IMQ, Matern32, Matern52
from sympredict.symplectic.metrics import relative_trajectory_error, symplecticity_defect
from sympredict.interpolation.greedy import ExactGreedy


class CoupledOscillators:
    """2n = 4 test system: H = |p|^2/2 + mu |q|^2/2 + q1^2 q2^2 / 4 (non-separable enough, non-linear)."""

    def gradient(self, x, mu):
        q1, q2, p1, p2 = x.T
        k = mu[:, 0]
        return np.column_stack([k * q1 + 0.5 * q1 * q2**2, k * q2 + 0.5 * q2 * q1**2, p1, p2])

    def hessian(self, x, mu):
        q1, q2 = x[:, 0], x[:, 1]
        hess = np.zeros((len(x), 4, 4))
        hess[:, 0, 0] = mu[:, 0] + 0.5 * q2**2
        hess[:, 1, 1] = mu[:, 0] + 0.5 * q1**2
        hess[:, 0, 1] = hess[:, 1, 0] = q1 * q2
        hess[:, 2, 2] = hess[:, 3, 3] = 1.0
        return hess


def _random_queries(rng, n=20):
    x = np.column_stack([rng.uniform(-2, 2, n), rng.uniform(-4, 4, n)])
    return x, rng.uniform(0.7, 0.8, n), rng.uniform(0.04, 0.06, n)


def test_learned_step_is_symplectic(small_pendulum_model, rng):
    x, mu, dt = _random_queries(rng)
    jac = small_pendulum_model.step_jacobian(x, mu=mu, dt=dt)
    assert symplecticity_defect(jac).max() <= 1e-8
    # and the Jacobian is the derivative of step (independent finite-difference check);
    # h balances truncation (h^2) against the step's round-off floor (~1e-10 / h)
    h = 1e-4
    fd = np.stack(
        [
            (small_pendulum_model.step(x + h * e, mu=mu, dt=dt) - small_pendulum_model.step(x - h * e, mu=mu, dt=dt))
            / (2 * h)
            for e in np.eye(2)
        ],
        axis=2,
    )
    np.testing.assert_allclose(jac, fd, atol=1e-6)


@pytest.mark.parametrize("state_kernel", [IMQ(0.3), Matern52(0.4), Matern32(0.4)], ids=repr)
def test_four_dimensional_system_symplectic_and_exact(state_kernel, rng):
    system = CoupledOscillators()
    x0 = rng.uniform(-1, 1, size=(25, 4))
    mu = rng.uniform(1.0, 2.0, size=(25, 1))
    x1 = integrate(implicit_midpoint_step, system, x0, mu, 0.01, 10)[:, -1]  # dT = 0.1
    model = SymplecticKernelPredictor(
        state_kernel, mu_kernel=IMQ(1.0), max_centers=100, trainer=ExactGreedy(tol=0.0, power_tol=0.0)
    )
    model.fit(x0, x1, mu=mu, dt=0.1)
    assert model.n_centers_ == 100 and model.history_.stop_reason == "exhausted"
    # all functionals selected: the step reproduces every training sample
    np.testing.assert_allclose(model.step(x0, mu=mu), x1, atol=1e-7)
    xq = rng.uniform(-0.8, 0.8, size=(10, 4))
    muq = rng.uniform(mu.min(), mu.max(), 10)
    assert symplecticity_defect(model.step_jacobian(xq, mu=muq)).max() <= 1e-8
    assert model.dt_fixed_ == 0.1


def test_predictor_beats_implicit_midpoint(pendulum, small_pendulum_model):
    x0 = np.column_stack([np.linspace(0.3, 1.4, 4), np.zeros(4)])
    mu = np.array([0.72, 0.74, 0.77, 0.79])
    dt, n_steps = 0.05, 100
    ref = pendulum.trajectory(x0, mu, dt, n_steps)
    pred = small_pendulum_model.rollout(x0, n_steps, mu=mu, dt=dt)
    im = integrate(implicit_midpoint_step, pendulum, x0, mu[:, None], dt, n_steps)
    err_kernel = relative_trajectory_error(pred, ref).mean(axis=0)[1:]
    err_im = relative_trajectory_error(im, ref).mean(axis=0)[1:]
    assert np.median(err_kernel) * 10 < np.median(err_im)
    assert err_kernel.max() < err_im.max()


def test_rollout_consistent_with_step(small_pendulum_model, rng):
    x, mu, dt = _random_queries(rng, 5)
    traj = small_pendulum_model.rollout(x, 3, mu=mu, dt=dt)
    assert traj.shape == (5, 4, 2)
    np.testing.assert_array_equal(traj[:, 0], x)
    np.testing.assert_allclose(traj[:, 1], small_pendulum_model.step(x, mu=mu, dt=dt), rtol=0, atol=1e-14)
    single = small_pendulum_model.rollout(x[0], 3, mu=mu[0], dt=dt[0])
    assert single.shape == (4, 2)
    np.testing.assert_allclose(single, traj[0], atol=1e-14)
    assert small_pendulum_model.rollout(x, 0, mu=mu, dt=dt).shape == (5, 1, 2)


def test_save_load_roundtrip_bit_exact(small_pendulum_model, tmp_path, rng):
    path = tmp_path / "model.h5"
    small_pendulum_model.save(path)
    loaded = SymplecticKernelPredictor.load(path)
    for name in ("centers_xi", "centers_mu", "centers_dt", "components", "coef"):
        np.testing.assert_array_equal(getattr(loaded.surrogate_, name), getattr(small_pendulum_model.surrogate_, name))
    np.testing.assert_array_equal(loaded.history_.train_max_residual, small_pendulum_model.history_.train_max_residual)
    x, mu, dt = _random_queries(rng, 7)
    np.testing.assert_array_equal(loaded.rollout(x, 5, mu=mu, dt=dt), small_pendulum_model.rollout(x, 5, mu=mu, dt=dt))
    assert loaded.kernel_ == small_pendulum_model.kernel_
    # saving again over the same path replaces it atomically (no temp files left)
    loaded.save(path)
    assert [p.name for p in tmp_path.iterdir()] == ["model.h5"]


def test_load_rejects_foreign_corrupted_and_newer_files(small_pendulum_model, tmp_path):
    with pytest.raises(ModelFileError, match="does not exist"):
        SymplecticKernelPredictor.load(tmp_path / "missing.h5")
    text = tmp_path / "notes.h5"
    text.write_text("not hdf5")
    with pytest.raises(ModelFileError, match="cannot be read"):
        SymplecticKernelPredictor.load(text)
    foreign = tmp_path / "foreign.h5"
    with h5py.File(foreign, "w") as f:
        f["x"] = np.ones(3)
    with pytest.raises(ModelFileError, match="not a sympredict file"):
        SymplecticKernelPredictor.load(foreign)
    good = tmp_path / "good.h5"
    small_pendulum_model.save(good)
    with h5py.File(good, "r+") as f:
        f["arrays/coef"][0] += 1.0
    with pytest.raises(ModelFileError, match="corrupted"):
        SymplecticKernelPredictor.load(good)
    small_pendulum_model.save(good)
    with h5py.File(good, "r+") as f:
        f.attrs["schema_version"] = 99
    with pytest.raises(ModelFileError, match="schema version 99"):
        SymplecticKernelPredictor.load(good)
    small_pendulum_model.save(good)
    truncated = tmp_path / "truncated.h5"
    truncated.write_bytes(good.read_bytes()[:2000])
    with pytest.raises(ModelFileError):
        SymplecticKernelPredictor.load(truncated)


def test_bad_input_gets_clear_errors(small_pendulum_model, small_pendulum_data):
    m = small_pendulum_model
    d = small_pendulum_data
    x = np.array([[0.1, 0.2]])
    cases = [
        (lambda: m.step(np.ones((2, 3)), mu=0.75, dt=0.05), "2 state components"),
        (lambda: m.step(np.array([[np.nan, 0.0]]), mu=0.75, dt=0.05), "NaN or Inf"),
        (lambda: m.step(x, mu=0.75, dt=0.0), "positive"),
        (lambda: m.step(x, mu=0.75, dt=-0.05), "positive"),
        (lambda: m.step(x, mu=0.75), "dt is required"),
        (lambda: m.step(x, dt=0.05), "mu is required"),
        (lambda: m.step(x, mu=np.ones((1, 2)), dt=0.05), "1 component"),
        (lambda: m.step(x, mu=[0.7, 0.8, 0.75], dt=0.05), "length 1"),
        (lambda: m.step(x, mu="a", dt=0.05), "numeric"),
        (lambda: m.rollout(x, -1, mu=0.75, dt=0.05), "n_steps"),
        (lambda: m.rollout(x, 2.5, mu=0.75, dt=0.05), "n_steps"),
    ]
    for call, msg in cases:
        with pytest.raises(ValueError, match=msg):
            call()
    fresh = SymplecticKernelPredictor(IMQ(0.15), mu_kernel=IMQ(2.0), dt_kernel=IMQ(5.0), max_centers=10)
    with pytest.raises(NotFittedError):
        fresh.step(x, mu=0.75, dt=0.05)
    with pytest.raises(ValueError, match="mu_kernel is set"):
        fresh.fit(d.x0, d.x1, dt=d.dt)
    with pytest.raises(ValueError, match="same number of samples"):
        fresh.fit(d.x0, d.x1[:-1], mu=d.mu, dt=d.dt)
    with pytest.raises(ValueError, match=r"contradictory samples.*rows 0, 3"):  # same x0, mu, dt; another x1
        fresh.fit(
            np.vstack([d.x0[:3], d.x0[:1]]), np.vstack([d.x1[:3], d.x1[1:2]]), mu=np.r_[d.mu[:3, 0], d.mu[0]], dt=0.05
        )
    with pytest.raises(ValueError, match="max_centers"):
        SymplecticKernelPredictor(IMQ(1.0), max_centers=0).fit(d.x0, d.x1, dt=0.05)
    # the symplectic predictor chooses a missing mu or dt kernel (tests/estimators/test_auto_defaults.py); the direct one refuses
    no_mu = DirectKernelPredictor(IMQ(1.0), dt_kernel=IMQ(5.0), max_centers=10)
    with pytest.raises(ValueError, match="mu_kernel=None"):
        no_mu.fit(d.x0, d.x1, mu=d.mu, dt=d.dt)
    fixed = DirectKernelPredictor(IMQ(1.0), max_centers=10)
    with pytest.raises(ValueError, match="fixed-step"):
        fixed.fit(d.x0, d.x1, dt=d.dt)


def test_fixed_step_parameter_free_model(pendulum, rng):
    x0 = np.column_stack([rng.uniform(-1, 1, 60), rng.uniform(-3, 3, 60)])
    x1 = pendulum.flow(x0, 0.75, 0.05)
    xv = np.column_stack([rng.uniform(-1, 1, 20), rng.uniform(-3, 3, 20)])
    model = SymplecticKernelPredictor(max_centers=80).fit(
        x0, x1, dt=0.05, validation=(xv, pendulum.flow(xv, 0.75, 0.05), None, 0.05)
    )
    # default state kernel: chosen inside the symplectic scaling (a q, p / a), a = sqrt(std p / std q) over the
    # training states (all of them: with validation data nothing is held out), as documented
    x = np.vstack([x0, x1])
    chosen = model.choice_["state_kernel"]
    assert chosen.factors[0] == pytest.approx(np.sqrt(x[:, 1].std() / x[:, 0].std()), rel=1e-12)
    assert model.kernel_.state == chosen.kernel and model.state_kernel is None
    assert model.step(x0[:3]).shape == (3, 2)
    with pytest.raises(ValueError, match="fixed step"):
        model.step(x0[:3], dt=0.1)
    with pytest.raises(ValueError, match="without a parameter"):
        model.step(x0[:3], mu=0.7)


def test_newton_failure_names_instances(small_pendulum_model, rng):
    x, mu, dt = _random_queries(rng, 6)
    strict = copy.copy(small_pendulum_model).set_params(solver__max_iter=1)  # the fitted model, one Newton iteration
    with pytest.raises(NewtonConvergenceError) as info:
        strict.rollout(x, 2, mu=mu, dt=dt)
    err = info.value
    assert err.step == 0 and len(err.instances) > 0
    assert set(err.instances) <= set(range(6))
    assert "instance" in str(err)


def test_extrapolation_warns(small_pendulum_model):
    with pytest.warns(ExtrapolationWarning, match="mu"):
        small_pendulum_model.step(np.array([0.3, 0.0]), mu=0.9, dt=0.05)
    with pytest.warns(ExtrapolationWarning, match="dt"):
        small_pendulum_model.step(np.array([0.3, 0.0]), mu=0.75, dt=0.1)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        small_pendulum_model.step(np.array([0.3, 0.0]), mu=0.75, dt=0.05)


def test_truncated_model_equals_refit_with_fewer_centres(small_pendulum_data, rng, tmp_path):
    d = small_pendulum_data
    kernels = (IMQ(0.15), IMQ(2.0), IMQ(5.0))
    full = SymplecticKernelPredictor(*kernels, max_centers=200).fit(d.x0, d.x1, mu=d.mu, dt=d.dt)
    small = full.truncated(80)
    refit = SymplecticKernelPredictor(*kernels, max_centers=80).fit(d.x0, d.x1, mu=d.mu, dt=d.dt)
    np.testing.assert_array_equal(small.surrogate_.centers_xi, refit.surrogate_.centers_xi)
    np.testing.assert_allclose(
        small.surrogate_.coef, refit.surrogate_.coef, rtol=1e-10, atol=1e-10 * np.abs(refit.surrogate_.coef).max()
    )
    x, mu, dt = _random_queries(rng, 5)
    np.testing.assert_allclose(small.step(x, mu=mu, dt=dt), refit.step(x, mu=mu, dt=dt), atol=1e-12)
    assert small.n_centers_ == 80 and full.n_centers_ == 200 and len(small.history_.train_max_residual) == 81
    with pytest.raises(ValueError, match="n_centers must be <= 200"):
        full.truncated(201)
    np.testing.assert_array_equal(small.truncated(10).surrogate_.coef, full.truncated(10).surrogate_.coef)
    small.save(tmp_path / "small.h5")
    with pytest.raises(ValueError, match="not stored in model files"):
        SymplecticKernelPredictor.load(tmp_path / "small.h5").truncated(10)


def test_smallest_model_meeting_a_validation_target(small_pendulum_data):
    train, val = small_pendulum_data.split(0.2, seed=2)
    model = SymplecticKernelPredictor(IMQ(0.15), IMQ(2.0), IMQ(5.0), max_centers=300).fit(
        train.x0, train.x1, mu=train.mu, dt=train.dt, validation=val
    )
    curve = model.history_.val_max_residual
    target = float(np.sort(curve[1:])[len(curve) // 2])  # a target reached somewhere in the middle
    small = model.smallest(target)
    m = small.n_centers_
    assert curve[m] <= target and np.all(curve[1:m] > target)
    # the truncated model really has that validation residual
    from sympredict.data import mixed_variables

    xi, y = mixed_variables(val.x0, val.x1, val.dt)
    assert np.abs(small.surrogate_gradient(xi, mu=val.mu, dt=val.dt) - y).max() == pytest.approx(curve[m], rel=1e-6)
    with pytest.raises(ValueError, match="the best is"):
        model.smallest(curve[1:].min() / 10)
    with pytest.raises(ValueError, match="validation data"):
        SymplecticKernelPredictor(IMQ(0.15), IMQ(2.0), IMQ(5.0), max_centers=20).fit(
            train.x0, train.x1, mu=train.mu, dt=train.dt
        ).smallest(1.0)
