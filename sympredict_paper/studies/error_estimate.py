"""How good is the error estimate of a prediction? Effectivities on systems the estimate was not developed on.

``model.rollout(x0, K, mu=..., dt=..., return_error=True)`` returns, next to the
states, an estimate of ``|x_predicted - x_exact|_2`` at every step (the posterior
covariance of the learned gradient, mapped through the implicit update,
propagated along the rollout, calibrated on the fit's held-out samples).  This
script measures it against the true error of the reference flow:

* **effectivity** ``estimate / true`` per (test trajectory, step): its median,
  the share of pairs underestimated by more than 3x (``effectivity < 1/3``),
  over all steps ``1..K`` and at several horizons;
* **rank correlation** (Spearman) between estimate and true error across the
  test trajectories at each horizon: does the estimate tell the worse
  predictions from the better ones?
* **cost**: rollout wall time with and without ``return_error``, side by side in
  the same process (medians of ``--repeats``).

Systems (``--systems``):

* ``three_body`` (held out for the one-step estimate; the propagation's fixed-coordinate part is there for
  its exponential growth): the planar circular restricted three-body problem in the
  rotating frame (:mod:`sympredict.systems.three_body`), mass ratio in [0.010, 0.014],
  tadpole librations near L4 (:func:`~sympredict.systems.three_body.librating_states`),
  ``dT = 0.05``, trained on trajectories (``--traj`` x ``--traj-steps``);
* ``coupled_pendulums``, ``fpu_chain`` (held out for the one-step estimate; the propagation along the
  rollout was revised where it failed on them), ``kepler`` (held out: not looked at before the revised
  propagation was fixed): the physical-unit systems of ``sympredict_paper/studies/defaults_acceptance.py``,
  trained on scattered one-step samples (``--samples``);
* ``pendulum`` (the system the estimate was developed on, for comparison):
  the README's pendulum, lengths in [0.7, 0.8], ``dT = 0.1``, trained on trajectories.
* ``morse`` (never used for the estimate; added with the evaluation of ``error_estimate_share_distance.py``):
  ``H = p^2/2 + (1 - exp(-a q))^2``, ``a`` in [0.8, 1.2], ``dT = 0.1``, states in ``[-0.4, 0.8] x [-0.6, 0.6]``
  (energies below about 0.6 of the dissociation energy 1), trained on trajectories, RK4 reference; not in the
  default ``--systems`` (``docs/data/error_estimate.json`` predates it).
* ``double_well`` (never looked at while the estimate was developed, added after its last revision was chosen):
  ``H = p^2/2 + q^4/4 - a q^2/2``, ``a`` in [0.5, 1.0], ``dT = 0.1``, states in ``[-1.6, 1.6] x [-0.8, 0.8]``
  (orbits in one well and over the barrier), trained on trajectories, RK4 reference
  (:class:`~sympredict.systems.flowmaps.HamiltonianSystem`).

The local scale of the estimate (the held-out ratios of the 20 nearest samples) was chosen on the pendulum and
the coupled pendulums with test trajectories of another seed (``--seed`` + 7000, 100 of them; 10, 20 and 40
neighbours looked at, within 0.05 of each other in rank correlation); the seeds of this study's test
trajectories (``--seed`` + 1000 and + 5000) were not looked at for it.  The residual part (the model's own
one-step residual vectors nearest to each step, carried coherently through the later steps, added in quadrature)
was chosen likewise on the pendulum and the coupled pendulums with 100 test trajectories of seed ``--seed`` + 9000
(``error_estimate_residuals.py`` compares the variants: mean residuals, independent or coherent residual covariances,
an along-track time shift, the local scale on more samples, 5 or 10 neighbours, alone or combined with the
posterior's estimate; ``docs/data/error_estimate_residuals_design.json``, run before the residual part existed);
the other three systems were measured only after the choice.  A later
candidate, the posterior part's scale cut to what the nearest residuals miss (chosen likewise on the same two
systems and seeds), was measured once on all systems and rejected: it underestimated half the (trajectory, step)
pairs of the three-body problem by more than 3x, whose test trajectories leave the residual samples behind.  Its
version that returns to the full scale away from the residual samples (``error_estimate_share_distance.py``: chosen
on the same two systems and seeds among four distance rules, the three-body problem looked at for its underestimates
only) was measured once with this study's seeds on its six systems and the Morse oscillator
(``docs/data/error_estimate_share_distance_final.json``), met the underestimate and effectivity goals on all seven
with no rank correlation below the former design's 90% interval, and is the library's estimate.

Every model is the defaults, ``SymplecticKernelPredictor(max_centers=M).fit(...)``
(``--max-centers``), as a new user would fit it.  Test: ``--n-test`` initial
states with their own parameters (seeds disjoint from training), ``--steps``
steps.  Goals: at most 10% of (trajectory, step) pairs underestimated by more
than 3x, median effectivity at most 30, rank correlation at least 0.6 at the last step.

``--other-draws N`` also fits ``N`` models on other training draws and rolls out the ``--n-rank`` trajectories with
them: how well the errors of other fits rank this fit's errors bounds what an estimate that knows how the fits of
this system err, but not how this particular one does, can reach.

Run:  python sympredict_paper/studies/error_estimate.py                  # writes docs/data/error_estimate.json
      python sympredict_paper/studies/error_estimate.py --systems pendulum --other-draws 4 \
          --json docs/data/error_estimate_other_draws_pendulum.json     # the ranking's ceiling (likewise
                                                                         # coupled_pendulums, --other-draws 3)
      python sympredict_paper/studies/error_estimate.py --quick          # a few minutes, small sizes, no JSON
One BLAS thread (``--blas-threads``), one numba thread (``--threads``); the record of ``sympredict_paper/studies/_protocol.py``.
"""

