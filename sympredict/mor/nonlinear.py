"""Intrusive reduced models of the sine-Gordon FOM: symplectic Galerkin and DEIM hyper-reduction.

With a symplectic basis ``V = [Vq; Vp]`` (2N, 2n) (``V^T J V = J``, e.g.
:func:`sympredict.mor.basis.complex_svd_basis`) and ``y`` the reduced state,
both reduced models have the vector field

    y' = J g(y),   g(y) = (c^2 A1 + A2) y + s W sin(S y),

with ``A1 = Vq^T D Vq`` and ``A2 = Vp^T Vp`` (2n, 2n, precomputed) and

* **Galerkin** (:meth:`ReducedSineGordon.galerkin`): ``S = Vq`` (N, 2n),
  ``W = Vq^T``: ``g = V^T grad H(V y)`` is the gradient of ``H(V y)``, so the
  ROM is Hamiltonian, symplectic schemes stay symplectic, and each evaluation
  costs ``O(N n)`` (lift, ``sin``, project);
* **DEIM** (:meth:`ReducedSineGordon.deim`): the nonlinear term ``sin(q)`` is
  replaced by its empirical interpolation ``U (P^T U)^{-1} P^T sin(q)`` (pyMOR's
  :func:`~pymor.algorithms.ei.deim`, ``m`` POD modes ``U`` of ``sin(q)``
  snapshots, interpolation rows ``P``): ``S = P^T Vq`` (m, 2n),
  ``W = Vq^T U (P^T U)^{-1}`` (2n, m), ``O(m n + n^2)`` per evaluation,
  independent of ``N``.  Its Jacobian ``s W diag(cos(S y)) S`` is not
  symmetric in general, so ``g`` is no gradient: **the DEIM ROM is not
  Hamiltonian, and implicit midpoint on it is not symplectic**
  (:meth:`ReducedSineGordon.gradient_asymmetry` measures it; the tests check
  it against the Galerkin ROM's round-off symmetry).

The complex-SVD basis mixes ``q`` and ``p`` in every reduced coordinate, so
``g`` is not separable and the explicit symplectic compositions (Störmer–Verlet,
Yoshida, Kahan–Li) do not apply: the reduced models run with the compiled
implicit midpoint of :mod:`sympredict.symplectic.integrators_compiled` (through
:meth:`ReducedSineGordon.pointwise`) or the compiled classical RK4 of
:func:`rk4_rollout` (not symplectic; the usual large-step competitor).
"""

from __future__ import annotations

import numpy as np

from sympredict._checks import as_positive_int, as_states, as_steps
from sympredict._numba import JIT, compilable, jit_cached
from sympredict.symplectic.integrators_compiled import HAVE_NUMBA, PointwiseHamiltonian, jit_pointwise, rollout
from sympredict.systems.linear_flow import QuadraticPart
from sympredict.mor.basis import symplectic_inverse


__all__ = ["ReducedSineGordon", "rk4_rollout", "nonlinear_snapshots"]


# fargs = (s, A1 (r*r), A2 (r*r), S (m*r), W (r*m)); iargs = (r, m); mu = (c,).
@compilable
def _packed(mu, fargs, iargs):
    """``(r, m, c^2, s)`` and the offsets ``(a1, a2, so, wo)`` of ``A1, A2, S, W`` in ``fargs``."""
    r, m = iargs[0], iargs[1]
    return r, m, mu[0] * mu[0], fargs[0], 1, 1 + r * r, 1 + 2 * r * r, 1 + 2 * r * r + m * r


@compilable
def _sine_argument(y, fargs, so, r, k):
    """``(S y)_k``; ``O(r)``."""
    z = 0.0
    for j in range(r):
        z += fargs[so + k * r + j] * y[j]
    return z


