"""Newton's watchdog: full steps while the residual improves, a restart from the best iterate otherwise, alike on
both backends."""

import numpy as np
import pytest


# --------------------------------------------------------------------------- Newton with a watchdog
def test_watchdog_rule_on_synthetic_values():
    from sympredict.newton_rule import MIN_FRACTION, accepted

    inf, nan = float("inf"), float("nan")
    merit = np.array([5.0, 5.0, 4.0, nan, 5.0, 1e-20, nan])
    best = np.array([inf, 4.0, 5.0, 5.0, 4.0, 1e-21, inf])
    fraction = np.array([1.0, 1.0, 1.0, 0.5, MIN_FRACTION, 1.0, 1.0])
    f_norm, f_floor = merit, np.full(7, 1e-18)
    np.testing.assert_array_equal(
        accepted(merit, best, fraction, f_norm, f_floor), [True, False, True, False, True, True, True]
    )


@pytest.mark.paths
def test_ordinary_steps_take_the_plain_newton_iterates(small_pendulum_model, monkeypatch):
    """Where every iterate improves (ordinary steps), the watchdog never acts: the rollout is bit-identical to the
    plain Newton iteration (the rule replaced by one that accepts everything), on the NumPy path."""
    import copy

    from sympredict.symplectic import newton

    rng = np.random.default_rng(3)
    x = np.column_stack([rng.uniform(-0.5, 0.5, 16), rng.uniform(-0.3, 0.3, 16)])
    mu = rng.uniform(0.71, 0.79, 16)
    model = copy.copy(small_pendulum_model).set_params(solver__backend="numpy")
    watched = model.rollout(x, 20, mu=mu, dt=0.05)
    monkeypatch.setattr(newton, "accepted", lambda merit, *args: np.ones(np.shape(merit), dtype=bool))
    np.testing.assert_array_equal(model.rollout(x, 20, mu=mu, dt=0.05), watched)


@pytest.mark.paths
def test_a_cycling_newton_is_restarted_alike_on_both_backends(small_pendulum_data):
    """Far steps (dT = 1.0 on a model trained at 0.04..0.06): for most single instances both backends report the
    same outcome (converged, or the same failing step), unchanged under relative perturbations 1e-14 and 1e-11."""
    import copy
    import warnings

    from sympredict import NewtonConvergenceError
    from sympredict.exceptions import ExtrapolationWarning
    from sympredict.interpolation.greedy import ExactGreedy
    from sympredict.kernels import IMQ

    from sympredict import SymplecticKernelPredictor

    d = small_pendulum_data
    model = SymplecticKernelPredictor(
        IMQ(0.15), mu_kernel=IMQ(2.0), dt_kernel=IMQ(0.2), max_centers=60, trainer=ExactGreedy(tol=1e-10)
    ).fit(d.x0, d.x1, mu=d.mu, dt=d.dt)
    rng = np.random.default_rng(0)
    x = np.column_stack([rng.uniform(0.0, np.pi / 2, 20), rng.uniform(-0.5, 0.5, 20)])
    mu = rng.uniform(0.71, 0.79, 20)

    def outcome(backend, xs, i):
        m = copy.copy(model).set_params(solver__backend=backend)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", ExtrapolationWarning)
                m.rollout(xs[i : i + 1], 20, mu=mu[i : i + 1], dt=1.0)
            return -1
        except NewtonConvergenceError as exc:
            return exc.step

    stable = 0
    for i in range(6):
        per = {rel: [outcome(b, x * (1 + rel), i) for b in ("numpy", "numba")] for rel in (0.0, 1e-14, 1e-11)}
        stable += len({v for pair in per.values() for v in pair}) == 1  # one outcome, backends and perturbations
    assert stable >= 4


@pytest.mark.paths
def test_far_steps_fail_or_converge_alike_on_both_backends(small_pendulum_data):
    """A model trained at dT 0.04..0.06 asked for dT = 1.0 (20 states, 50 steps): Newton is at the edge of
    converging there, and both backends must end alike (converged, or failed at the same macro step and instances).
    With a watchdog of 8 passes (full Newton steps for 8 passes without improving ``|F|_2``) and a damped iterate
    taken without decrease after 6 halvings, the compiled rollout failed at macro step 28 on instance 7 and NumPy's
    at step 15 on instance 2 under NUMBA_CPU_NAME=generic; with 3 passes and a line search that takes no iterate
    without decrease the iterates do not wander far enough for round-off to decide."""
    import copy
    import warnings

    from sympredict import NewtonConvergenceError, SymplecticKernelPredictor
    from sympredict.exceptions import ExtrapolationWarning
    from sympredict.interpolation.greedy import ExactGreedy
    from sympredict.kernels import IMQ

    d = small_pendulum_data
    model = SymplecticKernelPredictor(
        IMQ(0.15), mu_kernel=IMQ(2.0), dt_kernel=IMQ(0.2), max_centers=60, trainer=ExactGreedy(tol=1e-10)
    ).fit(d.x0, d.x1, mu=d.mu, dt=d.dt)
    rng = np.random.default_rng(0)  # the far-step study's states (sympredict_paper/studies/far_step_newton.py)
    x = np.column_stack([rng.uniform(0.0, np.pi / 2, 20), rng.uniform(-0.5, 0.5, 20)])
    mu = rng.uniform(0.71, 0.79, 20)

    def outcome(backend):
        m = copy.copy(model).set_params(solver__backend=backend)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", ExtrapolationWarning)
                return "converged", m.rollout(x, 50, mu=mu, dt=1.0)
        except NewtonConvergenceError as exc:
            return (exc.step, [int(i) for i in exc.instances]), None

    (numpy_end, numpy_traj), (numba_end, numba_traj) = outcome("numpy"), outcome("numba")
    assert numpy_end == numba_end
    if numpy_traj is not None:  # the first step from the same states: the same root (later steps start from states
        # that differ by round-off, which steps of this size about double per step)
        np.testing.assert_allclose(numba_traj[:, 1], numpy_traj[:, 1], rtol=0, atol=1e-8)
