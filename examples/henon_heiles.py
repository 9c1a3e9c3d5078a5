"""A Hénon–Heiles system defined by its Hamiltonian: flow-map data, symplectic predictor, long rollout.

Run:  python examples/henon_heiles.py [--samples 300] [--centers 600]

H(q, p; lambda) = (p1^2 + p2^2 + q1^2 + q2^2)/2 + lambda (q1^2 q2 - q2^3/3), with lambda and the
macro step dT as variables of one predictor.  The user code (marked) is the 15 lines a user writes;
the rest checks the result against sympredict's RK4 reference flow.
"""

import argparse

import numpy as np

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--samples", type=int, default=300, help="flow-map samples per training lambda")
parser.add_argument("--centers", type=int, default=600)
parser.add_argument("--steps", type=int, default=500, help="macro steps of the test rollout")
args = parser.parse_args()

# ---- user code: 15 lines ------------------------------------------------------------------------
from sympredict import SymplecticKernelPredictor
from sympredict.systems.flowmaps import (
    HamiltonianSystem,
    check_generating_function,
    sample_energy_box,
    sampled_flow_map_data,
)
from sympredict.kernels import IMQ

H = lambda x, mu: 0.5 * (x**2).sum(axis=1) + mu[:, 0] * (x[:, 0] ** 2 * x[:, 1] - x[:, 1] ** 3 / 3)
grad_H = lambda x, mu: np.column_stack(
    [x[:, 0] * (1 + 2 * mu[:, 0] * x[:, 1]), x[:, 1] + mu[:, 0] * (x[:, 0] ** 2 - x[:, 1] ** 2), x[:, 2], x[:, 3]]
)
system = HamiltonianSystem(H, grad_H, dim=4, parameters={"lambda": 1})
space = system.parameters.space(0.8, 1.2)
sampler = lambda mu, n, rng: sample_energy_box(
    system, n, mu, 1 / 12, -0.7, 0.7, rng
)  # bounded orbits: E < 1/(6 lambda^2)
data = sampled_flow_map_data(system, space.sample_uniformly(5), ("range", 0.1, 0.3), sampler, args.samples, seed=0)
val = sampled_flow_map_data(system, space.sample_randomly(3), ("range", 0.1, 0.3), sampler, args.samples // 4, seed=1)
check_generating_function(system, data)  # fails with the largest admissible dT if dT is too large
model = SymplecticKernelPredictor(IMQ(1.0), IMQ(2.0), IMQ(3.0), max_centers=args.centers)
model.fit(data.x0, data.x1, mu=data.mu, dt=data.dt, validation=(val.x0, val.x1, val.mu, val.dt))
# -------------------------------------------------------------------------------------------------

from sympredict.testing import assert_energy_bounded, assert_symplectic_step  # noqa: E402

lam, dT = 0.93, 0.17  # neither trained on
x0 = sampler(np.array([lam]), 4, np.random.default_rng(5))
pred = model.rollout(x0, args.steps, mu=lam, dt=dT)
ref = system.trajectory(x0, lam, dT, args.steps)
err = np.linalg.norm(pred - ref, axis=2) / np.linalg.norm(ref, axis=2)
print(
    f"{model.n_centers_} centres; relative error after 10 steps {err[:, 10].mean():.2e}, "
    f"after {args.steps} steps (t = {args.steps * dT:.0f}) {err[:, -1].mean():.2e}"
)
energy = assert_energy_bounded(system.hamiltonian, pred, mu=np.full((4, 1), lam), rtol=0.05)
print(f"max relative energy error over the rollout {energy:.2e}")
print(f"symplecticity defect {assert_symplectic_step(model, x0, mu=lam, dt=dT)['analytic']:.1e}")
