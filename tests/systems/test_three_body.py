"""The planar circular restricted three-body problem: derivatives, Lagrange points, reference flow, sampler."""

import numpy as np
import pytest

from sympredict.systems.flowmaps import rk4_flow
from sympredict.systems.three_body import ROUTH_MU, ThreeBody, lagrange_points, librating_states


@pytest.fixture(scope="module")
def tb():
    return ThreeBody()


def test_gradient_and_hessian_match_finite_differences(tb, rng):
    mu = rng.uniform(0.01, 0.014, 6)
    x = librating_states(mu, 6, radial=0.1, angle=0.5, speed=0.1, seed=1)
    h = 1e-6
    fd = np.column_stack([(tb.hamiltonian(x + h * e, mu) - tb.hamiltonian(x - h * e, mu)) / (2 * h) for e in np.eye(4)])
    np.testing.assert_allclose(tb.gradient(x, mu), fd, atol=1e-8)
    fdh = np.stack([(tb.gradient(x + h * e, mu) - tb.gradient(x - h * e, mu)) / (2 * h) for e in np.eye(4)], axis=2)
    np.testing.assert_allclose(tb.hessian(x, mu), fdh, atol=1e-7)


@pytest.mark.parametrize("mu", [0.01, 0.0121506, 0.3])
def test_lagrange_points_are_equilibria(tb, mu):
    lp = lagrange_points(mu)
    np.testing.assert_allclose(tb.vector_field(lp, mu), 0.0, atol=1e-12)
    # closed forms: L4/L5 equidistant (unit distance) from both primaries; L1 between them, L2 beyond m2, L3 beyond m1
    for k in (3, 4):
        np.testing.assert_allclose(np.hypot(lp[k, 0] + mu, lp[k, 1]), 1.0, rtol=1e-15)
        np.testing.assert_allclose(np.hypot(lp[k, 0] - 1 + mu, lp[k, 1]), 1.0, rtol=1e-15)
    assert -mu < lp[0, 0] < 1 - mu < lp[1, 0] and lp[2, 0] < -mu
    # Hill's approximation for small mu: L1, L2 at distance (mu/3)^(1/3) from m2
    if mu < 0.02:
        hill = (mu / 3) ** (1 / 3)
        np.testing.assert_allclose([1 - mu - lp[0, 0], lp[1, 0] - 1 + mu], hill, rtol=0.1)
    # the flow stays at an equilibrium
    np.testing.assert_allclose(tb.trajectory(lp[3], mu, 0.5, 4), np.tile(lp[3], (5, 1)), atol=1e-10)


def test_jacobi_constant_conserved_and_flow_matches_rk4(tb):
    assert ROUTH_MU == pytest.approx(0.0385209, abs=1e-7)
    mu = np.array([0.010, 0.012, 0.014])
    x0 = librating_states(mu, 3, seed=3)
    traj = tb.trajectory(x0, mu, 0.05, 400)  # T = 20
    assert traj.shape == (3, 401, 4)
    c = tb.jacobi_constant(traj.reshape(-1, 4), np.repeat(mu, 401)).reshape(3, -1)
    assert np.abs(c - c[:, :1]).max() < 1e-10 * np.abs(c).max()
    np.testing.assert_allclose(c, -2 * tb.hamiltonian(traj.reshape(-1, 4), np.repeat(mu, 401)).reshape(3, -1))
    # an independent integrator (RK4 with step halving) over T = 1
    ref = rk4_flow(lambda x, m: tb.gradient(x, m[:, 0]), x0, mu[:, None], np.full(3, 1.0), rtol=1e-12)
    np.testing.assert_allclose(traj[:, 20], ref, atol=1e-10)
    # per-instance steps share the rescaled grid
    mixed = tb.trajectory(x0, mu, np.array([0.05, 0.1, 0.025]), 10)
    np.testing.assert_allclose(mixed[0], traj[0, :11], atol=1e-10)
    np.testing.assert_allclose(mixed[1, 5], traj[1, 10], atol=1e-10)
    np.testing.assert_allclose(tb.flow(x0[0], mu[0], 0.05), traj[0, 1], atol=1e-12)


def test_librations_stay_near_l4(tb):
    # away from the 3:1 resonance (mu ~ 0.0135), small tadpoles stay tadpoles
    mu = np.full(4, 0.011)
    x0 = librating_states(mu, 4, seed=5)
    r0, th0 = np.hypot(x0[:, 0], x0[:, 1]), np.arctan2(x0[:, 1], x0[:, 0])
    assert np.all(np.abs(r0 - 1) <= 0.01) and np.all(np.abs(th0 - np.pi / 3) <= 0.15)
    traj = tb.trajectory(x0, mu, 0.5, 200)  # T = 100, several libration periods
    r, th = np.hypot(traj[..., 0], traj[..., 1]), np.arctan2(traj[..., 1], traj[..., 0])
    assert np.abs(r - 1).max() < 0.1 and np.all((th > np.radians(20)) & (th < np.radians(120)))


def test_input_checks(tb):
    with pytest.raises(ValueError, match="mass ratio"):
        tb.hamiltonian(np.zeros((1, 4)) + 0.5, 0.7)
    with pytest.raises(ValueError, match="x0"):
        tb.trajectory(np.zeros((1, 3)), 0.01, 0.1, 2)
    with pytest.raises(ValueError, match="mu"):
        lagrange_points(0.6)
