"""The surrogate's derivatives and the functionals' Gramian column, compiled (numba).

The compiled twins of :mod:`sympredict.interpolation.surrogate` and
:mod:`sympredict.interpolation.functionals`:

* :func:`_pass`, one fused pass over the ``m`` centres at a point, computes the
  gradient of ``s`` (all ``2n`` components), the part of its Hessian the Newton
  step's Jacobian needs (the ``n x n`` block ``d_p d_q s``, or for the midpoint
  update the upper triangle of the full ``2n x 2n`` Hessian) and the round-off
  floor of the gradient (no ``(B, m, (2n)^2)`` or even ``(B, m, 2n)``
  temporaries: ``O((2n + 6) * chunk)`` scratch per thread, the chunk sized by
  :func:`chunk_size` to stay in L1; the centres are grouped by differentiated
  component, :class:`CenterLayout`).  The reductions over a chunk may be
  reassociated so that they vectorise; their order then depends only on the
  chunk's length, so results stay bit-reproducible run to run, across batch
  sizes and threads (tested).  The compiled Newton rollout
  (:mod:`sympredict.symplectic._compiled_newton`) runs it once per iteration;
  :func:`gradients` (surrogate gradients at all training points, for the
  active-set greedy's refreshes) and :func:`newton_terms` (one iteration's
  terms, for tests) call it directly; :func:`factor_throughput` times its floor;
* :func:`hb_column` (the Gramian column for ``2n = 2`` and exact-arithmetic
  families) is bit-identical to the NumPy column it replaces.

The kernel formulas come from :mod:`sympredict.kernels._compiled`, the numba
policy from :mod:`sympredict._numba`.
"""

from __future__ import annotations

import math
import time

import numpy as np

from sympredict import _numba
from sympredict._numba import FJIT, JIT, PJIT, call, check_available, compiled, numba
from sympredict.kernels import IMQ
from sympredict.kernels._compiled import (
    _all_factors,
    _first_factors,
    _periodic_formulas,
    _profile,
    family_kernels,
    product_factors,
)

__all__ = [
    "CenterLayout",
    "chunk_size",
    "gradients",
    "newton_terms",
    "factor_throughput",
    "hb_column",
    "hb_column_supported",
]

_EPS = float(np.finfo(float).eps)


class CenterLayout:
    """Centres arranged for the compiled kernels: grouped by differentiated component, column-wise.

    Parameters
    ----------
    centers : ndarray of shape (m, 2n)
    components : ndarray of shape (m,), int

    periodic : PeriodicCoordinates, optional
        The state kernel's periodic coordinates (:class:`sympredict.kernels.PeriodicCoordinates`), in the
        coordinates of ``centers``.

    Attributes
    ----------
    order : ndarray of shape (m,), int64
        Permutation (stable sort by component); weights are passed as ``W[:, order]``.
    cT : ndarray of shape (2n, m)
        ``centers[order].T``, contiguous.
    seg : ndarray of shape (2n + 1,), int64
        Centres ``seg[l]:seg[l+1]`` (in the new order) differentiate component ``l``.
    per : ndarray of shape (2n,) or (0,)
        The period of each coordinate (0: not periodic); empty without periodic coordinates.

    Notes
    -----
    A group-averaged (symmetric) kernel is laid out by its plain functionals
    (:meth:`sympredict.kernels.StateSymmetry.expand`): ``centers`` are then the images ``g x_j``, and the
    compiled pass sums over them with the plain formulas (:meth:`HBSurrogate.layout`).
    """

    def __init__(self, centers, components, periodic=None):
        centers = np.asarray(centers, dtype=np.float64)
        components = np.asarray(components, dtype=np.int64)
        dim = centers.shape[1]
        self.order = np.argsort(components, kind="stable")
        self.cT = np.ascontiguousarray(centers[self.order].T)
        self.seg = np.searchsorted(components[self.order], np.arange(dim + 1)).astype(np.int64)
        self.per = np.zeros(0)
        if periodic is not None:
            periodic.check_dim(dim)
            self.per = np.zeros(dim)
            self.per[list(periodic.coordinates)] = periodic.periods


