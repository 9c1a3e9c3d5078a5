"""Independent oracles for the published numbers and figures of the pendulum scenarios.

A small end-to-end run (seconds) of scenarios A and B; the test recomputes the
test instances, a reference solution (scipy's DOP853 on the pendulum ODE written
out here, g = 9.81), implicit midpoint at the macro step (its own fixed-point
solver) and the error measures, and compares them with what the experiment
returns, with every line the report's figures draw (read back from the
matplotlib ``Line2D`` objects), and with the JSON files of the CLI's smoke run.
"""

import json

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from sympredict import DirectKernelPredictor, SymplecticKernelPredictor
from sympredict_paper import report
from sympredict_paper.pendulum import DT_EXTRAPOLATION, MU_EXTRAPOLATION, PendulumPreset, run_scenario_a, run_scenario_b

G = 9.81
TINY = PendulumPreset(n_grid=12, max_centers=80, n_val=60, horizon=1.0, n_grid_b=10, max_centers_b=60, select=False)
SEED = 3


# ------------------------------------------------------------------ separate code: instances, reference, midpoint, errors
def _instances(seed):
    """The paper's test set, written out: 5 q0 ~ U[0, pi/2] (p0 = 0) x 5 lengths ~ U[0.7, 0.8], q0-major."""
    rng = np.random.default_rng(seed)
    q0 = rng.uniform(0.0, np.pi / 2, 5)
    lengths = rng.uniform(0.7, 0.8, 5)
    return np.array([[q, 0.0] for q in q0 for _ in lengths]), np.array([l for _ in q0 for l in lengths])


def _rhs(_, y, lengths):
    q, p = y.reshape(2, -1)
    return np.concatenate([p / lengths**2, -G * lengths * np.sin(q)])


def _reference(x0, lengths, dt, n_steps):
    """Exact flow to ~1e-11 (DOP853) on the macro grid, shape (B, K+1, 2)."""
    t = dt * np.arange(n_steps + 1)
    sol = solve_ivp(
        _rhs,
        (0, t[-1]),
        np.concatenate([x0[:, 0], x0[:, 1]]),
        method="DOP853",
        t_eval=t,
        rtol=1e-12,
        atol=1e-12,
        args=(lengths,),
    )
    b = len(x0)
    return np.stack([sol.y[:b], sol.y[b:]], axis=-1)


def _midpoint(x0, lengths, dt, n_steps):
    """Implicit midpoint at the macro step, fixed-point iteration to round-off, shape (B, K+1, 2)."""
    traj = [x0.copy()]
    x = x0.copy()
    for _ in range(n_steps):
        y = x.copy()
        for _ in range(200):
            m = (x + y) / 2
            new = x + dt * np.column_stack([m[:, 1] / lengths**2, -G * lengths * np.sin(m[:, 0])])
            if np.abs(new - y).max() <= 1e-15:
                y = new
                break
            y = new
        x = y
        traj.append(x)
    return np.stack(traj, axis=1)


def _energy(x, lengths):
    return x[..., 1] ** 2 / (2 * lengths**2) + G * lengths * (1 - np.cos(x[..., 0]))


def _rel_err(pred, ref):
    return np.sqrt(((pred - ref) ** 2).sum(-1)) / np.sqrt((ref**2).sum(-1))


def _lines(fig):
    """{panel index: {label: (x, y)}} read back from the figure's Line2D objects."""
    return {
        i: {
            line.get_label(): (np.asarray(line.get_xdata(), float), np.asarray(line.get_ydata(), float))
            for line in ax.get_lines()
            if not line.get_label().startswith("_")
        }
        for i, ax in enumerate(fig.axes)
    }


# ------------------------------------------------------------------ runs
@pytest.fixture(scope="module")
def scenario_a():
    return run_scenario_a(TINY, seed=SEED)


@pytest.fixture(scope="module")
def scenario_b():
    return run_scenario_b(TINY, seed=SEED)


