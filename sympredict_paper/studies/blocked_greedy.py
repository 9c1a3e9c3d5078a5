"""The blocked greedy against the exact greedy: fit time, held-out and rollout errors, and the arithmetic limit.

System: the coupled pendulums of ``sympredict_paper/studies/defaults_acceptance.py`` (4-D state, one parameter kappa,
``dT = 0.1 s``), ``--trajectories`` trajectories of ``--steps`` steps from states uniform in ``H <= 8 J``
(300 x 60 = 18,000 one-step samples, 72,000 candidate functionals).  Kernels fixed to the recorded hand
settings (``HAND['coupled_pendulums']``, the state shape times ``--eps-factor``, 4: the hand shape's Gramian
turns numerically singular near 1,600 centres on these data), so both fits run the same greedy problem and differ only in the
trainer: ``ExactGreedy()`` (one centre per step, a matrix-vector pass over the Newton basis) and
``BlockedGreedy(block_size=b)`` (:mod:`sympredict.interpolation.greedy.blocked`).

Per ``max_centers`` in ``--centers``, in one process, exact then blocked: the fit's wall time and the greedy's
own time (``history_.elapsed[-1]``); the held-out error (mean relative one-step error
``|Phi(x0) - x1| / |x1 - x0|`` on ``--holdout`` trajectories of the same length, seed disjoint) and the max
residual over those held-out functionals' targets; the rollout error (median and max over ``--n-test``
test trajectories of the max relative trajectory error over ``--test-steps`` steps, and each trajectory's error,
``traj_errors``); the ratios blocked / exact, and per trajectory (their median and max).  A max over 20 test
trajectories is one trajectory's error: compare it with the per-trajectory ratios and a larger ``--n-test``.
The blocked trainer's ``--slack`` and ``--pool-factor`` default to its own defaults; ``--train-seed`` draws
another, equally good training set (the exact greedy against itself: the noise floor of the ratios).

Arithmetic limit: the greedy's Newton basis costs ``m^2 N`` flops in total (``2 m N`` for the ``m``-th
centre's projection), the minimum any f-greedy on the full Newton basis does; its time at this process's
rate of a matrix product (``dgemm`` of shape ``(b, m0) x (m0, N)``, the block update's shape, median of 3)
is the limit line.  Peak memory: the trainers' formulas (:func:`sympredict.interpolation.greedy.trainer_memory`).

Noise floor (``--noise-floor A.json B.json --json OUT``): two runs of this study on different ``--train-seed``
and the same test trajectories, compared trainer by trainer: the exact greedy of B against that of A (the
ratios an equally good exact fit moves by), beside each run's blocked / exact ratios.

Run:  python sympredict_paper/studies/blocked_greedy.py --centers 4000 1000 2000   # 4,000 / 1,000 / 2,000 centres
      python sympredict_paper/studies/blocked_greedy.py --centers 500 --trajectories 60 --json /tmp/quick.json   # a minute
One BLAS and one numba thread; writes ``docs/data/blocked_greedy.json`` (``--json``).
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

import _protocol  # sympredict_paper/studies/ (the script's folder is on sys.path)
from defaults_acceptance import HAND, hand_model, make_benchmarks, make_test_set, trajectory_metrics

from sympredict.interpolation.greedy import BlockedGreedy, ExactGreedy, trainer_memory
from sympredict.symplectic.metrics import relative_trajectory_error


def pendulum_samples(bench, n_traj: int, steps: int, seed: int):
    """``n_traj`` trajectories of ``steps`` steps: one-step pairs ``(x0, x1, mu, dt)`` of ``n_traj * steps`` samples."""
    x0, mu = bench.sample(n_traj, seed)
    traj = bench.system.trajectory(x0, mu[:, None], bench.dt, steps)
    a, b = traj[:, :-1].reshape(-1, bench.dim), traj[:, 1:].reshape(-1, bench.dim)
    return a, b, np.repeat(mu, steps), np.full(len(a), bench.dt)


def held_out_error(model, x0, x1, mu, dt) -> float:
    """Mean relative one-step error ``|Phi(x0) - x1| / |x1 - x0|`` (the error a rollout compounds)."""
    pred = model.step(x0, mu=mu, dt=dt)
    return float(np.mean(np.linalg.norm(pred - x1, axis=1) / np.linalg.norm(x1 - x0, axis=1)))


def gemm_rate(n: int, m0: int = 1000, b: int = 64, repeats: int = 3) -> dict:
    """Flops per second of ``(b, m0) @ (m0, n)`` (the block update's shape), median of ``repeats``."""
    rng = np.random.default_rng(0)
    a, v = rng.normal(size=(b, m0)), rng.normal(size=(m0, n))
    times = []
    for _ in range(repeats + 1):
        t0 = time.perf_counter()
        a @ v
        times.append(time.perf_counter() - t0)
    t = float(np.median(times[1:]))
    return {"shape": [b, m0, n], "median_s": t, "gflops": 2.0 * b * m0 * n / t / 1e9}


def fit_one(label, trainer, settings, data, heldout, test, bench, m, args) -> dict:
    x0, x1, mu, dt = data
    model = hand_model(settings, x0, m).set_params(trainer=trainer)
    t0 = time.perf_counter()
    model.fit(x0, x1, mu=mu, dt=dt)
    fit_s = time.perf_counter() - t0
    h = model.history_
    out = {
        "trainer": label,
        "spec": trainer.spec,
        "max_centers": m,
        "centers": int(model.surrogate_.n_centers),
        "fit_s": fit_s,
        "greedy_s": float(h.elapsed[-1]),
        "stop_reason": h.stop_reason,
        "train_max_residual": float(h.train_max_residual[-1]),
        "held_out_error": held_out_error(model, *heldout),
        "memory_formula_bytes": trainer_memory(trainer, 4 * len(x0), 0, m),
    }
    stats = model.greedy_result_.stats
    if "blocks" in stats:
        sizes = np.asarray(stats["block_sizes"])
        out.update(blocks=int(stats["blocks"]), mean_block=float(sizes.mean()))
    out.update(trajectory_metrics(model, bench, test, args.test_steps))
    if "traj_failure" not in out:
        # the per-trajectory errors (max over the horizon): which trajectory sets the max, and the ratios per trajectory
        pred = model.rollout(test["x0"], test["ref"].shape[1] - 1, mu=test["mu"], dt=bench.dt)
        out["traj_errors"] = relative_trajectory_error(pred, test["ref"])[:, 1:].max(axis=1).tolist()
    print(
        f"  {label:>8s} m={m}: fit {fit_s:7.1f} s (greedy {out['greedy_s']:7.1f} s), held-out {out['held_out_error']:.3e}, "
        f"rollout median {out.get('traj_error_median', float('nan')):.3e}",
        flush=True,
    )
    return out


def _ratios(num: dict, den: dict) -> dict:
    """Ratios ``num / den`` of two fits' errors, and per test trajectory (their median and max)."""
    out = {k: num[k] / den[k] for k in ("held_out_error", "traj_error_median", "traj_error_max") if den.get(k)}
    per_traj = np.asarray(num["traj_errors"]) / np.asarray(den["traj_errors"])
    out["per_traj_median"], out["per_traj_max"] = float(np.median(per_traj)), float(per_traj.max())
    return out


def noise_floor(path_a: str, path_b: str) -> dict:
    """The exact greedy of run B against that of run A at each size both ran (``exact_b_over_a``), beside each
    run's blocked / exact ratios; the runs must share the test trajectories and differ in the training seed."""
    a, b = (json.loads(open(p, encoding="utf-8").read()) for p in (path_a, path_b))
    for key in ("n_test", "test_steps", "system"):
        if a.get(key) != b.get(key):
            raise SystemExit(f"--noise-floor: the runs differ in {key!r} ({a.get(key)!r} vs {b.get(key)!r})")
    if a["seeds"]["test"] != b["seeds"]["test"] or a["seeds"]["train"] == b["seeds"]["train"]:
        raise SystemExit("--noise-floor: the runs must share the test seed and differ in the training seed")
    rows_b = {r["max_centers"]: r for r in b["rows"]}
    rows = []
    for ra in a["rows"]:
        rb = rows_b.get(ra["max_centers"])
        if rb is None:
            continue
        rows.append(
            {
                "max_centers": ra["max_centers"],
                "exact_b_over_a": _ratios(rb["exact"], ra["exact"]),
                "blocked_over_exact_a": _ratios(ra["blocked"], ra["exact"]),
                "blocked_over_exact_b": _ratios(rb["blocked"], rb["exact"]),
            }
        )
    if not rows:
        raise SystemExit("--noise-floor: the runs share no size (max_centers)")
    return {
        "runs": {"a": path_a, "b": path_b},
        "seeds": {"a": a["seeds"], "b": b["seeds"]},
        "n_test": a["n_test"],
        "rows": rows,
    }


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--centers", type=int, nargs="+", default=[1000, 2000, 4000])
    parser.add_argument("--trajectories", type=int, default=300)
    parser.add_argument("--steps", type=int, default=60)
    parser.add_argument("--holdout", type=int, default=30, help="held-out trajectories (same length)")
    parser.add_argument("--n-test", type=int, default=20)
    parser.add_argument("--train-seed", type=int, default=1, help="the training trajectories' seed (held-out: 2)")
    parser.add_argument("--test-seed", type=int, default=3, help="the test trajectories' seed")
    parser.add_argument("--test-steps", type=int, default=200)
    parser.add_argument("--block-size", type=int, default=64)
    parser.add_argument(
        "--pool-factor", type=int, default=None, help="the blocked trainer's pool_factor (default: its own)"
    )
    parser.add_argument("--slack", type=float, default=None, help="the blocked trainer's slack (default: its own)")
    parser.add_argument("--skip-exact", action="store_true", help="blocked only (no exact baseline)")
    parser.add_argument(
        "--noise-floor", nargs=2, metavar=("A_JSON", "B_JSON"), help="compare two runs (see above); needs --json"
    )
    parser.add_argument(
        "--eps-factor",
        type=float,
        default=4.0,
        help="state shape = this times the hand setting's (the hand kernel's Gramian turns singular "
        "near 1,600 centres on these data; 4: room for 4,000 centres)",
    )
    _protocol.add_arguments(parser, threads=1, json_default="docs/data/blocked_greedy.json")
    args = parser.parse_args(argv)
    if args.noise_floor:
        if args.json == "docs/data/blocked_greedy.json":
            raise SystemExit(
                "--noise-floor writes its own JSON: give --json (e.g. docs/data/blocked_greedy_noise.json)"
            )
        record = _protocol.record_options(args, repeats=1, warmup=0, notes="derived from the two runs' JSON")
        _protocol.write_json(args.json, noise_floor(*args.noise_floor), record)
        print(f"wrote {args.json}")
        return
    bench = make_benchmarks()["coupled_pendulums"]
    settings = dict(HAND["coupled_pendulums"])
    settings["eps_state"] *= args.eps_factor
    with _protocol.limits(args.blas_threads, args.threads):
        protocol = _protocol.record_options(
            args,
            repeats=1,
            warmup=0,
            notes="one fit per trainer and size; exact and blocked side by side in one process",
        )
        data = pendulum_samples(bench, args.trajectories, args.steps, seed=args.train_seed)
        heldout = pendulum_samples(bench, args.holdout, args.steps, seed=2)
        test = make_test_set(bench, args.n_test, args.test_steps, seed=args.test_seed)
        n_fun = 4 * len(data[0])
        rate = gemm_rate(n_fun)
        print(f"{len(data[0])} samples ({n_fun} functionals); dgemm {rate['gflops']:.2f} GFLOP/s", flush=True)
        rows = []
        for m in args.centers:
            limit_s = float(m) ** 2 * n_fun / (rate["gflops"] * 1e9)
            row = {"max_centers": m, "flops": float(m) ** 2 * n_fun, "arithmetic_limit_s": limit_s}
            if not args.skip_exact:
                row["exact"] = fit_one("exact", ExactGreedy(), settings, data, heldout, test, bench, m, args)
            blocked = BlockedGreedy(block_size=args.block_size)
            for name in ("pool_factor", "slack"):
                if getattr(args, name) is not None:
                    blocked.set_params(**{name: getattr(args, name)})
            row["blocked"] = fit_one("blocked", blocked, settings, data, heldout, test, bench, m, args)
            if "exact" in row:
                e, b = row["exact"], row["blocked"]
                row["ratios"] = {
                    k: b[k] / e[k]
                    for k in ("fit_s", "greedy_s", "held_out_error", "traj_error_median", "traj_error_max")
                    if k in e and k in b and e[k]
                }
                if "traj_errors" in e and "traj_errors" in b:
                    row["ratios"].update(_ratios(b, e))
                print(
                    "  ratios blocked/exact: " + ", ".join(f"{k} {v:.3f}" for k, v in row["ratios"].items()), flush=True
                )
            rows.append(row)
            _protocol.write_json(
                args.json,
                {
                    "system": "coupled_pendulums",
                    "samples": len(data[0]),
                    "functionals": n_fun,
                    "settings": {k: v for k, v in settings.items() if k != "search"},
                    "block_size": args.block_size,
                    "n_test": args.n_test,
                    "seeds": {"train": args.train_seed, "held_out": 2, "test": args.test_seed},
                    "test_steps": args.test_steps,
                    "gemm": rate,
                    "rows": rows,
                },
                protocol,
            )
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
