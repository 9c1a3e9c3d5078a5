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

from sympredict._checks import as_real, as_real_array, as_states
from sympredict.systems.flowmaps import linear_system_from_pymor
from sympredict.symplectic.metrics import canonical_J, j_times
from sympredict.systems.quadratic import QuadraticHamiltonian

__all__ = [
    "ComplexSVDBasis",
    "snapshot_rows",
    "basis_columns",
    "complex_svd_basis",
    "pymor_basis",
    "symplectic_inverse",
    "symplecticity_of_basis",
    "SymplecticROM",
]

logger = getLogger("sympredict.mor.basis")

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
        return pymor_basis(self.V, phase_space)


def pymor_basis(V, phase_space):
    """A basis ``V = [E, F]`` (2N, 2n), rows ``(q, p)``, as a pyMOR ``SymplecticBasis`` in ``phase_space``
    (a 2-block ``BlockVectorSpace``); the values are copied, not computed."""
    from pymor.algorithms.symplectic import SymplecticBasis

    V = basis_columns(V)
    big_n, n = V.shape[0] // 2, V.shape[1] // 2
    if V.shape[0] != phase_space.dim:
        raise ValueError(f"the basis has {V.shape[0]} rows, the phase space has dimension {phase_space.dim}")
    q_space, p_space = phase_space.subspaces
    E = phase_space.make_array([q_space.from_numpy(V[:big_n, :n]), p_space.from_numpy(V[big_n:, :n])])
    F = phase_space.make_array([q_space.from_numpy(V[:big_n, n:]), p_space.from_numpy(V[big_n:, n:])])
    return SymplecticBasis(E, F)


def snapshot_rows(snapshots, layout: Optional[str] = None) -> np.ndarray:
    """Snapshots as rows ``(K, 2N)`` ordered ``(q, p)``, from a VectorArray or an ndarray of known layout.

    Parameters
    ----------
    snapshots : VectorArray or ndarray
        A pyMOR VectorArray (a blocked ``(q, p)`` phase space or a NumPy space of
        even dimension; any length), or an ndarray of shape ``(K, 2N)``
        (``layout="rows"``, sympredict's convention) or ``(2N, K)``
        (``layout="columns"``, what pyMOR's ``to_numpy()`` returns).
    layout : {None, "rows", "columns"}
        Needed for an ndarray whose orientation cannot be told from its shape:
        ``None`` accepts only ``(K, 2N)`` with ``K`` odd; a ``(2N, K)`` array
        with ``K`` odd, or any array with two even dimensions, is refused
        (never silently transposed).

    Returns
    -------
    ndarray of shape (K, 2N)
    """
    if hasattr(snapshots, "space") and hasattr(snapshots, "to_numpy"):
        if layout is not None:
            raise ValueError("layout applies to ndarrays only: a VectorArray knows its orientation")
        cols = (
            np.vstack([b.to_numpy() for b in snapshots.blocks])
            if hasattr(snapshots, "blocks")
            else snapshots.to_numpy()
        )
        return np.ascontiguousarray(as_real_array(cols, "snapshots").T)
    arr = as_real_array(snapshots, "snapshots")  # complex, strings, NaN/Inf refused
    if arr.ndim != 2 or arr.size == 0:
        raise ValueError(f"snapshots must have shape (K, 2N) with K >= 1, got {arr.shape}")
    if layout == "rows":
        return arr
    if layout == "columns":
        return np.ascontiguousarray(arr.T)
    if layout is not None:
        raise ValueError(f"layout must be None, 'rows' or 'columns', got {layout!r}")
    k, d = arr.shape
    if d % 2 and k % 2 == 0:
        raise ValueError(
            f"snapshots of shape {arr.shape} look like pyMOR's (dim, len) layout (an odd number of columns "
            "cannot be a phase space (q, p)): pass layout='columns', or the VectorArray itself"
        )
    if d % 2 == 0 and k % 2 == 0:
        raise ValueError(
            f"snapshots of shape {arr.shape} are ambiguous: pass layout='rows' for (K, 2N) = (snapshots, dimension) "
            "or layout='columns' for pyMOR's (2N, K), or pass the VectorArray itself"
        )
    return arr


