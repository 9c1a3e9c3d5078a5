"""Does growing the model make it worse? The planar restricted three-body problem at several centre budgets.

The case: planar circular restricted three-body problem in the rotating frame
(:mod:`sympredict.systems.three_body`), mass ratio in [0.010, 0.014], tadpole
librations near L4 (:func:`~sympredict.systems.three_body.librating_states`),
``dT = 0.05``, ``--traj`` trajectories x ``--traj-steps`` steps of training data.

Two modes:

* ``--sizes M1 M2 ...`` (default): one ``SymplecticKernelPredictor(max_centers=--max-centers)`` fit (by default
  on the samples), and its prefixes (``truncated(m)``: the greedy's model after ``m`` centres, equal to a fit
  with ``max_centers=m`` and no prefix selection to round-off) scored at each ``m``; results under ``"sizes"``.
* ``--centers C1 C2 ...``: one fit per budget ``max_centers=C`` (what a user gets asking for ``C`` centres);
  results under ``"fits"``.  ``--data trajectories`` (default) gives the fit a
  :class:`~sympredict.data.TrajectoryData`: it holds whole trajectories out and keeps the prefix whose
  rollouts on them are best; ``--data samples`` gives the same data as samples (:class:`~sympredict.data.FlowMapData`):
  it holds samples out and keeps the prefix with the best held-out one-step error.  ``--state-eps``,
  ``--factors``, ``--mu-eps`` give the kernels (no search); then ``--holdout-traj`` trajectories are held out
  as ``validation`` (trajectories or their samples, as ``--data``; without prefix scoring the samples mode is
  the plain greedy).

Each model is scored

* **inside the data**: ``--n-val`` unseen whole trajectories from the training
  distribution, as long as the training trajectories: median and 90th percentile of
  the relative one-step error over all their pairs, and the error at their last step
  (a rollout over the training horizon);
* **beyond the data**: ``--n-test`` trajectories rolled out ``--steps`` steps (longer
  than the training trajectories): relative error at the last step (median, maximum),
  the share of their states outside the training box, and the relative Jacobi-constant
  drift over ``--long-steps`` steps (median, maximum);
* the smallest Newton pivot (power function of the selected centre) up to ``m``.

Run:  python sympredict_paper/studies/three_body_growth.py            # writes docs/data/three_body_growth.json
      python -m sympredict_paper.studies.three_body_growth --traj 300 --centers 1000 2000 4000 --json OUT.json
"""

from __future__ import annotations

import argparse
import logging
import re
import time
import warnings
from pathlib import Path

import numpy as np

try:
    import _protocol  # sympredict_paper/studies/ (the script's folder is on sys.path)
except ImportError:  # python -m sympredict_paper.studies.three_body_growth
    from sympredict_paper.studies import _protocol

from sympredict import SymplecticKernelPredictor
from sympredict.data import TrajectoryData
from sympredict.exceptions import ExtrapolationWarning
from sympredict.kernels import IMQ
from sympredict.kernels.transforms import Scaled
from sympredict.systems.three_body import MU_RANGE, ThreeBody, librating_states

RESULTS = Path(__file__).resolve().parents[2] / "docs" / "data" / "three_body_growth.json"


def trajectories(tb, n, seed, steps, dt):
    rng = np.random.default_rng(seed)
    mu = rng.uniform(*MU_RANGE, n)
    return tb.trajectory(librating_states(mu, n, seed=seed + 1), mu, dt, steps), mu


