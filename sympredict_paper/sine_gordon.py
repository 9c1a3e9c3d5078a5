"""Sine-Gordon MOR end to end: FOM, symplectic Galerkin and DEIM ROMs, learned reduced flow maps.

:func:`run_sine_gordon` returns results (numbers and arrays), no figures:

* FOM trajectories (compiled Kahan–Li-6, step halving to ``ref_tol``) at a grid
  of training parameters and at random test parameters (never trained on); the
  initial-data family is the preset's ``initial`` (:func:`initial_states`):
  ``'sech_cos'`` (default): ``amplitude * sech(x/2) cos(x)``, parameters ``(c, amplitude)``;
  ``'breather'``: the breather of frequency ``omega`` at wave speed ``c`` at its zero
  crossing, parameters ``(c, omega)`` (time-periodic and localized: with ``T`` at least one
  period ``2 pi / omega`` the training snapshots hold the long-time states);
* a complex-SVD symplectic basis per ``2n`` from the training snapshots;
* per ``2n``: the errors against the FOM (mean over time of the relative
  error of the reconstructed state) of the Galerkin ROM (implicit midpoint with
  ``substeps`` sub-steps per output step: its own reference), the DEIM ROM
  (``m = deim_factor * 2n`` points), the kernel ROM learned from Galerkin
  trajectories (``'reduced'``) and from projected FOM trajectories
  (``'projected'``, non-intrusive), each a :class:`~sympredict.SymplecticKernelPredictor`
  with a kernel on ``c`` at the fixed macro step ``DT``, trained by ``SymplecticKernelReductor`` in the scaled
  coordinates of :mod:`sympredict.flowmap.scaling`, and RK4 / implicit
  midpoint on the Galerkin ROM at the same ``DT`` (one step per output);
* the energy error ``dx H(V y)`` of every ROM over ``long_factor * T`` per test parameter, with the projected
  FOM trajectories' own as a reference, and :func:`energy_boundedness` (the definition of "bounded" that
  ``report.sine_gordon_claims`` checks); the Galerkin-data kernel is trained with :class:`EnergySamples`
  (extra pairs from the energy sublevel set of the training states), see ``docs/explanation/sine_gordon.md``;
* the large-step regime at a ``DT_large`` chosen on the training trajectories (:func:`choose_large_step`);
* optionally (``kernel_split``, :func:`split_setup`) the Galerkin-data kernel as a
  :class:`~sympredict.flowmap.splitting.SplitKernelPredictor` ``L_h o S o L_h`` with ``L_h`` the exact flow of the reduced
  Hessian at 0: the fast linear modes of the Galerkin ROM are then rotated exactly, not interpolated;
* online wall times per trajectory (medians of ``repeats``, same process,
  BLAS on one thread): kernel rollout, Galerkin and DEIM ROMs at their
  accurate step, FOM; and the cost against ``N`` (:func:`_cost_vs_N`): for
  each ``N`` of ``cost_N`` every ROM is built again at that ``N`` (basis,
  Galerkin, DEIM, both kernel ROMs) and timed, the reconstruction ``V y``
  separately; :func:`break_even` gives the kernel's flatness in ``N`` and the
  break-even ``N`` against the compiled Galerkin ROM per ``2n``.

The learned ROMs go through the library's ``sympredict.mor.SymplecticKernelReductor``
(:func:`sine_gordon_reductor`): the FOM's pyMOR model and the basis, the experiment's reduced pairs
as ``data``, the flow map taking ``c`` only, the split as ``split``, and the ridge term chosen by
rollouts on held-out training trajectories (``regularizations``, ``validation_data``).
"""

from __future__ import annotations

import time
from functools import partial
from dataclasses import asdict, dataclass, replace

import numpy as np
from pymor.core.logger import getLogger

from sympredict_paper import scenario_main
from sympredict_paper.presets import load_presets
from sympredict_paper.speed import time_median
from sympredict.systems.flowmaps import midpoint_sigma_min, type2_sigma_min
from sympredict.kernels import IMQ
from sympredict.symplectic.metrics import canonical_J, relative_trajectory_error
from sympredict.mor.nonlinear import ReducedSineGordon, nonlinear_snapshots
from sympredict.data import FlowMapData, TrajectoryData
from sympredict.estimators.predictor import SymplecticKernelPredictor
from sympredict.mor.basis import complex_svd_basis, pymor_basis, symplecticity_of_basis
from sympredict.mor import GivenSamples, QuadraticSplit, SymplecticKernelReductor, TrainingScaling, ValidationSelection
from sympredict.flowmap.scaling import BoxScaling
from sympredict.systems.sine_gordon import SineGordonFOM
from sympredict.interpolation.greedy import ExactGreedy

__all__ = [
    "SineGordonPreset",
    "PRESETS",
    "run_sine_gordon",
    "fom_data",
    "initial_states",
    "second_parameter",
    "energy_boundedness",
    "ENERGY_BOUND_RATIO",
    "ENERGY_BOUND_FLOOR",
    "EnergySamples",
    "split_setup",
    "sign_symmetry",
    "no_augmentation",
    "choose_large_step",
    "sine_gordon_reductor",
]

logger = getLogger("sympredict_paper.sine_gordon")


@dataclass(frozen=True)
class SineGordonPreset:
    """Sizes of one run (``quick``: minutes on 2 cores; ``paper``: the issue's sizes)."""

    n_points: int = 1000
    length: float = 20.0
    c_range: tuple = (0.8, 1.2)
    amplitude_range: tuple = (0.5, 1.5)
    n_c: int = 4  # 4 x 4 training trajectories and 1,000 centres: the largest measured size within the --quick budget
    #: training values of the second parameter (amplitude for 'sech_cos', omega for 'breather')
    n_amplitude: int = 4
    #: initial-data family (initial_states): 'sech_cos' (parameters c, amplitude) or 'breather' (c, omega)
    initial: str = "sech_cos"
    #: breather frequencies (units of sqrt(s) = 1): period 2 pi / omega, amplitude max |u| = 4 arctan(sqrt(1 - w^2) / w)
    omega_range: tuple = (0.6, 0.9)
    n_test: int = 3
    T: float = 5.0
    DT: float = 0.1
    long_factor: int = 10
    dims: tuple = (8, 12)
    deim_factor: int = 2
    substeps: int = 4
    max_centers: int = 1000
    #: the learned maps' update at DT ("symplectic_euler": the paper's type-II form; "midpoint": the symmetric form)
    kernel_update: str = "symplectic_euler"
    #: the Galerkin-data kernel as L_h o S o L_h (split_setup): "none", "quadratic" (L_h the exact flow of the reduced
    #: quadratic part of H) or "quadratic-mass" (plus the linearised 1 - cos q: the reduced Hessian at 0)
    kernel_split: str = "none"
    #: with a split: the Galerkin data's implicit-midpoint sub-steps keep the phase error of the fastest linear mode
    #: below this many radians per DT (the data must be the flow that L_h splits exactly)
    split_phase_tol: float = 0.1
    state_eps: float = None  # None: IMQ(1 / diameter of the training xi), the estimator's default
    mu_eps: float = 1.0  # on c scaled to [0, 1]
    state_scaling: str = "diag"
    #: ridge terms tried on held-out training trajectories (plus 0, the exact fit); () for the exact fit only
    regularizations: tuple = (1e-8, 1e-6, 1e-4)
    validation_every: int = 4
    #: extra pairs for the Galerkin-data kernel: 'energy' (EnergySamples: states with H <= max training energy,
    #: stepped by the Galerkin ROM), 'energy-box', 'symmetry' (u -> -u) or 'none'; for the FOM-data kernel
    #: 'symmetry' or 'none' (non-intrusive: no new FOM data)
    reduced_augment: str = "energy"
    projected_augment: str = "none"
    energy_samples_per_pair: float = 1.0
    #: the large-step regime: macro step large_step * DT (0: not run)
    large_step: int = 10
    #: further large steps tried by choose_large_step (on the training trajectories; () : large_step only)
    large_step_candidates: tuple = (15, 20)
    #: choose_large_step: the classical/floor ratio wanted on the training trajectories (10x plus 20 % for the
    #: kernel's distance above the floor) and the smallest admissible sigma_min((I + M) / 2)
    large_step_margin: float = 12.0
    large_step_sigma_min: float = 0.1
    #: the large-step FOM-data kernel as L_h o S o L_h (as kernel_split: "none", "quadratic", "quadratic-mass"); a
    #: split needs the reduced operator A_r(c) = V^T A(c) V, so the kernel is then no longer non-intrusive;
    #: "auto": the unsplit kernel where the training-only rule finds a step with the margin, else the split one
    #: (_choose_large_step_split)
    large_step_split: str = "none"
    ref_tol: float = 1e-7
    cost_N: tuple = (1000, 4000, 16000)
    repeats: int = 5
    seed: int = 0


