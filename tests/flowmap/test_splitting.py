"""The exact-linear-flow splitting Phi = L_h o S o L_h (sympredict.flowmap.splitting, sympredict.systems.linear_flow).

Oracles: scipy's expm one instance at a time and the closed-form rotation of a harmonic oscillator for the
propagators; DPhi^T J DPhi = J and finite differences for the composed Jacobian; exactness on a linear system
(the inner step has nothing to learn); the reverse step (time symmetry) and the pendulum's reversing symmetry
q -> -q with the Klein-invariant midpoint kernel; the two Newton backends against each other; file round trips.
"""

import copy

import numpy as np
import pytest
import sklearn.base
from scipy.linalg import expm

from sympredict import SymplecticKernelPredictor
from sympredict.base import clone
from sympredict.container import read_container, write_container
from sympredict.exceptions import ExtrapolationWarning, ModelFileError, NotFittedError
from sympredict.io import load_model, save_model
from sympredict.kernels import IMQ
from sympredict.systems.linear_flow import QuadraticPart, inverse_symplectic_matrices
from _surrogate_oracles import KLEIN, check_step_jacobian, klein_midpoint_predictor  # tests/
from _tolerances import rollout_bound  # tests/
from sympredict.symplectic.metrics import canonical_J
from sympredict.symplectic.newton import solve_midpoint_numpy
from sympredict.estimators.predictor import MODEL_FORMAT
from sympredict.flowmap.splitting import SplitKernelPredictor
from sympredict.symplectic.solvers import NewtonSolver
from sympredict.kernels.transforms import Scaled

J2 = canonical_J(2)


def _random_quadratic(rng, dim=4, d_mu=2):
    mats = rng.standard_normal((3, dim, dim))
    mats = mats + np.swapaxes(mats, 1, 2)
    return QuadraticPart(mats, [[1.0, 0.0], [0.0, 2.0], [-1.0, 0.5]][:3] if d_mu == 2 else None), mats