def score(model, tb, val, test, args, dt) -> dict:
    (vt, vmu), (tt, tmu) = val, test
    k = vt.shape[1] - 1
    x1 = model.step(vt[:, :-1].reshape(-1, 4), mu=np.repeat(vmu, k), dt=dt)
    inc = np.linalg.norm(vt[:, 1:] - vt[:, :-1], axis=2).reshape(-1)
    one = np.linalg.norm(x1 - vt[:, 1:].reshape(-1, 4), axis=1) / inc
    roll = model.rollout(vt[:, 0], k, mu=vmu, dt=dt)
    inside = np.linalg.norm(roll[:, -1] - vt[:, -1], axis=1) / np.linalg.norm(vt[:, -1], axis=1)
    out = {
        "inside_one_step_median": float(np.median(one)),
        "inside_one_step_p90": float(np.quantile(one, 0.9)),
        "inside_rollout_median": float(np.median(inside)),
        "inside_rollout_max": float(inside.max()),
    }
    pred = model.rollout(tt[:, 0], args.steps, mu=tmu, dt=dt)
    rel = np.linalg.norm(pred[:, -1] - tt[:, -1], axis=1) / np.linalg.norm(tt[:, -1], axis=1)
    lo, hi = model.domain_["x_min"], model.domain_["x_max"]
    out.update(
        beyond_median=float(np.median(rel)),
        beyond_max=float(rel.max()),
        beyond_share_outside_box=float(np.mean(np.any((tt < lo) | (tt > hi), axis=2))),
    )
    long = model.rollout(tt[:, 0], args.long_steps, mu=tmu, dt=dt, stride=10)
    c = tb.jacobi_constant(long.reshape(-1, 4), np.repeat(tmu, long.shape[1])).reshape(len(tmu), -1)
    drift = np.abs(c - c[:, :1]).max(axis=1) / np.abs(c[:, 0])
    out.update(drift_median=float(np.median(drift)), drift_max=float(drift.max()))
    return out


def estimator(args, max_centers: int) -> SymplecticKernelPredictor:
    """The defaults, or the kernels given by ``--state-eps`` / ``--factors`` / ``--mu-eps`` (no search)."""
    if args.state_eps is None:
        return SymplecticKernelPredictor(max_centers=max_centers)
    return SymplecticKernelPredictor(
        Scaled(IMQ(args.state_eps), factors=tuple(args.factors)),
        mu_kernel=IMQ(args.mu_eps),
        update="symplectic_euler",
        max_centers=max_centers,
    )


def fit_data(args, traj, mu, dt):
    """``(data, validation)`` for ``fit``: trajectories or their samples (``--data``); with given kernels the
    first ``--holdout-traj`` trajectories are the validation data."""
    val = None
    if args.state_eps is not None and args.holdout_traj:
        h = args.holdout_traj
        val, traj, mu = TrajectoryData(traj[:h], mu[:h], dt=dt), traj[h:], mu[h:]
    data = TrajectoryData(traj, mu, dt=dt)
    if args.data == "samples":
        data, val = data.pairs(), None if val is None else val.pairs()
    return data, val


