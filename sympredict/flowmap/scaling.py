"""Scalings around a flow-map predictor that keep the learned step symplectic.

* Parameters: affine map of the training box onto ``[0, 1]^d`` (components
  with zero width are only shifted), so one isotropic ``mu`` kernel fits every
  parameter whatever its units.
* Steps: time rescaling ``dT~ = dT / tau`` (``tau`` the largest training
  step).  The learned map is unchanged (``s~ = tau s``); an affine map of
  ``dT`` would not do, the step enters the update ``p1 = p0 - dT d_q s``.
* States: ``x~ = S x`` with ``S = sigma * blockdiag(diag(a), diag(1/a))``, or
  ``S = sigma W^-1`` with ``W`` the Williamson form of a reference Hamiltonian
  matrix (:func:`williamson`; symplectic, so the argument below holds too).
  ``diag(a, 1/a)`` is symplectic and the scalar ``sigma`` conformally
  symplectic (``S^T J S = sigma^2 J``).  The conjugate step
  ``Phi = S^-1 Phi~ S`` has ``D Phi = S^-1 D Phi~ S``, and with
  ``S^-T J S^-1 = sigma^-2 J``:
  ``D Phi^T J D Phi = sigma^-2 S^T (D Phi~^T J D Phi~) S = sigma^-2 S^T J S = J``
  whenever the learned step ``Phi~`` is symplectic.  ``a_i = sqrt(std(p_i) / std(q_i))`` makes
  each mode's ``q`` and ``p`` spreads equal, ``sigma`` makes the RMS state 1, so
  an isotropic state kernel sees comparable coordinates (DESIGN.md, "Linear
  symplectic normalization").
"""

from __future__ import annotations

import warnings
from itertools import product
from math import comb
from typing import Optional

from sympredict.exceptions import ExtrapolationWarning

import numpy as np
from scipy.linalg import schur

from sympredict._checks import as_parameter, as_positive_int
from sympredict.systems.linear_flow import QuadraticPart
from sympredict.symplectic.metrics import canonical_J

__all__ = ["BoxScaling", "SymplecticScaling", "NormalizedFlowMap", "williamson", "scaled_quadratic_part"]


class BoxScaling:
    """``u = (v - lo) / width`` per component, fitted from values (or bounds)."""

    def fit(self, values: np.ndarray, lo=None, hi=None) -> "BoxScaling":
        """Fit from values (M, d) or explicit bounds ``lo``, ``hi`` (d,)."""
        values = np.asarray(values, dtype=float)
        self.lo_ = np.asarray(values.min(axis=0) if lo is None else lo, dtype=float)
        hi = np.asarray(values.max(axis=0) if hi is None else hi, dtype=float)
        width = hi - self.lo_
        self.width_ = np.where(width > 0, width, 1.0)
        return self

    def transform(self, values) -> np.ndarray:
        return (np.asarray(values, dtype=float) - self.lo_) / self.width_

    def inverse_transform(self, values) -> np.ndarray:
        return np.asarray(values, dtype=float) * self.width_ + self.lo_


def williamson(H: np.ndarray) -> tuple:
    """Williamson normal form of an SPD ``H`` (2n, 2n): symplectic ``S`` with ``S^T H S = diag(d, d)``.

    ``A = H^{-1/2} J H^{-1/2}`` is skew-symmetric; its real Schur form
    ``Q^T A Q`` has 2x2 blocks ``[[0, b_k], [-b_k, 0]]`` (columns of a block
    swapped where ``b_k < 0``).  With the columns reordered into ``(q, p)``
    halves (``Q'``) and ``D = diag(b^{-1/2}, b^{-1/2})``, ``S = H^{-1/2} Q' D``
    gives ``S^T J S = D Q'^T A Q' D = J`` and ``S^T H S = D^2 = diag(1/b, 1/b)``:
    ``d = 1/b`` are the symplectic eigenvalues (the modal frequencies).

    Returns
    -------
    S : ndarray of shape (2n, 2n)
    d : ndarray of shape (n,)

    Raises
    ------
    ValueError
        If ``H`` is not symmetric positive definite.
    """
    H = np.asarray(H, dtype=float)
    dim = H.shape[0]
    n = dim // 2
    lam, U = np.linalg.eigh(0.5 * (H + H.T))
    if lam.min() <= 0:
        raise ValueError(f"the Williamson form needs an SPD Hamiltonian matrix; smallest eigenvalue {lam.min():.3e}")
    h_inv_sqrt = (U / np.sqrt(lam)) @ U.T
    J = canonical_J(dim)
    A = h_inv_sqrt @ J @ h_inv_sqrt
    T, Q = schur(0.5 * (A - A.T), output="real")
    b = np.empty(n)
    for k in range(n):
        if T[2 * k, 2 * k + 1] < 0:
            Q[:, [2 * k, 2 * k + 1]] = Q[:, [2 * k + 1, 2 * k]]
        b[k] = abs(T[2 * k, 2 * k + 1])
    Qp = Q[:, np.r_[0:dim:2, 1:dim:2]]
    S = h_inv_sqrt @ Qp * np.concatenate([b, b]) ** -0.5
    return S, 1.0 / b


