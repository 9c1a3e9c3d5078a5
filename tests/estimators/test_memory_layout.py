"""Fitted state has one memory layout (C-contiguous, native float64 / int64) whatever produced it.

OpenBLAS takes another kernel path for a Fortran-ordered operand than for a C-ordered
one (and may round differently with alignment on AVX-512), so a model whose fitted
arrays changed layout between ``fit`` and ``load`` predicts differently in the last
bits on some CPUs only.  These checks need no particular CPU: they look at the
layout itself, for every model class that can be saved, after ``fit``, ``load``,
``copy``/``deepcopy`` and for the reductor's ROM.
"""

import copy

import numpy as np
import pytest

from sympredict import DirectKernelPredictor, SymplecticKernelPredictor
from sympredict.container import read_container
from sympredict.io import load_model, save_model
from sympredict.kernels import IMQ
from sympredict.mor import DefaultEstimator, GalerkinSamples, SymplecticKernelReductor
from sympredict.estimators.predictor import MODEL_FORMAT
from sympredict.flowmap.scaling import SymplecticScaling
from sympredict.flowmap.splitting import SplitKernelPredictor
from sympredict.symplectic.solvers import NewtonSolver
from sympredict.kernels.transforms import Scaled


def fitted_arrays(obj, path="model", seen=None, out=None):
    """Every ndarray reachable from ``obj``'s attributes (sympredict objects, dicts, lists), as ``{path: array}``."""
    seen = set() if seen is None else seen
    out = {} if out is None else out
    if isinstance(obj, np.ndarray):  # every path to an array is listed, shared ones too
        out[path] = obj
        return out
    if id(obj) in seen:
        return out
    seen.add(id(obj))
    if isinstance(obj, dict):
        for k, v in obj.items():
            fitted_arrays(v, f"{path}[{k!r}]", seen, out)
    elif isinstance(obj, (list, tuple)):
        for i, v in enumerate(obj):
            fitted_arrays(v, f"{path}[{i}]", seen, out)
    elif hasattr(obj, "__dict__") and type(obj).__module__.startswith("sympredict"):
        for k, v in vars(obj).items():
            fitted_arrays(v, f"{path}.{k}", seen, out)
    return out


def assert_canonical_layout(obj, what):
    arrays = fitted_arrays(obj)
    assert arrays, f"{what}: no fitted arrays found (the walk is broken)"
    bad = {
        p: (a.dtype.str, a.flags.c_contiguous)
        for p, a in arrays.items()
        if not a.flags.c_contiguous
        or (a.dtype.kind == "f" and a.dtype != np.float64)
        or (a.dtype.kind in "iu" and a.dtype.itemsize != 8 and a.size > 1)
        or not a.dtype.isnative
    }
    assert not bad, f"{what}: arrays not C-contiguous native float64/int64: {bad}"


def _data(d, n=400):
    idx = np.random.default_rng(0).choice(len(d), n, replace=False)
    return d.x0[idx], d.x1[idx], d.mu[idx], d.dt[idx]


def _models(pendulum):
    kernels = (IMQ(0.2), IMQ(1.5), IMQ(3.0))
    return {
        "symplectic_euler": SymplecticKernelPredictor(*kernels, max_centers=30),
        "midpoint": SymplecticKernelPredictor(*kernels, max_centers=30, update="midpoint"),
        "state_scaling": SymplecticKernelPredictor(Scaled(kernels[0], factors=[2.0]), *kernels[1:], max_centers=30),
        "direct": DirectKernelPredictor(*kernels, max_centers=30),
        "split": SplitKernelPredictor(SymplecticKernelPredictor(*kernels, max_centers=30), pendulum.quadratic_part()),
    }


@pytest.mark.parametrize("name", ["symplectic_euler", "midpoint", "state_scaling", "direct", "split"])
def test_every_fitted_array_keeps_its_layout_through_save_and_load(small_pendulum_data, pendulum, tmp_path, name):
    x0, x1, mu, dt = _data(small_pendulum_data)
    model = _models(pendulum)[name].fit(x0, x1, mu=mu, dt=dt)
    assert_canonical_layout(model, f"{name} after fit")
    assert_canonical_layout(copy.copy(model), f"{name} after copy")
    assert_canonical_layout(copy.deepcopy(model), f"{name} after deepcopy")
    save_model(model, tmp_path / "m.h5")
    back = load_model(tmp_path / "m.h5")
    assert_canonical_layout(back, f"{name} after load")
    # the stored arrays come back bit for bit: the container writes and reads the same bytes
    _, written = read_container(tmp_path / "m.h5", MODEL_FORMAT)
    save_model(back, tmp_path / "again.h5")
    _, rewritten = read_container(tmp_path / "again.h5", MODEL_FORMAT)
    assert written.keys() == rewritten.keys()
    for key in written:
        np.testing.assert_array_equal(rewritten[key], written[key], err_msg=key)
    # every array the fitted model predicts with has its loaded twin with the same values and layout
    fit_arrays, load_arrays = fitted_arrays(model), fitted_arrays(back)
    unsaved = (".greedy_result", "history_.elapsed", "history.elapsed")  # the greedy's Newton data and timings
    shared = [p for p in fit_arrays if p in load_arrays and not any(u in p for u in unsaved)]
    assert any("coef" in p for p in shared), shared
    for p in shared:
        a, b = fit_arrays[p], load_arrays[p]
        assert (a.dtype, a.shape, a.strides) == (b.dtype, b.shape, b.strides), p
        np.testing.assert_array_equal(b, a, err_msg=p)


def test_warm_started_and_cloned_fits_keep_the_layout(small_pendulum_data):
    from sympredict.base import clone

    x0, x1, mu, dt = _data(small_pendulum_data)
    model = SymplecticKernelPredictor(
        IMQ(0.2), IMQ(1.5), IMQ(3.0), max_centers=30, solver=NewtonSolver(warm_start=True)
    ).fit(x0, x1, mu=mu, dt=dt)
    model.rollout(x0[:3], 3, mu=mu[:3], dt=dt[:3])  # a warm start stores its last solution
    assert_canonical_layout(model, "warm-started model after a rollout")
    # Fortran-ordered and strided input gives the same layout as C-ordered input
    refit = clone(model).fit(np.asfortranarray(x0), np.asfortranarray(x1)[:, :], mu=mu[:, ::-1][:, ::-1], dt=dt[::1])
    assert_canonical_layout(refit, "model fitted on Fortran-ordered data")
    np.testing.assert_array_equal(refit.surrogate_.coef, model.surrogate_.coef)


def test_scaling_and_reduced_model_keep_the_layout(wave):
    fom, train, RB, dt = wave
    red = SymplecticKernelReductor(
        fom, RB, dt, GalerkinSamples(train, n_samples=60, n_validation=1), DefaultEstimator(max_centers=40)
    )
    rom = red.reduce()
    assert_canonical_layout(red, "reductor after reduce")
    assert_canonical_layout(rom, "ROM")
    scaling = SymplecticScaling("diag").fit(np.asfortranarray(np.random.default_rng(0).normal(size=(50, 4))))
    assert_canonical_layout(scaling, "SymplecticScaling")
