"""Numeric arguments of the systems and data helpers: ValueError naming the argument (issue 16)."""

import time

import numpy as np
import pytest

from sympredict.symplectic.integrators import micro_steps
from sympredict.mor.basis import complex_svd_basis
from sympredict.systems.pendulum import Pendulum, energy_bounded_grid, flow_map_data, random_flow_map_data
from sympredict.systems.quadratic import QuadraticHamiltonian
from sympredict.systems.wave import WaveFOM, fd_laplacian

X = np.array([[0.3, 0.1]])


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"g": np.nan}, "g must be finite"),
        ({"g": np.inf}, "g must be finite"),
        ({"g": 0.0}, "g must be positive"),
        ({"g": "9.81"}, "g must be a real number"),
        ({"g": True}, "g must be a real number"),
        ({"mass": np.nan}, "mass must be finite"),
        ({"mass": -1.0}, "mass must be positive"),
        ({"mass": 1 + 1j}, "mass must be a real number"),
    ],
)
def test_pendulum_constants(kwargs, match):
    with pytest.raises(ValueError, match=match):
        Pendulum(**kwargs)


@pytest.mark.parametrize(
    "h_max, match",
    [
        (0.0, "h_max must be positive"),
        (-1e-3, "h_max must be positive"),
        (np.nan, "h_max must be finite"),
        (np.inf, "h_max must be finite"),
        (1e-300, "too many"),
    ],
)
def test_reference_flows_refuse_bad_micro_steps(h_max, match):
    P = Pendulum()
    with pytest.raises(ValueError, match=match):
        P.flow(X, 0.75, 0.05, h_max=h_max)
    with pytest.raises(ValueError, match=match):
        P.trajectory(X, 0.75, 0.05, 2, h_max=h_max)
    q = QuadraticHamiltonian(np.eye(2), np.zeros((2, 2)))
    with pytest.raises(ValueError, match=match):
        q.flow(X, 0.5, 0.05, h_max=h_max)
    with pytest.raises(ValueError, match=match):
        q.trajectory(X, 0.5, 0.05, 2, h_max=h_max)
    fom = WaveFOM(10)
    with pytest.raises(ValueError, match=match):
        fom.trajectory(np.zeros((1, 20)), 0.05, 0.1, 2, h_max=h_max)


def test_micro_steps_refuses_bad_times():
    assert micro_steps(0.05, 1e-3) == 50
    for t in (-0.1, np.nan, np.inf):
        with pytest.raises(ValueError, match="times must be finite and >= 0"):
            micro_steps(t, 1e-3)


@pytest.mark.parametrize("mu", [np.nan, np.inf, -0.0 + np.nan, [0.75, np.nan]])
def test_pendulum_lengths(mu):
    with pytest.raises(ValueError, match="pendulum length"):
        Pendulum().flow(np.array([[0.3, 0.1], [0.2, 0.0]]), mu, 0.05)


def test_wave_fom_times_and_constants():
    fom = WaveFOM(10)
    x = np.zeros((1, 20))
    for dt in (-0.1, 0.0, np.nan):
        with pytest.raises(ValueError, match="dt"):
            fom.exact_trajectory(x, 0.05, dt, 3)
        with pytest.raises(ValueError, match="dt"):
            fom.trajectory(x, 0.05, dt, 3)
    for kwargs, match in (
        ({"T": -1.0}, "T must be positive"),
        ({"T": np.nan}, "T must be finite"),
        ({"dt_micro": 0.0}, "dt_micro must be positive"),
        ({"length": np.nan}, "length must be finite"),
        ({"mu_range": (np.nan, 0.09)}, "mu_range must be finite"),
        ({"mu_range": (0.04,)}, "mu_range must be"),
    ):
        with pytest.raises(ValueError, match=match):
            WaveFOM(10, **kwargs)
    with pytest.raises(ValueError, match="energy must be finite"):
        fom.low_frequency_states(3, 2, 0.05, np.nan)
    with pytest.raises(ValueError, match="mu must be positive"):
        fom.low_frequency_states(3, 2, -0.05, 1.0)
    with pytest.raises(ValueError, match="length must be positive"):
        fd_laplacian(10, -1.0)
    with pytest.raises(ValueError, match="mu must be finite"):
        fom.hamiltonian_matrix(np.nan)


def test_complex_or_non_numeric_snapshots_are_refused():
    snaps = np.ones((4, 6))
    with pytest.raises(ValueError, match="snapshots must be real, got complex"):
        complex_svd_basis(snaps * (1 + 1j), n=1)
    with pytest.raises(ValueError, match="snapshots must be a real numeric array"):
        complex_svd_basis(np.array([["a"] * 6] * 4), n=1)
    with pytest.raises(ValueError, match="snapshots contains NaN"):
        complex_svd_basis(np.full((4, 6), np.nan), n=1)


def test_quadratic_hamiltonian_refuses_non_finite_matrices_and_parameters():
    with pytest.raises(ValueError, match="H0 contains NaN"):
        QuadraticHamiltonian(np.full((2, 2), np.nan), np.zeros((2, 2)))
    q = QuadraticHamiltonian(np.eye(2), np.eye(2))
    with pytest.raises(ValueError, match="mu must be finite"):
        q.sample_energy_ellipsoid(5, np.nan, 1.0)
    with pytest.raises(ValueError, match="h must be positive"):
        q.midpoint_propagator(0.5, -0.1)


def test_sampler_that_can_never_accept_gives_up_quickly():
    """With mass 1e12 the energy bound H < 2 g keeps |q| < ~2e-6: almost no draw is accepted."""
    t0 = time.perf_counter()
    with pytest.raises(ValueError, match=r"only \d+ of 50 states accepted .* in 5000 draws"):
        random_flow_map_data(Pendulum(mass=1e12), 50)
    assert time.perf_counter() - t0 < 5
    for kwargs, match in (
        ({"mu_range": (0.8, 0.7)}, "low <= high"),
        ({"dt_range": (np.nan, 0.06)}, "dt_range must be finite"),
        ({"mu_range": (-1.0, 0.8)}, "mu_range must be positive"),
    ):
        with pytest.raises(ValueError, match=match):
            random_flow_map_data(Pendulum(), 10, **kwargs)
    # the ordinary sampler still works and is unchanged by the bound
    d = random_flow_map_data(Pendulum(), 40, seed=3)
    assert len(d) == 40 and np.all(Pendulum().hamiltonian(d.x0, d.mu[:, 0]) < 2 * 9.81)


def test_grid_helpers():
    with pytest.raises(ValueError, match="energy_max must be finite"):
        energy_bounded_grid(Pendulum(), 0.75, 10, energy_max=np.nan)
    with pytest.raises(ValueError, match="mus must be a non-empty"):
        flow_map_data(Pendulum(), mus=(), n_grid=5)
    with pytest.raises(ValueError, match="dts must be a non-empty"):
        flow_map_data(Pendulum(), dts=[], n_grid=5)
