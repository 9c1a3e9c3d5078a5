"""Oracles shared by several test files.

* the modified state kernels (periodic factor, group average): the Gramian and the surrogate's value, gradient,
  Hessian and Newton terms against finite differences of the kernel's *value* only;
* the compiled Newton solvers: pendulum queries, a model with another backend, and agreement of two rollouts
  to the surrogate's gradient floor;
* model files whose kernel entry is malformed are refused;
* a predicted step's Jacobian: symplectic and equal to central differences of the step;
* pendulum samples at one length and step (the kernel-factor tests' data), the Klein group of sign flips and a
  midpoint predictor averaged over it.
"""

import copy

import numpy as np
import pytest

from sympredict import SymplecticKernelPredictor
from sympredict.container import write_container
from sympredict.exceptions import ModelFileError
from sympredict.io import load_model
from sympredict.kernels import IMQ
from sympredict.kernels.transforms import Symmetric
from sympredict.symplectic.metrics import canonical_J
from sympredict.symplectic.solvers import NewtonSolver
from sympredict.estimators.predictor import MODEL_FORMAT

from _tolerances import rollout_bound  # tests/


def check_surrogate_by_finite_differences(sur, kernel_value, centers, cmu, comps, coef, xi, qmu, h=1e-5):
    """Assert that ``sur`` (an :class:`~sympredict.interpolation.surrogate.HBSurrogate` with centres ``centers`` (m, D) at
    ``cmu`` (m, 1), differentiated components ``comps`` and coefficients ``coef``) evaluates

    * ``s(x) = sum_j c_j d/dy_{l_j} k((x, mu), (y, mu_j))|_{y = x_j}``, the derivative in ``y`` taken by central
      differences of ``kernel_value(x, y, mu_x, mu_y)`` (the oracle: the profile and the distance only);
    * its gradient and Hessian as central differences of ``value`` and ``gradient``;
    * ``newton_terms`` as the gradient, the ``(q, p)`` block of the Hessian and the same floor.

    Returns ``(w, grad, hess, floor)`` at the query points ``xi`` (B, D), ``qmu`` (B, 1) (``dT`` 0.05).
    """
    dim = xi.shape[1]
    w = sur.weights(qmu, np.full(len(xi), 0.05))
    eye = np.eye(dim) * h
    expected = np.array(
        [
            sum(
                coef[j]
                * (
                    kernel_value(x, centers[j] + eye[comps[j]], mu[0], cmu[j, 0])
                    - kernel_value(x, centers[j] - eye[comps[j]], mu[0], cmu[j, 0])
                )
                / (2 * h)
                for j in range(len(coef))
            )
            for x, mu in zip(xi, qmu)
        ]
    )
    np.testing.assert_allclose(sur.value(xi, w), expected, atol=1e-8 * np.abs(expected).max())
    grad, hess, floor = sur.gradient_hessian(xi, w, with_floor=True)
    np.testing.assert_array_equal(grad, sur.gradient(xi, w))
    fd_grad = np.column_stack([(sur.value(xi + eye[a], w) - sur.value(xi - eye[a], w)) / (2 * h) for a in range(dim)])
    np.testing.assert_allclose(grad, fd_grad, atol=1e-8 * np.abs(grad).max())
    fd_hess = np.stack(
        [(sur.gradient(xi + eye[c], w) - sur.gradient(xi - eye[c], w)) / (2 * h) for c in range(dim)], axis=2
    )
    np.testing.assert_allclose(hess, fd_hess, atol=1e-7 * np.abs(hess).max())
    g2, hqp, floor2 = sur.newton_terms(xi, w)
    n = dim // 2
    np.testing.assert_array_equal(g2, grad)
    np.testing.assert_allclose(hqp, hess[:, :n, n:], atol=1e-14 * np.abs(hess).max())
    np.testing.assert_array_equal(floor2, floor)
    return w, grad, hess, floor


def check_gramian_by_finite_differences(fun, kernel_value, pts, mu, rtol=1e-13, atol=1e-15, h=1e-4):
    """Assert that the Hermite-Birkhoff Gramian of ``fun`` (an :class:`~sympredict.interpolation.functionals.HBFunctionals` at
    ``pts`` (P, D), ``mu`` (P, 1), every state derivative of every point) is consistent (columns, rows and
    diagonal agree, symmetric, positive definite for points in general position) and equals the mixed central
    differences ``d/dx_a d/dy_b`` of ``kernel_value(x, y, mu_x, mu_y)``.  Returns the Gramian (P D, P D)."""
    dim = pts.shape[1]
    n = fun.n_functionals
    gram = np.empty((n, n))
    for j in range(n):
        fun.column(fun.representer(j), out=gram[:, j])
    rows = fun.gram_rows(fun, np.arange(n), out=np.empty((n, n)))
    np.testing.assert_allclose(rows, gram.T, rtol=rtol, atol=atol)
    np.testing.assert_allclose(gram, gram.T, atol=1e-14)
    assert np.linalg.eigvalsh(gram).min() > 0
    np.testing.assert_allclose(fun.diagonal(), np.diag(gram), rtol=rtol)
    eye = np.eye(dim) * h
    fd = np.empty((n, n))
    for i in range(n):
        p, a = divmod(i, dim)
        for j in range(n):
            q, b = divmod(j, dim)
            x, y, mx, my = pts[p], pts[q], mu[p, 0], mu[q, 0]
            fd[i, j] = (
                kernel_value(x + eye[a], y + eye[b], mx, my)
                - kernel_value(x + eye[a], y - eye[b], mx, my)
                - kernel_value(x - eye[a], y + eye[b], mx, my)
                + kernel_value(x - eye[a], y - eye[b], mx, my)
            ) / (4 * h * h)
    np.testing.assert_allclose(gram, fd, atol=1e-6 * np.abs(gram).max())
    return gram


