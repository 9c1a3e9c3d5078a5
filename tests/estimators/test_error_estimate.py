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


# ---------------------------------------------------------------- propagation along a rollout: oracles
def _rotation(theta):
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s], [s, c]])


def _harmonic_propagation(field, n_steps, theta=0.3, dt=0.1, eps=1e-3, m=0, seed=0):
    """Propagate a gradient-error field along a harmonic orbit ``x_k = R^k x0`` (``D Phi = R``, ``S = dT J``, which
    commute with ``R``).  ``field``: ``"coherent"`` (``delta g(x) = eps xi x``, one ``xi``: a frequency error) or
    ``"white"`` (independent ``eps xi_k`` per step); ``m > 0`` adds a Newton basis ``V`` to the prior rows that the
    propagation must subtract again.  Returns (x0, the propagation's kernel part and fixed part per step)."""
    from sympredict.estimators.error_estimate import CovariancePropagation

    rng = np.random.default_rng(seed)
    x0 = np.array([[0.8, -0.3]])
    rot, jmat = _rotation(theta), np.array([[0.0, 1.0], [-1.0, 0.0]])
    xs = np.array([np.linalg.matrix_power(rot, k) @ x0[0] for k in range(n_steps)])
    v = rng.standard_normal((n_steps, 2, m)) * 1e-2
    prop = CovariancePropagation(1, 2, m, n_steps)
    kernel_part, fixed_part = [], []
    for k in range(n_steps):
        if field == "coherent":
            cov = eps**2 * np.einsum("a,lc->alc", xs[k], xs[: k + 1])
        else:
            cov = np.zeros((2, k + 1, 2))
            cov[:, k, :] = eps**2 * np.eye(2)
        rows = cov + np.einsum("am,lcm->alc", v[k], v[: k + 1])  # prior = posterior + V V^T
        sigma = prop.advance(rot[None], dt * jmat[None], v[k][None], rows[None])
        kernel_part.append(np.trace(prop.correlated[0]))
        fixed_part.append(np.trace(prop.fixed[0]))
        np.testing.assert_allclose(sigma, 0.5 * (prop.correlated + prop.fixed), rtol=1e-14, atol=0)
    return x0, np.array(kernel_part), np.array(fixed_part)


@pytest.mark.parametrize("m", [0, 5])
def test_a_coherent_frequency_error_grows_linearly_along_a_harmonic_orbit(m):
    """Closed form: ``delta g(x) = eps xi x`` gives ``delta_K = K dT eps xi J x_K-1``, ``E|delta_K|^2 = (K dT eps |x0|)^2``:
    the kernel part of the propagation is exact for it; the part constant in the coordinates (the propagation before
    the covariance was carried) is averaged away by the rotation and stays bounded."""
    dt, eps, n = 0.1, 1e-3, 400
    x0, kernel_part, fixed_part = _harmonic_propagation("coherent", n, dt=dt, eps=eps, m=m)
    steps = np.arange(1, n + 1)
    expected = (steps * dt * eps * np.linalg.norm(x0)) ** 2
    np.testing.assert_allclose(kernel_part, expected, rtol=1e-10)
    # the fixed-coordinate part: a sum of rotated vectors of length <= dT eps |x0|, bounded by 1 / sin(theta / 2)
    assert fixed_part.max() <= (2 * dt * eps * np.linalg.norm(x0) / np.sin(0.15)) ** 2
    assert np.sqrt(fixed_part[-1] / kernel_part[-1]) < 0.05  # so the mixture follows the linear growth
    # the mixture's estimate grows linearly: after 400 steps within sqrt(2) of the closed form
    np.testing.assert_allclose(np.sqrt(0.5 * (kernel_part + fixed_part))[-1], np.sqrt(0.5 * expected[-1]), rtol=1e-2)


def test_independent_step_errors_add_as_a_random_walk():
    """Closed form: independent gradient errors ``eps xi_k`` (white in the steps) give ``tr Sigma_K = 2 K (dT eps)^2``."""
    dt, eps, n = 0.1, 1e-3, 200
    _, kernel_part, _ = _harmonic_propagation("white", n, dt=dt, eps=eps, m=3)
    np.testing.assert_allclose(kernel_part, 2 * np.arange(1, n + 1) * (dt * eps) ** 2, rtol=1e-10)


def _oracle_local_factors(fitted, x, mu, dt):
    """The local scale at states ``x`` (Q, 2n) by brute force: every coordinate divided by the training box's width,
    all distances sorted, ``exp`` of the mean log ratio of the ``local_neighbours`` nearest held-out samples."""
    local, k = fitted.error_local, fitted.error_calibration["local_neighbours"]
    box = fitted.domain
    lo = np.concatenate([box["x_min"], box["mu_min"], np.atleast_1d(box["dt_min"])])
    width = np.concatenate([box["x_max"], box["mu_max"], np.atleast_1d(box["dt_max"])]) - lo
    keep = width > 0
    pts = (local["points"][:, keep] - lo[keep]) / width[keep]
    out = []
    for row in np.column_stack([x, np.reshape(mu, (len(x), -1)), dt]):
        q = (row[keep] - lo[keep]) / width[keep]
        order = np.argsort(np.sum((pts - q) ** 2, axis=1), kind="stable")
        out.append(np.exp(np.mean(local["log_ratio"][order[:k]])))
    return np.array(out)


def _oracle_neighbours(fitted, points, x, mu, dt, k):
    """Indices of the ``k`` nearest ``points`` (N, 2n + d_mu + 1) to each ``(x, mu, dt)`` by brute force: every
    coordinate divided by the training box's width, all distances sorted."""
    box = fitted.domain
    lo = np.concatenate([box["x_min"], box["mu_min"], np.atleast_1d(box["dt_min"])])
    width = np.concatenate([box["x_max"], box["mu_max"], np.atleast_1d(box["dt_max"])]) - lo
    keep = width > 0
    pts = (points[:, keep] - lo[keep]) / width[keep]
    out = []
    for row in np.column_stack([x, np.reshape(mu, (len(x), -1)), dt]):
        q = (row[keep] - lo[keep]) / width[keep]
        out.append(np.argsort(np.sum((pts - q) ** 2, axis=1), kind="stable")[:k])
    return np.array(out)


