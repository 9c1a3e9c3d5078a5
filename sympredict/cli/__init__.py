"""The ``sympredict`` command (argument parsing, progress and files; no numerics here).

``sympredict run pendulum|wave|henon-heiles|all --quick --out DIR`` trains and evaluates the
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
import statistics
import sys
import time
from pathlib import Path

__all__ = ["main"]


def __getattr__(name):
    """``sympredict.cli.report``, imported on first use: matplotlib loads only for the commands that plot."""
    if name == "report":
        from sympredict.paper import report

        return report
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

SYSTEMS = ("pendulum", "wave", "henon-heiles")
#: What ``run all`` runs: Hénon–Heiles (about 2 min more on 2 shared cores) is run on its own, ``run henon-heiles``.
ALL_SYSTEMS = ("pendulum", "wave")
#: Written last into a run's output folder: the run completed.
RUN_MARKER = ".sympredict-run.json"
_RUN_OUTPUT_SUFFIXES = (".png", ".pdf", ".json", ".h5", ".md")


def _run_pendulum(preset_name: str, seed: int, out: Path):
    """Pendulum scenarios A and B and the stability study: returns (JSON summary, figure files, Markdown lines)."""
    from sympredict.paper import report
    from sympredict.paper.pendulum import PRESETS, run_scenario_a, run_scenario_b, run_speed_accuracy, run_stability, train_peers

    preset = PRESETS[preset_name]
    results = run_scenario_a(preset, seed=seed, model_path=out / "pendulum_model.h5")
    figures = report.save_figures(report.pendulum_a_figures(results), out)
    s = results["summary"]
    lines = report.pendulum_a_markdown(s)
    for r in s["per_dt"]:
        print(f"  pendulum dT={r['dt']}: kernel median error {r['kernel_median_err']:.2e} (max {r['kernel_max_err']:.2e}), "
              f"implicit midpoint {r['im_median_err']:.2e} (ratio {r['ratio_median']:.3g})")

    peers = train_peers(results["model"], preset, seed=seed)
    sa = run_speed_accuracy(results["model"], preset, seed=seed, direct=peers["direct"], vkoga=peers["vkoga"])
    sa["time_fit_direct_s"], sa["time_fit_vkoga_s"] = peers["time_fit_direct_s"], peers["time_fit_vkoga_s"]
    sa["vkoga_selection"] = peers["vkoga_selection"]
    figures += report.save_figures(report.speed_accuracy_figure(sa, "pendulum_speed_accuracy", f"Pendulum: speed against accuracy, dT={sa['dt']}"), out)
    lines += report.speed_accuracy_markdown(
        sa, f"Errors against {sa['error_reference']}. Micro-step reference (implicit midpoint, h <= 1e-3): "
        f"{sa['reference_time_s'] * 1e3:.2f} ms per trajectory. The direct model and VKOGA were trained on the same data "
        f"({sa['time_fit_direct_s']:.0f} s and {sa['time_fit_vkoga_s']:.0f} s).")
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
    print(f"  scenario B at l={sb['mu']}: energy drift symplectic {sb['energy_drift_symplectic']:+.1e}, "
          f"direct {sb['energy_drift_direct']:+.1e}")
    return s, figures, lines


def _run_wave(preset_name: str, seed: int, out: Path):
    """Wave MOR pipeline: returns (JSON summary, figure files, Markdown lines)."""
    from sympredict.paper import report
    from sympredict.paper.wave import PRESETS, run_wave

    results = run_wave(PRESETS[preset_name], seed=seed)
    for r in results["per_dt"]:
        r["model"].save(out / f"wave_model_dt{r['dt']}.h5")
    figures = report.save_figures(report.wave_figures(results), out)
    s = results["summary"]
    lines = report.wave_markdown(s)
    for r in s["per_dt"]:
        for c in r["cases"]:
            print(f"  wave dT={r['dt']} c={c['c']:.3f}: kernel {c['mean_kernel_red']:.2e}, implicit midpoint {c['mean_im_red']:.2e} "
                  f"(ratio {c['ratio_red']:.3g})")

    sa = s["speed_accuracy"]
    figures += report.save_figures(report.speed_accuracy_figure(sa, "wave_speed_accuracy", f"Wave: FOM vs ROM vs ROM + kernel, dT={sa['dt']}"), out)
    lines += report.speed_accuracy_markdown(
        sa, "Errors of full-space states against the FOM's exact solution (sine transform); every method starts from the same "
        "full states and returns full states (ROM methods include projection and reconstruction).")
    lines += report.smallest_model_markdown(s)
    z = s["smallest"]
    print(f"  wave smallest model for {z['target']:.0e}: 2n = {2 * z['n_reduced']}, "
          f"{z['n_centers'] if z['reached'] else 'target not reached with all'} centres, validation error {z['validation_error']:.2e}")
    return s, figures, lines


def _run_sine_gordon(preset_name: str, seed: int, out: Path):
    """Sine-Gordon MOR: returns (JSON summary, figure files, Markdown lines)."""
    from sympredict.paper import report
    from sympredict.paper.sine_gordon import PRESETS, run_sine_gordon

    s = run_sine_gordon(PRESETS[preset_name], seed=seed)
    figures = report.save_figures(report.sine_gordon_figures(s), out)
    for d, r in s["dims"].items():
        k = r["kernel_projected"]["error"]
        print(f"  sine-Gordon 2n={d}: Galerkin {statistics.median(r['galerkin_error']):.2e}, DEIM {statistics.median(r['deim_error']):.2e}, "
              f"kernel (FOM data) {'failed' if k is None else format(statistics.median(k), '.2e')}")
    return s, figures, report.sine_gordon_markdown(s)


def _run_henon_heiles(preset_name: str, seed: int, out: Path):
    """Hénon–Heiles speed against accuracy: returns (JSON summary, figure files, Markdown lines)."""
    from sympredict.paper import report
    from sympredict.paper.henon_heiles import PRESETS, run_henon_heiles

    results = run_henon_heiles(PRESETS[preset_name], seed=seed)
    results["model"].save(out / "henon_heiles_model.h5")
    s = results["summary"]
    sa = s["speed_accuracy"]
    figures = report.save_figures(report.speed_accuracy_figure(
        sa, "henon_heiles_speed_accuracy", f"Hénon–Heiles: speed against accuracy, dT={sa['dt']}"), out)
    lines = report.henon_heiles_markdown(s)
    best = min((r for r in sa["rows"] if r["method"] == "kernel predictor"), key=lambda r: r["median_err"])
    print(f"  Hénon–Heiles: kernel m={best['size']} median error {best['median_err']:.2e} in "
          f"{best['time_per_trajectory_s'] * 1e3:.3g} ms per trajectory")
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
        if entry.is_dir(follow_symlinks=False) and is_stale(int(match.group(1)), entry.stat(follow_symlinks=False).st_mtime):
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
    from sympredict.paper import report
    from threadpoolctl import threadpool_limits

    preset_name = args.preset or ("paper" if args.paper else "quick")
    if args.initial == "breather":  # the sine-Gordon breather scenario has its own presets
        breather_presets = {"quick": "breather", "smoke": "smoke-breather"}
        if args.system != "sine-gordon" or preset_name not in breather_presets:
            print("sympredict: --initial breather needs `run sine-gordon` with --quick or --preset smoke", file=sys.stderr)
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
    command = "sympredict " + " ".join(sys.argv[1:] if sys.argv[0].endswith("sympredict") else ["run", args.system, "..."])
    t0 = time.perf_counter()
    print(f"sympredict: {', '.join(systems)}, preset '{preset_name}', {args.threads} BLAS thread(s), output in {out}/", flush=True)
    try:
        results, figures, lines = {}, [], ["# sympredict results", "", f"Command: `{command}`", ""]
        runners = {"pendulum": _run_pendulum, "wave": _run_wave, "sine-gordon": _run_sine_gordon,
                   "henon-heiles": _run_henon_heiles}
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
            json.dump({"command": command, "preset": preset_name, "claims": claims, "results": results, "figures": figures}, f, indent=2)
        (staging / "summary.md").write_text("\n".join(lines) + "\n")
        marker = {"complete": True, "command": command, "preset": preset_name, "systems": list(systems),
                  "files": sorted(p.name for p in staging.iterdir())}
        (staging / RUN_MARKER).write_text(json.dumps(marker, indent=2) + "\n")
        _publish_run(staging, out)
    finally:
        if staging.exists():  # failed or interrupted: nothing half-written survives
            shutil.rmtree(staging, ignore_errors=True)
    print(f"done in {_duration(time.perf_counter() - t0)}; summary: {out / 'summary.md'}")
    return 0


_DEMO_FILES = ("model.h5", "demo.png", "demo.pdf", "demo.json")


def _cmd_demo(args) -> int:
    """The README's example in one command: pendulum trajectories, a model, a rollout, a figure, one line."""
    from threadpoolctl import threadpool_limits

    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {str(out)!r} exists and is not a directory; give a folder")
    if out.is_dir():
        other = sorted(e.name for e in out.iterdir() if e.name not in _DEMO_FILES)
        if other:
            raise ValueError(f"--out {str(out)!r} holds other files than a demo's (e.g. {other[0]!r}); give a new or "
                             "empty folder")
    out.mkdir(parents=True, exist_ok=True)
    from sympredict.paper.demo import HORIZON_STEPS, DT, run_demo

    t0 = time.perf_counter()
    with threadpool_limits(limits=args.threads), _Working("sympredict demo: training on 40 pendulum trajectories", quiet=args.verbose):
        r = run_demo(out, seed=args.seed)
    print(f"demo: {r['n_centers']} centres trained in {r['fit_s']:.0f} s; over t = {HORIZON_STEPS * DT:g} s: max state "
          f"error {r['max_state_error']:.1e}, max relative energy drift {r['max_energy_drift']:.1e}; wrote "
          f"{out / 'model.h5'} and {out / 'demo.png'} ({_duration(time.perf_counter() - t0)})")
    return 0


