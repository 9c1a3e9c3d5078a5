"""The kernel search's share of a default fit, with and without successive halving or the quick preset, and what
each chooses.

Per system, ``SymplecticKernelPredictor(max_centers=m)`` (the defaults) is fitted twice in one process, with the two
configurations of ``--configs`` (default ``full halving``) in alternating order from one system to the next (the
machine may be shared; compare the ratios, the second configuration's over the first's):

* ``full``: ``search=KernelSearch(early_stop=False)``: every search candidate fitted to its full size;
* ``default``: ``search=KernelSearch()``: the default, a candidate clearly losing stopped early (``early_stop``: in
  the first stage at a quarter, half or three quarters of ``m_star``, the families after the first bounded by their
  update's best; in the second stage's coordinate search at half its centres);
* ``halving``: ``search=KernelSearch(halving=True)``: candidates compared first at a fraction of their centres, and only
  those not clearly losing there fitted to full size (:class:`sympredict.KernelSearch`, Notes);
* ``quick``: ``search=KernelSearch.quick()``: candidates compared at 100 and 250 centres on 1,200 samples, with
  halving; only the final-size stage fits to ``max_centers``;
* ``previous``: the default with its first stage's early stop as it was before (at half of ``m_star`` only, every
  grid bounded by its own candidates; set around the fit in this study only), for a side-by-side run with
  ``default``;
* ``norefine``: the default without the second stage's coordinate refinement (``refine_sweeps=0``: the finalists'
  starts only), to measure what the refinement costs and what it changes.

The systems: the coupled pendulums and the Kepler orbits of ``defaults_acceptance.py`` (``--samples`` one-step
samples), the Hénon-Heiles system (``lambda`` in [0.8, 1.0], ``dT = 0.5``, ``--samples`` samples), the planar
restricted three-body problem (``--traj`` trajectories x 60 steps of 0.05 near L4), all at ``max_centers``
``--centers`` (the three-body problem also at each of ``--three-body-centers``), the README's pendulum (40
trajectories x 50 steps, ``max_centers=300``, as the README fits it) and noisy pendulum trajectories (30 x 20 steps of
0.05, noise 1e-3 on the states, ``max_centers=120``; held-out and test data without noise).

Recorded: fit wall time, the search's own time (``search_.seconds``) and its share of the fit (``search_.share``),
where the search's time went (``stage_s``: the candidates' fit and scoring seconds of each stage, 1 the grids, 2 the
finalists' coordinate search, 3 the structure stage, 4 the final-size stage, ``other`` the rest of the search), the
greedy's work per stage (``stage_work``: the sum of the candidates' centres squared, free of timing noise) and
the final fit's own seconds (``final_fit_s``: the fit less the search), the number of candidate fits, the choice
(kernels, update), the final model's held-out one-step error (mean of ``|step(x0) - x1| / |x1|`` over fresh samples)
and rollout errors (median and max over ``--n-test`` test trajectories of ``--steps`` steps of the largest relative
state error along each).  With ``--repeats r`` every system's two fits are repeated ``r`` times in the same process
(the two configurations' order alternating from one repeat to the next): ``repeats`` keeps each repeat's seconds and
shares, ``median_search_share`` and ``median_search_cpu_share`` their medians per configuration (of the wall
times, and of this process's processor times, less sensitive to other jobs on a shared machine); the errors and the ratios are those of the first repeat (the choice is deterministic:
``same_choice_across_repeats`` checks it).

Run:  python sympredict_paper/studies/search_cost.py        # writes docs/data/search_cost.json
      python sympredict_paper/studies/search_cost.py --configs full quick --systems three_body noisy_pendulum \
          readme_pendulum kepler henon_heiles coupled_pendulums --three-body-centers 2000 \
          --json docs/data/search_cost_quick.json
      python sympredict_paper/studies/search_cost.py --configs full quick --systems three_body --repeats 3 \
          --json docs/data/search_cost_stages.json
      python sympredict_paper/studies/search_cost.py --configs full default --systems three_body noisy_pendulum \
          readme_pendulum kepler henon_heiles coupled_pendulums --json docs/data/search_cost_early.json
      python sympredict_paper/studies/search_cost.py --configs full default --systems three_body --traj 300 \
          --repeats 3 --json docs/data/search_cost_early_300.json
      python sympredict_paper/studies/search_cost.py --decay --systems three_body noisy_pendulum readme_pendulum \
          kepler henon_heiles coupled_pendulums --json docs/data/search_decay.json
      python sympredict_paper/studies/search_cost.py --decay --systems three_body noisy_pendulum readme_pendulum \
          kepler henon_heiles coupled_pendulums --json docs/data/search_decay_stage1.json
      python sympredict_paper/studies/search_cost.py --configs previous default --systems three_body \
          readme_pendulum kepler henon_heiles coupled_pendulums noisy_pendulum --json docs/data/search_cost_stage1.json
      python sympredict_paper/studies/search_cost.py --configs previous default --systems three_body --traj 300 \
          --repeats 3 --json docs/data/search_cost_stage1_300.json
      python sympredict_paper/studies/search_cost.py --configs full default --systems three_body readme_pendulum \
          kepler henon_heiles coupled_pendulums noisy_pendulum --json docs/data/search_cost_reversal.json
      python sympredict_paper/studies/search_cost.py --configs full default --systems three_body --traj 300 \
          --json docs/data/search_cost_reversal_300.json
      python sympredict_paper/studies/search_cost.py --configs default norefine --systems three_body \
          readme_pendulum kepler henon_heiles coupled_pendulums noisy_pendulum --json docs/data/search_cost_norefine.json
      python sympredict_paper/studies/search_cost.py --configs default norefine --systems three_body --traj 300 \
          --repeats 3 --json docs/data/search_cost_norefine_300.json
One BLAS and one numba thread.
"""

