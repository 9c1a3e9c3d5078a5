"""A fit whose Newton basis exceeds the memory: the default trainer's choice, its peak memory and its accuracy.

System: an FPU-beta chain of ``--masses`` masses (4: a state of ``2n = 8``) ``m = 0.1 kg`` between fixed walls,
springs ``k = 40 N/m`` with a quartic term ``beta`` in [1000, 3000] N/m^3 (the one parameter),
``H = sum p_i^2 / (2 m) + sum_i k d_i^2 / 2 + beta d_i^4 / 4``, ``d_i = q_{i+1} - q_i``, ``q_0 = q_{n+1} = 0``;
states uniform in ``H <= 0.15 J``, ``dT = 0.015 s``; RK4 reference flow with step halving to ``rtol = 1e-11``.
Training data: ``--samples`` one-step pairs from trajectories of ``--steps`` steps, each with its own ``beta``;
held-out: ``--holdout`` samples from other trajectories (seed disjoint).  Kernels fixed (the chain's hand settings
of ``defaults_acceptance.py``, shapes relative to the data), so the fit's cost is the greedy's.

The fit: ``SymplecticKernelPredictor`` without ``trainer``: :func:`sympredict.interpolation.greedy.default_trainer`
picks the trainer by the trainers' memory formulas against the memory it has (``--memory`` sets
``SYMPREDICT_MEMORY``, as a user would on a machine shared with others; default 24 GiB, the machine the
full-size check is for, so that a larger machine runs the same configuration: check ``peak_rss_bytes``).
Recorded: the trainer chosen and why (its log line), the slots of a bounded active set, the fit's wall time,
the greedy's time and its refresh share, the process's peak resident memory (``ru_maxrss``) before and after
the fit, the formula's peak (:func:`sympredict.interpolation.greedy.trainer_memory`), the held-out error
(mean relative one-step error ``|Phi(x0) - x1| / |x1 - x0|``), the full training residual of the model.

``--compare``: the same data also with ``ExactGreedy()`` (where its basis fits) and with
``BoundedActiveSetGreedy`` whose budget gives its slots ``--slot-fraction`` of the points: held-out error ratio
bounded / exact at equal centres.

``--project-samples/--project-centers``: the time and memory of the full size from this run's measured parts
(blocks ``~ S m^2`` in products and ``~ S m`` besides, each refresh's evaluation ``~ N m``, its swap
``~ m^2`` per point swapped in) and the formula.

Run:  python sympredict_paper/studies/memory_bound.py --samples 100000 --dim 8 --centers 4000 --threads 2 --json OUT
      python sympredict_paper/studies/memory_bound.py --samples 10000 --centers 500 --memory 0.2G      # a minute
      python sympredict_paper/studies/memory_bound.py --samples 20000 --centers 1000 --memory 0.6G --compare   # 5 minutes
"""

from __future__ import annotations

import argparse
import logging
import os
import resource
import time

import numpy as np

import _protocol  # sympredict_paper/studies/ (the script's folder is on sys.path)
from blocked_greedy import gemm_rate
from defaults_acceptance import HAND, _rejection, hand_model

from sympredict.interpolation.greedy import (
    BlockedGreedy,
    BoundedActiveSetGreedy,
    ExactGreedy,
    available_memory,
    trainer_memory,
)
from sympredict.interpolation.greedy.active_set import bounded_capacity, bounded_memory
from sympredict.systems.flowmaps import HamiltonianSystem

MASS, SPRING, ENERGY, DT = 0.1, 40.0, 0.15, 0.015
BETA = (1000.0, 3000.0)


def chain(n: int) -> HamiltonianSystem:
    """The FPU-beta chain of ``n`` masses between fixed walls (``2n``-D state, parameter ``beta``)."""

    def elongations(q):
        z = np.zeros((len(q), 1))
        return np.diff(np.concatenate([z, q, z], axis=1), axis=1)  # (B, n + 1)

    def H(x, mu):
        q, p = x[:, :n], x[:, n:]
        d = elongations(q)
        return (p**2).sum(1) / (2 * MASS) + (0.5 * SPRING * d**2 + 0.25 * mu[:, :1] * d**4).sum(1)

    def grad(x, mu):
        q, p = x[:, :n], x[:, n:]
        d = elongations(q)
        f = SPRING * d + mu[:, :1] * d**3  # spring forces; dV/dq_i = f_{i-1} - f_i
        return np.concatenate([f[:, :n] - f[:, 1:], p / MASS], axis=1)

    system = HamiltonianSystem(H, grad, 2 * n, parameters={"beta": 1}, rtol=1e-11)
    system.energy = H
    return system