#: ``quick``, ``paper``, ``smoke`` and the breather family's ``breather``, ``smoke-breather`` (why these sizes:
#: the comments in sympredict_paper/presets/sine_gordon.toml)
PRESETS = load_presets("sine_gordon", SineGordonPreset)


def second_parameter(p: SineGordonPreset) -> tuple:
    """Name and range of the initial family's parameter besides ``c``: ``('amplitude', amplitude_range)`` for
    ``'sech_cos'``, ``('omega', omega_range)`` for ``'breather'``."""
    if p.initial == "sech_cos":
        return "amplitude", tuple(p.amplitude_range)
    if p.initial == "breather":
        return "omega", tuple(p.omega_range)
    raise ValueError(f"initial must be 'sech_cos' or 'breather', got {p.initial!r}")


def initial_states(fom, p: SineGordonPreset, c, s) -> np.ndarray:
    """Initial states (B, 2N) of the preset's family at wave speeds ``c`` (B,) and second parameters ``s`` (B,).

    ``'sech_cos'``: ``s * sech(x/2) cos(x)``, ``p = 0`` (the same shape for every ``c``); ``'breather'``:
    :meth:`~sympredict.systems.sine_gordon.SineGordonFOM.breather` at ``(c, omega = s)`` (``q = 0``, the exact
    breather's velocity at its zero crossing, width ``c / sqrt(1 - omega^2)``, centred).  ``O(B N)``.
    """
    c, s = np.atleast_1d(np.asarray(c, dtype=float)), np.atleast_1d(np.asarray(s, dtype=float))
    second_parameter(p)  # validates p.initial
    if p.initial == "breather":
        return np.stack([fom.breather(ci, si) for ci, si in zip(c, s)])
    return s[:, None] * fom.sech_cos(2.0, 1.0)[None, :]


def fom_data(p: SineGordonPreset) -> dict:
    """The FOM, the training and test parameters and the FOM trajectories of a run (what
    :func:`run_sine_gordon` and the benchmarks share).

    Training parameters: ``n_c x n_amplitude`` grid of ``c`` and the second parameter; test parameters:
    ``n_test`` uniform draws (seed ``p.seed``, never trained on).  FOM trajectories by
    :meth:`~sympredict.systems.sine_gordon.SineGordonFOM.reference_trajectory` (step halving to ``ref_tol``):
    ``X_tr`` (P, K+1, 2N) over ``[0, T]``, ``X_te`` (B, long_factor K + 1, 2N) over ``[0, long_factor T]``.
    Returns a dict with ``fom, K, name2, c_tr, a_tr, c_te, a_te, X_tr, X_te, step_halving_estimate,
    train_time``.  Cost: ``(P + long_factor B) K`` FOM steps of ``O(N)`` times the sub-steps.
    """
    rng = np.random.default_rng(p.seed)
    fom = SineGordonFOM(
        n_points=p.n_points,
        length=p.length,
        c_range=p.c_range,
        amplitude_range=p.amplitude_range,
        T=p.T,
        nt=int(round(p.T / p.DT)),
    )
    K = int(round(p.T / p.DT))
    name2, range2 = second_parameter(p)
    # a_tr, a_te: the second parameter (amplitude or omega)
    c_tr = np.repeat(np.linspace(*p.c_range, p.n_c), p.n_amplitude)
    a_tr = np.tile(np.linspace(*range2, p.n_amplitude), p.n_c)
    c_te = rng.uniform(*p.c_range, p.n_test)
    a_te = rng.uniform(*range2, p.n_test)
    t = time.perf_counter()
    X_tr, est = fom.reference_trajectory(
        initial_states(fom, p, c_tr, a_tr), c_tr, p.DT, K, tol=p.ref_tol, return_error=True
    )
    train_time = time.perf_counter() - t
    X_te = fom.reference_trajectory(initial_states(fom, p, c_te, a_te), c_te, p.DT, p.long_factor * K, tol=p.ref_tol)
    return {
        "fom": fom,
        "K": K,
        "name2": name2,
        "c_tr": c_tr,
        "a_tr": a_tr,
        "c_te": c_te,
        "a_te": a_te,
        "X_tr": X_tr,
        "X_te": X_te,
        "step_halving_estimate": est,
        "train_time": train_time,
    }