from __future__ import annotations

import argparse
import contextlib
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import _protocol  # sympredict_paper/studies/ (the script's folder is on sys.path)
from defaults_acceptance import make_benchmarks, make_test_set, one_step_error, trajectory_metrics

import sympredict.estimators.auto as _auto
import sympredict.estimators.search as _search
from sympredict import KernelSearch, SymplecticKernelPredictor
from sympredict.estimators.search import EARLY_STOP, EarlyStop
from sympredict.data import FlowMapData

RESULTS = Path(__file__).resolve().parents[2] / "docs" / "data" / "search_cost.json"
SYSTEMS = ("three_body", "readme_pendulum", "kepler", "henon_heiles", "coupled_pendulums", "noisy_pendulum")
#: The configurations compared: the default search, successive halving, and the quick preset.
CONFIGS = {
    "full": lambda: KernelSearch(early_stop=False),
    "default": lambda: KernelSearch(),
    "halving": lambda: KernelSearch(halving=True),
    "quick": lambda: KernelSearch.quick(),
    "previous": lambda: KernelSearch(),
    "norefine": lambda: KernelSearch(refine_sweeps=0),
}


@contextlib.contextmanager
def _previous_first_stage():
    """The default search with its first stage as it was before the stage's early stop checked three checkpoints and
    bounded the other families by their update's best (for a side-by-side run with ``default``, here only): the early
    stop at half of ``m_star`` alone (factor 200) and every grid bounded by its own candidates."""
    margins, grid_search = _search.E_VAL_STOP_MARGINS, _auto.grid_search

    def own_grid_only(*args, bound=np.inf, **kwargs):
        return grid_search(*args, **kwargs)

    _search.E_VAL_STOP_MARGINS, _auto.grid_search = ((0.5, 200.0),), own_grid_only
    try:
        yield
    finally:
        _search.E_VAL_STOP_MARGINS, _auto.grid_search = margins, grid_search


#: What a configuration changes around its fit (only ``previous``: the first stage's earlier rule).
AROUND = {"previous": _previous_first_stage}


def _relative_rollout(model, x0, mu, dt, ref) -> dict:
    """Median and max over the test trajectories of the largest relative state error along each."""
    try:
        pred = model.rollout(x0, ref.shape[1] - 1, mu=mu, dt=dt)
    except Exception as exc:  # a Newton failure is a result
        return {"traj_failure": f"{type(exc).__name__}: {exc}"}
    err = (np.linalg.norm(pred - ref, axis=2) / np.linalg.norm(ref, axis=2))[:, 1:].max(axis=1)
    return {
        "traj_error_median": float(np.median(err)),
        "traj_error_max": float(err.max()),
        "traj_steps": int(ref.shape[1] - 1),
    }


