"""Noisy training data on the pendulum: the exact fit against the regularized fit (lambda chosen on validation data).

Scenario A's quick data (50 x 50 energy-bounded grid, the 5 x 3 training
lengths and steps) with relative noise ``sigma`` on the training targets: each
increment ``x1 - x0`` (so each component of ``y = J^T (x1 - x0) / dT``) is
multiplied by ``1 + sigma N(0, 1)``.  The validation samples (random states on
the training ``(mu, dT)`` grid, seed 1) carry the same noise.  For every
``sigma`` the exact fit (``regularization=0``) and the ridge term chosen by
:func:`sympredict.estimators.selection.select_regularization` (RMS of the validation
gradient residual over a log grid of ``lambda``, the exact fit a candidate) are
compared on

* the validation score (the selection's own criterion), and
* trajectory errors against the clean micro-step reference: the paper's protocol
  (5 q0 x 5 lengths, test seed 0, never used for a choice), median over time of
  the instance-mean relative error, per test step.

Run:  python sympredict_paper/studies/pendulum_noise.py [--noise 0 1e-5 1e-4 1e-3] [--json out.json]
Threads: one BLAS/numba thread per process (``--threads``).
"""

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _protocol  # noqa: E402  (sympredict_paper/studies/_protocol.py)

from sympredict import SymplecticKernelPredictor  # noqa: E402
from sympredict.data import FlowMapData  # noqa: E402
from sympredict_paper.pendulum import paper_test_instances  # noqa: E402
from sympredict.kernels import IMQ  # noqa: E402
from sympredict.symplectic.metrics import relative_trajectory_error  # noqa: E402
from sympredict.estimators.selection import select_regularization  # noqa: E402
from sympredict.systems.pendulum import DT_TEST, DT_TRAIN, MU_TRAIN, Pendulum, flow_map_data, random_flow_map_data  # noqa: E402
from sympredict.interpolation.greedy import ExactGreedy  # noqa: E402

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--noise", type=float, nargs="+", default=[1e-5, 1e-4, 1e-3])
parser.add_argument("--lambdas", type=float, nargs="+", default=[1e-10, 1e-8, 1e-6, 1e-4])
parser.add_argument("--n-grid", type=int, default=50)
parser.add_argument("--n-val", type=int, default=2000)
parser.add_argument("--max-centers", type=int, default=1500)
parser.add_argument("--horizon", type=float, default=20.0)
_protocol.add_arguments(parser, blas_alias="--threads")
args = parser.parse_args()


def noisy(d: FlowMapData, sigma: float, seed: int) -> FlowMapData:
    rng = np.random.default_rng(seed)
    return FlowMapData(d.x0, d.x0 + (d.x1 - d.x0) * (1.0 + sigma * rng.standard_normal(d.x0.shape)), d.mu, d.dt)


def trajectory_errors(model, system, x0, lengths, refs):
    out = {}
    for dt in DT_TEST:
        n_steps = int(np.floor(args.horizon / dt + 1e-9))
        pred = model.rollout(x0, n_steps, mu=lengths, dt=dt)
        err = relative_trajectory_error(pred, refs[dt]).mean(axis=0)
        out[dt] = float(np.median(err[1:]))
    return out


with _protocol.limits(args.blas_threads):
    system = Pendulum()
    clean = flow_map_data(system, n_grid=args.n_grid)
    clean_val = random_flow_map_data(system, args.n_val, seed=1, mu_values=MU_TRAIN, dt_values=DT_TRAIN)
    x0, lengths = paper_test_instances(0)
    refs = {dt: system.trajectory(x0, lengths, dt, int(np.floor(args.horizon / dt + 1e-9))) for dt in DT_TEST}
    estimator = SymplecticKernelPredictor(
        IMQ(0.2), IMQ(1.5), IMQ(3.0), max_centers=args.max_centers, trainer=ExactGreedy(tol=1e-10)
    )
    rows = []
    for sigma in args.noise:
        train, val = noisy(clean, sigma, seed=10), noisy(clean_val, sigma, seed=11)
        t0 = time.perf_counter()
        sel = select_regularization(train, val, args.lambdas, estimator, keep_models=True)
        t_sel = time.perf_counter() - t0
        exact_row = next(r for r in sel.table if r["regularization"] == 0.0)
        err_exact = trajectory_errors(sel.models[0.0], system, x0, lengths, refs)
        err_reg = trajectory_errors(sel.model, system, x0, lengths, refs)
        # trajectory errors of every candidate too: does the validation score rank them?
        traj_all = {lam: trajectory_errors(m, system, x0, lengths, refs) for lam, m in sel.models.items()}
        row = {
            "sigma": sigma,
            "lambda": sel.regularization,
            "traj_all": traj_all,
            "val_rms_exact": exact_row["score"],
            "val_rms_reg": sel.score,
            "traj_exact": err_exact,
            "traj_reg": err_reg,
            "table": sel.table,
            "selection_s": t_sel,
        }
        rows.append(row)
        print(
            f"sigma={sigma:.0e}: lambda={sel.regularization:.0e}  val RMS exact {exact_row['score']:.3e} reg {sel.score:.3e}  "
            + "  ".join(f"dT={dt}: exact {err_exact[dt]:.2e} reg {err_reg[dt]:.2e}" for dt in DT_TEST),
            flush=True,
        )
    if args.json:
        _protocol.write_json(
            args.json,
            {"args": vars(args), "rows": rows},
            _protocol.record_options(args, repeats=1, statistic="one timed selection"),
        )
