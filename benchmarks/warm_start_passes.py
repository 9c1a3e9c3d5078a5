"""Passes over the centres per macro step of the compiled rollout, cold (explicit guess) against warm start.

Pendulum, n_grid 30, IMQ (0.2, 1.5, 3.0), 1,000 centres; the paper's 25 test
instances (seed 0), 400 steps.  Counts passes (deterministic, no timing) and
compares both trajectories with each other and with the reference.

Run:  python benchmarks/warm_start_passes.py
"""

import numpy as np
from threadpoolctl import threadpool_limits

from sympredict import SymplecticKernelPredictor, _fastkernels
from sympredict.paper.pendulum import paper_test_instances
from sympredict.kernels import IMQ
from sympredict.symplectic.metrics import relative_trajectory_error
from sympredict.systems.pendulum import Pendulum, flow_map_data

with threadpool_limits(1):
    system = Pendulum()
    d = flow_map_data(system, n_grid=30)
    model = SymplecticKernelPredictor(IMQ(0.2), IMQ(1.5), IMQ(3.0), max_centers=1000).fit(d.x0, d.x1, mu=d.mu, dt=d.dt)
    x0, lengths = paper_test_instances(0)
    sur = model.surrogate_
    for dt in (0.05, 0.0509):
        dts = np.full(len(x0), dt)
        w = sur.weights(lengths[:, None], dts)
        ref = system.trajectory(x0, lengths, dt, 400)
        trajs = {}
        for warm in (False, True):
            stats = {}
            traj, codes, *_ = _fastkernels.newton_rollout(x0, w, dts, sur.layout(), sur.kernel.state, 50, 400,
                                                          stats=stats, warm_start=warm)
            trajs[warm] = traj
            err = np.median(relative_trajectory_error(traj, ref).mean(axis=0)[1:])
            print(f"dT={dt} {'warm' if warm else 'cold'}: {stats['passes'].sum() / (len(x0) * 400):.2f} passes/step, "
                  f"failures {int((codes != 0).sum())}, median error {err:.3e}")
        print(f"  max |warm - cold| = {np.abs(trajs[True] - trajs[False]).max():.1e}")
