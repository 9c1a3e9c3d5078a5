"""The Newton solver of the implicit steps, as a setting: iterations, warm start, and which code runs it.

:class:`NewtonSolver` is what an estimator's ``solver`` parameter holds.  It
decides nothing about the equations (those belong to the update rule,
:mod:`sympredict.symplectic.updates`); it says how they are solved:

* ``max_iter``: Newton iterations per implicit step (at most :data:`MAX_NEWTON_ITER`);
* ``warm_start``: from the second macro step on, start Newton from a quadratic
  extrapolation of the previous three steps instead of the explicit guess;
* ``backend``: ``'numpy'`` (the reference), ``'numba'`` (compiled; ``pip install
  'sympredict[fast]'``) or ``'auto'`` (:meth:`NewtonSolver.backend_for`).

Both backends run one algorithm (:mod:`sympredict.symplectic.newton`) and agree to
round-off.  Features that only the NumPy solver runs are declared in one table
of the estimator (:data:`sympredict.estimators.predictor.NUMPY_ONLY`): ``'numba'`` is then
refused at fit with a message naming the fix, and ``'auto'`` uses NumPy and
says so (the fitted model's ``numpy_only_``).
"""

from __future__ import annotations

import logging
from typing import Optional


from sympredict import _numba
from sympredict.symplectic import _compiled_newton
from sympredict._checks import as_flag, as_positive_int
from sympredict.base import Setting

__all__ = ["NewtonSolver", "MAX_NEWTON_ITER", "AUTO_NUMPY_SECONDS", "numpy_seconds", "BACKENDS"]

logger = logging.getLogger("sympredict.estimators.predictor")

#: The solver backends.
BACKENDS = ("auto", "numpy", "numba")

#: Largest ``max_iter`` accepted (constructor and model files): Newton converges in a handful of
#: iterations or not at all, and a file must not be able to make prediction run without end.
MAX_NEWTON_ITER = 10_000

#: backend='auto' runs the NumPy solver where it is estimated to take less than this many seconds ...
AUTO_NUMPY_SECONDS = 0.5
#: ... by NumPy's cost per macro step (both measured on a 2-core x86-64 machine, pendulum models):
#: a fixed cost (a few batched Newton iterations, Python overhead) ...
NUMPY_STEP_SECONDS = 4e-4
#: ... plus this much per instance, centre and Hessian entry ``(2n)^2``.
NUMPY_TERM_SECONDS = 6e-8


def numpy_seconds(n_instances: int, n_steps: int, n_centers: int, dim: int) -> float:
    """Estimated wall time of ``n_steps`` NumPy macro steps of ``n_instances`` states (the ``auto`` rule's cost model).

    ``n_steps (NUMPY_STEP_SECONDS + NUMPY_TERM_SECONDS B m (2n)^2)``: a few Newton iterations per
    step, each a pass over the ``m`` centres with the ``(2n)^2`` Hessian entries per instance.
    """
    return n_steps * (NUMPY_STEP_SECONDS + NUMPY_TERM_SECONDS * n_instances * n_centers * dim * dim)


