"""Fast paths against their references: compiled Newton (numba) vs NumPy, float32 greedy vs float64.

The NumPy Newton iteration is the reference.  The compiled one sums over the
centres in another order, so the two agree to the round-off floor of the
surrogate's gradient (``eps * sum |terms|``, see ``HBSurrogate.gradient_hessian``):
to 1e-12 on a well-conditioned model, to that floor on an ill-conditioned one,
where the NumPy path does not even agree with itself across batch sizes.

numba is an optional dependency (``sympredict[fast]``); the tests that need it
are skipped with a reason shown by ``-ra`` when it is not installed.
"""

import copy

import numpy as np
import pytest

from sympredict.exceptions import extrapolation_expected
from sympredict import NewtonConvergenceError, SymplecticKernelPredictor
from sympredict import _numba
from sympredict.interpolation import _compiled as compiled_surrogate
from sympredict.interpolation.greedy import _compiled as compiled_greedy
from sympredict.symplectic import _compiled_newton
from sympredict.interpolation.functionals import HBFunctionals
from sympredict.interpolation.greedy import ActiveSetGreedy, DenseStore, ExactGreedy, greedy_interpolation, run_greedy
from sympredict.symplectic.integrators import implicit_midpoint_step, integrate
from sympredict.kernels import IMQ, Matern32, Matern52, ProductKernel
from sympredict.interpolation.surrogate import HBSurrogate
from sympredict.symplectic.solvers import NewtonSolver

from _surrogate_oracles import check_rollouts_agree_to_the_floor, pendulum_queries, with_backend  # tests/

needs_numba = pytest.mark.skipif(not _numba.HAVE_NUMBA, reason="numba not installed (pip install sympredict[fast])")


_queries = pendulum_queries
_with_backend = with_backend


@pytest.fixture(scope="module")
def well_conditioned_model(small_pendulum_data):
    """50 centres: coefficients ~1e4, gradient floor ~1e-12, so 1e-12 agreement is meaningful."""
    d = small_pendulum_data
    model = SymplecticKernelPredictor(
        IMQ(0.15), mu_kernel=IMQ(2.0), dt_kernel=IMQ(5.0), max_centers=50, solver=NewtonSolver(backend="numpy")
    )
    return model.fit(d.x0, d.x1, mu=d.mu, dt=d.dt)


