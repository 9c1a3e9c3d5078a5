"""Update rules: how a learned generating function ``s`` makes a symplectic step.

An update rule owns everything that depends on the form of the step: where
the training targets ``y = J^T (x1 - x0) / dT`` are interpolated, the implicit
equation and its NumPy Newton solver, the step's Jacobian, the contraction
estimate ``dT L_S``, and which state symmetries leave its ``s`` invariant
(the existence of ``s`` on data is checked by
:func:`sympredict.systems.flowmaps.check_generating_function`).  The compiled solver runs the
same equations (:func:`sympredict.symplectic.newton.implicit_rollout`, selected by
:attr:`UpdateRule.name`).

==========================  =========================================================  ===================
rule                        step                                                       exists while
==========================  =========================================================  ===================
:class:`SymplecticEuler`    ``p1 = p0 - dT d_q s(q0, p1)``, ``q1 = q0 + dT d_p s``     ``dp1/dp0``
                            (type II, the paper's)                                     invertible
                                                                                       (``omega dT < pi/2``)
:class:`Midpoint`           ``x1 = x0 + dT J grad s((x0 + x1) / 2)``                   ``(I + D Phi)/2``
                            (Poincare type, symmetric)                                 invertible
                                                                                       (``omega dT < pi``)
==========================  =========================================================  ===================

A new rule is a subclass defining these methods, registered in
:data:`UPDATE_RULES`; the compiled solver needs its own kernel in
:mod:`sympredict.symplectic._compiled_newton` (until then, declare it NumPy-only in the
estimator's table :data:`sympredict.estimators.predictor.NUMPY_ONLY`).
"""

from __future__ import annotations

import numpy as np

from sympredict.base import Parametrized
from sympredict.data import mixed_variables
from sympredict.symplectic.metrics import canonical_J
from sympredict.symplectic.newton import midpoint_jacobian, solve_midpoint_numpy, solve_step_numpy

__all__ = ["UpdateRule", "SymplecticEuler", "Midpoint", "UPDATE_RULES", "as_update"]


class UpdateRule(Parametrized):
    """Base class of the generating-function updates (no parameters; compared by type)."""

    #: Name in model files, in the compiled solver and as the estimator's ``update`` string.
    name: str = ""
    #: Whether the compiled solver has a kernel for this rule (dispatched on :attr:`name`); a rule without one
    #: is NumPy-only (:data:`sympredict.estimators.predictor.NUMPY_ONLY`).
    compiled: bool = True

    def __eq__(self, other) -> bool:
        return type(self) is type(other) or (isinstance(other, str) and other == self.name)

    def __hash__(self) -> int:
        return hash(self.name)

    def __repr__(self) -> str:
        return f"{type(self).__name__}()"

    def variables(self, x0: np.ndarray, x1: np.ndarray, dt: np.ndarray):
        """Interpolation points ``xi`` and gradient targets ``y = J^T (x1 - x0) / dT``, both (M, 2n)."""
        raise NotImplementedError

    def solve(self, sur, x: np.ndarray, weights: np.ndarray, dt: np.ndarray, max_iter: int) -> np.ndarray:
        """One implicit step of a validated batch (B, 2n) by the NumPy reference Newton solver."""
        raise NotImplementedError

    def jacobian(self, sur, x: np.ndarray, x1: np.ndarray, weights: np.ndarray, dt: np.ndarray) -> np.ndarray:
        """``D Phi`` (B, 2n, 2n) of the step ``x -> x1`` by implicit differentiation."""
        raise NotImplementedError

    def linearization(self, sur, x: np.ndarray, x1: np.ndarray, weights: np.ndarray, dt: np.ndarray) -> tuple:
        """The step's linearisation at a solved step ``x -> x1``, for error propagation.

        Returns ``(xi, jac, sens)``: the evaluation point ``xi`` (B, 2n) where the step reads ``grad s``,
        ``D Phi`` (B, 2n, 2n) (:meth:`jacobian`), and ``sens = d x1 / d g`` (B, 2n, 2n), how an error
        ``delta g`` of the gradient at ``xi`` moves the solution: ``delta x1 = DF^-1 dT J delta g``
        (``DF`` the implicit equation's Jacobian at the solution).  One Hessian evaluation.
        """
        raise NotImplementedError

    def contraction(self, sur, x: np.ndarray, weights: np.ndarray, dt: np.ndarray) -> np.ndarray:
        """``dT L_S`` (B,) at the states ``x``: the fixed-point form of the step contracts where it is < 1."""
        raise NotImplementedError

    def check_symmetry(self, group: np.ndarray) -> None:
        """``ValueError`` naming the first element of ``group`` (shape ``(|G|, 2n, 2n)``) under which this
        rule's ``s`` is not invariant."""
        raise NotImplementedError


