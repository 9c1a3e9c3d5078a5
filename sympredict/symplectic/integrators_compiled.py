"""Compiled, batched classical symplectic integrators (numba), on the same footing as the kernel rollout.

:func:`rollout` integrates ``B`` instances, each with its own parameter ``mu``
and macro step ``dt``, over ``K`` macro steps of ``r`` sub-steps each, and
returns ``(B, K+1, 2n)`` states, in one compiled call with the instances on
numba's threads (``numba.prange``; ``numba.set_num_threads`` sets how many).
The schemes (:data:`sympredict.symplectic.integrators.SCHEMES`):

=====================  =====  ==============================  ==================================
scheme                 order  needs                           cost per sub-step
=====================  =====  ==============================  ==================================
``stormer_verlet``     2      separable ``H = T(p) + V(q)``   1 ``grad V`` + 1 ``grad T``
``yoshida4``           4      separable                       3 ``grad V`` + 3 ``grad T``
``kahan_li6``          6      separable                       9 ``grad V`` + 9 ``grad T``
``implicit_midpoint``  2      any ``H``: ``grad H``, Hessian  per Newton iteration: ``grad H``,
                                                              Hessian, a dense ``2n x 2n`` LU
=====================  =====  ==============================  ==================================

The compositions use the coefficients of
:data:`sympredict.symplectic.integrators.COMPOSITIONS` (defined there once).  ``grad V``
at the end of a Störmer–Verlet stage is reused at the start of the next one
(the state has not changed), so a composition of ``s`` stages costs ``s``
evaluations of each gradient, not ``2s`` as in the NumPy reference; the
arithmetic is otherwise that of the reference, operation for operation.

A system is described *per instance* by a :class:`PointwiseHamiltonian`: numba
functions with the fixed signature (:data:`GRADIENT_SIGNATURE`)::

    grad_V(q, mu, fargs, iargs, out)      # out[:] = dV/dq (q; mu),   q, out: (n,)
    grad_T(p, mu, fargs, iargs, out)      # out[:] = dT/dp (p; mu),   p, out: (n,)
    grad_H(x, mu, fargs, iargs, out)      # out[:] = dH/dx (x; mu),   x, out: (2n,)
    hess_H(x, mu, fargs, iargs, out)      # out[:, :] = d^2H/dx^2,     out: (2n, 2n)

all arrays C-contiguous: ``mu`` float64 ``(d_mu,)`` (the instance's
parameters), ``fargs`` float64 ``(·,)`` and ``iargs`` int64 ``(·,)`` the
system's constants, the same for every instance (masses, matrices, a CSR
pattern: whatever the functions need).  The rollout is compiled once for this
signature (numba's first-class function types), not once per system, and is
cached on disk.  The shipped systems provide theirs through ``pointwise()``
(:mod:`sympredict.systems`).

For plain Python callables, or without numba, :func:`rollout` runs the NumPy
reference (:func:`sympredict.symplectic.integrators.integrate`) on the system's batched
``gradient(x, mu)`` / ``hessian(x, mu)``.

Implicit midpoint solves ``G(x1) = x1 - x0 - h J grad H((x0 + x1)/2) = 0`` by
Newton with the analytic Jacobian ``I - (h/2) J hess H``, instance by instance,
with the stopping rule of :func:`sympredict.symplectic.integrators.implicit_midpoint_step`.
Failure codes per instance: 0 converged, 1 non-finite iterate, 2 singular
Jacobian (exact zero pivot), 3 no convergence in ``max_iter`` iterations.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from sympredict._numeric import fill_nan_after, lu_solve_inplace
from sympredict._checks import as_choice, as_even_dimension, as_parameter, as_positive_int, as_states, as_steps
from sympredict.exceptions import NewtonConvergenceError
from sympredict.symplectic.integrators import COMPOSITIONS, SCHEMES, integrate

from sympredict._numba import HAVE_NUMBA, JIT, call, jit_cached, jit_user, numba, parallel_safe

_nt = numba.types if HAVE_NUMBA else None

__all__ = [
    "HAVE_NUMBA",
    "GRADIENT_SIGNATURE",
    "HESSIAN_SIGNATURE",
    "EXPLICIT_SCHEMES",
    "PointwiseHamiltonian",
    "jit_pointwise",
    "rollout",
    "unit_mass_grad_T",
    "csr_matvec",
    "csr_fill_dense",
]

#: The schemes that need a separable Hamiltonian (compositions of Störmer–Verlet).
EXPLICIT_SCHEMES = tuple(COMPOSITIONS)

#: Batches below this size run on one thread (thread start-up costs more).
PARALLEL_MIN_BATCH = 8

_EPS = float(np.finfo(float).eps)

if HAVE_NUMBA:
    #: numba signature of the per-instance gradients: ``(z, mu, fargs, iargs, out) -> None``.
    GRADIENT_SIGNATURE = _nt.void(
        _nt.float64[::1], _nt.float64[::1], _nt.float64[::1], _nt.int64[::1], _nt.float64[::1]
    )
    #: numba signature of the per-instance Hessian: ``(x, mu, fargs, iargs, out) -> None``, ``out`` 2-D.
    HESSIAN_SIGNATURE = _nt.void(
        _nt.float64[::1], _nt.float64[::1], _nt.float64[::1], _nt.int64[::1], _nt.float64[:, ::1]
    )
else:  # pragma: no cover
    GRADIENT_SIGNATURE = None
    HESSIAN_SIGNATURE = None


def jit_pointwise(fn):
    """Compile a per-instance gradient or Hessian with numba (lazily, cached on disk); unchanged without numba.

    The function must follow the signature of the module docstring; it is
    compiled for :data:`GRADIENT_SIGNATURE` / :data:`HESSIAN_SIGNATURE` on
    first use by :func:`rollout`.
    """
    if not HAVE_NUMBA:  # pragma: no cover
        return fn
    return jit_user(fn)


@jit_pointwise
def unit_mass_grad_T(p, mu, fargs, iargs, out):
    """``dT/dp = p`` of the unit-mass kinetic energy ``T = |p|^2 / 2`` (a per-instance gradient; any length)."""
    for j in range(p.shape[0]):
        out[j] = p[j]


# A sparse matrix ``A`` (n, n) in a system's constants (:meth:`PointwiseHamiltonian.unit_mass_csr`): its CSR values
# ``data`` in ``fargs`` (after the system's own constants), ``iargs = (indptr, indices)``, ``len(indptr) = n + 1``.
@jit_pointwise
def csr_matvec(q, scale, data, iargs, out):
    """``out = scale * (A q)`` (n,), ``A`` in CSR (``data``, ``iargs = (indptr, indices)``); ``O(nnz(A))``."""
    n = q.shape[0]
    for j in range(n):
        s = 0.0
        for k in range(iargs[j], iargs[j + 1]):
            s += data[k] * q[iargs[n + 1 + k]]
        out[j] = scale * s


@jit_pointwise
def csr_fill_dense(n, scale, data, iargs, out):
    """``out[:n, :n] = scale * A`` on ``A``'s pattern (the rest of ``out`` untouched), ``A`` in CSR as in
    :func:`csr_matvec`; ``O(nnz(A))``."""
    for j in range(n):
        for k in range(iargs[j], iargs[j + 1]):
            out[j, iargs[n + 1 + k]] = scale * data[k]


def _is_numba(fn) -> bool:
    return HAVE_NUMBA and isinstance(fn, numba.core.registry.CPUDispatcher)


class PointwiseHamiltonian:
    """A Hamiltonian given by per-instance gradient functions (see the module docstring).

    Parameters
    ----------
    dim : int
        Phase-space dimension ``2n``.
    n_mu : int
        Parameters per instance ``d_mu``.
    grad_T, grad_V : callable, optional
        ``dT/dp`` and ``dV/dq`` of a separable ``H = T(p; mu) + V(q; mu)``
        (the explicit schemes need both).
    grad_H, hess_H : callable, optional
        ``dH/dx`` and ``d^2H/dx^2`` (implicit midpoint).  Without ``grad_H``
        but with ``grad_T`` and ``grad_V``, the gradient is assembled from them
        (NumPy path only; the compiled implicit midpoint needs both functions).
    fargs : array_like of float, optional
        Float constants passed to every call (shape (·,)).
    iargs : array_like of int, optional
        Integer constants passed to every call (shape (·,)).
    check_mu : callable, optional
        ``check_mu(mu)`` with ``mu`` of shape (B, d_mu); raises ``ValueError``
        for parameters outside the system's domain.
    name : str

    Notes
    -----
    Numba-jitted functions (``numba.njit``, e.g. via :func:`jit_pointwise`) run
    compiled; plain Python callables make :func:`rollout` fall back to the
    NumPy reference, whose batched :meth:`gradient` / :meth:`hessian` here loop
    over the instances in Python (``O(B)`` calls per evaluation: slow, but
    correct).
    """

    def __init__(
        self,
        dim,
        n_mu,
        *,
        grad_T=None,
        grad_V=None,
        grad_H=None,
        hess_H=None,
        fargs=(),
        iargs=(),
        check_mu=None,
        name: str = "PointwiseHamiltonian",
    ):
        self.dim = as_even_dimension(as_positive_int(dim, "dim", minimum=2), "dim")
        self.n_mu = as_positive_int(n_mu, "n_mu")
        for arg, fn in (("grad_T", grad_T), ("grad_V", grad_V), ("grad_H", grad_H), ("hess_H", hess_H)):
            if fn is not None and not callable(fn):
                raise ValueError(f"{arg} must be callable, got {type(fn).__name__}")
        if (grad_T is None) != (grad_V is None):
            raise ValueError("grad_T and grad_V must be given together (a separable H = T(p) + V(q))")
        if grad_H is None and grad_T is None:
            raise ValueError("give grad_T and grad_V (separable H), or grad_H (and hess_H for implicit midpoint)")
        self.grad_T, self.grad_V, self.grad_H, self.hess_H = grad_T, grad_V, grad_H, hess_H
        self.fargs = np.ascontiguousarray(np.asarray(fargs, dtype=np.float64).reshape(-1))
        iargs = np.asarray(iargs)
        if iargs.size and not np.issubdtype(iargs.dtype, np.integer):
            raise ValueError(f"iargs must be integers, got dtype {iargs.dtype}")
        self.iargs = np.ascontiguousarray(iargs.astype(np.int64).reshape(-1))
        self._check_mu = check_mu
        self.name = name

    @classmethod
    def unit_mass_csr(
        cls, A, *, grad_V, grad_H, hess_H=None, head=(), n_mu: int = 1, check_mu=None, name: str
    ) -> "PointwiseHamiltonian":
        """``H = |p|^2 / 2 + V(q; mu)`` whose functions read a sparse ``A`` (n, n) (e.g. a stiffness matrix) with
        :func:`csr_matvec` / :func:`csr_fill_dense`: ``fargs = (*head, A.data)``, ``iargs = (A.indptr, A.indices)``.

        ``grad_T`` is :func:`unit_mass_grad_T`; the functions find ``A``'s values at ``fargs[len(head):]``; the
        other parameters are :class:`PointwiseHamiltonian`'s.  The phase space has dimension ``2n``.
        """
        A = A.tocsr()
        A.sort_indices()
        return cls(
            2 * A.shape[0],
            n_mu,
            grad_T=unit_mass_grad_T,
            grad_V=grad_V,
            grad_H=grad_H,
            hess_H=hess_H,
            fargs=np.concatenate([np.asarray(head, dtype=np.float64), A.data]),
            iargs=np.concatenate([A.indptr, A.indices]),
            check_mu=check_mu,
            name=name,
        )

    def __repr__(self) -> str:
        return f"{self.name}(dim={self.dim}, n_mu={self.n_mu}, separable={self.separable})"

    def pointwise(self) -> "PointwiseHamiltonian":
        """Itself (the protocol of the shipped systems)."""
        return self

    @property
    def separable(self) -> bool:
        """Whether ``grad_T`` and ``grad_V`` are given (the explicit schemes can run)."""
        return self.grad_T is not None

    def check_mu(self, mu) -> None:
        """Raise ``ValueError`` for parameters (B, d_mu) outside the system's domain."""
        if self._check_mu is not None:
            self._check_mu(mu)

    def compiled_for(self, scheme: str) -> bool:
        """Whether the functions ``scheme`` needs are numba-jitted."""
        if scheme in EXPLICIT_SCHEMES:
            return self.separable and _is_numba(self.grad_T) and _is_numba(self.grad_V)
        return _is_numba(self.grad_H) and _is_numba(self.hess_H)

    # ------------------------------------------------ batched NumPy protocol
    def gradient(self, x, mu) -> np.ndarray:
        """``grad H`` of states (B, 2n), one function call per instance; shape (B, 2n)."""
        x = np.ascontiguousarray(x, dtype=np.float64)
        mu = as_parameter(mu, len(x), self.n_mu)
        out = np.empty_like(x)
        n = self.dim // 2
        for i in range(len(x)):
            if self.grad_H is not None:
                self.grad_H(x[i], mu[i], self.fargs, self.iargs, out[i])
            else:
                gq, gp = np.empty(n), np.empty(n)
                self.grad_V(np.ascontiguousarray(x[i, :n]), mu[i], self.fargs, self.iargs, gq)
                self.grad_T(np.ascontiguousarray(x[i, n:]), mu[i], self.fargs, self.iargs, gp)
                out[i, :n], out[i, n:] = gq, gp
        return out

    def hessian(self, x, mu) -> np.ndarray:
        """``hess H`` of states (B, 2n), one call per instance; shape (B, 2n, 2n)."""
        if self.hess_H is None:
            raise ValueError(f"{self.name} has no hess_H: implicit midpoint needs the Hessian")
        x = np.ascontiguousarray(x, dtype=np.float64)
        mu = as_parameter(mu, len(x), self.n_mu)
        out = np.empty((len(x), self.dim, self.dim))
        for i in range(len(x)):
            self.hess_H(x[i], mu[i], self.fargs, self.iargs, out[i])
        return out


