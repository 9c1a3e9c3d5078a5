"""Structure in the data that an expert gives the kernel: symmetries, reversing symmetries, wrapped angles.

The kernel search (:class:`~sympredict.estimators.auto.KernelSearch`, ``structure=True``) runs these tests on its
training and validation samples and lets the structures that pass compete in its held-out comparison; a
structure is used only where that comparison prefers it.

**Symmetries from sign flips.**  For ``n`` conjugate pairs the candidates are diagonal maps ``g = diag(s)``:

* a *symmetry* flips some pairs ``(q_i, p_i)`` together (symplectic): ``g Phi g = Phi``, so ``(g x0, g x1)`` is a
  sample of the flow whenever ``(x0, x1)`` is;
* a *reversing symmetry* flips every momentum and some pairs (anti-symplectic: ``g^T J g = -J``, e.g.
  ``(x, y, px, py) -> (x, -y, -px, py)`` of the restricted three-body problem): ``g Phi g = Phi^-1``, so
  ``(g x1, g x0)`` is a sample (the orbit run backwards).  Only the midpoint update's ``s`` can carry it.

For ``n <= 3`` every subset of pairs is a candidate (``2^n - 1`` symmetries, ``2^n`` reversing symmetries); for
more pairs, no pair, each single pair and all pairs.  A group the user declares (``Symmetric``) is tested
element by element and reported, never replaced.

*The test* (:func:`check_sign_flip`): a quick model (the search's best kernels, at most
:data:`QUICK_CENTERS` centres) predicts the transformed validation pairs whose inputs lie in the box of the training
inputs (widened by :data:`BOX_TOLERANCE` of its width; a nearest-neighbour criterion would compare with the
validation inputs' neighbours on their own trajectories, far closer than any other), and its median relative one-step error there, ``e_T``, is compared with the same
error on the validation pairs themselves, ``e_0``.  The symmetry *holds* when
``e_T <= HOLD_FACTOR * e_0`` and ``e_T <= HOLD_CEILING``: a map that is no symmetry moves ``g Phi g (x)``
away from ``Phi(x)`` (or ``Phi^-1(x)``) by about a step's increment, ``e_T`` of order 1, however accurate the
model; noise in the data raises ``e_0`` and ``e_T`` alike and cannot lift a false symmetry under the ceiling.
It is *untestable* when fewer than :data:`MIN_TESTED` transformed inputs lie among the data (the map sends the
data where there are none: the data say nothing about it), or when ``e_0`` itself is above the ceiling (data too
noisy, or the quick model too coarse, to tell a symmetry from none).

**Wrapped angles** (:func:`wrapped_coordinates`): a coordinate whose increments ``x1_i - x0_i`` are small
(median below ``P / 8``) except for some that lie within ``P / 8`` of a nonzero multiple of the period ``P``
(default ``2 pi``), with all values in a window of about one period, is an angle reduced to one period: its
samples must be unwrapped (the increment is the true one) before a ``Periodic`` kernel can learn it.  The
search names such coordinates (:class:`~sympredict.exceptions.WrappedAngleWarning`) and does not change the
data.
"""

from __future__ import annotations

import itertools
import logging
import warnings
from dataclasses import dataclass
from typing import Optional

import numpy as np

from sympredict.base import clone
from sympredict.data import FlowMapData
from sympredict.estimators.search import fit_candidate
from sympredict.exceptions import (
    NewtonConvergenceError,
    NonFinitePredictionError,
    WrappedAngleWarning,
    extrapolation_expected,
)
from sympredict.kernels import StateSymmetry
from sympredict.kernels.transforms import Symmetric, lower_state_kernel

__all__ = [
    "StructureFinding",
    "sign_flip_candidates",
    "check_sign_flip",
    "check_group",
    "compete",
    "validation_error",
    "wrapped_coordinates",
    "group_of",
    "fold",
    "QUICK_CENTERS",
    "HOLD_FACTOR",
    "HOLD_CEILING",
    "MIN_TESTED",
]

logger = logging.getLogger("sympredict.estimators.structure")

#: Centres of the quick model the symmetry test predicts with.
QUICK_CENTERS = 200
#: A symmetry holds when the quick model's error on the transformed pairs is at most this times its error on the
#: validation pairs ... (not 1: validation pairs taken from trajectories have neighbours on their own orbit among
#: the training pairs, transformed pairs lie between orbits; 4.5 x measured for the true reversing symmetry of the
#: three-body problem's tadpole orbits, against errors of order 1 for maps that are no symmetry)
HOLD_FACTOR = 10.0
#: ... and at most this relative one-step error (a map that is no symmetry gives errors of order 1).
HOLD_CEILING = 0.25
#: Transformed validation inputs that must lie in the box of the training inputs for the test to decide.
MIN_TESTED = 20
#: ... widened by this fraction of its width per coordinate.
BOX_TOLERANCE = 0.05


