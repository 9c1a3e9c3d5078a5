"""Compiled classical integrators: agreement with the NumPy reference, orders, symplecticity, energy, input checks."""

import numba
import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.stats import linregress

from sympredict.exceptions import NewtonConvergenceError
from sympredict.symplectic.integrators import COMPOSITIONS, SCHEME_ORDERS, SCHEMES, apply_J
from sympredict.symplectic.integrators_compiled import (
    HAVE_NUMBA,
    PointwiseHamiltonian,
    csr_fill_dense,
    csr_matvec,
    jit_pointwise,
    rollout,
)
from sympredict.symplectic.metrics import canonical_J
from sympredict.systems.henon_heiles import HenonHeiles, energy_bounded_states
from sympredict.systems.pendulum import Pendulum
from sympredict.systems.quadratic import QuadraticHamiltonian
from sympredict.systems.wave import WaveFOM

ALL_SCHEMES = sorted(SCHEMES)
SYSTEMS = ["pendulum", "quadratic", "wave", "henon_heiles"]


def _quadratic(rng, separable=True):
    n = 3
    a = rng.normal(size=(n, n))
    z = np.zeros((n, n))
    coupling = 0.3 * rng.normal(size=(n, n)) if not separable else z
    H0 = np.block([[a @ a.T + 2 * np.eye(n), coupling], [coupling.T, np.diag([1.0, 1.5, 2.0])]])
    b = rng.normal(size=(n, n))
    H1 = np.block([[0.2 * (b + b.T), z], [z, 0.1 * np.eye(n)]])
    return QuadraticHamiltonian(H0, H1)


def _case(name, b=10, seed=0):
    """(system, states (b, 2n), parameters (b,)) for each shipped system."""
    rng = np.random.default_rng(seed)
    if name == "pendulum":  # m and g not 1 and 9.81: they must enter every formula
        system = Pendulum(g=9.0, mass=1.3)
        return system, np.column_stack([rng.uniform(-2.5, 2.5, b), rng.uniform(-2, 2, b)]), rng.uniform(0.7, 0.8, b)
    if name == "quadratic":
        system = _quadratic(rng)
        return system, rng.normal(size=(b, system.dim)), rng.uniform(0.0, 1.0, b)
    if name == "wave":
        system = WaveFOM(n_points=8, mu_range=(0.04, 0.09))
        mu = rng.uniform(0.04, 0.09, b)
        return system, system.low_frequency_states(b, 4, 0.06, system.reference_energy(0.06), seed=seed), mu
    if name == "henon_heiles":
        system = HenonHeiles()
        lam = rng.uniform(0.8, 1.0, b)
        x = np.vstack(
            [energy_bounded_states(system, lam_i, 1, energy_max=0.12, seed=seed + i) for i, lam_i in enumerate(lam)]
        )
        return system, x, lam
    raise KeyError(name)


def _exact(system, x, mu, t):
    """Independent oracles: closed forms for the linear systems, DOP853 at tolerance 1e-13 otherwise."""
    if isinstance(system, QuadraticHamiltonian):
        return system.exact_flow(x, mu, t)
    if isinstance(system, WaveFOM):
        return system.exact_trajectory(x, mu, t, 1)[:, 1]

    def rhs(_, y, m):
        return apply_J(system.gradient(y[None], np.array([[m]])))[0]

    return np.array(
        [
            solve_ivp(rhs, (0.0, t), xi, method="DOP853", rtol=1e-13, atol=1e-13, args=(m,)).y[:, -1]
            for xi, m in zip(x, mu)
        ]
    )


def test_numba_is_installed_for_these_tests():
    # the test extra installs numba: nothing below may silently test only the NumPy fallback
    assert HAVE_NUMBA


def test_composition_coefficients_are_consistent():
    for name, g in COMPOSITIONS.items():
        g = np.array(g)
        np.testing.assert_allclose(g.sum(), 1.0, rtol=0, atol=1e-15, err_msg=name)
        np.testing.assert_array_equal(g, g[::-1])  # symmetric: even order
        if len(g) > 1:  # order >= 4: sum g^3 = 0
            assert abs(np.sum(g**3)) < 1e-15, name
    assert abs(np.sum(np.array(COMPOSITIONS["kahan_li6"]) ** 5)) < 1e-15  # order 6 needs sum g^5 = 0 too


@pytest.mark.parametrize("name", SYSTEMS)
def test_pointwise_gradients_match_the_numpy_system(name):
    system, x, mu = _case(name)
    spec = system.pointwise()
    np.testing.assert_allclose(spec.gradient(x, mu), system.gradient(x, mu), rtol=1e-14, atol=1e-14)
    np.testing.assert_allclose(spec.hessian(x, mu), system.hessian(x, mu), rtol=1e-14, atol=1e-14)
    # the separable parts on their own (what the explicit schemes call)
    split = PointwiseHamiltonian(
        spec.dim, 1, grad_T=spec.grad_T, grad_V=spec.grad_V, fargs=spec.fargs, iargs=spec.iargs
    )
    np.testing.assert_allclose(split.gradient(x, mu), system.gradient(x, mu), rtol=1e-14, atol=1e-14)


