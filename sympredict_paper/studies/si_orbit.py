"""A satellite orbit in SI units: the defaults against an expert's tuning at the same number of centres.

System: the planar Kepler problem per unit mass, ``H = |p|^2 / 2 - GM / |q|`` with ``q`` in m, ``p`` in m/s and
the parameter ``GM`` in [3.6e14, 4.4e14] m^3/s^2 (around the Earth's 3.986e14), low Earth orbits: semi-major
axis ``a`` in [6.8e6, 7.4e6] m, eccentricity ``e`` in [0, 0.05] (perigee above the Earth's radius), uniform
periapsis direction and mean anomaly, prograde; ``dT = 60 s`` (about 100 steps per revolution).  Reference flow:
the closed-form Kepler flow of ``defaults_acceptance.py`` (Kepler's equation solved by Newton to round-off).

Training data as a user has them: ``--trajectories`` orbits of ``--steps-per-trajectory`` steps, each from its own
initial state and ``GM`` (a :class:`~sympredict.data.TrajectoryData` in SI units, fitted as given).  Test: ``--n-test``
orbits from the same distribution (another seed); the relative trajectory error ``|x_k - x_ref| / |x_ref|`` (SI
units), its maximum over the first ``--horizon`` steps per orbit, median and maximum over the orbits; the relative
energy error ``|H(x_k) - H(x_0)| / |H(x_0)|`` over ``--long-steps`` steps (2,000), median and maximum over the
orbits of its maximum along the orbit.

Configurations (all with ``max_centers = --max-centers``, fitted and scored in one process):

* ``defaults``: ``SymplecticKernelPredictor(max_centers=m).fit(data)`` on the SI data, nothing else;
* ``defaults_canonical``: the same, on the data in canonical units (length ``L = 7e6 m``, ``GM_ref = 4e14``, time
  ``T = sqrt(L^3 / GM_ref)`` = 926 s: ``dT = 0.065``, ``GM`` in [0.9, 1.1]); predictions converted back to SI.
  The unit-invariance check: the defaults should not care which units the user chose;
* ``defaults_active_set``: the defaults with ``trainer=ActiveSetGreedy()`` (one expert choice swapped in);
* ``expert_exact_greedy``: the expert's settings with the defaults' trainer (the exact greedy);
* ``expert``: what an expert does by hand: canonical units, the symplectic scaling ``Scaled(kernel(eps / spread),
  factors=sqrt(std p / std q))``, a parameter kernel of shape ``eps_mu`` (canonical ``GM``), the active-set greedy,
  the update and family chosen by hand; shapes from :data:`EXPERT` (found by ``--search``: a coordinate search by
  factors of 2 on a validation split of the training trajectories, never on test orbits, from
  :data:`EXPERT_START`; its cost is recorded).

Run:  python sympredict_paper/studies/si_orbit.py --configs defaults expert --search   # 1,000 centres (docs/data/si_orbit.json)
      python sympredict_paper/studies/si_orbit.py --configs expert expert_exact_greedy defaults_active_set
      python sympredict_paper/studies/si_orbit.py --max-centers 4000 --json docs/data/si_orbit_4000.json
      python sympredict_paper/studies/si_orbit.py --quick              # seconds: checks that the script runs
Writes ``docs/data/si_orbit.json`` (``--json``) with the record of ``sympredict_paper/studies/_protocol.py``.
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np

import _protocol  # sympredict_paper/studies/ (the script's folder is on sys.path)
from _coordinate_search import (  # sympredict_paper/studies/
    add_search_arguments,
    quick_search,
    run_search,
    search_record,
    with_overrides,
)
from defaults_acceptance import kepler_H, kepler_flow  # sympredict_paper/studies/

from pathlib import Path

from sympredict import SymplecticKernelPredictor
from sympredict.data import TrajectoryData
from sympredict.exceptions import ExtrapolationWarning
from sympredict.interpolation.greedy import ActiveSetGreedy, ExactGreedy
from sympredict.kernels import KERNEL_FAMILIES
from sympredict.kernels.transforms import Scaled
from sympredict.symplectic.metrics import relative_trajectory_error
from sympredict.systems.flowmaps import FlowFunctionSystem

GOAL = 1.5
RESULTS = Path(__file__).resolve().parents[2] / "docs" / "data" / "si_orbit.json"
GM_RANGE = (3.6e14, 4.4e14)  # m^3/s^2
A_RANGE = (6.8e6, 7.4e6)  # m
E_MAX = 0.05
DT = 60.0  # s
#: canonical units: length L, GM_ref, time T = sqrt(L^3 / GM_ref)
L_UNIT, GM_REF = 7.0e6, 4.0e14
T_UNIT = float(np.sqrt(L_UNIT**3 / GM_REF))
SYSTEM = FlowFunctionSystem(kepler_flow, 4, n_mu=1, H=kepler_H)

#: The expert's settings (canonical units; ``eps_state`` in units of 1 / spread of the scaled states, ``eps_mu`` in
#: 1 / canonical GM), found by ``--search`` at 1,000 centres; see the JSON's ``expert_search`` for the record.
EXPERT = {"family": "imq", "update": "midpoint", "eps_state": 0.25, "eps_mu": 1.25, "ratio": 2.0}
#: Where the search started (shapes ~ 1 / spread and ~ half the inverse width of GM's range, no anisotropy).
EXPERT_START = {"family": "imq", "update": "midpoint", "eps_state": 0.5, "eps_mu": 2.5, "ratio": 1.0}
#: The coordinates the expert's search can move (``--search-params``).
SEARCH_NAMES = ("eps_state", "eps_mu", "ratio")


def sample(n: int, seed: int):
    """``n`` states on LEO orbits and their ``GM``: ``(x (n, 4) in m and m/s, gm (n,))``."""
    rng = np.random.default_rng(seed)
    gm = rng.uniform(*GM_RANGE, n)
    a = rng.uniform(*A_RANGE, n)
    e = rng.uniform(0.0, E_MAX, n)
    omega, mean_anomaly = rng.uniform(0, 2 * np.pi, (2, n))
    ecc = mean_anomaly.copy()
    for _ in range(60):  # Kepler's equation E - e sin E = M
        ecc -= (ecc - e * np.sin(ecc) - mean_anomaly) / (1 - e * np.cos(ecc))
    r = a * (1 - e * np.cos(ecc))
    pos = np.stack([a * (np.cos(ecc) - e), a * np.sqrt(1 - e**2) * np.sin(ecc)], axis=1)
    vel = (np.sqrt(gm * a) / r)[:, None] * np.stack([-np.sin(ecc), np.sqrt(1 - e**2) * np.cos(ecc)], axis=1)
    c, s = np.cos(omega)[:, None], np.sin(omega)[:, None]
    rot = lambda v: np.concatenate([c * v[:, :1] - s * v[:, 1:], s * v[:, :1] + c * v[:, 1:]], axis=1)  # noqa: E731
    return np.concatenate([rot(pos), rot(vel)], axis=1), gm


def to_canonical(x, gm, dt):
    """SI -> canonical units (``q / L``, ``p T / L``, ``GM / GM_ref``, ``dt / T``)."""
    scale = np.array([1 / L_UNIT, 1 / L_UNIT, T_UNIT / L_UNIT, T_UNIT / L_UNIT])
    return x * scale, np.asarray(gm) / GM_REF, dt / T_UNIT


def from_canonical(x):
    return x * np.array([L_UNIT, L_UNIT, L_UNIT / T_UNIT, L_UNIT / T_UNIT])


class Canonical:
    """A model fitted in canonical units, used in SI units (``rollout``/``step`` as a predictor's)."""

    def __init__(self, model):
        self.model = model

    def rollout(self, x0, n_steps, mu=None, dt=None):
        xc, gc, dtc = to_canonical(x0, mu, dt)
        return from_canonical(self.model.rollout(xc, n_steps, mu=gc, dt=dtc))

    def step(self, x0, mu=None, dt=None):
        xc, gc, dtc = to_canonical(x0, mu, dt)
        return from_canonical(self.model.step(xc, mu=gc, dt=dtc))


def training_data(args, seed: int):
    x0, gm = sample(args.trajectories, seed)
    states = SYSTEM.trajectory(x0, gm[:, None], DT, args.steps_per_trajectory)
    return states, gm


def canonical_trajectories(states, gm) -> TrajectoryData:
    xc, gc, dtc = to_canonical(states, gm, DT)
    return TrajectoryData(xc, gc, dtc)


def expert_model(settings: dict, states_c: np.ndarray, max_centers: int, trainer=None):
    """The expert's model for canonical states ``states_c`` (any shape ``(..., 4)``)."""
    x = states_c.reshape(-1, 4)
    sd = x.std(axis=0)
    factors = settings["ratio"] * np.sqrt(sd[2:] / sd[:2])
    spread = float(np.exp(np.mean(0.5 * np.log(sd[:2] * sd[2:]))))
    family = KERNEL_FAMILIES[settings["family"]]
    return SymplecticKernelPredictor(
        Scaled(family(settings["eps_state"] / spread), factors=[float(f) for f in factors]),
        mu_kernel=family(settings["eps_mu"]),
        max_centers=max_centers,
        update=settings["update"],
        trainer=ActiveSetGreedy() if trainer is None else trainer,
    )


def metrics(model, test: dict, horizon: int, long_steps: int) -> dict:
    out = {}
    t0 = time.perf_counter()
    try:
        long = model.rollout(test["x0"], long_steps, mu=test["gm"], dt=DT)
        per = relative_trajectory_error(long[:, : horizon + 1], test["ref"])[:, 1:].max(axis=1)
        energy = kepler_H(long.reshape(-1, 4), np.repeat(test["gm"], long_steps + 1)[:, None]).reshape(len(per), -1)
        rel = (np.abs(energy - energy[:, :1]) / np.abs(energy[:, :1])).max(axis=1)
        out.update(
            error_median=float(np.median(per)),
            error_max=float(per.max()),
            energy_median=float(np.median(rel)),
            energy_max=float(rel.max()),
        )
    except Exception as exc:  # a Newton failure is a result
        out["failure"] = f"{type(exc).__name__}: {exc}"
    out["rollout_s"] = time.perf_counter() - t0
    return out


def run(label, make, data, wrap, test, args) -> dict:
    t0 = time.perf_counter()
    try:
        model = make().fit(data)
    except Exception as exc:
        print(f"  {label}: fit failed: {exc}", flush=True)
        return {"config": label, "error": f"{type(exc).__name__}: {exc}"}
    row = {"config": label, "fit_s": time.perf_counter() - t0, "n_centers": int(model.n_centers_)}
    hist = getattr(model, "history_", None)
    if hist is not None:
        row["stop_reason"] = getattr(hist, "stop_reason", None)
    row["choice"] = {k: repr(v) for k, v in (getattr(model, "choice_", None) or {}).items()}
    row["update"] = getattr(model, "update_", None)
    row["kernels"] = repr(getattr(model, "model_", None) and model.model_.kernel)[:400]
    row.update(metrics(wrap(model), test, args.horizon, args.long_steps))
    print(
        f"  {label}: {row['n_centers']} centres ({row.get('stop_reason')}), fit {row['fit_s']:.0f} s, error median/max "
        f"{row.get('error_median', np.nan):.3e}/{row.get('error_max', np.nan):.3e}, energy median/max "
        f"{row.get('energy_median', np.nan):.2e}/{row.get('energy_max', np.nan):.2e} {row.get('failure', '')}",
        flush=True,
    )
    return row


def expert_search(states_c, gm_c, args, start: dict) -> tuple:
    """Coordinate search (factor 2) over the expert's shapes on a split of the training trajectories."""
    rng = np.random.default_rng(7)
    perm = rng.permutation(len(states_c))
    n_va = max(2, len(perm) // 5)
    tr, va = perm[n_va:], perm[:n_va]
    train = TrajectoryData(states_c[tr], gm_c[tr], DT / T_UNIT)
    x0v, x1v = states_c[va, :-1].reshape(-1, 4), states_c[va, 1:].reshape(-1, 4)
    muv = np.repeat(gm_c[va], states_c.shape[1] - 1)
    rows, t_start = [], time.perf_counter()
    base = dict(start)

    def score(settings):
        t0 = time.perf_counter()
        try:
            model = expert_model(settings, states_c[tr], args.max_centers).fit(train)
            pred = model.step(x0v, mu=muv, dt=DT / T_UNIT)
            s = float(np.mean(np.linalg.norm(pred - x1v, axis=1) / np.linalg.norm(x1v - x0v, axis=1)))
        except Exception as exc:
            s = np.inf
            print(f"    {settings}: {exc}", flush=True)
        rows.append({"settings": dict(settings), "score": s, "time_s": time.perf_counter() - t0})
        print(f"    {settings}: {s:.3e} ({rows[-1]['time_s']:.0f} s)", flush=True)
        return s

    chosen, best_score = run_search(args, score, base, SEARCH_NAMES, list(args.search_params), 2.0, label="expert ")
    record = search_record(
        base,
        rows,
        t_start,
        best_score,
        score="mean relative one-step error |Phi(x0) - x1| / |x1 - x0| on a fifth of the training trajectories",
    )
    return chosen, record


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--max-centers", type=int, default=1000)
    p.add_argument("--trajectories", type=int, default=100, help="training orbits (default 100)")
    p.add_argument("--steps-per-trajectory", type=int, default=60, help="steps of each training orbit (default 60)")
    p.add_argument("--n-test", type=int, default=20)
    p.add_argument("--horizon", type=int, default=200, help="steps over which the trajectory error is taken")
    p.add_argument("--long-steps", type=int, default=2000, help="steps of the energy error")
    p.add_argument(
        "--configs",
        nargs="+",
        default=["defaults", "defaults_canonical", "expert"],
        choices=["defaults", "defaults_canonical", "defaults_active_set", "expert", "expert_exact_greedy"],
    )
    add_search_arguments(
        p,
        search_help="redo the expert's shape search",
        starts=["start", "expert"],
        start_default="start",
        start_help="start the expert's search at EXPERT_START (default) or at EXPERT (with --expert overrides)",
        names=SEARCH_NAMES,
        sweeps=1,
    )
    p.add_argument("--expert", nargs="*", default=[], metavar="NAME=VALUE", help="override the expert's settings")
    p.add_argument("--seed", type=int, default=0, help="training seed (test seed: seed + 1000)")
    p.add_argument("--quick", action="store_true", help="tiny sizes (seconds)")
    _protocol.add_arguments(p, threads=1, json_default=str(RESULTS))
    args = p.parse_args(argv)
    if args.quick:
        args.max_centers, args.trajectories, args.steps_per_trajectory = 60, 30, 10
        args.n_test, args.horizon, args.long_steps = 4, 20, 60
        quick_search(args)
    return args


def main(argv=None) -> dict:
    args = parse_args(argv)
    warnings.simplefilter("ignore", ExtrapolationWarning)
    settings = with_overrides(EXPERT, args.expert)
    with _protocol.limits(args.blas_threads, numba_threads=args.threads):
        states, gm = training_data(args, args.seed)
        tx0, tgm = sample(args.n_test, args.seed + 1000)
        test = {"x0": tx0, "gm": tgm, "ref": SYSTEM.trajectory(tx0, tgm[:, None], DT, args.horizon)}
        data_si = TrajectoryData(states, gm, DT)
        data_c = canonical_trajectories(states, gm)
        m = args.max_centers
        print(f"SI orbit: {args.trajectories} x {args.steps_per_trajectory} steps, {m} centres", flush=True)
        result = {
            "system": {
                "H": "|p|^2/2 - GM/|q| (per unit mass; q m, p m/s)",
                "GM_range": list(GM_RANGE),
                "a_range": list(A_RANGE),
                "e_max": E_MAX,
                "dt": DT,
                "canonical_units": {"L": L_UNIT, "GM_ref": GM_REF, "T": T_UNIT},
            },
            "data": {"trajectories": args.trajectories, "steps": args.steps_per_trajectory, "kind": "trajectories"},
            "test": {"orbits": args.n_test, "horizon": args.horizon, "long_steps": args.long_steps},
            "max_centers": m,
            "rows": {},
        }
        rows = result["rows"]
        si, canon = (lambda model: model), Canonical
        if "defaults" in args.configs:
            rows["defaults"] = run(
                "defaults", lambda: SymplecticKernelPredictor(max_centers=m), data_si, si, test, args
            )
        if "defaults_canonical" in args.configs:
            rows["defaults_canonical"] = run(
                "defaults_canonical", lambda: SymplecticKernelPredictor(max_centers=m), data_c, canon, test, args
            )
        if "defaults_active_set" in args.configs:
            rows["defaults_active_set"] = run(
                "defaults_active_set",
                lambda: SymplecticKernelPredictor(max_centers=m, trainer=ActiveSetGreedy()),
                data_si,
                si,
                test,
                args,
            )
        if "expert" in args.configs:
            record = None
            if args.search:
                start = settings if args.search_start == "expert" else EXPERT_START
                settings, record = expert_search(data_c.states, data_c.mu[:, 0], args, start)
            row = run("expert", lambda: expert_model(settings, data_c.states, m), data_c, canon, test, args)
            row["settings"] = settings
            row["search"] = record
            rows["expert"] = row
        if "expert_exact_greedy" in args.configs:  # the expert's settings with the defaults' trainer
            rows["expert_exact_greedy"] = run(
                "expert_exact_greedy",
                lambda: expert_model(settings, data_c.states, m, trainer=ExactGreedy()),
                data_c,
                canon,
                test,
                args,
            )
            rows["expert_exact_greedy"]["settings"] = settings
        d, e = rows.get("defaults"), rows.get("expert")
        if d and e and "error_median" in d and "error_median" in e:
            result["defaults_over_expert"] = {
                k: d[k] / e[k] for k in ("error_median", "error_max", "energy_median", "energy_max")
            }
            result["defaults_over_expert"]["within_goal"] = bool(
                max(result["defaults_over_expert"][k] for k in ("error_median", "energy_median")) <= GOAL
            )
            print(f"defaults / expert: {result['defaults_over_expert']}", flush=True)
        _protocol.write_json(
            args.json,
            result,
            _protocol.record_options(args, notes="shared 2-core machine; errors are deterministic given the seeds"),
        )
    return result


if __name__ == "__main__":
    main()
