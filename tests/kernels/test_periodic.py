"""The periodic kernel factor for angle coordinates (``periodic=``): formulas by finite differences, exact
interpolation, symplecticity, exact periodicity of the learned s, backends, model files, a rotating pendulum."""

import copy
import importlib.util
import pathlib
import warnings
from functools import partial

import numpy as np
import pytest

from sympredict import SymplecticKernelPredictor
from sympredict import _numba
from sympredict.interpolation import _compiled as compiled_surrogate
from sympredict.base import clone
from sympredict.exceptions import ExtrapolationWarning
from sympredict.interpolation.functionals import HBFunctionals, functional_residuals
from sympredict.io import load_model, save_model
from sympredict.kernels import IMQ, Matern52, PeriodicCoordinates, ProductKernel
from sympredict.estimators.predictor import update_variables
from sympredict.interpolation.surrogate import HBSurrogate
from sympredict.symplectic.solvers import NewtonSolver
from sympredict.kernels.transforms import Periodic, Scaled

from _tolerances import assert_same_predictions  # tests/
from _surrogate_oracles import (
    PENDULUM_DT,
    PENDULUM_LENGTH,
    assert_jacobians_symplectic,
    check_gramian_by_finite_differences,
    check_malformed_kernel_entries_refused,
    check_surrogate_by_finite_differences,
    pendulum_samples,
)  # tests/ (on sys.path under pytest)

LENGTH, DT = PENDULUM_LENGTH, PENDULUM_DT

PERIODICS = [(2, PeriodicCoordinates((0,), (2 * np.pi,))), (4, PeriodicCoordinates((0, 3), (2 * np.pi, 1.7)))]


def _shift(periodic, dim, k=1):
    s = np.zeros(dim)
    for i, period in zip(periodic.coordinates, periodic.periods):
        s[i] = k * period
    return s


def test_formulas_against_finite_differences():
    """g = d(u^2/2)/dd, g' and g'' by central differences; u^2 = (P/pi)^2 sin^2(pi d/P); P-periodic; = d near 0."""
    period = 1.7
    d = np.linspace(-7.0, 7.0, 301)
    u, g, g1, g2 = PeriodicCoordinates.formulas(d, period)
    h = 1e-5
    up, gp, g1p, _ = PeriodicCoordinates.formulas(d + h, period)
    um, gm, g1m, _ = PeriodicCoordinates.formulas(d - h, period)
    np.testing.assert_allclose(g, (up**2 - um**2) / (4 * h), atol=1e-9)
    np.testing.assert_allclose(g1, (gp - gm) / (2 * h), atol=1e-9)
    np.testing.assert_allclose(g2, (g1p - g1m) / (2 * h), atol=1e-8)
    np.testing.assert_allclose(u**2, (period / np.pi) ** 2 * np.sin(np.pi * d / period) ** 2, rtol=1e-13, atol=1e-15)
    shifted = PeriodicCoordinates.formulas(d + 3 * period, period)
    np.testing.assert_allclose(shifted[0] ** 2, u**2, atol=1e-13)  # u itself changes sign every period
    for a, b in zip((g, g1, g2), shifted[1:]):
        np.testing.assert_allclose(b, a, atol=1e-12)
    small = np.array([1e-6, -2e-5])
    np.testing.assert_allclose(PeriodicCoordinates.formulas(small, period)[1], small, rtol=1e-9)
    # the other coordinates are passed through: g = d, g' = 1, g'' = 0
    diff = np.random.default_rng(0).normal(size=(3, 4))
    r, G, G1, G2 = PeriodicCoordinates((1,), (period,)).terms(diff, order=3)
    np.testing.assert_array_equal(G[:, [0, 2, 3]], diff[:, [0, 2, 3]])
    assert np.all(G1[:, [0, 2, 3]] == 1.0) and np.all(G2[:, [0, 2, 3]] == 0.0)
    u1 = PeriodicCoordinates.formulas(diff[:, 1], period)[0]
    np.testing.assert_allclose(r, np.sqrt(diff[:, 0] ** 2 + u1**2 + diff[:, 2] ** 2 + diff[:, 3] ** 2), rtol=1e-14)


def _kernel_value(kernel, x, y, mu_x, mu_y):
    """``k((x, mu_x), (y, mu_y))`` from the profile and the periodic distance only (the oracle of the derivatives)."""
    r = kernel.periodic.distances((x - y)[None])[0]
    return kernel.state.phi(r) * kernel.mu.phi(np.abs(mu_x - mu_y))


