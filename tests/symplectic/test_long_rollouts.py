"""Long rollouts: chunks, kept states (stride), progress, memory checked first, Ctrl-C; the 'auto' backend's rule."""

import copy
import logging
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from sympredict import DirectKernelPredictor, SymplecticKernelPredictor
from sympredict import _numba
from sympredict.symplectic import _compiled_newton
from sympredict.symplectic import newton
from sympredict.exceptions import NewtonConvergenceError, RolloutMemoryError
from sympredict.kernels import IMQ
from sympredict.symplectic.newton import rollout_in_chunks
from sympredict.flowmap.splitting import SplitKernelPredictor
from sympredict.symplectic.solvers import NewtonSolver
from sympredict.kernels.transforms import Scaled


def _data(d, n=400):
    idx = np.random.default_rng(0).choice(len(d), n, replace=False)
    return d.x0[idx], d.x1[idx], d.mu[idx], d.dt[idx]


# ------------------------------------------------------------------ the chunk driver on a toy map
def _toy_run(calls):
    """A 'rollout' of x -> x + 1 that records the chunk lengths it was asked for."""

    def run(state, k):
        calls.append(k)
        return state[:, None, :] + np.arange(k + 1)[None, :, None]

    return run


@pytest.mark.parametrize("n_steps,stride", [(0, 1), (1, 1), (7, 1), (1000, 1), (1000, 7), (1000, 1000), (999, 1000)])
def test_chunks_keep_exactly_the_strided_states(monkeypatch, n_steps, stride):
    monkeypatch.setattr(newton, "FIRST_CHUNK_STEPS", 3)  # many chunks of varying length
    calls, seen = [], []
    x = np.array([[0.0, 10.0], [5.0, -1.0]])
    out = rollout_in_chunks(_toy_run(calls), x, n_steps, stride=stride, progress=lambda d, t: seen.append((d, t)))
    full = x[:, None, :] + np.arange(n_steps + 1)[None, :, None]
    np.testing.assert_array_equal(out, full[:, ::stride])  # integers: exact
    assert sum(calls) == n_steps and all(k >= 1 for k in calls)
    assert [d for d, _ in seen] == list(np.cumsum(calls)) and all(t == n_steps for _, t in seen)
    if n_steps >= 100:
        assert len(calls) > 1 and all(b <= newton.CHUNK_GROWTH * a for a, b in zip(calls, calls[1:]))  # bounded growth


def test_chunks_are_sized_by_time(monkeypatch):
    monkeypatch.setattr(newton, "CHUNK_SECONDS", 0.05)
    calls = []

    def slow(state, k):  # 10 ms a step: chunks of about 5 steps
        calls.append(k)
        time.sleep(0.01 * k)
        return state[:, None, :] + np.arange(k + 1)[None, :, None]

    rollout_in_chunks(slow, np.zeros((1, 2)), 40)
    assert calls[0] == 40 or max(calls[1:]) <= 10, calls


def test_a_failure_names_its_step_from_the_rollouts_start(monkeypatch):
    monkeypatch.setattr(newton, "FIRST_CHUNK_STEPS", 4)

    def failing(state, k):  # fails at global step 10, reported by the chunk as its own step index
        start = int(state[0, 0])
        if start + k > 10:
            raise NewtonConvergenceError([0], [1.0], step=10 - start)
        return state[:, None, :] + np.arange(k + 1)[None, :, None]

    with pytest.raises(NewtonConvergenceError, match="at macro step 10 ") as info:
        rollout_in_chunks(failing, np.zeros((1, 2)), 100)
    assert info.value.step == 10


def test_memory_is_checked_before_any_step(monkeypatch):
    monkeypatch.setattr(newton, "available_memory", lambda: 10**6)
    calls = []
    with pytest.raises(RolloutMemoryError, match=r"stride=k.*--stride") as info:
        rollout_in_chunks(_toy_run(calls), np.zeros((10, 4)), 10**6)
    assert calls == [] and info.value.needed == 10 * (10**6 + 1) * 4 * 8 and isinstance(info.value, MemoryError)
    # the same rollout keeping every 10,000th state fits
    out = rollout_in_chunks(_toy_run(calls), np.zeros((10, 4)), 10**6, stride=10**4)
    assert out.shape == (10, 101, 4) and out[0, -1, 0] == 10**6


# ------------------------------------------------------------------ every model class, both backends
def _fitted(name, pendulum, d, backend):
    kernels = (IMQ(0.3), IMQ(1.5), IMQ(3.0))
    x0, x1, mu, dt = _data(d)
    model = {
        "symplectic_euler": lambda: SymplecticKernelPredictor(
            Scaled(kernels[0], factors=[1.3]), *kernels[1:], max_centers=40, solver=NewtonSolver(backend=backend)
        ),
        "midpoint": lambda: SymplecticKernelPredictor(
            *kernels, max_centers=40, update="midpoint", solver=NewtonSolver(backend=backend)
        ),
        "direct": lambda: DirectKernelPredictor(*kernels, max_centers=40),
        "split": lambda: SplitKernelPredictor(
            SymplecticKernelPredictor(*kernels, max_centers=40, solver=NewtonSolver(backend=backend)),
            pendulum.quadratic_part(),
        ),
    }[name]()
    return model.fit(x0, x1, mu=mu, dt=dt)


