"""Regularized (ridge) HB interpolation in the greedy: the Newton basis of G + lambda I, and lambda on validation data."""

import warnings

import numpy as np
import pytest
from pymor.parallel.dummy import dummy_pool

from sympredict import SymplecticKernelPredictor
from sympredict._numba import HAVE_NUMBA
from sympredict.exceptions import ExtrapolationWarning
from sympredict.base import clone
from sympredict.data import FlowMapData, mixed_variables
from sympredict.interpolation.functionals import HBFunctionals
from sympredict.interpolation.greedy import (
    ActiveSetGreedy,
    DenseStore,
    ExactGreedy,
    ShardedGreedy,
    greedy_interpolation,
    run_greedy,
)
from sympredict.io import load_model, save_model
from sympredict.kernels import IMQ, ProductKernel
from sympredict.estimators.selection import select_regularization


def _subset(d, n, seed=0):
    idx = np.random.default_rng(seed).choice(len(d), n, replace=False)
    return d.subset(idx)


def _functionals(d):
    xi, y = mixed_variables(d.x0, d.x1, d.dt)
    kernel = ProductKernel(IMQ(0.3), IMQ(2.0), IMQ(5.0))
    return HBFunctionals(kernel, xi, d.mu, d.dt), y.reshape(-1)


def _gram(f):
    n = f.n_functionals
    gram = np.empty((n, n))
    for j in range(n):
        f.column(f.representer(j), out=gram[:, j])
    return 0.5 * (gram + gram.T)


@pytest.mark.parametrize("compiled", [False, True] if HAVE_NUMBA else [False])
@pytest.mark.parametrize("lam", [1e-6, 1e-2])
def test_all_centres_solve_the_ridge_system(small_pendulum_data, lam, compiled):
    """Every functional selected: c solves (G + lambda I) c = y (a dense Cholesky solve as the oracle)."""
    f, y = _functionals(_subset(small_pendulum_data, 40))
    store = DenseStore(f, y, regularization=lam, compiled=compiled, power_tol=0.0)
    res = run_greedy(store, max_centers=f.n_functionals, tol=0.0)
    assert res.history.stop_reason == "exhausted"
    order = np.argsort(res.selected)
    c = np.empty(f.n_functionals)
    c[res.selected] = res.coef
    gram = _gram(f)
    ref = np.linalg.solve(gram + lam * np.eye(len(y)), y)
    np.testing.assert_allclose(c, ref, rtol=1e-7, atol=1e-9 * np.abs(ref).max())
    assert len(order) == f.n_functionals


def test_partial_greedy_is_ridge_on_its_centres_and_validation_is_the_models_residual(small_pendulum_data):
    d = _subset(small_pendulum_data, 120)
    train, val = d.subset(np.arange(90)), d.subset(np.arange(90, 120))
    f, y = _functionals(train)
    fv, yv = _functionals(val)
    lam = 1e-4
    res = greedy_interpolation(f, y, max_centers=60, tol=0.0, validation=(fv, yv), regularization=lam)
    sel = res.selected
    gram = _gram(f)
    sub = gram[np.ix_(sel, sel)]
    np.testing.assert_allclose(
        (sub + lam * np.eye(len(sel))) @ res.coef, y[sel], rtol=1e-8, atol=1e-8 * np.abs(y).max()
    )
    # the model's residual at a centre is lambda c_j (not 0); elsewhere the greedy's residual is the model's
    model_res = y - gram[:, sel] @ res.coef
    np.testing.assert_allclose(model_res[sel], lam * res.coef, rtol=1e-6, atol=1e-10)
    # the validation curve is the residual of s itself (no lambda at functionals that are not centres)
    gv = np.empty((fv.n_functionals, len(sel)))
    for k, j in enumerate(sel):
        fv.column(f.representer(j), out=gv[:, k])
    assert np.isclose(res.history.val_max_residual[-1], np.abs(yv - gv @ res.coef).max(), rtol=1e-8)
    # a prefix of the expansion is the ridge fit on the first m centres
    m = 25
    np.testing.assert_allclose(
        (gram[np.ix_(sel[:m], sel[:m])] + lam * np.eye(m)) @ res.coef_prefix(m),
        y[sel[:m]],
        rtol=1e-8,
        atol=1e-8 * np.abs(y).max(),
    )


def test_zero_regularization_is_the_exact_fit_bit_for_bit(small_pendulum_data):
    d = _subset(small_pendulum_data, 300)
    base = SymplecticKernelPredictor(IMQ(0.3), IMQ(2.0), IMQ(5.0), max_centers=150, trainer=ExactGreedy(tol=0.0)).fit(
        d.x0, d.x1, mu=d.mu, dt=d.dt
    )
    zero = SymplecticKernelPredictor(
        IMQ(0.3), IMQ(2.0), IMQ(5.0), max_centers=150, trainer=ExactGreedy(tol=0.0, regularization=0.0)
    ).fit(d.x0, d.x1, mu=d.mu, dt=d.dt)
    f, y = _functionals(d)
    direct = greedy_interpolation(f, y, max_centers=150, tol=0.0)  # the store without the option
    for other in (zero.greedy_result_, direct):
        assert np.array_equal(base.greedy_result_.selected, other.selected)
        assert np.array_equal(base.greedy_result_.coef, other.coef)
    assert np.array_equal(base.history_.train_max_residual, zero.history_.train_max_residual)
    # and a positive lambda does change the fit
    reg = SymplecticKernelPredictor(
        IMQ(0.3), IMQ(2.0), IMQ(5.0), max_centers=150, trainer=ExactGreedy(tol=0.0, regularization=1e-3)
    ).fit(d.x0, d.x1, mu=d.mu, dt=d.dt)
    assert not np.array_equal(base.greedy_result_.coef, reg.greedy_result_.coef)


