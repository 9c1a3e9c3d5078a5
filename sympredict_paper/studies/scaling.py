"""Training cost against samples, centres and state dimension: the exact and the blocked greedy, scikit-learn's GPR.

Greedy runs (``trainer.run`` on the state-derivative functionals of ``M`` one-step samples, ``N = 2n M``
functionals, ``max_centers = m``, IMQ kernels of shape ``0.5 / sqrt(2n)`` and 1) of one of two problems
(``--system``):

* ``fpu`` (the default): the FPU-beta chain of ``n`` masses of ``memory_bound.py`` (``2n``-D state, the quartic
  coefficient as the parameter), samples from trajectories of 20 steps at an energy of 0.0375 J per mass; the mixed variables ``(q0, p1)`` centred
  and scaled per coordinate to the spread of ``[-1, 1]`` (the targets ``J^T (x1 - x0) / dT`` scaled with them),
  the parameter mapped to ``[0.5, 1.5]``;
* ``random``: random points in ``[-1, 1]^{2n}`` with one parameter in ``[0.5, 1.5]``, targets the gradient of
  ``mu sum cos(3 xi) + |xi|^4 / 4``.

Three sweeps:

* samples: ``2n = 4``, ``m = --m``, ``M`` in ``--points``;
* centres: ``2n = 4``, ``M = --m-points``, ``m`` in ``--centers``;
* dimension: ``M = --dim-points``, ``m = --m``, ``2n`` in ``--dims`` (``N`` grows with ``2n``).

Per run: the greedy's peak traced memory (a run under ``tracemalloc``: NumPy's allocations; it is also the
warm-up) and its wall time (a second run, no tracemalloc), the trainers' memory formula
(:func:`sympredict.interpolation.greedy.trainer_memory`) and the arithmetic limit ``m^2 N`` flops at this
process's ``dgemm`` rate.  Fitted exponents: least-squares slopes of ``log time`` (and ``log memory``) against
``log N``, ``log m``, ``log 2n``.

Peer: scikit-learn's ``GaussianProcessRegressor`` (fixed RBF kernel, ``optimizer=None``, a Cholesky factorisation
of the ``M x M`` kernel matrix: ``O(M^3)`` time, ``O(M^2)`` memory) on ``M`` in ``--gpr-points`` point values.

Large data in bounded memory (100,000 samples of an 8-D state): ``memory_bound.py``.

Run:  python sympredict_paper/studies/scaling.py                 # a few minutes on 2 cores
One BLAS and one numba thread; writes ``docs/data/scaling.json`` (``--json``).
"""

from __future__ import annotations

import argparse
import time
import tracemalloc

import numpy as np

import _protocol  # sympredict_paper/studies/ (the script's folder is on sys.path)

from sympredict.data import mixed_variables
from sympredict.interpolation.functionals import HBFunctionals
from sympredict.interpolation.greedy import BlockedGreedy, ExactGreedy, trainer_memory
from sympredict.kernels import IMQ, ProductKernel


