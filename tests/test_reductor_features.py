"""SymplecticKernelReductor features: the caller's data, scaling choices, kernel search with a given predictor.

Oracles: agreement with the code paths they replace (the reductor's own sampling, a hand-made
``select_kernels`` + ``fit``), ``V^T J V = J`` of the basis, ``DPhi^T J DPhi = J`` of the learned step.
"""

import numpy as np
import pytest
from pymor.core.logger import set_log_levels

from sympredict import SymplecticKernelPredictor
from sympredict.data import FlowMapData
from sympredict.estimators.selection import select_kernels
from sympredict.interpolation.greedy import ExactGreedy
from sympredict.kernels import IMQ, Matern52
from sympredict.kernels.transforms import Scaled
from sympredict.mor import SymplecticKernelReductor
from sympredict.mor.basis import SymplecticROM, complex_svd_basis, symplecticity_of_basis
from sympredict.systems.flowmaps import flow_map_data, sample_energy_ellipsoid
from sympredict.systems.wave import WaveFOM
from sympredict.testing import assert_symplectic_step

set_log_levels({"pymor": "ERROR", "sympredict": "WARNING"})


@pytest.fixture(scope="module")
def wave_rom():
    """sympredict's wave FOM (N = 40), a 2n = 4 basis from two-mode states, its Galerkin ROM and energy-ellipsoid
    samples at three speeds (training) and two others (validation), dt = 0.1."""
    fom = WaveFOM(n_points=40, T=1.0)
    energy = fom.reference_energy(0.09)
    snaps = fom.trajectory(fom.low_frequency_states(4, 2, 0.09, energy, seed=0), 0.09, 0.05, 20).reshape(-1, fom.dim)
    rom = SymplecticROM(fom, complex_svd_basis(snaps, n=2, layout="rows"))

    def samples(speeds, n, seed):
        parts = []
        for i, c in enumerate(speeds):
            x0 = sample_energy_ellipsoid(rom.system, n, c**2, energy, np.random.default_rng(seed + i))
            parts.append(flow_map_data(rom.system, x0, np.full((n, 1), c**2), 0.1))
        out = parts[0]
        for p in parts[1:]:
            out = out.concatenate(p)
        return out

    return fom, rom, samples((0.2, 0.25, 0.3), 120, 1), samples((0.22, 0.28), 40, 50)


def given(rom, train, val, predictor, **kw):
    return SymplecticKernelReductor(rom.model, rom.RB, None, 0.1, predictor, data=train, validation_data=val, **kw)


def test_the_basis_handed_over_is_symplectic_and_the_reductors_own(wave_rom):
    fom, rom, train, val = wave_rom
    assert symplecticity_of_basis(rom.RB) < 1e-14  # V^T J V = J
    red = given(rom, train, val, SymplecticKernelPredictor(IMQ(1e-2), IMQ(10.0), max_centers=30))
    np.testing.assert_array_equal(red.V, rom.V)  # the same basis, no arithmetic on the way
    # training parameters default to those of the samples
    assert sorted(float(m["mu"][0]) for m in red.training_parameters) == pytest.approx([0.04, 0.0625, 0.09])


def test_unscaled_kernel_search_is_the_hand_made_selection_and_fit(wave_rom):
    """No scaling and kernel candidates: the reductor's model is the one select_kernels + fit gave by hand."""
    fom, rom, train, val = wave_rom
    states, mus = [IMQ(3e-3), IMQ(1e-2), Matern52(1e-2)], [IMQ(3.0), IMQ(10.0)]
    red = given(rom, train, val, SymplecticKernelPredictor(max_centers=60, trainer=ExactGreedy(tol=1e-10)),
                state_scaling="none", parameter_scaling="none", time_scaling="none", state_kernels=states,
                mu_kernels=mus, m_star=25)
    kernel_rom = red.reduce()
    sel = select_kernels(train, val, states, mus, m_star=25)
    assert (red.selection_.state, red.selection_.mu, red.selection_.score) == (sel.state, sel.mu, sel.score)
    by_hand = SymplecticKernelPredictor(sel.state, sel.mu, None, max_centers=60, trainer=ExactGreedy(tol=1e-10))
    by_hand.fit(train.x0, train.x1, mu=train.mu, dt=0.1, validation=val)
    model = red.predictor_
    assert model.n_centers_ == by_hand.n_centers_
    np.testing.assert_array_equal(model.history_.val_max_residual, by_hand.history_.val_max_residual)
    x0, mu = val.x0[:6], val.mu[:6]
    np.testing.assert_array_equal(red.flow_map_.rollout(x0, 5, mu=mu), by_hand.rollout(x0, 5, mu=mu))
    # the scalings are identities: the ROM's flow map is the predictor in the caller's units
    np.testing.assert_array_equal(red.flow_map_.state_scaling.matrix_, np.eye(4))
    assert red.flow_map_.tau == 1.0 and red.flow_map_.mu_scaling.transform(np.array([[0.07]]))[0, 0] == 0.07
    assert set(red.timings_) == {"data", "selection", "fit"} and red.existence_["sigma_min"] > 0.9
    U = kernel_rom.solve(0.0625)
    assert len(U) == round(fom.model.T / 0.1) + 1 and np.all(np.isfinite(U.to_numpy()))