def run_sine_gordon(preset: SineGordonPreset = PRESETS["quick"], **overrides) -> dict:
    """Run the scenario; returns a JSON-friendly dict (lists and floats; the figures are drawn from it)."""
    from threadpoolctl import threadpool_limits

    p = replace(preset, **overrides)
    with threadpool_limits(1):
        d = fom_data(p)
        fom, K, name2 = d["fom"], d["K"], d["name2"]
        c_tr, a_tr, c_te, a_te, X_tr, X_te = (d[k] for k in ("c_tr", "a_tr", "c_te", "a_te", "X_tr", "X_te"))
        out = {
            "preset": asdict(p),
            "second_parameter": name2,
            "test_c": c_te.tolist(),
            f"test_{name2}": a_te.tolist(),
            "dims": {},
        }
        out["fom_train_time"] = d["train_time"]
        out["fom_step_halving_estimate"] = d["step_halving_estimate"]
        x0_te = X_te[:, 0]
        x_te = X_te[:, : K + 1]
        out["fom_time_per_trajectory"] = time_median(
            lambda: fom.reference_trajectory(x0_te[:1], c_te[:1], p.DT, K, tol=p.ref_tol), max(1, p.repeats // 2)
        )[0]
        snaps = X_tr.reshape(-1, fom.dim)
        for dim in p.dims:
            out["dims"][dim] = _one_dimension(fom, p, dim // 2, snaps, X_tr, c_tr, a_tr, X_te, c_te, a_te, K)
        out["cost_vs_N"] = _cost_vs_N(fom, p, out, X_tr, c_tr, x_te, c_te)
        out["break_even"] = break_even(out["cost_vs_N"], {d: r["DT_omega_max"] for d, r in out["dims"].items()})
    return out


def _curve(rom, Y, X):
    """Relative error of the reconstruction over time, mean over the test trajectories (K+1,)."""
    return relative_trajectory_error(rom.reconstruct(Y), X).mean(axis=0)


def failure_text(exc: BaseException) -> str:
    """A failed fit or rollout as a result: the exception's type and message, at most 300 characters."""
    return f"{type(exc).__name__}: {exc}"[:300]


def _err(rom, Y, X):
    """Mean over time of the relative error of the reconstruction, per test trajectory (B,)."""
    return relative_trajectory_error(rom.reconstruct(Y), X).mean(axis=1)


def _energy_errors(rom, Y, c):
    """``|E(t) - E(0)| / |E(0)|``, ``E = dx H(V y)``, per test trajectory over time (B, K+1)."""
    E = rom.reduced_energy(Y.reshape(-1, rom.dim), np.repeat(c, Y.shape[1])).reshape(len(c), -1)
    return np.abs(E - E[:, :1]) / np.abs(E[:, :1])


#: "bounded over 10 T" (:func:`energy_boundedness`): the max energy error over (T, 10 T] at most this
#: multiple of its max over [0, T] (fixed before the runs; a symplectic map's energy error oscillates at a level
#: set by its step, which [0, T] samples already)
ENERGY_BOUND_RATIO = 3.0
#: ... where the [0, T] level counts as at least this relative energy error (0.1 %: far below the ROMs' state
#: errors of 4-15 %; below it the level of an O(h^2) error depends on which states a trajectory visits)
ENERGY_BOUND_FLOOR = 1e-3


def energy_boundedness(err, n_train: int, ratio: float = ENERGY_BOUND_RATIO, floor: float = ENERGY_BOUND_FLOOR) -> dict:
    """Whether energy-error series stay bounded beyond the training horizon, per series.

    ``err`` (B, L+1) or (L+1,): ``|E(t_k) - E(0)| / |E(0)|`` on a uniform grid whose first ``n_train`` steps are
    the training horizon ``[0, T]``.  With ``m0`` the max over ``[0, T]``, ``m = max(m0, floor)`` and the windows
    of ``n_train`` steps after ``T``, a series is **bounded** iff

    0. ``m0 < 1`` (a ROM whose energy error already reaches 100 % on ``[0, T]`` has blown up there),
    1. ``max over (T, t_L] <= ratio * m`` (the later error stays at the level seen on the training horizon), and
    2. no secular growth: the least-squares line through the window maxima (against the window ends) rises
       by at most ``(ratio - 1) m`` from the first to the last window (a steady drift whose fitted envelope
       ends above ``ratio * m`` fails even where the measured maxima have not crossed 1. yet).

    Two oracle failures set ``floor`` and the threshold of 2.: the Galerkin ROM (implicit midpoint, whose
    energy error a symplectic integrator keeps bounded by backward error analysis) has ``m0 ~ 1e-5``; in the
    ``--quick`` run its envelope rose by ``1.03 m0`` at ``2n = 12`` (with a first threshold of ``m0``), and in the
    20-trajectory run its max after ``T`` was ``4.6 m0`` at ``2n = 8``: an ``O(h^2)`` error's level depends on
    the states visited, which change after ``T``.  Hence the floor: an energy error below ``floor`` counts as
    conserved.

    A non-finite value fails.  Returns per series ``m0``, ``max_after`` (the max over ``(T, t_L]``), ``ratio``
    (``max_after / m``), ``rise`` (of the fitted envelope, in units of ``m``; ``None`` with fewer than two
    windows) and ``bounded``, plus ``all_bounded``.  ``O(L)`` per series.
    """
    e = np.atleast_2d(np.asarray(err, dtype=float))
    n_train = int(n_train)
    if n_train < 1 or e.shape[1] <= n_train + 1:
        raise ValueError(
            f"need n_train >= 1 and a series longer than n_train + 1 points, got n_train = {n_train}, "
            f"length {e.shape[1]}"
        )
    out = {"m0": [], "max_after": [], "ratio": [], "rise": [], "bounded": []}
    for row in e:
        finite = bool(np.all(np.isfinite(row)))
        m0 = float(np.max(row[: n_train + 1])) if finite else np.inf
        m = max(m0, float(floor), 1e-300)
        after = row[n_train + 1 :]
        n_w = len(after) // n_train
        wmax = [float(np.max(after[w * n_train : (w + 1) * n_train])) for w in range(n_w)] if finite else []
        rise = None
        if len(wmax) >= 2:
            ends = n_train * (np.arange(len(wmax)) + 2.0)
            slope = np.polyfit(ends, wmax, 1)[0]
            rise = float(slope * (ends[-1] - ends[0]) / m)
        m_after = float(np.max(after)) if finite else np.inf
        out["m0"].append(m0)
        out["max_after"].append(m_after)
        out["ratio"].append(m_after / m)
        out["rise"].append(rise)
        out["bounded"].append(
            bool(finite and m0 < 1.0 and m_after <= ratio * m and (rise is None or rise <= ratio - 1.0))
        )
    out["all_bounded"] = all(out["bounded"])
    return out


def _one_dimension(fom, p, n, snaps, X_tr, c_tr, a_tr, X_te, c_te, a_te, K):
    basis = complex_svd_basis(snaps, n=n, layout="rows")
    res = {"projection_error": basis.projection_error, "symplecticity": symplecticity_of_basis(basis.V)}
    gal = ReducedSineGordon.galerkin(fom, basis.V)
    deim = ReducedSineGordon.deim(fom, basis.V, nonlinear_snapshots(fom, X_tr), p.deim_factor * 2 * n)
    x_te = X_te[:, : K + 1]
    y0 = gal.project(X_te[:, 0])
    t = p.DT * np.arange(K + 1)
    t_long = p.DT * np.arange(p.long_factor * K + 1)
    curves = {"t": t.tolist()}
    energy = {"t": t_long.tolist()}
    snap_k = [0, K // 2, K]
    snapshots = {
        "t": [float(t[k]) for k in snap_k],
        "x": fom.x.tolist(),
        "fom": x_te[0, snap_k, : fom.n_points].tolist(),
    }
    Yg = gal.solve(y0, c_te, p.DT, p.long_factor * K, substeps=p.substeps)
    res["galerkin_error"] = _err(gal, Yg[:, : K + 1], x_te).tolist()
    curves["galerkin"] = _curve(gal, Yg[:, : K + 1], x_te).tolist()
    # energy errors per test trajectory over 10 T (the boundedness claim, energy_boundedness) and their max (figure)
    energy_per_test = {"galerkin": _energy_errors(gal, Yg, c_te)}
    # the projected FOM test trajectories' own energy drift (diagnostic, never a choice): the FOM-data kernel learns
    # the map between projected states, so this is the energy error of an exact such map over 10 T
    energy_per_test["projected_fom"] = _energy_errors(gal, gal.project(X_te), c_te)
    energy["galerkin"] = energy_per_test["galerkin"].max(axis=0).tolist()
    energy["projected_fom"] = energy_per_test["projected_fom"].max(axis=0).tolist()
    res["galerkin_energy_error_long"] = max(energy["galerkin"])
    snapshots["galerkin"] = gal.reconstruct(Yg[0, snap_k])[:, : fom.n_points].tolist()
    Yd = deim.solve(y0, c_te, p.DT, K, substeps=p.substeps)
    res["deim_error"] = _err(deim, Yd, x_te).tolist()
    curves["deim"] = _curve(deim, Yd, x_te).tolist()
    snapshots["deim"] = deim.reconstruct(Yd[0, snap_k])[:, : fom.n_points].tolist()
    res["deim_points"] = deim.n_interpolation
    # classical schemes on the Galerkin ROM at the macro step DT (one step per output)
    for scheme in ("rk4", "implicit_midpoint"):
        try:
            Y = gal.solve(y0, c_te, p.DT, K, scheme=scheme, substeps=1)
            res[f"galerkin_{scheme}_at_DT_error"] = _err(gal, Y, x_te).tolist()
            curves[f"galerkin_{scheme}_at_DT"] = _curve(gal, Y, x_te).tolist()
        except Exception as exc:  # a Newton failure is a result here
            res[f"galerkin_{scheme}_at_DT_error"] = f"failed: {type(exc).__name__}"
    # linearized frequencies of the reduced system at the largest c: eigenvalues i omega of J dg(y0)
    res["DT_omega_max"] = float(p.DT * np.abs(np.linalg.eigvals(_jg(gal, y0[0], float(p.c_range[1])))).max())
    # learned reduced flow maps: data from Galerkin trajectories (intrusive) or projected FOM trajectories
    split = split_setup(p, gal)
    if split["quadratic"] is not None:  # the Galerkin ROM with the data's sub-steps (the flow the split kernel learns)
        res["galerkin_error_split_substeps"] = _err(
            gal, gal.solve(y0, c_te, p.DT, K, substeps=split["substeps"]), x_te
        ).tolist()
    Yg_tr = gal.solve(gal.project(X_tr[:, 0]), c_tr, p.DT, K, substeps=split["substeps"])
    Yp_tr = gal.project(X_tr)
    for data, Ytr in (("reduced", Yg_tr), ("projected", Yp_tr)):
        quad = split["quadratic"] if data == "reduced" else None
        flow, model, fit_time, reg, table = _fit_kernel(
            p,
            Ytr[:, :-1],
            Ytr[:, 1:],
            c_tr,
            p.DT,
            update=p.kernel_update,
            augment=_augmentation(split["preset"], data, gal),
            quadratic=quad,
            gal=gal,
        )
        hist = model.history_.train_max_residual
        entry = {
            "fit_time": fit_time,
            "update": getattr(model, "predictor_", model).update,
            "regularization": reg,
            "regularization_table": table,
            "centers": int(model.n_centers_),
            "train_residual": [float(v) for v in hist],
            "error": None,
            "energy_error_long": None,
            "time_per_trajectory": None,
            "failure": None,
        }
        if data == "reduced":
            entry.update(split={k: v for k, v in split.items() if k not in ("quadratic", "preset")})
        try:
            Yk = flow.rollout(y0, p.long_factor * K, mu=c_te[:, None], dt=p.DT)
            entry["error"] = _err(gal, Yk[:, : K + 1], x_te).tolist()
            curves[f"kernel_{data}"] = _curve(gal, Yk[:, : K + 1], x_te).tolist()
            energy_per_test[f"kernel_{data}"] = _energy_errors(gal, Yk, c_te)
            energy[f"kernel_{data}"] = energy_per_test[f"kernel_{data}"].max(axis=0).tolist()
            entry["energy_error_long"] = max(energy[f"kernel_{data}"])
            snapshots[f"kernel_{data}"] = gal.reconstruct(Yk[0, snap_k])[:, : fom.n_points].tolist()
            entry["time_per_trajectory"] = time_median(
                lambda: flow.rollout(y0[:1], K, mu=c_te[:1, None], dt=p.DT), p.repeats
            )[0]
        except Exception as exc:  # a failed rollout is a result, reported as such
            entry["failure"] = failure_text(exc)
        res[f"kernel_{data}"] = entry
    # pyMOR's DataDrivenReductor (VKOGA regressor, inputs scaled to the box): (c, amplitude) -> reduced trajectory,
    # trained on the same projected FOM trajectories (non-intrusive); it predicts on the training horizon only
    if p.large_step:
        res["large_step"] = _large_step(p, gal, X_tr, c_tr, X_te, c_te, K)
    res["data_driven"] = _data_driven(fom, p, Yp_tr, c_tr, a_tr, c_te, a_te, gal, x_te, K, curves)
    res["curves"], res["energy"], res["snapshots"] = curves, energy, snapshots
    res["energy_per_test"] = {k: v.tolist() for k, v in energy_per_test.items()}
    res["energy_bounded"] = {k: energy_boundedness(v, K) for k, v in energy_per_test.items()}
    for name, rom in (("galerkin", gal), ("deim", deim)):  # implicit midpoint (the default) and RK4
        for suffix, scheme in (("", {}), ("_rk4", {"scheme": "rk4"})):
            res[f"{name}{suffix}_time_per_trajectory"] = time_median(
                lambda: rom.solve(y0[:1], c_te[:1], p.DT, K, substeps=p.substeps, **scheme), p.repeats
            )[0]
    return res


def split_setup(p: SineGordonPreset, gal) -> dict:
    """The linear flow split off the Galerkin-data kernel (``p.kernel_split``) and the sub-steps of its data.

    ``'none'``: no split, the data with ``p.substeps`` implicit-midpoint sub-steps per ``DT`` (as the Galerkin
    reference).  ``'quadratic'`` / ``'quadratic-mass'``: the kernel ROM is ``L_h o S o L_h`` with
    ``L_h = expm(DT/2 J A(c))``, ``A(c)`` the reduced quadratic part of ``H`` without / with the linearised
    ``1 - cos q`` (:meth:`~sympredict.mor.nonlinear.ReducedSineGordon.quadratic_part`), and ``S`` learned.
    ``L_h`` is exact, so the data must be the Galerkin flow to an accuracy finer than the fast modes' turn: with
    ``omega`` the largest frequency of ``J A(c)`` over the ``c`` range, implicit midpoint with ``k`` sub-steps
    turns that mode by ``DT omega (DT omega / k)^2 / 12`` radians too little per ``DT``; ``k`` is the smallest
    count (at least ``p.substeps``) that keeps this below ``p.split_phase_tol``.  (Measured: with the data at
    ``p.substeps = 4`` and ``DT omega = 8.4``, the mismatch is 1.9 rad per step and the split kernel blows up;
    ``docs/explanation/sine_gordon.md``.)  Returns ``{"kind", "quadratic" (QuadraticPart or None), "substeps",
    "DT_omega_max_linear", "preset"}`` (``preset``: ``p`` with the data's sub-steps, for the energy samples).
    """
    if p.kernel_split == "none":
        return {
            "kind": "none",
            "quadratic": None,
            "substeps": int(p.substeps),
            "DT_omega_max_linear": None,
            "preset": p,
        }
    if p.kernel_split not in ("quadratic", "quadratic-mass"):
        raise ValueError(f"kernel_split must be 'none', 'quadratic' or 'quadratic-mass', got {p.kernel_split!r}")
    quad = gal.quadratic_part(mass=p.kernel_split == "quadratic-mass")
    JA = canonical_J(gal.dim) @ quad.hessian(np.asarray(p.c_range, dtype=float), 2)
    wdt = float(p.DT * np.abs(np.linalg.eigvals(JA)).max())
    k = max(int(p.substeps), int(np.ceil(wdt * np.sqrt(wdt / (12.0 * p.split_phase_tol)))))
    return {
        "kind": p.kernel_split,
        "quadratic": quad,
        "substeps": k,
        "DT_omega_max_linear": wdt,
        "preset": replace(p, substeps=k),
    }


def _pairs(Y0, Y1, c):
    """Flat pairs ``(x0, x1, mu)`` of ``P`` trajectories' pairs ``Y0, Y1`` (P, k, 2n) at wave speeds ``c`` (P,)."""
    dim = Y0.shape[-1]
    return Y0.reshape(-1, dim), Y1.reshape(-1, dim), np.repeat(np.asarray(c, dtype=float), Y0.shape[1])[:, None]


def no_augmentation(Y0, Y1, c):
    """The training pairs as they are: flat ``(x0, x1, mu)`` (``P k`` rows)."""
    return _pairs(Y0, Y1, c)


def sign_symmetry(Y0, Y1, c):
    """The pairs and their images under ``u -> -u`` (flat, ``2 P k`` rows).

    ``sin`` is odd, so ``x(t) -> -x(t)`` maps solutions of sine-Gordon to solutions at the same ``c``; the basis
    is linear (``V+ (-x) = -V+ x``), so the projected pairs ``(-y0, -y1)`` are exact samples of the same
    (projected) flow map: data only, no FOM evaluation and nothing beyond the training horizon.
    """
    x0, x1, mu = _pairs(Y0, Y1, c)
    return np.concatenate([x0, -x0]), np.concatenate([x1, -x1]), np.concatenate([mu, mu])


@dataclass
class EnergySamples:
    """Extra pairs of the Galerkin ROM (``data='reduced'``, intrusive): random reduced states ``y`` with
    ``dx H(V y; c) <= E_max`` (the largest energy of the training states), ``c`` uniform in ``c_range``, each
    stepped by the Galerkin ROM over ``DT`` (``substeps`` implicit-midpoint sub-steps).

    ``region='sublevel'`` (default): a direction ``d`` Gaussian in the coordinates where the quadratic part of
    ``H`` (``y^T (c^2 A1 + A2) y / 2``) is the Euclidean norm, scaled by bisection until ``dx H(r d) = U E_max``
    with ``U`` uniform in ``(0, 1]`` (``H`` grows along the ray while ``|V_q r d| < pi``; the bisection stays
    there): energy levels uniform up to ``E_max``.  ``region='box'``: uniform in the training states' bounding
    box, rejected where ``dx H > E_max``.

    Why: the Galerkin flow conserves ``H``, so the long-time reduced states of training-like initial states lie
    in ``{H <= E_max}``; the training trajectories over ``[0, T]`` cover a thin part of it, and the reduced
    dynamics leaves their box after ``T`` (mode amplitudes up to 1.5x the training maximum at ``2n = 8``,
    ``sympredict_paper/studies/sine_gordon_long_time.py``).  Uses the training states and energies only (no test data, no
    time beyond ``T``).  Cost: ``n_per_pair * P k`` Galerkin steps and ``O(60)`` energy evaluations per sample
    (``O(N n)`` each).  Returns the original pairs plus ``round(n_per_pair * P k)`` sampled ones, flat.
    """

    gal: object
    c_range: tuple
    dt: float
    substeps: int = 4
    n_per_pair: float = 1.0
    region: str = "sublevel"
    seed: int = 0

    def __call__(self, Y0, Y1, c):
        x0, x1, mu = _pairs(Y0, Y1, c)
        rng = np.random.default_rng(self.seed)
        states = np.concatenate([x0, x1])
        e_max = float(self.gal.reduced_energy(states, np.concatenate([mu[:, 0], mu[:, 0]])).max())
        m = int(round(self.n_per_pair * len(x0)))
        cc = rng.uniform(*self.c_range, m)
        if self.region == "box":
            lo, hi = states.min(axis=0), states.max(axis=0)
            ys, c_s = [], []
            while sum(len(y) for y in ys) < m:
                y = rng.uniform(lo, hi, size=(4 * m, len(lo)))
                cb = rng.uniform(*self.c_range, len(y))
                keep = self.gal.reduced_energy(y, cb) <= e_max
                ys.append(y[keep])
                c_s.append(cb[keep])
            y, cc = np.concatenate(ys)[:m], np.concatenate(c_s)[:m]
        elif self.region == "sublevel":
            Q = 0.5 * (self.gal.A1 + self.gal.A1.T) * np.mean(self.c_range) ** 2 + 0.5 * (self.gal.A2 + self.gal.A2.T)
            d = np.linalg.solve(np.linalg.cholesky(Q).T, rng.normal(size=(len(Q), m))).T  # |d|_Q Gaussian
            target = rng.uniform(0.0, 1.0, m) * e_max
            Vq = self.gal.V[: self.gal.fom.n_points]
            lo, hi = np.zeros(m), np.pi / np.abs(d @ Vq.T).max(axis=1)  # |q| <= pi along the ray
            for _ in range(50):  # vectorized bisection on the energy along each ray
                mid = 0.5 * (lo + hi)
                below = self.gal.reduced_energy(mid[:, None] * d, cc) < target
                lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
            y = lo[:, None] * d
        else:
            raise ValueError(f"region must be 'sublevel' or 'box', got {self.region!r}")
        y1 = self.gal.solve(y, cc, self.dt, 1, substeps=self.substeps)[:, 1]
        return np.concatenate([x0, y]), np.concatenate([x1, y1]), np.concatenate([mu, cc[:, None]])


def _augmentation(p, data: str, gal):
    """The pair augmentation of the preset for ``data`` (``'reduced'``: ``p.reduced_augment``, ``'projected'``:
    ``p.projected_augment``); ``gal`` is the Galerkin ROM that steps the energy samples (intrusive data only)."""
    kind = p.reduced_augment if data == "reduced" else p.projected_augment
    if kind == "none":
        return no_augmentation
    if kind == "symmetry":
        return sign_symmetry
    if kind in ("energy", "energy-box") and data == "reduced":
        return EnergySamples(
            gal,
            p.c_range,
            p.DT,
            p.substeps,
            p.energy_samples_per_pair,
            "sublevel" if kind == "energy" else "box",
            p.seed,
        )
    raise ValueError(f"augmentation {kind!r} is not available for data={data!r} (energy samples need the Galerkin ROM)")


def sine_gordon_reductor(
    p,
    gal,
    pairs,
    dt,
    regularization=0.0,
    update="symplectic_euler",
    quadratic=None,
    validation=None,
    regularizations=None,
) -> SymplecticKernelReductor:
    """The library's reductor set up as the experiment's kernel ROMs, on reduced pairs it is given.

    :class:`~sympredict.mor.SymplecticKernelReductor` on the FOM's pyMOR model and the Galerkin ROM's basis,
    with the flat pairs ``(x0, x1, mu)`` (``mu = c``, shape (m, 1): the flow map takes the wave speed only,
    ``flow_parameters=('c',)``; the second parameter enters the initial data alone), scaled coordinates
    (``p.state_scaling``, ``c`` mapped from ``p.c_range`` onto ``[0, 1]``, time unit ``dt``), the predictor
    ``IMQ(p.state_eps)`` (``None``: the estimator's default) x ``IMQ(p.mu_eps)`` with ``update`` and the f-greedy
    (``tol = 1e-9``, ridge ``regularization``) to ``p.max_centers``, and ``split=quadratic`` (a
    :class:`~sympredict.systems.linear_flow.QuadraticPart` ``A(c)``: ``L_h o S o L_h``, only ``S`` learned).
    With ``validation`` (a :class:`~sympredict.data.TrajectoryData`) and ``regularizations`` the reductor chooses
    the ridge term by the rollouts on those trajectories.  The reductor's existence check is off here: the
    experiment chooses its large step by its own rule on the training trajectories (:func:`choose_large_step`,
    which checks the generating function on ``S``'s pairs), and reports a kernel past the limit as a failed or
    inaccurate rollout (a result of the comparison) rather than refusing to train it.
    """
    fom = gal.fom
    space = fom.model.parameters.space(
        {"amplitude": tuple(fom.parameter_space.ranges["amplitude"]), "c": tuple(map(float, p.c_range))}
    )
    predictor = SymplecticKernelPredictor(
        None if p.state_eps is None else IMQ(p.state_eps),
        mu_kernel=IMQ(p.mu_eps),
        max_centers=p.max_centers,
        update=update,
        trainer=ExactGreedy(tol=1e-9, regularization=float(regularization)),
    )
    x0, x1, mu = pairs
    return SymplecticKernelReductor(
        fom.model,
        pymor_basis(gal.V, fom.phase_space),
        dt,
        GivenSamples(FlowMapData(x0, x1, mu, np.full(len(x0), float(dt))), validation, parameter_space=space),
        predictor,
        selection=None if regularizations is None else ValidationSelection(regularizations=regularizations),
        split=None if quadratic is None else QuadraticSplit(quadratic),
        scaling=TrainingScaling(p.state_scaling),
        flow_parameters=("c",),
        check_existence=False,
    )


def _fit_kernel(
    p,
    Y0,
    Y1,
    c_tr,
    dt,
    regularization=None,
    update="symplectic_euler",
    stride=1,
    augment=no_augmentation,
    quadratic=None,
    gal=None,
):
    """A kernel flow map at the macro step ``dt`` from pairs of reduced states ``Y1 = Phi^dt(Y0)`` (P, k, 2n)
    of ``P`` training trajectories at wave speeds ``c_tr`` (P,), through the reductor
    (:func:`sine_gordon_reductor` on the Galerkin ROM ``gal``'s basis).

    Scaled coordinates (:mod:`sympredict.flowmap.scaling`): conformally symplectic state map, ``c``
    onto ``[0, 1]``, time unit ``dt``; the learned step stays symplectic in the original coordinates.
    ``augment`` (a strategy: :func:`no_augmentation`, :func:`sign_symmetry`, :class:`EnergySamples`) turns
    the pairs of the trajectories a fit uses into the flat pairs it fits; it sees only those trajectories (a
    held-out trajectory's images are not in the fit that is scored on it).
    ``quadratic`` (a :class:`~sympredict.systems.linear_flow.QuadraticPart` ``A(c)``, optional) splits its exact flow off:
    the model is a :class:`~sympredict.flowmap.splitting.SplitKernelPredictor` ``L_h o S o L_h``, ``L_h = expm(dt/2 J A(c))``,
    and only ``S`` is learned (the reductor's ``split``); the held-out rollouts score the whole step.

    With ``p.regularizations`` and no ``regularization`` given, the ridge term is chosen among ``0`` and
    ``p.regularizations`` by **rollout on held-out training trajectories** (``1, 1 + validation_every, ...``;
    training data only, never the test parameters): the reductor fits each candidate on the other trajectories
    and rolls it out from the held-out initial states ``Y0[:, 0]`` (validation trajectories ``Y0[:, 0]``,
    ``Y1[:, ::stride]``: ``stride`` pairs per macro step when the pairs start at every output, as in the
    large-step regime); its score is the mean relative error, a failed or non-finite rollout scoring ``inf``;
    ties go to the smaller term.  The one-step gradient residual
    (:func:`~sympredict.estimators.selection.select_regularization`) does not predict
    whether a rollout stays in the data (measured: it chose ``1e-8`` at ``2n = 12`` where the rollout blows up
    and ``1e-6`` works).  The model is then refitted on all trajectories with the chosen term.

    Returns the flow map (original coordinates), the fitted predictor, the fit's wall time (selection
    included), the chosen ridge term and the selection table (``[(lambda, score), ...]``).
    """
    if gal is None:
        raise ValueError("_fit_kernel needs the Galerkin ROM (gal=...): its basis and FOM make the reductor")
    P, k, dim = Y0.shape
    t0 = time.perf_counter()
    table = []
    reg = 0.0 if regularization is None else float(regularization)
    if regularization is None and p.regularizations and P > 2:
        held = np.zeros(P, dtype=bool)
        held[1 :: p.validation_every] = True
        val = TrajectoryData(np.concatenate([Y0[held, :1], Y1[held, ::stride]], axis=1), c_tr[held, None], dt)
        chooser = sine_gordon_reductor(
            p,
            gal,
            augment(Y0[~held], Y1[~held], c_tr[~held]),
            dt,
            update=update,
            quadratic=quadratic,
            validation=val,
            regularizations=p.regularizations,
        )
        chooser.reduce()
        reg = chooser.regularization_
        table = [(row["regularization"], row["score"]) for row in chooser.regularization_table_]
    reductor = sine_gordon_reductor(p, gal, augment(Y0, Y1, c_tr), dt, reg, update, quadratic)
    reductor.reduce()
    return reductor.flow_map_, reductor.predictor_, time.perf_counter() - t0, reg, table


def choose_large_step(p, gal, X_tr, c_tr, K, quadratic=None, update="midpoint") -> dict:
    """The large step ``s`` (``DT_large = s DT``) among ``p.large_step`` and ``p.large_step_candidates``, by a rule
    on the **training** trajectories ``X_tr`` (P, K+1, 2N) only (never the test parameters):

    * admissible: the symmetric update's generating function exists on the data: per training ``c`` the
      least-squares linear map ``M`` of the projected pairs ``(y(t), y(t + DT_large))`` has
      ``sigma_min((I + M) / 2) >= p.large_step_sigma_min`` (:func:`~sympredict.systems.flowmaps.midpoint_sigma_min`,
      ``|cos(omega DT / 2)|`` for a mode turning by ``omega DT``: it fails at half a turn per step);
    * margin: ``r = min over training trajectories of (best classical error) / (projection floor)`` on the
      ``DT_large`` grid (best of implicit midpoint and RK4 on the Galerkin ROM from the training initial states;
      the floor ``|V V+ x - x|``, below which no ROM in this basis goes): a kernel ROM at the floor is ``r``
      times more accurate than the classical schemes;
    * the smallest admissible ``s`` with ``r >= p.large_step_margin``; if none reaches it, the admissible ``s``
      with the largest ``r``; if none is admissible, ``p.large_step``.

    With ``quadratic`` (a :class:`~sympredict.systems.linear_flow.QuadraticPart` ``A(c)``: the kernel is split as
    ``L_h o S o L_h``, ``h = DT_large / 2``) existence is checked on ``S``'s pairs ``(L_h y0, L_{-h} y1)``, the map
    that is learned; ``update='symplectic_euler'`` checks ``sigma_min(dp1/dp0)`` (a quarter turn) instead.

    Returns ``{"large_step": s, "table": [{"large_step", "DT", "sigma_min", "admissible", "ratio"}, ...]}``.
    Cost: per candidate one implicit-midpoint and one RK4 solve of the ``P`` training trajectories and ``P``
    least-squares fits of size ``2n``.
    """
    table = []
    Y = gal.project(X_tr)
    for s in sorted({int(p.large_step), *map(int, p.large_step_candidates)}):
        dt, Kl = s * p.DT, K // s
        x = X_tr[:, : Kl * s + 1 : s]
        sig = np.inf
        for c in np.unique(c_tr):
            sel = c_tr == c
            y0, y1 = Y[sel, :-s].reshape(-1, gal.dim), Y[sel, s:].reshape(-1, gal.dim)
            if quadratic is not None:  # S's pairs: row vectors times L^T
                y0 = y0 @ quadratic.propagator([c], 0.5 * dt)[0].T
                y1 = y1 @ quadratic.propagator([c], -0.5 * dt)[0].T
            M = np.linalg.lstsq(y0, y1, rcond=None)[0].T
            sig = min(sig, float((midpoint_sigma_min if update == "midpoint" else type2_sigma_min)(M[None])[0]))
        floor = _err(gal, gal.project(x), x)
        errs = []
        for scheme in ("implicit_midpoint", "rk4"):
            try:
                with np.errstate(all="ignore"):
                    e = _err(gal, gal.solve(gal.project(x[:, 0]), c_tr, dt, Kl, scheme=scheme), x)
                errs.append(np.where(np.isfinite(e), e, np.inf))
            except Exception:  # a failed classical scheme is absent
                pass
        best = np.min(errs, axis=0) if errs else np.full(len(x), np.inf)
        table.append(
            {
                "large_step": s,
                "DT": dt,
                "sigma_min": sig,
                "admissible": bool(sig >= p.large_step_sigma_min),
                "ratio": float(np.min(best / floor)),
            }
        )
    ok = [r for r in table if r["admissible"]]
    if not ok:
        return {"large_step": int(p.large_step), "table": table}
    meet = [r for r in ok if r["ratio"] >= p.large_step_margin]
    pick = meet[0] if meet else max(ok, key=lambda r: r["ratio"])
    return {"large_step": pick["large_step"], "table": table}


def _choose_large_step_split(p, gal, X_tr, c_tr, K):
    """``large_step_split='auto'``: the unsplit (non-intrusive) kernel where the training-only rule of
    :func:`choose_large_step` finds an admissible step with the wanted margin, else the split one
    (``'quadratic-mass'``) where it does, else the unsplit rule's choice.  Training trajectories only.

    Returns ``(split, quadratic, choice)``: the chosen kernel's split and quadratic part (``None`` unsplit), and
    ``choice`` as :func:`choose_large_step`'s for it, plus ``tables`` (the table of every rule evaluated, by split).
    """
    tables = {}
    for split, quad in (("none", None), ("quadratic-mass", gal.quadratic_part(mass=True))):
        choice = choose_large_step(p, gal, X_tr, c_tr, K, quadratic=quad)
        tables[split] = choice
        row = next(r for r in choice["table"] if r["large_step"] == choice["large_step"])
        if row["admissible"] and row["ratio"] >= p.large_step_margin:
            return split, quad, {**choice, "tables": {k: v["table"] for k, v in tables.items()}}
    return "none", None, {**tables["none"], "tables": {k: v["table"] for k, v in tables.items()}}


def _large_step(p, gal, X_tr, c_tr, X_te, c_te, K):
    """The large-step regime at ``DT_large = large_step * DT`` (one output per macro step, horizon ``T``).

    Classical schemes on the Galerkin ROM with one step per ``DT_large`` (implicit midpoint, RK4; Yoshida does
    not apply, the reduced ``H`` is not separable) against the kernel ROM learned from projected FOM
    trajectories (non-intrusive) with the symmetric update (``update='midpoint'``, whose generating function
    exists up to a half turn per step where the symplectic-Euler form fails at a quarter turn), trained on
    every pair ``(x(t), x(t + DT_large))`` of the training trajectories' output grid.  Errors against the FOM
    on the ``DT_large`` grid, per test parameter; the snapshot projection error there is the floor of any
    ROM in this basis.  ``DT_large`` is chosen by :func:`choose_large_step` on the training trajectories.

    ``p.large_step_split`` (``'quadratic'`` / ``'quadratic-mass'``, as :func:`split_setup`): the kernel is
    ``L_h o S o L_h`` with ``L_h`` the exact flow of the reduced quadratic part over ``DT_large / 2`` (existence then
    checked on ``S``'s pairs); ``A_r(c)`` is the reduced operator, so the kernel is then **not** non-intrusive.
    """
    if p.large_step_split not in ("none", "quadratic", "quadratic-mass", "auto"):
        raise ValueError(
            f"large_step_split must be 'none', 'quadratic', 'quadratic-mass' or 'auto', got {p.large_step_split!r}"
        )
    if p.large_step_split == "auto":
        split, quad, choice = _choose_large_step_split(p, gal, X_tr, c_tr, K)
    else:
        split = p.large_step_split
        quad = None if split == "none" else gal.quadratic_part(mass=split == "quadratic-mass")
        choice = choose_large_step(p, gal, X_tr, c_tr, K, quadratic=quad)
    s = choice["large_step"]
    dt = s * p.DT
    Kl = K // s
    x_te = X_te[:, : Kl * s + 1 : s]
    y0 = gal.project(x_te[:, 0])
    out = {
        "DT": dt,
        "steps": Kl,
        "choice": choice,
        "split": split,
        "split_setting": p.large_step_split,
        "projection_error": _err(gal, gal.project(x_te), x_te).tolist(),
        "DT_omega_max": float(dt * np.abs(np.linalg.eigvals(_jg(gal, y0[0], float(p.c_range[1])))).max()),
    }
    out["galerkin_error"] = _err(gal, gal.solve(y0, c_te, dt, Kl, substeps=s * p.substeps), x_te).tolist()
    for scheme in ("implicit_midpoint", "rk4"):
        try:
            out[f"{scheme}_at_DT_error"] = _err(gal, gal.solve(y0, c_te, dt, Kl, scheme=scheme), x_te).tolist()
        except Exception as exc:  # a Newton failure is a result here
            out[f"{scheme}_at_DT_error"] = f"failed: {type(exc).__name__}"
    out["implicit_midpoint_time_per_trajectory"] = time_median(lambda: gal.solve(y0[:1], c_te[:1], dt, Kl), p.repeats)[
        0
    ]
    Yp = gal.project(X_tr)
    flow, model, fit_time, reg, table = _fit_kernel(
        p, Yp[:, :-s], Yp[:, s:], c_tr, dt, update="midpoint", stride=s, quadratic=quad, gal=gal
    )
    entry = {
        "fit_time": fit_time,
        "regularization": reg,
        "regularization_table": table,
        "centers": int(model.n_centers_),
        "train_residual": [float(v) for v in model.history_.train_max_residual],
        "error": None,
        "time_per_trajectory": None,
        "failure": None,
    }
    try:
        entry["error"] = _err(gal, flow.rollout(y0, Kl, mu=c_te[:, None], dt=dt), x_te).tolist()
        entry["time_per_trajectory"] = time_median(
            lambda: flow.rollout(y0[:1], Kl, mu=c_te[:1, None], dt=dt), p.repeats
        )[0]
    except Exception as exc:  # a failed rollout is a result, reported as such
        entry["failure"] = failure_text(exc)
    out["kernel_projected_midpoint"] = entry
    return out


def _data_driven(fom, p, Yp_tr, c_tr, a_tr, c_te, a_te, gal, x_te, K, curves):
    from pymor.algorithms.ml.vkoga.regressor import VKOGARegressor
    from pymor.reductors.data_driven import DataDrivenReductor

    from pymor.parameters.base import Parameters

    # the scenario's parameters (c and the initial family's second one); for 'sech_cos' these are the pyMOR
    # model's own ({c, amplitude}); a breather's omega is not a parameter of the pyMOR model (its initial data are
    # linear in amplitude), so the regressor's inputs are declared here
    name2 = second_parameter(p)[0]
    params = Parameters({"c": 1, name2: 1})
    train = [params.parse({"c": c, name2: a}) for c, a in zip(c_tr, a_tr)]
    snaps = np.concatenate(list(Yp_tr))  # (P (K+1), 2n): DataDrivenReductor takes the rows, trajectory by trajectory
    entry = {"error": None, "time_per_trajectory": None, "fit_time": None, "failure": None}
    try:
        t0 = time.perf_counter()
        rom = DataDrivenReductor(train, snaps, regressor=VKOGARegressor(), T=p.T, input_scaler=BoxScaling()).reduce()
        entry["fit_time"] = time.perf_counter() - t0
        mus = [params.parse({"c": c, name2: a}) for c, a in zip(c_te, a_te)]
        Y = np.stack([rom.solve(mu).to_numpy().T for mu in mus])  # (B, K+1, 2n)
        entry["error"] = _err(gal, Y, x_te).tolist()
        curves["data_driven"] = _curve(gal, Y, x_te).tolist()
        entry["time_per_trajectory"] = time_median(lambda: rom.solve(mus[0]), p.repeats)[0]
    except Exception as exc:  # reported, not raised
        entry["failure"] = failure_text(exc)
    return entry


def _jg(rom, y, c):
    """``J dg`` at one reduced state: its eigenvalues are ``i omega`` (linearized frequencies)."""
    return canonical_J(rom.dim) @ rom.jacobian(y, c)


def _interpolation_matrix(x_from, x_to, length):
    """Linear interpolation between Dirichlet grids (zero at ``0`` and ``L``), sparse (len(x_to), len(x_from))."""
    import scipy.sparse as sps

    xf = np.concatenate([[0.0], x_from, [length]])
    j = np.clip(np.searchsorted(xf, x_to, side="right") - 1, 0, len(xf) - 2)
    w = (x_to - xf[j]) / (xf[j + 1] - xf[j])
    rows = np.concatenate([np.arange(len(x_to))] * 2)
    cols = np.concatenate([j, j + 1]) - 1  # the boundary nodes (columns -1 and len(x_from)) carry zeros
    vals = np.concatenate([1.0 - w, w])
    keep = (cols >= 0) & (cols < len(x_from))
    return sps.csr_matrix((vals[keep], (rows[keep], cols[keep])), shape=(len(x_to), len(x_from)))


def _to_grid(X, M):
    """States (..., 2N0) interpolated onto another grid by ``M`` (N, N0), (q, p) separately -> (..., 2N)."""
    n0 = M.shape[1]
    flat = X.reshape(-1, 2 * n0)
    return np.hstack([(M @ flat[:, :n0].T).T, (M @ flat[:, n0:].T).T]).reshape(*X.shape[:-1], 2 * M.shape[0])


def _truncate(V, n):
    """The first ``n`` complex modes of a complex-SVD basis ``[[Re U, -Im U], [Im U, Re U]]`` (2N, 2n_max)."""
    m = V.shape[1] // 2
    return np.hstack([V[:, :n], V[:, m : m + n]])


def _cost_vs_N(fom, p, out, X_tr, c_tr, x_te, c_te):
    """Every method's online cost at each ``N`` of ``cost_N``, each with its own ROMs built at that ``N``.

    Per ``N``: a FOM of that size; its training snapshots are the ``N = n_points`` FOM trajectories
    interpolated linearly onto its grid (a reference FOM at ``N = 16,000`` costs ``O(N^2)`` per trajectory:
    ``N`` per step, ``N`` steps by the CFL bound); from them a complex-SVD basis, the Galerkin and DEIM ROMs,
    Galerkin training trajectories and the kernel ROMs (Galerkin data and projected data), fitted exactly as
    at ``N = n_points``.  Timed per trajectory (medians of ``repeats``, same process): Galerkin RK4 with
    ``substeps`` sub-steps and with one step per ``DT``, Galerkin implicit midpoint, DEIM RK4, the kernel
    rollouts in reduced coordinates, the reconstruction ``V y`` alone; the repeats run interleaved over all
    ``N`` (one round times every call once), so a changing load hits every ``N`` alike.  Errors against the interpolated
    FOM test trajectories (the interpolation and the grid change are far below the ROM errors) make the
    equal-accuracy comparison per ``N``.
    """
    K = int(round(p.T / p.DT))
    rows, calls = [], []
    n_max = max(p.dims) // 2
    for N in p.cost_N:
        f = SineGordonFOM(
            n_points=N, length=p.length, c_range=p.c_range, amplitude_range=p.amplitude_range, T=p.T, nt=K
        )
        M = _interpolation_matrix(fom.x, f.x, p.length)
        Xn = _to_grid(X_tr, M)
        xn_te = _to_grid(x_te, M)
        V_all = complex_svd_basis(Xn.reshape(-1, f.dim), n=n_max, layout="rows").V
        nonlin = nonlinear_snapshots(f, Xn)
        for dim in p.dims:
            V = _truncate(V_all, dim // 2)
            gal = ReducedSineGordon.galerkin(f, V)
            deim = ReducedSineGordon.deim(f, V, nonlin, p.deim_factor * dim)
            y0 = gal.project(xn_te[:, 0])
            row = {"N": N, "dim": dim}
            Yg = gal.solve(y0, c_te, p.DT, K, substeps=p.substeps)
            row["galerkin_error"] = float(np.median(_err(gal, Yg, xn_te)))
            row["deim_error"] = float(np.median(_err(deim, deim.solve(y0, c_te, p.DT, K, substeps=p.substeps), xn_te)))
            fns = _cost_calls(p, gal, deim, y0[:1], c_te[:1], Yg[0], K)
            split = split_setup(p, gal)
            Yg_tr = gal.solve(gal.project(Xn[:, 0]), c_tr, p.DT, K, substeps=split["substeps"])
            for key, Ytr in (("kernel", Yg_tr), ("kernel_projected", gal.project(Xn))):
                row[key] = row[f"{key}_error"] = None
                # the ridge term chosen at N = n_points (a setting of the model, not chosen again per N)
                lam = out["dims"][dim]["kernel_reduced" if key == "kernel" else "kernel_projected"]["regularization"]
                flow, model, _, row[f"{key}_regularization"], _ = _fit_kernel(
                    p,
                    Ytr[:, :-1],
                    Ytr[:, 1:],
                    c_tr,
                    p.DT,
                    lam,
                    update=p.kernel_update,
                    augment=_augmentation(split["preset"], "reduced" if key == "kernel" else "projected", gal),
                    quadratic=split["quadratic"] if key == "kernel" else None,
                    gal=gal,
                )
                row[f"{key}_centers"] = int(model.n_centers_)
                try:
                    row[f"{key}_error"] = float(
                        np.median(_err(gal, flow.rollout(y0, K, mu=c_te[:, None], dt=p.DT), xn_te))
                    )
                    fns[key] = partial(flow.rollout, y0[:1], K, mu=c_te[:1, None], dt=p.DT)
                except Exception as exc:  # a failed rollout is a result: no time
                    row[f"{key}_failure"] = f"{type(exc).__name__}: {exc}"[:200]
            rows.append(row)
            calls.append(fns)
    # interleaved: repeat r times every call of every N, so that a changing load on the shared machine hits all N alike
    times = [{k: [] for k in fns} for fns in calls]
    for fns in calls:  # warm-up (compilation, caches)
        for fn in fns.values():
            fn()
    for _ in range(p.repeats):
        for fns, tm in zip(calls, times):
            for k, fn in fns.items():
                t0 = time.perf_counter()
                fn()
                tm[k].append(time.perf_counter() - t0)
    for row, tm in zip(rows, times):
        row.update({k: float(np.median(v)) for k, v in tm.items()})
        logger.info(
            f"cost at N = {row['N']}, 2n = {row['dim']}: "
            + ", ".join(f"{k} {v * 1e3:.2f} ms" for k, v in row.items() if k in _TIMED and v is not None)
        )
    return rows


def _cost_calls(p, gal, deim, y0, c, Y, K):
    """The timed calls of one ``(N, 2n)``: Galerkin RK4 (``substeps`` and one step per ``DT``), Galerkin implicit
    midpoint, DEIM RK4, reconstruction ``V y`` of one trajectory."""
    return {
        "galerkin_rk4": partial(gal.solve, y0, c, p.DT, K, scheme="rk4", substeps=p.substeps),
        # one RK4 step per DT: as accurate as the sub-stepped ROM where DT omega_max is small (see the results)
        "galerkin_rk4_at_DT": partial(gal.solve, y0, c, p.DT, K, scheme="rk4"),
        "galerkin_im": partial(gal.solve, y0, c, p.DT, K, substeps=p.substeps),
        "deim_rk4": partial(deim.solve, y0, c, p.DT, K, scheme="rk4", substeps=p.substeps),
        "reconstruction": partial(gal.reconstruct, Y),
    }


_TIMED = (
    "galerkin_rk4",
    "galerkin_rk4_at_DT",
    "galerkin_im",
    "deim_rk4",
    "reconstruction",
    "kernel",
    "kernel_projected",
)


def break_even(rows, dims_info) -> dict:
    """Per ``2n`` and kernel ROM (``'kernel'``: Galerkin data; ``'kernel_projected'``: FOM data): its cost ratio from
    the smallest to the largest ``N`` (flatness), its errors per ``N``, and the ``N`` at which the compiled Galerkin
    ROM (RK4 at its accurate step: one step per ``DT`` where ``DT omega_max < 1``, else ``substeps``) costs as much.

    The Galerkin cost is fitted as ``a + b N`` (least squares over the measured ``N``), the kernel's cost is
    its median over ``N``; ``N* = (t_kernel - a) / b`` (an extrapolation where it falls outside the
    measured range; ``None`` where the kernel failed at some ``N``).  Whether the two are of equal accuracy is
    read from the errors stored alongside (``galerkin_error``, ``error``).  ``dims_info`` maps ``2n`` to its
    ``DT_omega_max``.
    """
    out = {}
    for dim, wom in dims_info.items():
        rs = sorted((r for r in rows if r["dim"] == int(dim)), key=lambda r: r["N"])
        variant = "galerkin_rk4_at_DT" if wom < 1 else "galerkin_rk4"
        Ns = np.array([r["N"] for r in rs], dtype=float)
        tg = np.array([r[variant] for r in rs])
        b, a = np.polyfit(Ns, tg, 1) if len(rs) >= 2 else (np.nan, np.nan)
        entry = {
            "galerkin_variant": variant,
            "N": Ns.tolist(),
            "galerkin_time": tg.tolist(),
            "galerkin_fit": [float(a), float(b)],
            "galerkin_error": [r["galerkin_error"] for r in rs],
        }
        for key in ("kernel", "kernel_projected"):
            k = {
                "time": [r[key] for r in rs],
                "error": [r[f"{key}_error"] for r in rs],
                "flat_ratio": None,
                "N_star": None,
                "speedup_at_largest_N": None,
            }
            if len(rs) >= 2 and all(t is not None for t in k["time"]):
                tk = np.array(k["time"])
                k["flat_ratio"] = float(tk[-1] / tk[0])
                k["N_star"] = float((np.median(tk) - a) / b) if b > 0 else None
                k["speedup_at_largest_N"] = float(tg[-1] / tk[-1])
            entry[key] = k
        out[int(dim)] = entry
    return out


#: ``python -m sympredict_paper.sine_gordon [OPTIONS]``: ``sympredict-paper run sine-gordon [OPTIONS]``.
main = scenario_main("sine-gordon")


if __name__ == "__main__":
    raise SystemExit(main())
