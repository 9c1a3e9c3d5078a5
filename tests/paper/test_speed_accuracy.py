"""Speed-against-accuracy charts (issue 13): every chart holds the methods a user chooses between, the figure
draws the results file's rows, and the rows' errors agree with an independent recomputation.

The pendulum and wave charts come from the session's ``sympredict-paper run all --preset smoke``
(``smoke_run``); the Hénon–Heiles chart from ``sympredict-paper run henon-heiles --preset smoke`` (about 10 s).
"""

import json

import numpy as np
import pytest

from sympredict_paper import report
from sympredict_paper import speed
from sympredict_paper.peers import VKOGAFlowMap
from sympredict.symplectic.integrators_compiled import HAVE_NUMBA, rollout
from sympredict.symplectic.metrics import relative_trajectory_error

CLASSICAL = ("Stormer-Verlet (compiled)", "Yoshida-4 (compiled)", "Kahan-Li-6 (compiled)")


@pytest.fixture(scope="module")
def hh_run(tmp_path_factory):
    import contextlib
    import io

    from sympredict_paper.cli import main

    out = tmp_path_factory.mktemp("hh_smoke")
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["run", "henon-heiles", "--preset", "smoke", "--out", str(out), "--threads", "1"]) == 0
    return out, json.loads((out / "results.json").read_text())


def _charts(smoke_run, hh_run):
    _, results, _ = smoke_run
    hh_out, hh = hh_run
    return {
        "pendulum": (smoke_run[0], "pendulum_speed_accuracy", results["results"]["pendulum"]["speed_accuracy"]),
        "wave": (smoke_run[0], "wave_speed_accuracy", results["results"]["wave"]["speed_accuracy"]),
        "henon-heiles": (hh_out, "henon_heiles_speed_accuracy", hh["results"]["henon-heiles"]["speed_accuracy"]),
    }


def test_every_chart_has_the_methods_a_user_chooses_between(smoke_run, hh_run):
    for system, (_, _, sa) in _charts(smoke_run, hh_run).items():
        rows = sa["rows"]
        by = {}
        for r in rows:
            by.setdefault(r["method"], []).append(r)
            assert r["needs"] in speed.NEEDS.values() and r["time_per_trajectory_s"] > 0 and r["median_err"] > 0
        kernel = next(m for m in by if m.endswith("kernel predictor"))
        assert len({r["size"] for r in by[kernel]}) >= 3, system
        for method in CLASSICAL:
            assert len({r["size"] for r in by[method]}) >= 3, (system, method)
            assert all(r["needs"] == speed.NEEDS["equations"] for r in by[method])
        assert any("micro-step reference" in m for m in by), system
        assert any("direct kernel model" in m for m in by) and any("VKOGA" in m for m in by), system
        assert all(r["needs"] == speed.NEEDS["data"] for m in by if "VKOGA" in m or "kernel" in m for r in by[m])
        if system == "wave":
            (exact,) = by["ROM exact propagator (expm)"]
            assert exact["needs"] == speed.NEEDS["reduced operator"]


def test_charts_draw_the_results_rows(smoke_run, hh_run):
    for system, (out, name, sa) in _charts(smoke_run, hh_run).items():
        data = json.loads((out / f"{name}.json").read_text())
        (ax,) = data["axes"]
        for method in dict.fromkeys(r["method"] for r in sa["rows"]):
            rows = [r for r in sa["rows"] if r["method"] == method]
            (line,) = [ln for ln in ax["lines"] if ln["label"] == method]
            np.testing.assert_allclose(line["x"], [r["time_per_trajectory_s"] for r in rows], rtol=1e-12)
            np.testing.assert_allclose(line["y"], [r["median_err"] for r in rows], rtol=1e-12)


def test_summary_table_lists_every_row_with_what_it_needs(hh_run):
    out, results = hh_run
    text = (out / "summary.md").read_text()
    for r in results["results"]["henon-heiles"]["speed_accuracy"]["rows"]:
        assert f"| {r['method']} | {r['needs']} |" in text
    assert "At the cost of the largest kernel model" in text or "No method with the equations is as cheap" in text


def test_henon_heiles_classical_errors_recomputed_against_the_step_halving_reference(hh_run):
    """The table's errors of the compiled schemes, recomputed against a different reference (the system's
    step-halving Kahan–Li-6 to 1e-11, not the chart's fixed dT/256 run)."""
    from sympredict_paper.henon_heiles import DT_HH, PRESETS, henon_heiles_test_instances
    from sympredict.systems.henon_heiles import HenonHeiles

    _, results = hh_run
    sa = results["results"]["henon-heiles"]["speed_accuracy"]
    preset = PRESETS["smoke"]
    system = HenonHeiles()
    x0, lam = henon_heiles_test_instances(system, preset.n_test, preset.energy_max, seed=0)
    ref = system.trajectory(x0, lam, DT_HH, sa["n_steps"])
    for r in sa["rows"]:
        if r["method"] == "Yoshida-4 (compiled)":
            traj = rollout(system, x0, lam, DT_HH, sa["n_steps"], scheme="yoshida4", substeps=r["size"])
            err = relative_trajectory_error(traj, ref).mean(axis=0)[1:]
            assert np.median(err) == pytest.approx(r["median_err"], rel=1e-6)


