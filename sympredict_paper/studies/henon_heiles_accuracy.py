"""Hénon–Heiles with ``lambda`` and ``dT`` both kernel variables: shapes chosen by trajectory validation, then one test (issue 14, target b).

Target: median relative error at ``T = 10`` <= 2e-4 for energies up to 1/6,
``lambda`` in [0.8, 1.0], ``dT`` in [0.4, 0.6], 4,000 training samples, <= 1,000 centres.

Data: 4,000 flow-map samples, states uniform in the well with ``H <= 1/6``
(:func:`~sympredict.systems.henon_heiles.energy_bounded_states`), flown by the
Kahan–Li-6 reference with step halving to 1e-11.  ``--sampling grid L D``:
``L`` equispaced ``lambda`` x ``D`` equispaced ``dT`` (4000 / (L D) states each);
``random``: ``lambda`` and ``dT`` uniform per sample.

Protocol (test and validation alike): ``n_lam`` random ``lambda`` x ``n_state``
states with ``H <= 1/6`` each, every trajectory with its own ``dT ~ U[0.4, 0.6]``,
rolled out for ``K = floor(10 / dT)`` steps; the error of a trajectory is the
relative error ``|x - x_ref| / |x_ref|`` at its last step ``t_K = K dT`` (in
(9.4, 10]); the score is the median over trajectories.  Also reported: the median
over trajectories of the median over its steps.  Validation seeds (default 100,
101) choose the sampling and a coordinate search over the IMQ shapes of the
state, ``lambda`` and ``dT`` factors (each parameter times / divided by the
factor per sweep; the factor's exponent halves after a sweep without
improvement); the score is the largest median over the validation seeds.  The
test seeds (default 0) are evaluated once each, with the chosen model.

Run:  python sympredict_paper/studies/henon_heiles_accuracy.py [--update midpoint] [--json out.json]
      python sympredict_paper/studies/henon_heiles_accuracy.py --fixed 0.5 1 1 --sampling grid 5 5   # no search
      python sympredict_paper/studies/henon_heiles_accuracy.py --quick                               # seconds
One BLAS thread (``--blas-threads``) and one numba thread (set NUMBA_NUM_THREADS=1 too: numba reads it at import);
the JSON carries the record of ``sympredict_paper/studies/_protocol.py``.
"""

import argparse
import time

import numpy as np

import _protocol  # sympredict_paper/studies/ (the script's folder is on sys.path)
from _coordinate_search import Candidates, coordinate_search  # sympredict_paper/studies/

from sympredict import SymplecticKernelPredictor
from sympredict.data import FlowMapData
from sympredict.exceptions import extrapolation_expected
from sympredict.kernels import KERNEL_FAMILIES
from sympredict.symplectic.metrics import relative_trajectory_error
from sympredict.systems.henon_heiles import LAMBDA_RANGE, HenonHeiles, energy_bounded_states
from sympredict.interpolation.greedy import ExactGreedy
from sympredict.symplectic.solvers import NewtonSolver