@pytest.fixture(scope="module")
def recomputed_a(scenario_a):
    """Per test step: the independently computed trajectories of every method."""
    x0, lengths = _instances(SEED)
    out = []
    for r in scenario_a["per_dt"]:
        dt = r["dt"]
        n_steps = int(np.floor(TINY.horizon / dt + 1e-9))
        out.append(
            {
                "dt": dt,
                "n_steps": n_steps,
                "ref": _reference(x0, lengths, dt, n_steps),
                "im": _midpoint(x0, lengths, dt, n_steps),
                "kernel": scenario_a["model"].rollout(x0, n_steps, mu=lengths, dt=dt),
            }
        )
    return out


def test_scenario_a_errors_recomputed_from_the_trajectories(scenario_a, recomputed_a):
    assert [r["dt"] for r in scenario_a["per_dt"]] == list(TINY.dt_test)
    x0, lengths = _instances(SEED)
    for r, mine, row in zip(scenario_a["per_dt"], recomputed_a, scenario_a["summary"]["per_dt"]):
        np.testing.assert_allclose(r["t"], r["dt"] * np.arange(mine["n_steps"] + 1), rtol=1e-12)
        e_kernel = _rel_err(mine["kernel"], mine["ref"]).mean(axis=0)
        e_im = _rel_err(mine["im"], mine["ref"]).mean(axis=0)
        # the experiment's reference is micro-step implicit midpoint (h <= 1e-3): ~1e-6 from the exact flow
        assert np.abs(e_im[1:] - e_kernel[1:]).min() > 1e-4  # the two methods' errors differ far beyond that
        np.testing.assert_allclose(r["err_kernel"], e_kernel, rtol=1e-3, atol=1e-5)
        np.testing.assert_allclose(r["err_im"], e_im, rtol=1e-3, atol=1e-5)
        for key, traj in (("energy_kernel", mine["kernel"]), ("energy_im", mine["im"])):
            e = _energy(traj, lengths[:, None])
            np.testing.assert_allclose(r[key], (np.abs(e - e[:, :1]) / e[:, :1]).mean(axis=0), rtol=1e-6, atol=1e-12)
        assert r["energy_ref"].max() < 1e-6  # the reference conserves energy
        # the published table: medians and maxima over t > 0, and their ratio
        assert row["kernel_median_err"] == pytest.approx(np.median(e_kernel[1:]), rel=1e-3)
        assert row["kernel_max_err"] == pytest.approx(e_kernel[1:].max(), rel=1e-3)
        assert row["im_median_err"] == pytest.approx(np.median(e_im[1:]), rel=1e-3)
        assert row["im_max_err"] == pytest.approx(e_im[1:].max(), rel=1e-3)
        assert row["ratio_median"] == pytest.approx(np.median(e_im[1:]) / np.median(e_kernel[1:]), rel=2e-3)
        assert row["ratio_min_over_time"] == pytest.approx((e_im[1:] / e_kernel[1:]).min(), rel=2e-3)
    s = scenario_a["summary"]
    assert s["n_centers"] == scenario_a["model"].n_centers_ == TINY.max_centers
    assert s["E_train"] == scenario_a["model"].history_.train_max_residual[-1]


