"""Kernel ROM vs Galerkin ROM vs pyMOR's DataDrivenReductor on pyMOR's demo wave made parametric in c.

Run:  python sympredict_paper/figures/mor_comparison.py [--T 10] [--repeats 7] [--json out.json]

Setup (issue 12): ``pymordemos.symplectic_wave_equation.discretize_fom`` with the
stiffness block scaled by ``c^2 / 0.1^2``, ``c in [0.08, 0.12]``; 5 training speeds
(uniform), symplectic basis ``psd_complex_svd`` of their FOM trajectories, 2n = 4 (``psd_complex_svd(U, 4)``: 4 modes);
macro step dt = 10 FOM steps; 5 test speeds drawn at random in the range (seeded).
Errors: ``sqrt(sum_k |u_fom(t_k) - V u_rom(t_k)|^2 / sum_k |u_fom(t_k)|^2)`` on
``t_k = k dt`` over ``[0, T]`` and, past the training horizon, over ``(T, 2T]``.
Online times: median over ``repeats`` of ``rom.solve(mu)`` (pyMOR's
Galerkin ROM steps implicit midpoint at the FOM step; the kernel ROM takes
``round(T/dt)`` learned steps), one BLAS thread, all methods in this process.
"""

import argparse
import json
import time

import numpy as np
from threadpoolctl import threadpool_limits

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--T", type=float, default=10.0)
parser.add_argument("--repeats", type=int, default=7)
parser.add_argument("--centers", type=int, default=1000)
parser.add_argument("--samples", type=int, default=400)
parser.add_argument("--json", default=None)
args = parser.parse_args()
threadpool_limits(1)

from pymor.algorithms.ml.vkoga.kernels import GaussianKernel  # noqa: E402
from pymor.algorithms.ml.vkoga.regressor import VKOGARegressor  # noqa: E402
from pymor.algorithms.symplectic import psd_complex_svd  # noqa: E402
from pymor.core.logger import set_log_levels  # noqa: E402
from pymor.operators.block import BlockDiagonalOperator  # noqa: E402
from pymor.operators.constructions import LincombOperator  # noqa: E402
from pymor.parameters.functionals import ExpressionParameterFunctional  # noqa: E402
from pymor.reductors.data_driven import DataDrivenReductor  # noqa: E402
from pymor.reductors.symplectic import QuadraticHamiltonianRBReductor  # noqa: E402
from pymordemos.symplectic_wave_equation import discretize_fom  # noqa: E402

from sympredict.systems.flowmaps import random_parameters  # noqa: E402
from sympredict.mor import DefaultEstimator, GalerkinSamples, ProjectedTrajectories, SymplecticKernelReductor  # noqa: E402
from sympredict.flowmap.scaling import BoxScaling  # noqa: E402
from sympredict_paper.speed import time_median  # noqa: E402

set_log_levels({"pymor": "ERROR", "sympredict": "WARNING"})

fom = discretize_fom(T=args.T)
stiffness, identity = fom.H_op.blocks[0, 0], fom.H_op.blocks[1, 1]
fom = fom.with_(
    H_op=BlockDiagonalOperator(
        [LincombOperator([stiffness], [ExpressionParameterFunctional("c[0]**2 / 0.1**2", {"c": 1})]), identity]
    )
)
nt = fom.time_stepper.nt
dt = 10 * fom.T / nt
K = int(round(fom.T / dt))
train = fom.parameters.space(0.08, 0.12).sample_uniformly(5)
test = random_parameters(fom.parameters, [0.08], [0.12], 5, seed=12)
val = random_parameters(fom.parameters, [0.08], [0.12], 3, seed=34)

t0 = time.perf_counter()
U_train = [fom.solve(mu) for mu in train]
t_fom_train = time.perf_counter() - t0
U = fom.solution_space.empty()
for u in U_train:
    U.append(u)
RB = psd_complex_svd(U, 4)

# long FOM / Galerkin runs: 2T, to measure what each ROM gives past the training horizon
fom2 = fom.with_(T=2 * fom.T, time_stepper=fom.time_stepper.with_(nt=2 * nt), nt=2 * nt)
ref = {str(mu): fom2.solve(mu)[::10][: 2 * K + 1] for mu in test}


