"""The group-averaged (symmetry-invariant) state kernel (``symmetry=``): kernel and surrogate derivatives by
finite differences, exact invariance of s, exact interpolation, symplecticity and equivariance of the step,
the estimator contract, model files and refused input."""

import copy
import warnings
from functools import partial

import numpy as np
import pytest

from sympredict import DirectKernelPredictor, SymplecticKernelPredictor
from sympredict import _numba
from sympredict.interpolation import _compiled as compiled_surrogate
from sympredict.base import clone
from sympredict.exceptions import ExtrapolationWarning, ModelFileError
from sympredict.interpolation.functionals import (
    HBFunctionals,
    ValueFunctionals,
    dense_interpolation,
    functional_residuals,
)
from sympredict.interpolation.greedy import ActiveSetGreedy, ExactGreedy
from sympredict.io import load_model, save_model
from sympredict.kernels import IMQ, Matern52, PeriodicCoordinates, ProductKernel, StateSymmetry
from sympredict.estimators.predictor import update_variables
from sympredict.interpolation.surrogate import HBSurrogate
from sympredict.symplectic.solvers import NewtonSolver
from sympredict.kernels.transforms import Periodic, Scaled, Symmetric

from _tolerances import assert_same_predictions  # tests/
from _surrogate_oracles import (
    KLEIN,
    PENDULUM_DT,
    PENDULUM_LENGTH,
    assert_jacobians_symplectic,
    check_gramian_by_finite_differences,
    check_malformed_kernel_entries_refused,
    check_surrogate_by_finite_differences,
    pendulum_samples,
)  # tests/ (on sys.path under pytest)

LENGTH, DT = PENDULUM_LENGTH, PENDULUM_DT


def _rotations(k):
    """The cyclic group of the 2-D rotations by multiples of 2 pi / k (not signed permutations for k = 3)."""
    return [np.array([[np.cos(t), -np.sin(t)], [np.sin(t), np.cos(t)]]) for t in 2 * np.pi * np.arange(k) / k]


def _mode_swap():
    """4-D: exchange of the two modes ((q1, q2, p1, p2) -> (q2, q1, p2, p1)) and x -> -x: a group of order 4."""
    swap = np.eye(4)[[1, 0, 3, 2]]
    return [np.eye(4), swap, -np.eye(4), -swap]


GROUPS = [
    (2, StateSymmetry.from_signs(KLEIN)),
    (2, StateSymmetry(tuple(_rotations(3)))),
    (4, StateSymmetry(tuple(_mode_swap()))),
]
GROUP_IDS = ["klein", "rotations3", "modeswap4d"]


def _kernel_value(kernel, x, y, mu_x, mu_y):
    """``k_G((x, mu_x), (y, mu_y)) = sum_g phi(|x - g y|) k_mu``: the profile only (the oracle of the derivatives)."""
    return sum(kernel.state.phi(np.linalg.norm(x - g @ y)) for g in kernel.symmetry.array) * kernel.mu.phi(
        abs(mu_x - mu_y)
    )


@pytest.mark.parametrize("dim,group", GROUPS, ids=GROUP_IDS)
@pytest.mark.parametrize("state", [IMQ(0.7), Matern52(0.9)], ids=repr)
def test_gramian_entries_match_mixed_finite_differences(dim, group, state, rng):
    kernel = ProductKernel(state, IMQ(1.5), None, symmetry=group)
    pts, mu = rng.normal(size=(5, dim)), rng.normal(size=(5, 1))
    fun = HBFunctionals(kernel, pts, mu, np.full(5, 0.05))
    gram = check_gramian_by_finite_differences(fun, partial(_kernel_value, kernel), pts, mu)
    n = fun.n_functionals
    # an image g x_q of a point is the functional in the direction g e_b: column(g x_q, b) = sum_c g_cb column(x_q, c)
    for g in group.array[1:]:
        moved = HBFunctionals(kernel, pts @ g.T, mu, np.full(5, 0.05))
        for b in range(dim):
            col = fun.column(moved.representer(2 * dim + b), out=np.empty(n))
            np.testing.assert_allclose(col, gram[:, 2 * dim : 3 * dim] @ g.T[:, b], atol=1e-13 * np.abs(gram).max())


