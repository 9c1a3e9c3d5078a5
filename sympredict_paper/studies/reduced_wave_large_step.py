"""Kernel ROM against implicit midpoint at large macro steps on pyMOR's parametric demo wave (issue 14).

Run:  python sympredict_paper/studies/reduced_wave_large_step.py [--json out.json]      (2n = 20, steps 10x and 50x the FOM's)
      python sympredict_paper/studies/reduced_wave_large_step.py --quick                (seconds: T = 1, 2n = 6, few centres)
      python sympredict_paper/studies/reduced_wave_large_step.py --search rollout --factors 10 --updates midpoint \
          --test-seeds 12 31                                              (shapes, ridge and budget by validation rollout)

Setup: ``pymordemos.symplectic_wave_equation.discretize_fom(T)`` with its stiffness
block scaled by ``c^2 / 0.1^2``, ``c in [0.08, 0.12]``; ``--n-train`` training speeds
(uniform), a symplectic basis ``psd_complex_svd`` of their FOM trajectories with
``2n = --dim``; the symplectic Galerkin ROM (pyMOR ``QuadraticHamiltonianRBReductor``).
Test speeds are drawn at random in the range (``--test-seed``) and used for nothing
but the errors below; the kernel shapes are chosen on the reductor's validation
speeds (another seed), never on the test speeds.

For every step factor ``f`` (macro step ``dT = f h``, ``h`` the FOM step) and test
speed, over ``K = round(T / dT)`` macro steps from the FOM's initial data:

* reference: the Galerkin ROM's exact flow, ``expm(dT J H_red(c))`` (the ROM is linear);
* implicit midpoint on the Galerkin ROM at ``dT`` (one step per macro step; it needs
  the reduced operator);
* the kernel ROM (:class:`~sympredict.mor.SymplecticKernelReductor`, ``GalerkinSamples``:
  exact reduced flow samples near the reduced trajectories of the training speeds)
  with the paper's update (``symplectic_euler``, type II) and the symmetric one
  (``midpoint``), both on the NumPy Newton solver; states in the Williamson
  coordinates of ``H_red`` at the box centre (symplectic: each mode a rotation),
  IMQ shapes of the state and speed factors chosen per update on the validation
  speeds, by one of two searches (``--search``):

  - ``residual`` (default): :func:`~sympredict.estimators.selection.select_kernels`, the greedy's
    validation residual at ``m* = --m-star`` centres, then one fit to ``--centers``;
  - ``rollout``: :func:`~sympredict.estimators.selection.select_by_score` over every
    (state shape, speed shape, ridge) in ``--state-eps x --mu-eps x --ridges``, each
    fitted once to ``max(--budgets)`` centres and scored at every budget (greedy
    prefixes) by its rollout on the validation speeds: the largest ratio, over those
    speeds, of its error against the Galerkin flow to implicit midpoint's (the
    quantity of the target).  Nothing of the test speeds enters: the chosen settings
    do not depend on ``--test-seeds`` (tested).

Test speeds: ``--n-test`` per seed in ``--test-seeds``, each seed's speeds reported
with it, so a model chosen once is evaluated on fresh seeds and on earlier ones in
the same run.

Errors ``sqrt(sum_k |x(t_k) - x_ref(t_k)|^2 / sum_k |x_ref(t_k)|^2)`` in reduced
coordinates (the basis is orthonormal, so this is the error of ``V x`` too), and for
context the error of ``V x`` against the FOM on the same grid.  Existence is reported,
not hidden: the type-II check (:func:`~sympredict.systems.flowmaps.check_generating_function`)
on the training data, the midpoint form's ``min sigma((I + D Phi)/2)`` (it vanishes
where a mode turns by half a turn per step: the form ``x1 = x0 + dT J grad s((x0+x1)/2)``
cannot represent the map there) on the training, test and a scan of speeds, and every
Newton failure of a kernel rollout.  One BLAS thread by default (``--blas-threads``);
the JSON carries the record of ``sympredict_paper/studies/_protocol.py``.
"""

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _protocol  # noqa: E402  (sympredict_paper/studies/_protocol.py)

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--quick", action="store_true", help="small case for the tests (T = 1, 2n = 8, few centres)")
parser.add_argument("--T", type=float, default=10.0)
parser.add_argument("--dim", type=int, default=20, help="2n, the reduced dimension")
parser.add_argument("--factors", type=int, nargs="+", default=[10, 50], help="macro step / FOM step")
parser.add_argument("--updates", nargs="+", default=["symplectic_euler", "midpoint"])
parser.add_argument("--n-train", type=int, default=9, help="training speeds (uniform in the range)")
parser.add_argument("--n-val", type=int, default=3, help="validation speeds (random, for the kernel choice)")
parser.add_argument("--n-test", type=int, default=5)
parser.add_argument(
    "--test-seeds",
    "--test-seed",
    dest="test_seeds",
    type=int,
    nargs="+",
    default=[12],
    help="seeds of the test speeds (--n-test each); used for nothing but the reported errors",
)
parser.add_argument("--seed", type=int, default=0, help="data and validation seed of the reductor")
parser.add_argument("--samples", type=int, default=400, help="flow-map samples per training speed")
parser.add_argument("--radius", type=float, default=0.05)
parser.add_argument("--centers", type=int, default=1500)
parser.add_argument("--m-star", type=int, default=300)
parser.add_argument(
    "--search",
    choices=["residual", "rollout"],
    default="residual",
    help="kernel choice on the validation speeds: greedy residual at --m-star, or rollout error of final models",
)
parser.add_argument(
    "--state-eps",
    type=float,
    nargs="+",
    default=None,
    help="state shapes (default residual: 0.01 0.03 0.1 0.3; rollout: 0.001 0.003 0.01 0.03)",
)
parser.add_argument(
    "--mu-eps", type=float, nargs="+", default=None, help="speed shapes (default residual: 0.3 1 3; rollout: 0.3 1)"
)
parser.add_argument("--ridges", type=float, nargs="+", default=[0.0], help="--search rollout: ridge candidates")
parser.add_argument(
    "--budgets",
    type=int,
    nargs="+",
    default=[1000, 1500, 2000, 3000],
    help="--search rollout: centre budgets compared (greedy prefixes of one fit to the largest)",
)
parser.add_argument("--scaling", default="williamson", choices=["williamson", "diag"])
parser.add_argument(
    "--train-past-existence",
    nargs="*",
    default=["midpoint"],
    help="updates trained even where their existence check fails (the others are reported as refused)",
)
_protocol.add_arguments(parser)
args = parser.parse_args()
if args.quick:
    args.T, args.dim, args.n_train, args.n_val, args.n_test = 1.0, 6, 4, 2, 2
    args.samples, args.centers, args.m_star, args.budgets = 60, 60, 30, [30, 60]
    args.state_eps, args.mu_eps = args.state_eps or [0.1, 0.3], args.mu_eps or [1.0]
