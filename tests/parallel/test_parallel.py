"""Pool code on pyMOR's dummy pool: data generation over pools, the sharded greedy store (several shards
on one worker), worker failures; plus the two-rank MPI checks of tests/mpi/ when mpi4py and mpiexec are installed."""

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest
from pymor.parallel.dummy import dummy_pool

from sympredict import SymplecticKernelPredictor
from sympredict.interpolation.greedy import ShardedGreedy, greedy_interpolation, sharded_greedy
from sympredict.interpolation.greedy import sharded as sharded_module
from sympredict.parallel import WorkerError, checked, guarded, pool_flow, pool_map_instances
from sympredict.data import mixed_variables
from sympredict_paper import wave
from sympredict.interpolation.functionals import HBFunctionals, ValueFunctionals
from sympredict.kernels import IMQ, ProductKernel
from sympredict.estimators.predictor import DirectKernelPredictor
from sympredict.systems.pendulum import flow_map_data, random_flow_map_data

_spec = importlib.util.spec_from_file_location(
    "sympredict_tests_mpi_launch", Path(__file__).resolve().parents[1] / "mpi" / "launch.py"
)
launch = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(launch)

KERNEL = ProductKernel(IMQ(0.2), IMQ(1.5), IMQ(3.0))


@pytest.fixture(scope="module")
def problem(pendulum):
    data = flow_map_data(pendulum, n_grid=12)
    val = random_flow_map_data(pendulum, 150, seed=1, mu_values=(0.7, 0.75, 0.8), dt_values=(0.04, 0.05, 0.06))
    xi, y = mixed_variables(data.x0, data.x1, data.dt)
    vxi, vy = mixed_variables(val.x0, val.x1, val.dt)
    return {
        "data": data,
        "val": val,
        "y": y.reshape(-1),
        "vy": vy.reshape(-1),
        "F": HBFunctionals(KERNEL, xi, data.mu, data.dt),
        "VF": HBFunctionals(KERNEL, vxi, val.mu, val.dt),
    }


