"""Every figure of ``sympredict run all`` exists and shows the data the results report.

``plotting.save`` writes next to each figure the data it draws (``name.json``):
titles, axis labels and scales, and every labelled line.  These tests read
those files and compare the drawn curves with the numbers in ``results.json``,
so a figure that plots the wrong array, an empty axis or a missing method fails.
"""

import json

import numpy as np
import pytest


def _figure(out, name):
    assert (out / f"{name}.png").stat().st_size > 1000 and (out / f"{name}.pdf").stat().st_size > 1000
    data = json.loads((out / f"{name}.json").read_text())
    assert any(ax["title"] for ax in data["axes"]), f"{name}: no title"
    for ax in data["axes"]:
        # panels stacked on a shared time axis carry the x label once, at the bottom
        assert ax["ylabel"] and ax["lines"], f"{name}: unlabelled or empty panel"
        for line in ax["lines"]:
            assert line["label"] and len(line["x"]) == len(line["y"]) >= 1
    assert data["axes"][-1]["xlabel"], f"{name}: no x label"
    return data["axes"]


def _line(ax, label):
    matches = [line for line in ax["lines"] if line["label"] == label]
    assert len(matches) == 1, f"no single line labelled {label!r} in {[l['label'] for l in ax['lines']]}"
    return np.array(matches[0]["x"], dtype=float), np.array(matches[0]["y"], dtype=float)


def test_every_listed_figure_has_its_data(smoke_run):
    out, results, _ = smoke_run
    names = sorted({f.rsplit(".", 1)[0] for f in results["figures"]})
    assert len(names) == 15
    for name in names:
        _figure(out, name)


def test_greedy_residual_figures_end_at_the_reported_residuals(smoke_run):
    out, results, _ = smoke_run
    p = results["results"]["pendulum"]
    (ax,) = _figure(out, "pendulum_greedy_residuals")
    assert ax["xscale"] == ax["yscale"] == "log"
    m, train = _line(ax, "training")
    _, val = _line(ax, "validation")
    assert m[-1] == p["n_centers"] and train[-1] == pytest.approx(p["E_train"], rel=1e-12) and val[-1] == pytest.approx(p["E_val"], rel=1e-12)
    (ax,) = _figure(out, "wave_greedy_residuals")
    for r in results["results"]["wave"]["per_dt"]:
        m, train = _line(ax, f"training, dT={r['dt']}")
        assert m[-1] == r["n_centers"] and train[-1] == pytest.approx(r["E_train"], rel=1e-12)


def test_pendulum_error_and_energy_figures_show_the_reported_errors(smoke_run):
    out, results, _ = smoke_run
    p = results["results"]["pendulum"]
    (ax,) = _figure(out, "pendulum_error_over_time")
    assert ax["yscale"] == "log"
    for r in p["per_dt"]:
        t, kernel = _line(ax, f"kernel, dT={r['dt']}")
        _, im = _line(ax, f"implicit midpoint, dT={r['dt']}")
        np.testing.assert_allclose(np.diff(t), r["dt"], rtol=1e-9)
        assert t[-1] <= p["preset"]["horizon"] + 1e-9
        assert np.median(kernel) == pytest.approx(r["kernel_median_err"], rel=1e-12) and kernel.max() == pytest.approx(r["kernel_max_err"], rel=1e-12)
        assert np.median(im) == pytest.approx(r["im_median_err"], rel=1e-12) and im.max() == pytest.approx(r["im_max_err"], rel=1e-12)
    (ax,) = _figure(out, "pendulum_energy_error")
    _, kernel = _line(ax, "kernel predictor")
    _, im = _line(ax, "implicit midpoint, macro step")
    assert kernel.max() == pytest.approx(p["per_dt"][0]["kernel_max_energy_err"], rel=1e-12)
    assert im.max() == pytest.approx(p["per_dt"][0]["im_max_energy_err"], rel=1e-12)
    (ax,) = _figure(out, "pendulum_phase_portrait")
    starts = [(line["x"][0], line["y"][0]) for line in ax["lines"]]
    assert len(starts) == 3 and len(set(starts)) == 1 and starts[0][1] == 0.0  # one initial state (q0, 0) for all


