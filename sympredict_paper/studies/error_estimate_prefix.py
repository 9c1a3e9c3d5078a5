"""Experiment: an "embedded pair" error field from the model's own greedy expansion, carried along the rollout.

The learned gradient ``g_m`` of a model with ``m`` centres and the gradient ``g_m'`` of its prefix (the first ``m'``
centres of the same greedy expansion, :meth:`~sympredict.estimators.fitted.FittedSymplecticFlowMap.truncated`'s
coefficients) differ by ``d(z) = g_m(z) - g_m'(z)``, the hierarchical surplus of the last ``m - m'`` Newton terms.
Like the difference of an embedded Runge-Kutta pair it is a function-dependent local error indicator available at
every state (not only near the residual samples), with a direction, coherent along an orbit, and it is this model's
own.  At each step ``k`` of a rollout it moves the step by ``u_k = S_k d(z_k)`` (``S_k = d x1 / d g`` of the step's
linearisation) and is carried through the later steps like the residual part,

    F_0 = 0,   F_k+1 = D Phi_k F_k + u_k,   e_k = c_p |D^-1 F_k|,

with the scale ``c_p`` the 0.9 quantile over the fit's held-out calibration samples of ``|r_i| / |D^-1 u_i|``
(``r_i`` the true one-step residual; the one-step case, as the other parts are calibrated).

Variants (``--variants``; every one is measured on the same rollouts):

* ``current``: the library's estimate (posterior part with its local scale and share, residual part, in quadrature);
* ``post``, ``resid``: the library's posterior part (with its factors) and residual part, each alone (diagnostic:
  does one part rank better than their sum?); ``post_full``: the posterior part with the local scale only (no share);
* ``pfx{q}``: the prefix part alone with ``m' = round(q m / 100)``, ``q`` in 50, 75, 90;
  ``pfxmix``: the three prefixes as three columns of ``F`` (``U_k = [u50, u75, u90] / sqrt 3``, one scale);
* ``cur+pfx{q}`` / ``cur+pfxmix``: the prefix part joined to the library's estimate in quadrature;
* ``post+pfx{q}`` / ``post+pfxmix``: the prefix part replacing the residual part (posterior at full scale beside it,
  ``post_full``, since the share was calibrated against the residual part).

A second design, added after the first was rejected on development (below) and after the diagnostic ``--oracle``
(estimates that know the true local error vectors along the rollout) showed that the directions of the local errors,
not their sizes, set the ranking: ``dir{k}``, each step's local error taken as the direction of the mean of the ``k``
nearest residual vectors (``k`` in 5, 20; the residual part's search) times the size of the posterior's calibrated
one-step estimate with its local scale (no share), carried coherently like the others (its one-step case is the
posterior's, so it needs no scale of its own); ``cur+dir{k}`` and ``post+dir{k}`` join it to the library's estimate
or to the posterior part.  Chosen and adopted by the same rules, on the same development data.

Protocol (written before any number of this experiment was looked at):

* Development only on the pendulum, the coupled pendulums, the FPU chain and the Kepler problem with ``--n`` = 100
  test trajectories of seed ``--seed`` + 11000 (``--test-offset 11000``; not the study's + 1000 / + 5000, nor the + 7000
  / + 9000 used by earlier designs).  The FPU chain and Kepler are development systems for this design; their
  published seeds remain their evaluation.
* Choice on development: among the variants that are estimates on their own (``pfx*``, ``cur+*``, ``post+*``), the one
  with the highest mean Spearman at the last step (step 200) over the development systems, among those with at most
  5% of (trajectory, step) pairs underestimated by more than 3x and median effectivity <= 30 on every development
  system; it must beat ``current``'s mean, else nothing is chosen.
* Adoption rule: the chosen variant is measured once (``--final``) with the study's own seeds (``error_estimate.py``:
  20 trajectories of seed + 1000 for the effectivities over all steps, 100 of seed + 5000 for the rank correlation at
  step 200 with its 90% bootstrap interval) on three_body, coupled_pendulums, fpu_chain, kepler, pendulum,
  double_well and morse, beside ``current``.  Adopted only if the underestimate (<= 10% of pairs under 3x) and
  effectivity (median <= 30) goals hold on every system, the rank correlation improves on at least four of the seven,
  and on none falls below the lower end of ``current``'s 90% interval.  Nothing is tuned after that measurement.
* Then one system never used before, ``quartic`` (``H = p^2/2 + q^2/2 + b q^4/4``, ``b`` in [0.2, 1.0], ``dT = 0.1``,
  states in [-1.5, 1.5]^2, trained on trajectories, RK4 reference), measured once with the frozen design, whatever
  it gives.

Diagnostic (``--oracle``, development data only; the exact flow is not available to an estimate): ``oracle_coh``, the
true local error vectors ``Phi(x_k) - Phi_exact(x_k)`` along the rollout carried coherently through the later steps'
Jacobians (as ``error_estimate_residuals.py``'s ``oracle``); ``oracle_rss``, their sizes summed in quadrature without
propagation; ``oracle_post``, the posterior part's propagation with each step's local scale set so that its one-step
estimate equals the true local error's size; ``knn_mean_coh``, the mean of the 5 nearest residual vectors carried
coherently (``error_estimate_residuals.py``'s ``bias5``); ``oracle_size_knn_dir`` / ``knn_size_oracle_dir``, the
direction of one and the size of the other.

Result (100 trajectories of seed + 11000, Spearman at step 200; pendulum / coupled pendulums / FPU chain / Kepler):

* ``current`` 0.61 / 0.50 / 0.43 / 0.42 (mean 0.49); its parts alone: ``post`` 0.49 / 0.19 / 0.36 / 0.32, ``resid``
  0.44 / 0.53 / 0.36 / 0.35; the sum ranks better than either part on three of the four (on the coupled pendulums
  the residual part alone is 0.03 above it): the combination is not the defect.
* The prefix part does not indicate the local error: its one-step Spearman against the true one-step error on the
  held-out samples is -0.19 to 0.24 on all four systems and all three prefixes; alone it ranks the trajectories
  0.08 to 0.29 (mean over the systems), joined to the library's estimate 0.26 to 0.41, beside the posterior part
  0.17 to 0.35, every variant below ``current`` on the mean and on at least three of the four systems
  (``docs/data/error_estimate_prefix_dev.json``).  The surplus of the last Newton terms lives near the last centres,
  where the greedy has just removed the prefix's largest errors: it points to where the full model is now good.
* The oracles (``docs/data/error_estimate_prefix_oracle_dev.json``): ``oracle_coh`` 1.00 / 1.00 / 1.00 / 0.93, so the
  linear coherent propagation is not what limits the ranking; ``oracle_post`` 0.62 / 0.48 / 0.39 / 0.35, so true
  local sizes in the posterior's propagation do not help; ``knn_size_oracle_dir`` 0.69 / 0.79 / 0.81 / 0.31 against
  ``oracle_size_knn_dir`` 0.58 / 0.65 / 0.40 / 0.43: on three of the four systems the local errors' directions (the
  nearest residuals' mean direction agrees with the true one with median cosine 0.95 / 0.90 / 0.48 / 0.88) are what
  an estimate lacks.
* The direction design (``docs/data/error_estimate_prefix_direction_dev.json``): ``dir5`` mean 0.37, ``dir20`` 0.38,
  ``cur+dir5`` 0.44, ``cur+dir20`` 0.43, ``post+dir5`` 0.41, ``post+dir20`` 0.42: below ``current`` (0.49) on the mean;
  only on Kepler do the joined variants reach 0.45 to 0.46 against 0.42.

So by the rule above nothing was chosen, nothing was measured on the published seeds, and the library is unchanged.
The quartic oscillator was not run, so that it stays unseen for a later design.

Run:  python sympredict_paper/studies/error_estimate_prefix.py --test-offset 11000 \
          --systems pendulum coupled_pendulums fpu_chain kepler --json docs/data/error_estimate_prefix_dev.json
      python sympredict_paper/studies/error_estimate_prefix.py --test-offset 11000 --oracle \
          --variants current post resid post_full --json docs/data/error_estimate_prefix_oracle_dev.json
      python sympredict_paper/studies/error_estimate_prefix.py --test-offset 11000 \
          --variants current dir5 dir20 cur+dir5 cur+dir20 post+dir5 post+dir20 \
          --json docs/data/error_estimate_prefix_direction_dev.json
      python sympredict_paper/studies/error_estimate_prefix.py --final --variants current <chosen> \
          --systems three_body coupled_pendulums fpu_chain kepler pendulum double_well morse quartic \
          --json docs/data/error_estimate_prefix_final.json
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from scipy.stats import spearmanr

sys.path.insert(0, str(Path(__file__).resolve().parent))
import error_estimate as study  # noqa: E402

from sympredict.estimators.error_estimate import local_points, nearest, rollout_error_units  # noqa: E402
from sympredict.interpolation.surrogate import HBSurrogate  # noqa: E402

PREFIXES = (50, 75, 90)
DIRECTION_NEIGHBOURS = (5, 20)


def _quartic_H(x, mu):
    q, p, b = x[:, 0], x[:, 1], mu[:, 0]
    return 0.5 * p**2 + 0.5 * q**2 + 0.25 * b * q**4


def _quartic_grad(x, mu):
    q, p, b = x[:, 0], x[:, 1], mu[:, 0]
    return np.column_stack([q + b * q**3, p])


def _quartic_states(mu, n, seed):
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-1.5, 1.5, n), rng.uniform(-1.5, 1.5, n)])


_study_systems = study.systems


def systems() -> dict:
    """The study's systems and the unseen quartic oscillator."""
    out = _study_systems()
    out["quartic"] = study.analytic_system(
        "quartic",
        "quartic oscillator H = p^2/2 + q^2/2 + b q^4/4, b in [0.2, 1.0] (unseen: measured once, after the design "
        "was frozen)",
        _quartic_H,
        _quartic_grad,
        2,
        "b",
        _quartic_states,
        (0.2, 1.0),
    )
    return out


