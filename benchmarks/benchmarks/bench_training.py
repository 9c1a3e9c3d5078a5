"""Training: the greedy's time, peak memory and accuracy at a fixed number of centres."""

import numpy as np

from ._common import holdout, pendulum_model, pendulum_samples


class GreedyFit:
    """The exact f-greedy on the pendulum's flow-map samples (3,264 samples, 2 functionals each)."""

    params = [100, 400]
    param_names = ["centres"]
    timeout = 300

    def setup(self, centres):
        self.data = pendulum_samples()
        self.model = pendulum_model(centres)

    def time_fit(self, centres):
        d = self.data
        self.model.fit(d.x0, d.x1, mu=d.mu, dt=d.dt)

    def peakmem_fit(self, centres):
        d = self.data
        self.model.fit(d.x0, d.x1, mu=d.mu, dt=d.dt)

    def track_median_step_error(self, centres):
        """Median relative one-step error |Phi(x0) - x1| / |x1 - x0| on 200 training-grid samples."""
        d = self.data
        model = self.model.fit(d.x0, d.x1, mu=d.mu, dt=d.dt)
        x0, x1, mu, dt = holdout(d)
        err = np.linalg.norm(model.step(x0, mu=mu, dt=dt) - x1, axis=1) / np.linalg.norm(x1 - x0, axis=1)
        return float(np.median(err))

    track_median_step_error.unit = "relative error"
