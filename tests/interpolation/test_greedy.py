"""f-greedy / P-greedy against the dense solve and against directly recomputed residuals."""

import time

import numpy as np
import pytest

from sympredict.data import mixed_variables
from sympredict.interpolation.functionals import HBFunctionals, dense_interpolation
from sympredict.interpolation.greedy import greedy_interpolation
from sympredict.kernels import IMQ, Matern32, Matern52, ProductKernel
from sympredict.interpolation.surrogate import HBSurrogate


def _problem(rng, kernel, m_points=30, dim=2):
    xi = rng.uniform(-2, 2, size=(m_points, dim))
    mu = rng.uniform(0.7, 0.8, size=(m_points, 1))
    dt = rng.choice([0.04, 0.06], size=m_points)
    # gradient of a smooth generating function s = sum sin(xi) * mu + dt * |xi|^2
    y = np.cos(xi) * mu + 2 * dt[:, None] * xi
    return HBFunctionals(kernel, xi, mu, dt), xi, mu, dt, y


def _surrogate(kernel, xi, mu, dt, selected, coef):
    p, a = np.divmod(selected, xi.shape[1])
    return HBSurrogate(kernel, xi[p], mu[p], dt[p], a, coef)


@pytest.mark.parametrize("state", [IMQ(0.5), Matern32(0.7), Matern52(0.6)], ids=repr)
def test_greedy_to_exhaustion_equals_dense_solve(state, rng):
    kernel = ProductKernel(state, IMQ(2.0), IMQ(5.0))
    fun, xi, mu, dt, y = _problem(rng, kernel, m_points=15)
    res = greedy_interpolation(fun, y.ravel(), max_centers=fun.n_functionals, tol=0.0, power_tol=0.0)
    assert res.history.stop_reason == "exhausted"
    dense = dense_interpolation(fun, y.ravel())
    coef = np.zeros(fun.n_functionals)
    coef[res.selected] = res.coef
    np.testing.assert_allclose(coef, dense, atol=1e-7 * np.abs(dense).max())


def test_greedy_interpolates_exactly_at_selected_and_tracks_residuals(rng):
    kernel = ProductKernel(IMQ(0.5), IMQ(2.0), IMQ(5.0))
    fun, xi, mu, dt, y = _problem(rng, kernel, m_points=60)
    val_fun, vxi, vmu, vdt, vy = _problem(np.random.default_rng(7), kernel, m_points=20)
    t0 = time.perf_counter()
    res = greedy_interpolation(fun, y.ravel(), max_centers=40, tol=0.0, validation=(val_fun, vy.ravel()))
    wall = time.perf_counter() - t0
    sur = _surrogate(kernel, xi, mu, dt, res.selected, res.coef)
    grad = sur.gradient(xi, sur.weights(mu, dt)).ravel()
    # exact reproduction of the data at the selected functionals
    np.testing.assert_allclose(grad[res.selected], y.ravel()[res.selected], atol=1e-9 * np.abs(y).max())
    # residual bookkeeping of the greedy equals the directly recomputed residual
    assert res.history.train_max_residual[-1] == pytest.approx(np.abs(grad - y.ravel()).max(), rel=1e-6)
    vgrad = sur.gradient(vxi, sur.weights(vmu, vdt)).ravel()
    assert res.history.val_max_residual[-1] == pytest.approx(np.abs(vgrad - vy.ravel()).max(), rel=1e-6)
    assert len(res.history.train_max_residual) == 41 and len(res.history.val_max_residual) == 41
    # f-greedy picks the max residual: the first pick is argmax |y|
    assert res.selected[0] == np.argmax(np.abs(y.ravel()))
    assert len(set(res.selected.tolist())) == len(res.selected)
    # elapsed: one time per selected centre, since the start of this run (not cumulative over runs)
    assert res.history.elapsed.shape == (len(res.selected),)
    assert 0 <= res.history.elapsed[-1] <= wall