study.systems = systems


def prefix_surrogate(fm, m_prefix: int) -> HBSurrogate:
    """The surrogate of the first ``m_prefix`` centres of the greedy expansion (as ``fm.truncated`` builds it)."""
    sur = fm.surrogate
    return HBSurrogate(
        sur.kernel,
        sur.centers_xi[:m_prefix],
        sur.centers_mu[:m_prefix],
        sur.centers_dt[:m_prefix],
        sur.components[:m_prefix],
        fm.greedy_result.coef_prefix(m_prefix),
    )


def local_moves(fm, prefixes, xs, x1s, mu, dt):
    """``(jac (N, 2n, 2n), u (N, 2n, P))``: the steps' Jacobians and ``S d(z)`` for each prefix (scaled coords)."""
    sur = fm.surrogate
    w = sur.weights(mu, dt)
    xi, jac, sens = fm.rule.linearization(sur, xs, x1s, w, dt)
    g = sur.gradient(xi, w)
    cols = []
    for p in prefixes:
        d = g - p.gradient(xi, p.weights(mu, dt))
        cols.append(np.einsum("nij,nj->ni", sens, d))
    return jac, np.stack(cols, axis=2)


def prefix_scale(fm, prefixes) -> tuple:
    """``(c_p, one-step Spearman of |D^-1 u| against the true one-step error)`` on the calibration samples."""
    data = fm.calibration_samples[0]
    scale = fm.scale
    mu = data.mu if fm.n_mu else np.zeros((len(data), 0))
    w = fm.surrogate.weights(mu, data.dt)
    x1s = fm._solve_scaled(data.x0 * scale, w, data.dt, by_size=True)
    true = np.linalg.norm(x1s / scale - data.x1, axis=1)
    _, u = local_moves(fm, prefixes, data.x0 * scale, x1s, mu, data.dt)
    unit = np.sqrt(np.einsum("nik,i->n", u * u, 1.0 / scale**2) / u.shape[2])
    ok = (unit > 0) & np.isfinite(true)
    c = float(np.quantile(true[ok] / unit[ok], fm.ERROR_QUANTILE))
    return c, float(spearmanr(unit[ok], true[ok]).correlation)


