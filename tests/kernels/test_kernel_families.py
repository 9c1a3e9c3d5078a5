"""Every registered kernel family, NumPy against compiled, and a new family added the documented way.

A family's formulas are written once (static methods of its class) and
compiled from the same functions; these tests enumerate the registry, so a
family added later is checked without writing a test for it.
"""

import numpy as np
import pytest

from sympredict.exceptions import extrapolation_expected
from sympredict import SymplecticKernelPredictor
from sympredict import _numba
from sympredict.kernels import _compiled as compiled_kernels
from sympredict.interpolation import _compiled as compiled_surrogate
from sympredict.kernels import IMQ, KERNEL_FAMILIES, ProductKernel, RadialKernel, register_family
from sympredict.interpolation.surrogate import HBSurrogate
from sympredict.symplectic.solvers import NewtonSolver

needs_numba = pytest.mark.skipif(not _numba.HAVE_NUMBA, reason="numba not installed (pip install sympredict[fast])")


class Gaussian(RadialKernel):
    """The docs' example of a new family (docs/explanation/architecture.md): ``phi(r) = exp(-(eps r)^2)``.

    ``A = phi'/r = -2 e^2 E``, ``B = 2 dA/d(r^2) = 4 e^4 E``, ``C = 2 dB/d(r^2) = -8 e^6 E``, ``E = exp(-(e r)^2)``.
    """

    name = "test_gaussian"

    @staticmethod
    def profile(e, r):
        return np.exp(-(e * r) * (e * r))

    @staticmethod
    def first_factors(e, r):
        E = np.exp(-(e * r) * (e * r))
        return -2.0 * e * e * E, 4.0 * e**4 * E

    @staticmethod
    def all_factors(e, r):
        E = np.exp(-(e * r) * (e * r))
        return -2.0 * e * e * E, 4.0 * e**4 * E, -8.0 * e**6 * E


@pytest.fixture(scope="module", autouse=True)
def gaussian_registered():
    register_family(Gaussian)
    yield
    del KERNEL_FAMILIES[Gaussian.name]


FAMILIES = sorted(KERNEL_FAMILIES) + [Gaussian.name]


def _fd(f, r, h):
    return (f(r + h) - f(r - h)) / (2 * h)


@pytest.mark.parametrize("eps", [0.4, 1.7])
@pytest.mark.parametrize("name", FAMILIES)
def test_factors_match_finite_differences_of_the_profile(name, eps):
    kernel = KERNEL_FAMILIES[name](eps)
    r = np.linspace(0.2, 4.0, 17) / kernel.eps
    h = 1e-5 / kernel.eps
    A, B, C = kernel.factors(r, order=3)
    np.testing.assert_allclose(A, _fd(kernel.phi, r, h) / r, rtol=1e-7, atol=1e-12)
    np.testing.assert_allclose(B, _fd(lambda s: kernel.factors(s)[0], r, h) / r, rtol=1e-6, atol=1e-12)
    np.testing.assert_allclose(C, _fd(lambda s: kernel.factors(s)[1], r, h) / r, rtol=1e-6, atol=1e-12)
    A2, B2 = kernel.factors(r, order=2)
    np.testing.assert_array_equal(A, A2)
    np.testing.assert_array_equal(B, B2)
    assert kernel.phi(np.zeros(1))[0] == pytest.approx(1.0)


@needs_numba
@pytest.mark.parametrize("name", FAMILIES)
def test_compiled_formulas_are_the_numpy_formulas(name, rng):
    family = KERNEL_FAMILIES[name]
    e = 0.7
    r = np.concatenate([[0.0, 1e-200, 1e-120, 1e-8], rng.uniform(0, 6, 200), [1e3, 1e150]])
    profile, first, third = compiled_kernels.compiled_formulas(family)
    exact = family.exact_arithmetic  # correctly rounded operations only: bit for bit
    check = (
        np.testing.assert_array_equal
        if exact
        else (lambda a, b: np.testing.assert_allclose(a, b, rtol=1e-14, atol=1e-300))
    )
    check(np.array([profile(e, v) for v in r]), family.profile(e, r))
    for got, want in zip(zip(*[first(e, v) for v in r]), family.first_factors(e, r)):
        check(np.array(got), want)
    for got, want in zip(zip(*[third(e, v) for v in r]), family.all_factors(e, r)):
        check(np.array(got), want)


@needs_numba
@pytest.mark.parametrize("name", FAMILIES)
def test_compiled_formulas_stay_exact_after_the_fastmath_pass_compiles(name, rng):
    """The fused Newton pass is compiled with fastmath (reassoc, contract); the formulas it calls must not inherit it.

    numba compiles a callee that leaves ``fastmath`` unset with its caller's flags, once per signature, and caches
    that on disk: the formulas then differ from NumPy by an ulp for every later caller and process (seen in CI).
    """
    family = KERNEL_FAMILIES[name]
    for formula in compiled_kernels.compiled_formulas(family):
        assert formula.targetoptions.get("fastmath") is False
    kernel = family(0.7)
    x0 = rng.uniform(-1, 1, (40, 2))
    model = SymplecticKernelPredictor(kernel, None, None, max_centers=10, solver=NewtonSolver(backend="numba"))
    model.fit(x0, x0 + 0.01 * rng.standard_normal((40, 2)), dt=0.1)
    with extrapolation_expected():
        model.rollout(x0[:4], 2, dt=0.1)  # compiles the fastmath pass with this family's formulas
    r = rng.uniform(0, 6, 100)
    third = compiled_kernels.compiled_formulas(family)[2]
    check = (
        np.testing.assert_array_equal
        if family.exact_arithmetic
        else (lambda a, b: np.testing.assert_allclose(a, b, rtol=1e-14, atol=1e-300))
    )
    for got, want in zip(zip(*[third(0.7, v) for v in r]), family.all_factors(0.7, r)):
        check(np.array(got), want)