# ------------------------------------------------------------------ propagators
def test_propagators_against_expm_one_by_one(rng):
    quad, mats = _random_quadratic(rng)
    mu = rng.uniform(0.5, 1.5, (7, 2))
    t = rng.uniform(-0.4, 0.4, 7)
    L = quad.propagator(mu, t)
    J = canonical_J(4)
    for b in range(7):
        A = mu[b, 0] * mats[0] + mu[b, 1] ** 2 * mats[1] + mu[b, 0] ** -1 * mu[b, 1] ** 0.5 * mats[2]
        np.testing.assert_allclose(quad.hessian(mu[b : b + 1])[0], A, rtol=1e-14, atol=1e-14)
        np.testing.assert_allclose(L[b], expm(t[b] * J @ A), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(np.einsum("bji,jk,bkl->bil", L, J, L), np.broadcast_to(J, L.shape), atol=1e-12)
    np.testing.assert_allclose(inverse_symplectic_matrices(L), np.linalg.inv(L), atol=1e-10)
    np.testing.assert_allclose(quad.propagator(mu, -t), inverse_symplectic_matrices(L), atol=1e-10)
    # one parameter vector, one time for a batch of 3
    np.testing.assert_allclose(quad.propagator(mu[0], t[0], n=3), np.broadcast_to(L[0], (3, 4, 4)), atol=1e-14)


def test_propagator_closed_form_of_the_harmonic_oscillator(pendulum):
    """H0 = k q^2 / 2 + p^2 / (2 m): q(t) = q cos(w t) + p / (m w) sin(w t), w = sqrt(k / m); pendulum: w = sqrt(g / l)."""
    k, m = 2.5, 0.4
    w = np.sqrt(k / m)
    t = np.array([0.1, 1.0, 7.3])
    L = QuadraticPart([np.diag([k, 1.0 / m])]).propagator(t=t)
    c, s = np.cos(w * t), np.sin(w * t)
    exact = np.stack([np.stack([c, s / (m * w)], -1), np.stack([-m * w * s, c], -1)], 1)
    np.testing.assert_allclose(L, exact, atol=1e-13)
    lengths = np.array([0.7, 0.75, 0.8])
    quad = pendulum.quadratic_part()
    np.testing.assert_allclose(quad.hessian(lengths), pendulum.hessian(np.zeros((3, 2)), lengths), rtol=1e-15)
    w = np.sqrt(pendulum.g / lengths)
    L = quad.propagator(lengths, 0.3)
    np.testing.assert_allclose(L[:, 0, 0], np.cos(0.3 * w), atol=1e-14)
    np.testing.assert_allclose(L[:, 0, 1], np.sin(0.3 * w) / (lengths**2 * w), atol=1e-14)  # dq/dp0 = sin / (m l^2 w)


@pytest.mark.parametrize(
    "matrices, powers, match",
    [
        (np.eye(2), None, "list of matrices"),
        ([np.eye(3)], None, "even 2n"),
        ([[[1.0, 2.0], [0.0, 1.0]]], None, "not symmetric"),
        ([np.array([[np.nan, 0.0], [0.0, 1.0]])], None, "NaN"),
        ([np.eye(2), np.eye(2)], [[1.0]], "one row per matrix"),
        ([np.eye(2)], [[np.inf]], r"powers contains NaN or Inf \(index \(0, 0\): inf\)"),
        ("abc", None, "matrices must be"),
    ],
)
def test_malformed_quadratic_parts_are_refused(matrices, powers, match):
    with pytest.raises(ValueError, match=match):
        QuadraticPart(matrices, powers).propagator(1.0, 0.1)


def test_undefined_coefficients_and_missing_mu_are_refused(pendulum):
    quad = pendulum.quadratic_part()
    with pytest.raises(ValueError, match="mu is required"):
        quad.propagator(None, 0.1)
    with pytest.raises(ValueError, match="undefined"):
        quad.propagator(0.0, 0.1)  # l^-2 at l = 0
    with pytest.raises(ValueError, match="undefined"):
        QuadraticPart([np.eye(2)], [[0.5]]).hessian(-1.0)
    with pytest.raises(ValueError, match="mu must have length 3"):
        quad.propagator([0.7, 0.8], [0.1, 0.2, 0.3])
    with pytest.raises(ValueError, match="t must be a scalar or have length 2"):
        quad.propagator([0.7, 0.8], [0.1, 0.2, 0.3], n=2)
    with pytest.raises(ValueError, match="t must be a scalar or have shape"):
        quad.propagator(0.7, [[0.1]])


# ------------------------------------------------------------------ the split predictor on the pendulum
@pytest.fixture(scope="module")
def split_pendulum(small_pendulum_data, pendulum):
    d = small_pendulum_data
    idx = np.random.default_rng(0).choice(len(d), 1200, replace=False)
    inner = klein_midpoint_predictor(0.4, 0.75, 1.06, max_centers=250, backend="numpy")
    model = SplitKernelPredictor(inner, pendulum.quadratic_part())
    return model.fit(d.x0[idx], d.x1[idx], mu=d.mu[idx], dt=d.dt[idx]), d


def test_fit_trains_the_inner_step_on_the_transformed_pairs(split_pendulum, pendulum):
    model, d = split_pendulum
    assert model.n_centers_ == 250 and model.predictor_.update == "midpoint"
    assert model.predictor is not model.predictor_ and not model.predictor.is_fitted  # fit fits a clone
    x0, mu, dt = d.x0[:30], d.mu[:30], d.dt[:30]
    L = pendulum.quadratic_part().propagator(mu, dt / 2)
    inner = model.predictor_.step(np.einsum("bij,bj->bi", L, x0), mu=mu, dt=dt)
    np.testing.assert_allclose(model.step(x0, mu=mu, dt=dt), np.einsum("bij,bj->bi", L, inner), rtol=0, atol=1e-15)
    # accurate on training states and a little off them (coarse data, 250 centres)
    assert np.abs(model.step(x0, mu=mu, dt=dt) - d.x1[:30]).max() < 1e-4
    x = np.array([[0.8, 0.0], [0.3, 0.5], [0.05, 0.0]])
    ref = pendulum.trajectory(x, np.full(3, 0.74), 0.05, 1)[:, 1]
    assert np.abs(model.step(x, mu=0.74, dt=0.05) - ref).max() < 1e-4


def test_composed_jacobian_is_symplectic_and_matches_finite_differences(split_pendulum):
    model, _ = split_pendulum
    x = np.array([[0.4, 0.3], [1.0, -0.5], [-0.7, 0.9]])
    mu, dt = np.array([0.72, 0.75, 0.78]), np.array([0.045, 0.05, 0.055])
    jac, _ = check_step_jacobian(model, x, mu, dt, fd_atol=1e-7)
    assert np.abs(jac - np.eye(2)).max() > 1e-2  # a real step, not the identity
    np.testing.assert_allclose(model.step_jacobian(x[0], mu=mu[0], dt=dt[0]), jac[0], atol=1e-15)


def test_time_symmetry_and_reversibility_with_the_klein_kernel(split_pendulum, pendulum):
    """Phi_{-dT} = L_{-h} S_{-dT} L_{-h} inverts the step; and R Phi R = Phi^-1 for R(q, p) = (-q, p) (q -> -q)."""
    model, _ = split_pendulum
    x = np.random.default_rng(3).uniform([-1.2, -1.2], [1.2, 1.2], (20, 2))
    mu, dt = np.full(20, 0.75), np.full(20, 0.05)
    x1 = model.step(x, mu=mu, dt=dt)
    assert np.abs(x1 - x).max() > 1e-2
    Linv = pendulum.quadratic_part().propagator(mu, -dt / 2)
    sur = model.predictor_.surrogate_
    w = sur.weights(mu[:, None], dt)
    back = np.einsum("bij,bj->bi", Linv, solve_midpoint_numpy(sur, np.einsum("bij,bj->bi", Linv, x1), w, -dt, 50))
    np.testing.assert_allclose(back, x, atol=1e-13)
    R = np.array([-1.0, 1.0])
    np.testing.assert_allclose(model.step(R * x1, mu=mu, dt=dt), R * x, atol=1e-12)


def test_exact_on_a_linear_system_with_zero_centres(tmp_path):
    """Samples of the flow of H0 itself: the transformed pairs are fixed points of S, every target is 0 and the
    greedy stops at once (0 centres, stop reason 'tol'); the model is then the exact linear flow, both backends."""
    rng = np.random.default_rng(5)
    quad = QuadraticPart([np.diag([2.0, 0.0]), np.diag([0.0, 1.0])], [[1.0], [-2.0]])  # the linearized pendulum, g = 2
    x0 = rng.uniform(-1, 1, (200, 2))
    mu = rng.uniform(0.7, 0.8, 200)
    dt = rng.uniform(0.04, 0.06, 200)
    x1 = np.einsum("bij,bj->bi", quad.propagator(mu, dt), x0)
    xt = rng.uniform(-0.5, 0.5, (10, 2))
    for backend in ("numpy", "numba"):
        inner = SymplecticKernelPredictor(
            IMQ(1.0), IMQ(1.0), IMQ(1.0), max_centers=50, update="midpoint", solver=NewtonSolver(backend=backend)
        )
        model = SplitKernelPredictor(inner, quad).fit(x0, x1, mu=mu, dt=dt)
        assert model.n_centers_ == 0 and model.history_.stop_reason == "tol"
        L = quad.propagator(0.75, 0.05)[0]
        ref = np.empty((10, 31, 2))
        ref[:, 0] = xt
        for k in range(30):
            ref[:, k + 1] = ref[:, k] @ L.T
        np.testing.assert_allclose(model.rollout(xt, 30, mu=0.75, dt=0.05), ref, rtol=0, atol=1e-14)
        np.testing.assert_allclose(
            model.step_jacobian(xt, mu=0.75, dt=0.05), np.broadcast_to(L, (10, 2, 2)), atol=1e-15
        )
    save_model(model, tmp_path / "zero.h5")  # a model without centres is a valid file too
    loaded = load_model(tmp_path / "zero.h5")
    assert loaded.n_centers_ == 0
    np.testing.assert_array_equal(loaded.rollout(xt, 30, mu=0.75, dt=0.05), model.rollout(xt, 30, mu=0.75, dt=0.05))


def test_rollout_agrees_with_steps_and_between_backends(split_pendulum, small_pendulum_data, pendulum):
    model, d = split_pendulum
    x = np.array([[0.5, 0.0], [0.05, 0.0], [1.2, 0.3]])
    traj = model.rollout(x, 40, mu=[0.72, 0.75, 0.79], dt=0.05)
    assert traj.shape == (3, 41, 2)
    state = x
    for k in range(3):
        state = model.step(state, mu=[0.72, 0.75, 0.79], dt=0.05)
    np.testing.assert_allclose(traj[:, 3], state, rtol=0, atol=1e-15)
    ref = pendulum.trajectory(x, np.array([0.72, 0.75, 0.79]), 0.05, 40)
    assert np.abs(traj - ref).max() < 5e-3  # coarse: 250 centres on 1,200 samples of the 20 x 20 grid (1.8e-3)
    # the same fit with the compiled Newton solver (no symmetry: that one is NumPy only)
    idx = np.random.default_rng(0).choice(len(d), 600, replace=False)
    fits = {}
    for backend in ("numpy", "numba"):
        inner = SymplecticKernelPredictor(
            IMQ(0.4), IMQ(0.75), IMQ(1.06), max_centers=120, update="midpoint", solver=NewtonSolver(backend=backend)
        )
        fits[backend] = SplitKernelPredictor(inner, pendulum.quadratic_part()).fit(
            d.x0[idx], d.x1[idx], mu=d.mu[idx], dt=d.dt[idx]
        )
    a, b = (fits[k].rollout(x, 40, mu=0.75, dt=0.05) for k in ("numpy", "numba"))
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-11)
    single = fits["numba"].rollout(x[0], 5, mu=0.75, dt=0.05)
    assert single.shape == (6, 2)


