"""Cold start of a fresh process: ``import`` + ``load`` + the first ``rollout``, per backend.

Fits a 200-centre pendulum model once (scenario A data, IMQ kernels) and
saves it, then launches fresh Python processes that each import sympredict,
load the model and time its first rollout (20 trajectories x 100 macro steps).
numba's on-disk cache is pointed at a fresh folder (``NUMBA_CACHE_DIR``) for
the whole run, so the numba backend's first process compiles everything and
the ``--repeats`` processes after it show what every later process on the
machine pays.  The NumPy backend needs no compilation: its first rollout is the
floor a compiled first rollout is compared with.

Reported per backend: the first process (``first_*``) and the medians over the
later processes (``import_s``, ``load_s``, ``first_rollout_s``, ``total_s``);
``numba_cached_rollout_over_numpy_s`` is the later numba processes' first
rollout minus NumPy's (target: at most 1 s).

The command line, in the same cache: ``sympredict predict`` of ``--cli-steps``
(400) steps of one state per backend (wall time of the whole command, median
of ``--repeats`` fresh processes), and how long a 10^9-step ``predict`` takes
to exit after SIGINT (``interrupt_s``; it is sent once the process has run for
``--interrupt-after`` seconds, and its peak resident memory is recorded).

The children get ``--threads`` numba and ``--blas-threads`` BLAS/OpenMP threads
through their environment; medians and the JSON record follow
``sympredict_paper/studies/_protocol.py`` (the first process of a backend is its warm-up).

Run:  python sympredict_paper/studies/cold_start.py [--repeats 3] [--threads 1] [--json out.json]
"""

import argparse
import json
import os
import platform
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from sympredict.interpolation.greedy import ExactGreedy
from sympredict.symplectic.solvers import NewtonSolver

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _protocol  # noqa: E402  (sympredict_paper/studies/_protocol.py)

#: What each fresh process runs: times import, load and the first rollout; prints one JSON line.
CHILD = r"""
import json, sys, time
t0 = time.perf_counter()
import numpy as np
from sympredict import SymplecticKernelPredictor
t1 = time.perf_counter()
model = SymplecticKernelPredictor.load(sys.argv[1])
model.set_params(solver__backend=sys.argv[2])
x0 = np.load(sys.argv[3])
t2 = time.perf_counter()
traj = model.rollout(x0, int(sys.argv[4]), mu=float(sys.argv[5]), dt=float(sys.argv[6]))
t3 = time.perf_counter()
assert np.isfinite(traj).all()
print(json.dumps({"import_s": t1 - t0, "load_s": t2 - t1, "first_rollout_s": t3 - t2, "total_s": t3 - t0}))
"""


def fit_model(path: Path, centers: int) -> None:
    """The pendulum model of the benchmark (``centers`` centres), saved to ``path``."""
    from sympredict import SymplecticKernelPredictor
    from sympredict.kernels import IMQ
    from sympredict.systems.pendulum import Pendulum, flow_map_data

    d = flow_map_data(Pendulum(), n_grid=20)
    model = SymplecticKernelPredictor(
        IMQ(0.15),
        mu_kernel=IMQ(2.0),
        dt_kernel=IMQ(5.0),
        max_centers=centers,
        trainer=ExactGreedy(tol=1e-12),
        solver=NewtonSolver(backend="numpy"),
    )
    model.fit(d.x0, d.x1, mu=d.mu, dt=d.dt)
    model.save(path)
    return model, d