def test_time_median_excludes_the_warm_up_and_divides_by_the_batch():
    calls = []

    def run():
        calls.append(1)
        return len(calls)

    seconds, out = speed.time_median(run, repeats=3, batch=5)
    assert len(calls) == 4 and out == 4 and seconds >= 0


def test_a_models_row_is_sized_by_its_centres_and_needs_only_data():
    """``SpeedTable.add_model``: size and tag from ``n_centers_``, needs only data; a peer not fitted (``None``): no row."""
    exact = np.zeros((2, 4, 2))
    table = speed.SpeedTable(exact, repeats=1)

    class Fitted:
        n_centers_ = 7

    row = table.add_model("a model", Fitted(), lambda: exact + 1.0)
    assert (row["method"], row["size"], row["tag"], row["needs"]) == ("a model", 7, "m=7", "only data")
    assert table.add_model("not fitted", None, lambda: exact) is None and table.rows == [row]


@pytest.mark.skipif(not HAVE_NUMBA, reason="numba threads")
def test_deliberate_threads_sets_and_restores_numba_threads():
    import numba
    from threadpoolctl import threadpool_info

    before = numba.get_num_threads()
    with speed.deliberate_threads(1):
        assert numba.get_num_threads() == 1
        assert all(p["num_threads"] == 1 for p in threadpool_info())
    assert numba.get_num_threads() == before


def test_equal_cost_picks_the_most_accurate_classical_run_at_no_more_cost():
    eq, data = speed.NEEDS["equations"], speed.NEEDS["data"]
    sa = {
        "dt": 0.5,
        "n_trajectories": 4,
        "n_steps": 10,
        "repeats": 3,
        "rows": [
            {
                "method": "kernel predictor",
                "size": 100,
                "needs": data,
                "time_per_trajectory_s": 1.0,
                "median_err": 1e-2,
            },
            {
                "method": "kernel predictor",
                "size": 500,
                "needs": data,
                "time_per_trajectory_s": 2.0,
                "median_err": 1e-4,
            },
            {
                "method": "micro-step reference",
                "size": 0,
                "needs": eq,
                "time_per_trajectory_s": 0.5,
                "median_err": 1e-14,
            },
            {
                "method": "Yoshida-4 (compiled)",
                "size": 2,
                "needs": eq,
                "time_per_trajectory_s": 1.5,
                "median_err": 1e-6,
            },
            {
                "method": "Kahan-Li-6 (compiled)",
                "size": 8,
                "needs": eq,
                "time_per_trajectory_s": 3.0,
                "median_err": 1e-12,
            },
        ],
    }
    for r in sa["rows"]:
        r["max_err"] = 2 * r["median_err"]
    eq_cost = report.equal_cost(sa)
    # the micro-step reference needs the equations too, and here it is cheaper than the kernel
    assert eq_cost["kernel"]["size"] == 500 and eq_cost["classical"]["method"] == "micro-step reference"
    assert eq_cost["error_ratio"] == pytest.approx(1e-10)
    sa["rows"] = [r for r in sa["rows"] if r["method"] != "micro-step reference"]
    eq_cost = report.equal_cost(sa)
    assert eq_cost["classical"]["method"] == "Yoshida-4 (compiled)" and eq_cost["error_ratio"] == pytest.approx(1e-2)
    assert any("the kernel is 100x less accurate" in line for line in report.speed_accuracy_markdown(sa, ""))
    sa["rows"] = [r for r in sa["rows"] if r["method"] == "kernel predictor"] + [
        dict(sa["rows"][-1], time_per_trajectory_s=9.0)
    ]
    assert report.equal_cost(sa)["classical"] is None
    assert any("No method with the equations is as cheap" in line for line in report.speed_accuracy_markdown(sa, ""))


def test_vkoga_flow_map_interpolates_its_training_data():
    """With every sample a centre, pyMOR's VKOGA interpolates: the step reproduces x1 at the training states."""
    rng = np.random.default_rng(0)
    x0 = rng.uniform(-1, 1, (40, 2))
    mu = rng.uniform(0.5, 1.0, 40)
    x1 = x0 + 0.1 * np.column_stack([x0[:, 1], -mu * np.sin(x0[:, 0])])
    peer = VKOGAFlowMap(max_centers=40, length_scale=0.5, tol=0.0).fit(x0, x1, mu=mu, dt=np.full(40, 0.1))
    assert peer.n_centers_ == 40
    np.testing.assert_allclose(peer.step(x0, mu, 0.1), x1, atol=1e-6)
    traj = peer.rollout(x0[:3], 2, mu=mu[:3], dt=0.1)
    np.testing.assert_array_equal(traj[:, 1], peer.step(x0[:3], mu[:3], 0.1))