def errors(mu, U_rom):
    R = ref[str(mu)]
    n = len(U_rom)
    first = min(n, K + 1)
    e = lambda a, b: float(np.sqrt((R[a:b] - U_rom[a:b]).norm2().sum() / R[a:b].norm2().sum()))
    return e(0, first), (e(K + 1, n) if n > K + 1 else None)


rows = []
galerkin = QuadraticHamiltonianRBReductor(fom, RB)
t0 = time.perf_counter()
grom = galerkin.reduce()
t_offline = time.perf_counter() - t0
grom2 = grom.with_(T=2 * fom.T, time_stepper=grom.time_stepper.with_(nt=2 * nt), nt=2 * nt)
rows.append(
    {
        "method": "Galerkin ROM (pyMOR QuadraticHamiltonianRBReductor)",
        "needs": "reduced operator V^T H(mu) V",
        "offline_s": t_offline,
        "solve": lambda mu: grom.solve(mu),
        "long": lambda mu: galerkin.reconstruct(grom2.solve(mu))[::10],
        "recon": lambda mu: galerkin.reconstruct(grom.solve(mu))[::10],
    }
)

# the same Galerkin ROM stepped in NumPy with its exact propagator at dt, assembled online per mu
from scipy.linalg import expm  # noqa: E402

from sympredict.systems.flowmaps import linear_system_from_pymor, mu_to_vector  # noqa: E402

lin = linear_system_from_pymor(grom)
V_plus_arr = RB.transposed_symplectic_inverse().to_array()
x0_red = {str(mu): V_plus_arr.inner(fom.initial_data.as_range_array(mu))[:, 0] for mu in test}


def numpy_galerkin(mu, n_steps):
    lin._cache.clear()  # online: assemble H_red(mu) and the propagator anew for every solve
    P = expm(dt * (lin.J @ lin.matrix(mu_to_vector(mu, fom.parameters))))
    x = np.empty((n_steps + 1, lin.dim))
    x[0] = x0_red[str(mu)]
    for k in range(n_steps):
        x[k + 1] = P @ x[k]
    return x


rows.append(
    {
        "method": "Galerkin ROM in NumPy: exact propagator expm(dt J H_red(mu)) at dt, assembled online",
        "needs": "reduced operator V^T H(mu) V",
        "offline_s": t_offline,
        "solve": lambda mu: numpy_galerkin(mu, K),
        "long": lambda mu: RB.to_array().lincomb(numpy_galerkin(mu, 2 * K).T),
        "recon": lambda mu: RB.to_array().lincomb(numpy_galerkin(mu, K).T),
    }
)

for data in ("reduced", "projected"):
    samples = GalerkinSamples(train, n_samples=args.samples) if data == "reduced" else ProjectedTrajectories(train)
    red = SymplecticKernelReductor(fom, RB, dt, samples, DefaultEstimator(max_centers=args.centers))
    t0 = time.perf_counter()
    krom = red.reduce()
    t_off = time.perf_counter() - t0
    krom2 = krom.with_(T=2 * fom.T)
    rows.append(
        {
            "method": f"kernel ROM, data='{data}' (SymplecticKernelReductor)",
            "needs": "reduced operator (Galerkin flow samples)"
            if data == "reduced"
            else "FOM trajectories only (fom.solve)",
            "offline_s": t_off,
            "centres": red.predictor_.n_centers_,
            "kernel": f"{red.predictor_.state_kernel!r}, {red.predictor_.mu_kernel!r}",
            "solve": (lambda r: lambda mu: r.solve(mu))(krom),
            "long": (lambda r, k: lambda mu: r.reconstruct(k.solve(mu)))(red, krom2),
            "recon": (lambda r, k: lambda mu: r.reconstruct(k.solve(mu)))(red, krom),
        }
    )