#: Centres per chunk of the compiled kernels at most (scratch ``(2n + 6) * chunk`` doubles stays in L1).
CHUNK = 512

#: Doubles of scratch per thread the chunk is sized for (32 KiB: in the L1 cache with the centres' chunk).
SCRATCH_DOUBLES = 4096


def chunk_size(dim: int) -> int:
    """Centres per chunk for states of dimension ``dim``: ``SCRATCH_DOUBLES / (dim + 6)`` rounded down to a multiple
    of 8, between 32 and :data:`CHUNK` (2n = 2: 512, 2n = 8: 288, 2n = 40: 88).

    Depends on ``dim`` only, so every instance of a model sums in the same order
    (bit-reproducible across batch sizes).
    """
    c = SCRATCH_DOUBLES // (int(dim) + 6)
    return int(max(32, min(CHUNK, c - c % 8)))


# --------------------------------------------------------------------------- the compiled kernels
@compiled(JIT)
def _chunk_factors(family, eps, r2, fA, fB, fC, L):
    """The ``(A, B, C)`` of family ``family`` (its code, :func:`_all_factors`)
    at the distances ``sqrt(r2[j])``, ``j < L``: the factor-cost probe (:func:`factor_throughput`)."""
    for j in range(L):
        fA[j], fB[j], fC[j] = _all_factors(family, eps, math.sqrt(r2[j]))


@compiled(JIT)
def _chunk_factors_repeat(family, eps, r2, fA, fB, fC, L, reps):
    """:func:`_chunk_factors` ``reps`` times (the in-cache factor-cost probe)."""
    for _ in range(reps):
        _chunk_factors(family, eps, r2, fA, fB, fC, L)


@compiled(FJIT)
def _dot(x, y, L):
    s = 0.0
    for j in range(L):
        s += x[j] * y[j]
    return s


@compiled(FJIT)
def _dot3(x, y, z, L):
    s = 0.0
    for j in range(L):
        s += x[j] * y[j] * z[j]
    return s


@compiled(FJIT)
def _gradient_sums(grad, l, s_a, ubg, dif, dim, L):
    """A chunk's gradient terms (:func:`_chunk`, :func:`_chunk_periodic`): ``grad_l -= s_a`` (the identity term, sum
    of ``w_j A_j`` (times ``g'_jl``)), ``grad_a -= sum_j ubg_j dif_ja`` (``ubg_j = w_j B_j g_j``)."""
    grad[l] -= s_a
    for a in range(dim):
        grad[a] -= _dot(ubg, dif[a], L)


@compiled(FJIT)
def _m_terms(hess, l, c0, r1, uB, dif, dim, L):
    """``- M_ac - M_ca``, ``M_ac = sum_j uB_j dif_ja [l = c]``, into the stored part of the Hessian (rows ``< r1``,
    columns ``>= c0`` at ``c - c0``, upper triangle): column ``l`` (rows ``a <= l``) and row ``l`` (columns ``c >= l``)."""
    if l >= c0:
        for a in range(min(r1, l + 1)):
            hess[a, l - c0] -= _dot(uB, dif[a], L)
    if l < r1:
        for c in range(max(c0, l), dim):
            hess[l, c - c0] -= _dot(uB, dif[c], L)


