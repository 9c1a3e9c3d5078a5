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
from sympredict.flowmap.scaling import SymplecticScaling
from sympredict.mor import (
    GalerkinSamples,
    GivenSamples,
    QuadraticSplit,
    SymplecticKernelReductor,
    TrainingScaling,
    ValidationSelection,
)
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
    return SymplecticKernelReductor(rom.model, rom.RB, 0.1, GivenSamples(train, val), predictor, **kw)


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
    red = given(
        rom,
        train,
        val,
        SymplecticKernelPredictor(max_centers=60, trainer=ExactGreedy(tol=1e-10)),
        scaling=TrainingScaling("none", "none", "none"),
        selection=ValidationSelection(state_kernels=states, mu_kernels=mus, m_star=25),
    )
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
    """GalerkinSamples and the same samples handed in as GivenSamples give the same model."""
    fom, rom, _, _ = wave_rom
    mus = [fom.model.parameters.parse(c**2) for c in (0.2, 0.3)]
    predictor = SymplecticKernelPredictor(IMQ(0.3), IMQ(1.0), max_centers=40)
    own = SymplecticKernelReductor(
        fom.model, rom.RB, 0.1, GalerkinSamples(mus, n_samples=60, n_validation=2), predictor
    )
    own.reduce()
    train, val = own.train_data_, own.validation_data_
    handed = SymplecticKernelReductor(
        fom.model,
        rom.RB,
        0.1,
        GivenSamples(train, val, parameter_space=fom.model.parameters.space(0.04, 0.09)),
        predictor,
    )
    handed.reduce()
    x = val.x0[:5]
    np.testing.assert_allclose(
        handed.flow_map_.step(x, mu=val.mu[:5]),
        own.flow_map_.step(x, mu=val.mu[:5]),
        rtol=0,
        atol=1e-13 * np.abs(x).max(),
    )
    assert handed.predictor_.n_centers_ == own.predictor_.n_centers_


@pytest.mark.parametrize("scaling", [("diag", "box", "step"), ("none", "none", "none"), ("uniform", "box", "none")])
def test_the_learned_step_is_symplectic_under_every_scaling(wave_rom, scaling):
    fom, rom, train, val = wave_rom
    state, param, time = scaling
    red = given(
        rom,
        train,
        val,
        SymplecticKernelPredictor(max_centers=60, trainer=ExactGreedy(tol=1e-10)),
        scaling=TrainingScaling(state, param, time),
        selection=ValidationSelection([IMQ(3e-3), IMQ(1e-2), IMQ(0.1), IMQ(0.3)], [IMQ(1.0), IMQ(10.0)], m_star=30),
    )
    red.reduce()
    res = assert_symplectic_step(red.flow_map_, val.x0[:4], mu=val.mu[:4], dt=0.1, atol=1e-8, fd_h=1e-3, fd_atol=1e-3)
    assert res["analytic"] < 1e-8  # DPhi^T J DPhi = J


def test_kernel_search_keeps_the_given_predictors_parts(wave_rom):
    fom, rom, train, val = wave_rom
    template = SymplecticKernelPredictor(
        Scaled(IMQ(1.0), factors=(2.0, 0.5)), IMQ(1.0), update="midpoint", max_centers=40, trainer=ExactGreedy(tol=1e-9)
    )
    red = given(rom, train, val, template, selection=ValidationSelection([IMQ(0.03), IMQ(0.3)], m_star=20))
    red.reduce()
    chosen = red.predictor_
    assert template.get_params()["state_kernel"] == Scaled(IMQ(1.0), factors=(2.0, 0.5)) and not template.is_fitted
    assert isinstance(chosen.state_kernel, Scaled) and tuple(chosen.state_kernel.factors) == (
        2.0,
        0.5,
    )  # the candidate went inside
    # among the candidates, or one grid step beyond an edge (select_kernels widens the grid there)
    assert chosen.state_kernel.radial == red.selection_.state and red.selection_.state in [
        IMQ(3e-3),
        IMQ(0.03),
        IMQ(0.3),
        IMQ(3.0),
    ]
    assert chosen.mu_kernel == IMQ(1.0) and chosen.update == "midpoint" and chosen.trainer.tol == 1e-9
    assert {row["mu"]["eps"] for row in red.selection_.table} == {1.0}  # only the state kernel was searched
    # a given predictor without candidates is trained as given: no search
    plain = given(rom, train, val, template)
    plain.reduce()
    assert not hasattr(plain, "selection_") and plain.predictor_.state_kernel == template.state_kernel


