"""Sine-Gordon kernel ROMs over 10x the training horizon: why the energy error grows, measured.

The former ``--quick`` setting (9 training trajectories, c x amplitude on a 3 x 3 grid, T = 5, DT = 0.1,
N = 1000, 600 centres) at one 2n.  Per kernel ROM (data ``reduced``: Galerkin trajectories;
``projected``: projected FOM trajectories; optional augmentations), rolled out from the test
initial states over ``long_factor * T``, printed per window of length ``T``:

* the energy error ``max |E(t) - E(0)| / |E(0)|`` of ``E = dx H(V y)`` (the FOM's energy of the lift);
* how far the reduced state is from the training data: the distance to the nearest training state in the
  scaled coordinates of the fit, as a multiple of the median nearest-neighbour distance inside the data,
  and the share of states outside the bounding box of the training states;
* the largest complex-mode amplitude ``|(q_i, p_i)|`` relative to its maximum over the training data
  (which modes grow);
* Newton failures (the rollout raises).

Choices (lambda, augmentation) are never taken from these test numbers; they are diagnostics only.

Run:  python sympredict_paper/studies/sine_gordon_long_time.py [--dim 8] [--data reduced projected] [--augment ...]
"""

import argparse
import os
import warnings
from dataclasses import replace

import numpy as np
from scipy.spatial import cKDTree

import _protocol  # sympredict_paper/studies/ (the script's folder is on sys.path)
from _sine_gordon_data import galerkin_rom  # sympredict_paper/studies/

from sympredict_paper.sine_gordon import PRESETS, _fit_kernel, sign_symmetry, EnergySamples, no_augmentation
from sympredict.systems.sine_gordon import SineGordonFOM

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--dim", type=int, default=8)
parser.add_argument("--data", nargs="*", default=["reduced", "projected"])
parser.add_argument("--augment", nargs="*", default=["none"], help="none, symmetry, energy (reduced data only)")
parser.add_argument(
    "--lambdas", type=float, nargs="*", default=None, help="fixed ridge terms (default: the rollout choice)"
)
parser.add_argument(
    "--state-eps",
    type=float,
    nargs="*",
    default=[None],
    help="IMQ shape parameters of the state kernel in the scaled coordinates (default: the estimator's)",
)
parser.add_argument("--cache", default="/tmp/sine_gordon_long_time.npz")
_protocol.add_arguments(parser, json_option=False)
args = parser.parse_args()
warnings.simplefilter("ignore")