def assert_jacobians_symplectic(jac, atol=1e-12):
    """``DPhi^T J DPhi = J`` to ``atol`` for each of the Jacobians ``jac`` of shape (B, 2n, 2n)."""
    J = canonical_J(jac.shape[-1])
    np.testing.assert_allclose(np.einsum("bji,jk,bkl->bil", jac, J, jac), np.broadcast_to(J, jac.shape), atol=atol)


def check_step_jacobian(model, x, mu, dt, fd_atol, h=1e-4):
    """``DPhi^T J DPhi = J`` (to 1e-12) of ``model.step_jacobian`` and central differences of ``model.step``
    (step ``h``, to ``fd_atol``: the Newton tolerance sets the floor of the differences); returns ``(jac, fd)``."""
    dim = x.shape[1]
    jac = model.step_jacobian(x, mu=mu, dt=dt)
    assert_jacobians_symplectic(jac)
    fd = np.empty_like(jac)
    for k in range(dim):
        e = np.zeros(dim)
        e[k] = h
        fd[:, :, k] = (model.step(x + e, mu=mu, dt=dt) - model.step(x - e, mu=mu, dt=dt)) / (2 * h)
    np.testing.assert_allclose(fd, jac, atol=fd_atol)
    return jac, fd


#: the pendulum length and step of :func:`pendulum_samples`
PENDULUM_LENGTH, PENDULUM_DT = 0.75, 0.05


def pendulum_samples(q_max, p_max, n=500, seed=0):
    """``n`` pendulum states uniform in ``[-q_max, q_max] x [-p_max, p_max]`` and their true images after
    ``PENDULUM_DT`` at length ``PENDULUM_LENGTH``: ``(x0, x1)``, each of shape (n, 2)."""
    from sympredict.systems.pendulum import Pendulum

    rng = np.random.default_rng(seed)
    x0 = np.column_stack([rng.uniform(-q_max, q_max, n), rng.uniform(-p_max, p_max, n)])
    return x0, Pendulum().flow(x0, PENDULUM_LENGTH, PENDULUM_DT)


#: the Klein four-group of the 2-D sign flips ``(q, p) -> (+-q, +-p)``, as signs
KLEIN = [(1, 1), (-1, -1), (1, -1), (-1, 1)]


def klein_midpoint_predictor(state_eps, mu_eps, dt_eps, max_centers, backend):
    """A midpoint :class:`~sympredict.SymplecticKernelPredictor` (2n = 2) whose state kernel ``IMQ(state_eps)`` is
    averaged over :data:`KLEIN`, with IMQ parameter and step kernels and the Newton ``backend``."""
    return SymplecticKernelPredictor(
        Symmetric(IMQ(state_eps), group=KLEIN),
        IMQ(mu_eps),
        IMQ(dt_eps),
        max_centers=max_centers,
        update="midpoint",
        solver=NewtonSolver(backend=backend),
    )


def pendulum_queries(rng, n):
    """``n`` pendulum states with ``q`` in ``[0, pi/2]``, lengths and steps inside the small training box."""
    x = np.column_stack([rng.uniform(0.0, np.pi / 2, n), rng.uniform(-0.5, 0.5, n)])
    return x, rng.uniform(0.71, 0.79, n), rng.uniform(0.045, 0.055, n)


def with_backend(model, backend):
    """The fitted model with another Newton backend (a shallow copy: the fitted state is shared)."""
    return copy.copy(model).set_params(solver__backend=backend)


def check_rollouts_agree_to_the_floor(reference, fast, x, mu, dt, n_steps=20):
    """Assert that ``fast.rollout`` equals ``reference.rollout`` to :func:`_tolerances.rollout_bound` (per step the
    solutions may differ by ~``dT`` times the gradient floor of :meth:`HBSurrogate.gradient_hessian`) and that this
    bound is below 1e-5 (a meaningful agreement).  Returns the reference trajectories and the bound."""
    ref = reference.rollout(x, n_steps, mu=mu, dt=dt)
    out = fast.rollout(x, n_steps, mu=mu, dt=dt)
    sur = reference.surrogate_
    bound = rollout_bound(sur, ref, sur.weights(mu[:, None], dt), dt)
    assert bound < 1e-5
    assert np.abs(out - ref).max() <= bound
    return ref, bound


def check_malformed_kernel_entries_refused(path, settings, arrays, key, specs):
    """Write the model file ``path`` with ``settings["kernel"][key]`` replaced by each of ``specs`` (``None``:
    the entry deleted) and assert that loading it raises :class:`ModelFileError`."""
    for spec in specs:
        bad = {**settings, "kernel": {**settings["kernel"], key: spec}}
        if spec is None:
            del bad["kernel"][key]
        write_container(path, MODEL_FORMAT, bad, arrays)
        with pytest.raises(ModelFileError):
            load_model(path)


def gram_oracle(fun, selected):
    """``G(selected, selected)`` column by column through ``HBFunctionals.column`` (not a trainer's rows)."""
    out = np.empty((len(selected), len(selected)))
    col = np.empty(fun.n_functionals)
    for k, j in enumerate(selected):
        out[:, k] = fun.column(fun.representer(int(j)), col)[selected]
    return out
