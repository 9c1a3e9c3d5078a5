"""Every trainer's peak memory against its formula, and the bounded active set (BoundedActiveSetStore).

Peak memory is measured with tracemalloc (NumPy reports its allocations there) around the greedy run only;
each formula must bound it with a stated slack and must not be vacuous (the peak is at least a stated
share of it).  The bounded active set is checked against independent oracles: the returned model's
residual evaluated directly (``functional_residuals``), exact interpolation at the selected functionals,
the Cholesky factor against the selected Gramian built column by column; where every point has a slot it
is the blocked greedy (the same code path on the same arrays: bit for bit).
"""

import tracemalloc

import numpy as np
import pytest

from sympredict.interpolation.functionals import HBFunctionals, functional_residuals
from sympredict.interpolation.greedy import (
    ActiveSetGreedy,
    BlockedStore,
    BoundedActiveSetGreedy,
    BoundedActiveSetStore,
    DenseStore,
    ExactGreedy,
    available_memory,
    run_greedy,
    trainer_memory,
)
from sympredict.interpolation.greedy.active_set import bounded_capacity, bounded_memory, refresh_chunk
from sympredict.kernels import IMQ, ProductKernel
from _surrogate_oracles import gram_oracle  # tests/


def _problem(seed, m_points=1500, dim=8, n_mu=60):
    """An 8-D state-derivative problem: ``n_mu`` parameter values (trajectories), smooth targets."""
    rng = np.random.default_rng(seed)
    xi = rng.uniform(-2, 2, size=(m_points, dim))
    mu = np.repeat(rng.uniform(0.5, 1.5, size=(n_mu, 1)), -(-m_points // n_mu), axis=0)[:m_points]
    dt = np.full(m_points, 0.1)
    y = -np.sin(xi) * mu + 0.2 * xi * (xi**2).sum(axis=1, keepdims=True)
    return HBFunctionals(ProductKernel(IMQ(0.5), IMQ(1.0)), xi, mu, dt), y.ravel()


def _peak(fn):
    tracemalloc.start()
    try:
        out = fn()
        return out, tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_exact_greedy_peak_within_its_formula():
    """``8 m (N + N_val)``: the basis; slack: O(N) vectors and the m x m factor."""
    fun, y = _problem(0, m_points=2000)
    n, m = fun.n_functionals, 300
    ExactGreedy().run(fun, y, max_centers=5)  # compiled passes compiled outside the measurement
    _, peak = _peak(lambda: ExactGreedy().run(fun, y, max_centers=m))
    formula = trainer_memory(ExactGreedy(), n, 0, m)
    assert formula == 8 * m * n
    assert 0.9 * formula <= peak <= formula + 8 * (10 * n + 2 * m * m), (peak, formula)


def test_active_set_greedy_peak_within_its_bound():
    """``8 m (N_S + N_val)`` with ``N_S`` the bound of every refresh adding ``max_new_points``; slack: the doubling copy."""
    fun, y = _problem(1, m_points=3000)
    n, m = fun.n_functionals, 200
    trainer = ActiveSetGreedy(initial_points=300, refresh_every=50, max_new_points=200, tol=0)
    _, peak = _peak(lambda: trainer.run(fun, y, max_centers=m))
    bound = trainer_memory(trainer, n, 0, m, dim=fun.dim)
    first = trainer_memory(trainer, n, 0, m, dim=fun.dim, initial=True)
    assert first <= peak <= 3 * bound + 8 * (10 * n + 2 * m * m), (peak, first, bound)


@pytest.mark.parametrize("points", [250, 1000])
def test_bounded_peak_within_its_formula(points):
    """The formula counts everything the run allocates (store, refreshes, the loop's factor): peak <= formula,
    and the formula is not loose by more than the refresh chunk's fixed allowance (peak >= 0.6 formula)."""
    fun, y = _problem(2, m_points=3000)
    n, m = fun.n_functionals, 400
    store = BoundedActiveSetStore(fun, y, tol=0, max_points=points, refresh_every=100, max_new_points=300)
    result, peak = _peak(lambda: run_greedy(store, max_centers=m, tol=0))
    formula = bounded_memory(m, n, 0, points * fun.dim, fun.dim)
    assert result.stats["memory_formula"] == formula and result.stats["refreshes"] >= 2
    assert result.stats["swapped"] > 0
    assert 0.6 * formula <= peak <= formula, (peak, formula)


def test_bounded_trainer_sizes_its_slots_to_the_budget():
    fun, y = _problem(3, m_points=3000)
    n, m, dim = fun.n_functionals, 400, fun.dim
    budget = bounded_memory(m, n, 0, 700 * dim, dim) + 100
    trainer = BoundedActiveSetGreedy(memory_limit=budget, refresh_every=100, tol=0)
    assert trainer.capacity(n, 0, m, dim) == bounded_capacity(budget, m, n, 0, dim) == 700
    assert trainer_memory(trainer, n, 0, m, dim=dim) <= budget < bounded_memory(m, n, 0, 701 * dim, dim)
    result, peak = _peak(lambda: trainer.run(fun, y, max_centers=m))
    assert result.stats["slots"] == 700 * dim and peak <= budget
    # a budget below the fixed part: refused before any work, naming the way out
    with pytest.raises(ValueError, match="cannot hold one point.*fewer centres or raise memory_limit"):
        BoundedActiveSetGreedy(memory_limit=bounded_memory(m, n, 0, 0, dim) // 2).run(fun, y, max_centers=m)
    with pytest.raises(ValueError, match="max_points <= "):
        run_greedy(BoundedActiveSetStore(fun, y, tol=0, max_points=2000, memory_limit=budget), max_centers=m)


def test_refresh_chunk_bounds_the_rows_buffer():
    for m in (1, 10, 1000, 4000, 10**6):
        k = refresh_chunk(m, 8)
        assert k % 8 == 0 and k >= 8
        assert 8 * m * k <= 2**25 or k == 8


def test_bounded_with_every_point_in_slots_is_the_blocked_greedy():
    fun, y = _problem(4, m_points=600)
    m = 250
    blocked = run_greedy(BlockedStore(fun, y, block_size=32, pool_factor=4, slack=0.5), max_centers=m, tol=0)
    bounded = run_greedy(
        BoundedActiveSetStore(fun, y, tol=0, max_points=600, block_size=32, slack=0.5), max_centers=m, tol=0
    )
    np.testing.assert_array_equal(bounded.selected, blocked.selected)
    np.testing.assert_array_equal(bounded.coef, blocked.coef)
    assert bounded.stats["refreshes"] == 0


def test_bounded_model_interpolates_and_its_residual_is_the_direct_one():
    fun, y = _problem(5, m_points=2500)
    m = 300
    result = run_greedy(
        BoundedActiveSetStore(fun, y, tol=0, max_points=300, refresh_every=64, max_new_points=200), max_centers=m, tol=0
    )
    assert result.stats["swapped"] > 0 and len(result.selected) == m
    r = functional_residuals(fun, y, result.selected, result.coef, compiled=False)
    scale = np.abs(y).max()
    # the final residual of the history is the returned model's, over every candidate
    np.testing.assert_allclose(result.history.train_max_residual[-1], np.abs(r).max(), rtol=1e-9)
    # exact interpolation at the selected functionals, whichever slot (and swap) they came from
    assert np.abs(r[result.selected]).max() <= 1e-8 * scale
    # the Newton values are the Cholesky factor of the selected Gramian
    gram = gram_oracle(fun, result.selected)
    np.testing.assert_allclose(result.chol @ result.chol.T, gram, rtol=0, atol=1e-9 * np.abs(gram).max())


def test_bounded_stops_on_tol_only_over_every_candidate():
    fun, y = _problem(6, m_points=2000)
    full = run_greedy(BoundedActiveSetStore(fun, y, tol=0, max_points=2000), max_centers=400, tol=0)
    tol = float(full.history.train_max_residual[200])  # reachable with a few hundred centres
    result = run_greedy(
        BoundedActiveSetStore(fun, y, tol=tol, max_points=200, refresh_every=64, max_new_points=200),
        max_centers=2000,
        tol=tol,
    )
    assert result.history.stop_reason == "tol"
    r = functional_residuals(fun, y, result.selected, result.coef, compiled=False)
    assert np.abs(r).max() <= tol


@pytest.mark.parametrize("seed", [7, 8])
def test_bounded_accuracy_at_equal_centres_against_the_exact_greedy(seed):
    """A quarter of the points in slots: the mean held-out error (|r| at the functionals of 1,000 other points)
    within 1.1x of the exact greedy's at equal centres (measured 0.75 and 0.86; the max training residual,
    which the f-greedy chases, is 1.35-1.6x with a refresh every 256 centres and within 1.07x every 64)."""
    fun, y = _problem(seed, m_points=3000)
    other, y_other = _problem(seed + 100, m_points=1000)
    both = HBFunctionals(
        fun.kernel,
        np.vstack([fun.points, other.points]),
        np.vstack([fun.mu, other.mu]),
        np.concatenate([fun.dt, other.dt]),
    )
    m = 400

    def held_out(result):
        r = functional_residuals(both, np.concatenate([y, y_other]), result.selected, result.coef)
        return np.abs(r[len(y) :]).mean()

    exact = held_out(run_greedy(DenseStore(fun, y), max_centers=m, tol=0))
    bounded = held_out(run_greedy(BoundedActiveSetStore(fun, y, tol=0, max_points=750), max_centers=m, tol=0))
    print(f"held-out error bounded / exact at {m} centres: {bounded / exact:.3f}")
    assert bounded <= 1.1 * exact, (bounded, exact)


def test_memory_from_the_environment(monkeypatch):
    monkeypatch.setenv("SYMPREDICT_MEMORY", "2G")
    assert available_memory() == 2 * 2**30
    monkeypatch.setenv("SYMPREDICT_MEMORY", "123456789")
    assert available_memory() == 123456789
    for bad in ("lots", "-1G", "0", "nanM"):
        monkeypatch.setenv("SYMPREDICT_MEMORY", bad)
        with pytest.raises(ValueError, match="SYMPREDICT_MEMORY must be a positive number of bytes"):
            available_memory()
    monkeypatch.delenv("SYMPREDICT_MEMORY")
    assert available_memory() > 0


def test_bounded_trainer_refuses_what_it_cannot_run():
    from sympredict.interpolation.functionals import ValueFunctionals

    fun, y = _problem(8, m_points=50, dim=2)
    vfun = ValueFunctionals(fun.kernel, fun.points, fun.mu, fun.dt)
    with pytest.raises(ValueError, match="state-derivative functionals.*BlockedGreedy"):
        BoundedActiveSetGreedy().run(vfun, y[:50], max_centers=10)
    with pytest.raises(ValueError, match="max_points must be a positive integer"):
        BoundedActiveSetStore(fun, y, tol=0, max_points=0)
    with pytest.raises(ValueError, match="one output"):
        BoundedActiveSetStore(fun, np.column_stack([y, y]), tol=0)


def test_estimator_with_the_bounded_trainer_validation_and_spec_round_trip(small_pendulum_data, tmp_path):
    from sympredict import SymplecticKernelPredictor
    from sympredict.base import clone
    from sympredict.interpolation.greedy import trainer_from_spec
    from sympredict.kernels import IMQ as IMQKernel

    d = small_pendulum_data
    n_points = len(d.x0) - 40
    n = 2 * n_points  # the pendulum's 2-D state
    budget = bounded_memory(120, n, 80, 100 * 2, 2, 16, 3)  # 100 points in the slots
    trainer = BoundedActiveSetGreedy(
        block_size=16, pool_factor=3, refresh_every=32, max_new_points=50, tol=1e-9, memory_limit=budget
    )
    assert trainer_from_spec(trainer.spec) == trainer
    model = SymplecticKernelPredictor(
        IMQKernel(0.15), mu_kernel=IMQKernel(2.0), dt_kernel=IMQKernel(5.0), max_centers=120, trainer=trainer
    )
    model.fit(
        d.x0[:n_points],
        d.x1[:n_points],
        mu=d.mu[:n_points],
        dt=d.dt[:n_points],
        validation=(d.x0[n_points:], d.x1[n_points:], d.mu[n_points:], d.dt[n_points:]),
    )
    stats = model.greedy_result_.stats
    assert stats["slots"] == 200 < n and stats["refreshes"] >= 2 and model.surrogate_.n_centers == 120
    h = model.history_
    assert h.val_max_residual is not None and len(h.val_max_residual) == 121
    model.save(tmp_path / "b.h5")
    back = SymplecticKernelPredictor.load(tmp_path / "b.h5")
    assert back.trainer == trainer and clone(back).trainer == trainer
