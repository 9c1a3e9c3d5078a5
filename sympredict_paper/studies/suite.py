"""Performance suite: training against the bandwidth bound, rollout throughput and latency, scaling, wave pipeline.

One command (not part of the test run):

    python sympredict_paper/studies/suite.py --out benchmarks/results              # ~5 minutes on 2 cores
    python sympredict_paper/studies/suite.py --scenario-a --out benchmarks/results # + full scenario A, exact and fast (~6 min more, 9 GiB)

Writes ``<out>/suite.json`` (every number, and the protocol record: command line,
revision, threads, machine), ``<out>/suite.md`` (a short table)
and, with ``scaling``, ``docs/figures/performance_scaling.png`` (``--figure``).
Every timing is measured in this process (or, for peak memory, in a spawned
child per training run) by the protocol of ``sympredict_paper/studies/_protocol.py``, with the
thread settings stated in the output: BLAS threads through threadpoolctl
(``--blas-threads``, default 1), numba threads through ``numba.set_num_threads``
(``--threads``, default all cores).  Ratios are taken side by side in one
process; repeated timings are medians after a warm-up call.

Sections (``--sections``, comma separated; default all but ``scenario_a``):

``greedy``
    Exact f-greedy on a mid-size pendulum set: time per centre against the
    time of the matrix-vector product ``basis[:k].T @ v`` over the same Newton
    basis (the memory-bandwidth lower bound: every step must stream
    ``basis[:m]`` once), sampled at ``k`` across the run; the float32 basis
    against float64 (time, residual checked by direct evaluation).
``rollout``
    A 1500-centre pendulum model: trajectory-steps per second for a batch of
    1000, latency of one trajectory (per step inside a rollout, and per
    ``step()`` call), compiled (numba) against the NumPy reference, and their
    agreement.
``scaling``
    Costs against centres ``m``, candidates ``N``, batch size and state
    dimension ``2n``, with fitted log-log exponents.
``wave``
    The MOR pipeline (``sympredict_paper.wave``, quick preset, 2n = 4,
    dT = 0.1): basis, data, kernel selection, training, online step, each
    timed, with the accuracy of each stage's product.
``scenario_a``
    Full pendulum scenario A (688,464 functionals): exact f-greedy (1500
    centres, with the in-run bandwidth ratio over its own 8 GB basis) and the
    fast active-set path (``trainer=ActiveSetGreedy()``, ``tol=1e-5``), wall time, peak
    memory, max residual over all functionals, trajectory errors (paper protocol).
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from pymor.core.logger import set_log_levels  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _protocol  # noqa: E402  (sympredict_paper/studies/_protocol.py)

from sympredict import SymplecticKernelPredictor  # noqa: E402
from sympredict import _numba  # noqa: E402
from sympredict.interpolation import _compiled as compiled_surrogate  # noqa: E402
from sympredict.symplectic import _compiled_newton  # noqa: E402
from sympredict.data import mixed_variables  # noqa: E402
from sympredict.estimators.fitted import FittedSymplecticFlowMap, training_box  # noqa: E402
from sympredict.interpolation.functionals import HBFunctionals, functional_residuals  # noqa: E402
from sympredict.interpolation.greedy import GreedyHistory, active_set_greedy, greedy_interpolation  # noqa: E402
from sympredict.kernels import IMQ, ProductKernel  # noqa: E402
from sympredict.symplectic.metrics import relative_trajectory_error  # noqa: E402
from sympredict.interpolation.surrogate import HBSurrogate  # noqa: E402
from sympredict.systems.pendulum import DT_TEST, Pendulum, flow_map_data  # noqa: E402

#: The issue's kernel for scenario A (IMQ shapes of state, length, step).
EPS_A = (0.15, 2.0, 5.0)
SECTIONS = ("greedy", "rollout", "scaling", "wave", "scenario_a")


# --------------------------------------------------------------------------- helpers
def median_time(fn, repeats: int = 3, warmup: int = 1) -> float:
    """Median wall time of ``repeats`` calls of ``fn`` after ``warmup`` untimed ones (seconds; :func:`_protocol.measure`)."""
    return _protocol.measure(fn, repeats, warmup)["median_s"]


def touch_memory(nbytes: float) -> float:
    """Allocate, write once and free ``nbytes``; returns the seconds it took.

    On this project's VM, memory the guest has never used costs ~13 ms per
    5.5 MB on first write (the host backs it then), 20x the cost of memory used
    before.  Training runs are timed after this warm-up so that the ratio to the
    matrix-vector bound measures the algorithm; the warm-up's time is reported.
    """
    t0 = time.perf_counter()
    a = np.empty(int(nbytes) // 8)
    step = 1 << 20
    for i in range(0, a.size, step):
        a[i : i + step] = 0.0
    del a
    return time.perf_counter() - t0


def peak_rss() -> int:
    """This process's peak resident memory in bytes (``VmHWM``: unlike ``ru_maxrss``, not inherited from the parent)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def fit_exponent(x, y) -> float:
    """Slope of ``log y`` against ``log x`` (least squares)."""
    return float(np.polyfit(np.log(np.asarray(x, float)), np.log(np.asarray(y, float)), 1)[0])


def pendulum_functionals(n_grid: int, eps=EPS_A):
    data = flow_map_data(Pendulum(), n_grid=n_grid)
    xi, y = mixed_variables(data.x0, data.x1, data.dt)
    kernel = ProductKernel(IMQ(eps[0]), IMQ(eps[1]), IMQ(eps[2]))
    return data, HBFunctionals(kernel, xi, data.mu, data.dt), y.reshape(-1)