def complex_svd_basis(
    snapshots, n: Optional[int] = None, tol: Optional[float] = None, *, layout: Optional[str] = None
) -> ComplexSVDBasis:
    """PSD complex-SVD symplectic basis from phase-space snapshots.

    Parameters
    ----------
    snapshots : VectorArray, or ndarray of shape (K, 2N) / (2N, K)
        Snapshot states ordered ``(q, p)``; see :func:`snapshot_rows` (an
        ndarray whose orientation is ambiguous needs ``layout``).
    n
        Number of complex modes (reduced dimension ``2n``).
    tol
        Alternatively, the smallest ``n`` whose relative projection error
        ``sqrt(sum_{k>n} s_k^2 / sum s_k^2)`` is ``<= tol``.
    layout : {None, "rows", "columns"}
        Orientation of an ndarray (:func:`snapshot_rows`).

    Returns
    -------
    ComplexSVDBasis
        ``to_pymor(phase_space)`` gives the pyMOR ``SymplecticBasis``.

    Raises
    ------
    ValueError
        If neither or both of ``n`` and ``tol`` are given, ``n`` exceeds the
        numerical rank of the snapshots (singular values below ``1e-12 s_1``),
        or the orientation of an ndarray is ambiguous.

    Notes
    -----
    ``O(N K min(N, K))`` for the SVD; memory ``16 N K`` bytes for ``X``.
    """
    snapshots = snapshot_rows(snapshots, layout)  # complex, strings, NaN/Inf refused there
    snapshots, _ = as_states(snapshots, "snapshots", allow_single=False)  # (K, 2N), K >= 1
    if (n is None) == (tol is None):
        raise ValueError("give exactly one of n (number of modes) and tol (relative projection error)")
    big_n = snapshots.shape[1] // 2
    X = (snapshots[:, :big_n] + 1j * snapshots[:, big_n:]).T
    U, s, _ = svd(X, full_matrices=False, lapack_driver="gesdd")
    rank = int(np.sum(s > _RANK_RTOL * s[0])) if s[0] > 0 else 0
    if tol is not None:
        tol = as_real(tol, "tol", positive=True)
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
    """``V+ = J_2n^T V^T J_2N``, shape (2n, 2N); ``O(N n)`` time and memory (``J`` is never formed)."""
    # V^T J_2N = (J_2N^T V)^T = -(J_2N V)^T and J_2n^T B = -J_2n B
    return j_times(j_times(V, axis=0).T, axis=0)


def basis_columns(V) -> np.ndarray:
    """A basis as a (2N, 2n) array: from an ndarray, a ``ComplexSVDBasis`` or a pyMOR ``SymplecticBasis``.

    Raises
    ------
    ValueError
        For an ndarray with fewer rows than columns (a transposed basis ``(2n, 2N)``)
        or odd dimensions.
    """
    # C order whatever the source (a transposed VectorArray is Fortran-ordered): fitted state has
    # one memory layout, so BLAS takes the same kernel path for every model built on the basis
    if isinstance(V, ComplexSVDBasis):
        return np.ascontiguousarray(V.V, dtype=float)
    if hasattr(V, "to_array") and hasattr(V, "phase_space"):  # pyMOR SymplecticBasis
        return np.ascontiguousarray(snapshot_rows(V.to_array()).T, dtype=float)
    V = np.ascontiguousarray(V, dtype=float)
    if V.ndim != 2 or V.shape[0] % 2 or V.shape[1] % 2 or V.size == 0:
        raise ValueError(f"a symplectic basis must have shape (2N, 2n) with even sizes, got {np.shape(V)}")
    if V.shape[0] < V.shape[1]:
        raise ValueError(
            f"the basis has shape {V.shape}: fewer rows than columns, so it is transposed; a basis is (2N, 2n), "
            "one column per basis vector (pass V.T)"
        )
    return V


def symplecticity_of_basis(V) -> float:
    """``max |V^T J_2N V - J_2n|`` of a (2N, 2n) basis (ndarray, ``ComplexSVDBasis`` or pyMOR ``SymplecticBasis``).

    Raises
    ------
    ValueError
        For a transposed ndarray basis (:func:`basis_columns`).
    """
    V = basis_columns(V)
    return float(np.abs(V.T @ j_times(V, axis=0) - canonical_J(V.shape[1])).max())  # O(N n^2), J_2N never formed


