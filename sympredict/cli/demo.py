"""``sympredict demo``: the README's example as one command (pendulum trajectories -> model -> rollout -> figure).

The data are made here: 40 pendulum trajectories of 50 steps of 0.1, one length each in [0.7, 0.8], the
stand-in for a user's trajectories in the README.  The model is the estimator with its defaults and
300 centres at most; it is rolled out 200 steps from ``(q, p) = (1, 0)`` at the length 0.75 and compared
with the exact flow.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

from sympredict.cli._console import _duration, _Working
from sympredict.cli._options import _add_verbose, _int_at_least

__all__ = ["add_parser", "run_demo", "demo_figure"]

#: The README example's sizes.
N_TRAJECTORIES, N_STEPS, DT, MAX_CENTERS, HORIZON_STEPS = 40, 50, 0.1, 300, 200
X_TEST, MU_TEST = (1.0, 0.0), 0.75


def run_demo(out, seed: int = 0) -> dict:
    """Train the README's model, roll it out and write ``model.h5``, ``demo.png``/``.pdf``/``.json``.

    Parameters
    ----------
    out : path
        An existing folder.
    seed : int
        Seed of the training trajectories.

    Returns
    -------
    dict
        ``max_state_error``, ``max_energy_drift`` (relative), ``n_centers``, ``fit_s``, ``files``.

    Notes
    -----
    About 10 s on 2 cores (docs/data/runtimes.json: demo).
    """
    import numpy as np

    from sympredict import SymplecticKernelPredictor, TrajectoryData
    from sympredict.cli import figure_style as plotting
    from sympredict.systems.pendulum import Pendulum

    out = Path(out)
    rng = np.random.default_rng(seed)
    pendulum = Pendulum()
    mu = rng.uniform(0.7, 0.8, size=N_TRAJECTORIES)
    x0 = np.column_stack([rng.uniform(-1.5, 1.5, N_TRAJECTORIES), rng.uniform(-1.0, 1.0, N_TRAJECTORIES)])
    states = pendulum.trajectory(x0, mu, dt=DT, n_steps=N_STEPS)
    t0 = time.perf_counter()
    model = SymplecticKernelPredictor(max_centers=MAX_CENTERS).fit(TrajectoryData(states, mu=mu, dt=DT))
    fit_s = time.perf_counter() - t0
    model.save(out / "model.h5")
    x_test = np.array([X_TEST])
    pred = model.rollout(x_test, n_steps=HORIZON_STEPS, mu=MU_TEST, dt=DT)[0]
    exact = pendulum.trajectory(x_test, MU_TEST, dt=DT, n_steps=HORIZON_STEPS)[0]
    H = pendulum.hamiltonian(pred, MU_TEST)
    H_exact = pendulum.hamiltonian(exact, MU_TEST)
    t = np.arange(HORIZON_STEPS + 1) * DT
    files = plotting.save(
        demo_figure(t, exact, pred, np.abs(H - H[0]) / abs(H[0]), np.abs(H_exact - H_exact[0]) / abs(H_exact[0])),
        out,
        "demo",
    )
    return {
        "max_state_error": float(np.abs(pred - exact).max()),
        "max_energy_drift": float(np.abs(H - H[0]).max() / abs(H[0])),
        "n_centers": int(model.n_centers_),
        "fit_s": fit_s,
        "files": ["model.h5", *files],
    }


def demo_figure(t, exact, pred, drift, drift_exact):
    """Left: the phase plane of the exact and the predicted trajectory; right: relative energy error over time."""
    import numpy as np

    from sympredict.cli import figure_style as plotting

    fig, (ax, bx) = plotting.plt.subplots(1, 2, figsize=(10, 4.2), constrained_layout=True)
    ax.plot(exact[:, 0], exact[:, 1], color=plotting.method_color("exact"), lw=6, alpha=0.35, label="reference flow")
    ax.plot(
        pred[:, 0],
        pred[:, 1],
        "--",
        color=plotting.method_color("symplectic kernel model"),
        lw=1.2,
        label="symplectic kernel model",
    )
    ax.plot([exact[0, 0]], [exact[0, 1]], "o", color="k", ms=5, label="initial state")
    plotting.decorate(
        ax,
        "angle $q$ [rad]",
        "angular momentum $p$ [kg m$^2$/s]",
        f"phase plane, length $l$ = {MU_TEST} m, {len(t) - 1} steps of {DT} s",
    )
    curves = (
        (drift, "symplectic kernel model", 1.2, "symplectic kernel model"),
        (drift_exact, "exact", 1.0, "reference flow (implicit midpoint, h = 1e-3 s)"),
    )
    for values, method, lw, label in curves:  # floored: a log axis has no zero
        bx.semilogy(t[1:], np.maximum(values[1:], 1e-17), color=plotting.method_color(method), lw=lw, label=label)
    plotting.decorate(
        bx, "time $t$ [s]", "relative energy error $|H(t) - H(0)| / H(0)$ [1]", "energy error stays bounded"
    )
    return fig


_DEMO_FILES = ("model.h5", "demo.png", "demo.pdf", "demo.json")


def _cmd_demo(args) -> int:
    """The README's example in one command: pendulum trajectories, a model, a rollout, a figure, one line."""
    from threadpoolctl import threadpool_limits

    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {str(out)!r} exists and is not a directory; give a folder")
    if out.is_dir():
        other = sorted(e.name for e in out.iterdir() if e.name not in _DEMO_FILES)
        if other:
            raise ValueError(
                f"--out {str(out)!r} holds other files than a demo's (e.g. {other[0]!r}); give a new or empty folder"
            )
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    with (
        threadpool_limits(limits=args.threads),
        _Working("sympredict demo: training on 40 pendulum trajectories", quiet=args.verbose),
    ):
        r = run_demo(out, seed=args.seed)
    print(
        f"demo: {r['n_centers']} centres trained in {r['fit_s']:.0f} s; over t = {HORIZON_STEPS * DT:g} s: max state "
        f"error {r['max_state_error']:.1e}, max relative energy drift {r['max_energy_drift']:.1e}; wrote "
        f"{out / 'model.h5'} and {out / 'demo.png'} ({_duration(time.perf_counter() - t0)})"
    )
    return 0


def add_parser(sub) -> None:
    """Register ``sympredict demo`` with the subparsers ``sub``."""
    demo = sub.add_parser(
        "demo",
        help="the README's example: train on pendulum trajectories, predict, write a model, "
        "a figure and a one-line result (seconds on 2 cores)",
    )
    demo.add_argument("--out", default="sympredict-demo", help="output folder (default: sympredict-demo)")
    demo.add_argument("--seed", type=_int_at_least(0), default=0, help="seed of the training trajectories (default 0)")
    demo.add_argument(
        "--threads", type=_int_at_least(1), default=os.cpu_count() or 1, help="BLAS threads (default: all cores)"
    )
    _add_verbose(demo)
    demo.set_defaults(func=_cmd_demo)