def test_fixed_points_give_zero_functionals():
    """At q = 0 the derivative d/dq is the zero functional of the Klein-invariant space (diagonal 0)."""
    kernel = ProductKernel(IMQ(0.8), symmetry=StateSymmetry.from_signs(KLEIN))
    fun = HBFunctionals(kernel, np.array([[0.0, 0.7], [0.4, 0.0], [0.3, -0.5]]), np.zeros((3, 0)), np.full(3, 0.05))
    diag = fun.diagonal()
    assert diag[0] == 0.0 and diag[3] == 0.0 and np.all(np.delete(diag, [0, 3]) > 0)
    np.testing.assert_allclose(fun.column(fun.representer(0), out=np.empty(6)), 0.0, atol=1e-15)  # round-off of 4 terms


@pytest.mark.parametrize("dim,group", GROUPS, ids=GROUP_IDS)
@pytest.mark.parametrize("state", [IMQ(0.7), Matern52(0.9)], ids=repr)
def test_surrogate_value_gradient_hessian_by_finite_differences(dim, group, state, rng):
    kernel = ProductKernel(state, IMQ(1.5), None, symmetry=group)
    m = 20
    centers, cmu = rng.normal(size=(m, dim)), rng.normal(size=(m, 1))
    comps, coef = rng.integers(0, dim, m), rng.normal(size=m)
    sur = HBSurrogate(kernel, centers, cmu, np.full(m, 0.05), comps, coef)
    assert sur.n_centers == m
    xi, qmu = rng.normal(size=(4, dim)), rng.normal(size=(4, 1))
    kernel_value = partial(_kernel_value, kernel)
    w, grad, hess, floor = check_surrogate_by_finite_differences(sur, kernel_value, centers, cmu, comps, coef, xi, qmu)
    # exactly invariant: s(g x) = s(x), grad s(g x) = g grad s(x), Hess s(g x) = g Hess s(x) g^T (to round-off)
    for g in group.array:
        gx = xi @ g.T
        np.testing.assert_allclose(sur.value(gx, w), sur.value(xi, w), atol=1e-14 * np.abs(coef).sum())
        grad_g, hess_g, floor_g = sur.gradient_hessian(gx, w, with_floor=True)
        assert np.all(np.abs(grad_g - grad @ g.T).max(axis=1) <= 10 * (floor + floor_g) + 1e-15)
        np.testing.assert_allclose(hess_g, g @ hess @ g.T, atol=1e-13 * np.abs(hess).max())
    if _numba.HAVE_NUMBA:  # the compiled pass: the same gradient, Hessian and floor (another summation order)
        g_c, h_c, f_c = compiled_surrogate.newton_terms(xi, w, sur.layout(), kernel.state, full=True)
        np.testing.assert_allclose(g_c, grad, rtol=0, atol=1e-13 * np.abs(w).sum(axis=1).max())
        np.testing.assert_allclose(h_c, hess, rtol=0, atol=1e-13 * np.abs(w).sum(axis=1).max())
        np.testing.assert_allclose(f_c, floor, rtol=1e-12)


def test_dense_interpolation_is_exact_and_invariant(rng):
    """All functionals of points in general position: the dense solve interpolates them exactly, and the
    interpolant of arbitrary (non-invariant) data is still exactly invariant."""
    group = StateSymmetry(tuple(_rotations(3)))
    kernel = ProductKernel(IMQ(0.9), symmetry=group)
    pts = rng.normal(size=(12, 2))
    fun = HBFunctionals(kernel, pts, np.zeros((12, 0)), np.full(12, 0.05))
    y = rng.normal(size=24)
    coef = dense_interpolation(fun, y)
    sur = HBSurrogate(kernel, pts.repeat(2, axis=0), np.zeros((24, 0)), np.full(24, 0.05), np.tile([0, 1], 12), coef)
    w = sur.weights(np.zeros((12, 0)), np.full(12, 0.05))
    np.testing.assert_allclose(sur.gradient(pts, w).reshape(-1), y, atol=1e-8)
    for g in group.array:
        np.testing.assert_allclose(sur.gradient(pts @ g.T, w), sur.gradient(pts, w) @ g.T, atol=1e-8)


@pytest.fixture(scope="module")
def data():
    """Pendulum samples at one length and step (librations and rotations)."""
    return pendulum_samples(2.5, 4.0)


def _model(symmetry=KLEIN, backend="numpy", tol=None, trainer=None, state_scaling=None, periodic=None, **kw):
    kw = {"max_centers": 300, "update": "midpoint", **kw}
    kernel = IMQ(0.5)
    if state_scaling is not None:
        kernel = Scaled(kernel, factors=state_scaling)
    if periodic is not None:
        kernel = Periodic(kernel, coordinates=periodic)
    kernel = Symmetric(kernel, group=symmetry)
    if tol is not None:
        trainer = (ExactGreedy() if trainer is None else trainer).set_params(tol=tol)
    return SymplecticKernelPredictor(kernel, trainer=trainer, solver=NewtonSolver(backend=backend), **kw)


