"""Does the generating function of the reduced flow exist at the reductor's ``dt``?  The check before training.

A :class:`~sympredict.mor.reductor.SymplecticKernelReductor` learns a generating function of the step (type II,
or the midpoint form for ``update="midpoint"``); it exists only up to the first step where a Jacobian block
is singular.  :func:`check_existence` runs the check in the coordinates the estimator is trained in (the
Jacobian there is ``T D Phi T^-1`` for the state scaling ``T``): from the exact Jacobians of the Galerkin
system where it is known (:class:`~sympredict.mor.samples.GalerkinSamples` without a split), else from a
least-squares linear map per parameter (:func:`check_from_data`).  Where the update is left open it chooses the
form that exists (type II, else midpoint); where neither exists and the split is a fallback
(``QuadraticSplit(A, fallback=True)``), the exact linear flow of ``A`` is split off and the remainder checked.
"""

from __future__ import annotations

import logging
import warnings
from typing import Callable, Optional

import numpy as np
from scipy.linalg import logm

from sympredict.data import FlowMapData
from sympredict.symplectic.metrics import canonical_J
from sympredict.systems.linear_flow import inverse_symplectic_matrices
from sympredict.systems.flowmaps import (
    LinearHamiltonianSystem,
    _report_existence,
    check_generating_function,
    first_singular_step,
    midpoint_sigma_min,
    type2_sigma_min,
)

__all__ = ["check_existence", "check_from_data", "conjugated_system"]

logger = logging.getLogger("sympredict.mor.existence")