# ---------------------------------------------------------------- compiled code
def _explicit_instance(i, grad_T, grad_V, fargs, iargs, x0, mu, h, n_steps, substeps, fractions, traj):
    """One instance of the composed Störmer–Verlet rollout (kick, drift, kick per stage; grad V reused)."""
    dim = x0.shape[1]
    n = dim // 2
    q = x0[i, :n].copy()
    p = x0[i, n:].copy()
    gq = np.empty(n)
    gp = np.empty(n)
    mui = mu[i]
    for j in range(dim):
        traj[i, 0, j] = x0[i, j]
    hs = h[i] / substeps
    grad_V(q, mui, fargs, iargs, gq)
    for k in range(n_steps):
        for _ in range(substeps):
            for g in fractions:
                a = g * hs
                for j in range(n):
                    p[j] -= 0.5 * a * gq[j]
                grad_T(p, mui, fargs, iargs, gp)
                for j in range(n):
                    q[j] += a * gp[j]
                grad_V(q, mui, fargs, iargs, gq)
                for j in range(n):
                    p[j] -= 0.5 * a * gq[j]
        for j in range(n):
            traj[i, k + 1, j] = q[j]
            traj[i, k + 1, n + j] = p[j]


def _explicit_all(grad_T, grad_V, fargs, iargs, x0, mu, h, n_steps, substeps, fractions, traj):
    """Every instance (:func:`_explicit_instance`), compiled as ``_explicit_parallel`` (instances on numba's threads)
    and ``_explicit_serial`` (a plain loop)."""
    for i in numba.prange(x0.shape[0]):
        _explicit_one(i, grad_T, grad_V, fargs, iargs, x0, mu, h, n_steps, substeps, fractions, traj)


