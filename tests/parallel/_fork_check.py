"""Run as a script: a compiled parallel rollout, then os.fork and a Pool(fork) rolling out in the children."""

import multiprocessing
import os
import sys
import warnings

import numpy as np

from sympredict import SymplecticKernelPredictor
from sympredict.interpolation.greedy import ExactGreedy
from sympredict.kernels import IMQ
from sympredict.symplectic.solvers import NewtonSolver
from sympredict.systems.pendulum import Pendulum, flow_map_data

d = flow_map_data(Pendulum(), n_grid=8)
model = SymplecticKernelPredictor(
    IMQ(0.15),
    mu_kernel=IMQ(2.0),
    dt_kernel=IMQ(5.0),
    max_centers=60,
    trainer=ExactGreedy(tol=1e-8),
    solver=NewtonSolver(backend="numba"),
)
model.fit(d.x0, d.x1, mu=d.mu, dt=d.dt)
x0 = np.column_stack([np.linspace(-0.5, 0.5, 16), np.linspace(0.3, -0.3, 16)])
args = dict(mu=np.full(16, 0.75), dt=0.05)
parent = model.rollout(x0, 5, **args)


def work(i):
    return model.rollout(x0, 5, **args)


pid = os.fork()
if pid == 0:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        child = model.rollout(x0, 5, **args)
        again = model.rollout(x0, 5, **args)
    ok = np.array_equal(child, parent) and np.array_equal(again, parent)
    n_warn = sum(issubclass(w.category, RuntimeWarning) and "forked" in str(w.message) for w in caught)
    os._exit(0 if ok and n_warn == 1 else 3)
_, status = os.waitpid(pid, 0)
print("fork child status", status, flush=True)
with multiprocessing.get_context("fork").Pool(2) as pool:
    results = pool.map_async(work, range(4)).get(timeout=120)
print("pool equal", all(np.array_equal(r, parent) for r in results), flush=True)
sys.exit(0 if status == 0 and all(np.array_equal(r, parent) for r in results) else 1)
