"""``sympredict-paper run``: train and evaluate the paper's scenarios, write models, figures and a summary.

``sympredict-paper run pendulum|wave|henon-heiles|sine-gordon|all --quick --out DIR`` trains and evaluates the
paper's scenarios and writes into ``DIR``: trained models (HDF5), figures (PNG and PDF), ``results.json`` and
``summary.md``.  Each scenario module's ``main`` (``python -m sympredict_paper.pendulum --quick --out DIR``) is
this command for its scenario.

A run never leaves a folder that passes for complete when it is not: it writes
into a hidden sibling ``.DIR.partial-PID-XXXXXXXX``, puts the marker
``.sympredict-run.json`` there last, and renames the folder to ``DIR`` only
then.  A failed or interrupted run removes its staging folder (one killed
with SIGKILL is removed by a later run, see :func:`sympredict.container.is_stale`)
and leaves an existing ``DIR`` as it was.  An existing ``DIR`` is replaced
only if it is empty or a previous run's output (it has the marker, or only
the files a run writes); anything else is refused before the work starts.
Every error is one line on stderr with a non-zero exit code.
"""

from __future__ import annotations

import json
import os
import re
import secrets
import shutil
import stat
import statistics
import sys
import time
from pathlib import Path

from sympredict.cli._console import _duration
from sympredict.cli._options import _add_verbose, _int_at_least

__all__ = ["add_parser", "RUN_MARKER", "SYSTEMS", "ALL_SYSTEMS"]

SYSTEMS = ("pendulum", "wave", "henon-heiles")
#: What ``run all`` runs: Hénon–Heiles (about 2 min more on 2 shared cores) is run on its own, ``run henon-heiles``.
ALL_SYSTEMS = ("pendulum", "wave")
#: Written last into a run's output folder: the run completed.
RUN_MARKER = ".sympredict-run.json"
_RUN_OUTPUT_SUFFIXES = (".png", ".pdf", ".json", ".h5", ".md")


def _run_pendulum(preset_name: str, seed: int, out: Path):
    """Pendulum scenarios A and B and the stability study: returns (JSON summary, figure files, Markdown lines)."""
    from sympredict_paper import report
    from sympredict_paper.pendulum import (
        PRESETS,
        run_scenario_a,
        run_scenario_b,
        run_speed_accuracy,
        run_stability,
        train_peers,
    )

    preset = PRESETS[preset_name]
    results = run_scenario_a(preset, seed=seed, model_path=out / "pendulum_model.h5")
    figures = report.save_figures(report.pendulum_a_figures(results), out)
    s = results["summary"]
    lines = report.pendulum_a_markdown(s)
    for r in s["per_dt"]:
        print(
            f"  pendulum dT={r['dt']}: kernel median error {r['kernel_median_err']:.2e} (max {r['kernel_max_err']:.2e}), "
            f"implicit midpoint {r['im_median_err']:.2e} (ratio {r['ratio_median']:.3g})"
        )

    peers = train_peers(results["model"], preset, seed=seed)
    sa = run_speed_accuracy(results["model"], preset, seed=seed, direct=peers["direct"], vkoga=peers["vkoga"])
    sa["time_fit_direct_s"], sa["time_fit_vkoga_s"] = peers["time_fit_direct_s"], peers["time_fit_vkoga_s"]
    sa["vkoga_selection"] = peers["vkoga_selection"]
    figures += report.save_figures(
        report.speed_accuracy_figure(sa, "pendulum_speed_accuracy", f"Pendulum: speed against accuracy, dT={sa['dt']}"),
        out,
    )
    lines += report.speed_accuracy_markdown(
        sa,
        f"Errors against {sa['error_reference']}. Micro-step reference (implicit midpoint, h <= 1e-3): "
        f"{sa['reference_time_s'] * 1e3:.2f} ms per trajectory. The direct model and VKOGA were trained on the same data "
        f"({sa['time_fit_direct_s']:.0f} s and {sa['time_fit_vkoga_s']:.0f} s).",
    )
    lines += ["", "Targets no model reached: " + "; ".join(sa["unreached"])] if sa["unreached"] else []
    s["speed_accuracy"] = sa

    kernel = results["model"].kernel_
    b = run_scenario_b(preset, seed=seed, kernels=(kernel.state, kernel.mu, kernel.dt))
    sb = b["summary"]
    figures += report.save_figures(report.pendulum_b_figures(b), out)
    lines += report.pendulum_b_markdown(sb)
    s["scenario_b"] = sb

    st = run_stability(results["model"], preset, direct=peers["direct"])
    figures += report.save_figures(report.stability_figures(st), out)
    lines += report.stability_markdown(st, preset.horizon)
    s["stability"] = st
    print(
        f"  scenario B at l={sb['mu']}: energy drift symplectic {sb['energy_drift_symplectic']:+.1e}, "
        f"direct {sb['energy_drift_direct']:+.1e}"
    )
    return s, figures, lines