if args.search == "residual":
    args.state_eps, args.mu_eps = args.state_eps or [0.01, 0.03, 0.1, 0.3], args.mu_eps or [0.3, 1.0, 3.0]
else:
    args.state_eps, args.mu_eps = args.state_eps or [0.001, 0.003, 0.01, 0.03], args.mu_eps or [0.3, 1.0]

from pymor.algorithms.symplectic import psd_complex_svd  # noqa: E402
from pymor.core.logger import set_log_levels  # noqa: E402
from pymor.operators.block import BlockDiagonalOperator  # noqa: E402
from pymor.operators.constructions import LincombOperator  # noqa: E402
from pymor.parameters.functionals import ExpressionParameterFunctional  # noqa: E402
from pymor.reductors.symplectic import QuadraticHamiltonianRBReductor  # noqa: E402
from pymordemos.symplectic_wave_equation import discretize_fom  # noqa: E402

from sympredict import SymplecticKernelPredictor  # noqa: E402
from sympredict.exceptions import NewtonConvergenceError  # noqa: E402
from sympredict.systems.flowmaps import (
    check_generating_function,
    linear_system_from_pymor,
    midpoint_sigma_min,  # noqa: E402
    mu_to_vector,
    random_parameters,
)
from sympredict.symplectic.integrators import implicit_midpoint_step, integrate  # noqa: E402
from sympredict.kernels import IMQ  # noqa: E402
from sympredict.mor import DefaultEstimator, GalerkinSamples, SymplecticKernelReductor, TrainingScaling  # noqa: E402
from sympredict.flowmap.scaling import NormalizedFlowMap  # noqa: E402
from sympredict.estimators.selection import select_by_score, select_kernels  # noqa: E402
from sympredict.symplectic.solvers import NewtonSolver

