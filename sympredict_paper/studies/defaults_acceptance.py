"""Defaults against hand tuning on systems nobody tuned the defaults on (acceptance benchmark of the automatic defaults).

Three parametric Hamiltonian systems in physical units, none of them among the
paper's systems, each learned from scattered one-step samples by two
configurations with the same centre budget ``max_centers``:

* ``defaults``: ``SymplecticKernelPredictor(max_centers=m).fit(x0, x1, mu=mu, dt=dt)``
  and nothing else (the estimator normalises, chooses kernels, shapes and update
  itself; its ``choice_`` and ``diagnostics_`` are recorded when present).  If
  the fit raises, the row records the error;
* ``hand``: the best hand tuning found with the explicit API: a symplectic
  state scaling ``Scaled(kernel, factors=a)`` with ``a_i`` a multiple (``ratio``) of
  ``sqrt(std p_i / std q_i)`` of the training data, an IMQ or Matern 5/2 state kernel
  of shape ``eps_state`` (in the scaled coordinates), a ``mu_kernel`` of the same
  family with shape ``eps_mu`` (in the parameter's physical unit), the
  symplectic-Euler or midpoint update.  ``dt`` is one value per system (no
  ``dt_kernel``).  The settings found are recorded in :data:`HAND` with the
  search that found them; ``--search`` reruns the search.

Systems (``--systems``; parameter in its physical unit, uniform in its range):

* ``coupled_pendulums`` (the user story): two pendulums ``m = 1 kg``, ``L = 1 m``,
  ``g = 9.81 m/s^2`` joined by a torsion spring ``kappa`` in [0.5, 1.5] N m/rad,
  ``H = (p1^2 + p2^2) / (2 m L^2) + m g L (2 - cos q1 - cos q2) + kappa (q1 - q2)^2 / 2``;
  states uniform in ``H <= 8 J`` (angles up to 1.38 rad, momenta up to 4 kg m^2/s), ``dT = 0.1 s``;
* ``fpu_chain``: three masses ``m = 0.1 kg`` between fixed walls, springs ``k = 40 N/m`` with a
  FPU-beta quartic term ``beta`` in [1000, 3000] N/m^3,
  ``H = sum p_i^2 / (2 m) + sum_{i=0..3} k d_i^2 / 2 + beta d_i^4 / 4``, ``d_i = q_{i+1} - q_i``, ``q_0 = q_4 = 0``;
  states uniform in ``H <= 0.15 J`` (displacements up to 9 cm), ``dT = 0.015 s``;
* ``kepler``: a planar orbit around a star of ``GM`` in [0.5, 1.5] x 4 pi^2 AU^3/yr^2 (0.5 to 1.5 solar
  masses), ``H = |p|^2 / 2 - GM / |q|`` (per unit mass, positions in AU, velocities in AU/yr); states
  on prograde orbits with semi-major axis ``a`` in [1, 2] AU, eccentricity ``e`` in [0, 0.5], uniform
  periapsis direction and mean anomaly; ``dT = 0.02 yr``.

Reference flows: RK4 with step halving to ``rtol = 1e-11`` per instance
(:class:`sympredict.systems.flowmaps.HamiltonianSystem`) for the pendulums and
the chain, the closed-form Kepler flow (Kepler's equation in the eccentric-anomaly
increment, solved by Newton to round-off; the f and g functions) for the orbit.

Protocol per system: ``--samples`` training samples (states, parameters and the
one-step images); the hand search trains on 80 % of them and scores the mean
relative one-step error on the other 20 % (never on test trajectories); the
chosen settings are then refitted on all samples.  Test: ``--n-test`` initial
states with their own parameter (seed disjoint from the training and validation
seeds), rolled out ``--steps`` steps (200).  Metrics: the relative trajectory
error ``|x_k - x_ref(t_k)| / |x_ref(t_k)|`` (Euclidean in physical units,
:func:`sympredict.symplectic.metrics.relative_trajectory_error`), its maximum
over the steps per trajectory, then the median and the maximum over
trajectories; the relative energy error ``|H(x_k) - H(x_0)| / |H(x_0)|`` over
``--long-steps`` steps (10x the horizon: 2,000), median and maximum over
trajectories of its maximum over the steps; fit wall time (median of
``--repeats`` fits); centres.  A Newton failure or any other exception is a
result: the row records it.  Goal: defaults within 1.5x of the hand tuning.

Run:  python sympredict_paper/studies/defaults_acceptance.py                          # 5,000 samples, 1,000 centres, recorded hand settings
      python sympredict_paper/studies/defaults_acceptance.py --search                 # redo the hand search (validation split only)
      python sympredict_paper/studies/defaults_acceptance.py --big                    # the user story: coupled pendulums, 30,000 / 4,000, progress shown
      python sympredict_paper/studies/defaults_acceptance.py --quick --systems kepler --configs hand   # seconds
One BLAS thread (``--blas-threads``) and one numba thread (``--threads``; set NUMBA_NUM_THREADS too);
writes ``docs/data/defaults_acceptance.json`` (``--json``) with the record of ``sympredict_paper/studies/_protocol.py``.
"""