@dataclass
class StructureFinding:
    """One structure the search tested, and what the test found.

    Attributes
    ----------
    kind : str
        ``'symmetry'`` (symplectic sign flip), ``'reversing symmetry'`` (anti-symplectic) or ``'wrapped angle'``.
    signs : tuple of int or None
        The sign flip ``diag(signs)`` (symmetries).
    coordinate : int or None
        The state coordinate (wrapped angles).
    verdict : str
        ``'holds'``, ``'fails'`` or ``'untestable'``.
    reason : str
        The test and its numbers, in one sentence.
    e_transformed, e_validation : float
        The quick model's median relative one-step errors on the transformed and on the validation pairs (nan
        where not measured).
    n_tested : int
        Transformed pairs that lay among the data (symmetries), or samples with a jump (wrapped angles).
    """

    kind: str
    verdict: str
    reason: str
    signs: Optional[tuple] = None
    coordinate: Optional[int] = None
    e_transformed: float = float("nan")
    e_validation: float = float("nan")
    n_tested: int = 0

    def summary(self) -> str:
        what = (
            f"{self.kind} diag{self.signs}"
            if self.signs is not None
            else f"{self.kind} in coordinate {self.coordinate}"
        )
        return f"{what}: {self.verdict} ({self.reason})"


def sign_flip_candidates(dim: int) -> list:
    """``[(signs, kind), ...]``: the sign flips of conjugate pairs (symmetries) and of every momentum with some pairs
    (reversing symmetries) for states of dimension ``dim = 2n`` (module docstring)."""
    n = dim // 2
    if n <= 3:
        subsets = [s for k in range(n + 1) for s in itertools.combinations(range(n), k)]
    else:
        subsets = [()] + [(i,) for i in range(n)] + [tuple(range(n))]
    out = []
    for kind in ("reversing symmetry", "symmetry"):
        for subset in subsets:
            signs = np.ones(dim, dtype=int)
            signs[list(subset)] = -1
            signs[[n + i for i in subset]] = -1
            if kind == "reversing symmetry":
                signs[n:] *= -1
            elif not subset:
                continue  # the identity
            out.append((tuple(int(v) for v in signs), kind))
    return out


def _kind_of(g: np.ndarray) -> Optional[str]:
    """``'symmetry'`` (``g^T J g = J``), ``'reversing symmetry'`` (``= -J``) or ``None``."""
    n = len(g) // 2
    J = np.zeros((2 * n, 2 * n))
    J[:n, n:], J[n:, :n] = np.eye(n), -np.eye(n)
    gjg = g.T @ J @ g
    if np.allclose(gjg, J, atol=1e-12):
        return "symmetry"
    if np.allclose(gjg, -J, atol=1e-12):
        return "reversing symmetry"
    return None


def _relative_errors(
    model, x_in: np.ndarray, x_out: np.ndarray, data: FlowMapData, uses_mu: bool, uses_dt: bool
) -> np.ndarray:
    """``|Phi(x_in) - x_out| / |x_out - x_in|`` per pair (inf where Newton fails)."""
    inc = np.linalg.norm(x_out - x_in, axis=1)
    failures = (ArithmeticError, NewtonConvergenceError, NonFinitePredictionError, ValueError)

    def predict(rows):  # the test's own queries: near the box's edge by design, not the user's extrapolation
        with extrapolation_expected():
            return model.step(x_in[rows], mu=data.mu[rows] if uses_mu else None, dt=data.dt[rows] if uses_dt else None)

    try:
        pred = predict(np.arange(len(x_in)))
    except failures:  # one instance's failure fails the batch: the others one by one (a failure scores inf)
        pred = np.full(x_in.shape, np.inf)
        for i in range(len(x_in)):
            try:
                pred[i] = predict(np.array([i]))[0]
            except failures:
                pass
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.linalg.norm(pred - x_out, axis=1) / np.where(inc > 0, inc, np.nan)


def validation_error(model, val: FlowMapData, uses_mu: bool = True, uses_dt: bool = True) -> float:
    """The quick model's median relative one-step error on the validation pairs, ``e_0`` of :func:`check_sign_flip`."""
    return float(np.nanmedian(_relative_errors(model, val.x0, val.x1, val, uses_mu, uses_dt)))


