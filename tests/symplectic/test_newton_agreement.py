"""One Newton algorithm on both backends: the NumPy reference and the compiled rollout fail alike and agree.

The algorithm is written once (the :mod:`sympredict.symplectic.newton` module docstring); the two paths
differ only in rounding.  Checked here:

* steps far larger than the training steps: both backends raise the same exception naming the
  same instances, macro step and reason, with the contraction estimate ``dT L_S`` at the start
  guess in the report (the scenarios are ones whose failure does not hinge on rounding: the same
  report under relative perturbations of the states from 1e-14 to 1e-9, warm or cold);
* ordinary steps: the two rollouts agree to the bounds of ``tests/_tolerances.py``, also with a
  warm start, which now runs on both paths and goes on across the chunks of a long rollout;
* the estimate is evaluated only after a failure: a successful rollout makes the same passes
  over the centres on both paths and calls it never;
* the failure report's rule (earliest step, earliest iteration, reason order) on synthetic outcomes.
"""

import copy

import numpy as np
import pytest

from sympredict import NewtonConvergenceError, SymplecticKernelPredictor
from sympredict import _numba
from sympredict.interpolation.greedy import ExactGreedy
from sympredict.symplectic import newton
from sympredict.symplectic.solvers import NewtonSolver
from sympredict.exceptions import extrapolation_expected
from sympredict.kernels import IMQ

from _tolerances import rollout_bound  # tests/

pytestmark = pytest.mark.skipif(not _numba.HAVE_NUMBA, reason="the compiled rollout needs numba (optional extra)")

BACKENDS = ("numpy", "numba")


def _queries(seed, n=12):
    """``n`` pendulum states with ``q`` in ``[0, pi/2]``, ``|p| <= 0.5`` and lengths inside the training box."""
    rng = np.random.default_rng(seed)
    x = np.column_stack([rng.uniform(0.0, np.pi / 2, n), rng.uniform(-0.5, 0.5, n)])
    return x, rng.uniform(0.71, 0.79, n)


def _fit(data, warm=False, **settings):
    return SymplecticKernelPredictor(
        IMQ(0.15), mu_kernel=IMQ(2.0), trainer=ExactGreedy(tol=1e-10), solver=NewtonSolver(warm_start=warm), **settings
    ).fit(data.x0, data.x1, mu=data.mu, dt=data.dt)


@pytest.fixture(scope="module")
def far_models(small_pendulum_data):
    """Small models trained on steps 0.04..0.06, each with a query of steps 25-75 times as large.

    ``update -> (model, x, mu, dT)``.  The failures below were checked not to hinge on rounding:
    the same instances and step under relative perturbations of ``x`` from 1e-14 to 1e-9, on both
    backends and (symplectic Euler) with and without a warm start.  (The damped Newton converges on the
    midpoint model's dT = 1.0, where the undamped one failed: dT = 1.5 fails on both backends alike.)
    """
    d = small_pendulum_data
    euler = _fit(d, dt_kernel=IMQ(0.2), max_centers=60)
    midpoint = _fit(d, dt_kernel=IMQ(1.0), max_centers=150, update="midpoint")
    return {"symplectic_euler": (euler, *_queries(1), 3.0), "midpoint": (midpoint, *_queries(2), 1.5)}


def _failure(model, backend, x, n_steps, mu, dt, warm=False):
    m = copy.copy(model).set_params(solver__backend=backend, solver__warm_start=warm)
    with extrapolation_expected(), pytest.raises(NewtonConvergenceError) as info:
        if n_steps is None:
            m.step(x, mu=mu, dt=dt)
        else:
            m.rollout(x, n_steps, mu=mu, dt=dt)
    return info.value


def _assert_same_failure(a, b):
    assert type(a) is type(b) is NewtonConvergenceError
    assert a.step == b.step
    np.testing.assert_array_equal(a.instances, b.instances)
    assert a.reason == b.reason
    # dT L_S at the start guesses, evaluated by the same NumPy code from states that agree to round-off
    np.testing.assert_allclose(a.contraction, b.contraction, rtol=1e-6)
    assert "dT*L_S" in str(a) and "dT*L_S" in str(b)


@pytest.mark.parametrize("update", ["symplectic_euler", "midpoint"])
def test_steps_far_larger_than_the_training_steps_fail_alike(far_models, update):
    model, x, mu, dt = far_models[update]
    errors = {backend: _failure(model, backend, x, 6, mu, dt) for backend in BACKENDS}
    _assert_same_failure(errors["numpy"], errors["numba"])
    err = errors["numpy"]
    assert err.step == 1 and "did not converge" in err.reason  # the iteration wanders, it is not refused early
    assert np.all(np.isfinite(err.contraction)) and np.all(err.contraction > 0)
    # the same from the failing step's input, one step without a macro step (model.step)
    with extrapolation_expected():
        before = copy.copy(model).set_params(solver__backend="numpy").rollout(x, err.step, mu=mu, dt=dt)[:, -1]
    steps = {backend: _failure(model, backend, before, None, mu, dt) for backend in BACKENDS}
    _assert_same_failure(steps["numpy"], steps["numba"])
    assert steps["numpy"].step is None
    np.testing.assert_array_equal(steps["numpy"].instances, err.instances)


