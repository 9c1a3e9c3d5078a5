"""The compiled Newton solver for every state-kernel transform (Periodic, Symmetric, with Scaled) against NumPy.

Oracles: the NumPy surrogate's gradient, Hessian and floor (:meth:`HBSurrogate.gradient_hessian`, itself
checked against finite differences of the kernel's value in ``tests/kernels/test_periodic.py`` and
``tests/kernels/test_symmetry.py``) for the compiled pass; the NumPy rollout (:func:`implicit_rollout`) for the
compiled rollout, to the stopping rule's bound (``tests/_tolerances.py``); the group invariance
``s(g x) = s(x)`` and the period of the compiled gradient.
"""

import copy
import warnings

import numpy as np
import pytest
from scipy.linalg import expm

from sympredict import SymplecticKernelPredictor
from sympredict import _numba
from sympredict.interpolation import _compiled as compiled_surrogate
from sympredict.estimators.predictor import NUMPY_ONLY
from sympredict.exceptions import ExtrapolationWarning
from sympredict.kernels import IMQ, Matern52, PeriodicCoordinates, ProductKernel, StateSymmetry
from sympredict.kernels.transforms import Periodic, Scaled, Symmetric, lower_state_kernel
from sympredict.interpolation.surrogate import HBSurrogate
from sympredict.symplectic.solvers import NewtonSolver
from sympredict.symplectic.updates import Midpoint, SymplecticEuler

from _surrogate_oracles import (
    KLEIN,
    check_rollouts_agree_to_the_floor,
    klein_midpoint_predictor,
    pendulum_queries,
    with_backend,
)  # tests/

pytestmark = pytest.mark.skipif(not _numba.HAVE_NUMBA, reason="the compiled solver needs numba (optional extra)")


def _chain(dt=0.2, n=2, size=300, seed=3):
    """Samples of a linear chain of ``n`` oscillators (2n = 4): symmetric under x -> -x and p -> -p (reversing)."""
    k = 2.0 * np.eye(n) - np.eye(n, k=1) - np.eye(n, k=-1)
    a = np.zeros((2 * n, 2 * n))
    a[:n, n:] = np.eye(n)
    a[n:, :n] = -k
    x0 = np.random.default_rng(seed).uniform(-1, 1, (size, 2 * n))
    return x0, x0 @ expm(dt * a).T


PENDULUM_CASES = {
    "symmetric_klein_midpoint": (lambda: Symmetric(IMQ(0.3), group=KLEIN), "midpoint"),
    "symmetric_scaled_midpoint": (lambda: Symmetric(Scaled(IMQ(0.3), factors=(1.4,)), group=KLEIN), "midpoint"),
    "symmetric_euler": (lambda: Symmetric(IMQ(0.3), group=[(1, 1), (-1, -1)]), "symplectic_euler"),
    "periodic_euler": (lambda: Periodic(IMQ(0.3), coordinates=(0,), period=8.0), "symplectic_euler"),
    "periodic_scaled_midpoint": (
        lambda: Periodic(Scaled(Matern52(0.3), factors=(0.8,)), coordinates=(0,), period=8.0),
        "midpoint",
    ),
}


@pytest.fixture(scope="module", params=sorted(PENDULUM_CASES))
def pendulum_transform(request, small_pendulum_data):
    kernel, update = PENDULUM_CASES[request.param]
    d = small_pendulum_data
    model = SymplecticKernelPredictor(
        kernel(),
        mu_kernel=IMQ(2.0),
        dt_kernel=IMQ(5.0),
        max_centers=80,
        update=update,
        solver=NewtonSolver(backend="numpy"),
    )
    return model.fit(d.x0, d.x1, mu=d.mu, dt=d.dt)


def test_compiled_transform_rollout_equals_numpy_to_the_stopping_rule(pendulum_transform, rng):
    """2n = 2: the compiled rollout (batch: threads; one trajectory: serial) against NumPy's, to the rule's bound."""
    ref_model = pendulum_transform
    fast = with_backend(ref_model, "numba")
    assert fast._compiled() and fast.numpy_only_ is None and with_backend(ref_model, "auto").numpy_only_ is None
    x, mu, dt = pendulum_queries(rng, 12)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ExtrapolationWarning)
        ref, bound = check_rollouts_agree_to_the_floor(ref_model, fast, x, mu, dt, n_steps=30)
        assert np.abs(ref[:, -1] - ref[:, 0]).max() > 0.05  # the states move
        batch = fast.rollout(x, 30, mu=mu, dt=dt)
        one = fast.rollout(x[4], 30, mu=mu[4], dt=dt[4])
    np.testing.assert_array_equal(one, batch[4])  # bit-reproducible across batch sizes (serial vs threads)
    np.testing.assert_allclose(fast.step(x, mu=mu, dt=dt), ref[:, 1], rtol=0, atol=bound)


