"""The compiled Newton pass against the kernel-factor cost, and rollout throughput: this tree against a revision, side by side.

One command (from the repository root, the project's virtual environment)::

    .venv/bin/python sympredict_paper/studies/newton_pass.py --against 75d2b66 --threads 2

The model is the benchmark suite's (``sympredict_paper/studies/suite.py``: pendulum quick data,
50 x 50 grid, IMQ (0.15, 2, 5), exact f-greedy to 1,500 centres); the batch its
1,000 instances (``q0`` in [0, pi/2], ``p0 = 0``, ``l`` in [0.7, 0.8], ``dT`` in
[0.045, 0.055]).  ``--against REV`` loads that revision's
``sympredict/_fastkernels.py`` (revisions from before the compiled code moved
beside its users) as a second module into this process (compiled without
numba's disk cache), so both implementations run on the same model, the same
inputs and the same machine state, interleaved.  This tree's side is
:func:`this_tree`.

Measured per implementation (and per start: ``cold`` = explicit guess, ``warm`` =
previous step's increment, where the implementation has it):

* passes over the centres per macro step (deterministic counts);
* ns per centre visit of the serial rollout on one thread: the minimum over
  ``--samples`` short runs (10 instances x 20 steps, a few ms each), so that
  other processes on the machine stretch no sample that counts;
* the kernel-factor cost: the family's ``(A, B, C)`` loop alone on a chunk of
  256 distances in L1, minimum over as many short runs
  (:func:`sympredict.interpolation._compiled.factor_throughput` ``in_cache=True``, this
  tree's probe, measured next to each implementation), and the older probe
  (one loop over 1M distances, median) for reference;
* ``ratio`` = ns per centre visit / factor ns (L1 probe);
* trajectory-steps per second of the full batch (1,000 x 20 steps) on
  ``--threads`` numba threads, the best of ``--repeats`` runs.

All cases run side by side, interleaved, after a warm-up (``sympredict_paper/studies/_protocol.py``;
this script reports minima, not medians: the statistic is stated in the JSON).
Writes ``--json`` if given (with the protocol record) and prints a table.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import subprocess
import sys
import tempfile
import types
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "sympredict_paper" / "studies"))

from pymor.core.logger import set_log_levels  # noqa: E402

import _protocol  # noqa: E402  (sympredict_paper/studies/_protocol.py)
from sympredict.interpolation import _compiled as compiled_surrogate  # noqa: E402
from sympredict.symplectic import _compiled_newton  # noqa: E402
from sympredict.io import load_model, save_model  # noqa: E402
from sympredict.kernels import IMQ  # noqa: E402


def this_tree() -> types.SimpleNamespace:
    """This tree's compiled Newton code under the names a revision's ``_fastkernels`` module has."""
    return types.SimpleNamespace(
        newton_rollout=_compiled_newton.newton_rollout,
        CenterLayout=compiled_surrogate.CenterLayout,
        newton_terms=compiled_surrogate.newton_terms,
        factor_throughput=compiled_surrogate.factor_throughput,
    )


def load_revision(rev: str, where: Path):
    """``sympredict/_fastkernels.py`` of ``rev`` as a module (older revisions: numba's disk cache off for it; newer:
    cached next to the copy in ``where``)."""
    src = subprocess.run(
        ["git", "-C", str(ROOT), "show", f"{rev}:sympredict/_fastkernels.py"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    src = src.replace("_build(cache)", "_build(False)")
    path = where / f"_fastkernels_{rev.replace('/', '_')}.py"
    path.write_text(src)
    spec = importlib.util.spec_from_file_location(path.stem, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def factor_chunk_seconds(samples: int) -> float:
    """Seconds per factor evaluation of the family's loop alone on one chunk of distances in L1 (minimum of short runs;
    :func:`sympredict.interpolation._compiled.factor_throughput` with ``in_cache=True``, this tree's definition for both sides)."""
    return compiled_surrogate.factor_throughput(n=1 << 19, eps=0.15, repeats=samples, in_cache=True)