def test_given_data_and_scaling_settings_are_checked(wave_rom):
    fom, rom, train, val = wave_rom
    p = SymplecticKernelPredictor(IMQ(0.1), IMQ(1.0), max_centers=20)
    with pytest.raises(ValueError, match="GivenSamples: data must be a sympredict.data.FlowMapData"):
        SymplecticKernelReductor(fom.model, rom.RB, 0.1, GivenSamples((train.x0, train.x1)), p)
    with pytest.raises(ValueError, match="dimension 6, the basis has 2n = 4"):
        given(rom, FlowMapData(np.ones((3, 6)), np.ones((3, 6)), np.ones((3, 1)), 0.1), None, p)
    with pytest.raises(ValueError, match="parameter vectors of dimension 2"):
        given(rom, FlowMapData(train.x0, train.x1, np.ones((len(train), 2)), 0.1), None, p)
    with pytest.raises(ValueError, match="validation has steps .* dt is 0.1"):
        given(rom, train, FlowMapData(val.x0, val.x1, val.mu, 0.2), p)
    with pytest.raises(ValueError, match="TrainingScaling parameters must be one of"):
        given(rom, train, val, p, scaling=TrainingScaling(parameters="unit"))
    with pytest.raises(ValueError, match="TrainingScaling time must be one of"):
        given(rom, train, val, p, scaling=TrainingScaling(time=1.0))
    with pytest.raises(ValueError, match="scaling must be a TrainingScaling"):
        given(rom, train, val, p, scaling="none")
    with pytest.raises(ValueError, match="state_kernels must be a sequence"):
        given(rom, train, val, p, selection=ValidationSelection(state_kernels=IMQ(0.1)))
    with pytest.raises(ValueError, match="non-empty sequence of radial kernels"):
        given(rom, train, val, p, selection=ValidationSelection(mu_kernels=["imq"]))
    with pytest.raises(ValueError, match="m_star"):
        given(rom, train, val, p, selection=ValidationSelection(m_star=0))
    with pytest.raises(ValueError, match="selection must be a ValidationSelection"):
        given(rom, train, val, p, selection=[IMQ(0.1)])
    with pytest.raises(ValueError, match="needs validation data"):
        given(rom, train, None, p, selection=ValidationSelection(state_kernels=[IMQ(0.1)])).reduce()
    with pytest.raises(ValueError, match="needs validation data"):
        given(rom, train, None, None).reduce()  # the default predictor chooses its kernels


# ---------------------------------------------------------------- flow parameters, regularization, split
@pytest.fixture(scope="module")
def sine_gordon(small_sine_gordon):
    """The small sine-Gordon case (conftest): its pyMOR model, basis and projected trajectories (4, 21, 6) at c."""
    from sympredict.mor.basis import pymor_basis

    fom, gal, X, c = small_sine_gordon
    return fom, gal, pymor_basis(gal.V, fom.phase_space), gal.project(X), c


def sg_reductor(sine_gordon, pairs, predictor, validation=None, **kw):
    fom, gal, RB, Y, c = sine_gordon
    space = fom.model.parameters.space({"amplitude": (0.5, 1.5), "c": (0.8, 1.2)})
    return SymplecticKernelReductor(
        fom.model,
        RB,
        0.1,
        GivenSamples(pairs, validation, parameter_space=space),
        predictor,
        flow_parameters=("c",),
        **kw,
    )


