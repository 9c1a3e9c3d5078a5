"""Structure in the search, measured on the planar restricted three-body problem.

Data: tadpole orbits about both triangular points of the restricted three-body problem (rotating frame,
mass ratio ``mu`` in ``MU_RANGE``, ``dT = 0.05``): half started near ``L4``
(:func:`~sympredict.systems.three_body.librating_states`), half their images under the system's reversing
symmetry ``R = diag(1, -1, -1, 1)`` of ``(x, y, px, py)`` (``(x, y, px, py, t) -> (x, -y, -px, py, -t)``), which
are states of orbits about ``L5``; ``--trajectories`` x ``--steps`` samples.  Test orbits (another seed, drawn
the same way): the error ``|x_k - x_ref(k)|`` at steps ``--steps`` and ``--horizon``, median and worst over
the orbits, and the drift of the Jacobi constant.

Models, each with ``--centers`` centres, fitted to the training orbits given as trajectories
(``TrajectoryData``: the fit holds a twentieth of them out whole):

* ``defaults_no_structure``: ``SymplecticKernelPredictor(max_centers=M, search=KernelSearch(structure=False))``;
* ``defaults``: ``SymplecticKernelPredictor(max_centers=M)`` (the search tests the structures and lets those that
  hold compete; the smallest held-out one-step error decides);
* ``rollout_finalists``: ``KernelSearch(rollout_finalists=True)``: as ``defaults``, but the finalists' rollouts of
  the held-out orbits decide;
* ``quarter_size``: ``KernelSearch(final_centers=M // 4)``: the second and structure stages at a quarter of the
  centres, the choice then fitted to ``M`` centres and narrowed where that fit stops early (the final-size stage);
* ``quarter_size_only``: the same with ``final_size=False``: the shapes chosen at a quarter of the centres are
  used at ``M``;
* ``expert``: the first model's chosen kernels with the reversing symmetry declared,
  ``Symmetric(state_kernel, group=[(1, 1, 1, 1), (1, -1, -1, 1)])`` and ``update='midpoint'``;
* ``declared_expert``: a hand tuning with the symmetry declared, ``Symmetric(Scaled(IMQ(0.43), factors=(3.68,
  3.61)), group=...)``, ``update='midpoint'`` and the defaults' parameter kernel (``--expert-eps``,
  ``--expert-factors``).

Both experts are fitted to every sample; ``comparison`` gives each model's median and worst error at the horizon
over the experts' (``ratio_*``).  ``--train-seed`` draws another training set (the refitting noise);
``--configs`` runs only some of the searches (``defaults`` always).

Also: the structure test's verdicts on the data with Gaussian noise of ``--noise`` times the states' spread
added to every state (the true reversing symmetry should hold or be untestable, the other sign flips fail), and
the rollout time of the expert's symmetric midpoint model, compiled against NumPy, side by side in this process
(``--timing-steps`` steps of the test orbits, or ``--steps`` where an orbit's Newton solve fails before).

Run:  python sympredict_paper/studies/structure_search.py --trajectories 300 --steps 60 --centers 1000 --json docs/data/structure_search.json
"""

from __future__ import annotations

import argparse
import copy
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _protocol import add_arguments, limits, record, side_by_side, write_json  # noqa: E402

from sympredict import KernelSearch, SymplecticKernelPredictor, TrajectoryData  # noqa: E402
from sympredict.data import FlowMapData  # noqa: E402
from sympredict.estimators.structure import check_sign_flip, sign_flip_candidates  # noqa: E402
from sympredict.exceptions import extrapolation_expected  # noqa: E402
from sympredict.kernels import IMQ  # noqa: E402
from sympredict.kernels.transforms import Scaled, Symmetric  # noqa: E402
from sympredict.systems.three_body import MU_RANGE, ThreeBody, librating_states  # noqa: E402

R = np.array([1.0, -1.0, -1.0, 1.0])
DT = 0.05


def orbits(system, n, steps, seed):
    """``n`` orbits of ``steps`` steps, half about L4 and half their mirror images about L5; (mu, trajectories)."""
    rng = np.random.default_rng(seed)
    mu = rng.uniform(*MU_RANGE, n)
    x0 = librating_states(mu, n, seed=seed)
    x0[1::2] *= R  # R x is a state of the orbit of x run backwards, about L5
    return mu, system.trajectory(x0, mu, DT, steps)


def pairs(mu, traj):
    k = traj.shape[1] - 1
    return traj[:, :-1].reshape(-1, 4), traj[:, 1:].reshape(-1, 4), np.repeat(mu, k)