@pytest.mark.parametrize("scheme", ALL_SCHEMES)
@pytest.mark.parametrize("name", SYSTEMS)
def test_compiled_rollout_matches_numpy_reference(name, scheme):
    system, x, mu = _case(name)
    ref = rollout(system, x, mu, 0.1, 12, scheme=scheme, substeps=2, backend="numpy")
    scale = np.abs(ref).max()
    for parallel in (True, False):
        got = rollout(system, x, mu, 0.1, 12, scheme=scheme, substeps=2, backend="numba", parallel=parallel)
        assert got.shape == (len(x), 13, system.dim)
        np.testing.assert_allclose(got, ref, rtol=0, atol=1e-13 * scale)
    # per-instance steps, one state
    dts = np.linspace(0.05, 0.15, len(x))
    got = rollout(system, x, mu, dts, 5, scheme=scheme, backend="numba")
    np.testing.assert_allclose(
        got, rollout(system, x, mu, dts, 5, scheme=scheme, backend="numpy"), rtol=0, atol=1e-13 * scale
    )
    one = rollout(system, x[2], mu[2], 0.1, 12, scheme=scheme, substeps=2)
    np.testing.assert_allclose(one, ref[2], rtol=0, atol=1e-13 * scale)


# (final time, sub-step counts) per system: errors stay well above round-off at the finest step
_ORDER_GRID = {"pendulum": 1.0, "quadratic": 1.0, "wave": 1.0, "henon_heiles": 2.0}
_BASE_STEPS = {"stormer_verlet": 16, "implicit_midpoint": 16, "yoshida4": 8, "kahan_li6": 4}


@pytest.mark.parametrize("scheme", ALL_SCHEMES)
@pytest.mark.parametrize("name", SYSTEMS)
def test_observed_convergence_order(name, scheme):
    system, x, mu = _case(name, b=4, seed=3)
    t = _ORDER_GRID[name]
    exact = _exact(system, x, mu, t)
    steps = _BASE_STEPS[scheme] * np.array([1, 2, 4, 8])
    errors = np.array(
        [np.abs(rollout(system, x, mu, t, 1, scheme=scheme, substeps=int(r))[:, 1] - exact).max() for r in steps]
    )
    assert errors.min() > 1e-11, errors  # asymptotic range, not round-off
    fit = linregress(np.log(t / steps), np.log(errors))
    assert abs(fit.slope - SCHEME_ORDERS[scheme]) < 0.25, (fit.slope, errors)
    assert fit.rvalue > 0.999


def _one_step_jacobian(system, x, mu, h, scheme, eps=1e-5):
    """Central finite differences of one step, (2n, 2n)."""
    cols = []
    for e in np.eye(len(x)):
        plus = rollout(system, x + eps * e, mu, h, 1, scheme=scheme)[1]
        minus = rollout(system, x - eps * e, mu, h, 1, scheme=scheme)[1]
        cols.append((plus - minus) / (2 * eps))
    return np.array(cols).T


@pytest.mark.parametrize("scheme", ALL_SCHEMES)
@pytest.mark.parametrize("name", ["pendulum", "henon_heiles", "quadratic"])
def test_one_step_is_symplectic(name, scheme):
    system, x, mu = _case(name, b=2, seed=5)
    J = canonical_J(system.dim)
    for xi, m in zip(x, mu):
        D = _one_step_jacobian(system, xi, m, 0.2, scheme)
        np.testing.assert_allclose(D.T @ J @ D, J, atol=1e-8)


def test_symplecticity_check_detects_a_non_symplectic_map():
    # explicit Euler through the same finite-difference check: DPhi^T J DPhi - J is O(h^2), not 1e-8
    system, x, mu = _case("henon_heiles", b=1, seed=5)
    J = canonical_J(4)

    def euler(y):
        return y + 0.2 * apply_J(system.gradient(y[None], mu))[0]

    eps = 1e-5
    D = np.array([(euler(x[0] + eps * e) - euler(x[0] - eps * e)) / (2 * eps) for e in np.eye(4)]).T
    assert np.abs(D.T @ J @ D - J).max() > 1e-3