def test_newton_terms_equal_gradient_hessian_block(small_pendulum_model, rng):
    sur = small_pendulum_model.surrogate_
    for kernel in (IMQ(0.3), Matern52(0.5), Matern32(0.5)):
        # a 2n = 4 surrogate with random centres/components exercises every Hessian term
        m, dim = 40, 4
        s4 = HBSurrogate(
            ProductKernel(kernel),
            rng.normal(size=(m, dim)),
            np.zeros((m, 0)),
            np.ones(m),
            rng.integers(0, dim, m),
            rng.normal(size=m),
        )
        xi = rng.normal(size=(7, dim))
        w = s4.weights(np.zeros((7, 0)), np.ones(7))
        g_ref, h_ref, f_ref = s4.gradient_hessian(xi, w, with_floor=True)
        g, hqp, floor = s4.newton_terms(xi, w)
        np.testing.assert_allclose(g, g_ref, rtol=1e-13, atol=1e-13)
        np.testing.assert_allclose(hqp, h_ref[:, :2, 2:], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(floor, f_ref, rtol=1e-13)
    x, mu, dt = _queries(rng, 5)
    w = sur.weights(mu[:, None], dt)
    g_ref, h_ref = sur.gradient_hessian(x, w)
    g, hqp, _ = sur.newton_terms(x, w)
    # coefficients ~3e7 cancel to O(1) values: the two summation orders agree to ~1e-9 relative
    np.testing.assert_allclose(g, g_ref, rtol=0, atol=1e-7)
    np.testing.assert_allclose(hqp, h_ref[:, :1, 1:], rtol=1e-7)


@needs_numba
def test_compiled_rollout_equals_numpy_to_1e12(well_conditioned_model, rng):
    x, mu, dt = _queries(rng, 30)
    ref = _with_backend(well_conditioned_model, "numpy").rollout(x, 40, mu=mu, dt=dt)
    fast = _with_backend(well_conditioned_model, "numba").rollout(x, 40, mu=mu, dt=dt)
    np.testing.assert_allclose(fast, ref, rtol=0, atol=1e-12)
    # single step and a single trajectory (the serial, latency path)
    np.testing.assert_allclose(
        _with_backend(well_conditioned_model, "numba").step(x, mu=mu, dt=dt), ref[:, 1], rtol=0, atol=1e-12
    )
    one = _with_backend(well_conditioned_model, "numba").rollout(x[3], 40, mu=mu[3], dt=dt[3])
    np.testing.assert_allclose(one, ref[3], rtol=0, atol=1e-12)


@needs_numba
@pytest.mark.parametrize("state_kernel", [IMQ(0.3), Matern52(0.4), Matern32(0.4)], ids=repr)
@pytest.mark.parametrize("with_mu", [True, False])
def test_compiled_equals_numpy_four_dimensional(state_kernel, with_mu, rng):
    """2n = 4 (Hessian block 2 x 2, pivoted LU), every kernel family, with and without a parameter."""
    from test_predictor import CoupledOscillators  # tests/estimators/

    system = CoupledOscillators()
    x0 = rng.uniform(-1, 1, size=(40, 4))
    mu = rng.uniform(1.0, 2.0, size=(40, 1)) if with_mu else np.full((40, 1), 1.5)
    x1 = integrate(implicit_midpoint_step, system, x0, mu, 0.01, 10)[:, -1]
    model = SymplecticKernelPredictor(
        state_kernel, mu_kernel=IMQ(1.0) if with_mu else None, max_centers=60, solver=NewtonSolver(backend="numpy")
    )
    model.fit(x0, x1, mu=mu if with_mu else None, dt=0.1)
    xq = rng.uniform(-0.7, 0.7, size=(12, 4))
    kw = {"mu": rng.uniform(1.1, 1.9, 12)} if with_mu else {}
    with extrapolation_expected():  # backends compared, not accuracy: a trajectory may leave the training states
        ref = model.rollout(xq, 15, **kw)
        fast = _with_backend(model, "numba").rollout(xq, 15, **kw)
    scale = np.abs(model.surrogate_.coef).sum()  # round-off scale of the gradient sums
    np.testing.assert_allclose(fast, ref, rtol=0, atol=max(1e-12, 1e-14 * scale))


@needs_numba
def test_compiled_agrees_to_the_round_off_floor_on_an_ill_conditioned_model(small_pendulum_model, rng):
    """600 centres, coefficients ~3e7: both paths are only defined to the gradient floor."""
    x, mu, dt = _queries(rng, 20)
    numpy_model = _with_backend(small_pendulum_model, "numpy")
    # per step the solutions differ by ~dT * floor; 20 steps' growth and a factor 100 allowed
    ref, bound = check_rollouts_agree_to_the_floor(numpy_model, _with_backend(small_pendulum_model, "numba"), x, mu, dt)
    # the NumPy reference itself differs by as much between batch compositions
    single = np.stack([numpy_model.rollout(x[i], 20, mu=mu[i], dt=dt[i]) for i in range(len(x))])
    assert np.abs(single - ref).max() <= bound


@needs_numba
def test_compiled_rollout_is_bit_reproducible_across_batches_and_threads(small_pendulum_model, rng):
    model = _with_backend(small_pendulum_model, "numba")
    x, mu, dt = _queries(rng, 24)
    full = model.rollout(x, 10, mu=mu, dt=dt)
    single = np.stack([model.rollout(x[i], 10, mu=mu[i], dt=dt[i]) for i in range(len(x))])
    np.testing.assert_array_equal(full, single)
    before = _numba.get_num_threads()
    try:
        _numba.set_num_threads(1)
        np.testing.assert_array_equal(model.rollout(x, 10, mu=mu, dt=dt), full)
    finally:
        _numba.set_num_threads(before)


@needs_numba
@pytest.mark.parametrize("backend", ["numpy", "numba"])
def test_newton_failure_reported_alike(small_pendulum_model, rng, backend):
    x, mu, dt = _queries(rng, 10)
    strict = _with_backend(small_pendulum_model, backend)
    strict.set_params(solver__max_iter=1)
    with pytest.raises(NewtonConvergenceError) as info:
        strict.rollout(x, 3, mu=mu, dt=dt)
    reference = _with_backend(small_pendulum_model, "numpy")
    reference.set_params(solver__max_iter=1)
    with pytest.raises(NewtonConvergenceError) as ref_info:
        reference.rollout(x, 3, mu=mu, dt=dt)
    assert info.value.step == ref_info.value.step == 0
    np.testing.assert_array_equal(info.value.instances, ref_info.value.instances)
    assert info.value.reason == ref_info.value.reason


def test_backend_argument_checked(small_pendulum_model, small_pendulum_data, monkeypatch):
    x = np.array([[0.3, 0.0]])
    with pytest.raises(ValueError, match="backend"):  # set_params refuses it and changes nothing
        _with_backend(small_pendulum_model, "fortran")
    bad = copy.copy(small_pendulum_model)
    bad.solver = NewtonSolver(backend="fortran")  # set by assignment: prediction refuses it
    with pytest.raises(ValueError, match="backend"):
        bad.step(x, mu=0.75, dt=0.05)
    d = small_pendulum_data
    with pytest.raises(ValueError, match="backend"):
        SymplecticKernelPredictor(
            IMQ(0.15), mu_kernel=IMQ(2.0), dt_kernel=IMQ(5.0), solver=NewtonSolver(backend="gpu")
        ).fit(d.x0[:20], d.x1[:20], mu=d.mu[:20], dt=d.dt[:20])
    auto = _with_backend(small_pendulum_model, "auto")
    assert auto._compiled() is _numba.HAVE_NUMBA  # 'auto' compiles exactly when numba is there
    # without numba: 'numba' is refused, 'auto' takes the NumPy reference (and reports it)
    monkeypatch.setattr(_numba, "HAVE_NUMBA", False)
    with pytest.raises(ImportError, match="numba"):
        _with_backend(small_pendulum_model, "numba").step(x, mu=0.75, dt=0.05)
    assert auto._compiled() is False
    np.testing.assert_array_equal(
        auto.step(x, mu=0.75, dt=0.05), _with_backend(small_pendulum_model, "numpy").step(x, mu=0.75, dt=0.05)
    )


# ------------------------------------------------------------------ training paths
def _pendulum_functionals(data, kernel=None):
    from sympredict.data import mixed_variables

    kernel = kernel or ProductKernel(IMQ(0.15), IMQ(2.0), IMQ(5.0))
    xi, y = mixed_variables(data.x0, data.x1, data.dt)
    return HBFunctionals(kernel, xi, data.mu, data.dt), y.reshape(-1)


def test_functional_residuals_match_the_greedy_residual(small_pendulum_data):
    from sympredict.interpolation.functionals import functional_residuals

    fun, y = _pendulum_functionals(small_pendulum_data)
    res = greedy_interpolation(fun, y, max_centers=200, tol=0.0)
    direct = functional_residuals(fun, y, res.selected, res.coef)
    # the greedy's Newton-form residual and the directly evaluated one agree to round-off
    assert (
        abs(np.abs(direct).max() - res.history.train_max_residual[-1])
        <= 1e-6 * res.history.train_max_residual[-1] + 1e-9
    )
    np.testing.assert_allclose(direct[res.selected], 0.0, atol=1e-8)
    # the NumPy evaluation computes the same numbers
    np.testing.assert_allclose(
        functional_residuals(fun, y, res.selected, res.coef, compiled=False), direct, rtol=0, atol=1e-9
    )


def test_gram_rows_equal_columns(rng):
    for state in (IMQ(0.5), Matern32(0.7), Matern52(0.6)):
        kernel = ProductKernel(state, IMQ(1.0), IMQ(2.0))
        f = HBFunctionals(kernel, rng.normal(size=(700, 4)), rng.normal(size=(700, 1)), rng.uniform(0.1, 0.2, 700))
        g = HBFunctionals(kernel, rng.normal(size=(30, 4)), rng.normal(size=(30, 1)), rng.uniform(0.1, 0.2, 30))
        idx = rng.integers(0, g.n_functionals, 9)
        rows = f.gram_rows(g, idx, out=np.empty((9, f.n_functionals)))
        for k, i in enumerate(idx):
            np.testing.assert_array_equal(rows[k], f.column(g.representer(i), np.empty(f.n_functionals)))


def test_keep_basis_and_memory_message_offers_float32(small_pendulum_data):
    fun, y = _pendulum_functionals(small_pendulum_data)
    res = greedy_interpolation(fun, y, max_centers=50, keep_basis=True)
    assert res.basis.shape == (50, fun.n_functionals)
    # Newton-basis values at the selected functionals are the Cholesky factor
    np.testing.assert_allclose(res.basis[:, res.selected].T, res.chol, atol=1e-12)
    need = 8 * 300 * fun.n_functionals
    with pytest.raises(ValueError, match="basis_dtype='float32'") as info:
        greedy_interpolation(fun, y, max_centers=300, memory_limit=0.6 * need)
    assert "max_centers <= " in str(info.value) and "training functionals" in str(info.value)
    with pytest.raises(ValueError, match="basis_dtype"):
        greedy_interpolation(fun, y, max_centers=5, basis_dtype="float16")


def test_float32_basis_against_float64(small_pendulum_data):
    """Half the memory; accurate while the power function stays well above float32 round-off."""
    from sympredict.interpolation.functionals import functional_residuals

    fun, y = _pendulum_functionals(small_pendulum_data)
    r64 = greedy_interpolation(fun, y, max_centers=60, tol=0.0)
    r32 = greedy_interpolation(fun, y, max_centers=60, tol=0.0, basis_dtype="float32")
    np.testing.assert_array_equal(r32.selected[:20], r64.selected[:20])
    e64 = np.abs(functional_residuals(fun, y, r64.selected, r64.coef)).max()
    e32 = np.abs(functional_residuals(fun, y, r32.selected, r32.coef)).max()
    assert e32 <= 1.5 * e64
    # the tracked residual is the model's residual (checked by direct evaluation)
    assert abs(e32 - r32.history.train_max_residual[-1]) <= 1e-3 * e32


def test_active_set_on_all_points_is_the_exact_greedy(small_pendulum_data):
    from sympredict.interpolation.greedy import active_set_greedy

    fun, y = _pendulum_functionals(small_pendulum_data)
    n_points = len(fun.points)
    exact = greedy_interpolation(fun, y, max_centers=600, tol=2e-3)
    fast = active_set_greedy(fun, y, max_centers=600, tol=2e-3, margin=1.0, initial_points=n_points)
    np.testing.assert_array_equal(fast.selected, exact.selected)
    np.testing.assert_allclose(fast.coef, exact.coef, rtol=1e-9, atol=1e-9 * np.abs(exact.coef).max())
    assert fast.history.stop_reason == exact.history.stop_reason == "tol"


def test_active_set_reaches_tol_over_all_functionals(small_pendulum_data):
    from sympredict.interpolation.functionals import functional_residuals
    from sympredict.interpolation.greedy import active_set_greedy

    fun, y = _pendulum_functionals(small_pendulum_data)
    tol = 1e-3
    res = active_set_greedy(fun, y, max_centers=800, tol=tol, initial_points=200, refresh_every=40, max_new_points=100)
    assert res.history.stop_reason == "tol"
    direct = functional_residuals(fun, y, res.selected, res.coef)
    assert np.abs(direct).max() <= tol
    assert res.history.train_max_residual[-1] == pytest.approx(np.abs(direct).max(), rel=1e-6)
    assert len(np.unique(res.selected)) == len(res.selected)


def test_predictor_fast_training(small_pendulum_data, rng):
    d = small_pendulum_data
    kw = dict(mu_kernel=IMQ(2.0), dt_kernel=IMQ(5.0), max_centers=800)
    fast = SymplecticKernelPredictor(IMQ(0.15), trainer=ActiveSetGreedy(tol=1e-3), **kw).fit(
        d.x0, d.x1, mu=d.mu, dt=d.dt
    )
    exact = SymplecticKernelPredictor(IMQ(0.15), trainer=ExactGreedy(tol=1e-3), **kw).fit(d.x0, d.x1, mu=d.mu, dt=d.dt)
    assert fast.history_.stop_reason == "tol" and fast.history_.train_max_residual[-1] <= 1e-3
    x, mu, dt = _queries(rng, 8)
    a, b = fast.rollout(x, 30, mu=mu, dt=dt), exact.rollout(x, 30, mu=mu, dt=dt)
    assert np.abs(a - b).max() < 1e-2
    with pytest.raises(ValueError, match="trainer"):
        SymplecticKernelPredictor(IMQ(0.15), trainer="quick", **kw).fit(d.x0, d.x1, mu=d.mu, dt=d.dt)
    with pytest.raises(TypeError, match="criterion"):  # an f-greedy: the P-greedy cannot be asked of it
        ActiveSetGreedy(criterion="p")


def _dense(fun, y, compiled, **kw):
    """The exact greedy with or without the compiled fused update pass."""
    kw.setdefault("max_centers", 400)
    store = DenseStore(
        fun,
        y,
        validation=kw.pop("validation", None),
        power_tol=kw.pop("power_tol", 1e-12),
        basis_dtype=kw.pop("basis_dtype", "float64"),
        compiled=compiled,
    )
    return run_greedy(store, **kw)


@needs_numba
@pytest.mark.parametrize("basis_dtype", ["float64", "float32"])
def test_fused_greedy_update_is_bit_identical_to_numpy(small_pendulum_data, basis_dtype):
    """The exact f-greedy gives the same bits with and without the compiled vector pass."""
    from sympredict.data import mixed_variables
    from sympredict.systems.pendulum import Pendulum, random_flow_map_data

    fun, y = _pendulum_functionals(small_pendulum_data)
    val = random_flow_map_data(Pendulum(), 150, seed=3)
    vxi, vy = mixed_variables(val.x0, val.x1, val.dt)
    vfun = HBFunctionals(fun.kernel, vxi, val.mu, val.dt)
    fused = _dense(fun, y, True, max_centers=250, tol=0.0, validation=(vfun, vy.reshape(-1)), basis_dtype=basis_dtype)
    plain = _dense(fun, y, False, max_centers=250, tol=0.0, validation=(vfun, vy.reshape(-1)), basis_dtype=basis_dtype)
    np.testing.assert_array_equal(fused.selected, plain.selected)
    np.testing.assert_array_equal(fused.coef, plain.coef)
    np.testing.assert_array_equal(fused.chol, plain.chol)
    np.testing.assert_array_equal(fused.history.train_max_residual, plain.history.train_max_residual)
    np.testing.assert_array_equal(fused.history.val_max_residual, plain.history.val_max_residual)
    # and the tolerance and power stops fire at the same step
    for kw in ({"tol": 1e-2}, {"tol": 0.0, "power_tol": 1e-3}):
        a = _dense(fun, y, True, basis_dtype=basis_dtype, **kw)
        b = _dense(fun, y, False, basis_dtype=basis_dtype, **kw)
        assert a.history.stop_reason == b.history.stop_reason
        np.testing.assert_array_equal(a.selected, b.selected)


@needs_numba
def test_matvec_and_rollout_statistics(small_pendulum_model, rng):
    basis = rng.standard_normal((37, 50001))
    c = rng.standard_normal(37)
    for dtype in (np.float64, np.float32):
        b = basis.astype(dtype)
        got = compiled_greedy.matvec_t(b, 33, c)
        np.testing.assert_allclose(got, b[:33].astype(float).T @ c[:33], rtol=1e-12, atol=1e-12)
    sur = small_pendulum_model.surrogate_
    x, mu, dt = _queries(rng, 6)
    stats = {}
    _compiled_newton.newton_rollout(
        x, sur.weights(mu[:, None], dt), dt, sur.layout(), sur.kernel.state, 50, 4, stats=stats
    )
    # per step: one gradient pass for the explicit guess, at least one Newton pass
    assert np.all(stats["passes"] >= 2 * 4) and np.all(stats["passes"] <= 4 * 51)
    assert 0 < compiled_surrogate.factor_throughput(n=1 << 12, repeats=1) < 1e-6


@needs_numba
def test_compiled_column_is_bit_identical(rng):
    """The compiled Gramian column (2n = 2, IMQ factors) equals the NumPy column bit for bit."""
    cases = [
        (ProductKernel(IMQ(0.15), IMQ(2.0), IMQ(5.0)), 1),
        (ProductKernel(IMQ(0.7), None, IMQ(3.0)), 1),
        (ProductKernel(IMQ(3.3), IMQ(1.0), None), 2),
        (ProductKernel(IMQ(1e-3)), 0),
    ]
    for kernel, d_mu in cases:
        xi = rng.uniform(-3, 3, (5000, 2))
        xi[:10] = xi[10:20]  # coincident points: r = 0
        mu = rng.uniform(0.7, 0.8, (5000, d_mu))
        dt = rng.choice([0.04, 0.05, 0.06], 5000)
        fun = HBFunctionals(kernel, xi, mu, dt)
        assert fun._compiled_column
        for j in (0, 1, 21, 9999):
            rep = fun.representer(j)
            got = fun.column(rep, np.empty(fun.n_functionals))
            fun._compiled_column = False
            ref = fun.column(rep, np.empty(fun.n_functionals))
            fun._compiled_column = True
            np.testing.assert_array_equal(got, ref)
    # not used where NumPy's sums are not sequential or exp enters
    assert not HBFunctionals(
        ProductKernel(IMQ(0.5)), rng.normal(size=(5, 4)), np.zeros((5, 0)), np.ones(5)
    )._compiled_column
    assert not HBFunctionals(
        ProductKernel(Matern52(0.5)), rng.normal(size=(5, 2)), np.zeros((5, 0)), np.ones(5)
    )._compiled_column


def test_overflowing_coefficients_raise(rng):
    """Targets near the float64 limit (a subnormal dt) overflow the coefficients: an error, not inf."""
    model = SymplecticKernelPredictor(IMQ(0.5), IMQ(1.0), max_centers=1, solver=NewtonSolver(backend="numpy"))
    x0 = np.array([[0.0, 0.0]])
    with pytest.raises(ValueError, match="overflow"):
        model.fit(x0, x0 + 0.125, mu=0.0, dt=2.225073858507203e-309)


def test_short_parameter_factor_is_bit_identical(rng):
    from sympredict.interpolation.surrogate import _parameter_factor

    cm, cd = rng.uniform(0.7, 0.8, (300, 1)), rng.choice([0.04, 0.05, 0.06], 300)
    for kernel in (
        ProductKernel(IMQ(0.2), IMQ(1.5), IMQ(3.0)),
        ProductKernel(IMQ(0.2), Matern52(2.0), None),
        ProductKernel(IMQ(0.2), None, Matern32(4.0)),
        ProductKernel(IMQ(0.2)),
    ):
        for b in (1, 7, 50):
            mu, dt = rng.uniform(0.6, 0.9, (b, 1)), rng.uniform(0.03, 0.07, b)
            np.testing.assert_array_equal(
                _parameter_factor(kernel, mu, dt, cm, cd), kernel.parameter_factor(mu, dt, cm, cd)
            )
    k2 = ProductKernel(IMQ(0.2), IMQ(1.5), IMQ(3.0))
    mu2, cm2 = rng.normal(size=(4, 2)), rng.normal(size=(300, 2))
    np.testing.assert_array_equal(
        _parameter_factor(k2, mu2, dt[:4], cm2, cd), k2.parameter_factor(mu2, dt[:4], cm2, cd)
    )
