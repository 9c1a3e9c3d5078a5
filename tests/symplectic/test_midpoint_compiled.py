"""The compiled midpoint solver against the NumPy reference, and the compiled Newton pass for 2n up to 40.

Oracles: the NumPy solvers (:func:`~sympredict.symplectic.newton.solve_midpoint_numpy`,
:func:`~sympredict.symplectic.newton.solve_step_numpy`) and the NumPy Hessian
(:meth:`HBSurrogate.gradient_hessian`); finite differences of the compiled step
(``DPhi^T J DPhi = J``); the reverse step (time symmetry); the midpoint equation
itself, evaluated with the NumPy gradient.
"""

import numpy as np
import pytest
from scipy.linalg import expm

from sympredict import NewtonConvergenceError, SymplecticKernelPredictor
from sympredict import _numba
from sympredict.interpolation import _compiled as compiled_surrogate
from sympredict.symplectic import _compiled_newton
from sympredict.exceptions import extrapolation_expected
from sympredict.kernels import IMQ, ProductKernel
from sympredict.symplectic.metrics import canonical_J
from sympredict.symplectic.newton import implicit_rollout, rollout_numpy, solve_midpoint_numpy, solve_step_numpy
from sympredict.interpolation.surrogate import HBSurrogate
from sympredict.interpolation.greedy import ExactGreedy
from sympredict.symplectic.solvers import NewtonSolver

from _surrogate_oracles import check_rollouts_agree_to_the_floor, pendulum_queries, with_backend  # tests/

pytestmark = pytest.mark.skipif(not _numba.HAVE_NUMBA, reason="the compiled rollout needs numba (optional extra)")


_with_backend = with_backend


def _fit_pendulum_midpoint(d, **settings):
    """A midpoint predictor (NumPy Newton) of the pendulum data ``d`` with the kernels of these tests."""
    model = SymplecticKernelPredictor(
        IMQ(0.15),
        mu_kernel=IMQ(2.0),
        dt_kernel=IMQ(5.0),
        update="midpoint",
        solver=NewtonSolver(backend="numpy"),
        **settings,
    )
    return model.fit(d.x0, d.x1, mu=d.mu, dt=d.dt)


@pytest.fixture(scope="module")
def pendulum_mid(small_pendulum_data):
    """2n = 2, 50 centres: coefficients ~1e4, gradient floor ~1e-12 (as the symplectic-Euler 1e-12 test)."""
    return _fit_pendulum_midpoint(small_pendulum_data, max_centers=50)


def _chain_system(n=4):
    """Linear chain of ``n`` coupled oscillators (2n = 8): ``H = |p|^2/2 + q^T K q / 2``, flow ``expm(t A)``."""
    k = 2.0 * np.eye(n) - np.eye(n, k=1) - np.eye(n, k=-1)
    a = np.zeros((2 * n, 2 * n))
    a[:n, n:] = np.eye(n)
    a[n:, :n] = -k
    return a


@pytest.fixture(scope="module")
def chain_mid():
    """2n = 8 midpoint model of the linear chain at dT = 0.2 (400 random states in [-1, 1]^8)."""
    rng = np.random.default_rng(7)
    a = _chain_system(4)
    x0 = rng.uniform(-1, 1, (400, 8))
    x1 = x0 @ expm(0.2 * a).T
    model = SymplecticKernelPredictor(
        IMQ(0.3), max_centers=120, update="midpoint", solver=NewtonSolver(backend="numpy")
    )
    return model.fit(x0, x1, dt=0.2), a


_queries = pendulum_queries