def measure(modules: dict, sur, x0, w, dt, *, steps: int, samples: int, repeats: int) -> dict:
    """Every (implementation, start) side by side: the samples alternate between them, each keeps its minimum."""
    kernel = sur.kernel.state
    cases = {}
    for label, module in modules.items():
        layout = module.CenterLayout(sur.centers_xi, sur.components)
        for start in ("cold", "warm"):
            if start == "warm" and "warm_start" not in module.newton_rollout.__code__.co_varnames:
                continue
            kw = {"warm_start": True} if start == "warm" else {}
            cases[label, start] = (module, layout, kw)
    sub = slice(0, 10)
    out = {}
    for key, (module, layout, kw) in cases.items():
        stats, stats_b = {}, {}
        module.newton_rollout(x0[sub], w[sub], dt[sub], layout, kernel, 50, steps, parallel=False, stats=stats, **kw)
        module.newton_rollout(x0, w, dt, layout, kernel, 50, steps, stats=stats_b, **kw)
        out[key] = {
            "passes": float(stats["passes"].sum()),
            "passes_per_step_batch": float(stats_b["passes"].sum()) / (len(x0) * steps),
        }
    single = _protocol.side_by_side(
        {
            key: (
                lambda m=module, lay=layout, kw=kw: m.newton_rollout(
                    x0[sub], w[sub], dt[sub], lay, kernel, 50, steps, parallel=False, **kw
                )
            )
            for key, (module, layout, kw) in cases.items()
        },
        repeats=samples,
        statistic="min_s",
    )
    batch = _protocol.side_by_side(
        {
            key: (lambda m=module, lay=layout, kw=kw: m.newton_rollout(x0, w, dt, lay, kernel, 50, steps, **kw))
            for key, (module, layout, kw) in cases.items()
        },
        repeats=repeats,
        statistic="min_s",
    )
    for key in cases:
        out[key]["t1"] = single["methods"][key]["min_s"]
        out[key]["tb"] = batch["methods"][key]["min_s"]
    results = {}
    for (label, start), o in out.items():
        results.setdefault(label, {})[start] = {
            "passes_per_step": o["passes"] / (10 * steps),
            "passes_per_step_batch": o["passes_per_step_batch"],
            "ns_per_centre_visit_1_thread": 1e9 * o["t1"] / (o["passes"] * sur.n_centers),
            "traj_steps_per_s": len(x0) * steps / o["tb"],
        }
    return results