@pytest.mark.parametrize("update", ["symplectic_euler", "midpoint"])
def test_compiled_split_rollout_equals_the_numpy_one_and_repeated_steps(small_pendulum_data, pendulum, update):
    """The compiled rollout takes L_h before and after every step (one call for all steps); with a state scaling,
    both updates, a batch large enough for the parallel kernel: equal to the NumPy loop and to repeated step()."""
    d = small_pendulum_data
    idx = np.random.default_rng(1).choice(len(d), 600, replace=False)
    inner = SymplecticKernelPredictor(
        Scaled(IMQ(0.4), factors=(1.3,)),
        IMQ(0.75),
        IMQ(1.06),
        max_centers=120,
        update=update,
        solver=NewtonSolver(backend="numba"),
    )
    model = SplitKernelPredictor(inner, pendulum.quadratic_part()).fit(d.x0[idx], d.x1[idx], mu=d.mu[idx], dt=d.dt[idx])
    rng = np.random.default_rng(2)
    x = np.column_stack([rng.uniform(0.05, 1.2, 10), rng.uniform(-0.3, 0.3, 10)])
    mu, dt = rng.uniform(0.72, 0.78, 10), rng.uniform(0.046, 0.054, 10)
    traj = model.rollout(x, 25, mu=mu, dt=dt)
    # The compiled rollout applies L_h inside the compiled loop (FMA where the CPU has it), step() with
    # NumPy's matmul, and the Newton solves round differently: the paths agree to the gradient's round-off
    # floor accumulated over the steps, not to a fixed number (1.1e-13 apart on an AVX2 machine, 0 on
    # another). The floor is evaluated at the trajectory's states, scaled as trained.
    inner = model.predictor_
    sur = inner.surrogate_
    scaled = traj * np.array([1.3, 1 / 1.3])
    bound = rollout_bound(sur, scaled, sur.weights(mu[:, None], dt), dt)
    assert bound < 1e-8, bound  # far below what a wrong map would change (the states move by ~0.1)
    state = x
    for k in range(25):
        state = model.step(state, mu=mu, dt=dt)
        np.testing.assert_allclose(traj[:, k + 1], state, rtol=0, atol=bound * (k + 1) / 25)
    numpy_model = copy.copy(model)
    numpy_model.predictor_ = copy.copy(model.predictor_).set_params(solver__backend="numpy")
    np.testing.assert_allclose(numpy_model.rollout(x, 25, mu=mu, dt=dt), traj, rtol=0, atol=bound)
    assert np.abs(traj[:, -1] - x).max() > 0.1  # real steps (120 centres: a coarse model, not an accuracy test)