def propagate(jac, u, scale):
    """``F_k+1 = D Phi_k F_k + U_k`` with ``U_k = u_k / sqrt(P)``; ``jac`` (B, K, 2n, 2n), ``u`` (B, K, 2n, P);
    returns ``|D^-1 F_k|_F`` (B, K+1)."""
    b, k, dim, cols = u.shape
    f = np.zeros((b, dim, cols))
    out = np.zeros((b, k + 1))
    u = u / np.sqrt(cols)
    for j in range(k):
        f = np.matmul(jac[:, j], f) + u[:, j]
        out[:, j + 1] = np.sqrt(np.einsum("bik,i->b", f * f, 1.0 / scale**2))
    return out


def candidates(model, x0, mu, dt, steps, variants, pfx, c_mix):
    """Every variant's estimate (B, K+1) on the same rollouts, and the seconds of each part."""
    fm = model.model_
    t0 = time.perf_counter()
    pred, est, tmu, xs, mus, dts, twts = study.rollout_points(model, x0, mu, dt, steps)
    t_current = time.perf_counter() - t0
    b, k1, dim = pred.shape
    kk = k1 - 1
    c = fm.error_calibration["scale"]
    f_lib = fm._local_factors(xs, mus, dts).reshape(b, kk)
    f_est = fm._step_factors(xs, mus, dts).reshape(b, kk)
    part = fm._residual_neighbours(pred[:, :-1], tmu, np.full(b, dt))
    post = c * rollout_error_units(fm, pred, tmu, np.full(b, dt), twts, local=f_est, jacobians=part)
    resid = float(fm.error_calibration["residual_scale"]) * part.out
    post_full = c * rollout_error_units(fm, pred, tmu, np.full(b, dt), twts, local=f_lib)
    scale = fm.scale
    t0 = time.perf_counter()
    jac, u = local_moves(fm, [p for _, p, _ in pfx], xs * scale, (pred[:, 1:].reshape(-1, dim)) * scale, mus, dts)
    jac, u = jac.reshape(b, kk, dim, dim), u.reshape(b, kk, dim, -1)
    parts = {}
    for i, (q, _, cp) in enumerate(pfx):
        parts[f"pfx{q}"] = cp * propagate(jac, u[..., i : i + 1], scale)
    t_prefix = (time.perf_counter() - t0) / len(parts)
    parts["pfxmix"] = c_mix * propagate(jac, u, scale)
    # the second design: direction from the residual samples, size from the posterior's one-step estimate
    w = fm.surrogate.weights(mus, dts)
    e1 = c * f_lib.ravel() * fm._local_error_units(xs * scale, pred[:, 1:].reshape(-1, dim) * scale, mus, dts, w)
    points, vectors, _ = fm._residual_arrays()
    query = local_points(xs, mus, dts, fm.domain)
    for k in DIRECTION_NEIGHBOURS:
        mean = vectors[nearest(points, query, k)].mean(axis=1) / scale  # user units
        direction = mean / np.maximum(np.linalg.norm(mean, axis=1, keepdims=True), np.finfo(float).tiny)
        u_dir = (direction * e1[:, None] * scale).reshape(b, kk, dim, 1)
        parts[f"dir{k}"] = propagate(jac, u_dir, scale)
    out = {"current": est, "post": post, "resid": resid, "post_full": post_full}
    check = np.max(np.abs(np.hypot(post, resid) - est) / np.maximum(est, np.finfo(float).tiny))
    for name, e in parts.items():
        out[name] = e
        out[f"cur+{name}"] = np.hypot(est, e)
        out[f"post+{name}"] = np.hypot(post_full, e)
    out = {v: e for v, e in out.items() if v in variants or "all" in variants}
    info = {"current_s": t_current, "prefix_part_s_each": t_prefix, "parts_vs_current_max_rel": float(check)}
    return pred, out, info


