"""Optional compiled (numba) kernels: the prediction hot path and the greedy's O(N) passes.

The implicit symplectic-Euler step solves, per instance,
``F(p) = p - p0 + dT d_q s(q0, p) = 0`` by Newton with Jacobian
``I + dT d_p d_q s``; the symmetric (midpoint) update solves
``F(z) = z - x0 - dT/2 J grad s(z) = 0`` for the midpoint ``z`` with Jacobian
``I - dT/2 J Hess s(z)``.  The NumPy paths (:func:`sympredict.symplectic.newton.solve_step_numpy`,
:func:`sympredict.symplectic.newton.solve_midpoint_numpy`, ``backend='numpy'``) are the
references; the functions here compute the same iterations, instance by
instance, in compiled code (one solver, the update a flag):

* one fused pass over the ``m`` centres per Newton iteration computes the
  gradient of ``s`` (all ``2n`` components), the part of its Hessian the
  Jacobian needs (the ``n x n`` block ``d_p d_q s``, or for the midpoint update
  the upper triangle of the full ``2n x 2n`` Hessian) and the round-off floor of
  the gradient (no ``(B, m, (2n)^2)`` or even ``(B, m, 2n)`` temporaries:
  ``O((2n + 6) * chunk)`` scratch per thread, the chunk sized by
  :func:`chunk_size` to stay in L1; the centres are grouped by differentiated
  component, :class:`CenterLayout`).  The reductions over a chunk may be
  reassociated so that they vectorise; their order then depends only on the
  chunk's length, so results stay bit-reproducible run to run, across batch
  sizes and threads (tested);
* every instance iterates only until it has converged, with the stopping rule
  of the reference (:mod:`sympredict.newton_rule`: the same function);
* a whole rollout of ``K`` steps runs in one call, instances in parallel
  (``numba.prange``) when the batch is large enough, serially for one
  trajectory (latency).

Results agree with the NumPy reference to round-off (summation order differs):
``tests/estimators/test_performance_paths.py`` checks trajectories to ``1e-12`` on a
well-conditioned model and to the gradient's round-off floor on an
ill-conditioned one, where NumPy does not agree with itself across batch sizes
either.

Kernel formulas are not written here: the compiled code calls the families'
own static methods (:class:`sympredict.kernels.RadialKernel`), compiled from
the same Python functions (:func:`compiled_formulas`).  Every compiled kernel
is a top-level function that takes the kernel family as an integer code and
reaches the formulas through :func:`_profile`, :func:`_first_factors` and
:func:`_all_factors` (one branch per family of the package).  A family
registered from outside the package (:func:`sympredict.kernels.register_family`)
has no code: for it the same functions are compiled once more per process,
bound to dispatchers that know its formulas, and not cached on disk
(:func:`_kernels`).

For the exact f-greedy (:mod:`sympredict.interpolation.greedy`): :func:`greedy_update` (the
vector work of a step after the matrix-vector product, one pass) and
:func:`hb_column` (the Gramian column for ``2n = 2`` and exact-arithmetic families) are
bit-identical to the NumPy code they replace; :func:`matvec_t` (float64
accumulation over a float32 basis) and :func:`gradients` (surrogate gradients at
all training points, for the active-set greedy's refreshes) are not meant to be.

numba is optional (``pip install sympredict[fast]``): :data:`HAVE_NUMBA` says
whether it is importable, and nothing here is compiled before first use.

Compiled code is cached on disk, once per machine (numba's ``cache=True``):
the first process that uses a kernel compiles it (seconds), later processes
load it.  The cache lives where numba puts it: the ``__pycache__`` folder next
to this module when that is writable, else numba's per-user cache folder, or
the folder named by the environment variable ``NUMBA_CACHE_DIR`` (set before
numba is imported).  It holds one index per compiled function, with one entry
per argument types and CPU, so it does not grow with the number of processes.
A cache that cannot be read or written costs compilation in every process, not
an error: the kernels then run uncached, with one logged warning.  numba checks
the cache against the date of this file only: after editing a formula in
:mod:`sympredict.kernels`, :mod:`sympredict.newton_rule` or
:mod:`sympredict._numeric`, delete the cache folder.

Failure codes returned per instance: 0 converged, 1 non-finite residual,
2 singular Jacobian (exact zero pivot), 3 no convergence in ``max_iter``
iterations.
"""

from __future__ import annotations

import logging
import math
import time
import types
from typing import Optional

import numpy as np

try:  # pragma: no cover - exercised only where numba is installed
    import numba

    HAVE_NUMBA = True
except ImportError:  # pragma: no cover
    numba = None
    HAVE_NUMBA = False

from sympredict._numeric import lu_solve_inplace, parallel_safe
from sympredict.kernels import IMQ, Matern32, Matern52, PeriodicCoordinates
from sympredict.newton_rule import WATCHDOG, accepted, converged, residual_floor

__all__ = [
    "rollout_loaded",
    "HAVE_NUMBA", "compiled_formulas", "CenterLayout", "newton_solve", "newton_rollout", "matvec_t", "set_num_threads",
    "get_num_threads",
]

logger = logging.getLogger(__name__)

#: Batches below this size are solved on one thread (thread start-up costs more).
PARALLEL_MIN_BATCH = 8

_EPS = float(np.finfo(float).eps)


def get_num_threads() -> int:
    """Threads numba's parallel loops use (0 without numba)."""
    return numba.get_num_threads() if HAVE_NUMBA else 0


def set_num_threads(n: int) -> None:
    """Set the threads of numba's parallel loops (no-op without numba)."""
    if HAVE_NUMBA:
        numba.set_num_threads(int(n))


# --------------------------------------------------------------------------- compilation and the disk cache
#: Flags of the kernels.  _JIT: plain IEEE arithmetic.  _FJIT: the Newton pass's loops over a chunk of centres,
#: whose reductions may be reassociated (so that they vectorise) and products fused (FMA); the summation order
#: then depends only on the chunk's length (LLVM's vectoriser does not peel for alignment, and the pass's
#: reductions store nothing that could alias), so results stay bit-reproducible run to run, across batch sizes
#: and threads.  The formulas are compiled with _EXACT (fastmath off explicitly: numba compiles a callee that
#: leaves it unset with its caller's flags) and keep it when inlined.  _PJIT: the parallel loops.
_JIT = dict(nogil=True, fastmath=False, error_model="numpy")
_EXACT = _JIT
_FJIT = dict(nogil=True, fastmath={"reassoc", "contract"}, error_model="numpy")
_PJIT = dict(nogil=True, parallel=True)

#: ``(name, Python function, flags)`` of every compiled kernel below (:func:`_user_namespace` compiles them again).
_DEFINITIONS: list = []