@pytest.mark.parametrize(
    "name,backend",
    [(name, backend) for name in ("symplectic_euler", "midpoint", "split") for backend in ("numpy", "numba")]
    + [("direct", "numpy")],
)
def test_chunked_and_strided_rollouts_equal_the_one_call_rollout(
    small_pendulum_data, pendulum, monkeypatch, name, backend
):
    """Each step depends only on the state before it: chunks change nothing, bit for bit (same code, same arrays)."""
    model = _fitted(name, pendulum, small_pendulum_data, backend)
    x = np.array([[0.3, 0.1], [0.8, -0.2], [0.1, 0.0]])
    mu, dt = np.array([0.75, 0.78, 0.72]), np.array([0.05, 0.05, 0.048])
    monkeypatch.setattr(newton, "FIRST_CHUNK_STEPS", 10**9)
    whole = model.rollout(x, 60, mu=mu, dt=dt)
    single = model.rollout(x[1], 60, mu=mu[1], dt=dt[1])  # NumPy's batched sums depend on the batch size
    monkeypatch.setattr(newton, "FIRST_CHUNK_STEPS", 4)
    monkeypatch.setattr(newton, "CHUNK_SECONDS", 0.0)  # every chunk as short as the growth rule allows
    np.testing.assert_array_equal(model.rollout(x, 60, mu=mu, dt=dt), whole)
    np.testing.assert_array_equal(model.rollout(x, 60, mu=mu, dt=dt, stride=7), whole[:, ::7])
    np.testing.assert_array_equal(model.rollout(x[1], 60, mu=mu[1], dt=dt[1], stride=60), single[::60])
    with pytest.raises(ValueError, match="stride"):
        model.rollout(x, 5, mu=mu, dt=dt, stride=0)


def test_warm_started_chunks_solve_the_same_steps(small_pendulum_model, monkeypatch):
    """A warm start restarts from the explicit guess at each chunk: the same equation, within the stopping rule."""
    from _tolerances import rollout_bound  # tests/

    warm = copy.copy(small_pendulum_model).set_params(solver__warm_start=True, solver__backend="numba")
    x, mu, dt = np.array([[0.3, 0.1], [0.8, -0.2]]), np.array([0.75, 0.78]), np.array([0.05, 0.05])
    monkeypatch.setattr(newton, "FIRST_CHUNK_STEPS", 10**9)
    whole = warm.rollout(x, 40, mu=mu, dt=dt)
    monkeypatch.setattr(newton, "FIRST_CHUNK_STEPS", 3)
    monkeypatch.setattr(newton, "CHUNK_SECONDS", 0.0)
    sur = warm.surrogate_
    np.testing.assert_allclose(
        warm.rollout(x, 40, mu=mu, dt=dt),
        whole,
        rtol=0,
        atol=rollout_bound(sur, whole, sur.weights(mu[:, None], dt), dt),
    )


# ------------------------------------------------------------------ backend='auto'
def test_auto_picks_numpy_for_small_work_and_compiled_for_large(small_pendulum_model, monkeypatch, caplog):
    from sympredict.estimators import predictor

    model = copy.copy(small_pendulum_model).set_params(solver__backend="auto")
    m, dim = model.n_centers_, model.dim_
    monkeypatch.setattr(_compiled_newton, "rollout_loaded", lambda: False)  # a fresh process
    assert predictor.numpy_seconds(20, 100, m, dim) < predictor.AUTO_NUMPY_SECONDS
    with caplog.at_level(logging.DEBUG, logger="sympredict.estimators.predictor"):
        assert model.backend_for(20, 100) == "numpy"
    assert "backend='auto': NumPy" in caplog.text
    assert model.backend_for(1000, 1000) == "numba"
    # once this process has the compiled rollout loaded, it costs nothing more: 'auto' uses it
    monkeypatch.setattr(_compiled_newton, "rollout_loaded", lambda: True)
    assert model.backend_for(1, 1) == "numba"
    # the named backends decide alone; NumPy-only settings keep 'auto' on NumPy
    assert copy.copy(model).set_params(solver__backend="numpy").backend_for(10**6, 10**6) == "numpy"
    assert copy.copy(model).set_params(solver__backend="numba").backend_for(1, 1) == "numba"
    monkeypatch.setattr(_numba, "HAVE_NUMBA", False)
    assert model.backend_for(10**6, 10**6) == "numpy"


