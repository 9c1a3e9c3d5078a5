"""The sine-Gordon benchmarks' FOM data, cached in an npz file between runs (the studies only)."""

import os
from dataclasses import replace

import numpy as np

from sympredict_paper.sine_gordon import fom_data


def cached_fom_data(p, cache: str) -> dict:
    """:func:`~sympredict_paper.sine_gordon.fom_data` of preset ``p``, the trajectories kept in ``cache``.

    A cached file gives the training and test trajectories and parameters; the FOM itself is rebuilt (cheap:
    one step of one trajectory).  The cache is keyed by the caller's file name only, so callers name it by
    preset and sizes.
    """
    if os.path.exists(cache):
        z = np.load(cache)
        d = fom_data(replace(p, n_c=1, n_amplitude=1, n_test=1, T=p.DT, long_factor=2))  # the FOM only (cheap)
        return {**d, **{k: z[k] for k in ("X_tr", "X_te", "c_tr", "c_te")}}
    d = fom_data(p)
    np.savez(cache, **{k: d[k] for k in ("X_tr", "X_te", "c_tr", "c_te")})
    return d
