"""Hénon–Heiles speed against accuracy: a non-integrable system with a cheap right-hand side.

``lambda`` in ``[0.8, 1.0]``, fixed macro step ``dT = 0.5``.  :func:`run_henon_heiles`
trains the kernel predictor on flow-map samples of states in the well with
``H <= energy_max`` (half the escape energy at ``lambda = 1``), for
``n_lambda`` training values of ``lambda``; the direct kernel model and pyMOR's
VKOGA get the same samples.  Test: ``n_test`` states times ``n_test`` random
``lambda`` (energy at most ``0.9 energy_max``), horizon ``T``; every method is
timed side by side (:mod:`sympredict_paper.speed`).
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import numpy as np
from pymor.core.logger import getLogger

from sympredict.exceptions import extrapolation_expected
from sympredict.data import FlowMapData
from sympredict_paper import scenario_main
from sympredict_paper.presets import load_presets
from sympredict_paper.peers import VKOGAFlowMap, select_vkoga_length_scale
from sympredict_paper.speed import SpeedTable, add_classical, deliberate_threads, model_sizes, timed
from sympredict.symplectic.integrators_compiled import EXPLICIT_SCHEMES, rollout
from sympredict.symplectic.metrics import relative_hamiltonian_error
from sympredict.estimators.predictor import DirectKernelPredictor, SymplecticKernelPredictor
from sympredict.estimators.selection import kernel_grid, select_kernels
from sympredict.systems.henon_heiles import LAMBDA_RANGE, HenonHeiles, energy_bounded_states
from sympredict.interpolation.greedy import ExactGreedy

__all__ = [
    "HenonHeilesPreset",
    "PRESETS",
    "DT_HH",
    "henon_heiles_data",
    "henon_heiles_test_instances",
    "run_henon_heiles",
]

logger = getLogger("sympredict_paper.henon_heiles")

#: The issue's macro step.
DT_HH = 0.5


@dataclass(frozen=True)
class HenonHeilesPreset:
    """Sizes of a Hénon–Heiles run.

    Attributes
    ----------
    n_lambda, n_per_lambda, n_val
        Training values of ``lambda`` (equispaced in ``LAMBDA_RANGE``), samples per value,
        validation samples (``lambda`` uniform in the range).
    energy_max
        Energy bound of the sampled states (default: half the escape energy ``1/6`` at ``lambda = 1``).
    max_centers, centers
        Greedy budget; model sizes (prefixes) in the chart.
    state_eps, mu_eps, m_star
        Validation grid of IMQ shapes (state, ``lambda``) compared at ``m_star`` centres.
    vkoga_centers, vkoga_length_scales
        VKOGA's budget and the Gaussian length scales (inputs scaled to the unit box) it chooses from on
        the validation data (:func:`~sympredict_paper.peers.select_vkoga_length_scale`, 50 centres).
    n_test, horizon
        Test states per ``lambda`` and ``lambda`` values (``n_test^2`` trajectories); final time.
    refinements, repeats, threads
        Step refinements of the classical schemes; timed repeats; BLAS / numba threads.
    """

    n_lambda: int = 5
    n_per_lambda: int = 2000
    n_val: int = 1000
    energy_max: float = 1.0 / 12.0
    max_centers: int = 500
    centers: tuple = (100, 200, 500)
    state_eps: tuple = (0.25, 0.5, 1.0)
    mu_eps: tuple = (0.3, 1.0, 3.0)
    m_star: int = 200
    vkoga_centers: int = 200
    vkoga_length_scales: tuple = (0.1, 0.3, 1.0, 3.0)
    n_test: int = 5
    horizon: float = 50.0
    refinements: tuple = (1, 2, 4, 8)
    repeats: int = 3
    threads: int = 1


#: ``smoke``, ``quick``, ``paper``: sympredict_paper/presets/henon_heiles.toml
PRESETS = load_presets("henon_heiles", HenonHeilesPreset)


def henon_heiles_data(
    system: HenonHeiles, lams, n_per_lambda: int, energy_max: float, dt: float = DT_HH, seed: int = 0
) -> FlowMapData:
    """Flow-map samples: per ``lambda`` in ``lams``, ``n_per_lambda`` states with ``H <= energy_max`` and their flows over ``dt``."""
    parts = []
    for i, lam in enumerate(lams):
        x0 = energy_bounded_states(system, lam, n_per_lambda, energy_max, seed=seed + i)
        x1 = system.flow(x0, lam, dt)
        parts.append(FlowMapData(x0, x1, np.full((len(x0), 1), lam), np.full(len(x0), dt)))
    return FlowMapData(*(np.concatenate([getattr(p, k) for p in parts]) for k in ("x0", "x1", "mu", "dt")))


def henon_heiles_test_instances(system: HenonHeiles, n_test: int, energy_max: float, seed: int = 0):
    """``n_test`` random ``lambda`` in the range times ``n_test`` states each (``H <= 0.9 energy_max``): (x0 (B, 4), lam (B,))."""
    rng = np.random.default_rng(seed + 3000)
    lams = np.sort(rng.uniform(*LAMBDA_RANGE, n_test))
    x0 = np.concatenate(
        [
            energy_bounded_states(system, lam, n_test, 0.9 * energy_max, seed=seed + 3001 + i)
            for i, lam in enumerate(lams)
        ]
    )
    return x0, np.repeat(lams, n_test)


def run_henon_heiles(preset: HenonHeilesPreset, seed: int = 0) -> dict:
    """Train the kernel predictor, the direct kernel model and VKOGA on the same data; time every method side by side.

    Returns
    -------
    dict
        ``summary`` (JSON-ready: training, selection, ``speed_accuracy`` rows, energy errors),
        ``model``, ``direct``, ``vkoga``.
    """
    system = HenonHeiles()
    lams = np.linspace(*LAMBDA_RANGE, preset.n_lambda)
    t0 = time.perf_counter()
    with logger.block(f"Hénon–Heiles data: {preset.n_lambda} lambdas x {preset.n_per_lambda} states, dT = {DT_HH}"):
        data = henon_heiles_data(system, lams, preset.n_per_lambda, preset.energy_max, seed=seed)
        rng = np.random.default_rng(seed + 1)
        val_lams = rng.uniform(*LAMBDA_RANGE, preset.n_val)
        # one state per validation lambda: lambda uniform in the range, not on the training grid
        vx0 = np.concatenate(
            [
                energy_bounded_states(system, lam, 1, preset.energy_max, seed=seed + 100 + i)
                for i, lam in enumerate(val_lams)
            ]
        )
        val = FlowMapData(vx0, system.flow(vx0, val_lams, DT_HH), val_lams[:, None], np.full(len(vx0), DT_HH))
    t_data = time.perf_counter() - t0
    t0 = time.perf_counter()
    sel = select_kernels(
        data,
        val,
        kernel_grid(("imq",), preset.state_eps),
        kernel_grid(("imq",), preset.mu_eps),
        (None,),
        m_star=preset.m_star,
    )
    t_sel = time.perf_counter() - t0
    vsel = select_vkoga_length_scale(data, val, preset.vkoga_length_scales, m_star=min(50, preset.vkoga_centers))
    models, fit_time = {}, {}
    for name, make in (
        (
            "symplectic",
            lambda: SymplecticKernelPredictor(
                sel.state, sel.mu, None, max_centers=preset.max_centers, trainer=ExactGreedy(tol=1e-10)
            ),
        ),
        (
            "direct",
            lambda: DirectKernelPredictor(
                sel.state, sel.mu, None, max_centers=preset.max_centers, trainer=ExactGreedy(tol=1e-10)
            ),
        ),
        ("vkoga", lambda: VKOGAFlowMap(max_centers=preset.vkoga_centers, length_scale=vsel["length_scale"])),
    ):
        t0 = time.perf_counter()
        with logger.block(f"Hénon–Heiles: {name} model on {len(data)} samples"):
            extra = {"validation": val} if name == "symplectic" else {}
            models[name] = make().fit(data.x0, data.x1, mu=data.mu, dt=data.dt, **extra)
        fit_time[name] = time.perf_counter() - t0
    model, direct, vkoga = models["symplectic"], models["direct"], models["vkoga"]

    x0, lam_test = henon_heiles_test_instances(system, preset.n_test, preset.energy_max, seed)
    n_steps = int(np.floor(preset.horizon / DT_HH + 1e-9))
    # small models may wander off the training states: the chart's errors say so, no warning per rollout
    with (
        logger.block(f"Hénon–Heiles speed against accuracy: {len(x0)} trajectories x {n_steps} steps"),
        deliberate_threads(preset.threads),
        extrapolation_expected(),
    ):
        exact = rollout(system, x0, lam_test, DT_HH, n_steps, scheme="kahan_li6", substeps=256)
        table = SpeedTable(exact, preset.repeats)
        ref_row = table.add(
            "micro-step reference (Kahan-Li-6, step halving to 1e-11)",
            0,
            "tol=1e-11",
            "equations",
            lambda: system.trajectory(x0, lam_test, DT_HH, n_steps),
        )
        trajectories = {}
        for m in model_sizes(preset.centers, model.n_centers_):
            small = timed(model.truncated(m))
            table.add("kernel predictor", m, f"m={m}", "data", lambda: small.rollout(x0, n_steps, mu=lam_test))
        trajectories["kernel predictor"] = model.rollout(x0, n_steps, mu=lam_test)
        table.add_model("direct kernel model (NumPy)", direct, lambda: direct.rollout(x0, n_steps, mu=lam_test))
        trajectories["direct kernel model"] = direct.rollout(x0, n_steps, mu=lam_test)
        table.add_model(
            "pyMOR VKOGA flow map (NumPy)", vkoga, lambda: vkoga.rollout(x0, n_steps, mu=lam_test, dt=DT_HH)
        )
        trajectories["pyMOR VKOGA"] = vkoga.rollout(x0, n_steps, mu=lam_test, dt=DT_HH)
        add_classical(table, system, x0, lam_test, DT_HH, n_steps, preset.refinements, EXPLICIT_SCHEMES)
    energy = {}
    for name, traj in trajectories.items():
        with np.errstate(all="ignore"):
            e = relative_hamiltonian_error(
                system, np.nan_to_num(traj, nan=1e3, posinf=1e3, neginf=-1e3), lam_test[:, None]
            )
        energy[name] = float(np.max(e))
    speed = {
        "dt": DT_HH,
        "n_trajectories": len(x0),
        "n_steps": n_steps,
        "repeats": preset.repeats,
        "threads": preset.threads,
        "reference_time_s": ref_row["time_per_trajectory_s"],
        "error_reference": "Kahan-Li-6, dT/256 (compiled)",
        "rows": table.rows,
        "unreached": [],
    }
    summary = {
        "preset": asdict(preset),
        "seed": seed,
        "n_samples": len(data),
        "n_val_samples": len(val),
        "kernel": [repr(sel.state), repr(sel.mu)],
        "selection_E_val": sel.score,
        "n_centers": model.n_centers_,
        "stop_reason": model.history_.stop_reason,
        "E_val": float(model.history_.val_max_residual[-1]) if model.history_.val_max_residual is not None else None,
        "n_centers_direct": direct.n_centers_,
        "n_centers_vkoga": vkoga.n_centers_,
        "vkoga_selection": {k: v for k, v in vsel.items()},
        "time_data_s": t_data,
        "time_selection_s": t_sel,
        **{f"time_fit_{k}_s": v for k, v in fit_time.items()},
        "max_rel_energy_err": energy,
        "speed_accuracy": speed,
    }
    return {"summary": summary, "model": model, "direct": direct, "vkoga": vkoga}


#: ``python -m sympredict_paper.henon_heiles [OPTIONS]``: ``sympredict-paper run henon-heiles [OPTIONS]``.
main = scenario_main("henon-heiles")


if __name__ == "__main__":
    raise SystemExit(main())