@compiled(FJIT)
def _chunk(xi, w, cT, j0, L, l, family, eps, mode, dif, r2, dmax, uB, uC, ubg, tmp, grad, hess):
    """One chunk of :func:`_pass` (centres ``j0:j0+L``, all differentiating component ``l``); returns its floor sum."""
    dim = cT.shape[0]
    n = dim // 2
    # differences, squared distances and (for the floor) max_a |d_ja|: one sweep per pair of
    # coordinates (2n is even), which halves the traffic of r2 and dmax.  The chunk's rows are
    # views indexed from 0 (an index j0 + j would be checked for wraparound per element), and
    # the max is a select (numba's max() on floats does not vectorise).
    wc = w[j0 : j0 + L]
    for a in range(0, dim, 2):
        xa = xi[a]
        xb = xi[a + 1]
        row_a = dif[a]
        row_b = dif[a + 1]
        ca = cT[a, j0 : j0 + L]
        cb = cT[a + 1, j0 : j0 + L]
        if a == 0:
            for j in range(L):
                da = xa - ca[j]
                db = xb - cb[j]
                row_a[j] = da
                row_b[j] = db
                r2[j] = da * da + db * db
                ada = abs(da)
                adb = abs(db)
                dmax[j] = ada if ada > adb else adb
        else:
            for j in range(L):
                da = xa - ca[j]
                db = xb - cb[j]
                row_a[j] = da
                row_b[j] = db
                r2[j] += da * da + db * db
                ada = abs(da)
                adb = abs(db)
                m = dmax[j]
                m = ada if ada > m else m
                dmax[j] = adb if adb > m else m
    # kernel factors and their weighted combinations; the sums of w A, w B g and the floor terms
    g_row = dif[l]
    s_a = 0.0
    s_bg = 0.0
    s_fl = 0.0
    if mode == 0:
        for j in range(L):
            A, B, C = _all_factors(family, eps, math.sqrt(r2[j]))
            wj = wc[j]
            s_a += wj * A
            ubg[j] = (wj * B) * g_row[j]
    else:
        for j in range(L):
            A, B, C = _all_factors(family, eps, math.sqrt(r2[j]))
            wj = wc[j]
            g = g_row[j]
            a_ = wj * A
            b_ = wj * B
            bg = b_ * g
            s_a += a_
            s_bg += bg
            s_fl += abs(bg) * dmax[j] + abs(a_)
            ubg[j] = bg
            uB[j] = b_
            uC[j] = (wj * C) * g
    _gradient_sums(grad, l, s_a, ubg, dif, dim, L)
    if mode == 0:
        return 0.0
    # Hessian entries (a, c) with r0 <= a < r1, max(c0, a) <= c < c1, stored at hess[a - r0, c - c0]:
    # mode 1 the block d_p d_q s (rows q, columns p), mode 2 the upper triangle of the full Hessian
    c0, r1 = (n, n) if mode == 1 else (0, dim)
    for a in range(r1):
        cs = max(c0, a)
        if dim - cs == 1:
            hess[a, cs - c0] -= _dot3(uC, dif[a], dif[cs], L)
        else:
            row = dif[a]
            for j in range(L):
                tmp[j] = uC[j] * row[j]
            c = cs
            while c + 4 <= dim:  # four columns per sweep: each load of tmp feeds four products
                d0 = dif[c]
                d1 = dif[c + 1]
                d2 = dif[c + 2]
                d3 = dif[c + 3]
                s0 = 0.0
                s1 = 0.0
                s2 = 0.0
                s3 = 0.0
                for j in range(L):
                    t = tmp[j]
                    s0 += t * d0[j]
                    s1 += t * d1[j]
                    s2 += t * d2[j]
                    s3 += t * d3[j]
                hess[a, c - c0] -= s0
                hess[a, c + 1 - c0] -= s1
                hess[a, c + 2 - c0] -= s2
                hess[a, c + 3 - c0] -= s3
                c += 4
            for cc in range(c, dim):
                hess[a, cc - c0] -= _dot(tmp, dif[cc], L)
    _m_terms(hess, l, c0, r1, uB, dif, dim, L)  # M_ac = sum_j w_j B_j d_ja [l = c]
    if mode == 2:  # delta_ac sum_j w_j B_j g_j
        for a in range(dim):
            hess[a, a] -= s_bg
    return s_fl


