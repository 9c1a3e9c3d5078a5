"""Symplectic Galerkin and DEIM ROMs of sine-Gordon: exact oracles (complete basis = FOM, m = N DEIM = Galerkin),
the compiled field against NumPy and V^T grad H(V y), Jacobians by finite differences, symplecticity of one step
(Galerkin yes, DEIM no: measured), RK4's order."""

import numpy as np
import pytest
from scipy.stats import linregress

from sympredict.symplectic.integrators_compiled import rollout
from sympredict.symplectic.metrics import canonical_J
from sympredict.mor.nonlinear import ReducedSineGordon, nonlinear_snapshots, rk4_rollout
from sympredict.mor.basis import complex_svd_basis, symplecticity_of_basis
from sympredict.systems.sine_gordon import SineGordonFOM


@pytest.fixture(scope="module")
def setup():
    fom = SineGordonFOM(n_points=30, length=10.0, strength=1.0)
    rng = np.random.default_rng(0)
    x0 = np.stack([a * fom.sech_cos(1.5, 1.0) for a in (0.8, 1.2, 1.6)])
    traj = rollout(fom, x0, [[0.9], [1.0], [1.1]], 0.1, 40, scheme="kahan_li6", substeps=8)
    basis = complex_svd_basis(traj.reshape(-1, fom.dim), n=5, layout="rows")
    return fom, basis, traj, rng


def _one_step_defect(rom, y, c, h):
    """max |DPhi^T J DPhi - J| of one implicit-midpoint step, central differences."""
    e = 1e-6
    cols = [
        (rom.solve(y + e * v, c, h, 1)[0, -1] - rom.solve(y - e * v, c, h, 1)[0, -1]) / (2 * e) for v in np.eye(rom.dim)
    ]
    Dphi = np.array(cols).T
    J = canonical_J(rom.dim)
    return np.abs(Dphi.T @ J @ Dphi - J).max()


def test_galerkin_field_is_projected_gradient(setup):
    fom, basis, _, rng = setup
    rom = ReducedSineGordon.galerkin(fom, basis.V)
    assert symplecticity_of_basis(basis.V) < 1e-12
    y = 0.5 * rng.normal(size=(4, rom.dim))
    c = np.array([0.8, 0.9, 1.1, 1.2])
    expect = fom.gradient(y @ basis.V.T, c) @ basis.V
    assert np.abs(rom.g(y, c) - expect).max() < 1e-11
    assert np.abs(rom.pointwise().gradient(y, c[:, None]) - expect).max() < 1e-11
    e = 1e-6
    Jac = rom.jacobian(y[0], 0.8)
    fd = np.array([(rom.g(y[0] + e * v, 0.8)[0] - rom.g(y[0] - e * v, 0.8)[0]) / (2 * e) for v in np.eye(rom.dim)]).T
    assert np.abs(Jac - fd).max() < 1e-6 * np.abs(Jac).max()
    assert np.abs(rom.pointwise().hessian(y[:1], [[0.8]])[0] - Jac).max() < 1e-12


def test_complete_basis_reproduces_the_fom(setup):
    """With n = N (a complete orthosymplectic basis) the Galerkin ROM is the FOM in other coordinates."""
    fom, _, _, rng = setup
    basis = complex_svd_basis(rng.normal(size=(3 * fom.n_points, fom.dim)), n=fom.n_points, layout="rows")
    rom = ReducedSineGordon.galerkin(fom, basis.V)
    x0 = 0.7 * fom.sech_cos(1.5, 1.0)
    full = rollout(fom.pointwise(), x0[None], [[1.0]], 0.1, 10, scheme="implicit_midpoint", substeps=2)[0]
    red = rom.reconstruct(rom.solve(rom.project(x0)[None], 1.0, 0.1, 10, substeps=2)[0])
    assert np.abs(red - full).max() < 1e-9


def test_deim_with_all_points_is_galerkin(setup):
    """m = N interpolation points: U (P^T U)^-1 P^T = I, so DEIM's field equals Galerkin's (to round-off)."""
    fom, basis, _, rng = setup
    snaps = rng.normal(size=(3 * fom.n_points, fom.n_points))
    deim = ReducedSineGordon.deim(fom, basis.V, snaps, fom.n_points)
    gal = ReducedSineGordon.galerkin(fom, basis.V)
    y = 0.5 * rng.normal(size=(3, gal.dim))
    assert deim.n_interpolation == fom.n_points
    assert np.abs(deim.g(y, 1.0) - gal.g(y, 1.0)).max() < 1e-9


def test_deim_is_not_hamiltonian_galerkin_is(setup):
    """Galerkin: symmetric Jacobian of g and a symplectic midpoint step; DEIM (m < N): neither, measurably."""
    fom, basis, traj, _ = setup
    gal = ReducedSineGordon.galerkin(fom, basis.V)
    deim = ReducedSineGordon.deim(fom, basis.V, nonlinear_snapshots(fom, traj), 8)
    assert deim.n_interpolation == 8 and len(set(deim.interpolation_dofs)) == 8
    y = gal.project(traj[1, 20])
    assert gal.gradient_asymmetry(y, 1.0) < 1e-13
    assert deim.gradient_asymmetry(y, 1.0) > 1e-6
    assert _one_step_defect(gal, y, 1.0, 0.2) < 1e-7
    assert _one_step_defect(deim, y, 1.0, 0.2) > 1e-5
    # DEIM still approximates the Galerkin field on the data
    assert np.abs(deim.g(y, 1.0) - gal.g(y, 1.0)).max() < 0.05 * np.abs(gal.g(y, 1.0)).max()


def test_galerkin_energy_bounded_and_rk4_order(setup):
    fom, basis, traj, _ = setup
    rom = ReducedSineGordon.galerkin(fom, basis.V)
    y0 = rom.project(traj[:, 0])
    long = rom.solve(y0, [0.9, 1.0, 1.1], 0.05, 2000)
    E = rom.reduced_energy(long.reshape(-1, rom.dim), np.repeat([0.9, 1.0, 1.1], 2001)).reshape(3, -1)
    assert np.abs(E - E[:, :1]).max() < 1e-2 * np.abs(E[:, 0]).min()  # bounded over T = 100, no drift
    drift = np.abs(E[:, -500:] - E[:, :1]).max() / np.abs(E[:, :500] - E[:, :1]).max()
    assert drift < 2.0
    fine = rk4_rollout(rom.pointwise(), y0, [[0.9], [1.0], [1.1]], 1.0, 1, substeps=256)[:, -1]
    hs, errs = [], []
    for r in (16, 24, 32, 48):
        errs.append(
            np.abs(rk4_rollout(rom.pointwise(), y0, [[0.9], [1.0], [1.1]], 1.0, 1, substeps=r)[:, -1] - fine).max()
        )
        hs.append(1.0 / r)
    assert abs(linregress(np.log(hs), np.log(errs)).slope - 4) < 0.3, errs
