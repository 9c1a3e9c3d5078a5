"""The estimator composed of parts: kernel transforms, update rules, trainers, the Newton solver.

Each part owns its settings; the estimator keeps at most eight.  The flat options of the pre-release
versions are not parameters (a TypeError names the estimator's parameters), and their model files (layout 2,
committed, written by the code of that version: ``tests/data/layout2/make_files.py``) are refused with the
advice to refit.
"""

import json
from pathlib import Path

import numpy as np
import pytest

from sympredict import DirectKernelPredictor, SymplecticKernelPredictor
from sympredict.interpolation.greedy import ActiveSetGreedy, ExactGreedy, ShardedGreedy
from sympredict.io import load_model
from sympredict.kernels import IMQ
from sympredict.estimators.predictor import NUMPY_ONLY
from sympredict.exceptions import ModelFileError
from sympredict.symplectic.solvers import NewtonSolver
from sympredict.kernels.transforms import Periodic, Scaled, Symmetric, lower_state_kernel, transform_from_spec
from sympredict.symplectic.updates import Midpoint, SymplecticEuler, as_update
from _tolerances import rollout_bound  # tests/

LAYOUT2 = Path(__file__).resolve().parents[1] / "data" / "layout2"


def _data(d, n=300):
    inside = np.flatnonzero(np.abs(d.x0[:, 0]) < 3.0)  # no two angles one period apart (periodic models)
    idx = np.random.default_rng(1).choice(inside, n, replace=False)
    return d.x0[idx], d.x1[idx], d.mu[idx], d.dt[idx]


def test_the_estimators_keep_at_most_eight_options():
    assert len(SymplecticKernelPredictor._param_names()) <= 8, SymplecticKernelPredictor._param_names()
    assert len(DirectKernelPredictor._param_names()) <= 8
    assert set(SymplecticKernelPredictor._param_names()) == {
        "state_kernel",
        "mu_kernel",
        "dt_kernel",
        "max_centers",
        "update",
        "trainer",
        "solver",
        "search",
    }


# ------------------------------------------------------------------ pre-release options
PRE_RELEASE_OPTIONS = (
    "tol",
    "criterion",
    "power_tol",
    "memory_limit",
    "regularization",
    "backend",
    "newton_max_iter",
    "newton_warm_start",
    "state_scaling",
    "periodic",
    "period",
    "symmetry",
)


@pytest.mark.parametrize("name", PRE_RELEASE_OPTIONS)
def test_pre_release_options_are_not_parameters(name):
    with pytest.raises(TypeError, match=rf"unexpected keyword argument '{name}'"):
        SymplecticKernelPredictor(IMQ(0.3), max_centers=10, **{name: 1})
    with pytest.raises(ValueError, match=rf"no parameter '{name}'"):
        SymplecticKernelPredictor(IMQ(0.3), max_centers=10).set_params(**{name: 1})
    assert not hasattr(SymplecticKernelPredictor(IMQ(0.3)), name)


def test_unknown_options_are_type_errors():
    with pytest.raises(TypeError, match="unexpected keyword argument.*max_center"):
        SymplecticKernelPredictor(IMQ(0.3), max_center=3)
    with pytest.raises(TypeError, match="unexpected keyword argument.*backend"):
        DirectKernelPredictor(IMQ(0.3), backend="numpy")


# ------------------------------------------------------------------ files
def _expected():
    return json.loads((LAYOUT2 / "expected.json").read_text())


@pytest.mark.parametrize("name", sorted(_expected()["models"]))
def test_pre_release_model_files_are_refused_with_the_advice_to_refit(name):
    with pytest.raises(ModelFileError, match=r"pre-release version of sympredict .*fit the model again and save it"):
        load_model(LAYOUT2 / f"{name}.h5")