@compiled(FJIT)
def _chunk2(xi, w, cT, j0, L, l, family, eps, mode, grad, hess):
    """:func:`_chunk` for ``2n = 2``: one loop over centres ``j0:j0+L``, every sum in a register, no scratch.

    The same terms as :func:`_chunk` (``n = 1``: the block ``d_p d_q s`` is ``hess[0, 0]``; the full
    Hessian's upper triangle ``hess[0, 0], hess[0, 1], hess[1, 1]``); only the summation order differs.
    Why: for ``2n = 2`` storing the differences and weighted factors and reading them back costs as much
    as the arithmetic (pendulum rollout, 1,500 centres: 1.58 -> 1.17 ns per centre visit, one thread).
    """
    x0 = xi[0]
    x1 = xi[1]
    c0 = cT[0, j0 : j0 + L]
    c1 = cT[1, j0 : j0 + L]
    cl = cT[l, j0 : j0 + L]  # the differentiated coordinate: g = x_l - c_l without a select per centre
    xl = xi[l]
    wc = w[j0 : j0 + L]
    s_a = 0.0  # sum w A
    s_bg = 0.0  # sum w B g
    g0 = 0.0  # sum w B g d_0
    g1 = 0.0  # sum w B g d_1
    fl = 0.0  # floor terms
    h00 = 0.0  # sum w C g d_0 d_0
    h01 = 0.0  # sum w C g d_0 d_1
    h11 = 0.0  # sum w C g d_1 d_1
    m0 = 0.0  # sum w B d_0
    m1 = 0.0  # sum w B d_1
    for j in range(L):
        d0 = x0 - c0[j]
        d1 = x1 - c1[j]
        A, B, C = _all_factors(family, eps, math.sqrt(d0 * d0 + d1 * d1))
        wj = wc[j]
        g = xl - cl[j]
        a_ = wj * A
        b_ = wj * B
        bg = b_ * g
        s_a += a_
        g0 += bg * d0
        g1 += bg * d1
        if mode != 0:
            ad0 = abs(d0)
            ad1 = abs(d1)
            fl += abs(bg) * (ad0 if ad0 > ad1 else ad1) + abs(a_)
            cg = (wj * C) * g
            h01 += cg * d0 * d1
            m0 += b_ * d0
            m1 += b_ * d1
            if mode == 2:
                s_bg += bg
                h00 += cg * d0 * d0
                h11 += cg * d1 * d1
    grad[l] -= s_a
    grad[0] -= g0
    grad[1] -= g1
    if mode == 1:  # the block d_p d_q s: (a, c) = (0, 1), M_01 = [l = 1] m0, M_10 = [l = 0] m1
        hess[0, 0] -= h01 + (m0 if l == 1 else m1)
    elif mode == 2:
        # H_ac = -sum w C g d_a d_c - delta_ac s_bg - M_ac - M_ca, M_ac = [l = c] sum w B d_a
        hess[0, 0] -= h00 + s_bg + (2.0 * m0 if l == 0 else 0.0)
        hess[1, 1] -= h11 + s_bg + (2.0 * m1 if l == 1 else 0.0)
        hess[0, 1] -= h01 + (m0 if l == 1 else m1)
    return fl