def _oracle_share_factors(fitted, x, mu, dt):
    """The posterior part's share beside the residual part at states ``x`` (Q, 2n) by brute force: every coordinate
    divided by the training box's width, all distances to the residual samples sorted, ``d`` the
    ``residual_neighbours``-th smallest; ``share`` within ``share_distance``, 1 beyond twice it, linear between."""
    cal, res, box = fitted.error_calibration, fitted.error_residuals, fitted.domain
    lo = np.concatenate([box["x_min"], box["mu_min"], np.atleast_1d(box["dt_min"])])
    width = np.concatenate([box["x_max"], box["mu_max"], np.atleast_1d(box["dt_max"])]) - lo
    keep = width > 0
    pts = (res["points"][:, keep] - lo[keep]) / width[keep]
    share, ref, k = cal["posterior_share"], cal["share_distance"], cal["residual_neighbours"]
    out = []
    for row in np.column_stack([x, np.reshape(mu, (len(x), -1)), dt]):
        q = (row[keep] - lo[keep]) / width[keep]
        d = np.sqrt(np.sort(np.sum((pts - q) ** 2, axis=1))[k - 1])
        out.append(share if d <= ref else 1.0 if d >= 2 * ref else share + (1 - share) * (d - ref) / ref)
    return np.array(out)


def _oracle_residual_part(fitted, x, mu, dt, jac, kk):
    """The residual part after ``kk`` steps from the states ``x`` (K, 2n) with Jacobians ``jac`` (K, 2n, 2n) (scaled
    coordinates), the step maps multiplied out: ``c_r |D^-1 sum_k D Phi_kk-1 ... D Phi_k+1 U_k|_F``, ``U_k`` the
    ``residual_neighbours`` nearest residual vectors (scaled) over ``sqrt(k)``."""
    res, cal, scale = fitted.error_residuals, fitted.error_calibration, fitted.scale
    k = cal["residual_neighbours"]
    near = _oracle_neighbours(fitted, res["points"], x, mu, dt, k)
    total = np.zeros((len(scale), k))
    for step in range(kk):
        u = (res["vectors"][near[step]] * scale).T / np.sqrt(k)
        for j in range(step + 1, kk):
            u = jac[j] @ u
        total += u
    return cal["residual_scale"] * np.sqrt(np.sum(total**2 / scale[:, None] ** 2))


def test_rollout_estimate_is_the_dense_posterior_covariance_propagated(model):
    """Oracle: the posterior covariance of the gradient functionals at all of a rollout's evaluation points from the
    Gramian built column by column by the functionals' own code (dense solve), the step maps multiplied out
    explicitly with each step's local scale ``f_k`` times its share beside the residual part ``g_k`` (brute-force
    neighbours and distances), ``M_K,k = D Phi ... S_k f_k g_k``,
    ``Sigma_K = (sum_kl M_K,k C_kl M_K,l^T + F F^T) / 2``; with the residual part (the nearest residual vectors by
    brute force, carried by the explicit products of the steps' Jacobians) added in quadrature."""
    small = model.truncated(40)
    fitted = small.model_
    sur, rule, scale = fitted.surrogate, fitted.rule, fitted.scale
    x0 = np.array([[1.0, 0.0], [0.3, -0.4]])
    mu, n = np.array([0.72, 0.78]), 6
    traj, err = small.rollout(x0, n, mu=mu, dt=0.1, return_error=True)
    c = small.error_calibration_["scale"]
    m, dim = sur.n_centers, 2
    centres = HBFunctionals(sur.kernel, sur.centers_xi, sur.centers_mu, sur.centers_dt)
    sel = np.arange(m) * dim + sur.components
    gram = np.empty((m, m))
    col = np.empty(centres.n_functionals)
    for j in range(m):
        gram[:, j] = centres.column(centres.representer(sel[j]), col)[sel]
    gram[np.diag_indices(m)] += fitted.regularization
    for b in range(2):
        mub, dtb = np.full((n, 1), mu[b]), np.full(n, 0.1)
        w = sur.weights(mub, dtb)
        xi, jac, sens = rule.linearization(sur, traj[b, :-1] * scale, traj[b, 1:] * scale, w, dtb)
        assert fitted.error_local is not None
        factors = _oracle_local_factors(fitted, traj[b, :-1], mub, dtb)
        sens = sens * (factors * _oracle_share_factors(fitted, traj[b, :-1], mub, dtb))[:, None, None]
        queries = HBFunctionals(sur.kernel, xi, mub, dtb)
        kqc = np.empty((n * dim, m))
        kqq = np.empty((n * dim, n * dim))
        qcol = np.empty(n * dim)
        for j in range(m):
            queries.column(centres.representer(sel[j]), kqc[:, j])
        for i in range(n * dim):
            kqq[:, i] = queries.column(queries.representer(i), qcol)
        post = kqq - kqc @ np.linalg.solve(gram, kqc.T)
        for kk in range(1, n + 1):
            maps = []
            for k in range(kk):
                mk = sens[k]
                for j in range(k + 1, kk):
                    mk = jac[j] @ mk
                maps.append(mk)
            big = np.concatenate(maps, axis=1)  # (2n, kk 2n)
            sigma_gp = big @ post[: kk * dim, : kk * dim] @ big.T
            power = np.sqrt(np.maximum(np.diag(post)[: kk * dim], 0.0))
            f = sum(maps[k] * power[k * dim : (k + 1) * dim][None, :] for k in range(kk))
            sigma = 0.5 * (sigma_gp + f @ f.T)
            expected = c * np.sqrt(np.sum(np.diag(sigma) / scale**2))
            residual = _oracle_residual_part(fitted, traj[b, :-1], mub, dtb, jac, kk)
            assert residual > 0
            expected = np.hypot(expected, residual)
            np.testing.assert_allclose(err[b, kk], expected, rtol=1e-5)


def test_local_covariance_has_the_power_function_on_its_diagonal(model, transformed, rng):
    """The one-step covariance's diagonal is ``P_a^2`` (:meth:`HBSurrogate.power_function`, its own code), for plain
    and transformed state kernels; the prior blocks of points against themselves have ``K_aa`` (``diagonal``) on
    theirs, and the off-diagonal entries are the mixture's half of the posterior's, symmetric."""
    from sympredict.estimators.error_estimate import _prior_at_points, local_covariance, newton_rows

    for fitted in (model.truncated(40), transformed.truncated(25)):
        sur = fitted.surrogate_
        xi = np.column_stack([rng.uniform(-1.5, 1.5, 37), rng.uniform(-1.0, 1.0, 37)]) * fitted._scale_vector(2)
        mu, dt = rng.uniform(0.7, 0.8, (37, 1)), np.full(37, 0.1)
        chol = sur.gram_factor()
        k0 = float(np.max(sur.diagonal(xi)))
        prior = _prior_at_points(sur, xi, mu, dt)
        np.testing.assert_allclose(np.diagonal(prior, axis1=1, axis2=2), sur.diagonal(xi), rtol=1e-12, atol=1e-14 * k0)
        cov = local_covariance(sur, xi, mu, dt, chol)
        p = sur.power_function(xi, mu, dt, chol)
        np.testing.assert_allclose(np.diagonal(cov, axis1=1, axis2=2), p**2, rtol=1e-9, atol=1e-12 * k0)
        np.testing.assert_allclose(cov, cov.transpose(0, 2, 1), rtol=0, atol=1e-12 * k0)
        v = newton_rows(sur, xi, mu, dt, chol)
        posterior = prior - v @ v.transpose(0, 2, 1)
        np.testing.assert_allclose(cov[:, 0, 1], 0.5 * posterior[:, 0, 1], rtol=1e-12, atol=1e-14 * k0)


