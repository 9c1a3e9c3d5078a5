"""The defaults-acceptance benchmark harness (sympredict_paper/studies/defaults_acceptance.py): its metrics and its JSON.

The metric code is checked against oracles: the exact flow scores round-off
error and conserves energy, the flow at a 2 % wrong step scores a large error;
the closed-form Kepler flow agrees with an RK4 reference and is symplectic
(finite-difference ``DPhi^T J DPhi = J``).
"""

import numpy as np
import pytest

from sympredict.symplectic.metrics import canonical_J
from sympredict.systems.flowmaps import HamiltonianSystem

from _studies import run_study, study_module  # tests/


@pytest.fixture(scope="module")
def da():
    with study_module("defaults_acceptance.py") as module:
        yield module


def test_quick_run_hand_only_writes_the_schema(tmp_path):
    data, stdout = run_study(
        "defaults_acceptance.py", tmp_path / "out.json", "--quick", "--systems", "kepler", "--configs", "hand"
    )
    assert "| hand |" in stdout
    assert set(data["systems"]) == {"kepler"}
    assert data["protocol"]["threads"] == {"blas": 1, "numba": 1}
    assert data["protocol"]["command"] and data["protocol"]["machine"]["numpy"]
    entry = data["systems"]["kepler"]
    assert set(entry["rows"]) == {"hand"} and entry["dt"] == 0.02 and entry["mu"]["unit"] == "AU^3/yr^2"
    row = entry["rows"]["hand"]
    assert row["ok"] is True and row["config"] == "hand"
    assert 0 < row["n_centers"] <= row["max_centers"] == 40
    for key in ("traj_error_median", "traj_error_max", "energy_error_median", "energy_error_max", "fit_time_s"):
        assert np.isfinite(row[key]) and row[key] >= 0, key
    assert row["traj_error_median"] <= row["traj_error_max"]
    assert row["traj_steps"] == 20 and row["energy_steps"] == 60
    assert row["settings"]["family"] in ("imq", "matern52") and len(row["settings"]["factors"]) == 2
    assert row["search"]["rounds"]  # the recorded search comes with the recorded settings


@pytest.mark.parametrize("name", ["coupled_pendulums", "fpu_chain", "kepler"])
def test_metrics_score_the_exact_flow_zero_and_a_wrong_one_large(da, name):
    bench = da.make_benchmarks()[name]
    test = da.make_test_set(bench, 3, 15, seed=11)
    exact = da.trajectory_metrics(da.ExactFlowModel(bench), bench, test, long_steps=30)
    assert exact["traj_error_max"] < 1e-9 and exact["energy_error_max"] < 1e-9
    wrong = da.trajectory_metrics(da.ExactFlowModel(bench, dt_factor=1.02), bench, test, long_steps=30)
    assert wrong["traj_error_median"] > 1e-3
    assert wrong["traj_error_median"] <= wrong["traj_error_max"]


def test_a_failing_model_is_a_recorded_result(da):
    bench = da.make_benchmarks()["kepler"]
    test = da.make_test_set(bench, 2, 5, seed=3)

    class Broken:
        def rollout(self, *a, **k):
            raise RuntimeError("Newton failed")

    out = da.trajectory_metrics(Broken(), bench, test, long_steps=10)
    assert "Newton failed" in out["traj_failure"] and "Newton failed" in out["energy_failure"]
    assert "traj_error_max" not in out


def test_samplers_stay_in_their_energy_sets_and_physical_ranges(da):
    benches = da.make_benchmarks()
    x, mu = benches["coupled_pendulums"].sample(500, 1)
    assert np.all(benches["coupled_pendulums"].system.hamiltonian(x, mu[:, None]) <= da.PEND_E)
    assert np.all((mu >= 0.5) & (mu <= 1.5)) and np.abs(x[:, :2]).max() < 1.4
    x, mu = benches["fpu_chain"].sample(500, 1)
    assert np.all(benches["fpu_chain"].system.hamiltonian(x, mu[:, None]) <= da.FPU_E)
    x, mu = benches["kepler"].sample(500, 1)
    energy = da.kepler_H(x, mu[:, None])
    a = -mu / (2 * energy)  # semi-major axis from the energy
    np.testing.assert_array_less(1 - 1e-12, a)
    np.testing.assert_array_less(a, 2 + 1e-12)
    assert np.all(x[:, 0] * x[:, 3] - x[:, 1] * x[:, 2] > 0)  # prograde


def test_kepler_flow_against_rk4_and_symplectic(da):
    bench = da.make_benchmarks()["kepler"]
    x0, mu = bench.sample(20, 2)
    rk4 = HamiltonianSystem(da.kepler_H, da.kepler_grad, 4, parameters={"GM": 1}, rtol=1e-12)
    for t in (0.02, 0.7):
        np.testing.assert_allclose(da.kepler_flow(x0, mu, t), rk4.flow(x0, mu[:, None], t), rtol=0, atol=1e-9)
    jac = bench.system.flow_jacobian(x0, mu[:, None], 0.3)
    J = canonical_J(4)
    defect = np.abs(np.swapaxes(jac, 1, 2) @ J @ jac - J).max()
    assert defect / np.abs(jac).max() ** 2 < 1e-7  # central differences: O(h^2) of the entries' scale
    wrong = jac.copy()
    wrong[:, 0, 0] *= 1.01  # a 1 % error in one entry is visible
    assert np.abs(np.swapaxes(wrong, 1, 2) @ J @ wrong - J).max() / np.abs(jac).max() ** 2 > 1e-4