class NewtonSolver(Setting):
    """How the implicit steps are solved.

    Parameters
    ----------
    max_iter
        Newton iterations per implicit step, ``1 .. MAX_NEWTON_ITER`` (default 50).
    warm_start
        Compiled rollouts only: from the second macro step on, Newton starts from
        ``3 p_k - 3 p_k-1 + p_k-2`` (with the midpoint update, the midpoint of
        ``x_k`` and that extrapolation of ``x_k+1``) instead of the explicit guess,
        saving that guess's pass over the centres.  Both stop by the same rule,
        so trajectories differ within its tolerance.  Default ``False``.
    backend
        ``'numpy'``, ``'numba'`` or ``'auto'`` (default): see :meth:`backend_for`.
    """

    def __init__(self, max_iter: int = 50, warm_start: bool = False, backend: str = "auto"):
        self.max_iter = max_iter
        self.warm_start = warm_start
        self.backend = backend

    def check(self) -> "NewtonSolver":
        """``ValueError`` naming the setting that is malformed; returns ``self``."""
        self.iterations()
        if not isinstance(self.backend, str) or self.backend not in BACKENDS:
            raise ValueError(f"backend must be 'auto', 'numpy' or 'numba', got {self.backend!r}")
        as_flag(self.warm_start, "warm_start")
        return self

    def iterations(self) -> int:
        """``max_iter``, checked: an integer in ``1..MAX_NEWTON_ITER``."""
        max_iter = as_positive_int(self.max_iter, "max_iter (Newton iterations)")
        if max_iter > MAX_NEWTON_ITER:
            raise ValueError(
                f"max_iter must be at most {MAX_NEWTON_ITER} (Newton converges in a few iterations "
                f"or not at all), got {max_iter}"
            )
        return max_iter

    def refuse_compiled(self, numpy_only: Optional[str]) -> None:
        """``ValueError`` where ``backend='numba'`` is asked of a model that has no compiled solver, ``numpy_only``
        saying why (``None``: it has one); the one refusal of a part against a backend, at fit and at prediction."""
        if numpy_only is not None and self.backend == "numba":
            raise ValueError(f"{numpy_only}: use NewtonSolver(backend='numpy') or 'auto' (which then uses NumPy)")

    def compiled(
        self,
        n_instances: Optional[int],
        n_steps: int,
        n_centers: int,
        dim: int,
        numpy_only: Optional[str] = None,
        *,
        by_size: bool = False,
    ) -> bool:
        """Whether this much work runs compiled (see :meth:`backend_for`); ``numpy_only`` is the reason a model
        has no compiled solver (``None``: it has one).  ``by_size``: ``backend='auto'`` decides by the work's size
        alone, not by whether this process has loaded the compiled rollout already, so that what is computed with
        it (the error estimate's calibration) does not depend on what ran before in the process (the two solvers
        agree only to Newton's stopping rule)."""
        if numpy_only is not None:
            self.refuse_compiled(numpy_only)
            return False
        if self.backend == "numpy":
            return False
        if self.backend == "numba":
            if not _numba.HAVE_NUMBA:
                raise ImportError(
                    "backend='numba' needs numba: pip install 'sympredict[fast]' (or use backend='numpy')"
                )
            return True
        if self.backend != "auto":
            raise ValueError(f"backend must be 'auto', 'numpy' or 'numba', got {self.backend!r}")
        if not _numba.HAVE_NUMBA:
            return False
        if n_instances is None or (not by_size and _compiled_newton.rollout_loaded()):
            return True
        estimate = numpy_seconds(n_instances, n_steps, n_centers, dim)
        compiled = estimate >= AUTO_NUMPY_SECONDS
        logger.debug(
            "backend='auto': %s (NumPy estimated at %.2g s for %d instances x %d steps, %d centres)",
            "compiled" if compiled else "NumPy",
            estimate,
            n_instances,
            n_steps,
            n_centers,
        )
        return compiled

    def backend_for(
        self, n_instances: int, n_steps: int, n_centers: int, dim: int, numpy_only: Optional[str] = None
    ) -> str:
        """``'numpy'`` or ``'numba'``: the code that runs ``n_steps`` steps of ``n_instances`` states.

        ``backend='numpy'`` or ``'numba'`` decide alone (``'numba'`` is refused for
        a model with a NumPy-only feature, ``numpy_only``).  ``backend='auto'``:

        * ``'numpy'`` without numba, for a model with a NumPy-only feature, or when
          :func:`numpy_seconds` estimates the call at under :data:`AUTO_NUMPY_SECONDS`
          (loading compiled code costs a fresh process ~0.1-0.3 s from numba's disk
          cache, and compiling it ~20 s the first time on a machine) and this process
          has not loaded the compiled rollout yet;
        * ``'numba'`` otherwise.
        """
        return "numba" if self.compiled(int(n_instances), int(n_steps), n_centers, dim, numpy_only) else "numpy"