from __future__ import annotations

import argparse
import json
import time
import warnings
from pathlib import Path

import numpy as np
from scipy.stats import spearmanr

import _protocol  # sympredict_paper/studies/
from defaults_acceptance import make_benchmarks  # sympredict_paper/studies/

from sympredict import SymplecticKernelPredictor
from sympredict.data import FlowMapData
from sympredict.exceptions import ExtrapolationWarning
from sympredict.systems.flowmaps import HamiltonianSystem
from sympredict.systems.pendulum import Pendulum
from sympredict.systems.three_body import MU_RANGE, ThreeBody, librating_states

RESULTS = Path(__file__).resolve().parents[2] / "docs" / "data" / "error_estimate.json"
GOALS = {"share_under_3x_max": 0.10, "median_effectivity_max": 30.0, "rank_correlation_last_min": 0.6}


class _TrajectorySystem:
    """A system trained on trajectories: ``sample(n, seed) -> (x0, mu)``, ``trajectory(x0, mu, dt, K)``."""

    def __init__(self, name, title, system, sampler, mu_range, dt, held_out):
        self.name, self.title, self.system, self.sampler = name, title, system, sampler
        self.mu_range, self.dt, self.held_out = mu_range, dt, held_out

    def sample(self, n, seed):
        rng = np.random.default_rng(seed)
        mu = rng.uniform(*self.mu_range, n)
        return self.sampler(mu, n, seed + 1), mu

    def trajectory(self, x0, mu, k):
        return self.system.trajectory(x0, mu, self.dt, k)


def analytic_system(name, title, H, grad_H, dim: int, parameter: str, states, mu_range, dt: float = 0.1):
    """A :class:`_TrajectorySystem` of an analytic Hamiltonian ``H(x, mu)`` with one parameter, trained on
    trajectories, its reference flow integrated to ``rtol = 1e-11``."""
    system = HamiltonianSystem(H, grad_H, dim, parameters={parameter: 1}, rtol=1e-11)
    return _TrajectorySystem(name, title, system, states, mu_range, dt, True)


def _pendulum_states(mu, n, seed):
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-1.5, 1.5, n), rng.uniform(-1.0, 1.0, n)])


def _double_well_H(x, mu):
    q, p, a = x[:, 0], x[:, 1], mu[:, 0]
    return 0.5 * p**2 + 0.25 * q**4 - 0.5 * a * q**2


