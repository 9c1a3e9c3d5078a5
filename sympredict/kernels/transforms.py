"""Transforms of the state kernel: periodic coordinates, a symmetry group, a symplectic scaling.

A transform wraps a state kernel (a radial kernel, another transform, or
``None`` for the default radial kernel chosen at fit time) and changes what the
kernel sees of the state::

    SymplecticKernelPredictor(Periodic(IMQ(0.5), coordinates=(0,)), ...)
    SymplecticKernelPredictor(Symmetric(Scaled(IMQ(0.5), factors=[2.0]), group=[(1, 1), (-1, -1)]), ...)

==========================  ====================================================================
transform                   the state kernel becomes
==========================  ====================================================================
:class:`Scaled`             ``k(D x, D y)``, ``D = diag(a, 1/a)`` symplectic: per-pair shapes
                            ``eps a_i`` in ``q_i`` and ``eps / a_i`` in ``p_i``
:class:`Periodic`           ``P``-periodic in the angle coordinates
                            (:class:`~sympredict.kernels.PeriodicCoordinates`)
:class:`Symmetric`          ``sum_g k(x, g y)``: exactly invariant under a finite orthogonal
                            group (:class:`~sympredict.kernels.StateSymmetry`)
==========================  ====================================================================

A transform whose defining setting is ``None`` (``factors``, ``coordinates``,
``group``) is the identity.  Each transform may appear once in a chain, in any order: coordinates, periods
and group elements are always given in the user's (unscaled) coordinates.
:func:`lower_state_kernel` turns a chain into the flat description the
estimator trains with (:class:`StateKernelParts`); which combinations a solver
backend runs is declared in one table of the estimator
(:data:`sympredict.estimators.predictor.NUMPY_ONLY`).  Like kernels, transforms are
immutable values: :meth:`KernelTransform.set_params` returns a new one, and a
shape set on the transform (``set_params(eps=...)``, or
``state_kernel__eps`` on the estimator) goes to the radial kernel inside, so
model selection over shapes works through transforms.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from sympredict.base import Parametrized
from sympredict.kernels.radial import PeriodicCoordinates, RadialKernel, StateSymmetry, kernel_from_spec

__all__ = [
    "KernelTransform",
    "Scaled",
    "Periodic",
    "Symmetric",
    "StateKernelParts",
    "lower_state_kernel",
    "compose_state_kernel",
    "transform_from_spec",
    "encode_value",
    "decode_value",
]


class KernelTransform(Parametrized):
    """Base class: a transform of the state kernel ``kernel`` (a radial kernel, a transform, or ``None``)."""

    #: Name in model files.
    name: str = "transform"

    def __eq__(self, other) -> bool:
        return type(self) is type(other) and _same(self.get_params(deep=False), other.get_params(deep=False))

    def __hash__(self) -> int:
        return hash((type(self).__name__, repr(self)))

    def get_params(self, deep: bool = True) -> dict:
        """The transform's parameters; ``deep`` adds the inner kernel's (``kernel__eps``) and, for convenience, its
        shape as ``eps`` (so ``state_kernel__eps`` works on an estimator whatever transforms wrap the kernel)."""
        out = super().get_params(deep=deep)
        if deep:
            radial = self.radial
            if radial is not None:
                out.update(radial.get_params(deep=False))
        return out

    def set_params(self, **params) -> "KernelTransform":
        """A new transform with the given parameters; names that are not the transform's go to the inner kernel."""
        own = set(self._param_names())
        mine = {k: v for k, v in params.items() if k.partition("__")[0] in own}
        inner = {k: v for k, v in params.items() if k.partition("__")[0] not in own}
        values = self.get_params(deep=False)
        nested = {}
        for key, value in mine.items():
            name, _, sub = key.partition("__")
            if sub:
                nested.setdefault(name, {})[sub] = value
            else:
                values[name] = value
        for name, sub in nested.items():
            values[name] = values[name].set_params(**sub)
        if inner:
            if values["kernel"] is None:
                raise ValueError(
                    f"{type(self).__name__} wraps the default state kernel (None): it has no parameters "
                    f"{sorted(inner)}; wrap a kernel (e.g. IMQ(1.0)) to set them"
                )
            values["kernel"] = values["kernel"].set_params(**inner)
        return type(self)(**values)

    #: The parameter whose ``None`` makes the transform the identity (``Scaled(k, factors=None)`` is ``k``).
    _key: str = ""

    @property
    def is_identity(self) -> bool:
        """Whether the transform changes nothing (its key setting is ``None``)."""
        return getattr(self, self._key) is None

    @property
    def eps(self) -> float:
        """The shape of the radial kernel inside (what model selection varies)."""
        radial = self.radial
        if radial is None:
            raise AttributeError(f"{type(self).__name__} wraps the default state kernel (None), which has no eps yet")
        return radial.eps

    @property
    def radial(self) -> Optional[RadialKernel]:
        """The radial kernel at the bottom of the chain (``None``: the default chosen at fit time)."""
        inner = self.kernel
        return inner.radial if isinstance(inner, KernelTransform) else inner

    def with_radial(self, radial: Optional[RadialKernel]) -> "KernelTransform":
        """The same chain around another radial kernel (model selection: candidates inside the transforms)."""
        inner = self.kernel.with_radial(radial) if isinstance(self.kernel, KernelTransform) else radial
        return type(self)(**{**self.get_params(deep=False), "kernel": inner})

    @property
    def spec(self) -> dict:
        params = {k: encode_value(v) for k, v in self.get_params(deep=False).items()}
        return {"transform": self.name, "params": params}

    def _check(self) -> None:
        """``ValueError`` for a malformed setting (run at fit and load, scikit-learn's convention)."""
        inner = self.kernel
        if inner is not None and not isinstance(inner, (RadialKernel, KernelTransform)):
            raise ValueError(
                f"{type(self).__name__}: kernel must be a radial kernel (IMQ, Matern52, ...), a transform "
                f"or None, got {inner!r}"
            )