def trajectory_pairs_of(Y, c):
    return FlowMapData(
        Y[:, :-1].reshape(-1, Y.shape[-1]),
        Y[:, 1:].reshape(-1, Y.shape[-1]),
        np.repeat(c, Y.shape[1] - 1)[:, None],
        0.1,
    )


def test_trajectory_data_pairs_are_the_consecutive_states():
    from sympredict.data import TrajectoryData

    Y = np.arange(2 * 4 * 2, dtype=float).reshape(2, 4, 2)
    t = TrajectoryData(Y, [0.5, 0.7], 0.2)
    d = t.pairs()
    assert len(t) == 2 and t.mu.shape == (2, 1) and len(d) == 6
    np.testing.assert_array_equal(d.x0[3], Y[1, 0]) and np.testing.assert_array_equal(d.x1[3], Y[1, 1])
    np.testing.assert_array_equal(d.mu[:, 0], [0.5] * 3 + [0.7] * 3)
    with pytest.raises(ValueError, match=r"\(P, K\+1, 2n\)"):
        TrajectoryData(Y[:, :1], [0.5, 0.7], 0.2)


@pytest.mark.filterwarnings("ignore::sympredict.exceptions.ExtrapolationWarning")  # the rollout nears the data's edge
def test_flow_parameters_leave_out_the_initial_datas_parameters(sine_gordon):
    fom, gal, RB, Y, c = sine_gordon
    p = SymplecticKernelPredictor(IMQ(0.3), IMQ(1.0), max_centers=60)
    red = sg_reductor(sine_gordon, trajectory_pairs_of(Y, c), p)
    rom = red.reduce()
    assert red.flow_map_.n_mu_ == 1 and red.flow_parameters == {"c": 1}
    assert red.flow_lo.tolist() == [0.8] and red.flow_hi.tolist() == [1.2]  # c's part of the box
    # the ROM takes the FOM's parameters; its flow map sees c alone
    mu = fom.model.parameters.parse({"amplitude": 1.5, "c": 1.2})
    U = rom.solve(mu).to_numpy().T
    np.testing.assert_allclose(U, red.flow_map_.rollout(U[:1], len(U) - 1, mu=[[1.2]], dt=0.1)[0], rtol=0, atol=1e-12)
    # near the projected FOM trajectory it was trained on (initial data at amplitude 1.5, c = 1.2)
    assert np.abs(U - Y[3]).max() < 0.1 * np.abs(Y[3]).max()
    assert_symplectic_step(red.flow_map_, Y[3, 3:5], mu=[[1.2]], dt=0.1, atol=1e-8, fd_h=1e-3, fd_atol=1e-3)
    with pytest.raises(ValueError, match=r"depends on \['c'\].*leaves out \['c'\]"):
        SymplecticKernelReductor(
            fom.model, RB, 0.1, GivenSamples(trajectory_pairs_of(Y, c)), p, flow_parameters=("amplitude",)
        )
    with pytest.raises(ValueError, match="not parameters of the FOM"):
        SymplecticKernelReductor(fom.model, RB, 0.1, GivenSamples(trajectory_pairs_of(Y, c)), p, flow_parameters=("k",))
    with pytest.raises(
        ValueError, match="parameter vectors of dimension 1, the flow map's parameters have dimension 2"
    ):
        SymplecticKernelReductor(fom.model, RB, 0.1, GivenSamples(trajectory_pairs_of(Y, c)), p)


def hand_made_flow(pairs, lam, dt=0.1, quadratic=None, validation=None):
    """The fit the sine-Gordon experiment composed by hand before it used the reductor (one candidate);
    ``validation``: the validation pairs the reductor hands to the fit (its hold-out for the kernel search)."""
    from sympredict.flowmap.scaling import BoxScaling, NormalizedFlowMap, SymplecticScaling, scaled_quadratic_part
    from sympredict.flowmap.splitting import SplitKernelPredictor

    st = SymplecticScaling("diag").fit(np.concatenate([pairs.x0, pairs.x1]))
    ms = BoxScaling().fit(pairs.mu, np.array([0.8]), np.array([1.2]))
    model = SymplecticKernelPredictor(
        None, mu_kernel=IMQ(1.0), max_centers=50, trainer=ExactGreedy(tol=1e-9, regularization=lam)
    )
    if quadratic is not None:
        model = SplitKernelPredictor(model, scaled_quadratic_part(quadratic, st, ms, dt))
    val = (
        None
        if validation is None
        else (
            st.transform(validation.x0),
            st.transform(validation.x1),
            ms.transform(validation.mu),
            np.ones(len(validation)),
        )
    )
    model.fit(st.transform(pairs.x0), st.transform(pairs.x1), mu=ms.transform(pairs.mu), dt=1.0, validation=val)
    return NormalizedFlowMap(model, st, ms, dt)


