"""The exact f-/P-greedy's store: the Newton basis at every candidate, in memory.

Per step: one matrix-vector product streaming ``basis[:m]`` (``m N`` reads,
the bandwidth bound), one Gramian column (``O(N)``, in cache-sized chunks)
and one fused ``O(N)`` pass for the residual, power function, max and next
selection (compiled with numba when installed, bit-identical to the NumPy
passes it replaces).  Time ``O(m^2 (N + N_val) / 2)`` memory traffic in
total, memory ``itemsize * m_max (N + N_val)`` bytes, checked before the run.

``basis_dtype='float32'`` halves memory and traffic: the residual, the power
function and the new basis row are computed in float64 and each stored row
carries a relative error of ``~6e-8`` (with numba the matrix-vector product
accumulates in float64; without, it is a float32 product).
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from sympredict import _numba
from sympredict.interpolation.greedy import _compiled
from sympredict.interpolation.greedy.loop import BaseStore, Expansion, check_memory

__all__ = ["DenseStore", "abs_residual", "matvec_t"]


def abs_residual(res: np.ndarray, out: np.ndarray) -> np.ndarray:
    """``max_k |r_ik|`` per candidate into ``out`` (N,), without a temporary for one output."""
    if res.shape[1] == 1:
        return np.abs(res[:, 0], out=out)
    return np.abs(res).max(axis=1, out=out)


def matvec_t(basis: np.ndarray, m: int, c: np.ndarray) -> np.ndarray:
    """``basis[:m].T @ c`` for a float32 basis, shape (N,), float64.

    Compiled (numba) with float64 accumulation when available, streaming
    ``basis[:m]`` once in column chunks that keep the partial sums in cache;
    else a float32 BLAS product (``m N`` flops either way, ``4 m N`` bytes read).
    """
    if _numba.HAVE_NUMBA:
        return _compiled.matvec_t(basis, m, c)
    return (basis[:m].T @ c.astype(np.float32)).astype(float)


class DenseStore(BaseStore):
    """Newton basis, residuals and power function of all ``N`` candidates (and the validation set).

    Parameters
    ----------
    functionals
        The ``N`` candidates (:mod:`sympredict.interpolation.functionals`).
    targets : ndarray of shape (N,) or (N, q)
        ``q > 1`` interpolates ``q`` outputs with shared centres (selection by the max over outputs).
    criterion
        ``'f'`` or ``'p'``.
    power_tol
        Breakdown guard relative to ``max G_ii`` (see :func:`~sympredict.interpolation.greedy.greedy_interpolation`).
    validation
        Optional ``(val_functionals, val_targets)``: ``E_val(m)`` at ``O(N_val m)`` extra work per step.
    memory_limit
        Bytes the basis may use (default 90% of available memory).
    basis_dtype
        ``'float64'`` or ``'float32'``.
    compiled
        Use the compiled fused update pass (:func:`sympredict.interpolation.greedy._compiled.greedy_update`,
        bit-identical to the NumPy passes) for an f-greedy with one output;
        default: when numba is installed.
    diagonal_max
        ``max G_ii`` over the whole candidate set, when this store holds only a
        part of it (a shard of :class:`~sympredict.interpolation.greedy.sharded.ShardedStore`);
        default: over its own candidates.
    regularization
        Ridge term ``lambda >= 0``: the Newton basis of ``G + lambda I``
        (noisy data; regularized interpolation).  The power function starts
        at ``G_ii + lambda`` and a selected functional's column gets
        ``+ lambda`` at its own index; the coefficients ``c = L^{-T} beta``
        then solve ``(G_sel + lambda I) c = y_sel`` on the selected
        functionals (kernel ridge regression on the centres), and the model
        evaluates ``s`` with the plain kernel.  Training residuals are those of
        the augmented kernel (at a centre ``r_j = 0`` while
        ``y_j - lambda_j(s) = lambda c_j``); validation residuals are those of
        ``s`` itself.  ``0`` (default) runs exactly the unregularized code.
        The breakdown guard stays relative to ``max G_ii``.

    Notes
    -----
    :meth:`add` takes ``j = -1`` for a functional selected outside this store
    (a shard's view of another shard's winner).
    """

    label = "greedy"

    def __init__(
        self,
        functionals,
        targets,
        *,
        memory_limit: Optional[float] = None,
        basis_dtype: str = "float64",
        compiled: Optional[bool] = None,
        diagonal_max: Optional[float] = None,
        regularization: float = 0.0,
        **base,
    ):
        if not (np.isfinite(regularization) and regularization >= 0):
            raise ValueError(f"regularization must be a finite non-negative float, got {regularization!r}")
        if basis_dtype not in ("float64", "float32"):
            raise ValueError(f"basis_dtype must be 'float64' or 'float32', got {basis_dtype!r}")
        super().__init__(functionals, targets, **base)  # criterion, power_tol, validation
        self.memory_limit = memory_limit
        self.dtype = np.dtype(basis_dtype)
        self.diagonal_max = diagonal_max
        self.regularization = float(regularization)
        self.compiled = _numba.use_compiled(compiled)
        self.basis = None

    def open(self, expansion: Expansion):
        n, n_val, max_centers = self.n_functionals, self.n_val, expansion.max_centers
        check_memory(max_centers, n, n_val, self.memory_limit, itemsize=self.dtype.itemsize)
        self.single = self.dtype == np.float32
        self.res = self.y.copy()
        self.res_abs = np.empty(n)
        self.p2 = self.functionals.diagonal().astype(float)
        self.breakdown = self.power_tol * (self.p2.max() if self.diagonal_max is None else self.diagonal_max)
        if self.regularization:
            self.p2 += self.regularization  # diagonal of G + lambda I
        self.basis = np.empty((max_centers, n), dtype=self.dtype)
        self.vbasis = np.empty((max_centers, n_val), dtype=self.dtype) if n_val else None
        self.row64 = np.empty(n) if self.single else None
        self.vrow64 = np.empty(n_val) if self.single and n_val else None
        self.tmp = np.empty(n)
        # with numba the vector work after the matrix-vector product is one fused pass
        # (_compiled.greedy_update, bit-identical to the NumPy code), which also finds the next selection
        self.fused = self.compiled and self.criterion == "f" and self.n_outputs == 1
        self.zeros = np.zeros(n) if self.fused else None
        self.next_sel = None
        abs_residual(self.res, out=self.res_abs)
        return self.res_abs.max(), (np.abs(self.vres).max() if n_val else None)

    def select(self, m: int):
        if self.next_sel is not None:
            j, best = self.next_sel
            self.next_sel = None
        else:
            # res_abs holds |r| of the current residual (recomputed after every unfused step)
            score = self.res_abs if self.criterion == "f" else self.p2.copy()
            score[self.p2 <= self.breakdown] = -np.inf
            j = int(np.argmax(score))
            best = score[j]
        if not np.isfinite(best):
            return -1, best, np.inf
        return j, best, (best if self.criterion == "f" else np.inf)

    def winner(self, j: int, m: int):
        return j, self.functionals.representer(j), self.basis[:m, j].astype(float), self.p2[j], self.res[j]

    def add(self, m, rep, coeffs_j, pj, b, j):
        basis, single = self.basis, self.single
        if self.fused:
            if single:
                row = self.functionals.column(rep, out=self.row64)
                t = matvec_t(basis, m, coeffs_j) if m else self.zeros
            else:
                row = self.functionals.column(rep, out=basis[m])
                t = basis[:m].T @ coeffs_j if m else self.zeros
            if self.regularization and j >= 0:
                row[j] += self.regularization  # column of G + lambda I
            max_abs, next_j, next_best = _compiled.greedy_update(
                row, t, 1.0 / pj, b[0], self.res[:, 0], self.p2, j, self.breakdown, parallel=_numba.GREEDY_PARALLEL
            )
            self.next_sel = (next_j, next_best)
            if single:
                basis[m] = row
        else:
            if single:
                row = self.functionals.column(rep, out=self.row64)
                if m:
                    row -= matvec_t(basis, m, coeffs_j)
            else:
                row = self.functionals.column(rep, out=basis[m])
                if m:
                    row -= basis[:m].T @ coeffs_j
            if self.regularization and j >= 0:
                row[j] += self.regularization  # column of G + lambda I (the basis values at j are subtracted above)
            row *= 1.0 / pj
            if single:
                basis[m] = row
            res = self.res
            if self.n_outputs == 1:
                res[:, 0] -= b[0] * row
            else:
                res -= row[:, None] * b
            np.square(row, out=self.tmp)
            self.p2 -= self.tmp
            if j >= 0:
                res[j] = 0.0
                self.p2[j] = 0.0
        val_max = None
        if self.n_val:
            if single:
                vrow = self.val_functionals.column(rep, out=self.vrow64)
                if m:
                    vrow -= matvec_t(self.vbasis, m, coeffs_j)
                vrow *= 1.0 / pj
                self.vbasis[m] = vrow
            else:
                vrow = self.val_functionals.column(rep, out=self.vbasis[m])
                if m:
                    vrow -= self.vbasis[:m].T @ coeffs_j
                vrow *= 1.0 / pj
            self.vres -= vrow[:, None] * b
            val_max = np.abs(self.vres).max()
        if self.fused:
            return max_abs, val_max
        abs_residual(self.res, out=self.res_abs)
        return self.res_abs.max(), val_max
