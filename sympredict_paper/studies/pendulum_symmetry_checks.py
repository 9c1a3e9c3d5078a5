"""Two checks behind ``symmetry=`` on the pendulum (docs/explanation/beyond.md, "State symmetries").

1. ``--part invariance``: on the exact flow (SciPy DOP853, rtol 1e-13), whether the gradient data of the
   midpoint ``s((x0 + x1)/2)`` and of the type-II ``s(q0, p1)`` transform with the sign flips ``g``
   (``y(g z) = g y(z)``): 20 random states at ``dT = 0.05``; for type II the ``p0`` whose image has
   momentum ``+-p1`` is found by root finding.
2. ``--part design``: the group-averaged kernel against an invariant feature map ``F(q, p) = (q^2, p^2)``
   inside the radial kernel and the plain kernel: dense HB interpolation of all functionals of 300
   midpoints at one ``(l, dT)``, IMQ shape chosen on 1,000 validation samples, max gradient error on
   1,000 test samples relative to the largest target.

Run:  python sympredict_paper/studies/pendulum_symmetry_checks.py [--part invariance|design|both]
"""

import argparse

import numpy as np
from scipy.integrate import solve_ivp
from scipy.linalg import cho_factor, cho_solve, eigvalsh
from scipy.optimize import brentq

import _protocol  # sympredict_paper/studies/ (the script's folder is on sys.path)

from sympredict.interpolation.functionals import HBFunctionals
from sympredict.kernels import IMQ, ProductKernel, StateSymmetry
from sympredict.symplectic.metrics import canonical_J
from sympredict.estimators.predictor import update_variables
from sympredict.systems.pendulum import Pendulum

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--part", default="both", choices=["invariance", "design", "both"])
_protocol.add_arguments(parser, json_option=False)
args = parser.parse_args()

J = canonical_J(2)
KLEIN = [(1, 1), (-1, -1), (1, -1), (-1, 1)]
L, DT = 0.75, 0.05
system = Pendulum()


def exact_flow(x, length, t):
    f = lambda _, y: [y[1] / (system.mass * length**2), -system.mass * system.g * length * np.sin(y[0])]
    return solve_ivp(f, (0, t), x, method="DOP853", rtol=1e-13, atol=1e-14).y[:, -1]


def invariance():
    rng = np.random.default_rng(0)
    worst_mid, worst_ii = 0.0, {s: 0.0 for s in KLEIN[1:]}
    for _ in range(20):
        x0, length = rng.uniform([-1.5, -3], [1.5, 3]), rng.uniform(0.7, 0.8)
        x1 = exact_flow(x0, length, DT)
        xbar, y = 0.5 * (x0 + x1), J.T @ (x1 - x0) / DT
        for s in KLEIN:
            g = np.diag(s).astype(float)
            symplectic = np.allclose(g.T @ J @ g, J)
            a = g @ x0 if symplectic else g @ x1  # a symmetry maps x0 -> g x0, a reversing one R x1 -> R x0
            b = exact_flow(a, length, DT)
            assert np.allclose(0.5 * (a + b), g @ xbar, atol=1e-10)
            worst_mid = max(worst_mid, np.abs(J.T @ (b - a) / DT - g @ y).max())
        xi = np.array([x0[0], x1[1]])
        for s in KLEIN[1:]:
            q0g, p1g = np.array(s) * xi
            p0g = brentq(lambda p: exact_flow(np.array([q0g, p]), length, DT)[1] - p1g, -6, 6, xtol=1e-14)
            a = np.array([q0g, p0g])
            worst_ii[s] = max(worst_ii[s], np.abs(J.T @ (exact_flow(a, length, DT) - a) / DT - np.array(s) * y).max())
    print(f"midpoint s: max |y(g xbar) - g y(xbar)| over 20 states and the 4 flips: {worst_mid:.2e}")
    for s, v in worst_ii.items():
        print(f"type-II s(q0, p1), g = diag{s}: max |y(g xi) - g y(xi)| = {v:.2e}")


def samples(n, seed):
    rng = np.random.default_rng(seed)
    x0 = np.column_stack([rng.uniform(-1.6, 1.6, 4 * n), rng.uniform(-4.0, 4.0, 4 * n)])
    e_max = system.hamiltonian(np.array([[1.6, 0.0]]), [L])[0]
    x0 = x0[system.hamiltonian(x0, np.full(len(x0), L)) < e_max][:n]
    return update_variables("midpoint", x0, system.flow(x0, L, DT), np.full(n, DT))


def gram_library(kernel, xa, xb):
    """HB Gramian (2 Na, 2 Nb) of the library's functionals (plain or group-averaged kernel)."""
    fa = HBFunctionals(kernel, xa, np.zeros((len(xa), 0)), np.full(len(xa), DT))
    fb = HBFunctionals(kernel, xb, np.zeros((len(xb), 0)), np.full(len(xb), DT))
    return fa.gram_rows(fb, np.arange(fb.n_functionals), out=np.empty((fb.n_functionals, fa.n_functionals))).T


def gram_feature(eps, xa, xb):
    """HB Gramian of k(F(x), F(y)), F = x * x: -4 x_a y_b (B u_a u_b + A delta_ab), u = F(x) - F(y)."""
    u = xa[:, None, :] ** 2 - xb[None, :, :] ** 2
    A, B = IMQ(eps).factors(np.sqrt((u * u).sum(-1)), order=2)
    g = (
        -4
        * xa[:, None, :, None]
        * xb[None, :, None, :]
        * (B[..., None, None] * u[..., :, None] * u[..., None, :] + A[..., None, None] * np.eye(2))
    )
    return g.transpose(0, 2, 1, 3).reshape(2 * len(xa), 2 * len(xb))


def design():
    tr, va, te = samples(300, 0), samples(1000, 1), samples(1000, 2)
    klein = StateSymmetry.from_signs(KLEIN)
    kernels = {
        "plain": lambda e, a, b: gram_library(ProductKernel(IMQ(e)), a, b),
        "group average": lambda e, a, b: gram_library(ProductKernel(IMQ(e), symmetry=klein), a, b),
        "feature map (q^2, p^2)": gram_feature,
    }
    for name, gram in kernels.items():
        best = None
        for eps in (0.1, 0.2, 0.4, 0.8, 1.6, 3.2):
            K = gram(eps, tr[0], tr[0])
            lam = eigvalsh(K, subset_by_index=[0, 0])[0] / np.abs(np.diag(K)).max()
            try:
                c = cho_solve(cho_factor(K + 1e-15 * np.abs(np.diag(K)).max() * np.eye(len(K))), tr[1].reshape(-1))
            except np.linalg.LinAlgError:
                print(f"  {name}, eps {eps}: Cholesky failed (lambda_min / max G_ii = {lam:.1e})")
                continue
            err = lambda s: np.abs(gram(eps, s[0], tr[0]) @ c - s[1].reshape(-1)).max() / np.abs(s[1]).max()
            v = err(va)
            print(f"  {name}, eps {eps}: validation {v:.2e} (lambda_min / max G_ii = {lam:.1e})")
            if best is None or v < best[1]:
                best = (eps, v, err(te))
        print(f"{name}: chosen eps {best[0]}, validation {best[1]:.2e}, test {best[2]:.2e}")


with _protocol.limits(args.blas_threads):
    if args.part in ("invariance", "both"):
        invariance()
    if args.part in ("design", "both"):
        design()