set_log_levels(
    {"pymor": "ERROR", "sympredict": "WARNING", "sympredict.estimators.selection": "INFO"}
)  # progress of the searches
_limits = _protocol.limits(args.blas_threads)
_limits.__enter__()  # for the whole script (module level, like the computation below)

LO, HI = 0.08, 0.12


def rel_error(x, ref):
    return float(np.sqrt(np.sum((x - ref) ** 2) / np.sum(ref**2)))


t_start = time.perf_counter()
fom = discretize_fom(T=args.T)
stiffness, identity = fom.H_op.blocks[0, 0], fom.H_op.blocks[1, 1]
fom = fom.with_(
    H_op=BlockDiagonalOperator(
        [LincombOperator([stiffness], [ExpressionParameterFunctional("c[0]**2 / 0.1**2", {"c": 1})]), identity]
    )
)
h = fom.T / fom.time_stepper.nt
space = fom.parameters.space(LO, HI)
train = space.sample_uniformly(args.n_train)
test, test_seed = [], []  # test speeds, and the seed each was drawn with
for sd in args.test_seeds:
    drawn = random_parameters(fom.parameters, [LO], [HI], args.n_test, seed=sd)
    test += drawn
    test_seed += [sd] * len(drawn)
U = fom.solution_space.empty()
for mu in train:
    U.append(fom.solve(mu))
RB = psd_complex_svd(U, args.dim)
assert 2 * len(RB) == args.dim, (len(RB), args.dim)
galerkin = QuadraticHamiltonianRBReductor(fom, RB)
grom = galerkin.reduce()
lin = linear_system_from_pymor(grom)
V = RB.to_array()
V_plus = RB.transposed_symplectic_inverse().to_array()
orth = float(np.abs(V.gramian() - np.eye(args.dim)).max())
fom_traj = {str(mu): fom.solve(mu) for mu in test}
mu_vec = {str(mu): mu_to_vector(mu, fom.parameters) for mu in test}
x_init = {str(mu): V_plus.inner(fom.initial_data.as_range_array(mu))[:, 0] for mu in test}
omega_max = max(float(lin.frequencies(np.array([c])).max()) for c in (LO, HI))
print(
    f"FOM: N = {fom.solution_space.dim}, h = {h:.6g}, T = {fom.T}; 2n = {args.dim} (max |V^T V - I| = {orth:.1e}); "
    f"largest reduced frequency {omega_max:.3f} (at c = {HI}); training speeds {[round(float(m['c'][0]), 4) for m in train]}; "
    f"test speeds {[round(float(m['c'][0]), 4) for m in test]}"
)

results = {
    "setup": {k: v for k, v in vars(args).items() if k != "json"}
    | {
        "N": fom.solution_space.dim,
        "h": h,
        "omega_max": omega_max,
        "basis_orthogonality": orth,
        "train": [float(m["c"][0]) for m in train],
        "test": [float(m["c"][0]) for m in test],
        "test_seed": test_seed,
    },
    "factors": [],
}


