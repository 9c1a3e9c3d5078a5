"""The kernel search's share of a default fit, with its fits on the exact and on the blocked greedy.

Per system of ``sympredict_paper/studies/defaults_acceptance.py`` (``--systems``), ``--samples`` one-step samples and
``max_centers`` ``--centers``, in one process:

* ``exact_search``: ``SymplecticKernelPredictor(max_centers=m, trainer=ExactGreedy())``: the search's fits and the
  final fit on the one-at-a-time greedy (the search before the blocked greedy existed);
* ``blocked``: ``SymplecticKernelPredictor(max_centers=m, trainer=BlockedGreedy())``: the search's fits and the
  final fit on the blocked greedy (the search fits with the estimator's trainer).

Recorded: fit wall time, the search's own time (``search_.seconds``) and its share of the fit, the choice
(kernels, update), the held-out one-step error of the final model and the rollout metrics of the acceptance
benchmark (median and max over ``--n-test`` test trajectories of ``--steps`` steps).

Run:  python sympredict_paper/studies/search_cost.py                                  # coupled pendulums and Kepler, 5,000 / 1,000
One BLAS and one numba thread; writes ``search_cost.json`` (``--json``).
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np

import _protocol  # sympredict_paper/studies/ (the script's folder is on sys.path)
from defaults_acceptance import make_benchmarks, make_test_set, one_step_error, trajectory_metrics

from sympredict import SymplecticKernelPredictor
from sympredict.interpolation.greedy import BlockedGreedy, ExactGreedy


def run(label, make, bench, data, heldout, test, args) -> dict:
    x0, x1, mu = data
    model = make()
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model.fit(x0, x1, mu=mu, dt=bench.dt)
    fit_s = time.perf_counter() - t0
    search_s = float(model.search_.seconds) if model.search_ is not None else 0.0
    out = {"config": label, "fit_s": fit_s, "search_s": search_s, "search_share": search_s / fit_s,
           "choice": {k: repr(v) for k, v in model.choice_.items()}, "centers": int(model.n_centers_),
           "held_out_error": one_step_error(model, heldout[0], heldout[1], heldout[2], bench.dt)}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out.update(trajectory_metrics(model, bench, test, args.steps))
    print(f"  {label:>12s}: fit {fit_s:6.1f} s, search {search_s:6.1f} s ({100 * out['search_share']:.0f} %), "
          f"held-out {out['held_out_error']:.3e}, rollout median {out.get('traj_error_median', np.nan):.3e}, "
          f"choice {out['choice']}", flush=True)
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--systems", nargs="+", default=["coupled_pendulums", "kepler"],
                        choices=["coupled_pendulums", "fpu_chain", "kepler"])
    parser.add_argument("--samples", type=int, default=5000)
    parser.add_argument("--centers", type=int, default=1000)
    parser.add_argument("--n-test", type=int, default=20)
    parser.add_argument("--steps", type=int, default=200)
    _protocol.add_arguments(parser, threads=1)
    args = parser.parse_args(argv)
    args.json = args.json or "search_cost.json"
    benches = make_benchmarks()
    rows = []
    with _protocol.limits(args.blas_threads, args.threads):
        protocol = _protocol.record(blas_threads=args.blas_threads, numba_threads=args.threads, repeats=1, warmup=0,
                                    notes="one fit per configuration, side by side in one process")
        for name in args.systems:
            bench = benches[name]
            x0, mu = bench.sample(args.samples, seed=11)
            x1 = bench.system.flow(x0, mu[:, None], bench.dt)
            h0, hmu = bench.sample(1000, seed=12)
            heldout = (h0, bench.system.flow(h0, hmu[:, None], bench.dt), hmu)
            test = make_test_set(bench, args.n_test, args.steps, seed=13)
            print(f"{name}: {args.samples} samples, {args.centers} centres", flush=True)
            row = {"system": name, "samples": args.samples, "max_centers": args.centers}
            row["exact_search"] = run("exact_search", lambda: SymplecticKernelPredictor(
                max_centers=args.centers, trainer=ExactGreedy()), bench, (x0, x1, mu), heldout, test, args)
            row["blocked"] = run("blocked", lambda: SymplecticKernelPredictor(
                max_centers=args.centers, trainer=BlockedGreedy()), bench, (x0, x1, mu), heldout, test, args)
            e, d = row["exact_search"], row["blocked"]
            row["ratios"] = {k: d[k] / e[k] for k in ("fit_s", "search_s", "held_out_error", "traj_error_median",
                                                        "traj_error_max") if e.get(k) and k in d}
            print("  ratios blocked/exact_search: " + ", ".join(f"{k} {v:.3f}" for k, v in row["ratios"].items()),
                  flush=True)
            rows.append(row)
            _protocol.write_json(args.json, {"rows": rows}, protocol)
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
