"""The greedy's O(N) passes compiled (numba): the vector update, the float32 basis product, Gramian rows.

For the exact f-greedy (:mod:`sympredict.interpolation.greedy.dense`): :func:`greedy_update`
(the vector work of a step after the matrix-vector product, one pass) is
bit-identical to the NumPy code it replaces; :func:`matvec_t` (float64
accumulation over a float32 basis) is not meant to be.  For the blocked greedy
(:mod:`sympredict.interpolation.greedy.blocked`): :func:`hb_rows`, a block's Gramian
rows, the numbers of :meth:`sympredict.interpolation.functionals.HBFunctionals.gram_rows`
to round-off.

The kernel formulas come from :mod:`sympredict.kernels._compiled`, the numba
policy from :mod:`sympredict._numba`.
"""

from __future__ import annotations

import math

import numpy as np

from sympredict import _numba
from sympredict._numba import JIT, PJIT, call, check_available, compiled, numba
from sympredict.kernels._compiled import _first_factors, _profile, family_kernels, product_factors

__all__ = ["greedy_update", "matvec_t", "hb_rows", "hb_rows_supported"]


@compiled(PJIT)
def _matvec_t_kernel(basis, m, c, out, chunk):
    """Column chunks in parallel; four rows per sweep over a chunk's float64 sums."""
    n = basis.shape[1]
    n_chunks = (n + chunk - 1) // chunk
    for ch in numba.prange(n_chunks):
        i0 = ch * chunk
        i1 = min(n, i0 + chunk)
        L = i1 - i0
        acc = np.zeros(L)
        k = 0
        while k + 4 <= m:
            c0 = c[k]
            c1 = c[k + 1]
            c2 = c[k + 2]
            c3 = c[k + 3]
            r0 = basis[k, i0:i1]
            r1 = basis[k + 1, i0:i1]
            r2 = basis[k + 2, i0:i1]
            r3 = basis[k + 3, i0:i1]
            for i in range(L):
                acc[i] += (c0 * r0[i] + c1 * r1[i]) + (c2 * r2[i] + c3 * r3[i])
            k += 4
        while k < m:
            ck = c[k]
            r0 = basis[k, i0:i1]
            for i in range(L):
                acc[i] += ck * r0[i]
            k += 1
        out[i0:i1] = acc


@compiled(JIT)
def _greedy_update_chunk(ch, row, t, inv_pj, b, res, p2, j, breakdown, chunk, cmax, carg, cbest):
    """One chunk of :func:`greedy_update`: its max ``|r|`` and its best selectable candidate."""
    n = row.shape[0]
    i0 = ch * chunk
    i1 = min(n, i0 + chunk)
    mx = 0.0
    best = -np.inf
    arg = -1
    for i in range(i0, i1):
        v = (row[i] - t[i]) * inv_pj
        row[i] = v
        if i == j:
            r = 0.0
            q = 0.0
        else:
            r = res[i] - b * v
            q = p2[i] - v * v
        res[i] = r
        p2[i] = q
        a = abs(r)
        if a > mx or a != a:
            mx = a if (mx == mx) else mx
        if q > breakdown and (a > best or (a != a and best == best)):
            best = a
            arg = i
    cmax[ch] = mx
    carg[ch] = arg
    cbest[ch] = best


def _greedy_update(row, t, inv_pj, b, res, p2, j, breakdown, chunk, cmax, carg, cbest):
    """Every chunk's update (:func:`_greedy_update_chunk`); compiled as ``_greedy_update_parallel`` (chunks on
    numba's threads) and ``_greedy_update_serial`` (a plain loop)."""
    for ch in numba.prange(cmax.shape[0]):
        _greedy_update_chunk(ch, row, t, inv_pj, b, res, p2, j, breakdown, chunk, cmax, carg, cbest)


_greedy_update_parallel = compiled(PJIT, "_greedy_update_parallel")(_greedy_update)
_greedy_update_serial = compiled(JIT, "_greedy_update_serial")(_greedy_update)


@compiled(JIT)
def _task_vector(dim):
    """A work vector of one task of a parallel loop, allocated in a call: numba may hoist an allocation written in
    the loop body out of the loop, where the threads would share it."""
    return np.empty(dim)


def _hb_rows(points, mu, dt, xq, muq, dtq, comps, e, first_family, emu, mu_family, edt, dt_family, has_mu, has_dt, out):
    """Gramian rows of state-derivative functionals against every point (any ``2n``, plain kernel), a row a task;
    compiled as ``_hb_rows_parallel`` (rows on numba's threads) and ``_hb_rows_serial`` (a plain loop)."""
    n_pts, dim = points.shape
    d_mu = mu.shape[1]
    for k in numba.prange(xq.shape[0]):
        diff = _task_vector(dim)
        b = comps[k]
        for p in range(n_pts):
            r2 = 0.0
            for a in range(dim):
                d = points[p, a] - xq[k, a]
                diff[a] = d
                r2 += d * d
            A, B = _first_factors(first_family, e, math.sqrt(r2))
            w = 1.0
            if has_mu:
                m2 = 0.0
                for a in range(d_mu):
                    dm = mu[p, a] - muq[k, a]
                    m2 += dm * dm
                w = _profile(mu_family, emu, math.sqrt(m2))
            if has_dt:
                dd = dt[p] - dtq[k]
                w = w * _profile(dt_family, edt, math.sqrt(dd * dd))
            g = (-(w * B)) * diff[b]
            base = p * dim
            for a in range(dim):
                out[k, base + a] = diff[a] * g
            out[k, base + b] -= w * A