def test_given_data_reproduce_the_reductors_own_sampling(wave_rom):
    """data='reduced' and the same samples handed in as data=FlowMapData give the same model."""
    fom, rom, _, _ = wave_rom
    mus = [fom.model.parameters.parse(c**2) for c in (0.2, 0.3)]
    predictor = SymplecticKernelPredictor(IMQ(0.3), IMQ(1.0), max_centers=40)
    own = SymplecticKernelReductor(fom.model, rom.RB, mus, 0.1, predictor, n_samples=60, n_validation=2)
    own.reduce()
    train, val = own.train_data_, own.validation_data_
    handed = SymplecticKernelReductor(fom.model, rom.RB, mus, 0.1, predictor, data=train, validation_data=val,
                                      parameter_space=fom.model.parameters.space(0.04, 0.09))
    handed.reduce()
    x = val.x0[:5]
    np.testing.assert_allclose(handed.flow_map_.step(x, mu=val.mu[:5]), own.flow_map_.step(x, mu=val.mu[:5]),
                               rtol=0, atol=1e-13 * np.abs(x).max())
    assert handed.predictor_.n_centers_ == own.predictor_.n_centers_


@pytest.mark.parametrize("scaling", [("diag", "box", "step"), ("none", "none", "none"), ("uniform", "box", "none")])
def test_the_learned_step_is_symplectic_under_every_scaling(wave_rom, scaling):
    fom, rom, train, val = wave_rom
    state, param, time = scaling
    red = given(rom, train, val, SymplecticKernelPredictor(max_centers=60, trainer=ExactGreedy(tol=1e-10)),
                state_scaling=state, parameter_scaling=param, time_scaling=time,
                state_kernels=[IMQ(3e-3), IMQ(1e-2), IMQ(0.1), IMQ(0.3)], mu_kernels=[IMQ(1.0), IMQ(10.0)], m_star=30)
    red.reduce()
    res = assert_symplectic_step(red.flow_map_, val.x0[:4], mu=val.mu[:4], dt=0.1, atol=1e-8, fd_h=1e-3, fd_atol=1e-3)
    assert res["analytic"] < 1e-8  # DPhi^T J DPhi = J


def test_kernel_search_keeps_the_given_predictors_parts(wave_rom):
    fom, rom, train, val = wave_rom
    template = SymplecticKernelPredictor(Scaled(IMQ(1.0), factors=(2.0, 0.5)), IMQ(1.0), update="midpoint", max_centers=40,
                                         trainer=ExactGreedy(tol=1e-9))
    red = given(rom, train, val, template, state_kernels=[IMQ(0.03), IMQ(0.3)], m_star=20)
    red.reduce()
    chosen = red.predictor_
    assert template.get_params()["state_kernel"] == Scaled(IMQ(1.0), factors=(2.0, 0.5)) and not template.is_fitted
    assert isinstance(chosen.state_kernel, Scaled) and tuple(chosen.state_kernel.factors) == (2.0, 0.5)  # the candidate went inside
    # among the candidates, or one grid step beyond an edge (select_kernels widens the grid there)
    assert chosen.state_kernel.radial == red.selection_.state and red.selection_.state in [IMQ(3e-3), IMQ(0.03), IMQ(0.3),
                                                                                         IMQ(3.0)]
    assert chosen.mu_kernel == IMQ(1.0) and chosen.update == "midpoint" and chosen.trainer.tol == 1e-9
    assert {row["mu"]["eps"] for row in red.selection_.table} == {1.0}  # only the state kernel was searched
    # a given predictor without candidates is trained as given: no search
    plain = given(rom, train, val, template)
    plain.reduce()
    assert not hasattr(plain, "selection_") and plain.predictor_.state_kernel == template.state_kernel


def test_given_data_and_scaling_settings_are_checked(wave_rom):
    fom, rom, train, val = wave_rom
    p = SymplecticKernelPredictor(IMQ(0.1), IMQ(1.0), max_centers=20)
    with pytest.raises(ValueError, match="validation_data goes with the caller's data"):
        SymplecticKernelReductor(fom.model, rom.RB, None, 0.1, p, validation_data=val)
    with pytest.raises(ValueError, match="data must be 'reduced', 'projected' or a FlowMapData"):
        SymplecticKernelReductor(fom.model, rom.RB, None, 0.1, p, data=(train.x0, train.x1))
    with pytest.raises(ValueError, match="dimension 6, the basis has 2n = 4"):
        given(rom, FlowMapData(np.ones((3, 6)), np.ones((3, 6)), np.ones((3, 1)), 0.1), None, p)
    with pytest.raises(ValueError, match="parameter vectors of dimension 2"):
        given(rom, FlowMapData(train.x0, train.x1, np.ones((len(train), 2)), 0.1), None, p)
    with pytest.raises(ValueError, match="validation_data has steps .* dt is 0.1"):
        given(rom, train, FlowMapData(val.x0, val.x1, val.mu, 0.2), p)
    with pytest.raises(ValueError, match="parameter_scaling must be one of"):
        given(rom, train, val, p, parameter_scaling="unit")
    with pytest.raises(ValueError, match="time_scaling must be one of"):
        given(rom, train, val, p, time_scaling=1.0)
    with pytest.raises(ValueError, match="state_kernels must be a sequence"):
        given(rom, train, val, p, state_kernels=IMQ(0.1))
    with pytest.raises(ValueError, match="non-empty sequence of radial kernels"):
        given(rom, train, val, p, mu_kernels=["imq"])
    with pytest.raises(ValueError, match="m_star"):
        given(rom, train, val, p, m_star=0)
    with pytest.raises(ValueError, match="needs validation data"):
        given(rom, train, None, p, state_kernels=[IMQ(0.1)]).reduce()
    with pytest.raises(ValueError, match="needs validation data"):
        given(rom, train, None, None).reduce()  # the default predictor chooses its kernels