class SymplecticScaling:
    """``x~ = T x`` with a conformally symplectic ``T`` (``T^T J T = sigma^2 J``), fitted from states.

    Parameters
    ----------
    mode : {"diag", "uniform", "williamson", "none"}
        ``"diag"``: ``T = sigma blockdiag(diag(a), diag(1/a))``, per-mode
        ``a_i = sqrt(std(p_i) / std(q_i))``; ``"uniform"``: ``a = 1``;
        ``"williamson"``: ``T = sigma S^-1`` with ``S`` the Williamson form of
        ``reference`` (:func:`williamson`: each mode of the reference
        Hamiltonian becomes a rotation, its energy a sum of circles);
        ``"none"``: ``T = I``.  ``sigma`` makes the RMS transformed state 1.
    reference : ndarray of shape (2n, 2n), optional
        SPD Hamiltonian matrix for ``"williamson"`` (e.g. the reduced ``H(mu)`` at the box centre).
    """

    def __init__(self, mode: str = "diag", reference: Optional[np.ndarray] = None):
        if mode not in ("diag", "uniform", "williamson", "none"):
            raise ValueError(f"mode must be 'diag', 'uniform', 'williamson' or 'none', got {mode!r}")
        if mode == "williamson" and reference is None:
            raise ValueError("mode='williamson' needs a reference Hamiltonian matrix")
        self.mode = mode
        self.reference = reference

    def fit(self, states: np.ndarray) -> "SymplecticScaling":
        """Fit from states (M, 2n) ordered ``(q, p)``."""
        x = np.asarray(states, dtype=float)
        n = x.shape[1] // 2
        if self.mode == "williamson":
            S, _ = williamson(self.reference)
            T = np.linalg.inv(S)
        else:
            a = np.ones(n)
            if self.mode == "diag":
                sq, sp = x[:, :n].std(axis=0), x[:, n:].std(axis=0)
                ok = (sq > 0) & (sp > 0)
                a[ok] = np.sqrt(sp[ok] / sq[ok])
            T = np.diag(np.concatenate([a, 1.0 / a]))
        rms = np.sqrt(np.mean((x @ T.T) ** 2)) if self.mode != "none" else 1.0
        sigma = 1.0 / rms if rms > 0 else 1.0
        self.matrix_ = sigma * T
        self.inverse_ = np.linalg.inv(self.matrix_)
        return self

    def transform(self, x) -> np.ndarray:
        return np.asarray(x, dtype=float) @ self.matrix_.T

    def inverse_transform(self, x) -> np.ndarray:
        return np.asarray(x, dtype=float) @ self.inverse_.T