def test_far_larger_steps_fail_alike_with_a_warm_start(far_models):
    model, x, mu, dt = far_models["symplectic_euler"]
    _assert_same_failure(*(_failure(model, backend, x, 6, mu, dt, warm=True) for backend in BACKENDS))


def test_one_entry_point_takes_the_compiled_centre_order_on_both_backends(small_pendulum_model):
    """``weights_ordered``: weights in the compiled layout's order give each backend its result for the surrogate's
    order, bit for bit (the same arrays on the same path); an unknown backend is named."""
    sur = small_pendulum_model.surrogate_
    x, mu = _queries(5, 6)
    dt = np.full(6, 0.05)
    w = sur.weights(mu[:, None], dt)
    ordered = newton.ordered_weights(sur, w)
    assert not np.array_equal(ordered, w)  # the layout reorders the centres: the test sees the difference
    for backend in newton.BACKENDS:
        plain = newton.implicit_rollout(sur, x, w, dt, 4, 50, backend=backend)
        np.testing.assert_array_equal(
            newton.implicit_rollout(sur, x, ordered, dt, 4, 50, backend=backend, weights_ordered=True), plain
        )
    with pytest.raises(ValueError, match="backend must be one of"):
        newton.implicit_rollout(sur, x, w, dt, 4, 50, backend="jax")


def test_non_finite_iterates_reported_alike(small_pendulum_model):
    """Non-finite weights: a non-finite residual at the first iteration (reason 1), NaN residual, on both paths."""
    sur = small_pendulum_model.surrogate_
    x, mu = _queries(3, 6)
    dt = np.full(6, 0.05)
    w = sur.weights(mu[:, None], dt)
    w[[1, 4]] = np.nan
    errors = []
    for backend in newton.BACKENDS:
        with pytest.raises(NewtonConvergenceError) as info:
            newton.implicit_rollout(sur, x, w, dt, 3, 50, backend=backend)
        errors.append(info.value)
    a, b = errors
    assert a.step == b.step == 0 and a.reason == b.reason == newton.FAILURE_REASONS[1]
    np.testing.assert_array_equal(a.instances, [1, 4])
    np.testing.assert_array_equal(b.instances, [1, 4])
    assert np.all(np.isnan(a.residuals)) and np.all(np.isnan(b.residuals))


# ------------------------------------------------------------------ ordinary steps
@pytest.mark.parametrize("warm", [False, True])
@pytest.mark.parametrize("update", ["symplectic_euler", "midpoint"])
def test_ordinary_steps_agree_to_the_bounds(small_pendulum_data, update, warm):
    """Steps inside the training box: the two rollouts agree to :func:`_tolerances.rollout_bound`."""
    model = _fit(small_pendulum_data, dt_kernel=IMQ(5.0), max_centers=50, update=update, warm=warm)
    x, mu = _queries(4, 16)
    dt = np.random.default_rng(5).uniform(0.045, 0.055, 16)
    ref = copy.copy(model).set_params(solver__backend="numpy").rollout(x, 30, mu=mu, dt=dt)
    out = copy.copy(model).set_params(solver__backend="numba").rollout(x, 30, mu=mu, dt=dt)
    sur = model.surrogate_
    bound = rollout_bound(sur, ref, sur.weights(mu[:, None], dt), dt)
    assert bound < 1e-5
    assert np.abs(out - ref).max() <= bound


@pytest.mark.parametrize("backend", BACKENDS)
def test_a_warm_start_goes_on_across_chunks(small_pendulum_model, monkeypatch, backend):
    """The chunks of a long rollout pass their last states on: chunked equals one call, bit for bit."""
    model = copy.copy(small_pendulum_model).set_params(solver__backend=backend, solver__warm_start=True)
    x, mu = _queries(6, 5)
    one_call = model.rollout(x, 40, mu=mu, dt=0.05)
    monkeypatch.setattr(newton, "FIRST_CHUNK_STEPS", 1)  # chunks of 1, then at most 8 times the previous
    monkeypatch.setattr(newton, "CHUNK_SECONDS", 1e-9)  # ... and as short as the growth allows: 1, 1, 1, ...
    calls = []
    real = newton.rollout_in_chunks

    def counting(run, *args, **kwargs):
        return real(lambda *a: calls.append(a[1]) or run(*a), *args, **kwargs)

    monkeypatch.setattr("sympredict.estimators.fitted.rollout_in_chunks", counting)
    np.testing.assert_array_equal(model.rollout(x, 40, mu=mu, dt=0.05), one_call)
    assert len(calls) == 40  # one step per chunk: every step but the first starts from the carried states


