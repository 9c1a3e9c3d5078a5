"""Passes over the centres per macro step of the compiled rollout, cold (explicit guess) against warm start.

Pendulum, n_grid 30, IMQ (0.2, 1.5, 3.0), 1,000 centres; the paper's 25 test
instances (seed 0), 400 steps.  Counts passes (deterministic, no timing) and
compares both trajectories with each other and with the reference.  Threads
and the JSON record follow ``sympredict_paper/studies/_protocol.py``.

Run:  python sympredict_paper/studies/warm_start_passes.py [--json out.json]
"""

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _protocol  # noqa: E402  (sympredict_paper/studies/_protocol.py)
from sympredict import SymplecticKernelPredictor  # noqa: E402
from sympredict.symplectic import _compiled_newton  # noqa: E402
from sympredict_paper.pendulum import paper_test_instances  # noqa: E402
from sympredict.kernels import IMQ  # noqa: E402
from sympredict.symplectic.metrics import relative_trajectory_error  # noqa: E402
from sympredict.systems.pendulum import Pendulum, flow_map_data  # noqa: E402


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    _protocol.add_arguments(parser, threads=1)
    args = parser.parse_args(argv)
    rows = []
    with _protocol.limits(args.blas_threads, numba_threads=args.threads):
        system = Pendulum()
        d = flow_map_data(system, n_grid=30)
        model = SymplecticKernelPredictor(IMQ(0.2), IMQ(1.5), IMQ(3.0), max_centers=1000).fit(
            d.x0, d.x1, mu=d.mu, dt=d.dt
        )
        x0, lengths = paper_test_instances(0)
        sur = model.surrogate_
        for dt in (0.05, 0.0509):
            dts = np.full(len(x0), dt)
            w = sur.weights(lengths[:, None], dts)
            ref = system.trajectory(x0, lengths, dt, 400)
            trajs = {}
            for warm in (False, True):
                stats = {}
                traj, codes, *_ = _compiled_newton.newton_rollout(
                    x0, w, dts, sur.layout(), sur.kernel.state, 50, 400, stats=stats, warm_start=warm
                )
                trajs[warm] = traj
                err = np.median(relative_trajectory_error(traj, ref).mean(axis=0)[1:])
                row = {
                    "dt": dt,
                    "start": "warm" if warm else "cold",
                    "passes_per_step": float(stats["passes"].sum() / (len(x0) * 400)),
                    "failures": int((codes != 0).sum()),
                    "median_error": float(err),
                }
                rows.append(row)
                print(
                    f"dT={dt} {row['start']}: {row['passes_per_step']:.2f} passes/step, "
                    f"failures {row['failures']}, median error {err:.3e}"
                )
            diff = float(np.abs(trajs[True] - trajs[False]).max())
            rows[-1]["max_abs_warm_minus_cold"] = diff
            print(f"  max |warm - cold| = {diff:.1e}")
        protocol = _protocol.record_options(args, statistic="counts (no timing)")
    if args.json:
        _protocol.write_json(args.json, {"rows": rows}, protocol)
    return {"rows": rows}


if __name__ == "__main__":
    main()