def test_scenario_a_figures_draw_the_recomputed_trajectories(scenario_a, recomputed_a):
    figs = report.pendulum_a_figures(scenario_a)
    assert list(figs) == [
        "pendulum_greedy_residuals",
        "pendulum_error_over_time",
        "pendulum_phase_portrait",
        "pendulum_energy_error",
    ]
    x0, lengths = _instances(SEED)
    lines = _lines(figs["pendulum_error_over_time"])[0]
    assert len(lines) == 2 * len(recomputed_a)
    for mine in recomputed_a:
        t = mine["dt"] * np.arange(mine["n_steps"] + 1)
        for label, traj in (
            (f"kernel, dT={mine['dt']}", mine["kernel"]),
            (f"implicit midpoint, dT={mine['dt']}", mine["im"]),
        ):
            x, y = lines[label]
            np.testing.assert_allclose(x, t[1:], rtol=1e-12)
            np.testing.assert_allclose(y, _rel_err(traj, mine["ref"]).mean(axis=0)[1:], rtol=1e-3, atol=1e-5)
    # the phase portrait: the last test instance at the first test step, every method under its own label
    mine = recomputed_a[0]
    lines = _lines(figs["pendulum_phase_portrait"])[0]
    assert set(lines) == {"reference (implicit midpoint, h<=1e-3)", "kernel predictor", "implicit midpoint, macro step"}
    for label, traj, tol in (
        ("reference (implicit midpoint, h<=1e-3)", mine["ref"][-1], 1e-5),
        ("kernel predictor", mine["kernel"][-1], 1e-12),
        ("implicit midpoint, macro step", mine["im"][-1], 1e-9),
    ):
        q, p = lines[label]
        np.testing.assert_allclose(np.column_stack([q, p]), traj, atol=tol, err_msg=label)
    assert f"l={lengths[-1]:.3f}" in figs["pendulum_phase_portrait"].axes[0].get_title()
    lines = _lines(figs["pendulum_energy_error"])[0]
    for label, traj in (("kernel predictor", mine["kernel"]), ("implicit midpoint, macro step", mine["im"])):
        e = _energy(traj, lengths[:, None])
        np.testing.assert_allclose(
            lines[label][1], (np.abs(e - e[:, :1]) / e[:, :1]).mean(axis=0)[1:], rtol=1e-6, atol=1e-12
        )
    m, e_train = _lines(figs["pendulum_greedy_residuals"])[0]["training"]
    np.testing.assert_array_equal(e_train, scenario_a["history"].train_max_residual[1:])


def test_scenario_b_models_and_figures_recomputed(scenario_b):
    models = scenario_b["models"]
    assert type(models["symplectic"]) is SymplecticKernelPredictor and type(models["direct"]) is DirectKernelPredictor
    x0, _ = _instances(SEED)
    x0 = x0[::5]  # the 5 distinct q0
    dt, mu = DT_EXTRAPOLATION, MU_EXTRAPOLATION
    n_steps = int(np.floor(TINY.horizon / dt + 1e-9))
    x_ex = x0[:1]
    with pytest.warns(Warning):  # extrapolation in mu, by design
        mine = {
            "symplectic": models["symplectic"].rollout(x_ex, n_steps, mu=mu, dt=dt)[0],
            "direct": models["direct"].rollout(x_ex, n_steps, mu=mu, dt=dt)[0],
        }
    mine["reference"] = _reference(x_ex, np.array([mu]), dt, n_steps)[0]
    assert np.abs(mine["symplectic"] - mine["direct"]).max() > 1e-6  # the two models are told apart
    sb = scenario_b["summary"]
    assert (
        sb["mu"] == 0.825 and sb["dt_example"] == 0.05365 and sb["q0_example"] == pytest.approx(x_ex[0, 0], rel=1e-15)
    )
    t = dt * np.arange(n_steps + 1)
    figs = report.pendulum_b_figures(scenario_b)
    labels = {"reference": "reference", "symplectic kernel": "symplectic", "direct kernel": "direct"}
    tol = {"reference": 1e-5, "symplectic": 1e-12, "direct": 1e-12}
    q_panel, p_panel = _lines(figs["pendulum_b_trajectories"]).values()
    portrait = _lines(figs["pendulum_b_phase_portrait"])[0]
    energy = _lines(figs["pendulum_b_hamiltonian"])[0]
    energy_err = _lines(figs["pendulum_b_energy_error"])[0]
    for label, key in labels.items():
        traj = mine[key]
        np.testing.assert_allclose(q_panel[label][0], t, rtol=1e-12)
        np.testing.assert_allclose(q_panel[label][1], traj[:, 0], atol=tol[key], err_msg=label)
        np.testing.assert_allclose(p_panel[label][1], traj[:, 1], atol=tol[key], err_msg=label)
        np.testing.assert_allclose(np.column_stack(portrait[label]), traj, atol=tol[key], err_msg=label)
        h = _energy(traj, mu)
        np.testing.assert_allclose(energy[label][1], h, rtol=1e-6, err_msg=label)
        # the experiment's reference (micro-step midpoint) keeps the energy to ~1e-8, DOP853 to ~1e-11
        atol = 1e-7 if key == "reference" else 1e-12
        np.testing.assert_allclose(
            energy_err[label][1], (np.abs(h - h[0]) / h[0])[1:], rtol=1e-6, atol=atol, err_msg=label
        )
        if key != "reference":
            assert sb[f"max_rel_energy_err_{key}"] == pytest.approx((np.abs(h - h[0]) / h[0]).max(), rel=1e-6)
    # error curves over time for the paper's 5 q0, every test step
    lines = _lines(figs["pendulum_b_error_over_time"])[0]
    for r, row in zip(scenario_b["per_dt"], sb["per_dt"]):
        k = int(np.floor(TINY.horizon / r["dt"] + 1e-9))
        ref = _reference(x0, np.full(5, mu), r["dt"], k)
        with pytest.warns(Warning):
            for key in ("symplectic", "direct"):
                err = _rel_err(models[key].rollout(x0, k, mu=mu, dt=r["dt"]), ref).mean(axis=0)
                np.testing.assert_allclose(lines[f"{key} kernel, dT={r['dt']}"][1], err[1:], rtol=1e-3, atol=1e-5)
                assert row[f"{key}_median_err"] == pytest.approx(np.median(err[1:]), rel=1e-3)