def test_compiled_midpoint_equals_numpy_2n2(pendulum_mid, rng):
    x, mu, dt = _queries(rng, 30)
    ref = pendulum_mid.rollout(x, 40, mu=mu, dt=dt)
    fast_model = _with_backend(pendulum_mid, "numba")
    assert fast_model._compiled()
    fast = fast_model.rollout(x, 40, mu=mu, dt=dt)
    np.testing.assert_allclose(fast, ref, rtol=0, atol=1e-12)
    assert np.abs(ref[:, -1] - ref[:, 0]).max() > 0.1  # the states move
    np.testing.assert_allclose(fast_model.step(x, mu=mu, dt=dt), ref[:, 1], rtol=0, atol=1e-12)
    one = fast_model.rollout(x[3], 40, mu=mu[3], dt=dt[3])  # one trajectory: the serial path
    np.testing.assert_allclose(one, ref[3], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(one, fast[3])  # bit-reproducible across batch sizes
    assert _with_backend(pendulum_mid, "auto")._compiled()  # 'auto' now compiles the midpoint update too


def test_compiled_midpoint_equals_numpy_2n8(chain_mid, rng):
    model, a = chain_mid
    x = rng.uniform(-0.7, 0.7, (12, 8))
    with extrapolation_expected():
        ref = model.rollout(x, 15)
        fast = _with_backend(model, "numba").rollout(x, 15)
    scale = np.abs(model.surrogate_.coef).sum()
    np.testing.assert_allclose(fast, ref, rtol=0, atol=max(1e-12, 1e-14 * scale))
    # and the model is a model of the chain (not only two equal solvers): its error is a fraction of the motion
    exact = x @ expm(0.2 * a).T
    assert np.abs(fast[:, 1] - exact).max() < 0.2 * np.abs(exact - x).max()


@pytest.mark.parametrize("which", ["pendulum", "chain"])
def test_compiled_midpoint_step_is_symplectic_by_finite_differences(which, pendulum_mid, chain_mid, rng):
    if which == "pendulum":
        model = _with_backend(pendulum_mid, "numba")
        x = np.array([[0.4, 0.3], [1.0, -0.5], [-0.7, 0.9]])
        kw = {"mu": np.array([0.72, 0.75, 0.78]), "dt": np.array([0.045, 0.05, 0.055])}
    else:
        model = _with_backend(chain_mid[0], "numba")
        x = rng.uniform(-0.5, 0.5, (3, 8))
        kw = {}
    dim = x.shape[1]
    h = 1e-4
    fd = np.empty((len(x), dim, dim))
    with extrapolation_expected():
        for k in range(dim):
            e = np.zeros(dim)
            e[k] = h
            fd[:, :, k] = (model.step(x + e, **kw) - model.step(x - e, **kw)) / (2 * h)
        jac = model.step_jacobian(x, **kw)
    j = canonical_J(dim)
    np.testing.assert_allclose(np.einsum("bji,jk,bkl->bil", fd, j, fd), np.broadcast_to(j, fd.shape), atol=1e-7)
    np.testing.assert_allclose(fd, jac, atol=1e-7)
    assert np.abs(fd - np.eye(dim)).max() > 1e-2  # not the identity


@pytest.mark.parametrize("which", ["pendulum", "chain"])
def test_compiled_midpoint_reverse_step_inverts(which, pendulum_mid, chain_mid, rng):
    """With the same s, the compiled step with -dT from x1 returns to x0."""
    if which == "pendulum":
        sur = pendulum_mid.surrogate_
        x = rng.uniform([-1.5, -1.5], [1.5, 1.5], (20, 2))
        dt = np.full(20, 0.05)
        w = sur.weights(np.full((20, 1), 0.75), dt)
    else:
        sur = chain_mid[0].surrogate_
        x = rng.uniform(-0.5, 0.5, (20, 8))
        dt = np.full(20, 0.2)
        w = sur.weights(np.zeros((20, 0)), dt)
    x1 = implicit_rollout(sur, x, w, dt, 1, 50, backend="numba", update="midpoint")[:, 1]
    back = implicit_rollout(sur, x1, w, -dt, 1, 50, backend="numba", update="midpoint")[:, 1]
    np.testing.assert_allclose(back, x, rtol=0, atol=1e-13 if which == "pendulum" else 1e-12)
    assert np.abs(x1 - x).max() > 1e-2
    np.testing.assert_allclose(x1, solve_midpoint_numpy(sur, x, w, dt, 50), rtol=0, atol=1e-12)


def test_compiled_midpoint_on_an_ill_conditioned_model_agrees_to_the_floor(small_pendulum_data, rng):
    """600 centres, coefficients ~1e7: agreement to the gradient floor (several chunks: the 2n = 2 case below)."""
    model = _fit_pendulum_midpoint(small_pendulum_data, max_centers=600, trainer=ExactGreedy(tol=1e-10))
    x, mu, dt = _queries(rng, 20)
    check_rollouts_agree_to_the_floor(model, _with_backend(model, "numba"), x, mu, dt)


def test_compiled_midpoint_warm_start(pendulum_mid, rng):
    sur = pendulum_mid.surrogate_
    x, mu, dt = _queries(rng, 16)
    w = sur.weights(mu[:, None], dt)
    runs = {}
    for warm in (False, True):
        stats = {}
        traj, codes, *_ = _compiled_newton.newton_rollout(
            x, w, dt, sur.layout(), sur.kernel.state, 50, 100, stats=stats, warm_start=warm, update="midpoint"
        )
        assert np.all(codes == 0)
        runs[warm] = (traj, stats["passes"])
    (cold, p_cold), (warm, p_warm) = runs[False], runs[True]
    np.testing.assert_array_equal(cold[:, :2], warm[:, :2])
    assert p_warm.sum() < p_cold.sum()
    # every warm step solves x1 = x0 + dT J grad s((x0 + x1) / 2) (NumPy gradient as the oracle)
    a, b = warm[:, :-1].reshape(-1, 2), warm[:, 1:].reshape(-1, 2)
    g = sur.gradient(0.5 * (a + b), np.repeat(w, 100, axis=0))
    h = np.repeat(dt, 100)
    np.testing.assert_allclose(b[:, 0], a[:, 0] + h * g[:, 1], rtol=0, atol=1e-12)
    np.testing.assert_allclose(b[:, 1], a[:, 1] - h * g[:, 0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(warm, cold, rtol=0, atol=1e-10)


def test_compiled_midpoint_failure_reported_like_numpy(pendulum_mid, rng):
    x, mu, dt = _queries(rng, 10)
    errors = {}
    for backend in ("numpy", "numba"):
        strict = _with_backend(pendulum_mid, backend)
        strict.set_params(solver__max_iter=1)
        with pytest.raises(NewtonConvergenceError) as info:
            strict.rollout(x, 3, mu=mu, dt=dt)
        errors[backend] = info.value
    assert errors["numba"].step == errors["numpy"].step == 0
    np.testing.assert_array_equal(errors["numba"].instances, errors["numpy"].instances)
    assert errors["numba"].reason == errors["numpy"].reason
    assert "J Hess s" in errors["numba"].reason or "converge" in errors["numba"].reason


# ------------------------------------------------------------------ 2n up to 40
def _synthetic(dim, m, rng, big_segment=0):
    """Random centres in [-1, 1]^dim, components random (``big_segment`` of them on component 0)."""
    comps = rng.integers(0, dim, m)
    comps[:big_segment] = 0
    return HBSurrogate(
        ProductKernel(IMQ(0.5), IMQ(1.0), None),
        rng.uniform(-1, 1, (m, dim)),
        rng.uniform(0, 1, (m, 1)),
        np.ones(m),
        comps,
        1e-2 * rng.standard_normal(m),
    )


@pytest.mark.parametrize("dim", [2, 8, 40])
def test_compiled_pass_equals_numpy_gradient_hessian(dim, rng):
    """Gradient, Hessian block, full Hessian and floor of the compiled pass against NumPy; several chunks per component."""
    m = 1200
    sur = _synthetic(dim, m, rng, big_segment=400)
    assert np.diff(sur.layout().seg).max() > compiled_surrogate.chunk_size(dim)
    xi = rng.uniform(-1, 1, (5, dim))
    w = sur.weights(rng.uniform(0, 1, (5, 1)), np.ones(5))
    g_ref, h_ref, f_ref = sur.gradient_hessian(xi, w, with_floor=True)
    scale = np.abs(w).sum(axis=1).max() * 10
    g, h, f = compiled_surrogate.newton_terms(xi, w, sur.layout(), IMQ(0.5), full=True)
    np.testing.assert_allclose(g, g_ref, rtol=0, atol=1e-14 * scale)
    np.testing.assert_allclose(h, h_ref, rtol=0, atol=1e-14 * scale)
    np.testing.assert_array_equal(h, h.transpose(0, 2, 1))
    np.testing.assert_allclose(f, f_ref, rtol=1e-12)
    gb, hb, fb = compiled_surrogate.newton_terms(xi, w, sur.layout(), IMQ(0.5))
    n = dim // 2
    np.testing.assert_allclose(gb, g_ref, rtol=0, atol=1e-14 * scale)
    np.testing.assert_allclose(hb, h_ref[:, :n, n:], rtol=0, atol=1e-14 * scale)
    np.testing.assert_allclose(fb, f_ref, rtol=1e-12)
    grad = compiled_surrogate.gradients(xi, np.zeros(5, dtype=np.int64), w[:1], sur.layout(), IMQ(0.5))
    np.testing.assert_allclose(grad[:1], g_ref[:1], rtol=0, atol=1e-14 * scale)


@pytest.mark.parametrize("update", ["symplectic_euler", "midpoint"])
def test_compiled_rollouts_equal_numpy_at_2n_40(update, rng):
    dim, m = 40, 1200
    sur = _synthetic(dim, m, rng, big_segment=400)
    x = rng.uniform(-0.8, 0.8, (6, dim))
    dt = np.full(6, 0.05)
    w = sur.weights(np.full((6, 1), 0.5), dt)
    solve = solve_midpoint_numpy if update == "midpoint" else solve_step_numpy
    ref = rollout_numpy(lambda s: solve(sur, s, w, dt, 50), x, 5)
    fast = implicit_rollout(sur, x, w, dt, 5, 50, backend="numba", update=update)
    np.testing.assert_allclose(fast, ref, rtol=0, atol=1e-12)
    assert np.abs(ref[:, -1] - ref[:, 0]).max() > 1e-4  # (the states move: 1e-8 of the motion is the tolerance)
    np.testing.assert_array_equal(
        implicit_rollout(sur, x[2:3], w[2:3], dt[2:3], 5, 50, backend="numba", update=update)[0], fast[2]
    )


def test_chunk_size_keeps_the_scratch_in_l1():
    for dim in (2, 4, 10, 20, 40, 80):
        c = compiled_surrogate.chunk_size(dim)
        assert c % 8 == 0 and 32 <= c <= compiled_surrogate.CHUNK
        assert (dim + 6) * c <= compiled_surrogate.SCRATCH_DOUBLES or c == 32
    assert compiled_surrogate.chunk_size(2) == compiled_surrogate.CHUNK
    with pytest.raises(ValueError, match="update"):
        _compiled_newton.newton_rollout(
            np.zeros((1, 2)), np.zeros((1, 1)), np.ones(1), None, IMQ(1.0), 5, 1, update="leapfrog"
        )
