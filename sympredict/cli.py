"""The ``sympredict`` command (argument parsing, progress and files; no numerics here).

``sympredict run pendulum|wave|all --quick --out DIR`` trains and evaluates the
paper's scenarios and writes into ``DIR``: trained models (HDF5), figures (PNG
and PDF), ``results.json`` and ``summary.md``.  ``data``, ``train``, ``predict``
and ``report`` work on HDF5 data sets and models.

A run never leaves a folder that passes for complete when it is not: it writes
into a hidden sibling ``.DIR.partial-PID-XXXXXXXX``, puts the marker
``.sympredict-run.json`` there last, and renames the folder to ``DIR`` only
then.  A failed or interrupted run removes its staging folder (one killed
with SIGKILL is removed by a later run, see :func:`sympredict.container.is_stale`)
and leaves an existing ``DIR`` as it was.  An existing ``DIR`` is replaced
only if it is empty or a previous run's output (it has the marker, or only
the files a run writes); anything else is refused before the work starts.
Output paths are checked before any work, and one equal to an input path is
refused.  Every error is one line on stderr with a non-zero exit code.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import secrets
import shutil
import stat
import sys
import time
from pathlib import Path

__all__ = ["main"]

SYSTEMS = ("pendulum", "wave")
#: Written last into a run's output folder: the run completed.
RUN_MARKER = ".sympredict-run.json"
_RUN_OUTPUT_SUFFIXES = (".png", ".pdf", ".json", ".h5", ".md")


def _speed_accuracy_section(sa: dict, out: Path, name: str, title: str, note: str):
    """Figure and Markdown table of a speed-against-accuracy run (pendulum or wave): (figure files, lines)."""
    from sympredict import plotting

    figures = plotting.save(plotting.speed_accuracy(sa["rows"], sa["reference_time_s"], title), out, name)
    lines = [
        "",
        f"### Speed against accuracy (dT = {sa['dt']}, {sa['n_trajectories']} trajectories x {sa['n_steps']} steps, "
        f"medians of {sa['repeats']} timed runs, side by side in one process)",
        "",
        note,
        "",
        "| method | size | ms per trajectory | median error | max error |",
        "|---|---|---|---|---|",
        *[f"| {r['method']} | {plotting.point_tag(r)} | {r['time_per_trajectory_s'] * 1e3:.3g} | {r['median_err']:.2e} | "
          f"{r['max_err']:.2e} |" for r in sa["rows"]],
    ]
    return figures, lines


def _run_pendulum(preset_name: str, seed: int, out: Path):
    """Pendulum scenario A: returns (JSON summary, figure files, Markdown lines)."""
    from sympredict import plotting
    from sympredict.experiments.pendulum import PRESETS, run_scenario_a, run_scenario_b, run_speed_accuracy, run_stability

    results = run_scenario_a(PRESETS[preset_name], seed=seed, model_path=out / "pendulum_model.h5")
    figures = plotting.save(
        plotting.greedy_residuals({"": results["history"]}, "Pendulum scenario A: f-greedy residuals"), out, "pendulum_greedy_residuals"
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
    lines = [
        "## Pendulum scenario A",
        "",
        f"- training data: {s['n_samples']} samples ({s['n_functionals']} functionals), "
        f"{s['preset']['n_grid']}x{s['preset']['n_grid']} energy-bounded grid, lengths 0.7..0.8 (5), dT 0.04/0.05/0.06",
        f"- model: kernel {' x '.join(s['kernel'])}"
        + (f" (chosen by validation, below)" if s["selection"] else " (preset shapes)")
        + f", {s['n_centers']} centres (stop: {s['stop_reason']})",
        f"- f-greedy: E_train = {s['E_train']:.2e}, E_val = {s['E_val']:.2e} ({s['n_val_samples']} validation samples)",
        f"- time: data {s['time_data_s']:.1f} s, training {s['time_fit_s']:.1f} s; peak memory of the process so far {s['peak_rss_gib']:.2f} GiB",
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
            f"{r['im_max_err']:.2e} | {_ratio(r['ratio_median'])} | {r['kernel_max_energy_err']:.2e} | {r['im_max_energy_err']:.2e} |"
        )
    if s["selection"]:
        sel = s["selection"]
        lines += [
            "",
            f"### Kernel selection by validation ({sel['n_candidates']} candidates, {sel['time_s']:.0f} s)",
            "",
            f"Screening on a {s['preset']['select_n_grid']}x{s['preset']['select_n_grid']} grid ({sel['n_samples']} samples), "
            f"{sel['n_val_samples']} validation samples, E_val at m* = {sel['m_screen']} centres; best per family:",
            "",
            "| family | best tuple | E_val(m*) |",
            "|---|---|---|",
            *[f"| {fam} | {row['state']} x {row['mu']} x {row['dt']} | {row['E_val']:.2e} |" for fam, row in sel["best_per_family"].items()],
            "",
            f"Refinement of the winner's shapes (factor 2, one factor at a time) at m* = {sel['m_refine']}: "
            f"{' x '.join(sel['chosen'])} with E_val = {sel['chosen_E_val']:.2e}.",
        ]
    for r in s["per_dt"]:
        print(f"  pendulum dT={r['dt']}: kernel median error {r['kernel_median_err']:.2e} (max {r['kernel_max_err']:.2e}), "
              f"implicit midpoint {r['im_median_err']:.2e} (ratio {r['ratio_median']:.3g})")

    sa = run_speed_accuracy(results["model"], PRESETS[preset_name], seed=seed)
    figs, md = _speed_accuracy_section(
        sa, out, "pendulum_speed_accuracy", f"Pendulum: speed against accuracy, dT={sa['dt']}",
        f"Micro-step reference (implicit midpoint, h <= 1e-3): {sa['reference_time_s'] * 1e3:.2f} ms per trajectory.",
    )
    figures += figs
    lines += md + (["", "Targets no model reached: " + "; ".join(sa["unreached"])] if sa["unreached"] else [])
    s["speed_accuracy"] = sa

    kernel = results["model"].kernel_
    b = run_scenario_b(PRESETS[preset_name], seed=seed, kernels=(kernel.state, kernel.mu, kernel.dt))
    sb = b["summary"]
    curves = []
    for i, r in enumerate(b["per_dt"]):
        curves.append({"t": r["t"], "values": r["err_symplectic"], "label": f"symplectic kernel, dT={r['dt']}", "style": "-", "color": i})
        curves.append({"t": r["t"], "values": r["err_direct"], "label": f"direct kernel, dT={r['dt']}", "style": "--", "color": i})
    where = f"l={sb['mu']} (extrapolated), dT={sb['dt_example']}"
    figures += plotting.save(
        plotting.error_over_time(curves, f"Pendulum scenario B, l={sb['mu']} (extrapolated): error vs reference"), out, "pendulum_b_error_over_time"
    )
    ex = b["example"]
    labelled = {"reference": ex["reference"], "symplectic kernel": ex["symplectic"], "direct kernel": ex["direct"]}
    figures += plotting.save(plotting.trajectories_over_time(ex["t"], labelled, f"Scenario B trajectory, {where}"), out, "pendulum_b_trajectories")
    figures += plotting.save(plotting.phase_portrait(labelled, f"Scenario B phase portrait, {where}"), out, "pendulum_b_phase_portrait")
    energies = {"reference": b["energy"]["reference"], "symplectic kernel": b["energy"]["symplectic"], "direct kernel": b["energy"]["direct"]}
    figures += plotting.save(plotting.hamiltonian_over_time(ex["t"], energies, f"Scenario B Hamiltonian, {where}"), out, "pendulum_b_hamiltonian")
    figures += plotting.save(
        plotting.energy_error(ex["t"], {"reference": b["energy_err"]["reference"], "symplectic kernel": b["energy_err"]["symplectic"],
                                        "direct kernel": b["energy_err"]["direct"]}, f"Scenario B relative Hamiltonian error, {where}"),
        out,
        "pendulum_b_energy_error",
    )
    lines += [
        "",
        "## Pendulum scenario B: less data (p <= 0), extrapolation in the length",
        "",
        f"- training data: {sb['n_samples']} samples with p0 <= 0; symplectic model {sb['n_centers_symplectic']} centres, "
        f"direct (non-symplectic) model {sb['n_centers_direct']} centres, same kernel",
        f"- test at l = {sb['mu']} (training lengths 0.7..0.8), 5 random q0, p0 = 0",
        "",
        "| dT | symplectic median error | direct median error |",
        "|---|---|---|",
        *[f"| {r['dt']} | {r['symplectic_median_err']:.2e} | {r['direct_median_err']:.2e} |" for r in sb["per_dt"]],
        "",
        f"One trajectory (q0 = {sb['q0_example']:.3f}, {where}): relative energy error at most "
        f"{sb['max_rel_energy_err_symplectic']:.1e} (symplectic), {sb['max_rel_energy_err_direct']:.1e} (direct), "
        f"{sb['max_rel_energy_err_reference']:.1e} (reference); energy drift (last tenth minus first tenth, relative) "
        f"{sb['energy_drift_symplectic']:+.1e} (symplectic) vs {sb['energy_drift_direct']:+.1e} (direct).",
    ]
    s["scenario_b"] = sb

    st = run_stability(results["model"], PRESETS[preset_name])
    figures += plotting.save(
        plotting.stability_sweeps(st["dt_sweep"], st["mu_sweep"], (0.04, 0.06), (0.7, 0.8),
                                  f"Where methods fail: step sweep, l={st['mu']}, q0={st['q0']}"),
        out,
        "pendulum_stability",
    )

    def cell(v):
        return f"{v:.2e}" if isinstance(v, float) else v

    lines += [
        "",
        f"## Where methods fail (q0 = {st['q0']}, p0 = 0, l = {st['mu']})",
        "",
        f"Long horizon: {st['periods']} periods ({st['n_steps']} steps of dT = {st['dt']}):",
        "",
        "| method | energy error, first tenth | energy error, last tenth | phase error at the end [rad] | final relative error |",
        "|---|---|---|---|---|",
        *[f"| {k} | {v['energy_first']:.2e} | {v['energy_last']:.2e} | {v['phase_error_rad']:+.2e} | {v['final_rel_err']:.2e} |"
          for k, v in st["long"].items()],
        "",
        f"Step sweep (training steps 0.04..0.06; T = {PRESETS[preset_name].horizon}; mean relative error, or how the method failed):",
        "",
        "| dT | dT * L_S (kernel) | kernel predictor | implicit midpoint | Stormer-Verlet |",
        "|---|---|---|---|---|",
        *[f"| {r['dt']} | {r['solvability']:.2f} | {cell(r['kernel'])} | {cell(r['implicit midpoint'])} | {cell(r['Stormer-Verlet'])} |"
          for r in st["dt_sweep"]],
        "",
        "Extrapolation in the length (training lengths 0.7..0.8):",
        "",
        "| l | kernel predictor | implicit midpoint |",
        "|---|---|---|",
        *[f"| {r['mu']} | {cell(r['kernel'])} | {cell(r['implicit midpoint'])} |" for r in st["mu_sweep"]],
    ]
    s["stability"] = st
    print(f"  scenario B at l={sb['mu']}: energy drift symplectic {sb['energy_drift_symplectic']:+.1e}, "
          f"direct {sb['energy_drift_direct']:+.1e}")
    return s, figures, lines


def _run_wave(preset_name: str, seed: int, out: Path):
    """Wave MOR pipeline: returns (JSON summary, figure files, Markdown lines)."""
    import numpy as np

    from sympredict import plotting
    from sympredict.experiments.wave import PRESETS, run_wave

    results = run_wave(PRESETS[preset_name], seed=seed)
    for r in results["per_dt"]:
        r["model"].save(out / f"wave_model_dt{r['dt']}.h5")
    figures = plotting.save(
        plotting.greedy_residuals({f", dT={r['dt']}": r["model"].history_ for r in results["per_dt"]}, "Reduced wave: f-greedy residuals"),
        out,
        "wave_greedy_residuals",
    )
    for space, title in (("red", "reduced coordinates"), ("full", "full space, after reconstruction")):
        curves = []
        for i, r in enumerate(results["per_dt"]):
            t = r["cases"][0]["t"]
            kernel = np.mean([c["err"][f"kernel_{space}"] for c in r["cases"]], axis=0)
            im = np.mean([c["err"][f"im_{space}"] for c in r["cases"]], axis=0)
            curves.append({"t": t, "values": kernel, "label": f"kernel, dT={r['dt']}", "style": "-", "color": i})
            curves.append({"t": t, "values": im, "label": f"implicit midpoint, dT={r['dt']}", "style": "--", "color": i})
        figures += plotting.save(
            plotting.error_over_time(curves, f"Wave, {title}: error vs micro-step reference (mean over test speeds)"),
            out,
            f"wave_error_over_time_{space}",
        )
    s = results["summary"]
    b = s["basis"]
    lines = [
        "## Wave equation: MOR pipeline",
        "",
        f"- FOM: N = {s['preset']['n_points']} points (2N = {2 * s['preset']['n_points']}), pyMOR QuadraticHamiltonianModel, mu = c^2",
        f"- basis: complex SVD of {b['n_snapshots']} snapshots at c_ref = 0.3 in {b['time_basis_s']:.2f} s "
        f"(snapshots {b['time_snapshots_s']:.2f} s); 2n = {2 * s['preset']['n_reduced']}; "
        f"max |V^T J V - J| = {b['symplecticity']:.1e}, max |V^T V - I| = {b['orthonormality']:.1e}; "
        f"leading singular values {', '.join(f'{v:.3g}' for v in b['singular_values'][:2 * s['preset']['n_reduced'] + 2])}",
        f"- data per dT: {s['preset']['samples_per_speed']} reduced states per training speed (6 speeds), uniform in the energy ellipsoid",
        f"- test: speeds {', '.join(f'{c:.3f}' for c in s['test_speeds'])}, {s['preset']['n_test_ics']} initial conditions each, "
        f"T = {s['preset']['horizon']}; errors are time averages of the mean relative error over the initial conditions",
        "",
        "| dT | kernel (chosen on validation) | centres | E_train | c | kernel, reduced | IM, reduced | kernel, full | IM, full | ratio | time ROM+kernel / FOM ref |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in s["per_dt"]:
        for c in r["cases"]:
            lines.append(
                f"| {r['dt']} | {r['kernel']['state']} x {r['kernel']['mu']} | {r['n_centers']} ({r['stop_reason']}) | {r['E_train']:.1e} | "
                f"{c['c']:.3f} | {c['mean_kernel_red']:.2e} | {c['mean_im_red']:.2e} | {c['mean_kernel_full']:.2e} | {c['mean_im_full']:.2e} | "
                f"{_ratio(c['ratio_red'])} | {c['time_kernel_s']:.3f} s / {c['time_fom_ref_s']:.2f} s |"
            )
            print(f"  wave dT={r['dt']} c={c['c']:.3f}: kernel {c['mean_kernel_red']:.2e}, implicit midpoint {c['mean_im_red']:.2e} "
                  f"(ratio {c['ratio_red']:.3g})")

    sa = s["speed_accuracy"]
    figs, md = _speed_accuracy_section(
        sa, out, "wave_speed_accuracy", f"Wave: FOM vs ROM vs ROM + kernel, dT={sa['dt']}",
        "Errors of full-space states against the FOM's exact solution (sine transform); every method starts from the same "
        "full states and returns full states (ROM methods include projection and reconstruction).",
    )
    figures += figs
    lines += md
    z = s["smallest"]
    lines += [
        "",
        f"### No bigger model than needed: target {z['target']:.0e} (dT = {z['dt']})",
        "",
        f"Validation: FOM trajectories in the first {s['preset']['n_modes']} sine modes at random speeds, error against the exact FOM "
        f"solution. Reduction errors by reduced dimension: "
        + ", ".join(f"2n = {2 * int(n)}: {e:.1e}" for n, e in z["rom_errors"].items())
        + f" (budget for the reduction: {z['rom_share']:.0%} of the target).",
        "",
        (f"Built: 2n = {2 * z['n_reduced']}, {z['n_centers']} of {z['of_centers']} centres ({z['kernel']['state']} x {z['kernel']['mu']}); "
         f"validation error {z['validation_error']:.2e}, error on fresh test trajectories {z['test_error']:.2e}."
         if z["reached"] else
         f"Target NOT reached: 2n = {2 * z['n_reduced']}, all {z['of_centers']} centres give {z['validation_error']:.2e} "
         f"(test {z['test_error']:.2e})."),
    ]
    print(f"  wave smallest model for {z['target']:.0e}: 2n = {2 * z['n_reduced']}, "
          f"{z['n_centers'] if z['reached'] else 'target not reached with all'} centres, validation error {z['validation_error']:.2e}")
    return s, figures, lines


def _ratio(v: float) -> str:
    """A ratio of errors for tables: whole numbers from 10 on, two digits below."""
    return f"{v:.0f}x" if v >= 10 else f"{v:.2g}x"


def _claims(results: dict) -> list[dict]:
    """The paper's qualitative claims, each checked against this run's numbers.

    Returns
    -------
    list of dict
        ``claim``, ``holds`` (bool) and ``evidence`` (the numbers, in words).
    """
    claims = []
    if "pendulum" in results:
        p = results["pendulum"]
        ratios = [r["ratio_median"] for r in p["per_dt"]]
        pointwise = [r["ratio_min_over_time"] for r in p["per_dt"]]
        claims.append({
            "claim": "pendulum A: the kernel predictor is below implicit midpoint at every test step in the training range, "
                     "by two orders of magnitude (ratio of median errors >= 100)",
            "holds": min(ratios) >= 100 and min(pointwise) > 1,
            "evidence": f"ratios of medians {', '.join(_ratio(v) for v in ratios)} at dT = "
                        f"{', '.join(str(r['dt']) for r in p['per_dt'])}; smallest ratio at any time {_ratio(min(pointwise))}",
        })
        b = p["scenario_b"]
        ds, dd = b["energy_drift_symplectic"], b["energy_drift_direct"]
        claims.append({
            "claim": "pendulum B (extrapolation): bounded energy error for the symplectic predictor, drift for the direct model "
                     "(|drift direct| >= 10 |drift symplectic|)",
            "holds": abs(dd) >= 10 * abs(ds),
            "evidence": f"relative energy drift {ds:+.1e} (symplectic) vs {dd:+.1e} (direct); max relative energy error "
                        f"{b['max_rel_energy_err_symplectic']:.1e} vs {b['max_rel_energy_err_direct']:.1e}",
        })
    if "wave" in results:
        w = results["wave"]
        ratios = {r["dt"]: min(c["ratio_red"] for c in r["cases"]) for r in w["per_dt"]}
        claims.append({
            "claim": "wave: the ROM + kernel predictor is below ROM + implicit midpoint at every test speed and step",
            "holds": min(ratios.values()) > 1,
            "evidence": "smallest ratio of mean errors per dT: " + ", ".join(f"{_ratio(v)} at {dt}" for dt, v in ratios.items()),
        })
    return claims


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
    from sympredict.container import is_stale

    pattern = re.compile(r"\." + re.escape(name) + r"\.(?:partial|old)-(\d+)-[0-9a-f]{8}")
    try:
        entries = list(os.scandir(parent))
    except OSError:
        return
    for entry in entries:
        match = pattern.fullmatch(entry.name)
        if match and entry.is_dir(follow_symlinks=False) and is_stale(int(match.group(1)), entry.stat(follow_symlinks=False).st_mtime):
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
    from threadpoolctl import threadpool_limits

    preset_name = args.preset or ("paper" if args.paper else "quick")
    systems = SYSTEMS if args.system == "all" else (args.system,)
    out = Path(args.out)
    if out.is_symlink() and out.is_dir():  # write into the folder the link names; the link stays
        out = Path(os.path.realpath(out))
    _check_run_folder(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    _remove_stale_staging(out.parent, out.name)
    staging = out.parent / f".{out.name}.partial-{os.getpid()}-{secrets.token_hex(4)}"
    staging.mkdir()
    command = "sympredict " + " ".join(sys.argv[1:] if sys.argv[0].endswith("sympredict") else ["run", args.system, "..."])
    t0 = time.perf_counter()
    print(f"sympredict: {', '.join(systems)}, preset '{preset_name}', {args.threads} BLAS thread(s), output in {out}/", flush=True)
    try:
        results, figures, lines = {}, [], ["# sympredict results", "", f"Command: `{command}`", ""]
        runners = {"pendulum": _run_pendulum, "wave": _run_wave}
        with threadpool_limits(limits=args.threads):
            for system in systems:
                summary, figs, md = runners[system](preset_name, args.seed, staging)
                results[system] = summary
                figures += figs
                lines += md + ["", "Figures: " + ", ".join(f"`{f}`" for f in figs if f.endswith(".png")), ""]
        claims = _claims(results)
        lines[4:4] = ["## The paper's claims, checked on this run", "",
                      *[f"- {'HOLDS' if c['holds'] else 'DOES NOT HOLD'}: {c['claim']}. {c['evidence']}." for c in claims], ""]
        for c in claims:
            print(f"  claim {'holds' if c['holds'] else 'DOES NOT HOLD'}: {c['claim']}")
        with open(staging / "results.json", "w") as f:
            json.dump({"command": command, "preset": preset_name, "claims": claims, "results": results, "figures": figures}, f, indent=2)
        (staging / "summary.md").write_text("\n".join(lines) + "\n")
        marker = {"complete": True, "command": command, "preset": preset_name, "systems": list(systems),
                  "files": sorted(p.name for p in staging.iterdir())}
        (staging / RUN_MARKER).write_text(json.dumps(marker, indent=2) + "\n")
        _publish_run(staging, out)
    finally:
        if staging.exists():  # failed or interrupted: nothing half-written survives
            shutil.rmtree(staging, ignore_errors=True)
    print(f"done in {time.perf_counter() - t0:.0f} s; summary: {out / 'summary.md'}")
    return 0


def _check_output_file(out, *inputs, option: str = "--out") -> None:
    """Refuse an output file that is a directory or special file, lacks its folder, or is one of the inputs."""
    from sympredict.container import check_save_path

    try:
        check_save_path(out)
    except ValueError as exc:
        raise ValueError(f"{option}: {exc}") from None
    for given in inputs:
        if given is not None and _same_file(out, given):
            raise ValueError(f"{option} {str(out)!r} is also an input ({str(given)!r}): refusing to overwrite an input")


def _same_file(a, b) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return os.path.realpath(a) == os.path.realpath(b)


def _parse_kernel(spec: str):
    """``family:eps`` (e.g. ``imq:0.15``) -> kernel; ``none`` -> None."""
    from sympredict.kernels import KERNEL_FAMILIES

    if spec.lower() == "none":
        return None
    family, _, eps = spec.partition(":")
    if family not in KERNEL_FAMILIES or not eps:
        raise ValueError(f"kernel spec {spec!r} must be FAMILY:EPS with FAMILY in {sorted(KERNEL_FAMILIES)}, or 'none'")
    try:
        return KERNEL_FAMILIES[family](float(eps))
    except ValueError as exc:
        raise ValueError(f"kernel spec {spec!r}: {exc}") from None


def _cmd_data(args) -> int:
    from sympredict.io import save_dataset
    from sympredict.systems.pendulum import DT_TRAIN, MU_TRAIN, Pendulum, flow_map_data, random_flow_map_data

    _check_output_file(args.out)
    pendulum = Pendulum()
    if args.random:
        data = random_flow_map_data(pendulum, args.random, seed=args.seed)
        meta = {"system": "pendulum", "kind": "random", "n_samples": args.random, "seed": args.seed}
    else:
        data = flow_map_data(pendulum, MU_TRAIN, DT_TRAIN, n_grid=args.n_grid, p_nonpositive=args.p_nonpositive)
        meta = {"system": "pendulum", "kind": "grid", "n_grid": args.n_grid, "p_nonpositive": args.p_nonpositive}
    save_dataset(data, args.out, **meta)
    print(f"wrote {len(data)} pendulum flow-map samples to {args.out}")
    return 0


def _cmd_train(args) -> int:
    from threadpoolctl import threadpool_limits

    from sympredict import SymplecticKernelPredictor
    from sympredict.io import load_dataset

    _check_output_file(args.out, args.data, args.validation)
    data, meta = load_dataset(args.data)
    validation = load_dataset(args.validation)[0] if args.validation else None
    kernels = [_parse_kernel(k) for k in (args.state, args.mu, args.dt)]
    model = SymplecticKernelPredictor(*kernels, max_centers=args.centers, tol=args.tol)
    mu = data.mu if kernels[1] is not None else None
    if validation is not None and kernels[1] is None:
        validation = (validation.x0, validation.x1, None, validation.dt)
    with threadpool_limits(limits=args.threads):
        model.fit(data.x0, data.x1, mu=mu, dt=data.dt, validation=validation)
    model.save(args.out)
    h = model.history_
    print(f"trained {model.n_centers_} centres ({h.stop_reason}) on {len(data)} samples of {meta.get('system', 'unknown system')}: "
          f"E_train {h.train_max_residual[-1]:.2e}" + (f", E_val {h.val_max_residual[-1]:.2e}" if h.val_max_residual is not None else "")
          + f"; saved to {args.out}")
    return 0


def _cmd_predict(args) -> int:
    import numpy as np

    from sympredict import SymplecticKernelPredictor

    if args.out:
        _check_output_file(args.out, args.model)
    model = SymplecticKernelPredictor.load(args.model)
    try:
        x0 = np.array([[float(v) for v in state.split(",")] for state in args.x0])
    except ValueError:
        raise ValueError(f"--x0 takes comma-separated numbers per state, e.g. --x0 1.0,0.0; got {args.x0}") from None
    traj = model.rollout(x0, args.steps, mu=args.mu, dt=args.dt, check_solvability=args.check)
    if args.out:
        header = "instance,step," + ",".join(f"q{i}" for i in range(model.dim_ // 2)) + "," + ",".join(f"p{i}" for i in range(model.dim_ // 2))
        rows = [[b, k, *traj[b, k]] for b in range(traj.shape[0]) for k in range(traj.shape[1])]
        np.savetxt(args.out, np.array(rows), delimiter=",", header=header, comments="", fmt=["%d", "%d"] + ["%.17g"] * model.dim_)
        print(f"wrote {traj.shape[0]} trajectories of {args.steps} steps to {args.out}")
    else:
        for b in range(traj.shape[0]):
            print(f"instance {b}: x({args.steps} steps) = {', '.join(f'{v:.12g}' for v in traj[b, -1])}")
    return 0


def _cmd_report(args) -> int:
    from sympredict import SymplecticKernelPredictor

    model = SymplecticKernelPredictor.load(args.model)
    h, d = model.history_, model.domain_
    print(f"{args.model}: SymplecticKernelPredictor, state dimension 2n = {model.dim_}, {model.n_mu_} parameter(s)")
    print(f"  kernel: state {model.kernel_.state!r}, mu {model.kernel_.mu!r}, dt {model.kernel_.dt!r}")
    print(f"  {model.n_centers_} centres, greedy stop: {h.stop_reason}, E_train {h.train_max_residual[-1]:.3e}"
          + (f", E_val {h.val_max_residual[-1]:.3e}" if h.val_max_residual is not None else ""))
    print(f"  training box: states {d['x_min'].round(6).tolist()} .. {d['x_max'].round(6).tolist()}")
    if model.n_mu_:
        print(f"                mu {d['mu_min'].round(6).tolist()} .. {d['mu_max'].round(6).tolist()}")
    print(f"                dt {float(d['dt_min']):.6g} .. {float(d['dt_max']):.6g}" + (" (fixed step)" if model.dt_fixed_ else ""))
    return 0


class _Parser(argparse.ArgumentParser):
    """argparse with errors on one line (``prog: error: message``), exit code 2."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _int_at_least(minimum: int):
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer >= {minimum}, got {text!r}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"must be >= {minimum}, got {value}")
        return value

    parse.__name__ = f"integer >= {minimum}"
    return parse