def _lowrank_harmonic(field, n_steps, theta=0.3, dt=0.1, eps=1e-3):
    """:class:`LowRankPropagation` along the harmonic orbit of :func:`_harmonic_propagation`, the field given as
    its exact factorisation: ``"coherent"``, ``A_k = eps x_k^T`` (rank 1, no remainder); ``"white"``, ``A_k = 0``
    and the remainder ``eps^2 I``.  Returns the kernel part ``tr(G G^T + Q)`` per step."""
    from sympredict.estimators.error_estimate import LowRankPropagation

    x0 = np.array([0.8, -0.3])
    rot, jmat = _rotation(theta), np.array([[0.0, 1.0], [-1.0, 0.0]])
    prop = LowRankPropagation(1, 2, 1)
    out = []
    for k in range(n_steps):
        xk = np.linalg.matrix_power(rot, k) @ x0
        a = eps * xk[None, None, :] if field == "coherent" else np.zeros((1, 1, 2))
        resid = np.zeros((1, 2, 2)) if field == "coherent" else eps**2 * np.eye(2)[None]
        prop.advance(rot[None], dt * jmat[None], a, resid, np.zeros((1, 2)))
        out.append(np.trace(np.matmul(prop.g, prop.g.transpose(0, 2, 1))[0] + prop.q[0]))
    return np.array(out)


def test_lowrank_propagation_meets_the_closed_forms_of_the_exact_one():
    """The factorised recursion is the same sum as the pairwise one: a coherent frequency error grows linearly
    (``(K dT eps |x0|)^2``), independent step errors add as a random walk (``2 K (dT eps)^2``), and both equal
    :class:`CovariancePropagation`'s kernel part on the same fields."""
    dt, eps, n = 0.1, 1e-3, 300
    steps = np.arange(1, n + 1)
    coherent = _lowrank_harmonic("coherent", n, dt=dt, eps=eps)
    np.testing.assert_allclose(coherent, (steps * dt * eps * np.linalg.norm([0.8, -0.3])) ** 2, rtol=1e-10)
    np.testing.assert_allclose(coherent, _harmonic_propagation("coherent", n, dt=dt, eps=eps)[1], rtol=1e-10)
    white = _lowrank_harmonic("white", n, dt=dt, eps=eps)
    np.testing.assert_allclose(white, 2 * steps * (dt * eps) ** 2, rtol=1e-10)


def test_pivoted_cholesky_reproduces_the_pivots_and_leaves_a_small_remainder(rng):
    from sympredict.estimators.error_estimate import pivoted_cholesky

    basis = rng.standard_normal((60, 7)) * np.logspace(0, -6, 7)
    mat = basis @ basis.T
    pivots, factor = pivoted_cholesky(mat, 60, 1e-14)
    assert len(pivots) == 7 and len(set(pivots)) == 7
    np.testing.assert_allclose(factor @ factor.T, mat[np.ix_(pivots, pivots)], rtol=1e-12, atol=1e-14 * mat.max())
    # the Nystrom remainder at every row is below the stopping tolerance's scale
    cross = np.linalg.solve(factor, mat[pivots])
    assert np.max(np.diagonal(mat) - np.sum(cross**2, axis=0)) <= 1e-10 * np.max(np.diagonal(mat))
    capped, small = pivoted_cholesky(mat, 3, 0.0)
    assert len(capped) == 3 and small.shape == (3, 3)
    np.testing.assert_allclose(capped, pivots[:3])


def _rollout_units(model, n_steps, method, local=False):
    """``rollout_error_units`` along three rollouts; ``local``: with the posterior part's factor at each step, the
    local scale times the share beside the residual part where the model has one (brute force)."""
    from sympredict.estimators.error_estimate import rollout_error_units

    fitted = model.model_
    x0, mu = np.array([[1.0, 0.0], [0.3, -0.4], [-1.2, 0.5]]), np.array([[0.72], [0.75], [0.78]])
    traj = model.rollout(x0, n_steps, mu=mu[:, 0], dt=0.1)
    dt = np.full(3, 0.1)
    factors = None
    if local:
        x = traj[:, :-1].reshape(-1, 2)
        mus, dts = np.repeat(mu, n_steps, axis=0), np.full(len(x), 0.1)
        factors = _oracle_local_factors(fitted, x, mus, dts)
        if fitted._share() is not None:
            factors = factors * _oracle_share_factors(fitted, x, mus, dts)
        factors = factors.reshape(3, n_steps)
    return rollout_error_units(fitted, traj, mu, dt, fitted.surrogate.weights(mu, dt), method=method, local=factors)


def _residual_units(model, n_steps):
    """The residual part (3, K+1) along :func:`_rollout_units`' three rollouts, by :func:`_oracle_residual_part`."""
    fitted = model.model_
    x0, mu = np.array([[1.0, 0.0], [0.3, -0.4], [-1.2, 0.5]]), np.array([[0.72], [0.75], [0.78]])
    traj = model.rollout(x0, n_steps, mu=mu[:, 0], dt=0.1)
    out = np.zeros((3, n_steps + 1))
    for b in range(3):
        mub, dtb = np.repeat(mu[b : b + 1], n_steps, axis=0), np.full(n_steps, 0.1)
        scaled = traj[b] * fitted.scale
        jac = fitted.rule.jacobian(fitted.surrogate, scaled[:-1], scaled[1:], fitted.surrogate.weights(mub, dtb), dtb)
        for kk in range(1, n_steps + 1):
            out[b, kk] = _oracle_residual_part(fitted, traj[b, :-1], mub, dtb, jac, kk)
    return out