def samples(system, n_traj: int, steps: int, seed: int, energy: float = ENERGY, box=(0.1, 0.18)):
    """One-step pairs ``(x0, x1, mu, dt)`` from ``n_traj`` trajectories of ``steps`` steps, each with its own beta.

    Start states uniform in ``H <= energy`` by rejection from the box ``|q_i| <= box[0]``, ``|p_i| <= box[1]``.
    """
    rng = np.random.default_rng(seed)
    n = system.dim // 2
    beta = rng.uniform(*BETA, n_traj)
    x0 = _rejection(system.energy, beta, rng, [-box[0]] * n + [-box[1]] * n, [box[0]] * n + [box[1]] * n, energy)
    traj = system.trajectory(x0, beta[:, None], DT, steps)
    a, b = traj[:, :-1].reshape(-1, system.dim), traj[:, 1:].reshape(-1, system.dim)
    return a, b, np.repeat(beta, steps), np.full(len(a), DT)


def held_out_error(model, x0, x1, mu, dt) -> float:
    """Mean relative one-step error ``|Phi(x0) - x1| / |x1 - x0|``."""
    pred = model.step(x0, mu=mu, dt=dt)
    return float(np.mean(np.linalg.norm(pred - x1, axis=1) / np.linalg.norm(x1 - x0, axis=1)))


def peak_rss() -> int:
    """The process's peak resident memory in bytes (``ru_maxrss``, KiB on Linux)."""
    return int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss) * 1024


class _Choice(logging.Handler):
    """Keeps the default trainer's log line (``trainer: Name (why)``)."""

    def __init__(self):
        super().__init__(logging.INFO)
        self.lines = []

    def emit(self, record):
        msg = record.getMessage()
        if msg.startswith("trainer: ") or msg.startswith("bounded active set:"):
            self.lines.append(msg)


