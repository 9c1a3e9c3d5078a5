"""One figure style for the package's figures (sympredict_paper.plotting), checked on rendered figures.

Each figure function is drawn on small synthetic data shaped like the runs' results; the test then
renders it as ``save`` does (``bbox_inches="tight"``) and compares the extents of every piece of text:
no two overlap, none lies outside the saved area, every axis label states a unit (``[...]``), and
every labelled curve of a known method has that method's colour (the same on every figure).
"""

import itertools
from types import SimpleNamespace

import numpy as np
import pytest

from sympredict_paper import plotting  # noqa: E402
from matplotlib.colors import to_rgba  # noqa: E402

T = np.linspace(0, 20, 201)
#: the scenario-B figures' titles as the runs write them (report.py): the longest titles the package draws
WHERE = "l=0.825 (extrapolated), dT=0.05365"
RNG = np.random.default_rng(0)


def _history(m=300):
    n = np.arange(m + 1)
    return SimpleNamespace(
        n_centers=n, train_max_residual=np.exp(-n / 40.0) + 1e-9, val_max_residual=1.2 * np.exp(-n / 40.0) + 1e-9
    )


def _traj(phase=0.0):
    return np.column_stack([np.cos(T + phase), -np.sin(T + phase)])


def _speed_rows():
    rows = []
    for method, needs, sizes in (
        ("kernel predictor", "only data", (100, 200, 400, 800, 1500)),
        ("direct kernel model", "only data", (100, 200, 400)),
        ("implicit midpoint", "equations", (1, 2, 4, 8)),
        ("VKOGA", "only data", (150,)),
    ):
        for k, size in enumerate(sizes):
            # the direct model's points lie close to the kernel predictor's: their tags must not collide
            shift = 1.3 if method.startswith("direct") else 1.0
            rows.append(
                {
                    "method": method,
                    "needs": needs,
                    "size": size,
                    "time_per_trajectory_s": 1e-4 * (k + 1) * 2.0,
                    "median_err": shift * 10.0 ** (-2 - k),
                }
            )
    rows.append(
        {
            "method": "micro-step reference (implicit midpoint, h<=1e-3)",
            "needs": "equations",
            "size": 1,
            "tag": "h<=1e-3",
            "time_per_trajectory_s": 3e-3,
            "median_err": 3e-5,
        }
    )
    return rows


FIGURES = {
    "greedy_residuals": lambda: plotting.greedy_residuals({"": _history()}, "Pendulum scenario A: f-greedy residuals"),
    "error_over_time": lambda: plotting.error_over_time(
        [
            {"t": T, "values": 1e-5 * (1 + T), "label": f"kernel, dT={dt}", "style": s, "marker": m}
            for dt, s, m in ((0.1, "-", "o"), (0.05, "--", "s"))
        ]
        + [
            {"t": T, "values": 1e-2 * (1 + T), "label": f"implicit midpoint, dT={dt}", "style": s, "marker": m}
            for dt, s, m in ((0.1, "-", "o"), (0.05, "--", "s"))
        ],
        "Wave, full space, after reconstruction: error vs micro-step reference (mean over test speeds)",
        time_unit="1",
    ),
    "phase_portrait": lambda: plotting.phase_portrait(
        {"reference": _traj(), "symplectic kernel model": _traj(1e-3), "direct kernel model": _traj(3e-2)},
        f"Scenario B phase portrait, {WHERE}",
        t=T,
    ),
    "energy_error": lambda: plotting.energy_error(
        T,
        {"symplectic kernel model": 1e-4 * (1.1 + np.sin(T)), "direct kernel model": 1e-3 * (1 + T)},
        f"Scenario B relative Hamiltonian error, {WHERE}",
    ),
    "trajectories_over_time": lambda: plotting.trajectories_over_time(
        T,
        {"reference": _traj(), "symplectic kernel model": _traj(1e-3), "direct kernel model": _traj(3e-2)},
        f"Scenario B trajectory, {WHERE}",
    ),
    "hamiltonian_over_time": lambda: plotting.hamiltonian_over_time(
        T,
        {"reference": 2 + 0 * T, "symplectic kernel model": 2 + 1e-4 * np.sin(T), "direct kernel model": 2 + 1e-3 * T},
        f"Scenario B Hamiltonian, {WHERE}",
    ),
    "speed_accuracy": lambda: plotting.speed_accuracy(_speed_rows(), 3e-3, "Pendulum: speed against accuracy, dT=0.05"),
    "stability_sweeps": lambda: plotting.stability_sweeps(
        [
            {"dt": dt, "kernel predictor": 1e-4 * dt / 0.05, "direct kernel model": 1e-3, "implicit midpoint": 1e-2}
            for dt in (0.02, 0.04, 0.05, 0.06, 0.1)
        ],
        [
            {"mu": mu, "kernel predictor": 1e-4, "direct kernel model": 1e-3, "implicit midpoint": 1e-2}
            for mu in (0.65, 0.7, 0.75, 0.8, 0.85)
        ],
        (0.04, 0.06),
        (0.7, 0.8),
        "Pendulum: stability in dT",
    ),
    "solution_snapshots": lambda: plotting.solution_snapshots(
        np.linspace(0, 1, 50),
        [0.0, 1.0, 2.0],
        {
            "FOM": np.sin(np.outer([1, 2, 3], np.linspace(0, 3, 50))),
            "kernel ROM": np.sin(np.outer([1, 2, 3], np.linspace(0, 3, 50))) + 1e-2,
        },
        "2n=8",
    ),
    "cost_against_n": lambda: plotting.cost_against_n(
        [
            {"N": n, "label": f"{what}, 2n={d}", "time": 1e-4 * n * (d / 4)}
            for n in (100, 200, 400)
            for what in ("Galerkin RK4", "kernel, FOM data")
            for d in (4, 8)
        ],
        "Sine-Gordon: online cost against N",
    ),
}


