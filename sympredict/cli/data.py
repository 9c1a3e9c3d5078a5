"""``sympredict data``: a data set of a shipped system (pendulum flow-map samples, or trajectories of the others)."""

from __future__ import annotations

import math

from sympredict.cli._files import _check_output_file
from sympredict.cli._options import _add_verbose, _finite_float, _int_at_least

__all__ = ["add_parser", "DATA_SYSTEMS"]

#: ``sympredict data --system NAME``: the shipped systems that write trajectories, with their defaults
#: (macro step, parameter range, and for the PDEs the number of grid points).
DATA_SYSTEMS = {
    "henon-heiles": {"dt": 0.1, "mu": (0.8, 1.0)},
    "wave": {"dt": 0.1, "mu": (0.2**2, 0.3**2)},
    "sine-gordon": {"dt": 0.1, "mu": (0.8, 1.2)},
}


def _system_trajectories(name: str, n_traj: int, n_steps: int, dt: float, n_points: int, seed: int):
    """Reference trajectories of a shipped system: (states (P, K+1, 2n), mu (P,))."""
    import numpy as np

    lo, hi = DATA_SYSTEMS[name]["mu"]
    mu = np.random.default_rng(seed).uniform(lo, hi, n_traj)
    if name == "henon-heiles":
        from sympredict.systems.henon_heiles import HenonHeiles, energy_bounded_states

        system = HenonHeiles()
        x0 = np.vstack([energy_bounded_states(system, lam, 1, seed=seed + i) for i, lam in enumerate(mu)])
        return system.trajectory(x0, mu, dt, n_steps), mu
    if name == "wave":
        from sympredict.systems.wave import WaveFOM

        fom = WaveFOM(n_points=n_points)
        x0 = np.vstack(
            [
                fom.low_frequency_states(1, min(4, n_points), m, fom.reference_energy(m), seed=seed + i)
                for i, m in enumerate(mu)
            ]
        )
        return fom.trajectory(x0, mu, dt, n_steps), mu
    from sympredict.systems.sine_gordon import SineGordonFOM

    fom = SineGordonFOM(n_points=n_points)
    x0 = np.vstack(
        [fom.energy_bounded_states(1, 1.0, c=c, n_modes=min(8, n_points), seed=seed + i) for i, c in enumerate(mu)]
    )
    return fom.reference_trajectory(x0, mu, dt, n_steps), mu


def _cmd_data(args) -> int:
    from sympredict.io import save_dataset

    _check_output_file(args.out, force=args.force)
    system = args.system.replace("_", "-")
    if system != "pendulum":
        from sympredict.data import TrajectoryData
        from sympredict.io.trajectories import write_trajectories

        dt = args.dt if args.dt is not None else DATA_SYSTEMS[system]["dt"]
        states, mu = _system_trajectories(system, args.trajectories, args.steps, dt, args.n_points, args.seed)
        write_trajectories(TrajectoryData(states, mu, dt), args.out, overwrite=args.force)
        print(
            f"wrote {states.shape[0]} {system} trajectories of {args.steps} steps (dt = {dt}, 2n = {states.shape[2]}, "
            f"one parameter each) to {args.out}"
        )
        return 0
    from sympredict.systems.pendulum import DT_TRAIN, MU_TRAIN, Pendulum, flow_map_data, random_flow_map_data

    if not str(args.out).lower().endswith((".h5", ".hdf5")):
        raise ValueError(f"--out {args.out!r}: the pendulum data set is an HDF5 file; name it .h5")
    pendulum = Pendulum()
    if args.random is None:
        _check_grid_memory(args.n_grid, len(MU_TRAIN) * len(DT_TRAIN))
    if args.random is not None:
        data = random_flow_map_data(pendulum, args.random, seed=args.seed)
        meta = {"system": "pendulum", "kind": "random", "n_samples": args.random, "seed": args.seed}
    else:
        data = flow_map_data(pendulum, MU_TRAIN, DT_TRAIN, n_grid=args.n_grid, p_nonpositive=args.p_nonpositive)
        meta = {"system": "pendulum", "kind": "grid", "n_grid": args.n_grid, "p_nonpositive": args.p_nonpositive}
    save_dataset(data, args.out, overwrite=args.force, **meta)
    print(f"wrote {len(data)} pendulum flow-map samples to {args.out}")
    return 0


#: Bytes per grid point and (length, step) pair of ``flow_map_data``: the grid and its mask (~64 B per point)
#: and, for the ~56 % of points inside the energy bound, the samples (x0, x1, mu, dt: 48 B) about four times over
#: (the propagated copies and the concatenation).
_GRID_BYTES_PER_POINT, _SAMPLE_BYTES_PER_POINT = 64, 0.56 * 48 * 4


def _check_grid_memory(n_grid: int, n_pairs: int) -> None:
    """Refuse ``data --n-grid`` whose samples would not fit in the available memory, before allocating."""
    from sympredict.symplectic.newton import available_memory

    needed = n_grid**2 * (_GRID_BYTES_PER_POINT + n_pairs * _SAMPLE_BYTES_PER_POINT)
    available = available_memory()
    if available is not None and needed > available:
        largest = int(math.sqrt(available / (_GRID_BYTES_PER_POINT + n_pairs * _SAMPLE_BYTES_PER_POINT)))
        raise ValueError(
            f"--n-grid {n_grid}: the grid's samples need about {needed / 2**30:.3g} GiB, more than the "
            f"{available / 2**30:.3g} GiB available; give --n-grid {largest} or less (the paper's is 200)"
        )


#: The whole-number options of ``sympredict data``: flag, least value, default, metavar (``None``: the flag's name)
#: and help (``%(default)s``: argparse writes the default); the help names the systems an option applies to.
_COUNT_OPTIONS = (
    ("--n-grid", 2, 50, None, "pendulum: energy-bounded grid points per axis (default %(default)s; paper 200)"),
    ("--random", 1, None, "N", "pendulum: N >= 1 random samples instead of the grid (validation data)"),
    (
        "--trajectories",
        1,
        20,
        "P",
        "other systems: number of trajectories (default %(default)s), parameters drawn uniformly from the system's "
        "range",
    ),
    ("--steps", 1, 20, "K", "other systems: macro steps per trajectory (default %(default)s)"),
    (
        "--n-points",
        3,
        16,
        "N",
        "wave and sine-gordon: interior grid points, states of dimension 2N (default %(default)s)",
    ),
)


def add_parser(sub) -> None:
    """Register ``sympredict data`` with the subparsers ``sub``."""
    data = sub.add_parser("data", help="write a data set of a shipped system that 'sympredict train' reads")
    data.add_argument(
        "--system",
        choices=["pendulum", *DATA_SYSTEMS],
        default="pendulum",
        help="pendulum (default): flow-map samples (HDF5); the others: reference trajectories "
        "(.npz, .h5 or .csv by the --out suffix) with one parameter each",
    )
    data.add_argument("--out", required=True, help="data file (.h5 for the pendulum; .npz, .h5 or .csv otherwise)")
    data.add_argument(
        "--p-nonpositive", action="store_true", help="pendulum: keep only states with p <= 0 (scenario B)"
    )
    for flag, least, default, metavar, text in _COUNT_OPTIONS:
        data.add_argument(flag, type=_int_at_least(least), default=default, metavar=metavar, help=text)
    data.add_argument("--dt", type=_finite_float(positive=True), help="other systems: macro step (default 0.1)")
    data.add_argument("--seed", type=_int_at_least(0), default=0)
    data.add_argument("--force", action="store_true", help="replace an existing --out file")
    _add_verbose(data)
    data.set_defaults(func=_cmd_data)