@pytest.mark.parametrize(
    "scheme, tol", [("stormer_verlet", 5e-3), ("yoshida4", 5e-4), ("kahan_li6", 1e-4), ("implicit_midpoint", 5e-3)]
)
def test_energy_error_bounded_over_long_runs(scheme, tol):
    system = HenonHeiles()
    lam = np.array([0.8, 0.9, 1.0, 1.0])
    x = np.vstack([energy_bounded_states(system, m, 1, energy_max=0.12, seed=i) for i, m in enumerate(lam)])
    n_steps = 1000 if scheme != "implicit_midpoint" else 400
    traj = rollout(system, x, lam, 0.5, n_steps, scheme=scheme, substeps=5)  # h = 0.1, T = 500 (200)
    energy = system.hamiltonian(traj.reshape(-1, 4), np.repeat(lam, n_steps + 1)).reshape(len(x), -1)
    err = np.abs(energy - energy[:, :1]) / np.abs(energy[:, :1])
    assert err.max() < tol
    half = n_steps // 2
    assert err[:, half:].max() < 2 * err[:, :half].max() + 1e-13  # no drift


def test_implicit_midpoint_conserves_quadratic_energy_to_round_off():
    system, x, mu = _case("quadratic", b=4)
    traj = rollout(system, x, mu, 0.3, 200, scheme="implicit_midpoint")
    energy = system.hamiltonian(traj.reshape(-1, system.dim), np.repeat(mu, 201)).reshape(4, -1)
    np.testing.assert_allclose(energy, np.broadcast_to(energy[:, :1], energy.shape), rtol=1e-12)


# ------------------------------------------------------------ user systems
def _morse_grad_V(q, mu, fargs, iargs, out):
    # V = D (1 - exp(-a q))^2 per coordinate, D = mu[0], a = fargs[0]
    for j in range(q.shape[0]):
        e = np.exp(-fargs[0] * q[j])
        out[j] = 2.0 * mu[0] * fargs[0] * e * (1.0 - e)


def _morse_grad_T(p, mu, fargs, iargs, out):
    for j in range(p.shape[0]):
        out[j] = p[j]


def _morse_grad_H(x, mu, fargs, iargs, out):
    n = x.shape[0] // 2
    for j in range(n):
        e = np.exp(-fargs[0] * x[j])
        out[j] = 2.0 * mu[0] * fargs[0] * e * (1.0 - e)
        out[n + j] = x[n + j]


def _morse_hess_H(x, mu, fargs, iargs, out):
    n = x.shape[0] // 2
    out[:, :] = 0.0
    for j in range(n):
        e = np.exp(-fargs[0] * x[j])
        out[j, j] = 2.0 * mu[0] * fargs[0] ** 2 * e * (2.0 * e - 1.0)
        out[n + j, n + j] = 1.0


def _morse(fns):
    return PointwiseHamiltonian(
        4, 1, grad_T=fns[0], grad_V=fns[1], grad_H=fns[2], hess_H=fns[3], fargs=[1.3], name="morse"
    )


_PY = (_morse_grad_T, _morse_grad_V, _morse_grad_H, _morse_hess_H)
_JIT = tuple(jit_pointwise(f) for f in _PY)


@pytest.mark.parametrize("scheme", ALL_SCHEMES)
def test_user_system_jitted_and_plain_python_agree(scheme):
    x = np.array([[0.3, -0.2, 0.1, 0.4], [0.5, 0.1, -0.3, 0.0], [-0.2, 0.2, 0.2, -0.1]])
    mu = np.array([1.0, 2.0, 1.5])
    compiled, plain = _morse(_JIT), _morse(_PY)
    assert compiled.compiled_for(scheme) and not plain.compiled_for(scheme)
    a = rollout(compiled, x, mu, 0.1, 10, scheme=scheme, substeps=3, backend="numba")
    b = rollout(plain, x, mu, 0.1, 10, scheme=scheme, substeps=3)  # auto: NumPy reference, per-instance Python calls
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-13)
    with pytest.raises(ValueError, match="not numba-jitted"):
        rollout(plain, x, mu, 0.1, 1, scheme=scheme, backend="numba")