#: The disk-cached dispatchers (for :func:`_disable_disk_cache`).
_CACHED: list = []

_CACHE_WARNED = False


def _warn_cache(exc: BaseException) -> None:
    """Log, once per process, that the disk cache is unusable (compilation then happens in every process)."""
    global _CACHE_WARNED
    if not _CACHE_WARNED:
        _CACHE_WARNED = True
        logger.warning("numba's disk cache of sympredict's compiled kernels is unusable (%s: %s); compiling them in "
                       "this process instead.  Delete the cache folder (sympredict/__pycache__, or NUMBA_CACHE_DIR) "
                       "or make it writable.", type(exc).__name__, exc)


def _jit_cached(function, flags: dict):
    """``numba.njit(function, cache=True, **flags)``; a cache folder that cannot be used leaves it uncached."""
    dispatcher = numba.njit(**flags)(function)
    try:  # what cache=True does; it raises if no cache folder is writable (a read-only install, no home folder)
        dispatcher.enable_caching()
    except Exception as exc:  # noqa: BLE001 - any failure of the cache only costs compile time
        _warn_cache(exc)
    _CACHED.append(dispatcher)
    return dispatcher


def _compiled(flags: dict):
    """Decorator: a top-level compiled kernel, cached on disk (the Python function stays listed for other families)."""
    def decorate(function):
        _DEFINITIONS.append((function.__name__, function, flags))
        return _jit_cached(function, flags) if HAVE_NUMBA else function
    return decorate


def _from_cache_module(exc: Optional[BaseException]) -> bool:
    """Whether ``exc`` (or an exception it was raised from) came from numba's caching code: an unusable cache."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        tb = exc.__traceback__
        while tb is not None:
            if tb.tb_frame.f_code.co_filename.replace("\\", "/").endswith("numba/core/caching.py"):
                return True
            tb = tb.tb_next
        exc = exc.__cause__ or exc.__context__
    return False


def _disable_disk_cache(exc: BaseException) -> None:
    """Stop reading and writing the disk cache in this process (after ``exc`` from it); logs one warning."""
    _warn_cache(exc)
    for dispatcher in _CACHED:
        dispatcher._cache.disable()  # the dispatcher's FunctionCache; loads and saves become no-ops


def _call(kernel, *args):
    """``kernel(*args)``, surviving a corrupt or unwritable disk cache (compiles without it, warns once).

    A cache error is raised while numba loads or saves compiled code, before the
    kernel runs, so the call can be repeated.
    """
    try:
        return kernel(*args)
    except Exception as exc:
        if not _from_cache_module(exc):
            raise
        _disable_disk_cache(exc)
        return kernel(*args)


def rollout_loaded() -> bool:
    """Whether this process has the compiled Newton rollout loaded already (compiled or read from the cache)."""
    return HAVE_NUMBA and bool(_rollout_serial.signatures or _rollout_parallel.signatures)


# --------------------------------------------------------------------------- the families' formulas
class FamilyCode(int):
    """A kernel family's code as the compiled kernels take it: an ``int`` that numba types as a literal.

    The kernels are then compiled once per family with the code a constant, so
    the family dispatch (:func:`_all_factors`) folds to a direct call of the
    family's formula, inlined into the loops over the centres as a function
    argument would be; a plain ``int`` would leave a branch in those loops,
    which stops them from vectorising (slower, and other round-off).  Python
    ints are typed ``int64`` by numba; this subclass is typed
    ``Literal[int](code)`` (unboxed as an ``int``), and the cache index holds
    only numba's own types.
    """

    __slots__ = ()


if HAVE_NUMBA:
    from numba.core import types as _nbtypes
    from numba.extending import typeof_impl

    _LITERALS: dict = {}

    @typeof_impl.register(FamilyCode)
    def _typeof_family_code(value, context):
        # called on every call of a kernel from Python: the literal type is built once per code
        try:
            return _LITERALS[value]
        except KeyError:
            return _LITERALS.setdefault(value, _nbtypes.literal(int(value)))


#: The package's kernel families and their codes (the ``family`` argument of the compiled kernels).
FAMILY_CODES = {IMQ: FamilyCode(0), Matern52: FamilyCode(1), Matern32: FamilyCode(2)}

_FORMULA_NAMES = ("profile", "first_factors", "all_factors")


def _compile_formulas(family: type, cache: bool) -> tuple:
    """A family's ``(profile, first_factors, all_factors)``, compiled from its own static methods."""
    if cache:
        return tuple(_jit_cached(getattr(family, name), _EXACT) for name in _FORMULA_NAMES)
    return tuple(numba.njit(getattr(family, name), **_EXACT) for name in _FORMULA_NAMES)


if HAVE_NUMBA:
    _imq_profile, _imq_first, _imq_all = _compile_formulas(IMQ, True)
    _m52_profile, _m52_first, _m52_all = _compile_formulas(Matern52, True)
    _m32_profile, _m32_first, _m32_all = _compile_formulas(Matern32, True)
    #: The periodic factor's ``(u, g, g', g'')`` (:meth:`sympredict.kernels.PeriodicCoordinates.formulas`, the same
    #: Python function, compiled for scalars).
    _periodic_formulas = _jit_cached(PeriodicCoordinates.formulas, _EXACT)
else:  # pragma: no cover
    _periodic_formulas = PeriodicCoordinates.formulas


def _formula(flags: dict):
    """Decorator of the family dispatchers: compiled with the formulas' exact flags, cached on disk."""
    def decorate(function):
        return _jit_cached(function, flags) if HAVE_NUMBA else function
    return decorate


@_formula(_EXACT)
def _profile(family, e, r):
    """``phi(r)`` of the family with code ``family`` (:data:`FAMILY_CODES`)."""
    if family == 0:
        return _imq_profile(e, r)
    elif family == 1:
        return _m52_profile(e, r)
    return _m32_profile(e, r)


@_formula(_EXACT)
def _first_factors(family, e, r):
    """``(A, B)`` of the family with code ``family``."""
    if family == 0:
        return _imq_first(e, r)
    elif family == 1:
        return _m52_first(e, r)
    return _m32_first(e, r)


@_formula(_EXACT)
def _all_factors(family, e, r):
    """``(A, B, C)`` of the family with code ``family``."""
    if family == 0:
        return _imq_all(e, r)
    elif family == 1:
        return _m52_all(e, r)
    return _m32_all(e, r)


def _user_formula(family, e, r):
    """The template of a dispatcher for families from outside the package: codes -1, -2, -3, then the package's."""
    if family == -1:
        return _U0(e, r)  # noqa: F821 - bound by _user_namespace
    elif family == -2:
        return _U1(e, r)  # noqa: F821
    elif family == -3:
        return _U2(e, r)  # noqa: F821
    return _PACKAGE(family, e, r)  # noqa: F821