class Scaled(KernelTransform):
    """The state kernel in the symplectically scaled coordinates ``(a_i q_i, p_i / a_i)``.

    ``D = diag(a, 1/a)`` is symplectic, so a model trained on ``D x`` and mapped
    back (``Phi = D^-1 Phi~ D``) is as symplectic as one trained on ``x``, for
    both updates and both solvers.  An isotropic kernel of shape ``eps`` then
    has the shapes ``eps a_i`` in ``q_i`` and ``eps / a_i`` in ``p_i``: one free
    ratio of shapes per conjugate pair.

    Parameters
    ----------
    kernel
        The state kernel (``None``: the default, chosen at fit time in the scaled coordinates).
    factors : sequence of float
        ``n`` positive finite factors ``a_i``, one per ``q_i``.
    """

    name = "scaled"
    _key = "factors"

    def __init__(self, kernel=None, factors=(1.0,)):
        self.kernel = kernel
        self.factors = factors

    def _check(self) -> None:
        super()._check()
        _positive_vector(self.factors, "Scaled: factors")


def _periodic_setting(coordinates, period, dim: Optional[int] = None) -> tuple:
    """``(coordinates, periods)`` of a :class:`Periodic` setting as ints and floats, one period per coordinate.

    ``ValueError`` naming the malformed one; ``dim``: the state dimension where it is known (the indices must lie
    below it).
    """
    coords = coordinates
    within = "" if dim is None else f" in 0..{dim - 1}"
    if (
        not isinstance(coords, (tuple, list))
        or not coords
        or not all(isinstance(c, (int, np.integer)) and not isinstance(c, bool) and c >= 0 for c in coords)
        or len(set(int(c) for c in coords)) != len(coords)
        or (dim is not None and not all(c < dim for c in coords))
    ):
        raise ValueError(
            f"Periodic: coordinates must be a tuple of distinct state indices{within} (the periodic "
            f"coordinates, e.g. angles), got {coords!r}"
        )
    periods = tuple(period) if isinstance(period, (tuple, list)) else (period,) * len(coords)
    if len(periods) != len(coords) or not all(
        isinstance(p, (int, float, np.number)) and not isinstance(p, bool) and np.isfinite(p) and p > 0 for p in periods
    ):
        raise ValueError(
            f"Periodic: period must be a positive finite number or one per periodic coordinate "
            f"({len(coords)}), got {period!r}"
        )
    return tuple(int(c) for c in coords), tuple(float(p) for p in periods)


class Periodic(KernelTransform):
    """A state kernel periodic in some coordinates (angles): ``s`` is exactly periodic in them.

    The squared distance uses ``(P/pi)^2 sin^2(pi d_i / P)`` for ``d_i^2``
    (:class:`~sympredict.kernels.PeriodicCoordinates`), so the step commutes
    with ``q_i -> q_i + P`` and rotating orbits need no wrapping.  The data
    need not span more than one period, but ``x1 - x0`` must be the true
    increment (not wrapped separately).

    Parameters
    ----------
    kernel
        The state kernel (``None``: the default).
    coordinates : tuple of int
        Distinct state indices in ``0 .. 2n-1`` (usually angles ``q_i``).
    period : float or tuple of float
        The period ``P`` (default ``2 pi``), or one per coordinate, in the user's coordinates.
    """

    name = "periodic"
    _key = "coordinates"

    def __init__(self, kernel=None, coordinates=(0,), period=2 * np.pi):
        self.kernel = kernel
        self.coordinates = coordinates
        self.period = period

    def _check(self) -> None:
        super()._check()
        _periodic_setting(self.coordinates, self.period)

    @property
    def periods(self) -> tuple:
        """One period per coordinate."""
        p = self.period
        return tuple(p) if isinstance(p, (tuple, list)) else (p,) * len(tuple(self.coordinates))


