"""MPI check of the pool code and the sharded greedy: run under pyMOR's MPI event loop, exits non-zero on any mismatch.

    mpiexec -n 2 .venv/bin/python -m pymor.tools.mpi tests/mpi/run_sharded_greedy.py
    mpiexec -disable-auto-cleanup -n 2 .venv/bin/python -m pymor.tools.mpi tests/mpi/run_sharded_greedy.py --kill 1
    mpiexec -disable-auto-cleanup -n 2 .venv/bin/python -m pymor.tools.mpi tests/mpi/run_sharded_greedy.py --freeze 1

Default mode: pool data generation equals the serial data (bit for bit); the
sharded greedy selects what the serial greedy selects (f- and P-greedy, with
validation, multi-output value functionals, exact ties across shards);
``fit`` with ``trainer=ShardedGreedy(pool)`` equals ``fit``; a basis over one rank's memory limit
trains across the ranks; a worker's exception comes back naming its rank.
Prints ``MPI CHECK OK`` at the end.

``--kill R``: SIGKILL rank R at greedy step 5; the watchdog must end the job
with exit code 75 and a message naming rank R (checked by ``launch.py``).
``--exit R``: rank R calls ``os._exit(0)`` at step 5 (the silent case).
``--freeze R``: SIGSTOP rank R at step 5 (a hung worker); the heartbeat
timeout (3 s) must end the job the same way.

Only rank 0 runs this file (the other ranks run pyMOR's event loop), so
every function sent to the workers lives in the package (``sympredict.parallel``,
``sympredict.interpolation.greedy.sharded``).
"""

import os
import signal
import sys

import numpy as np

from pymor.parallel.default import new_parallel_pool

from sympredict import SymplecticKernelPredictor
from sympredict import parallel as par
from sympredict.interpolation.greedy import ShardedGreedy, greedy_interpolation, sharded_greedy
from sympredict.interpolation.greedy import sharded as sharded_module
from sympredict.data import mixed_variables
from sympredict_paper import wave
from sympredict.interpolation.functionals import HBFunctionals, ValueFunctionals
from sympredict.kernels import IMQ, ProductKernel
from sympredict.systems.pendulum import Pendulum, flow_map_data, random_flow_map_data

failures = []


def check(ok, what):
    print(("ok   " if ok else "FAIL ") + what, flush=True)
    if not ok:
        failures.append(what)


def same_greedy(r_serial, r_sharded, what):
    same = np.array_equal(r_serial.selected, r_sharded.selected)
    rel = float(np.abs(r_serial.coef - r_sharded.coef).max() / np.abs(r_serial.coef).max())
    hist = np.allclose(r_serial.history.train_max_residual, r_sharded.history.train_max_residual, rtol=1e-10, atol=0)
    check(
        same and rel <= 1e-10 and hist and r_serial.history.stop_reason == r_sharded.history.stop_reason,
        f"{what}: {len(r_sharded.selected)} centres, same selection {same}, coef rel. diff {rel:.1e}, "
        f"stop {r_sharded.history.stop_reason}",
    )


pool = new_parallel_pool()
par.set_blas_threads(pool, 1)
info = par.worker_info(pool)
print(f"pool of {len(pool)} workers: {info}", flush=True)
if len(pool) < 2:
    print("run this under mpiexec -n 2 (or more)", flush=True)
    sys.exit(2)

system = Pendulum()
data = flow_map_data(system, n_grid=14)
val = random_flow_map_data(system, 300, seed=1, mu_values=(0.7, 0.75, 0.8), dt_values=(0.04, 0.05, 0.06))
kernel = ProductKernel(IMQ(0.2), IMQ(1.5), IMQ(3.0))
xi, y = mixed_variables(data.x0, data.x1, data.dt)
vxi, vy = mixed_variables(val.x0, val.x1, val.dt)
F = HBFunctionals(kernel, xi, data.mu, data.dt)
VF = HBFunctionals(kernel, vxi, val.mu, val.dt)