_COMPILED_FORMULAS: dict = {}


def compiled_formulas(family: type):
    """The compiled ``(profile, first_factors, all_factors)`` of a kernel family.

    The same Python functions as the NumPy path (:class:`sympredict.kernels.RadialKernel`):
    a family's formulas are written once.  Cached on disk for the package's
    families; a family defined elsewhere is compiled in every process (numba's
    cache index of a function lists the types it was compiled for, and one
    from a script or a test module would make it unreadable elsewhere).
    """
    _check_available()
    out = _COMPILED_FORMULAS.get(family)
    if out is None:
        if family in FAMILY_CODES:
            out = {IMQ: (_imq_profile, _imq_first, _imq_all), Matern52: (_m52_profile, _m52_first, _m52_all),
                   Matern32: (_m32_profile, _m32_first, _m32_all)}[family]
        else:
            out = _compile_formulas(family, False)
        _COMPILED_FORMULAS[family] = out
    return out


# --------------------------------------------------------------------------- the compiled kernels
@_compiled(_JIT)
def _chunk_factors(family, eps, r2, fA, fB, fC, L):
    """The ``(A, B, C)`` of family ``family`` (its code, :func:`_all_factors`)
    at the distances ``sqrt(r2[j])``, ``j < L``: the factor-cost probe (:func:`factor_throughput`)."""
    for j in range(L):
        fA[j], fB[j], fC[j] = _all_factors(family, eps, math.sqrt(r2[j]))


@_compiled(_JIT)
def _chunk_factors_repeat(family, eps, r2, fA, fB, fC, L, reps):
    """:func:`_chunk_factors` ``reps`` times (the in-cache factor-cost probe)."""
    for _ in range(reps):
        _chunk_factors(family, eps, r2, fA, fB, fC, L)


@_compiled(_FJIT)
def _dot(x, y, L):
    s = 0.0
    for j in range(L):
        s += x[j] * y[j]
    return s


@_compiled(_FJIT)
def _dot3(x, y, z, L):
    s = 0.0
    for j in range(L):
        s += x[j] * y[j] * z[j]
    return s


@_compiled(_FJIT)
def _chunk(xi, w, cT, j0, L, l, family, eps, mode, dif, r2, dmax, uB, uC, ubg, tmp, grad, hess):
    """One chunk of :func:`_pass` (centres ``j0:j0+L``, all differentiating component ``l``); returns its floor sum."""
    dim = cT.shape[0]
    n = dim // 2
    # differences, squared distances and (for the floor) max_a |d_ja|: one sweep per pair of
    # coordinates (2n is even), which halves the traffic of r2 and dmax.  The chunk's rows are
    # views indexed from 0 (an index j0 + j would be checked for wraparound per element), and
    # the max is a select (numba's max() on floats does not vectorise).
    wc = w[j0:j0 + L]
    for a in range(0, dim, 2):
        xa = xi[a]
        xb = xi[a + 1]
        row_a = dif[a]
        row_b = dif[a + 1]
        ca = cT[a, j0:j0 + L]
        cb = cT[a + 1, j0:j0 + L]
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
    grad[l] -= s_a
    for a in range(dim):
        grad[a] -= _dot(ubg, dif[a], L)
    if mode == 0:
        return 0.0
    # Hessian entries (a, c) with r0 <= a < r1, max(c0, a) <= c < c1, stored at hess[a - r0, c - c0]:
    # mode 1 the block d_p d_q s (rows q, columns p), mode 2 the upper triangle of the full Hessian
    c0 = n if mode == 1 else 0
    r1 = n if mode == 1 else dim
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
    # M_ac + M_ca, M_ac = sum_j w_j B_j d_ja [l = c]: column l (rows a <= l) and row l (columns c >= l)
    if l >= c0:
        for a in range(min(r1, l + 1)):
            hess[a, l - c0] -= _dot(uB, dif[a], L)
    if l < r1:
        for c in range(max(c0, l), dim):
            hess[l, c - c0] -= _dot(uB, dif[c], L)
    if mode == 2:  # delta_ac sum_j w_j B_j g_j
        for a in range(dim):
            hess[a, a] -= s_bg
    return s_fl


@_compiled(_FJIT)
def _chunk2(xi, w, cT, j0, L, l, family, eps, mode, grad, hess):
    """:func:`_chunk` for ``2n = 2``: one loop over centres ``j0:j0+L``, every sum in a register, no scratch.

    The same terms as :func:`_chunk` (``n = 1``: the block ``d_p d_q s`` is ``hess[0, 0]``; the full
    Hessian's upper triangle ``hess[0, 0], hess[0, 1], hess[1, 1]``); only the summation order differs.
    Why: for ``2n = 2`` storing the differences and weighted factors and reading them back costs as much
    as the arithmetic (pendulum rollout, 1,500 centres: 1.58 -> 1.17 ns per centre visit, one thread).
    """
    x0 = xi[0]
    x1 = xi[1]
    c0 = cT[0, j0:j0 + L]
    c1 = cT[1, j0:j0 + L]
    cl = cT[l, j0:j0 + L]  # the differentiated coordinate: g = x_l - c_l without a select per centre
    xl = xi[l]
    wc = w[j0:j0 + L]
    s_a = 0.0   # sum w A
    s_bg = 0.0  # sum w B g
    g0 = 0.0    # sum w B g d_0
    g1 = 0.0    # sum w B g d_1
    fl = 0.0    # floor terms
    h00 = 0.0   # sum w C g d_0 d_0
    h01 = 0.0   # sum w C g d_0 d_1
    h11 = 0.0   # sum w C g d_1 d_1
    m0 = 0.0    # sum w B d_0
    m1 = 0.0    # sum w B d_1
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


@_compiled(_JIT)
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
    wc = w[j0:j0 + L]
    for a in range(dim):
        xa = xi[a]
        ca = cT[a, j0:j0 + L]
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
    grad[l] -= s_a
    for a in range(dim):
        grad[a] -= _dot(ubg, dif[a], L)
    if mode == 0:
        return 0.0
    c0 = n if mode == 1 else 0
    r1 = n if mode == 1 else dim
    for a in range(r1):
        for c in range(max(c0, a), dim):
            hess[a, c - c0] -= _dot3(uC, dif[a], dif[c], L)
    if l >= c0:
        for a in range(min(r1, l + 1)):
            hess[a, l - c0] -= _dot(uB, dif[a], L)
    if l < r1:
        for c in range(max(c0, l), dim):
            hess[l, c - c0] -= _dot(uB, dif[c], L)
    if mode == 2:  # delta_ac (sum_j w_j B_j g_j g'_ja + [a = l] sum_j w_j A_j g''_jl)
        for a in range(dim):
            hess[a, a] -= _dot(ubg, g1r[a], L)
        hess[l, l] -= s_ag2
    return s_fl


