"""Does growing the model make it worse? Defaults on the planar restricted three-body problem at several budgets.

The case: planar circular restricted three-body problem in the rotating frame
(:mod:`sympredict.systems.three_body`), mass ratio in [0.010, 0.014], tadpole
librations near L4, ``dT = 0.05``, ``--traj`` trajectories x ``--traj-steps`` steps of
training data, ``SymplecticKernelPredictor(max_centers=M)`` for each ``M`` in
``--budgets``.  Test: ``--n-test`` trajectories (own seeds), relative error
``|x_k - x_ref| / |x_ref|`` at step ``--steps`` (median and maximum over the
trajectories), relative Jacobi-constant drift over ``--long-steps`` steps
(median and maximum of the per-trajectory maximum).  Recorded per budget: the
centres kept, the greedy's stop, the held-out one-step errors of the prefixes
it scored (``prefix_errors_``), the fit time.

Run:  python benchmarks/three_body_growth.py            # writes docs/data/three_body_growth.json
"""

from __future__ import annotations

import argparse
import time
import warnings
from pathlib import Path

import numpy as np

import _protocol  # benchmarks/

from sympredict import SymplecticKernelPredictor
from sympredict.data import FlowMapData
from sympredict.exceptions import ExtrapolationWarning
from sympredict.systems.three_body import MU_RANGE, ThreeBody, librating_states

RESULTS = Path(__file__).resolve().parents[1] / "docs" / "data" / "three_body_growth.json"


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--budgets", type=int, nargs="+", default=[1000, 2000, 4000])
    p.add_argument("--traj", type=int, default=300)
    p.add_argument("--traj-steps", type=int, default=60)
    p.add_argument("--n-test", type=int, default=20)
    p.add_argument("--steps", type=int, default=200)
    p.add_argument("--long-steps", type=int, default=2000)
    p.add_argument("--seed", type=int, default=0)
    _protocol.add_arguments(p, threads=1)
    args = p.parse_args(argv)
    args.json = args.json or str(RESULTS)
    warnings.simplefilter("ignore", ExtrapolationWarning)
    tb, dt = ThreeBody(), 0.05
    rng = np.random.default_rng(args.seed)
    mu = rng.uniform(*MU_RANGE, args.traj)
    traj = tb.trajectory(librating_states(mu, args.traj, seed=args.seed + 1), mu, dt, args.traj_steps)
    data = FlowMapData(traj[:, :-1].reshape(-1, 4), traj[:, 1:].reshape(-1, 4), np.repeat(mu, args.traj_steps),
                       np.full(args.traj * args.traj_steps, dt))
    trng = np.random.default_rng(args.seed + 1000)
    tmu = trng.uniform(*MU_RANGE, args.n_test)
    tx0 = librating_states(tmu, args.n_test, seed=args.seed + 1001)
    ref = tb.trajectory(tx0, tmu, dt, args.steps)
    out = {"settings": {k: v for k, v in vars(args).items() if k != "json"}, "n_samples": len(data), "budgets": {}}
    with _protocol.limits(args.blas_threads, numba_threads=args.threads):
        for m in args.budgets:
            t0 = time.perf_counter()
            model = SymplecticKernelPredictor(max_centers=m).fit(data)
            fit_s = time.perf_counter() - t0
            row = {"fit_s": fit_s, "n_centers": model.n_centers_, "stop": model.history_.stop_reason,
                   "prefix_errors": {str(k): v for k, v in (model.prefix_errors_ or {}).items()},
                   "holdout_step_error": model.diagnostics_.holdout_step_error,
                   "choice": {k: repr(v) for k, v in model.choice_.items()}}
            try:
                pred = model.rollout(tx0, args.steps, mu=tmu, dt=dt)
                rel = np.linalg.norm(pred[:, -1] - ref[:, -1], axis=1) / np.linalg.norm(ref[:, -1], axis=1)
                row.update(median_rel_error=float(np.median(rel)), max_rel_error=float(rel.max()))
                long = model.rollout(tx0, args.long_steps, mu=tmu, dt=dt, stride=10)
                c = tb.jacobi_constant(long.reshape(-1, 4), np.repeat(tmu, long.shape[1])).reshape(len(tmu), -1)
                drift = np.abs(c - c[:, :1]).max(axis=1) / np.abs(c[:, 0])
                row.update(median_drift=float(np.median(drift)), max_drift=float(drift.max()))
            except Exception as exc:  # a failure is a result
                row["error"] = f"{type(exc).__name__}: {exc}"
            out["budgets"][str(m)] = row
            print(m, {k: v for k, v in row.items() if k not in ("prefix_errors", "choice")}, flush=True)
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    _protocol.write_json(args.json, out, _protocol.record(blas_threads=args.blas_threads, numba_threads=args.threads,
                                                          repeats=1, warmup=0, notes="shared 2-core machine"))
    return out


if __name__ == "__main__":
    main()