from __future__ import annotations

import argparse
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

import _protocol  # sympredict_paper/studies/ (the script's folder is on sys.path)
from _coordinate_search import (  # sympredict_paper/studies/
    add_search_arguments,
    quick_search,
    run_search,
    search_record,
    with_overrides,
)

from sympredict import SymplecticKernelPredictor
from sympredict.exceptions import ExtrapolationWarning
from sympredict.kernels import KERNEL_FAMILIES
from sympredict.kernels.transforms import Scaled
from sympredict.symplectic.metrics import relative_trajectory_error
from sympredict.systems.flowmaps import FlowFunctionSystem, HamiltonianSystem

GOAL = 1.5  # defaults within this factor of the hand tuning
RESULTS = Path(__file__).resolve().parents[2] / "docs" / "data" / "defaults_acceptance.json"
SEARCH_NAMES = ("eps_state", "eps_mu", "ratio")


# --------------------------------------------------------------------------- systems
@dataclass
class Benchmark:
    """One test system: reference flow, Hamiltonian, sampler, parameter range, step, units."""

    name: str
    title: str
    system: object  # flow(x0, mu, t), hamiltonian(x, mu), trajectory(x0, mu, dt, n), dim
    mu_name: str
    mu_unit: str
    mu_range: tuple
    dt: float
    units: dict
    sampler: Callable  # (mu (N,), rng) -> states (N, dim)
    notes: str = ""
    extra: dict = field(default_factory=dict)

    @property
    def dim(self) -> int:
        """The state dimension ``2n`` (the system's)."""
        return self.system.dim

    def sample(self, n: int, seed: int):
        """``n`` parameters uniform in the range and one state each: ``(x0 (n, dim), mu (n,))``."""
        rng = np.random.default_rng(seed)
        mu = rng.uniform(*self.mu_range, n)
        return self.sampler(mu, rng), mu