_hb_rows_parallel = compiled(PJIT, "_hb_rows_parallel")(_hb_rows)
_hb_rows_serial = compiled(JIT, "_hb_rows_serial")(_hb_rows)


MATVEC_CHUNK = 16384


def matvec_t(basis: np.ndarray, m: int, c: np.ndarray) -> np.ndarray:
    """``basis[:m].T @ c`` accumulated in float64, for a float32 or float64 basis.

    Parameters
    ----------
    basis : ndarray of shape (m_max, N), C-contiguous
        Newton basis, one row per centre.
    m
        Rows used.
    c : ndarray of shape (m,)

    Returns
    -------
    ndarray of shape (N,), float64

    Notes
    -----
    ``2 m N`` flops, one read of ``basis[:m]``: column chunks of
    :data:`MATVEC_CHUNK` in parallel over numba's threads, each chunk's sums in L2,
    four rows per sweep (measured 21-24 GB/s on this machine, like OpenBLAS's dgemv).
    """
    check_available()
    out = np.empty(basis.shape[1])
    call(
        family_kernels()[0]._matvec_t_kernel,
        basis,
        int(m),
        np.ascontiguousarray(c, dtype=np.float64),
        out,
        MATVEC_CHUNK,
    )
    return out


#: Entries per chunk of :func:`greedy_update` (one parallel task).
UPDATE_CHUNK = 65536


def greedy_update(row, t, inv_pj: float, b: float, res, p2, j: int, breakdown: float, parallel: bool = False):
    """The f-greedy step's vector work after the matrix-vector product, in one pass.

    Elementwise, with the same operations in the same order as the NumPy code
    of :func:`sympredict.interpolation.greedy.greedy_interpolation` (bit-identical results):
    ``v = (row - t) / sqrt(P2_j)`` into ``row``, ``r -= beta v``, ``P2 -= v^2``
    (both 0 at ``j``), then ``max |r|`` over all candidates and the next
    selection ``argmax |r|`` over the candidates with ``P2 > breakdown``
    (first index on ties, as ``np.argmax``).

    Parameters
    ----------
    row : ndarray of shape (N,)
        Gramian column of the selected functional; overwritten with the new basis row.
    t : ndarray of shape (N,)
        ``basis[:m].T @ basis[:m, j]``.
    res, p2 : ndarray of shape (N,)
        Residual and power function, updated in place.

    Returns
    -------
    max_abs : float
        ``max_i |r_i|``.
    next_j : int
        Next selection (-1 if no candidate is selectable).
    next_score : float
        ``|r|`` there (``-inf`` if none).

    parallel
        Chunks on numba's threads.  Off by default: right after OpenBLAS's
        threaded matrix-vector product, its spinning threads and numba's
        compete for the cores (measured 3-5x slower steps on 2 cores).

    Notes
    -----
    ``O(N)``, one read of ``row, t, res, p2`` and one write of ``row, res, p2``;
    replaces about ten NumPy passes.
    """
    check_available()
    n = row.shape[0]
    n_chunks = (n + UPDATE_CHUNK - 1) // UPDATE_CHUNK
    cmax = np.empty(n_chunks)
    carg = np.empty(n_chunks, dtype=np.int64)
    cbest = np.empty(n_chunks)
    ns = family_kernels()[0]
    kernel = ns._greedy_update_parallel if (parallel and n_chunks > 1) else ns._greedy_update_serial
    call(kernel, row, t, float(inv_pj), float(b), res, p2, int(j), float(breakdown), UPDATE_CHUNK, cmax, carg, cbest)
    max_abs = cmax.max() if not np.isnan(cmax).any() else np.nan
    k = int(np.argmax(cbest))  # first chunk with the best score: first index overall
    return float(max_abs), int(carg[k]), float(cbest[k])


def hb_rows_supported(kernel) -> bool:
    """Whether :func:`hb_rows` applies: numba installed, a plain product kernel (no periodic coordinates, no symmetry)."""
    return _numba.HAVE_NUMBA and kernel.periodic is None and kernel.symmetry is None


def hb_rows(kernel, points, mu, dt, xq, muq, dtq, comps, out: np.ndarray) -> np.ndarray:
    """Gramian rows of ``K`` state-derivative functionals against all ``N = 2n M`` of the points, compiled.

    The numbers of :meth:`sympredict.interpolation.functionals.HBFunctionals.gram_rows` (the
    formula ``w_p (-B d_pa d_pb - A delta_ab)``, ``d_p = xi_p - xi_q``) to round-off, without its
    ``K x 1024 x 2n`` temporaries; any ``2n``.  The blocked greedy's Gramian rows for a block.

    Parameters
    ----------
    points : ndarray of shape (M, 2n)
    mu : ndarray of shape (M, d_mu)
    dt : ndarray of shape (M,)
    xq : ndarray of shape (K, 2n)
    muq : ndarray of shape (K, d_mu)
    dtq : ndarray of shape (K,)
    comps : ndarray of shape (K,), int
    out : ndarray of shape (K, N), C-contiguous

    Notes
    -----
    ``O(K M (2n + d_mu))`` work, rows in parallel on numba's threads for ``K > 1``.
    """
    ns, factors = product_factors(kernel)
    fn = ns._hb_rows_parallel if (_numba.GREEDY_PARALLEL and len(xq) > 1) else ns._hb_rows_serial
    points, mu, dt, xq, muq, dtq = (np.ascontiguousarray(a, dtype=np.float64) for a in (points, mu, dt, xq, muq, dtq))
    call(fn, points, mu, dt, xq, muq, dtq, np.ascontiguousarray(comps, dtype=np.int64), *factors, out)
    return out