class _RolloutCost(logging.Handler):
    """Collects the seconds the fit spent scoring its prefixes' rollouts (the predictor's INFO log)."""

    def __init__(self):
        super().__init__(logging.INFO)
        self.seconds = None

    def emit(self, record):
        m = re.search(r"held-out rollouts scored \d+ prefixes in ([0-9.]+) s", record.getMessage())
        if m:
            self.seconds = float(m.group(1))


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--max-centers", type=int, default=1600, help="the budget of the --sizes mode's one fit")
    p.add_argument(
        "--sizes",
        type=int,
        nargs="+",
        default=[200, 400, 800, 1600],
        help="prefixes of one fit to score (the default mode)",
    )
    p.add_argument(
        "--centers",
        type=int,
        nargs="+",
        default=None,
        help="one fit per budget max_centers=C instead of prefixes (results under 'fits')",
    )
    p.add_argument(
        "--data",
        choices=("trajectories", "samples"),
        default=None,
        help="how fit receives the data (default: trajectories with --centers, samples with --sizes)",
    )
    p.add_argument("--state-eps", type=float, default=None, help="a given IMQ state kernel shape (no search)")
    p.add_argument("--factors", type=float, nargs="+", default=[0.8, 1.21], help="its Scaled factors")
    p.add_argument("--mu-eps", type=float, default=20.0, help="a given IMQ parameter kernel shape")
    p.add_argument(
        "--holdout-traj", type=int, default=30, help="with given kernels: trajectories held out as validation (0: none)"
    )
    p.add_argument("--traj", type=int, default=100)
    p.add_argument("--traj-steps", type=int, default=60)
    p.add_argument("--n-val", type=int, default=20)
    p.add_argument("--n-test", type=int, default=20)
    p.add_argument("--steps", type=int, default=200)
    p.add_argument("--long-steps", type=int, default=2000)
    p.add_argument("--seed", type=int, default=0)
    _protocol.add_arguments(p, threads=1, json_default=str(RESULTS))
    args = p.parse_args(argv)
    args.data = args.data or ("trajectories" if args.centers else "samples")
    warnings.simplefilter("ignore", ExtrapolationWarning)
    tb, dt = ThreeBody(), 0.05
    traj, mu = trajectories(tb, args.traj, args.seed, args.traj_steps, dt)
    val = trajectories(tb, args.n_val, args.seed + 500, args.traj_steps, dt)
    test = trajectories(tb, args.n_test, args.seed + 1000, args.steps, dt)
    out = {"settings": {k: v for k, v in vars(args).items() if k != "json"}, "n_samples": args.traj * args.traj_steps}
    with _protocol.limits(args.blas_threads, numba_threads=args.threads):
        if args.centers:
            out["fits"] = {}
            for cap in args.centers:
                data, validation = fit_data(args, traj, mu, dt)
                cost, log = _RolloutCost(), logging.getLogger("sympredict.estimators.predictor")
                log.addHandler(cost)
                level, log.level = log.level, logging.INFO
                t0 = time.perf_counter()
                try:
                    model = estimator(args, cap).fit(data, validation=validation)
                finally:
                    log.removeHandler(cost)
                    log.setLevel(level)
                row = {
                    "fit_s": time.perf_counter() - t0,
                    "rollout_scoring_s": cost.seconds,
                    "n_centers": model.n_centers_,
                    "stop": model.history_.stop_reason,
                    "choice": {k: repr(v) for k, v in model.choice_.items()},
                    "prefix_errors": {str(k): v for k, v in (model.prefix_errors_ or {}).items()},
                    "prefix_rollout_errors": {
                        str(k): v for k, v in (getattr(model, "prefix_rollout_errors_", None) or {}).items()
                    },
                }
                print(
                    f"max_centers {cap}: fit {row['fit_s']:.0f} s, {model.n_centers_} centres ({row['stop']})",
                    flush=True,
                )
                row.update(score(model, tb, val, test, args, dt))
                row["min_pivot"] = float(model.history_.selected_power.min())
                out["fits"][str(cap)] = row
                print(cap, {k: f"{v:.2e}" for k, v in row.items() if isinstance(v, float)}, flush=True)
        else:
            data, validation = fit_data(args, traj, mu, dt)
            out["sizes"] = {}
            t0 = time.perf_counter()
            model = estimator(args, args.max_centers).fit(data, validation=validation)
            out.update(
                fit_s=time.perf_counter() - t0,
                n_centers=model.n_centers_,
                stop=model.history_.stop_reason,
                choice={k: repr(v) for k, v in model.choice_.items()},
                prefix_errors={str(k): v for k, v in (model.prefix_errors_ or {}).items()},
            )
            print(f"fit {out['fit_s']:.0f} s, {model.n_centers_} centres ({out['stop']})", flush=True)
            for m in args.sizes:
                if m > model.n_centers_:
                    continue
                sub = model if m == model.n_centers_ else model.truncated(m)
                row = score(sub, tb, val, test, args, dt)
                row["min_pivot"] = float(model.history_.selected_power[:m].min())
                out["sizes"][str(m)] = row
                print(m, {k: f"{v:.2e}" for k, v in row.items()}, flush=True)
        protocol = _protocol.record_options(args, repeats=1, warmup=0, notes="shared 2-core machine")
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    _protocol.write_json(args.json, out, protocol)
    return out


if __name__ == "__main__":
    main()