def pass_vs_dim(modules: dict, dims, samples: int, m: int = 1500, points: int = 100) -> dict:
    """ns per centre of one pass (gradient; + Hessian block; + full Hessian) on synthetic surrogates, by 2n.

    Random centres in [-1, 1]^2n with random components, IMQ(0.5); ``points`` query points per sample,
    the minimum over ``samples``, implementations alternating.  Revisions without the full Hessian report
    the block only.
    """
    from sympredict.interpolation.surrogate import HBSurrogate
    from sympredict.kernels import ProductKernel

    out = {}
    for dim in dims:
        rng = np.random.default_rng(dim)
        sur = HBSurrogate(
            ProductKernel(IMQ(0.5), IMQ(1.0), None),
            rng.uniform(-1, 1, (m, dim)),
            rng.uniform(0, 1, (m, 1)),
            np.ones(m),
            rng.integers(0, dim, m),
            1e-2 * rng.standard_normal(m),
        )
        xi = rng.uniform(-1, 1, (points, dim))
        w = np.ascontiguousarray(np.repeat(sur.weights(np.full((1, 1), 0.5), np.ones(1)), points, axis=0))
        runs = {}
        for label, module in modules.items():
            layout = module.CenterLayout(sur.centers_xi, sur.components)
            full = "full" in module.newton_terms.__code__.co_varnames
            runs[f"{label} block"] = lambda mod=module, lay=layout: mod.newton_terms(xi, w, lay, IMQ(0.5))
            if full:
                runs[f"{label} full"] = lambda mod=module, lay=layout: mod.newton_terms(xi, w, lay, IMQ(0.5), full=True)
        best = _protocol.side_by_side(runs, repeats=samples, statistic="min_s")["methods"]
        out[dim] = {key: 1e9 * t["min_s"] / (points * m) for key, t in best.items()}
    return out


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--against", default=None, help="git revision to compare with (its _fastkernels.py)")
    parser.add_argument("--batch", type=int, default=1000)
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--samples", type=int, default=60, help="short runs per single-thread timing (minimum taken)")
    _protocol.add_arguments(
        parser,
        threads=2,
        threads_help="numba threads of the full-batch rollout",
        repeats=10,
        repeats_help="full-batch runs (best taken)",
    )
    parser.add_argument(
        "--dims", default="", help="also the pass cost by 2n on synthetic surrogates, e.g. 2,4,10,20,40"
    )
    parser.add_argument(
        "--model", default=None, help="model file: loaded if it exists, else the fitted model is saved there"
    )
    args = parser.parse_args(argv)
    set_log_levels({"sympredict": "WARNING", "pymor": "WARN"})
    import suite  # the suite's model and inputs

    threads = min(args.threads, os.cpu_count())
    with _protocol.limits(args.blas_threads, numba_threads=threads), tempfile.TemporaryDirectory() as tmp:
        print("pendulum model (quick data, 1500 centres) ...", flush=True)
        if args.model and Path(args.model).exists():
            model = load_model(args.model)
        else:
            model, _ = suite.pendulum_model()
            if args.model:
                save_model(model, args.model)
        sur = model.surrogate_
        x0, mu, dt = suite._rollout_inputs(args.batch)
        w = sur.weights(mu[:, None], dt)
        modules = {"this tree": this_tree()}
        if args.against:
            modules[args.against] = load_revision(args.against, Path(tmp))
        for label, module in modules.items():  # compile and warm up
            module.newton_rollout(
                x0[:16], w[:16], dt[:16], module.CenterLayout(sur.centers_xi, sur.components), sur.kernel.state, 50, 2
            )
        results = measure(modules, sur, x0, w, dt, steps=args.steps, samples=args.samples, repeats=args.repeats)
        by_dim = (
            pass_vs_dim(modules, [int(d) for d in args.dims.split(",")], max(5, args.samples // 6))
            if args.dims
            else None
        )
        factor = 1e9 * factor_chunk_seconds(args.samples)  # one probe (this tree's) for both
        for label, module in modules.items():
            results[label]["factor_ns_l1"] = factor
            results[label]["factor_ns_1M_median"] = 1e9 * module.factor_throughput()
        protocol = _protocol.record(
            blas_threads=args.blas_threads,
            numba_threads=threads,
            repeats=args.samples,
            warmup=1,
            statistic="min (single-thread samples and full-batch repeats, interleaved)",
        )
    lines = [
        f"{model.n_centers_} centres, batch {args.batch}, {args.steps} steps; {args.threads} numba thread(s) for the "
        f"batch, 1 for the pass",
        "",
        "| implementation | start | passes/step | ns per centre visit (1 thread) | factor ns (L1 / 1M) | pass / factor "
        "| traj-steps/s |",
        "|---|---|---|---|---|---|---|",
    ]
    for label, r in results.items():
        for start in ("cold", "warm"):
            if start not in r:
                continue
            m = r[start]
            m["ratio"] = m["ns_per_centre_visit_1_thread"] / r["factor_ns_l1"]
            lines.append(
                f"| {label} | {start} | {m['passes_per_step']:.2f} | {m['ns_per_centre_visit_1_thread']:.2f} | "
                f"{r['factor_ns_l1']:.2f} / {r['factor_ns_1M_median']:.2f} | {m['ratio']:.2f} | "
                f"{m['traj_steps_per_s']:,.0f} |"
            )
    out = {"args": vars(args), "results": results}
    if by_dim:
        out["pass_vs_dim"] = by_dim
        keys = list(next(iter(by_dim.values())))
        lines += [
            "",
            "ns per centre of one pass, 1,500 random centres, 1 thread:",
            "",
            "| 2n | " + " | ".join(keys) + " |",
            "|---|" + "---|" * len(keys),
        ]
        for dim, r in by_dim.items():
            lines.append(f"| {dim} | " + " | ".join(f"{r[k]:.2f}" for k in keys) + " |")
    print("\n".join(lines))
    if args.json:
        _protocol.write_json(args.json, out, protocol)
    return out


if __name__ == "__main__":
    main()