def run_child(args: list, env: dict) -> dict:
    out = subprocess.run([sys.executable, "-c", CHILD, *args], env=env, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def _predict_command(model: Path, steps: int, backend: str, x0, mu: float, dt: float) -> list:
    return [
        sys.executable,
        "-m",
        "sympredict.cli",
        "predict",
        str(model),
        "--x0",
        ",".join(repr(float(v)) for v in x0),
        "--mu",
        repr(mu),
        "--dt",
        repr(dt),
        "--steps",
        str(steps),
        "--backend",
        backend,
    ]


def time_cli(command: list, env: dict) -> float:
    """Wall time of one fresh ``sympredict`` process, start to exit."""
    t0 = time.perf_counter()
    subprocess.run(command, env=env, capture_output=True, text=True, check=True)
    return time.perf_counter() - t0


def time_interrupt(command: list, env: dict, after: float) -> dict:
    """Seconds from SIGINT to the exit of a running ``sympredict predict``, its exit code and peak memory (MiB)."""
    proc = subprocess.Popen(
        command,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    time.sleep(after)
    if proc.poll() is not None:
        raise RuntimeError(f"predict ended before the interrupt: {proc.communicate()}")
    peak = _peak_rss_mib(proc.pid)  # after `after` seconds of stepping: memory does not grow with the steps
    t0 = time.perf_counter()
    proc.send_signal(signal.SIGINT)
    proc.communicate(timeout=120)
    return {"interrupt_s": time.perf_counter() - t0, "returncode": proc.returncode, "peak_rss_mib": peak}


def _peak_rss_mib(pid: int):
    """A running process's peak resident memory (Linux ``VmHWM``), MiB; ``None`` where unknown."""
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--centers", type=int, default=200)
    parser.add_argument("--trajectories", type=int, default=20)
    parser.add_argument("--steps", type=int, default=100)
    _protocol.add_arguments(
        parser,
        threads=1,
        threads_help="numba threads of the child processes",
        repeats=3,
        repeats_help="fresh processes per backend after the first",
    )
    parser.add_argument("--cli-steps", type=int, default=400, help="steps of the timed `sympredict predict`")
    parser.add_argument(
        "--interrupt-after", type=float, default=5.0, help="seconds before SIGINT to a 10^9-step predict"
    )
    args = parser.parse_args(argv)

    with tempfile.TemporaryDirectory() as tmp, _protocol.limits(args.blas_threads):
        tmp = Path(tmp)
        model, d = fit_model(tmp / "model.h5", args.centers)
        rng = np.random.default_rng(0)
        x0 = d.x0[rng.choice(len(d.x0), args.trajectories, replace=False)]
        np.save(tmp / "x0.npy", x0)
        mu, dt = float(d.mu[0, 0]), float(d.dt[0])
        env = dict(
            os.environ,
            NUMBA_CACHE_DIR=str(tmp / "numba_cache"),
            NUMBA_NUM_THREADS=str(args.threads),
            OPENBLAS_NUM_THREADS=str(args.blas_threads),
            OMP_NUM_THREADS=str(args.blas_threads),
        )
        child_args = [str(tmp / "model.h5"), None, str(tmp / "x0.npy"), str(args.steps), repr(mu), repr(dt)]
        result = {
            "centers": int(len(model.surrogate_.centers_xi)),
            "trajectories": args.trajectories,
            "steps": args.steps,
            "repeats": args.repeats,
            "threads": args.threads,
            "python": platform.python_version(),
            "machine": f"{os.cpu_count()} CPUs, {platform.processor() or platform.machine()}, {platform.platform()}",
            "backends": {},
        }
        for backend in ("numpy", "numba", "auto"):  # 'auto', the default, after numba has filled the cache
            child_args[1] = backend
            first = run_child(child_args, env)  # numba: compiles and fills the fresh cache
            later = [run_child(child_args, env) for _ in range(args.repeats)]
            row = {f"first_{k}": v for k, v in first.items()}
            row.update({k: _protocol.summary([r[k] for r in later])["median_s"] for k in first})
            row["runs"] = later
            result["backends"][backend] = row
        result["cli"] = {}
        for backend in ("auto", "numpy", "numba"):
            command = _predict_command(tmp / "model.h5", args.cli_steps, backend, x0[0], mu, dt)
            times = [time_cli(command, env) for _ in range(args.repeats)]
            stops = [
                time_interrupt(
                    _predict_command(tmp / "model.h5", 10**9, backend, x0[0], mu, dt), env, args.interrupt_after
                )
                for _ in range(args.repeats)
            ]
            result["cli"][backend] = {
                "predict_s": _protocol.summary(times)["median_s"],
                "predict_runs_s": times,
                "interrupt_s": _protocol.summary([r["interrupt_s"] for r in stops])["median_s"],
                "interrupt_runs": stops,
            }
        cache = tmp / "numba_cache"
        result["cache_files"] = sum(1 for p in cache.rglob("*") if p.is_file()) if cache.exists() else 0
        protocol = _protocol.record_options(
            args,
            repeats=args.repeats,
            warmup=1,
            notes="fresh child processes; the first per backend compiles (its own keys)",
        )
    result = {"command": protocol["command"], **result}  # the docs print command and machine under their tables
    b = result["backends"]
    result["numba_cached_rollout_over_numpy_s"] = b["numba"]["first_rollout_s"] - b["numpy"]["first_rollout_s"]
    for name, row in b.items():
        print(
            f"{name:6s} first process: rollout {row['first_first_rollout_s']:.3f} s, total {row['first_total_s']:.3f} s; "
            f"later (median of {args.repeats}): import {row['import_s']:.3f} s, load {row['load_s']:.3f} s, "
            f"rollout {row['first_rollout_s']:.3f} s, total {row['total_s']:.3f} s"
        )
    print(
        f"numba cache files: {result['cache_files']}; later numba rollout - numpy rollout: "
        f"{result['numba_cached_rollout_over_numpy_s']:.3f} s"
    )
    for name, row in result["cli"].items():
        print(
            f"sympredict predict --backend {name}: {args.cli_steps} steps in {row['predict_s']:.2f} s (median); "
            f"10^9 steps stop {row['interrupt_s']:.2f} s after SIGINT (exit codes "
            f"{sorted({r['returncode'] for r in row['interrupt_runs']})})"
        )
    if args.json:
        _protocol.write_json(args.json, result, protocol)
    return result


if __name__ == "__main__":
    main()