def _check_output_file(out, *inputs, option: str = "--out", force=None) -> None:
    """Refuse an output file that is a directory or special file, lacks its folder (or write permission there),
    has a name longer than the file system takes, or is one of the inputs; with ``force`` given (the command's
    ``--force``), also an existing file unless it is true."""
    from sympredict.container import check_save_path

    try:
        check_save_path(out, writable=True)
    except ValueError as exc:
        raise ValueError(f"{option}: {exc}") from None
    for given in inputs:
        if given is not None and _same_file(out, given):
            raise ValueError(f"{option} {str(out)!r} is also an input ({str(given)!r}): refusing to overwrite an input")
    if force is False and (os.path.exists(out) or os.path.islink(out)):
        raise ValueError(f"{option} {str(out)!r} exists: pass --force to replace it, or give another name")


def _save_model_or_keep(model, out, overwrite: bool = True) -> None:
    """``model.save(out)``; if that fails after training, save it beside ``out`` (or in the temp folder) and say where.
    ``overwrite=False`` (no ``--force``): a file created at ``out`` meanwhile (another run) is not replaced."""
    try:
        model.save(out) if overwrite else model.save(out, overwrite=False)
        return
    except OSError as exc:
        failure = exc
    import tempfile

    name = f"sympredict-model-{os.getpid()}-{secrets.token_hex(4)}.h5"
    for folder in (Path(out).parent, Path(tempfile.gettempdir())):
        try:
            model.save(folder / name)
        except (OSError, ValueError):
            continue
        raise OSError(failure.errno, f"{failure.strerror or failure}; the trained model was kept in {str(folder / name)!r}: "
                                     f"move it where you want it")
    raise OSError(failure.errno, f"{failure.strerror or failure}; the trained model could not be kept anywhere "
                                 f"(also tried {str(Path(out).parent)!r} and {tempfile.gettempdir()!r})")


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
        x0 = np.vstack([fom.low_frequency_states(1, min(4, n_points), m, fom.reference_energy(m), seed=seed + i)
                        for i, m in enumerate(mu)])
        return fom.trajectory(x0, mu, dt, n_steps), mu
    from sympredict.systems.sine_gordon import SineGordonFOM

    fom = SineGordonFOM(n_points=n_points)
    x0 = np.vstack([fom.energy_bounded_states(1, 1.0, c=c, n_modes=min(8, n_points), seed=seed + i)
                    for i, c in enumerate(mu)])
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
        print(f"wrote {states.shape[0]} {system} trajectories of {args.steps} steps (dt = {dt}, 2n = {states.shape[2]}, "
              f"one parameter each) to {args.out}")
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


