"""Flow-map data: samples ``x1 = Phi_mu^dT(x0)`` and their mixed-variable form.

The symplectic predictor is trained on the *mixed* variables and targets

* ``xi = (q0, p1)``,
* ``y = J^T (x1 - x0) / dT = (-(p1 - p0) / dT, (q1 - q0) / dT)``,

with ``J = [[0, I], [-I, 0]]``, so that the implicit symplectic-Euler update
``p1 = p0 - dT d_q s(q0, p1)``, ``q1 = q0 + dT d_p s(q0, p1)`` reproduces the
data exactly where ``grad_xi s(xi_j) = y_j``.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Optional

import numpy as np

from sympredict._checks import as_parameter, as_states, as_steps, as_times, as_trajectories
from sympredict._numeric import j_times
from sympredict.exceptions import DuplicateSamplesWarning

__all__ = ["FlowMapData", "TrajectoryData", "mixed_variables", "as_flowmap_data", "unique_samples"]


def mixed_variables(x0: np.ndarray, x1: np.ndarray, dt: np.ndarray):
    """Mixed variables and gradient targets of flow-map samples.

    Parameters
    ----------
    x0, x1 : ndarray of shape (M, 2n)
    dt : ndarray of shape (M,)

    Returns
    -------
    xi : ndarray of shape (M, 2n)
        ``(q0, p1)``.
    y : ndarray of shape (M, 2n)
        ``J^T (x1 - x0) / dT``.
    """
    n = x0.shape[1] // 2
    xi = np.concatenate([x0[:, :n], x1[:, n:]], axis=1)
    inc = (x1 - x0) / dt[:, None]
    y = -j_times(inc)  # J^T = -J
    return xi, y


@dataclass
class FlowMapData:
    """A set of flow-map samples over parameters and macro steps.

    Parameters
    ----------
    x0, x1 : ndarray of shape (M, 2n)
        Initial and propagated states, ``x1 = Phi_mu^dt(x0)``.
    mu : ndarray of shape (M, d_mu)
        Parameters (``d_mu = 0`` for a parameter-free system).
    dt : ndarray of shape (M,)
        Macro steps.
    """

    x0: np.ndarray
    x1: np.ndarray
    mu: np.ndarray
    dt: np.ndarray

    def __post_init__(self):
        self.x0, _ = as_states(self.x0, "x0", allow_single=False)
        self.x1, _ = as_states(self.x1, "x1", dim=self.x0.shape[1], allow_single=False)
        m = len(self.x0)
        if len(self.x1) != m:
            raise ValueError(f"x0 and x1 must have the same number of samples, got {m} and {len(self.x1)}")
        if self.mu is None or np.size(self.mu) == 0:
            self.mu = np.zeros((m, 0))
        else:
            self.mu = as_parameter(self.mu, m, None)
        self.dt = as_steps(self.dt, m)
        # the estimators learn (x1 - x0) / dt: a step so small that it overflows would train on infinities
        with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
            rate = np.abs(self.x1 - self.x0).max(axis=1, initial=0.0) / self.dt
        bad = np.flatnonzero(~np.isfinite(rate))
        if bad.size:
            i = int(bad[0])
            raise ValueError(
                f"the increments (x1 - x0) / dt overflow for {bad.size} sample(s) (first: row {i}, "
                f"dt = {self.dt[i]:.3g}, |x1 - x0| = {np.abs(self.x1[i] - self.x0[i]).max():.3g}): give "
                f"dt and the states in units where the rate of change is a finite float (e.g. dt in "
                f"seconds, not in units of 1e-300 s)"
            )

    def __len__(self) -> int:
        return len(self.x0)

    def subset(self, index) -> "FlowMapData":
        """The samples selected by ``index`` (an index array, slice or mask)."""
        return FlowMapData(self.x0[index], self.x1[index], self.mu[index], self.dt[index])

    def split(self, validation_fraction: float, seed: int = 0):
        """Random train/validation split.

        Returns
        -------
        (FlowMapData, FlowMapData)
            Training and validation parts.
        """
        if not 0 < validation_fraction < 1:
            raise ValueError(f"validation_fraction must lie in (0, 1), got {validation_fraction!r}")
        perm = np.random.default_rng(seed).permutation(len(self))
        n_val = max(1, int(round(validation_fraction * len(self))))
        return self.subset(np.sort(perm[n_val:])), self.subset(np.sort(perm[:n_val]))

    def drop_duplicates(self):
        """The data without repeated samples (overlapping trajectory windows produce them).

        A sample repeats an earlier one when ``x0``, ``x1``, ``mu`` and ``dt`` are all equal
        (bit for bit); the first occurrence is kept and the order is preserved.

        Returns
        -------
        data : FlowMapData
            The distinct samples (``self`` itself when there is no duplicate).
        n_dropped : int
            How many samples were dropped.

        Raises
        ------
        ValueError
            Samples with the same ``x0``, ``mu`` and ``dt`` but different ``x1`` (a flow map has one
            value per state): the message names their row indices.
        """
        keep = unique_samples(self.x0, self.x1, self.mu, self.dt, key_name="x0", target_name="x1")
        if len(keep) == len(self):
            return self, 0
        return self.subset(keep), len(self) - len(keep)

    def concatenate(self, other: "FlowMapData") -> "FlowMapData":
        """The union of two data sets (same state and parameter dimensions)."""
        return FlowMapData(
            np.concatenate([self.x0, other.x0]),
            np.concatenate([self.x1, other.x1]),
            np.concatenate([self.mu, other.mu]),
            np.concatenate([self.dt, other.dt]),
        )


def unique_samples(points, targets, mu, dt, *, key_name: str = "x0", target_name: str = "x1") -> np.ndarray:
    """Indices of the distinct samples; an error for contradictory ones.

    Samples are grouped by their key ``(points, mu, dt)``.  Within a group, samples with
    equal targets (bit for bit) are redundant: the first is kept.  A group with two
    different targets is contradictory (an interpolant cannot take two values at one point).

    Parameters
    ----------
    points : ndarray of shape (M, D)
        Where the samples sit (``x0``, or the mixed variable ``xi`` a kernel model sees).
    targets : ndarray of shape (M, T)
        What the samples prescribe there (``x1``, or the gradient targets).
    mu : ndarray of shape (M, d_mu)
    dt : ndarray of shape (M,)
    key_name, target_name : str
        Names of ``points`` and ``targets`` for the error message.

    Returns
    -------
    keep : ndarray of int, shape (M_distinct,)
        Increasing indices of the first occurrence of every distinct sample.

    Raises
    ------
    ValueError
        Contradictory samples, naming the row indices of (up to five) groups.
    """
    m = len(points)
    key = np.column_stack([points, mu, dt]).reshape(m, -1)
    _, key_of_row = np.unique(key, axis=0, return_inverse=True)
    key_of_row = key_of_row.reshape(-1)
    if key_of_row.max() + 1 == m:  # all keys distinct
        return np.arange(m)
    _, first = np.unique(np.column_stack([key, targets]).reshape(m, -1), axis=0, return_index=True)
    # distinct (key, target) rows per key: more than one is a contradiction
    variants = np.bincount(key_of_row[first], minlength=key_of_row.max() + 1)
    bad_keys = np.flatnonzero(variants > 1)
    if len(bad_keys):
        groups = [np.flatnonzero(key_of_row == k) for k in bad_keys[:5]]
        shown = "; ".join("rows " + ", ".join(str(i) for i in g[:6]) + (" ..." if len(g) > 6 else "") for g in groups)
        more = f" and {len(bad_keys) - 5} more group(s)" if len(bad_keys) > 5 else ""
        raise ValueError(
            f"the training data contain contradictory samples: the same {key_name}, mu and dt with different "
            f"{target_name} ({shown}{more}); remove or correct them (a flow map takes one value per state)"
        )
    return np.sort(first)


def _drop_duplicate_samples(data: FlowMapData, stacklevel: int = 3) -> FlowMapData:
    """``data.drop_duplicates()`` with one :class:`DuplicateSamplesWarning` saying how many were dropped."""
    reduced, dropped = data.drop_duplicates()
    if dropped:
        warnings.warn(
            DuplicateSamplesWarning(
                f"dropped {dropped} duplicated sample(s) (same x0, x1, mu and dt as an earlier one) of {len(data)}; "
                f"{len(reduced)} remain"
            ),
            stacklevel=stacklevel,
        )
    return reduced


@dataclass
class TrajectoryData:
    """Trajectories sampled at increasing times, one parameter vector each.

    Give either a uniform step ``dt`` (``t_k = k dt``) or the sample ``times``
    (uniform or not).  :meth:`pairs` turns the trajectories into flow-map samples;
    validation data that score whole rollouts (e.g. the reductor's choice of a ridge
    term) roll a model out from ``states[:, 0]`` for ``K`` steps of ``dt`` and compare
    with ``states[:, 1:]`` (uniform steps only).

    Parameters
    ----------
    states : ndarray of shape (P, K+1, 2n)
        ``P`` trajectories of ``K+1`` states each, ordered ``(q, p)``.
    mu : ndarray of shape (P, d_mu), default=None
        Parameters (``d_mu = 0`` for a parameter-free system); given as ``None``, a scalar,
        ``(P,)`` or ``(P, d_mu)``.
    dt : float or None, default=None
        The uniform step between consecutive states; ``None`` when the ``times`` are not
        uniform (to round-off: ``|t_{k+1} - t_k - h| <= 64 eps max|t|`` with one ``h``).
    times : ndarray of shape (P, K+1), default=None
        Sample times, strictly increasing along each trajectory; given as ``(P, K+1)`` or
        ``(K+1,)`` (shared), or derived from ``dt`` as ``k dt``.
    """

    states: np.ndarray
    mu: Optional[np.ndarray] = None
    dt: Optional[float] = None
    times: Optional[np.ndarray] = None

    def __post_init__(self):
        states = self.states = as_trajectories(self.states, "states")
        p, k1, _ = states.shape
        self.mu = np.zeros((p, 0)) if self.mu is None or np.size(self.mu) == 0 else as_parameter(self.mu, p, None)
        if (self.dt is None) == (self.times is None):
            raise ValueError("TrajectoryData needs exactly one of dt (a uniform step) and times ((P, K+1) or (K+1,))")
        if self.times is None:
            self.dt = float(as_steps(self.dt, 1)[0])
            self.times = np.broadcast_to(np.arange(k1) * self.dt, (p, k1))
            return
        times = as_times(self.times, p, k1)
        steps = np.diff(times, axis=1)
        self.times = times
        h = float((times[0, -1] - times[0, 0]) / (k1 - 1))  # the mean step: more accurate than any one difference
        tol = 64 * np.finfo(float).eps * float(np.abs(times).max())
        self.dt = h if np.abs(steps - h).max() <= tol else None

    def __len__(self) -> int:
        return len(self.states)

    def pairs(self, strides=1) -> FlowMapData:
        """Flow-map samples ``(x(t_k), x(t_{k+s}))`` for every stride ``s`` in ``strides``.

        Parameters
        ----------
        strides : int or sequence of int, default=1
            Strides ``1 <= s <= K`` (distinct).  ``dt`` of a pair is ``t_{k+s} - t_k``; with a
            uniform step ``h`` (``dt`` given, or times uniform to round-off) it is exactly ``s h``,
            so that decimal times read from a file give one step per stride.

        Returns
        -------
        FlowMapData
            ``sum_s P (K + 1 - s)`` samples: stride by stride, trajectory by trajectory, in time order.
        """
        p, k1, dim = self.states.shape
        values = np.atleast_1d(np.asarray(strides))
        if values.ndim != 1 or len(values) == 0 or values.dtype.kind not in "iu":
            raise ValueError(f"strides must be a positive integer or a non-empty sequence of them, got {strides!r}")
        if values.min() < 1 or values.max() > k1 - 1:
            raise ValueError(
                f"strides must lie in 1..K = 1..{k1 - 1} (the trajectories have {k1} states), got {strides!r}"
            )
        if len(np.unique(values)) < len(values):
            raise ValueError(f"strides must be distinct, got {strides!r}")
        x0, x1, mu, dt = [], [], [], []
        for s in values.tolist():
            x0.append(self.states[:, :-s].reshape(-1, dim))
            x1.append(self.states[:, s:].reshape(-1, dim))
            mu.append(np.repeat(self.mu, k1 - s, axis=0))
            if self.dt is not None:
                dt.append(np.full(p * (k1 - s), s * self.dt))
            else:
                dt.append((self.times[:, s:] - self.times[:, :-s]).reshape(-1))
        mu = np.concatenate(mu)
        return FlowMapData(np.concatenate(x0), np.concatenate(x1), mu if mu.shape[1] else None, np.concatenate(dt))


def as_flowmap_data(x0, x1=None, mu=None, dt=None, what: str = "fit") -> FlowMapData:
    """Flow-map samples from any of the accepted forms.

    Parameters
    ----------
    x0 : array_like of shape (M, 2n), FlowMapData or TrajectoryData
        Initial states, or a whole data set (then ``x1``, ``mu`` and ``dt`` must be omitted;
        trajectories give their consecutive pairs, :meth:`TrajectoryData.pairs`).
    x1 : array_like of shape (M, 2n)
        Propagated states (required with arrays).
    mu : array_like of shape (M,) or (M, d_mu), optional
    dt : float or array_like of shape (M,)
        Macro steps (required with arrays).
    what : str
        The call that receives the data, for error messages (``"fit"``, ``"validation"``).

    Returns
    -------
    FlowMapData
        Validated samples (duplicates are kept).
    """
    if isinstance(x0, (FlowMapData, TrajectoryData)):
        given = [name for name, v in (("x1", x1), ("mu", mu), ("dt", dt)) if v is not None]
        if given:
            raise ValueError(
                f"{what}: the data were given as a {type(x0).__name__}, which holds the states, mu and "
                f"dt; do not pass {', '.join(given)} as well"
            )
        return x0.pairs() if isinstance(x0, TrajectoryData) else x0
    if x1 is None:
        raise ValueError(
            f"{what}: x1 is required with array data (samples x1 = Phi(x0)); or pass a FlowMapData "
            "or TrajectoryData as the only argument"
        )
    x0, _ = as_states(x0, "x0", allow_single=False)
    x1, _ = as_states(x1, "x1", dim=x0.shape[1], allow_single=False)
    if len(x0) != len(x1):
        raise ValueError(f"x0 and x1 must have the same number of samples, got {len(x0)} and {len(x1)}")
    mu_arr = None if mu is None else as_parameter(mu, len(x0), None)
    return FlowMapData(x0, x1, mu_arr, as_steps(dt, len(x0)))