def _midpoint_instance(
    i, grad_H, hess_H, fargs, iargs, x0, mu, h, n_steps, substeps, max_iter, traj, codes, fail_step, resid
):
    """One instance of the implicit-midpoint rollout (Newton, stopping rule of the NumPy reference)."""
    dim = x0.shape[1]
    n = dim // 2
    x = x0[i].copy()
    x1 = np.empty(dim)
    mid = np.empty(dim)
    g = np.empty(dim)
    hess = np.empty((dim, dim))
    jac = np.empty((dim, dim))
    delta = np.empty(dim)
    mui = mu[i]
    hs = h[i] / substeps
    c = 0.5 * hs
    for j in range(dim):
        traj[i, 0, j] = x[j]
    for k in range(n_steps):
        for _ in range(substeps):
            grad_H(x, mui, fargs, iargs, g)
            for j in range(n):  # explicit Euler predictor x + h J grad H(x)
                x1[j] = x[j] + hs * g[n + j]
                x1[n + j] = x[n + j] + hs * (-g[j])
            last = np.inf
            code = 3
            for _it in range(max_iter):
                for j in range(dim):
                    mid[j] = 0.5 * (x[j] + x1[j])
                grad_H(mid, mui, fargs, iargs, g)
                hess_H(mid, mui, fargs, iargs, hess)
                for j in range(n):
                    delta[j] = x1[j] - x[j] - hs * g[n + j]
                    delta[n + j] = x1[n + j] - x[n + j] - hs * (-g[j])
                    for l in range(dim):  # I - (h/2) J hess: rows of J hess are (hess_p., -hess_q.)
                        jac[j, l] = -(c * hess[n + j, l])
                        jac[n + j, l] = -(c * (-hess[j, l]))
                for j in range(dim):
                    jac[j, j] += 1.0
                if not lu_solve_inplace(jac, delta):
                    code = 2
                    break
                d_norm = 0.0
                scale = 0.0
                for j in range(dim):
                    x1[j] -= delta[j]
                    d_norm = max(d_norm, abs(delta[j]))
                    scale = max(scale, abs(x1[j]))
                if not math.isfinite(d_norm):
                    code = 1
                    last = d_norm
                    break
                scale += 1.0
                if d_norm <= 4.0 * _EPS * scale or (d_norm >= 0.5 * last and d_norm <= 1e3 * _EPS * scale):
                    code = 0
                    break
                last = d_norm
            if code != 0:
                codes[i] = code
                fail_step[i] = k
                resid[i] = last
                fill_nan_after(traj, i, k)
                return
            for j in range(dim):
                x[j] = x1[j]
        for j in range(dim):
            traj[i, k + 1, j] = x[j]


