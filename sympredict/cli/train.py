"""``sympredict train``: a model from a data set or the user's trajectories, saved to HDF5."""

from __future__ import annotations

import argparse
import os

from sympredict.cli._console import _info, _Working
from sympredict.cli._files import _check_output_file, _save_model_or_keep
from sympredict.cli._options import _add_backend_and_force, _add_verbose, _finite_float, _int_at_least, _parse_kernel

__all__ = ["add_parser"]


def _is_own_dataset(path) -> bool:
    """Whether ``path`` is a data set written by ``sympredict data`` / :func:`sympredict.io.save_dataset`."""
    import h5py

    if not str(path).lower().endswith((".h5", ".hdf5")) or not os.path.isfile(path):
        return False
    try:
        with h5py.File(path, "r") as f:
            return "format" in f.attrs and "arrays" in f
    except OSError:
        return False


def _describe(data) -> str:
    """What was read: trajectories or pairs, dimensions."""
    from sympredict.data import TrajectoryData

    d_mu = data.mu.shape[1]
    if isinstance(data, TrajectoryData):
        p, k1, dim = data.states.shape
        return (
            f"{p} trajectories of {k1} states (2n = {dim}, {d_mu} parameter(s), "
            + (f"dt = {data.dt:.6g}" if data.dt is not None else "non-uniform times")
            + f"), {p * (k1 - 1)} pairs"
        )
    return f"{len(data)} pairs (2n = {data.x0.shape[1]}, {d_mu} parameter(s))"


def _cmd_train_user_data(args) -> int:
    """``sympredict train`` on the user's trajectories or pairs (.npz, .h5, .csv): the estimator's defaults."""
    from threadpoolctl import threadpool_limits

    from sympredict import SymplecticKernelPredictor
    from sympredict.interpolation.greedy import ExactGreedy
    from sympredict.io import read_trajectories
    from sympredict.symplectic.solvers import NewtonSolver

    data = read_trajectories(args.data)
    _info(args, f"read {args.data}: {_describe(data)}")
    validation = read_trajectories(args.validation) if args.validation else None
    options = {} if args.centers is None else {"max_centers": args.centers}  # None: the estimator's default
    for name, spec in (
        ("state_kernel", args.state_kernel),
        ("mu_kernel", args.mu_kernel),
        ("dt_kernel", args.dt_kernel),
    ):
        if spec is not None:
            options[name] = _parse_kernel(spec)
    if args.tol is not None or args.target_error is not None:
        options["trainer"] = ExactGreedy(
            **({} if args.tol is None else {"tol": args.tol}), target_error=args.target_error
        )
    if args.backend != "auto":
        options["solver"] = NewtonSolver(backend=args.backend)
    model = SymplecticKernelPredictor(**options)
    with (
        threadpool_limits(limits=args.threads),
        _Working(f"sympredict train: {_describe(data)}, training", quiet=args.verbose),
    ):
        model.fit(data, validation=validation)
    return _save_and_report(model, args, _describe(data))


def _save_and_report(model, args, trained_on: str) -> int:
    """Save the fitted model to ``--out`` and print what was trained on ``trained_on`` (the data, in words)."""
    _save_model_or_keep(model, args.out, overwrite=args.force)
    h = model.history_
    print(
        f"trained {model.n_centers_} centres ({h.stop_reason}) on {trained_on}: E_train {h.train_max_residual[-1]:.2e}"
        + (f", E_val {h.val_max_residual[-1]:.2e}" if h.val_max_residual is not None else "")
        + f"; saved to {args.out}"
    )
    _print_target(model)
    return 0


def _print_target(model) -> None:
    """With ``--target-error``: the held-out error against the target (the fit also warns when it is missed)."""
    d = getattr(model, "diagnostics_", None)
    if d is not None and d.target_error is not None:
        print(
            f"target error {d.target_error:.2e}: {'met' if d.target_met else 'NOT met'} "
            f"(median one-step error {d.holdout_step_error:.2e} on held-out samples, {model.n_centers_} centres)"
        )


def _refuse_wrong_train_options(args) -> None:
    """``train --dt/--mu/--state``: say which option was meant (``--dt`` is the step on ``predict``, a kernel here)."""
    if args.wrong_dt is not None:
        raise ValueError(
            "train has no --dt: the sampling step is read from the data file ('dt' or 'times'); "
            "the step kernel is --dt-kernel FAMILY:EPS (e.g. --dt-kernel imq:5.0)"
        )
    if args.wrong_mu is not None:
        raise ValueError(
            "train has no --mu: the parameters are read from the data file ('mu'); "
            "the parameter kernel is --mu-kernel FAMILY:EPS (e.g. --mu-kernel imq:2.0) or 'none'"
        )
    if args.wrong_state is not None:
        raise ValueError(
            "train has no --state: the state kernel is --state-kernel FAMILY:EPS (e.g. --state-kernel imq:0.15)"
        )