def test_speed_accuracy_figures_show_the_table_rows(smoke_run):
    out, results, _ = smoke_run
    for name, sa in (("pendulum_speed_accuracy", results["results"]["pendulum"]["speed_accuracy"]),
                     ("wave_speed_accuracy", results["results"]["wave"]["speed_accuracy"])):
        (ax,) = _figure(out, name)
        assert ax["xscale"] == ax["yscale"] == "log"
        methods = dict.fromkeys(r["method"] for r in sa["rows"])
        for method in methods:
            rows = [r for r in sa["rows"] if r["method"] == method]
            t, e = _line(ax, method)
            np.testing.assert_allclose(t, [r["time_per_trajectory_s"] for r in rows], rtol=1e-12)
            np.testing.assert_allclose(e, [r["median_err"] for r in rows], rtol=1e-12)
    wave_methods = {r["method"] for r in results["results"]["wave"]["speed_accuracy"]["rows"]}
    assert {"FOM micro-step reference", "FOM implicit midpoint", "ROM implicit midpoint (compiled)", "ROM exact propagator (expm)",
            "ROM + kernel predictor"} <= wave_methods


def test_scenario_b_figures(smoke_run):
    out, results, _ = smoke_run
    b = results["results"]["pendulum"]["scenario_b"]
    (ax,) = _figure(out, "pendulum_b_error_over_time")
    for r in b["per_dt"]:
        _, sym = _line(ax, f"symplectic kernel, dT={r['dt']}")
        _, direct = _line(ax, f"direct kernel, dT={r['dt']}")
        assert np.median(sym) == pytest.approx(r["symplectic_median_err"], rel=1e-12)
        assert np.median(direct) == pytest.approx(r["direct_median_err"], rel=1e-12)
    q_ax, p_ax = _figure(out, "pendulum_b_trajectories")
    for ax in (q_ax, p_ax):
        t, _ = _line(ax, "reference")
        np.testing.assert_allclose(np.diff(t), b["dt_example"], rtol=1e-9)
    _, q_ref = _line(q_ax, "reference")
    assert q_ref[0] == pytest.approx(b["q0_example"])
    (ax,) = _figure(out, "pendulum_b_phase_portrait")
    assert {line["label"] for line in ax["lines"]} == {"reference", "symplectic kernel", "direct kernel"}
    (ax,) = _figure(out, "pendulum_b_hamiltonian")
    _, h_ref = _line(ax, "reference")
    _, h_sym = _line(ax, "symplectic kernel")
    assert np.abs(h_sym - h_sym[0]).max() / abs(h_sym[0]) == pytest.approx(b["max_rel_energy_err_symplectic"], rel=1e-9)
    (ax,) = _figure(out, "pendulum_b_energy_error")
    assert ax["yscale"] == "log"
    _, e_direct = _line(ax, "direct kernel")
    assert e_direct.max() == pytest.approx(b["max_rel_energy_err_direct"], rel=1e-12)


def test_stability_figure_marks_every_failure(smoke_run):
    out, results, _ = smoke_run
    st = results["results"]["pendulum"]["stability"]
    dt_ax, mu_ax = _figure(out, "pendulum_stability")
    for method in ("kernel", "implicit midpoint", "Stormer-Verlet"):
        ok = [(r["dt"], r[method]) for r in st["dt_sweep"] if isinstance(r[method], float)]
        failed = [r["dt"] for r in st["dt_sweep"] if not isinstance(r[method], float)]
        if ok:
            x, y = _line(dt_ax, method)
            np.testing.assert_allclose(np.column_stack([x, y]), ok, rtol=1e-12)
        labels = [line["label"] for line in dt_ax["lines"]]
        if failed:
            x, _ = _line(dt_ax, f"{method}: failed")
            np.testing.assert_allclose(x, failed)
        else:
            assert f"{method}: failed" not in labels
    x, y = _line(mu_ax, "kernel")
    np.testing.assert_allclose(np.column_stack([x, y]), [(r["mu"], r["kernel"]) for r in st["mu_sweep"]], rtol=1e-12)


def test_wave_error_figures_average_the_reported_cases(smoke_run):
    out, results, _ = smoke_run
    w = results["results"]["wave"]
    for space in ("red", "full"):
        (ax,) = _figure(out, f"wave_error_over_time_{space}")
        for r in w["per_dt"]:
            _, kernel = _line(ax, f"kernel, dT={r['dt']}")
            _, im = _line(ax, f"implicit midpoint, dT={r['dt']}")
            assert kernel.mean() == pytest.approx(np.mean([c[f"mean_kernel_{space}"] for c in r["cases"]]), rel=1e-9)
            assert im.mean() == pytest.approx(np.mean([c[f"mean_im_{space}"] for c in r["cases"]]), rel=1e-9)
