"""Matplotlib figures of experiment results (no computation here)."""

from __future__ import annotations


from sympredict.cli.figure_style import (  # the figure style, shared with `sympredict demo`
    METHOD_COLORS,
    _decorate,
    decorate,
    figure_data,
    method_color,
    plt,
    save,
)

__all__ = [
    "method_color",
    "decorate",
    "METHOD_COLORS",
    "greedy_residuals",
    "error_over_time",
    "phase_portrait",
    "energy_error",
    "trajectories_over_time",
    "hamiltonian_over_time",
    "speed_accuracy",
    "stability_sweeps",
    "point_tag",
    "figure_data",
    "save",
]

_COLORS = plt.rcParams["axes.prop_cycle"].by_key()["color"]

#: Lowest y-limit of the error plots: relative errors below it are round-off, and a log axis that runs
#: down to 1e-16 for one such value squeezes the curves that matter into a strip.
ERROR_FLOOR = 1e-12


def _log_limits(ax, curves, floor: float = ERROR_FLOOR, decades: float = 9.0) -> None:
    """y-limits of a log axis from the data of ``curves`` (arrays): the bulk of the values, not single dips.

    The bottom is the largest of ``floor``, a third of the 1st percentile of the positive
    finite values, and ``decades`` decades below the top (three times the largest value).
    Values below the bottom are cut off.
    """
    import numpy as np

    vals = np.concatenate([np.asarray(c, dtype=float).ravel() for c in curves]) if curves else np.empty(0)
    vals = vals[np.isfinite(vals) & (vals > 0)]
    if vals.size == 0:
        return
    top = 3.0 * vals.max()
    bottom = max(floor, np.percentile(vals, 1) / 3.0, top * 10.0 ** (-decades))
    ax.set_ylim(min(bottom, top / 10.0), top)


def greedy_residuals(histories, title: str):
    """``E_train(m)`` (solid) and ``E_val(m)`` (dashed, drawn on top) against the number of centres, log-log.

    The validation residual follows the training one closely on a good model, so it is
    drawn above it (higher ``zorder``), thicker and dashed; with one history it also
    gets its own colour.

    Parameters
    ----------
    histories : dict
        Label -> :class:`~sympredict.interpolation.greedy.GreedyHistory` (one colour each).
    """
    fig, ax = plt.subplots(figsize=(6, 4.2))
    single = len(histories) == 1
    for i, (label, history) in enumerate(histories.items()):
        m = history.n_centers
        color = _COLORS[i % len(_COLORS)]
        ax.loglog(m[1:], history.train_max_residual[1:], "-", color=color, label=f"training{label}", lw=1.2, zorder=2)
        if history.val_max_residual is not None:
            ax.loglog(
                m[1:],
                history.val_max_residual[1:],
                color=_COLORS[1] if single else color,
                ls=(0, (4, 2)),
                label=f"validation{label}",
                lw=2.0,
                zorder=3,
            )
    _decorate(
        ax, "number of selected centres $m$ [1]", r"max state-gradient residual $\max|\partial_{\xi_l} e_m|$ [1]", title
    )
    return fig