def exact_step(name, args):
    """``step(x (N, 2n), mu (N, d_mu)) -> x1 (N, 2n)``: the reference flow over one step (the oracle diagnostic)."""
    if name in study.systems():
        sysd = study.systems()[name]
        return lambda x, mu: sysd.system.trajectory(x, mu[:, 0], sysd.dt, 1)[:, 1]
    bench = study.make_benchmarks()[name]
    return lambda x, mu: bench.system.flow(x, mu, bench.dt)


def oracle(model, pred, mu, dt, step):
    """Diagnostic estimates that know the true local errors ``r_k = Phi(x_k) - Phi_exact(x_k)`` along the rollout:
    ``oracle_coh``, ``r_k`` carried coherently through the later steps' Jacobians (the ceiling of any design that
    estimates the local error vectors and propagates them linearly); ``oracle_rss``, ``sqrt(sum_k |r_k|^2)`` (no
    propagation); ``oracle_post``, the posterior's propagation with each step's local scale set to the true local
    error over the posterior's one-step estimate (the ceiling of a better local magnitude, direction from the
    posterior)."""
    fm = model.model_
    b, k1, dim = pred.shape
    kk = k1 - 1
    tmu = np.asarray(mu, float).reshape(b, -1) if model.n_mu_ else np.zeros((b, 0))
    xs, x1s = pred[:, :-1].reshape(-1, dim), pred[:, 1:].reshape(-1, dim)
    mus, dts = np.repeat(tmu, kk, axis=0), np.full(b * kk, dt)
    r = x1s - step(xs, mus)
    scale = fm.scale
    w = fm.surrogate.weights(mus, dts)
    _, jac, _ = fm.rule.linearization(fm.surrogate, xs * scale, x1s * scale, w, dts)
    coh = propagate(jac.reshape(b, kk, dim, dim), (r * scale).reshape(b, kk, dim, 1), scale)
    rss = np.concatenate([np.zeros((b, 1)), np.sqrt(np.cumsum(np.sum(r**2, axis=1).reshape(b, kk), axis=1))], axis=1)
    unit = fm._local_error_units(xs * scale, x1s * scale, mus, dts, w)
    f = (np.linalg.norm(r, axis=1) / np.maximum(unit, np.finfo(float).tiny)).reshape(b, kk)
    twts = fm.surrogate.weights(tmu, np.full(b, dt))
    post = rollout_error_units(fm, pred, tmu, np.full(b, dt), twts, local=f)
    # the residual samples' estimate of the local vectors: the mean of the k nearest (the residual part's search)
    points, vectors, k = fm._residual_arrays()
    near = nearest(points, local_points(xs, mus, dts, fm.domain), k)
    mean = vectors[near].mean(axis=1) / scale  # user units
    size = lambda v: np.linalg.norm(v, axis=1, keepdims=True)
    unit = lambda v: v / np.maximum(size(v), np.finfo(float).tiny)
    jac4 = jac.reshape(b, kk, dim, dim)
    carry = lambda v: propagate(jac4, (v * scale).reshape(b, kk, dim, 1), scale)
    info = {
        "local_r2_knn_mean": float(1 - np.sum((r - mean) ** 2) / np.sum(r**2)),
        "local_cosine_knn_mean_median": float(np.median(np.sum(unit(r) * unit(mean), axis=1))),
        "local_size_spearman_knn_mean": float(spearmanr(size(mean)[:, 0], size(r)[:, 0]).correlation),
    }
    est = {
        "oracle_coh": coh,
        "oracle_rss": rss,
        "oracle_post": post,
        "knn_mean_coh": carry(mean),
        "oracle_size_knn_dir": carry(unit(mean) * size(r)),
        "knn_size_oracle_dir": carry(unit(r) * size(mean)),
    }
    return est, info


