"""Reference flows and integrators: equivalence, convergence orders, energy behaviour."""

import numpy as np
import pytest

from sympredict.symplectic.integrators import (
    implicit_midpoint_step,
    integrate,
    stormer_verlet_step,
    symplectic_euler_step,
)
from sympredict.symplectic.metrics import relative_hamiltonian_error
from sympredict.systems.pendulum import (
    MU_TRAIN,
    DT_TRAIN,
    energy_bounded_grid,
    flow_map_data,
    random_flow_map_data,
)
from sympredict.symplectic.integrators import micro_steps


def _states(rng, n=6):
    return np.column_stack([rng.uniform(-2.5, 2.5, n), rng.uniform(-3, 3, n)]), rng.uniform(0.7, 0.8, n)


def test_pendulum_gradient_and_hessian_match_finite_differences(pendulum, rng):
    x, length = _states(rng)
    h = 1e-6
    fd = np.column_stack(
        [
            (pendulum.hamiltonian(x + h * e, length) - pendulum.hamiltonian(x - h * e, length)) / (2 * h)
            for e in np.eye(2)
        ]
    )
    np.testing.assert_allclose(pendulum.gradient(x, length[:, None]), fd, atol=1e-8)
    fdh = np.stack(
        [
            (pendulum.gradient(x + h * e, length[:, None]) - pendulum.gradient(x - h * e, length[:, None])) / (2 * h)
            for e in np.eye(2)
        ],
        axis=2,
    )
    np.testing.assert_allclose(pendulum.hessian(x, length[:, None]), fdh, atol=1e-7)


def test_specialized_reference_equals_generic_implicit_midpoint(pendulum, rng):
    x, length = _states(rng)
    ref = pendulum.flow(x, length, 0.05)  # 50 micro steps of 1e-3
    generic = integrate(implicit_midpoint_step, pendulum, x, length[:, None], 1e-3, 50)[:, -1]
    np.testing.assert_allclose(ref, generic, atol=1e-13)


def test_micro_step_count():
    np.testing.assert_array_equal(micro_steps(np.array([0.04, 0.05, 0.06, 0.0509, 0.001]), 1e-3), [40, 50, 60, 51, 1])


@pytest.mark.parametrize(
    "step, order",
    [(implicit_midpoint_step, 2), (stormer_verlet_step, 2), (symplectic_euler_step, 1)],
    ids=["implicit_midpoint", "stormer_verlet", "symplectic_euler"],
)
def test_observed_convergence_order(pendulum, rng, step, order):
    x, length = _states(rng, 4)
    t = 0.4
    exact = pendulum.flow(x, length, t, h_max=1e-5)
    errors = []
    for n in (20, 40, 80):
        approx = integrate(step, pendulum, x, length[:, None], t / n, n)[:, -1]
        errors.append(np.abs(approx - exact).max())
    observed = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    np.testing.assert_allclose(observed, order, atol=0.15)


def test_reference_energy_error_stays_small_and_bounded(pendulum):
    x = np.array([[1.2, 0.0], [2.5, 0.5]])
    length = np.array([0.7, 0.8])
    traj = pendulum.trajectory(x, length, 0.05, 400)  # T = 20, 20,000 micro steps
    err = relative_hamiltonian_error(pendulum, traj, length[:, None])
    assert err.max() < 1e-5
    # no drift: the second half is not worse than the first
    assert err[:, 200:].max() < 2 * err[:, :200].max() + 1e-12


def test_energy_bounded_sampling_matches_paper_size(pendulum):
    # the paper's 200 x 200 grid with H < 2g per length: 688,464 functionals (2 per sample)
    total = sum(len(energy_bounded_grid(pendulum, length, 200)) for length in MU_TRAIN) * len(DT_TRAIN) * 2
    assert total == 688_464
    grid = energy_bounded_grid(pendulum, 0.75, 30)
    assert np.all(pendulum.hamiltonian(grid, np.full(len(grid), 0.75)) < 2 * pendulum.g)


def test_flow_map_data_and_scenario_b(pendulum):
    a = flow_map_data(pendulum, n_grid=12)
    b = flow_map_data(pendulum, n_grid=12, p_nonpositive=True)
    assert a.mu.shape == (len(a), 1) and set(np.unique(a.dt)) == set(DT_TRAIN)
    assert np.all(b.x0[:, 1] <= 0) and len(b) < len(a)
    np.testing.assert_allclose(a.x1[:5], pendulum.flow(a.x0[:5], a.mu[:5, 0], a.dt[:5]), atol=1e-15)
    v1 = random_flow_map_data(pendulum, 50, seed=3)
    v2 = random_flow_map_data(pendulum, 50, seed=3)
    np.testing.assert_array_equal(v1.x1, v2.x1)
    with pytest.raises(ValueError, match="positive"):
        pendulum.flow(np.zeros((1, 2)), -0.7, 0.05)


def test_pendulum_period_formula_matches_the_reference_flow(pendulum):
    """4 sqrt(l/g) K(sin^2(q0/2)) (used by the stability study) against zero crossings of the reference."""
    from sympredict_paper.pendulum import _complete_elliptic_k, _upward_crossings

    q0, length = 1.2, 0.75
    traj = pendulum.trajectory(np.array([[q0, 0.0]]), length, 0.01, 1000)[0]  # t in [0, 10]
    crossings = _upward_crossings(0.01 * np.arange(1001), traj[:, 0])
    measured = np.mean(np.diff(crossings))
    predicted = 4 * np.sqrt(length / pendulum.g) * _complete_elliptic_k(np.sin(q0 / 2) ** 2)
    assert measured == pytest.approx(predicted, rel=1e-5)


def test_phase_error_of_shifted_sinusoids():
    from sympredict_paper.pendulum import _phase_error, _upward_crossings

    t = np.linspace(0, 50, 20001)
    ref = np.sin(2 * np.pi * t / 2.0)
    # a constant phase lag of 0.3 rad: the crossings come later, so the error is +0.3
    assert _phase_error(t, np.sin(2 * np.pi * t / 2.0 - 0.3), ref) == pytest.approx(0.3, abs=1e-4)
    # a 1% longer period: the k-th matched crossing is k * 0.02 late, i.e. 2 pi k 0.01 rad
    slow = np.sin(2 * np.pi * t / 2.02)
    k = min(len(_upward_crossings(t, slow)), len(_upward_crossings(t, ref)))
    assert _phase_error(t, slow, ref) == pytest.approx(2 * np.pi * k * 0.01, rel=1e-3)
    assert np.isnan(_phase_error(t[:10], ref[:10], ref[:10]))
