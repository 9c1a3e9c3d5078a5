"""The sine-Gordon kernel ROM with the reduced quadratic flow split off (``kernel_split``): the reduced Hessian at 0,
its flow carried into the scaled coordinates, the data's sub-step rule, and the option in a smoke run."""

from dataclasses import replace

import numpy as np
import pytest
from scipy.linalg import expm

from sympredict_paper.sine_gordon import PRESETS, _fit_kernel, run_sine_gordon, split_setup
from sympredict.systems.linear_flow import QuadraticPart
from sympredict.symplectic.metrics import canonical_J
from sympredict.mor.nonlinear import ReducedSineGordon
from sympredict.mor.basis import complex_svd_basis
from sympredict.flowmap.scaling import BoxScaling, SymplecticScaling, scaled_quadratic_part
from sympredict.systems.sine_gordon import SineGordonFOM


@pytest.fixture(scope="module")
def gal():
    fom = SineGordonFOM(n_points=40, length=12.0)
    rng = np.random.default_rng(0)
    X = np.cumsum(rng.normal(size=(60, fom.dim)), axis=1) * 0.05  # smooth-ish random states
    return ReducedSineGordon.galerkin(fom, complex_svd_basis(X, n=4, layout="rows").V)


def test_quadratic_part_is_the_reduced_hessian_at_zero(gal):
    """With the mass term: the Jacobian of ``g`` at ``y = 0`` (``c^2 A1 + A2 + s Vq^T Vq``); without: its
    quadratic part, checked against a central finite difference of the reduced gradient at 0 minus the mass term."""
    y0 = np.zeros(gal.dim)
    for c in (0.8, 1.13):
        with_mass = gal.quadratic_part().hessian(c)[0]
        assert np.allclose(with_mass, gal.jacobian(y0, c), rtol=0, atol=1e-13 * np.abs(with_mass).max())
        eps = 1e-6
        fd = np.column_stack([(gal.g(eps * e, c)[0] - gal.g(-eps * e, c)[0]) / (2 * eps) for e in np.eye(gal.dim)])
        assert np.allclose(with_mass, fd, atol=1e-6 * np.abs(fd).max())
        no_mass = gal.quadratic_part(mass=False).hessian(c)[0]
        Vq = gal.V[: gal.fom.n_points]
        assert np.allclose(no_mass, with_mass - gal.fom.strength * Vq.T @ Vq, atol=1e-12 * np.abs(with_mass).max())
    deim = ReducedSineGordon.deim(
        gal.fom, gal.V, np.sin(np.random.default_rng(1).normal(size=(30, gal.fom.n_points))), 6
    )
    with pytest.raises(ValueError, match="Galerkin"):
        deim.quadratic_part()


def test_scaled_quadratic_part_conjugates_the_flow(gal):
    """``expm(dT~ J A~(mu~)) = M expm(dT J A(mu)) M^-1`` with ``mu~`` the box-scaled ``c`` and ``dT~ = dT / tau``."""
    rng = np.random.default_rng(2)
    st = SymplecticScaling("diag").fit(rng.normal(size=(80, gal.dim)) * rng.uniform(0.1, 5.0, gal.dim))
    ms = BoxScaling().fit(np.array([[0.8], [1.2]]))
    tau = 0.1
    quad = gal.quadratic_part()
    scaled = scaled_quadratic_part(quad, st, ms, tau)
    M = st.matrix_
    for c, dt in ((0.8, 0.05), (1.07, 0.1), (1.2, -0.03)):
        L = expm(dt * canonical_J(gal.dim) @ quad.hessian(c)[0])
        Ls = scaled.propagator(ms.transform([[c]]), dt / tau)[0]
        assert np.allclose(Ls, M @ L @ np.linalg.inv(M), rtol=0, atol=1e-12 * np.abs(L).max())
    with pytest.raises(ValueError, match="non-negative integer"):
        scaled_quadratic_part(QuadraticPart([np.eye(gal.dim)], [[-2.0]]), st, ms, tau)


