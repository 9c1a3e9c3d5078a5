"""Cost of the library's compiled Störmer–Verlet against a hand-written numba loop (issue 13's target: <= 3x).

Both integrate the pendulum ``H = p^2/(2 m l^2) + m g l (1 - cos q)`` for a batch
of ``B`` instances (own length each) over ``K`` steps and return the whole
trajectory ``(B, K+1, 2)``, side by side in one process with the same numba and
BLAS threads (``sympredict_paper/studies/_protocol.py``: medians of ``--repeats`` interleaved
calls after one warm-up call, compilation excluded).  The library call includes
its input checks and allocation.  The NumPy reference (``backend='numpy'``) is
timed too, with fewer repeats.

Run:  python sympredict_paper/studies/integrators_speed.py [--batch 1000] [--steps 1000] [--threads 1] [--json out.json]
"""

import argparse
import sys
from pathlib import Path

import numba
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _protocol  # noqa: E402  (sympredict_paper/studies/_protocol.py)

from sympredict.symplectic.integrators_compiled import rollout  # noqa: E402
from sympredict.systems.pendulum import Pendulum  # noqa: E402


@numba.njit(parallel=True, cache=True)
def hand_written_sv(x0, length, dt, n_steps, m, g, traj):
    """The user's 10-line loop: kick, drift, kick, for each instance."""
    for i in numba.prange(x0.shape[0]):
        q, p, l, h = x0[i, 0], x0[i, 1], length[i], dt[i]
        traj[i, 0, 0], traj[i, 0, 1] = q, p
        for k in range(n_steps):
            p -= 0.5 * h * m * g * l * np.sin(q)
            q += h * p / (m * l * l)
            p -= 0.5 * h * m * g * l * np.sin(q)
            traj[i, k + 1, 0], traj[i, k + 1, 1] = q, p


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=1000)
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--dt", type=float, default=0.01)
    parser.add_argument("--numpy-repeats", type=int, default=3)
    _protocol.add_arguments(parser, threads=1, repeats=21)
    args = parser.parse_args()

    system = Pendulum()
    rng = np.random.default_rng(0)
    b, k = args.batch, args.steps
    x0 = np.column_stack([rng.uniform(-2.5, 2.5, b), rng.uniform(-2.0, 2.0, b)])
    length = rng.uniform(0.7, 0.8, b)
    dt = np.full(b, args.dt)
    traj_hand = np.empty((b, k + 1, 2))

    with _protocol.limits(args.blas_threads, numba_threads=args.threads):
        compiled = _protocol.side_by_side(
            {
                "hand_written_numba": lambda: hand_written_sv(x0, length, dt, k, system.mass, system.g, traj_hand),
                "library_compiled": lambda: rollout(system, x0, length, dt, k, scheme="stormer_verlet"),
            },
            repeats=args.repeats,
        )
        numpy_ref = _protocol.measure(
            lambda: rollout(system, x0, length, dt, k, scheme="stormer_verlet", backend="numpy"), args.numpy_repeats
        )
        lib = rollout(system, x0, length, dt, k, scheme="stormer_verlet")
        protocol = _protocol.record_options(args, repeats=args.repeats, warmup=1)
    t_hand = compiled["methods"]["hand_written_numba"]["median_s"]
    t_lib = compiled["methods"]["library_compiled"]["median_s"]
    t_np = numpy_ref["median_s"]
    diff = float(np.abs(lib - traj_hand).max())
    result = {
        "batch": b,
        "steps": k,
        "dt": args.dt,
        "threads": args.threads,
        "repeats": args.repeats,
        "library_compiled_s": t_lib,
        "hand_written_numba_s": t_hand,
        "library_numpy_s": t_np,
        "ratio_library_over_hand": t_lib / t_hand,
        "ratio_numpy_over_hand": t_np / t_hand,
        "ns_per_instance_step_library": 1e9 * t_lib / (b * k),
        "ns_per_instance_step_hand": 1e9 * t_hand / (b * k),
        "max_abs_difference": diff,
        "numba": numba.__version__,
        "numpy": np.__version__,
        "machine": protocol["machine"]["machine"],
        "processor": protocol["machine"]["cpu_model"],
        "timings": {"compiled": compiled, "numpy": numpy_ref},
    }
    print(f"pendulum Störmer–Verlet, batch {b}, {k} steps, {args.threads} thread(s), medians of {args.repeats}:")
    print(
        f"  hand-written numba loop : {t_hand * 1e3:9.2f} ms  ({result['ns_per_instance_step_hand']:.1f} ns per instance-step)"
    )
    print(
        f"  sympredict compiled     : {t_lib * 1e3:9.2f} ms  ({result['ns_per_instance_step_library']:.1f} ns per instance-step)"
        f"  ratio {result['ratio_library_over_hand']:.2f}x (target <= 3x)"
    )
    print(
        f"  sympredict NumPy ref.   : {t_np * 1e3:9.2f} ms  ratio {result['ratio_numpy_over_hand']:.0f}x "
        f"(median of {args.numpy_repeats})"
    )
    print(f"  max |library - hand-written| = {diff:.1e}")
    if args.json:
        _protocol.write_json(args.json, result, protocol, indent=2)


if __name__ == "__main__":
    main()
