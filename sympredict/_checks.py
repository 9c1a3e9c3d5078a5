"""Input validation as data: one function per kind of input, one table row per setting.

Every public entry point validates its inputs here, each rule written once, each message naming the
argument, the value (its shape or first offending entry) and the fix:

* states ``(B, 2n)`` or ``(2n,)``: :func:`as_states`;
* parameters ``mu`` ``(B, d_mu)``, matched to a model's parameter count or names: :func:`as_parameter`,
  :func:`as_model_parameter`;
* macro steps ``dt``, scalar or one per instance: :func:`as_steps`;
* trajectories ``(P, K+1, 2n)`` and their sample times: :func:`as_trajectories`, :func:`as_times`;
* numbers, counts, choices and flags: :func:`as_real`, :func:`as_positive_int`, :func:`as_real_array`,
  :func:`as_choice`, :func:`as_flag`;
* an estimator's settings: its table ``_parameter_constraints`` of :class:`Constraint` rows, read by
  :func:`check_settings` at ``fit``, model-file load and save, and by ``set_params``.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Optional

import numpy as np

__all__ = [
    "as_states",
    "as_parameter",
    "as_model_parameter",
    "as_steps",
    "as_trajectories",
    "as_times",
    "as_positive_int",
    "as_real",
    "as_real_array",
    "as_choice",
    "as_flag",
    "as_even_dimension",
    "Constraint",
    "check_settings",
]


def _first_bad(arr: np.ndarray, bad: np.ndarray) -> str:
    """``"at index (i, j): value"`` of the first ``True`` of the mask ``bad`` (what a message shows of the value)."""
    index = np.unravel_index(int(np.flatnonzero(bad.reshape(-1))[0]), arr.shape) if arr.ndim else ()
    where = f"index {tuple(int(i) for i in index)}" if arr.ndim > 1 else (f"index {int(index[0])}" if arr.ndim else "")
    value = float(arr[index]) if arr.ndim else float(arr)
    count = int(np.count_nonzero(bad))
    return (f"{where}: {value!r}" if where else f"{value!r}") + (f", {count} entries in all" if count > 1 else "")


def _as_float_array(value, name: str) -> np.ndarray:
    try:
        arr = np.asarray(value)
    except Exception as exc:  # ragged lists and the like
        raise ValueError(f"{name} must be a numeric array: {exc}") from None
    if arr.dtype == object or not (np.issubdtype(arr.dtype, np.number) or arr.dtype == bool):
        raise ValueError(f"{name} must be a real numeric array, got dtype {arr.dtype}")
    if np.iscomplexobj(arr):
        raise ValueError(f"{name} must be real, got complex values")
    arr = arr.astype(float)
    finite = np.isfinite(arr)
    if not np.all(finite):
        raise ValueError(f"{name} contains NaN or Inf ({_first_bad(arr, ~finite)}): give finite numbers")
    return arr


def as_real_array(value, name: str) -> np.ndarray:
    """A real, finite float array of any shape (complex, strings, objects and NaN/Inf rejected)."""
    return _as_float_array(value, name)


def as_states(x, name: str, dim: Optional[int] = None, allow_single: bool = True):
    """Validate a batch of states ``(B, 2n)`` (or one state ``(2n,)``).

    Returns
    -------
    states : ndarray of shape (B, 2n)
    single : bool
        Whether a single state was passed (the caller returns ``(2n,)`` then).
    """
    arr = _as_float_array(x, name)
    single = arr.ndim == 1 and allow_single
    if single:
        arr = arr[None, :]
    if arr.ndim != 2:
        raise ValueError(f"{name} must have shape (batch, 2n){' or (2n,)' if allow_single else ''}, got {arr.shape}")
    if len(arr) == 0:
        raise ValueError(f"{name} is empty (shape {arr.shape}): give at least one state (q, p)")
    if dim is not None and arr.shape[1] != dim:
        raise ValueError(f"{name} must have {dim} state components (2n = {dim}), got {arr.shape[1]}")
    if dim is None and (arr.shape[1] == 0 or arr.shape[1] % 2):
        raise ValueError(
            f"{name} must have an even, positive number of state components (q, p), shape (batch, 2n), "
            f"got shape {arr.shape}"
        )
    return np.ascontiguousarray(arr), single


def _is_mapping(mu) -> bool:
    """A pyMOR ``Mu`` or any mapping of parameter names to values (duck-typed: no pyMOR import here)."""
    return isinstance(mu, Mapping) or (
        callable(getattr(mu, "keys", None)) and callable(getattr(mu, "to_numpy", None)) and hasattr(mu, "__getitem__")
    )


def _mapping_to_vector(mu, d_mu: Optional[int], parameters, name: str) -> np.ndarray:
    """The parameter vector of one mapping ``name -> value`` (a pyMOR ``Mu`` or a dict).

    With ``parameters`` (a mapping ``name -> dimension``, e.g. pyMOR ``Parameters``): the values sorted by name,
    each flattened (pyMOR's ``Mu.to_numpy`` order), names and dimensions checked.  Without: a ``Mu``'s
    ``to_numpy()``, or the value of a dict with exactly one key.
    """
    keys = sorted(str(k) for k in mu.keys())
    if parameters is not None:
        wanted = {str(k): int(v) for k, v in dict(parameters).items()}
        if set(keys) != set(wanted):
            raise ValueError(
                f"{name} has the parameter names {keys}, the model's parameters are "
                f"{dict(sorted(wanted.items()))}: give exactly these names"
            )
        parts = []
        for k in sorted(wanted):
            v = _as_float_array(mu[k], f"{name}[{k!r}]").ravel()
            if v.size != wanted[k]:
                raise ValueError(
                    f"{name}[{k!r}] has {v.size} component(s), the model's parameter {k!r} has {wanted[k]}"
                )
            parts.append(v)
        return np.concatenate(parts) if parts else np.zeros(0)
    if callable(getattr(mu, "to_numpy", None)):  # a pyMOR Mu: its values sorted by name, each flattened
        return _as_float_array(mu.to_numpy(), name).ravel()
    if len(keys) != 1:
        raise ValueError(
            f"{name} is a dict with the keys {keys}: their order is ambiguous for a model that takes a "
            f"parameter vector; give a vector (values in the training order), a dict with one key, or "
            f"a pyMOR Mu (values sorted by name)"
        )
    return _as_float_array(next(iter(mu.values())), f"{name}[{keys[0]!r}]").ravel()


def _mappings_to_array(mu, d_mu: Optional[int], parameters, name: str):
    """A mapping (one parameter for all instances) or a list of mappings (one per instance) as an array; other
    inputs unchanged."""
    if _is_mapping(mu):
        return _mapping_to_vector(mu, d_mu, parameters, name)[None, :]
    if isinstance(mu, (list, tuple)) and mu and all(_is_mapping(m) for m in mu):
        return np.stack([_mapping_to_vector(m, d_mu, parameters, f"{name}[{i}]") for i, m in enumerate(mu)])
    return mu


def as_model_parameter(mu, n: int, n_mu: int, parameters=None) -> np.ndarray:
    """The parameter of a query to a fitted model with ``n_mu`` components (0: trained without one); ``(n, n_mu)``.

    ``ValueError`` when ``mu`` is passed to a parameter-free model or missing for a parametric one.
    """
    if n_mu == 0:
        if mu is not None:
            raise ValueError("this model was trained without a parameter (mu_kernel=None): do not pass mu")
        return np.zeros((n, 0))
    if mu is None:
        raise ValueError(f"mu is required: this model was trained with {n_mu} parameter component(s)")
    return as_parameter(mu, n, n_mu, parameters=parameters)


def as_parameter(mu, n: int, d_mu: Optional[int], name: str = "mu", parameters=None) -> np.ndarray:
    """Validate parameters for ``n`` instances; returns ``(n, d_mu)``.

    Accepted: a scalar (``d_mu = 1``), ``(n,)`` (``d_mu = 1``), ``(d_mu,)``
    (one vector for all instances, ``d_mu > 1``), ``(n, d_mu)`` or ``(1, d_mu)``;
    a pyMOR ``Mu`` or a dict ``name -> value`` (one parameter for all instances),
    or a list of them (one per instance).  With ``parameters`` (a mapping
    ``name -> dimension`` such as pyMOR ``Parameters``), a ``Mu``/dict must
    have exactly these names and dimensions and becomes the values sorted by
    name, each flattened (``Mu.to_numpy`` order); without, a ``Mu`` becomes
    ``Mu.to_numpy()`` and a dict must have one key (several keys are ambiguous:
    ``ValueError`` naming them).  With ``d_mu=None`` (fit), the dimension is
    taken from the input.

    Returns
    -------
    ndarray of shape (n, d_mu)
    """
    mu = _mappings_to_array(mu, d_mu, parameters, name)
    arr = _as_float_array(mu, name)
    if arr.ndim == 0:
        arr = np.full((n, 1), float(arr))
    elif arr.ndim == 1:
        if d_mu is not None and d_mu > 1:
            if len(arr) != d_mu:
                raise ValueError(f"{name} must have {d_mu} components per instance, got shape {arr.shape}")
            arr = np.broadcast_to(arr, (n, d_mu))
        else:
            if len(arr) not in (1, n):
                raise ValueError(
                    f"{name} must have length {n} (one value per instance) or be a scalar, got {arr.shape}"
                )
            arr = np.broadcast_to(arr[:, None], (n, 1))
    elif arr.ndim == 2:
        if arr.shape[0] not in (1, n):
            raise ValueError(f"{name} must have shape ({n}, d_mu), got {arr.shape}")
        arr = np.broadcast_to(arr, (n, arr.shape[1]))
    else:
        raise ValueError(f"{name} must be a scalar, (batch,) or (batch, d_mu), got shape {arr.shape}")
    if d_mu is not None and arr.shape[1] != d_mu:
        raise ValueError(f"{name} must have {d_mu} component(s) (as in training), got {arr.shape[1]}")
    if arr.shape[1] == 0:
        raise ValueError(
            f"{name} has zero components (shape {arr.shape}): give at least one parameter value per "
            f"instance, or none (None) for a parameter-free model"
        )
    return np.ascontiguousarray(arr)


def as_steps(dt, n: int, name: str = "dt") -> np.ndarray:
    """Validate macro steps for ``n`` instances: a positive scalar or ``(n,)``; returns ``(n,)``."""
    if dt is None:
        raise ValueError(f"{name} is required: the macro time step, a positive float or one per instance")
    arr = _as_float_array(dt, name)
    if arr.ndim == 0 or (arr.ndim == 1 and len(arr) == 1):
        arr = np.full(n, float(arr.reshape(-1)[0]))
    elif arr.ndim != 1 or len(arr) != n:
        raise ValueError(f"{name} must be a scalar or have shape ({n},), got {arr.shape}")
    if np.any(arr <= 0):
        raise ValueError(
            f"{name} must be positive, got min {float(arr.min())!r} ({_first_bad(arr, arr <= 0)}): "
            f"give the macro time step(s) > 0"
        )
    return arr


def as_trajectories(states, name: str = "states", *, dim: Optional[int] = None, allow_single: bool = False):
    """Validate trajectories ``(P, K+1, 2n)``: ``P`` trajectories of ``K + 1 >= 2`` finite states, ``2n`` even.

    With ``allow_single``, one trajectory ``(K+1, 2n)`` is accepted as ``(1, K+1, 2n)``; with ``dim``, ``2n`` must
    equal it.

    Returns
    -------
    ndarray of shape (P, K+1, 2n)
    """
    arr = _as_float_array(states, name)
    if allow_single and arr.ndim == 2:
        arr = arr[None]
    if arr.ndim != 3 or arr.shape[1] < 2 or arr.shape[2] == 0 or arr.shape[2] % 2:
        raise ValueError(
            f"{name} must have shape (P, K+1, 2n) with K >= 1 and an even 2n"
            f"{' (or (K+1, 2n) for one trajectory)' if allow_single else ''}, got {arr.shape}"
        )
    if dim is not None and arr.shape[2] != dim:
        raise ValueError(f"{name} must have {dim} state components (2n = {dim}), got {arr.shape[2]}")
    return arr


def as_times(times, p: int, k1: int, name: str = "times") -> np.ndarray:
    """Validate the sample times of ``p`` trajectories of ``k1`` states: ``(p, k1)`` or ``(k1,)`` (shared), finite,
    strictly increasing along each trajectory.

    Returns
    -------
    ndarray of shape (p, k1)
    """
    arr = _as_float_array(times, name)
    if arr.shape == (k1,):
        arr = np.broadcast_to(arr, (p, k1))
    if arr.shape != (p, k1):
        raise ValueError(f"{name} must have shape (P, K+1) = ({p}, {k1}) or (K+1,) = ({k1},), got {arr.shape}")
    steps = np.diff(arr, axis=1)
    bad = np.flatnonzero(~(steps > 0).all(axis=1))
    if len(bad):
        k = int(np.flatnonzero(steps[bad[0]] <= 0)[0])
        raise ValueError(
            f"{name} must increase strictly along each trajectory: trajectory {bad[0]} has "
            f"t[{k}] = {float(arr[bad[0], k])!r} >= t[{k + 1}] = {float(arr[bad[0], k + 1])!r}"
            + (f" ({len(bad)} trajectories are affected)" if len(bad) > 1 else "")
        )
    return arr


def as_real(value, name: str, *, positive: bool = False, nonnegative: bool = False) -> float:
    """A finite real number (bools, strings, complex and NaN/Inf rejected), optionally ``> 0`` or ``>= 0``."""
    arr = np.asarray(value) if not isinstance(value, (bool, np.bool_)) else None
    if arr is None or arr.ndim != 0 or arr.dtype.kind not in "iuf":
        raise ValueError(f"{name} must be a real number, got {value!r}")
    number = float(arr)
    if not np.isfinite(number):
        raise ValueError(f"{name} must be finite, got {number!r}")
    if positive and number <= 0:
        raise ValueError(f"{name} must be positive, got {number!r}")
    if nonnegative and number < 0:
        raise ValueError(f"{name} must be >= 0, got {number!r}")
    return number


def as_positive_int(value, name: str, minimum: int = 1) -> int:
    """An integer ``>= minimum`` (bools rejected)."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    if value < minimum:
        raise ValueError(f"{name} must be >= {minimum}, got {value}")
    return int(value)


def as_choice(value, name: str, choices) -> str:
    """``value`` if it is one of the strings ``choices``; ``ValueError`` naming ``name``, the value and the choices."""
    choices = tuple(choices)
    if not isinstance(value, str) or value not in choices:
        raise ValueError(f"{name} must be one of {choices}, got {value!r}")
    return value


def as_flag(value, name: str) -> bool:
    """``value`` as a ``bool`` if it is ``True`` or ``False`` (NumPy's too; ``1``, ``"yes"`` refused)."""
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{name} must be True or False, got {value!r}")
    return bool(value)


def as_even_dimension(dim, what: str = "states") -> int:
    """``dim`` if it is even (states ``(q, p)`` of dimension ``2n``); ``ValueError`` naming it otherwise."""
    if dim % 2:
        raise ValueError(f"{what} must have an even dimension 2n (q, p), got {dim}")
    return dim


class Constraint:
    """One setting's row in an estimator's table of settings (scikit-learn's ``_parameter_constraints``).

    Parameters
    ----------
    types : type or tuple of types, optional
        The accepted types (any, when empty).
    expected : str
        What the setting must be, with an example: the fix a message names (``"{name} must be {expected}, got
        {value!r}"``).
    required : bool
        Whether ``None`` is refused (else ``None`` means the default and passes).
    check : callable ``check(value, name)``, optional
        The value's own check (a range, the part's ``check()``), raising ``ValueError`` naming ``name``;
        returns the checked value.
    """

    def __init__(self, types=(), *, expected: str = "", required: bool = False, check=None):
        self.types, self.expected, self.required, self.check = types, expected, required, check

    def validate(self, name: str, value):
        """The checked ``value`` of the setting ``name`` (``None`` passes unless required); ``ValueError`` otherwise."""
        if value is None and not self.required:
            return None
        if self.types and not isinstance(value, self.types):
            raise ValueError(f"{name} must be {self.expected}, got {value!r}")
        return value if self.check is None else self.check(value, name)


def check_settings(owner, table: Mapping) -> dict:
    """``owner``'s settings checked against ``table`` (``{name: Constraint}``, in the table's order): the one
    place an estimator's settings are validated, for ``fit``, model files and the reductor alike."""
    return {name: rule.validate(name, getattr(owner, name)) for name, rule in table.items()}
