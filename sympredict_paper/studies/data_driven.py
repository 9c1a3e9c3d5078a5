"""Data-driven comparison (issue 13, docs/explanation/data_driven.md): the same flow-map samples given to every model.

Cases: pendulum at a fixed step (dT = 0.05, l in [0.7, 0.8]), pendulum over (l, dT) (scenario A's data),
Hénon–Heiles (lambda in [0.8, 1.0], dT = 0.5).  Models: the symplectic kernel predictor, the direct kernel
model (same kernel and budget), pyMOR's VKOGA (length scale chosen on validation data) and, when PyTorch is
installed (``pip install 'sympredict[bench]'``), a residual MLP and a parameter-conditioned G-SympNet
(sympredict_paper/studies/neural_peers.py).  Per model: training time, online time per trajectory (one warm-up, median of 3,
one thread: sympredict_paper/studies/_protocol.py, whose record the JSON carries), median / max over time of the mean relative trajectory error over the test horizon, and the
largest relative energy error over a long horizon (10x the test horizon).

    python sympredict_paper/studies/data_driven.py --out data_driven.json [--cases pendulum_fixed,pendulum_full,henon_heiles]
                                     [--neural-epochs 60] [--neural-only]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from pymor.core.logger import set_log_levels

import _protocol  # sympredict_paper/studies/ (the script's folder is on sys.path)

from sympredict import DirectKernelPredictor, SymplecticKernelPredictor
from sympredict_paper.henon_heiles import DT_HH, PRESETS as HH_PRESETS, henon_heiles_data, henon_heiles_test_instances
from sympredict_paper.pendulum import paper_test_instances
from sympredict_paper.peers import VKOGAFlowMap, select_vkoga_length_scale
from sympredict.symplectic.integrators_compiled import rollout
from sympredict.kernels import IMQ
from sympredict.symplectic.metrics import relative_hamiltonian_error, relative_trajectory_error
from sympredict.systems.henon_heiles import LAMBDA_RANGE, HenonHeiles, energy_bounded_states
from sympredict.data import FlowMapData
from sympredict.systems.pendulum import DT_TEST, MU_TRAIN, Pendulum, flow_map_data, random_flow_map_data
from sympredict.interpolation.greedy import ExactGreedy

try:
    from neural_peers import GSympNet, MLPFlowMap
except ImportError:  # no torch
    GSympNet = MLPFlowMap = None


#: per case: the test step and horizon, the reference flow's substeps, the kernels (state, parameter, step; the
#: Henon-Heiles one chosen on validation by ``sympredict-paper run henon-heiles --quick``), the centres and whether
#: the step is an input of the models
CASES = {
    "pendulum_fixed": dict(
        dt=0.05, horizon=20.0, substeps=128, kernels=(IMQ(0.2), IMQ(1.5), None), centers=1000, with_dt=False
    ),
    "pendulum_full": dict(
        dt=DT_TEST[0], horizon=20.0, substeps=128, kernels=(IMQ(0.2), IMQ(1.5), IMQ(3.0)), centers=1000, with_dt=True
    ),
    "henon_heiles": dict(
        dt=DT_HH, horizon=50.0, substeps=256, kernels=(IMQ(0.5), IMQ(1.0), None), centers=500, with_dt=False
    ),
}


def _case(name):
    if name not in CASES:
        raise ValueError(f"unknown case {name!r}: choose from {', '.join(CASES)}")
    if name == "pendulum_fixed":
        system = Pendulum()
        data = flow_map_data(system, MU_TRAIN, (0.05,), n_grid=50)
        val = random_flow_map_data(system, 1000, seed=2, dt_values=(0.05,))
        x0, mu = paper_test_instances(0)
    elif name == "pendulum_full":
        system = Pendulum()
        data = flow_map_data(system, n_grid=50)
        val = random_flow_map_data(system, 1000, seed=2)
        x0, mu = paper_test_instances(0)
    else:
        system = HenonHeiles()
        p = HH_PRESETS["quick"]
        data = henon_heiles_data(system, np.linspace(*LAMBDA_RANGE, p.n_lambda), p.n_per_lambda, p.energy_max)
        rng = np.random.default_rng(1)
        lv = rng.uniform(*LAMBDA_RANGE, 1000)
        vx0 = np.concatenate(
            [energy_bounded_states(system, lam, 1, p.energy_max, seed=100 + i) for i, lam in enumerate(lv)]
        )
        val = FlowMapData(vx0, system.flow(vx0, lv, DT_HH), lv[:, None], np.full(1000, DT_HH))
        x0, mu = henon_heiles_test_instances(system, p.n_test, p.energy_max)
    return dict(system=system, data=data, val=val, x0=x0, mu=mu, **CASES[name])


def run_case(name, neural_epochs, neural_only=False):
    c = _case(name)
    system, data, x0, mu, dt = c["system"], c["data"], c["x0"], c["mu"], c["dt"]
    n_steps = int(np.floor(c["horizon"] / dt + 1e-9))
    n_long = 10 * n_steps
    exact_long = rollout(system, x0, mu, dt, n_long, scheme="kahan_li6", substeps=c["substeps"])
    exact = exact_long[:, : n_steps + 1]
    dts = np.full(len(x0), dt)
    nn_mu = np.column_stack([data.mu[:, 0], data.dt]) if c["with_dt"] else data.mu
    nn_q = np.column_stack([mu, dts]) if c["with_dt"] else mu
    models = {}
    if neural_only:
        if MLPFlowMap is None:
            raise SystemExit("--neural-only needs PyTorch: pip install 'sympredict[bench]'")
    t0 = time.perf_counter()
    m = (
        None
        if neural_only
        else SymplecticKernelPredictor(*c["kernels"], max_centers=c["centers"], trainer=ExactGreedy(tol=1e-10)).fit(
            data.x0, data.x1, mu=data.mu, dt=data.dt
        )
    )
    if not neural_only:
        models["sympredict (symplectic kernel)"] = (
            m,
            time.perf_counter() - t0,
            lambda k: m.rollout(x0, k, mu=mu, dt=dt),
            m.n_centers_,
        )
        t0 = time.perf_counter()
        d = DirectKernelPredictor(*c["kernels"], max_centers=c["centers"], trainer=ExactGreedy(tol=1e-10)).fit(
            data.x0, data.x1, mu=data.mu, dt=data.dt
        )
        models["direct kernel model"] = (
            d,
            time.perf_counter() - t0,
            lambda k: d.rollout(x0, k, mu=mu, dt=dt),
            d.n_centers_,
        )
        t0 = time.perf_counter()
        sel = select_vkoga_length_scale(data, c["val"], m_star=50)
        v = VKOGAFlowMap(max_centers=150, length_scale=sel["length_scale"]).fit(
            data.x0, data.x1, mu=data.mu, dt=data.dt
        )
        models[f"pyMOR VKOGA (length scale {sel['length_scale']:g})"] = (
            v,
            time.perf_counter() - t0,
            lambda k: v.rollout(x0, k, mu=mu, dt=dt),
            v.n_centers_,
        )
    if MLPFlowMap is not None:
        for label, cls, arch in (
            ("MLP flow map (PyTorch, 3x64)", MLPFlowMap, {"width": 64, "depth": 3}),
            ("G-SympNet (PyTorch, 6 modules x 32)", GSympNet, {"width": 32, "n_modules": 6}),
        ):
            net = cls(epochs=neural_epochs, **arch)
            t0 = time.perf_counter()
            net.fit(data.x0, data.x1, nn_mu)
            models[label] = (
                net,
                time.perf_counter() - t0,
                lambda k, net=net: net.rollout(x0, k, nn_q),
                sum(p.numel() for p in net.net.parameters()),
            )
    rows = []
    for label, (model, t_fit, run, size) in models.items():
        last = {}
        timing = _protocol.measure(lambda: last.__setitem__("traj", run(n_steps)), repeats=3, warmup=1)
        seconds, traj = timing["median_s"] / len(x0), last["traj"]
        with np.errstate(all="ignore"):
            err = relative_trajectory_error(np.nan_to_num(traj, nan=1e3, posinf=1e3, neginf=-1e3), exact).mean(axis=0)[
                1:
            ]
            long = np.nan_to_num(run(n_long), nan=1e3, posinf=1e3, neginf=-1e3)
            energy = relative_hamiltonian_error(system, long, np.asarray(mu)[:, None])
        rows.append(
            {
                "model": label,
                "size": int(size),
                "time_fit_s": t_fit,
                "ms_per_trajectory": seconds * 1e3,
                "median_err": float(np.median(err)),
                "max_err": float(err.max()),
                "max_energy_err_long": float(np.max(energy)),
                "long_steps": n_long,
            }
        )
        print(
            f"{name}: {label}: fit {t_fit:.1f} s, {seconds * 1e3:.3g} ms/traj, median err {np.median(err):.2e}, "
            f"max energy err over {n_long} steps {np.max(energy):.2e}",
            flush=True,
        )
    return {"case": name, "n_samples": len(data), "dt": dt, "n_test": len(x0), "n_steps": n_steps, "rows": rows}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True)
    parser.add_argument("--cases", default="pendulum_fixed,pendulum_full,henon_heiles")
    parser.add_argument("--neural-epochs", type=int, default=60)
    parser.add_argument("--neural-only", action="store_true", help="only the PyTorch peers (e.g. with more epochs)")
    _protocol.add_arguments(parser, json_option=False)
    args = parser.parse_args()
    set_log_levels({"sympredict": "WARN", "pymor": "WARN"})
    if GSympNet is not None:
        import torch

        torch.set_num_threads(1)
    with _protocol.limits(args.blas_threads, numba_threads=1):
        results = [run_case(name, args.neural_epochs, args.neural_only) for name in args.cases.split(",")]
        protocol = _protocol.record(
            blas_threads=args.blas_threads,
            numba_threads=1,
            repeats=3,
            warmup=1,
            statistic="median online time per trajectory; one timed fit per model",
        )
    _protocol.write_json(
        args.out,
        {
            "command": "python sympredict_paper/studies/data_driven.py "
            + " ".join(f"--{k.replace('_', '-')} {v}" for k, v in vars(args).items()),
            "results": results,
        },
        protocol,
        indent=2,
    )


if __name__ == "__main__":
    main()
