"""The blocked greedy (BlockedStore / BlockedGreedy) against the exact greedy and against independent oracles.

Oracles: exact interpolation at the selected functionals (the surrogate's gradient re-evaluated), the
Cholesky factor against the selected Gramian built column by column, the residual history against directly
recomputed residuals; the exact greedy's selection for ``block_size=1`` and ``slack=0`` (two code paths of
one selection: ``paths`` marker); held-out error per centre against the exact greedy's.
"""

import tracemalloc

import numpy as np
import pytest

from sympredict import SymplecticKernelPredictor
from sympredict.base import clone
from sympredict.interpolation.functionals import HBFunctionals, ValueFunctionals
from sympredict.interpolation.greedy import (
    BlockedGreedy,
    BlockedStore,
    DenseStore,
    ExactGreedy,
    run_greedy,
    trainer_from_spec,
    trainer_memory,
)
from sympredict.interpolation.greedy.blocked import blocked_memory, pool_gramian
from sympredict.interpolation.surrogate import HBSurrogate
from sympredict.kernels import IMQ, Matern52, ProductKernel
from _surrogate_oracles import gram_oracle  # tests/

pytestmark = pytest.mark.paths


def _problem(seed, m_points=400, dim=4, kernel=None):
    rng = np.random.default_rng(seed)
    xi = rng.uniform(-2, 2, size=(m_points, dim))
    mu = rng.uniform(0.5, 1.5, size=(m_points, 1))
    dt = np.full(m_points, 0.1)
    # gradient of the generating function s = mu sum cos(xi) + 0.05 |xi|^4
    y = -np.sin(xi) * mu + 0.2 * xi * (xi**2).sum(axis=1, keepdims=True)
    kernel = kernel or ProductKernel(IMQ(0.5), IMQ(1.0))
    return HBFunctionals(kernel, xi, mu, dt), xi, mu, dt, y.ravel()


@pytest.mark.parametrize("criterion", ["f", "p"])
def test_block_size_one_selects_as_the_exact_greedy(criterion):
    fun, *_, y = _problem(0, m_points=150)
    exact = run_greedy(
        DenseStore(fun, y, criterion=criterion, compiled=False), max_centers=120, tol=0, criterion=criterion
    )
    blocked = run_greedy(
        BlockedStore(fun, y, criterion=criterion, block_size=1), max_centers=120, tol=0, criterion=criterion
    )
    np.testing.assert_array_equal(blocked.selected, exact.selected)
    scale = np.abs(y).max()
    np.testing.assert_allclose(
        blocked.history.train_max_residual, exact.history.train_max_residual, rtol=1e-6, atol=1e-9 * scale
    )
    np.testing.assert_allclose(blocked.chol, exact.chol, rtol=0, atol=1e-9 * np.abs(exact.chol).max())


def test_zero_slack_selects_as_the_exact_greedy_with_blocks():
    fun, *_, y = _problem(1, m_points=150)
    exact = run_greedy(DenseStore(fun, y, compiled=False), max_centers=150, tol=0)
    store = BlockedStore(fun, y, block_size=16, slack=0.0)
    blocked = run_greedy(store, max_centers=150, tol=0)
    np.testing.assert_array_equal(blocked.selected, exact.selected)
    assert max(store.stats["block_sizes"]) > 1  # blocks of several centres did run


@pytest.mark.parametrize("block_size", [7, 32])
def test_blocked_newton_basis_interpolates_and_its_factor_is_the_gramians(block_size):
    fun, xi, mu, dt, y = _problem(2)
    vfun, vxi, vmu, vdt, vy = _problem(3, m_points=100)
    store = BlockedStore(fun, y, block_size=block_size, validation=(vfun, vy))
    res = run_greedy(store, max_centers=200, tol=0)
    m = len(res.selected)
    assert m == 200 and store.stats["blocks"] < 200 and len(set(res.selected.tolist())) == m
    # the Cholesky factor of the selected Gramian, against the Gramian built column by column
    gram = gram_oracle(fun, res.selected)
    np.testing.assert_allclose(res.chol @ res.chol.T, gram, rtol=0, atol=1e-10 * np.abs(gram).max())
    assert np.allclose(res.chol, np.tril(res.chol))
    # exact interpolation at the selected functionals, re-evaluated by the surrogate
    p, a = np.divmod(res.selected, xi.shape[1])
    sur = HBSurrogate(fun.kernel, xi[p], mu[p], dt[p], a, res.coef)
    grad = sur.gradient(xi, sur.weights(mu, dt)).ravel()
    scale = np.abs(y).max()
    np.testing.assert_allclose(grad[res.selected], y[res.selected], rtol=0, atol=1e-8 * scale)
    # the residual history is that of the returned model, on the training and the validation functionals
    assert res.history.train_max_residual[-1] == pytest.approx(np.abs(grad - y).max(), rel=1e-6)
    vgrad = sur.gradient(vxi, sur.weights(vmu, vdt)).ravel()
    assert res.history.val_max_residual[-1] == pytest.approx(np.abs(vgrad - vy).max(), rel=1e-6)
    assert len(res.history.train_max_residual) == m + 1 == len(res.history.val_max_residual)
    # every prefix is an interpolant (truncation works as for the exact greedy)
    c = res.coef_prefix(77)
    sur77 = HBSurrogate(fun.kernel, xi[p[:77]], mu[p[:77]], dt[p[:77]], a[:77], c)
    g77 = sur77.gradient(xi, sur77.weights(mu, dt)).ravel()
    np.testing.assert_allclose(g77[res.selected[:77]], y[res.selected[:77]], rtol=0, atol=1e-8 * scale)