def model_from_greedy(data, functionals: HBFunctionals, result, eps=EPS_A) -> SymplecticKernelPredictor:
    """A fitted predictor from a greedy result on ``functionals`` (what ``fit`` does after its greedy)."""
    model = SymplecticKernelPredictor(IMQ(eps[0]), IMQ(eps[1]), IMQ(eps[2]), max_centers=len(result.selected))
    points, comps = np.divmod(result.selected, functionals.dim)
    k = functionals.kernel
    surrogate = HBSurrogate(
        k, functionals.points[points], functionals.mu[points], functionals.dt[points], comps, result.coef
    )
    model.model_ = FittedSymplecticFlowMap(
        k, surrogate, domain=training_box(data), history=result.history, greedy_result=result, update="symplectic_euler"
    )
    model.fitted_params_ = model.get_params(deep=False)
    return model


def paper_protocol_errors(model, seed: int = 0, horizon: float = 20.0) -> list:
    """Scenario A test protocol: 5 x 5 random ``q0`` and lengths, relative error over time per test step."""
    from sympredict_paper.pendulum import paper_test_instances

    system = Pendulum()
    x0, lengths = paper_test_instances(seed)
    rows = []
    for dt in DT_TEST:
        n_steps = int(np.floor(horizon / dt + 1e-9))
        ref = system.trajectory(x0, lengths, dt, n_steps)
        pred = model.rollout(x0, n_steps, mu=lengths, dt=dt)
        err = relative_trajectory_error(pred, ref).mean(axis=0)[1:]
        rows.append({"dt": dt, "median_err": float(np.median(err)), "max_err": float(err.max())})
    return rows


def environment(blas_threads: int) -> dict:
    """The machine (:func:`_protocol.machine_info`) with the requested BLAS threads (``blas_threads_requested``)."""
    env = _protocol.machine_info()
    env["blas_threads_requested"] = blas_threads
    return env