def run(name, args):
    data, test, dt, title, _ = study.training_data(name, args)
    model, fit_s = study.fit_defaults(data, args)
    fm = model.model_
    fm.error_calibration
    m = fm.n_centers
    pfx = []
    for q in PREFIXES:
        mp = max(1, min(m - 1, int(round(q * m / 100))))
        p = prefix_surrogate(fm, mp)
        c, rho1 = prefix_scale(fm, [p])
        pfx.append((q, p, c, rho1, mp))
    c_mix, rho_mix = prefix_scale(fm, [p for _, p, *_ in pfx])
    out = {
        "title": title,
        "fit_s": fit_s,
        "n_centers": m,
        "prefixes": {f"pfx{q}": {"m_prefix": mp, "scale": c, "one_step_spearman": rho1} for q, _, c, rho1, mp in pfx},
        "pfxmix": {"scale": c_mix, "one_step_spearman": rho_mix},
    }
    pfx = [(q, p, c) for q, p, c, *_ in pfx]

    def estimates(x0, mu):
        pred, cands, info = candidates(model, x0, mu, dt, args.steps, args.variants, pfx, c_mix)
        if args.oracle and not args.final:
            more, local_info = oracle(model, pred, mu, dt, exact_step(name, args))
            cands.update(more)
            info.update(local_info)
        return pred, cands, info

    out.update(study.measure_design_sets(args, test, estimates))
    return out


def report(name, r):
    print(name, json.dumps({k: v for k, v in r.items() if k not in ("dev", "effectivity", "rank")}), flush=True)
    for label in ("dev", "effectivity", "rank"):
        if label in r:
            print(f"  {label}:", {k: v for k, v in r[label].items() if k != "candidates"}, flush=True)
            for v, row in r[label]["candidates"].items():
                print(f"    {v:16s} {row}", flush=True)


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--systems", nargs="+", default=["pendulum", "coupled_pendulums", "fpu_chain", "kepler"])
    p.add_argument("--variants", nargs="+", default=["all"])
    p.add_argument(
        "--oracle", action="store_true", help="also the diagnostic estimates that know the true local errors"
    )
    study.add_design_arguments(p)
    args = p.parse_args()
    study.run_design_study(args, run, report)


if __name__ == "__main__":
    main()
