"""Assertions for your own pytest suites: symplectic steps, bounded energy, ROM vs FOM, symplectic bases.

Each raises ``AssertionError`` with a message that names the worst instance
and the measured value against the tolerance, e.g. ::

    from sympredict.testing import assert_symplectic_step, assert_energy_bounded

    def test_my_model_is_symplectic(model, states):
        assert_symplectic_step(model, states, mu=0.75, dt=0.05)

    def test_energy(model, system, x0):
        traj = model.rollout(x0, 10_000, mu=0.75, dt=0.05)
        assert_energy_bounded(system.hamiltonian, traj, mu=0.75, rtol=1e-3)

A *model* here is anything with ``step(x, mu=, dt=)`` and (for the analytic
check) ``step_jacobian(x, mu=, dt=)``: a fitted
:class:`~sympredict.SymplecticKernelPredictor`, or the flow map of a
:class:`~sympredict.mor.SymplecticKernelModel` (``rom.flow_map``).
"""

from __future__ import annotations

from typing import Callable, Optional, Sequence

import warnings

import numpy as np

from sympredict.exceptions import ExtrapolationWarning
from sympredict.symplectic.metrics import canonical_J
from sympredict.mor.basis import symplecticity_of_basis
from sympredict.mor.mass import MassMatrixCoordinates

__all__ = [
    "assert_symplectic_step",
    "assert_energy_bounded",
    "assert_rom_matches_fom",
    "assert_symplectic_basis",
    "fe_wave_matrices",
    "fe_wave_model",
    "finite_difference_jacobian",
]


def finite_difference_jacobian(step: Callable, x: np.ndarray, h: float = 1e-4) -> np.ndarray:
    """Central-difference Jacobian of a batched map ``step (B, 2n) -> (B, 2n)``, Richardson-extrapolated; (B, 2n, 2n).

    Per component the step is ``h * (|x_i| + 1e-2 |x|_inf)`` (components of
    very different sizes each get a relative step); ``(4 D(h/2) - D(h)) / 3``
    removes the ``O(h^2)`` term.  ``4 * 2n`` batched calls of ``step``.
    """
    x = np.atleast_2d(np.asarray(x, dtype=float))
    b, d = x.shape
    base = h * (np.abs(x) + 1e-2 * np.abs(x).max(axis=1, keepdims=True) + np.finfo(float).tiny)

    def central(hh):
        cols = []
        for i in range(d):
            e = np.zeros((b, d))
            e[:, i] = hh[:, i]
            cols.append((step(x + e) - step(x - e)) / (2 * hh[:, i : i + 1]))
        return np.stack(cols, axis=2)

    return (4 * central(base / 2) - central(base)) / 3


def _defect(jac: np.ndarray) -> np.ndarray:
    J = canonical_J(jac.shape[-1])
    return np.abs(np.swapaxes(jac, -1, -2) @ J @ jac - J).max(axis=(-2, -1))


def _scaled_finite_differences(step: Callable, x: np.ndarray, h: float):
    """Central differences with one step per state scaled to its size, ``h * max(|x|_inf, tiny)``.

    Returns the Richardson-extrapolated Jacobian ``(4 D(h/2) - D(h)) / 3`` (B, 2n, 2n), the error estimate
    ``max |D(h/2) - D(h)|`` per state (B,) (truncation and the map's own noise, e.g. a Newton tolerance,
    both show in it) and the steps (B,).
    """
    b, d = x.shape
    steps = h * np.maximum(np.abs(x).max(axis=1), np.finfo(float).tiny ** 0.25)

    def central(hh):
        cols = []
        for i in range(d):
            e = np.zeros((b, d))
            e[:, i] = hh
            cols.append((step(x + e) - step(x - e)) / (2 * hh[:, None]))
        return np.stack(cols, axis=2)

    full, half = central(steps), central(steps / 2)
    return (4 * half - full) / 3, np.abs(half - full).max(axis=(1, 2)), steps