def test_claims_follow_the_numbers():
    def results(ratio, pointwise, ds, dd, wave_ratio):
        return {
            "pendulum": {
                "per_dt": [{"dt": 0.05, "ratio_median": ratio, "ratio_min_over_time": pointwise}],
                "scenario_b": {
                    "energy_drift_symplectic": ds,
                    "energy_drift_direct": dd,
                    "max_rel_energy_err_symplectic": 1e-3,
                    "max_rel_energy_err_direct": 1e-1,
                },
            },
            "wave": {"per_dt": [{"dt": 0.1, "cases": [{"ratio_red": wave_ratio}, {"ratio_red": 50.0}]}]},
        }

    holds = [c["holds"] for c in report.claims(results(100.0, 1.01, 1e-4, -1e-3, 1.01))]
    assert holds == [True, True, True]
    assert [c["holds"] for c in report.claims(results(99.9, 2.0, 1e-4, 0.99e-3, 0.99))] == [False, False, False]
    assert [c["holds"] for c in report.claims(results(500.0, 1.0, 0.0, 0.0, 1.0))] == [False, True, False]
    assert report.ratio(123.4) == "123x" and report.ratio(3.456) == "3.5x"


def test_smoke_run_phase_portrait_is_the_saved_models_rollout(smoke_run):
    """End to end through the CLI: the saved model's rollout is the line labelled 'kernel predictor'."""
    out, results, _ = smoke_run
    p = results["results"]["pendulum"]
    data = json.loads((out / "pendulum_phase_portrait.json").read_text())
    lines = {line["label"]: np.column_stack([line["x"], line["y"]]) for line in data["axes"][0]["lines"]}
    x0, lengths = _instances(p["seed"])
    dt = p["per_dt"][0]["dt"]
    n_steps = int(np.floor(p["preset"]["horizon"] / dt + 1e-9))
    model = SymplecticKernelPredictor.load(out / "pendulum_model.h5")
    np.testing.assert_allclose(
        lines["kernel predictor"], model.rollout(x0[-1], n_steps, mu=lengths[-1], dt=dt), atol=1e-12
    )
    np.testing.assert_allclose(
        lines["reference (implicit midpoint, h<=1e-3)"], _reference(x0[-1:], lengths[-1:], dt, n_steps)[0], atol=1e-5
    )
    np.testing.assert_allclose(
        lines["implicit midpoint, macro step"], _midpoint(x0[-1:], lengths[-1:], dt, n_steps)[0], atol=1e-9
    )
