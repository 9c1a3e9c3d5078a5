"""Prediction: rollouts of a fitted model on the compiled and the NumPy Newton solver."""

import numpy as np

from ._common import pendulum_model, pendulum_samples


class Rollout:
    """100 steps of 200 pendulum trajectories (a 400-centre model), per backend."""

    params = ["numba", "numpy"]
    param_names = ["backend"]
    timeout = 300

    def setup(self, backend):
        from sympredict._numba import HAVE_NUMBA

        if backend == "numba" and not HAVE_NUMBA:
            raise NotImplementedError("numba is not installed")  # asv reports the benchmark as skipped
        d = pendulum_samples()
        self.model = pendulum_model(400).fit(d.x0, d.x1, mu=d.mu, dt=d.dt)
        self.model.set_params(solver__backend=backend)
        rng = np.random.default_rng(0)
        self.x0 = np.column_stack([rng.uniform(-1.0, 1.0, 200), rng.uniform(-0.5, 0.5, 200)])
        self.mu, self.dt = np.full(200, 0.75), np.full(200, 0.05)
        self.model.rollout(self.x0[:2], 2, mu=self.mu[:2], dt=self.dt[:2])  # compilation and caches: not timed

    def time_rollout(self, backend):
        self.model.rollout(self.x0, 100, mu=self.mu, dt=self.dt)

    def track_energy_drift(self, backend):
        """Largest relative energy drift over the 100 steps (symplectic: bounded, not growing)."""
        from sympredict.systems.pendulum import Pendulum

        traj = self.model.rollout(self.x0, 100, mu=self.mu, dt=self.dt)
        H = Pendulum().hamiltonian(traj.reshape(-1, 2), np.repeat(self.mu, traj.shape[1])).reshape(traj.shape[:2])
        return float(np.max(np.abs(H - H[:, :1]) / np.abs(H[:, :1]).clip(1e-12)))

    track_energy_drift.unit = "relative energy error"