class Symmetric(KernelTransform):
    """The group-averaged state kernel ``sum_g k(x, g y)``: ``s`` exactly invariant under a finite group ``G``.

    Which groups are valid depends on the update (checked at fit time by the
    update rule, :meth:`~sympredict.symplectic.updates.UpdateRule.check_symmetry`): the
    midpoint update takes symplectic and anti-symplectic elements, the
    symplectic-Euler update only ``diag(A, A)``.  The user asserts that the
    system has the symmetry; the data are not checked against it.

    Parameters
    ----------
    kernel
        The state kernel (``None``: the default).
    group
        A :class:`~sympredict.kernels.StateSymmetry`, sign patterns
        (``[(1, 1), (-1, -1)]``: the maps ``diag(s)``) or matrices ``(|G|, 2n, 2n)``,
        every element listed (identity included), in the user's coordinates.
    """

    name = "symmetric"
    _key = "group"

    def __init__(self, kernel=None, group=None):
        self.kernel = kernel
        self.group = group

    def _check(self) -> None:
        super()._check()
        StateSymmetry.coerce(self.group)


@dataclass(frozen=True)
class StateKernelParts:
    """A state kernel chain, flattened: what the estimator trains with.

    ``radial`` is ``None`` for the default kernel; ``scaling``, ``periodic``
    (coordinates), ``period`` and ``symmetry`` are ``None`` where the chain has no
    such transform, else the values of :class:`Scaled`, :class:`Periodic` and
    :class:`Symmetric`.
    """

    radial: Optional[RadialKernel] = None
    scaling: Optional[tuple] = None
    periodic: Optional[tuple] = None
    period: object = 2 * np.pi
    symmetry: object = None

    def scale_vector(self, dim: int) -> np.ndarray:
        """``(a, 1/a)`` of the scaling (ones without it), shape (2n,); ``ValueError`` for a malformed one."""
        if self.scaling is None:
            return np.ones(dim)
        try:
            a = None if isinstance(self.scaling, (str, bytes)) else np.asarray(self.scaling, dtype=float)
        except (TypeError, ValueError):
            a = None
        if a is None or a.shape != (dim // 2,) or not np.all(np.isfinite(a) & (a > 0)):
            raise ValueError(
                f"the state kernel's Scaled factors must be {dim // 2} positive finite numbers (one per "
                f"q_i), got {self.scaling!r}"
            )
        return np.concatenate([a, 1.0 / a])

    def original_periods(self, dim: int) -> tuple:
        """``(coordinates, periods)`` of the periodic coordinates in the user's coordinates; checks them."""
        if self.periodic is None:
            return (), ()
        return _periodic_setting(self.periodic, self.period, dim)

    def model_periodic(self, dim: int) -> Optional[PeriodicCoordinates]:
        """The kernel's periodic coordinates in the trained (scaled) coordinates: periods times the scaling."""
        coords, periods = self.original_periods(dim)
        if not coords:
            return None
        scale = self.scale_vector(dim)
        return PeriodicCoordinates(coords, tuple(p * float(scale[c]) for c, p in zip(coords, periods)))

    def model_symmetry(self, dim: int, rule) -> Optional[StateSymmetry]:
        """The group in the trained coordinates (conjugated by the scaling); ``ValueError`` for a malformed group,
        a wrong dimension, elements the update ``rule`` cannot use, a scaling that does not commute with the group,
        or, with periodic coordinates as well, elements that do not respect the periods
        (:meth:`~sympredict.kernels.StateSymmetry.check_periodic`)."""
        group = StateSymmetry.coerce(self.symmetry)
        if group is None:
            return None
        group.check_dim(dim)
        rule.check_symmetry(group.array)
        group = group.conjugated(self.scale_vector(dim)) if self.scaling is not None else group
        periodic = self.model_periodic(dim)
        if periodic is not None:
            group.check_periodic(periodic)
        return group


def lower_state_kernel(kernel) -> StateKernelParts:
    """Flatten a state-kernel chain; ``ValueError`` naming the problem for a malformed one.

    Refused: a transform twice in one chain.  :class:`Periodic` together with :class:`Symmetric` needs a group of
    signed permutations that respects the periods (checked at fit, :meth:`StateKernelParts.model_symmetry`).
    """
    if kernel is None or isinstance(kernel, RadialKernel):
        return StateKernelParts(radial=kernel)
    found: dict = {}
    node = kernel
    while isinstance(node, KernelTransform):
        if not node.is_identity:
            node._check()
            if type(node) in found:
                raise ValueError(f"the state kernel {kernel!r} applies {type(node).__name__} twice: use it once")
            found[type(node)] = node
        node = node.kernel
    if node is not None and not isinstance(node, RadialKernel):
        raise ValueError(
            f"state_kernel must be a radial kernel (IMQ, Matern52, Matern32), a transform of one "
            f"(Scaled, Periodic, Symmetric) or None, got {kernel!r}"
        )
    scaled, periodic, symmetric = found.get(Scaled), found.get(Periodic), found.get(Symmetric)
    return StateKernelParts(
        radial=node,
        scaling=None if scaled is None else tuple(float(a) for a in np.atleast_1d(np.asarray(scaled.factors, float))),
        periodic=None if periodic is None else tuple(int(c) for c in periodic.coordinates),
        period=2 * np.pi if periodic is None else periodic.period,
        symmetry=None if symmetric is None else symmetric.group,
    )


def compose_state_kernel(radial, scaling=None, periodic=None, period=2 * np.pi, symmetry=None):
    """The chain for the flat settings (the inverse of :func:`lower_state_kernel`; old settings' translation)."""
    kernel = radial
    if scaling is not None:
        kernel = Scaled(kernel, factors=scaling)
    if periodic is not None:
        kernel = Periodic(kernel, coordinates=periodic, period=period)
    if symmetry is not None:
        kernel = Symmetric(kernel, group=symmetry)
    return kernel


_TRANSFORMS = {cls.name: cls for cls in (Scaled, Periodic, Symmetric)}


def transform_from_spec(spec: dict) -> KernelTransform:
    """Rebuild a transform chain from :attr:`KernelTransform.spec`; ``ValueError`` for a malformed one."""
    try:
        cls = _TRANSFORMS[spec["transform"]]
        params = {k: decode_value(v) for k, v in spec["params"].items()}
        return cls(**params)
    except (KeyError, TypeError, AttributeError) as exc:
        raise ValueError(f"malformed kernel-transform spec {spec!r} ({exc!r}); known: {sorted(_TRANSFORMS)}") from None


def encode_value(value):
    """A kernel-valued setting as JSON (model files): kernels, transforms and groups by their specs, tuples
    and lists kept apart (a loaded setting repeats the given one), integers as integers.

    ``ValueError`` for a value that has no JSON form.
    """
    if isinstance(value, KernelTransform):
        return value.spec
    if isinstance(value, RadialKernel):
        return {"kernel": value.spec}
    if isinstance(value, StateSymmetry):
        return {"symmetry": value.spec}
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value)
    if isinstance(value, np.ndarray) and value.dtype.kind in "if":
        value = value.tolist()  # stored as nested lists (loaded back as lists)
    if isinstance(value, (tuple, list)):
        return {"tuple" if isinstance(value, tuple) else "list": [encode_value(v) for v in value]}
    raise ValueError(f"cannot store the value {value!r} in a model file")


