"""Kernel derivative factors and Gramian blocks against finite differences."""

import numpy as np
import pytest

from sympredict.kernels import IMQ, KERNEL_FAMILIES, Matern32, Matern52, ProductKernel, kernel_from_spec

KERNELS = [IMQ(0.4), IMQ(1.7), Matern32(0.5), Matern32(1.3), Matern52(0.6), Matern52(2.0)]


# factors against finite differences of the profile: tests/kernels/test_kernel_families.py (every registered family)


@pytest.mark.parametrize("kernel", KERNELS, ids=repr)
def test_factors_finite_at_zero(kernel):
    vals = kernel.factors(np.array([0.0, 1e-200, 1e-20]), order=3)
    for v in vals:
        assert np.all(np.isfinite(v))
    assert kernel.phi(np.zeros(1))[0] == pytest.approx(1.0)


@pytest.mark.parametrize("kernel", KERNELS, ids=repr)
def test_state_gramian_matches_mixed_finite_differences(kernel, rng):
    dim = 4
    x = rng.normal(size=(3, dim)) / kernel.eps
    y = rng.normal(size=(2, dim)) / kernel.eps
    gram = kernel.state_gramian(x, y)
    h = 1e-4 / kernel.eps
    eye = np.eye(dim) * h
    fd = np.empty_like(gram)
    for a in range(dim):
        for b in range(dim):
            fd[:, :, a, b] = (
                kernel(x + eye[a], y + eye[b])
                - kernel(x + eye[a], y - eye[b])
                - kernel(x - eye[a], y + eye[b])
                + kernel(x - eye[a], y - eye[b])
            ) / (4 * h * h)
    scale = np.abs(gram).max()
    np.testing.assert_allclose(gram, fd, atol=1e-6 * scale)


@pytest.mark.parametrize("kernel", KERNELS, ids=repr)
def test_state_gramian_is_symmetric_positive_definite(kernel, rng):
    x = rng.normal(size=(6, 2)) / kernel.eps
    gram = kernel.state_gramian(x, x).transpose(0, 2, 1, 3).reshape(12, 12)
    np.testing.assert_allclose(gram, gram.T, atol=1e-14 * np.abs(gram).max())
    assert np.linalg.eigvalsh(gram).min() > 0


def test_kernel_validation_and_specs():
    for bad in (0.0, -1.0, np.nan, np.inf, "abc", None):
        with pytest.raises(ValueError, match="eps"):
            IMQ(bad)
    for cls in KERNEL_FAMILIES.values():
        k = cls(0.25)
        assert kernel_from_spec(k.spec) == k
    assert kernel_from_spec(None) is None
    with pytest.raises(ValueError, match="unknown kernel family"):
        kernel_from_spec({"family": "gauss", "eps": 1.0})
    with pytest.raises(ValueError, match="state_kernel is required"):
        ProductKernel(None)
    with pytest.raises(ValueError, match="mu_kernel"):
        ProductKernel(IMQ(1.0), mu=lambda a, b: 1)


def test_product_kernel_parameter_factor(rng):
    pk = ProductKernel(IMQ(1.0), mu=Matern52(2.0), dt=IMQ(5.0))
    mu_a, mu_b = rng.normal(size=(4, 2)), rng.normal(size=(3, 2))
    dt_a, dt_b = rng.uniform(0.04, 0.06, 4), rng.uniform(0.04, 0.06, 3)
    fac = pk.parameter_factor(mu_a, dt_a, mu_b, dt_b)
    direct = np.array(
        [
            [
                Matern52(2.0).phi(np.linalg.norm(mu_a[i] - mu_b[j])) * IMQ(5.0).phi(abs(dt_a[i] - dt_b[j]))
                for j in range(3)
            ]
            for i in range(4)
        ]
    )
    np.testing.assert_allclose(fac, direct, rtol=1e-14)
    np.testing.assert_array_equal(ProductKernel(IMQ(1.0)).parameter_factor(mu_a, dt_a, mu_b, dt_b), np.ones((4, 3)))
