"""The sine-Gordon benchmarks' FOM data, cached in an npz file between runs (the studies only)."""

import os
import time
from dataclasses import replace
from typing import Callable, Optional

import numpy as np

from sympredict.mor.basis import complex_svd_basis
from sympredict.mor.nonlinear import ReducedSineGordon
from sympredict_paper.sine_gordon import failure_text, fom_data


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


def load_fom_data(
    p, preset: str, cache: Optional[str] = None, show: Callable = lambda c: np.round(c, 3).tolist()
) -> tuple:
    """The split studies' FOM data of preset ``p`` (named ``preset``): :func:`cached_fom_data`, by default cached
    per preset and sizes under ``/tmp``, reported in one line (the test parameters as ``show(c_te)``).

    Returns
    -------
    tuple
        ``(fom, K, c_tr, c_te, X_tr, X_te)``: the FOM, the steps ``K = T / DT`` of a training trajectory, the
        training and test parameters and trajectories.
    """
    cache = cache or f"/tmp/sine_gordon_split_{preset}_{p.n_c}x{p.n_amplitude}.npz"
    t0 = time.perf_counter()
    d = cached_fom_data(p, cache)
    print(
        f"FOM data: {len(d['c_tr'])} training, {len(d['c_te'])} test trajectories ({time.perf_counter() - t0:.0f} s); "
        f"test c = {show(d['c_te'])}",
        flush=True,
    )
    return d["fom"], int(round(p.T / p.DT)), d["c_tr"], d["c_te"], d["X_tr"], d["X_te"]


def galerkin_rom(fom, X, dim: int) -> ReducedSineGordon:
    """The Galerkin ROM of dimension ``dim`` (= 2n) on the complex SVD basis of the FOM states ``X`` (any shape
    ``(..., fom.dim)``, e.g. trajectories (B, K + 1, fom.dim))."""
    return ReducedSineGordon.galerkin(fom, complex_svd_basis(X.reshape(-1, fom.dim), n=dim // 2, layout="rows").V)


def record_failure(row: dict, exc: BaseException, what: str = "fails") -> str:
    """A failed fit or rollout is a result: ``row["failure"]`` (:func:`~sympredict_paper.sine_gordon.failure_text`);
    returns the line printed for it, ``what: `` and the first 160 characters."""
    row["failure"] = failure_text(exc)
    return f"{what}: {row['failure'][:160]}"