TARGET = 2e-4
DT_RANGE = (0.4, 0.6)
ENERGY_MAX = 1.0 / 6.0
NAMES = ("state", "mu", "dt")

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--update", default="midpoint", choices=["midpoint", "symplectic_euler"])
parser.add_argument("--family", default="imq")
parser.add_argument(
    "--samplings",
    nargs="+",
    default=["grid:3:3", "grid:5:5", "random"],
    help="training-parameter samplings compared at the start shapes: grid:L:D or random",
)
parser.add_argument("--start", type=float, nargs=3, default=[0.5, 1.0, 1.0], metavar=("STATE", "MU", "DT"))
parser.add_argument("--fixed", type=float, nargs=3, default=None, metavar=("STATE", "MU", "DT"))
parser.add_argument("--search", nargs="+", default=list(NAMES), choices=NAMES)
parser.add_argument("--factor", type=float, default=2.0)
parser.add_argument("--sweeps", type=int, default=3)
parser.add_argument("--n-samples", type=int, default=4000)
parser.add_argument("--max-centers", type=int, default=1000)
parser.add_argument("--n-lam", type=int, default=8)
parser.add_argument("--n-state", type=int, default=8)
parser.add_argument("--horizon", type=float, default=10.0)
parser.add_argument("--val-seeds", type=int, nargs="+", default=[100, 101])
parser.add_argument("--test-seeds", type=int, nargs="+", default=[0], help="evaluated once each, with the chosen model")
parser.add_argument(
    "--sizes",
    type=int,
    nargs="*",
    default=[250, 500],
    help="also report the test errors of the chosen model truncated to these sizes (no choice made on them)",
)
_protocol.add_arguments(parser)
parser.add_argument("--quick", action="store_true", help="tiny sizes, one sweep: checks that the script runs")
args = parser.parse_args()
if args.quick:
    args.n_samples, args.max_centers, args.n_lam, args.n_state, args.horizon = 300, 40, 2, 2, 2.0
    args.sweeps, args.val_seeds, args.search, args.samplings = 1, [100], ["state"], ["grid:2:2", "random"]
assert not set(args.test_seeds) & set(args.val_seeds), "the test seed must not be a validation seed"

system = HenonHeiles()
family = KERNEL_FAMILIES[args.family]


