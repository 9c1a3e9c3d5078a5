"""``sympredict predict``: roll a saved model out from given initial states."""

from __future__ import annotations

from sympredict.cli._console import _Progress
from sympredict.cli._files import _check_output_file
from sympredict.cli._options import (
    _add_backend_and_force,
    _add_verbose,
    _finite_float,
    _int_at_least,
    _number_list,
    _parse_numbers,
)

__all__ = ["add_parser"]


def _set_backend(model, backend: str):
    """The Newton backend of a loaded model (the inner predictor's for a split model; none for the direct model)."""
    from sympredict.estimators.predictor import newton_predictor

    inner = newton_predictor(model)
    if inner is not None:
        inner.set_params(solver__backend=backend)
    return model


def _cmd_predict(args) -> int:
    import numpy as np

    from sympredict import SymplecticKernelPredictor
    from sympredict.estimators.predictor import newton_predictor
    from sympredict.exceptions import RolloutMemoryError
    from sympredict.io import load_model

    if args.out:
        _check_output_file(args.out, args.model, args.x0_file, force=args.force)
        if not args.out.lower().endswith((".npz", ".csv")):
            raise ValueError(f"--out {args.out!r}: trajectories are written as .npz or .csv; name the file so")
    model = _set_backend(load_model(args.model), args.backend)
    mu = None if args.mu is None else _parse_numbers(args.mu, "--mu")
    if args.x0_file:
        from sympredict.io.trajectories import read_states

        x0, file_mu = read_states(args.x0_file, model.dim_)
        if file_mu is not None:
            if mu is not None:
                raise ValueError(f"--mu and the mu column(s) of --x0-file {args.x0_file!r}: give the parameters once")
            mu = file_mu
        print(f"read {args.x0_file}: {len(x0)} initial state(s) (2n = {x0.shape[1]})")
    else:
        x0 = np.array([_parse_numbers(state, "--x0") for state in args.x0]) if args.x0 else None
        if x0 is None or len({len(v) for v in x0}) != 1:
            raise ValueError("give --x0 (comma-separated q1,...,qn,p1,...,pn per state) or --x0-file")
        if x0.shape[1] != model.dim_:
            raise ValueError(
                f"--x0 has {x0.shape[1]} numbers per state; the model's states have 2n = {model.dim_} "
                "(q1,...,qn,p1,...,pn)"
            )
    if mu is not None and mu.ndim == 1 and getattr(model, "n_mu_", 1) > 1 and len(mu) == model.n_mu_:
        mu = mu[None]  # one parameter vector for every state
    # without --out only the final states are printed: keep the first and last state (memory O(batch))
    stride = args.stride if args.out else max(1, args.steps)
    progress = _Progress("predict")
    if args.check and not isinstance(model, SymplecticKernelPredictor):
        raise ValueError(
            f"--check estimates dT * L_S of a SymplecticKernelPredictor; {args.model!r} holds a "
            f"{type(model).__name__}: leave out --check"
        )
    kwargs = {"check_solvability": True} if args.check else {}
    if args.error:
        if not isinstance(model, SymplecticKernelPredictor):
            raise ValueError(
                f"--error estimates the error of a SymplecticKernelPredictor's prediction; {args.model!r} "
                f"holds a {type(model).__name__}: leave out --error"
            )
        kwargs["return_error"] = True
    error = None
    try:
        traj = model.rollout(x0, args.steps, mu=mu, dt=args.dt, stride=stride, progress=progress, **kwargs)
        if args.error:
            traj, error = traj
    except RolloutMemoryError as exc:
        raise ValueError(
            f"--steps {args.steps} with --stride {stride}: {exc.needed / 2**30:.3g} GiB of states, more than "
            f"the {exc.available / 2**30:.3g} GiB available; keep fewer states with a larger --stride"
        ) from None
    finally:
        progress.close()
    if args.out:
        from sympredict.data import TrajectoryData
        from sympredict.io.trajectories import write_trajectories

        step = args.dt if args.dt is not None else getattr(newton_predictor(model) or model, "dt_fixed_", None)
        kept = np.arange(traj.shape[1]) * stride
        times = kept * step if step is not None else kept.astype(float)
        mu_out = (
            None
            if mu is None
            else np.broadcast_to(
                np.asarray(mu, dtype=float).reshape(len(mu), -1) if np.ndim(mu) else np.full((1, 1), float(mu)),
                (traj.shape[0], max(1, model.n_mu_)),
            )
        )
        write_trajectories(
            TrajectoryData(traj, mu_out, times=times),
            args.out,
            overwrite=bool(args.force),
            extra=None if error is None else {"error": error},
        )
        print(
            f"wrote {traj.shape[0]} trajectories of {args.steps} steps"
            + (f" (one state every {stride} steps)" if stride > 1 else "")
            + f" to {args.out}"
            + ("" if step is not None else " (t counts steps: the model takes dt per query)")
        )
    else:
        for b in range(traj.shape[0]):
            print(
                f"instance {b}: x({args.steps} steps) = {', '.join(f'{v:.12g}' for v in traj[b, -1])}"
                + ("" if error is None else f"  (estimated error {error[b, -1]:.2e})")
            )
    return 0


def add_parser(sub) -> None:
    """Register ``sympredict predict`` with the subparsers ``sub``."""
    predict = sub.add_parser("predict", help="roll a saved model out from given initial states")
    predict.add_argument("model", help="model file")
    states = predict.add_mutually_exclusive_group(required=True)
    states.add_argument("--x0", nargs="+", help="initial states, each comma-separated (q1,...,qn,p1,...,pn)")
    states.add_argument(
        "--x0-file",
        help="initial states from a .npz (key x0 (B, 2n), optional mu) or .csv "
        "(columns q1..qn, p1..pn, optional mu or mu1..mud) file",
    )
    predict.add_argument("--mu", type=_number_list, help="parameter, comma-separated for several components")
    predict.add_argument(
        "--dt", type=_finite_float(positive=True), help="macro step (default: the training step of a fixed-step model)"
    )
    predict.add_argument("--steps", type=_int_at_least(0), required=True, help="number of macro steps")
    predict.add_argument("--check", action="store_true", help="refuse to start where dT * L_S >= 1")
    predict.add_argument(
        "--error",
        action="store_true",
        help="also estimate |x_predicted - x_exact| at every state written (an extra column or key "
        "'error'; see the how-to 'How accurate is my prediction?')",
    )
    predict.add_argument(
        "--out",
        help="trajectories file, .npz or .csv (the layout sympredict.io.read_trajectories "
        "reads; default: print the final states)",
    )
    predict.add_argument(
        "--stride",
        type=_int_at_least(1),
        default=1,
        help="with --out, write every k-th state only (default 1: all); memory is that of the states written",
    )
    _add_backend_and_force(predict, "Newton solver")
    _add_verbose(predict)
    predict.set_defaults(func=_cmd_predict)
