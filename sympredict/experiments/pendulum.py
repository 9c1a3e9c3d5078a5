"""Pendulum scenario A (paper section 4.2): one surrogate over length and macro step.

:func:`run_scenario_a` trains the predictor on the energy-bounded grid over
``MU_TRAIN x DT_TRAIN`` and evaluates it with the paper's protocol: 5 random
``q0 ~ U[0, pi/2]`` (``p0 = 0``) times 5 random lengths in ``[0.7, 0.8]``,
macro steps ``DT_TEST``, horizon ``T = 20``; kernel predictor vs implicit
midpoint at the same ``dT`` vs the micro-step reference.  It returns plain
results (numbers and arrays), no figures.
"""

from __future__ import annotations

import resource
import time
from dataclasses import asdict, dataclass, field

import numpy as np
from pymor.core.logger import getLogger

from sympredict.integrators import implicit_midpoint_step, integrate
from sympredict.kernels import IMQ, RadialKernel
from sympredict.metrics import relative_hamiltonian_error, relative_trajectory_error
from sympredict.predictor import SymplecticKernelPredictor
from sympredict.systems.pendulum import DT_TEST, DT_TRAIN, MU_TRAIN, Pendulum, flow_map_data, random_flow_map_data

__all__ = ["PendulumPreset", "PRESETS", "run_scenario_a", "paper_test_instances"]

logger = getLogger("sympredict.experiments.pendulum")


@dataclass(frozen=True)
class PendulumPreset:
    """Sizes of a pendulum scenario-A run.

    Attributes
    ----------
    n_grid
        Grid points per axis of the energy-bounded training grid (paper: 200).
    max_centers
        Greedy budget (paper: 1500).
    n_val
        Validation samples (random states on the training ``(mu, dT)`` grid).
    horizon
        Final time ``T`` of the test trajectories (paper: 20).
    eps
        Shape parameters ``(state, mu, dT)`` of the IMQ factors.
    """

    n_grid: int
    max_centers: int
    n_val: int
    horizon: float
    eps: tuple = (0.15, 2.0, 5.0)
    dt_test: tuple = field(default=DT_TEST)


PRESETS = {
    # seconds: for tests of the pipeline itself, not of accuracy
    "smoke": PendulumPreset(n_grid=14, max_centers=150, n_val=200, horizon=2.0),
    # about a minute on 2 cores: already meets the paper's accuracy
    "quick": PendulumPreset(n_grid=50, max_centers=1500, n_val=2000, horizon=20.0),
    # the paper's data size: 688,464 candidate functionals
    "paper": PendulumPreset(n_grid=200, max_centers=1500, n_val=20000, horizon=20.0),
}


def paper_test_instances(seed: int = 0, n_q0: int = 5, n_mu: int = 5):
    """The paper's test set: ``n_q0`` random ``q0 ~ U[0, pi/2]`` (``p0 = 0``) times ``n_mu`` random lengths.

    Returns
    -------
    x0 : ndarray of shape (n_q0 * n_mu, 2)
    mu : ndarray of shape (n_q0 * n_mu,)
    """
    rng = np.random.default_rng(seed)
    q0 = rng.uniform(0.0, np.pi / 2, n_q0)
    lengths = rng.uniform(0.7, 0.8, n_mu)
    qq, ll = np.meshgrid(q0, lengths, indexing="ij")
    return np.column_stack([qq.ravel(), np.zeros(qq.size)]), ll.ravel()


def _kernels(eps) -> tuple[RadialKernel, RadialKernel, RadialKernel]:
    return IMQ(eps[0]), IMQ(eps[1]), IMQ(eps[2])