def assert_symplectic_step(
    model, x, mu=None, dt=None, atol: float = 1e-8, fd: bool = True, fd_h: float = 1e-4, fd_atol: Optional[float] = None
) -> dict:
    """Assert ``D Phi^T J D Phi = J`` for the learned step at the states ``x``.

    With an analytic Jacobian (``model.step_jacobian``, e.g. a fitted predictor or ``rom.flow_map``) the
    verdict is on it, to ``atol`` (max-norm); with ``fd`` a central-difference Jacobian of ``model.step``
    must then agree with it (a wrong ``step_jacobian`` fails).  Without one, the finite-difference Jacobian
    itself is checked.  Finite differences: one step per state, ``fd_h * max|x|`` (scaled to the state's
    size), Richardson-extrapolated; their error is estimated from the two step sizes (it includes the
    map's own noise, e.g. an implicit step's Newton tolerance), and the tolerance follows from it
    (``4 * estimate + 100 eps max(1, |D Phi|)`` on the Jacobian; on the defect
    ``2n (2 |D Phi| tol + tol^2) + atol``), unless ``fd_atol`` fixes it (then ``fd_atol * max(1, |D Phi|)``).
    A failure message says which Jacobian failed and, for finite differences, the step and error estimate.

    Parameters
    ----------
    model
        Has ``step(x, mu=, dt=)``; optionally ``step_jacobian(x, mu=, dt=)``.
    x : array_like of shape (B, 2n)
    mu, dt
        As the model's ``step`` takes them (fixed for the batch).
    atol : float
        Bound on the analytic Jacobian's defect.
    fd : bool
        Compute the finite-difference Jacobian (always, when the model has no ``step_jacobian``).
    fd_h : float
        Relative finite-difference step.
    fd_atol : float, optional
        A fixed tolerance on the finite-difference Jacobian instead of the derived one.

    Returns
    -------
    dict
        ``analytic`` (max defect of ``step_jacobian``, if any), ``finite_differences`` (max defect of the
        finite-difference Jacobian), ``fd_error`` (largest error estimate), ``method`` (``"analytic"``,
        ``"analytic+finite_differences"`` or ``"finite_differences"``).

    ``ExtrapolationWarning`` is silenced here: the perturbed states may leave
    the training box by ``fd_h``.
    """
    x = np.atleast_2d(np.asarray(x, dtype=float))
    with warnings.catch_warnings():
        # the perturbed states of the finite differences may leave the training box by a hair
        warnings.simplefilter("ignore", ExtrapolationWarning)
        return _symplectic_step(model, x, mu, dt, atol, fd, fd_h, fd_atol)


def _symplectic_step(model, x, mu, dt, atol, fd, fd_h, fd_atol) -> dict:
    out = {}
    jac = None
    if callable(getattr(model, "step_jacobian", None)):
        jac = np.asarray(model.step_jacobian(x, mu=mu, dt=dt)).reshape(len(x), x.shape[1], x.shape[1])
        d = _defect(jac)
        i = int(np.argmax(d))
        out["analytic"], out["method"] = float(d[i]), "analytic"
        if not d[i] <= atol:
            raise AssertionError(
                f"the step is not symplectic: max |DPhi^T J DPhi - J| = {d[i]:.3e} > atol = {atol:.1e} "
                f"(analytic Jacobian, model.step_jacobian) at state #{i} {x[i].tolist()}"
            )
    if not fd and jac is not None:
        return out
    fdj, err, steps = _scaled_finite_differences(lambda z: np.asarray(model.step(z, mu=mu, dt=dt)), x, fd_h)
    size = np.maximum(1.0, np.abs(fdj).max(axis=(1, 2)))
    tol = fd_atol * size if fd_atol is not None else 4 * err + 100 * np.finfo(float).eps * size
    how = (
        "finite-difference Jacobian: central differences, step {h:.2e} (= fd_h * max|x|), estimated error "
        "{e:.2e}, tolerance {t:.2e}" + (" (fd_atol)" if fd_atol is not None else " (from the error estimate)")
    )

    def where(i: int) -> str:  # how state i's Jacobian was checked, and the state
        return f" ({how.format(h=steps[i], e=err[i], t=tol[i])}) at state #{i} {x[i].tolist()}"

    out["fd_error"] = float(err.max())
    if jac is None:
        d = _defect(fdj)
        bound = x.shape[1] * (2 * size * tol + tol**2) + atol
        i = int(np.argmax(d / bound))
        out["finite_differences"], out["method"] = float(d[i]), "finite_differences"
        if not d[i] <= bound[i]:
            raise AssertionError(
                f"the step is not symplectic: max |DPhi^T J DPhi - J| = {d[i]:.3e} > {bound[i]:.2e}" + where(i)
            )
        return out
    out["finite_differences"], out["method"] = float(_defect(fdj).max()), "analytic+finite_differences"
    gap = np.abs(fdj - jac).max(axis=(1, 2))
    i = int(np.argmax(gap / tol))
    if not gap[i] <= tol[i]:
        raise AssertionError(
            f"step_jacobian disagrees with the finite-difference Jacobian of step by {gap[i]:.3e}" + where(i)
        )
    return out