def decode_value(value):
    """The setting :func:`encode_value` wrote (specs are checked by the classes they rebuild)."""
    if isinstance(value, dict):
        if "transform" in value:
            return transform_from_spec(value)
        if "kernel" in value:
            return kernel_from_spec(value["kernel"])
        if "symmetry" in value:
            return StateSymmetry.from_spec(value["symmetry"])
        if set(value) == {"tuple"} and isinstance(value["tuple"], list):
            return tuple(decode_value(v) for v in value["tuple"])
        if set(value) == {"list"} and isinstance(value["list"], list):
            return [decode_value(v) for v in value["list"]]
    if isinstance(value, list):
        return [decode_value(v) for v in value]
    return value


def _same(a, b) -> bool:
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, (np.ndarray, list, tuple)) or isinstance(b, (np.ndarray, list, tuple)):
        try:
            return bool(np.array_equal(np.asarray(a, dtype=float), np.asarray(b, dtype=float)))
        except (TypeError, ValueError):
            return a == b
    return a == b


def _positive_vector(value, what: str) -> np.ndarray:
    try:
        arr = None if isinstance(value, (str, bytes)) else np.atleast_1d(np.asarray(value, dtype=float))
    except (TypeError, ValueError):
        arr = None
    if arr is None or arr.ndim != 1 or arr.size == 0 or not np.all(np.isfinite(arr) & (arr > 0)):
        raise ValueError(f"{what} must be positive finite numbers (one per q_i), got {value!r}")
    return arr