@_compiled(_JIT)
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
                floor += _chunk_periodic(xi, w, cT, j0, L, l, family, eps, mode, per, dif, g1r, r2, dmax, uB, uC,
                                         ubg, tmp, grad, hess)
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


@_compiled(_JIT)
def _scratch(dim, chunk, periodic):
    """The pass's scratch (:func:`_pass` ``sc``): differences (2n, chunk), six chunk vectors and, with periodic
    coordinates, ``g'`` (2n, chunk) (else a placeholder)."""
    return (np.empty((dim, chunk)), np.empty(chunk), np.empty(chunk), np.empty(chunk), np.empty(chunk),
            np.empty(chunk), np.empty(chunk), np.empty((dim if periodic else 1, chunk if periodic else 1)))


@_compiled(_JIT)
def _solve_one(x, w, h, cT, seg, family, eps, per, max_iter, out, sc, grad, hess, jac, delta, u, xi, warm, mid):
    """One implicit step for one instance: ``out <- Phi(x)``.  Returns ``(code, residual, iteration)``.

    The algorithm of :mod:`sympredict.symplectic.newton` (its module docstring; the NumPy
    reference :func:`sympredict.symplectic.newton.rollout_reference`), for one instance:
    symplectic Euler (``mid`` False): unknowns ``u = p1``,
    ``F = p1 - p0 + dT d_q s(q0, p1)``, Jacobian ``I + dT d_p d_q s``; midpoint
    (``mid`` True): unknowns ``u = z = (x0 + x1) / 2``, ``F = z - x0 - dT/2 J grad s(z)``,
    Jacobian ``I - dT/2 J Hess s(z)``.  ``u`` holds the first guess when ``warm``.
    The iteration count returned is that of the failure (``max_iter`` for code 3)
    or of the converged iterate.
    """
    dim = x.shape[0]
    n = dim // 2
    k = u.shape[0]  # unknowns: n (symplectic Euler) or 2n (midpoint)
    hh = 0.5 * h if mid else h  # the step in the residual
    if not warm:  # explicit guess from the gradient at x0: one pass over the centres
        _pass(x, w, cT, seg, family, eps, 0, per, sc, grad, hess)
        if mid:  # z ~ x0 + dT/2 J grad s(x0)
            for a in range(n):
                u[a] = x[a] + hh * grad[n + a]
                u[n + a] = x[n + a] + hh * -grad[a]
        else:  # p1 ~ p0 - dT d_q s(q0, p0)
            for a in range(n):
                u[a] = x[n + a] - h * grad[a]
    if not mid:
        for a in range(n):
            xi[a] = x[a]
    last = np.inf
    f_norm = np.inf
    # the watchdog (sympredict.newton_rule): the best iterate, its update and |F|_2, passes since, the step fraction
    u_best = np.empty(k)
    d_best = np.zeros(k)
    best = np.inf
    since = 0
    fraction = 1.0  # below 1: a damped trial from the best iterate
    for it in range(max_iter):
        for a in range(k):
            xi[dim - k + a] = u[a]
        floor = _pass(xi, w, cT, seg, family, eps, 2 if mid else 1, per, sc, grad, hess)
        f_norm = 0.0
        merit = 0.0
        scale = 0.0
        finite = True
        for a in range(k):
            if mid:
                jg = grad[n + a] if a < n else -grad[a - n]
                fk = u[a] - x[a] - hh * jg
                x_ref = x[a]
            else:
                fk = u[a] - x[n + a] + h * grad[a]
                x_ref = x[n + a]
            delta[a] = fk
            merit += fk * fk
            if not math.isfinite(fk):
                finite = False
            af = abs(fk)
            if af > f_norm or af != af:  # NaN propagates, as NumPy's max
                f_norm = af
            ap = abs(u[a])
            if ap > scale:
                scale = ap
            ap = abs(x_ref)
            if ap > scale:
                scale = ap
        f_floor = residual_floor(scale, floor, abs(hh))
        merit = math.sqrt(merit)
        new_best = accepted(merit, best, fraction, f_norm, f_floor)
        if fraction < 1.0 and not new_best:  # a damped trial rejected: halve it again
            fraction *= 0.5
            for a in range(k):
                u[a] = u_best[a] - fraction * d_best[a]
            continue
        if fraction == 1.0 and not new_best:
            since += 1
            if since >= WATCHDOG or not finite:  # no progress: back to the best iterate, half its step
                fraction = 0.5
                for a in range(k):
                    u[a] = u_best[a] - fraction * d_best[a]
                continue
        if not finite:
            return 1, f_norm, it
        if mid:  # I - dT/2 J H: rows of J H are (H[n + a], -H[a])
            for a in range(n):
                for c in range(dim):
                    jac[a, c] = -(hh * hess[n + a, c])
                    jac[n + a, c] = hh * hess[a, c]
        else:
            for a in range(n):
                for c in range(n):
                    jac[a, c] = h * hess[a, c]
        for a in range(k):
            jac[a, a] += 1.0
        if not lu_solve_inplace(jac, delta):  # the residual becomes the Newton update
            return 2, f_norm, it
        d_norm = 0.0
        for a in range(k):
            v = abs(delta[a])
            if v > d_norm or v != v:
                d_norm = v
        if converged(f_norm, f_floor, d_norm, last, scale):
            if mid:  # x1 = x0 + dT J grad s(z)
                for a in range(n):
                    out[a] = x[a] + h * grad[n + a]
                    out[n + a] = x[n + a] + h * -grad[a]
            else:
                for a in range(n):
                    out[a] = x[a] + h * grad[n + a]
                    out[n + a] = u[a]
            return 0, f_norm, it
        last = d_norm
        if new_best:
            best = merit
            since = 0
            for a in range(k):
                u_best[a] = u[a]
                d_best[a] = delta[a]
        fraction = 1.0
        for a in range(k):
            u[a] -= delta[a]
    return 3, f_norm, max_iter


@_compiled(_JIT)
def _matvec_into(M, x, out):
    """``out <- M x`` for a small square ``M`` (the split rollout's maps), ``O(dim^2)``."""
    for a in range(M.shape[0]):
        acc = 0.0
        for c in range(M.shape[1]):
            acc += M[a, c] * x[c]
        out[a] = acc