def assert_energy_bounded(hamiltonian: Callable, trajectories, mu=None, rtol: float = 1e-3, atol: float = 0.0) -> float:
    """Assert ``|H(x_k) - H(x_0)| <= rtol |H(x_0)| + atol`` along trajectories (e.g. a long rollout).

    Parameters
    ----------
    hamiltonian : callable ``(x (M, 2n), mu) -> (M,)``
        E.g. ``system.hamiltonian``; called with ``mu`` repeated per state when ``mu`` is not None.
    trajectories : ndarray of shape (B, K+1, 2n) or (K+1, 2n)

    Returns
    -------
    float
        The largest relative energy error.
    """
    traj = np.asarray(trajectories, dtype=float)
    if traj.ndim == 2:
        traj = traj[None]
    b, k1, d = traj.shape
    if not np.all(np.isfinite(traj)):
        bad = np.argwhere(~np.isfinite(traj).all(axis=2))[0]
        raise AssertionError(f"trajectory #{bad[0]} is not finite from step {bad[1]} on")
    flat = traj.reshape(-1, d)
    if mu is None:
        energy = np.asarray(hamiltonian(flat)).reshape(b, k1)
    else:
        m = np.asarray(mu, dtype=float)
        m = (
            np.repeat(m.reshape(b, -1), k1, axis=0)
            if m.ndim and m.shape[0] == b and b > 1
            else np.broadcast_to(m.reshape(1, -1), (b * k1, m.size))
        )
        energy = np.asarray(hamiltonian(flat, m if m.shape[1] > 1 else m[:, 0])).reshape(b, k1)
    err = np.abs(energy - energy[:, :1])
    bound = rtol * np.abs(energy[:, :1]) + atol
    worst = np.unravel_index(np.argmax(err - bound), err.shape)
    rel = err / np.maximum(np.abs(energy[:, :1]), np.finfo(float).tiny)
    if np.any(err > bound):
        raise AssertionError(
            f"energy error not bounded: |H(x_k) - H(x_0)| = {err[worst]:.3e} > "
            f"{bound[worst[0], 0]:.3e} (rtol {rtol:.1e}, atol {atol:.1e}) in trajectory #{worst[0]} at "
            f"step {worst[1]} of {k1 - 1} (H(x_0) = {energy[worst[0], 0]:.6g})"
        )
    return float(rel.max())


def assert_rom_matches_fom(
    fom, rom, mus: Sequence, rtol: float, reconstruct: Optional[Callable] = None, stride: Optional[int] = None
) -> list:
    """Assert ``|u_fom(t_k) - V u_rom(t_k)| <= rtol max_k |u_fom(t_k)|`` on the ROM's time grid for each ``mu``.

    Parameters
    ----------
    fom, rom : pyMOR models
        ``rom.solve(mu)`` gives states at ``t_k = k T / (len - 1)``; ``fom.solve(mu)`` on a finer grid
        that contains the ROM's (every ``stride``-th FOM state; inferred from the lengths).
    mus : sequence of pyMOR Mu
    reconstruct : callable, optional
        ``U_red -> VectorArray in fom.solution_space`` (e.g. ``reductor.reconstruct``); default identity.

    Returns
    -------
    list of float
        Per ``mu``, the largest error relative to the largest FOM state norm.
    """
    errors = []
    for mu in mus:
        U = fom.solve(mu)
        R = rom.solve(mu)
        R = reconstruct(R) if reconstruct is not None else R
        s = stride
        if s is None:
            s = (len(U) - 1) // max(1, len(R) - 1)
            if s < 1 or (len(R) - 1) * s > len(U) - 1:
                raise AssertionError(f"cannot align the ROM's {len(R)} states with the FOM's {len(U)}: pass stride")
        Uc = U[::s][: len(R)]
        if len(Uc) != len(R):
            raise AssertionError(f"the FOM grid (every {s}-th of {len(U)}) does not cover the ROM's {len(R)} states")
        err = (Uc - R).norm()
        scale = Uc.norm().max()
        k = int(np.argmax(err))
        rel = float(err[k] / scale)
        errors.append(rel)
        if not rel <= rtol:
            raise AssertionError(
                f"ROM differs from FOM at mu = {mu}, time index {k} (of {len(R) - 1}): "
                f"|u_fom - V u_rom| / max|u_fom| = {rel:.3e} > rtol = {rtol:.1e}"
            )
    return errors