def run_scenario_a(preset: PendulumPreset, seed: int = 0, model_path=None) -> dict:
    """Train and evaluate the scenario-A predictor.

    Parameters
    ----------
    preset
        Data and model sizes.
    seed
        Seed of the validation draw and of the test instances.
    model_path
        Where to save the trained model (HDF5), optional.

    Returns
    -------
    dict
        ``summary`` (JSON-ready numbers), ``history`` (greedy curves),
        ``per_dt`` (error and energy curves per test step), ``example``
        (one trajectory of each method for the portraits) and ``model``.
    """
    system = Pendulum()
    t0 = time.perf_counter()
    with logger.block(f"scenario A data: {preset.n_grid}x{preset.n_grid} grid x {len(MU_TRAIN)} lengths x {len(DT_TRAIN)} steps"):
        data = flow_map_data(system, n_grid=preset.n_grid)
        val = random_flow_map_data(system, preset.n_val, seed=seed + 1, mu_values=MU_TRAIN, dt_values=DT_TRAIN)
    t_data = time.perf_counter() - t0

    state_k, mu_k, dt_k = _kernels(preset.eps)
    model = SymplecticKernelPredictor(state_k, mu_k, dt_k, max_centers=preset.max_centers, tol=1e-10)
    t0 = time.perf_counter()
    model.fit(data.x0, data.x1, mu=data.mu, dt=data.dt, validation=val)
    t_fit = time.perf_counter() - t0
    peak_rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    if model_path is not None:
        model.save(model_path)

    x0, lengths = paper_test_instances(seed)
    per_dt = []
    for dt in preset.dt_test:
        n_steps = int(np.floor(preset.horizon / dt + 1e-9))
        with logger.block(f"test dT={dt}: {len(x0)} trajectories x {n_steps} steps"):
            t0 = time.perf_counter()
            ref = system.trajectory(x0, lengths, dt, n_steps)
            t_ref = time.perf_counter() - t0
            t0 = time.perf_counter()
            pred = model.rollout(x0, n_steps, mu=lengths, dt=dt)
            t_pred = time.perf_counter() - t0
            t0 = time.perf_counter()
            im = integrate(implicit_midpoint_step, system, x0, lengths[:, None], dt, n_steps)
            t_im = time.perf_counter() - t0
        err_kernel = relative_trajectory_error(pred, ref).mean(axis=0)
        err_im = relative_trajectory_error(im, ref).mean(axis=0)
        per_dt.append(
            {
                "dt": dt,
                "t": dt * np.arange(n_steps + 1),
                "err_kernel": err_kernel,
                "err_im": err_im,
                "energy_kernel": relative_hamiltonian_error(system, pred, lengths[:, None]).mean(axis=0),
                "energy_im": relative_hamiltonian_error(system, im, lengths[:, None]).mean(axis=0),
                "energy_ref": relative_hamiltonian_error(system, ref, lengths[:, None]).mean(axis=0),
                "time_kernel": t_pred,
                "time_im": t_im,
                "time_ref": t_ref,
                "example": {"ref": ref[-1], "kernel": pred[-1], "im": im[-1], "mu": float(lengths[-1])},
            }
        )

    hist = model.history_
    summary = {
        "n_samples": len(data),
        "n_functionals": 2 * len(data),
        "n_val_samples": len(val),
        "n_centers": model.n_centers_,
        "stop_reason": hist.stop_reason,
        "E_train": float(hist.train_max_residual[-1]),
        "E_val": float(hist.val_max_residual[-1]),
        "time_data_s": t_data,
        "time_fit_s": t_fit,
        "peak_rss_gib": peak_rss / 2**30,
        "preset": asdict(preset),
        "seed": seed,
        "per_dt": [
            {
                "dt": r["dt"],
                "kernel_median_err": float(np.median(r["err_kernel"][1:])),
                "kernel_max_err": float(r["err_kernel"][1:].max()),
                "im_median_err": float(np.median(r["err_im"][1:])),
                "im_max_err": float(r["err_im"][1:].max()),
                "ratio_median": float(np.median(r["err_im"][1:]) / np.median(r["err_kernel"][1:])),
                "kernel_max_energy_err": float(r["energy_kernel"].max()),
                "im_max_energy_err": float(r["energy_im"].max()),
                "time_kernel_s": r["time_kernel"],
                "time_im_s": r["time_im"],
                "time_ref_s": r["time_ref"],
            }
            for r in per_dt
        ],
    }
    return {"summary": summary, "history": hist, "per_dt": per_dt, "model": model}