# --------------------------------------------------------------------------- greedy
def bandwidth_ratio(history: GreedyHistory, basis: np.ndarray, n_samples: int = 10, repeats: int = 3) -> dict:
    """Time per centre against the matrix-vector product over the same basis, sampled across the run.

    For sampled ``k``, the greedy's step time (median of the steps ``k-4..k+4``)
    is compared with the median time of ``basis[:k].T @ v`` on the basis the run
    produced; the overall ratio is total greedy time over the sum of the
    product's time interpolated (linear in ``k``) to every step.
    """
    steps = np.diff(np.concatenate([[0.0], history.elapsed]))
    m = len(steps)
    ks = np.unique(np.linspace(max(2, m // 20), m - 1, n_samples).astype(int))
    rows = []
    rng = np.random.default_rng(0)
    for k in ks:
        v = rng.standard_normal(k).astype(basis.dtype)
        t_mv = median_time(lambda: basis[:k].T @ v, repeats)
        t_step = float(np.median(steps[max(0, k - 4) : k + 5]))
        rows.append(
            {
                "k": int(k),
                "step_s": t_step,
                "matvec_s": t_mv,
                "ratio": t_step / t_mv,
                "matvec_GBps": k * basis.shape[1] * basis.itemsize / t_mv / 1e9,
            }
        )
    # lower bound of the whole run: the product's time at every step (linear fit in k through the samples)
    kk = np.array([r["k"] for r in rows], float)
    tt = np.array([r["matvec_s"] for r in rows])
    slope, icpt = np.polyfit(kk, tt, 1)
    bound = float(np.sum(np.maximum(icpt + slope * np.arange(m), 0.0)))
    total = float(history.elapsed[-1])
    return {
        "samples": rows,
        "total_s": total,
        "matvec_bound_s": bound,
        "ratio_total": total / bound,
        "ratio_median_samples": float(np.median([r["ratio"] for r in rows])),
    }


def section_greedy(n_grid: int, centers: int, n_grid_f32: int, centers_f32: int) -> dict:
    data, fun, y = pendulum_functionals(n_grid)
    out = {"n_functionals": fun.n_functionals, "centers": centers, "kernel": list(EPS_A)}
    greedy_interpolation(fun, y, max_centers=3, tol=0.0, log_every=0)  # load the compiled kernels (not timed)
    out["first_touch_s"] = touch_memory(8 * centers * fun.n_functionals * 1.3)
    t0 = time.perf_counter()
    res = greedy_interpolation(fun, y, max_centers=centers, tol=0.0, keep_basis=True, log_every=0)
    out["time_s"] = time.perf_counter() - t0
    out["E_train"] = float(res.history.train_max_residual[-1])
    out["bandwidth"] = bandwidth_ratio(res.history, res.basis)
    del res
    # float32 basis vs float64 on a smaller set: time and the residual of the model actually returned
    data, fun, y = pendulum_functionals(n_grid_f32)
    f32 = {"n_functionals": fun.n_functionals, "centers": centers_f32}
    for dtype in ("float64", "float32"):
        t0 = time.perf_counter()
        r = greedy_interpolation(fun, y, max_centers=centers_f32, tol=0.0, basis_dtype=dtype, log_every=0)
        f32[dtype] = {
            "time_s": time.perf_counter() - t0,
            "n_centers": len(r.selected),
            "stop_reason": r.history.stop_reason,
            "E_train_tracked": float(r.history.train_max_residual[-1]),
            "E_train_direct": float(np.abs(functional_residuals(fun, y, r.selected, r.coef)).max()),
        }
    out["float32_vs_float64"] = f32
    return out


# --------------------------------------------------------------------------- rollout
def pendulum_model(n_grid: int = 50, centers: int = 1500):
    data, fun, y = pendulum_functionals(n_grid)
    t0 = time.perf_counter()
    res = greedy_interpolation(fun, y, max_centers=centers, tol=0.0, log_every=0)
    return model_from_greedy(data, fun, res), time.perf_counter() - t0


def _rollout_inputs(batch: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    x0 = np.column_stack([rng.uniform(0.0, np.pi / 2, batch), np.zeros(batch)])
    return x0, rng.uniform(0.7, 0.8, batch), rng.uniform(0.045, 0.055, batch)


def section_rollout(model, batch: int = 1000, steps_fast: int = 100, steps_numpy: int = 10, repeats: int = 5) -> dict:
    x0, mu, dt = _rollout_inputs(batch)
    out = {"n_centers": model.n_centers_, "batch": batch}
    for backend, steps in (("numba", steps_fast), ("numpy", steps_numpy)):
        if backend == "numba" and not _numba.HAVE_NUMBA:
            out[backend] = None
            continue
        model.set_params(solver__backend=backend)
        model.rollout(x0[:16], 2, mu=mu[:16], dt=dt[:16])  # compile / warm up
        model.rollout(x0[0], 2, mu=mu[0], dt=dt[0])
        t = median_time(lambda: model.rollout(x0, steps, mu=mu, dt=dt), repeats)
        k_lat = 4 * steps_fast if backend == "numba" else 40
        t_lat = median_time(lambda: model.rollout(x0[0], k_lat, mu=mu[0], dt=dt[0]), repeats)
        t_step = median_time(lambda: model.step(x0[0], mu=mu[0], dt=dt[0]), 50)
        out[backend] = {
            "steps": steps,
            "traj_steps_per_s": batch * steps / t,
            "latency_ms_per_step_in_rollout": 1e3 * t_lat / k_lat,
            "latency_ms_per_step_call": 1e3 * t_step,
        }
    # agreement: compiled vs NumPy reference on the same batch, and the reference against itself
    k = 20
    sub = slice(0, 200)
    model.set_params(solver__backend="numpy")
    ref = model.rollout(x0[sub], k, mu=mu[sub], dt=dt[sub])
    single = np.stack([model.rollout(x0[i], k, mu=mu[i], dt=dt[i]) for i in range(20)])
    out["numpy_batch_vs_single_max_diff"] = float(np.abs(single - ref[:20]).max())
    if _numba.HAVE_NUMBA:
        model.set_params(solver__backend="numba")
        fast = model.rollout(x0[sub], k, mu=mu[sub], dt=dt[sub])
        out["numba_vs_numpy_max_diff"] = float(np.abs(fast - ref).max())
        out["speedup_batch"] = out["numba"]["traj_steps_per_s"] / out["numpy"]["traj_steps_per_s"]
    sur = model.surrogate_
    if _numba.HAVE_NUMBA:
        # compute bound: passes over the centres per step, time per centre visit against the
        # kernel-factor loop alone (one division, two square roots per centre).  Both timed as the
        # minimum of short samples (10 instances x 20 steps; the factor loop on one chunk in L1),
        # alternating, so that other processes on the machine can only stretch samples that do not count.
        w = sur.weights(mu[:, None], dt)
        sub = slice(0, 10)
        layout = sur.layout()
        cases = {
            "cold": {},
            "warm": {"warm_start": True},
            "midpoint_cold": {"update": "midpoint"},
            "midpoint_warm": {"update": "midpoint", "warm_start": True},
        }
        passes = {}
        for key, kw in cases.items():
            stats = {}
            _compiled_newton.newton_rollout(
                x0[sub], w[sub], dt[sub], layout, sur.kernel.state, 50, 20, parallel=False, stats=stats, **kw
            )
            passes[key] = float(stats["passes"].sum())
        factor_samples = []  # the factor probe times itself; it runs interleaved with the passes
        runs = {
            key: (
                lambda kw=kw: _compiled_newton.newton_rollout(
                    x0[sub], w[sub], dt[sub], layout, sur.kernel.state, 50, 20, parallel=False, **kw
                )
            )
            for key, kw in cases.items()
        }
        runs["factor"] = lambda: factor_samples.append(
            compiled_surrogate.factor_throughput(n=1 << 18, repeats=1, in_cache=True)
        )
        timed = _protocol.side_by_side(runs, repeats=30, warmup=0, statistic="min_s")["methods"]
        t1 = {key: timed[key]["min_s"] for key in cases}
        t_factor = min(factor_samples)
        cb = {}
        for key in cases:
            ns_visit = 1e9 * t1[key] / (passes[key] * sur.n_centers)
            cb[key] = {
                "passes_per_step": passes[key] / (10 * 20),
                "ns_per_centre_visit_1_thread": ns_visit,
                "ratio": ns_visit / (1e9 * t_factor),
            }
        out["compute_bound"] = {
            **cb["cold"],
            "ns_per_factor_evaluation_1_thread": 1e9 * t_factor,
            "ns_per_factor_evaluation_1M_median": 1e9 * compiled_surrogate.factor_throughput(),
            "warm": cb["warm"],
            # the midpoint solver's pass (full Hessian, 2n unknowns) on the same centres: its cost, not its accuracy
            # (the model was trained for the symplectic-Euler update)
            "midpoint_cost": {"cold": cb["midpoint_cold"], "warm": cb["midpoint_warm"]},
        }
        # throughput of the batch with the warm start (newton_warm_start=True)
        model.set_params(solver__backend="numba")
        model.set_params(solver__warm_start=True)
        model.rollout(x0[:16], 3, mu=mu[:16], dt=dt[:16])
        t = median_time(lambda: model.rollout(x0, steps_fast, mu=mu, dt=dt), repeats)
        out["numba"]["traj_steps_per_s_warm_start"] = batch * steps_fast / t
        model.set_params(solver__warm_start=False)
    _, _, floor = sur.gradient_hessian(x0[sub], sur.weights(mu[sub, None], dt[sub]), with_floor=True)
    out["gradient_roundoff_floor"] = float(floor.max())
    out["max_abs_coef"] = float(np.abs(sur.coef).max())
    model.set_params(solver__backend="auto")
    return out


# --------------------------------------------------------------------------- scaling
def synthetic_surrogate(m: int, dim: int, seed: int = 0) -> HBSurrogate:
    rng = np.random.default_rng(seed)
    kernel = ProductKernel(IMQ(0.5), IMQ(1.0), None)
    return HBSurrogate(
        kernel,
        rng.uniform(-1, 1, (m, dim)),
        rng.uniform(0, 1, (m, 1)),
        np.ones(m),
        rng.integers(0, dim, m),
        rng.standard_normal(m) * 1e-3,
    )


def section_scaling(model, repeats: int = 3) -> dict:
    out = {}
    # rollout cost vs centres (prefixes of one greedy run) and vs batch, compiled path
    x0, mu, dt = _rollout_inputs(1000)
    if _numba.HAVE_NUMBA:
        ms = [100, 200, 400, 800, 1500]
        t_m = []
        for m in ms:
            small = model.truncated(m)
            small.set_params(solver__backend="numba")
            small.rollout(x0[:16], 1, mu=mu[:16], dt=dt[:16])
            t_m.append(median_time(lambda: small.rollout(x0[:500], 20, mu=mu[:500], dt=dt[:500]), repeats) / (500 * 20))
        out["rollout_vs_centers"] = {"m": ms, "s_per_traj_step": t_m, "exponent": fit_exponent(ms, t_m)}
        bs = [1, 10, 100, 1000]
        t_b = []
        model.set_params(solver__backend="numba")
        for b in bs:
            k = max(20, 2000 // b)
            t_b.append(median_time(lambda: model.rollout(x0[:b], k, mu=mu[:b], dt=dt[:b]), repeats) / (b * k))
        out["rollout_vs_batch"] = {
            "batch": bs,
            "s_per_traj_step": t_b,
            "exponent_total_time": fit_exponent(bs, np.array(t_b) * bs),
        }
        model.set_params(solver__backend="auto")
        # Newton-iteration work vs state dimension: one gradient+Hessian-block pass per point
        # (synthetic surrogates, m = 1500, coefficients 1e-3: Newton converges in the same few
        # iterations at every dimension, so the step time follows the per-iteration work)
        dims = [2, 4, 10, 20, 40]
        t_d, t_s, t_dn = [], [], []
        for dim in dims:
            sur = synthetic_surrogate(1500, dim)
            lay = sur.layout()
            pts = np.random.default_rng(1).uniform(-1, 1, (400, dim))
            w = sur.weights(np.full((1, 1), 0.5), np.ones(1))
            grp = np.zeros(len(pts), dtype=np.int64)
            compiled_surrogate.gradients(pts[:10], grp[:10], w, lay, IMQ(0.5))
            t_d.append(
                median_time(lambda: compiled_surrogate.gradients(pts, grp, w, lay, IMQ(0.5)), repeats) / len(pts)
            )
            wb = np.ascontiguousarray(np.repeat(w, len(pts), axis=0))
            h = np.full(len(pts), 0.01)
            run = lambda: _compiled_newton.newton_rollout(pts, wb, h, lay, IMQ(0.5), 50, 5)  # noqa: E731
            run()
            t_s.append(median_time(run, repeats) / (len(pts) * 5))
            t_dn.append(median_time(lambda: sur.newton_terms(pts[:200], wb[:200]), repeats) / 200)
        out["newton_vs_dim"] = {
            "dim": dims,
            "numba_implicit_step_s": t_s,
            "numba_gradient_s_per_point": t_d,
            "numpy_newton_terms_s_per_point": t_dn,
            "exponent_numba_step": fit_exponent(dims, t_s),
            "exponent_numba_gradient": fit_exponent(dims, t_d),
            "exponent_numpy_newton_terms": fit_exponent(dims, t_dn),
        }
    # greedy step cost vs N (fixed m) and vs m (one run)
    ns, t_n = [], []
    for n_grid in (40, 60, 90, 130):
        data, fun, y = pendulum_functionals(n_grid)
        res = greedy_interpolation(fun, y, max_centers=300, tol=0.0, log_every=0)
        steps = np.diff(np.concatenate([[0.0], res.history.elapsed]))
        ns.append(fun.n_functionals)
        t_n.append(float(np.median(steps[250:300])))
    out["greedy_step_vs_N"] = {"N": ns, "m": 300, "s_per_step": t_n, "exponent": fit_exponent(ns, t_n)}
    ms = np.array([50, 100, 200, 400, 600, 800])
    t_ms = [float(np.median(steps[max(0, m - 5) : m + 5])) for m in ms[ms < len(steps)]]
    if len(t_ms) < len(ms):  # the last run above has 300 steps; a longer one for the m-dependence
        res = greedy_interpolation(fun, y, max_centers=int(ms.max()) + 5, tol=0.0, log_every=0)
        steps = np.diff(np.concatenate([[0.0], res.history.elapsed]))
        t_ms = [float(np.median(steps[m - 5 : m + 5])) for m in ms]
    out["greedy_step_vs_m"] = {"N": ns[-1], "m": ms.tolist(), "s_per_step": t_ms, "exponent": fit_exponent(ms, t_ms)}
    return out


#: the scaling figure's panels, in order: (key of the ``scaling`` section, measured only where numba is installed,
#: title (formatted with the section's entries), x label, x entry, {legend: y entry}, y label)
SCALING_PANELS = [
    (
        "rollout_vs_centers",
        True,
        "rollout against centres",
        "centres $m$",
        "m",
        {"numba rollout": "s_per_traj_step"},
        "time per trajectory-step [s]",
    ),
    (
        "rollout_vs_batch",
        True,
        "rollout against batch size",
        "batch size $B$ [trajectories]",
        "batch",
        {"numba rollout": "s_per_traj_step"},
        "time per trajectory-step [s]",
    ),
    (
        "newton_vs_dim",
        True,
        "Newton terms against $2n$ ($m$ = 1500)",
        "state dimension $2n$",
        "dim",
        {
            "numba implicit step": "numba_implicit_step_s",
            "numba gradient": "numba_gradient_s_per_point",
            "NumPy grad + Hessian block": "numpy_newton_terms_s_per_point",
        },
        "time per state [s]",
    ),
    (
        "greedy_step_vs_N",
        False,
        "greedy step against candidates ($m$ = {m})",
        "candidates $N$ [functionals]",
        "N",
        {"greedy step": "s_per_step"},
        "time per greedy step [s]",
    ),
    (
        "greedy_step_vs_m",
        False,
        "greedy step against centres ($N$ = {N:,})",
        "centres $m$",
        "m",
        {"greedy step": "s_per_step"},
        "time per greedy step [s]",
    ),
]


def draw_scaling(scaling: dict):
    """The scaling figure of a ``scaling`` section: one log-log panel per measurement, two rows of three.

    Each panel has a title saying what is measured, axis labels with units and its
    fitted slopes in the legend; sized to stay readable at the page width of the docs.
    Returns the matplotlib Figure.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    panels = [
        (title.format(**r), xlabel, r[x], {label: r[y] for label, y in curves.items()}, ylabel)
        for key, compiled, title, xlabel, x, curves, ylabel in SCALING_PANELS
        if not compiled or key in scaling
        for r in [scaling[key]]
    ]
    ncols = min(3, len(panels))
    nrows = -(-len(panels) // ncols)
    with plt.rc_context(
        {
            "font.size": 10,
            "axes.titlesize": 10,
            "axes.labelsize": 10,
            "legend.fontsize": 8.5,
            "xtick.labelsize": 9,
            "ytick.labelsize": 9,
        }
    ):
        fig, axes = plt.subplots(
            nrows, ncols, figsize=(3.3 * ncols, 3.1 * nrows), constrained_layout=True, squeeze=False
        )
        for ax, (title, xlabel, x, curves, ylabel) in zip(axes.flat, panels):
            for label, yv in curves.items():
                e = fit_exponent(x, yv)
                ax.loglog(x, yv, "o-", ms=4, label=f"{label}, slope {e:.2f}")
            ax.set_title(title)
            ax.set_xlabel(xlabel)
            ax.set_ylabel(ylabel)
            ax.grid(True, which="major", alpha=0.3)
            # a tick label only where it does not run into the previous one (log spacing >= 1.6x)
            ticks = [x[0]]
            for v in x[1:]:
                if v >= 1.6 * ticks[-1]:
                    ticks.append(v)
            ax.set_xticks(ticks)
            ax.set_xticklabels([f"{v:g}" if v < 1e4 else f"{v / 1e3:.0f}k" for v in ticks])
            ax.xaxis.set_minor_locator(matplotlib.ticker.NullLocator())
            ax.legend(loc="upper left")
        for ax in list(axes.flat)[len(panels) :]:
            ax.set_visible(False)
    return fig


def scaling_figure(scaling: dict, path: Path) -> None:
    """Draw :func:`draw_scaling` into ``path`` (PNG)."""
    import matplotlib.pyplot as plt

    fig = draw_scaling(scaling)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=130)
    plt.close(fig)


# --------------------------------------------------------------------------- wave
def section_wave(seed: int = 0, basis_blas_threads: int = 1) -> dict:
    from sympredict_paper.wave import PRESETS, build_rom, train_wave_predictor

    preset = PRESETS["quick"]
    dt = 0.1
    t0 = time.perf_counter()
    # the dense complex SVD of the snapshot matrix: one BLAS thread (measured 2-3x faster than
    # two on this 2-core machine when anything else runs; DESIGN.md's oversubscription pitfall)
    with _protocol.limits(basis_blas_threads):
        fom, rom, energy, info = build_rom(preset, seed)
    t_rom = time.perf_counter() - t0
    trained = train_wave_predictor(rom, preset, dt, energy, seed=seed)
    model = trained["model"]
    rng = np.random.default_rng(seed + 1000)
    c = float(rng.uniform(0.2, 0.3))
    x0 = rom.system.sample_energy_ellipsoid(20, c**2, energy, seed=seed + 2000)
    n_steps = int(np.floor(preset.horizon / dt + 1e-9))
    ref = rom.system.trajectory(x0, c**2, dt, n_steps)
    out = {
        "N_fom": preset.n_points,
        "dim_reduced": rom.dim,
        "basis": {
            "time_s": t_rom,
            "time_snapshots_s": info["time_snapshots_s"],
            "time_basis_s": info["time_basis_s"],
            "symplecticity": info["symplecticity"],
            "blas_threads": basis_blas_threads,
        },
        "data": {"time_s": trained["time_data_s"], "n_samples": trained["n_samples"]},
        "selection": {
            "time_s": trained["time_selection_s"],
            "E_val_m_star": trained["selection"].score,
            "kernel": [repr(trained["selection"].state), repr(trained["selection"].mu)],
        },
        "training": {
            "time_s": trained["time_fit_s"],
            "n_centers": model.n_centers_,
            "E_train": float(model.history_.train_max_residual[-1]),
            "E_val": float(model.history_.val_max_residual[-1]),
        },
        "online": {"dt": dt, "n_steps": n_steps, "batch": len(x0)},
    }
    for backend in ("numba", "numpy"):
        if backend == "numba" and not _numba.HAVE_NUMBA:
            continue
        model.set_params(solver__backend=backend)
        model.rollout(x0[:2], 1, mu=c**2)
        t = median_time(lambda: model.rollout(x0, n_steps, mu=c**2), 3)
        pred = model.rollout(x0, n_steps, mu=c**2)
        t1 = median_time(lambda: model.step(x0[0], mu=c**2), 20)
        out["online"][backend] = {
            "s_per_step_batch": t / n_steps,
            "ms_per_step_single_call": 1e3 * t1,
            "mean_rel_err": float(relative_trajectory_error(pred, ref)[:, 1:].mean()),
        }
    t_fom = median_time(lambda: fom.trajectory(rom.reconstruct(x0), c**2, dt, n_steps), 1, warmup=0)
    out["online"]["fom_reference_s_per_step_batch"] = t_fom / n_steps
    return out


# --------------------------------------------------------------------------- scenario A (child processes)
def _scenario_a_child(kind: str, out_path: str, threads: int, n_grid: int = 200) -> None:
    set_log_levels({"sympredict": "INFO"})
    with _protocol.limits(threads):
        t0 = time.perf_counter()
        data, fun, y = pendulum_functionals(n_grid)
        t_data = time.perf_counter() - t0
        rss_data = peak_rss()
        greedy_interpolation(fun, y, max_centers=3, tol=0.0, log_every=0)  # load the compiled kernels (not timed)
        if kind == "fast":
            functional_residuals(fun, y, np.array([0, 1]), np.ones(2))
        t0 = time.perf_counter()
        if kind == "exact":
            res = greedy_interpolation(fun, y, max_centers=1500, tol=1e-10, keep_basis=True)
        else:
            res = active_set_greedy(fun, y, max_centers=2000, tol=1e-5)
        t_train = time.perf_counter() - t0
        peak = peak_rss()
        out = {
            "kind": kind,
            "n_functionals": fun.n_functionals,
            "time_data_s": t_data,
            "time_train_s": t_train,
            "peak_rss_bytes": peak,
            "peak_rss_after_data_bytes": rss_data,
            "n_centers": len(res.selected),
            "stop_reason": res.history.stop_reason,
            "E_train_tracked": float(res.history.train_max_residual[-1]),
        }
        if kind == "exact":
            out["bandwidth"] = bandwidth_ratio(res.history, res.basis, n_samples=8, repeats=3)
            res.basis = None
        t0 = time.perf_counter()
        out["E_train_direct"] = float(np.abs(functional_residuals(fun, y, res.selected, res.coef)).max())
        out["time_residual_check_s"] = time.perf_counter() - t0
        model = model_from_greedy(data, fun, res)
        out["trajectory_errors"] = paper_protocol_errors(model)
    Path(out_path).write_text(json.dumps(out))


def section_scenario_a(threads: int, n_grid: int = 200) -> dict:
    ctx = mp.get_context("spawn")
    out = {}
    n_functionals = 2 * len(flow_map_data(Pendulum(), n_grid=n_grid).x0)
    for kind in ("fast", "exact"):
        # warm the memory in this process (freed again before the child starts; the child's
        # peak RSS is its own): the VM's first-touch cost is reported, not mixed into training
        warm_bytes = 1.15 * 8 * 1500 * n_functionals if kind == "exact" else 2**30
        t_touch = touch_memory(warm_bytes)
        with tempfile.TemporaryDirectory() as tmp:
            path = os.path.join(tmp, "out.json")
            proc = ctx.Process(target=_scenario_a_child, args=(kind, path, threads, n_grid))
            t0 = time.perf_counter()
            proc.start()
            proc.join()
            if proc.exitcode != 0:
                out[kind] = {"error": f"child exited with {proc.exitcode}"}
                continue
            out[kind] = json.loads(Path(path).read_text())
            out[kind]["wall_child_s"] = time.perf_counter() - t0
            out[kind]["first_touch_s"] = t_touch
            out[kind]["first_touch_bytes"] = warm_bytes
    if "trajectory_errors" in out.get("fast", {}) and "trajectory_errors" in out.get("exact", {}):
        out["error_ratio_fast_over_exact"] = [
            f["median_err"] / e["median_err"]
            for f, e in zip(out["fast"]["trajectory_errors"], out["exact"]["trajectory_errors"])
        ]
    return out


# --------------------------------------------------------------------------- report
def markdown(results: dict) -> str:
    env = results["environment"]
    lines = ["# sympredict performance suite", ""]
    nb = env.get("numba") or {}
    pools = ", ".join(f"{p.get('internal_api')}: {p.get('num_threads')}" for p in env["threadpools"])
    lines.append(
        f"{env['cpus']} CPUs, {env['platform']}, NumPy {env['numpy']}; BLAS threads {env['blas_threads_requested']} "
        f"({pools}); numba {nb.get('version', 'absent')} with {nb.get('threads', 0)} threads "
        f"({nb.get('threading_layer')}). Started {results['started']}, finished {results.get('finished')}."
    )
    lines.append("")
    lines.append("| measurement | value | accuracy |")
    lines.append("|---|---|---|")
    g = results.get("greedy")
    if g:
        b = g["bandwidth"]
        lines.append(
            f"| exact f-greedy, N = {g['n_functionals']}, {g['centers']} centres | {g['time_s']:.1f} s; "
            f"{b['ratio_total']:.2f}x the in-run matvec bound ({b['matvec_bound_s']:.1f} s; memory warmed first: "
            f"{g['first_touch_s']:.1f} s) | E_train {g['E_train']:.2e} |"
        )
        f = g["float32_vs_float64"]
        for dtype in ("float64", "float32"):
            r = f[dtype]
            lines.append(
                f"| greedy {dtype} basis, N = {f['n_functionals']}, {r['n_centers']} centres ({r['stop_reason']}) | "
                f"{r['time_s']:.1f} s | E_train direct {r['E_train_direct']:.2e} |"
            )
    r = results.get("rollout")
    if r:
        for backend in ("numba", "numpy"):
            if r.get(backend):
                x = r[backend]
                warm = (
                    f" ({x['traj_steps_per_s_warm_start']:,.0f} with newton_warm_start)"
                    if "traj_steps_per_s_warm_start" in x
                    else ""
                )
                lines.append(
                    f"| rollout {backend}, batch {r['batch']}, {r['n_centers']} centres | "
                    f"{x['traj_steps_per_s']:,.0f} traj-steps/s{warm} | |"
                )
                lines.append(
                    f"| latency {backend}, 1 trajectory | {x['latency_ms_per_step_in_rollout']:.3f} ms/step in a rollout, "
                    f"{x['latency_ms_per_step_call']:.3f} ms per step() call | |"
                )
        if "compute_bound" in r:
            c = r["compute_bound"]
            lines.append(
                f"| compiled Newton pass, 1 thread | {c['ns_per_centre_visit_1_thread']:.2f} ns per centre visit "
                f"({c['passes_per_step']:.2f} passes per step); {c['ratio']:.1f}x the kernel-factor loop alone "
                f"({c['ns_per_factor_evaluation_1_thread']:.2f} ns in L1) | |"
            )
            if "warm" in c:
                wm = c["warm"]
                lines.append(
                    f"| compiled Newton pass, warm start | {wm['ns_per_centre_visit_1_thread']:.2f} ns per centre visit "
                    f"({wm['passes_per_step']:.2f} passes per step); {wm['ratio']:.1f}x the factor loop | |"
                )
                mc = c["midpoint_cost"]["warm"]
                lines.append(
                    f"| compiled midpoint pass (full Hessian), warm start | {mc['ns_per_centre_visit_1_thread']:.2f} ns "
                    f"per centre visit ({mc['passes_per_step']:.2f} passes per step) | cost only (same centres) |"
                )
        if "numba_vs_numpy_max_diff" in r:
            lines.append(
                f"| numba vs NumPy trajectories (200 x 20 steps) | max diff {r['numba_vs_numpy_max_diff']:.1e} | "
                f"NumPy batch vs single {r['numpy_batch_vs_single_max_diff']:.1e}, gradient floor {r['gradient_roundoff_floor']:.1e} |"
            )
    s = results.get("scaling")
    if s:
        if "rollout_vs_centers" in s:
            lines.append(f"| rollout cost vs m | exponent {s['rollout_vs_centers']['exponent']:.2f} | |")
            lines.append(
                f"| rollout total time vs batch | exponent {s['rollout_vs_batch']['exponent_total_time']:.2f} | |"
            )
            d = s["newton_vs_dim"]
            lines.append(
                f"| cost vs 2n (2 .. 40, m = 1500) | numba implicit step {d['exponent_numba_step']:.2f}, "
                f"numba gradient {d['exponent_numba_gradient']:.2f}, "
                f"NumPy grad+Hessian block {d['exponent_numpy_newton_terms']:.2f} | |"
            )
        lines.append(
            f"| greedy step vs N (m = {s['greedy_step_vs_N']['m']}) | exponent {s['greedy_step_vs_N']['exponent']:.2f} | |"
        )
        lines.append(f"| greedy step vs m | exponent {s['greedy_step_vs_m']['exponent']:.2f} | |")
    w = results.get("wave")
    if w:
        lines.append(
            f"| wave basis (N = {w['N_fom']}, 2n = {w['dim_reduced']}, {w['basis']['blas_threads']} BLAS thread) | "
            f"{w['basis']['time_s']:.2f} s (SVD {w['basis']['time_basis_s']:.2f} s) | "
            f"symplecticity {w['basis']['symplecticity']:.1e} |"
        )
        lines.append(f"| wave data ({w['data']['n_samples']} samples) | {w['data']['time_s']:.2f} s | |")
        lines.append(
            f"| wave kernel selection | {w['selection']['time_s']:.1f} s | E_val(m*) {w['selection']['E_val_m_star']:.1e} |"
        )
        lines.append(
            f"| wave training ({w['training']['n_centers']} centres) | {w['training']['time_s']:.1f} s | "
            f"E_train {w['training']['E_train']:.1e}, E_val {w['training']['E_val']:.1e} |"
        )
        for backend in ("numba", "numpy"):
            if backend in w["online"]:
                o = w["online"][backend]
                lines.append(
                    f"| wave online step ({backend}, batch {w['online']['batch']}) | {1e3 * o['s_per_step_batch']:.3f} ms/step, "
                    f"{o['ms_per_step_single_call']:.3f} ms per single step() | mean rel. error {o['mean_rel_err']:.1e} |"
                )
        lines.append(
            f"| wave FOM reference (batch {w['online']['batch']}) | {1e3 * w['online']['fom_reference_s_per_step_batch']:.2f} ms/step | |"
        )
    a = results.get("scenario_a")
    if a:
        for kind in ("exact", "fast"):
            x = a.get(kind, {})
            if "time_train_s" not in x:
                continue
            errs = ", ".join(f"{e['median_err']:.1e}" for e in x["trajectory_errors"])
            extra = ""
            if "bandwidth" in x:
                extra = (
                    f"; {x['bandwidth']['ratio_total']:.2f}x the in-run matvec bound "
                    f"(memory warmed first: {x['first_touch_s']:.1f} s for {x['first_touch_bytes'] / 2**30:.1f} GiB)"
                )
            lines.append(
                f"| scenario A {kind} (N = {x['n_functionals']}) | {x['time_train_s']:.1f} s, {x['n_centers']} centres, "
                f"peak {x['peak_rss_bytes'] / 2**30:.2f} GiB{extra} | max residual (direct) {x['E_train_direct']:.2e}; "
                f"median traj. errors {errs} |"
            )
    lines.append("")
    return "\n".join(lines)


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sections", default=",".join(SECTIONS[:-1]), help=f"comma separated subset of {SECTIONS}")
    parser.add_argument("--scenario-a", action="store_true", help="add the full scenario A section (minutes, ~9 GiB)")
    _protocol.add_arguments(parser, threads=os.cpu_count(), json_option=False)
    parser.add_argument(
        "--greedy-grid", type=int, default=100, help="pendulum grid of the greedy section (N ~ 17 grid^2)"
    )
    parser.add_argument("--greedy-centers", type=int, default=600)
    parser.add_argument(
        "--scenario-a-grid", type=int, default=200, help="grid of scenario A (200: the paper's 688,464 functionals)"
    )
    parser.add_argument("--wave-basis-threads", type=int, default=1, help="BLAS threads of the wave basis SVD")
    parser.add_argument("--out", default="benchmarks/results")
    parser.add_argument("--figure", default="docs/figures/performance_scaling.png")
    args = parser.parse_args(argv)
    sections = [s for s in args.sections.split(",") if s]
    if args.scenario_a and "scenario_a" not in sections:
        sections.append("scenario_a")
    unknown = set(sections) - set(SECTIONS)
    if unknown:
        parser.error(f"unknown sections {sorted(unknown)}; choose from {SECTIONS}")
    set_log_levels({"sympredict": "WARNING", "pymor": "WARN"})
    numba_threads = min(args.threads, os.cpu_count())
    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    results = {"started": time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime()), "argv": sys.argv[1:]}
    with _protocol.limits(args.blas_threads, numba_threads=numba_threads):
        results["environment"] = environment(args.blas_threads)
        model = None
        if "greedy" in sections:
            print("greedy ...", flush=True)
            results["greedy"] = section_greedy(args.greedy_grid, args.greedy_centers, 50, 600)
        if "rollout" in sections or "scaling" in sections:
            print("pendulum model (quick data, 1500 centres) ...", flush=True)
            model, t_fit = pendulum_model()
            results["model_fit_s"] = t_fit
        if "rollout" in sections:
            print("rollout ...", flush=True)
            results["rollout"] = section_rollout(model)
        if "scaling" in sections:
            print("scaling ...", flush=True)
            results["scaling"] = section_scaling(model)
            if args.figure:
                scaling_figure(results["scaling"], Path(args.figure))
        if "wave" in sections:
            print("wave ...", flush=True)
            results["wave"] = section_wave(basis_blas_threads=args.wave_basis_threads)
        results["environment"] = environment(args.blas_threads)  # numba's threading layer is known now
        protocol = _protocol.record(
            blas_threads=args.blas_threads,
            numba_threads=numba_threads,
            repeats=None,
            warmup=1,
            notes="repeats per measurement as stated next to it; scenario A in spawned children",
        )
    if "scenario_a" in sections:
        print("scenario A (children) ...", flush=True)
        results["scenario_a"] = section_scenario_a(args.blas_threads, args.scenario_a_grid)
    results["finished"] = time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime())
    _protocol.write_json(out_dir / "suite.json", results, protocol, indent=2)
    table = markdown(results)
    (out_dir / "suite.md").write_text(table)
    print(table)
    return results


if __name__ == "__main__":
    main()