p = replace(PRESETS["quick"], n_c=3, n_amplitude=3, max_centers=600)  # the sizes the docs' diagnostics were run with
K = int(round(p.T / p.DT))
L = p.long_factor * K
fom = SineGordonFOM(
    n_points=p.n_points, length=p.length, c_range=p.c_range, amplitude_range=p.amplitude_range, T=p.T, nt=K
)
u0 = fom.sech_cos(2.0, 1.0)
c_tr = np.repeat(np.linspace(*p.c_range, p.n_c), p.n_amplitude)
a_tr = np.tile(np.linspace(*p.amplitude_range, p.n_amplitude), p.n_c)
rng = np.random.default_rng(p.seed)
c_te, a_te = rng.uniform(*p.c_range, p.n_test), rng.uniform(*p.amplitude_range, p.n_test)
with _protocol.limits(args.blas_threads):
    if os.path.exists(args.cache):
        z = np.load(args.cache)
        X_tr, X_te = z["X_tr"], z["X_te"]
    else:
        X_tr = fom.reference_trajectory(a_tr[:, None] * u0, c_tr, p.DT, K, tol=p.ref_tol)
        X_te = fom.reference_trajectory(a_te[:, None] * u0, c_te, p.DT, L, tol=p.ref_tol)
        np.savez(args.cache, X_tr=X_tr, X_te=X_te)
    gal = galerkin_rom(fom, X_tr, args.dim)
    y0 = gal.project(X_te[:, 0])
    n = args.dim // 2
    Yg_te = gal.solve(y0, c_te, p.DT, L, substeps=p.substeps)
    data = {
        "reduced": gal.solve(gal.project(X_tr[:, 0]), c_tr, p.DT, K, substeps=p.substeps),
        "projected": gal.project(X_tr),
    }

    def windows(v):
        return " ".join(f"{v[w * K : (w + 1) * K + 1].max():.1e}" for w in range(p.long_factor))

    E = gal.reduced_energy(Yg_te.reshape(-1, args.dim), np.repeat(c_te, L + 1)).reshape(len(c_te), -1)
    print(
        f"2n={args.dim}; windows of length T = {p.T}; Galerkin ROM energy error per window: "
        f"{windows(np.max(np.abs(E - E[:, :1]) / np.abs(E[:, :1]), axis=0))}"
    )
    Yp_te = gal.project(X_te)
    Ep = gal.reduced_energy(Yp_te.reshape(-1, args.dim), np.repeat(c_te, L + 1)).reshape(len(c_te), -1)
    Ef = fom.energy(X_te.reshape(-1, fom.dim), np.repeat(c_te, L + 1)).reshape(len(c_te), -1)
    print(
        f"projected FOM test trajectories (diagnostic): energy error dx H(V V+ x) per window: "
        f"{windows(np.max(np.abs(Ep - Ep[:, :1]) / np.abs(Ep[:, :1]), axis=0))}; FOM's own: "
        f"{windows(np.max(np.abs(Ef - Ef[:, :1]) / np.abs(Ef[:, :1]), axis=0))}; projection error per window: "
        f"{windows(np.max(np.linalg.norm(gal.reconstruct(Yp_te) - X_te, axis=-1) / np.linalg.norm(X_te, axis=-1), axis=0))}"
    )
    amp = lambda Z: np.hypot(Z[..., :n], Z[..., n:])  # noqa: E731
    for kind in args.data:
        Y = data[kind]
        a_data = amp(Y).max(axis=(0, 1))
        lo, hi = Y.reshape(-1, args.dim).min(axis=0), Y.reshape(-1, args.dim).max(axis=0)
        for name, Z in (
            ("Galerkin ROM from the test states", Yg_te),
            ("projected FOM test trajectories", gal.project(X_te)),
        ):
            outside = np.any((Z < lo) | (Z > hi), axis=-1).mean(axis=0)
            print(
                f"{kind} data; reference {name} (diagnostic): share outside the {kind} data box per window: "
                f"{windows(outside)}; largest mode amplitude / training max per window: "
                f"{windows((amp(Z).max(axis=0) / a_data).max(axis=1))}"
            )
        for aug in args.augment:
            if aug.startswith("energy") and kind != "reduced":
                continue
            Y0, Y1 = Y[:, :-1], Y[:, 1:]
            strategy = {
                "none": no_augmentation,
                "symmetry": sign_symmetry,
                "energy": EnergySamples(gal, p.c_range, p.DT, p.substeps),
                "energy-box": EnergySamples(gal, p.c_range, p.DT, p.substeps, region="box"),
            }[aug]
            for lam, eps in [(lam, eps) for lam in (args.lambdas or [None]) for eps in args.state_eps]:
                flow, model, fit_time, reg, table = _fit_kernel(
                    replace(p, state_eps=eps), Y0, Y1, c_tr, p.DT, regularization=lam, augment=strategy, gal=gal
                )
                head = (
                    f"{kind:9s} augment={aug:8s} state_eps={eps} lambda={reg:g} (table {table}, fit pairs {len(strategy(Y0, Y1, c_tr)[0])}, "
                    f"fit {fit_time:.0f} s)"
                )
                Yk, failed = None, None
                try:
                    Yk = flow.rollout(y0, L, mu=c_te[:, None], dt=p.DT)
                except Exception as exc:
                    failed = f"{type(exc).__name__}: {str(exc)[:150]}"
                if Yk is None:  # find the failing step by rolling out window by window
                    print(f"{head}: rollout fails: {failed}")
                    continue
                Ek = gal.reduced_energy(Yk.reshape(-1, args.dim), np.repeat(c_te, L + 1)).reshape(len(c_te), -1)
                err = np.max(np.abs(Ek - Ek[:, :1]) / np.abs(Ek[:, :1]), axis=0)
                st = flow.state_scaling
                tr = st.transform(np.concatenate(strategy(Y0, Y1, c_tr)[:2]))
                tr = np.unique(tr, axis=0)  # x1 of one pair is x0 of the next
                tree = cKDTree(tr)
                nn = np.median(tree.query(tr, k=2)[0][:, 1])
                d = tree.query(st.transform(Yk.reshape(-1, args.dim)))[0].reshape(len(c_te), -1).max(axis=0) / nn
                lo, hi = tr.min(axis=0), tr.max(axis=0)
                yk = st.transform(Yk.reshape(-1, args.dim))
                out = (np.any((yk < lo) | (yk > hi), axis=1)).reshape(len(c_te), -1).mean(axis=0)
                amax = amp(np.concatenate(strategy(Y0, Y1, c_tr)[:2])).max(axis=0)
                ak = amp(Yk).max(axis=0) / amax  # (L+1, n)
                print(
                    f"{head}\n  energy error per window: {windows(err)}\n  distance to data / median NN spacing, max per window: "
                    f"{windows(d)}\n  share outside the data box per window: {windows(out)}\n  largest mode amplitude / "
                    f"training max per window: {windows(ak.max(axis=1))}; mode reaching it first: "
                    f"{int(np.argmax(ak.max(axis=0)))} (ratios at the end {np.round(ak[-1], 2).tolist()})"
                )