@needs_numba
@pytest.mark.parametrize("dim", [2, 4])  # 2n = 2 has its own fused pass (_chunk2), 2n = 4 the generic one
@pytest.mark.parametrize("name", FAMILIES)
def test_compiled_gradient_and_hessian_equal_numpy(name, dim, rng):
    """The compiled Newton pass (gradient, d_p d_q s, floor) against the NumPy surrogate, random centres."""
    kernel = KERNEL_FAMILIES[name](0.6)
    m = 60
    sur = HBSurrogate(
        ProductKernel(kernel, IMQ(1.0)),
        rng.normal(size=(m, dim)),
        rng.normal(size=(m, 1)),
        np.ones(m),
        rng.integers(0, dim, m),
        rng.normal(size=m),
    )
    xi = rng.normal(size=(9, dim))
    w = sur.weights(rng.normal(size=(9, 1)), np.ones(9))
    g_ref, h_ref, f_ref = sur.newton_terms(xi, w)
    g, h, f = compiled_surrogate.newton_terms(xi, w, sur.layout(), kernel)
    scale = np.abs(w).sum(axis=1).max() * 10  # round-off scale of the sums
    np.testing.assert_allclose(g, g_ref, rtol=0, atol=1e-14 * scale)
    np.testing.assert_allclose(h, h_ref, rtol=0, atol=1e-14 * scale)
    np.testing.assert_allclose(f, f_ref, rtol=1e-12)
    # the gradients of all points (the active-set refreshes) too
    grad = compiled_surrogate.gradients(xi, np.zeros(9, dtype=np.int64), w[:1], sur.layout(), kernel)
    np.testing.assert_allclose(grad[:1], sur.gradient(xi[:1], w[:1]), rtol=0, atol=1e-14 * scale)


@needs_numba
def test_a_new_family_trains_and_rolls_out_compiled(small_pendulum_data, rng):
    """One class, registered: fit, file round trip and the compiled rollout work with no other change."""
    d = small_pendulum_data
    idx = rng.choice(len(d), 500, replace=False)
    model = SymplecticKernelPredictor(
        Gaussian(0.3), IMQ(2.0), IMQ(5.0), max_centers=80, solver=NewtonSolver(backend="numba")
    )
    model.fit(d.x0[idx], d.x1[idx], mu=d.mu[idx], dt=d.dt[idx])
    x = d.x0[idx[:6]]
    mu, dt = d.mu[idx[:6], 0], d.dt[idx[:6]]
    with extrapolation_expected():  # backends compared, not accuracy: a trajectory may leave the training states
        fast = model.rollout(x, 10, mu=mu, dt=dt)
        ref = model.set_params(solver__backend="numpy").rollout(x, 10, mu=mu, dt=dt)
    np.testing.assert_allclose(fast, ref, rtol=0, atol=1e-9)
    assert model.history_.train_max_residual[-1] < 0.1 * model.history_.train_max_residual[0]


@needs_numba
def test_a_foreign_family_leaves_the_disk_cache_readable(small_pendulum_data, rng):
    """numba's cache index of a compiled function lists its types: a family from a module other processes
    cannot import (this test module) must not enter it, or every later process fails to load the cache."""
    import subprocess
    import sys

    d = small_pendulum_data
    idx = rng.choice(len(d), 300, replace=False)
    model = SymplecticKernelPredictor(
        Gaussian(0.3), IMQ(2.0), IMQ(5.0), max_centers=30, solver=NewtonSolver(backend="numba")
    )
    model.fit(d.x0[idx], d.x1[idx], mu=d.mu[idx], dt=d.dt[idx]).rollout(d.x0[idx[:9]], 3, mu=0.75, dt=0.05)
    code = (
        "import numpy as np; from sympredict import SymplecticKernelPredictor; from sympredict.kernels import IMQ; "
        "from sympredict.symplectic.solvers import NewtonSolver; "
        "from sympredict.systems.pendulum import Pendulum, flow_map_data; d = flow_map_data(Pendulum(), n_grid=8); "
        "m = SymplecticKernelPredictor(IMQ(0.3), IMQ(2.0), IMQ(5.0), max_centers=20, solver=NewtonSolver(backend='numba'))"
        ".fit(d.x0, d.x1, mu=d.mu, dt=d.dt); print(m.rollout(d.x0[:9], 3, mu=0.75, dt=0.05).shape)"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "(9, 4, 2)" in done.stdout
