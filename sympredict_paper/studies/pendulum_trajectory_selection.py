"""Choose the pendulum's IMQ shapes by *trajectory* validation (seeds disjoint from the test seed).

The gradient residual on validation samples does not rank the trajectory errors
(docs/explanation/results.md), so this script validates what the method is used for: for
each candidate (state, mu, dT) shape triple it trains on the quick data and
rolls out the paper's protocol (5 q0 x 5 lengths, the three test steps, T = 20)
for validation seeds 100..100+n-1, never the test seed 0. The score is the
mean over seeds of the worst (over dT) median-over-time error.

Run:  python sympredict_paper/studies/pendulum_trajectory_selection.py [--seeds 4] [--json out.json]
"""

import argparse
import itertools
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _protocol  # noqa: E402  (sympredict_paper/studies/_protocol.py)

from sympredict import SymplecticKernelPredictor  # noqa: E402
from sympredict_paper.pendulum import paper_test_instances  # noqa: E402
from sympredict.kernels import IMQ  # noqa: E402
from sympredict.symplectic.metrics import relative_trajectory_error  # noqa: E402
from sympredict.systems.pendulum import DT_TEST, Pendulum, flow_map_data  # noqa: E402

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--seeds", type=int, default=4)
parser.add_argument("--state", type=float, nargs="+", default=[0.15, 0.2])
parser.add_argument("--mu", type=float, nargs="+", default=[1.5, 2.0])
parser.add_argument("--dt", type=float, nargs="+", default=[3.0, 5.0])
_protocol.add_arguments(parser, blas_alias="--threads")
args = parser.parse_args()

pendulum = Pendulum()
data = flow_map_data(pendulum, n_grid=50)
cases = []
for seed in range(100, 100 + args.seeds):
    x0, lengths = paper_test_instances(seed)
    for dt in DT_TEST:
        n_steps = int(np.floor(20.0 / dt + 1e-9))
        cases.append((seed, dt, x0, lengths, n_steps, pendulum.trajectory(x0, lengths, dt, n_steps)))

rows = []
for eps in itertools.product(args.state, args.mu, args.dt):
    with _protocol.limits(args.blas_threads):
        model = SymplecticKernelPredictor(IMQ(eps[0]), IMQ(eps[1]), IMQ(eps[2]), max_centers=1500).fit(
            data.x0, data.x1, mu=data.mu, dt=data.dt
        )
    worst = {}
    for seed, dt, x0, lengths, n_steps, ref in cases:
        med = float(
            np.median(relative_trajectory_error(model.rollout(x0, n_steps, mu=lengths, dt=dt), ref).mean(axis=0)[1:])
        )
        worst[seed] = max(worst.get(seed, 0.0), med)
    score = float(np.mean(list(worst.values())))
    rows.append({"eps": eps, "score": score, "worst_median_per_seed": worst, "n_centers": model.n_centers_})
    print(
        f"eps {eps}: {model.n_centers_} centres, validation score {score:.3e} "
        f"(worst median per seed {', '.join(f'{v:.2e}' for v in worst.values())})",
        flush=True,
    )
best = min(rows, key=lambda r: r["score"])
print(f"chosen: eps = {best['eps']} (score {best['score']:.3e})")
if args.json:
    with _protocol.limits(args.blas_threads):
        _protocol.write_json(args.json, {"rows": rows, "chosen": best["eps"]}, _protocol.record_options(args), indent=2)
