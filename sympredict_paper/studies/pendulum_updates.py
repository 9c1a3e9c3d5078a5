"""Pendulum scenario A, quick data: the paper's symplectic-Euler update against the midpoint update (and state scalings).

Both trained on the quick data (50 x 50 energy-bounded grid, 5 lengths x 3 steps),
IMQ (0.2, 1.5, 3.0), 1500 centres; the paper's test protocol on test seed 0
(5 q0 x 5 lengths, T = 20), median over time of the instance-mean relative
error per test step, and the max relative energy error.  NumPy Newton solver
for both (the reference; the compiled solvers agree to round-off, tests/symplectic/test_midpoint_compiled.py).  ``--scalings``
adds symplectic-Euler models with ``state_scaling=(a,)``.

``--updates midpoint --compare-backends`` also rolls every test case out on the
compiled solver and reports the largest difference and both rollout times.

Run:  python sympredict_paper/studies/pendulum_updates.py [--scalings 0.5 2] [--updates midpoint] [--compare-backends] [--json out.json]
"""

import argparse
import copy
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _protocol  # noqa: E402  (sympredict_paper/studies/_protocol.py)

from sympredict import SymplecticKernelPredictor  # noqa: E402
from sympredict_paper.pendulum import paper_test_instances  # noqa: E402
from sympredict.kernels import IMQ  # noqa: E402
from sympredict.symplectic.metrics import relative_hamiltonian_error, relative_trajectory_error  # noqa: E402
from sympredict.systems.pendulum import DT_TEST, Pendulum, flow_map_data  # noqa: E402
from sympredict.interpolation.greedy import ExactGreedy  # noqa: E402
from sympredict.symplectic.solvers import NewtonSolver  # noqa: E402
from sympredict.kernels.transforms import Scaled  # noqa: E402

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--scalings", type=float, nargs="*", default=[])
parser.add_argument("--max-centers", type=int, default=1500)
_protocol.add_arguments(parser, threads=1)
parser.add_argument("--updates", nargs="*", default=["symplectic_euler", "midpoint"])
parser.add_argument("--compare-backends", action="store_true", help="also the compiled solver: max difference, times")
args = parser.parse_args()

with _protocol.limits(args.blas_threads, numba_threads=args.threads):
    system = Pendulum()
    data = flow_map_data(system, n_grid=50)
    x0, lengths = paper_test_instances(0)
    configs = [(u, None) for u in args.updates] + [("symplectic_euler", (a,)) for a in args.scalings]
    rows = []
    for update, scaling in configs:
        model = SymplecticKernelPredictor(
            Scaled(IMQ(0.2), factors=scaling),
            IMQ(1.5),
            IMQ(3.0),
            max_centers=args.max_centers,
            update=update,
            trainer=ExactGreedy(tol=1e-10),
            solver=NewtonSolver(backend="numpy"),
        )
        model.fit(data.x0, data.x1, mu=data.mu, dt=data.dt)
        row = {
            "update": update,
            "state_scaling": scaling,
            "n_centers": model.n_centers_,
            "E_train": float(model.history_.train_max_residual[-1]),
            "per_dt": {},
        }
        for dt in DT_TEST:
            n_steps = int(np.floor(20.0 / dt + 1e-9))
            ref = system.trajectory(x0, lengths, dt, n_steps)
            t0 = time.perf_counter()
            pred = model.rollout(x0, n_steps, mu=lengths, dt=dt)
            t_numpy = time.perf_counter() - t0
            err = relative_trajectory_error(pred, ref).mean(axis=0)
            energy = relative_hamiltonian_error(system, pred, lengths[:, None]).max()
            row["per_dt"][dt] = {"median_err": float(np.median(err[1:])), "max_energy_err": float(energy)}
            if args.compare_backends:
                fast = copy.copy(model).set_params(solver__backend="numba")
                fast.rollout(x0, 2, mu=lengths, dt=dt)  # compile (the batch path)
                t0 = time.perf_counter()
                pred_fast = fast.rollout(x0, n_steps, mu=lengths, dt=dt)
                t_fast = time.perf_counter() - t0
                err_fast = relative_trajectory_error(pred_fast, ref).mean(axis=0)
                row["per_dt"][dt].update(
                    {
                        "numba_median_err": float(np.median(err_fast[1:])),
                        "max_abs_numba_minus_numpy": float(np.abs(pred_fast - pred).max()),
                        "rollout_s_numpy": t_numpy,
                        "rollout_s_numba": t_fast,
                    }
                )
                print(
                    f"  dT={dt}: numba median error {np.median(err_fast[1:]):.3e}, max |numba - numpy| "
                    f"{np.abs(pred_fast - pred).max():.1e}, rollout {t_numpy:.2f} s (NumPy) / {t_fast:.3f} s (numba)",
                    flush=True,
                )
        rows.append(row)
        print(
            f"{update:17s} scaling={scaling}: {model.n_centers_} centres, E_train {row['E_train']:.2e}; "
            + "  ".join(
                f"dT={dt}: {v['median_err']:.2e} (energy {v['max_energy_err']:.1e})" for dt, v in row["per_dt"].items()
            ),
            flush=True,
        )
    if args.json:
        _protocol.write_json(
            args.json,
            {"rows": rows},
            _protocol.record_options(
                args, repeats=1, warmup=1, statistic="one timed rollout per backend (numba: after a compiling call)"
            ),
        )
