"""Rotating pendulum orbits: energy error over 1,000 macro steps with and without the periodic kernel factor.

One length ``l`` and one macro step ``dT`` (default), or a grid of them with
parameter kernels (``--lengths``, ``--dts``; orbits then at random ``l`` in the
training range and at ``--test-dts``).  Training data: flow-map samples
from a ``n_q x n_p`` grid on ``[-pi, pi) x [-p_max, p_max]`` (librating *and*
rotating states; energies above the separatrix ``2 g l`` included), angles of
``x0`` in ``[-pi, pi)`` and ``x1 = Phi(x0)`` the true (unwrapped) image.
Three ways to roll out rotating orbits (energies ``H / (2 g l)`` in
``ratio_range``, both senses of rotation):

* ``periodic``: ``SymplecticKernelPredictor(Periodic(kernel, coordinates=(0,)))``; ``q`` grows
  without bound, no wrapping;
* ``plain_wrapped``: the same estimator without the periodic factor, ``q``
  wrapped into ``[-pi, pi)`` after every step (a symplectic map on the
  cylinder, but ``s`` is not periodic: it jumps where ``q`` wraps);
* ``plain``: the same model as ``plain_wrapped``, no wrapping (``q`` leaves
  the training states after about one turn: extrapolation).

Score per orbit: ``max_k |H(x_k) - H(x_0)| / H(x_0)`` over the ``n_steps``
macro steps with the exact Hamiltonian (a failed Newton solve counts as
``inf``).  The state shape ``eps`` of each variant is chosen on validation
orbits (their own seed) by the median score; the test orbits (another seed)
are used for nothing else.  NumPy Newton solver for all (the same solver for every
variant).

Run:  python sympredict_paper/studies/rotating_pendulum.py [--update midpoint] [--json out.json]
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _protocol  # noqa: E402  (sympredict_paper/studies/_protocol.py)

from sympredict import SymplecticKernelPredictor  # noqa: E402
from sympredict.exceptions import ExtrapolationWarning, NewtonConvergenceError  # noqa: E402
from sympredict.kernels import IMQ  # noqa: E402
from sympredict.systems.pendulum import Pendulum  # noqa: E402
from sympredict.interpolation.greedy import ExactGreedy  # noqa: E402
from sympredict.symplectic.solvers import NewtonSolver  # noqa: E402
from sympredict.kernels.transforms import Periodic  # noqa: E402

VARIANTS = ("periodic", "plain_wrapped", "plain")


def training_data(system: Pendulum, lengths, dts, n_q: int, n_p: int, p_max: float, h_max: float):
    """Samples on the grid ``[-pi, pi) x [-p_max, p_max]`` (q endpoint excluded: one period) for every ``(l, dT)``.

    Returns ``x0, x1`` (M, 2), ``mu`` (M,), ``dt`` (M,).
    """
    q, p = np.meshgrid(np.linspace(-np.pi, np.pi, n_q, endpoint=False), np.linspace(-p_max, p_max, n_p), indexing="ij")
    grid = np.column_stack([q.ravel(), p.ravel()])
    x0 = np.concatenate([grid for _ in lengths for _ in dts])
    mu = np.concatenate([np.full(len(grid), float(length)) for length in lengths for _ in dts])
    dt = np.concatenate([np.full(len(grid), float(step)) for _ in lengths for step in dts])
    return x0, system.flow(x0, mu, dt, h_max), mu, dt


def rotating_orbits(
    system: Pendulum,
    n: int,
    seed: int,
    ratio_range=(1.1, 1.5),
    length_range=(0.75, 0.75),
    dt_values=(0.05,),
    length_values=None,
):
    """``n`` rotating initial states and their ``(l, dT)``.

    ``q0`` uniform in ``[-pi, pi)``, ``H / (2 m g l)`` uniform in ``ratio_range``,
    random sense of rotation; ``l`` uniform in ``length_range`` (or from
    ``length_values``) and ``dT`` from ``dt_values`` (drawn only when they vary).  Returns ``x0`` (n, 2), ``l`` (n,), ``dT`` (n,).
    """
    rng = np.random.default_rng(seed)
    q0 = rng.uniform(-np.pi, np.pi, n)
    ratio = rng.uniform(*ratio_range, n)
    sense = rng.choice([-1.0, 1.0], n)
    if length_values is not None:
        length = rng.choice(np.asarray(length_values, dtype=float), n)
    elif length_range[0] == length_range[1]:
        length = np.full(n, float(length_range[0]))
    else:
        length = rng.uniform(*length_range, n)
    dt = np.full(n, float(dt_values[0])) if len(dt_values) == 1 else rng.choice(np.asarray(dt_values, dtype=float), n)
    energy = ratio * 2 * system.mass * system.g * length
    potential = system.mass * system.g * length * (1 - np.cos(q0))
    p0 = sense * length * np.sqrt(2 * system.mass * (energy - potential))
    return np.column_stack([q0, p0]), length, dt


def wrap(q):
    return np.mod(q + np.pi, 2 * np.pi) - np.pi


def rollout(model, x0: np.ndarray, length, dt, n_steps: int, variant: str) -> np.ndarray:
    """Trajectories (B, K+1, 2) of one variant; ``NewtonConvergenceError`` propagates."""
    mu = length if model.mu_kernel is not None else None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ExtrapolationWarning)  # 'plain' leaves the training states by design
        if variant != "plain_wrapped":
            return model.rollout(x0, n_steps, mu=mu, dt=dt)
        traj = np.empty((len(x0), n_steps + 1, 2))
        traj[:, 0] = x0
        x = x0.copy()
        for k in range(n_steps):
            x = model.step(x, mu=mu, dt=dt)
            x[:, 0] = wrap(x[:, 0])
            traj[:, k + 1] = x
        return traj


def relative_energy_error(system: Pendulum, traj: np.ndarray, length) -> np.ndarray:
    """Per trajectory ``max_k |H_k - H_0| / H_0`` of ``traj`` (B, K+1, 2), lengths (B,)."""
    lengths = np.broadcast_to(np.asarray(length, dtype=float).reshape(-1, 1), traj.shape[:2]).reshape(-1)
    h = system.hamiltonian(traj.reshape(-1, 2), lengths).reshape(traj.shape[:2])
    err = np.abs(h - h[:, :1]).max(axis=1) / h[:, 0]
    return np.where(np.isfinite(err), err, np.inf)


def energy_errors(system: Pendulum, model, orbits, n_steps: int, variant: str) -> np.ndarray:
    """Per orbit ``max_k |H_k - H_0| / H_0`` (shape (B,)); instances whose Newton solve fails get ``inf``.

    ``orbits = (x0, l, dT)``.  Orbits are rolled out as one batch; on a failure
    the batch is split so that only the failing orbits count as failed.
    """
    x0, length, dt = orbits
    try:
        traj = rollout(model, x0, length, dt, n_steps, variant)
    except NewtonConvergenceError:
        if len(x0) == 1:
            return np.array([np.inf])
        half = len(x0) // 2
        return np.concatenate(
            [
                energy_errors(system, model, tuple(a[:half] for a in orbits), n_steps, variant),
                energy_errors(system, model, tuple(a[half:] for a in orbits), n_steps, variant),
            ]
        )
    return relative_energy_error(system, traj, length)


def run(
    *,
    lengths=(0.75,),
    dts=(0.05,),
    test_dts=None,
    mu_eps=1.5,
    dt_eps=3.0,
    n_q=48,
    n_p=48,
    p_max=5.5,
    eps_grid=(0.3, 0.5, 0.8),
    max_centers=1500,
    tol=1e-10,
    n_val=20,
    n_test=40,
    n_steps=1000,
    val_steps=None,
    update="symplectic_euler",
    val_seed=1,
    test_seed=2,
    ratio_range=(1.1, 1.5),
    variants=VARIANTS,
    h_max=1e-3,
    reference_floor=False,
    on_grid_test=False,
    log=print,
) -> dict:
    """Fit, choose ``eps`` per variant on validation orbits, score on test orbits; returns a JSON-friendly dict.

    ``lengths`` x ``dts``: the training ``(l, dT)``; with several of either the
    model gets ``mu_kernel=IMQ(mu_eps)`` / ``dt_kernel=IMQ(dt_eps)`` and the
    orbits draw ``l`` uniformly in ``[min, max]`` of ``lengths`` and ``dT`` from
    ``test_dts`` (default ``dts``).  ``h_max``: micro step of the training
    data's reference flow (implicit midpoint); ``reference_floor``: also report
    the energy error of that reference integrator itself on the test orbits
    (the data's own floor); ``on_grid_test``: also score the chosen models on
    test orbits at the training lengths and steps (``test_on_grid_*``).
    """
    system = Pendulum()
    x0, x1, mu, dt = training_data(system, lengths, dts, n_q, n_p, p_max, h_max)
    test_dts = tuple(dts) if test_dts is None else tuple(test_dts)
    draw = {"ratio_range": ratio_range, "length_range": (min(lengths), max(lengths)), "dt_values": test_dts}
    val_orbits = rotating_orbits(system, n_val, val_seed, **draw)
    test_orbits = rotating_orbits(system, n_test, test_seed, **draw)
    on_grid_orbits = rotating_orbits(
        system, n_test, test_seed, ratio_range, dt_values=tuple(dts), length_values=lengths
    )
    val_steps = n_steps if val_steps is None else val_steps
    mu_kernel = IMQ(mu_eps) if len(lengths) > 1 else None
    dt_kernel = IMQ(dt_eps) if len(dts) > 1 else None
    models = {}
    for periodic in sorted({v == "periodic" for v in variants}):
        for eps in eps_grid:
            t0 = time.perf_counter()
            model = SymplecticKernelPredictor(
                Periodic(IMQ(eps), coordinates=(0,) if periodic else None),
                mu_kernel,
                dt_kernel,
                max_centers=max_centers,
                update=update,
                trainer=ExactGreedy(tol=tol),
                solver=NewtonSolver(backend="numpy"),
            )
            model.fit(x0, x1, mu=mu if mu_kernel is not None else None, dt=dt if dt_kernel is not None else dt[0])
            models[periodic, eps] = (model, time.perf_counter() - t0)
    out = {
        "setup": {
            "lengths": list(lengths),
            "dts": list(dts),
            "test_dts": list(test_dts),
            "mu_kernel": repr(mu_kernel),
            "dt_kernel": repr(dt_kernel),
            "n_samples": len(x0),
            "grid": [n_q, n_p],
            "p_max": p_max,
            "eps_grid": list(eps_grid),
            "max_centers": max_centers,
            "tol": tol,
            "update": update,
            "n_val": n_val,
            "n_test": n_test,
            "n_steps": n_steps,
            "val_steps": val_steps,
            "ratio_range": list(ratio_range),
            "val_seed": val_seed,
            "test_seed": test_seed,
            "h_max": h_max,
        },
        "variants": {},
    }
    if reference_floor:
        xt, lt, dtt = test_orbits
        ref = relative_energy_error(system, system.trajectory(xt, lt, dtt, n_steps, h_max), lt)
        out["reference"] = {"test_median": float(np.median(ref)), "test_max": float(ref.max())}
        log(
            f"reference flow (implicit midpoint, micro step <= {h_max:g}) on the test orbits: energy error median "
            f"{out['reference']['test_median']:.2e}, max {out['reference']['test_max']:.2e}"
        )
    for variant in variants:
        periodic = variant == "periodic"
        scores = {}
        for eps in eps_grid:
            model, fit_s = models[periodic, eps]
            val = energy_errors(system, model, val_orbits, val_steps, variant)
            scores[eps] = {
                "val_median": float(np.median(val)),
                "val_max": float(val.max()),
                "n_centers": model.n_centers_,
                "E_train": float(model.history_.train_max_residual[-1]),
                "fit_s": fit_s,
                "stop_reason": model.history_.stop_reason,
            }
            log(
                f"{variant:13s} eps={eps}: {model.n_centers_} centres, E_train {scores[eps]['E_train']:.1e}, "
                f"validation energy error median {scores[eps]['val_median']:.2e}, max {scores[eps]['val_max']:.2e}"
            )
        best = min(eps_grid, key=lambda e: (scores[e]["val_median"], scores[e]["val_max"]))
        t0 = time.perf_counter()
        test = energy_errors(system, models[periodic, best][0], test_orbits, n_steps, variant)
        res = {
            "eps": best,
            "test_median": float(np.median(test)),
            "test_max": float(test.max()),
            "test_failed": int(np.sum(~np.isfinite(test))),
            "rollout_s": time.perf_counter() - t0,
            "validation": {str(k): v for k, v in scores.items()},
        }
        if on_grid_test:
            on = energy_errors(system, models[periodic, best][0], on_grid_orbits, n_steps, variant)
            res.update(
                {
                    "test_on_grid_median": float(np.median(on)),
                    "test_on_grid_max": float(on.max()),
                    "test_on_grid_failed": int(np.sum(~np.isfinite(on))),
                }
            )
            log(
                f"{variant:13s} chosen eps={best}: on-grid test orbits (training l and dT): median "
                f"{res['test_on_grid_median']:.2e}, max {res['test_on_grid_max']:.2e}"
            )
        out["variants"][variant] = res
        log(
            f"{variant:13s} chosen eps={best}: test energy error over {n_steps} steps: median {res['test_median']:.2e}, "
            f"max {res['test_max']:.2e} ({res['test_failed']} of {n_test} failed)"
        )
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--update", default="symplectic_euler", choices=["symplectic_euler", "midpoint"])
    parser.add_argument("--lengths", type=float, nargs="+", default=[0.75], help="training lengths l")
    parser.add_argument("--dts", type=float, nargs="+", default=[0.05], help="training macro steps")
    parser.add_argument(
        "--test-dts", type=float, nargs="+", default=None, help="macro steps of the orbits (default: --dts)"
    )
    parser.add_argument("--mu-eps", type=float, default=1.5)
    parser.add_argument("--dt-eps", type=float, default=3.0)
    parser.add_argument("--grid", type=int, nargs=2, default=[48, 48], metavar=("N_Q", "N_P"))
    parser.add_argument("--p-max", type=float, default=5.5)
    parser.add_argument("--eps", type=float, nargs="+", default=[0.3, 0.5, 0.8])
    parser.add_argument("--max-centers", type=int, default=1500)
    parser.add_argument("--n-val", type=int, default=20)
    parser.add_argument("--n-test", type=int, default=40)
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--val-steps", type=int, default=None)
    parser.add_argument("--h-max", type=float, default=1e-3, help="micro step of the training data's reference flow")
    parser.add_argument(
        "--reference-floor",
        action="store_true",
        help="also report the reference integrator's own energy error on the test orbits",
    )
    parser.add_argument(
        "--on-grid-test", action="store_true", help="also score test orbits at the training lengths and steps"
    )
    parser.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    _protocol.add_arguments(parser)
    args = parser.parse_args(argv)
    with _protocol.limits(args.blas_threads):
        out = run(
            lengths=tuple(args.lengths),
            dts=tuple(args.dts),
            test_dts=args.test_dts,
            mu_eps=args.mu_eps,
            dt_eps=args.dt_eps,
            n_q=args.grid[0],
            n_p=args.grid[1],
            p_max=args.p_max,
            eps_grid=tuple(args.eps),
            max_centers=args.max_centers,
            n_val=args.n_val,
            n_test=args.n_test,
            n_steps=args.steps,
            val_steps=args.val_steps,
            update=args.update,
            h_max=args.h_max,
            reference_floor=args.reference_floor,
            on_grid_test=args.on_grid_test,
            variants=tuple(args.variants),
            log=lambda s: print(s, flush=True),
        )
        protocol = _protocol.record_options(args, repeats=1, statistic="one run per fit and rollout")
    if args.json:
        _protocol.write_json(args.json, out, protocol)


if __name__ == "__main__":
    main()
