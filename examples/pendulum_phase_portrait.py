"""From data to phase portrait: the parameter-augmented symplectic predictor on the pendulum.

Run:  python examples/pendulum_phase_portrait.py [--n-grid 30] [--centers 800] [--out pendulum_example.png]

1. flow-map data over lengths l in {0.7, ..., 0.8} and macro steps dT in {0.04, 0.05, 0.06}
   (energy-bounded grid, reference flow by implicit midpoint with micro step 1e-3);
2. one surrogate s(xi, l, dT) with IMQ product kernel, trained by f-greedy;
3. a 20-second rollout at an unseen length and step, against the reference and
   implicit midpoint at the same macro step; phase portrait and energy error.
"""

import argparse

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from sympredict import SymplecticKernelPredictor
from sympredict.symplectic.integrators import implicit_midpoint_step, integrate
from sympredict.kernels import IMQ
from sympredict.symplectic.metrics import relative_hamiltonian_error, relative_trajectory_error
from sympredict.systems.pendulum import Pendulum, flow_map_data

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--n-grid", type=int, default=30)
parser.add_argument("--centers", type=int, default=800)
parser.add_argument("--horizon", type=float, default=20.0)
parser.add_argument("--out", default="pendulum_example.png")
args = parser.parse_args()

pendulum = Pendulum()
data = flow_map_data(pendulum, n_grid=args.n_grid)  # x0, x1 (M, 2); mu (M, 1); dt (M,)
model = SymplecticKernelPredictor(IMQ(0.15), mu_kernel=IMQ(2.0), dt_kernel=IMQ(5.0), max_centers=args.centers)
model.fit(data.x0, data.x1, mu=data.mu, dt=data.dt)
print(
    f"{model.n_centers_} centres from {2 * len(data)} functionals, max training residual {model.history_.train_max_residual[-1]:.1e}"
)

x0 = np.array([[1.2, 0.0]])
length, dt = 0.737, 0.0509  # neither in the training set
n_steps = int(args.horizon / dt)
ref = pendulum.trajectory(x0, length, dt, n_steps)
pred = model.rollout(x0, n_steps, mu=length, dt=dt)
im = integrate(implicit_midpoint_step, pendulum, x0, np.array([[length]]), dt, n_steps)
for name, traj in (("kernel predictor", pred), ("implicit midpoint", im)):
    err = relative_trajectory_error(traj, ref)[0, 1:]
    print(f"{name:>18}: median relative error {np.median(err):.1e}, max {err.max():.1e}")

t = dt * np.arange(n_steps + 1)
fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.2))
ax1.plot(ref[0, :, 0], ref[0, :, 1], "k-", lw=2.5, alpha=0.4, label="reference")
ax1.plot(pred[0, :, 0], pred[0, :, 1], "C0--", label="kernel predictor")
ax1.plot(im[0, :, 0], im[0, :, 1], "C1:", label="implicit midpoint, macro step")
ax1.set(xlabel="angle q [rad]", ylabel="angular momentum p", title=f"phase portrait, l={length}, dT={dt}")
ax1.legend()
for name, traj, style in (
    ("kernel predictor", pred, "C0-"),
    ("implicit midpoint", im, "C1-"),
    ("reference", ref, "k-"),
):
    ax2.semilogy(
        t[1:], relative_hamiltonian_error(pendulum, traj, np.array([[length]]))[0, 1:] + 1e-17, style, label=name, lw=1
    )
ax2.set(xlabel="time t", ylabel="relative Hamiltonian error", title="energy error (bounded: symplectic)")
ax2.legend()
fig.tight_layout()
fig.savefig(args.out, dpi=130)
print(f"wrote {args.out}")
