"""Finite-difference 1D wave equation as a pyMOR ``QuadraticHamiltonianModel`` (paper section 4.1).

``u_tt = mu u_zz`` on ``(0, L)``, homogeneous Dirichlet, ``N`` interior points,
``mu = c^2``.  With ``D`` the SPD central-difference matrix of ``-d^2/dz^2`` and
``x = (q, p) = (u, u_t)``,

    H(x; mu) = 1/2 p^T p + 1/2 mu q^T D q,      x' = J H(mu) x,   H(mu) = diag(mu D, I).

The pyMOR model's ``H_op`` is ``BlockDiagonalOperator([LincombOperator([D], [mu]), I])``
on the blocked phase space ``(q, p)``: affine in ``mu`` through the
``LincombOperator`` block.  (The equivalent top-level form
``mu * diag(D, 0) + diag(0, I)`` makes pyMOR 2026.1's implicit-midpoint solve
fail for ``N > 5``: ``to_matrix`` has no rule for the ``FixedParameterOperator``
it builds; the block form gives a ``BlockOperator`` that pyMOR inverts with
SciPy, and the symplectic reductor still returns an affine ``LincombOperator``.)
Reference trajectories use implicit midpoint with micro step ``<= 1e-3``
(sparse LU, factored once per ``mu``); the exact propagator (sine transform,
the system is linear) verifies them.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sps
from scipy.sparse.linalg import splu

from sympredict._checks import as_parameter, as_positive_int, as_real, as_states, as_steps
from sympredict.symplectic.integrators import micro_steps
from sympredict.symplectic.integrators_compiled import (
    PointwiseHamiltonian,
    csr_fill_dense,
    csr_matvec,
    jit_pointwise,
    unit_mass_grad_T,
)

__all__ = ["C_TRAIN", "C_REF", "DT_WAVE", "fd_laplacian", "laplacian_eigenvalues", "sine_modes", "WaveFOM"]

#: Training wave speeds, reference speed of the basis snapshots, and macro steps (paper).
C_TRAIN = (0.20, 0.22, 0.24, 0.26, 0.28, 0.30)
C_REF = 0.3
DT_WAVE = (0.1, 0.05, 0.025)


def fd_laplacian(n_points: int, length: float = 1.0) -> sps.csc_matrix:
    """SPD central-difference matrix of ``-d^2/dz^2``: ``tridiag(-1, 2, -1) / h^2``, ``h = L / (N + 1)``."""
    n_points = as_positive_int(n_points, "n_points")
    length = as_real(length, "length", positive=True)
    h = length / (n_points + 1)
    off = -np.ones(n_points - 1)
    return sps.diags([off, 2.0 * np.ones(n_points), off], [-1, 0, 1], format="csc") / h**2


def laplacian_eigenvalues(n_points: int, length: float = 1.0) -> np.ndarray:
    """Eigenvalues ``(2/h^2)(1 - cos(k pi h / L))``, ``k = 1..N``, of :func:`fd_laplacian`."""
    n_points = as_positive_int(n_points, "n_points")
    length = as_real(length, "length", positive=True)
    h = length / (n_points + 1)
    k = np.arange(1, n_points + 1)
    return (2.0 / h**2) * (1.0 - np.cos(k * np.pi * h / length))


def sine_modes(n_points: int, modes) -> np.ndarray:
    """Orthonormal eigenvectors ``sqrt(2/(N+1)) sin(k pi j / (N+1))`` of :func:`fd_laplacian`.

    Parameters
    ----------
    n_points
        ``N``.
    modes : int or array of int
        Mode numbers ``k`` (1-based); an int ``K`` means ``1..K``.

    Returns
    -------
    ndarray of shape (N, len(modes))
    """
    k = np.arange(1, modes + 1) if np.isscalar(modes) else np.asarray(modes)
    j = np.arange(1, n_points + 1)
    return np.sqrt(2.0 / (n_points + 1)) * np.sin(np.pi * np.outer(j, k) / (n_points + 1))


# Per-instance gradients for the compiled integrators (sympredict.symplectic.integrators_compiled):
# mu = (c^2,), fargs = D.data and iargs = (D.indptr, D.indices) of D in CSR; O(nnz(D)) per gradient.
@jit_pointwise
def _grad_V(q, mu, fargs, iargs, out):
    """``dV/dq = mu D q``."""
    csr_matvec(q, mu[0], fargs, iargs, out)


@jit_pointwise
def _grad_H(x, mu, fargs, iargs, out):
    """``(mu D q, p)``."""
    n = x.shape[0] // 2
    csr_matvec(x[:n], mu[0], fargs, iargs, out[:n])
    unit_mass_grad_T(x[n:], mu, fargs, iargs, out[n:])


@jit_pointwise
def _hess_H(x, mu, fargs, iargs, out):
    """``diag(mu D, I)``, dense (``O(N^2)`` writes: for small ``N``)."""
    n = x.shape[0] // 2
    out[:, :] = 0.0
    csr_fill_dense(n, mu[0], fargs, iargs, out)
    for j in range(n):
        out[n + j, n + j] = 1.0


class WaveFOM:
    """The wave full-order model: pyMOR model, sparse matrices and NumPy reference solvers.

    Parameters
    ----------
    n_points
        Interior grid points ``N`` (state dimension ``2N``).
    length
        Domain length ``L``.
    T
        Final time of the pyMOR model.
    mu_range
        Declared parameter range ``[c_min^2, c_max^2]``; queries outside raise ``ValueError``.
    dt_micro
        Micro step of the pyMOR model's implicit-midpoint time stepper.

    Attributes
    ----------
    model : pymor.models.symplectic.QuadraticHamiltonianModel
        The pyMOR FOM (parameter ``mu``, blocked phase space ``(q, p)``).
    parameter_space : pymor.parameters.base.ParameterSpace
    D : scipy.sparse.csc_matrix of shape (N, N)
    """

    def __init__(
        self,
        n_points: int = 1000,
        length: float = 1.0,
        T: float = 6.0,
        mu_range=(0.2**2, 0.3**2),
        dt_micro: float = 1e-3,
    ):
        from pymor.models.symplectic import QuadraticHamiltonianModel
        from pymor.operators.block import BlockDiagonalOperator
        from pymor.operators.constructions import IdentityOperator, LincombOperator
        from pymor.operators.numpy import NumpyMatrixOperator
        from pymor.parameters.functionals import ProjectionParameterFunctional

        self.n_points = as_positive_int(n_points, "n_points", minimum=2)
        length = as_real(length, "length", positive=True)
        T = as_real(T, "T", positive=True)
        dt_micro = as_real(dt_micro, "dt_micro", positive=True)
        if len(mu_range) != 2:
            raise ValueError(f"mu_range must be (min, max), got {mu_range!r}")
        lo, hi = (as_real(v, "mu_range") for v in mu_range)
        if not (0 < lo <= hi):
            raise ValueError(f"mu_range must satisfy 0 < min <= max, got {mu_range!r}")
        self.length = float(length)
        self.mu_range = (lo, hi)
        self.D = fd_laplacian(self.n_points, self.length)
        d_op = NumpyMatrixOperator(self.D, name="D")
        space = d_op.source
        H_op = BlockDiagonalOperator(
            [LincombOperator([d_op], [ProjectionParameterFunctional("mu")], name="mu_D"), IdentityOperator(space)],
            name="H",
        )
        self._space = space
        self.phase_space = H_op.source
        initial = self.to_pymor(self.unit_mode_state())
        self.model = QuadraticHamiltonianModel(T, initial, H_op, nt=int(micro_steps(T, dt_micro)), name="wave")
        self.parameter_space = self.model.parameters.space(lo, hi)

    @property
    def dim(self) -> int:
        """Phase-space dimension ``2N``."""
        return 2 * self.n_points

    # ------------------------------------------------------------ conversion
    def to_pymor(self, x):
        """NumPy states (B, 2N) ordered ``(q, p)`` -> pyMOR ``BlockVectorArray`` of length B."""
        x, _ = as_states(x, "x", dim=self.dim)
        n = self.n_points
        return self.phase_space.make_array([self._space.from_numpy(x[:, :n].T), self._space.from_numpy(x[:, n:].T)])

    def from_pymor(self, U) -> np.ndarray:
        """pyMOR ``BlockVectorArray`` -> NumPy states (len(U), 2N)."""
        if U.space != self.phase_space:
            raise ValueError(f"U must lie in {self.phase_space}, got {U.space}")
        return np.hstack([U.blocks[0].to_numpy().T, U.blocks[1].to_numpy().T])

    def check_mu(self, mu, n: int) -> np.ndarray:
        """Validated parameters (n,) inside the declared range (``ValueError`` otherwise)."""
        mu = as_parameter(mu, n, 1)[:, 0]
        lo, hi = self.mu_range
        tol = 1e-12 * hi
        if np.any(mu < lo - tol) or np.any(mu > hi + tol):
            raise ValueError(
                f"mu = c^2 must lie in the declared range [{lo:.6g}, {hi:.6g}] (c in [{np.sqrt(lo):.4g}, {np.sqrt(hi):.4g}]), "
                f"got {mu.min():.6g}..{mu.max():.6g}"
            )
        return mu

    # ------------------------------------------------------------ physics
    def hamiltonian_matrix(self, mu: float) -> sps.csc_matrix:
        """``H(mu) = diag(mu D, I)``, sparse (2N, 2N)."""
        return sps.block_diag([as_real(mu, "mu") * self.D, sps.identity(self.n_points)], format="csc")

    def hamiltonian(self, x, mu) -> np.ndarray:
        """Energies (B,) of states (B, 2N)."""
        x, _ = as_states(x, "x", dim=self.dim)
        mu = as_parameter(mu, len(x), 1)[:, 0]
        n = self.n_points
        q, p = x[:, :n], x[:, n:]
        return 0.5 * np.einsum("bi,bi->b", p, p) + 0.5 * mu * np.einsum("bi,bi->b", q, (self.D @ q.T).T)

    def gradient(self, x, mu) -> np.ndarray:
        """``grad H = (mu D q, p)``, shape (B, 2N), for states (B, 2N); ``O(B nnz(D))``."""
        x, _ = as_states(x, "x", dim=self.dim)
        mu = self.check_mu(mu, len(x))
        n = self.n_points
        return np.hstack([mu[:, None] * (self.D @ x[:, :n].T).T, x[:, n:]])

    def hessian(self, x, mu) -> np.ndarray:
        """``diag(mu D, I)`` per instance, dense (B, 2N, 2N): for implicit midpoint on small ``N`` only."""
        x, _ = as_states(x, "x", dim=self.dim)
        mu = self.check_mu(mu, len(x))
        n = self.n_points
        hess = np.zeros((len(x), self.dim, self.dim))
        hess[:, :n, :n] = mu[:, None, None] * self.D.toarray()[None]
        hess[:, n:, n:] = np.eye(n)[None]
        return hess

    def pointwise(self) -> PointwiseHamiltonian:
        """Per-instance gradients for :func:`sympredict.symplectic.integrators_compiled.rollout` (compiled with numba).

        Separable (``T = p^T p / 2``, ``V = mu q^T D q / 2``): every scheme
        applies; ``grad V`` is a CSR matrix-vector product, ``O(nnz(D))``.
        Implicit midpoint solves with a dense ``2N x 2N`` Jacobian,
        ``O(N^3)`` per Newton iteration: for small ``N``
        (:meth:`trajectory` is the sparse solver for this linear system).
        """
        return PointwiseHamiltonian.unit_mass_csr(
            self.D,
            grad_V=_grad_V,
            grad_H=_grad_H,
            hess_H=_hess_H,
            check_mu=lambda mu: self.check_mu(mu, len(mu)),
            name=f"WaveFOM(N={self.n_points})",
        )

    def unit_mode_state(self, k: int = 1) -> np.ndarray:
        """Displacement ``sin(k pi z)`` (unit amplitude), zero velocity; shape (2N,)."""
        z = np.linspace(0, self.length, self.n_points + 2)[1:-1]
        return np.concatenate([np.sin(k * np.pi * z / self.length), np.zeros(self.n_points)])

    def reference_energy(self, mu: float) -> float:
        """Energy of :meth:`unit_mode_state` (fundamental mode, unit amplitude) at ``mu``: the sampling bound."""
        return float(self.hamiltonian(self.unit_mode_state()[None], mu)[0])

    def low_frequency_states(self, n_states: int, n_modes: int, mu: float, energy: float, seed: int = 0) -> np.ndarray:
        """Random states in the first ``n_modes`` sine modes, uniform in ``{H(x; mu) <= energy}``.

        In modal coordinates ``q = sum a_k phi_k``, ``p = sum b_k phi_k`` the
        energy is ``1/2 sum (b_k^2 + mu lambda_k a_k^2)``: an ellipsoid, sampled
        uniformly (uniform direction, radius ``U^(1/(2K))``).  The bound makes
        higher modes smaller (``|a_k| <= sqrt(2 E / (mu lambda_k))``): low frequency.

        Returns
        -------
        ndarray of shape (n_states, 2N)
        """
        n_states = as_positive_int(n_states, "n_states")
        n_modes = as_positive_int(n_modes, "n_modes")
        mu = as_real(mu, "mu", positive=True)
        energy = as_real(energy, "energy", positive=True)
        if n_modes > self.n_points:
            raise ValueError(f"n_modes must be <= n_points = {self.n_points}, got {n_modes}")
        rng = np.random.default_rng(seed)
        z = rng.normal(size=(n_states, 2 * n_modes))
        z *= (rng.uniform(size=(n_states, 1)) ** (1.0 / (2 * n_modes))) / np.linalg.norm(z, axis=1, keepdims=True)
        lam = laplacian_eigenvalues(self.n_points, self.length)[:n_modes]
        a = z[:, :n_modes] * np.sqrt(2 * energy / (mu * lam))
        b = z[:, n_modes:] * np.sqrt(2 * energy)
        phi = sine_modes(self.n_points, n_modes)
        return np.hstack([a @ phi.T, b @ phi.T])

    def trajectory(self, x0, mu, dt, n_steps: int, h_max: float = 1e-3) -> np.ndarray:
        """Reference trajectories by implicit midpoint, micro step ``dt / ceil(dt / h_max)``.

        ``(I - h/2 A) x_{k+1} = (I + h/2 A) x_k`` with ``A = J H(mu)``, sparse LU
        factored once per distinct ``mu``; all instances of that ``mu`` advance together.

        Parameters
        ----------
        x0 : array_like of shape (B, 2N)
        mu : float or array_like of shape (B,)
        dt : float
            Macro step (output spacing).
        n_steps : int
            Number of macro steps.

        Returns
        -------
        ndarray of shape (B, K+1, 2N)
        """
        x0, single = as_states(x0, "x0", dim=self.dim)
        mu = self.check_mu(mu, len(x0))
        dt = float(as_steps(dt, 1)[0])
        n_steps = as_positive_int(n_steps, "n_steps", minimum=0)
        n_micro = int(micro_steps(dt, h_max))
        h = dt / n_micro
        n = self.n_points
        traj = np.empty((len(x0), n_steps + 1, self.dim))
        traj[:, 0] = x0
        for m in np.unique(mu):
            sel = mu == m
            # A = J H(mu) = [[0, I], [-mu D, 0]]
            A = sps.bmat([[None, sps.identity(n)], [-m * self.D, None]], format="csc")
            eye = sps.identity(2 * n, format="csc")
            lu = splu((eye - 0.5 * h * A).tocsc())
            rhs_op = (eye + 0.5 * h * A).tocsr()
            x = x0[sel].T.copy()
            for k in range(n_steps):
                for _ in range(n_micro):
                    x = lu.solve(rhs_op @ x)
                traj[sel, k + 1] = x.T
        return traj[0] if single else traj

    def exact_trajectory(self, x0, mu, dt, n_steps: int) -> np.ndarray:
        """Exact trajectories via the sine transform (modal frequencies ``sqrt(mu lambda_k)``), (B, K+1, 2N)."""
        x0, single = as_states(x0, "x0", dim=self.dim)
        mu = self.check_mu(mu, len(x0))
        dt = float(as_steps(dt, 1)[0])
        n_steps = as_positive_int(n_steps, "n_steps", minimum=0)
        n = self.n_points
        phi = sine_modes(n, n)
        qh, ph = x0[:, :n] @ phi, x0[:, n:] @ phi
        omega = np.sqrt(mu[:, None] * laplacian_eigenvalues(n, self.length)[None, :])
        t = float(dt) * np.arange(n_steps + 1)
        c = np.cos(omega[:, None, :] * t[None, :, None])
        s = np.sin(omega[:, None, :] * t[None, :, None])
        q = c * qh[:, None, :] + s * (ph / omega)[:, None, :]
        p = -s * (omega * qh)[:, None, :] + c * ph[:, None, :]
        traj = np.concatenate([q @ phi.T, p @ phi.T], axis=2)
        return traj[0] if single else traj
