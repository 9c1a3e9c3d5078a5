"""The pyMOR user's rough edges of the reductor, and finite-element models with a mass matrix."""

import numpy as np
import pytest
from pymor.parameters.base import Mu, Parameters

from sympredict._checks import as_parameter
from sympredict.mor import DefaultEstimator, GalerkinSamples, ProjectedTrajectories, SymplecticKernelReductor
from sympredict.mor.mass import MassMatrixCoordinates
from sympredict.symplectic.metrics import canonical_J
from sympredict.testing import fe_wave_matrices


@pytest.fixture(scope="module")
def small_rom(small_fe_wave):
    fom, coords, space, train, RB = small_fe_wave
    h = fom.T / fom.time_stepper.nt
    red = SymplecticKernelReductor(
        fom,
        RB,
        4 * h,
        ProjectedTrajectories(train, parameter_space=space, n_validation=1),
        DefaultEstimator(max_centers=200),
    )
    return red, red.reduce()


# ------------------------------------------------------------------ a. Mu and dicts wherever a mu is accepted
def test_as_parameter_reads_mu_and_dicts_in_parameter_order():
    params = Parameters({"b": 2, "a": 1})
    want = np.array([[3.0, 1.0, 2.0]] * 2)  # sorted by name: a, then b
    np.testing.assert_array_equal(as_parameter(Mu({"b": [1, 2], "a": 3}), 2, 3), want)
    np.testing.assert_array_equal(as_parameter({"b": [1, 2], "a": 3}, 2, 3, parameters=params), want)
    np.testing.assert_array_equal(as_parameter({"c": 0.9}, 3, 1), np.full((3, 1), 0.9))
    np.testing.assert_array_equal(as_parameter([{"c": 1.0}, {"c": 2.0}], 2, 1), [[1.0], [2.0]])
    with pytest.raises(ValueError, match=r"ambiguous.*\['a', 'b'\]|\['a', 'b'\].*ambiguous"):
        as_parameter({"b": [1, 2], "a": 3}, 2, 3)
    with pytest.raises(ValueError, match=r"names \['a', 'b'\].*'c'"):
        as_parameter({"b": [1, 2], "a": 3}, 2, 3, parameters={"a": 1, "c": 2})
    with pytest.raises(ValueError, match=r"mu\['b'\] has 1 component"):
        as_parameter({"b": 1.0, "a": 3}, 2, 2, parameters={"a": 1, "b": 2})


def test_rom_flow_map_takes_pymor_mu_and_dict(small_fe_wave, small_rom):
    fom = small_fe_wave[0]
    red, rom = small_rom
    x = red.project(fom.initial_data.as_range_array(fom.parameters.parse(0.93)))
    ref = rom.flow_map.step(x, mu=0.93, dt=red.dt)
    np.testing.assert_array_equal(rom.flow_map.step(x, mu=fom.parameters.parse(0.93), dt=red.dt), ref)
    np.testing.assert_array_equal(rom.flow_map.step(x, mu={"c": 0.93}, dt=red.dt), ref)
    np.testing.assert_array_equal(rom.flow_map.rollout(x, 3, mu=Mu({"c": 0.93}), dt=red.dt)[:, 1], ref)
    with pytest.raises(ValueError, match="'c'"):
        rom.flow_map.step(x, mu={"speed": 0.93}, dt=red.dt)


# ------------------------------------------------------------------ 6. mass matrices
def test_mass_coordinates_are_symplectic_and_carry_the_energy():
    M, K, _ = fe_wave_matrices(12)
    rng = np.random.default_rng(0)
    q, p = rng.standard_normal((2, 5, 11))
    for lumped in (False, True):
        co = MassMatrixCoordinates(M, lumped=lumped)
        Mm = co.L @ co.L.T
        if not lumped:
            np.testing.assert_allclose(Mm, M.toarray(), rtol=0, atol=1e-14)
        T = co.matrix()
        J = canonical_J(22)
        assert np.abs(T.T @ J @ T - J).max() <= 1e-13
        qt, pt = co.to_canonical(q, p)
        np.testing.assert_allclose(np.concatenate([qt, pt], axis=1), np.concatenate([q, p], axis=1) @ T.T, atol=1e-13)
        q2, p2 = co.from_canonical(qt, pt)
        np.testing.assert_allclose(q2, q, atol=1e-12)
        np.testing.assert_allclose(p2, p, atol=1e-12)
        A = co.canonical_stiffness(K)
        Kd = K.toarray()
        H = 0.5 * np.einsum("bi,ij,bj->b", p, np.linalg.inv(Mm), p) + 0.5 * np.einsum("bi,ij,bj->b", q, Kd, q)
        Ht = 0.5 * (pt**2).sum(1) + 0.5 * np.einsum("bi,ij,bj->b", qt, A, qt)
        np.testing.assert_allclose(Ht, H, rtol=1e-12)
        np.testing.assert_allclose(co.velocity(pt), p @ np.linalg.inv(Mm), atol=1e-11)