class NormalizedFlowMap:
    """A fitted flow-map predictor used in scaled coordinates: ``Phi(x) = S^-1 Phi~(S x; mu~, dT~)``.

    Parameters
    ----------
    predictor
        Fitted; has ``step``, ``rollout``, ``step_jacobian`` in scaled coordinates.
    state_scaling : SymplecticScaling
    mu_scaling : BoxScaling or None
        ``None`` for a parameter-free predictor.
    tau : float
        Time unit: the predictor sees ``dT / tau``.
    parameters : mapping of str to int, optional
        Names and dimensions of the parameters (e.g. pyMOR ``Parameters``): a pyMOR ``Mu`` or a dict
        passed as ``mu`` is read in this order (values sorted by name, each flattened).  Without it a
        ``Mu`` is read by ``Mu.to_numpy()`` and a dict must have one key.
    """

    def __init__(
        self, predictor, state_scaling: SymplecticScaling, mu_scaling: Optional[BoxScaling], tau: float, parameters=None
    ):
        self.predictor = predictor
        self.state_scaling = state_scaling
        self.mu_scaling = mu_scaling
        self.tau = float(tau)
        self.parameters = None if parameters is None else {str(k): int(v) for k, v in dict(parameters).items()}

    def _mu(self, mu, b):
        """``mu`` as given, or a pyMOR ``Mu``/dict (or a list of them) as an array ``(B, d)``."""
        if mu is None or self.mu_scaling is None:
            return mu
        return as_parameter(mu, b, len(self.mu_scaling.lo_), parameters=getattr(self, "parameters", None))

    def _args(self, mu, dt, b):
        m = None
        if self.mu_scaling is not None:
            d = len(self.mu_scaling.lo_)
            mu = np.asarray(self._mu(mu, b), dtype=float)
            if mu.ndim == 2:
                mu = np.broadcast_to(mu, (b, d))
            elif d == 1 and mu.size == b:
                mu = mu.reshape(b, 1)
            else:
                mu = np.broadcast_to(mu.reshape(1, d), (b, d))
            m = self.mu_scaling.transform(mu)
        return m, None if dt is None else np.asarray(dt, dtype=float) / self.tau

    def _in_user_units(self, call, mu, dt):
        """``call()``, with the predictor's :class:`ExtrapolationWarning` (about scaled values) said again in the
        caller's units: parameters, steps, and the states' box mapped back."""
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", ExtrapolationWarning)
            out = call()
        for w in caught:
            if not issubclass(w.category, ExtrapolationWarning):
                warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
                continue
            warnings.warn(self._user_message(mu, dt), ExtrapolationWarning, stacklevel=3)
        return out

    def _user_message(self, mu, dt) -> str:
        """The extrapolation note in original units (the predictor's training box mapped back)."""
        parts = []
        domain = getattr(self.predictor, "domain_", None)
        if domain is not None and self.mu_scaling is not None and mu is not None:
            lo = self.mu_scaling.inverse_transform(np.asarray(domain["mu_min"])[None])[0]
            hi = self.mu_scaling.inverse_transform(np.asarray(domain["mu_max"])[None])[0]
            given = np.asarray(mu, dtype=float).reshape(-1, len(lo))
            parts.append(
                f"mu spans {given.min(axis=0).tolist()}..{given.max(axis=0).tolist()}, "
                f"training box {lo.tolist()}..{hi.tolist()}"
            )
        if domain is not None and dt is not None:
            parts.append(
                f"dt = {np.unique(np.asarray(dt, dtype=float))[:5].tolist()}, training steps "
                f"{float(domain['dt_min']) * self.tau!r}..{float(domain['dt_max']) * self.tau!r}"
            )
        return (
            "extrapolation: the query (or its trajectory) leaves the training data of the flow map; in the caller's "
            "units: " + ("; ".join(parts) if parts else "the states leave the box of the training states")
        )

    @property
    def dim_(self) -> int:
        """State dimension ``2n`` (the flow-map protocol, :mod:`sympredict.flowmap.protocol`)."""
        return self.predictor.dim_

    @property
    def n_mu_(self) -> int:
        """Parameter dimension."""
        return self.predictor.n_mu_

    def step(self, x, mu=None, dt=None) -> np.ndarray:
        """One step of states (B, 2n); ``mu`` (d,) or (B, d) in original units."""
        x = np.atleast_2d(np.asarray(x, dtype=float))
        mu = self._mu(mu, len(x))
        m, d = self._args(mu, dt, len(x))
        return self.state_scaling.inverse_transform(
            self._in_user_units(lambda: self.predictor.step(self.state_scaling.transform(x), mu=m, dt=d), mu, dt)
        )

    def step_jacobian(self, x, mu=None, dt=None) -> np.ndarray:
        """``D Phi = T^-1 D Phi~ T``, shape (B, 2n, 2n)."""
        x = np.atleast_2d(np.asarray(x, dtype=float))
        mu = self._mu(mu, len(x))
        m, d = self._args(mu, dt, len(x))
        jac = self.predictor.step_jacobian(self.state_scaling.transform(x), mu=m, dt=d)
        return self.state_scaling.inverse_ @ jac @ self.state_scaling.matrix_

    def rollout(self, x0, n_steps: int, mu=None, dt=None) -> np.ndarray:
        """Trajectories (B, K+1, 2n) of ``n_steps`` steps."""
        n_steps = as_positive_int(n_steps, "n_steps", minimum=0)
        x0 = np.atleast_2d(np.asarray(x0, dtype=float))
        mu = self._mu(mu, len(x0))
        m, d = self._args(mu, dt, len(x0))
        return self.state_scaling.inverse_transform(
            self._in_user_units(
                lambda: self.predictor.rollout(self.state_scaling.transform(x0), n_steps, mu=m, dt=d), mu, dt
            )
        )


