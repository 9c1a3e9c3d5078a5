"""The error estimate of a prediction: power function, local error, propagation along a rollout, calibration."""

import warnings

import numpy as np
import pytest

from sympredict import SymplecticKernelPredictor
from sympredict.data import FlowMapData
from sympredict.interpolation.functionals import HBFunctionals
from sympredict.interpolation.greedy.trainers import ExactGreedy
from sympredict.kernels import IMQ
from sympredict.kernels.transforms import Periodic, Symmetric
from sympredict.symplectic.solvers import NewtonSolver
from sympredict.systems.pendulum import Pendulum


def _pendulum_data(n, seed, steps=20, dt=0.1):
    rng = np.random.default_rng(seed)
    pend = Pendulum()
    mu = rng.uniform(0.7, 0.8, n)
    x0 = np.column_stack([rng.uniform(-1.5, 1.5, n), rng.uniform(-1.0, 1.0, n)])
    traj = pend.trajectory(x0, mu, dt=dt, n_steps=steps)
    x = traj[:, :-1].reshape(-1, 2)
    x1 = traj[:, 1:].reshape(-1, 2)
    return FlowMapData(x, x1, np.repeat(mu, steps), np.full(len(x), dt))


@pytest.fixture(scope="module")
def model():
    train, val = _pendulum_data(30, 0), _pendulum_data(10, 1)
    return SymplecticKernelPredictor(IMQ(0.5), mu_kernel=IMQ(2.0), max_centers=150, trainer=ExactGreedy(tol=1e-12)).fit(
        train, validation=val
    )


def _explicit_power(sur, xi, mu, dt):
    """``P_a^2 = K_aa - k_a^T G^-1 k_a`` with the Gramian and ``k`` built column by column by the
    functionals' own code (:meth:`HBFunctionals.column`), solved densely."""
    m, dim = sur.n_centers, sur.dim
    centres = HBFunctionals(sur.kernel, sur.centers_xi, sur.centers_mu, sur.centers_dt)
    sel = np.arange(m) * dim + sur.components
    queries = HBFunctionals(sur.kernel, xi, mu, dt)
    gram = np.empty((m, m))
    kq = np.empty((len(xi) * dim, m))
    col = np.empty(centres.n_functionals)
    for j in range(m):
        rep = centres.representer(sel[j])
        gram[:, j] = centres.column(rep, col)[sel]
        queries.column(rep, kq[:, j])
    diag = queries.diagonal()
    p2 = diag - np.einsum("ij,ij->i", kq, np.linalg.solve(gram, kq.T).T)
    return p2.reshape(len(xi), dim)


def test_power_function_matches_the_explicit_gramian(model, rng):
    sur = model.surrogate_
    small = model.truncated(40).surrogate_  # well conditioned: the dense solve is an accurate oracle
    xi = np.column_stack([rng.uniform(-1.5, 1.5, 7), rng.uniform(-1.0, 1.0, 7)]) * model._scale_vector(2)
    mu, dt = rng.uniform(0.7, 0.8, (7, 1)), np.full(7, 0.1)
    p = small.power_function(xi, mu, dt, small.gram_factor())
    expected = _explicit_power(small, xi, mu, dt)
    k0 = -small.kernel.state.factors(np.zeros(1), order=2)[0][0]
    np.testing.assert_allclose(p**2, np.maximum(expected, 0), atol=1e-9 * k0)
    assert np.all(p > 0) and np.all(p**2 <= k0 * (1 + 1e-12))
    # more centres: the power function does not grow (the posterior variance shrinks with more data)
    assert np.all(sur.power_function(xi, mu, dt, sur.gram_factor()) <= p * (1 + 1e-6) + 1e-7 * np.sqrt(k0))


def test_power_function_vanishes_at_the_centres(model):
    sur = model.truncated(40).surrogate_
    p = sur.power_function(sur.centers_xi, sur.centers_mu, sur.centers_dt, sur.gram_factor())
    k0 = -sur.kernel.state.factors(np.zeros(1), order=2)[0][0]
    at_centre = p[np.arange(sur.n_centers), sur.components]
    assert at_centre.max() < 1e-5 * np.sqrt(k0)
    # away from the centres (a point between two of them) it does not vanish
    mid = 0.5 * (sur.centers_xi[0] + sur.centers_xi[1])[None]
    assert sur.power_function(mid, sur.centers_mu[:1], sur.centers_dt[:1], sur.gram_factor()).min() > 1e-4 * np.sqrt(k0)