def test_pool_gramian_matches_columns():
    fun, *_ = _problem(4, m_points=60)
    pool = np.array([5, 17, 3, 200, 201, 239])
    np.testing.assert_allclose(pool_gramian(fun, pool), gram_oracle(fun, pool), rtol=1e-13, atol=1e-13)
    vf = ValueFunctionals(ProductKernel(IMQ(0.5), IMQ(1.0)), fun.points, fun.mu, fun.dt)
    vpool = np.array([5, 17, 3, 40])
    expected = np.array([[vf.column(vf.representer(j), np.empty(60))[i] for j in vpool] for i in vpool])
    np.testing.assert_allclose(pool_gramian(vf, vpool), expected, rtol=1e-13, atol=1e-13)


@pytest.mark.parametrize(
    "kernel", [ProductKernel(IMQ(0.5), IMQ(1.0)), ProductKernel(Matern52(0.7), Matern52(1.0))], ids=["imq", "matern52"]
)
def test_held_out_error_per_centre_within_ten_percent_of_the_exact_greedy(kernel):
    """The blocked greedy's default rule loses at most 10 % of held-out accuracy at the same number of centres."""
    fun, *_, y = _problem(5, m_points=1500, kernel=kernel)
    vfun, *_, vy = _problem(6, m_points=500, kernel=kernel)
    out = {}
    for name, store in (
        ("exact", DenseStore(fun, y, validation=(vfun, vy), compiled=False)),
        ("blocked", BlockedStore(fun, y, validation=(vfun, vy), block_size=64, slack=0.5)),
    ):
        out[name] = run_greedy(store, max_centers=800, tol=0).history.val_max_residual
    for m in (400, 800):
        assert out["blocked"][m] <= 1.1 * out["exact"][m], (m, out["blocked"][m], out["exact"][m])


def test_estimator_with_blocked_trainer_and_spec_round_trip(small_pendulum_data, tmp_path):
    d = small_pendulum_data
    trainer = BlockedGreedy(block_size=16, pool_factor=3, slack=0.25, tol=1e-9)
    assert trainer_from_spec(trainer.spec) == trainer
    model = SymplecticKernelPredictor(
        IMQ(0.15), mu_kernel=IMQ(2.0), dt_kernel=IMQ(5.0), max_centers=120, trainer=trainer
    ).fit(d.x0, d.x1, mu=d.mu, dt=d.dt)
    assert model.surrogate_.n_centers == 120 and model.greedy_result_.stats["blocks"] < 120
    small = model.truncated(50)
    assert small.surrogate_.n_centers == 50
    model.save(tmp_path / "b.h5")
    back = SymplecticKernelPredictor.load(tmp_path / "b.h5")
    assert back.trainer == trainer and clone(back).trainer == trainer


def test_blocked_argument_checks():
    fun, *_, y = _problem(7, m_points=10)
    for bad in (dict(block_size=0), dict(block_size=2.5), dict(pool_factor=0), dict(slack=1.0), dict(slack=-0.1)):
        with pytest.raises(ValueError, match=next(iter(bad))):
            BlockedStore(fun, y, **bad)


def test_memory_formula_bounds_the_measured_peak():
    """The blocked store's arrays stay within its formula (plus its O(N) vectors and the rows' temporaries)."""
    fun, *_, y = _problem(8, m_points=2000)
    n, m, b, c = fun.n_functionals, 300, 32, 4
    store = BlockedStore(fun, y, block_size=b, pool_factor=c)
    tracemalloc.start()
    try:
        run_greedy(store, max_centers=m, tol=0)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    formula = blocked_memory(m, n, 0, b, c)
    assert formula == trainer_memory(BlockedGreedy(block_size=b, pool_factor=c), n, 0, m)
    vectors = 8 * n * 8  # residual, |r|, P2, the score and a few O(N) temporaries
    rows_temporaries = 8 * b * 1024 * (3 * fun.dim + 8)
    assert 0.9 * formula <= peak <= formula + vectors + rows_temporaries + 8 * m * m, (peak, formula)
    assert trainer_memory(ExactGreedy(), n, 0, m) == 8 * m * n


