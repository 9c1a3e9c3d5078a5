"""The reductor's estimator argument, the caller's FOM trajectories, the existence check in the trained coordinates."""

import logging
import warnings

import numpy as np
import pytest

from sympredict import SymplecticKernelPredictor
from sympredict.estimators.auto import KernelSearch
from sympredict.interpolation.greedy import ExactGreedy
from sympredict.kernels import IMQ
from sympredict.mor import (
    DefaultEstimator,
    GalerkinSamples,
    GivenSamples,
    GivenTrajectories,
    ProjectedTrajectories,
    QuadraticSplit,
    SymplecticKernelReductor,
    TrainingScaling,
)


def _small_search():
    return KernelSearch(
        families=("imq",), shapes=(0.5, 1.0), parameter_shapes=(0.5,), m_star=20, refine_sweeps=0, max_samples=200
    )


# ------------------------------------------------------------------ the estimator as one argument
def test_the_estimator_is_one_argument(small_fe):
    fom, space, train, RB = small_fe
    h = fom.T / fom.time_stepper.nt
    est = SymplecticKernelPredictor(IMQ(0.5), IMQ(0.5), max_centers=30, update="symplectic_euler")
    samples = ProjectedTrajectories(train, n_validation=1)
    # pre-release names and the settings now held by the parts are gone (no shim): a budget beside the estimator
    # cannot contradict it
    for old in (
        {"predictor": est},
        {"max_centers": 50},
        {"data": "projected"},
        {"state_kernels": [IMQ(1.0)]},
        {"split_fallback": None},
        {"trajectories": None},
        {"n_samples": 10},
    ):
        with pytest.raises(TypeError, match=f"unexpected keyword argument '{next(iter(old))}'"):
            SymplecticKernelReductor(fom, RB, 4 * h, samples, est, **old)
    with warnings.catch_warnings():
        warnings.simplefilter("error", FutureWarning)  # silent
        assert SymplecticKernelReductor(fom, RB, 4 * h, samples, estimator=est).estimator is est
    assert SymplecticKernelReductor(fom, RB, 4 * h, samples).estimator == DefaultEstimator(1000)


def test_estimator_knobs_reach_the_fit_and_its_search_choice_is_recorded(small_fe):
    """Every part of the estimator is used as given (trainer with power_tol, update, budget) and its own kernel
    search (KernelSearch, no kernels given) chooses the kernels; the reductor records what it chose."""
    fom, space, train, RB = small_fe
    h = fom.T / fom.time_stepper.nt
    est = SymplecticKernelPredictor(
        max_centers=25, update="midpoint", trainer=ExactGreedy(tol=1e-12, power_tol=1e-9), search=_small_search()
    )
    red = SymplecticKernelReductor(
        fom, RB, 4 * h, ProjectedTrajectories(train, parameter_space=space, n_validation=1), estimator=est
    )
    red.reduce()
    fitted = red.predictor_
    assert not est.is_fitted and fitted is not est
    assert fitted.update_ == "midpoint" and fitted.n_centers_ <= 25
    assert fitted.trainer.power_tol == 1e-9
    chosen = red.choice_["estimator"]
    assert set(chosen) == {"state_kernel", "mu_kernel"}  # chosen by the estimator's search, not the reductor's grid
    assert fitted.search_ is not None and fitted.search_.m_star == 20
    assert red.choice_["update"] == "midpoint"


# ------------------------------------------------------------------ the existence check in the trained coordinates
def sheared_oscillators(c=-2.0, w=(1.0, 0.7)):
    """Two oscillators of frequencies ``w`` seen through the symplectic shear ``p -> p + c q``: ``H = S^-T W S^-1``.

    In these coordinates ``dp1/dp0 = cos(w t) + c sin(w t)``: singular at ``tan(w t) = -1/c`` (``w t = 0.464`` for
    ``c = -2``), long before a quarter turn; the Williamson coordinates undo the shear (``dp1/dp0 = cos(w t)``).
    The basis is the identity (2n = 2N = 4), so the reduced coordinates are these.
    """
    from pymor.algorithms.symplectic import SymplecticBasis
    from pymor.models.symplectic import QuadraticHamiltonianModel
    from pymor.operators.numpy import NumpyMatrixOperator

    n = len(w)
    S = np.block([[np.eye(n), np.zeros((n, n))], [c * np.eye(n), np.eye(n)]])
    Si = np.linalg.inv(S)
    H = Si.T @ np.diag(np.concatenate([w, w])) @ Si
    op = NumpyMatrixOperator(0.5 * (H + H.T))
    fom = QuadraticHamiltonianModel(10.0, op.source.from_numpy(np.array([[1.0], [0.5], [0.0], [0.2]])), op, nt=100)
    space = fom.solution_space
    RB = SymplecticBasis(space.from_numpy(np.eye(2 * n)[:, :n]), space.from_numpy(np.eye(2 * n)[:, n:]), space)
    return fom, RB