def _no_residuals(settings=None, arrays=None):
    """Edits of a model file that drop the residual part (as written before it existed), then ``settings`` and
    ``arrays``."""

    def edit_settings(s):
        for key in ("residual_neighbours", "residual_scale", "residual_samples", "posterior_share", "share_distance"):
            s["error_calibration"].pop(key)
        if settings is not None:
            settings(s)

    def edit_arrays(a):
        a.pop("error_residual_points")
        a.pop("error_residual_vectors")
        if arrays is not None:
            arrays(a)

    return {"settings": edit_settings, "arrays": edit_arrays}


@pytest.mark.paths
@pytest.mark.parametrize("n_steps", [150, 400])
def test_lowrank_estimate_agrees_with_the_exact_pairwise_one(model, n_steps):
    """Every evaluation point a candidate landmark: the factorised posterior is the exact one up to the pivoted
    Cholesky's stopping tolerance, so the estimates agree far below the estimate's own accuracy."""
    exact = _rollout_units(model, n_steps, "exact")
    low = _rollout_units(model, n_steps, "lowrank")
    assert np.all(exact[:, 1:] > 0)
    np.testing.assert_allclose(low, exact, rtol=1e-6, atol=0)


@pytest.mark.paths
def test_lowrank_estimate_with_subsampled_landmarks_stays_close(model, monkeypatch):
    """A long horizon pivots its landmarks from an evenly spaced subset of the evaluation points: with 40 of 400
    points as candidates the estimate stays within 10% of the exact one (the remainder's diagonal is kept)."""
    from sympredict.estimators import error_estimate

    exact = _rollout_units(model, 400, "exact")
    monkeypatch.setattr(error_estimate, "_CANDIDATES", 80)
    low = _rollout_units(model, 400, "lowrank")
    np.testing.assert_allclose(low, exact, rtol=0.1, atol=0)


@pytest.mark.paths
def test_long_horizons_take_the_linear_path_and_say_so(model, monkeypatch, caplog):
    """``method="auto"`` is exact up to ``EXACT_MAX_STEPS`` and factorised beyond, logged at INFO; the public
    rollout uses it; an unknown method is refused by name."""
    import logging

    from sympredict.estimators import error_estimate

    x0, mu = np.array([[1.0, 0.0]]), np.array([0.72])
    _, short = model.rollout(x0, 30, mu=mu, dt=0.1, return_error=True)
    c = model.error_calibration_["scale"]
    expected = np.hypot(c * _rollout_units(model, 30, "exact", local=True), _residual_units(model, 30))[:1]
    np.testing.assert_allclose(short, expected, rtol=1e-8, atol=0)
    monkeypatch.setattr(error_estimate, "EXACT_MAX_STEPS", 20)
    with caplog.at_level(logging.INFO, logger="sympredict.estimators.error_estimate"):
        _, long = model.rollout(x0, 30, mu=mu, dt=0.1, return_error=True)
    assert "landmarks" in caplog.text and "30 steps" in caplog.text
    expected = np.hypot(c * _rollout_units(model, 30, "lowrank", local=True), _residual_units(model, 30))[:1]
    np.testing.assert_allclose(long, expected, rtol=1e-8, atol=0)
    assert not np.array_equal(long, short)
    with pytest.raises(ValueError, match="method"):
        _rollout_units(model, 5, "fast")


def test_local_scale_recovers_a_linear_and_a_step_field(rng):
    """``local_log_ratio`` is the mean over the ``k`` nearest points: for a linear field exactly the field at the
    neighbours' centroid (brute-force neighbours), with or without each point's own value; for a field with two
    levels, the level of the region at queries farther from its border than their neighbours are."""
    from sympredict.estimators.error_estimate import local_log_ratio

    pts = rng.uniform(0.0, 1.0, (400, 3))
    slope = np.array([2.0, -1.0, 0.5])
    field = pts @ slope + 0.3
    queries = rng.uniform(0.0, 1.0, (50, 3))
    for k in (1, 7, 20):
        got = local_log_ratio(pts, field, queries, k)
        near = np.argsort(np.sum((queries[:, None] - pts[None]) ** 2, axis=2), axis=1)[:, :k]
        np.testing.assert_allclose(got, pts[near].mean(axis=1) @ slope + 0.3, rtol=1e-12, atol=1e-12)
        loo = local_log_ratio(pts, field, pts, k, leave_one_out=True)
        d2 = np.sum((pts[:, None] - pts[None]) ** 2, axis=2)
        np.fill_diagonal(d2, np.inf)
        near = np.argsort(d2, axis=1)[:, :k]
        np.testing.assert_allclose(loo, pts[near].mean(axis=1) @ slope + 0.3, rtol=1e-12, atol=1e-12)
    step = np.where(pts[:, 0] < 0.5, np.log(10.0), 0.0)
    inner = np.array([[0.1, 0.5, 0.5], [0.9, 0.5, 0.5]])
    np.testing.assert_allclose(local_log_ratio(pts, step, inner, 10), [np.log(10.0), 0.0], atol=1e-12)
    # k beyond the points: all of them (the others, leaving one out)
    np.testing.assert_allclose(local_log_ratio(pts, field, queries[:2], 10**6), field.mean(), rtol=1e-12)


def _edited_local(model, tmp_path, log_ratio=None, settings=None, arrays=None, name="edited.h5"):
    from _model_files import _rewrite  # tests/

    src = tmp_path / "src.h5"
    model.save(src)

    def edit_arrays(a):
        if log_ratio is not None:
            a["error_local_log_ratio"] = np.full_like(a["error_local_log_ratio"], log_ratio)
        if arrays is not None:
            arrays(a)

    _rewrite(src, tmp_path / name, settings=settings, arrays=edit_arrays)
    return SymplecticKernelPredictor.load(tmp_path / name)


