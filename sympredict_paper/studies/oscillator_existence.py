"""Existence range of the two generating-function updates on the linear oscillator H = (q^2 + p^2) / 2.

The exact step is a rotation by theta = omega dT.  Each update is trained on
300 states uniform in [-1, 1]^2 (fixed step, IMQ 0.5, all 600 functionals
offered) and tested on 40 states in [-0.5, 0.5]^2: max abs error of one step.
The midpoint form's s exists for theta < pi (S = 2/dT tan(theta/2) I); the
type-II s(q0, p1) degenerates at theta = pi/2.

Run:  python sympredict_paper/studies/oscillator_existence.py [--blas-threads 1]
"""

import argparse
import warnings

import numpy as np

import _protocol  # sympredict_paper/studies/ (the script's folder is on sys.path)

from sympredict import SymplecticKernelPredictor
from sympredict.kernels import IMQ
from sympredict.symplectic.solvers import NewtonSolver


def rotation(x, theta):
    c, s = np.cos(theta), np.sin(theta)
    return np.column_stack([c * x[:, 0] + s * x[:, 1], -s * x[:, 0] + c * x[:, 1]])


parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
_protocol.add_arguments(parser, json_option=False)
args = parser.parse_args()
rng = np.random.default_rng(0)
x0 = rng.uniform(-1, 1, (300, 2))
xt = 0.5 * np.random.default_rng(1).uniform(-1, 1, (40, 2))
print(f"{'theta':>7} {'symplectic_euler':>18} {'midpoint':>10}")
with _protocol.limits(args.blas_threads), warnings.catch_warnings():
    warnings.simplefilter("ignore")
    for theta in [0.5, 1.2, 1.5, np.pi / 2, 1.7, 2.5, 3.0]:
        errs = []
        for update in ("symplectic_euler", "midpoint"):
            model = SymplecticKernelPredictor(
                IMQ(0.5), max_centers=600, update=update, solver=NewtonSolver(backend="numpy")
            )
            try:
                model.fit(x0, rotation(x0, theta), dt=theta)
                errs.append(f"{np.abs(model.step(xt) - rotation(xt, theta)).max():.1e}")
            except ArithmeticError as exc:
                errs.append(f"failed ({type(exc).__name__})")
        print(f"{theta:7.3f} {errs[0]:>18} {errs[1]:>10}")