def make_case(name: str, args) -> dict:
    """``{'data', 'heldout': (x0, x1, mu, dt), 'metrics': callable(model) -> dict, 'max_centers'}``."""
    if name in ("coupled_pendulums", "kepler"):
        bench = make_benchmarks()[name]
        x0, mu = bench.sample(args.samples, seed=11)
        data = FlowMapData(x0, bench.system.flow(x0, mu[:, None], bench.dt), mu[:, None], np.full(len(x0), bench.dt))
        h0, hmu = bench.sample(1000, seed=12)
        heldout = (h0, bench.system.flow(h0, hmu[:, None], bench.dt), hmu, bench.dt)
        test = make_test_set(bench, args.n_test, args.steps, seed=13)
        return {
            "data": data,
            "heldout": heldout,
            "max_centers": args.centers,
            "metrics": lambda model: trajectory_metrics(model, bench, test, args.steps),
        }
    if name == "henon_heiles":
        from sympredict_paper.henon_heiles import DT_HH, henon_heiles_data, henon_heiles_test_instances
        from sympredict.systems.henon_heiles import HenonHeiles

        system, e_max = HenonHeiles(), 1.0 / 12.0
        data = henon_heiles_data(system, np.linspace(0.8, 1.0, 5), args.samples // 5, e_max, seed=0)
        held = henon_heiles_data(system, np.linspace(0.82, 0.98, 5), 200, e_max, seed=500)
        x0, lam = henon_heiles_test_instances(system, int(np.ceil(np.sqrt(args.n_test))), e_max, seed=0)
        x0, lam = x0[: args.n_test], lam[: args.n_test]
        ref = system.trajectory(x0, lam, DT_HH, args.steps)
        return {
            "data": data,
            "heldout": (held.x0, held.x1, held.mu, DT_HH),
            "max_centers": args.centers,
            "metrics": lambda model: _relative_rollout(model, x0, lam, DT_HH, ref),
        }
    if name == "three_body":
        from sympredict.systems.three_body import MU_RANGE, ThreeBody, librating_states

        tb, dt, steps = ThreeBody(), 0.05, 60

        def trajectories(n, seed, k):
            mu = np.random.default_rng(seed).uniform(*MU_RANGE, n)
            return tb.trajectory(librating_states(mu, n, seed=seed + 1), mu, dt, k), mu

        traj, mu = trajectories(args.traj, 0, steps)
        data = FlowMapData(
            traj[:, :-1].reshape(-1, 4),
            traj[:, 1:].reshape(-1, 4),
            np.repeat(mu, steps),
            np.full(args.traj * steps, dt),
        )
        vt, vmu = trajectories(20, 500, steps)
        heldout = (vt[:, :-1].reshape(-1, 4), vt[:, 1:].reshape(-1, 4), np.repeat(vmu, steps), dt)
        tt, tmu = trajectories(args.n_test, 1000, args.steps)
        return {
            "data": data,
            "heldout": heldout,
            "max_centers": args.centers,
            "metrics": lambda model: _relative_rollout(model, tt[:, 0], tmu, dt, tt),
        }
    if name == "noisy_pendulum":  # 30 pendulum trajectories x 20 steps, noise 1e-3 on the states, 120 centres
        from sympredict.data import TrajectoryData
        from sympredict.systems.pendulum import Pendulum

        rng = np.random.default_rng(0)
        pendulum = Pendulum()
        x0 = np.column_stack([rng.uniform(-1, 1, 30), rng.uniform(-1, 1, 30)])
        clean = pendulum.trajectory(x0, np.full(30, 0.75), 0.05, 20)
        data = TrajectoryData(clean + 1e-3 * rng.normal(size=clean.shape), None, 0.05)
        r2 = np.random.default_rng(7)
        h0 = np.column_stack([r2.uniform(-1, 1, 500), r2.uniform(-1, 1, 500)])
        h1 = pendulum.flow(h0, 0.75, 0.05)
        t0 = np.column_stack([r2.uniform(-1, 1, args.n_test), r2.uniform(-1, 1, args.n_test)])
        ref = pendulum.trajectory(t0, np.full(args.n_test, 0.75), dt=0.05, n_steps=args.steps)
        return {
            "data": data,
            "heldout": (h0, h1, None, 0.05),
            "max_centers": 120,
            "metrics": lambda model: _relative_rollout(model, t0, None, 0.05, ref),
        }
    if name == "readme_pendulum":  # the README's example, as it fits it
        from sympredict.systems.pendulum import Pendulum

        rng = np.random.default_rng(0)
        pendulum, mu = Pendulum(), rng.uniform(0.7, 0.8, size=40)
        x0 = np.column_stack([rng.uniform(-1.5, 1.5, 40), rng.uniform(-1.0, 1.0, 40)])
        states = pendulum.trajectory(x0, mu, dt=0.1, n_steps=50)
        data = FlowMapData(
            states[:, :-1].reshape(-1, 2), states[:, 1:].reshape(-1, 2), np.repeat(mu, 50), np.full(40 * 50, 0.1)
        )
        r2 = np.random.default_rng(7)
        hmu = r2.uniform(0.7, 0.8, 500)
        h0 = np.column_stack([r2.uniform(-1.5, 1.5, 500), r2.uniform(-1.0, 1.0, 500)])
        h1 = np.vstack([pendulum.flow(h0[i : i + 1], hmu[i], 0.1) for i in range(500)])
        tmu = r2.uniform(0.7, 0.8, args.n_test)
        t0 = np.column_stack([r2.uniform(-1.5, 1.5, args.n_test), r2.uniform(-1.0, 1.0, args.n_test)])
        ref = pendulum.trajectory(t0, tmu, dt=0.1, n_steps=args.steps)
        return {
            "data": data,
            "heldout": (h0, h1, hmu, 0.1),
            "max_centers": 300,
            "metrics": lambda model: _relative_rollout(model, t0, tmu, 0.1, ref),
        }
    raise ValueError(f"unknown system {name!r}; choose from {SYSTEMS}")


def max_centers_of(row: dict, search) -> bool:
    """Was the candidate of ``row`` fitted with the estimator's ``max_centers`` (the final-size stage, or a second
    stage at the final size)?"""
    return row.get("stage") == 4 or (search.final_size == 0 and row.get("stage") in (2, 3))


def stage_seconds(search) -> dict:
    """``search_.stage_seconds`` with string keys (``'1'`` to ``'4'``) and ``'other'``: the rest of the search's
    seconds (normalisation, tests of the structure, bookkeeping)."""
    out = {str(stage): seconds for stage, seconds in search.stage_seconds.items()}
    out["other"] = float(search.seconds) - sum(out.values())
    return out


def stage_work(search) -> dict:
    """``{stage: sum of n_centers^2 over the stage's candidates}`` (string keys, as :func:`stage_seconds`)."""
    out = {}
    for row in search.table:
        key = str(row.get("stage"))
        out[key] = out.get(key, 0) + int(row.get("n_centers") or 0) ** 2
    return out


def run(label: str, case: dict) -> dict:
    data, (h0, h1, hmu, hdt) = case["data"], case["heldout"]
    model = SymplecticKernelPredictor(max_centers=case["max_centers"], search=CONFIGS[label]())
    t0, c0 = time.perf_counter(), time.process_time()
    with warnings.catch_warnings(), AROUND.get(label, contextlib.nullcontext)():
        warnings.simplefilter("ignore")
        model.fit(data)
    fit_s, fit_cpu = time.perf_counter() - t0, time.process_time() - c0
    search = model.search_
    table = search.table
    out = {
        "config": label,
        "fit_s": fit_s,
        "search_s": float(search.seconds),
        "search_share": search.seconds / fit_s,
        "fit_cpu_s": fit_cpu,
        "search_cpu_s": float(search.cpu_seconds),
        "search_cpu_share": search.cpu_seconds / fit_cpu,
        "fits": len(table),
        "fits_full_size": sum(1 for r in table if "rung" not in r and not r.get("cut")),
        # candidates fitted to the estimator's max_centers (the final size; the final fit itself not counted)
        "fits_at_max_centers": sum(
            1
            for r in table
            if r.get("stage") != 1 and "rung" not in r and not r.get("cut") and max_centers_of(r, search)
        ),
        # where the search's time went: each stage's candidates (fits and their scoring), and the rest of the search
        "stage_s": stage_seconds(search),
        # the greedy's work in each stage, the sum of centres^2 over its candidates (a fit costs about its candidate
        # functionals times centres^2, the same functionals throughout a stage): a cost free of timing noise
        "stage_work": stage_work(search),
        "final_fit_s": fit_s - float(search.seconds),
        "choice": {k: repr(v) for k, v in model.choice_.items()},
        "centers": int(model.n_centers_),
    }
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out["held_out_error"] = one_step_error(model, h0, h1, hmu, hdt)
        out.update(case["metrics"](model))
    print(
        f"  {label:>8s}: fit {fit_s:6.1f} s, search {out['search_s']:6.1f} s ({100 * out['search_share']:.0f} %; "
        f"processor time {100 * out['search_cpu_share']:.0f} %), "
        f"{out['fits']} fits ({out['fits_full_size']} full size), held-out {out['held_out_error']:.3e}, rollout "
        f"median {out.get('traj_error_median', np.nan):.3e}, choice {out['choice']}",
        flush=True,
    )
    return out


@dataclass
class _Recorder(EarlyStop):
    """An :class:`EarlyStop` that never stops: it keeps each full-size candidate's checkpoint scores (``history``,
    one dict per candidate fitted, in the order of the search's table rows of stages 2 to 4)."""

    history: list = field(default_factory=list)

    def start(self, bound: float, reference=None) -> "EarlyStop":
        self.history.append({})
        return super().start(np.inf)

    def give_up(self, c: int, m: int, value: float) -> bool:
        self.history[-1][int(c)] = float(value)
        return False


def recorded_fit(case: dict, recorder: "_Recorder") -> SymplecticKernelPredictor:
    """The defaults fitted to ``case['data']`` with every search candidate at its full size (``early_stop=False``),
    ``recorder`` keeping each later-stage candidate's checkpoint scores (warnings silenced: candidates may underfit)."""
    model = SymplecticKernelPredictor(max_centers=case["max_centers"], search=KernelSearch(early_stop=False))
    token = EARLY_STOP.set(recorder)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            model.fit(case["data"])
    finally:
        EARLY_STOP.reset(token)
    return model


def decay(name: str, case: dict) -> dict:
    """How far each search candidate's score fell from a checkpoint to its full size (the early stop's margin):
    the default search with every candidate at full size (``early_stop=False``); the first stage's ``E_val`` at a
    quarter, half and three quarters of ``m_star`` (``E_val_quarter``, ``E_val_half``, ``E_val_three_quarters``) over
    ``E_val(m_star)``; the later stages' held-out one-step error at a quarter and
    at half of the centres (the prefix of the same fit) over the full fit's.  Only candidates that reached their size."""
    recorder = _Recorder(margins=((0.25, np.inf), (0.5, np.inf)))
    model = recorded_fit(case, recorder)
    table = model.search_.table
    first = {
        key: [
            r[f"E_val_{key}"] / r["E_val"]
            for r in table
            if r.get("stage") == 1 and f"E_val_{key}" in r and r.get("complete")
        ]
        for key in ("quarter", "half", "three_quarters")
    }
    later = [r for r in table if r.get("stage") in (2, 3, 4)]
    assert len(later) == len(recorder.history), "one recorded candidate per row of stages 2 to 4"
    m_final, out = model.search_.m_final, {"quarter": [], "half": []}
    for row, scores in zip(later, recorder.history):
        m = model.search_.final_size if row["stage"] == 4 else m_final
        if not np.isfinite(row["score"]) or row["n_centers"] < m or row["score"] <= 0:
            continue
        for key, fraction in (("quarter", 0.25), ("half", 0.5)):
            value = scores.get(int(fraction * m))
            if value is not None and np.isfinite(value):
                out[key].append(value / float(row["score"]))
    result = {
        "system": name,
        **{
            f"first_stage_{k}": {"n": len(v), "max": max(v, default=None), "median": _median(v)}
            for k, v in first.items()
        },
        **{f"one_step_{k}": {"n": len(v), "max": max(v, default=None), "median": _median(v)} for k, v in out.items()},
        "choice": {k: repr(v) for k, v in model.choice_.items()},
    }
    print(f"  {name}: {result}", flush=True)
    return result


def add_case_arguments(parser: argparse.ArgumentParser) -> None:
    """The options :func:`make_case` reads: the systems, their sizes and the test rollouts."""
    parser.add_argument("--systems", nargs="+", default=list(SYSTEMS), choices=SYSTEMS)
    parser.add_argument("--samples", type=int, default=5000)
    parser.add_argument("--traj", type=int, default=100, help="three-body training trajectories (60 steps each)")
    parser.add_argument("--centers", type=int, default=1000)
    parser.add_argument("--n-test", type=int, default=20)
    parser.add_argument("--steps", type=int, default=200)


def _median(values):
    return float(np.median(values)) if values else None


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_case_arguments(parser)
    parser.add_argument(
        "--repeats",
        type=int,
        default=1,
        help="fits per configuration and system, side by side in the same process (their median share is kept)",
    )
    parser.add_argument(
        "--configs",
        nargs=2,
        default=["full", "halving"],
        choices=tuple(CONFIGS),
        help="the two configurations compared; the ratios are the second's over the first's",
    )
    parser.add_argument(
        "--three-body-centers",
        type=int,
        nargs="*",
        default=[],
        help="further three-body rows at these max_centers (the search's share at larger sizes)",
    )
    parser.add_argument(
        "--decay",
        action="store_true",
        help="instead of the comparison: how far each search candidate's score fell from a checkpoint to its full "
        "size (the early stop's margin), with every candidate at full size",
    )
    _protocol.add_arguments(parser, threads=1, json_default=str(RESULTS))
    args = parser.parse_args(argv)
    if args.decay:
        with _protocol.limits(args.blas_threads, args.threads):
            protocol = _protocol.record_options(args, repeats=1, warmup=0, notes="one fit per system")
            rows = []
            for name in args.systems:
                rows.append(decay(name, make_case(name, args)))
                summary = {
                    key: max((r[key]["max"] for r in rows if r[key]["max"] is not None), default=None)
                    for key in (
                        "first_stage_quarter",
                        "first_stage_half",
                        "first_stage_three_quarters",
                        "one_step_half",
                        "one_step_quarter",
                    )
                }
                _protocol.write_json(
                    args.json,
                    {"settings": {k: v for k, v in vars(args).items() if k != "json"}, "rows": rows, "max": summary},
                    protocol,
                )
        print(f"wrote {args.json}")
        return
    rows = []
    with _protocol.limits(args.blas_threads, args.threads):
        protocol = _protocol.record_options(
            args,
            repeats=args.repeats,
            warmup=0,
            notes=f"{args.repeats} fit(s) per configuration, side by side in one process, the two "
            "configurations in alternating order from one system (and repeat) to the next",
        )
        jobs = [(name, args.centers) for name in args.systems]
        jobs += [("three_body", m) for m in args.three_body_centers]
        for i, (name, centers) in enumerate(jobs):
            case = make_case(name, argparse.Namespace(**{**vars(args), "centers": centers}))
            print(f"{name}: {len(case['data'])} samples, max_centers {case['max_centers']}", flush=True)
            row = {"system": name, "samples": len(case["data"]), "max_centers": case["max_centers"]}
            first, second = args.configs
            runs = {first: [], second: []}
            for r in range(args.repeats):
                for label in (first, second) if (i + r) % 2 == 0 else (second, first):
                    runs[label].append(run(label, case))
            for label in (first, second):
                row[label] = runs[label][0]
            if args.repeats > 1:
                keys = ("fit_s", "search_s", "search_share", "search_cpu_share", "stage_s", "stage_work", "final_fit_s")
                row["repeats"] = {label: [{k: out[k] for k in keys} for out in runs[label]] for label in runs}
                for key in ("search_share", "search_cpu_share"):  # wall time, and this process's processor time
                    row[f"median_{key}"] = {
                        label: float(np.median([out[key] for out in runs[label]])) for label in runs
                    }
                row["median_stage1_s"] = {
                    label: float(np.median([out["stage_s"].get("1", 0.0) for out in runs[label]])) for label in runs
                }
                row["same_choice_across_repeats"] = all(
                    out["choice"] == runs[label][0]["choice"] for label in runs for out in runs[label]
                )
                print(
                    "  median search share: "
                    + ", ".join(f"{label} {100 * v:.0f} %" for label, v in row["median_search_share"].items()),
                    flush=True,
                )
            full, new = row[first], row[second]
            row["same_choice"] = full["choice"] == new["choice"]
            # the first stage's seconds and each stage's greedy work, the second configuration's over the first's
            row["stage_ratios"] = {
                **({"stage_s_1": new["stage_s"]["1"] / full["stage_s"]["1"]} if full["stage_s"].get("1") else {}),
                **{f"stage_work_{k}": new["stage_work"].get(k, 0) / v for k, v in full["stage_work"].items() if v},
            }
            row["ratios"] = {
                k: new[k] / full[k]
                for k in (
                    "fit_s",
                    "search_s",
                    "fit_cpu_s",
                    "search_cpu_s",
                    "held_out_error",
                    "traj_error_median",
                    "traj_error_max",
                )
                if full.get(k) and k in new
            }
            print(
                f"  {second} / {first}: "
                + ", ".join(f"{k} {v:.3f}" for k, v in row["ratios"].items())
                + f", same choice: {row['same_choice']}",
                flush=True,
            )
            rows.append(row)
            _protocol.write_json(
                args.json, {"settings": {k: v for k, v in vars(args).items() if k != "json"}, "rows": rows}, protocol
            )
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
