"""The package's numba policy: availability, compile flags, the disk cache and its recovery, threads.

Every compiled module of the package takes numba from here (only numba typing
extensions stay with the code they type, :mod:`sympredict.kernels._compiled`):

* availability: :data:`HAVE_NUMBA`; numba is optional (``pip install
  sympredict[fast]``).  Where it is installed but cannot start (a bad
  environment variable such as ``NUMBA_NUM_THREADS=0``), it is hidden from the
  whole process with one ``RuntimeWarning`` and every module takes its NumPy
  path.  :func:`check_available` raises the one "numba missing" message;
* flags: :data:`JIT` (plain IEEE arithmetic), :data:`EXACT` (the kernel
  families' formulas), :data:`FJIT` (loops whose reductions may be
  reassociated so that they vectorise) and :data:`PJIT` (parallel loops);
* the disk cache: :func:`compiled` and :func:`jit_cached` compile lazily with
  numba's cache on, :func:`call` survives a cache that cannot be read or
  written (compiles without it, one logged warning), :func:`jit_user` compiles
  a user's function (numba's own ``cache=True``);
* threads: :func:`get_num_threads`, :func:`set_num_threads`, and fork safety
  (:func:`parallel_safe`: a child forked after numba's parallel loops ran runs
  them serially);
* :func:`compilable` marks a plain Python function as callable from compiled
  code (numba's ``register_jitable``; without numba the identity): the kernel
  families' formula helpers, Newton's stopping rule and the small dense solves
  are written once for NumPy-level Python and compiled code.

This module sits in the lowest layer of the package and imports nothing of it.

Compiled code is cached on disk, once per machine (numba's ``cache=True``):
the first process that uses a kernel compiles it (seconds), later processes
load it.  The cache lives where numba puts it: the ``__pycache__`` folder next
to the compiled module when that is writable, else numba's per-user cache
folder, or the folder named by the environment variable ``NUMBA_CACHE_DIR``
(set before numba is imported).  It holds one index per compiled function, with
one entry per argument types and CPU, so it does not grow with the number of
processes.  A cache that cannot be read or written costs compilation in every
process, not an error: the kernels then run uncached, with one logged warning.
numba checks a function's cache against the date of its own file only: after
editing a function it calls from another file (a formula in
:mod:`sympredict.kernels`, :mod:`sympredict.newton_rule` or
:mod:`sympredict._numeric`, or a compiled kernel of another module), delete the
cache folders.
"""

from __future__ import annotations

import logging
import os
import sys
import types
import warnings
from typing import Optional

__all__ = [
    "HAVE_NUMBA",
    "numba",
    "JIT",
    "EXACT",
    "FJIT",
    "PJIT",
    "compiled",
    "jit_cached",
    "jit_user",
    "call",
    "check_available",
    "get_num_threads",
    "set_num_threads",
    "compilable",
    "parallel_safe",
]

logger = logging.getLogger(__name__)


def _start() -> Optional[object]:
    """numba, started once; ``None`` where it is missing or cannot start (then hidden from the whole process)."""
    try:
        import numba as nb
    except ImportError:
        return None
    except Exception as exc:  # numba's configuration raises ValueError, KeyError, ... at import
        for name in [m for m in sys.modules if m == "numba" or m.startswith("numba.")]:
            del sys.modules[name]
        sys.modules["numba"] = None  # later "import numba" raises ImportError: the NumPy fallbacks
        warnings.warn(
            f"numba is installed but cannot start ({type(exc).__name__}: {exc}); sympredict runs on its "
            "NumPy code paths (slower). Check numba's environment variables (NUMBA_NUM_THREADS must be a "
            "positive integer).",
            RuntimeWarning,
            stacklevel=3,
        )
        return None
    return nb


numba = _start()

#: Whether numba is importable (and started).
HAVE_NUMBA = numba is not None

if HAVE_NUMBA:
    from numba.extending import register_jitable as compilable
else:  # pragma: no cover

    def compilable(function):
        """Without numba: the function itself."""
        return function


#: The message of a compiled path asked for without numba.
MISSING = "the compiled backend needs numba: pip install 'sympredict[fast]' (or numba>=0.59)"


def check_available() -> None:
    """Raise ``ImportError`` (:data:`MISSING`) without numba."""
    if not HAVE_NUMBA:
        raise ImportError(MISSING)


def use_compiled(requested: Optional[bool], name: str = "compiled") -> bool:
    """Whether a part runs its compiled path: ``None`` means where numba is installed.

    ``True`` without numba raises ``ImportError`` naming the setting and the way out.
    """
    if requested and not HAVE_NUMBA:
        raise ImportError(f"{name}=True needs numba: pip install 'sympredict[fast]' (or set {name}=None)")
    return HAVE_NUMBA if requested is None else bool(requested)


def get_num_threads() -> int:
    """Threads numba's parallel loops use (0 without numba)."""
    return numba.get_num_threads() if HAVE_NUMBA else 0


def set_num_threads(n: int) -> None:
    """Set the threads of numba's parallel loops (no-op without numba)."""
    if HAVE_NUMBA:
        numba.set_num_threads(int(n))


#: Whether the greedy's compiled O(N) passes (column, vector update, Gramian rows) run on numba's threads.
#: Off: right after OpenBLAS's threaded matrix-vector product, its spinning threads and numba's compete for the
#: cores (measured 3-5x slower steps on 2 cores).
GREEDY_PARALLEL = False