def _drawn_tick_labels(axis):
    lo, hi = sorted(axis.get_view_interval())
    span = hi - lo
    for tick in axis.get_major_ticks() + axis.get_minor_ticks():
        if lo - 1e-9 * span <= tick.get_loc() <= hi + 1e-9 * span:  # matplotlib draws only the ticks in view
            yield from (tick.label1, tick.label2)


def _texts(fig):
    """Every drawn, non-empty text of a rendered figure (titles, axis and tick labels, legends, annotations,
    figure texts) with its extent in display units."""
    renderer = fig.canvas.get_renderer()
    candidates = list(fig.texts)
    for ax in fig.axes:
        candidates += [
            ax.title,
            ax._left_title,
            ax._right_title,
            ax.xaxis.label,
            ax.yaxis.label,
            *ax.texts,
            *_drawn_tick_labels(ax.xaxis),
            *_drawn_tick_labels(ax.yaxis),
        ]
        if ax.get_legend() is not None:
            candidates += ax.get_legend().get_texts() + [ax.get_legend().get_title()]
    found = []
    for t in candidates:
        if t.get_visible() and t.get_text().strip() and t.get_alpha() != 0:
            bbox = t.get_window_extent(renderer)
            if bbox.width > 0 and bbox.height > 0:
                found.append((t, bbox))
    return found


@pytest.fixture(params=sorted(FIGURES))
def figure(request):
    fig = FIGURES[request.param]()
    fig.canvas.draw()
    yield fig
    plotting.plt.close(fig)


def test_no_text_overlaps_another_or_leaves_the_saved_area(figure):
    renderer = figure.canvas.get_renderer()
    saved = figure.get_tightbbox(renderer).transformed(figure.dpi_scale_trans)  # what bbox_inches="tight" keeps
    texts = _texts(figure)
    outside = [
        t.get_text()
        for t, b in texts
        if b.x0 < saved.x0 - 1 or b.x1 > saved.x1 + 1 or b.y0 < saved.y0 - 1 or b.y1 > saved.y1 + 1
    ]
    assert not outside, outside
    overlaps = [
        (a.get_text(), b.get_text())
        for (a, ba), (b, bb) in itertools.combinations(texts, 2)
        if ba.overlaps(bb) and ba.intersection(ba, bb).width > 1 and ba.intersection(ba, bb).height > 1
    ]
    assert not overlaps, overlaps
    # nor does a text of a panel run under a legend box it does not belong to
    for ax in figure.axes:
        legend = ax.get_legend()
        if legend is None:
            continue
        box, own = legend.get_window_extent(renderer), {id(t) for t in legend.get_texts()}
        under = [
            t.get_text()
            for t, b in texts
            if id(t) not in own
            and t is not legend.get_title()
            and box.overlaps(b)
            and box.intersection(box, b).width > 1
            and box.intersection(box, b).height > 1
        ]
        assert not under, under


def test_every_axis_label_fits_beside_its_axes(figure):
    """An axis label longer than its axis runs past the panel into the title or off the saved image."""
    renderer = figure.canvas.get_renderer()
    too_long = []
    for ax in figure.axes:
        box = ax.get_window_extent(renderer)
        for label, extent, room in ((ax.xaxis.label, "width", box.width), (ax.yaxis.label, "height", box.height)):
            if label.get_text() and getattr(label.get_window_extent(renderer), extent) > room:
                too_long.append(label.get_text())
    assert not too_long, too_long


def test_every_axis_label_states_a_unit(figure):
    labels = [label for ax in figure.axes for label in (ax.get_xlabel(), ax.get_ylabel()) if label]
    assert labels and all("[" in label and "]" in label for label in labels), labels


def test_every_method_has_its_colour_on_every_figure(figure):
    for ax in figure.axes:
        for line in ax.get_lines():
            label = line.get_label()
            if label.startswith("_"):
                continue
            known = any(k in label.lower() for keys, _ in plotting.METHOD_COLORS for k in keys)
            if known:
                assert to_rgba(line.get_color()) == to_rgba(plotting.method_color(label)), label


def test_the_kernel_model_is_orange_and_the_reference_dark_everywhere():
    assert plotting.method_color("symplectic kernel model") == plotting.method_color("kernel predictor") == "tab:orange"
    assert plotting.method_color("kernel, dT=0.1") == "tab:orange"
    assert plotting.method_color("direct kernel model") == "tab:green"
    assert plotting.method_color("implicit midpoint, dT=0.05") == "tab:blue"
    assert plotting.method_color("reference flow") == plotting.method_color("FOM") == "0.15"


def test_the_speed_chart_explains_only_the_markers_it_draws():
    fig = FIGURES["speed_accuracy"]()
    title = fig.axes[0].get_title()
    plotting.plt.close(fig)
    assert "only data" in title and "equations" in title and "reduced operator" not in title