def test_settings_and_inputs_are_checked(split_pendulum, pendulum, small_pendulum_data):
    model, d = split_pendulum
    x0, x1, mu, dt = d.x0[:40], d.x1[:40], d.mu[:40], d.dt[:40]
    inner = SymplecticKernelPredictor(IMQ(0.4), IMQ(0.75), IMQ(1.06), max_centers=5)
    with pytest.raises(NotFittedError):
        SplitKernelPredictor(inner, pendulum.quadratic_part()).step(x0)
    with pytest.raises(ValueError, match="predictor must be"):
        SplitKernelPredictor("imq", pendulum.quadratic_part()).fit(x0, x1, mu=mu, dt=dt)
    with pytest.raises(ValueError, match="quadratic must be"):
        SplitKernelPredictor(inner, np.eye(2)).fit(x0, x1, mu=mu, dt=dt)
    with pytest.raises(ValueError, match="the states have 2n = 2"):
        SplitKernelPredictor(inner, QuadraticPart([np.eye(4)])).fit(x0, x1, mu=mu, dt=dt)
    with pytest.raises(ValueError, match="pass mu"):
        SplitKernelPredictor(SymplecticKernelPredictor(IMQ(0.4), max_centers=5), pendulum.quadratic_part()).fit(
            x0, x1, dt=0.05
        )
    with pytest.raises(ValueError, match="same number of samples"):
        SplitKernelPredictor(inner, pendulum.quadratic_part()).fit(x0, x1[:10], mu=mu, dt=dt)
    with pytest.raises(ValueError, match="dt is required"):
        SplitKernelPredictor(inner, pendulum.quadratic_part()).fit(x0, x1, mu=mu)
    with pytest.raises(ValueError, match="2 state components"):
        model.step(np.zeros((3, 4)), mu=0.75, dt=0.05)
    with pytest.raises(ValueError, match="mu is required"):
        model.step(x0, dt=0.05)
    with pytest.raises(ValueError, match="dt is required"):
        model.step(x0, mu=0.75)
    with pytest.warns(ExtrapolationWarning):
        model.step(x0[:2], mu=0.9, dt=0.05)


