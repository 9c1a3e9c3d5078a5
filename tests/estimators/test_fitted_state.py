"""The fitted state is what predicts: settings changed after a fit take effect at the next fit; a failed refit keeps
the fitted settings; what save writes, load accepts."""

import numpy as np
import pytest

from sympredict import SymplecticKernelPredictor
from sympredict.kernels import IMQ
from sympredict.estimators.predictor import MAX_NEWTON_ITER
from sympredict.symplectic.solvers import NewtonSolver
from sympredict.kernels.transforms import Periodic, Scaled

DT = 0.1


def test_set_params_after_fit_does_not_change_predictions(coarse_pendulum_data, tmp_path):
    m = SymplecticKernelPredictor(IMQ(0.3), max_centers=20, solver=NewtonSolver(backend="numpy")).fit(
        coarse_pendulum_data.x0, coarse_pendulum_data.x1, dt=DT
    )
    x = coarse_pendulum_data.x0[:4]
    before = m.step(x)
    for change in (
        {"update": "midpoint"},
        {"state_kernel": Scaled(IMQ(0.3), factors=(2.0,))},
        {"state_kernel": Periodic(IMQ(0.3), coordinates=(0,))},
    ):
        m.set_params(**change)
        np.testing.assert_array_equal(m.step(x), before)
    m.save(tmp_path / "m.h5")  # the fitted settings are written (a later periodic kernel would not fit the arrays)
    back = SymplecticKernelPredictor.load(tmp_path / "m.h5")
    np.testing.assert_array_equal(back.step(x), before)
    # the fitted settings, not the later ones (update=None at fit: 'symplectic_euler' with the kernel given)
    assert back.update is None and back.update_ == "symplectic_euler" and back.state_kernel == IMQ(0.3)


def test_a_changed_parameter_takes_effect_at_the_next_fit(coarse_pendulum_data):
    m = SymplecticKernelPredictor(IMQ(0.3), max_centers=20, solver=NewtonSolver(backend="numpy")).fit(
        coarse_pendulum_data.x0, coarse_pendulum_data.x1, dt=DT
    )
    m.set_params(update="midpoint").fit(coarse_pendulum_data.x0, coarse_pendulum_data.x1, dt=DT)
    assert m.update_ == "midpoint" and m.fitted_params_["update"] == "midpoint"


def test_failed_refit_keeps_the_fitted_settings(coarse_pendulum_data):
    m = SymplecticKernelPredictor(IMQ(0.3), max_centers=20, solver=NewtonSolver(backend="numpy")).fit(
        coarse_pendulum_data.x0, coarse_pendulum_data.x1, dt=DT
    )
    x = coarse_pendulum_data.x0[:4]
    before = m.step(x)
    m.set_params(state_kernel=Scaled(IMQ(0.3), factors=(2.0,)))
    with pytest.raises(ValueError):
        m.fit(coarse_pendulum_data.x0, coarse_pendulum_data.x1[:5], dt=DT)
    assert m.state_scaling_ is None
    np.testing.assert_array_equal(m.step(x), before)


def test_save_refuses_a_solver_setting_load_would_refuse(coarse_pendulum_model, tmp_path):
    import copy

    m = copy.copy(coarse_pendulum_model)
    solver = m.solver
    with pytest.raises(ValueError, match=r"set_params\(solver__backend='gpu'\): backend must be .*got 'gpu'"):
        m.set_params(solver__backend="gpu")  # refused at once, and nothing changed
    assert m.solver is solver
    m.solver = NewtonSolver(backend="gpu")  # planted by assignment: save must refuse it
    with pytest.raises(ValueError, match="backend"):
        m.save(tmp_path / "x.h5")
    assert not (tmp_path / "x.h5").exists()


def test_a_fitted_periodic_model_saves_with_the_compiled_backend(coarse_pendulum_data, tmp_path):
    """Periodic coordinates run compiled now: backend='numba' is a valid pair, saved and loaded back (a pair load
    would refuse is refused at save: test_save_refuses_a_solver_setting_load_would_refuse)."""
    m = SymplecticKernelPredictor(
        Periodic(IMQ(0.3), coordinates=(0,)), max_centers=10, solver=NewtonSolver(backend="numpy")
    ).fit(coarse_pendulum_data.x0, coarse_pendulum_data.x1, dt=DT)
    m.set_params(solver__backend="numba")
    m.save(tmp_path / "n.h5")
    loaded = SymplecticKernelPredictor.load(tmp_path / "n.h5")
    assert loaded.periodic_ == (0,) and loaded.solver.backend == "numba"
    m.set_params(solver__backend="auto")
    m.save(tmp_path / "p.h5")
    assert SymplecticKernelPredictor.load(tmp_path / "p.h5").periodic_ == (0,)


def test_endless_newton_setting_refused_at_prediction(coarse_pendulum_model, coarse_pendulum_data):
    import copy

    m = copy.copy(coarse_pendulum_model)
    solver = m.solver
    with pytest.raises(ValueError, match="max_iter must be at most"):
        m.set_params(solver__max_iter=10**15)  # refused at once, and nothing changed
    assert m.solver is solver
    m.solver = NewtonSolver(max_iter=10**15)  # set by assignment: prediction checks it
    with pytest.raises(ValueError, match="max_iter must be at most"):
        m.step(coarse_pendulum_data.x0[:2])
    with pytest.raises(ValueError, match=str(MAX_NEWTON_ITER)):
        SymplecticKernelPredictor(IMQ(0.3), solver=NewtonSolver(max_iter=MAX_NEWTON_ITER + 1)).fit(
            coarse_pendulum_data.x0, coarse_pendulum_data.x1, dt=DT
        )