@jit_pointwise
def _g(y, mu, fargs, iargs, out):
    """``g(y) = (c^2 A1 + A2) y + s W sin(S y)``; ``O(r^2 + m r)``."""
    r, m, c2, s, a1, a2, so, wo = _packed(mu, fargs, iargs)
    for i in range(r):
        acc = 0.0
        for j in range(r):
            acc += (c2 * fargs[a1 + i * r + j] + fargs[a2 + i * r + j]) * y[j]
        out[i] = acc
    for k in range(m):
        sk = s * np.sin(_sine_argument(y, fargs, so, r, k))
        for i in range(r):
            out[i] += fargs[wo + i * m + k] * sk


@jit_pointwise
def _dg(y, mu, fargs, iargs, out):
    """Jacobian ``c^2 A1 + A2 + s W diag(cos(S y)) S`` (r, r); ``O(r^2 m)``."""
    r, m, c2, s, a1, a2, so, wo = _packed(mu, fargs, iargs)
    for i in range(r):
        for j in range(r):
            out[i, j] = c2 * fargs[a1 + i * r + j] + fargs[a2 + i * r + j]
    for k in range(m):
        ck = s * np.cos(_sine_argument(y, fargs, so, r, k))
        for i in range(r):
            wik = fargs[wo + i * m + k] * ck
            for j in range(r):
                out[i, j] += wik * fargs[so + k * r + j]


def _rk4_instance(i, g, fargs, iargs, x0, mu, h, n_steps, substeps, traj):
    """Classical RK4 on ``y' = J g(y)``, one instance."""
    dim = x0.shape[1]
    n = dim // 2
    y = x0[i].copy()
    tmp = np.empty(dim)
    k = np.empty((4, dim))
    gv = np.empty(dim)
    hs = h[i] / substeps
    mui = mu[i]
    for j in range(dim):
        traj[i, 0, j] = y[j]
    for step in range(n_steps):
        for _ in range(substeps):
            for st in range(4):
                a = 0.0 if st == 0 else (0.5 * hs if st < 3 else hs)
                for j in range(dim):
                    tmp[j] = y[j] + a * k[st - 1, j] if st > 0 else y[j]
                g(tmp, mui, fargs, iargs, gv)
                for j in range(n):  # J g = (g_p, -g_q)
                    k[st, j] = gv[n + j]
                    k[st, n + j] = -gv[j]
            for j in range(dim):
                y[j] += hs / 6.0 * (k[0, j] + 2.0 * k[1, j] + 2.0 * k[2, j] + k[3, j])
        for j in range(dim):
            traj[i, step + 1, j] = y[j]


def _rk4_all(g, fargs, iargs, x0, mu, h, n_steps, substeps, traj):
    for i in range(x0.shape[0]):
        _rk4_one(i, g, fargs, iargs, x0, mu, h, n_steps, substeps, traj)


if HAVE_NUMBA:
    _rk4_one = jit_cached(_rk4_instance, JIT)
    _rk4_all = jit_cached(_rk4_all, JIT)


def rk4_rollout(system: PointwiseHamiltonian, x0, mu, dt, n_steps: int, substeps: int = 1) -> np.ndarray:
    """Compiled classical RK4 on ``x' = J grad_H(x)`` of a :class:`PointwiseHamiltonian` (its ``grad_H``).

    Not symplectic; here as the standard explicit competitor.  ``O(B K r c)``
    for gradient cost ``c``; serial over instances.

    Returns
    -------
    ndarray of shape (B, K+1, 2n)
    """
    x0, single = as_states(x0, "x0", dim=system.dim)
    mu = np.ascontiguousarray(np.asarray(mu, dtype=float).reshape(len(x0), -1))
    system.check_mu(mu)
    h = np.ascontiguousarray(as_steps(dt, len(x0), name="dt"))
    n_steps = as_positive_int(n_steps, "n_steps", minimum=0)
    substeps = as_positive_int(substeps, "substeps")
    traj = np.empty((len(x0), n_steps + 1, system.dim))
    _rk4_all(system.grad_H, system.fargs, system.iargs, np.ascontiguousarray(x0), mu, h, n_steps, substeps, traj)
    return traj[0] if single else traj


