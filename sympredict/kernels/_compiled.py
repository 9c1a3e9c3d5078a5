"""The kernel families' formulas compiled (numba), and the compiled kernels by family.

Kernel formulas are not written here: the compiled code calls the families'
own static methods (:class:`sympredict.kernels.RadialKernel`), compiled from
the same Python functions (:func:`compiled_formulas`).  Every compiled kernel
of the package (:func:`sympredict._numba.compiled`: the surrogate's pass in
:mod:`sympredict.interpolation._compiled`, the greedy's updates in
:mod:`sympredict.interpolation.greedy._compiled`, the Newton rollout in
:mod:`sympredict.symplectic._compiled_newton`) is a top-level function that takes
the kernel family as an integer code and reaches the formulas through
:func:`_profile`, :func:`_first_factors` and :func:`_all_factors` (one branch per
family of the package, :data:`FAMILY_CODES`).  A family registered from outside
the package (:func:`sympredict.kernels.register_family`) has no code: for it
the same functions are compiled once more per process, bound to dispatchers
that know its formulas, and not cached on disk (:func:`family_kernels`).

The numba policy (flags, the disk cache, threads) is :mod:`sympredict._numba`.
"""

from __future__ import annotations

import types

from sympredict._numba import DEFINITIONS, EXACT, HAVE_NUMBA, check_available, jit_cached, numba
from sympredict._numba import parallel_safe
from sympredict.kernels import IMQ, Matern32, Matern52, PeriodicCoordinates

__all__ = ["FamilyCode", "FAMILY_CODES", "compiled_formulas", "family_kernels", "product_factors"]


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
        return tuple(jit_cached(getattr(family, name), EXACT) for name in _FORMULA_NAMES)
    return tuple(numba.njit(getattr(family, name), **EXACT) for name in _FORMULA_NAMES)


if HAVE_NUMBA:
    _imq_profile, _imq_first, _imq_all = _compile_formulas(IMQ, True)
    _m52_profile, _m52_first, _m52_all = _compile_formulas(Matern52, True)
    _m32_profile, _m32_first, _m32_all = _compile_formulas(Matern32, True)
    #: The periodic factor's ``(u, g, g', g'')`` (:meth:`sympredict.kernels.PeriodicCoordinates.formulas`, the same
    #: Python function, compiled for scalars).
    _periodic_formulas = jit_cached(PeriodicCoordinates.formulas, EXACT)
else:  # pragma: no cover
    _periodic_formulas = PeriodicCoordinates.formulas


def _formula(flags: dict):
    """Decorator of the family dispatchers: compiled with the formulas' exact flags, cached on disk."""

    def decorate(function):
        return jit_cached(function, flags) if HAVE_NUMBA else function

    return decorate


@_formula(EXACT)
def _profile(family, e, r):
    """``phi(r)`` of the family with code ``family`` (:data:`FAMILY_CODES`)."""
    if family == 0:
        return _imq_profile(e, r)
    elif family == 1:
        return _m52_profile(e, r)
    return _m32_profile(e, r)


@_formula(EXACT)
def _first_factors(family, e, r):
    """``(A, B)`` of the family with code ``family``."""
    if family == 0:
        return _imq_first(e, r)
    elif family == 1:
        return _m52_first(e, r)
    return _m32_first(e, r)


@_formula(EXACT)
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
    check_available()
    out = _COMPILED_FORMULAS.get(family)
    if out is None:
        if family in FAMILY_CODES:
            out = {
                IMQ: (_imq_profile, _imq_first, _imq_all),
                Matern52: (_m52_profile, _m52_first, _m52_all),
                Matern32: (_m32_profile, _m32_first, _m32_all),
            }[family]
        else:
            out = _compile_formulas(family, False)
        _COMPILED_FORMULAS[family] = out
    return out


# --------------------------------------------------------------------------- kernels by family
_NAMESPACES: dict = {}


def _package_namespace() -> types.SimpleNamespace:
    """The disk-cached top-level kernels, by name."""
    return types.SimpleNamespace(**{name: dispatcher for name, _, _, dispatcher in DEFINITIONS})


