"""The estimator composed of parts: kernel transforms, update rules, trainers, the Newton solver.

Each part owns its settings; the estimator keeps at most eight; the options of sympredict 0.1 still work
with a FutureWarning naming the replacement, and model files of layout 2 (committed, written by the code of
that version: ``tests/data/layout2/make_files.py``) load into the new composition and predict as they did.
"""

import json
import warnings
from pathlib import Path

import numpy as np
import pytest

from sympredict import DirectKernelPredictor, SymplecticKernelPredictor
from sympredict.base import clone
from sympredict.interpolation.greedy import ActiveSetGreedy, ExactGreedy, ShardedGreedy
from sympredict.io import load_model
from sympredict.kernels import IMQ, Matern52
from sympredict.estimators.predictor import MOVED_OPTIONS, NUMPY_ONLY
from sympredict.symplectic.solvers import NewtonSolver
from sympredict.kernels.transforms import Periodic, Scaled, Symmetric, lower_state_kernel, transform_from_spec
from sympredict.symplectic.updates import Midpoint, SymplecticEuler, as_update
from _tolerances import rollout_bound, value_rollout_bound  # tests/

LAYOUT2 = Path(__file__).parent / "data" / "layout2"


def _data(d, n=300):
    inside = np.flatnonzero(np.abs(d.x0[:, 0]) < 3.0)  # no two angles one period apart (periodic models)
    idx = np.random.default_rng(1).choice(inside, n, replace=False)
    return d.x0[idx], d.x1[idx], d.mu[idx], d.dt[idx]


def test_the_estimators_keep_at_most_eight_options():
    assert len(SymplecticKernelPredictor._param_names()) <= 8, SymplecticKernelPredictor._param_names()
    assert len(DirectKernelPredictor._param_names()) <= 8
    assert set(SymplecticKernelPredictor._param_names()) == {
        "state_kernel", "mu_kernel", "dt_kernel", "max_centers", "update", "trainer", "solver", "search"}


# ------------------------------------------------------------------ old options
@pytest.mark.parametrize("name, value, check", [
    ("tol", 1e-9, lambda m: m.trainer == ExactGreedy(tol=1e-9) or m.trainer.tol == 1e-9),
    ("criterion", "p", lambda m: m.trainer.criterion == "p"),
    ("power_tol", 1e-11, lambda m: m.trainer.power_tol == 1e-11),
    ("memory_limit", 1e9, lambda m: m.trainer.memory_limit == 1e9),
    ("regularization", 1e-6, lambda m: m.trainer.regularization == 1e-6),
    ("backend", "numpy", lambda m: m.solver.backend == "numpy"),
    ("newton_max_iter", 7, lambda m: m.solver.max_iter == 7),
    ("newton_warm_start", True, lambda m: m.solver.warm_start is True),
    ("state_scaling", [2.0], lambda m: m.state_kernel == Scaled(IMQ(0.3), factors=[2.0])),
    ("periodic", (0,), lambda m: m.state_kernel == Periodic(IMQ(0.3), coordinates=(0,))),
    ("symmetry", [(1, 1), (-1, -1)], lambda m: m.state_kernel == Symmetric(IMQ(0.3), group=[(1, 1), (-1, -1)])),
])
def test_each_old_option_warns_with_its_replacement_and_lands_in_its_part(name, value, check):
    part = MOVED_OPTIONS[name][0]
    with pytest.warns(FutureWarning, match=rf"{name}=\.\.\.\) is deprecated: pass {part}="):
        model = SymplecticKernelPredictor(IMQ(0.3), max_centers=10, **{name: value})
    assert check(model)
    assert set(model.get_params(deep=False)) == set(SymplecticKernelPredictor._param_names())
    with pytest.warns(FutureWarning, match="deprecated"):
        same = SymplecticKernelPredictor(IMQ(0.3), max_centers=10).set_params(**{name: value})
    assert repr(same.get_params(deep=False)) == repr(model.get_params(deep=False))
    with pytest.warns(FutureWarning, match=f"read it from the part that owns it.*{part}="):
        read = getattr(model, name)
    assert read == value or np.array_equal(np.asarray(read, dtype=float), np.asarray(value, dtype=float))


