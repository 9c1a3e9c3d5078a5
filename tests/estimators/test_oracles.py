"""Analytic and independent oracles where two code paths coincide in the other tests.

Each test compares the library with something computed by separate code:
closed forms of the pendulum (constants, mass != 1), finite differences of
the public ``surrogate_gradient`` and ``step``, a non-orthonormal symplectic
basis (where ``V+ != V^T``), and a Newton pass count with a known bound.
"""

import numpy as np
import pytest

from sympredict import SymplecticKernelPredictor
from sympredict.symplectic.integrators import implicit_midpoint_step, integrate
from sympredict.kernels import IMQ
from sympredict.symplectic.metrics import canonical_J, symplecticity_defect
from sympredict.mor.basis import complex_svd_basis, symplectic_inverse, symplecticity_of_basis
from sympredict.systems.pendulum import Pendulum, flow_map_data
from sympredict.interpolation.greedy import ExactGreedy


# ------------------------------------------------------------------ pendulum constants and mass
def test_pendulum_constants_are_the_papers():
    p = Pendulum()
    assert p.g == 9.81 and p.mass == 1.0
    # H(q, p; l) = p^2 / (2 m l^2) + m g l (1 - cos q), written out here with the paper's constants
    x = np.array([[0.7, -1.3], [2.0, 0.4]])
    lengths = np.array([0.75, 0.8])
    expected = x[:, 1] ** 2 / (2 * lengths**2) + 9.81 * lengths * (1 - np.cos(x[:, 0]))
    np.testing.assert_allclose(p.hamiltonian(x, lengths), expected, rtol=1e-15)


@pytest.mark.parametrize("mass", [1.0, 2.5, 0.3])
def test_pendulum_with_mass_has_the_small_angle_closed_form(mass):
    """q(t) = q0 cos(w t), p(t) = -m l^2 q0 w sin(w t), w = sqrt(g / l): independent of the mass.

    A mass dropped from dH/dp (or kept only there) changes the frequency to sqrt(m g / l) or
    sqrt(g / (m l)), so the state after 0.3 periods moves by ~10% for m != 1.
    """
    system = Pendulum(mass=mass)
    length, q0 = 0.75, 1e-3  # amplitude correction ~q0^2/16: 6e-8 relative
    w = np.sqrt(9.81 / length)
    t = 0.3 * 2 * np.pi / w
    x0 = np.array([[q0, 0.0]])
    exact = np.array([q0 * np.cos(w * t), -mass * length**2 * q0 * w * np.sin(w * t)])
    scale = np.array([q0, mass * length**2 * q0 * w])
    # the reference flow (scalar midpoint Newton) ...
    np.testing.assert_allclose(system.flow(x0, length, t, h_max=1e-4)[0] / scale, exact / scale, atol=1e-5)
    # ... and the generic integrators, which use gradient() and hessian()
    n = 2000
    traj = integrate(implicit_midpoint_step, system, x0, np.array([[length]]), t / n, n)
    np.testing.assert_allclose(traj[0, -1] / scale, exact / scale, atol=1e-5)
    # energy of the closed form: m g l q0^2 / 2 at the start, conserved by the midpoint rule
    e = system.hamiltonian(traj[0], np.full(n + 1, length))
    assert e[0] == pytest.approx(mass * 9.81 * length * q0**2 / 2, rel=1e-6)
    np.testing.assert_allclose(e, e[0], rtol=1e-8)


@pytest.mark.parametrize("mass", [1.0, 2.5])
def test_pendulum_gradient_and_hessian_are_derivatives_of_the_hamiltonian(mass, rng):
    system = Pendulum(mass=mass)
    x = rng.uniform([-2, -3], [2, 3], size=(7, 2))
    lengths = rng.uniform(0.7, 0.8, 7)
    h = 1e-6
    fd = np.stack(
        [
            (system.hamiltonian(x + h * e, lengths) - system.hamiltonian(x - h * e, lengths)) / (2 * h)
            for e in np.eye(2)
        ],
        axis=1,
    )
    np.testing.assert_allclose(system.gradient(x, lengths), fd, rtol=1e-7, atol=1e-8)
    fd2 = np.stack(
        [(system.gradient(x + h * e, lengths) - system.gradient(x - h * e, lengths)) / (2 * h) for e in np.eye(2)],
        axis=2,
    )
    np.testing.assert_allclose(system.hessian(x, lengths), fd2, rtol=1e-7, atol=1e-8)