@pytest.mark.filterwarnings("ignore::sympredict.exceptions.ExtrapolationWarning")
def test_regularization_chosen_by_rollouts_on_validation_trajectories(sine_gordon):
    """regularizations + TrajectoryData: the table and the choice of the hand-made held-out rollouts."""
    from sympredict.data import TrajectoryData

    fom, gal, RB, Y, c = sine_gordon
    held = np.array([False, True, False, False])
    train, val = trajectory_pairs_of(Y[~held], c[~held]), TrajectoryData(Y[held], c[held, None], 0.1)
    lams = (1e-8, 1e-4, 1e-1)
    red = sg_reductor(
        sine_gordon,
        train,
        SymplecticKernelPredictor(None, IMQ(1.0), max_centers=50, trainer=ExactGreedy(tol=1e-9)),
        validation=val,
        selection=ValidationSelection(regularizations=lams),
    )
    red.reduce()
    table = []
    for lam in (0.0, *lams):
        flow = hand_made_flow(train, lam, validation=val.pairs())
        pred = flow.rollout(Y[held, 0], 20, mu=c[held, None], dt=0.1)[:, 1:]
        table.append(
            (lam, float(np.mean(np.linalg.norm(pred - Y[held, 1:], axis=-1) / np.linalg.norm(Y[held, 1:], axis=-1))))
        )
    assert [(r["regularization"], r["score"]) for r in red.regularization_table_] == table
    assert red.regularization_ == min((s, lam) for lam, s in table)[1]
    assert red.predictor_.trainer.regularization == red.regularization_
    assert red.validation_score(red.flow_map_) == min(s for _, s in table)
    # validation samples: the one-step error
    pairs = val.pairs()
    one_step = np.mean(
        np.linalg.norm(red.flow_map_.step(pairs.x0, mu=pairs.mu, dt=0.1) - pairs.x1, axis=-1)
        / np.linalg.norm(pairs.x1, axis=-1)
    )
    assert red.validation_score(red.flow_map_, pairs) == pytest.approx(one_step, rel=1e-12)
    with pytest.raises(
        ValueError,
        match=r"regularizations=\(1e-08, 0.0001, 0.1\)\) scores each ridge term on "
        r"validation data: give GivenSamples\(..., validation=...\)",
    ):
        sg_reductor(
            sine_gordon,
            train,
            SymplecticKernelPredictor(None, IMQ(1.0)),
            selection=ValidationSelection(regularizations=lams),
        )
    with pytest.raises(ValueError, match="regularizations must be >= 0"):
        sg_reductor(sine_gordon, train, None, selection=ValidationSelection(regularizations=(-1.0,)))
    with pytest.raises(ValueError, match="trajectories of dimension 4"):
        sg_reductor(sine_gordon, train, None, validation=TrajectoryData(Y[held, :, :4], c[held, None], 0.1))