def _type2(scaling, dt):
    fom, RB = sheared_oscillators()
    red = SymplecticKernelReductor(
        fom,
        RB,
        dt,
        GalerkinSamples(n_samples=40, n_validation=1),
        SymplecticKernelPredictor(update="symplectic_euler"),
        scaling=TrainingScaling(scaling),
    )
    red.training_data()
    return red


def test_williamson_scaling_checks_existence_where_it_trains():
    # trained in Williamson coordinates the type II form exists at w dt = 0.8 (it was refused from the sheared ones)
    red = _type2("williamson", 0.8)
    assert red.existence_["sigma_min"] == pytest.approx(np.cos(0.8), rel=1e-8)  # the fastest mode, cos(w dt)
    assert red.existence_["dt_max"] == pytest.approx(np.arccos(1e-2), rel=0.01)  # sigma = 1e-2 of the fastest mode
    assert "williamson" in red.existence_["coordinates"]
    # trained in the sheared coordinates themselves it does not exist: refused
    with pytest.raises(ValueError, match=r"past the first step where it is singular"):
        _type2("none", 0.8)
    # past a quarter turn it does not exist in any coordinates: still refused in the Williamson ones
    with pytest.raises(ValueError, match=r"dp1/dp0.*largest admissible dT here is about 1\.5"):
        _type2("williamson", 1.7)


def test_conjugated_system_has_the_conjugated_flow_jacobian():
    from sympredict.mor.existence import conjugated_system as _conjugated_system
    from sympredict.symplectic.metrics import canonical_J
    from sympredict.systems.flowmaps import linear_system_from_pymor

    fom, RB = sheared_oscillators()
    system = linear_system_from_pymor(fom)
    J = canonical_J(4)
    M = 1.7 * np.array([[2.0, 0, 0.3, 0], [0, 0.5, 0, 0], [0, 0, 0.5, 0], [0, 0, 0, 2.0]])
    M[:, 2] += 0.3 * M[:, 0]  # a shear: M^T J M = 1.7^2 J still
    assert np.abs(M.T @ J @ M - 1.7**2 * J).max() < 1e-12
    x = np.ones((1, 4))
    D = system.flow_jacobian(x, None, 0.9)[0]
    D_scaled = _conjugated_system(system, M).flow_jacobian(x, None, 0.9)[0]
    np.testing.assert_allclose(D_scaled, M @ D @ np.linalg.inv(M), rtol=0, atol=1e-12)


# ------------------------------------------------------------------ the caller's FOM trajectories
def test_given_trajectories_give_the_rom_of_the_fom_solving_path(small_fe, monkeypatch):
    fom, space, train, RB = small_fe
    dt = 4 * fom.T / fom.time_stepper.nt
    solved = SymplecticKernelReductor(
        fom,
        RB,
        dt,
        ProjectedTrajectories(train, parameter_space=space, n_validation=1),
        DefaultEstimator(max_centers=60),
    )
    rom = solved.reduce()
    val_mus = solved.validation_parameters()
    U = [fom.solve(mu) for mu in train]
    U_val = [fom.solve(mu) for mu in val_mus]
    test_mu = fom.parameters.parse(0.93)
    ref = rom.solve(test_mu).to_numpy()
    monkeypatch.setattr(type(fom), "solve", lambda *a, **k: (_ for _ in ()).throw(AssertionError("FOM solved")))
    arrays = np.stack([u.to_numpy().T for u in U])  # (P, K+1, N)
    for trajectories in ((U, train), (arrays, [{"c": float(m["c"][0])} for m in train])):
        given = SymplecticKernelReductor(
            fom,
            RB,
            dt,
            GivenTrajectories(*trajectories, validation=(U_val, val_mus), parameter_space=space),
            DefaultEstimator(max_centers=60),
        )
        out = given.reduce().solve(test_mu).to_numpy()
        assert len(given.train_data_) == len(solved.train_data_)
        np.testing.assert_allclose(out, ref, rtol=0, atol=1e-12 * np.abs(ref).max())
    # without validation trajectories an estimator that holds out its own samples still trains
    SymplecticKernelReductor(
        fom,
        RB,
        dt,
        GivenTrajectories(U, train, parameter_space=space),
        estimator=SymplecticKernelPredictor(max_centers=20, update="symplectic_euler", search=_small_search()),
    ).reduce()