# --------------------------------------------------------------------------- flags
#: Flags of the kernels.  JIT: plain IEEE arithmetic.  FJIT: the Newton pass's loops over a chunk of centres,
#: whose reductions may be reassociated (so that they vectorise) and products fused (FMA); the summation order
#: then depends only on the chunk's length (LLVM's vectoriser does not peel for alignment, and the pass's
#: reductions store nothing that could alias), so results stay bit-reproducible run to run, across batch sizes
#: and threads.  The formulas are compiled with EXACT (fastmath off explicitly: numba compiles a callee that
#: leaves it unset with its caller's flags) and keep it when inlined.  PJIT: the parallel loops.
JIT = dict(nogil=True, fastmath=False, error_model="numpy")
EXACT = JIT
FJIT = dict(nogil=True, fastmath={"reassoc", "contract"}, error_model="numpy")
PJIT = dict(nogil=True, parallel=True)

# --------------------------------------------------------------------------- the disk cache
#: ``(name, Python function, flags, dispatcher)`` of every top-level compiled kernel of the package
#: (:func:`compiled`); :func:`sympredict.kernels._compiled.family_kernels` compiles them again for kernel families
#: from outside the package.  Names are unique across modules.
DEFINITIONS: list = []

#: The disk-cached dispatchers (for :func:`_disable_disk_cache`).
CACHED: list = []

_CACHE_WARNED = False


def _warn_cache(exc: BaseException) -> None:
    """Log, once per process, that the disk cache is unusable (compilation then happens in every process)."""
    global _CACHE_WARNED
    if not _CACHE_WARNED:
        _CACHE_WARNED = True
        logger.warning(
            "numba's disk cache of sympredict's compiled kernels is unusable (%s: %s); compiling them in "
            "this process instead.  Delete the cache folders (sympredict's __pycache__ folders, or "
            "NUMBA_CACHE_DIR) or make them writable.",
            type(exc).__name__,
            exc,
        )


def jit_cached(function, flags: dict, name: Optional[str] = None):
    """``numba.njit(function, cache=True, **flags)``; a cache folder that cannot be used leaves it uncached.

    ``name``: compile a copy of ``function`` under this name (one Python function, two sets of flags: see
    :func:`compiled`).
    """
    if name is not None:
        function = _named_copy(function, name)
    dispatcher = numba.njit(**flags)(function)
    try:  # what cache=True does; it raises if no cache folder is writable (a read-only install, no home folder)
        dispatcher.enable_caching()
    except Exception as exc:  # noqa: BLE001 - any failure of the cache only costs compile time
        _warn_cache(exc)
    CACHED.append(dispatcher)
    return dispatcher


def compiled(flags: dict, name: Optional[str] = None):
    """Decorator: a top-level compiled kernel, cached on disk and listed in :data:`DEFINITIONS` (without numba:
    the Python function).

    ``name``: the kernel's name where it is not the function's.  One Python function compiled under two names with
    two sets of flags (a loop over ``numba.prange``: parallel with :data:`PJIT`, a plain loop with :data:`JIT`)
    is one copy of the function per name, because numba's disk cache tells kernels apart by their name and code,
    not by their flags.
    """

    def decorate(function):
        if name is not None:
            function = _named_copy(function, name)
        if any(name == function.__name__ for name, _, _, _ in DEFINITIONS):
            raise RuntimeError(f"a compiled kernel named {function.__name__!r} exists already")
        dispatcher = jit_cached(function, flags) if HAVE_NUMBA else function
        DEFINITIONS.append((function.__name__, function, flags, dispatcher))
        return dispatcher

    return decorate


def _named_copy(function, name: str):
    """``function`` under another name (its code, globals, defaults and docstring)."""
    copy = types.FunctionType(function.__code__, function.__globals__, name, function.__defaults__)
    copy.__qualname__ = name
    copy.__doc__ = function.__doc__
    return copy


def jit_user(function):
    """A user's (or a system's) per-instance function compiled lazily, cached on disk by numba itself."""
    return numba.njit(cache=True, nogil=True, error_model="numpy")(function)


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
    for dispatcher in CACHED:
        dispatcher._cache.disable()  # the dispatcher's FunctionCache; loads and saves become no-ops


def call(kernel, *args):
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


# --------------------------------------------------------------------------- fork safety of numba's parallel loops
#: Set in a process forked after numba's threading layer started (GNU OpenMP cannot run a parallel region in
#: such a child: numba terminates it).  Such a child runs the parallel loops serially (:func:`parallel_safe`).
_FORKED_AFTER_THREADS = False
_FORK_WARNED = False


def _threads_started() -> bool:
    """Whether numba's threading layer has started in this process (its worker threads exist)."""
    try:
        from numba.np.ufunc import parallel as _parallel

        return bool(getattr(_parallel, "_is_initialized", True))
    except Exception:  # noqa: BLE001 - an unknown numba layout: assume started (the safe side)
        return True


def _after_fork_in_child() -> None:
    global _FORKED_AFTER_THREADS, _FORK_WARNED
    if _FORKED_AFTER_THREADS or ("numba" in sys.modules and _threads_started()):
        _FORKED_AFTER_THREADS = True
        _FORK_WARNED = False


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_after_fork_in_child)


def parallel_safe() -> bool:
    """Whether numba's parallel loops may run in this process: not in a child forked after they ran.

    In such a child (``os.fork``, ``multiprocessing`` with the fork start method) every compiled kernel runs
    its loops on one thread (the same code compiled without ``parallel``), and one :class:`RuntimeWarning`
    says so; the results are those of the serial kernels.
    """
    global _FORK_WARNED
    if not _FORKED_AFTER_THREADS:
        return True
    if not _FORK_WARNED:
        _FORK_WARNED = True
        import warnings

        warnings.warn(
            "this process was forked after numba's parallel loops ran (GNU OpenMP cannot run them in a "
            "forked child): the compiled kernels run on one thread here; use multiprocessing's 'spawn' or "
            "'forkserver' start method for parallel loops in the workers",
            RuntimeWarning,
            stacklevel=3,
        )
    return False