def test_rollout_error_shape_zero_at_start_and_no_change_of_states(model):
    x0 = np.array([[1.0, 0.0], [0.3, -0.4]])
    plain = model.rollout(x0, 30, mu=[0.72, 0.78], dt=0.1)
    traj, err = model.rollout(x0, 30, mu=[0.72, 0.78], dt=0.1, return_error=True)
    np.testing.assert_array_equal(traj, plain)  # the states come from the same solver
    assert err.shape == (2, 31) and np.all(err[:, 0] == 0) and np.all(err[:, 1:] > 0)
    # one step: the rollout's first estimate is the step's estimate
    x1, e1 = model.step(x0, mu=[0.72, 0.78], dt=0.1, return_error=True)
    np.testing.assert_allclose(err[:, 1], e1, rtol=1e-10)
    np.testing.assert_array_equal(x1, model.step(x0, mu=[0.72, 0.78], dt=0.1))
    # stride keeps every stride-th estimate; a single state gives (K+1,)
    traj5, err5 = model.rollout(x0, 30, mu=[0.72, 0.78], dt=0.1, return_error=True, stride=5)
    np.testing.assert_allclose(err5, err[:, ::5], rtol=1e-12)
    assert traj5.shape == (2, 7, 2)
    t1, e_single = model.rollout(x0[0], 30, mu=0.72, dt=0.1, return_error=True)
    assert t1.shape == (31, 2) and e_single.shape == (31,)
    x1s, e1s = model.step(x0[0], mu=0.72, dt=0.1, return_error=True)
    assert isinstance(e1s, float)


def test_local_error_is_the_gradient_error_mapped_through_the_implicit_step(model, rng):
    """``delta x1 = DF^-1 dT J delta g``: perturb the learned gradient by ``eps e_a`` and re-solve (oracle)."""
    from sympredict.symplectic.updates import as_update

    sur = model.surrogate_
    scale = model._scale_vector(2)
    x = np.array([[0.8, 0.1]]) * scale
    mu, dt = np.array([[0.75]]), np.array([0.1])
    w = sur.weights(mu, dt)
    rule = as_update(model.update_)
    x1 = rule.solve(sur, x, w, dt, 50)
    _, _, sens = rule.linearization(sur, x, x1, w, dt)

    class Shifted:  # the surrogate with its gradient shifted by a constant vector
        def __init__(self, delta):
            self.delta = delta

        def __getattr__(self, name):
            return getattr(sur, name)

        def gradient(self, xi, weights):
            return sur.gradient(xi, weights) + self.delta

        def newton_terms(self, xi, weights):
            g, h, f = sur.newton_terms(xi, weights)
            return g + self.delta, h, f

        def gradient_hessian(self, xi, weights, with_floor=False):
            out = sur.gradient_hessian(xi, weights, with_floor=with_floor)
            return (out[0] + self.delta, *out[1:])

    eps = 1e-6
    for a in range(2):
        d = np.zeros(2)
        d[a] = eps
        moved = rule.solve(Shifted(d), x, w, dt, 50)
        np.testing.assert_allclose((moved - x1)[0] / eps, sens[0, :, a], rtol=1e-4, atol=1e-8)


def test_estimate_against_true_error_on_the_pendulum(model):
    rng = np.random.default_rng(7)
    x0 = np.column_stack([rng.uniform(-1.2, 1.2, 12), rng.uniform(-0.8, 0.8, 12)])
    mu = rng.uniform(0.71, 0.79, 12)
    traj, err = model.rollout(x0, 100, mu=mu, dt=0.1, return_error=True)
    exact = Pendulum().trajectory(x0, mu, dt=0.1, n_steps=100)
    true = np.linalg.norm(traj - exact, axis=2)
    for k in (1, 10, 100):
        eff = err[:, k] / true[:, k]
        assert np.median(eff) < 30 and np.mean(eff < 1 / 3) <= 0.25, (k, eff)
    cal = model.error_calibration_
    assert cal["source"] == "held-out samples" and cal["n_samples"] == 200 and cal["quantile"] == 0.9
    assert cal["share_under_3x"] <= 0.1 and cal["scale"] > 0


def test_calibration_survives_files_and_truncation(model, tmp_path):
    path = tmp_path / "m.h5"
    model.save(path)
    loaded = SymplecticKernelPredictor.load(path)
    assert loaded.error_calibration_ == model.error_calibration_
    x0 = np.array([[1.0, 0.0]])
    a = model.rollout(x0, 10, mu=0.75, dt=0.1, return_error=True)
    b = loaded.rollout(x0, 10, mu=0.75, dt=0.1, return_error=True)
    np.testing.assert_allclose(b[1], a[1], rtol=1e-8)
    small = model.truncated(50)
    assert small.error_calibration_["scale"] != model.error_calibration_["scale"]
    assert small.step(x0, mu=0.75, dt=0.1, return_error=True)[1][0] > a[1][0, 1]