@pytest.fixture(scope="module")
def fitted(data):
    return _model().fit(*data, dt=DT)


def test_interpolates_the_selected_functionals(fitted, data):
    x0, x1 = data
    xi, y = update_variables("midpoint", x0, x1, np.full(len(x0), DT))
    pts, comps = np.divmod(fitted.greedy_result_.selected, 2)
    g = fitted.surrogate_gradient(xi[pts], dt=DT)
    np.testing.assert_allclose(g[np.arange(len(pts)), comps], y[pts, comps], rtol=1e-7, atol=1e-7 * np.abs(y).max())
    fun = HBFunctionals(fitted.kernel_, xi, np.zeros((len(xi), 0)), np.full(len(xi), DT))
    res = functional_residuals(fun, y.reshape(-1), fitted.greedy_result_.selected, fitted.greedy_result_.coef)
    # (to the round-off of the Newton basis: coefficients ~1e6 times the data)
    assert np.abs(res).max() == pytest.approx(fitted.history_.train_max_residual[-1], abs=1e-10 * np.abs(y).max())
    with pytest.raises(ValueError, match="symmetry"):
        functional_residuals(
            fun, y.reshape(-1), fitted.greedy_result_.selected, fitted.greedy_result_.coef, compiled=True
        )
    # the same model at the mirrored samples: the gradient of s is mirrored (s is invariant, grad s(g z) = g grad s(z))
    for s in KLEIN:
        np.testing.assert_allclose(
            fitted.surrogate_gradient(xi[:50] * s, dt=DT),
            fitted.surrogate_gradient(xi[:50], dt=DT) * s,
            atol=1e-9 * np.abs(y).max(),
        )


def test_symmetry_lowers_the_residual_against_the_plain_kernel(fitted, data):
    """The invariant kernel on the same data and budget: a smaller training residual (the lever of issue 14)."""
    plain = _model(symmetry=None).fit(*data, dt=DT)
    assert fitted.history_.train_max_residual[-1] < 0.5 * plain.history_.train_max_residual[-1]


def test_step_symplectic_equivariant_and_reversible(fitted):
    x = np.array([[0.3, 0.1], [-1.2, 0.8], [0.05, -2.0], [1.0, 0.0]])
    jac = fitted.step_jacobian(x)
    assert_jacobians_symplectic(jac)
    # h balances the differences' O(h^2) against Newton's stopping floor (~1e-11 here: coefficients ~1e6)
    h = 3e-4
    fd = np.stack([(fitted.step(x + h * e) - fitted.step(x - h * e)) / (2 * h) for e in np.eye(2)], axis=2)
    np.testing.assert_allclose(fd, jac, atol=1e-7 * np.abs(jac).max())
    x1 = fitted.step(x)
    # x -> -x is symplectic: the learned step commutes with it; (q, p) -> (q, -p) and (-q, p) are reversing:
    # the step from R x1 lands on R x0 (the midpoint update with an R-invariant s is R-reversible)
    np.testing.assert_allclose(fitted.step(-x), -x1, atol=1e-12)
    for r in (np.array([1.0, -1.0]), np.array([-1.0, 1.0])):
        np.testing.assert_allclose(fitted.step(x1 * r), x * r, atol=1e-10)  # Newton's stopping floor


def test_active_set_trainer_and_truncation(data):
    x0, x1 = data[0][:300], data[1][:300]
    model = _model(max_centers=120, tol=0.0, trainer=ActiveSetGreedy(refresh_every=40)).fit(x0, x1, dt=DT)
    xi, y = update_variables("midpoint", x0, x1, np.full(len(x0), DT))
    fun = HBFunctionals(model.kernel_, xi, np.zeros((len(xi), 0)), np.full(len(xi), DT))
    res = functional_residuals(fun, y.reshape(-1), model.greedy_result_.selected, model.greedy_result_.coef)
    assert np.abs(res).max() == pytest.approx(model.history_.train_max_residual[-1], abs=1e-10 * np.abs(y).max())
    small = model.truncated(60)
    assert small.kernel_.symmetry == StateSymmetry.from_signs(KLEIN) and small.n_centers_ == 60