@pytest.mark.parametrize("dim,periodic", PERIODICS)
@pytest.mark.parametrize("state", [IMQ(0.7), Matern52(0.9)], ids=repr)
def test_gramian_entries_match_mixed_finite_differences(dim, periodic, state, rng):
    kernel = ProductKernel(state, IMQ(1.5), None, periodic)
    pts = rng.normal(size=(5, dim)) * 3.0  # spread over more than one period
    mu = rng.normal(size=(5, 1))
    fun = HBFunctionals(kernel, pts, mu, np.full(5, 0.05))
    gram = check_gramian_by_finite_differences(fun, partial(_kernel_value, kernel), pts, mu, rtol=1e-14, atol=1e-16)
    n = fun.n_functionals
    # a point one period away is the same functional: identical Gramian column
    moved = HBFunctionals(kernel, pts + _shift(periodic, dim, 3), mu, np.full(5, 0.05))
    col = fun.column(moved.representer(3), out=np.empty(n))
    np.testing.assert_allclose(col, gram[:, 3], atol=1e-13)


@pytest.mark.parametrize("dim,periodic", PERIODICS)
@pytest.mark.parametrize("state", [IMQ(0.7), Matern52(0.9)], ids=repr)
def test_surrogate_value_gradient_hessian_by_finite_differences(dim, periodic, state, rng):
    kernel = ProductKernel(state, IMQ(1.5), None, periodic)
    m = 20
    centers, cmu = rng.normal(size=(m, dim)) * 3.0, rng.normal(size=(m, 1))
    comps, coef = rng.integers(0, dim, m), rng.normal(size=m)
    sur = HBSurrogate(kernel, centers, cmu, np.full(m, 0.05), comps, coef)
    xi, qmu = rng.normal(size=(4, dim)) * 3.0, rng.normal(size=(4, 1))
    w, grad, hess, floor = check_surrogate_by_finite_differences(
        sur, partial(_kernel_value, kernel), centers, cmu, comps, coef, xi, qmu
    )
    np.testing.assert_allclose(hess, hess.transpose(0, 2, 1), atol=1e-13 * np.abs(hess).max())
    # exactly periodic: value, gradient and Hessian at xi + k P
    for k in (1, -4, 50):
        s = _shift(periodic, dim, k)
        np.testing.assert_allclose(
            sur.value(xi + s, w), sur.value(xi, w), atol=1e-13 * (1 + abs(k)) * np.abs(coef).sum()
        )
        g_s, h_s = sur.gradient_hessian(xi + s, w)
        np.testing.assert_allclose(g_s, grad, atol=1e-13 * (1 + abs(k)) * np.abs(coef).sum())
        np.testing.assert_allclose(h_s, hess, atol=1e-12 * (1 + abs(k)) * np.abs(coef).sum())
    if _numba.HAVE_NUMBA:  # the compiled pass: the same gradient, Hessian and floor (another summation order)
        g_c, h_c, f_c = compiled_surrogate.newton_terms(xi, w, sur.layout(), kernel.state, full=True)
        np.testing.assert_allclose(g_c, grad, rtol=0, atol=1e-13 * np.abs(w).sum(axis=1).max())
        np.testing.assert_allclose(h_c, hess, rtol=0, atol=1e-13 * np.abs(w).sum(axis=1).max())
        np.testing.assert_allclose(f_c, floor, rtol=1e-12)


@pytest.fixture(scope="module")
def data():
    """Pendulum samples at one length and step (angles of x0 in [-pi, pi), x1 the true image (rotations included))."""
    return pendulum_samples(np.pi, 5.5)


def _model(update="symplectic_euler", periodic=(0,), period=2 * np.pi, backend="numpy", state_scaling=None, **kw):
    kw = {"max_centers": 400, **kw}
    kernel = Periodic(Scaled(IMQ(0.5), factors=state_scaling), coordinates=periodic, period=period)
    return SymplecticKernelPredictor(kernel, update=update, solver=NewtonSolver(backend=backend), **kw)


@pytest.fixture(scope="module", params=["symplectic_euler", "midpoint"])
def fitted(request, data):
    x0, x1 = data
    return _model(request.param).fit(x0, x1, dt=DT)


# rotating states, far outside the training angles
X_FAR = np.array([[3.0 + 40 * np.pi, 3.0], [-3.1 - 8 * np.pi, -3.2], [0.3, 4.8], [-2.0 + 1e3, 2.0]])


