"""Warm-started compiled Newton rollout: the previous step's increment as the first guess."""

import copy

import numpy as np
import pytest

from sympredict import _numba
from sympredict.symplectic import _compiled_newton
from sympredict_paper.pendulum import paper_test_instances
from _tolerances import newton_step_bound  # tests/

pytestmark = pytest.mark.skipif(not _numba.HAVE_NUMBA, reason="the compiled rollout needs numba (optional extra)")


def test_warm_start_saves_passes_and_solves_the_same_equation(small_pendulum_model):
    model = small_pendulum_model
    sur = model.surrogate_
    x0, lengths = paper_test_instances(0)
    dt = np.full(len(x0), 0.05)
    w = sur.weights(lengths[:, None], dt)
    runs = {}
    for warm in (False, True):
        stats = {}
        traj, codes, *_ = _compiled_newton.newton_rollout(
            x0, w, dt, sur.layout(), sur.kernel.state, 50, 200, stats=stats, warm_start=warm
        )
        assert np.all(codes == 0)
        runs[warm] = (traj, stats["passes"])
    (cold, p_cold), (warm, p_warm) = runs[False], runs[True]
    np.testing.assert_array_equal(cold[:, :2], warm[:, :2])  # the first step has no previous increment
    assert p_warm.sum() < 0.9 * p_cold.sum()
    # every warm step solves the implicit equation p1 = p0 - dT d_q s(q0, p1) (NumPy gradient as the oracle)
    a, b = warm[:, :-1].reshape(-1, 2), warm[:, 1:].reshape(-1, 2)
    ww = np.repeat(w, 200, axis=0)
    xi = np.column_stack([a[:, 0], b[:, 1]])
    g = sur.gradient(xi, ww)
    # within what Newton's stopping rule lets a converged iterate miss the equation by (not a fixed number:
    # compiled code built for another CPU, with or without FMA, stops at another point inside it)
    bound = newton_step_bound(sur, xi, ww, 0.05)
    assert np.all(np.abs(b[:, 1] - (a[:, 1] - 0.05 * g[:, 0])) <= bound)
    assert np.all(np.abs(b[:, 0] - (a[:, 0] + 0.05 * g[:, 1])) <= bound + 4 * np.finfo(float).eps * np.abs(b[:, 0]))
    assert bound.max() < 1e-5  # far below a wrong equation's miss (dT |grad s| ~ 1e-2); coefficients ~3e7 set the floor
    np.testing.assert_allclose(warm, cold, atol=1e-6)


def test_estimator_option(small_pendulum_model, tmp_path):
    from sympredict.base import clone
    from sympredict.io import load_model, save_model

    model = small_pendulum_model
    warm = copy.copy(model).set_params(solver__warm_start=True)  # the fitted model, its solver a changed copy
    assert model.solver is None or model.solver.warm_start is False
    x0, lengths = paper_test_instances(0)
    a = model.rollout(x0, 100, mu=lengths, dt=0.05)
    b = warm.rollout(x0, 100, mu=lengths, dt=0.05)
    np.testing.assert_allclose(b, a, atol=1e-7)
    assert not np.array_equal(a, b)  # the option is used
    save_model(warm, tmp_path / "w.h5")
    assert load_model(tmp_path / "w.h5").solver.warm_start is True
    with pytest.raises(ValueError, match="warm_start"):
        clone(model).set_params(solver__warm_start="yes", max_centers=5).fit(x0, x0, mu=lengths, dt=0.05)