def _shared_scope() -> dict:
    """The globals of every compiled kernel's module in one dict (the names the kernels use must agree)."""
    scope: dict = {}
    for name, function, _, _ in DEFINITIONS:
        for used in function.__code__.co_names:
            if used in function.__globals__:
                value = function.__globals__[used]
                if used in scope and scope[used] is not value and not (type(value) is float and scope[used] == value):
                    raise RuntimeError(
                        f"compiled kernel {name!r} uses the global {used!r}, which another compiled "
                        "module defines differently; give one of them another name"
                    )
                scope[used] = value
    return scope


def _user_namespace(outside: tuple) -> types.SimpleNamespace:
    """The kernels compiled again for kernel families from outside the package (at most three), not cached on disk.

    Each kernel's Python function is rebound to a private copy of its module's
    globals (one scope for all of them, :func:`_shared_scope`) in which the family
    dispatchers also know the families ``outside`` (codes ``-1, -2, -3``) and the
    kernels call each other's copies: the same source, no closures.  Not cached:
    a family's type in numba's cache index would make it unreadable to any
    process that cannot import that family.
    """
    if len(outside) > 3:
        raise ValueError(f"at most three kernel families from outside the package per call, got {len(outside)}")
    scope = _shared_scope()
    formulas = [compiled_formulas(f) for f in outside]
    for k, package in enumerate((_profile, _first_factors, _all_factors)):
        bound = {
            "_U0": formulas[0][k],
            "_U1": formulas[min(1, len(outside) - 1)][k],
            "_U2": formulas[-1][k],
            "_PACKAGE": package,
        }
        dispatcher = types.FunctionType(_user_formula.__code__, bound, package.__name__)
        scope[package.__name__] = numba.njit(dispatcher, **EXACT)
    for name, function, flags, _ in DEFINITIONS:
        scope[name] = numba.njit(types.FunctionType(function.__code__, scope, name, function.__defaults__), **flags)
    return types.SimpleNamespace(**{name: scope[name] for name, _, _, _ in DEFINITIONS})


def family_kernels(*families):
    """The compiled kernels for these kernel families and each family's code.

    Returns
    -------
    namespace : SimpleNamespace
        The kernels by name (of every compiled module imported so far): the disk-cached ones when every family is the
        package's own (:data:`FAMILY_CODES`), else their uncached copies
        (:func:`_user_namespace`).
    codes : tuple of FamilyCode
        The ``family`` argument of the kernels for each of ``families``.
    """
    check_available()
    outside = tuple(dict.fromkeys(f for f in families if f not in FAMILY_CODES))
    serial = not parallel_safe()
    key = (outside, serial, len(DEFINITIONS))  # a compiled module imported later adds its kernels
    ns = _NAMESPACES.get(key)
    if ns is None:
        ns = _package_namespace() if not outside else _user_namespace(outside)
        ns = _NAMESPACES[key] = _serial_namespace(ns) if serial else ns
    codes = tuple(FAMILY_CODES[f] if f in FAMILY_CODES else FamilyCode(-1 - outside.index(f)) for f in families)
    return ns, codes


def product_factors(kernel) -> tuple:
    """The compiled kernels for a product kernel's families, and its factors as the compiled Gramian kernels take them.

    Returns
    -------
    namespace : SimpleNamespace
        As :func:`family_kernels`.
    factors : tuple
        ``(e, state_family, e_mu, mu_family, e_dt, dt_family, has_mu, has_dt)``: the shape parameters and family
        codes of the state, ``mu`` and ``dT`` factors and whether the latter two are present (a dropped factor's
        shape parameter is 0 and its family code the state's, never used).
    """
    state, mu_k, dt_k = (k if k is not None else kernel.state for k in (kernel.state, kernel.mu, kernel.dt))
    ns, (state_family, mu_family, dt_family) = family_kernels(type(state), type(mu_k), type(dt_k))
    emu = kernel.mu.eps if kernel.mu is not None else 0.0
    edt = kernel.dt.eps if kernel.dt is not None else 0.0
    has_mu, has_dt = kernel.mu is not None, kernel.dt is not None
    return ns, (float(kernel.state.eps), state_family, emu, mu_family, edt, dt_family, has_mu, has_dt)


def _serial_namespace(ns: types.SimpleNamespace) -> types.SimpleNamespace:
    """``ns`` with each parallel kernel replaced by the same function compiled without ``parallel`` (uncached)."""
    out = types.SimpleNamespace(**vars(ns))
    for name, _function, flags, _ in DEFINITIONS:
        if flags.get("parallel"):
            setattr(out, name, numba.njit(nogil=True)(getattr(ns, name).py_func))
    return out