def _info(args, line: str) -> None:
    """A line of what the command does: printed with ``--verbose`` only (the default output is the result line)."""
    if getattr(args, "verbose", False):
        print(line, file=sys.stderr)


def _add_verbose(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("-v", "--verbose", action="store_true",
                        help="print what is read and the training log (default: one result line)")


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
        raise ValueError(f"--n-grid {n_grid}: the grid's samples need about {needed / 2**30:.3g} GiB, more than the "
                         f"{available / 2**30:.3g} GiB available; give --n-grid {largest} or less (the paper's is 200)")


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
        return (f"{p} trajectories of {k1} states (2n = {dim}, {d_mu} parameter(s), "
                + (f"dt = {data.dt:.6g}" if data.dt is not None else "non-uniform times") + f"), {p * (k1 - 1)} pairs")
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
    for name, spec in (("state_kernel", args.state_kernel), ("mu_kernel", args.mu_kernel), ("dt_kernel", args.dt_kernel)):
        if spec is not None:
            options[name] = _parse_kernel(spec)
    if args.tol is not None or args.target_error is not None:
        options["trainer"] = ExactGreedy(**({} if args.tol is None else {"tol": args.tol}),
                                         target_error=args.target_error)
    if args.backend != "auto":
        options["solver"] = NewtonSolver(backend=args.backend)
    model = SymplecticKernelPredictor(**options)
    with threadpool_limits(limits=args.threads), _Working(f"sympredict train: {_describe(data)}, training", quiet=args.verbose):
        model.fit(data, validation=validation)
    _save_model_or_keep(model, args.out, overwrite=args.force)
    h = model.history_
    print(f"trained {model.n_centers_} centres ({h.stop_reason}) on {_describe(data)}: E_train {h.train_max_residual[-1]:.2e}"
          + (f", E_val {h.val_max_residual[-1]:.2e}" if h.val_max_residual is not None else "")
          + f"; saved to {args.out}")
    _print_target(model)
    return 0


def _print_target(model) -> None:
    """With ``--target-error``: the held-out error against the target (the fit also warns when it is missed)."""
    d = getattr(model, "diagnostics_", None)
    if d is not None and d.target_error is not None:
        print(f"target error {d.target_error:.2e}: {'met' if d.target_met else 'NOT met'} "
              f"(median one-step error {d.holdout_step_error:.2e} on held-out samples, {model.n_centers_} centres)")


def _refuse_wrong_train_options(args) -> None:
    """``train --dt/--mu/--state``: say which option was meant (``--dt`` is the step on ``predict``, a kernel here)."""
    if args.wrong_dt is not None:
        raise ValueError("train has no --dt: the sampling step is read from the data file ('dt' or 'times'); "
                         "the step kernel is --dt-kernel FAMILY:EPS (e.g. --dt-kernel imq:5.0)")
    if args.wrong_mu is not None:
        raise ValueError("train has no --mu: the parameters are read from the data file ('mu'); "
                         "the parameter kernel is --mu-kernel FAMILY:EPS (e.g. --mu-kernel imq:2.0) or 'none'")
    if args.wrong_state is not None:
        raise ValueError("train has no --state: the state kernel is --state-kernel FAMILY:EPS (e.g. --state-kernel imq:0.15)")


class _Working:
    """One line on a terminal while a long call runs (``what ...``), erased when it ends; nothing when piped."""

    def __init__(self, what: str, stream=None, quiet: bool = False):
        self.stream = stream or sys.stderr
        # not with --verbose (``quiet``): the log's lines would run into it
        self.enabled = bool(getattr(self.stream, "isatty", lambda: False)()) and not quiet
        self.what = what

    def __enter__(self):
        if self.enabled:
            self.stream.write(f"{self.what} ...")
            self.stream.flush()
        return self

    def __exit__(self, *exc):
        if self.enabled:
            self.stream.write("\r\033[K")
            self.stream.flush()
        return False


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
    kernels = [_parse_kernel(k if k is not None else default) for k, default in
               ((args.state_kernel, "imq:0.15"), (args.mu_kernel, "imq:2.0"), (args.dt_kernel, "imq:5.0"))]
    model = SymplecticKernelPredictor(*kernels, max_centers=args.centers or 1500,
                                      trainer=ExactGreedy(tol=1e-10 if args.tol is None else args.tol,
                                                          target_error=args.target_error),
                                      solver=NewtonSolver(backend=args.backend))
    mu = data.mu if kernels[1] is not None else None
    if validation is not None and kernels[1] is None:
        validation = (validation.x0, validation.x1, None, validation.dt)
    with threadpool_limits(limits=args.threads), _Working(f"sympredict train: {_describe(data)}, training", quiet=args.verbose):
        model.fit(data.x0, data.x1, mu=mu, dt=data.dt, validation=validation)
    _save_model_or_keep(model, args.out, overwrite=args.force)
    h = model.history_
    print(f"trained {model.n_centers_} centres ({h.stop_reason}) on {len(data)} samples of {meta.get('system', 'unknown system')}: "
          f"E_train {h.train_max_residual[-1]:.2e}" + (f", E_val {h.val_max_residual[-1]:.2e}" if h.val_max_residual is not None else "")
          + f"; saved to {args.out}")
    _print_target(model)
    return 0


class _Progress:
    """``step k/K (p %), elapsed, left`` on one line of stderr, redrawn at most twice a second, from 1 s on.

    Only on a terminal: piped or redirected output gets no progress lines.
    """

    def __init__(self, what: str, stream=None):
        self.what, self.stream = what, stream or sys.stderr
        self.enabled = bool(getattr(self.stream, "isatty", lambda: False)())
        self.start = self.last = time.perf_counter()
        self.shown = False

    def __call__(self, done: int, total: int) -> None:
        now = time.perf_counter()
        if not self.enabled or now - self.start < 1.0 or (now - self.last < 0.5 and done < total):
            return
        self.last, elapsed = now, now - self.start
        left = elapsed * (total - done) / done if done else float("inf")
        self.stream.write(f"\r{self.what}: step {done:,}/{total:,} ({100 * done / total:.1f} %), "
                          f"{_duration(elapsed)} elapsed, about {_duration(left)} left   ")
        self.stream.flush()
        self.shown = True

    def close(self) -> None:
        if self.shown:
            self.stream.write("\n")
            self.stream.flush()


def _duration(seconds: float) -> str:
    if not math.isfinite(seconds):
        return "?"
    if seconds < 60:
        return f"{seconds:.0f} s"
    if seconds < 3600:
        return f"{seconds // 60:.0f} min {seconds % 60:02.0f} s"
    return f"{seconds // 3600:.0f} h {seconds % 3600 // 60:02.0f} min"


def _set_backend(model, backend: str):
    """The Newton backend of a loaded model (the inner predictor's for a split model; none for the direct model)."""
    from sympredict.estimators.predictor import newton_predictor

    inner = newton_predictor(model)
    if inner is not None:
        inner.set_params(solver__backend=backend)
    return model


def _parse_numbers(text: str, option: str):
    """``"1.0,0.5"`` -> array; an error naming the option and the bad entry."""
    import numpy as np

    values = []
    for i, part in enumerate(text.split(","), start=1):
        try:
            value = float(part)
        except ValueError:
            raise ValueError(f"{option} takes comma-separated numbers, e.g. {option} 1.0,0.0; entry {i} of {text!r} "
                             f"is {part.strip()!r}") from None
        if not math.isfinite(value):
            raise ValueError(f"{option}: entry {i} of {text!r} is not finite")
        values.append(value)
    return np.array(values)


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
            raise ValueError(f"--x0 has {x0.shape[1]} numbers per state; the model's states have 2n = {model.dim_} "
                             "(q1,...,qn,p1,...,pn)")
    if mu is not None and mu.ndim == 1 and getattr(model, "n_mu_", 1) > 1 and len(mu) == model.n_mu_:
        mu = mu[None]  # one parameter vector for every state
    # without --out only the final states are printed: keep the first and last state (memory O(batch))
    stride = args.stride if args.out else max(1, args.steps)
    progress = _Progress("predict")
    if args.check and not isinstance(model, SymplecticKernelPredictor):
        raise ValueError(f"--check estimates dT * L_S of a SymplecticKernelPredictor; {args.model!r} holds a "
                         f"{type(model).__name__}: leave out --check")
    kwargs = {"check_solvability": True} if args.check else {}
    if args.error:
        if not isinstance(model, SymplecticKernelPredictor):
            raise ValueError(f"--error estimates the error of a SymplecticKernelPredictor's prediction; {args.model!r} "
                             f"holds a {type(model).__name__}: leave out --error")
        kwargs["return_error"] = True
    error = None
    try:
        traj = model.rollout(x0, args.steps, mu=mu, dt=args.dt, stride=stride, progress=progress, **kwargs)
        if args.error:
            traj, error = traj
    except RolloutMemoryError as exc:
        raise ValueError(f"--steps {args.steps} with --stride {stride}: {exc.needed / 2**30:.3g} GiB of states, more than "
                         f"the {exc.available / 2**30:.3g} GiB available; keep fewer states with a larger --stride") from None
    finally:
        progress.close()
    if args.out:
        from sympredict.data import TrajectoryData
        from sympredict.io.trajectories import write_trajectories

        step = args.dt if args.dt is not None else getattr(newton_predictor(model) or model, "dt_fixed_", None)
        kept = np.arange(traj.shape[1]) * stride
        times = kept * step if step is not None else kept.astype(float)
        mu_out = None if mu is None else np.broadcast_to(np.asarray(mu, dtype=float).reshape(len(mu), -1)
                                                         if np.ndim(mu) else np.full((1, 1), float(mu)),
                                                         (traj.shape[0], max(1, model.n_mu_)))
        write_trajectories(TrajectoryData(traj, mu_out, times=times), args.out, overwrite=bool(args.force),
                           extra=None if error is None else {"error": error})
        print(f"wrote {traj.shape[0]} trajectories of {args.steps} steps"
              + (f" (one state every {stride} steps)" if stride > 1 else "") + f" to {args.out}"
              + ("" if step is not None else " (t counts steps: the model takes dt per query)"))
    else:
        for b in range(traj.shape[0]):
            print(f"instance {b}: x({args.steps} steps) = {', '.join(f'{v:.12g}' for v in traj[b, -1])}"
                  + ("" if error is None else f"  (estimated error {error[b, -1]:.2e})"))
    return 0


def _cmd_report(args) -> int:
    from sympredict import SymplecticKernelPredictor
    from sympredict.io.formats import check_model_file

    check_model_file(args.model)
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


def _number_list(text: str) -> str:
    """An argparse type: comma-separated finite numbers, kept as text (parsed by :func:`_parse_numbers`)."""
    try:
        _parse_numbers(text, "")
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated finite numbers, got {text!r}") from None
    return text


def _add_backend_and_force(parser: argparse.ArgumentParser, solver: str) -> None:
    """``--backend`` (``solver``: what it sets) and ``--force`` (replace an existing ``--out``) of train and predict."""
    parser.add_argument("--backend", choices=["auto", "numpy", "numba"], default="auto",
                        help=f"{solver}: NumPy or compiled (numba); 'auto' (default) picks by the size of the work")
    parser.add_argument("--force", action="store_true", help="replace an existing --out file")


def build_parser() -> argparse.ArgumentParser:
    from sympredict._version import __version__

    parser = _Parser(prog="sympredict", description="Symplectic large-step kernel predictors for Hamiltonian systems.")
    parser.add_argument("--version", action="version", version=f"sympredict {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="train, evaluate and write figures and a summary")
    run.add_argument("system", choices=[*SYSTEMS, "sine-gordon", "all"],
                     help="the scenario to run ('all': pendulum and wave; sine-Gordon runs alone)")
    run.add_argument("--out", required=True, help="output folder (created if missing)")
    size = run.add_mutually_exclusive_group()
    size.add_argument("--quick", action="store_true", help="small data (default): minutes on 2 cores (measured times: docs/data/runtimes.json)")
    size.add_argument("--paper", action="store_true", help="the paper's data sizes: minutes, ~10 GiB")
    size.add_argument("--preset", choices=["smoke", "quick", "paper"], help="a preset by name ('smoke': seconds, for testing)")
    run.add_argument("--initial", choices=["sech_cos", "breather"], default="sech_cos",
                     help="sine-Gordon only: initial-data family ('breather': the breather presets, --quick or --preset smoke)")
    run.add_argument("--seed", type=_int_at_least(0), default=0, help="seed of the validation and test draws (default 0)")
    run.add_argument("--threads", type=_int_at_least(1), default=os.cpu_count() or 1, help="BLAS threads (default: all cores)")
    _add_verbose(run)
    run.set_defaults(func=_cmd_run)

    demo = sub.add_parser("demo", help="the README's example: train on pendulum trajectories, predict, write a model, "
                                       "a figure and a one-line result (seconds on 2 cores)")
    demo.add_argument("--out", default="sympredict-demo", help="output folder (default: sympredict-demo)")
    demo.add_argument("--seed", type=_int_at_least(0), default=0, help="seed of the training trajectories (default 0)")
    demo.add_argument("--threads", type=_int_at_least(1), default=os.cpu_count() or 1, help="BLAS threads (default: all cores)")
    _add_verbose(demo)
    demo.set_defaults(func=_cmd_demo)

    data = sub.add_parser("data", help="write a data set of a shipped system that 'sympredict train' reads")
    data.add_argument("--system", choices=["pendulum", *DATA_SYSTEMS], default="pendulum",
                      help="pendulum (default): flow-map samples (HDF5); the others: reference trajectories "
                           "(.npz, .h5 or .csv by the --out suffix) with one parameter each")
    data.add_argument("--out", required=True, help="data file (.h5 for the pendulum; .npz, .h5 or .csv otherwise)")
    data.add_argument("--n-grid", type=_int_at_least(2), default=50, help="pendulum: energy-bounded grid points per axis (default 50; paper 200)")
    data.add_argument("--p-nonpositive", action="store_true", help="pendulum: keep only states with p <= 0 (scenario B)")
    data.add_argument("--random", type=_int_at_least(1), metavar="N", help="pendulum: N >= 1 random samples instead of the grid (validation data)")
    data.add_argument("--trajectories", type=_int_at_least(1), default=20, metavar="P",
                      help="other systems: number of trajectories (default 20), parameters drawn uniformly from the system's range")
    data.add_argument("--steps", type=_int_at_least(1), default=20, metavar="K", help="other systems: macro steps per trajectory (default 20)")
    data.add_argument("--dt", type=_finite_float(positive=True), help="other systems: macro step (default 0.1)")
    data.add_argument("--n-points", type=_int_at_least(3), default=16, metavar="N",
                      help="wave and sine-gordon: interior grid points, states of dimension 2N (default 16)")
    data.add_argument("--seed", type=_int_at_least(0), default=0)
    data.add_argument("--force", action="store_true", help="replace an existing --out file")
    _add_verbose(data)
    data.set_defaults(func=_cmd_data)

    train = sub.add_parser("train", help="train a symplectic predictor on a data set or the user's trajectories and save it (HDF5)")
    train.add_argument("data", help="a data set written by 'sympredict data' or sympredict.io.save_dataset, or trajectories "
                                    "or pairs in a .npz, .h5 or .csv file (layout: sympredict.io.read_trajectories)")
    train.add_argument("--out", required=True, help="model file (.h5)")
    train.add_argument("--validation", help="validation data, same kinds of file (records E_val)")
    train.add_argument("--state-kernel", metavar="FAMILY:EPS",
                       help="state kernel, e.g. imq:0.15 (default: imq:0.15 for a sympredict data set, chosen on "
                            "held-out samples otherwise)")
    train.add_argument("--mu-kernel", metavar="FAMILY:EPS",
                       help="parameter kernel or 'none' (default: imq:2.0 for a sympredict data set, chosen otherwise)")
    train.add_argument("--dt-kernel", metavar="FAMILY:EPS",
                       help="step kernel or 'none' (default: imq:5.0 for a sympredict data set, chosen otherwise)")
    # --dt, --mu and --state are no options of train (the step and parameters come from the file): named so that
    # they are refused with the right option instead of being taken as abbreviations of the kernel options
    for wrong in ("--dt", "--mu", "--state"):
        train.add_argument(wrong, dest=f"wrong_{wrong[2:]}", help=argparse.SUPPRESS)
    train.add_argument("--max-centers", "--centers", dest="centers", type=_int_at_least(1),
                       help="maximal number of centres (default: 1500 for a sympredict data set, the estimator's default otherwise)")
    train.add_argument("--tol", type=_finite_float(nonnegative=True), help="greedy residual tolerance (default 1e-10)")
    train.add_argument("--target-error", type=_finite_float(positive=True),
                       help="grow the model until the median relative one-step error on held-out samples is at "
                            "most this (e.g. 1e-4), then stop: the smallest model that meets it (--max-centers "
                            "stays the cap)")
    train.add_argument("--threads", type=_int_at_least(1), default=os.cpu_count() or 1)
    _add_verbose(train)
    _add_backend_and_force(train, "the saved model's Newton solver")
    train.set_defaults(func=_cmd_train)

    predict = sub.add_parser("predict", help="roll a saved model out from given initial states")
    predict.add_argument("model", help="model file")
    states = predict.add_mutually_exclusive_group(required=True)
    states.add_argument("--x0", nargs="+", help="initial states, each comma-separated (q1,...,qn,p1,...,pn)")
    states.add_argument("--x0-file", help="initial states from a .npz (key x0 (B, 2n), optional mu) or .csv "
                                          "(columns q1..qn, p1..pn, optional mu or mu1..mud) file")
    predict.add_argument("--mu", type=_number_list, help="parameter, comma-separated for several components")
    predict.add_argument("--dt", type=_finite_float(positive=True), help="macro step (default: the training step of a fixed-step model)")
    predict.add_argument("--steps", type=_int_at_least(0), required=True, help="number of macro steps")
    predict.add_argument("--check", action="store_true", help="refuse to start where dT * L_S >= 1")
    predict.add_argument("--error", action="store_true",
                         help="also estimate |x_predicted - x_exact| at every state written (an extra column or key "
                              "'error'; see the how-to 'How accurate is my prediction?')")
    predict.add_argument("--out", help="trajectories file, .npz or .csv (the layout sympredict.io.read_trajectories "
                                       "reads; default: print the final states)")
    predict.add_argument("--stride", type=_int_at_least(1), default=1,
                         help="with --out, write every k-th state only (default 1: all); memory is that of the states written")
    _add_backend_and_force(predict, "Newton solver")
    _add_verbose(predict)
    predict.set_defaults(func=_cmd_predict)

    describe = sub.add_parser("report", help="describe a saved model: kernel, centres, residuals, training box")
    describe.add_argument("model", help="model file")
    describe.set_defaults(func=_cmd_report)
    return parser


def _use_color(stream) -> bool:
    """Colour only on a terminal, and never with ``NO_COLOR`` set (https://no-color.org)."""
    return bool(getattr(stream, "isatty", lambda: False)()) and not os.environ.get("NO_COLOR")


def _plain_log_output() -> None:
    """pyMOR's log formatter colours by the terminal type, not by where the output goes: decide here."""
    import logging

    from pymor.core.logger import ColoredFormatter

    color = _use_color(sys.stderr)
    loggers = [logging.getLogger()] + [lg for lg in logging.Logger.manager.loggerDict.values() if isinstance(lg, logging.Logger)]
    for lg in loggers:
        for handler in lg.handlers:
            if isinstance(handler.formatter, ColoredFormatter):
                handler.formatter.use_color = color


def _one_line_warning(message, category, filename, lineno, line=None) -> str:
    """A warning as one line: ``sympredict: warning: Category: message`` (no source line, no path)."""
    return f"sympredict: warning: {category.__name__}: {' '.join(str(message).split())}\n"


def main(argv=None) -> int:
    """Entry point; user errors end with one line on stderr and exit code 1, never a traceback."""
    import warnings

    from pymor.core.logger import set_log_levels

    from sympredict.exceptions import SympredictError

    args = build_parser().parse_args(argv)
    # quiet by default: the result line, warnings and errors; --verbose (where a command has it) adds the log
    set_log_levels({"sympredict": "INFO" if getattr(args, "verbose", False) else "WARN", "pymor": "WARN"})
    _plain_log_output()
    formatwarning = warnings.formatwarning
    warnings.formatwarning = _one_line_warning
    try:
        return args.func(args)
    except (ValueError, SympredictError, OSError) as exc:
        message = " ".join(str(exc).split()) or type(exc).__name__
        print(f"sympredict: error: {message}", file=sys.stderr)
        return 1
    except KeyboardInterrupt as exc:
        print("sympredict: interrupted" + (f": {exc}" if str(exc) else ""), file=sys.stderr)
        return 130
    finally:
        warnings.formatwarning = formatwarning  # main() may be called from Python (tests): leave it as found


if __name__ == "__main__":
    sys.exit(main())