@pytest.mark.parametrize("exact_max", [1000, 5])
def test_a_constant_local_scale_multiplies_the_estimate(model, tmp_path, monkeypatch, exact_max):
    """A local log ratio of ``ln 3`` everywhere makes every step's gradient error 3 times larger, so every estimate
    (one step, the exact and the low-rank propagation) is 3 times that of a log ratio of 0 (files without the
    residual part, which the local scale does not multiply)."""
    from sympredict.estimators import error_estimate

    monkeypatch.setattr(error_estimate, "EXACT_MAX_STEPS", exact_max)
    one = _edited_local(model, tmp_path, log_ratio=0.0, name="one.h5", **_no_residuals())
    three = _edited_local(model, tmp_path, log_ratio=np.log(3.0), name="three.h5", **_no_residuals())
    assert one.model_.error_residuals is None
    x0, mu = np.array([[1.0, 0.0], [-0.6, 0.4]]), np.array([0.72, 0.78])
    _, e1 = one.rollout(x0, 12, mu=mu, dt=0.1, return_error=True)
    _, e3 = three.rollout(x0, 12, mu=mu, dt=0.1, return_error=True)
    assert np.all(e1[:, 1:] > 0)
    # the same arrays scaled by 3 (9 in the covariances): round-off of a posterior that is a difference of
    # prior-sized terms (``Q - W W^T``), relative to the prior
    np.testing.assert_allclose(e3, 3.0 * e1, rtol=1e-8, atol=0)
    s1 = one.step(x0, mu=mu, dt=0.1, return_error=True)[1]
    s3 = three.step(x0, mu=mu, dt=0.1, return_error=True)[1]
    np.testing.assert_allclose(s3, 3.0 * s1, rtol=1e-12, atol=0)
    np.testing.assert_allclose(s1, e1[:, 1], rtol=1e-10)  # the one-step estimate is the K = 1 case


def test_local_scale_is_calibrated_and_survives_model_files(model, tmp_path):
    """The local scale is the held-out samples' centred log ratios, stored in the model file and read back;
    the estimates of the loaded model are the fitted one's."""
    local = model.model_.error_local
    cal = model.error_calibration_
    assert cal["local_neighbours"] == 20 and local["points"].shape == (cal["n_samples"], 2 + 1 + 1)
    assert abs(local["log_ratio"].mean()) < 1e-12 and np.ptp(local["log_ratio"]) > 0
    path = tmp_path / "m.h5"
    model.save(path)
    loaded = SymplecticKernelPredictor.load(path)
    np.testing.assert_array_equal(loaded.model_.error_local["points"], local["points"])
    np.testing.assert_array_equal(loaded.model_.error_local["log_ratio"], local["log_ratio"])
    x0 = np.array([[1.0, 0.0], [0.3, -0.4]])
    a = model.rollout(x0, 8, mu=0.75, dt=0.1, return_error=True)[1]
    np.testing.assert_allclose(loaded.rollout(x0, 8, mu=0.75, dt=0.1, return_error=True)[1], a, rtol=1e-12)


def test_files_without_the_local_scale_load_with_one_scale(model, tmp_path):
    """A model file written before the local scale and the residual part existed (no arrays, no
    ``local_neighbours``, no ``residual_*``) loads, and its estimate is its one scale times the propagated covariance,
    without local factors."""

    def old_settings(s):
        s["error_calibration"].pop("local_neighbours")

    def old_arrays(a):
        a.pop("error_local_points")
        a.pop("error_local_log_ratio")

    old = _edited_local(model, tmp_path, **_no_residuals(old_settings, old_arrays))
    assert old.model_.error_local is None and old.model_.error_residuals is None
    _, err = old.rollout(
        np.array([[1.0, 0.0], [0.3, -0.4], [-1.2, 0.5]]), 10, mu=[0.72, 0.75, 0.78], dt=0.1, return_error=True
    )
    c = old.error_calibration_["scale"]
    np.testing.assert_allclose(err, c * _rollout_units(old, 10, "exact"), rtol=1e-12, atol=0)


@pytest.mark.parametrize(
    "settings, arrays, match",
    [
        (None, lambda a: a.pop("error_local_log_ratio"), "incomplete"),
        (lambda s: s["error_calibration"].pop("local_neighbours"), None, "incomplete"),
        (None, lambda a: a.update(error_local_points=a["error_local_points"][:, :2]), "not \\(N, 4\\)"),
        (None, lambda a: a.update(error_local_log_ratio=a["error_local_log_ratio"][:-1]), "not \\(N, 4\\)"),
        (lambda s: s["error_calibration"].update(local_neighbours=0), None, "local_neighbours"),
        (lambda s: s["error_calibration"].update(local_neighbours=10**6), None, "local_neighbours"),
        (lambda s: s["error_calibration"].update(local_neighbours=2.5), None, "local_neighbours"),
        (None, lambda a: a["error_local_log_ratio"].__setitem__(0, np.nan), "finite"),
    ],
)
def test_hostile_local_scale_in_model_files_is_refused(model, tmp_path, settings, arrays, match):
    from sympredict.exceptions import ModelFileError

    with pytest.raises(ModelFileError, match=match):
        _edited_local(model, tmp_path, settings=settings, arrays=arrays)


@pytest.mark.paths
def test_lowrank_keeps_each_steps_own_covariance_whatever_its_rank(model, monkeypatch):
    """With two landmark functionals the factorisation misses most of the posterior, but each step's own covariance
    is kept exactly (landmark part plus remainder): the first step's estimate, ``sqrt(tr S C(z, z) S^T)``, is the
    exact path's; the later ones differ (the correlations between steps the landmarks miss are dropped)."""
    from sympredict.estimators import error_estimate

    exact = _rollout_units(model, 30, "exact")
    monkeypatch.setattr(error_estimate, "_RANK_MAX", 2)
    low = _rollout_units(model, 30, "lowrank")
    np.testing.assert_allclose(low[:, 1], exact[:, 1], rtol=1e-8, atol=0)
    assert np.all(np.isfinite(low)) and not np.allclose(low, exact, rtol=1e-3)


def test_a_calibration_set_by_hand_keeps_the_local_scale_only_with_its_neighbours(model, tmp_path):
    """``error_calibration_ = {...}`` with ``local_neighbours`` keeps the local scale; without, the estimate is that
    one scale times the propagated covariance; either model's file loads back to the same estimate."""
    x0 = np.array([[1.0, 0.0], [0.3, -0.4], [-1.2, 0.5]])
    mu = [0.72, 0.75, 0.78]
    for keep in (True, False):
        copy_ = SymplecticKernelPredictor.__new__(SymplecticKernelPredictor)
        copy_.__dict__.update(model.__dict__)
        cal = {"scale": 2.0, **({"local_neighbours": 5} if keep else {})}
        copy_.error_calibration_ = cal
        assert (copy_.model_.error_local is not None) is keep
        assert copy_.model_.error_residuals is None  # without residual_neighbours: no residual part
        _, err = copy_.rollout(x0, 10, mu=mu, dt=0.1, return_error=True)
        units = _rollout_units(copy_, 10, "exact", local=keep)
        np.testing.assert_allclose(err, 2.0 * units, rtol=1e-12, atol=0)
        copy_.save(tmp_path / f"{keep}.h5")
        loaded = SymplecticKernelPredictor.load(tmp_path / f"{keep}.h5")
        np.testing.assert_allclose(loaded.rollout(x0, 10, mu=mu, dt=0.1, return_error=True)[1], err, rtol=1e-12)


