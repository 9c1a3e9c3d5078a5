"""Far steps: a pendulum model trained at dT 0.04-0.06 asked for dT = 1.0 (20 states, 50 steps), both Newton backends.

Reports, per backend, where the batch rollout fails (macro step and instances) or that it converges; per instance
(each rolled out alone) the outcome (the failing step, or -1) at dT in ``--dts``, and how many of these outcomes
move when the initial state is perturbed by 1e-11 (relative); for ``--seeds`` further batches of 20 states (seeds
0, 1, ...) at each dT whether the two backends end alike (converged, or failed at the same macro step and
instances); and the normal rollout's time (training-range dT) side by side.  ``python sympredict_paper/studies/far_step_newton.py --json out.json``.
"""

import argparse
import json
import sys
import time
import warnings

import numpy as np

from sympredict import SymplecticKernelPredictor
from sympredict.container import atomic_output
from sympredict.exceptions import ExtrapolationWarning, NewtonConvergenceError
from sympredict.interpolation.greedy import ExactGreedy
from sympredict.kernels import IMQ
from sympredict.systems.pendulum import Pendulum, flow_map_data


def model(kind):
    """``small``: the test suite's small pendulum model (600 centres); ``narrow``: 60 centres, step kernel IMQ(0.2);
    ``default``: the estimator's defaults (kernel search), 300 centres."""
    d = flow_map_data(Pendulum(), n_grid=20)
    if kind == "default":
        return SymplecticKernelPredictor(max_centers=300).fit(d.x0, d.x1, mu=d.mu, dt=d.dt)
    dt_kernel, centers = (IMQ(5.0), 600) if kind == "small" else (IMQ(0.2), 60)
    m = SymplecticKernelPredictor(
        IMQ(0.15), mu_kernel=IMQ(2.0), dt_kernel=dt_kernel, max_centers=centers, trainer=ExactGreedy(tol=1e-10)
    )
    return m.fit(d.x0, d.x1, mu=d.mu, dt=d.dt)


def states(b=20, seed=0):
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(0.0, np.pi / 2, b), rng.uniform(-0.5, 0.5, b)]), rng.uniform(0.71, 0.79, b)


def outcome(m, x0, mu, dt, steps, backend):
    m.set_params(solver__backend=backend)
    try:
        m.rollout(x0, steps, mu=mu, dt=dt)
        return {"converged": True}
    except NewtonConvergenceError as exc:
        return {
            "converged": False,
            "step": int(exc.step),
            "instances": [int(i) for i in exc.instances],
            "residual": [float(r) for r in np.atleast_1d(exc.residuals)],
        }


def main(argv=None):
    parser = argparse.ArgumentParser()
    parser.add_argument("--json")
    parser.add_argument("--dts", default="0.8,1.0,1.2")
    parser.add_argument("--steps", type=int, default=50)
    parser.add_argument("--model", choices=["small", "narrow", "default"], default="narrow")
    parser.add_argument("--seeds", type=int, default=12)
    parser.add_argument("--no-timing", action="store_true")
    parser.add_argument("--timing-only", action="store_true")
    args = parser.parse_args(argv)
    warnings.simplefilter("ignore", ExtrapolationWarning)
    m = model(args.model)
    x0, mu = states()
    out = {"batch": {}, "per_instance": {}, "moved": {}, "timing": {}}
    for backend in () if args.timing_only else ("numpy", "numba"):
        out["batch"][backend] = outcome(m, x0, mu, 1.0, args.steps, backend)
    dts = [] if args.timing_only else [float(v) for v in args.dts.split(",")]
    rng = np.random.default_rng(1)
    pert = x0 * (1 + 1e-11 * rng.standard_normal(x0.shape))
    for backend in () if args.timing_only else ("numpy", "numba"):
        rows, moved = {}, 0
        for dt in dts:
            for i in range(len(x0)):
                a = outcome(m, x0[i : i + 1], mu[i : i + 1], dt, args.steps, backend)
                b = outcome(m, pert[i : i + 1], mu[i : i + 1], dt, args.steps, backend)
                sa, sb = a.get("step", -1), b.get("step", -1)
                rows[f"{dt}/{i}"] = [sa, sb]
                moved += sa != sb
        out["per_instance"][backend] = rows
        out["moved"][backend] = {"moved": moved, "failures": sum(v[0] >= 0 for v in rows.values()), "cases": len(rows)}
    if not args.timing_only:
        agree = sum(
            out["per_instance"]["numpy"][k][0] == out["per_instance"]["numba"][k][0]
            for k in out["per_instance"]["numpy"]
        )
        out["backends_agree_per_instance"] = {"agree": agree, "cases": len(out["per_instance"]["numpy"])}
    ends = {}  # batches of other states: do both backends end alike?
    for seed in range(0 if args.timing_only else args.seeds):
        xb, mb = states(seed=seed)
        for dt in dts:
            pair = [outcome(m, xb, mb, dt, args.steps, backend) for backend in ("numpy", "numba")]
            ends[f"{seed}/{dt}"] = [[e.get("step", -1), e.get("instances", [])] for e in pair]
    if ends:
        out["batch_seeds"] = {
            "agree": sum(a == b for a, b in ends.values()),
            "cases": len(ends),
            "converged": sum(a[0] == b[0] == -1 for a, b in ends.values()),
            "disagree": {k: v for k, v in ends.items() if v[0] != v[1]},
        }
    # the normal rollout (dT in the training range) side by side: median of 5
    xs, ms = states(200, seed=3)
    for backend in () if args.no_timing else ("numpy", "numba"):
        m.set_params(solver__backend=backend)
        m.rollout(xs, 5, mu=ms, dt=0.05)
        t = []
        for _ in range(5):
            t0 = time.perf_counter()
            m.rollout(xs, 100, mu=ms, dt=0.05)
            t.append(time.perf_counter() - t0)
        out["timing"][backend] = float(np.median(t))
    if args.json:
        with atomic_output(args.json) as fh:
            fh.write(json.dumps(out, indent=1).encode())
    print(
        json.dumps(
            {k: out.get(k) for k in ("batch", "moved", "backends_agree_per_instance", "batch_seeds", "timing")},
            indent=1,
        )
    )


if __name__ == "__main__":
    sys.exit(main())