def _run_wave(preset_name: str, seed: int, out: Path):
    """Wave MOR pipeline: returns (JSON summary, figure files, Markdown lines)."""
    from sympredict_paper import report
    from sympredict_paper.wave import PRESETS, run_wave

    results = run_wave(PRESETS[preset_name], seed=seed)
    for r in results["per_dt"]:
        r["model"].save(out / f"wave_model_dt{r['dt']}.h5")
    figures = report.save_figures(report.wave_figures(results), out)
    s = results["summary"]
    lines = report.wave_markdown(s)
    for r in s["per_dt"]:
        for c in r["cases"]:
            print(
                f"  wave dT={r['dt']} c={c['c']:.3f}: kernel {c['mean_kernel_red']:.2e}, implicit midpoint {c['mean_im_red']:.2e} "
                f"(ratio {c['ratio_red']:.3g})"
            )

    sa = s["speed_accuracy"]
    figures += report.save_figures(
        report.speed_accuracy_figure(sa, "wave_speed_accuracy", f"Wave: FOM vs ROM vs ROM + kernel, dT={sa['dt']}"), out
    )
    lines += report.speed_accuracy_markdown(
        sa,
        "Errors of full-space states against the FOM's exact solution (sine transform); every method starts from the same "
        "full states and returns full states (ROM methods include projection and reconstruction).",
    )
    lines += report.smallest_model_markdown(s)
    z = s["smallest"]
    print(
        f"  wave smallest model for {z['target']:.0e}: 2n = {2 * z['n_reduced']}, "
        f"{z['n_centers'] if z['reached'] else 'target not reached with all'} centres, validation error {z['validation_error']:.2e}"
    )
    return s, figures, lines


def _run_sine_gordon(preset_name: str, seed: int, out: Path):
    """Sine-Gordon MOR: returns (JSON summary, figure files, Markdown lines)."""
    from sympredict_paper import report
    from sympredict_paper.sine_gordon import PRESETS, run_sine_gordon

    s = run_sine_gordon(PRESETS[preset_name], seed=seed)
    figures = report.save_figures(report.sine_gordon_figures(s), out)
    for d, r in s["dims"].items():
        k = r["kernel_projected"]["error"]
        print(
            f"  sine-Gordon 2n={d}: Galerkin {statistics.median(r['galerkin_error']):.2e}, DEIM {statistics.median(r['deim_error']):.2e}, "
            f"kernel (FOM data) {'failed' if k is None else format(statistics.median(k), '.2e')}"
        )
    return s, figures, report.sine_gordon_markdown(s)