def conjugated_system(system: LinearHamiltonianSystem, M: np.ndarray) -> LinearHamiltonianSystem:
    """``system`` in the coordinates ``x~ = M x`` (``M^T J M = s^2 J``, conformally symplectic): ``H~ = s^2 M^-T H M^-1``
    and ``h~ = s^2 M^-T h``, so that ``J H~ = M J H M^-1`` and the flow Jacobian is ``M D Phi M^-1``."""
    M = np.asarray(M, dtype=float)
    dim = M.shape[0]
    J = canonical_J(dim)
    s2 = float((M.T @ J @ M)[0, dim // 2] / J[0, dim // 2])
    Minv = np.linalg.inv(M)
    return LinearHamiltonianSystem(
        lambda mu: s2 * Minv.T @ system.matrix(mu) @ Minv,
        dim,
        system.n_mu,
        lambda mu: s2 * Minv.T @ system.linear_term(mu),
    )


def check_from_data(data: FlowMapData, dt: float, update: str, log=logger) -> dict:
    """Existence check (type II, or the midpoint form for ``update="midpoint"``) from the samples alone.

    Per parameter a least-squares linear map ``x1 ~ M x0`` (exact for a linear FOM, the best linear fit of a
    nonlinear one), its generator ``log(M) / dt`` for the largest admissible step.  Parameters with fewer than
    ``2n`` samples (or samples spanning fewer dimensions) are skipped, with one log line; where none is left,
    ``{"not_checked": True}`` and a warning.  ``ValueError`` (with the largest admissible step) where the form
    does not exist at ``dt``.  Cost: one ``(2n)^3`` fit, ``logm`` and eigen-decomposition per parameter value.
    """
    dim = data.x0.shape[1]
    worst, generators, skipped = (np.inf, None), [], 0
    for row in np.unique(data.mu, axis=0):
        sel = np.all(data.mu == row, axis=1)
        if sel.sum() < dim:
            skipped += 1
            continue
        M, _, rank, _ = np.linalg.lstsq(data.x0[sel], data.x1[sel], rcond=None)
        if rank < dim:
            log.info(
                f"existence check skipped at mu = {row.tolist()}: its samples span only {rank} of "
                f"the {dim} reduced dimensions (no linear map to fit)"
            )
            continue
        M = M.T
        sigma = float((midpoint_sigma_min if update == "midpoint" else type2_sigma_min)(M[None])[0])
        generators.append(np.real(logm(M)) / dt)
        if sigma < worst[0]:
            worst = (sigma, row)
    if skipped:
        log.info(f"existence check: {skipped} parameter value(s) with fewer than 2n = {dim} samples skipped")
    if worst[1] is None:
        log.warning(
            f"existence check not done: no parameter value has samples spanning all 2n = {dim} reduced "
            f"dimensions, so nothing says whether the generating function exists at dt = {dt!r} (more "
            f"samples per parameter, or check_existence=False to say so)"
        )
        return {"not_checked": True}
    om = max(float(np.abs(np.linalg.eigvals(A).imag).max()) for A in generators)
    if om * dt < 1e-6:  # no rotation to speak of (e.g. the remainder S of a split): no singular step ahead
        dt_max = np.inf
    else:
        try:
            with np.errstate(all="ignore"):
                dt_max = first_singular_step(generators, update=update)
        except np.linalg.LinAlgError:  # the scan ran into the non-symplectic round-off of the fitted maps
            dt_max = np.inf
    return _report_existence(worst[0], worst[1], dt, dt_max, 1e-2, 0.1, update)


def _scaled_states(d: FlowMapData, scaling) -> FlowMapData:
    """Samples with their states in the scaled coordinates (parameters and steps as given)."""
    return FlowMapData(scaling.transform(d.x0), scaling.transform(d.x1), d.mu if d.mu.shape[1] else None, d.dt)


def _choose_update(
    check: Callable[[str], dict], given: Optional[str], open_estimator: bool, split_in_use: bool, dt: float, log
) -> tuple:
    """``check(update)`` for the update to train.  Where the caller left the update open (the default estimator,
    or an estimator with ``update=None``, ``open_estimator``): when the type II generating function does not exist
    at ``dt`` (a mode turns past a quarter turn per step), the midpoint form (up to half a turn) is chosen instead;
    for an estimator with ``update=None`` the choice stays with it (``update None``) where both forms exist.

    Returns ``(report, choice)``, ``choice = {"update", "reason"}``.
    """
    choice = (
        {"update": given, "reason": "the given estimator's update"}
        if given is not None
        else {"update": "symplectic_euler", "reason": "type II generating function exists at dt"}
    )
    try:
        out = check(choice["update"])
    except ValueError as exc:
        if given is not None or split_in_use:
            raise
        first = str(exc)
    else:
        if isinstance(out, dict) and out.get("not_checked"):
            choice["reason"] = "not checked: too few samples per parameter (see the log)"
            return out, choice
        if given is None and open_estimator:  # the estimator chooses, where both forms exist
            try:
                with warnings.catch_warnings():  # a probe: its warnings are not the caller's
                    warnings.simplefilter("ignore")
                    check("midpoint")
            except ValueError as exc:
                choice = {
                    "update": "symplectic_euler",
                    "reason": f"the midpoint form does not exist at dt = {dt!r} ({exc}); the type II form does",
                }
                log.info(f"update='symplectic_euler' set on the estimator: {choice['reason']}")
            else:
                choice = {
                    "update": None,
                    "reason": "both generating functions exist at dt: the estimator's search chooses (update=None)",
                }
        return out, choice
    choice = {"update": "midpoint", "reason": f"type II does not exist at dt = {dt!r}: {first}"}
    try:
        out = check("midpoint")
    except ValueError as exc:
        raise ValueError(
            f"neither generating function exists at dt = {dt!r}: midpoint: {exc}; type II: {first}"
        ) from None
    log.info(
        f"update='midpoint' chosen: the type II generating function does not exist at dt = "
        f"{dt!r} ({first}); the midpoint form does"
    )
    return out, choice


def check_existence(
    train: FlowMapData,
    scaling,
    dt: float,
    *,
    given_update: Optional[str],
    open_estimator: bool,
    split=None,
    reference=None,
    log=logger,
) -> tuple:
    """The existence check in the trained coordinates, with the choice of the update and of the fallback split.

    Parameters
    ----------
    train : FlowMapData
        Training samples in reduced coordinates (parameter vectors of the flow parameters).
    scaling : SymplecticScaling
        The fitted state scaling ``x~ = T x`` of the trained coordinates.
    dt : float
        The macro step the update must exist at.
    given_update : str or None
        The update the caller fixed (by name), or ``None`` where it is chosen here.
    open_estimator : bool
        The given estimator leaves its update open (``update=None``): where both forms exist it keeps the choice.
    split : QuadraticSplit or None, default=None
        The quadratic part split off (``fallback=False``: always; ``fallback=True``: only where no generating
        function exists at ``dt`` without it).
    reference : tuple (LinearHamiltonianSystem, FlowMapData) or None, default=None
        The exact reduced system and the samples with the FOM's parameter vectors (Galerkin samples): exact
        Jacobians instead of fitted linear maps, where no split is in use.
    log : logging.Logger, default=logging.getLogger("sympredict.mor.existence")
        Where the choices and skipped checks are logged (the reductor passes its own logger).

    Returns
    -------
    report : dict
        :func:`~sympredict.systems.flowmaps.check_generating_function`'s report (``sigma_min``, ``dt_max``, ...).
    choice : dict
        ``{"update", "reason"}`` and, where the fallback split was needed, ``"split": "split_fallback"``.
    quadratic : QuadraticPart or None
        The quadratic part split off in the end.
    """
    always = None if split is None or split.fallback else split.quadratic

    def checker(quadratic):
        def check(update):
            if reference is not None and quadratic is None:
                system, full = reference
                return check_generating_function(
                    conjugated_system(system, scaling.matrix_), _scaled_states(full, scaling), update=update
                )
            pairs = train if quadratic is None else split_pairs(train, quadratic)
            return check_from_data(_scaled_states(pairs, scaling), dt, update, log)

        return check

    try:
        out, choice = _choose_update(checker(always), given_update, open_estimator, always is not None, dt, log)
        return out, choice, always
    except ValueError as exc:
        if split is None or not split.fallback:
            raise
        first = str(exc)
    try:
        out, choice = _choose_update(checker(split.quadratic), given_update, open_estimator, True, dt, log)
    except ValueError as exc:
        raise ValueError(
            f"no generating function exists at dt = {dt!r}, neither without a split ({first}) "
            f"nor for the remainder S once the exact linear flow of the fallback split is split off "
            f"({exc}): use a smaller macro step"
        ) from None
    choice["split"] = "split_fallback"
    choice["reason"] = (
        f"no generating function exists at dt = {dt!r} without a split ({first}); with "
        f"the exact linear flow of the fallback split split off, the remainder's "
        f"({choice['reason']})"
    )
    log.info(
        f"fallback split used: the step is L_h o S o L_h with the exact linear flow L_h of the "
        f"quadratic part; {choice['reason']}"
    )
    return out, choice, split.quadratic


def split_pairs(data: FlowMapData, quadratic) -> FlowMapData:
    """``S``'s samples ``(L_h x0, L_{-h} x1)``, ``L_h = expm(dt/2 J A(mu))``, of samples ``x1 = Phi(x0)``."""
    L = quadratic.propagator(data.mu if data.mu.shape[1] else None, 0.5 * data.dt, n=len(data))
    return FlowMapData(
        np.einsum("bij,bj->bi", L, data.x0),
        np.einsum("bij,bj->bi", inverse_symplectic_matrices(L), data.x1),
        data.mu if data.mu.shape[1] else None,
        data.dt,
    )