def test_sharded_trainer_selects_the_exact_greedys_centres(data):
    from sympredict.interpolation.greedy import ShardedGreedy

    x0, x1 = data[0][:200], data[1][:200]
    exact = _model(max_centers=60).fit(x0, x1, dt=DT)
    sharded = _model(max_centers=60, trainer=ShardedGreedy(n_shards=2)).fit(x0, x1, dt=DT)
    np.testing.assert_array_equal(sharded.greedy_result_.selected, exact.greedy_result_.selected)
    np.testing.assert_allclose(
        sharded.surrogate_.coef, exact.surrogate_.coef, rtol=0, atol=1e-10 * np.abs(exact.surrogate_.coef).max()
    )


def test_estimator_contract(data):
    model = _model()
    params = model.get_params()
    assert params["state_kernel"] == Symmetric(IMQ(0.5), group=KLEIN)
    copy = clone(model)
    assert repr(copy.get_params()) == repr(params) and not copy.is_fitted
    copy.set_params(state_kernel=IMQ(0.5), update="symplectic_euler")
    assert copy.state_kernel == IMQ(0.5) and model.state_kernel.group == KLEIN
    x0, x1 = data[0][:100], data[1][:100]
    as_group = _model(symmetry=StateSymmetry.from_signs(KLEIN), max_centers=40).fit(x0, x1, dt=DT)
    as_list = _model(max_centers=40).fit(x0, x1, dt=DT)
    assert as_group.kernel_ == as_list.kernel_
    np.testing.assert_array_equal(as_group.step(x0[:3]), as_list.step(x0[:3]))
    # type II: x -> -x (diag(A, A) with A = -1) is allowed; the model's s is then odd-point invariant
    t2 = _model(update="symplectic_euler", symmetry=[(1, 1), (-1, -1)], max_centers=40).fit(x0, x1, dt=DT)
    np.testing.assert_allclose(t2.step(-x0[:3]), -t2.step(x0[:3]), atol=1e-12)


@pytest.mark.parametrize(
    "matrices",
    [
        lambda: StateSymmetry.from_signs(KLEIN),
        lambda: KLEIN,
        lambda: tuple(tuple(s) for s in KLEIN),
        lambda: [np.diag(s).tolist() for s in KLEIN],
    ],
    ids=["group", "list", "tuples", "matrices"],
)
def test_model_files_round_trip(data, tmp_path, matrices):
    x0, x1 = data[0][:200], data[1][:200]
    model = _model(symmetry=matrices(), max_centers=60).fit(x0, x1, dt=DT)
    save_model(model, tmp_path / "s.h5")
    back = load_model(tmp_path / "s.h5")
    assert back.get_params() == model.get_params() and type(back.state_kernel.group) is type(model.state_kernel.group)
    assert back.kernel_ == model.kernel_ and back.kernel_.symmetry == StateSymmetry.from_signs(KLEIN)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ExtrapolationWarning)  # 200 samples: a rollout may leave them
        np.testing.assert_array_equal(back.rollout(x0[:3], 5), model.rollout(x0[:3], 5))


def test_model_files_refused(data, tmp_path):
    from sympredict.container import read_container, write_container
    from sympredict.estimators.predictor import MODEL_FORMAT

    model = _model(max_centers=30).fit(data[0][:100], data[1][:100], dt=DT)
    save_model(model, tmp_path / "s.h5")
    settings, arrays = read_container(tmp_path / "s.h5", MODEL_FORMAT)
    eye = [[1.0, 0.0], [0.0, 1.0]]
    bad_specs = [
        None,
        {"matrices": [eye, [[-1.0, 0.0], [0.0, -1.0]]]},
        {"matrices": [eye, [[2.0, 0.0], [0.0, 1.0]]]},
        {"matrices": [eye, [[1.0, 0.0], [0.0, -1.0]], [[-1.0, 0.0], [0.0, 1.0]]]},
        {"matrices": "klein"},
        [1, 2],
    ]
    check_malformed_kernel_entries_refused(tmp_path / "bad.h5", settings, arrays, "symmetry", bad_specs)
    # settings with a non-group symmetry are refused too
    bad = {
        **settings,
        "params": {
            **settings["params"],
            "symmetry": {"list": [{"list": [1, 1]}, {"list": [1, -1]}, {"list": [-1, 1]}]},
        },
    }
    write_container(tmp_path / "bad.h5", MODEL_FORMAT, bad, arrays)
    with pytest.raises(ModelFileError):
        load_model(tmp_path / "bad.h5")
    # a plain model's file has no symmetry entry (unchanged layout)
    plain = _model(symmetry=None, max_centers=20).fit(data[0][:100], data[1][:100], dt=DT)
    save_model(plain, tmp_path / "plain.h5")
    assert "symmetry" not in read_container(tmp_path / "plain.h5", MODEL_FORMAT)[0]["kernel"]