def error_over_time(
    curves,
    title: str,
    ylabel: str = "mean relative error $e_{rel}(t)$ [1]",
    floor: float = ERROR_FLOOR,
    time_unit: str = "s",
):
    """Error curves over time, log scale, the y-axis bounded below by the data's bulk and ``floor``.

    Parameters
    ----------
    curves : list of dict
        Each with ``t``, ``values``, ``label``, ``style`` (``'-'`` or ``'--'``) and ``color`` index.
    floor : float
        Lowest y-limit (:func:`_log_limits`); values below it are round-off.
    """
    fig, ax = plt.subplots(figsize=(7, 4))
    for c in curves:
        ax.semilogy(
            c["t"][1:],
            c["values"][1:],
            c.get("style", "-"),
            color=method_color(c["label"], c.get("color", 0)),
            label=c["label"],
            lw=1.2,
            marker=c.get("marker"),
            markevery=max(1, len(c["t"]) // 12),
            ms=4,
        )
    _log_limits(ax, [c["values"][1:] for c in curves], floor)
    _decorate(ax, f"time $t$ [{time_unit}]", ylabel, title, legend_outside=True)
    return fig


def phase_portrait(trajectories, title: str, t=None):
    """Phase plane of a few trajectories and, given ``t``, their distance to the first one over time.

    Left: the ``(q, p)`` curves, the first (the reference) as a wide pale band under
    the others, which are drawn thin with a marker every few steps; a black dot marks
    the initial state.  Right (with ``t``): ``|x(t) - x_ref(t)|`` per method on a log
    axis, where curves that coincide in the phase plane are told apart at a glance.

    Parameters
    ----------
    trajectories : dict
        Label -> array (K+1, 2) of ``(q, p)``; the first entry is the reference.
    title : str
        Title of the phase-plane panel.
    t : array (K+1,), optional
        Times of the states; without it only the phase plane is drawn.
    """
    import numpy as np

    items = list(trajectories.items())
    fig, axes = plt.subplots(
        1,
        2 if t is not None else 1,
        figsize=(11, 4.5) if t is not None else (5.5, 4.8),
        constrained_layout=True,
        squeeze=False,
    )
    ax = axes[0, 0]
    n = len(items[0][1])
    for i, (label, traj) in enumerate(items):
        style = (
            dict(color=method_color(label, i), alpha=0.3, lw=6, solid_capstyle="round", zorder=1)
            if i == 0
            else dict(
                ls="-" if i == 1 else "--",
                color=method_color(label, i),
                lw=1.2,
                marker="os^v"[i % 4],
                ms=3.5,
                markevery=max(1, n // 25),
                zorder=2 + i,
            )
        )
        ax.plot(traj[:, 0], traj[:, 1], label=label, **style)
    q0 = items[0][1][0]
    ax.plot([q0[0]], [q0[1]], "o", color="k", ms=6, zorder=10, label="_initial state")
    _decorate(ax, "angle $q$ [rad]", "angular momentum $p$ [kg m$^2$/s]", title)
    if t is not None:
        ax = axes[0, 1]
        ref = np.asarray(items[0][1], dtype=float)
        dists = []
        for i, (label, traj) in enumerate(items[1:], start=1):
            d = np.linalg.norm(np.asarray(traj, dtype=float) - ref, axis=1)
            ax.semilogy(t[1:], d[1:], "-" if i == 1 else "--", color=method_color(label, i), label=label, lw=1.2)
            dists.append(d[1:])
        _log_limits(ax, dists)
        _decorate(
            ax,
            "time $t$ [s]",
            "distance to the reference $|x(t) - x_{ref}(t)|$ [1]",
            "distance to the reference in the phase plane",
        )
    return fig


def energy_error(t, curves, title: str, time_unit: str = "s"):
    """Relative Hamiltonian error ``|H(x_k) - H(x_0)| / |H(x_0)|`` over time; ``curves`` maps label -> values."""
    fig, ax = plt.subplots(figsize=(6, 4))
    for i, (label, values) in enumerate(curves.items()):
        ax.semilogy(t[1:], values[1:], color=method_color(label, i), label=label, lw=1.0)
    _decorate(ax, f"time $t$ [{time_unit}]", r"relative energy error $|H(t) - H(0)|\,/\,|H(0)|$ [1]", title)
    return fig


def trajectories_over_time(t, trajectories, title: str):
    """``q(t)`` and ``p(t)`` in two panels; ``trajectories`` maps a label to an array (K+1, 2)."""
    fig, axes = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
    for i, (label, traj) in enumerate(trajectories.items()):
        for ax, comp in zip(axes, (0, 1)):
            ax.plot(
                t,
                traj[:, comp],
                "-" if i == 0 else "--",
                color=method_color(label, i),
                label=label,
                lw=1.5 if i == 0 else 1.0,
            )
    axes[0].set_ylabel("angle $q(t)$ [rad]")
    axes[1].set_ylabel("momentum $p(t)$ [kg m$^2$/s]")
    axes[1].set_xlabel("time $t$ [s]")
    axes[0].set_title(title)
    for ax in axes:
        ax.grid(True, alpha=0.3)
    axes[0].legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    return fig


def hamiltonian_over_time(t, energies, title: str):
    """``H(x(t))`` along trajectories; ``energies`` maps a label to values (K+1,)."""
    fig, ax = plt.subplots(figsize=(6, 4))
    for i, (label, values) in enumerate(energies.items()):
        ax.plot(
            t, values, "-" if i == 0 else "--", color=method_color(label, i), label=label, lw=1.5 if i == 0 else 1.0
        )
    _decorate(ax, "time $t$ [s]", "Hamiltonian $H(q, p; l)$ [J]", title)
    return fig


def point_tag(row: dict) -> str:
    """Label of a speed-accuracy point: its ``tag``, else ``m=size`` for kernel methods and ``dT/size`` otherwise."""
    return row.get("tag") or (f"m={row['size']}" if "kernel" in row["method"] else f"dT/{row['size']}")


def speed_accuracy(rows, reference_time: float, title: str):
    """Median error over time against wall time per trajectory, one line per method, log-log.

    Parameters
    ----------
    rows : list of dict
        ``method``, ``size`` (centres or step refinement), ``time_per_trajectory_s``, ``median_err``,
        optionally ``tag`` (the point's annotation; default ``m=size`` for kernel methods, ``dT/size`` otherwise).
    reference_time
        Wall time per trajectory of the micro-step reference (a vertical line).
    """
    fig, ax = plt.subplots(figsize=(8.5, 5.0))
    methods, used, seen = list(dict.fromkeys(r["method"] for r in rows)), set(), {}
    t_max = max([reference_time] + [r["time_per_trajectory_s"] for r in rows])
    for i, method in enumerate(methods):
        pts = [r for r in rows if r["method"] == method]
        t = [r["time_per_trajectory_s"] for r in pts]
        e = [r["median_err"] for r in pts]
        # the marker says what the method needs: circles only data, squares the equations, triangles a reduced operator
        needs = pts[0].get("needs", "")
        marker = "o" if needs.startswith("only data") else "^" if needs.startswith("reduced") else "s"
        used.add(marker)
        color = method_color(method, i)
        repeat = seen[color] = seen.get(color, -1) + 1  # the same method again (another size): another marker face
        ax.loglog(
            t,
            e,
            marker + ("-" if len(pts) > 1 else ""),
            color=color,
            label=method,
            ms=5 if len(pts) > 1 else 8,
            mfc="none" if marker == "s" or repeat % 2 else None,
            mew=1.5 if repeat else 1.0,
        )
        # one tag per curve, at its most accurate point (tags at every point overlap where curves cross)
        best = min(pts, key=lambda r: r["median_err"] if r["median_err"] == r["median_err"] else float("inf"))
        tag = f"{point_tag(pts[0])} .. {point_tag(pts[-1])}" if len(pts) > 1 else point_tag(pts[0])
        # near the right edge of the (log) time axis the tag goes to the left of its point, inside the axes
        left = best["time_per_trajectory_s"] > t_max / 4
        ax.annotate(
            tag,
            (best["time_per_trajectory_s"], best["median_err"]),
            fontsize=6,
            xytext=(-4 if left else 4, -9),
            textcoords="offset points",
            color=color,
            ha="right" if left else "left",
            annotation_clip=True,
        )
    ax.axvline(reference_time, color=method_color("reference"), ls=":", label="micro-step reference (time)")
    # a relative error above 10 is a blown-up run (CFL): keep the axis on the runs that work, say so on the chart
    blown = [r for r in rows if not r["median_err"] <= 10]
    if blown:
        ax.set_ylim(top=30)
        ax.text(
            0.01,
            0.99,
            "off the chart (error > 10, unstable): " + ", ".join(f"{r['method']} {point_tag(r)}" for r in blown),
            transform=ax.transAxes,
            fontsize=6,
            va="top",
            wrap=True,
        )
    key = ", ".join(
        text
        for m, text in (("o", "o: only data"), ("s", "open square: equations"), ("^", "^: reduced operator"))
        if m in used
    )
    _decorate(
        ax,
        "wall time per trajectory [s]",
        "median over time of the mean relative error [1]",
        title + f"\n({key})",
        legend_outside=True,
    )
    return fig


def stability_sweeps(dt_rows, mu_rows, dt_train, mu_train, title: str):
    """Two panels: mean relative error against ``dT`` and against ``mu`` (log scale).

    Rows hold a float error per method or a string when the method failed; failures
    are drawn as crosses on the top edge.  The training ranges are shaded.
    """
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for ax, rows, key, train, xlabel in (
        (axes[0], dt_rows, "dt", dt_train, "macro step $\\Delta T$ [s]"),
        (axes[1], mu_rows, "mu", mu_train, "pendulum length $l$ [m]"),
    ):
        methods = [k for k in rows[0] if k not in (key, "solvability", "inside_training_box")]
        ax.axvspan(*train, color="0.9", label="training range")
        for i, method in enumerate(methods):
            ok = [(r[key], r[method]) for r in rows if isinstance(r[method], float)]
            bad = [r[key] for r in rows if not isinstance(r[method], float)]
            if ok:
                ax.semilogy(*zip(*ok), "o-", color=method_color(method, i), label=method, ms=4)
            if bad:
                # staggered per method so that failures at the same step stay visible
                ax.plot(
                    bad,
                    [1e1 * 2.0**i] * len(bad),
                    "x",
                    color=method_color(method, i),
                    ms=9,
                    mew=2,
                    label=f"{method}: failed",
                )
        ax.set_xscale("log" if key == "dt" else "linear")
        _decorate(
            ax, xlabel, "mean relative error over $[0, T]$ [1]", title if key == "dt" else "extrapolation in the length"
        )
    return fig


def solution_snapshots(x, times, solutions, title: str):
    """``u(x, t)`` at a few times, one panel per time; ``solutions`` maps a label to rows (len(times), N)."""
    fig, axes = plt.subplots(1, len(times), figsize=(4 * len(times), 3.5), sharey=True)
    axes = list(axes) if len(times) > 1 else [axes]
    for k, (ax, t) in enumerate(zip(axes, times)):
        for i, (label, rows) in enumerate(solutions.items()):
            ax.plot(
                x,
                rows[k],
                "-" if i == 0 else "--",
                color=method_color(label, i),
                label=label,
                lw=1.5 if i == 0 else 1.0,
            )
        ax.set_title(f"{title}, t = {t:g}")
        ax.set_xlabel("position $x$ [1]")
        ax.grid(True, alpha=0.3)
    axes[0].set_ylabel("$u(x, t)$ [1]")
    axes[-1].legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    return fig


def cost_against_n(rows, title: str):
    """Online wall time per trajectory against ``N``, log-log; ``rows``: ``N``, ``label``, ``time`` (one line per label)."""
    fig, ax = plt.subplots(figsize=(6, 4))
    labels = list(dict.fromkeys(r["label"] for r in rows))
    seen: dict = {}
    for i, label in enumerate(labels):
        pts = sorted((r["N"], r["time"]) for r in rows if r["label"] == label and r["time"] is not None)
        if pts:
            color = method_color(label, i)
            repeat = seen[color] = seen.get(color, -1) + 1  # the same method at another size: another line style
            ax.loglog(
                *zip(*pts), "os^v"[repeat % 4], ls=("-", "--", ":", "-.")[repeat % 4], color=color, label=label, ms=4
            )
    _decorate(ax, "full dimension $N$ (grid points) [1]", "wall time per trajectory [s]", title, legend_outside=True)
    return fig