CHAIN_CASES = {
    "symmetric_reversing_midpoint": (
        lambda: Symmetric(IMQ(0.5), group=[(1, 1, 1, 1), (-1, -1, -1, -1), (1, 1, -1, -1), (-1, -1, 1, 1)]),
        "midpoint",
    ),
    "symmetric_scaled_euler": (
        lambda: Symmetric(Scaled(IMQ(0.5), factors=(1.2, 1.2)), group=[(1, 1, 1, 1), (-1, -1, -1, -1)]),
        "symplectic_euler",
    ),
    "periodic_two_angles_midpoint": (lambda: Periodic(IMQ(0.5), coordinates=(0, 1), period=(3.0, 4.0)), "midpoint"),
    "periodic_momentum_euler": (
        lambda: Periodic(Scaled(IMQ(0.5), factors=(1.1, 0.9)), coordinates=(1, 2), period=5.0),
        "symplectic_euler",
    ),
}


@pytest.mark.parametrize("case", sorted(CHAIN_CASES))
def test_compiled_transform_rollout_equals_numpy_at_2n_4(case, rng):
    """2n = 4 (the chunked pass, not the 2n = 2 one): every transform on both updates against NumPy."""
    kernel, update = CHAIN_CASES[case]
    x0, x1 = _chain()
    ref_model = SymplecticKernelPredictor(
        kernel(), max_centers=120, update=update, solver=NewtonSolver(backend="numpy")
    ).fit(x0, x1, dt=0.2)
    fast = with_backend(ref_model, "numba")
    assert fast._compiled()
    x = rng.uniform(-0.6, 0.6, (6, 4))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ExtrapolationWarning)
        ref = ref_model.rollout(x, 25)
        out = fast.rollout(x, 25)
    from _tolerances import rollout_bound  # tests/

    sur = ref_model.surrogate_
    scale = ref_model._scale_vector(4)
    dt = np.full(6, 0.2)
    bound = rollout_bound(sur, ref * scale, sur.weights(np.zeros((6, 0)), dt), dt)
    assert bound < 1e-5
    assert np.abs(ref[:, -1] - ref[:, 0]).max() > 0.1
    np.testing.assert_allclose(out, ref, rtol=0, atol=bound)