def training_data(sampling: str, seed: int = 1000) -> FlowMapData:
    """``args.n_samples`` samples with ``H <= 1/6``; parameters on a grid (``grid:L:D``) or uniform per sample (``random``)."""
    if sampling == "random":
        rng = np.random.default_rng(seed)
        lams = rng.uniform(*LAMBDA_RANGE, args.n_samples)
        dts = rng.uniform(*DT_RANGE, args.n_samples)
        x0 = np.concatenate(
            [energy_bounded_states(system, lam, 1, ENERGY_MAX, seed=seed + 1 + i) for i, lam in enumerate(lams)]
        )
    else:
        _, n_l, n_d = sampling.split(":")
        grid = [(lam, dt) for lam in np.linspace(*LAMBDA_RANGE, int(n_l)) for dt in np.linspace(*DT_RANGE, int(n_d))]
        per = -(-args.n_samples // len(grid))
        x0 = np.concatenate(
            [energy_bounded_states(system, lam, per, ENERGY_MAX, seed=seed + 1 + i) for i, (lam, _) in enumerate(grid)]
        )
        lams = np.repeat([g[0] for g in grid], per)
        dts = np.repeat([g[1] for g in grid], per)
        x0, lams, dts = x0[: args.n_samples], lams[: args.n_samples], dts[: args.n_samples]
    return FlowMapData(x0, system.flow(x0, lams, dts), lams[:, None], dts)


def instances(seed: int):
    """``n_lam`` lambdas x ``n_state`` states (``H <= 1/6``), a ``dT`` per trajectory; their steps and references."""
    rng = np.random.default_rng(seed + 5000)
    lams = rng.uniform(*LAMBDA_RANGE, args.n_lam)
    x0 = np.concatenate(
        [
            energy_bounded_states(system, lam, args.n_state, ENERGY_MAX, seed=seed + 5001 + i)
            for i, lam in enumerate(lams)
        ]
    )
    lam = np.repeat(lams, args.n_state)
    dt = rng.uniform(*DT_RANGE, len(x0))
    k = np.floor(args.horizon / dt + 1e-9).astype(int)
    ref = system.trajectory(x0, lam, dt, int(k.max()))
    return x0, lam, dt, k, ref


def errors(model, inst) -> tuple[np.ndarray, np.ndarray]:
    """Per trajectory: relative error at its last step ``t_K <= T``, and the median over its steps 1..K."""
    x0, lam, dt, k, ref = inst
    with extrapolation_expected():
        pred = model.rollout(x0, int(k.max()), mu=lam, dt=dt)
    err = relative_trajectory_error(pred, ref)
    idx = np.arange(len(x0))
    return err[idx, k], np.array([np.median(err[i, 1 : k[i] + 1]) for i in idx])


def fit(p, data):
    model = SymplecticKernelPredictor(
        family(p[0]),
        family(p[1]),
        family(p[2]),
        max_centers=args.max_centers,
        update=args.update,
        trainer=ExactGreedy(tol=1e-10),
        solver=NewtonSolver(backend="numpy" if args.update == "midpoint" else "auto"),
    )
    return model.fit(data.x0, data.x1, mu=data.mu, dt=data.dt)


candidates = Candidates(NAMES)


def measure(p, data, vals):
    """The row entries and score of the parameters ``p``: the worst validation median error at T."""
    model = fit(p, data)
    at_t = {s: float(np.median(errors(model, inst)[0])) for s, inst in vals.items()}
    return dict(
        n_centers=model.n_centers_,
        stop_reason=model.history_.stop_reason,
        E_train=float(model.history_.train_max_residual[-1]),
        val_median_at_T=at_t,
        score=max(at_t.values()),
    )


def evaluate(p, sampling, data, vals):
    return candidates.score(p, lambda q: measure(q, data, vals), sampling=sampling)


with _protocol.limits(args.blas_threads, numba_threads=1):
    t_start = time.perf_counter()
    datasets = {s: training_data(s) for s in args.samplings}
    if args.fixed is not None:
        best, sampling = list(args.fixed), args.samplings[0]
    else:
        vals = {s: instances(s) for s in args.val_seeds}
        best = list(args.start)
        scores = {s: evaluate(best, s, datasets[s], vals) for s in args.samplings}
        sampling = min(scores, key=scores.get)
        best_score = scores[sampling]
        best, best_score = coordinate_search(
            lambda cand: evaluate(cand, sampling, datasets[sampling], vals),
            best,
            NAMES,
            args.search,
            args.factor,
            args.sweeps,
            start_score=best_score,
            label=f"{sampling} ",
        )
    model = fit(best, datasets[sampling])
    test, by_size = {}, {}
    for seed in args.test_seeds:
        test_inst = instances(seed)
        at_t, over_t = errors(model, test_inst)
        test[seed] = {
            "median_at_T": float(np.median(at_t)),
            "median_over_time": float(np.median(over_t)),
            "max_at_T": float(np.max(at_t)),
        }
        print(
            f"  test seed {seed}: median at T {test[seed]['median_at_T']:.2e}, median over time "
            f"{test[seed]['median_over_time']:.2e}, max at T {test[seed]['max_at_T']:.2e}",
            flush=True,
        )
        by_size[seed] = {}
        for m in (m for m in args.sizes if m < model.n_centers_):
            a, o = errors(model.truncated(m), test_inst)
            by_size[seed][m] = {"median_at_T": float(np.median(a)), "median_over_time": float(np.median(o))}
            print(f"    truncated to {m} centres: median at T {by_size[seed][m]['median_at_T']:.2e}", flush=True)
    worst = max(t["median_at_T"] for t in test.values())
    summary = {
        "update": args.update,
        "family": args.family,
        "sampling": sampling,
        "chosen": dict(zip(NAMES, best)),
        "n_centers": model.n_centers_,
        "E_train": float(model.history_.train_max_residual[-1]),
        "n_samples": args.n_samples,
        "test_seeds": args.test_seeds,
        "val_seeds": args.val_seeds,
        "test": test,
        "test_truncated": by_size,
        "target": TARGET,
        "met": bool(worst <= TARGET),
        "time_s": time.perf_counter() - t_start,
        "candidates": candidates.rows,
    }
    print(
        f"chosen {sampling} {summary['chosen']} ({model.n_centers_} centres): worst test median at T {worst:.2e} "
        f"-> target {TARGET:g} {'met' if summary['met'] else 'NOT met'}",
        flush=True,
    )
    statistic = "medians over test instances (no timing)"
    _protocol.write_json(args.json, summary, _protocol.record_options(args, numba_threads=1, statistic=statistic))