def test_p_greedy_selects_by_power_function(rng):
    kernel = ProductKernel(IMQ(0.5))
    xi = rng.uniform(-2, 2, size=(40, 2))
    fun = HBFunctionals(kernel, xi, np.zeros((40, 0)), np.full(40, 0.1))
    y = rng.normal(size=80)
    res_p = greedy_interpolation(fun, y, max_centers=10, criterion="p")
    res_p2 = greedy_interpolation(fun, rng.normal(size=80), max_centers=10, criterion="p")
    # P-greedy is data independent
    np.testing.assert_array_equal(res_p.selected, res_p2.selected)
    assert np.all(np.diff(res_p.history.selected_power) <= 1e-12)


def test_duplicate_points_stop_on_power_breakdown_without_nan():
    kernel = ProductKernel(IMQ(1.0))
    xi = np.array([[0.0, 0.0], [0.0, 0.0], [1.0, 0.5]])
    fun = HBFunctionals(kernel, xi, np.zeros((3, 0)), np.full(3, 0.1))
    y = np.array([1.0, 0.0, 2.0, 0.5, -1.0, 0.3])  # contradictory data at the duplicate
    res = greedy_interpolation(fun, y, max_centers=6, tol=0.0)
    assert res.history.stop_reason == "power"
    assert len(res.selected) == 4
    assert np.all(np.isfinite(res.coef))


def test_tolerance_stop_and_argument_checks(rng):
    kernel = ProductKernel(IMQ(0.5), IMQ(2.0), IMQ(5.0))
    fun, xi, mu, dt, y = _problem(rng, kernel, m_points=40)
    res = greedy_interpolation(fun, y.ravel(), max_centers=80, tol=1e-3)
    assert res.history.stop_reason == "tol"
    assert res.history.train_max_residual[-1] <= 1e-3 < res.history.train_max_residual[-2]
    with pytest.raises(ValueError, match="criterion"):
        greedy_interpolation(fun, y.ravel(), max_centers=5, criterion="x")
    with pytest.raises(ValueError, match="max_centers <= "):
        greedy_interpolation(fun, y.ravel(), max_centers=50, memory_limit=8 * 80 * 10)


def test_functional_forms_are_the_strategies_run(rng):
    """greedy_interpolation / active_set_greedy split their keywords into the strategy's settings and the run's
    arguments: the same result as the strategy's run, and any other keyword refused, naming both lists."""
    from sympredict.interpolation.greedy import ActiveSetGreedy, ExactGreedy, active_set_greedy

    kernel = ProductKernel(IMQ(0.5), IMQ(2.0), IMQ(5.0))
    fun, xi, mu, dt, y = _problem(rng, kernel, m_points=40)
    seen = []
    res = greedy_interpolation(
        fun, y.ravel(), max_centers=30, tol=0.0, criterion="p", callback=lambda m, e: seen.append(m)
    )
    ref = ExactGreedy(tol=0.0, criterion="p").run(fun, y.ravel(), max_centers=30)
    np.testing.assert_array_equal(res.selected, ref.selected)
    np.testing.assert_array_equal(res.coef, ref.coef)
    assert len(seen) == len(res.selected)
    act = active_set_greedy(fun, y.ravel(), max_centers=20, tol=0.0, initial_points=10, refresh_every=5)
    act_ref = ActiveSetGreedy(initial_points=10, refresh_every=5, tol=0.0).run(fun, y.ravel(), max_centers=20)
    np.testing.assert_array_equal(act.selected, act_ref.selected)
    with pytest.raises(
        TypeError,
        match=r"greedy_interpolation\(\) got unexpected keyword arguments \['tolerance'\]; "
        r"ExactGreedy's settings are \[.*'tol'.*\], the run's arguments \[.*'validation'.*\]",
    ):
        greedy_interpolation(fun, y.ravel(), max_centers=5, tolerance=1e-3)
    with pytest.raises(ValueError, match="keep_basis needs ExactGreedy"):
        active_set_greedy(fun, y.ravel(), max_centers=5, keep_basis=True)