def fit_one(label, trainer, data, heldout, m, settings) -> dict:
    x0, x1, mu, dt = data
    model = hand_model(settings, x0, m).set_params(trainer=trainer)
    handler = _Choice()
    log = logging.getLogger("sympredict.interpolation.greedy")
    log.addHandler(handler)
    level = log.level
    log.setLevel(logging.INFO)
    rss0 = peak_rss()
    t0 = time.perf_counter()
    try:
        model.fit(x0, x1, mu=mu, dt=dt)
    finally:
        log.removeHandler(handler)
        log.setLevel(level)
    fit_s = time.perf_counter() - t0
    h, result = model.history_, model.greedy_result_
    stats = {k: v for k, v in result.stats.items() if k != "block_sizes"}
    out = {
        "label": label,
        "trainer_given": None if trainer is None else trainer.spec,
        "log": handler.lines,
        "max_centers": m,
        "centers": int(model.surrogate_.n_centers),
        "fit_s": fit_s,
        "greedy_s": float(h.elapsed[-1]) if len(h.elapsed) else 0.0,
        "stop_reason": h.stop_reason,
        "train_max_residual": float(h.train_max_residual[-1]),
        "held_out_error": held_out_error(model, *heldout),
        "peak_rss_before_fit_bytes": rss0,
        "peak_rss_bytes": peak_rss(),
        "store_stats": stats,
    }
    chosen = next((line.split()[1] for line in handler.lines if line.startswith("trainer: ")), None)
    out["trainer"] = chosen or type(trainer).__name__
    print(
        f"  {label:>8s}: {out['trainer']}, fit {fit_s:.1f} s (greedy {out['greedy_s']:.1f} s), "
        f"{out['centers']} centres, held-out {out['held_out_error']:.3e}, peak RSS {peak_rss() / 2**30:.2f} GiB",
        flush=True,
    )
    for line in handler.lines:
        print(f"           {line}", flush=True)
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--samples", type=int, default=10_000)
    parser.add_argument("--dim", type=int, default=8, help="state dimension 2n (n masses)")
    parser.add_argument("--centers", type=int, default=500)
    parser.add_argument("--steps", type=int, default=100, help="steps per training trajectory")
    parser.add_argument("--holdout", type=int, default=2000, help="held-out samples (other trajectories)")
    parser.add_argument(
        "--memory",
        default="24G",
        help="the memory the fit may assume (SYMPREDICT_MEMORY: bytes, or 24G; default 24G, the machine "
        "this check is for); 'machine': what this machine has",
    )
    parser.add_argument("--trainer", choices=["default", "exact", "blocked", "bounded"], default="default")
    parser.add_argument(
        "--compare",
        action="store_true",
        help="also the exact greedy and the bounded active set with --slot-fraction of the points",
    )
    parser.add_argument("--slot-fraction", type=float, default=0.25)
    parser.add_argument("--project-samples", type=int, default=100_000)
    parser.add_argument("--project-centers", type=int, default=4000)
    parser.add_argument("--project-memory", default="24G", help="the memory of the projected machine")
    _protocol.add_arguments(parser, threads=2)
    args = parser.parse_args(argv)
    if args.memory == "machine":
        args.memory = None
    if args.memory:
        os.environ["SYMPREDICT_MEMORY"] = args.memory
    if args.dim % 2:
        parser.error("--dim must be even (2n)")
    system = chain(args.dim // 2)
    settings = dict(HAND["fpu_chain"])
    blas = max(args.blas_threads, args.threads)
    with _protocol.limits(blas, args.threads):
        protocol = _protocol.record(
            blas_threads=blas,
            numba_threads=args.threads,
            repeats=1,
            warmup=0,
            notes="one fit per trainer; peak RSS is the process's (ru_maxrss), monotone",
        )
        t0 = time.perf_counter()
        n_traj = -(-args.samples // args.steps)
        data = [a[: args.samples] for a in samples(system, n_traj, args.steps, seed=1)]
        heldout = [a[: args.holdout] for a in samples(system, -(-args.holdout // args.steps), args.steps, seed=2)]
        data_s = time.perf_counter() - t0
        n_fun, dim, m = args.dim * len(data[0]), args.dim, args.centers
        print(
            f"{len(data[0])} samples of a {dim}-D FPU chain ({n_fun} functionals), {args.holdout} held out; "
            f"data {data_s:.1f} s; memory {available_memory() / 2**30:.2f} GiB; exact basis "
            f"{8 * m * n_fun / 2**30:.2f} GiB",
            flush=True,
        )
        trainers = {
            "default": None,
            "exact": ExactGreedy(),
            "blocked": BlockedGreedy(),
            "bounded": BoundedActiveSetGreedy(),
        }
        runs = [fit_one(args.trainer, trainers[args.trainer], data, heldout, m, settings)]
        if args.compare:
            # the estimator holds out no samples here (every kernel given): N_val = 0
            slots = int(args.slot_fraction * len(data[0]))
            budget = bounded_memory(m, n_fun, 0, slots * dim, dim)
            assert bounded_capacity(budget, m, n_fun, 0, dim) == slots
            runs.append(fit_one("bounded", BoundedActiveSetGreedy(memory_limit=budget), data, heldout, m, settings))
            # the exact greedy's own check would use the assumed memory: here it may use what its basis needs
            exact = ExactGreedy(memory_limit=trainer_memory(ExactGreedy(), n_fun, 0, m) + 1)
            runs.append(fit_one("exact", exact, data, heldout, m, settings))
        base = runs[0]
        result = {
            "system": f"FPU-beta chain, {args.dim // 2} masses",
            "dim": dim,
            "samples": len(data[0]),
            "functionals": n_fun,
            "holdout": args.holdout,
            "max_centers": m,
            "data_s": data_s,
            "memory_assumed_bytes": available_memory(),
            "settings": {k: v for k, v in settings.items() if k != "search"},
            "runs": runs,
        }
        if args.compare:
            by = {r["label"]: r for r in runs}
            result["held_out_ratio_bounded_to_exact"] = by["bounded"]["held_out_error"] / by["exact"]["held_out_error"]
            result["centers_bounded_exact"] = [by["bounded"]["centers"], by["exact"]["centers"]]
            print(
                f"held-out error bounded / exact at {m} centres: {result['held_out_ratio_bounded_to_exact']:.3f}",
                flush=True,
            )
        result["projection"] = project(args, base, dim, n_fun, m, data_s)
        if args.json:
            _protocol.write_json(args.json, result, protocol)
            print(f"wrote {args.json}")
    return result


def project(args, run, dim, n_fun, m, data_s) -> dict:
    """The full size's formula memory, and its time from this run's parts: blocks ``~ S m^2``, each refresh ``~ N m``."""
    from sympredict.interpolation.greedy.loop import available_memory as _avail

    os.environ["SYMPREDICT_MEMORY"] = args.project_memory
    try:
        mem = _avail()
    finally:
        if args.memory:
            os.environ["SYMPREDICT_MEMORY"] = args.memory
        else:
            os.environ.pop("SYMPREDICT_MEMORY")
    n_full, m_full = args.project_samples * dim, args.project_centers
    n_val = 0  # as in this run: every kernel given, the fit holds out no samples
    limit = 0.9 * mem
    exact = trainer_memory(ExactGreedy(), n_full, n_val, m_full)
    bounded = BoundedActiveSetGreedy(memory_limit=0.5 * limit)
    points = bounded.capacity(n_full, n_val, m_full, dim)
    need = trainer_memory(bounded, n_full, n_val, m_full, dim=dim)
    stats = run["store_stats"]
    out = {
        "samples": args.project_samples,
        "centers": m_full,
        "functionals": n_full,
        "memory_bytes": mem,
        "exact_basis_bytes": exact,
        "bounded_points": points,
        "bounded_formula_bytes": need,
    }
    if "slots" in stats and run["greedy_s"] > 0:
        refresh = float(stats.get("refresh_s", 0.0))
        blocks = run["greedy_s"] - refresh
        mm, slots = run["centers"], stats["slots"]
        # blocks: the products (S m^2 flops at this process's dgemm rate) and the rest, ~ S m (vector passes per
        # centre, Gramian rows of the blocks)
        rate = gemm_rate(slots, m0=mm)["gflops"] * 1e9
        gemm_here = slots * mm**2 / rate
        s_full = points * dim
        t_gemm = s_full * m_full**2 / rate
        t_rest = max(blocks - gemm_here, 0.0) * (s_full * m_full) / (slots * mm)
        t_blocks = t_gemm + t_rest
        out.update(gemm_gflops=rate / 1e9, blocks_gemm_projected_s=t_gemm, blocks_rest_projected_s=t_rest)
        # refreshes: every refresh_every centres (and at the end), each N m Gramian entries; the swaps that follow
        # them m^2 2n flops per point swapped in (bound: max_new_points at every refresh)
        trainer = BoundedActiveSetGreedy()
        every, new_points = trainer.refresh_every, trainer.max_new_points
        swap = float(stats.get("swap_s", 0.0))
        work_here = n_fun * max(sum(stats["evaluated_at"]), 1)
        work_full = n_full * (every * sum(range(1, m_full // every + 1)) + m_full)
        t_eval = (refresh - swap) * work_full / work_here
        swap_here = sum(float(mk) ** 2 * k for mk, k in stats.get("swaps", [])) or 1.0
        swap_full = sum(float(every * k) ** 2 * new_points for k in range(1, m_full // every + 1))
        t_swap = swap * swap_full / swap_here
        t_refresh = t_eval + t_swap
        out.update(evaluation_projected_s=t_eval, swap_projected_s=t_swap)
        out.update(
            greedy_projected_s=t_blocks + t_refresh,
            blocks_projected_s=t_blocks,
            refresh_projected_s=t_refresh,
            fit_rest_projected_s=(run["fit_s"] - run["greedy_s"]) * n_full / n_fun,
            data_projected_s=data_s * n_full / n_fun,
        )
        out["total_projected_s"] = out["greedy_projected_s"] + out["fit_rest_projected_s"] + out["data_projected_s"]
        print(
            f"projection, {args.project_samples} samples x {m_full} centres on {mem / 2**30:.0f} GiB: "
            f"{points} points in slots, formula peak {need / 2**30:.2f} GiB; greedy ~{t_blocks + t_refresh:.0f} s "
            f"(blocks {t_blocks:.0f} s, refreshes {t_eval:.0f} s, swaps {t_swap:.0f} s), run in all ~{out['total_projected_s']:.0f} s at "
            f"this run's rates",
            flush=True,
        )
    else:
        print(
            f"projection: formula peak {need / 2**30:.2f} GiB ({points} points in slots); no time projection "
            f"(this run's trainer has no slots)",
            flush=True,
        )
    return out


if __name__ == "__main__":
    main()