def _cmd_train(args) -> int:
    from threadpoolctl import threadpool_limits

    from sympredict import SymplecticKernelPredictor
    from sympredict.interpolation.greedy import ExactGreedy
    from sympredict.io import load_dataset
    from sympredict.symplectic.solvers import NewtonSolver

    _refuse_wrong_train_options(args)
    _check_output_file(args.out, args.data, args.validation, force=args.force)
    if not _is_own_dataset(args.data) and str(args.data).lower().endswith((".npz", ".csv", ".h5", ".hdf5")):
        return _cmd_train_user_data(args)
    data, meta = load_dataset(args.data)
    _info(args, f"read {args.data}: {_describe(data)}")
    validation = load_dataset(args.validation)[0] if args.validation else None
    kernels = [
        _parse_kernel(k if k is not None else default)
        for k, default in ((args.state_kernel, "imq:0.15"), (args.mu_kernel, "imq:2.0"), (args.dt_kernel, "imq:5.0"))
    ]
    model = SymplecticKernelPredictor(
        *kernels,
        max_centers=args.centers or 1500,
        trainer=ExactGreedy(tol=1e-10 if args.tol is None else args.tol, target_error=args.target_error),
        solver=NewtonSolver(backend=args.backend),
    )
    mu = data.mu if kernels[1] is not None else None
    if validation is not None and kernels[1] is None:
        validation = (validation.x0, validation.x1, None, validation.dt)
    with (
        threadpool_limits(limits=args.threads),
        _Working(f"sympredict train: {_describe(data)}, training", quiet=args.verbose),
    ):
        model.fit(data.x0, data.x1, mu=mu, dt=data.dt, validation=validation)
    return _save_and_report(model, args, f"{len(data)} samples of {meta.get('system', 'unknown system')}")


def add_parser(sub) -> None:
    """Register ``sympredict train`` with the subparsers ``sub``."""
    train = sub.add_parser(
        "train", help="train a symplectic predictor on a data set or the user's trajectories and save it (HDF5)"
    )
    train.add_argument(
        "data",
        help="a data set written by 'sympredict data' or sympredict.io.save_dataset, or trajectories "
        "or pairs in a .npz, .h5 or .csv file (layout: sympredict.io.read_trajectories)",
    )
    train.add_argument("--out", required=True, help="model file (.h5)")
    train.add_argument("--validation", help="validation data, same kinds of file (records E_val)")
    train.add_argument(
        "--state-kernel",
        metavar="FAMILY:EPS",
        help="state kernel, e.g. imq:0.15 (default: imq:0.15 for a sympredict data set, chosen on "
        "held-out samples otherwise)",
    )
    train.add_argument(
        "--mu-kernel",
        metavar="FAMILY:EPS",
        help="parameter kernel or 'none' (default: imq:2.0 for a sympredict data set, chosen otherwise)",
    )
    train.add_argument(
        "--dt-kernel",
        metavar="FAMILY:EPS",
        help="step kernel or 'none' (default: imq:5.0 for a sympredict data set, chosen otherwise)",
    )
    # --dt, --mu and --state are no options of train (the step and parameters come from the file): named so that
    # they are refused with the right option instead of being taken as abbreviations of the kernel options
    for wrong in ("--dt", "--mu", "--state"):
        train.add_argument(wrong, dest=f"wrong_{wrong[2:]}", help=argparse.SUPPRESS)
    train.add_argument(
        "--max-centers",
        "--centers",
        dest="centers",
        type=_int_at_least(1),
        help="maximal number of centres (default: 1500 for a sympredict data set, the estimator's default otherwise)",
    )
    train.add_argument("--tol", type=_finite_float(nonnegative=True), help="greedy residual tolerance (default 1e-10)")
    train.add_argument(
        "--target-error",
        type=_finite_float(positive=True),
        help="grow the model until the median relative one-step error on held-out samples is at "
        "most this (e.g. 1e-4), then stop: the smallest model that meets it (--max-centers "
        "stays the cap)",
    )
    train.add_argument("--threads", type=_int_at_least(1), default=os.cpu_count() or 1)
    _add_verbose(train)
    _add_backend_and_force(train, "the saved model's Newton solver")
    train.set_defaults(func=_cmd_train)