@pytest.mark.paths
def test_compiled_rollout_gives_the_same_estimate(model):
    pytest.importorskip("numba")
    x0 = np.array([[1.0, 0.0], [0.3, -0.4]])
    num = model.set_params(solver=NewtonSolver(backend="numpy")).rollout(x0, 20, mu=0.75, dt=0.1, return_error=True)
    jit = model.set_params(solver=NewtonSolver(backend="numba")).rollout(x0, 20, mu=0.75, dt=0.1, return_error=True)
    model.set_params(solver=None)
    np.testing.assert_allclose(jit[0], num[0], atol=1e-9)
    np.testing.assert_allclose(jit[1], num[1], rtol=1e-4)


def test_refusals(model):
    x0 = np.array([[1.0, 0.0]])
    with pytest.raises(ValueError, match="around"):
        model.rollout(x0, 3, mu=0.75, dt=0.1, around=(np.eye(2), np.eye(2)), return_error=True)
    stale = SymplecticKernelPredictor.__new__(SymplecticKernelPredictor)
    stale.__dict__.update(model.__dict__)
    stale.error_calibration_ = None
    with pytest.raises(ValueError, match="calibration"):
        stale.step(x0, mu=0.75, dt=0.1, return_error=True)


@pytest.fixture(scope="module", params=["periodic", "symmetric", "both"])
def transformed(request):
    """Models whose state kernel is a transform: periodic in q, the pendulum's Klein group, or both."""
    kernel = {
        "periodic": Periodic(IMQ(0.5), coordinates=(0,)),
        "symmetric": Symmetric(IMQ(0.5), group=[(1, 1), (-1, -1), (1, -1), (-1, 1)]),
        "both": Symmetric(Periodic(IMQ(0.5), coordinates=(0,)), group=[(1, 1), (-1, -1)]),
    }[request.param]
    update = "symplectic_euler" if request.param == "periodic" else "midpoint"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return SymplecticKernelPredictor(
            kernel, mu_kernel=IMQ(2.0), max_centers=40, update=update, trainer=ExactGreedy(tol=1e-12)
        ).fit(_pendulum_data(20, 5), validation=_pendulum_data(6, 6))


def test_transformed_kernels_rows_sum_to_the_gradient_and_match_the_explicit_gramian(transformed, rng):
    """With Periodic and Symmetric state kernels: sum_j c_j K_a(xi)_j is the surrogate's gradient, and the power
    function is the one of the Gramian built column by column by the functionals' own code."""
    sur = transformed.truncated(25).surrogate_
    xi = np.column_stack([rng.uniform(-1.5, 1.5, 6), rng.uniform(-1.0, 1.0, 6)]) * transformed._scale_vector(2)
    mu, dt = rng.uniform(0.7, 0.8, (6, 1)), np.full(6, 0.1)
    rows = sur.gradient_kernel_rows(xi, sur.parameter_factor(mu, dt))
    grad = sur.gradient(xi, sur.weights(mu, dt))
    scale = np.abs(rows).max() * np.abs(sur.coef).sum()
    np.testing.assert_allclose(rows @ sur.coef, grad, rtol=0, atol=1e-12 * scale)
    p = sur.power_function(xi, mu, dt, sur.gram_factor())
    expected = _explicit_power(sur, xi, mu, dt)
    k0 = float(np.max(sur.diagonal(xi)))
    np.testing.assert_allclose(p**2, np.maximum(expected, 0), atol=1e-8 * k0)
    at_centre = sur.power_function(sur.centers_xi, sur.centers_mu, sur.centers_dt, sur.gram_factor())[
        np.arange(sur.n_centers), sur.components
    ]
    assert at_centre.max() < 1e-4 * np.sqrt(k0)


def test_transformed_models_estimate_their_rollout_error(transformed):
    x0 = np.array([[1.0, 0.0], [0.5, 0.3]])
    states, err = transformed.rollout(x0, 20, mu=np.array([0.75, 0.72]), dt=0.1, return_error=True)
    plain = transformed.rollout(x0, 20, mu=np.array([0.75, 0.72]), dt=0.1)
    np.testing.assert_array_equal(states, plain)
    assert err.shape == (2, 21) and np.all(err[:, 0] == 0) and np.all(np.isfinite(err)) and np.all(err[:, 1:] > 0)