def _finite_float(positive: bool = False, nonnegative: bool = False):
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"must be finite, got {text!r}")
        if positive and value <= 0:
            raise argparse.ArgumentTypeError(f"must be positive, got {value!r}")
        if nonnegative and value < 0:
            raise argparse.ArgumentTypeError(f"must be >= 0, got {value!r}")
        return value

    parse.__name__ = "number"
    return parse


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="sympredict", description="Symplectic large-step kernel predictors for Hamiltonian systems.")
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="train, evaluate and write figures and a summary")
    run.add_argument("system", choices=[*SYSTEMS, "all"], help="the scenario to run")
    run.add_argument("--out", required=True, help="output folder (created if missing)")
    size = run.add_mutually_exclusive_group()
    size.add_argument("--quick", action="store_true", help="small data (default): pendulum ~30 s, wave ~2 min on 2 cores")
    size.add_argument("--paper", action="store_true", help="the paper's data sizes: minutes, ~10 GiB")
    size.add_argument("--preset", choices=["smoke", "quick", "paper"], help="a preset by name ('smoke': seconds, for testing)")
    run.add_argument("--seed", type=_int_at_least(0), default=0, help="seed of the validation and test draws (default 0)")
    run.add_argument("--threads", type=_int_at_least(1), default=os.cpu_count() or 1, help="BLAS threads (default: all cores)")
    run.set_defaults(func=_cmd_run)

    data = sub.add_parser("data", help="write a pendulum flow-map data set (HDF5)")
    data.add_argument("--out", required=True, help="data file (.h5)")
    data.add_argument("--n-grid", type=_int_at_least(2), default=50, help="energy-bounded grid points per axis (default 50; paper 200)")
    data.add_argument("--p-nonpositive", action="store_true", help="keep only states with p <= 0 (scenario B)")
    data.add_argument("--random", type=_int_at_least(0), default=0, metavar="N", help="N random samples instead of the grid (validation data)")
    data.add_argument("--seed", type=_int_at_least(0), default=0)
    data.set_defaults(func=_cmd_data)

    train = sub.add_parser("train", help="train a symplectic predictor on a data set and save it (HDF5)")
    train.add_argument("data", help="data set written by 'sympredict data' or sympredict.io.save_dataset")
    train.add_argument("--out", required=True, help="model file (.h5)")
    train.add_argument("--validation", help="validation data set (records E_val)")
    train.add_argument("--state", default="imq:0.15", help="state kernel FAMILY:EPS (default imq:0.15)")
    train.add_argument("--mu", default="imq:2.0", help="parameter kernel FAMILY:EPS or 'none' (default imq:2.0)")
    train.add_argument("--dt", default="imq:5.0", help="step kernel FAMILY:EPS or 'none' (default imq:5.0)")
    train.add_argument("--centers", type=_int_at_least(1), default=1500, help="maximal number of centres (default 1500)")
    train.add_argument("--tol", type=_finite_float(nonnegative=True), default=1e-10, help="greedy residual tolerance (default 1e-10)")
    train.add_argument("--threads", type=_int_at_least(1), default=os.cpu_count() or 1)
    train.set_defaults(func=_cmd_train)

    predict = sub.add_parser("predict", help="roll a saved model out from given initial states")
    predict.add_argument("model", help="model file")
    predict.add_argument("--x0", required=True, nargs="+", help="initial states, each comma-separated (q..., p...)")
    predict.add_argument("--mu", type=_finite_float(), help="parameter (models with one parameter)")
    predict.add_argument("--dt", type=_finite_float(positive=True), help="macro step (default: the training step of a fixed-step model)")
    predict.add_argument("--steps", type=_int_at_least(0), required=True, help="number of macro steps")
    predict.add_argument("--check", action="store_true", help="refuse to start where dT * L_S >= 1")
    predict.add_argument("--out", help="CSV file for the trajectories (default: print the final states)")
    predict.set_defaults(func=_cmd_predict)

    report = sub.add_parser("report", help="describe a saved model: kernel, centres, residuals, training box")
    report.add_argument("model", help="model file")
    report.set_defaults(func=_cmd_report)
    return parser


def main(argv=None) -> int:
    """Entry point; user errors end with one line on stderr and exit code 1, never a traceback."""
    from pymor.core.logger import set_log_levels

    from sympredict.exceptions import SympredictError

    args = build_parser().parse_args(argv)
    set_log_levels({"sympredict": "INFO", "pymor": "WARN"})
    try:
        return args.func(args)
    except (ValueError, SympredictError, OSError) as exc:
        message = " ".join(str(exc).split()) or type(exc).__name__
        print(f"sympredict: error: {message}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("sympredict: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