def _double_well_grad(x, mu):
    q, p, a = x[:, 0], x[:, 1], mu[:, 0]
    return np.column_stack([q**3 - a * q, p])


def _double_well_states(mu, n, seed):
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-1.6, 1.6, n), rng.uniform(-0.8, 0.8, n)])


def _morse_H(x, mu):
    q, p, a = x[:, 0], x[:, 1], mu[:, 0]
    return 0.5 * p**2 + (1.0 - np.exp(-a * q)) ** 2


def _morse_grad(x, mu):
    q, p, a = x[:, 0], x[:, 1], mu[:, 0]
    e = np.exp(-a * q)
    return np.column_stack([2.0 * a * e * (1.0 - e), p])


def _morse_states(mu, n, seed):
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-0.4, 0.8, n), rng.uniform(-0.6, 0.6, n)])


def systems() -> dict:
    out = {
        "morse": _TrajectorySystem(
            "morse",
            "Morse oscillator H = p^2/2 + (1 - exp(-a q))^2, a in [0.8, 1.2], bound anharmonic orbits (never used "
            "while the estimate was developed, added for the evaluation of the distance-dependent posterior share)",
            HamiltonianSystem(_morse_H, _morse_grad, 2, parameters={"a": 1}, rtol=1e-11),
            _morse_states,
            (0.8, 1.2),
            0.1,
            True,
        ),
        "double_well": _TrajectorySystem(
            "double_well",
            "double-well oscillator H = p^2/2 + q^4/4 - a q^2/2, a in [0.5, 1.0], orbits in one well and over the "
            "barrier (never looked at while the estimate was developed)",
            HamiltonianSystem(_double_well_H, _double_well_grad, 2, parameters={"a": 1}, rtol=1e-11),
            _double_well_states,
            (0.5, 1.0),
            0.1,
            True,
        ),
        "three_body": _TrajectorySystem(
            "three_body",
            "planar circular restricted three-body problem, rotating frame, librations near L4 (4-D)",
            ThreeBody(),
            lambda mu, n, seed: librating_states(mu, n, seed=seed),
            MU_RANGE,
            0.05,
            True,
        ),
        "pendulum": _TrajectorySystem(
            "pendulum",
            "pendulum, lengths in [0.7, 0.8] (the system the estimate was developed on)",
            Pendulum(),
            _pendulum_states,
            (0.7, 0.8),
            0.1,
            False,
        ),
    }
    return out


def training_data(name, args):
    """``FlowMapData`` of the system's training set and a function ``test(n, seed, K) -> (x0, mu, ref)``."""
    if name in systems():
        sysd = systems()[name]
        x0, mu = sysd.sample(args.traj, args.seed)
        traj = sysd.trajectory(x0, mu, args.traj_steps)
        data = FlowMapData(
            traj[:, :-1].reshape(-1, traj.shape[2]),
            traj[:, 1:].reshape(-1, traj.shape[2]),
            np.repeat(mu, args.traj_steps),
            np.full(args.traj * args.traj_steps, sysd.dt),
        )

        def test(n, seed, k):
            tx0, tmu = sysd.sample(n, seed)
            return tx0, tmu, sysd.trajectory(tx0, tmu, k)

        return data, test, sysd.dt, sysd.title, sysd.held_out
    bench = make_benchmarks()[name]
    x0, mu = bench.sample(args.samples, seed=args.seed)
    x1 = bench.system.flow(x0, mu[:, None], bench.dt)
    data = FlowMapData(x0, x1, mu, np.full(len(x0), bench.dt))

    def test(n, seed, k):
        tx0, tmu = bench.sample(n, seed)
        return tx0, tmu, bench.system.trajectory(tx0, tmu[:, None], bench.dt, k)

    return data, test, bench.dt, bench.title, True