def scaled_quadratic_part(
    quadratic: QuadraticPart, state_scaling: SymplecticScaling, mu_scaling: Optional[BoxScaling], tau: float
) -> QuadraticPart:
    """The quadratic part ``A(mu)`` in the scaled coordinates of :class:`NormalizedFlowMap`.

    With ``x~ = M x`` (``M^T J M = sigma^2 J``), ``mu = lo + width * mu~`` and ``dT~ = dT / tau``, the flow of
    ``x' = J A(mu) x`` is ``dx~/dT~ = J A~(mu~) x~`` with ``A~ = tau J^T M J A M^-1 = tau sigma^2 M^-T A M^-1``
    (symmetric), so ``expm(dT~ J A~(mu~)) = M expm(dT J A(mu)) M^-1``: the splitting predictor
    (:mod:`sympredict.flowmap.splitting`) fitted in the scaled coordinates has the same exact linear flow.  Each
    monomial ``prod_i mu_i^p_i`` becomes the polynomial ``prod_i (lo_i + width_i mu~_i)^p_i``, expanded into
    monomials of ``mu~`` (binomial terms; equal powers merged), so the powers must be non-negative integers.

    Parameters
    ----------
    quadratic : QuadraticPart
        ``A(mu)`` in the original coordinates and units.
    state_scaling : SymplecticScaling
        Fitted (``matrix_`` is ``M``).
    mu_scaling : BoxScaling or None
        Fitted; ``None`` for a parameter-free ``A``.
    tau : float
        The time unit.

    Returns
    -------
    QuadraticPart
        ``A~(mu~)``; ``O(K 2^d (2n)^3)`` for ``K`` terms, ``d`` parameter components.

    Raises
    ------
    ValueError
        A power that is not a non-negative integer while ``mu`` is scaled, or a parameter-dependent ``A``
        without ``mu_scaling``.
    """
    mats, pw = quadratic.checked(dim=state_scaling.matrix_.shape[0])
    M = state_scaling.matrix_
    J = canonical_J(M.shape[0])
    left, right = float(tau) * J.T @ M @ J, np.linalg.inv(M)
    scaled = [left @ A @ right for A in mats]
    scaled = [0.5 * (A + A.T) for A in scaled]  # symmetric up to round-off
    if pw.shape[1] == 0:
        return QuadraticPart(np.array(scaled), None)
    if mu_scaling is None:
        raise ValueError("scaled_quadratic_part: A(mu) depends on mu, pass the fitted mu_scaling")
    if np.any(pw < 0) or np.any(pw != np.round(pw)):
        raise ValueError(
            f"scaled_quadratic_part: an affine scaling of mu keeps A(mu) a sum of monomials only for "
            f"non-negative integer powers, got {pw.tolist()}"
        )
    lo, width = np.asarray(mu_scaling.lo_, dtype=float), np.asarray(mu_scaling.width_, dtype=float)
    terms = {}
    for A, p in zip(scaled, pw.astype(int)):
        for e in product(*(range(pi + 1) for pi in p)):  # exponents of mu~ in the expansion
            coef = np.prod([comb(pi, ei) * lo[i] ** (pi - ei) * width[i] ** ei for i, (pi, ei) in enumerate(zip(p, e))])
            terms[e] = terms.get(e, 0.0) + coef * A
    keys = sorted(terms)
    return QuadraticPart(np.array([terms[k] for k in keys]), np.array(keys, dtype=float))
