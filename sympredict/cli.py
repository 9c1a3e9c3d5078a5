"""The ``sympredict`` command (argument parsing, progress and files; no numerics here).

``sympredict run pendulum --quick --out DIR`` trains the scenario-A pendulum
predictor and writes into ``DIR``: the trained model (``model.h5``), figures
(PNG and PDF), ``results.json`` and ``summary.md``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

__all__ = ["main"]


def _write_pendulum_outputs(results: dict, out: Path, command: str) -> list[str]:
    from sympredict import plotting

    figures = []
    figures += plotting.save(
        plotting.greedy_residuals(results["history"], "Pendulum scenario A: f-greedy residuals"), out, "pendulum_greedy_residuals"
    )
    curves = []
    for i, r in enumerate(results["per_dt"]):
        curves.append({"t": r["t"], "values": r["err_kernel"], "label": f"kernel, dT={r['dt']}", "style": "-", "color": i})
        curves.append({"t": r["t"], "values": r["err_im"], "label": f"implicit midpoint, dT={r['dt']}", "style": "--", "color": i})
    figures += plotting.save(
        plotting.error_over_time(curves, "Pendulum scenario A: error vs micro-step reference"), out, "pendulum_error_over_time"
    )
    r0 = results["per_dt"][0]
    ex = r0["example"]
    figures += plotting.save(
        plotting.phase_portrait(
            {"reference (implicit midpoint, h<=1e-3)": ex["ref"], "kernel predictor": ex["kernel"], "implicit midpoint, macro step": ex["im"]},
            f"Phase portrait, l={ex['mu']:.3f}, dT={r0['dt']}",
        ),
        out,
        "pendulum_phase_portrait",
    )
    figures += plotting.save(
        plotting.energy_error(
            r0["t"],
            {"kernel predictor": r0["energy_kernel"], "implicit midpoint, macro step": r0["energy_im"], "reference": r0["energy_ref"]},
            f"Relative Hamiltonian error (mean over test set), dT={r0['dt']}",
        ),
        out,
        "pendulum_energy_error",
    )
    s = results["summary"]
    with open(out / "results.json", "w") as f:
        json.dump({"pendulum_scenario_a": s, "figures": figures, "command": command}, f, indent=2)
    lines = [
        "# sympredict results: pendulum scenario A",
        "",
        f"Command: `{command}`",
        "",
        f"- training data: {s['n_samples']} samples ({s['n_functionals']} functionals), "
        f"{s['preset']['n_grid']}x{s['preset']['n_grid']} energy-bounded grid, lengths 0.7..0.8 (5), dT 0.04/0.05/0.06",
        f"- model: IMQ eps = {s['preset']['eps']}, {s['n_centers']} centres (stop: {s['stop_reason']})",
        f"- f-greedy: E_train = {s['E_train']:.2e}, E_val = {s['E_val']:.2e} ({s['n_val_samples']} validation samples)",
        f"- time: data {s['time_data_s']:.1f} s, training {s['time_fit_s']:.1f} s; peak memory {s['peak_rss_gib']:.2f} GiB",
        "",
        f"Test: 5 q0 ~ U[0, pi/2] x 5 lengths ~ U[0.7, 0.8], p0 = 0, T = {s['preset']['horizon']}; "
        "mean relative error over the 25 trajectories, then median / max over time.",
        "",
        "| dT | kernel median | kernel max | implicit midpoint median | implicit midpoint max | ratio (median) | kernel max energy err | IM max energy err |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in s["per_dt"]:
        lines.append(
            f"| {r['dt']} | {r['kernel_median_err']:.2e} | {r['kernel_max_err']:.2e} | {r['im_median_err']:.2e} | "
            f"{r['im_max_err']:.2e} | {r['ratio_median']:.0f}x | {r['kernel_max_energy_err']:.2e} | {r['im_max_energy_err']:.2e} |"
        )
    lines += ["", "Figures:", ""] + [f"- `{name}`" for name in figures if name.endswith(".png")]
    (out / "summary.md").write_text("\n".join(lines) + "\n")
    return figures


def _cmd_run(args) -> int:
    from threadpoolctl import threadpool_limits

    from sympredict.experiments.pendulum import PRESETS, run_scenario_a

    preset_name = args.preset or ("paper" if args.paper else "quick")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    command = "sympredict " + " ".join(sys.argv[1:]) if sys.argv[0].endswith("sympredict") else "sympredict run " + args.system
    t0 = time.perf_counter()
    print(f"sympredict: {args.system}, preset '{preset_name}', {args.threads} BLAS thread(s), output in {out}/", flush=True)
    with threadpool_limits(limits=args.threads):
        results = run_scenario_a(PRESETS[preset_name], seed=args.seed, model_path=out / "pendulum_model.h5")
    _write_pendulum_outputs(results, out, command)
    s = results["summary"]
    print(f"trained {s['n_centers']} centres on {s['n_functionals']} functionals in {s['time_fit_s']:.1f} s "
          f"(E_train {s['E_train']:.2e}, E_val {s['E_val']:.2e})")
    for r in s["per_dt"]:
        print(f"  dT={r['dt']}: kernel median error {r['kernel_median_err']:.2e} (max {r['kernel_max_err']:.2e}), "
              f"implicit midpoint {r['im_median_err']:.2e} (ratio {r['ratio_median']:.3g})")
    print(f"done in {time.perf_counter() - t0:.0f} s; summary: {out / 'summary.md'}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="sympredict", description="Symplectic large-step kernel predictors for Hamiltonian systems.")
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="train, evaluate and write figures and a summary for a system")
    run.add_argument("system", choices=["pendulum"], help="the scenario to run")
    run.add_argument("--out", required=True, help="output folder (created if missing)")
    size = run.add_mutually_exclusive_group()
    size.add_argument("--quick", action="store_true", help="50x50 grid, 1500 centres: about a minute on 2 cores (default)")
    size.add_argument("--paper", action="store_true", help="the paper's 200x200 grid (688,464 functionals): minutes, ~10 GiB")
    size.add_argument("--preset", choices=["smoke", "quick", "paper"], help="a preset by name ('smoke': seconds, for testing)")
    run.add_argument("--seed", type=int, default=0, help="seed of the validation and test draws (default 0)")
    run.add_argument("--threads", type=int, default=os.cpu_count() or 1, help="BLAS threads (default: all cores)")
    run.set_defaults(func=_cmd_run)
    return parser


def main(argv=None) -> int:
    from pymor.core.logger import set_log_levels

    args = build_parser().parse_args(argv)
    set_log_levels({"sympredict": "INFO"})
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
