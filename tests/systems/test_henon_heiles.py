"""Hénon–Heiles: derivatives, reference flow, energy-bounded sampler, input checks."""

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from sympredict.exceptions import SympredictError
from sympredict.symplectic.integrators import apply_J
from sympredict.systems.henon_heiles import HenonHeiles, _well_radius, energy_bounded_states, escape_energy


@pytest.fixture(scope="module")
def hh():
    return HenonHeiles()


def _states(rng, b=6):
    return rng.uniform(-0.5, 0.5, size=(b, 4)), rng.uniform(0.8, 1.0, b)


def test_hamiltonian_closed_form(hh):
    # a saddle of lambda = 1 at (0, 1): energy 1/6 with p = 0; the origin has energy |p|^2 / 2
    np.testing.assert_allclose(
        hh.hamiltonian(np.array([[0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 0.3, 0.4]]), 1.0), [1 / 6, 0.125]
    )
    assert escape_energy(1.0) == pytest.approx(1 / 6) and escape_energy(0.5) == pytest.approx(2 / 3)
    # the saddles of lambda: (0, 1/lambda) and (+-sqrt(3)/(2 lambda), -1/(2 lambda)), energy 1/(6 lambda^2)
    lam = 0.8
    saddles = np.array([[0.0, 1.0, 0, 0], [np.sqrt(3) / 2, -0.5, 0, 0], [-np.sqrt(3) / 2, -0.5, 0, 0]]) / lam
    np.testing.assert_allclose(hh.gradient(saddles, lam), 0.0, atol=1e-15)
    np.testing.assert_allclose(hh.hamiltonian(saddles, lam), escape_energy(lam), rtol=1e-15)


def test_gradient_and_hessian_match_finite_differences(hh, rng):
    x, lam = _states(rng)
    h = 1e-6
    fd = np.column_stack(
        [(hh.hamiltonian(x + h * e, lam) - hh.hamiltonian(x - h * e, lam)) / (2 * h) for e in np.eye(4)]
    )
    np.testing.assert_allclose(hh.gradient(x, lam), fd, atol=1e-9)
    fdh = np.stack([(hh.gradient(x + h * e, lam) - hh.gradient(x - h * e, lam)) / (2 * h) for e in np.eye(4)], axis=2)
    np.testing.assert_allclose(hh.hessian(x, lam), fdh, atol=1e-8)


def test_reference_flow_matches_dop853_and_conserves_energy(hh):
    lam = np.array([0.8, 0.9, 1.0])
    x = np.vstack(
        [energy_bounded_states(hh, m, 1, energy_max=0.9 * escape_energy(m), seed=i) for i, m in enumerate(lam)]
    )
    traj = hh.trajectory(x, lam, 0.5, 40)  # T = 20
    assert traj.shape == (3, 41, 4)

    def rhs(_, y, m):
        return apply_J(hh.gradient(y[None], m))[0]

    t_eval = 0.5 * np.arange(41)
    for i in range(3):
        sol = solve_ivp(rhs, (0, 20), x[i], method="DOP853", rtol=1e-13, atol=1e-13, t_eval=t_eval, args=(lam[i],))
        np.testing.assert_allclose(traj[i], sol.y.T, atol=1e-9)
    energy = hh.hamiltonian(traj.reshape(-1, 4), np.repeat(lam, 41)).reshape(3, -1)
    assert np.abs(energy - energy[:, :1]).max() < 1e-13
    np.testing.assert_allclose(hh.flow(x, lam, 0.5), traj[:, 1], atol=1e-12)
    np.testing.assert_array_equal(hh.flow(x[0], lam[0], 0.5).shape, (4,))


def test_reference_flow_refuses_an_escaping_orbit(hh):
    with pytest.raises(SympredictError, match="step halving"):
        hh.trajectory(np.array([0.0, 3.0, 0.0, 2.0]), 1.0, 5.0, 1, max_halvings=2)


@pytest.mark.parametrize("lam, energy_max", [(1.0, None), (0.8, 0.1), (-0.9, 0.05)])
def test_sampler_stays_in_the_well_below_the_energy(hh, lam, energy_max):
    x = energy_bounded_states(hh, lam, 500, energy_max=energy_max, seed=1)
    e_max = escape_energy(lam) if energy_max is None else energy_max
    assert x.shape == (500, 4)
    assert np.all(hh.hamiltonian(x, lam) <= e_max)
    assert np.all(np.linalg.norm(x[:, :2], axis=1) <= _well_radius(lam, e_max))
    # below the escape energy orbits stay bounded: integrate a few for T = 50
    traj = hh.trajectory(x[:5], lam, 5.0, 10, tol=1e-9)
    assert np.all(np.linalg.norm(traj[:, :, :2], axis=2) <= _well_radius(lam, e_max) + 1e-9)
    # deterministic per seed, different across seeds
    np.testing.assert_array_equal(x, energy_bounded_states(hh, lam, 500, energy_max=energy_max, seed=1))
    assert not np.array_equal(x, energy_bounded_states(hh, lam, 500, energy_max=energy_max, seed=2))


def test_sampler_is_uniform_in_phase_space(hh):
    # lambda = 0: the set H <= E is a 4-ball of radius sqrt(2E); uniform => P(H <= E/2) = (1/2)^2
    x = energy_bounded_states(hh, 0.0, 20000, energy_max=0.1, seed=3)
    frac = np.mean(hh.hamiltonian(x, 0.0) <= 0.05)
    assert abs(frac - 0.25) < 0.015  # 5 standard deviations
    # the well radius solves r^2/2 - |lambda| r^3/3 = E and reaches 1/|lambda| at the escape energy
    r = _well_radius(0.9, 0.1)
    assert r * r / 2 - 0.9 * r**3 / 3 == pytest.approx(0.1, abs=1e-14)
    assert _well_radius(0.9, escape_energy(0.9)) == pytest.approx(1 / 0.9)


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda hh: energy_bounded_states(hh, 1.0, 10, energy_max=0.2), "energy_max"),
        (lambda hh: energy_bounded_states(hh, 1.0, 10, energy_max=-0.1), "energy_max"),
        (lambda hh: energy_bounded_states(hh, 0.0, 10), "energy_max"),
        (lambda hh: energy_bounded_states(hh, 1.0, 0), "n_samples"),
        (lambda hh: energy_bounded_states(hh, np.inf, 10), "lam"),
        (lambda hh: hh.trajectory(np.zeros((2, 2)), 1.0, 0.1, 1), "x0"),
        (lambda hh: hh.trajectory(np.zeros((2, 4)), np.ones(3), 0.1, 1), "lambda"),
        (lambda hh: hh.trajectory(np.zeros((2, 4)), 1.0, -0.1, 1), "dt"),
        (lambda hh: hh.trajectory(np.zeros((2, 4)), 1.0, 0.1, 1, h_max=0.0), "h_max"),
        (lambda hh: hh.trajectory(np.zeros((2, 4)), 1.0, 0.1, 1, tol=-1.0), "tol"),
        (lambda hh: hh.hamiltonian(np.zeros((2, 3)), 1.0), "x"),
    ],
)
def test_bad_input_names_the_argument(hh, call, match):
    with pytest.raises(ValueError, match=match):
        call(hh)