def validation_rollout_score(flow_map_of, x0, mus, refs, imp_errors, K, dT, log):
    """Score of a fitted model for select_by_score: the largest ratio, over the validation speeds, of its rollout
    error against the Galerkin flow to implicit midpoint's; inf on a Newton failure. Appends the errors to log."""

    def score(model):
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                x = flow_map_of(model).rollout(x0, K, mu=mus, dt=dT)
        except (NewtonConvergenceError, np.linalg.LinAlgError) as exc:
            log.append({"newton_failure": str(exc)[:200]})
            return np.inf
        errors = [rel_error(x[i], refs[i]) for i in range(len(x0))]
        log.append({"errors": errors})
        ratio = max(e / i for e, i in zip(errors, imp_errors))
        return ratio if np.isfinite(ratio) else np.inf

    return score


scan = np.linspace(LO, HI, 401)
for f in args.factors:
    dT = f * h
    K = int(round(fom.T / dT))
    entry = {"factor": f, "dT": dT, "steps": K, "max_turn_per_step": omega_max * dT, "tests": [], "kernels": {}}
    # existence of the midpoint form over the speed range: exact propagators on a scan of c
    sig_scan = np.array(
        [midpoint_sigma_min(lin.propagator(np.array([c]), dT)[None, : args.dim, : args.dim])[0] for c in scan]
    )
    entry["midpoint_sigma_scan_min"] = float(sig_scan.min())
    entry["midpoint_sigma_scan_argmin"] = float(scan[int(np.argmin(sig_scan))])
    refs = {}
    for mu in test:
        key, m = str(mu), mu_vec[str(mu)]
        x0 = x_init[key][None]
        ref = lin.trajectory(x0, m[None], dT, K)[0]
        refs[key] = ref
        imp = integrate(implicit_midpoint_step, lin, x0, m[None], dT, K)[0]
        U_fom = fom_traj[key][::f][: K + 1]
        sig = float(midpoint_sigma_min(lin.propagator(m, dT)[None, : args.dim, : args.dim])[0])
        entry["tests"].append(
            {
                "c": float(m[0]),
                "seed": test_seed[len(entry["tests"])],
                "midpoint_sigma": sig,
                "reduction_error": rel_error(V.lincomb(ref.T).to_numpy(), U_fom.to_numpy()),
                "implicit_midpoint": {
                    "error": rel_error(imp, ref),
                    "error_fom": rel_error(V.lincomb(imp.T).to_numpy(), U_fom.to_numpy()),
                },
            }
        )
    for update in args.updates:
        rec = {"update": update}
        red = SymplecticKernelReductor(
            fom,
            RB,
            dT,
            GalerkinSamples(
                train,
                n_samples=args.samples,
                radius=args.radius,
                n_validation=args.n_val,
                parameter_space=space,
                seed=args.seed,
            ),
            DefaultEstimator(max_centers=args.centers),
            scaling=TrainingScaling(args.scaling),
            check_existence=False,
        )
        t0 = time.perf_counter()
        s_train, s_val, state_scaling, mu_scaling = red.scaled_training_data()
        train_data = red.train_data_
        rec["validation_speeds"] = [float(m["c"][0]) for m in red.validation_parameters()]
        rec["samples"] = len(train_data)
        # existence on the training data (sympredict.systems.flowmaps.check_generating_function), for both forms
        for form in ("symplectic_euler", "midpoint"):
            try:
                with warnings.catch_warnings(record=True) as caught:
                    warnings.simplefilter("always")
                    info = check_generating_function(red.reduced_system, train_data, update=form)
                rec[f"check_{form}"] = {
                    "ok": True,
                    "sigma_min": info["sigma_min"],
                    "dt_max": info["dt_max"],
                    "warning": "; ".join(str(w.message) for w in caught) or None,
                }
            except ValueError as exc:
                rec[f"check_{form}"] = {"ok": False, "message": str(exc)}
        if not rec[f"check_{update}"]["ok"]:
            print(
                f"f = {f}, {update}: existence check FAILS on the training data: {rec[f'check_{update}']['message'][:200]}..."
            )
            if update not in args.train_past_existence:
                rec["status"] = "not trained: its generating function does not exist at this step (existence check)"
                entry["kernels"][update] = rec
                continue
        base = SymplecticKernelPredictor(update=update, solver=NewtonSolver(backend="numpy"))
        if args.search == "residual":
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                sel = select_kernels(
                    s_train,
                    s_val,
                    [IMQ(e) for e in args.state_eps],
                    [IMQ(e) for e in args.mu_eps],
                    m_star=args.m_star,
                    estimator=base,
                )
            rec["selection"] = [
                {k: v for k, v in r.items() if k in ("kernels", "E_val", "E_train", "centres", "complete", "error")}
                for r in sel.table
            ]
            rec["kernel"] = {"state": sel.state.eps, "mu": sel.mu.eps}
            red.predictor = base.set_params(
                state_kernel=sel.state, mu_kernel=sel.mu, max_centers=args.centers, trainer__tol=1e-12
            )
            red.reduce()
            flow_map, predictor = red.flow_map_, red.predictor_
        else:
            # validation speeds only (the reductor's, seed + 7): their Galerkin flow and implicit midpoint's errors
            val_mus = red.validation_parameters()
            vm = np.array([mu_to_vector(mu, fom.parameters) for mu in val_mus])
            vx0 = np.array([V_plus.inner(fom.initial_data.as_range_array(mu))[:, 0] for mu in val_mus])
            vref = lin.trajectory(vx0, vm, dT, K)
            vimp = [
                rel_error(integrate(implicit_midpoint_step, lin, vx0[i : i + 1], vm[i : i + 1], dT, K)[0], vref[i])
                for i in range(len(val_mus))
            ]
            log = []
            score = validation_rollout_score(
                lambda model: NormalizedFlowMap(model, state_scaling, mu_scaling, dT), vx0, vm, vref, vimp, K, dT, log
            )
            candidates = [
                {"state_kernel": IMQ(se), "mu_kernel": IMQ(me), "trainer__regularization": lam}
                for se in args.state_eps
                for me in args.mu_eps
                for lam in args.ridges
            ]
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                sel = select_by_score(
                    s_train, s_val, candidates, args.budgets, score, estimator=base.set_params(trainer__tol=1e-12)
                )
            scored = [r for r in sel.table if r["budget"] is not None]
            assert len(scored) == len(log)
            for r, extra in zip(scored, log):
                r.update(validation_errors=extra.get("errors"), newton_failure=extra.get("newton_failure"))
            rec["validation_implicit_midpoint"] = vimp
            rec["selection"] = sel.table
            rec["kernel"] = {
                "state": sel.params["state_kernel"].eps,
                "mu": sel.params["mu_kernel"].eps,
                "ridge": sel.params["trainer__regularization"],
                "centres": sel.n_centers,
                "score": sel.score,
            }
            rec["on_grid_edge"] = {
                name: len(grid) > 1 and value in (min(grid), max(grid))
                for name, value, grid in (
                    ("state", rec["kernel"]["state"], args.state_eps),
                    ("mu", rec["kernel"]["mu"], args.mu_eps),
                    ("ridge", rec["kernel"]["ridge"], args.ridges),
                    ("centres", sel.n_centers, [min(b, sel.n_centers) for b in args.budgets]),
                )
            }
            predictor = sel.model
            flow_map = NormalizedFlowMap(predictor, state_scaling, mu_scaling, dT)
        rec["offline_s"] = time.perf_counter() - t0
        rec["centres"] = predictor.n_centers_
        rec["stop_reason"] = predictor.history_.stop_reason
        rec["per_test"] = []
        for mu in test:
            key = str(mu)
            t1 = time.perf_counter()
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")  # extrapolation warnings: the errors say it
                    x = flow_map.rollout(x_init[key][None], K, mu=mu_vec[key], dt=dT)[0]
                row = {
                    "c": float(mu_vec[key][0]),
                    "error": rel_error(x, refs[key]),
                    "error_fom": rel_error(V.lincomb(x.T).to_numpy(), fom_traj[key][::f][: K + 1].to_numpy()),
                    "online_s": time.perf_counter() - t1,
                }
            except (NewtonConvergenceError, np.linalg.LinAlgError) as exc:
                row = {"c": float(mu_vec[key][0]), "error": None, "newton_failure": str(exc)}
            rec["per_test"].append(row)
        entry["kernels"][update] = rec
        ridge = f", ridge {rec['kernel']['ridge']:g}" if rec["kernel"].get("ridge") else ""
        print(
            f"f = {f}, {update}: kernel IMQ({rec['kernel']['state']:g}) x IMQ({rec['kernel']['mu']:g}){ridge}, {rec['centres']} centres "
            f"({rec['stop_reason']}), offline {rec['offline_s']:.0f} s; existence check of its form on the training data: "
            f"{'ok' if rec[f'check_{update}']['ok'] else 'FAILS'}"
        )
    if args.search == "rollout":  # the update, too, is chosen on the validation speeds (smallest selection score)
        scores = {u: k["kernel"]["score"] for u, k in entry["kernels"].items() if "kernel" in k}
        entry["chosen_update"] = min(scores, key=scores.get) if scores else None
        for u, k in entry["kernels"].items():
            if "selection" in k:
                print(f"  {u}: validation scores (max over validation speeds of kernel / implicit midpoint error):")
                for r in k["selection"]:
                    print(
                        f"    {r['params']}, {r['n_centers']} centres: "
                        + (
                            f"{r['score']:.3g}"
                            if r.get("budget") is not None
                            else f"fit failed: {r.get('error', '')[:100]}"
                        )
                    )
    results["factors"].append(entry)

    print(
        f"\n### {f}x the FOM step (dT = {dT:.4g}, {K} macro steps, largest turn per step {omega_max * dT:.2f} rad; "
        f"midpoint sigma over c in [{LO}, {HI}]: min {entry['midpoint_sigma_scan_min']:.2e} at c = {entry['midpoint_sigma_scan_argmin']:.4f})\n"
    )
    head = (
        ["test seed", "c", "Galerkin vs FOM", "implicit midpoint vs Galerkin"]
        + [f"kernel ({u}) vs Galerkin" for u in args.updates]
        + (["chosen kernel / implicit midpoint"] if args.search == "rollout" else ["best kernel / implicit midpoint"])
        + ["midpoint sigma"]
    )
    print("| " + " | ".join(head) + " |")
    print("|" + "---|" * len(head))
    for i, t in enumerate(entry["tests"]):
        cells = [
            str(t["seed"]),
            f"{t['c']:.4f}",
            f"{t['reduction_error']:.2e}",
            f"{t['implicit_midpoint']['error']:.2e}",
        ]
        best = np.inf
        for u in args.updates:
            k = entry["kernels"].get(u, {})
            if "per_test" not in k:
                cells.append("refused: no generating function")
            elif k["per_test"][i]["error"] is None:
                cells.append("Newton failure")
            else:
                e = k["per_test"][i]["error"]
                best = min(best, e)
                cells.append(f"{e:.2e}")
        if args.search == "rollout":  # the validation-chosen update's ratio, not the best on the test speeds
            chosen = entry["kernels"].get(entry["chosen_update"], {}).get("per_test", [{}] * (i + 1))[i].get("error")
            best = np.inf if chosen is None else chosen
        cells.append(f"{best / t['implicit_midpoint']['error']:.3f}" if np.isfinite(best) else "-")
        cells.append(f"{t['midpoint_sigma']:.3f}")
        print("| " + " | ".join(cells) + " |")
    print()

results["wall_s"] = time.perf_counter() - t_start
print(f"total {results['wall_s']:.0f} s")
if args.json:
    _protocol.write_json(
        args.json,
        results,
        _protocol.record_options(args, repeats=1, statistic="one run per fit and rollout"),
    )
