"""How sensitive is pendulum scenario A to the test draw and to the shape parameters?

For each IMQ shape triple (state, mu, dT) this trains on the quick preset's data
(50x50 grid) and reports

* the gradient residual on validation samples with (mu, dT) *on* the training
  grid and *off* it (uniform in [0.7, 0.8] x [0.04, 0.06]);
* the paper protocol's median-over-time of the mean relative trajectory error
  for several test-draw seeds.

Run:  python sympredict_paper/studies/pendulum_sensitivity.py [--eps 0.15,2,5 --eps 0.15,1,2 ...] [--seeds 4]
"""

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _protocol  # noqa: E402  (sympredict_paper/studies/_protocol.py)

from sympredict import SymplecticKernelPredictor  # noqa: E402
from sympredict.data import mixed_variables  # noqa: E402
from sympredict_paper.pendulum import paper_test_instances  # noqa: E402
from sympredict.kernels import IMQ  # noqa: E402
from sympredict.symplectic.metrics import relative_trajectory_error  # noqa: E402
from sympredict.systems.pendulum import DT_TEST, DT_TRAIN, MU_TRAIN, Pendulum, flow_map_data, random_flow_map_data  # noqa: E402

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--eps", action="append", help="state,mu,dt shape triple (repeatable)")
parser.add_argument("--seeds", type=int, default=4)
parser.add_argument("--n-grid", type=int, default=50)
parser.add_argument("--centers", type=int, default=1500)
_protocol.add_arguments(parser, blas_alias="--threads")
args = parser.parse_args()
triples = [tuple(float(v) for v in e.split(",")) for e in (args.eps or ["0.15,2,5", "0.15,1,2", "0.2,1.5,3"])]

pendulum = Pendulum()
data = flow_map_data(pendulum, n_grid=args.n_grid)
val_on = random_flow_map_data(pendulum, 4000, seed=12, mu_values=MU_TRAIN, dt_values=DT_TRAIN)
val_off = random_flow_map_data(pendulum, 4000, seed=11)
tests = []
for seed in range(args.seeds):
    x0, lengths = paper_test_instances(seed)
    for dt in DT_TEST:
        n_steps = int(np.floor(20.0 / dt + 1e-9))
        tests.append((seed, dt, x0, lengths, n_steps, pendulum.trajectory(x0, lengths, dt, n_steps)))


def gradient_residual(model, val):
    xi, y = mixed_variables(val.x0, val.x1, val.dt)
    err = np.abs(model.surrogate_gradient(xi, mu=val.mu, dt=val.dt) - y).max(axis=1)
    return float(err.max()), float(np.median(err))


rows = []
for eps in triples:
    with _protocol.limits(args.blas_threads):
        model = SymplecticKernelPredictor(IMQ(eps[0]), IMQ(eps[1]), IMQ(eps[2]), max_centers=args.centers)
        model.fit(data.x0, data.x1, mu=data.mu, dt=data.dt)
    medians = {}
    for seed, dt, x0, lengths, n_steps, ref in tests:
        err = relative_trajectory_error(model.rollout(x0, n_steps, mu=lengths, dt=dt), ref).mean(axis=0)[1:]
        medians.setdefault(seed, []).append(float(np.median(err)))
    row = {
        "eps": eps,
        "n_centers": model.n_centers_,
        "stop": model.history_.stop_reason,
        "E_train": float(model.history_.train_max_residual[-1]),
        "on_grid_max_median": gradient_residual(model, val_on),
        "off_grid_max_median": gradient_residual(model, val_off),
        "trajectory_median_per_seed": medians,
    }
    rows.append(row)
    print(
        f"eps {eps}: {row['n_centers']} centres ({row['stop']}), E_train {row['E_train']:.1e}, "
        f"on-grid max/median {row['on_grid_max_median'][0]:.1e}/{row['on_grid_max_median'][1]:.1e}, "
        f"off-grid {row['off_grid_max_median'][0]:.1e}/{row['off_grid_max_median'][1]:.1e}",
        flush=True,
    )
    for seed, meds in medians.items():
        print(f"   test seed {seed}: median error at dT={DT_TEST}: " + ", ".join(f"{m:.2e}" for m in meds), flush=True)
if args.json:
    with _protocol.limits(args.blas_threads):
        _protocol.write_json(args.json, {"rows": rows}, _protocol.record_options(args), indent=2)