def _surrogate(kernel, dim, m, rng):
    comps = rng.integers(0, dim, m)
    comps[: m // 2] = 1  # one long segment: several chunks of one component
    return HBSurrogate(
        kernel,
        rng.uniform(-1, 1, (m, dim)),
        rng.uniform(0, 1, (m, 1)),
        np.ones(m),
        comps,
        1e-2 * rng.standard_normal(m),
    )


@pytest.mark.parametrize("dim", [2, 6])
@pytest.mark.parametrize("transform", ["periodic", "symmetric", "both_scaled_periods"])
def test_compiled_pass_equals_numpy_for_transformed_kernels(dim, transform, rng):
    """Gradient, Hessian block, full Hessian and floor of the compiled pass against the NumPy surrogate's."""
    if transform == "periodic":
        kernel = ProductKernel(IMQ(0.5), IMQ(1.0), periodic=PeriodicCoordinates((0, dim - 1), (2.5, 3.0)))
    elif transform == "symmetric":
        signs = np.ones(dim)
        signs[dim // 2 :] = -1  # p -> -p: anti-symplectic, as the midpoint update takes
        kernel = ProductKernel(IMQ(0.5), IMQ(1.0), symmetry=StateSymmetry.from_signs([np.ones(dim), signs]))
    else:  # periodic in every coordinate, periods unlike the data's spread
        kernel = ProductKernel(
            Matern52(0.7), IMQ(1.0), periodic=PeriodicCoordinates(tuple(range(dim)), tuple(1.5 + np.arange(dim)))
        )
    m = 1500
    sur = _surrogate(kernel, dim, m, rng)
    assert np.diff(sur.layout().seg).max() > compiled_surrogate.chunk_size(dim)
    xi = rng.uniform(-1.5, 1.5, (5, dim))
    w = sur.weights(rng.uniform(0, 1, (5, 1)), np.ones(5))
    g_ref, h_ref, f_ref = sur.gradient_hessian(xi, w, with_floor=True)
    scale = np.abs(w).sum(axis=1).max() * 10  # the terms are O(|w|): round-off of sums of ~m of them
    g, h, f = compiled_surrogate.newton_terms(xi, w, sur.layout(), kernel.state, full=True)
    np.testing.assert_allclose(g, g_ref, rtol=0, atol=1e-14 * scale)
    np.testing.assert_allclose(h, h_ref, rtol=0, atol=1e-14 * scale)
    np.testing.assert_allclose(f, f_ref, rtol=1e-12)
    n = dim // 2
    gb, hb, fb = compiled_surrogate.newton_terms(xi, w, sur.layout(), kernel.state)
    np.testing.assert_allclose(gb, g_ref, rtol=0, atol=1e-14 * scale)
    np.testing.assert_allclose(hb, h_ref[:, :n, n:], rtol=0, atol=1e-14 * scale)
    grad = compiled_surrogate.gradients(xi, np.zeros(5, dtype=np.int64), w[:1], sur.layout(), kernel.state)
    np.testing.assert_allclose(grad[:1], g_ref[:1], rtol=0, atol=1e-14 * scale)
    assert np.abs(h_ref).max() > 1e-3 * scale / 10  # not a vanishing Hessian


def test_compiled_gradient_is_periodic_and_invariant(rng):
    """Independent of NumPy: the compiled gradient of a periodic kernel repeats after a period; a symmetric
    kernel's gradient transforms with the group (``grad s(g x) = g grad s(x)``, g orthogonal)."""
    per = ProductKernel(IMQ(0.5), IMQ(1.0), periodic=PeriodicCoordinates((1,), (2.0,)))
    sur = _surrogate(per, 4, 300, rng)
    xi = rng.uniform(-1, 1, (4, 4))
    w = sur.weights(np.full((4, 1), 0.5), np.ones(4))
    shifted = xi + np.array([0.0, 2.0, 0.0, 0.0])
    g0, _, _ = compiled_surrogate.newton_terms(xi, w, sur.layout(), per.state, full=True)
    g1, _, _ = compiled_surrogate.newton_terms(shifted, w, sur.layout(), per.state, full=True)
    np.testing.assert_allclose(g1, g0, rtol=0, atol=1e-12 * np.abs(g0).max())
    flip = np.array([1.0, -1.0, 1.0, -1.0])
    sym = ProductKernel(IMQ(0.5), IMQ(1.0), symmetry=StateSymmetry.from_signs([np.ones(4), flip]))
    sur = _surrogate(sym, 4, 300, rng)
    w = sur.weights(np.full((4, 1), 0.5), np.ones(4))
    g0, _, _ = compiled_surrogate.newton_terms(xi, w, sur.layout(), sym.state, full=True)
    g1, _, _ = compiled_surrogate.newton_terms(xi * flip, w, sur.layout(), sym.state, full=True)
    np.testing.assert_allclose(g1, g0 * flip, rtol=0, atol=1e-12 * np.abs(g0).max())


def test_numpy_only_table_holds_only_what_cannot_be_compiled(small_pendulum_data):
    """Every transform and both updates compile: the table's one row is an update rule without a compiled kernel."""
    d = small_pendulum_data
    for kernel in (
        Periodic(IMQ(0.3), coordinates=(0,), period=8.0),
        Symmetric(IMQ(0.3), group=KLEIN),
        Symmetric(Scaled(IMQ(0.3), factors=(2.0,)), group=KLEIN),
    ):
        parts = lower_state_kernel(kernel)
        for rule in (Midpoint(), SymplecticEuler()):
            assert not [reason for applies, reason in NUMPY_ONLY if applies(parts, rule)]
    assert len(NUMPY_ONLY) == 1

    class Outside(Midpoint):  # a rule added from outside: the compiled solver has no kernel for it
        compiled = False

    assert [reason for applies, reason in NUMPY_ONLY if applies(lower_state_kernel(IMQ(0.3)), Outside())]
    model = klein_midpoint_predictor(0.3, 1.5, 3.0, max_centers=10, backend="numba")
    model.fit(d.x0, d.x1, mu=d.mu, dt=d.dt)
    assert model.numpy_only_ is None and model.backend_for(100, 100) == "numba"
    auto = copy.copy(model).set_params(solver__backend="auto")
    assert auto.backend_for(10_000, 10_000) == "numba"


# ------------------------------------------------------------------ Periodic and Symmetric together
def _both_value(kernel, x, y, mu_x, mu_y):
    """``sum_g phi(r_P(x - g y)) k_mu``: the profile and the periodic distance only (the derivatives' oracle)."""
    return sum(
        kernel.state.phi(kernel.periodic.distances((x - g @ y)[None])[0]) for g in kernel.symmetry.array
    ) * kernel.mu.phi(abs(mu_x - mu_y))


@pytest.mark.parametrize("dim", [2, 4])
def test_periodic_symmetric_kernel_by_finite_differences_and_compiled(dim, rng):
    """The group-averaged periodic kernel: Gramian and surrogate against finite differences of its value, exactly
    periodic and invariant, and the compiled pass equal to the NumPy one."""
    from functools import partial

    from sympredict.interpolation.functionals import HBFunctionals

    from _surrogate_oracles import check_gramian_by_finite_differences, check_surrogate_by_finite_differences

    signs = [np.ones(dim), -np.ones(dim)] + ([np.r_[1.0, -1.0], np.r_[-1.0, 1.0]] if dim == 2 else [])
    kernel = ProductKernel(
        IMQ(0.7), IMQ(1.5), periodic=PeriodicCoordinates((0,), (2.5,)), symmetry=StateSymmetry.from_signs(signs)
    )
    value = partial(_both_value, kernel)
    pts, mu = rng.normal(size=(4, dim)) * 2.0, rng.normal(size=(4, 1))
    check_gramian_by_finite_differences(HBFunctionals(kernel, pts, mu, np.full(4, 0.05)), value, pts, mu)
    m = 20
    centers, cmu = rng.normal(size=(m, dim)) * 2.0, rng.normal(size=(m, 1))
    comps, coef = rng.integers(0, dim, m), rng.normal(size=m)
    sur = HBSurrogate(kernel, centers, cmu, np.full(m, 0.05), comps, coef)
    xi, qmu = rng.normal(size=(4, dim)) * 2.0, rng.normal(size=(4, 1))
    w, grad, hess, floor = check_surrogate_by_finite_differences(sur, value, centers, cmu, comps, coef, xi, qmu)
    shift = np.zeros(dim)
    shift[0] = 2.5
    np.testing.assert_allclose(sur.gradient(xi + 3 * shift, w), grad, atol=1e-12 * np.abs(coef).sum())
    np.testing.assert_allclose(sur.value(-xi, w), sur.value(xi, w), atol=1e-13 * np.abs(coef).sum())
    g_c, h_c, f_c = compiled_surrogate.newton_terms(xi, w, sur.layout(), kernel.state, full=True)
    np.testing.assert_allclose(g_c, grad, rtol=0, atol=1e-13 * np.abs(w).sum(axis=1).max())
    np.testing.assert_allclose(h_c, hess, rtol=0, atol=1e-13 * np.abs(w).sum(axis=1).max())
    np.testing.assert_allclose(f_c, floor, rtol=1e-12)


def test_periodic_symmetric_pendulum_compiled_equals_numpy(small_pendulum_data, rng):
    """The pendulum's angle with its Klein group (sign flips respect the period): fitted, and rolled out on both
    solvers to the stopping rule's bound."""
    d = small_pendulum_data
    kernel = Symmetric(Periodic(Scaled(IMQ(0.3), factors=(1.2,)), coordinates=(0,), period=8.0), group=KLEIN)
    ref_model = SymplecticKernelPredictor(
        kernel,
        mu_kernel=IMQ(2.0),
        dt_kernel=IMQ(5.0),
        max_centers=80,
        update="midpoint",
        solver=NewtonSolver(backend="numpy"),
    )
    ref_model.fit(d.x0, d.x1, mu=d.mu, dt=d.dt)
    assert ref_model.periodic_ == (0,) and ref_model.symmetry_ == KLEIN
    x, mu, dt = pendulum_queries(rng, 8)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ExtrapolationWarning)
        check_rollouts_agree_to_the_floor(ref_model, with_backend(ref_model, "numba"), x, mu, dt, n_steps=20)
