"""Hostile model files: every setting checked like a constructor's, shapes and arrays against each other, huge
coefficients and sizes refused, fuzzed files either load into a model that predicts finite states or are refused.

Files are rewritten with a recomputed checksum (:func:`sympredict.container.write_container`), as anyone can."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from _model_files import _param, _rewrite  # tests/

from sympredict import DirectKernelPredictor, ModelFileError, SymplecticKernelPredictor, SympredictError
from sympredict.container import read_container, write_container
from sympredict.exceptions import NonFinitePredictionError, extrapolation_expected
from sympredict.io import load_model
from sympredict.kernels import IMQ
from sympredict.estimators.predictor import MODEL_FORMAT
from sympredict.systems.pendulum import Pendulum
from sympredict.symplectic.solvers import NewtonSolver

DT = 0.1


@pytest.mark.parametrize(
    "name, value, match",
    [
        (
            "solver",
            {"solver": {"max_iter": 10**15, "warm_start": False, "backend": "auto"}},
            "max_iter must be at most",
        ),
        ("solver", {"solver": {"max_iter": 0, "warm_start": False, "backend": "auto"}}, "max_iter"),
        ("solver", {"solver": {"max_iter": 2.5, "warm_start": False, "backend": "auto"}}, "max_iter"),
        ("solver", {"solver": {"max_iter": 50, "warm_start": False, "backend": "cuda"}}, "backend"),
        ("solver", {"solver": {"max_iter": 50, "warm_start": "yes", "backend": "auto"}}, "warm_start"),
        ("solver", {"solver": {"max_iter": 50, "gpu": True}}, "gpu"),
        ("update", "leapfrog", "update"),
        ("trainer", {"trainer": {"name": "ExactGreedy", "params": {"tol": -1.0}}}, "tol"),
        ("newton_max_iter", 50, "unknown setting.*newton_max_iter"),  # a layout-3 file has no flat options
        ("max_centers", -3, "max_centers"),
        (
            "state_kernel",
            {
                "transform": "scaled",
                "params": {"kernel": {"kernel": {"family": "imq", "eps": 0.3}}, "factors": {"list": [1.0, 2.0]}},
            },
            "factors",
        ),
        (
            "state_kernel",
            {"transform": "periodic", "params": {"kernel": None, "coordinates": {"tuple": [5]}, "period": 6.0}},
            "periodic",
        ),
        (
            "state_kernel",
            {
                "transform": "symmetric",
                "params": {"kernel": None, "group": {"list": [{"tuple": [1, 1]}, {"tuple": [1, -1]}]}},
            },
            "symmetry",
        ),
    ],
)
def test_invalid_setting_in_a_file_is_refused_naming_it(coarse_pendulum_model_file, tmp_path, name, value, match):
    path = _rewrite(coarse_pendulum_model_file, tmp_path / "bad.h5", settings=_param(name, value))
    with pytest.raises(ModelFileError, match=match):
        SymplecticKernelPredictor.load(path)
    with pytest.raises(ModelFileError, match=match):
        load_model(path)


@pytest.mark.parametrize(
    "key, value, match",
    [
        ("dim", float("inf"), "dim"),
        ("dim", 2.0, "dim"),
        ("dim", True, "dim"),
        ("n_mu", -1, "n_mu"),
        ("dt_fixed", -0.1, "dt_fixed"),
        ("dt_fixed", "0.1", "dt_fixed"),
        ("layout", 7, "layout"),
        ("stop_reason", 3, "stop_reason"),
    ],
)
def test_invalid_shape_information_in_a_file_is_refused(coarse_pendulum_model_file, tmp_path, key, value, match):
    def edit(s):
        s[key] = value

    path = _rewrite(coarse_pendulum_model_file, tmp_path / "bad.h5", settings=edit)
    with pytest.raises(ModelFileError, match=match):
        SymplecticKernelPredictor.load(path)


@pytest.mark.parametrize(
    "name, value",
    [
        ("train_max_residual", np.zeros(0)),
        ("selected_power", np.zeros(0)),
        ("train_max_residual", np.zeros((31, 1))),
        ("domain_x_min", np.full(2, 10.0)),  # min above max
        ("domain_dt_min", np.array(-1.0)),
    ],
)
def test_inconsistent_arrays_in_a_file_are_refused(coarse_pendulum_model_file, tmp_path, name, value):
    def edit(a):
        a[name] = value

    path = _rewrite(coarse_pendulum_model_file, tmp_path / "bad.h5", arrays=edit)
    with pytest.raises(ModelFileError):
        SymplecticKernelPredictor.load(path)


def test_file_asking_for_endless_newton_never_hangs(coarse_pendulum_model_file, tmp_path):
    """A solver with max_iter = 10**15 loaded would make `sympredict predict` run without end: the file is refused."""
    path = _rewrite(
        coarse_pendulum_model_file,
        tmp_path / "hang.h5",
        settings=_param("solver", {"solver": {"max_iter": 10**15, "warm_start": False, "backend": "auto"}}),
    )
    proc = subprocess.run(
        [sys.executable, "-m", "sympredict.cli", "predict", str(path), "--x0", "0.5,0.1", "--steps", "3"],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "NUMBA_NUM_THREADS": "1"},
    )
    assert proc.returncode == 1 and "max_iter" in proc.stderr and "Traceback" not in proc.stderr


def test_direct_model_with_huge_coefficients_raises_instead_of_inf(coarse_pendulum_data, tmp_path):
    model = DirectKernelPredictor(IMQ(0.3), max_centers=10).fit(coarse_pendulum_data.x0, coarse_pendulum_data.x1, dt=DT)
    model.save(tmp_path / "d.h5")

    def edit(a):
        a["coef"] = np.full_like(a["coef"], 1.7e308)

    path = _rewrite(tmp_path / "d.h5", tmp_path / "huge.h5", arrays=edit)
    loaded = DirectKernelPredictor.load(path)
    with pytest.raises(NonFinitePredictionError, match="non-finite"):
        loaded.step(coarse_pendulum_data.x0[:3])
    with pytest.raises(NonFinitePredictionError):
        loaded.rollout(coarse_pendulum_data.x0[:3], 4)


def test_symplectic_model_with_huge_coefficients_raises(coarse_pendulum_model_file, coarse_pendulum_data, tmp_path):
    def edit(a):
        a["coef"] = np.full_like(a["coef"], 1e308)

    loaded = SymplecticKernelPredictor.load(_rewrite(coarse_pendulum_model_file, tmp_path / "huge.h5", arrays=edit))
    for call in (
        lambda: loaded.step(coarse_pendulum_data.x0[:3]),
        lambda: loaded.rollout(coarse_pendulum_data.x0[:3], 3),
    ):
        with pytest.raises(SympredictError):
            call()


def test_split_model_with_huge_coefficients_raises(coarse_pendulum_data, tmp_path):
    from sympredict.flowmap.splitting import SplitKernelPredictor

    quad = Pendulum().quadratic_part()
    mu = np.full(len(coarse_pendulum_data.x0), 0.75)
    inner = SymplecticKernelPredictor(IMQ(0.5), IMQ(1.0), max_centers=10, solver=NewtonSolver(backend="numpy"))
    split = SplitKernelPredictor(inner, quad).fit(coarse_pendulum_data.x0, coarse_pendulum_data.x1, mu=mu, dt=DT)
    split.predictor_.surrogate_.coef[:] = 1e308
    x = coarse_pendulum_data.x0[:3]
    for call in (lambda: split.step(x, mu=0.75, dt=DT), lambda: split.rollout(x, 3, mu=0.75, dt=DT)):
        with pytest.raises(SympredictError):
            with extrapolation_expected():
                call()


_SETTING_VALUES = [
    None,
    True,
    False,
    0,
    1,
    -1,
    2,
    3,
    10**15,
    2.5,
    -0.5,
    1e308,
    float("inf"),
    float("nan"),
    "",
    "numba",
    "midpoint",
    "x",
    [],
    [0],
    [1.0, 2.0],
    {},
    {"kernel": {}},
    {"tuple": [0]},
    {"list": [1e300]},
]


def _paths(d, prefix=()):
    """Every key path into the nested settings dict."""
    for key, value in d.items():
        yield prefix + (key,)
        if isinstance(value, dict):
            yield from _paths(value, prefix + (key,))


def _mutations(settings, arrays, rng, n):
    """``n`` seeded edits of a model's (settings, arrays): one setting or one array changed each."""
    keys = list(_paths(settings))
    names = sorted(arrays)
    for _ in range(n):
        s, a = json.loads(json.dumps(settings)), {k: v.copy() for k, v in arrays.items()}
        if rng.random() < 0.5:
            where = keys[rng.integers(len(keys))]
            target = s
            for key in where[:-1]:
                target = target[key]
            key = where[-1]
            choice = rng.integers(3)
            if choice == 0:
                target[key] = _SETTING_VALUES[rng.integers(len(_SETTING_VALUES))]
            elif choice == 1:
                target.pop(key)
            else:
                target[key] = {"kernel": {"family": "imq", "eps": float(10 ** rng.uniform(-60, 60))}}
        else:
            name = names[rng.integers(len(names))]
            arr = a[name]
            choice = rng.integers(5)
            if choice == 0 and arr.size:
                flat = arr.reshape(-1)
                if arr.dtype.kind == "f":
                    flat[rng.integers(flat.size)] = [np.inf, np.nan, 1e308, -1e308, 0.0, 1e-308][rng.integers(6)]
                else:
                    flat[rng.integers(flat.size)] = [-1, 0, 1, 2, 10**9][rng.integers(5)]
            elif choice == 1:
                a[name] = arr.reshape(-1)[: max(0, arr.size - 1)]
            elif choice == 2:
                a[name] = arr * 10.0 ** rng.integers(-300, 300) if arr.dtype.kind == "f" else arr + 10**9
            elif choice == 3:
                a[name] = np.concatenate([arr.reshape(-1), arr.reshape(-1)]) if arr.size else np.ones(3)
            else:
                a.pop(name)
        yield s, a


