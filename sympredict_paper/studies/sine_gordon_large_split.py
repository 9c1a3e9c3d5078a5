"""Sine-Gordon large-step regime (issue 15) with the exact linear flow split off the FOM-data kernel, measured.

The target: at ``DT_large`` with ``DT_large * omega_max >= 1`` the kernel ROM is >= 10x more accurate against the
FOM than the best classical scheme (implicit midpoint, RK4; one step per ``DT_large``) on the Galerkin ROM, at every
test parameter.  Without a split (the experiment's ``_large_step``) the midpoint generating function stops existing
past ``DT_large = 1``; here the FOM-data (projected) kernel is

    Phi = L_h o S o L_h,    L_h(c) = expm(h J A_r(c)),    h = DT_large / 2,

``A_r(c)`` the reduced Hessian at 0 (``quadratic-mass``) or the reduced quadratic part of ``H`` (``quadratic``),
``S`` learned from the transformed pairs ``(L_h y(t), L_{-h} y(t + DT_large))`` of the projected FOM training
trajectories.  **Not non-intrusive**: ``A_r(c) = V^T A(c) V`` needs the FOM's operators (the projected data alone
do not give it).

``DT_large`` is chosen on the training trajectories only
(:func:`~sympredict_paper.sine_gordon.choose_large_step` with ``quadratic``: existence of the update's
generating function checked on ``S``'s pairs, margin of the best classical scheme over the projection floor);
the test parameters (the preset's, seed 0) are used for the printed errors only.  For every candidate the numbers
are printed, the chosen one is marked.  ``--rule validation`` adds a second training-only rule
(:func:`held_out_ratio`: the smallest candidate whose ratio best classical / kernel against the FOM on the held-out
training trajectories reaches the margin, the kernel fitted on the others).  It was added after the first rule's
test numbers at ``2n = 12`` had been seen (docs/explanation/sine_gordon.md says so); it is printed, not used by the experiment.

Data, basis, Galerkin ROM, ridge selection (held-out training trajectories) and the scaled fit are the
experiment's own (``fom_data``, ``choose_large_step``, ``_fit_kernel``, ``_err``).

Run (one core):  OMP_NUM_THREADS=1 NUMBA_NUM_THREADS=1 python sympredict_paper/studies/sine_gordon_large_split.py --dims 8 \\
    [--steps 10 15 20 30] [--updates midpoint symplectic_euler] [--splits quadratic-mass quadratic none] \\
    [--rule existence validation] [--json f]
"""

import argparse
import time
import warnings
from dataclasses import replace

import numpy as np

import _protocol  # sympredict_paper/studies/ (the script's folder is on sys.path)
from _sine_gordon_data import galerkin_rom, load_fom_data, record_failure  # sympredict_paper/studies/

from sympredict.symplectic.metrics import canonical_J
from sympredict_paper.sine_gordon import PRESETS, _err, _fit_kernel, _jg, choose_large_step


def _r(v, d=4):
    return [float(f"{x:.{d}g}") for x in np.atleast_1d(v)]


def held_out_ratio(p, gal, X_tr, c_tr, K, s, quadratic, update):
    """Second training-only rule (``--rule validation``): ``min`` over the held-out training trajectories
    (``1, 1 + validation_every, ...``, as ``_fit_kernel``'s ridge selection) of best classical / kernel against the
    FOM at ``DT_large = s DT``, the kernel fitted on the other training trajectories (the basis ``gal`` is the one
    of all training trajectories, held-out ones included).  A failed fit or rollout gives ratio 0."""
    held = np.zeros(len(c_tr), dtype=bool)
    held[1 :: p.validation_every] = True
    dt, Kl = s * p.DT, K // s
    x = X_tr[held, : Kl * s + 1 : s]
    y0 = gal.project(x[:, 0])
    Yp = gal.project(X_tr[~held])
    best = np.full(len(x), np.inf)
    for scheme in ("implicit_midpoint", "rk4"):
        try:
            with np.errstate(all="ignore"):
                e = _err(gal, gal.solve(y0, c_tr[held], dt, Kl, scheme=scheme), x)
            best = np.minimum(best, np.where(np.isfinite(e), e, np.inf))
        except Exception:  # a failed classical scheme is absent
            pass
    try:
        flow = _fit_kernel(
            p, Yp[:, :-s], Yp[:, s:], c_tr[~held], dt, update=update, stride=s, quadratic=quadratic, gal=gal
        )[0]
        with np.errstate(all="ignore"):
            e = _err(gal, flow.rollout(y0, Kl, mu=c_tr[held, None], dt=dt), x)
        return float(np.min(best / e)) if np.all(np.isfinite(e)) else 0.0
    except Exception:  # a failed fit or rollout: not admissible
        return 0.0


