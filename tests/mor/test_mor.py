"""SymplecticKernelReductor on pyMOR models, model-agnostic flow-map data, scaling, pyMOR interop, sympredict.testing."""

import numpy as np
import pytest
from pymor.algorithms.symplectic import SymplecticBasis, psd_complex_svd
from pymor.core.logger import set_log_levels
from pymor.models.basic import StationaryModel
from pymor.operators.block import BlockDiagonalOperator
from pymor.operators.numpy import NumpyMatrixOperator
from pymor.parameters.base import Mu
from pymor.reductors.symplectic import QuadraticHamiltonianRBReductor

from sympredict import SymplecticKernelPredictor
from sympredict.exceptions import GeneratingFunctionWarning
from sympredict.systems.flowmaps import (
    HamiltonianSystem,
    LinearHamiltonianSystem,
    check_generating_function,
    flow_map_data,
    mu_to_vector,
    random_parameters,
    sample_energy_box,
    sample_trajectory_neighbourhood,
)
from sympredict.kernels import IMQ
from sympredict.symplectic.metrics import canonical_J
from sympredict.mor import (
    DefaultEstimator,
    GalerkinSamples,
    ProjectedTrajectories,
    SymplecticKernelReductor,
    TrainingScaling,
)
from sympredict.mor.basis import SymplecticROM, complex_svd_basis, symplecticity_of_basis
from sympredict.flowmap.scaling import BoxScaling, NormalizedFlowMap, SymplecticScaling
from sympredict.testing import (
    assert_energy_bounded,
    assert_rom_matches_fom,
    assert_symplectic_basis,
    assert_symplectic_step,
)

from _pymor_wave import parametric_wave  # tests/; the wave fixture is in tests/conftest.py

set_log_levels({"pymor": "ERROR", "sympredict": "WARNING"})

pymordemos = pytest.importorskip("pymordemos.symplectic_wave_equation")


def relative_error(fom, U_red_full, mu, stride=10):
    U = fom.solve(mu)[::stride][: len(U_red_full)]
    return float(np.sqrt((U - U_red_full).norm2().sum() / U.norm2().sum()))


# ---------------------------------------------------------------- flowmaps
def test_mu_flattening_follows_sorted_parameter_names():
    from pymor.parameters.base import Parameters

    params = Parameters({"b": 2, "a": 1})
    mu = Mu({"b": np.array([1.0, 2.0]), "a": np.array([3.0])})
    np.testing.assert_array_equal(mu_to_vector(mu, params), [3.0, 1.0, 2.0])
    np.testing.assert_array_equal(mu_to_vector(mu, params), mu.to_numpy())
    with pytest.raises(ValueError, match="does not match"):
        mu_to_vector(Mu({"b": np.array([1.0, 2.0]), "c": np.array([3.0])}), params)
    drawn = random_parameters(params, [0.0, 10.0, 10.0], [1.0, 20.0, 20.0], 5, seed=1)
    vec = np.stack([mu_to_vector(m, params) for m in drawn])
    assert np.all((vec >= [0, 10, 10]) & (vec <= [1, 20, 20]))


