"""Every figure of ``sympredict-paper run all`` exists and shows the data the results report.

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
    assert (
        m[-1] == p["n_centers"]
        and train[-1] == pytest.approx(p["E_train"], rel=1e-12)
        and val[-1] == pytest.approx(p["E_val"], rel=1e-12)
    )
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
        assert np.median(kernel) == pytest.approx(r["kernel_median_err"], rel=1e-12) and kernel.max() == pytest.approx(
            r["kernel_max_err"], rel=1e-12
        )
        assert np.median(im) == pytest.approx(r["im_median_err"], rel=1e-12) and im.max() == pytest.approx(
            r["im_max_err"], rel=1e-12
        )
    (ax,) = _figure(out, "pendulum_energy_error")
    _, kernel = _line(ax, "kernel predictor")
    _, im = _line(ax, "implicit midpoint, macro step")
    assert kernel.max() == pytest.approx(p["per_dt"][0]["kernel_max_energy_err"], rel=1e-12)
    assert im.max() == pytest.approx(p["per_dt"][0]["im_max_energy_err"], rel=1e-12)
    plane, distance = _figure(
        out, "pendulum_phase_portrait"
    )  # the phase plane, and each method's distance to the reference
    methods = [line for line in plane["lines"] if not line["label"].startswith("_")]  # '_initial state': the marker
    starts = [(line["x"][0], line["y"][0]) for line in methods]
    assert len(starts) == 3 and len(set(starts)) == 1 and starts[0][1] == 0.0  # one initial state (q0, 0) for all
    assert distance["yscale"] == "log" and len(distance["lines"]) == 2


def test_speed_accuracy_figures_show_the_table_rows(smoke_run):
    out, results, _ = smoke_run
    for name, sa in (
        ("pendulum_speed_accuracy", results["results"]["pendulum"]["speed_accuracy"]),
        ("wave_speed_accuracy", results["results"]["wave"]["speed_accuracy"]),
    ):
        (ax,) = _figure(out, name)
        assert ax["xscale"] == ax["yscale"] == "log"
        methods = dict.fromkeys(r["method"] for r in sa["rows"])
        for method in methods:
            rows = [r for r in sa["rows"] if r["method"] == method]
            t, e = _line(ax, method)
            np.testing.assert_allclose(t, [r["time_per_trajectory_s"] for r in rows], rtol=1e-12)
            np.testing.assert_allclose(e, [r["median_err"] for r in rows], rtol=1e-12)
    wave_methods = {r["method"] for r in results["results"]["wave"]["speed_accuracy"]["rows"]}
    assert {
        "FOM micro-step reference",
        "FOM implicit midpoint",
        "ROM implicit midpoint (compiled)",
        "ROM exact propagator (expm)",
        "ROM + kernel predictor",
    } <= wave_methods


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
    plane, distance = _figure(out, "pendulum_b_phase_portrait")
    assert {line["label"] for line in plane["lines"] if not line["label"].startswith("_")} == {
        "reference",
        "symplectic kernel",
        "direct kernel",
    }
    assert {line["label"] for line in distance["lines"]} == {"symplectic kernel", "direct kernel"}
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


# ----------------------------------------------------------------------------------------------------------------
# Readability of the figures, from small synthetic results (no run): what is drawn on top, the axis limits, labels.

from pathlib import Path  # noqa: E402
from types import SimpleNamespace  # noqa: E402

import matplotlib  # noqa: E402

matplotlib.use("Agg")


def _render(fig):
    """Draw the figure with Agg into PNG bytes (layout computed as in the docs) and close it."""
    import io

    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=60)
    plt.close(fig)
    assert buf.getvalue()[:4] == b"\x89PNG"


def _history(n=300, seed=0, with_val=True):
    rng = np.random.default_rng(seed)
    m = np.arange(n + 1)
    train = 10.0 * (m + 1.0) ** -2 * np.exp(0.1 * rng.standard_normal(n + 1))
    val = train * 1.05 if with_val else None
    return SimpleNamespace(n_centers=m, train_max_residual=train, val_max_residual=val)


@pytest.mark.parametrize("n_histories", [1, 3])
def test_greedy_residuals_draw_the_validation_line_on_top_and_visible(n_histories):
    from sympredict_paper import plotting

    labels = [""] if n_histories == 1 else [f", dT={dt}" for dt in (0.1, 0.05, 0.025)]
    fig = plotting.greedy_residuals({lab: _history(seed=i) for i, lab in enumerate(labels)}, "greedy")
    (ax,) = fig.axes
    lines = {line.get_label(): line for line in ax.get_lines()}
    ylo, yhi = ax.get_ylim()
    for lab in labels:
        train, val = lines[f"training{lab}"], lines[f"validation{lab}"]
        assert val.get_zorder() > max(
            line.get_zorder() for line in ax.get_lines() if line.get_label().startswith("training")
        )
        assert val.get_visible() and val.get_alpha() in (None, 1.0) and val.get_linewidth() > train.get_linewidth()
        assert val.get_linestyle() != train.get_linestyle()
        y = val.get_ydata()
        assert ylo <= y.min() and y.max() <= yhi  # inside the axes, not clipped away
        if n_histories == 1:
            assert val.get_color() != train.get_color()
    assert ax.get_xlabel() and ax.get_ylabel() and ax.get_title() == "greedy"
    _render(fig)


def test_greedy_residuals_without_validation_draw_only_training():
    from sympredict_paper import plotting

    fig = plotting.greedy_residuals({"": _history(with_val=False)}, "greedy")
    assert [line.get_label() for line in fig.axes[0].get_lines()] == ["training"]
    _render(fig)


def test_error_over_time_y_axis_stops_at_a_floor_above_round_off():
    """One round-off value (1e-17) must not pull the log axis down to 1e-16: the bulk decides, above a floor."""
    from sympredict_paper import plotting

    t = np.linspace(0, 6, 121)
    kernel = 1e-6 * (1 + t)
    kernel[5] = 1e-17  # a single step that happens to hit the reference
    im = 1e-3 * (1 + t)
    curves = [
        {"t": t, "values": kernel, "label": "kernel, dT=0.05", "style": "-", "color": 0},
        {"t": t, "values": im, "label": "implicit midpoint, dT=0.05", "style": "--", "color": 0},
    ]
    fig = plotting.error_over_time(curves, "wave")
    (ax,) = fig.axes
    lo, hi = ax.get_ylim()
    assert ax.get_yscale() == "log"
    assert lo >= plotting.ERROR_FLOOR and lo <= 1e-6 and hi >= im.max()
    assert 1e-7 < lo  # the bulk of the kernel curve (>= 1e-6) sets the bottom, not the dip
    assert ax.get_xlabel() and ax.get_ylabel() and ax.get_title() == "wave"
    _render(fig)
    # every value at round-off: then that is what the figure shows, inside the axes
    flat = [{"t": t, "values": np.full_like(t, 1e-17), "label": "exact", "style": "-", "color": 0}]
    fig = plotting.error_over_time(flat, "exact")
    lo, hi = fig.axes[0].get_ylim()
    assert lo < 1e-17 < hi
    _render(fig)


def test_phase_portrait_tells_the_methods_apart_at_a_glance():
    from sympredict_paper import plotting

    t = np.linspace(0.0, 20.0, 401)
    ref = np.column_stack([np.cos(2 * t), -2 * np.sin(2 * t)])
    kernel = ref + 1e-4 * np.column_stack([np.sin(t), np.cos(t)])
    im = np.column_stack([np.cos(2.01 * t), -2.01 * np.sin(2.01 * t)])
    trajs = {"reference": ref, "kernel predictor": kernel, "implicit midpoint, macro step": im}
    fig = plotting.phase_portrait(trajs, "Phase portrait, l=0.794", t=t)
    plane, dist = fig.axes
    lines = {line.get_label(): line for line in plane.get_lines()}
    assert [lab for lab in lines if not lab.startswith("_")] == list(trajs)  # the phase plane: one line per method
    ref_line = lines["reference"]
    # the reference is a wide band under the methods, which are drawn on top with markers
    for lab in ("kernel predictor", "implicit midpoint, macro step"):
        assert lines[lab].get_zorder() > ref_line.get_zorder() and lines[lab].get_marker() not in (None, "None", "")
        assert ref_line.get_linewidth() >= 3 * lines[lab].get_linewidth()
    np.testing.assert_array_equal(lines["kernel predictor"].get_xdata(), kernel[:, 0])
    assert "[rad]" in plane.get_xlabel() and "[" in plane.get_ylabel() and "l=0.794" in plane.get_title()
    # the second panel: distance to the reference, which separates 1e-4 from 1e-1 at once
    assert dist.get_yscale() == "log" and "[s]" in dist.get_xlabel() and dist.get_ylabel() and dist.get_title()
    d = {line.get_label(): line.get_ydata() for line in dist.get_lines()}
    assert set(d) == {"kernel predictor", "implicit midpoint, macro step"}
    np.testing.assert_allclose(d["kernel predictor"], np.linalg.norm(kernel - ref, axis=1)[1:], rtol=1e-12)
    assert np.median(d["implicit midpoint, macro step"]) > 100 * np.median(d["kernel predictor"])
    lo, hi = dist.get_ylim()
    assert lo <= d["kernel predictor"].min() * 1.01 and hi >= d["implicit midpoint, macro step"].max()
    _render(fig)


def test_phase_portrait_without_times_is_one_panel():
    from sympredict_paper import plotting

    ref = np.column_stack([np.cos(np.linspace(0, 6, 50)), np.sin(np.linspace(0, 6, 50))])
    fig = plotting.phase_portrait({"reference": ref, "kernel": ref * 1.01}, "pp")
    assert len(fig.axes) == 1
    _render(fig)


def _suite():
    import importlib.util

    spec = importlib.util.spec_from_file_location(
        "suite_for_tests", Path(__file__).resolve().parents[2] / "sympredict_paper" / "studies" / "suite.py"
    )
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_performance_scaling_figure_is_readable_at_page_width():
    suite = _suite()
    ms = [100, 200, 400, 800, 1500]
    scaling = {
        "rollout_vs_centers": {"m": ms, "s_per_traj_step": [3e-6 * (m / 100) ** 0.8 for m in ms], "exponent": 0.8},
        "rollout_vs_batch": {
            "batch": [1, 10, 100, 1000],
            "s_per_traj_step": [3.6e-5, 2.4e-5, 2.5e-5, 2.7e-5],
            "exponent_total_time": 0.96,
        },
        "newton_vs_dim": {
            "dim": [2, 4, 10, 20, 40],
            "numba_implicit_step_s": [2e-5, 4e-5, 1e-4, 3e-4, 1e-3],
            "numba_gradient_s_per_point": [2e-5, 2e-5, 4e-5, 6e-5, 1e-4],
            "numpy_newton_terms_s_per_point": [5e-5, 9e-5, 1.3e-4, 2.2e-4, 4e-4],
        },
        "greedy_step_vs_N": {
            "N": [30000, 60000, 120000, 289704],
            "m": 300,
            "s_per_step": [8e-3, 9e-3, 2e-2, 5e-2],
            "exponent": 0.8,
        },
        "greedy_step_vs_m": {
            "N": 289704,
            "m": [50, 100, 200, 400, 600, 800],
            "s_per_step": [0.015, 0.02, 0.04, 0.07, 0.09, 0.13],
            "exponent": 0.79,
        },
    }
    fig = suite.draw_scaling(scaling)
    visible = [ax for ax in fig.axes if ax.get_visible()]
    assert len(visible) == 5
    width, height = fig.get_size_inches()
    assert width <= 10.5  # shown at the page width: a wider figure shrinks its text below reading size
    rows = {round(ax.get_position().y0, 2) for ax in visible}
    assert len(rows) == 2  # two rows of panels, not one strip
    for ax in visible:
        assert ax.get_title() and ax.get_xlabel() and "[s]" in ax.get_ylabel()
        assert ax.get_xscale() == ax.get_yscale() == "log"
        assert min(label.get_fontsize() for label in ax.get_xticklabels()) >= 8
        assert all("slope" in text.get_text() for text in ax.get_legend().get_texts())
    _render(fig)