def check_sign_flip(
    model,
    train: FlowMapData,
    val: FlowMapData,
    signs,
    kind: str,
    uses_mu: bool = True,
    uses_dt: bool = True,
    e_validation: Optional[float] = None,
) -> StructureFinding:
    """Whether ``diag(signs)`` is a symmetry (``kind='symmetry'``) or a reversing symmetry of the sampled flow.

    Parameters
    ----------
    model
        A fitted quick model of ``train`` (it predicts the transformed pairs).
    train, val : FlowMapData
        The search's training and validation samples.
    signs : sequence of int
        ``+1`` / ``-1`` per state coordinate.
    kind : str
        ``'symmetry'``: the pairs ``(g x0, g x1)``; ``'reversing symmetry'``: ``(g x1, g x0)``.
    uses_mu, uses_dt : bool
        Whether the model takes ``mu`` and ``dt`` per query.
    e_validation : float, optional
        ``e_0`` when known (:func:`validation_error`; the same for every candidate).

    Returns
    -------
    StructureFinding

    Notes
    -----
    Cost: one one-step prediction of the transformed validation samples (and one of the samples themselves
    unless ``e_validation`` is given).  A transformed input in a hole of the data's box
    is predicted poorly: the test then misses a symmetry rather than taking a false one.  Robust to noise as the module docstring says: measured in ``tests/estimators/test_structure.py``.
    """
    g = np.asarray(signs, dtype=float)
    if kind == "symmetry":
        a, b = val.x0 * g, val.x1 * g
    else:
        a, b = val.x1 * g, val.x0 * g
    lo, hi = train.x0.min(axis=0), train.x0.max(axis=0)
    margin = BOX_TOLERANCE * (hi - lo)
    near = np.all((a >= lo - margin) & (a <= hi + margin), axis=1)
    name = f"diag{tuple(int(v) for v in signs)}"
    if near.sum() < MIN_TESTED:
        return StructureFinding(
            kind,
            "untestable",
            f"only {int(near.sum())} of {len(a)} transformed validation "
            f"inputs lie in the box of the training inputs (at least {MIN_TESTED} needed): {name} "
            "maps the data where there are none",
            signs=tuple(int(v) for v in signs),
            n_tested=int(near.sum()),
        )
    e0 = validation_error(model, val, uses_mu, uses_dt) if e_validation is None else float(e_validation)
    sub = val.subset(np.flatnonzero(near))
    et = float(np.nanmedian(_relative_errors(model, a[near], b[near], sub, uses_mu, uses_dt)))
    holds = et <= HOLD_FACTOR * e0 and et <= HOLD_CEILING
    pairs = "(g x0, g x1)" if kind == "symmetry" else "(g x1, g x0)"
    reason = (
        f"a quick model's median relative one-step error on {int(near.sum())} pairs {pairs} is {et:.3g}, on the "
        f"validation pairs {e0:.3g}: {'within' if holds else 'beyond'} {HOLD_FACTOR:g} x and {HOLD_CEILING:g}"
    )
    verdict = "holds" if holds else "fails"
    if not holds and not e0 <= HOLD_CEILING:  # the data's own pairs are not predicted: nothing to compare with
        verdict = "untestable"
        reason += " (the validation error itself is above the ceiling: data too noisy or the model too coarse)"
    return StructureFinding(
        kind,
        verdict,
        reason,
        signs=tuple(int(v) for v in signs),
        e_transformed=et,
        e_validation=e0,
        n_tested=int(near.sum()),
    )


def check_group(model, train, val, group, uses_mu=True, uses_dt=True) -> list:
    """:func:`check_sign_flip` for each non-identity element of a declared group that is a signed diagonal; other
    elements are reported ``'untestable'`` (only sign flips are tested)."""
    out = []
    for g in StateSymmetry.coerce(group).array:
        if np.allclose(g, np.eye(len(g))):
            continue
        kind = _kind_of(g)
        diag = np.diag(g)
        if kind is None or not np.allclose(g, np.diag(diag)):
            out.append(StructureFinding(kind or "map", "untestable", "only sign flips are tested"))
            continue
        out.append(check_sign_flip(model, train, val, tuple(int(round(v)) for v in diag), kind, uses_mu, uses_dt))
    return out


def group_of(signs_list) -> list:
    """The group generated by commuting sign flips: every product of a subset, the identity first (sign patterns)."""
    ident = (1,) * len(signs_list[0])
    elements = {ident}
    for s in signs_list:
        elements |= {tuple(int(a * b) for a, b in zip(e, s)) for e in elements}
    return [ident] + sorted(e for e in elements if e != ident)