# ------------------------------------------------------------------ backends
def test_numpy_only_features_are_declared_once_refused_for_numba_and_said_under_auto(small_pendulum_data):
    """The table's remaining row (an update rule without a compiled kernel) is refused for 'numba' at fit and said
    under 'auto'; every transform compiles (``tests/kernels/test_transforms_compiled.py`` checks them against NumPy)."""
    x0, x1, mu, dt = _data(small_pendulum_data)

    class Outside(Midpoint):  # a rule added from outside the package: no compiled kernel
        compiled = False

    reasons = [reason for applies, reason in NUMPY_ONLY if applies(lower_state_kernel(IMQ(0.3)), Outside())]
    assert len(reasons) == 1
    numba = SymplecticKernelPredictor(
        IMQ(0.3), IMQ(1.5), IMQ(3.0), max_centers=10, update=Outside(), solver=NewtonSolver(backend="numba")
    )
    with pytest.raises(ValueError, match=reasons[0] + ".*backend='numpy'"):
        numba.fit(x0, x1, mu=mu, dt=dt)
    for kernel in (Periodic(IMQ(0.3), coordinates=(0,), period=8.0), Symmetric(IMQ(0.3), group=[(1, 1), (-1, -1)])):
        parts = lower_state_kernel(kernel)
        assert not [reason for applies, reason in NUMPY_ONLY if applies(parts, Midpoint())]
        auto = SymplecticKernelPredictor(
            kernel, IMQ(1.5), IMQ(3.0), max_centers=10, update="midpoint", solver=NewtonSolver()
        ).fit(x0, x1, mu=mu, dt=dt)
        assert auto.numpy_only_ is None
        assert auto.backend_for(10_000, 10_000) == "numba"
    plain = SymplecticKernelPredictor(IMQ(0.3), IMQ(1.5), IMQ(3.0), max_centers=10).fit(x0, x1, mu=mu, dt=dt)
    assert plain.numpy_only_ is None


# ------------------------------------------------------------------ transforms
def test_transforms_pass_shapes_through_and_refuse_bad_chains():
    k = Symmetric(Periodic(IMQ(0.3), coordinates=(0,)), group=[(1, 1), (-1, -1)])  # both: sign flips respect periods
    parts = lower_state_kernel(k)
    assert parts.periodic == (0,) and parts.symmetry == [(1, 1), (-1, -1)]
    with pytest.raises(ValueError, match="applies Scaled twice"):
        lower_state_kernel(Scaled(Scaled(IMQ(1.0), factors=[2.0]), factors=[3.0]))
    with pytest.raises(ValueError, match="coordinates must be a tuple of distinct"):
        lower_state_kernel(Periodic(IMQ(1.0), coordinates=(0, 0)))
    with pytest.raises(ValueError, match="factors must be positive"):
        lower_state_kernel(Scaled(IMQ(1.0), factors=[-1.0]))
    chain = Periodic(Scaled(IMQ(0.3), factors=[2.0]), coordinates=(0,), period=4.0)
    assert chain.get_params()["eps"] == 0.3
    moved = chain.set_params(eps=0.6)
    assert moved.radial == IMQ(0.6) and chain.radial == IMQ(0.3)  # a new value; the old one unchanged
    assert transform_from_spec(chain.spec) == chain
    parts = lower_state_kernel(chain)
    assert parts.scaling == (2.0,) and parts.periodic == (0,) and parts.period == 4.0
    model = SymplecticKernelPredictor(chain).set_params(state_kernel__eps=0.5)
    assert model.state_kernel.radial == IMQ(0.5)
    with pytest.raises(ValueError, match="default state kernel"):
        Periodic(None, coordinates=(0,)).set_params(eps=1.0)


def test_the_direct_model_refuses_transforms(small_pendulum_data):
    x0, x1, mu, dt = _data(small_pendulum_data, 50)
    with pytest.raises(ValueError, match="radial state kernel"):
        DirectKernelPredictor(Periodic(IMQ(0.3)), IMQ(1.5), IMQ(3.0)).fit(x0, x1, mu=mu, dt=dt)


# ------------------------------------------------------------------ update rules and trainers
def test_update_rules_by_name_and_their_symmetry_checks():
    assert as_update("midpoint") == Midpoint() and as_update(SymplecticEuler()) == "symplectic_euler"
    with pytest.raises(ValueError, match="update must be one of"):
        as_update("leapfrog")
    flip_q = np.diag([-1.0, 1.0])  # q -> -q: anti-symplectic, a reversing symmetry
    Midpoint().check_symmetry(np.array([np.eye(2), flip_q]))
    with pytest.raises(ValueError, match="not of the form diag"):
        SymplecticEuler().check_symmetry(np.array([np.eye(2), flip_q]))
    with pytest.raises(ValueError, match="neither symplectic"):
        Midpoint().check_symmetry(np.array([np.eye(2), np.diag([2.0, 1.0])]))