@compiled(JIT)
def _chunk_periodic(xi, w, cT, j0, L, l, family, eps, mode, per, dif, g1r, r2, dmax, uB, uC, ubg, g2l, grad, hess):
    """:func:`_chunk` with periodic coordinates (``per[a] > 0``: the period of coordinate ``a``; any ``2n``).

    The differences ``d`` become ``G = g(d)`` and the squared distance sums ``u(d)^2`` in those coordinates
    (:meth:`sympredict.kernels.PeriodicCoordinates.formulas`, compiled from the same function); the identity
    terms carry ``g'`` and the Hessian's diagonal ``g''``, as in
    :meth:`sympredict.interpolation.surrogate.HBSurrogate.gradient_hessian`:

    ``grad_a = -sum_j w_j B_j g_j G_ja - [a = l] sum_j w_j A_j g'_jl``,
    ``H_ac = -sum_j w_j C_j g_j G_ja G_jc - delta_ac (sum_j w_j B_j g_j g'_ja + [a = l] sum_j w_j A_j g''_jl)
    - M_ac - M_ca``, ``M_ac = sum_j w_j B_j g'_jl G_ja [l = c]``, with ``g_j = G_jl``.

    ``g1r`` (2n, chunk) holds ``g'`` (1 in the plain coordinates), ``g2l`` (chunk) ``g''`` of coordinate ``l``.
    Plain loops (no pairing of coordinates): the periodic models' pass, ``O(L 2n)`` sines and cosines more.
    """
    dim = cT.shape[0]
    n = dim // 2
    wc = w[j0 : j0 + L]
    for a in range(dim):
        xa = xi[a]
        ca = cT[a, j0 : j0 + L]
        row = dif[a]
        row1 = g1r[a]
        period = per[a]
        for j in range(L):
            d = xa - ca[j]
            if period > 0.0:
                u, g, g1, g2 = _periodic_formulas(d, period)
                row[j] = g
                row1[j] = g1
                if a == l:
                    g2l[j] = g2
                uu = u * u
            else:
                row[j] = d
                row1[j] = 1.0
                uu = d * d
            ag = abs(row[j])
            if a == 0:
                r2[j] = uu
                dmax[j] = ag
            else:
                r2[j] += uu
                if ag > dmax[j]:
                    dmax[j] = ag
    periodic_l = per[l] > 0.0
    g_row = dif[l]
    g1_row = g1r[l]
    s_a = 0.0
    s_ag2 = 0.0
    s_fl = 0.0
    for j in range(L):
        A, B, C = _all_factors(family, eps, math.sqrt(r2[j]))
        wj = wc[j]
        g = g_row[j]
        g1 = g1_row[j]
        a_ = wj * A * g1 if periodic_l else wj * A
        bg = (wj * B) * g
        s_a += a_
        ubg[j] = bg
        if mode != 0:
            s_fl += abs(bg) * dmax[j] + abs(a_)
            uB[j] = wj * B * g1 if periodic_l else wj * B
            uC[j] = (wj * C) * g
            if periodic_l:
                s_ag2 += wj * A * g2l[j]
    _gradient_sums(grad, l, s_a, ubg, dif, dim, L)
    if mode == 0:
        return 0.0
    c0, r1 = (n, n) if mode == 1 else (0, dim)
    for a in range(r1):
        for c in range(max(c0, a), dim):
            hess[a, c - c0] -= _dot3(uC, dif[a], dif[c], L)
    _m_terms(hess, l, c0, r1, uB, dif, dim, L)  # M_ac = sum_j w_j B_j g'_jl G_ja [l = c]
    if mode == 2:  # delta_ac (sum_j w_j B_j g_j g'_ja + [a = l] sum_j w_j A_j g''_jl)
        for a in range(dim):
            hess[a, a] -= _dot(ubg, g1r[a], L)
        hess[l, l] -= s_ag2
    return s_fl