mode = sys.argv[1] if len(sys.argv) > 1 else "--compare"
if mode in ("--kill", "--freeze", "--exit"):
    rank = int(sys.argv[2])
    pid = next(p for r, _, p in info if r == rank)
    sig = {"--kill": signal.SIGKILL, "--freeze": signal.SIGSTOP}.get(mode)

    def strike(m, e_train):
        if m == 5 and sig is not None:
            print(f"sending {sig.name} to rank {rank} (pid {pid}) at step {m}", flush=True)
            os.kill(pid, sig)
        elif m == 5:  # the worker itself calls os._exit(0) inside a pool call
            print(f"rank {rank} calls os._exit(0) at step {m}", flush=True)
            pool.apply_only(os._exit, rank, 0)

    sharded_greedy(
        F, y.reshape(-1), max_centers=400, validation=(VF, vy.reshape(-1)), pool=pool, timeout=3.0, callback=strike
    )
    print("UNEXPECTED: the run survived a dead worker", flush=True)
    sys.exit(1)

# ---- data generation over the pool equals the serial data, bit for bit
d2 = flow_map_data(system, n_grid=14, pool=pool)
check(
    np.array_equal(d2.x0, data.x0)
    and np.array_equal(d2.x1, data.x1)
    and np.array_equal(d2.mu, data.mu)
    and np.array_equal(d2.dt, data.dt),
    f"pendulum grid data on the pool ({len(data)} samples)",
)
v2 = random_flow_map_data(
    system, 300, seed=1, mu_values=(0.7, 0.75, 0.8), dt_values=(0.04, 0.05, 0.06), pool=pool, chunk_size=37
)
check(np.array_equal(v2.x1, val.x1) and np.array_equal(v2.x0, val.x0), "pendulum random data on the pool")
preset = wave.PRESETS["smoke"]
fom, rom, energy, _ = wave.build_rom(preset)
fom2, rom2, energy2, _ = wave.build_rom(preset, pool=pool)
check(np.array_equal(rom.V, rom2.V) and energy == energy2, "wave snapshots and basis on the pool")
wd = wave.reduced_flow_map_data(rom, (0.2, 0.25, 0.3), 0.1, 50, energy, seed=3)
wd2 = wave.reduced_flow_map_data(rom, (0.2, 0.25, 0.3), 0.1, 50, energy, seed=3, pool=pool)
check(np.array_equal(wd.x1, wd2.x1) and np.array_equal(wd.x0, wd2.x0), "reduced wave data on the pool")