def test_each_trainer_owns_only_the_settings_it_can_run():
    assert "criterion" not in ActiveSetGreedy._param_names()
    assert "regularization" not in ActiveSetGreedy._param_names()
    assert "memory_limit" not in ShardedGreedy._param_names()
    for bad, match in [
        (ExactGreedy(tol=-1.0), "tol"),
        (ExactGreedy(criterion="x"), "criterion"),
        (ExactGreedy(power_tol=2.0), "power_tol"),
        (ExactGreedy(memory_limit=0), "memory_limit"),
        (ActiveSetGreedy(tol=float("nan")), "tol"),
    ]:
        with pytest.raises(ValueError, match=match):
            bad.check()
    with pytest.raises(ValueError, match="max_iter"):
        NewtonSolver(max_iter=0).check()
    with pytest.raises(ValueError, match="backend must be"):
        NewtonSolver(backend="gpu").check()


# ------------------------------------------------------------------ the flow-map protocol and the wrappers' hook
def test_predictors_and_wrappers_are_flow_maps(small_pendulum_data):
    from sympredict.flowmap.protocol import FlowMap, SymplecticFlowMap
    from sympredict.flowmap.splitting import SplitKernelPredictor
    from sympredict.systems.linear_flow import QuadraticPart

    x0, x1, mu, dt = _data(small_pendulum_data)
    sym = SymplecticKernelPredictor(IMQ(0.3), IMQ(1.5), IMQ(3.0), max_centers=20).fit(x0, x1, mu=mu, dt=dt)
    direct = DirectKernelPredictor(IMQ(0.3), IMQ(1.5), IMQ(3.0), max_centers=20).fit(x0, x1, mu=mu, dt=dt)
    split = SplitKernelPredictor(
        SymplecticKernelPredictor(IMQ(0.3), IMQ(1.5), IMQ(3.0), max_centers=20),
        QuadraticPart(np.eye(2)[None], np.zeros((1, 1))),
    ).fit(x0, x1, mu=mu, dt=dt)
    for model in (sym, split):
        assert isinstance(model, SymplecticFlowMap) and model.dim_ == 2 and model.n_mu_ == 1
    assert isinstance(direct, FlowMap) and not isinstance(direct, SymplecticFlowMap)


@pytest.mark.parametrize("backend", ["numpy", "numba"])
def test_the_around_hook_is_the_composed_step_on_the_same_solver(small_pendulum_data, backend, monkeypatch):
    import sympredict.estimators.fitted as fitted  # the fitted flow map runs the rollouts

    x0, x1, mu, dt = _data(small_pendulum_data)
    model = SymplecticKernelPredictor(
        IMQ(0.3), IMQ(1.5), IMQ(3.0), max_centers=40, solver=NewtonSolver(backend=backend)
    ).fit(x0, x1, mu=mu, dt=dt)
    theta = 0.05
    rot = np.array([[np.cos(theta), np.sin(theta)], [-np.sin(theta), np.cos(theta)]])  # symplectic (det 1, 2-D)
    x = x0[:3] * 0.5
    calls = []
    real = fitted.implicit_rollout
    monkeypatch.setattr(fitted, "implicit_rollout", lambda *a, **k: calls.append(k["backend"]) or real(*a, **k))
    traj = model.rollout(x, 4, mu=mu[:3], dt=dt[:3], around=(rot, rot.T))
    assert set(calls) == {backend}  # a wrapped rollout stays on the model's solver
    expected = [x]
    for _ in range(4):
        expected.append(expected[-1] @ rot.T)  # pre x
        expected[-1] = model.step(expected[-1], mu=mu[:3], dt=dt[:3]) @ rot  # post Phi(pre x)
    expected = np.stack(expected, axis=1)
    sur = model.surrogate_
    bound = rollout_bound(sur, expected, sur.weights(mu[:3].reshape(3, -1), dt[:3]), dt[:3])
    np.testing.assert_allclose(traj, expected, rtol=0, atol=bound)
    with pytest.raises(ValueError, match="around: pre must be finite matrices"):
        model.rollout(x, 2, mu=mu[:3], dt=dt[:3], around=(np.eye(3), np.eye(2)))
    model.set_params(solver__warm_start=True)  # not run inside a wrapped rollout: said, not silently dropped
    with pytest.warns(UserWarning, match="warm_start does not apply to a wrapped rollout"):
        model.rollout(x, 2, mu=mu[:3], dt=dt[:3], around=(rot, rot.T))