def test_propagated_residuals_meet_the_closed_form_of_a_linear_map(rng):
    """Oracle: with one Jacobian ``D`` at every step and the same neighbours' residuals ``U`` (2n, k) / sqrt(k),
    ``F_K = sum_j<K D^j U = (I - D)^-1 (I - D^K) U`` (a geometric series); with ``D = I`` the error grows linearly,
    ``K |U|_F``; with a rotation it stays bounded by ``2 |U|_F / |1 - e^i theta|``.  In the states' units: the
    scaled coordinates divided out."""
    from sympredict.estimators.error_estimate import propagated_residuals

    theta, k, n_steps = 0.3, 4, 60
    rot = np.array([[np.cos(theta), np.sin(theta)], [-np.sin(theta), np.cos(theta)]])
    scale = np.array([2.0, 0.5])
    resid = rng.normal(size=(k, 2))
    for d in (np.eye(2), rot, 1.01 * rot):
        jac = np.broadcast_to(d, (1, n_steps, 2, 2))
        got = propagated_residuals(jac, np.broadcast_to(resid, (1, n_steps, k, 2)), scale)[0]
        u = resid.T / np.sqrt(k)
        for kk in range(n_steps + 1):
            if np.allclose(d, np.eye(2)):
                f = kk * u
            else:
                f = np.linalg.solve(np.eye(2) - d, (np.eye(2) - np.linalg.matrix_power(d, kk)) @ u)
            np.testing.assert_allclose(got[kk], np.sqrt(np.sum(f**2 / scale[:, None] ** 2)), rtol=1e-10, atol=1e-15)
    bounded = propagated_residuals(
        np.broadcast_to(rot, (1, n_steps, 2, 2)), np.broadcast_to(resid, (1, n_steps, k, 2)), np.ones(2)
    )
    assert bounded.max() <= 2 * np.linalg.norm(resid / np.sqrt(k)) / abs(1 - np.exp(1j * theta)) + 1e-12


@pytest.mark.paths
def test_residual_part_is_the_models_own_residuals_calibrated_and_survives_model_files(model, tmp_path):
    """The residual vectors are the model's one-step residuals ``Phi(x0_i) - x1_i`` on its held-out samples and
    the training samples that are not centres; ``residual_scale`` is the 0.9 quantile of ``|r_i|`` over the root mean
    square of its nearest other residuals (brute force); the one-step estimate is the rollout's first step; the model
    file stores the arrays and the loaded model gives the same estimates."""
    fitted = model.model_
    res, cal = fitted.error_residuals, model.error_calibration_
    pool = fitted.residual_samples
    assert len(pool) > cal["n_samples"] and res["vectors"].shape == (len(pool), 2) == (cal["residual_samples"], 2)
    pred = model.step(pool.x0, mu=pool.mu, dt=pool.dt)
    # two Newton solves of the same steps (another batch, another solver state): within the solver's stopping rule
    from _tolerances import rollout_bound  # tests/

    states = np.stack([pool.x0, pred], axis=1) * fitted.scale
    tol = rollout_bound(fitted.surrogate, states, fitted.surrogate.weights(pool.mu, pool.dt), pool.dt)
    np.testing.assert_allclose(res["vectors"], pred - pool.x1, rtol=0, atol=tol / fitted.scale.min())
    np.testing.assert_array_equal(res["points"], np.column_stack([pool.x0, pool.mu, pool.dt]))
    k = cal["residual_neighbours"]
    near = _oracle_neighbours(fitted, res["points"], pool.x0, pool.mu, pool.dt, k + 1)
    ratios = []
    for i, row in enumerate(near):
        others = row[row != i][:k]
        ratios.append(np.linalg.norm(res["vectors"][i]) / np.sqrt(np.mean(np.sum(res["vectors"][others] ** 2, axis=1))))
    np.testing.assert_allclose(cal["residual_scale"], np.quantile(ratios, 0.9), rtol=1e-12)
    x0, mu = np.array([[1.0, 0.0], [0.3, -0.4]]), np.array([0.72, 0.78])
    _, err = model.rollout(x0, 8, mu=mu, dt=0.1, return_error=True)
    np.testing.assert_allclose(model.step(x0, mu=mu, dt=0.1, return_error=True)[1], err[:, 1], rtol=1e-10)
    path = tmp_path / "m.h5"
    model.save(path)
    loaded = SymplecticKernelPredictor.load(path)
    np.testing.assert_array_equal(loaded.model_.error_residuals["vectors"], res["vectors"])
    np.testing.assert_array_equal(loaded.model_.error_residuals["points"], res["points"])
    np.testing.assert_allclose(loaded.rollout(x0, 8, mu=mu, dt=0.1, return_error=True)[1], err, rtol=1e-12)


@pytest.mark.parametrize(
    "settings, arrays, match",
    [
        (None, lambda a: a.pop("error_residual_vectors"), "incomplete"),
        (lambda s: s["error_calibration"].pop("residual_scale"), None, "incomplete"),
        (None, lambda a: a.update(error_residual_points=a["error_residual_points"][:, :2]), "not \\(N, 4\\)"),
        (None, lambda a: a.update(error_residual_vectors=a["error_residual_vectors"][:-1]), "not \\(N, 4\\)"),
        (None, lambda a: a.update(error_residual_vectors=a["error_residual_vectors"].astype(int)), "float"),
        (None, lambda a: a["error_residual_vectors"].__setitem__((0, 0), np.inf), "finite"),
        (lambda s: s["error_calibration"].update(residual_neighbours=0), None, "residual_neighbours"),
        (lambda s: s["error_calibration"].update(residual_neighbours=10**7), None, "residual_neighbours"),
        (lambda s: s["error_calibration"].update(residual_scale=-1.0), None, "residual_scale"),
        (lambda s: s["error_calibration"].update(residual_scale="big"), None, "residual_scale"),
    ],
)
def test_hostile_residual_part_in_model_files_is_refused(model, tmp_path, settings, arrays, match):
    from sympredict.exceptions import ModelFileError

    with pytest.raises(ModelFileError, match=match):
        _edited_local(model, tmp_path, settings=settings, arrays=arrays)