def test_parameters_clone_and_set_params(split_pendulum, pendulum):
    model, _ = split_pendulum
    params = model.get_params()
    assert set(model.get_params(deep=False)) == {"predictor", "quadratic"}
    assert params["predictor__update"] == "midpoint" and params["predictor__state_kernel__eps"] == 0.4
    assert {"quadratic__matrices", "quadratic__powers"} <= set(params)
    for copy_ in (clone(model), sklearn.base.clone(model)):
        assert not copy_.is_fitted and copy_.predictor is not model.predictor
        assert copy_.get_params()["predictor__state_kernel__eps"] == 0.4
    other = clone(model).set_params(predictor__max_centers=7, predictor__state_kernel__eps=0.3)
    assert other.predictor.max_centers == 7 and other.predictor.state_kernel.eps == 0.3
    assert model.predictor.max_centers == 250  # the original is untouched
    with pytest.raises(ValueError, match="no parameter"):
        clone(model).set_params(nonsense=1)


def test_save_load_round_trip(split_pendulum, tmp_path):
    model, _ = split_pendulum
    x = np.array([[0.5, 0.1], [1.0, -0.2]])
    save_model(model, tmp_path / "split.h5")
    for loaded in (load_model(tmp_path / "split.h5"), SplitKernelPredictor.load(tmp_path / "split.h5")):
        assert isinstance(loaded, SplitKernelPredictor) and loaded.n_centers_ == model.n_centers_
        np.testing.assert_array_equal(loaded.rollout(x, 5, mu=0.75, dt=0.05), model.rollout(x, 5, mu=0.75, dt=0.05))
        assert loaded.predictor.update == "midpoint" and loaded.predictor.max_centers == 250
        np.testing.assert_array_equal(np.array(loaded.predictor.state_kernel.group), np.array(KLEIN))
        np.testing.assert_array_equal(loaded.quadratic_.checked()[0], model.quadratic_.checked()[0])
        assert not loaded.predictor.is_fitted  # the template stays unfitted
    with pytest.raises(ModelFileError, match="not a SymplecticKernelPredictor"):
        SymplecticKernelPredictor.load(tmp_path / "split.h5")


def _tampered(tmp_path, edit):
    settings, arrays = read_container(tmp_path / "split.h5", MODEL_FORMAT)
    settings, arrays = copy.deepcopy(settings), dict(arrays)
    edit(settings, arrays)
    write_container(tmp_path / "bad.h5", MODEL_FORMAT, settings, arrays)
    return tmp_path / "bad.h5"


@pytest.mark.parametrize(
    "edit, match",
    [
        (lambda s, a: a.update(quadratic_matrices=np.array([[[1.0, 2.0], [0.0, 1.0]]] * 2)), "not symmetric"),
        (lambda s, a: a.update(quadratic_matrices=np.zeros((2, 4, 4))), "do not fit"),
        (lambda s, a: a.update(quadratic_powers=np.zeros((2, 3))), "do not fit"),
        (lambda s, a: a.update(quadratic_powers=np.array([[np.nan], [1.0]])), "finite floats"),
        (lambda s, a: a.pop("quadratic_powers"), "expected the arrays"),
        (lambda s, a: a.update(extra=np.zeros(2)), "expected the arrays"),
        (lambda s, a: s.update(dim=3), "invalid dimensions"),
        (lambda s, a: s.update(n_mu=0), "do not fit|disagree"),
        (lambda s, a: s.update(hack="x"), "exactly the keys"),
        (lambda s, a: s["inner"].update({"class": "DirectKernelPredictor"}), "inner model must be"),
        (lambda s, a: a.update(inner_coef=a["inner_coef"][:3]), "has shape"),  # the inner model's own checks
        (lambda s, a: s.update(layout=99), "unknown layout"),
    ],
)
def test_malformed_model_files_are_refused(split_pendulum, tmp_path, edit, match):
    model, _ = split_pendulum
    save_model(model, tmp_path / "split.h5")
    path = _tampered(tmp_path, edit)
    with pytest.raises(ModelFileError, match=match):
        load_model(path)