def effectivity_metrics(est, true, horizons) -> dict:
    """Median effectivity, share underestimated > 3x (all steps, and per horizon), Spearman per horizon."""
    tiny = np.finfo(float).tiny
    eff = est[:, 1:] / np.maximum(true[:, 1:], tiny)
    out = {
        "all_steps": {
            "median_effectivity": float(np.median(eff)),
            "share_under_3x": float(np.mean(eff < 1 / 3)),
            "share_over_30x": float(np.mean(eff > 30)),
            "pairs": int(eff.size),
        },
        "horizons": {},
    }
    for k in horizons:
        e = est[:, k] / np.maximum(true[:, k], tiny)
        rho = spearmanr(est[:, k], true[:, k]).correlation if len(e) > 2 else float("nan")
        out["horizons"][str(k)] = {
            "median_effectivity": float(np.median(e)),
            "share_under_3x": float(np.mean(e < 1 / 3)),
            "spearman": float(rho),
            "median_true_error": float(np.median(true[:, k])),
            "median_estimate": float(np.median(est[:, k])),
        }
    return out


def spearman_interval(a, b, n_boot=2000, seed=0) -> list:
    """90% bootstrap interval of Spearman's rank correlation of ``a`` and ``b`` over resampled trajectories."""
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, len(a), (n_boot, len(a)))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a resample with ties only
        rhos = np.array([spearmanr(a[i], b[i]).correlation for i in idx])
    return np.nanpercentile(rhos, [5, 95]).tolist()


def other_draws(name, args, x0, mu, dt, ref_last, true_r) -> dict:
    """How far any estimate that knows only how the fits err, not how this one does, could rank the trajectories:
    ``--other-draws`` models fitted the same way on other training draws (seeds ``--seed`` + 100, 101, ...) roll out
    the same trajectories; Spearman between this model's true errors at the last step and the mean log error of
    the others, and the median Spearman between the errors of any two of the models."""
    logs = [np.log(np.maximum(true_r, np.finfo(float).tiny))]
    seeds = [args.seed + 100 + i for i in range(args.other_draws)]
    for seed in seeds:
        data, *_ = training_data(name, argparse.Namespace(**{**vars(args), "seed": seed}))
        other = SymplecticKernelPredictor(max_centers=args.max_centers).fit(data)
        last = other.rollout(x0, args.steps, mu=mu, dt=dt)[:, -1]
        logs.append(np.log(np.maximum(np.linalg.norm(last - ref_last, axis=1), np.finfo(float).tiny)))
    logs = np.array(logs)
    pairs = [spearmanr(logs[i], logs[j]).correlation for i in range(len(logs)) for j in range(i + 1, len(logs))]
    return {
        "other_draws_seeds": seeds,
        "spearman_last_other_draws_mean": float(spearmanr(logs[0], logs[1:].mean(axis=0)).correlation),
        "spearman_pairwise_median": float(np.median(pairs)),
    }


def ranking_checks(model, test, dt, est, true, args, name=None) -> dict:
    """Why the ranking at the last step is what it is: the statistic's sampling error over the test trajectories
    (bootstrap), the same statistic over ``--n-rank`` fresh trajectories, the spread of the true errors across
    trajectories, and whether the one-step estimate ranks the true one-step errors of the held-out samples the
    scale is calibrated on (a single scale cannot rank trajectories better than the local estimate ranks steps)."""
    out = {
        "spearman_interval_90": spearman_interval(est[:, -1], true[:, -1]),
        "true_log10_sd": float(np.std(np.log10(np.maximum(true[:, -1], np.finfo(float).tiny)))),
        "estimate_log10_sd": float(np.std(np.log10(np.maximum(est[:, -1], np.finfo(float).tiny)))),
    }
    samples = model.model_.calibration_samples
    if samples is not None:
        data = samples[0]
        x1, e1 = model.step(data.x0, mu=data.mu if model.n_mu_ else None, dt=data.dt, return_error=True)
        out["one_step_spearman_heldout"] = float(spearmanr(e1, np.linalg.norm(x1 - data.x1, axis=1)).correlation)
    if args.n_rank:
        x0, mu, ref = test(args.n_rank, args.seed + 5000, args.steps)
        pred, est_r = model.rollout(x0, args.steps, mu=mu, dt=dt, return_error=True)
        true_r = np.linalg.norm(pred[:, -1] - ref[:, -1], axis=1)
        out["n_rank"] = args.n_rank
        out["spearman_last_n_rank"] = float(spearmanr(est_r[:, -1], true_r).correlation)
        out["spearman_interval_90_n_rank"] = spearman_interval(est_r[:, -1], true_r)
        out["share_under_3x_last_n_rank"] = float(np.mean(3 * est_r[:, -1] < true_r))
        if args.other_draws:
            out.update(other_draws(name, args, x0, mu, dt, ref[:, -1], true_r))
    return out