@compiled(JIT)
def _pass(xi, w, cT, seg, family, eps, mode, per, sc, grad, hess):
    """One pass over the centres at the point ``xi``: gradient of ``s`` and, by ``mode``, Hessian terms and floor.

    ``mode`` 0: the gradient only; 1: also the block ``d_p d_q s`` (``hess[:n, :n]``,
    rows ``q``, columns ``p``; the symplectic-Euler Jacobian); 2: also the full
    Hessian (``hess`` (2n, 2n); the midpoint Jacobian).  Centres are grouped by
    differentiated component: ``cT`` (2n, m) holds them column-wise, centres
    ``seg[l]:seg[l+1]`` differentiate component ``l``.  Per component the
    centres are processed in chunks of ``sc[0].shape[1]`` that stay in L1:
    differences, kernel factors, then each sum over the chunk as one
    vectorised reduction.  With ``g_j = d_{j l}``:

    ``grad_a = -sum_j w_j B_j g_j d_ja - [a = l] sum_j w_j A_j``,
    ``H_ac = -sum_j w_j C_j g_j d_ja d_jc - delta_ac sum_j w_j B_j g_j - M_ac - M_ca``,
    ``M_ac = sum_j w_j B_j d_ja [l = c]``
    (:meth:`sympredict.interpolation.surrogate.HBSurrogate.gradient_hessian`).
    ``per`` (2n,): the period of each coordinate, 0 where it is not periodic (no periodic
    coordinates: an empty array); with periodic coordinates :func:`_chunk_periodic` does the chunks.

    ``O(m 2n)`` flops for the gradient, ``+ O(m n^2)`` for the block, ``+ O(m (2n)^2 / 2)``
    for the full Hessian (its upper triangle, mirrored); ``O((2n + 6) chunk)``
    scratch.  Returns the floor ``eps (sum_j |w_j B_j g_j| max_a |d_ja| + sum_j |w_j A_j|)``
    (0 in mode 0).
    """
    dif, r2, dmax, uB, uC, ubg, tmp, g1r = sc
    dim = cT.shape[0]
    periodic = per.shape[0] > 0
    n = dim // 2
    ch = dif.shape[1]
    for a in range(dim):
        grad[a] = 0.0
    if mode == 1:
        for a in range(n):
            for c in range(n):
                hess[a, c] = 0.0
    elif mode == 2:
        for a in range(dim):
            for c in range(dim):
                hess[a, c] = 0.0
    floor = 0.0
    for l in range(dim):
        if periodic:  # tmp holds g'' of the differentiated coordinate
            for j0 in range(seg[l], seg[l + 1], ch):
                L = min(ch, seg[l + 1] - j0)
                floor += _chunk_periodic(
                    xi, w, cT, j0, L, l, family, eps, mode, per, dif, g1r, r2, dmax, uB, uC, ubg, tmp, grad, hess
                )
            continue
        if dim == 2:  # no scratch, so no chunks: one loop over the component's centres
            floor += _chunk2(xi, w, cT, seg[l], seg[l + 1] - seg[l], l, family, eps, mode, grad, hess)
            continue
        for j0 in range(seg[l], seg[l + 1], ch):
            L = min(ch, seg[l + 1] - j0)
            floor += _chunk(xi, w, cT, j0, L, l, family, eps, mode, dif, r2, dmax, uB, uC, ubg, tmp, grad, hess)
    if mode == 2:
        for a in range(dim):
            for c in range(a):
                hess[a, c] = hess[c, a]
    return _EPS * floor


@compiled(JIT)
def _scratch(dim, chunk, periodic):
    """The pass's scratch (:func:`_pass` ``sc``): differences (2n, chunk), six chunk vectors and, with periodic
    coordinates, ``g'`` (2n, chunk) (else a placeholder)."""
    return (
        np.empty((dim, chunk)),
        np.empty(chunk),
        np.empty(chunk),
        np.empty(chunk),
        np.empty(chunk),
        np.empty(chunk),
        np.empty(chunk),
        np.empty((dim if periodic else 1, chunk if periodic else 1)),
    )