def test_csr_helpers_match_scipy_and_unit_mass_csr_packs_the_matrix_after_the_head():
    """``csr_matvec`` / ``csr_fill_dense`` against SciPy's product and dense matrix, on a random unsorted CSR matrix
    read at the offset ``unit_mass_csr`` puts it (after two constants of the system's own)."""
    import scipy.sparse as sps

    rng = np.random.default_rng(3)
    n = 9
    A = sps.random(n, n, density=0.4, random_state=4, format="csr") + sps.identity(n, format="csr")
    A = A.tocsr()[:, rng.permutation(n)][rng.permutation(n)].tocsr()  # an unsorted index order to be sorted
    spec = PointwiseHamiltonian.unit_mass_csr(A, grad_V=_JIT[1], grad_H=_JIT[2], head=(7.0, -1.0), n_mu=2, name="csr")
    assert spec.dim == 2 * n and spec.n_mu == 2 and spec.grad_T is not None
    np.testing.assert_array_equal(spec.fargs[:2], [7.0, -1.0])
    q, scale = rng.normal(size=n), -1.7
    out = np.full(n, np.nan)
    csr_matvec(q, scale, spec.fargs[2:], spec.iargs, out)
    terms = abs(scale) * (abs(A) @ np.abs(q))  # the round-off of a sum of at most n products
    np.testing.assert_array_less(np.abs(out - scale * (A @ q)), 4 * n * np.finfo(float).eps * terms + 1e-300)
    dense = np.full((2 * n, 2 * n), 5.0)
    csr_fill_dense(n, scale, spec.fargs[2:], spec.iargs, dense)
    expected = np.where(A.toarray() != 0, scale * A.toarray(), 5.0)  # A's pattern written, the rest untouched
    np.testing.assert_array_equal(dense[:n, :n], expected)
    np.testing.assert_array_equal(dense[n:], 5.0)
    np.testing.assert_array_equal(dense[:, n:], 5.0)


def test_user_gradient_with_wrong_signature_is_named():
    @numba.njit
    def grad_V(q, mu, out):
        out[0] = q[0]

    system = PointwiseHamiltonian(2, 1, grad_T=_JIT[0], grad_V=grad_V)
    with pytest.raises(ValueError, match="grad_V does not compile"):
        rollout(system, np.ones((1, 2)), 1.0, 0.1, 1)


def test_newton_failure_is_reported_with_step():
    # H = (q^2 - p^2)/2: at h = 2 the midpoint Jacobian I - (h/2) J H is exactly singular
    system = QuadraticHamiltonian(np.diag([1.0, -1.0]), np.zeros((2, 2)))
    x = np.array([[1.0, 0.0], [0.5, 0.5]])
    rollout(system, x, 0.0, np.array([1.0, 1.0]), 2, scheme="implicit_midpoint")  # fine
    with pytest.raises(NewtonConvergenceError, match="singular") as info:
        rollout(system, x, 0.0, np.array([1.0, 2.0]), 3, scheme="implicit_midpoint", backend="numba")
    assert list(info.value.instances) == [1] and info.value.step == 0


# ------------------------------------------------------------ bad input
@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(scheme="leapfrog"), "scheme"),
        (dict(backend="cuda"), "backend"),
        (dict(x0=np.ones((3, 3))), "x0"),
        (dict(x0=np.full((3, 2), np.nan)), "x0"),
        (dict(mu=np.ones(4)), "mu"),
        (dict(mu=-np.ones(3)), "length"),
        (dict(dt=-0.1), "dt"),
        (dict(dt=np.ones(2)), "dt"),
        (dict(n_steps=-1), "n_steps"),
        (dict(n_steps=2.5), "n_steps"),
        (dict(substeps=0), "substeps"),
        (dict(max_iter=0), "max_iter"),
    ],
)
def test_bad_input_names_the_argument(kwargs, match):
    args = dict(x0=np.zeros((3, 2)), mu=np.full(3, 0.75), dt=0.1, n_steps=2)
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        rollout(Pendulum(), args.pop("x0"), args.pop("mu"), args.pop("dt"), args.pop("n_steps"), **args)


def test_system_specific_domain_and_separability_checks():
    wave, x, _ = _case("wave", b=2)
    with pytest.raises(ValueError, match="mu = c"):
        rollout(wave, x, 1.0, 0.1, 1)
    coupled = _quadratic(np.random.default_rng(0), separable=False)
    assert not coupled.separable and coupled.pointwise().grad_V is None
    with pytest.raises(ValueError, match="separable"):
        rollout(coupled, np.ones((1, 6)), 0.5, 0.1, 1, scheme="yoshida4")
    rollout(coupled, np.ones((1, 6)), 0.5, 0.1, 1, scheme="implicit_midpoint")
    with pytest.raises(ValueError, match="grad_T and grad_V"):
        PointwiseHamiltonian(2, 1, grad_V=_JIT[1])
    with pytest.raises(ValueError, match="dim"):
        PointwiseHamiltonian(3, 1, grad_H=_JIT[2])


def test_without_numba_the_numpy_reference_runs(monkeypatch):
    import sympredict.symplectic.integrators_compiled as ic

    system, x, mu = _case("henon_heiles", b=3)
    compiled = rollout(system, x, mu, 0.1, 5, scheme="yoshida4")
    monkeypatch.setattr(ic, "HAVE_NUMBA", False)
    np.testing.assert_allclose(ic.rollout(system, x, mu, 0.1, 5, scheme="yoshida4"), compiled, rtol=0, atol=1e-14)
    with pytest.raises(ValueError, match="numba is not installed"):
        ic.rollout(system, x, mu, 0.1, 5, backend="numba")