def test_parameter_free_fixed_step_model_defaults_to_its_step():
    """No mu, one dT (dt_kernel=None): step() and rollout() use the training step; a Duffing-type oscillator
    H = (q^2 + p^2) / 2 + q^4 / 4 split around its quadratic part, against the unsplit model's own step."""
    rng = np.random.default_rng(2)
    quad = QuadraticPart([np.eye(2)])
    x0 = rng.uniform(-0.5, 0.5, (300, 2))

    def flow(x, t, n_sub=200):  # a fine Stormer-Verlet reference (kick-drift-kick)
        q, p, h = x[:, 0].copy(), x[:, 1].copy(), t / n_sub
        for _ in range(n_sub):
            p -= 0.5 * h * (q + q**3)
            q += h * p
            p -= 0.5 * h * (q + q**3)
        return np.column_stack([q, p])

    model = SplitKernelPredictor(
        SymplecticKernelPredictor(IMQ(1.0), max_centers=200, update="midpoint", solver=NewtonSolver(backend="numpy")),
        quad,
    ).fit(x0, flow(x0, 0.3), dt=0.3)
    assert model.n_mu_ == 0 and model.predictor_.dt_fixed_ == 0.3 and model.n_centers_ > 0
    x = rng.uniform(-0.3, 0.3, (5, 2))
    np.testing.assert_array_equal(model.step(x), model.step(x, dt=0.3))
    assert np.abs(model.step(x) - flow(x, 0.3)).max() < 1e-6
    with pytest.raises(ValueError, match="do not pass mu"):
        model.step(x, mu=0.5)
    with pytest.raises(ValueError, match="fixed step"):
        model.step(x, dt=0.2)
    traj = model.rollout(x, 10)
    np.testing.assert_allclose(traj[:, 2], model.step(model.step(x)), rtol=0, atol=1e-15)


def test_validation_data_are_transformed_too(small_pendulum_data, pendulum):
    """E_val(m) of the split model is the inner model's residual on the transformed validation pairs."""
    d = small_pendulum_data
    idx = np.random.default_rng(4).permutation(len(d))
    tr, va = idx[:400], idx[400:600]
    inner = SymplecticKernelPredictor(
        IMQ(0.4), IMQ(0.75), IMQ(1.06), max_centers=40, update="midpoint", solver=NewtonSolver(backend="numpy")
    )
    quad = pendulum.quadratic_part()
    model = SplitKernelPredictor(inner, quad).fit(
        d.x0[tr], d.x1[tr], mu=d.mu[tr], dt=d.dt[tr], validation=(d.x0[va], d.x1[va], d.mu[va], d.dt[va])
    )
    val = model.history_.val_max_residual
    assert val is not None and len(val) == model.n_centers_ + 1 and val[-1] < val[0]
    # the same residual from the inner model's surrogate on the pairs (L_h x0, L_{-h} x1) at their midpoints
    L = quad.propagator(d.mu[va], d.dt[va] / 2)
    y0 = np.einsum("bij,bj->bi", L, d.x0[va])
    y1 = np.einsum("bij,bj->bi", inverse_symplectic_matrices(L), d.x1[va])
    target = (y1 - y0) @ J2 / d.dt[va][:, None]  # J^T (y1 - y0) / dT, row-wise
    grad = model.predictor_.surrogate_gradient(0.5 * (y0 + y1), mu=d.mu[va], dt=d.dt[va])
    np.testing.assert_allclose(np.abs(grad - target).max(), val[-1], rtol=1e-6)
    with pytest.raises(ValueError, match="validation must be"):
        SplitKernelPredictor(inner, quad).fit(d.x0[tr], d.x1[tr], mu=d.mu[tr], dt=d.dt[tr], validation=3)
