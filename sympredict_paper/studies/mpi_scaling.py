"""Pendulum scenario A training: serial greedy vs the sharded greedy on MPI ranks; writes JSON.

Serial (one process, the serial greedy of ``model.fit``, BLAS threads set with threadpoolctl)::

    .venv/bin/python sympredict_paper/studies/mpi_scaling.py --preset quick --threads 2 --out results/mpi_a.json
    .venv/bin/python sympredict_paper/studies/mpi_scaling.py --preset quick --threads 1 --out results/mpi_b.json

Sharded (P MPI ranks, one BLAS thread each, ``trainer=ShardedGreedy(pool)``)::

    .venv/bin/mpiexec -n 2 .venv/bin/python -m pymor.tools.mpi \\
        sympredict_paper/studies/mpi_scaling.py --preset quick --threads 1 --out results/mpi_c.json

Data, kernel and greedy settings are those of ``run_scenario_a`` (seed 0):
the energy-bounded grid over ``MU_TRAIN x DT_TRAIN``, ``n_val`` validation
samples on the training ``(mu, dT)`` grid, IMQ(0.2, 1.5, 3.0), ``tol=1e-10``.
Recorded: data and fit wall times, peak resident memory of every rank, the
selection (to check that every mode selects the same functionals), per-step
timings (serial: from ``history_.elapsed``; sharded: the two pool calls and
each worker's compute time), and the round-trip latency of empty pool calls.
``--compare A.json B.json ...`` prints a table and checks equal selections.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import resource
import sys
import time
from pathlib import Path

import numpy as np

# this file's folder, sympredict_paper/studies/ (under `python -m pymor.tools.mpi` the script is exec'd: __file__ is pymor's)
sys.path.insert(0, str(Path(sys._getframe().f_code.co_filename).resolve().parent))
import _protocol  # noqa: E402  (sympredict_paper/studies/_protocol.py)


def _peak_rss_bytes() -> int:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def _step_profile(step_seconds: np.ndarray, n_functionals: int) -> dict:
    """Per-step time against the step index: ``t(m) ~ a + b m``; ``b / N`` is the time per basis entry."""
    m = np.arange(len(step_seconds))
    b, a = np.polyfit(m, step_seconds, 1) if len(m) > 2 else (np.nan, np.nan)
    return {
        "fit_a_s": float(a),
        "fit_b_s_per_centre": float(b),
        "ns_per_basis_entry": float(b / n_functionals * 1e9),
        "median_s": float(np.median(step_seconds)),
        "total_s": float(step_seconds.sum()),
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="quick", choices=["smoke", "quick", "paper"])
    _protocol.add_arguments(parser, json_option=False, blas_alias="--threads")  # BLAS threads per process
    parser.add_argument("--max-centers", type=int, default=None, help="override the preset's greedy budget")
    parser.add_argument("--out", default=None, help="JSON file to write")
    parser.add_argument("--compare", nargs="+", default=None, help="JSON files to tabulate (no run)")
    parser.add_argument("--project", default=None, help="JSON of a sharded run: project the greedy loop to more ranks")
    parser.add_argument(
        "--latency-us",
        type=float,
        default=5.0,
        help="assumed point-to-point latency between nodes for --project (InfiniBand ~2-5, TCP ~30-50)",
    )
    args = parser.parse_args(argv)
    if args.compare:
        return compare(args.compare)
    if args.project:
        return project(args.project, args.latency_us)

    from pymor.tools import mpi

    with _protocol.limits(args.blas_threads):
        return _run(args, mpi)


def _run(args, mpi) -> int:

    from sympredict import SymplecticKernelPredictor, parallel as par
    from sympredict.interpolation.greedy import ExactGreedy, ShardedGreedy
    from sympredict_paper.pendulum import PRESETS
    from sympredict.kernels import IMQ
    from sympredict.systems.pendulum import DT_TRAIN, MU_TRAIN, Pendulum, flow_map_data, random_flow_map_data

    preset = PRESETS[args.preset]
    max_centers = args.max_centers or preset.max_centers
    sharded = mpi.parallel
    pool = None
    out = {"preset": args.preset, "threads_per_rank": args.blas_threads, "max_centers": max_centers}
    if sharded:
        from pymor.parallel.default import new_parallel_pool

        pool = new_parallel_pool()
        par.set_blas_threads(pool, args.blas_threads)
        out["mode"] = f"sharded, {len(pool)} MPI ranks x {args.blas_threads} BLAS thread(s)"
        out["ranks"] = len(pool)
        # latency of an empty round trip through the pool (what every greedy step pays twice)
        lat = {}
        for name, call in [("apply", lambda: pool.apply(abs, 0)), ("apply_only", lambda: pool.apply_only(abs, 1, 0))]:
            call()
            t0 = time.perf_counter()
            for _ in range(300):
                call()
            lat[name + "_us"] = (time.perf_counter() - t0) / 300 * 1e6
        out["pool_call_latency"] = lat
    else:
        out["mode"] = f"serial greedy, 1 process x {args.blas_threads} BLAS thread(s)"
        out["ranks"] = 1

    system = Pendulum()
    t0 = time.perf_counter()
    if sharded:
        data = flow_map_data(system, n_grid=preset.n_grid, pool=pool)
        val = random_flow_map_data(system, preset.n_val, seed=1, mu_values=MU_TRAIN, dt_values=DT_TRAIN, pool=pool)
    else:
        data = flow_map_data(system, n_grid=preset.n_grid)
        val = random_flow_map_data(system, preset.n_val, seed=1, mu_values=MU_TRAIN, dt_values=DT_TRAIN)
    out["time_data_s"] = time.perf_counter() - t0
    out["data_sha1"] = hashlib.sha1(np.concatenate([data.x1.ravel(), val.x1.ravel()]).tobytes()).hexdigest()
    n_functionals = 2 * len(data)
    out["n_functionals"] = n_functionals
    out["n_val_functionals"] = 2 * len(val)

    eps = preset.eps
    model = SymplecticKernelPredictor(
        IMQ(eps[0]),
        IMQ(eps[1]),
        IMQ(eps[2]),
        max_centers=max_centers,
        trainer=ShardedGreedy(pool, tol=1e-10) if sharded else ExactGreedy(tol=1e-10),
    )
    t0 = time.perf_counter()
    model.fit(data.x0, data.x1, mu=data.mu, dt=data.dt, validation=val)
    stats = model.greedy_result_.stats
    out["time_fit_s"] = time.perf_counter() - t0
    hist = model.history_
    out["n_centers"] = model.n_centers_
    out["stop_reason"] = hist.stop_reason
    out["E_train"] = float(hist.train_max_residual[-1])
    out["E_val"] = float(hist.val_max_residual[-1])
    sel = np.asarray(model.greedy_result_.selected)
    out["selected_sha1"] = hashlib.sha1(sel.astype(np.int64).tobytes()).hexdigest()
    out["selected_first"] = sel[:20].tolist()
    out["coef_abs_sum"] = float(np.abs(model.surrogate_.coef).sum())
    steps = np.diff(np.concatenate([[0.0], hist.elapsed]))
    out["greedy_loop_s"] = float(hist.elapsed[-1])
    out["step_profile"] = _step_profile(steps, n_functionals)
    if sharded:
        rss = [r.ru_maxrss * 1024 for r in pool.apply(resource.getrusage, resource.RUSAGE_SELF)]
        comp = stats["worker_compute"]
        comm = stats["step_call"] - comp.max(axis=1)
        out["peak_rss_bytes_per_rank"] = rss
        out["sharded"] = {
            "shard_sizes": stats["shard_sizes"].tolist(),
            "compute_per_rank_total_s": comp.sum(axis=0).tolist(),
            "compute_max_profile": _step_profile(comp.max(axis=1), n_functionals // out["ranks"]),
            "winner_call_total_s": float(stats["winner_call"].sum()),
            "winner_call_median_us": float(np.median(stats["winner_call"]) * 1e6),
            "step_call_total_s": float(stats["step_call"].sum()),
            "step_overhead_median_us": float(np.median(comm) * 1e6),
            "step_overhead_total_s": float(comm.sum()),
            "imbalance_total_s": float((comp.max(axis=1) - comp.min(axis=1)).sum()),
        }
    else:
        out["peak_rss_bytes_per_rank"] = [_peak_rss_bytes()]
    out["protocol"] = _protocol.record_options(args, repeats=1, statistic="one fit; pool latency: mean of 300 calls")
    text = json.dumps(out, indent=1)
    print(text, flush=True)
    if args.out:
        with open(args.out, "w") as f:
            f.write(text + "\n")
    return 0


def compare(paths) -> int:
    runs = [json.load(open(p)) for p in paths]
    print("| run | functionals | centres | data s | fit s | greedy loop s | peak RSS per rank (GiB) |")
    print("|---|---|---|---|---|---|---|")
    for r in runs:
        rss = ", ".join(f"{b / 2**30:.2f}" for b in r["peak_rss_bytes_per_rank"])
        print(
            f"| {r['mode']} | {r['n_functionals']:,} | {r['n_centers']} | {r['time_data_s']:.1f} | {r['time_fit_s']:.1f} | "
            f"{r['greedy_loop_s']:.1f} | {rss} |"
        )
    same = len({r["selected_sha1"] for r in runs}) == 1
    same_data = len({r.get("data_sha1") for r in runs}) == 1
    print(f"\nsame data in all runs (bit for bit): {same_data}; same selection in all runs: {same}")
    return 0 if same and same_data else 1


def project(path, latency_us: float, ranks=(2, 4, 8, 16, 32, 64, 128), functionals=(None, 688464)) -> int:
    """Greedy-loop time at P ranks from one measured sharded run (a model, not a measurement).

    Per step ``m`` the slowest rank computes ``(a + b m) (N / P) / (N_meas / P_meas)`` seconds
    (``a``, ``b``: straight-line fit of the measured per-step maximum over ranks; this
    keeps the measured per-core memory bandwidth, i.e. it assumes a node sustains
    the bandwidth per core seen here with every core busy), and the driver adds
    the measured per-step overhead of the two pool calls, ``o_meas``, plus
    ``2 (2 latency log2(P / P_meas) + (P - P_meas) g)``: two tree collectives and
    ``g`` = 5 us of driver-side unpickling per extra rank report.
    """
    r = json.load(open(path))
    sh = r["sharded"]
    a = sh["compute_max_profile"]["fit_a_s"]
    b = sh["compute_max_profile"]["fit_b_s_per_centre"]
    p0 = r["ranks"]
    n0 = r["n_functionals"]
    m_total = r["n_centers"]
    o_meas = (sh["step_overhead_median_us"] + sh["winner_call_median_us"]) * 1e-6
    g = 5e-6
    lat = latency_us * 1e-6
    print(
        f"measured at P={p0}, N={n0:,}, {m_total} centres: per-step compute (slowest rank) {a * 1e3:.2f} ms + "
        f"{b * 1e6:.2f} us x m; per-step overhead {o_meas * 1e6:.0f} us; loop {r['greedy_loop_s']:.1f} s"
    )
    print("| N | ranks | compute s | overhead s | loop s | speed-up vs 2 ranks |")
    print("|---|---|---|---|---|---|")
    for n in functionals:
        n = n or n0
        base = None
        for p in ranks:
            scale = (n / p) / (n0 / p0)
            compute = sum((a + b * m) * scale for m in range(m_total))
            overhead = m_total * (o_meas + 2 * (2 * lat * max(0.0, np.log2(p / p0)) + max(0, p - p0) * g))
            total = compute + overhead
            base = base or total
            print(f"| {n:,} | {p} | {compute:.1f} | {overhead:.1f} | {total:.1f} | {base / total:.1f}x |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