def _midpoint_all(grad_H, hess_H, fargs, iargs, x0, mu, h, n_steps, substeps, max_iter, traj, codes, fail_step, resid):
    """Every instance (:func:`_midpoint_instance`), compiled as ``_midpoint_parallel`` and ``_midpoint_serial``."""
    for i in numba.prange(x0.shape[0]):
        _midpoint_one(
            i, grad_H, hess_H, fargs, iargs, x0, mu, h, n_steps, substeps, max_iter, traj, codes, fail_step, resid
        )


if HAVE_NUMBA:
    _explicit_one = jit_cached(_explicit_instance, JIT)
    _midpoint_one = jit_cached(_midpoint_instance, JIT)
    _explicit_parallel = jit_cached(_explicit_all, dict(JIT, parallel=True), "_explicit_parallel")
    _explicit_serial = jit_cached(_explicit_all, JIT, "_explicit_serial")
    _midpoint_parallel = jit_cached(_midpoint_all, dict(JIT, parallel=True), "_midpoint_parallel")
    _midpoint_serial = jit_cached(_midpoint_all, JIT, "_midpoint_serial")


@functools.lru_cache(maxsize=None)
def _kernels():
    """Compile (or load from numba's disk cache) the rollouts for the function-type signature, once."""
    t = _nt
    fg, fh = t.FunctionType(GRADIENT_SIGNATURE), t.FunctionType(HESSIAN_SIGNATURE)
    a1, a2, a3, i1, i8 = t.float64[::1], t.float64[:, ::1], t.float64[:, :, ::1], t.int64[::1], t.int64
    explicit_sig = t.void(fg, fg, a1, i1, a2, a2, a1, i8, i8, a1, a3)
    midpoint_sig = t.void(fg, fh, a1, i1, a2, a2, a1, i8, i8, i8, a3, i1, i1, a1)
    out = {}
    for key, fn, sig in (
        ("explicit_parallel", _explicit_parallel, explicit_sig),
        ("explicit_serial", _explicit_serial, explicit_sig),
        ("midpoint_parallel", _midpoint_parallel, midpoint_sig),
        ("midpoint_serial", _midpoint_serial, midpoint_sig),
    ):
        call(fn.compile, sig)  # a corrupt or unwritable disk cache costs compilation, not an error
        fn.disable_compile()
        out[key] = fn
    return out