class SymplecticROM:
    """``fom -> reductor.reduce() -> rom`` (symplectic Galerkin), plus NumPy projection and reconstruction.

    Parameters
    ----------
    fom : pymor.models.symplectic.QuadraticHamiltonianModel or sympredict.systems.wave.WaveFOM
        The full-order model: any pyMOR quadratic Hamiltonian model (identity
        mass), or a ``WaveFOM`` (its ``model`` is used).
    basis : ComplexSVDBasis or pymor.algorithms.symplectic.SymplecticBasis
        A symplectic basis of the FOM's phase space.
    symplectic_tol
        Largest accepted ``max |V^T J V - J|``.

    Attributes
    ----------
    RB : pymor.algorithms.symplectic.SymplecticBasis
        The basis in the FOM's phase space (what :class:`~sympredict.mor.SymplecticKernelReductor` takes).
    reductor : pymor.reductors.symplectic.QuadraticHamiltonianRBReductor
    rom : pyMOR reduced model (``V^T H(mu) V``)
    system : QuadraticHamiltonian or sympredict.systems.flowmaps.LinearHamiltonianSystem
        The reduced Hamiltonian for NumPy stepping: a ``QuadraticHamiltonian``
        (``H0 + mu H1``, scalar ``mu``) when the model has one scalar affine
        parameter named ``mu`` (the wave), otherwise a ``LinearHamiltonianSystem``
        assembling ``V^T H(mu) V`` per parameter vector
        (:func:`sympredict.systems.flowmaps.mu_to_vector` order).
    V, V_plus : ndarray of shapes (2N, 2n), (2n, 2N)
    """

    def __init__(self, fom, basis, symplectic_tol: float = 1e-10):
        from pymor.algorithms.symplectic import SymplecticBasis
        from pymor.models.symplectic import QuadraticHamiltonianModel
        from pymor.reductors.symplectic import QuadraticHamiltonianRBReductor

        model = getattr(fom, "model", fom)
        if not isinstance(model, QuadraticHamiltonianModel):
            raise ValueError(f"fom must be a pyMOR QuadraticHamiltonianModel (or a WaveFOM), got {type(fom).__name__}")
        phase_space = model.solution_space
        V = basis_columns(basis)
        if V.shape[0] != phase_space.dim:
            raise ValueError(f"basis has {V.shape[0]} rows but the FOM phase space has dimension {phase_space.dim}")
        if isinstance(basis, SymplecticBasis) and basis.phase_space != phase_space:
            raise ValueError(f"basis lives in {basis.phase_space}, the FOM in {phase_space}: mismatched spaces")
        defect = symplecticity_of_basis(V)
        if defect > symplectic_tol:
            raise ValueError(f"the basis is not symplectic: max |V^T J V - J| = {defect:.2e} > {symplectic_tol:.0e}")
        self.fom = fom
        self.model = model
        self.basis = basis
        self.V = V
        self.V_plus = np.ascontiguousarray(symplectic_inverse(V))  # one layout for fitted state (BLAS kernel paths)
        rb = basis if isinstance(basis, SymplecticBasis) else basis.to_pymor(phase_space)
        self.RB = rb
        with logger.block(f"symplectic Galerkin projection onto 2n = {V.shape[1]}"):
            self.reductor = QuadraticHamiltonianRBReductor(model, rb)
            self.rom = self.reductor.reduce()
        params = self.rom.H_op.parameters
        if set(params) == {"mu"} and params["mu"] == 1:
            try:
                self.system = QuadraticHamiltonian.from_pymor(self.rom.H_op)
            except ValueError:  # not affine in mu: assemble per parameter
                self.system = linear_system_from_pymor(self.rom)
        else:
            self.system = linear_system_from_pymor(self.rom)

    @property
    def dim(self) -> int:
        """Reduced dimension ``2n``."""
        return self.V.shape[1]

    def project(self, x) -> np.ndarray:
        """Reduced coordinates ``V+ x`` of full states (..., 2N) -> (..., 2n), or of a VectorArray -> (len, 2n)."""
        if hasattr(x, "space"):
            if x.space != self.model.solution_space:
                raise ValueError(f"x must lie in the FOM's solution space {self.model.solution_space}, got {x.space}")
            x = snapshot_rows(x)
        return np.asarray(x) @ self.V_plus.T

    def reconstruct(self, x_red) -> np.ndarray:
        """Full states ``V x_red`` of reduced states (..., 2n) -> (..., 2N)."""
        return np.asarray(x_red) @ self.V.T