class SymplecticEuler(UpdateRule):
    """The type-II update ``p1 = p0 - dT d_q s(q0, p1)``, ``q1 = q0 + dT d_p s(q0, p1)`` (the paper's; default).

    The map generated by ``q0.p1 + dT s(q0, p1)``; Newton solves for ``p1``
    alone (``n`` unknowns, Jacobian ``I + dT d_p d_q s``).
    """

    name = "symplectic_euler"

    def variables(self, x0, x1, dt):
        return mixed_variables(x0, x1, dt)

    def solve(self, sur, x, weights, dt, max_iter):
        return solve_step_numpy(sur, x, weights, dt, max_iter)

    def jacobian(self, sur, x, x1, weights, dt):
        """With ``S`` the Hessian of ``s`` at ``(q0, p1)`` and ``M = I + dT S_qp``:
        ``dp1 = M^-1 (dp0 - dT S_qq dq0)``, ``dq1 = (I + dT S_pq) dq0 + dT S_pp dp1``."""
        return self.linearization(sur, x, x1, weights, dt)[1]

    def linearization(self, sur, x, x1, weights, dt):
        """:meth:`UpdateRule.linearization`; a gradient error ``(dg_q, dg_p)`` at ``(q0, p1)`` moves the step by
        ``dp1 = -dT M^-1 dg_q``, ``dq1 = dT dg_p + dT S_pp dp1``."""
        n = x.shape[1] // 2
        xi = np.concatenate([x[:, :n], x1[:, n:]], axis=1)
        _, S = sur.gradient_hessian(xi, weights)
        h = dt[:, None, None]
        eye = np.eye(n)
        Sqq, Sqp, Spq, Spp = S[:, :n, :n], S[:, :n, n:], S[:, n:, :n], S[:, n:, n:]
        Minv = np.linalg.inv(eye + h * Sqp)
        dp_dq = -h * (Minv @ Sqq)
        dq_dq = eye + h * Spq + h * (Spp @ dp_dq)
        dq_dp = h * (Spp @ Minv)
        jac = np.block([[dq_dq, dq_dp], [dp_dq, Minv]])
        zero = np.zeros_like(Minv)
        sens = np.block([[-h * dq_dp, h * np.broadcast_to(eye, Minv.shape)], [-h * Minv, zero]])
        return xi, jac, sens

    def contraction(self, sur, x, weights, dt):
        """``dT ||d^2 s / d xi d p||_2`` at ``xi = (q0, p0)`` (paper, Prop. 2 (ii); a local estimate)."""
        n = x.shape[1] // 2
        _, hess = sur.gradient_hessian(x, weights)
        return dt * np.linalg.norm(hess[:, :, n:], ord=2, axis=(1, 2))

    def check_symmetry(self, group):
        n = group.shape[1] // 2
        for i, g in enumerate(group):
            if (
                np.abs(g[:n, n:]).max() > 0
                or np.abs(g[n:, :n]).max() > 0
                or np.abs(g[:n, :n] - g[n:, n:]).max() > 1e-12
            ):
                raise ValueError(
                    f"symmetry: element {i} is not of the form diag(A, A): with update='symplectic_euler' "
                    "the type-II s(q0, p1) is invariant only under such maps (a reversing symmetry such as "
                    "q -> -q maps (q0, p1) to (q1, p0)); use update='midpoint'"
                )


class Midpoint(UpdateRule):
    """The symmetric (Poincare-type) update ``x1 = x0 + dT J grad s((x0 + x1) / 2)``.

    The implicit midpoint rule of the Hamiltonian ``s``: symplectic for every
    ``s`` (a Cayley transform) and time-symmetric; Newton on all ``2n``
    unknowns (Jacobian ``I - dT/2 J Hess s``).  Its ``s`` exists for a linear
    mode turning by ``theta < pi`` per step, twice the type-II range.
    """

    name = "midpoint"

    def variables(self, x0, x1, dt):
        _, y = mixed_variables(x0, x1, dt)
        return 0.5 * (x0 + x1), y

    def solve(self, sur, x, weights, dt, max_iter):
        return solve_midpoint_numpy(sur, x, weights, dt, max_iter)

    def jacobian(self, sur, x, x1, weights, dt):
        """``(I - A)^-1 (I + A)``, ``A = dT/2 J Hess s(z)`` at the midpoint ``z``."""
        _, S = sur.gradient_hessian(0.5 * (x + x1), weights)
        return midpoint_jacobian(S, dt)

    def linearization(self, sur, x, x1, weights, dt):
        """:meth:`UpdateRule.linearization`: ``d x1 / d g = (I - A)^-1 dT J`` at the midpoint ``z``."""
        z = 0.5 * (x + x1)
        _, S = sur.gradient_hessian(z, weights)
        dim = x.shape[1]
        jmat = canonical_J(dim)
        eye = np.eye(dim)
        a = 0.5 * dt[:, None, None] * (jmat @ S)
        inv = np.linalg.inv(eye - a)
        return z, inv @ (eye + a), dt[:, None, None] * (inv @ jmat)

    def contraction(self, sur, x, weights, dt):
        """``dT/2 ||Hess s||_2``: ``z -> x0 + dT/2 J grad s(z)`` contracts where it is < 1."""
        _, hess = sur.gradient_hessian(x, weights)
        return 0.5 * dt * np.linalg.norm(hess, ord=2, axis=(1, 2))

    def check_symmetry(self, group):
        jmat = canonical_J(group.shape[1])
        for i, g in enumerate(group):
            sigma = g.T @ jmat @ g
            if not (np.allclose(sigma, jmat, atol=1e-12) or np.allclose(sigma, -jmat, atol=1e-12)):
                raise ValueError(
                    f"symmetry: element {i} is neither symplectic (g^T J g = J) nor anti-symplectic "
                    "(g^T J g = -J): no symmetry of a Hamiltonian flow makes the midpoint s invariant under it"
                )


#: The update rules by name.
UPDATE_RULES = {cls.name: cls for cls in (SymplecticEuler, Midpoint)}


def as_update(value) -> UpdateRule:
    """An update rule from its name (``'symplectic_euler'``, ``'midpoint'``) or an :class:`UpdateRule`."""
    if isinstance(value, UpdateRule):
        return value
    if isinstance(value, str) and value in UPDATE_RULES:
        return UPDATE_RULES[value]()
    raise ValueError(
        f"update must be one of {tuple(UPDATE_RULES)} or an UpdateRule (SymplecticEuler(), Midpoint()), got {value!r}"
    )
