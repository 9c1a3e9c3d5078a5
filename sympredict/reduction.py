"""Symplectic model order reduction on pyMOR: complex-SVD basis, projection, reconstruction.

Basis (PSD complex SVD, Peng & Mohseni 2016): with snapshots ``(Q, P)`` form
``X = Q + i P`` (``N x K`` complex), take its SVD ``X = U S W^H`` and the first
``n`` left singular vectors ``U_n``; then

    E = [Re U_n; Im U_n],    F = [-Im U_n; Re U_n],    V = [E, F] in R^{2N x 2n}

is orthonormal *and* symplectic (``V^T J_2N V = J_2n``) because ``U_n`` has
orthonormal complex columns.  We compute the SVD directly (LAPACK ``gesdd``)
and wrap ``E, F`` in pyMOR's ``SymplecticBasis``: pyMOR's ``psd_complex_svd``
goes through method-of-snapshots POD, which loses symplecticity to ~1e-11 and
drops the singular values, which we keep and report.

The symplectic inverse is ``V+ = J_2n^T V^T J_2N`` (``V+ V = I``; for this
orthosymplectic ``V`` it equals ``V^T``).  The reduced model comes from pyMOR's
``QuadraticHamiltonianRBReductor`` (``H_red(mu) = V^T H(mu) V``, affine in
``mu``), and is stepped in NumPy through :class:`~sympredict.systems.quadratic.QuadraticHamiltonian`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np
from pymor.core.logger import getLogger
from scipy.linalg import svd

from sympredict._checks import as_real_array
from sympredict.metrics import canonical_J
from sympredict.systems.quadratic import QuadraticHamiltonian

__all__ = ["ComplexSVDBasis", "complex_svd_basis", "symplectic_inverse", "symplecticity_of_basis", "SymplecticROM"]

logger = getLogger("sympredict.reduction")

#: Relative singular value below which a direction counts as outside the snapshot span.
_RANK_RTOL = 1e-12


@dataclass
class ComplexSVDBasis:
    """A symplectic basis and the singular values it was cut from.

    Attributes
    ----------
    V : ndarray of shape (2N, 2n)
        ``[E, F]``, rows ordered ``(q, p)``.
    singular_values : ndarray of shape (min(N, K),)
        All singular values of ``Q + i P``.
    n : int
        Number of complex modes kept (reduced dimension ``2n``).
    """

    V: np.ndarray
    singular_values: np.ndarray
    n: int

    @property
    def projection_error(self) -> float:
        """``sqrt(sum_{k>n} s_k^2 / sum_k s_k^2)``: relative snapshot projection error of the basis."""
        s2 = (self.singular_values / self.singular_values[0]) ** 2
        return float(np.sqrt(max(0.0, s2[self.n :].sum()) / s2.sum()))

    def to_pymor(self, phase_space):
        """The basis as pyMOR ``SymplecticBasis`` in ``phase_space`` (a 2-block ``BlockVectorSpace``)."""
        from pymor.algorithms.symplectic import SymplecticBasis

        big_n = self.V.shape[0] // 2
        q_space, p_space = phase_space.subspaces
        E = phase_space.make_array([q_space.from_numpy(self.V[:big_n, : self.n]), p_space.from_numpy(self.V[big_n:, : self.n])])
        F = phase_space.make_array([q_space.from_numpy(self.V[:big_n, self.n :]), p_space.from_numpy(self.V[big_n:, self.n :])])
        return SymplecticBasis(E, F)


def complex_svd_basis(snapshots: np.ndarray, n: Optional[int] = None, tol: Optional[float] = None) -> ComplexSVDBasis:
    """PSD complex-SVD symplectic basis from phase-space snapshots.

    Parameters
    ----------
    snapshots : ndarray of shape (K, 2N)
        Snapshot states ordered ``(q, p)``.
    n
        Number of complex modes (reduced dimension ``2n``).
    tol
        Alternatively, the smallest ``n`` whose relative projection error
        ``sqrt(sum_{k>n} s_k^2 / sum s_k^2)`` is ``<= tol``.

    Returns
    -------
    ComplexSVDBasis

    Raises
    ------
    ValueError
        If neither or both of ``n`` and ``tol`` are given, or ``n`` exceeds the
        numerical rank of the snapshots (singular values below ``1e-12 s_1``).

    Notes
    -----
    ``O(N K min(N, K))`` for the SVD; memory ``16 N K`` bytes for ``X``.
    """
    snapshots = as_real_array(snapshots, "snapshots")  # complex, strings, NaN/Inf refused
    if snapshots.ndim != 2 or snapshots.shape[1] % 2 or snapshots.shape[1] == 0 or len(snapshots) == 0:
        raise ValueError(f"snapshots must have shape (K, 2N) with K >= 1, got {snapshots.shape}")
    if (n is None) == (tol is None):
        raise ValueError("give exactly one of n (number of modes) and tol (relative projection error)")
    big_n = snapshots.shape[1] // 2
    X = (snapshots[:, :big_n] + 1j * snapshots[:, big_n:]).T
    U, s, _ = svd(X, full_matrices=False, lapack_driver="gesdd")
    rank = int(np.sum(s > _RANK_RTOL * s[0])) if s[0] > 0 else 0
    if tol is not None:
        if not (np.isfinite(tol) and tol > 0):
            raise ValueError(f"tol must be a positive float, got {tol!r}")
        s2 = (s / s[0]) ** 2 if s[0] > 0 else np.ones_like(s)  # normalized: no overflow for huge snapshots
        tail = np.sqrt(np.maximum(0.0, 1.0 - np.cumsum(s2) / s2.sum()))
        n = int(np.argmax(tail <= tol)) + 1 if np.any(tail <= tol) else len(s)
        n = min(n, max(rank, 1))
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise ValueError(f"n must be a positive integer, got {n!r}")
    if n > rank:
        raise ValueError(
            f"n = {n} exceeds the numerical rank {rank} of the snapshots (singular values "
            f"{', '.join(f'{v:.2e}' for v in s[: min(len(s), n + 2)])}): add snapshots or choose n <= {rank}"
        )
    Un = U[:, :n]
    V = np.block([[Un.real, -Un.imag], [Un.imag, Un.real]])
    return ComplexSVDBasis(V=V, singular_values=s, n=int(n))


def symplectic_inverse(V: np.ndarray) -> np.ndarray:
    """``V+ = J_2n^T V^T J_2N``, shape (2n, 2N)."""
    return canonical_J(V.shape[1]).T @ V.T @ canonical_J(V.shape[0])


def symplecticity_of_basis(V: np.ndarray) -> float:
    """``max |V^T J_2N V - J_2n|``."""
    return float(np.abs(V.T @ canonical_J(V.shape[0]) @ V - canonical_J(V.shape[1])).max())


class SymplecticROM:
    """``fom -> reductor.reduce() -> rom`` for a wave FOM, plus NumPy projection and reconstruction.

    Parameters
    ----------
    fom : sympredict.systems.wave.WaveFOM
        The full-order model (its ``model`` is a pyMOR ``QuadraticHamiltonianModel``).
    basis : ComplexSVDBasis
        A symplectic basis of the FOM's phase space.
    symplectic_tol
        Largest accepted ``max |V^T J V - J|``.

    Attributes
    ----------
    reductor : pymor.reductors.symplectic.QuadraticHamiltonianRBReductor
    rom : pyMOR reduced model (``V^T H(mu) V``, affine in ``mu``)
    system : QuadraticHamiltonian
        The reduced Hamiltonian as two dense ``2n x 2n`` matrices, for NumPy stepping.
    V, V_plus : ndarray of shapes (2N, 2n), (2n, 2N)
    """

    def __init__(self, fom, basis: ComplexSVDBasis, symplectic_tol: float = 1e-10):
        from pymor.reductors.symplectic import QuadraticHamiltonianRBReductor

        if basis.V.shape[0] != fom.dim:
            raise ValueError(f"basis has {basis.V.shape[0]} rows but the FOM phase space has dimension {fom.dim}")
        defect = symplecticity_of_basis(basis.V)
        if defect > symplectic_tol:
            raise ValueError(f"the basis is not symplectic: max |V^T J V - J| = {defect:.2e} > {symplectic_tol:.0e}")
        self.fom = fom
        self.basis = basis
        self.V = basis.V
        self.V_plus = symplectic_inverse(basis.V)
        with logger.block(f"symplectic Galerkin projection onto 2n = {basis.V.shape[1]}"):
            self.reductor = QuadraticHamiltonianRBReductor(fom.model, basis.to_pymor(fom.phase_space))
            self.rom = self.reductor.reduce()
        self.system = QuadraticHamiltonian.from_pymor(self.rom.H_op)

    @property
    def dim(self) -> int:
        """Reduced dimension ``2n``."""
        return self.V.shape[1]

    def project(self, x) -> np.ndarray:
        """Reduced coordinates ``V+ x`` of full states (..., 2N) -> (..., 2n)."""
        return np.asarray(x) @ self.V_plus.T

    def reconstruct(self, x_red) -> np.ndarray:
        """Full states ``V x_red`` of reduced states (..., 2n) -> (..., 2N)."""
        return np.asarray(x_red) @ self.V.T
