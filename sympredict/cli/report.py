"""``sympredict report``: describe a saved model (kernel, centres, residuals, training box)."""

from __future__ import annotations

__all__ = ["add_parser"]


def _cmd_report(args) -> int:
    from sympredict import SymplecticKernelPredictor
    from sympredict.io.formats import check_model_file

    check_model_file(args.model)
    model = SymplecticKernelPredictor.load(args.model)
    h, d = model.history_, model.domain_
    print(f"{args.model}: SymplecticKernelPredictor, state dimension 2n = {model.dim_}, {model.n_mu_} parameter(s)")
    print(f"  kernel: state {model.kernel_.state!r}, mu {model.kernel_.mu!r}, dt {model.kernel_.dt!r}")
    print(
        f"  {model.n_centers_} centres, greedy stop: {h.stop_reason}, E_train {h.train_max_residual[-1]:.3e}"
        + (f", E_val {h.val_max_residual[-1]:.3e}" if h.val_max_residual is not None else "")
    )
    print(f"  training box: states {d['x_min'].round(6).tolist()} .. {d['x_max'].round(6).tolist()}")
    if model.n_mu_:
        print(f"                mu {d['mu_min'].round(6).tolist()} .. {d['mu_max'].round(6).tolist()}")
    print(
        f"                dt {float(d['dt_min']):.6g} .. {float(d['dt_max']):.6g}"
        + (" (fixed step)" if model.dt_fixed_ else "")
    )
    return 0


def add_parser(sub) -> None:
    """Register ``sympredict report`` with the subparsers ``sub``."""
    describe = sub.add_parser("report", help="describe a saved model: kernel, centres, residuals, training box")
    describe.add_argument("model", help="model file")
    describe.set_defaults(func=_cmd_report)
