"""Shared set-up of the asv benchmarks: deliberate threads and small fixed data sets."""

import functools

import numpy as np
from threadpoolctl import threadpool_limits

# one BLAS thread for every benchmark: on small machines a second OpenBLAS thread competes with numba's
# threads and with other processes (2-20x slower dense work), and timings would follow the machine's load
threadpool_limits(1)


@functools.lru_cache(maxsize=None)
def pendulum_samples(n_grid: int = 20):
    """Flow-map samples of the pendulum (scenario A on an ``n_grid x n_grid`` grid): ``FlowMapData``."""
    from sympredict.systems.pendulum import Pendulum, flow_map_data

    return flow_map_data(Pendulum(), n_grid=n_grid)


def pendulum_model(max_centers: int = 400, trainer=None):
    """An unfitted pendulum model with fixed kernels (no search: the greedy alone is measured)."""
    from sympredict import SymplecticKernelPredictor
    from sympredict.interpolation.greedy import ExactGreedy
    from sympredict.kernels import IMQ

    return SymplecticKernelPredictor(
        IMQ(0.15),
        mu_kernel=IMQ(2.0),
        dt_kernel=IMQ(5.0),
        max_centers=max_centers,
        trainer=ExactGreedy(tol=1e-10) if trainer is None else trainer,
    )


def holdout(data, n: int = 200, seed: int = 0):
    """``n`` samples of ``data`` drawn with a fixed seed: ``(x0, x1, mu, dt)``."""
    rows = np.random.default_rng(seed).choice(len(data.x0), size=min(n, len(data.x0)), replace=False)
    return data.x0[rows], data.x1[rows], data.mu[rows], data.dt[rows]