# ------------------------------------------------------------------ solvability
def _fd_hessian(model, xi, mu, dt, h=1e-5):
    """Hessian of the surrogate ``s`` by central differences of the public ``surrogate_gradient``, (B, 2n, 2n)."""
    cols = [
        (model.surrogate_gradient(xi + h * e, mu=mu, dt=dt) - model.surrogate_gradient(xi - h * e, mu=mu, dt=dt))
        / (2 * h)
        for e in np.eye(xi.shape[1])
    ]
    return np.stack(cols, axis=2)


@pytest.fixture(scope="module")
def pendulum_model():
    d = flow_map_data(Pendulum(), mus=(0.7, 0.8), dts=(0.04, 0.06), n_grid=12)
    return SymplecticKernelPredictor(IMQ(0.3), IMQ(2.0), IMQ(5.0), max_centers=100).fit(d.x0, d.x1, mu=d.mu, dt=d.dt)


def test_solvability_is_dt_times_the_norm_of_the_p_columns_of_the_hessian(pendulum_model, rng):
    """``dT * ||d^2 s / (d xi d p)||_2`` at ``xi = (q0, p0)``, with the Hessian from finite differences."""
    x = np.column_stack([rng.uniform(-1.5, 1.5, 12), rng.uniform(-2.5, 2.5, 12)])
    mu, dt = rng.uniform(0.7, 0.8, 12), rng.uniform(0.04, 0.06, 12)
    hess = _fd_hessian(pendulum_model, x, mu, dt)
    # the q and p columns differ by far more than the tolerance here: reading the wrong ones fails
    q_cols = dt * np.linalg.norm(hess[:, :, :1], ord=2, axis=(1, 2))
    p_cols = dt * np.linalg.norm(hess[:, :, 1:], ord=2, axis=(1, 2))
    assert np.all(np.abs(q_cols - p_cols) > 1e-2 * p_cols)
    np.testing.assert_allclose(pendulum_model.solvability(x, mu=mu, dt=dt), p_cols, rtol=1e-6)
    # the pendulum's flow: s ~ dT H, d_p d_p s ~ dT / l^2 -> margin ~ dT^2 / l^2 dominates the p column
    assert pendulum_model.solvability(x[0], mu=mu[0], dt=dt[0]) == pytest.approx(p_cols[0], rel=1e-6)


# ------------------------------------------------------------------ symplectic inverse
def test_symplectic_inverse_of_a_non_orthonormal_symplectic_basis(rng):
    """``V = [[I, B], [0, I]] V0`` with ``B`` symmetric is symplectic, not orthonormal: ``V+ = J^T V^T J != V^T``."""
    big_n, n = 5, 2
    snapshots = rng.normal(size=(30, 2 * big_n))
    V0 = complex_svd_basis(snapshots, n=n, layout="rows").V
    B = rng.normal(size=(big_n, big_n))
    B = B + B.T
    S = np.block([[np.eye(big_n), B], [np.zeros((big_n, big_n)), np.eye(big_n)]])
    for V in (S, S @ V0):
        assert symplecticity_of_basis(V) < 1e-12
        assert np.abs(V.T @ V - np.eye(V.shape[1])).max() > 0.1  # not orthonormal: V^T is not the inverse
        Vp = symplectic_inverse(V)
        assert Vp.shape == V.T.shape
        np.testing.assert_allclose(Vp @ V, np.eye(V.shape[1]), atol=1e-12)
        P = V @ Vp
        np.testing.assert_allclose(P @ P, P, atol=1e-11)  # a projection
        # written out: J_2n^T V^T J_2N
        np.testing.assert_allclose(Vp, canonical_J(V.shape[1]).T @ V.T @ canonical_J(V.shape[0]), atol=1e-14)
    # for the square case the inverse is known in closed form: [[I, -B], [0, I]]
    np.testing.assert_allclose(
        symplectic_inverse(S), np.block([[np.eye(big_n), -B], [np.zeros((big_n, big_n)), np.eye(big_n)]]), atol=1e-13
    )


def test_projection_error_is_the_relative_snapshot_residual(rng):
    """``projection_error`` = ``||S - S V V^T||_F / ||S||_F`` for the snapshots ``S`` (rows), computed directly."""
    snapshots = rng.normal(size=(40, 10)) * np.geomspace(1.0, 1e-3, 10)
    for n in (1, 2, 4):
        basis = complex_svd_basis(snapshots, n=n, layout="rows")
        V = basis.V
        direct = np.linalg.norm(snapshots - snapshots @ V @ V.T) / np.linalg.norm(snapshots)
        assert basis.projection_error == pytest.approx(direct, rel=1e-10)
        # and tol picks the smallest n that meets it
        assert complex_svd_basis(snapshots, tol=basis.projection_error * (1 + 1e-9), layout="rows").n == n