def test_given_trajectories_are_checked(small_fe):
    from pymor.vectorarrays.numpy import NumpyVectorSpace

    fom, space, train, RB = small_fe
    dt = 4 * fom.T / fom.time_stepper.nt
    U = [fom.solve(mu) for mu in train]
    arrays = np.stack([u.to_numpy().T for u in U])
    cases = [
        ((arrays[:, :, :-1], train), r"shape \(P, K\+1, N\).*N = 30"),
        ((np.where(np.arange(30) == 3, np.nan, arrays), train), "finite"),
        (([U[0], U[1][:50]], train[:2]), "same number K \\+ 1"),
        ((U, train[:2]), "one parameter value per trajectory \\(3\\)"),
        ((U, [0.9, 1.0, "x"]), "cannot read 'x'"),
        (([u[::3] for u in U], train), "nt = 100 steps, not a multiple of 33"),
        (([NumpyVectorSpace(30).zeros(101)], train[:1]), r"solution space .*entry 0 is a NumpyVectorArray"),
    ]
    for trajectories, match in cases:
        with pytest.raises(ValueError, match=match):
            SymplecticKernelReductor(fom, RB, dt, GivenTrajectories(*trajectories))
        with pytest.raises(ValueError, match=match):  # the validation trajectories are checked alike
            SymplecticKernelReductor(fom, RB, dt, GivenTrajectories(U, train, validation=trajectories))
    with pytest.raises(ValueError, match="validation must be a pair \\(U, mus\\)"):
        SymplecticKernelReductor(fom, RB, dt, GivenTrajectories(U, train, validation=(U,)))
    with pytest.raises(ValueError, match="multiple of the FOM's output step"):
        SymplecticKernelReductor(fom, RB, 1.5 * fom.T / fom.time_stepper.nt, GivenTrajectories(U, train))
    with pytest.raises(ValueError, match="needs validation data: give .*GivenTrajectories\\(U, mus, validation="):
        SymplecticKernelReductor(fom, RB, dt, GivenTrajectories(U, train), DefaultEstimator(max_centers=20)).reduce()


# ------------------------------------------------------------------ log messages
def test_existence_check_that_could_not_run_says_so(small_fe, caplog):
    """Given samples too few per parameter to fit a linear map: the log and choice_ say the check was not done (it
    used to record 'type II generating function exists at dt')."""
    from sympredict.data import FlowMapData

    fom, space, train, RB = small_fe
    dt = 4 * fom.T / fom.time_stepper.nt
    full = SymplecticKernelReductor(fom, RB, dt, ProjectedTrajectories(train, n_validation=1), check_existence=False)
    pairs = full.training_data()[0]
    rows = np.concatenate([np.flatnonzero(pairs.mu[:, 0] == m)[:5] for m in np.unique(pairs.mu[:, 0])])  # 5 < 2n = 8
    few = FlowMapData(pairs.x0[rows], pairs.x1[rows], pairs.mu[rows], pairs.dt[rows])
    red = SymplecticKernelReductor(fom, RB, dt, GivenSamples(few, parameter_space=space))
    with caplog.at_level(logging.WARNING):
        red.training_data()
    assert "existence check not done" in caplog.text
    assert red.choice_["reason"].startswith("not checked") and red.existence_["not_checked"]


# ------------------------------------------------------------------ the exact linear flow split off as a fallback
def test_split_fallback_where_no_generating_function_exists_without_it():
    """Past half a turn per step (w dt = 3.5) neither form exists; with the quadratic part known (here the whole
    reduced Hamiltonian, so S is the identity) the reductor splits its exact flow off and the ROM's step is the
    exact propagator.  A quadratic part that leaves S turning past half a turn is still refused."""
    from scipy.linalg import expm

    from sympredict.symplectic.metrics import canonical_J
    from sympredict.systems.flowmaps import linear_system_from_pymor
    from sympredict.systems.linear_flow import QuadraticPart

    fom, RB = sheared_oscillators()
    H = linear_system_from_pymor(fom).matrix(np.zeros(0))
    dt = 3.5
    est = SymplecticKernelPredictor(IMQ(1.0), max_centers=10, update="symplectic_euler")
    samples = GalerkinSamples(n_samples=40, n_validation=1)
    kw = dict(scaling=TrainingScaling("none"))
    with pytest.raises(ValueError, match="dp1/dp0"):
        SymplecticKernelReductor(fom, RB, dt, samples, est, **kw).training_data()
    with pytest.raises(ValueError, match="neither generating function exists"):
        SymplecticKernelReductor(fom, RB, dt, samples, **kw).training_data()
    red = SymplecticKernelReductor(
        fom, RB, dt, samples, est, split=QuadraticSplit(QuadraticPart([H]), fallback=True), **kw
    )
    rom = red.reduce()
    assert red.choice_["split"] == "split_fallback" and "without a split" in red.choice_["reason"]
    assert type(red.predictor_).__name__ == "SplitKernelPredictor"
    x = red.train_data_.x0[:5]
    exact = x @ expm(dt * canonical_J(4) @ H).T
    np.testing.assert_allclose(red.flow_map_.step(x, dt=dt), exact, rtol=0, atol=1e-10 * np.abs(exact).max())
    assert len(rom.solve()) == round(fom.T / dt) + 1
    with pytest.raises(ValueError, match="nor for the remainder S"):
        SymplecticKernelReductor(
            fom, RB, dt, samples, est, split=QuadraticSplit(QuadraticPart([0.05 * H]), fallback=True), **kw
        ).training_data()
    with pytest.raises(ValueError, match="check_existence=False never checks"):  # a fallback decided by no check
        SymplecticKernelReductor(
            fom,
            RB,
            dt,
            samples,
            est,
            split=QuadraticSplit(QuadraticPart([H]), fallback=True),
            check_existence=False,
            **kw,
        )