def test_chunks_receive_the_states_before_them(monkeypatch):
    """``rollout_in_chunks(history=2)`` hands each chunk the last two states before its first (toy map x -> x + 1)."""
    monkeypatch.setattr(newton, "FIRST_CHUNK_STEPS", 1)
    x = np.array([[0.0, 10.0], [5.0, -1.0]])
    full = x[:, None, :] + np.arange(101)[None, :, None]
    seen = []

    def run(state, k, previous):
        start = int(state[0, 0])
        expected = full[:, max(0, start - 2) : start]
        if start == 0:
            assert previous is None
        else:
            np.testing.assert_array_equal(previous, expected)
        seen.append(start)
        return state[:, None, :] + np.arange(k + 1)[None, :, None]

    np.testing.assert_array_equal(newton.rollout_in_chunks(run, x, 100, history=2), full)
    assert len(seen) > 3 and seen[1] == 1


def test_warm_start_on_numpy_saves_the_guess_pass(small_pendulum_model):
    """The NumPy reference counts passes as the compiled rollout: the warm start saves a pass per step."""
    sur = small_pendulum_model.surrogate_
    x, mu = _queries(7, 8)
    dt = np.full(8, 0.05)
    w = sur.weights(mu[:, None], dt)
    passes = {}
    for warm in (False, True):
        stats = {}
        newton.implicit_rollout(sur, x, w, dt, 20, 50, warm_start=warm, stats=stats)
        passes[warm] = stats["passes"]
    assert np.all(passes[True] < passes[False])


# ------------------------------------------------------------------ the estimate is free on success
def test_the_estimate_costs_no_pass_on_success(small_pendulum_data, monkeypatch):
    """Successful rollouts: the same passes over the centres on both paths, no contraction estimate."""
    calls = []
    real = newton.contraction_estimate
    monkeypatch.setattr(newton, "contraction_estimate", lambda *a, **k: calls.append(1) or real(*a, **k))
    model = _fit(small_pendulum_data, dt_kernel=IMQ(5.0), max_centers=50)
    sur = model.surrogate_
    x, mu = _queries(8, 16)
    dt = np.full(16, 0.05)
    w = sur.weights(mu[:, None], dt)
    for warm in (False, True):
        stats = {"numpy": {}, "numba": {}}
        for backend in newton.BACKENDS:
            newton.implicit_rollout(sur, x, w, dt, 20, 50, backend=backend, warm_start=warm, stats=stats[backend])
        np.testing.assert_array_equal(stats["numba"]["passes"], stats["numpy"]["passes"])
        # the explicit guess (warm: at the first step only) and about three Newton passes per step
        assert stats["numba"]["passes"].max() <= (20 * 3 + 1 if warm else 20 * 4)
    assert calls == []
    with extrapolation_expected(), pytest.raises(NewtonConvergenceError):
        newton.implicit_rollout(sur, x, w, dt * 200, 20, 50, backend="numba")
    assert calls == [1]  # once, for the failure report


# ------------------------------------------------------------------ the report's rule
def test_failure_report_rule():
    """Earliest macro step, then earliest iteration, then reason 1 before 2 before 3; the estimate at that step."""
    codes = np.array([0, 3, 2, 1, 3, 1, 2])
    fail_step = np.array([-1, 4, 4, 5, 4, 4, 4])
    fail_iter = np.array([-1, 50, 7, 2, 50, 7, 9])
    resid = np.arange(7.0)
    seen = []

    def estimate(instances, step):
        seen.append((list(instances), step))
        return np.full(len(instances), 0.5)

    err = newton.failure_error(codes, fail_step, fail_iter, resid, 50, False, estimate)
    assert err.step == 4 and err.reason == newton.FAILURE_REASONS[1]
    np.testing.assert_array_equal(err.instances, [5])  # iteration 7 at step 4: reason 1 (instance 5) before 2 (2)
    assert seen == [([5], 4)] and "dT*L_S 0.5" in str(err)
    codes[5] = 0
    err = newton.failure_error(codes, fail_step, fail_iter, resid, 50, True, estimate, step_index=False)
    np.testing.assert_array_equal(err.instances, [2])
    assert err.step is None and err.reason == newton.MIDPOINT_FAILURE_REASONS[2]
    codes[[1, 2, 3, 4, 6]] = 0
    assert newton.failure_error(codes, fail_step, fail_iter, resid, 50, False, estimate) is None
    assert err.at_step(3).contraction is not None
