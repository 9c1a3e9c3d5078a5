"""Sine-Gordon kernel ROMs: why the implicit step's Newton solve fails, per training data and ridge term.

The issue-15 setting with 20 training trajectories (c in {0.8, ..., 1.2} x amplitude
in {0.5, ..., 1.5}, 5 x 4, T = 5, DT = 0.1, N = 1000), a complex-SVD basis of size 2n,
and one kernel ROM per training data (``reduced``: Galerkin trajectories;
``projected``: the FOM trajectories projected, non-intrusive) and ridge term
``lambda``, 1500 centres, in the scaled coordinates of the experiment.  Printed per
model: the greedy's last residual, ``dT L_S`` (the implicit step is a contraction
where it is < 1; ``solvability``) at the training states and at midpoints of random
pairs of them, the largest expansion coefficient, and whether a rollout from the
training trajectories' initial states runs (Newton failures counted).

Run:  python sympredict_paper/studies/sine_gordon_newton.py [--dims 8 12] [--lambdas 0 1e-6]
"""

import argparse
import warnings
from dataclasses import replace

import numpy as np

import _protocol  # sympredict_paper/studies/ (the script's folder is on sys.path)
from _sine_gordon_data import galerkin_rom  # sympredict_paper/studies/

from sympredict_paper.sine_gordon import PRESETS, _fit_kernel
from sympredict.systems.sine_gordon import SineGordonFOM

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--dims", type=int, nargs="*", default=[8, 12])
parser.add_argument("--lambdas", type=float, nargs="*", default=[0.0, 1e-6])
parser.add_argument("--max-centers", type=int, default=1500)
_protocol.add_arguments(parser, json_option=False)
args = parser.parse_args()
warnings.simplefilter("ignore")

p = PRESETS["quick"]
K = int(round(p.T / p.DT))
fom = SineGordonFOM(n_points=p.n_points, length=p.length, T=p.T, nt=K)
c_tr = np.repeat(np.linspace(*p.c_range, 5), 4)
a_tr = np.tile(np.linspace(*p.amplitude_range, 4), 5)
with _protocol.limits(args.blas_threads):
    X = fom.reference_trajectory(a_tr[:, None] * fom.sech_cos(2.0, 1.0), c_tr, p.DT, K, tol=p.ref_tol)
    for dim in args.dims:
        gal = galerkin_rom(fom, X, dim)
        data = {
            "reduced": gal.solve(gal.project(X[:, 0]), c_tr, p.DT, K, substeps=p.substeps),
            "projected": gal.project(X),
        }
        for kind, Y in data.items():
            for lam in args.lambdas:
                flow, model, *_ = _fit_kernel(
                    replace(p, max_centers=args.max_centers),
                    Y[:, :-1],
                    Y[:, 1:],
                    c_tr,
                    p.DT,
                    regularization=lam,
                    gal=gal,
                )
                xs = flow.state_scaling.transform(Y[:, :-1].reshape(-1, dim))
                ms = flow.mu_scaling.transform(np.repeat(c_tr, K)[:, None])
                at = model.solvability(xs, mu=ms, dt=1.0)
                a, b = np.random.default_rng(0).integers(0, len(xs), (2, 2000))
                mid = model.solvability(0.5 * (xs[a] + xs[b]), mu=0.5 * (ms[a] + ms[b]), dt=1.0)
                try:
                    flow.rollout(Y[:, 0], K, mu=c_tr[:, None], dt=p.DT)
                    roll = "rollout from the training initial states runs"
                except Exception as exc:
                    roll = f"rollout fails: {type(exc).__name__}: {str(exc)[:110]}"
                print(
                    f"2n={dim} {kind:9s} lambda={lam:g}: residual {model.history_.train_max_residual[-1]:.2e}, "
                    f"dT L_S at training states median {np.median(at):.2f} max {at.max():.2f} ({np.mean(at >= 1):.0%} >= 1), "
                    f"between them median {np.median(mid):.2f} max {mid.max():.2f}; max |coef| {np.abs(model.surrogate_.coef).max():.1e}; "
                    f"{roll}"
                )