def _rejection(h, mu, rng, lo, hi, e_max, max_rounds: int = 10_000):
    """States uniform in the box ``[lo, hi]`` with ``h(x, mu) <= e_max`` (one per entry of ``mu``)."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    out = np.empty((len(mu), len(lo)))
    todo = np.arange(len(mu))
    for _ in range(max_rounds):
        cand = rng.uniform(lo, hi, (len(todo), len(lo)))
        ok = h(cand, mu[todo, None]) <= e_max
        out[todo[ok]] = cand[ok]
        todo = todo[~ok]
        if not len(todo):
            return out
    raise RuntimeError(f"rejection sampling left {len(todo)} states after {max_rounds} rounds")


# coupled pendulums: q = (q1, q2) rad, p = (p1, p2) kg m^2/s, kappa N m/rad
PEND_M, PEND_L, PEND_G, PEND_E = 1.0, 1.0, 9.81, 8.0


def _pend_H(x, mu):
    q1, q2, p1, p2 = x.T
    kappa = mu[:, 0]
    return (
        (p1**2 + p2**2) / (2 * PEND_M * PEND_L**2)
        + PEND_M * PEND_G * PEND_L * (2 - np.cos(q1) - np.cos(q2))
        + 0.5 * kappa * (q1 - q2) ** 2
    )


def _pend_grad(x, mu):
    q1, q2, p1, p2 = x.T
    kappa = mu[:, 0]
    mgl = PEND_M * PEND_G * PEND_L
    return np.stack(
        [
            mgl * np.sin(q1) + kappa * (q1 - q2),
            mgl * np.sin(q2) - kappa * (q1 - q2),
            p1 / (PEND_M * PEND_L**2),
            p2 / (PEND_M * PEND_L**2),
        ],
        axis=1,
    )


def _pend_sampler(mu, rng):
    return _rejection(_pend_H, mu, rng, [-1.4, -1.4, -4.1, -4.1], [1.4, 1.4, 4.1, 4.1], PEND_E)


# FPU-beta chain: q_i m, p_i kg m/s, beta N/m^3
FPU_M, FPU_K, FPU_E = 0.1, 40.0, 0.15


def _fpu_d(q):
    z = np.zeros((len(q), 1))
    return np.diff(np.concatenate([z, q, z], axis=1), axis=1)  # (B, 4) spring elongations


def _fpu_H(x, mu):
    q, p = x[:, :3], x[:, 3:]
    d = _fpu_d(q)
    return (p**2).sum(1) / (2 * FPU_M) + (0.5 * FPU_K * d**2 + 0.25 * mu[:, :1] * d**4).sum(1)


def _fpu_grad(x, mu):
    q, p = x[:, :3], x[:, 3:]
    d = _fpu_d(q)
    f = FPU_K * d + mu[:, :1] * d**3  # spring forces (B, 4); dV/dq_i = f_{i-1} - f_i
    return np.concatenate([f[:, :3] - f[:, 1:], p / FPU_M], axis=1)


def _fpu_sampler(mu, rng):
    return _rejection(_fpu_H, mu, rng, [-0.1] * 3 + [-0.18] * 3, [0.1] * 3 + [0.18] * 3, FPU_E)


# Kepler: q AU, p AU/yr (per unit mass), GM AU^3/yr^2
GM_SUN = 4 * np.pi**2
KEPLER_E_MAX = 0.5


def kepler_H(x, mu):
    """``|p|^2 / 2 - GM / |q|``, shape (B,)."""
    return 0.5 * (x[:, 2] ** 2 + x[:, 3] ** 2) - mu[:, 0] / np.hypot(x[:, 0], x[:, 1])


def kepler_flow(x0, mu, t):
    """The exact Kepler flow of bound orbits: Kepler's equation in ``dE`` by Newton, then the f and g functions.

    ``n t = dE + sigma0 / sqrt(a) (1 - cos dE) - (1 - r0 / a) sin dE`` with
    ``sigma0 = q0 . p0 / sqrt(GM)`` (no singularity at ``e = 0``); its
    derivative ``r(dE) / a`` is positive, so Newton from ``dE = n t`` converges.
    """
    gm = np.asarray(mu, float).reshape(len(x0), -1)[:, 0]
    t = np.broadcast_to(np.asarray(t, float), (len(x0),))
    r0v, v0v = x0[:, :2], x0[:, 2:]
    r0 = np.hypot(r0v[:, 0], r0v[:, 1])
    energy = 0.5 * (v0v**2).sum(1) - gm / r0
    if np.any(energy >= 0):
        raise ValueError("kepler_flow: unbound states (H >= 0) given; the benchmark samples bound orbits only")
    a = -gm / (2 * energy)
    sigma0 = (r0v * v0v).sum(1) / np.sqrt(gm)
    n_mean = np.sqrt(gm / a**3)
    c1, c2 = sigma0 / np.sqrt(a), 1.0 - r0 / a
    target = n_mean * t
    dE = target.copy()
    for _ in range(100):
        s, c = np.sin(dE), np.cos(dE)
        f = dE + c1 * (1 - c) - c2 * s - target
        step = f / (1 + c1 * s - c2 * c)
        dE = dE - step
        if np.all(np.abs(step) <= 4e-16 * np.maximum(1.0, np.abs(dE))):
            break
    s, c = np.sin(dE), np.cos(dE)
    f = 1 - a / r0 * (1 - c)
    g = t - (dE - s) / n_mean
    r1v = f[:, None] * r0v + g[:, None] * v0v
    r1 = np.hypot(r1v[:, 0], r1v[:, 1])
    fdot = -np.sqrt(gm * a) / (r1 * r0) * s
    gdot = 1 - a / r1 * (1 - c)
    v1v = fdot[:, None] * r0v + gdot[:, None] * v0v
    return np.concatenate([r1v, v1v], axis=1)


def kepler_grad(x, mu):
    """``grad H = (GM q / |q|^3, p)``, shape (B, 4)."""
    r3 = np.hypot(x[:, 0], x[:, 1]) ** 3
    return np.concatenate([mu[:, :1] * x[:, :2] / r3[:, None], x[:, 2:]], axis=1)


def _kepler_sampler(mu, rng):
    n = len(mu)
    a = rng.uniform(1.0, 2.0, n)
    e = rng.uniform(0.0, KEPLER_E_MAX, n)
    omega = rng.uniform(0, 2 * np.pi, n)
    mean_anomaly = rng.uniform(0, 2 * np.pi, n)
    ecc = mean_anomaly.copy()
    for _ in range(100):  # Kepler's equation E - e sin E = M
        step = (ecc - e * np.sin(ecc) - mean_anomaly) / (1 - e * np.cos(ecc))
        ecc -= step
        if np.all(np.abs(step) < 1e-15):
            break
    r = a * (1 - e * np.cos(ecc))
    pos = np.stack([a * (np.cos(ecc) - e), a * np.sqrt(1 - e**2) * np.sin(ecc)], axis=1)
    vel = (np.sqrt(mu * a) / r)[:, None] * np.stack([-np.sin(ecc), np.sqrt(1 - e**2) * np.cos(ecc)], axis=1)
    rot = np.stack([np.stack([np.cos(omega), -np.sin(omega)], 1), np.stack([np.sin(omega), np.cos(omega)], 1)], 1)
    return np.concatenate([np.einsum("bij,bj->bi", rot, pos), np.einsum("bij,bj->bi", rot, vel)], axis=1)


def make_benchmarks() -> dict:
    """The systems by name."""
    benchmarks = (
        Benchmark(
            "coupled_pendulums",
            "two pendulums coupled by a torsion spring (the user story: 4-D, dT = 0.1 s)",
            HamiltonianSystem(_pend_H, _pend_grad, 4, parameters={"kappa": 1}, rtol=1e-11),
            "kappa",
            "N m/rad",
            (0.5, 1.5),
            0.1,
            {"q": "rad", "p": "kg m^2/s", "t": "s", "H": "J"},
            _pend_sampler,
            notes=f"m = {PEND_M} kg, L = {PEND_L} m, g = {PEND_G} m/s^2, states uniform in H <= {PEND_E} J",
        ),
        Benchmark(
            "fpu_chain",
            "three-mass FPU-beta chain between fixed walls (6-D)",
            HamiltonianSystem(_fpu_H, _fpu_grad, 6, parameters={"beta": 1}, rtol=1e-11),
            "beta",
            "N/m^3",
            (1000.0, 3000.0),
            0.015,
            {"q": "m", "p": "kg m/s", "t": "s", "H": "J"},
            _fpu_sampler,
            notes=f"m = {FPU_M} kg, k = {FPU_K} N/m, states uniform in H <= {FPU_E} J",
        ),
        Benchmark(
            "kepler",
            "planar Kepler orbits, a in [1, 2] AU, e in [0, 0.5] (4-D)",
            FlowFunctionSystem(kepler_flow, 4, n_mu=1, H=kepler_H),
            "GM",
            "AU^3/yr^2",
            (0.5 * GM_SUN, 1.5 * GM_SUN),
            0.02,
            {"q": "AU", "p": "AU/yr", "t": "yr", "H": "AU^2/yr^2"},
            _kepler_sampler,
            notes="exact flow (Kepler's equation); prograde orbits",
        ),
    )
    return {b.name: b for b in benchmarks}


# --------------------------------------------------------------------------- hand settings
#: The best hand settings found by ``--search`` (validation split only) and the searches that found them
#: (each round: family x update at the start, then a coordinate search over eps_state, eps_mu, ratio by factors
#: of 2, 3 sweeps; cost on the shared 2-core machine, 1 BLAS and 1 numba thread).
#: ``factors`` are the Scaled transform's ``a_i`` = ratio * sqrt(std p_i / std q_i) of the training data;
#: ``eps_state`` is in units of 1 / spread (``spread``), ``eps_mu`` in 1 / (the parameter's unit).
def _searched(samples: int, max_centers: int, *rounds: tuple) -> dict:
    """The record of a hand search: its data size and centre budget, and per round ``(start, evaluations,
    cost_s, best_validation)``."""
    keys = ("start", "evaluations", "cost_s", "best_validation")
    return {"rounds": [dict(zip(keys, r)) for r in rounds], "samples": samples, "max_centers": max_centers}


HAND: dict = {
    "coupled_pendulums": {
        "family": "imq",
        "update": "midpoint",
        "eps_state": 0.0625,
        "eps_mu": 0.125,
        "ratio": 1.0,
        "search": _searched(
            5000,
            1000,
            ("imq, midpoint, eps_state 0.5, eps_mu 1.0, ratio 1.0", 21, 182, 1.21e-4),
            ("round 1's best (matern52, symplectic_euler, 0.0625, 0.25, 1.0)", 13, 50, 3.05e-7),
        ),
    },
    "fpu_chain": {
        "family": "imq",
        "update": "midpoint",
        "eps_state": 0.015625,
        "eps_mu": 0.000125,
        "ratio": 2.0,
        "search": _searched(
            5000,
            1000,
            ("imq, midpoint, eps_state 0.5, eps_mu 5e-4, ratio 1.0", 19, 203, 1.80e-3),
            ("round 1's best (matern52, midpoint, 0.0625, 0.001, 2.0)", 16, 118, 9.11e-4),
            ("round 2's best (matern52, midpoint, 0.015625, 5e-4, 2.0)", 14, 78, 1.27e-4),
        ),
    },
    "kepler": {
        "family": "matern52",
        "update": "symplectic_euler",
        "eps_state": 0.125,
        "eps_mu": 0.0253,
        "ratio": 2.0,
        "search": _searched(
            5000,
            1000,
            ("imq, midpoint, eps_state 0.5, eps_mu 0.0253, ratio 1.0", 15, 108, 1.23e-3),
            ("round 1's best with eps_state 0.0625 (matern52, symplectic_euler, ratio 2.0)", 10, 37, 1.15e-3),
        ),
    },
}


def base_factors(x0: np.ndarray) -> np.ndarray:
    """``sqrt(std p_i / std q_i)``: the symplectic scaling that gives ``q_i`` and ``p_i`` equal spreads."""
    n = x0.shape[1] // 2
    sd = x0.std(axis=0)
    return np.sqrt(sd[n:] / sd[:n])


def spread(x0: np.ndarray) -> float:
    """The common spread ``sqrt(std q_i std p_i)`` (geometric mean over pairs) of the scaled coordinates."""
    n = x0.shape[1] // 2
    sd = x0.std(axis=0)
    return float(np.exp(np.mean(0.5 * np.log(sd[:n] * sd[n:]))))


def hand_model(settings: dict, x0: np.ndarray, max_centers: int) -> SymplecticKernelPredictor:
    """The explicit-API model of ``settings``; shapes relative to the data: ``eps_state / spread``."""
    family = KERNEL_FAMILIES[settings["family"]]
    factors = settings["ratio"] * base_factors(x0)
    state = Scaled(family(settings["eps_state"] / spread(x0)), factors=[float(f) for f in factors])
    return SymplecticKernelPredictor(
        state, mu_kernel=family(settings["eps_mu"]), max_centers=max_centers, update=settings["update"]
    )


# --------------------------------------------------------------------------- metrics
class ExactFlowModel:
    """The reference flow as a 'model' (``rollout`` like a predictor's): the metrics' zero; ``dt_factor`` spoils it."""

    def __init__(self, bench: Benchmark, dt_factor: float = 1.0):
        self.bench, self.dt_factor = bench, float(dt_factor)

    def rollout(self, x0, n_steps, mu=None, dt=None):
        return self.bench.system.trajectory(x0, np.asarray(mu, float).reshape(-1, 1), dt * self.dt_factor, n_steps)

    def step(self, x0, mu=None, dt=None):
        return self.bench.system.flow(x0, np.asarray(mu, float).reshape(-1, 1), dt * self.dt_factor)


def make_test_set(bench: Benchmark, n_test: int, steps: int, seed: int) -> dict:
    """``n_test`` initial states, each with its own parameter, and their reference trajectories ``(B, steps+1, 2n)``."""
    x0, mu = bench.sample(n_test, seed)
    ref = bench.system.trajectory(x0, mu[:, None], bench.dt, steps)
    return {"x0": x0, "mu": mu, "ref": ref}


def one_step_error(model, x0, x1, mu, dt) -> float:
    """Mean relative one-step error ``|step(x0) - x1| / |x1|`` (the hand search's validation score)."""
    pred = model.step(x0, mu=mu, dt=dt)
    return float(np.mean(np.linalg.norm(pred - x1, axis=1) / np.linalg.norm(x1, axis=1)))


def trajectory_metrics(model, bench: Benchmark, test: dict, long_steps: int) -> dict:
    """Trajectory error over the test horizon and energy error over ``long_steps``; a failure is recorded, not raised."""
    out = {}
    t0 = time.perf_counter()
    try:
        pred = model.rollout(test["x0"], test["ref"].shape[1] - 1, mu=test["mu"], dt=bench.dt)
        per_traj = relative_trajectory_error(pred, test["ref"])[:, 1:].max(axis=1)
        out.update(
            traj_error_median=float(np.median(per_traj)),
            traj_error_max=float(np.max(per_traj)),
            traj_steps=int(test["ref"].shape[1] - 1),
        )
    except Exception as exc:  # a Newton failure is a result
        out["traj_failure"] = f"{type(exc).__name__}: {exc}"
    out["rollout_time_s"] = time.perf_counter() - t0
    try:
        long = model.rollout(test["x0"], long_steps, mu=test["mu"], dt=bench.dt)
        energy = bench.system.hamiltonian(long.reshape(-1, bench.dim), np.repeat(test["mu"], long_steps + 1)[:, None])
        energy = energy.reshape(len(test["x0"]), long_steps + 1)
        rel = (np.abs(energy - energy[:, :1]) / np.abs(energy[:, :1])).max(axis=1)
        if not np.all(np.isfinite(rel)):
            raise FloatingPointError("non-finite energy along the long rollout")
        out.update(
            energy_error_median=float(np.median(rel)), energy_error_max=float(np.max(rel)), energy_steps=int(long_steps)
        )
    except Exception as exc:
        out["energy_failure"] = f"{type(exc).__name__}: {exc}"
    return out


# --------------------------------------------------------------------------- configurations
def fit_timed(make, x0, x1, mu, dt, repeats: int):
    """``repeats`` fits of fresh models; the last model and the median wall time."""
    times, model = [], None
    for _ in range(max(1, repeats)):
        model = make()
        t0 = time.perf_counter()
        model.fit(x0, x1, mu=mu, dt=dt)
        times.append(time.perf_counter() - t0)
    return model, _protocol.summary(times)


def _jsonable_attr(value):
    try:
        import json

        json.dumps(value, default=str)
        return value
    except (TypeError, ValueError):
        return repr(value)


def run_config(label: str, make, bench, data, test, args, settings=None) -> dict:
    """Fit and score one configuration; any exception becomes the row's ``error``."""
    x0, x1, mu = data
    row = {"config": label, "max_centers": args.max_centers, "n_samples": int(len(x0))}
    if settings is not None:
        row["settings"] = settings
    try:
        model, timing = fit_timed(make, x0, x1, mu, bench.dt, args.repeats)
    except Exception as exc:
        row.update(ok=False, error=f"fit: {type(exc).__name__}: {exc}")
        print(f"  {bench.name} {label}: fit failed: {row['error']}", flush=True)
        return row
    row.update(
        fit_time_s=timing["median_s"],
        fit_timing=timing,
        n_centers=int(model.n_centers_),
        update=getattr(model, "update_", None) or model.update,
    )
    hist = getattr(model, "history_", None)
    if hist is not None:
        row["train_max_residual"] = float(hist.train_max_residual[-1])
        row["stop_reason"] = getattr(hist, "stop_reason", None)
    for attr in ("choice_", "diagnostics_"):
        if hasattr(model, attr):
            row[attr.rstrip("_")] = _jsonable_attr(getattr(model, attr))
    row.update(trajectory_metrics(model, bench, test, args.long_steps))
    row["ok"] = "traj_failure" not in row and "energy_failure" not in row
    print(
        f"  {bench.name} {label}: {row['n_centers']} centres, fit {row['fit_time_s']:.1f} s, traj median/max "
        f"{row.get('traj_error_median', float('nan')):.2e}/{row.get('traj_error_max', float('nan')):.2e}, energy max "
        f"{row.get('energy_error_max', float('nan')):.2e} {'' if row['ok'] else '(FAILURES recorded)'}",
        flush=True,
    )
    return row


def hand_search(bench, data, args) -> tuple[dict, dict]:
    """Choose the hand settings on an 80/20 split of the training samples; returns ``(settings, record)``."""
    x0, x1, mu = data
    rng = np.random.default_rng(7)
    perm = rng.permutation(len(x0))
    n_tr = int(0.8 * len(x0))
    tr, va = perm[:n_tr], perm[n_tr:]
    t_start = time.perf_counter()
    rows, seen = [], {}
    recorded = HAND[bench.name]
    base = {k: recorded[k] for k in ("family", "update", "eps_state", "eps_mu", "ratio")}
    if args.search_start == "default":  # the start a person would take: shapes ~ 1 / spread, 1 / parameter range
        base.update(eps_state=0.5, eps_mu=float(1.0 / (bench.mu_range[1] - bench.mu_range[0])), ratio=1.0)
    base = with_overrides(base, args.search_from)  # NAME=VALUE overrides of the start

    def score(settings) -> float:
        key = tuple(sorted((k, round(v, 12) if isinstance(v, float) else v) for k, v in settings.items()))
        if key in seen:
            return seen[key]
        t0 = time.perf_counter()
        row = {"settings": dict(settings)}
        try:
            model = hand_model(settings, x0[tr], args.search_centers or args.max_centers)
            model.fit(x0[tr], x1[tr], mu=mu[tr], dt=bench.dt)
            row.update(val_one_step=one_step_error(model, x0[va], x1[va], mu[va], bench.dt), n_centers=model.n_centers_)
            row["score"] = row["val_one_step"]
        except Exception as exc:  # a candidate whose fit or Newton solve fails ranks last
            row.update(error=f"{type(exc).__name__}: {exc}", score=np.inf)
        row["time_s"] = time.perf_counter() - t0
        rows.append(row)
        seen[key] = row["score"]
        print(f"    {bench.name} {settings}: val {row['score']:.3e} ({row['time_s']:.0f} s)", flush=True)
        return row["score"]

    # kernel family x update at the start shapes, then a coordinate search over the shapes and the q/p ratio
    names = [n for n in SEARCH_NAMES if n in args.search_params]
    chosen, best_score = run_search(args, score, base, SEARCH_NAMES, names, args.search_factor, label=f"{bench.name} ")
    record = search_record(
        base,
        rows,
        t_start,
        best_score,
        split={"train": int(n_tr), "validation": int(len(va)), "seed": 7},
        score="mean relative one-step error on the validation split",
        max_centers=args.search_centers or args.max_centers,
        families=list(args.search_families),
        updates=list(args.search_updates),
        params=names,
        factor=args.search_factor,
        sweeps=args.search_sweeps,
    )
    return chosen, record


# --------------------------------------------------------------------------- main
def parse_args(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--systems",
        nargs="+",
        default=["coupled_pendulums", "fpu_chain", "kepler"],
        choices=["coupled_pendulums", "fpu_chain", "kepler"],
    )
    parser.add_argument("--configs", nargs="+", default=["defaults", "hand"], choices=["defaults", "hand"])
    parser.add_argument("--samples", type=int, default=5000, help="training samples per system (default 5000)")
    parser.add_argument("--max-centers", type=int, default=1000, help="centre budget of both configurations")
    parser.add_argument("--n-test", type=int, default=20, help="test trajectories (states x parameters)")
    parser.add_argument("--steps", type=int, default=200, help="test horizon in steps (default 200)")
    parser.add_argument("--long-steps", type=int, default=None, help="energy horizon (default 10 x --steps)")
    add_search_arguments(
        parser,
        search_help="redo the hand search instead of the recorded settings",
        starts=["recorded", "default"],
        start_default="default",
        start_help="start the search at the recorded settings or at 1/spread, 1/range (default)",
        names=SEARCH_NAMES,
        sweeps=2,
        factor=2.0,
    )
    parser.add_argument(
        "--search-from",
        nargs="*",
        default=[],
        metavar="NAME=VALUE",
        help="override the search start, e.g. eps_state=0.1 family=imq",
    )
    parser.add_argument(
        "--search-centers", type=int, default=None, help="centre budget during the search (default: --max-centers)"
    )
    parser.add_argument("--seed", type=int, default=0, help="training seed (test seed: seed + 1000)")
    parser.add_argument(
        "--big", action="store_true", help="the user story: coupled pendulums, 30,000 samples, 4,000 centres"
    )
    parser.add_argument("--quick", action="store_true", help="tiny sizes: checks that the script runs (seconds)")
    parser.add_argument(
        "--progress",
        action="store_true",
        help="show the library's progress log (the greedy's centres and residuals; on with --big)",
    )
    _protocol.add_arguments(parser, threads=1, repeats=1, json_default=str(RESULTS))
    args = parser.parse_args(argv)
    if args.big:
        args.systems, args.samples, args.max_centers, args.progress = ["coupled_pendulums"], 30_000, 4000, True
    if args.quick:
        args.samples, args.max_centers, args.n_test, args.steps = 300, 40, 4, 20
        args.long_steps = args.long_steps or 60
        quick_search(args)
        args.search_sweeps = 1
    if args.long_steps is None:
        args.long_steps = 10 * args.steps
    return args


def ratios(rows: dict) -> dict:
    """``defaults / hand`` per metric where both exist (below 1: the defaults win)."""
    d, h = rows.get("defaults"), rows.get("hand")
    if not d or not h:
        return {}
    if "error" in d or "error" in h:
        return {"within_goal": False, "reason": "the " + ("defaults" if "error" in d else "hand") + " fit failed"}
    out = {}
    for key in ("traj_error_median", "traj_error_max", "energy_error_max", "fit_time_s"):
        if key in d and key in h and h[key] > 0:
            out[key] = d[key] / h[key]
    acc = [out[k] for k in ("traj_error_median", "traj_error_max") if k in out]
    out["within_goal"] = bool(d.get("ok") and h.get("ok") and acc and max(acc) <= GOAL)
    return out


def main(argv=None) -> dict:
    args = parse_args(argv)
    warnings.simplefilter("ignore", ExtrapolationWarning)
    if args.progress:
        from pymor.core.logger import set_log_levels

        set_log_levels({"sympredict": "INFO"})
    benches = make_benchmarks()
    result = {
        "goal": f"defaults within {GOAL}x of the hand tuning (median and max trajectory error)",
        "settings": {k: v for k, v in vars(args).items() if k != "json"},
        "systems": {},
    }
    with _protocol.limits(args.blas_threads, numba_threads=args.threads):
        for name in args.systems:
            bench = benches[name]
            t0 = time.perf_counter()
            x0, mu = bench.sample(args.samples, seed=args.seed)
            x1 = bench.system.flow(x0, mu[:, None], bench.dt)
            data_s = time.perf_counter() - t0
            test = make_test_set(bench, args.n_test, args.steps, seed=args.seed + 1000)
            print(
                f"{name}: {args.samples} samples ({data_s:.1f} s), {args.n_test} test trajectories x {args.steps} steps, "
                f"energy over {args.long_steps}",
                flush=True,
            )
            entry = {
                "title": bench.title,
                "notes": bench.notes,
                "dim": bench.dim,
                "mu": {"name": bench.mu_name, "unit": bench.mu_unit, "range": list(bench.mu_range)},
                "dt": bench.dt,
                "units": bench.units,
                "n_samples": args.samples,
                "max_centers": args.max_centers,
                "data_time_s": data_s,
                "state_std": x0.std(axis=0).tolist(),
                "rows": {},
            }
            if "defaults" in args.configs:
                entry["rows"]["defaults"] = run_config(
                    "defaults",
                    lambda: SymplecticKernelPredictor(max_centers=args.max_centers),
                    bench,
                    (x0, x1, mu),
                    test,
                    args,
                )
            if "hand" in args.configs:
                if args.search:
                    settings, search = hand_search(bench, (x0, x1, mu), args)
                else:
                    settings = {k: HAND[name][k] for k in ("family", "update", "eps_state", "eps_mu", "ratio")}
                    search = HAND[name]["search"]
                full = dict(
                    settings,
                    factors=[float(f) for f in settings["ratio"] * base_factors(x0)],
                    eps_state_absolute=settings["eps_state"] / spread(x0),
                )
                row = run_config(
                    "hand",
                    lambda: hand_model(settings, x0, args.max_centers),
                    bench,
                    (x0, x1, mu),
                    test,
                    args,
                    settings=full,
                )
                row["search"] = search
                entry["rows"]["hand"] = row
            entry["defaults_over_hand"] = ratios(entry["rows"])
            result["systems"][name] = entry
        print_table(result)
        if args.json:
            _protocol.write_json(
                args.json,
                result,
                _protocol.record_options(
                    args,
                    repeats=args.repeats,
                    warmup=0,
                    notes="fit times on a shared machine are indicative only; errors are deterministic given the seeds",
                ),
            )
    return result


def _fmt(row, key, spec=".2e"):
    v = row.get(key)
    return "-" if v is None else format(v, spec)


def print_table(result: dict) -> None:
    """One Markdown table per system."""
    for name, entry in result["systems"].items():
        print(f"\n{name}: {entry['title']}  ({entry['n_samples']} samples, max_centers {entry['max_centers']})")
        print("| config | centres | traj median | traj max | energy max | fit s | status |")
        print("|---|---|---|---|---|---|---|")
        for label, row in entry["rows"].items():
            status = (
                "ok" if row.get("ok") else (row.get("error") or row.get("traj_failure") or row.get("energy_failure"))
            )
            print(
                f"| {label} | {row.get('n_centers', '-')} | {_fmt(row, 'traj_error_median')} | {_fmt(row, 'traj_error_max')} "
                f"| {_fmt(row, 'energy_error_max')} | {_fmt(row, 'fit_time_s', '.1f')} | {str(status)[:80]} |"
            )
        if entry.get("defaults_over_hand"):
            print(f"defaults / hand: {entry['defaults_over_hand']}")


if __name__ == "__main__":
    main()