def _run_henon_heiles(preset_name: str, seed: int, out: Path):
    """Hénon–Heiles speed against accuracy: returns (JSON summary, figure files, Markdown lines)."""
    from sympredict_paper import report
    from sympredict_paper.henon_heiles import PRESETS, run_henon_heiles

    results = run_henon_heiles(PRESETS[preset_name], seed=seed)
    results["model"].save(out / "henon_heiles_model.h5")
    s = results["summary"]
    sa = s["speed_accuracy"]
    figures = report.save_figures(
        report.speed_accuracy_figure(
            sa, "henon_heiles_speed_accuracy", f"Hénon–Heiles: speed against accuracy, dT={sa['dt']}"
        ),
        out,
    )
    lines = report.henon_heiles_markdown(s)
    best = min((r for r in sa["rows"] if r["method"] == "kernel predictor"), key=lambda r: r["median_err"])
    print(
        f"  Hénon–Heiles: kernel m={best['size']} median error {best['median_err']:.2e} in "
        f"{best['time_per_trajectory_s'] * 1e3:.3g} ms per trajectory"
    )
    return s, figures, lines


def _check_run_folder(out: Path) -> None:
    """Refuse an ``--out`` that a run may not replace (before any work); see the module docstring."""
    if out.exists() or out.is_symlink():
        if not out.is_dir():
            raise ValueError(f"--out {str(out)!r} exists and is not a directory; give a folder")
        cwd = Path.cwd().resolve()
        if out.resolve() == cwd or out.resolve() in cwd.parents:
            raise ValueError(f"--out {str(out)!r} is the current directory or contains it; run from outside it")
        entries = list(out.iterdir())
        legacy = any(e.name == "results.json" for e in entries) and all(
            e.is_file() and not e.is_symlink() and e.suffix in _RUN_OUTPUT_SUFFIXES for e in entries
        )
        if entries and not (out / RUN_MARKER).is_file() and not legacy:
            raise ValueError(
                f"--out {str(out)!r} exists and is not the output folder of a previous run (it holds other files, "
                f"e.g. {entries[0].name!r}); give a new or empty folder"
            )
    parent = out.parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise ValueError(f"--out {str(out)!r}: {str(parent)!r} is not a directory")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise ValueError(f"--out {str(out)!r}: no permission to create folders in {str(parent)!r}")


def _remove_stale_staging(parent: Path, name: str) -> None:
    """Remove staging folders of ``name`` left by killed runs (same rule as the container's temp files)."""
    from sympredict.container import entries_matching, is_stale

    pattern = re.compile(r"\." + re.escape(name) + r"\.(?:partial|old)-(\d+)-[0-9a-f]{8}")
    for entry, match in entries_matching(parent, pattern):
        if entry.is_dir(follow_symlinks=False) and is_stale(
            int(match.group(1)), entry.stat(follow_symlinks=False).st_mtime
        ):
            shutil.rmtree(entry.path, ignore_errors=True)


def _publish_run(staging: Path, out: Path) -> None:
    """Rename the finished ``staging`` folder to ``out`` (replacing a previous run's folder)."""
    if out.exists():
        old = out.parent / f".{out.name}.old-{os.getpid()}-{secrets.token_hex(4)}"
        os.chmod(staging, stat.S_IMODE(out.stat().st_mode))
        os.rename(out, old)
        try:
            os.rename(staging, out)
        except BaseException:
            os.rename(old, out)
            raise
        shutil.rmtree(old, ignore_errors=True)
    else:
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(staging, 0o777 & ~umask)
        os.rename(staging, out)