def test_interpolates_the_selected_functionals(fitted, data):
    x0, x1 = data
    xi, y = update_variables(fitted.update, x0, x1, np.full(len(x0), DT))
    pts, comps = np.divmod(fitted.greedy_result_.selected, 2)
    g = fitted.surrogate_gradient(xi[pts], dt=DT)
    np.testing.assert_allclose(g[np.arange(len(pts)), comps], y[pts, comps], rtol=1e-7, atol=1e-7 * np.abs(y).max())
    # the greedy's claimed residual is the model's (direct evaluation, NumPy: the compiled one refuses)
    fun = HBFunctionals(fitted.kernel_, xi, np.zeros((len(xi), 0)), np.full(len(xi), DT))
    res = functional_residuals(fun, y.reshape(-1), fitted.greedy_result_.selected, fitted.greedy_result_.coef)
    assert np.abs(res).max() == pytest.approx(fitted.history_.train_max_residual[-1], rel=1e-6)
    with pytest.raises(ValueError, match="periodic"):
        functional_residuals(
            fun, y.reshape(-1), fitted.greedy_result_.selected, fitted.greedy_result_.coef, compiled=True
        )


def test_step_symplectic_finite_differences_and_periodic(fitted):
    x = X_FAR
    jac = fitted.step_jacobian(x)
    assert_jacobians_symplectic(jac)
    h = 1e-5
    fd = np.stack([(fitted.step(x + h * e) - fitted.step(x - h * e)) / (2 * h) for e in np.eye(2)], axis=2)
    np.testing.assert_allclose(fd, jac, atol=1e-7 * np.abs(jac).max())
    # the learned s is exactly 2 pi periodic in q (round-off of q's size), so the step commutes with q -> q + 2 pi k
    sur, w = fitted.surrogate_, fitted.surrogate_.weights(np.zeros((len(x), 0)), np.full(len(x), DT))
    base = x.copy()
    base[:, 0] = np.mod(base[:, 0] + np.pi, 2 * np.pi) - np.pi
    k = np.round((x[:, 0] - base[:, 0]) / (2 * np.pi))
    scale = np.abs(sur.coef).sum() * np.abs(x).max() * np.finfo(float).eps * 100
    np.testing.assert_allclose(sur.value(x, w), sur.value(base, w), atol=scale)
    shift = np.column_stack([2 * np.pi * k, np.zeros(len(x))])
    np.testing.assert_allclose(fitted.step(x) - shift, fitted.step(base), atol=1e-10 * np.abs(x).max())


def test_rotating_orbit_without_wrapping(fitted):
    """1,000 steps of rotating orbits: q grows by ~150 rad, no extrapolation warning, energy kept to ~1e-5."""
    from sympredict.systems.pendulum import Pendulum

    x = X_FAR[:3] - np.array([[40 * np.pi, 0], [-8 * np.pi, 0], [0, 0]])
    with warnings.catch_warnings():
        warnings.simplefilter("error", ExtrapolationWarning)
        traj = fitted.rollout(x, 1000)
    assert np.all(np.abs(traj[:, -1, 0]) > 100)
    h = (
        Pendulum()
        .hamiltonian(traj.reshape(-1, 2), np.full(traj.shape[0] * traj.shape[1], LENGTH))
        .reshape(traj.shape[:2])
    )
    assert (np.abs(h - h[:, :1]) / h[:, :1]).max() < 1e-4


def test_without_periodic_factor_the_same_orbit_extrapolates(data):
    x0, x1 = data
    plain = _model(periodic=None).fit(x0, x1, dt=DT)
    with pytest.warns(ExtrapolationWarning, match="leave the training states"):
        try:
            plain.rollout(X_FAR[2:3], 300)
        except ArithmeticError:
            pass  # Newton may fail out there as well; the warning comes first only if it does not


