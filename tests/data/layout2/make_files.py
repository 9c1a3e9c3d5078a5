"""Writes the layout-2 model files in this folder (sympredict 0.1's flat estimator options).

Run once with the code of commit 98cca6a (the last to write layout 2), from any folder:

    git worktree add /tmp/old 98cca6a
    PYTHONPATH=/tmp/old python tests/data/layout2/make_files.py tests/data/layout2

Each model is small (pendulum, 40 centres); ``expected.json`` holds the states each model predicted
when it was written (rollouts of 3 steps), which ``tests/estimators/test_parts.py`` compares the loaded models with.
"""

import json
import sys
from pathlib import Path

import numpy as np

from sympredict import DirectKernelPredictor, SymplecticKernelPredictor
from sympredict.interpolation.greedy import ActiveSetGreedy, ExactGreedy
from sympredict.kernels import IMQ, Matern52
from sympredict.systems.pendulum import Pendulum, flow_map_data

out = Path(sys.argv[1])
data = flow_map_data(Pendulum(), n_grid=12)
rng = np.random.default_rng(0)
inside = np.flatnonzero(np.abs(data.x0[:, 0]) < 3.0)  # no two angles one period apart (periodic model)
idx = rng.choice(inside, 300, replace=False)
x0, x1, mu, dt = data.x0[idx], data.x1[idx], data.mu[idx], data.dt[idx]
start = x0[:3] * 0.5


def pendulum_model(state=None, cls=SymplecticKernelPredictor, **options):
    """A model of 40 centres with the parameter and step kernels every model here shares (state kernel
    ``IMQ(0.3)`` unless given); ``options``: its own."""
    return cls(IMQ(0.3) if state is None else state, IMQ(1.5), IMQ(3.0), max_centers=40, **options)


models = {
    "plain": pendulum_model(),
    "solver_and_greedy": pendulum_model(
        Matern52(0.4),
        tol=1e-9,
        criterion="p",
        power_tol=1e-11,
        newton_max_iter=30,
        backend="numpy",
        newton_warm_start=True,
        regularization=1e-10,
    ),
    "midpoint_scaled": pendulum_model(update="midpoint", state_scaling=[1.5]),
    "periodic": pendulum_model(periodic=(0,), period=2 * np.pi, backend="numpy"),
    "symmetric": pendulum_model(update="midpoint", symmetry=[(1, 1), (-1, -1)], backend="auto"),
    "active_set": pendulum_model(tol=1e-8, trainer=ActiveSetGreedy(initial_points=200, refresh_every=20)),
    "float32": pendulum_model(trainer=ExactGreedy("float32")),
    "direct": pendulum_model(cls=DirectKernelPredictor, tol=1e-9, power_tol=1e-11),
}
expected = {"start": start.tolist(), "mu": mu[:3].tolist(), "dt": dt[:3].tolist(), "models": {}}
for name, model in models.items():
    model.fit(x0, x1, mu=mu, dt=dt)
    model.save(out / f"{name}.h5")
    expected["models"][name] = model.rollout(start, 3, mu=mu[:3], dt=dt[:3]).tolist()
(out / "expected.json").write_text(json.dumps(expected, indent=1))