def test_mass_coordinates_refuse_bad_matrices():
    with pytest.raises(ValueError, match="not positive definite"):
        MassMatrixCoordinates(-np.eye(3))
    with pytest.raises(ValueError, match="not symmetric"):
        MassMatrixCoordinates(np.array([[1.0, 0.5], [0.0, 1.0]]))
    with pytest.raises(ValueError, match="NaN"):
        MassMatrixCoordinates(np.array([[np.nan, 0.0], [0.0, 1.0]]))
    with pytest.raises(ValueError, match="square"):
        MassMatrixCoordinates(np.ones((2, 3)))


def test_fe_wave_fom_conserves_the_mass_matrix_energy(small_fe_wave):
    fom, coords, *_ = small_fe_wave
    M, K, _ = fe_wave_matrices(16)
    U = fom.solve(fom.parameters.parse(1.1))
    X = np.vstack([b.to_numpy() for b in U.blocks]).T  # (K+1, 2N) canonical
    q, p = coords.from_canonical(X[:, : coords.N], X[:, coords.N :])
    E = 0.5 * np.einsum("ki,ij,kj->k", p, np.linalg.inv(M.toarray()), p) + 0.5 * 1.1**2 * np.einsum(
        "ki,ij,kj->k", q, K.toarray(), q
    )
    np.testing.assert_allclose(E, E[0], rtol=1e-9)  # implicit midpoint conserves quadratic invariants


# ------------------------------------------------------------------ b. assert_symplectic_step on a valid ROM
def test_assert_symplectic_step_passes_a_valid_rom_and_says_what_it_used(small_fe_wave, small_rom):
    from sympredict.testing import assert_symplectic_step

    fom, *_, train, _ = small_fe_wave
    red, rom = small_rom
    X = red.project(fom.solve(train[1]))[::10]  # reduced states of very different component sizes
    res = assert_symplectic_step(rom.flow_map, X, mu=0.9, dt=red.dt)  # failed on finite-difference noise before
    assert res["method"] == "analytic+finite_differences" and res["analytic"] <= 1e-8


def test_assert_symplectic_step_finite_differences_tolerate_noise_and_catch_stretches():
    from sympredict.testing import assert_symplectic_step

    class NoisyRotation:  # symplectic, evaluated to ~1e-10 (like an implicit step's Newton tolerance)
        def step(self, x, mu=None, dt=None):
            c, s = np.cos(0.3), np.sin(0.3)
            y = x @ np.array([[c, -s], [s, c]]).T
            return y + 1e-10 * np.sin(1e7 * x)

    res = assert_symplectic_step(NoisyRotation(), np.array([[1.0, 1e-3], [0.5, -2.0]]))
    assert res["method"] == "finite_differences" and res["fd_error"] > 0

    class Stretch:
        def step(self, x, mu=None, dt=None):
            return x * [1.001, 1.0]

    with pytest.raises(AssertionError, match=r"not symplectic.*finite-difference Jacobian: central differences, step"):
        assert_symplectic_step(Stretch(), np.ones((3, 2)))


# ------------------------------------------------------------------ d. dt, T and nt checked before any FOM solve
def test_projected_step_checked_before_any_solve_with_exact_numbers(small_fe_wave):
    fom, coords, space, train, RB = small_fe_wave

    class NoSolve(type(fom)):
        def solve(self, *args, **kwargs):  # pragma: no cover - reached only if the check comes too late
            raise AssertionError("the FOM was solved before dt was checked")

    bare = fom.with_(new_type=NoSolve)
    with pytest.raises(
        ValueError,
        match=r"h = T / nt = 0\.5 / 100 = 0\.005; dt = 0\.012 is 2\.4 output steps: use "
        r"dt = k \* h, e\.g\. 0\.01 or 0\.015",
    ):
        SymplecticKernelReductor(bare, RB, 0.012, ProjectedTrajectories(train))
    with pytest.raises(ValueError, match=r"horizon = 0\.75 is past the FOM's final time T = 0\.5"):
        SymplecticKernelReductor(bare, RB, 0.01, ProjectedTrajectories(train, horizon=0.75))
    with pytest.raises(ValueError, match=r"dt = 0\.6 is longer than the sampled time span"):
        SymplecticKernelReductor(bare, RB, 0.6, ProjectedTrajectories(train))


