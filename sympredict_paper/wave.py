"""The MOR pipeline on the parametric wave equation (paper section 4.1).

``fom -> snapshots at c_ref -> complex-SVD symplectic basis -> rom -> reduced
flow-map data -> one SymplecticKernelReductor per macro step (kernel selection,
training, the kernel ROM) -> evaluation``.  The Galerkin ROM (:class:`SymplecticROM`)
stays for the intrusive comparisons: its reference flows, implicit midpoint and
exact propagator.

:func:`run_wave` returns results (numbers and arrays), no figures:

* basis: singular values, symplecticity, timings;
* per ``dT``: the kernel chosen on validation data (log grids of shapes), the
  greedy curves, and for each random test speed the mean relative error over
  time of the kernel predictor and of implicit midpoint at ``dT``, both in
  reduced coordinates (against the reduced micro-step reference) and after
  reconstruction ``V x_red`` (against the FOM micro-step reference);
* online wall times of ROM + kernel, ROM + implicit midpoint and the FOM reference;
* speed against accuracy at the first ``dT`` (:func:`run_wave_speed_accuracy`):
  FOM vs ROM vs ROM + kernel, timed side by side;
* the smallest model meeting a validation target (:func:`smallest_wave_model`).
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, replace
from typing import Optional

import numpy as np
from pymor.core.logger import getLogger

from sympredict.data import FlowMapData
from sympredict.exceptions import extrapolation_expected
from sympredict.systems.flowmaps import flow_map_data, mus_to_matrix, random_parameters, sample_energy_ellipsoid
from sympredict.symplectic.metrics import relative_trajectory_error
from sympredict.parallel import pool_flow, pool_map_instances
from sympredict_paper import scenario_main
from sympredict_paper.presets import load_presets
from sympredict_paper.peers import VKOGAFlowMap, select_vkoga_length_scale
from sympredict_paper.speed import SpeedTable, add_classical, deliberate_threads, model_sizes, timed
from sympredict.symplectic.integrators_compiled import EXPLICIT_SCHEMES, rollout
from sympredict.estimators.predictor import DirectKernelPredictor, SymplecticKernelPredictor
from sympredict.mor.basis import SymplecticROM, complex_svd_basis, symplecticity_of_basis
from sympredict.estimators.selection import kernel_grid
from sympredict.mor import GivenSamples, SymplecticKernelReductor, TrainingScaling, ValidationSelection
from sympredict.systems.wave import C_REF, C_TRAIN, DT_WAVE, WaveFOM
from sympredict.interpolation.greedy import ExactGreedy

__all__ = [
    "WavePreset",
    "PRESETS",
    "fom_snapshots",
    "build_rom",
    "reduced_flow_map_data",
    "validation_speeds",
    "wave_reductor",
    "train_wave_predictor",
    "run_wave",
    "run_wave_speed_accuracy",
    "smallest_wave_model",
]

logger = getLogger("sympredict_paper.wave")


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
    speed_centers, speed_repeats, speed_refinements, speed_threads
        Model sizes, timing repeats, step refinements of the implicit schemes and BLAS/numba threads of the
        speed-against-accuracy comparison (first ``dT``).
    fom_explicit_refinements
        Step refinements of the explicit FOM schemes: they are stable only below the CFL limit
        ``h < 2 / (c omega_max)``, ``omega_max ~ 2 (N + 1)`` (``h < 3.3e-3`` at ``N = 1000``, ``c = 0.3``);
        ``dT/1`` is kept to show the instability.
    vkoga_centers, vkoga_length_scales
        pyMOR VKOGA's budget on the same reduced data and its Gaussian length scales (unit-box inputs), one
        chosen on the validation data.
    target_accuracy
        Target of :func:`smallest_wave_model` (validation error of full-space trajectories, first ``dT``).
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
    speed_centers: tuple = (50, 100, 200, 400, 800, 1500)
    speed_repeats: int = 3
    speed_refinements: tuple = (1, 2, 4, 8)
    fom_explicit_refinements: tuple = (1, 32, 64)
    speed_threads: int = 1
    vkoga_centers: int = 150
    vkoga_length_scales: tuple = (0.1, 0.3, 1.0, 3.0)
    target_accuracy: float = 1e-4


#: ``smoke``, ``quick``, ``paper``: sympredict_paper/presets/wave.toml
PRESETS = load_presets("wave", WavePreset)


def fom_snapshots(preset: WavePreset, seed: int = 0, pool=None):
    """FOM and its snapshot trajectories at ``c_ref``; with a pyMOR worker ``pool``, computed over it
    (:func:`sympredict.parallel.pool_map_instances`, the same snapshots bit for bit).

    Returns
    -------
    fom : WaveFOM
    snapshots : ndarray of shape (n_snapshot_states * (K+1), 2N)
    energy : float
        Energy bound of the sampling region (unit-amplitude fundamental mode at ``c_ref``).
    seconds : float
        Wall time of the snapshot trajectories.
    """
    t0 = time.perf_counter()
    fom = WaveFOM(preset.n_points, T=preset.horizon)
    mu_ref = C_REF**2
    energy = fom.reference_energy(mu_ref)
    with logger.block(f"snapshots at c_ref={C_REF}: {preset.n_snapshot_states} trajectories, {preset.n_modes} modes"):
        x0 = fom.low_frequency_states(preset.n_snapshot_states, preset.n_modes, mu_ref, energy, seed=seed)
        n_snap = int(round(preset.horizon / preset.snapshot_dt))
        if pool is None:
            snapshots = fom.trajectory(x0, mu_ref, preset.snapshot_dt, n_snap)
        else:
            snapshots = pool_map_instances(fom, "trajectory", x0, mu_ref, preset.snapshot_dt, n_snap, pool=pool)
        snapshots = snapshots.reshape(-1, fom.dim)
    return fom, snapshots, energy, time.perf_counter() - t0


def build_rom(preset: WavePreset, seed: int = 0, pool=None):
    """FOM, snapshots at ``c_ref`` (over ``pool`` when given), complex-SVD basis, reduced model.

    Returns
    -------
    fom : WaveFOM
    rom : SymplecticROM
    energy : float
        Energy bound of the sampling region (unit-amplitude fundamental mode at ``c_ref``).
    info : dict
        Timings, singular values, symplecticity and orthonormality of the basis.
    """
    fom, snapshots, energy, t_snap = fom_snapshots(preset, seed, pool)
    t0 = time.perf_counter()
    basis = complex_svd_basis(snapshots, n=preset.n_reduced, layout="rows")
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


def reduced_flow_map_data(
    rom: SymplecticROM,
    speeds,
    dt: float,
    n_per_speed: int,
    energy: float,
    seed: int,
    *,
    pool=None,
    chunk_size: Optional[int] = None,
) -> FlowMapData:
    """Reduced states uniform in ``{H_red(x; mu) <= energy}`` per speed, and their reference flows over ``dt``.

    The wave FOM's parameter is ``mu = c^2`` (:class:`~sympredict.systems.wave.WaveFOM`):
    each speed ``c`` is mapped to it once here.  States come from the generic
    :func:`sympredict.systems.flowmaps.sample_energy_ellipsoid` (exact, rejection-free), flows
    from :func:`sympredict.systems.flowmaps.flow_map_data` (serial).

    With ``pool`` (or ``chunk_size``) the flows are evaluated over a pyMOR worker
    pool in chunks of states (:func:`sympredict.parallel.pool_flow`, the same
    samples bit for bit).

    Returns
    -------
    FlowMapData
        ``mu = c^2`` of shape (M, 1).
    """
    parts = []
    for i, c in enumerate(speeds):
        mu = float(c) ** 2
        x0 = sample_energy_ellipsoid(rom.system, n_per_speed, mu, energy, np.random.default_rng(seed + i))
        if pool is None and chunk_size is None:
            parts.append(flow_map_data(rom.system, x0, np.full((n_per_speed, 1), mu), dt))
        else:
            x1 = pool_flow(rom.system, x0, mu, dt, pool=pool, chunk_size=chunk_size)
            parts.append(FlowMapData(x0, x1, np.full((n_per_speed, 1), mu), np.full(n_per_speed, dt)))
    out = parts[0]
    for p in parts[1:]:
        out = out.concatenate(p)
    return out


def validation_speeds(fom: WaveFOM, n: int, seed: int) -> np.ndarray:
    """``n`` speeds with ``c^2`` uniform in the FOM's declared parameter range (not the training speeds).

    Validating on the training speeds measures interpolation in the states only
    and picked kernels 3-9x worse than validation at speeds drawn in the range.
    """
    lo, hi = fom.mu_range
    mus = random_parameters(fom.model.parameters, [lo], [hi], n, seed=seed)
    return np.sqrt(mus_to_matrix(mus, fom.model.parameters)[:, 0])


def wave_reductor(
    rom: SymplecticROM, preset: WavePreset, dt: float, data: FlowMapData, validation: FlowMapData
) -> SymplecticKernelReductor:
    """The library's reductor set up as the paper's wave experiment, on samples it is given.

    :class:`~sympredict.mor.SymplecticKernelReductor` on the FOM's pyMOR model and the
    ROM's basis, with the experiment's samples (``data``, ``validation``: reduced states in
    the energy ellipsoid, :func:`reduced_flow_map_data`), trained in the reduced coordinates
    and units as they are (no state, parameter or time scaling: the preset's kernel shapes are
    in these units), the kernel tuple chosen on the validation samples from the preset's grid
    at ``m_star`` centres, then trained by f-greedy (``tol = 1e-10``) to ``max_centers``.
    """
    return SymplecticKernelReductor(
        rom.model,
        rom.RB,
        dt,
        GivenSamples(data, validation),
        SymplecticKernelPredictor(max_centers=preset.max_centers, trainer=ExactGreedy(tol=1e-10)),
        scaling=TrainingScaling("none", "none", "none"),
        selection=ValidationSelection(
            kernel_grid(preset.families, preset.state_eps), kernel_grid(("imq",), preset.mu_eps), m_star=preset.m_star
        ),
    )


def train_wave_predictor(rom: SymplecticROM, preset: WavePreset, dt: float, energy: float, seed: int = 0) -> dict:
    """Reduced flow-map data at one macro step, then the reductor: kernel chosen on validation data, f-greedy fit.

    Training states are drawn per training speed (``C_TRAIN``), validation states
    per speed drawn in the declared range (:func:`validation_speeds`), uniformly in
    the reduced energy ellipsoid; :func:`wave_reductor` then chooses the kernel tuple
    minimizing ``E_val(m_star)`` over the preset's grid (:func:`~sympredict.estimators.selection.select_kernels`) and
    trains it to ``preset.max_centers`` centres.

    Returns
    -------
    dict
        ``model`` (the fitted predictor, with ``E_val`` history: with no scaling it is the ROM's
        flow map in reduced coordinates), ``selection``, ``n_samples``, ``data`` and ``validation``
        (the samples), ``reductor`` and ``kernel_rom`` (the pyMOR model it returned),
        ``time_data_s``, ``time_selection_s``, ``time_fit_s``.
    """
    with logger.block(f"dT = {dt}, 2n = {rom.dim}: data, kernel selection, training"):
        t0 = time.perf_counter()
        data = reduced_flow_map_data(rom, C_TRAIN, dt, preset.samples_per_speed, energy, seed=seed + 1)
        val = reduced_flow_map_data(
            rom, validation_speeds(rom.fom, len(C_TRAIN), seed + 500), dt, preset.val_per_speed, energy, seed=seed + 500
        )
        t_data = time.perf_counter() - t0
        reductor = wave_reductor(rom, preset, dt, data, val)
        kernel_rom = reductor.reduce()
    return {
        "model": reductor.predictor_,
        "selection": reductor.selection_,
        "n_samples": len(data),
        "data": data,
        "validation": val,
        "reductor": reductor,
        "kernel_rom": kernel_rom,
        "time_data_s": t_data,
        "time_selection_s": reductor.timings_["selection"],
        "time_fit_s": reductor.timings_["fit"],
    }


def run_wave(preset: WavePreset, seed: int = 0, **overrides) -> dict:
    """Run the whole pipeline; ``overrides`` replace preset fields (e.g. ``n_reduced=5, n_modes=5``)."""
    preset = replace(preset, **overrides) if overrides else preset
    fom, rom, energy, basis_info = build_rom(preset, seed)
    rng = np.random.default_rng(seed + 1000)
    test_speeds = np.sort(rng.uniform(0.2, 0.3, preset.n_test_speeds))
    test_x0 = {
        c: rom.system.sample_energy_ellipsoid(preset.n_test_ics, c**2, energy, seed=seed + 2000 + i)
        for i, c in enumerate(test_speeds)
    }
    per_dt = []
    for j, dt in enumerate(preset.dts):
        trained = train_wave_predictor(rom, preset, dt, energy, seed=seed + 10 * j)
        model = trained["model"]
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
            cases.append(
                {
                    "c": float(c),
                    "t": dt * np.arange(n_steps + 1),
                    "err": err,
                    "time_kernel_s": t_kernel,
                    "time_rom_im_s": t_im,
                    "time_fom_ref_s": t_fom,
                }
            )
        per_dt.append({"dt": dt, "cases": cases, **trained})

    x0_all = np.concatenate([test_x0[c] for c in test_speeds])
    mu_all = np.repeat(test_speeds**2, preset.n_test_ics)
    first = per_dt[0]
    k = first["model"].kernel_
    d = first["data"]
    t0 = time.perf_counter()
    with logger.block("wave peers: direct kernel model and pyMOR VKOGA on the same reduced data"):
        direct = DirectKernelPredictor(
            k.state, k.mu, None, max_centers=preset.max_centers, trainer=ExactGreedy(tol=1e-10)
        ).fit(d.x0, d.x1, mu=d.mu, dt=d.dt)
        t_direct = time.perf_counter() - t0
        vsel = select_vkoga_length_scale(
            d, first["validation"], preset.vkoga_length_scales, m_star=min(50, preset.vkoga_centers)
        )
        vkoga = VKOGAFlowMap(max_centers=preset.vkoga_centers, length_scale=vsel["length_scale"]).fit(
            d.x0, d.x1, mu=d.mu, dt=d.dt
        )
    speed = run_wave_speed_accuracy(
        fom,
        rom,
        first["model"],
        x0_all,
        mu_all,
        preset.dts[0],
        preset.horizon,
        centers=preset.speed_centers,
        refinements=preset.speed_refinements,
        repeats=preset.speed_repeats,
        direct=direct,
        vkoga=vkoga,
        threads=preset.speed_threads,
        explicit_refinements=preset.fom_explicit_refinements,
    )
    speed["time_fit_direct_s"], speed["time_fit_vkoga_s"] = t_direct, vkoga.fit_time_s_
    speed["vkoga_selection"] = vsel
    sizing = smallest_wave_model(preset, preset.target_accuracy, preset.dts[0], seed=seed, trained=per_dt[0])

    summary = {
        "preset": asdict(preset),
        "seed": seed,
        "basis": basis_info,
        "test_speeds": test_speeds.tolist(),
        "per_dt": [
            {
                "dt": r["dt"],
                "n_samples": r["n_samples"],
                "kernel": {
                    "state": repr(r["selection"].state),
                    "mu": repr(r["selection"].mu),
                    "E_val_m_star": r["selection"].score,
                },
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
    summary["speed_accuracy"] = speed
    summary["smallest"] = {k: v for k, v in sizing.items() if k not in ("model", "rom")}
    return {"summary": summary, "per_dt": per_dt, "fom": fom, "rom": rom, "speed_accuracy": speed, "smallest": sizing}


def run_wave_speed_accuracy(
    fom: WaveFOM,
    rom: SymplecticROM,
    model: SymplecticKernelPredictor,
    x0_red,
    mu,
    dt: float,
    horizon: float,
    centers=(50, 100, 200, 400, 800, 1500),
    refinements=(1, 2, 4, 8),
    repeats: int = 3,
    direct: Optional[DirectKernelPredictor] = None,
    vkoga=None,
    threads: int = 1,
    explicit_refinements=None,
) -> dict:
    """Online wall time per trajectory against accuracy: FOM vs ROM vs ROM + data-driven maps, timed side by side.

    Every method starts from the same full states ``V x0_red`` and returns full
    states on the macro grid ``t_k = k dt``; errors are relative to the FOM's
    exact solution (sine transform), so the FOM's own time-stepping error is
    measured too.  Timing by :mod:`sympredict_paper.speed` (warm-up, medians, ``threads``).

    * the equations (FOM): the micro-step reference (implicit midpoint, ``h <= 1e-3``,
      sparse LU), implicit midpoint (sparse LU) and the compiled Störmer–Verlet,
      Yoshida-4 and Kahan–Li-6 at ``dt / r`` for each ``r`` in ``explicit_refinements``
      (default ``refinements``; the explicit schemes are stable only below the CFL limit);
    * the reduced operator (intrusive ROM): compiled implicit midpoint at ``dt / r`` and
      the exact propagator (matrix exponential, the reduction's error floor),
      with projection and reconstruction;
    * only data (and the basis ``V`` for projection and reconstruction): ROM + kernel at each
      number of ``centers`` (prefixes of ``model``), ROM + ``direct`` model and ROM + ``vkoga``.

    Parameters
    ----------
    x0_red : ndarray of shape (B, 2n)
        Reduced initial states.
    mu : ndarray of shape (B,)
        Parameters ``c^2`` per instance.

    Returns
    -------
    dict
        ``rows`` (``method``, ``size``, ``tag``, ``needs``, ``time_per_trajectory_s``,
        ``median_err``, ``max_err``), ``reference_time_s``, ``dt``, ``n_steps``,
        ``n_trajectories``, ``repeats``, ``threads``.
    """
    x0_red = np.asarray(x0_red, dtype=float)
    mu = np.asarray(mu, dtype=float)
    batch = len(x0_red)
    n_steps = int(np.floor(horizon / dt + 1e-9))
    x0_full = rom.reconstruct(x0_red)
    exact = fom.exact_trajectory(x0_full, mu, dt, n_steps)

    def reduced(run):  # projection before, reconstruction after: part of the timed work
        return lambda: rom.reconstruct(run(rom.project(x0_full)))

    # small models may wander off the training states: the chart's errors say so, no warning per rollout
    with (
        logger.block(
            f"wave speed against accuracy: {batch} trajectories x {n_steps} steps of dT = {dt}, {repeats} repeats"
        ),
        deliberate_threads(threads),
        extrapolation_expected(),
    ):
        table = SpeedTable(exact, repeats)
        ref_row = table.add(
            "FOM micro-step reference", 0, "h<=1e-3", "equations", lambda: fom.trajectory(x0_full, mu, dt, n_steps)
        )
        for r in refinements:
            table.add(
                "FOM implicit midpoint",
                r,
                f"dT/{r}",
                "equations",
                lambda r=r: fom.trajectory(x0_full, mu, dt, n_steps, h_max=dt / r),
            )
        add_classical(
            table,
            fom,
            x0_full,
            mu,
            dt,
            n_steps,
            refinements if explicit_refinements is None else explicit_refinements,
            EXPLICIT_SCHEMES,
        )
        for r in refinements:
            table.add(
                "ROM implicit midpoint (compiled)",
                r,
                f"dT/{r}",
                "reduced operator",
                reduced(lambda x, r=r: rollout(rom.system, x, mu, dt, n_steps, scheme="implicit_midpoint", substeps=r)),
            )
        table.add(
            "ROM exact propagator (expm)",
            0,
            "exact",
            "reduced operator",
            reduced(lambda x: rom.system.trajectory(x, mu, dt, n_steps, exact=True)),
        )
        for m in model_sizes(centers, model.n_centers_):
            small = timed(model.truncated(m))
            table.add(
                "ROM + kernel predictor",
                m,
                f"m={m}",
                "data",
                reduced(lambda x, small=small: small.rollout(x, n_steps, mu=mu)),
            )
        table.add_model(
            "ROM + direct kernel model (NumPy)", direct, reduced(lambda x: direct.rollout(x, n_steps, mu=mu))
        )
        table.add_model("ROM + pyMOR VKOGA (NumPy)", vkoga, reduced(lambda x: vkoga.rollout(x, n_steps, mu=mu, dt=dt)))
    return {
        "dt": dt,
        "n_steps": n_steps,
        "n_trajectories": batch,
        "repeats": repeats,
        "threads": threads,
        "reference_time_s": ref_row["time_per_trajectory_s"],
        "error_reference": "the FOM's exact solution (sine transform)",
        "rows": table.rows,
    }


def _full_space_error(rom: SymplecticROM, traj_red: np.ndarray, exact: np.ndarray) -> float:
    """Time- and instance-mean relative error of ``V traj_red`` against full trajectories ``exact``."""
    return float(relative_trajectory_error(rom.reconstruct(traj_red), exact)[:, 1:].mean())


def smallest_wave_model(
    preset: WavePreset,
    target: float,
    dt: float,
    seed: int = 0,
    rom_share: float = 0.5,
    n_validation: int = 12,
    n_max: int | None = None,
    trained: dict | None = None,
) -> dict:
    """No bigger model than the case needs: the smallest reduced dimension, then the fewest centres, meeting ``target``.

    Accuracy is the mean relative error over time of full-space trajectories
    against the FOM's exact solution, on validation trajectories disjoint from
    training and test data: ``n_validation`` FOM states in the first
    ``preset.n_modes`` sine modes (energy bound as for the snapshots) at random
    speeds in ``[0.2, 0.3]``, over ``[0, preset.horizon]`` with macro step ``dt``.

    1. Reduced dimension: for ``n = 1, 2, ...`` the complex-SVD basis of the
       snapshots; the first ``n`` whose exact reduced flow, reconstructed, is
       within ``rom_share * target`` (the rest of the budget is the kernel's).
    2. Centres: a predictor for that ROM (:func:`train_wave_predictor`; ``trained``
       is reused when it was built for a ROM of the same dimension); among
       prefixes of its greedy expansion on a logarithmic grid of sizes, the
       smallest whose validation error is ``<= target``.

    Returns
    -------
    dict
        ``target``, ``n_reduced``, ``rom_errors`` (error per tried ``n``),
        ``n_centers`` (None if unreached), ``validation_error`` (of the chosen
        model, or of the largest one if unreached), ``center_errors`` (size ->
        error on the grid), ``test_error`` (the same measure on fresh trajectories),
        ``reached`` (bool), and the chosen ``model`` and ``rom``.

    Raises
    ------
    ValueError
        For a non-positive target or when no reduced dimension up to ``n_max``
        (default: the snapshots' numerical rank, at most 20) meets ``rom_share * target``.
    """
    if not (np.isfinite(target) and target > 0):
        raise ValueError(f"target must be a positive float, got {target!r}")
    if not (0 < rom_share < 1):
        raise ValueError(f"rom_share must lie in (0, 1), got {rom_share!r}")
    fom, snapshots, energy, _ = fom_snapshots(preset, seed)
    rng = np.random.default_rng(seed + 7000)
    speeds = rng.uniform(0.2, 0.3, n_validation)
    x0 = np.concatenate(
        [fom.low_frequency_states(1, preset.n_modes, c**2, energy, seed=seed + 7001 + i) for i, c in enumerate(speeds)]
    )
    mu = speeds**2
    n_steps = int(np.floor(preset.horizon / dt + 1e-9))
    exact = fom.exact_trajectory(x0, mu, dt, n_steps)
    rom_errors = {}
    rom = None
    n_max = n_max or 20
    with logger.block(f"smallest model for target {target:.1e}: reduced dimension"):
        for n in range(1, n_max + 1):
            try:
                basis = complex_svd_basis(snapshots, n=n, layout="rows")
            except ValueError:  # beyond the numerical rank of the snapshots
                break
            candidate = SymplecticROM(fom, basis)
            err = _full_space_error(
                candidate, candidate.system.trajectory(candidate.project(x0), mu, dt, n_steps, exact=True), exact
            )
            rom_errors[n] = err
            logger.info(f"2n = {2 * n}: reduction error {err:.2e}")
            if err <= rom_share * target:
                rom = candidate
                break
    if rom is None and not rom_errors:
        raise ValueError("the snapshots have numerical rank 0: no reduced basis exists")
    if rom is None:
        raise ValueError(
            f"no reduced dimension up to 2n = {2 * max(rom_errors)} reaches {rom_share * target:.1e} "
            f"(best {min(rom_errors.values()):.1e}): more snapshots or a looser target"
        )
    if trained is None or trained["model"].dim_ != rom.dim:
        trained = train_wave_predictor(rom, preset, dt, energy, seed=seed + 8000)
    model = trained["model"]
    x0_red = rom.project(x0)
    sizes = np.unique(np.round(np.geomspace(min(10, model.n_centers_), model.n_centers_, 24)).astype(int))
    center_errors = {}
    chosen = None
    with logger.block(f"smallest model: fewest centres (of {model.n_centers_}) for target {target:.1e}"):
        for m in sizes:
            small = model.truncated(int(m))
            with extrapolation_expected():  # too small a model may leave the training states: its error decides
                center_errors[int(m)] = _full_space_error(rom, small.rollout(x0_red, n_steps, mu=mu), exact)
            if center_errors[int(m)] <= target:
                chosen = small
                break
    reached = chosen is not None
    last = int(m)
    # the choice used validation data only: report its error on fresh trajectories too
    speeds_test = rng.uniform(0.2, 0.3, n_validation)
    x0_test = np.concatenate(
        [
            fom.low_frequency_states(1, preset.n_modes, c**2, energy, seed=seed + 9001 + i)
            for i, c in enumerate(speeds_test)
        ]
    )
    final = chosen if reached else model
    test_error = _full_space_error(
        rom,
        final.rollout(rom.project(x0_test), n_steps, mu=speeds_test**2),
        fom.exact_trajectory(x0_test, speeds_test**2, dt, n_steps),
    )
    logger.info(
        f"smallest model: 2n = {rom.dim}, {final.n_centers_} centres, validation error {center_errors[last]:.2e}, "
        f"test error {test_error:.2e} (target {target:.1e}{'' if reached else ', NOT reached'})"
    )
    return {
        "target": target,
        "dt": dt,
        "rom_share": rom_share,
        "n_reduced": rom.dim // 2,
        "rom_errors": {str(k): v for k, v in rom_errors.items()},
        "n_centers": chosen.n_centers_ if reached else None,
        "of_centers": model.n_centers_,
        "validation_error": center_errors[last],
        "test_error": test_error,
        "center_errors": {str(k): v for k, v in center_errors.items()},
        "reached": reached,
        "kernel": {"state": repr(model.kernel_.state), "mu": repr(model.kernel_.mu)},
        "model": chosen if reached else model,
        "rom": rom,
    }


#: ``python -m sympredict_paper.wave [OPTIONS]``: ``sympredict-paper run wave [OPTIONS]``.
main = scenario_main("wave")


if __name__ == "__main__":
    raise SystemExit(main())