def test_old_options_fold_into_a_given_part_without_changing_the_callers_object():
    given = ActiveSetGreedy(initial_points=100)
    with pytest.warns(FutureWarning):
        model = SymplecticKernelPredictor(IMQ(0.3), trainer=given, tol=1e-7, criterion="f")
    assert model.trainer.tol == 1e-7 and model.trainer.initial_points == 100 and given.tol == 1e-10
    with pytest.warns(FutureWarning), pytest.raises(ValueError, match="ActiveSetGreedy has no setting criterion"):
        SymplecticKernelPredictor(IMQ(0.3), trainer=ActiveSetGreedy(), criterion="p")
    with pytest.raises(TypeError, match="unexpected keyword argument.*max_center"):
        SymplecticKernelPredictor(IMQ(0.3), max_center=3)
    with pytest.raises(TypeError, match="unexpected keyword argument.*backend"):
        DirectKernelPredictor(IMQ(0.3), backend="numpy")


def test_old_and_new_spelling_fit_the_same_model(small_pendulum_data):
    x0, x1, mu, dt = _data(small_pendulum_data)
    new = SymplecticKernelPredictor(Scaled(IMQ(0.3), factors=[1.5]), IMQ(1.5), IMQ(3.0), max_centers=30,
                                    update="midpoint", trainer=ExactGreedy(tol=1e-9, power_tol=1e-11),
                                    solver=NewtonSolver(backend="numpy", max_iter=20)).fit(x0, x1, mu=mu, dt=dt)
    with pytest.warns(FutureWarning):
        old = SymplecticKernelPredictor(IMQ(0.3), IMQ(1.5), IMQ(3.0), max_centers=30, update="midpoint", tol=1e-9,
                                        power_tol=1e-11, backend="numpy", newton_max_iter=20, state_scaling=[1.5])
    old.fit(x0, x1, mu=mu, dt=dt)
    # the same settings through the same code on the same arrays: the same fit, bit for bit
    np.testing.assert_array_equal(old.surrogate_.coef, new.surrogate_.coef)
    np.testing.assert_array_equal(old.step(x0[:4], mu=mu[:4], dt=dt[:4]), new.step(x0[:4], mu=mu[:4], dt=dt[:4]))
    assert new.state_scaling_ == (1.5,) and new.update_ == "midpoint" and new.numpy_only_ is None


# ------------------------------------------------------------------ files
def _expected():
    return json.loads((LAYOUT2 / "expected.json").read_text())


@pytest.mark.parametrize("name", sorted(_expected()["models"]))
def test_layout_2_files_load_into_the_parts_and_predict_as_when_written(name, tmp_path):
    exp = _expected()
    with warnings.catch_warnings():
        warnings.simplefilter("error", FutureWarning)  # a file is not the user's spelling: no deprecation noise
        model = load_model(LAYOUT2 / f"{name}.h5")
    start, mu, dt = (np.array(exp[k]) for k in ("start", "mu", "dt"))
    expected = np.array(exp["models"][name])
    got = model.rollout(start, 3, mu=mu, dt=dt)
    sur = model.surrogate_
    if isinstance(model, DirectKernelPredictor):
        bound = value_rollout_bound(sur.coef, expected, dt)
    else:
        bound = rollout_bound(sur, expected, sur.weights(mu.reshape(len(mu), -1), dt), dt)
    np.testing.assert_allclose(got, expected, rtol=0, atol=bound)
    assert bound < 1e-8
    # written again, the file is layout 3 and loads to the same parameters
    model.save(tmp_path / "again.h5")
    back = load_model(tmp_path / "again.h5")
    assert repr(back.get_params(deep=False)) == repr(model.get_params(deep=False))


def test_layout_2_settings_become_parts():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        models = {name: load_model(LAYOUT2 / f"{name}.h5") for name in _expected()["models"]}
    m = models["solver_and_greedy"]
    assert m.state_kernel == Matern52(0.4)
    assert m.trainer.get_params() == ExactGreedy(tol=1e-9, criterion="p", power_tol=1e-11,
                                                 regularization=1e-10).get_params()
    assert m.solver.get_params() == NewtonSolver(max_iter=30, warm_start=True, backend="numpy").get_params()
    assert models["midpoint_scaled"].state_kernel == Scaled(IMQ(0.3), factors=[1.5])
    assert models["midpoint_scaled"].update_ == "midpoint"
    assert models["periodic"].state_kernel == Periodic(IMQ(0.3), coordinates=(0,), period=2 * np.pi)
    assert models["symmetric"].state_kernel == Symmetric(IMQ(0.3), group=[(1, 1), (-1, -1)])
    assert models["active_set"].trainer.tol == 1e-8 and models["active_set"].trainer.initial_points == 200
    assert models["float32"].trainer.basis_dtype == "float32"
    assert models["direct"].trainer.get_params() == ExactGreedy(tol=1e-9, power_tol=1e-11).get_params()