def test_sharded_and_float32_stores_regularize_like_the_dense_one(small_pendulum_data):
    d = _subset(small_pendulum_data, 200)
    f, y = _functionals(d)
    lam = 1e-3
    dense = greedy_interpolation(f, y, max_centers=80, tol=0.0, regularization=lam)
    from sympredict.interpolation.greedy import sharded_greedy

    sharded = sharded_greedy(f, y, max_centers=80, tol=0.0, pool=dummy_pool, n_shards=3, regularization=lam)
    assert np.array_equal(dense.selected, sharded.selected)
    np.testing.assert_allclose(sharded.coef, dense.coef, rtol=1e-12, atol=1e-12 * np.abs(dense.coef).max())
    single = greedy_interpolation(f, y, max_centers=40, tol=0.0, regularization=lam, basis_dtype="float32")
    assert np.array_equal(single.selected[:10], dense.selected[:10])


def test_estimator_parameter_checked_stored_and_refused_where_unsupported(small_pendulum_data, tmp_path):
    d = _subset(small_pendulum_data, 100)
    for bad in (-1.0, float("nan"), "1e-3", True):
        with pytest.raises(ValueError, match="regularization"):
            SymplecticKernelPredictor(IMQ(0.3), IMQ(2.0), IMQ(5.0), trainer=ExactGreedy(regularization=bad)).fit(
                d.x0, d.x1, mu=d.mu, dt=d.dt
            )
    with pytest.raises(TypeError, match="regularization"):  # the active set has no regularized store: no such setting
        ActiveSetGreedy(regularization=1e-3)
    model = SymplecticKernelPredictor(
        IMQ(0.3), IMQ(2.0), IMQ(5.0), max_centers=50, trainer=ShardedGreedy(n_shards=2, regularization=2.5e-4)
    ).fit(d.x0, d.x1, mu=d.mu, dt=d.dt)
    save_model(model, tmp_path / "m.h5")
    loaded = load_model(tmp_path / "m.h5")
    assert loaded.trainer.regularization == 2.5e-4
    x = d.x0[:5]
    np.testing.assert_array_equal(loaded.step(x, mu=d.mu[:5], dt=d.dt[:5]), model.step(x, mu=d.mu[:5], dt=d.dt[:5]))
    assert ExactGreedy(regularization=0.1).store(*_functionals(d), tol=0.0, validation=None).regularization == 0.1


def test_lambda_chosen_on_noisy_validation_data_beats_the_exact_fit(small_pendulum_data):
    """With 1e-2 relative noise on the increments the exact fit interpolates noise; the chosen lambda does better."""
    d = _subset(small_pendulum_data, 600, seed=1)
    rng = np.random.default_rng(7)
    noisy = FlowMapData(d.x0, d.x0 + (d.x1 - d.x0) * (1 + 1e-2 * rng.standard_normal(d.x0.shape)), d.mu, d.dt)
    train, val = noisy.subset(np.arange(450)), noisy.subset(np.arange(450, 600))
    est = SymplecticKernelPredictor(IMQ(0.3), IMQ(2.0), IMQ(5.0), max_centers=400, trainer=ExactGreedy(tol=0.0))
    out = select_regularization(train, val, [1e-6, 1e-4, 1e-2], est)
    scores = {row["regularization"]: row["score"] for row in out.table}
    assert set(scores) == {0.0, 1e-6, 1e-4, 1e-2}
    assert out.score == min(scores.values()) and out.regularization > 0
    assert out.score < 0.9 * scores[0.0]
    # the clean targets are recovered better too (an oracle the selection never saw)
    exact = SymplecticKernelPredictor(IMQ(0.3), IMQ(2.0), IMQ(5.0), max_centers=400, trainer=ExactGreedy(tol=0.0)).fit(
        train.x0, train.x1, mu=train.mu, dt=train.dt
    )
    reg = (
        clone(est)
        .set_params(trainer__regularization=out.regularization)
        .fit(train.x0, train.x1, mu=train.mu, dt=train.dt)
    )
    clean = d.subset(np.arange(450, 600))
    xi, y = mixed_variables(clean.x0, clean.x1, clean.dt)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ExtrapolationWarning)
        err = [np.sqrt(np.mean((m.surrogate_gradient(xi, mu=clean.mu, dt=clean.dt) - y) ** 2)) for m in (exact, reg)]
    assert err[1] < err[0]
    with pytest.raises(ValueError, match="metric"):
        select_regularization(train, val, [1e-3], est, metric="mean")