def test_residual_propagation_in_blocks_is_the_propagation_in_one_go(rng):
    """:class:`ResidualPropagation` fed the steps in blocks of any sizes carries ``F`` from block to block: the
    same recursion as :func:`propagated_residuals` over all steps at once, up to round-off."""
    from sympredict.estimators.error_estimate import ResidualPropagation, propagated_residuals

    b, n_steps, k, dim = 3, 23, 4, 4
    jac = np.eye(dim) + 0.1 * rng.normal(size=(b, n_steps, dim, dim))
    resid = rng.normal(size=(b, n_steps, k, dim))
    scale = np.array([2.0, 0.5, 1.0, 3.0])
    whole = propagated_residuals(jac, resid, scale)
    for cuts in ([0, 1, 2, 23], [0, 7, 8, 20, 23], [0, 23]):
        prop = ResidualPropagation(b, dim, k, scale, n_steps)
        for k0, k1 in zip(cuts[:-1], cuts[1:]):
            prop.advance(jac[:, k0:k1], resid[:, k0:k1])
        np.testing.assert_allclose(prop.out, whole, rtol=1e-13, atol=0)


@pytest.mark.paths
@pytest.mark.parametrize("method", ["exact", "lowrank"])
def test_residual_part_reuses_the_linearisations_hessians(model, monkeypatch, method):
    """The residual part takes the steps' Jacobians from the posterior's linearisation, block by block: the Hessian
    is evaluated once per step of the rollout (not once more for the residual part), the residual samples' points
    are normalised once per model (later calls normalise only the rollout's states), and the estimate is the
    brute-force oracle's (the explicit products of the steps' Jacobians, :func:`_residual_units`)."""
    from sympredict.estimators import error_estimate, fitted as fitted_module
    from sympredict.interpolation.surrogate import HBSurrogate

    fitted = model.model_
    x0, mu = np.array([[1.0, 0.0], [0.3, -0.4], [-1.2, 0.5]]), np.array([[0.72], [0.75], [0.78]])
    n_steps = 12
    traj = model.rollout(x0, n_steps, mu=mu[:, 0], dt=0.1)
    dt = np.full(3, 0.1)
    weights = fitted.surrogate.weights(mu, dt)
    if method == "lowrank":
        monkeypatch.setattr(error_estimate, "EXACT_MAX_STEPS", 5)
    monkeypatch.setattr(error_estimate, "_BLOCK_ENTRIES", 3 * 4 * 13 * 5)  # blocks of 5 steps (exact)
    first = fitted._rollout_error(traj, mu, dt, weights)
    hessians, normalised = [], []
    hessian, points = HBSurrogate.gradient_hessian, fitted_module.local_points

    def counted_hessian(self, xi, w):
        hessians.append(len(xi))
        return hessian(self, xi, w)

    def counted_points(x, *args):
        normalised.append(len(x))
        return points(x, *args)

    monkeypatch.setattr(HBSurrogate, "gradient_hessian", counted_hessian)
    monkeypatch.setattr(fitted_module, "local_points", counted_points)
    err = fitted._rollout_error(traj, mu, dt, weights)
    assert sum(hessians) == 3 * n_steps and len(hessians) > 1
    assert normalised == [3 * n_steps]  # the local scale's queries; the stored points were normalised before
    np.testing.assert_array_equal(err, first)
    c = fitted.error_calibration["scale"]
    expected = np.hypot(c * _rollout_units(model, n_steps, method, local=True), _residual_units(model, n_steps))
    np.testing.assert_allclose(err, expected, rtol=1e-8, atol=0)


def test_posterior_share_is_its_closed_form_and_kth_distance_is_brute_force(rng):
    """``g(d) = s`` up to the reference distance, ``1`` from twice it, linear between (exact values at the
    breakpoints and the midpoint); :func:`kth_distance` is the ``k``-th smallest of all distances, with and without
    leaving each point out."""
    from sympredict.estimators.error_estimate import kth_distance, posterior_share

    d = np.array([0.0, 0.5, 1.0, 1.25, 1.5, 2.0, 7.0])
    np.testing.assert_allclose(posterior_share(2 * d, 0.2, 2.0), [0.2, 0.2, 0.2, 0.4, 0.6, 1.0, 1.0], rtol=1e-15)
    np.testing.assert_array_equal(posterior_share(d, 1.0, 1.0), np.ones_like(d))
    pts, q = rng.uniform(size=(40, 3)), rng.uniform(size=(7, 3))
    full = np.sqrt(((q[:, None] - pts[None]) ** 2).sum(-1))
    np.testing.assert_allclose(kth_distance(pts, q, 4), np.sort(full, axis=1)[:, 3], rtol=1e-13)
    own = np.sqrt(((pts[:, None] - pts[None]) ** 2).sum(-1)) + np.diag(np.full(40, np.inf))
    np.testing.assert_allclose(kth_distance(pts, pts, 4, leave_one_out=True), np.sort(own, axis=1)[:, 3], rtol=1e-13)