def _compile_pointwise(fn, signature, arg: str):
    """Compile a numba function for the fixed signature; ``ValueError`` naming ``arg`` if it does not fit."""
    if signature.args in fn.overloads:  # already compiled (or loaded from the disk cache): skip numba's lock
        return
    try:
        fn.compile(signature)
    except Exception as exc:  # numba raises TypingError, TypeError, ... for a wrong signature
        raise ValueError(
            f"{arg} does not compile for the signature {arg}(z, mu, fargs, iargs, out) of "
            f"sympredict.symplectic.integrators_compiled ({type(exc).__name__}: {' '.join(str(exc).split())[:600]})"
        ) from None


def rollout(
    system,
    x0,
    mu,
    dt,
    n_steps: int,
    *,
    scheme: str = "stormer_verlet",
    substeps: int = 1,
    backend: str = "auto",
    max_iter: int = 50,
    parallel=None,
) -> np.ndarray:
    """Trajectories of a classical symplectic scheme, ``K`` macro steps of ``r`` sub-steps each.

    Parameters
    ----------
    system
        A shipped system (anything with ``pointwise()`` returning a
        :class:`PointwiseHamiltonian`), a :class:`PointwiseHamiltonian`, or
        any object with the batched NumPy protocol of
        :mod:`sympredict.symplectic.integrators` (``gradient``, ``hessian``; NumPy path).
    x0 : array_like of shape (B, 2n) or (2n,)
        Initial states ``(q, p)``.
    mu : float or array_like of shape (B,), (B, d_mu) or (d_mu,)
        Parameters per instance.
    dt : float or array_like of shape (B,)
        Macro step per instance (the output spacing).
    n_steps : int
        Macro steps ``K``.
    scheme : str
        ``'stormer_verlet'``, ``'yoshida4'``, ``'kahan_li6'`` (separable ``H``)
        or ``'implicit_midpoint'`` (any ``H``).
    substeps : int
        Sub-steps ``r`` per macro step (step size ``dt / r``).
    backend : str
        ``'auto'`` (compiled where numba and jitted functions are available,
        else NumPy), ``'numba'`` (``ValueError`` if not possible) or ``'numpy'``.
    max_iter : int
        Newton iterations per implicit-midpoint step.
    parallel : bool, optional
        Run instances on numba's threads; default: when ``B >= 8``.

    Returns
    -------
    ndarray of shape (B, K+1, 2n), or (K+1, 2n) for one state ``(2n,)``
        States at ``t_k = k dt``.

    Raises
    ------
    ValueError
        Bad input (the message names the argument), or an explicit scheme on a
        non-separable system.
    NewtonConvergenceError
        Implicit midpoint failed for some instances (``step``: the first macro
        step at which one failed; ``instances``: all that failed).

    Notes
    -----
    ``O(B K r s c)`` for ``s`` stages and gradient cost ``c``; implicit
    midpoint ``O(B K r n_newton (c + (2n)^3))``.  Memory ``O(B K 2n)``.
    """
    as_choice(scheme, "scheme", sorted(SCHEMES))
    as_choice(backend, "backend", ("auto", "numba", "numpy"))
    x0, single = as_states(x0, "x0", dim=getattr(system, "dim", None))
    b = len(x0)
    mu = as_parameter(mu, b, getattr(system, "n_mu", None), name="mu")
    dt = as_steps(dt, b, name="dt")
    n_steps = as_positive_int(n_steps, "n_steps", minimum=0)
    substeps = as_positive_int(substeps, "substeps")
    max_iter = as_positive_int(max_iter, "max_iter")
    spec = system.pointwise() if hasattr(system, "pointwise") else None
    if spec is not None:
        spec.check_mu(mu)
        if scheme in EXPLICIT_SCHEMES and not spec.separable:
            raise ValueError(
                f"scheme {scheme!r} needs a separable Hamiltonian H = T(p) + V(q) (grad_T and grad_V); "
                f"{spec.name} is not: use scheme='implicit_midpoint'"
            )
    compiled = backend != "numpy" and HAVE_NUMBA and spec is not None and spec.compiled_for(scheme)
    if backend == "numba" and not compiled:
        why = (
            "numba is not installed"
            if not HAVE_NUMBA
            else "the system has no pointwise() description"
            if spec is None
            else "its functions for this scheme are not numba-jitted"
        )
        raise ValueError(f"backend='numba' is not possible for scheme {scheme!r}: {why}")
    if not compiled:
        traj = integrate(SCHEMES[scheme], system, x0, mu, dt / substeps, n_steps, substeps)
        return traj[0] if single else traj

    kernels = _kernels()
    # numba's signatures are for writable C arrays: broadcast (read-only) views are copied
    x0, mu, dt = (np.array(a, dtype=np.float64, order="C") for a in (x0, mu, dt))
    if parallel is None:
        parallel = b >= PARALLEL_MIN_BATCH
    parallel = parallel and parallel_safe()  # not in a child forked after the parallel loops ran
    traj = np.empty((b, n_steps + 1, x0.shape[1]))
    codes = np.zeros(b, dtype=np.int64)
    fail_step = np.full(b, -1, dtype=np.int64)
    resid = np.zeros(b)
    # the scheme chooses the kernel, its two pointwise functions and the arguments after the common ones
    if scheme in EXPLICIT_SCHEMES:
        kind, functions = "explicit", (("grad_T", GRADIENT_SIGNATURE), ("grad_V", GRADIENT_SIGNATURE))
        last = (np.asarray(COMPOSITIONS[scheme], dtype=np.float64), traj)
    else:
        kind, functions = "midpoint", (("grad_H", GRADIENT_SIGNATURE), ("hess_H", HESSIAN_SIGNATURE))
        last = (max_iter, traj, codes, fail_step, resid)
    for name, signature in functions:
        _compile_pointwise(getattr(spec, name), signature, name)
    fn = kernels[f"{kind}_parallel" if parallel else f"{kind}_serial"]
    fn(*(getattr(spec, name) for name, _ in functions), spec.fargs, spec.iargs, x0, mu, dt, n_steps, substeps, *last)
    bad = np.flatnonzero(codes)  # the explicit kernels leave them 0
    if bad.size:
        reasons = {
            1: "produced a non-finite iterate",
            2: "met a singular Jacobian",
            3: f"did not converge in {max_iter} iterations",
        }
        reason = "(implicit midpoint, compiled) " + "; ".join(sorted({reasons[int(c)] for c in codes[bad]}))
        raise NewtonConvergenceError(bad, resid[bad], reason=reason, step=int(fail_step[bad].min()))
    return traj[0] if single else traj
