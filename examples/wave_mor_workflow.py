"""The MOR workflow: wave FOM (pyMOR) -> symplectic basis -> ROM -> kernel predictor -> reconstruction.

Run:  python examples/wave_mor_workflow.py [--n-points 1000] [--samples 2000] [--centers 1500]

1. the finite-difference wave FOM, a pyMOR ``QuadraticHamiltonianModel`` with parameter mu = c^2;
2. snapshots at c_ref = 0.3 from low-frequency states, complex-SVD symplectic basis (2n = 4);
3. pyMOR's symplectic reductor: reduced Hamiltonian V^T H(mu) V, stepped in NumPy;
4. flow-map data in reduced coordinates over the six training speeds, and sympredict's reductor on
   them: one predictor for dT = 0.1, trained in the reduced coordinates as they are, and its pyMOR ROM;
5. prediction at an unseen speed, reconstructed in the full space and compared with the FOM.
"""

import argparse


from sympredict import SymplecticKernelPredictor
from sympredict_paper.wave import reduced_flow_map_data
from sympredict.kernels import IMQ
from sympredict.mor import GivenSamples, SymplecticKernelReductor, TrainingScaling
from sympredict.symplectic.metrics import relative_trajectory_error
from sympredict.mor.basis import SymplecticROM, complex_svd_basis, symplecticity_of_basis
from sympredict.systems.wave import C_REF, C_TRAIN, WaveFOM

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--n-points", type=int, default=1000)
parser.add_argument("--samples", type=int, default=2000, help="reduced training states per training speed")
parser.add_argument("--centers", type=int, default=1500)
args = parser.parse_args()

# 1. FOM
fom = WaveFOM(n_points=args.n_points, T=6.0)
print(fom.model)

# 2. snapshots and basis
mu_ref = C_REF**2
energy = fom.reference_energy(mu_ref)  # unit-amplitude fundamental mode
x0 = fom.low_frequency_states(10, 2, mu_ref, energy, seed=0)
snapshots = fom.trajectory(x0, mu_ref, 0.02, 300).reshape(-1, fom.dim)
basis = complex_svd_basis(snapshots, n=2, layout="rows")
print(f"singular values {basis.singular_values[:4]}, V^T J V - J: {symplecticity_of_basis(basis.V):.1e}")

# 3. reduction (pyMOR's QuadraticHamiltonianRBReductor inside)
rom = SymplecticROM(fom, basis)
print(f"reduced model: {rom.rom.H_op.name} of dimension {rom.dim}")

# 4. data and the reductor for dT = 0.1, no dT factor (one model per step); no scaling: the kernel shapes are
#    in the reduced coordinates and in mu = c^2
dt = 0.1
data = reduced_flow_map_data(rom, C_TRAIN, dt, args.samples, energy, seed=1)
reductor = SymplecticKernelReductor(
    fom.model,
    rom.RB,
    dt,
    GivenSamples(data),
    SymplecticKernelPredictor(IMQ(1e-3), mu_kernel=IMQ(3.0), max_centers=args.centers),
    scaling=TrainingScaling("none", "none", "none"),
)
kernel_rom = reductor.reduce()  # a pyMOR model: kernel_rom.solve(mu) from the FOM's initial data
model = reductor.flow_map_  # the learned step in reduced coordinates
fitted = reductor.predictor_
print(
    f"{fitted.n_centers_} centres ({fitted.history_.stop_reason}), max training residual {fitted.history_.train_max_residual[-1]:.1e}"
)

# 5. an unseen speed: predict in reduced coordinates, reconstruct, compare with the FOM
c = 0.257
x_red = rom.system.sample_energy_ellipsoid(3, c**2, energy, seed=7)
n_steps = 60  # T = 6
pred = model.rollout(x_red, n_steps, mu=c**2, dt=dt)  # (3, 61, 4)
fom_ref = fom.trajectory(rom.reconstruct(x_red), c**2, dt, n_steps)
im = rom.system.trajectory(x_red, c**2, dt, n_steps, h_max=dt)
for name, traj in (("ROM + kernel predictor", pred), ("ROM + implicit midpoint", im)):
    err = relative_trajectory_error(rom.reconstruct(traj), fom_ref).mean(axis=0)[1:]
    print(f"{name:>24}: time-averaged relative error in the full space {err.mean():.1e}")
