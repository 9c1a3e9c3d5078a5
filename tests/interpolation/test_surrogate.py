"""The HB surrogate's value, gradient and Hessian against finite differences."""

import numpy as np
import pytest

from sympredict.kernels import IMQ, Matern32, Matern52, ProductKernel
from sympredict.interpolation.surrogate import HBSurrogate


def random_surrogate(rng, state_kernel, dim=4, m=25, with_params=True):
    kernel = ProductKernel(state_kernel, IMQ(1.5) if with_params else None, Matern52(3.0) if with_params else None)
    scale = 1.0 / state_kernel.eps
    return HBSurrogate(
        kernel,
        rng.normal(size=(m, dim)) * scale,
        rng.normal(size=(m, 2 if with_params else 0)),
        rng.uniform(0.04, 0.06, m),
        rng.integers(0, dim, m),
        rng.normal(size=m),
    )


@pytest.mark.parametrize("state_kernel", [IMQ(0.7), Matern32(0.8), Matern52(0.9)], ids=repr)
@pytest.mark.parametrize("dim", [2, 4])
def test_gradient_and_hessian_match_finite_differences(state_kernel, dim, rng):
    sur = random_surrogate(rng, state_kernel, dim=dim)
    xi = rng.normal(size=(5, dim)) / state_kernel.eps
    w = sur.weights(rng.normal(size=(5, 2)), rng.uniform(0.04, 0.06, 5))
    grad, hess, floor = sur.gradient_hessian(xi, w, with_floor=True)
    np.testing.assert_array_equal(grad, sur.gradient(xi, w))
    h = 1e-5 / state_kernel.eps
    eye = np.eye(dim) * h
    fd_grad = np.column_stack([(sur.value(xi + eye[a], w) - sur.value(xi - eye[a], w)) / (2 * h) for a in range(dim)])
    np.testing.assert_allclose(grad, fd_grad, atol=1e-7 * np.abs(grad).max())
    fd_hess = np.stack(
        [(sur.gradient(xi + eye[c], w) - sur.gradient(xi - eye[c], w)) / (2 * h) for c in range(dim)], axis=2
    )
    np.testing.assert_allclose(hess, fd_hess, atol=1e-6 * np.abs(hess).max())
    np.testing.assert_allclose(hess, hess.transpose(0, 2, 1), atol=1e-13 * np.abs(hess).max())
    assert np.all(floor > 0) and np.all(floor < 1e-12 * np.abs(sur.coef).sum() * 10)


def test_weights_and_chunking_consistent(rng, monkeypatch):
    import sympredict.interpolation.surrogate as surrogate_module

    sur = random_surrogate(rng, IMQ(1.0), dim=2, m=40)
    xi = rng.normal(size=(37, 2))
    w = sur.weights(rng.normal(size=(37, 2)), rng.uniform(0.04, 0.06, 37))
    full = sur.gradient_hessian(xi, w)
    monkeypatch.setattr(surrogate_module, "_CHUNK_ENTRIES", 2 * 40 * 2)  # 2 queries per chunk
    chunked = sur.gradient_hessian(xi, w)
    for a, b in zip(full, chunked):
        np.testing.assert_allclose(a, b, rtol=1e-13, atol=1e-15)


def test_parameter_free_surrogate(rng):
    sur = random_surrogate(rng, IMQ(1.0), dim=2, with_params=False)
    w = sur.weights(np.zeros((3, 0)), np.full(3, 0.1))
    np.testing.assert_array_equal(w, np.broadcast_to(sur.coef, (3, sur.n_centers)))
