"""The sine-Gordon FOM: gradients and Hessians against finite differences, the compiled functions against NumPy,
the breather's closed form (second order in dx), the reference's order 6 and energy, and the pyMOR model."""

import numpy as np
import pytest
from scipy.stats import linregress

from sympredict.symplectic.integrators_compiled import rollout
from sympredict.systems.sine_gordon import SineGordonFOM, fd_laplacian_1d


@pytest.fixture(scope="module")
def small():
    return SineGordonFOM(n_points=40, length=20.0, strength=0.7, c_range=(0.8, 1.2))


def _state(fom, seed=0):
    rng = np.random.default_rng(seed)
    return np.concatenate(
        [fom.sech_cos(2.0, 1.0)[: fom.n_points], 0.3 * fom.breather(1.0, 0.5)[fom.n_points :]]
    ) + 0.1 * rng.normal(size=fom.dim)


@pytest.mark.parametrize("boundary", ["dirichlet", "periodic"])
def test_laplacian(boundary):
    D = fd_laplacian_1d(16, 3.0, boundary).toarray()
    assert np.allclose(D, D.T)
    ev = np.linalg.eigvalsh(D)
    dx = 3.0 / (17 if boundary == "dirichlet" else 16)
    assert ev.min() > -1e-9 and ev.max() <= 4 / dx**2 * (1 + 1e-12)
    if boundary == "periodic":
        assert np.allclose(D.sum(axis=1), 0.0)  # constants in the kernel
    else:
        k = np.arange(1, 17)
        assert np.allclose(np.sort(ev), (2 / dx**2) * (1 - np.cos(k * np.pi / 17)))


def test_gradient_and_hessian_against_finite_differences(small):
    x, c, e = _state(small), 1.1, 1e-6
    g = small.gradient(x[None], c)[0]
    fd = np.array(
        [
            (small.hamiltonian((x + e * v)[None], c)[0] - small.hamiltonian((x - e * v)[None], c)[0]) / (2 * e)
            for v in np.eye(small.dim)
        ]
    )
    assert np.abs(g - fd).max() < 1e-6 * (1 + np.abs(g).max())
    H = small.hessian(x[None], c)[0]
    fdH = np.array(
        [
            (small.gradient((x + e * v)[None], c)[0] - small.gradient((x - e * v)[None], c)[0]) / (2 * e)
            for v in np.eye(small.dim)
        ]
    ).T
    assert np.abs(H - fdH).max() < 1e-5 * (1 + np.abs(H).max())
    assert np.allclose(H, H.T)


def test_compiled_functions_match_numpy(small):
    pw = small.pointwise()
    x = np.stack([_state(small, s) for s in range(3)])
    c = np.array([0.8, 1.0, 1.2])
    assert np.abs(pw.gradient(x, c[:, None]) - small.gradient(x, c)).max() < 1e-12
    assert np.abs(pw.hessian(x, c[:, None]) - small.hessian(x, c)).max() < 1e-10
    with pytest.raises(ValueError, match="c must lie"):
        small.gradient(x, 2.0)


def test_breather_closed_form_second_order_in_dx():
    """Against the exact breather on the line: error O(dx^2) (reference converged in time to 1e-10)."""
    errs, dxs = [], []
    for n in (100, 200, 400):
        fom = SineGordonFOM(n_points=n, length=40.0)
        traj = fom.reference_trajectory(fom.breather(1.0, 0.6), 1.0, 0.5, 4, tol=1e-10)
        errs.append(np.abs(traj - fom.breather_exact(0.5 * np.arange(5), 1.0, 0.6)).max())
        dxs.append(fom.dx)
    slope = linregress(np.log(dxs), np.log(errs)).slope
    assert abs(slope - 2) < 0.2, (errs, slope)


def test_reference_order_six_and_energy(small):
    """Kahan–Li-6 on the FOM: observed order 6 against a fine run; energy conserved, step halving converged."""
    x0, c, T = _state(small), 1.0, 2.0
    fine = rollout(small, x0[None], [[c]], T, 1, scheme="kahan_li6", substeps=512)[0, -1]
    hs, errs = [], []
    for r in (24, 32, 48, 64):
        errs.append(np.abs(rollout(small, x0[None], [[c]], T, 1, scheme="kahan_li6", substeps=r)[0, -1] - fine).max())
        hs.append(T / r)
    slope = linregress(np.log(hs), np.log(errs)).slope
    assert abs(slope - 6) < 0.35, (errs, slope)
    traj, est = small.reference_trajectory(x0, c, 0.5, 40, tol=1e-10, return_error=True)
    assert est <= 1e-10
    E = small.energy(traj, c)
    assert np.abs(E - E[0]).max() < 1e-9 * E[0]


def test_pymor_model_solves_with_the_reference():
    fom = SineGordonFOM(n_points=60, length=20.0, T=2.0, nt=20, initial="kink_antikink", c_range=(0.8, 1.2))
    assert set(fom.model.parameters) == {"c", "amplitude"}
    mu = fom.model.parameters.parse({"c": 0.9, "amplitude": 0.7})
    X = fom.from_pymor(fom.model.solve(mu))
    ref = fom.reference_trajectory(0.7 * fom.initial_state(1.0), 0.9, 0.1, 20, tol=1e-10)
    assert X.shape == (21, fom.dim)
    assert np.abs(X - ref).max() < 1e-8
    # the operator is -J grad H, its Jacobian agrees with finite differences of apply
    x = _state(fom)
    U = fom.to_pymor(x)
    A = fom.from_pymor(fom.operator.apply(U, mu))[0]
    g = fom.gradient(x[None], 0.9)[0]
    n = fom.n_points
    assert np.allclose(A, -np.concatenate([g[n:], -g[:n]]))
    jac = fom.operator.jacobian(U, mu)
    v = np.random.default_rng(1).normal(size=fom.dim)
    Jv = fom.from_pymor(jac.apply(fom.to_pymor(v)))[0]
    e = 1e-6
    fd = (
        fom.from_pymor(fom.operator.apply(fom.to_pymor(x + e * v), mu))[0]
        - fom.from_pymor(fom.operator.apply(fom.to_pymor(x - e * v), mu))[0]
    ) / (2 * e)
    assert np.abs(Jv - fd).max() < 1e-5 * np.abs(Jv).max()


def test_initial_families():
    fom = SineGordonFOM(n_points=400, length=40.0)
    ka = fom.kink_antikink(1.0, 0.5, 16.0)
    n = fom.n_points
    tail = 4 * np.exp(-(12 - fom.x[0]) / np.sqrt(0.75))  # kinks at x = 12, 28; g = 1 / sqrt(1 - v^2)
    assert abs(ka[0]) < 1.1 * tail and abs(ka[n - 1]) < 1.1 * tail
    assert abs(ka[n // 2] - 2 * np.pi) < 1.1 * 8 * np.exp(-8 / np.sqrt(0.75))  # 2 pi between (two tails 4 e^(-g d / 2))
    assert np.allclose(fom.breather_exact([0.0], 1.0, 0.6)[0], fom.breather(1.0, 0.6))
    states = fom.energy_bounded_states(5, energy=2.0, c=1.0, seed=3)
    E = fom.energy(states, 1.0)
    assert np.all(E <= 2.0 * (1 + 1e-9)) and np.all(E > 0)
    assert np.abs(states[:, :n]).max() <= np.pi + 1e-12