def problem(n_points: int, dim: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    xi = rng.uniform(-1, 1, size=(n_points, dim))
    mu = rng.uniform(0.5, 1.5, size=(n_points, 1))
    y = -3 * mu * np.sin(3 * xi) + xi * (xi**2).sum(axis=1, keepdims=True)
    kernel = ProductKernel(IMQ(0.5 / np.sqrt(dim)), IMQ(1.0))
    return HBFunctionals(kernel, xi, mu, np.full(n_points, 0.1)), y.ravel()


def fpu_problem(n_points: int, dim: int, seed: int = 0):
    """One-step samples of the FPU-beta chain with ``dim / 2`` masses, as the greedy's functionals."""
    from memory_bound import BETA, chain, samples  # sympredict_paper/studies/

    # energy per mass fixed (the chain's 4-mass level, 0.15 J / 4) and a box shrunk to 0.35 of the chain's, so
    # that its states mostly lie below it and rejection sampling works in 32 dimensions too
    x0, x1, beta, dt = samples(
        chain(dim // 2), -(-n_points // 20), 20, seed, energy=0.0375 * (dim // 2), box=(0.035, 0.063)
    )
    x0, x1, beta, dt = x0[:n_points], x1[:n_points], beta[:n_points], dt[:n_points]
    xi, y = mixed_variables(x0, x1, dt)
    scale = xi.std(axis=0) / np.sqrt(1.0 / 3.0)  # the spread of uniform [-1, 1]
    xi = (xi - xi.mean(axis=0)) / scale
    y = y * scale  # the gradient in the scaled coordinates
    mu = 0.5 + (beta[:, None] - BETA[0]) / (BETA[1] - BETA[0])
    kernel = ProductKernel(IMQ(0.5 / np.sqrt(dim)), IMQ(1.0))
    return HBFunctionals(kernel, xi, mu, dt), y.ravel()


def greedy_run(trainer, fun, y, m, memory: bool) -> dict:
    if memory:
        tracemalloc.start()
    t0 = time.perf_counter()
    result = trainer.run(fun, y, max_centers=m, log_every=0)
    seconds = time.perf_counter() - t0
    out = {"seconds": seconds, "centers": len(result.selected), "stop": result.history.stop_reason}
    if memory:
        out["peak_bytes"] = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    return out


def measure(fun, y, m, rate, trainers) -> dict:
    n = fun.n_functionals
    row = {
        "N": n,
        "points": len(fun.points),
        "dim": fun.dim,
        "m": m,
        "flops": float(m) ** 2 * n,
        "arithmetic_limit_s": float(m) ** 2 * n / rate,
    }
    for name, trainer in trainers.items():
        mem = greedy_run(trainer, fun, y, m, memory=True)  # first: also the warm-up (compilation, caches)
        timed = greedy_run(trainer, fun, y, m, memory=False)
        row[name] = {
            "seconds": timed["seconds"],
            "centers": timed["centers"],
            "stop": timed["stop"],
            "peak_bytes": mem["peak_bytes"],
            "formula_bytes": trainer_memory(trainer, n, 0, m),
        }
    print(
        f"  N={n:6d} m={m:5d} 2n={fun.dim:2d}: "
        + ", ".join(f"{k} {row[k]['seconds']:.2f} s / {row[k]['peak_bytes'] / 2**20:.0f} MiB" for k in trainers)
        + f", limit {row['arithmetic_limit_s']:.2f} s",
        flush=True,
    )
    return row


def slope(x, y) -> float:
    return float(np.polyfit(np.log(np.asarray(x, float)), np.log(np.asarray(y, float)), 1)[0])


def gemm_rate() -> float:
    rng = np.random.default_rng(0)
    a, v = rng.normal(size=(64, 1000)), rng.normal(size=(1000, 32000))
    times = []
    for _ in range(4):
        t0 = time.perf_counter()
        a @ v
        times.append(time.perf_counter() - t0)
    return 2.0 * 64 * 1000 * 32000 / float(np.median(times[1:]))


def gpr_sweep(points) -> list:
    from sklearn.gaussian_process import GaussianProcessRegressor
    from sklearn.gaussian_process.kernels import RBF

    rows = []
    for n_points in points:
        rng = np.random.default_rng(1)
        x = rng.uniform(-1, 1, size=(n_points, 5))
        y = np.cos(3 * x).sum(axis=1)
        tracemalloc.start()
        GaussianProcessRegressor(RBF(0.5), alpha=1e-8, optimizer=None).fit(x, y)
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        gpr = GaussianProcessRegressor(RBF(0.5), alpha=1e-8, optimizer=None)
        t0 = time.perf_counter()
        gpr.fit(x, y)
        seconds = time.perf_counter() - t0
        rows.append({"points": n_points, "seconds": seconds, "peak_bytes": peak})
        print(f"  GPR M={n_points}: {seconds:.2f} s, {peak / 2**20:.0f} MiB", flush=True)
    return rows


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--points", type=int, nargs="+", default=[2000, 4000, 8000, 16000])
    parser.add_argument("--m", type=int, default=500)
    parser.add_argument("--m-points", type=int, default=4000)
    parser.add_argument("--centers", type=int, nargs="+", default=[250, 500, 1000, 2000])
    parser.add_argument("--dim-points", type=int, default=2000)
    parser.add_argument("--dims", type=int, nargs="+", default=[2, 4, 8, 16, 32])
    parser.add_argument("--gpr-points", type=int, nargs="+", default=[1000, 2000, 4000])
    parser.add_argument("--system", choices=("fpu", "random"), default="fpu", help="the greedy's problem")
    _protocol.add_arguments(parser, threads=1, json_default="docs/data/scaling.json")
    args = parser.parse_args(argv)
    trainers = {"exact": ExactGreedy(tol=0), "blocked": BlockedGreedy(tol=0)}
    out = {"system": args.system}
    with _protocol.limits(args.blas_threads, args.threads):
        protocol = _protocol.record_options(
            args, repeats=1, warmup=0, notes="one timed and one traced run per size and trainer, in one process"
        )
        rate = gemm_rate()
        out["gemm_gflops"] = rate / 1e9
        print(f"dgemm {rate / 1e9:.1f} GFLOP/s", flush=True)
        sweeps = {
            "samples": [(p, 4, args.m) for p in args.points],
            "centers": [(args.m_points, 4, m) for m in args.centers],
            "dim": [(args.dim_points, d, args.m) for d in args.dims],
        }
        for name, sizes in sweeps.items():
            print(f"sweep over {name}", flush=True)
            rows = []
            for n_points, dim, m in sizes:
                fun, y = (fpu_problem if args.system == "fpu" else problem)(n_points, dim)
                rows.append(measure(fun, y, m, rate, trainers))
            key = {"samples": "N", "centers": "m", "dim": "dim"}[name]
            x = [r[key] for r in rows]
            exps = {
                t: {
                    "time": slope(x, [r[t]["seconds"] for r in rows]),
                    "memory": slope(x, [r[t]["peak_bytes"] for r in rows]),
                }
                for t in trainers
            }
            exps["arithmetic_limit"] = {"time": slope(x, [r["arithmetic_limit_s"] for r in rows])}
            out[name] = {"variable": key, "rows": rows, "exponents": exps}
            print("  exponents: " + ", ".join(f"{t} {e['time']:.2f}" for t, e in exps.items()), flush=True)
            _protocol.write_json(args.json, out, protocol)
        print("scikit-learn GPR", flush=True)
        gpr = gpr_sweep(args.gpr_points)
        out["gpr"] = {
            "rows": gpr,
            "exponents": {
                "time": slope([r["points"] for r in gpr], [r["seconds"] for r in gpr]),
                "memory": slope([r["points"] for r in gpr], [r["peak_bytes"] for r in gpr]),
            },
        }
        _protocol.write_json(args.json, out, protocol)
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