def nonlinear_snapshots(fom, trajectories) -> np.ndarray:
    """``sin(q)`` of FOM states (..., 2N) as rows (K, N): the snapshots of DEIM's collateral basis."""
    x = np.asarray(trajectories).reshape(-1, fom.dim)
    return np.sin(x[:, : fom.n_points])


class ReducedSineGordon:
    """A reduced sine-Gordon model ``y' = J ((c^2 A1 + A2) y + s W sin(S y))`` (module docstring).

    Build with :meth:`galerkin` or :meth:`deim`.

    Attributes
    ----------
    V : ndarray (2N, 2n)
    A1, A2 : ndarray (2n, 2n)
    S : ndarray (m, 2n)
    W : ndarray (2n, m)
    interpolation_dofs : ndarray of int (m,) or None (Galerkin)
    kind : str
    """

    def __init__(self, fom, V, S, W, kind: str, interpolation_dofs=None):
        self.fom, self.V, self.kind = fom, np.ascontiguousarray(V), kind
        n = fom.n_points
        Vq, Vp = V[:n], V[n:]
        self.A1 = Vq.T @ (fom.D @ Vq)
        self.A2 = Vp.T @ Vp
        self.S, self.W = np.ascontiguousarray(S), np.ascontiguousarray(W)
        self.interpolation_dofs = interpolation_dofs
        self.dim = V.shape[1]

    @classmethod
    def galerkin(cls, fom, V) -> "ReducedSineGordon":
        """Symplectic Galerkin ROM ``y' = J V^T grad H(V y)``: ``O(N n)`` per evaluation."""
        Vq = V[: fom.n_points]
        return cls(fom, V, Vq, Vq.T, "galerkin")

    @classmethod
    def deim(cls, fom, V, nonlinear_snapshots, m: int) -> "ReducedSineGordon":
        """DEIM ROM with ``m`` interpolation points from snapshots of ``sin(q)`` (K, N) (pyMOR's ``deim``)."""
        from pymor.algorithms.ei import deim
        from pymor.vectorarrays.numpy import NumpyVectorSpace

        F = NumpyVectorSpace(fom.n_points).from_numpy(np.asarray(nonlinear_snapshots).T)
        dofs, basis, _ = deim(F, modes=m)
        U = basis.to_numpy()  # (N, m)
        dofs = np.asarray(dofs, dtype=int)
        Vq = V[: fom.n_points]
        W = Vq.T @ U @ np.linalg.inv(U[dofs])
        return cls(fom, V, Vq[dofs], W, "deim", dofs)

    @property
    def n_interpolation(self) -> int:
        """``m``: rows of ``S`` (``N`` for Galerkin)."""
        return self.S.shape[0]

    def pointwise(self) -> PointwiseHamiltonian:
        """Compiled ``g`` and its Jacobian for :func:`~sympredict.symplectic.integrators_compiled.rollout`
        (``scheme='implicit_midpoint'``) and :func:`rk4_rollout`; ``mu = (c,)``."""
        fargs = np.concatenate([[self.fom.strength], self.A1.ravel(), self.A2.ravel(), self.S.ravel(), self.W.ravel()])
        return PointwiseHamiltonian(
            self.dim,
            1,
            grad_H=_g,
            hess_H=_dg,
            fargs=fargs,
            iargs=[self.dim, self.n_interpolation],
            check_mu=lambda mu: self.fom.check_c(np.asarray(mu)[:, 0], len(mu)),
            name=f"{self.kind}ROM(2n={self.dim}, m={self.n_interpolation})",
        )

    def quadratic_part(self, mass: bool = True) -> QuadraticPart:
        """The Hessian of the reduced Hamiltonian ``H(V y; c)`` at ``y = 0`` as a
        :class:`~sympredict.systems.linear_flow.QuadraticPart` in ``c``: ``A(c) = (A2 + s Vq^T Vq) + c^2 A1`` (powers 0, 2).

        ``mass=False`` leaves out ``s Vq^T Vq``, the linearised ``s sum (1 - cos q)`` (then ``A`` is the quadratic
        part of ``H`` alone).  Its flow ``expm(t J A(c))`` is the linearised ROM; the splitting predictor
        (:mod:`sympredict.flowmap.splitting`) composes it with a learned map.  Galerkin only with ``mass=True``: the DEIM
        ROM's ``s W S`` is not symmetric (no Hamiltonian).  ``O(N n^2)``.
        """
        if mass and self.kind != "galerkin":
            raise ValueError(
                "the mass term of the reduced Hessian needs the Galerkin ROM (the DEIM ROM has no Hamiltonian)"
            )
        A0 = self.A2 + (self.fom.strength * (self.S.T @ self.S) if mass else 0.0)
        sym = lambda A: 0.5 * (A + A.T)  # noqa: E731  (round-off of the products)
        return QuadraticPart([sym(A0), sym(self.A1)], [[0.0], [2.0]])

    # -------------------------------------------------------------- NumPy (checks, small batches)
    def g(self, y, c) -> np.ndarray:
        """``g`` of reduced states (B, 2n)."""
        y = np.atleast_2d(y)
        c = self.fom.check_c(c, len(y))
        return (c**2)[:, None] * (y @ self.A1.T) + y @ self.A2.T + self.fom.strength * np.sin(y @ self.S.T) @ self.W.T

    def jacobian(self, y, c: float) -> np.ndarray:
        """``dg/dy`` at one reduced state (2n,), shape (2n, 2n)."""
        y = np.asarray(y, dtype=float)
        return c * c * self.A1 + self.A2 + self.fom.strength * (self.W * np.cos(self.S @ y)[None, :]) @ self.S

    def gradient_asymmetry(self, y, c: float) -> float:
        """``|dg - dg^T|_F / |dg|_F``: 0 (round-off) iff ``g`` is locally a gradient (a Hamiltonian ROM)."""
        Jg = self.jacobian(y, c)
        return float(np.linalg.norm(Jg - Jg.T) / np.linalg.norm(Jg))

    def reduced_energy(self, y, c) -> np.ndarray:
        """``dx H(V y)`` (B,): the FOM energy of the lifted states (``O(B N n)``)."""
        y = np.atleast_2d(y)
        return self.fom.energy(y @ self.V.T, c)

    def project(self, x) -> np.ndarray:
        """``V+ x = J^T V^T J x`` of full states (..., 2N) -> (..., 2n)."""
        return np.asarray(x) @ symplectic_inverse(self.V).T

    def reconstruct(self, y) -> np.ndarray:
        """``V y`` (..., 2n) -> (..., 2N)."""
        return np.asarray(y) @ self.V.T

    def solve(self, y0, c, dt, n_steps, scheme="implicit_midpoint", substeps=1) -> np.ndarray:
        """Reduced trajectories (B, K+1, 2n): ``scheme`` ``'implicit_midpoint'`` (compiled) or ``'rk4'``."""
        c = np.asarray(c, dtype=float).reshape(-1, 1)
        y0 = np.atleast_2d(y0)
        if c.shape[0] == 1:
            c = np.repeat(c, len(y0), axis=0)
        if scheme == "rk4":
            return rk4_rollout(self.pointwise(), y0, c, dt, n_steps, substeps)
        if scheme != "implicit_midpoint":
            raise ValueError(
                f"scheme must be 'implicit_midpoint' or 'rk4' (the reduced H is not separable), got {scheme!r}"
            )
        return rollout(self.pointwise(), y0, c, dt, n_steps, scheme=scheme, substeps=substeps)