# ---- sharded greedy equals the serial greedy
serial = greedy_interpolation(F, y.reshape(-1), max_centers=300, validation=(VF, vy.reshape(-1)))
sharded = sharded_greedy(F, y.reshape(-1), max_centers=300, validation=(VF, vy.reshape(-1)), pool=pool)
same_greedy(serial, sharded, "f-greedy, 2 ranks, with validation")
check(
    np.allclose(serial.history.val_max_residual, sharded.history.val_max_residual, rtol=1e-10, atol=0),
    "validation residual curve",
)
sharded3 = sharded_greedy(F, y.reshape(-1), max_centers=300, pool=pool, n_shards=5)
same_greedy(greedy_interpolation(F, y.reshape(-1), max_centers=300), sharded3, "f-greedy, 5 shards on 2 ranks")
same_greedy(
    greedy_interpolation(F, y.reshape(-1), max_centers=120, criterion="p"),
    sharded_greedy(F, y.reshape(-1), max_centers=120, criterion="p", pool=pool),
    "P-greedy",
)
VAL = ValueFunctionals(kernel, data.x0, data.mu, data.dt)
inc = data.x1 - data.x0
same_greedy(
    greedy_interpolation(VAL, inc, max_centers=150),
    sharded_greedy(VAL, inc, max_centers=150, pool=pool),
    "value functionals, 2 outputs",
)
# exact ties: the same maximal |y| at the start of shard 0 and in shard 1 -> serial argmax takes the lowest index
yt = np.full(F.n_functionals, 0.5)
yt[[7, F.n_functionals // 2 + 3, F.n_functionals - 1]] = 2.0
same_greedy(
    greedy_interpolation(F, yt, max_centers=60),
    sharded_greedy(F, yt, max_centers=60, pool=pool),
    "exact ties across shards",
)
check(sharded_greedy(F, yt, max_centers=1, pool=pool).selected[0] == 7, "tie at step 1 goes to the lowest index")

# ---- fit with the sharded strategy equals fit
model_a = SymplecticKernelPredictor(IMQ(0.2), IMQ(1.5), IMQ(3.0), max_centers=200)
model_b = SymplecticKernelPredictor(IMQ(0.2), IMQ(1.5), IMQ(3.0), max_centers=200, trainer=ShardedGreedy(pool))
model_a.fit(data.x0, data.x1, mu=data.mu, dt=data.dt, validation=val)
model_b.fit(data.x0, data.x1, mu=data.mu, dt=data.dt, validation=val)
sa, sb = model_a.surrogate_, model_b.surrogate_
check(
    np.array_equal(sa.centers_xi, sb.centers_xi)
    and np.array_equal(sa.components, sb.components)
    and np.allclose(sa.coef, sb.coef, rtol=0, atol=1e-10 * np.abs(sa.coef).max())
    and np.allclose(
        model_a.step(val.x0[:20], mu=val.mu[:20], dt=val.dt[:20]),
        model_b.step(val.x0[:20], mu=val.mu[:20], dt=val.dt[:20]),
        rtol=0,
        atol=1e-12,
    ),
    "fit with trainer=ShardedGreedy(pool) equals fit",
)

# ---- a basis over one rank's memory limit trains across two ranks
m_max = 300
need = 8 * m_max * F.n_functionals
limit = 0.6 * need
try:
    greedy_interpolation(F, y.reshape(-1), max_centers=m_max, memory_limit=limit)
    check(False, "serial greedy should refuse the low memory limit")
except ValueError as err:
    check(
        "memory limit" in str(err), f"serial greedy refuses {limit / 2**20:.2f} MiB for a {need / 2**20:.2f} MiB basis"
    )
low = sharded_greedy(F, y.reshape(-1), max_centers=m_max, pool=pool, memory_limit_per_rank=limit)
same_greedy(
    greedy_interpolation(F, y.reshape(-1), max_centers=m_max),
    low,
    f"the same basis sharded over 2 ranks with a {limit / 2**20:.2f} MiB per-rank limit",
)
wb = sharded_module.shard_bounds(3, 2, align=1)  # 3 shards on 2 ranks: one rank holds two of them and is over the limit
big = int(np.argmax(np.diff(wb)))
try:
    sharded_greedy(F, y.reshape(-1), max_centers=m_max, pool=pool, n_shards=3, memory_limit_per_rank=0.45 * need)
    check(False, f"rank {big} should be over its limit")
except ValueError as err:
    check(
        f"worker rank {big} " in str(err) and "per-rank memory limit" in str(err), f"over the limit: {str(err)[:90]}..."
    )

# ---- an exception on a worker comes back naming its rank (no hang)
try:
    par.checked(pool.apply_only(sharded_module._w_winner, 1, 0, 0, 0, shards=None))
    check(False, "the worker should have raised")
except par.WorkerError as err:
    check(err.rank == 1 and "AttributeError" in str(err), f"worker exception re-raised: {str(err).splitlines()[0]}")
# and the pool still works afterwards
check(len(par.worker_info(pool)) == len(pool), "pool usable after a worker exception")

if failures:
    print(f"MPI CHECK FAILED: {len(failures)} failure(s)", flush=True)
    sys.exit(1)
print("MPI CHECK OK", flush=True)