@_compiled(_JIT)
def _state(traj, prev, i, j, c):
    """Component ``c`` of instance ``i``'s state ``j`` of the rollout; ``j < 0``: the states before it (``prev``)."""
    if j >= 0:
        return traj[i, j, c]
    return prev[i, prev.shape[1] + j, c]


@_compiled(_JIT)
def _rollout_one(i, x0, W, h, cT, seg, family, eps, per, max_iter, chunk, traj, codes, fail_step, fail_iter, resid, passes,
                 warm_start, mid, pre, post, around, prev):
    """One instance's rollout; with ``around``: ``x_k+1 = post[i] S(pre[i] x_k)`` (S the implicit step).

    ``prev`` (B, j, 2n): the rollout's states before ``x0`` (oldest first), which a warm start extrapolates from.
    """
    dim = x0.shape[1]
    n = dim // 2
    k_unknown = dim if mid else n
    sc = _scratch(dim, chunk, per.shape[0] > 0)
    grad = np.empty(dim)
    hess = np.empty((dim, dim))
    jac = np.empty((k_unknown, k_unknown))
    u = np.empty(k_unknown)
    delta = np.empty(k_unknown)
    xi = np.empty(dim)
    y_in = np.empty(dim)  # around: the step's input pre x_k and output S(pre x_k)
    y_out = np.empty(dim)
    for a in range(dim):
        traj[i, 0, a] = x0[i, a]
    n_steps = traj.shape[1] - 1
    codes[i] = 0
    fail_step[i] = -1
    fail_iter[i] = -1
    resid[i] = 0.0
    n_prev = prev.shape[1]
    for k in range(n_steps):
        before = k + n_prev  # states before x_k
        warm = warm_start and before > 0
        if warm:  # extrapolate the previous steps: saves the explicit guess's pass
            off = 0 if mid else n
            for a in range(k_unknown):
                x_k = traj[i, k, off + a]
                x_1 = _state(traj, prev, i, k - 1, off + a)
                if before >= 2:  # x_k+1 ~ 3 x_k - 3 x_k-1 + x_k-2 (error O(dT^3))
                    nxt = 3.0 * (x_k - x_1) + _state(traj, prev, i, k - 2, off + a)
                else:  # x_k+1 ~ 2 x_k - x_k-1 (error O(dT^2))
                    nxt = 2.0 * x_k - x_1
                u[a] = 0.5 * (x_k + nxt) if mid else nxt  # midpoint: z = (x_k + x_k+1) / 2
        if around:
            _matvec_into(pre[i], traj[i, k], y_in)
            code, r, it = _solve_one(y_in, W[i], h[i], cT, seg, family, eps, per, max_iter, y_out, sc, grad, hess,
                                     jac, delta, u, xi, warm, mid)
            _matvec_into(post[i], y_out, traj[i, k + 1])
        else:
            code, r, it = _solve_one(traj[i, k], W[i], h[i], cT, seg, family, eps, per, max_iter, traj[i, k + 1], sc, grad,
                                     hess, jac, delta, u, xi, warm, mid)
        # (the explicit guess's gradient pass and) the Newton passes: it + 1, or max_iter without convergence
        passes[i] += (max_iter if code == 3 else it + 1) + (0 if warm else 1)
        if code != 0:
            codes[i] = code
            fail_step[i] = k
            fail_iter[i] = it
            resid[i] = r
            for kk in range(k + 1, n_steps + 1):
                for a in range(dim):
                    traj[i, kk, a] = np.nan
            return


@_compiled(_PJIT)
def _rollout_parallel(x0, W, h, cT, seg, family, eps, per, max_iter, chunk, traj, codes, fail_step, fail_iter, resid, passes,
                      warm_start, mid, pre, post, around, prev):
    for i in numba.prange(x0.shape[0]):
        _rollout_one(i, x0, W, h, cT, seg, family, eps, per, max_iter, chunk, traj, codes, fail_step, fail_iter,
                     resid, passes, warm_start, mid, pre, post, around, prev)


@_compiled(_JIT)
def _rollout_serial(x0, W, h, cT, seg, family, eps, per, max_iter, chunk, traj, codes, fail_step, fail_iter, resid, passes,
                    warm_start, mid, pre, post, around, prev):
    for i in range(x0.shape[0]):
        _rollout_one(i, x0, W, h, cT, seg, family, eps, per, max_iter, chunk, traj, codes, fail_step, fail_iter,
                     resid, passes, warm_start, mid, pre, post, around, prev)


@_compiled(_PJIT)
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