def test_split_setup_substeps_bound_the_phase_error(gal):
    """The data's sub-steps ``k``: implicit midpoint's turn of the fastest linear mode per ``DT`` (from the
    eigenvalues of ``Cayley^k``) is within ``split_phase_tol`` of the exact ``expm``'s, and ``k - 1`` would not be
    (unless ``k`` is the preset's own count); ``'none'`` keeps the preset's sub-steps."""
    p = PRESETS["smoke"]
    assert split_setup(p, gal)["substeps"] == p.substeps and split_setup(p, gal)["quadratic"] is None
    for tol in (0.3, 0.1, 0.02):
        q = replace(p, kernel_split="quadratic-mass", split_phase_tol=tol, substeps=1)
        sp = split_setup(q, gal)
        JA = canonical_J(gal.dim) @ sp["quadratic"].hessian(q.c_range[1])[0]
        w = np.abs(np.linalg.eigvals(JA)).max()
        assert sp["DT_omega_max_linear"] == pytest.approx(q.DT * w)

        def phase_error(k):  # of the fastest mode: exact angle DT w minus k Cayley angles 2 arctan(h w / 2)
            return q.DT * w - 2 * k * np.arctan(q.DT / k * w / 2)

        k = sp["substeps"]
        assert phase_error(k) <= tol * 1.05  # the rule uses the leading term (h w)^3 / 12, an upper bound
        if k > 1:
            assert phase_error(k - 1) > 0.8 * tol
    with pytest.raises(ValueError, match="kernel_split"):
        split_setup(replace(p, kernel_split="cubic"), gal)


@pytest.mark.filterwarnings("ignore::sympredict.exceptions.ExtrapolationWarning")  # a few steps past the data's box
def test_split_kernel_step_is_symplectic_in_original_coordinates(gal):
    """The split kernel fitted in the scaled coordinates (``_fit_kernel(..., quadratic=...)``) has
    ``DPhi^T J DPhi = J`` in the reduced coordinates, and its rollout equals repeated steps."""
    p = replace(PRESETS["smoke"], kernel_split="quadratic-mass", regularizations=(), max_centers=40)
    sp = split_setup(p, gal)
    rng = np.random.default_rng(3)
    c = np.repeat([0.85, 1.15], 3)
    Y = gal.solve(0.1 * rng.normal(size=(6, gal.dim)), c, p.DT, 6, substeps=sp["substeps"])
    flow, model, *_ = _fit_kernel(p, Y[:, :-1], Y[:, 1:], c, p.DT, quadratic=sp["quadratic"], gal=gal)
    assert type(model).__name__ == "SplitKernelPredictor" and 0 < model.n_centers_ <= 40
    x = Y[:2, 2]
    D = flow.step_jacobian(x, mu=c[:2, None], dt=p.DT)
    J = canonical_J(gal.dim)
    assert np.abs(np.swapaxes(D, 1, 2) @ J @ D - J).max() < 1e-8
    traj = flow.rollout(x, 3, mu=c[:2, None], dt=p.DT)
    y = x
    for k in range(3):
        y = flow.step(y, mu=c[:2, None], dt=p.DT)
        assert np.allclose(traj[:, k + 1], y, rtol=0, atol=1e-10)


@pytest.mark.filterwarnings("ignore::sympredict.exceptions.ExtrapolationWarning")  # the 10 T rollout leaves the data
def test_kernel_split_option_in_a_smoke_run():
    """``kernel_split`` reaches the Galerkin-data kernel only, is recorded in the results, and the split kernel
    runs and tracks the Galerkin ROM on the smoke case."""
    r = run_sine_gordon(PRESETS["smoke"], kernel_split="quadratic-mass", large_step=0, cost_N=(60,), repeats=1)
    assert r["preset"]["kernel_split"] == "quadratic-mass"
    res = r["dims"]["4"] if "4" in r["dims"] else r["dims"][4]
    k = res["kernel_reduced"]
    assert k["split"]["kind"] == "quadratic-mass" and k["split"]["substeps"] >= PRESETS["smoke"].substeps
    assert "split" not in res["kernel_projected"]
    assert k["failure"] is None and np.all(np.isfinite(k["error"]))
    gal = np.array(res["galerkin_error"])
    assert np.allclose(res["galerkin_error_split_substeps"], gal, rtol=0.1)  # both are the Galerkin ROM
    assert np.all(np.array(k["error"]) < 2 * gal)
    row = r["cost_vs_N"][0]
    assert row["kernel_error"] is not None and row["kernel"] > 0