@pytest.mark.filterwarnings("ignore::sympredict.exceptions.ExtrapolationWarning")
def test_split_is_the_hand_made_split_predictor_and_symplectic(sine_gordon):
    fom, gal, RB, Y, c = sine_gordon
    quad = gal.quadratic_part(mass=True)
    train = trajectory_pairs_of(Y, c)
    red = sg_reductor(
        sine_gordon,
        train,
        SymplecticKernelPredictor(None, IMQ(1.0), max_centers=50, trainer=ExactGreedy(tol=1e-9)),
        split=QuadraticSplit(quad),
    )
    red.reduce()
    assert type(red.predictor_).__name__ == "SplitKernelPredictor"
    by_hand = hand_made_flow(train, 0.0, quadratic=quad)
    x = Y[:, 5]
    np.testing.assert_array_equal(red.flow_map_.step(x, mu=c[:, None], dt=0.1), by_hand.step(x, mu=c[:, None], dt=0.1))
    D = red.flow_map_.step_jacobian(x, mu=c[:, None], dt=0.1)
    J = np.block([[np.zeros((3, 3)), np.eye(3)], [-np.eye(3), np.zeros((3, 3))]])
    assert np.abs(np.swapaxes(D, 1, 2) @ J @ D - J).max() < 1e-8  # DPhi^T J DPhi = J
    # the existence check saw S's pairs (L_h x0, L_-h x1): per c the least-squares linear map of those pairs,
    # in the coordinates the predictor is trained in (x~ = T x, the "diag" scaling: D S~ = T D S T^-1)
    from scipy.linalg import expm

    T = SymplecticScaling("diag").fit(np.concatenate([train.x0, train.x1])).matrix_
    sigmas = []
    for cc in np.unique(c):
        L = expm(0.05 * J @ quad.hessian(cc)[0])
        sel = train.mu[:, 0] == cc
        M = np.linalg.lstsq(train.x0[sel] @ L.T, train.x1[sel] @ np.linalg.inv(L).T, rcond=None)[0].T
        M = T @ M @ np.linalg.inv(T)
        sigmas.append(np.linalg.svd(M[3:, 3:], compute_uv=False)[-1])  # dp1/dp0 of S
    assert red.existence_["sigma_min"] == pytest.approx(min(sigmas), rel=1e-6)
    with pytest.raises(ValueError, match="QuadraticSplit needs a sympredict.systems.linear_flow.QuadraticPart"):
        sg_reductor(sine_gordon, train, None, split=QuadraticSplit(np.eye(6)))
    with pytest.raises(ValueError, match="split must be a QuadraticSplit"):
        sg_reductor(sine_gordon, train, None, split=quad)
    with pytest.raises(ValueError, match="inner SymplecticKernelPredictor as estimator"):
        from sympredict.flowmap.splitting import SplitKernelPredictor

        sg_reductor(
            sine_gordon, train, SplitKernelPredictor(SymplecticKernelPredictor(), quad), split=QuadraticSplit(quad)
        )


def test_split_of_the_whole_quadratic_hamiltonian_is_its_exact_flow(wave_rom):
    """On a linear ROM with split = its whole Hamiltonian, S is the identity: the learned step is expm(dt J H(mu)),
    also at a speed between the training ones and with the kernels chosen on S's pairs."""
    from scipy.linalg import expm

    from sympredict.systems.linear_flow import QuadraticPart

    fom, rom, _, _ = wave_rom
    mus = [fom.model.parameters.parse(c**2) for c in (0.2, 0.25, 0.3)]
    H0, H1 = rom.system.H0, rom.system.H1  # H(mu) = H0 + mu H1
    red = SymplecticKernelReductor(
        fom.model,
        rom.RB,
        0.1,
        GalerkinSamples(mus, n_samples=40, n_validation=2),
        SymplecticKernelPredictor(max_centers=30),
        split=QuadraticSplit(QuadraticPart([H0, H1], [[0.0], [1.0]])),
        selection=ValidationSelection([IMQ(0.1), IMQ(1.0)], [IMQ(1.0)], m_star=10),
    )
    red.reduce()
    assert hasattr(red, "selection_")
    x = red.validation_data_.x0[:5]
    for mu in (0.05, 0.0784):
        exact = x @ expm(0.1 * rom.system.J @ (H0 + mu * H1)).T
        np.testing.assert_allclose(red.flow_map_.step(x, mu=[[mu]], dt=0.1), exact, rtol=0, atol=1e-9 * np.abs(x).max())