def test_backends_and_settings(data):
    x0, x1 = data[0][:60], data[1][:60]
    model = _model(backend="auto").fit(x0, x1, dt=DT)  # auto: NumPy for this little work, compiled for more
    ref = _model(backend="numpy").fit(x0, x1, dt=DT)
    assert model.numpy_only_ is None and model.backend_for(10_000, 10_000) == "numba"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ExtrapolationWarning)  # 60 samples: a rollout soon leaves them
        assert_same_predictions(model, ref, x0[:3], 5)  # auto may run compiled once this process has loaded it
        if _numba.HAVE_NUMBA:  # periodic coordinates run compiled (tests/kernels/test_transforms_compiled.py)
            assert_same_predictions(copy.copy(ref).set_params(solver__backend="numba"), ref, x0[:3], 5)
    for bad in ((2,), (0, 0), (-1,), "0", (0.0,), (True,)):
        with pytest.raises(ValueError, match="periodic"):
            _model(periodic=bad).fit(x0, x1, dt=DT)
    for bad in (0.0, -1.0, float("inf"), (1.0, 2.0), "2pi"):
        with pytest.raises(ValueError, match="period"):
            _model(period=bad).fit(x0, x1, dt=DT)
    # duplicates one period apart are duplicates for the kernel (a period and angles whose wrapping is exact)
    xa = np.array([[0.5, 1.0], [1.25, -2.0], [4.5, 1.0]])
    with pytest.raises(ValueError, match="contradictory samples"):
        _model(period=4.0).fit(xa, xa + 0.01, dt=DT)
    _model(period=2 * np.pi, max_centers=4).fit(xa, xa + 0.01, dt=DT)  # not duplicates for another period
    params = _model(period=3.0).get_params()
    assert params["state_kernel"].coordinates == (0,) and params["state_kernel"].period == 3.0
    assert clone(_model(period=3.0)).get_params() == params


def test_period_and_state_scaling(data):
    """The period is in the original coordinates; with state_scaling (a q, p/a) the kernel's period is a P."""
    x0, x1 = data[0][:300], data[1][:300]
    model = _model(state_scaling=(2.0,), max_centers=200).fit(x0, x1, dt=DT)
    assert model.kernel_.periodic == PeriodicCoordinates((0,), (4 * np.pi,))
    x = X_FAR[:2]
    base = x.copy()
    base[:, 0] = np.mod(base[:, 0] + np.pi, 2 * np.pi) - np.pi
    shift = np.column_stack([x[:, 0] - base[:, 0], np.zeros(2)])
    np.testing.assert_allclose(model.step(x) - shift, model.step(base), atol=1e-11 * np.abs(x).max())
    jac = model.step_jacobian(x)
    assert_jacobians_symplectic(jac)


def test_model_files(data, tmp_path):
    x0, x1 = data[0][:200], data[1][:200]
    model = _model(max_centers=80, period=2 * np.pi).fit(x0, x1, dt=DT)
    save_model(model, tmp_path / "p.h5")
    back = load_model(tmp_path / "p.h5")
    assert back.get_params() == model.get_params() and type(back.periodic_[0]) is int
    assert back.kernel_ == model.kernel_ and back.kernel_.periodic == PeriodicCoordinates((0,), (2 * np.pi,))
    np.testing.assert_array_equal(back.rollout(X_FAR[:2], 5), model.rollout(X_FAR[:2], 5))
    # a file whose kernel and settings disagree is refused
    from sympredict.container import read_container
    from sympredict.estimators.predictor import MODEL_FORMAT

    settings, arrays = read_container(tmp_path / "p.h5", MODEL_FORMAT)
    check_malformed_kernel_entries_refused(
        tmp_path / "bad.h5",
        settings,
        arrays,
        "periodic",
        ({"coordinates": [0], "periods": [3.0]}, None, {"coordinates": [0]}, {"coordinates": [5], "periods": [1.0]}),
    )
    # and a plain model's file has no periodic entry (unchanged layout)
    plain = _model(periodic=None, max_centers=20).fit(x0, x1, dt=DT)
    save_model(plain, tmp_path / "plain.h5")
    settings, _ = read_container(tmp_path / "plain.h5", MODEL_FORMAT)
    assert "periodic" not in settings["kernel"]


def _benchmark():
    path = pathlib.Path(__file__).resolve().parents[2] / "sympredict_paper" / "studies" / "rotating_pendulum.py"
    spec = importlib.util.spec_from_file_location("rotating_pendulum_benchmark", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_rotating_pendulum_benchmark_small():
    """A small version of sympredict_paper/studies/rotating_pendulum.py: the periodic model keeps the energy of rotating
    orbits (q unwrapped) and beats the same model without the factor, unwrapped and wrapped."""
    out = _benchmark().run(
        n_q=24, n_p=24, eps_grid=(0.5,), max_centers=500, n_val=3, n_test=6, n_steps=300, log=lambda s: None
    )
    v = out["variants"]
    assert v["periodic"]["test_failed"] == 0 and v["periodic"]["test_max"] < 1e-3
    assert v["periodic"]["test_median"] < v["plain_wrapped"]["test_median"]
    assert v["periodic"]["test_median"] < v["plain"]["test_median"]
