"""pyMOR's demo wave equation, made parametric in the wave speed c, reduced with SymplecticKernelReductor.

Run:  python examples/pymor_wave_reductor.py [--T 5] [--data projected|reduced] [--centers 1000]

The user code (marked) is what a pyMOR user writes: the demo model with its stiffness block
scaled by c^2 / 0.1^2 (the demo has c = 0.1), snapshots at 5 training speeds, a symplectic
basis (2n = 4: ``psd_complex_svd(U, 4)`` has 4 modes), the reductor with dt = 10 FOM steps.  The rest compares with the FOM and with
pyMOR's symplectic Galerkin ROM at speeds not trained on.
"""

import argparse

import numpy as np

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--T", type=float, default=5.0)
parser.add_argument(
    "--data",
    default="projected",
    choices=["projected", "reduced"],
    help="projected FOM trajectories or samples of the Galerkin ROM's exact flow",
)
parser.add_argument("--centers", type=int, default=1000)
parser.add_argument("--samples", type=int, default=400, help="--data reduced: samples per training speed")
args = parser.parse_args()


# ---- user code: 15 lines ------------------------------------------------------------------------
from pymor.algorithms.symplectic import psd_complex_svd
from pymor.operators.block import BlockDiagonalOperator
from pymor.operators.constructions import LincombOperator
from pymor.parameters.functionals import ExpressionParameterFunctional
from pymordemos.symplectic_wave_equation import discretize_fom
from sympredict.mor import DefaultEstimator, GalerkinSamples, ProjectedTrajectories, SymplecticKernelReductor

fom = discretize_fom(T=args.T)
stiffness, identity = fom.H_op.blocks[0, 0], fom.H_op.blocks[1, 1]  # the demo's wave speed is c = 0.1
fom = fom.with_(
    H_op=BlockDiagonalOperator(
        [LincombOperator([stiffness], [ExpressionParameterFunctional("c[0]**2 / 0.1**2", {"c": 1})]), identity]
    )
)
train = fom.parameters.space(0.08, 0.12).sample_uniformly(5)
U = fom.solution_space.empty()
for mu in train:
    U.append(fom.solve(mu))
samples = ProjectedTrajectories(train) if args.data == "projected" else GalerkinSamples(train, n_samples=args.samples)
reductor = SymplecticKernelReductor(
    fom, psd_complex_svd(U, 4), 10 * fom.T / fom.time_stepper.nt, samples, DefaultEstimator(max_centers=args.centers)
)  # CI runs it small
rom = reductor.reduce()
# -------------------------------------------------------------------------------------------------

from pymor.reductors.symplectic import QuadraticHamiltonianRBReductor  # noqa: E402

galerkin = QuadraticHamiltonianRBReductor(fom, reductor.RB)
galerkin_rom = galerkin.reduce()
for c in (0.0853, 0.1031, 0.1168):  # not trained on
    mu = fom.parameters.parse(c)
    U_fom = fom.solve(mu)[::10]
    U_kernel = reductor.reconstruct(rom.solve(mu))
    U_galerkin = galerkin.reconstruct(galerkin_rom.solve(mu))[::10]
    err = lambda V: np.sqrt((U_fom - V).norm2().sum() / U_fom.norm2().sum())
    print(f"c = {c}: relative error kernel ROM {err(U_kernel):.2e}, Galerkin ROM {err(U_galerkin):.2e}")
long = rom.with_(T=4 * fom.T).solve(fom.parameters.parse(0.1031))
print(
    f"past the training horizon: {len(long)} states up to t = {4 * fom.T:g}, finite: {np.all(np.isfinite(long.to_numpy()))}"
)