def test_rk4_reference_flow_is_accurate_and_fourth_order():
    # harmonic oscillator H = (p^2 + w^2 q^2)/2 with w = mu: closed-form flow
    H = lambda x, mu: 0.5 * (x[:, 1] ** 2 + mu[:, 0] ** 2 * x[:, 0] ** 2)
    grad = lambda x, mu: np.column_stack([mu[:, 0] ** 2 * x[:, 0], x[:, 1]])
    sys = HamiltonianSystem(H, grad, 2, {"w": 1}, rtol=1e-12)
    x0 = np.array([[1.0, 0.5], [-0.3, 0.2]])
    w, t = np.array([1.5, 2.0]), np.array([0.7, 1.3])
    exact = np.column_stack(
        [
            x0[:, 0] * np.cos(w * t) + x0[:, 1] / w * np.sin(w * t),
            -x0[:, 0] * w * np.sin(w * t) + x0[:, 1] * np.cos(w * t),
        ]
    )
    np.testing.assert_allclose(sys.flow(x0, w[:, None], t), exact, atol=1e-10)
    # observed order of the RK4 core: halve the step, error / 16
    from scipy.stats import linregress

    from sympredict.systems.flowmaps import rk4_flow

    errs = [
        np.abs(rk4_flow(grad, x0, w[:, None], t, rtol=np.inf, min_steps=s // 2) - exact).max()
        for s in (16, 32, 64, 128)
    ]
    slope = linregress(np.log([16, 32, 64, 128]), np.log(errs)).slope
    assert slope == pytest.approx(-4.0, abs=0.2)
    # the FD Jacobian of the reference flow matches the exact rotation
    jac = sys.flow_jacobian(x0, w[:, None], t)
    exact_jac = np.array(
        [[[np.cos(a * b), np.sin(a * b) / a], [-a * np.sin(a * b), np.cos(a * b)]] for a, b in zip(w, t)]
    )
    np.testing.assert_allclose(jac, exact_jac, atol=1e-7)


def test_linear_system_exact_flow_matches_rk4_and_samplers():
    rng = np.random.default_rng(0)
    A = rng.normal(size=(4, 4))
    M = A @ A.T + np.eye(4)
    lin = LinearHamiltonianSystem(lambda mu: (1 + mu[0]) * M, 4, 1)
    gen = HamiltonianSystem(
        lambda x, mu: 0.5 * (1 + mu[:, 0]) * np.einsum("bi,ij,bj->b", x, M, x),
        lambda x, mu: (1 + mu[:, :1]) * (x @ M),
        4,
        {"m": 1},
    )
    x0 = rng.normal(size=(3, 4))
    mu = np.array([[0.1], [0.2], [0.3]])
    np.testing.assert_allclose(lin.flow(x0, mu, 0.3), gen.flow(x0, mu, 0.3), atol=1e-9)
    np.testing.assert_allclose(lin.flow_jacobian(x0, mu, 0.3), gen.flow_jacobian(x0, mu, 0.3), atol=1e-6)
    box = sample_energy_box(gen, 50, [0.1], 1.0, -2, 2, rng)
    assert np.all(gen.hamiltonian(box, np.full((50, 1), 0.1)) <= 1.0)
    traj = lin.trajectory(x0[:1], [0.1], 0.05, 20)[0]
    near = sample_trajectory_neighbourhood(traj, 200, 0.1, rng)
    dist = np.min(np.linalg.norm(near[:, None] - traj[None], axis=2), axis=1)
    assert np.all(dist <= 0.1 * np.linalg.norm(traj, axis=1).max() + 1e-12)
    on = sample_trajectory_neighbourhood(traj, 21, 0.0, rng)
    assert len(np.unique(on, axis=0)) == 21  # distinct points: no duplicated samples


def test_generating_function_check_names_cause_and_largest_step():
    osc = LinearHamiltonianSystem(lambda mu: np.eye(2), 2, 0)  # omega = 1: dp1/dp0 = cos(dT)
    x0 = np.random.default_rng(1).normal(size=(20, 2))
    info = check_generating_function(osc, flow_map_data(osc, x0, None, 1.0))
    assert info["sigma_min"] == pytest.approx(np.cos(1.0), rel=1e-10)
    assert info["dt_max"] == pytest.approx(np.arccos(1e-2), abs=0.01)
    with pytest.warns(GeneratingFunctionWarning, match="largest admissible dT"):
        check_generating_function(osc, flow_map_data(osc, x0, None, 1.5))
    with pytest.raises(ValueError, match=r"dp1/dp0.*pi/2.*largest admissible dT here is about 1.56"):
        check_generating_function(osc, flow_map_data(osc, x0, None, np.pi / 2))
    # nonlinear (pendulum-like) system: FD Jacobians of the reference flow, dT scan
    pend = HamiltonianSystem(
        lambda x, mu: 0.5 * x[:, 1] ** 2 + 1 - np.cos(x[:, 0]),
        lambda x, mu: np.column_stack([np.sin(x[:, 0]), x[:, 1]]),
        2,
    )
    small = 0.2 * x0
    with pytest.raises(ValueError, match="largest admissible dT"):
        check_generating_function(pend, flow_map_data(pend, small, None, 1.6), max_points=5)


def test_midpoint_existence_check_holds_to_a_half_turn():
    osc = LinearHamiltonianSystem(lambda mu: np.eye(2), 2, 0)  # a rotation by dT: (I + DPhi)/2 has sigma |cos(dT/2)|
    x0 = np.random.default_rng(1).normal(size=(20, 2))
    for dT in (1.0, 2.0, 2.5):  # past the type-II limit pi/2, below the half turn
        info = check_generating_function(osc, flow_map_data(osc, x0, None, dT), update="midpoint")
        assert info["sigma_min"] == pytest.approx(np.cos(dT / 2), rel=1e-10)
        assert info["dt_max"] == pytest.approx(2 * np.arccos(1e-2), abs=0.01)
    with pytest.raises(ValueError, match="dp1/dp0"):
        check_generating_function(osc, flow_map_data(osc, x0, None, 2.0))
    with pytest.warns(GeneratingFunctionWarning, match="half a turn"):
        check_generating_function(osc, flow_map_data(osc, x0, None, 3.0), update="midpoint")
    with pytest.raises(ValueError, match=r"\(I \+ DPhi\)/2.*half a turn"):
        check_generating_function(osc, flow_map_data(osc, x0, None, np.pi), update="midpoint")
    with pytest.raises(ValueError, match="past the first step"):  # 1.2 turns: sigma recovered, the branch broke
        check_generating_function(osc, flow_map_data(osc, x0, None, 1.2 * np.pi), update="midpoint")
    with pytest.raises(ValueError, match="update must be"):
        check_generating_function(osc, flow_map_data(osc, x0, None, 1.0), update="leapfrog")


def test_reductor_checks_the_existence_of_its_predictors_update(wave):
    fom, train, RB, dt = wave
    red = SymplecticKernelReductor(fom, RB, dt, GalerkinSamples(train, n_samples=30, n_validation=1))
    red.training_data()
    limit = red.existence_["dt_max"]
    big = 1.5 * limit  # past the type-II limit, below the midpoint form's (twice as long)
    with pytest.raises(ValueError, match="dp1/dp0"):  # a type-II predictor is refused
        SymplecticKernelReductor(
            fom,
            RB,
            big,
            GalerkinSamples(train, n_samples=30, n_validation=1),
            SymplecticKernelPredictor(update="symplectic_euler"),
        ).training_data()
    open_update = SymplecticKernelReductor(
        fom, RB, big, GalerkinSamples(train, n_samples=30, n_validation=1), SymplecticKernelPredictor()
    )
    open_update.training_data()  # an estimator with update=None gets the form that exists
    assert open_update.choice_["update"] == "midpoint" and "dp1/dp0" in open_update.choice_["reason"]
    both = SymplecticKernelReductor(
        fom, RB, 0.5 * limit, GalerkinSamples(train, n_samples=30, n_validation=1), SymplecticKernelPredictor()
    )
    both.training_data()  # both forms exist: the estimator's search keeps the choice
    assert both.choice_["update"] is None
    auto = SymplecticKernelReductor(fom, RB, big, GalerkinSamples(train, n_samples=30, n_validation=1))
    auto.training_data()  # the default predictor takes the midpoint form, which exists here
    assert auto.choice_["update"] == "midpoint" and "dp1/dp0" in auto.choice_["reason"]
    mid = SymplecticKernelReductor(
        fom, RB, big, GalerkinSamples(train, n_samples=30, n_validation=1), SymplecticKernelPredictor(update="midpoint")
    )
    mid_train, _ = mid.training_data()
    # coordinate-free: the first half turn of the fastest reduced mode (type II depends on the coordinates)
    om = max(mid.reduced_system.frequencies(m).max() for m in np.unique(mid_train.mu, axis=0))
    assert mid.existence_["dt_max"] == pytest.approx(2 * np.arccos(1e-2) / om, rel=0.01)
    assert mid.existence_["dt_max"] > big
    with pytest.raises(ValueError, match="half a turn"):
        SymplecticKernelReductor(
            fom,
            RB,
            2.5 * limit,
            GalerkinSamples(train, n_samples=30, n_validation=1),
            SymplecticKernelPredictor(update="midpoint"),
        ).training_data()


# ---------------------------------------------------------------- scaling
def test_scaled_predictor_step_is_symplectic():
    rng = np.random.default_rng(2)
    lin = LinearHamiltonianSystem(lambda mu: np.diag([mu[0] * 400.0, 9.0, 1.0, 0.01]), 4, 1)
    x0 = rng.normal(size=(150, 4)) * [0.05, 0.3, 1.0, 10.0]
    mu = rng.uniform(0.8, 1.2, size=(150, 1))
    data = flow_map_data(lin, x0, mu, 0.05)
    S = SymplecticScaling("diag").fit(np.concatenate([data.x0, data.x1]))
    Sm = S.matrix_
    J = canonical_J(4)
    sigma2 = (Sm.T @ J @ Sm)[0, 2]
    np.testing.assert_allclose(Sm.T @ J @ Sm, sigma2 * J, atol=1e-12)  # conformally symplectic
    mu_s = BoxScaling().fit(data.mu)
    model = SymplecticKernelPredictor(IMQ(0.5), IMQ(1.0), None, max_centers=60)
    model.fit(S.transform(data.x0), S.transform(data.x1), mu=mu_s.transform(data.mu), dt=1.0)
    flow = NormalizedFlowMap(model, S, mu_s, 0.05)
    res = assert_symplectic_step(flow, x0[:5], mu=[1.0], dt=0.05, atol=1e-9, fd_atol=1e-5)
    assert res["analytic"] < 1e-9
    # the scaled model is a different map from the unscaled kernel: it is not the identity of the test
    assert np.abs(flow.step(x0[:5], mu=[1.0], dt=0.05) - x0[:5]).max() > 1e-3


def test_williamson_form_is_symplectic_and_diagonalizes():
    from sympredict.flowmap.scaling import williamson

    rng = np.random.default_rng(3)
    A = rng.normal(size=(6, 6))
    H = A @ A.T + 0.5 * np.eye(6)
    S, d = williamson(H)
    J = canonical_J(6)
    np.testing.assert_allclose(S.T @ J @ S, J, atol=1e-10)
    np.testing.assert_allclose(S.T @ H @ S, np.diag(np.concatenate([d, d])), atol=1e-10 * np.abs(H).max())
    # symplectic eigenvalues = |eigenvalues of J H| (the modal frequencies)
    np.testing.assert_allclose(np.sort(d), np.sort(np.abs(np.linalg.eigvals(J @ H).imag))[::2], rtol=1e-9)
    with pytest.raises(ValueError, match="SPD"):
        williamson(-H)


def test_reductor_with_williamson_scaling(wave):
    fom, train, RB, dt = wave
    red = SymplecticKernelReductor(
        fom,
        RB,
        dt,
        GalerkinSamples(train, n_samples=200),
        DefaultEstimator(max_centers=300),
        scaling=TrainingScaling("williamson"),
    )
    rom = red.reduce()
    mu = fom.parameters.parse(0.111)
    gal = QuadraticHamiltonianRBReductor(fom, RB)
    e_gal = relative_error(fom, gal.reconstruct(gal.reduce().solve(mu))[::10], mu)
    assert relative_error(fom, red.reconstruct(rom.solve(mu)), mu) <= 1.5 * e_gal + 1e-3
    x = rom.solve(mu).to_numpy().T[:4]
    assert (
        assert_symplectic_step(rom.flow_map, x, mu=[0.111], dt=dt, atol=1e-8, fd_h=1e-3, fd_atol=1e-3)["analytic"]
        < 1e-8
    )
    with pytest.raises(ValueError, match="williamson"):
        SymplecticKernelReductor(fom, RB, dt, ProjectedTrajectories(train), scaling=TrainingScaling("williamson"))


# ---------------------------------------------------------------- sympredict.testing
def test_testing_assertions_fail_with_clear_messages():
    class Stretch:
        def step(self, x, mu=None, dt=None):
            return x * [2.0, 1.0]

        def step_jacobian(self, x, mu=None, dt=None):
            return np.tile(np.diag([2.0, 1.0]), (len(x), 1, 1))

    with pytest.raises(AssertionError, match="not symplectic.*analytic"):
        assert_symplectic_step(Stretch(), np.ones((3, 2)))

    class Liar(Stretch):
        def step_jacobian(self, x, mu=None, dt=None):
            return np.tile(np.eye(2), (len(x), 1, 1))

    with pytest.raises(AssertionError, match="finite-difference"):
        assert_symplectic_step(Liar(), np.ones((3, 2)))
    traj = np.stack([np.ones(2) * (1 + 0.01 * k) for k in range(50)])[None]
    with pytest.raises(AssertionError, match="energy error not bounded.*step"):
        assert_energy_bounded(lambda x: 0.5 * (x**2).sum(axis=1), traj, rtol=1e-3)
    assert assert_energy_bounded(lambda x: 0.5 * (x**2).sum(axis=1), traj, rtol=1.5) > 0
    V = complex_svd_basis(np.random.default_rng(0).normal(size=(9, 10)), n=2).V
    assert_symplectic_basis(V)
    with pytest.raises(AssertionError, match="not symplectic"):
        assert_symplectic_basis(1.1 * V)
    with pytest.raises(AssertionError, match="transposed"):
        assert_symplectic_basis(V.T)


# ---------------------------------------------------------------- reduction interop
def test_complex_svd_basis_takes_vector_arrays_and_refuses_ambiguous_arrays(wave):
    fom, train, RB, _ = wave
    U = fom.solve(train[0])
    rows = np.hstack([U.blocks[0].to_numpy().T, U.blocks[1].to_numpy().T])  # (K, 2N)
    from_va = complex_svd_basis(U, n=3)
    np.testing.assert_allclose(from_va.V, complex_svd_basis(rows, n=3, layout="rows").V)
    np.testing.assert_allclose(from_va.V, complex_svd_basis(rows.T, n=3, layout="columns").V)
    with pytest.raises(ValueError, match="ambiguous"):
        complex_svd_basis(rows[:100], n=3)  # (100, 1000): both even
    with pytest.raises(ValueError, match="pyMOR's \\(dim, len\\) layout"):
        complex_svd_basis(rows[:101].T, n=3)  # (1000, 101)
    assert complex_svd_basis(rows[:101], n=3).n == 3  # (101, 1000): unambiguous rows
    pb = from_va.to_pymor(fom.solution_space)
    assert symplecticity_of_basis(pb) < 1e-13
    with pytest.raises(ValueError, match="transposed"):
        symplecticity_of_basis(from_va.V.T)


def test_symplectic_rom_on_a_pymor_model_matches_pymor_galerkin(wave):
    fom, train, RB, _ = wave
    rom = SymplecticROM(fom, RB)
    mu = fom.parameters.parse(0.095)
    pymor_rom = QuadraticHamiltonianRBReductor(fom, RB).reduce()
    ref = pymor_rom.solve(mu).to_numpy().T  # (K+1, 2n), implicit midpoint at the FOM step
    h = fom.T / fom.time_stepper.nt
    x0 = rom.project(fom.initial_data.as_range_array(mu))
    ours = rom.system.trajectory(x0, mu, h, fom.time_stepper.nt)[0]  # a Mu is accepted
    np.testing.assert_array_equal(
        ours, rom.system.trajectory(x0, mu_to_vector(mu, fom.parameters), h, fom.time_stepper.nt)[0]
    )
    # exact flow vs pyMOR's implicit midpoint at h: agree to the midpoint's O(h^2) error
    np.testing.assert_allclose(ours, ref, atol=1e-3 * np.abs(ref).max())
    with pytest.raises(ValueError, match="QuadraticHamiltonianModel"):
        SymplecticROM(StationaryModel(NumpyMatrixOperator(np.eye(4)), NumpyMatrixOperator(np.ones((4, 1)))), RB)


# ---------------------------------------------------------------- the reductor
@pytest.mark.parametrize("samples", [GalerkinSamples, ProjectedTrajectories])
def test_reductor_on_pymor_demo_wave_matches_galerkin(wave, samples):
    fom, train, RB, dt = wave
    reductor = SymplecticKernelReductor(fom, RB, dt, samples(train), DefaultEstimator(max_centers=300))
    rom = reductor.reduce()
    assert rom.parameters == fom.parameters
    gal = QuadraticHamiltonianRBReductor(fom, RB)
    grom = gal.reduce()
    for c in (0.087, 0.111):  # not trained on
        mu = fom.parameters.parse(c)
        U_red = rom.solve(mu)
        assert len(U_red) == round(fom.T / dt) + 1 and U_red.space == rom.solution_space
        U = reductor.reconstruct(U_red)
        assert U.space == fom.solution_space
        e_kernel = relative_error(fom, U, mu)
        e_gal = relative_error(fom, gal.reconstruct(grom.solve(mu))[::10], mu)
        assert e_kernel <= 1.5 * e_gal + 1e-3, (c, e_kernel, e_gal)
    assert_rom_matches_fom(fom, rom, [fom.parameters.parse(0.1)], rtol=0.05, reconstruct=reductor.reconstruct)
    assert_symplectic_step(
        rom.flow_map,
        rom.solve(fom.parameters.parse(0.1)).to_numpy().T[:5],
        mu=[0.1],
        dt=dt,
        atol=1e-8,
        fd_h=1e-3,
        fd_atol=1e-3,
    )  # flat kernels: step noise ~1e-9 relative
    # a flow map runs past the training horizon
    long = rom.with_(T=3 * fom.T).solve(fom.parameters.parse(0.1))
    assert len(long) == round(3 * fom.T / dt) + 1 and np.all(np.isfinite(long.to_numpy()))


def test_reductor_without_parameters_and_with_a_non_affine_vector_parameter():
    fom = pymordemos.discretize_fom(T=0.5)
    U = fom.solve()
    RB = psd_complex_svd(U, 2)
    dt = 5 * fom.T / fom.time_stepper.nt
    red = SymplecticKernelReductor(fom, RB, dt, GalerkinSamples(n_samples=100), DefaultEstimator(max_centers=150))
    rom = red.reduce()
    assert not rom.parameters
    err = relative_error(fom, red.reconstruct(rom.solve()), None, stride=5)
    gal = QuadraticHamiltonianRBReductor(fom, RB)
    assert err <= 1.5 * relative_error(fom, gal.reconstruct(gal.reduce().solve())[::5], None, stride=5) + 1e-3
    # H_op non-affine in a 2-component parameter named 'k'
    fom2 = parametric_wave(T=0.5, H_expr="exp(k[0]) * k[1]**2 / 0.01", params={"k": 2})
    train = [Mu({"k": np.array([a, b])}) for a in (0.0, 0.1) for b in (0.09, 0.11)]
    U2 = fom2.solution_space.empty()
    for mu in train:
        U2.append(fom2.solve(mu))
    red2 = SymplecticKernelReductor(
        fom2, psd_complex_svd(U2, 2), dt, GalerkinSamples(train, n_samples=100), DefaultEstimator(max_centers=200)
    )
    rom2 = red2.reduce()
    assert rom2.parameters == fom2.parameters
    mu = Mu({"k": np.array([0.05, 0.1])})
    assert relative_error(fom2, red2.reconstruct(rom2.solve(mu)), mu, stride=5) < 0.05


def test_projected_reductor_on_a_nonlinear_pymor_model():
    """Any time-dependent pyMOR model with ProjectedTrajectories: the sine-Gordon InstationaryModel (nonlinear operator)."""
    from sympredict.systems.sine_gordon import SineGordonFOM

    sg = SineGordonFOM(n_points=60, length=20.0, T=4.0, nt=40, c_range=(0.8, 1.2))
    fom = sg.model
    space = fom.parameters.space({"amplitude": (0.5, 1.5), "c": (0.8, 1.2)})
    train = space.sample_uniformly(3)
    RB = complex_svd_basis(np.vstack([sg.from_pymor(fom.solve(mu)) for mu in train]), n=3).to_pymor(sg.phase_space)
    with pytest.raises(ValueError, match="GalerkinSamples needs .*QuadraticHamiltonianModel.*ProjectedTrajectories"):
        SymplecticKernelReductor(fom, RB, 0.2, GalerkinSamples(train))
    reductor = SymplecticKernelReductor(
        fom, RB, 0.2, ProjectedTrajectories(train, parameter_space=space), DefaultEstimator(max_centers=200)
    )
    rom = reductor.reduce()
    assert rom.parameters == fom.parameters and reductor.existence_["sigma_min"] > 0.1
    for values in ({"amplitude": 0.9, "c": 1.07}, {"amplitude": 1.3, "c": 0.85}):  # not trained on
        mu = fom.parameters.parse(values)
        X = sg.from_pymor(fom.solve(mu))[::2]  # FOM output step 0.1, ROM step 0.2
        U_red = rom.solve(mu)
        Y = sg.from_pymor(reductor.reconstruct(U_red))
        Xr = reductor.project(fom.solve(mu))[::2]
        P = sg.from_pymor(reductor.reconstruct(rom.solution_space.from_numpy(Xr.T)))
        err = np.linalg.norm(Y - X, axis=1).mean() / np.linalg.norm(X, axis=1).mean()
        floor = np.linalg.norm(P - X, axis=1).mean() / np.linalg.norm(X, axis=1).mean()
        assert err < 2 * floor, (values, err, floor)  # near the best the basis can represent (measured 1.02-1.07x)
        assert_symplectic_step(
            reductor.flow_map_, U_red.to_numpy().T[3:4], mu=np.array([[values["amplitude"], values["c"]]])
        )


def test_reductor_bad_input(wave):
    fom, train, RB, dt = wave
    stationary = StationaryModel(NumpyMatrixOperator(np.eye(4)), NumpyMatrixOperator(np.ones((4, 1))))
    with pytest.raises(ValueError, match="Hamiltonian"):
        SymplecticKernelReductor(stationary, RB, dt, GalerkinSamples(train))
    with pytest.raises(ValueError, match="time-dependent pyMOR Model.*lacks initial_data, T"):
        SymplecticKernelReductor(stationary, RB, dt, ProjectedTrajectories(train))
    bad = SymplecticBasis(RB.E * 1.1, RB.F, check_symplecticity=False)
    with pytest.raises(ValueError, match="not symplectic"):
        SymplecticKernelReductor(fom, bad, dt, GalerkinSamples(train))
    # a basis of another phase space
    from pymor.operators.constructions import IdentityOperator
    from pymor.vectorarrays.numpy import NumpyVectorSpace
    from pymor.models.symplectic import QuadraticHamiltonianModel

    sp = NumpyVectorSpace(10)
    fom_small = QuadraticHamiltonianModel(
        1.0,
        BlockDiagonalOperator([IdentityOperator(sp), IdentityOperator(sp)]).source.ones(),
        BlockDiagonalOperator([IdentityOperator(sp), IdentityOperator(sp)]),
        nt=10,
    )
    with pytest.raises(ValueError, match="mismatched spaces"):
        SymplecticKernelReductor(fom_small, RB, 0.1)
    with pytest.raises(ValueError, match="does not match"):
        SymplecticKernelReductor(fom, RB, dt, GalerkinSamples([Mu({"d": np.array([0.1])})]))
    with pytest.raises(ValueError, match="multiple of the FOM's output step"):
        SymplecticKernelReductor(fom, RB, 1.55 * dt, ProjectedTrajectories(train))
    with pytest.raises(
        ValueError, match=r"past the first step where it is singular.*largest admissible dT here is about 1\.[34]"
    ):
        SymplecticKernelReductor(
            fom, RB, 20 * dt, GalerkinSamples(train, n_samples=50), SymplecticKernelPredictor(update="symplectic_euler")
        ).training_data()  # omega_max dT > pi/2
    reductor = SymplecticKernelReductor(
        fom, RB, dt, GalerkinSamples(train, n_samples=100), DefaultEstimator(max_centers=100)
    )
    rom = reductor.reduce()
    with pytest.raises(ValueError, match="does not match"):
        rom.solve(Mu({"d": np.array([0.1])}))


# ---------------------------------------------------------------- examples (CI, small sizes)
def _run_example(name, *args):
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    out = subprocess.run(
        [sys.executable, str(root / "examples" / name), *args], capture_output=True, text=True, timeout=600
    )
    assert out.returncode == 0, out.stderr[-3000:]
    return out.stdout


@pytest.mark.parametrize("data", ["projected", "reduced"])
def test_example_pymor_wave_reductor(data):
    import re

    out = _run_example("pymor_wave_reductor.py", "--T", "1", "--centers", "200", "--samples", "100", "--data", data)
    pairs = [(float(a), float(b)) for a, b in re.findall(r"kernel ROM ([0-9.e+-]+), Galerkin ROM ([0-9.e+-]+)", out)]
    assert len(pairs) == 3
    assert all(k <= 1.5 * g + 1e-3 for k, g in pairs), out
    assert "finite: True" in out


def test_example_henon_heiles():
    import re

    out = _run_example("henon_heiles.py", "--samples", "120", "--centers", "250", "--steps", "60")
    err10 = float(re.search(r"after 10 steps ([0-9.e+-]+)", out).group(1))
    assert err10 < 0.1, out
    assert float(re.search(r"symplecticity defect ([0-9.e+-]+)", out).group(1)) < 1e-9


def test_reductor_clones_the_given_predictor(wave):
    fom, train, RB, dt = wave
    given = SymplecticKernelPredictor(IMQ(0.05), IMQ(0.5), None, max_centers=120)
    reductor = SymplecticKernelReductor(fom, RB, dt, GalerkinSamples(train, n_samples=80), estimator=given)
    rom = reductor.reduce()
    assert not given.is_fitted and reductor.predictor_.is_fitted and reductor.predictor_ is not given
    assert reductor.predictor_.get_params()["state_kernel"] == IMQ(0.05)
    assert len(rom.solve(fom.parameters.parse(0.1))) == round(fom.T / dt) + 1
    from sympredict.estimators.auto import KernelSearch

    # mu_kernel=None with varying parameters: the estimator chooses one (its KernelSearch), the reductor records it
    search = KernelSearch(families=("imq",), parameter_shapes=(0.5, 2.5), m_star=20, refine_sweeps=0, max_samples=200)
    chooses = SymplecticKernelReductor(
        fom,
        RB,
        dt,
        GalerkinSamples(train, n_samples=80),
        SymplecticKernelPredictor(IMQ(0.05), max_centers=40, update="symplectic_euler", search=search),
    )
    chooses.reduce()
    assert list(chooses.choice_["estimator"]) == ["mu_kernel"] and chooses.predictor_.kernel_.mu is not None