def fold(x: np.ndarray, group) -> np.ndarray:
    """The sign flip ``g`` (in ``group``) that maps each state of ``x`` to its representative: the image ``g x``
    that is largest in the lexicographic order of the coordinates sorted by their spread over ``x``
    (largest first; ties by index).

    A symmetric kernel ``sum_g k(x, g y)`` sees the data only modulo the group, so its normalisation and shapes
    belong to the folded states: on the three-body problem's orbits about ``L4`` and their mirror images about
    ``L5`` (``y -> -y``) the unfolded ``y`` spreads over both clusters, the folded ``y`` over one.  The fold is clean
    where the widest flipped coordinate separates the images (it does there); where the images overlap in it, the
    folded states mix parts of both.

    Parameters
    ----------
    x : ndarray of shape (M, 2n)
    group : sequence of sign patterns (tuples of ``+1`` / ``-1``), the identity among them

    Returns
    -------
    ndarray of shape (M, 2n)
        ``g`` per state (``x * fold(x, group)`` are the folded states; a pair ``(x0, x1)`` folds with ``x0``'s).
        ``O(|G| M 2n)``.
    """
    x = np.asarray(x, dtype=float)
    signs = np.asarray(group, dtype=float)
    order = np.argsort(-np.std(x, axis=0), kind="stable")
    images = signs[:, None, :] * x[None, :, :]  # (|G|, M, 2n)
    keys = images[:, :, order]
    best = np.zeros(len(x), dtype=int)
    rows = np.arange(len(x))
    for k in range(1, len(signs)):
        diff = keys[k] - keys[best, rows]
        first = np.argmax(diff != 0, axis=1)  # the first coordinate where the two images differ
        best = np.where(diff[rows, first] > 0, k, best)
    return signs[best]


def wrapped_coordinates(data: FlowMapData, period: float = 2 * np.pi) -> list:
    """The coordinates that look like angles reduced to one period (module docstring), as findings.

    ``O(M 2n)``.  Returns one :class:`StructureFinding` (verdict ``'holds'``) per such coordinate.
    """
    out = []
    d = data.x1 - data.x0
    x = np.concatenate([data.x0, data.x1])
    for i in range(d.shape[1]):
        di = d[:, i]
        k = np.round(di / period)
        jump = (k != 0) & (np.abs(di - k * period) < period / 8)
        if not jump.any() or jump.mean() > 0.25:
            continue
        typical = float(np.median(np.abs(di[~jump])))
        span = float(np.ptp(x[:, i]))
        if typical < period / 8 and span <= 1.05 * period:
            out.append(
                StructureFinding(
                    "wrapped angle",
                    "holds",
                    f"{int(jump.sum())} of {len(di)} samples jump by about {period:.6g} (a period) between consecutive "
                    f"states while the median step is {typical:.3g}, and the values span {span:.6g}: an angle reduced to "
                    f"one period. Unwrap each trajectory (numpy.unwrap along time, or x1 = x0 + the increment reduced "
                    f"to [-P/2, P/2)) and pass Periodic(None, coordinates=({i},)) as the state kernel",
                    coordinate=i,
                    n_tested=int(jump.sum()),
                )
            )
    return out


def warn_wrapped_angles(data: FlowMapData) -> None:
    """One :class:`~sympredict.exceptions.WrappedAngleWarning` per coordinate of ``data`` that looks like an angle
    reduced to one period (:func:`wrapped_coordinates`), naming it and the fix.  ``O(M 2n)``."""
    n = data.x0.shape[1] // 2
    for f in wrapped_coordinates(data):
        name = f"q{f.coordinate + 1}" if f.coordinate < n else f"p{f.coordinate - n + 1}"
        warnings.warn(
            f"state coordinate {f.coordinate} ({name}) looks like a wrapped angle: {f.reason}",
            WrappedAngleWarning,
            stacklevel=5,
        )