def test_default_trainer_picks_what_fits_the_memory_and_logs_it(caplog):
    from sympredict.interpolation.greedy import default_trainer

    fun, *_ = _problem(9, m_points=1000)  # N = 4,000 functionals
    n, m = fun.n_functionals, 500
    exact = 8 * m * n
    with caplog.at_level("INFO", logger="sympredict"):
        assert type(default_trainer(fun, 0, m, memory=2 * exact)) is ExactGreedy
        assert "ExactGreedy" in caplog.text
    from sympredict.interpolation.greedy import trainers

    old = trainers.BLOCKED_ABOVE_BYTES
    trainers.BLOCKED_ABOVE_BYTES = exact // 2  # a basis above the threshold: the blocked greedy
    try:
        assert type(default_trainer(fun, 0, m, memory=2 * exact)) is BlockedGreedy
    finally:
        trainers.BLOCKED_ABOVE_BYTES = old
    # neither full basis fits: the bounded active set, its whole peak (formula) within half of the memory
    from sympredict.interpolation.greedy import BoundedActiveSetGreedy
    from sympredict.interpolation.greedy.active_set import bounded_memory

    big, *_ = _problem(9, m_points=120000)  # 480,000 functionals
    n_big = big.n_functionals
    memory = 0.5 * trainer_memory(ExactGreedy(), n_big, 0, m)
    caplog.clear()
    with caplog.at_level("INFO", logger="sympredict"):
        chosen = default_trainer(big, 0, m, memory=memory)
    assert type(chosen) is BoundedActiveSetGreedy and chosen.memory_limit == 0.5 * memory
    points = chosen.capacity(n_big, 0, m, big.dim)
    assert 0 < points < len(big.points)
    need = trainer_memory(chosen, n_big, 0, m, dim=big.dim)
    assert need == bounded_memory(m, n_big, 0, points * big.dim, big.dim) <= 0.5 * memory
    assert bounded_memory(m, n_big, 0, (points + 1) * big.dim, big.dim) > 0.5 * memory  # the largest that fits
    assert "trainer: BoundedActiveSetGreedy" in caplog.text and f"{points} of 120000 points" in caplog.text
    # not even the bounded set's fixed part fits: the exact greedy, whose check says what does
    tiny = 0.5 * bounded_memory(m, n_big, 0, 0, big.dim)
    assert type(default_trainer(big, 0, m, memory=tiny)) is ExactGreedy


@pytest.mark.parametrize("dim", [2, 4, 6])
def test_compiled_gramian_rows_match_numpy(dim):
    from sympredict.interpolation.greedy import _compiled as compiled_greedy
    from sympredict.interpolation.greedy.blocked import gram_rows

    for kernel in (
        ProductKernel(IMQ(0.5), IMQ(1.0)),
        ProductKernel(Matern52(0.7), Matern52(1.0), IMQ(3.0)),
        ProductKernel(IMQ(0.5)),
    ):
        fun, xi, mu, dt, y = _problem(10, m_points=300, dim=dim, kernel=kernel)
        if kernel.dt is not None:
            fun = HBFunctionals(kernel, xi, mu, np.linspace(0.05, 0.15, len(xi)))
        if kernel.mu is None:
            fun = HBFunctionals(kernel, xi, np.zeros((len(xi), 0)), dt)
        idx = np.array([0, 7, 55, fun.n_functionals - 1])
        numpy_rows = fun.gram_rows(fun, idx, np.empty((4, fun.n_functionals)))
        compiled = gram_rows(fun, fun, idx, np.empty((4, fun.n_functionals)), compiled=True)
        assert compiled_greedy.hb_rows_supported(kernel)
        np.testing.assert_allclose(compiled, numpy_rows, rtol=1e-13, atol=1e-14 * np.abs(numpy_rows).max())


def test_point_evaluation_functionals_block_size_one_selects_as_the_exact_greedy():
    """The direct model's functionals (no vectorised Gramian rows: column by column) through the blocked store."""
    fun, xi, mu, dt, _ = _problem(11, m_points=200)
    vf = ValueFunctionals(ProductKernel(IMQ(0.5), IMQ(1.0)), xi, mu, dt)
    y = np.cos(xi).sum(axis=1) * mu[:, 0]
    exact = run_greedy(DenseStore(vf, y, compiled=False), max_centers=60, tol=0)
    blocked = run_greedy(BlockedStore(vf, y, block_size=1), max_centers=60, tol=0)
    np.testing.assert_array_equal(blocked.selected, exact.selected)
    many = run_greedy(BlockedStore(vf, y, block_size=16, slack=0.5), max_centers=60, tol=0)
    gram = np.array([vf.column(vf.representer(j), np.empty(200))[many.selected] for j in many.selected]).T
    np.testing.assert_allclose(many.chol @ many.chol.T, gram, rtol=0, atol=1e-10)
