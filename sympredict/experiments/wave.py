"""The MOR pipeline on the parametric wave equation (paper section 4.1).

``fom -> snapshots at c_ref -> complex-SVD symplectic basis -> rom -> reduced
flow-map data -> one SymplecticKernelPredictor per macro step -> evaluation``.

:func:`run_wave` returns results (numbers and arrays), no figures:

* basis: singular values, symplecticity, timings;
* per ``dT``: the kernel chosen on validation data (log grids of shapes), the
  greedy curves, and for each random test speed the mean relative error over
  time of the kernel predictor and of implicit midpoint at ``dT``, both in
  reduced coordinates (against the reduced micro-step reference) and after
  reconstruction ``V x_red`` (against the FOM micro-step reference);
* online wall times of ROM + kernel, ROM + implicit midpoint and the FOM reference.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, replace

import numpy as np
from pymor.core.logger import getLogger

from sympredict.data import FlowMapData
from sympredict.metrics import relative_trajectory_error
from sympredict.predictor import SymplecticKernelPredictor
from sympredict.reduction import SymplecticROM, complex_svd_basis, symplecticity_of_basis
from sympredict.selection import kernel_grid, select_kernels
from sympredict.systems.wave import C_REF, C_TRAIN, DT_WAVE, WaveFOM

__all__ = ["WavePreset", "PRESETS", "build_rom", "reduced_flow_map_data", "run_wave"]

logger = getLogger("sympredict.experiments.wave")


@dataclass(frozen=True)
class WavePreset:
    """Sizes of a wave-pipeline run.

    Attributes
    ----------
    n_points
        FOM grid points ``N`` (paper: 1000).
    n_reduced
        Complex modes ``n`` of the basis (reduced dimension ``2n``; paper: 2).
    n_modes
        Sine modes excited in the snapshot initial states (richer states for larger ``n``).
    n_snapshot_states, snapshot_dt
        Snapshot trajectories at ``c_ref`` over ``[0, horizon]``, sampled every ``snapshot_dt``.
    samples_per_speed, val_per_speed
        Reduced training / validation states per training speed (paper: 20,000 training).
    max_centers
        Greedy budget of each predictor.
    dts
        Macro steps, one predictor each.
    n_test_speeds, n_test_ics, horizon
        Random test speeds in ``[0.2, 0.3]``, initial conditions per speed, final time.
    state_eps, mu_eps, families, m_star
        Validation grid: state-kernel families and shapes, IMQ shapes of the ``mu`` factor,
        and the number of centres at which candidates are compared.
    """

    n_points: int = 1000
    n_reduced: int = 2
    n_modes: int = 2
    n_snapshot_states: int = 10
    snapshot_dt: float = 0.02
    samples_per_speed: int = 2000
    val_per_speed: int = 300
    max_centers: int = 1500
    dts: tuple = DT_WAVE
    n_test_speeds: int = 3
    n_test_ics: int = 5
    horizon: float = 6.0
    state_eps: tuple = (3e-4, 1e-3, 3e-3, 1e-2)
    mu_eps: tuple = (1.0, 3.0, 10.0)
    families: tuple = ("imq", "matern52")
    m_star: int = 300


PRESETS = {
    "smoke": WavePreset(
        n_points=200, n_snapshot_states=4, samples_per_speed=150, val_per_speed=40, max_centers=150, dts=(0.1,),
        n_test_speeds=2, n_test_ics=2, horizon=1.0, state_eps=(3e-3, 1e-2), mu_eps=(10.0,), families=("imq",), m_star=60,
    ),
    "quick": WavePreset(),
    "paper": WavePreset(samples_per_speed=20000, val_per_speed=2000),
}


def build_rom(preset: WavePreset, seed: int = 0):
    """FOM, snapshots at ``c_ref``, complex-SVD basis, reduced model.

    Returns
    -------
    fom : WaveFOM
    rom : SymplecticROM
    energy : float
        Energy bound of the sampling region (unit-amplitude fundamental mode at ``c_ref``).
    info : dict
        Timings, singular values, symplecticity and orthonormality of the basis.
    """
    t0 = time.perf_counter()
    fom = WaveFOM(preset.n_points, T=preset.horizon)
    mu_ref = C_REF**2
    energy = fom.reference_energy(mu_ref)
    with logger.block(f"snapshots at c_ref={C_REF}: {preset.n_snapshot_states} trajectories, {preset.n_modes} modes"):
        x0 = fom.low_frequency_states(preset.n_snapshot_states, preset.n_modes, mu_ref, energy, seed=seed)
        n_snap = int(round(preset.horizon / preset.snapshot_dt))
        snapshots = fom.trajectory(x0, mu_ref, preset.snapshot_dt, n_snap).reshape(-1, fom.dim)
    t_snap = time.perf_counter() - t0
    t0 = time.perf_counter()
    basis = complex_svd_basis(snapshots, n=preset.n_reduced)
    t_basis = time.perf_counter() - t0
    rom = SymplecticROM(fom, basis)
    info = {
        "n_snapshots": len(snapshots),
        "time_snapshots_s": t_snap,
        "time_basis_s": t_basis,
        "singular_values": basis.singular_values[: 2 * preset.n_reduced + 4].tolist(),
        "projection_error": basis.projection_error,
        "symplecticity": symplecticity_of_basis(basis.V),
        "orthonormality": float(np.abs(basis.V.T @ basis.V - np.eye(basis.V.shape[1])).max()),
        "energy_bound": energy,
    }
    return fom, rom, energy, info


def reduced_flow_map_data(rom: SymplecticROM, speeds, dt: float, n_per_speed: int, energy: float, seed: int) -> FlowMapData:
    """Reduced states uniform in ``{H_red(x; c^2) <= energy}`` per speed, and their reference flows over ``dt``.

    Returns
    -------
    FlowMapData
        ``mu = c^2`` of shape (M, 1).
    """
    parts = []
    for i, c in enumerate(speeds):
        mu = float(c) ** 2
        x0 = rom.system.sample_energy_ellipsoid(n_per_speed, mu, energy, seed=seed + i)
        parts.append(FlowMapData(x0, rom.system.flow(x0, mu, dt), np.full((n_per_speed, 1), mu), np.full(n_per_speed, dt)))
    out = parts[0]
    for p in parts[1:]:
        out = out.concatenate(p)
    return out


def run_wave(preset: WavePreset, seed: int = 0, **overrides) -> dict:
    """Run the whole pipeline; ``overrides`` replace preset fields (e.g. ``n_reduced=5, n_modes=5``)."""
    preset = replace(preset, **overrides) if overrides else preset
    fom, rom, energy, basis_info = build_rom(preset, seed)
    rng = np.random.default_rng(seed + 1000)
    test_speeds = np.sort(rng.uniform(0.2, 0.3, preset.n_test_speeds))
    test_x0 = {c: rom.system.sample_energy_ellipsoid(preset.n_test_ics, c**2, energy, seed=seed + 2000 + i) for i, c in enumerate(test_speeds)}
    state_kernels = kernel_grid(preset.families, preset.state_eps)
    mu_kernels = kernel_grid(("imq",), preset.mu_eps)
    per_dt = []
    for j, dt in enumerate(preset.dts):
        with logger.block(f"dT = {dt}: data, kernel selection, training"):
            t0 = time.perf_counter()
            data = reduced_flow_map_data(rom, C_TRAIN, dt, preset.samples_per_speed, energy, seed=seed + 10 * j + 1)
            val = reduced_flow_map_data(rom, C_TRAIN, dt, preset.val_per_speed, energy, seed=seed + 10 * j + 500)
            t_data = time.perf_counter() - t0
            t0 = time.perf_counter()
            sel = select_kernels(data, val, state_kernels, mu_kernels, m_star=min(preset.m_star, preset.max_centers))
            t_sel = time.perf_counter() - t0
            model = SymplecticKernelPredictor(sel.state, sel.mu, None, max_centers=preset.max_centers, tol=1e-10)
            t0 = time.perf_counter()
            model.fit(data.x0, data.x1, mu=data.mu, dt=dt, validation=val)
            t_fit = time.perf_counter() - t0
        n_steps = int(np.floor(preset.horizon / dt + 1e-9))
        cases = []
        for c in test_speeds:
            mu = c**2
            x0 = test_x0[c]
            ref = rom.system.trajectory(x0, mu, dt, n_steps)
            t0 = time.perf_counter()
            pred = model.rollout(x0, n_steps, mu=mu)
            t_kernel = time.perf_counter() - t0
            t0 = time.perf_counter()
            im = rom.system.trajectory(x0, mu, dt, n_steps, h_max=dt)  # one midpoint step per macro step
            t_im = time.perf_counter() - t0
            t0 = time.perf_counter()
            ref_full = fom.trajectory(rom.reconstruct(x0), mu, dt, n_steps)
            t_fom = time.perf_counter() - t0
            err = {
                "kernel_red": relative_trajectory_error(pred, ref).mean(axis=0),
                "im_red": relative_trajectory_error(im, ref).mean(axis=0),
                "kernel_full": relative_trajectory_error(rom.reconstruct(pred), ref_full).mean(axis=0),
                "im_full": relative_trajectory_error(rom.reconstruct(im), ref_full).mean(axis=0),
            }
            cases.append({"c": float(c), "t": dt * np.arange(n_steps + 1), "err": err,
                          "time_kernel_s": t_kernel, "time_rom_im_s": t_im, "time_fom_ref_s": t_fom})
        per_dt.append({"dt": dt, "model": model, "selection": sel, "cases": cases,
                       "time_data_s": t_data, "time_selection_s": t_sel, "time_fit_s": t_fit, "n_samples": len(data)})

    summary = {
        "preset": asdict(preset),
        "seed": seed,
        "basis": basis_info,
        "test_speeds": test_speeds.tolist(),
        "per_dt": [
            {
                "dt": r["dt"],
                "n_samples": r["n_samples"],
                "kernel": {"state": repr(r["selection"].state), "mu": repr(r["selection"].mu), "E_val_m_star": r["selection"].score},
                "n_centers": r["model"].n_centers_,
                "stop_reason": r["model"].history_.stop_reason,
                "E_train": float(r["model"].history_.train_max_residual[-1]),
                "E_val": float(r["model"].history_.val_max_residual[-1]),
                "time_data_s": r["time_data_s"],
                "time_selection_s": r["time_selection_s"],
                "time_fit_s": r["time_fit_s"],
                "cases": [
                    {
                        "c": case["c"],
                        **{f"mean_{k}": float(v[1:].mean()) for k, v in case["err"].items()},
                        "ratio_red": float(case["err"]["im_red"][1:].mean() / case["err"]["kernel_red"][1:].mean()),
                        "time_kernel_s": case["time_kernel_s"],
                        "time_rom_im_s": case["time_rom_im_s"],
                        "time_fom_ref_s": case["time_fom_ref_s"],
                    }
                    for case in r["cases"]
                ],
            }
            for r in per_dt
        ],
    }
    return {"summary": summary, "per_dt": per_dt, "fom": fom, "rom": rom}