def test_refused_input(data):
    x0, x1 = data[0][:60], data[1][:60]
    shear = np.array([[1.0, 0.5], [0.0, 1.0]])
    cases = [
        ([(1, 1), (-1, -1), (1, -1)], "not a group"),  # not closed
        ([(-1, -1), (1, 1), (-1, -1)], "distinct"),
        ([(-1, -1)], "identity"),
        ([(1, 1), (0, 1)], "sign patterns"),
        ([(1, 1), (2, -1)], "sign patterns"),
        ([(1, 1, 1), (-1, -1, -1)], "dimension"),  # 3 components for 2n = 2
        ([np.eye(2), shear], "orthogonal"),
        ([np.eye(2), np.eye(3)], "one size"),
        ("klein", "symmetry must be"),
        ([np.eye(2), np.full((2, 2), np.nan)], "finite"),
    ]
    for symmetry, match in cases:
        with pytest.raises(ValueError, match=match):
            _model(symmetry=symmetry).fit(x0, x1, dt=DT)
    with pytest.raises(ValueError, match="diag\\(A, A\\)"):  # q -> -q is no symmetry of the type-II s
        _model(update="symplectic_euler").fit(x0, x1, dt=DT)
    # 4-D: flipping p1 only is neither symplectic nor anti-symplectic
    flip = np.diag([1.0, 1.0, -1.0, 1.0])
    x4 = np.concatenate([x0, x0[::-1]], axis=1)
    with pytest.raises(ValueError, match="neither symplectic"):
        _model(symmetry=[np.eye(4), flip]).fit(x4, x4 + 0.01, dt=DT)
    # a mode swap does not commute with a scaling that differs between the modes
    with pytest.raises(ValueError, match="state_scaling"):
        _model(symmetry=_mode_swap(), state_scaling=(1.0, 2.0)).fit(x4, x4 + 0.01, dt=DT)
    _model(symmetry=_mode_swap(), state_scaling=(2.0, 2.0), max_centers=10).fit(x4, x4 + 0.01, dt=DT)
    if _numba.HAVE_NUMBA:  # a symmetric model runs compiled (tests/kernels/test_transforms_compiled.py)
        assert _model(backend="numba", max_centers=20).fit(x0, x1, dt=DT).numpy_only_ is None
    # Periodic with Symmetric: the group must map periodic coordinates onto ones of the same period
    with pytest.raises(ValueError, match="same period"):
        _model(symmetry=_mode_swap(), periodic=(0,)).fit(x4, x4 + 0.01, dt=DT)
    with pytest.raises(ValueError, match="same period"):
        ProductKernel(IMQ(1.0), periodic=PeriodicCoordinates((0,), (1.0,)), symmetry=StateSymmetry(tuple(_mode_swap())))
    ProductKernel(IMQ(1.0), periodic=PeriodicCoordinates((0,), (1.0,)), symmetry=StateSymmetry.from_signs(KLEIN))
    ProductKernel(
        IMQ(1.0), periodic=PeriodicCoordinates((0, 1), (1.0, 1.0)), symmetry=StateSymmetry(tuple(_mode_swap()))
    )
    with pytest.raises(ValueError, match="direct model"):
        ValueFunctionals(
            ProductKernel(IMQ(1.0), symmetry=StateSymmetry.from_signs(KLEIN)), x0, np.zeros((60, 0)), np.full(60, DT)
        )
    model = _model(max_centers=20).fit(x0, x1, dt=DT)
    if _numba.HAVE_NUMBA:
        assert_same_predictions(copy.copy(model).set_params(solver__backend="numba"), model, x0[:2], 3)
    assert "symmetry" not in DirectKernelPredictor().get_params()


def test_state_scaling_with_sign_flips(data):
    """Sign flips commute with the diagonal scaling (a q, p / a): the kernel's group is the same, the step equivariant."""
    x0, x1 = data[0][:300], data[1][:300]
    model = _model(state_scaling=(2.0,), max_centers=150).fit(x0, x1, dt=DT)
    assert model.kernel_.symmetry == StateSymmetry.from_signs(KLEIN)
    x = np.array([[0.3, 0.1], [-1.2, 0.8]])
    np.testing.assert_allclose(model.step(-x), -model.step(x), atol=1e-12)
    jac = model.step_jacobian(x)
    assert_jacobians_symplectic(jac)