def test_auto_runs_what_it_reports(small_pendulum_model, monkeypatch):
    model = copy.copy(small_pendulum_model).set_params(solver__backend="auto")
    ran = []
    monkeypatch.setattr(_compiled_newton, "rollout_loaded", lambda: False)
    import sympredict.estimators.fitted as fitted  # the fitted flow map runs the rollouts
    import sympredict.symplectic.solvers as solvers

    real = fitted.implicit_rollout
    monkeypatch.setattr(fitted, "implicit_rollout", lambda *a, **k: ran.append(k["backend"]) or real(*a, **k))
    model.rollout(np.array([[0.3, 0.1]]), 5, mu=0.75, dt=0.05)
    assert set(ran) == {"numpy"} and model.backend_for(1, 5) == "numpy"
    ran.clear()
    monkeypatch.setattr(solvers, "AUTO_NUMPY_SECONDS", 0.0)  # the solver owns the auto rule
    model.rollout(np.array([[0.3, 0.1]]), 5, mu=0.75, dt=0.05)
    assert set(ran) == {"numba"} and model.backend_for(1, 5) == "numba"


# ------------------------------------------------------------------ the command line: Ctrl-C, memory
@pytest.fixture(scope="module")
def model_file(tmp_path_factory, small_pendulum_data):
    path = tmp_path_factory.mktemp("long") / "m.h5"
    x0, x1, mu, dt = _data(small_pendulum_data)
    SymplecticKernelPredictor(IMQ(0.3), IMQ(1.5), IMQ(3.0), max_centers=40).fit(x0, x1, mu=mu, dt=dt).save(path)
    return path


def _predict(model_file, steps, backend, *extra):
    return [
        sys.executable,
        "-m",
        "sympredict.cli",
        "predict",
        str(model_file),
        "--x0",
        "0.3,0.1",
        "--mu",
        "0.75",
        "--dt",
        "0.05",
        "--steps",
        str(steps),
        "--backend",
        backend,
        *extra,
    ]


@pytest.mark.parametrize("backend", ["numpy", "numba"])
def test_a_billion_step_predict_stops_on_ctrl_c(model_file, backend):
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1"}
    proc = subprocess.Popen(
        _predict(model_file, 10**9, backend),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    try:
        # wait until it is stepping (imports, load and, for numba, the compiled code are behind it)
        deadline = time.monotonic() + 240
        while time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.5)
            if _cpu_seconds(proc.pid) > (8.0 if backend == "numba" else 3.0):
                break
        time.sleep(1.0)
        assert proc.poll() is None, proc.communicate()
        sent = time.monotonic()
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=30)
        waited = time.monotonic() - sent
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130 and "interrupted" in err, err
    assert waited < 3.0, waited  # a chunk is ~0.2 s; interpreter shutdown on a loaded 2-core machine adds the rest


def _cpu_seconds(pid: int) -> float:
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return 0.0


def test_predict_refuses_an_output_that_cannot_fit_before_stepping(model_file, tmp_path):
    proc = subprocess.run(
        _predict(model_file, 10**11, "numpy", "--out", str(tmp_path / "t.csv")),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 1 and "--stride" in proc.stderr and "Traceback" not in proc.stderr, proc.stderr
    assert not (tmp_path / "t.csv").exists()
    # printing the final state keeps two states: a long run's memory does not grow with its steps
    proc = subprocess.run(_predict(model_file, 2000, "numpy"), capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and proc.stdout.startswith("instance 0: x(2000 steps) = "), proc.stderr
    proc = subprocess.run(
        _predict(model_file, 20, "numpy", "--out", str(tmp_path / "s.csv"), "--stride", "5"),
        capture_output=True,
        text=True,
        timeout=120,
    )
    rows = np.loadtxt(tmp_path / "s.csv", delimiter=",", skiprows=1)
    # the time column: every 5th step of dt = 0.05
    assert proc.returncode == 0 and rows[:, 1] == pytest.approx([0, 0.25, 0.5, 0.75, 1.0], rel=1e-12), proc.stderr


def test_predict_on_a_direct_model_with_check_is_refused_in_one_line(small_pendulum_data, tmp_path):
    x0, x1, mu, dt = _data(small_pendulum_data)
    path = tmp_path / "direct.h5"
    DirectKernelPredictor(IMQ(0.3), IMQ(1.5), IMQ(3.0), max_centers=20).fit(x0, x1, mu=mu, dt=dt).save(path)
    ok = subprocess.run(_predict(path, 5, "numba"), capture_output=True, text=True, timeout=120)
    assert ok.returncode == 0 and ok.stdout.startswith("instance 0: x(5 steps) = "), (
        ok.stderr
    )  # no Newton solver to set
    proc = subprocess.run(_predict(path, 5, "auto", "--check"), capture_output=True, text=True, timeout=120)
    assert proc.returncode == 1 and "--check" in proc.stderr and "Traceback" not in proc.stderr, proc.stderr