@_compiled(_PJIT)
def _gradients_kernel(xi, group, Wg, cT, seg, family, eps, per, chunk, out):
    dim = xi.shape[1]
    n_pts = xi.shape[0]
    block = 256  # points per task: the scratch is allocated once per block
    for blk in numba.prange((n_pts + block - 1) // block):
        sc = _scratch(dim, chunk, per.shape[0] > 0)
        hess = np.empty((dim, dim))
        for i in range(blk * block, min(n_pts, (blk + 1) * block)):
            _pass(xi[i], Wg[group[i]], cT, seg, family, eps, 0, per, sc, out[i], hess)


@_compiled(_JIT)
def _terms_kernel(xi, W, cT, seg, family, eps, per, chunk, mode, grad, hess, floor):
    dim = xi.shape[1]
    sc = _scratch(dim, chunk, per.shape[0] > 0)
    for i in range(xi.shape[0]):
        floor[i] = _pass(xi[i], W[i], cT, seg, family, eps, mode, per, sc, grad[i], hess[i])


@_compiled(_JIT)
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


@_compiled(_PJIT)
def _greedy_update_parallel(row, t, inv_pj, b, res, p2, j, breakdown, chunk, cmax, carg, cbest):
    for ch in numba.prange(cmax.shape[0]):
        _greedy_update_chunk(ch, row, t, inv_pj, b, res, p2, j, breakdown, chunk, cmax, carg, cbest)


@_compiled(_JIT)
def _greedy_update_serial(row, t, inv_pj, b, res, p2, j, breakdown, chunk, cmax, carg, cbest):
    for ch in range(cmax.shape[0]):
        _greedy_update_chunk(ch, row, t, inv_pj, b, res, p2, j, breakdown, chunk, cmax, carg, cbest)


@_compiled(_JIT)
def _hb_column2_range(p0, p1, points, mu, dt, xq, muq, dtq, b, e, first_family, emu, mu_family, edt, dt_family,
                      has_mu, has_dt, out):
    """Column entries of points ``p0:p1`` (``2n = 2``), the operations of the NumPy column in its order."""
    d_mu = mu.shape[1]
    for p in range(p0, p1):
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


@_compiled(_JIT)
def _hb_column2_serial(points, mu, dt, xq, muq, dtq, b, e, first_family, emu, mu_family, edt, dt_family,
                       has_mu, has_dt, out):
    _hb_column2_range(0, points.shape[0], points, mu, dt, xq, muq, dtq, b, e, first_family, emu,
                      mu_family, edt, dt_family, has_mu, has_dt, out)


@_compiled(_PJIT)
def _hb_column2_parallel(points, mu, dt, xq, muq, dtq, b, e, first_family, emu, mu_family, edt, dt_family,
                         has_mu, has_dt, out):
    n_pts = points.shape[0]
    block = 32768
    for k in numba.prange((n_pts + block - 1) // block):
        _hb_column2_range(k * block, min(n_pts, (k + 1) * block), points, mu, dt, xq, muq, dtq, b, e, first_family,
                          emu, mu_family, edt, dt_family, has_mu, has_dt, out)


@_compiled(_JIT)
def _hb_rows_range(k0, k1, points, mu, dt, xq, muq, dtq, comps, e, first_family, emu, mu_family, edt, dt_family,
                   has_mu, has_dt, out):
    """Gramian rows ``k0:k1`` of state-derivative functionals against every point (any ``2n``, plain kernel)."""
    n_pts, dim = points.shape
    d_mu = mu.shape[1]
    diff = np.empty(dim)
    for k in range(k0, k1):
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


@_compiled(_JIT)
def _hb_rows_serial(points, mu, dt, xq, muq, dtq, comps, e, first_family, emu, mu_family, edt, dt_family,
                    has_mu, has_dt, out):
    _hb_rows_range(0, xq.shape[0], points, mu, dt, xq, muq, dtq, comps, e, first_family, emu, mu_family, edt,
                   dt_family, has_mu, has_dt, out)


@_compiled(_PJIT)
def _hb_rows_parallel(points, mu, dt, xq, muq, dtq, comps, e, first_family, emu, mu_family, edt, dt_family,
                      has_mu, has_dt, out):
    for k in numba.prange(xq.shape[0]):
        _hb_rows_range(k, k + 1, points, mu, dt, xq, muq, dtq, comps, e, first_family, emu, mu_family, edt,
                       dt_family, has_mu, has_dt, out)


# --------------------------------------------------------------------------- kernels by family
_NAMESPACES: dict = {}


def _package_namespace() -> types.SimpleNamespace:
    """The disk-cached top-level kernels, by name."""
    return types.SimpleNamespace(**{name: globals()[name] for name, _, _ in _DEFINITIONS})


def _user_namespace(outside: tuple) -> types.SimpleNamespace:
    """The kernels compiled again for kernel families from outside the package (at most three), not cached on disk.

    Each kernel's Python function is rebound to a private copy of this module's
    globals in which the family dispatchers also know the families ``outside``
    (codes ``-1, -2, -3``) and the kernels call each other's copies: the same
    source, no closures.  Not cached: a family's type in numba's cache index
    would make it unreadable to any process that cannot import that family.
    """
    if len(outside) > 3:
        raise ValueError(f"at most three kernel families from outside the package per call, got {len(outside)}")
    scope = dict(globals())
    formulas = [compiled_formulas(f) for f in outside]
    for k, package in enumerate((_profile, _first_factors, _all_factors)):
        bound = {"_U0": formulas[0][k], "_U1": formulas[min(1, len(outside) - 1)][k],
                 "_U2": formulas[-1][k], "_PACKAGE": package}
        dispatcher = types.FunctionType(_user_formula.__code__, bound, package.__name__)
        scope[package.__name__] = numba.njit(dispatcher, **_EXACT)
    for name, function, flags in _DEFINITIONS:
        scope[name] = numba.njit(types.FunctionType(function.__code__, scope, name, function.__defaults__), **flags)
    return types.SimpleNamespace(**{name: scope[name] for name, _, _ in _DEFINITIONS})


def _kernels(*families):
    """The compiled kernels for these kernel families and each family's code.

    Returns
    -------
    namespace : SimpleNamespace
        The kernels by name: the disk-cached ones when every family is the
        package's own (:data:`FAMILY_CODES`), else their uncached copies
        (:func:`_user_namespace`).
    codes : tuple of FamilyCode
        The ``family`` argument of the kernels for each of ``families``.
    """
    _check_available()
    outside = tuple(dict.fromkeys(f for f in families if f not in FAMILY_CODES))
    serial = not parallel_safe()
    ns = _NAMESPACES.get((outside, serial))
    if ns is None:
        ns = _package_namespace() if not outside else _user_namespace(outside)
        ns = _NAMESPACES[(outside, serial)] = _serial_namespace(ns) if serial else ns
    codes = tuple(FAMILY_CODES[f] if f in FAMILY_CODES else FamilyCode(-1 - outside.index(f)) for f in families)
    return ns, codes


def _serial_namespace(ns: types.SimpleNamespace) -> types.SimpleNamespace:
    """``ns`` with each parallel kernel replaced by the same function compiled without ``parallel`` (uncached)."""
    out = types.SimpleNamespace(**vars(ns))
    for name, _function, flags in _DEFINITIONS:
        if flags.get("parallel"):
            setattr(out, name, numba.njit(nogil=True)(getattr(ns, name).py_func))
    return out


def _check_available():
    if not HAVE_NUMBA:
        raise ImportError("the compiled backend needs numba: pip install 'sympredict[fast]' (or numba>=0.59)")


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


#: The updates the compiled rollout solves (``mid`` flag of the compiled solver).
UPDATES = ("symplectic_euler", "midpoint")

#: Previous states a warm start extrapolates from.
WARM_HISTORY = 2


def check_around(around, b: int, dim: int, warm_start: bool):
    """``(pre, post)`` of a split rollout as C-contiguous float arrays (B, 2n, 2n), or ``None``; checked.

    Shared by the compiled rollout and the NumPy reference (:func:`sympredict.symplectic.newton.rollout_reference`).
    """
    if around is None:
        return None
    if warm_start:
        raise ValueError("newton_rollout: warm_start cannot be combined with around (pre, post maps)")
    pre, post = (np.ascontiguousarray(a, dtype=np.float64) for a in around)
    if pre.shape != (b, dim, dim) or post.shape != (b, dim, dim):
        raise ValueError(f"around: pre and post must have shape {(b, dim, dim)}, got {pre.shape} and {post.shape}")
    return pre, post


def previous_states(previous, b: int, dim: int) -> np.ndarray:
    """The states before a rollout's first, (B, j, 2n) with ``j <= WARM_HISTORY``, oldest first, C-contiguous
    (``None``: ``j = 0``); shared by both rollouts."""
    if previous is None:
        return np.empty((b, 0, dim))
    previous = np.asarray(previous, dtype=np.float64)
    if previous.ndim != 3 or previous.shape[0] != b or previous.shape[2] != dim:
        raise ValueError(f"previous must have shape (B, j, 2n) = ({b}, j, {dim}), got {previous.shape}")
    return np.ascontiguousarray(previous[:, max(0, previous.shape[1] - WARM_HISTORY):])


def newton_rollout(x0, weights, dt, layout: CenterLayout, kernel, max_iter: int, n_steps: int,
                   *, weights_ordered: bool = False, parallel=None, stats: Optional[dict] = None,
                   warm_start: bool = False, update: str = "symplectic_euler", around=None, previous=None):
    """``n_steps`` implicit steps (symplectic Euler or midpoint) for every instance, in compiled code.

    Parameters
    ----------
    x0 : ndarray of shape (B, 2n)
        Initial states.
    weights : ndarray of shape (B, m)
        Centre weights ``c_j k_mu k_dT`` per instance (:meth:`HBSurrogate.weights`), in the
        surrogate's centre order (or in ``layout.order`` when ``weights_ordered``).
    dt : ndarray of shape (B,)
        Macro steps.
    layout
        The centres (:class:`CenterLayout`).
    kernel
        The state kernel (a :class:`~sympredict.kernels.RadialKernel`; any registered family).
    max_iter
        Newton iterations per step.
    n_steps
        Number of macro steps ``K``.
    parallel
        Run instances on numba's threads; default: when ``B >= 8``.
    stats
        If a dict, ``stats['passes']`` receives the passes over the centres per
        instance (one per gradient or Newton evaluation), shape (B,).
    warm_start
        From the second state of the rollout on (counting ``previous``), start
        Newton from an extrapolation of the previous states instead of the
        explicit guess ``p0 - dT d_q s(q0, p0)``: saves that guess's pass over the
        centres.  ``p_k+1 ~ 3 p_k - 3 p_k-1 + p_k-2`` (error ``O(dT^3)``;
        ``2 p_k - p_k-1`` with one previous state), against the explicit guess's
        ``O(dT^2)``; for ``update='midpoint'`` the midpoint ``z = (x_k + x_k+1) / 2``
        with the same extrapolation of ``x_k+1``.  The converged result satisfies
        the same stopping rule.  Each instance stops iterating on its own
        (converged instances are dropped by construction: one loop per instance).
    previous : ndarray of shape (B, j, 2n), optional
        The rollout's states before ``x0``, oldest first (the last two are used): a
        warm start goes on from them (a chunked rollout's next chunk).
    update
        ``'symplectic_euler'``: ``F(p1) = p1 - p0 + dT d_q s(q0, p1)``, Jacobian
        ``I + dT d_p d_q s`` (``n`` unknowns, the Hessian block only);
        ``'midpoint'``: ``x1 = x0 + dT J grad s((x0 + x1) / 2)``, Newton on the
        midpoint ``z`` (``2n`` unknowns) with Jacobian ``I - dT/2 J Hess s(z)``
        (the full Hessian, its upper triangle computed).  The same pass, solver and
        stopping rule (:func:`sympredict.newton_rule.converged`) for both; they equal
        :func:`sympredict.symplectic.newton.solve_step_numpy` and
        :func:`sympredict.symplectic.newton.solve_midpoint_numpy` to round-off.
    around
        ``None``, or ``(pre, post)``, two arrays (B, 2n, 2n): each macro step is then
        ``x_k+1 = post S(pre x_k)`` with ``S`` the implicit step (the exact-linear-flow
        splitting, :class:`sympredict.flowmap.splitting.SplitKernelPredictor`); ``traj`` holds the
        ``x_k``.  Not combined with ``warm_start`` (its extrapolation would mix the
        coordinates of ``x_k`` and of the step's input).  ``+ O(K B (2n)^2)`` flops.

    Returns
    -------
    traj : ndarray of shape (B, K+1, 2n)
        Rows after an instance's failure are NaN.
    codes : ndarray of shape (B,), int64
        0 converged throughout, else the failure code (module docstring).
    fail_step : ndarray of shape (B,), int64
        Macro step of the failure (-1 if none).
    fail_iter : ndarray of shape (B,), int64
        Newton iteration of the failure (``max_iter`` for code 3, -1 if none).
    residual : ndarray of shape (B,)
        ``|F|_inf`` at the failure.

    Notes
    -----
    ``O(K B m (2n + n^2) (1 + n_newton))`` flops (midpoint: ``O(K B m (2n)^2 / 2 (1 + n_newton))``),
    ``O(B K 2n)`` memory plus ``O((2n + 6) chunk_size(2n))`` scratch per thread; instances in parallel.
    """
    if update not in UPDATES:
        raise ValueError(f"update must be one of {UPDATES}, got {update!r}")
    _check_available()
    x0 = np.ascontiguousarray(x0, dtype=np.float64)
    weights = np.asarray(weights, dtype=np.float64)
    weights = np.ascontiguousarray(weights if weights_ordered else weights[:, layout.order])
    dt = np.ascontiguousarray(dt, dtype=np.float64)
    b, dim = x0.shape
    traj = np.empty((b, int(n_steps) + 1, dim))
    codes = np.zeros(b, dtype=np.int64)
    fail_step = np.full(b, -1, dtype=np.int64)
    fail_iter = np.full(b, -1, dtype=np.int64)
    resid = np.zeros(b)
    if parallel is None:
        parallel = b >= PARALLEL_MIN_BATCH
    parallel = parallel and parallel_safe()  # a child forked after the parallel loops ran: the cached serial kernel
    maps = check_around(around, b, dim, warm_start)
    pre, post = maps if maps is not None else (np.empty((0, dim, dim)), np.empty((0, dim, dim)))
    prev = previous_states(previous, b, dim)
    ns, (family,) = _kernels(type(kernel))
    fn = ns._rollout_parallel if parallel else ns._rollout_serial
    passes = np.zeros(b, dtype=np.int64)
    _call(fn, x0, weights, dt, layout.cT, layout.seg, family, float(kernel.eps), layout.per, int(max_iter),
          chunk_size(dim), traj,
          codes, fail_step, fail_iter, resid, passes, bool(warm_start), update == "midpoint", pre, post,
          around is not None, prev)
    if stats is not None:
        stats["passes"] = passes
    return traj, codes, fail_step, fail_iter, resid


def newton_solve(x, weights, dt, layout: CenterLayout, kernel, max_iter: int, **kw):
    """One implicit step for every instance (:func:`newton_rollout` with ``K = 1``).

    Returns
    -------
    x1 : ndarray of shape (B, 2n)
    codes, fail_step, fail_iter, residual : ndarray of shape (B,)
    """
    traj, codes, fail_step, fail_iter, resid = newton_rollout(x, weights, dt, layout, kernel, max_iter, 1, **kw)
    return traj[:, 1], codes, fail_step, fail_iter, resid


#: Columns per chunk of :func:`matvec_t` (the float64 partial sums, 128 KiB, stay in L2).
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
    _check_available()
    out = np.empty(basis.shape[1])
    _call(_kernels()[0]._matvec_t_kernel, basis, int(m), np.ascontiguousarray(c, dtype=np.float64), out, MATVEC_CHUNK)
    return out


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
    _check_available()
    xi = np.ascontiguousarray(xi, dtype=np.float64)
    out = np.empty_like(xi)
    wg = np.ascontiguousarray(np.asarray(group_weights, dtype=np.float64)[:, layout.order])
    ns, (family,) = _kernels(type(kernel))
    _call(ns._gradients_kernel, xi, np.ascontiguousarray(group, dtype=np.int64), wg, layout.cT, layout.seg, family,
          float(kernel.eps), layout.per, chunk_size(xi.shape[1]), out)
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
    _check_available()
    xi = np.ascontiguousarray(xi, dtype=np.float64)
    b, dim = xi.shape
    grad, hess, floor = np.empty((b, dim)), np.empty((b, dim, dim)), np.empty(b)
    w = np.ascontiguousarray(np.asarray(weights, dtype=np.float64)[:, layout.order])
    ns, (family,) = _kernels(type(kernel))
    _call(ns._terms_kernel, xi, w, layout.cT, layout.seg, family, float(kernel.eps), layout.per, chunk_size(dim),
          2 if full else 1, grad, hess, floor)
    return grad, (hess if full else np.ascontiguousarray(hess[:, : dim // 2, : dim // 2])), floor


#: Whether the greedy's compiled O(N) passes (column, vector update) run on numba's threads.
GREEDY_PARALLEL = False

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
    _check_available()
    n = row.shape[0]
    n_chunks = (n + UPDATE_CHUNK - 1) // UPDATE_CHUNK
    cmax = np.empty(n_chunks)
    carg = np.empty(n_chunks, dtype=np.int64)
    cbest = np.empty(n_chunks)
    ns = _kernels()[0]
    kernel = ns._greedy_update_parallel if (parallel and n_chunks > 1) else ns._greedy_update_serial
    _call(kernel, row, t, float(inv_pj), float(b), res, p2, int(j), float(breakdown), UPDATE_CHUNK, cmax, carg, cbest)
    max_abs = cmax.max() if not np.isnan(cmax).any() else np.nan
    k = int(np.argmax(cbest))  # first chunk with the best score: first index overall
    return float(max_abs), int(carg[k]), float(cbest[k])


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
    _check_available()
    ns, (family,) = _kernels(IMQ)
    if in_cache:
        r2 = np.random.default_rng(0).uniform(0.0, 4.0, CHUNK)
        fA, fB, fC = np.empty(CHUNK), np.empty(CHUNK), np.empty(CHUNK)
        reps = max(1, n // CHUNK)
        _call(ns._chunk_factors_repeat, family, eps, r2, fA, fB, fC, CHUNK, 1)
        best = np.inf
        for _ in range(repeats):
            t0 = time.perf_counter()
            ns._chunk_factors_repeat(family, eps, r2, fA, fB, fC, CHUNK, reps)
            best = min(best, time.perf_counter() - t0)
        return float(best) / (reps * CHUNK)
    r2 = np.random.default_rng(0).uniform(0.0, 4.0, n)
    fA, fB, fC = np.empty(n), np.empty(n), np.empty(n)
    chunk_factors = ns._chunk_factors
    _call(chunk_factors, family, eps, r2, fA, fB, fC, n)
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
    if not HAVE_NUMBA or dim != 2 or d_mu > 2:
        return False
    return all(k is None or k.exact_arithmetic for k in (kernel.state, kernel.mu, kernel.dt))


def hb_column(kernel, points, mu, dt, representer, out: np.ndarray) -> np.ndarray:
    """The Gramian column of one state-derivative functional, compiled (see :func:`hb_column_supported`).

    ``out[2 p + a] = w_p (-B d_pa d_pb - A delta_ab)`` with ``d_p = xi_p - xi_q``,
    ``w_p = k_mu(mu_p, mu_q) k_dT(dT_p, dT_q)``; one pass, no temporaries.
    ``O(N)``; bit-identical to :meth:`sympredict.interpolation.functionals.HBFunctionals.column`.
    """
    xq, muq, dtq, b = representer
    # a dropped factor's family code is the state's (never used)
    state, mu_k, dt_k = (k if k is not None else kernel.state for k in (kernel.state, kernel.mu, kernel.dt))
    ns, (state_family, mu_family, dt_family) = _kernels(type(state), type(mu_k), type(dt_k))
    emu = kernel.mu.eps if kernel.mu is not None else 0.0
    edt = kernel.dt.eps if kernel.dt is not None else 0.0
    fn = ns._hb_column2_parallel if (GREEDY_PARALLEL and len(points) > 65536) else ns._hb_column2_serial
    _call(fn, points, mu, dt, np.ascontiguousarray(xq, dtype=np.float64), np.ascontiguousarray(muq, dtype=np.float64),
          float(dtq), int(b), float(kernel.state.eps), state_family, emu, mu_family, edt, dt_family,
          kernel.mu is not None, kernel.dt is not None, out)
    return out


def hb_rows_supported(kernel) -> bool:
    """Whether :func:`hb_rows` applies: numba installed, a plain product kernel (no periodic coordinates, no symmetry)."""
    return HAVE_NUMBA and kernel.periodic is None and kernel.symmetry is None


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
    state, mu_k, dt_k = (k if k is not None else kernel.state for k in (kernel.state, kernel.mu, kernel.dt))
    ns, (state_family, mu_family, dt_family) = _kernels(type(state), type(mu_k), type(dt_k))
    emu = kernel.mu.eps if kernel.mu is not None else 0.0
    edt = kernel.dt.eps if kernel.dt is not None else 0.0
    fn = ns._hb_rows_parallel if (GREEDY_PARALLEL and len(xq) > 1) else ns._hb_rows_serial
    f64 = lambda a: np.ascontiguousarray(a, dtype=np.float64)  # noqa: E731
    _call(fn, f64(points), f64(mu), f64(dt), f64(xq), f64(muq), f64(dtq),
          np.ascontiguousarray(comps, dtype=np.int64), float(kernel.state.eps), state_family, emu, mu_family, edt,
          dt_family, kernel.mu is not None, kernel.dt is not None, out)
    return out
