"""The reductor's estimator argument, the caller's FOM trajectories, the existence check in the trained coordinates."""

import warnings

import pytest

from sympredict import SymplecticKernelPredictor
from sympredict.estimators.auto import KernelSearch
from sympredict.interpolation.greedy import ExactGreedy
from sympredict.kernels import IMQ
from sympredict.mor import SymplecticKernelReductor
from sympredict.mor.basis import complex_svd_basis
from sympredict.testing import fe_wave_model


@pytest.fixture(scope="module")
def small_fe():
    """A small FE wave model (2N = 30), its training speeds and a 2n = 8 basis of their trajectories."""
    fom, coords, space = fe_wave_model(n_elements=16, T=0.5, nt=100)
    train = space.sample_uniformly(3)
    S = fom.solution_space.empty()
    for mu in train:
        S.append(fom.solve(mu))
    RB = complex_svd_basis(S, n=4).to_pymor(fom.solution_space)
    return fom, space, train, RB


def _small_search():
    return KernelSearch(families=("imq",), shapes=(0.5, 1.0), parameter_shapes=(0.5,), m_star=20, refine_sweeps=0,
                        max_samples=200)


# ------------------------------------------------------------------ the estimator as one argument
def test_predictor_keyword_warns_and_means_estimator(small_fe):
    fom, space, train, RB = small_fe
    h = fom.T / fom.time_stepper.nt
    est = SymplecticKernelPredictor(IMQ(0.5), IMQ(0.5), max_centers=30, update="symplectic_euler")
    with pytest.warns(FutureWarning, match=r"estimator="):
        old = SymplecticKernelReductor(fom, RB, train, 4 * h, data="projected", predictor=est, n_validation=1)
    assert old.estimator is est
    with pytest.raises(ValueError, match="not both"):
        SymplecticKernelReductor(fom, RB, train, 4 * h, est, data="projected", predictor=est)
    with pytest.raises(ValueError, match=r"max_centers=50.*SymplecticKernelPredictor\(max_centers=50"):
        SymplecticKernelReductor(fom, RB, train, 4 * h, est, data="projected", max_centers=50)
    with warnings.catch_warnings():
        warnings.simplefilter("error", FutureWarning)  # the new spelling is silent
        SymplecticKernelReductor(fom, RB, train, 4 * h, data="projected", estimator=est, n_validation=1)


def test_estimator_knobs_reach_the_fit_and_its_search_choice_is_recorded(small_fe):
    """Every part of the estimator is used as given (trainer with power_tol, update, budget) and its own kernel
    search (KernelSearch, no kernels given) chooses the kernels; the reductor records what it chose."""
    fom, space, train, RB = small_fe
    h = fom.T / fom.time_stepper.nt
    est = SymplecticKernelPredictor(max_centers=25, update="midpoint", trainer=ExactGreedy(tol=1e-12, power_tol=1e-9),
                                    search=_small_search())
    red = SymplecticKernelReductor(fom, RB, train, 4 * h, estimator=est, data="projected", parameter_space=space,
                                   n_validation=1)
    red.reduce()
    fitted = red.predictor_
    assert not est.is_fitted and fitted is not est
    assert fitted.update_ == "midpoint" and fitted.n_centers_ <= 25
    assert fitted.trainer.power_tol == 1e-9
    chosen = red.choice_["estimator"]
    assert set(chosen) == {"state_kernel", "mu_kernel"}  # chosen by the estimator's search, not the reductor's grid
    assert fitted.search_ is not None and fitted.search_.m_star == 20
    assert red.choice_["update"] == "midpoint"
