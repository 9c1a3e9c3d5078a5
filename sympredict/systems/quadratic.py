"""Quadratic Hamiltonians ``H(x; mu) = 1/2 x^T (H0 + mu H1) x`` in NumPy (small, dense).

Used for reduced models: pyMOR's reductor produces the reduced operator, and
:meth:`QuadraticHamiltonian.from_pymor` turns it into two dense ``2n x 2n``
matrices so that reduced trajectories are stepped in NumPy (pyMOR's time
stepping costs ~40 µs of overhead per step, more than a 4x4 step itself).

Since the system is linear, every flow is a matrix: the implicit-midpoint
step is the Cayley transform ``(I - h/2 A)^{-1} (I + h/2 A)`` of
``A = J H(mu)``, and the exact flow is ``expm(t A)``.  ``H(mu)`` and the exact
flow belong to a :class:`~sympredict.systems.linear_flow.QuadraticPart` with the
matrices ``(H0, H1)`` and the powers ``(0, 1)`` (:meth:`QuadraticHamiltonian.quadratic_part`):
this class adds the system's interface (energies, gradients, compiled
pointwise evaluation, reference and exact trajectories).
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import solve

from sympredict._checks import as_parameter, as_positive_int, as_real, as_real_array, as_states, as_steps
from sympredict.symplectic.metrics import canonical_J
from sympredict.symplectic.integrators import micro_steps
from sympredict.symplectic.integrators_compiled import PointwiseHamiltonian, jit_pointwise
from sympredict.systems.flowmaps import sample_energy_ellipsoid
from sympredict.systems.linear_flow import QuadraticPart

__all__ = ["QuadraticHamiltonian"]


# Per-instance gradients for the compiled integrators (sympredict.symplectic.integrators_compiled):
# fargs = (H0.ravel(), H1.ravel()) of the 2n x 2n matrices, iargs = (2n,), mu = (mu,);
# out = H0 z + mu H1 z on the block that z belongs to (the diagonal blocks for a separable H).
@jit_pointwise
def _block_matvec(z, mu, fargs, dim, offset, out):
    m = z.shape[0]
    off1 = dim * dim
    for j in range(m):
        s0 = 0.0
        s1 = 0.0
        row = (offset + j) * dim + offset
        for k in range(m):
            s0 += fargs[row + k] * z[k]
            s1 += fargs[off1 + row + k] * z[k]
        out[j] = s0 + mu[0] * s1


@jit_pointwise
def _grad_V(q, mu, fargs, iargs, out):
    """``dV/dq = (H0_qq + mu H1_qq) q``."""
    _block_matvec(q, mu, fargs, iargs[0], 0, out)


@jit_pointwise
def _grad_T(p, mu, fargs, iargs, out):
    """``dT/dp = (H0_pp + mu H1_pp) p``."""
    _block_matvec(p, mu, fargs, iargs[0], p.shape[0], out)


@jit_pointwise
def _grad_H(x, mu, fargs, iargs, out):
    """``(H0 + mu H1) x``."""
    _block_matvec(x, mu, fargs, iargs[0], 0, out)


@jit_pointwise
def _hess_H(x, mu, fargs, iargs, out):
    """``H0 + mu H1``."""
    dim = x.shape[0]
    off1 = dim * dim
    for j in range(dim):
        for k in range(dim):
            out[j, k] = fargs[j * dim + k] + mu[0] * fargs[off1 + j * dim + k]


class QuadraticHamiltonian:
    """``H(x; mu) = 1/2 x^T (H0 + mu H1) x`` with one scalar parameter.

    Parameters
    ----------
    H0, H1 : ndarray of shape (2n, 2n)
        Symmetric matrices.
    """

    n_mu = 1

    def __init__(self, H0: np.ndarray, H1: np.ndarray):
        H0 = as_real_array(H0, "H0")
        H1 = as_real_array(H1, "H1")
        if H0.ndim != 2 or H0.shape[0] != H0.shape[1] or H0.shape[0] % 2 or H0.shape != H1.shape:
            raise ValueError(f"H0 and H1 must be square of equal, even size, got {H0.shape} and {H1.shape}")
        for name, M in (("H0", H0), ("H1", H1)):
            if not np.allclose(M, M.T, atol=1e-12 * max(1.0, np.abs(M).max())):
                raise ValueError(f"{name} must be symmetric")
        self.H0 = 0.5 * (H0 + H0.T)
        self.H1 = 0.5 * (H1 + H1.T)
        self.dim = H0.shape[0]
        self.J = canonical_J(self.dim)

    @classmethod
    def from_pymor(cls, H_op) -> "QuadraticHamiltonian":
        """From a pyMOR operator affine in the scalar parameter ``mu`` (e.g. a reduced ``H_op``).

        Assembles the operator at ``mu = 0`` and ``mu = 1`` and checks the
        affine decomposition at ``mu = 0.5``.
        """
        from pymor.algorithms.to_matrix import to_matrix

        params = H_op.parameters
        if set(params) != {"mu"} or params["mu"] != 1:
            raise ValueError(f"expected an operator depending on one scalar parameter 'mu', got parameters {params}")
        mat = {v: np.asarray(to_matrix(H_op, mu=params.parse(v), format="dense")) for v in (0.0, 0.5, 1.0)}
        H0, H1 = mat[0.0], mat[1.0] - mat[0.0]
        if not np.allclose(H0 + 0.5 * H1, mat[0.5], atol=1e-10 * np.abs(mat[1.0]).max()):
            raise ValueError("the operator is not affine in mu")
        return cls(H0, H1)

    @property
    def separable(self) -> bool:
        """Whether the ``q``-``p`` blocks of ``H0`` and ``H1`` vanish (``H = T(p) + V(q)``: explicit schemes apply)."""
        n = self.dim // 2
        return not (np.any(self.H0[:n, n:]) or np.any(self.H1[:n, n:]))

    def pointwise(self) -> PointwiseHamiltonian:
        """Per-instance gradients and Hessian for :func:`sympredict.symplectic.integrators_compiled.rollout` (compiled with numba).

        ``grad_T`` / ``grad_V`` (the diagonal blocks) only when :attr:`separable`;
        ``grad_H`` / ``hess_H`` always.  ``O((2n)^2)`` per evaluation.
        """
        sep = self.separable
        return PointwiseHamiltonian(
            self.dim,
            1,
            grad_T=_grad_T if sep else None,
            grad_V=_grad_V if sep else None,
            grad_H=_grad_H,
            hess_H=_hess_H,
            fargs=np.concatenate([self.H0.ravel(), self.H1.ravel()]),
            iargs=(self.dim,),
            name=f"QuadraticHamiltonian(2n={self.dim})",
        )

    def quadratic_part(self) -> QuadraticPart:
        """``H(mu) = H0 + mu H1`` as a :class:`~sympredict.systems.linear_flow.QuadraticPart` (powers 0 and 1).

        It owns ``H(mu)`` and the exact flow ``expm(t J H(mu))`` (batched over
        ``mu`` and ``t``); :meth:`matrix` and :meth:`exact_propagator` use it.
        Built from the current ``H0``, ``H1`` on each call (it stores them, ``O((2n)^2)``).
        """
        return QuadraticPart(np.stack([self.H0, self.H1]), [[0.0], [1.0]])

    def matrix(self, mu: float) -> np.ndarray:
        """``H0 + mu H1``, shape (2n, 2n)."""
        return self.quadratic_part().hessian(as_real(mu, "mu"))[0]

    def hamiltonian(self, x, mu) -> np.ndarray:
        """Energies, shape (B,), for states (B, 2n) and parameters (B,) / (B, 1)."""
        x, _ = as_states(x, "x", dim=self.dim)
        mu = as_parameter(mu, len(x), 1)[:, 0]
        return 0.5 * (np.einsum("bi,ij,bj->b", x, self.H0, x) + mu * np.einsum("bi,ij,bj->b", x, self.H1, x))

    def gradient(self, x, mu) -> np.ndarray:
        """``(H0 + mu H1) x``, shape (B, 2n)."""
        mu = np.asarray(mu, dtype=float).reshape(len(x), -1)[:, :1]
        return x @ self.H0 + mu * (x @ self.H1)

    def hessian(self, x, mu) -> np.ndarray:
        """``H0 + mu H1`` per instance, shape (B, 2n, 2n)."""
        mu = np.asarray(mu, dtype=float).reshape(len(x), -1)[:, 0]
        return self.H0[None] + mu[:, None, None] * self.H1[None]

    def sample_energy_ellipsoid(self, n_samples: int, mu: float, energy: float, seed: int = 0) -> np.ndarray:
        """States uniform in ``{x : H(x; mu) <= energy}`` (an ellipsoid; ``H(mu)`` must be SPD).

        ``x = sqrt(2 energy) L^{-T} z`` with ``H(mu) = L L^T`` and ``z`` uniform
        in the unit ball (normal direction, radius ``U^(1/2n)``): exact and
        rejection-free in any dimension (:func:`sympredict.systems.flowmaps.sample_energy_ellipsoid`
        with ``numpy.random.default_rng(seed)``).

        Returns
        -------
        ndarray of shape (n_samples, 2n)
        """
        n_samples = as_positive_int(n_samples, "n_samples")
        return sample_energy_ellipsoid(self, n_samples, mu, energy, np.random.default_rng(seed))

    def midpoint_propagator(self, mu: float, h: float, n_steps: int = 1) -> np.ndarray:
        """Matrix of ``n_steps`` implicit-midpoint steps of size ``h``: ``((I - h/2 A)^{-1}(I + h/2 A))^n``."""
        h = as_real(h, "h", positive=True)
        n_steps = as_positive_int(n_steps, "n_steps", minimum=0)
        A = self.J @ self.matrix(mu)
        eye = np.eye(self.dim)
        step = solve(eye - 0.5 * h * A, eye + 0.5 * h * A)
        return np.linalg.matrix_power(step, int(n_steps))

    def exact_propagator(self, mu: float, t: float) -> np.ndarray:
        """``expm(t J H(mu))``, shape (2n, 2n) (:meth:`QuadraticPart.propagator <sympredict.systems.linear_flow.QuadraticPart.propagator>`)."""
        return self.quadratic_part().propagator(as_real(mu, "mu"), as_real(t, "t"))[0]

    def _grouped(self, x0, mu, t, propagator):
        x0, single = as_states(x0, "x0", dim=self.dim)
        b = len(x0)
        mu = as_parameter(mu, b, 1)[:, 0]
        t = as_steps(t, b, name="t")
        out = np.empty_like(x0)
        keys = np.stack([mu, t], axis=1)
        uniq, inverse = np.unique(keys, axis=0, return_inverse=True)
        for i, (m, tt) in enumerate(uniq):
            sel = inverse.ravel() == i
            out[sel] = x0[sel] @ propagator(m, tt).T
        return out[0] if single else out

    def flow(self, x0, mu, t, h_max: float = 1e-3) -> np.ndarray:
        """Reference flow: implicit midpoint with micro step ``t / ceil(t / h_max)``.

        One propagator matrix per distinct ``(mu, t)``; shape (B, 2n).
        """
        return self._grouped(
            x0, mu, t, lambda m, tt: self.midpoint_propagator(m, tt / micro_steps(tt, h_max), micro_steps(tt, h_max))
        )

    def exact_flow(self, x0, mu, t) -> np.ndarray:
        """Exact flow ``expm(t J H(mu)) x0``, shape (B, 2n)."""
        return self._grouped(x0, mu, t, self.exact_propagator)

    def trajectory(self, x0, mu, dt, n_steps: int, h_max: float = 1e-3, exact: bool = False) -> np.ndarray:
        """Trajectories on the macro grid ``t_k = k dt``, shape (B, K+1, 2n).

        Reference (implicit midpoint, micro step ``<= h_max``) or, with
        ``exact=True``, the exact flow.
        """
        n_steps = as_positive_int(n_steps, "n_steps", minimum=0)
        x0, single = as_states(x0, "x0", dim=self.dim)
        b = len(x0)
        mu = as_parameter(mu, b, 1)[:, 0]
        dt = as_steps(dt, b)
        traj = np.empty((b, n_steps + 1, self.dim))
        traj[:, 0] = x0
        uniq, inverse = np.unique(np.stack([mu, dt], axis=1), axis=0, return_inverse=True)
        for i, (m, d) in enumerate(uniq):
            sel = inverse.ravel() == i
            if exact:
                P = self.exact_propagator(m, d)
            else:
                n_micro = int(micro_steps(d, h_max))
                P = self.midpoint_propagator(m, d / n_micro, n_micro)
            x = x0[sel]
            for k in range(n_steps):
                x = x @ P.T
                traj[sel, k + 1] = x
        return traj[0] if single else traj