# ------------------------------------------------------------------ j. log messages say what happened
def test_greedy_divergence_message_does_not_claim_truncating_to_zero_centres():
    from sympredict.interpolation.greedy.loop import _divergence_message

    zero = _divergence_message("greedy", 1, 0, 5.0, 1.0)
    assert "truncating to 0" not in zero and "keeps no centres" in zero and "duplicate samples" in zero
    assert "round-off" not in zero  # one centre has no Newton-basis round-off to blame
    some = _divergence_message("greedy", 40, 37, 5.0, 1e-6)
    assert "keeping the first 37 centres" in some and "power_tol" in some


def test_finite_element_howto_runs():
    """The how-to's code blocks, run in order as a user would (its ROM error is small)."""
    import re
    from pathlib import Path

    text = (Path(__file__).resolve().parents[2] / "docs" / "howto" / "finite_element_models.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.S)
    assert len(blocks) == 3
    namespace = {}
    for code in blocks:
        exec(compile(code, "finite_element_models.md", "exec"), namespace)
    assert namespace["error"] < 0.1
    assert namespace["q"].shape == (len(namespace["U"]), namespace["coords"].N)
    assert type(namespace["reductor"].samples).__name__ == "GivenTrajectories"
    assert namespace["rom_from_saved"].solve(0.95) is not None


# ------------------------------------------------------------------ g. a Newton failure keeps the trajectory so far
def test_newton_failure_in_rom_solve_carries_the_trajectory_so_far(small_fe_wave, small_rom):
    from sympredict.exceptions import NewtonConvergenceError

    fom = small_fe_wave[0]
    red, rom = small_rom
    inner = rom.flow_map

    class FailsAtStep5:  # the learned map, whose Newton solve fails at macro step index 5
        def rollout(self, x0, n_steps, mu=None, dt=None):
            if n_steps > 5:
                raise NewtonConvergenceError([0], [1.0], step=5)
            return inner.rollout(x0, n_steps, mu=mu, dt=dt)

    failing = rom.with_(flow_map=FailsAtStep5())
    mu = fom.parameters.parse(0.9)
    with pytest.raises(NewtonConvergenceError) as info:
        failing.solve(mu)
    exc = info.value
    assert exc.completed_steps == 5 and exc.trajectory_kind == "reduced" and len(exc.trajectory) == 6
    np.testing.assert_array_equal(exc.trajectory.to_numpy(), rom.solve(mu).to_numpy()[:, :6])
    assert red.reconstruct(exc.trajectory).space == fom.solution_space


# ------------------------------------------------------------------ e/f. a generating function that exists; no unusable ROM
def test_default_predictor_switches_to_midpoint_where_type_ii_does_not_exist(small_fe_wave):
    fom, coords, space, train, RB = small_fe_wave
    samples = GalerkinSamples(train, n_samples=40, n_validation=1, parameter_space=space)
    red = SymplecticKernelReductor(fom, RB, 0.06, samples, DefaultEstimator(max_centers=100))
    rom = red.reduce()
    assert red.choice_["update"] == "midpoint" and "type II does not exist" in red.choice_["reason"]
    assert red.predictor_.update == "midpoint"
    assert np.all(np.isfinite(rom.solve(fom.parameters.parse(0.9)).to_numpy()))
    with pytest.raises(ValueError, match="neither generating function exists at dt = 0.25"):
        SymplecticKernelReductor(fom, RB, 0.25, samples, DefaultEstimator(max_centers=100)).reduce()
    ok = SymplecticKernelReductor(fom, RB, 0.01, samples, DefaultEstimator(max_centers=100))
    ok.training_data()
    assert ok.choice_["update"] == "symplectic_euler"


def test_reduce_never_returns_a_rom_that_cannot_step(small_fe_wave, small_rom):
    from sympredict.exceptions import NewtonConvergenceError

    red, _ = small_rom

    class Fails:
        def step(self, x, mu=None, dt=None):
            raise NewtonConvergenceError([0], [1.0])

    class NotFinite:
        def step(self, x, mu=None, dt=None):
            return np.full_like(np.atleast_2d(x), np.nan)

    for bad, why in ((Fails(), "Newton's method failed"), (NotFinite(), "not finite")):
        with pytest.raises(ValueError, match=f"cannot take one step.*{why}.*update='midpoint'.*smaller dt"):
            red._check_one_step(bad)
    red._check_one_step(red.flow_map_)  # the fitted map passes