def fit_defaults(data, args):
    """The study's model: the defaults with ``args.max_centers``, as a new user fits them; ``(model, seconds)``."""
    t0 = time.perf_counter()
    model = SymplecticKernelPredictor(max_centers=args.max_centers).fit(data)
    return model, time.perf_counter() - t0


def run_system(name, args) -> dict:
    t0 = time.perf_counter()
    data, test, dt, title, held_out = training_data(name, args)
    data_s = time.perf_counter() - t0
    model, fit_s = fit_defaults(data, args)
    x0, mu, ref = test(args.n_test, args.seed + 1000, args.steps)
    print(
        f"{name}: {len(data)} samples, fit {fit_s:.0f} s, {model.n_centers_} centres, choice {model.choice_}",
        flush=True,
    )
    entry = {
        "title": title,
        "held_out": held_out,
        "n_samples": len(data),
        "max_centers": args.max_centers,
        "n_centers": model.n_centers_,
        "dt": dt,
        "n_test": args.n_test,
        "steps": args.steps,
        "fit_s": fit_s,
        "data_s": data_s,
        "choice": {k: repr(v) for k, v in model.choice_.items()},
        "calibration": model.error_calibration_,
        "holdout_step_error": model.diagnostics_.holdout_step_error,
    }
    try:
        t0 = time.perf_counter()
        pred, est = model.rollout(x0, args.steps, mu=mu, dt=dt, return_error=True)
        entry["estimate_s"] = time.perf_counter() - t0
    except Exception as exc:  # a failure is a result
        entry["error"] = f"{type(exc).__name__}: {exc}"
        print(f"  failed: {entry['error']}", flush=True)
        return entry
    true = np.linalg.norm(pred - ref, axis=2)
    horizons = sorted({1, 10, args.steps // 4, args.steps // 2, args.steps} - {0})
    entry.update(effectivity_metrics(est, true, horizons))
    last = entry["horizons"][str(args.steps)]
    entry["goals_met"] = {
        "share_under_3x": entry["all_steps"]["share_under_3x"] <= GOALS["share_under_3x_max"],
        "median_effectivity": entry["all_steps"]["median_effectivity"] <= GOALS["median_effectivity_max"],
        "rank_correlation_last": last["spearman"] >= GOALS["rank_correlation_last_min"],
    }
    entry["rank_correlation_last"] = last["spearman"]  # the goal's number (Spearman, horizons[K]["spearman"])
    entry["ranking"] = ranking_checks(model, test, dt, est, true, args, name)
    # cost: rollout with and without the estimate, interleaved in this process
    x_small, mu_small = x0[: args.timing_batch], mu[: args.timing_batch]
    timing = _protocol.side_by_side(
        {
            "states only": lambda: model.rollout(x_small, args.timing_steps, mu=mu_small, dt=dt),
            "states and error": lambda: model.rollout(
                x_small, args.timing_steps, mu=mu_small, dt=dt, return_error=True
            ),
        },
        repeats=args.repeats,
        warmup=1,
    )
    entry["timing"] = {"batch": len(x_small), "steps": args.timing_steps, **timing}
    # the curves for a figure: median over trajectories of estimate and true error, and one trajectory
    stride = max(1, args.steps // 100)
    entry["curves"] = {
        "step": list(range(0, args.steps + 1, stride)),
        "median_estimate": np.median(est, axis=0)[::stride].tolist(),
        "median_true": np.median(true, axis=0)[::stride].tolist(),
        "example_estimate": est[0, ::stride].tolist(),
        "example_true": true[0, ::stride].tolist(),
    }
    a = entry["all_steps"]
    print(
        f"  all steps: median effectivity {a['median_effectivity']:.2f}, under 3x {a['share_under_3x']:.1%}; "
        f"last step: Spearman {last['spearman']:.2f}, median effectivity {last['median_effectivity']:.2f}; "
        f"time ratio {timing['ratios']['states and error']:.1f}x; ranking {entry['ranking']}",
        flush=True,
    )
    return entry


def add_training_arguments(p: argparse.ArgumentParser) -> None:
    """The options :func:`training_data` reads (the training set of a system and the model's size), shared with the
    design studies of the estimate (``error_estimate_residuals.py``, ``error_estimate_share_distance.py``)."""
    p.add_argument("--max-centers", type=int, default=500)
    p.add_argument("--samples", type=int, default=3000, help="scattered samples (defaults_acceptance systems)")
    p.add_argument("--traj", type=int, default=100, help="training trajectories (three_body, pendulum)")
    p.add_argument("--traj-steps", type=int, default=30)
    p.add_argument("--seed", type=int, default=0)


def add_development_arguments(p: argparse.ArgumentParser) -> None:
    """The design studies' development test set: ``--n`` trajectories from seeds offset by ``--test-offset`` from
    the training seed, other than the trajectories this study evaluates on."""
    p.add_argument("--test-offset", type=int, default=9000)
    p.add_argument("--n", type=int, default=100)


def add_design_arguments(p: argparse.ArgumentParser) -> None:
    """The options a design study's fit and test sets read (:func:`fit_defaults`, :func:`measure_design_sets`): the
    training options, the development set, and ``--final`` with this study's own test sets; ``--steps`` and
    ``--json``."""
    add_training_arguments(p)
    add_development_arguments(p)
    p.add_argument("--final", action="store_true", help="measure on this study's own test sets (the evaluation)")
    p.add_argument("--n-test", type=int, default=20)
    p.add_argument("--n-rank", type=int, default=100)
    p.add_argument("--steps", type=int, default=200)
    p.add_argument("--json", default=None)


def run_design_study(args: argparse.Namespace, run, report) -> dict:
    """A design study's loop: ``run(name, args)`` for each of ``args.systems``, ``report(name, result)`` (prints),
    and, with ``args.json``, ``{"settings": vars(args), "systems": {name: result}}`` written after each system (a
    stopped run keeps the systems it finished).  Extrapolation warnings are silenced: the studies roll out far."""
    warnings.simplefilter("ignore", ExtrapolationWarning)
    results = {}
    for name in args.systems:
        results[name] = run(name, args)
        report(name, results[name])
        if args.json:
            Path(args.json).write_text(json.dumps({"settings": vars(args), "systems": results}, indent=1))
    return results


def rollout_points(model, x0, mu, dt: float, steps: int) -> tuple:
    """A design study's rollout with the library's estimate and the points its steps read:
    ``(pred (B, K + 1, 2n), estimate (B, K + 1), mu (B, d_mu), xs (B K, 2n), mus (B K, d_mu), dts (B K,),
    weights)``, ``xs`` the states steps ``0..K-1`` start from, ``weights`` the surrogate's per trajectory."""
    pred, est = model.rollout(x0, steps, mu=mu, dt=dt, return_error=True)
    b, k1, dim = pred.shape
    tmu = np.asarray(mu, float).reshape(b, -1) if model.n_mu_ else np.zeros((b, 0))
    xs = pred[:, :-1].reshape(-1, dim)
    mus = np.repeat(tmu, k1 - 1, axis=0)
    weights = model.model_.surrogate.weights(tmu, np.full(b, dt))
    return pred, est, tmu, xs, mus, np.full(len(xs), dt), weights


def design_metrics(estimate: np.ndarray, true: np.ndarray, quiet_rank: bool = False) -> dict:
    """A design study's measures of one variant: median effectivity and share underestimated by more than 3x over
    steps ``1..K``, and (unless ``quiet_rank``) the Spearman correlation at the last step with its 90% bootstrap
    interval.  ``estimate`` and ``true`` of shape ``(B, K + 1)``."""
    eff = estimate[:, 1:] / np.maximum(true[:, 1:], np.finfo(float).tiny)
    row = {"med_eff": round(float(np.median(eff)), 3), "under3": round(float(np.mean(eff < 1 / 3)), 4)}
    if not quiet_rank:
        row["spearman_last"] = round(float(spearmanr(estimate[:, -1], true[:, -1]).correlation), 3)
        row["ci90_last"] = [round(v, 3) for v in spearman_interval(estimate[:, -1], true[:, -1], n_boot=1000)]
    return row


def measure_design_sets(args: argparse.Namespace, test, estimates, quiet_rank: bool = False) -> dict:
    """A design study's test sets and measures: with ``args.final`` this study's own test sets (``--n-test``
    trajectories of seed ``--seed`` + 1000 for the effectivities, ``--n-rank`` of seed + 5000 for the ranking),
    else the development set (``--n`` of seed ``--seed`` + ``--test-offset``).  ``test(n, seed, steps)`` gives
    ``(x0, mu, reference states)``; ``estimates(x0, mu)`` gives ``(predicted states (B, K + 1, 2n), {variant:
    estimate (B, K + 1)}, info)``.  Returns ``{set: {n, seed, **info, candidates: {variant: design_metrics}}}``."""
    if args.final:
        sets = {"effectivity": (args.n_test, args.seed + 1000), "rank": (args.n_rank, args.seed + 5000)}
    else:
        sets = {"dev": (args.n, args.seed + args.test_offset)}
    out = {}
    for label, (n, seed) in sets.items():
        x0, mu, ref = test(n, seed, args.steps)
        pred, variants, info = estimates(x0, mu)
        true = np.linalg.norm(pred - ref, axis=2)
        out[label] = {
            "n": n,
            "seed": seed,
            **info,
            "candidates": {v: design_metrics(e, true, quiet_rank) for v, e in variants.items()},
        }
    return out


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument(
        "--systems",
        nargs="+",
        default=["three_body", "coupled_pendulums", "fpu_chain", "kepler", "pendulum", "double_well"],
    )
    add_training_arguments(p)
    p.add_argument("--n-test", type=int, default=20)
    p.add_argument("--n-rank", type=int, default=100, help="fresh trajectories for the rank correlation's check")
    p.add_argument(
        "--other-draws",
        type=int,
        default=0,
        help="models fitted on other training draws that roll out the --n-rank trajectories (the ranking's ceiling)",
    )
    p.add_argument("--steps", type=int, default=200)
    p.add_argument("--timing-batch", type=int, default=4)
    p.add_argument("--timing-steps", type=int, default=50)
    p.add_argument("--quick", action="store_true", help="small sizes (a smoke run)")
    _protocol.add_arguments(p, threads=1, repeats=3)
    args = p.parse_args(argv)
    if args.json is None and not args.quick:
        args.json = str(RESULTS)
    if args.quick:
        args.max_centers, args.samples, args.traj, args.traj_steps = 150, 800, 30, 20
        args.n_test, args.steps, args.repeats, args.n_rank = 8, 50, 1, 16
    return args


def main(argv=None) -> dict:
    args = parse_args(argv)
    warnings.simplefilter("ignore", ExtrapolationWarning)
    result = {"goals": GOALS, "settings": {k: v for k, v in vars(args).items() if k != "json"}, "systems": {}}
    with _protocol.limits(args.blas_threads, numba_threads=args.threads):
        for name in args.systems:
            result["systems"][name] = run_system(name, args)
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        _protocol.write_json(
            args.json,
            result,
            _protocol.record(
                blas_threads=args.blas_threads,
                numba_threads=args.threads,
                repeats=args.repeats,
                warmup=1,
                notes="shared 2-core machine: timings indicative, ratios side by side; errors deterministic given the seeds",
            ),
        )
    return result


if __name__ == "__main__":
    main()