def assert_symplectic_basis(V, atol: float = 1e-10) -> float:
    """Assert ``V^T J_2N V = J_2n`` (max-norm ``atol``) for an ndarray (2N, 2n), ``ComplexSVDBasis`` or pyMOR ``SymplecticBasis``.

    A transposed ndarray basis fails with a message saying so.
    """
    try:
        defect = symplecticity_of_basis(V)
    except ValueError as exc:
        raise AssertionError(f"not a valid basis: {exc}") from None
    if not defect <= atol:
        raise AssertionError(f"the basis is not symplectic: max |V^T J V - J| = {defect:.3e} > atol = {atol:.1e}")
    return defect


def fe_wave_matrices(n_elements: int = 64, length: float = 1.0):
    """P1 finite-element mass and stiffness matrices of ``u_tt = c^2 u_xx`` on ``(0, length)``, ``u = 0`` at both ends.

    Linear elements on a uniform mesh of ``n_elements`` cells; the ``N = n_elements - 1`` interior nodes
    are the unknowns.  Consistent mass ``M = h/6 tridiag(1, 4, 1)``, stiffness ``K = 1/h tridiag(-1, 2, -1)``.

    Returns
    -------
    M, K : scipy.sparse.csr_matrix of shape (N, N)
        Symmetric positive definite.
    nodes : ndarray of shape (N,)
        Coordinates of the interior nodes.
    """
    import scipy.sparse

    n_elements = int(n_elements)
    if n_elements < 2:
        raise ValueError(f"n_elements must be >= 2 (one interior node), got {n_elements}")
    h = float(length) / n_elements
    N = n_elements - 1
    ones = np.ones(N - 1)
    M = scipy.sparse.diags([ones, np.full(N, 4.0), ones], [-1, 0, 1]).tocsr() * (h / 6)
    K = scipy.sparse.diags([-ones, np.full(N, 2.0), -ones], [-1, 0, 1]).tocsr() / h
    return M, K, np.linspace(h, length - h, N)


def fe_wave_model(n_elements: int = 64, T: float = 2.0, nt: int = 400, lumped: bool = False, c_range=(0.8, 1.2)):
    """A parametric finite-element wave model with a mass matrix, as a pyMOR model in canonical coordinates.

    ``M q'' = -c^2 K q`` (:func:`fe_wave_matrices`), ``p = M q'``, ``c`` (the wave speed, parameter ``"c"``)
    in ``c_range``; initial data a smooth bump ``q(0)`` (centre 0.4, half-width 0.35), ``q'(0) = 0``.  The model is a pyMOR
    ``QuadraticHamiltonianModel`` in the coordinates ``q~ = L^T q``, ``p~ = L^-1 p``
    (:class:`~sympredict.mor.mass.MassMatrixCoordinates`), ``H = blockdiag(c^2 L^-1 K L^-T, I)``,
    stepped by pyMOR's implicit midpoint rule with ``nt`` steps over ``T``.

    Returns
    -------
    fom : pymor.models.symplectic.QuadraticHamiltonianModel
        Solution space: two blocks ``(q~, p~)`` of dimension ``N = n_elements - 1``.
    coords : MassMatrixCoordinates
        ``coords.from_canonical(q~, p~)`` gives the physical ``(q, p)``.
    parameter_space : pyMOR ParameterSpace
        ``c`` in ``c_range``.
    """
    from pymor.models.symplectic import QuadraticHamiltonianModel
    from pymor.operators.block import BlockDiagonalOperator
    from pymor.operators.constructions import IdentityOperator, LincombOperator
    from pymor.operators.numpy import NumpyMatrixOperator
    from pymor.parameters.functionals import ExpressionParameterFunctional
    from pymor.vectorarrays.numpy import NumpyVectorSpace

    M, K, nodes = fe_wave_matrices(n_elements)
    coords = MassMatrixCoordinates(M, lumped=lumped)
    space = NumpyVectorSpace(coords.N)
    stiff = LincombOperator(
        [NumpyMatrixOperator(coords.canonical_stiffness(K))], [ExpressionParameterFunctional("c[0]**2", {"c": 1})]
    )
    H_op = BlockDiagonalOperator([stiff, IdentityOperator(space)])
    s = np.clip(np.abs(nodes - 0.4) / 0.35, 0.0, 1.0)
    q0 = (1 - s) ** 3 * (1 + 3 * s)  # a C^2 bump of half-width 0.35
    qt, pt = coords.to_canonical(q0, np.zeros_like(q0))
    initial = H_op.source.make_array([space.make_array(qt), space.make_array(pt)])
    fom = QuadraticHamiltonianModel(T, initial, H_op, nt=nt, name="fe_wave")
    return fom, coords, fom.parameters.space(*c_range)