@compiled(PJIT)
def _gradients_kernel(xi, group, Wg, cT, seg, family, eps, per, chunk, out):
    dim = xi.shape[1]
    n_pts = xi.shape[0]
    block = 256  # points per task: the scratch is allocated once per block
    for blk in numba.prange((n_pts + block - 1) // block):
        sc = _scratch(dim, chunk, per.shape[0] > 0)
        hess = np.empty((dim, dim))
        for i in range(blk * block, min(n_pts, (blk + 1) * block)):
            _pass(xi[i], Wg[group[i]], cT, seg, family, eps, 0, per, sc, out[i], hess)


@compiled(JIT)
def _terms_kernel(xi, W, cT, seg, family, eps, per, chunk, mode, grad, hess, floor):
    dim = xi.shape[1]
    sc = _scratch(dim, chunk, per.shape[0] > 0)
    for i in range(xi.shape[0]):
        floor[i] = _pass(xi[i], W[i], cT, seg, family, eps, mode, per, sc, grad[i], hess[i])


def _hb_column2(points, mu, dt, xq, muq, dtq, b, e, first_family, emu, mu_family, edt, dt_family, has_mu, has_dt, out):
    """Column entries of every point (``2n = 2``), the operations of the NumPy column in its order; compiled as
    ``_hb_column2_parallel`` (points on numba's threads) and ``_hb_column2_serial`` (a plain loop)."""
    d_mu = mu.shape[1]
    for p in numba.prange(points.shape[0]):
        d0 = points[p, 0] - xq[0]
        d1 = points[p, 1] - xq[1]
        A, B = _first_factors(first_family, e, math.sqrt(d0 * d0 + d1 * d1))
        w = 1.0
        if has_mu:
            m2 = 0.0
            for a in range(d_mu):
                dm = mu[p, a] - muq[a]
                m2 = dm * dm if a == 0 else m2 + dm * dm
            w = _profile(mu_family, emu, math.sqrt(m2))
        if has_dt:
            dd = dt[p] - dtq
            kd = _profile(dt_family, edt, math.sqrt(dd * dd))
            w = w * kd if has_mu else kd
        g = (-(w * B)) * (d1 if b == 1 else d0)
        v0 = d0 * g
        v1 = d1 * g
        if b == 0:
            v0 -= w * A
        else:
            v1 -= w * A
        out[2 * p] = v0
        out[2 * p + 1] = v1


_hb_column2_parallel = compiled(PJIT, "_hb_column2_parallel")(_hb_column2)
_hb_column2_serial = compiled(JIT, "_hb_column2_serial")(_hb_column2)


def gradients(xi, group, group_weights, layout: CenterLayout, kernel) -> np.ndarray:
    """Surrogate gradients at many points whose parameters take few distinct values.

    Parameters
    ----------
    xi : ndarray of shape (P, 2n)
        Points.
    group : ndarray of shape (P,), int
        Index of each point's ``(mu, dT)`` in ``group_weights``.
    group_weights : ndarray of shape (G, m)
        Centre weights per distinct ``(mu, dT)``, in the surrogate's centre order.
    layout
        The centres (:class:`CenterLayout`).
    kernel
        The state kernel.

    Returns
    -------
    ndarray of shape (P, 2n)

    Notes
    -----
    ``O(P m 2n)`` flops, points in parallel; memory ``O(P 2n + G m)``
    (no ``(P, m)`` weight matrix).
    """
    check_available()
    xi = np.ascontiguousarray(xi, dtype=np.float64)
    out = np.empty_like(xi)
    wg = np.ascontiguousarray(np.asarray(group_weights, dtype=np.float64)[:, layout.order])
    ns, (family,) = family_kernels(type(kernel))
    call(
        ns._gradients_kernel,
        xi,
        np.ascontiguousarray(group, dtype=np.int64),
        wg,
        layout.cT,
        layout.seg,
        family,
        float(kernel.eps),
        layout.per,
        chunk_size(xi.shape[1]),
        out,
    )
    return out


def newton_terms(xi, weights, layout: CenterLayout, kernel, full: bool = False):
    """What one compiled Newton iteration computes at each point: gradient, Hessian terms, gradient floor.

    The compiled twin of :meth:`sympredict.interpolation.surrogate.HBSurrogate.newton_terms`
    (``full=False``: the ``d_p d_q s`` block the symplectic-Euler step needs) and
    of :meth:`~sympredict.interpolation.surrogate.HBSurrogate.gradient_hessian` (``full=True``:
    the full Hessian of the midpoint step), same outputs, another summation
    order, for checking the compiled pass family by family and dimension by
    dimension; serial, ``O(B m (2n + n^2))`` (full: ``O(B m (2n)^2)``).

    Parameters
    ----------
    xi : ndarray of shape (B, 2n)
    weights : ndarray of shape (B, m)
        In the surrogate's centre order.
    layout
        The centres (:class:`CenterLayout`).
    kernel
        The state kernel.
    full
        The full Hessian instead of its block.

    Returns
    -------
    grad : ndarray of shape (B, 2n)
    hess : ndarray of shape (B, n, n) (the block ``d_p d_q s``) or (B, 2n, 2n) (``full``)
    floor : ndarray of shape (B,)
    """
    check_available()
    xi = np.ascontiguousarray(xi, dtype=np.float64)
    b, dim = xi.shape
    grad, hess, floor = np.empty((b, dim)), np.empty((b, dim, dim)), np.empty(b)
    w = np.ascontiguousarray(np.asarray(weights, dtype=np.float64)[:, layout.order])
    ns, (family,) = family_kernels(type(kernel))
    call(
        ns._terms_kernel,
        xi,
        w,
        layout.cT,
        layout.seg,
        family,
        float(kernel.eps),
        layout.per,
        chunk_size(dim),
        2 if full else 1,
        grad,
        hess,
        floor,
    )
    return grad, (hess if full else np.ascontiguousarray(hess[:, : dim // 2, : dim // 2])), floor


def factor_throughput(n: int = 1 << 20, eps: float = 0.2, repeats: int = 5, in_cache: bool = False) -> float:
    """Seconds per IMQ factor evaluation ``(A, B, C)`` in the compiled loop of the Newton pass.

    The floor of any evaluation of the surrogate's derivatives: a square root,
    one division, one square root and a few multiplications per centre.
    Benchmarks compare the compiled Newton pass's time per centre with it.

    ``in_cache=False``: one loop over ``n`` distances (a stream through memory),
    median of ``repeats``.  ``in_cache=True``: the loop over one chunk of
    :data:`CHUNK` distances in L1, repeated in compiled code (``n`` evaluations
    per sample), the minimum of ``repeats`` samples: the pass's own regime, and a
    statistic that other processes on the machine can only raise.
    """
    check_available()
    ns, (family,) = family_kernels(IMQ)
    if in_cache:
        r2 = np.random.default_rng(0).uniform(0.0, 4.0, CHUNK)
        fA, fB, fC = np.empty(CHUNK), np.empty(CHUNK), np.empty(CHUNK)
        reps = max(1, n // CHUNK)
        call(ns._chunk_factors_repeat, family, eps, r2, fA, fB, fC, CHUNK, 1)
        best = np.inf
        for _ in range(repeats):
            t0 = time.perf_counter()
            ns._chunk_factors_repeat(family, eps, r2, fA, fB, fC, CHUNK, reps)
            best = min(best, time.perf_counter() - t0)
        return float(best) / (reps * CHUNK)
    r2 = np.random.default_rng(0).uniform(0.0, 4.0, n)
    fA, fB, fC = np.empty(n), np.empty(n), np.empty(n)
    chunk_factors = ns._chunk_factors
    call(chunk_factors, family, eps, r2, fA, fB, fC, n)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        chunk_factors(family, eps, r2, fA, fB, fC, n)
        times.append(time.perf_counter() - t0)
    return float(np.median(times)) / n


def hb_column_supported(kernel, dim: int, d_mu: int) -> bool:
    """Whether :func:`hb_column` reproduces ``HBFunctionals.column`` bit for bit.

    The same operations in the same order as the NumPy column are only
    guaranteed where NumPy's own sums are sequential (``2n = 2``, at most two
    parameter components) and where every factor's formulas use correctly
    rounded operations only (:attr:`RadialKernel.exact_arithmetic`: no
    ``exp``, whose NumPy and libm versions may differ in the last bit).
    """
    if not _numba.HAVE_NUMBA or dim != 2 or d_mu > 2:
        return False
    return all(k is None or k.exact_arithmetic for k in (kernel.state, kernel.mu, kernel.dt))


def hb_column(kernel, points, mu, dt, representer, out: np.ndarray) -> np.ndarray:
    """The Gramian column of one state-derivative functional, compiled (see :func:`hb_column_supported`).

    ``out[2 p + a] = w_p (-B d_pa d_pb - A delta_ab)`` with ``d_p = xi_p - xi_q``,
    ``w_p = k_mu(mu_p, mu_q) k_dT(dT_p, dT_q)``; one pass, no temporaries.
    ``O(N)``; bit-identical to :meth:`sympredict.interpolation.functionals.HBFunctionals.column`.
    """
    xq, muq, dtq, b = representer
    ns, factors = product_factors(kernel)
    fn = ns._hb_column2_parallel if (_numba.GREEDY_PARALLEL and len(points) > 65536) else ns._hb_column2_serial
    xq, muq = (np.ascontiguousarray(a, dtype=np.float64) for a in (xq, muq))
    call(fn, points, mu, dt, xq, muq, float(dtq), int(b), *factors, out)
    return out
