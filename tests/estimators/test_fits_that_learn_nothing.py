"""Fits that would learn nothing (data in small units, kernels far too narrow, no centre selected) learn or say so;
data that do not move give the identity without a warning."""

import warnings

import numpy as np
import pytest

from sympredict import DirectKernelPredictor, SymplecticKernelPredictor
from sympredict.exceptions import UnderfitWarning
from sympredict.kernels import IMQ
from sympredict.interpolation.greedy import ExactGreedy
from sympredict.symplectic.solvers import NewtonSolver

DT = 0.1


def test_small_units_fit_learns(coarse_pendulum_data):
    """States x 1e-11 with the shape scaled to match: before, tol (absolute) stopped at 0 centres (identity)."""
    s = 1e-11
    m = SymplecticKernelPredictor(IMQ(0.3 / s), max_centers=30, solver=NewtonSolver(backend="numpy")).fit(
        coarse_pendulum_data.x0 * s, coarse_pendulum_data.x1 * s, dt=DT
    )
    ref = SymplecticKernelPredictor(IMQ(0.3), max_centers=30, solver=NewtonSolver(backend="numpy")).fit(
        coarse_pendulum_data.x0, coarse_pendulum_data.x1, dt=DT
    )
    assert m.n_centers_ == ref.n_centers_ == 30
    x, x1 = coarse_pendulum_data.x0, coarse_pendulum_data.x1
    err, err_ref, moved = (np.abs(m.step(x * s) / s - x1).max(), np.abs(ref.step(x) - x1).max(), np.abs(x1 - x).max())
    assert err < 0.1 * moved and err < 3 * err_ref  # learned as well as in units of order one


def test_small_units_default_kernel_learns(coarse_pendulum_data):
    """``state_kernel=None`` on states x 1e-11: the default shape follows the data and the fit learns."""
    s = 1e-11
    m = SymplecticKernelPredictor(max_centers=30, solver=NewtonSolver(backend="numpy")).fit(
        coarse_pendulum_data.x0 * s, coarse_pendulum_data.x1 * s, dt=DT
    )
    assert m.n_centers_ == 30
    err = np.abs(m.step(coarse_pendulum_data.x0[:4] * s) - coarse_pendulum_data.x1[:4] * s).max() / s
    assert err < 0.1 * np.abs(coarse_pendulum_data.x1 - coarse_pendulum_data.x0).max()


def test_default_kernel_on_states_too_small_is_refused(coarse_pendulum_data):
    """States x 1e-170: the diameter was 0 (underflow) and IMQ(1) was used silently; now a clear ValueError."""
    with pytest.raises(ValueError, match="rescale the states"):
        SymplecticKernelPredictor(max_centers=10).fit(
            coarse_pendulum_data.x0 * 1e-170, coarse_pendulum_data.x1 * 1e-170, dt=DT
        )


def test_fit_selecting_no_centre_warns(coarse_pendulum_data):
    with pytest.warns(UnderfitWarning, match="selected no centre.*lower tol"):
        m = SymplecticKernelPredictor(IMQ(0.3), max_centers=30, trainer=ExactGreedy(tol=100.0)).fit(
            coarse_pendulum_data.x0, coarse_pendulum_data.x1, dt=DT
        )
    assert m.n_centers_ == 0


def test_direct_fit_selecting_no_centre_warns(coarse_pendulum_data):
    with pytest.warns(UnderfitWarning, match="DirectKernelPredictor.fit selected no centre"):
        DirectKernelPredictor(IMQ(0.3), max_centers=30, trainer=ExactGreedy(tol=100.0)).fit(
            coarse_pendulum_data.x0, coarse_pendulum_data.x1, dt=DT
        )


def test_fit_with_a_kernel_far_too_narrow_warns(coarse_pendulum_data):
    """A shape 10^4 times too large: the model moves only its few centres, i.e. barely moves the data."""
    with pytest.warns(UnderfitWarning, match="less than a tenth"):
        SymplecticKernelPredictor(IMQ(3e4), max_centers=3, solver=NewtonSolver(backend="numpy")).fit(
            coarse_pendulum_data.x0, coarse_pendulum_data.x1, dt=DT
        )


def test_data_that_do_not_move_give_the_identity_without_warning(coarse_pendulum_data):
    with warnings.catch_warnings():
        warnings.simplefilter("error", UnderfitWarning)
        m = SymplecticKernelPredictor(IMQ(0.3), max_centers=30).fit(
            coarse_pendulum_data.x0, coarse_pendulum_data.x0.copy(), dt=DT
        )
    assert m.n_centers_ == 0