def _cmd_run(args) -> int:
    from sympredict_paper import report
    from threadpoolctl import threadpool_limits

    preset_name = args.preset or ("paper" if args.paper else "quick")
    if args.initial == "breather":  # the sine-Gordon breather scenario has its own presets
        breather_presets = {"quick": "breather", "smoke": "smoke-breather"}
        if args.system != "sine-gordon" or preset_name not in breather_presets:
            print(
                "sympredict-paper: --initial breather needs `run sine-gordon` with --quick or --preset smoke",
                file=sys.stderr,
            )
            return 2
        preset_name = breather_presets[preset_name]
    systems = ALL_SYSTEMS if args.system == "all" else (args.system,)
    out = Path(args.out)
    if out.is_symlink() and out.is_dir():  # write into the folder the link names; the link stays
        out = Path(os.path.realpath(out))
    _check_run_folder(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    _remove_stale_staging(out.parent, out.name)
    staging = out.parent / f".{out.name}.partial-{os.getpid()}-{secrets.token_hex(4)}"
    staging.mkdir()
    command = "sympredict-paper " + " ".join(
        sys.argv[1:] if sys.argv[0].endswith("sympredict-paper") else ["run", args.system, "..."]
    )
    t0 = time.perf_counter()
    print(
        f"sympredict-paper: {', '.join(systems)}, preset '{preset_name}', {args.threads} BLAS thread(s), output in {out}/",
        flush=True,
    )
    try:
        results, figures, lines = {}, [], ["# sympredict results", "", f"Command: `{command}`", ""]
        runners = {
            "pendulum": _run_pendulum,
            "wave": _run_wave,
            "sine-gordon": _run_sine_gordon,
            "henon-heiles": _run_henon_heiles,
        }
        with threadpool_limits(limits=args.threads):
            for system in systems:
                summary, figs, md = runners[system](preset_name, args.seed, staging)
                results[system] = summary
                figures += figs
                lines += md + ["", "Figures: " + ", ".join(f"`{f}`" for f in figs if f.endswith(".png")), ""]
        claims = report.claims(results)
        lines[4:4] = report.claims_markdown(claims)
        for c in claims:
            print(f"  claim {'holds' if c['holds'] else 'DOES NOT HOLD'}: {c['claim']}")
        with open(staging / "results.json", "w") as f:
            json.dump(
                {"command": command, "preset": preset_name, "claims": claims, "results": results, "figures": figures},
                f,
                indent=2,
            )
        (staging / "summary.md").write_text("\n".join(lines) + "\n")
        marker = {
            "complete": True,
            "command": command,
            "preset": preset_name,
            "systems": list(systems),
            "files": sorted(p.name for p in staging.iterdir()),
        }
        (staging / RUN_MARKER).write_text(json.dumps(marker, indent=2) + "\n")
        _publish_run(staging, out)
    finally:
        if staging.exists():  # failed or interrupted: nothing half-written survives
            shutil.rmtree(staging, ignore_errors=True)
    print(f"done in {_duration(time.perf_counter() - t0)}; summary: {out / 'summary.md'}")
    return 0


def add_parser(sub) -> None:
    """Register ``sympredict-paper run`` with the subparsers ``sub``."""
    run = sub.add_parser("run", help="train, evaluate and write figures and a summary")
    run.add_argument(
        "system",
        choices=[*SYSTEMS, "sine-gordon", "all"],
        help="the scenario to run ('all': pendulum and wave; sine-Gordon runs alone)",
    )
    run.add_argument("--out", required=True, help="output folder (created if missing)")
    size = run.add_mutually_exclusive_group()
    size.add_argument(
        "--quick",
        action="store_true",
        help="small data (default): minutes on 2 cores (measured times: docs/data/runtimes.json)",
    )
    size.add_argument("--paper", action="store_true", help="the paper's data sizes: minutes, ~10 GiB")
    size.add_argument(
        "--preset", choices=["smoke", "quick", "paper"], help="a preset by name ('smoke': seconds, for testing)"
    )
    run.add_argument(
        "--initial",
        choices=["sech_cos", "breather"],
        default="sech_cos",
        help="sine-Gordon only: initial-data family ('breather': the breather presets, --quick or --preset smoke)",
    )
    run.add_argument(
        "--seed", type=_int_at_least(0), default=0, help="seed of the validation and test draws (default 0)"
    )
    run.add_argument(
        "--threads", type=_int_at_least(1), default=os.cpu_count() or 1, help="BLAS threads (default: all cores)"
    )
    _add_verbose(run)
    run.set_defaults(func=_cmd_run)
