"""The reductor's parts on their own: the existence check against its exact-Jacobian oracle, a samples part shared
by reductors, the default estimator spelled out."""

import numpy as np
import pytest

from sympredict.data import FlowMapData
from sympredict.mor import (
    DefaultEstimator,
    GivenTrajectories,
    ProjectedTrajectories,
    QuadraticSplit,
    SymplecticKernelReductor,
    TrainingScaling,
    ValidationSelection,
)
from sympredict.mor.existence import check_from_data
from sympredict.systems.flowmaps import LinearHamiltonianSystem, check_generating_function
from sympredict.systems.linear_flow import QuadraticPart


def _oscillators(w):
    """Uncoupled oscillators ``H = sum w_i (q_i^2 + p_i^2) / 2`` (2n = 2 len(w)), no parameter."""
    H = np.diag(np.concatenate([w, w]))
    return LinearHamiltonianSystem(lambda mu: H, 2 * len(w), 0)


@pytest.mark.parametrize("update", ["symplectic_euler", "midpoint"])
def test_existence_from_data_is_the_exact_check_on_a_linear_flow(update):
    """On samples of a linear flow the least-squares map is the flow's Jacobian: the data check finds the exact
    check's sigma_min (|cos(w dt)| type II, |cos(w dt / 2)| midpoint, of the fastest mode) and both refuse past it."""
    system = _oscillators(np.array([1.0, 0.6]))
    rng = np.random.default_rng(0)
    x0 = rng.normal(size=(40, 4))
    for dt in (0.5, 1.2):
        data = FlowMapData(x0, system.flow(x0, None, dt), None, np.full(40, dt))
        exact = check_generating_function(system, data, update=update)
        fitted = check_from_data(data, dt, update)
        assert fitted["sigma_min"] == pytest.approx(exact["sigma_min"], rel=1e-9)
        closed = abs(np.cos(dt if update == "symplectic_euler" else dt / 2))
        assert fitted["sigma_min"] == pytest.approx(closed, rel=1e-9)
    dt = 1.7  # w dt past a quarter turn: no type II form, the midpoint form still exists
    data = FlowMapData(x0, system.flow(x0, None, dt), None, np.full(40, dt))
    if update == "symplectic_euler":
        with pytest.raises(ValueError, match="dp1/dp0"):
            check_from_data(data, dt, update)
    else:
        assert check_from_data(data, dt, update)["sigma_min"] == pytest.approx(np.cos(dt / 2), rel=1e-9)


def test_existence_from_too_few_samples_is_not_done():
    system = _oscillators(np.array([1.0]))
    x0 = np.ones((1, 2))
    report = check_from_data(FlowMapData(x0, system.flow(x0, None, 0.3), None, 0.3), 0.3, "symplectic_euler")
    assert report == {"not_checked": True}


def test_one_samples_part_serves_several_reductors(small_fe):
    """A part holds settings only: the same ProjectedTrajectories / GivenTrajectories in two reductors gives each
    its own data (the second FOM's horizon and trajectories, not the first's)."""
    fom, space, train, RB = small_fe
    h = fom.T / fom.time_stepper.nt
    samples = ProjectedTrajectories(train, parameter_space=space, n_validation=1)
    nt = fom.time_stepper.nt // 2
    short = fom.with_(T=fom.T / 2, time_stepper=fom.time_stepper.with_(nt=nt), nt=nt)
    long_red = SymplecticKernelReductor(fom, RB, 4 * h, samples, check_existence=False)
    short_red = SymplecticKernelReductor(short, RB, 4 * h, samples, check_existence=False)
    n_long, n_short = len(long_red.training_data()[0]), len(short_red.training_data()[0])
    # every pair of states dt = 4 h apart: K + 1 - 4 per trajectory of K + 1 states (K = nt)
    assert n_long == 3 * (2 * nt + 1 - 4) and n_short == 3 * (nt + 1 - 4)
    U = [fom.solve(mu) for mu in train]
    given = GivenTrajectories(U, train, parameter_space=space)
    a = SymplecticKernelReductor(fom, RB, 4 * h, given, check_existence=False).training_data()[0]
    b = SymplecticKernelReductor(fom, RB, 8 * h, given, check_existence=False).training_data()[0]
    assert len(a) == 3 * (2 * nt + 1 - 4) and len(b) == 3 * (2 * nt + 1 - 8) and np.allclose(b.dt, 8 * h)


def test_given_trajectories_are_read_once(small_fe, monkeypatch):
    """The caller's trajectories (here an array of full states, copied and scanned for NaN on each read) are read
    once for the reductor's check, its validation parameters and its training data; new trajectories are read anew."""
    import sympredict.mor.samples as samples_module

    fom, space, train, RB = small_fe
    h = fom.T / fom.time_stepper.nt
    U = np.stack([fom.solve(mu).to_numpy().T for mu in train])  # (P, K + 1, N)
    reads = []
    real = samples_module._as_trajectories
    monkeypatch.setattr(samples_module, "_as_trajectories", lambda *a, **k: reads.append(a[-1]) or real(*a, **k))
    given = GivenTrajectories(U, train, validation=(U[:1], train[:1]), parameter_space=space)
    reductor = SymplecticKernelReductor(fom, RB, 4 * h, given, check_existence=False)
    reductor.validation_parameters()
    reductor.training_data()
    assert reads == ["GivenTrajectories", "GivenTrajectories validation"]
    given.set_params(U=U[::-1].copy())
    reductor.training_data()
    assert len(reads) == 4


def test_the_default_estimator_is_estimator_none(small_fe):
    fom, space, train, RB = small_fe
    h = fom.T / fom.time_stepper.nt
    samples = ProjectedTrajectories(train, parameter_space=space, n_validation=1)
    implicit = SymplecticKernelReductor(fom, RB, 4 * h, samples)
    assert implicit.estimator == DefaultEstimator() and implicit.estimator.max_centers == 1000
    a = SymplecticKernelReductor(fom, RB, 4 * h, samples, None)
    b = SymplecticKernelReductor(fom, RB, 4 * h, samples, DefaultEstimator(1000))
    a.reduce(), b.reduce()
    x = a.validation_data_.x0[:4]
    np.testing.assert_array_equal(
        a.flow_map_.step(x, mu=a.validation_data_.mu[:4]), b.flow_map_.step(x, mu=a.validation_data_.mu[:4])
    )


def test_parts_check_their_own_settings():
    with pytest.raises(ValueError, match="DefaultEstimator max_centers must be >= 1, got 0"):
        DefaultEstimator(0).check()
    with pytest.raises(
        ValueError,
        match=r"TrainingScaling state must be one of \('diag', 'uniform', 'williamson', "
        r"'none'\), got 'log'",
    ):
        TrainingScaling("log").check()
    with pytest.raises(ValueError, match="ValidationSelection regularizations must be >= 0"):
        ValidationSelection(regularizations=[1e-6, -1.0]).check()
    assert ValidationSelection(regularizations=1e-6).check().regularizations_ == [1e-6]
    A = QuadraticPart([np.eye(4)])
    with pytest.raises(ValueError, match="QuadraticSplit fallback must be True or False, got 'yes'"):
        QuadraticSplit(A, fallback="yes").check(4, 0)
    with pytest.raises(ValueError, match="depends on 1 parameter component"):
        QuadraticSplit(QuadraticPart([np.eye(4), np.eye(4)], [[0.0], [1.0]])).check(4, 0)
    assert QuadraticSplit(A).check(4, 0) == QuadraticSplit(A)