# ------------------------------------------------------------------ 4-D step Jacobian
class CoupledPendula:
    """2n = 4: ``H = |p|^2 / 2 + (1 - cos q1) + (1 - cos q2) + mu (q1 - q2)^2 / 2``."""

    def hamiltonian(self, x, mu):
        q1, q2, p1, p2 = np.atleast_2d(x).T
        k = np.asarray(mu, dtype=float).reshape(-1)
        return (p1**2 + p2**2) / 2 + 2 - np.cos(q1) - np.cos(q2) + k * (q1 - q2) ** 2 / 2

    def gradient(self, x, mu):
        q1, q2, p1, p2 = x.T
        k = mu[:, 0]
        return np.column_stack([np.sin(q1) + k * (q1 - q2), np.sin(q2) - k * (q1 - q2), p1, p2])

    def hessian(self, x, mu):
        q1, q2 = x[:, 0], x[:, 1]
        k = mu[:, 0]
        hess = np.zeros((len(x), 4, 4))
        hess[:, 0, 0] = np.cos(q1) + k
        hess[:, 1, 1] = np.cos(q2) + k
        hess[:, 0, 1] = hess[:, 1, 0] = -k
        hess[:, 2, 2] = hess[:, 3, 3] = 1.0
        return hess


def test_four_dimensional_step_jacobian_is_the_derivative_of_step(rng):
    system = CoupledPendula()
    x0 = rng.uniform(-1, 1, size=(60, 4))
    mu = rng.uniform(0.5, 1.0, size=(60, 1))
    x1 = integrate(implicit_midpoint_step, system, x0, mu, 0.01, 10)[:, -1]
    model = SymplecticKernelPredictor(
        IMQ(0.5), mu_kernel=IMQ(1.0), max_centers=150, trainer=ExactGreedy(tol=1e-10)
    ).fit(x0, x1, mu=mu, dt=0.1)
    xq = rng.uniform(-0.7, 0.7, size=(8, 4))
    muq = rng.uniform(0.55, 0.95, 8)
    jac = model.step_jacobian(xq, mu=muq)
    h = 1e-5
    fd = np.stack(
        [(model.step(xq + h * e, mu=muq) - model.step(xq - h * e, mu=muq)) / (2 * h) for e in np.eye(4)], axis=2
    )
    np.testing.assert_allclose(jac, fd, atol=1e-6)
    # the finite-difference Jacobian itself is symplectic: ties the property to the step, not to the formula
    assert symplecticity_defect(fd).max() <= 1e-5
    # and it is not the identity or the exact flow's trivial part: the step moves states
    assert np.abs(fd - np.eye(4)).max() > 1e-2


# ------------------------------------------------------------------ Newton pass count
def compiled_newton_passes(model, x, mu, dt, n_steps):
    """Passes over the centres per instance of the compiled rollout, shape (B,).

    The one place that calls :func:`sympredict.symplectic._compiled_newton.newton_rollout` with ``stats``
    (no public predictor API reports Newton iterations); adapt here when its arguments change.
    """
    from sympredict.symplectic import _compiled_newton

    sur = model.surrogate_
    dt = np.full(len(x), float(dt))
    weights = sur.weights(np.full((len(x), 1), float(mu)), dt)
    stats = {}
    _compiled_newton.newton_rollout(
        x, weights, dt, sur.layout(), sur.kernel.state, model._newton_iterations(), n_steps, stats=stats
    )
    return stats["passes"]


def test_compiled_newton_converges_in_three_iterations_from_the_explicit_guess(pendulum_model, rng):
    """Per step: one gradient pass for the guess ``p0 - dT d_q s(q0, p0)`` (error O(dT^2)) and, with
    quadratic convergence from there, three Newton passes (the last only confirms convergence).

    A wrong guess (e.g. ``p0 + dT d_q s``: error O(dT)) needs 4-6 Newton passes on most instances.
    """
    from sympredict import _numba

    if not _numba.HAVE_NUMBA:
        pytest.fail("numba is part of the test extra: pip install -e '.[test]'")
    x = np.column_stack([rng.uniform(-1, 1, 20), rng.uniform(-2, 2, 20)])
    n_steps = 10
    passes = compiled_newton_passes(pendulum_model, x, 0.75, 0.05, n_steps)
    assert np.all(passes <= 4 * n_steps) and np.all(passes >= 3 * n_steps), passes
    # the rollout is the one the public API returns
    traj = pendulum_model.rollout(x, n_steps, mu=0.75, dt=0.05)
    assert np.all(np.isfinite(traj))