def test_posterior_share_is_calibrated_on_the_residual_neighbours_misfit(model):
    """Oracle (brute force): on the calibration samples, with ``u_i`` the one-step estimate before calibration times
    the local scale the estimate applies at the sample, the share of the posterior's scale beside the residual part
    is the 0.9 quantile of ``|r_i - mean of the k nearest residual vectors other than its own| / u_i`` over the
    scale; ``share_distance`` the 0.9 quantile of the residual samples' distances to their ``k``-th nearest other
    one; the one-step estimate is ``hypot(c f g U, R)`` with ``g`` the share at the state's distance: the share near
    the residual samples, 1 far from them."""
    fitted = model.model_
    cal, res = fitted.error_calibration, fitted.error_residuals
    data = fitted.calibration_samples[0]
    scale = fitted.scale
    w = fitted.surrogate.weights(data.mu, data.dt)
    x1 = model.step(data.x0, mu=data.mu, dt=data.dt)
    r = x1 - data.x1
    unit = fitted._local_error_units(data.x0 * scale, x1 * scale, data.mu, data.dt, w)
    u = unit * _oracle_local_factors(fitted, data.x0, data.mu, data.dt)
    raw = np.column_stack([data.x0, data.mu, data.dt])
    k = cal["residual_neighbours"]
    near = _oracle_neighbours(fitted, res["points"], data.x0, data.mu, data.dt, k + 1)
    misfit = []
    for i, row in enumerate(near):
        others = [j for j in row if not np.array_equal(res["points"][j], raw[i])][:k]
        misfit.append(np.linalg.norm(r[i] - res["vectors"][others].mean(axis=0)))
    share = np.quantile(np.array(misfit) / u, 0.9) / cal["scale"]
    assert 0.05 < share < 1  # the neighbours explain part of the residuals
    np.testing.assert_allclose(cal["posterior_share"], share, rtol=1e-6)
    box = fitted.domain
    lo = np.concatenate([box["x_min"], box["mu_min"], np.atleast_1d(box["dt_min"])])
    width = np.concatenate([box["x_max"], box["mu_max"], np.atleast_1d(box["dt_max"])]) - lo
    keep = width > 0
    pts = (res["points"][:, keep] - lo[keep]) / width[keep]
    own = np.sqrt(((pts[:, None] - pts[None]) ** 2).sum(-1)) + np.diag(np.full(len(pts), np.inf))
    np.testing.assert_allclose(cal["share_distance"], np.quantile(np.sort(own, axis=1)[:, k - 1], 0.9), rtol=1e-12)
    # the one-step estimate: near the data (a residual sample's state), between, and far outside the training box
    x0 = np.array([res["points"][0, :2], [1.0, 0.0], [0.3, -0.4], [4.0, 3.0]])
    mu, dt = np.array([res["points"][0, 2], 0.72, 0.78, 0.75]), np.full(4, 0.1)
    g = _oracle_share_factors(fitted, x0, mu, dt)
    assert g[0] == cal["posterior_share"] and g[-1] == 1.0
    from sympredict.exceptions import ExtrapolationWarning

    with pytest.warns(ExtrapolationWarning, match="left the box"):  # the last state, far outside
        _, e1 = model.step(x0, mu=mu, dt=0.1, return_error=True)
    with pytest.warns(ExtrapolationWarning, match="left the box"):
        x1 = model.step(x0, mu=mu, dt=0.1)
    nearest_res = _oracle_neighbours(fitted, res["points"], x0, mu, dt, k)
    part = [np.sqrt(np.sum(res["vectors"][row] ** 2) / k) * cal["residual_scale"] for row in nearest_res]
    w = fitted.surrogate.weights(mu[:, None], dt)
    post = (
        cal["scale"]
        * g
        * _oracle_local_factors(fitted, x0, mu[:, None], dt)
        * fitted._local_error_units(x0 * scale, x1 * scale, mu[:, None], dt, w)
    )
    np.testing.assert_allclose(e1, np.hypot(post, part), rtol=1e-8)


@pytest.mark.parametrize(
    "edit, match",
    [
        ({"posterior_share": 0.0}, "posterior_share"),
        ({"posterior_share": -0.5}, "posterior_share"),
        ({"posterior_share": 1.5}, "posterior_share"),
        ({"posterior_share": float("nan")}, "posterior_share"),
        ({"posterior_share": "half"}, "posterior_share"),
        ({"posterior_share": 1}, "posterior_share"),
        ({"share_distance": 0.0}, "share_distance"),
        ({"share_distance": -1.0}, "share_distance"),
        ({"share_distance": float("inf")}, "share_distance"),
        ({"share_distance": "far"}, "share_distance"),
        ({"share_distance": None}, "both or none"),
        ({"posterior_share": None}, "both or none"),
    ],
)
def test_hostile_posterior_share_in_model_files_is_refused(model, tmp_path, edit, match):
    from sympredict.exceptions import ModelFileError

    def settings(s):
        for key, value in edit.items():
            if value is None:
                s["error_calibration"].pop(key)
            else:
                s["error_calibration"][key] = value

    with pytest.raises(ModelFileError, match=match):
        _edited_local(model, tmp_path, settings=settings)


def test_files_without_the_posterior_share_use_the_posterior_at_its_full_scale(model, tmp_path):
    """A file written before the share existed (its residual part without ``posterior_share`` and
    ``share_distance``) loads and adds the posterior's part at its full scale: ``hypot(c U, R)``, ``U`` with the
    local scale only and ``R`` by the brute-force oracles; the file of today gives ``hypot(c G U, R)`` with the
    share's factors ``G`` and stores them."""

    def old_settings(s):
        s["error_calibration"].pop("posterior_share")
        s["error_calibration"].pop("share_distance")

    old = _edited_local(model, tmp_path, settings=old_settings)
    assert old.model_._share() is None and old.model_.error_residuals is not None
    cal = model.error_calibration_
    path = tmp_path / "now.h5"
    model.save(path)
    loaded = SymplecticKernelPredictor.load(path)
    assert loaded.error_calibration_["posterior_share"] == cal["posterior_share"]
    assert loaded.error_calibration_["share_distance"] == cal["share_distance"]
    x0, mu = np.array([[1.0, 0.0], [0.3, -0.4], [-1.2, 0.5]]), np.array([0.72, 0.75, 0.78])
    _, now = loaded.rollout(x0, 10, mu=mu, dt=0.1, return_error=True)
    _, before = old.rollout(x0, 10, mu=mu, dt=0.1, return_error=True)
    resid = _residual_units(model, 10)
    np.testing.assert_allclose(
        now, np.hypot(cal["scale"] * _rollout_units(model, 10, "exact", local=True), resid), rtol=1e-8
    )
    np.testing.assert_allclose(
        before, np.hypot(cal["scale"] * _rollout_units(old, 10, "exact", local=True), resid), rtol=1e-8
    )
    assert np.all(now[:, 1:] <= before[:, 1:] * (1 + 1e-12)) and np.any(now[:, 1:] < 0.99 * before[:, 1:])


def test_the_calibration_does_not_depend_on_what_ran_before_in_the_process(monkeypatch):
    """``backend='auto'`` runs a small batch compiled once the process has loaded the compiled rollout, and NumPy in a
    fresh one; the two solvers agree only to Newton's stopping rule.  The calibration's held-out and residual steps
    are chosen by their size alone, so a model calibrates alike in a fresh process and after other fits (compared
    bit for bit: the same code path on the same arrays)."""
    from sympredict.symplectic import _compiled_newton

    train, val = _pendulum_data(20, 3), _pendulum_data(8, 4)
    calibrations = []
    for loaded in (False, True):
        monkeypatch.setattr(_compiled_newton, "rollout_loaded", lambda loaded=loaded: loaded)
        est = SymplecticKernelPredictor(IMQ(0.5), mu_kernel=IMQ(2.0), max_centers=80, trainer=ExactGreedy(tol=1e-12))
        est.fit(train, validation=val)
        # the case this guards: a later call of this size in this process would run compiled
        assert est.model_.compiled(len(val), 1) is loaded
        calibrations.append((est.error_calibration_, est.model_.error_local, est.model_.error_residuals))
    (cal_a, local_a, res_a), (cal_b, local_b, res_b) = calibrations
    assert cal_a == cal_b
    for key in local_a:
        np.testing.assert_array_equal(local_a[key], local_b[key])
    for key in res_a:
        np.testing.assert_array_equal(res_a[key], res_b[key])