# ------------------------------------------------------------------ backends
def test_numpy_only_features_are_declared_once_refused_for_numba_and_said_under_auto(small_pendulum_data):
    """The table's remaining row (an update rule without a compiled kernel) is refused for 'numba' at fit and said
    under 'auto'; every transform compiles (``tests/test_transforms_compiled.py`` checks them against NumPy)."""
    x0, x1, mu, dt = _data(small_pendulum_data)

    class Outside(Midpoint):  # a rule added from outside the package: no compiled kernel
        compiled = False

    reasons = [reason for applies, reason in NUMPY_ONLY if applies(lower_state_kernel(IMQ(0.3)), Outside())]
    assert len(reasons) == 1
    numba = SymplecticKernelPredictor(IMQ(0.3), IMQ(1.5), IMQ(3.0), max_centers=10, update=Outside(),
                                      solver=NewtonSolver(backend="numba"))
    with pytest.raises(ValueError, match=reasons[0] + ".*backend='numpy'"):
        numba.fit(x0, x1, mu=mu, dt=dt)
    for kernel in (Periodic(IMQ(0.3), coordinates=(0,), period=8.0), Symmetric(IMQ(0.3), group=[(1, 1), (-1, -1)])):
        parts = lower_state_kernel(kernel)
        assert not [reason for applies, reason in NUMPY_ONLY if applies(parts, Midpoint())]
        auto = SymplecticKernelPredictor(kernel, IMQ(1.5), IMQ(3.0), max_centers=10, update="midpoint",
                                         solver=NewtonSolver()).fit(x0, x1, mu=mu, dt=dt)
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
    for bad, match in [(ExactGreedy(tol=-1.0), "tol"), (ExactGreedy(criterion="x"), "criterion"),
                       (ExactGreedy(power_tol=2.0), "power_tol"), (ExactGreedy(memory_limit=0), "memory_limit"),
                       (ActiveSetGreedy(tol=float("nan")), "tol")]:
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
    split = SplitKernelPredictor(SymplecticKernelPredictor(IMQ(0.3), IMQ(1.5), IMQ(3.0), max_centers=20),
                                 QuadraticPart(np.eye(2)[None], np.zeros((1, 1)))).fit(x0, x1, mu=mu, dt=dt)
    for model in (sym, split):
        assert isinstance(model, SymplecticFlowMap) and model.dim_ == 2 and model.n_mu_ == 1
    assert isinstance(direct, FlowMap) and not isinstance(direct, SymplecticFlowMap)


@pytest.mark.parametrize("backend", ["numpy", "numba"])
def test_the_around_hook_is_the_composed_step_on_the_same_solver(small_pendulum_data, backend, monkeypatch):
    import sympredict.estimators.predictor as predictor
    from _tolerances import rollout_bound

    x0, x1, mu, dt = _data(small_pendulum_data)
    model = SymplecticKernelPredictor(IMQ(0.3), IMQ(1.5), IMQ(3.0), max_centers=40,
                                      solver=NewtonSolver(backend=backend)).fit(x0, x1, mu=mu, dt=dt)
    theta = 0.05
    rot = np.array([[np.cos(theta), np.sin(theta)], [-np.sin(theta), np.cos(theta)]])  # symplectic (det 1, 2-D)
    x = x0[:3] * 0.5
    calls = []
    real = predictor.rollout_compiled
    monkeypatch.setattr(predictor, "rollout_compiled", lambda *a, **k: calls.append(1) or real(*a, **k))
    traj = model.rollout(x, 4, mu=mu[:3], dt=dt[:3], around=(rot, rot.T))
    assert bool(calls) == (backend == "numba")  # a wrapped rollout stays on the model's solver
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


def test_an_old_option_set_as_an_attribute_lands_in_its_part():
    model = SymplecticKernelPredictor(IMQ(0.3))
    with pytest.warns(FutureWarning, match=r"set_params\(solver__backend=\.\.\.\)"):
        model.backend = "numpy"
    assert model.solver == NewtonSolver(backend="numpy") and "backend" not in model.__dict__