def test_strategies_declare_their_settings_once_and_hand_their_own_to_the_store():
    """The shared settings are the Trainer's keyword-only fields, each strategy's own settings its positional
    fields, which are its store's keyword arguments (by the same names, every one of them)."""
    import inspect

    from sympredict.interpolation.greedy import TRAINERS, Trainer
    from sympredict.interpolation.greedy.trainers import ActiveSetStore, BoundedActiveSetStore, BlockedStore
    from sympredict.interpolation.greedy.trainers import DenseStore, ShardedStore

    stores = {
        "ExactGreedy": DenseStore,
        "ActiveSetGreedy": ActiveSetStore,
        "ShardedGreedy": ShardedStore,
        "BlockedGreedy": BlockedStore,
        "BoundedActiveSetGreedy": BoundedActiveSetStore,
    }
    assert set(stores) == set(TRAINERS)
    for name, cls in TRAINERS.items():
        params = inspect.signature(cls.__init__).parameters.values()
        keyword = {p.name for p in params if p.kind is p.KEYWORD_ONLY}
        own = [p.name for p in params if p.kind is p.POSITIONAL_OR_KEYWORD and p.name != "self"]
        assert {"tol", "power_tol", "target_error"} <= keyword and not keyword & set(own), name
        trainer = cls()
        settings = trainer.store_settings(validation=None)
        assert all(settings[k] == getattr(trainer, k) for k in own), name
        assert set(own) <= set(inspect.signature(stores[name].__init__).parameters), name
        assert set(settings) - {"power_tol", "validation"} <= set(trainer.get_params()), name
    # a strategy lacking a setting runs with the Trainer's value for it, and cannot be given one
    assert Trainer.criterion == "f" and Trainer.regularization == 0.0 and Trainer.memory_limit is None
    with pytest.raises(TypeError):
        TRAINERS["ActiveSetGreedy"](criterion="p")


def test_mixed_variables_roundtrip(rng):
    x0, x1, dt = rng.normal(size=(5, 4)), rng.normal(size=(5, 4)), rng.uniform(0.1, 0.2, 5)
    xi, y = mixed_variables(x0, x1, dt)
    np.testing.assert_array_equal(xi[:, :2], x0[:, :2])
    np.testing.assert_array_equal(xi[:, 2:], x1[:, 2:])
    # symplectic Euler with the exact targets reproduces x1: p1 = p0 - dt y_q, q1 = q0 + dt y_p
    np.testing.assert_allclose(x0[:, 2:] - dt[:, None] * y[:, :2], x1[:, 2:], atol=1e-14)
    np.testing.assert_allclose(x0[:, :2] + dt[:, None] * y[:, 2:], x1[:, :2], atol=1e-14)


def test_round_off_blow_up_is_detected_and_truncated_to_best(small_pendulum_data):
    """With the breakdown guard set too low, round-off in the Newton basis makes the
    residual explode; the run must stop, truncate to its best step, and stay finite."""
    d = small_pendulum_data
    kernel = ProductKernel(IMQ(0.15), IMQ(2.0), IMQ(5.0))
    xi, y = mixed_variables(d.x0, d.x1, d.dt)
    fun = HBFunctionals(kernel, xi, d.mu, d.dt)
    res = greedy_interpolation(fun, y.ravel(), max_centers=3000, tol=0.0, power_tol=0.0, divergence_factor=100.0)
    hist = res.history
    assert hist.stop_reason == "diverged"
    assert hist.train_max_residual[-1] == hist.train_max_residual.min()
    assert len(res.selected) == len(hist.train_max_residual) - 1 == len(res.coef)
    sur = _surrogate(kernel, xi, d.mu, d.dt, res.selected, res.coef)
    direct = np.abs(sur.gradient(xi, sur.weights(d.mu, d.dt)) - y).max()
    assert direct < 1e-3