def mode_table(gal, Y, c_tr, c, s, dt, quadratic):
    """Why the existence check fails or passes, per eigenmode of ``J A_r(c)`` (training trajectories at ``c``):
    its turn ``omega dt``, the angles and moduli of the eigenvalues of the least-squares linear map ``M`` of the
    raw pairs and of ``S``'s pairs, and the mean modulus of the data's coefficient per mode (slowest first,
    relative to the largest).  A linear map fitted to a symplectic flow has ``|eig| = 1``; ``|eig|`` far from 1
    marks directions the least-squares fit does not determine."""
    sel = c_tr == c
    y0, y1 = Y[sel, :-s].reshape(-1, gal.dim), Y[sel, s:].reshape(-1, gal.dim)
    a0, a1 = y0 @ quadratic.propagator([c], dt / 2)[0].T, y1 @ quadratic.propagator([c], -dt / 2)[0].T
    lam, W = np.linalg.eig(canonical_J(gal.dim) @ quadratic.hessian([c], 1)[0])
    order = np.argsort(np.abs(lam.imag))
    coef = np.abs(np.linalg.solve(W, y0.T)).mean(axis=1)[order][::2]
    out = {"omega_dt": np.abs(lam.imag)[order][::2] * dt, "data_weight": coef / coef.max()}
    for name, (u, v) in (("raw", (y0, y1)), ("S", (a0, a1))):
        ev = np.linalg.eigvals(np.linalg.lstsq(u, v, rcond=None)[0].T)
        out[f"{name}_angles"] = np.sort(np.abs(np.angle(ev)))[::2]
        out[f"{name}_moduli"] = np.sort(np.abs(ev))
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="quick")
    parser.add_argument("--dims", type=int, nargs="*", default=[8])
    parser.add_argument("--steps", type=int, nargs="*", default=[10, 15, 20, 30], help="DT_large / DT candidates")
    parser.add_argument("--updates", nargs="*", default=["midpoint", "symplectic_euler"])
    parser.add_argument("--splits", nargs="*", default=["quadratic-mass"])
    parser.add_argument("--margin", type=float, default=None, help="the preset's large_step_margin")
    parser.add_argument(
        "--rule",
        nargs="*",
        default=["existence"],
        choices=["existence", "validation"],
        help="existence: choose_large_step (sigma_min of S's pairs, classical/floor margin); validation: "
        "smallest DT with held-out training ratio >= margin (held_out_ratio)",
    )
    parser.add_argument("--modes", action="store_true", help="print mode_table per split and step (c = c_max)")
    parser.add_argument(
        "--horizon", type=int, default=1, help="test horizon in units of T (<= long_factor; training: T)"
    )
    parser.add_argument(
        "--cache", default=None, help="npz file for the FOM trajectories (default: per preset and sizes)"
    )
    _protocol.add_arguments(parser)
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    p = replace(
        PRESETS[args.preset],
        large_step=min(args.steps),
        large_step_candidates=tuple(args.steps),
        **({} if args.margin is None else {"large_step_margin": args.margin}),
    )
    results = {
        "preset": args.preset,
        "steps": args.steps,
        "horizon": args.horizon,
        "margin": p.large_step_margin,
        "rows": [],
        "choices": [],
    }
    with _protocol.limits(args.blas_threads):
        protocol = _protocol.record_options(args, repeats=1, statistic="one run per fit and rollout")
        fom, K, c_tr, c_te, X_tr, X_te = load_fom_data(p, args.preset, args.cache, show=_r)
        for dim in args.dims:
            gal = galerkin_rom(fom, X_tr, dim)
            quads = {
                sp: None if sp == "none" else gal.quadratic_part(mass=sp == "quadratic-mass") for sp in args.splits
            }
            w = np.abs(np.linalg.eigvals(_jg(gal, gal.project(X_te[:1, 0])[0], float(p.c_range[1])))).max()
            print(
                f"\n2n = {dim}: omega_max (linearised at the first test state, c = {p.c_range[1]}) {w:.3f}", flush=True
            )
            # the training-only rules, per split and update
            chosen, chosen_val = {}, {}
            for sp, quad in quads.items():
                for update in args.updates:
                    ch = choose_large_step(p, gal, X_tr, c_tr, K, quadratic=quad, update=update)
                    chosen[sp, update] = ch["large_step"]
                    results["choices"].append({"dim": dim, "split": sp, "update": update, **ch})
                    print(
                        f"  rule ({sp}, {update}): chooses DT = {ch['large_step'] * p.DT:g}; table "
                        + "; ".join(
                            f"DT {r['DT']:g}: sigma_min {r['sigma_min']:.3f}, classical/floor {r['ratio']:.2f}"
                            for r in ch["table"]
                        ),
                        flush=True,
                    )
                    if "validation" in args.rule:
                        val = {st: held_out_ratio(p, gal, X_tr, c_tr, K, st, quad, update) for st in args.steps}
                        meet = [st for st in args.steps if val[st] >= p.large_step_margin]
                        chosen_val[sp, update] = meet[0] if meet else max(val, key=val.get)
                        results["choices"][-1]["validation"] = {
                            "ratios": {str(k): v for k, v in val.items()},
                            "large_step": chosen_val[sp, update],
                        }
                        print(
                            "    validation rule: held-out training ratio "
                            + ", ".join(f"DT {st * p.DT:g}: {v:.2f}" for st, v in val.items())
                            + f" -> DT = {chosen_val[sp, update] * p.DT:g}",
                            flush=True,
                        )
            Yp = gal.project(X_tr)
            if args.modes:
                for sp, quad in quads.items():
                    for s in args.steps if quad is not None else []:
                        mt = mode_table(gal, Yp, c_tr, float(p.c_range[1]), s, s * p.DT, quad)
                        print(
                            f"  modes ({sp}, DT {s * p.DT:g}, c = {p.c_range[1]}): omega DT {_r(mt['omega_dt'], 3)}; data weight "
                            f"{_r(mt['data_weight'], 2)}; angles raw M {_r(mt['raw_angles'], 2)}, S's M {_r(mt['S_angles'], 2)}; "
                            f"|eig| S's M {_r(mt['S_moduli'], 2)}",
                            flush=True,
                        )
            for s in args.steps:
                dt, Kl = s * p.DT, (args.horizon * K) // s
                x_te = X_te[:, : Kl * s + 1 : s]
                y0 = gal.project(x_te[:, 0])
                floor = _err(gal, gal.project(x_te), x_te)
                cls = {}
                for scheme in ("implicit_midpoint", "rk4"):
                    try:
                        with np.errstate(all="ignore"):
                            e = _err(gal, gal.solve(y0, c_te, dt, Kl, scheme=scheme), x_te)
                        cls[scheme] = np.where(np.isfinite(e), e, np.inf)
                    except Exception as exc:  # a Newton failure is a result
                        cls[scheme] = np.full(len(c_te), np.inf)
                        print(f"    {scheme} fails: {type(exc).__name__}", flush=True)
                best = np.minimum(cls["implicit_midpoint"], cls["rk4"])
                print(
                    f"  DT_large = {dt:g} (DT omega_max {dt * w:.2f}, {Kl} steps): floor {_r(floor)}; implicit midpoint "
                    f"{_r(cls['implicit_midpoint'])}; RK4 {_r(cls['rk4'])}; best classical / floor {_r(best / floor, 3)}",
                    flush=True,
                )
                for sp, quad in quads.items():
                    for update in args.updates:
                        row = {
                            "dim": dim,
                            "DT": dt,
                            "split": sp,
                            "update": update,
                            "chosen": chosen[sp, update] == s,
                            "chosen_validation": chosen_val.get((sp, update)) == s,
                            "floor": floor.tolist(),
                            "implicit_midpoint": cls["implicit_midpoint"].tolist(),
                            "rk4": cls["rk4"].tolist(),
                            "DT_omega_max": float(dt * w),
                        }
                        t1 = time.perf_counter()
                        try:
                            flow, model, fit_time, reg, table = _fit_kernel(
                                p, Yp[:, :-s], Yp[:, s:], c_tr, dt, update=update, stride=s, quadratic=quad, gal=gal
                            )
                            row.update(
                                regularization=reg,
                                centers=int(model.n_centers_),
                                fit_time=fit_time,
                                train_residual=float(model.history_.train_max_residual[-1]),
                            )
                            with np.errstate(all="ignore"):
                                e = _err(gal, flow.rollout(y0, Kl, mu=c_te[:, None], dt=dt), x_te)
                            if not np.all(np.isfinite(e)):
                                raise FloatingPointError("non-finite rollout")
                            row.update(error=e.tolist(), over_floor=(e / floor).tolist(), ratio=(best / e).tolist())
                            msg = (
                                f"error {_r(e)} ({_r(e / floor, 3)} x floor); best classical / kernel {_r(best / e, 3)} "
                                f"(min {np.min(best / e):.2f})"
                            )
                        except Exception as exc:  # a failed fit or rollout is a result
                            msg = record_failure(row, exc)
                        mark = (" [chosen]" if row["chosen"] else "") + (
                            " [chosen: validation]" if row["chosen_validation"] else ""
                        )
                        print(
                            f"    kernel split={sp:14s} {update:16s}{mark}: lambda={row.get('regularization')}, centres "
                            f"{row.get('centers')}, {time.perf_counter() - t1:.0f} s: {msg}",
                            flush=True,
                        )
                        results["rows"].append(row)
    _protocol.write_json(args.json, results, protocol)  # nothing without --json


if __name__ == "__main__":
    main()