def _fuzz(coarse_pendulum_model_file, tmp_path, n, seed, mu=None):
    settings, arrays = read_container(coarse_pendulum_model_file, MODEL_FORMAT)
    x = np.array([[0.4, 0.1], [-0.3, 0.2]])
    outcomes = {"refused": 0, "predicted": 0, "numerical": 0}
    path = tmp_path / "fuzz.h5"
    for s, a in _mutations(settings, arrays, np.random.default_rng(seed), n):
        try:
            write_container(path, MODEL_FORMAT, s, a)
        except ValueError:
            continue  # not writable as a container at all (e.g. NaN in JSON is fine, but not every object)
        try:
            loaded = load_model(path)
        except ModelFileError:
            outcomes["refused"] += 1
            continue
        try:
            with extrapolation_expected():
                out = loaded.rollout(x, 3, mu=mu if loaded.n_mu_ else None, dt=DT)
        except SympredictError as exc:  # numerical failure said clearly (Newton, non-finite), never silent
            assert not isinstance(exc, ModelFileError)
            outcomes["numerical"] += 1
            continue
        except ValueError as exc:  # the query is invalid for this (valid) model: a step it was not trained for
            assert "fixed step" in str(exc), exc
            outcomes["predicted"] += 1
            continue
        assert np.all(np.isfinite(out))
        outcomes["predicted"] += 1
    assert outcomes["refused"] > n // 4 and outcomes["predicted"] > 0
    return outcomes