def compete(
    estimator,
    chosen: dict,
    chosen_score: float,
    m_final: int,
    train: FlowMapData,
    val: FlowMapData,
    score,
    open_state: bool,
    open_update: bool,
    by_update: Optional[dict] = None,
    refine=None,
):
    """The search's structure stage: test the candidates and let those that hold compete with ``chosen``.

    Parameters
    ----------
    estimator
        The unfitted estimator (its given settings kept).
    chosen : dict
        The search's best ``state_kernel``, ``mu_kernel``, ``dt_kernel``, ``update``.
    chosen_score : float
        Its held-out one-step error at ``m_final`` centres.
    m_final : int
        Centres of the held-out comparison.
    train, val : FlowMapData
        The search's samples.
    score
        ``score(params) -> (float, int)``: the held-out one-step error of the candidate ``params`` at ``m_final``
        centres and the centres its fit reached (the search's own criterion, which also records the candidate in
        the search's table).
    open_state, open_update : bool
        Whether the search chose the state kernel and the update (a given state kernel is the user's: only a group
        the user declared inside it is tested, and reported).
    by_update : dict, optional
        The search's best parameters per update (``{'midpoint': params, ...}``): a group that reverses time
        competes with the best midpoint kernels, not with kernels chosen for another update.
    refine : callable, optional
        ``refine(params, group, value, n_centers) -> (params, value)``: the symmetric candidate normalised for its
        group where that is better (the search's :func:`~sympredict.estimators.auto._refine_structured`); ``None``:
        the candidate keeps the normalisation and shapes chosen without the symmetry.

    Returns
    -------
    params : dict
        ``chosen``, or the candidate with a :class:`~sympredict.kernels.transforms.Symmetric` state kernel (and the
        midpoint update where the group reverses time) that the held-out comparison preferred.
    score : float
    findings : list of StructureFinding

    Notes
    -----
    Cost: one quick fit (at most :data:`QUICK_CENTERS` centres), one one-step prediction of the validation
    samples plus one per candidate that stays in the data's box (``2^n + 2^n - 1`` candidates for ``n <= 3``),
    then per group that holds (at most one more per holding flip) one fit to ``m_final`` centres, and those of
    ``refine`` (the search's: one more where the fold separates).  ``O(M 2n)``
    for the wrapped-angle check.
    """
    findings = wrapped_coordinates(train)  # warned about once per fit, by the estimator (warn_wrapped_angles)
    for f in findings:
        logger.info("structure: coordinate %d looks like a wrapped angle: %s", f.coordinate, f.reason)
    if not open_state:
        return chosen, chosen_score, findings
    uses_mu, uses_dt = chosen.get("mu_kernel") is not None, chosen.get("dt_kernel") is not None
    quick = clone(estimator).set_params(**chosen, max_centers=min(QUICK_CENTERS, m_final))
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            fit_candidate(quick, train, uses_mu=uses_mu, quiet=False)
    except (ValueError, ArithmeticError) as exc:
        logger.info("structure: the quick model did not fit (%s); no symmetry tested", exc)
        return chosen, chosen_score, findings
    declared = lower_state_kernel(chosen["state_kernel"]).symmetry
    if declared is not None:  # the user's group: tested and reported, never replaced
        for f in check_group(quick, train, val, declared, uses_mu, uses_dt):
            findings.append(f)
            (logger.warning if f.verdict == "fails" else logger.info)("structure (declared group): %s", f.summary())
        return chosen, chosen_score, findings
    holding = []
    e0 = validation_error(quick, val, uses_mu, uses_dt)
    for signs, kind in sign_flip_candidates(train.x0.shape[1]):
        f = check_sign_flip(quick, train, val, signs, kind, uses_mu, uses_dt, e_validation=e0)
        findings.append(f)
        logger.info("structure: %s", f.summary())
        if f.verdict == "holds":
            holding.append(f)
    if not holding:
        return chosen, chosen_score, findings
    groups = [[f.signs for f in holding]]
    if len(holding) > 1:
        groups += [[f.signs] for f in holding]
    best, best_score = chosen, chosen_score
    for generators in groups:
        group = group_of(generators)
        reversing = any(_kind_of(np.diag(np.asarray(s, dtype=float))) == "reversing symmetry" for s in group)
        update = "midpoint" if reversing else chosen["update"]
        if reversing and not open_update and str(getattr(chosen["update"], "name", chosen["update"])) != "midpoint":
            logger.info(
                "structure: the group %s reverses time, which only the midpoint update carries; the "
                "update is given, so it does not compete",
                group,
            )
            continue
        base = (by_update or {}).get(update, chosen) if update != chosen["update"] else chosen
        cand = {**base, "state_kernel": Symmetric(base["state_kernel"], group=group), "update": update}
        value, n = score(cand)
        if refine is not None:  # the group changes what the kernel sees
            cand, value = refine(cand, group, value, n)
        logger.info(
            "structure: Symmetric(group=%s) with update %r: held-out one-step error %.3e (without: %.3e)",
            group,
            update,
            value,
            chosen_score,
        )
        if value < best_score:
            best, best_score = cand, value
    return best, best_score, findings