def errors(system, model, mu, ref, steps):
    """Errors at ``steps`` (median, worst) and the Jacobi drift; an orbit whose Newton solve fails counts as an
    infinite error from there on (``failed`` orbits, each rolled out alone)."""
    out = {}
    n_steps = ref.shape[1] - 1
    with extrapolation_expected():  # long test orbits leave the training box: measured, not warned
        try:
            pred = model.rollout(ref[:, 0], n_steps, mu=mu)
        except Exception:  # noqa: BLE001 - one orbit's failure fails the batch: each orbit alone
            pred = np.full(ref.shape, np.inf)
            for i in range(len(ref)):
                try:
                    pred[i] = model.rollout(ref[i, 0], n_steps, mu=mu[i])
                except Exception as exc:  # noqa: BLE001 - a failed orbit is a result
                    out.setdefault("failures", []).append(f"orbit {i}: {type(exc).__name__}: {str(exc)[:120]}")
    out["failed"] = int(np.sum(~np.all(np.isfinite(pred), axis=(1, 2))))
    for k in steps:
        e = np.linalg.norm(pred[:, k] - ref[:, k], axis=1)
        e = np.where(np.isfinite(e), e, np.inf)
        out[f"step_{k}"] = {"median": float(np.median(e)), "worst": float(np.max(e))}
    ok = np.all(np.isfinite(pred), axis=(1, 2))
    if ok.any():
        c = system.jacobi_constant(pred[ok].reshape(-1, 4), np.repeat(mu[ok], pred.shape[1])).reshape(-1, pred.shape[1])
        out["jacobi_drift_median"] = float(np.median(np.abs(c - c[:, :1]).max(axis=1)))
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--trajectories", type=int, default=160)
    parser.add_argument("--steps", type=int, default=60)
    parser.add_argument("--centers", type=int, default=400)
    parser.add_argument("--test-orbits", type=int, default=20)
    parser.add_argument("--horizon", type=int, default=200)
    parser.add_argument("--noise", type=float, nargs="*", default=[1e-4, 1e-3, 1e-2])
    parser.add_argument("--timing-steps", type=int, default=200)
    parser.add_argument("--train-seed", type=int, default=0)
    parser.add_argument("--expert-eps", type=float, default=0.43)
    parser.add_argument("--expert-factors", type=float, nargs=2, default=[3.68, 3.61])
    parser.add_argument("--configs", nargs="*", default=None, help="searches to run (default: all)")
    parser.add_argument("--no-extras", action="store_true", help="skip the noise test and the timing")
    add_arguments(parser, threads=1, repeats=3)
    args = parser.parse_args(argv)
    if args.train_seed == 1:
        parser.error("--train-seed 1 draws the test orbits: choose another seed")
    system = ThreeBody()
    result = {"settings": {k: v for k, v in vars(args).items() if k != "json"}}
    with limits(args.blas_threads, args.threads):
        mu, traj = orbits(system, args.trajectories, args.steps, seed=args.train_seed)
        x0, x1, mus = pairs(mu, traj)
        mu_t, ref = orbits(system, args.test_orbits, args.horizon, seed=1)
        steps = sorted({args.steps, args.horizon})
        models = {}
        configs = (
            ("defaults_no_structure", KernelSearch(structure=False)),
            ("defaults", KernelSearch()),
            ("rollout_finalists", KernelSearch(rollout_finalists=True)),
            ("quarter_size", KernelSearch(final_centers=max(1, args.centers // 4))),
            ("quarter_size_only", KernelSearch(final_centers=max(1, args.centers // 4), final_size=False)),
        )
        configs = [c for c in configs if args.configs is None or c[0] in args.configs or c[0] == "defaults"]
        for name, search in configs:
            t0 = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                model = SymplecticKernelPredictor(max_centers=args.centers, search=search)
                model.fit(TrajectoryData(traj, mu=mu, dt=DT))
            models[name] = model
            table = model.search_.table
            result[name] = {
                "fit_s": time.perf_counter() - t0,
                "choice": {k: repr(v) for k, v in model.choice_.items()},
                "structure": [f.summary() for f in model.search_.structure],
                "verdicts": {f"{f.kind} diag{f.signs}": f.verdict for f in model.search_.structure},
                "search_s": model.search_.seconds,
                "n_centers": model.n_centers_,
                "search_score": model.search_.score,
                "decided_by": model.search_.decided_by,
                "rollout_score": model.search_.rollout_score,
                "finalists": model.search_.finalists,
                "rollout_s": model.search_.rollout_seconds,
                "best_stage2_score": min(r["score"] for r in table if r["stage"] == 2),
                "best_stage2_update": min((r for r in table if r["stage"] == 2), key=lambda r: r["score"])["update"],
                "best_stage3_score": min((r["score"] for r in table if r["stage"] == 3), default=None),
                "stage3_candidates": sum(r["stage"] == 3 for r in table),
                "stage3": [
                    {k: r.get(k) for k in ("kernels", "update", "score", "rollout", "n_centers")}
                    for r in table
                    if r["stage"] == 3
                ],
                **errors(system, model, mu_t, ref, steps),
            }
            print(name, result[name], flush=True)
        base = models["defaults_no_structure" if "defaults_no_structure" in models else "defaults"].choice_
        plain = base["state_kernel"].kernel if isinstance(base["state_kernel"], Symmetric) else base["state_kernel"]
        group = [(1, 1, 1, 1), (1, -1, -1, 1)]
        given = {  # the issue's expert: the defaults' own shapes under the reversing symmetry; and its declared shapes
            "expert": (Symmetric(plain, group=group), base["mu_kernel"]),
            "declared_expert": (
                Symmetric(Scaled(IMQ(args.expert_eps), factors=tuple(args.expert_factors)), group=group),
                models["defaults"].choice_["mu_kernel"],
            ),
        }
        for name, (state_kernel, mu_kernel) in given.items():
            model = SymplecticKernelPredictor(state_kernel, mu_kernel, max_centers=args.centers, update="midpoint")
            t0 = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                model.fit(x0, x1, mu=mus, dt=DT)
            result[name] = {
                "fit_s": time.perf_counter() - t0,
                "state_kernel": repr(model.state_kernel),
                "mu_kernel": repr(model.mu_kernel),
                "n_centers": model.n_centers_,
                **errors(system, model, mu_t, ref, steps),
            }
            print(name, result[name], flush=True)
            models[name] = model
        result["comparison"] = {}  # one row per model, for the docs' table
        for name, model in models.items():
            kernel, update = model.get_params()["state_kernel"], model.get_params()["update"]
            if name not in ("expert", "declared_expert"):
                kernel, update = model.choice_.get("state_kernel", kernel), model.choice_.get("update", update)
            row = result[name]
            result["comparison"][name] = {
                "model": ("symmetric " if isinstance(kernel, Symmetric) else "plain ") + str(update),
                "decided_by": row.get("decided_by", "given"),
                "n_centers": row["n_centers"],
                "at_steps": row[f"step_{args.steps}"]["median"],
                "median": row[f"step_{args.horizon}"]["median"],
                "worst": row[f"step_{args.horizon}"]["worst"],
                "drift": row.get("jacobi_drift_median", float("nan")),
                "fit_s": row["fit_s"],
                "search_s": row.get("search_s", float("nan")),
            }
        for name, row in result["comparison"].items():  # each model's errors over the experts' (median, worst)
            for expert_name in ("expert", "declared_expert"):
                ref_row = result["comparison"][expert_name]
                row[f"ratio_{expert_name}_median"] = row["median"] / ref_row["median"]
                row[f"ratio_{expert_name}_worst"] = row["worst"] / ref_row["worst"]
        if args.no_extras:
            if args.json:
                write_json(
                    args.json,
                    result,
                    record(blas_threads=args.blas_threads, numba_threads=args.threads, repeats=args.repeats),
                )
            return

        # the structure test on noisy data: the search's quick model and split, noise on every state
        noisy = {}
        spread = np.std(np.concatenate([x0, x1]), axis=0)
        rng = np.random.default_rng(5)
        for level in [0.0] + list(args.noise):
            n0 = x0 + level * spread * rng.standard_normal(x0.shape)
            n1 = x1 + level * spread * rng.standard_normal(x1.shape)
            data = FlowMapData(n0, n1, mus[:, None], np.full(len(n0), DT))
            rows = np.random.default_rng(0).permutation(len(data))
            val, train = data.subset(np.sort(rows[: len(rows) // 4])), data.subset(np.sort(rows[len(rows) // 4 :]))
            quick = clone_quick(base, train)
            noisy[str(level)] = {
                f"{kind} diag{signs}": check_sign_flip(quick, train, val, signs, kind).verdict
                for signs, kind in sign_flip_candidates(4)
            }
            print("noise", level, noisy[str(level)], flush=True)
        result["noise"] = noisy

        # rollout time of the symmetric midpoint model: compiled against NumPy, the same orbits, side by side
        fast = copy.copy(models["expert"]).set_params(solver__backend="numba")
        slow = copy.copy(models["expert"]).set_params(solver__backend="numpy")
        x_t = ref[:, 0]
        n_time = args.timing_steps
        with extrapolation_expected():
            fast.rollout(x_t[:2], 2, mu=mu_t[:2])  # compile (or load the cache) outside the timing
            try:
                slow.rollout(x_t, n_time, mu=mu_t)
            except Exception:  # noqa: BLE001 - an orbit that fails later: time the in-distribution horizon
                n_time = args.steps
            timing = side_by_side(
                {
                    "numpy": lambda: slow.rollout(x_t, n_time, mu=mu_t),
                    "compiled": lambda: fast.rollout(x_t, n_time, mu=mu_t),
                },
                repeats=args.repeats,
                warmup=0,
            )
        timing["orbits"], timing["steps"] = len(x_t), n_time
        result["rollout_timing"] = timing
        print("timing", {k: v["median_s"] for k, v in timing["methods"].items()}, flush=True)
    if args.json:
        write_json(
            args.json, result, record(blas_threads=args.blas_threads, numba_threads=args.threads, repeats=args.repeats)
        )


def clone_quick(base, train):
    """The search's quick model: the defaults' kernels at 200 centres, fitted to ``train``."""
    from sympredict.estimators.structure import QUICK_CENTERS

    model = SymplecticKernelPredictor(
        base["state_kernel"], base["mu_kernel"], max_centers=QUICK_CENTERS, update=base["update"]
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return model.fit(train.x0, train.x1, mu=train.mu, dt=train.dt)


if __name__ == "__main__":
    main()