def assert_same(serial, sharded, exact=True):
    """The serial greedy's selection and stop reason; coefficients and curves bit for bit with aligned shards
    (``exact``), else to round-off (shards too small to align: BLAS sums in another order)."""
    np.testing.assert_array_equal(sharded.selected, serial.selected)
    assert sharded.history.stop_reason == serial.history.stop_reason
    pairs = [
        (sharded.coef, serial.coef),
        (sharded.newton_coef, serial.newton_coef),
        (sharded.chol, serial.chol),
        (sharded.history.train_max_residual, serial.history.train_max_residual),
        (sharded.history.val_max_residual, serial.history.val_max_residual),
        (sharded.coef_prefix(len(serial.selected) // 2), serial.coef_prefix(len(serial.selected) // 2)),
    ]
    for a, b in pairs:
        if b is None:
            assert a is None
        elif exact:
            np.testing.assert_array_equal(a, b)
        else:
            np.testing.assert_allclose(a, b, rtol=1e-10, atol=1e-13 * np.abs(b).max())


# ------------------------------------------------------------------ data generation
def test_pendulum_data_on_pool_equals_serial(pendulum):
    serial = flow_map_data(pendulum, n_grid=12, p_nonpositive=True)
    for chunk in (None, 50, 333):
        pooled = flow_map_data(pendulum, n_grid=12, p_nonpositive=True, pool=dummy_pool, chunk_size=chunk)
        for name in ("x0", "x1", "mu", "dt"):
            np.testing.assert_array_equal(getattr(pooled, name), getattr(serial, name))


def test_random_pendulum_data_on_pool_equals_serial(pendulum):
    serial = random_flow_map_data(pendulum, 400, seed=7)
    pooled = random_flow_map_data(pendulum, 400, seed=7, chunk_size=61)
    np.testing.assert_array_equal(pooled.x0, serial.x0)
    np.testing.assert_array_equal(pooled.x1, serial.x1)
    np.testing.assert_array_equal(pooled.dt, serial.dt)


def test_wave_snapshots_basis_and_reduced_data_on_pool_equal_serial():
    preset = wave.PRESETS["smoke"]
    fom, rom, energy, info = wave.build_rom(preset)
    fom2, rom2, energy2, info2 = wave.build_rom(preset, pool=dummy_pool)
    np.testing.assert_array_equal(rom2.V, rom.V)
    assert energy2 == energy and info2["singular_values"] == info["singular_values"]
    x0 = fom.low_frequency_states(5, 2, 0.09, energy, seed=4)
    split = pool_map_instances(fom, "trajectory", x0, 0.09, 0.02, 10, chunk_size=2)
    np.testing.assert_array_equal(split, fom.trajectory(x0, 0.09, 0.02, 10))
    serial = wave.reduced_flow_map_data(rom, (0.2, 0.3), 0.05, 40, energy, seed=2)
    pooled = wave.reduced_flow_map_data(rom, (0.2, 0.3), 0.05, 40, energy, seed=2, chunk_size=15)
    np.testing.assert_array_equal(pooled.x0, serial.x0)
    np.testing.assert_array_equal(pooled.x1, serial.x1)
    np.testing.assert_array_equal(pooled.mu, serial.mu)


def test_pool_flow_passes_extra_arguments(pendulum, rng):
    x0 = rng.uniform(-1, 1, (30, 2))
    np.testing.assert_array_equal(
        pool_flow(pendulum, x0, 0.75, 0.05, 5e-4, chunk_size=7), pendulum.flow(x0, 0.75, 0.05, 5e-4)
    )


# ------------------------------------------------------------------ sharded greedy
@pytest.mark.parametrize("n_shards", [1, 2, 3])
def test_sharded_f_greedy_equals_serial_with_validation(problem, n_shards):
    p = problem
    serial = greedy_interpolation(p["F"], p["y"], max_centers=150, validation=(p["VF"], p["vy"]))
    sharded = sharded_greedy(p["F"], p["y"], max_centers=150, validation=(p["VF"], p["vy"]), n_shards=n_shards)
    assert_same(serial, sharded)


def test_sharded_greedy_unaligned_shards_still_agree(problem, monkeypatch):
    """Shards off the BLAS-friendly boundaries: the Newton basis differs in the last bits only."""
    p = problem
    monkeypatch.setattr(sharded_module, "SHARD_ALIGN", 1)
    monkeypatch.setattr(sharded_module.shard_bounds, "__defaults__", (1, 1))
    serial = greedy_interpolation(p["F"], p["y"], max_centers=60)
    sharded = sharded_greedy(p["F"], p["y"], max_centers=60, n_shards=7)
    np.testing.assert_array_equal(sharded.selected, serial.selected)
    np.testing.assert_allclose(sharded.coef, serial.coef, rtol=0, atol=1e-8 * np.abs(serial.coef).max())


def test_sharded_p_greedy_and_value_functionals_equal_serial(problem):
    p = problem
    assert_same(
        greedy_interpolation(p["F"], p["y"], max_centers=80, criterion="p"),
        sharded_greedy(p["F"], p["y"], max_centers=80, criterion="p", n_shards=2),
    )
    d = p["data"]
    vf = ValueFunctionals(KERNEL, d.x0, d.mu, d.dt)
    assert_same(
        greedy_interpolation(vf, d.x1 - d.x0, max_centers=80),
        sharded_greedy(vf, d.x1 - d.x0, max_centers=80, n_shards=3),
    )


def test_sharded_greedy_stop_reasons_equal_serial(problem):
    p = problem
    kw = dict(max_centers=400, tol=1e-3)
    assert_same(greedy_interpolation(p["F"], p["y"], **kw), sharded_greedy(p["F"], p["y"], n_shards=2, **kw))
    # few points: every candidate's power function reaches round-off -> 'power', or all selected -> 'exhausted'
    sub = HBFunctionals(KERNEL, p["F"].points[:40:3], p["F"].mu[:40:3], p["F"].dt[:40:3])
    ys = p["y"].reshape(-1, 2)[:40:3].reshape(-1)
    for power_tol in (1e-12, 1e-3):
        serial = greedy_interpolation(sub, ys, max_centers=100, power_tol=power_tol)
        assert_same(serial, sharded_greedy(sub, ys, max_centers=100, power_tol=power_tol, n_shards=2), exact=False)
    assert {greedy_interpolation(sub, ys, max_centers=100, power_tol=t).history.stop_reason for t in (1e-12, 1e-3)} <= {
        "exhausted",
        "power",
        "tol",
    }


def test_ties_go_to_the_lowest_global_index(problem):
    p = problem
    n = p["F"].n_functionals
    y = np.full(n, 0.25)
    y[[n // 2 + 5, 11, n - 1]] = 3.0  # the same maximum in shard 1, shard 0 and the last shard
    for n_shards in (2, 3):
        first = sharded_greedy(p["F"], y, max_centers=1, n_shards=n_shards)
        assert first.selected[0] == 11 == greedy_interpolation(p["F"], y, max_centers=1).selected[0]
        assert_same(
            greedy_interpolation(p["F"], y, max_centers=40),
            sharded_greedy(p["F"], y, max_centers=40, n_shards=n_shards),
        )


@pytest.mark.parametrize("cls", [SymplecticKernelPredictor, DirectKernelPredictor])
def test_sharded_trainer_fit_equals_fit(problem, cls):
    d, v = problem["data"], problem["val"]
    a = cls(IMQ(0.2), IMQ(1.5), IMQ(3.0), max_centers=120).fit(d.x0, d.x1, mu=d.mu, dt=d.dt, validation=v)
    b = cls(IMQ(0.2), IMQ(1.5), IMQ(3.0), max_centers=120, trainer=ShardedGreedy(n_shards=2)).fit(
        d.x0, d.x1, mu=d.mu, dt=d.dt, validation=v
    )
    np.testing.assert_array_equal(b.greedy_result_.selected, a.greedy_result_.selected)
    np.testing.assert_array_equal(b.surrogate_.coef, a.surrogate_.coef)  # aligned shards: bit for bit
    assert b.greedy_result_.stats["n_shards"] == 2 and len(b.greedy_result_.stats["step_call"]) == 120
    np.testing.assert_array_equal(b.surrogate_.centers_mu, a.surrogate_.centers_mu)
    np.testing.assert_allclose(
        b.surrogate_.coef, a.surrogate_.coef, rtol=0, atol=1e-10 * np.abs(a.surrogate_.coef).max()
    )
    np.testing.assert_array_equal(b.history_.val_max_residual, a.history_.val_max_residual)
    assert b.domain_.keys() == a.domain_.keys() and all(np.array_equal(b.domain_[k], a.domain_[k]) for k in a.domain_)
    x, mu, dt = d.x0[::50], d.mu[::50], d.dt[::50]
    np.testing.assert_allclose(b.step(x, mu=mu, dt=dt), a.step(x, mu=mu, dt=dt), rtol=0, atol=1e-12)


def test_per_rank_memory_limit_is_checked_on_the_worker(problem):
    p = problem
    need = 8 * 100 * p["F"].n_functionals
    with pytest.raises(ValueError, match=r"worker rank 0 .*per-rank memory limit.*at least 2"):
        sharded_greedy(p["F"], p["y"], max_centers=100, n_shards=2, memory_limit_per_rank=0.6 * need)
    # the dummy pool survives the failure and the same limit holds a basis that fits
    assert_same(
        greedy_interpolation(p["F"], p["y"], max_centers=50),
        sharded_greedy(p["F"], p["y"], max_centers=50, n_shards=2, memory_limit_per_rank=0.6 * need),
    )


def test_worker_exceptions_come_back_naming_the_rank():
    with pytest.raises(WorkerError, match=r"worker rank 0 on .* raised AttributeError") as info:
        checked(dummy_pool.apply(sharded_module._w_winner, 0, 0, 0, shards=None))
    assert info.value.rank == 0 and "Traceback" in info.value.remote_traceback
    # sys.exit on a worker is an error too (pyMOR's event loop would swallow it and leave the driver waiting)
    with pytest.raises(WorkerError, match="SystemExit"):
        checked(dummy_pool.apply(guarded(sys.exit), 3))


def test_bad_arguments(problem):
    p = problem
    with pytest.raises(ValueError, match="n_shards"):
        sharded_greedy(p["F"], p["y"], max_centers=5, n_shards=0)
    with pytest.raises(ValueError, match="criterion"):
        sharded_greedy(p["F"], p["y"], max_centers=5, criterion="x")
    with pytest.raises(TypeError, match="point-based"):
        sharded_greedy(object(), p["y"], max_centers=5)
    with pytest.raises(ValueError, match="n_shards"):
        model = SymplecticKernelPredictor(
            IMQ(0.2), IMQ(1.5), IMQ(3.0), max_centers=5, trainer=ShardedGreedy(n_shards=0)
        )
        model.fit(p["data"].x0, p["data"].x1, mu=p["data"].mu, dt=p["data"].dt)


def test_shard_bounds_are_balanced_aligned_and_cover():
    for n, k, per in [(229488, 2, 2), (1000, 7, 2), (50, 8, 6), (5, 5, 2)]:
        b = sharded_module.shard_bounds(n, k, per)
        assert b[0] == 0 and b[-1] == n and np.all(np.diff(b) > 0)
        if n >= k * 16:
            assert np.all(b[1:-1] * per % sharded_module.SHARD_ALIGN == 0)
            assert np.diff(b).max() - np.diff(b).min() <= 2 * sharded_module.SHARD_ALIGN


# ------------------------------------------------------------------ two MPI ranks
@pytest.mark.skipif(not launch.have_mpi(), reason="MPI checks need mpi4py and mpiexec: pip install -e '.[mpi]'")
def test_two_mpi_ranks():
    """Sharded vs serial under ``mpiexec -n 2``, and dead (exit, kill) and hung workers end the job naming rank 1."""
    for name, check in launch.CHECKS.items():
        ok, out = check()
        assert ok, f"mpi {name} check failed:\n{out[-4000:]}"