@pytest.fixture(scope="module")
def other_model_files(coarse_pendulum_data, tmp_path_factory):
    """A DirectKernelPredictor's and a SplitKernelPredictor's files (the symplectic one is ``model_file``)."""
    from sympredict.flowmap.splitting import SplitKernelPredictor

    folder = tmp_path_factory.mktemp("others")
    DirectKernelPredictor(IMQ(0.3), max_centers=20).fit(coarse_pendulum_data.x0, coarse_pendulum_data.x1, dt=DT).save(
        folder / "direct.h5"
    )
    inner = SymplecticKernelPredictor(IMQ(0.5), IMQ(1.0), max_centers=15, solver=NewtonSolver(backend="numpy"))
    SplitKernelPredictor(inner, Pendulum().quadratic_part()).fit(
        coarse_pendulum_data.x0, coarse_pendulum_data.x1, mu=np.full(len(coarse_pendulum_data.x0), 0.75), dt=DT
    ).save(folder / "split.h5")
    return {"direct": folder / "direct.h5", "split": folder / "split.h5"}


def test_fuzzed_model_files_load_and_predict_or_are_refused(coarse_pendulum_model_file, tmp_path):
    _fuzz(coarse_pendulum_model_file, tmp_path, 300, seed=3)


@pytest.mark.parametrize("kind", ["direct", "split"])
def test_fuzzed_files_of_the_other_models(other_model_files, tmp_path, kind):
    _fuzz(other_model_files[kind], tmp_path, 150, seed=4, mu=0.75)


@pytest.mark.slow
def test_fuzzed_model_files_long(coarse_pendulum_model_file, other_model_files, tmp_path):
    for seed in range(6):
        _fuzz(coarse_pendulum_model_file, tmp_path, 1000, seed=100 + seed)
        for kind, path in other_model_files.items():
            _fuzz(path, tmp_path, 500, seed=200 + seed, mu=0.75)


@pytest.mark.parametrize("key", ["dim", "n_mu"])
def test_a_file_with_huge_sizes_is_refused_before_allocating(coarse_pendulum_model_file, tmp_path, key):
    """A file's dim or n_mu of 10**15 must be refused by its arrays' shapes, not by a failed allocation."""
    path = _rewrite(coarse_pendulum_model_file, tmp_path / "huge.h5", settings=lambda s: s.__setitem__(key, 10**15))
    with pytest.raises(ModelFileError, match=f"{key}=1000000000000000 disagrees with its training box"):
        SymplecticKernelPredictor.load(path)