# pyMOR's DataDrivenReductor on the same data: projected FOM trajectories at the training speeds, on the macro grid
V_plus = RB.transposed_symplectic_inverse().to_array()
snaps = []
for u in U_train:
    snaps.append(V_plus.inner(u[::10][: K + 1]).T)  # (K+1, 2n)
snap_va = np.concatenate(snaps)  # (P (K+1), 2n): DataDrivenReductor iterates rows


def data_driven(regressor, scaler):
    dd = DataDrivenReductor(train, snap_va, regressor=regressor, T=K * dt, input_scaler=scaler)
    t0 = time.perf_counter()
    rom = dd.reduce()
    return rom, time.perf_counter() - t0


def dd_recon(rom):
    return lambda mu: RB.to_array().lincomb(rom.solve(mu).to_numpy())


for label, make in (
    ("default VKOGARegressor()", lambda ls: (VKOGARegressor(), None)),
    (
        "VKOGA, 500 centres, scaled inputs, Gaussian width chosen on validation speeds",
        lambda ls: (VKOGARegressor(GaussianKernel(ls), max_centers=500, tol=1e-12), BoxScaling()),
    ),
):
    best = None
    for ls in (1.0,) if label.startswith("default") else (0.03, 0.1, 0.3, 1.0):
        rom, t_off = data_driven(*make(ls))
        rec = dd_recon(rom)
        v = (
            [
                float(
                    np.sqrt(
                        (fom.solve(mu)[::10][: K + 1] - rec(mu)).norm2().sum()
                        / fom.solve(mu)[::10][: K + 1].norm2().sum()
                    )
                )
                for mu in val
            ]
            if not label.startswith("default")
            else [0.0]
        )
        if best is None or np.mean(v) < best[0]:
            best = (np.mean(v), rom, t_off, ls)
    _, rom, t_off, ls = best
    rom2 = rom.with_(T=2 * K * dt, nt=2 * K + 1)
    rows.append(
        {
            "method": f"pyMOR DataDrivenReductor, {label}" + ("" if label.startswith("default") else f" (width {ls})"),
            "needs": "FOM trajectories only (same projected data)",
            "offline_s": t_off,
            "solve": (lambda r: lambda mu: r.solve(mu))(rom),
            "long": (lambda r: lambda mu: RB.to_array().lincomb(r.solve(mu).to_numpy()))(rom2),
            "recon": dd_recon(rom),
        }
    )

results = []
for row in rows:
    errs, errs_long, times = [], [], []
    for mu in test:
        e, _ = errors(mu, row["recon"](mu))
        _, el = errors(mu, row["long"](mu))
        errs.append(e)
        errs_long.append(el)
        times.append(time_median(lambda: row["solve"](mu), args.repeats)[0])
    results.append(
        {k: v for k, v in row.items() if k not in ("solve", "long", "recon")}
        | {
            "error_0_T": float(np.mean(errs)),
            "error_T_2T": float(np.mean(errs_long)),
            "online_s": float(np.median(times)),
        }
    )

gal = results[0]
print(
    f"FOM: N = {fom.solution_space.dim}, nt = {nt}, T = {fom.T}, dt = {dt:.6g} ({K} macro steps); 5 training FOM solves "
    f"{t_fom_train:.2f} s; test speeds {[round(float(m['c'][0]), 4) for m in test]}"
)
print(
    "| method | needs | error on [0, T] | ratio to Galerkin | error on (T, 2T] | online solve (median) | speed-up vs pyMOR Galerkin | offline |"
)
print("|---|---|---|---|---|---|---|---|")
for r in results:
    print(
        f"| {r['method']} | {r['needs']} | {r['error_0_T']:.2e} | {r['error_0_T'] / gal['error_0_T']:.2f} | "
        f"{r['error_T_2T']:.2e} | {1e3 * r['online_s']:.2f} ms | {gal['online_s'] / r['online_s']:.1f}x | {r['offline_s']:.1f} s |"
    )
for r in results:
    if "centres" in r:
        print(f"{r['method']}: {r['centres']} centres, kernels {r['kernel']}")
if args.json:
    with open(args.json, "w") as f:
        json.dump({"T": fom.T, "dt": dt, "results": results}, f, indent=1)
